"""How results show themselves: a short ``repr`` in a terminal, HTML tables in Jupyter, pandas DataFrames.

Every user-facing result (:class:`~stableins.estimators.result.FitResult`, the calibration record,
the diagnosis, the ranking, the discovery history, the system stage's result, the noise model ...)
has

* ``repr(result)``: at most :data:`MAX_REPR_LINES` lines: what it is, its headline numbers and how
  to see the rest (``print(result)`` prints the full report);
* ``result._repr_html_()``: the same as HTML tables for Jupyter, in engineering units, with statuses
  and 1σ; every text is escaped (:func:`html.escape`), so ids, notes and file names cannot inject markup;
* ``result.to_dataframe()`` where the result is a table (parameters, candidates, steps): a
  :class:`pandas.DataFrame`.  pandas is an optional dependency (``pip install stableins[pandas]``);
  without it ``to_dataframe`` raises an :class:`ImportError` that names the extra.

Values with a standard uncertainty are shown as GUM 7.2.6 recommends: σ to two significant digits,
the value rounded to the same decimal place (:func:`value_sigma`).  No numpy here.
"""

from __future__ import annotations

import html
import math
import re
from collections.abc import Iterable, Sequence
from typing import Any

from stableins.status import Status

#: Most lines a result's ``repr`` prints (the rest: ``print(result)``).
MAX_REPR_LINES = 25
#: What to install for :func:`require_pandas`.
PANDAS_EXTRA = "stableins[pandas]"
#: Parameters per line in a repr's grouped parameter block.
PER_LINE = 3


def require_pandas() -> Any:
    """Import :mod:`pandas`, or raise an ImportError that says how to install it (the ``pandas`` extra)."""
    try:
        import pandas
    except ImportError as error:  # pragma: no cover - the test extra installs pandas; tested by hiding it
        raise ImportError(
            f"to_dataframe() needs pandas, an optional dependency of stableins: pip install '{PANDAS_EXTRA}' (or pip install pandas)"
        ) from error
    return pandas


def unit_text(unit: str) -> str:
    """Engineering unit as people read it (``ug/g^2`` → ``µg/g²``, ``1`` → no unit)."""
    if unit in ("1", ""):
        return ""
    unit = re.sub(r"(?<![A-Za-z])u(g|rad)(?![A-Za-z])", r"µ\1", unit)
    return unit.replace("^2", "²").replace("^3", "³").replace("sqrt(Hz)", "√Hz").replace("sqrt(s)", "√s")


def number(x: float, significant: int = 4) -> str:
    """``x`` to ``significant`` significant digits (``—`` for NaN, ``∞`` for infinity)."""
    if isinstance(x, float | int) and not isinstance(x, bool):
        if math.isnan(x):
            return "—"
        if math.isinf(x):
            return "∞" if x > 0 else "−∞"
    return f"{x:.{significant}g}"


def value_sigma(value: float, sigma: float, unit: str = "") -> str:
    """``value ± σ unit``: σ to two significant digits and the value to the same decimal place (GUM 7.2.6).

    >>> value_sigma(12.3456, 0.0123, "ppm")
    '+12.346 ± 0.012 ppm'
    >>> value_sigma(-0.5, float("nan"))
    '-0.5'
    """
    tail = f" {unit}" if unit else ""
    if not math.isfinite(value):
        return "—"
    if not (math.isfinite(sigma) and sigma > 0):
        return f"{value:.6g}{tail}"
    decimals = max(1 - math.floor(math.log10(sigma)), 0)
    shown = f"{value:+.{decimals}f}"
    if float(shown) == 0.0:
        shown = f"{0.0:.{decimals}f}"  # no signed zero
    return f"{shown} ± {sigma:.{decimals}f}{tail}"


def clipped(lines: Sequence[str], hint: str) -> str:
    """At most :data:`MAX_REPR_LINES` lines, the last one ``hint`` (how to see everything)."""
    lines = [line for line in lines if line is not None]
    room = MAX_REPR_LINES - 1
    if len(lines) > room:
        dropped = len(lines) - (room - 1)
        lines = [*lines[: room - 1], f"  … {dropped} more lines"]
    return "\n".join([*lines, hint])


def _stem(parameter_id: str) -> tuple[str, str]:
    """``sf_x`` → (``sf``, ``x``); ``theta10`` → (``theta``, ``10``); ``Kcc_xxy`` → (``Kcc``, ``xxy``)."""
    if "_" in parameter_id:
        head, tail = parameter_id.rsplit("_", 1)
        return head, tail
    match = re.fullmatch(r"(.*?[A-Za-z])(\d+)", parameter_id)
    return (match.group(1), match.group(2)) if match else (parameter_id, "")


