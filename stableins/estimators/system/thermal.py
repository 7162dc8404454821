r"""Temperature in the system stage: the bias and scale-factor temperature sensitivities as terms of the system model.

docs/system-calibration.md §1b.  With ``ΔT(t)`` the record's temperature column minus its mean, a bias sensitivity
``Kt_bias_a`` [m/s²/K] and a scale-factor sensitivity ``Kt_sf_a`` [1/K] (the library's terms: the output gains
``Kt_bias ΔT`` and ``Kt_sf f_a ΔT``) add to the specific-force error

.. math:: δ_a(t) = ΔT(t)\,(Kt\_bias_a/g + Kt\_sf_a\,u_a(t)),\qquad u = (\cos L\cos S, \cos L\sin S, \sin L).

They enter ``z = u·δ`` and, through the damping loop, pitch ``Δf_N/g`` and roll ``−Δf_E/g`` like any specific-force
error.  **Identifiability.**  A daily cycle ``ΔT = a_c cos S + a_s sin S`` (a solar day differs from the sidereal
one by 1/365: 1° of phase per day) turns every one of these regressors into Earth-rate harmonics the stage already
fits: ``ΔT u_x Kt_bias_x/g`` is ``cosL (a_c/2 + a_c/2 cos 2S + a_s/2 sin 2S) Kt_bias_x/g`` (x1, x4, x5), ``ΔT u_z`` is
a fundamental (x2, x3), ``ΔT u_x²`` a fundamental and a third harmonic (x2, x3, x6, x7).  So a purely daily cycle is
indistinguishable from the accelerometer terms: the bias sensitivity of x and y aliases ``(D_x − D_y)/2`` and
``(Δβxz − Δβyz)/2`` (x4, x5, θ2c, φ2s ...) and, through pitch and roll, ``φ̄``; that of z the combinations A, B
and ``Δβzx``, ``Δβzy``; the scale-factor sensitivities the fundamentals and the third harmonic (a residual K2's
signature).  More generally ``ΔT`` with content at 0, 1 and 2 cycles per sidereal day only is absorbed by the
harmonics 0–3 the stage fits.  What separates them: a temperature history with other content (a ramp or a step, a
cycle of another period, a record with a different thermal history) or a sensitivity measured elsewhere (a thermal
test, given in the record).

**What the stage does** (:func:`analyse_temperature`). The six sensitivities are nuisance parameters ``p`` with a
prior (the calibration record's entries for ``Kt_bias_a``, ``Kt_sf_a`` when it has them, else
``SystemOptions.thermal_prior``: 5 µg/K and 5 ppm/K, 1σ), centred on the record's values of them (a device-level
thermal test, ``stableins calibrate thermal``, docs/thermal-calibration.md) or on 0. Their response ``J`` in ``v``
(x1..x7, attitude) is computed with the record's own ``ΔT`` on the filter bins: ``z`` through the harmonic fit's
map, pitch and roll through the loop's bin mixing (:func:`.spectrum.loop_bin_mixing`) and the attitude fit's map, plus
the vertical path, exactly as the coloured noise is propagated (§1a). The ``z`` residuals determine the part of ``p``
the harmonics do not absorb: with ``Z̃ = R_z Z`` the thermal regressors after the harmonic fit and ``C`` the bins'
noise covariance (white ``R/n`` plus the coloured model), ``F = Z̃ᵀ C̃⁺ Z̃``, ``g = Z̃ᵀ C̃⁺ e`` (``e`` the residuals).
Posterior ``P = (P₀⁻¹ + F)⁻¹``, ``p̂ = P (P₀⁻¹ p₀ + g)`` (``p₀`` the prior mean); the coefficients become ``v − J p̂``
with covariance ``+ J P Jᵀ`` (the residuals are uncorrelated with the least-squares coefficients under white noise:
Frisch–Waugh). A direction of ``p`` is **separable** when the fraction of its thermal signal the harmonics leave in
the residuals (generalized eigenvalue of ``F`` against the information before the fit) is at least ``1/VIF_LIMIT``; a
thermal term is **detected** when the data-only χ² of the separable directions exceeds its ``1 − α`` quantile (α the
stage's false-positive rate). A combined coefficient whose variance is more than half the thermal part ``J P Jᵀ`` is
**not separable** from the thermal cycle: it keeps its value with the larger σ, the note says so and why; a named
combination whose σ grew more than :data:`.separation.GROWTH_LIMIT` (10) times over its σ without the thermal part is
not called determined (:func:`.separation.without_growth`, issue 25).

The arithmetic on the stage's bins
----------------------------------
The thermal model's arithmetic on the stage's bins (:mod:`.thermal`, docs/system-calibration.md §1b).

The record's temperature on the merged filter bins, the response of the six sensitivities in ``z``, pitch and roll and in
``v = (x1..x7, attitude)``, the information the ``z`` residuals carry on them, the directions the record separates from
the harmonics, and the share of the temperature's variance at 1 and 2 cycles per sidereal day.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from stableins.conventions import AXES, MICRO_G, PPM
from stableins.estimators.system import spectrum
from stableins.estimators.system.assembly import VIF_LIMIT, k2_map
from stableins.estimators.system.coloured import LowBand, attitude_bin_map, low_band
from stableins.estimators.system.options import DEFAULT_THERMAL_PRIOR
from stableins.estimators.system.separation import COMBINED_COEFFICIENTS

if TYPE_CHECKING:
    from stableins.estimators.system.accumulate import RecordSums, SampleBins
    from stableins.estimators.system.checks import StageContext
    from stableins.estimators.system.options import SystemOptions
    from stableins.estimators.system.solve import AttitudeStep, HarmonicFit, NoiseDecision, WhiteNoise
    from stableins.noise import NoiseModel


#: The thermal terms of the system model (the library's ids): bias sensitivities [m/s²/K], scale-factor ones [1/K].
THERMAL_TERMS = tuple(f"Kt_bias_{a}" for a in AXES) + tuple(f"Kt_sf_{a}" for a in AXES)
#: A combined coefficient is "not separable" from the thermal cycle when the thermal part is this share of its variance.
THERMAL_SHARE_LIMIT = 0.5
#: Thermal σ below this fraction of the smallest data σ of the combined coefficients: the note says "negligible".
NEGLIGIBLE = 0.05


@dataclass(frozen=True)
class ThermalFit:
    """The temperature sensitivities as the system stage sees them in one record (:func:`analyse_temperature`).

    Attributes
    ----------
    terms : tuple of str
        :data:`THERMAL_TERMS`.
    temperature_span : float
        Peak-to-peak of ``ΔT`` over the filter bins [K] (0 without a temperature column).
    daily_fraction : float
        Share of the variance of ``ΔT`` at 1 and 2 cycles per sidereal day (what the harmonics absorb; 1: a pure daily cycle).
    jacobian : ndarray (17, 6)
        Response of ``v = (x1..x7, attitude)`` to each sensitivity [per SI unit].
    prior_sigma, estimate, covariance : ndarray
        Prior 1σ, posterior mean and covariance of the sensitivities [SI].
    separable : ndarray (6, 6) or empty
        Rows: the directions of the sensitivities the record separates from the harmonics.
    chi2, dof, p_value : float, int, float
        Data-only test of the separable directions (``p_value`` 1 when there are none).
    detected : bool
        ``p_value`` below the stage's false-positive rate.
    not_separable : tuple of str
        Combined coefficients whose variance is dominated by the thermal part.
    thermal_sigma : ndarray (15,)
        σ of each combined coefficient from the thermal terms alone.
    data_sigma : ndarray (15,)
        σ of each combined coefficient without them.
    note : str
        What the stage says about temperature (never absent).
    mean_temperature : float
        The record's mean temperature [°C], from which ``ΔT`` is counted (the bias at it is the bias).
    data_estimate : ndarray (6,) or None
        The data-only estimate on the separable directions (what :meth:`remover` takes out of the residuals).
    removed : bool
        Whether the thermal test (under the stage's first, provisional noise decision) detected terms that were taken out
        of the residuals of the decision the stage keeps (:func:`thermal_step`).
    """

    terms: tuple[str, ...]
    temperature_span: float
    daily_fraction: float
    jacobian: NDArray[np.float64]
    prior_sigma: NDArray[np.float64]
    estimate: NDArray[np.float64]
    covariance: NDArray[np.float64]
    separable: NDArray[np.float64]
    chi2: float
    dof: int
    p_value: float
    detected: bool
    not_separable: tuple[str, ...]
    thermal_sigma: NDArray[np.float64]
    data_sigma: NDArray[np.float64]
    note: str
    mean_temperature: float = 0.0
    data_estimate: NDArray[np.float64] | None = None
    removed: bool = False

    def remover(self, stage: ThermalInputs) -> tuple[SampleBins, Callable[[LowBand], list[NDArray[np.float64]]]] | None:
        """Return the fine bins and the low band's residual channels without the detected thermal terms (None when none is detected).

        The noise decision runs on the residuals of the fits; a thermal term the record separates (a ramp, a step) would
        otherwise look like random walk there.  The fine bins lose ``n·z_T`` (their high band starts at 30 cycles/day,
        where what the harmonics absorb of ``z_T`` has no power); the low band's channels lose ``R z_T``, ``R pitch_T``,
        ``R roll_T`` with each channel's residual maker ``R`` (:func:`.solve.decide_noise`, ``remove``).
        """
        fine_t = stage.sums.fine_temperature_bins
        if not self.detected or self.data_estimate is None or fine_t is None:
            return None
        p = self.data_estimate
        fine = stage.sums.fine_bins
        n = fine.n.size
        count = np.zeros(n)
        total = np.zeros(n)
        m = min(n, fine_t.count.size)
        count[:m], total[:m] = fine_t.count[:m], fine_t.total[:m]
        filled = fine.n > 0
        have = count > 0
        centre = np.arange(n, dtype=float)
        temperature = np.interp(centre, centre[have], total[have] / count[have]) if have.any() else np.full(n, self.mean_temperature)
        delta = temperature - self.mean_temperature
        u = np.zeros((n, 3))
        u[filled, :2] = fine.h[filled, 1:3] / fine.n[filled, None]
        u[:, 2] = math.sin(stage.context.site.latitude)
        z_t = delta * (u @ (p[:3] / stage.context.site.gravity) + (u**2) @ p[3:])
        cleaned = replace(fine, z=fine.z - np.where(filled, fine.n * z_t, 0.0))

        def remove(band: LowBand) -> list[NDArray[np.float64]]:
            keep = stage.sums.filter_bins.n > 0
            delta_band = bin_temperature(stage.sums, keep, band) - self.mean_temperature
            z_cols, pitch, roll, _ = response(stage.context.site.gravity, stage.attitude, band, delta_band)
            out = [band.makers[0] @ (z_cols @ p)]
            if len(band.channels) == 3:
                out += [band.makers[1] @ (pitch @ p), band.makers[2] @ (roll @ p)]
            return out

        return cleaned, remove

    @property
    def aliases(self) -> dict[str, tuple[NDArray[np.float64], str]]:
        """The scale-factor sensitivities as explanations of a third harmonic (:func:`thermal_aliases`)."""
        return thermal_aliases(self)

    @property
    def combined_notes(self) -> tuple[str, ...]:
        """The combined coefficients' note naming those not separable from the temperature cycle (empty when none)."""
        if not self.not_separable:
            return ()
        names = ", ".join(self.not_separable)
        return (f"not separable from the record's temperature cycle (σ mostly the thermal terms', docs system-calibration §1b): {names}",)

    @property
    def covariance_v(self) -> NDArray[np.float64]:
        """The thermal terms' part of the covariance of ``v = (x1..x7, attitude)``: ``J P Jᵀ`` (zero when not applied)."""
        return np.asarray(self.jacobian @ self.covariance @ self.jacobian.T, dtype=np.float64)

    @property
    def applied(self) -> bool:
        """Whether the stage's coefficients were corrected and their covariance widened (a temperature column that varies)."""
        return bool(np.any(self.jacobian))

    def apply(
        self, harmonic: HarmonicFit, attitude: AttitudeStep, decision: NoiseDecision
    ) -> tuple[HarmonicFit, AttitudeStep, NoiseDecision]:
        """Return the harmonic states, the attitude step and the covariance with the thermal terms taken out: ``v − J p̂``, ``+ J P Jᵀ``."""
        if not self.applied:
            return harmonic, attitude, decision
        shift = self.jacobian @ self.estimate
        x_hat = harmonic.x_hat - shift[:7]
        fit = replace(attitude.fit, values=attitude.fit.values - shift[7:])
        covariance = decision.covariance + self.jacobian @ self.covariance @ self.jacobian.T
        return replace(harmonic, x_hat=x_hat), replace(attitude, fit=fit), replace(decision, covariance=0.5 * (covariance + covariance.T))

    def to_dict(self) -> dict[str, object]:
        """Return the JSON form (engineering units: µg/K, ppm/K)."""
        scale = np.array([MICRO_G] * 3 + [PPM] * 3)
        return {
            "terms": list(self.terms),
            "units": ["ug/K"] * 3 + ["ppm/K"] * 3,
            "temperature_span": self.temperature_span,
            "daily_fraction": self.daily_fraction,
            "estimate": (self.estimate / scale).tolist(),
            "sigma": (np.sqrt(np.diag(self.covariance)) / scale).tolist(),
            "prior_sigma": (self.prior_sigma / scale).tolist(),
            "separable_directions": int(self.separable.shape[0]),
            "chi2": self.chi2,
            "dof": self.dof,
            "p_value": self.p_value,
            "detected": self.detected,
            "not_separable": list(self.not_separable),
            "note": self.note,
        }


def thermal_prior_mean(prior: Mapping[str, float] | None) -> NDArray[np.float64]:
    """Return the prior mean of :data:`THERMAL_TERMS`: the record's values where it has them, else 0 [SI].

    The values come from a device-level thermal test (``stableins calibrate thermal``, docs/thermal-calibration.md).
    """
    out = np.zeros(len(THERMAL_TERMS))
    for k, term in enumerate(THERMAL_TERMS):
        value = None if prior is None else prior.get(term)
        if value is not None and math.isfinite(value):
            out[k] = float(value)
    return out


def prior_sigma(prior_covariance: Mapping[tuple[str, str], float] | None, default: tuple[float, float]) -> NDArray[np.float64]:
    """Prior 1σ of :data:`THERMAL_TERMS`: the calibration record's variances where it has them, else ``default`` (bias, sf)."""
    out = np.array([default[0]] * 3 + [default[1]] * 3, dtype=float)
    for k, term in enumerate(THERMAL_TERMS):
        value = None if prior_covariance is None else prior_covariance.get((term, term))
        if value is not None and math.isfinite(value) and value > 0:
            out[k] = math.sqrt(value)
    return out


def _empty(note: str, sigma: NDArray[np.float64]) -> ThermalFit:
    zero = np.zeros(15)
    return ThermalFit(
        THERMAL_TERMS,
        0.0,
        0.0,
        np.zeros((17, 6)),
        sigma,
        np.zeros(6),
        np.diag(sigma**2),
        np.zeros((0, 6)),
        0.0,
        0,
        1.0,
        False,
        (),
        zero,
        zero,
        note,
    )


@dataclass(frozen=True)
class ThermalInputs:
    """What the thermal model reads of the stage: the pass's sums, the fits up to the noise decision, the stage's context.

    ``noise`` and ``given``: what the noise decision needs when it is made again (:func:`thermal_step`).  ``prior``: the
    calibration record's values; its :data:`THERMAL_TERMS` (a device-level thermal test) are the prior mean of the
    sensitivities (:func:`thermal_prior_mean`).
    """

    sums: RecordSums
    harmonic: HarmonicFit
    attitude: AttitudeStep
    decision: NoiseDecision
    context: StageContext
    noise: WhiteNoise | None = None
    given: NoiseModel | None = None
    prior: Mapping[str, float] | None = None


def analyse_temperature(
    stage: ThermalInputs, options: SystemOptions, prior_covariance: Mapping[tuple[str, str], float] | None
) -> ThermalFit:
    """Return the thermal terms of the record (module docstring): response, estimate, separability, test and note."""
    sigma0 = prior_sigma(prior_covariance, options.thermal_prior)
    if stage.sums.temperature_bins is None:
        return _empty(
            "no temperature column: the temperature sensitivities of bias and scale factor are not modelled.  A temperature cycle "
            "at one cycle per day would alias the Earth-rate harmonics (a 5 µg/K bias sensitivity with a 2 K cycle moves "
            "(D_x − D_y)/2, the roll mean and β_zx, β_zy by up to 9e-6 rad); record the instrument temperature "
            "(docs/system-calibration.md §1b)",
            sigma0,
        )
    keep = stage.sums.filter_bins.n > 0
    if int(keep.sum()) < 16 or stage.attitude.fit.block_map is None:
        return _empty("the record is too short for the thermal model (fewer than 16 bins): temperature sensitivities not modelled", sigma0)
    from stableins.estimators.system.solve import residual_fits

    band = low_band(stage.sums.filter_bins, stage.context.site, residual_fits(stage.harmonic, stage.attitude, stage.context))
    temperature = bin_temperature(stage.sums, keep, band)
    weights = band.weights[0]
    mean_temperature = float(np.sum(weights * temperature) / np.sum(weights))
    delta_t = temperature - mean_temperature
    z_cols, _, _, jacobian = response(stage.context.site.gravity, stage.attitude, band, delta_t)
    info, gradient, info_raw = information(stage.harmonic, stage.decision, band, z_cols)
    posterior: NDArray[np.float64] = np.asarray(np.linalg.inv(np.diag(1.0 / sigma0**2) + info), dtype=np.float64)
    estimate = posterior @ (thermal_prior_mean(stage.prior) / sigma0**2 + gradient)
    separable, chi2, dof = separable_directions(info, info_raw, gradient, regressors=z_cols)
    data_estimate = None
    if dof:
        d = separable.T  # (6, k)
        data_estimate = d @ np.linalg.solve(d.T @ info @ d, d.T @ gradient)
    from stableins.estimators.distributions import chi2_sf

    p_value = chi2_sf(chi2, dof) if dof else 1.0
    to_combined = k2_map(stage.context.site.latitude, estimate_k2=options.estimate_k2)
    thermal_cov = to_combined @ jacobian @ posterior @ jacobian.T @ to_combined.T
    data_cov = to_combined @ stage.decision.covariance @ to_combined.T
    share = np.diag(thermal_cov) / np.diag(data_cov + thermal_cov)
    fit = ThermalFit(
        terms=THERMAL_TERMS,
        temperature_span=float(np.ptp(temperature)),
        daily_fraction=daily_fraction(band, delta_t, stage.context.site.latitude),
        jacobian=jacobian,
        prior_sigma=sigma0,
        estimate=estimate,
        covariance=posterior,
        separable=separable,
        chi2=chi2,
        dof=dof,
        p_value=p_value,
        detected=bool(dof and p_value < options.noise_false_positive_rate),
        not_separable=tuple(name for name, s in zip(COMBINED_COEFFICIENTS, share, strict=True) if s > THERMAL_SHARE_LIMIT),
        thermal_sigma=np.sqrt(np.diag(thermal_cov)),
        data_sigma=np.sqrt(np.diag(data_cov)),
        note="",
        mean_temperature=mean_temperature,
        data_estimate=data_estimate,
    )
    return replace(fit, note=_note(fit, options.noise_false_positive_rate))


def thermal_step(
    inputs: ThermalInputs, options: SystemOptions, prior_covariance: Mapping[tuple[str, str], float] | None, *, test: bool = True
) -> tuple[ThermalFit, HarmonicFit, AttitudeStep, NoiseDecision]:
    """Return the thermal terms and the stage's fits with them taken out (:meth:`ThermalFit.apply`).

    A thermal term the record detects is signal, not slow noise: the noise is decided again without it
    (:func:`.solve.decide_noise` with :meth:`ThermalFit.remover`) and the terms refitted under that noise.  The test
    itself runs under the stage's first decision, which fits the attitude white levels; the noise is decided again with
    them held whenever the record has a temperature column (``hold_attitude_white``), and the terms refitted under it.
    ``test=False`` holds the test's outcome "nothing to remove" (its first decision and analysis are not made;
    ``inputs.decision`` is then unused when the record has a temperature column): a Type B re-run of a stage whose test
    removed nothing (:attr:`ThermalFit.removed`; :mod:`stableins.estimators.system.sensitivity`), a discrete choice a derivative holds.
    """
    from stableins.estimators.system import solve

    thermal = analyse_temperature(inputs, options, prior_covariance) if test else None
    remove = None if thermal is None else thermal.remover(inputs)
    decision = inputs.decision
    if inputs.noise is not None and (remove is not None or inputs.sums.temperature_bins is not None):
        # the final decision holds the attitude white levels (the first one, made for this test, fitted them)
        decision = solve.decide_noise(
            inputs.sums, inputs.harmonic, inputs.attitude, inputs.noise, context=inputs.context, given=inputs.given, remove=remove
        )
        thermal = replace(analyse_temperature(replace(inputs, decision=decision), options, prior_covariance), removed=remove is not None)
    elif thermal is None:
        thermal = analyse_temperature(inputs, options, prior_covariance)
    harmonic, attitude, decision = thermal.apply(inputs.harmonic, inputs.attitude, decision)
    return thermal, harmonic, attitude, decision


def thermal_aliases(fit: ThermalFit) -> dict[str, tuple[NDArray[np.float64], str]]:
    """Return the scale-factor sensitivities as explanations of a third harmonic under the record's thermal cycle.

    ``{Kt_sf_a: (response (17,) per unit, what separates it)}`` for the axes whose sensitivity the record does not
    separate and whose response reaches x6 or x7 (:func:`.third_harmonic.explain_third_harmonic`).
    """
    out = {}
    for k in (3, 4):
        column = fit.jacobian[:, k]
        if np.any(column[5:7]) and fit.not_separable:
            out[THERMAL_TERMS[k]] = (column, "a record with a different thermal history, or the sensitivity from a thermal test")
    return out


def _format(values: NDArray[np.float64], sigma: NDArray[np.float64]) -> str:
    units = ["µg/K"] * 3 + ["ppm/K"] * 3
    scale = [MICRO_G] * 3 + [PPM] * 3
    return ", ".join(
        f"{term} = {v / s:.2f} ± {e / s:.2f} {u}" for term, v, e, s, u in zip(THERMAL_TERMS, values, sigma, scale, units, strict=True)
    )


def _detected(fit: ThermalFit, alpha: float) -> str:
    return f"thermal term DETECTED (χ² = {fit.chi2:.1f}, ν = {fit.dof}, p = {fit.p_value:.2g} < {alpha:g})"


def _note(fit: ThermalFit, alpha: float) -> str:
    sigma = np.sqrt(np.diag(fit.covariance))
    prior = _format(np.zeros(6), fit.prior_sigma).replace("0.00 ± ", "± ")
    head = (
        f"temperature: ΔT spans {fit.temperature_span:.3f} K over the record, {100 * fit.daily_fraction:.1f} % of its variance at 1 and 2 "
        "cycles per sidereal day"
    )
    largest = float(np.max(fit.thermal_sigma, initial=0.0))
    if not fit.applied or largest < NEGLIGIBLE * float(np.min(fit.data_sigma, initial=np.inf)):
        return (
            f"{head}: with sensitivities of the prior's size ({prior}) the temperature moves no combined coefficient by more than "
            f"{largest:.1e} rad (1σ), negligible; " + (_detected(fit, alpha) if fit.detected else "no thermal term detected")
        )
    alias = (
        "a daily temperature cycle is indistinguishable from the Earth-rate harmonics (the bias sensitivities of x and y alias "
        "(D_x − D_y)/2 and (Δβxz − Δβyz)/2, that of z the fundamentals A, B, Δβzx, Δβzy; the scale-factor sensitivities the "
        "fundamentals and the third harmonic, a residual K2's signature); a ramp, a step or a record with a different thermal "
        "history separates them, or a sensitivity measured in a thermal test and carried in the record"
    )
    found = (
        f"the record separates {fit.dof} of the 6 sensitivity directions from the harmonics; "
        + (_detected(fit, alpha) if fit.detected else f"not detected (p = {fit.p_value:.2g})")
        if fit.dof
        else "the record separates none of the sensitivities from the harmonics"
    )
    moved = (
        f"not separable from the thermal cycle (thermal part over half the variance): {', '.join(fit.not_separable)}, "
        f"thermal σ up to {float(np.max(fit.thermal_sigma)):.2e} rad; their values are kept with the larger σ and the update "
        "weights them accordingly"
        if fit.not_separable
        else f"the thermal part of σ is at most {float(np.max(fit.thermal_sigma)):.2e} rad"
    )
    return (
        f"{head}; the sensitivities are terms of the system model with prior {prior}; {found}; posterior {_format(fit.estimate, sigma)}; "
        "coefficients corrected by the thermal terms' posterior mean, σ widened by their posterior covariance; "
        f"{moved}.  Identifiability: {alias}"
    )


def bin_temperature(sums: RecordSums, keep: NDArray[np.bool_], band: LowBand) -> NDArray[np.float64]:
    """Mean temperature on the merged filter bins of ``band`` (bins without a temperature sample interpolated)."""
    assert sums.temperature_bins is not None
    n = band.groups.size
    index = np.unique(np.flatnonzero(keep) // band.merge, return_inverse=True)[1]
    size = sums.filter_bins.n.size
    total, count = np.zeros(size), np.zeros(size)
    m = min(size, sums.temperature_bins.count.size)
    total[:m], count[:m] = sums.temperature_bins.total[:m], sums.temperature_bins.count[:m]
    t_sum = np.bincount(index, weights=total[keep], minlength=n)
    t_count = np.bincount(index, weights=count[keep], minlength=n)
    have = t_count > 0
    return np.interp(band.time, band.time[have], t_sum[have] / t_count[have]) if have.any() else np.zeros(n)


def response(
    gravity: float, attitude: AttitudeStep, band: LowBand, delta_t: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Return the six sensitivities' ``z``, pitch and roll on the bins ``(n, 6)`` and their response ``J (17, 6)`` in ``v``.

    ``gravity`` [m/s²] of the site; ``attitude``: the stage's attitude step (its Fourier fit and vertical channel).
    """
    n = band.groups.size
    loads = band.mixing[0]  # u_a on the bins
    # δ_a per unit of each sensitivity on the bins: bias ΔT/g on its axis, scale factor ΔT u_a
    inputs = np.zeros((6, 3, n))
    for a in range(3):
        inputs[a, a] = delta_t / gravity
        inputs[3 + a, a] = delta_t * loads[a]
    z_cols = np.stack([sum(loads[a] * inputs[p, a] for a in range(3)) for p in range(6)], axis=1)
    pitch = np.stack([sum(band.mixing[1][a] @ inputs[p, a] for a in range(3)) for p in range(6)], axis=1)
    roll = np.stack([sum(band.mixing[2][a] @ inputs[p, a] for a in range(3)) for p in range(6)], axis=1)
    att = attitude.fit
    jac_x = np.zeros((10, 7))
    jac_x[:, :5] = att.vertical_jacobian @ np.diag(-attitude.along)  # ∂attitude/∂x through the vertical channel
    j_x = band.a_z @ z_cols
    return z_cols, pitch, roll, np.vstack([j_x, attitude_bin_map(att, band.groups, band.merge) @ np.vstack([pitch, roll]) + jac_x @ j_x])


def information(
    harmonic: HarmonicFit, decision: NoiseDecision, band: LowBand, z_cols: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Return the ``z`` residuals' information and gradient on the sensitivities, and the information before the harmonic fit.

    Bins' covariance: white ``R/n`` plus the coloured model the stage decided on; the residuals' is ``R_z C R_zᵀ``
    (pseudo-inverse: rank ``n − 7``).  ``harmonic``: the stage's harmonic fit (its residual variance); ``decision``: its
    noise decision (the coloured model).
    """
    n = band.groups.size
    loads = band.mixing[0]
    cov = np.diag(harmonic.residual_variance / band.weights[0])
    fit = decision.fit
    amplitudes = fit.amplitudes if fit is not None else np.zeros((len(band.kernels), 3))
    eye = np.eye(n)
    for c, kernel in enumerate(band.kernels):
        cov = cov + np.einsum("a,aij->ij", amplitudes[c], spectrum.component_quadratic(eye, eye, [loads], kernel, per_axis=True))
    maker = band.makers[0]
    residual_cov = maker @ cov @ maker.T
    precision = np.linalg.pinv(0.5 * (residual_cov + residual_cov.T), rcond=1e-10, hermitian=True)
    z_tilde = maker @ z_cols
    return z_tilde.T @ precision @ z_tilde, z_tilde.T @ precision @ band.channels[0], z_cols.T @ np.linalg.solve(cov, z_cols)


#: Relative singular value of the sensitivities' ``z`` regressors (scaled) below which a direction counts as not reached.
COLLINEAR = 1e-3


def separable_directions(
    info: NDArray[np.float64],
    info_raw: NDArray[np.float64],
    gradient: NDArray[np.float64],
    *,
    regressors: NDArray[np.float64] | None = None,
) -> tuple[NDArray[np.float64], float, int]:
    """Directions of the sensitivities the record separates from the harmonics, and the data-only χ² on them.

    Generalized eigenproblem ``F w = λ F_raw w``: ``λ`` is the share of the thermal signal along ``w`` left after the
    harmonic fit; directions with ``λ ≥ 1/VIF_LIMIT`` are separable.  ``regressors``: the sensitivities' ``z`` on the bins
    ``(n, 6)`` (:func:`response`); given, the directions they do not reach at all are left out first, from the
    regressors themselves (singular values below :data:`COLLINEAR` of the largest): ``k_z``, ``s_z`` and ``s_x + s_y``
    all enter ``z`` as ``ΔT`` (the last to 1e-5 on bin means), two null directions the information matrices show only
    to their round-off under a large random walk, where the threshold on them let them through and the data-only
    estimate moved along them by 0.1 m/s²/K: invisible in ``z``, 1000 times the signal in pitch (issue 25).
    """
    scale = np.sqrt(np.clip(np.diag(info_raw), 1e-300, None))
    basis = np.eye(info_raw.shape[0])
    if regressors is not None:
        _, singular, right = np.linalg.svd(regressors / np.where(scale > 0, scale, 1.0), full_matrices=False)
        basis = right[singular > COLLINEAR * max(float(singular.max(initial=0.0)), 1e-300)].T  # (6, k): the reachable directions
    raw = basis.T @ (info_raw / np.outer(scale, scale)) @ basis
    values, vectors = np.linalg.eigh(raw)
    keep = values > 1e-9 * max(values.max(initial=0.0), 1e-300)  # exact collinearities are ~1e-12
    if not keep.any():
        return np.zeros((0, 6)), 0.0, 0
    half = basis @ (vectors[:, keep] / np.sqrt(values[keep]))  # raw^{-1/2} on its range
    shares, w = np.linalg.eigh(half.T @ (info / np.outer(scale, scale)) @ half)
    directions = (half @ w[:, shares >= 1.0 / VIF_LIMIT]).T / scale  # in the parameters
    chi2 = 0.0
    for d in directions:
        fd = float(d @ info @ d)
        if fd > 0:
            chi2 += float(d @ gradient) ** 2 / fd
    return directions, chi2, int(directions.shape[0])


def daily_fraction(band: LowBand, delta_t: NDArray[np.float64], latitude: float) -> float:
    """Share of the weighted variance of ``ΔT`` explained by 1 and 2 cycles per sidereal day (Earth-rate angle of the bins)."""
    loads = band.mixing[0]
    weights = band.weights[0]
    c = math.cos(latitude)
    cos_s, sin_s = loads[0] / c, loads[1] / c
    design = np.stack([np.ones_like(cos_s), cos_s, sin_s, cos_s**2 - sin_s**2, 2 * cos_s * sin_s], axis=1)
    w = np.sqrt(weights)
    coef = np.linalg.lstsq(design * w[:, None], delta_t * w, rcond=None)[0]
    total = float(np.sum(weights * delta_t**2))
    left = float(np.sum(weights * (delta_t - design @ coef) ** 2))
    return 1.0 - left / total if total > 0 else 0.0


__all__ = [
    "COLLINEAR",
    "DEFAULT_THERMAL_PRIOR",
    "THERMAL_SHARE_LIMIT",
    "THERMAL_TERMS",
    "ThermalFit",
    "ThermalInputs",
    "analyse_temperature",
    "bin_temperature",
    "daily_fraction",
    "information",
    "prior_sigma",
    "response",
    "separable_directions",
    "thermal_aliases",
    "thermal_prior_mean",
    "thermal_step",
]
