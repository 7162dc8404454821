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
#: Correlation times [s] of the Gauss-Markov sum standing for flicker (bias instability), one decade apart.  The sum has
#: a 1/f spectrum from about ``1/(2π·1e5 s)`` (0.14 cycles/day) to ``1/(2π·1e2 s)`` (140 cycles/day), which covers
#: the fitted band (3.5 to 30 cycles/day) and reaches down to the harmonic frequencies.
FLICKER_TIME_CONSTANTS = (1e2, 1e3, 1e4, 1e5)

#: The coloured components: random walk and flicker, one amplitude each for the three accelerometer axes.
COLOURED_KINDS = ("random_walk", "flicker")


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
    for tau in FLICKER_TIME_CONSTANTS:
        x = width / tau
        shrink = (np.sinh(0.5 * x) / (0.5 * x)) ** 2  # two disjoint bins of the same width
        cov += np.exp(-lag / tau) * shrink
        cov[np.diag_indices_from(cov)] += 2.0 * (x - 1.0 + np.exp(-x)) / (x * x) - shrink
    return cov


def _mix(rows: NDArray[np.float64], operator: NDArray[np.float64]) -> NDArray[np.float64]:
    """``rows @ M`` for a channel's mixing operator ``M``: a loading ``(n,)`` (diagonal) or a matrix ``(n, n)``."""
    if operator.ndim == 1:
        return rows * operator
    return np.einsum("in,nm->im", rows, operator)  # einsum, not BLAS (docs/system-calibration.md §6)


def component_quadratic(
    left: NDArray[np.float64], right: NDArray[np.float64], mixing: list[list[NDArray[np.float64]]], kernel: NDArray[np.float64]
) -> NDArray[np.float64]:
    """``A Σ Bᵀ`` for the stacked channel bins without forming the stacked covariance ``Σ``.

    Channel ``p``'s coloured noise on the bins is ``Σ_a M_pa n_a`` with ``n_a`` the bin means of axis ``a``'s unit
    process (covariance ``C`` = ``kernel``, the same for the three axes and independent between them) and ``M_pa``
    = ``mixing[p][a]``: a loading ``L_pa(t_i)`` (diagonal, ``(n,)``) or an ``(n, n)`` operator (a loop filtering
    the loadings, :func:`loop_bin_mixing`).  ``left (r, P·n)``, ``right (s, P·n)`` act on the ``P`` channels' bins
    stacked; per axis ``A_a = Σ_p A_p M_pa`` and ``A Σ Bᵀ = Σ_a A_a C B_aᵀ``.  Memory ``O((r + s) n)`` besides the
    kernel and the operators.
    """
    n = kernel.shape[0]
    out = np.zeros((left.shape[0], right.shape[0]))
    for axis in range(3):
        a = sum(_mix(left[:, p * n : (p + 1) * n], ops[axis]) for p, ops in enumerate(mixing))
        b = a if right is left else sum(_mix(right[:, p * n : (p + 1) * n], ops[axis]) for p, ops in enumerate(mixing))
        out += np.einsum("in,nm,km->ik", a, kernel, b)
    return out


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

    Returns ``(design, observed, channels)`` with ``E P = design @ (w_1..w_P, α_1..α_C)`` (the
    channels' ordinates one after the other), or ``None`` when the band holds fewer than four Fourier frequencies or
    there are fewer than eight bins.
    """
    n_ch = len(residuals)
    n_bins = time.size
    span = float(time[-1] - time[0]) + (float(np.median(np.diff(time))) if n_bins > 1 else 0.0)
    ks = np.arange(max(1, int(np.ceil(band[0] * span))), int(np.floor(band[1] * span)) + 1)
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
                e += np.einsum("kn,nm,km->k", pa, kernel, pa)
            block[:, n_ch + c] = 0.5 * (e[:m] + e[m:])
        if white_gains is not None and white_gains[p] is not None:
            block[:, p] *= np.array([white_gains[p](f) for f in ks / span])
        blocks.append(block)
    return np.concatenate(blocks), np.concatenate(observed), n_ch


def whittle_fit(design: NDArray[np.float64], observed: NDArray[np.float64], free: NDArray[np.bool_] | None = None) -> tuple[NDArray, float]:
    r"""Maximum of the Whittle likelihood ``ℓ(θ) = −Σ_k [log E_k + P_k/E_k]``, ``E = design @ θ``, over ``θ ≥ 0``.

    The ordinates are independent and exponentially distributed with means ``E_k`` (the Whittle approximation).
    ``free`` selects the columns fitted (the others stay 0).  L-BFGS-B on ``θ`` scaled so that every column
    contributes about the mean ordinate.  Returns ``θ`` and ``ℓ(θ)``.
    """
    from scipy.optimize import minimize

    p = design.shape[1]
    free = np.ones(p, dtype=bool) if free is None else free
    mean = float(observed.mean())
    scale = mean / np.maximum(design[:, free].mean(axis=0), 1e-300)
    a = design[:, free] * scale
    floor = 1e-12 * mean

    def objective(u: NDArray[np.float64]) -> tuple[float, NDArray[np.float64]]:
        e = np.maximum(a @ u, floor)
        r = observed / e
        return float(np.sum(np.log(e) + r)), a.T @ ((1.0 - r) / e)

    start = np.full(a.shape[1], 1.0 / a.shape[1])
    res = minimize(
        objective,
        start,
        jac=True,
        method="L-BFGS-B",
        bounds=[(0.0, None)] * a.shape[1],
        options={"maxiter": 2000, "ftol": 1e-14, "gtol": 1e-12},
    )
    theta = np.zeros(p)
    theta[free] = res.x * scale
    return theta, -float(res.fun)


def fit_coloured_noise(
    design: NDArray[np.float64], observed: NDArray[np.float64], channels: int
) -> tuple[NDArray[np.float64], dict[str, Any]]:
    """Amplitudes of the coloured components: maximum Whittle likelihood over white levels and amplitudes ``≥ 0``.

    No detection threshold: the amplitudes are the likelihood's maximum (zero where the data show no coloured power).
    A threshold (keep the coloured model only when it is significant) leaves σ white in the records where a real
    coloured excess happens to fall below it, which makes the heavy tail of the normalized errors
    (docs/system-calibration.md §1a).  Diagnostics: ``loglik_gain`` = 2(ℓ_coloured − ℓ_white), the number of
    Fourier frequencies per channel and the white levels.
    """
    white_only = np.zeros(design.shape[1], dtype=bool)
    white_only[:channels] = True
    theta0, loglik0 = whittle_fit(design, observed, white_only)
    theta, loglik = whittle_fit(design, observed)
    if loglik < loglik0:  # the optimizer stopped short of the nested white-only maximum
        theta, loglik = theta0, loglik0
    info = {"loglik_gain": 2.0 * (loglik - loglik0), "ordinates": int(observed.size), "white_levels": theta[:channels].tolist()}
    return theta[channels:], info
