r"""The system-level stage over a whole record, streaming in bounded memory: a small pipeline.

1. one pass over the record in chunks of ``chunk_rows`` samples (:class:`.accumulate.StageAccumulator`,
   ``add(chunk)`` then ``finish()``): the compensated specific force's squared amplitude ``z`` and its harmonic
   information at full rate (block-Taylor sums), noise from second differences, attitude, velocity and time at a
   decimated rate (block means, static-base and platform-rate checks), the Kalman-filter and noise-model bins;
2. the solve steps (:mod:`.solve`), each returning a small frozen result: white noise, the harmonic states (x1..x5 of
   the paper plus the third harmonic x6, x7 that measures a residual K2), the filter's convergence curve, the
   loop-compensated attitude coefficients, the low-frequency noise decision, the combined coefficients and their
   separation into accelerometer corrections (:mod:`stableins.estimators.system.separation`);
3. the result (:mod:`.assembly`): the Bayesian update of the prior, the combined coefficients, typed diagnostics
   (:class:`SystemDiagnostics`).

On a turned or tilted base the Earth-rate angle comes from the full gimbal kinematics; the gyro drift, measured in the
gimbal readings (:mod:`.gyro_drift`) or given, is removed from pitch and roll.  Checks: sampling (gaps, jitter,
order), static base (velocity, attitude excursion), platform turning at the Earth rate, polar alignment, record length
(short records keep only the combinations they determine).  Read through :mod:`stableins.data.chunks`; docs/system-calibration.md.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from stableins.data.chunks import ChunkSource, source_columns, source_path, source_time_grid
from stableins.errormodel import Term
from stableins.estimators.details import CombinedDetails
from stableins.estimators.result import FitResult, Stage
from stableins.estimators.system import harmonics as hm
from stableins.estimators.system import solve
from stableins.estimators.system.accumulate import FORCE_COLUMNS, RecordSums, SourceContents, StageAccumulator
from stableins.estimators.system.assembly import (
    StagePrior,
    combined_terms,
    fit_result,
    fixed_variance,
    prior_residual_covariance,
    prior_term_covariance,
    residual_scale,
    separation_likelihood,
)
from stableins.estimators.system.attitude import AttitudeFit
from stableins.estimators.system.blocks import GIMBAL_COLUMNS
from stableins.estimators.system.checks import StageContext, check_metadata
from stableins.estimators.system.diagnostics import SystemDiagnostics
from stableins.estimators.system.gyro_drift import (
    DriftStep,
    drift_covariance_v,
    drift_step,
    likelihood_inputs,
    measure_gimbals,
    prior_drift,
)
from stableins.estimators.system.loop import DampingLoop
from stableins.estimators.system.options import SystemOptions
from stableins.estimators.system.polar import PolarAlignment, check_deferred, check_polar_alignment, drift_prediction, polar_alignment
from stableins.estimators.system.separation import Separation
from stableins.estimators.system.settings import SystemSettings
from stableins.estimators.system.thermal import THERMAL_TERMS, ThermalFit, ThermalInputs, thermal_step
from stableins.estimators.system.third_harmonic import record_note
from stableins.estimators.system.view import SystemCalibrationView
from stableins.estimators.system.whittle import ColouredNoiseFit
from stableins.noise import NoiseModel
from stableins.site import SiteMetadata
from stableins.status import Status


@dataclass(frozen=True, repr=False)
class SystemCalibration(SystemCalibrationView):
    """Everything the system stage found.

    Attributes
    ----------
    result : FitResult
        Stage ``"system"`` over the accelerometer terms of the prior: updated values
        (prior + correction), covariance of the updated values, status
        (``estimated`` when a parameter is determined by itself, ``gauge`` when only
        combinations are, ``fixed`` for terms this stage does not touch).
    combined : FitResult
        The fifteen combined coefficients (``x1..x5``, pitch and roll) [rad].
    separation : Separation
        The weighted least-squares separation (residual space).
    attitude : AttitudeFit
        The Fourier fit of pitch and roll.
    history : hm.FilterHistory or None
        Kalman-filter convergence on the decimated bins (``history_time`` gives the bin ends).
    coloured_noise : ColouredNoiseFit or None
        The low-frequency noise of the accelerometers found in the residuals: decision, amplitudes, intervals
        (None when the record is too short for the model).
    thermal : ThermalFit or None
        The bias and scale-factor temperature sensitivities as terms of the system model (:mod:`.thermal`, docs §1b).
    noise_model : NoiseModel
        The instrument's noise model under every σ of this stage, per axis (:func:`_measured_noise_model`): white noise
        from second differences, bias instability and random walk from the residual spectra, with intervals; the given
        model when a datasheet model was given.  It goes into the calibration record.
    diagnostics : SystemDiagnostics
        What the stage measured about the record besides its coefficients (noise, checks, sampling, temperature).
    drift : DriftStep or None
        The drift removed from pitch and roll, its source and the gimbal readings' measurement ``drift.gimbal`` (docs §9).
    held : HeldSteps or None
        The steps a Type B re-run holds (:mod:`stableins.estimators.system.sensitivity`); None in such a re-run's own result.
    """

    result: FitResult
    combined: FitResult
    separation: Separation
    attitude: AttitudeFit
    history: hm.FilterHistory | None
    history_time: NDArray[np.float64]
    corrections: dict[str, float]
    diagnostics: SystemDiagnostics
    notes: tuple[str, ...] = ()
    coloured_noise: ColouredNoiseFit | None = None
    noise_model: NoiseModel | None = None
    drift: DriftStep | None = None
    thermal: ThermalFit | None = None
    held: HeldSteps | None = field(default=None, compare=False)


@dataclass(frozen=True)
class HeldSteps:
    """What a re-run of the solve steps for a Type B sensitivity takes from the stage's run.

    The re-runs are :mod:`stableins.estimators.system.sensitivity`'s.

    Attributes
    ----------
    noise, harmonic : solve.WhiteNoise, solve.HarmonicFit
        The white noise and the harmonic fit (before the thermal terms): they depend on neither the damping loop nor a
        known gyro drift.
    decision : solve.NoiseDecision
        The stage's noise decision, handed unread to the thermal step of a re-run that does not test
        (:func:`.thermal.thermal_step` with ``test=False``, which decides the noise again).
    drift : DriftStep or None
        The drift step, which does not depend on the loop (None: made again, the known drift being the input).
    polar : PolarAlignment or None
        The polar alignment from the gimbal readings.
    thermal_removed : bool
        Whether the stage's thermal test removed terms from the noise decision's residuals (:attr:`.thermal.ThermalFit.removed`).
        When it did not, a re-run holds that outcome, a discrete choice, as a derivative does: the test's first decision
        and analysis are not made again.
    """

    noise: solve.WhiteNoise
    harmonic: solve.HarmonicFit
    decision: solve.NoiseDecision
    drift: DriftStep | None
    polar: PolarAlignment | None
    thermal_removed: bool


@dataclass(frozen=True)
class SystemNoise:
    """The instrument's noise in a system-level record, as the stage measures it (:func:`measure_noise_model`).

    Attributes
    ----------
    noise_model : NoiseModel
        The model under the stage's σ (:attr:`SystemCalibration.noise_model`).
    coloured_noise : ColouredNoiseFit or None
        The decision and the amplitudes (None when the record is too short for the model).
    duration : float
        Length of the record [s].
    notes : tuple of str
        What the decision, the thermal model and a third harmonic's explanations found.
    """

    noise_model: NoiseModel
    coloured_noise: ColouredNoiseFit | None
    duration: float
    notes: tuple[str, ...] = ()


def run_system_stage(
    source: ChunkSource,
    metadata: SiteMetadata,
    prior: Mapping[str, float],
    prior_covariance: Mapping[tuple[str, str], float] | None = None,
    options: SystemOptions = SystemOptions(),
    *,
    compensation_terms: Sequence[Term] = (),
    noise_model: NoiseModel | None = None,
    sums: RecordSums | None = None,
    held: HeldSteps | None = None,
) -> SystemCalibration:
    """Run the system-level stage on a static, polar-aligned record.

    Parameters
    ----------
    source : ChunkSource
        The record (``stableins.data`` reader or :class:`stableins.data.chunks.ArraySource`).
    metadata : SiteMetadata
        Latitude, gravity, sample rate, gimbal senses, base attitude, damping.
    prior : mapping
        Installed calibration the INS compensates with (record values) [SI].
    prior_covariance : mapping, optional
        ``{(id_i, id_j): cov}`` of the prior; sets the gauge metric and the
        uncertainty carried into directions the data do not see.  Default: nominal
        magnitudes of the terms.
    options : SystemOptions
    compensation_terms : sequence of Term
        Discovered (additive) terms of the prior, whose values are in ``prior``: the INS applies
        them, so the stage compensates the raw outputs with them too (the record's
        :meth:`~stableins.records.CalibrationRecord.error_model`).  This stage does not update them.
    noise_model : NoiseModel, optional
        The instrument's noise model as known before this record (the calibration record's).  A datasheet model gives
        the amplitudes of the low-frequency noise as they are; a measured one (device dwells, an earlier static record)
        is a prior on them (docs/system-calibration.md §1a).  The white level is always measured in the record.
    sums : RecordSums, optional
        The stage's pass over this record (:func:`record_sums` with the same source, prior, compensation terms and
        options), when already made: the pass is then not repeated.  The known gyro drift and the damping loop do not
        enter it, so the Type B sensitivities (:mod:`stableins.estimators.system.sensitivity`) re-run only the solve steps on it.
    held : HeldSteps, optional
        A Type B re-run (:mod:`stableins.estimators.system.sensitivity`): the steps of the stage's run (its
        :attr:`SystemCalibration.held`) that do not depend on the perturbed input are taken from it, the thermal test's
        outcome is held when it removed nothing, and the attitude fit's spectral diagnostic and the drift step's checks
        and notes are not made again: the likelihood is that of a whole run (tested against one).

    Returns
    -------
    SystemCalibration
        With :attr:`SystemCalibration.noise_model`, the noise model under its σ: measured in this record (source
        ``static record``), or with a datasheet model its slow terms as given and the record's white noise.
    """
    stage = _run(
        source,
        metadata,
        prior,
        prior_covariance,
        options,
        compensation_terms=compensation_terms,
        noise_model=noise_model,
        sums=sums,
        held=held,
    )
    harmonic, attitude, decision = stage.harmonic, stage.attitude, stage.decision
    combination = solve.combine(
        harmonic,
        attitude,
        decision,
        stage.prior_res_cov,
        context=stage.context,
        duration=stage.sums.duration,
        drift=stage.drift,
        thermal=solve.ThermalPart(stage.thermal.aliases, stage.thermal.covariance_v),
    )
    outcome = _assemble(stage, combination, prior, prior_covariance, options, noise_model=noise_model)
    return outcome if held is not None else replace(outcome, held=stage.held)


def measure_noise_model(
    source: ChunkSource,
    metadata: SiteMetadata,
    prior: Mapping[str, float],
    prior_covariance: Mapping[tuple[str, str], float] | None = None,
    options: SystemOptions = SystemOptions(),
    *,
    compensation_terms: Sequence[Term] = (),
    noise_model: NoiseModel | None = None,
) -> SystemNoise:
    """Measure the noise model of the instrument in a system-level record, exactly as :func:`run_system_stage` measures it.

    The same pass, fits and decision (docs/system-calibration.md §1a), without the separation: a record too short to
    determine the coefficients the separation needs (e.g. six hours) still gives its noise (``stableins diagnose``).
    """
    stage = _run(source, metadata, prior, prior_covariance, options, compensation_terms=compensation_terms, noise_model=noise_model)
    decision = stage.decision
    v = np.concatenate([stage.harmonic.x_hat, stage.attitude.fit.values])  # a third harmonic's explanations (discovery)
    site = stage.context.site
    third = record_note(v, decision.covariance, (site.latitude, site.gravity), options.noise_false_positive_rate, stage.thermal.aliases)
    return SystemNoise(decision.noise_model, decision.fit, stage.sums.duration, (decision.note, stage.thermal.note, *third))


@dataclass(frozen=True)
class _Stage:
    """The pass and the solve steps up to the noise decision (shared by the stage and :func:`measure_noise_model`)."""

    context: StageContext
    sums: RecordSums
    noise: solve.WhiteNoise
    harmonic: solve.HarmonicFit
    prior_res_cov: NDArray[np.float64]
    curve: solve.FilterCurve
    attitude: solve.AttitudeStep
    decision: solve.NoiseDecision
    drift: DriftStep
    thermal: ThermalFit
    polar: PolarAlignment | None
    held: HeldSteps


def _run(
    source: ChunkSource,
    metadata: SiteMetadata,
    prior: Mapping[str, float],
    prior_covariance: Mapping[tuple[str, str], float] | None,
    options: SystemOptions,
    *,
    compensation_terms: Sequence[Term],
    noise_model: NoiseModel | None,
    sums: RecordSums | None = None,
    held: HeldSteps | None = None,
) -> _Stage:
    """Run the pass over the record (:class:`.accumulate.StageAccumulator`; ``sums`` when given) and the solve steps 1-5 (:mod:`.solve`).

    ``held``: a Type B re-run (:func:`run_system_stage`), which takes the steps that do not depend on its input from it.
    """
    context, compensation_terms = _context(source, metadata, options, compensation_terms)
    latitude, gravity, rate = context.site.latitude, context.site.gravity, context.site.rate
    loop = context.loop
    if sums is None:
        sums = _accumulate(source, metadata, prior, context, compensation_terms)
    if held is None:
        noise = solve.white_noise(sums, latitude, gravity)
        harmonic = solve.fit_harmonics(sums, noise, gravity)
    else:
        noise, harmonic = held.noise, held.harmonic
    prior_res_cov = prior_residual_covariance(prior, prior_covariance, gravity)
    curve = solve.FilterCurve(None, np.zeros(0))
    if options.run_filter:
        curve = solve.filter_curve(sums, harmonic, prior_res_cov, fixed_variance(prior_covariance), latitude, gravity=gravity, rate=rate)
    if held is not None:  # a Type B re-run: the drift (made again when a known drift is the input), the polar alignment held
        polar = held.polar  # the gimbal readings' (a known drift does not enter their fit)
        drift = (
            held.drift
            if held.drift is not None
            else drift_step(sums, metadata, prior, prior_covariance, latitude=latitude, options=options)
        )
    else:
        drift = drift_step(sums, metadata, prior, prior_covariance, latitude=latitude, options=options)
        # the polar alignment from the gimbal readings (fitted for the check alone when the drift is not estimated), docs §9
        gimbal = drift.gimbal if drift.gimbal is not None else measure_gimbals(sums, metadata, prior, prior_covariance, latitude=latitude)
        polar = None if gimbal is None else polar_alignment(gimbal)
        # the static-base and polar refusals the pass kept: an equatorial drift the readings measure explains its own (docs §9)
        removed = drift.gimbal is not None
        predicted = drift_prediction(sums.attitude_blocks.means(), loop, drift.values) if removed and sums.checks.deferred else None
        explained = check_deferred(sums.checks, polar if removed else None, predicted, options)
        check_polar_alignment(polar, sums.checks.rate_ratio, options, context.path, drift_removed=removed)
        if polar is not None:
            drift = replace(drift, notes=(*drift.notes, polar.describe(), *((explained,) if explained else ())))
    attitude = solve.fit_attitude_coefficients(
        sums, harmonic, noise, loop, latitude, rate=rate, options=options, drift=drift, spectral_ratio=held is None
    )
    # with a temperature column, the thermal test's first decision fits the attitude white levels (an unmodelled thermal
    # signal goes there, not into the slow amplitudes); the thermal step decides again with them held (docs §1a, §1b).
    # A Type B re-run holds the test's outcome when it removed nothing: that first decision is then not made
    held_white = sums.temperature_bins is None
    test = held is None or held.thermal_removed
    if test or held_white:
        decision = solve.decide_noise(sums, harmonic, attitude, noise, context=context, given=noise_model, hold_attitude_white=held_white)
    else:
        assert held is not None
        decision = held.decision  # not read: the thermal step decides again (thermal_step, test=False)
    inputs = ThermalInputs(sums, harmonic, attitude, decision, context, noise, noise_model, prior)
    thermal, fitted, attitude, decision = thermal_step(inputs, options, prior_covariance, test=test)  # docs §1b
    kept = held if held is not None else HeldSteps(noise, harmonic, decision, drift, polar, thermal.removed)
    return _Stage(context, sums, noise, fitted, prior_res_cov, curve, attitude, decision, drift, thermal, polar, kept)


def record_sums(
    source: ChunkSource,
    metadata: SiteMetadata,
    prior: Mapping[str, float],
    options: SystemOptions = SystemOptions(),
    *,
    compensation_terms: Sequence[Term] = (),
) -> RecordSums:
    """Make the stage's one pass over the record (step 1 of the module docstring), for :func:`run_system_stage`'s ``sums``.

    It depends on the record, the prior it compensates with, the compensation terms, the site's gimbal senses and base
    attitude and the pass options (chunk, block and decimation settings), not on the damping loop nor on a known gyro
    drift: those enter only the solve steps.
    """
    context, compensation_terms = _context(source, metadata, options, compensation_terms)
    return _accumulate(source, metadata, prior, context, compensation_terms)


def _context(
    source: ChunkSource, metadata: SiteMetadata, options: SystemOptions, compensation_terms: Sequence[Term]
) -> tuple[StageContext, tuple[Term, ...]]:
    """Return the run's :class:`StageContext` (metadata checked) and the compensation terms the pass applies."""
    path = source_path(source)
    site = check_metadata(metadata, path)
    # the record's thermal sensitivities are the thermal terms' prior (docs §1b), not a compensation of the outputs
    terms = tuple(t for t in compensation_terms if t.id not in THERMAL_TERMS)
    loop = DampingLoop.from_metadata(metadata.damping, site.latitude, site.gravity, couplings=options.couplings)
    return StageContext(path, site, loop, options), terms


