"""Lever arms and time asynchrony (issue 17 part 2): simulator effects, the estimator, the rotating procedure, the CLI."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from stableins import cli
from stableins import conventions as cv
from stableins.errors import InputError, NotDeterminedError
from stableins.estimators.lever import LeverOptions, LeverSet, estimate_lever
from stableins.noise import NoiseModel
from stableins.procedures.definition import PROCEDURE_DIRECTORY, load_procedure
from stableins.procedures.planning import plan_from_definition
from stableins.records import CalibrationRecord
from stableins.simulator.device import SimulatedPlatform
from stableins.simulator.noise import NoiseSettings
from stableins.simulator.truth import DEFAULT_SETTLING, Truth

ROTATING = load_procedure("device-rotating")
#: Cai's white noise (1 µg per 100-Hz sample) and the quartz angle noise.
CAI_NOISE = NoiseSettings(velocity_random_walk=1e-6, angle_noise=0.2 * cv.ARCSEC)


def _columns(blocks):
    t = np.concatenate([b.time for b in blocks])
    f = np.concatenate([b.specific_force for b in blocks])
    a = np.concatenate([b.angles for b in blocks])
    out = {"time": t, "temperature": np.concatenate([b.temperature for b in blocks])}
    out |= {f"angle_{g}": a[:, k] for k, g in enumerate(("platform", "inner", "middle"))}
    out |= {f"f_{x}": f[:, k] for k, x in enumerate("xyz")}
    return out


def _slews(truth, path, pause, seed=1):
    platform = SimulatedPlatform(truth, rate=100.0, seed=seed)
    blocks = []
    commands = []
    for readings in path:
        commands.append(platform.status()["sample"])
        platform.command(readings)
        blocks.append(platform.acquire(platform.slew_duration() + pause))
    return _columns(blocks) | {"command_sample": np.array(commands)}


def _noise_model(settings):
    return NoiseModel.given(
        settings.velocity_random_walk, settings.bias_instability, settings.acceleration_random_walk, settings.quantization / math.sqrt(12)
    )


# ----------------------------------------------------------------------------- the simulator (the independent world)
def test_asynchrony_in_the_simulator_is_the_path_sampled_late():
    """τ = 1 ms: the output changes by τ ω×f^p (conventions.asynchrony_error, first order), the readings do not."""
    quiet = Truth.draw(3, noise=NoiseSettings.quiet())
    late = Truth.draw(3, noise=NoiseSettings.quiet(), effects={"t_async": 1e-3})
    path = [(0.0, 0.0, math.radians(90.0)), (math.radians(-90.0), 0.0, math.radians(90.0))]
    a, b = _slews(quiet, path, 2.0), _slews(late, path, 2.0)
    np.testing.assert_array_equal(a["angle_middle"], b["angle_middle"])
    platform = quiet.platform()
    readings = np.stack([a[f"angle_{g}"] for g in ("platform", "inner", "middle")], axis=1)
    rates = np.gradient(readings, 0.01, axis=0)
    omega = platform.angular_rate(platform.actual_angles(readings), rates)
    f_p = platform.specific_force_platform(readings, quiet.site.gravity)
    expected = cv.asynchrony_error(1e-3, omega, f_p)
    got = np.stack([b[f"f_{x}"] - a[f"f_{x}"] for x in "xyz"], axis=1)
    # 90° at 10°/s peak: τ ω g up to 1.7e-3 m/s² (175 µg) less the base attitude; the output is the sensor's (SF, C_p^a)
    assert np.max(np.abs(expected)) > 1e-3
    inside = np.ones(len(rates), dtype=bool)
    for k in a["command_sample"]:  # the numerical rate of the check is one-sided at a command: left out
        inside[max(k - 1, 0) : k + 2] = False
    np.testing.assert_allclose(got[inside], expected[inside], atol=2e-3 * np.max(np.abs(expected)) + 1e-7)


def test_lever_effect_follows_the_simulated_slew_profile():
    """lever_x_x during a slew about the middle axis (y_p): −ω² r with the cosine profile's ω (not an estimator formula)."""
    quiet = Truth.draw(4, noise=NoiseSettings.quiet())
    arm = Truth.draw(4, noise=NoiseSettings.quiet(), effects={"lever_x_x": 0.02})
    path = [(0.0, 0.0, math.radians(90.0))]
    a, b = _slews(quiet, path, 1.0), _slews(arm, path, 1.0)
    peak = DEFAULT_SETTLING["slew_rate"]
    duration = math.pi / 2 * math.radians(90.0) / peak
    t = a["time"]
    omega = np.where(t < duration, 0.5 * math.pi / duration * math.radians(90.0) * np.sin(math.pi * t / duration), 0.0)
    moving = (t > 0.5) & (t < duration - 0.5)
    got = (b["f_x"] - a["f_x"])[moving]
    np.testing.assert_allclose(got, -(omega**2)[moving] * 0.02, rtol=2e-3, atol=1e-7)
    assert np.max(np.abs(got)) == pytest.approx(peak**2 * 0.02, rel=1e-3)


