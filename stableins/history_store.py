r"""The history store: every unit's calibration records, indexed in SQLite, each record verified when it is read.

Layout of a store (``--store DIR``, default ``$STABLEINS_HISTORY`` or ``~/.local/share/stableins/history``)::

    DIR/history.sqlite                       the index (SQLite, WAL mode): units, records, digests, statuses
    DIR/<serial>/<valid-from>-<sha8>.json    the records, copied in byte for byte
    DIR/<serial>/<valid-from>-<sha8>.evidence.json   the data-only estimate a recalibration kept beside its record
                                                     (stores of earlier versions; records now carry their likelihoods)

Why a database (docs/procedures.md, README "Dependencies and why"): the index is changed in transactions, so any
number of processes may file records at once (``stableins history --add``, ``stableins recal``) without losing an
entry, and a process killed at any moment (``kill -9``, power loss) leaves it as it was before or after its
transaction, never in between.  Writers take SQLite's write lock for the whole of a filing (``BEGIN IMMEDIATE``:
they queue, with a busy timeout of :data:`BUSY_TIMEOUT` seconds); readers never block them (WAL).  A filing
writes the record's file before the transaction that indexes it commits, so every indexed file exists; a
record file without an index row (a filing killed between the two) is never read and is rewritten, byte for
byte, when the record is filed again.

The index holds, per record: the unit, the file, its SHA-256, the time it is valid from, its creation time,
procedure, stages, the prior it was built on, every parameter's value, σ and status, and the data-only estimates
of its calibration (:func:`stableins.history.data_only`, the points of the drift), so that a laboratory can ask
about its whole fleet without opening a record: which units are due (:meth:`HistoryStore.fleet`, ``stableins
history --fleet --due``), which drift (``--drifted``).  A record is read only through :meth:`HistoryStore.load`,
which compares its SHA-256 with the index and refuses a record changed after it was filed, naming its path and
the digest expected.

Stores written by earlier versions (``DIR/<serial>/index.json``) are migrated on first use: each unit's entries
are checked against their files' digests and indexed in one transaction; the old index is then renamed
``index.json.migrated``.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import math
import os
import re
import shlex
import sqlite3
import tempfile
import time
from collections.abc import Iterator
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import TYPE_CHECKING, Any

from stableins.data.atomic import fsync_directory
from stableins.errors import InputError
from stableins.history import DEFAULT_MAX_AGE, Comparison, Trend, compare, data_only, parse_date, trend
from stableins.status import Status

if TYPE_CHECKING:  # pragma: no cover
    from stableins.records import CalibrationRecord

STORE_NAME = "history.sqlite"
STORE_FORMAT = "stableins-history-store"
STORE_SCHEMA_VERSION = 1
#: Seconds a writer waits for another writer's transaction before giving up.
BUSY_TIMEOUT = 60.0
#: The index of stores written before the database (migrated on first use).
INDEX_NAME = "index.json"
INDEX_FORMAT = "stableins-history-index"
#: Largest record file filed or read [bytes].
MAX_RECORD_BYTES = 64 << 20
#: ``|drift| / σ`` beyond which a unit counts as drifting in fleet queries.
DRIFT_SIGMAS = 3.0
#: A serial number that can name a folder on every file system stableins runs on.
_SERIAL = re.compile(r"[^\x00-\x1f/\\:*?\"<>|]{1,128}")
_SHA256 = re.compile(r"[0-9a-f]{64}")

_SCHEMA = (
    "CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL)",
    "CREATE TABLE IF NOT EXISTS units (serial TEXT PRIMARY KEY, first_filed TEXT NOT NULL)",
    """CREATE TABLE IF NOT EXISTS records (
        id INTEGER PRIMARY KEY,
        serial TEXT NOT NULL REFERENCES units(serial),
        file TEXT NOT NULL,
        sha256 TEXT NOT NULL CHECK (length(sha256) = 64),
        valid_from TEXT NOT NULL,
        valid_from_utc REAL NOT NULL,
        created TEXT NOT NULL,
        procedure TEXT NOT NULL,
        stages TEXT NOT NULL,
        prior TEXT NOT NULL,
        evidence TEXT NOT NULL,
        evidence_sha256 TEXT NOT NULL,
        filed TEXT NOT NULL,
        UNIQUE (serial, sha256),
        UNIQUE (serial, file))""",
    """CREATE TABLE IF NOT EXISTS parameters (
        record INTEGER NOT NULL REFERENCES records(id),
        source TEXT NOT NULL CHECK (source IN ('record', 'evidence', 'data_only')),
        id TEXT NOT NULL,
        value REAL NOT NULL,
        sigma REAL,
        unit TEXT NOT NULL,
        status TEXT NOT NULL,
        PRIMARY KEY (record, source, id))""",
    "CREATE TABLE IF NOT EXISTS migrations (serial TEXT PRIMARY KEY, source TEXT NOT NULL, migrated TEXT NOT NULL)",
    "CREATE INDEX IF NOT EXISTS records_by_unit ON records(serial, valid_from_utc)",
)
_ENTRY_COLUMNS = "file, valid_from, created, sha256, procedure, stages, prior, evidence, evidence_sha256"


def default_store() -> Path:
    env = os.environ.get("STABLEINS_HISTORY")
    return Path(env) if env else Path.home() / ".local" / "share" / "stableins" / "history"


@dataclass(frozen=True)
class Entry:
    """One record in a unit's history (a row of the index)."""

    file: str
    valid_from: str
    created: str
    sha256: str
    procedure: str
    stages: tuple[str, ...]
    prior: str = ""  #: sha256 of the record used as prior ("" for an independent calibration)
    evidence: str = ""  #: file of the data-only estimate kept beside a prior-based record
    evidence_sha256: str = ""  #: its SHA-256

    @property
    def time(self) -> datetime:
        return parse_date(self.valid_from, "valid_from")


