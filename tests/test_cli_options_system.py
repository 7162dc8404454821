"""``calibrate system``'s options (and ``--allow-gaps`` of check and diagnose) in successful runs, effects asserted (issue 31).

One paper-residual static record (the fuzz workspace's, a few seconds per calibration) is calibrated with and
without each option; the record written says what the stage did (its settings, parameters, calibration), so each
option is checked where it lands.  tests/test_cli_options.py maps the options to these tests.
"""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
from inprocess import run_cli

from stableins.records import CalibrationRecord


@pytest.fixture(scope="module")
def ws(fuzz_workspace):
    return fuzz_workspace  # tests/conftest.py: built once per process


@pytest.fixture(scope="module")
def base(ws, tmp_path_factory):
    """The calibration without options: the record the option runs are compared with."""
    out = tmp_path_factory.mktemp("system-base") / "base.json"
    assert run_cli(["calibrate", "system", ws.system_h5, "--prior", ws.record, "--out", out])[0] == 0
    return CalibrationRecord.load(out)


def _values(record: CalibrationRecord) -> dict[str, float]:
    return {p.id: p.value for p in record.parameters}


def test_calibrate_system_model_options(ws, base, tmp_path):
    """--case-rotation-period, --no-couplings, --no-loop-compensation, --estimate-k2, --chunk-rows, --set, --new-calibration."""
    out = tmp_path / "options.json"
    argv = ["calibrate", "system", ws.system_h5, "--prior", ws.record, "--out", out, "--case-rotation-period", "600", "--no-couplings",
            "--no-loop-compensation", "--estimate-k2", "--chunk-rows", "4096", "--set", "laboratory=Lab S",
            "--new-calibration"]  # fmt: skip
    status, _, err = run_cli(argv)
    assert status == 0, err[-1000:]
    record = CalibrationRecord.load(out)
    settings, before = record.stages_run[-1].settings, base.stages_run[-1].settings
    assert (before.options.case_rotation_period, settings.options.case_rotation_period) == (480.0, 600.0)  # --case-rotation-period
    assert before.options.couplings and not settings.options.couplings  # --no-couplings
    assert before.options.compensate_loop and not settings.options.compensate_loop  # --no-loop-compensation
    assert settings.options.chunk_rows == 4096 != before.options.chunk_rows  # --chunk-rows
    assert not before.options.estimate_k2 and settings.options.estimate_k2  # --estimate-k2: K2_x, K2_y from the third harmonic
    assert base["K2_x"].value == 0.0 and record["K2_x"].value != 0.0 and record["K2_x"].sigma <= base["K2_x"].sigma
    assert ("laboratory", "Lab S") in [(e.key, e.value) for e in record.calibration.entries]  # --set
    prior = CalibrationRecord.load(ws.record)
    assert base.calibration.id == prior.calibration.id  # without --new-calibration the stage continues the prior's calibration
    assert record.calibration.id != prior.calibration.id and record.provenance.stages == ("system",)  # --new-calibration
    changed = [k for k, v in _values(record).items() if k in _values(base) and v != _values(base)[k]]
    assert {"sf_x", "bias_x", "beta_zy"} <= set(changed)  # the paper's (biased) quasi-static reading moves the estimates


def test_calibrate_system_chunk_rows_do_not_change_the_result(ws, base, tmp_path):
    """--chunk-rows: the record is streamed in chunks of that many rows; the estimates agree within 1 % of their σ."""
    out = tmp_path / "chunked.json"
    status, _, err = run_cli(["calibrate", "system", ws.system_h5, "--prior", ws.record, "--out", out, "--chunk-rows", "1024"])
    assert status == 0, err[-1000:]
    record = CalibrationRecord.load(out)
    assert record.stages_run[-1].settings.options.chunk_rows == 1024
    for p in base.parameters:
        assert abs(record[p.id].value - p.value) <= 0.01 * p.sigma, p.id


