"""Write a designed stage (:mod:`stableins.estimators.experiment`) as a procedure file that ``stableins run`` executes.

The designed file is the template procedure (every section it has: acceptance, offset iteration, runner, person
steps, tolerances, uncertainty, model) with the designed ``[[step]]`` list: each position with its commanded
readings and its own ``dwell``, ``settle`` and ``sample_rate``.  It is written atomically and loaded back with
:func:`stableins.procedures.definition.load_procedure` before it is renamed into place, so a file that the loader
would refuse is never left behind.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from stableins.data.atomic import atomic_path
from stableins.errors import InputError
from stableins.estimators.experiment import DevicePlan, PlannedStage
from stableins.procedures.definition import ProcedureDefinition, load_procedure, read_toml


def _value(v: Any) -> str:
    """One TOML value (strings, booleans, numbers, lists of them)."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int | float):
        return repr(v) if isinstance(v, int) or math.isfinite(v) else "nan"
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, list):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {v!r} as TOML")


def _key(k: str) -> str:
    return k if k.replace("_", "").replace("-", "").isalnum() else _value(k)


def _table(name: str, data: dict[str, Any]) -> list[str]:
    """``[name]`` with its scalar keys, then its sub-tables and arrays of tables."""
    lines = [f"[{name}]"] + [f"{_key(k)} = {_value(v)}" for k, v in data.items() if not isinstance(v, dict) and _plain(v)]
    for k, v in data.items():
        if isinstance(v, dict):
            lines += ["", *_table(f"{name}.{_key(k)}", v)]
        elif isinstance(v, list) and not _plain(v):
            for item in v:
                lines += ["", f"[[{name}.{_key(k)}]]"] + [f"{_key(a)} = {_value(b)}" for a, b in item.items()]
    return lines


def _plain(v: Any) -> bool:
    return not isinstance(v, list) or not any(isinstance(x, dict) for x in v)


def procedure_text(template: ProcedureDefinition, stage: PlannedStage, *, name: str, source: str) -> str:
    """TOML of ``template`` with the designed positions and timing of ``stage`` (module docstring)."""
    data = read_toml(template.path, what="a procedure definition")
    data["procedure"] = {**data["procedure"], "name": name, "source": source}
    data["defaults"] = {"settle": float(stage.settle[0]), "dwell": float(stage.dwell[0]), "sample_rate": float(stage.sample_rate)}
    data.pop("step", None)
    lines = [f"# {name}: designed by `stableins design` from {template.name} ({source}).", ""]
    for section, content in data.items():
        if isinstance(content, list):
            for item in content:
                lines += [f"[[{section}]]", *_table("x", item)[1:], ""]
        else:
            lines += [*_table(section, content), ""]
    for k, (command, dwell, settle) in enumerate(zip(stage.commands, stage.dwell, stage.settle), start=1):
        platform, inner, middle = (round(math.degrees(a), 9) for a in command)
        lines += [
            "[[step]]",
            f"position = {k}",
            f"platform = {platform!r}",
            f"inner = {inner!r}",
            f"middle = {middle!r}",
            f"settle = {round(float(settle), 3)!r}",
            f"dwell = {round(float(dwell), 1)!r}",
            f"sample_rate = {float(stage.sample_rate)!r}",
            "",
        ]
    return "\n".join(lines)


def write_procedure(path: str | Path, template: ProcedureDefinition, stage: PlannedStage, *, name: str, source: str) -> ProcedureDefinition:
    """Write the designed ``stage`` to ``path`` (atomically, validated by the loader first) and return it as loaded."""
    if template.stage != stage.stage:
        raise InputError(f"the template is a {template.stage} procedure, the designed stage is {stage.stage}", path=template.path)
    text = procedure_text(template, stage, name=name, source=source)
    target = Path(path)
    with atomic_path(target) as tmp:
        Path(tmp).write_text(text, encoding="utf-8")
        load_procedure(Path(tmp))  # the loader's verdict before the file is renamed into place
    return load_procedure(target)


def planned_stage(definition: ProcedureDefinition, *, passes: int = 1, sample_rate: float | None = None) -> PlannedStage:
    """Return the plan of a procedure definition: its positions, dwell and settle times (``passes`` runs of a coarse stage)."""
    steps = definition.steps
    return PlannedStage(
        definition.stage,
        np.array([s.command for s in steps]),
        np.array([s.dwell for s in steps]),
        np.array([s.settle for s in steps]),
        sample_rate or steps[0].sample_rate,
        passes,
    )


def device_plan(
    coarse: ProcedureDefinition, fine: ProcedureDefinition | None = None, *, passes: int = 2, sample_rate: float | None = None
) -> DevicePlan:
    """Return the plan of a coarse procedure run ``passes`` times and an optional fine procedure."""
    return DevicePlan(
        planned_stage(coarse, passes=passes, sample_rate=sample_rate),
        None if fine is None else planned_stage(fine, sample_rate=sample_rate),
    )
