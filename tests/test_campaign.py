"""Campaigns on Dask: config validation, task identity, resume, and a real scheduler and worker as separate processes.

The distributed test starts ``dask scheduler`` and ``dask worker`` (the executables of this environment) on 127.0.0.1
only, runs a small campaign through ``--scheduler`` and compares its table with the local cluster's, task by task
(timing columns excepted); the processes are always stopped (bounded waits, then kill).
"""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from stableins.campaign.config import Task, load_campaign
from stableins.campaign.execution import run_campaign, task_file
from stableins.campaign.summary import write_outputs
from stableins.cli import main
from stableins.errors import InputError
from stableins.estimators.experiment import PlannedStage
from stableins.procedures.definition import load_procedure
from stableins.procedures.designed import write_procedure

TIMINGS = ("simulate_s", "calibrate_s", "diagnose_s")
BIN = Path(sys.executable).parent


def _short_procedures(directory: Path) -> None:
    """The 18 positions of Wu et al. with 5 s dwells (coarse) and 10 s dwells (fine): a cheap but complete calibration."""
    for name, dwell in (("device-coarse", 5.0), ("device-fine", 10.0)):
        template = load_procedure(name)
        commands = np.array([s.command for s in template.steps])
        stage = PlannedStage(template.stage, commands, np.full(18, dwell), np.full(18, 2.0), 20.0)
        write_procedure(directory / f"short-{template.stage}.toml", template, stage, name=f"short-{template.stage}", source="test")


def _config(directory: Path, devices: int = 2, diagnose: bool = False) -> Path:
    _short_procedures(directory)
    path = directory / "campaign.toml"
    path.write_text(
        f"""[campaign]
name = "small"
first_seed = 11
devices = {devices}
diagnose = {str(diagnose).lower()}

[[procedure]]
name = "short"
coarse = "short-coarse.toml"
fine = "short-fine.toml"
passes = 2

[[noise]]
name = "quartz"
preset = "quartz"

[[hidden]]
name = "none"
""",
        encoding="utf-8",
    )
    return path


def _table(path: Path) -> list[dict[str, str]]:
    with open(path, newline="", encoding="utf-8") as handle:
        return [{k: v for k, v in row.items() if k not in TIMINGS} for row in csv.DictReader(handle)]


def test_task_seed_comes_from_identity_not_order():
    a, b = Task(3, "p", "n", "h"), Task(3, "p", "n", "h")
    assert a.stream_seed == b.stream_seed
    assert Task(4, "p", "n", "h").stream_seed != a.stream_seed
    assert Task(3, "q", "n", "h").stream_seed != a.stream_seed


@pytest.mark.parametrize(
    ("text", "field"),
    [
        ("[campaign]\ndevices = 0\n[[procedure]]\nname='a'\ncoarse='device-coarse'\n[[noise]]\nname='q'\n", "campaign.devices"),
        ("[campaign]\ndevices = 1\n[[procedure]]\nname='a'\ncoarse='device-fine'\n[[noise]]\nname='q'\n", "procedure[0].coarse"),
        (
            "[campaign]\ndevices = 1\n[[procedure]]\nname='a'\ncoarse='device-coarse'\n[[noise]]\nname='q'\npreset='mems'\n",
            "noise[0].preset",
        ),
        (
            "[campaign]\ndevices = 1\n[[procedure]]\nname='a'\ncoarse='device-coarse'\n[[noise]]\nname='q'\n"
            "[[hidden]]\nname='h'\neffects={nope=1.0}\n",
            "hidden[0].effects",
        ),
        ("[campaign]\ndevices = 1\n[[procedure]]\nname='a__b'\ncoarse='device-coarse'\n[[noise]]\nname='q'\n", "procedure[0].name"),
        ("[campaign]\ndevices = 1\n[[noise]]\nname='q'\n", "procedure"),
        ("[campaign]\ndevices = 1\n[[procedure]]\nname='../x'\ncoarse='device-coarse'\n[[noise]]\nname='q'\n", "procedure[0].name"),
        (  # the last seed beyond the range every command admits (issue 31: first_seed = 2**64 - 1 ran)
            "[campaign]\nfirst_seed = 18446744073709551615\ndevices = 1\n[[procedure]]\nname='a'\ncoarse='device-coarse'\n"
            "[[noise]]\nname='q'\n",
            "campaign.first_seed",
        ),
        (  # the simulator's bound on an effect, checked before any task runs (issue 31: failed in a worker)
            "[campaign]\ndevices = 1\n[[procedure]]\nname='a'\ncoarse='device-coarse'\n[[noise]]\nname='q'\n"
            "[[hidden]]\nname='h'\neffects={Kcc_xxy=1e30}\n",
            "hidden[0].effects.Kcc_xxy",
        ),
    ],
)
def test_bad_campaign_file_names_the_field(tmp_path, text, field):
    path = tmp_path / "c.toml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(InputError) as error:
        load_campaign(path)
    assert error.value.field == field


