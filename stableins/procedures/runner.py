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

Modules: :mod:`~stableins.procedures.session` (the journal-backed session), :mod:`~stableins.procedures.verdict`
(the checks of a dwell while it is recorded), :mod:`~stableins.procedures.entries` (the accepted dwells as
columns, what a resume replays); the operator console is :class:`stableins.console.Console`.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any, Protocol, cast

import numpy as np
from numpy.typing import NDArray

from stableins.conventions import ARCSEC
from stableins.documents import JSONObject
from stableins.drivers.errors import DriverConnectionError, DriverError, DriverProtocolError
from stableins.errors import InputError
from stableins.estimators.layout import DwellChecks
from stableins.procedures.entries import AcceptedDwell, dwell_entry, iteration_entries
from stableins.procedures.journal import Record
from stableins.procedures.plan import DwellStep, OffsetIterationStep, PersonStep, Plan, StaticRecordStep
from stableins.procedures.quicklook import QuickLook
from stableins.procedures.session import Session, SessionDriver
from stableins.procedures.verdict import CheckResult, estimator_verdict, evaluate_dwell
from stableins.samples import SampleBlock
from stableins.schema import Columns

#: A static record prints its quick look (:class:`~stableins.procedures.quicklook.QuickLook`) this many times (and at
#: least a chunk apart): a day-long record every 3 h, the 21-min drift test every 2.6 min.
QUICK_LOOKS = 8


class RunStopped(Exception):
    """The run stopped (a step failed too often, the link failed too often); it can be resumed."""


