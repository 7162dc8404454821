r"""Carry out a procedure step by step on a platform, journaling everything, resumable after any crash.

How a run survives ``kill -9``
------------------------------
Every driver operation (command, angle read, each piece of a dwell) and every decision
(verdict of a dwell, value a person entered, a stop) is appended to the run journal
(:mod:`stableins.procedures.journal`) and fsync-ed *before* the runner acts on it.  The
runner's decisions depend only on what the driver returned and what people entered, so on
``--resume`` the runner executes the procedure again from the top while a :class:`Session`
answers from the journal instead of the platform, until the journal is used up; then it
goes live.  Nothing is asked twice, nothing is written twice, nothing already journaled is lost.

* Deterministic drivers (the simulated platform, a replay): the fresh driver is brought to
  the journaled state by forwarding it every journaled operation, each result checked
  against the journal; the run continues mid-dwell, sample for sample as if never stopped.
* A real platform cannot be rewound: the operations after the last decision (the unfinished
  attempt) are marked superseded (they stay in the journal) and that attempt is repeated
  from its command, because a dwell must not be stitched across a gap.

Acceptance checks of a dwell (SI; thresholds in the procedure)
--------------------------------------------------------------
reached : :math:`\max_i |\bar r_i - r_i^{cmd}| \le` ``angle_tolerance`` (wrapped to ±π).
still   : per accelerometer axis, the least-squares line :math:`f(t) = a + b (t - \bar t)` with residual
          standard deviation :math:`s \le` ``scatter_max``; the slope fails only when it exceeds the limit
          beyond its own noise, :math:`|b| - 3\sigma_b >` ``slope_max`` with
          :math:`\sigma_b = s / \sqrt{\sum (t - \bar t)^2}` (a short, noisy dwell is not rejected for noise).
complete: all samples finite and at least ``min_fraction`` of ``dwell × rate`` of them.
"""

from __future__ import annotations

import math
import sys
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import UTC, datetime
from typing import Any, TextIO

import numpy as np
from numpy.typing import NDArray

from stableins.data.errors import InputError
from stableins.data.schema import DEVICE_COLUMNS
from stableins.drivers.base import PlatformDriver, SampleBlock
from stableins.drivers.errors import AcquisitionInterrupted, DriverConnectionError, DriverError, DriverProtocolError
from stableins.drivers.replay import block_from_record, live_operations
from stableins.procedures.journal import Journal, Record
from stableins.procedures.plan import Checks, DwellStep, OffsetIterationStep, PersonStep, Plan, StaticRecordStep

#: A slope counts against the limit only beyond this many σ of its own noise (short dwells are noisy).
SLOPE_SIGMAS = 3.0
#: Exit status of a run that stopped and can be resumed (2 is reserved for bad input).
EXIT_STOPPED = 3
_ERROR_TYPES: dict[str, type[DriverError]] = {
    "AcquisitionInterrupted": AcquisitionInterrupted,
    "DriverConnectionError": DriverConnectionError,
    "DriverProtocolError": DriverProtocolError,
    "DriverError": DriverError,
}


class RunStopped(Exception):
    """The run stopped (a step failed too often, the link failed too often); it can be resumed."""


class JournalMismatch(Exception):
    """On resume the procedure asked for something other than what the journal holds."""


# --------------------------------------------------------------------------- console
#: Marks what a resumed run prints of steps the journal answers (nothing happens on the platform for them).
REPLAY_MARK = "replay"
#: Answers a confirmation takes (case-insensitive); anything else is asked again.
YES_ANSWERS = ("y", "yes")
NO_ANSWERS = ("n", "no")


