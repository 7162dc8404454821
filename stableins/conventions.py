r"""Frames, rotation senses, sign conventions and Earth constants.

This is the single place where stableins defines its geometry. Every other module
imports from here; ``docs/conventions.md`` is the prose version of the same
definitions and the two must agree.

Frames
------
n : local geographic navigation frame, North-East-Down (NED).  Static specific force
    ``f^n = [0, 0, -g]`` (Wu et al. 2018 Eq. 1 with the lost minus restored).
b : body (base) frame, Forward-Right-Down.  ``C_n^b`` is the yaw-pitch-roll
    (3-2-1) DCM of Wu et al. 2018 Eq. 3.
p : platform frame.  At zero actual gimbal angles it coincides with b.  ``z_p`` is the
    platform (stable element) axis, ``x_p`` the inner gimbal axis, ``y_p`` the middle
    gimbal axis.
a : accelerometer frame (non-orthogonal).
    The rows of ``C_p^a`` are the sensitive axes.

Rotation matrices
-----------------
``R1, R2, R3`` are *frame* (passive) rotations: ``R_i(a)`` is the DCM from a frame
to the frame turned by ``+a`` (right hand) about its axis ``i``.  Hence
``R_i(a) = I - a [e_i x] + O(a^2)``.

Gimbal chain (outer to inner, base to platform)::

    C_b^p = R3(s1*alpha1) @ R1(s2*alpha2) @ R2(s3*alpha3) @ R3(s4*q)

alpha1: platform axis (z_p), alpha2: inner gimbal (x), alpha3: middle gimbal (y),
q: outer (azimuth) gimbal, normally held at zero.  ``s_i = +1/-1`` are the rotation
senses (configuration).  Angle sensors read ``r_i``; the actual angle is
``alpha_i = r_i + theta_i0`` where ``theta_i0`` is the sensor's zero offset: the
actual angle when the sensor reads zero.  Commanding ``r_i = r_nominal - theta_i0_hat``
removes the offset (Wu et al. 2018 Section 3).

Only when ``s1*s2*s3 = +1`` does the 18-position sequence of Wu et al. Table 1 point
every sensitive axis both up and down (see ``docs/conventions.md``).

Accelerometer frame (Wu et al. 2018 Eq. 5, signs restored)::

    C_p^a = [[1, bxz, -bxy], [-byz, 1, byx], [bzy, -bzx, 1]]

``b_ij`` is a right-hand rotation of sensitive axis ``i`` about platform axis ``j``.
The matrix is the definition: the sensitive-axis directions are its rows; their norm
excess (``~b^2/2 < 1e-8`` for 20 arcsec) is absorbed in the scale factor.

Attitude error
--------------
The computed navigation frame n' differs from n by the small rotation ``phi``:
``C_n^{n'} = I - [phi x]``.  Attitude errors are computed minus true Euler angles;
for a level, north-pointing body ``(d_roll, d_pitch, d_yaw) = -(phi_N, phi_E, phi_D)``.

Earth
-----
WGS-84 constants; normal gravity by Somigliana's closed formula with the second-order
height correction (NIMA TR8350.2, Eqs. 4-1 and 4-3).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from types import MappingProxyType
from typing import Final

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stableins.dwell_mode import DwellMode

# --------------------------------------------------------------------------- units
#: Standard gravity, used only for engineering units (µg, µg/g²), never as local g.
STANDARD_GRAVITY: Final = 9.80665
ARCSEC: Final = np.pi / (180.0 * 3600.0)
#: One arcsecond per hour [rad/s] (platform drift rates at the edges).
ARCSEC_PER_HOUR: Final = ARCSEC / 3600.0
MICRO_G: Final = 1e-6 * STANDARD_GRAVITY
#: µg/g² in SI [s²/m] (the quadratic nonlinearity at the edges; docs/conventions.md, "Units").
MICRO_G_PER_G2: Final = MICRO_G / STANDARD_GRAVITY**2
PPM: Final = 1e-6
#: One degree per hour [rad/s] (gyro drift at the edges).
DEG_PER_HOUR: Final = np.pi / (180.0 * 3600.0)
#: One degree per hour per standard g [rad/s per m/s²] (gyro g-sensitivity ``Dg_ab`` at the edges).
DEG_PER_HOUR_PER_G: Final = DEG_PER_HOUR / STANDARD_GRAVITY

#: Input excursion [m/s²] a slew must exceed to set an axis' hysteresis state (``Kh_a``), the one definition of the
#: truth simulator and of discovery's dwells.  A real accelerometer's hysteresis follows the excursion of its input: a
#: change much smaller than the loop (here arcsecond-level geometry, ~1e-4 m/s²) does not reverse the magnetic/flexure
#: state, so the state keeps its last value.
HYSTERESIS_THRESHOLD: Final = 1e-2

#: One millisecond [s] (the accelerometer–angle-reading time asynchrony at the edges).
MILLISECOND: Final = 1e-3
#: One millimetre [m] (lever arms at the edges).
MILLIMETRE: Final = 1e-3

# --------------------------------------------------------------------------- timing
#: Sign of the time asynchrony ``τ`` (``t_async``, docs/conventions.md "Time asynchrony"): ``τ > 0`` means the
#: accelerometer sample stamped ``t`` was taken at ``t − τ`` (the accelerometers lag the angle readings).  On a
#: static base ``f^n`` is constant and ``Ċ_n^p = −[ω×] C_n^p`` (``ω = ω_bp^p``), so the recorded output errs by
#: ``f^p(t − τ) − f^p(t) = −τ ḟ^p = +τ ω × f^p``, i.e. ``δf = ASYNC_SIGN · τ · ω × f^p``.
ASYNC_SIGN: Final = 1.0


def asynchrony_error(tau: ArrayLike, angular_rate: ArrayLike, specific_force: ArrayLike) -> NDArray[np.float64]:
    r"""First-order output error of a time asynchrony ``τ`` [s]: ``δf = τ ω × f^p`` (:data:`ASYNC_SIGN`).

    .. math:: \delta f^p = f^p(t-\tau) - f^p(t) = -\tau \dot f^p = \tau\, \omega_{bp}^p \times f^p

    (static base: ``f^n`` constant, ``\dot C_n^p = -[\omega\times] C_n^p``).  ``angular_rate`` ``ω_bp^p``
    [rad/s] and ``specific_force`` ``f^p`` [m/s²], shape (..., 3).  The estimator's regressor; the simulator
    does not use it (it evaluates the whole accelerometer input at ``t − τ``).
    """
    omega = np.asarray(angular_rate, dtype=float)
    return ASYNC_SIGN * np.asarray(tau, dtype=float)[..., None] * np.cross(omega, np.asarray(specific_force, dtype=float))


# --------------------------------------------------------------------------- WGS-84
WGS84_SEMI_MAJOR_AXIS: Final = 6378137.0  # a [m]
WGS84_FLATTENING: Final = 1.0 / 298.257223563  # f
WGS84_GM: Final = 3.986004418e14  # [m^3/s^2]
EARTH_RATE: Final = 7.292115e-5  # omega_ie [rad/s]
WGS84_SEMI_MINOR_AXIS: Final = WGS84_SEMI_MAJOR_AXIS * (1.0 - WGS84_FLATTENING)
WGS84_ECCENTRICITY_SQUARED: Final = WGS84_FLATTENING * (2.0 - WGS84_FLATTENING)
WGS84_GRAVITY_EQUATOR: Final = 9.7803253359  # gamma_e [m/s^2]
WGS84_SOMIGLIANA_K: Final = 0.00193185265241  # k = (b gamma_p)/(a gamma_e) - 1
SIDEREAL_DAY: Final = 2.0 * np.pi / EARTH_RATE  # [s]
#: Mean Earth radius used for the Schuler frequency of the error dynamics [m].
EARTH_RADIUS: Final = 6371000.0


def platform_drift_rate(drift: ArrayLike, g_sensitivity: ArrayLike, specific_force: ArrayLike) -> NDArray[np.float64]:
    r"""Return the inertial turn rate ``w`` [rad/s] of a stabilized platform whose gyros err.

    The stabilization loop nulls the gyro outputs, so a gyro output error turns the platform the
    other way: with the constant drift ``ε^p`` and the g-sensitivity matrix ``D_g`` (row ``a``: the
    gyro about platform axis ``a``; column ``b``: specific force along platform axis ``b``; Cai et
    al. 2016 Eq. 1, coefficient G)

    .. math:: w = -(\varepsilon^p + D_g f^p) .

    Parameters
    ----------
    drift : array_like (..., 3)
        Constant gyro drift ``ε^p`` [rad/s].
    g_sensitivity : array_like (3, 3)
        ``D_g``, entry ``[a, b]`` = ``Dg_ab`` [rad/s per m/s²].
    specific_force : array_like (..., 3)
        Platform-frame specific force ``f^p`` [m/s²].

    Returns
    -------
    ndarray (..., 3)
        ``w`` in the platform frame [rad/s].
    """
    force = np.asarray(specific_force, dtype=float)
    return -(np.asarray(drift, dtype=float) + np.einsum("ab,...b->...a", np.asarray(g_sensitivity, dtype=float), force))


def dwell_platform_rate(
    mode: DwellMode, drift_rate: ArrayLike, earth_rate: ArrayLike, torquer_scale: ArrayLike = (0.0, 0.0, 0.0)
) -> NDArray[np.float64]:
    r"""Return the platform's rate relative to the base within a dwell, ``ω_bp^p`` [rad/s], in the platform frame.

    .. math::
        \omega_{bp}^p = \omega_{ip}^p - \omega_{ie}^p = \begin{cases}
            0 & \text{caged (the angle loops hold the readings)} \\
            w + k \circ \omega_{ie}^p & \text{torqued at the computed Earth rate } (1 + k) \circ \omega_{ie}^p \\
            w - \omega_{ie}^p & \text{inertially held (not torqued)}
        \end{cases}

    with the gyro-error rate ``w = −(ε^p + D_g f^p)`` (:func:`platform_drift_rate`) and ``k`` the torquers'
    scale-factor error per platform axis (a torquer turns the platform at ``(1 + k_a)`` times the commanded rate).
    Derivation: the stabilization loop nulls the gyro outputs ``ω_ip^p − ω_cmd^p + ε^p + D_g f^p``, so
    ``ω_ip^p = ω_cmd^p + w``; the base turns at ``ω_ie`` (static base).

    Parameters
    ----------
    mode : DwellMode
    drift_rate : array_like (..., 3)
        ``w`` [rad/s].
    earth_rate : array_like (..., 3)
        ``ω_ie^p = C_n^p ω_ie^n`` [rad/s] (:func:`earth_rate_nav`).
    torquer_scale : array_like (3,)
        ``k`` (dimensionless; only the torqued mode uses it).
    """
    w = np.asarray(drift_rate, dtype=float)
    earth = np.asarray(earth_rate, dtype=float)
    if mode is DwellMode.CAGED:
        return np.zeros(np.broadcast_shapes(w.shape, earth.shape))
    if mode is DwellMode.EARTH_RATE:
        return w + np.asarray(torquer_scale, dtype=float) * earth
    return w - earth


def normal_gravity(latitude: ArrayLike, height: ArrayLike = 0.0) -> NDArray[np.float64]:
    r"""WGS-84 normal gravity at geodetic latitude and ellipsoidal height.

    .. math::
        \gamma_0 = \gamma_e \frac{1 + k \sin^2 L}{\sqrt{1 - e^2 \sin^2 L}},\qquad
        \gamma(h) = \gamma_0\Big[1 - \frac{2}{a}(1 + f + m - 2f\sin^2 L)h
                    + \frac{3}{a^2}h^2\Big]

    with :math:`m = \omega^2 a^2 b / GM` (NIMA TR8350.2, Eqs. 4-1, 4-3).

    Parameters
    ----------
    latitude : array_like
        Geodetic latitude [rad].
    height : array_like, optional
        Height above the ellipsoid [m].

    Returns
    -------
    ndarray
        Normal gravity magnitude [m/s²].
    """
    latitude = np.asarray(latitude, dtype=float)
    height = np.asarray(height, dtype=float)
    a, b, f = WGS84_SEMI_MAJOR_AXIS, WGS84_SEMI_MINOR_AXIS, WGS84_FLATTENING
    sin2 = np.sin(latitude) ** 2
    gamma0 = WGS84_GRAVITY_EQUATOR * (1.0 + WGS84_SOMIGLIANA_K * sin2) / np.sqrt(1.0 - WGS84_ECCENTRICITY_SQUARED * sin2)
    m = EARTH_RATE**2 * a**2 * b / WGS84_GM
    return gamma0 * (1.0 - 2.0 / a * (1.0 + f + m - 2.0 * f * sin2) * height + 3.0 / a**2 * height**2)


def earth_rate_nav(latitude: ArrayLike) -> NDArray[np.float64]:
    r"""Earth rotation rate in the NED frame, :math:`\omega_{ie}^n = \omega(\cos L, 0, -\sin L)`."""
    latitude = np.asarray(latitude, dtype=float)
    zero = np.zeros_like(latitude)
    return EARTH_RATE * np.stack([np.cos(latitude), zero, -np.sin(latitude)], axis=-1)


def specific_force_nav(gravity: ArrayLike) -> NDArray[np.float64]:
    """Return the static specific force in NED, ``[0, 0, -g]`` (Wu et al. 2018 Eq. 1)."""
    gravity = np.asarray(gravity, dtype=float)
    zero = np.zeros_like(gravity)
    return np.stack([zero, zero, -gravity], axis=-1)


# --------------------------------------------------------------------------- rotations
def _elementary(angle: ArrayLike, axis: int) -> NDArray[np.float64]:
    angle = np.asarray(angle, dtype=float)
    c, s = np.cos(angle), np.sin(angle)
    out = np.zeros(angle.shape + (3, 3))
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    out[..., axis, axis] = 1.0
    out[..., i, i] = c
    out[..., j, j] = c
    out[..., i, j] = s
    out[..., j, i] = -s
    return out


def R1(angle: ArrayLike) -> NDArray[np.float64]:
    """Frame rotation by ``angle`` about x: ``[[1,0,0],[0,c,s],[0,-s,c]]`` (vectorized)."""
    return _elementary(angle, 0)


def R2(angle: ArrayLike) -> NDArray[np.float64]:
    """Frame rotation by ``angle`` about y: ``[[c,0,-s],[0,1,0],[s,0,c]]`` (vectorized)."""
    return _elementary(angle, 1)


def R3(angle: ArrayLike) -> NDArray[np.float64]:
    """Frame rotation by ``angle`` about z: ``[[c,s,0],[-s,c,0],[0,0,1]]`` (vectorized)."""
    return _elementary(angle, 2)


def skew(vector: ArrayLike) -> NDArray[np.float64]:
    """Cross-product matrix ``[v x]`` with ``[v x] w = v x w`` (vectorized)."""
    v = np.asarray(vector, dtype=float)
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1], out[..., 0, 2] = -v[..., 2], v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = v[..., 2], -v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -v[..., 1], v[..., 0]
    return out


def dcm_nav_to_body(yaw: ArrayLike, pitch: ArrayLike, roll: ArrayLike) -> NDArray[np.float64]:
    r"""``C_n^b = R1(roll) R2(pitch) R3(yaw)`` (Wu et al. 2018 Eq. 3, 3-2-1 Euler angles)."""
    return R1(roll) @ R2(pitch) @ R3(yaw)


def euler_from_dcm(dcm_nav_to_body_: ArrayLike) -> tuple[NDArray, NDArray, NDArray]:
    """Inverse of :func:`dcm_nav_to_body`: returns ``(yaw, pitch, roll)`` [rad]."""
    c = np.asarray(dcm_nav_to_body_, dtype=float)
    yaw = np.arctan2(c[..., 0, 1], c[..., 0, 0])
    pitch = -np.arcsin(np.clip(c[..., 0, 2], -1.0, 1.0))
    roll = np.arctan2(c[..., 1, 2], c[..., 2, 2])
    return yaw, pitch, roll


@dataclass(frozen=True)
class GimbalConfiguration:
    """Rotation senses of the four gimbals (configuration, not estimated).

    ``senses = (s1, s2, s3, s4)`` for platform (z), inner (x), middle (y), outer
    azimuth (z).  ``s_i = +1`` means a positive sensor reading turns the inner member
    right-handedly about the positive axis.  The default is the right-handed set.
    """

    senses: tuple[int, int, int, int] = (1, 1, 1, 1)

    def __post_init__(self) -> None:
        if len(self.senses) != 4 or any(s not in (1, -1) for s in self.senses):
            raise ValueError(f"gimbal senses must be four values of +1 or -1, got {self.senses!r}")

    @property
    def handedness(self) -> int:
        """``s1*s2*s3``: +1 for the handedness under which Table 1 reverses every axis."""
        s1, s2, s3, _ = self.senses
        return s1 * s2 * s3


DEFAULT_GIMBALS: Final = GimbalConfiguration()


def dcm_body_to_platform(
    platform_angle: ArrayLike,
    inner_angle: ArrayLike,
    middle_angle: ArrayLike,
    outer_angle: ArrayLike = 0.0,
    configuration: GimbalConfiguration = DEFAULT_GIMBALS,
) -> NDArray[np.float64]:
    r"""Exact gimbal kinematics ``C_b^p`` from *actual* gimbal angles.

    .. math:: C_b^p = R_3(s_1\alpha_1) R_1(s_2\alpha_2) R_2(s_3\alpha_3) R_3(s_4 q)

    Equivalent to Wu et al. 2018 Eq. 4 (``R3(-St) R2(h + pi/2) R3(-q)``) with
    ``alpha1 = -St``, ``alpha2 = 0``, ``alpha3 = h + pi/2``.
    """
    s1, s2, s3, s4 = configuration.senses
    return (
        R3(s1 * np.asarray(platform_angle, dtype=float))
        @ R1(s2 * np.asarray(inner_angle, dtype=float))
        @ R2(s3 * np.asarray(middle_angle, dtype=float))
        @ R3(s4 * np.asarray(outer_angle, dtype=float))
    )


def actual_gimbal_angles(readings: ArrayLike, zero_offsets: ArrayLike) -> NDArray[np.float64]:
    """Actual angles from sensor readings: ``alpha_i = r_i + theta_i0`` (last axis: gimbals)."""
    return np.asarray(readings, dtype=float) + np.asarray(zero_offsets, dtype=float)


#: Where each installation angle stands in ``C_p^a`` and with which sign (Eq. 5, signs restored):
#: ``C_p^a[row, col] = sign · β`` (:func:`dcm_platform_to_accelerometer`).
INSTALLATION_ENTRIES: Final = MappingProxyType(
    {
        "beta_xz": (0, 1, 1.0),
        "beta_xy": (0, 2, -1.0),
        "beta_yz": (1, 0, -1.0),
        "beta_yx": (1, 2, 1.0),
        "beta_zy": (2, 0, 1.0),
        "beta_zx": (2, 1, -1.0),
    }
)


def dcm_platform_to_accelerometer(
    *,
    beta_xz: ArrayLike,
    beta_xy: ArrayLike,
    beta_yz: ArrayLike,
    beta_yx: ArrayLike,
    beta_zy: ArrayLike,
    beta_zx: ArrayLike,
) -> NDArray[np.float64]:
    r"""Installation matrix ``C_p^a`` (Wu et al. 2018 Eq. 5, signs restored).

    .. math::
        C_p^a = \begin{bmatrix} 1 & \beta_{xz} & -\beta_{xy}\\
                -\beta_{yz} & 1 & \beta_{yx}\\ \beta_{zy} & -\beta_{zx} & 1\end{bmatrix}
    """
    b = np.broadcast_arrays(*(np.asarray(x, dtype=float) for x in (beta_xz, beta_xy, beta_yz, beta_yx, beta_zy, beta_zx)))
    angles = dict(zip(("beta_xz", "beta_xy", "beta_yz", "beta_yx", "beta_zy", "beta_zx"), b, strict=True))
    out = np.zeros(b[0].shape + (3, 3))
    out[..., 0, 0] = out[..., 1, 1] = out[..., 2, 2] = 1.0
    for name, (row, col, sign) in INSTALLATION_ENTRIES.items():
        out[..., row, col] = angles[name] if sign > 0 else -angles[name]
    return out


def polar_alignment_readings(latitude: float, configuration: GimbalConfiguration = DEFAULT_GIMBALS) -> tuple[float, float]:
    """Actual (platform, middle) angles that put ``z_p`` on the Earth's spin axis.

    For a level, north-pointing base: ``s3*alpha3 = pi/2 + L`` puts ``z_p`` along
    ``(cos L, 0, -sin L)`` in NED (towards the celestial pole), and ``f^p/g =
    (cos St cos L, sin St cos L, sin L)`` with the Earth-rate angle
    ``St = -s1*alpha1`` (Wu et al. 2018 Eq. 19 with all signs +).  Returns
    ``(alpha1 at St = 0, alpha3)``.
    """
    _, _, s3, _ = configuration.senses
    return 0.0, s3 * (np.pi / 2.0 + latitude)


def earth_rate_angle(platform_angle: ArrayLike, configuration: GimbalConfiguration = DEFAULT_GIMBALS) -> NDArray[np.float64]:
    """Earth-rate rotation angle ``St = -s1*alpha1`` of a polar-aligned platform."""
    return -configuration.senses[0] * np.asarray(platform_angle, dtype=float)


def attitude_error_from_misalignment(
    phi: ArrayLike, yaw: ArrayLike = 0.0, pitch: ArrayLike = 0.0, roll: ArrayLike = 0.0
) -> NDArray[np.float64]:
    r"""Euler-angle errors ``(d_yaw, d_pitch, d_roll)`` caused by a small misalignment ``phi``.

    Exact: ``C_n^{b'} = C_n^b (I + [phi x])`` (computed frame ``C_n^{n'} = I - [phi x]``),
    then the computed Euler angles minus the true ones.  For a level north-pointing
    body this is ``-(phi_D, phi_E, phi_N)`` to first order.
    """
    phi = np.asarray(phi, dtype=float)
    c_true = dcm_nav_to_body(yaw, pitch, roll)
    angle = np.linalg.norm(phi, axis=-1)[..., None, None]
    k = skew(phi)
    with np.errstate(invalid="ignore", divide="ignore"):
        s = np.where(angle > 0, np.sin(angle) / np.where(angle > 0, angle, 1.0), 1.0)
        c = np.where(angle > 0, (1 - np.cos(angle)) / np.where(angle > 0, angle, 1.0) ** 2, 0.5)
    rotation = np.eye(3) + s * k + c * (k @ k)  # exp([phi x]) = C_{n'}^n
    c_computed = c_true @ rotation
    y1, p1, r1 = euler_from_dcm(c_computed)
    y0, p0, r0 = euler_from_dcm(c_true)
    wrap = lambda x: (x + np.pi) % (2 * np.pi) - np.pi  # noqa: E731
    return np.stack([wrap(y1 - y0), p1 - p0, wrap(r1 - r0)], axis=-1)


def heading_to_north_pointing(pitch: ArrayLike, roll: ArrayLike, yaw: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    r"""Pitch and roll errors of a level body with heading ``yaw`` as the pair a north-pointing body would show.

    A level body with heading ψ sees ``(δpitch, δroll) = R(ψ)(−φ_E, −φ_N)`` (first order of
    :func:`attitude_error_from_misalignment`); this rotates back,
    ``(cos ψ δpitch + sin ψ δroll, −sin ψ δpitch + cos ψ δroll) = (−φ_E, −φ_N)``: the pitch and roll errors of a
    north-pointing body, as the damping-loop model outputs them.
    """
    cos_yaw, sin_yaw = math.cos(yaw), math.sin(yaw)
    pitch, roll = np.asarray(pitch, dtype=float), np.asarray(roll, dtype=float)
    return cos_yaw * pitch + sin_yaw * roll, -sin_yaw * pitch + cos_yaw * roll


def misalignment_pitch_roll(relative: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    r"""Pitch and roll errors of a north-pointing body from the relative DCM ``C_b^n C_n^{b'} ≈ I + [φ×]`` of a tilted body.

    ``C_n^{b'} = C_n^b (I + [φ×])``: ``φ`` from the antisymmetric part of ``relative`` (``(n, 3, 3)``), and
    ``(δpitch, δroll) = (−φ_E, −φ_N)`` as for a level north-pointing body (:func:`attitude_error_from_misalignment`).
    """
    return -0.5 * (relative[:, 0, 2] - relative[:, 2, 0]), -0.5 * (relative[:, 2, 1] - relative[:, 1, 2])


#: What each installation angle of ``C_p^a`` is (Eq. 5).
INSTALLATION_MEANING: Final = {
    "beta_xy": "rotation of the x sensitive axis about y_p",
    "beta_xz": "rotation of the x sensitive axis about z_p",
    "beta_yx": "rotation of the y sensitive axis about x_p",
    "beta_yz": "rotation of the y sensitive axis about z_p",
    "beta_zx": "rotation of the z sensitive axis about x_p",
    "beta_zy": "rotation of the z sensitive axis about y_p",
}

#: What each gimbal zero offset is (Wu et al. 2018 Section 3).
#: The angle-sensor zero offsets ``θ_i0`` of the platform, inner and middle gimbal, by id [rad].
GIMBAL_IDS: Final = ("theta10", "theta20", "theta30")
GIMBAL_OFFSET_MEANING: Final = {
    "theta10": "zero offset of the platform-axis (z_p) angle sensor",
    "theta20": "zero offset of the inner-gimbal (x) angle sensor",
    "theta30": "zero offset of the middle-gimbal (y) angle sensor",
}

#: The accelerometer (and platform) axes, in order.
AXES = ("x", "y", "z")
