"""How a :class:`~stableins.noise.NoiseModel` shows itself: one line, a table, ``repr``, Jupyter, pandas.

Engineering units (µg/√Hz, µg, µg/√s, µg·√s) as :data:`stableins.noise.ENGINEERING` scales them.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from stableins.conventions import MICRO_G
from stableins.display import clipped, html_result, html_table, require_pandas, unit_text
from stableins.noise import AXES, ENGINEERING, LABELS, TERMS

if TYPE_CHECKING:
    from stableins.noise import NoiseModel


def _triple(v: NDArray[np.float64], rtol: float = 1e-5) -> str:
    """One number when the three axes agree (to ``rtol``), else x/y/z."""
    return f"{np.max(v):.3g}" if np.allclose(v, np.max(v), rtol=rtol, atol=0.0) else "/".join(f"{x:.3g}" for x in v)


def describe(model: NoiseModel) -> str:
    """Return one line: source and the slow terms (engineering units)."""
    b = model.values("bias_instability") / MICRO_G
    k = model.values("random_walk") / MICRO_G
    parts = [f"noise model ({model.source.value}"]
    if model.provenance:
        parts[0] += f": {model.provenance}"
    parts[0] += ")"
    if model.test is not None and not model.test.detected:  # the console's words: not detected, and what the data allow
        b_up = model.limits("bias_instability")[1] / MICRO_G
        k_up = model.limits("random_walk")[1] / MICRO_G
        b_text = f"up to {_triple(b_up, 0.01)} µg" if np.all(np.isfinite(b_up)) else "not bounded"
        k_text = f"up to {_triple(k_up, 0.01)} µg/√s" if np.all(np.isfinite(k_up)) else "not bounded"
        parts.append(f"slow noise not detected: bias instability {b_text}, random walk {k_text}")
        return "; ".join(parts)
    parts.append(f"bias instability {_triple(b)} µg, random walk {_triple(k)} µg/√s")
    if not model.slow_noise_bounded:
        parts.append("slow noise not bounded by the data")
    return "; ".join(parts)


def summary(model: NoiseModel) -> str:
    """Return one short line for tables (certificate settings): source, N, B and K with their upper limits, the decision."""

    def term(name: str, unit: str, *, limit: bool = True) -> str:
        v = model.values(name) / MICRO_G
        up = model.limits(name)[1] / MICRO_G
        text = f"{_triple(v, 0.01)} {unit}"
        if not limit:
            return text
        if np.all(np.isinf(up)):
            return text + " (not bounded)" if np.all(v == 0) else text
        if not np.allclose(up, v):
            text += f" (≤ {_triple(up, 0.01)})"
        return text

    parts = [
        f"noise model ({model.source.value}): white {term('white', 'µg/√Hz', limit=False)}",
        f"bias instability {term('bias_instability', 'µg')}",
        f"random walk {term('random_walk', 'µg/√s')}",
    ]
    if model.test is not None:
        parts.append(f"slow noise {'detected' if model.test.detected else 'not detected'} (p = {model.test.p_value:.2g})")
    return ", ".join(parts[:3]) + ("; " + parts[3] if len(parts) > 3 else "")


def report(model: NoiseModel) -> str:
    """Return the table of every term per axis with its interval, in engineering units."""
    level = f"{100 * model.confidence:g} %"
    lines = [f"noise model: {model.source.value}" + (f" ({model.provenance})" if model.provenance else "")]
    lines.append(f"{'term':<40} {'axis':>4} {'value':>12} {level + ' interval':>28}  unit")
    for label, axis, value, interval, unit in term_rows(model):
        lines.append(f"{label if axis == AXES[0] else '':<40} {axis:>4} {value:>12} {interval:>28}  {unit}")
    decision = test_line(model)
    if decision is not None:
        lines.append(decision)
    return "\n".join(lines)


def term_rows(model: NoiseModel) -> list[list[str]]:
    """Return one row per term and axis: label, axis, value, interval (engineering units)."""
    rows = []
    for name in TERMS:
        unit, scale = ENGINEERING[name]
        for a, axis in enumerate(model.axes):
            term = axis.term(name)
            upper = "not bounded" if not term.bounded else f"{term.upper / scale:.4g}"
            rows.append([LABELS[name], AXES[a], f"{term.value / scale:.4g}", f"[{term.lower / scale:.4g}, {upper}]", unit])
    return rows


def test_line(model: NoiseModel) -> str | None:
    """Return the slow-noise decision in one line, None without a test."""
    if model.test is None:
        return None
    t = model.test
    verdict = "detected" if t.detected else "not detected"
    return (
        f"slow noise {verdict}: statistic {t.statistic:+.2f} (0 ± 1 under white noise), p = {t.p_value:.3g} "
        f"(false-positive rate {t.alpha:g})"
    )


def short_repr(model: NoiseModel) -> str:
    """Return the ``repr``: one line per term, clipped for a terminal."""
    lines = [f"<NoiseModel ({model.source.value}{': ' + model.provenance if model.provenance else ''})>"]
    for name in TERMS:
        unit, scale = ENGINEERING[name]
        cells = []
        for axis in model.axes:
            term = axis.term(name)
            upper = "∞" if not term.bounded else f"{term.upper / scale:.3g}"
            interval = "" if term.lower == term.value == term.upper else f" [{term.lower / scale:.3g}, {upper}]"
            cells.append(f"{term.value / scale:.3g}{interval}")
        same = len(set(cells)) == 1
        shown = f"{cells[0]} on every axis" if same else "   ".join(f"{a} {c}" for a, c in zip(AXES, cells, strict=True))
        lines.append(f"  {LABELS[name]} [{unit_text(unit)}]: {shown}")
    lines.append(test_line(model) or f"intervals at {100 * model.confidence:g} % confidence")
    return clipped(lines, "(print(model) for the table)")


def html(model: NoiseModel) -> str:
    """Return the Jupyter rendering: the table of :func:`term_rows`."""
    rows = [[label, axis, value, interval, unit_text(unit)] for label, axis, value, interval, unit in term_rows(model)]
    table = html_table(["term", "axis", "value", f"{100 * model.confidence:g} % interval", "unit"], rows, numeric=(2, 3))
    return html_result(f"Noise model: {model.source.value}", [model.provenance, test_line(model) or ""], [table])


def dataframe(model: NoiseModel) -> Any:
    """Return every term and axis as a :class:`pandas.DataFrame` (needs pandas).

    Columns ``term``, ``axis``, ``value``, ``lower``, ``upper``, ``unit``; engineering units, ``upper``
    infinite where the data do not bound the term.
    """
    pandas = require_pandas()
    rows = []
    for name in TERMS:
        unit, scale = ENGINEERING[name]
        for a, axis in enumerate(model.axes):
            term = axis.term(name)
            rows.append(
                {
                    "term": name,
                    "axis": AXES[a],
                    "value": term.value / scale,
                    "lower": term.lower / scale,
                    "upper": term.upper / scale,
                    "unit": unit,
                }
            )
    return pandas.DataFrame.from_records(rows)
