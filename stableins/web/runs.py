"""The runs under a run root and the progress of each, read from its journal as it grows.

A run directory is one that holds the journal of ``stableins run`` (``journal.bin``) and the plan it runs
(``procedure.json``).  :class:`RunWatcher` reads each journal incrementally (:func:`stableins.procedures.journal.follow`:
only the records appended since the last look, a record still being written left for the next look) and keeps, per
run, what the runner's console shows:

* the step, its stage and name; the position (and pass of the zero-offset iteration); the phase (slew, settle,
  dwell, static); the seconds dwelt at the position against the plan's settle + dwell;
* the samples recorded (the lengths of the journaled sample arrays);
* the platform time the plan still needs (settle and dwell of the steps not yet done, the static record's rest; a
  zero-offset iteration counts the passes it has not yet made up to its minimum of two, so the figure is a lower
  bound while the iteration runs), and the run's state (running, finished, stopped);
* for a system-level static record, the running quick look of the runner
  (:class:`stableins.procedures.quicklook.QuickLook`: the Earth-rate harmonics and residual rms of the north and east
  velocity, gaps, orientation), updated chunk by chunk from the journaled chunks.
"""

from __future__ import annotations

import json
import math
import os
import threading
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from numpy.typing import NDArray

from stableins.errors import InputError
from stableins.web.models import QuickLookDocument, RunProgress

JOURNAL = "journal.bin"
PLAN = "procedure.json"
#: How deep below the run root run directories are looked for.
MAX_RUN_DEPTH = 3
#: Passes the zero-offset iteration makes at least (the remaining time counts them).
MIN_PASSES = 2


@dataclass(frozen=True)
class _Step:
    """What the progress reads of one step of the plan (``procedure.json``): its kind, names, positions and times."""

    kind: str = ""
    name: str | None = None
    stage: str | None = None
    settle: float = 0.0
    dwell: float = 0.0
    duration: float = 0.0  # a static record's
    position: int | None = None  # a dwell's (None: not given or 0)
    pass_number: int = 1  # a dwell's pass of the zero-offset iteration
    positions: tuple[int, ...] = ()  # the zero-offset iteration's, with their settles and dwells
    settles: tuple[float, ...] = ()
    dwells: tuple[float, ...] = ()
    angle_tolerance: float = math.inf  # a static record's check of the platform angles

    @classmethod
    def read(cls, step: dict[str, object]) -> _Step:
        """Return the step of a plan's JSON object (ValueError, TypeError: a value of the wrong type)."""
        checks = step.get("checks")
        tolerance = checks.get("angle_tolerance", math.inf) if isinstance(checks, dict) else math.inf
        name, stage = step.get("name"), step.get("stage")
        return cls(
            kind=str(step.get("kind", "")),
            name=None if name is None else str(name),
            stage=None if stage is None else str(stage),
            settle=_real(step.get("settle", 0.0)),
            dwell=_real(step.get("dwell", 0.0)),
            duration=_real(step.get("duration", 0.0)),
            position=int(_real(step.get("position", 0))) or None,
            pass_number=int(_real(step.get("pass_number", 1))),
            positions=tuple(int(_real(p)) for p in _sequence(step.get("positions"))),
            settles=tuple(_real(v) for v in _sequence(step.get("settles"))),
            dwells=tuple(_real(v) for v in _sequence(step.get("dwells"))),
            angle_tolerance=_real(tolerance),
        )


@dataclass(frozen=True)
class _Plan:
    """What the progress reads of a run's plan (``procedure.json``): its name, sample rate and steps."""

    name: str = ""
    sample_rate: float = 0.0
    steps: tuple[_Step, ...] = ()

    @classmethod
    def read(cls, document: object) -> _Plan:
        """Return the plan of ``procedure.json``'s JSON value (an empty plan when it is not a plan's object)."""
        if not isinstance(document, dict):
            return cls()
        try:
            steps = tuple(_Step.read(s) for s in _sequence(document.get("steps")) if isinstance(s, dict))
            return cls(str(document.get("name") or ""), _real(document.get("sample_rate") or 0.0), steps)
        except (TypeError, ValueError):  # a value of the wrong type: read as a plan that says nothing
            return cls()


def _real(value: object) -> float:
    if not isinstance(value, int | float | str):  # what float() takes of JSON values
        raise TypeError(f"not a number: {value!r}")
    return float(value)


def _sequence(value: object) -> list[object]:
    return list(value) if isinstance(value, list | tuple) else []


@dataclass
class _State:
    """What has been read of one run's journal so far (mutable; one per run, under the watcher's lock)."""

    valid_length: int = 0
    records: int = 0
    unit: str = ""
    procedure: str = ""
    started: str = ""
    step: int = -1
    phase: str = ""
    commands_in_step: int = 0
    dwelt: float = 0.0  # seconds of samples since the last command
    samples: int = 0
    recorded: float = 0.0  # platform seconds in the current step
    static_samples: int = 0
    finished: str = ""
    stopped: str = ""
    complete: bool = False
    quicklook: Any = None
    error: str = ""