def parameter_lines(rows: Iterable[tuple[str, float, float, str, str]]) -> list[str]:
    """Compact lines of ``(id, value, σ, unit, status)`` rows (engineering units) for a repr.

    Parameters sharing a stem and unit (``sf_x, sf_y, sf_z``) share a line, :data:`PER_LINE` at a
    time; a parameter that is not ``estimated`` shows its status instead of a σ.
    """
    groups: dict[tuple[str, str], list[str]] = {}
    for parameter_id, value, sigma, unit, status in rows:
        stem, tail = _stem(parameter_id)
        status = str(status)
        if status == Status.UNIDENTIFIABLE:
            text = "not determined"
        elif status == Status.ESTIMATED:
            text = value_sigma(value, sigma)
        else:
            text = f"{value:.4g} ({status})"
        groups.setdefault((stem, unit_text(unit)), []).append(f"{tail or parameter_id} {text}")
    width = max((len(f"{s} [{u}]") for s, u in groups), default=0)
    lines = []
    for (stem, unit), items in groups.items():
        label = f"{stem} [{unit}]" if unit else stem
        for k in range(0, len(items), PER_LINE):
            head = label if k == 0 else ""
            lines.append(f"  {head:<{width}}  " + "   ".join(items[k : k + PER_LINE]))
    return lines


def parameter_table(rows: Sequence[tuple[Any, ...]], determined: Sequence[str] = (), notes: Sequence[str] = ()) -> list[str]:
    """Return the text lines of a parameter table ``(id, value, 1σ, unit, status[, determined by])`` in engineering units.

    Unidentifiable parameters show no numbers (their value in a record is only the prior
    carried through).  Shared by :meth:`stableins.estimators.result.FitResult.report` and the calibration record's report.
    """
    sources = any(len(r) > 5 for r in rows)
    lines = [f"{'parameter':<12} {'value':>14} {'1 sigma':>11} {'unit':<8} {'status':<15}" + (" last determined by" if sources else "")]
    for parameter_id, value, sigma, unit, status, *source in rows:
        tail = f" {source[0]}" if source else ""
        if status == Status.UNIDENTIFIABLE:
            lines.append(f"{parameter_id:<12} {'—':>14} {'—':>11} {unit:<8} {status:<15}{tail}".rstrip())
        else:
            # four decimals; for a σ below 1e-3 of its unit (a gyro drift of 1e-7 °/h) two significant digits of σ and
            # the value to the same place, as value_sigma writes them (four decimals would show 0.0000 ± 0.0000)
            places = 4 if not 0.0 < sigma < 1e-3 else 1 - math.floor(math.log10(sigma))
            lines.append(f"{parameter_id:<12} {value:>14.{places}f} {sigma:>11.{places}f} {unit:<8} {status:<15}{tail}".rstrip())
    if determined:
        lines += ["", "determined combinations:"] + [f"  {d}" for d in determined]
    if notes:
        lines += ["", "notes:"] + [f"  {n}" for n in notes]
    return lines


def plural(count: int, word: str) -> str:
    """``1 note``, ``3 notes``."""
    return f"{count} {word}" + ("" if count == 1 else "s")


def status_counts(statuses: Iterable[str]) -> str:
    """``17 estimated, 1 gauge, 1 fixed`` (in the order first seen)."""
    counts: dict[str, int] = {}
    for s in statuses:
        counts[str(s)] = counts.get(str(s), 0) + 1
    return ", ".join(f"{n} {s}" for s, n in counts.items())


# ----------------------------------------------------------------------------- HTML
_STYLE = "border-collapse:collapse;font-size:90%;margin:0.3em 0"
_CELL = "padding:1px 8px;border-bottom:1px solid #ddd"
_STATUS_COLOUR = {"estimated": "", "fixed": "#555", "gauge": "#555", "unidentifiable": "#a00"}


def escape_html(text: Any) -> str:
    """HTML-escaped ``str(text)`` (quotes too)."""
    return html.escape(str(text), quote=True)


def html_table(
    columns: Sequence[str],
    rows: Iterable[Sequence[Any]],
    *,
    numeric: Iterable[int] = (),
    titles: Sequence[str] = (),
    status_column: int | None = None,
) -> str:
    """Render an HTML table; every cell is escaped.

    Cells are typeset (:func:`typeset`: ``χ²_ν``, ``f_x``).  ``numeric``: column indices aligned right; ``titles``: a
    tooltip per row (e.g. a parameter's meaning);
    ``status_column``: the column holding a parameter status (rows not ``estimated`` are greyed, ``unidentifiable`` red).
    """
    right = set(numeric)

    def cell(k: int, value: Any, tag: str = "td") -> str:
        align = "right" if k in right else "left"
        return f'<{tag} style="{_CELL};text-align:{align}">{typeset(escape_html(value))}</{tag}>'

    head = "<tr>" + "".join(cell(k, c, "th") for k, c in enumerate(columns)) + "</tr>"
    body = []
    for r, row in enumerate(rows):
        title = f' title="{escape_html(titles[r])}"' if r < len(titles) and titles[r] else ""
        status = str(row[status_column]) if status_column is not None else ""
        colour = f' style="color:{_STATUS_COLOUR[status]}"' if _STATUS_COLOUR.get(status) else ""
        body.append(f"<tr{title}{colour}>" + "".join(cell(k, v) for k, v in enumerate(row)) + "</tr>")
    return f'<table style="{_STYLE}"><thead>{head}</thead><tbody>{"".join(body)}</tbody></table>'


