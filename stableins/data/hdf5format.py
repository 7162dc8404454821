"""HDF5 files for long records (see ``docs/formats.md``).

Layout::

    /                      attrs: format, schema_version, rows, complete, serial_number,
                                  header (JSON: format, schema_version, metadata with units)
    /columns/<name>        1-D chunked dataset per column, attrs: unit (physical columns), meaning
    /overview/<name>       optional, attrs (group): step.  Every ``step``-th row of each numeric column
                           (rows 0, step, 2·step, ...), written with the columns by the same writer, so
                           readers wanting slowly varying columns at a low rate read these few values
                           instead of touching every chunk of the full-rate column.
    /time_grid             optional, (n, 3) float64 rows (first_row, first_time, period), attrs: tolerance.
                           Segments of the time column: rows first_row .. (next first_row − 1) have
                           time = first_time + (row − first_row)·period within ``tolerance`` seconds.
                           Written by the writer from the values it writes (at most MAX_SEGMENTS; a time
                           column with more irregular steps gets none), so readers can reconstruct
                           uniformly sampled stretches instead of reading the column.

Written through a temporary file renamed on success (:mod:`stableins.data.atomic`), in
chunks, so a day-long record never has to be in memory and a crash never leaves a
half-written file under the final name.
"""

from __future__ import annotations

import contextlib
import json
import os
from collections.abc import Mapping, Sequence
from typing import Any

from stableins.data.validation import FORMAT_TAGS
from stableins.errors import InputError, NotDeterminedError
from stableins.schema import Column, Columns

GROUP = "columns"
OVERVIEW = "overview"
TIME_GRID = "time_grid"
#: /time_grid reproduces the time column within this fraction of the period.
TIME_GRID_TOLERANCE = 1e-6
STRING_DTYPE = "S16"
DEFAULT_CHUNK = 65536
#: A time column needing more segments than this gets no /time_grid (readers then read the column).
MAX_SEGMENTS = 4096
#: Values of an overview column read at a time (a window reused across chunks: few HDF5 calls).
OVERVIEW_WINDOW = 1 << 16


