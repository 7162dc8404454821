r"""Zero-offset iteration, the execution: command the platform pass by pass until the offsets converge.

Wu et al. 2018 Section 3: after a coarse pass, the inner and middle gimbals are re-commanded by
``−θ̂20`` and ``−θ̂30`` and the coarse calibration is repeated until the re-estimated offsets are
negligible.  This module drives the platform (:class:`stableins.drivers.base.PlatformDriver`): per
position it commands, waits for arrival, settles, records the dwell and summarizes it; the estimate of
each pass and the stopping test are :class:`stableins.estimators.offset_iteration.OffsetEstimator`
(plain values in).  After ``max_passes`` passes without convergence an :class:`OffsetIterationError`
carries the whole pass history.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, Protocol

import numpy as np

from stableins.conventions import ARCSEC
from stableins.drivers.base import PlatformDriver
from stableins.errormodel import Term
from stableins.estimators.dwell import DwellSummary, summarize_dwell
from stableins.estimators.offset_iteration import OffsetEstimator, OffsetIterationResult, PassRecord, repointed_command
from stableins.estimators.setting import DeviceSetting
from stableins.procedures.definition import OffsetIteration, ProcedureDefinition
from stableins.samples import SampleBlock


class OffsetIterationError(RuntimeError):
    """The offsets did not converge within the allowed passes (``history`` has every pass)."""

    def __init__(self, message: str, history: list[PassRecord]):
        self.history = history
        super().__init__(message + "\n" + "\n".join(p.describe() for p in history))


class PassObserver(Protocol):
    """Sees every position of a pass as it is measured.

    The runner's console shows one line per dwell, settle and dwell progress, the dwell's verdict.  Observing changes
    nothing: the operations and the estimates are the same.
    """

    def position(self, pass_number: int, step: Any, command: tuple[float, float, float]) -> None:
        """Announce that position ``step`` of pass ``pass_number`` is about to be commanded to the readings ``command`` [rad]."""

    def phase(self, name: str, done: float, total: float) -> None:
        """``done`` of ``total`` seconds of the phase ``name`` (``"settle"`` or ``"dwell"``) recorded (0 before it starts)."""

    def measured(self, block: SampleBlock, summary: DwellSummary) -> None:
        """Receive the dwell's samples and their summary, with the flags of the procedure's dwell checks."""


def wait_until_arrived(
    driver: PlatformDriver, command: tuple[float, float, float], tolerance: float, timeout: float = 300.0, poll: float = 0.5
) -> float:
    """Let time pass (``acquire(poll)``, discarded) until the readings are within ``tolerance`` of ``command``.

    ``poll`` is at least one sample period of the platform: a shorter acquisition records no sample and lets no time
    pass (at 1 Hz a 0.5-s poll never advanced the session).  Returns the time waited [s]; raises ``RuntimeError`` after
    ``timeout`` seconds.
    """
    poll = max(poll, 1.0 / driver.metadata.sample_rate)
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
    checks = procedure.checks
    setting = DeviceSetting.from_site(driver.metadata)
    dwells = []
    for step in procedure.steps:
        command = repointed_command(step.command, offsets) if procedure.repoint else step.command
        if observer is not None:
            observer.position(pass_number, step, tuple(float(c) for c in command))  # type: ignore[arg-type]
        driver.command(command)
        wait_until_arrived(driver, command, checks.angle_tolerance)
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
            setting=setting,
        )
        if observer is not None:
            observer.measured(block, summary)
        dwells.append(summary)
    return dwells


def iterate_offsets(
    driver: PlatformDriver,
    procedure: ProcedureDefinition,
    *,
    stopping: OffsetIteration | None = None,
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
    stopping : OffsetIteration, optional
        Replaces the procedure's ``[offset_iteration]`` table (threshold in rad).
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
    cfg = procedure.offset_iteration if stopping is None else stopping
    threshold, max_passes, noise_sigmas = cfg.threshold, cfg.max_passes, cfg.noise_sigmas
    site = driver.metadata
    estimator = OffsetEstimator(
        setting=DeviceSetting.from_site(site, extra_terms=tuple(extra_terms)),
        positions=procedure.positions,
        orientation_tolerance=procedure.checks.orientation_tolerance,
        threshold=threshold,
        noise_sigmas=noise_sigmas,
        initial_offsets=initial_offsets,
        nonlinear=nonlinear,
    )
    for k in range(1, max_passes + 1):
        offsets = tuple(float(o) for o in estimator.offsets)
        record = estimator.add_pass(measure_pass(driver, procedure, offsets, pass_number=k, observer=observer))  # type: ignore[arg-type]
        if progress is not None:
            progress(record)
        if record.converged:
            return estimator.result()
    raise OffsetIterationError(
        f"zero offsets did not converge within {max_passes} passes "
        f"(threshold {threshold / ARCSEC:.3g}″, or {noise_sigmas:g} σ of one pass)",
        estimator.history,
    )
