"""The shipped candidate effects of model discovery.

Each is an additive error-model term with its group and the procedure that separates it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace
from functools import partial

import numpy as np
from numpy.typing import NDArray

from stableins.conventions import ARCSEC, AXES, MICRO_G, PPM, STANDARD_GRAVITY
from stableins.errormodel import GYRO_G_TERMS, Term, TermInputs, TermKind
from stableins.terms import CROSS_COUPLING_TERMS, MICRO_G_PER_G2

G0 = STANDARD_GRAVITY
MICRO_G_PER_G3 = MICRO_G / G0**3

#: Groups of candidates, for reports.
CANDIDATE_GROUPS = ("instrument", "environment", "rotation", "equipment", "custom")


@dataclass(frozen=True)
class Candidate:
    """A library entry: the error-model term plus what discovery needs to explain it.

    Attributes
    ----------
    term : Term
        The additive error-model term (id, regressor, units, meaning, excitation, aliases).
    group : str
        One of :data:`CANDIDATE_GROUPS`.
    separation : str
        A procedure that separates the effect from the standard model's parameters.
    needs : tuple of str
        ``TermInputs`` fields the regressor reads (``"temperature"``, ``"time"`` ...).
    """

    term: Term
    group: str
    separation: str
    needs: tuple[str, ...] = field(default=())

    @property
    def id(self) -> str:
        """Id of the candidate's term."""
        return self.term.id


# ----------------------------------------------------------------------------- regressors
def _on_axis(axis: int, values: NDArray) -> NDArray:
    out = np.zeros(values.shape + (3,))
    out[..., axis] = values
    return out


def _f(inputs: TermInputs) -> NDArray:
    return np.asarray(inputs.specific_force, dtype=float)


def _polynomial(axis: int, function: Callable[[NDArray], NDArray]) -> Callable[[TermInputs], NDArray]:
    return lambda inputs: _on_axis(axis, function(_f(inputs)))


def _cubed(f: NDArray, *, i: int) -> NDArray:
    return f[..., i] ** 3


def _signed_square(f: NDArray, *, i: int) -> NDArray:
    return f[..., i] * np.abs(f[..., i])


def _squared(f: NDArray, *, i: int) -> NDArray:
    return f[..., i] ** 2


def _absolute(f: NDArray, *, i: int) -> NDArray:
    return np.abs(f[..., i])


def _series_on_axis(i: int, series: NDArray, _inputs: TermInputs) -> NDArray:
    return _on_axis(i, series)


def _input_times_series(i: int, series: NDArray, inputs: TermInputs) -> NDArray:
    return _on_axis(i, _f(inputs)[..., i] * series)


def _component_on_axis(i: int, series: NDArray, _inputs: TermInputs) -> NDArray:
    return _on_axis(i, series[..., i])


def _needs(term_id: str, name: str, build: Callable[[NDArray, TermInputs], NDArray]) -> Callable[[TermInputs], NDArray]:
    def regressor(inputs: TermInputs) -> NDArray:
        return build(inputs.require(name, term_id), inputs)

    return regressor


def _lever(axis: int, offset_axis: int, term_id: str) -> Callable[[TermInputs], NDArray]:
    e = np.eye(3)[offset_axis]

    def regressor(inputs: TermInputs) -> NDArray:
        w = inputs.require("angular_rate", term_id)
        dw = inputs.require("angular_acceleration", term_id)
        acc = np.cross(dw, e) + np.cross(w, np.cross(w, np.broadcast_to(e, w.shape)))
        return _on_axis(axis, acc[..., axis])

    return regressor


def _drift(axis: int, term_id: str) -> Callable[[TermInputs], NDArray]:
    """Zero: the angle sensors measure the drifting platform, so f^a stays consistent with the readings.

    The drift shows in the slopes of the readings within dwells (:mod:`stableins.discovery.drift`).
    """

    def regressor(inputs: TermInputs) -> NDArray:
        return np.zeros_like(_f(inputs))

    return regressor


