"""Content builders, one per report section (ISO/IEC 17025:2017 7.8 and the GUM as the checklist).

Each builder takes the :class:`ReportContext` and returns flowables.  A section whose
evidence the record does not carry says so ("not performed" / "not recorded"); no
number is ever made up.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from reportlab.platypus import CondPageBreak, Flowable, KeepTogether, Paragraph

from stableins.history import CHANGE_THRESHOLD, Comparison
from stableins.records import CalibrationRecord
from stableins.reporting import content, document, figures
from stableins.reporting.content import MINUS, ChangeRow, Check, ParameterRow
from stableins.reporting.document import escape
from stableins.reporting.evidence import StageEvidence
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
    record_path: str = ""
    previous: CalibrationRecord | None = None
    previous_path: str | None = None
    comparison: Comparison | None = None
    changes: list[ChangeRow] | None = None
    software_version: str = ""
    evidence_notes: list[str] = field(default_factory=list)
    figures: int = 0
    discovery: dict[str, Any] = field(default_factory=dict)
    discovery_source: str = "calibration record"

    def figure_label(self) -> str:
        """ "Figure n." with n counting the figures in the order they are laid out."""
        self.figures += 1
        return f"Figure {self.figures}."


def _p(text: str, style: str = "body") -> Paragraph:
    return Paragraph(text, document.styles()[style])


def _fmt(x: float, significant: int = 3) -> str:
    return content.number(x, significant) if math.isfinite(x) else "—"


def _degrees(radians: float) -> str:
    return f"{math.degrees(radians):.6f}°".replace("-", MINUS)


# ---------------------------------------------------------------------- sections
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
        return f"{start} to {end}"
    return start or end or NOT_RECORDED


def method(ctx: ReportContext) -> list[Flowable]:
    r = ctx.record
    out: list[Flowable] = [_p("1  Procedure and method", "h1")]
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
        rows.append([s.name, s.procedure or NOT_RECORDED, _span(s.data_start, s.data_end), rate, content.describe_settings(s.settings)])
    out.append(_p(f"Stages run in this calibration ({escape(r.calibration.id)})", "h2"))
    if len(rows) > 1:
        out.append(document.table(rows, [0.13, 0.20, 0.26, 0.09, 0.32]))
    else:
        out.append(_p("None recorded."))
    earlier = [s for s in r.stages if s.calibration != r.calibration.id]
    if earlier:
        out.append(_p("Stages of earlier calibrations the record carries over", "h2"))
        rows = [["Stage", "Procedure", "Data (UTC)", "Calibration"]]
        rows += [[s.name, s.procedure or NOT_RECORDED, _span(s.data_start, s.data_end), s.calibration] for s in earlier]
        out.append(document.table(rows, [0.14, 0.22, 0.38, 0.26]))
    if r.calibration.prior is not None:
        prior = r.calibration.prior
        out.append(
            _p(
                f"This calibration updates the record in force before it: {escape(Path(prior.path).name or 'record')} "
                f"(SHA-256 {escape(prior.sha256[:16])}…, created {escape(prior.created or NOT_RECORDED)}).",
                "small",
            )
        )
    return out


def site_environment(ctx: ReportContext) -> list[Flowable]:
    out: list[Flowable] = [_p("2  Site and environment", "h1")]
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
        rows = [
            ["Quantity", "Value"],
            ["latitude (geodetic)", _degrees(site.latitude)],
            ["height (ellipsoidal)", f"{site.height:.1f} m".replace("-", MINUS)],
            ["local gravity g", f"{site.gravity:.7f} m/s²"],
            ["source of g", site.gravity_source],
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
    out.append(_p("Entries made during the calibration", "h2"))
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


def inputs(ctx: ReportContext) -> list[Flowable]:
    rows: list[list[Any]] = [["Role", "File", "SHA-256", "Check"]]
    for f in ctx.inputs:
        rows.append([f.role, f.name, f.sha256, f.check])
    out: list[Flowable] = [_p("3  Inputs and their integrity", "h1")]
    out.append(
        _p(
            "SHA-256 digests of every file this calibration and this report were made from. "
            "A file whose digest differs is not the file used."
        )
    )
    out.append(document.table(rows, [0.14, 0.27, 0.41, 0.18], mono=(2,)))
    return out


def results(ctx: ReportContext) -> list[Flowable]:
    out: list[Flowable] = [CondPageBreak(120), _p("4  Results", "h1")]
    out.append(
        _p(
            "Values of the record in force after this calibration, in engineering units: scale factors as deviation from 1 in ppm, "
            "biases in µg, angles in arcsec, quadratic nonlinearity in µg/g² (1 g = 9.80665 m/s², the conventional value used for units "
            "only). u is the standard uncertainty; U = k·u is the expanded uncertainty with coverage factor k = 2. 'Last determined by' "
            "names the stage whose data last saw the parameter, alone or only in combination with others; a parameter no stage of this "
            "calibration saw is 'carried over' from an earlier one."
        )
    )
    header = ["Parameter", "Status", "Value", "u", "U (k = 2)", "Unit", "Last determined by"]
    rows: list[list[Any]] = [header]
    for row in ctx.rows:
        value, u, expanded = row.formatted()
        rows.append([row.id, row.status.value, value, u, expanded, row.unit, row.source])
    out.append(document.table(rows, [0.11, 0.13, 0.13, 0.08, 0.11, 0.09, 0.35], align_right=(2, 3, 4)))
    out.append(document.spacer(2))
    out.append(_p(_uncertainty_statement(ctx), "small"))
    carried = [r for r in ctx.rows if r.estimated and not r.measured]
    if carried:
        out.append(
            _p(
                f"Carried over, not re-measured in this calibration: {escape(', '.join(r.id for r in carried))} "
                "(value and u as the earlier calibration determined them, updated only through their correlation with what was "
                "measured).",
                "small",
            )
        )
    not_estimated = [r for r in ctx.rows if not r.estimated]
    out.append(_p("Parameters not estimated", "h2"))
    if not_estimated:
        rows = [["Parameter", "Status", "Why"]] + [[r.id, r.status.value, r.why or NOT_RECORDED] for r in not_estimated]
        out.append(document.table(rows, [0.14, 0.16, 0.70]))
    else:
        out.append(_p("None: every parameter of the model was estimated from the data."))
    out.append(_p("Meaning of the parameters", "h2"))
    out.append(document.table([["Parameter", "Meaning"]] + [[r.id, r.meaning] for r in ctx.rows], [0.14, 0.86]))
    determined = [(s.name, d) for s in ctx.record.stages_run if s.name != "system" for d in s.determined]  # system: section 5
    if determined:
        out.append(_p("Combinations the data determine", "h2"))
        out.append(document.table([["Stage", "Combination"]] + [list(d) for d in determined], [0.14, 0.86]))
    ids, matrix = content.correlation(ctx.record)
    heading = _p("Correlation of the estimates", "h2")
    if len(ids) >= 2:
        png, aspect = figures.correlation_matrix(ids, matrix)
        width = 0.85 * min(1.0, (1.6 + 0.28 * len(ids) + 0.9) / figures.FULL_WIDTH)
        caption = (
            f"{ctx.figure_label()} Correlation coefficients of the {len(ids)} estimated parameters, "
            "from the covariance in the calibration record."
        )
        out.append(KeepTogether([heading, document.figure(png, width, aspect, caption)]))
    else:
        out += [heading, _p("Not shown: the calibration record carries no covariance of two or more estimated parameters.")]
    return out


def _uncertainty_statement(ctx: ReportContext) -> str:
    text = (
        "Uncertainty evaluation (GUM, JCGM 100:2008): u is the square root of the diagonal of the parameter covariance, propagated "
        "by least squares and the Bayesian update of each stage from the noise measured in the calibration data (Type A, GUM 4.2). "
        "U = 2u gives a coverage probability of "
        "about 95\u00a0% for a normal distribution (GUM 6.2, 6.3). Uncertainties are reported as estimated, not scaled by χ²_ν; "
    )
    high = [s for s in ctx.stages if s.dof > 0 and s.chi2_red > s.chi2_red_interval()[1]]
    if high:
        names = ", ".join(f"{s.stage} (χ²_ν = {s.chi2_red:.2f})" for s in high)
        text += (
            f"<b>caution</b>: the residuals of {escape(names)} exceed the noise by more than chance allows, so effects outside the model "
            "are present and u may understate the error (see section 5)."
        )
    elif ctx.stages:
        text += "the residuals agree with the noise (section 5), so no unmodelled effect is seen at this level."
    else:
        text += "no residual evidence was available to check this (section 5)."
    return text


def evidence(ctx: ReportContext) -> list[Flowable]:
    out: list[Flowable] = [CondPageBreak(150), _p("5  Evidence that the model fits", "h1")]
    for note in ctx.evidence_notes:
        out.append(_p(escape(note[0].upper() + note[1:]) + ".", "small"))
    if not ctx.stages:
        out.append(
            _p(
                "Residual analysis: <b>not performed</b>; the calibration record carries no residual evidence of its stages "
                "and no device-level data file was given (--data)."
            )
        )
    else:
        rows: list[list[Any]] = [["Fit", "Stage run", "Obs.", "Rank / param.", "χ²_ν", "ν", "95\u00a0% interval, noise alone", "Verdict"]]
        colours = {}
        for i, s in enumerate(ctx.stages, start=1):
            low, high = s.chi2_red_interval()
            ok = low <= s.chi2_red <= high
            verdict = "consistent with noise" if ok else ("residuals exceed noise" if s.chi2_red > high else "residuals below noise")
            colours[(i, 7)] = document.VERDICT_COLOURS["pass" if ok else "conditional fail"]
            rows.append(
                [
                    s.stage,
                    s.run or "recomputed",
                    str(len(s.residuals)),
                    f"{s.rank} / {s.n_parameters}",
                    f"{s.chi2_red:.3f}",
                    str(s.dof),
                    f"{low:.3f} to {high:.3f}",
                    verdict,
                ]
            )
        widths = [0.12, 0.13, 0.07, 0.12, 0.08, 0.06, 0.20, 0.22]
        out.append(document.table(rows, widths, align_right=(2, 4, 5), cell_colours=colours))
        out.append(
            _p(
                "χ²_ν = Σ(r_i/σ_i)²/ν with ν = observations − rank; σ_i is the noise floor of observation i measured in the data; "
                "where the stage models noise correlated between observations (slow bias drift), χ² is that of the whitened "
                "residuals. Values inside the interval mean the model explains the data down to the noise.",
                "small",
            )
        )
        for s in ctx.stages:
            if s.stage == "system":
                if s.notes:
                    out.append(_p("Notes of the system stage: " + "; ".join(escape(n) for n in s.notes), "small"))
                continue
            if s.labels and s.unlabelled == 0:
                png, aspect = figures.residuals_by_position(s)
                caption = (
                    f"{ctx.figure_label()} {s.stage.capitalize()} stage: residual of each position (per axis, or of the specific-force "
                    "magnitude |f|) with ±1σ error bars; "
                    "the grey band is the noise floor (±1σ) measured in the data."
                )
            else:
                png, aspect = figures.normalized_residuals(s)
                caption = f"{ctx.figure_label()} {s.stage.capitalize()} stage: residual of each observation divided by its 1σ noise floor."
            out.append(document.figure(png, 1.0, aspect, caption))
            if s.notes:
                out.append(_p(f"Notes of the {escape(s.stage)} stage: " + "; ".join(escape(n) for n in s.notes), "small"))
    out.append(KeepTogether([_p("System-level stage", "h2"), *_system(ctx)]))
    return out


def _system(ctx: ReportContext) -> list[Flowable]:
    runs = [s for s in ctx.record.stages_run if s.name == "system"]
    if not runs:
        return [_p("<b>Not performed</b>: no system-level stage ran in this calibration.")]
    out: list[Flowable] = []
    for run in runs:
        fit = next((f for f in run.fits if f.get("stage") == "system"), None)
        if fit is not None and fit.get("chi2_red") is not None:
            out.append(
                _p(
                    f"Separation of the combined coefficients (Earth-rate harmonics of the specific-force error, pitch and roll): "
                    f"χ²_ν = {float(fit['chi2_red']):.3f} with ν = {fit.get('dof')} (table above). What these data determine, "
                    "each with its 1σ from these data alone [rad]:"
                )
            )
        rows: list[list[Any]] = [["Combination", "Value ± 1σ", "Determined"]]
        for line in run.determined:
            name, _, rest = line.partition(" = ")
            determined = "NOT determined" not in rest
            rows.append([name, rest.replace(" (NOT determined by these data)", ""), "yes" if determined else "no (short record)"])
        if len(rows) > 1:
            out.append(document.table(rows, [0.50, 0.32, 0.18]))
    return out


def discovery(ctx: ReportContext) -> list[Flowable]:
    """The model in force (the record's discovery history) and, when given, the diagnosis (``stableins diagnose --json``)."""
    out: list[Flowable] = [CondPageBreak(120), _p("6  Model discovery", "h1")]
    history = ctx.record.discovery.to_json() if ctx.record.discovery is not None else None
    if history:
        out += _model_history(ctx, history)
    if "history" in ctx.discovery:
        if history:
            out.append(_p("Diagnosis of the data", "h2"))
        out += _diagnosis(ctx)
    if not history and "history" not in ctx.discovery:
        out.append(
            _p(
                "<b>Not performed</b>: the calibration record carries no model-discovery history and no diagnosis was given. "
                "The error model is the standard one (Wu et al. 2018 Eq. 6 with the quadratic terms)."
            )
        )
    return out


def _model_history(ctx: ReportContext, history: dict[str, Any]) -> list[Flowable]:
    """The record's ``discovery`` section: every effect tested in the calibration, its verdict, the fit after each step."""
    from stableins.conventions import MICRO_G

    steps = [s for s in history.get("steps", []) if isinstance(s, dict)]
    channels = [str(c) for c in (steps[0].get("channels", []) if steps else [])]
    out: list[Flowable] = [
        _p("Model in force", "h2"),
        _p(
            f"Effects found by model discovery and estimated with the standard parameters ({escape(str(history.get('stage', '')))} fit "
            f"of the calibration record). Each step adds one effect to the model in force; it stays when the F-test of its "
            f"χ² reduction gives p &lt; α = {float(history.get('alpha', math.nan)):g}, and is otherwise left out of the record. "
            "χ²_ν is expected within 1 ± 2√(2/ν); the residual RMS is per output axis and for the fine stage's |f|."
        ),
    ]
    head = ["Step", "Model", "χ²_ν (ν)"] + [f"RMS {c.removeprefix('f_')}" for c in channels] + ["p", "ΔBIC", "Decision"]
    rows: list[list[Any]] = [head]
    for i, step in enumerate(steps):
        rms = [float(x) / MICRO_G for x in step.get("residual_rms", [])]
        p_value, delta_bic = step.get("p_value"), step.get("delta_bic")
        rows.append(
            [str(i), str(step.get("label", "")), f"{_fmt(float(step.get('chi2_red') or math.nan), 3)} ({step.get('dof', '—')})"]
            + [_fmt(x, 3) for x in rms]
            + [
                "—" if p_value is None else f"{float(p_value):.2g}",
                "—" if delta_bic is None else f"{float(delta_bic):+.1f}".replace("-", MINUS),
                str(step.get("decision", "")),
            ]
        )
    floor = [float(x) / MICRO_G for x in (steps[-1].get("noise_floor", []) if steps else [])]
    rows.append(["", "noise floor", "1"] + [_fmt(x, 3) for x in floor] + ["", "", ""])
    n = len(channels)
    widths = [0.06, 0.17, 0.12] + [0.34 / max(n, 1)] * n + [0.08, 0.08, 0.15]
    out.append(document.table(rows, widths, align_right=tuple(range(2, 5 + n))))
    out.append(_p("Residual RMS in µg. Verdicts:", "small"))
    for step in steps[1:]:
        reason = content.unit_words(str(step.get("reason", "")))
        out.append(_p(f"<b>{escape(str(step.get('decision', '')))}</b>: {escape(reason)}", "small"))
    if steps and channels:
        png, aspect = figures.model_history(steps)
        caption = f"{ctx.figure_label()} Residual RMS per output channel after each step of the calibration's model (dashed: noise floor)."
        out.append(document.figure(png, 1.0, aspect, caption))
    return out


def _diagnosis(ctx: ReportContext) -> list[Flowable]:
    """The output of ``stableins diagnose --json``: the refit history and the ranked candidates."""
    from stableins.conventions import MICRO_G

    d = ctx.discovery
    out: list[Flowable] = [
        _p(
            f"From {escape(ctx.discovery_source)} (stableins diagnose): {escape(d.get('stage') or 'device')} stage, "
            f"χ²_ν = {float(d.get('chi2_red', math.nan)):.3f} with ν = {d.get('dof', '—')}. Candidates are ranked by the "
            "significance of the residual they explain; ΔBIC &lt; 0 favours adding the effect."
        )
    ]
    rows: list[list[Any]] = [["Candidate", "p-value", "ΔBIC", "Estimate ± 1σ", "Flag", "Advice"]]
    for c in d.get("candidates", [])[:12]:
        predicted = c.get("predicted") or {}
        estimate = predicted.get("estimate")
        sigma = predicted.get("sigma")
        text = (
            "—"
            if estimate is None
            else f"{_fmt(float(estimate), 3)} ± {_fmt(float(sigma), 2)} {content.unit_text(str(predicted.get('unit', '')))}"
        )
        p_value = c.get("p_value")
        rows.append(
            [
                str(c.get("id", "")),
                "—" if p_value is None else f"{float(p_value):.2g}",
                "—" if c.get("delta_bic") is None else f"{float(c['delta_bic']):.1f}".replace("-", MINUS),
                text,
                "yes" if c.get("flagged") else "no",
                str(c.get("advice", "")),
            ]
        )
    if len(rows) > 1:
        out.append(document.table(rows, [0.15, 0.09, 0.08, 0.2, 0.08, 0.40], align_right=(1, 2)))
    else:
        out.append(_p("No candidate effect was tested."))
    steps = []
    for step in d.get("history", []):
        rms = [float(x) for x in step.get("residual_rms", [])]
        floor = [float(x) for x in step.get("noise_floor", [])]
        if not rms:
            continue
        steps.append(
            {
                "label": str(step.get("label", "")),
                "residual_rms": math.sqrt(sum(x * x for x in rms) / len(rms)) / MICRO_G,
                "noise_floor": math.sqrt(sum(x * x for x in floor) / len(floor)) / MICRO_G if floor else None,
                "unit": "µg",
                "chi2_red": step.get("chi2_red"),
                "bic": step.get("bic"),
            }
        )
    if steps:
        out.append(_p("Refit history", "h2"))
        rows = [["Step", "Model", "Residual RMS [µg]", "Noise floor [µg]", "χ²_ν", "BIC"]]
        for i, st in enumerate(steps):
            rows.append(
                [
                    str(i),
                    st["label"],
                    _fmt(st["residual_rms"], 3),
                    _fmt(st["noise_floor"], 3) if st["noise_floor"] is not None else "—",
                    _fmt(float(st["chi2_red"]), 3) if st.get("chi2_red") is not None else "—",
                    f"{float(st['bic']):.1f}".replace("-", MINUS) if st.get("bic") is not None else "—",
                ]
            )
        out.append(document.table(rows, [0.07, 0.33, 0.16, 0.16, 0.12, 0.16], align_right=(2, 3, 4, 5)))
        png, aspect = figures.discovery_steps(steps)
        caption = (
            f"{ctx.figure_label()} Residual RMS (RMS over the output axes) after each step of the refit history, with the noise floor."
        )
        out.append(document.figure(png, 1.0, aspect, caption))
    return out


def change(ctx: ReportContext) -> list[Flowable]:
    out: list[Flowable] = [CondPageBreak(120), _p("7  Change since the previous calibration", "h1")]
    if ctx.previous is None or ctx.comparison is None or ctx.changes is None:
        out.append(_p("<b>Not performed</b>: no previous calibration record was given."))
        return out
    prev = ctx.previous
    how = (
        "This record updates the previous one (a Bayesian update), so their errors are correlated: u(Δ)² = u_prev² − u_new²."
        if ctx.comparison.relation == "descendant"
        else "The two calibrations are independent: u(Δ)² = u_prev² + u_new²."
    )
    out.append(
        _p(
            f"Previous record: {escape(Path(ctx.previous_path).name if ctx.previous_path else 'in memory')} (serial number "
            f"{escape(prev.serial_number)}, calibrated {escape(_period(prev))}). Δ = new − previous; {how} z = Δ / u(Δ) is "
            f"standard normal when nothing changed; a change with |z| ≥ {CHANGE_THRESHOLD:g} is flagged (false-alarm probability "
            "0.27\u00a0% per parameter). The same statistic and flag as 'stableins recal' and 'stableins history'."
        )
    )
    if ctx.changes:
        rows: list[list[Any]] = [["Parameter", "Previous", "Now", "Δ", "u(Δ)", "z", "Changed", "Unit"]]
        colours = {}
        for i, c in enumerate(ctx.changes, start=1):
            z = f"{c.significance:.2f}".replace("-", MINUS) if math.isfinite(c.significance) else "—"
            rows.append(
                [c.id, _fmt(c.old, 5), _fmt(c.new, 5), _fmt(c.delta, 3), _fmt(c.u_delta, 2), z, "yes" if c.significant else "no", c.unit]
            )
            if c.significant:
                colours[(i, 6)] = document.VERDICT_COLOURS["fail"]
        out.append(
            document.table(rows, [0.13, 0.13, 0.13, 0.12, 0.11, 0.09, 0.14, 0.15], align_right=(1, 2, 3, 4, 5), cell_colours=colours)
        )
        png, aspect = figures.changes(ctx.changes)
        out.append(
            document.figure(
                png,
                1.0,
                aspect,
                f"{ctx.figure_label()} Change of each parameter in units of its standard uncertainty (z); "
                f"bars beyond ±{CHANGE_THRESHOLD:g} are flagged.",
            )
        )
    if ctx.comparison.skipped:
        out.append(_p("Not compared: " + "; ".join(escape(s) for s in ctx.comparison.skipped) + ".", "small"))
    return out


def conformity(ctx: ReportContext) -> list[Flowable]:
    out: list[Flowable] = [CondPageBreak(120), _p("8  Statement of conformity", "h1")]
    t = ctx.tolerances
    if t.empty:
        out.append(_p(escape(content.NO_STATEMENT).replace("No statement of conformity", "<b>No statement of conformity</b>", 1)))
        return out
    verdict = content.overall_verdict(ctx.checks)
    colour = document.VERDICT_COLOURS.get(verdict.lower(), document.VERDICT_COLOURS["not assessed"])
    out.append(
        _p(
            f"Tolerances: {escape(t.source)}. Decision rule: {escape(RULE_TEXT[t.decision_rule])} "
            f"Coverage factor of U: k = {t.coverage_factor:g}."
        )
    )
    rows: list[list[Any]] = [list(content.CONFORMITY_HEADER)]
    colours = {}
    for i, c in enumerate(ctx.checks, start=1):
        rows.append(list(content.conformity_row(c)))
        colours[(i, 6)] = document.VERDICT_COLOURS[c.verdict]
    out.append(document.table(rows, [0.16, 0.14, 0.13, 0.09, 0.10, 0.09, 0.29], align_right=(2, 3, 4), cell_colours=colours))
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


def closing(ctx: ReportContext) -> list[Flowable]:
    out: list[Flowable] = [CondPageBreak(140), _p("9  Notes and authorization", "h1")]
    if ctx.record.notes:
        out.append(document.table([["Notes from the calibration record"]] + [[escape(n)] for n in ctx.record.notes], [1.0]))
    else:
        out.append(_p("The calibration record carries no notes."))
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


SECTIONS = (title_block, method, site_environment, inputs, results, evidence, discovery, change, conformity, closing)
