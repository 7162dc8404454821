"""Procedure definitions: load a TOML file of gimbal steps and validate it.

The format is documented at the top of ``device-coarse.toml`` and in ``docs/procedures.md``.  The
definitions shipped with stableins are package data (``stableins/procedures/definitions/``), so a
name such as ``"device-coarse"`` is found from any directory, in a checkout and in an installed
wheel alike; ``procedures/`` at the top of the repository links to them.  Angles are
written in degrees in the file and held in radians here (SI inside).  Every problem
raises :class:`stableins.data.errors.InputError` naming the file and the field.
"""

from __future__ import annotations

import math
import tomllib
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from stableins.conventions import ARCSEC
from stableins.data.errors import InputError

#: Where the definitions shipped with stableins live: package data, found by name from any directory.
PROCEDURE_DIRECTORY = Path(__file__).resolve().parent / "definitions"

_STEP_KEYS = {"position", "platform", "inner", "middle", "settle", "dwell", "sample_rate", "expect"}
#: ``tolerances`` and ``uncertainty`` are read and validated by the report (stableins.reporting.tolerances and
#: stableins.reporting.budget, docs/reports.md).
_SECTIONS = {
    "procedure", "defaults", "acceptance", "offset_iteration", "step", "runner", "person", "record", "tolerances", "uncertainty", "model",
}  # fmt: skip
#: Stages a definition may declare.
STAGES = ("coarse", "fine", "system")
_AXIS_WORDS = {"up", "down", "level", "+45", "-45"}


@dataclass(frozen=True)
class Step:
    """One position: commanded angle-sensor readings [rad] and timing [s, Hz]."""

    position: int
    command: tuple[float, float, float]
    settle: float
    dwell: float
    sample_rate: float
    expect: str = ""

    @property
    def command_degrees(self) -> tuple[float, float, float]:
        return tuple(math.degrees(a) for a in self.command)  # type: ignore[return-value]


@dataclass(frozen=True)
class Acceptance:
    """Dwell acceptance checks (SI): see :class:`stableins.estimators.dwell.DwellChecks`."""

    min_samples: int = 20
    noise_blocks: int = 10
    saturation: float = 29.41995
    max_angle_span: float = 20.0 * ARCSEC
    orientation_tolerance: float = 0.196133

    def dwell_checks(self):
        from stableins.estimators.dwell import DwellChecks

        return DwellChecks(
            min_samples=self.min_samples, blocks=self.noise_blocks, saturation=self.saturation, max_angle_span=self.max_angle_span
        )


@dataclass(frozen=True)
class OffsetIteration:
    """Zero-offset re-commanding loop: stop below ``threshold`` [rad] (or within
    ``noise_sigmas`` of zero), at most ``max_passes`` passes."""

    threshold: float = 0.1 * ARCSEC
    max_passes: int = 5
    noise_sigmas: float = 3.0


@dataclass(frozen=True)
class ProcedureDefinition:
    """A validated procedure."""

    name: str
    stage: str
    source: str
    handedness: int
    repoint: bool
    steps: tuple[Step, ...]
    acceptance: Acceptance
    offset_iteration: OffsetIteration
    path: str = ""
    runner: RunnerSettings = field(default_factory=lambda: RunnerSettings())
    people: tuple[PersonAction, ...] = ()
    record: StaticRecord | None = None
    #: ``[model] add``: discovered effects (library ids) the stage estimates with the standard terms.
    model_add: tuple[str, ...] = ()
    #: the ``[tolerances]`` table as written (validated by :mod:`stableins.reporting.tolerances`), None if absent
    tolerances: dict[str, Any] | None = None
    #: the ``[uncertainty]`` table as written (Type B inputs, validated by :mod:`stableins.reporting.budget`), None if absent
    uncertainty: dict[str, Any] | None = None

    @property
    def positions(self) -> tuple[int, ...]:
        return tuple(s.position for s in self.steps)

    def step(self, position: int) -> Step:
        for s in self.steps:
            if s.position == position:
                return s
        raise KeyError(position)

    @property
    def duration(self) -> float:
        """Total settle + dwell time [s] (slews not included)."""
        return sum(s.settle + s.dwell for s in self.steps)