class RunWatcher:
    """The runs under ``root``, each read incrementally from its journal (thread-safe)."""

    def __init__(self, root: Path | None) -> None:
        self.root = root.resolve() if root is not None else None
        self._states: dict[Path, _State] = {}
        self._plans: dict[Path, _Plan] = {}
        self._lock = threading.Lock()

    def names(self) -> list[str]:
        """Return the run directories under the root (relative, ``/``-separated), sorted."""
        if self.root is None or not self.root.is_dir():
            return []
        out = []
        for folder, directories, files in os.walk(self.root, followlinks=False):
            relative = Path(folder).relative_to(self.root)
            if len(relative.parts) >= MAX_RUN_DEPTH:
                directories[:] = []
            directories[:] = sorted(d for d in directories if not d.startswith("."))
            if JOURNAL in files and PLAN in files:
                out.append(relative.as_posix() if relative.parts else ".")
        return sorted(out)

    def directory(self, name: str) -> Path:
        """Return the run directory named ``name`` (one :meth:`names` lists; nothing else, so no path leaves the root).

        Raises
        ------
        InputError
            No run of that name under the root.
        """
        if self.root is None or name not in self.names():
            raise InputError(f"no run {name[:80]!r} under the run root", field="run")
        path = (self.root / name).resolve()
        if not path.is_relative_to(self.root):  # a symbolic link out of the root
            raise InputError(f"run {name[:80]!r} leaves the run root", field="run")
        return path

    def progress(self, name: str) -> RunProgress:
        """Return the progress of run ``name`` as the API's document (:meth:`directory` for the names accepted)."""
        folder = self.directory(name)
        with self._lock:
            state = self._states.get(folder)
            if state is None or _shrunk(folder / JOURNAL, state.valid_length):  # a new run in the same directory: read anew
                state = self._states[folder] = _State()
            plan = self._plan(folder)
            self._read(folder, state, plan)
            return _describe(name, folder, state, plan)

    def all(self) -> list[RunProgress]:
        """Return the progress of every run under the root, running ones first, then the newest."""
        runs = [self.progress(n) for n in self.names()]
        return sorted(runs, key=lambda r: (r.state != "running", _negated(r.updated)))

    def _plan(self, folder: Path) -> _Plan:
        if folder not in self._plans:
            try:
                document = json.loads((folder / PLAN).read_text(encoding="utf-8"))
            except (OSError, ValueError):
                document = {}
            self._plans[folder] = _Plan.read(document)
        return self._plans[folder]

    def _read(self, folder: Path, state: _State, plan: _Plan) -> None:
        """Read the records appended to the run's journal since the last look."""
        from stableins.procedures.journal import follow

        try:
            found = follow(folder / JOURNAL, state.valid_length, state.records)
        except InputError as error:
            state.error = error.message
            return
        except OSError as error:
            state.error = f"cannot read the journal ({error.strerror})"
            return
        rate = plan.sample_rate
        for record in found.records:
            _apply(state, record, plan, rate)
        state.records += len(found.records)
        state.valid_length = found.valid_length or state.valid_length


def _shrunk(journal: Path, length: int) -> bool:
    """Whether the journal is now shorter than what was read of it (replaced by another run's)."""
    try:
        return journal.stat().st_size < length
    except OSError:
        return False


def _negated(text: str) -> float:
    try:
        return -datetime.fromisoformat(text).timestamp()
    except ValueError:
        return 0.0


def _apply(state: _State, record: Any, plan: _Plan, rate: float) -> None:
    """Update the run's state with one journal record."""
    fields = record.fields
    if record.kind == "start":
        state.unit = str(fields.get("unit") or "")
        state.started = str(fields.get("utc") or "")
        state.procedure = plan.name
        return
    if record.kind in ("finished", "complete", "stop"):
        state.finished = str(fields.get("utc") or "") if record.kind == "finished" else state.finished
        state.complete = state.complete or record.kind == "complete"
        state.stopped = str(fields.get("reason") or "") if record.kind == "stop" else state.stopped
        return
    step = fields.get("step")
    if isinstance(step, int) and step != state.step:
        state.step, state.commands_in_step, state.dwelt, state.recorded = step, 0, 0.0, 0.0
        state.stopped = ""
    if record.kind == "op":
        _operation(state, record, plan, rate)


