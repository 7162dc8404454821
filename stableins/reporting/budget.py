r"""Uncertainty budget of a calibration record: Type A from the record, Type B from the inputs taken as known.

GUM (JCGM 100:2008) 5.1.2: the combined standard uncertainty of an output quantity
:math:`y = f(x_1, \dots, x_N)` with uncorrelated inputs is :math:`u_c^2(y) = \sum_i c_i^2 u^2(x_i)`,
:math:`c_i = \partial f/\partial x_i`.  Here the output quantities are the record's parameters and
the inputs are

* the calibration data (Type A, GUM 4.2): the record's covariance :math:`P`, from the noise measured in
  the data and propagated by least squares and the Bayesian update of each stage;
* what the stages take as known (Type B, GUM 4.3): the local gravity, the static accuracy of the gimbal
  angle sensors, the instrument temperature, the gyro drift and the damping-loop parameters.

**Sensitivity through the record.**  Every stage k enters the record through the information vector
:math:`\eta_k = \Lambda_k \hat x_k + g_k` of its likelihood; the record's values are
:math:`x = P \sum_k \eta_k` with :math:`P^{-1} = \sum_k \Lambda_k` over the parameters the record states
(the Bayesian updates in information form; :mod:`stableins.estimators.posterior`).  An input error
:math:`\delta q` therefore moves the record by

.. math:: \delta x = P \sum_k \frac{\partial \eta_k}{\partial q}\,\delta q, \qquad
          c_q = P \sum_k \frac{\partial \eta_k}{\partial q}

(a stage that does not use the input contributes nothing; a gauge parameter, held by convention, has a zero
row in :math:`P` and does not move).  For a set of independent inputs of one kind (the reading of every dwell),
:math:`\mathrm{Cov}(\delta x) = u^2\, P\,(\sum_k S_k)\,P` with :math:`S_k` the stage's
:attr:`~stableins.estimators.result.InputSensitivity.covariance`.

**Gravity** needs no stored sensitivity: g is the reference of every stage, and the model is closed under
a change of it (output ``= f/SF``, ``f ∝ g``): the data are reproduced exactly with ``SF_i → SF_i (1 + δg/g)``
and an additive term of degree d in f scaled by ``(1 + δg/g)^{−d}``.  So ``∂η_k/∂g = Λ_k v`` with
``v_{SF_i} = SF_i/g``, ``v_p = −d p/g``: for a record whose stages all share the site's g,
``c_g = P Σ Λ_k v = v`` on every parameter the record determines — the scale factors move by δg/g,
nothing else.  (The system stage sees g only through the normalization of x1, with the same ``v``;
checked against a re-run of each stage with g perturbed, ``tests/test_budget.py``.)

**Temperature**: the device and system stages have no temperature model; a temperature sensitivity
:math:`k_T` stated in the procedure's ``[uncertainty.temperature_sensitivity]`` table gives
:math:`u = |k_T|\,(T_{max} - T_{min})/\sqrt{12}` (the recorded range as a rectangular distribution,
GUM 4.3.7); without one the recorded range is stated as a condition of validity.

The inputs' standard uncertainties come from the site metadata (``gravity_uncertainty``), the stage
settings (``gyro_drift_uncertainty``), the procedure's ``[uncertainty]`` table, or the documented
defaults below, in this order (docs/reports.md).
"""

from __future__ import annotations

import fnmatch
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from stableins.conventions import ARCSEC
from stableins.errormodel import Term, TermKind
from stableins.errors import InputError
from stableins.records import CalibrationRecord
from stableins.status import Status

MGAL = 1e-5  # m/s²
DEG_PER_H = math.radians(1.0) / 3600.0  # rad/s
#: Normal gravity omits the local gravity anomaly, tens of mGal in general and beyond 100 mGal in mountains.
NORMAL_GRAVITY_UNCERTAINTY = 30.0 * MGAL
#: Static accuracy of a gimbal angle reading, "at the level of 1″" (Wu et al. 2018 §6): ±1″ rectangular.
ANGLE_SENSOR_BOUND = 1.0 * ARCSEC
#: Gyro drift "less than 0.001 °/h" (Wu et al. 2018 §6): ±0.001 °/h rectangular per platform axis.
GYRO_DRIFT_BOUND = 0.001 * DEG_PER_H
#: Budget columns, in the order printed.
GROUPS = ("gravity", "angle_sensors", "temperature", "gyro_drift", "damping_loop")
TITLES = {
    "gravity": "local gravity g",
    "angle_sensors": "gimbal angle sensors",
    "temperature": "instrument temperature",
    "gyro_drift": "gyro drift",
    "damping_loop": "damping-loop parameters",
}
SHORT = {"gravity": "g", "angle_sensors": "angle sensors", "temperature": "temp.", "gyro_drift": "gyro drift", "damping_loop": "loop"}
_KEYS = {"gravity", "angle_sensor", "gyro_drift", "damping_loop", "temperature_sensitivity"}


