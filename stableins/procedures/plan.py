"""Execution plan of a procedure: the steps the runner carries out, in SI, JSON round-trippable.

The plan is what the runner executes and what the journal's start record stores, so that a
resumed run carries out exactly the procedure it started with even if the TOML file has been
edited since.  Procedure files (``procedures/*.toml``) are read by
:mod:`stableins.procedures.definition` and turned into a plan.
"""

from __future__ import annotations

import math
from dataclasses import MISSING, asdict, dataclass, field, fields
from enum import StrEnum
from typing import Any

from stableins.documents import JSONObject
from stableins.errors import InputError, NotDeterminedError
from stableins.estimators.layout import DwellChecks
from stableins.turns import IndexAxis, PlatformTurn, check_turns

#: ``chunk`` [s]: dwells are journaled in pieces this long (a piece must hold samples; a day-long piece is no journal).
CHUNK_RANGE = (0.1, 3600.0)
#: Default ``chunk`` [s]: a dwell reaches the journal and the console one second of data at a time (issue 27: an
#: operator of a real platform sees the dwell progress, and a crash loses at most a second).
DEFAULT_CHUNK_SECONDS = 1.0
#: ``retries``: repeats of a rejected dwell.
RETRIES_RANGE = (0, 100)
#: Longest settle, dwell or slew of one step [s], and longest static record [s].
MAX_STEP_SECONDS = 86400.0
MAX_RECORD_SECONDS = 30 * 86400.0
#: Most steps of a plan.
MAX_STEPS = 1_000_000
#: Largest commanded reading [rad]: four turns (the cumulative middle-gimbal reading of device-rotating).
MAX_READING = 8 * math.pi


@dataclass(frozen=True)
class DwellStep:
    """Command a position, let it settle, record a dwell, check it.

    ``readings`` are the nominal angle-sensor readings (platform, inner, middle) [rad]; when
    ``offset_corrected`` is true the runner subtracts the current zero-offset estimate
    (``r = r_nominal - theta_hat``, Wu et al. 2018 Section 3).
    """

    name: str
    stage: str
    pass_number: int
    position: int
    readings: tuple[float, float, float]
    settle: float
    dwell: float
    checks: DwellChecks = field(default_factory=DwellChecks)
    why: str = ""
    offset_corrected: bool = False
    kind: str = "dwell"
    #: keep the slew (and settle) samples with the dwell (a rotating procedure: the lever arms are in the slews)
    keep_slew: bool = False


@dataclass(frozen=True)
class PersonStep:
    """A step a person carries out: ``confirm`` something, or ``enter`` a value (temperature, site data).

    ``key`` names the value in the run's metadata (``extra``); ``default`` is what ``--yes``
    uses for an ``enter`` step (none: the value must be given with ``--set key=value``).
    """

    name: str
    action: str
    prompt: str
    key: str = ""
    unit: str = ""
    minimum: float | None = None
    maximum: float | None = None
    default: float | str | None = None
    kind: str = "person"


@dataclass(frozen=True)
class OffsetIterationStep:
    """Run the device-level zero-offset iteration through the driver (Wu et al. 2018 Section 3).

    The iteration (:func:`stableins.procedures.iteration.iterate_offsets`) runs passes of
    the procedure's positions; per position it commands, waits for arrival and settles (samples
    discarded) and records the dwell last.  ``positions``, ``settles`` and ``dwells`` are kept
    here so that the journal alone says which samples belong to which pass and position.
    """

    name: str
    positions: tuple[int, ...] = ()
    settles: tuple[float, ...] = ()
    dwells: tuple[float, ...] = ()
    stage: str = "coarse"
    why: str = "the angle sensors' zero offsets bias every commanded position; re-command with the estimate until they converge"
    kind: str = "offset_iteration"


