"""The score of one candidate term against a fit: its effect statistics, its refit and the separating procedures proposed for it."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from stableins.errormodel import ErrorModel, Term
from stableins.errors import InputError, NotDeterminedError
from stableins.estimators.result import FitResult
from stableins.status import Status

if TYPE_CHECKING:  # pragma: no cover
    from stableins.estimators.leastsquares import Problem


#: Below this ‖z⊥‖/‖z‖ a candidate is not separable from the model with these data.
IDENTIFIABLE_TOLERANCE = 1e-3
#: A candidate whose nominal size moves the data by less than this (whitened norm over the whole record) is "not excited".
EXCITATION_TOLERANCE = 0.05
#: ``|corr|`` of projected columns above which two candidates cannot be told apart.
CONFUSION_CORRELATION = 0.99
#: Level of the test for a signature left after a candidate (:func:`stableins.discovery.signature.laboratory_columns`):
#: a candidate whose residual still follows a laboratory-fixed direction at ``p`` below it is not named.  Under a true
#: library effect the residual with it is noise, so the test refuses a true name with probability ``SIGNATURE_ALPHA``.
SIGNATURE_ALPHA = 0.05
#: Likelihood margin of the best group: a candidate whose ΔRSS is within this of the best significant candidate's is
#: named with it as one group (these data cannot tell them apart).  With the true effect ``c`` of size ``a`` (whitened)
#: and a rival ``j`` at correlation ``ρ`` of their projected columns, ``ΔRSS_j − ΔRSS_c ≈ N(−s², 4s²)`` with
#: ``s = a√(1 − ρ²)`` (to first order in the noise), so ``P(ΔRSS_j − ΔRSS_c > M) = Φ(−(M + s²)/(2s)) ≤ Φ(−√M)``
#: for every ``s`` (the bound is reached at ``s = √M``): with ``M = 1.96²`` a rival beats the true effect by more than
#: the margin with probability at most 2.5 % whatever its correlation, so the group holds the truth (docs/discovery.md).
GROUP_MARGIN = 1.959963984540054**2
#: The band ``χ²_ν`` must come back into for a candidate to explain the residual: its two-sided 95 % range under the model
#: with the candidate (``ν − 1`` degrees of freedom); a candidate is *named* (flagged) only if adding it brings ``χ²``
#: to or below the band's upper edge (:func:`explains`).
EXPLAINED_BAND = 0.95


def not_named_because(chi2_red_with: float, leaves: Sequence[str], signature_p: float) -> str:
    """Return why the best identifiable candidate is not named, in words (the naming rule of :mod:`stableins.discovery.ranking`).

    In the rule's order: ``χ²_ν`` with it above its 95 % band; other candidates still significant with it
    (``leaves``); the residual with it still following a laboratory-fixed direction (``signature_p`` below
    :data:`SIGNATURE_ALPHA`).
    """
    if leaves:
        return f"would leave χ²_ν = {chi2_red_with:.3g} with {', '.join(leaves)} still significant"
    if signature_p < SIGNATURE_ALPHA:
        return (
            f"would leave χ²_ν = {chi2_red_with:.3g}, but a residual that still follows a laboratory-fixed direction "
            f"(p = {signature_p:.2g})"
        )
    return f"would leave χ²_ν = {chi2_red_with:.3g}, above its 95 % band"


@dataclass(frozen=True)
class CandidateScore:
    """One candidate's standing against the current model.

    Attributes
    ----------
    id : str
        Candidate id.
    term : Term
        The candidate term.
    statistic : float
        ΔRSS in χ² units (score / added-variable statistic; refit value when ``refit``).
    p_value : float
        F-test p-value, ``F(1, ν−1)``.
    delta_bic : float
        BIC change on adding the effect (negative favours it).
    estimate, sigma : float
        Coefficient and 1σ [SI].
    predicted : float
        Largest predicted change of an observation caused by the estimated effect [SI of the observation].
    identifiable : bool
        False when the effect cannot be separated from the model with these data.
    excited : bool
        False when the data do not excite the effect at all (zero or negligible column).
    separability : float
        ``‖z⊥‖/‖z‖``.
    aliases : tuple of (str, float)
        Model parameters the effect is absorbed into when left out, with the shift per unit
        effect [parameter SI per candidate SI], largest first.
    confused_with : tuple of str
        Other candidates indistinguishable from this one with these data.
    refit : bool
        True when the numbers come from a full refit (not the one-step statistic).
    shifts : dict
        Refit only: shift of each model parameter [SI] and in units of its 1σ.
    advice : str
        What would separate the effect (when not identifiable) or confirm it.
    flagged : bool
        Significant at the family-wise level (Bonferroni) *and* explaining the residual (``explains``).
    chi2_red_with : float
        ``χ²_ν`` of the fit with the effect added: ``(χ² − ΔRSS)/(ν − 1)`` (NaN when not identifiable).
    explains : bool
        Whether the effect alone explains the residual: adding it brings ``χ²_ν`` into its 95 % band
        (:data:`EXPLAINED_BAND`, :func:`explains`) and leaves no other candidate significant (``leaves`` empty).
    leaves : tuple of str
        The candidates still significant once this one is added (the residual is not this effect alone).
    signature_p : float
        Device dwells: p-value of the residual with the effect added along directions fixed in the laboratory
        (:func:`stableins.discovery.signature.laboratory_columns`, F-test); below :data:`SIGNATURE_ALPHA` a signature is
        left and the effect is not named.  NaN when not tested.
    """

    id: str
    term: Term
    statistic: float
    p_value: float
    delta_bic: float
    estimate: float
    sigma: float
    predicted: float
    identifiable: bool
    excited: bool
    separability: float
    aliases: tuple[tuple[str, float], ...] = ()
    confused_with: tuple[str, ...] = ()
    refit: bool = False
    shifts: dict = field(default_factory=dict)
    advice: str = ""
    flagged: bool = False
    chi2_red_with: float = float("nan")
    explains: bool = False
    leaves: tuple[str, ...] = ()
    signature_p: float = float("nan")

    def __repr__(self) -> str:
        from stableins.display import number, unit_text, value_sigma

        value, sigma = self.estimate_engineering
        estimate = value_sigma(value, sigma, unit_text(self.term.unit)) if self.identifiable else "not identifiable"
        flag = ", flagged" if self.flagged else ""
        test = f"ΔRSS = {self.statistic:.2f}, p = {number(self.p_value, 2)}, ΔBIC = {self.delta_bic:+.1f}"
        return f"<CandidateScore {self.id}: {estimate}; {test}{flag}>"

    @property
    def estimate_engineering(self) -> tuple[float, float]:
        """Estimate and 1σ in the term's engineering unit."""
        return float(self.term.to_engineering(self.estimate)), float(self.term.sigma_to_engineering(self.sigma))

    def alias_text(self, model: ErrorModel | None = None) -> str:
        """Return the parameters the candidate is confused with, and their correlation, in words."""
        if not self.aliases:
            return "—"
        parts = []
        for pid, c in self.aliases:
            if model is not None and pid in model:
                per = c * self.term.scale / model[pid].scale  # parameter eng units per candidate eng unit
                parts.append(f"{pid} ({per:+.3g} {model[pid].unit} per {self.term.unit})")
            else:
                parts.append(pid)
        return ", ".join(parts)

    def to_json(self, model: ErrorModel | None = None) -> dict:
        """Return the JSON form of the score (numbers in engineering units; non-finite as null)."""
        value, sigma = self.estimate_engineering
        return {
            "id": self.id,
            "statistic": _finite(self.statistic),
            "p_value": _finite(self.p_value),
            "delta_bic": _finite(self.delta_bic),
            "predicted": {
                "estimate": _finite(value),
                "sigma": _finite(sigma),
                "unit": self.term.unit,
                "max_output_change": _finite(self.predicted),
                "max_output_change_unit": "SI unit of the observation (m/s^2 for dwell means, rad/s for reading slopes)",
            },
            "identifiable": bool(self.identifiable),
            "excited": bool(self.excited),
            "separability": _finite(self.separability),
            "aliases": [{"id": pid, "shift_per_unit": _finite(c)} for pid, c in self.aliases],
            "confused_with": list(self.confused_with),
            "refit": self.refit,
            "flagged": self.flagged,
            "chi2_red_with": _finite(self.chi2_red_with),
            "explains": self.explains,
            "leaves": list(self.leaves),
            "signature_p": _finite(self.signature_p),
            "advice": self.advice,
        }


