"""A recorded run played back: the replay driver of ``--driver replay:RUNDIR``, from the run's journal.

The driver (:class:`stableins.drivers.replay.ReplayDriver`) reads no journal: this module reads the run's
journal (:func:`stableins.procedures.journal.scan`) and hands it the operations that stand (those a resume
superseded and the failed ones left out), each answered from its record when the replay reaches it.
"""

from __future__ import annotations

from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from stableins.drivers.base import PlatformDriver
from stableins.drivers.replay import RecordedOperation, ReplayDriver
from stableins.drivers.select import open_driver
from stableins.errors import InputError
from stableins.procedures.journal import Record, block_from_record, journal_path, live_operations, metadata_from_start, scan

#: The prefix of a ``--driver`` specification that replays a recorded run.
REPLAY_PREFIX = "replay:"


def replay_driver(path: str | Path) -> ReplayDriver:
    """Return the driver that plays back the run recorded in ``path`` (a run directory or its journal file).

    Raises
    ------
    InputError
        The journal has no start record.
    """
    path = journal_path(path)
    records = scan(path).records
    if not records or records[0].kind != "start":
        raise InputError("the journal has no start record", path=path, expected="a journal written by 'stableins run'")
    operations = [
        RecordedOperation(r["operation"], tuple(r["arguments"]), partial(_answer, r), r.seq)
        for r in live_operations(records)
        if not r.get("error")
    ]
    return ReplayDriver(metadata_from_start(records[0]), operations, path)


def _answer(record: Record) -> Any:
    """Return the platform's recorded answer to one operation."""
    operation = record["operation"]
    if operation == "command":
        return float(record["result"])
    if operation == "read_angles":
        return np.array(record.arrays["angles"])
    return block_from_record(record)


def open_run_driver(
    spec: str,
    *,
    seed: int | None = None,
    unit: str | None = None,
    sample_rate: float | None = None,
    timeout: float = 10.0,
    truth: Any = None,
) -> PlatformDriver:
    """Open the driver of a run named by ``spec``.

    ``replay:PATH`` plays a recorded run back; every other one is :func:`stableins.drivers.select.open_driver`'s
    (the keywords are its own; a replay takes none of them).
    """
    if spec.startswith(REPLAY_PREFIX) and truth is None:
        return replay_driver(spec[len(REPLAY_PREFIX) :])
    return open_driver(spec, seed=seed, unit=unit, sample_rate=sample_rate, timeout=timeout, truth=truth)
