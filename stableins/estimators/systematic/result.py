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
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from stableins.conventions import ARCSEC, DEG_PER_HOUR, DEG_PER_HOUR_PER_G
from stableins.display import value_sigma
from stableins.documents import DocumentFields, JSONObject
from stableins.errormodel import MICRO_G_PER_G2, known_terms
from stableins.estimators.details import StageDetails
from stableins.estimators.result import FitResult, Likelihood, Stage
from stableins.estimators.systematic.model import BASE_IDS, OFFSET_IDS, parameter_ids
from stableins.estimators.systematic.observations import HoldSummary
from stableins.estimators.systematic.passes import PassResult, Prior, rank_report
from stableins.estimators.systematic.rank import GroupRank, resolution
from stableins.status import Status
from stableins.terms import CROSS_COUPLING_TERMS


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
    left_out : mapping of str to float
        Cross-couplings the record does not hold that these data do not determine (1σ above their resolution), with
        their σ [SI]: they stay out of the record, marginalized under their wide prior (:func:`handed_over`).
    """

    holds: tuple[HoldSummary, ...]
    rank: tuple[GroupRank, ...]
    nuisance: Mapping[str, tuple[float, float]]
    passes: int
    changes: tuple[float, ...]
    chi2: float
    dof: int
    step: float
    left_out: Mapping[str, float] = field(default_factory=dict)


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
        lines.append(
            "gyro terms (platform frame; the stage's posterior, with its wide prior on terms the record does not hold: the "
            "record update removes that prior, so the record's numbers can differ where the data leave a direction loose):"
        )
        for term, value, sigma in zip(self.fit.terms, self.fit.values, self.fit.sigma, strict=True):
            if term.id.startswith("gyro_drift_"):
                lines.append(f"  {term.id:<14} {value_sigma(value / DEG_PER_HOUR, sigma / DEG_PER_HOUR, '°/h')}")
            elif term.id.startswith("Dg_"):
                lines.append(f"  {term.id:<14} {value_sigma(value / DEG_PER_HOUR_PER_G, sigma / DEG_PER_HOUR_PER_G, '°/h/g')}")
        if any(term.id.startswith("Kcc_") for term in self.fit.terms) or d.left_out:
            lines.append("cross-couplings (µg/g²):")
        for term, value, sigma in zip(self.fit.terms, self.fit.values, self.fit.sigma, strict=True):
            if term.id.startswith("Kcc_"):
                lines.append(f"  {term.id:<14} {value_sigma(float(term.to_engineering(value)), float(term.sigma_to_engineering(sigma)))}")
        for name, sigma in d.left_out.items():
            lines.append(f"  {name:<14} not determined (σ {sigma / MICRO_G_PER_G2:.1f}): not written to the record")
        lines.append("nuisances: " + ", ".join(f"{k} {v / ARCSEC:+.2f} ± {s / ARCSEC:.2f}″" for k, (v, s) in d.nuisance.items()))
        lines.append(
            f"innovations of every step: χ²/ν = {d.chi2 / max(d.dof, 1):.3f} (ν = {d.dof}); the record's evidence "
            f"({len(self.fit.residuals)} whitened innovations kept, less the rank; the certificate's figure): "
            f"χ²_ν = {self.fit.chi2_red:.3f} (ν = {self.fit.dof})"
        )
        return "\n".join(lines)

    def __str__(self) -> str:
        return self.report()

    def _repr_html_(self) -> str:
        return f"<pre>{html.escape(self.report())}</pre>"


def handed_over(result: PassResult, prior: Prior) -> tuple[tuple[str, ...], dict[str, float]]:
    """Return the ids whose information the record gets, and the cross-couplings left out with their σ [SI].

    Every accelerometer and gyro state, except a cross-coupling the record does not hold (it entered under the wide
    prior :data:`~stableins.estimators.systematic.passes.NEW_TERM_SIGMA`) whose σ from these data stays above its
    resolution (:func:`~stableins.estimators.systematic.rank.resolution`): the INS would compensate with a value that
    is noise.  It stays a nuisance: the information handed over is marginalized under its wide prior.
    """
    layout = result.layout
    sigma = np.sqrt(np.diag(result.estimate.P)) * layout.scales()
    ids: list[str] = []
    left: dict[str, float] = {}
    for k, name in enumerate(parameter_ids(layout), start=layout.accelerometer.start):
        new = not np.isfinite(prior.sigma(name, np.inf))
        if name.startswith("Kcc_") and new and sigma[k] > resolution(name):
            left[name] = float(sigma[k])
        else:
            ids.append(name)
    return tuple(ids), left


def build_result(result: PassResult, prior: Prior, step: float) -> SystematicCalibration:
    """Return the frozen result of the passes: posterior values, the data-only likelihood, the rank report."""
    layout = result.layout
    ids, left_out = handed_over(result, prior)
    index = np.array([layout.names.index(i) for i in ids])
    scales = layout.scales()[index]
    x = result.estimate.x[index] * scales
    cov = result.estimate.P[np.ix_(index, index)] * np.outer(scales, scales)
    cov0 = result.prior_covariance[np.ix_(index, index)] * np.outer(scales, scales)
    x0 = result.estimate_prior_mean[index] * scales
    point = np.array([_record_value(prior, i) for i in ids])
    # accelerometer states are residuals of the installed values; gyro states are the terms themselves
    residual = np.array([i in layout.accelerometer_ids for i in ids])
    values = np.where(residual, point + x, x)
    information = _symmetric(np.linalg.inv(cov) - np.linalg.inv(cov0))
    gradient = np.linalg.solve(cov, x - x0)
    likelihood = Likelihood(ids, point, information, gradient)
    innovations = np.concatenate(result.estimate.innovations) if result.estimate.innovations else np.zeros(0)
    terms = known_terms(CROSS_COUPLING_TERMS)
    totals = result.totals(result.estimate)
    sigma = np.sqrt(np.diag(result.estimate.P)) * layout.scales()
    nuisance = {n: (float(totals[k]), float(sigma[k])) for k, n in enumerate(layout.names) if n in BASE_IDS + OFFSET_IDS}
    details = SystematicDetails(
        result.holds, rank_report(result), nuisance, result.passes, result.changes, result.estimate.chi2, result.estimate.dof, step,
        left_out,
    )  # fmt: skip
    fit = FitResult(
        stage=Stage.SYSTEMATIC,
        terms=tuple(terms[i] for i in ids),
        values=values,
        covariance=_symmetric(cov),
        status=(Status.ESTIMATED,) * len(ids),
        residuals=innovations,
        residual_sigma=np.ones(len(innovations)),
        rank=sum(g.rank for g in details.rank if g.group != "nuisance"),
        notes=tuple(g.describe() for g in details.rank) + _left_out_note(left_out),
        details=details,
        likelihood=likelihood,
        settings=SystematicSettings(step, result.passes, tuple(_orientation(h) for h in result.holds)),
    )
    return SystematicCalibration(fit, details)


@dataclass(frozen=True)
class Orientation:
    """One orientation of a systematic run as its settings state it.

    The hold [h], the mean specific force in the platform frame [g] and the angle of the platform's z axis from the
    Earth's axis [°].
    """

    start_h: float
    end_h: float
    specific_force_g: tuple[float, ...]
    polar_angle_deg: float

    def to_document(self) -> JSONObject:
        """Return ``{"start_h", "end_h", "specific_force_g", "polar_angle_deg"}``."""
        return {"start_h": self.start_h, "end_h": self.end_h, "specific_force_g": list(self.specific_force_g),
                "polar_angle_deg": self.polar_angle_deg}  # fmt: skip

    @classmethod
    def from_document(cls, fields: DocumentFields) -> Orientation:
        """Return the orientation :meth:`to_document` wrote."""
        return cls(fields.number("start_h"), fields.number("end_h"), fields.numbers("specific_force_g"), fields.number("polar_angle_deg"))


@dataclass(frozen=True)
class SystematicSettings:
    """The settings of a systematic run: the filter step [s], the passes and the orientations it was indexed to."""

    step: float
    passes: int
    orientations: tuple[Orientation, ...]

    def to_document(self) -> JSONObject:
        """Return ``{"step", "passes", "orientations"}`` (docs/formats.md)."""
        return {"step": self.step, "passes": self.passes, "orientations": [o.to_document() for o in self.orientations]}

    @classmethod
    def from_document(cls, fields: DocumentFields) -> SystematicSettings:
        """Return the settings :meth:`to_document` wrote (:class:`InputError` naming the field)."""
        orientations = tuple(Orientation.from_document(o) for o in fields.objects("orientations"))
        return cls(fields.number("step"), fields.count("passes"), orientations)


def _orientation(hold: HoldSummary) -> Orientation:
    """One orientation as the record stores it."""
    return Orientation(hold.start / 3600.0, hold.end / 3600.0, tuple(float(f) for f in hold.specific_force),
                       float(np.degrees(hold.polar_angle)))  # fmt: skip


def _left_out_note(left_out: Mapping[str, float]) -> tuple[str, ...]:
    if not left_out:
        return ()
    text = ", ".join(f"{k} (σ {s / MICRO_G_PER_G2:.1f} µg/g²)" for k, s in left_out.items())
    return (f"cross-couplings not determined by these orientations, not written to the record: {text}",)


def _record_value(prior: Prior, term_id: str) -> float:
    term = known_terms(CROSS_COUPLING_TERMS)[term_id]
    return float(prior.values.get(term_id, term.reference))


def _symmetric(matrix: NDArray[np.float64]) -> NDArray[np.float64]:
    return 0.5 * (matrix + matrix.T)
