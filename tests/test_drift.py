"""Indexing by torquing in the system-level world and the two-position gyro-drift test (issue 16 part 4).

The estimator's observation equations (docs/drift-test.md) are derived independently of the world's
kinematics (stableins.simulator.indexing); these tests check the one against the other with fixed seeds
and k·σ bounds (the 100-seed campaign is benchmarks/bench_two_position.py).
"""

import argparse
import json
import math

import numpy as np
import pytest

from stableins.commands import calibrate_drift
from stableins.conventions import ARCSEC, DEG_PER_HOUR, EARTH_RATE, earth_rate_nav, skew
from stableins.data.system import SystemRecordWriter
from stableins.errormodel import CORE_TERMS, GIMBAL_TERMS
from stableins.errors import InputError
from stableins.estimators.drift import drift_from_record, estimate_drift, find_holds, small_angle_vector
from stableins.estimators.result import FitResult
from stableins.platform import rotation_about
from stableins.procedures.definition import load_procedure
from stableins.procedures.plan import Plan
from stableins.procedures.planning import plan_from_definition
from stableins.records import CalibrationRecord, RunInfo
from stableins.simulator.indexing import earth_rotation
from stableins.simulator.noise import NoiseSettings
from stableins.simulator.system import SystemWorld, indexed_record_chunks, simulate_system
from stableins.simulator.truth import SimulatedSite, Truth
from stableins.turns import IndexAxis, PlatformTurn

RATE = 10.0
TWO = (PlatformTurn(600.0, math.pi),)
THREE = (PlatformTurn(600.0, math.pi), PlatformTurn(1228.3, math.pi, IndexAxis.MIDDLE))
DRIFT = {"x": 0.005 * DEG_PER_HOUR, "y": -0.005 * DEG_PER_HOUR, "z": 0.005 * DEG_PER_HOUR}
BASE = {"tilt_north": 10 * ARCSEC, "tilt_east": -8 * ARCSEC, "azimuth_error": 30 * ARCSEC}


def fit(truth, record, **options):
    site = truth.site
    return estimate_drift(
        record,
        site,
        prior_values=truth.installed_calibration,
        **options,
    )


def eps(truth):
    return np.array([truth.gyro_drift[a] for a in "xyz"])


# ----------------------------------------------------------------------------- the world
def test_general_kinematics_without_turns_is_the_polar_world():
    truth = Truth.draw(5, site=SimulatedSite(sample_rate=RATE), gyro_drift=DRIFT)
    plain = simulate_system(truth, 300, rate=RATE)
    general = simulate_system(truth, 300, rate=RATE, initial_readings=SystemWorld(truth, RATE).initial_readings)
    for name in ("angle_platform", "angle_inner", "angle_middle", "f_x", "f_z", "velocity_east", "heading"):
        assert np.max(np.abs(general[name] - plain[name])) < 1e-12, name
    # with a g-sensitive drift both compose it the same way (trapezoid rule, Bortz, f^p of the drifted orientation)
    truth = Truth.draw(5, site=SimulatedSite(sample_rate=RATE), noise=NoiseSettings.quiet(), effects={"Dg_xx": 3e-9})
    plain = simulate_system(truth, 300, rate=RATE)
    general = simulate_system(truth, 300, rate=RATE, initial_readings=SystemWorld(truth, RATE).initial_readings)
    for name in ("angle_platform", "angle_inner", "angle_middle"):
        assert np.max(np.abs(general[name] - plain[name])) < 1e-12, name


def test_indexed_samples_do_not_depend_on_chunking():
    truth = Truth.draw(6, site=SimulatedSite(sample_rate=RATE), gyro_drift=DRIFT)
    a = list(indexed_record_chunks(truth, 700, TWO, rate=RATE, chunk_samples=997))
    b = list(indexed_record_chunks(truth, 700, TWO, rate=RATE, chunk_samples=4096))
    for name in ("angle_platform", "angle_middle", "f_y", "velocity_north"):
        assert np.array_equal(np.concatenate([c[name] for c in a]), np.concatenate([c[name] for c in b])), name