@dataclass(frozen=True)
class UncertaintyInputs:
    """The procedure's ``[uncertainty]`` table (Type B inputs the data do not carry), in SI.

    TOML keys and units::

        [uncertainty]
        gravity = 0.05          # mGal: standard uncertainty of the site's g, when the site does not state it
        angle_sensor = 0.58     # arcsec: standard uncertainty of one static angle reading
        gyro_drift = 0.00058    # deg/h: per platform axis, of the drift given (or of zero)
        damping_loop = 0.0      # relative standard uncertainty of each damping-loop parameter

        [uncertainty.temperature_sensitivity]   # engineering unit of the term per kelvin
        "bias_*" = 5.0          # µg/K
        "sf_*" = 1.0            # ppm/K
    """

    gravity: float | None = None
    angle_sensor: float | None = None
    gyro_drift: float | None = None
    damping_loop: float | None = None
    temperature_sensitivity: Mapping[str, float] = field(default_factory=dict)
    source: str = ""

    @classmethod
    def from_mapping(cls, table: Any, source: str = "procedure") -> UncertaintyInputs:
        """Validate an ``[uncertainty]`` table; problems raise :class:`InputError` naming ``source``."""
        if table is None:
            return cls(source=source)
        if not isinstance(table, Mapping):
            raise InputError("[uncertainty] is not a table", path=source, field="uncertainty")
        unknown = sorted(set(table) - _KEYS)
        if unknown:
            raise InputError(f"unknown keys {unknown}", path=source, field="uncertainty", expected=", ".join(sorted(_KEYS)))

        def amount(key: str, scale: float) -> float | None:
            if key not in table:
                return None
            value = table[key]
            if isinstance(value, bool) or not isinstance(value, int | float) or not (math.isfinite(value) and value >= 0):
                raise InputError(f"not a non-negative number: {value!r}", path=source, field=f"uncertainty.{key}", expected="a number ≥ 0")
            return float(value) * scale

        sensitivity = table.get("temperature_sensitivity", {})
        if not isinstance(sensitivity, Mapping):
            raise InputError("not a table", path=source, field="uncertainty.temperature_sensitivity")
        temperature = {}
        for key, value in sensitivity.items():
            if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
                raise InputError(
                    f"not a number: {value!r}", path=source, field=f"uncertainty.temperature_sensitivity.{key}", expected="a number"
                )
            temperature[str(key)] = abs(float(value))
        return cls(
            gravity=amount("gravity", MGAL),
            angle_sensor=amount("angle_sensor", ARCSEC),
            gyro_drift=amount("gyro_drift", DEG_PER_H),
            damping_loop=amount("damping_loop", 1.0),
            temperature_sensitivity=temperature,
            source=source,
        )

    @classmethod
    def from_procedure_file(cls, path: str) -> UncertaintyInputs:
        """Read the ``[uncertainty]`` table of a procedure (a shipped definition's name or a TOML file; absent table:
        every input takes its default)."""
        from stableins.procedures.definition import read_toml, resolve

        resolved = resolve(path)
        data = read_toml(resolved, what="a procedure definition (TOML)")
        return cls.from_mapping(data.get("uncertainty"), source=str(resolved))


@dataclass(frozen=True)
class Source:
    """One Type B input as the certificate lists it (values as text, for people)."""

    group: str
    value: str
    uncertainty: str
    distribution: str
    origin: str
    effect: str
    #: "evaluated"; "not applicable" (no stage of the record uses the input); "condition" (stated as a condition
    #: of validity instead); "not evaluated" (the record lacks what the evaluation needs)
    state: str = "evaluated"

    @property
    def evaluated(self) -> bool:
        return self.state == "evaluated"


