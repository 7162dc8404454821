"""Sections 9-11 of a certificate: the change since the previous calibration, conformity, notes and authorization."""

from __future__ import annotations

import math
from typing import Any

from reportlab.platypus import Flowable, KeepTogether

from stableins.history import CHANGE_THRESHOLD
from stableins.reporting import content, document, figures, rounding
from stableins.reporting.context import ReportContext, file_name, fmt, no_statement, paragraph, period, verdict_colour_hex
from stableins.reporting.document import escape, heading
from stableins.reporting.symbols import MINUS, markup
from stableins.reporting.tolerances import RULE_TEXT


# ---------------------------------------------------------------------- 9 change
def change(ctx: ReportContext) -> list[Flowable]:
    """Return section 9: the change of every parameter since the previous calibration of the unit."""
    out: list[Flowable] = [*heading("9  Change since the previous calibration", room_mm=50)]
    if ctx.previous is None or ctx.comparison is None or ctx.changes is None:
        out.append(paragraph("<b>Not performed</b>: no previous calibration record was given."))
        return out
    prev = ctx.previous
    how = (
        "This record updates the previous one (a Bayesian update), so their errors are correlated: u(Δ)² = u<sub>prev</sub>² − "
        "u<sub>new</sub>²."
        if ctx.comparison.relation == "descendant"
        else "The two calibrations are independent: u(Δ)² = u<sub>prev</sub>² + u<sub>new</sub>²."
    )
    out.append(
        paragraph(
            f"Previous record: {escape(file_name(ctx.previous_path))} (serial number "
            f"{escape(prev.serial_number)}, calibrated {escape(period(prev))}). Δ = now − previous; {how} Here u is the Type A "
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
            now_text = now.rounded().value if now is not None else fmt(c.new, 5)
            before_text = before.rounded().value if before is not None else fmt(c.old, 5)
            delta = (
                f"{rounding.round_to_uncertainty(c.delta, c.u_delta)}" if math.isfinite(c.u_delta) and c.u_delta > 0 else fmt(c.delta, 3)
            )
            rows.append(
                [markup(c.id), before_text, now_text, delta, fmt(c.u_delta, 2), z, "yes" if c.significant else "no", escape(c.unit)]
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
        out.append(paragraph("Not compared: " + "; ".join(ctx.text(s) for s in ctx.comparison.skipped) + ".", "small"))
    return out


# ---------------------------------------------------------------------- 10 conformity
def conformity_statement(ctx: ReportContext) -> list[Flowable]:
    """Return section 10: the statement of conformity with the procedure's tolerances and decision rule."""
    out: list[Flowable] = [*heading("10  Statement of conformity", room_mm=50)]
    t = ctx.tolerances
    if t.empty:
        return [*out, no_statement(t)]
    verdict = content.overall_verdict(ctx.checks)
    colour = verdict_colour_hex(verdict)
    out.append(
        paragraph(
            f"Tolerances: {escape(file_name(t.source))}. Decision rule: {escape(RULE_TEXT[t.decision_rule])} "
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
                paragraph(f'Verdict: <font color="{colour}">{verdict}</font>', "verdict"),
                paragraph(
                    f"{content.conformity_counts(ctx.checks)}. Checks marked 'not assessed' concern parameters without a stated value "
                    "or evidence and do not enter the verdict.",
                    "small",
                ),
            ]
        )
    )
    return out


# ---------------------------------------------------------------------- 12 notes
def closing(ctx: ReportContext) -> list[Flowable]:
    """Return section 12: the notes of the record not shown before (the certificate carries the signatures)."""
    out: list[Flowable] = [*heading("12  Notes", room_mm=45)]
    stage_notes = {n for s in ctx.record.stages for n in s.notes} | {f"[{s.name}] {n}" for s in ctx.record.stages for n in s.notes}
    remaining = [n for n in ctx.record.notes if n not in ctx.shown_notes and n not in stage_notes]
    if remaining:
        out.append(document.table([["Notes from the calibration record"]] + [[ctx.text(n)] for n in remaining], [1.0], markup=True))
    else:
        out.append(paragraph("Every note of the calibration record is shown with the stage it belongs to (sections 4 and 7)."))
    out.append(document.spacer(4))
    out.append(paragraph("End of report.", "small"))
    return out
