"""Content builders, one per report section (ISO/IEC 17025:2017 7.8 and the GUM as the checklist).

Each builder takes the :class:`ReportContext` and returns flowables.  A section whose
evidence the record does not carry says so ("not performed" / "not recorded"); no
number is ever made up.  Parameters are printed with their typeset symbols
(:mod:`stableins.reporting.symbols`), values and uncertainties through the one GUM rounding
(:func:`stableins.reporting.content.gum`), text from the record through
:func:`stableins.reporting.symbols.prose` (no command-line syntax, no machine paths).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from reportlab.platypus import Flowable, KeepTogether, Paragraph

from stableins.discovery.diagnose_report import DiagnoseReport
from stableins.history import CHANGE_THRESHOLD, Comparison
from stableins.records import CalibrationRecord
from stableins.reporting import content, document, figures
from stableins.reporting.budget import GROUPS, SHORT, TITLES, Budget
from stableins.reporting.content import MINUS, ChangeRow, Check, ParameterRow
from stableins.reporting.document import escape, heading
from stableins.reporting.evidence import StageEvidence
from stableins.reporting.symbols import markup, prose
from stableins.reporting.tolerances import RULE_TEXT, Tolerances

NOT_RECORDED = "not recorded"


@dataclass(frozen=True)
class InputFile:
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
    inputs: list[InputFile]
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

    def figure_label(self) -> str:
        """ "Figure n." with n counting the figures in the order they are laid out."""
        self.figures += 1
        return f"Figure {self.figures}."

    def row(self, parameter_id: str) -> ParameterRow | None:
        return next((r for r in self.rows if r.id == parameter_id), None)

    def text(self, note: str) -> str:
        """A note of the record for people (symbols, words for flags, file names), remembered as shown."""
        self.shown_notes.add(note)
        return prose(note, self.record.ids)


def _p(text: str, style: str = "body") -> Paragraph:
    return Paragraph(text, document.styles()[style])


def _fmt(x: float, significant: int = 3) -> str:
    return content.number(x, significant) if math.isfinite(x) else "—"


def _degrees(radians: float) -> str:
    return f"{math.degrees(radians):.6f}°".replace("-", MINUS)


def _name(path: str | None) -> str:
    """A file as a certificate names it: its file name, as written (no folders, no capitals added)."""
    return Path(path).name if path else "in memory"


# ---------------------------------------------------------------------- title
def _entry(record: CalibrationRecord, key: str) -> str | None:
    for e in record.entries:
        if e.key == key:
            return e.text()
    return None


def title_block(ctx: ReportContext) -> list[Flowable]:
    r = ctx.record
    extra = r.site.extra if r.site else {}

    def field_text(key: str, default: str) -> str:
        return _entry(r, key) or str(extra.get(key, default))

    rows = [
        ["Report id", ctx.report_id],
        ["Item calibrated", f"tri-axis accelerometer of a space-stable (gimbaled) INS, unit serial number {r.serial_number}"],
        ["Laboratory", field_text("laboratory", NOT_RECORDED)],
        ["Customer", field_text("customer", NOT_RECORDED)],
        ["Operator", field_text("operator", NOT_RECORDED)],
        ["Location of calibration", field_text("location", "on the system, at the site described in section 2")],
        ["Calibration performed", _period(r)],
        ["Procedure", r.calibration.procedure or NOT_RECORDED],
        ["Date of issue", ctx.issued],
        [
            "Software",
            f"stableins {ctx.software_version} (this certificate); calibration by {r.calibration.software or NOT_RECORDED} "
            f"(record schema {r.schema_version})",
        ],
    ]
    return [
        _p("Calibration certificate", "title"),
        _p("On-system calibration of the tri-axis accelerometer of a space-stable inertial navigation system", "subtitle"),
        document.table(rows, [0.24, 0.76], header_rows=0, key_value=True),
        document.spacer(2),
        _p(
            "The results relate only to the item calibrated, at the time and under the conditions stated. This report shall not be "
            "reproduced except in full without the written approval of the issuing laboratory.",
            "small",
        ),
    ]


def _period(record: CalibrationRecord) -> str:
    p = record.provenance
    if p.data_start and p.data_end:
        return f"{p.data_start} to {p.data_end} (data of the stages run)"
    if p.data_start or p.data_end:
        return p.data_start or p.data_end
    if p.created:
        return f"record created {p.created} (times of the data not recorded)"
    return NOT_RECORDED


def _span(start: str, end: str) -> str:
    if start and end:
        return f"{_utc(start)} to {_utc(end)}"
    return _utc(start or end) or NOT_RECORDED


def _utc(text: str) -> str:
    """An ISO 8601 time in UTC as a table prints it (``2026-11-22 02:46:58``); other times as written."""
    match = re.fullmatch(r"(\d{4}-\d\d-\d\d)T(\d\d:\d\d:\d\d)(?:\.\d+)?(?:Z|\+00:00)?", text or "")
    return f"{match.group(1)} {match.group(2)}" if match else text


# ---------------------------------------------------------------------- 1 method
def method(ctx: ReportContext) -> list[Flowable]:
    r = ctx.record
    out: list[Flowable] = [*heading("1  Procedure and method")]
    out.append(
        _p(
            "Multi-position self-calibration on the system's own gimbals: the platform is turned to a sequence of positions and the "
            "accelerometer outputs are compared with local gravity resolved through the exact gimbal kinematics; at system level the "
            "Earth-rate harmonics of the specific-force error on a static base are separated into accelerometer corrections (after "
            "Wu et al., Sensors 2018, 18, 2888, with the physics re-derived and sign errors corrected). Each stage is a Bayesian update "
            "of the record before it: no uncertainty grows, nothing moves along what its data do not determine."
        )
    )
    rows: list[list[Any]] = [["Stage", "Procedure", "Data (UTC)", "Sample rate", "Settings"]]
    for s in r.stages_run:
        rate = f"{s.sample_rate:g} Hz" if s.sample_rate else NOT_RECORDED
        settings = prose(content.describe_settings(s.settings), markup_symbols=False)
        rows.append([escape(s.name), escape(s.procedure or NOT_RECORDED), escape(_span(s.data_start, s.data_end)), rate, settings])
    out += heading(f"Stages run in this calibration ({escape(r.calibration.id)})", "h2")
    if len(rows) > 1:
        out.append(document.table(rows, [0.13, 0.17, 0.24, 0.09, 0.37], markup=True))
    else:
        out.append(_p("None recorded."))
    earlier = [s for s in r.stages if s.calibration != r.calibration.id]
    if earlier:
        out += heading("Stages of earlier calibrations the record carries over", "h2")
        rows = [["Stage", "Procedure", "Data (UTC)", "Calibration"]]
        rows += [[s.name, s.procedure or NOT_RECORDED, _span(s.data_start, s.data_end), s.calibration] for s in earlier]
        out.append(document.table(rows, [0.14, 0.22, 0.38, 0.26]))
    if r.calibration.prior is not None:
        prior = r.calibration.prior
        out.append(
            _p(
                f"This calibration updates the record in force before it: {escape(_name(prior.path) if prior.path else 'record')} "
                f"(SHA-256 {escape(prior.sha256[:16])}…, created {escape(prior.created or NOT_RECORDED)}).",
                "small",
            )
        )
    return out


# ---------------------------------------------------------------------- 2 site
def site_environment(ctx: ReportContext) -> list[Flowable]:
    out: list[Flowable] = [*heading("2  Site and environment")]
    site = ctx.record.site
    if site is None:
        out.append(
            _p(
                "Site metadata: not recorded in the calibration record. "
                "Local gravity, the reference of this calibration, is therefore not stated."
            )
        )
    else:
        yaw, pitch, roll = site.base_attitude
        source = ctx.budget.source("gravity") if ctx.budget is not None else None
        rows = [
            ["Quantity", "Value"],
            ["latitude (geodetic)", _degrees(site.latitude)],
            ["height (ellipsoidal)", f"{site.height:.1f} m".replace("-", MINUS)],
            ["local gravity g", f"{site.gravity:.7f} m/s²"],
            ["source of g", site.gravity_source],
            ["standard uncertainty of g", f"{source.uncertainty} ({source.origin})" if source is not None else NOT_RECORDED],
            ["base attitude (yaw, pitch, roll)", f"{_degrees(yaw)}, {_degrees(pitch)}, {_degrees(roll)} (site survey)"],
            ["gimbal rotation senses (s1..s4)", ", ".join(f"{s:+d}" for s in site.gimbal_senses)],
            ["reference temperature", f"{site.reference_temperature:.1f} °C"],
        ]
        for s in ctx.record.stages_run:
            rows.append([f"instrument temperature ({s.name})", _temperature(s.environment)])
        if not ctx.record.stages_run:
            rows.append(["instrument temperature", f"{NOT_RECORDED} in the calibration record"])
        out.append(document.table(rows, [0.32, 0.68], key_value=True))
    entries = [(e, "calibration") for e in ctx.record.calibration.entries] + [(e, s.name) for s in ctx.record.stages_run for e in s.entries]
    out += heading("Entries made during the calibration", "h2", room_mm=20)
    if entries:
        rows = [["Entry", "Value", "Asked as", "Stage"]]
        rows += [[e.key.replace("_", " "), e.text(), e.prompt or "—", where] for e, where in entries]
        out.append(document.table(rows, [0.22, 0.22, 0.38, 0.18]))
    else:
        out.append(_p("None: no value was entered by a person during this calibration."))
    if site is not None:
        out.append(
            _p(
                "Metrological traceability: the reference quantity of this calibration is the local gravity g stated above; scale "
                "factors are traceable to the SI through it and its source. Angles are realized by the system's own gimbal angle sensors, "
                "whose zero offsets are part of the model. Biases and installation angles are determined relative to these references.",
                "small",
            )
        )
    return out


def _temperature(environment: Any) -> str:
    temperature = environment.get("temperature") if isinstance(environment, dict) else None
    if isinstance(temperature, dict) and "mean" in temperature:
        text = f"mean {float(temperature['mean']):.2f} °C"
        if "min" in temperature and "max" in temperature:
            text += f", range {float(temperature['min']):.2f} to {float(temperature['max']):.2f} °C"
        return text + " (from the data)"
    return f"{NOT_RECORDED} in the data"


# ---------------------------------------------------------------------- 3 inputs
def inputs(ctx: ReportContext) -> list[Flowable]:
    rows: list[list[Any]] = [["Role", "File", "SHA-256", "Check"]]
    for f in ctx.inputs:
        rows.append([f.role, _name(f.name), f.sha256, prose(f.check, markup_symbols=False)])
    out: list[Flowable] = [*heading("3  Inputs and their integrity")]
    out.append(
        _p(
            "SHA-256 digests of every file this calibration and this report were made from (file names without their folders). "
            "A file whose digest differs is not the file used."
        )
    )
    out.append(document.table([[escape(c) if i != 3 else c for i, c in enumerate(r)] for r in rows], [0.14, 0.25, 0.41, 0.20],
                              mono=(2,), markup=True))  # fmt: skip
    return out


# ---------------------------------------------------------------------- 4 results
def results(ctx: ReportContext) -> list[Flowable]:
    out: list[Flowable] = [*heading("4  Results", room_mm=60)]
    k = content.COVERAGE_FACTOR
    out.append(
        _p(
            "Values of the record in force after this calibration, in engineering units: scale factors SF as deviation from 1 in ppm, "
            "biases δb in µg, angles in arcsec, quadratic nonlinearity K<sub>2</sub> in µg/g² (1 g = 9.80665 m/s², the conventional "
            f"value, for units only). u is the combined standard uncertainty of section 5 (Type A and Type B); U = k·u with k = {k:g}. "
            "U and u are given to two significant digits and the value to the last digit of U (GUM 7.2.6). 'Last determined by' "
            "names the stage whose data last saw the parameter, alone or only in combination with others; a parameter no stage of "
            "this calibration saw is 'carried over' from an earlier one."
        )
    )
    header = ["Parameter", "Status", "Value", "u", f"U (k = {k:g})", "Unit", "Last determined by"]
    rows: list[list[Any]] = [header]
    for row in ctx.rows:
        r = row.rounded()
        rows.append([row.symbol, row.status.value, r.value, r.u, r.expanded, escape(row.unit), escape(row.source)])
    out.append(document.table(rows, [0.11, 0.14, 0.11, 0.08, 0.10, 0.09, 0.37], align_right=(2, 3, 4), markup=True))
    carried = [r for r in ctx.rows if r.estimated and not r.measured]
    if carried:
        out.append(
            _p(
                f"Carried over, not re-measured in this calibration: {', '.join(r.symbol for r in carried)} "
                "(value and u as the earlier calibration determined them, updated only through their correlation with what was "
                "measured).",
                "small",
            )
        )
    not_estimated = [r for r in ctx.rows if not r.estimated]
    if not_estimated:
        out += heading("Parameters not estimated", "h2", room_mm=20)
        rows = [["Parameter", "Status", "Why"]]
        rows += [[r.symbol, r.status.value, ctx.text(r.why) if r.why else NOT_RECORDED] for r in not_estimated]
        out.append(document.table(rows, [0.14, 0.16, 0.70], markup=True))
    determined = [(s.name, d) for s in ctx.record.stages_run if s.name != "system" for d in s.determined]  # system: section 7
    if determined:
        out += heading("Combinations the data determine", "h2", room_mm=20)
        rows = [["Stage", "Combination"]] + [[escape(n), ctx.text(d)] for n, d in determined]
        out.append(document.table(rows, [0.14, 0.86], markup=True))
    out += heading("Symbols", "h2", room_mm=25)
    glossary = [(f'{r.symbol} <font name="{document.FONT_MONO}" size="6.5" color="#5f6b7a">{escape(r.id)}</font>', prose(r.meaning))
                for r in ctx.rows]  # fmt: skip
    half = (len(glossary) + 1) // 2
    rows = [["Symbol (record id)", "Meaning", "Symbol (record id)", "Meaning"]]
    for i in range(half):
        left = glossary[i]
        right = glossary[half + i] if half + i < len(glossary) else ("", "")
        rows.append([left[0], left[1], right[0], right[1]])
    out.append(document.table(rows, [0.15, 0.35, 0.15, 0.35], markup=True))
    return out


# ---------------------------------------------------------------------- 5 budget
def uncertainty(ctx: ReportContext) -> list[Flowable]:
    """The uncertainty budget (GUM): Type A from the record, each Type B input, combined u, k and U per parameter."""
    out: list[Flowable] = [*heading("5  Uncertainty budget", room_mm=50)]
    budget = ctx.budget
    k = content.COVERAGE_FACTOR
    if budget is None:
        out.append(_p("<b>Not evaluated</b>: no budget was computed for this record."))
        return out
    out.append(
        _p(
            "Evaluated per the GUM (JCGM 100:2008). <b>Type A</b> (GUM 4.2): the record's covariance, from the noise measured in the "
            "calibration data, propagated by least squares and the Bayesian update of each stage. <b>Type B</b> (GUM 4.3): what the "
            "stages take as known. Each input's sensitivity coefficient is derived through the record itself: every stage enters the "
            "record through the information vector of its likelihood, so an input error δq moves the values by "
            "δx = P Σ<sub>k</sub> (∂η<sub>k</sub>/∂q) δq (P the record's covariance); ∂η<sub>k</sub>/∂q is computed when the stage "
            "runs, by re-running the system stage with the input perturbed and from the fit's Jacobian for the angle readings, and "
            "exactly for g (docs/reports.md). The contributions are combined in quadrature, u<sub>c</sub>² = u<sub>A</sub>²&nbsp;+&nbsp;"
            f"Σ&nbsp;u<sub>i</sub>² (GUM 5.1.2, inputs uncorrelated), and U = k·u<sub>c</sub> with coverage factor k = {k:g} (about "
            "95 % coverage for a normal distribution, GUM 6.3). Conformity decisions (section 10) use this U. The record itself "
            "keeps the Type A covariance."
        )
    )
    out += heading("Type B inputs", "h2", room_mm=25)
    rows: list[list[Any]] = [["Input", "Value used", "Standard uncertainty", "Distribution", "Source of the uncertainty", "Effect"]]
    for s in budget.sources:
        rows.append([TITLES[s.group], prose(s.value), prose(s.uncertainty), s.distribution, prose(s.origin), prose(s.effect)])
    out.append(document.table(rows, [0.13, 0.16, 0.12, 0.13, 0.21, 0.25], markup=True))
    out += heading("Budget per parameter", "h2", room_mm=35)
    head = ["Parameter", "Unit", "Type A u<sub>A</sub>", *[SHORT[g] for g in GROUPS], "u<sub>c</sub>", f"U (k = {k:g})"]
    rows = [head]
    for row in ctx.rows:
        if not row.estimated or not (row.u > 0):
            continue
        decimals = content.decimals_of(row.u)
        term_scale = row.u / budget.combined_of(row.id) if budget.combined_of(row.id) > 0 else math.nan

        def cell(si: float, group: str = "", decimals: int = decimals, scale: float = term_scale) -> str:
            state = budget.state(group) if group else "evaluated"
            if state != "evaluated":
                return "n.e." if state == "not evaluated" else "—"
            return f"{si * scale:.{decimals}f}"

        r = row.rounded()
        rows.append(
            [row.symbol, escape(row.unit), cell(budget.type_a[budget.ids.index(row.id)])]
            + [cell(budget.contribution(g, row.id), g) for g in GROUPS]
            + [r.u, r.expanded]
        )
    widths = [0.12, 0.08, 0.10, 0.08, 0.10, 0.08, 0.10, 0.08, 0.10, 0.12]
    out.append(document.table(rows, widths, align_right=tuple(range(2, 10)), markup=True))
    not_evaluated = [TITLES[s.group] for s in budget.sources if s.state == "not evaluated"]
    text = (
        "Standard uncertainties in the unit of each parameter, given to the decimal place of u<sub>c</sub> (a contribution below "
        "it shows as 0). Columns: local gravity g, gimbal angle sensors, instrument temperature (temp.), gyro drift, damping loop; "
        "—: the input does not apply to this record or is stated as a condition of validity (see the inputs above)."
    )
    if not_evaluated:
        text += f" n.e.: not evaluated ({escape(', '.join(not_evaluated))}); it is not in u<sub>c</sub>."
    out.append(_p(text, "small"))
    if budget.conditions:
        out += heading("Conditions of validity", "h2", room_mm=15)
        for condition in budget.conditions:
            out.append(_p(prose(condition)))
    out.append(_p(_uncertainty_statement(ctx), "small"))
    return out


def _uncertainty_statement(ctx: ReportContext) -> str:
    text = "Uncertainties are not scaled by χ²<sub>ν</sub>; "
    high = [s for s in ctx.stages if s.dof > 0 and s.chi2_red > s.chi2_red_interval()[1]]
    if high:
        names = ", ".join(f"{escape(s.stage)} (χ²<sub>ν</sub> = {content.chi2_text(s.chi2_red)})" for s in high)
        text += (
            f"<b>caution</b>: the residuals of {names} exceed the noise by more than chance allows, so effects outside the model "
            "are present and u may understate the error (section 7)."
        )
    elif ctx.stages:
        text += "the residuals agree with the noise (section 7), so no unmodelled effect is seen at this level."
    else:
        text += "no residual evidence was available to check this (section 7)."
    return text


# ---------------------------------------------------------------------- 6 correlation
def correlations(ctx: ReportContext) -> list[Flowable]:
    out: list[Flowable] = [*heading("6  Correlation of the estimates", room_mm=40)]
    ids, matrix = content.correlation(ctx.record)
    if len(ids) < 2:
        out.append(_p("Not shown: the calibration record carries no covariance of two or more estimated parameters."))
        return out
    strong = sorted(
        ((abs(matrix[i][j]), ids[i], ids[j], matrix[i][j]) for i in range(len(ids)) for j in range(i)),
        reverse=True,
    )
    strong = [s for s in strong if s[0] >= 0.5]
    out.append(
        _p(
            "Correlation coefficients ρ of the estimates (the record's covariance, Type A). A user who propagates these results "
            "into another quantity must use the correlations; pairs with |ρ| ≥ 0.5: "
            + (", ".join(f"{markup(a)}–{markup(b)} {f'{rho:+.2f}'.replace('-', MINUS)}" for _, a, b, rho in strong) if strong else "none")
            + "."
        )
    )
    png, aspect = figures.correlation_matrix(ids, matrix)
    caption = (
        f"{ctx.figure_label()} Correlation coefficients of the {len(ids)} estimated parameters (lower triangle); "
        "the coefficients with |ρ| ≥ 0.3 are written in their cells."
    )
    out.append(document.figure(png, figures.CORRELATION_WIDTH / figures.FULL_WIDTH, aspect, caption, min_scale=0.75))
    return out


# ---------------------------------------------------------------------- 7 evidence
def evidence(ctx: ReportContext) -> list[Flowable]:
    out: list[Flowable] = [*heading("7  Evidence that the model fits", room_mm=50)]
    for note in ctx.evidence_notes:
        out.append(_p(prose(note) + ".", "small"))
    if not ctx.stages:
        out.append(
            _p(
                "Residual analysis: <b>not performed</b>; the calibration record carries no residual evidence of its stages "
                "and no device-level data file was given."
            )
        )
    else:
        rows: list[list[Any]] = [
            ["Fit", "Stage run", "Obs.", "Rank / param.", "χ²<sub>ν</sub>", "ν", "95\u00a0% interval, noise alone", "Verdict"]
        ]
        colours = {}
        for i, s in enumerate(ctx.stages, start=1):
            low, high = s.chi2_red_interval()
            ok = low <= s.chi2_red <= high
            verdict = "consistent with noise" if ok else ("residuals exceed noise" if s.chi2_red > high else "residuals below noise")
            colours[(i, 7)] = document.VERDICT_COLOURS["pass" if ok else "conditional fail"]
            rows.append(
                [
                    escape(s.stage),
                    escape(s.run or "recomputed"),
                    str(len(s.residuals)),
                    f"{s.rank} / {s.n_parameters}",
                    content.chi2_text(s.chi2_red),
                    str(s.dof),
                    f"{content.chi2_text(low)} to {content.chi2_text(high)}",
                    verdict,
                ]
            )
        widths = [0.12, 0.13, 0.07, 0.12, 0.08, 0.06, 0.20, 0.22]
        out.append(document.table(rows, widths, align_right=(2, 4, 5), cell_colours=colours, markup=True))
        out.append(
            _p(
                "χ²<sub>ν</sub> = Σ(r<sub>i</sub>/σ<sub>i</sub>)²/ν with ν = observations − rank; σ<sub>i</sub> is the noise floor of "
                "observation i measured in the data; where the stage models noise correlated between observations (slow bias drift), "
                "χ² is that of the whitened residuals. Values inside the interval mean the model explains the data down to the noise.",
                "small",
            )
        )
        for s in ctx.stages:
            if s.labels and s.unlabelled == 0:
                png, aspect = figures.residuals_by_position(s)
                groups = s.by_position_axis()
                what = (
                    "per axis and of the specific-force magnitude |f| (fine positions)"
                    if "|f|" in groups and len(groups) > 1
                    else "of the specific-force magnitude |f|"
                    if "|f|" in groups
                    else "per axis"
                )
                caption = (
                    f"{ctx.figure_label()} {escape(s.stage.capitalize())} stage: residual of each position {what}, with ±1σ error "
                    "bars; the grey band is the noise floor (±1σ) measured in the data."
                )
            else:
                png, aspect = figures.normalized_residuals(s)
                what = "combined coefficient" if s.stage == "system" else "observation"
                caption = (
                    f"{ctx.figure_label()} {escape(s.stage.capitalize())} stage: residual of each {what} of the fit divided by its 1σ; "
                    "the grey band is ±1σ, the spread expected from noise alone."
                )
            out.append(document.figure(png, 1.0, aspect, caption))
            out += _notes(ctx, f"Notes of the {s.stage} stage", s.notes)
    out += heading("System-level stage", "h2", room_mm=40)
    out += _system(ctx)
    return out


#: The system stage's determined combinations (docs/system-calibration.md §4): typeset, and how to turn the
#: stored value [rad] into an engineering unit ("bias": × g in µg; "ppm": × 1e6; "angle": arcsec).
SYSTEM_COMBINATIONS = {
    "b_x - beta_xy*sinL": ("δb<sub>x</sub> − g β<sub>xy</sub> sin L", "bias"),
    "b_y + beta_yx*sinL": ("δb<sub>y</sub> + g β<sub>yx</sub> sin L", "bias"),
    "beta_zy": ("β<sub>zy</sub>", "angle"),
    "beta_zx": ("β<sub>zx</sub>", "angle"),
    "(D_x - D_y)/2": ("½(δSF<sub>x</sub>/SF<sub>x</sub> − δSF<sub>y</sub>/SF<sub>y</sub>)", "ppm"),
    "(beta_xz - beta_yz)/2": ("½(β<sub>xz</sub> − β<sub>yz</sub>)", "angle"),
    "x1 = -(D_x+D_y)/2*cos2L - D_z*sin2L + b_z*sinL": (
        "x<sub>1</sub> = −½(D<sub>x</sub> + D<sub>y</sub>) cos²L − D<sub>z</sub> sin²L + (δb<sub>z</sub>/g) sin L",
        "ppm",
    ),
}
_DETERMINED = re.compile(r"^(?P<name>.+?) = (?P<value>[-+0-9.eE]+) ± (?P<sigma>[0-9.eE+-]+)(?P<not> \(NOT determined by these data\))?$")


def system_combination_rows(record: CalibrationRecord, lines: Any) -> list[tuple[str, float, float, str, bool]]:
    """``(typeset name, correction, 1σ, unit, determined)`` of the system stage's determined lines, in engineering units."""
    from stableins.conventions import ARCSEC, MICRO_G, STANDARD_GRAVITY

    g = record.site.gravity if record.site is not None else STANDARD_GRAVITY
    scale = {"bias": (g / MICRO_G, "µg"), "ppm": (1e6, "ppm"), "angle": (1.0 / ARCSEC, "arcsec")}
    out = []
    for line in lines:
        match = _DETERMINED.match(str(line))
        if match is None:
            continue
        name = match.group("name")
        typeset, kind = SYSTEM_COMBINATIONS.get(name, (prose(name), "angle"))
        factor, unit = scale[kind]
        out.append((typeset, float(match.group("value")) * factor, float(match.group("sigma")) * factor, unit, match.group("not") is None))
    return out


