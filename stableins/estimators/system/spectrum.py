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
fitted band is a model assumption (documented in docs/system-calibration.md).  The attitude fit
uses this only as a diagnostic.

The system stage's covariance uses the second half of the module: a random walk and a flicker
noise of the accelerometer axes, their exact bin-mean covariances (:func:`bin_process_kernel`),
how they reach each channel (loadings, and the damping loop through :func:`loop_bin_mixing`),
the expected residual periodograms (:func:`periodogram_design`), the maximum of the Whittle
likelihood (:func:`fit_coloured_noise`) and the propagation ``A Σ Bᵀ`` without the stacked
covariance (:func:`component_quadratic`).  docs/system-calibration.md §1a.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import Enum
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stableins import noise as _noise
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
#: Correlation times [s] of the Gauss-Markov sum standing for flicker (bias instability), one decade apart: the noise
#: model's (:data:`stableins.noise.FLICKER_TIME_CONSTANTS`, 1 s to 1e5 s).  The sum has a 1/f spectrum from about
#: ``1/(2π·1e5 s)`` (0.14 cycles/day) to ``1/(2π·1 s)``, which covers the fitted bands (3.5 to about 650 cycles/day)
#: and reaches down to the harmonic frequencies.
FLICKER_TIME_CONSTANTS = _noise.FLICKER_TIME_CONSTANTS

#: The coloured components: random walk and flicker, one amplitude each for the three accelerometer axes.
COLOURED_KINDS = ("random_walk", "flicker")


def amplitudes_to_allan(amplitudes: ArrayLike, gravity: float) -> NDArray[np.float64]:
    """``(K, B)`` [m/s²/√s, m/s²] from the amplitudes ``((K/g)², σ²/g²)``, ``σ² = B² ln 10/π`` per Gauss-Markov process.

    Works elementwise on arrays whose first axis is the kind (:data:`COLOURED_KINDS`); ``inf`` stays ``inf``.
    """
    a = np.maximum(np.asarray(amplitudes, dtype=float), 0.0)
    return np.stack([gravity * np.sqrt(a[0]), gravity * np.sqrt(a[1] / _noise.FLICKER_VARIANCE_PER_B2)])


def allan_to_amplitudes(random_walk: ArrayLike, bias_instability: ArrayLike, gravity: float) -> NDArray[np.float64]:
    """The inverse of :func:`amplitudes_to_allan`: ``((K/g)², (B/g)² ln 10/π)``."""
    k = np.asarray(random_walk, dtype=float)
    b = np.asarray(bias_instability, dtype=float)
    return np.stack([(k / gravity) ** 2, (b / gravity) ** 2 * _noise.FLICKER_VARIANCE_PER_B2])


def bin_process_kernel(kind: str, time: NDArray[np.float64], width: float) -> NDArray[np.float64]:
    """Covariance ``(n, n)`` of the bin means (bins of ``width`` centred at ``time`` since the record start) of a unit process.

    ``"random_walk"``: ``W(0) = 0``, ``Cov W(s)W(t) = min(s, t)`` [per s]; the mean over a bin ``[a, b]`` has
    variance ``a + (b − a)/3`` and, for disjoint bins, covariance = the earlier bin's centre.
    ``"flicker"``: a sum of unit Gauss-Markov processes (:data:`FLICKER_TIME_CONSTANTS`), exact bin averages:
    ``e^{−|Δt|/τ} (sinh(x/2)/(x/2))²`` between disjoint bins and ``2(x − 1 + e^{−x})/x²`` within one, ``x = width/τ``.

    One ``(n, n)`` matrix for the whole record (at most ``COLOURED_BINS`` bins in the stage, 0.8 MB); the
    channels and axes are applied through the loadings (:func:`component_quadratic`), never as a stacked matrix.
    """
    t = np.asarray(time, dtype=float)
    if kind == "random_walk":
        cov = np.minimum.outer(t, t)
        cov[np.diag_indices_from(cov)] -= width / 6.0
        return cov
    lag = np.abs(np.subtract.outer(t, t))
    cov = np.zeros_like(lag)
    diagonal = np.diag_indices_from(cov)
    for tau in FLICKER_TIME_CONSTANTS:
        x = width / tau
        # two disjoint bins: e^{−Δt/τ} (sinh(x/2)/(x/2))² = e^{−(Δt − w)/τ} ((1 − e^{−x})/x)², without overflow for x ≫ 1
        part = np.exp(-np.maximum(lag - width, 0.0) / tau) * (-math.expm1(-x) / x) ** 2
        part[diagonal] = 2.0 * (x - 1.0 + math.exp(-x)) / (x * x) if x > 1e-6 else 1.0 - x / 3.0
        cov += part
    return cov