def band_upper(nu: int, level: float = EXPLAINED_BAND) -> float:
    """Upper edge of the two-sided ``level`` range of ``χ²_ν`` on ``nu`` degrees of freedom: ``χ²_{(1+level)/2}(ν)/ν``."""
    from scipy import stats

    return float(stats.chi2.ppf(0.5 + level / 2.0, nu) / nu) if nu > 0 else float("inf")


def explains(chi2_before: float, delta_rss: float, nu: int) -> tuple[float, bool]:
    r"""``χ²_ν`` with an effect added and whether it lies in its 95 % band (at or below the upper edge).

    .. math:: \chi^2_{\nu,1} = \frac{\chi^2_0 - \Delta RSS}{\nu - 1} \le \frac{\chi^2_{0.975}(\nu - 1)}{\nu - 1}

    A value below the band is not a failure to explain (the noise floor is then overstated).  ``chi2_before`` is the
    whitened χ² of the model (``ν`` degrees of freedom), ``delta_rss`` the fall the effect brings (refit or one step).
    """
    dof = max(nu - 1, 1)
    after = max(chi2_before - delta_rss, 0.0) / dof
    return float(after), bool(after <= band_upper(dof))


def _finite(x: float) -> float | None:
    x = float(x)
    return x if np.isfinite(x) else None


