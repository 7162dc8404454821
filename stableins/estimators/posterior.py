r"""A stage as a Bayesian update of the record in force (docs/system-calibration.md §4, docs/formats.md).

The prior is the record: values :math:`x_0` and covariance :math:`P_0` of the parameters it
states (``estimated``, or ``fixed`` with a stated uncertainty).  The stage's data give a
:class:`~stableins.estimators.result.Likelihood`, linearized at :math:`\hat x`:
:math:`\log L = g^T(x-\hat x) - \tfrac12 (x-\hat x)^T\Lambda_d (x-\hat x)`.  The posterior
(information form, Gelb 1974 §4.2; Bishop 2006 Eq. 2.116):

.. math::
    \Lambda_1 = P_0^{-1} + \Lambda_d, \qquad
    x_1 = x_0 + \Lambda_1^{-1}\,\bigl(g + \Lambda_d(\hat x - x_0)\bigr), \qquad P_1 = \Lambda_1^{-1}.

Consequences, each tested (``tests/test_posterior.py``):

* **No σ grows**: :math:`P_1 = (P_0^{-1} + \Lambda_d)^{-1} \preceq P_0`, so every
  :math:`\sigma_1 \le \sigma_0` (and every linear combination's).
* **Nothing moves along what the data do not determine**: for any direction :math:`w` with
  :math:`\Lambda_d w = 0`, :math:`w^T\Lambda_1 (x_1 - x_0) = w^T (g + \Lambda_d(\hat x - x_0)) = 0` and
  :math:`w^T \Lambda_1 w = w^T P_0^{-1} w`: the information along :math:`w`, and the update measured
  in that information's metric, are the prior's.  A parameter correlated in the prior with one the data
  see moves by :math:`P_0 H^T S^{-1}(\cdot)` — the prior's own correlation, as Bayes requires.
* **Gauges are held**: a ``gauge`` parameter (σ = 0 by convention) conditions the likelihood at its value.
* Parameters neither the prior nor the data determine stay ``unidentifiable`` — only parameters without a prior can
  (a stated prior bounds every direction it enters) — and are integrated out of the data's information about the
  others (Schur complement, :meth:`_Information.marginalized`): the others' σ is what a joint update with an
  uninformative prior on them gives, not the smaller σ of holding them at the likelihood's point.

For an unbiased stage the errors obey :math:`\mathrm{Cov}(x_1 - x, x_0 - x) = P_1` (Kalman), hence
:math:`\mathrm{Var}(x_1 - x_0) = P_0 - P_1` — the change statistic of :mod:`stableins.history`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from stableins.estimators.result import INFORMATION_RTOL, Likelihood
from stableins.status import Determination, Status

#: Relative eigenvalue (of the unit-diagonal information of the parameters being marginalized) below which a direction
#: counts as unseen by the data in :meth:`_Information.marginalized`: far below :data:`INFORMATION_RTOL`, since a weakly
#: determined direction still couples to the rest and must be integrated out, not dropped.
MARGINAL_RTOL = 1e-14


@dataclass(frozen=True)
class Posterior:
    """Result of :func:`bayesian_update` over ``ids`` (prior ids first, then new ones of the likelihood).

    ``covariance`` has NaN rows/columns for ``unidentifiable`` parameters; ``determination`` says how the
    stage's data saw each parameter (None: not at all).
    """

    ids: tuple[str, ...]
    values: NDArray[np.float64]
    covariance: NDArray[np.float64]
    status: tuple[Status, ...]
    determination: tuple[Determination | None, ...]

    @property
    def sigma(self) -> NDArray[np.float64]:
        """Return the posterior 1σ (NaN for ``unidentifiable`` parameters)."""
        return np.sqrt(np.clip(np.diag(self.covariance), 0.0, None))


def _has_prior(status: Status, sigma: float) -> bool:
    return status in (Status.ESTIMATED, Status.FIXED) and math.isfinite(sigma) and sigma > 0.0


@dataclass(frozen=True)
class _Prior:
    """The prior over the prior's ids followed by the likelihood's new ones (no prior: NaN covariance, unidentifiable)."""

    ids: tuple[str, ...]
    values: NDArray[np.float64]
    covariance: NDArray[np.float64]
    status: tuple[Status, ...]

    @classmethod
    def joined(
        cls,
        ids: Sequence[str],
        values: NDArray[np.float64],
        covariance: NDArray[np.float64],
        status: Sequence[Status | str],
        likelihood: Likelihood,
    ) -> _Prior:
        """Return the prior extended by the likelihood's parameters it does not state (at the likelihood's point)."""
        prior_ids = list(ids)
        all_ids = prior_ids + [i for i in likelihood.ids if i not in prior_ids]
        n = len(all_ids)
        x0 = np.zeros(n)
        x0[: len(prior_ids)] = np.asarray(values, dtype=float)
        p0 = np.full((n, n), np.nan)
        p0[: len(prior_ids), : len(prior_ids)] = np.asarray(covariance, dtype=float)
        st = [Status(s) for s in status] + [Status.UNIDENTIFIABLE] * (n - len(prior_ids))
        for k in range(len(prior_ids), n):
            x0[k] = likelihood.point[likelihood.index(all_ids[k])]
        return cls(tuple(all_ids), x0, p0, tuple(st))

    @property
    def sigma(self) -> NDArray[np.float64]:
        """Return the prior 1σ (NaN where the prior states none)."""
        return np.sqrt(np.abs(np.diag(self.covariance)))

    def held(self) -> dict[str, float]:
        """Return the gauges and fixed values without uncertainty: the likelihood is conditioned at their values."""
        sigma0 = self.sigma
        return {
            pid: float(self.values[k])
            for k, pid in enumerate(self.ids)
            if self.status[k] is Status.GAUGE or (self.status[k] is Status.FIXED and not sigma0[k] > 0)
        }


@dataclass(frozen=True)
class _Information:
    """The update's information in scaled coordinates (prior σ, or the data's own scale for uninformed parameters)."""

    prior: _Prior
    data: NDArray[np.float64]  # Λ_d over all ids
    rhs: NDArray[np.float64]  # g + Λ_d (x̂ − x0) over all ids
    scale: NDArray[np.float64]
    informed: frozenset[int]

    @classmethod
    def of(cls, prior: _Prior, likelihood: Likelihood, informed: Sequence[int]) -> _Information:
        """Return the data's information and right-hand side placed over the prior's ids, with the scaling."""
        n = len(prior.ids)
        index = {pid: k for k, pid in enumerate(prior.ids)}
        lam_d = np.zeros((n, n))
        h = np.zeros(n)
        rows = [index[pid] for pid in likelihood.ids]
        lam_d[np.ix_(rows, rows)] = likelihood.information
        h[rows] = likelihood.gradient + likelihood.information @ (likelihood.point - prior.values[rows])
        diag_d = np.sqrt(np.clip(np.diag(lam_d), 0.0, None))
        sigma0 = prior.sigma
        scale = np.array([sigma0[k] if k in informed else (1.0 / diag_d[k] if diag_d[k] > 0 else 1.0) for k in range(n)])
        return cls(prior, lam_d, h, scale, frozenset(informed))

    def marginalized(self, loose: Sequence[int]) -> _Information:
        r"""Return the information of the data about the other parameters with ``loose`` marginalized (no prior on them).

        The likelihood is Gaussian in the parameters and ``loose`` have no prior, so integrating them out leaves the
        Schur complement (Bishop 2006 §2.3.2, the marginal of a Gaussian in its precision; the same as profiling them):

        .. math::
            \Lambda' = \Lambda_{rr} - \Lambda_{rl}\Lambda_{ll}^{+}\Lambda_{lr}, \qquad
            h' = h_r - \Lambda_{rl}\Lambda_{ll}^{+} h_l

        (``Λ_ll⁺``: pseudo-inverse in the data's own scale, directions below :data:`MARGINAL_RTOL` of its largest
        eigenvalue dropped: those the data do not see at all, hence do not couple to the rest either).  Leaving them
        out instead (conditioning on their likelihood point) would credit the other parameters with information the
        data only hold jointly with the loose ones.
        """
        loose_index = np.array(sorted(loose), dtype=int)
        scale = self.scale[loose_index]
        block = self.data[np.ix_(loose_index, loose_index)] * np.outer(scale, scale)
        pinv = np.linalg.pinv(0.5 * (block + block.T), rcond=MARGINAL_RTOL, hermitian=True)
        coupling = self.data[:, loose_index] * scale[None, :]
        data = self.data - coupling @ pinv @ coupling.T
        rhs = self.rhs - coupling @ pinv @ (self.rhs[loose_index] * scale)
        data[loose_index, :] = 0.0
        data[:, loose_index] = 0.0
        rhs[loose_index] = 0.0
        return _Information(self.prior, 0.5 * (data + data.T), rhs, self.scale, self.informed)

    def solve(self, members: list[int]) -> tuple[NDArray[np.float64], NDArray[np.float64], list[int]]:
        """Return the update and posterior covariance of ``members``, or the members neither prior nor data determine."""
        scale = self.scale
        f = np.array(members, dtype=int)
        prior_members = [k for k in members if k in self.informed]
        lam = self.data[np.ix_(f, f)] * np.outer(scale[f], scale[f])
        if prior_members:
            pos = [members.index(k) for k in prior_members]
            p_block = self.prior.covariance[np.ix_(prior_members, prior_members)] / np.outer(scale[prior_members], scale[prior_members])
            try:
                chol = np.linalg.cholesky(0.5 * (p_block + p_block.T))
            except np.linalg.LinAlgError:
                raise ValueError("the prior covariance of the stated parameters is not positive definite") from None
            inv_chol = np.linalg.solve(chol, np.eye(len(pos)))
            lam[np.ix_(pos, pos)] += inv_chol.T @ inv_chol
        eigenvalues, vectors = np.linalg.eigh(0.5 * (lam + lam.T))
        top = max(float(eigenvalues.max(initial=0.0)), 1e-300)
        null = vectors[:, eigenvalues <= INFORMATION_RTOL * top]
        # only a parameter without a prior can be left undetermined: a stated prior bounds every direction it enters
        loading = np.linalg.norm(null, axis=1) if null.size else np.zeros(len(members))
        loose = [members[i] for i in np.flatnonzero(loading > 1e-6) if members[i] not in self.informed]
        if loose:
            return np.zeros(0), np.zeros((0, 0)), loose
        cov = np.linalg.inv(lam)
        cov = 0.5 * (cov + cov.T)
        delta = cov @ (self.rhs[f] * scale[f])
        return delta * scale[f], cov * np.outer(scale[f], scale[f]), []


def _determination(prior: _Prior, likelihood: Likelihood) -> list[Determination | None]:
    """Return how the (conditioned) likelihood sees each parameter: alone, in combination, or not at all (None)."""
    index = {pid: k for k, pid in enumerate(prior.ids)}
    seen_mask = likelihood.seen()
    estimable = likelihood.estimable()
    determination: list[Determination | None] = [None] * len(prior.ids)
    for j, pid in enumerate(likelihood.ids):
        if seen_mask[j]:
            determination[index[pid]] = Determination.ALONE if estimable[j] else Determination.COMBINATION
    return determination


def _keep_unreached(
    out_x: NDArray[np.float64], out_p: NDArray[np.float64], prior: _Prior, members: list[int], *, seen: set[int], informed: set[int]
) -> None:
    """Give the members the update does not reach their prior values and covariance exactly (in place).

    Those are the members with no data and no prior covariance with what the data see (the algebra gives
    the same up to rounding).
    """
    f = np.array(members, dtype=int)
    x0, p0 = prior.values, prior.covariance
    for k in members:
        if k in seen or k not in informed:
            continue
        coupled = any(p0[k, j] != 0.0 and np.isfinite(p0[k, j]) for j in seen if j in informed)
        if not coupled:
            out_x[k] = x0[k]
            out_p[k, f] = np.where(np.isin(f, list(informed)), p0[k, f], 0.0)
            out_p[f, k] = out_p[k, f]


def _clear_outside(out_p: NDArray[np.float64], out_status: list[Status], members: list[int]) -> None:
    """Set the cross terms with parameters outside the update to zero, or NaN for unidentifiable ones (in place)."""
    f = np.array(members, dtype=int)
    for k in range(len(out_status)):
        if k in members:
            continue
        if out_status[k] is Status.UNIDENTIFIABLE:
            out_p[k, :] = np.nan
            out_p[:, k] = np.nan
        else:
            out_p[k, f] = 0.0
            out_p[f, k] = 0.0


def bayesian_update(
    ids: Sequence[str],
    values: NDArray[np.float64],
    covariance: NDArray[np.float64],
    status: Sequence[Status | str],
    likelihood: Likelihood,
) -> Posterior:
    """Return the posterior of a prior ``(ids, values, covariance, status)`` given a stage's ``likelihood`` (module docstring).

    Parameters of the likelihood not in the prior join with no prior information (their value and σ come
    from the data alone, if the data determine them).  Raises ``ValueError`` when the prior covariance of
    the parameters it states is not positive definite.
    """
    prior = _Prior.joined(ids, values, covariance, status, likelihood)
    all_ids, n = prior.ids, len(prior.ids)
    index = {pid: k for k, pid in enumerate(all_ids)}
    held = prior.held()
    lik = likelihood.conditioned({i: v for i, v in held.items() if i in likelihood.ids})
    determination = _determination(prior, lik)
    sigma0 = prior.sigma
    informed = [k for k in range(n) if _has_prior(prior.status[k], sigma0[k]) and all_ids[k] not in held]
    seen_mask = lik.seen()
    seen = [index[pid] for j, pid in enumerate(lik.ids) if seen_mask[j]]
    free = sorted(set(informed) | set(seen))
    out_x = prior.values.copy()
    out_p = prior.covariance.copy()
    out_status = list(prior.status)
    if not free:
        return Posterior(all_ids, out_x, out_p, tuple(out_status), tuple(determination))
    information = _Information.of(prior, lik, informed)
    members = list(free)
    while True:
        delta, cov, loose = information.solve(members)
        if not loose:
            break
        members = [k for k in members if k not in loose]  # neither prior nor data determine these
        information = information.marginalized(loose)  # what the data say about the rest, whatever their values
        for k in loose:
            out_status[k] = Status.UNIDENTIFIABLE
            out_p[k, :] = np.nan
            out_p[:, k] = np.nan
        if not members:
            return Posterior(all_ids, out_x, out_p, tuple(out_status), tuple(determination))
    f = np.array(members, dtype=int)
    out_x[f] = prior.values[f] + delta
    out_p[np.ix_(f, f)] = cov
    _keep_unreached(out_x, out_p, prior, members, seen=set(seen), informed=set(informed))
    _clear_outside(out_p, out_status, members)
    for k in members:
        if k in seen:  # the data saw it: its value and σ now rest on data (a prior 'fixed' becomes estimated)
            out_status[k] = Status.ESTIMATED
    return Posterior(all_ids, out_x, out_p, tuple(out_status), tuple(determination))


__all__ = ["Posterior", "bayesian_update"]