#: Longest settle or dwell of a step and longest static record [s]; fastest sample rate [Hz].
MAX_SECONDS = 86400.0
MAX_RECORD_SECONDS = 30 * 86400.0
MAX_RATE = 1e4
#: Largest procedure file read [bytes] (50 000 steps are about 5 MB).
MAX_FILE_BYTES = 64 << 20


def _number(
    table: dict,
    key: str,
    path: str,
    where: str,
    *,
    positive: bool = False,
    minimum: float | None = None,
    maximum: float | None = None,
    whole: bool = False,
) -> float:
    value = table[key]
    field = f"{where.split()[0]}.{key}"  # "step 3" -> step.dwell, "runner" -> runner.chunk
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise InputError(f"{where}: not a finite number ({str(value)[:40]!r})", path=path, field=field, expected="a number")
    if positive and value <= 0:
        raise InputError(f"{where}: must be positive ({value!r})", path=path, field=field, expected="> 0")
    if minimum is not None and value < minimum:
        raise InputError(f"{where}: below {minimum} ({value!r})", path=path, field=field, expected=f">= {minimum}")
    if maximum is not None and value > maximum:
        raise InputError(f"{where}: above {maximum:g} ({value!r})", path=path, field=field, expected=f"<= {maximum:g}")
    if whole and value != int(value):
        raise InputError(f"{where}: {value!r} is not a whole number", path=path, field=field, expected="a whole number")
    return float(value)


def shipped_procedures() -> tuple[str, ...]:
    """Names of the definitions shipped with stableins (``"device-coarse"``, ...)."""
    return tuple(sorted(p.stem for p in PROCEDURE_DIRECTORY.glob("*.toml")))


def _table(value: Any, path: str, name: str) -> dict[str, Any]:
    if not isinstance(value, dict):
        raise InputError(f"[{name}] must be a table", path=path, field=name, expected=f"a [{name}] table")
    return value


def resolve(name_or_path: str | Path) -> Path:
    """A path, or the name of a shipped definition (``"device-coarse"``).

    A name without ``.toml`` that is not an existing file is looked up among the shipped
    definitions (package data, :data:`PROCEDURE_DIRECTORY`), whatever the working directory.
    """
    p = Path(name_or_path)
    if p.suffix == ".toml" or p.exists():
        return p
    return PROCEDURE_DIRECTORY / f"{name_or_path}.toml"