def _mix(rows: NDArray[np.float64], operator: NDArray[np.float64]) -> NDArray[np.float64]:
    """``rows @ M`` for a channel's mixing operator ``M``: a loading ``(n,)`` (diagonal) or a matrix ``(n, n)``."""
    if operator.ndim == 1:
        return rows * operator
    return np.einsum("in,nm->im", rows, operator)  # einsum, not BLAS (docs/system-calibration.md §6)


def component_quadratic(
    left: NDArray[np.float64],
    right: NDArray[np.float64],
    mixing: list[list[NDArray[np.float64]]],
    kernel: NDArray[np.float64],
    *,
    per_axis: bool = False,
) -> NDArray[np.float64]:
    """``A Σ Bᵀ`` for the stacked channel bins without forming the stacked covariance ``Σ``.

    Channel ``p``'s coloured noise on the bins is ``Σ_a M_pa n_a`` with ``n_a`` the bin means of axis ``a``'s unit
    process (covariance ``C`` = ``kernel``, the same for the three axes and independent between them) and ``M_pa``
    = ``mixing[p][a]``: a loading ``L_pa(t_i)`` (diagonal, ``(n,)``) or an ``(n, n)`` operator (a loop filtering
    the loadings, :func:`loop_bin_mixing`).  ``left (r, P·n)``, ``right (s, P·n)`` act on the ``P`` channels' bins
    stacked; per axis ``A_a = Σ_p A_p M_pa`` and ``A Σ Bᵀ = Σ_a A_a C B_aᵀ``.  Memory ``O((r + s) n)`` besides the
    kernel and the operators.  ``per_axis``: the three terms ``A_a C B_aᵀ`` separately, shape ``(3, r, s)`` (axes with
    different noise levels).
    """
    n = kernel.shape[0]
    out = np.zeros((3, left.shape[0], right.shape[0]))
    for axis in range(3):
        a = sum(_mix(left[:, p * n : (p + 1) * n], ops[axis]) for p, ops in enumerate(mixing))
        b = a if right is left else sum(_mix(right[:, p * n : (p + 1) * n], ops[axis]) for p, ops in enumerate(mixing))
        out[axis] = np.einsum("im,km->ik", np.einsum("in,nm->im", a, kernel), b)  # two products: a three-operand einsum loops naively
    return out if per_axis else out.sum(axis=0)


def loop_bin_mixing(
    modes: tuple[NDArray[np.complex128], NDArray[np.complex128], NDArray[np.complex128]],
    time: NDArray[np.float64],
    width: float,
    input_loadings: list[NDArray[np.float64]],
) -> list[list[NDArray[np.float64]]]:
    r"""Mixing operators ``(n, n)`` from the axes' bin means to the bin means of a linear loop's outputs.

    ``modes = (λ, C_m, B_m)``: the loop's impulse response ``h(t) = Σ_m C_m B_m e^{λ_m t}`` (outputs × inputs, modal
    form of :class:`.loop.DampingLoop`).  With the input held at its bin mean over each bin of ``width`` ``w``
    (the coloured noise varies little within a bin), the output's mean over bin ``i`` is ``Σ_{j ≤ i} Φ_ij u_j`` with

    .. math:: Φ_{ij} = Σ_m C_m B_m\, w\, e^{λ_m (t_i − t_j − w)} \left(\frac{e^{x} − 1}{x}\right)^2 \;(i > j),\qquad
              Φ_{ii} = Σ_m C_m B_m\, w\, \frac{e^{x} − 1 − x}{x^2}, \qquad x = λ_m w,

    (``1/w`` times the double integral of ``h(t − τ)`` over the two bins; a constant input gives ``G(0)``).
    Input ``k``'s loadings are ``input_loadings[k]`` ``(n, 3)``; returns ``mixing[output][axis] = Σ_k Φ_(output, k) diag(L_k[:, axis])``.

    Why not ``|G(f)|²`` on the expected periodogram: a random walk's residual periodogram at a Fourier frequency is
    mostly leakage of its power at much lower frequencies, where ``G ≈ 1``; multiplying it by ``|G(f_k)|²`` (0.13 at
    30 cycles/day in a ζ = 0.5 loop) is wrong by up to 5× (docs/system-calibration.md §1a).
    """
    eigenvalues, out, inp = modes
    t = np.asarray(time, dtype=float)
    n = t.size
    lag = np.subtract.outer(t, t) - width  # t_i − t_j − w
    later = lag > -0.5 * width
    lag[~later] = 0.0
    mixing = [[np.zeros((n, n)) for _ in range(3)] for _ in range(out.shape[0])]
    for lam, c_m, b_m in zip(eigenvalues, out.T, inp, strict=True):
        x = lam * width
        small = abs(x) < 1e-6
        ratio = 1.0 + 0.5 * x if small else np.expm1(x) / x
        diagonal = 0.5 + x / 6.0 if small else (np.expm1(x) - x) / (x * x)
        shape = np.exp(lam * lag)
        shape *= width * ratio * ratio
        shape[~later] = 0.0
        shape[np.diag_indices(n)] = width * diagonal
        for axis in range(3):
            column = sum(b_m[k] * input_loadings[k][:, axis] for k in range(inp.shape[1]))  # input side, (n,)
            for o in range(out.shape[0]):
                mixing[o][axis] += np.real(shape * (c_m[o] * column)[None, :])
    return mixing


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


