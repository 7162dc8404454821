"""The platform interface used by the procedures, the zero-offset iteration and the runner.

A driver commands gimbal angle-sensor *readings* (never actual angles: the zero offsets
are unknown to it) and acquires blocks of samples.  The simulated platform, the TCP
driver and the replay driver all implement :class:`PlatformDriver`.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from stableins.samples import SampleBlock
from stableins.site import SiteMetadata


@runtime_checkable
class PlatformDriver(Protocol):
    """What a calibration procedure needs from a platform."""

    @property
    def metadata(self) -> SiteMetadata:
        """Return the site metadata of the platform (latitude, gravity, sample rate, ...)."""

    def command(self, readings: tuple[float, float, float]) -> float:
        """Slew to the commanded angle-sensor readings (platform, inner, middle) [rad].

        Returns the session time [s] at which the command was issued.
        """
        ...

    def read_angles(self) -> NDArray[np.float64]:
        """Return the current angle-sensor readings [rad]."""
        ...

    def acquire(self, duration: float) -> SampleBlock:
        """Record ``duration`` seconds of samples at the platform's sample rate."""
        ...

    def status(self) -> dict[str, object]:
        """Driver state for logs and error messages."""
        ...

    def close(self) -> None:
        """Release the platform (close the connection or file)."""