@dataclass(frozen=True)
class UnitStatus:
    """Where one unit of the fleet stands (:meth:`HistoryStore.fleet`).

    Attributes
    ----------
    serial : str
    records : int
        Records filed.
    in_force : Entry or None
        The record in force at the date asked about (None: none yet).
    age_days : float or None
        Age of the record in force at that date [days].
    due : bool
        No record in force, or one older than the age limit: recalibrate.
    drifting : tuple of (str, float)
        Parameters whose drift per year exceeds :data:`DRIFT_SIGMAS` of its σ, with the significance z.
    """

    serial: str
    records: int
    in_force: Entry | None
    age_days: float | None
    due: bool
    drifting: tuple[tuple[str, float], ...]


def _utc_now() -> str:
    return datetime.now(UTC).replace(microsecond=0).isoformat()


class HistoryStore:
    """Per-serial store of calibration records indexed in SQLite (module docstring)."""

    def __init__(self, root: str | os.PathLike[str] | None = None) -> None:
        self.root = Path(root) if root is not None else default_store()
        self.index_path = self.root / STORE_NAME

    # ------------------------------------------------------------------ database
    @contextlib.contextmanager
    def _database(self, *, create: bool) -> Iterator[sqlite3.Connection | None]:
        """A connection (None when the store does not exist and ``create`` is false); migrates old stores first."""
        if self.root.exists() and not self.root.is_dir():
            raise InputError("is a file, not a directory", path=self.root, field="root", expected="a history store directory")
        if not self.index_path.exists():
            if not create and not self._legacy_units():
                yield None
                return
            try:
                self.root.mkdir(parents=True, exist_ok=True)
            except OSError as error:
                raise InputError(f"cannot create the history store ({error.strerror})", path=self.root, field="root") from None
        try:
            connection = sqlite3.connect(self.index_path, timeout=BUSY_TIMEOUT, isolation_level=None)
        except sqlite3.Error as error:
            raise InputError(f"cannot open the history index ({error})", path=self.index_path) from None
        try:
            self._prepare(connection)
            self._migrate(connection)
            yield connection
        except sqlite3.DatabaseError as error:
            raise InputError(
                f"the history index cannot be used ({error}); it is damaged or not a stableins history index",
                path=self.index_path,
                expected=f"a {STORE_FORMAT} SQLite database",
            ) from None
        finally:
            connection.close()

    def _prepare(self, connection: sqlite3.Connection) -> None:
        """WAL mode, the schema and the format check (idempotent; safe when several processes start at once)."""
        for attempt in range(200):  # switching to WAL needs a moment alone with the file
            try:
                connection.execute("PRAGMA journal_mode=WAL").fetchone()
                break
            except sqlite3.OperationalError as error:
                if "locked" not in str(error) or attempt == 199:
                    raise
                time.sleep(0.01 + 0.002 * attempt)
        connection.execute("PRAGMA synchronous=FULL")
        connection.execute("PRAGMA foreign_keys=ON")
        found = self._meta(connection)
        if not found:
            with _transaction(connection):  # several processes may start on a new store at once: one creates it
                found = self._meta(connection)
                if not found:
                    for statement in _SCHEMA:
                        connection.execute(statement)
                    found = {"format": STORE_FORMAT, "schema_version": str(STORE_SCHEMA_VERSION), "created": _utc_now()}
                    connection.executemany("INSERT INTO meta (key, value) VALUES (?, ?)", list(found.items()))
        if found.get("format") == STORE_FORMAT and found.get("schema_version") == str(STORE_SCHEMA_VERSION):
            return
        if found.get("format") != STORE_FORMAT:
            raise InputError(
                f"format {found.get('format')!r}: not a stableins history index", path=self.index_path, expected=f"'{STORE_FORMAT}'"
            )
        raise InputError(
            f"schema version {found.get('schema_version')!r}; this stableins reads version {STORE_SCHEMA_VERSION}",
            path=self.index_path,
            field="schema_version",
            expected=str(STORE_SCHEMA_VERSION),
        )

    @staticmethod
    def _meta(connection: sqlite3.Connection) -> dict[str, str]:
        exists = connection.execute("SELECT 1 FROM sqlite_master WHERE type = 'table' AND name = 'meta'").fetchone()
        if not exists:
            return {}
        return dict(connection.execute("SELECT key, value FROM meta").fetchall())

    # ------------------------------------------------------------------ units and entries
    def unit_directory(self, serial: str) -> Path:
        """``DIR/<serial>`` (InputError for a serial number that cannot name a folder)."""
        if not isinstance(serial, str) or not _SERIAL.fullmatch(serial) or serial.strip() != serial or serial.startswith("."):
            raise InputError(
                f"serial number {str(serial)[:40]!r} cannot name a history folder",
                field="serial",
                expected="1 to 128 printable characters without / \\ : * ? \" < > |, not starting with '.' or a space",
            )
        return self.root / serial

    _unit_directory = unit_directory

    def entries(self, serial: str) -> list[Entry]:
        """The unit's entries, oldest first; empty if it has none."""
        self.unit_directory(serial)
        with self._database(create=False) as connection:
            if connection is None:
                return []
            rows = connection.execute(
                f"SELECT {_ENTRY_COLUMNS} FROM records WHERE serial = ? ORDER BY valid_from_utc, id", (serial,)
            ).fetchall()
        return [_entry(row) for row in rows]

    def serials(self) -> list[str]:
        """Units with at least one record, sorted."""
        with self._database(create=False) as connection:
            if connection is None:
                return []
            return [row[0] for row in connection.execute("SELECT DISTINCT serial FROM records ORDER BY serial")]

    def add(self, record_path: str | os.PathLike[str], *, prior: str = "", evidence: str | os.PathLike[str] | None = None) -> Entry:
        """File a record in its unit's history (idempotent: the same bytes are filed once).

        The record (and the data-only ``evidence`` estimate kept beside it) is validated from the very bytes that are
        filed; nothing is written when either is refused.
        """

        if prior and not _SHA256.fullmatch(prior):
            raise InputError(f"prior {prior[:70]!r} is not a SHA-256 digest", field="prior", expected="64 lower-case hexadecimal digits")
        data, record = _read_record(record_path)
        digest = hashlib.sha256(data).hexdigest()
        evidence_data: bytes | None = None
        evidence_record: CalibrationRecord | None = None
        if evidence is not None:
            evidence_data, evidence_record = _read_record(evidence)
            if evidence_record.serial_number != record.serial_number:
                raise InputError(
                    f"the estimate is of unit {evidence_record.serial_number!r}, the record of {record.serial_number!r}",
                    path=evidence,
                    field="serial_number",
                    expected="the data-only estimate of the same unit",
                )
        serial = record.serial_number
        directory = self.unit_directory(serial)
        valid_from = record.provenance.data_end or record.provenance.created
        if not valid_from:
            raise InputError("record has neither a data end time nor a creation time", path=record_path, field="provenance.data_end")
        when = parse_date(valid_from, "provenance.data_end")
        stamp = when.strftime("%Y%m%dT%H%M%SZ")
        name = f"{stamp}-{digest[:8]}.json"
        evidence_name = f"{stamp}-{digest[:8]}.evidence.json" if evidence_data is not None else ""
        evidence_digest = hashlib.sha256(evidence_data).hexdigest() if evidence_data is not None else ""
        entry = Entry(
            name,
            valid_from,
            record.provenance.created,
            digest,
            record.provenance.procedure,
            record.provenance.stages,
            prior,
            evidence_name,
            evidence_digest,
        )
        with self._database(create=True) as connection:
            assert connection is not None
            existing = self._find(connection, serial, digest)
            if existing is not None:
                return existing
            try:
                directory.mkdir(parents=True, exist_ok=True)
            except OSError as error:
                raise InputError(f"cannot create the unit's folder ({error.strerror})", path=directory) from None
            staged = [_stage(directory, name, data)]
            try:
                if evidence_data is not None:
                    staged.append(_stage(directory, evidence_name, evidence_data))
                with _transaction(connection):
                    existing = self._find(connection, serial, digest)  # filed by another process meanwhile
                    if existing is not None:
                        return existing
                    self._insert(connection, serial, entry, when, record, evidence_record)
                    for temporary, final in staged:  # under the write lock: the files appear with their row
                        os.replace(temporary, final)
                    fsync_directory(directory)
            finally:
                for temporary, _ in staged:
                    with contextlib.suppress(FileNotFoundError):
                        os.unlink(temporary)
        return entry

    @staticmethod
    def _find(connection: sqlite3.Connection, serial: str, digest: str) -> Entry | None:
        row = connection.execute(f"SELECT {_ENTRY_COLUMNS} FROM records WHERE serial = ? AND sha256 = ?", (serial, digest)).fetchone()
        return None if row is None else _entry(row)

    @staticmethod
    def _insert(
        connection: sqlite3.Connection,
        serial: str,
        entry: Entry,
        when: datetime,
        record: CalibrationRecord,
        evidence: CalibrationRecord | None,
    ) -> None:
        now = _utc_now()
        connection.execute("INSERT OR IGNORE INTO units (serial, first_filed) VALUES (?, ?)", (serial, now))
        cursor = connection.execute(
            "INSERT INTO records (serial, file, sha256, valid_from, valid_from_utc, created, procedure, stages, prior, evidence, "
            "evidence_sha256, filed) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
            (
                serial,
                entry.file,
                entry.sha256,
                entry.valid_from,
                when.timestamp(),
                entry.created,
                entry.procedure,
                json.dumps(list(entry.stages)),
                entry.prior,
                entry.evidence,
                entry.evidence_sha256,
                now,
            ),
        )
        rows = []
        for source, which in (("record", record), ("evidence", evidence)):
            if which is None:
                continue
            for p in which.parameters:
                sigma = p.sigma if math.isfinite(p.sigma) else None
                rows.append((cursor.lastrowid, source, p.id, p.value, sigma, p.unit, getattr(p.status, "value", str(p.status))))
        # what the record's own calibration determines from its data alone: the points of the drift (fleet queries)
        for pid, (value, sigma) in data_only(record).items():
            rows.append((cursor.lastrowid, "data_only", pid, value, sigma, record[pid].unit, "estimated"))
        connection.executemany("INSERT INTO parameters (record, source, id, value, sigma, unit, status) VALUES (?, ?, ?, ?, ?, ?, ?)", rows)

    # ------------------------------------------------------------------ reading records
    def record_path(self, serial: str, entry: Entry, *, evidence: bool = False) -> Path:
        """Path of a filed record after its SHA-256 was checked against the index (InputError otherwise)."""
        path, digest = self._file_and_digest(serial, entry, evidence=evidence)
        _verified_bytes(path, digest)
        return path

    def _file_and_digest(self, serial: str, entry: Entry, *, evidence: bool) -> tuple[Path, str]:
        if evidence and entry.evidence:
            return self.unit_directory(serial) / entry.evidence, entry.evidence_sha256
        return self.unit_directory(serial) / entry.file, entry.sha256

    def load(self, serial: str, entry: Entry, *, evidence: bool = False) -> CalibrationRecord:
        """A filed record (or the estimate kept beside it), refused unless its bytes have the SHA-256 the index holds."""
        from stableins.data.jsonio import parse_json
        from stableins.records import CalibrationRecord

        path, digest = self._file_and_digest(serial, entry, evidence=evidence)
        data = _verified_bytes(path, digest)
        return CalibrationRecord.from_document(parse_json(data, path=path, what="a calibration record"), str(path))

    def verify(self, serial: str | None = None) -> list[str]:
        """Check the index (SQLite's integrity check) and every filed file against its digest; the problems found."""
        problems: list[str] = []
        with self._database(create=False) as connection:
            if connection is None:
                return problems
            result = connection.execute("PRAGMA integrity_check").fetchone()[0]
            if result != "ok":
                problems.append(f"{self.index_path}: SQLite integrity check: {result}")
            query = f"SELECT serial, {_ENTRY_COLUMNS} FROM records" + (" WHERE serial = ?" if serial else "") + " ORDER BY serial, id"
            rows = connection.execute(query, (serial,) if serial else ()).fetchall()
        for row in rows:
            entry = _entry(row[1:])
            for evidence in (False, True) if entry.evidence else (False,):
                try:
                    _verified_bytes(*self._file_and_digest(row[0], entry, evidence=evidence))
                except InputError as error:
                    problems.append(str(error))
        return problems

    # ------------------------------------------------------------------ questions
    def in_force(self, serial: str, date: datetime | None = None) -> Entry:
        """The entry in force at ``date`` (now by default).

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
                path=self.root,
                expected=f"a record filed with 'stableins history {shlex.quote(serial)} --store {shlex.quote(str(self.root))} "
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

    def staleness(self, entry: Entry, date: datetime | None = None, max_age: timedelta = DEFAULT_MAX_AGE) -> str | None:
        """A warning if ``entry`` is older than ``max_age`` at ``date``, else ``None``."""
        date = date or datetime.now(UTC)
        age = date - entry.time
        if age > max_age:
            return f"the record in force is {age.days} days old (limit {max_age.days} days): recalibrate (stableins recal)"
        return None

    def changes(self, serial: str) -> list[tuple[Entry, Entry, Comparison]]:
        """Consecutive pairs of records with every parameter's change and significance (:func:`stableins.history.compare`)."""
        entries = self.entries(serial)
        out = []
        for old, new in zip(entries, entries[1:]):
            out.append((old, new, compare(self.load(serial, old), self.load(serial, new))))
        return out

    def __repr__(self) -> str:
        return f"HistoryStore({str(self.root)!r})"

    def to_dataframe(self, serial: str) -> Any:
        """The unit's calibration history as a :class:`pandas.DataFrame`, one row per record, oldest first.

        Columns ``valid_from``, ``file``, ``procedure``, ``stages``, ``prior`` (``independent`` or ``updates <sha256>``), then
        for every parameter of any record its value and ``σ <id>`` in engineering units (NaN where a record does not state it).
        Every record is read verified (:meth:`load`).  Needs pandas (``pip install stableins[pandas]``).
        """
        from stableins.display import require_pandas

        pandas = require_pandas()
        rows = []
        for entry in self.entries(serial):
            record = self.load(serial, entry)
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
        """Drift trend of every parameter that at least two calibrations determine from their own data
        (:func:`stableins.history.data_only`)."""
        entries = self.entries(serial)
        series: dict[str, list[tuple[datetime, float, float]]] = {}
        units: dict[str, str] = {}
        for entry in entries:
            record = self.load(serial, entry)
            for pid, (value, sigma) in data_only(record).items():
                series.setdefault(pid, []).append((entry.time, value, sigma))
                units[pid] = record[pid].unit
        return [trend(points, pid, units[pid]) for pid, points in series.items() if len(points) >= 2]

    def fleet(
        self, date: datetime | None = None, max_age: timedelta = DEFAULT_MAX_AGE, drift_sigmas: float = DRIFT_SIGMAS
    ) -> list[UnitStatus]:
        """Every unit: its record in force at ``date``, whether it is due, which parameters drift (from the index alone).

        The drift of a parameter is the weighted straight line through the data-only estimates of its records (indexed
        when they were filed), as :meth:`trends` computes it from the records; a unit drifts when one of its
        parameters' ``|z| = |drift / σ|`` reaches ``drift_sigmas``.
        """
        date = date or datetime.now(UTC)
        with self._database(create=False) as connection:
            if connection is None:
                return []
            rows = connection.execute(f"SELECT id, serial, {_ENTRY_COLUMNS} FROM records ORDER BY serial, valid_from_utc, id").fetchall()
            values = connection.execute("SELECT record, id, value, sigma FROM parameters WHERE source = 'data_only'").fetchall()
        by_record: dict[int, list[tuple[str, float, float]]] = {}
        for record_id, pid, value, sigma in values:
            by_record.setdefault(record_id, []).append((pid, value, sigma if sigma is not None else math.nan))
        units: dict[str, list[tuple[int, Entry]]] = {}
        for row in rows:
            units.setdefault(row[1], []).append((row[0], _entry(row[2:])))
        out = []
        for serial, items in units.items():
            earlier = [e for _, e in items if e.time <= date]
            current = earlier[-1] if earlier else None
            age = (date - current.time).total_seconds() / 86400.0 if current is not None else None
            series: dict[str, list[tuple[datetime, float, float]]] = {}
            for record_id, entry in items:
                for pid, value, sigma in by_record.get(record_id, []):
                    if math.isfinite(sigma) and sigma > 0:
                        series.setdefault(pid, []).append((entry.time, value, sigma))
            drifting = []
            for pid, points in sorted(series.items()):
                if len(points) >= 2:
                    z = trend(points, pid).significance
                    if math.isfinite(z) and abs(z) >= drift_sigmas:
                        drifting.append((pid, float(z)))
            due = current is None or (date - current.time) > max_age
            out.append(UnitStatus(serial, len(items), current, age, due, tuple(drifting)))
        return out

    # ------------------------------------------------------------------ migration
    def _legacy_units(self) -> list[Path]:
        """Unit folders that still carry an index of the JSON store (not yet migrated)."""
        if not self.root.is_dir():
            return []
        try:
            return sorted(p for p in self.root.iterdir() if (p / INDEX_NAME).is_file())
        except OSError as error:
            raise InputError(f"cannot list the history store ({error.strerror})", path=self.root) from None

    def _migrate(self, connection: sqlite3.Connection) -> None:
        """Index every unit of an old JSON store, one transaction per unit (entries verified against their files)."""
        for folder in self._legacy_units():
            index = folder / INDEX_NAME
            with _transaction(connection):
                if connection.execute("SELECT 1 FROM migrations WHERE serial = ?", (folder.name,)).fetchone() is None:
                    for entry, when, record, evidence in _legacy_entries(index, folder):
                        if self._find(connection, folder.name, entry.sha256) is None:
                            self._insert(connection, folder.name, entry, when, record, evidence)
                    connection.execute(
                        "INSERT INTO migrations (serial, source, migrated) VALUES (?, ?, ?)", (folder.name, str(index), _utc_now())
                    )
            with contextlib.suppress(OSError):  # after the commit; a failed rename is retried on the next use
                os.replace(index, folder / f"{INDEX_NAME}.migrated")


