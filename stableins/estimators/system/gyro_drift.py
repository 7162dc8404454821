r"""The constant gyro drift ``ε^p`` from a system record: the gimbal readings through the exact inverse kinematics.

docs/system-calibration.md §9.  A space-stable platform is held fixed in inertial space by its gyros; a gyro drift
``ε^p`` (output error, constant in the platform frame) turns it at ``−ε^p``, so the platform's orientation relative
to inertial space, read from the gimbal angles, carries the ramp ``−ε^p t``.

The measurement
---------------
With ``C_b^p(α)`` the exact gimbal kinematics of the readings plus the installed zero offsets
(:func:`stableins.conventions.dcm_body_to_platform`), ``C_n^b`` the surveyed base attitude and
``E(t) = C_{n(t)}^{n_0} = exp(ω_ie t [u×])`` (``u`` the Earth's axis in NED) the turn of the local frame since the
record start,

.. math:: Q(t) = C_b^p(α(t))\, C_n^b\, E(t)^T = C_{p_0}^{p}(t)\, C_{n_0}^{p_0}

is constant for a platform held in inertial space; a drift makes ``C_{p_0}^p(t) = \mathrm{rot}(−ε^p t)`` (frame
rotation, :func:`stableins.platform.rotation_about`).  The error vector ``e(t)`` with
``Q(t) Q_{ref}^T = \mathrm{rot}(e(t))`` is, exactly for a pure drift, ``e = −ε^p t``.

The nuisances (each a physical effect of a real platform, all in the truth simulator)
-------------------------------------------------------------------------------------
* the initial orientation ``Q(0)`` (polar-alignment error, platform-axis zero offset): a constant ``c`` in ``e``;
* a constant rotation ``ω_b`` of everything fixed to the base (base tilt and azimuth error, residual zero offsets of
  the inner and middle gimbals, gimbal non-orthogonality): ``C_b^p(α_true) = C_b^p(α) \mathrm{rot}(ω_b)`` turns into
  ``e += C_b^p(t) ω_b`` (``M \mathrm{rot}(v) M^T = \mathrm{rot}(M v)``), a vector turning with the Earth-rate angle
  about ``z_p``; its polar component is a constant (the same as ``c_z``), so two equatorial components are fitted;
* the once-per-revolution error of the platform-axis angle sensor, ``c_1 \cos r_1 + s_1 \sin r_1`` (the reading
  sweeps a turn per sidereal day): a rotation about ``z_p`` on the left, ``e_z += h_c \cos r_1 + h_s \sin r_1``.  The
  inner and middle readings stand still, so their sensor errors are constant offsets (part of ``ω_b``);
* with the record's g-sensitivity ``D_g``, the platform's turn by ``−D_g f^p`` (a wobble at the Earth rate and a
  constant rate): composed out of the readings exactly (:func:`g_sensitive_turn`), the errors of ``D_g`` as nuisances
  with the record's σ (:func:`g_sensitive_columns`); the drift returned is the one the record sees, ``ε^p + D_g f̄^p``.

Model, per block mean of the readings (10-s attitude blocks, at the attitude decimation):
``e(t_k) = c + C_b^p(t_k) P ω + (h_c \cos r_{1k} + h_s \sin r_{1k}) e_z − ε^p t_k + n_k`` (``P``: two body vectors
normal to the Earth's axis).  Products of the nuisances with the ramp (``½ ε t × ω`` ~ 1e-8 rad for 0.001 °/h and 10″)
are removed by iterating: each pass removes the fitted rotations exactly from the matrices and fits again.

Over one sidereal day the ramp is correlated with the Earth-rate harmonic ``sin S`` (``−√24/2π = −0.78``): σ(ε) is
``1/√(1 − 0.61) = 1.6`` times that of a ramp alone, ``σ_ε = 1.6 σ_e √(12/(N T²))``.  With the simulator's default
0.2″ of white angle noise at 1 Hz: about 5e-8 °/h per axis.  The noise σ of each axis is the weighted residual rms
(white noise assumed: the readings' noise is the angle sensors'); the residuals' variance on hour-long bins is checked
against it (:attr:`GimbalDrift.low_frequency_ratio`) and σ is scaled by it when the excess is significant.

The drift in the stage
----------------------
The gyro drift in the system stage: what is removed from pitch and roll, and what goes into the update.

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

from stableins.conventions import (
    ARCSEC,
    DEG_PER_HOUR,
    EARTH_RATE,
    R2,
    GimbalConfiguration,
    dcm_body_to_platform,
    dcm_nav_to_body,
    earth_rate_nav,
    skew,
)
from stableins.estimators.system.attitude import AttitudeModel, fit_attitude
from stableins.estimators.system.blocks import GimbalBlocks
from stableins.estimators.system.loop import DRIFT_SCALE, DampingLoop, drift_columns
from stableins.platform import rotation_about, rotation_vector
from stableins.site import SiteMetadata

if TYPE_CHECKING:
    from stableins.estimators.system.accumulate import RecordSums
    from stableins.estimators.system.options import SystemOptions


#: Names of the three drift parameters (platform axes x, y, z), as the record holds them.
DRIFT_IDS = ("gyro_drift_x", "gyro_drift_y", "gyro_drift_z")

#: Width of the bins on which the residuals' low-frequency variance is checked [s].
CHECK_BIN_SECONDS = 3600.0

#: Default prior σ of the inner-gimbal zero offset's residual [rad] (the nominal magnitude of θ20, 60″).
INNER_OFFSET_SIGMA = 60.0 * ARCSEC

#: Prior σ of the local slope of the inner and middle angle sensors' errors [rad/rad]: a once-per-revolution error of
#: amplitude A has slopes up to A (2″, the magnitude of the simulator's effects ``ang1_<gimbal>_c|s``).
SLOPE_SIGMA = 2.0 * ARCSEC

#: Passes of the fit (each removes the fitted nuisances exactly; on noise-free simulator readings the fourth pass
#: leaves residuals below 3e-10 rad rms).
PASSES = 4

#: Smallest σ of one decimated sample of the error vector [rad]: the accuracy of the model on noise-free readings
#: (about 3e-10 rad rms, see :data:`PASSES`), so that a record without angle noise does not claim more.
SIGMA_FLOOR = 1e-9


@dataclass(frozen=True)
class GimbalDrift:
    """The drift the gimbal readings measure (:func:`fit_gimbal_drift`).

    Attributes
    ----------
    values : ndarray, shape (3,)
        ``ε^p`` [rad/s] (platform x, y, z).
    covariance : ndarray, shape (3, 3)
        Its covariance [(rad/s)²].
    noise_sigma : ndarray, shape (3,)
        Per-axis σ of one decimated sample of the error vector ``e`` [rad] (from the residuals).
    base_rotation : ndarray, shape (3,)
        The fitted constant rotation of the base-fixed chain ``ω_b`` [rad] (body frame; its polar part is not
        separable from the initial orientation and is zero here).
    sensor_error : ndarray, shape (2,)
        Once-per-revolution error of the platform-axis sensor ``(h_c, h_s)`` as seen about ``z_p`` [rad].
    residual_rms : ndarray, shape (3,)
        rms of the block residuals per axis [rad].
    low_frequency_ratio : float
        Variance of the residuals on :data:`CHECK_BIN_SECONDS` bins over its white-noise expectation (≈ 1; σ is
        scaled by it when it is significantly larger).
    blocks : int
        Blocks fitted.
    orientation : ndarray, shape (3, 3)
        The platform's orientation in inertial space at ``t = 0``, ``C_{n_0}^{p}`` with the nuisances removed (the
        reference the fit converged to).
    latitude : float
        [rad] (the Earth's axis in ``n_0``).
    span : tuple of float
        First and last block time [s].
    orientation_sigma : ndarray, shape (3,)
        1σ of the orientation's constant ``c`` per axis [rad] (platform frame).
    """

    values: NDArray[np.float64]
    covariance: NDArray[np.float64]
    noise_sigma: NDArray[np.float64]
    base_rotation: NDArray[np.float64]
    sensor_error: NDArray[np.float64]
    residual_rms: NDArray[np.float64]
    low_frequency_ratio: float
    blocks: int
    orientation: NDArray[np.float64]
    latitude: float
    span: tuple[float, float]
    orientation_sigma: NDArray[np.float64]

    @property
    def sigma(self) -> NDArray[np.float64]:
        """1σ per axis [rad/s]."""
        return np.sqrt(np.diag(self.covariance))

    def earth_axis(self, time: NDArray[np.float64]) -> NDArray[np.float64]:
        """Return the Earth's axis in the platform frame at ``time`` [s] (n, 3): ``rot(−ε t) C_{n_0}^p (cos L, 0, −sin L)``.

        ``(0, 0, 1)`` on a polar-aligned platform; its x, y components are the polar misalignment of z_p (docs §9).
        """
        axis = self.orientation @ (earth_rate_nav(self.latitude) / EARTH_RATE)
        turn = rotation_about(-np.outer(np.atleast_1d(np.asarray(time, dtype=float)), self.values))
        return np.asarray(turn @ axis)

    def describe(self) -> str:
        """One line in °/h."""
        v, s = self.values / DEG_PER_HOUR, self.sigma / DEG_PER_HOUR
        parts = ", ".join(f"{a} {v[i]:+.2e} ± {s[i]:.1e}" for i, a in enumerate("xyz"))
        return f"gyro drift from the gimbal readings (deg/h, platform axes): {parts}"


def earth_turn(time: NDArray[np.float64], latitude: float) -> NDArray[np.float64]:
    """``E(t) = C_{n(t)}^{n_0} = exp(ω_ie t [u×])`` (n, 3, 3): the local frame's turn with the Earth since ``t = 0``."""
    k = skew(earth_rate_nav(latitude) / EARTH_RATE)
    angle = EARTH_RATE * np.asarray(time, dtype=float)
    return np.eye(3) + np.sin(angle)[:, None, None] * k + (1.0 - np.cos(angle))[:, None, None] * (k @ k)


def fit_gimbal_drift(
    blocks: Mapping[str, NDArray[np.float64]],
    latitude: float,
    configuration: GimbalConfiguration,
    *,
    offsets: NDArray[np.float64] | tuple[float, float, float] = (0.0, 0.0, 0.0),
    base_attitude: tuple[float, float, float] = (0.0, 0.0, 0.0),
    inner_offset_sigma: float = INNER_OFFSET_SIGMA,
    g_sensitivity: NDArray[np.float64] | None = None,
    g_sensitivity_sigma: NDArray[np.float64] | None = None,
    gravity: float = 0.0,
) -> GimbalDrift:
    """Fit ``ε^p`` and the nuisances to the block means of the gimbal readings (module docstring).

    Parameters
    ----------
    blocks : mapping
        :meth:`GimbalBlocks.means` (``time`` since the record start [s], readings [rad], ``count``).
    latitude : float
        [rad].
    configuration : GimbalConfiguration
        Gimbal senses.
    offsets : sequence of 3 float
        Installed zero offsets θ10, θ20, θ30 [rad] (added to the readings).
    base_attitude : (yaw, pitch, roll)
        Surveyed base attitude [rad].
    inner_offset_sigma : float
        Prior σ of the inner-gimbal zero offset's residual ``d_2`` [rad] (the record's σ of θ20).
    g_sensitivity, g_sensitivity_sigma : ndarray (3, 3), optional
        The record's ``D_g`` and its σ [rad/s per m/s²]: the platform's turn by the g-sensitive drift is composed out of
        the readings (:func:`g_sensitive_turn`) and the σ of its equatorial columns are the prior of nuisances
        (:func:`g_sensitive_columns`); the drift returned is the one the record sees, ``ε^p + D_g f̄^p``
        (``f̄^p`` the specific force along the Earth's axis).
    gravity : float
        [m/s²] (with ``g_sensitivity``).
    """
    t = np.asarray(blocks["time"], dtype=float)
    weight = np.asarray(blocks["count"], dtype=float)
    readings = np.stack([blocks["platform"], blocks["inner"], blocks["middle"]], axis=1)
    angles = readings + np.asarray(offsets, dtype=float)
    c_bp = dcm_body_to_platform(angles[:, 0], angles[:, 1], angles[:, 2], 0.0, configuration)
    q = c_bp @ dcm_nav_to_body(*base_attitude) @ earth_turn(t, latitude).swapaxes(1, 2)
    # two body-frame directions normal to the Earth's axis (the polar part of ω_b is the constant c_z)
    polar_body = c_bp.swapaxes(1, 2)[:, :, 2].mean(axis=0)
    polar_body /= np.linalg.norm(polar_body)
    basis = np.linalg.svd(np.eye(3) - np.outer(polar_body, polar_body))[0][:, :2]
    reference = q[0]
    omega_b, sensor, inner, slopes = np.zeros(3), np.zeros(2), 0.0, np.zeros(2)
    cos_r, sin_r = np.cos(readings[:, 0]), np.sin(readings[:, 0])
    s2, s3 = configuration.senses[1], configuration.senses[2]
    # the inner gimbal's axis in the body frame, R2(s3 α3)ᵀ e_x: it moves with the middle angle, a base rotation does not
    inner_body = R2(s3 * angles[:, 2]).swapaxes(1, 2)[:, :, 0]
    inner_reference = inner_body.mean(axis=0)
    # the inner and middle angles move a little (the drift tilts the platform): a sensor error's local slope scales that
    moved = angles[:, 1:] - angles[:, 1:].mean(axis=0)
    column_prior = g_sensitivity_sigma if g_sensitivity is not None else None  # the D_g errors' σ when its turn is composed out
    columns, column_sigma = np.zeros((t.size, 3, 0)), np.zeros(0)
    if column_prior is not None:  # the first pass's columns (its drift 0, its reference the start's)
        columns, column_sigma = g_sensitive_columns(
            t, latitude, reference=reference, gravity=gravity, sigma=column_prior, drift=np.zeros(3)
        )
    extra = column_sigma.size
    prior = np.diag(np.r_[np.zeros(10), 1.0 / inner_offset_sigma**2, np.full(2, 1.0 / SLOPE_SIGMA**2), 1.0 / column_sigma**2])
    sigma = np.ones(3)
    fit = None
    drift = np.zeros(3)
    for iteration in range(PASSES):
        # remove the fitted nuisances exactly: the inner offset inside the chain, base-fixed ω_b on the right, the z_p
        # sensor error on the left
        inner_angle = angles[:, 1] + inner + slopes[0] * moved[:, 0]
        middle_angle = angles[:, 2] + slopes[1] * moved[:, 1]
        c_true = dcm_body_to_platform(angles[:, 0], inner_angle, middle_angle, 0.0, configuration) @ rotation_about(omega_b).T
        z_turn = rotation_about(np.outer(sensor[0] * cos_r + sensor[1] * sin_r, [0.0, 0.0, 1.0]))
        q = z_turn.swapaxes(1, 2) @ c_true @ dcm_nav_to_body(*base_attitude) @ earth_turn(t, latitude).swapaxes(1, 2)
        if g_sensitivity is None:
            e = rotation_vector(q @ reference.T)
        else:  # X = rot(−ε t) Z: the g-sensitive turn Z composed out on the right (in the frame of the start)
            turn = g_sensitive_turn(t, latitude, reference=reference, gravity=gravity, g_sensitivity=g_sensitivity, drift=drift)
            e = rotation_vector(q @ reference.T @ turn.swapaxes(1, 2))
            if column_prior is not None and iteration > 0:  # later passes: the fitted drift and reference
                columns = g_sensitive_columns(t, latitude, reference=reference, gravity=gravity, sigma=column_prior, drift=drift)[0]
        # an inner offset d moves e by −s2 d a_p(t) (a_p = C_b^p b_inner, the axis in the platform frame); taken with the
        # base rotation s2 d b_ref that cancels it to first order, its column is the small s2 C_b^p (b_ref − b_inner(t))
        # an error k·(α − ᾱ) of the inner (middle) angle turns the platform by −s k (α − ᾱ) about that gimbal's axis
        chain = np.stack(
            [
                s2 * np.einsum("nij,nj->ni", c_true, inner_reference - inner_body),
                -s2 * np.einsum("nij,nj->ni", c_true, inner_body) * moved[:, :1],
                -s3 * c_true[:, :, 1] * moved[:, 1:],
            ],
            axis=2,
        )
        design = np.concatenate([_design(t, c_true, basis, cos_r, sin_r, chain=chain), columns], axis=2)
        fit = _solve(design, e, weight, sigma, prior=prior, current=np.r_[np.zeros(10), inner, slopes, np.zeros(extra)])
        beta, sigma = fit[0], fit[2]
        drift = beta[3:6]
        reference = rotation_about(beta[:3]) @ reference
        omega_b = omega_b + basis @ beta[6:8] + s2 * beta[10] * inner_reference
        sensor = sensor + beta[8:10]
        inner += beta[10]
        slopes = slopes + beta[11:13]
    assert fit is not None
    beta, cov, sigma, residuals = fit
    ratio = _low_frequency_ratio(t, residuals, weight, sigma)
    inflation = ratio if ratio > 1.0 + 3.0 * math.sqrt(2.0 / max(_bins(t), 1)) else 1.0
    values = beta[3:6]
    if g_sensitivity is not None:  # the drift the record sees: the turn's constant part back (docstring)
        values = values + g_sensitivity @ _earth_axis_force(latitude, reference, gravity)
    return GimbalDrift(
        values=values,
        covariance=cov[3:6, 3:6] * inflation,
        noise_sigma=sigma,
        base_rotation=omega_b,
        sensor_error=sensor,
        residual_rms=np.sqrt(np.average(residuals**2, axis=0, weights=weight)),
        low_frequency_ratio=ratio,
        blocks=int(t.size),
        orientation=reference,
        latitude=float(latitude),
        span=(float(t[0]), float(t[-1])),
        orientation_sigma=np.sqrt(np.diag(cov[0:3, 0:3]) * inflation),
    )


def _earth_axis_force(latitude: float, reference: NDArray[np.float64], gravity: float) -> NDArray[np.float64]:
    """``f̄^p``: the specific force's component along the Earth's axis in the platform frame at the start [m/s²] (3,)."""
    axis = reference @ (earth_rate_nav(latitude) / EARTH_RATE)
    return float(axis @ (reference @ np.array([0.0, 0.0, -gravity]))) * axis


def _start_force(time: NDArray[np.float64], latitude: float, reference: NDArray[np.float64], gravity: float) -> NDArray[np.float64]:
    """``f^p`` of the platform held at its start orientation ``C_{n_0}^{p_0}`` (reference): ``C_{n_0}^{p_0} E(t) (0, 0, −g)`` (n, 3)."""
    return np.einsum("ij,njk,k->ni", reference, earth_turn(time, latitude), np.array([0.0, 0.0, -gravity]))


#: Step of the grid on which :func:`g_sensitive_turn` integrates the g-sensitive drift [s] (the Earth turns 4.4e-3 rad
#: a step: the trapezoid rule's relative error ``(Ω h)²/12`` is 1.6e-6 of the turn, 8e-11 rad for 0.001 °/h/g).
TURN_STEP = 60.0


def _turn_grid(time: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.intp]]:
    """Return the :data:`TURN_STEP` grid from 0 with the times in it (sorted, unique) and the times' indices in it."""
    end = float(np.max(time)) if time.size else 0.0
    grid, where = np.unique(np.r_[0.0, np.arange(TURN_STEP, end, TURN_STEP), time], return_inverse=True)
    return grid, where[where.size - time.size :]


