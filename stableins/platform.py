r"""The physical gimbal platform: angle sensors, gimbal chain and base.

:class:`GimbalPlatform` turns angle-sensor *readings* into the exact platform
orientation, using only the definitions of :mod:`stableins.conventions`, plus the
imperfections a real platform has and the conventions leave out:

Angle sensors
    ``alpha_i = r_i + theta_i0 + c_i cos r_i + s_i sin r_i`` : reading plus zero
    offset (conventions) plus an optional once-per-revolution sensor error with cosine
    and sine amplitudes ``c_i, s_i`` [rad] (effect ids ``ang1_<gimbal>_c`` /
    ``ang1_<gimbal>_s``, gimbal in platform, inner, middle).

Gimbal chain with non-orthogonal axes
    .. math::
        C_b^p = R_3(s_1\alpha_1)\,R_2(\nu_{12})\,R_1(s_2\alpha_2)\,R_3(\nu_{23})\,
                R_2(s_3\alpha_3)\,R_3(s_4 q)

    ``nu12`` (``nonorth_12``) is a fixed frame rotation about y inserted between the
    platform (z) and inner (x) axes: the inner axis makes the angle ``pi/2 + nu12``
    with the platform axis.  ``nu23`` (``nonorth_23``) is a fixed rotation about z
    between the inner (x) and middle (y) axes: they make the angle ``pi/2 + nu23``.
    With ``nu = 0`` this is :func:`stableins.conventions.dcm_body_to_platform`.

Base
    ``C_n^b = dcm_nav_to_body(yaw, pitch, roll) @ R2(t_E) @ R1(t_N) @ R3(ψ_e)``: the
    true base is the surveyed one turned right-handedly by ``ψ_e`` (``azimuth_error``)
    about Down, by ``t_N`` (``tilt_north``) about North, then by ``t_E``
    (``tilt_east``) about East (frame rotations, as in conventions).

Everything is vectorized over leading dimensions of the readings.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from types import MappingProxyType

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stableins.conventions import (
    DEFAULT_GIMBALS,
    R1,
    R2,
    R3,
    GimbalConfiguration,
    dcm_nav_to_body,
    skew,
    specific_force_nav,
)
from stableins.errormodel import GIMBAL_IDS

#: A gimbal-rate map ``J`` (:meth:`GimbalPlatform.rate_map`) worse conditioned than this is near gimbal lock: no
#: gimbal turns the platform about one direction (inner gimbal at ±90°, platform and middle axes aligned; Wu's
#: positions 3, 4, 5 and 14).  There a gyro-stabilized platform cannot be held: the angle loops cage it
#: (docs/conventions.md, "The platform during a dwell").
GIMBAL_LOCK_CONDITION = 1e3
#: Gimbal names in angle-sensor order (platform z, inner x, middle y), as in the data schema.
GIMBAL_NAMES = ("platform", "inner", "middle")
#: Ids of the kinematic (test-equipment) effects, in [rad].
KINEMATIC_IDS = (
    "nonorth_12",
    "nonorth_23",
    "tilt_north",
    "tilt_east",
    "azimuth_error",
    *(f"ang1_{g}_{cs}" for g in GIMBAL_NAMES for cs in ("c", "s")),
)
_ROT = (R1, R2, R3)
_E = np.eye(3)


# --------------------------------------------------------------------------- kinematics
def _frozen(mapping: Mapping[str, float] | None) -> Mapping[str, float]:
    return MappingProxyType(dict(mapping or {}))


def sensor_error_coefficients(effects: Mapping[str, float] | None) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Once-per-revolution angle-sensor amplitudes ``(c, s)`` per gimbal from ``ang1_<gimbal>_c|s`` ids [rad]."""
    effects = effects or {}
    c = np.array([effects.get(f"ang1_{g}_c", 0.0) for g in GIMBAL_NAMES], dtype=float)
    s = np.array([effects.get(f"ang1_{g}_s", 0.0) for g in GIMBAL_NAMES], dtype=float)
    return c, s


