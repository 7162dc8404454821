"""The index of the history store: its SQLite schema, the rows it holds, transactions and the format check."""

from __future__ import annotations

import contextlib
import json
import os
import sqlite3
import time
from collections.abc import Iterator
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeAlias

from stableins.errors import InputError
from stableins.history import parse_date
from stableins.identifiers import utc_now

if TYPE_CHECKING:  # pragma: no cover
    from stableins.history_store.postgres import PostgresConnection

#: A connection to the store's index: SQLite's, or PostgreSQL's through :class:`~stableins.history_store.postgres.PostgresConnection`.
Connection: TypeAlias = "sqlite3.Connection | PostgresConnection"

STORE_NAME = "history.sqlite"
STORE_FORMAT = "stableins-history-store"
STORE_SCHEMA_VERSION = 1
#: Seconds a writer waits for another writer's transaction before giving up.
BUSY_TIMEOUT = 60.0
#: Largest record file filed or read [bytes].
MAX_RECORD_BYTES = 64 << 20

SCHEMA = (
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
#: The columns of ``records`` an :class:`HistoryEntry` is read from, in its field order.
ENTRY_COLUMNS = "file, valid_from, created, sha256, procedure, stages, prior, evidence, evidence_sha256"


def default_store() -> Path | str:
    """Return the default store: ``$STABLEINS_HISTORY`` (a directory or a ``postgresql://`` URL), else the user's folder.

    The user's folder is ``~/.local/share/stableins/history``.
    """
    from stableins.history_store.postgres import is_url

    env = os.environ.get("STABLEINS_HISTORY")
    if env and is_url(env):
        return env
    return Path(env) if env else Path.home() / ".local" / "share" / "stableins" / "history"


@dataclass(frozen=True)
class HistoryEntry:
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
        """The time the record is valid from (UTC)."""
        return parse_date(self.valid_from, "valid_from")


def entry_from_row(row: tuple[Any, ...]) -> HistoryEntry:
    """Return the entry of a row of :data:`ENTRY_COLUMNS`."""
    file, valid_from, created, sha256, procedure, stages, prior, evidence, evidence_sha256 = row
    return HistoryEntry(file, valid_from, created, sha256, procedure, tuple(json.loads(stages)), prior, evidence, evidence_sha256)


@contextlib.contextmanager
def transaction(connection: Connection) -> Iterator[None]:
    """Run ``BEGIN IMMEDIATE`` … ``COMMIT`` (rolled back on any exception): writers queue for SQLite's write lock."""
    connection.execute("BEGIN IMMEDIATE")
    try:
        yield
    except BaseException:
        connection.execute("ROLLBACK")
        raise
    connection.execute("COMMIT")


def find_entry(connection: Connection, serial: str, digest: str) -> HistoryEntry | None:
    """Return the unit's entry of the record with this SHA-256, None if it is not filed."""
    row = connection.execute(f"SELECT {ENTRY_COLUMNS} FROM records WHERE serial = ? AND sha256 = ?", (serial, digest)).fetchone()
    return None if row is None else entry_from_row(row)


def prepare(connection: Connection, index_path: Path | str) -> None:
    """Set WAL mode, create the schema and check the format (idempotent; safe when several processes start at once).

    On PostgreSQL (:class:`~stableins.history_store.postgres.PostgresConnection`) the schema is
    :data:`stableins.history_store.postgres.SCHEMA`, created under the write lock.

    Raises
    ------
    InputError
        The database is not a stableins history index, or of another schema version.
    """
    from stableins.history_store.postgres import PostgresConnection, postgres_schema

    postgres = isinstance(connection, PostgresConnection)
    if not isinstance(connection, PostgresConnection):
        _write_ahead_log(connection)
        connection.execute("PRAGMA synchronous=FULL")
        connection.execute("PRAGMA foreign_keys=ON")
    found = _meta(connection)
    if not found:
        with transaction(connection):  # several processes may start on a new store at once: one creates it
            found = _meta(connection)
            if not found:
                for statement in postgres_schema(SCHEMA) if postgres else SCHEMA:
                    connection.execute(statement)
                found = {"format": STORE_FORMAT, "schema_version": str(STORE_SCHEMA_VERSION), "created": utc_now()}
                connection.executemany("INSERT INTO meta (key, value) VALUES (?, ?)", list(found.items()))
    if found.get("format") == STORE_FORMAT and found.get("schema_version") == str(STORE_SCHEMA_VERSION):
        return
    if found.get("format") != STORE_FORMAT:
        raise InputError(f"format {found.get('format')!r}: not a stableins history index", path=index_path, expected=f"'{STORE_FORMAT}'")
    raise InputError(
        f"schema version {found.get('schema_version')!r}; this stableins reads version {STORE_SCHEMA_VERSION}",
        path=index_path,
        field="schema_version",
        expected=str(STORE_SCHEMA_VERSION),
    )


def _write_ahead_log(connection: sqlite3.Connection) -> None:
    """Switch the database to WAL mode (retried: the switch needs a moment alone with the file)."""
    for attempt in range(200):
        try:
            connection.execute("PRAGMA journal_mode=WAL").fetchone()
            break
        except sqlite3.OperationalError as error:
            if "locked" not in str(error) or attempt == 199:
                raise
            time.sleep(0.01 + 0.002 * attempt)


def _meta(connection: Connection) -> dict[str, str]:
    from stableins.history_store.postgres import PostgresConnection

    if isinstance(connection, PostgresConnection):
        exists = "meta" in connection.tables()
    else:
        exists = connection.execute("SELECT 1 FROM sqlite_master WHERE type = 'table' AND name = 'meta'").fetchone() is not None
    if not exists:
        return {}
    return dict(connection.execute("SELECT key, value FROM meta").fetchall())
