"""The device-level pipeline: dwell summaries → coarse passes → fine stage.

Takes the dwell summaries of a device-level session, runs the coarse stage on every
coarse pass (zero-offset history, screening), fits all passes jointly (the coarse
result), runs the fine stage when fine dwells are present, and fuses coarse and fine
by a joint generalized least squares (:mod:`stableins.estimators.joint`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from stableins.conventions import ARCSEC, MICRO_G, GimbalConfiguration, dcm_nav_to_body
from stableins.errormodel import Term
from stableins.errors import InputError
from stableins.estimators.coarse import calibrate_coarse
from stableins.estimators.design import describe_design
from stableins.estimators.device_settings import DeviceSessionSettings
from stableins.estimators.dwell import DwellSummary
from stableins.estimators.fine import calibrate_fine, fine_model
from stableins.estimators.joint import fit_joint
from stableins.estimators.layout import StageLayout
from stableins.estimators.orientation import check_orientation
from stableins.estimators.residual_noise import ResidualSlowNoise, given_noise_test, residual_slow_noise
from stableins.estimators.result import FitResult, InputSensitivity, Stage
from stableins.estimators.setting import DeviceSetting
from stableins.estimators.slow_noise import SLOW_NOISE_ALPHA, DwellSlowNoise, slow_noise_test
from stableins.noise import AxisNoise, NoiseModel, NoiseSource, NoiseTerm
from stableins.site import SiteMetadata
from stableins.status import Status


@dataclass(frozen=True)
class DeviceCalibration:
    """Results of a device-level calibration.

    Attributes
    ----------
    coarse : FitResult
        Coarse stage: joint GLS fit of every coarse pass (:mod:`stableins.estimators.joint`);
        with one pass, the fit of that pass.
    fine : FitResult or None
        Fine stage alone, linearized about ``coarse`` (None when the data have no fine dwells).
    passes : tuple of FitResult
        Coarse fit of every pass on its own, in order (zero-offset history).
    fused : FitResult or None
        Joint GLS fit of all coarse passes and the fine stage (stage ``"coarse+fine"``):
        the result that goes into the record.  None without fine dwells.
    noise : NoiseModel or None
        The noise model every σ rests on (given, or measured from the dwells).
    floor : FitResult or None
        When the noise model was measured from the dwells and slow noise was not detected:
        :attr:`final` refitted with the bias instability at the upper limit the dwells allow
        (the largest floor), to show what the σ would become.
    """

    coarse: FitResult
    fine: FitResult | None = None
    passes: tuple[FitResult, ...] = field(default=(), repr=False)
    fused: FitResult | None = None
    #: The options the pipeline ran with (procedures, noise model, coarse nonlinearity, missing positions): stored in
    #: the record's stage run so that a report recomputes exactly what the calibration did.
    settings: DeviceSessionSettings | None = None
    noise: NoiseModel | None = None
    floor: FitResult | None = field(default=None, repr=False)

    @property
    def final(self) -> FitResult:
        """The result recorded: ``fused`` when there is a fine stage, else ``coarse``."""
        return self.fused if self.fused is not None else self.coarse

    def offset_history(self) -> list[str]:
        """θ20, θ30 of every pass and their change from the previous pass."""
        lines, previous = [], None
        for k, fit in enumerate(self.passes, start=1):
            t2, s2, _ = fit["theta20"]
            t3, s3, _ = fit["theta30"]
            text = f"pass {k}: theta20 = {t2 / ARCSEC:+.3f} ± {s2 / ARCSEC:.3f}″, theta30 = {t3 / ARCSEC:+.3f} ± {s3 / ARCSEC:.3f}″"
            if previous is not None:
                text += f" (change {(t2 - previous[0]) / ARCSEC:+.3f}″, {(t3 - previous[1]) / ARCSEC:+.3f}″)"
            lines.append(text)
            previous = (t2, t3)
        return lines

    def report(self) -> str:
        """Return every stage's report: coarse (and the passes), fine, fused, the noise model and the largest floor."""
        scope = f"joint fit of {len(self.passes)} passes" if len(self.passes) > 1 else "one pass"
        title = f"== device-level coarse stage ({scope}) =="
        parts = [title, self.coarse.report(), ""]
        parts += describe_design(self.coarse.ids, self.coarse.singular_values, self.coarse.null_space)
        if len(self.passes) > 1:
            parts += ["", "zero-offset passes (each on its own):"] + [f"  {line}" for line in self.offset_history()]
        if self.fine is not None:
            parts += ["", "== device-level fine stage (alone, linearized about the coarse result) ==", self.fine.report(), ""]
            parts += describe_design(self.fine.ids, self.fine.singular_values, self.fine.null_space)
        if self.fused is not None:
            parts += ["", "== coarse + fine fused (joint GLS; recorded) ==", self.fused.report()]
        if self.noise is not None:
            parts += ["", "== noise model (every σ above rests on it) ==", self.noise.report()]
        if self.floor is not None:
            parts += ["", *floor_table(self.final, self.floor, self.noise)]
        return "\n".join(parts)

    def __str__(self) -> str:
        return self.report()

    def __repr__(self) -> str:
        from stableins.display import clipped, parameter_lines

        fits = [f"coarse ({len(self.passes) or 1} pass{'es' if len(self.passes) > 1 else ''}) χ²_ν = {self.coarse.chi2_red:.3f}"]
        if self.fine is not None:
            fits.append(f"fine χ²_ν = {self.fine.chi2_red:.3f}")
        if self.fused is not None:
            fits.append(f"fused χ²_ν = {self.fused.chi2_red:.3f} (ν = {self.fused.dof})")
        lines = [f"<DeviceCalibration: stage '{self.final.stage}' recorded, {len(self.final.terms)} parameters>", "; ".join(fits)]
        lines += parameter_lines(self.final.rows())
        return clipped(
            lines,
            "(print(calibration) for every stage, calibration.final for the recorded fit, "
            "CalibrationRecord.from_device(calibration, site) for the record)",
        )

    def _repr_html_(self) -> str:
        return self.final._repr_html_()