def _system(ctx: ReportContext) -> list[Flowable]:
    runs = [s for s in ctx.record.stages_run if s.name == "system"]
    if not runs:
        return [_p("<b>Not performed</b>: no system-level stage ran in this calibration.")]
    out: list[Flowable] = []
    for run in runs:
        fit = next((f for f in run.fits if f.get("stage") == "system"), None)
        chi2 = (
            f"χ²<sub>ν</sub> = {content.chi2_text(float(fit['chi2_red']))} with ν = {fit.get('dof')} (table and figure above). "
            if fit is not None and fit.get("chi2_red") is not None
            else ""
        )
        out.append(
            _p(
                "Separation of the combined coefficients (Earth-rate harmonics of the specific-force error, pitch and roll): "
                f"{chi2}What these data determine: the correction each combination asks of the installed calibration (Δ = true − "
                "installed), with its 1σ from these data alone. The record combines it with the installed values and their "
                "uncertainty (a Bayesian update; the results of section 4)."
            )
        )
        rows: list[list[Any]] = [["Combination", "Correction ± 1σ (these data alone)", "Unit", "Determined"]]
        for name, value, sigma, unit, determined in system_combination_rows(ctx.record, run.determined):
            text = f"{content.round_to_uncertainty(value, sigma)} ± {content.number(sigma, 2)}" if sigma > 0 else _fmt(value)
            rows.append([name, text.replace("-", MINUS), unit, "yes" if determined else "no (short record)"])
        if len(rows) > 1:
            out.append(document.table(rows, [0.50, 0.26, 0.10, 0.14], align_right=(1,), markup=True))
    return out