def _kinematic(term_id: str) -> Callable[[TermInputs], NDArray]:
    def regressor(inputs: TermInputs) -> NDArray:
        columns, names = inputs.platform_jacobian, inputs.platform_jacobian_ids
        if columns is None or term_id not in names:
            raise ValueError(f"term {term_id!r} acts through the gimbal kinematics; these data carry no angle readings for it")
        return np.asarray(columns, dtype=float)[..., names.index(term_id)]

    return regressor


# ----------------------------------------------------------------------------- library
_STATIC_SEPARATION = "positions with the axis at intermediate inputs (45° positions, e.g. the 12 tilted positions of Wu et al. Table 1)"


def _instrument_powers() -> list[Candidate]:
    out: list[Candidate] = []
    for i, a in enumerate(AXES):
        out.append(
            Candidate(
                Term(
                    f"K3_{a}",
                    TermKind.ADDITIVE,
                    "s^4/m^2",
                    "ug/g^3",
                    MICRO_G_PER_G3,
                    10 * MICRO_G_PER_G3,
                    f"cubic nonlinearity of the {a} accelerometer (IEEE 1293 K3)",
                    axis=i,
                    regressor=_polynomial(i, partial(_cubed, i=i)),
                    excitation="the axis at ±1 g and at intermediate inputs (±0.7 g)",
                    aliases=(f"sf_{a}",),
                    source="IEEE Std 1293 model equation",
                ),
                "instrument",
                _STATIC_SEPARATION + "; at ±1 g and 0 g only, f³ = g² f is a scale factor",
            )
        )
        out.append(
            Candidate(
                Term(
                    f"Koq_{a}",
                    TermKind.ADDITIVE,
                    "s^2/m",
                    "ug/g^2",
                    MICRO_G_PER_G2,
                    10 * MICRO_G_PER_G2,
                    f"odd quadratic nonlinearity f|f| of the {a} accelerometer (IEEE 1293 Koq)",
                    axis=i,
                    regressor=_polynomial(i, partial(_signed_square, i=i)),
                    excitation="the axis at ±1 g and at intermediate inputs",
                    aliases=(f"sf_{a}",),
                    source="IEEE Std 1293 model equation",
                ),
                "instrument",
                _STATIC_SEPARATION + "; at ±1 g and 0 g only, f|f| = g f is a scale factor",
            )
        )
        out.append(
            Candidate(
                Term(
                    f"Ksa_{a}",
                    TermKind.ADDITIVE,
                    "1",
                    "ppm",
                    PPM,
                    20 * PPM,
                    f"scale-factor asymmetry of the {a} accelerometer: output gains Ksa·|f| (half the difference of the "
                    "positive- and negative-input scale factors)",
                    axis=i,
                    regressor=_polynomial(i, partial(_absolute, i=i)),
                    excitation="the axis at ±1 g and at intermediate inputs",
                    aliases=(f"K2_{a}", f"bias_{a}"),
                    source="IEEE Std 1293 (scale-factor asymmetry)",
                ),
                "instrument",
                _STATIC_SEPARATION + "; at ±1 g and 0 g only, |f| = f²/g is a quadratic coefficient",
            )
        )
    return out


def _instrument_couplings() -> list[Candidate]:
    out: list[Candidate] = []
    for i, a in enumerate(AXES):
        for j, b in enumerate(AXES):
            if j == i:
                continue
            out.append(
                Candidate(
                    Term(
                        f"Kcq_{a}{b}",
                        TermKind.ADDITIVE,
                        "s^2/m",
                        "ug/g^2",
                        MICRO_G_PER_G2,
                        10 * MICRO_G_PER_G2,
                        f"sensitivity of the {a} accelerometer to the square of the {b} input (IEEE 1293 Kpp/Koo)",
                        axis=i,
                        regressor=_polynomial(i, partial(_squared, i=j)),
                        excitation=f"the {b} input at several magnitudes with the {a} axis horizontal and vertical",
                        aliases=(f"bias_{a}",),
                        source="IEEE Std 1293 model equation",
                    ),
                    "instrument",
                    f"positions where f_{b}² takes at least two values while the other inputs are fixed",
                )
            )
    for term in CROSS_COUPLING_TERMS:  # defined with the record's terms (stableins.terms): the systematic stage estimates them
        b, c = term.id[-2], term.id[-1]
        out.append(Candidate(term, "instrument", f"45° positions in the {b}{c} plane with both signs of f_{b}·f_{c}"))
    return out


