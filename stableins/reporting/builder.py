"""Assemble and write a calibration report: :func:`write_report`.

Python API used by ``stableins report``, ``stableins run`` and the demo::

    from stableins.reporting import write_report
    summary = write_report("report.pdf", "record.json", data=["device.csv"], previous="old.json",
                           procedure="procedures/wu2018.toml")

The PDF is laid out in memory and written atomically: a reader sees no file or the
whole report, never half a PDF.
"""

from __future__ import annotations

import datetime as dt
import hashlib
import io
import json
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, replace
from os import PathLike
from pathlib import Path
from typing import Any

from stableins.data.atomic import atomic_write
from stableins.discovery.diagnose_report import DiagnoseReport
from stableins.errors import InputError
from stableins.history import Comparison
from stableins.records import CalibrationRecord, file_sha256
from stableins.reporting import content, document, sections
from stableins.reporting.budget import UncertaintyInputs, uncertainty_budget
from stableins.reporting.context import InputFile, ReportContext, file_name
from stableins.reporting.evidence import StageEvidence, stage_evidence
from stableins.reporting.tolerances import Tolerances

TITLE = "Calibration certificate"


@dataclass(frozen=True)
class ReportSummary:
    """What was written."""

    path: str
    report_id: str
    pages: int
    verdict: str
    sha256: str
    #: the certificate's statement of conformity in plain text (:func:`stableins.reporting.content.conformity_text`)
    conformity: tuple[str, ...] = ()


@dataclass(frozen=True)
class ReportSettings:
    """What a certificate states beyond its record and files, given directly rather than read from them.

    Attributes
    ----------
    tolerances : Tolerances, optional
        Conformity limits (override the procedure's ``[tolerances]`` table).
    uncertainty : UncertaintyInputs, optional
        Type B inputs (override the procedure's ``[uncertainty]`` table; :mod:`stableins.reporting.budget`).
    report_id : str, optional
        Id to print; by default :func:`report_id_for`.
    issued : datetime, optional
        Date of issue (default: now, UTC).
    """

    tolerances: Tolerances | None = None
    uncertainty: UncertaintyInputs | None = None
    report_id: str | None = None
    issued: dt.datetime | None = None


@dataclass(frozen=True)
class LoadedRecord:
    """A record read through the one reader (:meth:`CalibrationRecord.load`), with the file it came from."""

    record: CalibrationRecord
    path: str = ""
    sha256: str = ""

    @classmethod
    def of(cls, source: CalibrationRecord | str | PathLike[str]) -> LoadedRecord:
        """Return the record of ``source`` (a record, or a file read with its SHA-256)."""
        if isinstance(source, CalibrationRecord):
            return cls(source)
        record = CalibrationRecord.load(source)
        return cls(record, str(source), file_sha256(source))


def report_id_for(loaded: LoadedRecord, digests: Iterable[str]) -> str:
    """Return a unique, reproducible report id: serial, calibration date and a digest of every input.

    ``SI-<serial>-<yyyymmdd>-<8 hex>``; the same inputs give the same id, any change of
    an input (record, data, previous record, procedure) gives another.
    """
    record = loaded.record
    digest = hashlib.sha256()
    digest.update((loaded.sha256 or json.dumps(record.to_document(), sort_keys=True, default=str)).encode())
    for d in sorted(digests):
        digest.update(d.encode())
    date = (record.provenance.data_end or record.provenance.data_start or record.calibration.created or "")[:10].replace("-", "")
    serial = "".join(c if c.isalnum() or c in "-_" else "-" for c in record.serial_number)
    return "-".join(x for x in ("SI", serial, date, digest.hexdigest()[:8].upper()) if x)


def collect_inputs(loaded: LoadedRecord, data: Sequence[str | PathLike[str]]) -> list[InputFile]:
    """Rows of the inputs table; a data file the record does not list is an :class:`InputError`."""
    record = loaded.record
    hashed = [(p, file_sha256(p)) for p in data]
    given = {digest: Path(p).name for p, digest in hashed}
    listed = [(s, f) for s in record.stages for f in s.inputs]
    recorded = {f.sha256 for _, f in listed}
    rows = []
    if loaded.path:
        rows.append(InputFile("calibration record", Path(loaded.path).name, loaded.sha256, "read by this report"))
    this = {s.id for s in record.stages_run}
    for stage, f in listed:
        role = f"{stage.name} data" + ("" if stage.id in this else " (earlier calibration)")
        check = (
            f"verified: {given[f.sha256]} given to this report" if f.sha256 in given else "listed in the record; not given to this report"
        )
        rows.append(InputFile(role, Path(f.path).name, f.sha256, check))
    for path, digest in hashed:
        if digest in recorded:
            continue
        if recorded:
            raise InputError(
                f"SHA-256 {digest} is not among the {len(recorded)} inputs the calibration record lists",
                path=path,
                expected="a data file this calibration was made from",
            )
        rows.append(InputFile("data", Path(path).name, digest, "the record lists no inputs"))
    return rows