def periodogram_design(
    residuals: list[NDArray[np.float64]],
    residual_makers: list[NDArray[np.float64]],
    weights: list[NDArray[np.float64]],
    time: NDArray[np.float64],
    kernels: list[NDArray[np.float64]],
    mixing: list[list[NDArray[np.float64]]],
    band: tuple[float, float],
    white_gains: list[Any] | None = None,
    exclude: tuple[float, ...] = (),
) -> tuple[NDArray[np.float64], NDArray[np.float64], int] | None:
    r"""Periodogram ordinates of the channels' residuals and their expectations per unit noise level.

    For each channel ``p`` (residual maker ``R_p`` of its fit on the bins, bin weights ``w``, loadings ``L_p``) and
    Fourier frequency ``f_k = k/T`` in ``band``, ``P_k = ½(a_k² + b_k²)`` with ``a_k, b_k`` the weighted cosine and sine
    projections of the residuals.  Its expectation is

    .. math:: E P_k = w_p\,|G_p(f_k)|^2 e_k(\mathrm{white}) + Σ_c α_c e_k(c), \qquad
              e_k(c) = ½ Σ_{v ∈ (\cos, \sin)} Σ_a (v R_p M_{pa}) C_c (v R_p M_{pa})ᵀ,

    exact for what the fit absorbed, for the Earth-rate modulation of the x and y axes and for a loop filtering the
    channel (``M_pa`` = ``mixing[p][a]``, :func:`component_quadratic`; ``C_c`` the bin kernel of component ``c``,
    :func:`bin_process_kernel`, one amplitude for the three axes).  ``white_gains[p]``, a function of frequency [Hz],
    is ``|G(f)|²`` of the loop for the white noise (stationary: its periodogram is its spectrum times ``|G|²``).

    ``exclude``: frequencies [Hz] left out with their neighbours within half a Fourier spacing (the harmonics the fits
    absorb, where a residual ordinate carries nothing).

    Returns ``(design, observed, channels)`` with ``E P = design @ (w_1..w_P, α_1..α_C)`` (the
    channels' ordinates one after the other), or ``None`` when the band holds fewer than four Fourier frequencies or
    there are fewer than eight bins.
    """
    n_ch = len(residuals)
    n_bins = time.size
    span = float(time[-1] - time[0]) + (float(np.median(np.diff(time))) if n_bins > 1 else 0.0)
    ks = np.arange(max(1, int(np.ceil(band[0] * span))), int(np.floor(band[1] * span)) + 1)
    for f in exclude:  # frequencies the fits absorb (the harmonics): no ordinate within half a Fourier spacing
        ks = ks[np.abs(ks - f * span) >= 0.5]
    if ks.size < 4 or n_bins < 8:
        return None
    m = ks.size
    t = time - time[0]
    arg = 2.0 * np.pi * np.outer(ks / span, t)
    blocks, observed = [], []
    for p in range(n_ch):
        w = weights[p] / weights[p].sum()
        vectors = np.concatenate([2.0 * w * np.cos(arg), 2.0 * w * np.sin(arg)])  # (2m, n)
        proj = np.einsum("kn,nm->km", vectors, residual_makers[p])  # einsum, not BLAS (docs §6)
        a = np.einsum("kn,n->k", vectors, residuals[p])
        observed.append(0.5 * (a[:m] ** 2 + a[m:] ** 2))
        block = np.zeros((m, n_ch + len(kernels)))
        white = np.einsum("kn,n,kn->k", proj, 1.0 / weights[p], proj)
        block[:, p] = 0.5 * (white[:m] + white[m:])
        for c, kernel in enumerate(kernels):
            e = np.zeros(2 * m)
            for axis in range(3):
                pa = _mix(proj, mixing[p][axis])
                e += np.einsum("km,km->k", np.einsum("kn,nm->km", pa, kernel), pa)
            block[:, n_ch + c] = 0.5 * (e[:m] + e[m:])
        if white_gains is not None and white_gains[p] is not None:
            block[:, p] *= np.array([white_gains[p](f) for f in ks / span])
        blocks.append(block)
    return np.concatenate(blocks), np.concatenate(observed), n_ch


