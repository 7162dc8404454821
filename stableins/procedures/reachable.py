"""What a system-level plan asks of the platform, checked before the platform moves: an index must not lock the gimbals.

A record indexed by torquing (``[[record.index]]``, :class:`stableins.turns.PlatformTurn`) holds the platform in inertial
space while the Earth turns the base under it; the gimbals follow.  An index that, with the Earth's turn, brings the
inner gimbal to ±90° (the lock of the three-gimbal chain) cannot be carried out: the platform would tumble.  The record
starts polar-aligned (``z_p`` on the Earth's axis: the INS in navigation mode, as the simulated platform records it,
docs/simulator.md), so whether it locks depends on the site's latitude and the gimbal senses, known once the platform
reports its metadata; :func:`check_reachable` runs then, before anything is commanded or written.
"""

from __future__ import annotations

import math
import os

from stableins.conventions import GimbalConfiguration, polar_alignment_readings
from stableins.errors import InputError
from stableins.platform import GimbalPlatform
from stableins.procedures.plan import Plan, StaticRecordStep
from stableins.site import SiteMetadata


def check_reachable(plan: Plan, metadata: SiteMetadata, definition_file: str | os.PathLike[str] | None) -> None:
    """Refuse a plan whose indexing brings the inner gimbal to lock during its record (:func:`inner_gimbal_lock`).

    Raises
    ------
    InputError
        Naming the definition file and the index (``record.index[k]``, the last one begun when the lock comes).
    """
    from stableins.simulator.indexing import inner_gimbal_lock

    for step in plan.steps:
        if not isinstance(step, StaticRecordStep) or not step.turns:
            continue
        configuration = GimbalConfiguration(metadata.gimbal_senses)
        platform = GimbalPlatform(configuration=configuration, base_attitude=metadata.base_attitude)
        first, middle = polar_alignment_readings(metadata.latitude, configuration)
        rate = float(plan.sample_rate or metadata.sample_rate)
        when = inner_gimbal_lock(
            platform, step.turns, step.duration, latitude=metadata.latitude, initial_readings=(first, 0.0, middle), rate=rate
        )
        if when is None:
            continue
        k = max(i for i, turn in enumerate(step.turns) if turn.start <= when) if step.turns[0].start <= when else 0
        turn = step.turns[k]
        raise InputError(
            f"the index of {math.degrees(turn.angle):+g} deg about the {turn.axis.value} gimbal axis at {turn.start:g} s brings "
            f"the inner gimbal to ±90° (gimbal lock) {when:.0f} s into the record at this site (latitude "
            f"{math.degrees(metadata.latitude):.2f}°): the platform cannot be held there",
            path=definition_file,
            field=f"record.index[{k}]",
            expected="indexes that keep the inner gimbal off ±90° for the whole record (system-indexed: 60° about the middle axis)",
        )