def _accumulate(
    source: ChunkSource, metadata: SiteMetadata, prior: Mapping[str, float], context: StageContext, compensation_terms: tuple[Term, ...]
) -> RecordSums:
    """Make the one pass over the record (:class:`.accumulate.StageAccumulator`)."""
    grid = source_time_grid(source)
    contents = SourceContents(
        has_temperature="temperature" in source_columns(source),
        has_gimbals=not source_columns(source) or set(GIMBAL_COLUMNS) <= set(source_columns(source)),
        time_grid=grid,
        grid_time=None if grid is None else getattr(source, "grid_time"),  # noqa: B009  (a GriddedChunkSource)
    )
    accumulator = StageAccumulator(metadata, prior, context, compensation_terms=compensation_terms, source=contents)
    rows, thin, step = accumulator.chunk_rows, accumulator.thin, accumulator.decimation
    for chunk in source.iter_chunks(accumulator.columns, rows=rows, thin=thin, step=step, reuse=True, unchecked=FORCE_COLUMNS):
        accumulator.add(chunk)
    return accumulator.finish()


def _assemble(
    stage: _Stage,
    combination: solve.Combination,
    prior: Mapping[str, float],
    prior_covariance: Mapping[tuple[str, str], float] | None,
    options: SystemOptions,
    *,
    noise_model: NoiseModel | None,
) -> SystemCalibration:
    """Assemble the stage's result: the Bayesian update of the prior, the combined coefficients and the diagnostics."""
    sums, harmonic, att, decision = stage.sums, stage.harmonic, stage.attitude.fit, stage.decision
    gravity, cov_v, to_combined, transform = stage.context.site.gravity, decision.covariance, combination.to_combined, combination.transform
    notes = [*sums.notes, *stage.attitude.notes, decision.note, stage.thermal.note, *combination.notes]
    scale = residual_scale(prior, gravity)
    cov_x = cov_v[:7, :7]
    k2_covariance = cov_x[5:7, 5:7] * np.outer([4.0 / gravity, -4.0 / gravity], [4.0 / gravity, -4.0 / gravity])
    cov_v, drift = likelihood_inputs(stage.drift, stage.attitude.drift_jacobian, cov_v)
    likelihood, fit = separation_likelihood(
        prior,
        stage.context.site,
        combination.v,
        cov_v,
        to_combined=to_combined,
        transform=transform,
        estimate_k2=options.estimate_k2,
        drift=drift,
    )
    installed = StagePrior(prior, prior_term_covariance(prior_covariance, stage.prior_res_cov, scale), prior_drift(prior, prior_covariance))
    result, corrections = fit_result(
        combination.separation,
        fit,
        likelihood,
        installed,
        notes,
        settings=SystemSettings.of(options, noise_model, stage.drift.source),
        k2=(combination.k2_values, k2_covariance) if options.estimate_k2 else None,
    )
    observable = combination.observable
    combined = FitResult(
        stage=Stage.SYSTEM_COMBINED,
        terms=combined_terms(),
        values=combination.values,
        covariance=combination.covariance,
        status=tuple(Status.ESTIMATED if ok else Status.UNIDENTIFIABLE for ok in observable),
        residuals=np.zeros(0),
        residual_sigma=np.zeros(0),
        rank=int(observable.sum()),
        notes=(f"x1 corrected for the noise bias E|n|²/(2g²) = {harmonic.noise_bias:.3e}", *stage.thermal.combined_notes),
        details=CombinedDetails(observed_attitude=att.observed, observed_attitude_covariance=att.observed_covariance, transform=transform),
    )
    return SystemCalibration(
        result=result,
        combined=combined,
        separation=combination.separation,
        attitude=att,
        history=stage.curve.history,
        history_time=stage.curve.time,
        corrections=corrections,
        diagnostics=_diagnostics(stage, combination),
        notes=tuple(notes),
        coloured_noise=decision.fit,
        noise_model=decision.noise_model,
        drift=stage.drift,
        thermal=stage.thermal,
    )