def slow_fraction(run: _Stages) -> float:
    """Return the largest share of an estimated parameter's variance the bias instability carries in ``run``.

    ``max_p 1 − σ_p²(B = 0)/σ_p²(B)``, the recorded fit refitted with the bias instability at 0 (the random walk kept):
    the ``ρ`` of :meth:`stableins.estimators.residual_noise.ResidualSlowNoise.bias_instability_for_sigma`.
    """
    final = run.fused or run.coarse
    white = replace(run.session, noise=run.session.noise.with_values(bias_instability=0.0))
    if run.fused is not None:
        without = white.fit_joint(run.used_coarse, run.used_fine, start=run.fused, stage=Stage.DEVICE)
    else:
        without = white.fit_joint(run.used_coarse, start=run.coarse, nonlinear=any(i.startswith("K2_") for i in run.coarse.ids))
    shares = [
        1.0 - (without[k][1] / final[k][1]) ** 2
        for k, st in zip(final.ids, final.status, strict=True)
        if st == Status.ESTIMATED and final[k][1] > 0 and k in without.ids
    ]
    return min(max(max(shares, default=0.0), 0.0), 1.0)


def _measured_slow_noise(
    white: NoiseModel, residual: ResidualSlowNoise, source: str, stages: Callable[[NoiseModel], _Stages]
) -> tuple[NoiseModel, _Stages]:
    """Return the measured model with the σ's amplitude (:func:`noise_from_residuals` with :func:`slow_fraction`) and its run.

    The stages run under the REML estimate itself, and again under the corrected amplitude when it differs.
    """
    run = stages(noise_from_residuals(white, residual, source))
    fraction = slow_fraction(run) if residual.bias_instability > 0 else 0.0
    model = noise_from_residuals(white, residual, source, slow_fraction=fraction)
    if residual.bias_instability_for_sigma(fraction) <= residual.bias_instability:
        return model, run
    return model, stages(model)


def dwell_slow_noise(dwells: Sequence[DwellSummary], *, alpha: float = SLOW_NOISE_ALPHA, confidence: float = 0.95) -> DwellSlowNoise:
    """Return the within-dwell Allan decision of :func:`stableins.estimators.slow_noise.slow_noise_test` on the usable dwells."""
    usable = [d for d in dwells if d.usable and d.samples > 1 and d.duration > 0]
    ratios = [(d.samples, d.allan_ratios, d.noise**2, d.rate) for d in usable if d.allan_ratios is not None]
    return slow_noise_test(ratios, alpha=alpha, confidence=confidence)


