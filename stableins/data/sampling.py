"""Sampling checks of a record's time column: gaps, jitter and the mean rate, streamed chunk by chunk.

:class:`SamplingChecker` follows the time column of a record chunk by chunk in bounded memory and reports
what it found as a :class:`SamplingReport`; :meth:`stableins.data.system.SystemRecord.check_sampling` turns
the report into errors and :class:`SamplingWarning` (docs/formats.md, "Sampling checks").
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from stableins.data.validation import check_finite, check_increasing


@dataclass(frozen=True)
class SamplingIssue:
    """One irregularity of the time column.

    Attributes
    ----------
    kind : str
        ``"gap"`` (a step longer than ``gap_factor`` sample periods) or ``"jitter"``
        (a step off the nominal period by more than the tolerance).
    row : int
        1-based row of the sample after the irregular step.
    step : float
        The step [s].
    expected : float
        Nominal period 1/rate [s].
    """

    kind: str
    row: int
    step: float
    expected: float

    def describe(self, path: str) -> str:
        """Return the irregularity in words, with the file ``path`` and the row."""
        return f"{path}: row {self.row}: {self.kind}: time step {self.step:.6g} s (nominal {self.expected:.6g} s)"


class SamplingWarning(UserWarning):
    """Sampling irregularities that do not stop processing; ``.issues`` and ``.path`` say what and where."""

    def __init__(self, message: str, path: str, issues: Sequence[SamplingIssue]) -> None:
        super().__init__(message)
        self.path = path
        self.issues = tuple(issues)


@dataclass(frozen=True)
class SamplingReport:
    """Result of :meth:`SystemRecord.check_sampling`.

    Attributes
    ----------
    n_samples : int
        Samples checked.
    mean_rate : float
        (n − 1) / (t_last − t_first) [Hz].
    gaps, jitter : tuple of SamplingIssue
        Issues found (jitter capped at the first 100; ``n_jitter`` counts all).
    n_jitter : int
        Number of off-nominal steps.
    max_step_error : float
        Largest ``|step − 1/rate|`` [s].
    """

    n_samples: int
    mean_rate: float
    gaps: tuple[SamplingIssue, ...] = ()
    jitter: tuple[SamplingIssue, ...] = ()
    n_jitter: int = 0
    max_step_error: float = 0.0
    n_gaps: int = 0

    @property
    def uniform(self) -> bool:
        """Whether the record has neither gaps nor jitter."""
        return not self.gaps and not self.n_jitter


class SamplingChecker:
    """Streaming check of a time column against a nominal rate.

    Non-increasing time raises :class:`InputError` at once; gaps and jitter are
    collected.  Feed chunks in order with :meth:`update`, then call :meth:`finish`.

    Parameters
    ----------
    rate : float
        Nominal sample rate [Hz].
    path : str
        File name for messages.
    tolerance : float
        Allowed relative deviation of a step from 1/rate before it counts as jitter.
    gap_factor : float
        A step longer than ``gap_factor / rate`` is a gap (missing samples).
    """

    def __init__(self, rate: float, path: str, tolerance: float = 0.01, gap_factor: float = 1.5) -> None:
        self.rate = float(rate)
        self.period = 1.0 / self.rate
        self.path = path
        self.tolerance = tolerance
        self.gap_factor = gap_factor
        self.n = 0
        self.first: float | None = None
        self.last: float | None = None
        self.gaps: list[SamplingIssue] = []
        self.jitter: list[SamplingIssue] = []
        self.n_jitter = 0
        self.n_gaps = 0
        self.max_step_error = 0.0

    def update(self, time: Any) -> None:
        """Check the time stamps of the next chunk (seconds) against the ones seen so far."""
        import numpy as np

        time = np.asarray(time, dtype=float)
        if time.size == 0:
            return
        check_finite("time", time, self.path, first_row=self.n + 1)
        steps = np.diff(time)
        first = None if self.last is None else time[0] - self.last
        if not ((steps.size == 0 or steps.min() > 0) and (first is None or first > 0)):
            check_increasing(time, self.path, first_row=self.n + 1, previous=self.last)  # names the row
        low, high = (1.0 - self.tolerance) * self.period, min((1.0 + self.tolerance) * self.period, self.gap_factor * self.period)
        if steps.size and low <= steps.min() and steps.max() <= high and (first is None or low <= first <= high):
            # every step regular (the usual case): two passes instead of the per-step bookkeeping below
            self.max_step_error = max(self.max_step_error, float(steps.max()) - self.period, self.period - float(steps.min()))
            if first is not None:
                self.max_step_error = max(self.max_step_error, abs(first - self.period))
            steps = steps[:0]
        elif first is not None:
            steps = np.concatenate([[first], steps])
        row0 = self.n + 1 if self.last is None else self.n
        if steps.size:
            error = np.abs(steps - self.period)
            self.max_step_error = max(self.max_step_error, float(error.max()))
            gap = steps > self.gap_factor * self.period
            self.n_gaps += int(gap.sum())
            for k in np.flatnonzero(gap)[: max(0, 100 - len(self.gaps))]:
                self.gaps.append(SamplingIssue("gap", row0 + int(k) + 1, float(steps[k]), self.period))
            off = (error > self.tolerance * self.period) & ~gap
            self.n_jitter += int(off.sum())
            for k in np.flatnonzero(off)[: max(0, 100 - len(self.jitter))]:
                self.jitter.append(SamplingIssue("jitter", row0 + int(k) + 1, float(steps[k]), self.period))
        if self.first is None:
            self.first = float(time[0])
        self.last = float(time[-1])
        self.n += time.size

    def finish(self) -> SamplingReport:
        """Return the report of every time stamp seen."""
        span = (self.last or 0.0) - (self.first or 0.0)
        mean_rate = (self.n - 1) / span if self.n > 1 and span > 0 else float("nan")
        return SamplingReport(self.n, mean_rate, tuple(self.gaps), tuple(self.jitter), self.n_jitter, self.max_step_error, self.n_gaps)