def test_turn_kinematics_exact():
    """Noise-free: the platform's inertial attitude from the readings (true offsets) turns by exactly the command,
    and drifts at −ε^p in its own frame before and after the turn."""
    truth = Truth.draw(7, site=SimulatedSite(sample_rate=RATE), noise=NoiseSettings.quiet(), gyro_drift=DRIFT)
    record = simulate_system(truth, 1258, rate=RATE, turns=TWO)
    platform = truth.platform()
    readings = np.stack([record[f"angle_{g}"] for g in ("platform", "inner", "middle")], axis=1)
    axis = skew(earth_rate_nav(truth.site.latitude) / EARTH_RATE)
    inertial = platform.dcm_nav_to_platform(readings) @ earth_rotation(axis, record["time"]).swapaxes(1, 2)
    a, b = 5000, 7000  # 500 s and 700 s
    relative = inertial[b] @ inertial[a].T
    # commanded: 180° about z_p, plus the drift over 200 s (about the pre-turn axes for the part before the turn)
    expected = rotation_about([0.0, 0.0, math.pi])
    assert np.max(np.abs(relative - expected)) < 2e-5  # drift angles are ~5e-6 rad over 200 s
    for first, last in ((1000, 5000), (8000, 12000)):
        rate = small_angle_vector(inertial[last] @ inertial[first].T) / (record["time"][last] - record["time"][first])
        assert np.allclose(rate, -eps(truth), atol=1e-12), rate  # 0.005 °/h = 2.4e-8 rad/s


def test_commanded_start_orientation():
    """A platform commanded to arbitrary readings is held there in inertial space and drifts at −ε^p."""
    truth = Truth.draw(9, site=SimulatedSite(sample_rate=RATE), noise=NoiseSettings.quiet(), gyro_drift=DRIFT)
    start = (0.4, 0.1, 0.3)
    record = simulate_system(truth, 600, rate=RATE, initial_readings=start)
    readings = np.stack([record[f"angle_{g}"] for g in ("platform", "inner", "middle")], axis=1)
    assert np.allclose(readings[0], start, atol=1e-9)
    axis = skew(earth_rate_nav(truth.site.latitude) / EARTH_RATE)
    inertial = truth.platform().dcm_nav_to_platform(readings) @ earth_rotation(axis, record["time"]).swapaxes(1, 2)
    rate = small_angle_vector(inertial[-1] @ inertial[0].T) / record["time"][-1]
    assert np.allclose(rate, -eps(truth), atol=1e-12)
    assert np.ptp(readings[:, 1]) > 1e-3  # not polar: the Earth's turn moves more than the platform gimbal


def test_middle_flip_reverses_the_polar_axis():
    truth = Truth.draw(8, site=SimulatedSite(sample_rate=RATE), noise=NoiseSettings.quiet())
    record = simulate_system(truth, 1857, rate=RATE, turns=THREE)
    f_z = record["f_z"]
    assert f_z[100] > 6.0 and f_z[-100] < -6.0  # g sin L, then −g sin L
    assert abs(record["angle_middle"][-1] - record["angle_middle"][0] - math.pi) < 1e-3
    assert np.all(np.abs(np.diff(record["angle_platform"])) < 0.2)  # continuous readings


def test_turns_checked():
    with pytest.raises(ValueError, match="before the previous one ends"):
        simulate_system(Truth.draw(1), 100, rate=RATE, turns=(PlatformTurn(10, 1.0), PlatformTurn(12, 1.0)))
    with pytest.raises(ValueError, match="after the record"):
        simulate_system(Truth.draw(1), 100, rate=RATE, turns=(PlatformTurn(95, math.pi),))


# ----------------------------------------------------------------------------- the estimator
@pytest.fixture(scope="module")
def two_position():
    out = []
    for seed in (11, 12, 13):
        truth = Truth.draw(seed, site=SimulatedSite(sample_rate=RATE), gyro_drift=DRIFT, effects=BASE)
        out.append((truth, simulate_system(truth, 1258, rate=RATE, turns=TWO), simulate_system(truth, 1258, rate=RATE)))
    return out