def _notes(ctx: ReportContext, title: str, notes: Any) -> list[Flowable]:
    """A stage's notes, one per line, in words (:meth:`ReportContext.text`)."""
    notes = [n for n in notes if n]
    if not notes:
        return []
    return [_p(f"<b>{escape(title)}</b>", "small"), *(_p("• " + ctx.text(n), "note") for n in notes)]


# ---------------------------------------------------------------------- 8 discovery
def discovery(ctx: ReportContext) -> list[Flowable]:
    """The model in force (the record's discovery history) and, when given, the diagnosis (``stableins diagnose --json``)."""
    out: list[Flowable] = [*heading("8  Model discovery", room_mm=50)]
    history = ctx.record.discovery.to_json() if ctx.record.discovery is not None else None
    if history:
        out += _model_history(ctx, history)
    if ctx.discovery is not None:
        if history:
            out += heading("Diagnosis of the data", "h2")
        out += _diagnosis(ctx, ctx.discovery)
    if not history and ctx.discovery is None:
        out.append(
            _p(
                "<b>Not performed</b>: the calibration record carries no model-discovery history and no diagnosis was given. "
                "The error model is the standard one (Wu et al. 2018 Eq. 6 with the quadratic terms)."
            )
        )
    return out


def _label(text: str, ids: Any = ()) -> str:
    """A model label of a discovery step (``+ K3_x``) with typeset names."""
    return prose(text, ids)


