r"""Low-frequency noise of the fit residuals: how much the white-noise covariance understates it.

The covariances of the harmonic states and of the attitude coefficients are built from the
per-sample noise measured in the data, which is right for white noise.  Accelerometer bias
instability (flicker) and bias random walk add power that grows toward low frequencies, and the
Earth-rate harmonics sit at one and two cycles per day, where that power is largest.

The residuals of each fit are projected on sines and cosines at the Fourier frequencies
``f_k = k/T`` between ``f_low`` and ``f_high`` (above the fitted harmonics); the power of each
pair, divided by what the white-noise level predicts, gives ratios ``ρ_k`` (≈ 1 for white
noise, exponentially distributed).  A non-negative least-squares fit of

.. math:: ρ(f) = w + l\,(f_{ie}/f) + r\,(f_{ie}/f)^2

(white, flicker, random walk) is evaluated at the harmonic frequencies; the variance of a
coefficient at frequency ``f`` is scaled by ``max(1, ρ(f))``.  The extrapolation below the
fitted band is a model assumption (documented in docs/system-calibration.md).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from stableins.conventions import EARTH_RATE

#: Earth-rate frequency [Hz].
EARTH_FREQUENCY = EARTH_RATE / (2.0 * np.pi)


def spectral_ratios(
    time: NDArray[np.float64],
    residual: NDArray[np.float64],
    weight: NDArray[np.float64],
    white_variance: float,
    band: tuple[float, float],
    gain: NDArray[np.float64] | None = None,
    gain_frequencies: NDArray[np.float64] | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Ratios of residual power to the white-noise prediction at the Fourier frequencies in ``band`` [Hz].

    Parameters
    ----------
    time, residual, weight : ndarray
        Block times [s], block-mean residuals and the number of samples in each block.
    white_variance : float
        Per-sample variance of the white noise the covariance was built on.
    band : (float, float)
        Frequencies [Hz] used.
    gain : callable-free array, optional
        ``|G(f)|`` at ``gain_frequencies`` (a loop filtering the noise); 1 if omitted.

    Returns
    -------
    frequencies, ratios : ndarray
    """
    span = float(time[-1] - time[0])
    if span <= 0 or white_variance <= 0:
        return np.zeros(0), np.zeros(0)
    n_total = float(weight.sum())
    ks = np.arange(max(1, int(np.ceil(band[0] * span))), int(np.floor(band[1] * span)) + 1)
    freqs = ks / span
    ratios = np.empty(ks.size)
    t = time - time[0]
    wr = weight * residual
    for i, f in enumerate(freqs):
        arg = 2.0 * np.pi * f * t
        a = 2.0 * float(np.sum(wr * np.cos(arg))) / n_total
        b = 2.0 * float(np.sum(wr * np.sin(arg))) / n_total
        g = 1.0 if gain is None else float(np.interp(f, gain_frequencies, gain))
        predicted = 2.0 * white_variance * g * g / n_total  # variance of a and of b for white noise
        ratios[i] = 0.5 * (a * a + b * b) / predicted
    return freqs, ratios


def power_law_ratio(frequencies: NDArray[np.float64], ratios: NDArray[np.float64], at: NDArray[np.float64]) -> NDArray[np.float64]:
    """NNLS fit of ``w + l f_ie/f + r (f_ie/f)²`` to the ratios, evaluated at ``at`` [Hz]; ``nan`` without data."""
    from scipy.optimize import nnls

    if frequencies.size < 4:
        return np.full(np.shape(at), np.nan)
    x = np.stack([np.ones_like(frequencies), EARTH_FREQUENCY / frequencies, (EARTH_FREQUENCY / frequencies) ** 2], axis=1)
    coef, _ = nnls(x, ratios)
    a = np.asarray(at, dtype=float)
    return coef[0] + coef[1] * EARTH_FREQUENCY / a + coef[2] * (EARTH_FREQUENCY / a) ** 2


def inflation(frequencies: NDArray[np.float64], ratios: NDArray[np.float64], at: NDArray[np.float64]) -> NDArray[np.float64]:
    """Variance factors ``max(1, ρ(f))`` at ``at``; 1 where the spectrum cannot be estimated or is white.

    The coloured model is used only when the lowest third of the band shows significant excess
    power (mean ratio above ``1 + 3/√m`` for ``m`` exponentially distributed ratios): with
    white noise an unconstrained ``1/f²`` term fitted to scatter would be amplified by the
    extrapolation and inflate σ for nothing.
    """
    ones = np.ones(np.shape(at))
    if frequencies.size < 4:
        return ones
    m = max(2, frequencies.size // 3)
    if float(np.mean(ratios[:m])) <= 1.0 + 3.0 / np.sqrt(m):
        return ones
    rho = power_law_ratio(frequencies, ratios, at)
    return np.where(np.isfinite(rho), np.maximum(rho, 1.0), 1.0)
