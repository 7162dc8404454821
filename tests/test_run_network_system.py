"""System-level records over the network (issue 27, protocol version 2): the INS's navigation outputs streamed by
``serve-sim`` (``REC``/``NAV``), journaled as they arrive; the same data and the same record as ``--driver sim``; a run
interrupted in the record resumes to identical data; a controller without the capability is told what is missing."""

from __future__ import annotations

import os
import signal
import subprocess
import sys

import pytest
from systematic_world import prior_record

from stableins.console import Console
from stableins.data.system import open_system_record
from stableins.drivers.errors import DriverProtocolError
from stableins.drivers.select import simulated_platform
from stableins.drivers.server import PROTOCOL_VERSION
from stableins.drivers.tcp import connect, parse_greeting
from stableins.procedures.definition import load_procedure, resolve
from stableins.procedures.journal import KILL_AFTER_ENV, scan
from stableins.procedures.planning import plan_from_definition
from stableins.records import CalibrationRecord
from stableins.runs import RunSetup, resume_run, start_run
from tests.tcp_fixtures import ROOT, ServerProcess
from tests.test_run_systematic import SHORT as SYSTEMATIC_2H  # system-indexed with two holds of an hour at 2 Hz

SEED, UNIT, RATE = 5, "NAV-1", 10.0
DRIFT = """
[procedure]
name = "drift-short"
stage = "system"
[record]
settle = 1.0
duration = 300.0
sample_rate = 10.0
[[record.index]]
at = 140.0
axis = "platform"
angle = 180.0
rate = 10.0
[runner]
chunk = 30.0
"""


class Crash(Exception):
    pass


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    folder = tmp_path_factory.mktemp("nav")
    (folder / "drift.toml").write_text(DRIFT)
    prior_record(simulated_platform(SEED, UNIT, RATE).truth).save(folder / "cal.json")
    return folder


def _run(folder, rundir, spec, driver=None, unit=UNIT):
    setup = RunSetup(definition_file=folder / "drift.toml", prior_file=folder / "cal.json")
    plan = plan_from_definition(load_procedure(folder / "drift.toml"))
    console = Console(yes=True, quiet=True)
    return start_run(plan, rundir, driver_spec=spec, seed=SEED, unit=unit, console=console, setup=setup, driver=driver)


def _same_record(a, b):
    data_a, data_b = open_system_record(a).read(), open_system_record(b).read()
    assert set(data_a) == set(data_b)
    for name in data_a:
        assert (data_a[name] == data_b[name]).all(), name


@pytest.mark.slow
def test_drift_test_over_tcp_equals_the_simulated_run_and_resumes_to_identical_data(inputs, tmp_path):
    reference = _run(inputs, tmp_path / "sim", "sim")
    with ServerProcess(seed=SEED, simulator=True, unit=UNIT, rate=RATE, installed=inputs / "cal.json") as server:
        spec = f"tcp://127.0.0.1:{server.port}"
        network = _run(inputs, tmp_path / "tcp", spec)
        # the navigation outputs were journaled chunk by chunk as they arrived
        chunks = [r for r in scan(tmp_path / "tcp" / "journal.bin").records if r.kind == "op" and r["operation"] == "static_chunk"]
        assert len(chunks) == 10 and all(len(c.arrays["velocity_north"]) == 300 for c in chunks)
        _same_record(network.dataset, reference.dataset)
        ours, theirs = CalibrationRecord.load(network.record), CalibrationRecord.load(reference.record)
        for axis in "xyz":  # the stage's record: the same numbers
            assert ours[f"gyro_drift_{axis}"].value == theirs[f"gyro_drift_{axis}"].value
            assert ours[f"gyro_drift_{axis}"].sigma == theirs[f"gyro_drift_{axis}"].sigma
        # a run that dies in the middle of the record (the process, as on kill -9), resumed over the network
        driver = connect(spec)
        chunks_of = driver.static_record

        def dying(duration, chunk, turns=()):
            for k, piece in enumerate(chunks_of(duration, chunk, turns)):
                if k == 4:
                    raise Crash("the process dies here")
                yield piece

        driver.static_record = dying
        with pytest.raises(Crash):
            _run(inputs, tmp_path / "killed", spec, driver=driver)
        driver.close()
        resumed = resume_run(tmp_path / "killed", console=Console(yes=True, quiet=True))
    _same_record(resumed.dataset, reference.dataset)
    kinds = [r.kind for r in scan(tmp_path / "killed" / "journal.bin").records]
    assert "resume" in kinds and kinds[-1] == "finished"


STATIC_DAY = """
[procedure]
name = "system-static-1hz"
stage = "system"
[record]
settle = 1.0
duration = 86400.0
sample_rate = 1.0
[runner]
chunk = 3600.0
"""