def _diagnostics(stage: _Stage, combination: solve.Combination) -> SystemDiagnostics:
    """Collect the stage's :class:`SystemDiagnostics`."""
    sums, harmonic, att, decision, checks = stage.sums, stage.harmonic, stage.attitude.fit, stage.decision, stage.sums.checks
    white = decision.covariance - decision.coloured + drift_covariance_v(stage.attitude.drift_jacobian, stage.drift)  # not coloured
    to_combined = combination.to_combined
    return SystemDiagnostics(
        duration=sums.duration,
        samples=sums.samples,
        block_length=sums.block,
        attitude_block_seconds=sums.attitude_blocks.block_seconds,  # doubled from the option's value beyond 2^14 blocks
        axis_noise_sigma=np.sqrt(stage.noise.axis_variance),
        z_residual_sigma=math.sqrt(harmonic.residual_variance),
        z_low_frequency_ratio=decision.low_frequency_ratio,
        # without the coloured part
        combined_sigma_white=np.sqrt(np.diag(to_combined @ white @ to_combined.T)),
        noise_samples=sums.noise_count,
        noise_bias_x1=harmonic.noise_bias,
        k2_residual=combination.k2_values,
        k2_residual_sigma=combination.k2_sigma,
        third_harmonic=harmonic.x_hat[5:7],
        attitude_noise_sigma=(stage.noise.sigma_pitch, stage.noise.sigma_roll),
        attitude_residual_rms=att.residual_rms,
        attitude_noise_ratio=att.residual_noise_ratio,
        platform_rate_ratio=checks.rate_ratio,
        polar_misalignment=float("nan") if stage.polar is None else stage.polar.angle,
        max_velocity=checks.max_velocity,
        attitude_excursion=checks.excursion,
        loop=stage.context.loop,
        sampling=checks.summary(),
        temperature=sums.temperature,
        time_span=(checks.first_time, checks.last_time),
    )


__all__ = [
    "HeldSteps",
    "SystemCalibration",
    "SystemDiagnostics",
    "SystemNoise",
    "SystemOptions",
    "measure_noise_model",
    "record_sums",
    "run_system_stage",
]
