"""The thermal model's arithmetic on the stage's bins (:mod:`.thermal`, docs/system-calibration.md §1b).

The record's temperature on the merged filter bins, the response of the six sensitivities in ``z``, pitch and roll and in
``v = (x1..x7, attitude)``, the information the ``z`` residuals carry on them, the directions the record separates from
the harmonics, and the share of the temperature's variance at 1 and 2 cycles per sidereal day.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from stableins.estimators.system import spectrum
from stableins.estimators.system.assembly import VIF_LIMIT
from stableins.estimators.system.coloured import LowBand, attitude_bin_map

if TYPE_CHECKING:
    from stableins.estimators.system.accumulate import RecordSums
    from stableins.estimators.system.solve import AttitudeStep, HarmonicFit, NoiseDecision


def bin_temperature(sums: RecordSums, keep: NDArray[np.bool_], band: LowBand) -> NDArray[np.float64]:
    """Mean temperature on the merged filter bins of ``band`` (bins without a temperature sample interpolated)."""
    assert sums.temperature_bins is not None
    n = band.groups.size
    index = np.unique(np.flatnonzero(keep) // band.merge, return_inverse=True)[1]
    size = sums.filter_bins.n.size
    total, count = np.zeros(size), np.zeros(size)
    m = min(size, sums.temperature_bins.count.size)
    total[:m], count[:m] = sums.temperature_bins.total[:m], sums.temperature_bins.count[:m]
    t_sum = np.bincount(index, weights=total[keep], minlength=n)
    t_count = np.bincount(index, weights=count[keep], minlength=n)
    have = t_count > 0
    return np.interp(band.time, band.time[have], t_sum[have] / t_count[have]) if have.any() else np.zeros(n)


def response(
    gravity: float, attitude: AttitudeStep, band: LowBand, delta_t: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Return the six sensitivities' ``z``, pitch and roll on the bins ``(n, 6)`` and their response ``J (17, 6)`` in ``v``.

    ``gravity`` [m/s²] of the site; ``attitude``: the stage's attitude step (its Fourier fit and vertical channel).
    """
    n = band.groups.size
    loads = band.mixing[0]  # u_a on the bins
    # δ_a per unit of each sensitivity on the bins: bias ΔT/g on its axis, scale factor ΔT u_a
    inputs = np.zeros((6, 3, n))
    for a in range(3):
        inputs[a, a] = delta_t / gravity
        inputs[3 + a, a] = delta_t * loads[a]
    z_cols = np.stack([sum(loads[a] * inputs[p, a] for a in range(3)) for p in range(6)], axis=1)
    pitch = np.stack([sum(band.mixing[1][a] @ inputs[p, a] for a in range(3)) for p in range(6)], axis=1)
    roll = np.stack([sum(band.mixing[2][a] @ inputs[p, a] for a in range(3)) for p in range(6)], axis=1)
    att = attitude.fit
    jac_x = np.zeros((10, 7))
    jac_x[:, :5] = att.vertical_jacobian @ np.diag(-attitude.along)  # ∂attitude/∂x through the vertical channel
    j_x = band.a_z @ z_cols
    return z_cols, pitch, roll, np.vstack([j_x, attitude_bin_map(att, band.groups, band.merge) @ np.vstack([pitch, roll]) + jac_x @ j_x])