def _model_history(ctx: ReportContext, history: dict[str, Any]) -> list[Flowable]:
    """The record's ``discovery`` section: every effect tested in the calibration, its verdict, the fit after each step."""
    from stableins.conventions import MICRO_G

    steps = [s for s in history.get("steps", []) if isinstance(s, dict)]
    channels = [str(c) for c in (steps[0].get("channels", []) if steps else [])]
    out: list[Flowable] = [
        *heading("Model in force", "h2"),
        _p(
            f"Effects found by model discovery and estimated with the standard parameters ({escape(str(history.get('stage', '')))} fit "
            f"of the calibration record). Each step adds one effect to the model in force; it stays when the F-test of its "
            f"χ² reduction gives p &lt; α = {float(history.get('alpha', math.nan)):g}, and is otherwise left out of the record. "
            "χ²<sub>ν</sub> is expected within 1 ± 2√(2/ν); the residual RMS is per output axis and for the fine stage's |f|."
        ),
    ]

    def channel(c: str) -> str:
        return "|f|" if c.startswith("|") else f"f<sub>{escape(c.removeprefix('f_'))}</sub>"

    head = ["Step", "Model", "χ²<sub>ν</sub> (ν)"] + [f"RMS {channel(c)}" for c in channels] + ["p", "ΔBIC", "Decision"]
    rows: list[list[Any]] = [head]
    for i, step in enumerate(steps):
        rms = [float(x) / MICRO_G for x in step.get("residual_rms", [])]
        p_value, delta_bic = step.get("p_value"), step.get("delta_bic")
        chi2 = f"{content.chi2_text(float(step.get('chi2_red') or math.nan))} ({step.get('dof', '—')})"
        rows.append(
            [str(i), _label(str(step.get("label", ""))), chi2]
            + [_fmt(x, 3) for x in rms]
            + [
                "—" if p_value is None else f"{float(p_value):.2g}",
                "—" if delta_bic is None else f"{float(delta_bic):+.1f}".replace("-", MINUS),
                escape(str(step.get("decision", ""))),
            ]
        )
    floor = [float(x) / MICRO_G for x in (steps[-1].get("noise_floor", []) if steps else [])]
    rows.append(["", "noise floor", "1"] + [_fmt(x, 3) for x in floor] + ["", "", ""])
    n = len(channels)
    widths = [0.06, 0.17, 0.12] + [0.34 / max(n, 1)] * n + [0.08, 0.08, 0.15]
    out.append(document.table(rows, widths, align_right=tuple(range(2, 5 + n)), markup=True))
    out.append(_p("Residual RMS in µg. Verdicts:", "small"))
    for step in steps[1:]:
        out.append(_p(f"<b>{escape(str(step.get('decision', '')))}</b>: {_label(str(step.get('reason', '')))}", "small"))
    if len(steps) >= 2 and channels:
        png, aspect = figures.model_history(steps)
        caption = (
            f"{ctx.figure_label()} Residual RMS per output channel after each step of the calibration's model; dashed: the noise "
            "floor of the channel of the same colour."
        )
        out.append(document.figure(png, 1.0, aspect, caption))
    return out


