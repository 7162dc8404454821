r"""The candidate-effect library: physical effects the standard model leaves out.

Every candidate is a :class:`stableins.errormodel.Term` of kind ``"additive"``: its
regressor returns the change of the accelerometer output ``f^a`` per unit of the
parameter (SI), evaluated on :class:`~stableins.errormodel.TermInputs`, so ``model +
effect`` is a valid :class:`~stableins.errormodel.ErrorModel` and every fitter that
handles additive terms can estimate it.  Ids are the simulator's (``docs/simulator.md``);
the regressors follow the IEEE Std 1293-2018 accelerometer model equation

.. math::
    E/K_1 = K_0 + a_i + K_2 a_i^2 + K_3 a_i^3 + K_{oq} a_i|a_i| + K_{ip} a_i a_p + K_{io} a_i a_o
            + K_{po} a_p a_o + K_{pp} a_p^2 + K_{oo} a_o^2 + \dots

and Cai et al. 2016 Eqs. 4, 9–12 (cross-coupling ``K_axy f_x f_y`` is our ``Kcc_xxy``; size
effect ``−(ω_y² + ω_z²) r_x``).  Inputs are platform-frame (``f^p`` on the nominal
sensitive axes), see :mod:`stableins.errormodel`.

Instrument terms (per axis ``a``; ``b ≠ a``; ``bc ∈ {xy, xz, yz}``):

==================  ===================================  ============
id                  regressor (on axis a)                unit
==================  ===================================  ============
``K3_a``            ``f_a³``                             µg/g³
``Koq_a``           ``f_a |f_a|``                        µg/g²
``Ksa_a``           ``|f_a|`` (half the SF difference    ppm
                    between positive and negative input)
``Kcq_ab``          ``f_b²``                             µg/g²
``Kcc_abc``         ``f_b f_c``                          µg/g²
==================  ===================================  ============

Environment and time: ``Kt_bias_a`` (``ΔT``, µg/K), ``Kt_sf_a`` (``f_a ΔT``, ppm/K),
``Kd_bias_a`` (``t``, µg/h), ``Kh_a`` (direction ±1 of the last slew of the axis' input, µg).
Rotation and platform: ``lever_a_b`` (accelerometer ``a`` displaced by ``r`` along platform
axis ``b``: ``e_a·(ω̇×e_b + ω×(ω×e_b))``, mm), ``Dg_a`` (gyro g-sensitivity: the platform
drifts about ``p``-axis ``a`` at ``Dg_a f_a``, °/h/g; the angle sensors measure the drift, so
its regressor on ``f^a`` against measured readings is zero: it is found from the slopes of the
readings within dwells, :mod:`stableins.discovery.drift`).
Test equipment (through the exact kinematics of :mod:`stableins.platform`,
regressor ``∂f^p/∂p``): ``nonorth_12``, ``nonorth_23``, ``tilt_north``, ``tilt_east``,
``azimuth_error``, ``ang1_<gimbal>_c``/``_s``.

Custom effects: build a Term with :func:`custom_effect` (a Python function of
``TermInputs``) and :func:`register` it; it is then ranked like the library's own.

Carried into a calibration (``stableins calibrate device --add ID``, :func:`calibration_terms`):
the instrument group, whose regressors read the specific force only, so that the device
stages can estimate them and any compensation (:meth:`ErrorModel.inverse`) can apply them.
The other groups are diagnosed only; :func:`calibration_limit` says why.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from stableins.conventions import ARCSEC, AXES, MICRO_G, PPM, STANDARD_GRAVITY
from stableins.errormodel import Term, TermInputs, TermKind

G0 = STANDARD_GRAVITY
MICRO_G_PER_G2 = MICRO_G / G0**2
MICRO_G_PER_G3 = MICRO_G / G0**3
DEG_PER_HOUR = np.pi / 180.0 / 3600.0
#: °/h per g expressed in rad/s per (m/s²).
DEG_PER_HOUR_PER_G = DEG_PER_HOUR / G0

#: Groups of candidates, for reports.
GROUPS = ("instrument", "environment", "rotation", "equipment", "custom")

#: Groups whose effects a calibration carries (estimated by the device stages, applied by compensation).
CALIBRATION_GROUPS = ("instrument",)
#: Why the other groups are diagnosed but not carried into a calibration record.
_NOT_CARRIED = {
    "environment": "it needs the temperature, session time or slew history of every dwell, which the device stages do not model",
    "rotation": "it is not an output of the accelerometers at rest (lever arm: needs rotation; Dg: the gyros move the platform)",
    "equipment": "it acts through the gimbal kinematics or the base (a property of the platform or the site), not through the "
    "accelerometer outputs that a calibration record compensates",
    "custom": "a user-defined regressor may read inputs the device stages do not have",
}


@dataclass(frozen=True)
class Candidate:
    """A library entry: the error-model term plus what discovery needs to explain it.

    Attributes
    ----------
    term : Term
        The additive error-model term (id, regressor, units, meaning, excitation, aliases).
    group : str
        One of :data:`GROUPS`.
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
        columns = inputs.extra.get("platform_jacobian")
        names = inputs.extra.get("platform_jacobian_ids")
        if columns is None or names is None or term_id not in tuple(names):
            raise ValueError(f"term {term_id!r} acts through the gimbal kinematics; these data carry no angle readings for it")
        return np.asarray(columns, dtype=float)[..., tuple(names).index(term_id)]

    return regressor


