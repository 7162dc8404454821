r"""The gyro drift in the system stage: what is removed from pitch and roll, and what goes into the update.

docs/system-calibration.md §9.  Order in the stage (:mod:`.stage`):

1. :func:`drift_step` after the pass: the drift the gimbal readings measure (:func:`.gyro_drift.fit_gimbal_drift`),
   combined with a drift given to the stage (``SystemOptions.known_gyro_drift``; with
   ``gyro_drift_uncertainty`` a measurement of its own, without it a value held exactly);
2. the attitude fit removes the loop's response to that drift ``ε_0`` from pitch and roll
   (:meth:`.loop.DampingLoop.drift_responses`), and :func:`attitude_drift_jacobian` gives
   ``J = ∂(attitude coefficients)/∂ε``, so the attitude coefficients carry ``J P Jᵀ`` of the drift's covariance ``P``
   (the combined coefficients and the data-only separation);
3. the likelihood of the update (:func:`augment_measurement`): the drift is a parameter of it, seen by the attitude
   coefficients through ``J (ε − ε_0)`` and by the gimbal readings directly (``ε̂ = ε + e``, covariance ``P``,
   independent of the accelerometer noise): the joint likelihood of the accelerometer residuals and ``ε^p``, so the
   record gets ``gyro_drift_x/y/z`` with σ and their correlation with the accelerometer terms.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, replace
from enum import StrEnum
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from stableins.conventions import ARCSEC, DEG_PER_HOUR, EARTH_RATE, GimbalConfiguration
from stableins.estimators.system.attitude import AttitudeModel, fit_attitude
from stableins.estimators.system.gyro_drift import DRIFT_IDS, INNER_OFFSET_SIGMA, GimbalBlocks, GimbalDrift, fit_gimbal_drift
from stableins.estimators.system.loop import DRIFT_SCALE, DampingLoop, drift_columns
from stableins.site import SiteMetadata

if TYPE_CHECKING:
    from stableins.estimators.system.accumulate import RecordSums
    from stableins.estimators.system.options import SystemOptions

#: Span of gimbal readings below which the drift is not estimated [s] (the stage's shortest record, 4 h).
MINIMUM_SPAN = 4 * 3600.0
#: Blocks of gimbal readings below which the drift is not estimated (13 parameters are fitted to them).
MINIMUM_BLOCKS = 100


class DriftSource(StrEnum):
    """Where the drift removed from pitch and roll comes from (:attr:`DriftStep.source`)."""

    #: Measured by the gimbal readings of this record.
    GIMBALS = "gimbal readings"
    #: Given to the stage with an uncertainty, combined with the gimbal readings' measurement.
    GIVEN_AND_GIMBALS = "given and gimbal readings"
    #: Given with an uncertainty, no gimbal measurement (not a parameter of the update; its σ is propagated).
    GIVEN_UNCERTAIN = "given with uncertainty"
    #: Given without an uncertainty: held exactly, not updated.
    GIVEN = "given"
    #: Neither given nor measured: assumed zero.
    NONE = "none"


@dataclass(frozen=True)
class DriftStep:
    """The drift ``ε_0`` the attitude fit removes and what the stage knows of it.

    Attributes
    ----------
    values : ndarray, shape (3,)
        ``ε_0`` [rad/s] (platform x, y, z).
    covariance : ndarray (3, 3) or None
        Its covariance; None when held exactly (given without uncertainty) or assumed zero.
    source : DriftSource
    gimbal : GimbalDrift or None
        The gimbal readings' own measurement (None without inner and middle readings, or when not estimated).
    in_likelihood : bool
        The drift is a parameter of the stage's likelihood (measured by this record).
    notes : tuple of str
    g_sensitivity : ndarray (3, 3) or None
        The prior's gyro g-sensitivity ``D_g`` [rad/s per m/s²] (row: gyro axis, column: specific-force axis), whose
        Earth-rate drift's loop response is removed from pitch and roll (:func:`g_sensitivity_removed`); None without.
    """

    values: NDArray[np.float64]
    covariance: NDArray[np.float64] | None
    source: DriftSource
    gimbal: GimbalDrift | None
    in_likelihood: bool
    notes: tuple[str, ...] = ()
    g_sensitivity: NDArray[np.float64] | None = None


def _deg_h(values: NDArray[np.float64]) -> str:
    return "(" + ", ".join(f"{v / DEG_PER_HOUR:+.2e}" for v in values) + ") deg/h"


def measure_gimbals(
    sums: RecordSums,
    metadata: SiteMetadata,
    prior: Mapping[str, float],
    prior_covariance: Mapping[tuple[str, str], float] | None,
    *,
    latitude: float,
) -> GimbalDrift | None:
    """Fit the gimbal readings (:func:`.gyro_drift.fit_gimbal_drift`); None without them or when too few or too short.

    The prior's σ of θ20 (the inner-gimbal zero offset) is the prior of its residual in the fit (nominal 60″ without).
    """
    from typing import cast

    blocks = sums.gimbal_blocks
    if blocks is None:
        return None
    means = blocks.means()
    if means["time"].size < MINIMUM_BLOCKS or means["time"][-1] - means["time"][0] < MINIMUM_SPAN:
        return None
    return fit_gimbal_drift(
        means,
        latitude,
        GimbalConfiguration(cast("tuple[int, int, int, int]", tuple(metadata.gimbal_senses))),
        offsets=np.array([float(prior.get(k, 0.0)) for k in ("theta10", "theta20", "theta30")]),
        base_attitude=cast("tuple[float, float, float]", tuple(float(a) for a in (metadata.base_attitude or (0.0, 0.0, 0.0)))),
        inner_offset_sigma=_offset_sigma(prior_covariance),
    )


def drift_step(
    sums: RecordSums,
    metadata: SiteMetadata,
    prior: Mapping[str, float],
    prior_covariance: Mapping[tuple[str, str], float] | None,
    *,
    latitude: float,
    options: SystemOptions,
) -> DriftStep:
    """Measure the drift in the gimbal readings and combine it with a given one (module docstring, step 1).

    The gimbal fit is :func:`measure_gimbals` (only with ``options.estimate_gyro_drift``); the step carries the prior's
    ``D_g`` (:func:`prior_g_sensitivity`).
    """
    g_sensitivity = prior_g_sensitivity(prior)
    step = _drift_step(sums, metadata, prior, prior_covariance, latitude=latitude, options=options, g_sensitivity=g_sensitivity)
    if g_sensitivity is None:
        return step
    note = (
        "the loop's response to the Earth-rate part of the record's gyro g-sensitivity D_g (its drift D_g f^p turns at the "
        "Earth rate about z_p) is removed from pitch and roll; the constant part D_g f_z is in the measured drift"
    )
    return replace(step, g_sensitivity=g_sensitivity, notes=(*step.notes, note))


def prior_g_sensitivity(prior: Mapping[str, float]) -> NDArray[np.float64] | None:
    """Return the prior's ``D_g`` (3, 3) [rad/s per m/s²] from ``Dg_ab`` (gyro ``a``, specific force ``b``); None when all are 0."""
    values = np.array([[float(prior.get(f"Dg_{a}{b}", 0.0)) for b in "xyz"] for a in "xyz"])
    return values if np.any(values) else None


