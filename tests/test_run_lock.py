"""One run per directory (issue 27): the lock is taken before anything is written, a second process is refused with one
message naming the directory and the holder's pid (exit 2), the lock dies with its process (kill -9), and a journal
without its start record is started afresh.

Real processes, synchronized without sleeps: a run waits at a person's prompt (its standard input is a pipe) while
the lock is held; the test reads its console up to the prompt, so it knows the lock is taken.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys

import pytest

from stableins.errors import InputError
from stableins.procedures.journal import FILE_MAGIC, scan
from stableins.procedures.runlock import LOCK_NAME, RunLock
from tests.runner_fixtures import SIM_CHECKS, SMALL_MOVES, short_plan
from tests.tcp_fixtures import ROOT


def _plan(tmp_path):
    plan = tmp_path / "plan.json"
    plan.write_text(json.dumps(short_plan(dwell=1.0, chunk=0.5, checks=SIM_CHECKS, positions=SMALL_MOVES[:2]).to_dict()))
    return plan


def _stableins(*argv, stdin=None):
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    command = [sys.executable, "-m", "stableins.cli", *map(str, argv)]
    return subprocess.Popen(command, cwd=ROOT, env=env, stdin=stdin, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _until(stream, text):
    """Read ``stream`` one character at a time until ``text`` has been read (the process waits for an answer then)."""
    seen = ""
    while not seen.endswith(text):
        c = stream.read(1)
        assert c, f"the process ended before {text!r}: {seen}"
        seen += c
    return seen


def _start_at_prompt(tmp_path, rundir):
    """A run started without --yes, waiting at its first prompt: it holds the lock of ``rundir``."""
    process = _stableins("run", _plan(tmp_path), "--driver", "sim", "--seed", "3", "--out", rundir, "--set", "lab_temperature=21",
                         stdin=subprocess.PIPE)  # fmt: skip
    _until(process.stderr, "[y/n] ")
    return process


def _refused(argv):
    second = _stableins(*argv, stdin=subprocess.DEVNULL)
    out, err = second.communicate(timeout=120)
    return second.returncode, err


def test_a_second_run_on_the_directory_is_refused_naming_it_and_the_running_pid(tmp_path):
    rundir = tmp_path / "run"
    first = _start_at_prompt(tmp_path, rundir)
    try:
        journal_before = (rundir / "journal.bin").read_bytes()
        for argv in (
            ["run", _plan(tmp_path), "--driver", "sim", "--seed", "3", "--out", rundir, "--yes"],
            ["run", "--resume", rundir, "--yes"],
        ):
            status, err = _refused(argv)
            assert status == 2, err
            assert f"pid {first.pid}" in err and str(rundir) in err and "Traceback" not in err
            assert len(err.strip().splitlines()) <= 3, err  # one message (wrapped), no traceback
        assert (rundir / "journal.bin").read_bytes() == journal_before  # the second process wrote nothing
        first.stdin.write("y\n")
        first.stdin.close()
        assert first.wait(timeout=120) == 0, first.stderr.read()
    finally:
        if first.poll() is None:
            first.kill()
        first.stdout.close()
        first.stderr.close()
    kinds = [r.kind for r in scan(rundir / "journal.bin").records]
    assert kinds[0] == "start" and kinds.count("start") == 1 and kinds[-1] == "finished"
    assert not (rundir / LOCK_NAME).exists()  # released (and removed) when the run ended


def test_the_lock_dies_with_a_killed_process_and_the_run_resumes(tmp_path):
    rundir = tmp_path / "run"
    first = _start_at_prompt(tmp_path, rundir)
    os.kill(first.pid, signal.SIGKILL)
    first.wait(timeout=30)
    first.stdout.close()
    first.stderr.close()
    assert (rundir / LOCK_NAME).exists()  # left by the killed process, and no longer locked
    resumed = _stableins("run", "--resume", rundir, "--yes", "--quiet", stdin=subprocess.DEVNULL)
    out, err = resumed.communicate(timeout=120)
    assert resumed.returncode == 0, err
    assert (rundir / "device.h5").exists()


def test_a_journal_without_its_start_record_is_started_afresh(tmp_path):
    rundir = tmp_path / "run"
    rundir.mkdir()
    (rundir / "journal.bin").write_bytes(FILE_MAGIC)  # a run killed in its first half-second by an earlier version: 20 bytes
    (rundir / "journal.bin.4242.new").write_bytes(FILE_MAGIC[:5])  # a start killed before its journal was linked
    status, err = _refused(["run", "--resume", rundir, "--yes"])
    assert status == 2 and "stopped before its first record" in err and "Traceback" not in err, err
    again = _stableins("run", _plan(tmp_path), "--driver", "sim", "--seed", "3", "--out", rundir, "--yes", "--quiet",
                       stdin=subprocess.DEVNULL)  # fmt: skip
    out, err = again.communicate(timeout=120)
    assert again.returncode == 0, err
    assert [r.kind for r in scan(rundir / "journal.bin").records][0] == "start"
    assert not list(rundir.glob("*.new"))


def test_run_lock_in_one_process(tmp_path):
    rundir = tmp_path / "new" / "run"
    with RunLock.acquire(rundir):
        assert (rundir / LOCK_NAME).read_text().startswith(f"pid {os.getpid()},")
        with pytest.raises(InputError, match=f"pid {os.getpid()}") as refused:
            RunLock.acquire(rundir)  # flock is per open file: a second acquisition conflicts even in one process
        assert str(rundir) in refused.value.message
    assert not rundir.exists()  # created for the run, left empty: removed with the lock
    rundir.mkdir(parents=True)
    (rundir / "kept.txt").write_text("x")
    with RunLock.acquire(rundir):
        pass
    assert sorted(p.name for p in rundir.iterdir()) == ["kept.txt"]