# ----------------------------------------------------------------------------- the estimator
@pytest.fixture(scope="module")
def cai_noise_fit():
    """Five rotations of the path (two axes), 2-cm arms and τ = 1 ms, Cai's noise level; all nine arms fitted."""
    arms = {"lever_x_x": 0.02, "lever_y_y": -0.02, "lever_z_z": 0.02, "lever_x_z": 0.02, "lever_z_y": -0.02}
    truth = Truth.draw(5, noise=CAI_NOISE, effects={**arms, "t_async": 1e-3})
    path = [tuple(s.command) for s in ROTATING.steps[:8]]
    columns = _slews(truth, path, 30.0, seed=5)
    options = LeverOptions(arms=LeverSet.FULL)
    return truth, estimate_lever(columns, truth.site, truth.installed_calibration, noise_model=_noise_model(CAI_NOISE), options=options)


def test_lever_arms_and_asynchrony_recovered_at_cai_noise(cai_noise_fit):
    truth, fit = cai_noise_fit
    z = (fit.values - np.array([truth.effects.get(t.id, 0.0) for t in fit.terms])) / fit.sigma
    assert np.all(np.abs(z) < 4.0), dict(zip([t.id for t in fit.terms], np.round(z, 2), strict=True))
    assert np.all(fit.sigma[:-1] < 0.1e-3)  # Cai's Table 2 level: 0.01 cm
    assert abs(fit.values[-1] - 1e-3) < 0.1e-3
    assert all(f.flagged for f in fit.details.flags)
    assert fit.likelihood is not None and fit.likelihood.ids == tuple(t.id for t in fit.terms)


def test_clean_quartz_data_raise_no_flag():
    truth = Truth.draw(6)
    path = [tuple(s.command) for s in ROTATING.steps[:8]]
    fit = estimate_lever(_slews(truth, path, 30.0, seed=6), truth.site, truth.installed_calibration, noise_model=_noise_model(truth.noise))
    assert [f.name for f in fit.details.flags] == ["lever arms", "time asynchrony"]
    assert not any(f.flagged for f in fit.details.flags)
    assert abs(fit.chi2_red - 1.0) < 3 * math.sqrt(2.0 / fit.dof)
    assert np.all(np.abs(fit.values / fit.sigma) < 4.0)


def test_no_slew_is_refused():
    truth = Truth.draw(7)
    columns = _slews(truth, [(0.0, 0.0, 0.0)], 20.0)
    with pytest.raises(InputError, match="no slew") as error:
        estimate_lever(columns, truth.site, truth.installed_calibration, source="still.h5")
    assert "still.h5" in str(error.value)


def test_one_axis_of_rotation_does_not_determine_nine_arms():
    truth = Truth.draw(8)
    path = [(0.0, 0.0, math.radians(a)) for a in (90.0, 180.0)]
    with pytest.raises(NotDeterminedError, match="do not determine"):
        estimate_lever(_slews(truth, path, 20.0), truth.site, truth.installed_calibration, options=LeverOptions(arms=LeverSet.FULL))


# ----------------------------------------------------------------------------- the procedure
#: Cai's Table 1: where body X, Y, Z point (ENU) at the start and after each of the 18 rotations.
CAI_UP = ("ENU", "EUS", "EDN", "EUS", "UWS", "DES", "UWS", "SWD", "NWU", "SWD")
CAI_UP += ("DWN", "NWU", "UWS", "WDS", "DES", "EUS", "ESD", "EDN", "ENU")


