r"""The slews of a rotating record: where the platform turns, its rate and angular acceleration, window means.

The angular rate comes from the angle readings alone (no slew profile is assumed): the readings are
smoothed and differentiated by a Savitzky–Golay filter (a local cubic over :data:`SMOOTHING` seconds,
symmetric, so without lag), the actual gimbal rates turned into the platform's rate by the exact gimbal
kinematics (:meth:`stableins.platform.GimbalPlatform.angular_rate`),

.. math:: \omega_{bp}^p = s_1\dot\alpha_1 e_3 + R_3(s_1\alpha_1)\big[s_2\dot\alpha_2 e_1 + R_1(s_2\alpha_2)\,s_3\dot\alpha_3 e_2\big],

and ``ω̇`` by central differences of ``ω`` (so that its window mean is the change of ``ω`` across the
window).  The specific force the platform should sense is computed from the unsmoothed readings (exact
kinematics; their noise is white and is measured with the accelerometer noise).  A slew is a run of samples with ``|ω|`` above
:data:`SLEW_RATE_THRESHOLD`; its segment adds :data:`STILL_MARGIN` seconds of the still platform before and after (the
reference levels of the fit).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from stableins.platform import GimbalPlatform

#: Span of the Savitzky–Golay filter that smooths and differentiates the readings [s].
SMOOTHING = 0.15
#: A sample belongs to a slew when the platform turns faster than this [rad/s] (0.06 °/s).
SLEW_RATE_THRESHOLD = 1e-3
#: Still time kept before and after each slew [s] (at most half-way to the next slew): the segment's reference levels.
STILL_MARGIN = 90.0
#: Two runs of motion closer than this [s] are one slew.
JOIN = 2.0
#: Shortest slew analysed [s].
MIN_SLEW = 1.0


@dataclass(frozen=True)
class Motion:
    """Platform motion sampled with the record: smoothed actual angles, ``ω`` and ``ω̇`` in the p-frame.

    Attributes
    ----------
    actual : ndarray (N, 3)
        Actual gimbal angles (readings + zero offsets, not smoothed) [rad].
    rate, acceleration : ndarray (N, 3)
        ``ω_bp^p`` [rad/s] and ``ω̇`` [rad/s²].
    """

    actual: NDArray[np.float64]
    rate: NDArray[np.float64]
    acceleration: NDArray[np.float64]


@dataclass(frozen=True)
class Segment:
    """One slew with its still margins: sample range ``[first, stop)`` and the moving part ``[moving_first, moving_stop)``."""

    first: int
    stop: int
    moving_first: int
    moving_stop: int

    def describe(self, time: NDArray[np.float64]) -> str:
        """One line: when the slew ran and how long."""
        return f"{time[self.moving_first]:.1f}–{time[self.moving_stop - 1]:.1f} s"


def smoothing_length(rate: float) -> int:
    """Odd number of samples of the smoothing filter at ``rate`` [Hz] (at least 7)."""
    n = max(7, int(round(SMOOTHING * rate)))
    return n if n % 2 else n + 1


def motion(readings: NDArray[np.float64], rate: float, platform: GimbalPlatform) -> Motion:
    """Return the platform motion from angle readings (N, 3) [rad] sampled at ``rate`` [Hz] (module docstring)."""
    from scipy.signal import savgol_filter

    n = smoothing_length(rate)
    dt = 1.0 / rate
    if len(readings) < n:
        zeros = np.zeros_like(readings)
        return Motion(platform.actual_angles(readings), zeros, zeros.copy())
    smooth = savgol_filter(readings, n, 3, axis=0, mode="interp")
    reading_rate = savgol_filter(readings, n, 3, deriv=1, delta=dt, axis=0, mode="interp")
    omega = platform.angular_rate(platform.actual_angles(smooth), reading_rate)
    # central differences of ω: a window mean of ω̇ is then the change of ω across the window
    omega_dot = np.gradient(omega, dt, axis=0)
    return Motion(platform.actual_angles(readings), omega, omega_dot)


def find_segments(time: NDArray[np.float64], omega: NDArray[np.float64]) -> tuple[Segment, ...]:
    """Return the slews (runs of ``|ω| > SLEW_RATE_THRESHOLD`` of at least :data:`MIN_SLEW`), each with its still margins.

    A segment never reaches into the next slew: its margins stop half-way between two slews.  Samples
    are consecutive on one clock (gaps are checked by the caller).
    """
    moving = np.linalg.norm(omega, axis=1) > SLEW_RATE_THRESHOLD
    if not np.any(moving):
        return ()
    edges = np.flatnonzero(np.diff(moving.astype(np.int8)))
    starts = list(edges[moving[edges + 1]] + 1) if len(edges) else []
    stops = list(edges[~moving[edges + 1]] + 1) if len(edges) else []
    if moving[0]:
        starts.insert(0, 0)
    if moving[-1]:
        stops.append(len(moving))
    runs: list[list[int]] = []
    for a, b in zip(starts, stops, strict=True):
        if runs and time[a] - time[runs[-1][1] - 1] < JOIN:
            runs[-1][1] = b
        else:
            runs.append([a, b])
    runs = [r for r in runs if time[r[1] - 1] - time[r[0]] >= MIN_SLEW]
    segments = []
    for k, (a, b) in enumerate(runs):
        low = time[a] - STILL_MARGIN
        high = time[b - 1] + STILL_MARGIN
        if k > 0:
            low = max(low, 0.5 * (time[runs[k - 1][1] - 1] + time[a]))
        if k + 1 < len(runs):
            high = min(high, 0.5 * (time[b - 1] + time[runs[k + 1][0]]))
        first = int(np.searchsorted(time, low, side="left"))
        stop = int(np.searchsorted(time, high, side="right"))
        segments.append(Segment(first, stop, int(a), int(b)))
    return tuple(segments)


def window_means(values: NDArray[np.float64], first: int, stop: int, length: int) -> NDArray[np.float64]:
    """Means of ``values[first:stop]`` over consecutive windows of ``length`` samples (the last partial window dropped)."""
    count = (stop - first) // length
    block = values[first : first + count * length]
    return block.reshape((count, length) + values.shape[1:]).mean(axis=1)


def unexcited_arms(commands: list[tuple[float, float, float]], platform: GimbalPlatform | None = None) -> tuple[str, ...]:
    """Cai's along-axis arms (``lever_a_a``) that no move between consecutive commanded readings [rad] excites.

    ``ℓ_aa`` reads the centripetal ``(|ω|² − ω_a²) ℓ_aa``: a turn excites it unless it is about ``a_p``.  The
    rotation axis of a move of one gimbal at the start of the move comes from the gimbal kinematics (a move of
    several gimbals at once is counted by each of them).  A procedure whose moves leave an arm unexcited cannot
    determine it; checked before the platform moves.
    """
    platform = platform or GimbalPlatform()
    excited = np.zeros(3, dtype=bool)
    for before, after in zip(commands[:-1], commands[1:], strict=True):
        for gimbal in range(3):
            if abs(after[gimbal] - before[gimbal]) < 1e-9:
                continue
            rate = np.zeros(3)
            rate[gimbal] = 1.0
            axis = platform.angular_rate(platform.actual_angles(np.asarray(before, dtype=float)), rate)
            axis = axis / np.linalg.norm(axis)
            excited |= 1.0 - axis**2 > 0.1
    return tuple(f"lever_{a}_{a}" for a, on in zip("xyz", excited, strict=True) if not on)
