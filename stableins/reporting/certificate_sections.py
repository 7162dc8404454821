"""The calibration certificate: at most three pages a quality manager signs (ISO/IEC 17025:2017 7.8.2, 7.8.4, 7.8.6).

Identification, the results with U (k = 2) and its coverage, the statement of conformity with its decision rule
and specification, traceability and the conditions of validity, the signature block.  Everything else — the
evidence of fit, residuals, noise model, discovery history, budget derivation, correlations and notes — is in
the technical report (:data:`stableins.reporting.sections.TECHNICAL_SECTIONS`), which the certificate names by
its SHA-256.  Both documents are laid out from one :class:`ReportContext`: a number that appears in both is the
same text, rounded by the one function (:func:`stableins.reporting.rounding.gum`).
"""

from __future__ import annotations

import math
from typing import Any

from reportlab.platypus import Flowable, KeepTogether

from stableins.conventions import STANDARD_GRAVITY
from stableins.reporting import content, document, rounding
from stableins.reporting.budget import TITLES
from stableins.reporting.context import (
    NOT_RECORDED,
    ReportContext,
    angle_reference,
    file_name,
    from_poses,
    item_calibrated,
    no_statement,
    paragraph,
    period,
    verdict_colour_hex,
)
from stableins.reporting.document import escape, heading
from stableins.reporting.rounding import COVERAGE_FACTOR
from stableins.reporting.symbols import markup, prose
from stableins.reporting.tolerances import RULE_TEXT, Verdict

#: What a draft lacks, in the words of the certificate.
NOT_STATED = "not stated"


def draft(ctx: ReportContext) -> list[str]:
    """Return the identification a certificate lacks (laboratory, customer, operator): it is then a DRAFT."""
    return [k for k in ("laboratory", "customer", "operator") if not ctx.identification.get(k)]


def identification(ctx: ReportContext) -> list[Flowable]:
    """Return the title block: who calibrated what for whom, when, by which procedure, and the technical report's digest."""
    r = ctx.record
    extra = r.site.extra if r.site else {}
    ident = ctx.identification
    technical = ctx.technical
    rows = [
        ["Certificate number", ctx.report_id],
        ["Item calibrated", item_calibrated(r)],
        ["Laboratory", ident.get("laboratory") or NOT_STATED],
        ["Customer", ident.get("customer") or NOT_STATED],
        ["Operator", ident.get("operator") or NOT_STATED],
        ["Location", str(extra.get("location", NOT_RECORDED if from_poses(r) else "on the system, at its site (section 3)"))],
        ["Calibration performed", period(r)],
        ["Procedure", r.calibration.procedure or NOT_RECORDED],
        ["Date of issue", ctx.issued],
        [
            "Technical report",
            f"{technical.name}, {technical.check}, SHA-256 {technical.sha256}: the evidence, noise model, discovery history, "
            "uncertainty budget and notes behind these results"
            if technical is not None
            else NOT_RECORDED,
        ],
        ["Software", f"stableins {ctx.software_version}; calibration by {r.calibration.software or NOT_RECORDED}"],
    ]
    out: list[Flowable] = [
        paragraph("Calibration certificate", "title"),
        paragraph(
            "Calibration of a tri-axis accelerometer from static poses"
            if from_poses(r)
            else "On-system calibration of the tri-axis accelerometer of a space-stable inertial navigation system",
            "subtitle",
        ),
    ]
    missing = draft(ctx)
    if missing:
        colour = document.VERDICT_COLOURS["fail"].hexval()
        out.append(
            paragraph(
                f'<font color="{colour}"><b>DRAFT</b>: the {", ".join(missing)} {"is" if len(missing) == 1 else "are"} not stated; '
                "this document is not a certificate until they are.</font>"
            )
        )
    if ctx.simulated:
        out.append(
            paragraph(
                f'<font color="{document.VERDICT_COLOURS["fail"].hexval()}"><b>Simulated data</b>: the calibration data were '
                "produced by the stableins truth simulator; the results describe a simulated unit, not a physical one.</font>"
            )
        )
    out += [
        document.table(rows, [0.22, 0.78], header_rows=0, key_value=True),
        document.spacer(1),
        paragraph(
            "The results relate only to the item calibrated, at the time and under the conditions stated. This certificate shall "
            "not be reproduced except in full without the written approval of the issuing laboratory.",
            "small",
        ),
    ]
    return out