# --------------------------------------------------------------------------- the z channel above the low band
def _dft_of_geometric_covariance(theta: NDArray[np.float64], n: int, variance: float, lag_one: float, rho: float) -> NDArray[np.float64]:
    r"""``E|Σ_j x_j e^{−iθj}|²`` for ``n`` stationary values with covariance ``c_0 = variance``, ``c_m = lag_one·ρ^{m−1}`` (m ≥ 1).

    ``= n c_0 + 2 Re Σ_{m=1}^{n−1} (n − m) c_m e^{−iθm}`` in closed form (geometric sums of ``q = ρ e^{−iθ}``):
    ``Σ (n − m) q^m = n S_1 − S_2``, ``S_1 = q(1 − q^{n−1})/(1 − q)``, ``S_2 = q(1 − n q^{n−1} + (n − 1) q^n)/(1 − q)²``.
    """
    if rho <= 0.0 or lag_one == 0.0:
        return np.full(theta.shape, n * variance)
    q = rho * np.exp(-1j * theta)
    qn1 = q ** (n - 1)
    one = 1.0 - q
    s1 = q * (1.0 - qn1) / one
    s2 = q * (1.0 - n * qn1 + (n - 1) * qn1 * q) / (one * one)
    return n * variance + 2.0 * (lag_one / rho) * np.real(n * s1 - s2)


def _dft_of_random_walk(theta: NDArray[np.float64], n: int, width: float) -> NDArray[np.float64]:
    r"""``E|Σ_j W̄_j e^{−iθj}|²`` for the bin means of a unit random walk started at the first bin's start.

    ``Cov(W̄_i, W̄_j) = w (min(i, j) + ½ − δ_ij/6)`` (:func:`bin_process_kernel`), so the expectation is
    ``w [F(θ) + ½ G(θ) − n/6]`` with ``G = sin²(nθ/2)/sin²(θ/2)`` (Fejér) and
    ``F(θ) = Σ_ij min(i, j) e^{−iθ(i−j)} = Σ_{l=1}^{n−1} |Σ_{i≥l} e^{−iθi}|² = [2(n − 1) − 2 Σ_{m=1}^{n−1} cos mθ]/(2 − 2 cos θ)``.
    """
    half = 0.5 * theta
    s_half = np.sin(half)
    cos_sum = (np.sin((n - 0.5) * theta) - s_half) / (2.0 * s_half)  # Σ_{m=1}^{n−1} cos mθ
    f = (2.0 * (n - 1) - 2.0 * cos_sum) / (4.0 * s_half * s_half)
    g = (np.sin(n * half) / s_half) ** 2
    return width * (f + 0.5 * g - n / 6.0)


