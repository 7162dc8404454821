"""``run --driver sim --truth truth.json`` and ``--hidden`` (issue 27): a procedure runs against a known world and its run
directory keeps the truth it ran; the drift test recovers the truth's drift (the 20-seed campaign is
benchmarks/bench_run_truth_drift.py)."""

from __future__ import annotations

import io
import json
import math

import numpy as np
from systematic_world import prior_record

from stableins import cli
from stableins.commands.arguments import effect_magnitude
from stableins.conventions import ARCSEC, DEG_PER_HOUR
from stableins.data.device import load_device
from stableins.data.truth import load_truth, save_truth
from stableins.procedures.journal import start_record
from stableins.procedures.plan import DwellStep, PersonStep, Plan
from stableins.records import CalibrationRecord
from stableins.simulator.truth import SimulatedSite, Truth
from tests.runner_fixtures import SIM_CHECKS, SMALL_MOVES

DRIFT = 0.005  # °/h per axis


def drift_world(seed: int) -> Truth:
    """The issue's world: 0.005 °/h of drift per axis (signs from the seed) and 5″ of base azimuth error, 10 Hz."""
    signs = np.random.default_rng([seed, 27]).choice([-1.0, 1.0], size=3)
    drift = {a: s * DRIFT * DEG_PER_HOUR for a, s in zip("xyz", signs, strict=True)}
    site = SimulatedSite(sample_rate=10.0, serial_number="DRIFT-27")
    return Truth.draw(seed, site=site, effects={"azimuth_error": 5 * ARCSEC}, gyro_drift=drift)


def test_run_with_a_known_truth_keeps_it_and_calibrate_drift_recovers_its_drift(tmp_path, capsys):
    truth = drift_world(3)
    save_truth(truth, tmp_path / "truth.json")
    prior_record(truth).save(tmp_path / "cal.json")
    run = tmp_path / "run"
    argv = ["run", "drift-two-position", "--driver", "sim", "--truth", str(tmp_path / "truth.json"), "--prior", str(tmp_path / "cal.json"),
            "--out", str(run), "--yes", "--quiet"]  # fmt: skip
    assert cli.main(argv) == 0
    kept = load_truth(run / "truth.json")
    assert kept.to_dict() == truth.to_dict()  # the world it ran, in the run directory
    start = start_record(run / "journal.bin")
    assert start is not None and start["truth"] == "truth.json" and "truth.json" in start["inputs"]
    assert cli.main(["calibrate", "drift", str(run), "--prior", str(tmp_path / "cal.json"), "--out", str(tmp_path / "drift.json")]) == 0
    capsys.readouterr()
    for path in (tmp_path / "drift.json", run / "record.json"):  # 'calibrate drift' and the run's own stage: the same estimate
        record = CalibrationRecord.load(path)
        for axis in "xyz":
            p = record[f"gyro_drift_{axis}"]
            assert abs(p.value - truth.gyro_drift[axis]) <= 3 * p.sigma, (path.name, axis, p.value / DEG_PER_HOUR, p.sigma / DEG_PER_HOUR)
            assert p.sigma < 0.1 * DRIFT * DEG_PER_HOUR
    one = CalibrationRecord.load(tmp_path / "drift.json")
    other = CalibrationRecord.load(run / "record.json")
    assert math.isclose(one["gyro_drift_x"].value, other["gyro_drift_x"].value, rel_tol=1e-9)


def test_hidden_effects_are_simulated_and_kept_and_a_resume_simulates_the_same_world(tmp_path, capsys, monkeypatch):
    moves = enumerate(SMALL_MOVES[:3], start=1)
    steps = [DwellStep(f"position {k}", "coarse", 1, k, r, settle=0.5, dwell=1.0, checks=SIM_CHECKS) for k, r in moves]
    steps.append(PersonStep("done", "confirm", "Return the platform to its transport position"))
    plan = tmp_path / "plan.json"
    plan.write_text(json.dumps(Plan("short", "device", tuple(steps), chunk=0.5).to_dict()))
    common = ["--driver", "sim", "--seed", "8", "--unit", "HID-1", "--hidden", "Kcc_xxy=60ug/g2", "--hidden", "azimuth_error=5arcsec"]
    assert cli.main(["run", str(plan), *common, "--out", str(tmp_path / "reference"), "--yes", "--quiet"]) == 0
    kept = load_truth(tmp_path / "reference" / "truth.json")
    assert math.isclose(kept.effects["azimuth_error"], 5 * ARCSEC)
    assert math.isclose(kept.effects["Kcc_xxy"], effect_magnitude("Kcc_xxy=60ug/g2")[1])
    assert kept.site.serial_number == "HID-1" and kept.seed == 8
    # stopped at the last prompt, then resumed: the resume simulates the kept world again (every journaled sample checked)
    monkeypatch.setattr("sys.stdin", io.StringIO("n\n"))
    assert cli.main(["run", str(plan), *common, "--out", str(tmp_path / "run"), "--quiet"]) == 3
    assert cli.main(["run", "--resume", str(tmp_path / "run"), "--yes", "--quiet"]) == 0
    expected = load_device(tmp_path / "reference" / "device.h5").columns
    got = load_device(tmp_path / "run" / "device.h5").columns
    for name in expected:
        np.testing.assert_array_equal(got[name], expected[name], err_msg=name)
    # without the hidden effects the samples differ: the effects reach the data
    assert cli.main(["run", str(plan), *common[:6], "--out", str(tmp_path / "plain"), "--yes", "--quiet"]) == 0
    plain = load_device(tmp_path / "plain" / "device.h5").columns
    assert not np.array_equal(plain["f_x"], expected["f_x"])
    # --truth and --hidden are for the simulated platform only: refused before anything is written
    capsys.readouterr()
    truth = str(tmp_path / "run" / "truth.json")
    bad = ["run", str(plan), "--driver", "tcp://127.0.0.1:9", "--truth", truth, "--out", str(tmp_path / "no")]
    assert cli.main(bad) == 2
    assert "--driver sim" in capsys.readouterr().err and not (tmp_path / "no").exists()
