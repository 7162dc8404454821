"""History store (index, record in force, staleness), change significance, drift trends, recalibration with a prior."""

from __future__ import annotations

import math
from datetime import UTC, datetime, timedelta

import numpy as np
import pytest
from inprocess import run_cli

from stableins.errormodel import known_terms
from stableins.errors import InputError
from stableins.estimators.result import FitResult, Likelihood
from stableins.history import compare, format_changes, format_trends, parse_date, plot_trends, trend
from stableins.history_store import HistoryStore
from stableins.records import Calibration, CalibrationRecord, Parameter, PriorReference, RunInfo, StageRun

IDS = ("bias_x", "bias_y", "sf_x")
UNITS = ("m/s^2", "m/s^2", "1")
SIGMA = np.array([2e-5, 3e-5, 5e-6])


def estimate(values, covariance, stage="fine"):
    """A data-only estimate as a stage result: its likelihood has information P⁻¹ at its values."""
    terms = tuple(known_terms()[i] for i in IDS)
    values, covariance = np.asarray(values, dtype=float), np.asarray(covariance, dtype=float)
    likelihood = Likelihood(IDS, values, np.linalg.inv(covariance), np.zeros(len(IDS)))
    return FitResult(stage, terms, values, covariance, ("estimated",) * len(IDS), np.zeros(0), np.zeros(0), likelihood=likelihood)


def make_record(values, covariance, created, serial="INS-7", stages=("fine",), status=None, procedure="device-fine"):
    """A first calibration (no prior) whose stage run took its data until ``created``."""
    status = status or ["estimated"] * len(values)
    sigma = np.sqrt(np.diag(covariance))
    calibration = Calibration(f"cal-{created[:10]}-{abs(hash((created, serial))) % 10**8:08d}", procedure, "stableins test", created)
    run = StageRun(f"{stages[0]}-{abs(hash((created, serial, 1))) % 10**8:08d}", stages[0], calibration.id, procedure, created=created,
                   data_start=created, data_end=created)  # fmt: skip
    parameters = tuple(
        Parameter(
            i, float(v), u, float(s) if st != "unidentifiable" else math.nan, st, ((records_how(run.id),) if st == "estimated" else ())
        )
        for i, v, u, s, st in zip(IDS, values, UNITS, sigma, status)
    )
    cov = np.array(covariance, dtype=float)
    for k, st in enumerate(status):
        if st == "unidentifiable":
            cov[k, :] = np.nan
            cov[:, k] = np.nan
    return CalibrationRecord(serial, parameters, cov, calibration, (run,))


def records_how(stage_id):
    from stableins.records import DeterminedBy
    from stableins.status import Determination

    return DeterminedBy(stage_id, Determination.ALONE)


TRUTH = np.array([1e-4, -2e-4, 1.0 + 50e-6])


def test_store_index_in_force_and_staleness(tmp_path):
    store = HistoryStore(tmp_path / "store")
    rng = np.random.default_rng(3)
    dates = ["2025-01-10T00:00:00+00:00", "2025-06-01T00:00:00+00:00", "2026-02-01T00:00:00+00:00"]
    paths = []
    for k, date in enumerate(dates):
        path = tmp_path / f"r{k}.json"
        make_record(TRUTH + rng.normal(0, SIGMA), np.diag(SIGMA**2), date).save(path)
        paths.append(path)
    for path in (paths[2], paths[0], paths[1]):  # added out of order
        store.add(path)
    assert store.add(paths[1]).file == store.entries("INS-7")[1].file  # the same bytes are added once
    entries = store.entries("INS-7")
    assert [e.valid_from for e in entries] == dates
    assert store.serials() == ["INS-7"]
    assert store.in_force("INS-7", parse_date("2025-03-01")).valid_from == dates[0]
    assert store.in_force("INS-7", parse_date("2025-06-01T00:00:00Z")).valid_from == dates[1]
    assert store.in_force("INS-7", parse_date("2030-01-01")).valid_from == dates[2]
    with pytest.raises(InputError, match="no calibration in force on 2024"):
        store.in_force("INS-7", parse_date("2024-12-31"))
    with pytest.raises(InputError, match="no calibration records for unit 'OTHER'"):
        store.in_force("OTHER")
    entry = store.in_force("INS-7", parse_date("2026-03-01"))
    assert store.staleness(entry, parse_date("2026-03-01")) is None
    warning = store.staleness(entry, parse_date("2026-12-01"), max_age=timedelta(days=180))
    assert warning and "303 days old" in warning
    # the stored record is the record, byte for byte
    assert (store.root / "INS-7" / entry.file).read_bytes() == paths[2].read_bytes()


