"""The device-level pipeline: dwell summaries → coarse passes → fine stage.

Takes the dwell summaries of a device-level session, runs the coarse stage on every
coarse pass (zero-offset history, screening), fits all passes jointly (the coarse
result), runs the fine stage when fine dwells are present, and fuses coarse and fine
by a joint generalized least squares (:mod:`stableins.estimators.joint`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np

from stableins.conventions import ARCSEC, GimbalConfiguration, dcm_nav_to_body
from stableins.data.errors import InputError
from stableins.data.metadata import SiteMetadata
from stableins.errormodel import Term
from stableins.estimators.coarse import calibrate_coarse, check_orientation
from stableins.estimators.design import describe_design
from stableins.estimators.dwell import DwellSummary, pooled_allan_excess
from stableins.estimators.fine import calibrate_fine
from stableins.estimators.joint import fit_joint
from stableins.estimators.noise_model import SlowNoise, slow_noise_from_allan_excess
from stableins.estimators.result import FitResult
from stableins.procedures.definition import ProcedureDefinition, load_procedure

if TYPE_CHECKING:  # pragma: no cover
    from stableins.records import CalibrationRecord, Entry


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
    """

    coarse: FitResult
    fine: FitResult | None = None
    passes: tuple[FitResult, ...] = field(default=(), repr=False)
    fused: FitResult | None = None
    #: The options the pipeline ran with (procedures, slow noise, coarse nonlinearity, missing positions): stored in
    #: the record's stage run so that a report recomputes exactly what the calibration did.
    settings: dict = field(default_factory=dict)

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
        lines = [f"<DeviceCalibration: stage {self.final.stage!r} recorded, {len(self.final.terms)} parameters>", "; ".join(fits)]
        lines += parameter_lines(self.final.rows())
        return clipped(
            lines, "(print(calibration) for every stage, calibration.final for the recorded fit, calibration.record(site) for the record)"
        )

    def _repr_html_(self) -> str:
        return self.final._repr_html_()

    def record(
        self,
        site: SiteMetadata,
        inputs: Sequence[str] = (),
        procedure: str = "",
        *,
        data_start: str = "",
        data_end: str = "",
        environment: dict | None = None,
        entries: Sequence[Entry] = (),
    ) -> CalibrationRecord:
        """Calibration record of :attr:`final` (coarse and fine fused by joint GLS, not replaced).

        The record's stage run (``coarse+fine``, or ``coarse``) keeps the evidence of every fit (coarse, fine alone,
        fused, each with its χ²_ν), the fused likelihood and :attr:`settings`; ``entries`` are the calibration's fields.
        """
        from stableins.records import Calibration, CalibrationRecord, StageRun

        calibration = Calibration.new(procedure, entries)
        fits = [self.coarse] + [f for f in (self.fine, self.fused) if f is not None]
        stage = StageRun.from_fit(
            self.final,
            calibration=calibration.id,
            procedure=procedure,
            inputs=inputs,
            data_start=data_start,
            data_end=data_end,
            sample_rate=site.sample_rate,
            environment=environment,
            fits=fits,
            settings=self.settings or self.final.settings,
        )
        return CalibrationRecord.from_fit_result(self.final, site=site, stage=stage, calibration=calibration)


def estimate_slow_noise(dwells: Sequence[DwellSummary], significance: float = 2.0) -> SlowNoise:
    """Bias instability from the pooled Allan excess of the longest dwells (weak; see dwell.pooled_allan_excess)."""
    longest = max((d.duration for d in dwells if d.usable), default=0.0)
    chosen = [d for d in dwells if d.usable and d.duration >= 0.5 * longest]
    mean, stderr, count = pooled_allan_excess(chosen)
    if count >= 3 and np.any(mean > significance * stderr):
        return slow_noise_from_allan_excess(mean, source=f"estimated from the pooled Allan excess of {count} dwells (weak estimate)")
    bound = np.sqrt(np.max(np.clip(mean, 0.0, None) + significance * stderr)) / 0.664 if count >= 3 else float("inf")
    return SlowNoise(
        0.0,
        0.0,
        source=f"none given, none detected in the dwells (bias instability below about {bound / 9.80665e-6:.2g} ug)",
        undetected_bound=float(bound),
    )


