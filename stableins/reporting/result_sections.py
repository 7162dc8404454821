"""Sections 4-6 of a certificate: the results, the uncertainty budget and the correlations."""

from __future__ import annotations

import math
from typing import Any

from reportlab.platypus import Flowable

from stableins.conventions import STANDARD_GRAVITY
from stableins.reporting import content, document, figures, rounding
from stableins.reporting.budget import GROUPS, SHORT, TITLES
from stableins.reporting.context import NOT_RECORDED, ReportContext, paragraph
from stableins.reporting.document import escape, heading
from stableins.reporting.symbols import MINUS, markup, prose


# ---------------------------------------------------------------------- 4 results
def results(ctx: ReportContext) -> list[Flowable]:
    """Return section 4: every parameter's value, expanded uncertainty, status and the stage that determined it."""
    from stableins.estimators.result import Stage

    out: list[Flowable] = [*heading("4  Results", room_mm=60)]
    k = rounding.COVERAGE_FACTOR
    out.append(
        paragraph(
            "Values of the record in force after this calibration, in engineering units: scale factors SF as deviation from 1 in ppm, "
            "biases δb in µg, angles in arcsec, quadratic nonlinearity K<sub>2</sub> in µg/g² "
            f"(1 g = {STANDARD_GRAVITY:g} m/s², the conventional value, for units only). u is the combined standard uncertainty of "
            f"section 5 (Type A and Type B); U = k·u with k = {k:g}. "
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
    out.append(document.table(rows, [0.11, 0.14, 0.12, 0.10, 0.11, 0.09, 0.33], align_right=(2, 3, 4), markup=True))
    carried = [r for r in ctx.rows if r.estimated and not r.measured]
    if carried:
        out.append(
            paragraph(
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
    determined = [(s.name, d) for s in ctx.record.stages_run if s.name != Stage.SYSTEM for d in s.determined]  # system: section 7
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
    """Return section 5, the uncertainty budget (GUM): Type A from the record, each Type B input, combined u, k and U per parameter."""
    out: list[Flowable] = [*heading("5  Uncertainty budget", room_mm=50)]
    budget = ctx.budget
    k = rounding.COVERAGE_FACTOR
    if budget is None:
        out.append(paragraph("<b>Not evaluated</b>: no budget was computed for this record."))
        return out
    out.append(
        paragraph(
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
        term_scale = row.u / budget.combined_of(row.id) if budget.combined_of(row.id) > 0 else math.nan

        def cell(si: float, group: str = "", *, row: content.ParameterRow = row, scale: float = term_scale) -> str:
            state = budget.state(group) if group else "evaluated"
            if state != "evaluated":
                return "n.e." if state == "not evaluated" else "—"
            # as the results table writes u (rounding.gum): to u's decimal place, m×10ⁿ at U's power when U is tiny
            return rounding.like_uncertainty(si * scale, row.u, row.coverage)

        r = row.rounded()
        rows.append(
            [row.symbol, escape(row.unit), cell(budget.type_a[budget.ids.index(row.id)])]
            + [cell(budget.contribution(g, row.id), g) for g in GROUPS]
            + [r.u, r.expanded]
        )
    widths = [0.11, 0.07, 0.12, 0.05, 0.09, 0.07, 0.07, 0.06, 0.08, 0.12, 0.11]
    out.append(document.table(rows, widths, align_right=tuple(range(2, 11)), markup=True))
    not_evaluated = [TITLES[s.group] for s in budget.sources if s.state == "not evaluated"]
    text = (
        "Standard uncertainties in the unit of each parameter, given to the decimal place of u<sub>c</sub> (a contribution below "
        "it shows as 0). Columns: local gravity g, gimbal angle sensors, instrument temperature (temp.), gyro drift, damping loop, "
        "slow noise the dwells allow but do not resolve; "
        "—: the input does not apply to this record or is stated as a condition of validity (see the inputs above)."
    )
    if not_evaluated:
        text += f" n.e.: not evaluated ({escape(', '.join(not_evaluated))}); it is not in u<sub>c</sub>."
    out.append(paragraph(text, "small"))
    if budget.conditions:
        out += heading("Conditions of validity", "h2", room_mm=15)
        for condition in budget.conditions:
            out.append(paragraph(prose(condition)))
    out.append(paragraph(_uncertainty_statement(ctx), "small"))
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
    """Return section 6: the correlation matrix of the estimates."""
    out: list[Flowable] = [*heading("6  Correlation of the estimates", room_mm=40)]
    ids, matrix = content.correlation(ctx.record)
    if len(ids) < 2:
        out.append(paragraph("Not shown: the calibration record carries no covariance of two or more estimated parameters."))
        return out
    strong = sorted(
        ((abs(matrix[i][j]), ids[i], ids[j], matrix[i][j]) for i in range(len(ids)) for j in range(i)),
        reverse=True,
    )
    strong = [s for s in strong if s[0] >= 0.5]
    out.append(
        paragraph(
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
