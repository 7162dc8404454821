"""Closed forms of the noise model: Allan variance and window-mean covariances of its processes.

:class:`~stableins.noise.NoiseModel` builds its Allan variance and its dwell-mean covariance from these
(derivations in docs/noise.md and the module docstring of :mod:`stableins.noise`).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray


def gauss_markov_allan(x: NDArray[np.float64]) -> NDArray[np.float64]:
    """Allan variance of a unit-variance Gauss-Markov process at ``x = τ/τ_c``: ``v(x) − c(x)``."""
    x = np.asarray(x, dtype=float)
    small = x < 1e-3
    xs = np.where(small, 1.0, x)
    v = 2.0 / xs - 2.0 * (-np.expm1(-xs)) / xs**2
    c = (-np.expm1(-xs) / xs) ** 2
    series = 2.0 * x / 3.0 - x**2 / 2.0 + 7.0 * x**3 / 30.0
    return np.where(small, series, v - c)


def gauss_markov_window_covariance(start: NDArray, length: NDArray, tau: float) -> NDArray[np.float64]:
    """Covariance of window means of a unit-variance Gauss-Markov process (disjoint windows)."""
    end = start + length
    x = length / tau
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        var = np.where(x > 1e-6, 2.0 / x - 2.0 * (-np.expm1(-x)) / x**2, 1.0 - x / 3.0)
        shape = np.where(x > 1e-12, -np.expm1(-x) / x, 1.0)  # (τ/T)(1 − e^{−T/τ})
    first = np.minimum.outer(end, end)  # end of the earlier window
    later_start = np.maximum.outer(start, start)
    gap = np.clip(later_start - first, 0.0, None)
    cov = np.outer(shape, shape) * np.exp(-gap / tau)
    cov[np.diag_indices_from(cov)] = var
    return cov


def random_walk_window_covariance(start: NDArray, length: NDArray) -> NDArray[np.float64]:
    """Covariance of window means of ``W(t − t_0)`` (unit intensity), ``t_0`` the first window's start."""
    t0 = start.min()
    mid = start + length / 2 - t0
    cov = np.where(start[:, None] <= start[None, :], mid[:, None], mid[None, :])
    cov[np.diag_indices(start.size)] = start - t0 + length / 3
    return cov


def sessions(start: ArrayLike, length: ArrayLike) -> NDArray[np.int64]:
    """Session number of each dwell, in the order given: a dwell that starts before the previous one ended starts a new session.

    Dwells of one session share a time base (one continuous record); a file or pass
    recorded with its own time origin overlaps the windows before it and begins a new one.
    """
    s = np.asarray(start, dtype=float).reshape(-1)
    end = s + np.asarray(length, dtype=float).reshape(-1)
    new = np.r_[False, s[1:] < end[:-1]] if s.size else np.zeros(0, bool)
    return np.cumsum(new).astype(np.int64)
