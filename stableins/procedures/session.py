"""Journal-backed access to the platform: a run's :class:`Session` replays its journal first, then goes live.

Every driver operation and every decision of a run is appended to the run journal and fsync-ed before the
runner acts on it (:mod:`stableins.procedures.runner` explains how a run survives ``kill -9``); on resume the
session answers from the journal until it is used up.  The platform's clock is checked on every answer:
times are finite and never run back.
"""

from __future__ import annotations

import contextlib
import math
from collections import deque
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from stableins.documents import JSONObject
from stableins.drivers.base import PlatformDriver
from stableins.drivers.errors import AcquisitionInterrupted, DriverConnectionError, DriverError, DriverProtocolError
from stableins.procedures.journal import Journal, Record, block_from_record
from stableins.samples import SampleBlock

_ERROR_TYPES: dict[str, type[DriverError]] = {
    "AcquisitionInterrupted": AcquisitionInterrupted,
    "DriverConnectionError": DriverConnectionError,
    "DriverProtocolError": DriverProtocolError,
    "DriverError": DriverError,
}


class JournalMismatch(Exception):
    """On resume the procedure asked for something other than what the journal holds."""


class Session:
    """Journal-backed access to the driver: replays the journal first, then goes live.

    Parameters
    ----------
    journal : Journal
        Open journal; new records are appended to it.
    script : list of Record
        Journaled records still to replay (empty for a new run).
    driver : PlatformDriver
        The live platform.
    forward : bool
        Deterministic driver: forward replayed operations to it and check its answers.
    """

    def __init__(self, journal: Journal, script: list[Record], driver: PlatformDriver, *, forward: bool) -> None:
        self.journal = journal
        self.script = deque(script)
        self.driver = driver
        self.forward = forward
        self.context: JSONObject = {}
        self.replayed = 0
        #: when a list, every operation record (replayed or new) is also appended to it
        self.trace: list[Record] | None = None
        #: the latest platform time seen [s] and whether it was a sample's (the next sample must then come strictly
        #: later) or a command's (a sample may carry the command's time): the platform's clock never runs back
        self.clock: tuple[float, bool] = (-math.inf, False)
        #: the latest sample time of the accepted data [s]: nothing recorded later may come before it
        self.floor = -math.inf
        #: a system-level static record has its own time base (time since the start of the record)
        self.static_clock: tuple[float, bool] = (-math.inf, False)
        self._live = False
        #: whether the latest operation was answered by the journal
        self.last_replayed = False
        #: called once, when the last journaled record has been replayed (the run goes live from there)
        self.on_live: Callable[[int], None] | None = None

    @property
    def replaying(self) -> bool:
        """Whether journaled records are still to be replayed."""
        return bool(self.script)

    def _next(self, kind: str, describe: str) -> Record:
        record = self.script.popleft()
        if record.kind != kind:
            raise JournalMismatch(
                f"resuming: the procedure reaches {describe} but the journal has a {record.kind!r} record (seq {record.seq})"
            )
        self.replayed += 1
        if not self.script and self.on_live is not None:
            self.on_live(self.replayed)
        return record

    # ------------------------------------------------------------------ driver operations
    def operate(self, operation: str, arguments: list[float], call: Callable[[], Any] | None = None) -> Any:
        """Perform one driver operation, journaled (live) or answered from the journal (replay).

        ``call`` performs operations other than command / read_angles / acquire (e.g. the next
        chunk of a static record, ``static_chunk``).
        """
        if call is None:
            call = self._driver_call(operation, arguments)
        self.last_replayed = bool(self.script)
        if self.script:
            return self._replay(operation, arguments, call)
        if not self._live:
            self._live = True
            if self.replayed and not self.forward:
                # a real platform after a resume: its clock may have restarted with its power, which is harmless as long
                # as nothing it records comes before the data already accepted
                self.clock = (self.floor, True)
        return self._operate_live(operation, arguments, call)

    def _driver_call(self, operation: str, arguments: list[float]) -> Callable[[], Any]:
        """Return the driver call of a command, read_angles or acquire operation."""
        calls: dict[str, Callable[[], Any]] = {
            "command": lambda: self.driver.command((arguments[0], arguments[1], arguments[2])),
            "read_angles": self.driver.read_angles,
            "acquire": lambda: self.driver.acquire(arguments[0]),
        }
        return calls[operation]

    def _replay(self, operation: str, arguments: list[float], call: Callable[[], Any]) -> Any:
        """Answer an operation from the next journaled record (and forward it to a deterministic platform)."""
        record = self._next("op", f"{operation} {arguments}")
        if record["operation"] != operation or not np.allclose(record["arguments"], arguments, rtol=0, atol=1e-12):
            raise JournalMismatch(
                f"resuming: the procedure asks for {operation} {arguments}, the journal has {record['operation']} {record['arguments']}"
            )
        if record.get("error"):
            if self.forward:  # keep the fresh platform in step: it did this operation too
                with contextlib.suppress(DriverError):
                    call()
            raise _ERROR_TYPES.get(record["error_type"], DriverError)(record["error"])
        result = _result_of(record)
        if self.forward:
            _check_same(operation, result, call(), record.seq)
        if self.trace is not None:
            self.trace.append(record)
        if operation == "static_chunk":
            self.static_clock = _latest_time(operation, result, self.static_clock)
        else:
            self.clock = _latest_time(operation, result, self.clock)
        return result

    def _operate_live(self, operation: str, arguments: list[float], call: Callable[[], Any]) -> Any:
        """Perform an operation on the platform, check its clock and journal its result (or its error)."""
        try:
            result = call()
            if operation == "static_chunk":  # before anything is journaled
                self.static_clock = _check_clock(operation, result, self.static_clock)
            else:
                self.clock = _check_clock(operation, result, self.clock)
        except DriverError as error:
            self.journal.append(
                "op",
                {**self.context, "operation": operation, "arguments": arguments, "error": str(error), "error_type": type(error).__name__},
            )
            raise
        fields: JSONObject = {**self.context, "operation": operation, "arguments": [*arguments]}
        arrays: dict[str, NDArray[Any]] = {}
        if operation == "command":
            fields["result"] = float(result)
        elif operation == "read_angles":
            arrays["angles"] = np.asarray(result, dtype=float)
        elif operation == "static_chunk":
            arrays = {name: np.asarray(values) for name, values in result.items()}
        else:
            arrays = {
                "time": result.time,
                "specific_force": result.specific_force,
                "angles": result.angles,
                "temperature": result.temperature,
            }
        record = self.journal.append("op", fields, arrays)
        if self.trace is not None:
            self.trace.append(record)
        return _result_of(record)

    def accept(self, blocks: list[SampleBlock]) -> None:
        """Blocks that became part of the run's data: later recordings must come after them."""
        for block in blocks:
            if len(block.time):
                self.floor = max(self.floor, float(block.time[-1]))

    # ------------------------------------------------------------------ decisions
    def decide(self, kind: str, fields: JSONObject) -> tuple[Record, bool]:
        """Journal a decision, or consume it from the journal when replaying.  Returns (record, replayed)."""
        if self.script:
            record = self._next(kind, f"a {kind} decision")
            if record.get("step") != fields.get("step"):
                raise JournalMismatch(f"resuming: {kind} for step {fields.get('step')} expected, journal has step {record.get('step')}")
            return record, True
        return self.journal.append(kind, {**self.context, **fields}), False

    def enter(self, kind: str, step: int, ask: Callable[[], Any]) -> Any:
        """Return a value from a person: from the journal when replaying, else asked and journaled."""
        if self.script:
            return self._next(kind, f"step {step}'s input")["value"]
        value = ask()
        self.journal.append(kind, {"step": step, "value": value})
        return value


