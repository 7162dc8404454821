"""What the system stage reads: a source of column chunks (the chunk-source protocol).

The system-level stage (:func:`stableins.estimators.system.stage.run_system_stage`) makes one pass over a record
that may be far larger than memory.  It reads it through a *chunk source*:

* required: ``iter_chunks(columns, rows, *, thin, step, reuse, unchecked)`` yielding ``{column: ndarray}`` chunks of
  at most ``rows`` rows, in order, every chunk holding every requested column (:class:`ChunkSource`);
* optional: ``path`` (named in messages; ``"<record>"`` without it), ``columns`` (the names the source has: the stage
  reads ``temperature`` only when it is among them) and a time grid, ``time_grid`` with ``grid_time(start, stop)``
  (:class:`GriddedChunkSource`): uniform stretches of the time column, so that the stage reads the time stamps at the
  attitude decimation only.

:class:`stableins.data.system.SystemRecord` (CSV and HDF5 files) and :class:`ArraySource` (in-memory columns) are
chunk sources; any object with the same methods is one (tests and benchmarks wrap sources to time or cut them).
"""

from __future__ import annotations

from collections.abc import Collection, Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from stableins.data.validation import check_finite
from stableins.errors import InputError
from stableins.schema import Columns

#: Rows per chunk when the caller does not say.
DEFAULT_ROWS = 1 << 16


@runtime_checkable
class ChunkSource(Protocol):
    """A record read in chunks of rows, in order, in bounded memory.

    ``iter_chunks`` yields dicts ``{column: ndarray}`` with every column of ``columns`` (all of the source's when
    None), at most ``rows`` rows each, consecutive and in order; a column that is not in the source raises
    :class:`~stableins.errors.InputError` naming it.
    """

    def iter_chunks(
        self,
        columns: Sequence[str] | None = None,
        rows: int = DEFAULT_ROWS,
        *,
        thin: Sequence[str] = (),
        step: int = 1,
        reuse: bool = False,
        unchecked: Sequence[str] = (),
    ) -> Iterator[Columns]:
        """Yield the record's chunks ``{column: ndarray}``, consecutive and in order (see the class docstring).

        Parameters
        ----------
        columns : sequence of str, optional
            Columns to read.
        rows : int
            Rows per chunk (the last chunk may be shorter).
        thin : sequence of str
            Columns wanted only at the rows whose index (0-based, from the first row of the record) is a multiple of
            ``step``: each chunk then holds them at those rows only.
        step : int
            The decimation of the ``thin`` columns.
        reuse : bool
            The source may reuse its buffers from chunk to chunk: the arrays are then valid only until the next chunk is
            requested (one-pass consumers).  A source may ignore it.
        unchecked : sequence of str
            Full-rate columns the caller checks for NaN/inf itself (naming the row).  A source may check them anyway; every
            other column must be checked (:func:`stableins.data.validation.check_finite`).
        """
        ...


@runtime_checkable
class GriddedChunkSource(ChunkSource, Protocol):
    """A chunk source whose time column is described by uniform segments (HDF5 ``/time_grid``, docs/formats.md).

    ``time_grid`` is ``None`` or an ``(n, 3)`` array of rows ``(first_row, first_time, period)``, one per uniformly
    sampled segment, in order; ``grid_time(start, stop)`` gives the time stamps of rows ``start:stop`` from it.
    """

    @property
    def time_grid(self) -> NDArray[np.float64] | None:
        """Uniform segments of the time column, or None."""
        ...

    def grid_time(self, start: int, stop: int) -> NDArray[np.float64]:
        """Time stamps of rows ``start:stop`` reconstructed from :attr:`time_grid`."""
        ...


def source_path(source: ChunkSource) -> str:
    """Return the name a source's messages use: its ``path``, ``"<record>"`` when it has none."""
    return str(getattr(source, "path", "<record>"))


def source_columns(source: ChunkSource) -> Collection[str]:
    """Return the columns a source says it has (empty when it does not say)."""
    columns: Collection[str] = getattr(source, "columns", ())
    return columns


def source_time_grid(source: ChunkSource) -> NDArray[np.float64] | None:
    """Return the source's time grid (:class:`GriddedChunkSource`), None when it has none."""
    grid: NDArray[np.float64] | None = getattr(source, "time_grid", None)
    return grid


@dataclass(frozen=True)
class ArraySource:
    """In-memory columns as a :class:`ChunkSource` (tests, small records).  Checks NaN/inf.

    Attributes
    ----------
    columns : mapping of str to ndarray
        The record's columns, equal lengths (``"temperature" in source.columns`` is how the stage asks).
    path : str
        What messages call the record.
    """

    columns: Mapping[str, NDArray[np.float64]]
    path: str = "<arrays>"

    def iter_chunks(
        self,
        columns: Sequence[str] | None = None,
        rows: int = DEFAULT_ROWS,
        *,
        thin: Sequence[str] = (),
        step: int = 1,
        reuse: bool = False,
        unchecked: Sequence[str] = (),
    ) -> Iterator[Columns]:
        """Yield chunks as :meth:`stableins.data.system.SystemRecord.iter_chunks` does (``reuse``, ``unchecked`` have no effect)."""
        names = list(self.columns if columns is None else columns)
        for name in names:
            if name not in self.columns:
                raise InputError("missing column", path=self.path, field=name, expected="the system-record columns")
        n = len(self.columns[names[0]])
        for start in range(0, n, rows):
            phase = (-start) % step
            chunk = {}
            for name in names:
                values = np.asarray(self.columns[name][start : start + rows], dtype=float)
                if name in thin:
                    values = values[phase::step]
                    check_finite(name, values, self.path, first_row=start + phase + 1, row_step=step)
                else:
                    check_finite(name, values, self.path, first_row=start + 1)
                chunk[name] = values
            yield chunk


__all__ = ["DEFAULT_ROWS", "ArraySource", "ChunkSource", "GriddedChunkSource", "source_columns", "source_path", "source_time_grid"]