def noise_from_residuals(white: NoiseModel, residual: ResidualSlowNoise, source: str, *, slow_fraction: float = 0.0) -> NoiseModel:
    """Return the session's noise model: white noise from ``white`` (the dwells), slow noise from the residuals' REML estimate.

    Bias instability: the value the σ use (:meth:`ResidualSlowNoise.bias_instability_for_sigma` with
    ``slow_fraction``: the estimate with the second-order correction of the σ it dominates, issue 25; 0: the
    estimate), lower limit 0 unless the combined decision detects slow noise (then the estimate), upper limit the
    profile limit; random walk: the estimate, not bounded above (a session cannot separate it from bias instability
    well); the decision is the combined test
    (:mod:`stableins.estimators.residual_noise`).
    """
    detected = residual.test.detected
    used = residual.bias_instability_for_sigma(slow_fraction)
    b = NoiseTerm(used, residual.bias_instability if detected else 0.0, max(residual.bias_instability_upper, used))
    k = NoiseTerm(residual.random_walk, residual.random_walk if detected else 0.0, math.inf)
    axes = tuple(replace(a, bias_instability=b, random_walk=k) for a in white.axes)
    provenance = (
        f"measured in the dwells of {source}: white noise from the sample variances; slow noise "
        f"({'detected' if detected else 'not detected'}, p = {residual.test.p_value:.3g} at false-positive rate "
        f"{residual.test.alpha:g}: residual scatter between passes at each position p = {residual.residual_p:.3g}, "
        f"Allan variance inside the dwells p = {residual.allan_p:.3g}) estimated by restricted maximum likelihood from "
        f"{residual.rows} within-position contrasts of the dwell-mean residuals and the within-dwell Allan variance: "
        f"B = {residual.bias_instability / MICRO_G:.3g} ug (upper {residual.bias_instability_upper / MICRO_G:.3g} ug), "
        f"K = {residual.random_walk:.3g} m/s^2/sqrt(s) (not bounded above); the σ use these values, detected or not, "
        f"B as {used / MICRO_G:.3g} ug (B^2 + rho Var(B^2)/B^2 with rho = {slow_fraction:.2f} the largest share of a σ² it "
        "carries, capped at the upper limit: the second-order correction of the σ it dominates; docs/noise.md §3)"
    )
    return NoiseModel(axes, NoiseSource.DEVICE_DWELLS, provenance, white.confidence, residual.test)  # type: ignore[arg-type]


def noise_from_dwells(
    dwells: Sequence[DwellSummary], *, alpha: float = SLOW_NOISE_ALPHA, confidence: float = 0.95, source: str = "the dwells"
) -> NoiseModel:
    """Return the noise model a device session measures (source ``DEVICE_DWELLS``).

    * white noise ``N`` per axis from the sample variances, pooled over the usable dwells
      (``N² = s²/rate``; interval from χ² with the pooled degrees of freedom);
    * slow noise: the decision of :func:`stableins.estimators.slow_noise.slow_noise_test` at the
      false-positive rate ``alpha``.  Detected: the bias instability is its unbiased estimate
      with interval; not detected: 0 with the upper limit the dwells allow.  The dwells
      cannot separate the random walk from bias instability: ``K`` is 0, not bounded;
    * quantization: not measured (0, not bounded).
    """
    from stableins.estimators.distributions import chi2_ppf, norm_ppf

    usable = [d for d in dwells if d.usable and d.samples > 1 and d.duration > 0]
    if not usable:
        return NoiseModel.unknown("no usable dwells")
    dof = np.array([d.samples - 1.0 for d in usable])
    n2 = np.array([d.noise**2 / d.rate for d in usable])  # (m, 3): s² dt
    pooled = (dof[:, None] * n2).sum(axis=0) / dof.sum()
    total = dof.sum()
    q = (1.0 - confidence) / 2.0
    lo, hi = total / chi2_ppf(1 - q, total), total / chi2_ppf(q, total)
    slow = dwell_slow_noise(usable, alpha=alpha, confidence=confidence)
    z = norm_ppf(confidence)
    # detected: the unbiased estimate of B² with its interval; not detected: 0 with the upper limit.  (Using the
    # non-significant estimate instead inflates σ on white noise, grossly so for short dwells, where it is mostly noise.)
    if slow.test.detected:
        b_hat = math.sqrt(max(slow.b2, 0.0))
        b = NoiseTerm(b_hat, math.sqrt(max(slow.b2 - z * slow.b2_sigma, 0.0)), max(slow.b_upper, b_hat))
    else:
        b = NoiseTerm(0.0, 0.0, slow.b_upper)
    longest = max(d.duration for d in usable)
    axes = tuple(
        AxisNoise(
            NoiseTerm(math.sqrt(pooled[a]), math.sqrt(pooled[a] * lo), math.sqrt(pooled[a] * hi)),
            b,
            NoiseTerm.unbounded(),
            NoiseTerm.unbounded(),
        )
        for a in range(3)
    )
    provenance = (
        f"measured in {len(usable)} dwells of {source} (longest {longest:.0f} s): white noise from the sample variances; "
        f"slow noise {'detected' if slow.test.detected else 'not detected'} by the pooled Allan variance at 1/4 ... 1/32 of each dwell "
        f"(p = {slow.test.p_value:.3g}, false-positive rate {alpha:g}), expressed as bias instability; "
        "the random walk cannot be told from it in these dwells (not bounded)"
    )
    return NoiseModel(axes, NoiseSource.DEVICE_DWELLS, provenance, confidence, slow.test)  # type: ignore[arg-type]


