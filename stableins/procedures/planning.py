"""Turn a procedure definition (``procedures/*.toml``, :mod:`stableins.procedures.definition`) into a runnable plan.

* A coarse definition that re-points (``repoint = true``, ``[offset_iteration]``) becomes one
  zero-offset iteration step: passes of all positions until the offsets converge.
* Any other definition becomes one dwell step per position, re-pointed by the current
  zero-offset estimate (from the unit's previous record) when ``repoint`` is set; a rotating
  definition's steps keep their slews (``keep_slew``).

Every dwell step carries the definition's one set of dwell checks
(:class:`~stableins.estimators.layout.DwellChecks`: ``[acceptance]`` and the thresholds of
``[runner]``): the runner checks each dwell online (reached, still, complete), the estimators
check it again when the data are estimated.
"""

from __future__ import annotations

from typing import Any, cast

from stableins.procedures.plan import DwellStep, OffsetIterationStep, PersonStep, Plan, StaticRecordStep


def plan_from_definition(definition: Any, *, retries: int | None = None, chunk: float | None = None) -> Plan:
    """Return the plan that carries out ``definition`` (a :class:`~stableins.procedures.definition.ProcedureDefinition`).

    ``[runner]`` gives the retries and journal chunk (``retries``/``chunk``
    override it); ``[[person]]`` entries are placed before the position they name.
    """
    settings = definition.runner
    checks = definition.checks
    rates = {s.sample_rate for s in definition.steps}
    sample_rate = rates.pop() if len(rates) == 1 else None
    if definition.stage == "system":
        record = definition.record
        sample_rate = record.sample_rate
        work: list = [
            StaticRecordStep(
                f"{definition.name}: static record",
                record.command,
                record.settle,
                record.duration,
                checks,
                turns=record.turns,
                estimation=record.estimation,
            )
        ]
    elif definition.stage == "coarse" and definition.repoint:
        work = [
            OffsetIterationStep(
                name=f"{definition.name}: zero-offset iteration over {len(definition.steps)} positions",
                positions=tuple(s.position for s in definition.steps),
                settles=tuple(float(s.settle) for s in definition.steps),
                dwells=tuple(float(s.dwell) for s in definition.steps),
                stage=definition.stage,
            )
        ]
    else:
        work = [
            DwellStep(
                name=f"{definition.stage} position {s.position}",
                stage=definition.stage,
                pass_number=1,
                position=s.position,
                readings=cast("tuple[float, float, float]", tuple(float(a) for a in s.command)),
                settle=float(s.settle),
                dwell=float(s.dwell),
                checks=checks,
                why=f"ideal axes: {s.expect}" if s.expect else "",
                offset_corrected=bool(definition.repoint),
                keep_slew=definition.stage == "rotating",
            )
            for s in definition.steps
        ]
    steps: list = []
    positions = [getattr(w, "position", 1) for w in work]
    for index, step in enumerate(work):
        here = positions[index] if isinstance(step, DwellStep) else 1
        if index == 0:
            steps += [_person(p) for p in definition.people if p.before <= here]
        else:
            steps += [_person(p) for p in definition.people if positions[index - 1] < p.before <= here]
        steps.append(step)
    last = positions[-1] if work and isinstance(work[-1], DwellStep) else 1
    steps += [_person(p) for p in definition.people if p.before > last]
    return Plan(
        name=definition.name,
        level="system" if definition.stage == "system" else "device",
        steps=tuple(steps),
        retries=settings.retries if retries is None else retries,
        chunk=settings.chunk if chunk is None else chunk,
        sample_rate=sample_rate,
        description=definition.source,
    )


def _person(action: Any) -> PersonStep:
    name = action.key or action.prompt
    return PersonStep(
        name=name,
        action=action.action,
        prompt=action.prompt,
        key=action.key,
        unit=action.unit,
        minimum=action.minimum,
        maximum=action.maximum,
        default=action.default,
    )
