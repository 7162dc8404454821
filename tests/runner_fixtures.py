"""Short procedures and a subprocess entry point for the runner tests."""

from __future__ import annotations

import math
import sys
import time

from stableins.estimators.layout import DwellChecks
from stableins.procedures.plan import DwellStep, PersonStep, Plan
from tests.platform_double import PlatformDouble

POSITIONS = [
    (0.0, 0.0, 0.0),
    (0.0, math.pi / 2, 0.0),
    (math.pi / 2, math.pi / 2, 0.0),
    (0.0, 0.0, math.pi / 2),
    (math.pi, 0.0, math.pi / 2),
    (0.0, math.pi, 0.0),
]
LOOSE = DwellChecks(angle_tolerance=math.radians(0.01), scatter_max=5e-3, slope_max=2e-4, min_fraction=0.98)


#: Checks for the simulated platform's quartz-like noise (~500 µg per sample at 100 Hz).
SIM_CHECKS = DwellChecks(angle_tolerance=math.radians(0.01), scatter_max=2e-2, slope_max=2e-4, min_fraction=0.98)


#: Small moves (10°): the simulated platform slews at 10°/s, so a kill test run stays short.
SMALL_MOVES = [
    (0.0, 0.0, 0.0),
    (0.0, 0.1745, 0.0),
    (0.1745, 0.1745, 0.0),
    (0.1745, 0.1745, 0.1745),
    (0.0, 0.1745, 0.1745),
    (0.0, 0.0, 0.1745),
]


def short_plan(
    retries: int = 2, dwell: float = 2.0, chunk: float = 0.5, person: bool = True, checks: DwellChecks = LOOSE, positions=POSITIONS
) -> Plan:
    steps: list = []
    if person:
        steps.append(PersonStep("confirm mounting", "confirm", "Is the unit mounted and powered?"))
        steps.append(
            PersonStep(
                "lab temperature", "enter", "Lab temperature", key="lab_temperature", unit="degC", minimum=-20, maximum=60, default=21.5
            )
        )
    for k, readings in enumerate(positions, start=1):
        steps.append(DwellStep(f"position {k}", "coarse", 1, k, readings, settle=0.5, dwell=dwell, checks=checks, why="test position"))
    return Plan("short test procedure", "device", tuple(steps), retries=retries, chunk=chunk)


class CrashAfter(PlatformDouble):
    """The platform double that dies (``KeyboardInterrupt``) at its ``limit + 1``-th acquisition: a run to resume."""

    def __init__(self, seed, limit):
        super().__init__(seed)
        self.limit = limit

    def acquire(self, duration):
        self.limit -= 1
        if self.limit < 0:
            raise KeyboardInterrupt  # stands for the process dying here
        return super().acquire(duration)


class PacedDouble:
    """The platform double, slowed down so that a kill lands at varied points of a run."""

    def __new__(cls, seed: int, pace: float):
        double = PlatformDouble(seed=seed)
        acquire = double.acquire

        def slow(duration):
            time.sleep(pace)
            return acquire(duration)

        double.acquire = slow
        return double


def main(argv: list[str]) -> int:
    """``python -m tests.runner_fixtures start|resume RUNDIR SEED PACE``: run the short plan on the double."""
    from stableins.console import Console
    from stableins.runs import resume_run, start_run

    mode, rundir, seed, pace = argv[0], argv[1], int(argv[2]), float(argv[3])
    console = Console(yes=True, quiet=True)
    if mode == "start":
        start_run(short_plan(), rundir, driver_spec="double", seed=seed, console=console, driver=PacedDouble(seed, pace))
    else:
        resume_run(rundir, console=console, driver_factory=lambda start: PacedDouble(start["seed"], pace))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