def with_given_slow_noise(dwells: Sequence[DwellSummary], bias_instability: float, random_walk: float, provenance: str) -> NoiseModel:
    """Return a datasheet's bias instability and random walk (same on every axis) with the white noise measured in the dwells."""
    measured = noise_from_dwells(dwells)
    b, k = NoiseTerm.exact(bias_instability), NoiseTerm.exact(random_walk)
    axes = tuple(replace(a, bias_instability=b, random_walk=k) for a in measured.axes)
    return NoiseModel(axes, NoiseSource.DATASHEET, f"{provenance}; white noise measured in the dwells", measured.confidence)  # type: ignore[arg-type]


def floor_table(final: FitResult, floor: FitResult, noise: NoiseModel | None) -> list[str]:
    """Return the table of what the σ become with the largest floor the data allow (bias instability at its upper limit)."""
    b_up = float(np.max(noise.limits("bias_instability")[1])) if noise is not None else float("nan")
    lines = [
        "slow noise not detected: the σ above rest on white noise.  The dwells allow a bias instability up to "
        f"{b_up / MICRO_G:.3g} ug ({100 * (noise.confidence if noise else 0.95):g} % upper limit; random walk not bounded).  "
        "With that largest floor the σ would be:",
        f"{'parameter':<12} {'σ recorded':>18} {'σ largest floor':>18} {'ratio':>7}",
    ]
    for k in final.ids:
        v, s, st = final[k]
        if st != Status.ESTIMATED:
            continue
        s_floor = floor[k][1]
        term = final.terms[final.ids.index(k)]
        lines.append(
            f"{k:<12} {term.sigma_to_engineering(s):>11.4g} {term.unit:<6} {term.sigma_to_engineering(s_floor):>11.4g} {term.unit:<6} "
            f"{s_floor / s if s > 0 else float('nan'):>7.2f}"
        )
    return lines


def floor_ratio(final: FitResult, floor: FitResult) -> float:
    """Largest σ(largest floor)/σ(recorded) over the estimated parameters."""
    ratios = [floor[k][1] / final[k][1] for k in final.ids if final[k][2] == Status.ESTIMATED and final[k][1] > 0]
    return max(ratios, default=1.0)


@dataclass(frozen=True)
class _DeviceFit:
    """What every joint fit of one device session shares: site, gimbal senses, noise model, discovered terms."""

    site: SiteMetadata
    configuration: GimbalConfiguration
    noise: NoiseModel
    extra_terms: tuple[Term, ...]

    def fit_joint(
        self,
        coarse_dwells: Sequence[DwellSummary],
        fine_dwells: Sequence[DwellSummary] = (),
        *,
        start: FitResult | Mapping[str, float],
        nonlinear: bool = True,
        stage: Stage = Stage.COARSE,
        notes: Sequence[str] = (),
    ) -> FitResult:
        """Return :func:`stableins.estimators.joint.fit_joint` of these dwells with the session's settings."""
        return fit_joint(coarse_dwells, fine_dwells, setting=self.setting, start=start, nonlinear=nonlinear, stage=stage, notes=notes)

    @property
    def setting(self) -> DeviceSetting:
        """The plain values every fit of this session works in."""
        return DeviceSetting(self.site.gravity, self.site.base_attitude, self.configuration, self.noise, self.extra_terms)


def _stage_layouts(layouts: Mapping[str, StageLayout]) -> tuple[StageLayout, StageLayout]:
    """Return the coarse and fine layouts, checked to be present and of their stage."""
    missing = {"coarse", "fine"} - set(layouts)
    if missing:
        raise ValueError(f"layouts of the {' and '.join(sorted(missing))} stage missing: layouts maps 'coarse' and 'fine' to a StageLayout")
    for procedure, stage in ((layouts["coarse"], "coarse"), (layouts["fine"], "fine")):
        if procedure.stage != stage:
            raise InputError(
                f"procedure {procedure.name!r} is a {procedure.stage!r} procedure, given for the {stage} stage",
                path=procedure.source or None,
                field="procedure.stage",
                expected=repr(stage),
            )
    return layouts["coarse"], layouts["fine"]


