"""The low-frequency (coloured) noise of the accelerometers in the system stage (docs/system-calibration.md §1a).

:func:`coloured_covariance`: the residual periodograms on the filter and fine bins, the decision (coloured noise or
not) and the amplitudes (:func:`.whittle.fit_coloured_noise`), and the unit covariances of ``(x1..x7, attitude)`` per
component and axis; :func:`noise_prior` reads a prior noise model; :func:`measured_noise_model` is the instrument's
noise model the stage puts under its σ; :func:`coloured_note` says what the decision found.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any, cast

import numpy as np
from numpy.typing import NDArray

from stableins.conventions import MICRO_G
from stableins.estimators.system import bootstrap, spectrum, whittle
from stableins.estimators.system.accumulate import SampleBins
from stableins.estimators.system.attitude import AttitudeFit, AttitudeModel
from stableins.estimators.system.checks import RecordSite
from stableins.estimators.system.whittle import ColouredNoiseFit, ColouredSource, NoisePrior
from stableins.noise import AxisNoise, NoiseModel, NoiseSource, NoiseTerm

#: At most this many bins enter the coloured-noise model (longer records: wider bins, so its memory, about 4 MiB,
#: does not depend on the record's length; one day has 144 bins of 600 s).  Monte Carlo of 4-day records (30 seeds):
#: rms z 1.03 with 160 bins, 1.22 with 320 (docs/system-calibration.md §1a).
COLOURED_BINS = 160


#: What the note says when the record carries slow noise: one day cannot tell a slow bias drift from it (docs §8, the bound).
DRIFT_CAVEAT = (
    "A slow bias drift (a ramp) is not told apart from this slow noise on one day (with the noise known, a drift's sigma "
    "is about 5 ug/day per axis on one day, 2.7 on two): it is not named, and these sigma cover it only in part (10 ug/day "
    "per axis: rms z 1.45 on x2..x5); telling it apart needs two days or more with the instrument's noise model known "
    "(docs/system-calibration.md sections 8 and 10)"
)


@dataclass(frozen=True)
class ResidualFits:
    """The stage's fits whose residuals the coloured-noise model reads (:func:`coloured_covariance`, :func:`low_band`).

    Attributes
    ----------
    x_ls : ndarray (7,)
        The least-squares harmonic states ``x1..x7``.
    blocks : dict
        The attitude block means the attitude fit ran on (``time``, ``count``, ``cos``, ``sin``, ...).
    attitude : AttitudeFit
        The attitude fit (its block residuals and ``block_map``).
    jac_x : ndarray (10, 7)
        ``∂(attitude coefficients)/∂x`` through the vertical channel.
    model : AttitudeModel
        The damping loop and the case-rotation period the attitude fit was designed with.
    """

    x_ls: NDArray[np.float64]
    blocks: dict[str, NDArray[np.float64]]
    attitude: AttitudeFit
    jac_x: NDArray[np.float64]
    model: AttitudeModel


def coloured_covariance(
    filter_bins: SampleBins,
    fine_bins: SampleBins,
    site: RecordSite,
    fits: ResidualFits,
    *,
    alpha: float = 0.05,
    prior: NoisePrior | None = None,
    remove: Callable[[LowBand], list[NDArray[np.float64]]] | None = None,
    loop_inputs: NDArray[np.float64] | None = None,
) -> tuple[NDArray[np.float64], ColouredNoiseFit | None]:
    """Return the unit covariances ``(2, 3, 17, 17)`` of ``(x1..x7, attitude)`` per coloured component and axis, and the amplitudes.

    The z, pitch and roll residuals on the filter bins with samples (merged to at most :data:`COLOURED_BINS`) give the low band: residual
    periodograms between 3.5 and 30 cycles/day (at most 0.45/bin width) with exact expectations for what the fits absorb
    (:func:`attitude_residual_maker` for pitch and roll), for the Earth-rate modulation of x and y
    (:func:`.spectrum.axis_loadings`) and for the damping loop (:func:`.spectrum.loop_bin_mixing`).  The z residual on the
    fine bins gives the high band, from the top of the low band to 0.45/fine-bin width, with the closed-form expectations
    of :func:`.spectrum.z_bin_expectations`; it shares the z channel's white level with the low band, which pins that
    level where the coloured noise is weak and makes the coloured excess below it visible.  The decision (coloured noise
    or not, false-positive rate ``alpha``), the amplitudes and their intervals: :func:`.whittle.fit_coloured_noise`.
    ``remove(bins)``: the part of each residual channel on the low band's bins that a modelled signal explains (the
    thermal terms, :meth:`.thermal.ThermalFit.remover`), taken out before the periodograms; the caller passes ``fine_bins``
    with it taken out too.
    ``loop_inputs`` (3,): the white variance per attitude-block sample of the loop's inputs ``(Δf_N/g, −Δf_E/g, Δf_D/g)``
    [rad²], from the accelerometers' white noise measured in the second differences (:func:`loop_input_variances`).  Given,
    the white levels of the pitch and roll channels are held there (``Σ_i |G_pi(f)|² v_i``) instead of fitted: one day has
    only about 26 low-band ordinates per channel, so a fitted level scatters by ±40 % (2σ) from record to record and trades
    with the slow amplitudes, while the second differences pin it to 0.6 % (issue 25; docs/system-calibration.md §1a).
    Each component of unit amplitude is propagated through the linear maps of the harmonic fit and of the attitude fit,
    ``J Σ_c Jᵀ`` (:func:`.spectrum.component_quadratic`, ``(n, n)`` matrices only): the stage's covariance adds
    ``Σ_c α_c J Σ_c Jᵀ``.  This carries the low-frequency noise at the harmonic frequencies themselves (a slowly drifting
    x bias is, over the record, part of x2 and of φ1s) and the correlation it creates between the specific-force and
    attitude coefficients.  docs/system-calibration.md §1a.  Returns ``(units, fit)``; ``fit`` is None when the record is
    too short for the model (the covariance is then white).
    """
    units = np.zeros((len(spectrum.COLOURED_KINDS), 3, 17, 17))
    if int(np.count_nonzero(filter_bins.n > 0)) < 16 or fits.attitude.block_map is None:
        return units, None
    bins = low_band(filter_bins, site, fits, loop_inputs=loop_inputs)
    if remove is not None:  # a signal the stage models (the thermal terms, .thermal) is not noise: out of the residuals
        bins = replace(bins, channels=[c - r for c, r in zip(bins.channels, remove(bins), strict=False)])
    harmonics = tuple(j * spectrum.EARTH_FREQUENCY for j in range(4))
    channels = spectrum.ResidualChannels(bins.channels, bins.makers, bins.weights, bins.gains)
    mixing = bins.mixing[: len(bins.channels)]
    built = spectrum.periodogram_design(channels, bins.time, bins.kernels, mixing, (0.0, bins.high), exclude=harmonics)
    if built is None:
        return units, None
    design, observed, n_ch = built
    design, observed, n_high, top = _high_band(fine_bins, site, fits.x_ls, bins.high, design=design, observed=observed, n_ch=n_ch)
    offset = None
    held = np.zeros(0)
    if loop_inputs is not None and n_ch > 1:  # pitch and roll white levels held at the measured noise
        held = bins.quasi_static @ np.asarray(loop_inputs, dtype=float)

    def factors() -> tuple[list[NDArray[np.float64]], list[list[NDArray[np.float64]]]]:
        made = spectrum.ordinate_factors(channels, bins.time, bins.kernels, mixing, (0.0, bins.high), exclude=harmonics)
        assert made is not None  # the same band as the design's, which exists
        return made

    # the ordinates' own law, for the tests' p-values near their decision (.bootstrap); its factors made on first use
    high_rows = design[design.shape[0] - n_high :][:, [0, *range(n_ch, design.shape[1])]]
    law = bootstrap.OrdinateLaw(factors, high_rows, held)
    if held.size:
        offset = design[:, 1:n_ch] @ held
        design = np.delete(design, np.s_[1:n_ch], axis=1)
        n_ch = 1
    fit = whittle.fit_coloured_noise(
        design,
        observed,
        n_ch,
        offset=offset,
        alpha=alpha,
        prior=NoisePrior() if prior is None else prior,
        law=law,
    )
    fit = replace(
        fit,
        ordinates=(int(observed.size - n_high), n_high),
        band=(_lowest_frequency(bins.time, bins.wide, harmonics), bins.high, top),
        white_levels=np.concatenate([fit.white_levels, held]),
    )
    n = bins.groups.size
    a_att = attitude_bin_map(fits.attitude, bins.groups, bins.merge)
    j = np.zeros((17, 3 * n))
    j[:7, :n] = bins.a_z
    j[7:, :n] = fits.jac_x @ bins.a_z
    j[7:, n:] = a_att
    for c, kernel in enumerate(bins.kernels):
        unit = spectrum.component_quadratic(j, j, bins.mixing, kernel, per_axis=True)
        units[c] = 0.5 * (unit + unit.transpose(0, 2, 1))
    return units, fit


def loop_input_variances(axis_variance: NDArray[np.float64], latitude: float, gravity: float, decimation: float) -> NDArray[np.float64]:
    r"""Return the white variance per attitude-block sample of the loop's inputs ``(Δf_N/g, −Δf_E/g, Δf_D/g)`` [rad²], (3,).

    From the platform axes' white variances ``σ_a²`` per sample (second differences), mapped through ``C_p^n``
    (docs/system-calibration.md §2) and averaged over the Earth-rate angle: ``(sin²L σ_xy² + cos²L σ_z²,  σ_xy²,
    cos²L σ_xy² + sin²L σ_z²) / (g² d)`` with ``σ_xy² = (σ_x² + σ_y²)/2`` and ``d`` samples per attitude sample (the
    attitude blocks count decimated samples: the same per-count variance as the stage's attitude σ, :func:`.solve.white_noise`).
    """
    sin2, cos2 = math.sin(latitude) ** 2, math.cos(latitude) ** 2
    var_xy = 0.5 * float(axis_variance[0] + axis_variance[1])
    var_z = float(axis_variance[2])
    return np.array([sin2 * var_xy + cos2 * var_z, var_xy, cos2 * var_xy + sin2 * var_z]) / (gravity**2 * decimation)


def attitude_bin_map(att: AttitudeFit, groups: NDArray[np.int64], merge: int) -> NDArray[np.float64]:
    """Return the attitude fit's map ``(10, 2n)`` from the (pitch, roll) bin means on the merged filter bins to its coefficients.

    ``att.block_map`` sums the blocks per filter bin (block time since the record start); ``groups`` are the merged bins
    (``merge`` filter bins each) of :func:`low_band`.
    """
    assert att.block_map is not None
    n = groups.size
    n_map = att.block_map.shape[1] // 2
    map_group = np.clip(np.searchsorted(groups, np.arange(n_map) // merge), 0, n - 1)  # 600-s bins of the fit → groups
    a_att = np.zeros((10, 2 * n))
    for ch in range(2):
        part = att.block_map[:, ch * n_map : (ch + 1) * n_map]
        for k in range(10):
            a_att[k, ch * n : (ch + 1) * n] = np.bincount(map_group, weights=part[k], minlength=n)
    return a_att


@dataclass(frozen=True)
class LowBand:
    """The residual channels on the (merged) filter bins and what the periodogram design needs of them."""

    groups: NDArray[np.int64]
    merge: int
    time: NDArray[np.float64]
    wide: float
    high: float
    a_z: NDArray[np.float64]
    kernels: list[NDArray[np.float64]]
    mixing: list[Any]
    channels: list[NDArray[np.float64]]
    makers: list[NDArray[np.float64]]
    weights: list[NDArray[np.float64]]
    gains: list[Any]
    #: ``|G_pi(0)|²`` (2, 3): the loop's quasi-static gain from each input to pitch and roll; a channel's white level is
    #: ``Σ_i |G_pi(0)|² v_i`` (the quasi-static attitude's white variance), its gain's shape ``Σ_i |G_pi(f)|² v_i`` over it.
    quasi_static: NDArray[np.float64] = field(default_factory=lambda: np.eye(2, 3))


def low_band(filter_bins: SampleBins, site: RecordSite, fits: ResidualFits, *, loop_inputs: NDArray[np.float64] | None = None) -> LowBand:
    """Build the low band: the z, pitch and roll residuals on the filter bins with samples, merged to at most :data:`COLOURED_BINS`.

    With their residual makers, weights, white-noise gains, the bin kernels of the coloured components and the loop's
    mixing.  ``loop_inputs``: the white variances ``v_i`` of the loop's three inputs (:func:`coloured_covariance`; without
    them, equal ones): the pitch and roll white gains are ``Σ_i |G_pi(f)|² v_i sinc²(f w) / Σ_i |G_pi(0)|² v_i``, so a
    channel's white level is the white variance of its quasi-static attitude per attitude sample.
    """
    inputs = np.ones(3) if loop_inputs is None else np.asarray(loop_inputs, dtype=float)
    quasi_static = np.abs(fits.model.loop.frequency_response(0.0)) ** 2  # (2, 3)
    x_ls, blocks, att, loop, latitude = fits.x_ls, fits.blocks, fits.attitude, fits.model.loop, site.latitude
    keep_bins = filter_bins.n > 0
    n_keep = int(np.count_nonzero(keep_bins))
    width = filter_bins.samples / site.rate
    merge = max(1, -(-n_keep // COLOURED_BINS))
    ids = np.flatnonzero(keep_bins) // merge
    groups, index = np.unique(ids, return_inverse=True)
    n = groups.size
    count = np.asarray(np.bincount(index, weights=filter_bins.n[keep_bins], minlength=n), dtype=float)
    zsum = np.bincount(index, weights=filter_bins.z[keep_bins], minlength=n)
    hsum = np.stack([np.bincount(index, weights=filter_bins.h[keep_bins][:, k], minlength=n) for k in range(7)], axis=1)
    x_bins = hsum / count[:, None]
    residual = zsum / count - x_bins @ x_ls
    time = np.asarray((groups + 0.5) * width * merge, dtype=float)
    wide = width * merge
    a_z = np.linalg.solve(x_bins.T @ (x_bins * count[:, None]), (x_bins * count[:, None]).T)  # (7, n)
    r_z = np.eye(n) - x_bins @ a_z
    cos_l = math.cos(latitude)
    cos_s, sin_s = x_bins[:, 1] / cos_l, x_bins[:, 2] / cos_l
    loads = [spectrum.axis_loadings(ch, cos_s, sin_s, latitude) for ch in ("z", "pitch", "roll")]
    kernels = [spectrum.bin_process_kernel(kind, time, wide) for kind in spectrum.COLOURED_KINDS]  # (n, n) each
    high = min(30.0 * spectrum.EARTH_FREQUENCY, 0.45 / wide)
    # pitch and roll: the loop filters (Δf_N/g, −Δf_E/g, Δf_D/g) = (pitch, roll, −z loadings) · n/g, bin by bin
    mixing = [[loads[0][:, a] for a in range(3)]] + spectrum.loop_bin_mixing(
        loop._controllable_modes(), time, wide, [loads[1], loads[2], -loads[0]]
    )
    # attitude residuals on the same bins (block residuals aggregated; the fit's residual maker approximated on bins)
    block_bin = np.clip(np.searchsorted(groups, np.floor(blocks["time"] / wide).astype(np.int64)), 0, n - 1)
    att_count = np.asarray(np.bincount(block_bin, weights=blocks["count"], minlength=n), dtype=float)
    channels, makers, weights = [residual], [r_z], [count]
    gains: list[Any] = [None]
    if (att_count > 0).all():
        r_att = attitude_residual_maker(blocks, block_bin, att_count, fits.model)
        for ch in range(2):
            res = np.bincount(block_bin, weights=blocks["count"] * att.block_residuals[:, ch], minlength=n) / att_count
            channels.append(res)
            makers.append(r_att)
            weights.append(att_count)
            # white accelerometer noise through the loop (three independent inputs), then averaged over the bin: the
            # bin means of a loop-filtered white noise have the spectrum Σ_i |G_pi(f)|² sinc²(f w) (no aliases: |G| ≪ 1
            # beyond the bins' Nyquist frequency)
            share = inputs / float(quasi_static[ch] @ inputs)
            gains.append(
                lambda f, ch=ch, share=share: float(
                    np.sum(share * np.abs(loop.frequency_response(2.0 * np.pi * f)[ch]) ** 2) * np.sinc(f * wide) ** 2
                )
            )
    # low band: every Fourier frequency of the record up to `high` but the harmonics the fits absorb (one day: from 4 cycles
    # per day; longer records also between the harmonics, where the random walk's power is largest)
    return LowBand(groups, merge, time, wide, high, a_z, kernels, mixing, channels, makers, weights, gains, quasi_static)


def _high_band(
    fine_bins: SampleBins,
    site: RecordSite,
    x_ls: NDArray[np.float64],
    high: float,
    *,
    design: NDArray[np.float64],
    observed: NDArray[np.float64],
    n_ch: int,
) -> tuple[NDArray[np.float64], NDArray[np.float64], int, float]:
    """Append the high band: the z residual on the fine bins (a trailing partial bin left out), above the low band.

    Returns ``(design, observed, ordinates of the high band, top frequency)`` with its rows and ordinates appended.
    """
    fine_count = fine_bins.n.copy()
    last = int(np.flatnonzero(fine_count > 0)[-1]) + 1 if np.any(fine_count > 0) else 0
    if last and fine_count[last - 1] < fine_bins.samples:
        last -= 1
    fine_count = fine_count[:last]
    top = high
    n_high = 0
    if last >= 16:
        fine_width = fine_bins.samples / site.rate
        k = np.arange(int(math.floor(high * last * fine_width)) + 1, int(math.floor(0.45 * last)) + 1)
        k = k[k / (last * fine_width) > high]
        if k.size:
            filled = fine_count > 0
            fine_residual = np.zeros(last)
            fine_residual[filled] = (fine_bins.z[:last][filled] - fine_bins.h[:last][filled] @ x_ls) / fine_count[filled]
            expected = spectrum.z_bin_expectations(k, last, fine_width, site.latitude, float(fine_count.sum()) / last)
            rows = np.zeros((k.size, design.shape[1]))
            rows[:, 0] = expected[:, 0]  # the z channel's white level, shared with the low band
            rows[:, n_ch:] = expected[:, 1:]
            design = np.vstack([design, rows])
            observed = np.concatenate([observed, spectrum.z_bin_periodogram(fine_residual, fine_count, k)])
            n_high = int(k.size)
            top = float(k[-1] / (last * fine_width))
    return design, observed, n_high, top


def _lowest_frequency(time: NDArray[np.float64], width: float, harmonics: tuple[float, ...]) -> float:
    """Return the lowest Fourier frequency of the low band (the first not within half a spacing of an absorbed harmonic)."""
    span = float(time[-1] - time[0]) + width
    k = 1
    while any(abs(k - f * span) < 0.5 for f in harmonics):
        k += 1
    return k / span


def coloured_note(fit: ColouredNoiseFit, units: NDArray[np.float64], white_x2: float, gravity: float) -> str:
    """Say what the decision on low-frequency noise found and what it does to σ (docs/system-calibration.md §1a)."""
    from stableins.estimators.system.spectrum import amplitudes_to_allan

    upper = amplitudes_to_allan(fit.upper, gravity)
    allowed = float(np.einsum("c,ca->", fit.upper, units[:, :, 1, 1]))
    bound = (
        f"the data allow up to bias instability {upper[1] / MICRO_G:.3g} ug and random walk {upper[0]:.3g} m/s^2/sqrt(s) "
        f"({100 * fit.confidence:g} % upper limits), with which the variance of x2 would be "
        f"{(white_x2 + allowed) / white_x2:.1f}x the white-noise value"
    )
    factor = (white_x2 + float(np.einsum("ca,ca->", fit.amplitudes, units[:, :, 1, 1]))) / white_x2
    used = amplitudes_to_allan(fit.amplitudes.mean(axis=1), gravity)
    levels = f"bias instability {used[1] / MICRO_G:.3g} ug and random walk {used[0]:.3g} m/s^2/sqrt(s)"
    if fit.source is ColouredSource.CONTRADICTED:
        return (
            f"the GIVEN noise model's low-frequency noise is REJECTED by the record (likelihood-ratio test of the given "
            f"amplitudes, false-alarm rate {fit.alpha:g}): it is not used; σ follow the record's own measurement ({levels}, maximum "
            f"likelihood, one value for the three axes), which makes the variance of x2 {factor:.1f}x the white-noise value; "
            f"{fit.describe()}; {bound}.  Correct the datasheet values (or give none: the stage measures them)"
        )
    if fit.source is ColouredSource.GIVEN:
        return (
            f"low-frequency noise as given in the noise model ({levels}) makes the variance of x2 {factor:.1f}x the white-noise "
            f"value; the record's own fit: {fit.describe()}; {bound}"
        )
    if fit.detected:
        how = "posterior mode with the prior noise model" if fit.source is ColouredSource.PRIOR else "maximum likelihood"
        return (
            f"the residuals carry low-frequency noise of the accelerometers ({fit.describe()}): {levels} ({how}, one value for "
            f"the three axes) make the variance of x2 {factor:.1f}x the white-noise value; the covariance of all coefficients "
            f"includes it; {bound}.  {DRIFT_CAVEAT}"
        )
    return f"no low-frequency noise ({fit.describe()}): σ is the white-noise σ; {bound}"


def noise_prior(model: NoiseModel | None, gravity: float) -> NoisePrior:
    """Return what a prior noise model says about the coloured amplitudes (:class:`.whittle.NoisePrior`).

    A datasheet model: the amplitudes per axis, used as they are (``given``, ``(2, 3)``).  A measured model (device dwells,
    an earlier static record): a Gaussian prior on each amplitude (one value for the three axes, the mean over the axes)
    (``gaussian``) with its centre at the model's value and its standard deviation from the model's interval (two-sided
    when the term was detected, one-sided from its upper limit otherwise; none when the term is not bounded);
    ``detected`` when a slow term was detected.  Nothing known (no model, source ``none``): no prior.
    """
    from scipy.special import ndtri  # the normal quantile

    from stableins.estimators.system.spectrum import allan_to_amplitudes

    if model is None or model.source is NoiseSource.NONE:
        return NoisePrior()
    values = allan_to_amplitudes(model.values("random_walk"), model.values("bias_instability"), gravity)  # (2, 3)
    if model.source is NoiseSource.DATASHEET:
        return NoisePrior(given=values)
    (k_lo, k_hi), (b_lo, b_hi) = model.limits("random_walk"), model.limits("bias_instability")
    lower = allan_to_amplitudes(k_lo, b_lo, gravity).mean(axis=1)
    upper = allan_to_amplitudes(k_hi, b_hi, gravity).mean(axis=1)
    centre = values.mean(axis=1)
    two_sided, one_sided = float(ndtri(0.5 + 0.5 * model.confidence)), float(ndtri(model.confidence))
    sd = np.where(lower > 0, (upper - lower) / (2.0 * two_sided), (upper - centre) / one_sided)
    sd = np.where(np.isfinite(upper) & (sd > 0), sd, np.inf)
    detected = bool(np.any(np.concatenate([k_lo, b_lo]) > 0))
    return NoisePrior(gaussian=(centre, sd), detected=detected)


#: Effective degrees of freedom per second difference of white noise: consecutive second differences are correlated
#: (−2/3 at lag 1, 1/6 at lag 2), so the variance of their mean square is ``2(1 + 2(4/9 + 1/36))/n`` times its square.
SECOND_DIFFERENCE_DOF = 1.0 / (1.0 + 2.0 * (4.0 / 9.0 + 1.0 / 36.0))


def measured_noise_model(
    axis_variance: NDArray[np.float64],
    count: int,
    rate: float,
    fit: ColouredNoiseFit | None,
    gravity: float,
    *,
    given: NoiseModel | None,
    path: str,
    duration: float,
) -> NoiseModel:
    """Return the noise model of the instrument measured in this record (source ``static record``), per axis.

    * White noise ``N = σ/√rate`` per axis from the second differences of the raw outputs (``σ²``, insensitive to the
      Earth-rate signal), interval from ``χ²`` with ``SECOND_DIFFERENCE_DOF · count`` degrees of freedom;
    * bias instability ``B`` and random walk ``K``: the amplitudes under σ (one value for the three axes) with their
      profile-likelihood intervals (:class:`.whittle.ColouredNoiseFit`); not detected: 0 with the upper limit;
    * quantization: not separable from the white noise at the sample rate: 0, with the upper limit at which it would make
      all of the second differences' variance (``20 Q²/dt²``).

    With a datasheet model given to the stage, its bias instability, random walk and quantization are the ones used and
    are kept (source ``datasheet``); the white noise is the record's, as under every σ of the stage.  A datasheet the
    record rejects (:func:`.whittle.given_rejected`) is not: the record's own measurement is the model (source ``static
    record``), and its provenance says the datasheet was contradicted.
    """
    from dataclasses import replace

    from scipy.special import gammaincinv

    from stableins.estimators.system.spectrum import amplitudes_to_allan

    confidence = 0.95 if fit is None else fit.confidence
    dof = max(1.0, SECOND_DIFFERENCE_DOF * count)
    tail = 0.5 * (1.0 - confidence)
    white = np.sqrt(axis_variance / rate)
    white_lo = white * math.sqrt(dof / (2.0 * float(gammaincinv(0.5 * dof, 1.0 - tail))))  # χ²_dof quantiles
    white_hi = white * math.sqrt(dof / (2.0 * float(gammaincinv(0.5 * dof, tail))))
    q_upper = np.sqrt(6.0 * axis_variance / 20.0) / rate
    whites = [NoiseTerm(float(white[a]), float(white_lo[a]), float(white_hi[a])) for a in range(3)]
    if given is not None and given.source is NoiseSource.DATASHEET and (fit is None or fit.source is not ColouredSource.CONTRADICTED):
        axes = cast("tuple[AxisNoise, AxisNoise, AxisNoise]", tuple(replace(axis, white=whites[a]) for a, axis in enumerate(given.axes)))
        provenance = (
            f"white noise measured in the system-level record {path} ({count} second differences per axis); bias instability, "
            f"random walk and quantization as given ({given.provenance or 'datasheet'})"
        )
        return replace(given, axes=axes, provenance=provenance)
    if fit is None:
        slow = {"random_walk": NoiseTerm.unbounded(), "bias_instability": NoiseTerm.unbounded()}
        slow_text = "bias instability and random walk not measured (record too short for the residual-spectrum model)"
    else:
        value = amplitudes_to_allan(fit.amplitudes.mean(axis=1), gravity)
        lower = amplitudes_to_allan(fit.lower, gravity)
        upper = amplitudes_to_allan(fit.upper, gravity)
        slow = {}
        for k, name in enumerate(("random_walk", "bias_instability")):
            v = float(value[k])
            lo = min(float(lower[k]), v) if fit.detected else 0.0
            slow[name] = NoiseTerm(v, lo, max(float(upper[k]), v))
        slow_text = (
            "bias instability and random walk from the residual spectra, one value for the three axes ("
            + fit.describe()
            + ("; with the prior noise model" if fit.source is ColouredSource.PRIOR else "")
            + ("; the given datasheet model is REJECTED by the record and not used" if fit.source is ColouredSource.CONTRADICTED else "")
            + ")"
        )
    per_axis = tuple(
        AxisNoise(
            white=whites[a],
            bias_instability=slow["bias_instability"],
            random_walk=slow["random_walk"],
            quantization=NoiseTerm(0.0, 0.0, float(q_upper[a])),
        )
        for a in range(3)
    )
    provenance = (
        f"system-level record {path}: {duration / 3600:.2f} h at {rate:g} Hz; white noise from {count} second differences "
        f"per axis; {slow_text}; quantization not separable from the white noise at this rate (upper limit)"
    )
    return NoiseModel(cast("tuple[AxisNoise, AxisNoise, AxisNoise]", per_axis), NoiseSource.STATIC_RECORD, provenance, confidence)


def attitude_residual_maker(
    blocks: dict[str, NDArray[np.float64]],
    block_bin: NDArray[np.int64],
    bin_count: NDArray[np.float64],
    model: AttitudeModel,
) -> NDArray[np.float64]:
    """Residual maker ``(n, n)`` of the attitude fit on the bins: ``R = I − X̄ (XᵀWX)⁻¹ X̄ᵀ W̄``.

    The attitude fit runs on the blocks with all its columns (mean, harmonics, the decaying Schuler and vertical
    transients, the case-rotation terms: :func:`.attitude._design`).  For noise that is constant within a bin, the
    binned residual is ``R`` applied to the binned noise, with ``X̄`` the bin means of the columns, ``W̄`` the bin
    counts and ``XᵀWX`` the fit's block-level normal matrix.  The transient columns matter: over the first hour they
    absorb a large part of a random walk's low-frequency power (the residual variance on the bins drops by up to a
    half), which a residual maker with only the mean and the harmonics misses.  Built in slices of
    :data:`.attitude.FIT_ROWS` blocks (bounded memory).  Drift columns (``gyro_drift="fit"``) are not included.
    """
    from stableins.estimators.system.attitude import FIT_ROWS, _design

    n = bin_count.size
    columns = None
    normal = None
    for start in range(0, blocks["time"].size, FIT_ROWS):
        rows = slice(start, start + FIT_ROWS)
        x = _design({k: blocks[k][rows] for k in ("time", "cos", "sin")}, model.loop, model.case_rotation_period)[0]
        wx = x * blocks["count"][rows, None]
        part = np.einsum("bi,bj->ij", wx, x)  # einsum, not BLAS (docs §6)
        sums = np.stack([np.bincount(block_bin[rows], weights=wx[:, k], minlength=n) for k in range(x.shape[1])], axis=1)
        normal = part if normal is None else normal + part
        columns = sums if columns is None else columns + sums
    assert columns is not None and normal is not None  # the record has blocks
    mean_columns = columns / bin_count[:, None]
    return np.eye(n) - mean_columns @ np.linalg.solve(normal, columns.T)


__all__ = [
    "COLOURED_BINS",
    "DRIFT_CAVEAT",
    "SECOND_DIFFERENCE_DOF",
    "LowBand",
    "ResidualFits",
    "attitude_residual_maker",
    "coloured_covariance",
    "coloured_note",
    "loop_input_variances",
    "measured_noise_model",
    "noise_prior",
]
