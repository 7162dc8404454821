r"""Zero-offset iteration, the estimate: the offsets of every pass and when they have converged.

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
This module estimates from the dwells of each pass (:class:`OffsetEstimator`, plain values in,
no platform); the loop that commands the platform pass by pass is an execution concern,
:func:`stableins.procedures.iteration.iterate_offsets`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from stableins.conventions import ARCSEC, GimbalConfiguration
from stableins.errormodel import Term
from stableins.estimators.coarse import calibrate_coarse
from stableins.estimators.dwell import DwellSummary
from stableins.estimators.joint import fit_joint
from stableins.estimators.result import FitResult


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
        """Whether every residual offset is within its limit."""
        return all(abs(r) <= lim for r, lim in zip(self.residual, self.limit, strict=True))

    def describe(self) -> str:
        """Return the pass in words: residual offsets ± 1σ, the offsets estimated, the limits [arcsec]."""
        r = ", ".join(f"{x / ARCSEC:+.3f}" for x in self.residual)
        s = ", ".join(f"{x / ARCSEC:.3f}" for x in self.sigma)
        e = ", ".join(f"{x / ARCSEC:+.3f}" for x in self.estimated_offsets)
        lim = ", ".join(f"{x / ARCSEC:.3f}" for x in self.limit)
        verdict = "converged" if self.converged else "not converged"
        return (
            f"pass {self.pass_number}: theta20, theta30 = ({e})″, re-estimated residual ({r})″ ± ({s})″, "
            f"limit ({lim})″ = max(threshold, noise_sigmas·σ): {verdict}, chi2_red {self.chi2_red:.2f}"
        )


@dataclass(frozen=True)
class OffsetIterationResult:
    """Converged iteration (:meth:`OffsetEstimator.result`).

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
        """Return every pass in words, one line each."""
        return "\n".join(p.describe() for p in self.history)


def repointed_command(nominal: tuple[float, float, float], offsets: NDArray[np.float64] | tuple[float, ...]) -> tuple[float, float, float]:
    """Return the readings that put the gimbals at their nominal angles: ``r = r_nominal − θ̂`` (θ10 not re-commanded)."""
    return (float(nominal[0]), float(nominal[1] - offsets[1]), float(nominal[2] - offsets[2]))


class OffsetEstimator:
    """The estimate of a zero-offset iteration, pass by pass (plain values in; no platform).

    Each pass's coarse fit (:func:`stableins.estimators.coarse.calibrate_coarse`) re-estimates the offsets
    relative to the commands of that pass; :meth:`add_pass` returns its :class:`PassRecord`, converged when
    ``|δ̂| ≤ max(threshold, noise_sigmas · σ)`` on both gimbals.  :meth:`result` is the joint fit of every pass.

    Parameters
    ----------
    gravity, base_attitude, configuration
        Local gravity [m/s²], base attitude (yaw, pitch, roll) [rad] and gimbal senses of the site.
    positions : tuple of int
        The positions of a pass (screening: a missing or foreign position is refused).
    orientation_tolerance : float
        Largest difference between measured and commanded orientation [m/s²] (:class:`~stableins.estimators.layout.DwellChecks`).
    threshold, noise_sigmas : float
        The stopping test (threshold in rad).
    initial_offsets : (θ10, θ20, θ30)
        Offsets the first pass is re-pointed by [rad].
    nonlinear : bool
        Estimate ``K2_*`` in each pass (default); ``False`` is the paper's 15-parameter stage.
    extra_terms : sequence of Term
        Discovered (additive) terms estimated in every pass and in the joint fit.
    """

    def __init__(
        self,
        *,
        gravity: float,
        base_attitude: tuple[float, float, float],
        configuration: GimbalConfiguration,
        positions: tuple[int, ...],
        orientation_tolerance: float,
        threshold: float,
        noise_sigmas: float,
        initial_offsets: tuple[float, float, float] = (0.0, 0.0, 0.0),
        nonlinear: bool = True,
        extra_terms: Sequence[Term] = (),
    ) -> None:
        self.gravity = gravity
        self.base_attitude = base_attitude
        self.configuration = configuration
        self.positions = positions
        self.orientation_tolerance = orientation_tolerance
        self.threshold = threshold
        self.noise_sigmas = noise_sigmas
        self.nonlinear = nonlinear
        self.extra_terms = tuple(extra_terms)
        #: the offsets the next pass is re-pointed by (θ10, θ20, θ30) [rad]
        self.offsets = np.array(initial_offsets, dtype=float)
        self.history: list[PassRecord] = []
        self.dwells: list[DwellSummary] = []
        self._used: list[DwellSummary] = []
        self._last: FitResult | None = None

    def add_pass(self, dwells: Sequence[DwellSummary]) -> PassRecord:
        """Fit the dwells of the next pass (measured with the commands of :attr:`offsets`); its record."""
        k = len(self.history) + 1
        self.dwells += dwells
        fit = calibrate_coarse(
            dwells,
            gravity=self.gravity,
            base_attitude=self.base_attitude,
            configuration=self.configuration,
            expected_positions=self.positions,
            orientation_tolerance=self.orientation_tolerance,
            nonlinear=self.nonlinear,
            extra_terms=self.extra_terms,
            source=f"coarse pass {k}",
        )
        self._used += sorted((d for d in dwells if d.position in fit.positions()), key=lambda d: d.position)
        estimate = np.array([fit["theta10"][0], fit["theta20"][0], fit["theta30"][0]])
        sigma = np.array([fit["theta20"][1], fit["theta30"][1]])
        residual = estimate[1:] - self.offsets[1:]
        limit = np.maximum(self.threshold, self.noise_sigmas * sigma)
        record = PassRecord(
            k,
            (float(self.offsets[1]), float(self.offsets[2])),
            (float(estimate[1]), float(estimate[2])),
            (float(residual[0]), float(residual[1])),
            (float(sigma[0]), float(sigma[1])),
            (float(limit[0]), float(limit[1])),
            fit.chi2_red,
        )
        self.history.append(record)
        self.offsets = np.array([self.offsets[0], estimate[1], estimate[2]])
        self._last = fit
        return record

    def result(self) -> OffsetIterationResult:
        """Return the converged iteration: the joint fit of every pass (the last pass alone after one pass)."""
        if self._last is None:
            raise ValueError("no pass has been added")
        fit = joint = self._last
        k = len(self.history)
        if k > 1:
            joint = fit_joint(
                self._used,
                gravity=self.gravity,
                base_attitude=self.base_attitude,
                configuration=self.configuration,
                start=fit,
                nonlinear=self.nonlinear,
                notes=(f"joint fit of coarse passes 1..{k} (each with its own commanded readings)",),
                extra_terms=self.extra_terms,
            )
        offsets = (float(self.offsets[0]), float(self.offsets[1]), float(self.offsets[2]))
        return OffsetIterationResult(joint, offsets, tuple(self.history), tuple(self.dwells), fit)