def hidden_slow_noise_warning(slow_noise: SlowNoise, dwells: Sequence[DwellSummary]) -> str | None:
    """A warning when undetected bias instability could be comparable to the white noise of the dwell means.

    The pooled Allan excess of 10 min dwells cannot see a bias instability of a few µg, which
    is already comparable to the white noise of such a dwell mean; the fine-stage 1σ are then
    too small (on the simulator's quartz instrument, B = 2 µg, its NEES is about twice χ²).
    Warn when the largest hidden Allan floor ``0.664 B`` exceeds half the median white 1σ.
    """
    if slow_noise.undetected_bound <= 0.0:
        return None
    sems = [float(np.median(d.sem)) for d in dwells if d.usable]
    if not sems:
        return None
    white = float(np.median(sems))
    hidden = 0.664 * slow_noise.undetected_bound
    if hidden <= 0.5 * white:
        return None
    ug = 9.80665e-6
    return (
        f"warning: no bias instability given and none detectable in these dwells, but an Allan floor up to about {hidden / ug:.2g} ug "
        f"could hide in them, against {white / ug:.2g} ug white noise of a dwell mean: the {dwells[0].stage}-stage 1σ may be too small. "
        "Give the instrument's value (--bias-instability, --random-walk)"
    )


def calibrate_device(
    dwells: Sequence[DwellSummary],
    site: SiteMetadata,
    *,
    coarse_procedure: ProcedureDefinition | None = None,
    fine_procedure: ProcedureDefinition | None = None,
    allow_missing: bool = False,
    slow_noise: SlowNoise | None = None,
    coarse_nonlinear: bool = True,
    extra_terms: Sequence[Term] = (),
    source: str = "data",
) -> DeviceCalibration:
    """Coarse stage on every coarse pass, then the fine stage if fine dwells are present.

    ``slow_noise`` is the instrument's bias instability / random walk (datasheet or a long
    static record).  Without it, the pooled Allan excess of the fine dwells is used when it
    is significant (2 standard errors); otherwise the stages use white noise only and say so.

    ``coarse_nonlinear`` (default True) also estimates ``K2_*`` in the coarse stage.  The
    paper's 15-parameter coarse stage (``False``) ignores them, which for nominal
    ``K2 = 20 µg/g²`` biases the coarse biases by about 3σ and θ30 by about 1σ
    (benchmarks/bench_device_montecarlo.py); the fine stage re-estimates the biases either way.

    ``extra_terms`` are additive terms (discovered effects, :func:`stableins.discovery.library.calibration_terms`)
    estimated jointly with the standard parameters in every stage that determines them; a stage
    that does not holds them (status ``unidentifiable``) at the value of the stage before.
    """
    coarse_procedure = coarse_procedure or load_procedure("device-coarse")
    fine_procedure = fine_procedure or load_procedure("device-fine")
    for procedure, stage in ((coarse_procedure, "coarse"), (fine_procedure, "fine")):
        if procedure.stage != stage:
            raise InputError(
                f"procedure {procedure.name!r} is a {procedure.stage!r} procedure, given for the {stage} stage",
                path=procedure.path or None,
                field="procedure.stage",
                expected=repr(stage),
            )
    configuration = GimbalConfiguration(tuple(site.gimbal_senses))
    if slow_noise is None:
        slow_noise = estimate_slow_noise(dwells)
    coarse_dwells = [d for d in dwells if d.stage == "coarse"]
    if not coarse_dwells:
        raise InputError("no coarse-stage dwells in the data", path=source, field="stage", expected="rows with stage 'coarse'")
    passes = []
    for p in sorted({d.pass_number for d in coarse_dwells}):
        passes.append(
            calibrate_coarse(
                [d for d in coarse_dwells if d.pass_number == p],
                gravity=site.gravity,
                base_attitude=site.base_attitude,
                configuration=configuration,
                expected_positions=coarse_procedure.positions,
                allow_missing=allow_missing,
                orientation_tolerance=coarse_procedure.acceptance.orientation_tolerance,
                slow_noise=slow_noise,
                nonlinear=coarse_nonlinear,
                extra_terms=extra_terms,
                source=f"{source} (coarse pass {p})",
            )
        )
    pass_dwells = {
        p: [d for d in coarse_dwells if d.pass_number == p and d.position in fit.extra["positions_used"]]
        for p, fit in zip(sorted({d.pass_number for d in coarse_dwells}), passes, strict=True)
    }
    used_coarse = [d for p in sorted(pass_dwells) for d in sorted(pass_dwells[p], key=lambda d: d.position)]
    joint = dict(
        gravity=site.gravity, base_attitude=site.base_attitude, configuration=configuration, slow_noise=slow_noise, extra_terms=extra_terms
    )
    if len(passes) > 1:
        coarse = fit_joint(
            used_coarse,
            start=passes[-1],
            nonlinear=coarse_nonlinear,
            notes=(f"joint fit of coarse passes {', '.join(map(str, sorted(pass_dwells)))} (each with its own readings)",),
            **joint,
        )
    else:
        coarse = passes[-1]
    mismatch = None
    if coarse_procedure.handedness != configuration.handedness:
        mismatch = (
            f"warning: procedure {coarse_procedure.name!r} is designed for gimbal handedness {coarse_procedure.handedness:+d}, "
            f"the unit's gimbal_senses {tuple(configuration.senses)} give {configuration.handedness:+d}: the sequence does not point "
            "every axis both up and down (docs/conventions.md), so scale factors, biases and K2 of some axes are poorly determined"
        )
        coarse = replace(coarse, notes=coarse.notes + (mismatch,))
        passes[-1] = replace(passes[-1], notes=passes[-1].notes + (mismatch,))
    fine_dwells = [d for d in dwells if d.stage == "fine"]
    fine = fused = None
    if fine_dwells:
        usable = [d for d in fine_dwells if d.usable]
        tolerance = fine_procedure.acceptance.orientation_tolerance
        wrong = check_orientation(usable, site.gravity, dcm_nav_to_body(*site.base_attitude), configuration, tolerance, f"{source} (fine)")
        fine_dwells = [replace(d, flags=d.flags + (wrong[d.position],)) if d.position in wrong else d for d in fine_dwells]
        fine = calibrate_fine(
            fine_dwells,
            coarse,
            gravity=site.gravity,
            expected_positions=fine_procedure.positions,
            allow_missing=allow_missing,
            slow_noise=slow_noise,
            extra_terms=extra_terms,
            source=f"{source} (fine)",
        )
        warning = hidden_slow_noise_warning(slow_noise, [d for d in fine_dwells if d.usable])
        if warning is not None:
            fine = replace(fine, notes=fine.notes + (warning,))
        if mismatch is not None:
            fine = replace(fine, notes=fine.notes + (mismatch,))
        used_fine = sorted((d for d in fine_dwells if d.position in fine.extra["positions_used"]), key=lambda d: d.position)
        start = coarse.as_dict() | {k: v for k, v, st in zip(fine.ids, fine.values, fine.status, strict=True) if st == "estimated"}
        fused = fit_joint(
            used_coarse,
            used_fine,
            start=start,
            stage="coarse+fine",
            notes=("coarse passes and fine stage fused by joint GLS (docs/device-calibration.md)",)
            + ((mismatch,) if mismatch is not None else ())
            + ((warning,) if warning is not None else ()),
            **joint,
        )
    settings = {
        "coarse_procedure": coarse_procedure.name,
        "fine_procedure": fine_procedure.name,
        "allow_missing": bool(allow_missing),
        "coarse_nonlinear": bool(coarse_nonlinear),
        "slow_noise": slow_noise.settings(),
        "effects": [t.id for t in extra_terms],  # discovered terms estimated with the standard ones
    }
    return DeviceCalibration(coarse, fine, tuple(passes), fused, settings)
