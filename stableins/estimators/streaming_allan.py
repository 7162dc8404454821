r"""The overlapping Allan variance of a whole record, one chunk at a time (bounded memory).

For rate samples ``y`` at ``τ₀ = 1/rate`` the phase is ``x_j = τ₀ Σ_{i<j} y_i`` (``j = 0 … n``) and the
overlapping Allan variance at cluster size ``m`` (``τ = m τ₀``) is (NIST SP 1065 Eq. 11;
``allantools.oadev`` with ``data_type="freq"``)::

    σ²(τ) = Σ_{j=0}^{N−2m−1} (x_{j+2m} − 2 x_{j+m} + x_j)² / (2 τ² (N − 2m)),    N = n + 1

:class:`StreamingAllan` accumulates the sum of squares and the number of terms per ``m`` as chunks
arrive, keeping only the last ``2 max(m)`` phase points between chunks, so every sample of a record
of any length is used at every ``τ`` and memory stays that of one chunk.  A gap (:meth:`StreamingAllan.gap`)
ends a segment; segments are pooled as :func:`stableins.estimators.allan.allan_points` pools them (the
variance weighted by the number of terms, the segment lengths kept for Greenhall's edf).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stableins.estimators.allan import AllanPoints


class StreamingAllan:
    """Accumulate the overlapping Allan variance of three axes at cluster sizes ``clusters`` over chunks.

    Parameters
    ----------
    clusters : array_like of int
        Cluster sizes ``m`` (``τ = m / rate``).
    rate : float
        Sample rate [Hz].
    """

    def __init__(self, clusters: ArrayLike, rate: float) -> None:
        self.clusters = np.unique(np.asarray(clusters, dtype=np.int64))
        if self.clusters.size == 0 or self.clusters[0] < 1:
            raise ValueError("cluster sizes must be positive integers")
        self.rate = float(rate)
        self._sums = np.zeros((self.clusters.size, 3))
        self._terms = np.zeros(self.clusters.size)
        self._lengths: list[int] = []
        self._tail = np.zeros((1, 3))  # phase points kept from the segment so far (x_0 = 0)
        self._samples = 0

    def add(self, samples: ArrayLike) -> None:
        """Add consecutive samples ``(n, 3)`` that continue the current segment."""
        y = np.asarray(samples, dtype=float).reshape(-1, 3)
        if y.shape[0] == 0:
            return
        phase = self._tail[-1] + np.cumsum(y, axis=0) / self.rate
        x = np.vstack([self._tail, phase])
        first_new = self._tail.shape[0]
        for k, m in enumerate(self.clusters):
            # terms whose last point x_{j+2m} is new: j + 2m >= first_new, j >= 0
            start = max(first_new - 2 * m, 0)
            stop = x.shape[0] - 2 * m
            if stop <= start:
                continue
            d = x[start + 2 * m : stop + 2 * m] - 2.0 * x[start + m : stop + m] + x[start:stop]
            self._sums[k] += np.sum(d * d, axis=0)
            self._terms[k] += stop - start
        keep = int(2 * self.clusters[-1])
        self._tail = x[-keep:] if x.shape[0] > keep else x
        self._samples += y.shape[0]

    def gap(self) -> None:
        """End the current segment (a gap in the record): the next samples start a new one."""
        if self._samples:
            self._lengths.append(self._samples + 1)
        self._tail = np.zeros((1, 3))
        self._samples = 0

    def points(self) -> AllanPoints:
        """Return the pooled points of every cluster size with at least one term."""
        lengths = np.array([*self._lengths, self._samples + 1] if self._samples else self._lengths, dtype=np.int64)
        keep = self._terms > 0
        tau = self.clusters[keep] / self.rate
        variance = self._sums[keep] / (2.0 * tau[:, None] ** 2 * self._terms[keep, None])
        per_cluster = tuple(lengths[2 * m < lengths - 1] for m in self.clusters[keep])
        return AllanPoints(tau, variance, self._terms[keep].astype(float), self.clusters[keep], per_cluster, self.rate)


def octave_clusters(longest: int, max_fraction: int = 8) -> NDArray[np.int64]:
    """Return the octave cluster sizes ``1, 2, 4, …`` up to ``longest / max_fraction`` samples."""
    return 2 ** np.arange(int(np.floor(np.log2(max(longest // max_fraction, 1)))) + 1)