def load_procedure(name_or_path: str | Path) -> ProcedureDefinition:
    """Load and validate a procedure definition.

    Raises
    ------
    InputError
        Unreadable file, TOML syntax error, unknown or missing keys, bad numbers,
        duplicated or non-consecutive positions.
    """
    path = resolve(name_or_path)
    spath = str(path)
    shipped = ", ".join(shipped_procedures())
    data = read_toml(path, what=f"a procedure definition (a TOML file, or the name of a shipped definition: {shipped})")
    unknown = set(data) - _SECTIONS
    if unknown:
        raise InputError(f"unknown sections {sorted(unknown)}", path=spath, expected=f"{sorted(_SECTIONS)}")
    head = data.get("procedure")
    if not isinstance(head, dict):
        raise InputError("missing [procedure] table", path=spath, field="procedure")
    for key in ("name", "stage"):
        if not isinstance(head.get(key), str):
            raise InputError("missing or not a string", path=spath, field=f"procedure.{key}")
    if head.get("angle_unit", "deg") != "deg":
        raise InputError("commands must be written in degrees", path=spath, field="procedure.angle_unit", expected='"deg"')
    handedness = head.get("handedness", 1)
    if isinstance(handedness, bool) or handedness not in (1, -1):
        raise InputError("must be +1 or -1", path=spath, field="procedure.handedness")
    for key in ("source",):
        if key in head and not isinstance(head[key], str):
            raise InputError("not a string", path=spath, field=f"procedure.{key}")
    if "repoint" in head and not isinstance(head["repoint"], bool):
        raise InputError(f"{head['repoint']!r} is not true or false", path=spath, field="procedure.repoint", expected="true or false")
    defaults = _table(data.get("defaults", {}), spath, "defaults")
    unknown = set(defaults) - set(_TIMING_LIMITS)
    if unknown:
        raise InputError(f"unknown keys {sorted(unknown)}", path=spath, field="defaults", expected=f"{sorted(_TIMING_LIMITS)}")
    base = {}
    for key, fallback in (("settle", 0.0), ("dwell", None), ("sample_rate", None)):
        if key in defaults:
            base[key] = _number(defaults, key, spath, "defaults", **_TIMING_LIMITS[key])
        elif fallback is not None:
            base[key] = fallback
    acc_table = _table(data.get("acceptance", {}), spath, "acceptance")
    acc_fields = {"min_samples", "noise_blocks", "saturation", "max_angle_span", "orientation_tolerance"}
    if set(acc_table) - acc_fields:
        raise InputError(
            f"unknown keys {sorted(set(acc_table) - acc_fields)}", path=spath, field="acceptance", expected=f"{sorted(acc_fields)}"
        )
    acc_values: dict[str, Any] = {k: _number(acc_table, k, spath, "acceptance", **_ACCEPTANCE_LIMITS[k]) for k in acc_table}
    for k in ("min_samples", "noise_blocks"):
        if k in acc_values:
            acc_values[k] = int(acc_values[k])
    if "max_angle_span" in acc_values:
        acc_values["max_angle_span"] *= ARCSEC
    acceptance = Acceptance(**acc_values)
    it_table = _table(data.get("offset_iteration", {}), spath, "offset_iteration")
    it_fields = {"threshold", "max_passes", "noise_sigmas"}
    if set(it_table) - it_fields:
        raise InputError(f"unknown keys {sorted(set(it_table) - it_fields)}", path=spath, field="offset_iteration")
    it_limits: dict[str, dict[str, Any]] = {
        "threshold": {"minimum": 0.0, "maximum": 3600.0},
        "max_passes": {"minimum": 1.0, "maximum": 100.0, "whole": True},
        "noise_sigmas": {"minimum": 0.0, "maximum": 100.0},
    }
    it_values: dict[str, Any] = {k: _number(it_table, k, spath, "offset_iteration", **it_limits[k]) for k in it_table}
    if "threshold" in it_values:
        it_values["threshold"] *= ARCSEC
    if "max_passes" in it_values:
        it_values["max_passes"] = int(it_values["max_passes"])
    if head["stage"] not in STAGES:
        raise InputError(f"unknown stage {head['stage']!r}", path=spath, field="procedure.stage", expected=" or ".join(map(repr, STAGES)))
    steps_raw = data.get("step")
    if head["stage"] == "system" and steps_raw is None:
        steps_raw = []  # a static record: [record] says where and how long
    elif not isinstance(steps_raw, list) or not steps_raw:
        raise InputError("no [[step]] entries", path=spath, field="step")
    steps = []
    for k, raw in enumerate(steps_raw, start=1):
        where = f"step {k}"
        if not isinstance(raw, dict):
            raise InputError(f"{where}: not a table", path=spath, field="step", expected="[[step]] tables")
        unknown = set(raw) - _STEP_KEYS
        if unknown:
            raise InputError(f"{where}: unknown keys {sorted(unknown)}", path=spath, field="step", expected=f"{sorted(_STEP_KEYS)}")
        for key in ("position", "platform", "inner", "middle"):
            if key not in raw:
                raise InputError(f"{where}: missing", path=spath, field=f"step.{key}")
        position = raw["position"]
        if isinstance(position, bool) or not isinstance(position, int):
            raise InputError(f"{where}: position must be an integer", path=spath, field="step.position")
        angles = []
        for key in ("platform", "inner", "middle"):
            deg = _number(raw, key, spath, where)
            if abs(deg) > 720.0:
                raise InputError(
                    f"{where}: {deg} deg is not a gimbal angle in degrees", path=spath, field=f"step.{key}", expected="degrees"
                )
            angles.append(math.radians(deg))
        timing = dict(base)
        for key in ("settle", "dwell", "sample_rate"):
            if key in raw:
                timing[key] = _number(raw, key, spath, where, **_TIMING_LIMITS[key])
            if key not in timing:
                raise InputError(f"{where}: no {key} and no default", path=spath, field=f"step.{key}")
        expect = raw.get("expect", "")
        if expect:
            words = [w.strip().split() for w in str(expect).split(",")]
            if len(words) != 3 or any(len(w) != 2 or w[0] != a or w[1] not in _AXIS_WORDS for w, a in zip(words, "xyz")):
                raise InputError(
                    f"{where}: cannot read {expect!r}", path=spath, field="step.expect", expected="'x <dir>, y <dir>, z <dir>'"
                )
        steps.append(Step(position, tuple(angles), timing["settle"], timing["dwell"], timing["sample_rate"], str(expect)))
    positions = [s.position for s in steps]
    if positions != list(range(1, len(steps) + 1)):  # linear in the number of steps
        dup = sorted(p for p, count in Counter(positions).items() if count > 1)
        first = next(k for k, p in enumerate(positions, start=1) if p != k)
        what = f"duplicated positions {dup[:10]}" if dup else f"step {first} has position {positions[first - 1]}"
        raise InputError(f"{what}: positions must run 1, 2, ... {len(steps)} in order", path=spath, field="step.position")
    return ProcedureDefinition(
        name=head["name"],
        stage=head["stage"],
        source=str(head.get("source", "")),
        handedness=int(handedness),
        repoint=bool(head.get("repoint", False)),
        steps=tuple(steps),
        acceptance=acceptance,
        offset_iteration=OffsetIteration(**it_values),
        path=spath,
        runner=_runner_settings(data.get("runner", {}), spath),
        people=_people(data.get("person", []), spath, len(steps)),
        record=_static_record(data.get("record"), head["stage"], spath),
        model_add=_model_add(data.get("model", {}), head["stage"], spath),
        tolerances=None if data.get("tolerances") is None else data["tolerances"],
        uncertainty=None if data.get("uncertainty") is None else data["uncertainty"],
    )