def _operation(state: _State, record: Any, plan: _Plan, rate: float) -> None:
    """Update the run's state with one journaled driver operation (a command, samples, a chunk of a static record)."""
    fields = record.fields
    state.phase = str(fields.get("phase") or state.phase)
    operation = fields.get("operation")
    if operation == "command":
        state.commands_in_step += 1
        state.dwelt = 0.0
    elif operation == "acquire" and fields.get("_has_arrays"):
        n = len(record.arrays.get("time", ()))
        state.samples += n
        seconds = n / rate if rate > 0 else 0.0
        state.recorded += seconds
        if fields.get("phase") in ("settle", "dwell", "iteration"):
            state.dwelt += seconds
    elif operation == "static_chunk" and fields.get("_has_arrays"):
        chunk = record.arrays
        n = len(chunk.get("time", ()))
        state.samples += n
        state.static_samples += n
        state.recorded += n / rate if rate > 0 else 0.0
        _quicklook(state, plan, chunk, rate)


def _quicklook(state: _State, plan: _Plan, chunk: dict[str, NDArray[Any]], rate: float) -> None:
    """Feed a journaled chunk of a static record to the run's quick look (the runner's own)."""
    from stableins.procedures.quicklook import QuickLook

    if state.quicklook is None:
        tolerance = plan.steps[state.step].angle_tolerance if 0 <= state.step < len(plan.steps) else math.inf
        state.quicklook = QuickLook(rate, tolerance)
    try:
        state.quicklook.update(chunk)
    except (KeyError, ValueError):  # a chunk without the columns a quick look reads
        state.quicklook = False


def _step_seconds(step: _Step) -> float:
    """Platform seconds a step of the plan takes at least (settle + dwell; a static record's settle + duration)."""
    if step.kind == "dwell":
        return step.settle + step.dwell
    if step.kind == "static_record":
        return step.settle + step.duration
    if step.kind == "offset_iteration":
        return MIN_PASSES * (sum(step.settles) + sum(step.dwells))
    return 0.0


def _describe(name: str, folder: Path, state: _State, plan: _Plan) -> RunProgress:
    """Return a run's progress as the API's document (:class:`~stableins.web.models.RunProgress`)."""
    steps = plan.steps
    step = steps[state.step] if 0 <= state.step < len(steps) else _Step()
    kind = step.kind
    position: int | None = None
    pass_number: int | None = None
    planned_here = 0.0
    if kind == "dwell":
        position = step.position
        pass_number = step.pass_number
        planned_here = step.settle + step.dwell
    elif kind == "offset_iteration" and step.positions:
        positions = step.positions
        k = max(state.commands_in_step - 1, 0)
        position = positions[k % len(positions)]
        pass_number = k // len(positions) + 1
        planned_here = step.settles[k % len(positions)] + step.dwells[k % len(positions)]
    elif kind == "static_record":
        planned_here = step.settle + step.duration
    if state.finished or state.complete:
        remaining: float | None = 0.0
        lower_bound = False
    elif state.step < 0:
        remaining = sum(_step_seconds(s) for s in steps)
        lower_bound = any(s.kind == "offset_iteration" for s in steps)
    else:
        later = sum(_step_seconds(s) for s in steps[state.step + 1 :])
        here = (
            max(_step_seconds(step) - state.recorded, 0.0)
            if kind != "offset_iteration"
            else max(_step_seconds(step) - state.recorded, planned_here - state.dwelt, 0.0)
        )
        remaining = later + here
        lower_bound = kind == "offset_iteration" or any(s.kind == "offset_iteration" for s in steps[state.step + 1 :])
    try:
        updated = datetime.fromtimestamp((folder / JOURNAL).stat().st_mtime, UTC).isoformat(timespec="seconds")
    except OSError:
        updated = ""
    status = "finished" if state.finished else "stopped" if state.stopped else "complete" if state.complete else "running"
    look: QuickLookDocument | None = None
    if state.quicklook:
        harmonics = state.quicklook.harmonics()
        look = QuickLookDocument(
            text=state.quicklook.describe(),
            hours=state.static_samples / (plan.sample_rate or 1.0) / 3600.0,
            amplitude=None if harmonics is None or harmonics[0] is None else [float(a) for a in harmonics[0]],
            residual_rms=None if harmonics is None else [float(r) for r in harmonics[1]],
        )
    return RunProgress(
        name=name,
        unit=state.unit,
        procedure=state.procedure or plan.name,
        state=status,
        reason=state.stopped or None,
        started=state.started,
        updated=updated,
        journal_records=state.records,
        step=state.step + 1 if state.step >= 0 else None,
        steps=len(steps),
        step_name=step.name,
        stage=step.stage or ("system" if kind == "static_record" else None),
        phase=state.phase or None,
        position=position,
        pass_=pass_number,
        dwell_seconds=state.dwelt,
        dwell_planned=planned_here,
        samples=state.samples,
        remaining_seconds=remaining,
        remaining_is_lower_bound=lower_bound,
        quicklook=look,
        error=state.error or None,
    )
