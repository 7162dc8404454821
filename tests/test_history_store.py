"""The history store in SQLite (issue 14): concurrent writers, kill -9, tampered records, migration, fleet queries."""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
import multiprocessing
import os
import signal
import sqlite3
import subprocess
import sys
from datetime import timedelta
from pathlib import Path

import numpy as np
import pytest
from fuzzing import make_record

from stableins import cli
from stableins.errors import InputError
from stableins.history import parse_date
from stableins.history_store import STORE_NAME, HistoryStore
from stableins.records import CalibrationRecord

ROOT = Path(__file__).resolve().parents[1]
IDS = ("bias_x", "sf_x")
SIGMA = np.array([2e-5, 5e-6])


def record(serial: str, day: int, values=(1e-4, 1.0)) -> CalibrationRecord:
    """An independent calibration of one fine-stage run whose data end ``day`` days after 2025-01-01."""
    created = (parse_date("2025-01-01") + timedelta(days=day)).isoformat()
    return make_record(serial, created, dict(zip(IDS, values)), dict(zip(IDS, SIGMA)))


def write_records(directory: Path, serial: str, count: int, start_day: int = 0) -> list[Path]:
    directory.mkdir(parents=True, exist_ok=True)
    paths = []
    for k in range(count):
        path = directory / f"{serial}-{k}.json"
        record(serial, start_day + k, values=(1e-4 + k * 1e-7, 1.0)).save(path)
        paths.append(path)
    return paths


def v1_record(serial: str, created: str, bias: float) -> dict:
    """A calibration record as version 1 of the format wrote it (what stores of that version hold)."""
    return {
        "format": "stableins-calibration-record",
        "schema_version": 1,
        "serial_number": serial,
        "parameters": [
            {"id": "bias_x", "value": bias, "unit": "m/s^2", "sigma": 2e-5, "status": "estimated"},
            {"id": "sf_x", "value": 1.0, "unit": "1", "sigma": 5e-6, "status": "estimated"},
        ],
        "covariance": {"ids": ["bias_x", "sf_x"], "unit": "SI", "matrix": [[4e-10, 0.0], [0.0, 2.5e-11]]},
        "provenance": {
            "software": "stableins 0.1.0",
            "procedure": "device-fine",
            "stages": ["fine"],
            "inputs": [],
            "created": created,
            "data_start": created,
            "data_end": created,
        },  # fmt: skip
        "site": None,
        "determined": [],
        "notes": [],
    }


def consistent(store: HistoryStore) -> None:
    """The index passes SQLite's integrity check and every indexed file has the digest the index holds."""
    assert store.verify() == []
    for serial in store.serials():
        for entry in store.entries(serial):
            store.load(serial, entry)


def _file(args: tuple[str, str]) -> None:
    root, path = args
    HistoryStore(root).add(path)


def test_eight_concurrent_writers_lose_nothing(tmp_path):
    """8 processes file 8 different records at once into a fresh store, several times: every entry is kept."""
    context = multiprocessing.get_context("fork")
    for trial in range(3):
        store = tmp_path / f"store{trial}"
        paths = write_records(tmp_path / f"records{trial}", "INS-8", 8)
        workers = [context.Process(target=_file, args=((str(store), str(p)),)) for p in paths]
        for w in workers:
            w.start()
        for w in workers:
            w.join(60)
        assert [w.exitcode for w in workers] == [0] * 8
        entries = HistoryStore(store).entries("INS-8")
        assert sorted(e.sha256 for e in entries) == sorted(hashlib.sha256(p.read_bytes()).hexdigest() for p in paths)
        consistent(HistoryStore(store))


