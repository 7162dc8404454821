"""Replay driver: plays a recorded run back through the same path as a live platform.

``--driver replay:RUNDIR`` (or ``replay:RUNDIR/journal.bin``) answers every ``command``,
``read_angles`` and ``acquire`` with what the platform answered when the run was recorded,
in the recorded order.  The procedure must ask for the same operations as it did then (the
same commands and dwell durations); the first request that differs stops the replay with a
message naming both, so a recording is never silently applied to a different procedure.
Operations of interrupted attempts that a resume superseded are skipped, as are failed ones.
A driver reads no journal: :func:`stableins.procedures.replay.replay_driver` reads the run's journal and
hands this driver the recorded operations.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from stableins.drivers.errors import DriverError
from stableins.samples import SampleBlock
from stableins.site import SiteMetadata


@dataclass(frozen=True)
class RecordedOperation:
    """One operation as the platform answered it when the run was recorded.

    ``answer`` returns the recorded answer when the replay reaches it (a float for ``command``, the angles
    [rad] for ``read_angles``, a :class:`~stableins.samples.SampleBlock` for ``acquire``), so a recording
    of any length plays back in bounded memory.
    """

    operation: str
    arguments: tuple[float, ...]
    answer: Callable[[], Any]
    #: The record's number in the recording, named by the error of a mismatch.
    seq: int


class ReplayDriver:
    """:class:`~stableins.drivers.base.PlatformDriver` that answers from a recorded run journal."""

    deterministic = True

    def __init__(self, metadata: SiteMetadata, operations: Sequence[RecordedOperation], path: str | Path) -> None:
        self.path = Path(path)
        self._metadata = metadata
        self._operations = list(operations)
        self._next = 0

    @property
    def metadata(self) -> SiteMetadata:
        """Return the site metadata of the replayed run."""
        return self._metadata

    def _take(self, operation: str, arguments: list[float]) -> RecordedOperation:
        if self._next >= len(self._operations):
            raise DriverError(f"replay of {self.path}: the recording ends here, but the procedure asks for {operation} {arguments}")
        record = self._operations[self._next]
        recorded = list(record.arguments)
        if record.operation != operation or len(recorded) != len(arguments) or not np.allclose(recorded, arguments, rtol=0, atol=1e-12):
            raise DriverError(
                f"replay of {self.path}: the procedure asks for {operation} {arguments} but the recording has "
                f"{record.operation} {recorded} at operation {self._next + 1} (record {record.seq}); "
                "a recording plays back only the procedure and options it was made with"
            )
        self._next += 1
        return record

    def command(self, readings: tuple[float, float, float]) -> float:
        """Return the journaled answer to the next command."""
        return float(self._take("command", [float(r) for r in readings]).answer())

    def read_angles(self) -> NDArray[np.float64]:
        """Return the journaled answer to the next angle reading."""
        return np.array(self._take("read_angles", []).answer())

    def acquire(self, duration: float) -> SampleBlock:
        """Return the journaled samples of the next acquisition."""
        block: SampleBlock = self._take("acquire", [float(duration)]).answer()
        return block

    def status(self) -> dict[str, object]:
        """Return the replay's position in the journal."""
        return {"driver": "replay", "path": str(self.path), "operation": self._next, "of": len(self._operations)}

    def close(self) -> None:
        """Release nothing: the recording was read when the driver was made."""