class SystemEstimation(StrEnum):
    """The estimation a system-level record ends with (``[record] estimation`` of a procedure, docs/procedures.md).

    ``SYSTEM``: the system stage on a static record (docs/system-calibration.md), no index; ``DRIFT``: the drift test
    (docs/drift-test.md), an indexed record; ``SYSTEMATIC``: the systematic stage (docs/systematic-calibration.md),
    an indexed record.
    """

    SYSTEM = "system"
    DRIFT = "drift"
    SYSTEMATIC = "systematic"

    @classmethod
    def default(cls, *, indexed: bool) -> SystemEstimation:
        """Return what a record ends with when its procedure does not say: the drift test if indexed, else the system stage."""
        return cls.DRIFT if indexed else cls.SYSTEM

    def problem(self, *, indexed: bool) -> str:
        """Return why a record indexed (or not) cannot end with this estimation; ``""`` when it can."""
        if self is SystemEstimation.SYSTEM and indexed:
            return "the system stage reads a record held in one orientation, and this one is indexed"
        if self is not SystemEstimation.SYSTEM and not indexed:
            return f"the {self.value} estimation needs at least two orientations: an index during the record"
        return ""


@dataclass(frozen=True)
class StaticRecordStep:
    """System-level static record: hold ``readings`` [rad], settle [s], record ``duration`` [s] with the INS outputs.

    ``turns`` index the platform by torquing during the record; ``estimation`` is what the run ends with.
    """

    name: str
    readings: tuple[float, float, float]
    settle: float
    duration: float
    checks: DwellChecks = field(default_factory=DwellChecks)
    why: str = "the platform stays fixed in inertial space while the INS error dynamics are recorded"
    kind: str = "static_record"
    #: indexing by torquing during the record (times from the record's start)
    turns: tuple[PlatformTurn, ...] = ()
    #: the estimation the run ends with (the system stage, the drift test or the systematic stage)
    estimation: SystemEstimation = SystemEstimation.SYSTEM

    def __post_init__(self) -> None:
        object.__setattr__(self, "estimation", SystemEstimation(self.estimation))


#: Ranges of the thresholds of a plan's dwell checks (SI; every one above its lower end).
_CHECK_RANGES: dict[str, tuple[float, float]] = {
    "saturation": (0.0, 1e5),
    "max_angle_span": (0.0, 4 * math.pi),
    "orientation_tolerance": (0.0, 1e3),
    "angle_tolerance": (0.0, math.pi),
    "scatter_max": (0.0, 1e3),
    "slope_max": (0.0, 1e3),
    "min_fraction": (0.0, 1.0),
    "max_slew": (0.0, MAX_STEP_SECONDS),
    "noise_floor": (0.0, 1e3),
    "correlation_quantile": (0.0, 1.0),
}
#: Whole-number checks and their ranges.
_WHOLE_CHECKS: dict[str, tuple[int, int]] = {"min_samples": (2, 10**8), "noise_blocks": (2, 1000)}

PlanStep = DwellStep | PersonStep | OffsetIterationStep | StaticRecordStep
_STEP_TYPES: dict[str, type[PlanStep]] = {
    "dwell": DwellStep,
    "person": PersonStep,
    "offset_iteration": OffsetIterationStep,
    "static_record": StaticRecordStep,
}


