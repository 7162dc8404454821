r"""A continuous log of an accelerometer triad recorded by other means: any columns, any units.

A real inertial measurement unit logs its outputs in its own file layout: columns with its own
names, raw converter counts, outputs in g, or velocity increments (Δv pulses) with a pulse weight,
time in seconds or as timestamps.  :func:`read_raw_log` reads such a file (CSV, whitespace- or
comma-separated, with or without a header, or HDF5) given a :class:`LogLayout`, the user's
statement of what each column is, and returns the specific force in SI (:class:`RawLog`).

Units of an axis (:func:`parse_unit`)::

    m/s2                    the output is specific force in m/s²
    g                       in units of standard gravity, 9.80665 m/s² (conventions.STANDARD_GRAVITY)
    counts:S/g              raw converter counts, S counts per g:      f = (c − c0) g₀ / S
    counts:S/(m/s2)         raw converter counts, S counts per m/s²:   f = (c − c0) / S
    dv:W                    Δv pulses per sample, W m/s per pulse:      f = n W / Δt

``c0`` is the converter's zero (``zero``, in counts; 0 unless given, e.g. 32768 for an
offset-binary 16-bit converter).  A unit that is not one of these, or a bare ``counts:S`` (counts
per g or per m/s²?), is refused with the field named.

The converter's range (``full_scale``, in the file's units) is where clipping is read from: a
sample at or beyond either end is at the rail (:attr:`RawLog.railed`).  Without a declared range,
an HDF5 integer dataset's own dtype gives it (the format's full scale); a CSV file has none, and
no sample is taken as railed.  Clipping is never read from the shape of a histogram (issue 26).

The file is read in chunks of :data:`CHUNK_ROWS` lines and only the mapped columns are kept, so
memory grows with the samples kept (four or five float64 per sample), not with the file's width.
"""

from __future__ import annotations

import enum
import os
import re
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from stableins.conventions import STANDARD_GRAVITY
from stableins.errors import InputError

#: Lines parsed at once from a CSV file (bounded memory for the text being parsed).
CHUNK_ROWS = 200_000

#: The fields a layout maps: time, the three axes, an optional temperature.
FIELDS = ("time", "f_x", "f_y", "f_z", "temperature")
OUTPUT_COLUMNS = ("f_x", "f_y", "f_z")

#: The unit spellings :func:`parse_unit` accepts (named in its messages).
LOG_UNIT_SPELLINGS = "m/s2, g, counts:S/g, counts:S/(m/s2), dv:W (W in m/s per pulse)"

#: Time units of a numeric time column, in seconds (``samples``: a sample counter, at ``rate``).
TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9, "samples": float("nan")}


class UnitKind(enum.Enum):
    """What an axis column holds."""

    SPECIFIC_FORCE = "m/s2"
    GRAVITY = "g"
    COUNTS = "counts"
    PULSES = "dv"


@dataclass(frozen=True)
class AxisUnit:
    """The unit of one axis column.

    Attributes
    ----------
    kind : UnitKind
    scale : float
        SI per unit after the zero is removed: m/s² per count (``COUNTS``), m/s per pulse
        (``PULSES``), 9.80665 (``GRAVITY``) or 1 (``SPECIFIC_FORCE``).
    text : str
        The spelling it was given as.
    """

    kind: UnitKind
    scale: float
    text: str


def parse_unit(text: str, *, field_name: str = "--units", source: str | None = None) -> AxisUnit:
    """Return the unit ``text`` spells (:data:`LOG_UNIT_SPELLINGS`); :class:`InputError` naming ``field_name`` otherwise."""
    spelled = text.strip().replace(" ", "").replace("^", "").replace("²", "2")
    expected = LOG_UNIT_SPELLINGS
    if spelled in ("m/s2", "ms-2"):
        return AxisUnit(UnitKind.SPECIFIC_FORCE, 1.0, text)
    if spelled == "g":
        return AxisUnit(UnitKind.GRAVITY, STANDARD_GRAVITY, text)
    counts = re.fullmatch(r"counts:([^/]+)(?:/(.*))?", spelled)
    if counts:
        per = counts.group(2)
        value = _positive(counts.group(1), field_name, source, expected)
        if per is None:
            raise InputError(
                f"unit {text!r} is ambiguous: counts per g or per m/s^2?",
                path=source,
                field=field_name,
                expected=f"counts:{value:g}/g or counts:{value:g}/(m/s2)",
            )
        if per == "g":
            return AxisUnit(UnitKind.COUNTS, STANDARD_GRAVITY / value, text)
        if per in ("(m/s2)", "m/s2"):
            return AxisUnit(UnitKind.COUNTS, 1.0 / value, text)
        raise InputError(f"unknown unit {text!r}", path=source, field=field_name, expected=expected)
    pulses = re.fullmatch(r"dv:([^/]+?)(?:m/s)?", spelled)
    if pulses:
        return AxisUnit(UnitKind.PULSES, _positive(pulses.group(1), field_name, source, expected), text)
    raise InputError(f"unknown unit {text!r}", path=source, field=field_name, expected=expected)