def test_bad_inputs(tmp_path):
    store = HistoryStore(tmp_path)
    with pytest.raises(InputError, match="cannot name a history folder"):
        store.entries("../etc")
    with pytest.raises(InputError, match="as a date"):
        parse_date("yesterday")
    (tmp_path / "X").mkdir()
    (tmp_path / "X" / "index.json").write_text("{not json")
    with pytest.raises(InputError, match="history index unreadable"):
        store.entries("X")


def test_trend_significance_is_standard_normal_without_drift():
    rng = np.random.default_rng(11)
    times = [datetime(2024, 1, 1, tzinfo=UTC) + timedelta(days=d) for d in (0, 40, 150, 200, 380, 500, 620)]
    sigmas = np.array([1.0, 2.0, 1.0, 1.5, 1.0, 3.0, 1.0]) * 1e-5
    z = []
    for _ in range(2000):
        values = 1e-4 + rng.normal(0, sigmas)
        z.append(trend(list(zip(times, values, sigmas))).significance)
    z = np.array(z)
    # mean 0 ± 3/sqrt(2000), std 1 ± 3 * 1/sqrt(2 * 2000)
    assert abs(z.mean()) < 3 / math.sqrt(2000)
    assert abs(z.std() - 1) < 3 / math.sqrt(4000)


def test_trend_recovers_an_injected_drift():
    rng = np.random.default_rng(12)
    times = [datetime(2024, 1, 1, tzinfo=UTC) + timedelta(days=91 * k) for k in range(9)]
    slope = 4e-5  # per year
    sigma = np.full(9, 1e-5)
    years = np.array([(t - times[0]).days / 365.25 for t in times])
    values = 1e-4 + slope * years + rng.normal(0, sigma)
    result = trend(list(zip(times, values, sigma)), "bias_x", "m/s^2")
    assert abs(result.slope - slope) < 3 * result.slope_sigma
    assert result.significance > 5
    assert result.chi2_red_constant > 3  # a constant does not fit
    assert "drifting" in format_trends([result])


def test_recalibration_change_significance_matches_the_independent_form_and_is_calibrated():
    rng = np.random.default_rng(5)
    p0 = np.diag(SIGMA**2)
    pd = np.diag((0.7 * SIGMA) ** 2)
    z_fused, z_direct = [], []
    for k in range(400):
        x0 = TRUTH + rng.normal(0, SIGMA)
        xd = TRUTH + rng.normal(0, 0.7 * SIGMA)
        old = make_record(x0, p0, "2025-01-01T00:00:00+00:00")
        run = RunInfo(data_end="2025-09-01T00:00:00+00:00")
        fused = old.updated(estimate(xd, pd), run, new_calibration=True, prior=PriorReference("a" * 64))
        comparison = compare(old, fused)
        direct = compare(old, make_record(xd, pd, "2025-09-01T00:00:00+00:00"))
        assert comparison.relation == "descendant" and direct.relation == "independent"
        z_fused.append([c.significance for c in comparison.changes])
        z_direct.append([c.significance for c in direct.changes])
        if k == 0:
            # scalar identity: (x1 - x0)/sqrt(P0 - P1) == (xd - x0)/sqrt(P0 + Pd): one statistic, whatever the relation
            np.testing.assert_allclose(z_fused[0], z_direct[0], rtol=1e-9)
            expected = (x0 / SIGMA**2 + xd / (0.7 * SIGMA) ** 2) / (1 / SIGMA**2 + 1 / (0.7 * SIGMA) ** 2)
            np.testing.assert_allclose([fused[i].value for i in IDS], expected, rtol=1e-12)
            assert fused.provenance.stages == ("fine",) and fused.calibration.prior.sha256 == "a" * 64
            assert format_changes(comparison.changes).count("\n") == 3
    z = np.array(z_fused)
    assert np.all(np.abs(z.mean(axis=0)) < 3 / math.sqrt(400))
    assert np.all(np.abs(z.std(axis=0) - 1) < 3 / math.sqrt(800))
    # the flag |z| ≥ 3: false alarms at 0.27 % per parameter (1200 comparisons: expect 3.2, allow < 12)
    assert (np.abs(z) >= 3).sum() < 12


