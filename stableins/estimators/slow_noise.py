r"""Slow noise in device dwells: the test for more than white noise in the dwells of a device session.

The dwells of a device session
measure white noise precisely but bias instability only weakly.  The decision uses, per
dwell and axis, the normalized overlapping Allan variances ``r_j = σ̂²_A(m_j) m_j / s²``
at ``m_j = n/4, n/8, n/16, n/32`` samples (``s²`` the sample variance).  Under white noise
each ``σ̂²_A(m)`` is a quadratic form ``xᵀA_m x`` of the samples, ``E r_j = 1`` and

.. math:: \mathrm{Cov}(r_i, r_j) = 2 m_i m_j \,\mathrm{tr}(A_{m_i} A_{m_j})
          = \frac{m_i m_j}{2 M_i M_j} \sum_\delta c_{ij}(\delta)\, g_{ij}(\delta)^2

exactly (``M = n − 2m + 1`` terms, ``g_ij`` the cross-correlation of the two Allan
kernels, ``c_ij(δ)`` the number of kernel pairs ``δ`` apart).  The statistic
``S = Σ_{dwell, axis} wᵀ(r − 1)`` with ``w = max(C⁻¹μ, 0)`` (``μ_j`` the excess that a
unit ``B²`` adds) is a positive combination of quadratic forms: under white noise it is
approximated by a scaled χ² with the exact mean and variance (Satterthwaite), which gives
the p-value; slow noise is declared present when ``p < α``.  ``S/D`` (``D = Σ wᵀμ``) is an
unbiased estimate of ``B²`` with standard error ``sqrt(V)/D``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stableins.noise import NoiseModel, SlowNoiseTest

#: Cluster sizes of the dwell test, as fractions of the dwell's samples.
TEST_FRACTIONS = (4, 8, 16, 32)
#: False-positive rate of the slow-noise decision.
SLOW_NOISE_ALPHA = 0.05


# ----------------------------------------------------------------------------- device dwells
@lru_cache(maxsize=64)
def white_allan_covariance(n: int, clusters: tuple[int, ...]) -> NDArray[np.float64]:
    """Exact covariance of ``r_j = σ̂²_A(m_j) m_j/σ²`` for ``n`` white samples (module docstring)."""
    out = np.empty((len(clusters), len(clusters)))
    for i, mi in enumerate(clusters):
        for j, mj in enumerate(clusters[i:], start=i):
            big_i, big_j = n - 2 * mi + 1, n - 2 * mj + 1
            hi = np.r_[-np.ones(mi), np.ones(mi)] / mi
            hj = np.r_[-np.ones(mj), np.ones(mj)] / mj
            g = _fftconvolve(hi, hj[::-1])  # g[k]: h_j starting (k − len(h_j) + 1) samples after h_i
            delta = np.arange(g.size) - (hj.size - 1)
            count = np.clip(np.minimum(big_i, big_j - delta) - np.maximum(0, -delta), 0, None)
            trace = float(np.sum(count * g**2)) / (4.0 * big_i * big_j)
            out[i, j] = out[j, i] = 2.0 * mi * mj * trace
    return out


def dwell_test_clusters(n: int) -> tuple[int, ...]:
    """Cluster sizes ``n/4, n/8, n/16, n/32`` (at least 2 samples, distinct) of the dwell test."""
    return tuple(sorted({n // f for f in TEST_FRACTIONS if n // f >= 2}, reverse=True))


def _fftconvolve(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """``scipy.signal.fftconvolve(a, b, mode="full")`` of two real 1-D arrays, its operations one by one (equal to the bit).

    :mod:`scipy.signal` imports :mod:`scipy.stats`, about a second of every device command (issue 30); :mod:`scipy.fft`
    does not.  scipy 1.17 (``signal._signaltools._freq_domain_conv``): real FFTs of the next fast length, their
    product, the inverse, the first ``len(a) + len(b) − 1`` values.
    """
    from scipy import fft

    shape = a.size + b.size - 1
    length = fft.next_fast_len(shape, True)
    product = fft.rfftn(a, [length], axes=[0]) * fft.rfftn(b, [length], axes=[0])
    return np.asarray(fft.irfftn(product, [length], axes=[0])[:shape]).copy()


def overlapping_allan_deviation(
    frequency: NDArray[np.float64], rate: float, clusters: NDArray[np.int64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    r"""Return ``(τ, σ_A(τ))``, the overlapping Allan deviation of finite frequency data at ``τ = m/rate``.

    .. math:: \sigma^2_A(m\tau_0) = \frac{1}{2 (m\tau_0)^2 (N - 2m)} \sum_{n=1}^{N-2m} (x_{n+2m} - 2x_{n+m} + x_n)^2

    with ``x`` the phase (the cumulative sum of the frequency less its mean, times ``τ₀``; NIST SP 1065 Eq. 11).
    This is ``allantools.oadev(frequency, rate=rate, data_type="freq", taus=clusters / rate)`` (allantools 2024.06)
    operation by operation, equal to the bit (tests/test_slow_noise_oadev.py), without importing allantools, which
    imports :mod:`scipy.stats` and :mod:`scipy.signal` (about a second of every device command, issue 30).  ``m`` are
    rounded, kept in ``0 < m < N + 1``, sorted and made unique; results from fewer than two terms are dropped.
    """
    dt = 1.0 / float(rate)
    freq = frequency - np.nanmean(frequency)
    phase = np.insert(np.cumsum(freq) * dt, 0, 0)
    rate = float(rate)
    m = np.round(np.asarray(clusters / rate) * rate)
    m = np.unique(m[(m < len(phase)) & (m > 0) & (m <= len(phase))])
    taus = m / rate
    devs = np.zeros_like(taus)
    terms = np.zeros_like(taus)
    for k, mj in enumerate(m):
        j = int(mj)
        n = max(len(phase) - 2 * j, 0) or 1
        v = phase[2 * j :][:n] - 2 * phase[j:][:n] + phase[:n]
        devs[k] = np.sqrt(np.sum(v * v) / (2.0 * n)) / j * rate
        terms[k] = n
    keep = terms > 1
    return taus[keep], devs[keep]


def dwell_allan_ratios(samples: ArrayLike, rate: float) -> tuple[tuple[int, ...], NDArray[np.float64]]:
    """Return the normalized overlapping Allan variances ``r_j`` (k, 3) of one dwell at :func:`dwell_test_clusters`.

    The deviations are :func:`overlapping_allan_deviation` (``allantools.oadev``'s, to the bit).
    """
    x = np.asarray(samples, dtype=float).reshape(-1, 3)
    clusters = dwell_test_clusters(x.shape[0])
    ratios = np.full((len(clusters), 3), np.nan)
    if not clusters:
        return clusters, ratios
    s2 = x.var(axis=0, ddof=1)
    m = np.array(clusters)
    for a in range(3):
        if not s2[a] > 0:
            continue
        tau_used, dev = overlapping_allan_deviation(x[:, a], rate, m)
        index = np.searchsorted(-m, -np.rint(np.asarray(tau_used) * rate).astype(np.int64))
        ratios[index, a] = np.asarray(dev) ** 2 * m[index] / s2[a]
    return clusters, ratios


@dataclass(frozen=True)
class DwellSlowNoise:
    """What the dwells say about slow noise: the decision and the estimate of ``B²``.

    Attributes
    ----------
    test : SlowNoiseTest
    b2, b2_sigma : float
        Unbiased estimate of ``B²`` [(m/s²)²] (slow noise expressed as bias instability) and its 1σ.
    b_upper : float
        Upper confidence limit of ``B`` [m/s²] at ``confidence``.
    k_upper : float
        Upper limit of the random walk ``K`` if all the excess were random walk.
    dwells : int
        Dwell-axes used.
    """

    test: SlowNoiseTest
    b2: float
    b2_sigma: float
    b_upper: float
    k_upper: float
    dwells: int


def slow_noise_test(
    ratios: Sequence[tuple[int, NDArray[np.float64], NDArray[np.float64], float]],
    *,
    alpha: float = SLOW_NOISE_ALPHA,
    confidence: float = 0.95,
) -> DwellSlowNoise:
    """Return the slow-noise decision over dwells (module docstring).

    ``ratios``: per dwell ``(n, r (k, 3), s² (3,), rate)`` with ``r`` at :func:`dwell_test_clusters` ``(n)``.
    """
    from stableins.estimators.distributions import chi2_sf, norm_ppf

    unit_b = NoiseModel.given(bias_instability=1.0)
    unit_k = NoiseModel.given(random_walk=1.0)
    s_total = v_total = d_total = dk_total = mean_total = 0.0
    used = 0
    for n, r, s2, rate in ratios:
        clusters = dwell_test_clusters(int(n))
        if len(clusters) < 2 or r.shape != (len(clusters), 3):
            continue
        m = np.array(clusters, dtype=float)
        tau = m / rate
        mu_b = unit_b.allan_variance(tau)[:, 0] * m
        mu_k = unit_k.allan_variance(tau)[:, 0] * m
        cov = white_allan_covariance(int(n), clusters)
        for a in range(3):
            if not (np.all(np.isfinite(r[:, a])) and s2[a] > 0):
                continue
            mu = mu_b / s2[a]
            w = np.clip(np.linalg.solve(cov, mu), 0.0, None)
            s_total += float(w @ (r[:, a] - 1.0))
            v_total += float(w @ cov @ w)
            d_total += float(w @ mu)
            dk_total += float(w @ (mu_k / s2[a]))
            mean_total += float(w.sum())
            used += 1
    if used == 0 or v_total <= 0:
        test = SlowNoiseTest(0.0, 1.0, alpha)
        return DwellSlowNoise(test, 0.0, math.inf, math.inf, math.inf, 0)
    # Satterthwaite: Σ wᵀr ≈ g χ²_h with the exact mean and variance under white noise
    g = v_total / (2.0 * mean_total)
    h = 2.0 * mean_total**2 / v_total
    p_value = chi2_sf((s_total + mean_total) / g, h)
    statistic = s_total / math.sqrt(v_total)
    b2 = s_total / d_total
    b2_sigma = math.sqrt(v_total) / d_total
    z = norm_ppf(confidence)
    b_upper = math.sqrt(max(b2, 0.0) + z * b2_sigma)
    k_upper = math.sqrt(max(s_total, 0.0) / dk_total + z * math.sqrt(v_total) / dk_total)
    return DwellSlowNoise(SlowNoiseTest(statistic, p_value, alpha), b2, b2_sigma, b_upper, k_upper, used)