def advice_text(advice: str) -> str:
    """A candidate's advice as a sentence: "to confirm, repeat ..." rather than "confirm with repeat ..."."""
    advice = advice.strip()
    if advice.startswith("confirm with "):
        advice = "to confirm: " + advice.removeprefix("confirm with ")
    return advice[:1].upper() + advice[1:] if advice else advice


def _estimate_text(estimate: float, sigma: float, unit: str) -> str:
    """A candidate's estimate ± 1σ rounded to its σ ("—" when there is none)."""
    if not math.isfinite(estimate):
        return "—"
    if math.isfinite(sigma) and sigma > 0:
        return f"{content.round_to_uncertainty(estimate, sigma)} ± {content.number(sigma, 2)} {unit}"
    return f"{_fmt(estimate, 3)} {unit}"


def _diagnosis(ctx: ReportContext, d: DiagnoseReport) -> list[Flowable]:
    """The output of ``stableins diagnose --json``: the refit history and the ranked candidates."""
    from stableins.conventions import MICRO_G

    def number(x: float, text: str) -> str:
        return text if math.isfinite(x) else "—"

    out: list[Flowable] = [
        _p(
            f"From {escape(_name(ctx.discovery_source))} (stableins diagnose): {escape(str(d.stage))} stage, "
            f"χ²<sub>ν</sub> = {content.chi2_text(d.chi2_red)} with ν = {d.dof}. Candidates are "
            "ranked by the significance of the residual they explain; ΔBIC &lt; 0 favours adding the effect."
        )
    ]
    rows: list[list[Any]] = [["Candidate", "p-value", "ΔBIC", "Estimate ± 1σ", "Flag", "Advice"]]
    for c in d.candidates[:12]:
        rows.append(
            [
                markup(c.id),
                number(c.p_value, f"{c.p_value:.2g}"),
                number(c.delta_bic, f"{c.delta_bic:.1f}".replace("-", MINUS)),
                _estimate_text(c.estimate, c.sigma, escape(content.unit_text(c.unit))),
                "yes" if c.flagged else "no",
                prose(advice_text(c.advice)),
            ]
        )
    if len(rows) > 1:
        out.append(document.table(rows, [0.13, 0.09, 0.08, 0.2, 0.07, 0.43], align_right=(1, 2), markup=True))
    else:
        out.append(_p("No candidate effect was tested."))
    steps: list[dict[str, Any]] = []
    for step in d.history:
        rms = [float(x) for x in step.rms]
        floor = [float(x) for x in step.noise_floor]
        if not rms:
            continue
        steps.append(
            {
                "label": step.label,
                "residual_rms": math.sqrt(sum(x * x for x in rms) / len(rms)) / MICRO_G,
                "noise_floor": math.sqrt(sum(x * x for x in floor) / len(floor)) / MICRO_G if floor else None,
                "unit": "µg",
                "chi2_red": step.chi2_red if math.isfinite(step.chi2_red) else None,
                "bic": step.bic if math.isfinite(step.bic) else None,
            }
        )
    if steps:
        out += heading("Refit history", "h2", room_mm=20)
        rows = [["Step", "Model", "Residual RMS [µg]", "Noise floor [µg]", "χ²<sub>ν</sub>", "BIC"]]
        for i, st in enumerate(steps):
            rows.append(
                [
                    str(i),
                    _label(st["label"]),
                    _fmt(st["residual_rms"], 3),
                    _fmt(st["noise_floor"], 3) if st["noise_floor"] is not None else "—",
                    content.chi2_text(float(st["chi2_red"])) if st.get("chi2_red") is not None else "—",
                    f"{float(st['bic']):.1f}".replace("-", MINUS) if st.get("bic") is not None else "—",
                ]
            )
        out.append(document.table(rows, [0.07, 0.33, 0.16, 0.16, 0.12, 0.16], align_right=(2, 3, 4, 5), markup=True))
        if len(steps) >= 2:
            png, aspect = figures.discovery_steps(steps)
            caption = (
                f"{ctx.figure_label()} Residual RMS (RMS over the output axes) after each step of the refit history, with the "
                "noise floor (dashed)."
            )
            out.append(document.figure(png, 1.0, aspect, caption))
        else:
            out.append(
                _p(
                    "One step only: nothing was flagged, so the model was not refitted; the residual RMS of the model in force "
                    f"({_fmt(steps[0]['residual_rms'], 3)} µg) is at or below the noise floor"
                    + (f" ({_fmt(steps[0]['noise_floor'], 3)} µg)." if steps[0]["noise_floor"] is not None else "."),
                    "small",
                )
                if steps[0]["noise_floor"] is None or steps[0]["residual_rms"] <= steps[0]["noise_floor"] * 1.05
                else _p(
                    f"One step only: the model in force leaves a residual RMS of {_fmt(steps[0]['residual_rms'], 3)} µg against a "
                    f"noise floor of {_fmt(steps[0]['noise_floor'], 3)} µg.",
                    "small",
                )
            )
    return out


