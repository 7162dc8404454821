"""One truth per unit (issue 12): one record per recalibration, in force, certified as it is; one change statistic;
no stage raises a σ; a stage that determines nothing writes nothing; everything entered reaches the certificate."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from dataclasses import replace
from pathlib import Path

import certificate_checks
import numpy as np
import pytest
from device_world import GRAVITY, device_columns, draw_truth

from stableins import cli
from stableins.conventions import MICRO_G
from stableins.data.device import save_device
from stableins.errormodel import CORE_TERMS, known_terms
from stableins.estimators.result import FitResult
from stableins.history_store import HistoryStore
from stableins.procedures.definition import load_procedure
from stableins.records import CalibrationRecord, RunInfo, file_sha256
from stableins.reporting.symbols import plain
from stableins.site import SiteMetadata
from stableins.status import Status

POPPLER = shutil.which("pdftotext")
needs_poppler = pytest.mark.skipif(not POPPLER, reason="pdftotext (Debian package poppler-utils) is not installed")


def pdf_text(path: Path) -> str:
    return subprocess.run(["pdftotext", "-layout", str(path), "-"], check=True, capture_output=True, text=True, timeout=60).stdout


def flagged_on_certificate(text: str) -> set[str]:
    """Parameters whose row in the change section says 'Changed: yes' (ids from their typeset symbols)."""
    section = text[text.index("Change since the previous calibration") : text.index("Statement of conformity")]
    ids = {plain(t): t for t in known_terms()}
    return {ids[m.group(1)] for m in re.finditer(r"^\s*(\S+)\s+\S+\s+\S+\s+\S+\s+\S+\s+\S+\s+yes\s", section, re.M)}


@needs_poppler
def test_recal_writes_one_record_in_force_whose_certificate_shows_it(tmp_path, capsys):
    """run device-coarse → file → recal field-recal-device on the simulated platform (the issue's session)."""
    store = tmp_path / "store"
    argv = [
        "run",
        "device-coarse",
        "--driver",
        "sim",
        "--unit",
        "SN042",
        "--seed",
        "4",
        "--out",
        str(tmp_path / "run1"),
        "--yes",
        "--quiet",
    ]
    assert cli.main(argv) == 0
    assert cli.main(["history", "SN042", "--store", str(store), "--add", str(tmp_path / "run1" / "record.json")]) == 0
    before = CalibrationRecord.load(tmp_path / "run1" / "record.json")
    capsys.readouterr()
    out = tmp_path / "recal1"
    argv = ["recal", "field-recal-device", "--unit", "SN042", "--store", str(store), "--driver", "sim", "--seed", "4", "--out", str(out),
            "--yes", "--quiet", "--set", "site_temperature=23.5", "--set", "laboratory=Field team 3", "--json"]  # fmt: skip
    assert cli.main(argv) == 0
    # exactly one new record in the run directory (prior.json is the copy of the record in force it started from)
    records = []
    for path in sorted(out.glob("*.json")):
        try:
            records.append((path.name, CalibrationRecord.load(path)))
        except Exception:  # noqa: BLE001 - procedure.json is not a record
            continue
    names = [n for n, _ in records]
    assert names == ["prior.json", "record.json"] and file_sha256(out / "prior.json") == file_sha256(
        store / "SN042" / HistoryStore(store).entries("SN042")[0].file
    )
    record = dict(records)["record.json"]
    # it is the record in force, byte for byte
    entry = HistoryStore(store).in_force("SN042")
    assert (store / "SN042" / entry.file).read_bytes() == (out / "record.json").read_bytes()
    # only the fine stage ran in this calibration; the coarse stage is carried over
    assert record.provenance.stages == ("fine",) and record.calibration.prior is not None
    assert record.source_text("theta20").endswith("carried over") and record.measured_in_this_calibration("sf_x")
    # a Bayesian update: no σ grew
    for p in record.parameters:
        assert not (p.sigma > before[p.id].sigma * (1 + 1e-9)), p.id
    # its certificate's technical report shows its values and what was entered
    text = pdf_text(out / "report-technical.pdf")
    flat = " ".join(text.split())
    rows = {m.group(1): (m.group(2), m.group(4)) for m in re.finditer(r"^(\S+)\s+estimated\s+(\S+)\s+(\S+)\s+(\S+)\s", text, re.M)}
    for pid in ("sf_x", "bias_y", "beta_zx", "K2_z", "theta30"):
        p = record[pid]
        term = known_terms()[pid]
        value, expanded = rows[plain(pid)]
        decimals = len(value.partition(".")[2])
        assert decimals == len(expanded.partition(".")[2]), pid  # GUM 7.2.6: the value to the last digit of U
        shown = float(value.replace("\u2212", "-"))
        assert abs(shown - float(term.to_engineering(p.value))) <= 0.5 * 10**-decimals + 1e-9, pid
    assert "Field team 3" in flat and "site temperature 23.5 °C Site temperature fine" in flat
    assert "field-recal-device" in flat and "100 Hz" in flat and "(from the data)" in flat
    assert f"{record.provenance.data_start} to {record.provenance.data_end}" in flat
    assert "Stages of earlier calibrations the record carries over" in flat
    assert certificate_checks.review(out / "report.pdf", tmp_path) == []  # the field recalibration's certificate, reviewed


def exact_unit(serial: str, seed: int):
    """A unit on the exact platform of tests/device_world: truth, site metadata and a device-level session file pair."""
    rng = np.random.default_rng(seed)
    truth = draw_truth(rng)
    site = SiteMetadata(serial, np.radians(40.0), 0.0, GRAVITY, "WGS-84 normal gravity", 100.0, start_time="2026-01-05T08:00:00+00:00")
    return truth, site


def fine_estimate(truth, site, prior: CalibrationRecord, seed: int, path: Path) -> Path:
    """A field device-level set of new data, calibrated on its own (data only): the record `recal --estimate` applies."""
    from stableins.estimators.dwell import dwells_from_columns
    from stableins.estimators.fine import calibrate_fine

    procedure = load_procedure("device-fine")
    offsets = (0.0, prior["theta20"].value, prior["theta30"].value)
    columns = {
        k: np.concatenate(v) if isinstance(v, list) else v
        for k, v in device_columns(truth, procedure, seed=seed, stage="fine", offsets=offsets, dwell=60.0, settle=2.0).items()
    }
    data = save_device(path.with_suffix(".h5"), columns, replace(site, start_time="2026-06-01T08:00:00+00:00"))
    dwells = dwells_from_columns(columns, layouts={"fine": procedure.layout}, source=str(data))
    fit = calibrate_fine(dwells, prior.values(), gravity=site.gravity, expected_positions=procedure.positions, source=str(data))
    run = RunInfo(inputs=[data], procedure="device-fine", data_end="2026-06-01T12:00:00+00:00")
    estimate = CalibrationRecord.from_fit_result(fit, run, site=site)
    return estimate.save(path)


@needs_poppler
def test_recal_history_and_certificate_agree_on_every_change_flag(tmp_path, capsys):
    """Two units, one whose bias_x stepped by 60 µg, one unchanged: recal, history and the certificate flag the same."""
    store = tmp_path / "store"
    flags = {}
    for serial, seed, step in (("UNIT-A", 1, 60.0), ("UNIT-B", 2, 0.0)):
        truth, site = exact_unit(serial, seed)
        files = []
        for name, stage in (("device-coarse", "coarse"), ("device-fine", "fine")):
            cols = device_columns(
                truth, load_procedure(name), seed=seed + 10 * len(files), stage=stage, dwell=60.0 if stage == "fine" else None
            )
            cols = {k: np.concatenate(v) if isinstance(v, list) else v for k, v in cols.items()}
            files.append(str(save_device(tmp_path / f"{serial}-{name}.h5", cols, site)))
        base = tmp_path / f"{serial}.json"
        assert cli.main(["calibrate", "device", *files, "--out", str(base), "--bias-instability", "0"]) == 0
        first = CalibrationRecord.load(base)  # the data's start_time and time column give the calibration date
        assert first.provenance.data_start == "2026-01-05T08:00:00+00:00" and first.provenance.data_end > first.provenance.data_start
        assert cli.main(["history", serial, "--store", str(store), "--add", str(base)]) == 0
        changed = dict(truth, bias_x=truth["bias_x"] + step * MICRO_G)
        estimate = fine_estimate(changed, site, CalibrationRecord.load(base), seed + 100, tmp_path / f"{serial}-estimate.json")
        capsys.readouterr()
        assert (
            cli.main(
                ["recal", "--unit", serial, "--store", str(store), "--estimate", str(estimate), "--out", str(tmp_path / serial), "--json"]
            )
            == 0
        )
        recal = json.loads(capsys.readouterr().out)
        assert cli.main(["history", serial, "--store", str(store), "--json"]) == 0
        history = json.loads(capsys.readouterr().out)
        certificate = flagged_on_certificate(pdf_text(tmp_path / serial / "report-technical.pdf"))  # its change section
        flags[serial] = (set(recal["significant"]), set(history["changes"][-1]["significant"]), certificate)
        # the same z everywhere: recal's JSON and history's JSON
        z_recal = {c["id"]: c["significance"] for c in recal["changes"]}
        z_history = {c["id"]: c["significance"] for c in history["changes"][-1]["parameters"]}
        assert z_recal == pytest.approx(z_history)
    for serial, (recal, history, certificate) in flags.items():
        assert recal == history == certificate, serial
    assert "bias_x" in flags["UNIT-A"][0]  # a 60 µg step: about 30σ
    assert flags["UNIT-B"][0] == set()  # nothing changed: |z| ≥ 3 has probability 0.27 % per parameter


def test_a_stage_on_six_hours_writes_no_record_and_exits_4_with_the_reason(tmp_path, capsys):
    """Six hours do not determine the combinations (NotDeterminedError): exit 4, the reason, no record (docs/cli.md)."""
    from stableins.data.truth import load_truth

    assert cli.main(["simulate", "system", "--seed", "3", "--duration", "6h", "--rate", "1", "--out", str(tmp_path)]) == 0
    truth = load_truth(tmp_path / "truth.json")
    terms = CORE_TERMS
    values = np.array([truth.installed_calibration.get(t.id, t.reference) for t in terms])
    covariance = np.diag([(0.02 * t.nominal) ** 2 for t in terms])
    prior = CalibrationRecord.from_fit_result(
        FitResult("coarse+fine", terms, values, covariance, (Status.ESTIMATED,) * len(terms), np.zeros(0), np.zeros(0)), site=truth.site
    )
    prior.save(tmp_path / "prior.json")
    capsys.readouterr()
    out = tmp_path / "cal.json"
    assert cli.main(["calibrate", "system", str(tmp_path / "system.h5"), "--prior", str(tmp_path / "prior.json"), "--out", str(out)]) == 4
    error = capsys.readouterr().err
    assert "6.00 h" in error and "lack one sidereal day" in error and "no record was written" in error and "Traceback" not in error
    assert not out.exists()


def test_every_system_stage_parameter_keeps_or_lowers_its_sigma():
    """The system stage on a synthetic day updating a device-like record with a correlated covariance (the prior)."""
    from system_synthetic import paper_residuals, record

    from stableins.data.chunks import ArraySource
    from stableins.estimators.system.stage import run_system_stage

    true, installed = paper_residuals()
    cols, meta = record(true, installed, rate=1.0, seed=21)
    terms = CORE_TERMS
    rng = np.random.default_rng(5)
    scale = np.array([0.02 * t.nominal for t in terms])
    a = rng.normal(size=(len(terms), len(terms) + 4))
    covariance = (a @ a.T / len(terms)) * np.outer(scale, scale)
    values = np.array([installed.get(t.id, t.reference) for t in terms])
    prior = CalibrationRecord.from_fit_result(
        FitResult("coarse+fine", terms, values, covariance, (Status.ESTIMATED,) * len(terms), np.zeros(0), np.zeros(0)), site=meta
    )
    mapping = {(x, y): float(prior.covariance[i, j]) for i, x in enumerate(prior.ids) for j, y in enumerate(prior.ids)}
    outcome = run_system_stage(ArraySource(cols), meta, prior.values(), mapping)
    updated = prior.updated(outcome.result, RunInfo(inputs=[], data_end="2026-01-06T00:00:00+00:00"))
    ratio = {p.id: p.sigma / prior[p.id].sigma for p in updated.parameters if p.id in prior.ids}  # (the gyro drift is new)
    assert max(ratio.values()) <= 1.0 + 1e-9, ratio
    assert min(ratio.values()) < 0.9  # the day carried information
    # the stage's own result is the same posterior (one update function)
    np.testing.assert_allclose(outcome.result.sigma, [updated[i].sigma for i in outcome.result.ids], rtol=1e-9)
    assert updated.last_determined_by("beta_zy")[1] == "alone" and updated.last_determined_by("bias_x")[1] == "in combination"
