"""Calibration records: build from a FitResult, round trip, validation, stage updates."""

from __future__ import annotations

import hashlib
import json
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from stableins.errormodel import CORE_TERMS, GIMBAL_TERMS
from stableins.errors import InputError, NotDeterminedError
from stableins.estimators.result import FitResult, Likelihood
from stableins.records import CalibrationRecord, RunInfo, file_sha256, parse_entries
from stableins.site import SiteMetadata

SITE = SiteMetadata("INS-0042", math.radians(45.0), 30.0, 9.8062, "WGS-84 normal gravity", 100.0)


def make_result(terms=CORE_TERMS + GIMBAL_TERMS, stage="coarse", seed=0, statuses=None) -> FitResult:
    rng = np.random.default_rng(seed)
    n = len(terms)
    scale = np.array([t.nominal for t in terms]) * 0.05
    a = rng.normal(size=(n, n + 3))
    covariance = (a @ a.T / n) * np.outer(scale, scale)
    statuses = list(statuses or ["estimated"] * n)
    for k, s in enumerate(statuses):
        if s == "gauge":
            covariance[k, :] = covariance[:, k] = 0.0
    values = np.array([t.reference + rng.normal() * t.nominal for t in terms])
    return FitResult(stage, tuple(terms), values, covariance, tuple(statuses), rng.normal(size=20), np.ones(20), rank=n, notes=("a note",))


def gimbal_statuses():
    ids = [t.id for t in CORE_TERMS + GIMBAL_TERMS]
    return ["gauge" if i == "theta10" else "unidentifiable" if i == "theta30" else "estimated" for i in ids]


def test_from_fit_result_round_trip(tmp_path):
    data = tmp_path / "session.csv"
    data.write_bytes(b"some bytes")
    result = make_result(statuses=gimbal_statuses())
    run = RunInfo(inputs=[data], procedure="wu2018-18pos", data_start="2026-01-01T00:00:00Z")
    record = CalibrationRecord.from_fit_result(result, run, site=SITE)
    assert record.serial_number == "INS-0042"
    assert record.provenance.inputs[0].sha256 == hashlib.sha256(b"some bytes").hexdigest() == file_sha256(data)
    assert record.provenance.stages == ("coarse",) and record.provenance.software.startswith("stableins ")
    sf = record["sf_x"]
    assert sf.unit == "1" and sf.value == result.values[0] and sf.sigma == pytest.approx(result.sigma[0], rel=1e-15)
    assert record["bias_y"].unit == "m/s^2" and record["beta_zx"].unit == "rad" and record["K2_z"].unit == "s^2/m"
    assert record["theta10"].status == "gauge" and record["theta10"].sigma == 0.0
    assert record["theta30"].status == "unidentifiable" and math.isnan(record["theta30"].sigma)
    path = record.save(tmp_path / "cal.json")
    document = json.loads(path.read_text())
    assert document["schema_version"] == 2 and document["covariance"]["ids"] == list(record.ids)
    assert document["parameters"][-1]["sigma"] is None  # theta30: no number for what the data cannot say
    back = CalibrationRecord.load(path)
    assert back.ids == record.ids and back.site == record.site
    np.testing.assert_array_equal(back.covariance, record.covariance)
    assert [p.value for p in back.parameters] == [p.value for p in record.parameters]
    assert back.provenance == record.provenance and back.notes == record.notes
    assert "INS-0042" in back.report() and "unidentifiable" in back.report()


def as_likelihood(result: FitResult) -> FitResult:
    """The result with the likelihood of a data-only estimate: information P⁻¹ at its values."""
    from dataclasses import replace

    ids = result.ids
    return replace(result, likelihood=Likelihood(ids, result.values, np.linalg.inv(result.covariance), np.zeros(len(ids))))