class SessionDriver:
    """The session seen as a :class:`~stableins.drivers.base.PlatformDriver`, for estimators that drive the platform themselves."""

    def __init__(self, session: Session, *, piece: float | None = None, on_piece: Callable[[float], None] | None = None) -> None:
        self.session = session
        #: longest journaled acquisition [s] (the run's chunk): a long acquisition is journaled, and shown, piece by piece
        self.piece = piece
        #: told the seconds recorded after every live piece of an acquisition (the console's progress)
        self.on_piece = on_piece

    @property
    def metadata(self) -> Any:
        """The platform's site metadata."""
        return self.session.driver.metadata

    def command(self, readings: tuple[float, float, float]) -> float:
        """Command the gimbals to ``readings`` [rad] through the session; return the platform time."""
        return self.session.operate("command", [float(r) for r in readings])

    def read_angles(self) -> NDArray[np.float64]:
        """Read the gimbal angles [rad] through the session."""
        return self.session.operate("read_angles", [])

    def acquire(self, duration: float) -> SampleBlock:
        """Record ``duration`` seconds of samples through the session, in journaled pieces of at most :attr:`piece` seconds."""
        if self.piece is None or duration <= self.piece:
            return self.session.operate("acquire", [float(duration)])
        blocks = []
        done = 0.0
        while duration - done > 1e-9:
            length = min(self.piece, duration - done)
            blocks.append(self.session.operate("acquire", [float(length)]))
            done += length
            if self.on_piece is not None and not self.session.last_replayed:
                self.on_piece(done)
        return SampleBlock.concatenate(blocks)

    def status(self) -> dict[str, object]:
        """Return the platform's status (not journaled)."""
        return self.session.driver.status()

    def close(self) -> None:
        """Leave the platform open: the session's owner closes it."""