def test_calibrate_system_gyro_drift_and_noise_options(ws, base, tmp_path):
    """--gyro-drift with --gyro-drift-uncertainty: combined with the gimbal readings; --noise: that record's noise model."""
    from fuzzing import _record

    from stableins.noise import NoiseModel

    out = tmp_path / "drift.json"
    argv = ["calibrate", "system", ws.system_h5, "--prior", ws.record, "--out", out, "--gyro-drift", "0.01", "0", "0",
            "--gyro-drift-uncertainty", "0.0001", "--json"]  # fmt: skip
    status, stdout, err = run_cli(argv)
    assert status == 0, err[-1000:]
    record = CalibrationRecord.load(out)
    settings = record.stages_run[-1].settings
    assert settings.options.known_gyro_drift == pytest.approx([np.radians(0.01) / 3600, 0.0, 0.0])  # --gyro-drift [°/h] in SI
    assert settings.options.gyro_drift_uncertainty == pytest.approx(np.radians(0.0001) / 3600)  # --gyro-drift-uncertainty
    assert base.stages_run[-1].settings.options.known_gyro_drift is None
    assert (base.stages_run[-1].settings.gyro_drift_source, settings.gyro_drift_source) == (
        "gimbal readings",
        "given and gimbal readings",
    )
    # the given drift is combined with the readings' measurement (without it: the base record), information-weighted
    given, sigma_given = np.radians(0.01) / 3600, np.radians(0.0001) / 3600
    read, sigma_read = base["gyro_drift_x"].value, base["gyro_drift_x"].sigma
    combined = (read / sigma_read**2 + given / sigma_given**2) / (1 / sigma_read**2 + 1 / sigma_given**2)
    assert record["gyro_drift_x"].value == pytest.approx(combined, rel=0.01) and combined > 10 * abs(read)
    assert json.loads(stdout)["out"] == str(out)

    model = NoiseModel.given(3e-4, 1e-5, 2e-7, provenance="noise record for the options test")
    noisy = tmp_path / "noise.json"
    replace(_record(ws.serial), noise_model=model).save(noisy)
    out = tmp_path / "noise-out.json"
    status, _, err = run_cli(["calibrate", "system", ws.system_h5, "--prior", ws.record, "--out", out, "--noise", noisy])
    assert status == 0, err[-1000:]
    written = CalibrationRecord.load(out).noise_model
    assert "noise record for the options test" in written.provenance  # --noise: the model of that record
    np.testing.assert_array_equal(written.values("random_walk"), model.values("random_walk"))
    assert base.noise_model is None or "noise record for the options test" not in base.noise_model.provenance


@pytest.fixture(scope="module")
def gapped(tmp_path_factory):
    """The workspace's static record with 100 s cut out of its middle (a gap in the time column)."""
    import system_synthetic

    from stableins.data.system import SystemRecordWriter

    true, installed = system_synthetic.paper_residuals()
    columns, meta = system_synthetic.record(true, installed, rate=1.0, seed=4)
    keep = np.ones(len(columns["time"]), bool)
    keep[len(keep) // 2 : len(keep) // 2 + 100] = False
    path = tmp_path_factory.mktemp("gapped") / "gapped.h5"
    with SystemRecordWriter(path, meta, chunk_samples=2048) as writer:
        writer.append({k: np.asarray(v)[keep] for k, v in columns.items()})
    return path


def test_allow_gaps_lets_check_calibrate_and_diagnose_read_a_gapped_record(ws, gapped, tmp_path):
    """Without --allow-gaps the gap is refused (exit 2, naming the row); with it each command reads the record, warned."""
    status, _, err = run_cli(["check", gapped])
    assert status == 2 and "gap" in err
    status, stdout, err = run_cli(["check", gapped, "--allow-gaps", "--json"])
    assert status == 0, err[-1000:]
    found = json.loads(stdout)["files"][0]
    assert found["gaps"] == 1 and found["samples"] == 86064  # --allow-gaps: accepted, the one gap of 100 samples reported
    out = tmp_path / "gapped.json"
    assert run_cli(["calibrate", "system", gapped, "--prior", ws.record, "--out", out])[0] == 2 and not out.exists()
    status, _, err = run_cli(["calibrate", "system", gapped, "--prior", ws.record, "--out", out, "--allow-gaps"])
    assert status == 0 and "gap" in err and out.exists()  # --allow-gaps: calibrated from the samples present, warned
    assert run_cli(["diagnose", gapped, "--record", ws.record])[0] == 2
    status, stdout, err = run_cli(["diagnose", gapped, "--record", ws.record, "--allow-gaps", "--json"])
    assert status == 0, err[-1000:]
    document = json.loads(stdout)  # --allow-gaps: the diagnosis of the gapped record, its 23.93 h without the gap
    assert document["stage"] == "system" and "gapped.h5: 23.93 h" in document["noise_model"]["provenance"] and "gap" in err