def _positive(text: str, field_name: str, source: str | None, expected: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise InputError(f"{text!r} is not a number", path=source, field=field_name, expected=expected) from None
    if not (np.isfinite(value) and value > 0):
        raise InputError(f"{text!r} must be a positive finite number", path=source, field=field_name, expected=expected)
    return value


@dataclass(frozen=True)
class LogLayout:
    """What the columns of a log are (the user's statement: ``--columns``, ``--units`` ... or a mapping file).

    Attributes
    ----------
    columns : mapping
        ``{field: column}`` for the fields of :data:`FIELDS` (``f_x``, ``f_y``, ``f_z`` required; ``time``
        unless ``rate`` is given).  A column is a header name, a 1-based column number of a file
        without a header, or an HDF5 dataset path with an optional column index (``imu/acc:0``).
    units : mapping
        ``{axis: AxisUnit}`` for ``f_x``, ``f_y``, ``f_z``.
    zero : tuple of float
        The converter's zero per axis, in the file's units (counts; 0 unless given).
    full_scale : tuple of (float, float) or None
        The converter's range per axis in the file's units (lowest, highest), or None (declared by
        none; the HDF5 integer dtype's range is used then).
    time_unit : str
        ``s``, ``ms``, ``us``, ``ns`` (a numeric time column), ``samples`` (a sample counter, at ``rate``) or
        ``iso`` (ISO 8601 timestamps).
    rate : float or None
        Sample rate [Hz] of a sample counter, or when the log has no time column (time = row index / rate).
    """

    columns: Mapping[str, str]
    units: Mapping[str, AxisUnit]
    zero: tuple[float, float, float] = (0.0, 0.0, 0.0)
    full_scale: tuple[tuple[float, float], ...] | None = None
    time_unit: str = "s"
    rate: float | None = None

    def __post_init__(self) -> None:
        for name in self.columns:
            if name not in FIELDS:
                raise InputError(f"unknown field {name!r}", field="--columns", expected=", ".join(FIELDS))
        for axis in OUTPUT_COLUMNS:
            if axis not in self.columns:
                raise InputError(f"no column given for {axis}", field="--columns", expected=f"{axis}=COLUMN")
            if axis not in self.units:
                raise InputError(f"no unit given for {axis}", field="--units", expected=LOG_UNIT_SPELLINGS)
        if ("time" not in self.columns or self.time_unit == "samples") and self.rate is None:
            raise InputError(
                "no time in seconds and no sample rate", field="--rate", expected="time=COLUMN in s, ms, us, ns or iso, or --rate HZ"
            )
        if self.time_unit not in (*TIME_UNITS, "iso"):
            raise InputError(f"unknown time unit {self.time_unit!r}", field="--time-unit", expected="s, ms, us, ns, samples or iso")


@dataclass(frozen=True)
class RawLog:
    """A log read into SI: specific force per sample, time, and where the converter rails.

    Attributes
    ----------
    path : str
    time : ndarray (n,)
        Seconds since the first sample.
    specific_force : ndarray (n, 3)
        [m/s²].
    railed : ndarray (n,) of bool
        A sample at or beyond the converter's range on some axis (clipped).
    temperature : ndarray (n,) or None
    start_time : str
        ISO 8601 time of the first sample ("" when the log has no timestamps).
    resolution : ndarray (3,)
        One least significant bit in m/s² (the count's or pulse's size; 0 for outputs in m/s² or g).
    full_scale : tuple or None
        The range clipping was read from, per axis in the file's units, or None.
    range_source : str
        Where it comes from: ``declared``, ``HDF5 dtype``, or ``none``.
    layout : LogLayout
    """

    path: str
    time: NDArray[np.float64]
    specific_force: NDArray[np.float64]
    railed: NDArray[np.bool_]
    temperature: NDArray[np.float64] | None
    start_time: str
    resolution: NDArray[np.float64]
    full_scale: tuple[tuple[float, float], ...] | None
    range_source: str
    layout: LogLayout = field(repr=False)

    @property
    def rate(self) -> float:
        """Median sample rate [Hz]."""
        return float(1.0 / np.median(np.diff(self.time))) if self.time.size > 1 else float("nan")


def read_raw_log(path: str | os.PathLike[str], layout: LogLayout) -> RawLog:
    """Read a log (CSV or HDF5) and convert it to SI with ``layout``.

    Raises :class:`InputError` naming the file and field for a missing column, a non-numeric value,
    a clock that goes backwards (or repeats a time), or too few samples.
    """
    source = str(path)
    if not Path(path).is_file():
        raise InputError("no such file", path=source, expected="a CSV or HDF5 log")
    with open(path, "rb") as handle:
        is_hdf5 = handle.read(8) == b"\x89HDF\r\n\x1a\n"
    raw, dtype_range = _read_hdf5(source, layout) if is_hdf5 else (_read_csv(source, layout), None)
    full_scale = layout.full_scale if layout.full_scale is not None else dtype_range
    range_source = "declared" if layout.full_scale is not None else ("HDF5 dtype" if dtype_range is not None else "none")
    n = raw["f_x"].size
    if n < 2:
        raise InputError(f"only {n} samples", path=source, expected="a log of many samples")
    time, start = _time(raw, layout, source, n)
    counts = np.stack([raw[a] for a in OUTPUT_COLUMNS], axis=-1)
    railed = np.zeros(n, dtype=bool)
    if full_scale is not None:
        low = np.array([r[0] for r in full_scale])
        high = np.array([r[1] for r in full_scale])
        railed = np.any((counts <= low) | (counts >= high), axis=1)
    force = np.empty_like(counts)
    resolution = np.zeros(3)
    for i, axis in enumerate(OUTPUT_COLUMNS):
        unit = layout.units[axis]
        if unit.kind is UnitKind.PULSES:
            dt = np.diff(time)
            force[:, i] = np.r_[np.nan, counts[1:, i] * unit.scale / dt]
            resolution[i] = unit.scale / float(np.median(dt))
        else:
            force[:, i] = (counts[:, i] - layout.zero[i]) * unit.scale
            resolution[i] = unit.scale if unit.kind is UnitKind.COUNTS else 0.0
    if any(layout.units[a].kind is UnitKind.PULSES for a in OUTPUT_COLUMNS):  # the first sample has no interval
        time, force, railed = time[1:], force[1:], railed[1:]
        raw = {k: v[1:] for k, v in raw.items()}
    _check_specific_force(force, layout, source)
    temperature = raw.get("temperature")
    return RawLog(source, time - time[0], force, railed, temperature, start, resolution, full_scale, range_source, layout)


def _check_specific_force(force: NDArray[np.float64], layout: LogLayout, source: str) -> None:
    """Refuse a converted specific force beyond what any accelerometer can read (the data files' limits, docs/formats.md)."""
    from stableins.schema import column_limits

    limits = column_limits()
    for i, axis in enumerate(OUTPUT_COLUMNS):
        low, high = limits[axis]
        outside = ~((force[:, i] >= low) & (force[:, i] <= high))
        if np.any(outside):
            k = int(np.argmax(outside))
            raise InputError(
                f"sample {k + 1}: {force[k, i]:.6g} m/s^2 is beyond any accelerometer",
                path=source,
                field=axis,
                expected=f"a specific force in [{low:g}, {high:g}] m/s^2 once converted with --units and --zero",
            )


def _time(raw: Mapping[str, Any], layout: LogLayout, source: str, n: int) -> tuple[NDArray[np.float64], str]:
    """Return seconds from the first sample and the ISO start time; :class:`InputError` when the clock goes backwards."""
    if "time" not in raw:
        assert layout.rate is not None
        return np.arange(n) / layout.rate, ""
    column = layout.columns["time"]
    start = ""
    if layout.time_unit == "iso":
        try:
            stamps = np.array(raw["time"], dtype="datetime64[ns]")
        except ValueError as error:
            raise InputError(
                f"not an ISO 8601 timestamp: {error}", path=source, field=column, expected="e.g. 2024-05-01T12:00:00.125"
            ) from None
        start = str(stamps[0].astype("datetime64[us]"))
        time = (stamps - stamps[0]).astype(np.int64) * 1e-9
    else:
        scale = 1.0 / layout.rate if layout.time_unit == "samples" and layout.rate else TIME_UNITS[layout.time_unit]
        time = np.asarray(raw["time"], dtype=float) * scale
    steps = np.diff(time)
    bad = np.flatnonzero(~(steps > 0))
    if bad.size:
        row = int(bad[0]) + 2
        raise InputError(
            f"the clock goes backwards or stands still: {time[bad[0] + 1] - time[bad[0]]:+.6g} s from the row before",
            path=source,
            field=column,
            row=row,
            expected="strictly increasing times",
        )
    return time, start


def _csv_lines(path: str) -> Iterator[str]:
    """Yield the non-empty, non-comment lines of a text log (``.gz`` and ``.xz`` read compressed)."""
    import gzip
    import lzma

    opener: Any = {".gz": gzip.open, ".xz": lzma.open}.get(Path(path).suffix, open)
    with opener(path, "rt", encoding="utf-8", errors="replace") as handle:
        for line in handle:
            if line.strip() and not line.lstrip().startswith("#"):
                yield line


def _split(line: str, delimiter: str | None) -> list[str]:
    return [c.strip().strip('"') for c in (line.split(delimiter) if delimiter else line.split())]


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _read_csv(source: str, layout: LogLayout) -> dict[str, NDArray[Any]]:
    """Read the mapped columns of a delimited text file, :data:`CHUNK_ROWS` lines at a time."""
    lines = _csv_lines(source)
    first = next(lines, None)
    if first is None:
        raise InputError("the file is empty", path=source, expected="a CSV log")
    delimiter = next((d for d in (",", ";", "\t") if d in first), None)
    cells = _split(first, delimiter)
    header = not all(_is_number(c) for c in cells)
    names = cells if header else [str(i + 1) for i in range(len(cells))]
    index: dict[str, int] = {}
    for name, column in layout.columns.items():
        if column not in names:
            raise InputError(
                f"no column {column!r} for {name}",
                path=source,
                field=name,
                expected=f"one of {', '.join(names)}" if header else f"a column number 1 ... {len(names)} (the file has no header)",
            )
        index[name] = names.index(column)
    text_fields = {"time"} if layout.time_unit == "iso" else set()
    parts: dict[str, list[NDArray[Any]]] = {k: [] for k in index}
    row = 1 if header else 0
    pending = [] if header else [first]
    for line in lines:
        pending.append(line)
        if len(pending) >= CHUNK_ROWS:
            row = _parse_chunk(pending, delimiter, index, parts, text_fields=text_fields, source=source, row=row)
            pending = []
    if pending:
        _parse_chunk(pending, delimiter, index, parts, text_fields=text_fields, source=source, row=row)
    return {k: np.concatenate(v) if v else np.zeros(0) for k, v in parts.items()}


def _parse_chunk(
    lines: Sequence[str],
    delimiter: str | None,
    index: Mapping[str, int],
    parts: dict[str, list[NDArray[Any]]],
    *,
    text_fields: set[str],
    source: str,
    row: int,
) -> int:
    """Parse one chunk of lines into ``parts``; return the row count so far."""
    split = [_split(line, delimiter) for line in lines]
    for name, i in index.items():
        try:
            values = [cells[i] for cells in split]
        except IndexError:
            bad = next(k for k, cells in enumerate(split) if len(cells) <= i)
            raise InputError("the row has too few columns", path=source, field=name, row=row + bad + 1) from None
        if name in text_fields:
            parts[name].append(np.array(values))
            continue
        try:
            parts[name].append(np.array(values, dtype=float))
        except ValueError:
            bad = next(k for k, v in enumerate(values) if not _is_number(v))
            raise InputError(f"{values[bad]!r} is not a number", path=source, field=name, row=row + bad + 1) from None
    return row + len(lines)


def _read_hdf5(source: str, layout: LogLayout) -> tuple[dict[str, NDArray[Any]], tuple[tuple[float, float], ...] | None]:
    """Read the mapped datasets of an HDF5 file (``path`` or ``path:column``); the integer dtype's range when all axes share one."""
    import h5py

    out: dict[str, NDArray[Any]] = {}
    ranges: list[tuple[float, float] | None] = []
    with h5py.File(source, "r") as handle:
        for name, column in layout.columns.items():
            dataset_path, _, col = column.partition(":")
            if dataset_path not in handle or not isinstance(handle[dataset_path], h5py.Dataset):
                raise InputError(f"no dataset {dataset_path!r} for {name}", path=source, field=name, expected="an HDF5 dataset path")
            dataset = handle[dataset_path]
            data = dataset[:, int(col)] if col else dataset[()]
            if np.asarray(data).ndim != 1:
                raise InputError(f"dataset {dataset_path!r} is not one column", path=source, field=name, expected=f"{dataset_path}:COLUMN")
            if name in OUTPUT_COLUMNS:
                ranges.append(
                    (float(np.iinfo(dataset.dtype).min), float(np.iinfo(dataset.dtype).max)) if dataset.dtype.kind in "iu" else None
                )
            out[name] = np.asarray(data) if name == "time" and layout.time_unit == "iso" else np.asarray(data, dtype=float)
    if "time" in out and layout.time_unit == "iso" and out["time"].dtype.kind == "S":
        out["time"] = out["time"].astype(str)
    full = tuple(r for r in ranges if r is not None)
    return out, (full if len(full) == 3 else None)