def _coarse_passes(
    session: _DeviceFit, dwells: Sequence[DwellSummary], layout: StageLayout, *, allow_missing: bool, nonlinear: bool, source: str
) -> tuple[list[FitResult], dict[int, list[DwellSummary]]]:
    """Return the coarse fit of every pass on its own, and the dwells each pass used (by pass number)."""
    coarse_dwells = [d for d in dwells if d.stage == "coarse"]
    if not coarse_dwells:
        raise InputError("no coarse-stage dwells in the data", path=source, field="stage", expected="rows with stage 'coarse'")
    numbers = sorted({d.pass_number for d in coarse_dwells})
    passes = [
        calibrate_coarse(
            [d for d in coarse_dwells if d.pass_number == p],
            setting=session.setting,
            expected_positions=layout.positions,
            allow_missing=allow_missing,
            orientation_tolerance=layout.checks.orientation_tolerance,
            nonlinear=nonlinear,
            source=f"{source} (coarse pass {p})",
        )
        for p in numbers
    ]
    used = {
        p: [d for d in coarse_dwells if d.pass_number == p and d.position in fit.positions()]
        for p, fit in zip(numbers, passes, strict=True)
    }
    return passes, used


def _handedness_warning(layout: StageLayout, configuration: GimbalConfiguration) -> str | None:
    """Return the warning when the coarse sequence was designed for the other gimbal handedness, else None."""
    if layout.handedness == configuration.handedness:
        return None
    return (
        f"warning: procedure {layout.name!r} is designed for gimbal handedness {layout.handedness:+d}, "
        f"the unit's gimbal_senses {tuple(configuration.senses)} give {configuration.handedness:+d}: the sequence does not point "
        "every axis both up and down (docs/conventions.md), so scale factors, biases and K2 of some axes are poorly determined"
    )


def _fine_dwells(session: _DeviceFit, dwells: Sequence[DwellSummary], layout: StageLayout, source: str) -> list[DwellSummary]:
    """Return the fine-stage dwells, those pointing the wrong way flagged by the orientation check."""
    fine_dwells = [d for d in dwells if d.stage == "fine"]
    if not fine_dwells:
        return []
    usable = [d for d in fine_dwells if d.usable]
    base_dcm = dcm_nav_to_body(*session.site.base_attitude)
    tolerance = layout.checks.orientation_tolerance
    wrong = check_orientation(usable, session.site.gravity, base_dcm, session.configuration, tolerance=tolerance, source=f"{source} (fine)")
    return [replace(d, flags=d.flags + (wrong[d.position],)) if d.position in wrong else d for d in fine_dwells]


def _floor_note(noise: NoiseModel, b_up: NDArray[np.float64], ratio: float) -> str:
    """Return the note of a measured noise model without slow noise: what the largest floor would do to the σ."""
    test = noise.test
    assert test is not None  # a measured noise model carries its slow-noise test
    b, k = float(np.max(noise.values("bias_instability"))), float(np.max(noise.values("random_walk")))
    resting = (
        "the σ rest on white noise"
        if b == 0 and k == 0
        else f"the σ rest on the slow noise the residuals estimate (B = {b / MICRO_G:.2g} ug, K = {k:.2g} m/s^2/sqrt(s))"
    )
    text = (
        f"slow noise not detected in the dwells (p = {test.p_value:.2g} at false-positive rate {test.alpha:g}): "
        f"{resting}.  The dwells allow a bias instability up to {float(np.max(b_up)) / MICRO_G:.2g} ug; "
        f"with that largest floor the σ would be up to {ratio:.2f}× larger (report: 'largest floor'; the certificate's U "
        "includes it as the Type B input 'slow noise not resolved'), and the random walk "
        "is not bounded.  Measure the noise model on a static record ('stableins noise') or give it (--noise)"
    )
    return "warning: " + text if ratio > 1.1 else text


#: The input of the unresolved slow noise in a stage run's sensitivities (the certificate's budget column).
SLOW_NOISE_INPUT = "slow_noise.unresolved"