def _environment() -> list[Candidate]:
    out: list[Candidate] = []
    for i, a in enumerate(AXES):
        out.append(
            Candidate(
                Term(
                    f"Kt_bias_{a}",
                    TermKind.ADDITIVE,
                    "m/s^2/K",
                    "ug/K",
                    MICRO_G,
                    5 * MICRO_G,
                    f"bias temperature sensitivity of the {a} accelerometer (ΔT from the reference temperature)",
                    axis=i,
                    regressor=_needs(f"Kt_bias_{a}", "temperature", partial(_series_on_axis, i)),
                    excitation="a temperature change during the procedure",
                    aliases=(f"bias_{a}", f"Kd_bias_{a}"),
                    source="IEEE Std 1293 (environment sensitivity)",
                ),
                "environment",
                "a temperature step or ramp that is not linear in time (warm-up, then repeat positions)",
                needs=("temperature",),
            )
        )
        out.append(
            Candidate(
                Term(
                    f"Kt_sf_{a}",
                    TermKind.ADDITIVE,
                    "1/K",
                    "ppm/K",
                    PPM,
                    5 * PPM,
                    f"scale-factor temperature sensitivity of the {a} accelerometer: output gains Kt_sf·f·ΔT",
                    axis=i,
                    regressor=_needs(f"Kt_sf_{a}", "temperature", partial(_input_times_series, i)),
                    excitation="±1 g positions of the axis at two or more temperatures",
                    aliases=(f"sf_{a}",),
                    source="IEEE Std 1293 (environment sensitivity)",
                ),
                "environment",
                "repeat the up/down positions of the axis at a different temperature",
                needs=("temperature",),
            )
        )
        out.append(
            Candidate(
                Term(
                    f"Kd_bias_{a}",
                    TermKind.ADDITIVE,
                    "m/s^3",
                    "ug/h",
                    MICRO_G / 3600.0,
                    20 * MICRO_G / 3600.0,
                    f"linear bias drift in time of the {a} accelerometer (t = session time)",
                    axis=i,
                    regressor=_needs(f"Kd_bias_{a}", "time", partial(_series_on_axis, i)),
                    excitation="repeated positions spread over the session",
                    aliases=(f"bias_{a}", f"Kt_bias_{a}"),
                    source="IEEE Std 1293 (bias drift)",
                ),
                "environment",
                "repeat the first positions at the end of the procedure (a closing pass)",
                needs=("time",),
            )
        )
        out.append(
            Candidate(
                Term(
                    f"Kh_{a}",
                    TermKind.ADDITIVE,
                    "m/s^2",
                    "ug",
                    MICRO_G,
                    5 * MICRO_G,
                    f"hysteresis of the {a} accelerometer: output shift ±Kh after a slew that raised (+1) or lowered (−1) its input",
                    axis=i,
                    regressor=_needs(f"Kh_{a}", "slew_direction", partial(_component_on_axis, i)),
                    excitation="each position approached from both directions",
                    aliases=(f"bias_{a}",),
                    source="IEEE Std 1293 (hysteresis)",
                ),
                "environment",
                "visit each position twice, approaching it from above and from below (reverse the sequence)",
                needs=("slew_direction",),
            )
        )
    return out