def test_update_is_bayesian_and_keeps_what_the_stage_does_not_see():
    coarse = CalibrationRecord.from_fit_result(make_result(statuses=gimbal_statuses()), RunInfo(procedure="device-coarse"), site=SITE)
    fine_terms = tuple(t for t in CORE_TERMS if t.id.startswith(("sf_", "bias_", "K2_")))
    fine = as_likelihood(make_result(terms=fine_terms, stage="fine", seed=5))
    merged = coarse.updated(fine, RunInfo(procedure="device-fine", entries=parse_entries(["site_temperature=21.5 degC"])))
    assert merged.ids == coarse.ids  # order kept
    fine_ids = [t.id for t in fine_terms]
    # the posterior is the Kalman update of the coarse record by the fine estimate (H selects the fine ids)
    keep = [i for i in coarse.ids if coarse[i].status == "estimated"]
    p0 = coarse.covariance_of(keep)
    h = np.array([[1.0 if k == f else 0.0 for k in keep] for f in fine_ids])
    gain = p0 @ h.T @ np.linalg.inv(h @ p0 @ h.T + fine.covariance)
    expected = np.array([coarse[k].value for k in keep]) + gain @ (fine.values - h @ [coarse[k].value for k in keep])
    np.testing.assert_allclose([merged[k].value for k in keep], expected, rtol=0, atol=1e-12)
    np.testing.assert_allclose(merged.covariance_of(keep), p0 - gain @ h @ p0, rtol=0, atol=1e-9 * np.abs(p0).max())
    for p in merged.parameters:  # no σ grows
        assert not (p.sigma > coarse[p.id].sigma * (1 + 1e-9)), p.id
    assert merged["theta10"] == coarse["theta10"] and merged["theta30"].status == "unidentifiable"
    assert merged.provenance.stages == ("coarse", "fine") and merged.calibration.procedure == "device-coarse + device-fine"
    assert [d.how for d in merged["K2_x"].determined_by] == ["alone", "alone"]  # coarse, then fine
    assert len(merged["beta_xy"].determined_by) == 1 and merged.last_determined_by("beta_xy")[0].name == "coarse"
    assert merged.entries[0].text() == "21.5 °C" and merged.stages_run[-1].entries[0].prompt == ""
    assert "[fine] a note" in merged.notes
    back = CalibrationRecord.from_document(json.loads(json.dumps(merged.to_document())))
    assert back.stages == merged.stages and back.parameters == merged.parameters


def test_a_recalibration_starts_a_new_calibration_and_carries_the_rest_over():
    from stableins.records import PriorReference

    coarse = CalibrationRecord.from_fit_result(make_result(statuses=gimbal_statuses()), RunInfo(procedure="device-coarse"), site=SITE)
    fine = as_likelihood(make_result(terms=CORE_TERMS[:6], stage="fine", seed=7))
    recal = coarse.updated(fine, RunInfo(procedure="field-recal-device"), new_calibration=True, prior=PriorReference("0" * 64))
    assert recal.calibration.id != coarse.calibration.id and recal.calibration.prior.sha256 == "0" * 64
    assert recal.provenance.stages == ("fine",) and recal.calibration.procedure == "field-recal-device"
    assert recal.measured_in_this_calibration("sf_x") and not recal.measured_in_this_calibration("beta_xy")
    assert recal.source_text("beta_xy").endswith("carried over") and "fine (alone" in recal.source_text("sf_x")


def test_a_stage_that_determines_nothing_writes_no_record():
    coarse = CalibrationRecord.from_fit_result(make_result(), site=SITE)
    blind = make_result(terms=CORE_TERMS[:3], stage="system")
    from dataclasses import replace

    blind = replace(blind, likelihood=Likelihood(blind.ids, blind.values, np.zeros((3, 3)), np.zeros(3)))
    with pytest.raises(NotDeterminedError, match="determine no parameter"):
        coarse.updated(blind)
    with pytest.raises(InputError, match="no likelihood"):
        coarse.updated(make_result(terms=CORE_TERMS[:3], stage="fine"))


def test_version_1_records_are_migrated(tmp_path):
    v2 = CalibrationRecord.from_fit_result(make_result(statuses=gimbal_statuses()), RunInfo(data_end="2026-01-02T00:00:00Z"), site=SITE)
    document = v2.to_document()
    v1 = {k: v for k, v in document.items() if k not in ("calibration", "stages")}
    v1["schema_version"] = 1
    for p in v1["parameters"]:
        p.pop("determined_by")
    v1["provenance"] = {"software": "stableins 0.1.0", "procedure": "p", "stages": ["coarse", "fine"], "inputs": [],
                        "created": "2026-01-02T01:00:00+00:00", "data_start": "", "data_end": "2026-01-02T00:00:00Z"}  # fmt: skip
    (tmp_path / "v1.json").write_text(json.dumps(v1))
    record = CalibrationRecord.load(tmp_path / "v1.json")
    assert record.schema_version == 2 and [s.name for s in record.stages] == ["coarse+fine"]
    assert record.provenance.stages == ("coarse+fine",) and record.provenance.data_end == "2026-01-02T00:00:00Z"
    assert record["sf_x"].determined_by[0].stage == record.stages[0].id and record["theta10"].determined_by == ()
    assert record.stages[0].likelihood is None and "migrated" in record.notes[-1]
    np.testing.assert_array_equal(record.covariance, v2.covariance)
    assert json.loads(record.save(tmp_path / "v2.json").read_text())["schema_version"] == 2


@pytest.fixture
def saved(tmp_path):
    return CalibrationRecord.from_fit_result(make_result(statuses=gimbal_statuses()), site=SITE).save(tmp_path / "cal.json")


def corrupt(path, change):
    document = json.loads(path.read_text())
    change(document)
    path.write_text(json.dumps(document))


