"""Commanded turns of a space-stable platform by torquing its gyros (indexing; docs/simulator.md, docs/drift-test.md).

The plain description a procedure, a plan, the simulated world and the drift test share: when, about which
gimbal axis, by how much and how fast.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from enum import StrEnum

import numpy as np
from numpy.typing import ArrayLike, NDArray


class IndexAxis(StrEnum):
    """Axis of a commanded index: ``PLATFORM`` (``z_p``) or ``MIDDLE`` (the middle gimbal axis when the turn starts).

    The middle axis is fixed in the base: a turn about it moves the middle gimbal only and never takes the inner
    gimbal through ±90° (the lock of the three-gimbal chain).
    """

    PLATFORM = "platform"
    MIDDLE = "middle"


#: Default peak rate of a commanded index [rad/s] (10°/s, like the device-level slews).
INDEX_RATE = float(np.radians(10.0))


@dataclass(frozen=True)
class PlatformTurn:
    r"""A commanded turn of a space-stable platform in inertial space by torquing its gyros (docs/simulator.md).

    The torquers add ``ψ'(t) a`` to the platform's inertial rate (``a``: the unit :class:`IndexAxis`, positive
    right-handed: the platform reading grows by ``s1 Δ``, the middle one by ``s3 Δ``); the gimbals follow.
    ``ψ(τ) = Δ/2 (1 − cos(πτ/D))`` for ``0 ≤ τ = t − t_0 ≤ D = π|Δ|/(2 ψ'_max)``.

    Parameters
    ----------
    start : float
        ``t_0`` [s] from the start of the record.
    angle : float
        ``Δ`` [rad], non-zero, at most one revolution.
    axis : IndexAxis
    rate : float
        Peak rate ``ψ'_max`` [rad/s], in (0, π].
    """

    start: float
    angle: float
    axis: IndexAxis = IndexAxis.PLATFORM
    rate: float = INDEX_RATE

    def __post_init__(self) -> None:
        object.__setattr__(self, "axis", IndexAxis(self.axis))
        ok = np.isfinite([self.start, self.angle, self.rate]).all() and self.start >= 0.0 and 0.0 < self.rate <= np.pi
        if not (ok and 0.0 < abs(self.angle) <= 2 * np.pi):
            raise ValueError(f"turn at {self.start!r} s by {self.angle!r} rad at {self.rate!r} rad/s: expected t >= 0, 0 < |angle| <= 2 pi")

    @property
    def duration(self) -> float:
        """``D`` [s]."""
        return float(np.pi * abs(self.angle) / (2.0 * self.rate))

    @property
    def end(self) -> float:
        """``t_0 + D`` [s]."""
        return self.start + self.duration

    def angle_at(self, time: ArrayLike) -> NDArray[np.float64]:
        """``ψ(t)`` [rad]: 0 before the turn, ``Δ`` after it."""
        tau = np.clip((np.asarray(time, dtype=float) - self.start) / self.duration, 0.0, 1.0)
        return 0.5 * self.angle * (1.0 - np.cos(np.pi * tau))


def check_turns(turns: Sequence[PlatformTurn], duration: float) -> None:
    """Raise ValueError unless the turns are in time order, do not overlap and end within ``duration`` [s]."""
    end = 0.0
    for k, turn in enumerate(turns):
        if turn.start < end:
            raise ValueError(f"turn {k + 1} starts at {turn.start:g} s, before the previous one ends ({end:g} s)")
        end = turn.end
    if turns and end > duration + 1e-9:
        raise ValueError(f"the last turn ends at {end:g} s, after the record ({duration:g} s)")
