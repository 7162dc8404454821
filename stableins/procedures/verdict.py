r"""Checks of a dwell on the platform while it is recorded: reached, still, complete.

The thresholds are those of :class:`~stableins.estimators.layout.DwellChecks`:

- reached: :math:`\max_i |\hat r_i(t_0) - r_i^{cmd}| \le` ``angle_tolerance`` (wrapped to ±π), with
  :math:`\hat r_i(t_0)` the readings' least-squares line at the dwell's first sample: a platform held by its gyros
  turns steadily after it arrived (docs/conventions.md, "The platform during a dwell").
- still: per accelerometer axis, the least-squares line :math:`f(t) = a + b (t - \bar t)` with residual
  standard deviation :math:`s \le` ``scatter_max``; the slope fails only when it exceeds the limit
  beyond its own noise, :math:`|b| - 3\sigma_b >` ``slope_max`` with
  :math:`\sigma_b = s / \sqrt{\sum (t - \bar t)^2}` (a short, noisy dwell is not rejected for noise).
- complete: all samples finite and at least ``min_fraction`` of ``dwell × rate`` of them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from stableins.conventions import MICRO_G
from stableins.estimators.layout import DwellChecks
from stableins.samples import SampleBlock

#: A slope counts against the limit only beyond this many σ of its own noise (short dwells are noisy).
SLOPE_SIGMAS = 3.0


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
        """Return the checked quantities of the dwell as one line of text, in engineering units."""
        return (
            f"reached within {math.degrees(self.angle_error) * 3600:.1f} arcsec, scatter {self.scatter / MICRO_G:.1f} µg, "
            f"slope {self.slope / MICRO_G:.2f} µg/s, {self.samples}/{self.expected_samples} samples"
        )


def evaluate_dwell(command: NDArray[np.float64], block: SampleBlock, checks: DwellChecks, dwell: float, rate: float) -> CheckResult:
    """Run the acceptance checks of one dwell (see the module docstring for the formulas)."""
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
    if scatter > checks.scatter_max:
        reasons.append(f"not still: scatter {scatter / MICRO_G:.1f} µg (limit {checks.scatter_max / MICRO_G:.1f})")
    if excess > checks.slope_max:
        reasons.append(
            f"not still: slope {slope / MICRO_G:.2f} ± {slope_sigma / MICRO_G:.2f} µg/s on {'xyz'[axis]} "
            f"(limit {checks.slope_max / MICRO_G:.2f} µg/s beyond {SLOPE_SIGMAS:g}σ)"
        )
    return CheckResult(not reasons, tuple(reasons), angle_error, scatter, slope, n, expected)


def dwell_statistics(command: Any, block: SampleBlock) -> tuple[float, float, float, float, float, int] | None:
    """Return what the acceptance checks look at in a dwell; ``None`` when it has fewer than 3 samples or a non-finite one.

    Returns ``(angle_error, scatter, slope, slope_sigma, excess, axis)``: the largest absolute difference of the
    readings' least-squares line at the dwell's first sample and the command (wrapped to ±π) [rad]; the largest
    residual standard deviation about the per-axis least-squares line [m/s²]; the slope [m/s² per s] and its 1σ on
    the axis ``axis`` where ``|b| − 3σ_b`` (``excess``) is largest.
    """
    n = len(block.time)
    finite = n > 0 and all(np.all(np.isfinite(a)) for a in (block.time, block.specific_force, block.angles, block.temperature))
    if n < 3 or not finite:
        return None
    t = block.time - block.time.mean()
    # where the readings' line starts: a platform held by its gyros turns steadily after it arrived (a 0.05 °/h drift
    # moves the readings 30″ in 600 s); that is the drift the gyro stage measures, not a failure to arrive
    spread = float(t @ t)
    reading_slope = t @ (block.angles - block.angles.mean(axis=0)) / spread if spread > 0 else np.zeros(3)
    start = np.mean(block.angles, axis=0) + reading_slope * t[0]
    difference = start - np.asarray(command, dtype=float)
    angle_error = float(np.max(np.abs(np.angle(np.exp(1j * difference)))))
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
    """Return the verdict of a dwell the estimator itself checks (the zero-offset iteration's coarse dwells).

    Accepted when the procedure's ``[acceptance]`` checks (:func:`stableins.estimators.dwell.summarize_dwell`) leave it
    usable, else the reasons are its flags; the figures are those of :func:`evaluate_dwell`, so every dwell of every
    stage is described alike.
    """
    statistics = dwell_statistics(command, block)
    angle_error, scatter, slope = statistics[:3] if statistics is not None else (math.inf, math.inf, math.inf)
    return CheckResult(summary.usable, tuple(summary.flags), angle_error, scatter, slope, len(block.time), max(1, int(round(dwell * rate))))
