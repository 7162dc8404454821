"""The systematic stage's result: a frozen, typed result that reports itself, and the likelihood for the record.

The record update is Bayesian (:func:`stableins.estimators.posterior.bayesian_update`): the stage hands over the
information of its data alone about the accelerometer residuals and the gyro terms, ``Λ = P⁻¹ − P₀⁻¹`` on the
estimate filter's marginal (nuisances eliminated under their own priors: the survey's for the base, free for the
zero offsets and the torquing), with ``g = P⁻¹(x − x₀)`` at the record's values ``x₀``.  Directions the data do
not determine have no information: nothing moves along them and no σ grows.
"""

from __future__ import annotations

import html
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from stableins.conventions import ARCSEC, DEG_PER_HOUR, DEG_PER_HOUR_PER_G
from stableins.errormodel import known_terms
from stableins.estimators.details import StageDetails
from stableins.estimators.result import FitResult, Likelihood
from stableins.estimators.systematic.model import BASE_IDS, OFFSET_IDS, parameter_ids
from stableins.estimators.systematic.observations import HoldSummary
from stableins.estimators.systematic.passes import PassResult, Prior, rank_report
from stableins.estimators.systematic.rank import GroupRank
from stableins.status import Status


@dataclass(frozen=True, eq=False)
class SystematicDetails(StageDetails):
    """What the systematic stage worked with, beyond the parameters.

    Attributes
    ----------
    holds : tuple of HoldSummary
        The orientations the record held.
    rank : tuple of GroupRank
        What they determine, group by group (:mod:`~stableins.estimators.systematic.rank`).
    nuisance : mapping of str to (float, float)
        Base error and zero-offset residuals (totals), value and 1σ [rad].
    passes : int
        Passes of the outer re-linearization loop.
    changes : tuple of float
        Largest move of the linearization point after each pass [σ].
    chi2, dof : float, int
        Normalized innovations of the last pass's estimate filter: ``Σ νᵀS⁻¹ν`` and the number of observations.
    step : float
        Filter step [s].
    """

    holds: tuple[HoldSummary, ...]
    rank: tuple[GroupRank, ...]
    nuisance: Mapping[str, tuple[float, float]]
    passes: int
    changes: tuple[float, ...]
    chi2: float
    dof: int
    step: float


@dataclass(frozen=True, eq=False)
class SystematicCalibration:
    """The outcome of :func:`stableins.estimators.systematic.systematic_calibration`.

    Attributes
    ----------
    fit : FitResult
        Stage ``"systematic"``: the accelerometer residual terms (as record values) and the gyro terms, posterior of the
        stage's own prior, with the likelihood the record update uses.
    details : SystematicDetails
    """

    fit: FitResult
    details: SystematicDetails

    def report(self) -> str:
        """Text report: orientations, what they determine, the gyro terms, the nuisances, the filter's χ²."""
        d = self.details
        lines = [f"systematic calibration over {len(d.holds)} orientations (filter step {d.step:g} s, {d.passes} passes):"]
        for h in d.holds:
            f = ", ".join(f"{v:+.3f}" for v in h.specific_force)
            lines.append(
                f"  orientation {h.index + 1}: {h.start / 3600:.2f}–{h.end / 3600:.2f} h, f^p/g = ({f}), "
                f"z_p {np.degrees(h.polar_angle):.1f}° from the Earth's axis"
            )
        lines.append("what they determine (σ ≤ 1 resolution unit):")
        lines += [f"  {g.describe()}" for g in d.rank]
        lines.append("gyro terms (platform frame):")
        for term, value, sigma in zip(self.fit.terms, self.fit.values, self.fit.sigma, strict=True):
            if term.id.startswith("gyro_drift_"):
                lines.append(f"  {term.id:<14} {value / DEG_PER_HOUR:+.6f} ± {sigma / DEG_PER_HOUR:.6f} °/h")
            elif term.id.startswith("Dg_"):
                lines.append(f"  {term.id:<14} {value / DEG_PER_HOUR_PER_G:+.6f} ± {sigma / DEG_PER_HOUR_PER_G:.6f} °/h/g")
        lines.append("nuisances: " + ", ".join(f"{k} {v / ARCSEC:+.2f} ± {s / ARCSEC:.2f}″" for k, (v, s) in d.nuisance.items()))
        lines.append(f"innovations: χ²/ν = {d.chi2 / max(d.dof, 1):.3f} (ν = {d.dof})")
        return "\n".join(lines)

    def __str__(self) -> str:
        return self.report()

    def _repr_html_(self) -> str:
        return f"<pre>{html.escape(self.report())}</pre>"


def build_result(result: PassResult, prior: Prior, step: float) -> SystematicCalibration:
    """Return the frozen result of the passes: posterior values, the data-only likelihood, the rank report."""
    layout = result.layout
    ids = parameter_ids(layout)
    index = np.arange(layout.accelerometer.start, layout.gyro.stop)
    scales = layout.scales()[index]
    x = result.estimate.x[index] * scales
    cov = result.estimate.P[np.ix_(index, index)] * np.outer(scales, scales)
    cov0 = result.prior_covariance[np.ix_(index, index)] * np.outer(scales, scales)
    x0 = result.estimate_prior_mean[index] * scales
    point = np.array([_record_value(prior, i) for i in ids])
    # accelerometer states are residuals of the installed values; gyro states are the terms themselves
    accel = len(ids) - 12
    values = point + np.concatenate([x[:accel], x[accel:] - point[accel:]])
    information = _symmetric(np.linalg.inv(cov) - np.linalg.inv(cov0))
    gradient = np.linalg.solve(cov, x - x0)
    likelihood = Likelihood(ids, point, information, gradient)
    innovations = np.concatenate(result.estimate.innovations) if result.estimate.innovations else np.zeros(0)
    terms = known_terms()
    totals = result.totals(result.estimate)
    sigma = np.sqrt(np.diag(result.estimate.P)) * layout.scales()
    nuisance = {n: (float(totals[k]), float(sigma[k])) for k, n in enumerate(layout.names) if n in BASE_IDS + OFFSET_IDS}
    details = SystematicDetails(
        result.holds, rank_report(result), nuisance, result.passes, result.changes, result.estimate.chi2, result.estimate.dof, step
    )
    fit = FitResult(
        stage="systematic",
        terms=tuple(terms[i] for i in ids),
        values=values,
        covariance=_symmetric(cov),
        status=(Status.ESTIMATED,) * len(ids),
        residuals=innovations,
        residual_sigma=np.ones(len(innovations)),
        rank=sum(g.rank for g in details.rank if g.group != "nuisance"),
        notes=tuple(g.describe() for g in details.rank),
        details=details,
        likelihood=likelihood,
        settings={"step": step, "passes": result.passes, "orientations": [_orientation(h) for h in result.holds]},
    )
    return SystematicCalibration(fit, details)


def _orientation(hold: HoldSummary) -> dict[str, object]:
    """One orientation as the record stores it (JSON)."""
    return {
        "start_h": hold.start / 3600.0,
        "end_h": hold.end / 3600.0,
        "specific_force_g": list(hold.specific_force),
        "polar_angle_deg": float(np.degrees(hold.polar_angle)),
    }


def _record_value(prior: Prior, term_id: str) -> float:
    term = known_terms()[term_id]
    return float(prior.values.get(term_id, term.reference))


def _symmetric(matrix: NDArray[np.float64]) -> NDArray[np.float64]:
    return 0.5 * (matrix + matrix.T)
