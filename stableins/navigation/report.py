"""How a navigation budget shows itself: the ranked table, the JSON document, the figure, the comparison."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

from stableins.conventions import ARCSEC
from stableins.display import number, unit_text

if TYPE_CHECKING:  # pragma: no cover
    from stableins.navigation.budget import BudgetComparison, NavigationBudget
    from stableins.navigation.summary import ErrorSummary

#: Columns of the text table: (header, quantity, peak or final).
TABLE_COLUMNS = (
    ("pos peak", "position", "peak"),
    ("pos final", "position", "final"),
    ("vel peak", "velocity", "peak"),
    ("vel final", "velocity", "final"),
    ("pitch pk", "pitch", "peak"),
    ("roll pk", "roll", "peak"),
    ("head pk", "heading", "peak"),
    ("head final", "heading", "final"),
)


def _days(seconds: float) -> str:
    days = seconds / 86400.0
    return f"{number(days, 4)} d" if days >= 1 else f"{number(seconds / 3600.0, 4)} h"


def scenario_text(budget: NavigationBudget) -> str:
    """One line: unit, duration, latitude, damping."""
    s = budget.scenario
    hemisphere = "N" if s.latitude >= 0 else "S"
    damping = f"damping ζ = {number(s.zeta, 3)}" if s.zeta > 0 else "undamped (pure inertial, ζ = 0)"
    vertical = "vertical channel held by a height reference" if s.vertical_gains is not None else "vertical channel left out"
    return (
        f"Navigation budget of {budget.serial_number or 'the unit'} over {_days(budget.duration)} at "
        f"{abs(math.degrees(s.latitude)):.4f}° {hemisphere}, {damping}, {vertical}"
    )


def _cell(summary: ErrorSummary, quantity: str, which: str) -> str:
    pf = summary[quantity]
    value = getattr(pf, which)
    return number(value / ARCSEC if quantity in ("pitch", "roll", "heading") else value, 3)


def _sigma_text(sigma: float, unit: str) -> str:
    return f"{number(sigma, 3)} {unit_text(unit)}".strip()


def budget_text(budget: NavigationBudget, *, rows: int | None = None) -> str:
    """Return the ranked table of :meth:`NavigationBudget.report`."""
    head = ["term", "1σ"] + [c[0] for c in TABLE_COLUMNS]
    body = []
    shown = budget.terms if rows is None else budget.terms[:rows]
    for t in shown:
        body.append([t.id, _sigma_text(t.sigma_engineering, t.unit)] + [_cell(t.summary, q, w) for _, q, w in TABLE_COLUMNS])
    if rows is not None and len(budget.terms) > rows:
        body.append([f"({len(budget.terms) - rows} more)", ""] + [""] * len(TABLE_COLUMNS))
    body.append(["RSS of the terms", ""] + [_cell(budget.rss, q, w) for _, q, w in TABLE_COLUMNS])
    body.append(["total (correlated)", ""] + [_cell(budget.total, q, w) for _, q, w in TABLE_COLUMNS])
    widths = [max(len(r[i]) for r in [head, *body]) for i in range(len(head))]
    line = lambda r: "  ".join(c.ljust(widths[i]) if i < 2 else c.rjust(widths[i]) for i, c in enumerate(r))  # noqa: E731
    lines = [
        scenario_text(budget),
        "Each term: a residual of +1σ alone.  Position and velocity horizontal [m, m/s], attitude [arcsec] of a",
        "level, north-pointing INS; peak over the navigation time and the final value.",
        "",
        line(head),
        *(line(r) for r in body),
    ]
    notes = budget.notes
    if notes:
        lines.append("")
        lines.extend(f"note: {n}" for n in notes)
    return "\n".join(lines)


def _scenario_document(budget: NavigationBudget) -> dict[str, Any]:
    s = budget.scenario
    return {
        "latitude_deg": math.degrees(s.latitude),
        "gravity": s.gravity,
        "zeta": s.zeta,
        "radius": s.radius,
        "vertical_loop": s.vertical_gains is not None,
        "earth_angle_deg": math.degrees(s.earth_angle),
        "duration_s": budget.duration,
        "step_s": budget.step,
    }


def budget_html(budget: NavigationBudget) -> str:
    """Return the ranked table for Jupyter (:func:`stableins.display.html_result`)."""
    from stableins.display import html_result, html_table

    head = ["term", "1σ"] + [c[0] for c in TABLE_COLUMNS]
    rows = [[t.id, _sigma_text(t.sigma_engineering, t.unit)] + [_cell(t.summary, q, w) for _, q, w in TABLE_COLUMNS] for t in budget.terms]
    rows.append(["RSS of the terms", ""] + [_cell(budget.rss, q, w) for _, q, w in TABLE_COLUMNS])
    rows.append(["total (correlated)", ""] + [_cell(budget.total, q, w) for _, q, w in TABLE_COLUMNS])
    units = "position [m], velocity [m/s] (horizontal), attitude [arcsec]; +1σ of each term alone"
    table = html_table(head, rows, numeric=range(2, len(head)))
    return html_result(scenario_text(budget), [units], [table], [("notes", list(budget.notes))])


def budget_document(budget: NavigationBudget) -> dict[str, Any]:
    """Return the JSON document (engineering units)."""
    return {
        "serial_number": budget.serial_number,
        "scenario": _scenario_document(budget),
        "drift": budget.drift.value,
        "terms": [
            {"id": t.id, "kind": t.kind.value, "sigma": t.sigma_engineering, "unit": t.unit, "errors": t.summary.to_dict()}
            for t in budget.terms
        ],
        "rss": budget.rss.to_dict(),
        "total": budget.total.to_dict(),
        "left_out": [{"id": item.id, "reason": item.reason} for item in budget.left_out],
        "notes": list(budget.notes),
    }


def budget_figure(budget: NavigationBudget, path: str | None, *, top: int = 6, file_format: str | None = None) -> Any:
    """Three panels (horizontal position, horizontal velocity, heading): the largest error up to each time."""
    import matplotlib

    if path is not None:
        matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt
    import numpy as np

    from stableins.display import layout_with_caption
    from stableins.navigation.summary import Quantity

    panels = (
        (Quantity.POSITION, "horizontal position [m]", 1.0),
        (Quantity.VELOCITY, "horizontal velocity [m/s]", 1.0),
        (Quantity.HEADING, "heading [arcsec]", ARCSEC),
    )
    fig, axes = plt.subplots(1, 3, figsize=(13, 4.4))
    days = budget.time / 86400.0
    order = list(Quantity)
    shown = budget.terms[:top]
    for ax, (quantity, label, scale) in zip(axes, panels, strict=True):
        q = order.index(quantity)
        floor = None
        for k, term in enumerate(shown):
            series = np.maximum.accumulate(budget.responses[:, q, k]) / scale
            ax.plot(days, series, lw=1.2, label=f"{term.id} ({_sigma_text(term.sigma_engineering, term.unit)})")
            positive = series[series > 0]
            if positive.size:
                floor = positive.min() if floor is None else min(floor, positive.min())
        ax.plot(days, np.maximum.accumulate(budget.rss_series[:, q]) / scale, "k--", lw=1.6, label="RSS of the terms")
        ax.plot(days, np.maximum.accumulate(budget.total_series[:, q]) / scale, "k", lw=2.0, label="total (correlated)")
        ax.set_yscale("log")
        top_value = max(np.max(budget.rss_series[:, q]), np.max(budget.total_series[:, q])) / scale
        if top_value > 0:
            ax.set_ylim(max(floor or top_value * 1e-4, top_value * 1e-4), top_value * 2.0)
        ax.set_xlabel("navigation time [days]")
        ax.set_title(f"largest {label} up to t", fontsize=10)
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=7, loc="lower right")
    layout_with_caption(fig, scenario_text(budget), top=0.88)
    if path is not None:
        fig.savefig(path, dpi=110, format=file_format)
        plt.close(fig)
    return fig


def comparison_text(comparison: BudgetComparison) -> str:
    """Term by term: peak horizontal position and heading of both records and the difference (other − base)."""
    base, other = comparison.base, comparison.other
    ids = list(dict.fromkeys([t.id for t in base.terms] + [t.id for t in other.terms]))
    head = ["term", "1σ A", "1σ B", "pos pk A", "pos pk B", "B − A", "head pk A", "head pk B", "B − A"]
    rows = []

    def cells(a: Any, b: Any) -> list[str]:
        pa = a.position.peak if a else math.nan
        pb = b.position.peak if b else math.nan
        ha = a.heading.peak / ARCSEC if a else math.nan
        hb = b.heading.peak / ARCSEC if b else math.nan
        return [number(pa, 3), number(pb, 3), number(pb - pa, 3), number(ha, 3), number(hb, 3), number(hb - ha, 3)]

    for pid in ids:
        ta = next((t for t in base.terms if t.id == pid), None)
        tb = next((t for t in other.terms if t.id == pid), None)
        sa = _sigma_text(ta.sigma_engineering, ta.unit) if ta else "—"
        sb = _sigma_text(tb.sigma_engineering, tb.unit) if tb else "—"
        rows.append([pid, sa, sb, *cells(ta.summary if ta else None, tb.summary if tb else None)])
    rows.append(["RSS of the terms", "", "", *cells(base.rss, other.rss)])
    rows.append(["total (correlated)", "", "", *cells(base.total, other.total)])
    widths = [max(len(r[i]) for r in [head, *rows]) for i in range(len(head))]
    line = lambda r: "  ".join(c.ljust(widths[i]) if i == 0 else c.rjust(widths[i]) for i, c in enumerate(r))  # noqa: E731
    return "\n".join(
        [
            f"A: {comparison.labels[0] + ': ' if comparison.labels[0] else ''}{scenario_text(base)}",
            f"B: {comparison.labels[1] + ': ' if comparison.labels[1] else ''}{other.serial_number or 'the unit'} in the same scenario",
            "Peak horizontal position [m] and heading [arcsec] per term (+1σ alone); B − A < 0: B's calibration leaves less.",
            "",
            line(head),
            *(line(r) for r in rows),
        ]
    )


def comparison_document(comparison: BudgetComparison) -> dict[str, Any]:
    """JSON of a comparison: both budgets and the differences (other − base) of every peak and final."""
    from stableins.navigation.summary import Quantity

    base, other = comparison.base, comparison.other

    def difference(a: ErrorSummary | None, b: ErrorSummary | None) -> dict[str, dict[str, float | None]]:
        out: dict[str, dict[str, float | None]] = {}
        for q in Quantity:
            if a is None or b is None:
                out[q.value] = {"peak": None, "final": None, "unit": q.unit}  # type: ignore[dict-item]
            else:
                out[q.value] = {"peak": (b[q].peak - a[q].peak) / q.scale, "final": (b[q].final - a[q].final) / q.scale, "unit": q.unit}  # type: ignore[dict-item]
        return out

    ids = list(dict.fromkeys([t.id for t in base.terms] + [t.id for t in other.terms]))
    by_a = {t.id: t for t in base.terms}
    by_b = {t.id: t for t in other.terms}
    return {
        "labels": list(comparison.labels),
        "base": budget_document(base),
        "other": budget_document(other),
        "difference": {
            "terms": {
                pid: difference(by_a[pid].summary if pid in by_a else None, by_b[pid].summary if pid in by_b else None) for pid in ids
            },
            "rss": difference(base.rss, other.rss),
            "total": difference(base.total, other.total),
        },
    }
