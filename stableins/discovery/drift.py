r"""Platform drift within dwells, seen by the angle sensors (gyro g-sensitivity ``Dg_ab``).

A stabilised platform whose gyro about platform axis ``a`` errs by ``Σ_b Dg_ab f^p_b`` (Cai et al.
2016 Eq. 1, coefficient G) turns at ``w = −D_g f^p`` while it holds a position
(:func:`stableins.conventions.platform_drift_rate`).  The angle
sensors measure the actual gimbal angles, so the drift is *in the readings*: the accelerometer
outputs stay consistent with the measured readings and the dwell-mean residuals do not show
it.  What shows it is the slope of the readings within each dwell.  With the gimbal-rate map
``ω_bp^p = G(α) α̇`` (:meth:`stableins.platform.GimbalPlatform.angular_rate`, exact), a drift
``ω = w = −D_g f^p`` makes the readings move at

.. math:: \dot r = G(\alpha)^{-1}\, \omega

This module measures the reading slopes (least-squares line per dwell and gimbal, 1σ from the
scatter about it), and builds a :class:`~stableins.discovery.linear.LinearProblem`: the null
model is a constant reading rate per gimbal (servo creep), the default candidates are the
diagonal ``Dg_xx, Dg_yy, Dg_zz`` (any ``Dg_ab`` may be given).  Dwells near gimbal lock
(``cond G > 1e3``) are left out: there the readings cannot follow the platform.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stableins.conventions import AXES, platform_drift_rate
from stableins.discovery.dwells import DwellSet
from stableins.discovery.linear import LinearProblem
from stableins.errormodel import ErrorModel, Term, TermKind

GIMBALS = ("platform", "inner", "middle")
#: Dwells whose gimbal-rate map is worse conditioned than this are left out (near gimbal lock).
MAX_CONDITION = 1e3


#: Fraction of each dwell left out at its start before fitting reading slopes (servo settling).
SLOPE_SKIP = 0.5


def reading_slope(time: ArrayLike, angles: ArrayLike, skip: float = SLOPE_SKIP) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Least-squares slope of each angle reading [rad/s] and its 1σ from the scatter about the line.

    The first ``skip`` fraction of the dwell is left out: the gimbal servo's settling transient
    (a damped oscillation after the slew) is in the readings there and biases a slope although
    it hardly moves a mean.  Simulated with the default settling (0.5 Hz, ζ = 0.2) and a 3 s
    settle, slopes over whole dwells gave χ²_ν ≈ 3 on clean data; over the second half 0.83–1.24
    (3 or 10 s settle, 20 or 60 s dwells, ν ≈ 78).
    """
    t_all = np.asarray(time, dtype=float)
    keep = t_all >= t_all[0] + skip * (t_all[-1] - t_all[0])
    t = t_all[keep]
    a = np.asarray(angles, dtype=float).reshape(t_all.size, -1)[keep]
    x = t - t.mean()
    sxx = float(x @ x)
    slope = x @ (a - a.mean(axis=0)) / sxx
    residual = a - a.mean(axis=0) - np.outer(x, slope)
    s2 = (residual**2).sum(axis=0) / max(t.size - 2, 1)
    sigma = np.sqrt(s2 / sxx) if sxx > 0 else np.full(a.shape[1], np.nan)
    # a reading that takes fewer than 3 values (a quiet or coarsely quantized sensor) has no scatter to weigh its
    # slope by (the residuals are rounding): NaN, and the drift analysis leaves the dwell out
    distinct = np.array([np.unique(a[:, k]).size for k in range(a.shape[1])])
    return slope, np.where(distinct >= 3, sigma, np.nan)


def _nuisance_terms() -> tuple[Term, ...]:
    zero = lambda inputs: np.zeros_like(inputs.specific_force)  # noqa: E731  (never evaluated through the error model)
    arcsec_per_hour = np.pi / 648000 / 3600
    return tuple(
        Term(
            f"reading_rate_{g}", TermKind.ADDITIVE, "rad/s", "arcsec/h", arcsec_per_hour, 1e-9, f"constant {g} reading rate", regressor=zero
        )
        for g in GIMBALS
    )