def slow_noise_sensitivity(final: FitResult, floor: FitResult) -> InputSensitivity | None:
    r"""Return the unresolved slow noise as an input of the stage: what the largest floor adds to its estimate's covariance.

    When the dwells do not resolve the slow noise, the stage's σ rest on white noise while the data allow a bias
    instability up to its upper limit.  Refitted with that largest floor the stage's estimate has covariance
    :math:`\Sigma_f`; the recorded one is :math:`\Sigma`.  The stage enters the record through
    :math:`\eta = \Lambda\hat x + g`, so the extra error of :math:`\hat x` reaches the record as
    :math:`P\,S\,P` with :math:`S = \Lambda(\Sigma_f - \Sigma)\Lambda` (docs/reports.md, "Uncertainty budget"),
    stored here as a set of inputs of unit variance.  For a data-only record :math:`P = \Lambda^{+}` and the
    combined variance is that of the largest floor: the upper limit, taken whole (the note's "up to … larger").

    Returns None when the stage has no likelihood or the floor adds nothing.
    """
    likelihood = final.likelihood
    if likelihood is None:
        return None
    ids = [i for i in likelihood.ids if i in final.ids and i in floor.ids and final[i][2] == Status.ESTIMATED]
    if not ids:
        return None
    a = [final.ids.index(i) for i in ids]
    b = [floor.ids.index(i) for i in ids]
    extra = np.asarray(floor.covariance)[np.ix_(b, b)] - np.asarray(final.covariance)[np.ix_(a, a)]
    extra = 0.5 * (extra + extra.T)
    values, vectors = np.linalg.eigh(extra)
    extra = (vectors * np.clip(values, 0.0, None)) @ vectors.T  # a larger floor never makes an estimate better
    if not np.any(extra):
        return None
    keep = [likelihood.ids.index(i) for i in ids]
    information = np.asarray(likelihood.information)
    n = len(likelihood.ids)
    covariance = np.zeros((n, n))
    lam = information[:, keep]
    covariance += lam @ extra @ lam.T
    return InputSensitivity(SLOW_NOISE_INPUT, "1", likelihood.ids, 0.0, covariance=0.5 * (covariance + covariance.T))


def _with_floor(fit: FitResult, floor: FitResult, note: str) -> FitResult:
    """Return ``fit`` with the floor's note and the unresolved slow noise among its sensitivities (:func:`slow_noise_sensitivity`)."""
    sensitivity = slow_noise_sensitivity(fit, floor)
    extra = (sensitivity,) if sensitivity is not None else ()
    return replace(fit, notes=fit.notes + (note,), sensitivities=tuple(fit.sensitivities) + extra)


def _with_note(fit: FitResult, note: str | None) -> FitResult:
    """Return ``fit`` with ``note`` appended to its notes (unchanged when None)."""
    return fit if note is None else replace(fit, notes=fit.notes + (note,))


def _dwells_and_site(given: Any, site: SiteMetadata | None, layouts: Mapping[str, StageLayout]) -> tuple[list[DwellSummary], SiteMetadata]:
    """Return the dwell summaries and the site of what :func:`calibrate_device` was given.

    What :func:`stableins.data.device.load_device` returns (one dataset or a list) is summarized as ``stableins
    calibrate device`` does (:func:`stableins.estimators.dwell.dwells_from_columns`), with the site of the first
    dataset unless one is given; dwell summaries are taken as they are.
    """
    from stableins.data.device import DeviceDataset

    items = [given] if isinstance(given, DeviceDataset) else list(given) if isinstance(given, Sequence) else None
    if items is None:
        raise TypeError(
            f"calibrate_device takes the datasets load_device returns or dwell summaries (dwells_from_columns), not a "
            f"{type(given).__name__}; discovery's DwellSet holds dwell means for the model search (stableins.discovery)"
        )
    if items and all(isinstance(d, DeviceDataset) for d in items):
        from stableins.estimators.dwell import dwells_from_columns

        summaries = [
            w
            for d in items
            for w in dwells_from_columns(
                d.columns, layouts=layouts, source=str(d.path or "data"), setting=DeviceSetting.from_site(d.metadata)
            )
        ]
        return summaries, site if site is not None else items[0].metadata
    summaries = [d for d in items if isinstance(d, DwellSummary)]
    if len(summaries) != len(items):
        raise TypeError("calibrate_device takes datasets (load_device) or dwell summaries (dwells_from_columns), not a mixture")
    if site is None:
        raise TypeError("calibrate_device needs the site (SiteMetadata) with dwell summaries; datasets carry their own")
    return summaries, site