class Console:
    """What the runner says, its progress bars and its prompts (all on ``out``, stderr by default).

    Every dwell of every stage is shown the same way (:meth:`dwell`, :meth:`progress`, :meth:`verdict`): a line
    with the command and the timing, a settle and a dwell bar on a terminal, and the verdict with its reasons.
    Lines are never cut: on a terminal they wrap at its width (``width``), elsewhere (logs, pipes) they stay whole.
    What a resumed run replays from its journal is marked :data:`REPLAY_MARK`.

    Parameters
    ----------
    yes : bool
        Unattended: confirm every confirmation, use defaults and ``values`` for entries.
    values : dict
        Values given on the command line (``--set key=value``) for ``enter`` steps.
    out : text stream, optional
        Where to write (stderr by default: standard output is the command's result, e.g. ``--json``).
    quiet : bool
        Say nothing (prompts are still asked).
    width : int, optional
        Wrap lines at this many columns; default: the terminal's width when ``out`` is a terminal, else no wrapping.
    bars : bool, optional
        Draw progress bars; default: when ``out`` is a terminal.
    """

    def __init__(
        self,
        *,
        yes: bool = False,
        values: dict[str, str] | None = None,
        out: TextIO | None = None,
        quiet: bool = False,
        width: int | None = None,
        bars: bool | None = None,
    ) -> None:
        self.yes = yes
        self.values = dict(values or {})
        self.out = out or sys.stderr
        self.quiet = quiet
        terminal = bool(getattr(self.out, "isatty", None) and self.out.isatty())
        if width is None and terminal:
            import shutil

            width = shutil.get_terminal_size((100, 24)).columns
        self.width = width or 0
        self.bars = terminal if bars is None else bars
        self._bar: Any = None
        self._pending: str | None = None

    def journal_used_up(self, replayed: int) -> None:
        """The resumed run has replayed its journal (``replayed`` records); said before the next live line."""
        self._pending = f"journal replayed ({replayed} records): the run is live from here"

    # ------------------------------------------------------------------ lines
    def say(self, text: str, *, replay: bool = False) -> None:
        """Print ``text`` (each of its lines wrapped, never cut); ``replay``: marked as answered by the journal."""
        self._end_bar()
        if self.quiet:
            return
        if self._pending is not None and not replay:
            pending, self._pending = self._pending, None
            print(self._wrap(pending), file=self.out, flush=True)
        for line in text.split("\n"):
            print(self._wrap(f"{REPLAY_MARK} {line}" if replay else line), file=self.out, flush=True)

    def _wrap(self, line: str) -> str:
        if not self.width or len(line) <= self.width:
            return line
        import textwrap

        body = line.lstrip(" ")
        indent = " " * (len(line) - len(body))
        return textwrap.fill(
            body, self.width, initial_indent=indent, subsequent_indent=indent + "    ", break_long_words=False, break_on_hyphens=False
        )

    def dwell(self, label: str, readings: Any, settle: float, dwell: float, why: str = "", *, replay: bool = False) -> None:
        """The line that opens a dwell of any stage: where the gimbals are commanded, how long it settles and dwells."""
        degrees = ", ".join(f"{math.degrees(r):.4f}" for r in readings)
        reason = f" — {why}" if why else ""
        self.say(f"{label}: command readings ({degrees}) deg, settle {settle:g} s, dwell {dwell:g} s{reason}", replay=replay)

    def verdict(self, result: CheckResult, *, replay: bool = False, rejected: str = "rejected", indent: str = "  ") -> None:
        """The verdict of a dwell with its reasons: ``accepted: ...`` or ``<rejected>: <reasons> (...)``."""
        if result.accepted:
            self.say(f"{indent}accepted: {result.describe()}", replay=replay)
        else:
            self.say(f"{indent}{rejected}: {'; '.join(result.reasons)} ({result.describe()})", replay=replay)

    def progress(self, label: str, done: float, total: float) -> None:
        """Progress of a settle or dwell phase (a bar on a terminal, :class:`stableins.progress.Progress`); closed when done."""
        if self.quiet or not self.bars:
            return
        from stableins.progress import Progress

        if self._bar is None or self._bar.label != f"  {label}":
            self._end_bar()
            self._bar = Progress(total=total, label=f"  {label}", stream=self.out, enabled=True)
        self._bar.update(done - self._bar.done)
        if done >= total:
            self._end_bar()

    def _end_bar(self) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None

    # ------------------------------------------------------------------ prompts
    def confirm(self, prompt: str) -> bool:
        """Ask ``prompt``; ``y``/``yes`` confirms, ``n``/``no`` declines, anything else (a typo, nothing) is asked again."""
        if self.yes:
            self.say(f"  {prompt} — confirmed (--yes)")
            return True
        self._end_bar()
        while True:
            answer = self._ask(f"  {prompt} [y/n] ").strip().lower()
            if answer in YES_ANSWERS:
                return True
            if answer in NO_ANSWERS:
                return False
            self._tell(f"  {answer!r} is neither yes nor no: please answer y or n" if answer else "  please answer y or n")

    def enter(self, step: PersonStep) -> str:
        """The text a person enters for ``step`` (``--set``, the default with ``--yes``, or asked)."""
        if step.key in self.values:
            self.say(f"  {step.prompt}: {self.values[step.key]} {step.unit} (--set)")
            return self.values[step.key]
        if self.yes:
            if step.default is None:
                raise RunStopped(
                    f"step {step.name!r} needs a person to enter {step.key!r}; unattended, give it with --set {step.key}=VALUE"
                )
            self.say(f"  {step.prompt}: {step.default} {step.unit} (default, --yes)")
            return str(step.default)
        self._end_bar()
        bounds = f", {step.minimum:g} to {step.maximum:g}" if step.minimum is not None and step.maximum is not None else ""
        unit = f" ({step.unit}{bounds})" if step.unit or bounds else ""
        default = f" [{step.default}]" if step.default is not None else ""
        answer = self._ask(f"  {step.prompt}{unit}{default}: ").strip()
        return answer or ("" if step.default is None else str(step.default))

    def _tell(self, text: str) -> None:
        """A line for the person answering a prompt (shown even when quiet: a prompt is being asked)."""
        self._end_bar()
        print(self._wrap(text), file=self.out, flush=True)

    def _ask(self, prompt: str) -> str:
        """One answer from standard input; the prompt goes to ``out`` (wrapped like every line), not to standard output."""
        text = self._wrap(prompt)
        print(text, end="" if text.endswith(" ") else " ", file=self.out, flush=True)
        answer = _ask("")
        if not (getattr(sys.stdin, "isatty", None) and sys.stdin.isatty()):  # no terminal echoes it: the log shows the answer
            print(answer, file=self.out, flush=True)
        return answer


