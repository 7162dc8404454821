"""The gathered content of a report (:class:`ReportContext`) and the small text helpers its sections share."""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path

from reportlab.platypus import Paragraph

from stableins.discovery.diagnose_report import DiagnoseReport
from stableins.history import Comparison
from stableins.records import CalibrationRecord
from stableins.reporting import document, rounding
from stableins.reporting.budget import Budget
from stableins.reporting.content import ChangeRow, Check, ParameterRow
from stableins.reporting.evidence import StageEvidence
from stableins.reporting.symbols import MINUS, prose
from stableins.reporting.tolerances import Tolerances

NOT_RECORDED = "not recorded"


@dataclass(frozen=True)
class ReportInput:
    """One input of the report and its SHA-256, with how it was checked."""

    role: str
    name: str
    sha256: str
    check: str = ""


@dataclass
class ReportContext:
    """Everything a report states, gathered before layout."""

    record: CalibrationRecord
    report_id: str
    issued: str
    rows: list[ParameterRow]
    stages: list[StageEvidence]
    inputs: list[ReportInput]
    tolerances: Tolerances
    checks: list[Check]
    budget: Budget | None = None
    record_path: str = ""
    previous: CalibrationRecord | None = None
    previous_path: str | None = None
    previous_rows: list[ParameterRow] | None = None
    comparison: Comparison | None = None
    changes: list[ChangeRow] | None = None
    software_version: str = ""
    evidence_notes: list[str] = field(default_factory=list)
    figures: int = 0
    discovery: DiagnoseReport | None = None
    discovery_source: str = "calibration record"
    shown_notes: set[str] = field(default_factory=set)
    #: laboratory, customer, operator ("" where not stated: the documents are a DRAFT)
    identification: dict[str, str] = field(default_factory=dict)
    #: made from simulated data (every page says so)
    simulated: bool = False
    #: the technical report, named with its SHA-256 by the certificate (None while it is itself laid out)
    technical: ReportInput | None = None

    def figure_label(self) -> str:
        """Return "Figure n.", n counting the figures in the order they are laid out."""
        self.figures += 1
        return f"Figure {self.figures}."

    def row(self, parameter_id: str) -> ParameterRow | None:
        """Return the results row of a parameter (None: not in the results)."""
        return next((r for r in self.rows if r.id == parameter_id), None)

    def text(self, note: str) -> str:
        """Return a note of the record for people (symbols, words for flags, file names), remembered as shown."""
        self.shown_notes.add(note)
        return prose(note, self.record.ids)


def paragraph(text: str, style: str = "body") -> Paragraph:
    """Return ``text`` (reportlab markup) as a paragraph of the certificate's ``style``."""
    return Paragraph(text, document.styles()[style])


def no_statement(tolerances: Tolerances) -> Paragraph:
    """Return the paragraph that says why no statement of conformity is made (certificate and technical report alike)."""
    from stableins.reporting.content import no_statement_text

    text = document.escape(no_statement_text(tolerances.source))
    return paragraph(text.replace("No statement of conformity", "<b>No statement of conformity</b>", 1))


def verdict_colour_hex(verdict: str) -> str:
    """Return the colour a verdict is printed in, as reportlab markup wants it (``#rrggbb``)."""
    return document.VERDICT_COLOURS.get(verdict.lower(), document.VERDICT_COLOURS["not assessed"]).hexval()


def fmt(x: float, significant: int = 3) -> str:
    """Return a number to ``significant`` digits as the certificate prints it (a dash when not finite)."""
    return rounding.significant_digits(x, significant) if math.isfinite(x) else "—"


def degrees(radians: float) -> str:
    """Return an angle in degrees to six decimals, with a typographic minus."""
    return f"{math.degrees(radians):.6f}°".replace("-", MINUS)


def file_name(path: str | None) -> str:
    """Return a file as a certificate names it: its file name, as written (no folders, no capitals added)."""
    return Path(path).name if path else "in memory"


def entry_text(record: CalibrationRecord, key: str) -> str | None:
    """Return the text of the record's entry ``key`` (None: no such entry)."""
    for e in record.entries:
        if e.key == key:
            return e.text()
    return None


#: The procedure name of a record made from a log of static poses (``stableins calibrate poses``).
POSES_PROCEDURE = "poses"


def from_poses(record: CalibrationRecord) -> bool:
    """Return whether the record was made from static poses of a triad (``calibrate poses``), not on a gimbaled system."""
    return bool(record.stages_run) and all(s.procedure == POSES_PROCEDURE for s in record.stages_run)


def item_calibrated(record: CalibrationRecord) -> str:
    """Return what the documents say was calibrated: the accelerometer of a gimbaled INS, or a triad from its static poses."""
    if from_poses(record):
        return f"tri-axis accelerometer (a triad, calibrated from static poses), serial number {record.serial_number}"
    return f"tri-axis accelerometer of a space-stable (gimbaled) INS, serial number {record.serial_number}"


def angle_reference(record: CalibrationRecord) -> str:
    """Return how the documents say angles are realized (traceability): the gimbals' angle sensors, or the triad's own axes."""
    if from_poses(record):
        return (
            "No angle reference took part: the squared amplitude of the outputs is compared with g², so the triad's "
            "non-orthogonality is determined relative to its own axes and its orientation is not."
        )
    return "Angles are realized by the system's own gimbal angle sensors, whose zero offsets are part of the model."


def period(record: CalibrationRecord) -> str:
    """Return when the calibration was performed: the times of its data, else when the record was created."""
    p = record.provenance
    if p.data_start and p.data_end:
        return f"{p.data_start} to {p.data_end} (data of the stages run)"
    if p.data_start or p.data_end:
        return p.data_start or p.data_end
    if p.created:
        return f"record created {p.created} (times of the data not recorded)"
    return NOT_RECORDED


def span(start: str, end: str) -> str:
    """Return the span of a stage's data in UTC as a table prints it."""
    if start and end:
        return f"{utc(start)} to {utc(end)}"
    return utc(start or end) or NOT_RECORDED


def utc(text: str) -> str:
    """Return an ISO 8601 time in UTC as a table prints it (``2026-11-22 02:46:58``); other times as written."""
    match = re.fullmatch(r"(\d{4}-\d\d-\d\d)T(\d\d:\d\d:\d\d)(?:\.\d+)?(?:Z|\+00:00)?", text or "")
    return f"{match.group(1)} {match.group(2)}" if match else text
