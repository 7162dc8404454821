"""The :class:`HistoryStore`: filing records, reading them verified, and the questions asked of a unit's history."""

from __future__ import annotations

import contextlib
import hashlib
import math
import os
import shlex
import sqlite3
import tempfile
from collections.abc import Iterable, Iterator
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import TYPE_CHECKING, Any

from stableins.data.atomic import fsync_directory
from stableins.errors import InputError
from stableins.history import DEFAULT_MAX_AGE, Comparison, Trend, compare, data_only, trend
from stableins.history_store.filing import (
    Filing,
    check_serial,
    checked_digest,
    insert_entry,
    read_filing,
    stage_file,
    verified_bytes,
)
from stableins.history_store.legacy import legacy_units, migrate
from stableins.history_store.postgres import PostgresConnection, is_url, redacted
from stableins.history_store.queries import DRIFT_SIGMAS, UnitStatus, fleet_status
from stableins.history_store.schema import (
    BUSY_TIMEOUT,
    ENTRY_COLUMNS,
    STORE_FORMAT,
    STORE_NAME,
    Connection,
    HistoryEntry,
    default_store,
    entry_from_row,
    find_entry,
    prepare,
    transaction,
)
from stableins.status import Status

if TYPE_CHECKING:  # pragma: no cover
    from stableins.records import CalibrationRecord


