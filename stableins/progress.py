"""A progress bar on a terminal, silence otherwise (no dependency).

The bar is drawn on stderr only when stderr is a terminal, so logs, pipes and
``--json`` output stay clean.  Redraws are limited to ten per second.

Examples
--------
>>> with Progress(total=n_chunks, label="simulate") as progress:   # doctest: +SKIP
...     for chunk in chunks:
...         writer.append(chunk)
...         progress.update()
"""

from __future__ import annotations

import sys
import time
from typing import TextIO


class Progress:
    """Progress of a job of known (or unknown) size.

    Parameters
    ----------
    total : float, optional
        Total amount of work (chunks, samples, seconds of data ...); ``None`` if unknown.
    label : str
        Shown before the bar.
    stream : text stream, optional
        Where to draw; ``sys.stderr`` by default.
    enabled : bool, optional
        Force the bar on or off; by default on exactly when ``stream`` is a terminal.
    width : int
        Bar width in characters.
    """

    def __init__(
        self, total: float | None = None, label: str = "", *, stream: TextIO | None = None, enabled: bool | None = None, width: int = 30
    ) -> None:
        self.total = total
        self.label = label
        self.stream = sys.stderr if stream is None else stream
        if enabled is None:
            isatty = getattr(self.stream, "isatty", None)
            enabled = bool(isatty and isatty())
        self.enabled = enabled
        self.width = width
        self.done = 0.0
        self._start = time.monotonic()
        self._last_draw = -1.0
        self._drawn = False

    def update(self, amount: float = 1.0) -> None:
        """Add ``amount`` of work done and redraw (at most every 0.1 s)."""
        self.done += amount
        if not self.enabled:
            return
        now = time.monotonic()
        if now - self._last_draw >= 0.1 or (self.total is not None and self.done >= self.total):
            self._last_draw = now
            self._draw(now)

    def line(self, now: float | None = None) -> str:
        """Return the text of the bar as it would be drawn now."""
        elapsed = (time.monotonic() if now is None else now) - self._start
        head = f"{self.label} " if self.label else ""
        if not self.total:
            return f"{head}{self.done:g} done, {elapsed:.1f} s"
        fraction = min(max(self.done / self.total, 0.0), 1.0)
        filled = int(round(fraction * self.width))
        eta = elapsed * (1.0 - fraction) / fraction if fraction > 0 else float("nan")
        eta_text = f"eta {eta:.0f} s" if eta == eta else "eta ?"
        return f"{head}[{'#' * filled}{'.' * (self.width - filled)}] {100 * fraction:3.0f}% {elapsed:.1f} s {eta_text}"

    def _draw(self, now: float) -> None:
        self.stream.write("\r" + self.line(now) + "\x1b[K")
        self.stream.flush()
        self._drawn = True

    def close(self) -> None:
        """Finish the line (only if something was drawn)."""
        if self.enabled and self._drawn:
            self._draw(time.monotonic())
            self.stream.write("\n")
            self.stream.flush()
            self._drawn = False

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