def actual_angles(
    readings: ArrayLike, zero_offsets: ArrayLike = (0.0, 0.0, 0.0), effects: Mapping[str, float] | None = None
) -> NDArray[np.float64]:
    """Actual gimbal angles ``alpha_i = r_i + theta_i0 + c_i cos r_i + s_i sin r_i`` (last axis: 3 gimbals)."""
    r = np.asarray(readings, dtype=float)
    alpha = r + np.asarray(zero_offsets, dtype=float)
    c, s = sensor_error_coefficients(effects)
    if c.any() or s.any():
        alpha = alpha + c * np.cos(r) + s * np.sin(r)
    return alpha


def gimbal_chain(
    actual: ArrayLike,
    configuration: GimbalConfiguration = DEFAULT_GIMBALS,
    nonorthogonality: tuple[float, float] = (0.0, 0.0),
    outer_angle: float = 0.0,
    keep: Sequence[str] = (),
) -> list[tuple[str, int, NDArray[np.float64]]]:
    r"""Factors ``(name, axis, angle)`` of ``C_b^p`` from the platform outwards (left to right).

    .. math:: C_b^p = R_3(s_1\alpha_1) R_2(\nu_{12}) R_1(s_2\alpha_2) R_3(\nu_{23}) R_2(s_3\alpha_3) R_3(s_4 q)

    Names are the gimbal names, ``nonorth_12``, ``nonorth_23`` and ``outer``; a fixed factor
    whose angle is zero (the identity) is left out unless its name is in ``keep``.
    """
    alpha = np.asarray(actual, dtype=float)
    s1, s2, s3, s4 = configuration.senses
    zero = np.zeros(alpha.shape[:-1])
    factors = [
        ("platform", 2, s1 * alpha[..., 0]),
        ("nonorth_12", 1, zero + nonorthogonality[0]),
        ("inner", 0, s2 * alpha[..., 1]),
        ("nonorth_23", 2, zero + nonorthogonality[1]),
        ("middle", 1, s3 * alpha[..., 2]),
        ("outer", 2, zero + s4 * outer_angle),
    ]
    fixed = {"nonorth_12": nonorthogonality[0], "nonorth_23": nonorthogonality[1], "outer": outer_angle}
    return [f for f in factors if f[0] not in fixed or fixed[f[0]] != 0.0 or f[0] in keep]


def chain_product(factors: Sequence[tuple[str, int, NDArray[np.float64]]]) -> NDArray[np.float64]:
    """Product of the factors of :func:`gimbal_chain`, left to right: ``C_b^p``."""
    out = _ROT[factors[0][1]](factors[0][2])
    for _, axis, angle in factors[1:]:
        out = out @ _ROT[axis](angle)
    return out


def nav_to_body(base_dcm: ArrayLike, effects: Mapping[str, float] | None = None) -> NDArray[np.float64]:
    """Return the true ``C_n^b = C_n^b(surveyed) R2(t_E) R1(t_N) R3(psi_e)`` (module docstring); ``effects`` by id [rad]."""
    effects = effects or {}
    c = np.asarray(base_dcm, dtype=float)
    t_north, t_east, azimuth = (float(effects.get(k, 0.0)) for k in ("tilt_north", "tilt_east", "azimuth_error"))
    if t_north or t_east or azimuth:
        c = c @ R2(t_east) @ R1(t_north) @ R3(azimuth)
    return c


def _surveyed(base_attitude: ArrayLike | None, base_dcm: ArrayLike | None) -> NDArray[np.float64]:
    if base_dcm is not None:
        if base_attitude is not None:
            raise ValueError("give the base as base_attitude or as base_dcm, not both")
        return np.asarray(base_dcm, dtype=float)
    yaw, pitch, roll = np.asarray((0.0, 0.0, 0.0) if base_attitude is None else base_attitude, dtype=float)
    return dcm_nav_to_body(yaw, pitch, roll)