def test_campaign_cli_bad_file_exit_2_and_nothing_written(tmp_path, capsys):
    path = tmp_path / "c.toml"
    path.write_text("[campaign]\ndevices = -1\n", encoding="utf-8")
    assert main(["campaign", str(path), "--out", str(tmp_path / "out"), "--workers", "1"]) == 2
    assert "campaign.devices" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("address", ["ftp://x", "tcp://", "tcp://host", "127.0.0.1:8786", "tcp://h:99999"])
def test_campaign_refuses_a_scheduler_address_before_writing(tmp_path, capsys, address):
    """A malformed ``--scheduler`` is one message naming the option, exit 2, and nothing written (issue 31)."""
    path = tmp_path / "c.toml"
    path.write_text("[campaign]\ndevices = 1\n[[procedure]]\nname='a'\ncoarse='device-coarse'\n[[noise]]\nname='q'\n")
    assert main(["campaign", str(path), "--out", str(tmp_path / "out"), "--scheduler", address]) == 2
    err = capsys.readouterr().err
    assert "--scheduler" in err and "tcp://HOST:PORT" in err and "Traceback" not in err
    assert not (tmp_path / "out").exists()


def test_campaign_with_no_scheduler_answering_writes_nothing(tmp_path, capsys, monkeypatch):
    """A well-formed address where nothing listens: exit 2 naming ``--scheduler``; the directory is not claimed."""
    import socket

    import stableins.campaign.execution

    monkeypatch.setattr(stableins.campaign.execution, "CONNECT_TIMEOUT", 1.0)  # nothing answers: no need to wait 30 s

    with socket.socket() as probe:  # a port nothing listens on: bound, never listening
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
        path = tmp_path / "c.toml"
        path.write_text("[campaign]\ndevices = 1\n[[procedure]]\nname='a'\ncoarse='device-coarse'\n[[noise]]\nname='q'\n")
        code = main(["campaign", str(path), "--out", str(tmp_path / "out"), "--scheduler", f"tcp://127.0.0.1:{port}"])
    assert code == 2
    assert "--scheduler" in capsys.readouterr().err
    assert not (tmp_path / "out" / "campaign.json").exists() and not (tmp_path / "out" / "tasks").exists()


def _stop(process: subprocess.Popen) -> None:
    if process.poll() is None:
        process.send_signal(signal.SIGINT)
        try:
            process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait(timeout=10)


def _wait_for(path: Path, processes: list[subprocess.Popen], timeout: float = 60.0) -> dict:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if path.exists():
            try:
                return json.loads(path.read_text(encoding="utf-8"))
            except ValueError:
                pass
        if any(p.poll() is not None for p in processes):
            raise RuntimeError("a dask process ended before the scheduler was up")
        time.sleep(0.2)
    raise TimeoutError(f"no scheduler file {path} within {timeout} s")


