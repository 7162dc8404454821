"""The history store on PostgreSQL (issue 32): a real server started here, concurrent filing, kill -9, the same output as SQLite.

The server is initdb'ed into a temporary folder and listens on a Unix socket only (tests/postgres_server.py); the
tests are skipped, with the reason, only where PostgreSQL's server programs or psycopg are not installed
(``make system-deps`` installs Debian's postgresql).
"""

from __future__ import annotations

import hashlib
import io
import json
import multiprocessing
import os
import signal
import subprocess
import sys
from contextlib import redirect_stdout
from pathlib import Path

import pytest
from postgres_server import PostgresServer, missing_reason
from test_history_store import record, write_records

from stableins import cli
from stableins.errors import InputError
from stableins.history_store import HistoryStore

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.skipif(missing_reason() is not None, reason=missing_reason() or "")


@pytest.fixture(scope="module")
def server():
    running = PostgresServer()
    yield running
    running.stop()


def consistent(store: HistoryStore) -> None:
    """Every indexed record has its bytes, with the SHA-256 the index holds, and reads as a record."""
    assert store.verify() == []
    for serial in store.serials():
        for entry in store.entries(serial):
            store.load(serial, entry)


def _file_many(args: tuple[str, list[str]]) -> None:
    url, paths = args
    for path in paths:
        HistoryStore(url).add(path)


def test_four_processes_file_25_records_each_and_lose_none(server, tmp_path):
    url = server.database()
    batches = [[str(p) for p in write_records(tmp_path / f"w{k}", f"PG-{k % 2}", 25, start_day=100 * k)] for k in range(4)]
    context = multiprocessing.get_context("fork")
    workers = [context.Process(target=_file_many, args=((url, batch),)) for batch in batches]
    for w in workers:
        w.start()
    for w in workers:
        w.join(120)
    assert [w.exitcode for w in workers] == [0] * 4
    store = HistoryStore(url)
    filed = {e.sha256 for s in store.serials() for e in store.entries(s)}
    expected = {hashlib.sha256(Path(p).read_bytes()).hexdigest() for batch in batches for p in batch}
    assert len(expected) == 100 and filed == expected  # 0 lost, none twice
    consistent(store)


WRITER = """
import os, signal, sys
sys.path.insert(0, {root!r})
from stableins.history_store import HistoryStore
from stableins.history_store import postgres
store = HistoryStore({url!r})
executemany = postgres.PostgresConnection.executemany


def dying(self, sql, rows):  # inside the filing's transaction: the record's row and parameters inserted, not committed
    if "INSERT INTO files" in sql:
        if {bytes_written!r}:
            executemany(self, sql, rows)
        os.kill(os.getpid(), signal.SIGKILL)
    return executemany(self, sql, rows)


for k, path in enumerate({paths!r}):
    if k == {killed!r}:
        postgres.PostgresConnection.executemany = dying
    store.add(path)
    print(path, flush=True)
"""


def test_kill_9_mid_filing_leaves_the_store_consistent(server, tmp_path):
    """A writer killed inside a filing's transaction (before or after the record's bytes are inserted): rolled back."""
    url = server.database()
    store = HistoryStore(url)
    filed = 0
    for k, killed in enumerate((3, 7)):
        paths = [str(p) for p in write_records(tmp_path / f"batch{k}", "PG-9", 10, start_day=40 * k)]
        script = WRITER.format(root=str(ROOT), url=url, paths=paths, killed=killed, bytes_written=k % 2 == 1)
        process = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        out, err = process.communicate(timeout=120)
        assert process.returncode == -signal.SIGKILL, err
        assert len(out.splitlines()) == killed  # it filed `killed` records, then died inside the next filing
        consistent(store)
        assert len(store.entries("PG-9")) - filed == killed  # what it said it filed is there; the interrupted one is not
        entry = store.add(paths[killed])  # the interrupted filing, done again, files normally
        filed += killed + 1
        assert store.entries("PG-9")[-1] == entry and len(store.entries("PG-9")) == filed
        consistent(store)


def _history(argv: list[str]) -> str:
    buffer = io.StringIO()
    with redirect_stdout(buffer):
        assert cli.main(argv) == 0
    return buffer.getvalue()