@dataclass(frozen=True)
class Budget:
    """Type A and Type B standard uncertainties of every parameter of a record [SI].

    ``contributions[group][k]`` is the standard uncertainty the input group gives parameter ``ids[k]``
    (zero where it has none, and for a group whose :attr:`Source.state` is not "evaluated").
    """

    ids: tuple[str, ...]
    type_a: NDArray[np.float64]
    contributions: Mapping[str, NDArray[np.float64]]
    sources: tuple[Source, ...]
    conditions: tuple[str, ...] = ()

    @property
    def combined(self) -> NDArray[np.float64]:
        """u_c = sqrt(u_A² + Σ u_i²) (GUM Eq. 10, inputs uncorrelated)."""
        total = self.type_a**2
        for values in self.contributions.values():
            total = total + values**2
        return np.sqrt(total)

    def state(self, group: str) -> str:
        source = self.source(group)
        return source.state if source is not None else "not evaluated"

    def combined_of(self, parameter_id: str) -> float:
        return float(self.combined[self.ids.index(parameter_id)])

    def contribution(self, group: str, parameter_id: str) -> float:
        """The group's standard uncertainty of the parameter [SI]; NaN unless the group was evaluated."""
        values = self.contributions.get(group)
        if values is None or self.state(group) != "evaluated":
            return math.nan
        return float(values[self.ids.index(parameter_id)])

    def source(self, group: str) -> Source | None:
        return next((s for s in self.sources if s.group == group), None)