def effect_statistics(delta_rss: float, rss0: float, nu: int, m: int) -> tuple[float, float, float]:
    """``(ΔRSS, p, ΔBIC)`` of adding one effect to a fit with χ² ``rss0`` on ``nu`` degrees of freedom, ``m`` observations.

    ``p`` from ``F = ΔRSS / (RSS₁/(ν−1))`` with ``F(1, ν−1)`` (robust to a mis-scaled noise floor);
    ``ΔBIC = −ΔRSS + ln m`` (negative favours the effect).
    """
    from scipy import stats

    rss1 = max(rss0 - delta_rss, 1e-300)
    dof = max(nu - 1, 1)
    f = delta_rss / (rss1 / dof)
    return float(delta_rss), float(stats.f.sf(f, 1, dof)), float(-delta_rss + np.log(m))


def candidate_columns(problem: Problem, terms: Sequence[Term], result: FitResult) -> NDArray[np.float64]:
    """Return the candidates' columns of ``problem`` at ``result``; one whose inputs the data lack gets a zero column (not excited).

    Like :meth:`stableins.estimators.leastsquares.Problem.candidate_columns`, which raises ``ValueError`` for such a
    candidate; the ranking needs a column for every candidate.
    """
    if not terms:
        return np.zeros((result.residuals.size, 0))
    try:
        return problem.candidate_columns(terms, result)
    except (InputError, NotDeterminedError):
        raise  # a described error passes through as it is (issue 29)
    except ValueError:
        cols = []
        for t in terms:
            try:
                cols.append(problem.candidate_columns([t], result)[:, 0])
            except (InputError, NotDeterminedError):
                raise  # a described error passes through as it is (issue 29)
            except ValueError:
                cols.append(np.zeros(result.residuals.size))
        return np.stack(cols, axis=1)


def refit(problem: Problem, result: FitResult, model: ErrorModel, candidate: CandidateScore, *, nu: int, m: int) -> CandidateScore:
    """Full refit of ``model + candidate``: ΔRSS, F-test, ΔBIC, estimate and parameter shifts."""
    new = problem.fit(model + candidate.term, start=result.as_dict())
    from stableins.discovery.problem import fit_chi2

    delta = fit_chi2(result) - fit_chi2(new)
    stat, p, dbic = effect_statistics(delta, fit_chi2(result), nu, m)
    value, sigma, _ = new[candidate.id]
    shifts = {}
    for t, v0, s0, st in zip(result.terms, result.values, result.sigma, result.status, strict=True):
        if st != Status.ESTIMATED:
            continue
        v1 = new[t.id][0]
        shifts[t.id] = (float(v1 - v0), float((v1 - v0) / s0) if s0 > 0 else float("nan"))
    column = candidate_columns(problem, [candidate.term], result)[:, 0]
    return CandidateScore(
        **{
            **candidate.__dict__,
            "statistic": stat,
            "p_value": p,
            "delta_bic": dbic,
            "estimate": value,
            "sigma": sigma,
            "predicted": float(np.max(np.abs(column * value))),
            "refit": True,
            "shifts": shifts,
        }
    )
