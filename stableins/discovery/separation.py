r"""Which extra procedure would separate a candidate effect?  Answered numerically.

For a candidate that the current data cannot separate from the model (or from another
candidate), each *proposal* — a set of extra dwells — is appended to the current design and
the candidate's separability ``‖z⊥‖/‖z‖`` (and its correlation with its confusion partners)
is recomputed.  Designs depend only on geometry, time, temperature and slew history, not on
outputs, so no data are needed: the proposals carry the current data's median 1σ per axis.

Proposals (device level):

==================  =====================================================================
``tumble_30``       36 positions, each gimbal stepped by 30° (inputs 0, ±0.5, ±0.87, ±1 g)
``azimuth_180``     the current positions with the base turned by 180° in azimuth
``reverse``         the current positions in reverse order (each approached from the other side)
``closing_pass``    the current positions repeated after the session (drift vs bias)
``temperature``     the current positions repeated 5 K warmer (temperature vs bias/drift)
==================  =====================================================================
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from stableins.discovery.dwells import DwellSet
from stableins.discovery.problem import DwellProblem, whiten
from stableins.errormodel import Term
from stableins.estimators.result import FitResult

PROPOSALS = ("tumble_30", "azimuth_180", "reverse", "closing_pass", "temperature")


@dataclass(frozen=True)
class ProposalSeparation:
    """How one proposal changes a candidate's separability."""

    proposal: str
    separability: float
    correlation: dict
    excitation: float = 0.0

    def separates(self, tolerance: float = 1e-3, confusion: float = 0.9) -> bool:
        """Return whether the candidate is separated by the tested positions.

        That is: separable (sin > tolerance), excited (the nominal effect's unabsorbed part exceeds the
        ranking's excitation threshold) and no longer confused (``|corr|`` < ``confusion``).
        """
        from stableins.discovery.scores import EXCITATION_TOLERANCE

        return (
            self.separability > tolerance
            and self.excitation > EXCITATION_TOLERANCE
            and all(abs(c) < confusion for c in self.correlation.values())
        )


def _proposal(dwells: DwellSet, name: str) -> DwellSet:
    p = dwells.n_positions
    sigma = np.broadcast_to(np.median(dwells.sigma, axis=0), (p, 3)).copy()
    end = float(dwells.time.max()) + float(np.median(np.diff(np.sort(dwells.time)))) if p > 1 else float(dwells.time.max())
    base = replace(dwells, sigma=sigma, output=np.zeros((p, 3)), slow_covariance=None, initial_readings=tuple(dwells.readings[-1]))
    if name == "azimuth_180":
        yaw, pitch, roll = dwells.base_attitude
        return replace(base, base_attitude=(yaw + np.pi, pitch, roll), time=dwells.time - dwells.time.min() + end)
    if name == "reverse":
        r = base.subset(np.arange(p)[::-1])
        return replace(r, time=dwells.time - dwells.time.min() + end, initial_readings=tuple(dwells.readings[-1]))
    if name == "closing_pass":
        return replace(base, time=dwells.time - dwells.time.min() + end + (dwells.time.max() - dwells.time.min()))
    if name == "temperature":
        return replace(base, time=dwells.time - dwells.time.min() + end, temperature=dwells.temperature + 5.0)
    if name == "tumble_30":
        steps = np.deg2rad(np.arange(0.0, 360.0, 30.0))
        zero = np.zeros_like(steps)
        readings = np.concatenate(
            [np.stack([zero, steps, zero], 1), np.stack([zero, zero, steps], 1), np.stack([steps, zero, zero + np.pi / 2], 1)]
        )
        n = len(readings)
        return DwellSet(
            readings=readings,
            output=np.zeros((n, 3)),
            sigma=np.broadcast_to(sigma[0], (n, 3)).copy(),
            gravity=dwells.gravity,
            time=np.asarray(end + 60.0 * np.arange(n), dtype=np.float64),
            time_since_command=np.full(n, float(np.median(dwells.time_since_command))),
            temperature=np.full(n, float(np.median(dwells.temperature))),
            slew_direction=np.zeros((n, 3)),
            labels=tuple(f"t{k + 1}" for k in range(n)),
            base_attitude=dwells.base_attitude,
            configuration=dwells.configuration,
            initial_readings=tuple(dwells.readings[-1]),
        )
    raise KeyError(f"unknown proposal {name!r} (known: {', '.join(PROPOSALS)})")