def _ask(prompt: str) -> str:
    try:
        return input(prompt)
    except EOFError:
        raise RunStopped(
            "a person must answer a prompt but standard input is closed; run with --yes (and --set) for unattended runs"
        ) from None


# --------------------------------------------------------------------------- session
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
        self.context: dict[str, Any] = {}
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
        """One driver operation, journaled (live) or answered from the journal (replay).

        ``call`` performs operations other than command / read_angles / acquire (e.g. the next
        chunk of a static record, ``static_chunk``).
        """
        if call is None:
            call = {
                "command": lambda: self.driver.command(tuple(arguments)),  # type: ignore[arg-type]
                "read_angles": self.driver.read_angles,
                "acquire": lambda: self.driver.acquire(arguments[0]),
            }[operation]
        self.last_replayed = bool(self.script)
        if self.script:
            record = self._next("op", f"{operation} {arguments}")
            if record["operation"] != operation or not np.allclose(record["arguments"], arguments, rtol=0, atol=1e-12):
                raise JournalMismatch(
                    f"resuming: the procedure asks for {operation} {arguments}, the journal has {record['operation']} {record['arguments']}"
                )
            if record.get("error"):
                if self.forward:  # keep the fresh platform in step: it did this operation too
                    try:
                        call()
                    except DriverError:
                        pass
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
        if not self._live:
            self._live = True
            if self.replayed and not self.forward:
                # a real platform after a resume: its clock may have restarted with its power, which is harmless as long
                # as nothing it records comes before the data already accepted
                self.clock = (self.floor, True)
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
        fields: dict[str, Any] = {**self.context, "operation": operation, "arguments": arguments}
        arrays: dict[str, Any] = {}
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
    def decide(self, kind: str, fields: dict[str, Any]) -> tuple[Record, bool]:
        """Journal a decision, or consume it from the journal when replaying.  Returns (record, replayed)."""
        if self.script:
            record = self._next(kind, f"a {kind} decision")
            if record.get("step") != fields.get("step"):
                raise JournalMismatch(f"resuming: {kind} for step {fields.get('step')} expected, journal has step {record.get('step')}")
            return record, True
        return self.journal.append(kind, {**self.context, **fields}), False

    def enter(self, kind: str, step: int, ask: Callable[[], Any]) -> Any:
        """A value from a person: from the journal when replaying, else asked and journaled."""
        if self.script:
            return self._next(kind, f"step {step}'s input")["value"]
        value = ask()
        self.journal.append(kind, {"step": step, "value": value})
        return value


class SessionDriver:
    """The session seen as a :class:`~stableins.drivers.base.PlatformDriver`, for estimators that drive the platform themselves."""

    def __init__(self, session: Session) -> None:
        self.session = session

    @property
    def metadata(self) -> Any:
        return self.session.driver.metadata

    def command(self, readings: tuple[float, float, float]) -> float:
        return self.session.operate("command", [float(r) for r in readings])

    def read_angles(self) -> NDArray[np.float64]:
        return self.session.operate("read_angles", [])

    def acquire(self, duration: float) -> SampleBlock:
        return self.session.operate("acquire", [float(duration)])

    def status(self) -> dict[str, object]:
        return self.session.driver.status()

    def close(self) -> None:
        pass


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
    """The clock after an operation (journaled results: already checked)."""
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


# --------------------------------------------------------------------------- checks
@dataclass(frozen=True)
class CheckResult:
    """Outcome of the acceptance checks of one dwell (SI)."""

    accepted: bool
    reasons: tuple[str, ...]
    angle_error: float
    scatter: float
    slope: float
    samples: int
    expected_samples: int
    values: dict[str, float] = field(default_factory=dict)

    def describe(self) -> str:
        return (
            f"reached within {math.degrees(self.angle_error) * 3600:.1f} arcsec, scatter {self.scatter / 9.80665e-6:.1f} µg, "
            f"slope {self.slope / 9.80665e-6:.2f} µg/s, {self.samples}/{self.expected_samples} samples"
        )