def test_four_simultaneous_history_add_commands_keep_all_four(tmp_path):
    paths = write_records(tmp_path / "r", "INS-4", 4)
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    argv = [sys.executable, "-m", "stableins.cli", "history", "INS-4", "--store", str(tmp_path / "store"), "--add"]
    processes = [subprocess.Popen([*argv, str(p)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env) for p in paths]
    assert [p.wait(120) for p in processes] == [0] * 4, [p.stderr.read() for p in processes]
    for p in processes:
        p.stderr.close()
    assert len(HistoryStore(tmp_path / "store").entries("INS-4")) == 4


WRITER = """
import os, signal, sys
sys.path.insert(0, {root!r})
from stableins.history_store import HistoryStore
store = HistoryStore({store!r})
replace = os.replace


def dying(source, target, *args, **kwargs):  # the filing's file appears (or not) and the process dies before its commit
    if {files_appear!r}:
        replace(source, target, *args, **kwargs)
    os.kill(os.getpid(), signal.SIGKILL)


for k, path in enumerate({paths!r}):
    if k == {killed!r}:
        os.replace = dying  # inside the filing's transaction: its row inserted, not committed
    store.add(path)
    print(path, flush=True)
"""


def test_kill_9_of_a_writer_leaves_the_store_consistent(tmp_path):
    """A writer killed inside a filing's transaction, at a seeded record, before or after the file appears.

    The kill is the writer's own (at its ``os.replace`` of the chosen filing), so it interrupts a filing under any load
    (issue 31: a kill after a random delay never asserted that it interrupted anything).
    """
    rng = np.random.default_rng(14)
    store = HistoryStore(tmp_path / "store")
    filed = 0
    for k in range(4):
        paths = [str(p) for p in write_records(tmp_path / f"batch{k}", "INS-9", 30, start_day=40 * k)]
        killed = int(rng.integers(1, 29))
        script = WRITER.format(root=str(ROOT), store=str(store.root), paths=paths, killed=killed, files_appear=k % 2 == 1)
        process = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        reported = len(process.stdout.read().splitlines())
        assert process.wait(60) == -signal.SIGKILL
        process.stdout.close()
        assert reported == killed  # the kill interrupted the filing of record `killed`, after `killed` were filed
        consistent(store)
        entries = store.entries("INS-9")
        assert len(entries) - filed == reported  # what it said it filed is there; the interrupted filing is not
        filed = len(entries)
        # the record the killed writer was filing is filed normally afterwards (a file left from the kill is rewritten)
        entry = store.add(paths[killed])
        filed += 1
        assert store.entries("INS-9")[-1] == entry and len(store.entries("INS-9")) == filed
        consistent(store)


def test_a_tampered_record_is_refused_with_its_path_and_digest(tmp_path):
    paths = write_records(tmp_path / "r", "INS-7", 2)
    store = HistoryStore(tmp_path / "store")
    for p in paths:
        store.add(p)
    entry = store.entries("INS-7")[1]
    filed = store.root / "INS-7" / entry.file
    document = json.loads(filed.read_text())
    document["parameters"][1]["value"] += 0.01  # sf_x + 0.01, still a valid record
    filed.write_text(json.dumps(document))
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        status = cli.main(["history", "INS-7", "--store", str(store.root)])
    assert status == 2 and str(filed) in err.getvalue() and entry.sha256 in err.getvalue(), err.getvalue()
    assert "changed after it was filed" in err.getvalue()
    with pytest.raises(InputError, match=entry.sha256):
        store.record_path("INS-7", entry)  # what `run --store` and `recal` use as the prior
    assert len(store.verify()) == 1 and str(filed) in store.verify()[0]
    with contextlib.redirect_stderr(io.StringIO()) as verify_err, contextlib.redirect_stdout(io.StringIO()):
        assert cli.main(["history", "--store", str(store.root), "--verify"]) == 2
    assert entry.sha256 in verify_err.getvalue()


def test_a_json_store_is_migrated_on_first_use(tmp_path):
    """A store of the JSON-index version: entries, order, records, digests and prior links are carried over."""
    root = tmp_path / "store"
    unit = root / "INS-3"
    unit.mkdir(parents=True)
    entries = []
    for k in range(3):  # records of that version: schema 1
        created = f"2025-01-0{k + 1}T00:00:00+00:00"
        data = json.dumps(v1_record("INS-3", created, 1e-4 + k * 1e-6)).encode()
        digest = hashlib.sha256(data).hexdigest()
        name = f"2025010{k + 1}T000000Z-{digest[:8]}.json"
        (unit / name).write_bytes(data)
        prior = entries[-1]["sha256"] if entries else ""
        entries.append(
            {
                "file": name,
                "valid_from": created,
                "created": created,
                "sha256": digest,
                "procedure": "device-fine",
                "stages": ["fine"],
                "prior": prior,
                "evidence": "",
            }
        )
    (unit / "index.json").write_text(json.dumps({"format": "stableins-history-index", "serial_number": "INS-3", "entries": entries[::-1]}))
    store = HistoryStore(root)
    migrated = store.entries("INS-3")
    assert [e.sha256 for e in migrated] == [e["sha256"] for e in entries]
    assert migrated[2].prior == entries[1]["sha256"] and migrated[0].prior == ""
    assert not (unit / "index.json").exists() and (unit / "index.json.migrated").exists()
    assert (root / STORE_NAME).exists()
    consistent(store)
    comparison = store.changes("INS-3")[1][2]
    assert len(store.changes("INS-3")) == 2 and comparison.relation == "independent" and len(comparison.changes) == 2
    assert [t.id for t in store.trends("INS-3")] == ["bias_x", "sf_x"]  # the v1 records are read (migrated) as they are

    # an old index whose record no longer matches its digest is not migrated silently
    other = tmp_path / "store2" / "INS-4"
    other.mkdir(parents=True)
    (other / entries[0]["file"]).write_bytes((unit / entries[1]["file"]).read_bytes())
    (other / "index.json").write_text(json.dumps({"format": "stableins-history-index", "entries": [entries[0]]}))
    with pytest.raises(InputError, match=entries[0]["sha256"]):
        HistoryStore(tmp_path / "store2").entries("INS-4")
    assert (other / "index.json").exists()  # left for the person to repair


def test_fleet_which_units_are_due_and_which_drift(tmp_path, capsys):
    store = HistoryStore(tmp_path / "store")
    rng = np.random.default_rng(2)
    for k in range(5):  # steady: noise only
        path = tmp_path / f"steady{k}.json"
        record("STEADY", 400 + 30 * k, values=(1e-4 + rng.normal(0, 2e-5), 1.0 + rng.normal(0, 5e-6))).save(path)
        store.add(path)
    for k in range(5):  # bias drifting 20 σ over the year
        path = tmp_path / f"drift{k}.json"
        record("DRIFTER", 400 + 30 * k, values=(1e-4 + k * 1e-4, 1.0)).save(path)
        store.add(path)
    path = tmp_path / "old.json"
    record("OLD", 0).save(path)
    store.add(path)
    date = parse_date("2026-04-01")
    units = {u.serial: u for u in store.fleet(date, timedelta(days=180))}
    assert set(units) == {"STEADY", "DRIFTER", "OLD"}
    assert units["OLD"].due and not units["STEADY"].due and not units["DRIFTER"].due
    assert [p for p, _ in units["DRIFTER"].drifting] == ["bias_x"] and units["DRIFTER"].drifting[0][1] > 3
    assert units["STEADY"].drifting == () and units["OLD"].records == 1
    # the same drift as the per-unit analysis from the records themselves
    trend = {t.id: t for t in store.trends("DRIFTER")}["bias_x"]
    assert units["DRIFTER"].drifting[0][1] == pytest.approx(trend.significance, rel=1e-12)
    capsys.readouterr()
    assert cli.main(["history", "--store", str(store.root), "--fleet", "--due", "--at", "2026-04-01", "--json"]) == 0
    shown = json.loads(capsys.readouterr().out)["units"]
    assert [u["serial"] for u in shown] == ["OLD"]
    assert cli.main(["history", "--store", str(store.root), "--fleet", "--drifted", "--at", "2026-04-01"]) == 0
    text = capsys.readouterr().out
    assert "DRIFTER" in text and "STEADY" not in text.split("\n", 2)[2]


def test_the_index_refuses_what_is_not_a_stableins_index(tmp_path):
    root = tmp_path / "store"
    root.mkdir()
    (root / STORE_NAME).write_bytes(b"this is not SQLite" * 100)
    with pytest.raises(InputError, match="history index cannot be used"):
        HistoryStore(root).entries("X")
    other = tmp_path / "other"
    other.mkdir()
    with sqlite3.connect(other / STORE_NAME) as connection:
        connection.execute("CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL)")
        connection.execute("INSERT INTO meta VALUES ('format', 'someone-else')")
    with pytest.raises(InputError, match="not a stableins history index"):
        HistoryStore(other).entries("X")
    with pytest.raises(InputError, match="cannot name a history folder"):
        HistoryStore(tmp_path).entries("a/b")