def certificate_results(ctx: ReportContext) -> list[Flowable]:
    """Return section 1: each estimated parameter's value, U (k = 2), the limits it was checked against and the result."""
    out: list[Flowable] = [*heading("1  Results", room_mm=60)]
    k = COVERAGE_FACTOR
    out.append(
        paragraph(
            "Values of the calibration record in force after this calibration, in engineering units: scale factors SF as deviation "
            f"from 1 in ppm, biases δb in µg, angles in arcsec, K<sub>2</sub> in µg/g² (g = {STANDARD_GRAVITY:g} m/s² for units only). "
            f"U is the expanded uncertainty U = k·u<sub>c</sub> with coverage factor k = {k:g}, about 95 % coverage for a normal "
            "distribution (GUM 6.3); u<sub>c</sub> combines the Type A uncertainty of the data with the Type B inputs of section 3 "
            "(budget: technical report, section 5). U has two significant digits and the value the last digit of U (GUM 7.2.6).",
            "small",
        )
    )
    checks: dict[str, list[content.Check]] = {}
    for c in ctx.checks:
        checks.setdefault(c.subject, []).append(c)
    head = ["Parameter", "Value", f"U (k = {k:g})", "Unit", "Limit of |x|", "Limit of U", "Result"]
    rows: list[list[Any]] = [head]
    colours = {}
    for row in ctx.rows:
        if not row.estimated or not (row.u > 0):
            continue
        r = row.rounded()
        mine = [c for c in checks.get(row.id, []) if c.kind in (content.CheckKind.VALUE, content.CheckKind.UNCERTAINTY)]
        value_limit = next((c.limit for c in mine if c.kind is content.CheckKind.VALUE), math.nan)
        u_limit = next((c.limit for c in mine if c.kind is content.CheckKind.UNCERTAINTY), math.nan)
        verdict = _worst(mine)
        cells = [row.symbol, r.value, r.expanded, escape(row.unit), _limit(value_limit), _limit(u_limit), verdict or "—"]
        if verdict:
            colours[(len(rows), 6)] = document.VERDICT_COLOURS[verdict]
        rows.append(cells)
    out.append(document.table(rows, [0.13, 0.15, 0.13, 0.10, 0.13, 0.13, 0.23], align_right=(1, 2, 4, 5), cell_colours=colours,
                              markup=True))  # fmt: skip
    others = [r for r in ctx.rows if not (r.estimated and r.u > 0)]
    if others:
        held = ("gauge", "fixed")
        text = "; ".join(f"{r.symbol} {escape(r.status.value)}" + (f" (held at {r.rounded().value})" if r.status.value in held else "")
                         for r in others)  # fmt: skip
        out.append(paragraph(f"Not estimated by this calibration: {text}. Why: technical report, section 4.", "small"))
    return out


def _limit(x: float) -> str:
    return rounding.significant_digits(x, 4) if math.isfinite(x) else "—"


def _worst(checks: list[content.Check]) -> str:
    """Return the worst verdict of a parameter's checks ("" without any)."""
    order = (Verdict.FAIL, Verdict.CONDITIONAL_FAIL, Verdict.CONDITIONAL_PASS, Verdict.PASS, Verdict.NOT_ASSESSED)
    found = {c.verdict for c in checks}
    return next((str(v) for v in order if v in found), "")


def certificate_conformity(ctx: ReportContext) -> list[Flowable]:
    """Return section 2: the verdict, the specification it was judged against, the decision rule and the fit checks."""
    out: list[Flowable] = [*heading("2  Statement of conformity", room_mm=45)]
    t = ctx.tolerances
    if t.empty:
        return [*out, no_statement(t)]
    verdict = content.overall_verdict(ctx.checks)
    colour = verdict_colour_hex(verdict)
    spec = next((f for f in ctx.inputs if f.role == "procedure"), None)
    specification = (
        f"the [tolerances] table of the procedure {escape(spec.name)} (SHA-256 {spec.sha256[:16]}…)"
        if spec
        else escape(file_name(t.source))
    )
    counts = content.conformity_counts(ctx.checks)
    out.append(paragraph(f'Verdict: <font color="{colour}">{verdict}</font>  ({counts})', "verdict"))
    out.append(
        paragraph(
            f"<b>Specification</b>: {specification}. <b>Decision rule</b>: {escape(RULE_TEXT[t.decision_rule])} "
            f"U is that of section 1 (k = {t.coverage_factor:g}). 'Not assessed' checks concern parameters without an estimate "
            "and do not enter the verdict.",
            "small",
        )
    )
    fits = [c for c in ctx.checks if c.kind is content.CheckKind.FIT]
    stability = [c for c in ctx.checks if c.kind is content.CheckKind.STABILITY]
    if fits:
        rows: list[list[Any]] = [["Fit", "χ²<sub>ν</sub>", "Limit", "Result"]]
        colours = {}
        for i, c in enumerate(fits, start=1):
            _, subject, measured, _, limit, _, result = content.conformity_row(c, t.coverage_factor)
            rows.append([escape(subject).replace("χ²_ν", "χ²<sub>ν</sub>"), measured, limit, escape(result)])
            colours[(i, 3)] = document.VERDICT_COLOURS[c.verdict]
        out.append(
            paragraph(
                f"Model fit: each fit's χ²<sub>ν</sub> must not exceed the upper end of its central {t.chi2_interval or 0.95:.0%} "
                "interval for noise alone (χ² distribution with the fit's ν; technical report, section 7).",
                "small",
            )
        )
        out.append(document.table(rows, [0.34, 0.14, 0.14, 0.38], align_right=(1, 2), cell_colours=colours, markup=True))
    if stability:
        rows = [["Change since the previous calibration", "|Δ|", "U(Δ)", "Limit", "Unit", "Result"]]
        colours = {}
        for i, c in enumerate(stability, start=1):
            _, subject, measured, expanded, limit, unit, result = content.conformity_row(c, t.coverage_factor)
            rows.append([markup(subject), measured, expanded, limit, escape(unit), escape(result)])
            colours[(i, 5)] = document.VERDICT_COLOURS[c.verdict]
        out.append(document.table(rows, [0.30, 0.12, 0.12, 0.12, 0.10, 0.24], align_right=(1, 2, 3), cell_colours=colours, markup=True))
    return out