# --------------------------------------------------------------------------- console
class RunConsole(Protocol):
    """What the runner says and asks (the operator console, :class:`stableins.console.Console`, is one).

    ``yes``: unattended (confirm everything, use defaults); ``values``: values given for ``enter`` steps.
    """

    yes: bool
    values: dict[str, str]

    def say(self, text: str, *, replay: bool = False) -> None:
        """Print ``text``; ``replay``: marked as answered by the journal."""

    def dwell(self, label: str, readings: Any, settle: float, dwell: float, why: str = "", *, replay: bool = False) -> None:
        """Print the line that opens a dwell."""

    def verdict(self, result: CheckResult, *, replay: bool = False, rejected: str = "rejected", indent: str = "  ") -> None:
        """Print the verdict of a dwell with its reasons."""

    def progress(self, label: str, done: float, total: float) -> None:
        """Progress of a settle or dwell phase."""

    def confirm(self, prompt: str) -> bool:
        """Ask a person to confirm ``prompt``."""

    def enter(self, step: PersonStep) -> str:
        """Return the text a person enters for ``step``."""

    def tell(self, text: str) -> None:
        """Print a line for the person answering a prompt."""

    def journal_used_up(self, replayed: int) -> None:
        """Note that the resumed run has replayed its journal (``replayed`` records)."""


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
        console: RunConsole,
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
        self.inputs: dict[str, float | str] = {}
        #: accepted dwells in the order they were recorded (see :func:`accepted_columns`)
        self.entries: list[AcceptedDwell] = []
        #: result of the zero-offset iteration, if the plan has one
        self.iteration: Any = None
        #: journal records of the system-level static record, in order (if the plan has one)
        self.static_chunks: list[Record] = []

    def execute(self) -> None:
        """Run every step of the plan in order (journaled; resumable)."""
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
                    self.console.tell(f"  {error.message} (expected {error.expected}); please enter it again")

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
                slew: list[SampleBlock] = []
                arrived = self._wait_until_reached(readings, step.checks, keep=slew if step.keep_slew else None)
                if arrived is None and step.settle > 0:
                    slew += self._record(step.settle, "settle", "settle")
                blocks = self._record(step.dwell, "dwell", "dwell") if arrived is None else []
            except (DriverConnectionError, DriverProtocolError) as error:
                link_failures = self._link_failure(
                    index,
                    attempt,
                    step.name,
                    error,
                    failures=link_failures,
                    consequence="this attempt's samples are set aside (kept in the journal); repeating the step",
                )
                continue
            if arrived is None:
                result = evaluate_dwell(readings, SampleBlock.concatenate(blocks), step.checks, step.dwell, self.rate)
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
                kept = (slew + blocks) if step.keep_slew else blocks
                self.entries.append(
                    dwell_entry(step.stage, step.pass_number, step.position, command=readings, command_time=command_time, blocks=kept)
                )
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
                "(the simulated platform does; a network platform does when its greeting states NAV, docs/protocol.md)"
            )
        hours = step.duration / 3600.0
        what = f"{label}: hold the platform, record {hours:.2f} h at {self.rate:g} Hz — {step.why}"
        for turn in step.turns:
            what += (
                f"\n  index at {turn.start:g} s: {math.degrees(turn.angle):+g} deg about the {turn.axis.value} gimbal axis "
                f"by torquing ({turn.duration:.1f} s)"
            )
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
        chunks = recorder(step.duration, self.plan.chunk, turns=step.turns) if step.turns else recorder(step.duration, self.plan.chunk)
        total = int(round(step.duration * self.rate))
        done = 0
        context: JSONObject = {"step": index, "attempt": 1, "phase": "static"}
        self.static_chunks = []
        self.session.static_clock = (-math.inf, False)  # the record's own time base starts with it
        look = QuickLook(self.rate, step.checks.angle_tolerance, step.turns)  # what the operator sees during a long record
        interval = max(self.plan.chunk, step.duration / QUICK_LOOKS)
        next_look = interval
        while done < total:
            self.session.context = dict(context)
            self.session.trace = []
            chunk = self.session.operate(
                "static_chunk", [float(len(self.static_chunks))], call=functools.partial(_next_chunk, chunks, done, total)
            )
            self.static_chunks += self.session.trace
            self.session.trace = None
            done += len(chunk["time"])
            look.update(chunk)
            due = done / self.rate >= next_look - 1e-9 or done >= total
            while next_look <= done / self.rate + 1e-9:
                next_look += interval
            if not self.session.last_replayed:
                self.console.progress("static record", done / self.rate, total / self.rate)
                if due:
                    self.console.say(f"  {look.describe()}")
        self.session.context = {"step": index}
        _, replayed = self.session.decide("static_record", {"step": index, "samples": done, "duration": step.duration})
        self.console.say(f"  recorded {done} samples ({done / self.rate / 3600.0:.2f} h)", replay=replayed)

    def _link_failure(self, index: int, attempt: int, name: str, error: Exception, *, failures: int, consequence: str) -> int:
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

    def _wait_until_reached(self, readings: NDArray[np.float64], checks: DwellChecks, keep: list[SampleBlock] | None = None) -> str | None:
        """Record short pieces until the platform is at the commanded readings (discarded, or appended to ``keep``).

        Returns ``None`` on arrival, else why it did not arrive within ``checks.max_slew``.
        The settle time counts from arrival: slews take as long as they take (10°/s is typical).
        """
        piece = min(1.0, self.plan.chunk)
        waited = 0.0
        context = dict(self.session.context, phase="slew")
        error = math.inf
        degrees = ", ".join(f"{math.degrees(r):.4f}" for r in readings)
        label = f"slewing: waiting for arrival at ({degrees}) deg within {checks.angle_tolerance / ARCSEC:g} arcsec"
        while waited < checks.max_slew - 1e-9:
            self.session.context = context
            block = self.session.operate("acquire", [piece])
            waited += piece
            if not self.session.last_replayed:  # what the platform is waiting for, second by second (at most max_slew)
                self.console.progress(label, waited, checks.max_slew)
            if keep is not None:
                keep.append(block)
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
        from stableins.procedures.iteration import OffsetIterationError, iterate_offsets

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
                observer = _IterationConsole(self.console, self.session, self.rate)
                # the dwells journaled and shown a chunk at a time, as every other dwell
                driver = SessionDriver(self.session, piece=self.plan.chunk, on_piece=observer.piece)
                result = iterate_offsets(
                    driver,
                    self.definition,
                    initial_offsets=cast("tuple[float, float, float]", tuple(float(o) for o in self.offsets)),
                    progress=lambda record: self.console.say(f"  {record.describe()}", replay=self.session.last_replayed),
                    extra_terms=self.extra_terms,
                    observer=observer,
                )
            except OffsetIterationError as error:
                message = f"step {step.name!r}: {error}"
                _, replayed = self.session.decide("stop", {"step": index, "reason": message})
                if replayed:
                    continue
                raise RunStopped(message) from None
            except (DriverConnectionError, DriverProtocolError) as error:
                link_failures = self._link_failure(
                    index,
                    attempt,
                    step.name,
                    error,
                    failures=link_failures,
                    consequence="the iteration starts again (its samples so far stay in the journal)",
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
                self.session.accept(entry.blocks)
            seconds = ", ".join(f"{o / ARCSEC:+.2f}" for o in self.offsets)
            self.console.say(f"  converged after {len(result.history)} passes: zero offsets ({seconds}) arcsec", replay=replayed)
            return


class _IterationConsole:
    """The console of the zero-offset iteration (:class:`~stableins.procedures.iteration.PassObserver`).

    Every dwell of every pass is shown as a dwell of any other stage (:meth:`Console.dwell`, :meth:`Console.progress`,
    :meth:`Console.verdict`); its verdict is the estimator's own check of the dwell (used, or left out of the pass's fit).
    """

    def __init__(self, console: RunConsole, session: Session, rate: float) -> None:
        self.console = console
        self.session = session
        self.rate = rate
        self.command: tuple[float, ...] = ()
        self.dwell = 0.0
        self.live = True
        self.current = ("", 0.0)  # the phase being recorded: name, length [s]

    def position(self, pass_number: int, step: Any, command: tuple[float, float, float]) -> None:
        self.command, self.dwell = command, float(step.dwell)
        why = f"ideal axes: {step.expect}" if getattr(step, "expect", "") else ""
        label = f"  pass {pass_number}, position {step.position}"
        self.console.dwell(label, command, step.settle, step.dwell, why, replay=self.session.replaying)

    def phase(self, name: str, done: float, total: float) -> None:
        if done == 0.0:
            self.live = not self.session.replaying
            self.current = (name, total)
        if self.live:
            self.console.progress(name, done, total)

    def piece(self, done: float) -> None:
        """Show that ``done`` seconds of the current settle or dwell are recorded (a piece arrived)."""
        name, total = self.current
        if self.live and name and done < total:  # its end is shown by phase()
            self.console.progress(name, done, total)

    def measured(self, block: SampleBlock, summary: Any) -> None:
        result = estimator_verdict(self.command, block, summary, self.dwell, self.rate)
        self.console.verdict(result, replay=self.session.last_replayed, rejected="left out of this pass's fit", indent="    ")


def _next_chunk(chunks: Any, done: int, total: int) -> Columns:
    try:
        return next(chunks)
    except StopIteration:
        raise DriverError(f"the platform's recorder stopped after {done} of {total} samples") from None


def parse_entry(step: PersonStep, text: str) -> Any:
    """Return the value a person entered for ``step`` (a number within the step's range, or text); InputError otherwise."""
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


__all__ = [
    "RunConsole",
    "RunOptions",
    "RunStopped",
    "Runner",
    "parse_entry",
]
