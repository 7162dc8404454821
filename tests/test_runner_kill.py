"""kill -9 at random points, resume, compare sample for sample with an uninterrupted run of the same seed."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import numpy as np

from stableins.procedures.journal import scan
from stableins.procedures.runner import journal_columns
from tests.tcp_fixtures import ROOT

PACE = 0.01  # seconds of wall time per acquisition: a run takes ~0.6 s, so kills land all over it


def _launch(mode, rundir, seed):
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.Popen(
        [sys.executable, "-m", "tests.runner_fixtures", mode, str(rundir), str(seed), str(PACE)], cwd=ROOT, env=env, stderr=subprocess.PIPE
    )


def _count(journal):
    if not journal.exists():
        return 0
    try:
        return len(scan(journal).records)
    except Exception:  # a header half-written at this instant
        return 0


def _columns(rundir):
    return journal_columns(scan(rundir / "journal.bin").records)


def test_kill_9_resume_equals_uninterrupted(tmp_path):
    seed = 21
    reference = tmp_path / "reference"
    process = _launch("start", reference, seed)
    assert process.wait(timeout=60) == 0, process.stderr.read()
    process.stderr.close()
    expected = _columns(reference)

    rng = np.random.default_rng(2024)
    rundir = tmp_path / "killed"
    journal = rundir / "journal.bin"
    mode, kills = "start", 0
    for _ in range(40):  # bounded: each round either finishes or is killed after making progress
        before = _count(journal)
        process = _launch(mode, rundir, seed)
        target = before + int(rng.integers(1, 12))  # kill once this many records are on disk (a random point)
        deadline = time.monotonic() + 30
        while process.poll() is None and _count(journal) < target and time.monotonic() < deadline:
            time.sleep(0.002)
        if process.poll() is None:
            time.sleep(rng.uniform(0.0, PACE))  # between records too, not only right after one
            os.kill(process.pid, signal.SIGKILL)
            process.wait(timeout=10)
            process.stderr.close()
            kills += 1
            mode = "resume" if journal.exists() else "start"
            continue
        message = process.stderr.read()
        process.stderr.close()
        assert process.returncode == 0, message
        break
    else:
        raise AssertionError("the run never finished")
    assert kills >= 3, "the kills should interrupt the run several times"
    records = scan(rundir / "journal.bin").records
    assert sum(r.kind == "complete" for r in records) == 1
    assert sum(r.kind == "resume" for r in records) >= 1
    got = _columns(rundir)
    for name in expected:
        np.testing.assert_array_equal(got[name], expected[name], err_msg=name)
    # exactly once: every step accepted once, every journaled operation unique in (step, attempt, phase, order)
    accepted = [r["step"] for r in records if r.kind == "verdict" and r["accepted"]]
    assert sorted(accepted) == sorted(set(accepted))