def evaluate_dwell(command: NDArray[np.float64], block: SampleBlock, checks: Checks, dwell: float, rate: float) -> CheckResult:
    """Acceptance checks of one dwell (see the module docstring for the formulas)."""
    n = len(block.time)
    expected = max(1, int(round(dwell * rate)))
    statistics = dwell_statistics(command, block)
    if statistics is None:
        finite = n > 0 and all(np.all(np.isfinite(a)) for a in (block.time, block.specific_force, block.angles, block.temperature))
        reason = f"{n} samples, {'some not finite' if n and not finite else 'too few to check'}"
        return CheckResult(False, (reason,), math.inf, math.inf, math.inf, n, expected)
    angle_error, scatter, slope, slope_sigma, excess, axis = statistics
    reasons = []
    if n < checks.min_fraction * expected:
        reasons.append(f"only {n} of {expected} expected samples (gaps)")
    if angle_error > checks.angle_tolerance:
        reasons.append(
            f"platform not at the commanded angles: off by {math.degrees(angle_error) * 3600:.1f} arcsec "
            f"(limit {math.degrees(checks.angle_tolerance) * 3600:.1f})"
        )
    micro_g = 9.80665e-6
    if scatter > checks.scatter_max:
        reasons.append(f"not still: scatter {scatter / micro_g:.1f} µg (limit {checks.scatter_max / micro_g:.1f})")
    if excess > checks.slope_max:
        reasons.append(
            f"not still: slope {slope / micro_g:.2f} ± {slope_sigma / micro_g:.2f} µg/s on {'xyz'[axis]} "
            f"(limit {checks.slope_max / micro_g:.2f} µg/s beyond {SLOPE_SIGMAS:g}σ)"
        )
    return CheckResult(not reasons, tuple(reasons), angle_error, scatter, slope, n, expected)


def dwell_statistics(command: Any, block: SampleBlock) -> tuple[float, float, float, float, float, int] | None:
    """What the acceptance checks look at in a dwell; ``None`` when it has fewer than 3 samples or a non-finite one.

    Returns ``(angle_error, scatter, slope, slope_sigma, excess, axis)``: the largest |mean reading − command| (wrapped
    to ±π) [rad]; the largest residual standard deviation about the per-axis least-squares line [m/s²]; the slope
    [m/s² per s] and its 1σ on the axis ``axis`` where ``|b| − 3σ_b`` (``excess``) is largest.
    """
    n = len(block.time)
    finite = n > 0 and all(np.all(np.isfinite(a)) for a in (block.time, block.specific_force, block.angles, block.temperature))
    if n < 3 or not finite:
        return None
    difference = np.mean(block.angles, axis=0) - np.asarray(command, dtype=float)
    angle_error = float(np.max(np.abs(np.angle(np.exp(1j * difference)))))
    t = block.time - block.time.mean()
    design = np.column_stack([np.ones(n), t])
    coefficients, *_ = np.linalg.lstsq(design, block.specific_force, rcond=None)
    residual = block.specific_force - design @ coefficients
    deviation = np.std(residual, axis=0, ddof=2)
    scatter = float(np.max(deviation))
    slope_sigma = deviation / math.sqrt(float(np.sum(t**2))) if np.any(t) else np.full(3, math.inf)
    excess = np.abs(coefficients[1]) - SLOPE_SIGMAS * slope_sigma
    worst = int(np.argmax(excess))
    return angle_error, scatter, float(abs(coefficients[1][worst])), float(slope_sigma[worst]), float(excess[worst]), worst


def estimator_verdict(command: Any, block: SampleBlock, summary: Any, dwell: float, rate: float) -> CheckResult:
    """The verdict of a dwell the estimator itself checks (the zero-offset iteration's coarse dwells).

    Accepted when the procedure's ``[acceptance]`` checks (:func:`stableins.estimators.dwell.summarize_dwell`) leave it
    usable, else the reasons are its flags; the figures are those of :func:`evaluate_dwell`, so every dwell of every
    stage is described alike.
    """
    statistics = dwell_statistics(command, block)
    angle_error, scatter, slope = statistics[:3] if statistics is not None else (math.inf, math.inf, math.inf)
    return CheckResult(summary.usable, tuple(summary.flags), angle_error, scatter, slope, len(block.time), max(1, int(round(dwell * rate))))


# --------------------------------------------------------------------------- runner
@dataclass
class RunOptions:
    """Runner options that are not part of the procedure."""

    link_failures: int = 3  #: consecutive link failures of one step before the run stops