# --------------------------------------------------------------------------- helpers
@contextlib.contextmanager
def _transaction(connection: sqlite3.Connection) -> Iterator[None]:
    """``BEGIN IMMEDIATE`` … ``COMMIT`` (rolled back on any exception): writers queue for SQLite's write lock."""
    connection.execute("BEGIN IMMEDIATE")
    try:
        yield
    except BaseException:
        connection.execute("ROLLBACK")
        raise
    connection.execute("COMMIT")


def _entry(row: tuple[Any, ...]) -> Entry:
    file, valid_from, created, sha256, procedure, stages, prior, evidence, evidence_sha256 = row
    return Entry(file, valid_from, created, sha256, procedure, tuple(json.loads(stages)), prior, evidence, evidence_sha256)


def _read_record(path: str | os.PathLike[str]) -> tuple[bytes, CalibrationRecord]:
    """A record's bytes and the record validated from those very bytes."""
    from stableins.data.jsonio import parse_json, read_input_bytes
    from stableins.records import CalibrationRecord

    what = "a calibration record (JSON) written by stableins"
    data = read_input_bytes(path, max_bytes=MAX_RECORD_BYTES, what=what)
    return data, CalibrationRecord.from_document(parse_json(data, path=path, what=what), str(path))


def _verified_bytes(path: Path, digest: str) -> bytes:
    """The bytes of a filed file, refused unless their SHA-256 is ``digest`` (the index's)."""
    from stableins.data.jsonio import read_input_bytes

    if not path.exists():
        raise InputError(
            "the filed record is missing", path=path, field="sha256", expected=f"the file the history index lists, SHA-256 {digest}"
        )
    data = read_input_bytes(path, max_bytes=MAX_RECORD_BYTES, what="a filed calibration record")
    found = hashlib.sha256(data).hexdigest()
    if found != digest:
        raise InputError(
            f"the filed record was changed after it was filed (its SHA-256 is now {found})",
            path=path,
            field="sha256",
            expected=f"SHA-256 {digest}, as the history index holds",
        )
    return data