def z_bin_expectations(k: NDArray[np.int64], n: int, width: float, latitude: float, samples_per_bin: float) -> NDArray[np.float64]:
    r"""Expected periodogram ordinates of the z residual on ``n`` uniform bins of ``width`` [s], per unit noise level.

    Columns: white (per-sample variance 1, ``samples_per_bin`` samples per bin), random walk ``(K/g)² = 1`` [1/s],
    flicker (each Gauss-Markov process of :data:`FLICKER_TIME_CONSTANTS` of variance 1), at the Fourier
    frequencies ``f_k = k/(n w)``.  With uniform weights ``P_k = 2|Σ_j r_j e^{−iθ_k j}|²/n²`` (:func:`z_bin_periodogram`)
    and ``θ_k = 2πk/n``,

    .. math:: E P_k = \frac{2}{n^2}\Big[\sin^2 L\, X(θ_k) + \cos^2 L\, \tfrac12\big(X(θ_k − φ) + X(θ_k + φ)\big)\Big],
              \qquad φ = ω_{ie} w,

    ``X(θ) = E|Σ_j x_j e^{−iθj}|²`` of one axis' bin means: the z axis enters z with the constant loading ``sin L``, the x
    and y axes as ``cos L (n_x cos S + n_y sin S)``, whose covariance is the axis covariance times ``cos(S_i − S_j)``.  Exact
    for the bin means (stationary Gauss-Markov processes in closed form, :func:`_dft_of_geometric_covariance`; the random
    walk, :func:`_dft_of_random_walk`, with the leakage of its growth over the record, which doubles its ordinates over the
    stationary ``2S(f)/T``).  What the harmonic fit absorbs is left out: its columns are harmonics of one to three cycles per
    day, orthogonal to the ordinates above the low band over whole days.  docs/system-calibration.md §1a.
    """
    theta = 2.0 * np.pi * np.asarray(k, dtype=float) / n
    phi = EARTH_RATE * width
    s2, c2 = math.sin(latitude) ** 2, math.cos(latitude) ** 2
    out = np.zeros((theta.size, 3))
    out[:, 0] = 2.0 / (n * samples_per_bin)  # white: bin means independent, variance 1/samples

    def modulated(x: Any) -> NDArray[np.float64]:
        return (s2 * x(theta) + 0.5 * c2 * (x(theta - phi) + x(theta + phi))) * 2.0 / (n * n)

    out[:, 1] = modulated(lambda th: _dft_of_random_walk(th, n, width))
    flicker = np.zeros(theta.size)
    for tau in FLICKER_TIME_CONSTANTS:
        x = width / tau
        variance = 2.0 * (x - 1.0 + math.exp(-x)) / (x * x) if x > 1e-6 else 1.0 - x / 3.0
        lag_one = (-math.expm1(-x) / x) ** 2  # e^{−x} (sinh(x/2)/(x/2))², the covariance of adjacent bins
        rho = math.exp(-x)
        flicker += modulated(lambda th, v=variance, c=lag_one, r=rho: _dft_of_geometric_covariance(th, n, v, c, r))
    out[:, 2] = flicker
    return out


def z_bin_periodogram(residual: NDArray[np.float64], count: NDArray[np.float64], k: NDArray[np.int64]) -> NDArray[np.float64]:
    """``P_k = ½(a_k² + b_k²)`` of bin residuals (weights ∝ ``count``, empty bins weight 0) at ``θ_k = 2πk/n``, by one FFT."""
    w = count / count.sum()
    spectrum_ = np.fft.rfft(w * np.where(count > 0, residual, 0.0))
    return 2.0 * np.abs(spectrum_[np.asarray(k)]) ** 2