class H5Writer:
    """Streaming, atomic writer of one stableins HDF5 file.

    Rows appended with :meth:`append` are buffered up to ``chunk_samples`` and then
    written, so memory stays bounded whatever the record length.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        kind: str,
        schema: Sequence[Column],
        document: Mapping[str, Any],
        *,
        chunk_samples: int = DEFAULT_CHUNK,
        compression: str | None = None,
        overview_step: int = 0,
        time_period: float | None = None,
    ) -> None:
        self.path = str(path)
        self.kind = kind
        self.schema = tuple(schema)
        self.document = dict(document)
        self.chunk_samples = int(chunk_samples)
        self.compression = compression
        self.overview_step = int(overview_step) if overview_step and overview_step >= 2 else 0
        self.time_period = float(time_period) if time_period else None
        self._segments: list[tuple[int, float]] | None = [] if self.time_period else None
        self.rows = 0
        self._buffer: list[Mapping[str, Any]] = []
        self._buffered = 0
        self._file: Any = None
        self._atomic: Any = None

    def __enter__(self) -> H5Writer:
        import h5py

        from stableins.data.atomic import atomic_path

        self._atomic = atomic_path(self.path)
        tmp = self._atomic.__enter__()
        try:
            self._file = h5py.File(tmp, "w", rdcc_nbytes=0)  # whole-chunk writes: a chunk cache only copies
            f = self._file
            f.attrs["format"] = FORMAT_TAGS[self.kind]
            f.attrs["schema_version"] = self.document["schema_version"]
            f.attrs["header"] = json.dumps(self.document, allow_nan=False)
            serial = self.document.get("metadata", {}).get("serial_number")
            if serial is not None:
                f.attrs["serial_number"] = serial
            f.attrs["complete"] = False
            group = f.create_group(GROUP)
            self._datasets = {}
            for c in self.schema:
                dtype = STRING_DTYPE if c.dtype == "str" else c.dtype
                d = group.create_dataset(
                    c.name, shape=(0,), maxshape=(None,), dtype=dtype, chunks=(self.chunk_samples,), compression=self.compression
                )
                if c.unit is not None:
                    d.attrs["unit"] = c.unit
                d.attrs["meaning"] = c.meaning
                self._datasets[c.name] = d
            self._overview = {}
            if self.overview_step:
                view = f.create_group(OVERVIEW)
                view.attrs["step"] = self.overview_step
                for c in self.schema:
                    if c.dtype != "str":
                        self._overview[c.name] = view.create_dataset(
                            c.name,
                            shape=(0,),
                            maxshape=(None,),
                            dtype=c.dtype,
                            chunks=(max(1024, self.chunk_samples // self.overview_step),),
                        )
        except BaseException as error:
            self._abort(error)
            raise
        return self

    def append(self, chunk: Mapping[str, Any]) -> None:
        """Queue rows (dict of equal-length 1-D arrays, one per schema column).

        The writer copies what it keeps beyond this call, so the caller may reuse its arrays.
        """
        import numpy as np

        n = len(chunk[self.schema[0].name])
        self._buffered += n
        if self._buffered >= self.chunk_samples:
            self._buffer.append(chunk)
            self._flush()  # writes whole chunks now and copies the remainder
        else:
            self._buffer.append({c.name: np.array(chunk[c.name]) for c in self.schema})

    def _flush(self, *, final: bool = False) -> None:
        """Write the whole chunks buffered (everything if ``final``); keep the remainder.

        Writes then always cover whole HDF5 chunks, so no chunk is read back and rewritten.
        """
        import numpy as np

        if not self._buffer:
            return
        n = self._buffered if final else self._buffered - self._buffered % self.chunk_samples
        if n == 0:
            return
        rest: Columns = {}
        for c in self.schema:
            parts = [np.asarray(ch[c.name]) for ch in self._buffer]
            values = parts[0] if len(parts) == 1 else np.concatenate(parts)
            rest[c.name] = values[n:].copy()
            values = values[:n]
            if c.dtype == "str":
                values = np.char.encode(values.astype(str), "ascii")
            d = self._datasets[c.name]
            d.resize((self.rows + n,))
            d[self.rows :] = values
            if c.name == "time" and self._segments is not None:
                self._track_segments(np.asarray(values, dtype=float))
            view = self._overview.get(c.name)
            if view is not None:  # rows self.rows .. self.rows+n−1 that are multiples of the step
                picked = values[(-self.rows) % self.overview_step :: self.overview_step]
                if picked.size:
                    m = view.shape[0]
                    view.resize((m + picked.size,))
                    view[m:] = picked
        self.rows += n
        self._buffered -= n
        self._buffer[:] = [rest] if self._buffered else []

    def _track_segments(self, values: Any) -> None:
        """Extend the uniform segments of the time column by rows ``self.rows ..`` (values of this flush)."""
        import numpy as np

        period = self.time_period
        segments = self._segments
        if period is None:  # no time column to grid
            return
        tolerance = TIME_GRID_TOLERANCE * period
        position = 0
        while segments is not None and position < values.size:
            if not segments:
                segments.append((self.rows + position, float(values[position])))
            first_row, first_time = segments[-1]
            rows = self.rows + position + np.arange(values.size - position)
            off = np.abs(values[position:] - (first_time + (rows - first_row) * period)) > tolerance
            if not off.any():
                break
            position += int(np.argmax(off))
            segments.append((self.rows + position, float(values[position])))
            if len(segments) > MAX_SEGMENTS:
                segments = None
        self._segments = segments

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        if exc_type is not None:
            self._abort(exc)
            return
        try:
            self._flush(final=True)
            period = self.time_period
            if self._segments and period is not None:
                grid = self._file.create_dataset(TIME_GRID, data=[(row, time, period) for row, time in self._segments], dtype="f8")
                grid.attrs["tolerance"] = TIME_GRID_TOLERANCE * period
            self._file.attrs["rows"] = self.rows
            self._file.attrs["complete"] = True
            self._file.close()
            self._file = None
        except BaseException as error:
            self._abort(error)
            raise
        self._atomic.__exit__(None, None, None)

    def _abort(self, error: BaseException | None) -> None:
        if self._file is not None:
            with contextlib.suppress(Exception):  # already failing; the temporary file is removed below
                self._file.close()
            self._file = None
        if self._atomic is not None:
            err = error if error is not None else RuntimeError("aborted")
            try:
                self._atomic.__exit__(type(err), err, None)
            except BaseException as raised:  # atomic_path re-raises the error it was given
                if raised is not err:
                    raise
            self._atomic = None


#: Largest ``header`` attribute read [bytes].
MAX_HEADER_BYTES = 1 << 20


def open_h5(path: str | os.PathLike[str], *, chunk_cache: bool = True) -> Any:
    """Open an HDF5 file for reading; InputError naming the file when it is missing, a directory or not HDF5."""
    import h5py

    if os.path.isdir(path):
        raise InputError("is a directory", path=path, expected="an HDF5 file")
    try:
        return h5py.File(path, "r") if chunk_cache else h5py.File(path, "r", rdcc_nbytes=0)
    except FileNotFoundError:
        raise InputError("no such file", path=path) from None
    except OSError as error:
        raise InputError(f"cannot be read as HDF5 ({error}); the file is truncated or corrupt", path=path) from None


#: What h5py raises when the file's internal metadata (attributes, links, dataset headers) is damaged.
H5_DAMAGE = (KeyError, RuntimeError, OSError, ValueError, TypeError, UnicodeDecodeError)


def read_header_attribute(f: Any, path: Any) -> Any:
    """Return the JSON document of the root ``header`` attribute (safe JSON reader; InputError naming the file and field)."""
    from stableins.data.jsonio import parse_json

    try:
        header = f.attrs["header"]
    except KeyError:
        raise InputError("no 'header' attribute: not a stableins HDF5 file", path=path, field="header") from None
    except (InputError, NotDeterminedError):
        raise  # a described error passes through as it is (issue 29)
    except H5_DAMAGE as error:
        raise InputError(f"the 'header' attribute cannot be read ({error}); the file is corrupt", path=path, field="header") from None
    if not isinstance(header, str | bytes):
        raise InputError(
            f"the 'header' attribute is {type(header).__name__}, not text", path=path, field="header", expected="a JSON string"
        )
    return parse_json(header, path=path, field="header", max_bytes=MAX_HEADER_BYTES, what="the JSON header of docs/formats.md")