def drift_problem(
    dwells: DwellSet,
    slopes: ArrayLike,
    slope_sigma: ArrayLike,
    zero_offsets: ArrayLike = (0.0, 0.0, 0.0),
    drift_terms: Sequence[Term] | None = None,
) -> tuple[LinearProblem, ErrorModel, tuple[Term, ...], tuple[str, ...]]:
    """Return the reading-slope problem: (problem, null model, candidate terms, notes).

    Parameters
    ----------
    dwells : DwellSet
        Geometry of the dwells (mean readings, gravity, base, senses).
    slopes, slope_sigma : array_like (P, 3)
        Reading slopes [rad/s] and their 1σ, per dwell and gimbal.
    zero_offsets : array_like (3,)
        ``theta10, theta20, theta30`` (e.g. from the fit) for the actual angles.
    drift_terms : sequence of Term, optional
        The ``Dg`` terms (default: the library's).
    """
    from stableins.discovery.library import LIBRARY
    from stableins.platform import GimbalPlatform, platform_specific_force

    slopes = np.asarray(slopes, dtype=float)
    slope_sigma = np.asarray(slope_sigma, dtype=float)
    offsets = np.asarray(zero_offsets, dtype=float)
    platform = GimbalPlatform(
        zero_offsets=(offsets[0], offsets[1], offsets[2]), configuration=dwells.configuration, base_attitude=dwells.base_attitude
    )
    actual = platform.actual_angles(dwells.readings)
    g = np.stack([platform.angular_rate(actual, np.eye(3)[k]) for k in range(3)], axis=-1)  # (P, 3 omega, 3 gimbals)
    locked = ~(np.linalg.cond(g) < MAX_CONDITION)
    # a reading that does not move within a dwell (a quiet or coarsely quantized angle sensor) has a slope whose
    # 1σ from the scatter is 0: it cannot be weighed, and is left out like a dwell near gimbal lock
    unweighable = ~np.all(np.isfinite(slope_sigma) & (slope_sigma > 0) & np.isfinite(slopes), axis=1)
    keep = ~locked & ~unweighable
    notes = tuple(
        f"{lbl}: {'near gimbal lock' if lock else 'readings constant within the dwell (slope cannot be weighed)'}, "
        "left out of the drift analysis"
        for lbl, lock, bad in zip(dwells.labels, locked, unweighable, strict=True)
        if lock or bad
    )
    f_p = platform_specific_force(
        dwells.readings, dwells.gravity, zero_offsets=zero_offsets, base_attitude=dwells.base_attitude, configuration=dwells.configuration
    )
    terms = tuple(drift_terms) if drift_terms is not None else tuple(LIBRARY[f"Dg_{a}{a}"].term for a in AXES)
    columns: dict[str, NDArray] = {}
    for term in terms:
        unit = np.zeros((3, 3))
        unit[AXES.index(term.id[3]), AXES.index(term.id[4])] = 1.0  # Dg_ab
        omega = platform_drift_rate(np.zeros(3), unit, f_p)
        columns[term.id] = np.linalg.solve(g[keep], omega[keep][..., None])[..., 0].reshape(-1)
    nuisance = _nuisance_terms()
    n = int(keep.sum())
    for k, term in enumerate(nuisance):
        col = np.zeros((n, 3))
        col[:, k] = 1.0
        columns[term.id] = col.reshape(-1)
    labels = [f"{lbl} d{gm}/dt" for lbl, k in zip(dwells.labels, keep, strict=True) if k for gm in GIMBALS]
    problem = LinearProblem(slopes[keep].reshape(-1), slope_sigma[keep].reshape(-1), columns, labels, stage="reading slopes")
    return problem, ErrorModel(nuisance), terms, notes