# ---------------------------------------------------------------------- 9 change
def change(ctx: ReportContext) -> list[Flowable]:
    out: list[Flowable] = [*heading("9  Change since the previous calibration", room_mm=50)]
    if ctx.previous is None or ctx.comparison is None or ctx.changes is None:
        out.append(_p("<b>Not performed</b>: no previous calibration record was given."))
        return out
    prev = ctx.previous
    how = (
        "This record updates the previous one (a Bayesian update), so their errors are correlated: u(Δ)² = u<sub>prev</sub>² − "
        "u<sub>new</sub>²."
        if ctx.comparison.relation == "descendant"
        else "The two calibrations are independent: u(Δ)² = u<sub>prev</sub>² + u<sub>new</sub>²."
    )
    out.append(
        _p(
            f"Previous record: {escape(_name(ctx.previous_path))} (serial number "
            f"{escape(prev.serial_number)}, calibrated {escape(_period(prev))}). Δ = now − previous; {how} Here u is the Type A "
            f"uncertainty of the records (a Type B error common to both calibrations, such as the site's g, cancels in Δ). "
            f"z = Δ / u(Δ) is standard normal when nothing changed; a change with |z| ≥ {CHANGE_THRESHOLD:g} is flagged "
            "(false-alarm probability 0.27\u00a0% per parameter). The same statistic and flag as 'stableins recal' and "
            "'stableins history'. 'Now' is the value of section 4."
        )
    )
    if ctx.changes:
        previous = {r.id: r for r in ctx.previous_rows or []}
        rows: list[list[Any]] = [["Parameter", "Previous", "Now", "Δ", "u(Δ)", "z", "Changed", "Unit"]]
        colours = {}
        for i, c in enumerate(ctx.changes, start=1):
            z = f"{c.significance:.2f}".replace("-", MINUS) if math.isfinite(c.significance) else "—"
            now = ctx.row(c.id)
            before = previous.get(c.id)
            now_text = now.rounded().value if now is not None else _fmt(c.new, 5)
            before_text = before.rounded().value if before is not None else _fmt(c.old, 5)
            delta = (
                f"{content.round_to_uncertainty(c.delta, c.u_delta)}" if math.isfinite(c.u_delta) and c.u_delta > 0 else _fmt(c.delta, 3)
            )
            rows.append(
                [markup(c.id), before_text, now_text, delta, _fmt(c.u_delta, 2), z, "yes" if c.significant else "no", escape(c.unit)]
            )
            if c.significant:
                colours[(i, 6)] = document.VERDICT_COLOURS["fail"]
        out.append(
            document.table(
                rows, [0.13, 0.13, 0.13, 0.12, 0.11, 0.09, 0.14, 0.15], align_right=(1, 2, 3, 4, 5), cell_colours=colours, markup=True
            )
        )
        png, aspect = figures.changes(ctx.changes)
        out.append(
            document.figure(
                png,
                1.0,
                aspect,
                f"{ctx.figure_label()} Change of each parameter in units of its standard uncertainty, z = Δ / u(Δ); "
                f"bars beyond ±{CHANGE_THRESHOLD:g} are flagged.",
            )
        )
    if ctx.comparison.skipped:
        out.append(_p("Not compared: " + "; ".join(ctx.text(s) for s in ctx.comparison.skipped) + ".", "small"))
    return out


