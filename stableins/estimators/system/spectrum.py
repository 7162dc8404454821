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
likelihood (:func:`.whittle.fit_coloured_noise`) and the propagation ``A Σ Bᵀ`` without the stacked
covariance (:func:`component_quadratic`).  docs/system-calibration.md §1a.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
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
    *,
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
        if gain is None:
            g = 1.0
        else:
            assert gain_frequencies is not None  # given with the gain
            g = float(np.interp(f, gain_frequencies, gain))
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
# The Gauss-Markov sum standing for flicker (bias instability) has the noise model's correlation times, one decade
# apart (:data:`stableins.noise.FLICKER_TIME_CONSTANTS`, 1 s to 1e5 s).  The sum has a 1/f spectrum from about
# ``1/(2π·1e5 s)`` (0.14 cycles/day) to ``1/(2π·1 s)``, which covers the fitted bands (3.5 to about 650 cycles/day)
# and reaches down to the harmonic frequencies.

#: The coloured components: random walk and flicker, one amplitude each for the three accelerometer axes.
COLOURED_KINDS = ("random_walk", "flicker")


def amplitudes_to_allan(amplitudes: ArrayLike, gravity: float) -> NDArray[np.float64]:
    """``(K, B)`` [m/s²/√s, m/s²] from the amplitudes ``((K/g)², σ²/g²)``, ``σ² = B² ln 10/π`` per Gauss-Markov process.

    Works elementwise on arrays whose first axis is the kind (:data:`COLOURED_KINDS`); ``inf`` stays ``inf``.
    """
    a = np.maximum(np.asarray(amplitudes, dtype=float), 0.0)
    return np.stack([gravity * np.sqrt(a[0]), gravity * np.sqrt(a[1] / _noise.FLICKER_VARIANCE_PER_B2)])


def allan_to_amplitudes(random_walk: ArrayLike, bias_instability: ArrayLike, gravity: float) -> NDArray[np.float64]:
    """Invert :func:`amplitudes_to_allan`: ``((K/g)², (B/g)² ln 10/π)``."""
    k = np.asarray(random_walk, dtype=float)
    b = np.asarray(bias_instability, dtype=float)
    return np.stack([(k / gravity) ** 2, (b / gravity) ** 2 * _noise.FLICKER_VARIANCE_PER_B2])


def bin_process_kernel(kind: str, time: NDArray[np.float64], width: float) -> NDArray[np.float64]:
    """Covariance ``(n, n)`` of the bin means (bins of ``width`` centred at ``time`` since the record start) of a unit process.

    ``"random_walk"``: ``W(0) = 0``, ``Cov W(s)W(t) = min(s, t)`` [per s]; the mean over a bin ``[a, b]`` has
    variance ``a + (b − a)/3`` and, for disjoint bins, covariance = the earlier bin's centre.
    ``"flicker"``: a sum of unit Gauss-Markov processes (:data:`stableins.noise.FLICKER_TIME_CONSTANTS`), exact bin averages:
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
    for tau in _noise.FLICKER_TIME_CONSTANTS:
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
    """Compute ``A Σ Bᵀ`` for the stacked channel bins without forming the stacked covariance ``Σ``.

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


@dataclass(frozen=True)
class ResidualChannels:
    """The residual channels on common bins whose periodograms :func:`periodogram_design` builds, one entry per channel.

    Attributes
    ----------
    residuals : list of ndarray (n,)
        The bin-mean residuals of each channel's fit.
    residual_makers : list of ndarray (n, n)
        The residual maker ``R_p`` of each channel's fit on the bins.
    weights : list of ndarray (n,)
        The bin weights (samples per bin).
    white_gains : list of callable or None, optional
        ``|G(f)|²`` of a loop filtering the channel's white noise, a function of frequency [Hz] (None: 1).
    """

    residuals: list[NDArray[np.float64]]
    residual_makers: list[NDArray[np.float64]]
    weights: list[NDArray[np.float64]]
    white_gains: list[Any] | None = None


