r"""Extra physical effects the world can contain, injectable by id with a magnitude [SI].

Two kinds:

``output`` effects add to the accelerometer output *before* the quadratic
nonlinearity of Eq. 6 (they enter ``w`` of :meth:`stableins.simulator.physics.Accelerometer.output`
as additive effects), each as ``value × regressor``.  The regressors below are the
simulator's own physics, written here; they do not come from any estimator.
``f`` is the platform-frame specific force ``f^p`` along the nominal sensitive axes,
``ΔT`` the temperature minus the reference, ``t`` the session time.

``geometry`` effects change the platform kinematics (:mod:`stableins.platform`) or
the platform's motion (:mod:`stableins.simulator.device`).

``timing`` effects shift when the instrument samples: ``t_async`` = ``τ`` [s], the
accelerometer sample stamped ``t`` is the accelerometer's whole input (specific force,
lever-arm accelerations) at ``t − τ`` on the exact slew path, while the angle readings
stay at ``t`` (device-level simulator; docs/conventions.md "Lever arms and time
asynchrony": to first order ``δf = τ ω × f^p``, a formula the simulator does not use).

===============  ==============================================================
id               added output of accelerometer ``a`` (axis a in x, y, z)
===============  ==============================================================
``K3_a``         ``K3 f_a³``
``Koq_a``        ``Koq f_a |f_a|``
``Ksa_a``        ``Ksa |f_a|``: scale factor ``1 + Ksa`` for positive input and
                 ``1 − Ksa`` for negative input; ``(SF₊ − SF₋)/SF = 2 Ksa``
``Kcq_ab``       ``Kcq f_b²`` (b ≠ a)
``Kcc_abc``      ``Kcc f_b f_c`` (b < c in x < y < z; Cai et al. 2016 K_abc where a is b or c, else IEEE Std 1293)
``Kt_bias_a``    ``Kt ΔT``
``Kt_sf_a``      ``Kt ΔT f_a`` (scale factor changes by ``Kt`` per kelvin)
``Kd_bias_a``    ``Kd t``
``Kh_a``         ``Kh h_a``: hysteresis state ``h_a`` (+1/−1/0) of axis a, the sign of
                 the last slew that moved ``f_a`` by more than ``HYSTERESIS_THRESHOLD``
                 (0.01 m/s²); smaller changes keep the state; 0 before the first such
                 slew (changes measured from ``f^p`` at the initial readings)
``lever_a_b``    ``e_a · (ω̇ × r + ω × (ω × r))`` with ``r = lever_a_b e_b`` the proof-mass
                 position of accelerometer a from the rotation centre; ``ω`` platform
                 angular rate: non-zero only while the platform moves (slews, settling)
===============  ==============================================================

Geometry effects: ``Dg_ab`` (g-sensitivity of the gyro about p-axis a to the specific force
along p-axis b, a gyro output error: the stabilized platform turns at ``−D_g f^p``,
:func:`stableins.conventions.platform_drift_rate`, after each slew, as the site's dwell mode says; the angle sensors
see it),
``nonorth_12``, ``nonorth_23``
(gimbal-axis non-orthogonality, :mod:`stableins.platform`), ``tilt_north``,
``tilt_east`` (base tilt), ``azimuth_error`` (base azimuth), ``ang1_<gimbal>_c`` / ``_s`` (once-per-revolution angle
sensor error ``c cos r + s sin r``).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from types import MappingProxyType

import numpy as np
from numpy.typing import NDArray

from stableins.conventions import ARCSEC, AXES, DEG_PER_HOUR, HYSTERESIS_THRESHOLD, MICRO_G, PPM, STANDARD_GRAVITY
from stableins.errors import InputError
from stableins.simulator.physics import Regressor, SensorInputs

_G = STANDARD_GRAVITY


def hysteresis_state(
    previous: NDArray[np.float64], change: NDArray[np.float64], threshold: float = HYSTERESIS_THRESHOLD
) -> NDArray[np.float64]:
    r"""Hysteresis state of each axis after a slew (threshold plus memory).

    .. math:: h_a^{+} = \operatorname{sign}(\Delta f_a)\ \text{if}\ |\Delta f_a| > f_{th},\ \text{else}\ h_a

    (IEEE Std 1293 hysteresis: the output depends on the direction from which the input was
    approached; the state changes only with an input excursion beyond ``f_th``).

    Parameters
    ----------
    previous : ndarray (3,)
        State before the slew (+1/−1; 0 before any slew moved the axis' input beyond ``threshold``).
    change : ndarray (3,)
        Change of the platform specific force ``f^p`` over the slew [m/s²].
    threshold : float
        ``f_th`` [m/s²] (default :data:`HYSTERESIS_THRESHOLD`).
    """
    change = np.asarray(change, dtype=float)
    return np.where(np.abs(change) > threshold, np.sign(change), np.asarray(previous, dtype=float))


@dataclass(frozen=True)
class Effect:
    """One injectable physical effect.

    Attributes
    ----------
    id, unit, nominal, meaning :
        Stable id, SI unit, typical magnitude [SI], one-line meaning.
    kind : str
        ``"output"`` (adds to the accelerometer output), ``"geometry"`` or ``"timing"``.
    regressor : callable or None
        For output effects: ``SensorInputs -> (..., 3)`` output change per unit value.
    axis : int or None
        Accelerometer axis (output effects) or gyro axis (``Dg_ab``: ``a``).
    """

    id: str
    unit: str
    nominal: float
    meaning: str
    kind: str
    regressor: Regressor | None = None
    axis: int | None = None


def _on_axis(axis: int, values: Callable[[SensorInputs], NDArray[np.float64]]) -> Callable[[SensorInputs], NDArray[np.float64]]:
    def regressor(inputs: SensorInputs) -> NDArray[np.float64]:
        v = values(inputs)
        out = np.zeros(np.shape(v) + (3,))
        out[..., axis] = v
        return out

    return regressor


def _f(inputs: SensorInputs, i: int) -> NDArray[np.float64]:
    return np.asarray(inputs.specific_force, dtype=float)[..., i]


def _broadcast_scalar(inputs: SensorInputs, name: str, term_id: str) -> NDArray[np.float64]:
    v = inputs.require(name, term_id)
    return np.broadcast_to(v, np.shape(inputs.specific_force)[:-1])


def _lever_matrix(inputs: SensorInputs, term_id: str) -> NDArray[np.float64]:
    from stableins.conventions import skew

    w = inputs.require("angular_rate", term_id)
    wd = inputs.require("angular_acceleration", term_id)
    sw = skew(w)
    return skew(wd) + sw @ sw


def _nonlinearity_effects(i: int, a: str) -> list[Effect]:
    """Nonlinear output effects of accelerometer ``i`` (axis name ``a``): K3, Koq, Ksa, Kcq, Kcc."""
    effects = [
        Effect(
            f"K3_{a}",
            "s^4/m^2",
            MICRO_G / _G**3,
            f"cubic nonlinearity of the {a} accelerometer: + K3 f_{a}^3",
            "output",
            _on_axis(i, lambda x: _f(x, i) ** 3),
            i,
        ),
        Effect(
            f"Koq_{a}",
            "s^2/m",
            10 * MICRO_G / _G**2,
            f"odd quadratic of the {a} accelerometer: + Koq f_{a}|f_{a}|",
            "output",
            _on_axis(i, lambda x: _f(x, i) * np.abs(_f(x, i))),
            i,
        ),
        Effect(
            f"Ksa_{a}",
            "1",
            10 * PPM,
            f"scale-factor asymmetry of the {a} accelerometer: + Ksa |f_{a}| ((SF+ - SF-)/SF = 2 Ksa)",
            "output",
            _on_axis(i, lambda x: np.abs(_f(x, i))),
            i,
        ),
    ]
    effects += [_cross_quadratic_effect(i, a, j) for j in range(3) if j != i]
    effects += [_cross_coupling_effect(i, a, j, k) for j in range(3) for k in range(j + 1, 3)]
    return effects


def _cross_quadratic_effect(i: int, a: str, j: int) -> Effect:
    """Kcq: accelerometer ``i`` (axis name ``a``) sensitive to the square of the specific force along ``j``."""
    b = AXES[j]
    return Effect(
        f"Kcq_{a}{b}",
        "s^2/m",
        5 * MICRO_G / _G**2,
        f"cross-axis quadratic: {a} accelerometer + Kcq f_{b}^2",
        "output",
        _on_axis(i, lambda x: _f(x, j) ** 2),
        i,
    )


def _cross_coupling_effect(i: int, a: str, j: int, k: int) -> Effect:
    """Kcc: accelerometer ``i`` (axis name ``a``) sensitive to the product of the specific forces along ``j`` and ``k``."""
    return Effect(
        f"Kcc_{a}{AXES[j]}{AXES[k]}",
        "s^2/m",
        10 * MICRO_G / _G**2,
        f"cross-coupling: {a} accelerometer + Kcc f_{AXES[j]} f_{AXES[k]} "
        + ("(Cai et al. 2016 K_cross)" if a in (AXES[j], AXES[k]) else "(IEEE Std 1293; not in Cai et al. 2016)"),
        "output",
        _on_axis(i, lambda x: _f(x, j) * _f(x, k)),
        i,
    )


def _environment_effects(i: int, a: str) -> list[Effect]:
    """Output effects of accelerometer ``i`` (axis name ``a``) driven by temperature, time, history and rotation."""
    effects = [
        Effect(
            f"Kt_bias_{a}",
            "m/s^2/K",
            5 * MICRO_G,
            f"bias temperature sensitivity of the {a} accelerometer: + Kt dT",
            "output",
            _on_axis(i, lambda x: _broadcast_scalar(x, "temperature", f"Kt_bias_{a}")),
            i,
        ),
        Effect(
            f"Kt_sf_{a}",
            "1/K",
            5 * PPM,
            f"scale-factor temperature sensitivity of the {a} accelerometer: + Kt dT f_{a}",
            "output",
            _on_axis(i, lambda x: _broadcast_scalar(x, "temperature", f"Kt_sf_{a}") * _f(x, i)),
            i,
        ),
        Effect(
            f"Kd_bias_{a}",
            "m/s^3",
            10 * MICRO_G / 86400.0,
            f"bias drift in time of the {a} accelerometer: + Kd t",
            "output",
            _on_axis(i, lambda x: _broadcast_scalar(x, "time", f"Kd_bias_{a}")),
            i,
        ),
        Effect(
            f"Kh_{a}",
            "m/s^2",
            5 * MICRO_G,
            f"hysteresis of the {a} accelerometer: + Kh sign(last change of f_{a} over a slew > 0.01 m/s^2)",
            "output",
            _on_axis(i, lambda x: x.require("slew_direction", f"Kh_{a}")[..., i]),
            i,
        ),
    ]
    return effects + [_lever_effect(i, a, j) for j in range(3)]


def _lever_effect(i: int, a: str, j: int) -> Effect:
    """Proof-mass position of accelerometer ``i`` (axis name ``a``) along platform axis ``j``."""
    b = AXES[j]
    return Effect(
        f"lever_{a}_{b}",
        "m",
        0.02,
        f"proof-mass position of the {a} accelerometer along {b}_p (size effect, only while rotating)",
        "output",
        _on_axis(i, lambda x: _lever_matrix(x, f"lever_{a}_{b}")[..., i, j]),
        i,
    )


def _geometry_effects() -> list[Effect]:
    """Effects on the geometry of the platform: g-sensitive drift, non-orthogonality, base tilt, angle sensors."""
    effects = [
        Effect(
            f"Dg_{a}{b}",
            "rad s/m",
            0.01 * DEG_PER_HOUR / _G,
            f"g-sensitivity of the {a}_p gyro to f_{b} (the platform turns at -Dg f_{b} about {a}_p during a dwell) [rad/s per m/s^2]",
            "geometry",
            axis=i,
        )
        for i, a in enumerate(AXES)
        for b in AXES
    ]
    effects += [
        Effect(
            "nonorth_12",
            "rad",
            10 * ARCSEC,
            "non-orthogonality of the platform (z) and inner (x) gimbal axes (angle pi/2 + nu12)",
            "geometry",
        ),
        Effect(
            "nonorth_23",
            "rad",
            10 * ARCSEC,
            "non-orthogonality of the inner (x) and middle (y) gimbal axes (angle pi/2 + nu23)",
            "geometry",
        ),
        Effect(
            "tilt_north", "rad", 10 * ARCSEC, "unknown base tilt about North (right-handed) relative to the surveyed attitude", "geometry"
        ),
        Effect(
            "tilt_east", "rad", 10 * ARCSEC, "unknown base tilt about East (right-handed) relative to the surveyed attitude", "geometry"
        ),
        Effect(
            "azimuth_error", "rad", 30 * ARCSEC, "unknown base azimuth error about Down (right-handed) relative to the survey", "geometry"
        ),
    ]
    for g in ("platform", "inner", "middle"):
        effects.append(
            Effect(f"ang1_{g}_c", "rad", 2 * ARCSEC, f"once-per-revolution {g} angle-sensor error: actual += c cos(reading)", "geometry")
        )
        effects.append(
            Effect(f"ang1_{g}_s", "rad", 2 * ARCSEC, f"once-per-revolution {g} angle-sensor error: actual += s sin(reading)", "geometry")
        )
    return effects


#: The timing effect: time asynchrony of the accelerometer samples against the angle readings [s].
TIME_ASYNC = Effect(
    "t_async",
    "s",
    1e-4,
    "time asynchrony: the accelerometer sample stamped t is taken at t - t_async (> 0: the accelerometers lag the angle readings)",
    "timing",
)


def _build() -> dict[str, Effect]:
    """Build the catalogue: every effect by id, per accelerometer axis first, then the geometry and the timing."""
    effects: list[Effect] = []
    for i, a in enumerate(AXES):
        effects += _nonlinearity_effects(i, a) + _environment_effects(i, a)
    effects += _geometry_effects() + [TIME_ASYNC]
    catalogue = {e.id: e for e in effects}
    assert len(catalogue) == len(effects), "effect ids are unique"
    return catalogue


#: All injectable effects by id (read-only).
CATALOGUE: Mapping[str, Effect] = MappingProxyType(_build())


#: An injected effect may be at most this many times its nominal size (beyond, the model leaves its domain:
#: a quadratic output reaches its fold, angles leave the small-angle regime).
MAX_EFFECT_FACTOR = 1e4


def validate_effects(effects: Mapping[str, float], source: str | None = None) -> dict[str, float]:
    """Check ids and values; return a plain ``dict`` of floats.

    Raises
    ------
    InputError
        Unknown id (the message lists the known ids) or a non-finite value.
    """
    out: dict[str, float] = {}
    for key, value in effects.items():
        if key not in CATALOGUE:
            raise InputError(f"unknown effect id {key!r}", path=source, field="effects", expected=f"one of {', '.join(CATALOGUE)}")
        try:
            v = float(value)
        except (TypeError, ValueError):
            raise InputError(f"effect {key!r} has a non-numeric value {value!r}", path=source, field=f"effects.{key}") from None
        if not np.isfinite(v):
            raise InputError(f"effect {key!r} is not finite", path=source, field=f"effects.{key}", expected="a finite SI value")
        limit = MAX_EFFECT_FACTOR * abs(CATALOGUE[key].nominal)
        if abs(v) > limit:
            raise InputError(
                f"effect {key!r} = {v:g} {CATALOGUE[key].unit} is beyond any instrument this simulator models",
                path=source,
                field=f"effects.{key}",
                expected=f"at most {MAX_EFFECT_FACTOR:g} × its nominal size, |value| <= {limit:.3g} {CATALOGUE[key].unit}",
            )
        out[key] = v
    return out


def output_effects(effects: Mapping[str, float]) -> tuple[tuple[str, Regressor], ...]:
    """``(id, regressor)`` of the non-zero output effects in ``effects``, in their order (for ``physics.Accelerometer``)."""
    out = []
    for key, value in effects.items():
        regressor = CATALOGUE[key].regressor
        if CATALOGUE[key].kind == "output" and value != 0.0 and regressor is not None:
            out.append((key, regressor))
    return tuple(out)


def g_sensitivity(effects: Mapping[str, float]) -> NDArray[np.float64]:
    """Return the gyro g-sensitivity matrix ``D_g`` (3, 3) [rad/s per m/s²] of the ``Dg_ab`` effects (zero if none)."""
    return np.array([[float(effects.get(f"Dg_{a}{b}", 0.0)) for b in AXES] for a in AXES])


def needs(effects: Mapping[str, float], prefix: str) -> bool:
    """Whether any non-zero effect id starts with ``prefix``."""
    return any(k.startswith(prefix) and v != 0.0 for k, v in effects.items())


def catalogue_table() -> list[tuple[str, str, float, str]]:
    """``(id, SI unit, nominal, meaning)`` rows for documentation."""
    return [(e.id, e.unit, e.nominal, e.meaning) for e in CATALOGUE.values()]
