r"""Exact platform kinematics with test-equipment imperfections, and their analytic Jacobian.

The platform-frame specific force of a static position is

.. math::
    f^p = C_b^p(\alpha)\, C_n^b\, f^n ,\qquad f^n = (0, 0, -g)

with the gimbal chain of :mod:`stableins.conventions`.  Model discovery needs the same
chain with the test-equipment effects that the standard model leaves out:

* **gimbal-axis non-orthogonality** ``nonorth_12`` (platform axis z vs inner axis x) and
  ``nonorth_23`` (inner axis x vs middle axis y): a small frame rotation about the common
  normal of the two axes inserted between their rotations,
  ``C_b^p = R3(s1 α1) R2(n12) R1(s2 α2) R3(n23) R2(s3 α3) R3(s4 q)``.  A rotation about
  either axis itself would be a zero offset; the common normal (z × x = y, x × y = z) is
  the only new direction.
* **base tilt and azimuth** ``tilt_north``, ``tilt_east``, ``azimuth_error``: the true base is
  the surveyed one turned by ``tilt_north`` about North, ``tilt_east`` about East and
  ``azimuth_error`` about Down, ``C_n^b = C_n^b(yaw, pitch, roll) R2(t_E) R1(t_N) R3(ψ_e)``
  (as :mod:`stableins.platform`).  ``R3(ψ_e)`` leaves ``f^n = (0, 0, −g)`` unchanged: the
  azimuth error is invisible to gravity (it matters at system level, through the Earth rate).
* **once-per-revolution angle-sensor error** ``ang1_<gimbal>_c``, ``ang1_<gimbal>_s``:
  the actual angle is ``α_i = r_i + θ_i0 + c_i cos r_i + s_i sin r_i``.

The derivative of a chain of frame rotations with respect to the angle of one factor is
exact and simple: ``d R_k(a)/da = −[e_k×] R_k(a)`` (because ``R_k(a) = exp(−a[e_k×])``),
so ``∂C/∂a_j = P_j (−[e_k×]) R_k(a_j) S_j`` with ``P_j``, ``S_j`` the products before and after
factor ``j``.  Everything here is tested against central differences of
:func:`platform_specific_force`.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stableins.conventions import DEFAULT_GIMBALS, R1, R2, R3, GimbalConfiguration, dcm_nav_to_body, skew

#: Gimbal names in angle-sensor order (platform z, inner x, middle y), as in the data schema.
GIMBAL_NAMES = ("platform", "inner", "middle")

#: Ids of the kinematic (test-equipment) effects.
KINEMATIC_IDS = (
    "nonorth_12",
    "nonorth_23",
    "tilt_north",
    "tilt_east",
    "azimuth_error",
    *(f"ang1_{g}_{cs}" for g in GIMBAL_NAMES for cs in ("c", "s")),
)
#: Zero-offset ids, in gimbal order.
OFFSET_IDS = ("theta10", "theta20", "theta30")

_ROT = (R1, R2, R3)
_E = np.eye(3)


def _chain(readings: NDArray, offsets: NDArray, effects: Mapping[str, float], senses) -> list[tuple[int, NDArray]]:
    """Factors (axis, angle) of ``C_b^p`` from the platform outwards (left to right)."""
    s1, s2, s3, s4 = senses
    alpha = readings + offsets
    for i, g in enumerate(GIMBAL_NAMES):
        c = effects.get(f"ang1_{g}_c", 0.0)
        s = effects.get(f"ang1_{g}_s", 0.0)
        alpha[..., i] = alpha[..., i] + c * np.cos(readings[..., i]) + s * np.sin(readings[..., i])
    zero = np.zeros(readings.shape[:-1])
    return [
        (2, s1 * alpha[..., 0]),
        (1, zero + effects.get("nonorth_12", 0.0)),
        (0, s2 * alpha[..., 1]),
        (2, zero + effects.get("nonorth_23", 0.0)),
        (1, s3 * alpha[..., 2]),
        (2, zero * s4),  # outer (azimuth) gimbal held at zero
    ]


def _nav_to_body(base_attitude: ArrayLike, effects: Mapping[str, float]) -> NDArray:
    yaw, pitch, roll = np.asarray(base_attitude, dtype=float)
    tilt = R2(effects.get("tilt_east", 0.0)) @ R1(effects.get("tilt_north", 0.0)) @ R3(effects.get("azimuth_error", 0.0))
    return dcm_nav_to_body(yaw, pitch, roll) @ tilt


def _product(factors: list[tuple[int, NDArray]]) -> NDArray:
    out = None
    for axis, angle in factors:
        m = _ROT[axis](angle)
        out = m if out is None else out @ m
    return out


def platform_specific_force(
    readings: ArrayLike,
    gravity: float,
    zero_offsets: ArrayLike = (0.0, 0.0, 0.0),
    base_attitude: ArrayLike = (0.0, 0.0, 0.0),
    effects: Mapping[str, float] | None = None,
    configuration: GimbalConfiguration = DEFAULT_GIMBALS,
) -> NDArray[np.float64]:
    r"""``f^p`` of static positions from angle-sensor readings, exactly.

    .. math:: f^p = R_3(s_1\alpha_1) R_2(n_{12}) R_1(s_2\alpha_2) R_3(n_{23}) R_2(s_3\alpha_3)
              \, C_n^b(\psi,\theta,\phi) R_2(t_E) R_1(t_N)\,(0, 0, -g)^T

    Parameters
    ----------
    readings : array_like (..., 3)
        Angle-sensor readings (platform, inner, middle) [rad].
    gravity : float
        Local gravity [m/s²].
    zero_offsets : array_like (3,)
        ``theta10, theta20, theta30`` [rad].
    base_attitude : array_like (3,)
        Nominal (yaw, pitch, roll) of the base [rad].
    effects : mapping, optional
        Values of :data:`KINEMATIC_IDS` [rad]; absent ids are zero.
    configuration : GimbalConfiguration
        Rotation senses.

    Returns
    -------
    ndarray (..., 3)
        ``f^p`` [m/s²].
    """
    effects = {} if effects is None else effects
    r = np.asarray(readings, dtype=float)
    chain = _chain(r.copy(), np.asarray(zero_offsets, dtype=float), effects, configuration.senses)
    f_b = _nav_to_body(base_attitude, effects) @ np.array([0.0, 0.0, -gravity])
    return np.einsum("...ij,j->...i", _product(chain), f_b)


def platform_jacobian(
    readings: ArrayLike,
    gravity: float,
    zero_offsets: ArrayLike = (0.0, 0.0, 0.0),
    base_attitude: ArrayLike = (0.0, 0.0, 0.0),
    effects: Mapping[str, float] | None = None,
    configuration: GimbalConfiguration = DEFAULT_GIMBALS,
    ids: tuple[str, ...] = OFFSET_IDS + KINEMATIC_IDS,
) -> NDArray[np.float64]:
    r"""Analytic ``∂f^p/∂p`` for zero offsets and kinematic effects, shape ``(..., 3, len(ids))``.

    Uses ``∂R_k(a)/∂a = −[e_k×] R_k(a)`` inside the chain; the angle of gimbal ``i``
    depends on ``θ_i0`` with slope ``s_i`` and on ``ang1_i_c``/``ang1_i_s`` with slopes
    ``s_i cos r_i``/``s_i sin r_i``; the base tilts act on ``C_n^b`` likewise.
    """
    effects = {} if effects is None else effects
    r = np.asarray(readings, dtype=float)
    chain = _chain(r.copy(), np.asarray(zero_offsets, dtype=float), effects, configuration.senses)
    nav_to_body = _nav_to_body(base_attitude, effects)
    f_n = np.array([0.0, 0.0, -gravity])
    f_b = nav_to_body @ f_n
    mats = [_ROT[axis](angle) for axis, angle in chain]
    n = len(mats)
    # suffix products applied to f_b: v_j = M_j ... M_{n-1} f_b ; prefix P_j = M_0 ... M_{j-1}
    suffix = [None] * (n + 1)
    suffix[n] = np.broadcast_to(f_b, r.shape).copy()
    for j in range(n - 1, -1, -1):
        suffix[j] = np.einsum("...ij,...j->...i", mats[j], suffix[j + 1])
    prefix = [np.broadcast_to(_E, r.shape[:-1] + (3, 3))]
    for j in range(n):
        prefix.append(prefix[-1] @ mats[j])

    def d_factor(j: int) -> NDArray:
        """∂f^p/∂(angle of factor j)."""
        axis = chain[j][0]
        inner = -np.cross(_E[axis], suffix[j])  # −[e×] (R_j S_j f_b)
        return np.einsum("...ij,...j->...i", prefix[j], inner)

    full = prefix[n]  # C_b^p

    def d_tilt(rotation_axis: int) -> NDArray:
        """∂f^p/∂(base rotation about North, East or Down): C_b^p C_ypr [R2 R1 R3 with one factor differentiated] f^n."""
        yaw_pitch_roll = dcm_nav_to_body(*np.asarray(base_attitude, dtype=float))
        factors = [(1, effects.get("tilt_east", 0.0)), (0, effects.get("tilt_north", 0.0)), (2, effects.get("azimuth_error", 0.0))]
        m = yaw_pitch_roll
        v = None
        for axis, angle in factors:
            rot = _ROT[axis](angle)
            m = m @ (-skew(_E[axis]) @ rot if axis == rotation_axis else rot)
        v = m @ f_n
        return np.einsum("...ij,j->...i", full, v)

    senses = configuration.senses
    gimbal_factor = (0, 2, 4)
    columns = []
    for pid in ids:
        if pid in OFFSET_IDS:
            i = OFFSET_IDS.index(pid)
            columns.append(senses[i] * d_factor(gimbal_factor[i]))
        elif pid == "nonorth_12":
            columns.append(d_factor(1))
        elif pid == "nonorth_23":
            columns.append(d_factor(3))
        elif pid == "tilt_north":
            columns.append(d_tilt(0))
        elif pid == "tilt_east":
            columns.append(d_tilt(1))
        elif pid == "azimuth_error":
            columns.append(d_tilt(2))
        elif pid.startswith("ang1_"):
            _, g, cs = pid.split("_")
            i = GIMBAL_NAMES.index(g)
            slope = np.cos(r[..., i]) if cs == "c" else np.sin(r[..., i])
            columns.append(senses[i] * slope[..., None] * d_factor(gimbal_factor[i]))
        else:
            raise KeyError(f"{pid!r} is not a kinematic parameter (known: {', '.join(OFFSET_IDS + KINEMATIC_IDS)})")
    return np.stack(columns, axis=-1)
