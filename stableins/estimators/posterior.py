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
* Parameters neither the prior nor the data determine stay ``unidentifiable``.

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
        return np.sqrt(np.clip(np.diag(self.covariance), 0.0, None))


def _has_prior(status: Status, sigma: float) -> bool:
    return status in (Status.ESTIMATED, Status.FIXED) and math.isfinite(sigma) and sigma > 0.0


def bayesian_update(
    ids: Sequence[str],
    values: NDArray[np.float64],
    covariance: NDArray[np.float64],
    status: Sequence[Status | str],
    likelihood: Likelihood,
) -> Posterior:
    """Posterior of a prior ``(ids, values, covariance, status)`` given a stage's ``likelihood`` (module docstring).

    Parameters of the likelihood not in the prior join with no prior information (their value and σ come
    from the data alone, if the data determine them).  Raises ``ValueError`` when the prior covariance of
    the parameters it states is not positive definite.
    """
    prior_ids = list(ids)
    all_ids = prior_ids + [i for i in likelihood.ids if i not in prior_ids]
    n = len(all_ids)
    index = {pid: k for k, pid in enumerate(all_ids)}
    x0 = np.zeros(n)
    x0[: len(prior_ids)] = np.asarray(values, dtype=float)
    p0 = np.full((n, n), np.nan)
    p0[: len(prior_ids), : len(prior_ids)] = np.asarray(covariance, dtype=float)
    st = [Status(s) for s in status] + [Status.UNIDENTIFIABLE] * (n - len(prior_ids))
    for k in range(len(prior_ids), n):
        x0[k] = likelihood.point[likelihood.index(all_ids[k])]
    sigma0 = np.sqrt(np.abs(np.diag(p0)))

    # gauges and fixed values without uncertainty are held: the likelihood is conditioned at their values
    held = {all_ids[k]: float(x0[k]) for k in range(n) if st[k] is Status.GAUGE or (st[k] is Status.FIXED and not sigma0[k] > 0)}
    lik = likelihood.conditioned({i: v for i, v in held.items() if i in likelihood.ids})
    seen_mask = lik.seen()
    estimable = lik.estimable()
    determination: list[Determination | None] = [None] * n
    for j, pid in enumerate(lik.ids):
        if seen_mask[j]:
            determination[index[pid]] = Determination.ALONE if estimable[j] else Determination.COMBINATION

    informed = [k for k in range(n) if _has_prior(st[k], sigma0[k]) and all_ids[k] not in held]
    seen = [index[pid] for j, pid in enumerate(lik.ids) if seen_mask[j]]
    free = sorted(set(informed) | set(seen))
    out_x = x0.copy()
    out_p = p0.copy()
    out_status = list(st)
    if not free:
        return Posterior(tuple(all_ids), out_x, out_p, tuple(out_status), tuple(determination))

    # information of the free parameters, in scaled coordinates (prior σ, or the data's own scale)
    lam_d = np.zeros((n, n))
    h = np.zeros(n)
    rows = [index[pid] for pid in lik.ids]
    lam_d[np.ix_(rows, rows)] = lik.information
    h[rows] = lik.gradient + lik.information @ (lik.point - x0[rows])
    diag_d = np.sqrt(np.clip(np.diag(lam_d), 0.0, None))
    scale = np.array([sigma0[k] if k in informed else (1.0 / diag_d[k] if diag_d[k] > 0 else 1.0) for k in range(n)])

    def solve(members: list[int]) -> tuple[NDArray[np.float64], NDArray[np.float64], list[int]]:
        f = np.array(members, dtype=int)
        prior_members = [k for k in members if k in informed]
        lam = lam_d[np.ix_(f, f)] * np.outer(scale[f], scale[f])
        if prior_members:
            pos = [members.index(k) for k in prior_members]
            p_block = p0[np.ix_(prior_members, prior_members)] / np.outer(scale[prior_members], scale[prior_members])
            try:
                chol = np.linalg.cholesky(0.5 * (p_block + p_block.T))
            except np.linalg.LinAlgError:
                raise ValueError("the prior covariance of the stated parameters is not positive definite") from None
            inv_chol = np.linalg.solve(chol, np.eye(len(pos)))
            lam[np.ix_(pos, pos)] += inv_chol.T @ inv_chol
        eigenvalues, vectors = np.linalg.eigh(0.5 * (lam + lam.T))
        top = max(float(eigenvalues.max(initial=0.0)), 1e-300)
        null = vectors[:, eigenvalues <= INFORMATION_RTOL * top]
        loose = [members[i] for i in np.flatnonzero(np.linalg.norm(null, axis=1) > 1e-6)] if null.size else []
        if loose:
            return np.zeros(0), np.zeros((0, 0)), loose
        cov = np.linalg.inv(lam)
        cov = 0.5 * (cov + cov.T)
        delta = cov @ (h[f] * scale[f])
        return delta * scale[f], cov * np.outer(scale[f], scale[f]), []

    members = list(free)
    while True:
        delta, cov, loose = solve(members)
        if not loose:
            break
        members = [k for k in members if k not in loose]  # neither prior nor data determine these
        for k in loose:
            out_status[k] = Status.UNIDENTIFIABLE
            out_p[k, :] = np.nan
            out_p[:, k] = np.nan
        if not members:
            return Posterior(tuple(all_ids), out_x, out_p, tuple(out_status), tuple(determination))
    f = np.array(members, dtype=int)
    out_x[f] = x0[f] + delta
    out_p[np.ix_(f, f)] = cov
    # parameters the update does not reach (no data, no prior covariance with what the data see) keep
    # their prior values and covariance exactly (the algebra gives the same up to rounding)
    seen_set = set(seen)
    for k in members:
        if k in seen_set or k not in informed:
            continue
        coupled = any(p0[k, j] != 0.0 and np.isfinite(p0[k, j]) for j in seen_set if j in informed)
        if not coupled:
            out_x[k] = x0[k]
            out_p[k, f] = np.where(np.isin(f, informed), p0[k, f], 0.0)
            out_p[f, k] = out_p[k, f]
    # cross terms with parameters outside the update (held, unidentifiable, not informed) are zero or NaN
    outside = [k for k in range(n) if k not in members]
    for k in outside:
        if out_status[k] is Status.UNIDENTIFIABLE:
            out_p[k, :] = np.nan
            out_p[:, k] = np.nan
        else:
            out_p[k, f] = 0.0
            out_p[f, k] = 0.0
    for k in members:
        if k in seen_set:  # the data saw it: its value and σ now rest on data (a prior 'fixed' becomes estimated)
            out_status[k] = Status.ESTIMATED
    return Posterior(tuple(all_ids), out_x, out_p, tuple(out_status), tuple(determination))


__all__ = ["Posterior", "bayesian_update"]
