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
  inner and middle readings stand still, so their sensor errors are constant offsets (part of ``ω_b``).

Model, per block mean of the readings (10-s attitude blocks, at the attitude decimation):
``e(t_k) = c + C_b^p(t_k) P ω + (h_c \cos r_{1k} + h_s \sin r_{1k}) e_z − ε^p t_k + n_k`` (``P``: two body vectors
normal to the Earth's axis).  Products of the nuisances with the ramp (``½ ε t × ω`` ~ 1e-8 rad for 0.001 °/h and 10″)
are removed by iterating: each pass removes the fitted rotations exactly from the matrices and fits again.

Over one sidereal day the ramp is correlated with the Earth-rate harmonic ``sin S`` (``−√24/2π = −0.78``): σ(ε) is
``1/√(1 − 0.61) = 1.6`` times that of a ramp alone, ``σ_ε = 1.6 σ_e √(12/(N T²))``.  With the simulator's default
0.2″ of white angle noise at 1 Hz: about 5e-8 °/h per axis.  The noise σ of each axis is the weighted residual rms
(white noise assumed: the readings' noise is the angle sensors'); the residuals' variance on hour-long bins is checked
against it (:attr:`GimbalDrift.low_frequency_ratio`) and σ is scaled by it when the excess is significant.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar

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
from stableins.estimators.system.blocks import AttitudeBlocks
from stableins.platform import rotation_about, rotation_vector

#: The readings besides the platform angle that the drift needs (read at the attitude decimation).
GIMBAL_COLUMNS = ("angle_inner", "angle_middle")

#: Blocks of gimbal readings at most (pairs merge beyond: 43-s blocks for one day, 5 min for a week).
GIMBAL_BLOCKS = 1 << 11

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


@dataclass
class GimbalBlocks(AttitudeBlocks):
    """Block means of the three gimbal readings (platform angle unwrapped), on the attitude blocks' time bins.

    Same bins and merging as :class:`.blocks.AttitudeBlocks`, at most :data:`GIMBAL_BLOCKS` of them: the readings are
    linear in time within a block (the platform angle turns at the Earth rate, the others stand still), so the mean
    readings are the readings at the mean time whatever the width, and the fit's cost stays small.
    """

    _KEYS: ClassVar[tuple[str, ...]] = ("count", "time", "platform", "inner", "middle")
    _last_platform: float | None = None

    def add_readings(
        self, time: NDArray[np.float64], platform: NDArray[np.float64], inner: NDArray[np.float64], middle: NDArray[np.float64]
    ) -> None:
        """Add decimated readings [rad]; the platform angle is unwrapped across chunks (a record may wrap it)."""
        if time.size == 0:
            return
        previous = platform[:1] if self._last_platform is None else np.array([self._last_platform])
        unwrapped = np.unwrap(np.concatenate([previous, platform]))[1:]  # continuous with the previous chunk's last value
        self._last_platform = float(unwrapped[-1])
        self._accumulate(time, {"platform": unwrapped, "inner": inner, "middle": middle})

    def means(self) -> dict[str, NDArray[np.float64]]:
        """Return the block means of the non-empty blocks (``count``, ``time`` since the start, the three readings)."""
        count = self.sums["count"]
        keep = count > 0
        out = {"count": count[keep]}
        for key in self._KEYS[1:]:
            out[key] = self.sums[key][keep] / count[keep]
        return out


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
    prior = np.diag(np.r_[np.zeros(10), 1.0 / inner_offset_sigma**2, np.full(2, 1.0 / SLOPE_SIGMA**2)])
    sigma = np.ones(3)
    fit = None
    for _ in range(PASSES):
        # remove the fitted nuisances exactly: the inner offset inside the chain, base-fixed ω_b on the right, the z_p
        # sensor error on the left
        inner_angle = angles[:, 1] + inner + slopes[0] * moved[:, 0]
        middle_angle = angles[:, 2] + slopes[1] * moved[:, 1]
        c_true = dcm_body_to_platform(angles[:, 0], inner_angle, middle_angle, 0.0, configuration) @ rotation_about(omega_b).T
        z_turn = rotation_about(np.outer(sensor[0] * cos_r + sensor[1] * sin_r, [0.0, 0.0, 1.0]))
        q = z_turn.swapaxes(1, 2) @ c_true @ dcm_nav_to_body(*base_attitude) @ earth_turn(t, latitude).swapaxes(1, 2)
        e = rotation_vector(q @ reference.T)
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
        design = _design(t, c_true, basis, cos_r, sin_r, chain=chain)
        fit = _solve(design, e, weight, sigma, prior=prior, current=np.r_[np.zeros(10), inner, slopes])
        beta, sigma = fit[0], fit[2]
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


__all__ = ["DRIFT_IDS", "GimbalBlocks", "GimbalDrift", "earth_turn", "fit_gimbal_drift"]