class Runner:
    """Executes a :class:`~stableins.procedures.plan.Plan` through a :class:`Session`.

    After :meth:`execute` returns, :attr:`accepted` maps the index of every dwell step to the
    journal records of its accepted dwell, in order; :func:`accepted_columns` turns them into
    the device-level data set.
    """

    def __init__(
        self,
        plan: Plan,
        session: Session,
        console: Console,
        options: RunOptions | None = None,
        *,
        definition: Any = None,
        offsets: tuple[float, float, float] = (0.0, 0.0, 0.0),
        extra_terms: tuple[Any, ...] = (),
    ) -> None:
        self.plan = plan
        #: discovered terms of the unit's model the stage estimates (the prior record's and the definition's ``[model] add``)
        self.extra_terms = tuple(extra_terms)
        self.session = session
        self.console = console
        self.options = options or RunOptions()
        self.definition = definition
        self.rate = float(session.driver.metadata.sample_rate)
        self.offsets = np.asarray(offsets, dtype=float)
        self.inputs: dict[str, Any] = {}
        #: accepted dwells in the order they were recorded (see :func:`accepted_columns`)
        self.entries: list[dict[str, Any]] = []
        #: result of the zero-offset iteration, if the plan has one
        self.iteration: Any = None
        #: journal records of the system-level static record, in order (if the plan has one)
        self.static_chunks: list[Record] = []

    def execute(self) -> None:
        total = len(self.plan.steps)
        if self.session.on_live is None:
            self.session.on_live = self.console.journal_used_up
        for index, step in enumerate(self.plan.steps):
            self.session.context = {"step": index}
            label = f"[{index + 1}/{total}] {step.name}"
            if isinstance(step, DwellStep):
                self._dwell(index, step, label)
            elif isinstance(step, PersonStep):
                self._person(index, step, f"[{index + 1}/{total}]")
            elif isinstance(step, OffsetIterationStep):
                self._offset_iteration(index, step, label)
            elif isinstance(step, StaticRecordStep):
                self._static_record(index, step, label)
        self.session.context = {}
        self.session.decide("complete", {"step": total, "utc": datetime.now(UTC).replace(microsecond=0).isoformat()})

    # ------------------------------------------------------------------ steps
    def _person(self, index: int, step: PersonStep, number: str) -> None:
        """Ask a person (the prompt's full text, wrapped, never cut); a typo or an out-of-range value is asked again."""
        replay = self.session.replaying
        what = "confirm" if step.action == "confirm" else f"enter {step.key or 'a value'}"
        self.console.say(f"{number} a person must act: {what}", replay=replay)
        if step.action == "confirm":

            def ask() -> bool:
                if not self.console.confirm(step.prompt):
                    raise RunStopped(f"step {step.name!r} was not confirmed; the run stops here")
                return True

            self.session.enter("input", index, ask)
            if replay:
                self.console.say(f"  {step.prompt}: confirmed (answered before the run was interrupted)", replay=True)
            return

        def ask_value() -> Any:
            while True:
                text = self.console.enter(step)
                try:
                    return parse_entry(step, text)
                except InputError as error:
                    if self.console.yes or step.key in self.console.values:
                        raise  # checked before the run started; cannot happen unless the plan changed
                    self.console._tell(f"  {error.message} (expected {error.expected}); please enter it again")

        value = self.session.enter("input", index, ask_value)
        if replay:
            self.console.say(f"  {step.prompt}: {value} {step.unit} (entered before the run was interrupted)".rstrip(), replay=True)
        self.inputs[step.key] = value

    def _dwell(self, index: int, step: DwellStep, label: str) -> None:
        readings = np.asarray(step.readings, dtype=float) - (self.offsets if step.offset_corrected else 0.0)
        rejections = 0
        link_failures = 0
        attempt = 0
        while True:
            attempt += 1
            self.session.context = {"step": index, "attempt": attempt}
            again = f" (attempt {attempt})" if attempt > 1 else ""
            self.console.dwell(f"{label}{again}", readings, step.settle, step.dwell, step.why, replay=self.session.replaying)
            try:
                command_time = self.session.operate("command", [float(r) for r in readings])
                arrived = self._wait_until_reached(readings, step.checks)
                if arrived is None and step.settle > 0:
                    self._record(step.settle, "settle", "settle")
                blocks = self._record(step.dwell, "dwell", "dwell") if arrived is None else []
            except (DriverConnectionError, DriverProtocolError) as error:
                link_failures = self._link_failure(
                    index,
                    attempt,
                    step.name,
                    error,
                    link_failures,
                    "this attempt's samples are set aside (kept in the journal); repeating the step",
                )
                continue
            if arrived is None:
                result = evaluate_dwell(readings, _concatenate(blocks), step.checks, step.dwell, self.rate)
            else:
                result = CheckResult(False, (arrived,), math.inf, math.inf, math.inf, 0, int(round(step.dwell * self.rate)))
            verdict = {
                "step": index,
                "attempt": attempt,
                "accepted": result.accepted,
                "reasons": list(result.reasons),
                "angle_error": result.angle_error,
                "scatter": result.scatter,
                "slope": result.slope,
                "samples": result.samples,
                "command_time": command_time,
                "command": [float(r) for r in readings],
            }
            _, replayed = self.session.decide("verdict", verdict)
            self.console.verdict(result, replay=replayed)
            if result.accepted:
                self.entries.append(_entry(step.stage, step.pass_number, step.position, readings, command_time, blocks))
                self.session.accept(blocks)
                return
            rejections += 1
            if rejections > self.plan.retries:
                last = "; ".join(result.reasons)
                message = f"step {step.name!r} rejected {rejections} times (retries = {self.plan.retries}); last reason: {last}"
                _, replayed = self.session.decide("stop", {"step": index, "reason": message})
                if replayed:  # stopped here before and was resumed: fresh retries
                    self.console.say("  (the run had stopped here; resumed with fresh retries)", replay=True)
                    rejections = 0
                    continue
                raise RunStopped(message)
            self.console.say(f"  repeating the step ({rejections} of {self.plan.retries} retries used)", replay=replayed)

    def _static_record(self, index: int, step: StaticRecordStep, label: str) -> None:
        """Command the position, wait for arrival, settle, then stream the static record chunk by chunk into the journal."""
        recorder = getattr(self.session.driver, "static_record", None)
        if recorder is None:
            raise RunStopped(
                f"{label}: this platform driver does not record the INS outputs a system-level static record needs "
                "(the simulated platform does; the network protocol does not yet)"
            )
        hours = step.duration / 3600.0
        what = f"{label}: hold the platform, record {hours:.2f} h at {self.rate:g} Hz — {step.why}"
        self.console.say(what, replay=self.session.replaying)
        self.session.context = {"step": index, "attempt": 1}
        readings = np.asarray(step.readings, dtype=float)
        self.session.operate("command", [float(r) for r in readings])
        arrived = self._wait_until_reached(readings, step.checks)
        if arrived is not None:
            self.session.decide("stop", {"step": index, "reason": arrived})
            raise RunStopped(f"{label}: {arrived}")
        if step.settle > 0:
            self._record(step.settle, "settle", "settle")
        chunks = recorder(step.duration, self.plan.chunk)
        total = int(round(step.duration * self.rate))
        done = 0
        context = {"step": index, "attempt": 1, "phase": "static"}
        self.static_chunks = []
        self.session.static_clock = (-math.inf, False)  # the record's own time base starts with it
        while done < total:
            self.session.context = dict(context)
            self.session.trace = []
            chunk = self.session.operate(
                "static_chunk", [float(len(self.static_chunks))], call=lambda done=done: _next_chunk(chunks, done, total)
            )
            self.static_chunks += self.session.trace
            self.session.trace = None
            done += len(chunk["time"])
            if not self.session.last_replayed:
                self.console.progress("static record", done / self.rate, total / self.rate)
        self.session.context = {"step": index}
        _, replayed = self.session.decide("static_record", {"step": index, "samples": done, "duration": step.duration})
        self.console.say(f"  recorded {done} samples ({done / self.rate / 3600.0:.2f} h)", replay=replayed)

    def _link_failure(self, index: int, attempt: int, name: str, error: Exception, failures: int, consequence: str) -> int:
        """Journal a broken link, say what happens next; stop the run after ``options.link_failures`` in a row.

        Returns the updated count of consecutive failures (reset to 0 when a replayed stop was passed).
        """
        failures += 1
        self.session.decide("interrupted", {"step": index, "attempt": attempt, "reason": str(error)})
        self.console.say(f"  link failure: {error}; {consequence}")
        if failures >= self.options.link_failures:
            message = f"step {name!r}: the link to the platform failed {failures} times in a row (last: {error})"
            _, replayed = self.session.decide("stop", {"step": index, "reason": message})
            if not replayed:
                raise RunStopped(message) from None
            failures = 0
        return failures

    def _wait_until_reached(self, readings: NDArray[np.float64], checks: Checks) -> str | None:
        """Record (and discard) short pieces until the platform is at the commanded readings.

        Returns ``None`` on arrival, else why it did not arrive within ``checks.max_slew``.
        The settle time counts from arrival: slews take as long as they take (10°/s is typical).
        """
        piece = min(1.0, self.plan.chunk)
        waited = 0.0
        context = dict(self.session.context, phase="slew")
        error = math.inf
        while waited < checks.max_slew - 1e-9:
            self.session.context = context
            block = self.session.operate("acquire", [piece])
            waited += piece
            if len(block) == 0 or not np.all(np.isfinite(block.angles)):
                continue
            offsets = np.angle(np.exp(1j * (block.angles - readings)))
            error = float(max(np.max(np.abs(np.mean(offsets, axis=0))), np.max(np.abs(offsets[-1]))))
            if error <= checks.angle_tolerance:
                self.session.context = {k: v for k, v in context.items() if k != "phase"}
                return None
        self.session.context = {k: v for k, v in context.items() if k != "phase"}
        return f"platform did not reach the commanded angles within {checks.max_slew:g} s (still {math.degrees(error):.4f} deg off)"

    def _record(self, duration: float, label: str, phase: str) -> list[SampleBlock]:
        blocks = []
        done = 0.0
        context = dict(self.session.context, phase=phase)
        while duration - done > 1e-9:
            piece = min(self.plan.chunk, duration - done)
            self.session.context = context
            blocks.append(self.session.operate("acquire", [piece]))
            done += piece
            if not self.session.last_replayed:  # a bar for what the platform records, not for what the journal replays
                self.console.progress(label, done, duration)
        self.session.context = {k: v for k, v in context.items() if k != "phase"}
        return blocks

    def _offset_iteration(self, index: int, step: OffsetIterationStep, label: str) -> None:
        from stableins.estimators.offset_iteration import OffsetIterationError, iterate_offsets

        if self.definition is None:
            raise RunStopped(f"{label}: the procedure definition is not available to the zero-offset iteration")
        link_failures = 0
        attempt = 0
        while True:
            attempt += 1
            again = f" (attempt {attempt})" if attempt > 1 else ""
            self.console.say(f"{label}{again} — {step.why}", replay=self.session.replaying)
            self.session.context = {"step": index, "attempt": attempt, "phase": "iteration"}
            self.session.trace = []
            try:
                result = iterate_offsets(
                    SessionDriver(self.session),
                    self.definition,
                    initial_offsets=tuple(float(o) for o in self.offsets),
                    progress=lambda record: self.console.say(f"  {record.describe()}", replay=self.session.last_replayed),
                    extra_terms=self.extra_terms,
                    observer=_IterationConsole(self.console, self.session, self.rate),
                )
            except OffsetIterationError as error:
                message = f"step {step.name!r}: {error}"
                _, replayed = self.session.decide("stop", {"step": index, "reason": message})
                if replayed:
                    continue
                raise RunStopped(message) from None
            except (DriverConnectionError, DriverProtocolError) as error:
                link_failures = self._link_failure(
                    index, attempt, step.name, error, link_failures, "the iteration starts again (its samples so far stay in the journal)"
                )
                continue
            finally:
                trace, self.session.trace = self.session.trace, None
            self.offsets = np.asarray(result.offsets, dtype=float)
            self.iteration = result
            _, replayed = self.session.decide(
                "iteration", {"step": index, "attempt": attempt, "offsets": list(self.offsets), "passes": len(result.history)}
            )
            accepted = iteration_entries(step, trace)
            self.entries += accepted
            for entry in accepted:
                self.session.accept(entry["blocks"])
            seconds = ", ".join(f"{o / 4.84813681109536e-06:+.2f}" for o in self.offsets)
            self.console.say(f"  converged after {len(result.history)} passes: zero offsets ({seconds}) arcsec", replay=replayed)
            return


