"""The system stage's solve steps, in order, each returning a small frozen result (docs/system-calibration.md).

From the sums of one pass (:class:`.accumulate.RecordSums`):

1. :func:`white_noise`: per-axis white noise from the second differences and its σ in pitch and roll;
2. :func:`fit_harmonics`: the least-squares harmonic states ``x1..x7`` (:class:`HarmonicFit`);
3. :func:`filter_curve`: the Kalman filter's convergence on the decimated bins (:class:`FilterCurve`);
4. :func:`fit_attitude_coefficients`: the loop-compensated Fourier fit of pitch and roll (:class:`AttitudeStep`);
5. :func:`decide_noise`: the low-frequency noise decision and the joint covariance of ``(x, attitude)``
   (:class:`NoiseDecision`);
6. :func:`combine`: the combined coefficients, the combinations the record determines and the separation
   (:class:`Combination`).

:mod:`.assembly` turns the last into the stage's result.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from stableins.conventions import SIDEREAL_DAY
from stableins.errormodel import MICRO_G_PER_G2
from stableins.errors import NotDeterminedError
from stableins.estimators.system import harmonics as hm
from stableins.estimators.system.accumulate import RecordSums, SampleBins
from stableins.estimators.system.assembly import ESTIMATE_K2_PARAMETER, GYRO_DRIFT_PARAMETER, VIF_LIMIT, k2_map, observable_directions
from stableins.estimators.system.attitude import AttitudeDrift, AttitudeFit, AttitudeModel, fit_attitude
from stableins.estimators.system.checks import StageContext
from stableins.estimators.system.coloured import (
    LowBand,
    ResidualFits,
    coloured_covariance,
    coloured_note,
    loop_input_variances,
    measured_noise_model,
    noise_prior,
)
from stableins.estimators.system.gyro_drift import (
    DriftSource,
    DriftStep,
    drift_covariance_v,
    drift_notes,
    g_sensitivity_removed,
    sensor_error_removed,
)
from stableins.estimators.system.loop import DampingLoop, drift_curvature_removed
from stableins.estimators.system.separation import COMBINED_COEFFICIENTS, GROWTH_LIMIT, Separation, separate, without_growth
from stableins.estimators.system.third_harmonic import explain_third_harmonic
from stableins.estimators.system.whittle import ColouredNoiseFit, ColouredSource
from stableins.noise import NoiseModel

if TYPE_CHECKING:
    from stableins.estimators.system.options import SystemOptions


#: Steps of the sequential Kalman filter's convergence curve at most (filter bins merged beyond 3.5 days).
FILTER_STEPS = 512


@dataclass(frozen=True)
class WhiteNoise:
    """Per-axis white noise from the second differences of the raw outputs (insensitive to the Earth-rate signal).

    Attributes
    ----------
    axis_variance : ndarray, shape (3,)
        Variance of one sample per axis [(m/s²)²]: ``E[(Δ²n)²] = 6σ²`` for white noise.
    sigma_pitch, sigma_roll : float
        σ of one sample of the pitch and roll channels [rad]: the accelerometer noise as an angle.
    """

    axis_variance: NDArray[np.float64]
    sigma_pitch: float
    sigma_roll: float


def white_noise(sums: RecordSums, latitude: float, gravity: float) -> WhiteNoise:
    """Step 1: the white noise per axis and its σ in the pitch and roll channels."""
    axis_variance = sums.noise_sums / sums.noise_count / 6.0  # E[(Δ²n)²] = 6σ² for white noise
    sin_l, cos_l = math.sin(latitude), math.cos(latitude)
    var_xy = 0.5 * (axis_variance[0] + axis_variance[1])
    sigma_pitch = math.sqrt(sin_l**2 * var_xy + cos_l**2 * axis_variance[2]) / gravity
    sigma_roll = math.sqrt(var_xy) / gravity
    return WhiteNoise(axis_variance, sigma_pitch, sigma_roll)


@dataclass(frozen=True)
class HarmonicFit:
    """The least-squares fit of the harmonic states ``x1..x7`` to ``z`` (paper x1..x5 and the third harmonic x6, x7).

    Attributes
    ----------
    x_ls : ndarray, shape (7,)
        Least-squares estimate (independent of the noise level).
    x_hat : ndarray, shape (7,)
        ``x_ls`` with x1 corrected for the noise bias ``E|n|²/(2g²)``.
    covariance : ndarray, shape (7, 7)
        White-noise covariance of ``x_hat``: the unit covariance times the residual variance.
    residual_variance : float
        Variance of the ``z`` residuals.
    noise_bias : float
        ``E|n|²/(2g²)``, removed from x1.
    """

    x_ls: NDArray[np.float64]
    x_hat: NDArray[np.float64]
    covariance: NDArray[np.float64]
    residual_variance: float
    noise_bias: float


def fit_harmonics(sums: RecordSums, noise: WhiteNoise, gravity: float) -> HarmonicFit:
    """Step 2: the harmonic states from the accumulated information."""
    info = sums.information
    x_ls, cov_unit = info.solve(1.0)  # LS estimate is independent of R
    r_var = info.residual_variance(x_ls)
    noise_bias = float(noise.axis_variance.sum()) / (2.0 * gravity**2)
    x_hat = x_ls.copy()
    x_hat[0] -= noise_bias
    return HarmonicFit(x_ls, x_hat, cov_unit * r_var, r_var, noise_bias)


@dataclass(frozen=True)
class FilterCurve:
    """The Kalman filter's convergence on the decimated bins: ``history`` (None when not run), ``time`` the bin ends [s]."""

    history: hm.FilterHistory | None
    time: NDArray[np.float64]