def test_rotating_procedure_is_cai_table_1():
    """Each pause has the vertical axis of Cai's Table 1 under the mapping (x, y, z)_Cai = (y, x, −z)_p."""
    assert ROTATING.stage == "rotating" and ROTATING.positions == tuple(range(1, 20))
    assert all(s.dwell == 180.0 and s.settle == 0.0 for s in ROTATING.steps)
    for step, cai in zip(ROTATING.steps, CAI_UP, strict=True):
        f = cv.dcm_body_to_platform(*step.command, 0.0, cv.DEFAULT_GIMBALS) @ np.array([0.0, 0.0, -1.0])
        up = {"U": 1.0, "D": -1.0}
        np.testing.assert_allclose(f, [up.get(cai[1], 0.0), up.get(cai[0], 0.0), -up.get(cai[2], 0.0)], atol=1e-12)
        words = {"up": 1.0, "down": -1.0, "level": 0.0}
        np.testing.assert_allclose(f, [words[w.split()[1]] for w in step.expect.split(",")], atol=1e-12)
        assert step.command[1] == 0.0  # the inner gimbal stays at 0
    turns = np.abs(np.diff([s.command for s in ROTATING.steps], axis=0))
    assert np.degrees(turns[:, 2]).sum() == pytest.approx(1440.0) and np.degrees(turns[:, 0]).sum() == pytest.approx(720.0)
    assert all(step.keep_slew for step in plan_from_definition(ROTATING).steps)


def test_pause_is_configurable_and_steps_are_validated(tmp_path):
    text = (PROCEDURE_DIRECTORY / "device-rotating.toml").read_text()
    path = tmp_path / "short.toml"
    path.write_text(text.replace("dwell = 180.0", "dwell = 30.0"))
    assert all(s.dwell == 30.0 for s in load_procedure(path).steps)
    path.write_text(text.replace("middle = 1440.0", "middle = 1450.0"))
    with pytest.raises(InputError) as error:
        load_procedure(path)
    assert error.value.field == "step.middle" and str(path) in str(error.value)
    head, *steps = text.split("\n[[step]]")
    path.write_text(head + "".join("\n[[step]]" + s for s in steps[:4]))  # the middle gimbal alone, about y_p
    with pytest.raises(InputError, match="lever_y_y") as error:
        load_procedure(path)
    assert error.value.field == "step" and str(path) in str(error.value)


# ----------------------------------------------------------------------------- a run and the CLI
def _short_rotating(tmp_path):
    """The first five positions of device-rotating with 25-s pauses (what a real run does, in 2 minutes of samples)."""
    text = (PROCEDURE_DIRECTORY / "device-rotating.toml").read_text().replace("dwell = 180.0", "dwell = 25.0")
    head, *steps = text.split("\n[[step]]")
    path = tmp_path / "rotating-short.toml"
    path.write_text(head + "".join("\n[[step]]" + s for s in steps[:5]))
    return path


@pytest.fixture(scope="module")
def rotating_run(tmp_path_factory):
    tmp_path = tmp_path_factory.mktemp("rotating")
    prior = tmp_path / "prior.json"
    truth = Truth.draw(0)
    from stableins.records import CalibrationRecord as Record
    from tests.test_drift import prior_record

    prior_record(truth).save(prior)
    assert Record.load(prior).serial_number == "SIM-0"
    argv = ["run", str(_short_rotating(tmp_path)), "--driver", "sim", "--unit", "SIM-0", "--seed", "0", "--yes", "--quiet"]
    assert cli.main(argv + ["--prior", str(prior), "--out", str(tmp_path / "run")]) == 0
    return tmp_path


