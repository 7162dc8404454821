"""A block of consecutive samples from a platform: the plain type the simulator, the drivers and the runner share."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray


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

    def device_columns(self, *, stage: str, pass_number: int, position: int, command: ArrayLike, command_time: float) -> dict[str, NDArray]:
        """Return these samples as one dwell's rows of a device file (:data:`stableins.schema.DEVICE_COLUMNS`).

        The samples were recorded at ``position`` of ``stage``'s pass ``pass_number`` after the command ``command``
        (readings [rad]) given at ``command_time`` [s]: the simulator's dwells and a recorded platform's are written alike.
        """
        n = len(self)
        r = np.asarray(command, dtype=float)
        return {
            "time": self.time,
            "stage": np.full(n, stage),
            "pass": np.full(n, pass_number, dtype=np.int32),
            "position": np.full(n, position, dtype=np.int32),
            "time_since_command": self.time - command_time,
            "command_platform": np.full(n, r[0]),
            "command_inner": np.full(n, r[1]),
            "command_middle": np.full(n, r[2]),
            "angle_platform": self.angles[:, 0],
            "angle_inner": self.angles[:, 1],
            "angle_middle": self.angles[:, 2],
            "f_x": self.specific_force[:, 0],
            "f_y": self.specific_force[:, 1],
            "f_z": self.specific_force[:, 2],
            "temperature": self.temperature,
        }
