"""kill -9 at seeded points, resume, compare sample for sample with an uninterrupted run of the same seed.

``stableins run`` drives the simulated platform in its own process.  In the first test the process kills itself
with SIGKILL once its journal holds a seeded number of records (the journal's test hook,
``STABLEINS_KILL_AFTER_RECORDS``): the kill points do not depend on how fast the machine is, so the test interrupts
the run the same number of times under any load (issue 31: a 1-ms polling parent missed its targets under load).
Every other kill also tears the journal's last record (a write cut short, as a crash mid-write leaves it); the
resume must drop it and repeat what it held.  The resumed run (which may be killed too) must give the samples of
the uninterrupted run, bit for bit.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys

import numpy as np

from stableins.data.device import load_device
from stableins.procedures.entries import journal_columns
from stableins.procedures.journal import KILL_AFTER_ENV, scan
from tests.runner_fixtures import SIM_CHECKS, SMALL_MOVES, short_plan
from tests.tcp_fixtures import ROOT


def _launch(mode, rundir, seed, plan, *, kill_after=None):
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    if kill_after is not None:
        env[KILL_AFTER_ENV] = str(kill_after)
    if mode == "start":
        argv = ["run", str(plan), "--driver", "sim", "--seed", str(seed), "--unit", "KILL-1", "--out", str(rundir), "--yes", "--quiet"]
    else:
        argv = ["run", "--resume", str(rundir), "--yes", "--quiet"]
    command = [sys.executable, "-m", "stableins.cli", *argv]
    return subprocess.Popen(command, cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)


def _count(journal):
    if not journal.exists():
        return 0
    try:
        return len(scan(journal).records)
    except Exception:  # a header half-written at this instant
        return 0


def test_kill_9_resume_equals_uninterrupted(tmp_path):
    seed = 21
    plan = tmp_path / "plan.json"
    plan.write_text(json.dumps(short_plan(chunk=0.5, checks=SIM_CHECKS, positions=SMALL_MOVES).to_dict()))
    reference = tmp_path / "reference"
    process = _launch("start", reference, seed, plan)
    assert process.wait(timeout=120) == 0, process.stderr.read()
    process.stderr.close()
    expected = load_device(reference / "device.h5").columns

    rng = np.random.default_rng(2024)
    rundir = tmp_path / "killed"
    journal = rundir / "journal.bin"
    mode, kills, torn = "start", 0, 0
    for _ in range(40):  # bounded: each round either finishes or is killed after making progress
        before = _count(journal)
        target = before + int(rng.integers(2, 15))  # the process kills itself once this many records are on disk
        process = _launch(mode, rundir, seed, plan, kill_after=target)
        code = process.wait(timeout=300)
        message = process.stderr.read()
        process.stderr.close()
        if code == -signal.SIGKILL:
            kills += 1
            assert _count(journal) == target  # killed right after the target record reached the disk
            if kills % 2 == 0 and target >= 2:  # a write cut short: the last record loses its tail
                size = journal.stat().st_size
                os.truncate(journal, size - int(rng.integers(1, 9)))
                assert scan(journal).torn_bytes > 0
                torn += 1
            mode = "resume"
            continue
        assert code == 0, message
        break
    else:
        raise AssertionError("the run never finished")
    assert kills >= 3, "the kills should interrupt the run several times"
    assert torn >= 1, "a torn last record should be resumed from"
    records = scan(journal).records
    assert sum(r.kind == "complete" for r in records) == 1
    assert sum(r.kind == "resume" for r in records) >= 1
    got = load_device(rundir / "device.h5").columns
    for name in expected:
        np.testing.assert_array_equal(got[name], expected[name], err_msg=name)
    # the journal alone says the same (every step accepted exactly once)
    from_journal = journal_columns(records)
    np.testing.assert_array_equal(from_journal["f_z"], expected["f_z"])
    accepted = [r["step"] for r in records if r.kind == "verdict" and r["accepted"]]
    assert sorted(accepted) == sorted(set(accepted))


def test_kill_9_over_the_network_loses_and_duplicates_nothing(tmp_path):
    """A real platform cannot be rewound: the killed attempt is repeated, never stitched, never counted twice."""
    from stableins.data.device import load_device
    from tests.tcp_fixtures import ServerProcess

    plan = tmp_path / "plan.json"
    plan.write_text(json.dumps(short_plan(chunk=0.5, checks=SIM_CHECKS, positions=SMALL_MOVES, person=False).to_dict()))
    rundir = tmp_path / "net"
    journal = rundir / "journal.bin"
    rng = np.random.default_rng(7)
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    with ServerProcess(seed=3, simulator=True, unit="NET-K") as server:
        spec = f"tcp://127.0.0.1:{server.port}"
        kills = 0
        for _ in range(20):
            if journal.exists():
                argv = ["run", "--resume", str(rundir), "--yes", "--quiet"]
            else:
                argv = ["run", str(plan), "--driver", spec, "--unit", "NET-K", "--out", str(rundir), "--yes", "--quiet"]
            before = _count(journal)
            target = before + int(rng.integers(3, 20))  # the process kills itself once this many records are on disk
            killing = dict(env, **{KILL_AFTER_ENV: str(target)}) if kills < 4 else env
            process = subprocess.Popen(
                [sys.executable, "-m", "stableins.cli", *argv], cwd=ROOT, env=killing, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE
            )
            code = process.wait(timeout=300)
            message = process.stderr.read()
            process.stderr.close()
            if code == -signal.SIGKILL:
                kills += 1
                continue
            assert code == 0, message
            break
        else:
            raise AssertionError("the run never finished")
    assert kills >= 2, "the kills should interrupt the run"
    records = scan(journal).records
    resumes = [r for r in records if r.kind == "resume"]
    assert resumes and all(not r["deterministic"] for r in resumes)
    data = load_device(rundir / "device.h5")
    dwells = data.dwells()
    assert [d.position for d in dwells] == [1, 2, 3, 4, 5, 6]  # each position once
    assert all(len(d) == 200 for d in dwells)  # whole dwells, never stitched across a kill
    assert all(np.all(np.diff(d.time) > 0) and np.ptp(np.diff(d.time)) < 1e-9 for d in dwells)  # contiguous
    np.testing.assert_array_equal(journal_columns(records)["f_x"], data.columns["f_x"])


def test_killed_while_writing_outputs_resume_writes_them(tmp_path):
    """Killed after the last step's ``complete`` record but before the outputs were written: resume writes them from
    the journal (sample for sample those of the run) and journals the run as finished; a second resume says finished."""
    plan = tmp_path / "plan.json"
    plan.write_text(json.dumps(short_plan(chunk=0.5, checks=SIM_CHECKS, positions=SMALL_MOVES).to_dict()))
    rundir = tmp_path / "run"
    process = _launch("start", rundir, 5, plan)
    assert process.wait(timeout=120) == 0, process.stderr.read()
    process.stderr.close()
    journal = rundir / "journal.bin"
    records = scan(journal).records
    assert [r.kind for r in records][-2:] == ["complete", "finished"]
    expected = load_device(rundir / "device.h5").columns
    # the state a kill between 'complete' and the outputs leaves: no 'finished' record, no data set
    with open(journal, "r+b") as handle:
        handle.truncate(records[-1].offset)
    (rundir / "device.h5").unlink()
    process = _launch("resume", rundir, 5, plan)
    assert process.wait(timeout=120) == 0, process.stderr.read()
    process.stderr.close()
    got = load_device(rundir / "device.h5").columns
    for name in expected:
        np.testing.assert_array_equal(got[name], expected[name], err_msg=name)
    kinds = [r.kind for r in scan(journal).records]
    assert kinds.count("complete") == 1 and kinds[-1] == "finished" and "resume" not in kinds
    process = _launch("resume", rundir, 5, plan)
    message = process.stderr.read().decode()
    assert process.wait(timeout=60) == 0 and "is finished" in message, message
    process.stderr.close()
