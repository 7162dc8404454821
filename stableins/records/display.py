"""What people see of a record: its parameter table in engineering units (console, Jupyter, pandas)."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

from stableins.status import Status

if TYPE_CHECKING:  # pragma: no cover
    from stableins.records.content import RecordContent


def record_rows(record: RecordContent) -> list[tuple[str, float, float, str, str, str]]:
    """Return ``(id, value, σ, unit, status, determined by)`` in engineering units where the id is a known term."""
    from stableins.discovery.library import all_terms

    terms = all_terms()  # discovered terms in engineering units too
    out = []
    for p in record.parameters:
        t = terms.get(p.id)
        value, sigma, unit = (
            (float(t.to_engineering(p.value)), float(t.sigma_to_engineering(p.sigma)), t.unit) if t else (p.value, p.sigma, p.unit)
        )
        out.append((p.id, value, sigma, unit, p.status.value, source_text(record, p.id)))
    return out


def source_text(record: RecordContent, parameter_id: str) -> str:
    """Return which stage last determined the parameter, how, and whether in this calibration (console and certificate)."""
    last = record.last_determined_by(parameter_id)
    if last is None:
        return "—"
    run, how = last
    when = (run.data_end or run.created)[:10]
    text = f"{run.name} ({how.value}{', ' + when if when else ''})"
    return text if run.calibration == record.calibration.id else f"{text}, carried over"


def report(record: RecordContent) -> str:
    """Return a plain-text table in engineering units: value, 1σ, status and the stage that last determined each parameter."""
    from stableins.display import parameter_table

    run = ", ".join(s.name for s in record.stages_run) or "none"
    lines = [f"calibration record of {record.serial_number} (stages run: {run}; {record.calibration.software})", ""]
    lines += parameter_table(record_rows(record), record.determined, record.notes)
    if record.discovery is not None:
        lines += ["", record.discovery.report()]
    return "\n".join(lines)


def _summary_lines(record: RecordContent) -> list[str]:
    from stableins.display import plural

    run = ", ".join(s.name for s in record.stages_run) or "none"
    lines = [
        f"calibration {record.calibration.id} ({record.calibration.software}); stages run: {run}; valid from {record.valid_from or '—'}"
    ]
    carried = len(record.stages) - len(record.stages_run)
    if carried:
        lines[0] += f"; rests on {plural(carried, 'earlier stage run')}"
    return lines


def _discovery_line(record: RecordContent) -> str | None:
    if record.discovery is None:
        return None
    verdicts = [f"{s.added[0][0]} {s.decision}" for s in record.discovery.steps[1:] if s.decision is not None and s.added]
    return "discovery: " + ("; ".join(verdicts) if verdicts else "baseline only")


def _noise_line(record: RecordContent) -> str | None:
    model: Any = record.noise_model
    if model is None:
        return None
    describe = getattr(model, "describe", None)
    if callable(describe):
        return str(describe())
    return f"noise model: {model.get('source', '')}" + (f" ({model['provenance']})" if model.get("provenance") else "")


def summary(record: RecordContent) -> list[str]:
    """Return the record's short form as lines: counts, calibration, the parameters grouped by kind, discovery, noise model.

    The ``repr`` of a record and the default console of ``stableins calibrate device`` (about a screen; the full report
    with ``--verbose``).
    """
    from stableins.display import parameter_lines, status_counts

    counts = status_counts(p.status for p in record.parameters)
    head = f"<CalibrationRecord of {record.serial_number}: {len(record.parameters)} parameters ({counts})>"
    lines = [head, *_summary_lines(record), *parameter_lines(row[:5] for row in record_rows(record))]
    return lines + [line for line in (_discovery_line(record), _noise_line(record)) if line]


def text_repr(record: RecordContent) -> str:
    """Return the record's short text form: counts, calibration, the first parameter rows, discovery and noise model."""
    from stableins.display import clipped

    return clipped(summary(record), "(print(record) for the full report, record.to_dataframe() for the table)")


def html_repr(record: RecordContent) -> str:
    """Return the record as HTML for Jupyter: the parameter table with each term's meaning, the discovery history."""
    from stableins.discovery.library import all_terms
    from stableins.display import html_result, parameter_html

    terms = all_terms()
    meanings = [terms[p.id].meaning if p.id in terms else "" for p in record.parameters]
    tables = [parameter_html(record_rows(record), meanings, extra="last determined by")]
    if record.discovery is not None:
        tables.append(record.discovery._repr_html_())
    return html_result(
        f"Calibration record of {record.serial_number}",
        [*_summary_lines(record), _noise_line(record) or ""],
        tables,
        [("determined combinations", record.determined), ("notes", record.notes)],
    )


def dataframe(record: RecordContent) -> Any:
    """Return the parameter table as a :class:`pandas.DataFrame` indexed by parameter id (:meth:`CalibrationRecord.to_dataframe`)."""
    from stableins.display import require_pandas

    pandas = require_pandas()
    out = []
    for (pid, value, sigma, unit, status, source), p in zip(record_rows(record), record.parameters, strict=True):
        hidden = p.status is Status.UNIDENTIFIABLE
        nan = math.nan
        out.append(
            {
                "parameter": pid,
                "value": nan if hidden else value,
                "sigma": nan if hidden else sigma,
                "unit": unit,
                "status": status,
                "determined_by": source,
                "value_si": nan if hidden else p.value,
                "sigma_si": nan if hidden else p.sigma,
                "si_unit": p.unit,
            }
        )
    return pandas.DataFrame.from_records(out, index="parameter")
