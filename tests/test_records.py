"""Calibration records: build from a FitResult, round trip, validation, stage updates."""

from __future__ import annotations

import hashlib
import json
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from stableins.data.errors import InputError
from stableins.data.metadata import SiteMetadata
from stableins.errormodel import CORE_TERMS, GIMBAL_TERMS
from stableins.estimators.result import STATUSES, FitResult
from stableins.records import STATUSES as RECORD_STATUSES
from stableins.records import CalibrationRecord, file_sha256

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


def test_statuses_agree_with_fit_result():
    assert RECORD_STATUSES == STATUSES


def test_from_fit_result_round_trip(tmp_path):
    data = tmp_path / "session.csv"
    data.write_bytes(b"some bytes")
    result = make_result(statuses=gimbal_statuses())
    record = CalibrationRecord.from_fit_result(
        result, site=SITE, inputs=[data], procedure="wu2018-18pos", data_start="2026-01-01T00:00:00Z"
    )
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
    assert document["schema_version"] == 1 and document["covariance"]["ids"] == list(record.ids)
    assert document["parameters"][-1]["sigma"] is None  # theta30: no number for what the data cannot say
    back = CalibrationRecord.load(path)
    assert back.ids == record.ids and back.site == record.site
    np.testing.assert_array_equal(back.covariance, record.covariance)
    assert [p.value for p in back.parameters] == [p.value for p in record.parameters]
    assert back.provenance == record.provenance and back.notes == record.notes
    assert "INS-0042" in back.report() and "unidentifiable" in back.report()


def test_update_refines_some_parameters_and_keeps_the_rest():
    coarse = CalibrationRecord.from_fit_result(make_result(statuses=gimbal_statuses()), site=SITE)
    fine_terms = tuple(t for t in CORE_TERMS if t.id.startswith(("sf_", "bias_", "K2_")))
    fine = make_result(terms=fine_terms, stage="fine", seed=5)
    merged = coarse.update(fine)
    assert merged.ids == coarse.ids  # order kept
    fine_ids = [t.id for t in fine_terms]
    kept_ids = [i for i in coarse.ids if i not in fine_ids and i != "theta30"]
    np.testing.assert_array_equal(merged.covariance_of(fine_ids), fine.covariance)
    np.testing.assert_array_equal(merged.covariance_of(kept_ids), coarse.covariance_of(kept_ids))
    cross = merged.covariance[np.ix_([merged.ids.index(i) for i in fine_ids], [merged.ids.index(i) for i in kept_ids])]
    assert not cross.any()
    assert merged["K2_x"].value == fine.values[fine_ids.index("K2_x")]
    assert merged["beta_xy"] == coarse["beta_xy"]
    assert merged.provenance.stages == ("coarse", "fine")
    assert "[fine] a note" in merged.notes
    assert merged.merge is not None and CalibrationRecord.merge is CalibrationRecord.update


def test_update_ignores_unidentifiable_and_adds_new_terms():
    coarse = CalibrationRecord.from_fit_result(make_result(), site=SITE)
    later = make_result(terms=CORE_TERMS[:2] + GIMBAL_TERMS[:1], stage="system", statuses=["unidentifiable", "estimated", "estimated"])
    later = FitResult(later.stage, later.terms, later.values, later.covariance, later.status, later.residuals, later.residual_sigma)
    plain = CalibrationRecord.from_fit_result(make_result(terms=CORE_TERMS), site=SITE)
    merged = plain.update(later)
    assert merged["sf_x"] == plain["sf_x"]  # the later stage could not see it
    assert merged.ids[-1] == "theta10" and merged["theta10"].status == "estimated"
    assert coarse.update(later)["sf_y"].value == later.values[1]


def test_update_refuses_another_unit():
    a = CalibrationRecord.from_fit_result(make_result(), site=SITE)
    b = CalibrationRecord.from_fit_result(make_result(), "INS-9999")
    with pytest.raises(InputError, match="different units"):
        a.update(b)


@pytest.fixture
def saved(tmp_path):
    path = CalibrationRecord.from_fit_result(make_result(statuses=gimbal_statuses()), site=SITE).save(tmp_path / "cal.json")
    return path


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
    corrupt(saved, lambda d: d.update(schema_version=2))
    expect_error(saved, "field 'schema_version'", "unknown schema version 2")


@pytest.mark.parametrize("key", ["serial_number", "parameters", "covariance", "provenance"])
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
