"""An interrupted field recalibration resumes as a recalibration (issue 27): the console names ``stableins recal --resume
DIR``; that command, or ``stableins run --resume DIR``, files exactly one new record and prints the change table."""

from __future__ import annotations

import io
import json
import re
import shlex
import shutil

from systematic_world import prior_record

from stableins import cli
from stableins.drivers.select import simulated_platform
from stableins.history_store import HistoryStore
from stableins.procedures.definition import resolve
from tests.runner_fixtures import SIM_CHECKS, SMALL_MOVES, short_plan


def _short(name: str, target, *, dwell: float, settle: float):
    """The shipped definition ``name`` with shorter dwells (the test's time), written to ``target``."""
    text = resolve(name).read_text()
    text = re.sub(r"^dwell = .*$", f"dwell = {dwell}", text, count=1, flags=re.M)
    text = re.sub(r"^settle = .*$", f"settle = {settle}", text, count=1, flags=re.M)
    target.write_text(text)
    return target


def _interrupted_recal(tmp_path, capsys, monkeypatch, store, name):
    """A recalibration whose last prompt is answered "n" (its record not written); returns the continuation the console gives."""
    definition = _short("field-recal-device", tmp_path / "recal.toml", dwell=2.0, settle=0.2)
    out = tmp_path / name
    monkeypatch.setattr("sys.stdin", io.StringIO("y\nn\n"))  # confirm the start, decline the last step
    argv = ["recal", definition, "--unit", "SN27", "--store", store, "--driver", "sim", "--seed", "5", "--out", out,
            "--set", "site_temperature=22", "--operator", "A. Tester", "--laboratory", "Lab", "--customer", "Owner"]  # fmt: skip
    assert cli.main(list(map(str, argv))) == 3
    err = capsys.readouterr().err
    match = re.search(r"continue with: (stableins .*)$", err, re.M)
    assert match, err
    assert not (out / "record.json").exists()
    return shlex.split(match.group(1))


def _prior_in_store(tmp_path, capsys, store):
    """The unit's record in force: a device-level record of the simulated unit (seed 5) filed in ``store``."""
    prior_record(simulated_platform(5, "SN27", 100.0).truth).save(tmp_path / "cal.json")
    assert cli.main(["history", "SN27", "--store", str(store), "--add", str(tmp_path / "cal.json")]) == 0
    capsys.readouterr()


def _filed(store, rundir):
    """The store's records of SN27: exactly the record in force and the recalibration's record."""
    entries = HistoryStore(store).entries("SN27")
    assert len(entries) == 2
    assert (store / "SN27" / entries[-1].file).read_bytes() == (rundir / "record.json").read_bytes()


def test_an_interrupted_recal_resumed_as_the_console_says_files_exactly_one_record(tmp_path, capsys, monkeypatch):
    store = tmp_path / "store"
    _prior_in_store(tmp_path, capsys, store)
    command = _interrupted_recal(tmp_path, capsys, monkeypatch, store, "recal")
    # the same interrupted recalibration, its store as it was, for 'stableins run --resume' below
    shutil.copytree(store, tmp_path / "store-before")
    shutil.copytree(tmp_path / "recal", tmp_path / "recal-before")
    # as the console says: stableins recal --resume DIR
    assert command[:3] == ["stableins", "recal", "--resume"] and command[3] == str(tmp_path / "recal")
    assert cli.main([*command[1:], "--yes"]) == 0
    out = capsys.readouterr().out
    assert re.search(r"^sf_x\s", out, re.M) and "field recalibration of SN27" in out, out  # the change table
    _filed(store, tmp_path / "recal")
    assert cli.main([*command[1:], "--yes"]) == 0  # resumed again: finished, nothing filed twice
    assert len(HistoryStore(store).entries("SN27")) == 2
    # the same through 'stableins run --resume DIR' on a recalibration's directory
    shutil.rmtree(store)
    shutil.rmtree(tmp_path / "recal")
    shutil.copytree(tmp_path / "store-before", store)
    shutil.copytree(tmp_path / "recal-before", tmp_path / "recal")
    capsys.readouterr()
    assert cli.main(["run", "--resume", str(tmp_path / "recal"), "--yes"]) == 0
    out = capsys.readouterr().out
    assert re.search(r"^sf_x\s", out, re.M), out
    _filed(store, tmp_path / "recal")
    assert (tmp_path / "recal" / "recal-changes.txt").exists()


def test_recal_resume_of_a_plain_run_names_the_right_command(tmp_path, capsys):
    plan = tmp_path / "plan.json"
    plan.write_text(json.dumps(short_plan(dwell=1.0, checks=SIM_CHECKS, positions=SMALL_MOVES[:2], person=False).to_dict()))
    assert cli.main(["run", str(plan), "--driver", "sim", "--seed", "4", "--out", str(tmp_path / "run"), "--yes", "--quiet"]) == 0
    capsys.readouterr()
    assert cli.main(["recal", "--resume", str(tmp_path / "run"), "--yes"]) == 2
    err = capsys.readouterr().err
    assert "no field recalibration" in err and f"run --resume {tmp_path / 'run'}" in err and "Traceback" not in err