def g_sensitive_turn(
    time: NDArray[np.float64],
    latitude: float,
    *,
    reference: NDArray[np.float64],
    gravity: float,
    g_sensitivity: NDArray[np.float64],
    drift: NDArray[np.float64],
) -> NDArray[np.float64]:
    r"""Return ``Z(t)`` (n, 3, 3): the platform's turn by its g-sensitive drift, in the frame of its start orientation.

    The platform turns at ``w = −(ε^p + D_g f^p)`` in its own frame (:func:`stableins.conventions.platform_drift_rate`).
    With ``R = rot(−ε^p t)`` (exact for the constant drift) its turn from the start is ``X = R Z``, and
    ``\dot X = −[w×] X`` leaves ``\dot Z = −[(R^T w_g)×] Z``, ``w_g = −D_g f^p``, ``f^p = R Z f_0(t)`` with
    ``f_0(t) = C_{n_0}^{p_0} E(t) (0, 0, −g)`` the specific force of the platform held at its start: the rate is
    ``r = −R^T D_g R Z f_0(t)``, ``Z f_0`` from a predictor with ``f_0`` (``Z``'s angle is the wobble
    ``A = g cosL |D_g|/Ω``, 5e-5 rad for 0.001 °/h/g, and ``D_g (Z − I) f_0`` has a constant part of up to ``|D_g g| A``,
    2.4e-13 rad/s or 5e-8 °/h, the readings' σ; the corrector leaves ``|D_g g| A²``), integrated by the rotation vector's
    second-order equation ``θ' = r + ½ θ × r`` (Bortz 1971: the wobble's coning, ``½ A² Ω`` ≈ 1e-13 rad/s about the
    Earth's axis for 0.001 °/h/g, is in it) with the trapezoid rule on a :data:`TURN_STEP` grid (and the times).
    ``time`` [s] since the record start (``Z(0) = I``); ``drift``: ``ε^p`` [rad/s] without the g-sensitive part.
    """
    grid, where = _turn_grid(time)
    turn = rotation_about(-np.outer(grid, drift))
    force = _start_force(grid, latitude, reference, gravity)
    angle = np.zeros((grid.size, 3))
    for _ in range(2):  # predictor with f_0, corrector with Z f_0 (f^p of the turned platform)
        held = np.einsum("nij,nj->ni", rotation_about(angle), force)
        rate = -np.einsum("nji,jk,nkl,nl->ni", turn, g_sensitivity, turn, held)
        steps = 0.5 * np.diff(grid)[:, None] * (rate[1:] + rate[:-1])
        first = np.vstack([np.zeros(3), np.cumsum(steps, axis=0)])
        angle = np.vstack([np.zeros(3), np.cumsum(steps + 0.5 * np.cross(first[:-1], steps), axis=0)])
    return rotation_about(angle[where])


