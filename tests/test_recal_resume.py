"""An interrupted field recalibration resumes as a recalibration (issue 27): the console names ``stableins recal --resume
DIR``; that command, or ``stableins run --resume DIR``, files exactly one new record and prints the change table."""

from __future__ import annotations

import io
import re
import shlex

from stableins import cli
from stableins.history_store import HistoryStore
from stableins.procedures.definition import resolve


def _short(name: str, target, *, dwell: float, settle: float):
    """The shipped definition ``name`` with shorter dwells (the test's time), written to ``target``."""
    text = resolve(name).read_text()
    text = re.sub(r"^dwell = .*$", f"dwell = {dwell}", text, count=1, flags=re.M)
    text = re.sub(r"^settle = .*$", f"settle = {settle}", text, count=1, flags=re.M)
    target.write_text(text)
    return target


def _interrupted_recal(tmp_path, capsys, monkeypatch, store, name):
    """A recalibration whose last prompt is answered "n" (its record not written); returns the continuation the console gives."""
    definition = _short("field-recal-device", tmp_path / "recal.toml", dwell=5.0, settle=0.5)
    out = tmp_path / name
    monkeypatch.setattr("sys.stdin", io.StringIO("y\nn\n"))  # confirm the start, decline the last step
    argv = ["recal", definition, "--unit", "SN27", "--store", store, "--driver", "sim", "--seed", "5", "--out", out,
            "--set", "site_temperature=22"]  # fmt: skip
    assert cli.main(list(map(str, argv))) == 3
    err = capsys.readouterr().err
    match = re.search(r"continue with: (stableins .*)$", err, re.M)
    assert match, err
    assert not (out / "record.json").exists()
    return shlex.split(match.group(1))


def _prior_in_stores(tmp_path, capsys, stores):
    coarse = _short("device-coarse", tmp_path / "coarse.toml", dwell=5.0, settle=0.5)
    argv = ["run", str(coarse), "--driver", "sim", "--unit", "SN27", "--seed", "4", "--out", str(tmp_path / "coarse"), "--yes", "--quiet"]
    assert cli.main(argv) == 0
    for store in stores:
        assert cli.main(["history", "SN27", "--store", str(store), "--add", str(tmp_path / "coarse" / "record.json")]) == 0
    capsys.readouterr()


def test_an_interrupted_recal_resumed_as_the_console_says_files_exactly_one_record(tmp_path, capsys, monkeypatch):
    stores = [tmp_path / "store1", tmp_path / "store2"]
    _prior_in_stores(tmp_path, capsys, stores)
    # as the console says: stableins recal --resume DIR
    command = _interrupted_recal(tmp_path, capsys, monkeypatch, stores[0], "recal1")
    assert command[:3] == ["stableins", "recal", "--resume"] and command[3] == str(tmp_path / "recal1")
    assert cli.main([*command[1:], "--yes"]) == 0
    out = capsys.readouterr().out
    assert "changed (|z| ≥ 3)" in out or "significant" in out  # the change table of the recalibration
    assert re.search(r"^sf_x\s", out, re.M), out
    entries = HistoryStore(stores[0]).entries("SN27")
    assert len(entries) == 2  # the coarse record and exactly one new record
    assert (stores[0] / "SN27" / entries[-1].file).read_bytes() == (tmp_path / "recal1" / "record.json").read_bytes()
    # resumed again: finished, nothing filed twice
    assert cli.main([*command[1:], "--yes"]) == 0
    assert len(HistoryStore(stores[0]).entries("SN27")) == 2
    # the same through 'stableins run --resume DIR' on a recalibration's directory
    _interrupted_recal(tmp_path, capsys, monkeypatch, stores[1], "recal2")
    assert cli.main(["run", "--resume", str(tmp_path / "recal2"), "--yes"]) == 0
    out = capsys.readouterr().out
    assert re.search(r"^sf_x\s", out, re.M), out
    entries = HistoryStore(stores[1]).entries("SN27")
    assert len(entries) == 2
    assert (stores[1] / "SN27" / entries[-1].file).read_bytes() == (tmp_path / "recal2" / "record.json").read_bytes()
    assert (tmp_path / "recal2" / "recal-changes.txt").exists()


def test_recal_resume_of_a_plain_run_names_the_right_command(tmp_path, capsys):
    coarse = _short("device-coarse", tmp_path / "coarse.toml", dwell=2.0, settle=0.5)
    assert cli.main(["run", str(coarse), "--driver", "sim", "--seed", "4", "--out", str(tmp_path / "run"), "--yes", "--quiet"]) == 0
    capsys.readouterr()
    assert cli.main(["recal", "--resume", str(tmp_path / "run"), "--yes"]) == 2
    err = capsys.readouterr().err
    assert "no field recalibration" in err and f"run --resume {tmp_path / 'run'}" in err and "Traceback" not in err