def uncertainty_budget(
    record: CalibrationRecord, inputs: UncertaintyInputs | None = None, terms: Mapping[str, Term] | None = None
) -> Budget:
    """The budget of every parameter of ``record`` (module docstring), with ``inputs`` from the procedure."""
    from stableins.discovery.library import all_terms

    inputs = inputs or UncertaintyInputs()
    terms = dict(terms or all_terms())
    ids = record.ids
    n = len(ids)
    covariance = np.nan_to_num(np.asarray(record.covariance, dtype=float))
    held = [k for k, p in enumerate(record.parameters) if p.status in (Status.GAUGE, Status.UNIDENTIFIABLE)]
    covariance[held, :] = 0.0
    covariance[:, held] = 0.0
    type_a = np.sqrt(np.clip(np.diag(covariance), 0.0, None))
    contributions: dict[str, NDArray[np.float64]] = {}
    sources: list[Source] = []
    conditions: list[str] = []

    def to_record(sensitivity_ids: Sequence[str], vector: NDArray[np.float64]) -> NDArray[np.float64]:
        out = np.zeros(n)
        for k, pid in enumerate(sensitivity_ids):
            if pid in ids:
                out[ids.index(pid)] += vector[k]
        return out

    def to_record_matrix(sensitivity_ids: Sequence[str], matrix: NDArray[np.float64]) -> NDArray[np.float64]:
        index = [ids.index(p) for p in sensitivity_ids if p in ids]
        keep = [k for k, p in enumerate(sensitivity_ids) if p in ids]
        out = np.zeros((n, n))
        out[np.ix_(index, index)] = matrix[np.ix_(keep, keep)]
        return out

    def largest(vector: NDArray[np.float64]) -> str:
        """The largest effect on a parameter in engineering units, as text."""
        best = None
        for k, pid in enumerate(ids):
            term = terms.get(pid)
            if term is None or not vector[k]:
                continue
            value = abs(float(term.sigma_to_engineering(vector[k])))
            relative = value / max(float(term.sigma_to_engineering(type_a[k])), 1e-300) if type_a[k] > 0 else 0.0
            if best is None or relative > best[0]:
                best = (relative, pid, value, term.unit)
        if best is None:
            return "no effect on the parameters"
        from stableins.reporting.content import number, unit_text

        return f"largest on {best[1]}: {number(best[2], 2)} {unit_text(best[3])}"

    # ---------------------------------------------------------------- gravity
    site = record.site
    if site is None:
        sources.append(Source("gravity", "not recorded", "—", "—", "the record has no site metadata", "not evaluated", "not evaluated"))
        contributions["gravity"] = np.zeros(n)
    else:
        g = float(site.gravity)
        if site.gravity_uncertainty is not None:
            u_g, origin, distribution = float(site.gravity_uncertainty), "stated with the site", "normal"
        elif inputs.gravity is not None:
            u_g, origin, distribution = inputs.gravity, f"procedure ({_name(inputs.source)})", "normal"
        elif "normal" in site.gravity_source.lower():
            u_g, origin, distribution = NORMAL_GRAVITY_UNCERTAINTY, _NORMAL_GRAVITY_TEXT, "normal"
        else:
            u_g, origin, distribution = NORMAL_GRAVITY_UNCERTAINTY, _UNSTATED_GRAVITY_TEXT, "normal"
        direction = gravity_direction(record, terms)
        gradient = np.zeros(n)
        stages = [s for s in record.stages if s.likelihood is not None]
        for stage in stages:
            lik = stage.likelihood
            v = np.array([direction.get(pid, 0.0) for pid in lik.ids])
            gradient += to_record(lik.ids, lik.information @ v)
        c = covariance @ gradient if stages else np.array([direction.get(pid, 0.0) for pid in ids])
        contributions["gravity"] = np.abs(c) * u_g
        sources.append(
            Source(
                "gravity",
                f"{g:.7f} m/s² ({site.gravity_source})",
                f"{_mgal(u_g)} mGal" + ("" if u_g == 0 else f" ({scientific(u_g)} m/s²)"),
                distribution,
                origin,
                "δSF/SF = δg/g on every scale factor (" + largest(c * u_g) + ")" if u_g > 0 else "δSF/SF = δg/g on every scale factor",
            )
        )

    # ---------------------------------------------------------------- stored sensitivities (angle sensors, gyro drift, loop)
    stored: dict[str, list[tuple[Any, Any]]] = {}
    for stage in record.stages:
        for s in stage.sensitivities:
            stored.setdefault(s.group, []).append((stage, s))

    # angle sensors: the static reading error of every dwell, independent from dwell to dwell
    u_angle, angle_origin = (
        (inputs.angle_sensor, f"procedure ({_name(inputs.source)})")
        if inputs.angle_sensor is not None
        else (ANGLE_SENSOR_BOUND / math.sqrt(3.0), _ANGLE_TEXT)
    )
    angle = stored.get("angle_sensors", [])
    if angle:
        total = np.zeros((n, n))
        for _, s in angle:
            if s.covariance is not None:
                total += to_record_matrix(s.ids, s.covariance)
        cov = covariance @ total @ covariance * u_angle**2
        contributions["angle_sensors"] = np.sqrt(np.clip(np.diag(cov), 0.0, None))
        effect = (
            "each dwell's readings as independent errors of the coarse stage's orientations ("
            + largest(contributions["angle_sensors"])
            + ")"
        )
        sources.append(Source("angle_sensors", "static readings of the three gimbal angle sensors", f"{u_angle / ARCSEC:.2g}″ per reading",
                              "rectangular" if inputs.angle_sensor is None else "normal", angle_origin, effect))  # fmt: skip
    else:
        device = [s for s in record.stages if s.name in ("coarse", "coarse+fine")]
        contributions["angle_sensors"] = np.zeros(n)
        why = (
            "no stage of the record reads the gimbal angles (the fine and system stages do not)"
            if not device
            else "the record's coarse stage stores no angle-sensor sensitivity (written by an earlier version): not evaluated"
        )
        sources.append(Source("angle_sensors", "static readings of the gimbal angle sensors", f"{u_angle / ARCSEC:.2g}″ per reading",
                              "rectangular", angle_origin, why, "not evaluated" if device else "not applicable"))  # fmt: skip

    # gyro drift: the system stage's input, per platform axis
    drift = stored.get("gyro_drift", [])
    if drift:
        vectors = {}
        origins = set()
        for stage, s in drift:
            stated = stage.settings.get("gyro_drift_uncertainty")
            if isinstance(stated, int | float) and math.isfinite(stated):
                u, origin = float(stated), "given with the system stage"
            elif inputs.gyro_drift is not None:
                u, origin = inputs.gyro_drift, f"procedure ({_name(inputs.source)})"
            else:
                u, origin = GYRO_DRIFT_BOUND / math.sqrt(3.0), _DRIFT_TEXT
            origins.add((u, origin))
            if s.gradient is not None:
                vectors[s.input] = vectors.get(s.input, np.zeros(n)) + to_record(s.ids, s.gradient) * u
        per_axis = [covariance @ v for v in vectors.values()]
        contributions["gyro_drift"] = np.sqrt(sum(np.abs(c) ** 2 for c in per_axis)) if per_axis else np.zeros(n)
        given = [stage.settings.get("known_gyro_drift") for stage, _ in drift]
        value = (
            "not given: assumed zero"
            if all(x is None for x in given)
            else "given: " + ", ".join(f"{float(v) / DEG_PER_H:.4g}" for v in next(x for x in given if x is not None)) + " °/h (x, y, z)"
        )
        u_text = "; ".join(sorted({f"{u / DEG_PER_H:.2g} °/h per axis" for u, _ in origins}))
        origin = "; ".join(sorted({o for _, o in origins}))
        sources.append(
            Source(
                "gyro_drift",
                f"constant drift in the platform frame, {value}",
                u_text,
                "rectangular" if origin == _DRIFT_TEXT else "normal",
                origin,
                "the system stage re-run with each axis perturbed; the drift drives the loop's Earth-rate mode and moves the "
                f"attitude coefficients ({largest(contributions['gyro_drift'])})",
            )
        )
    else:
        contributions["gyro_drift"] = np.zeros(n)
        sources.append(_system_input_missing(record, "gyro_drift", "constant drift in the platform frame"))

    # damping loop: software constants of the navigation computer unless the procedure says otherwise
    loop = stored.get("damping_loop", [])
    relative = inputs.damping_loop if inputs.damping_loop is not None else 0.0
    if loop:
        per_parameter = [covariance @ (to_record(s.ids, s.gradient) * abs(s.value)) for _, s in loop if s.gradient is not None]
        contributions["damping_loop"] = relative * np.sqrt(sum(np.abs(c) ** 2 for c in per_parameter))
        one_percent = 0.01 * np.sqrt(sum(np.abs(c) ** 2 for c in per_parameter))
        names = ", ".join(dict.fromkeys(_LOOP_NAMES.get(s.input.partition(".")[2], s.input) for _, s in loop))
        sources.append(
            Source(
                "damping_loop",
                f"{names} of the INS damping loop (site metadata)",
                f"{relative:.2g} relative" if relative else "0",
                "normal",
                f"procedure ({_name(inputs.source)})" if inputs.damping_loop is not None else _LOOP_TEXT,
                f"the system stage re-run with each parameter perturbed; a 1 % error of each would give {largest(one_percent)}",
            )
        )
    else:
        contributions["damping_loop"] = np.zeros(n)
        sources.append(_system_input_missing(record, "damping_loop", "damping-loop parameters"))

    # temperature: the recorded range, with a stated sensitivity or as a condition of validity
    low, high, mean = _temperature_range(record)
    contributions["temperature"] = np.zeros(n)
    if low is None:
        conditions.append("The instrument temperature is not recorded in the data: the results apply to the conditions of the calibration.")
        effect = "the results apply to the conditions of the calibration"
        sources.append(Source("temperature", "not recorded", "—", "—", "—", effect, "condition"))
    else:
        spread = (high - low) / math.sqrt(12.0)
        stated = {pid: _pattern(inputs.temperature_sensitivity, pid) for pid in ids}
        for k, pid in enumerate(ids):
            sensitivity = stated[pid]
            term = terms.get(pid)
            if sensitivity is not None and term is not None and type_a[k] > 0:
                contributions["temperature"][k] = float(term.from_engineering(sensitivity * spread) - term.from_engineering(0.0))
        known = any(v is not None for v in stated.values())
        sources.append(
            Source(
                "temperature",
                f"recorded range {low:.2f} to {high:.2f} °C (mean {mean:.2f} °C)",
                f"{spread:.2g} K",
                "rectangular",
                f"recorded range; sensitivities from the procedure ({_name(inputs.source)})" if known else "recorded range",
                "u = |k_T| (T_max − T_min)/√12"
                if known
                else "no temperature sensitivity known to this calibration: not in the budget, stated as a condition of validity",
                "evaluated" if known else "condition",
            )
        )
        conditions.append(
            f"The results apply to instrument temperatures from {low:.2f} to {high:.2f} °C (recorded during the calibration"
            f"{'' if known else '; no temperature sensitivity is known to it'})."
        )
    order = {g: i for i, g in enumerate(GROUPS)}
    sources.sort(key=lambda s: order[s.group])
    return Budget(ids, type_a, {g: contributions[g] for g in GROUPS}, tuple(sources), tuple(conditions))