def read_toml(path: str | Path, *, what: str) -> dict[str, Any]:
    """A TOML file as a table; InputError naming the file when it is missing, a directory, too large, not UTF-8 or not TOML."""
    from stableins.data.jsonio import read_input_bytes

    data = read_input_bytes(path, max_bytes=MAX_FILE_BYTES, what=what)
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as error:
        raise InputError(
            f"not UTF-8 text (byte {error.start} is {data[error.start : error.start + 1]!r})", path=path, expected="a TOML file in UTF-8"
        ) from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"not valid TOML: {exc}", path=path) from None
    except RecursionError:
        raise InputError("nested too deeply", path=path, expected="a TOML procedure definition") from None


# --------------------------------------------------------------------------- runner sections
@dataclass(frozen=True)
class RunnerSettings:
    """``[runner]``: how ``stableins run`` executes and accepts each dwell (SI).

    ``angle_tolerance`` [rad] (file: arcsec): the platform must be this close to the
    commanded readings (arrival, and the mean over the dwell); ``max_slew`` [s]: longest wait
    for arrival; ``scatter_max`` [m/s²] (file: µg): largest residual standard deviation of a
    dwell about its straight line; ``slope_max`` [m/s² per s] (file: µg/s): largest slope
    beyond 3σ of its own noise; ``retries``: repeats of a rejected dwell before the run stops;
    ``chunk`` [s]: dwells are journaled in pieces of at most this length.
    """

    retries: int = 2
    chunk: float = 10.0
    angle_tolerance: float = 20.0 * ARCSEC
    scatter_max: float = 5e-3 * 9.80665
    slope_max: float = 20e-6 * 9.80665
    max_slew: float = 120.0


@dataclass(frozen=True)
class PersonAction:
    """``[[person]]``: a step a person carries out before position ``before`` (0: before the first;
    ``len(steps) + 1``: at the end).  ``action`` is ``"confirm"`` or ``"enter"`` (a value with
    ``unit`` in ``[minimum, maximum]``; ``default`` is what an unattended run uses)."""

    before: int
    action: str
    prompt: str
    key: str = ""
    unit: str = ""
    minimum: float | None = None
    maximum: float | None = None
    default: float | str | None = None


@dataclass(frozen=True)
class StaticRecord:
    """``[record]`` of a system-level procedure: hold the platform at ``command`` [rad] (file: deg),
    settle [s], then record ``duration`` [s] at ``sample_rate`` [Hz]."""

    command: tuple[float, float, float]
    settle: float
    duration: float
    sample_rate: float