def specific_force_and_jacobian(
    readings: ArrayLike,
    gravity: ArrayLike,
    *,
    zero_offsets: ArrayLike = (0.0, 0.0, 0.0),
    base_attitude: ArrayLike | None = None,
    base_dcm: ArrayLike | None = None,
    effects: Mapping[str, float] | None = None,
    configuration: GimbalConfiguration = DEFAULT_GIMBALS,
    ids: Sequence[str] = GIMBAL_IDS + KINEMATIC_IDS,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    r"""Exact static ``f^p`` and its analytic derivative ``∂f^p/∂p`` for zero offsets and kinematic effects.

    .. math:: f^p = R_3(s_1\alpha_1) R_2(\nu_{12}) R_1(s_2\alpha_2) R_3(\nu_{23}) R_2(s_3\alpha_3)
              \, C_n^b(\psi,\theta,\phi) R_2(t_E) R_1(t_N) R_3(\psi_e)\,(0, 0, -g)^T

    The derivative of a chain of frame rotations with respect to the angle of one factor is
    ``∂C/∂a_j = P_j (−[e_k×]) R_k(a_j) S_j`` (because ``R_k(a) = exp(−a[e_k×])``), with ``P_j``,
    ``S_j`` the products before and after factor ``j``; the angle of gimbal ``i`` depends on
    ``θ_i0`` with slope ``s_i`` and on ``ang1_<i>_c|s`` with slopes ``s_i cos r_i``, ``s_i sin r_i``;
    the base tilts act on ``C_n^b`` likewise.

    Parameters
    ----------
    readings : array_like (..., 3)
        Angle-sensor readings (platform, inner, middle) [rad].
    gravity : float or array_like
        Local gravity [m/s²] (broadcast against the leading dimensions of ``readings``).
    zero_offsets : array_like (..., 3)
        ``theta10, theta20, theta30`` [rad].
    base_attitude : array_like (3,), optional
        Surveyed (yaw, pitch, roll) of the base [rad] (default level, north).
    base_dcm : array_like (3, 3), optional
        Surveyed ``C_n^b`` instead of ``base_attitude``.
    effects : mapping, optional
        Values of :data:`KINEMATIC_IDS` [rad]; absent ids are zero.
    configuration : GimbalConfiguration
        Rotation senses.
    ids : sequence of str
        Parameters of the derivative, from :data:`GIMBAL_IDS` and :data:`KINEMATIC_IDS`.

    Returns
    -------
    f_p : ndarray (..., 3)
        ``f^p`` [m/s²].
    jacobian : ndarray (..., 3, len(ids))
        ``∂f^p/∂p`` [m/s² per rad].
    """
    effects = effects or {}
    unknown = [i for i in ids if i not in GIMBAL_IDS + KINEMATIC_IDS]
    if unknown:
        raise KeyError(f"{unknown[0]!r} is not a kinematic parameter (known: {', '.join(GIMBAL_IDS + KINEMATIC_IDS)})")
    r = np.asarray(readings, dtype=float)
    alpha = actual_angles(r, zero_offsets, effects)
    nonorth = (float(effects.get("nonorth_12", 0.0)), float(effects.get("nonorth_23", 0.0)))
    chain = gimbal_chain(alpha, configuration, nonorth, keep=ids)
    surveyed = _surveyed(base_attitude, base_dcm)
    f_n = specific_force_nav(gravity)
    mats = [_ROT[axis](angle) for _, axis, angle in chain]
    # suffix[j] = M_j ... M_{n-1} f_b, applied to the vector from the right; suffix[0] = f^p
    suffix = [np.einsum("ij,...j->...i", nav_to_body(surveyed, effects), f_n)]
    for m in reversed(mats):
        suffix.insert(0, np.einsum("...ij,...j->...i", m, suffix[0]))
    f_p = suffix[0]
    if not ids:
        return f_p, np.zeros(f_p.shape + (0,))
    prefix = [np.broadcast_to(_E, alpha.shape[:-1] + (3, 3))]
    for m in mats:
        prefix.append(prefix[-1] @ m)
    names = [name for name, _, _ in chain]

    def d_factor(name: str) -> NDArray[np.float64]:
        """∂f^p/∂(angle of the named factor): ``P_j (−[e_k×]) (M_j S_j f_b)``."""
        j = names.index(name)
        return np.einsum("...ij,...j->...i", prefix[j], -np.cross(_E[chain[j][1]], suffix[j]))

    def d_tilt(rotation_axis: int) -> NDArray[np.float64]:
        """∂f^p/∂(base rotation about North, East or Down): ``C_b^p C_ypr [R2 R1 R3, one factor differentiated] f^n``."""
        m = surveyed
        for axis, key in ((1, "tilt_east"), (0, "tilt_north"), (2, "azimuth_error")):
            rot = _ROT[axis](effects.get(key, 0.0))
            m = m @ (-skew(_E[axis]) @ rot if axis == rotation_axis else rot)
        return np.einsum("...ij,...j->...i", prefix[-1], np.einsum("ij,...j->...i", m, f_n))

    return f_p, np.stack([_jacobian_column(pid, r, configuration.senses, d_factor, d_tilt) for pid in ids], axis=-1)


def _jacobian_column(
    pid: str,
    readings: NDArray[np.float64],
    senses: Sequence[int],
    d_factor: Callable[[str], NDArray[np.float64]],
    d_tilt: Callable[[int], NDArray[np.float64]],
) -> NDArray[np.float64]:
    """Return ``∂f^p/∂pid`` from the derivatives by a factor's angle (``d_factor``) and by a base rotation (``d_tilt``)."""
    if pid in GIMBAL_IDS:
        i = GIMBAL_IDS.index(pid)
        return senses[i] * d_factor(GIMBAL_NAMES[i])
    if pid.startswith("nonorth_"):
        return d_factor(pid)
    if pid in ("tilt_north", "tilt_east", "azimuth_error"):
        return d_tilt(("tilt_north", "tilt_east", "azimuth_error").index(pid))
    # ang1_<gimbal>_<c|s>
    _, g, cs = pid.split("_")
    i = GIMBAL_NAMES.index(g)
    slope = np.cos(readings[..., i]) if cs == "c" else np.sin(readings[..., i])
    return senses[i] * slope[..., None] * d_factor(g)


def platform_specific_force(
    readings: ArrayLike,
    gravity: ArrayLike,
    *,
    zero_offsets: ArrayLike = (0.0, 0.0, 0.0),
    base_attitude: ArrayLike | None = None,
    base_dcm: ArrayLike | None = None,
    effects: Mapping[str, float] | None = None,
    configuration: GimbalConfiguration = DEFAULT_GIMBALS,
) -> NDArray[np.float64]:
    """``f^p`` of static positions from angle-sensor readings, exactly (:func:`specific_force_and_jacobian`)."""
    return specific_force_and_jacobian(
        readings,
        gravity,
        zero_offsets=zero_offsets,
        base_attitude=base_attitude,
        base_dcm=base_dcm,
        effects=effects,
        configuration=configuration,
        ids=(),
    )[0]


@dataclass(frozen=True)
class GimbalPlatform:
    """A gimbaled platform on a static base.

    Parameters
    ----------
    zero_offsets : tuple of float
        ``(theta10, theta20, theta30)`` [rad]: actual angle when the sensor reads zero.
    configuration : GimbalConfiguration
        Rotation senses (see :mod:`stableins.conventions`).
    base_attitude : tuple of float
        Surveyed (yaw, pitch, roll) of the base [rad].
    base_tilt : tuple of float
        ``(tilt_north, tilt_east)`` [rad]: unknown small rotation of the true base
        about North then East relative to the surveyed attitude.
    base_azimuth : float
        Unknown azimuth error of the base about Down [rad].
    nonorthogonality : tuple of float
        ``(nu12, nu23)`` [rad], see the module docstring.
    angle_sensor_errors : mapping
        Once-per-revolution sensor errors by id ``ang1_<gimbal>_c`` / ``_s`` [rad].
    outer_angle : float
        Outer (azimuth) gimbal angle, normally held at zero [rad].
    """

    zero_offsets: tuple[float, float, float] = (0.0, 0.0, 0.0)
    configuration: GimbalConfiguration = DEFAULT_GIMBALS
    base_attitude: tuple[float, float, float] = (0.0, 0.0, 0.0)
    base_tilt: tuple[float, float] = (0.0, 0.0)
    base_azimuth: float = 0.0
    nonorthogonality: tuple[float, float] = (0.0, 0.0)
    angle_sensor_errors: Mapping[str, float] = field(default_factory=lambda: MappingProxyType({}))
    outer_angle: float = 0.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "angle_sensor_errors", _frozen(self.angle_sensor_errors))
        known = {f"ang1_{g}_{k}" for g in GIMBAL_NAMES for k in "cs"}
        unknown = set(self.angle_sensor_errors) - known
        if unknown:
            raise ValueError(f"unknown angle-sensor error ids {sorted(unknown)} (known: {sorted(known)})")

    # ------------------------------------------------------------------ sensors
    def actual_angles(self, readings: ArrayLike) -> NDArray[np.float64]:
        """Actual gimbal angles ``alpha = r + theta0 + c cos r + s sin r`` (:func:`actual_angles`)."""
        return actual_angles(readings, self.zero_offsets, self.angle_sensor_errors)

    def readings_from_actual(self, actual: ArrayLike, iterations: int = 3) -> NDArray[np.float64]:
        """Inverse of :meth:`actual_angles` (fixed-point iteration; exact for zero sensor errors)."""
        alpha = np.asarray(actual, dtype=float)
        r = alpha - np.asarray(self.zero_offsets, dtype=float)
        if self.angle_sensor_errors:
            c, s = sensor_error_coefficients(self.angle_sensor_errors)
            base = r.copy()
            for _ in range(iterations):
                r = base - c * np.cos(r) - s * np.sin(r)
        return r

    # ------------------------------------------------------------------ kinematics
    def dcm_body_to_platform_actual(self, actual: ArrayLike) -> NDArray[np.float64]:
        """``C_b^p`` from actual angles (module docstring chain, with non-orthogonality)."""
        return chain_product(gimbal_chain(actual, self.configuration, self.nonorthogonality, self.outer_angle))

    def dcm_body_to_platform(self, readings: ArrayLike) -> NDArray[np.float64]:
        """``C_b^p`` from angle-sensor readings."""
        return self.dcm_body_to_platform_actual(self.actual_angles(readings))

    def dcm_nav_to_body(self) -> NDArray[np.float64]:
        """Return the true ``C_n^b`` of the base: surveyed attitude, then tilt and azimuth error (module docstring)."""
        yaw, pitch, roll = self.base_attitude
        t_north, t_east = self.base_tilt
        tilts = {"tilt_north": t_north, "tilt_east": t_east, "azimuth_error": self.base_azimuth}
        return nav_to_body(dcm_nav_to_body(yaw, pitch, roll), tilts)

    def dcm_nav_to_platform(self, readings: ArrayLike) -> NDArray[np.float64]:
        """``C_n^p = C_b^p(readings) C_n^b`` (exact)."""
        return self.dcm_body_to_platform(readings) @ self.dcm_nav_to_body()

    def specific_force_platform(self, readings: ArrayLike, gravity: float) -> NDArray[np.float64]:
        """Exact static specific force in the platform frame, ``f^p = C_b^p C_n^b f^n``."""
        return np.einsum("...ij,j->...i", self.dcm_nav_to_platform(readings), specific_force_nav(gravity))

    def angular_rate(self, actual: ArrayLike, actual_rate: ArrayLike) -> NDArray[np.float64]:
        r"""Angular rate of the platform relative to the base in the p-frame, ``omega_bp^p``.

        .. math::
            \omega_{bp}^p = s_1\dot\alpha_1 e_3 + R_3(s_1\alpha_1)R_2(\nu_{12})\big[s_2\dot\alpha_2 e_1
                            + R_1(s_2\alpha_2)R_3(\nu_{23})\,s_3\dot\alpha_3 e_2\big]
        """
        alpha = np.asarray(actual, dtype=float)
        rate = np.broadcast_to(np.asarray(actual_rate, dtype=float), alpha.shape)
        s1, s2, s3, _ = self.configuration.senses
        nu12, nu23 = self.nonorthogonality
        a, b = s1 * alpha[..., 0], s2 * alpha[..., 1]
        r1, r2, r3 = s1 * rate[..., 0], s2 * rate[..., 1], s3 * rate[..., 2]
        cb, sb = np.cos(b), np.sin(b)
        # inner = s2 a2' e1 + R1(b) R3(nu23) e2 s3 a3',  R3(nu) e2 = (sin nu, cos nu, 0)
        v0 = r2 + r3 * np.sin(nu23)
        v1 = r3 * cb * np.cos(nu23)
        v2 = -r3 * sb * np.cos(nu23)
        # R2(nu12) v = (c v0 - s v2, v1, s v0 + c v2); then R3(a) w = (ca w0 + sa w1, -sa w0 + ca w1, w2)
        c12, s12 = np.cos(nu12), np.sin(nu12)
        w0, w2 = c12 * v0 - s12 * v2, s12 * v0 + c12 * v2
        ca, sa = np.cos(a), np.sin(a)
        return np.stack([ca * w0 + sa * v1, -sa * w0 + ca * v1, w2 + r1], axis=-1)

    def rate_map(self, actual: ArrayLike) -> NDArray[np.float64]:
        """Return ``J(α)`` (..., 3, 3): ``ω_bp^p`` per unit rate of each gimbal (columns platform, inner, middle)."""
        alpha = np.asarray(actual, dtype=float)
        return np.stack([self.angular_rate(alpha, np.eye(3)[k]) for k in range(3)], axis=-1)

    def near_gimbal_lock(self, actual: ArrayLike) -> NDArray[np.bool_]:
        """Return whether the gimbals cannot turn the platform about some direction (``cond J >`` :data:`GIMBAL_LOCK_CONDITION`)."""
        return np.asarray(~(np.linalg.cond(self.rate_map(actual)) < GIMBAL_LOCK_CONDITION))

    # ------------------------------------------------------------------ inverse kinematics
    def actual_from_dcm(
        self, dcm_body_to_platform_: ArrayLike, initial: ArrayLike | None = None, iterations: int = 2
    ) -> NDArray[np.float64]:
        """Actual gimbal angles that produce a given ``C_b^p`` (outer angle held).

        Without ``initial``: closed form for the orthogonal chain ``R3(a) R1(b) R2(c)``,
        ``b = asin(-M21)`` in [-pi/2, pi/2], ``c = atan2(M20, M22)``, ``a = atan2(M01, M11)``,
        refined by Newton steps on the small rotation error when the axes are
        non-orthogonal.  With ``initial`` (angles close to the answer, any branch):
        Newton steps from there, which keeps the gimbal branch of ``initial``.
        """
        target = np.asarray(dcm_body_to_platform_, dtype=float)
        s1, s2, s3, s4 = self.configuration.senses
        if initial is None:
            m = target @ R3(s4 * self.outer_angle).swapaxes(-1, -2) if self.outer_angle else target
            b = np.arcsin(np.clip(-m[..., 2, 1], -1.0, 1.0))
            c = np.arctan2(m[..., 2, 0], m[..., 2, 2])
            a = np.arctan2(m[..., 0, 1], m[..., 1, 1])
            alpha = np.stack([s1 * a, s2 * b, s3 * c], axis=-1)
            if self.nonorthogonality == (0.0, 0.0):
                return alpha
        else:
            alpha = np.array(np.broadcast_to(np.asarray(initial, dtype=float), target.shape[:-2] + (3,)))
        eye = np.eye(3)
        for _ in range(iterations):
            residual = _rotation_vector(target @ self.dcm_body_to_platform_actual(alpha).swapaxes(-1, -2))
            # d(C_b^p) = -[(J dalpha) x] C_b^p with the columns of J the angular rates for unit gimbal rates
            jac = np.stack([self.angular_rate(alpha, np.broadcast_to(eye[k], alpha.shape)) for k in range(3)], axis=-1)
            alpha = alpha + np.linalg.solve(jac, residual[..., None])[..., 0]
        return alpha

    def readings_from_dcm_nav_to_platform(
        self, dcm_nav_to_platform_: ArrayLike, initial_readings: ArrayLike | None = None
    ) -> NDArray[np.float64]:
        """Angle-sensor readings that a platform with orientation ``C_n^p`` shows (exact inverse kinematics)."""
        c_bp = np.asarray(dcm_nav_to_platform_, dtype=float) @ self.dcm_nav_to_body().T
        initial = None if initial_readings is None else self.actual_angles(initial_readings)
        return self.readings_from_actual(self.actual_from_dcm(c_bp, initial))