def information(
    harmonic: HarmonicFit, decision: NoiseDecision, band: LowBand, z_cols: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Return the ``z`` residuals' information and gradient on the sensitivities, and the information before the harmonic fit.

    Bins' covariance: white ``R/n`` plus the coloured model the stage decided on; the residuals' is ``R_z C R_zᵀ``
    (pseudo-inverse: rank ``n − 7``).  ``harmonic``: the stage's harmonic fit (its residual variance); ``decision``: its
    noise decision (the coloured model).
    """
    n = band.groups.size
    loads = band.mixing[0]
    cov = np.diag(harmonic.residual_variance / band.weights[0])
    fit = decision.fit
    amplitudes = fit.amplitudes if fit is not None else np.zeros((len(band.kernels), 3))
    eye = np.eye(n)
    for c, kernel in enumerate(band.kernels):
        cov = cov + np.einsum("a,aij->ij", amplitudes[c], spectrum.component_quadratic(eye, eye, [loads], kernel, per_axis=True))
    maker = band.makers[0]
    residual_cov = maker @ cov @ maker.T
    precision = np.linalg.pinv(0.5 * (residual_cov + residual_cov.T), rcond=1e-10, hermitian=True)
    z_tilde = maker @ z_cols
    return z_tilde.T @ precision @ z_tilde, z_tilde.T @ precision @ band.channels[0], z_cols.T @ np.linalg.solve(cov, z_cols)


#: Relative singular value of the sensitivities' ``z`` regressors (scaled) below which a direction counts as not reached.
COLLINEAR = 1e-3


def separable_directions(
    info: NDArray[np.float64],
    info_raw: NDArray[np.float64],
    gradient: NDArray[np.float64],
    *,
    regressors: NDArray[np.float64] | None = None,
) -> tuple[NDArray[np.float64], float, int]:
    """Directions of the sensitivities the record separates from the harmonics, and the data-only χ² on them.

    Generalized eigenproblem ``F w = λ F_raw w``: ``λ`` is the share of the thermal signal along ``w`` left after the
    harmonic fit; directions with ``λ ≥ 1/VIF_LIMIT`` are separable.  ``regressors``: the sensitivities' ``z`` on the bins
    ``(n, 6)`` (:func:`response`); given, the directions they do not reach at all are left out first, from the
    regressors themselves (singular values below :data:`COLLINEAR` of the largest): ``k_z``, ``s_z`` and ``s_x + s_y``
    all enter ``z`` as ``ΔT`` (the last to 1e-5 on bin means), two null directions the information matrices show only
    to their round-off under a large random walk, where the threshold on them let them through and the data-only
    estimate moved along them by 0.1 m/s²/K: invisible in ``z``, 1000 times the signal in pitch (issue 25).
    """
    scale = np.sqrt(np.clip(np.diag(info_raw), 1e-300, None))
    basis = np.eye(info_raw.shape[0])
    if regressors is not None:
        _, singular, right = np.linalg.svd(regressors / np.where(scale > 0, scale, 1.0), full_matrices=False)
        basis = right[singular > COLLINEAR * max(float(singular.max(initial=0.0)), 1e-300)].T  # (6, k): the reachable directions
    raw = basis.T @ (info_raw / np.outer(scale, scale)) @ basis
    values, vectors = np.linalg.eigh(raw)
    keep = values > 1e-9 * max(values.max(initial=0.0), 1e-300)  # exact collinearities are ~1e-12
    if not keep.any():
        return np.zeros((0, 6)), 0.0, 0
    half = basis @ (vectors[:, keep] / np.sqrt(values[keep]))  # raw^{-1/2} on its range
    shares, w = np.linalg.eigh(half.T @ (info / np.outer(scale, scale)) @ half)
    directions = (half @ w[:, shares >= 1.0 / VIF_LIMIT]).T / scale  # in the parameters
    chi2 = 0.0
    for d in directions:
        fd = float(d @ info @ d)
        if fd > 0:
            chi2 += float(d @ gradient) ** 2 / fd
    return directions, chi2, int(directions.shape[0])


def daily_fraction(band: LowBand, delta_t: NDArray[np.float64], latitude: float) -> float:
    """Share of the weighted variance of ``ΔT`` explained by 1 and 2 cycles per sidereal day (Earth-rate angle of the bins)."""
    loads = band.mixing[0]
    weights = band.weights[0]
    c = math.cos(latitude)
    cos_s, sin_s = loads[0] / c, loads[1] / c
    design = np.stack([np.ones_like(cos_s), cos_s, sin_s, cos_s**2 - sin_s**2, 2 * cos_s * sin_s], axis=1)
    w = np.sqrt(weights)
    coef = np.linalg.lstsq(design * w[:, None], delta_t * w, rcond=None)[0]
    total = float(np.sum(weights * delta_t**2))
    left = float(np.sum(weights * (delta_t - design @ coef) ** 2))
    return 1.0 - left / total if total > 0 else 0.0


__all__ = ["COLLINEAR", "bin_temperature", "daily_fraction", "information", "response", "separable_directions"]