def _system_input_missing(record: CalibrationRecord, group: str, value: str) -> Source:
    """The source of a system-stage input the record stores no sensitivity for: not applicable, or not evaluated."""
    system = any(s.name == "system" for s in record.stages)
    effect = (
        "the record's system stage stores no sensitivity (written by an earlier version): not evaluated"
        if system
        else "no system-level stage in the record: the device stages do not depend on it"
    )
    return Source(group, value, "—", "—", "—", effect, "not evaluated" if system else "not applicable")


def gravity_direction(record: CalibrationRecord, terms: Mapping[str, Term]) -> dict[str, float]:
    """``v = ∂x/∂g`` of a data-only estimate (module docstring): ``SF_i/g`` on the scale factors, ``−d p/g`` on a term of degree d."""
    if record.site is None:
        return {}
    g = float(record.site.gravity)
    out = {}
    for p in record.parameters:
        term = terms.get(p.id)
        if p.id.startswith("sf_"):
            out[p.id] = p.value / g
        elif term is not None and term.kind == TermKind.ADDITIVE and math.isfinite(p.value):
            degree = homogeneity_degree(term, g)
            if degree:
                out[p.id] = -degree * p.value / g
    return out


def homogeneity_degree(term: Term, gravity: float) -> int | None:
    """Degree d with ``r(λ f) = λ^d r(f)`` of an additive term's regressor (None: not homogeneous in f, or needs other inputs)."""
    from stableins.errormodel import TermInputs

    if term.regressor is None:
        return None
    directions = np.array([[0.6, -0.48, 0.64], [-0.36, 0.8, 0.48], [0.0, 0.6, -0.8]]) * gravity
    try:
        once = np.asarray(term.regressor(TermInputs(directions)), dtype=float)
        twice = np.asarray(term.regressor(TermInputs(2.0 * directions)), dtype=float)
    except (ValueError, TypeError, KeyError):
        return None
    mask = np.abs(once) > 1e-12 * max(float(np.abs(once).max(initial=0.0)), 1e-300)
    if not mask.any():
        return None
    ratios = np.log2(np.abs(twice[mask] / once[mask]))
    degree = round(float(np.median(ratios)))
    return degree if np.allclose(ratios, degree, atol=1e-6) else None