#: Ranges of the timing keys of [defaults] and [[step]].
_TIMING_LIMITS: dict[str, dict[str, Any]] = {
    "settle": {"minimum": 0.0, "maximum": MAX_SECONDS},
    "dwell": {"positive": True, "maximum": MAX_SECONDS},
    "sample_rate": {"positive": True, "maximum": MAX_RATE},
}
#: Ranges of the [acceptance] keys (file units: samples, blocks, m/s², arcsec, m/s²).
_ACCEPTANCE_LIMITS: dict[str, dict[str, Any]] = {
    "min_samples": {"minimum": 2.0, "maximum": 1e8, "whole": True},
    "noise_blocks": {"minimum": 2.0, "maximum": 1000.0, "whole": True},
    "saturation": {"positive": True, "maximum": 1e4},
    "max_angle_span": {"positive": True, "maximum": 1296000.0},
    "orientation_tolerance": {"positive": True, "maximum": 100.0},
}
_RUNNER_KEYS = {
    "retries": 1.0,
    "chunk": 1.0,
    "angle_tolerance": ARCSEC,
    "scatter_max": 9.80665e-6,
    "slope_max": 9.80665e-6,
    "max_slew": 1.0,
}
_PERSON_KEYS = {"before", "action", "prompt", "key", "unit", "minimum", "maximum", "default"}
_RECORD_KEYS = {"platform", "inner", "middle", "settle", "duration", "sample_rate"}


def _runner_settings(table: Any, path: str) -> RunnerSettings:
    if not isinstance(table, dict):
        raise InputError("[runner] must be a table", path=path, field="runner")
    unknown = set(table) - set(_RUNNER_KEYS)
    if unknown:
        raise InputError(f"unknown keys {sorted(unknown)}", path=path, field="runner", expected=f"{sorted(_RUNNER_KEYS)}")
    from stableins.procedures.plan import CHUNK_RANGE, RETRIES_RANGE

    limits: dict[str, dict[str, Any]] = {
        "retries": {"minimum": RETRIES_RANGE[0], "maximum": RETRIES_RANGE[1], "whole": True},
        "chunk": {"minimum": CHUNK_RANGE[0], "maximum": CHUNK_RANGE[1]},
        "angle_tolerance": {"positive": True, "maximum": 648000.0},
        "scatter_max": {"positive": True, "maximum": 1e8},
        "slope_max": {"positive": True, "maximum": 1e8},
        "max_slew": {"positive": True, "maximum": MAX_SECONDS},
    }
    values: dict[str, Any] = {}
    for key, factor in _RUNNER_KEYS.items():
        if key in table:
            values[key] = _number(table, key, path, "runner", **limits[key]) * factor
    if "retries" in values:
        values["retries"] = int(values["retries"])
    return RunnerSettings(**values)


def _people(entries: Any, path: str, steps: int) -> tuple[PersonAction, ...]:
    if not isinstance(entries, list):
        raise InputError("person steps are written [[person]]", path=path, field="person")
    from stableins.procedures.plan import check_person_default

    people = []
    for k, raw in enumerate(entries, start=1):
        where = f"person {k}"
        if not isinstance(raw, dict):
            raise InputError(f"{where}: not a table", path=path, field="person", expected="[[person]] tables")
        unknown = set(raw) - _PERSON_KEYS
        if unknown:
            raise InputError(f"{where}: unknown keys {sorted(unknown)}", path=path, field="person", expected=f"{sorted(_PERSON_KEYS)}")
        for key in ("before", "action", "prompt"):
            if key not in raw:
                raise InputError(f"{where}: missing", path=path, field=f"person.{key}")
        before = raw["before"]
        if isinstance(before, bool) or not isinstance(before, int) or not 0 <= before <= steps + 1:
            raise InputError(f"{where}: before = {before!r}", path=path, field="person.before", expected=f"a position 0 .. {steps + 1}")
        if raw["action"] not in ("confirm", "enter"):
            raise InputError(f"{where}: action {raw['action']!r}", path=path, field="person.action", expected="'confirm' or 'enter'")
        if not isinstance(raw["prompt"], str) or not raw["prompt"].strip():
            raise InputError(f"{where}: empty prompt", path=path, field="person.prompt", expected="what the person must do")
        if raw["action"] == "enter" and not isinstance(raw.get("key"), str):
            raise InputError(
                f"{where}: an 'enter' step names its value", path=path, field="person.key", expected="a key, e.g. 'lab_temperature'"
            )
        bounds = {b: _number(raw, b, path, where) if b in raw else None for b in ("minimum", "maximum")}
        if bounds["minimum"] is not None and bounds["maximum"] is not None and bounds["minimum"] > bounds["maximum"]:
            raise InputError(f"{where}: minimum above maximum", path=path, field="person.minimum")
        default = raw.get("default")
        if isinstance(default, bool) or (default is not None and not isinstance(default, str | int | float)):
            raise InputError(f"{where}: default {default!r}", path=path, field="person.default", expected="a number or text")
        if isinstance(default, float) and not math.isfinite(default):
            raise InputError(f"{where}: default {default!r}", path=path, field="person.default", expected="a finite number or text")
        for key in ("key", "unit"):
            if key in raw and not isinstance(raw[key], str):
                raise InputError(f"{where}: {raw[key]!r} is not a string", path=path, field=f"person.{key}")
        check_person_default(bounds["minimum"], bounds["maximum"], default, path, f"person {k}: default")
        people.append(
            PersonAction(
                before, raw["action"], raw["prompt"].strip(), str(raw.get("key", "")), str(raw.get("unit", "")), **bounds, default=default
            )
        )
    return tuple(people)


