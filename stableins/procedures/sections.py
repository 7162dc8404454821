"""The sections of a procedure file that say how it runs: ``[runner]``, ``[[person]]``, ``[record]`` and ``[model]``.

Read and validated for :func:`stableins.procedures.definition.load_procedure`; every problem raises
:class:`~stableins.errors.InputError` naming the file and the field (docs/procedures.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, TypedDict

from stableins.conventions import ARCSEC, MICRO_G
from stableins.documents import TOMLTable
from stableins.errors import InputError, NotDeterminedError
from stableins.procedures.plan import DEFAULT_CHUNK_SECONDS, MAX_RECORD_SECONDS, SystemEstimation
from stableins.turns import INDEX_RATE, IndexAxis, PlatformTurn, check_turns

#: Longest settle or dwell of a step and longest static record [s]; fastest sample rate [Hz].
MAX_SECONDS = 86400.0
MAX_RATE = 1e4


class NumberLimits(TypedDict, total=False):
    """The bounds :func:`toml_number` checks a number against (each optional)."""

    positive: bool
    minimum: float
    maximum: float
    whole: bool


def toml_number(
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
    """Return ``table[key]`` as a finite number within the given bounds; InputError naming the field otherwise."""
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


def toml_table(value: object, path: str, name: str) -> TOMLTable:
    """Return ``value`` if it is a TOML table; InputError naming ``[name]`` otherwise."""
    if not isinstance(value, dict):
        raise InputError(f"[{name}] must be a table", path=path, field=name, expected=f"a [{name}] table")
    return value


@dataclass(frozen=True)
class RunnerSettings:
    """``[runner]``: how ``stableins run`` executes a procedure.

    ``retries``: repeats of a rejected dwell before the run stops; ``chunk`` [s]: dwells are
    journaled in pieces of at most this length (default :data:`~stableins.procedures.plan.DEFAULT_CHUNK_SECONDS`, 1 s: the
    journal and the console follow a dwell second by second).  The table's thresholds (``angle_tolerance``,
    ``scatter_max``, ``slope_max``, ``max_slew``) are dwell checks: they go to the procedure's
    :class:`~stableins.estimators.layout.DwellChecks`.
    """

    retries: int = 2
    chunk: float = DEFAULT_CHUNK_SECONDS


@dataclass(frozen=True)
class PersonAction:
    """``[[person]]``: a step a person carries out before position ``before``.

    ``before`` is 0 before the first position and ``len(steps) + 1`` at the end.  ``action`` is ``"confirm"`` or
    ``"enter"`` (a value with ``unit`` in ``[minimum, maximum]``; ``default`` is what an unattended run uses).
    """

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
    """``[record]`` of a system-level procedure.

    Hold the platform at ``command`` [rad] (file: deg), settle [s], then record ``duration`` [s] at ``sample_rate`` [Hz].
    """

    command: tuple[float, float, float]
    settle: float
    duration: float
    sample_rate: float
    #: indexing of the platform by torquing during the record (``[[record.index]]``), in time order
    turns: tuple[PlatformTurn, ...] = ()
    #: what the run ends with (``estimation``; by default the drift test for an indexed record, else the system stage)
    estimation: SystemEstimation = SystemEstimation.SYSTEM


_RUNNER_KEYS = {
    "retries": 1.0,
    "chunk": 1.0,
    "angle_tolerance": ARCSEC,
    "scatter_max": MICRO_G,
    "slope_max": MICRO_G,
    "max_slew": 1.0,
}
_PERSON_KEYS = {"before", "action", "prompt", "key", "unit", "minimum", "maximum", "default"}
_RECORD_KEYS = {"platform", "inner", "middle", "settle", "duration", "sample_rate", "index", "estimation"}
_INDEX_KEYS = {"at", "axis", "angle", "rate"}


class RunnerChecks(TypedDict, total=False):
    """The dwell checks ``[runner]`` gives, in SI (the fields of :class:`~stableins.estimators.layout.DwellChecks` it may set)."""

    angle_tolerance: float
    scatter_max: float
    slope_max: float
    max_slew: float


def _runner_values(table: Any, path: str) -> dict[str, float]:
    """Return the ``[runner]`` table in SI, validated (file units: arcsec, µg, µg/s, s)."""
    if not isinstance(table, dict):
        raise InputError("[runner] must be a table", path=path, field="runner")
    unknown = set(table) - set(_RUNNER_KEYS)
    if unknown:
        raise InputError(f"unknown keys {sorted(unknown)}", path=path, field="runner", expected=f"{sorted(_RUNNER_KEYS)}")
    from stableins.procedures.plan import CHUNK_RANGE, RETRIES_RANGE

    limits: dict[str, NumberLimits] = {
        "retries": {"minimum": RETRIES_RANGE[0], "maximum": RETRIES_RANGE[1], "whole": True},
        "chunk": {"minimum": CHUNK_RANGE[0], "maximum": CHUNK_RANGE[1]},
        "angle_tolerance": {"positive": True, "maximum": 648000.0},
        "scatter_max": {"positive": True, "maximum": 1e8},
        "slope_max": {"positive": True, "maximum": 1e8},
        "max_slew": {"positive": True, "maximum": MAX_SECONDS},
    }
    values: dict[str, float] = {}
    for key, factor in _RUNNER_KEYS.items():
        if key in table:
            values[key] = toml_number(table, key, path, "runner", **limits[key]) * factor
    if "retries" in values:
        values["retries"] = int(values["retries"])
    return values


def runner_settings(table: Any, path: str) -> RunnerSettings:
    """Return the run settings of ``[runner]`` (retries, chunk)."""
    values = _runner_values(table, path)
    return RunnerSettings(int(values.get("retries", RunnerSettings.retries)), values.get("chunk", RunnerSettings.chunk))


def runner_checks(table: Any, path: str) -> RunnerChecks:
    """Return the dwell checks of ``[runner]`` (arrival, stillness, slew time), in SI."""
    values = _runner_values(table, path)
    checks: RunnerChecks = {}
    if "angle_tolerance" in values:
        checks["angle_tolerance"] = values["angle_tolerance"]
    if "scatter_max" in values:
        checks["scatter_max"] = values["scatter_max"]
    if "slope_max" in values:
        checks["slope_max"] = values["slope_max"]
    if "max_slew" in values:
        checks["max_slew"] = values["max_slew"]
    return checks


def people(entries: Any, path: str, steps: int) -> tuple[PersonAction, ...]:
    """Return the ``[[person]]`` steps, validated, in file order."""
    if not isinstance(entries, list):
        raise InputError("person steps are written [[person]]", path=path, field="person")
    return tuple(_person(raw, f"person {k}", path, steps) for k, raw in enumerate(entries, start=1))


def _person(raw: Any, where: str, path: str, steps: int) -> PersonAction:
    """Read one ``[[person]]`` table."""
    from stableins.procedures.plan import check_person_default

    _check_keys(raw, where, path)
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
    bounds = {b: toml_number(raw, b, path, where) if b in raw else None for b in ("minimum", "maximum")}
    if bounds["minimum"] is not None and bounds["maximum"] is not None and bounds["minimum"] > bounds["maximum"]:
        raise InputError(f"{where}: minimum above maximum", path=path, field="person.minimum")
    default = _person_default(raw.get("default"), where, path)
    for key in ("key", "unit"):
        if key in raw and not isinstance(raw[key], str):
            raise InputError(f"{where}: {raw[key]!r} is not a string", path=path, field=f"person.{key}")
    check_person_default(bounds["minimum"], bounds["maximum"], default, path, f"{where}: default")
    return PersonAction(
        before, raw["action"], raw["prompt"].strip(), str(raw.get("key", "")), str(raw.get("unit", "")), **bounds, default=default
    )


def _check_keys(raw: Any, where: str, path: str) -> None:
    """Check that a ``[[person]]`` entry is a table with the known keys and the required ones."""
    if not isinstance(raw, dict):
        raise InputError(f"{where}: not a table", path=path, field="person", expected="[[person]] tables")
    unknown = set(raw) - _PERSON_KEYS
    if unknown:
        raise InputError(f"{where}: unknown keys {sorted(unknown)}", path=path, field="person", expected=f"{sorted(_PERSON_KEYS)}")
    for key in ("before", "action", "prompt"):
        if key not in raw:
            raise InputError(f"{where}: missing", path=path, field=f"person.{key}")


def _person_default(default: Any, where: str, path: str) -> Any:
    """Return a person step's default: None, a text or a finite number."""
    if isinstance(default, bool) or (default is not None and not isinstance(default, str | int | float)):
        raise InputError(f"{where}: default {default!r}", path=path, field="person.default", expected="a number or text")
    if isinstance(default, float) and not math.isfinite(default):
        raise InputError(f"{where}: default {default!r}", path=path, field="person.default", expected="a finite number or text")
    return default