def stored_evidence(record: CalibrationRecord, where: str) -> list[StageEvidence]:
    """Return the residual evidence of every fit of the stages run in this calibration, as stored in the record."""
    out = []
    for run in record.stages_run:
        fits = [stage_evidence(f, where, run=run.name) for f in run.fits]
        if fits:
            fits[-1] = replace(fits[-1], notes=run.notes, determined=run.determined)
        out += fits
    return out


def read_discovery(path: str | PathLike[str]) -> DiagnoseReport:
    """Read the document of ``stableins diagnose --json``, every field checked (:meth:`DiagnoseReport.from_json`)."""
    from stableins.data.jsonio import load_json_file
    from stableins.discovery.diagnose_report import DOCUMENT

    return DiagnoseReport.from_json(load_json_file(path, what=DOCUMENT), path)


def write_report(
    out: str | PathLike[str],
    record: CalibrationRecord | str | PathLike[str],
    *,
    data: Sequence[str | PathLike[str]] = (),
    previous: CalibrationRecord | str | PathLike[str] | None = None,
    procedure: str | PathLike[str] | None = None,
    discovery: str | PathLike[str] | None = None,
    settings: ReportSettings | None = None,
) -> ReportSummary:
    """Write the calibration certificate of ``record`` to ``out`` (PDF).

    The certificate renders the record: its values, statuses, the stage that last determined each
    parameter, the stages run and their settings, entries, environment and the residual evidence stored
    in its stage runs.  Only a record without stored evidence (migrated from schema version 1) has its
    device-level evidence recomputed from ``data``, with the settings its stage run states.

    Parameters
    ----------
    out : path
        PDF to write (atomically).
    record : path or CalibrationRecord
        The calibration record (read by :meth:`CalibrationRecord.load`, the one reader).
    data : sequence of paths
        Data files of the calibration; their SHA-256 are checked against the record.
    previous : path or CalibrationRecord, optional
        Previous calibration record of the unit, for the change section (:func:`stableins.history.compare`).
    procedure : path, optional
        Procedure definition (TOML) whose ``[tolerances]`` table gives the conformity limits.
    discovery : path, optional
        Output of ``stableins diagnose --json`` (ranked candidates and refit history).
    settings : ReportSettings, optional
        Limits, Type B inputs, id and date of issue given directly (:class:`ReportSettings`).

    Returns
    -------
    ReportSummary
    """
    import stableins
    from stableins.discovery.library import record_terms

    settings = settings or ReportSettings()
    uncertainty, issued = settings.uncertainty, settings.issued
    loaded = LoadedRecord.of(record)
    view = loaded.record
    previous_loaded = LoadedRecord.of(previous) if previous is not None else None
    inputs = collect_inputs(loaded, data)
    stages, evidence_notes = _evidence(view, loaded.path or "calibration record", data)
    terms = content.known_terms(record_terms(view.ids))
    if uncertainty is None:
        uncertainty = UncertaintyInputs.from_procedure_file(str(procedure)) if procedure is not None else UncertaintyInputs()
    budget = uncertainty_budget(view, uncertainty, terms)
    rows = content.parameter_rows(view, terms, budget=budget)
    if previous_loaded is not None:
        inputs.append(InputFile("previous record", file_name(previous_loaded.path), previous_loaded.sha256 or "—", "read by this report"))
    tolerances, procedure_inputs = _tolerances(procedure, settings.tolerances)
    inputs += procedure_inputs
    comparison, changes, previous_rows = _previous(previous_loaded, view, terms, uncertainty)
    checks = content.conformity(rows, changes, stages, tolerances)

    discovery_document, discovery_source = None, ""  # the record's own history is ctx.record.discovery
    if discovery is not None:
        discovery_document, discovery_source = read_discovery(discovery), Path(discovery).name
        inputs.append(InputFile("model discovery", Path(discovery).name, file_sha256(discovery), "read by this report"))

    issued = issued or dt.datetime.now(dt.UTC)
    ctx = ReportContext(
        record=view,
        record_path=loaded.path,
        report_id=settings.report_id or report_id_for(loaded, [f.sha256 for f in inputs]),
        issued=issued.strftime("%Y-%m-%d %H:%M UTC"),
        rows=rows,
        budget=budget,
        previous_rows=previous_rows,
        stages=stages,
        inputs=inputs,
        tolerances=tolerances,
        checks=checks,
        previous=None if previous_loaded is None else previous_loaded.record,
        previous_path=None if previous_loaded is None else previous_loaded.path,
        comparison=comparison,
        changes=changes,
        software_version=stableins.__version__,
        evidence_notes=evidence_notes,
        discovery=discovery_document,
        discovery_source=discovery_source,
    )
    pdf, pages = _render(ctx)
    with atomic_write(out, "wb") as handle:
        handle.write(pdf)
    verdict = content.overall_verdict(checks) if not tolerances.empty else "NO STATEMENT"
    statement = tuple(content.conformity_text(checks, assessed=not tolerances.empty, coverage_factor=tolerances.coverage_factor))
    return ReportSummary(str(out), ctx.report_id, pages, verdict, hashlib.sha256(pdf).hexdigest(), statement)