def test_run_keeps_the_slews_and_updates_the_record(rotating_run):
    from stableins.data.device import load_device
    from stableins.procedures.entries import journal_columns
    from stableins.procedures.journal import scan

    data = load_device(rotating_run / "run" / "device.h5")
    columns = data.columns
    assert set(columns["stage"]) == {"rotating"}
    middle = columns["angle_middle"][columns["position"] == 2]
    assert np.degrees(middle.max() - middle.min()) > 89.0  # the slew of position 2 is in the data
    assert np.all(np.diff(columns["time"]) < 0.0101)  # one clock, no gap: slews, settles and pauses kept
    from_journal = journal_columns(scan(rotating_run / "run" / "journal.bin").records)
    np.testing.assert_array_equal(from_journal["time"], columns["time"])
    record = CalibrationRecord.load(rotating_run / "run" / "record.json")
    prior = CalibrationRecord.load(rotating_run / "prior.json")
    for pid in ("lever_x_x", "lever_y_y", "lever_z_z", "t_async"):
        assert record[pid].sigma > 0 and abs(record[pid].value) < 4 * record[pid].sigma  # the simulated unit has none
    for pid in prior.ids:  # a Bayesian update: nothing else moves
        assert record[pid].value == pytest.approx(prior[pid].value, abs=1e-12 * max(1.0, abs(prior[pid].value)))
        assert record[pid].sigma == pytest.approx(prior[pid].sigma, rel=1e-12)
    assert not any(pid.startswith("lever_") for pid in record.error_model().ids)  # not an output term at rest


def test_cli_calibrate_lever_all_arms(rotating_run, capsys):
    out = rotating_run / "cal2.json"
    argv = ["calibrate", "lever", str(rotating_run / "run"), "--prior", str(rotating_run / "prior.json"), "--out", str(out)]
    assert cli.main(argv + ["--all-arms", "--json"]) == 0
    document = json.loads(capsys.readouterr().out)
    assert len(document["lever"]) == 10 and document["lever"]["lever_x_y"]["unit"] == "mm"
    assert document["lever"]["t_async"]["unit"] == "ms"
    assert CalibrationRecord.load(out)["lever_z_x"].sigma > 0


def test_cli_calibrate_lever_options(rotating_run, capsys, monkeypatch):
    """Issue 31: --no-asynchrony, --window, --new-calibration, --set and --quiet, each against the run without it."""
    from test_cli_options_quiet import quiet_main

    run, prior = str(rotating_run / "run"), str(rotating_run / "prior.json")
    base_out, options_out = rotating_run / "base.json", rotating_run / "options.json"
    assert cli.main(["calibrate", "lever", run, "--prior", prior, "--out", str(base_out), "--json"]) == 0
    base = json.loads(capsys.readouterr().out)
    argv = ["calibrate", "lever", run, "--prior", prior, "--out", str(options_out), "--no-asynchrony", "--window", "1",
            "--new-calibration", "--set", "laboratory=Lab L", "--json"]  # fmt: skip
    assert cli.main(argv) == 0
    document = json.loads(capsys.readouterr().out)
    assert "t_async" in base["lever"] and "t_async" not in document["lever"]  # --no-asynchrony: τ held at zero, not estimated
    assert "t_async" not in CalibrationRecord.load(options_out).ids or CalibrationRecord.load(options_out)["t_async"].value == 0.0
    assert (base["settings"]["window"], document["settings"]["window"]) == (0.5, 1.0)  # --window: the means over 1 s
    assert document["lever"]["lever_x_x"]["value"] != base["lever"]["lever_x_x"]["value"]
    before, continued, started = (CalibrationRecord.load(p) for p in (prior, base_out, options_out))
    assert continued.calibration.id == before.calibration.id != started.calibration.id  # --new-calibration
    assert ("laboratory", "Lab L") in [(e.key, e.value) for e in started.calibration.entries]  # --set
    argv = ["calibrate", "lever", run, "--prior", prior, "--out", rotating_run / "quiet.json", "--quiet"]
    status, _, err, seen = quiet_main(monkeypatch, argv, "stableins.commands.calibrate_lever")
    assert status == 0 and seen == [True], err[-1000:]  # --quiet: silenced while it works


def test_cli_refuses_data_without_slews(rotating_run, tmp_path, capsys):
    from stableins.data.device import load_device, save_device

    data = load_device(rotating_run / "run" / "device.h5")
    columns = dict(data.columns)
    columns["stage"] = np.full(len(columns["time"]), "coarse")
    save_device(tmp_path / "coarse.h5", columns, data.metadata)
    argv = ["calibrate", "lever", str(tmp_path / "coarse.h5"), "--prior", str(rotating_run / "prior.json")]
    assert cli.main(argv + ["--out", str(tmp_path / "out.json")]) == 2
    err = capsys.readouterr().err
    assert "coarse.h5" in err and "rotating" in err and not (tmp_path / "out.json").exists()