@pytest.mark.slow
@pytest.mark.parametrize(
    ("definition", "rate", "parameters"),
    [
        ("drift-two-position", 10.0, ("gyro_drift_x", "gyro_drift_y", "gyro_drift_z")),
        ("drift-three-position", 10.0, ("gyro_drift_x", "gyro_drift_y", "gyro_drift_z")),
        (SYSTEMATIC_2H, 2.0, ("gyro_drift_x", "Dg_zz", "bias_x", "sf_y")),
        (STATIC_DAY, 1.0, ("bias_x", "bias_y", "sf_z", "beta_zx")),
    ],
    ids=["drift-two-position", "drift-three-position", "system-indexed-2h", "system-static-day-1hz"],
)
def test_every_system_level_procedure_over_tcp_ends_with_the_same_record_as_the_simulated_run(tmp_path, definition, rate, parameters):
    if definition.lstrip().startswith("["):
        path = tmp_path / "definition.toml"
        path.write_text(definition)
    else:
        path = resolve(definition)
    prior_record(simulated_platform(SEED, UNIT, rate).truth).save(tmp_path / "cal.json")
    plan = plan_from_definition(load_procedure(path))
    setup = RunSetup(definition_file=path, prior_file=tmp_path / "cal.json")
    outcomes = {}
    with ServerProcess(seed=SEED, simulator=True, unit=UNIT, rate=rate, installed=tmp_path / "cal.json") as server:
        for spec in ("sim", f"tcp://127.0.0.1:{server.port}"):
            name = spec.split(":")[0]
            console = Console(yes=True, quiet=True)
            outcomes[name] = start_run(plan, tmp_path / name, driver_spec=spec, seed=SEED, unit=UNIT, console=console, setup=setup)
    _same_record(outcomes["tcp"].dataset, outcomes["sim"].dataset)
    ours, theirs = CalibrationRecord.load(outcomes["tcp"].record), CalibrationRecord.load(outcomes["sim"].record)
    assert ours.ids == theirs.ids
    for pid in parameters:
        assert (ours[pid].value, ours[pid].sigma) == (theirs[pid].value, theirs[pid].sigma), pid


def test_kill_9_in_the_record_over_tcp_then_resume_gives_identical_data(inputs, tmp_path):
    reference = _run(inputs, tmp_path / "sim", "sim")
    records = scan(tmp_path / "sim" / "journal.bin").records
    chunks = [k for k, r in enumerate(records) if r.kind == "op" and r["operation"] == "static_chunk"]
    kill_after = chunks[4] + 1  # the process dies once the fifth chunk of the record is on disk
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    with ServerProcess(seed=SEED, simulator=True, unit=UNIT, rate=RATE, installed=inputs / "cal.json") as server:
        rundir = tmp_path / "tcp"
        argv = ["run", str(inputs / "drift.toml"), "--driver", f"tcp://127.0.0.1:{server.port}", "--seed", str(SEED), "--unit", UNIT,
                "--prior", str(inputs / "cal.json"), "--out", str(rundir), "--yes", "--quiet"]  # fmt: skip
        killed = subprocess.run([sys.executable, "-m", "stableins.cli", *argv], cwd=ROOT, capture_output=True, text=True,
                                env=env | {KILL_AFTER_ENV: str(kill_after)}, timeout=300)  # fmt: skip
        assert killed.returncode == -signal.SIGKILL, killed.stderr
        assert len(scan(rundir / "journal.bin").records) == kill_after
        resumed = subprocess.run([sys.executable, "-m", "stableins.cli", "run", "--resume", str(rundir), "--yes", "--quiet"], cwd=ROOT,
                                 capture_output=True, text=True, env=env, timeout=300)  # fmt: skip
        assert resumed.returncode == 0, resumed.stderr
    _same_record(rundir / "system.h5", reference.dataset)
    ours, theirs = CalibrationRecord.load(rundir / "record.json"), CalibrationRecord.load(reference.record)
    assert [ours[f"gyro_drift_{a}"].value for a in "xyz"] == [theirs[f"gyro_drift_{a}"].value for a in "xyz"]


def test_a_controller_without_navigation_outputs_is_told_what_is_missing(inputs, tmp_path):
    with ServerProcess(seed=1) as server:  # the test double: no INS outputs, so no NAV in its greeting
        spec = f"tcp://127.0.0.1:{server.port}"
        with pytest.raises(DriverProtocolError, match="without the capability NAV|needs the capability NAV") as refused:
            _run(inputs, tmp_path / "run", spec, unit=None)
    assert f"protocol version {PROTOCOL_VERSION} with capabilities METACRC" in str(refused.value)  # NAV is the one missing
    assert not (tmp_path / "run" / "journal.bin").exists()  # refused before anything moved or was journaled


def test_greetings():
    assert parse_greeting("STABLEINS-PLATFORM 1") == (1, frozenset())
    assert parse_greeting("STABLEINS-PLATFORM 2 NAV") == (2, frozenset({"NAV"}))
    for bad, reason in (
        ("STABLEINS-PLATFORM 3 NAV", "version 3"),
        ("STABLEINS-PLATFORM 1 NAV", "only version 2"),
        ("HELLO", "expected 'STABLEINS-PLATFORM"),
        ("STABLEINS-PLATFORM 2 nav", "upper-case"),
    ):
        with pytest.raises(ValueError, match=reason):
            parse_greeting(bad)