@dataclass(frozen=True)
class _Stages:
    """The fits of one device session under one noise model."""

    session: _DeviceFit
    coarse: FitResult
    fine: FitResult | None
    passes: tuple[FitResult, ...]
    fused: FitResult | None
    used_coarse: list[DwellSummary]
    used_fine: list[DwellSummary]


def _run_stages(
    session: _DeviceFit,
    dwells: Sequence[DwellSummary],
    coarse_layout: StageLayout,
    fine_layout: StageLayout,
    *,
    allow_missing: bool,
    coarse_nonlinear: bool,
    extra_terms: Sequence[Term],
    source: str,
) -> _Stages:
    """Coarse passes, their joint fit, the fine stage and the fused fit of one session under ``session.noise``."""
    site, configuration, noise_model = session.site, session.configuration, session.noise
    passes, pass_dwells = _coarse_passes(
        session, dwells, coarse_layout, allow_missing=allow_missing, nonlinear=coarse_nonlinear, source=source
    )
    used_coarse = [d for p in sorted(pass_dwells) for d in sorted(pass_dwells[p], key=lambda d: d.position)]
    if len(passes) > 1:
        joint_note = f"joint fit of coarse passes {', '.join(map(str, sorted(pass_dwells)))} (each with its own readings)"
        coarse = session.fit_joint(used_coarse, start=passes[-1], nonlinear=coarse_nonlinear, notes=(joint_note,))
    else:
        coarse = passes[-1]
    mismatch = _handedness_warning(coarse_layout, configuration)
    coarse, passes[-1] = _with_note(coarse, mismatch), _with_note(passes[-1], mismatch)
    fine = fused = None
    used_fine: list[DwellSummary] = []
    fine_dwells = _fine_dwells(session, dwells, fine_layout, source)
    if fine_dwells:
        fine = calibrate_fine(
            fine_dwells,
            coarse,
            gravity=site.gravity,
            expected_positions=fine_layout.positions,
            allow_missing=allow_missing,
            noise=noise_model,
            model=fine_model(extra_terms),
            source=f"{source} (fine)",
        )
        fine = _with_note(fine, mismatch)
        used_fine = sorted((d for d in fine_dwells if d.position in fine.positions()), key=lambda d: d.position)
        start = coarse.as_dict() | {k: v for k, v, st in zip(fine.ids, fine.values, fine.status, strict=True) if st == Status.ESTIMATED}
        fused = session.fit_joint(
            used_coarse,
            used_fine,
            start=start,
            stage=Stage.DEVICE,
            notes=("coarse passes and fine stage fused by joint GLS (docs/device-calibration.md)",)
            + ((mismatch,) if mismatch is not None else ()),
        )
    return _Stages(session, coarse, fine, tuple(passes), fused, used_coarse, used_fine)


