"""The user's statement of what a log's columns are: command-line options or a small mapping file.

``--columns time=t,f_x=acc_x,f_y=acc_y,f_z=acc_z`` (header names, 1-based column numbers of a file without
a header, or HDF5 dataset paths), ``--units`` (one spelling for all axes or one per axis), ``--zero``,
``--range``, ``--time-unit``, ``--rate``; or ``--columns MAP.toml``::

    [columns]
    time = "t"
    f_x = "acc_x"
    f_y = "acc_y"
    f_z = "acc_z"
    temperature = "temp"     # optional

    units = "counts:4096/g"  # or [units] f_x = "counts:4101/g" ... (top-level keys before [columns])
    zero = 32768
    range = "0:65535"
    time_unit = "s"

Options given on the command line take precedence over the file.  The result is a
:class:`stableins.data.rawlog.LogLayout`.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from stableins.data.rawlog import LOG_UNIT_SPELLINGS, OUTPUT_COLUMNS, LogLayout, parse_unit
from stableins.errors import InputError


def layout_from_options(
    columns: str | None,
    units: str | None,
    *,
    zero: str | None = None,
    full_scale: str | None = None,
    time_unit: str | None = None,
    rate: float | None = None,
) -> LogLayout:
    """Return the layout the command-line options (or a mapping TOML file given as ``columns``) state.

    ``columns``: ``time=t,f_x=acc_x,...`` or a TOML file with a ``[columns]`` table and optionally ``units``
    (one spelling or a table per axis), ``zero``, ``range``, ``time_unit``, ``rate``; options given on the command
    line take precedence.  ``units``: one spelling for all three axes or ``f_x=...,f_y=...,f_z=...``.
    ``zero``: one number or three comma-separated; ``full_scale``: ``LOW:HIGH`` (all axes) in the file's units.
    """
    document: dict[str, Any] = {}
    if columns is not None and columns.endswith(".toml"):
        document = _mapping_file(columns)
        mapping = {str(k): str(v) for k, v in document.get("columns", {}).items()}
    else:
        mapping = _pairs(columns or "", "--columns")
    unit_text: Any = units if units is not None else document.get("units")
    if unit_text is None:
        raise InputError("no unit given for the axes", field="--units", expected=LOG_UNIT_SPELLINGS)
    if isinstance(unit_text, Mapping):
        unit_map = {str(k): str(v) for k, v in unit_text.items()}
    elif "=" in str(unit_text):
        unit_map = _pairs(str(unit_text), "--units")
    else:
        unit_map = {a: str(unit_text) for a in OUTPUT_COLUMNS}
    parsed = {a: parse_unit(unit_map[a], field_name=f"--units {a}") for a in OUTPUT_COLUMNS if a in unit_map}
    unknown = set(unit_map) - set(OUTPUT_COLUMNS)
    if unknown:
        raise InputError(f"unknown axis {sorted(unknown)[0]!r}", field="--units", expected="f_x, f_y, f_z")
    zero_value: Any = zero if zero is not None else document.get("zero", 0.0)
    zeros = _three(zero_value, "--zero")
    range_value: Any = full_scale if full_scale is not None else document.get("range")
    ranges = None
    if range_value is not None:
        low, high = _range(range_value)
        ranges = ((low, high),) * 3
    return LogLayout(
        columns=mapping,
        units=parsed,
        zero=zeros,
        full_scale=ranges,
        time_unit=time_unit or str(document.get("time_unit", "s")),
        rate=rate if rate is not None else document.get("rate"),
    )


def _mapping_file(path: str) -> dict[str, Any]:
    import tomllib

    try:
        with open(path, "rb") as handle:
            document = tomllib.load(handle)
    except OSError as error:
        raise InputError(f"cannot read the mapping file: {error.strerror}", path=path, field="--columns") from None
    except tomllib.TOMLDecodeError as error:
        raise InputError(f"not TOML: {error}", path=path, field="--columns") from None
    if not isinstance(document.get("columns"), dict):
        raise InputError("no [columns] table", path=path, field="columns", expected="[columns] f_x = 'acc_x' ...")
    return document


def _pairs(text: str, option: str) -> dict[str, str]:
    out = {}
    for part in filter(None, (p.strip() for p in text.split(","))):
        key, sep, value = part.partition("=")
        if not sep or not key.strip() or not value.strip():
            raise InputError(f"{part!r} is not NAME=VALUE", field=option, expected="e.g. time=t,f_x=acc_x,f_y=acc_y,f_z=acc_z")
        out[key.strip()] = value.strip()
    return out


def _three(value: Any, option: str) -> tuple[float, float, float]:
    items = value if isinstance(value, list) else str(value).split(",")
    try:
        if any(isinstance(v, str) and (not v.isascii() or "_" in v) for v in items):  # float() reads 1_0 and full-width digits
            raise ValueError
        numbers = [float(v) for v in items]
    except (TypeError, ValueError):
        raise InputError(f"{value!r} is not a number or three", field=option, expected="e.g. 32768 or 32768,32768,32768") from None
    if len(numbers) == 1:
        numbers *= 3
    if len(numbers) != 3 or not all(np.isfinite(numbers)):
        raise InputError(f"{value!r}: one number or three", field=option, expected="e.g. 32768 or 32768,32768,32768")
    return (numbers[0], numbers[1], numbers[2])


def _range(value: Any) -> tuple[float, float]:
    items = value if isinstance(value, list) else str(value).split(":")
    try:
        low, high = (float(v) for v in items)
    except ValueError:
        raise InputError(
            f"{value!r} is not LOW:HIGH", field="--range", expected="the converter's range, e.g. 0:65535 or -32768:32767"
        ) from None
    if not low < high:
        raise InputError(f"{value!r}: LOW must be below HIGH", field="--range", expected="e.g. 0:65535")
    return low, high