def g_sensitivity_removed(
    blocks: dict[str, NDArray[np.float64]], loop: DampingLoop, g_sensitivity: NDArray[np.float64] | None
) -> dict[str, NDArray[np.float64]]:
    """Return the attitude blocks with the loop's response to the Earth-rate part of the g-sensitive drift removed.

    On the polar-aligned platform ``f^p = g (cos L cos S, cos L sin S, sin L)``, so the gyro error ``D_g f^p`` is the
    constant ``g sin L D_g e_z`` (a constant drift: the gimbal readings measure it with ``ε^p``) plus
    ``g cos L (D_g e_x cos S + D_g e_y sin S)``, a drift turning at the Earth rate in the platform frame, which drives the
    loop like the equatorial drift (Britting's Earth-rate mode) and which the gimbal fit's harmonic nuisances absorb: its
    response (:meth:`.loop.DampingLoop.drift_responses` with these rates) is removed here, from the record's ``D_g``
    (0.001 °/h/g moves the pitch coefficients by about 0.6σ of one day; a D_g known to 10 % leaves 0.06σ).
    """
    if g_sensitivity is None:
        return blocks
    d = g_sensitivity
    scale = loop.gravity * math.cos(loop.latitude)

    def rates(angle: NDArray[np.float64]) -> NDArray[np.float64]:
        return scale * (np.cos(angle)[:, None] * d[:, 0] + np.sin(angle)[:, None] * d[:, 1])

    response = drift_columns(blocks, loop, rates=rates).sum(axis=2) / DRIFT_SCALE
    out = dict(blocks)
    out["pitch"] = blocks["pitch"] - response[:, 0]
    out["roll"] = blocks["roll"] - response[:, 1]
    return out