def _rotation() -> list[Candidate]:
    out: list[Candidate] = []
    for i, a in enumerate(AXES):
        for j, b in enumerate(AXES):
            tid = f"lever_{a}_{b}"
            out.append(
                Candidate(
                    Term(
                        tid,
                        TermKind.ADDITIVE,
                        "m",
                        "mm",
                        1e-3,
                        5e-3,
                        f"lever arm (size effect) of the {a} accelerometer: its offset along p-axis {b} from the measurement point",
                        axis=i,
                        regressor=_lever(i, j, tid),
                        excitation="continuous rotation or angular acceleration (not excited in static dwells)",
                        aliases=(),
                        source="Cai et al. 2016 Eqs. 9-12",
                    ),
                    "rotation",
                    "record during continuous rotation about at least two axes (a rate table or gimbal slews at constant rate)",
                    needs=("angular_rate", "angular_acceleration"),
                )
            )
    for term in GYRO_G_TERMS:
        # the discovery candidate is the record's term as an additive effect with a zero output regressor: the
        # accelerometers stay consistent with the readings; the reading slopes show it (stableins.discovery.drift)
        out.append(
            Candidate(
                replace(term, kind=TermKind.ADDITIVE, regressor=_drift(term.axis or 0, term.id)),
                "rotation",
                "the reading-slope analysis (Discovery.drift, stableins.discovery.drift) on dwells away from gimbal lock",
                needs=(),
            )
        )
    return out


_EQUIPMENT_TEXT = {
    "nonorth_12": ("non-orthogonality of the platform axis (z) and the inner-gimbal axis (x)", ("theta20", "beta_zx")),
    "nonorth_23": ("non-orthogonality of the inner-gimbal axis (x) and the middle-gimbal axis (y)", ("theta30", "beta_xy")),
    "tilt_north": ("tilt of the base about North (level error)", ("theta20",)),
    "tilt_east": ("tilt of the base about East (level error)", ("theta30",)),
    "azimuth_error": ("azimuth error of the base about Down (survey error)", ()),
}


_EQUIPMENT_SEPARATION = {
    "nonorth_12": "positions that turn the platform axis with the inner gimbal at 0 and at ±90°",
    "nonorth_23": "positions with the inner gimbal at 0 and at ±90° for two middle-gimbal angles",
    "tilt_north": "turn the base by 180° in azimuth (or measure the tilt with a precision level)",
    "tilt_east": "turn the base by 180° in azimuth (or measure the tilt with a precision level); θ30 and the "
    "east tilt are one rotation about the same axis for a fixed base",
    "azimuth_error": "invisible to gravity: a system-level record (Earth rate) or an optical azimuth survey",
}


def _equipment() -> list[Candidate]:
    from stableins.platform import GIMBAL_NAMES, KINEMATIC_IDS

    out: list[Candidate] = []
    for tid in KINEMATIC_IDS:
        if tid.startswith("ang1_"):
            _, g, cs = tid.split("_")
            i = GIMBAL_NAMES.index(g)
            meaning = f"once-per-revolution error of the {g} angle sensor ({'cos' if cs == 'c' else 'sin'} of the reading)"
            aliases: tuple[str, ...] = (f"theta{i + 1}0",)
            separation = f"positions covering a full revolution of the {g} gimbal at 45° steps"
        else:
            meaning, aliases = _EQUIPMENT_TEXT[tid]
            separation = _EQUIPMENT_SEPARATION[tid]
        out.append(
            Candidate(
                Term(
                    tid,
                    TermKind.ADDITIVE,
                    "rad",
                    "arcsec",
                    ARCSEC,
                    10 * ARCSEC,
                    meaning + "; acts through the gimbal kinematics (regressor ∂f^p/∂p)",
                    regressor=_kinematic(tid),
                    excitation="gimbal angles that turn the effect's axis relative to gravity",
                    aliases=aliases,
                    source="stableins.platform",
                ),
                "equipment",
                separation,
                needs=("platform_jacobian",),
            )
        )
    return out


def default_candidates() -> list[Candidate]:
    """Return the shipped candidates, group by group (:data:`CANDIDATE_GROUPS`)."""
    return _instrument_powers() + _instrument_couplings() + _environment() + _rotation() + _equipment()