def _temperature_range(record: CalibrationRecord) -> tuple[float | None, float | None, float | None]:
    lows, highs, means = [], [], []
    for stage in record.stages_run:
        t = stage.environment.get("temperature") if isinstance(stage.environment, Mapping) else None
        if isinstance(t, Mapping) and all(isinstance(t.get(k), int | float) for k in ("min", "max", "mean")):
            lows.append(float(t["min"]))
            highs.append(float(t["max"]))
            means.append(float(t["mean"]))
    if not lows:
        return None, None, None
    return min(lows), max(highs), float(np.mean(means))


def _pattern(table: Mapping[str, float], parameter_id: str) -> float | None:
    if parameter_id in table:
        return table[parameter_id]
    matches = [p for p in table if fnmatch.fnmatchcase(parameter_id, p)]
    return table[max(matches, key=len)] if matches else None


def _name(source: str) -> str:
    from pathlib import Path

    return Path(source).name if source else "procedure"


def _mgal(u: float) -> str:
    from stableins.reporting.content import number

    return number(u / MGAL, 2) if u else "0"


def scientific(x: float, significant: int = 2) -> str:
    """``5.0 × 10⁻⁷``: a number in scientific notation for people."""
    mantissa, exponent = f"{x:.{significant - 1}e}".split("e")
    power = str(int(exponent)).translate(str.maketrans("-0123456789", "⁻⁰¹²³⁴⁵⁶⁷⁸⁹"))
    return f"{mantissa} × 10{power}".replace("-", "\u2212")


_NORMAL_GRAVITY_TEXT = (
    "assumed: the normal-gravity formula omits the local gravity anomaly (tens of mGal, beyond 100 mGal in mountains); "
    "a surveyed g removes most of it"
)
_UNSTATED_GRAVITY_TEXT = "assumed as for the normal-gravity formula: the site states no uncertainty for its g"
_ANGLE_TEXT = "assumed: ±1″ static accuracy (Wu et al. 2018 §6), rectangular"
_DRIFT_TEXT = "assumed: ±0.001 °/h (Wu et al. 2018 §6: drift below 0.001 °/h), rectangular"
_LOOP_TEXT = "software constants of the navigation computer, taken as exact"
_LOOP_NAMES = {"zeta": "ζ", "omega_s": "ω_s", "schuler_frequency": "ω_s", "k1": "k_1", "k2": "k_2", "k3": "k_3"}
