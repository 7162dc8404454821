"""A block of consecutive samples from a platform: the plain type the simulator, the drivers and the runner share."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray


@dataclass(frozen=True)
class SampleBlock:
    """Consecutive samples from the platform.

    Attributes
    ----------
    time : ndarray (n,)
        Session time [s].
    specific_force : ndarray (n, 3)
        Accelerometer outputs f^a [m/s²].
    angles : ndarray (n, 3)
        Angle-sensor readings (platform, inner, middle) [rad].
    temperature : ndarray (n,)
        Instrument temperature [°C].
    """

    time: NDArray[np.float64]
    specific_force: NDArray[np.float64]
    angles: NDArray[np.float64]
    temperature: NDArray[np.float64]

    def __len__(self) -> int:
        return len(self.time)

    @classmethod
    def concatenate(cls, blocks: Sequence[SampleBlock]) -> SampleBlock:
        """Return the sample blocks joined in order."""
        return cls(
            time=np.concatenate([b.time for b in blocks]),
            specific_force=np.concatenate([b.specific_force for b in blocks]),
            angles=np.concatenate([b.angles for b in blocks]),
            temperature=np.concatenate([b.temperature for b in blocks]),
        )
