"""A driver wrapper that keeps what a procedure measured, as device-level data columns.

:class:`RecordingDriver` passes every call through to the wrapped
:class:`~stableins.drivers.base.PlatformDriver` and remembers, for every command, the
command, the time it was issued and the *last* block acquired under it — the dwell
(earlier blocks under the same command are slew waiting and settling).  ``take``
turns what was recorded into columns of :data:`stableins.schema.DEVICE_COLUMNS`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import cast

import numpy as np
from numpy.typing import NDArray

from stableins.drivers.base import PlatformDriver
from stableins.samples import SampleBlock


@dataclass
class _Commanded:
    readings: tuple[float, float, float]
    time: float
    dwell: SampleBlock | None = None


class RecordingDriver:
    """Wrap ``driver``; record the dwell (last acquisition) of every command."""

    def __init__(self, driver: PlatformDriver) -> None:
        self.driver = driver
        self._commands: list[_Commanded] = []

    @property
    def metadata(self):  # noqa: ANN201 - same as the wrapped driver
        """Return the wrapped driver's site metadata."""
        return self.driver.metadata

    def command(self, readings: tuple[float, float, float]) -> float:
        """Command the wrapped driver and record the call."""
        time = self.driver.command(readings)
        self._commands.append(_Commanded(cast("tuple[float, float, float]", tuple(float(r) for r in readings)), float(time)))
        return time

    def read_angles(self) -> NDArray[np.float64]:
        """Read the wrapped driver's angles and record the call."""
        return self.driver.read_angles()

    def acquire(self, duration: float) -> SampleBlock:
        """Acquire from the wrapped driver and record the samples."""
        block = self.driver.acquire(duration)
        if self._commands:
            self._commands[-1].dwell = block
        return block

    def status(self) -> dict[str, object]:
        """Return the wrapped driver's status."""
        return self.driver.status()

    def close(self) -> None:
        """Close the wrapped driver."""
        self.driver.close()

    def take(self, stage: str, positions: Sequence[int]) -> dict[str, NDArray]:
        """Columns of every command recorded since the last ``take``, then forget them.

        The commands are the passes of a procedure in order: command ``k`` is position
        ``positions[k % n]`` of pass ``k // n + 1``.
        """
        commanded, self._commands = self._commands, []
        n = len(positions)
        if n == 0 or len(commanded) % n:
            raise RuntimeError(f"{len(commanded)} commands recorded, not whole passes of {n} positions")
        parts: dict[str, list[NDArray]] = {}
        for k, entry in enumerate(commanded):
            block = entry.dwell
            if block is None or len(block) == 0:
                raise RuntimeError(f"no samples were acquired at command {k + 1} ({stage})")
            position = positions[k % n]
            columns = block.device_columns(
                stage=stage, pass_number=k // n + 1, position=position, command=entry.readings, command_time=entry.time
            )
            for name, values in columns.items():
                parts.setdefault(name, []).append(np.asarray(values))
        return {name: np.concatenate(values) for name, values in parts.items()}
