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
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, replace
from os import PathLike
from pathlib import Path
from typing import Any

from stableins.data.atomic import atomic_write
from stableins.discovery.diagnose_report import DiagnoseReport
from stableins.errors import InputError
from stableins.estimators.result import Stage
from stableins.history import Comparison
from stableins.records import CalibrationRecord, file_sha256
from stableins.reporting import content, document, sections
from stableins.reporting.budget import UncertaintyInputs
from stableins.reporting.budget_sources import uncertainty_budget
from stableins.reporting.context import ReportContext, ReportInput, file_name
from stableins.reporting.evidence import StageEvidence, stage_evidence
from stableins.reporting.tolerances import Tolerances

TITLE = "Calibration certificate"
TECHNICAL_TITLE = "Technical report"
#: The file name of the technical report beside a certificate ``NAME.pdf`` when none is given.
TECHNICAL_SUFFIX = "-technical"
#: The entries a certificate needs to identify who calibrated what for whom (ISO/IEC 17025 7.8.2.1 b, e, o).
IDENTIFICATION = ("laboratory", "customer", "operator")


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
    #: the technical report the certificate references by its SHA-256, its pages and digest
    technical: str = ""
    technical_pages: int = 0
    technical_sha256: str = ""
    #: identification the certificate lacks (laboratory, customer, operator): it is a watermarked draft
    missing: tuple[str, ...] = ()


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
    laboratory, customer, operator : str, optional
        Who calibrated, for whom, and who performed it (ISO/IEC 17025 7.8.2.1 b, e, o); each overrides the record's
        entry of that name.  A certificate without all three is a watermarked DRAFT.
    no_statement : bool
        Make no statement of conformity even where the procedure defines tolerances (the customer did not ask for one).
    sign_key, sign_certificate : path, optional
        Sign the certificate (PAdES, :mod:`stableins.reporting.signing`) with this PEM private key and its X.509
        certificate (default: in the key's file).
    progress : callable, optional
        ``progress(done, total)``, called as the sections of the two documents are laid out and each is built (a
        console's progress bar).
    """

    tolerances: Tolerances | None = None
    uncertainty: UncertaintyInputs | None = None
    report_id: str | None = None
    issued: dt.datetime | None = None
    laboratory: str | None = None
    customer: str | None = None
    operator: str | None = None
    no_statement: bool = False
    sign_key: str | None = None
    sign_certificate: str | None = None
    progress: Callable[[int, int], None] | None = None


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


def collect_inputs(loaded: LoadedRecord, data: Sequence[str | PathLike[str]]) -> list[ReportInput]:
    """Rows of the inputs table; a data file the record does not list is an :class:`InputError`."""
    record = loaded.record
    hashed = [(p, file_sha256(p)) for p in data]
    given = {digest: Path(p).name for p, digest in hashed}
    listed = [(s, f) for s in record.stages for f in s.inputs]
    recorded = {f.sha256 for _, f in listed}
    rows = []
    if loaded.path:
        rows.append(ReportInput("calibration record", Path(loaded.path).name, loaded.sha256, "read by this report"))
    this = {s.id for s in record.stages_run}
    for stage, f in listed:
        role = f"{stage.name} data" + ("" if stage.id in this else " (earlier calibration)")
        check = (
            f"verified: {given[f.sha256]} given to this report" if f.sha256 in given else "listed in the record; not given to this report"
        )
        rows.append(ReportInput(role, Path(f.path).name, f.sha256, check))
    for path, digest in hashed:
        if digest in recorded:
            continue
        if recorded:
            raise InputError(
                f"SHA-256 {digest} is not among the {len(recorded)} inputs the calibration record lists",
                path=path,
                expected="a data file this calibration was made from",
            )
        rows.append(ReportInput("data", Path(path).name, digest, "the record lists no inputs"))
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


def _discovery_input(discovery: str | PathLike[str] | None, inputs: list[ReportInput]) -> tuple[DiagnoseReport | None, str]:
    """Return the ``diagnose --json`` document given to the report and its file name, naming it among ``inputs``.

    ``(None, "")`` when none is given: the record's own discovery history is then the report's (``ctx.record.discovery``).
    """
    if discovery is None:
        return None, ""
    inputs.append(ReportInput("model discovery", Path(discovery).name, file_sha256(discovery), "read by this report"))
    return read_discovery(discovery), Path(discovery).name


def write_report(
    out: str | PathLike[str],
    record: CalibrationRecord | str | PathLike[str],
    *,
    data: Sequence[str | PathLike[str]] = (),
    previous: CalibrationRecord | str | PathLike[str] | None = None,
    procedure: str | PathLike[str] | None = None,
    discovery: str | PathLike[str] | None = None,
    settings: ReportSettings | None = None,
    technical: str | PathLike[str] | None = None,
) -> ReportSummary:
    """Write the calibration certificate of ``record`` to ``out`` and its technical report beside it (PDF).

    Two documents from one context, so every number that appears in both is the same number: the
    certificate (at most three pages: identification, results with U (k = 2), the statement of conformity
    with its decision rule and specification, traceability, signatures) and the technical report (the
    evidence, residuals, noise model, discovery history, budget derivation and notes), which the
    certificate names by its SHA-256.

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
        Procedure definition (TOML) whose ``[tolerances]`` table gives the conformity limits; validated as ``stableins
        run`` validates it (:func:`stableins.procedures.definition.load_procedure`) before anything is read or written.
    discovery : path, optional
        Output of ``stableins diagnose --json`` (ranked candidates and refit history).
    settings : ReportSettings, optional
        Limits, Type B inputs, id and date of issue given directly (:class:`ReportSettings`).
    technical : path, optional
        Technical report to write (default: ``out`` with ``-technical`` before its suffix).

    Returns
    -------
    ReportSummary
    """
    import stableins
    from stableins.discovery.library import record_terms

    settings = settings or ReportSettings()
    uncertainty, issued = settings.uncertainty, settings.issued
    _check_procedure(procedure)
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
        inputs.append(ReportInput("previous record", file_name(previous_loaded.path), previous_loaded.sha256 or "—", "read by this report"))
    chosen = procedure if procedure is not None else _record_procedure(view, settings)
    tolerances, procedure_inputs = _tolerances(chosen, settings.tolerances)
    if settings.no_statement:
        tolerances = Tolerances.from_mapping(None, source=content.NO_STATEMENT_ASKED)
    inputs += procedure_inputs
    comparison, changes, previous_rows = _previous(previous_loaded, view, terms, uncertainty)
    checks = content.conformity(rows, changes, stages, tolerances)

    discovery_document, discovery_source = _discovery_input(discovery, inputs)

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
    technical_path = Path(technical) if technical is not None else technical_path_for(out)
    if technical_path.resolve() == Path(out).resolve():
        raise InputError("the technical report would overwrite the certificate", path=str(technical), expected="another file name")
    ctx.identification = _identification(view, settings)
    ctx.simulated = is_simulated(view)
    steps = _Steps(len(sections.TECHNICAL_SECTIONS) + len(sections.CERTIFICATE_SECTIONS) + 2, settings.progress)
    technical_pdf, technical_pages = _render(ctx, sections.TECHNICAL_SECTIONS, TECHNICAL_TITLE, steps)
    digest = hashlib.sha256(technical_pdf).hexdigest()
    ctx.technical = ReportInput("technical report", technical_path.name, digest, f"{technical_pages} pages")
    ctx.figures = 0
    pdf, pages = _render(ctx, sections.CERTIFICATE_SECTIONS, TITLE, steps)
    if settings.sign_key is not None:
        from stableins.reporting.signing import sign

        pdf = sign(pdf, settings.sign_key, settings.sign_certificate)
    with atomic_write(technical_path, "wb") as handle:
        handle.write(technical_pdf)
    with atomic_write(out, "wb") as handle:
        handle.write(pdf)
    verdict = content.overall_verdict(checks) if not tolerances.empty else "NO STATEMENT"
    statement = tuple(
        content.conformity_text(checks, assessed=not tolerances.empty, coverage_factor=tolerances.coverage_factor, reason=tolerances.source)
    )
    return ReportSummary(
        str(out),
        ctx.report_id,
        pages,
        verdict,
        hashlib.sha256(pdf).hexdigest(),
        statement,
        str(technical_path),
        technical_pages,
        ctx.technical.sha256,
        tuple(k for k in IDENTIFICATION if not ctx.identification.get(k)),
    )


def technical_path_for(out: str | PathLike[str]) -> Path:
    """Return the technical report beside the certificate ``out``: ``cert.pdf`` → ``cert-technical.pdf``."""
    path = Path(out)
    return path.with_name(f"{path.stem}{TECHNICAL_SUFFIX}{path.suffix or '.pdf'}")


def is_simulated(record: CalibrationRecord) -> bool:
    """Return whether the record was made from simulated data (the simulator's site metadata say so)."""
    site = record.site
    if site is None:
        return False
    return bool(site.extra.get("simulated")) or "simulated" in site.gravity_source.lower()


def _identification(record: CalibrationRecord, settings: ReportSettings) -> dict[str, str]:
    """Return laboratory, customer and operator: given to the report, else the record's entries, else its site's extra fields."""
    from stableins.reporting.context import entry_text

    extra = record.site.extra if record.site else {}
    out = {}
    for key in IDENTIFICATION:
        given = getattr(settings, key)
        text = given if given is not None else entry_text(record, key) or str(extra.get(key, "") or "")
        out[key] = text.strip()
    return out


def _record_procedure(record: CalibrationRecord, settings: ReportSettings) -> str | None:
    """Return the shipped procedure whose ``[tolerances]`` the certificate applies by default.

    The last stage run of the calibration whose procedure defines tolerances decides (``device-coarse + device-fine``:
    the later one first); None when no stage's procedure defines any, or when limits are given directly.
    """
    if settings.tolerances is not None or settings.no_statement:
        return None
    from stableins.procedures.definition import PROCEDURE_DIRECTORY

    for run in reversed(record.stages_run):  # a shipped definition of the name the stage ran (a file is given with --procedure)
        for name in reversed([n.strip() for n in (run.procedure or "").split("+") if n.strip()]):
            path = PROCEDURE_DIRECTORY / f"{name}.toml"
            if path.is_file() and not Tolerances.from_procedure_file(str(path)).empty:
                return name
    return None


def _evidence(view: CalibrationRecord, where: str, data: Sequence[str | PathLike[str]]) -> tuple[list[StageEvidence], list[str]]:
    """Return the stages' evidence of fit and notes on it: stored in the record, or recomputed from ``data`` for a migrated record."""
    from stableins.discovery.library import record_terms

    evidence_notes: list[str] = []
    stages = stored_evidence(view, where)
    bare = [run for run in view.stages_run if not run.fits and run.name != Stage.SYSTEM]
    if bare and data:  # a migrated record: its device-level evidence is recomputed with the settings it states
        from stableins.estimators.device_settings import DeviceSessionSettings
        from stableins.reporting.replay import device_fits

        stated = bare[0].settings
        settings = stated if isinstance(stated, DeviceSessionSettings) else None
        fits, evidence_notes = device_fits(data, settings, noise=view.noise_model, effects=record_terms(view.ids))
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


def _check_procedure(procedure: str | PathLike[str] | None) -> None:
    """Validate a procedure given to the report as ``stableins run`` validates it (unknown sections, an empty file ...)."""
    if procedure is not None:
        from stableins.procedures.definition import load_procedure

        load_procedure(str(procedure))


def _tolerances(procedure: str | PathLike[str] | None, tolerances: Tolerances | None) -> tuple[Tolerances, list[ReportInput]]:
    """Return the conformity limits (given, the procedure's ``[tolerances]`` table, or none) and the procedure as an input."""
    if procedure is None:
        return (tolerances if tolerances is not None else Tolerances.from_mapping(None)), []
    from stableins.procedures.definition import resolve

    resolved = resolve(procedure)  # a shipped definition's name ("system-static") or a TOML file
    if tolerances is None:
        tolerances = Tolerances.from_procedure_file(str(resolved))
    read = ReportInput("procedure", Path(resolved).name, file_sha256(resolved), "tolerances and uncertainty inputs read from it")
    return tolerances, [read]


@dataclass
class _Steps:
    """The steps of :func:`write_report` done so far, told to its ``progress(done, total)``."""

    total: int
    progress: Callable[[int, int], None] | None
    done: int = 0

    def step(self) -> None:
        self.done += 1
        if self.progress is not None:
            self.progress(self.done, self.total)


def _render(ctx: ReportContext, parts: Sequence[Any], title: str, steps: _Steps) -> tuple[bytes, int]:
    """Return the PDF of one document laid out from ``ctx`` (the certificate or its technical report), and its number of pages."""
    import stableins
    from stableins.reporting.signing import manifest_text

    ctx.shown_notes = set()
    story = []
    for section in parts:
        story += section(ctx)
        steps.step()
    named = [(f.role, f.name, f.sha256) for f in ctx.inputs] + ([(ctx.technical.role, ctx.technical.name, ctx.technical.sha256)]
                                                                if ctx.technical is not None else [])  # fmt: skip
    buffer = io.BytesIO()
    pages = document.build(
        story,
        buffer,
        title=title,
        report_id=ctx.report_id,
        serial=ctx.record.serial_number,
        footer=f"stableins {stableins.__version__}  ·  issued {ctx.issued}  ·  not to be reproduced except in full",
        subject=f"Accelerometer calibration of unit {ctx.record.serial_number}",
        marks=document.PageMarks(
            watermark="DRAFT" if any(not ctx.identification.get(k) for k in IDENTIFICATION) else "",
            banner="SIMULATED DATA: not a calibration of a physical unit" if ctx.simulated else "",
            keywords=manifest_text(named),
        ),
    )
    steps.step()
    return buffer.getvalue(), pages
