"""The accepted dwells of a run: from the runner's entries or straight from a journal, as device-level columns.

Also which journal records a resumed run replays (:func:`resume_script`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from stableins.procedures.journal import Record, block_from_record, live_operations
from stableins.procedures.plan import OffsetIterationStep, Plan
from stableins.procedures.session import JournalMismatch
from stableins.samples import SampleBlock
from stableins.schema import DEVICE_COLUMNS


@dataclass(frozen=True, eq=False)
class AcceptedDwell:
    """One accepted dwell of a run: its stage, pass and position, the commanded readings [rad], when [s], its sample blocks."""

    stage: str
    pass_number: int
    position: int
    command: NDArray[np.float64]
    command_time: float
    blocks: list[SampleBlock]


def dwell_entry(
    stage: str, pass_number: int, position: int, *, command: Any, command_time: float, blocks: list[SampleBlock]
) -> AcceptedDwell:
    """Return one dwell of a run: where it was commanded, when, and its sample blocks."""
    return AcceptedDwell(stage, pass_number, position, np.asarray(command, dtype=float), command_time, blocks)


def iteration_entries(step: OffsetIterationStep, operations: list[Record]) -> list[AcceptedDwell]:
    """Dwells of a zero-offset iteration from its operations.

    Per position the iteration commands, lets time pass until arrival and settling (acquisitions
    whose samples are discarded) and records the dwell last, in one or more acquisitions (pieces of
    at most the run's chunk): the dwell of a command is its last acquisitions before the next
    command whose lengths add up to the position's dwell.
    """
    n = len(step.positions)
    groups: list[tuple[Record, list[Record]]] = []
    for record in operations:
        if record.get("error"):
            continue
        if record["operation"] == "command":
            groups.append((record, []))
        elif record["operation"] == "acquire" and groups:
            groups[-1][1].append(record)
    entries: list[AcceptedDwell] = []
    for k, (command, acquisitions) in enumerate(groups):
        if not acquisitions:
            continue
        position = k % n
        expected = step.dwells[position] if step.dwells else None
        pieces = _dwell_pieces(acquisitions, expected)
        if pieces is None:
            raise JournalMismatch(
                f"zero-offset iteration: the last acquisitions after command {k + 1} do not add up to the "
                f"{expected} s that position {step.positions[position]} dwells"
            )
        entries.append(
            dwell_entry(
                step.stage,
                k // n + 1,
                step.positions[position],
                command=command["arguments"],
                command_time=float(command["result"]),
                blocks=[block_from_record(piece) for piece in pieces],
            )
        )
    return entries


def _dwell_pieces(acquisitions: list[Record], expected: float | None) -> list[Record] | None:
    """Return the trailing acquisitions that make up a dwell of ``expected`` seconds (the last alone when None), or None."""
    if expected is None:
        return acquisitions[-1:]
    total = 0.0
    for start in range(len(acquisitions) - 1, -1, -1):
        total += float(acquisitions[start]["arguments"][0])
        if abs(total - expected) <= 1e-9 * max(1.0, expected):
            return acquisitions[start:]
        if total > expected:
            return None
    return None


# --------------------------------------------------------------------------- resume script
def resume_script(records: list[Record], *, deterministic: bool) -> tuple[list[Record], tuple[int, int] | None]:
    """Return the records to replay on resume, and the range of operation records to mark superseded.

    Deterministic drivers replay everything.  Otherwise operations after the last decision
    (the attempt the crash interrupted) cannot be continued and are superseded.
    """
    superseded: set[int] = set()
    for record in records:
        if record.kind == "resume" and record.get("superseded"):
            first, last = record["superseded"]
            superseded.update(range(first, last + 1))
    script = [r for r in records[1:] if r.kind not in ("resume", "finished") and r.seq not in superseded]
    if deterministic or not script:
        return script, None
    cut = len(script)
    while cut and script[cut - 1].kind == "op":
        cut -= 1
    if cut == len(script):
        return script, None
    return script[:cut], (script[cut].seq, script[-1].seq)


def accepted_columns(entries: list[AcceptedDwell]) -> dict[str, NDArray[Any]]:
    """Return the accepted dwells as device-level columns (:data:`stableins.schema.DEVICE_COLUMNS`), in recording order."""
    parts: dict[str, list[Any]] = {k: [] for k in _DEVICE_NAMES}
    for entry in entries:
        block = SampleBlock.concatenate(entry.blocks)
        n = len(block)
        parts["time"].append(block.time)
        parts["stage"].append(np.full(n, entry.stage, dtype=object))
        parts["pass"].append(np.full(n, entry.pass_number, dtype=np.int32))
        parts["position"].append(np.full(n, entry.position, dtype=np.int32))
        parts["time_since_command"].append(block.time - entry.command_time)
        for k, name in enumerate(("platform", "inner", "middle")):
            parts[f"command_{name}"].append(np.full(n, entry.command[k]))
            parts[f"angle_{name}"].append(block.angles[:, k])
        for k, axis in enumerate("xyz"):
            parts[f"f_{axis}"].append(block.specific_force[:, k])
        parts["temperature"].append(block.temperature)
    return {k: (np.concatenate(v) if v else np.zeros(0)) for k, v in parts.items()}


def journal_columns(records: list[Record]) -> dict[str, NDArray[Any]]:
    """Read the accepted dwells straight from a journal (no driver, no re-execution): an independent check.

    Collects, for every accepted verdict (and every converged iteration), the dwell pieces of
    that step and attempt that no resume superseded; raises if a step was accepted twice.
    """
    plan = Plan.from_dict(records[0]["plan"])
    operations = live_operations(records)
    entries: list[tuple[float, AcceptedDwell]] = []
    done: set[int] = set()
    for record in records:
        if not ((record.kind == "verdict" and record["accepted"]) or record.kind == "iteration"):
            continue
        index = record["step"]
        if index in done:
            raise JournalMismatch(f"step {index} accepted twice in the journal")
        done.add(index)
        mine = [r for r in operations if r.get("step") == index and r.get("attempt") == record["attempt"] and not r.get("error")]
        step = plan.steps[index]
        if record.kind == "iteration":
            new = iteration_entries(step, mine)
        else:
            phases = ("slew", "settle", "dwell") if getattr(step, "keep_slew", False) else ("dwell",)
            blocks = [block_from_record(r) for r in mine if r.get("phase") in phases and r.get("operation") == "acquire"]
            new = [
                dwell_entry(
                    step.stage,
                    step.pass_number,
                    step.position,
                    command=record["command"],
                    command_time=record["command_time"],
                    blocks=blocks,
                )
            ]
        entries += [(e.command_time, e) for e in new]
    return accepted_columns([e for _, e in sorted(entries, key=lambda pair: pair[0])])


_DEVICE_NAMES = tuple(c.name for c in DEVICE_COLUMNS)