# ---------------------------------------------------------------------- 10 conformity
def conformity(ctx: ReportContext) -> list[Flowable]:
    out: list[Flowable] = [*heading("10  Statement of conformity", room_mm=50)]
    t = ctx.tolerances
    if t.empty:
        out.append(_p(escape(content.NO_STATEMENT).replace("No statement of conformity", "<b>No statement of conformity</b>", 1)))
        return out
    verdict = content.overall_verdict(ctx.checks)
    colour = document.VERDICT_COLOURS.get(verdict.lower(), document.VERDICT_COLOURS["not assessed"])
    out.append(
        _p(
            f"Tolerances: {escape(_name(t.source))}. Decision rule: {escape(RULE_TEXT[t.decision_rule])} "
            f"U is the expanded uncertainty of section 5 (Type A and Type B) with coverage factor k = {t.coverage_factor:g}; "
            "'measured' is the value of section 4."
        )
    )
    rows: list[list[Any]] = [list(content.CONFORMITY_HEADER)]
    colours = {}
    for i, c in enumerate(ctx.checks, start=1):
        kind, _, measured, expanded, limit, unit, _ = content.conformity_row(c, ctx.tolerances.coverage_factor)
        result = escape(c.verdict) + (f" ({ctx.text(c.reason)})" if c.reason else "")
        subject = markup(c.subject) if c.kind != content.CheckKind.FIT else escape(c.subject).replace("χ²_ν", "χ²<sub>ν</sub>")
        rows.append([kind, subject, measured, expanded, limit, escape(unit), result])
        colours[(i, 6)] = document.VERDICT_COLOURS[c.verdict]
    out.append(document.table(rows, [0.16, 0.14, 0.13, 0.09, 0.10, 0.09, 0.29], align_right=(2, 3, 4), cell_colours=colours, markup=True))
    out.append(
        KeepTogether(
            [
                _p(f'Verdict: <font color="{colour.hexval()}">{verdict}</font>', "verdict"),
                _p(
                    f"{content.conformity_counts(ctx.checks)}. Checks marked 'not assessed' concern parameters without a stated value "
                    "or evidence and do not enter the verdict.",
                    "small",
                ),
            ]
        )
    )
    return out


