"""Procedure definitions: load a TOML file of gimbal steps and validate it.

The format is documented at the top of ``device-coarse.toml`` and in ``docs/procedures.md``.  The
definitions shipped with stableins are package data (``stableins/procedures/definitions/``), so a
name such as ``"device-coarse"`` is found from any directory, in a checkout and in an installed
wheel alike; ``procedures/`` at the top of the repository links to them.  Angles are
written in degrees in the file and held in radians here (SI inside).  Every problem
raises :class:`stableins.errors.InputError` naming the file and the field.
"""

from __future__ import annotations

import math
import os
import tomllib
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypedDict

from stableins.conventions import ARCSEC
from stableins.documents import TOMLTable, TOMLValue
from stableins.dwell_mode import DEFAULT_DWELL_MODE, DwellMode
from stableins.errors import InputError
from stableins.estimators.layout import DwellChecks, StageLayout
from stableins.procedures import sections
from stableins.procedures.sections import (
    MAX_RATE,
    MAX_SECONDS,
    NumberLimits,
    PersonAction,
    RunnerSettings,
    StaticRecord,
    toml_number,
    toml_table,
)

#: Where the definitions shipped with stableins live: package data, found by name from any directory.
PROCEDURE_DIRECTORY = Path(__file__).resolve().parent / "definitions"

_STEP_KEYS = {"position", "platform", "inner", "middle", "settle", "dwell", "sample_rate", "expect"}
#: ``tolerances`` and ``uncertainty`` are read and validated by the report (stableins.reporting.tolerances and
#: stableins.reporting.budget, docs/reports.md).
_SECTIONS = {
    "procedure", "defaults", "acceptance", "offset_iteration", "step", "runner", "person", "record", "tolerances", "uncertainty", "model",
}  # fmt: skip
#: Stages a definition may declare.
STAGES = ("coarse", "fine", "rotating", "system")
_AXIS_WORDS = {"up", "down", "level", "+45", "-45"}
#: Largest commanded reading of a step [deg]: four turns, the cumulative middle-gimbal reading of device-rotating.
MAX_STEP_DEGREES = 1440.0


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
        """The commanded readings in degrees."""
        return tuple(math.degrees(a) for a in self.command)  # type: ignore[return-value]


@dataclass(frozen=True)
class OffsetIteration:
    """Zero-offset re-commanding loop.

    It stops below ``threshold`` [rad] (or within ``noise_sigmas`` of zero), after at most ``max_passes`` passes.
    """

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
    #: the checks of every dwell: ``[acceptance]`` and the thresholds of ``[runner]``
    checks: DwellChecks
    offset_iteration: OffsetIteration
    path: str = ""
    runner: RunnerSettings = field(default_factory=lambda: RunnerSettings())
    people: tuple[PersonAction, ...] = ()
    record: StaticRecord | None = None
    #: ``[model] add``: discovered effects (library ids) the stage estimates with the standard terms.
    model_add: tuple[str, ...] = ()
    #: the ``[tolerances]`` table as written (validated by :mod:`stableins.reporting.tolerances`), None if absent
    tolerances: TOMLValue | None = None
    #: the ``[uncertainty]`` table as written (Type B inputs, validated by :mod:`stableins.reporting.budget`), None if absent
    uncertainty: TOMLValue | None = None
    #: ``[procedure] dwell_mode``: how the platform is held during the dwells (docs/conventions.md, "The platform during a dwell")
    dwell_mode: DwellMode = DEFAULT_DWELL_MODE

    @property
    def positions(self) -> tuple[int, ...]:
        """The position numbers of the steps, in order."""
        return tuple(s.position for s in self.steps)

    def step(self, position: int) -> Step:
        """Return the step of ``position``."""
        for s in self.steps:
            if s.position == position:
                return s
        raise KeyError(position)

    @property
    def layout(self) -> StageLayout:
        """The positions, settle times, handedness and dwell checks, as the estimators take them."""
        return StageLayout(
            self.name, self.stage, self.positions, tuple(s.settle for s in self.steps), self.handedness, self.checks, self.path
        )

    def check_dwell_mode(self, metadata: Any) -> None:
        """Refuse a platform whose metadata declare another dwell mode than this procedure (before anything moves).

        Raises
        ------
        InputError
            Naming ``procedure.dwell_mode``, what the procedure declares and what the platform does.
        """
        held = getattr(metadata, "dwell_mode", None)
        if held is not None and held != self.dwell_mode:
            raise InputError(
                f"the procedure declares dwell_mode {self.dwell_mode} but the platform holds its dwells as {held} (its metadata)",
                path=self.path or None, field="procedure.dwell_mode",
                expected=f'{held} (docs/conventions.md, "The platform during a dwell")',
            )  # fmt: skip

    @property
    def duration(self) -> float:
        """Total settle + dwell time [s] (slews not included)."""
        return sum(s.settle + s.dwell for s in self.steps)