def calibrate_device(
    dwells: Sequence[DwellSummary] | Any,
    site: SiteMetadata | None = None,
    *,
    layouts: Mapping[str, StageLayout],
    allow_missing: bool = False,
    noise: NoiseModel | None = None,
    coarse_nonlinear: bool = True,
    extra_terms: Sequence[Term] = (),
    source: str = "data",
) -> DeviceCalibration:
    """Run the coarse stage on every coarse pass, then the fine stage if fine dwells are present.

    ``dwells`` are dwell summaries (:func:`stableins.estimators.dwell.dwells_from_columns`) or what
    :func:`stableins.data.device.load_device` returns (one dataset or a list of them, summarized here; ``site``
    then defaults to the first dataset's).

    ``layouts`` are the positions of the two stages (``{"coarse": ..., "fine": ...}``, e.g. from
    :func:`stableins.procedures.definition.device_layouts`): which positions a pass must hold, the
    orientation tolerance of their dwells, the gimbal handedness the sequence was designed for.

    ``noise`` is the instrument's noise model (a calibration record's ``noise_model``, measured
    by ``stableins noise`` on a static record, or a datasheet).  Without it the dwells'
    own (:func:`noise_from_dwells`): the bias instability they measure, with the decision at
    the false-positive rate :data:`stableins.estimators.slow_noise.SLOW_NOISE_ALPHA`; when slow noise is not detected the result says so and
    :attr:`DeviceCalibration.floor` shows the σ with the largest floor the dwells allow.

    ``coarse_nonlinear`` (default True) also estimates ``K2_*`` in the coarse stage.  The
    paper's 15-parameter coarse stage (``False``) ignores them, which for nominal
    ``K2 = 20 µg/g²`` biases the coarse biases by about 3σ and θ30 by about 1σ
    (benchmarks/bench_device_montecarlo.py); the fine stage re-estimates the biases either way.

    ``extra_terms`` are additive terms (discovered effects, :func:`stableins.discovery.library.calibration_terms`)
    estimated jointly with the standard parameters in every stage that determines them; a stage
    that does not holds them (status ``unidentifiable``) at the value of the stage before.
    """
    dwells, site = _dwells_and_site(dwells, site, layouts)
    coarse_layout, fine_layout = _stage_layouts(layouts)
    configuration = GimbalConfiguration((*site.gimbal_senses,))
    measured = noise is None or noise.source is NoiseSource.NONE
    noise_model = noise_from_dwells(dwells, source=source) if noise is None or measured else noise

    def stages(model: NoiseModel) -> _Stages:
        return _run_stages(
            _DeviceFit(site, configuration, model, tuple(extra_terms)),
            dwells,
            coarse_layout,
            fine_layout,
            allow_missing=allow_missing,
            coarse_nonlinear=coarse_nonlinear,
            extra_terms=extra_terms,
            source=source,
        )

    run = stages(noise_model)
    if measured and noise_model.test is not None:
        # the default path: slow noise from the residual scatter between passes at each position and the Allan variance
        # inside the dwells (REML, stableins.estimators.residual_noise); the σ use it, detected or not
        within = dwell_slow_noise(dwells)
        residual = residual_slow_noise(
            run.used_coarse,
            run.used_fine,
            setting=run.session.setting,
            fit=run.fused or run.coarse,
            allan=(within.b2, within.b2_sigma, within.test.p_value),
        )
        noise_model, run = _measured_slow_noise(noise_model, residual, source, stages)
    rejected_note = None
    if not measured and noise_model.source is not NoiseSource.NONE:
        # a given model (datasheet, another record's) the residuals reject is said, and the σ follow the data
        final = run.fused or run.coarse
        within = dwell_slow_noise(dwells)
        evidence = (within.b2, within.b2_sigma, within.test.p_value)
        check = given_noise_test(run.used_coarse, run.used_fine, setting=run.session.setting, fit=final, model=noise_model, allan=evidence)
        if check.rejected:
            residual = residual_slow_noise(
                run.used_coarse,
                run.used_fine,
                setting=run.session.setting,
                fit=run.fused or run.coarse,
                allan=(within.b2, within.b2_sigma, within.test.p_value),
            )
            given_text = noise_model.describe()
            white = noise_from_dwells(dwells, source=source)
            noise_model, run = _measured_slow_noise(white, residual, source, stages)
            rejected_note = (
                f"warning: the given noise model ({given_text}) is rejected by the dwells (residuals between passes and "
                f"Allan variance inside the dwells: likelihood ratio {check.statistic:.3g}, p = {check.p_value:.2g} < {check.alpha:g}): "
                "the σ use the noise model the data "
                f"measure instead (B = {residual.bias_instability / MICRO_G:.3g} ug, K = {residual.random_walk:.3g} m/s^2/sqrt(s))"
            )
    session, coarse, fine, passes, fused = run.session, run.coarse, run.fine, list(run.passes), run.fused
    used_coarse, used_fine = run.used_coarse, run.used_fine
    floor = None
    if measured and noise_model.test is not None and not noise_model.test.detected:
        b_up = noise_model.limits("bias_instability")[1]
        if np.all(np.isfinite(b_up)) and np.any(b_up > 0):
            largest = replace(session, noise=noise_model.with_values(bias_instability=b_up))
            if fused is not None:
                floor = largest.fit_joint(used_coarse, used_fine, start=fused, stage=Stage.DEVICE)
                fused = _with_floor(fused, floor, _floor_note(noise_model, b_up, floor_ratio(fused, floor)))
            else:
                floor = largest.fit_joint(used_coarse, start=coarse, nonlinear=coarse_nonlinear)
                coarse = _with_floor(coarse, floor, _floor_note(noise_model, b_up, floor_ratio(coarse, floor)))
    if rejected_note is not None:
        if fused is not None:
            fused = _with_note(fused, rejected_note)
        else:
            coarse = _with_note(coarse, rejected_note)
    settings = DeviceSessionSettings(
        coarse_procedure=coarse_layout.name,
        fine_procedure=fine_layout.name,
        allow_missing=bool(allow_missing),
        coarse_nonlinear=bool(coarse_nonlinear),
        noise_model=noise_model,
        effects=tuple(t.id for t in extra_terms),  # discovered terms estimated with the standard ones
    )
    return DeviceCalibration(coarse, fine, tuple(passes), fused, settings, noise_model, floor)