def test_the_same_history_output_as_sqlite_and_migration_both_ways(server, tmp_path):
    paths = write_records(tmp_path / "r", "PG-7", 5, start_day=0)
    paths += write_records(tmp_path / "r2", "PG-7", 3, start_day=200)
    sqlite_store = tmp_path / "store"
    url = server.database()
    for where in (str(sqlite_store), url):
        _history(["history", "PG-7", "--store", where, "--add", *map(str, paths)])
    texts = [_history(["history", "PG-7", "--store", where, "--at", "2025-09-01"]) for where in (str(sqlite_store), url)]
    assert texts[0].replace(str(sqlite_store), "STORE") == texts[1].replace(HistoryStore(url).location, "STORE")
    documents = [json.loads(_history(["history", "PG-7", "--store", w, "--json", "--at", "2025-09-01"])) for w in (str(sqlite_store), url)]
    assert documents[0] == documents[1] and len(documents[0]["entries"]) == 8
    fleets = [json.loads(_history(["history", "--fleet", "--store", w, "--json", "--at", "2025-09-01"])) for w in (str(sqlite_store), url)]
    assert fleets[0]["units"] == fleets[1]["units"]
    # SQLite -> PostgreSQL -> SQLite: the same records, byte for byte
    copy = server.database()
    moved = json.loads(_history(["history", "--migrate", str(sqlite_store), copy, "--json"]))
    assert (moved["units"], moved["records"], moved["filed"], moved["problems"]) == (1, 8, 8, [])
    again = json.loads(_history(["history", "--migrate", str(sqlite_store), copy, "--json"]))
    assert again["filed"] == 0  # idempotent: a migration interrupted is finished by running it again
    back = tmp_path / "back"
    _history(["history", "--migrate", copy, str(back)])
    original = HistoryStore(sqlite_store)
    returned = HistoryStore(back)
    assert original.entries("PG-7") == returned.entries("PG-7")
    for entry in original.entries("PG-7"):
        assert (back / "PG-7" / entry.file).read_bytes() == (sqlite_store / "PG-7" / entry.file).read_bytes()


def test_a_record_changed_in_the_database_is_refused(server, tmp_path):
    import psycopg

    url = server.database()
    path = tmp_path / "one.json"
    record("PG-1", 3).save(path)
    store = HistoryStore(url)
    entry = store.add(path)
    assert store.add(path) == entry  # the same bytes are filed once
    with psycopg.connect(url, autocommit=True) as connection:
        connection.execute("UPDATE files SET data = data || '\\x20'::bytea WHERE name = %s", (entry.file,))
    with pytest.raises(InputError, match="changed after it was filed") as caught:
        store.load("PG-1", entry)
    assert entry.sha256 in str(caught.value) and "***" not in url
    assert len(store.verify()) == 1
    # the copy a run reads as its prior is written only from verified bytes
    with pytest.raises(InputError, match="changed after it was filed"):
        store.record_path("PG-1", entry)


def test_a_password_never_shows_and_an_unreachable_server_is_one_clear_error(tmp_path):
    url = f"postgresql://lab:secret@/none?host={tmp_path}&port=1"
    store = HistoryStore(url)
    assert "secret" not in store.location and "***" in store.location
    with pytest.raises(InputError) as caught:
        store.entries("X-1")
    assert "secret" not in str(caught.value) and "cannot connect" in str(caught.value)
    env = dict(os.environ, STABLEINS_HISTORY=url)
    argv = [sys.executable, "-m", "stableins.cli", "history", "--fleet"]
    done = subprocess.run(argv, capture_output=True, text=True, env=env, timeout=60)
    assert done.returncode == 2 and "secret" not in done.stderr and "Traceback" not in done.stderr


def test_the_schema_is_sqlites_table_for_table_and_column_for_column(server, tmp_path):
    import sqlite3

    import psycopg

    url = server.database()
    path = tmp_path / "one.json"
    record("PG-2", 1).save(path)
    HistoryStore(url).add(path)
    HistoryStore(tmp_path / "store").add(path)
    lite = sqlite3.connect(tmp_path / "store" / "history.sqlite")
    tables = [r[0] for r in lite.execute("SELECT name FROM sqlite_master WHERE type = 'table' ORDER BY name")]
    sqlite_columns = {t: [r[1] for r in lite.execute(f"PRAGMA table_info({t})")] for t in tables}
    with psycopg.connect(url) as connection:
        rows = connection.execute(
            "SELECT table_name, column_name FROM information_schema.columns WHERE table_schema = current_schema() "
            "ORDER BY table_name, ordinal_position"
        ).fetchall()
    postgres_columns: dict[str, list[str]] = {}
    for table, column in rows:
        postgres_columns.setdefault(table, []).append(column)
    assert postgres_columns.pop("files") == ["serial", "name", "data"]  # the records' bytes: no shared folder
    assert postgres_columns == sqlite_columns
