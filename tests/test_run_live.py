"""Live progress (issue 27): under a real-time platform (``serve-sim --realtime 1``) a dwell reaches the journal and the
console in pieces of at most a second of data while it is recorded, and the arrival wait says what it waits for.

No wall-clock interval is measured: the journal's pieces are judged by their samples' own time stamps, and its growth
during the dwell by the number of distinct states a reader sees while the run is still going.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import subprocess
import sys

import numpy as np

from stableins.console import Console
from stableins.procedures.journal import scan
from stableins.procedures.plan import DwellStep, Plan
from stableins.runs import start_run
from tests.runner_fixtures import SIM_CHECKS
from tests.tcp_fixtures import ROOT, ServerProcess

DWELL = 5.0  # s of real time


def _plan() -> Plan:
    step = DwellStep("hold", "fine", 1, 1, (0.0, 0.0, 0.0), settle=0.5, dwell=DWELL, checks=SIM_CHECKS, why="live test")
    return Plan("live", "device", (step,))  # the default chunk: 1 s


def _dwell_pieces(journal):
    return [r for r in scan(journal).records if r.kind == "op" and r.get("phase") == "dwell"]


def test_the_journal_grows_during_a_real_time_dwell_a_second_at_a_time(tmp_path):
    plan = tmp_path / "plan.json"
    plan.write_text(json.dumps(_plan().to_dict()))
    rundir = tmp_path / "run"
    journal = rundir / "journal.bin"
    with ServerProcess(seed=3, simulator=True, unit="LIVE-1", realtime=1.0) as server:
        env = dict(os.environ, PYTHONPATH=str(ROOT))
        argv = ["run", str(plan), "--driver", f"tcp://127.0.0.1:{server.port}", "--out", str(rundir), "--yes", "--quiet"]
        process = subprocess.Popen([sys.executable, "-m", "stableins.cli", *argv], cwd=ROOT, env=env,
                                   stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)  # fmt: skip
        seen = set()
        while process.poll() is None:  # what a reader of the journal sees while the dwell is recorded
            if journal.exists():
                with contextlib.suppress(Exception):  # a record being written at this instant
                    seen.add(len(_dwell_pieces(journal)))
        assert process.wait() == 0, process.stderr.read()
        process.stderr.close()
    pieces = _dwell_pieces(journal)
    n = len(pieces)
    assert n == int(DWELL)  # one journal record per second of data
    spans = [float(p.arrays["time"][-1] - p.arrays["time"][0]) for p in pieces]
    assert max(spans) <= 1.0  # each holds at most a second of samples (their own time stamps)
    ends = np.array([float(p.arrays["time"][-1]) for p in pieces])
    assert np.all(np.diff(ends) <= 2.0)  # the data reach the journal at least every 2 s of the dwell
    # the journal grew while the dwell went on: a reader saw intermediate states (generous: 2 of the 4 between 0 and 5)
    assert len({k for k in seen if 0 < k < n}) >= 2, sorted(seen)


def test_the_console_follows_the_dwell_and_names_the_arrival_wait(tmp_path):
    out = io.StringIO()
    with ServerProcess(seed=3, simulator=True, unit="LIVE-1", realtime=1.0) as server:
        console = Console(yes=True, out=out, bars=True)
        start_run(_plan(), tmp_path / "run", driver_spec=f"tcp://127.0.0.1:{server.port}", console=console)
    text = out.getvalue()
    assert "slewing: waiting for arrival at (0.0000, 0.0000, 0.0000) deg within 36 arcsec" in text
    # the dwell's bar is redrawn once per second of data (5 updates, then closed), not only at its end
    dwell_updates = [line for line in text.replace("\r", "\n").split("\n") if line.strip().startswith("dwell")]
    assert len(dwell_updates) >= int(DWELL), text