# --------------------------------------------------------------------------- Whittle likelihood
def whittle_fit(
    design: NDArray[np.float64],
    observed: NDArray[np.float64],
    free: NDArray[np.bool_] | None = None,
    offset: NDArray[np.float64] | None = None,
    start: NDArray[np.float64] | None = None,
    penalty: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None,
) -> tuple[NDArray[np.float64], float]:
    r"""Maximum of the Whittle likelihood ``ℓ(θ) = −Σ_k [log E_k + P_k/E_k]``, ``E = design @ θ + offset``, over ``θ ≥ 0``.

    The ordinates are independent and exponentially distributed with means ``E_k`` (the Whittle approximation).
    ``free`` selects the columns fitted (the others stay 0; ``offset`` carries any fixed part of ``E``).  Projected Fisher
    scoring on columns scaled to the mean ordinate: the step solves ``I Δ = ∇ℓ`` with ``I = Dᵀ diag(E⁻²) D`` over the
    columns not held at their bound (a column at 0 whose gradient points below 0 is held), halved until ``ℓ`` increases;
    converged when the Newton decrement ``∇ℓᵀ I⁻¹ ∇ℓ < 1e-10``.  A few iterations of a few small matrix products: the
    stage runs dozens of these fits (decision, intervals) in milliseconds.  ``penalty = (mean, sd)`` per column adds a
    Gaussian prior ``−½ Σ ((θ_c − mean_c)/sd_c)²`` (``sd = inf``: none), an independent measurement of the levels; the
    maximum is then the posterior mode.  Returns ``θ`` and the (penalized) ``ℓ(θ)``.
    """
    p = design.shape[1]
    free = np.ones(p, dtype=bool) if free is None else np.asarray(free, dtype=bool)
    mean = float(observed.mean())
    scale = mean / np.maximum(design[:, free].mean(axis=0), 1e-300)
    a = design[:, free] * scale
    base = np.zeros(observed.size) if offset is None else np.asarray(offset, dtype=float)
    floor = 1e-12 * mean
    if start is None:
        u = np.full(a.shape[1], 1.0 / a.shape[1])
    else:
        u = np.maximum(np.asarray(start, dtype=float)[free] / scale, 0.0)
        if not np.any(a @ u + base > floor):
            u = np.full(a.shape[1], 1.0 / a.shape[1])

    if penalty is None:
        centre, weight = np.zeros(a.shape[1]), np.zeros(a.shape[1])
    else:
        sd = np.asarray(penalty[1], dtype=float)[free] / scale
        centre = np.asarray(penalty[0], dtype=float)[free] / scale
        weight = np.where(np.isfinite(sd) & (sd > 0), 1.0 / np.where(sd > 0, sd, 1.0) ** 2, 0.0)
        centre = np.where(weight > 0, centre, 0.0)

    def loglik(v: NDArray[np.float64]) -> tuple[float, NDArray[np.float64]]:
        e = np.maximum(a @ v + base, floor)
        return -float(np.sum(np.log(e) + observed / e)) - 0.5 * float(np.sum(weight * (v - centre) ** 2)), e

    value, e = loglik(u)
    for _ in range(200):
        gradient = a.T @ ((observed / e - 1.0) / e) - weight * (u - centre)
        moving = (u > 0.0) | (gradient > 0.0)
        if not moving.any():
            break
        scaled = a[:, moving] / e[:, None]
        fisher = scaled.T @ scaled + np.diag(weight[moving])
        try:
            step = np.linalg.solve(fisher, gradient[moving])
        except np.linalg.LinAlgError:
            step = np.linalg.lstsq(fisher, gradient[moving], rcond=None)[0]
        if float(gradient[moving] @ step) < 1e-10:
            break
        t = 1.0
        for _ in range(40):
            trial = u.copy()
            trial[moving] = np.maximum(u[moving] + t * step, 0.0)
            new, e_new = loglik(trial)
            if new >= value:
                break
            t *= 0.5
        else:
            break
        improved = new - value
        u, value, e = trial, new, e_new
        if improved < 1e-12 * max(1.0, abs(value)):
            break
    theta = np.zeros(p)
    theta[free] = u * scale
    return theta, value


def _chi_bar_squared_sf(statistic: float, correlation: float | None) -> float:
    r"""``P(χ̄² ≥ statistic)`` for the likelihood ratio of ``θ = 0`` against ``θ ≥ 0`` (one or two amplitudes).

    Two amplitudes whose unconstrained estimates have correlation ``ρ``: ``χ̄² = w₁ χ²₁ + w₂ χ²₂`` with ``w₁ = ½``,
    ``w₂ = ¼ + arcsin(ρ)/(2π)`` (and ``w₀ = ½ − w₂`` at zero); one amplitude: ``½ χ²₁`` (Shapiro 1985; Self & Liang 1987).
    """
    from scipy.special import gammaincc  # χ²_k survival function: Q(k/2, x/2) (scipy.stats costs the stage's memory)

    if statistic <= 0.0:
        return 1.0
    if correlation is None:
        return 0.5 * float(gammaincc(0.5, 0.5 * statistic))
    w2 = 0.25 + math.asin(max(-1.0, min(1.0, correlation))) / (2.0 * math.pi)
    return 0.5 * float(gammaincc(0.5, 0.5 * statistic)) + w2 * float(gammaincc(1.0, 0.5 * statistic))


class ColouredSource(Enum):
    """Where the coloured-noise amplitudes under σ come from."""

    #: The record alone: a decision with a calibrated false-positive rate, then the maximum-likelihood amplitudes.
    DATA = "the record alone"
    #: The record and the prior noise model (an earlier measurement): the posterior mode.
    PRIOR = "the record and the prior noise model"
    #: Given (a datasheet): the amplitudes are the given ones; the record's own fit is reported beside them.
    GIVEN = "given"


