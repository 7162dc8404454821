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
from dataclasses import dataclass
from os import PathLike
from pathlib import Path
from typing import Any

from stableins.data.atomic import atomic_write
from stableins.data.errors import InputError
from stableins.reporting import content, document, sections
from stableins.reporting.evidence import StageEvidence, stage_evidence
from stableins.reporting.record_view import RecordView, sha256_file
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


def report_id_for(record: RecordView, digests: Iterable[str]) -> str:
    """Unique, reproducible report id: serial, calibration date and a digest of every input.

    ``SI-<serial>-<yyyymmdd>-<8 hex>``; the same inputs give the same id, any change of
    an input (record, data, previous record, procedure) gives another.
    """
    digest = hashlib.sha256()
    digest.update((record.sha256 or json.dumps([p.__dict__ for p in record.parameters], sort_keys=True, default=str)).encode())
    for d in sorted(digests):
        digest.update(d.encode())
    date = (record.times.get("finished") or record.times.get("started") or record.times.get("created") or "")[:10].replace("-", "")
    serial = "".join(c if c.isalnum() or c in "-_" else "-" for c in record.serial_number)
    return "-".join(x for x in ("SI", serial, date, digest.hexdigest()[:8].upper()) if x)


def collect_inputs(record: RecordView, data: Sequence[str | PathLike[str]]) -> list[sections.InputFile]:
    """Rows of the inputs table; a data file the record does not list is an :class:`InputError`."""
    hashed = [(p, sha256_file(p)) for p in data]
    given = {digest: Path(p).name for p, digest in hashed}
    recorded = {digest: name for name, digest in record.inputs}
    rows = []
    if record.path:
        rows.append(sections.InputFile("calibration record", Path(record.path).name, record.sha256, "read by this report"))
    for name, digest in record.inputs:
        check = f"verified: {given[digest]} given to this report" if digest in given else "listed in the record; not given to this report"
        rows.append(sections.InputFile("calibration input", name, digest, check))
    for path, digest in hashed:
        if digest in recorded:
            continue
        if record.inputs:
            raise InputError(
                f"SHA-256 {digest} is not among the {len(record.inputs)} inputs the calibration record lists",
                path=path,
                expected="a data file this calibration was made from",
            )
        rows.append(sections.InputFile("data", Path(path).name, digest, "the record lists no inputs"))
    return rows


def read_discovery(path: str | PathLike[str]) -> dict[str, Any]:
    """The JSON document of ``stableins diagnose --json`` (checked for its two lists)."""
    try:
        document = json.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError("no such file", path=path, expected="the output of 'stableins diagnose --json'") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as error:
        raise InputError(f"cannot read JSON ({error})", path=path, expected="the output of 'stableins diagnose --json'") from None
    if not isinstance(document, dict) or not isinstance(document.get("history"), list) or not isinstance(document.get("candidates"), list):
        raise InputError("no 'history' and 'candidates' lists", path=path, expected="the output of 'stableins diagnose --json'")
    return document


def write_report(
    out: str | PathLike[str],
    record: Any,
    *,
    data: Sequence[str | PathLike[str]] = (),
    previous: Any = None,
    procedure: str | PathLike[str] | None = None,
    tolerances: Tolerances | None = None,
    fits: Sequence[Any] = (),
    report_id: str | None = None,
    issued: dt.datetime | None = None,
    discovery: str | PathLike[str] | None = None,
) -> ReportSummary:
    """Write the calibration report of ``record`` to ``out`` (PDF).

    Parameters
    ----------
    out : path
        PDF to write (atomically).
    record : path, mapping, RecordView or object with ``to_dict()``
        The calibration record.
    data : sequence of paths
        Data files of the calibration; their SHA-256 are checked against the record.
    previous : same types as ``record``, optional
        Previous calibration record of the unit, for the change section.
    procedure : path, optional
        Procedure definition (TOML) whose ``[tolerances]`` table gives the conformity limits.
    tolerances : Tolerances, optional
        Limits given directly (overrides ``procedure``).
    fits : sequence of FitResult or stage dictionaries, optional
        Stage results in memory (``stableins run``); otherwise the record's ``stages``.
    report_id : str, optional
        Id to print; by default :func:`report_id_for`.
    issued : datetime, optional
        Date of issue (default: now, UTC).
    discovery : path, optional
        Output of ``stableins diagnose --json`` (ranked candidates and refit history).

    Returns
    -------
    ReportSummary
    """
    import stableins

    view = RecordView.from_any(record)
    previous_view = RecordView.from_any(previous) if previous is not None else None
    where = view.path or "calibration record"
    inputs = collect_inputs(view, data)
    evidence_notes: list[str] = []
    if not fits and not view.stages and data:
        from stableins.reporting.replay import device_fits

        fits, evidence_notes = device_fits(data, noise=view.noise_model)
    stages: list[StageEvidence] = [stage_evidence(f, where) for f in (fits or view.stages)]
    extra_terms = [t for f in fits if not isinstance(f, dict) for t in getattr(f, "terms", ())]
    terms = content.known_terms(extra_terms)
    rows = content.parameter_rows(view, terms)
    if previous_view is not None:
        inputs.append(
            sections.InputFile(
                "previous record",
                Path(previous_view.path).name if previous_view.path else "in memory",
                previous_view.sha256 or "—",
                "read by this report",
            )
        )
    if tolerances is None:
        if procedure is not None:
            tolerances = Tolerances.from_procedure_file(str(procedure))
        else:
            tolerances = Tolerances.from_mapping(
                view.procedure.get("tolerances"), source=f"{Path(where).name}, provenance.procedure.tolerances"
            )
    if procedure is not None:
        inputs.append(sections.InputFile("procedure", Path(procedure).name, sha256_file(procedure), "tolerances read from it"))

    changes = skipped = None
    if previous_view is not None:
        changes, skipped = content.compare(rows, content.parameter_rows(previous_view, terms))
    checks = content.conformity(rows, changes, stages, tolerances)

    discovery_document, discovery_source = view.discovery, "calibration record"
    if discovery is not None:
        discovery_document, discovery_source = read_discovery(discovery), Path(discovery).name
        inputs.append(sections.InputFile("model discovery", Path(discovery).name, sha256_file(discovery), "read by this report"))

    issued = issued or dt.datetime.now(dt.UTC)
    ctx = sections.ReportContext(
        record=view,
        report_id=report_id or report_id_for(view, [f.sha256 for f in inputs]),
        issued=issued.strftime("%Y-%m-%d %H:%M UTC"),
        rows=rows,
        stages=stages,
        inputs=inputs,
        tolerances=tolerances,
        checks=checks,
        previous=previous_view,
        changes=changes,
        skipped_changes=skipped or [],
        software_version=stableins.__version__,
        evidence_notes=evidence_notes,
        discovery=discovery_document,
        discovery_source=discovery_source,
    )
    story = [flowable for section in sections.SECTIONS for flowable in section(ctx)]
    buffer = io.BytesIO()
    pages = document.build(
        story,
        buffer,
        title=TITLE,
        report_id=ctx.report_id,
        serial=view.serial_number,
        footer=f"stableins {stableins.__version__}  ·  issued {ctx.issued}  ·  not to be reproduced except in full",
        subject=f"Accelerometer calibration of unit {view.serial_number}",
    )
    pdf = buffer.getvalue()
    with atomic_write(out, "wb") as handle:
        handle.write(pdf)
    verdict = content.overall_verdict(checks) if not tolerances.empty else "NO STATEMENT"
    return ReportSummary(str(out), ctx.report_id, pages, verdict, hashlib.sha256(pdf).hexdigest())