# ---------------------------------------------------------------------- 11 notes
def closing(ctx: ReportContext) -> list[Flowable]:
    out: list[Flowable] = [*heading("11  Notes and authorization", room_mm=45)]
    stage_notes = {n for s in ctx.record.stages for n in s.notes} | {f"[{s.name}] {n}" for s in ctx.record.stages for n in s.notes}
    remaining = [n for n in ctx.record.notes if n not in ctx.shown_notes and n not in stage_notes]
    if remaining:
        out.append(document.table([["Notes from the calibration record"]] + [[ctx.text(n)] for n in remaining], [1.0], markup=True))
    else:
        out.append(_p("Every note of the calibration record is shown with the stage it belongs to (sections 4 and 7)."))
    out.append(document.spacer(6))
    rows = [["", "Name", "Function", "Signature and date"], ["Performed by", "", "", ""], ["Authorized by", "", "", ""]]
    signature = document.table(rows, [0.18, 0.30, 0.22, 0.30])
    signature.setStyle(
        [("ROWBACKGROUNDS", (0, 1), (-1, -1), [None]), ("TOPPADDING", (0, 1), (-1, -1), 14), ("GRID", (0, 0), (-1, -1), 0.4, document.RULE)]
    )
    out.append(KeepTogether([_p("Persons authorizing the report (ISO/IEC 17025 7.8.2.1 o)", "h2"), signature]))
    out.append(document.spacer(4))
    out.append(_p("End of report.", "small"))
    return out


SECTIONS = (
    title_block,
    method,
    site_environment,
    inputs,
    results,
    uncertainty,
    correlations,
    evidence,
    discovery,
    change,
    conformity,
    closing,
)