class HistoryStore:
    """Per-serial store of calibration records indexed in SQLite, or in PostgreSQL (:mod:`stableins.history_store`).

    Parameters
    ----------
    root : path or str, optional
        The store's directory (SQLite), or a ``postgresql://`` URL (:mod:`stableins.history_store.postgres`);
        default :func:`default_store`.

    Attributes
    ----------
    location : str
        What messages name the store by: its directory, or its URL without the password.
    url : str or None
        The PostgreSQL URL (None for SQLite).
    root : Path
        The store's directory; for PostgreSQL, the local folder where :meth:`record_path` puts verified copies.
    """

    def __init__(self, root: str | os.PathLike[str] | None = None) -> None:
        location = root if root is not None else default_store()
        self.url: str | None = str(location) if is_url(location) else None
        if self.url is not None:
            key = hashlib.sha256(self.url.encode()).hexdigest()[:16]
            self.root = Path(tempfile.gettempdir()) / f"stableins-history-{os.getuid()}" / key
            self.location = redacted(self.url)
        else:
            self.root = Path(location)
            self.location = str(self.root)
        self.index_path: Path | str = self.location if self.url is not None else self.root / STORE_NAME

    def __repr__(self) -> str:
        return f"HistoryStore({self.location!r})"

    # ------------------------------------------------------------------ database
    @contextlib.contextmanager
    def _database(self, *, create: bool) -> Iterator[Connection | None]:
        """Yield a connection (None when the store does not exist and ``create`` is false); migrate old stores first."""
        if self.url is not None:
            with self._postgres(create=create) as connection:
                yield connection
            return
        if self.root.exists() and not self.root.is_dir():
            raise InputError("is a file, not a directory", path=self.root, field="root", expected="a history store directory")
        if not (self.root / STORE_NAME).exists():
            if not create and not legacy_units(self.root):
                yield None
                return
            try:
                self.root.mkdir(parents=True, exist_ok=True)
            except OSError as error:
                raise InputError(f"cannot create the history store ({error.strerror})", path=self.root, field="root") from None
        try:
            connection = sqlite3.connect(self.root / STORE_NAME, timeout=BUSY_TIMEOUT, isolation_level=None)
        except sqlite3.Error as error:
            raise InputError(f"cannot open the history index ({error})", path=self.index_path) from None
        try:
            prepare(connection, self.index_path)
            migrate(connection, self.root)
            yield connection
        except sqlite3.DatabaseError as error:
            raise InputError(
                f"the history index cannot be used ({error}); it is damaged or not a stableins history index",
                path=self.index_path,
                expected=f"a {STORE_FORMAT} SQLite database",
            ) from None
        finally:
            connection.close()

    @contextlib.contextmanager
    def _postgres(self, *, create: bool) -> Iterator[Connection | None]:
        """Yield a connection to the PostgreSQL store (None when it has no schema yet and ``create`` is false)."""
        import psycopg

        assert self.url is not None
        connection = PostgresConnection(self.url)
        try:
            if not create and "meta" not in connection.tables():
                yield None
                return
            prepare(connection, self.location)
            yield connection
        except psycopg.Error as error:
            raise InputError(
                f"the history store cannot be used ({str(error).strip()[:300]})",
                path=self.location,
                expected=f"a {STORE_FORMAT} PostgreSQL database",
            ) from None
        finally:
            connection.close()

    # ------------------------------------------------------------------ units and entries
    def unit_directory(self, serial: str) -> Path:
        """Return ``DIR/<serial>`` (InputError for a serial number that cannot name a folder)."""
        return self.root / check_serial(serial)

    def entries(self, serial: str) -> list[HistoryEntry]:
        """Return the unit's entries, oldest first; empty if it has none."""
        self.unit_directory(serial)
        with self._database(create=False) as connection:
            if connection is None:
                return []
            rows = connection.execute(
                f"SELECT {ENTRY_COLUMNS} FROM records WHERE serial = ? ORDER BY valid_from_utc, id", (serial,)
            ).fetchall()
        return [entry_from_row(row) for row in rows]

    def serials(self) -> list[str]:
        """Return the units with at least one record, sorted."""
        with self._database(create=False) as connection:
            if connection is None:
                return []
            return [row[0] for row in connection.execute("SELECT DISTINCT serial FROM records ORDER BY serial")]

    def state(self) -> tuple[int, int]:
        """Return (records filed, largest row id): it changes whenever a record is filed (what a reader caches by)."""
        with self._database(create=False) as connection:
            if connection is None:
                return (0, 0)
            count, last = connection.execute("SELECT count(*), coalesce(max(id), 0) FROM records").fetchone()
        return int(count), int(last)

    def add(self, record_path: str | os.PathLike[str], *, prior: str = "", evidence: str | os.PathLike[str] | None = None) -> HistoryEntry:
        """File a record in its unit's history (idempotent: the same bytes are filed once).

        The record (and the data-only ``evidence`` estimate kept beside it) is validated from the very bytes that are
        filed; nothing is written when either is refused.

        Parameters
        ----------
        record_path : path
            The record to file.
        prior : str
            SHA-256 of the record it was built on ("" for an independent calibration).
        evidence : path, optional
            The data-only estimate kept beside a prior-based record (stores of earlier versions).

        Returns
        -------
        HistoryEntry
            The record's entry (the one already filed when the same bytes were filed before).
        """
        filing = read_filing(record_path, prior=prior, evidence=evidence)
        self.unit_directory(filing.record.serial_number)
        return self.add_filings([filing])[0]

    def add_filings(self, filings: Iterable[Filing]) -> list[HistoryEntry]:
        """File records already read (:func:`~stableins.history_store.filing.filing_of`), each in its own transaction.

        One connection serves them all (:meth:`add` files one; ``history --migrate`` and the fleet benchmark file many).
        """
        entries = []
        with self._database(create=True) as connection:
            assert connection is not None
            for filing in filings:
                serial = filing.record.serial_number
                directory = self.unit_directory(serial)
                existing = find_entry(connection, serial, filing.entry.sha256)
                if existing is not None:
                    entries.append(existing)
                elif self.url is not None:
                    entries.append(self._file_in_database(connection, filing))
                else:
                    try:
                        directory.mkdir(parents=True, exist_ok=True)
                    except OSError as error:
                        raise InputError(f"cannot create the unit's folder ({error.strerror})", path=directory) from None
                    entries.append(self._file(connection, directory, filing))
        return entries

    @staticmethod
    def _file_in_database(connection: Connection, filing: Filing) -> HistoryEntry:
        """Index a filing and store its bytes in one transaction (PostgreSQL: the bytes appear with their row)."""
        entry, serial = filing.entry, filing.record.serial_number
        with transaction(connection):
            existing = find_entry(connection, serial, entry.sha256)  # filed by another station meanwhile
            if existing is not None:
                return existing
            insert_entry(connection, serial, entry, filing.record, filing.evidence_record)
            files = [(serial, entry.file, filing.data)]
            if filing.evidence_data is not None:
                files.append((serial, entry.evidence, filing.evidence_data))
            connection.executemany("INSERT INTO files (serial, name, data) VALUES (?, ?, ?)", files)
        return entry

    @staticmethod
    def _file(connection: Connection, directory: Path, filing: Filing) -> HistoryEntry:
        """Write the filing's files and index them in one transaction (the files appear with their row)."""
        entry, serial = filing.entry, filing.record.serial_number
        staged = [stage_file(directory, entry.file, filing.data)]
        try:
            if filing.evidence_data is not None:
                staged.append(stage_file(directory, entry.evidence, filing.evidence_data))
            with transaction(connection):
                existing = find_entry(connection, serial, entry.sha256)  # filed by another process meanwhile
                if existing is not None:
                    return existing
                insert_entry(connection, serial, entry, filing.record, filing.evidence_record)
                for temporary, final in staged:  # under the write lock: the files appear with their row
                    os.replace(temporary, final)
                fsync_directory(directory)
        finally:
            for temporary, _ in staged:
                with contextlib.suppress(FileNotFoundError):
                    os.unlink(temporary)
        return entry

    # ------------------------------------------------------------------ reading records
    def record_path(self, serial: str, entry: HistoryEntry, *, evidence: bool = False) -> Path:
        """Return the path of a filed record after its SHA-256 was checked against the index (InputError otherwise).

        On PostgreSQL the verified bytes are written (atomically) to ``root/<serial>/<file>``, a local folder of this
        user's, and that copy's path is returned.
        """
        if self.url is None:
            path, digest = self._file_and_digest(serial, entry, evidence=evidence)
            verified_bytes(path, digest)
            return path
        from stableins.data.atomic import atomic_write

        name = entry.evidence if evidence and entry.evidence else entry.file
        path = self.unit_directory(serial) / name
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_write(path, "wb") as handle:
            handle.write(self.verified_data(serial, entry, evidence=evidence))
        return path

    def _file_and_digest(self, serial: str, entry: HistoryEntry, *, evidence: bool) -> tuple[Path, str]:
        if evidence and entry.evidence:
            return self.unit_directory(serial) / entry.evidence, entry.evidence_sha256
        return self.unit_directory(serial) / entry.file, entry.sha256

    def verified_data(self, serial: str, entry: HistoryEntry, *, evidence: bool = False) -> bytes:
        """Return the bytes of a filed record (or of the estimate kept beside it), refused unless their SHA-256 is the index's.

        Raises
        ------
        InputError
            The file is missing, or its SHA-256 differs from the one its row holds.
        """
        path, digest = self._file_and_digest(serial, entry, evidence=evidence)
        if self.url is None:
            return verified_bytes(path, digest)
        where = f"{self.location} {serial}/{path.name}"
        with self._database(create=False) as connection:
            row = (
                None
                if connection is None
                else connection.execute("SELECT data FROM files WHERE serial = ? AND name = ?", (serial, path.name)).fetchone()
            )
        if row is None:
            raise InputError(
                "the filed record is missing", path=where, field="sha256", expected=f"the file the history index lists, SHA-256 {digest}"
            )
        return checked_digest(bytes(row[0]), digest, where)

    def load(self, serial: str, entry: HistoryEntry, *, evidence: bool = False) -> CalibrationRecord:
        """Return a filed record (or the estimate kept beside it), refused unless its bytes have the SHA-256 the index holds."""
        from stableins.data.jsonio import parse_json
        from stableins.records import CalibrationRecord

        path, _ = self._file_and_digest(serial, entry, evidence=evidence)
        data = self.verified_data(serial, entry, evidence=evidence)
        return CalibrationRecord.from_document(parse_json(data, path=path, what="a calibration record"), str(path))

    def verify(self, serial: str | None = None) -> list[str]:
        """Check the index (SQLite's integrity check) and every filed file against its digest; return the problems found."""
        problems: list[str] = []
        with self._database(create=False) as connection:
            if connection is None:
                return problems
            if self.url is None:
                result = connection.execute("PRAGMA integrity_check").fetchone()[0]
                if result != "ok":
                    problems.append(f"{self.index_path}: SQLite integrity check: {result}")
            query = f"SELECT serial, {ENTRY_COLUMNS} FROM records" + (" WHERE serial = ?" if serial else "") + " ORDER BY serial, id"
            rows = connection.execute(query, (serial,) if serial else ()).fetchall()
        for row in rows:
            entry = entry_from_row(row[1:])
            for evidence in (False, True) if entry.evidence else (False,):
                try:
                    self.verified_data(row[0], entry, evidence=evidence)
                except InputError as error:
                    problems.append(str(error))
        return problems

    # ------------------------------------------------------------------ questions
    def in_force(self, serial: str, date: datetime | None = None) -> HistoryEntry:
        """Return the entry in force at ``date`` (now by default).

        Raises
        ------
        InputError
            The unit has no history, or none of its records is older than ``date``.
        """
        date = date or datetime.now(UTC)
        entries = self.entries(serial)
        if not entries:
            raise InputError(
                f"no calibration records for unit {serial!r}",
                path=self.location,
                expected=f"a record filed with 'stableins history {shlex.quote(serial)} --store {shlex.quote(self.location)} "
                "--add RECORD.json'",
            )
        earlier = [e for e in entries if e.time <= date]
        if not earlier:
            raise InputError(
                f"unit {serial!r} had no calibration in force on {date.isoformat()}; "
                f"its first record is valid from {entries[0].valid_from}",
                field="date",
            )
        return earlier[-1]

    def staleness(self, entry: HistoryEntry, date: datetime | None = None, max_age: timedelta = DEFAULT_MAX_AGE) -> str | None:
        """Return a warning if ``entry`` is older than ``max_age`` at ``date``, else ``None``."""
        date = date or datetime.now(UTC)
        age = date - entry.time
        if age > max_age:
            return f"the record in force is {age.days} days old (limit {max_age.days} days): recalibrate (stableins recal)"
        return None

    def records(self, serial: str) -> list[tuple[HistoryEntry, CalibrationRecord]]:
        """Return the unit's entries with their records, oldest first, every record read verified by its SHA-256.

        One read of the store for them all (on PostgreSQL one query, not one connection per record).
        """
        from stableins.data.jsonio import parse_json
        from stableins.records import CalibrationRecord

        entries = self.entries(serial)
        stored: dict[str, bytes] | None = None
        if self.url is not None and entries:
            with self._database(create=False) as connection:
                query = "SELECT name, data FROM files WHERE serial = ?"
                rows = [] if connection is None else connection.execute(query, (serial,)).fetchall()
            stored = {name: bytes(data) for name, data in rows}
        out = []
        for entry in entries:
            path = self.unit_directory(serial) / entry.file
            if stored is None:
                data = verified_bytes(path, entry.sha256)
            elif entry.file in stored:
                data = checked_digest(stored[entry.file], entry.sha256, f"{self.location} {serial}/{entry.file}")
            else:
                data = self.verified_data(serial, entry)  # missing: the same refusal as a single read
            out.append((entry, CalibrationRecord.from_document(parse_json(data, path=path, what="a calibration record"), str(path))))
        return out

    def changes(self, serial: str) -> list[tuple[HistoryEntry, HistoryEntry, Comparison]]:
        """Return consecutive pairs of records with every parameter's change and significance (:func:`stableins.history.compare`)."""
        loaded = self.records(serial)
        return [(old, new, compare(before, after)) for (old, before), (new, after) in zip(loaded, loaded[1:])]

    def to_dataframe(self, serial: str) -> Any:
        """Return the unit's calibration history as a :class:`pandas.DataFrame`, one row per record, oldest first.

        Columns ``valid_from``, ``file``, ``procedure``, ``stages``, ``prior`` (``independent`` or ``updates <sha256>``), then
        for every parameter of any record its value and ``σ <id>`` in engineering units (NaN where a record does not state it).
        Every record is read verified (:meth:`load`).  Needs pandas (``pip install stableins[pandas]``).
        """
        from stableins.display import require_pandas

        pandas = require_pandas()
        rows = []
        for entry, record in self.records(serial):
            row: dict[str, Any] = {
                "valid_from": entry.time,
                "file": entry.file,
                "procedure": entry.procedure,
                "stages": ", ".join(entry.stages),
                "prior": f"updates {entry.prior[:12]}" if entry.prior else "independent",
            }
            for pid, value, sigma, unit, status, _ in record.rows():
                shown = status != Status.UNIDENTIFIABLE
                row[f"{pid} [{unit}]"] = value if shown else math.nan
                row[f"σ {pid}"] = sigma if shown and status == Status.ESTIMATED else math.nan
            rows.append(row)
        return pandas.DataFrame.from_records(rows)

    def trends(self, serial: str) -> list[Trend]:
        """Return the drift trend of every parameter that at least two calibrations determine from their own data.

        The points are each record's data-only estimates (:func:`stableins.history.data_only`).
        """
        from dataclasses import replace

        series: dict[str, list[tuple[datetime, float, float]]] = {}
        stated: dict[str, list[tuple[float, float]]] = {}
        units: dict[str, str] = {}
        for entry, record in self.records(serial):
            for pid, (value, sigma) in data_only(record).items():
                series.setdefault(pid, []).append((entry.time, value, sigma))
                stated.setdefault(pid, []).append((record[pid].value, record[pid].sigma))
                units[pid] = record[pid].unit
        out = []
        for pid, points in series.items():
            if len(points) >= 2:
                values, sigmas = zip(*stated[pid], strict=True)
                out.append(replace(trend(points, pid, units[pid]), record_values=tuple(values), record_sigmas=tuple(sigmas)))
        return out

    def fleet(
        self, date: datetime | None = None, max_age: timedelta = DEFAULT_MAX_AGE, drift_sigmas: float = DRIFT_SIGMAS
    ) -> list[UnitStatus]:
        """Return every unit: its record in force at ``date``, whether it is due, which parameters drift (from the index alone).

        The drift of a parameter is the weighted straight line through the data-only estimates of its records (indexed
        when they were filed), as :meth:`trends` computes it from the records; a unit drifts when one of its
        parameters' ``|z| = |drift / σ|`` reaches ``drift_sigmas``.
        """
        date = date or datetime.now(UTC)
        with self._database(create=False) as connection:
            if connection is None:
                return []
            rows = connection.execute(f"SELECT id, serial, {ENTRY_COLUMNS} FROM records ORDER BY serial, valid_from_utc, id").fetchall()
            values = connection.execute("SELECT record, id, value, sigma FROM parameters WHERE source = 'data_only'").fetchall()
        return fleet_status(rows, values, date, max_age, drift_sigmas)
