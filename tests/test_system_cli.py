"""``stableins calibrate system``: HDF5 record + prior record in, updated record out; user errors exit 2."""

import argparse

import numpy as np
import pytest
from system_synthetic import paper_residuals, record

from stableins.commands import calibrate_system
from stableins.data.system import SystemRecordWriter
from stableins.errormodel import CORE_TERMS
from stableins.errors import InputError
from stableins.estimators.result import FitResult
from stableins.noise import NoiseSource
from stableins.records import CalibrationRecord, RunInfo


def prior_record(values, serial="SYN-1"):
    terms = tuple(CORE_TERMS)
    fit = FitResult(
        "fine",
        terms,
        np.array([float(values.get(t.id, t.reference)) for t in terms]),
        np.diag([t.nominal**2 for t in terms]),
        ("estimated",) * len(terms),
        np.zeros(0),
        np.zeros(0),
    )
    return CalibrationRecord.from_fit_result(fit, RunInfo(procedure="device-fine"), serial_number=serial)


def parse(argv):
    parser = argparse.ArgumentParser()
    calibrate_system.configure(parser)
    parser.add_argument("--json", action="store_true")
    return parser.parse_args(argv)


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("cli")
    true, installed = paper_residuals()
    cols, meta = record(true, installed, rate=1.0, seed=21)
    path = tmp / "day.h5"
    with SystemRecordWriter(path, meta, chunk_samples=8192) as writer:
        for start in range(0, cols["time"].size, 20000):
            writer.append({k: v[start : start + 20000] for k, v in cols.items()})
    prior = tmp / "prior.json"
    prior_record(installed).save(prior)
    return tmp, path, prior, true, meta


def test_cli_writes_updated_record(files, capsys):
    tmp, path, prior, true, meta = files
    out = tmp / "cal2.json"
    assert calibrate_system.run(parse([str(path), "--prior", str(prior), "--out", str(out), "--chunk-rows", "8192"])) == 0
    text = capsys.readouterr().out
    assert "combined coefficients" in text and "b_x - beta_xy*sinL" in text
    updated = CalibrationRecord.load(out)
    assert updated.provenance.stages == ("fine", "system")  # the stage continues the prior's calibration
    assert updated.calibration.procedure == "device-fine + system-static"
    assert updated["beta_zy"].status == "estimated"
    # bias_x is only seen through b_x/g - beta_xy*sinL: a posterior (estimated, with σ), determined in combination;
    # the console prints the record's own status and source, the same words as the record and the certificate
    previous = CalibrationRecord.load(prior)
    assert updated["bias_x"].status == "estimated" and updated["bias_x"].sigma < previous["bias_x"].sigma
    assert updated["bias_x"].value != previous["bias_x"].value
    assert updated.source_text("bias_x").startswith("system (in combination")
    line = next(x for x in text.splitlines() if x.startswith("bias_x "))
    assert "estimated" in line and "system (in combination" in line and "gauge" not in text.split("calibration record of")[1]
    stage = updated.stages_run[-1]
    assert stage.sample_rate == 1.0 and stage.settings.options.case_rotation_period == 480.0 and stage.fits[0]["stage"] == "system"
    # beta_zy is determined by itself: the record now holds the truth within 4 sigma
    assert abs(updated["beta_zy"].value - true["beta_zy"]) < 4 * updated["beta_zy"].sigma
    assert updated["K2_x"].value == 0.0  # not touched


def test_cli_json(files, capsys):
    import json

    tmp, path, prior, _, _ = files
    out = tmp / "cal3.json"
    assert calibrate_system.run(parse([str(path), "--prior", str(prior), "--out", str(out), "--json"])) == 0
    doc = json.loads(capsys.readouterr().out)
    assert [c["name"] for c in doc["combined"]][:5] == ["x1", "x2", "x3", "x4", "x5"]
    assert doc["rank"] == 12  # the separation's 9 and the gyro drift's 3 (measured by the gimbal readings)
    record = CalibrationRecord.load(out)
    by_id = {p["id"]: p for p in doc["parameters"]}
    for p in record.parameters:  # JSON = record: value, σ, status, source
        assert by_id[p.id]["status"] == p.status and by_id[p.id]["sigma"] == pytest.approx(p.sigma)
        assert by_id[p.id]["last_determined_by"] == record.source_text(p.id)
        if by_id[p.id]["prior_sigma"] is not None:  # the gyro drift is new: measured by this record, no prior
            assert by_id[p.id]["sigma"] <= by_id[p.id]["prior_sigma"] * (1 + 1e-9)
    assert doc["chi2_red"] == pytest.approx(record.stages_run[-1].fits[0]["chi2_red"])


def test_cli_serial_mismatch_is_a_user_error(files):
    tmp, path, _, _, _ = files
    other = tmp / "other.json"
    prior_record({}, serial="OTHER").save(other)
    out = tmp / "never.json"
    with pytest.raises(InputError, match="serial"):
        calibrate_system.run(parse([str(path), "--prior", str(other), "--out", str(out)]))
    assert not out.exists()