def _stage(directory: Path, name: str, data: bytes) -> tuple[str, Path]:
    """Write ``data`` to a temporary file beside ``directory/name`` (fsync'ed); returns (temporary, final)."""
    fd, temporary = tempfile.mkstemp(prefix=f".{name}.", suffix=".partial", dir=directory)
    try:
        with os.fdopen(fd, "wb") as handle:
            handle.write(data)
            handle.flush()
            os.fsync(handle.fileno())
        mask = os.umask(0)
        os.umask(mask)
        os.chmod(temporary, 0o666 & ~mask)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(temporary)
        raise
    return temporary, directory / name


def _legacy_entries(index: Path, folder: Path) -> Iterator[tuple[Entry, datetime, CalibrationRecord, CalibrationRecord | None]]:
    """The entries of an old ``index.json``, each checked against its file (and read for its parameters)."""
    from stableins.data.jsonio import expect_list, expect_mapping, expect_text, load_json_file, parse_json, read_input_bytes
    from stableins.records import CalibrationRecord

    document = load_json_file(index, what=f"a {INDEX_FORMAT} file (history index unreadable)")
    document = expect_mapping(document, index, "", f"a {INDEX_FORMAT} file (history index unreadable)")
    if document.get("format") != INDEX_FORMAT:
        raise InputError(f"history index unreadable: format {str(document.get('format'))[:40]!r}", path=index, expected=f"'{INDEX_FORMAT}'")
    for k, raw in enumerate(expect_list(document.get("entries"), index, "entries", "a list of entries")):
        where = f"entries[{k}]"
        raw = expect_mapping(raw, index, where)
        fields = {
            key: expect_text(raw.get(key, ""), index, f"{where}.{key}")
            for key in ("file", "valid_from", "created", "sha256", "procedure", "prior", "evidence")
        }
        stages = tuple(expect_text(s, index, f"{where}.stages") for s in expect_list(raw.get("stages", []), index, f"{where}.stages"))
        if not _SHA256.fullmatch(fields["sha256"]):
            raise InputError(f"{fields['sha256'][:70]!r} is not a SHA-256 digest", path=index, field=f"{where}.sha256")
        for key in ("file", "evidence"):
            if fields[key] and (Path(fields[key]).name != fields[key] or fields[key].startswith(".")):
                raise InputError(f"{fields[key][:70]!r} is not a file of this folder", path=index, field=f"{where}.{key}")
        when = parse_date(fields["valid_from"], f"{where}.valid_from")
        data = _verified_bytes(folder / fields["file"], fields["sha256"])
        record = CalibrationRecord.from_document(parse_json(data, path=folder / fields["file"]), str(folder / fields["file"]))
        evidence = None
        evidence_digest = ""
        if fields["evidence"]:  # the old index kept no digest of the estimate: it is taken as found (and kept from now on)
            evidence_path = folder / fields["evidence"]
            evidence_data = read_input_bytes(evidence_path, max_bytes=MAX_RECORD_BYTES, what="the estimate the history index lists")
            evidence = CalibrationRecord.from_document(parse_json(evidence_data, path=evidence_path), str(evidence_path))
            evidence_digest = hashlib.sha256(evidence_data).hexdigest()
        entry = Entry(
            fields["file"],
            fields["valid_from"],
            fields["created"],
            fields["sha256"],
            fields["procedure"],
            stages,
            fields["prior"],
            fields["evidence"],
            evidence_digest,
        )
        yield entry, when, record, evidence
