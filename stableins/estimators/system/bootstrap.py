r"""The null law of the coloured-noise tests from the record's own design: the residual ordinates drawn (parametric bootstrap).

The decision on slow noise and the test of a given datasheet (:func:`.whittle.fit_coloured_noise`,
:func:`.whittle.given_rejected`) compare a likelihood ratio of the Whittle likelihood with an asymptotic law (χ̄², χ²).
Both laws assume independent, exponentially distributed ordinates.  The record's low-band ordinates are not: the fits'
residual makers correlate neighbouring projections, a random walk's growth over the record leaks into every low-band
frequency along one direction, and one axis' noise reaches the z, pitch and roll channels.  Measured on one-day records
through the truth simulator, the asymptotic laws left the decision at 6 % false alarms on white records and the datasheet
test at 10 % false rejections of a true datasheet (docs/system-calibration.md §1a, §10).

:class:`OrdinateLaw` carries the exact Gaussian law of the low-band projections under any noise model
(:func:`.spectrum.ordinate_factors`: the residual makers, the loop's bin mixing, the bin kernels) and the high band's
exponential ordinates (white-dominated, where the Whittle approximation holds); :func:`monte_carlo_p_value` draws ordinates
from it under the null hypothesis, recomputes the statistic on each draw exactly as on the record, and returns the
Monte Carlo p-value ``(1 + #{S_b ≥ S})/(1 + B)`` with Besag & Clifford's (1991) sequential stop after :data:`EXCEEDANCES`
exceedances.  Under a simple null this p-value is exact (``P(p ≤ α) ≤ α``); the white levels (and the held levels'
scale) are plugged in at their fit under the null, a parametric bootstrap.
"""

from __future__ import annotations

import zlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.typing import NDArray

#: Draws of the Monte Carlo null law at most (the p-value's resolution ``1/(1 + DRAWS)``).
DRAWS = 399
#: Sequential stop (Besag & Clifford 1991): once this many draws reach the record's statistic, the p-value is
#: ``EXCEEDANCES/draws`` (a large p-value is known well enough after a few dozen draws).
EXCEEDANCES = 20
#: The seed of the draws, with the record's ordinates (:func:`monte_carlo_p_value`): the stage is deterministic (the same
#: record gives the same p-value) and different records have independent draws (so the test's level is exact over records,
#: not that of one fixed set of draws).
SEED = 20250125
#: The Monte Carlo law is drawn when the asymptotic p-value is in this range: below it the statistic is far beyond any
#: null draw (tens of likelihood units), above it far inside (on 100 white records the asymptotic and Monte Carlo
#: p-values agree to ±0.1 there).
ZONE = (1e-5, 0.3)


@dataclass(frozen=True)
class OrdinateLaw:
    """The law of the record's periodogram ordinates under a noise model, to draw from (module docstring).

    Attributes
    ----------
    factors : callable
        Returns ``(white, coloured)`` (:func:`.spectrum.ordinate_factors`), made on first use: only a p-value near the
        decision (:data:`ZONE`) draws from the law, so most records never pay for its factors.
    high : ndarray (h, 1 + kinds)
        The high band's expectations per unit z white level and per unit amplitude (its ordinates exponential).
    held : ndarray
        The pitch and roll white levels held at the measured noise (the fit's ``offset``), else empty.
    """

    factors: Callable[[], tuple[Sequence[NDArray[np.float64]], Sequence[Sequence[NDArray[np.float64]]]]]
    high: NDArray[np.float64]
    held: NDArray[np.float64]

    @cached_property
    def _made(self) -> tuple[tuple[NDArray[np.float64], ...], tuple[tuple[NDArray[np.float64], ...], ...]]:
        white, coloured = self.factors()
        return tuple(white), tuple(tuple(per_axis) for per_axis in coloured)

    @property
    def white(self) -> tuple[NDArray[np.float64], ...]:
        """Per low-band channel (z, pitch, roll): the factor ``(R, n)`` of its white noise per unit per-sample level.

        ``R = 2 m P`` projection rows (``m`` frequencies, ``P`` channels).
        """
        return self._made[0]

    @property
    def coloured(self) -> tuple[tuple[NDArray[np.float64], ...], ...]:
        """Per coloured kind (:data:`.spectrum.COLOURED_KINDS`) and accelerometer axis: the factor ``(R, n)`` per unit amplitude."""
        return self._made[1]

    def levels(self, fitted: NDArray[np.float64], scale: float = 1.0) -> NDArray[np.float64]:
        """Return the white level of every low-band channel: the fitted ones, then the held ones times ``scale``."""
        fitted = np.asarray(fitted, dtype=float)
        return np.concatenate([fitted, scale * self.held]) if self.held.size else fitted

    def draw(
        self, levels: NDArray[np.float64], amplitudes: NDArray[np.float64], rng: np.random.Generator, size: int
    ) -> NDArray[np.float64]:
        """Draw ``size`` sets of ordinates ``(size, ordinates)`` in the design's order (low band channel by channel, high band).

        ``levels`` (P,): the channels' white levels; ``amplitudes`` (kinds,): one per coloured kind for the three axes.
        """
        rows, n = self.white[0].shape
        projections = np.zeros((rows, size))
        for factor, level in zip(self.white, levels, strict=True):
            if level > 0.0:
                projections += np.sqrt(level) * (factor @ rng.standard_normal((n, size)))
        for per_axis, amplitude in zip(self.coloured, amplitudes, strict=True):
            if amplitude > 0.0:
                for factor in per_axis:
                    projections += np.sqrt(amplitude) * (factor @ rng.standard_normal((n, size)))
        m = rows // (2 * len(self.white))
        pairs = projections.reshape(len(self.white), 2, m, size)
        low = 0.5 * (pairs[:, 0] ** 2 + pairs[:, 1] ** 2).reshape(-1, size)
        means = self.high @ np.concatenate([[levels[0]], amplitudes])
        high = rng.exponential(np.maximum(means, 0.0)[:, None], size=(means.size, size))
        return np.vstack([low, high]).T


def monte_carlo_p_value(
    statistic: Callable[[NDArray[np.float64]], float],
    observed: float,
    law: OrdinateLaw,
    levels: NDArray[np.float64],
    amplitudes: NDArray[np.float64],
    *,
    record: NDArray[np.float64],
) -> tuple[float, int]:
    """Return the Monte Carlo p-value of ``observed`` under the law with these levels and amplitudes, and the draws used.

    ``statistic(ordinates)`` is the test's statistic computed on a draw exactly as on the record.  ``(1 + #{S_b ≥ S})/(1 + B)``
    after :data:`DRAWS` draws, or ``EXCEEDANCES/B`` as soon as :data:`EXCEEDANCES` draws reach ``observed`` (Besag & Clifford
    1991).  The draws' seed is :data:`SEED` and the ``record``'s ordinates (a digest of their bytes).
    """
    digest = zlib.crc32(np.ascontiguousarray(record, dtype=np.float64).tobytes())
    rng = np.random.default_rng([SEED, digest])
    exceed, done = 0, 0
    batch = 50
    while done < DRAWS:
        size = min(batch, DRAWS - done)
        for ordinates in law.draw(levels, amplitudes, rng, size):
            done += 1
            exceed += statistic(ordinates) >= observed
            if exceed >= EXCEEDANCES:
                return exceed / done, done
    return (1 + exceed) / (1 + done), done


__all__ = ["DRAWS", "EXCEEDANCES", "SEED", "ZONE", "OrdinateLaw", "monte_carlo_p_value"]