def filter_curve(
    sums: RecordSums,
    fit: HarmonicFit,
    prior_res_cov: NDArray[np.float64],
    k2_variance: Mapping[str, float],
    latitude: float,
    *,
    gravity: float,
    rate: float,
) -> FilterCurve:
    """Step 3: filterpy's filter over at most :data:`FILTER_STEPS` bins (consecutive bins merged: exact, sums add).

    ``R/n`` per bin; the initial covariance from the prior's residual covariance (x1..x5) and the K2 variances.
    """
    bins = sums.filter_bins
    keep = bins.n > 0
    nn = bins.n[keep]
    zb = bins.z[keep] / nn - fit.noise_bias
    hb = bins.h[keep] / nn[:, None]
    m_x = hm.state_combinations(latitude)
    p0 = np.zeros((7, 7))
    p0[:5, :5] = m_x @ prior_res_cov @ m_x.T
    p0[5, 5], p0[6, 6] = (gravity**2 / 16.0) * k2_variance["K2_x"], (gravity**2 / 16.0) * k2_variance["K2_y"]
    # at most FILTER_STEPS steps: consecutive bins merged (exact: sums add), so a week costs what two days do
    merge = -(-nn.size // FILTER_STEPS)
    if merge > 1:
        group = np.arange(nn.size) // merge
        size = int(group[-1]) + 1
        zsum = np.bincount(group, weights=zb * nn, minlength=size)
        hsum = np.stack([np.bincount(group, weights=hb[:, k] * nn, minlength=size) for k in range(hb.shape[1])], axis=1)
        nn = np.asarray(np.bincount(group, weights=nn, minlength=size), dtype=float)
        zb, hb = zsum / nn, hsum / nn[:, None]
    history = hm.kalman_filter(hb, zb, fit.residual_variance / nn, np.zeros(7), p0)
    return FilterCurve(history, (np.cumsum(nn)) / rate)


@dataclass(frozen=True)
class AttitudeStep:
    """The Fourier fit of pitch and roll (:class:`.attitude.AttitudeFit`) and what the next steps need of it.

    The block means it ran on, the projection ``along`` of x1..x5 on the vertical, the notes of the step, and the
    drift's Jacobian ``∂values/∂ε`` (10, 3) when the drift removed carries an uncertainty (:mod:`.gyro_drift`).
    """

    fit: AttitudeFit
    blocks: dict[str, NDArray[np.float64]]
    along: NDArray[np.float64]
    notes: tuple[str, ...]
    drift_jacobian: NDArray[np.float64] | None = None

    @property
    def x_jacobian(self) -> NDArray[np.float64]:
        """Return ``∂(attitude coefficients)/∂x`` (10, 7) through the vertical channel (zero for x6, x7)."""
        jac_x = np.zeros((10, 7))
        jac_x[:, :5] = self.fit.vertical_jacobian @ np.diag(-self.along)
        return jac_x


def residual_fits(harmonic: HarmonicFit, attitude: AttitudeStep, context: StageContext) -> ResidualFits:
    """Return the fits whose residuals the coloured-noise model reads (:class:`.coloured.ResidualFits`)."""
    options = context.options
    model = AttitudeModel(context.loop, options.case_rotation_period, compensate_loop=options.compensate_loop)
    return ResidualFits(harmonic.x_ls, attitude.blocks, attitude.fit, attitude.x_jacobian, model)


def fit_attitude_coefficients(
    sums: RecordSums,
    harmonic: HarmonicFit,
    noise: WhiteNoise,
    loop: DampingLoop,
    latitude: float,
    *,
    rate: float,
    options: SystemOptions,
    drift: DriftStep | None = None,
    spectral_ratio: bool = True,
) -> AttitudeStep:
    """Step 4: the loop-compensated attitude coefficients (the vertical channel from x1..x5), the gyro drift removed.

    ``drift``: the drift measured or given (:func:`.gyro_drift.drift_step`); without it, the given
    ``options.known_gyro_drift`` (or none).  On a level base the second order of the drift's response is removed from
    pitch and roll too (:func:`.loop.drift_curvature_removed`).  ``spectral_ratio``: measure the residuals' spectral
    ratio, a diagnostic (:func:`.attitude.fit_attitude`; the Type B re-runs leave it out).
    """
    blocks = sums.attitude_blocks.means()
    if drift is not None:
        blocks = sensor_error_removed(blocks, sums.gimbal_blocks, drift.gimbal, latitude)
        blocks = g_sensitivity_removed(blocks, loop, drift.g_sensitivity)
        if drift.source is not DriftSource.NONE and sums.level_yaw is not None:
            blocks = drift_curvature_removed(blocks, loop, drift.values, yaw=sums.level_yaw)
    cos_l = math.cos(latitude)
    along = np.array([1.0, cos_l, cos_l, cos_l**2, cos_l**2])
    vertical = -along * harmonic.x_hat[:5]  # Δf_D/g = −u·δ = −H x: (mean, cos S, sin S, cos 2S, sin 2S)
    decimation = sums.decimation
    sigma = (noise.sigma_pitch / math.sqrt(decimation), noise.sigma_roll / math.sqrt(decimation))
    known = options.known_gyro_drift if drift is None else (None if drift.source is DriftSource.NONE else drift.values)
    att = fit_attitude(
        blocks,
        AttitudeModel(loop, options.case_rotation_period, compensate_loop=options.compensate_loop),
        sigma,
        vertical=vertical,
        drift=AttitudeDrift(options.gyro_drift, known, jacobian=drift is not None and drift.covariance is not None),
        scale_low_frequency=False,
        map_bin_seconds=sums.filter_bins.samples / rate,
        spectral_ratio=spectral_ratio,
    )
    notes = list(att.notes)
    if drift is not None:
        notes += [*drift.notes, *drift_notes(drift)]
        return AttitudeStep(att, blocks, along, tuple(notes), att.drift_jacobian)
    if options.known_gyro_drift is None:
        notes.append(
            "gyro drift not supplied: the attitude coefficients assume none.  A constant drift of 0.001 deg/h along a platform "
            "axis drives the loop's undamped Earth-rate mode and biases them by up to 1.9e-5 rad (x1..x5 do not see it); one day "
            "of pitch and roll cannot separate it from the accelerometer harmonics.  Supply the drift in the platform frame from "
            f"the gyro calibration ({GYRO_DRIFT_PARAMETER}) for unbiased attitude coefficients"
        )
    return AttitudeStep(att, blocks, along, tuple(notes))


@dataclass(frozen=True)
class NoiseDecision:
    """The low-frequency noise decision and what it does to the covariance of ``v = (x1..x7, attitude)``.

    Attributes
    ----------
    covariance : ndarray, shape (17, 17)
        Joint covariance of ``v``, white plus coloured.
    coloured : ndarray, shape (17, 17)
        The coloured part alone.
    fit : ColouredNoiseFit or None
        Decision, amplitudes, intervals (None when the record is too short for the model).
    low_frequency_ratio : float
        Variance of x2 over its white-noise variance.
    noise_model : NoiseModel
        The instrument's noise model under every σ of the stage (:func:`.coloured.measured_noise_model`).
    note : str
        What the decision found.
    """

    covariance: NDArray[np.float64]
    coloured: NDArray[np.float64]
    fit: ColouredNoiseFit | None
    low_frequency_ratio: float
    noise_model: NoiseModel
    note: str


def decide_noise(
    sums: RecordSums,
    harmonic: HarmonicFit,
    attitude: AttitudeStep,
    noise: WhiteNoise,
    *,
    context: StageContext,
    given: NoiseModel | None,
    remove: tuple[SampleBins, Callable[[LowBand], list[NDArray[np.float64]]]] | None = None,
    hold_attitude_white: bool = True,
) -> NoiseDecision:
    """Step 5: decide on the low-frequency noise and build the covariance of ``v`` under it.

    The joint white covariance of ``v`` (cross terms from the vertical path), the coloured noise measured in the
    residuals (:func:`.coloured.coloured_covariance`) added to it, and the noise model.  ``remove``: the fine bins and
    the low band's channels without a signal the stage models (the thermal terms, :meth:`.thermal.ThermalFit.remover`).
    ``hold_attitude_white``: the pitch and roll white levels held at the accelerometers' measured white noise through
    the loop (the stage's σ); ``False`` fits them, which lets a signal not yet modelled (a thermal ramp before the
    thermal test) go into them rather than into the slow amplitudes: the thermal test's first decision
    (:func:`.thermal.thermal_step`; docs/system-calibration.md §1a), provisional: it warns of nothing (the decision the
    stage keeps, made again with them held, does).
    """
    att = attitude.fit
    gravity, rate, path = context.site.gravity, context.site.rate, context.path
    cov_x = harmonic.covariance
    cov_v = np.zeros((17, 17))
    cov_v[:7, :7] = cov_x
    fits = residual_fits(harmonic, attitude, context)
    jac_x = fits.jac_x  # ∂attitude/∂x through the vertical channel
    cov_v[7:, 7:] = att.covariance + jac_x @ cov_x @ jac_x.T
    cov_v[7:, :7] = jac_x @ cov_x
    cov_v[:7, 7:] = cov_v[7:, :7].T
    # coloured (low-frequency) accelerometer noise measured in the residuals: joint covariance of x and the attitude
    units, fit = coloured_covariance(
        sums.filter_bins,
        sums.fine_bins if remove is None else remove[0],
        context.site,
        fits,
        alpha=context.options.noise_false_positive_rate,
        prior=noise_prior(given, gravity),
        remove=None if remove is None else remove[1],
        loop_inputs=loop_input_variances(noise.axis_variance, context.site.latitude, gravity, sums.decimation)
        if hold_attitude_white
        else None,
    )
    # too short for the model: given amplitudes still apply (propagated on no bins: nothing), measured ones do not exist
    amplitudes = fit.amplitudes if fit is not None else np.zeros(units.shape[:2])
    coloured = np.einsum("ca,caij->ij", amplitudes, units)
    white_x2 = cov_v[1, 1]
    cov_v = cov_v + coloured
    if fit is not None:
        note = coloured_note(fit, units, white_x2, gravity)
        if fit.source is ColouredSource.CONTRADICTED and hold_attitude_white:  # not the thermal test's provisional decision
            warnings.warn(f"{path}: {note}", UserWarning, stacklevel=3)
    else:
        note = (
            "the record is too short for the low-frequency noise model (fewer than 16 bins of "
            f"{sums.filter_bins.samples / rate:.0f} s or four Fourier frequencies): σ is the white-noise σ"
        )
    measured = measured_noise_model(
        noise.axis_variance, sums.noise_count, rate, fit, gravity, given=given, path=path, duration=sums.duration
    )
    return NoiseDecision(cov_v, coloured, fit, float(cov_v[1, 1] / white_x2), measured, note)


@dataclass(frozen=True)
class ThermalPart:
    """What the thermal terms (:class:`.thermal.ThermalFit`) hand the combination step (:func:`combine`).

    Attributes
    ----------
    aliases : mapping
        The thermal terms as explanations of a third harmonic (:attr:`.thermal.ThermalFit.aliases`).
    covariance : ndarray (17, 17)
        Their part of the covariance of ``v`` (:attr:`.thermal.ThermalFit.covariance_v`).
    """

    aliases: Mapping[str, tuple[NDArray[np.float64], str]]
    covariance: NDArray[np.float64]


@dataclass(frozen=True)
class Combination:
    """The combined coefficients, the combinations the record determines, and their separation.

    Attributes
    ----------
    v : ndarray, shape (17,)
        ``(x1..x7, attitude coefficients)``.
    to_combined : ndarray, shape (15, 17)
        From ``v`` to the combined coefficients (:func:`.assembly.k2_map`).
    values, covariance : ndarray
        The combined coefficients and their covariance.
    transform : ndarray
        Rows: the combinations the record determines (:func:`.assembly.observable_directions`).
    observable : ndarray of bool
        Which combined coefficients are determined on their own.
    separation : Separation
        The data-only separation into accelerometer residuals.
    k2_values, k2_sigma : ndarray, shape (2,)
        Residual ``K2_x``, ``K2_y`` from the third harmonic and their σ.
    notes : tuple of str
        Notes of the step (residual K2, short record).
    """

    v: NDArray[np.float64]
    to_combined: NDArray[np.float64]
    values: NDArray[np.float64]
    covariance: NDArray[np.float64]
    transform: NDArray[np.float64]
    observable: NDArray[np.bool_]
    separation: Separation
    k2_values: NDArray[np.float64]
    k2_sigma: NDArray[np.float64]
    notes: tuple[str, ...]


def _k2_note(harmonic: HarmonicFit, k2_values: NDArray[np.float64], k2_sigma: NDArray[np.float64], latitude: float) -> str:
    """Return the size of the third harmonic as residual K2 (what it would be if it were K2) and the bias it causes."""
    cos_l = math.cos(latitude)
    bias = 3 * cos_l**2 * np.abs(harmonic.x_hat[5:7]).max()
    return (
        "read as residual quadratic coefficients "
        f"ΔK2_x = {k2_values[0] / MICRO_G_PER_G2:.1f} ± {k2_sigma[0] / MICRO_G_PER_G2:.1f} µg/g², "
        f"ΔK2_y = {k2_values[1] / MICRO_G_PER_G2:.1f} ± {k2_sigma[1] / MICRO_G_PER_G2:.1f} µg/g², it biases x2, x3 and the "
        f"fundamentals of pitch and roll by up to {bias:.2e} rad"
    )


def combine(
    harmonic: HarmonicFit,
    attitude: AttitudeStep,
    decision: NoiseDecision,
    prior_res_cov: NDArray[np.float64],
    *,
    context: StageContext,
    duration: float,
    drift: DriftStep | None = None,
    thermal: ThermalPart | None = None,
) -> Combination:
    """Step 6: the combined coefficients, what the record determines of them, and their separation.

    Raises :class:`~stableins.errors.InputError` when the record determines nothing the stage can certify.  A third
    harmonic is explained by every hypothesis the record accepts (:func:`.third_harmonic.explain_third_harmonic`, level
    ``context.options.noise_false_positive_rate``; ``thermal.aliases`` adds further ones, the thermal terms'); the note
    names them all and advises the K2 correction only when K2 is the one explanation (``options.estimate_k2``: the
    residual K2 is estimated).  ``prior_res_cov``: the prior's covariance of the residuals.  ``drift``: the drift removed
    from pitch and roll; its covariance is propagated into the attitude coefficients'.  ``inseparable``: the part of the
    covariance of ``v`` a nuisance the record cannot separate adds (the thermal terms' ``J P Jᵀ`` under a daily cycle,
    docs §1b); a combination whose σ grew more than :data:`.separation.GROWTH_LIMIT` times over its σ without that part
    is not called determined (:func:`.separation.without_growth`).
    """
    latitude, gravity, path = context.site.latitude, context.site.gravity, context.path
    estimate_k2, alpha = context.options.estimate_k2, context.options.noise_false_positive_rate
    cov_v = decision.covariance
    if drift is not None:
        cov_v = cov_v + drift_covariance_v(attitude.drift_jacobian, drift)
    cov_x = cov_v[:7, :7]
    x_hat = harmonic.x_hat
    v = np.concatenate([x_hat, attitude.fit.values])
    notes: list[str] = []
    # third harmonic: residual quadratic coefficients (x6 = gΔK_x/4, x7 = −gΔK_y/4)
    k2_values = np.array([4.0 * x_hat[5] / gravity, -4.0 * x_hat[6] / gravity])
    k2_sigma = 4.0 * np.sqrt(np.diag(cov_x)[5:7]) / gravity
    to_combined = k2_map(latitude, estimate_k2=estimate_k2)
    third = explain_third_harmonic(v, cov_v, latitude, gravity, alpha=alpha, extra=None if thermal is None else thermal.aliases)
    text = third.note(estimate_k2=estimate_k2, parameter=ESTIMATE_K2_PARAMETER, reading=_k2_note(harmonic, k2_values, k2_sigma, latitude))
    if text is not None:
        notes.append(text)
        if any(third.significant) and not (estimate_k2 and third.k2_alone):  # within 3σ: a note, not a warning
            warnings.warn(f"{path}: {text}", UserWarning, stacklevel=3)
    combined_values = to_combined @ v
    combined_cov = to_combined @ cov_v @ to_combined.T
    transform, observable, kept = observable_directions(combined_cov)
    if duration < 0.98 * SIDEREAL_DAY or not observable.all():
        hidden = [n for n, ok in zip(COMBINED_COEFFICIENTS, observable, strict=True) if not ok]
        why = (
            f"record of {duration / 3600:.2f} h (< one sidereal day)"
            if duration < 0.98 * SIDEREAL_DAY
            else f"record of {duration / 3600:.2f} h whose temperature cycle aliases the harmonics (the thermal terms' σ, docs §1b)"
        )
        notes.append(
            f"{why}: the data determine {kept} of 15 combinations of the combined "
            f"coefficients (variance inflation ≤ {VIF_LIMIT:g}); "
            + (
                f"not observable on their own and reported as unidentifiable: {', '.join(hidden)}; the separation uses only the "
                "determined combinations"
                if hidden
                else "every coefficient remains observable, with larger uncertainty than over a full day"
            )
        )
        if hidden:
            warnings.warn(f"{path}: {notes[-1]}", UserWarning, stacklevel=3)
    # what the data determine (data-only separation)
    prior_sigma = {n: math.sqrt(prior_res_cov[i, i]) for i, n in enumerate(hm.RESIDUAL_NAMES)}
    sep = separate(list(COMBINED_COEFFICIENTS), combined_values, combined_cov, latitude, prior_sigma=prior_sigma, transform=transform)
    if thermal is not None and np.any(thermal.covariance):
        own = combined_cov - to_combined @ thermal.covariance @ to_combined.T
        own_transform = observable_directions(own)[0]  # what the record determines without the thermal terms
        reference = separate(list(COMBINED_COEFFICIENTS), combined_values, own, latitude, prior_sigma=prior_sigma, transform=own_transform)
        sep, grown = without_growth(sep, reference)
        if grown:
            notes.append(
                f"not determined by these data: {', '.join(grown)}: their σ grew more than {GROWTH_LIMIT:g}× over the σ the "
                "record gives without the thermal terms it cannot separate (a daily temperature cycle, docs §1b); what pins them is "
                "the thermal prior, not the record.  A sensitivity measured in a device-level thermal test (stableins calibrate "
                "thermal) and carried in the record makes them determined again"
            )
            warnings.warn(f"{path}: {notes[-1]}", UserWarning, stacklevel=3)
    _check_determined(sep, kept, duration, path)
    return Combination(v, to_combined, combined_values, combined_cov, transform, observable, sep, k2_values, k2_sigma, tuple(notes))


def _check_determined(sep: Separation, kept: int, duration: float, path: str) -> None:
    """Raise when the separation has nothing to estimate or nothing left to test the model with."""
    if sep.dof < 1 or not any(ok for _, _, ok in sep.combinations.values()):
        what = (
            f"none of the combinations the separation needs ({'; '.join(sep.combinations)}) is determined"
            if not any(ok for _, _, ok in sep.combinations.values())
            else f"the {kept} combinations it resolves are all used by the {sep.rank} the separation estimates (ν = 0): its χ²_ν is "
            "undefined and nothing is left to test the model"
        )
        raise NotDeterminedError(
            f"the record of {duration / 3600:.2f} h determines nothing the stage can certify: {what}; over less than one sidereal day "
            "the Earth-rate harmonics are not separable from one another (the data lack one sidereal day). Nothing was estimated "
            "and no record was written",
            path=path,
            field="time",
            expected=f"a static record of one sidereal day ({SIDEREAL_DAY / 3600:.2f} h) or more",
        )


__all__ = [
    "FILTER_STEPS",
    "AttitudeStep",
    "Combination",
    "FilterCurve",
    "HarmonicFit",
    "NoiseDecision",
    "ThermalPart",
    "WhiteNoise",
    "combine",
    "decide_noise",
    "filter_curve",
    "fit_attitude_coefficients",
    "fit_harmonics",
    "residual_fits",
    "white_noise",
]