def test_distributed_scheduler_and_worker_give_the_local_table_and_resume(tmp_path):
    config_path = _config(tmp_path)
    config = load_campaign(config_path)
    assert main(["campaign", str(config_path), "--out", str(tmp_path / "local"), "--workers", "1", "--no-plot"]) == 0
    local = _table(tmp_path / "local" / "results.csv")
    assert len(local) == 2 * 18 and {r["seed"] for r in local} == {"11", "12"}

    scheduler_file = tmp_path / "scheduler.json"
    env = {**os.environ, "DASK_DISTRIBUTED__WORKER__DAEMON": "False"}
    processes: list[subprocess.Popen] = []
    try:
        processes.append(
            subprocess.Popen(
                [
                    str(BIN / "dask"),
                    "scheduler",
                    "--host",
                    "127.0.0.1",
                    "--port",
                    "0",
                    "--no-dashboard",
                    "--scheduler-file",
                    str(scheduler_file),
                ],
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
                env=env,
                cwd=tmp_path,
            )
        )
        address = _wait_for(scheduler_file, processes)["address"]
        assert address.startswith("tcp://127.0.0.1:")
        processes.append(
            subprocess.Popen(
                [
                    str(BIN / "dask"),
                    "worker",
                    address,
                    "--host",
                    "127.0.0.1",
                    "--nworkers",
                    "1",
                    "--nthreads",
                    "1",
                    "--no-dashboard",
                    "--death-timeout",
                    "60",
                ],
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
                env=env,
                cwd=tmp_path,
            )
        )
        out = tmp_path / "distributed"
        command = [str(BIN / "stableins"), "campaign", str(config_path), "--out", str(out), "--scheduler", address, "--no-plot"]
        assert subprocess.run(command, capture_output=True, timeout=180, check=False).returncode == 0
    finally:
        for process in reversed(processes):
            _stop(process)
    assert all(p.poll() is not None for p in processes)
    assert _table(out / "results.csv") == local
    # resume: a task removed is run again, the others are kept as they are
    first = task_file(out, config.tasks()[0])
    kept = task_file(out, config.tasks()[1]).read_bytes()
    first.unlink()
    ran = run_campaign(config, out, workers=1)
    assert (ran.resumed, ran.ran) == (1, 1)
    assert task_file(out, config.tasks()[1]).read_bytes() == kept
    write_outputs(config, out, plot=False)
    assert _table(out / "results.csv") == local


def test_resume_refuses_another_campaign_in_the_directory(tmp_path):
    config_path = _config(tmp_path, devices=1)
    out = tmp_path / "out"
    config = load_campaign(config_path)
    (out / "tasks").mkdir(parents=True)
    (out / "campaign.json").write_text(json.dumps({"digest": "0" * 64}), encoding="utf-8")
    with pytest.raises(InputError) as error:
        run_campaign(config, out, workers=1)
    assert error.value.field == "campaign.json"


def test_a_tasks_diagnosis_reuses_its_calibrations_dwell_statistics_to_the_bit(tmp_path):
    """The session's dwell statistics handed to discovery are those dwells_from_columns makes of the merged rows (issue 30).

    The calibration's own statistics are those of each stage's rows; the clock-free ones are made once for both clocks.
    """
    from dataclasses import fields

    from stableins.campaign.task import _session, _stage_columns, _statistics
    from stableins.data.device import DeviceDataset
    from stableins.discovery.diagnose import DiagnoseOptions, diagnose_data
    from stableins.estimators.dwell import dwells_from_columns
    from stableins.estimators.setting import DeviceSetting
    from stableins.simulator.truth import Truth

    config = load_campaign(_config(tmp_path, devices=1, diagnose=True))
    task = config.tasks()[0]
    spec = config.procedure(task.procedure)
    truth = Truth.draw(task.seed, noise=config.noise(task.noise).settings)
    stages = ["coarse", "fine"]
    columns = {stage: _stage_columns(truth, spec, stage, task.stream_seed + k) for k, stage in enumerate(stages)}
    layouts = {"coarse": spec.coarse.layout, "fine": spec.fine.layout}
    setting = DeviceSetting.from_site(truth.site)
    own, made = _statistics(columns, stages, layouts, setting, session=True)
    merged = _session(columns, stages)
    fresh = dwells_from_columns(merged, layouts=layouts, setting=setting)
    assert len(made) == len(fresh) == 2 * 18 + 18
    alone = [d for stage in stages for d in dwells_from_columns(columns[stage], layouts=layouts, setting=setting)]
    assert [d.start for d in made[36:]] != [d.start for d in alone[36:]]  # the fine stage is on another clock
    for a, b in [*zip(made, fresh, strict=True), *zip([d for stage in stages for d in own[stage]], alone, strict=True)]:
        for f in fields(a):
            x, y = getattr(a, f.name), getattr(b, f.name)
            assert np.array_equal(x, y, equal_nan=True) if isinstance(x, np.ndarray) else x == y or (x != x and y != y), f.name
    record = type("Record", (), {"ids": (), "covariance": np.zeros((0, 0)), "noise_model": None, "values": lambda self: {}})()
    data = [DeviceDataset(truth.site, merged)]
    given = diagnose_data(data, record, layouts=layouts, options=DiagnoseOptions(), summaries=[made])
    again = diagnose_data(data, record, layouts=layouts, options=DiagnoseOptions())
    assert [(c.id, c.statistic, c.p_value, c.flagged) for c in given.ranking.candidates] == [
        (c.id, c.statistic, c.p_value, c.flagged) for c in again.ranking.candidates
    ]