class _IterationConsole:
    """The console of the zero-offset iteration (:class:`~stableins.estimators.offset_iteration.PassObserver`): every
    dwell of every pass is shown as a dwell of any other stage (:meth:`Console.dwell`, :meth:`Console.progress`,
    :meth:`Console.verdict`); its verdict is the estimator's own check of the dwell (used, or left out of the pass's fit)."""

    def __init__(self, console: Console, session: Session, rate: float) -> None:
        self.console = console
        self.session = session
        self.rate = rate
        self.command: tuple[float, ...] = ()
        self.dwell = 0.0
        self.live = True

    def position(self, pass_number: int, step: Any, command: tuple[float, float, float]) -> None:
        self.command, self.dwell = command, float(step.dwell)
        why = f"ideal axes: {step.expect}" if getattr(step, "expect", "") else ""
        label = f"  pass {pass_number}, position {step.position}"
        self.console.dwell(label, command, step.settle, step.dwell, why, replay=self.session.replaying)

    def phase(self, name: str, done: float, total: float) -> None:
        if done == 0.0:
            self.live = not self.session.replaying
        if self.live:
            self.console.progress(name, done, total)

    def measured(self, block: SampleBlock, summary: Any) -> None:
        result = estimator_verdict(self.command, block, summary, self.dwell, self.rate)
        self.console.verdict(result, replay=self.session.last_replayed, rejected="left out of this pass's fit", indent="    ")


