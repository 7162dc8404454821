"""Turn a procedure definition (``procedures/*.toml``, :mod:`stableins.procedures.definition`) into a runnable plan.

* A coarse definition that re-points (``repoint = true``, ``[offset_iteration]``) becomes one
  zero-offset iteration step: passes of all positions until the offsets converge.
* Any other definition becomes one dwell step per position, re-pointed by the current
  zero-offset estimate (from the unit's previous record) when ``repoint`` is set.

The runner's online checks of each dwell (reached, still) use the thresholds of
:class:`~stableins.procedures.plan.Checks`; the estimators' own dwell checks (the
definition's ``[acceptance]`` table) still apply when the data are estimated.
"""

from __future__ import annotations

import math
from typing import Any

from stableins.procedures.plan import Checks, DwellStep, OffsetIterationStep, Plan

#: Online checks for device-level dwells: 20″ of pointing, 5 mg of scatter (vibration), 20 µg/s of creep.
DEVICE_CHECKS = Checks(angle_tolerance=math.radians(20.0 / 3600.0), scatter_max=5e-3 * 9.80665, slope_max=20e-6 * 9.80665)


def plan_from_definition(definition: Any, *, retries: int = 2, chunk: float = 10.0, checks: Checks = DEVICE_CHECKS) -> Plan:
    """The plan that carries out ``definition`` (a :class:`~stableins.procedures.definition.ProcedureDefinition`)."""
    rates = {s.sample_rate for s in definition.steps}
    sample_rate = rates.pop() if len(rates) == 1 else None
    if definition.stage == "coarse" and definition.repoint:
        steps: tuple = (
            OffsetIterationStep(
                name=f"{definition.name}: zero-offset iteration over {len(definition.steps)} positions",
                positions=tuple(s.position for s in definition.steps),
                settles=tuple(float(s.settle) for s in definition.steps),
                stage=definition.stage,
            ),
        )
    else:
        steps = tuple(
            DwellStep(
                name=f"{definition.stage} position {s.position}",
                stage=definition.stage,
                pass_number=1,
                position=s.position,
                readings=tuple(float(a) for a in s.command),
                settle=float(s.settle),
                dwell=float(s.dwell),
                checks=checks,
                why=f"ideal axes: {s.expect}" if s.expect else "",
                offset_corrected=bool(definition.repoint),
            )
            for s in definition.steps
        )
    return Plan(
        name=definition.name,
        level="device",
        steps=steps,
        retries=retries,
        chunk=chunk,
        sample_rate=sample_rate,
        description=definition.source,
    )
