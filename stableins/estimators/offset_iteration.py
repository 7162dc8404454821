r"""Zero-offset iteration: re-command the gimbals by the estimated offsets and measure again.

Wu et al. 2018 Section 3: after a coarse pass, the inner and middle gimbals are
re-commanded by ``−θ̂20`` and ``−θ̂30`` and the coarse calibration is repeated until
the re-estimated offsets are negligible.  With the exact kinematics of
:mod:`stableins.estimators.coarse` (which uses the *measured* readings), every pass
estimates the sensor offsets ``θ_i0`` themselves; what shrinks from pass to pass is
the pointing error of the re-commanded positions,

.. math:: \hat\delta^{(k)} = \hat\theta^{(k)} - \hat\theta^{(k-1)},

the offset re-estimated relative to the commands of pass ``k`` (this is the paper's
"re-estimated θ̂20, θ̂30").  Its 1σ is that of ``θ̂^{(k)}``.  The loop stops when
``|δ̂| ≤ max(threshold, noise_sigmas · σ)`` for both gimbals: a threshold below the
noise of one pass (≈ 1″ for 20 s dwells) cannot be reached and is replaced by a
``noise_sigmas`` test, reported as such.  ``noise_sigmas = 0`` enforces the threshold
alone.  After ``max_passes`` passes without convergence a
:class:`OffsetIterationError` carries the whole pass history.

``θ10`` is the gauge of the coarse problem (held at 0) and is not re-commanded.
All acquisition goes through :class:`stableins.drivers.base.PlatformDriver`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from stableins.conventions import ARCSEC, GimbalConfiguration
from stableins.drivers.base import PlatformDriver, SampleBlock
from stableins.errormodel import Term
from stableins.estimators.coarse import calibrate_coarse
from stableins.estimators.dwell import DwellSummary, summarize_dwell
from stableins.estimators.joint import fit_joint
from stableins.estimators.result import FitResult
from stableins.procedures.definition import ProcedureDefinition


@dataclass(frozen=True)
class PassRecord:
    """One pass: offsets used in the commands, re-estimated offsets, residual and its 1σ [rad]."""

    pass_number: int
    commanded_offsets: tuple[float, float]
    estimated_offsets: tuple[float, float]
    residual: tuple[float, float]
    sigma: tuple[float, float]
    limit: tuple[float, float]
    chi2_red: float

    @property
    def converged(self) -> bool:
        return all(abs(r) <= lim for r, lim in zip(self.residual, self.limit, strict=True))

    def describe(self) -> str:
        r = ", ".join(f"{x / ARCSEC:+.3f}" for x in self.residual)
        s = ", ".join(f"{x / ARCSEC:.3f}" for x in self.sigma)
        e = ", ".join(f"{x / ARCSEC:+.3f}" for x in self.estimated_offsets)
        lim = ", ".join(f"{x / ARCSEC:.3f}" for x in self.limit)
        verdict = "converged" if self.converged else "not converged"
        return (
            f"pass {self.pass_number}: theta20, theta30 = ({e})″, re-estimated residual ({r})″ ± ({s})″, "
            f"limit ({lim})″ = max(threshold, noise_sigmas·σ): {verdict}, chi2_red {self.chi2_red:.2f}"
        )


class OffsetIterationError(RuntimeError):
    """The offsets did not converge within the allowed passes (``history`` has every pass)."""

    def __init__(self, message: str, history: list[PassRecord]):
        self.history = history
        super().__init__(message + "\n" + "\n".join(p.describe() for p in history))


@dataclass(frozen=True)
class OffsetIterationResult:
    """Converged iteration.

    Attributes
    ----------
    fit : FitResult
        Joint fit of *all* passes (:func:`stableins.estimators.joint.fit_joint`): the passes
        are independent measurements of the same parameters at different commanded
        readings, so their combination has about ``1/√k`` the 1σ of one pass.
    offsets : (θ10, θ20, θ30)
        Offsets to re-point with (the last pass's estimate, used for the commands).
    history : tuple of PassRecord
    dwells : tuple of DwellSummary
        Every dwell of every pass.
    last : FitResult or None
        The last pass on its own (what the stopping test used).
    """

    fit: FitResult
    offsets: tuple[float, float, float]
    history: tuple[PassRecord, ...]
    dwells: tuple[DwellSummary, ...] = field(repr=False)
    last: FitResult | None = field(default=None, repr=False)

    def describe(self) -> str:
        return "\n".join(p.describe() for p in self.history)


class PassObserver(Protocol):
    """Sees every position of a pass as it is measured (the runner's console: one line per dwell, settle and dwell
    progress, the dwell's verdict).  Observing changes nothing: the operations and the estimates are the same."""

    def position(self, pass_number: int, step: Any, command: tuple[float, float, float]) -> None:
        """The position ``step`` of pass ``pass_number`` is about to be commanded to the readings ``command`` [rad]."""

    def phase(self, name: str, done: float, total: float) -> None:
        """``done`` of ``total`` seconds of the phase ``name`` (``"settle"`` or ``"dwell"``) recorded (0 before it starts)."""

    def measured(self, block: SampleBlock, summary: DwellSummary) -> None:
        """The dwell's samples and their summary, with the acceptance flags of the procedure's ``[acceptance]`` checks."""


def repointed_command(nominal: tuple[float, float, float], offsets: NDArray[np.float64] | tuple[float, ...]) -> tuple[float, float, float]:
    """Readings that put the gimbals at their nominal angles: ``r = r_nominal − θ̂`` (θ10 not re-commanded)."""
    return (float(nominal[0]), float(nominal[1] - offsets[1]), float(nominal[2] - offsets[2]))


def wait_until_arrived(
    driver: PlatformDriver, command: tuple[float, float, float], tolerance: float, timeout: float = 300.0, poll: float = 0.5
) -> float:
    """Let time pass (``acquire(poll)``, discarded) until the readings are within ``tolerance`` of ``command``.

    Returns the time waited [s]; raises ``RuntimeError`` after ``timeout`` seconds.
    """
    waited = 0.0
    target = np.asarray(command, dtype=float)
    while np.max(np.abs(np.asarray(driver.read_angles(), dtype=float) - target)) > tolerance:
        if waited >= timeout:
            raise RuntimeError(
                f"the platform did not reach the commanded readings {np.degrees(target).round(4).tolist()} deg within {timeout:g} s "
                f"(driver status {driver.status()})"
            )
        driver.acquire(poll)
        waited += poll
    return waited


def measure_pass(
    driver: PlatformDriver,
    procedure: ProcedureDefinition,
    offsets: tuple[float, float, float],
    *,
    stage: str = "coarse",
    pass_number: int = 1,
    observer: PassObserver | None = None,
) -> list[DwellSummary]:
    """Command every step (re-pointed by ``offsets``), wait for the slew, settle, dwell and summarize.

    ``observer`` (optional) is told of every position, the settle and dwell phases and every dwell's summary.
    """
    checks = procedure.acceptance.dwell_checks()
    dwells = []
    for step in procedure.steps:
        command = repointed_command(step.command, offsets) if procedure.repoint else step.command
        if observer is not None:
            observer.position(pass_number, step, tuple(float(c) for c in command))  # type: ignore[arg-type]
        driver.command(command)
        wait_until_arrived(driver, command, procedure.acceptance.max_angle_span)
        if step.settle > 0:
            if observer is not None:
                observer.phase("settle", 0.0, step.settle)
            driver.acquire(step.settle)
            if observer is not None:
                observer.phase("settle", step.settle, step.settle)
        if observer is not None:
            observer.phase("dwell", 0.0, step.dwell)
        block = driver.acquire(step.dwell)
        if observer is not None:
            observer.phase("dwell", step.dwell, step.dwell)
        summary = summarize_dwell(
            block.time,
            block.specific_force,
            block.angles,
            command,
            position=step.position,
            stage=stage,
            pass_number=pass_number,
            checks=checks,
        )
        if observer is not None:
            observer.measured(block, summary)
        dwells.append(summary)
    return dwells


def iterate_offsets(
    driver: PlatformDriver,
    procedure: ProcedureDefinition,
    *,
    threshold: float | None = None,
    max_passes: int | None = None,
    noise_sigmas: float | None = None,
    initial_offsets: tuple[float, float, float] = (0.0, 0.0, 0.0),
    nonlinear: bool = True,
    progress: Callable[[PassRecord], None] | None = None,
    extra_terms: Sequence[Term] = (),
    observer: PassObserver | None = None,
) -> OffsetIterationResult:
    """Run coarse passes through ``driver`` until the re-estimated offsets are negligible.

    Parameters
    ----------
    driver : PlatformDriver
        The platform (simulated now, real later); its metadata give gravity, base
        attitude and gimbal senses.
    procedure : ProcedureDefinition
        The coarse procedure (``procedures/device-coarse.toml``).
    threshold, max_passes, noise_sigmas : optional
        Override the procedure's ``[offset_iteration]`` table (threshold in rad).
    initial_offsets : (θ10, θ20, θ30)
        Offsets already known (e.g. from the last record) [rad].
    nonlinear : bool
        Estimate ``K2_*`` in each coarse pass (default); ``False`` is the paper's
        15-parameter stage, whose offsets absorb part of the quadratic terms.
    extra_terms : sequence of Term
        Discovered (additive) terms of the unit's model, estimated in every pass and in the
        joint fit (a hidden cross-coupling would otherwise bias the offsets the passes re-point by).
    observer : PassObserver, optional
        Told of every position, settle and dwell of every pass (:func:`measure_pass`).
    """
    cfg = procedure.offset_iteration
    threshold = cfg.threshold if threshold is None else threshold
    max_passes = cfg.max_passes if max_passes is None else max_passes
    noise_sigmas = cfg.noise_sigmas if noise_sigmas is None else noise_sigmas
    site = driver.metadata
    configuration = GimbalConfiguration(tuple(site.gimbal_senses))
    offsets = np.array(initial_offsets, dtype=float)
    history: list[PassRecord] = []
    all_dwells: list[DwellSummary] = []
    used: list[DwellSummary] = []
    for k in range(1, max_passes + 1):
        dwells = measure_pass(driver, procedure, tuple(offsets), pass_number=k, observer=observer)
        all_dwells += dwells
        fit = calibrate_coarse(
            dwells,
            gravity=site.gravity,
            base_attitude=site.base_attitude,
            configuration=configuration,
            expected_positions=procedure.positions,
            orientation_tolerance=procedure.acceptance.orientation_tolerance,
            nonlinear=nonlinear,
            extra_terms=extra_terms,
            source=f"coarse pass {k}",
        )
        used += sorted((d for d in dwells if d.position in fit.positions()), key=lambda d: d.position)
        estimate = np.array([fit["theta10"][0], fit["theta20"][0], fit["theta30"][0]])
        sigma = np.array([fit["theta20"][1], fit["theta30"][1]])
        residual = estimate[1:] - offsets[1:]
        limit = np.maximum(threshold, noise_sigmas * sigma)
        record = PassRecord(
            k,
            (float(offsets[1]), float(offsets[2])),
            (float(estimate[1]), float(estimate[2])),
            (float(residual[0]), float(residual[1])),
            (float(sigma[0]), float(sigma[1])),
            (float(limit[0]), float(limit[1])),
            fit.chi2_red,
        )
        history.append(record)
        if progress is not None:
            progress(record)
        offsets = np.array([offsets[0], estimate[1], estimate[2]])
        if record.converged:
            joint = fit
            if k > 1:
                joint = fit_joint(
                    used,
                    gravity=site.gravity,
                    base_attitude=site.base_attitude,
                    configuration=configuration,
                    start=fit,
                    nonlinear=nonlinear,
                    notes=(f"joint fit of coarse passes 1..{k} (each with its own commanded readings)",),
                    extra_terms=extra_terms,
                )
            offsets_out = (float(offsets[0]), float(offsets[1]), float(offsets[2]))
            return OffsetIterationResult(joint, offsets_out, tuple(history), tuple(all_dwells), fit)
    raise OffsetIterationError(
        f"zero offsets did not converge within {max_passes} passes "
        f"(threshold {threshold / ARCSEC:.3g}″, or {noise_sigmas:g} σ of one pass)",
        history,
    )
