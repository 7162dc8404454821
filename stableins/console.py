"""The operator console of a procedure run: what the runner says, its progress bars and its prompts.

:class:`Console` is the terminal side of :class:`stableins.procedures.runner.RunConsole`: lines wrapped at the
terminal's width (never cut), settle and dwell bars (:class:`stableins.progress.Progress`), confirmations and
entries read from standard input.  ``stableins run`` builds one from its options (docs/procedures.md).
"""

from __future__ import annotations

import math
import sys
from typing import Any, TextIO

from stableins.procedures.plan import PersonStep
from stableins.procedures.runner import RunStopped
from stableins.procedures.verdict import CheckResult

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
        """Note that the resumed run has replayed its journal (``replayed`` records); said before the next live line."""
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
        """Print the line that opens a dwell of any stage: where the gimbals are commanded, how long it settles and dwells."""
        degrees = ", ".join(f"{math.degrees(r):.4f}" for r in readings)
        reason = f" — {why}" if why else ""
        self.say(f"{label}: command readings ({degrees}) deg, settle {settle:g} s, dwell {dwell:g} s{reason}", replay=replay)

    def verdict(self, result: CheckResult, *, replay: bool = False, rejected: str = "rejected", indent: str = "  ") -> None:
        """Print the verdict of a dwell with its reasons: ``accepted: ...`` or ``<rejected>: <reasons> (...)``."""
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
            self.tell(f"  {answer!r} is neither yes nor no: please answer y or n" if answer else "  please answer y or n")

    def enter(self, step: PersonStep) -> str:
        """Return the text a person enters for ``step`` (``--set``, the default with ``--yes``, or asked)."""
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

    def name(self, key: str, prompt: str) -> str:
        """Return a name a person types for ``key`` (an operator, a laboratory), empty when none is stated.

        ``--set key=NAME`` answers it; unattended (``--yes``) it is not asked and none is stated.  Pressing Enter states
        none, and so does a closed standard input (a script): what needs the name (a certificate) says so.
        """
        if key in self.values:
            self.say(f"  {prompt}: {self.values[key]} (--set)")
            return self.values[key]
        if self.yes:
            self.say(f"  {prompt}: not stated (--yes)")
            return ""
        self._end_bar()
        try:
            return self._ask(f"  {prompt} [Enter: not stated]: ").strip()
        except RunStopped:
            self.say(f"  {prompt}: not stated (standard input is closed)")
            return ""

    def tell(self, text: str) -> None:
        """Print a line for the person answering a prompt (shown even when quiet: a prompt is being asked)."""
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
    except (EOFError, OSError):  # closed, or not readable at all (a detached process; a test harness capturing it)
        raise RunStopped(
            "a person must answer a prompt but standard input is closed; run with --yes (and --set) for unattended runs"
        ) from None
