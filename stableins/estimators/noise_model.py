r"""Covariance of dwell means under slow noise (bias instability, random walk).

A dwell mean carries white noise, measured within the dwell (:mod:`stableins.estimators.dwell`),
and the slow wander of the bias, which one dwell cannot measure: flicker noise (bias
instability ``B``, Allan floor ``0.664 B``) and acceleration random walk ``K``.  The
slow part is *correlated between dwells*, so the observations of a stage get a full
covariance per axis::

    R_a = diag(σ_white,a²) + C_slow,     C_slow[i, j] = Cov(b̄_i, b̄_j)

with ``b̄_i`` the mean bias over dwell window ``[s_i, s_i + T_i]``.

Flicker is represented, as usual (e.g. IEEE Std 952-1997 Annex C), by first-order
Gauss-Markov processes one decade apart in correlation time ``τ_c`` with variance
``σ_c² = B² ln(10)/π`` each (a density ``1/ln 10`` per ``ln τ_c`` of processes with
PSD ``2σ_c²τ_c/(1 + (2πfτ_c)²)`` sums to ``B²/(2π f)``).  Window means of one
process (unit variance) have, with ``x = T/τ``::

    Var = 2/x − 2(1 − e^{−x})/x²
    Cov = (τ²/(T_i T_j)) (1 − e^{−T_i/τ}) (1 − e^{−T_j/τ}) e^{−gap/τ}     (disjoint windows)

and a random walk ``W(t)`` started at ``t_0`` (the first dwell)::

    Var = K² (s − t_0 + T/3),     Cov = K² (mid_i − t_0)   (window i before window j)

The constant part common to all dwells is absorbed by the bias parameters; the rest
is what makes the fine stage's 1σ honest.  ``B`` and ``K`` come from the instrument's
noise specification (a datasheet or an Allan analysis of a long static record), or,
weakly, from the pooled Allan excess of the dwells themselves
(:func:`stableins.estimators.dwell.pooled_allan_excess`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

#: Correlation times [s] of the Gauss-Markov sum representing flicker noise: 1 s to
#: about one day, the span over which an Allan floor is normally specified.  Flicker
#: variance grows with ln(τ_max); slower wander is a change of bias between sessions.
FLICKER_TIME_CONSTANTS = tuple(10.0**k for k in range(0, 6))


@dataclass(frozen=True)
class SlowNoise:
    """Slow accelerometer noise (same on every axis).

    Attributes
    ----------
    bias_instability : float
        ``B`` [m/s²] (flicker; Allan deviation floor ``0.664 B``).
    random_walk : float
        ``K`` [m/s²/√s] (acceleration random walk).
    source : str
        Where the values come from (shown in reports).
    undetected_bound : float
        When none was given and none was detected: the largest bias instability [m/s²]
        the dwells could still hide (``inf`` when they cannot tell); 0 otherwise.
    """

    bias_instability: float = 0.0
    random_walk: float = 0.0
    source: str = "none"
    undetected_bound: float = 0.0

    @property
    def is_zero(self) -> bool:
        return self.bias_instability == 0.0 and self.random_walk == 0.0

    def settings(self) -> dict[str, float | str]:
        """The values as stage settings in a record (SI: ``bias_instability`` [m/s²], ``random_walk`` [m/s²/√s])."""
        return {"bias_instability": float(self.bias_instability), "random_walk": float(self.random_walk), "source": self.source}

    @classmethod
    def from_settings(cls, settings: dict) -> SlowNoise:
        """Inverse of :meth:`settings` (what a report recomputes with)."""
        source = str(settings.get("source", "record"))
        return cls(float(settings.get("bias_instability", 0.0)), float(settings.get("random_walk", 0.0)), source)

    def describe(self) -> str:
        ug = 9.80665e-6
        return (
            f"slow noise: bias instability {self.bias_instability / ug:.3g} ug, "
            f"random walk {self.random_walk:.3g} m/s^2/sqrt(s) ({self.source})"
        )


def _gauss_markov_window_covariance(start: NDArray, length: NDArray, tau: float) -> NDArray[np.float64]:
    end = start + length
    x = length / tau
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        var = np.where(x > 1e-6, 2.0 / x - 2.0 * (-np.expm1(-x)) / x**2, 1.0 - x / 3.0)
        shape = -np.expm1(-x) / x  # (τ/T)(1 − e^{−T/τ})
    first = np.minimum.outer(end, end)  # end of the earlier window
    later_start = np.maximum.outer(start, start)
    gap = np.clip(later_start - first, 0.0, None)
    cov = np.outer(shape, shape) * np.exp(-gap / tau)
    cov[np.diag_indices_from(cov)] = var
    return cov


def sessions(start: ArrayLike, length: ArrayLike) -> NDArray[np.int64]:
    """Session number of each dwell, in the order given: a dwell that starts before the previous one ended starts a new session.

    Dwells of one session share a time base (one continuous record); a file or pass
    recorded with its own time origin overlaps the windows before it and begins a new one.
    """
    s = np.asarray(start, dtype=float)
    end = s + np.asarray(length, dtype=float)
    new = np.r_[False, s[1:] < end[:-1]] if s.size else np.zeros(0, bool)
    return np.cumsum(new).astype(np.int64)


def dwell_mean_covariance(start: ArrayLike, length: ArrayLike, slow: SlowNoise) -> NDArray[np.float64]:
    """``C_slow`` (m, m) [(m/s²)²] for dwells starting at ``start`` and lasting ``length`` [s], in acquisition order.

    Within one session (:func:`sessions`) the windows are disjoint and the covariance is
    the one derived above.  Different sessions (separate time bases: coarse passes or
    stages recorded as separate runs) are treated as independent draws of the slow
    noise: the covariance between them is zero.  This is exact for the truth simulator,
    which draws every run's noise afresh; for a real instrument whose sessions follow
    each other closely, record them on one time base so that the slow components common
    to both are modelled (otherwise the 1σ of a bias combined over sessions is too small
    by up to ``1/√(number of sessions)`` of its slow part).
    """
    s = np.asarray(start, dtype=float)
    t = np.asarray(length, dtype=float)
    labels = sessions(s, t)
    if labels.size and labels[-1] > 0:
        cov = np.zeros((s.size, s.size))
        for k in range(int(labels[-1]) + 1):
            idx = np.flatnonzero(labels == k)
            cov[np.ix_(idx, idx)] = dwell_mean_covariance(s[idx], t[idx], slow)
        return cov
    m = s.size
    cov = np.zeros((m, m))
    if slow.bias_instability > 0:
        variance = slow.bias_instability**2 * np.log(10.0) / np.pi
        for tau in FLICKER_TIME_CONSTANTS:
            cov += variance * _gauss_markov_window_covariance(s, t, tau)
    if slow.random_walk > 0:
        t0 = s.min()
        mid = s + t / 2 - t0
        earlier = np.where(s[:, None] <= s[None, :], mid[:, None], mid[None, :])
        rw = earlier.copy()
        rw[np.diag_indices(m)] = s - t0 + t / 3
        cov += slow.random_walk**2 * rw
    return cov


def slow_noise_from_allan_excess(excess: ArrayLike, source: str = "pooled Allan excess of the dwells") -> SlowNoise:
    """``B`` from a flicker Allan floor ``e = 0.664² B²`` (per axis; the largest axis is used)."""
    e = float(np.max(np.asarray(excess, dtype=float)))
    return SlowNoise(bias_instability=np.sqrt(max(e, 0.0)) / 0.664, source=source)
