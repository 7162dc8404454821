"""The campaign file: seeds × procedures × noise models × hidden effects, validated before anything runs.

Format (TOML, docs/campaigns.md)::

    [campaign]
    name = "paper"
    first_seed = 1          # devices: seeds first_seed, first_seed + 1, ...
    devices = 100
    diagnose = true         # run model discovery on every task (detection and false-alarm rates)

    [[procedure]]
    name = "paper"
    coarse = "device-coarse"    # a shipped name or a file, like `stableins run`
    fine = "device-fine"        # optional
    passes = 2                  # coarse passes (one session, as the zero-offset iteration runs them)
    sample_rate = 10.0          # optional: simulate every dwell at this rate (the dwell mean's white noise is N/√T)

    [[noise]]
    name = "quartz"
    preset = "quartz"           # the simulator's NoiseSettings preset: quartz, white (quartz without slow noise)
    # world = "lab"             # or a named world (stableins simulate --list-worlds): its noise, effects, temperature
    calibrate = "datasheet"     # the noise model the calibration is given: datasheet (the preset's N, B, K, Q) or dwells

    [[hidden]]
    name = "none"               # effects = {} : the false-alarm rate

    [[hidden]]
    name = "Kcc_xxy"
    effects = { Kcc_xxy = 60.0 }  # engineering unit of the library term
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
from collections.abc import Mapping
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path
from typing import Any

from stableins.errors import InputError
from stableins.identifiers import FILE_STEM_RULE, SEED_RANGE, is_file_stem
from stableins.procedures.definition import ProcedureDefinition, load_procedure, read_toml
from stableins.simulator.noise import NoiseSettings

#: Largest campaign accepted (tasks), so that a typo cannot queue a billion simulations.
MAX_TASKS = 1_000_000


class CalibrationNoise(StrEnum):
    """Which noise model the calibration of a task is given."""

    DATASHEET = "datasheet"  #: the simulated instrument's N, B, K, Q (a datasheet that is right)
    DWELLS = "dwells"  #: none: the white noise and the slow-noise decision from the dwells (stableins calibrate device)


def noise_presets() -> dict[str, NoiseSettings]:
    """Return the simulator noise presets a campaign can name."""
    quartz = NoiseSettings.quartz()
    return {"quartz": quartz, "white": dataclasses.replace(quartz, bias_instability=0.0, acceleration_random_walk=0.0)}


@dataclass(frozen=True)
class ProcedureSpec:
    """One procedure of a campaign: the coarse (and fine) definitions, the passes, an optional simulation rate."""

    name: str
    coarse: ProcedureDefinition
    fine: ProcedureDefinition | None
    passes: int
    sample_rate: float | None = None


@dataclass(frozen=True)
class NoiseSpec:
    """One noise model of a campaign: the simulator's noise and what the calibration is told."""

    name: str
    settings: NoiseSettings
    calibrate: CalibrationNoise
    world: str = "default"  #: a named world of :mod:`stableins.simulator.worlds` (its noise is ``settings``)


@dataclass(frozen=True)
class HiddenSpec:
    """Effects injected into the simulated instrument (library ids, SI values) that the calibration model lacks."""

    name: str
    effects: Mapping[str, float]


@dataclass(frozen=True)
class Task:
    """One simulated device through one procedure under one noise model with one hidden effect set."""

    seed: int
    procedure: str
    noise: str
    hidden: str

    @property
    def key(self) -> str:
        """The task's identity as a file-name-safe string (its results file, its random streams)."""
        return f"{self.procedure}__{self.noise}__{self.hidden}__{self.seed}"

    @property
    def stream_seed(self) -> int:
        """Seed of the task's noise streams, from its identity only (not from its place in the queue)."""
        return int.from_bytes(hashlib.sha256(self.key.encode()).digest()[:4], "little")


