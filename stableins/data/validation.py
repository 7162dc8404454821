"""Checks shared by every reader: column names and units, finite values, time order.

Each check raises :class:`~stableins.errors.InputError` naming the file, the
1-based data row and/or the field, and what was expected.
"""

from __future__ import annotations

import difflib
import re
from collections.abc import Sequence
from typing import Any

from stableins.errors import InputError
from stableins.schema import SCHEMA_VERSION, Column, column_limits

#: The physical limits of every bounded column, by name (stableins.schema).
_LIMITS = column_limits()
_HEADER = re.compile(r"^\s*([^\[\]]*?)\s*(?:\[([^\[\]]*)\])?\s*$")

#: File kinds and the ``format`` tag written in their header.
FORMAT_TAGS = {"device": "stableins-device", "system": "stableins-system"}


def parse_header(header: str) -> tuple[str, str | None]:
    """Split ``"f_x[m/s^2]"`` into ``("f_x", "m/s^2")``; a header without brackets has unit ``None``."""
    match = _HEADER.match(header)
    if match is None:
        return header.strip(), None
    return match.group(1), match.group(2)


def match_columns(found: Sequence[tuple[str, str | None]], schema: Sequence[Column], path: Any) -> dict[str, int]:
    """Map every schema column to its position in ``found`` (``(name, unit)`` pairs).

    Raises
    ------
    InputError
        For a missing column (suggesting the closest found name), a duplicated column
        or a column with the wrong unit (found vs expected).
    """
    positions: dict[str, int] = {}
    for k, (name, _unit) in enumerate(found):
        if name in positions:
            raise InputError("column appears twice", path=path, field=name, expected="each column once")
        positions[name] = k
    expected_names = {c.name for c in schema}
    for c in schema:
        if c.name not in positions:
            unknown = [n for n, _ in found if n not in expected_names]
            close = difflib.get_close_matches(c.name, unknown, n=1, cutoff=0.5) or difflib.get_close_matches(
                c.name.lower(), [n.lower() for n in unknown], n=1, cutoff=0.5
            )
            hint = f"; found '{close[0]}' instead, did you mean '{c.header}'?" if close else ""
            raise InputError(f"missing column{hint}", path=path, field=c.name, expected=f"a column headed '{c.header}' ({c.meaning})")
        unit = found[positions[c.name]][1]
        if (unit or None) != c.unit:
            shown = "no unit" if unit is None else f"unit '{unit}'"
            wanted = "no unit" if c.unit is None else f"unit '{c.unit}', header '{c.header}'"
            raise InputError(f"wrong unit: {shown} found", path=path, field=c.name, expected=wanted)
    return {name: positions[name] for name in (c.name for c in schema)}


def check_header_document(document: Any, kind: str, path: Any) -> None:
    """Check the ``format`` and ``schema_version`` entries of a file header."""
    if not isinstance(document, dict):
        raise InputError("header is not a JSON object", path=path, expected="the header of docs/formats.md")
    tag = FORMAT_TAGS[kind]
    if document.get("format") != tag:
        raise InputError(f"format {document.get('format')!r} found", path=path, field="format", expected=f"'{tag}'")
    version = document.get("schema_version")
    if version != SCHEMA_VERSION:
        raise InputError(
            f"unknown schema version {version!r}; this stableins reads version {SCHEMA_VERSION}",
            path=path,
            field="schema_version",
            expected=str(SCHEMA_VERSION),
        )


def check_finite(name: str, values: Any, path: Any, first_row: int = 1, row_step: int = 1) -> None:
    """Raise for the first NaN or infinity of a float column, or a value outside the column's physical limits.

    ``first_row`` is the row number of ``values[0]``; ``row_step`` the rows between consecutive values
    (values taken at every ``row_step``-th row of the record).  The limits are those of :mod:`stableins.schema`
    (``Column.limits``: what any instrument can write there, e.g. ±10⁴ m/s² of specific force), so every reader
    of every file kind refuses the same values (docs/formats.md, "What the readers check").
    """
    import numpy as np

    values = np.asarray(values)
    if values.dtype.kind != "f":
        return
    limits = _LIMITS.get(name)
    with np.errstate(over="ignore", invalid="ignore"):  # a sum of large finite values may overflow: then look (below)
        total = np.add.reduce(values, axis=None)
    if np.isfinite(total) and (limits is None or values.size == 0 or limits[0] <= values.min() and values.max() <= limits[1]):
        return  # NaN and ±inf propagate into the sum: one pass, no temporary; the limits: two more
    bad = ~np.isfinite(values)  # a non-finite value, or finite values whose sum overflowed: look
    if limits is not None and not bad.any():
        outside = (values < limits[0]) | (values > limits[1])
        if outside.any():
            k = int(np.argmax(outside))
            raise InputError(
                f"value {values[k].item()!r} is beyond what an instrument can give",
                path=path,
                row=first_row + k * row_step,
                field=name,
                expected=f"a value from {limits[0]:g} to {limits[1]:g} (docs/formats.md)",
            )
    if bad.any():
        k = int(np.argmax(bad))
        raise InputError(
            f"value {values[k].item()!r} is not finite", path=path, row=first_row + k * row_step, field=name, expected="a finite number"
        )


def check_increasing(time: Any, path: Any, first_row: int = 1, previous: float | None = None, field: str = "time") -> None:
    """Raise at the first sample whose time does not increase strictly."""
    import numpy as np

    time = np.asarray(time, dtype=float)
    if previous is not None:
        time = np.concatenate([[previous], time])
        first_row -= 1
    if time.size < 2:
        return
    bad = np.diff(time) <= 0
    if bad.any():
        k = int(np.argmax(bad)) + 1
        raise InputError(
            f"time does not increase: {float(time[k])!r} s follows {float(time[k - 1])!r} s",
            path=path,
            row=first_row + k,
            field=field,
            expected="strictly increasing time",
        )