def test_cli_plot(files):
    tmp, path, prior, _, _ = files
    png = tmp / "conv.png"
    assert calibrate_system.run(parse([str(path), "--prior", str(prior), "--out", str(tmp / "cal4.json"), "--plot", str(png)])) == 0
    assert png.stat().st_size > 10_000 and png.read_bytes()[:4] == b"\x89PNG"


def test_cli_noise_model_in_and_out(files, capsys):
    """The record written carries the noise model under the stage's σ; a datasheet model in the prior is used as given."""
    import json
    from dataclasses import replace

    from stableins.noise import NoiseModel

    tmp, path, prior, _, _ = files
    out = tmp / "cal-noise.json"
    assert calibrate_system.run(parse([str(path), "--prior", str(prior), "--out", str(out), "--chunk-rows", "8192", "--json"])) == 0
    data = json.loads(capsys.readouterr().out)
    measured = CalibrationRecord.load(out).noise_model
    assert measured.source is NoiseSource.STATIC_RECORD and measured == NoiseModel.from_document(data["noise_model"])
    assert data["low_frequency_noise"]["source"] == "data" and 0.0 <= data["low_frequency_noise"]["p_value"] <= 1.0
    sheet = NoiseModel.given(1e-4, 2e-5, 1e-7, provenance="datasheet of the unit")
    with_sheet = tmp / "prior-sheet.json"
    replace(CalibrationRecord.load(prior), noise_model=sheet).save(with_sheet)
    out2 = tmp / "cal-sheet.json"
    assert calibrate_system.run(parse([str(path), "--prior", str(with_sheet), "--out", str(out2), "--chunk-rows", "8192", "--json"])) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["low_frequency_noise"]["source"] == "given"
    written = CalibrationRecord.load(out2).noise_model
    assert written.source is NoiseSource.DATASHEET
    np.testing.assert_array_equal(written.values("bias_instability"), sheet.values("bias_instability"))
    assert not np.allclose(written.values("white"), sheet.values("white"))  # the white noise is the record's
    assert CalibrationRecord.load(out2).stages_run[-1].settings.noise_source is NoiseSource.DATASHEET
    # datasheet flags on the command line: the same, without a record carrying them
    out3 = tmp / "cal-flags.json"
    argv = [str(path), "--prior", str(prior), "--out", str(out3), "--chunk-rows", "8192"]
    argv += ["--bias-instability", "2", "--random-walk", "1e-7"]
    assert calibrate_system.run(parse(argv)) == 0
    flags = CalibrationRecord.load(out3).noise_model
    assert flags.source is NoiseSource.DATASHEET and flags.values("random_walk")[0] == 1e-7


def test_cli_thermal_prior_and_json_thermal(files, capsys):
    """--thermal-prior sets the thermal terms' prior; --json carries the thermal model; a bad prior exits 2 (argparse)."""
    import json

    tmp, path, prior, _, _ = files
    out = tmp / "cal-thermal.json"
    argv = [str(path), "--prior", str(prior), "--out", str(out), "--json", "--thermal-prior", "2", "3"]
    assert calibrate_system.run(parse(argv)) == 0
    thermal = json.loads(capsys.readouterr().out)["thermal"]
    assert thermal["terms"][0] == "Kt_bias_x" and thermal["prior_sigma"] == pytest.approx([2, 2, 2, 3, 3, 3])
    assert thermal["not_separable"] == [] and "temperature" in thermal["note"]
    with pytest.raises(SystemExit) as exc:
        parse([str(path), "--prior", str(prior), "--out", str(out), "--thermal-prior", "-1", "5"])
    assert exc.value.code == 2


def test_the_records_thermal_sensitivities_are_the_thermal_prior_not_a_compensation(files):
    """A record carrying Kt_bias/Kt_sf from ``calibrate thermal`` (issue 25): the system stage takes their values and σ
    as its thermal prior (the INS does not compensate temperature), runs, and leaves them as they were."""
    from stableins.conventions import MICRO_G, PPM
    from stableins.discovery.library import LIBRARY
    from stableins.estimators.thermal_sensitivity import THERMAL_TERM_IDS

    tmp, path, prior, _, _ = files
    terms = tuple(LIBRARY[i].term for i in THERMAL_TERM_IDS)
    values = np.array([2 * MICRO_G] * 3 + [1 * PPM] * 3)
    sigma = np.array([0.3 * MICRO_G] * 3 + [0.3 * PPM] * 3)
    from stableins.estimators.result import Likelihood

    likelihood = Likelihood(THERMAL_TERM_IDS, values, np.diag(sigma**-2), np.zeros(6))
    thermal = FitResult("thermal", terms, values, np.diag(sigma**2), ("estimated",) * 6, np.zeros(0), np.zeros(0), likelihood=likelihood)
    with_kt = tmp / "prior-kt.json"
    CalibrationRecord.load(prior).updated(thermal, RunInfo(procedure="device-thermal")).save(with_kt)
    out = tmp / "cal-kt.json"
    assert calibrate_system.run(parse([str(path), "--prior", str(with_kt), "--out", str(out), "--chunk-rows", "8192"])) == 0
    written = CalibrationRecord.load(out)
    for pid, v, s in zip(THERMAL_TERM_IDS, values, sigma, strict=True):
        assert written[pid].value == pytest.approx(v) and written[pid].sigma == pytest.approx(s)
