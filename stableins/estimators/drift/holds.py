"""The holds of an indexing test: where the platform is still, found from the readings alone."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

#: A sample is "moving" when a gimbal reading changes faster than this over one second [rad/s] (14× the Earth rate).
MOVING_RATE = 1e-3
#: Samples left out on each side of a move (servo settling after an index) [s].
MOVE_MARGIN = 10.0
#: Shortest hold used [s].
MIN_HOLD = 60.0


@dataclass(frozen=True)
class StillHold:
    """One still stretch of the record: sample range, times [s] and the mean platform-frame specific force [m/s²]."""

    first: int
    stop: int
    start: float
    end: float
    specific_force: tuple[float, float, float]

    @property
    def duration(self) -> float:
        """Length of the hold [s]."""
        return self.end - self.start


def small_angle_vector(dcm: NDArray[np.float64]) -> NDArray[np.float64]:
    """Small-angle vector ``θ`` of a frame rotation ``C = I − [θ×] + O(θ²)`` (…, 3).

    First order in ``θ``; the exact inverse of :func:`stableins.platform.rotation_about` is
    :func:`stableins.platform.rotation_vector`.
    """
    return 0.5 * np.stack([dcm[..., 1, 2] - dcm[..., 2, 1], dcm[..., 2, 0] - dcm[..., 0, 2], dcm[..., 0, 1] - dcm[..., 1, 0]], axis=-1)


def find_holds(time: NDArray[np.float64], readings: NDArray[np.float64]) -> tuple[tuple[int, int], ...]:
    """Sample ranges ``[first, stop)`` where no gimbal moves faster than :data:`MOVING_RATE` (turns and :data:`MOVE_MARGIN` cut out)."""
    n = len(time)
    if n < 2:
        return ()
    dt = float(np.median(np.diff(time)))
    lag = max(1, int(round(1.0 / dt)))
    change = np.abs(readings[lag:] - readings[:-lag]).max(axis=1) / (lag * dt) if n > lag else np.zeros(0)
    moving = np.zeros(n, dtype=bool)
    fast = np.flatnonzero(change > MOVING_RATE)
    margin = int(round(MOVE_MARGIN / dt))
    for k in fast:  # few: turns only
        moving[max(0, k - margin) : min(n, k + lag + margin + 1)] = True
    edges = np.diff(np.concatenate([[1], moving.astype(np.int8), [1]]))
    starts, stops = np.flatnonzero(edges == -1), np.flatnonzero(edges == 1)
    return tuple((int(a), int(b)) for a, b in zip(starts, stops, strict=True) if time[b - 1] - time[a] >= MIN_HOLD)