@dataclass(frozen=True)
class CampaignConfig:
    """A validated campaign file."""

    name: str
    first_seed: int
    devices: int
    diagnose: bool
    procedures: tuple[ProcedureSpec, ...]
    noises: tuple[NoiseSpec, ...]
    hidden: tuple[HiddenSpec, ...]
    path: str = ""

    def tasks(self) -> tuple[Task, ...]:
        """Every task, in a fixed order (procedures, noise models, hidden effects, seeds)."""
        return tuple(
            Task(seed, p.name, n.name, h.name)
            for p in self.procedures
            for n in self.noises
            for h in self.hidden
            for seed in range(self.first_seed, self.first_seed + self.devices)
        )

    def procedure(self, name: str) -> ProcedureSpec:
        """Return the procedure named ``name``."""
        return next(p for p in self.procedures if p.name == name)

    def noise(self, name: str) -> NoiseSpec:
        """Return the noise model named ``name``."""
        return next(n for n in self.noises if n.name == name)

    def hidden_effects(self, name: str) -> HiddenSpec:
        """Return the hidden-effect set named ``name``."""
        return next(h for h in self.hidden if h.name == name)


def _integer(table: Mapping[str, Any], key: str, where: str, path: str, *, minimum: int, default: int | None = None) -> int:
    value = table.get(key, default)
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise InputError(
            f"{value!r} is not a whole number ≥ {minimum}", path=path, field=f"{where}.{key}", expected=f"an integer ≥ {minimum}"
        )
    return value


def _name(table: Mapping[str, Any], where: str, path: str, seen: set[str]) -> str:
    value = table.get("name")
    if not is_file_stem(value):
        raise InputError(f"{value!r} is not a name", path=path, field=f"{where}.name", expected=FILE_STEM_RULE)
    if value in seen:
        raise InputError(f"the name {value!r} is used twice", path=path, field=f"{where}.name")
    seen.add(value)
    return value


def _keys(table: Any, allowed: set[str], where: str, path: str) -> Mapping[str, Any]:
    if not isinstance(table, dict):
        raise InputError("must be a table", path=path, field=where)
    unknown = set(table) - allowed
    if unknown:
        raise InputError(f"unknown keys {sorted(unknown)}", path=path, field=where, expected=f"{sorted(allowed)}")
    return table


def _procedure(raw: Any, where: str, path: str, seen: set[str]) -> ProcedureSpec:
    table = _keys(raw, {"name", "coarse", "fine", "passes", "sample_rate"}, where, path)
    name = _name(table, where, path, seen)
    base = Path(path).parent
    loaded = {}
    for stage in ("coarse", "fine"):
        ref = table.get(stage)
        if ref is None:
            continue
        if not isinstance(ref, str):
            raise InputError(f"{ref!r} is not a procedure", path=path, field=f"{where}.{stage}", expected="a shipped name or a file")
        candidate = base / ref
        loaded[stage] = load_procedure(candidate if candidate.suffix == ".toml" and candidate.exists() else ref)
        if loaded[stage].stage != stage:
            raise InputError(
                f"{ref} is a {loaded[stage].stage} procedure", path=path, field=f"{where}.{stage}", expected=f"a {stage} procedure"
            )
    if "coarse" not in loaded:
        raise InputError("a procedure needs its coarse stage", path=path, field=f"{where}.coarse")
    rate = table.get("sample_rate")
    if rate is not None and not (isinstance(rate, int | float) and not isinstance(rate, bool) and math.isfinite(rate) and 0 < rate <= 1e4):
        raise InputError(f"{rate!r} is not a sample rate", path=path, field=f"{where}.sample_rate", expected="Hz in (0, 1e4]")
    passes = _integer(table, "passes", where, path, minimum=1, default=2)
    return ProcedureSpec(name, loaded["coarse"], loaded.get("fine"), passes, None if rate is None else float(rate))