#: Largest procedure (or campaign) file read [bytes]: 10,000 steps are about 0.5 MB; parsing 1 MiB of TOML takes
#: under a second, so a refused file costs no more.
MAX_FILE_BYTES = 1 << 20
#: Most ``[[step]]`` entries a procedure may hold (the 18-position coarse stage has 18; a designed one tens).
MAX_PROCEDURE_STEPS = 10_000


def shipped_procedures() -> tuple[str, ...]:
    """Names of the definitions shipped with stableins (``"device-coarse"``, ...)."""
    return tuple(sorted(p.stem for p in PROCEDURE_DIRECTORY.glob("*.toml")))


def resolve(name_or_path: str | os.PathLike[str]) -> Path:
    """Resolve a path, or the name of a shipped definition (``"device-coarse"``).

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
    data: TOMLTable = read_toml(path, what=f"a procedure definition (a TOML file, or the name of a shipped definition: {shipped})")
    unknown = set(data) - _SECTIONS
    if unknown:
        raise InputError(f"unknown sections {sorted(unknown)}", path=spath, expected=f"{sorted(_SECTIONS)}")
    head = _head(data, spath)
    base = _timing_defaults(data, spath)
    acceptance = _acceptance(data, spath)
    offset_iteration = _offset_iteration(data, spath)
    if head.stage not in STAGES:
        raise InputError(f"unknown stage {head.stage!r}", path=spath, field="procedure.stage", expected=" or ".join(map(repr, STAGES)))
    steps = _steps(data, head.stage, base, spath)
    if head.stage == "rotating":
        _check_rotations(steps, spath)
    return ProcedureDefinition(
        name=head.name,
        stage=head.stage,
        source=head.source,
        handedness=head.handedness,
        repoint=head.repoint,
        steps=steps,
        checks=DwellChecks(**acceptance, **sections.runner_checks(data.get("runner", {}), spath)),
        offset_iteration=offset_iteration,
        path=spath,
        runner=sections.runner_settings(data.get("runner", {}), spath),
        people=sections.people(data.get("person", []), spath, len(steps)),
        record=sections.static_record(data.get("record"), head.stage, spath),
        model_add=sections.model_add(data.get("model", {}), head.stage, spath),
        tolerances=data.get("tolerances"),
        uncertainty=data.get("uncertainty"),
        dwell_mode=_dwell_mode(head.table, spath),
    )


def _check_rotations(steps: tuple[Step, ...], spath: str) -> None:
    """Refuse a rotating procedure that does not turn the platform about two of its axes (Cai's three arms undetermined)."""
    from stableins.estimators.lever.kinematics import unexcited_arms

    missing = unexcited_arms([s.command for s in steps])
    if missing:
        raise InputError(
            f"no move between the steps turns the platform so as to excite {', '.join(missing)}", path=spath, field="step",
            expected="moves about at least two platform axes (the middle gimbal and the platform axis, as device-rotating)",
        )  # fmt: skip


def _dwell_mode(head: TOMLTable, spath: str) -> DwellMode:
    """Return ``[procedure] dwell_mode`` (the default when absent)."""
    value = head.get("dwell_mode", str(DEFAULT_DWELL_MODE))
    if not isinstance(value, str) or value not in {m.value for m in DwellMode}:
        expected = " or ".join(f'"{m.value}"' for m in DwellMode) + ' (docs/conventions.md, "The platform during a dwell")'
        raise InputError(f"{str(value)[:60]!r} is not a dwell mode", path=spath, field="procedure.dwell_mode", expected=expected)
    return DwellMode(value)


@dataclass(frozen=True)
class _Head:
    """The ``[procedure]`` table, validated."""

    name: str
    stage: str
    source: str
    handedness: int
    repoint: bool
    #: the table as written (``dwell_mode`` is read from it last, after the other sections)
    table: TOMLTable


def _head(data: TOMLTable, spath: str) -> _Head:
    """Return the ``[procedure]`` table, validated."""
    head = data.get("procedure")
    if not isinstance(head, dict):
        raise InputError("missing [procedure] table", path=spath, field="procedure")
    name, stage = head.get("name"), head.get("stage")
    for key, value in (("name", name), ("stage", stage)):
        if not isinstance(value, str):
            raise InputError("missing or not a string", path=spath, field=f"procedure.{key}")
    if head.get("angle_unit", "deg") != "deg":
        raise InputError("commands must be written in degrees", path=spath, field="procedure.angle_unit", expected='"deg"')
    handedness = head.get("handedness", 1)
    if isinstance(handedness, bool) or handedness not in (1, -1):
        raise InputError("must be +1 or -1", path=spath, field="procedure.handedness")
    if "source" in head and not isinstance(head["source"], str):
        raise InputError("not a string", path=spath, field="procedure.source")
    repoint = head.get("repoint", False)
    if not isinstance(repoint, bool):
        raise InputError(f"{repoint!r} is not true or false", path=spath, field="procedure.repoint", expected="true or false")
    assert isinstance(name, str) and isinstance(stage, str)  # checked above
    return _Head(name, stage, str(head.get("source", "")), 1 if handedness == 1 else -1, repoint, head)


def _timing_defaults(data: TOMLTable, spath: str) -> dict[str, float]:
    """``[defaults]``: settle (0 when absent), dwell and sample rate for every step."""
    defaults = toml_table(data.get("defaults", {}), spath, "defaults")
    unknown = set(defaults) - set(_TIMING_LIMITS)
    if unknown:
        raise InputError(f"unknown keys {sorted(unknown)}", path=spath, field="defaults", expected=f"{sorted(_TIMING_LIMITS)}")
    base = {}
    for key, fallback in (("settle", 0.0), ("dwell", None), ("sample_rate", None)):
        if key in defaults:
            base[key] = toml_number(defaults, key, spath, "defaults", **_TIMING_LIMITS[key])
        elif fallback is not None:
            base[key] = fallback
    return base


class _Acceptance(TypedDict, total=False):
    """``[acceptance]`` in SI: the fields of :class:`DwellChecks` it may set."""

    min_samples: int
    noise_blocks: int
    saturation: float
    max_angle_span: float
    orientation_tolerance: float


def _acceptance(data: TOMLTable, spath: str) -> _Acceptance:
    """Return ``[acceptance]`` in SI: the estimators' dwell checks of :class:`DwellChecks`."""
    acc_table = toml_table(data.get("acceptance", {}), spath, "acceptance")
    acc_fields = set(_ACCEPTANCE_LIMITS)
    if set(acc_table) - acc_fields:
        raise InputError(
            f"unknown keys {sorted(set(acc_table) - acc_fields)}", path=spath, field="acceptance", expected=f"{sorted(acc_fields)}"
        )
    numbers = {k: toml_number(acc_table, k, spath, "acceptance", **_ACCEPTANCE_LIMITS[k]) for k in acc_table}  # in file order
    acceptance: _Acceptance = {}
    if "min_samples" in numbers:
        acceptance["min_samples"] = int(numbers["min_samples"])
    if "noise_blocks" in numbers:
        acceptance["noise_blocks"] = int(numbers["noise_blocks"])
    if "saturation" in numbers:
        acceptance["saturation"] = numbers["saturation"]
    if "max_angle_span" in numbers:
        acceptance["max_angle_span"] = numbers["max_angle_span"] * ARCSEC
    if "orientation_tolerance" in numbers:
        acceptance["orientation_tolerance"] = numbers["orientation_tolerance"]
    return acceptance


def _offset_iteration(data: TOMLTable, spath: str) -> OffsetIteration:
    """``[offset_iteration]``: threshold (arcsec in the file), max passes, noise sigmas."""
    it_table = toml_table(data.get("offset_iteration", {}), spath, "offset_iteration")
    it_fields = {"threshold", "max_passes", "noise_sigmas"}
    if set(it_table) - it_fields:
        raise InputError(f"unknown keys {sorted(set(it_table) - it_fields)}", path=spath, field="offset_iteration")
    it_limits: dict[str, NumberLimits] = {
        "threshold": {"minimum": 0.0, "maximum": 3600.0},
        "max_passes": {"minimum": 1.0, "maximum": 100.0, "whole": True},
        "noise_sigmas": {"minimum": 0.0, "maximum": 100.0},
    }
    numbers = {k: toml_number(it_table, k, spath, "offset_iteration", **it_limits[k]) for k in it_table}  # in file order
    default = OffsetIteration()
    return OffsetIteration(
        threshold=numbers["threshold"] * ARCSEC if "threshold" in numbers else default.threshold,
        max_passes=int(numbers["max_passes"]) if "max_passes" in numbers else default.max_passes,
        noise_sigmas=numbers.get("noise_sigmas", default.noise_sigmas),
    )


def _steps(data: TOMLTable, stage: str, base: dict[str, float], spath: str) -> tuple[Step, ...]:
    """Return the ``[[step]]`` tables, validated; positions must run 1, 2, ... in order."""
    steps_raw = data.get("step")
    if stage == "system" and steps_raw is None:
        steps_raw = []  # a static record: [record] says where and how long
    elif not isinstance(steps_raw, list) or not steps_raw:
        raise InputError("no [[step]] entries", path=spath, field="step")
    if len(steps_raw) > MAX_PROCEDURE_STEPS:
        raise InputError(f"{len(steps_raw)} [[step]] entries", path=spath, field="step", expected=f"at most {MAX_PROCEDURE_STEPS}")
    steps = [_step(raw, f"step {k}", base, spath) for k, raw in enumerate(steps_raw, start=1)]
    positions = [s.position for s in steps]
    if positions != list(range(1, len(steps) + 1)):  # linear in the number of steps
        dup = sorted(p for p, count in Counter(positions).items() if count > 1)
        first = next(k for k, p in enumerate(positions, start=1) if p != k)
        what = f"duplicated positions {dup[:10]}" if dup else f"step {first} has position {positions[first - 1]}"
        raise InputError(f"{what}: positions must run 1, 2, ... {len(steps)} in order", path=spath, field="step.position")
    return tuple(steps)


def _step(raw: Any, where: str, base: dict[str, float], spath: str) -> Step:
    """Read one ``[[step]]`` table."""
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
    angles = _step_angles(raw, where, spath)
    timing = _step_timing(raw, where, base, spath)
    expect = raw.get("expect", "")
    if expect:
        words = [w.strip().split() for w in str(expect).split(",")]
        if len(words) != 3 or any(len(w) != 2 or w[0] != a or w[1] not in _AXIS_WORDS for w, a in zip(words, "xyz")):
            raise InputError(f"{where}: cannot read {expect!r}", path=spath, field="step.expect", expected="'x <dir>, y <dir>, z <dir>'")
    return Step(position, angles, timing["settle"], timing["dwell"], timing["sample_rate"], str(expect))


def _step_angles(raw: TOMLTable, where: str, spath: str) -> tuple[float, float, float]:
    """Return the commanded readings of a ``[[step]]`` table [rad] (the file gives degrees)."""
    angles = []
    for key in ("platform", "inner", "middle"):
        deg = toml_number(raw, key, spath, where)
        if abs(deg) > MAX_STEP_DEGREES:
            raise InputError(
                f"{where}: {deg} deg is not a gimbal angle in degrees", path=spath, field=f"step.{key}",
                expected=f"degrees, at most {MAX_STEP_DEGREES:g} in magnitude (cumulative readings of a rotating path)",
            )  # fmt: skip
        angles.append(math.radians(deg))
    return angles[0], angles[1], angles[2]


def _step_timing(raw: TOMLTable, where: str, base: dict[str, float], spath: str) -> dict[str, float]:
    """Return the settle, dwell and sample rate of a ``[[step]]`` table, the procedure's defaults where it gives none."""
    timing = dict(base)
    for key in ("settle", "dwell", "sample_rate"):
        if key in raw:
            timing[key] = toml_number(raw, key, spath, where, **_TIMING_LIMITS[key])
        if key not in timing:
            raise InputError(f"{where}: no {key} and no default", path=spath, field=f"step.{key}")
    return timing


def device_layouts(coarse: str | Path = "device-coarse", fine: str | Path = "device-fine") -> dict[str, StageLayout]:
    """``{"coarse": ..., "fine": ...}``: the stage layouts of two device-level procedures (names or paths) for the estimators.

    What :func:`stableins.estimators.device.calibrate_device`, :func:`stableins.estimators.dwell.dwells_from_columns`
    and :func:`stableins.discovery.dwells.dwells_from_dataset` take; by default those of the shipped procedures.
    """
    return {"coarse": load_procedure(coarse).layout, "fine": load_procedure(fine).layout}


def read_toml(path: str | Path, *, what: str) -> dict[str, Any]:
    """Read a TOML file as a table; InputError naming the file when it is missing, a directory, too large, not UTF-8 or not TOML."""
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


#: Ranges of the timing keys of [defaults] and [[step]].
_TIMING_LIMITS: dict[str, NumberLimits] = {
    "settle": {"minimum": 0.0, "maximum": MAX_SECONDS},
    "dwell": {"positive": True, "maximum": MAX_SECONDS},
    "sample_rate": {"positive": True, "maximum": MAX_RATE},
}
#: Ranges of the [acceptance] keys (file units: samples, blocks, m/s², arcsec, m/s²).
_ACCEPTANCE_LIMITS: dict[str, NumberLimits] = {
    "min_samples": {"minimum": 2.0, "maximum": 1e8, "whole": True},
    "noise_blocks": {"minimum": 2.0, "maximum": 1000.0, "whole": True},
    "saturation": {"positive": True, "maximum": 1e4},
    "max_angle_span": {"positive": True, "maximum": 1296000.0},
    "orientation_tolerance": {"positive": True, "maximum": 100.0},
}
