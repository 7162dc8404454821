"""System-level records: streaming writer, bounded-memory reader, sampling verdicts (checks in :mod:`~stableins.data.sampling`).

A system-level record (columns :data:`~stableins.schema.SYSTEM_COLUMNS`) is hours to
days of samples at the INS rate: 8.6 million rows per day at 100 Hz.  It is written and
read in chunks, never held in memory whole.  HDF5 (``.h5``) is the format for real
records; CSV (``.csv``) is accepted for small ones.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from stableins.data.device import CSV_SUFFIXES, H5_SUFFIXES, header_document
from stableins.data.hdf5format import DEFAULT_CHUNK
from stableins.data.metadata import metadata_from_document
from stableins.data.sampling import SamplingChecker, SamplingReport, SamplingWarning
from stableins.data.validation import check_finite, check_increasing
from stableins.errors import InputError
from stableins.schema import SYSTEM_COLUMNS, Columns
from stableins.site import SiteMetadata

if TYPE_CHECKING:  # pragma: no cover
    from numpy.typing import NDArray

#: HDF5 system records carry an ``/overview`` of every column at this period [s] (one row per second): the system
#: stage reads attitude, velocity and gimbal angles at 1 Hz from it (docs/formats.md).
OVERVIEW_SECONDS = 1.0
NAMES = tuple(c.name for c in SYSTEM_COLUMNS)


def _kind_of(path: Path) -> str:
    suffix = path.suffix.lower()
    if suffix in H5_SUFFIXES:
        return "h5"
    if suffix in CSV_SUFFIXES:
        return "csv"
    raise InputError(f"unknown file type {suffix!r}", path=path, expected="a .h5 (or, for small records, .csv) file")


class SystemRecordWriter:
    """Write a system-level record chunk by chunk, atomically.

    Use as a context manager; :meth:`append` takes a dict with one equal-length 1-D array
    per column of :data:`SYSTEM_COLUMNS` [SI].  The data go to a temporary file beside
    ``path`` that is renamed to ``path`` only when the ``with`` block ends without an
    exception; otherwise it is deleted and an existing ``path`` is left untouched.

    Each chunk is checked (all columns present, equal lengths, finite, time strictly
    increasing across chunks) before it is written.

    Parameters
    ----------
    path : path-like
        ``.h5`` (chunked HDF5) or ``.csv``.
    metadata : SiteMetadata
        Site and unit; ``sample_rate`` is the record's nominal rate.
    chunk_samples : int
        HDF5 chunk length and write-buffer size [samples].
    compression : str, optional
        HDF5 filter (``"gzip"``, ``"lzf"``); none by default (noisy float64 barely compresses).

    Examples
    --------
    >>> with SystemRecordWriter("day.h5", metadata) as writer:   # doctest: +SKIP
    ...     for chunk in system_record_chunks(truth, 86400.0, 100.0, seed=1):
    ...         writer.append(chunk)
    """

    def __init__(
        self, path: str | os.PathLike[str], metadata: SiteMetadata, chunk_samples: int = DEFAULT_CHUNK, compression: str | None = None
    ) -> None:
        self.path = Path(path)
        self.metadata = metadata
        self.kind = _kind_of(self.path)
        self.chunk_samples = int(chunk_samples)
        self.compression = compression
        self.n_samples = 0
        self._last_time: float | None = None
        self._inner: Any = None
        self._rows_written = 0

    def __enter__(self) -> SystemRecordWriter:
        document = header_document("system", self.metadata)
        if self.kind == "h5":
            from stableins.data.hdf5format import H5Writer

            step = int(round(self.metadata.sample_rate * OVERVIEW_SECONDS)) if self.metadata.sample_rate else 0
            period = 1.0 / self.metadata.sample_rate if self.metadata.sample_rate else None
            self._inner = H5Writer(
                self.path,
                "system",
                SYSTEM_COLUMNS,
                document,
                chunk_samples=self.chunk_samples,
                compression=self.compression,
                overview_step=step,
                time_period=period,
            )
            self._inner.__enter__()
        else:
            from stableins.data.atomic import atomic_write
            from stableins.data.csvformat import header_text

            self._atomic = atomic_write(self.path)
            self._handle = self._atomic.__enter__()
            self._handle.write(header_text("system", document, SYSTEM_COLUMNS))
        return self

    def append(self, chunk: Mapping[str, Any]) -> None:
        """Check and write one chunk of rows."""
        import numpy as np

        where = f"chunk starting at sample {self.n_samples + 1}"
        missing = [n for n in NAMES if n not in chunk]
        if missing:
            raise InputError(f"{where} has no column {missing[0]!r}", path=self.path, field=missing[0], expected="every system column")
        extra = [n for n in chunk if n not in NAMES]
        if extra:
            raise InputError(f"{where} has an unknown column {extra[0]!r}", path=self.path, field=extra[0], expected="system columns only")
        arrays = {n: np.asarray(chunk[n], dtype=float) for n in NAMES}  # the writers copy what they keep
        n = len(arrays["time"])
        for name, values in arrays.items():
            if values.shape != (n,):
                raise InputError(f"{where}: shape {values.shape}", path=self.path, field=name, expected=f"shape ({n},) like 'time'")
            check_finite(name, values, self.path, first_row=self.n_samples + 1)
        check_increasing(arrays["time"], self.path, first_row=self.n_samples + 1, previous=self._last_time)
        if n == 0:
            return
        if self.kind == "h5":
            self._inner.append(arrays)
        else:
            from stableins.data.csvformat import format_rows

            self._handle.write(format_rows(arrays, SYSTEM_COLUMNS))
        self.n_samples += n
        self._last_time = float(arrays["time"][-1])

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        if self.kind == "h5":
            self._inner.__exit__(exc_type, exc, tb)
            return
        if exc_type is None:
            from stableins.data.csvformat import trailer_text

            self._handle.write(trailer_text(self.n_samples))
        self._atomic.__exit__(exc_type, exc, tb)


@dataclass(frozen=True)
class RecordValidation:
    """Result of :meth:`SystemRecord.validate`: the time base, and the derived datasets found consistent.

    Attributes
    ----------
    sampling : SamplingReport
    overview_step : int
        Step of the ``/overview`` datasets (0: none).
    time_grid_segments : int
        Segments of ``/time_grid`` (0: none).
    """

    sampling: SamplingReport
    overview_step: int = 0
    time_grid_segments: int = 0


@dataclass(frozen=True)
class SystemRecord:
    """An opened (validated) system-level record; reads happen chunk by chunk.

    Attributes
    ----------
    path : str
        The file.
    metadata : SiteMetadata
        Site and unit.
    n_samples : int
        Number of rows.
    """

    path: str
    metadata: SiteMetadata
    n_samples: int
    _reader: Any = field(repr=False, compare=False)

    @property
    def sample_rate(self) -> float:
        """Nominal sample rate [Hz] (from the metadata)."""
        return self.metadata.sample_rate

    @property
    def columns(self) -> tuple[str, ...]:
        """Column names of a system record, in file order."""
        return NAMES

    @property
    def duration(self) -> float:
        """Nominal duration n / rate [s]."""
        return self.n_samples / self.sample_rate

    def iter_chunks(
        self,
        columns: Sequence[str] | None = None,
        rows: int = DEFAULT_CHUNK,
        *,
        thin: Sequence[str] = (),
        step: int = 1,
        reuse: bool = False,
        unchecked: Sequence[str] = (),
    ) -> Iterator[Columns]:
        """Yield dicts ``{column: ndarray}`` of up to ``rows`` rows, in order, each checked for NaN/inf.

        Memory is bounded by ``rows`` × number of columns, whatever the record length.

        Parameters
        ----------
        columns : sequence of str, optional
            Columns to read (all by default).
        rows : int
            Rows per chunk.
        thin : sequence of str
            Columns of ``columns`` wanted only at the rows whose index (0-based, from the first row
            of the record) is a multiple of ``step`` (slowly varying outputs: attitude, velocity,
            gimbal angles).  HDF5: gathered without reading the rows in between.
        reuse : bool
            HDF5: read the other columns into buffers reused from chunk to chunk; the arrays are
            valid only until the next chunk is requested (for one-pass consumers).
        unchecked : sequence of str
            HDF5 with ``reuse``: full-rate columns the caller checks for NaN/inf in its own pass (naming the row).
        """
        names = list(NAMES if columns is None else columns)
        unknown = [n for n in names if n not in NAMES]
        if unknown:
            raise InputError(f"unknown column {unknown[0]!r}", path=self.path, field=unknown[0], expected="one of " + ", ".join(NAMES))
        if self._reader is None:  # CSV: parse again, streaming
            from stableins.data.csvformat import CsvReader

            with CsvReader(self.path, "system", SYSTEM_COLUMNS) as reader:
                first = 1
                for chunk in reader.iter_chunks(rows):
                    for n in names:
                        check_finite(n, chunk[n], self.path, first_row=first)
                    phase = (-(first - 1)) % step
                    first += len(chunk["time"])
                    yield {n: chunk[n][phase::step] if n in thin else chunk[n] for n in names}
        else:
            yield from self._reader.iter_chunks(names, rows, thin=thin, step=step, reuse=reuse, unchecked=unchecked)

    def read(self, columns: Sequence[str] | None = None) -> Columns:
        """Whole columns at once (for short records or a few columns)."""
        import numpy as np

        chunks = list(self.iter_chunks(columns, rows=1 << 20))
        names = list(NAMES if columns is None else columns)
        if not chunks:
            return {n: np.zeros(0) for n in names}
        return {n: np.concatenate([c[n] for c in chunks]) for n in names}

    def verify_derived(self) -> tuple[int, int]:
        """HDF5: check ``/overview`` and ``/time_grid`` against the columns in one pass; returns (overview step, grid segments).

        Zeros for what the file does not have (and for CSV).
        """
        return (0, 0) if self._reader is None else self._reader.verify_derived()

    @property
    def time_grid(self) -> Any:
        """HDF5: the uniform segments of the time column, ``(n, 3)`` rows (first_row, first_time, period), or None."""
        return None if self._reader is None else self._reader.time_grid

    def grid_time(self, start: int, stop: int) -> Any:
        """Time of rows ``start:stop`` from :attr:`time_grid` (which must exist)."""
        return self._reader.grid_time(start, stop)

    def validate(self, *, allow_gaps: bool = False, tolerance: float = 0.01, rows: int = 1 << 18) -> RecordValidation:
        """Validate the record: the one validation of a system-level record.

        Every command that reads one (``check``, ``calibrate system``, ``diagnose``) runs it, so that they never disagree
        about a file.

        One streaming pass (bounded memory) over every column: every value finite, the time strictly increasing and
        sampled at ``metadata.sample_rate`` (:meth:`check_sampling`'s rules: a gap is an error unless ``allow_gaps``, a
        mean rate off the metadata by more than 1 % is an error, jitter is a :class:`SamplingWarning`), and the derived
        datasets of an HDF5 file (``/overview``, ``/time_grid``) equal to the columns they were derived from.

        Raises
        ------
        InputError
            The first problem, naming the row and the column (or dataset).
        """
        checker = SamplingChecker(self.sample_rate, self.path, tolerance=tolerance)
        for chunk in self._verified_chunks(rows):
            checker.update(chunk["time"])
        return self._validation(checker, allow_gaps=allow_gaps)

    def validating(self, *, allow_gaps: bool = False, tolerance: float = 0.01) -> ValidatingRecord:
        """Return this record as a chunk source that runs :meth:`validate` while it is read (one pass, not two).

        A stage that reads the record once (``calibrate system``) reads it through this source: every chunk is
        validated before it is handed on, and the time-base verdict is given after the last chunk (before the stage
        finishes its pass), so the first problem raises :class:`InputError` naming its row and column as
        :meth:`validate` would, and nothing has been written yet.
        """
        return ValidatingRecord(self, allow_gaps=allow_gaps, tolerance=tolerance)

    def _verified_chunks(self, rows: int) -> Iterator[dict[str, NDArray[Any]]]:
        """Every column, chunk by chunk, each value and (HDF5) the derived datasets checked (:meth:`validate`'s reading)."""
        if self._reader is None:
            return self.iter_chunks(rows=rows)
        return self._reader.iter_verified(rows)

    def _validation(self, checker: SamplingChecker, *, allow_gaps: bool) -> RecordValidation:
        """Return the verdict of a validating pass whose time column ``checker`` has seen (raises on the first problem)."""
        report = self._sampling_verdict(checker.finish(), allow_gaps=allow_gaps)
        grid = None if self._reader is None else self._reader.time_grid
        step, segments = (0 if self._reader is None else self._reader.overview_step), (0 if grid is None else len(grid))
        return RecordValidation(report, step, segments)

    def check_sampling(self, *, allow_gaps: bool = False, tolerance: float = 0.01, rows: int = DEFAULT_CHUNK) -> SamplingReport:
        """Check the time column against the metadata rate (streaming).

        Raises
        ------
        InputError
            Non-increasing time (row named); a gap unless ``allow_gaps``; a mean rate
            that disagrees with the metadata sample rate by more than 1 %.

        Warns
        -----
        SamplingWarning
            Jitter (steps off 1/rate by more than ``tolerance``), and gaps when allowed.
        """
        checker = SamplingChecker(self.sample_rate, self.path, tolerance=tolerance)
        for chunk in self.iter_chunks(["time"], rows=rows):
            checker.update(chunk["time"])
        return self._sampling_verdict(checker.finish(), allow_gaps=allow_gaps)

    def _sampling_verdict(self, report: SamplingReport, *, allow_gaps: bool) -> SamplingReport:
        """Errors and warnings of a time base (docs/formats.md, "Sampling checks")."""
        steps = report.n_samples - 1
        if steps >= 2 and report.n_gaps > steps / 2:
            raise InputError(
                f"{report.n_gaps} of the {steps} time steps are longer than 1.5 periods of metadata.sample_rate "
                f"(mean rate of the stamps {report.mean_rate:.6g} Hz): the sample rate is wrong, not the record gapped",
                path=self.path,
                field="time",
                expected=f"time stamps consistent with metadata.sample_rate = {self.sample_rate:g} Hz",
            )
        if report.gaps and not allow_gaps:
            g = report.gaps[0]
            raise InputError(
                f"gap in the record: time step {g.step:.6g} s ({len(report.gaps)} gap(s) in all)",
                path=self.path,
                row=g.row,
                field="time",
                expected=f"uniform sampling at {self.sample_rate:g} Hz (step {g.expected:.6g} s), or --allow-gaps",
            )
        if report.n_samples > 1 and abs(report.mean_rate / self.sample_rate - 1.0) > 0.01 and not report.gaps:
            raise InputError(
                f"time stamps give {report.mean_rate:.6g} Hz but the metadata say {self.sample_rate:g} Hz",
                path=self.path,
                field="time",
                expected="time stamps consistent with metadata.sample_rate",
            )
        issues = report.gaps + report.jitter
        if issues:
            text = "; ".join(i.describe(self.path) for i in issues[:3])
            more = f" (and {len(report.gaps) + report.n_jitter - 3} more)" if len(report.gaps) + report.n_jitter > 3 else ""
            warnings.warn(SamplingWarning(f"irregular sampling: {text}{more}", self.path, issues), stacklevel=3)
        return report


class ValidatingRecord:
    """A system record as a chunk source (:class:`stableins.data.chunks.ChunkSource`) that validates what it reads.

    Made by :meth:`SystemRecord.validating`.  :meth:`iter_chunks` reads every column of every row once, checks them as
    :meth:`SystemRecord.validate` does (finite values, time increasing, ``/overview`` and ``/time_grid`` equal to the
    columns), hands on the columns asked for (the ``thin`` ones at every ``step``-th row of the record, copied), and
    after the last chunk gives the time-base verdict (:attr:`validation`): a gap, a wrong rate raise
    :class:`InputError`, jitter warns.  Everything else (``path``, ``metadata``, ``columns``, the time grid) is the
    record's.
    """

    def __init__(self, record: SystemRecord, *, allow_gaps: bool, tolerance: float) -> None:
        self.record = record
        self.allow_gaps = allow_gaps
        self.tolerance = tolerance
        self.validation: RecordValidation | None = None

    def __getattr__(self, name: str) -> Any:
        return getattr(self.record, name)

    def iter_chunks(
        self,
        columns: Sequence[str] | None = None,
        rows: int = DEFAULT_CHUNK,
        *,
        thin: Sequence[str] = (),
        step: int = 1,
        reuse: bool = False,
        unchecked: Sequence[str] = (),
    ) -> Iterator[Columns]:
        """Yield ``{column: ndarray}`` chunks of ``rows`` rows as :meth:`SystemRecord.iter_chunks` does, validating all.

        The full-rate arrays are the reader's buffers (valid until the next chunk is asked for, as with ``reuse``);
        every value is checked, ``unchecked`` included.
        """
        import numpy as np

        record = self.record
        names = list(NAMES if columns is None else columns)
        unknown = [n for n in names if n not in NAMES]
        if unknown:
            raise InputError(f"unknown column {unknown[0]!r}", path=record.path, field=unknown[0], expected="one of " + ", ".join(NAMES))
        thin_set = set(thin)
        checker = SamplingChecker(record.sample_rate, record.path, tolerance=self.tolerance)
        first = 0
        for chunk in record._verified_chunks(rows):
            checker.update(chunk["time"])
            phase = (-first) % step
            first += len(chunk["time"])
            yield {n: np.array(chunk[n][phase::step]) if n in thin_set else chunk[n] for n in names}
        self.validation = record._validation(checker, allow_gaps=self.allow_gaps)


def open_system_record(path: str | os.PathLike[str]) -> SystemRecord:
    """Open and validate a system-level record (``.h5`` or ``.csv``, by suffix).

    The structure (header, schema version, metadata, columns and units, lengths) is
    checked now; values are checked for NaN/inf as chunks are read, and the time base
    by :meth:`SystemRecord.check_sampling`.
    """
    path = Path(path)
    kind = _kind_of(path)
    if kind == "h5":
        from stableins.data.hdf5reader import H5Reader

        reader = H5Reader(path, "system", SYSTEM_COLUMNS)
        document, n, inner = reader.document, reader.rows, reader
    else:
        from stableins.data.csvformat import CsvReader

        with CsvReader(path, "system", SYSTEM_COLUMNS) as csv_reader:
            document = csv_reader.document
            n = 0
            for chunk in csv_reader.iter_chunks(DEFAULT_CHUNK):  # validates every row, bounded memory
                n += len(chunk["time"])
        inner = None
    if "metadata" not in document:
        raise InputError("header has no metadata", path=path, field="metadata", expected="site metadata (docs/formats.md)")
    metadata = metadata_from_document(document["metadata"], str(path))
    return SystemRecord(str(path), metadata, n, inner)