def _drift_step(
    sums: RecordSums,
    metadata: SiteMetadata,
    prior: Mapping[str, float],
    prior_covariance: Mapping[tuple[str, str], float] | None,
    *,
    latitude: float,
    options: SystemOptions,
    g_sensitivity: NDArray[np.float64] | None,
) -> DriftStep:
    """:func:`drift_step` but for the prior's ``D_g`` in the step (its wobble's σ is in the gimbal measurement's)."""
    gimbal = None
    notes: list[str] = []
    if options.estimate_gyro_drift:
        gimbal = measure_gimbals(sums, metadata, prior, prior_covariance, latitude=latitude)
        if gimbal is not None:
            gimbal = _with_wobble(gimbal, g_sensitivity, metadata.gravity)
            notes.append(_gimbal_note(gimbal))
    given = None if options.known_gyro_drift is None else np.asarray(options.known_gyro_drift, dtype=float)
    uncertainty = options.gyro_drift_uncertainty
    if given is not None and (uncertainty is None or uncertainty == 0.0):
        if gimbal is not None:
            z = (gimbal.values - given) / gimbal.sigma
            notes.append(
                f"the given gyro drift {_deg_h(given)} is held exactly (no uncertainty given); the gimbal readings measure "
                f"{_deg_h(gimbal.values)}, {np.abs(z).max():.1f} sigma from it at most"
            )
        return DriftStep(given, None, DriftSource.GIVEN, gimbal, False, tuple(notes))
    if given is not None:
        assert uncertainty is not None
        given_information = np.eye(3) / uncertainty**2
        if gimbal is None:
            return DriftStep(given, np.eye(3) * uncertainty**2, DriftSource.GIVEN_UNCERTAIN, None, False, tuple(notes))
        information = np.linalg.inv(gimbal.covariance) + given_information
        covariance = np.linalg.inv(information)
        values = covariance @ (np.linalg.solve(gimbal.covariance, gimbal.values) + given_information @ given)
        notes.append(
            f"the given gyro drift {_deg_h(given)} ± {uncertainty / DEG_PER_HOUR:.1e} deg/h is combined with the gimbal readings' "
            f"measurement (information-weighted): {_deg_h(values)}"
        )
        return DriftStep(values, 0.5 * (covariance + covariance.T), DriftSource.GIVEN_AND_GIMBALS, gimbal, True, tuple(notes))
    if gimbal is not None:
        return DriftStep(gimbal.values, gimbal.covariance, DriftSource.GIMBALS, gimbal, True, tuple(notes))
    return DriftStep(np.zeros(3), None, DriftSource.NONE, None, False, tuple(notes))


def wobble_sigma(gimbal: GimbalDrift, g_sensitivity: NDArray[np.float64], gravity: float) -> float:
    """σ added to ``ε_x``, ``ε_y`` by the g-sensitive wobble read with a z_p drift [rad/s]: ``|ε_z| g cos L ‖D_eq‖ / ω_ie``.

    The Earth-rate part of ``D_g f^p`` (:func:`g_sensitivity_removed`) tilts the platform by ``H(t)``, amplitude
    ``A = g cos L ‖D_eq‖ / ω_ie`` (``D_eq`` the equatorial 2×2 block, ‖·‖ its largest singular value: 5e-5 rad for
    0.001 °/h/g), with a mean offset from the record's start of up to ``A``; the z_p drift then turns the platform about
    an axis tilted by it, which the gimbal fit (its reference the start, its nuisances base-fixed) reads as an equatorial
    drift of up to ``ε_z A`` (measured: 0.92 ε_z A, 2.4e-6 °/h for 0.05 °/h and 0.001 °/h/g, 30× the readings' σ;
    docs/system-calibration.md §9).  Not modelled: its size is its σ.
    """
    amplitude = gravity * math.cos(gimbal.latitude) * float(np.linalg.svd(g_sensitivity[:2, :2], compute_uv=False)[0]) / EARTH_RATE
    return abs(float(gimbal.values[2])) * amplitude


def _with_wobble(gimbal: GimbalDrift, g_sensitivity: NDArray[np.float64] | None, gravity: float | None) -> GimbalDrift:
    """Return the gimbal measurement with :func:`wobble_sigma` added to the variance of ``ε_x``, ``ε_y``."""
    if g_sensitivity is None or gravity is None:
        return gimbal
    variance = wobble_sigma(gimbal, g_sensitivity, gravity) ** 2
    return replace(gimbal, covariance=gimbal.covariance + np.diag([variance, variance, 0.0]))