def traceability(ctx: ReportContext) -> list[Flowable]:
    """Return section 3: the reference and its traceability, the Type B inputs of U and the conditions of validity."""
    out: list[Flowable] = [*heading("3  Traceability, uncertainty and conditions", room_mm=40)]
    site = ctx.record.site
    if site is None:
        out.append(paragraph("Site metadata: not recorded in the calibration record; local gravity, the reference, is not stated."))
    else:
        source = ctx.budget.source("gravity") if ctx.budget is not None else None
        u_g = f", standard uncertainty {prose(source.uncertainty)}" if source is not None else ""
        out.append(
            paragraph(
                f"<b>Reference</b>: local gravity g = {site.gravity:.7f} m/s² ({escape(site.gravity_source)}{u_g}) at latitude "
                f"{math.degrees(site.latitude):.6f}°. Scale factors are traceable to the SI through g and its source. "
                f"{angle_reference(ctx.record)} Biases and installation angles are determined relative to these references.",
                "small",
            )
        )
    if ctx.budget is not None:
        evaluated = [TITLES[s.group] for s in ctx.budget.sources if s.state == "evaluated"]
        other = [TITLES[s.group] for s in ctx.budget.sources if s.state != "evaluated"]
        text = "<b>Uncertainty</b> (GUM): u<sub>c</sub> combines the Type A uncertainty of the calibration data"
        text += f" with the Type B inputs {', '.join(evaluated)}" if evaluated else ""
        text += f"; {', '.join(other)}: not applicable or stated as a condition" if other else ""
        text += ". " + _fit_statement(ctx)
        out.append(paragraph(text, "small"))
        for condition in ctx.budget.conditions:
            out.append(paragraph("<b>Condition of validity</b>: " + prose(condition), "small"))
    return out


def _fit_statement(ctx: ReportContext) -> str:
    """Return what the evidence of fit says about u (the same sentence as the technical report's uncertainty statement)."""
    high = [s for s in ctx.stages if s.dof > 0 and s.chi2_red > s.chi2_red_interval()[1]]
    if high:
        names = ", ".join(f"{escape(s.stage)} (χ²<sub>ν</sub> = {content.chi2_text(s.chi2_red)})" for s in high)
        return f"<b>Caution</b>: the residuals of {names} exceed the noise by more than chance allows; u may understate the error."
    if ctx.stages:
        return "The residuals of every fit agree with the noise (technical report, section 7); u is not scaled."
    return "No residual evidence was available to check the model."


def signatures(ctx: ReportContext) -> list[Flowable]:
    """Return the signature block (ISO/IEC 17025 7.8.2.1 o) and the end of the certificate."""
    operator = ctx.identification.get("operator", "")
    rows = [["", "Name", "Function", "Signature and date"], ["Performed by", escape(operator), "", ""], ["Authorized by", "", "", ""]]
    signature = document.table(rows, [0.18, 0.30, 0.22, 0.30], markup=True)
    signature.setStyle(
        [("ROWBACKGROUNDS", (0, 1), (-1, -1), [None]), ("TOPPADDING", (0, 1), (-1, -1), 12), ("GRID", (0, 0), (-1, -1), 0.4, document.RULE)]
    )
    return [
        document.spacer(2),
        KeepTogether([paragraph("Persons performing and authorizing (ISO/IEC 17025 7.8.2.1 o)", "h2"), signature]),
        document.spacer(2),
        paragraph("End of certificate.", "small"),
    ]


CERTIFICATE_SECTIONS = (identification, certificate_results, certificate_conformity, traceability, signatures)
