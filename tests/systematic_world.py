"""The indexed world of the systematic-calibration tests and benchmark (issue 18): truth, record, prior.

The record comes from the truth simulator (stableins.simulator: exact kinematics, time-domain INS error dynamics);
the prior is what a device-level calibration leaves (the installed calibration with the residual σ the truth was
drawn with, the unit's noise model).  Nothing here calls estimator code except to build its input types.
"""

from __future__ import annotations

import math

import numpy as np

from stableins.conventions import ARCSEC, DEG_PER_HOUR, DEG_PER_HOUR_PER_G
from stableins.errormodel import CORE_IDS, CORE_TERMS, GIMBAL_IDS, GIMBAL_TERMS, MICRO_G_PER_G2, ErrorModel, known_terms
from stableins.estimators.result import FitResult
from stableins.estimators.systematic import Prior
from stableins.noise import NoiseModel
from stableins.records import CalibrationRecord
from stableins.simulator.noise import NoiseSettings
from stableins.simulator.system import simulate_system
from stableins.simulator.truth import DEFAULT_RESIDUAL, SimulatedSite, Truth
from stableins.terms import CROSS_COUPLING_TERMS
from stableins.turns import IndexAxis, PlatformTurn

#: 0.001 °/h per axis (the acceptance's drift), signs mixed.
DRIFT = {"x": 0.001 * DEG_PER_HOUR, "y": -0.001 * DEG_PER_HOUR, "z": 0.001 * DEG_PER_HOUR}
#: A g-sensitivity with every kind of entry (diagonal, off-diagonal) [rad/s per m/s²].
G_SENSITIVITY = {"Dg_xy": 0.002 * DEG_PER_HOUR_PER_G, "Dg_yy": 0.001 * DEG_PER_HOUR_PER_G, "Dg_zx": -0.001 * DEG_PER_HOUR_PER_G}
#: Base errors of the simulated site (right-handed about north, east, down).
BASE = {"tilt_north": 10 * ARCSEC, "tilt_east": -8 * ARCSEC, "azimuth_error": 30 * ARCSEC}
#: The index of procedures/system-indexed.toml: 60° about the middle gimbal axis.
INDEX_ANGLE = math.radians(60.0)
#: 1σ of a cross-coupling carried into the device-level record (``calibrate device --add``; README: ±4.0 µg/g²) [s²/m].
CROSS_COUPLING_SIGMA = 5 * MICRO_G_PER_G2


def indexed_truth(seed: int, *, rate: float, noise: NoiseSettings | None = None, g_sensitivity: bool = True) -> Truth:
    """A random instrument (Truth.draw) with the drift, g-sensitivity and base errors above."""
    effects = {**BASE, **(G_SENSITIVITY if g_sensitivity else {})}
    return Truth.draw(seed, site=SimulatedSite(sample_rate=rate), gyro_drift=DRIFT, effects=effects, noise=noise)


def with_cross_coupling(truth: Truth, true: dict[str, float], installed: dict[str, float] | None = None) -> Truth:
    """The truth with hidden cross-couplings ``true`` (simulator effects) and those the INS compensates with (``installed``)."""
    return truth.with_changes(effects={**truth.effects, **true}, installed_calibration={**truth.installed_calibration, **(installed or {})})


def turns(duration: float) -> tuple[PlatformTurn, ...]:
    """One index in the middle of the record (two holds of ``duration/2``)."""
    return (PlatformTurn(duration / 2, INDEX_ANGLE, IndexAxis.MIDDLE),)


def indexed_record(truth: Truth, duration: float, **options) -> dict[str, np.ndarray]:
    """A whole indexed record (two holds) as one dict of columns."""
    return simulate_system(truth, duration, turns=turns(duration), **options)


def noise_model(truth: Truth) -> NoiseModel:
    """The unit's noise model: the simulator's settings in the noise module's terms (quantization Δ/√12)."""
    n = truth.noise
    return NoiseModel.given(n.velocity_random_walk, n.bias_instability, n.acceleration_random_walk, n.quantization / math.sqrt(12.0))


def unit_prior(truth: Truth) -> Prior:
    """The record a device-level calibration leaves: installed values, the residual σ the truth was drawn with.

    Cross-couplings the INS compensates with (``truth.installed_calibration``) are the record's discovered terms
    (``calibrate device --add``), with :data:`CROSS_COUPLING_SIGMA`.
    """
    carried = tuple(t for t in CROSS_COUPLING_TERMS if t.id in truth.installed_calibration)
    ids = tuple(CORE_IDS) + tuple(GIMBAL_IDS) + tuple(t.id for t in carried)
    terms = known_terms(carried)
    sigma = np.array([CROSS_COUPLING_SIGMA if i.startswith("Kcc_") else DEFAULT_RESIDUAL[str(terms[i].kind)] for i in ids])
    model = ErrorModel.standard(nonlinear=True) + carried
    return Prior(dict(truth.installed_calibration), ids, np.diag(sigma**2), model, noise_model(truth))


def true_values(truth: Truth, ids: tuple[str, ...]) -> np.ndarray:
    """The true value of each id: the parameter, the gyro drift, the g-sensitivity or cross-coupling (0 when not injected)."""
    out = []
    for name in ids:
        if name.startswith("gyro_drift_"):
            out.append(truth.gyro_drift.get(name[-1], 0.0))
        elif name.startswith(("Dg_", "Kcc_")):
            out.append(truth.effects.get(name, 0.0))
        else:
            out.append(truth.parameters[name])
    return np.array(out, dtype=float)


def prior_pull(fit: FitResult, prior: Prior, true: np.ndarray) -> tuple[np.ndarray, np.ndarray, list[int]]:
    """The record's prior's part of the stage's error, for a linear-Gaussian posterior ``P`` (Bayes' rule).

    ``x̂ − t = P P0⁻¹ (x0 − t) + P Λ (x_data − t)``: the first term is the prior's pull, fixed by the residual
    ``t − x0`` the seed drew; drawn from ``N(0, P0)`` it has the covariance ``P P0⁻¹ P``.  The second is the data's
    noise, of covariance ``P − P P0⁻¹ P`` when ``P`` is right.

    Returns
    -------
    pull : ndarray
        ``P P0⁻¹ (x0 − t)`` on the fit's terms [SI] (``P0`` block-diagonal: only the prior's terms pull).
    variance : ndarray
        The diagonal of ``P P0⁻¹ P`` [SI²].
    held : list of int
        Positions of the terms the prior holds (whose residuals the seed drew).
    """
    ids = tuple(t.id for t in fit.terms)
    held = [k for k, i in enumerate(ids) if i in prior.ids]
    p0 = np.diag(prior.covariance)[[prior.ids.index(ids[k]) for k in held]]
    x0 = np.array([prior.values[ids[k]] for k in held])
    gain = fit.covariance[:, held] / p0  # P P0⁻¹ on the prior's terms
    return gain @ (x0 - true[held]), np.einsum("ij,j,ij->i", gain, p0, gain), held


def prior_record(truth: Truth) -> CalibrationRecord:
    """:func:`unit_prior` as the calibration record the INS runs with (a device-level record: the installed values)."""
    terms = tuple(CORE_TERMS) + tuple(GIMBAL_TERMS)
    prior = unit_prior(truth)
    values = np.array([float(truth.installed_calibration.get(t.id, t.reference)) for t in terms])
    fit = FitResult("fine", terms, values, prior.covariance, ("estimated",) * len(terms), np.zeros(0), np.zeros(0))
    return CalibrationRecord.from_fit_result(fit, serial_number=truth.site.serial_number, noise_model=prior.noise_model)
