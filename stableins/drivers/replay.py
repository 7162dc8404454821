"""Replay driver: plays a recorded run back through the same path as a live platform.

``--driver replay:RUNDIR`` (or ``replay:RUNDIR/journal.bin``) answers every ``command``,
``read_angles`` and ``acquire`` with what the platform answered when the run was recorded,
in the recorded order.  The procedure must ask for the same operations as it did then (the
same commands and dwell durations); the first request that differs stops the replay with a
message naming both, so a recording is never silently applied to a different procedure.
Operations of interrupted attempts that a resume superseded are skipped, as are failed ones.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from stableins.drivers.errors import DriverError
from stableins.errors import InputError
from stableins.samples import SampleBlock
from stableins.site import SiteMetadata

JOURNAL_NAME = "journal.bin"


def journal_path(path: str | Path) -> Path:
    """Return the journal file of a run directory (or the journal file itself)."""
    path = Path(path)
    return path / JOURNAL_NAME if path.is_dir() else path


def live_operations(records: list[Any]) -> list[Any]:
    """Operation records that stand: drop those a resume superseded (see :mod:`stableins.procedures.runner`)."""
    superseded: set[int] = set()
    for record in records:
        if record.kind == "resume":
            first, last = record["superseded"] if record.get("superseded") else (0, -1)
            superseded.update(range(first, last + 1))
    return [r for r in records if r.kind == "op" and r.seq not in superseded]


def metadata_from_start(record: Any) -> SiteMetadata:
    """Return the site metadata a journal's start record holds."""
    d = dict(record["metadata"])
    d["gimbal_senses"] = tuple(d["gimbal_senses"])
    d["base_attitude"] = tuple(d["base_attitude"])
    return SiteMetadata(**d)


def block_from_record(record: Any) -> SampleBlock:
    """Return the samples a journaled acquisition holds."""
    a = record.arrays
    return SampleBlock(time=a["time"], specific_force=a["specific_force"], angles=a["angles"], temperature=a["temperature"])


class ReplayDriver:
    """:class:`~stableins.drivers.base.PlatformDriver` that answers from a recorded run journal."""

    deterministic = True

    def __init__(self, path: str | Path) -> None:
        from stableins.procedures.journal import scan

        self.path = journal_path(path)
        records = scan(self.path).records
        if not records or records[0].kind != "start":
            raise InputError("the journal has no start record", path=self.path, expected="a journal written by 'stableins run'")
        self._metadata = metadata_from_start(records[0])
        self._operations = [r for r in live_operations(records) if not r.get("error")]
        self._next = 0

    @property
    def metadata(self) -> SiteMetadata:
        """Return the site metadata of the replayed run."""
        return self._metadata

    def _take(self, operation: str, arguments: list[float]) -> Any:
        if self._next >= len(self._operations):
            raise DriverError(f"replay of {self.path}: the recording ends here, but the procedure asks for {operation} {arguments}")
        record = self._operations[self._next]
        recorded = record["arguments"]
        if record["operation"] != operation or len(recorded) != len(arguments) or not np.allclose(recorded, arguments, rtol=0, atol=1e-12):
            raise DriverError(
                f"replay of {self.path}: the procedure asks for {operation} {arguments} but the recording has "
                f"{record['operation']} {recorded} at operation {self._next + 1} (record {record.seq}); "
                "a recording plays back only the procedure and options it was made with"
            )
        self._next += 1
        return record

    def command(self, readings: tuple[float, float, float]) -> float:
        """Return the journaled answer to the next command."""
        return float(self._take("command", [float(r) for r in readings])["result"])

    def read_angles(self) -> NDArray[np.float64]:
        """Return the journaled answer to the next angle reading."""
        return np.array(self._take("read_angles", []).arrays["angles"])

    def acquire(self, duration: float) -> SampleBlock:
        """Return the journaled samples of the next acquisition."""
        return block_from_record(self._take("acquire", [float(duration)]))

    def status(self) -> dict[str, object]:
        """Return the replay's position in the journal."""
        return {"driver": "replay", "path": str(self.path), "operation": self._next, "of": len(self._operations)}

    def close(self) -> None:
        """Release nothing: the journal was read when the driver was made."""