def _evidence(view: CalibrationRecord, where: str, data: Sequence[str | PathLike[str]]) -> tuple[list[StageEvidence], list[str]]:
    """Return the stages' evidence of fit and notes on it: stored in the record, or recomputed from ``data`` for a migrated record."""
    from stableins.discovery.library import record_terms

    evidence_notes: list[str] = []
    stages = stored_evidence(view, where)
    bare = [run for run in view.stages_run if not run.fits and run.name != "system"]
    if bare and data:  # a migrated record: its device-level evidence is recomputed with the settings it states
        from stableins.reporting.replay import device_fits

        settings = bare[0].settings or ({"noise_model": view.noise_model.to_document()} if view.noise_model is not None else None)
        fits, evidence_notes = device_fits(data, settings, effects=record_terms(view.ids))
        stages = [stage_evidence(f, where) for f in fits] + stages
    return stages, evidence_notes


def _previous(
    previous_loaded: LoadedRecord | None, view: CalibrationRecord, terms: Any, uncertainty: UncertaintyInputs
) -> tuple[Comparison | None, list[content.ChangeRow] | None, list[content.ParameterRow] | None]:
    """Return the comparison with the previous record of the unit, its change rows and its parameter rows (None without one)."""
    from stableins.discovery.library import record_terms
    from stableins.history import compare

    if previous_loaded is None:
        return None, None, None
    if previous_loaded.record.serial_number != view.serial_number:
        raise InputError(
            f"the previous record is of unit {previous_loaded.record.serial_number!r}, this one of {view.serial_number!r}",
            path=previous_loaded.path or None,
            field="serial_number",
            expected="a record of the same unit",
        )
    comparison = compare(previous_loaded.record, view)
    changes = content.change_rows(comparison, terms)
    previous_terms = content.known_terms(record_terms(previous_loaded.record.ids))
    previous_rows = content.parameter_rows(
        previous_loaded.record, previous_terms, budget=uncertainty_budget(previous_loaded.record, uncertainty, previous_terms)
    )
    return comparison, changes, previous_rows


def _tolerances(procedure: str | PathLike[str] | None, tolerances: Tolerances | None) -> tuple[Tolerances, list[InputFile]]:
    """Return the conformity limits (given, the procedure's ``[tolerances]`` table, or none) and the procedure as an input."""
    if procedure is None:
        return (tolerances if tolerances is not None else Tolerances.from_mapping(None)), []
    from stableins.procedures.definition import resolve

    resolved = resolve(procedure)  # a shipped definition's name ("system-static") or a TOML file
    if tolerances is None:
        tolerances = Tolerances.from_procedure_file(str(resolved))
    read = InputFile("procedure", Path(resolved).name, file_sha256(resolved), "tolerances and uncertainty inputs read from it")
    return tolerances, [read]


def _render(ctx: ReportContext) -> tuple[bytes, int]:
    """Return the PDF of the report laid out from ``ctx``, and its number of pages."""
    import stableins

    story = [flowable for section in sections.SECTIONS for flowable in section(ctx)]
    buffer = io.BytesIO()
    pages = document.build(
        story,
        buffer,
        title=TITLE,
        report_id=ctx.report_id,
        serial=ctx.record.serial_number,
        footer=f"stableins {stableins.__version__}  ·  issued {ctx.issued}  ·  not to be reproduced except in full",
        subject=f"Accelerometer calibration of unit {ctx.record.serial_number}",
    )
    return buffer.getvalue(), pages
