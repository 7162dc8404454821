r"""Platform drift within dwells, seen by the angle sensors (gyro drift ``ε^p`` and g-sensitivity ``Dg_ab``).

A stabilised platform whose gyro about platform axis ``a`` errs by ``ε_a + Σ_b Dg_ab f^p_b`` (Cai et al. 2016
Eq. 1, coefficient G) turns at ``w = −(ε^p + D_g f^p)`` while it holds a position
(:func:`stableins.conventions.platform_drift_rate`).  The angle sensors measure the actual gimbal angles, so the
drift is *in the readings*: the accelerometer outputs stay consistent with the measured readings and the
dwell-mean residuals do not show it.  What shows it is the slope of the readings within each dwell,
``ṙ = J(α)⁻¹ w`` with the exact gimbal-rate map ``J`` (:mod:`stableins.estimators.gyro_sensitivity`, which
holds the slope fit, the geometry and the estimator of all twelve numbers).

This module builds the discovery form of it, a :class:`~stableins.discovery.linear.LinearProblem`: the null
model is a constant reading rate per gimbal (servo creep) and the constant gyro drift ``gyro_drift_x/y/z``
(a drift is not a missing effect: the stage ``stableins calibrate device`` estimates it), plus any ``Dg_ab``
already added and the nuisances of the dwell mode (torqued at the Earth rate: the torquers' scale-factor errors,
docs/conventions.md "The platform during a dwell"); the candidates are the nine ``Dg_ab``.  Only dwells torqued at
the Earth rate are ranked here: caged dwells carry no gyro information, and inertially held ones turn at 15 °/h
(the gyro stage, ``gyro_from_datasets``, models them; ``stableins calibrate device`` refuses them: its
accelerometer stages need dwells held to the base).  Dwells near gimbal lock (``cond J >`` 1e3) are left out: there
the platform is caged.  The slopes are weighed by the angle noise measured within the
dwells (per dwell and gimbal).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stableins.conventions import ARCSEC_PER_HOUR
from stableins.discovery.dwells import DwellSet
from stableins.discovery.linear import LinearProblem
from stableins.errormodel import GYRO_DRIFT_TERMS, ErrorModel, Term, TermKind
from stableins.estimators.gyro_sensitivity import MAX_CONDITION, SLOPE_SKIP, SlopeGeometry, reading_slope
from stableins.estimators.result import Stage
from stableins.platform import GIMBAL_NAMES

__all__ = ["MAX_CONDITION", "SLOPE_SKIP", "drift_problem", "reading_slope"]


def _nuisance_terms() -> tuple[Term, ...]:
    zero = lambda inputs: np.zeros_like(inputs.specific_force)  # noqa: E731  (never evaluated through the error model)
    return tuple(
        Term(
            f"reading_rate_{g}", TermKind.ADDITIVE, "rad/s", "arcsec/h", ARCSEC_PER_HOUR, 1e-9, f"constant {g} reading rate", regressor=zero
        )
        for g in GIMBAL_NAMES
    )


def _mode_terms(geometry: SlopeGeometry) -> tuple[Term, ...]:
    """Return the dwell mode's nuisance parameters as null-model terms (torqued dwells: the torquers' scale-factor errors)."""
    zero = lambda inputs: np.zeros_like(inputs.specific_force)  # noqa: E731  (never evaluated through the error model)
    return tuple(
        Term(name, TermKind.ADDITIVE, "1", "ppm", 1e-6, 1e-6, f"nuisance of the dwell mode {geometry.mode}", regressor=zero)
        for name, _ in geometry.nuisance
    )


def drift_problem(
    dwells: DwellSet,
    slopes: ArrayLike,
    slope_sigma: ArrayLike,
    zero_offsets: ArrayLike = (0.0, 0.0, 0.0),
    drift_terms: Sequence[Term] | None = None,
    *,
    added: Sequence[Term] = (),
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
        The ``Dg`` candidates (default: the library's nine, less ``added``).
    added : sequence of Term
        ``Dg_ab`` terms in the null model (``stableins diagnose --add Dg_xz``).
    """
    from stableins.discovery.library import LIBRARY
    from stableins.errormodel import GYRO_G_TERMS

    slopes = np.asarray(slopes, dtype=float)
    slope_sigma = np.asarray(slope_sigma, dtype=float)
    geometry = SlopeGeometry.of(  # at the centre of the samples each slope is fitted on (gyro_sensitivity.ReadingSlopes)
        dwells.readings if dwells.reading_centre is None else dwells.reading_centre,
        dwells.gravity,
        zero_offsets=zero_offsets,
        base_attitude=dwells.base_attitude,
        configuration=dwells.configuration,
        mode=dwells.dwell_mode,
        latitude=dwells.latitude,
    )
    # a reading that does not move within a dwell (a quiet or coarsely quantized angle sensor) has a slope whose
    # 1σ from the scatter is 0: it cannot be weighed, and is left out like a dwell near gimbal lock
    unweighable = ~np.all(np.isfinite(slope_sigma) & (slope_sigma > 0) & np.isfinite(slopes), axis=1)
    keep = ~geometry.locked & ~unweighable
    notes = tuple(
        f"{lbl}: {'near gimbal lock' if lock else 'readings constant within the dwell (slope cannot be weighed)'}, "
        "left out of the drift analysis"
        for lbl, lock, bad in zip(dwells.labels, geometry.locked, unweighable, strict=True)
        if lock or bad
    )
    added_ids = {t.id for t in added}
    if drift_terms is None:
        drift_terms = tuple(LIBRARY[t.id].term for t in GYRO_G_TERMS if t.id not in added_ids)
    columns: dict[str, NDArray] = {t.id: geometry.column(t.id)[keep].reshape(-1) for t in (*GYRO_DRIFT_TERMS, *added, *drift_terms)}
    nuisance = _nuisance_terms()
    n = int(keep.sum())
    for k, term in enumerate(nuisance):
        col = np.zeros((n, 3))
        col[:, k] = 1.0
        columns[term.id] = col.reshape(-1)
    mode_terms = _mode_terms(geometry)
    for term, (_, column) in zip(mode_terms, geometry.nuisance, strict=True):
        columns[term.id] = column[keep].reshape(-1)
    nuisance = nuisance + mode_terms
    labels = [f"{lbl} d{gm}/dt" for lbl, k in zip(dwells.labels, keep, strict=True) if k for gm in GIMBAL_NAMES]
    problem = LinearProblem(slopes[keep].reshape(-1), slope_sigma[keep].reshape(-1), columns, labels, stage=Stage.READING_SLOPES)
    return problem, ErrorModel(nuisance + GYRO_DRIFT_TERMS + tuple(added)), tuple(drift_terms), notes
