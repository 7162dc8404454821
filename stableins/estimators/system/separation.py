r"""Separation of the fifteen combined coefficients into accelerometer corrections.

Model (docs/system-calibration.md §4).  The five specific-force states
(:func:`.harmonics.state_combinations`) and the ten quasi-static attitude coefficients
(:func:`.attitude.attitude_combinations`) are linear in the twelve residuals
``p = (D_x, D_y, D_z, b_x, b_y, b_z, Δβxy, Δβxz, Δβyx, Δβyz, Δβzx, Δβzy)``; the pitch and
roll means also contain base tilt and gimbal zero offsets, so each gets a free nuisance
column.  Weighted least squares with the coefficients' full covariance ``C``:

.. math:: \hat p = \arg\min (c - G p)^T C^{-1} (c - G p).

Rank.  On a polar-aligned platform ``f_z`` is constant, so ``b_x`` and ``Δβxy`` only act
through ``A = b_x − Δβxy sinL`` and ``b_y``, ``Δβyx`` through ``B = b_y + Δβyx sinL``
(Wu et al. 2018 Eq. 41 drops these angle terms from rows 5–6 and is singular once they
are restored); ``(Δβxz + Δβyz)/2`` is a rotation about ``z_p`` that only moves the roll
mean (together with the platform-axis zero offset); and the scale factors and ``b_z``
enter the non-harmonic terms only through ``x1``.  The 12 residuals plus 2 nuisances have
rank 9: determined are ``A``, ``B``, ``Δβzy``, ``Δβzx``, ``(D_x − D_y)/2``,
``(Δβxz − Δβyz)/2`` and ``x1``.

Gauge.  The solution is the minimum-norm one in the metric of the prior uncertainties
(``p = S q``, ``S = diag(prior σ)``, minimum ``|q|``): a determined combination is
corrected exactly, and its correction is shared among the parameters in proportion to
their prior variances; directions the data do not see are left at the prior.  With these
corrections the specific-force error is removed in this orientation up to the
undetermined constant horizontal terms, which the base tilt and gimbal zero offsets
mimic anyway.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stableins.estimators.system.attitude import ATTITUDE_COEFFICIENTS, attitude_combinations
from stableins.estimators.system.harmonics import HARMONIC_STATES, RESIDUAL_NAMES, state_combinations

COMBINED_COEFFICIENTS = HARMONIC_STATES + ATTITUDE_COEFFICIENTS
ATTITUDE_NUISANCES = ("pitch_offset", "roll_offset")
#: A combination whose σ grew more than this factor over its σ without a nuisance the record cannot separate (the
#: thermal terms under a daily cycle, docs/system-calibration.md §1b) is not called determined: the data no longer pin it,
#: the nuisance's prior does (issue 25).
GROWTH_LIMIT = 10.0


def combination_matrix(latitude: float) -> NDArray[np.float64]:
    """``G (15, 14)``: combined coefficients from residuals and the two mean nuisances."""
    g = np.zeros((15, 14))
    g[:5, :12] = state_combinations(latitude)
    g[5:, :12] = attitude_combinations(latitude)
    g[5, 12] = 1.0  # pitch mean: base tilt about east, middle-gimbal zero
    g[10, 13] = 1.0  # roll mean: base tilt about north, platform-axis zero · cosL
    return g


def determined_combinations(latitude: float) -> dict[str, NDArray[np.float64]]:
    """Named combinations of the residuals (14-vectors) that a full day determines."""
    s, c = np.sin(latitude), np.cos(latitude)
    ix = {n: i for i, n in enumerate(RESIDUAL_NAMES)}

    def vec(**terms: float) -> NDArray[np.float64]:
        v = np.zeros(14)
        for k, val in terms.items():
            v[ix[k]] = val
        return v

    return {
        "b_x - beta_xy*sinL": vec(b_x=1.0, beta_xy=-s),
        "b_y + beta_yx*sinL": vec(b_y=1.0, beta_yx=s),
        "beta_zy": vec(beta_zy=1.0),
        "beta_zx": vec(beta_zx=1.0),
        "(D_x - D_y)/2": vec(D_x=0.5, D_y=-0.5),
        "(beta_xz - beta_yz)/2": vec(beta_xz=0.5, beta_yz=-0.5),
        "x1 = -(D_x+D_y)/2*cos2L - D_z*sin2L + b_z*sinL": vec(D_x=-0.5 * c * c, D_y=-0.5 * c * c, D_z=-s * s, b_z=s),
    }


@dataclass(frozen=True)
class Separation:
    """Weighted least-squares separation (all vectors in :data:`RESIDUAL_NAMES` + nuisance order).

    ``b_*`` are bias residuals divided by g.  ``combinations`` holds, for each named
    combination, ``(value, sigma, determined)``.
    """

    names: tuple[str, ...]
    values: NDArray[np.float64]
    covariance: NDArray[np.float64]
    rank: int
    singular_values: NDArray[np.float64]
    null_space: NDArray[np.float64]
    determined: tuple[bool, ...]
    combinations: dict[str, tuple[float, float, bool]]
    coefficient_names: tuple[str, ...]
    residuals: NDArray[np.float64]
    residual_sigma: NDArray[np.float64]
    chi2: float
    dof: int


def separate(
    coefficient_names: Sequence[str],
    coefficients: ArrayLike,
    covariance: ArrayLike,
    latitude: float,
    prior_sigma: Mapping[str, float] | None = None,
    *,
    rank_tolerance: float = 1e-8,
    transform: ArrayLike | None = None,
) -> Separation:
    """Solve the combined coefficients for the residuals (rank-revealing, prior-metric gauge).

    Parameters
    ----------
    coefficient_names : sequence of str
        Which of :data:`COMBINED_COEFFICIENTS` are supplied.
    coefficients, covariance : array_like
        Their values and full covariance.
    latitude : float
        [rad].
    prior_sigma : mapping, optional
        Prior 1σ of each residual (:data:`RESIDUAL_NAMES`; biases divided by g) — the gauge
        metric.  Default: 1e-4 for every residual.
    transform : array_like (m, k), optional
        Use only the combinations ``T c`` of the supplied coefficients (a short record
        determines some combinations of them, not each one).
    """
    rows = [COMBINED_COEFFICIENTS.index(n) for n in coefficient_names]
    g = combination_matrix(latitude)[rows]
    c = np.asarray(coefficients, dtype=float)
    cov = np.asarray(covariance, dtype=float)
    if transform is not None:
        t = np.asarray(transform, dtype=float)
        g, c, cov = t @ g, t @ c, t @ cov @ t.T
    names = RESIDUAL_NAMES + ATTITUDE_NUISANCES
    scale = np.array([float((prior_sigma or {}).get(n, 1e-4)) for n in RESIDUAL_NAMES] + [1e-4, 1e-4])
    # whiten with the coefficient covariance
    sd = np.sqrt(np.diag(cov))
    chol = np.linalg.cholesky(cov / np.outer(sd, sd))
    whiten = np.linalg.solve(chol, np.diag(1.0 / sd))  # W with W C Wᵀ = I
    a = whiten @ g * scale[None, :]
    y = whiten @ c
    u, sv, vt = np.linalg.svd(a, full_matrices=True)
    rank = int(np.sum(sv > rank_tolerance * sv[0]))
    v = vt.T
    q = v[:, :rank] @ ((u[:, :rank].T @ y) / sv[:rank])
    p = scale * q
    cov_q = v[:, :rank] @ np.diag(sv[:rank] ** -2) @ v[:, :rank].T
    cov_p = cov_q * np.outer(scale, scale)
    null = scale[:, None] * v[:, rank:]
    null = null / np.linalg.norm(null, axis=0, keepdims=True) if null.size else np.zeros((14, 0))

    def is_determined(vec: NDArray[np.float64]) -> bool:
        if null.shape[1] == 0:
            return True
        # vᵀp is determined iff it vanishes on the null space; compare in the prior metric
        return bool(np.linalg.norm((vec * scale) @ v[:, rank:]) < 1e-6 * np.linalg.norm(vec * scale))

    determined = tuple(is_determined(np.eye(14)[i]) for i in range(14))
    combos = {}
    for name, vec in determined_combinations(latitude).items():
        combos[name] = (float(vec @ p), float(np.sqrt(max(vec @ cov_p @ vec, 0.0))), is_determined(vec))
    fitted = g @ p
    resid = c - fitted
    chi2 = float((whiten @ resid) @ (whiten @ resid))
    return Separation(
        names=names,
        values=p,
        covariance=0.5 * (cov_p + cov_p.T),
        rank=rank,
        singular_values=sv,
        null_space=null,
        determined=determined,
        combinations=combos,
        coefficient_names=tuple(coefficient_names),
        residuals=resid,
        residual_sigma=sd,
        chi2=chi2,
        dof=len(c) - rank,
    )


def without_growth(sep: Separation, reference: Separation, limit: float = GROWTH_LIMIT) -> tuple[Separation, tuple[str, ...]]:
    """Return ``sep`` with every combination whose σ grew more than ``limit`` times over ``reference``'s marked not determined.

    ``reference``: the same separation under the covariance without the inseparable nuisance (e.g. the thermal terms'
    part ``J P Jᵀ``, :class:`.thermal.ThermalFit`), i.e. the σ the record would give without it.  A combination
    determined by the structure of the day (null space) but whose σ is then mostly the nuisance's prior is determined by
    that prior, not by the data.  Returns the separation and the names of the combinations so relabelled.
    """
    combos = dict(sep.combinations)
    grown = []
    for name, (value, sigma, ok) in sep.combinations.items():
        base = reference.combinations.get(name, (0.0, 0.0, False))[1]
        if ok and base > 0 and sigma > limit * base:
            combos[name] = (value, sigma, False)
            grown.append(name)
    return replace(sep, combinations=combos), tuple(grown)