def expect_error(path, *fragments):
    with pytest.raises(InputError) as info:
        CalibrationRecord.load(path)
    message = str(info.value)
    assert str(path) in message
    for fragment in fragments:
        assert fragment in message, f"{fragment!r} not in {message!r}"


def test_unknown_schema_version(saved):
    corrupt(saved, lambda d: d.update(schema_version=3))
    expect_error(saved, "field 'schema_version'", "unknown schema version 3")


def test_determined_by_must_name_a_stage_of_the_record(saved):
    corrupt(saved, lambda d: d["parameters"][0]["determined_by"][0].update(stage="fine-00000000"))
    expect_error(saved, "field 'parameters[0].determined_by[0]'", "does not name a stage")


@pytest.mark.parametrize("key", ["serial_number", "parameters", "covariance", "calibration", "stages"])
def test_missing_top_level_key(saved, key):
    corrupt(saved, lambda d: d.pop(key))
    expect_error(saved, f"field '{key}'", "missing key")


def test_missing_parameter_key(saved):
    corrupt(saved, lambda d: d["parameters"][3].pop("sigma"))
    expect_error(saved, "field 'parameters[3].sigma'", "missing key")


def test_bad_status(saved):
    corrupt(saved, lambda d: d["parameters"][2].update(status="guessed"))
    expect_error(saved, "field 'parameters[2].status'", "bad status 'guessed' for 'sf_z'", "estimated or fixed or gauge or unidentifiable")


def test_non_symmetric_covariance(saved):
    def skew(d):
        d["covariance"]["matrix"][0][4] *= 1.5

    corrupt(saved, skew)
    expect_error(saved, "field 'covariance'", "not symmetric", "(sf_x, bias_y)")


def test_not_positive_semidefinite(saved):
    def break_psd(d):
        m = d["covariance"]["matrix"]
        s = math.sqrt(m[0][0] * m[1][1])
        m[0][1] = m[1][0] = 1.5 * s

    corrupt(saved, break_psd)
    expect_error(saved, "not positive semi-definite")


def test_sigma_disagreeing_with_covariance(saved):
    corrupt(saved, lambda d: d["parameters"][5].update(sigma=d["parameters"][5]["sigma"] * 2))
    expect_error(saved, "field 'parameters[5].sigma'", "disagrees with the covariance diagonal")


def test_covariance_ids_out_of_order(saved):
    corrupt(saved, lambda d: d["covariance"]["ids"].reverse())
    expect_error(saved, "field 'covariance.ids'")


def test_null_sigma_only_for_unidentifiable(saved):
    corrupt(saved, lambda d: d["parameters"][0].update(sigma=None))
    expect_error(saved, "covariance of 'sf_x' (estimated) is not finite")


def test_truncated_record(saved):
    text = saved.read_text()
    saved.write_text(text[: len(text) // 2])
    expect_error(saved, "not valid JSON", "truncated")


def test_save_is_atomic(saved, monkeypatch):
    before = saved.read_bytes()
    record = CalibrationRecord.load(saved)

    def crash(*args, **kwargs):  # the new bytes are written, the machine dies before the rename
        raise OSError("power cut")

    monkeypatch.setattr("stableins.data.atomic.os.fsync", crash)
    with pytest.raises(OSError):
        record.save(saved)
    assert saved.read_bytes() == before
    assert [p.name for p in saved.parent.iterdir()] == [saved.name]


def _leaves(value, path=()):
    if isinstance(value, dict):
        for k, v in value.items():
            yield from _leaves(v, path + (k,))
    elif isinstance(value, list):
        for k, v in enumerate(value):
            yield from _leaves(v, path + (k,))
    yield path


json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False) | st.text(max_size=5),
    lambda children: st.lists(children, max_size=3) | st.dictionaries(st.text(max_size=3), children, max_size=3),
    max_leaves=5,
)


@settings(max_examples=150, deadline=None)
@given(st.data())
def test_any_damaged_value_gives_input_error_or_a_valid_record(tmp_path_factory, data):
    record = CalibrationRecord.from_fit_result(make_result(statuses=gimbal_statuses()), site=SITE)
    document = record.to_document()
    paths = [p for p in _leaves(document) if p]
    target = data.draw(st.sampled_from(paths))
    parent = document
    for key in target[:-1]:
        parent = parent[key]
    if data.draw(st.booleans()):
        parent[target[-1]] = data.draw(json_values)
    elif isinstance(parent, dict):
        del parent[target[-1]]
    else:
        parent.pop(target[-1])
    path = tmp_path_factory.mktemp("fuzz") / "cal.json"
    path.write_text(json.dumps(document))
    try:
        CalibrationRecord.load(path)
    except InputError as error:
        assert str(path) in str(error)
