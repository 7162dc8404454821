"""Device-level data sets: load, validate, save, split into dwells (see ``docs/formats.md``).

A device-level session is one table (columns :data:`~stableins.schema.DEVICE_COLUMNS`)
of samples taken while the platform dwells at commanded positions.  Consecutive rows
with the same ``(stage, pass, position)`` form one :class:`Dwell`.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import TYPE_CHECKING, Any

from stableins.data.metadata import metadata_from_document, metadata_to_document
from stableins.data.validation import check_finite, check_increasing
from stableins.documents import JSONObject
from stableins.errors import InputError
from stableins.schema import DEVICE_COLUMNS, SCHEMA_VERSION, Columns
from stableins.site import SiteMetadata

if TYPE_CHECKING:  # pragma: no cover
    import numpy as np
    from numpy.typing import NDArray

#: Stage names allowed in the ``stage`` column.
DEVICE_STAGES = ("coarse", "fine", "rotating")
CSV_SUFFIXES = (".csv",)
H5_SUFFIXES = (".h5", ".hdf5", ".hdf")


@dataclass(frozen=True)
class Dwell:
    """The samples of one dwell at one commanded position.

    Attributes
    ----------
    stage : str
        ``"coarse"`` or ``"fine"``.
    pass_number : int
        Pass (1, 2, ...).
    position : int
        Position number in the procedure.
    command : ndarray (3,)
        Commanded angle-sensor readings (platform, inner, middle) [rad].
    angles : ndarray (n, 3)
        Measured angle-sensor readings [rad].
    time_since_command : ndarray (n,)
        Time since the position was commanded [s].
    time : ndarray (n,)
        Session time [s].
    specific_force : ndarray (n, 3)
        Accelerometer outputs (f_x, f_y, f_z) [m/s²].
    temperature : ndarray (n,)
        Instrument temperature [°C].
    first_row : int
        1-based data row of the first sample in the source file.
    """

    stage: str
    pass_number: int
    position: int
    command: NDArray[np.float64]
    angles: NDArray[np.float64]
    time_since_command: NDArray[np.float64]
    time: NDArray[np.float64]
    specific_force: NDArray[np.float64]
    temperature: NDArray[np.float64]
    first_row: int = 1

    def __len__(self) -> int:
        return len(self.time)


@dataclass(frozen=True)
class DeviceDataset:
    """A validated device-level session.

    Attributes
    ----------
    metadata : SiteMetadata
        Site and unit.
    columns : mapping of str to ndarray
        One read-only array per column of :data:`DEVICE_COLUMNS` (SI).
    path : str or None
        File it was read from.
    """

    metadata: SiteMetadata
    columns: Mapping[str, Any]
    path: str | None = None
    _blocks: tuple[tuple[int, int], ...] = field(default=(), repr=False, compare=False)

    def __post_init__(self) -> None:
        columns = {c.name: _as_column(self.columns[c.name], c.dtype) for c in DEVICE_COLUMNS}
        for values in columns.values():
            values.setflags(write=False)
        object.__setattr__(self, "columns", MappingProxyType(columns))
        object.__setattr__(self, "_blocks", validate_device_columns(columns, self.path))

    def __len__(self) -> int:
        return len(self.columns["time"])

    def dwells(self, stage: str | None = None, pass_number: int | None = None) -> tuple[Dwell, ...]:
        """Dwells in file order, optionally only those of one stage and/or pass."""
        import numpy as np

        c = self.columns
        out = []
        for start, stop in self._blocks:
            s, p = str(c["stage"][start]), int(c["pass"][start])
            if (stage is not None and s != stage) or (pass_number is not None and p != pass_number):
                continue
            rows = slice(start, stop)
            out.append(
                Dwell(
                    stage=s,
                    pass_number=p,
                    position=int(c["position"][start]),
                    command=np.array([c["command_platform"][start], c["command_inner"][start], c["command_middle"][start]]),
                    angles=np.column_stack([c["angle_platform"][rows], c["angle_inner"][rows], c["angle_middle"][rows]]),
                    time_since_command=c["time_since_command"][rows],
                    time=c["time"][rows],
                    specific_force=np.column_stack([c["f_x"][rows], c["f_y"][rows], c["f_z"][rows]]),
                    temperature=c["temperature"][rows],
                    first_row=start + 1,
                )
            )
        return tuple(out)

    @property
    def stages(self) -> tuple[str, ...]:
        """Stages present, in order of appearance."""
        seen: dict[str, None] = {}
        for start, _ in self._blocks:
            seen[str(self.columns["stage"][start])] = None
        return tuple(seen)


def _as_column(values: Any, dtype: str) -> Any:
    import numpy as np

    array = np.asarray(values)
    if dtype == "str":
        return array.astype(str)
    return array.astype(dtype)


def check_device_rows(columns: Mapping[str, Any], path: str | None, first_row: int = 1, previous_time: float | None = None) -> None:
    """Check single rows (and the time order) of a device table, or of a piece of one starting at ``first_row``.

    Readers run them on each piece as it is read, so that a file that is wrong from its first rows on (a sparse or
    forged file declaring millions of rows) is refused before the rest is read.
    """
    import numpy as np

    n = len(columns["time"])
    for c in DEVICE_COLUMNS:
        if len(columns[c.name]) != n:
            raise InputError(f"column has {len(columns[c.name])} rows, 'time' has {n}", path=path, field=c.name, expected=f"{n} rows")
        check_finite(c.name, columns[c.name], path, first_row=first_row)
    stage = columns["stage"]
    bad = ~np.isin(stage, DEVICE_STAGES)
    if bad.any():
        k = int(np.argmax(bad))
        raise InputError(
            f"unknown stage {str(stage[k])[:40]!r}", path=path, row=first_row + k, field="stage", expected="'coarse', 'fine' or 'rotating'"
        )
    for name in ("pass", "position"):
        bad = columns[name] < 1
        if bad.any():
            k = int(np.argmax(bad))
            raise InputError(
                f"{name} {columns[name][k]} is not positive", path=path, row=first_row + k, field=name, expected="an integer ≥ 1"
            )
    check_increasing(columns["time"], path, first_row=first_row, previous=previous_time)
    bad = columns["time_since_command"] < 0
    if bad.any():
        k = int(np.argmax(bad))
        raise InputError("negative time since command", path=path, row=first_row + k, field="time_since_command", expected="a value ≥ 0 s")


def validate_device_columns(columns: Mapping[str, Any], path: str | None) -> tuple[tuple[int, int], ...]:
    """Check the content of a device table; return its ``(start, stop)`` dwell blocks.

    Raises
    ------
    InputError
        On unequal column lengths, NaN/inf, unknown stage, non-positive pass/position,
        non-increasing time, a command that changes within a dwell, or a
        ``(stage, pass, position)`` that occurs in two separate blocks.
    """
    import numpy as np

    n = len(columns["time"])
    if n == 0:
        raise InputError("the file holds no data rows", path=path, expected="the samples of at least one dwell")
    check_device_rows(columns, path)
    stage = columns["stage"]
    change = np.zeros(n, dtype=bool)
    change[0] = True
    for name in ("stage", "pass", "position"):
        change[1:] |= columns[name][1:] != columns[name][:-1]
    starts = np.flatnonzero(change)
    stops = np.append(starts[1:], n)
    seen: dict[tuple[str, int, int], int] = {}
    for start, stop in zip(starts.tolist(), stops.tolist()):
        key = (str(stage[start]), int(columns["pass"][start]), int(columns["position"][start]))
        if key in seen:
            raise InputError(
                f"stage {key[0]} pass {key[1]} position {key[2]} occurs again (first block starts at row {seen[key]}); "
                "a position is dwelt at once per pass",
                path=path,
                row=start + 1,
                field="position",
                expected="each (stage, pass, position) in one contiguous block",
            )
        seen[key] = start + 1
        for name in ("command_platform", "command_inner", "command_middle"):
            values = columns[name][start:stop]
            moved = values != values[0]
            if moved.any():
                k = start + int(np.argmax(moved))
                raise InputError(
                    f"command changes within the dwell of stage {key[0]} pass {key[1]} position {key[2]}",
                    path=path,
                    row=k + 1,
                    field=name,
                    expected="one command per dwell",
                )
    return tuple(zip(starts.tolist(), stops.tolist()))


def _kind_of(path: Path) -> str:
    suffix = path.suffix.lower()
    if suffix in CSV_SUFFIXES:
        return "csv"
    if suffix in H5_SUFFIXES:
        return "h5"
    raise InputError(f"unknown file type {suffix!r}", path=path, expected="a .csv or .h5 file")


def header_document(kind: str, metadata: SiteMetadata) -> JSONObject:
    """Return the JSON header of a device file of ``kind`` (format tag, schema version, site metadata)."""
    from stableins.data.validation import FORMAT_TAGS

    return {"format": FORMAT_TAGS[kind], "schema_version": SCHEMA_VERSION, "end_marker": True, "metadata": metadata_to_document(metadata)}


def load_device(path: str | os.PathLike[str]) -> DeviceDataset:
    """Read and validate a device-level session (``.csv`` or ``.h5``, by suffix).

    Raises
    ------
    InputError
        For every problem listed in ``docs/formats.md`` (file, row/field, expectation).
    """
    path = Path(path)
    kind = _kind_of(path)
    if kind == "csv":
        from stableins.data.csvformat import CsvReader

        with CsvReader(path, "device", DEVICE_COLUMNS) as reader:
            document = reader.document
            columns = reader.read_all()
    else:
        from stableins.data.hdf5reader import H5Reader

        reader_h5 = H5Reader(path, "device", DEVICE_COLUMNS)
        document = reader_h5.document
        columns = _read_h5_checked(reader_h5, str(path))
    if "metadata" not in document:
        raise InputError("header has no metadata", path=path, field="metadata", expected="site metadata (docs/formats.md)")
    metadata = metadata_from_document(document["metadata"], str(path))
    return DeviceDataset(metadata, columns, str(path))


def _read_h5_checked(reader: Any, path: str) -> Columns:
    """All rows of a device HDF5 file, each piece checked as it is read (memory grows only with rows that pass)."""
    import numpy as np

    parts: list[Columns] = []
    first, previous = 1, None
    for chunk in reader.iter_chunks():
        check_device_rows(chunk, path, first_row=first, previous_time=previous)
        parts.append(chunk)
        first += len(chunk["time"])
        previous = float(chunk["time"][-1]) if len(chunk["time"]) else previous
    if not parts:
        return reader.read()
    return {c.name: np.concatenate([p[c.name] for p in parts]) for c in DEVICE_COLUMNS}


def save_device(path: str | os.PathLike[str], columns: Mapping[str, Any], metadata: SiteMetadata) -> Path:
    """Validate and write a device-level session atomically (``.csv`` or ``.h5``, by suffix)."""
    path = Path(path)
    kind = _kind_of(path)
    dataset = DeviceDataset(metadata, columns, None)  # validates before anything is written
    document = header_document("device", metadata)
    data = dict(dataset.columns)
    if kind == "csv":
        from stableins.data.csvformat import write_csv

        write_csv(path, "device", DEVICE_COLUMNS, document, [data])
    else:
        from stableins.data.hdf5format import H5Writer

        with H5Writer(path, "device", DEVICE_COLUMNS, document, chunk_samples=max(1, min(len(dataset), 65536))) as writer:
            writer.append(data)
    return path