@dataclass(frozen=True)
class Plan:
    """A procedure ready to run.

    Attributes
    ----------
    name : str
        Procedure name.
    level : str
        ``"device"``, ``"system"`` or ``"recal"``: which estimation runs at the end.
    steps : tuple
        The steps in order.
    retries : int
        Repeats of a rejected dwell before the run stops.
    chunk : float
        Dwells are recorded (and journaled) in pieces of at most this many seconds.
    sample_rate : float or None
        Rate the procedure asks of the simulated platform [Hz] (real platforms have their own).
    """

    name: str
    level: str
    steps: tuple[PlanStep, ...]
    retries: int = 2
    chunk: float = DEFAULT_CHUNK_SECONDS
    sample_rate: float | None = None
    description: str = ""

    def __post_init__(self) -> None:
        if not RETRIES_RANGE[0] <= self.retries <= RETRIES_RANGE[1]:
            raise InputError(f"retries = {self.retries}", field="retries", expected=f"{RETRIES_RANGE[0]} to {RETRIES_RANGE[1]}")
        if not CHUNK_RANGE[0] <= self.chunk <= CHUNK_RANGE[1]:
            raise InputError(f"chunk = {self.chunk}", field="chunk", expected=f"{CHUNK_RANGE[0]:g} to {CHUNK_RANGE[1]:g} s")
        for step in self.steps:
            if isinstance(step, DwellStep) and not (step.dwell > 0 and step.settle >= 0):
                raise InputError(f"step {step.name!r}: dwell {step.dwell} s, settle {step.settle} s", expected="dwell > 0, settle >= 0")
            if isinstance(step, PersonStep) and step.action not in ("confirm", "enter"):
                raise InputError(f"step {step.name!r}: action {step.action!r}", field="action", expected="'confirm' or 'enter'")

    def to_dict(self) -> JSONObject:
        """Return the plan document (``procedure.json``) that :meth:`from_dict` reads back."""
        return {
            "name": self.name,
            "level": self.level,
            "retries": self.retries,
            "chunk": self.chunk,
            "sample_rate": self.sample_rate,
            "description": self.description,
            "steps": [asdict(s) for s in self.steps],
        }

    @classmethod
    def from_dict(cls, d: Any, path: Any = None) -> Plan:
        """Validate a plan document (``procedure.json``, a journal's start record) completely and build the plan.

        Raises
        ------
        InputError
            Naming ``path`` and the field (``steps[3].dwell``) and what was expected.
        """
        v = _Validator(path)
        d = v.mapping(d, "", {"name", "level", "retries", "chunk", "sample_rate", "description", "steps"}, {"name", "level", "steps"})
        level = v.choice(d["level"], "level", ("device", "system", "recal"))
        raw_steps = v.list(d["steps"], "steps", 1, MAX_STEPS)
        steps: list[PlanStep] = [v.step(item, f"steps[{k}]") for k, item in enumerate(raw_steps)]
        rate = d.get("sample_rate")
        return cls(
            name=v.text(d["name"], "name"),
            level=level,
            steps=tuple(steps),
            retries=v.integer(d.get("retries", 2), "retries", *RETRIES_RANGE),
            chunk=v.number(d.get("chunk", 10.0), "chunk", *CHUNK_RANGE),  # a plan written before the default changed
            sample_rate=None if rate is None else v.number(rate, "sample_rate", 0.0, 1e4, above=True),
            description=v.text(d.get("description", ""), "description"),
        )