def separation(
    problem: DwellProblem,
    result: FitResult,
    candidate: Term,
    partners: Sequence[Term] = (),
    proposals: Sequence[str] = PROPOSALS,
) -> list[ProposalSeparation]:
    """Separability of ``candidate`` (and its correlation with ``partners``) with each proposal added.

    With ``X`` the whitened design extended by a proposal's dwells and ``z`` the candidates' whitened columns over the
    same dwells, ``z⊥ = z − Q Qᵀ z`` (``X = QR``); the separability is ``‖z⊥_0‖/‖z_0‖`` and the correlation with a
    partner ``z⊥_0ᵀ z⊥_k / (‖z⊥_0‖ ‖z⊥_k‖)`` (:mod:`stableins.discovery.ranking`).

    Parameters
    ----------
    problem : DwellProblem
        The current problem (its dwells are the template of the proposals).
    result : FitResult
        The current fit (the design is evaluated at its values).
    candidate : Term
        The effect to separate.
    partners : sequence of Term
        Candidates it is confused with.
    proposals : sequence of str
        Names from :data:`PROPOSALS`.
    """
    return separations(problem, result, [(candidate, partners)], proposals)[0]


def separations(
    problem: DwellProblem, result: FitResult, tested: Sequence[tuple[Term, Sequence[Term]]], proposals: Sequence[str] = PROPOSALS
) -> list[list[ProposalSeparation]]:
    """:func:`separation` of several candidates (each with its partners) against one fit, with the shared work done once.

    The proposals' dwells, the extended designs and their QR factors do not depend on the candidate, and a term's
    column does not depend on the other terms evaluated with it (to rounding: a separability that is zero comes out as
    another 1e-16): each is computed once for all ``tested``.
    """
    if not tested:
        return []
    union = list({t.id: t for candidate, partners in tested for t in (candidate, *partners)}.values())
    column = {t.id: k for k, t in enumerate(union)}
    x0 = whiten(problem, result, problem.design(result))
    z0 = whiten(problem, result, problem.candidate_columns(union, result))
    bases = []
    for name in proposals:
        extra = DwellProblem(_proposal(problem.dwells, name).following(problem.dwells))  # visited after the data
        q, _ = np.linalg.qr(np.vstack([x0, extra.whiten(extra.design(result))]))
        bases.append((name, q, np.vstack([z0, extra.whiten(extra.candidate_columns(union, result))])))
    out = []
    for candidate, partners in tested:
        pick = [column[t.id] for t in (candidate, *partners)]
        found = []
        for name, q, everything in bases:
            z = everything[:, pick]
            perp = z - q @ (q.T @ z)
            norms = np.linalg.norm(perp, axis=0)
            sep = float(norms[0] / max(np.linalg.norm(z[:, 0]), 1e-300))
            corr = {}
            for k, t in enumerate(partners, start=1):
                corr[t.id] = float(perp[:, 0] @ perp[:, k] / max(norms[0] * norms[k], 1e-300))
            found.append(ProposalSeparation(name, sep, corr, float(norms[0] * abs(candidate.nominal))))
        out.append(found)
    return out


def describe(results: Sequence[ProposalSeparation]) -> str:
    """One line: which proposals separate the candidate."""
    good = [r.proposal for r in results if r.separates()]
    return ("separated by: " + ", ".join(good)) if good else "none of the standard extensions separates it"
