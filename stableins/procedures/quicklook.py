r"""A running quick look at a system-level static record while it is recorded (what the operator sees during a day).

After every chunk of the record the runner updates a :class:`QuickLook` with the chunk's columns (O(n) per chunk:
running sums, nothing kept), and prints :meth:`QuickLook.describe` every so often:

* the **Earth-rate harmonics so far** of the INS's north and east velocity: the least-squares fit of

  .. math:: v(t) = a + b\,t + c\cos\Omega t + d\sin\Omega t

  (:math:`\Omega` the Earth rate, :data:`stableins.conventions.EARTH_RATE`), whose amplitude
  :math:`\sqrt{c^2 + d^2}` the system stage reads (docs/system-calibration.md), and the **rms of the residual**;
  the normal equations are accumulated chunk by chunk, so the fit is that of the whole record so far;
* **gaps**: sample intervals longer than 1.5 sample periods (count and the longest);
* **orientation**: how far the angle-sensor readings moved during each hold beyond the Earth's turn since its start
  (a platform held in inertial space turns with respect to the base at the Earth rate at most; the turns of an
  indexed record excluded), against the procedure's angle tolerance.

It is a quick look, not the estimation: the stage at the end of the run fits the full model.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import NDArray

from stableins.conventions import ARCSEC, EARTH_RATE


class QuickLook:
    """The running quick look at a static record (see the module docstring).

    Parameters
    ----------
    rate : float
        Sample rate [Hz].
    tolerance : float
        Angle tolerance of the procedure [rad]: a hold whose readings wander further is flagged.
    turns : sequence of PlatformTurn
        Indexing during the record (their spans are not holds).
    """

    def __init__(self, rate: float, tolerance: float, turns: Any = ()) -> None:
        self.rate = rate
        self.tolerance = tolerance
        self.windows = [(float(t.start), float(t.start + t.duration)) for t in turns]
        self.samples = 0
        self.start = math.nan
        self.last = math.nan
        self.gaps = 0
        self.longest_gap = 0.0
        self.normal = np.zeros((4, 4))
        self.right = np.zeros((4, 2))
        self.squares = np.zeros(2)
        self.wander = -math.inf
        self.hold: int | None = None  # index of the hold the reference readings belong to
        self.reference = np.zeros(3)
        self.reference_time = 0.0

    def update(self, chunk: Mapping[str, NDArray[np.float64]]) -> None:
        """Add a chunk of the record (:data:`~stableins.schema.SYSTEM_COLUMNS` arrays)."""
        t = np.asarray(chunk["time"], dtype=float)
        if not len(t):
            return
        if math.isnan(self.start):
            self.start = float(t[0])
        steps = np.diff(np.concatenate(([self.last], t)) if not math.isnan(self.last) else t)
        late = steps > 1.5 / self.rate
        self.gaps += int(np.count_nonzero(late))
        if np.any(late):
            self.longest_gap = max(self.longest_gap, float(np.max(steps[late])))
        self.last = float(t[-1])
        tau = t - self.start
        basis = np.column_stack([np.ones_like(tau), tau / 3600.0, np.cos(EARTH_RATE * tau), np.sin(EARTH_RATE * tau)])
        velocity = np.column_stack([chunk["velocity_north"], chunk["velocity_east"]])
        self.normal += basis.T @ basis
        self.right += basis.T @ velocity
        self.squares += np.sum(velocity**2, axis=0)
        self.samples += len(t)
        self._orientation(tau, np.column_stack([chunk["angle_platform"], chunk["angle_inner"], chunk["angle_middle"]]))

    def _orientation(self, tau: NDArray[np.float64], angles: NDArray[np.float64]) -> None:
        """Track how far the readings move within each hold beyond the Earth's turn since the hold's start.

        The platform holds its orientation in inertial space, so its gimbal readings follow the Earth's rotation: none
        turns faster than the Earth rate Ω.  A reading that moved more than ``Ω (t − t_hold)`` from its value at the
        start of the hold, beyond the tolerance, means the platform left its orientation (a gyro or torquer fault).
        """
        hold = np.searchsorted([w[0] for w in self.windows], tau, side="right")  # holds are numbered by the turns before them
        turning = np.zeros(len(tau), dtype=bool)
        for begin, end in self.windows:
            turning |= (tau >= begin) & (tau <= end + 1.0)  # the gimbals follow a turn within a second
        for k in np.flatnonzero(~turning):
            if self.hold != hold[k]:
                self.hold, self.reference, self.reference_time = int(hold[k]), angles[k].copy(), float(tau[k])
            offset = np.abs(np.angle(np.exp(1j * (angles[k] - self.reference))))
            beyond = float(np.max(offset)) - EARTH_RATE * (float(tau[k]) - self.reference_time)
            self.wander = max(self.wander, beyond)

    def harmonics(self) -> tuple[NDArray[np.float64] | None, NDArray[np.float64]] | None:
        """Return (Earth-rate amplitude, residual rms) of the north and east velocity [m/s] so far, or None (too few samples).

        The amplitude is None while the harmonic cannot be told from the mean and the trend (a record of less than a few
        hours): the residual is then that of the mean and the trend alone.
        """
        if self.samples < 8:
            return None
        for size in (4, 2):
            normal = self.normal[:size, :size]
            if np.linalg.cond(normal) < 1e10:
                coefficients = np.linalg.solve(normal, self.right[:size])
                explained = np.sum(coefficients * self.right[:size], axis=0)
                residual = np.sqrt(np.maximum(self.squares - explained, 0.0) / max(self.samples - size, 1))
                return (np.hypot(coefficients[2], coefficients[3]) if size == 4 else None), residual
        return None

    def describe(self) -> str:
        """Return the quick-look line: harmonics and residual rms so far, gaps, orientation."""
        hours = (self.last - self.start) / 3600.0 if self.samples else 0.0
        fit = self.harmonics()
        amplitude, residual = fit if fit is not None else (None, None)
        if residual is None:
            motion = "too few samples for a fit yet"
        elif amplitude is None:
            motion = (
                f"v_N, v_E residual rms {residual[0]:.3g}, {residual[1]:.3g} m/s about mean and trend "
                "(the Earth-rate harmonic cannot be told from them yet)"
            )
        else:
            motion = (
                f"Earth-rate harmonic of v_N, v_E {amplitude[0]:.3g}, {amplitude[1]:.3g} m/s, "
                f"residual rms {residual[0]:.3g}, {residual[1]:.3g} m/s (mean, trend and the harmonic; the stage fits the full model)"
            )
            if hours < 2 * math.pi / EARTH_RATE / 3600.0:
                motion += " — less than a sidereal day: the harmonic is not yet well separated from the trend"
        gaps = "no gaps" if not self.gaps else f"ANOMALY: {self.gaps} gap(s), longest {self.longest_gap:.3g} s"
        beyond = max(self.wander, 0.0) / ARCSEC
        orientation = (
            f"orientation held (readings within the Earth's turn + {beyond:.1f} arcsec)"
            if self.wander <= self.tolerance
            else f"ANOMALY: the platform left its orientation ({beyond:.1f} arcsec beyond the Earth's turn; tolerance "
            f"{self.tolerance / ARCSEC:g})"
        )
        return f"quick look at {hours:.2f} h ({self.samples} samples): {motion}; {gaps}; {orientation}"


__all__ = ["QuickLook"]
