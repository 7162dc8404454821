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

from typing import Any

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
    max_frequencies: int | None = None,
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
    max_frequencies : int, optional
        Use at most this many Fourier frequencies, evenly spread over the band.

    Returns
    -------
    frequencies, ratios : ndarray
    """
    span = float(time[-1] - time[0])
    if span <= 0 or white_variance <= 0:
        return np.zeros(0), np.zeros(0)
    n_total = float(weight.sum())
    ks = np.arange(max(1, int(np.ceil(band[0] * span))), int(np.floor(band[1] * span)) + 1)
    if max_frequencies is not None and ks.size > max_frequencies:  # long records: an even subset of the band
        ks = ks[np.linspace(0, ks.size - 1, max_frequencies).round().astype(int)]
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


# --------------------------------------------------------------------------- coloured accelerometer noise, modulated
#: Correlation times [s] of the Gauss-Markov sum standing for flicker (bias instability), one decade apart.
FLICKER_TIME_CONSTANTS = (1e3, 1e4, 1e5)


def _bin_process_covariance(kind: str, time: NDArray[np.float64], width: float) -> NDArray[np.float64]:
    """Covariance of the bin means (bins of ``width`` centred at ``time`` since the record start) of a unit process.

    ``"random_walk"``: ``W(0) = 0``, ``Cov W(s)W(t) = min(s, t)`` [per s]; the mean over a bin ``[a, b]`` has
    variance ``a + (b − a)/3`` and, for disjoint bins, covariance = the earlier bin's centre.
    ``"flicker"``: a sum of unit Gauss-Markov processes (``FLICKER_TIME_CONSTANTS``), exact bin averages.
    """
    t = np.asarray(time, dtype=float)
    if kind == "random_walk":
        cov = np.minimum.outer(t, t)
        cov[np.diag_indices_from(cov)] -= width / 6.0
        return cov
    lag = np.abs(np.subtract.outer(t, t))
    cov = np.zeros_like(lag)
    for tau in FLICKER_TIME_CONSTANTS:
        x = width / tau
        shrink = (np.sinh(0.5 * x) / (0.5 * x)) ** 2  # two disjoint bins of the same width
        block = np.exp(-lag / tau) * shrink
        block[np.diag_indices_from(block)] = 2.0 * (x - 1.0 + np.exp(-x)) / (x * x)
        cov += block
    return cov


def axis_loadings(channel: str, cos_s: NDArray[np.float64], sin_s: NDArray[np.float64], latitude: float) -> NDArray[np.float64]:
    """``(n, 3)``: how platform-axis accelerometer noise ``n/g`` enters a channel (docs/system-calibration.md §1-2).

    z: ``u = (cosL cosS, cosL sinS, sinL)``; pitch ``Δf_N/g``: ``(−sinL cosS, −sinL sinS, cosL)``;
    roll ``−Δf_E/g``: ``(sinS, −cosS, 0)``.
    """
    s, c = np.sin(latitude), np.cos(latitude)
    zero = np.zeros_like(cos_s)
    if channel == "z":
        return np.stack([c * cos_s, c * sin_s, np.full_like(cos_s, s)], axis=1)
    if channel == "pitch":
        return np.stack([-s * cos_s, -s * sin_s, np.full_like(cos_s, c)], axis=1)
    return np.stack([sin_s, -cos_s, zero], axis=1)


def coloured_components(
    time: NDArray[np.float64], width: float, loadings: list[NDArray[np.float64]]
) -> tuple[list[str], list[NDArray[np.float64]]]:
    """Unit covariances of the stacked channel bins for each coloured component.

    Components: random walk and flicker of the x and y accelerometers (one level for both) and of z,
    each ``Σ_(p,i),(q,j) = Σ_a L_pa(i) L_qa(j) C(t_i, t_j)`` over the axes ``a`` of the group.
    """
    names, covs = [], []
    big = np.concatenate(loadings, axis=0)  # (channels·n, 3)
    tt = np.concatenate([time] * len(loadings))
    for kind in ("random_walk", "flicker"):
        c = _bin_process_covariance(kind, tt, width)
        for group, axes in (("xy", (0, 1)), ("z", (2,))):
            cov = sum(np.outer(big[:, a], big[:, a]) for a in axes) * c
            names.append(f"{kind}_{group}")
            covs.append(cov)
    return names, covs


def fit_coloured_noise(
    residuals: list[NDArray[np.float64]],
    residual_makers: list[NDArray[np.float64]],
    weights: list[NDArray[np.float64]],
    time: NDArray[np.float64],
    components: list[NDArray[np.float64]],
    band: tuple[float, float],
    threshold: float = 2.0,
    power_gains: list[Any] | None = None,
) -> tuple[NDArray[np.float64], dict[str, float]]:
    """Amplitudes of the coloured components from the residual periodograms of the channels (Whittle, NNLS-IRLS).

    For each channel ``p`` (residual maker ``R_p`` of its fit on the bins, bin weights ``w``) and Fourier
    frequency ``f_k`` in ``band``, the periodogram ``P_k = ½(a_k² + b_k²)`` of the residuals (``a_k, b_k`` the
    weighted cosine and sine projections) has expectation
    ``E P_k = w_p e_k(white_p) + Σ_c α_c e_k(c)``, ``e_k(c) = ½ Σ_{v ∈ (cos, sin)} vᵀ R_p Σ_c R_pᵀ v``,
    which accounts exactly for what the fit absorbed and for the modulation of the x, y axes by the Earth-rate
    angle.  White levels per channel and the shared amplitudes ``α ≥ 0`` are fitted by non-negative least squares
    weighted by ``1/E P_k`` (two reweighting passes: the Whittle likelihood's normal equations for exponential
    ordinates).  The coloured model is kept only when it raises the Whittle log-likelihood by more than
    ``threshold/2`` (``2Δℓ > threshold``); otherwise the amplitudes are zero (white noise).
    ``power_gains[p]``, when given, is a function of frequency [Hz] multiplying channel ``p``'s expectations
    (``|G(f)|²`` of a loop that filters both the white and the coloured noise of that channel).

    Returns the amplitudes and diagnostics (``{"loglik_gain": 2Δℓ, "frequencies": m}``).
    """
    from scipy.optimize import nnls

    n_ch = len(residuals)
    n_bins = time.size
    span = float(time[-1] - time[0]) + (float(np.median(np.diff(time))) if n_bins > 1 else 0.0)
    ks = np.arange(max(1, int(np.ceil(band[0] * span))), int(np.floor(band[1] * span)) + 1)
    if ks.size < 4 or n_bins < 8:
        return np.zeros(len(components)), {"loglik_gain": 0.0, "frequencies": int(ks.size)}
    t = time - time[0]
    rows, observed, owner = [], [], []
    for p in range(n_ch):
        w = weights[p] / weights[p].sum()
        arg = 2.0 * np.pi * np.outer(ks / span, t)
        vectors = np.concatenate([2.0 * w * np.cos(arg), 2.0 * w * np.sin(arg)])  # (2m, n)
        proj = np.einsum("kn,nm->km", vectors, residual_makers[p])
        m = ks.size
        a = np.einsum("kn,n->k", vectors, residuals[p])
        observed.append(0.5 * (a[:m] ** 2 + a[m:] ** 2))
        sl = slice(p * n_bins, (p + 1) * n_bins)
        cols = []
        white = np.einsum("kn,n,kn->k", proj, 1.0 / weights[p], proj)
        cols.append(0.5 * (white[:m] + white[m:]))
        for cov in components:  # einsum, not BLAS: its threads stall on a loaded machine (docs §6)
            e = np.einsum("kn,nm,km->k", proj, cov[sl, sl], proj)
            cols.append(0.5 * (e[:m] + e[m:]))
        gain = np.ones(m) if power_gains is None or power_gains[p] is None else np.array([power_gains[p](f) for f in ks / span])
        rows.append(np.array(cols).T * gain[:, None])
        owner.append(np.full(m, p))
    design_parts = []
    for p in range(n_ch):
        block = np.zeros((rows[p].shape[0], n_ch + len(components)))
        block[:, p] = rows[p][:, 0]
        block[:, n_ch:] = rows[p][:, 1:]
        design_parts.append(block)
    design = np.concatenate(design_parts)
    y = np.concatenate(observed)

    def whittle(coef: NDArray[np.float64]) -> float:
        e = np.maximum(design @ coef, 1e-300)
        return float(-np.sum(np.log(e) + y / e))

    def fit(columns: NDArray[np.bool_]) -> NDArray[np.float64]:
        coef = np.zeros(design.shape[1])
        expected = np.full(y.size, y.mean())
        for _ in range(3):
            scale = 1.0 / expected
            sol, _ = nnls(design[:, columns] * scale[:, None], y * scale)
            coef = np.zeros(design.shape[1])
            coef[columns] = sol
            expected = np.maximum(design @ coef, 1e-3 * y.mean())
        return coef

    white_only = np.zeros(design.shape[1], dtype=bool)
    white_only[:n_ch] = True
    coef0 = fit(white_only)
    coef1 = fit(np.ones(design.shape[1], dtype=bool))
    gain = 2.0 * (whittle(coef1) - whittle(coef0))
    amplitudes = coef1[n_ch:] if gain > threshold else np.zeros(len(components))
    return amplitudes, {"loglik_gain": gain, "frequencies": int(ks.size)}