def test_two_position_recovers_drift_despite_base_errors(two_position):
    for truth, indexed, _ in two_position:
        result = fit(truth, indexed)
        z = (result.values - eps(truth)) / result.sigma
        assert np.all(np.abs(z) < 5), z
        assert np.all(np.abs(result.values - eps(truth)) < 0.01 * 0.005 * DEG_PER_HOUR)  # 1 % (criterion 10 %)
        assert result.details.base_separated
        assert len(result.details.holds) == 2


def test_one_position_carries_the_misprojection(two_position):
    """Held at the survey, one position is off by Ω·(u × δ) in the platform frame (derivation in docs/drift-test.md)."""
    for truth, _, plain in two_position:
        result = fit(truth, plain, base="survey")
        assert not result.details.base_separated
        delta = np.array([BASE["tilt_north"], BASE["tilt_east"], BASE["azimuth_error"]])
        latitude = truth.site.latitude
        u = np.array([math.cos(latitude), 0.0, -math.sin(latitude)])
        misprojection = EARTH_RATE * np.cross(u, delta)  # NED; the platform is polar-aligned at St ≈ 0
        size = np.linalg.norm(misprojection)
        error = result.values - eps(truth)
        assert np.hypot(error[0], error[1]) > 0.5 * size  # tens of % of 0.005 °/h
        assert abs(np.hypot(error[0], error[1]) - size) < 0.35 * size  # offset residuals (2″) and ang1 add a little
        assert abs(error[2]) < 0.05 * size


def test_three_position_separates_g_sensitive_polar_drift():
    truth = Truth.draw(14, site=SimulatedSite(sample_rate=RATE), gyro_drift=DRIFT, effects={**BASE, "Dg_zz": 1e-9})
    three = fit(truth, simulate_system(truth, 1857, rate=RATE, turns=THREE))
    z = (three.values - eps(truth)) / three.sigma
    assert np.all(np.abs(z) < 5), z
    value, sigma = three.details.nuisance["Dg_zz"]
    assert abs(value - 1e-9) < 5 * sigma
    two = fit(truth, simulate_system(truth, 1258, rate=RATE, turns=TWO))
    g_sin = truth.site.gravity * math.sin(truth.site.latitude)
    assert abs(two.values[2] - (eps(truth)[2] + 1e-9 * g_sin)) < 5 * two.sigma[2]  # rate −(ε_z + Dg_zz f_z)
    assert any("Dg_zz" in line and "estimated" in line for line in three.details.rank)
    assert any("drift-three-position separates" in line for line in two.details.rank)


def test_rank_report_names_the_gauge(two_position):
    truth, indexed, _ = two_position[0]
    rank = fit(truth, indexed).details.rank
    assert any("not observable" in line and "gauge: held at the survey" in line for line in rank)


def test_find_holds_cuts_the_turn(two_position):
    truth, indexed, _ = two_position[0]
    readings = np.stack([indexed[f"angle_{g}"] for g in ("platform", "inner", "middle")], axis=1)
    holds = find_holds(indexed["time"], readings)
    assert len(holds) == 2
    assert indexed["time"][holds[0][1] - 1] < 600.0 and indexed["time"][holds[1][0]] > TWO[0].end


# ----------------------------------------------------------------------------- procedures, CLI, bad input
def test_procedures_ship_with_their_index():
    two = load_procedure("drift-two-position")
    assert two.record.duration <= 21 * 60 and len(two.record.turns) == 1
    three = load_procedure("drift-three-position")
    assert [t.axis for t in three.record.turns] == [IndexAxis.PLATFORM, IndexAxis.MIDDLE]
    plan = plan_from_definition(three)
    assert Plan.from_dict(json.loads(json.dumps(plan.to_dict()))) == plan


def test_index_beyond_the_record_is_refused(tmp_path):
    from stableins.procedures.definition import PROCEDURE_DIRECTORY

    text = (PROCEDURE_DIRECTORY / "drift-two-position.toml").read_text().replace("at = 600.0", "at = 1250.0")
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(InputError) as error:
        load_procedure(path)
    assert error.value.field == "record.index" and str(path) in str(error.value)