def _rotation_vector(dcm: NDArray[np.float64]) -> NDArray[np.float64]:
    """Small-angle vector ``theta`` of a frame rotation ``C = I - [theta x] + O(theta^2)``."""
    return 0.5 * np.stack([dcm[..., 1, 2] - dcm[..., 2, 1], dcm[..., 2, 0] - dcm[..., 0, 2], dcm[..., 0, 1] - dcm[..., 1, 0]], axis=-1)


def rotation_about(axis_angle: ArrayLike) -> NDArray[np.float64]:
    r"""Frame rotation by the vector ``theta`` (right hand about its direction), exact Rodrigues form.

    ``C = I - sin|θ|/|θ| [θx] + (1-cos|θ|)/|θ|^2 [θx]^2``, so ``C = I - [θx] + O(θ^2)``
    like :func:`stableins.conventions.R1`.
    """
    from stableins.conventions import skew

    theta = np.asarray(axis_angle, dtype=float)
    angle = np.linalg.norm(theta, axis=-1)[..., None, None]
    k = skew(theta)
    safe = np.where(angle > 0, angle, 1.0)
    s = np.where(angle > 1e-4, np.sin(angle) / safe, 1.0 - angle**2 / 6.0)
    c = np.where(angle > 1e-4, (1.0 - np.cos(angle)) / safe**2, 0.5 - angle**2 / 24.0)
    return np.eye(3) - s * k + c * (k @ k)


def rotation_vector(dcm: ArrayLike) -> NDArray[np.float64]:
    """Inverse of :func:`rotation_about`: the vector ``θ`` with ``rotation_about(θ) = dcm`` (``|θ| < π``), vectorized.

    ``rotation_about(θ) = exp(−[θ×])``, so ``θ`` is minus the rotation vector of ``dcm`` as an active rotation.
    """
    from scipy.spatial.transform import Rotation

    matrix = np.asarray(dcm, dtype=float)
    flat = matrix.reshape(-1, 3, 3)
    out = -Rotation.from_matrix(flat).as_rotvec()
    return out.reshape(matrix.shape[:-2] + (3,))