def model_add(table: Any, stage: str, path: str) -> tuple[str, ...]:
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


def static_record(table: Any, stage: str, path: str) -> StaticRecord | None:
    """Return the ``[record]`` table of a system-level procedure, validated (None for other stages)."""
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
        deg = toml_number(table, key, path, "record") if key in table else 0.0
        if abs(deg) > 720.0:
            raise InputError(f"{deg} deg is not a gimbal angle in degrees", path=path, field=f"record.{key}", expected="degrees")
        angles.append(math.radians(deg))
    duration = toml_number(table, "duration", path, "record", positive=True, maximum=MAX_RECORD_SECONDS)
    turns = index_turns(table.get("index", []), duration, path)
    return StaticRecord(
        command=(angles[0], angles[1], angles[2]),
        settle=toml_number(table, "settle", path, "record", minimum=0.0, maximum=MAX_SECONDS) if "settle" in table else 0.0,
        duration=duration,
        sample_rate=toml_number(table, "sample_rate", path, "record", positive=True, maximum=MAX_RATE),
        turns=turns,
        estimation=_estimation(table, path, indexed=bool(turns)),
    )


def _estimation(table: dict[str, Any], path: str, *, indexed: bool) -> SystemEstimation:
    """``[record] estimation``: what the run ends with; checked against the record's indexing."""
    if "estimation" not in table:
        return SystemEstimation.default(indexed=indexed)
    options = " or ".join(repr(e.value) for e in SystemEstimation)
    try:
        estimation = SystemEstimation(table["estimation"])
    except (InputError, NotDeterminedError):
        raise  # a described error passes through as it is (issue 29)
    except ValueError:
        raise InputError(f"{str(table['estimation'])[:40]!r}", path=path, field="record.estimation", expected=options) from None
    problem = estimation.problem(indexed=indexed)
    if problem:
        expected = "an [[record.index]] turn" if not indexed else "'drift' or 'systematic' for an indexed record"
        raise InputError(problem, path=path, field="record.estimation", expected=expected)
    return estimation