def _model_add(table: Any, stage: str, path: str) -> tuple[str, ...]:
    """``[model] add = ["Kcc_xxy", ...]``: effects of the discovery library carried into the device stages."""
    if not isinstance(table, dict):
        raise InputError("[model] must be a table", path=path, field="model")
    unknown = set(table) - {"add"}
    if unknown:
        raise InputError(f"unknown keys {sorted(unknown)}", path=path, field="model", expected="add = [effect ids]")
    ids = table.get("add", [])
    if not isinstance(ids, list) or not all(isinstance(i, str) for i in ids):
        raise InputError(f"{ids!r} is not a list of effect ids", path=path, field="model.add", expected='e.g. add = ["Kcc_xxy"]')
    if ids and stage == "system":
        raise InputError(
            "a system-level record does not estimate discovered effects; it compensates those of the prior record",
            path=path,
            field="model.add",
            expected="[model] in a coarse or fine procedure",
        )
    from stableins.discovery.library import calibration_terms

    try:
        calibration_terms(ids, source="model.add")
    except InputError as error:
        raise InputError(error.message, path=path, field="model.add", expected=error.expected) from None
    return tuple(ids)


def _static_record(table: Any, stage: str, path: str) -> StaticRecord | None:
    if table is None:
        if stage == "system":
            raise InputError(
                "a system-level procedure needs a [record] table", path=path, field="record", expected=f"{sorted(_RECORD_KEYS)}"
            )
        return None
    if stage != "system":
        raise InputError(f"[record] belongs to system-level procedures, this one is {stage!r}", path=path, field="record")
    if not isinstance(table, dict):
        raise InputError("[record] must be a table", path=path, field="record")
    unknown = set(table) - _RECORD_KEYS
    missing = {"duration", "sample_rate"} - set(table)
    if unknown or missing:
        what = f"unknown keys {sorted(unknown)}" if unknown else f"missing {sorted(missing)}"
        raise InputError(what, path=path, field="record", expected=f"{sorted(_RECORD_KEYS)} (duration and sample_rate required)")
    angles = []
    for key in ("platform", "inner", "middle"):
        deg = _number(table, key, path, "record") if key in table else 0.0
        if abs(deg) > 720.0:
            raise InputError(f"{deg} deg is not a gimbal angle in degrees", path=path, field=f"record.{key}", expected="degrees")
        angles.append(math.radians(deg))
    return StaticRecord(
        command=(angles[0], angles[1], angles[2]),
        settle=_number(table, "settle", path, "record", minimum=0.0, maximum=MAX_SECONDS) if "settle" in table else 0.0,
        duration=_number(table, "duration", path, "record", positive=True, maximum=MAX_RECORD_SECONDS),
        sample_rate=_number(table, "sample_rate", path, "record", positive=True, maximum=MAX_RATE),
    )