def test_recalibration_carries_prior_correlations_and_keeps_what_the_data_do_not_see():
    # the new data see only bias_x; bias_y is correlated with it in the prior and must move too
    p0 = np.array([[4e-10, 3e-10, 0], [3e-10, 9e-10, 0], [0, 0, 25e-12]])
    old = make_record(TRUTH, p0, "2025-01-01T00:00:00+00:00")
    new = estimate(TRUTH + [2e-5, 0, 0], np.diag([1e-10, 1.0, 1.0]))
    only_x = Likelihood(IDS, new.values, np.diag([1e10, 0.0, 0.0]), np.zeros(3))
    from dataclasses import replace

    fused = old.updated(replace(new, likelihood=only_x), new_calibration=True)
    gain = p0[0, 0] / (p0[0, 0] + 1e-10)
    assert fused["bias_x"].value == pytest.approx(TRUTH[0] + gain * 2e-5, rel=1e-9)
    assert fused["bias_y"].value == pytest.approx(TRUTH[1] + p0[1, 0] / (p0[0, 0] + 1e-10) * 2e-5, rel=1e-9)
    assert fused["sf_x"].value == TRUTH[2] and fused["sf_x"].sigma == pytest.approx(5e-6)
    assert fused["bias_x"].sigma == pytest.approx(math.sqrt(p0[0, 0] * (1 - gain)), rel=1e-9)
    comparison = compare(old, fused)
    assert [c.id for c in comparison.changes] == ["bias_x"]  # bias_y moved only by correlation; sf_x not at all
    assert any(s.startswith("bias_y: not re-measured") for s in comparison.skipped)
    assert any(s.startswith("sf_x: not re-measured") for s in comparison.skipped)


def test_records_of_two_branches_cannot_be_compared():
    old = make_record(TRUTH, np.diag(SIGMA**2), "2025-01-01T00:00:00+00:00")
    a = old.updated(estimate(TRUTH, np.diag(SIGMA**2)), RunInfo(data_end="2025-02-01T00:00:00+00:00"), new_calibration=True)
    b = old.updated(estimate(TRUTH, np.diag(SIGMA**2), stage="system"), RunInfo(data_end="2025-03-01T00:00:00+00:00"), new_calibration=True)
    with pytest.raises(InputError, match="correlation of their errors is not known"):
        compare(a, b)


def test_history_changes_trends_and_plot(tmp_path):
    store = HistoryStore(tmp_path / "store")
    rng = np.random.default_rng(8)
    for k in range(5):
        date = (datetime(2024, 1, 1, tzinfo=UTC) + timedelta(days=120 * k)).isoformat()
        drifted = TRUTH + np.array([3e-5 * k, 0, 0])  # bias_x drifts 3e-5 per 120 days
        path = tmp_path / f"r{k}.json"
        make_record(drifted + rng.normal(0, SIGMA), np.diag(SIGMA**2), date).save(path)
        store.add(path)
    pairs = store.changes("INS-7")
    assert len(pairs) == 4 and all(len(c.changes) == 3 and c.relation == "independent" for _, _, c in pairs)
    trends = {t.id: t for t in store.trends("INS-7")}
    assert trends["bias_x"].significance > 5
    assert abs(trends["bias_y"].significance) < 3
    fig = plot_trends(list(trends.values()), "INS-7")
    out = tmp_path / "history.png"
    fig.savefig(out)
    assert out.stat().st_size > 1000
    assert len([ax for ax in fig.axes if ax.get_visible()]) == 3