def index_turns(entries: Any, duration: float, path: str) -> tuple[PlatformTurn, ...]:
    """Return the ``[[record.index]]`` turns of the platform by torquing during the record.

    Keys: ``at`` [s], ``axis``, ``angle`` [deg], ``rate`` [deg/s]; checked in time order within the record.
    """
    if not isinstance(entries, list) or not all(isinstance(e, dict) for e in entries):
        raise InputError("[[record.index]] must be an array of tables", path=path, field="record.index", expected="at, axis, angle, rate")
    turns = []
    for k, entry in enumerate(entries):
        where = f"record.index[{k}]"
        unknown, missing = set(entry) - _INDEX_KEYS, {"at", "angle"} - set(entry)
        if unknown or missing:
            what = f"unknown keys {sorted(unknown)}" if unknown else f"missing {sorted(missing)}"
            raise InputError(what, path=path, field=where, expected=f"{sorted(_INDEX_KEYS)} (at and angle required)")
        axis = entry.get("axis", "platform")
        if axis not in {a.value for a in IndexAxis}:
            raise InputError(
                f"axis {str(axis)[:40]!r}", path=path, field=f"{where}.axis", expected=" or ".join(repr(a.value) for a in IndexAxis)
            )
        at = toml_number(entry, "at", path, where, minimum=0.0, maximum=MAX_RECORD_SECONDS)
        angle = toml_number(entry, "angle", path, where, minimum=-360.0, maximum=360.0)
        if angle == 0.0:
            raise InputError("an index of 0 deg", path=path, field=f"{where}.angle", expected="a non-zero angle in degrees, -360 to 360")
        rate = toml_number(entry, "rate", path, where, positive=True, maximum=180.0) if "rate" in entry else math.degrees(INDEX_RATE)
        turns.append(PlatformTurn(at, math.radians(angle), IndexAxis(axis), math.radians(rate)))
    try:
        check_turns(turns, duration)
    except (InputError, NotDeterminedError):
        raise  # a described error passes through as it is (issue 29)
    except ValueError as error:
        raise InputError(str(error), path=path, field="record.index", expected="turns in time order, within record.duration") from None
    return tuple(turns)