def _offset_sigma(prior_covariance: Mapping[tuple[str, str], float] | None) -> float:
    """Return the prior σ of the inner-gimbal zero offset θ20 [rad] (its nominal magnitude when the prior has none)."""
    variance = None if prior_covariance is None else prior_covariance.get(("theta20", "theta20"))
    if variance is not None and math.isfinite(variance) and variance > 0:
        return math.sqrt(variance)
    return INNER_OFFSET_SIGMA


def _gimbal_note(gimbal: GimbalDrift) -> str:
    """Return the note on the drift the gimbal readings measure."""
    text = (
        f"{gimbal.describe()}; measured from the platform's orientation in inertial space (exact inverse kinematics of the "
        f"readings, {gimbal.blocks} blocks) with the base rotation ({np.linalg.norm(gimbal.base_rotation) / ARCSEC:.1f} arcsec), "
        "the platform-axis sensor's once-per-revolution error and the initial orientation as nuisances"
    )
    if gimbal.low_frequency_ratio > 1.0:
        text += f"; residuals on hour bins {gimbal.low_frequency_ratio:.2f}x the white-noise level"
    return text


def attitude_drift_jacobian(
    blocks: dict[str, NDArray[np.float64]],
    loop: DampingLoop,
    noise_sigma: tuple[float, float],
    options: SystemOptions,
    map_bin_seconds: float,
) -> NDArray[np.float64]:
    """``J = ∂(attitude coefficients)/∂ε`` (10, 3) [rad per rad/s]: the attitude fit of the loop's response to each unit drift.

    The fit is linear in pitch and roll, so ``J e_j`` is the fit (same columns, loop compensation and case-rotation
    terms as the stage's) of the response to a unit drift along platform axis ``j`` (:func:`.loop.drift_columns`).
    """
    responses = drift_columns(blocks, loop) / DRIFT_SCALE
    out = np.zeros((10, 3))
    for j in range(3):
        unit = dict(blocks)
        unit["pitch"], unit["roll"] = responses[:, 0, j], responses[:, 1, j]
        model = AttitudeModel(loop, options.case_rotation_period, compensate_loop=options.compensate_loop)
        fit = fit_attitude(unit, model, noise_sigma, scale_low_frequency=False, map_bin_seconds=map_bin_seconds)
        out[:, j] = fit.values
    return out


def sensor_error_removed(
    blocks: dict[str, NDArray[np.float64]], gimbal_blocks: GimbalBlocks | None, gimbal: GimbalDrift | None, latitude: float
) -> dict[str, NDArray[np.float64]]:
    """Return the attitude blocks with the platform-axis sensor's once-per-revolution error taken out of roll.

    The navigation computer builds the attitude from the readings: an error ``h(t) = h_c cos r_1 + h_s sin r_1`` of the
    platform-axis reading turns ``Ĉ_b^p`` by ``h`` about ``z_p`` (:func:`.gyro_drift.fit_gimbal_drift` measures it),
    so ``C_b^{n'} = rot(h u) C_b^n`` with ``u = C_p^n e_z`` the Earth's axis ``(cos L, 0, −sin L)``: ``φ = h u``, and
    the north-pointing pair ``(−φ_E, −φ_N)`` is ``(0, −h cos L)``.  It is an output error, not through the loop, at
    exactly the Earth rate: left in, it moves φ1s, φ1c by up to ``h cos L`` (7e-6 rad for 2″).  Its uncertainty from
    the gimbal fit (a few 1e-9 rad) is neglected.  The platform reading at the attitude blocks' times is interpolated
    from the gimbal blocks (it is linear in time).
    """
    if gimbal is None or gimbal_blocks is None:
        return blocks
    readings = gimbal_blocks.means()
    platform = np.interp(blocks["time"], readings["time"], readings["platform"])
    h = gimbal.sensor_error[0] * np.cos(platform) + gimbal.sensor_error[1] * np.sin(platform)
    out = dict(blocks)
    out["roll"] = blocks["roll"] + math.cos(latitude) * h
    return out


def drift_covariance_v(jacobian: NDArray[np.float64] | None, step: DriftStep) -> NDArray[np.float64]:
    """Return the drift's contribution to the covariance of ``v = (x1..x7, attitude)`` (17, 17): ``J P Jᵀ`` on the attitude block.

    The values carry ``−J ε_0`` and the data ``J ε``: their error from the drift is ``J (ε − ε_0)``.
    """
    out = np.zeros((17, 17))
    if jacobian is not None and step.covariance is not None:
        out[7:, 7:] = jacobian @ step.covariance @ jacobian.T
    return out