@dataclass(frozen=True)
class ColouredNoiseFit:
    """The coloured-noise amplitudes of a record and how they were decided (docs/system-calibration.md §1a).

    Attributes
    ----------
    amplitudes : ndarray (2, 3)
        The amplitudes used for σ per kind (:data:`COLOURED_KINDS`: random walk ``(K/g)²`` [1/s]; flicker, the variance of
        each Gauss-Markov process of :data:`FLICKER_TIME_CONSTANTS`, ``σ²/g² = (B/g)² ln 10/π``) and accelerometer axis:
        the maximum-likelihood values (or the posterior mode) when coloured noise is detected, the given ones, else 0.
    maximum_likelihood : ndarray (2,)
        The maximum of the record's Whittle likelihood over amplitudes ≥ 0 (one value for the three axes).
    lower, upper : ndarray (2,)
        Profile-likelihood interval of each amplitude at ``confidence`` (with the prior when there is one); ``upper`` is
        the largest amplitude the data allow.
    statistic, p_value : float
        ``2(ℓ_coloured − ℓ_white)`` of the record alone and its p-value under white noise (χ̄², :func:`_chi_bar_squared_sf`).
    alpha : float
        False-positive rate of the decision: coloured noise is detected when ``p_value < alpha``.
    source : ColouredSource
        Where :attr:`amplitudes` come from.
    white_levels : ndarray
        White levels of the channels (z, pitch, roll) [per-sample variance, z in g²; pitch and roll in rad² at the blocks].
    ordinates : tuple of int
        Periodogram ordinates in the low band (z, pitch, roll) and in the z channel's high band.
    band : tuple of float
        Frequencies [Hz]: low band start, low band end (= high band start), high band end.
    """

    amplitudes: NDArray[np.float64]
    maximum_likelihood: NDArray[np.float64]
    lower: NDArray[np.float64]
    upper: NDArray[np.float64]
    statistic: float
    p_value: float
    alpha: float
    confidence: float
    source: ColouredSource = ColouredSource.DATA
    white_levels: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))
    ordinates: tuple[int, int] = (0, 0)
    band: tuple[float, float, float] = (0.0, 0.0, 0.0)

    @property
    def detected(self) -> bool:
        """The amplitudes under σ are not zero (detected by the decision, or given, or known from the prior)."""
        return bool(np.any(self.amplitudes > 0))

    @property
    def data_detected(self) -> bool:
        """The record alone shows coloured noise (``p_value < alpha``)."""
        return self.p_value < self.alpha

    def describe(self) -> str:
        verdict = "detected" if self.data_detected else "not detected"
        return (
            f"low-frequency noise {verdict} in the record: likelihood ratio {self.statistic:.2f} against white noise, "
            f"p = {self.p_value:.3g} (false-positive rate {self.alpha:g}; {self.ordinates[0]} + {self.ordinates[1]} periodogram "
            "ordinates)"
        )


def fit_coloured_noise(
    design: NDArray[np.float64],
    observed: NDArray[np.float64],
    channels: int,
    *,
    alpha: float = 0.05,
    confidence: float = 0.95,
    ordinates: tuple[int, int] = (0, 0),
    band: tuple[float, float, float] = (0.0, 0.0, 0.0),
    prior: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None,
    prior_detected: bool = False,
    given: NDArray[np.float64] | None = None,
) -> ColouredNoiseFit:
    """Decide whether the residuals carry coloured noise, with a calibrated false-positive rate, and fit its amplitudes.

    ``design`` columns: the channels' white levels, then the amplitudes of :data:`COLOURED_KINDS`.  The likelihood ratio of
    the coloured model against white noise alone, ``2(ℓ̂ − ℓ̂₀)``, has the χ̄² distribution under white noise
    (:func:`_chi_bar_squared_sf`, with the correlation of the amplitudes from the Fisher information at the white fit).
    Coloured noise is detected when its p-value is below ``alpha``; then the amplitudes are the maximum-likelihood ones
    (both, no further selection: dropping an amplitude that one day cannot pin leaves σ too small), otherwise 0.  The
    interval of each amplitude is the profile-likelihood one at ``confidence``; its upper end is what the data allow.
    Why a decision and not always the maximum: with white noise the maximum is above 0 in about 60 % of one-day records
    and a random-walk amplitude far below detection multiplies the variance at the harmonics (docs §1a).

    ``prior = (mean, sd)`` of the amplitudes (an earlier measurement of the instrument; ``sd = inf``: nothing known):
    the amplitudes are then the posterior mode (:func:`whittle_fit` with the penalty) when the record or the prior
    (``prior_detected``) shows coloured noise, else 0.  ``given`` ``(2, 3)``: the amplitudes per axis, used as they are
    (the record's own fit and decision are still reported).
    """
    from scipy.special import gammaincinv

    p = design.shape[1]
    kinds = p - channels
    white_only = np.zeros(p, dtype=bool)
    white_only[:channels] = True
    theta0, loglik0 = whittle_fit(design, observed, white_only)
    theta, loglik = whittle_fit(design, observed, start=theta0 + _small_amplitudes(design, theta0, channels))
    if loglik < loglik0:  # the nested white-only maximum is a point of the full model
        theta, loglik = theta0, loglik0
    statistic = max(0.0, 2.0 * (loglik - loglik0))
    e0 = np.maximum(design @ theta0, 1e-12 * float(observed.mean()) + 1e-300)  # a channel without noise has E = 0
    scaled = design / e0[:, None]
    scaled = scaled / np.maximum(np.linalg.norm(scaled, axis=0), 1e-300)
    covariance = np.linalg.pinv(scaled.T @ scaled)
    amp = slice(channels, p)
    block = covariance[amp, amp]
    correlation = None if block.shape[0] < 2 else float(block[0, 1] / math.sqrt(max(block[0, 0] * block[1, 1], 1e-300)))
    p_value = _chi_bar_squared_sf(statistic, correlation)
    detected = p_value < alpha
    penalty = None
    best, best_loglik = theta, loglik
    source = ColouredSource.DATA
    if given is not None:
        source = ColouredSource.GIVEN
        used = np.asarray(given, dtype=float).reshape(kinds, 3)
    elif prior is not None:
        source = ColouredSource.PRIOR
        penalty = (
            np.concatenate([np.zeros(channels), np.asarray(prior[0], dtype=float)]),
            np.concatenate([np.full(channels, np.inf), np.asarray(prior[1], dtype=float)]),
        )
        best, best_loglik = whittle_fit(design, observed, start=theta, penalty=penalty)
        used = np.repeat(best[amp][:, None], 3, axis=1) if (detected or prior_detected) else np.zeros((kinds, 3))
    else:
        used = np.repeat(theta[amp][:, None], 3, axis=1) if detected else np.zeros((kinds, 3))
    level = 2.0 * float(gammaincinv(0.5, confidence))  # the χ²₁ quantile
    lower, upper = np.zeros(kinds), np.zeros(kinds)
    for c in range(channels, p):
        lower[c - channels], upper[c - channels] = _profile_interval(design, observed, best, best_loglik, c, level, penalty)
    return ColouredNoiseFit(
        amplitudes=used,
        maximum_likelihood=theta[amp].copy(),
        lower=lower,
        upper=upper,
        statistic=statistic,
        p_value=p_value,
        alpha=alpha,
        confidence=confidence,
        source=source,
        white_levels=theta[:channels].copy(),
        ordinates=ordinates,
        band=band,
    )


