"""The runner over the network driver against 'stableins serve-sim' in another process: link faults, resume, no data lost."""

from __future__ import annotations

import io

import numpy as np
import pytest

from stableins.console import Console
from stableins.data.device import load_device
from stableins.drivers.tcp import TcpDriver
from stableins.procedures.entries import journal_columns
from stableins.procedures.journal import scan
from stableins.procedures.runner import RunStopped
from stableins.runs import RunSetup, resume_run, start_run
from tests.runner_fixtures import SIM_CHECKS, SMALL_MOVES, short_plan
from tests.tcp_fixtures import FaultyRelay, ServerProcess

PLAN = short_plan(chunk=0.5, checks=SIM_CHECKS, positions=SMALL_MOVES, person=False)


@pytest.fixture
def server():
    with ServerProcess(seed=4, simulator=True, unit="NET-1") as s:
        yield s


def _check_complete(rundir, samples_per_dwell):
    records = scan(rundir / "journal.bin").records
    data = load_device(rundir / "device.h5")
    dwells = data.dwells()
    assert [d.position for d in dwells] == [1, 2, 3, 4, 5, 6]
    assert all(len(d) == samples_per_dwell for d in dwells)  # whole dwells only, never stitched
    np.testing.assert_array_equal(journal_columns(records)["f_y"], data.columns["f_y"])
    accepted = [r["step"] for r in records if r.kind == "verdict" and r["accepted"]]
    assert sorted(accepted) == [0, 1, 2, 3, 4, 5]  # each exactly once
    return records, data


def test_disconnect_in_the_middle_of_a_dwell_repeats_the_step(server, tmp_path):
    with FaultyRelay(server.port, fault=("cut", 60_000)) as relay:
        driver = TcpDriver("127.0.0.1", relay.port, timeout=5, reconnect_delay=0.05)
        out = io.StringIO()
        start_run(
            PLAN,
            tmp_path / "run",
            driver_spec=f"tcp://127.0.0.1:{relay.port}",
            unit="NET-1",
            console=Console(yes=True, out=out),
            driver=driver,
        )
    text = out.getvalue()
    assert "link failure" in text and "repeating the step" in text
    records, _ = _check_complete(tmp_path / "run", 200)
    interrupted = [r for r in records if r.kind == "interrupted"]
    assert len(interrupted) == 1 and "interrupted after" in interrupted[0]["reason"]
    failed = [r for r in records if r.kind == "op" and r.get("error")]
    assert len(failed) == 1 and failed[0]["error_type"] == "AcquisitionInterrupted"


def test_garbage_stops_after_the_allowed_link_failures_then_resumes(server, tmp_path):
    from stableins.procedures.runner import RunOptions

    class Garbled(TcpDriver):
        """Every acquisition of the third position comes back corrupted (as from a broken cable)."""

        def acquire(self, duration):
            block = super().acquire(duration)
            if self.garble and np.allclose(self.last, SMALL_MOVES[2]):
                from stableins.drivers.errors import DriverProtocolError

                raise DriverProtocolError("sample line 'S 1.0 #.2' is garbage")
            return block

        def command(self, readings):
            self.last = readings
            return super().command(readings)

    driver = Garbled("127.0.0.1", server.port, timeout=5)
    driver.garble = True
    with pytest.raises(RunStopped, match="failed 2 times in a row"):
        start_run(
            PLAN,
            tmp_path / "run",
            driver_spec=f"tcp://127.0.0.1:{server.port}",
            unit="NET-1",
            console=Console(yes=True, quiet=True),
            driver=driver,
            setup=RunSetup(options=RunOptions(link_failures=2)),
        )
    # the cable is fixed: resume on the same platform (not re-simulated: it is a real link)
    outcome = resume_run(tmp_path / "run", console=Console(yes=True, quiet=True), driver_spec=f"tcp://127.0.0.1:{server.port}")
    assert outcome.replayed > 0
    _check_complete(tmp_path / "run", 200)


class Crash(Exception):
    pass


def test_crash_then_resume_over_the_network_supersedes_the_unfinished_attempt(server, tmp_path):
    class Crashing(TcpDriver):
        def acquire(self, duration):
            self.count += 1
            if self.count == 17:
                raise Crash("power lost")
            return super().acquire(duration)

    driver = Crashing("127.0.0.1", server.port, timeout=5)
    driver.count = 0
    spec = f"tcp://127.0.0.1:{server.port}"
    with pytest.raises(Crash):
        start_run(PLAN, tmp_path / "run", driver_spec=spec, unit="NET-1", console=Console(yes=True, quiet=True), driver=driver)
    before = scan(tmp_path / "run" / "journal.bin").records
    unfinished = [r.seq for r in before if r.kind == "op" and r.seq > max(x.seq for x in before if x.kind != "op")]
    assert unfinished, "the crash should interrupt an attempt"
    outcome = resume_run(tmp_path / "run", console=Console(yes=True, quiet=True), driver_spec=spec)
    assert outcome.superseded == (unfinished[0], unfinished[-1])
    records, _ = _check_complete(tmp_path / "run", 200)
    # nothing was deleted from the journal: the superseded operations are still there
    assert [r.seq for r in records[: len(before)]] == [r.seq for r in before]


def test_wrong_unit_on_the_network(server, tmp_path):
    from stableins.errors import InputError

    driver = TcpDriver("127.0.0.1", server.port, timeout=5)
    with pytest.raises(InputError, match="reports unit 'NET-1'"):
        start_run(PLAN, tmp_path / "run", driver_spec="tcp://x:1", unit="OTHER", console=Console(quiet=True), driver=driver)
    assert not (tmp_path / "run" / "journal.bin").exists()


def test_replay_driver_plays_a_run_back_through_the_same_path(tmp_path):
    from stableins.procedures.replay import open_run_driver

    first = start_run(PLAN, tmp_path / "a", driver_spec="sim", seed=5, unit="R-1", console=Console(yes=True, quiet=True))
    again = start_run(
        PLAN,
        tmp_path / "b",
        driver_spec=f"replay:{tmp_path / 'a'}",
        console=Console(yes=True, quiet=True),
        driver=open_run_driver(f"replay:{tmp_path / 'a'}"),
    )
    a, b = load_device(first.dataset).columns, load_device(again.dataset).columns
    for name in a:
        np.testing.assert_array_equal(a[name], b[name])
    # a different procedure does not silently play back
    from dataclasses import replace

    from stableins.drivers.errors import DriverError

    other = replace(PLAN, steps=PLAN.steps[1:])
    with pytest.raises(DriverError, match="the recording has"):
        start_run(
            other,
            tmp_path / "c",
            driver_spec="replay",
            console=Console(yes=True, quiet=True),
            driver=open_run_driver(f"replay:{tmp_path / 'a'}"),
        )