def likelihood_inputs(
    step: DriftStep, jacobian: NDArray[np.float64] | None, cov_v: NDArray[np.float64]
) -> tuple[NDArray[np.float64], tuple[NDArray[np.float64], DriftStep] | None]:
    """Return the covariance of ``v`` and the drift argument of :func:`.assembly.separation_likelihood`.

    A drift the record measured is a parameter of the likelihood (``(J, step)``, covariance of ``v`` unchanged); a drift
    given with an uncertainty and not measured only adds ``J P Jᵀ`` to the attitude coefficients.
    """
    if step.in_likelihood and jacobian is not None:
        return cov_v, (jacobian, step)
    return cov_v + drift_covariance_v(jacobian, step), None


def augment_measurement(
    rows: NDArray[np.float64],
    h_res: NDArray[np.float64],
    h_nuisance: NDArray[np.float64],
    cov_w: NDArray[np.float64],
    w: NDArray[np.float64],
    *,
    jacobian: NDArray[np.float64],
    step: DriftStep,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Add the drift to the stage's measurement model (module docstring, step 3); linearized at ``ε = ε_0``.

    ``w = rows v`` measures ``H q + H_n n + rows J_v (ε − ε_0)``; three more rows, ``ε̂ − ε_0 = (ε − ε_0) + e``, with the
    drift's covariance (independent of the accelerometer noise).  Returns ``(h_res, h_nuisance, cov_w, w)`` extended:
    three columns of ``h_res`` (after the existing ones) and three rows, and the scale ``s`` of the three new parameters
    (``ε = ε_0 + s q``, ``s`` the drift's σ, so that their whitened columns are of order one like the others').
    """
    assert step.covariance is not None
    scale = np.sqrt(np.diag(step.covariance))
    j_v = np.zeros((17, 3))
    j_v[7:] = jacobian  # v = (fit of the data) − J ε_0 and the data carry J ε: v moves by J (ε − ε_0)
    k, m = h_res.shape
    h = np.zeros((k + 3, m + 3))
    h[:k, :m], h[:k, m:], h[k:, m:] = h_res, (rows @ j_v) * scale, np.diag(scale)
    h_n = np.vstack([h_nuisance, np.zeros((3, h_nuisance.shape[1]))])
    cov = np.zeros((k + 3, k + 3))
    cov[:k, :k], cov[k:, k:] = cov_w, step.covariance
    return h, h_n, cov, np.concatenate([w, np.zeros(3)]), scale


def drift_notes(step: DriftStep) -> list[str]:
    """Return the standing note when the drift is neither measured nor given (the attitude coefficients assume none)."""
    if step.source is not DriftSource.NONE:
        return []
    from stableins.estimators.system.options import GYRO_DRIFT_PARAMETER

    why = "the record has no inner and middle gimbal readings to measure it" if step.gimbal is None else "it was not estimated"
    return [
        f"gyro drift not supplied and not measured ({why}): the attitude coefficients assume none.  A constant drift of 0.001 "
        "deg/h along a platform axis drives the loop's undamped Earth-rate mode and biases them by up to 1.9e-5 rad (x1..x5 do "
        "not see it).  Record the inner and middle gimbal readings, or supply the drift in the platform frame from the gyro "
        f"calibration ({GYRO_DRIFT_PARAMETER}) for unbiased attitude coefficients"
    ]


def prior_drift(
    prior: Mapping[str, float], covariance: Mapping[tuple[str, str], float] | None
) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
    """Return the prior's drift (values, covariance) when it states all three with finite positive variances, else None."""
    if covariance is None or not all(i in prior for i in DRIFT_IDS):
        return None
    cov = np.array([[covariance.get((a, b), 0.0 if a != b else math.nan) for b in DRIFT_IDS] for a in DRIFT_IDS], dtype=float)
    if not np.isfinite(cov).all() or not (np.diag(cov) > 0).all():
        return None
    return np.array([float(prior[i]) for i in DRIFT_IDS]), 0.5 * (cov + cov.T)


__all__ = [
    "MINIMUM_BLOCKS",
    "MINIMUM_SPAN",
    "DriftSource",
    "DriftStep",
    "attitude_drift_jacobian",
    "augment_measurement",
    "drift_covariance_v",
    "drift_notes",
    "drift_step",
    "g_sensitivity_removed",
    "measure_gimbals",
    "prior_g_sensitivity",
    "wobble_sigma",
    "likelihood_inputs",
    "prior_drift",
]
