r"""Uncertainty budget of a calibration record: Type A from the record, Type B from the inputs taken as known.

GUM (JCGM 100:2008) 5.1.2: the combined standard uncertainty of an output quantity
:math:`y = f(x_1, \dots, x_N)` with uncorrelated inputs is :math:`u_c^2(y) = \sum_i c_i^2 u^2(x_i)`,
:math:`c_i = \partial f/\partial x_i`.  Here the output quantities are the record's parameters and
the inputs are

* the calibration data (Type A, GUM 4.2): the record's covariance :math:`P`, from the noise measured in
  the data and propagated by least squares and the Bayesian update of each stage;
* what the stages take as known (Type B, GUM 4.3): the local gravity, the static accuracy of the gimbal
  angle sensors, the instrument temperature, the gyro drift and the damping-loop parameters; and the slow
  noise a device stage's dwells allow but do not resolve (its σ rest on white noise; the covariance its
  largest floor adds, :func:`stableins.estimators.device.slow_noise_sensitivity`, the upper limit taken whole).

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

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from stableins.conventions import ARCSEC, DEG_PER_HOUR
from stableins.errormodel import Term, TermKind
from stableins.errors import InputError, NotDeterminedError
from stableins.records import CalibrationRecord

MGAL = 1e-5  # m/s²
#: Normal gravity omits the local gravity anomaly, tens of mGal in general and beyond 100 mGal in mountains.
NORMAL_GRAVITY_UNCERTAINTY = 30.0 * MGAL
#: Static accuracy of a gimbal angle reading, "at the level of 1″" (Wu et al. 2018 §6): ±1″ rectangular.
ANGLE_SENSOR_BOUND = 1.0 * ARCSEC
#: Gyro drift "less than 0.001 °/h" (Wu et al. 2018 §6): ±0.001 °/h rectangular per platform axis.
GYRO_DRIFT_BOUND = 0.001 * DEG_PER_HOUR
#: Budget columns, in the order printed.
GROUPS = ("gravity", "angle_sensors", "temperature", "gyro_drift", "damping_loop", "slow_noise")
TITLES = {
    "gravity": "local gravity g",
    "angle_sensors": "gimbal angle sensors",
    "temperature": "instrument temperature",
    "gyro_drift": "gyro drift",
    "damping_loop": "damping-loop parameters",
    "slow_noise": "slow noise not resolved",
}
SHORT = {
    "gravity": "g",
    "angle_sensors": "angle sensors",
    "temperature": "temp.",
    "gyro_drift": "gyro drift",
    "damping_loop": "loop",
    "slow_noise": "slow noise",
}
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
            gyro_drift=amount("gyro_drift", DEG_PER_HOUR),
            damping_loop=amount("damping_loop", 1.0),
            temperature_sensitivity=temperature,
            source=source,
        )

    @classmethod
    def from_procedure_file(cls, path: str) -> UncertaintyInputs:
        """Read the ``[uncertainty]`` table of a procedure (a shipped definition's name or a TOML file).

        Without the table every input takes its default.
        """
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
        """Return whether the input was evaluated (its state is "evaluated")."""
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
        """Return the state of the group's source ("not evaluated" when the budget has no such source)."""
        source = self.source(group)
        return source.state if source is not None else "not evaluated"

    def combined_of(self, parameter_id: str) -> float:
        """Return the combined standard uncertainty of a parameter [SI]."""
        return float(self.combined[self.ids.index(parameter_id)])

    def contribution(self, group: str, parameter_id: str) -> float:
        """Return the group's standard uncertainty of the parameter [SI]; NaN unless the group was evaluated."""
        values = self.contributions.get(group)
        if values is None or self.state(group) != "evaluated":
            return math.nan
        return float(values[self.ids.index(parameter_id)])

    def source(self, group: str) -> Source | None:
        """Return the source of an input group (None: not in the budget)."""
        return next((s for s in self.sources if s.group == group), None)


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
    except (InputError, NotDeterminedError):
        raise  # a described error passes through as it is (issue 29)
    except (ValueError, TypeError, KeyError):
        return None
    mask = np.abs(once) > 1e-12 * max(float(np.abs(once).max(initial=0.0)), 1e-300)
    if not mask.any():
        return None
    ratios = np.log2(np.abs(twice[mask] / once[mask]))
    degree = round(float(np.median(ratios)))
    return degree if np.allclose(ratios, degree, atol=1e-6) else None