class _Validator:
    """Field checks of a plan document; every failure is an InputError naming the file and the field."""

    def __init__(self, path: Any) -> None:
        self.path = path

    def fail(self, message: str, where: str, expected: str) -> InputError:
        return InputError(message, path=self.path, field=where or None, expected=expected)

    def mapping(self, value: Any, where: str, allowed: set[str], required: set[str]) -> JSONObject:
        if not isinstance(value, dict):
            raise self.fail(f"{str(value)[:40]!r} is not an object", where, "a JSON object")
        unknown = sorted(set(value) - allowed)
        if unknown:
            raise self.fail(f"unknown key {unknown[0][:40]!r}", where, "keys " + ", ".join(sorted(allowed)))
        missing = sorted(required - set(value))
        if missing:
            raise self.fail(f"missing key {missing[0]!r}", where, "keys " + ", ".join(sorted(required)))
        return value

    def list(self, value: Any, where: str, shortest: int = 0, longest: int = MAX_STEPS) -> list[Any]:
        if not isinstance(value, list) or not shortest <= len(value) <= longest:
            raise self.fail(f"{str(value)[:40]!r} is not a list of {shortest} to {longest} items", where, "a list")
        return value

    def text(self, value: Any, where: str) -> str:
        if not isinstance(value, str):
            raise self.fail(f"{str(value)[:40]!r} is not a string", where, "a string")
        return value

    def choice(self, value: Any, where: str, options: tuple[str, ...]) -> str:
        if value not in options:
            raise self.fail(f"{str(value)[:40]!r}", where, " or ".join(repr(o) for o in options))
        return value

    def flag(self, value: Any, where: str) -> bool:
        if not isinstance(value, bool):
            raise self.fail(f"{str(value)[:40]!r} is not true or false", where, "a boolean")
        return value

    def number(self, value: Any, where: str, low: float, high: float, *, above: bool = False) -> float:
        ok = not isinstance(value, bool) and isinstance(value, int | float) and math.isfinite(value)
        if ok:
            ok = (value > low if above else value >= low) and value <= high
        if not ok:
            raise self.fail(f"{str(value)[:40]!r}", where, f"a number in {'(' if above else '['}{low:g}, {high:g}]")
        return float(value)

    def optional_number(self, value: Any, where: str) -> float | None:
        return None if value is None else self.number(value, where, -1e300, 1e300)

    def integer(self, value: Any, where: str, low: int, high: int) -> int:
        if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
            raise self.fail(f"{str(value)[:40]!r}", where, f"a whole number from {low} to {high}")
        return value

    def readings(self, value: Any, where: str) -> tuple[float, float, float]:
        items = self.list(value, where, 3, 3)
        return tuple(self.number(x, f"{where}[{k}]", -MAX_READING, MAX_READING) for k, x in enumerate(items))  # type: ignore[return-value]

    def checks(self, value: Any, where: str) -> DwellChecks:
        d = self.mapping(value, where, set(DwellChecks.__dataclass_fields__), set())
        whole: dict[str, int] = {}
        numbers: dict[str, float] = {}
        for key, item in d.items():  # in the document's order: the first bad field is the one named
            if key in _WHOLE_CHECKS:
                whole[key] = self.integer(item, f"{where}.{key}", *_WHOLE_CHECKS[key])
            else:
                numbers[key] = self.number(item, f"{where}.{key}", *_CHECK_RANGES[key], above=True)
        default = DwellChecks()
        return DwellChecks(
            min_samples=whole.get("min_samples", default.min_samples),
            noise_blocks=whole.get("noise_blocks", default.noise_blocks),
            saturation=numbers.get("saturation", default.saturation),
            max_angle_span=numbers.get("max_angle_span", default.max_angle_span),
            orientation_tolerance=numbers.get("orientation_tolerance", default.orientation_tolerance),
            angle_tolerance=numbers.get("angle_tolerance", default.angle_tolerance),
            scatter_max=numbers.get("scatter_max", default.scatter_max),
            slope_max=numbers.get("slope_max", default.slope_max),
            min_fraction=numbers.get("min_fraction", default.min_fraction),
            max_slew=numbers.get("max_slew", default.max_slew),
            noise_floor=numbers.get("noise_floor", default.noise_floor),
            correlation_quantile=numbers.get("correlation_quantile", default.correlation_quantile),
        )

    def turns(self, value: Any, where: str, duration: float) -> tuple[PlatformTurn, ...]:
        """Check the turns of a static-record step (SI) and return them in time order within ``duration``."""
        out = []
        for k, item in enumerate(self.list(value, where, 0, 1000)):
            here = f"{where}[{k}]"
            d = self.mapping(item, here, {"start", "angle", "axis", "rate"}, {"start", "angle", "axis", "rate"})
            axis = self.choice(d["axis"], f"{here}.axis", tuple(a.value for a in IndexAxis))
            start = self.number(d["start"], f"{here}.start", 0.0, MAX_RECORD_SECONDS)
            angle = self.number(d["angle"], f"{here}.angle", -2 * math.pi, 2 * math.pi)
            rate = self.number(d["rate"], f"{here}.rate", 0.0, math.pi, above=True)
            if angle == 0.0:
                raise self.fail("a turn of 0 rad", f"{here}.angle", "a non-zero angle [rad]")
            out.append(PlatformTurn(start, angle, IndexAxis(axis), rate))
        try:
            check_turns(out, duration)
        except (InputError, NotDeterminedError):
            raise  # a described error passes through as it is (issue 29)
        except ValueError as error:
            raise self.fail(str(error), where, "turns in time order within the record") from None
        return tuple(out)

    def step(self, value: Any, where: str) -> PlanStep:
        """Read one step of a plan document: its ``kind`` and that kind's fields, every value checked."""
        if not isinstance(value, dict) or not isinstance(value.get("kind"), str) or value["kind"] not in _STEP_TYPES:
            kind = value.get("kind") if isinstance(value, dict) else value
            raise self.fail(f"step kind {str(kind)[:40]!r}", f"{where}.kind", " or ".join(repr(k) for k in _STEP_TYPES))
        kind = value["kind"]
        step_type = _STEP_TYPES[kind]
        names = {spec.name for spec in fields(step_type)}
        required = {spec.name for spec in fields(step_type) if spec.default is spec.default_factory is MISSING}
        d = self.mapping(value, where, names, required | {"kind"})
        name = self.text(d["name"], f"{where}.name")
        texts: dict[str, str] = {key: self.text(d[key], f"{where}.{key}") for key in ("why", "prompt", "key", "unit") if key in d}
        if kind == "dwell":
            return self._dwell_step(d, where, name, texts)
        if kind == "static_record":
            return self._static_record_step(d, where, name, texts)
        if kind == "offset_iteration":
            return self._offset_iteration_step(d, where, name, texts)
        return self._person_step(d, where, name, texts)

    def _dwell_step(self, d: JSONObject, where: str, name: str, texts: dict[str, str]) -> DwellStep:
        """Return a dwell step, its fields checked (``texts``: its ``why``, checked already)."""
        stage = self.choice(d["stage"], f"{where}.stage", ("coarse", "fine", "rotating"))
        pass_number = self.integer(d["pass_number"], f"{where}.pass_number", 1, 10**6)
        position = self.integer(d["position"], f"{where}.position", 1, 10**6)
        readings = self.readings(d["readings"], f"{where}.readings")
        settle = self.number(d["settle"], f"{where}.settle", 0.0, MAX_STEP_SECONDS)
        dwell = self.number(d["dwell"], f"{where}.dwell", 0.0, MAX_STEP_SECONDS, above=True)
        checks = self.checks(d["checks"], f"{where}.checks") if "checks" in d else DwellChecks()
        flags = {key: self.flag(d[key], f"{where}.{key}") for key in ("offset_corrected", "keep_slew") if key in d}
        return DwellStep(
            name,
            stage,
            pass_number,
            position,
            readings,
            settle,
            dwell,
            checks,
            why=texts.get("why", DwellStep.why),
            offset_corrected=flags.get("offset_corrected", DwellStep.offset_corrected),
            keep_slew=flags.get("keep_slew", DwellStep.keep_slew),
        )

    def _static_record_step(self, d: JSONObject, where: str, name: str, texts: dict[str, str]) -> StaticRecordStep:
        """Return a static-record step, its fields checked (``texts``: its ``why``, checked already)."""
        readings = self.readings(d["readings"], f"{where}.readings")
        settle = self.number(d["settle"], f"{where}.settle", 0.0, MAX_STEP_SECONDS)
        duration = self.number(d["duration"], f"{where}.duration", 0.0, MAX_RECORD_SECONDS, above=True)
        checks = self.checks(d["checks"], f"{where}.checks") if "checks" in d else DwellChecks()
        turns = self.turns(d["turns"], f"{where}.turns", duration) if "turns" in d else ()
        indexed = bool(turns)
        if "estimation" in d:
            options = tuple(e.value for e in SystemEstimation)
            estimation = SystemEstimation(self.choice(d["estimation"], f"{where}.estimation", options))
        else:  # a plan written before the field: what its record ended with then
            estimation = SystemEstimation.default(indexed=indexed)
        problem = estimation.problem(indexed=indexed)
        if problem:
            raise self.fail(problem, f"{where}.estimation", "'system' for a record without turns, 'drift' or 'systematic' with turns")
        why = texts.get("why", StaticRecordStep.why)
        return StaticRecordStep(name, readings, settle, duration, checks, why=why, turns=turns, estimation=estimation)

    def _offset_iteration_step(self, d: JSONObject, where: str, name: str, texts: dict[str, str]) -> OffsetIterationStep:
        """Return a zero-offset iteration step, its fields checked (``texts``: its ``why``, checked already)."""
        at = f"{where}.positions"
        positions = self.list(d.get("positions", []), at, 1, 10**4)
        n = len(positions)
        return OffsetIterationStep(
            name,
            positions=tuple(self.integer(p, f"{at}[{k}]", 1, 10**6) for k, p in enumerate(positions)),
            settles=tuple(
                self.number(x, f"{where}.settles[{k}]", 0.0, MAX_STEP_SECONDS)
                for k, x in enumerate(self.list(d.get("settles", []), f"{where}.settles", n, n))
            ),
            dwells=tuple(
                self.number(x, f"{where}.dwells[{k}]", 0.0, MAX_STEP_SECONDS, above=True)
                for k, x in enumerate(self.list(d.get("dwells", []), f"{where}.dwells", n, n))
            ),
            stage=self.choice(d["stage"], f"{where}.stage", ("coarse",)) if "stage" in d else OffsetIterationStep.stage,
            why=texts.get("why", OffsetIterationStep.why),
        )

    def _person_step(self, d: JSONObject, where: str, name: str, texts: dict[str, str]) -> PersonStep:
        """Return a person step, its fields checked (``texts``: its ``prompt``, ``key`` and ``unit``, checked already)."""
        action = self.choice(d["action"], f"{where}.action", ("confirm", "enter"))
        bounds = {key: self.optional_number(d[key], f"{where}.{key}") for key in ("minimum", "maximum") if key in d}
        default = d.get("default")
        if isinstance(default, bool) or not (default is None or isinstance(default, str | int | float)):
            raise self.fail(f"default {str(default)[:40]!r}", f"{where}.default", "a number, a text or null")
        minimum, maximum = bounds.get("minimum"), bounds.get("maximum")
        check_person_default(minimum, maximum, default, self.path, f"{where}.default")
        return PersonStep(
            name,
            action,
            texts["prompt"],
            key=texts.get("key", PersonStep.key),
            unit=texts.get("unit", PersonStep.unit),
            minimum=minimum,
            maximum=maximum,
            default=default,
        )


def check_person_default(minimum: float | None, maximum: float | None, default: Any, path: Any, where: str) -> None:
    """Check that a person step's bounds are ordered and that its default (what an unattended run enters) obeys them."""
    if minimum is not None and maximum is not None and minimum > maximum:
        raise InputError(f"minimum {minimum:g} above maximum {maximum:g}", path=path, field=where, expected="minimum <= maximum")
    if default is None or (minimum is None and maximum is None):
        return
    if isinstance(default, str):
        try:
            value = float(default)
        except ValueError:
            raise InputError(f"default {default[:40]!r} is not a number", path=path, field=where, expected="a number") from None
    else:
        value = float(default)
    if not math.isfinite(value) or (minimum is not None and value < minimum) or (maximum is not None and value > maximum):
        raise InputError(
            f"default {default!r} is outside the step's range",
            path=path,
            field=where,
            expected=f"a default from {minimum} to {maximum}",
        )