def test_two_records_a_minute_apart_state_no_drift(tmp_path, capsys):
    """55 s between two records cannot carry a drift per year: history prints none (and says why), the plot shows the records."""
    store = HistoryStore(tmp_path / "store")
    rng = np.random.default_rng(3)
    for k, date in enumerate(("2026-11-28T10:00:00+00:00", "2026-11-28T10:00:55+00:00")):
        path = tmp_path / f"r{k}.json"
        make_record(TRUTH + rng.normal(0, SIGMA), np.diag(SIGMA**2), date).save(path)
        store.add(path)
    trends = store.trends("INS-7")
    assert trends and all(t.too_short and math.isnan(t.slope) and math.isnan(t.significance) for t in trends)
    record = HistoryStore(tmp_path / "store").load("INS-7", store.entries("INS-7")[0])
    assert trends[0].record_values[0] == record[trends[0].id].value  # the plot's points are the records' own values
    text = format_trends(trends)
    assert "no drift stated" in text and "55 s" in text and "per year" in text and "ppm" not in text
    from stableins import cli

    assert cli.main(["history", "INS-7", "--store", str(tmp_path / "store"), "--plot", str(tmp_path / "h.png")]) == 0
    out = capsys.readouterr().out
    assert "no drift stated: the records span 55 s" in out and "drifting" not in out
    # 40 days apart: the drift is stated
    late = tmp_path / "late.json"
    make_record(TRUTH + rng.normal(0, SIGMA), np.diag(SIGMA**2), "2027-01-07T10:00:00+00:00").save(late)
    store.add(late)
    assert all(math.isfinite(t.slope) for t in store.trends("INS-7"))


def test_recal_asks_for_the_operator_laboratory_and_customer(tmp_path):
    import json
    from dataclasses import replace

    from stableins.records import CalibrationRecord, parse_entries

    store, rng = tmp_path / "store", np.random.default_rng(4)
    first = make_record(TRUTH + rng.normal(0, SIGMA), np.diag(SIGMA**2), "2025-01-01T00:00:00+00:00")
    first.with_entries(parse_entries(["customer=Navy Yard"])).save(tmp_path / "first.json")
    assert run_cli(["history", "INS-7", "--store", str(store), "--add", str(tmp_path / "first.json")]).returncode == 0
    other = make_record(TRUTH + rng.normal(0, 0.5 * SIGMA), np.diag((0.5 * SIGMA) ** 2), "2026-01-02T00:00:00+00:00")
    run = replace(other.stages[0], likelihood=estimate([p.value for p in other.parameters], other.covariance).likelihood)
    (tmp_path / "estimate.json").write_text(json.dumps(replace(other, stages=(run,)).to_document()))
    argv = ["recal", "--unit", "INS-7", "--store", str(store), "--estimate", str(tmp_path / "estimate.json"), "--no-file"]
    # asked at the terminal: the operator, then the laboratory; the customer is the record in force's
    result = run_cli([*argv, "--out", str(tmp_path / "a")], stdin="A. Tester\nPTB\n")
    assert result.returncode == 0, result.stderr
    assert "Operator (the person performing this recalibration) [Enter: not stated]:" in result.stderr
    assert "Customer: Navy Yard (the record in force's)" in result.stderr and "DRAFT" not in result.stderr
    record = CalibrationRecord.load(tmp_path / "a" / "record.json")
    assert {e.key: e.text() for e in record.calibration.entries} == {"operator": "A. Tester", "laboratory": "PTB", "customer": "Navy Yard"}
    # Enter states none: the certificate is a DRAFT and says which flag gives it; the flags answer without a prompt
    result = run_cli([*argv, "--out", str(tmp_path / "b")], stdin="\n\n")
    assert result.returncode == 0 and "the certificate is a DRAFT: laboratory, operator not stated" in result.stderr, result.stderr
    result = run_cli([*argv, "--out", str(tmp_path / "c"), "--operator", "B", "--laboratory", "L"], stdin="")
    assert result.returncode == 0 and "[Enter: not stated]" not in result.stderr and "DRAFT" not in result.stderr, result.stderr