def _next_chunk(chunks: Any, done: int, total: int) -> dict[str, Any]:
    try:
        return next(chunks)
    except StopIteration:
        raise DriverError(f"the platform's recorder stopped after {done} of {total} samples") from None


def _entry(stage: str, pass_number: int, position: int, command: Any, command_time: float, blocks: list[SampleBlock]) -> dict[str, Any]:
    return {
        "stage": stage,
        "pass": pass_number,
        "position": position,
        "command": np.asarray(command, dtype=float),
        "command_time": command_time,
        "blocks": blocks,
    }


def iteration_entries(step: OffsetIterationStep, operations: list[Record]) -> list[dict[str, Any]]:
    """Dwells of a zero-offset iteration from its operations.

    Per position the iteration commands, lets time pass until arrival and settling (acquisitions
    whose samples are discarded) and records the dwell last: the dwell of a command is its last
    acquisition before the next command, and its length must be the position's dwell.
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
    entries = []
    for k, (command, acquisitions) in enumerate(groups):
        if not acquisitions:
            continue
        position = k % n
        dwell = acquisitions[-1]
        expected = step.dwells[position] if step.dwells else None
        if expected is not None and abs(float(dwell["arguments"][0]) - expected) > 1e-9:
            raise JournalMismatch(
                f"zero-offset iteration: the last acquisition after command {k + 1} lasts {dwell['arguments'][0]} s, "
                f"position {step.positions[position]} dwells {expected} s"
            )
        entries.append(
            _entry(
                step.stage, k // n + 1, step.positions[position], command["arguments"], float(command["result"]), [block_from_record(dwell)]
            )
        )
    return entries


def _concatenate(blocks: list[SampleBlock]) -> SampleBlock:
    return SampleBlock(
        time=np.concatenate([b.time for b in blocks]),
        specific_force=np.concatenate([b.specific_force for b in blocks]),
        angles=np.concatenate([b.angles for b in blocks]),
        temperature=np.concatenate([b.temperature for b in blocks]),
    )


def parse_entry(step: PersonStep, text: str) -> Any:
    """The value a person entered for ``step`` (a number within the step's range, or text); InputError otherwise."""
    if step.minimum is None and step.maximum is None and not _is_number(text):
        if not text:
            raise InputError(f"step {step.name!r}: no value entered", field=step.key, expected=f"a value in {step.unit or 'text'}")
        return text
    if not _is_number(text):
        raise InputError(f"step {step.name!r}: {text!r} is not a number", field=step.key, expected=f"a number in {step.unit}")
    value = float(text)
    if (step.minimum is not None and value < step.minimum) or (step.maximum is not None and value > step.maximum):
        raise InputError(
            f"step {step.name!r}: {value:g} {step.unit} is out of range",
            field=step.key,
            expected=f"{step.minimum} to {step.maximum} {step.unit}",
        )
    return value


def _is_number(text: str) -> bool:
    try:
        return math.isfinite(float(text))
    except ValueError:
        return False


# --------------------------------------------------------------------------- resume script
def resume_script(records: list[Record], *, deterministic: bool) -> tuple[list[Record], tuple[int, int] | None]:
    """Records to replay on resume, and the range of operation records to mark superseded.

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


def accepted_columns(entries: list[dict[str, Any]]) -> dict[str, NDArray[Any]]:
    """Accepted dwells as device-level columns (:data:`stableins.data.schema.DEVICE_COLUMNS`), in recording order."""
    parts: dict[str, list[Any]] = {k: [] for k in _DEVICE_NAMES}
    for entry in entries:
        block = _concatenate(entry["blocks"])
        n = len(block)
        parts["time"].append(block.time)
        parts["stage"].append(np.full(n, entry["stage"], dtype=object))
        parts["pass"].append(np.full(n, entry["pass"], dtype=np.int32))
        parts["position"].append(np.full(n, entry["position"], dtype=np.int32))
        parts["time_since_command"].append(block.time - entry["command_time"])
        for k, name in enumerate(("platform", "inner", "middle")):
            parts[f"command_{name}"].append(np.full(n, entry["command"][k]))
            parts[f"angle_{name}"].append(block.angles[:, k])
        for k, axis in enumerate("xyz"):
            parts[f"f_{axis}"].append(block.specific_force[:, k])
        parts["temperature"].append(block.temperature)
    return {k: (np.concatenate(v) if v else np.zeros(0)) for k, v in parts.items()}


def journal_columns(records: list[Record]) -> dict[str, NDArray[Any]]:
    """The accepted dwells straight from a journal (no driver, no re-execution): an independent check.

    Collects, for every accepted verdict (and every converged iteration), the dwell pieces of
    that step and attempt that no resume superseded; raises if a step was accepted twice.
    """
    plan = Plan.from_dict(records[0]["plan"])
    operations = live_operations(records)
    entries: list[tuple[float, dict[str, Any]]] = []
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
            blocks = [block_from_record(r) for r in mine if r.get("phase") == "dwell"]
            new = [_entry(step.stage, step.pass_number, step.position, record["command"], record["command_time"], blocks)]
        entries += [(e["command_time"], e) for e in new]
    return accepted_columns([e for _, e in sorted(entries, key=lambda pair: pair[0])])


_DEVICE_NAMES = tuple(c.name for c in DEVICE_COLUMNS)


__all__ = [
    "Console",
    "EXIT_STOPPED",
    "JournalMismatch",
    "RunOptions",
    "RunStopped",
    "Runner",
    "Session",
    "accepted_columns",
    "evaluate_dwell",
    "live_operations",
    "resume_script",
]
