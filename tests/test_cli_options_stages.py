"""``calibrate drift`` and ``calibrate thermal``'s options in successful runs, effects asserted (issue 31).

One simulated drift-two-position run (``stableins run`` on the simulated platform) and one device-thermal session;
each option is compared with the calibration without it.  ``--new-calibration`` and ``--set`` are the shared
record options of every stage (``stableins.commands.stage_record``), checked here on both commands.
tests/test_cli_options.py maps the options to these tests.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from inprocess import run_cli
from test_cli_options_quiet import quiet_main

from stableins.records import CalibrationRecord


def _shared_record_options(prior: Path, base: Path, out: Path) -> None:
    """--new-calibration starts a calibration of its own (the base run continued the prior's); --set enters a value."""
    prior_record, continued, started = (CalibrationRecord.load(p) for p in (prior, base, out))
    assert continued.calibration.id == prior_record.calibration.id
    assert started.calibration.id != prior_record.calibration.id and started.calibration.prior is not None  # --new-calibration
    assert ("laboratory", "Lab O") in [(e.key, e.value) for e in started.calibration.entries]  # --set
    assert ("laboratory", "Lab O") not in [(e.key, e.value) for e in continued.calibration.entries]


# --------------------------------------------------------------------------- calibrate drift
@pytest.fixture(scope="module")
def drift_run(tmp_path_factory):
    from systematic_world import prior_record
    from test_run_truth import drift_world

    from stableins.data.truth import save_truth

    root = tmp_path_factory.mktemp("drift-options")
    truth = drift_world(3)
    save_truth(truth, root / "truth.json")
    prior_record(truth).save(root / "cal.json")
    argv = ["run", "drift-two-position", "--driver", "sim", "--truth", root / "truth.json", "--prior", root / "cal.json",
            "--out", root / "run", "--yes", "--quiet"]  # fmt: skip
    assert run_cli(argv)[0] == 0
    return root


def test_calibrate_drift_options(drift_run, tmp_path, monkeypatch):
    """--json, --one-position (the base held at its survey), --new-calibration, --set, --quiet."""
    run, prior = drift_run / "run", drift_run / "cal.json"
    status, out, err = run_cli(["calibrate", "drift", run, "--prior", prior, "--out", tmp_path / "base.json", "--json"])
    assert status == 0, err[-1000:]
    base = json.loads(out)  # --json: one document, the record's numbers in °/h
    assert base["out"] == str(tmp_path / "base.json") and set(base["gyro_drift_deg_per_hour"]) == {f"gyro_drift_{a}" for a in "xyz"}
    argv = ["calibrate", "drift", run, "--prior", prior, "--out", tmp_path / "one.json", "--one-position", "--json"]
    status, out, err = run_cli(argv)
    assert status == 0, err[-1000:]
    one = json.loads(out)
    assert (base["settings"]["base"], one["settings"]["base"]) == ("auto", "survey")  # --one-position
    assert "tilt_east" in base["settings"]["nuisances"] and "tilt_east" not in one["settings"]["nuisances"]
    argv = ["calibrate", "drift", run, "--prior", prior, "--out", tmp_path / "new.json", "--new-calibration", "--set", "laboratory=Lab O"]
    assert run_cli(argv)[0] == 0
    _shared_record_options(prior, tmp_path / "base.json", tmp_path / "new.json")
    argv = ["calibrate", "drift", run, "--prior", prior, "--out", tmp_path / "quiet.json", "--quiet"]
    status, _, err, seen = quiet_main(monkeypatch, argv, "stableins.commands.calibrate_drift")
    assert status == 0 and seen == [True], err[-1000:]  # --quiet: silenced while it works


# --------------------------------------------------------------------------- calibrate thermal
@pytest.fixture(scope="module")
def thermal_session(tmp_path_factory):
    from test_thermal_sensitivity import CYCLE, _prior_record, _truth, session

    from stableins.data.device import save_device

    root = tmp_path_factory.mktemp("thermal-options")
    truth = _truth(7, CYCLE)
    data = session(truth, 7)
    save_device(root / "device.h5", data.columns, data.metadata)
    _prior_record(truth).save(root / "prior.json")
    return root


def test_calibrate_thermal_options(thermal_session, tmp_path, monkeypatch):
    """--json (the sensitivities with σ), --new-calibration, --set, --quiet."""
    from stableins.conventions import MICRO_G, PPM
    from stableins.estimators.thermal_sensitivity import THERMAL_TERM_IDS

    prior = thermal_session / "prior.json"
    status, out, err = run_cli(["calibrate", "thermal", thermal_session, "--prior", prior, "--out", tmp_path / "base.json", "--json"])
    assert status == 0, err[-1000:]
    document = json.loads(out)  # --json: the document, the same numbers as the record
    record = CalibrationRecord.load(tmp_path / "base.json")
    assert set(document["sensitivities"]) == set(THERMAL_TERM_IDS)
    for pid, entry in document["sensitivities"].items():  # µg/K and ppm/K; the prior had none, so the record holds the fit
        scale = MICRO_G if entry["unit"] == "ug/K" else PPM
        assert entry["value"] * scale == pytest.approx(record[pid].value, rel=1e-9) and entry["sigma"] * scale == pytest.approx(
            record[pid].sigma
        )
    argv = ["calibrate", "thermal", thermal_session, "--prior", prior, "--out", tmp_path / "new.json", "--new-calibration",
            "--set", "laboratory=Lab O"]  # fmt: skip
    assert run_cli(argv)[0] == 0
    _shared_record_options(prior, tmp_path / "base.json", tmp_path / "new.json")
    argv = ["calibrate", "thermal", thermal_session, "--prior", prior, "--out", tmp_path / "quiet.json", "--quiet"]
    status, _, err, seen = quiet_main(monkeypatch, argv, "stableins.commands.calibrate_thermal")
    assert status == 0 and seen == [True], err[-1000:]