def _small_amplitudes(design: NDArray[np.float64], theta0: NDArray[np.float64], channels: int) -> NDArray[np.float64]:
    """A start for the full fit: each amplitude at 1 % of the mean ordinate of the white fit."""
    out = np.zeros(design.shape[1])
    level = 0.01 * float((design @ theta0).mean())
    out[channels:] = level / np.maximum(design[:, channels:].mean(axis=0), 1e-300)
    return out


def _profile_interval(
    design: NDArray[np.float64],
    observed: NDArray[np.float64],
    theta: NDArray[np.float64],
    loglik: float,
    column: int,
    level: float,
    penalty: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None,
) -> tuple[float, float]:
    """``{v : 2(ℓ̂ − max_{θ_c = v} ℓ) ≤ level}`` for amplitude ``column``: lower and upper end (lower 0 when 0 is inside)."""
    from scipy.optimize import brentq

    free = np.ones(design.shape[1], dtype=bool)
    free[column] = False
    best = float(theta[column])
    prior_term = 0.0, 0.0
    if penalty is not None and np.isfinite(penalty[1][column]) and penalty[1][column] > 0:
        prior_term = float(penalty[0][column]), float(penalty[1][column])

    def deficit(v: float) -> float:
        fitted, value = whittle_fit(design, observed, free, offset=v * design[:, column], start=theta, penalty=penalty)
        if prior_term[1] > 0:  # the fixed column's own prior term
            value -= 0.5 * ((v - prior_term[0]) / prior_term[1]) ** 2
        return 2.0 * (loglik - value) - level

    # a scale: the amplitude whose column adds the mean ordinate over the band
    unit = float((design @ theta).mean()) / max(float(design[:, column].mean()), 1e-300)
    hi = max(2.0 * best, 0.05 * unit)
    for _ in range(60):
        if deficit(hi) > 0.0:
            break
        hi *= 4.0
    else:
        return 0.0, math.inf
    upper = brentq(deficit, best, hi, rtol=1e-3, xtol=1e-12 * unit)
    if best <= 0.0 or deficit(0.0) <= 0.0:
        return 0.0, float(upper)
    return float(brentq(deficit, 0.0, best, rtol=1e-3, xtol=1e-12 * unit)), float(upper)
