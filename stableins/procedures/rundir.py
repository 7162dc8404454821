"""A run directory: start a run, resume it, and write what it produced.

Layout of ``RUNDIR`` (see ``docs/procedures.md``)::

    journal.bin       every operation and decision, append-only (the ground truth of the run)
    procedure.json    the plan that runs (also in the journal's start record)
    device.csv        accepted dwells in the device-level data format read by ``stableins calibrate``
    record.json       the calibration record, once the estimation has run
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from stableins import __version__
from stableins.data.errors import InputError
from stableins.data.metadata import SiteMetadata
from stableins.drivers.base import PlatformDriver
from stableins.drivers.replay import JOURNAL_NAME, metadata_from_start
from stableins.drivers.select import is_deterministic, open_driver
from stableins.procedures.journal import Journal
from stableins.procedures.plan import Plan
from stableins.procedures.runner import Console, Runner, RunOptions, Session, accepted_columns, resume_script

DATASET_NAME = "device.csv"
PLAN_NAME = "procedure.json"


@dataclass
class RunOutcome:
    """What a finished run left in its directory."""

    rundir: Path
    runner: Runner
    dataset: Path | None
    replayed: int
    superseded: tuple[int, int] | None = None


def start_run(
    plan: Plan,
    rundir: str | os.PathLike[str],
    *,
    driver_spec: str,
    seed: int | None = None,
    unit: str | None = None,
    console: Console | None = None,
    options: RunOptions | None = None,
    driver: PlatformDriver | None = None,
) -> RunOutcome:
    """Start a new run of ``plan`` in ``rundir`` (which must not hold a journal yet)."""
    rundir = Path(rundir)
    console = console or Console()
    journal_file = rundir / JOURNAL_NAME
    if journal_file.exists():
        raise InputError(
            "this run directory already holds a run", path=rundir, expected="a new directory, or 'stableins run --resume RUNDIR'"
        )
    driver = driver or open_driver(driver_spec, seed=seed, unit=unit, sample_rate=plan.sample_rate)
    try:
        metadata = driver.metadata
        if unit is not None and metadata.serial_number != unit:
            raise InputError(f"the platform reports unit {metadata.serial_number!r}", field="--unit", expected=repr(unit))
        journal = Journal.create(journal_file)
        with journal:
            journal.append(
                "start",
                {
                    "version": __version__,
                    "plan": plan.to_dict(),
                    "driver": driver_spec,
                    "seed": seed,
                    "unit": metadata.serial_number,
                    "metadata": metadata.to_dict(),
                    "deterministic": is_deterministic(driver),
                    "options": vars(options or RunOptions()),
                },
            )
            _write_plan(rundir, plan)
            console.say(f"run of {plan.name!r} on unit {metadata.serial_number} ({driver_spec}) in {rundir}")
            runner = Runner(plan, Session(journal, [], driver, forward=False), console, options)
            runner.execute()
            dataset = export(rundir, runner, metadata)
        return RunOutcome(rundir, runner, dataset, 0)
    finally:
        driver.close()


def resume_run(
    rundir: str | os.PathLike[str],
    *,
    console: Console | None = None,
    driver_spec: str | None = None,
    driver_factory: Callable[[dict[str, Any]], PlatformDriver] | None = None,
) -> RunOutcome:
    """Continue the run in ``rundir`` where it stopped.

    ``driver_spec`` may replace the journaled one for a network platform that moved
    (``tcp://`` to ``tcp://``); the simulated platform is rebuilt from the journaled seed.
    """
    rundir = Path(rundir)
    console = console or Console()
    journal = Journal.open(rundir / JOURNAL_NAME)
    with journal:
        if not journal.records or journal.records[0].kind != "start":
            raise InputError(
                "the journal holds no start record: nothing to resume", path=journal.path, expected="a run started with 'stableins run'"
            )
        start = journal.records[0]
        plan = Plan.from_dict(start["plan"])
        spec = start["driver"]
        if driver_spec is not None and driver_spec != spec:
            if not (driver_spec.startswith("tcp://") and spec.startswith("tcp://")):
                raise InputError(
                    f"this run was made with --driver {spec}",
                    field="--driver",
                    expected=f"{spec} (only a tcp:// address may change on resume)",
                )
            spec = driver_spec
        if journal.recovered is not None:
            torn = journal.recovered
            console.say(f"journal: dropped a torn last record ({torn.torn_bytes} bytes, {torn.torn_reason}) left by the interruption")
        driver = (
            driver_factory(start.fields)
            if driver_factory
            else open_driver(spec, seed=start["seed"], unit=start["unit"], sample_rate=plan.sample_rate)
        )
        try:
            metadata = driver.metadata
            if metadata.serial_number != start["unit"]:
                raise InputError(
                    f"the platform reports unit {metadata.serial_number!r}, this run is of unit {start['unit']!r}", field="--driver"
                )
            deterministic = is_deterministic(driver)
            script, superseded = resume_script(journal.records, deterministic)
            journal.append(
                "resume", {"superseded": list(superseded) if superseded else None, "deterministic": deterministic, "driver": spec}
            )
            how = "continuing exactly where it stopped" if deterministic else "repeating the interrupted attempt from its command"
            console.say(f"resuming {plan.name!r} on unit {start['unit']}: {len(script)} journaled records to replay, then {how}")
            runner = Runner(plan, Session(journal, script, driver, forward=deterministic), console, RunOptions(**start.get("options", {})))
            runner.execute()
            replayed = runner.session.replayed
            dataset = export(rundir, runner, metadata_from_start(start) if not hasattr(metadata, "to_dict") else metadata)
        finally:
            driver.close()
    return RunOutcome(rundir, runner, dataset, replayed, superseded)


def export(rundir: Path, runner: Runner, metadata: SiteMetadata) -> Path | None:
    """Write the accepted dwells in the device-level data format (atomically); ``None`` if there are none."""
    columns = accepted_columns(runner.entries)
    if not len(columns["time"]):
        return None
    extra = dict(metadata.extra)
    extra.update(procedure=runner.plan.name, inputs=dict(runner.inputs))
    metadata = SiteMetadata(**{**metadata.__dict__, "extra": extra})
    try:
        from stableins.data.device import save_device
    except ImportError:  # the data-format writers are not installed: the samples stay in the journal only
        runner.console.say("note: no device-level data writer in this installation; the accepted samples are in journal.bin")
        return None
    return save_device(rundir / DATASET_NAME, columns, metadata)


def _write_plan(rundir: Path, plan: Plan) -> None:
    from stableins.data.atomic import atomic_write

    with atomic_write(rundir / PLAN_NAME) as handle:
        json.dump(plan.to_dict(), handle, indent=2)
