"""``stableins calibrate system``: HDF5 record + prior record in, updated record out; user errors exit 2."""

import argparse

import numpy as np
import pytest
from system_synthetic import paper_residuals, record

from stableins.commands import calibrate_system
from stableins.data.errors import InputError
from stableins.data.system import SystemRecordWriter
from stableins.errormodel import CORE_TERMS
from stableins.records import CalibrationRecord, Parameter, Provenance


def prior_record(values, serial="SYN-1"):
    terms = [t for t in CORE_TERMS]
    params = tuple(Parameter(t.id, float(values.get(t.id, t.reference)), t.si_unit, t.nominal, "estimated") for t in terms)
    return CalibrationRecord(serial, params, np.diag([t.nominal**2 for t in terms]), Provenance("test", stages=("fine",)))


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
    assert "system" in updated.provenance.stages
    assert updated["beta_zy"].status == "estimated"
    # bias_x is only seen through b_x/g - beta_xy*sinL: the stage shares that correction by prior
    # variances, so the record keeps the prior's status for it (the stage's own result says "gauge")
    previous = CalibrationRecord.load(prior)
    assert updated["bias_x"].status == previous["bias_x"].status
    assert updated["bias_x"].value != previous["bias_x"].value
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
    assert doc["rank"] == 9


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
