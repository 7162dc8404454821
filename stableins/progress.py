"""Progress of a long step on the terminal (tqdm), silence otherwise: the one progress concept of the CLI.

Every command that can take more than a couple of seconds shows its long steps with :class:`Progress` (``calibrate
system``'s pass over the record and its sensitivity re-runs, ``noise``, ``report``, ``calibrate device`` and its
``--add`` refits, ``simulate``, ``campaign``, and the settle and dwell bars of ``run``'s console).  The bar is drawn
by tqdm on stderr, and only when stderr is a terminal and the command was not asked for ``--json`` or ``--quiet``
(:func:`silence`), so logs, pipes, the test suite and ``--json | jq`` stay clean.  Redraws are limited to ten per
second.

Examples
--------
>>> with Progress(total=n_chunks, label="simulate") as progress:   # doctest: +SKIP
...     for chunk in chunks:
...         writer.append(chunk)
...         progress.update()
"""

from __future__ import annotations

import shutil
import sys
from collections.abc import Iterator, Sequence
from typing import Any, TextIO

from stableins.schema import Columns

#: Set by :func:`silence` (the CLI's ``--json`` and ``--quiet``): no bar is drawn, whatever the stream.
_silenced = False

#: What a bar looks like: ``label [#####.....]  50% 00:12 eta 00:12`` (one line, redrawn in place).
BAR_FORMAT = "{desc} [{bar}] {percentage:3.0f}% {elapsed} eta {remaining}"
#: A step of unknown size: ``label 12 done 00:04``.
COUNT_FORMAT = "{desc} {n_fmt} done {elapsed}"


#: The bars being drawn now (a message printed meanwhile goes above them, :func:`write`).
_drawn: list[Any] = []


def write(message: str, stream: TextIO | None = None) -> None:
    """Print a line for the person at the terminal (stderr), above any bar being drawn (it is redrawn below)."""
    stream = sys.stderr if stream is None else stream
    if _drawn:
        from tqdm import tqdm

        tqdm.write(message, file=stream)
    else:
        print(message, file=stream)


def silence(*, quiet: bool = True) -> None:
    """Draw no progress in this process (``quiet=False`` restores the default: bars on a terminal)."""
    global _silenced
    _silenced = quiet


def silenced() -> bool:
    """Whether :func:`silence` is in force."""
    return _silenced


class Progress:
    """Progress of a job of known (or unknown) size, a tqdm bar on a terminal.

    Parameters
    ----------
    total : float, optional
        Total amount of work (chunks, samples, seconds of data ...); ``None`` if unknown.
    label : str
        Shown before the bar.
    stream : text stream, optional
        Where to draw; ``sys.stderr`` by default.
    enabled : bool, optional
        Force the bar on or off; by default on exactly when ``stream`` is a terminal and :func:`silence` is not in force.
    width : int, optional
        Bar width in characters (default: what fits the terminal).
    """

    def __init__(
        self,
        total: float | None = None,
        label: str = "",
        *,
        stream: TextIO | None = None,
        enabled: bool | None = None,
        width: int | None = None,
    ) -> None:
        self.total = total
        self.label = label
        self.stream = sys.stderr if stream is None else stream
        if enabled is None:
            isatty = getattr(self.stream, "isatty", None)
            enabled = bool(isatty and isatty()) and not _silenced
        self.enabled = enabled
        self.done = 0.0
        self.width = width
        self._bar: Any = None
        if enabled:
            from tqdm import tqdm

            self._bar = tqdm(
                total=total,
                desc=label,
                file=self.stream,
                bar_format=self._format() if total else COUNT_FORMAT,
                ascii=".#",
                mininterval=0.1,
                ncols=shutil.get_terminal_size().columns,  # tqdm's own probe finds no width on a terminal of unknown size
                leave=True,
            )
            _drawn.append(self._bar)

    def update(self, amount: float = 1.0) -> None:
        """Add ``amount`` of work done and redraw (at most every 0.1 s)."""
        self.done += amount
        if self._bar is not None:
            self._bar.update(amount)

    def set(self, done: float, total: float | None = None) -> None:
        """Set the work done (and the total, when it becomes known): for callbacks that say ``(done, total)``."""
        if total is not None and total != self.total:
            self.total = total
            if self._bar is not None:
                self._bar.total = total
                self._bar.bar_format = self._format()
        self.update(done - self.done)

    def describe(self, label: str) -> None:
        """Say what is being done now (the text before the bar)."""
        self.label = label
        if self._bar is not None:
            self._bar.set_description_str(label)

    def _format(self) -> str:
        return BAR_FORMAT if self.width is None else BAR_FORMAT.replace("{bar}", f"{{bar:{self.width}}}")

    def line(self) -> str:
        """Return the text of the bar as it would be drawn now (empty when no bar is drawn)."""
        return "" if self._bar is None else str(self._bar)

    def close(self) -> None:
        """Finish the line (only if a bar was drawn)."""
        if self._bar is not None:
            self._bar.close()
            _drawn.remove(self._bar)
            self._bar = None

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class CountedSource:
    """A chunk source (:class:`stableins.data.chunks.ChunkSource`) that tells a :class:`Progress` the rows it yields.

    Everything else (``path``, ``columns``, ``metadata``, the time grid ...) is the wrapped source's, so a stage reads
    it exactly as it reads the source.

    Parameters
    ----------
    source : ChunkSource
        The record.
    progress : Progress
        Told the rows of every chunk, as the chunk is handed on.
    """

    def __init__(self, source: Any, progress: Progress) -> None:
        self._source = source
        self.progress = progress

    def __getattr__(self, name: str) -> Any:
        return getattr(self._source, name)

    def iter_chunks(self, columns: Sequence[str] | None = None, rows: int = 1 << 16, **options: Any) -> Iterator[Columns]:
        """Yield the source's chunks, telling the progress the rows of each (its longest column)."""
        for chunk in self._source.iter_chunks(columns, rows, **options):
            yield chunk
            self.progress.update(max((len(v) for v in chunk.values()), default=0))