def prior_record(truth):
    terms = tuple(CORE_TERMS) + tuple(GIMBAL_TERMS)
    fit_ = FitResult(
        "fine",
        terms,
        np.array([float(truth.installed_calibration.get(t.id, t.reference)) for t in terms]),
        np.diag([(2e-6 if t.id.startswith("theta") else t.nominal * 0.05) ** 2 for t in terms]),
        ("estimated",) * len(terms),
        np.zeros(0),
        np.zeros(0),
    )
    return CalibrationRecord.from_fit_result(fit_, RunInfo(procedure="device-fine"), serial_number=truth.site.serial_number)


def write(path, truth, turns, duration):
    with SystemRecordWriter(path, truth.site) as writer:
        for chunk in indexed_record_chunks(truth, duration, turns, rate=RATE):
            writer.append(chunk)


def parse(argv):
    parser = argparse.ArgumentParser()
    calibrate_drift.configure(parser)
    parser.add_argument("--json", action="store_true")
    return parser.parse_args(argv)


def test_cli_updates_the_record(tmp_path, capsys):
    truth = Truth.draw(15, site=SimulatedSite(sample_rate=RATE), gyro_drift=DRIFT, effects=BASE)
    write(tmp_path / "system.h5", truth, TWO, 1258)
    prior = tmp_path / "prior.json"
    before = prior_record(truth)
    before.save(prior)
    out = tmp_path / "cal2.json"
    assert calibrate_drift.run(parse([str(tmp_path), "--prior", str(prior), "--out", str(out)])) == 0
    text = capsys.readouterr().out
    assert "gyro_drift_x" in text and "accelerometer cross-check" in text
    after = CalibrationRecord.load(out)
    for axis in "xyz":
        p = after[f"gyro_drift_{axis}"]
        assert abs(p.value - truth.gyro_drift[axis]) < 5 * p.sigma
    for pid in before.ids:  # a Bayesian update: no σ grows, nothing the drift does not see moves
        assert after[pid].sigma <= before[pid].sigma * (1 + 1e-12)
        assert after[pid].value == pytest.approx(before[pid].value, abs=1e-12 * max(1.0, abs(before[pid].value)))


def test_cli_refuses_a_record_without_an_index(tmp_path):
    truth = Truth.draw(16, site=SimulatedSite(sample_rate=RATE), gyro_drift=DRIFT)
    write(tmp_path / "system.h5", truth, (), 700)
    prior = tmp_path / "prior.json"
    prior_record(truth).save(prior)
    with pytest.raises(InputError) as error:
        calibrate_drift.run(parse([str(tmp_path / "system.h5"), "--prior", str(prior), "--out", str(tmp_path / "out.json")]))
    assert error.value.field == "angle_platform" and "system.h5" in str(error.value)
    assert not (tmp_path / "out.json").exists()


def test_cli_refuses_another_units_prior(tmp_path):
    truth = Truth.draw(17, site=SimulatedSite(sample_rate=RATE))
    write(tmp_path / "system.h5", truth, TWO, 1258)
    other = Truth.draw(18, site=SimulatedSite(serial_number="OTHER-1"))
    prior = tmp_path / "prior.json"
    prior_record(other).save(prior)
    with pytest.raises(InputError) as error:
        calibrate_drift.run(parse([str(tmp_path), "--prior", str(prior), "--out", str(tmp_path / "out.json")]))
    assert error.value.field == "serial_number"
    assert not (tmp_path / "out.json").exists()


def test_record_level_entry_refuses_one_hold(tmp_path):
    truth = Truth.draw(19, site=SimulatedSite(sample_rate=RATE))
    write(tmp_path / "one.h5", truth, (), 300)
    from stableins.data.system import open_system_record

    with pytest.raises(InputError, match="no index"):
        drift_from_record(open_system_record(tmp_path / "one.h5"), truth.installed_calibration)