def _result_of(record: Record) -> Any:
    operation = record["operation"]
    if operation == "command":
        return float(record["result"])
    if operation == "read_angles":
        return np.array(record.arrays["angles"])
    if operation == "static_chunk":
        return dict(record.arrays)
    return block_from_record(record)


def _check_same(operation: str, journaled: Any, live: Any, seq: int) -> None:
    if operation == "acquire":
        same = all(np.array_equal(getattr(journaled, n), getattr(live, n)) for n in ("time", "specific_force", "angles", "temperature"))
    elif operation == "static_chunk":
        same = set(journaled) == set(live) and all(np.array_equal(journaled[n], live[n]) for n in journaled)
    else:
        same = bool(np.array_equal(np.asarray(journaled), np.asarray(live)))
    if not same:
        raise JournalMismatch(
            f"resuming: the platform does not reproduce journal record {seq} ({operation}); it is not the same seed or version"
        )


def _validate_block(block: SampleBlock) -> None:
    n = len(block.time)
    shapes = {"specific_force": (n, 3), "angles": (n, 3), "temperature": (n,)}
    for name, shape in shapes.items():
        if np.shape(getattr(block, name)) != shape:
            raise DriverProtocolError(f"the platform returned {name} of shape {np.shape(getattr(block, name))}, expected {shape}")


def _sample_times(operation: str, result: Any) -> Any:
    if operation == "acquire":
        return np.asarray(result.time, dtype=float)
    if operation == "static_chunk":
        return np.asarray(result.get("time", ()), dtype=float)
    return None


def _latest_time(operation: str, result: Any, clock: tuple[float, bool]) -> tuple[float, bool]:
    """Return the clock after an operation (journaled results: already checked)."""
    if operation == "command":
        return max(clock[0], float(result)), clock[1] and clock[0] >= float(result)
    time = _sample_times(operation, result)
    if time is not None and time.size:
        return max(clock[0], float(time[-1])), True
    return clock


def _check_clock(operation: str, result: Any, clock: tuple[float, bool]) -> tuple[float, bool]:
    """Refuse (DriverProtocolError, before it is journaled) a result whose times are not finite or run back; the new clock.

    A session's times must increase throughout: the data set of the run is one time series, and samples that ran
    back would make every export of the run, and so every resume, fail the same way.  A command may carry the time
    of the last sample, and the first sample after it the command's time; samples increase strictly.
    """
    latest, strict = clock
    if operation == "acquire":
        _validate_block(result)
    elif operation == "command":
        issued = float(result)
        if not math.isfinite(issued):
            raise DriverProtocolError(f"the platform reported the command at time {issued!r}")
        if issued < latest:
            raise DriverProtocolError(f"the platform's clock ran back: a command at {issued!r} s after a sample at {latest!r} s")
        return issued, False
    time = _sample_times(operation, result)
    if time is None or time.size == 0:
        return clock
    if not np.isfinite(time).all():
        raise DriverProtocolError(f"the platform sent a sample time {time[~np.isfinite(time)][0]!r} (expected finite times)")
    steps = np.diff(time)
    first_ok = time[0] > latest if strict else time[0] >= latest
    if not first_ok or not (steps > 0).all():
        k = 0 if not first_ok else int(np.argmax(~(steps > 0))) + 1
        before = latest if k == 0 else float(time[k - 1])
        raise DriverProtocolError(
            f"the platform's clock ran back: sample {k + 1} of {time.size} at {float(time[k])!r} s follows {before!r} s "
            "(times must increase through the whole session)"
        )
    return float(time[-1]), True