def periodogram_design(
    channels: ResidualChannels,
    time: NDArray[np.float64],
    kernels: list[NDArray[np.float64]],
    mixing: list[list[NDArray[np.float64]]],
    band: tuple[float, float],
    *,
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
    :func:`bin_process_kernel`, one amplitude for the three axes).  ``channels.white_gains[p]``, a function of frequency
    [Hz], is ``|G(f)|²`` of the loop for the white noise (stationary: its periodogram is its spectrum times ``|G|²``).

    ``exclude``: frequencies [Hz] left out with their neighbours within half a Fourier spacing (the harmonics the fits
    absorb, where a residual ordinate carries nothing).

    Returns ``(design, observed, channels)`` with ``E P = design @ (w_1..w_P, α_1..α_C)`` (the
    channels' ordinates one after the other), or ``None`` when the band holds fewer than four Fourier frequencies or
    there are fewer than eight bins.
    """
    residuals, residual_makers, weights, white_gains = channels.residuals, channels.residual_makers, channels.weights, channels.white_gains
    n_ch = len(residuals)
    frequencies = _band_frequencies(time, band, exclude)
    if frequencies is None:
        return None
    m = frequencies.size
    blocks, observed = [], []
    for p in range(n_ch):
        vectors, proj = _projections(time, frequencies, weights[p], residual_makers[p])
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
            block[:, p] *= np.array([white_gains[p](f) for f in frequencies])
        blocks.append(block)
    return np.concatenate(blocks), np.concatenate(observed), n_ch


def _band_frequencies(time: NDArray[np.float64], band: tuple[float, float], exclude: tuple[float, ...]) -> NDArray[np.float64] | None:
    """Return the Fourier frequencies [Hz] of :func:`periodogram_design`'s band (None: fewer than four, or fewer than eight bins)."""
    n_bins = time.size
    span = float(time[-1] - time[0]) + (float(np.median(np.diff(time))) if n_bins > 1 else 0.0)
    ks = np.arange(max(1, int(np.ceil(band[0] * span))), int(np.floor(band[1] * span)) + 1)
    for f in exclude:  # frequencies the fits absorb (the harmonics): no ordinate within half a Fourier spacing
        ks = ks[np.abs(ks - f * span) >= 0.5]
    if ks.size < 4 or n_bins < 8:
        return None
    return ks / span


def _projections(
    time: NDArray[np.float64], frequencies: NDArray[np.float64], weights: NDArray[np.float64], residual_maker: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Return the weighted cosine and sine vectors ``V`` ``(2m, n)`` of a channel and ``V R`` (its projections of the bin noise)."""
    w = weights / weights.sum()
    arg = 2.0 * np.pi * np.outer(frequencies, time - time[0])
    vectors = np.concatenate([2.0 * w * np.cos(arg), 2.0 * w * np.sin(arg)])  # (2m, n)
    return vectors, np.einsum("kn,nm->km", vectors, residual_maker)  # einsum, not BLAS (docs §6)


def ordinate_factors(
    channels: ResidualChannels,
    time: NDArray[np.float64],
    kernels: list[NDArray[np.float64]],
    mixing: list[list[NDArray[np.float64]]],
    band: tuple[float, float],
    *,
    exclude: tuple[float, ...] = (),
) -> tuple[list[NDArray[np.float64]], list[list[NDArray[np.float64]]]] | None:
    r"""Return the Gaussian law of the projections ``(a_k, b_k)`` behind :func:`periodogram_design`'s ordinates as factors.

    The channels' projections stacked (channel by channel, each its ``m`` cosines then its ``m`` sines; ordinate ``k`` of
    channel ``p`` is ``½(a² + b²)`` of rows ``2mp + k`` and ``2mp + m + k``) are ``Σ_p √w_p F_p ξ_p + Σ_c √α_c Σ_a F_ca η_ca``
    with independent standard normal ``ξ_p, η_ca`` ``(n,)``:

    * white, channel ``p``: ``F_p = diag(|G_p(f_k)|) V_p R_p diag(1/√n_i)`` on the channel's rows (the bins' white means,
      per-sample variance 1; a loop's gain on each projection, as in the expectations);
    * coloured component ``c`` and axis ``a``: ``F_ca = [V_p R_p M_pa]_p L_c`` with ``L_c L_cᵀ = C_c`` (the bin kernel,
      :func:`bin_process_kernel`; eigen-factor, clipped at 0): the same axis' noise in every channel, so the channels'
      projections are jointly Gaussian with exactly the covariance whose diagonal :func:`periodogram_design` sums.

    So ``E ½(a² + b²)`` of these draws is the design's expectation, and the correlations the Whittle likelihood leaves
    out (the residual maker's, a random walk's leakage along the record, one axis' noise in three channels) are in.
    Returns ``(white, coloured)``: ``white[p]`` ``(2mP, n)``, ``coloured[c][a]`` ``(2mP, n)``; None as for the design.
    """
    frequencies = _band_frequencies(time, band, exclude)
    if frequencies is None:
        return None
    n_ch, n, m = len(channels.residuals), time.size, frequencies.size
    roots = []
    for kernel in kernels:
        values, vectors = np.linalg.eigh(0.5 * (kernel + kernel.T))
        roots.append(vectors * np.sqrt(np.maximum(values, 0.0)))
    white = [np.zeros((2 * m * n_ch, n)) for _ in range(n_ch)]
    coloured = [[np.zeros((2 * m * n_ch, n)) for _ in range(3)] for _ in kernels]
    for p in range(n_ch):
        rows = slice(2 * m * p, 2 * m * (p + 1))
        _, proj = _projections(time, frequencies, channels.weights[p], channels.residual_makers[p])
        gain = np.ones(m)
        if channels.white_gains is not None and channels.white_gains[p] is not None:
            gain = np.sqrt(np.array([channels.white_gains[p](f) for f in frequencies]))
        white[p][rows] = np.concatenate([gain, gain])[:, None] * proj / np.sqrt(channels.weights[p])[None, :]
        for c, root in enumerate(roots):
            for axis in range(3):
                coloured[c][axis][rows] = np.einsum("kn,nm->km", _mix(proj, mixing[p][axis]), root)
    return white, coloured


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
    r"""Return the expected periodogram ordinates of the z residual on ``n`` uniform bins of ``width`` [s], per unit noise level.

    Columns: white (per-sample variance 1, ``samples_per_bin`` samples per bin), random walk ``(K/g)² = 1`` [1/s],
    flicker (each Gauss-Markov process of :data:`stableins.noise.FLICKER_TIME_CONSTANTS` of variance 1), at the Fourier
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
    for tau in _noise.FLICKER_TIME_CONSTANTS:
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