def _noise(raw: Any, where: str, path: str, seen: set[str]) -> NoiseSpec:
    from stableins.simulator.worlds import world

    table = _keys(raw, {"name", "preset", "calibrate", "world"}, where, path)
    name = _name(table, where, path, seen)
    presets = noise_presets()
    preset = table.get("preset", "quartz")
    if preset not in presets:
        raise InputError(f"unknown preset {preset!r}", path=path, field=f"{where}.preset", expected=" or ".join(presets))
    calibrate = table.get("calibrate", CalibrationNoise.DATASHEET.value)
    if calibrate not in {c.value for c in CalibrationNoise}:
        raise InputError(f"{calibrate!r}", path=path, field=f"{where}.calibrate", expected=" or ".join(c.value for c in CalibrationNoise))
    named = world(str(table.get("world", "default")), source=path, field=f"{where}.world")
    if named.noise is not None and "preset" in table:
        raise InputError(
            f"world {named.name!r} has its own noise", path=path, field=f"{where}.preset", expected="a preset or a world, not both"
        )
    settings = presets[preset] if named.noise is None else named.noise
    return NoiseSpec(name, settings, CalibrationNoise(calibrate), named.name)


def _hidden(raw: Any, where: str, path: str, seen: set[str]) -> HiddenSpec:
    from stableins.discovery.library import LIBRARY
    from stableins.simulator.effects import validate_effects

    table = _keys(raw, {"name", "effects"}, where, path)
    name = _name(table, where, path, seen)
    effects = _keys(table.get("effects", {}), set(LIBRARY.ids), f"{where}.effects", path)
    values = {}
    for effect, value in effects.items():
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
            raise InputError(f"{value!r} is not a number", path=path, field=f"{where}.effects.{effect}", expected=LIBRARY[effect].term.unit)
        values[effect] = float(LIBRARY[effect].term.from_engineering(value))
        try:  # the simulator's own bounds, before any task runs
            validate_effects({effect: values[effect]}, source=path)
        except InputError as error:
            raise InputError(error.message, path=path, field=f"{where}.effects.{effect}", expected=error.expected) from None
    return HiddenSpec(name, values)


def _entries(data: Mapping[str, Any], key: str, path: str) -> list[Any]:
    entries = data.get(key)
    if not isinstance(entries, list) or not entries:
        raise InputError(f"at least one [[{key}]] table is needed", path=path, field=key)
    return entries


def load_campaign(path: str | Path) -> CampaignConfig:
    """Read and validate a campaign file (module docstring); :class:`InputError` naming the file and the field."""
    spath = str(path)
    data = read_toml(path, what="a campaign file (TOML, docs/campaigns.md)")
    _keys(data, {"campaign", "procedure", "noise", "hidden"}, "campaign file", spath)
    head = _keys(data.get("campaign", {}), {"name", "first_seed", "devices", "diagnose"}, "campaign", spath)
    name = _name({"name": head.get("name", Path(spath).stem)}, "campaign", spath, set())
    first_seed = _integer(head, "first_seed", "campaign", spath, minimum=0, default=1)
    devices = _integer(head, "devices", "campaign", spath, minimum=1)
    if first_seed + devices - 1 > SEED_RANGE[1]:
        raise InputError(
            f"seeds {first_seed} to {first_seed + devices - 1}",
            path=spath,
            field="campaign.first_seed",
            expected=f"first_seed + devices - 1 <= {SEED_RANGE[1]} (the largest seed)",
        )
    diagnose = head.get("diagnose", False)
    if not isinstance(diagnose, bool):
        raise InputError(f"{diagnose!r}", path=spath, field="campaign.diagnose", expected="true or false")
    seen: set[str] = set()
    procedures = tuple(_procedure(r, f"procedure[{k}]", spath, seen) for k, r in enumerate(_entries(data, "procedure", spath)))
    seen = set()
    noises = tuple(_noise(r, f"noise[{k}]", spath, seen) for k, r in enumerate(_entries(data, "noise", spath)))
    seen = set()
    hidden = tuple(_hidden(r, f"hidden[{k}]", spath, seen) for k, r in enumerate(data.get("hidden") or [{"name": "none"}]))
    total = devices * len(procedures) * len(noises) * len(hidden)
    if total > MAX_TASKS:
        raise InputError(f"{total} tasks", path=spath, field="campaign.devices", expected=f"at most {MAX_TASKS} tasks")
    return CampaignConfig(name, first_seed, devices, diagnose, procedures, noises, hidden, spath)
