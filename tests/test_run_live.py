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
import re
import subprocess
import sys

import numpy as np
import pytest

from stableins.console import Console
from stableins.conventions import ARCSEC, EARTH_RATE
from stableins.data.device import load_device
from stableins.procedures.definition import load_procedure, resolve
from stableins.procedures.journal import scan
from stableins.procedures.plan import DwellStep, Plan
from stableins.procedures.planning import plan_from_definition
from stableins.procedures.quicklook import QuickLook
from stableins.runs import RunSetup, start_run
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


def _record(hours: float, rate: float, *, gap_at: float | None = None, runaway: float = 0.0):
    """Synthetic INS outputs: v_N = 0.01 + 0.02 cos Ωt − 0.005 sin Ωt + noise; the platform reading turns at the Earth rate
    (plus ``runaway`` rad/s); one sample interval of 10 s at ``gap_at``."""
    rng = np.random.default_rng(27)
    t = np.arange(0.0, hours * 3600.0, 1.0 / rate)
    if gap_at is not None:
        t = t[(t < gap_at) | (t >= gap_at + 10.0)]
    w = EARTH_RATE * t
    return {
        "time": t,
        "velocity_north": 0.01 + 0.02 * np.cos(w) - 0.005 * np.sin(w) + 1e-3 * rng.standard_normal(len(t)),
        "velocity_east": 0.003 * np.sin(w) + 1e-3 * rng.standard_normal(len(t)),
        "angle_platform": 0.1 + (EARTH_RATE + runaway) * t,
        "angle_inner": np.full(len(t), 0.2),
        "angle_middle": np.full(len(t), -0.3),
    }


def _chunks(columns, size):
    for k in range(0, len(columns["time"]), size):
        yield {name: values[k : k + size] for name, values in columns.items()}


def test_quick_look_sees_the_harmonics_gaps_and_a_platform_that_left_its_orientation():
    columns = _record(48.0, 0.05)
    look = QuickLook(0.05, 20 * ARCSEC)
    for chunk in _chunks(columns, 360):
        look.update(chunk)
    amplitude, residual = look.harmonics()
    assert abs(amplitude[0] - np.hypot(0.02, 0.005)) < 3e-4 and abs(amplitude[1] - 0.003) < 3e-4
    assert np.all(np.abs(residual - 1e-3) < 1e-4)  # the noise
    whole = QuickLook(0.05, 20 * ARCSEC)
    whole.update(columns)  # chunk by chunk = at once
    np.testing.assert_allclose(whole.harmonics()[0], amplitude, rtol=1e-9)
    text = look.describe()
    assert "quick look at 47.99 h (8640 samples)" in text and "no gaps" in text and "orientation held" in text and "ANOMALY" not in text
    gapped = QuickLook(0.05, 20 * ARCSEC)
    for chunk in _chunks(_record(2.0, 0.05, gap_at=3000.0), 50):
        gapped.update(chunk)
    assert "ANOMALY: 1 gap(s), longest 40 s" in gapped.describe()  # 20-s samples: the hole takes the one at 3000 s
    runaway = QuickLook(0.05, 20 * ARCSEC)
    runaway.update(_record(1.0, 0.05, runaway=0.01 * ARCSEC))  # 36″ beyond the Earth's turn in an hour
    assert "ANOMALY: the platform left its orientation" in runaway.describe()


def test_a_static_record_prints_its_quick_look_while_it_records(tmp_path):
    definition = tmp_path / "short.toml"
    definition.write_text('[procedure]\nname = "s"\nstage = "system"\n[record]\nsettle = 0.0\nduration = 200.0\nsample_rate = 10.0\n'
                          '[runner]\nchunk = 25.0\n')  # fmt: skip
    out = io.StringIO()
    plan = plan_from_definition(load_procedure(definition))
    start_run(plan, tmp_path / "run", driver_spec="sim", seed=2, console=Console(yes=True, out=out))
    looks = [line for line in out.getvalue().splitlines() if "quick look at" in line]
    assert len(looks) == 8 and "(2000 samples)" in looks[-1] and "orientation held" in looks[-1], out.getvalue()


@pytest.mark.slow
def test_the_coarse_iterations_dwells_are_journaled_a_second_at_a_time_with_the_same_samples(tmp_path):
    text = resolve("device-coarse").read_text()
    text = re.sub(r"^dwell = .*$", "dwell = 3.0", text, count=1, flags=re.M)
    text = re.sub(r"^settle = .*$", "settle = 0.5", text, count=1, flags=re.M)
    definition = tmp_path / "coarse.toml"
    definition.write_text(text)
    columns = {}
    for chunk in (1.0, 10.0):
        plan = plan_from_definition(load_procedure(definition), chunk=chunk)
        outcome = start_run(plan, tmp_path / f"chunk{chunk:g}", driver_spec="sim", seed=6, console=Console(yes=True, quiet=True),
                            setup=RunSetup(definition_file=definition))  # fmt: skip
        columns[chunk] = load_device(outcome.dataset).columns
        pieces = [r["arguments"][0] for r in scan(tmp_path / f"chunk{chunk:g}" / "journal.bin").records if r.get("operation") == "acquire"]
        assert max(pieces) == min(chunk, 3.0)
    for name in columns[1.0]:  # the pieces change what is journaled when, not the samples
        np.testing.assert_array_equal(columns[1.0][name], columns[10.0][name], err_msg=name)