def g_sensitive_columns(
    time: NDArray[np.float64],
    latitude: float,
    *,
    reference: NDArray[np.float64],
    gravity: float,
    sigma: NDArray[np.float64],
    drift: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    r"""Return the fit's columns (n, 3, k) and prior σ (k,) of the errors of ``Dg_ab``, ``b`` = x, y, whose σ is not 0.

    An error ``δD_ab`` of the record's ``D_g`` turns the platform by ``−∫_0^t R^T e_a (R f_0^{rot})_b dτ`` more (first
    order in it; :func:`g_sensitive_turn`, ``R = rot(−ε^p τ)``), ``f_0^{rot}`` the Earth-rate part of the held
    platform's specific force (its constant part along the Earth's axis is a constant drift: in the drift the record
    sees).  The part that turns with the Earth like ``ω_b`` is that nuisance's; the part turning the other way
    (``D_xx − D_yy``, ``D_xy + D_yx``) and the polar row (``D_zx``, ``D_zy``, the platform-axis sensor's pattern) are
    not, and they correlate with the ramp: their prior is the record's σ.  ``R`` matters: 0.05 °/h along z_p turns the
    wobble by 0.018 rad in a day, 1 % of an error's leak (4e-7 °/h for an error of 1e-4 °/h/g).
    """
    k = skew(earth_rate_nav(latitude) / EARTH_RATE)
    down = np.array([0.0, 0.0, -gravity])
    b, c = reference @ k @ down, reference @ k @ k @ down  # f_0 = f̄ + sin(Ωt) b − cos(Ωt) c (earth_turn)
    grid, where = _turn_grid(time)
    angle = EARTH_RATE * grid
    turn = rotation_about(-np.outer(grid, drift))
    force = np.einsum("nij,nj->ni", turn, np.outer(np.sin(angle), b) - np.outer(np.cos(angle), c))  # R f_0^rot
    pairs = [(a, j) for a in range(3) for j in range(2) if sigma[a, j] > 0]
    if not pairs:
        return np.zeros((time.size, 3, 0)), np.zeros(0)
    rate = np.stack([-turn[:, a, :] * force[:, j : j + 1] for a, j in pairs], axis=2)  # −Rᵀ e_a (R f_rot)_b
    steps = 0.5 * np.diff(grid)[:, None, None] * (rate[1:] + rate[:-1])
    columns = np.concatenate([np.zeros((1, 3, len(pairs))), np.cumsum(steps, axis=0)])
    return columns[where], np.array([sigma[a, j] for a, j in pairs])


def _design(
    t: NDArray[np.float64],
    c_bp: NDArray[np.float64],
    basis: NDArray[np.float64],
    cos_r: NDArray[np.float64],
    sin_r: NDArray[np.float64],
    *,
    chain: NDArray[np.float64],
) -> NDArray[np.float64]:
    """Return the design ``(n, 3, 13)``.

    Columns: constant c (3), drift ε (3, column −t), base-fixed ω (2), platform sensor (h_c, h_s), and the chain's
    columns (n, 3, 3): inner offset, inner and middle sensor slopes.
    """
    n = t.size
    x = np.zeros((n, 3, 13))
    x[:, :, 0:3] = np.eye(3)
    x[:, :, 3:6] = -t[:, None, None] * np.eye(3)
    x[:, :, 6:8] = c_bp @ basis
    x[:, 2, 8], x[:, 2, 9] = cos_r, sin_r
    x[:, :, 10:13] = chain
    return x


def _solve(
    design: NDArray[np.float64],
    e: NDArray[np.float64],
    weight: NDArray[np.float64],
    sigma: NDArray[np.float64],
    *,
    prior: NDArray[np.float64],
    current: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Weighted least squares of the increments over the stacked axes (weights ``count/σ_a²``), σ_a re-measured from the residuals.

    ``prior``: information of a zero-mean prior on the parameters' totals (``current`` + increment).  Returns
    ``(increments β, cov β, σ per axis, residuals (n, 3))``.
    """
    for _ in range(2):  # weights from the previous σ, then σ from these residuals
        w = weight[:, None] / sigma[None, :] ** 2
        xtwx = np.einsum("nap,na,naq->pq", design, w, design) + prior
        xtwy = np.einsum("nap,na,na->p", design, w, e) - prior @ current
        scale = np.sqrt(np.diag(xtwx))
        inv = np.linalg.inv(xtwx / np.outer(scale, scale)) / np.outer(scale, scale)
        beta = inv @ xtwy
        residuals = e - np.einsum("nap,p->na", design, beta)
        dof = max(residuals.shape[0] - design.shape[2] / 3.0, 1.0)
        sigma = np.maximum(np.sqrt(np.sum(weight[:, None] * residuals**2, axis=0) / dof), SIGMA_FLOOR)
    w = weight[:, None] / sigma[None, :] ** 2
    xtwx = np.einsum("nap,na,naq->pq", design, w, design) + prior
    scale = np.sqrt(np.diag(xtwx))
    inv = np.linalg.inv(xtwx / np.outer(scale, scale)) / np.outer(scale, scale)
    return beta, 0.5 * (inv + inv.T), sigma, residuals


def _bins(t: NDArray[np.float64]) -> int:
    return int(np.floor(t[-1] / CHECK_BIN_SECONDS)) + 1 if t.size else 0


def _low_frequency_ratio(
    t: NDArray[np.float64], residuals: NDArray[np.float64], weight: NDArray[np.float64], sigma: NDArray[np.float64]
) -> float:
    """Weighted variance of the residuals' bin means over what white noise of σ gives (mean over the axes)."""
    index = np.floor(t / CHECK_BIN_SECONDS).astype(np.int64)
    counts = np.bincount(index, weights=weight)
    keep = counts > 0
    ratios = []
    for a in range(3):
        sums = np.bincount(index, weights=weight * residuals[:, a])[keep]
        # Σ_bins (Σ w r)² / (σ² Σ w): each term has expectation ≈ 1 for white noise
        ratios.append(float(np.mean(sums**2 / (sigma[a] ** 2 * counts[keep]))))
    return float(np.mean(ratios))


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
        g_sensitivity=prior_g_sensitivity(prior),
        g_sensitivity_sigma=_g_sensitivity_sigma(prior_covariance),
        gravity=metadata.gravity,
    )


def _g_sensitivity_sigma(prior_covariance: Mapping[tuple[str, str], float] | None) -> NDArray[np.float64]:
    """Return the prior σ of ``Dg_ab`` (3, 3) [rad/s per m/s²] (0 where the record holds none)."""
    out = np.zeros((3, 3))
    for i, a in enumerate("xyz"):
        for j, b in enumerate("xyz"):
            variance = None if prior_covariance is None else prior_covariance.get((f"Dg_{a}{b}", f"Dg_{a}{b}"))
            if variance is not None and math.isfinite(variance) and variance > 0:
                out[i, j] = math.sqrt(variance)
    return out


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
    """:func:`drift_step` but for the prior's ``D_g`` in the step (the gimbal fit composes its turn out, :func:`measure_gimbals`)."""
    gimbal = None
    notes: list[str] = []
    if options.estimate_gyro_drift:
        gimbal = measure_gimbals(sums, metadata, prior, prior_covariance, latitude=latitude)
        if gimbal is not None:
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
    "DRIFT_IDS",
    "DriftSource",
    "DriftStep",
    "GimbalDrift",
    "MINIMUM_BLOCKS",
    "MINIMUM_SPAN",
    "attitude_drift_jacobian",
    "augment_measurement",
    "drift_covariance_v",
    "drift_notes",
    "drift_step",
    "earth_turn",
    "fit_gimbal_drift",
    "g_sensitive_columns",
    "g_sensitive_turn",
    "g_sensitivity_removed",
    "likelihood_inputs",
    "measure_gimbals",
    "prior_drift",
    "prior_g_sensitivity",
]