def typeset(text: str) -> str:
    """Return escaped HTML text with the plain-text notations typeset, no literal underscore.

    ``χ²_ν`` → χ²<sub>ν</sub>, the outputs ``f_x`` → f<sub>x</sub> (parameter ids stay as they are typed).
    """
    text = text.replace("χ²_ν", "χ²<sub>ν</sub>").replace("chi2_red", "χ²<sub>ν</sub>")
    return re.sub(r"\bf_([xyz])\b", r"<i>f</i><sub>\1</sub>", text)


def html_result(
    title: str, lines: Iterable[str] = (), tables: Iterable[str] = (), details: Iterable[tuple[str, Sequence[str]]] = ()
) -> str:
    """Render a result for Jupyter: a bold title, lines of text, tables (already HTML) and collapsed details.

    ``lines`` and ``details`` are plain text (escaped here); ``tables`` are :func:`html_table` output.
    """
    parts = [f'<div class="stableins-result"><strong>{escape_html(title)}</strong>']
    for line in lines:
        if line:
            colour = ";color:#b3261e" if line.startswith("warning:") else ""
            parts.append(f'<div style="margin:0.2em 0{colour}">{typeset(escape_html(line))}</div>')
    parts += list(tables)
    for summary, items in details:
        if items:
            body = "".join(f"<li>{typeset(escape_html(item))}</li>" for item in items)
            parts.append(f"<details><summary>{escape_html(summary)}</summary><ul>{body}</ul></details>")
    parts.append("</div>")
    return "".join(parts)


def parameter_html(
    rows: Iterable[tuple[str, float, float, str, str] | tuple[str, float, float, str, str, str]],
    meanings: Sequence[str] = (),
    extra: str = "",
) -> str:
    """Render the parameter table in HTML: parameter, value ± 1σ, unit, status (and a last column ``extra`` when rows carry one)."""
    rows = list(rows)
    columns = ["parameter", "value ± 1σ", "unit", "status"] + ([extra] if extra else [])
    body = []
    for parameter_id, value, sigma, unit, status, *rest in rows:
        shown = (
            "not determined" if status == Status.UNIDENTIFIABLE else value_sigma(value, sigma if status == Status.ESTIMATED else math.nan)
        )
        body.append([parameter_id, shown, unit_text(unit), str(status), *rest[:1]])
    return html_table(columns, body, numeric=(1,), titles=list(meanings), status_column=3)


# ----------------------------------------------------------------------------- figures
#: An identifier with a subscript, as results name outputs and effects (``f_x``, ``Kcc_xxy``, ``K3_x``).
_SUBSCRIPTED = re.compile(r"(?<![\w$\\^])([A-Za-z][A-Za-z0-9]*)_([A-Za-z0-9]+(?:_[A-Za-z0-9]+)*)\b")


def plot_text(text: str) -> str:
    r"""Return ``text`` for a matplotlib title, label or legend, subscripts typeset in mathtext, never a literal underscore.

    ``χ²_ν`` becomes :math:`\chi^2_\nu` and an identifier ``name_sub`` (an output ``f_x``, an effect ``Kcc_xxy``) the name
    with its subscript (``$\mathregular{Kcc}_{\mathregular{xxy}}$``); text already in mathtext (``$...$``) is left as it
    is.  Commands to type (a figure's caption) keep their underscores: they are not passed here.
    """
    if "$" in text:
        return text
    text = text.replace("χ²_ν", r"$\chi^2_\nu$")
    return _SUBSCRIPTED.sub(_subscripted, text)


def _subscripted(match: re.Match[str]) -> str:
    """``f_x`` → ``$f_{x}$`` (a one-letter symbol in italics), ``Kcc_xxy`` → upright name and subscript."""
    name, subscript = match.group(1), match.group(2).replace("_", ",")
    if len(name) == 1:
        return rf"${name}_{{{subscript}}}$"
    return rf"$\mathregular{{{name}}}_{{\mathregular{{{subscript}}}}}$"


def layout_with_caption(fig: Any, text: str | None, top: float = 0.94) -> None:
    """Lay a matplotlib figure out (``tight_layout`` under a suptitle ending at ``top``) with ``text`` wrapped under it.

    The discovery plots end with what to do next (:meth:`stableins.discovery.ranking.Ranking.next_step`).
    """
    import textwrap

    bottom = 0.0
    if text:
        wrapped = textwrap.fill(text, max(60, int(fig.get_figwidth() * 14)))
        if "$" not in wrapped:  # a command in the caption keeps its underscores; χ²_ν is typeset
            wrapped = wrapped.replace("χ²_ν", r"$\chi^2_\nu$")
        fig.text(0.5, 0.008, wrapped, ha="center", va="bottom", fontsize=9, style="italic", color="#7a2e00")
        bottom = (0.2 + 0.16 * (wrapped.count("\n") + 1)) / fig.get_figheight()
    fig.tight_layout(rect=(0.0, bottom, 1.0, top))
