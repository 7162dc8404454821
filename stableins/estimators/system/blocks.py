"""Block means of the decimated attitude record in bounded memory (:class:`AttitudeBlocks`; the attitude fit's input).

:class:`.gyro_drift.GimbalBlocks` keeps the gimbal readings on the same bins.  docs/system-calibration.md §2, §6.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np
from numpy.typing import NDArray


@dataclass
class AttitudeBlocks:
    """Block means of the attitude record (streaming accumulator) in bounded memory.

    Blocks are fixed time bins of ``block_seconds`` from ``start_time``; each keeps the sample
    count and the sums of time, ``cos S``, ``sin S``, pitch and roll.  When the record would need
    more than ``max_blocks`` bins, adjacent pairs are merged and ``block_seconds`` doubles (sums
    add exactly, so this equals accumulating with the doubled width from the start): memory is
    bounded by ``6 · max_blocks`` values whatever the record length, and so is the cost of the fit.  The
    default, 2¹⁴ bins, keeps the 10-s blocks up to 1.9 days; a week gets 40-s blocks, still 126 times shorter
    than the Schuler period.  They attenuate the 8-minute case-rotation nuisance by 1.1 % (its amplitude is
    free, so nothing is biased) and the Earth-rate harmonics by about 1e-6 of their size (the block means of
    ``cos S`` and ``sin S`` are exact; ``cos 2S`` from them is second order in the block's angle).
    """

    block_seconds: float
    start_time: float
    max_blocks: int = 1 << 14
    sums: dict[str, NDArray[np.float64]] = field(default_factory=dict)

    _KEYS: ClassVar[tuple[str, ...]] = ("count", "time", "cos", "sin", "pitch", "roll")

    def add(
        self,
        time: NDArray[np.float64],
        cos_s: NDArray[np.float64],
        sin_s: NDArray[np.float64],
        pitch: NDArray[np.float64],
        roll: NDArray[np.float64],
    ) -> None:
        """Add decimated samples (time, ``cos S``, ``sin S``, pitch, roll) to their blocks."""
        self._accumulate(time, {"cos": cos_s, "sin": sin_s, "pitch": pitch, "roll": roll})

    def _accumulate(self, time: NDArray[np.float64], columns: dict[str, NDArray[np.float64]]) -> None:
        """Add samples of ``columns`` (the keys of :attr:`_KEYS` but count and time) at ``time`` to their blocks."""
        while True:
            index = np.floor((time - self.start_time) / self.block_seconds).astype(np.int64)
            if int(index[-1]) < self.max_blocks:
                break
            self._merge_pairs()
        lo = int(index[0])
        local = index - lo
        size = int(local[-1]) + 1
        values = {"count": None, "time": time - self.start_time, **columns}
        needed = lo + size
        for key in self._KEYS:
            arr = self.sums.get(key)
            if arr is None:
                arr = np.zeros(min(max(needed, 1024), self.max_blocks))
            elif arr.size < needed:
                arr = np.concatenate([arr, np.zeros(min(max(needed - arr.size, arr.size), self.max_blocks - arr.size))])
            arr[lo:needed] += np.bincount(local, weights=values[key], minlength=size)
            self.sums[key] = arr

    def _merge_pairs(self) -> None:
        """Merge bins ``(2j, 2j+1)`` into bin ``j`` and double ``block_seconds``."""
        for key, arr in self.sums.items():
            if arr.size % 2:
                arr = np.append(arr, 0.0)
            self.sums[key] = arr.reshape(-1, 2).sum(axis=1)
        self.block_seconds *= 2.0

    def means(self) -> dict[str, NDArray[np.float64]]:
        """Return the block means of the non-empty blocks (``count``, ``time`` since the start, ``cos``, ``sin``, pitch, roll)."""
        count = self.sums["count"]
        keep = count > 0
        out = {"count": count[keep]}
        for key in self._KEYS[1:]:
            out[key] = self.sums[key][keep] / count[keep]
        norm = np.hypot(out["cos"], out["sin"])  # block averaging shrinks (cos, sin) by ~1 − (ωT)²/24
        out["cos"], out["sin"] = out["cos"] / norm, out["sin"] / norm
        return out


__all__ = ["AttitudeBlocks"]