# ----------------------------------------------------------------------------- library
_STATIC_SEPARATION = "positions with the axis at intermediate inputs (45° positions, e.g. the 12 tilted positions of Wu et al. Table 1)"


def _instrument() -> list[Candidate]:
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
                    regressor=_polynomial(i, lambda f, i=i: f[..., i] ** 3),
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
                    regressor=_polynomial(i, lambda f, i=i: f[..., i] * np.abs(f[..., i])),
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
                    regressor=_polynomial(i, lambda f, i=i: np.abs(f[..., i])),
                    excitation="the axis at ±1 g and at intermediate inputs",
                    aliases=(f"K2_{a}", f"bias_{a}"),
                    source="IEEE Std 1293 (scale-factor asymmetry)",
                ),
                "instrument",
                _STATIC_SEPARATION + "; at ±1 g and 0 g only, |f| = f²/g is a quadratic coefficient",
            )
        )
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
                        regressor=_polynomial(i, lambda f, j=j: f[..., j] ** 2),
                        excitation=f"the {b} input at several magnitudes with the {a} axis horizontal and vertical",
                        aliases=(f"bias_{a}",),
                        source="IEEE Std 1293 model equation",
                    ),
                    "instrument",
                    f"positions where f_{b}² takes at least two values while the other inputs are fixed",
                )
            )
    for i, a in enumerate(AXES):
        for b, c in (("x", "y"), ("x", "z"), ("y", "z")):
            j, k = AXES.index(b), AXES.index(c)
            out.append(
                Candidate(
                    Term(
                        f"Kcc_{a}{b}{c}",
                        TermKind.ADDITIVE,
                        "s^2/m",
                        "ug/g^2",
                        MICRO_G_PER_G2,
                        10 * MICRO_G_PER_G2,
                        f"cross-coupling of the {a} accelerometer to the product f_{b}·f_{c} (Cai et al. 2016 Eq. 4 K_a{b}{c}"
                        ", IEEE 1293 Kip/Kio/Kpo)",
                        axis=i,
                        regressor=_polynomial(i, lambda f, j=j, k=k: f[..., j] * f[..., k]),
                        excitation=f"positions with f_{b} and f_{c} both non-zero (45° between the two axes), both signs",
                        aliases=(f"beta_{a}{b}" if b != a else f"beta_{a}{c}", f"bias_{a}"),
                        source="Cai et al. 2016 Eq. 4; IEEE Std 1293",
                    ),
                    "instrument",
                    f"45° positions in the {b}{c} plane with both signs of f_{b}·f_{c}",
                )
            )
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
                    regressor=_needs(f"Kt_bias_{a}", "temperature", lambda t, _, i=i: _on_axis(i, t)),
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
                    regressor=_needs(f"Kt_sf_{a}", "temperature", lambda t, inp, i=i: _on_axis(i, _f(inp)[..., i] * t)),
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
                    regressor=_needs(f"Kd_bias_{a}", "time", lambda t, _, i=i: _on_axis(i, t)),
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
                    regressor=_needs(f"Kh_{a}", "slew_direction", lambda s, _, i=i: _on_axis(i, s[..., i])),
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
    for i, a in enumerate(AXES):
        tid = f"Dg_{a}"
        out.append(
            Candidate(
                Term(
                    tid,
                    TermKind.ADDITIVE,
                    "rad/s/(m/s^2)",
                    "deg/h/g",
                    DEG_PER_HOUR_PER_G,
                    0.01 * DEG_PER_HOUR_PER_G,
                    f"g-sensitivity of the {a}-axis stabilisation gyro: the platform drifts about p-axis {a} at Dg·f_{a} "
                    "while it holds a position, tilting the input of the other accelerometers",
                    axis=i,
                    regressor=_drift(i, tid),
                    excitation="dwells with the axis vertical; seen in the slopes of the angle readings within dwells",
                    aliases=(),
                    source="Cai et al. 2016 Eq. 1 (gyro g-sensitivity G)",
                ),
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
            aliases = (f"theta{i + 1}0",)
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


class Library:
    """An ordered registry of candidates; the default one holds every built-in effect.

    Examples
    --------
    >>> lib = Library.default()
    >>> lib["Kcc_xxy"].term.unit
    'ug/g^2'
    """

    def __init__(self, candidates: Iterable[Candidate] = ()) -> None:
        self._items: dict[str, Candidate] = {}
        for c in candidates:
            self.register(c)

    @classmethod
    def default(cls) -> Library:
        return cls(_instrument() + _environment() + _rotation() + _equipment())

    def register(self, item: Candidate | Term, separation: str = "", group: str = "custom") -> Candidate:
        """Add a candidate (or a bare additive Term) to the library; its id must be new."""
        candidate = item if isinstance(item, Candidate) else Candidate(item, group, separation or item.excitation)
        if candidate.term.kind != TermKind.ADDITIVE or candidate.term.regressor is None:
            raise ValueError(f"candidate {candidate.id!r} must be an additive term with a regressor")
        if candidate.id in self._items:
            raise ValueError(f"candidate {candidate.id!r} is already in the library")
        self._items[candidate.id] = candidate
        return candidate

    def __getitem__(self, term_id: str) -> Candidate:
        try:
            return self._items[term_id]
        except KeyError:
            raise KeyError(f"no candidate effect {term_id!r} (known: {', '.join(self._items)})") from None

    def __contains__(self, term_id: object) -> bool:
        return term_id in self._items

    def __iter__(self):
        return iter(self._items.values())

    def __len__(self) -> int:
        return len(self._items)

    @property
    def ids(self) -> tuple[str, ...]:
        return tuple(self._items)

    def terms(self) -> tuple[Term, ...]:
        return tuple(c.term for c in self._items.values())


def calibration_limit(term_id: str, library: Library | None = None) -> str | None:
    """Why an effect cannot be carried into a calibration record, or None when it can (:data:`CALIBRATION_GROUPS`)."""
    library = library if library is not None else LIBRARY
    if term_id not in library:
        return f"no candidate effect {term_id!r} in the library"
    group = library[term_id].group
    return None if group in CALIBRATION_GROUPS else _NOT_CARRIED.get(group, f"its group {group!r} is not carried")


def calibration_terms(term_ids: Iterable[str], *, source: str = "--add", library: Library | None = None) -> tuple[Term, ...]:
    """The library terms for effects to be estimated in a calibration, in order, each once.

    Raises
    ------
    InputError
        An unknown id, an id given twice, or an effect that a calibration cannot carry
        (:func:`calibration_limit`), naming ``source`` (an option or a procedure file).
    """
    from stableins.errors import InputError

    library = library if library is not None else LIBRARY
    ids = list(term_ids)
    carried = [c.id for c in library if c.group in CALIBRATION_GROUPS]
    seen: set[str] = set()
    for term_id in ids:
        if term_id in seen:
            raise InputError(f"effect {term_id!r} is given twice", field=source, expected="each effect once")
        seen.add(term_id)
        if term_id not in library:
            raise InputError(f"unknown effect {term_id!r}", field=source, expected=f"an effect of the library: {', '.join(carried)}")
        why = calibration_limit(term_id, library)
        if why is not None:
            raise InputError(
                f"effect {term_id!r} cannot be carried into a calibration: {why}; 'stableins diagnose --add {term_id}' tests it",
                field=source,
                expected=f"an instrument effect: {', '.join(carried)}",
            )
    return tuple(library[i].term for i in ids)


def record_terms(parameter_ids: Iterable[str], library: Library | None = None) -> tuple[Term, ...]:
    """The discovered (additive) terms among a record's parameter ids, in record order."""
    library = library if library is not None else LIBRARY
    return tuple(library[i].term for i in parameter_ids if i in library)


def all_terms(library: Library | None = None) -> dict[str, Term]:
    """Every term a calibration record may carry, by id: the standard and gimbal terms and the library's."""
    from stableins.errormodel import known_terms

    return known_terms((library if library is not None else LIBRARY).terms())


def markdown_table(library: Library | None = None) -> str:
    """The candidates as a Markdown table (id, unit, meaning, excitation, aliases, separation) for the docs."""
    library = library if library is not None else LIBRARY
    rows = ["| id | unit | group | meaning | excitation | aliases into | separated by |", "|---|---|---|---|---|---|---|"]

    def cell(text: str) -> str:
        return text.replace("|", "\\|")

    for c in library:
        t = c.term
        aliases = ", ".join(f"`{a}`" for a in t.aliases) or "—"
        rows.append(f"| `{t.id}` | {t.unit} | {c.group} | {cell(t.meaning)} | {cell(t.excitation)} | {aliases} | {cell(c.separation)} |")
    return "\n".join(rows)


#: The process-wide default library; :func:`register` adds custom effects to it.
LIBRARY = Library.default()


def register(item: Candidate | Term, separation: str = "") -> Candidate:
    """Register a custom effect in the default library (it is then ranked like the built-in ones)."""
    return LIBRARY.register(item, separation)


def custom_effect(
    term_id: str,
    regressor: Callable[[TermInputs], NDArray],
    *,
    unit: str,
    scale: float,
    si_unit: str = "",
    nominal: float | None = None,
    meaning: str = "user-defined effect",
    excitation: str = "",
    aliases: tuple[str, ...] = (),
    axis: int | None = None,
) -> Term:
    """Build an additive Term from a user function ``TermInputs -> (..., 3)`` [m/s² per SI unit].

    Examples
    --------
    >>> import numpy as np
    >>> def fourth(inputs):
    ...     out = np.zeros_like(inputs.specific_force)
    ...     out[..., 0] = inputs.specific_force[..., 0] ** 4
    ...     return out
    >>> term = custom_effect("K4_x", fourth, unit="ug/g^4", scale=MICRO_G / STANDARD_GRAVITY**4)
    >>> term.kind
    <TermKind.ADDITIVE: 'additive'>
    """
    return Term(
        term_id,
        TermKind.ADDITIVE,
        si_unit or f"({unit}) in SI",
        unit,
        scale,
        scale if nominal is None else nominal,
        meaning,
        axis=axis,
        regressor=regressor,
        excitation=excitation or "user-defined",
        aliases=aliases,
        source="user-defined",
    )