def test_cli_history_and_recal_with_an_estimate(tmp_path):
    import json

    rng = np.random.default_rng(21)
    store = tmp_path / "store"
    first = tmp_path / "first.json"
    make_record(TRUTH + rng.normal(0, SIGMA), np.diag(SIGMA**2), "2025-01-01T00:00:00+00:00").save(first)
    result = run_cli(["history", "INS-7", "--store", str(store), "--add", str(first), "--at", "2026-01-01", "--max-age", "180"])
    assert result.returncode == 0, result.stderr
    assert "WARNING: the record in force is 365 days old" in result.stdout
    # a field recalibration whose data show a real 10σ change of bias_x: a calibration of new data made elsewhere
    shifted = TRUTH + np.array([10 * SIGMA[0], 0, 0])
    other = make_record(shifted + rng.normal(0, 0.5 * SIGMA), np.diag((0.5 * SIGMA) ** 2), "2026-01-02T00:00:00+00:00")
    from dataclasses import replace

    run = replace(other.stages[0], likelihood=estimate([p.value for p in other.parameters], other.covariance).likelihood)
    (tmp_path / "estimate.json").write_text(json.dumps(replace(other, stages=(run,)).to_document()))
    result = run_cli([
        "recal", "--unit", "INS-7", "--store", str(store), "--estimate", str(tmp_path / "estimate.json"), "--out", str(tmp_path / "recal"),
        "--json"]
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    document = json.loads(result.stdout)
    assert document["significant"] == ["bias_x"] and document["relation"] == "descendant"
    z = {c["id"]: c["significance"] for c in document["changes"]}
    assert z["bias_x"] > 5 and abs(z["bias_y"]) < 3
    # exactly one new record, filed, the record in force; its certificate
    written = sorted(p.name for p in (tmp_path / "recal").iterdir())
    assert written == ["recal-changes.txt", "record.json", "report-technical.pdf", "report.pdf"]
    entries = HistoryStore(store).entries("INS-7")
    in_force = HistoryStore(store).in_force("INS-7")
    assert len(entries) == 2 and (store / "INS-7" / in_force.file).read_bytes() == (tmp_path / "recal" / "record.json").read_bytes()
    result = run_cli(["history", "INS-7", "--store", str(store), "--plot", str(tmp_path / "drift.png"), "--json"])
    assert result.returncode == 0, result.stderr
    history = json.loads(result.stdout)
    assert history["changes"][0]["relation"] == "descendant" and history["changes"][0]["significant"] == ["bias_x"]
    assert (tmp_path / "drift.png").stat().st_size > 1000
    # bad input: another unit's record, an unknown unit
    other_unit = tmp_path / "other.json"
    make_record(TRUTH, np.diag(SIGMA**2), "2025-01-01T00:00:00+00:00", serial="INS-8").save(other_unit)
    result = run_cli(["history", "INS-7", "--store", str(store), "--add", str(other_unit)])
    assert result.returncode == 2 and "INS-8" in result.stderr and "Traceback" not in result.stderr
    result = run_cli(["recal", "--unit", "NOPE", "--store", str(store), "--estimate", str(tmp_path / "estimate.json")])
    assert result.returncode == 2 and "no calibration records for unit 'NOPE'" in result.stderr
