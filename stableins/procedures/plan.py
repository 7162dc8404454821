"""Execution plan of a procedure: the steps the runner carries out, in SI, JSON round-trippable.

The plan is what the runner executes and what the journal's start record stores, so that a
resumed run carries out exactly the procedure it started with even if the TOML file has been
edited since.  Procedure files (``procedures/*.toml``) are read by
:mod:`stableins.procedures.definition` and turned into a plan.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any

from stableins.data.errors import InputError


@dataclass(frozen=True)
class Checks:
    """Acceptance checks of a dwell (SI).

    Attributes
    ----------
    angle_tolerance : float
        Largest |mean measured reading − commanded reading| of any gimbal [rad] ("reached").
    scatter_max : float
        Largest standard deviation of any accelerometer axis about its straight-line fit [m/s²] ("still").
    slope_max : float
        Largest |slope| of that fit on any axis [m/s² per s] ("still": no drift, no creep).
    min_fraction : float
        Smallest fraction of the expected number of samples (``dwell × rate``) accepted (gaps).
    max_slew : float
        Longest wait for the platform to arrive after a command [s]; the settle time starts on arrival.
    """

    angle_tolerance: float = math.radians(0.01)
    scatter_max: float = 1e-3
    slope_max: float = 1e-5
    min_fraction: float = 0.98
    max_slew: float = 120.0


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
    checks: Checks = field(default_factory=Checks)
    why: str = ""
    offset_corrected: bool = False
    kind: str = "dwell"


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

    The iteration (:func:`stableins.estimators.offset_iteration.iterate_offsets`) runs passes of
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


@dataclass(frozen=True)
class StaticRecordStep:
    """System-level static record: hold ``readings`` [rad], settle [s], record ``duration`` [s] with the INS outputs."""

    name: str
    readings: tuple[float, float, float]
    settle: float
    duration: float
    checks: Checks = field(default_factory=Checks)
    why: str = "the platform stays fixed in inertial space while the INS error dynamics are recorded"
    kind: str = "static_record"


Step = DwellStep | PersonStep | OffsetIterationStep | StaticRecordStep
_STEP_TYPES: dict[str, type] = {
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
    steps: tuple[Step, ...]
    retries: int = 2
    chunk: float = 10.0
    sample_rate: float | None = None
    description: str = ""

    def __post_init__(self) -> None:
        if self.retries < 0:
            raise InputError(f"retries = {self.retries}", field="retries", expected="0 or more")
        if not self.chunk > 0:
            raise InputError(f"chunk = {self.chunk}", field="chunk", expected="a positive duration [s]")
        for step in self.steps:
            if isinstance(step, DwellStep) and not (step.dwell > 0 and step.settle >= 0):
                raise InputError(f"step {step.name!r}: dwell {step.dwell} s, settle {step.settle} s", expected="dwell > 0, settle >= 0")
            if isinstance(step, PersonStep) and step.action not in ("confirm", "enter"):
                raise InputError(f"step {step.name!r}: action {step.action!r}", field="action", expected="'confirm' or 'enter'")

    @property
    def dwell_steps(self) -> tuple[DwellStep, ...]:
        return tuple(s for s in self.steps if isinstance(s, DwellStep))

    def to_dict(self) -> dict[str, Any]:
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
    def from_dict(cls, d: dict[str, Any]) -> Plan:
        steps: list[Step] = []
        for s in d["steps"]:
            s = dict(s)
            kind = s["kind"]
            if kind in ("dwell", "static_record"):
                s["readings"] = tuple(s["readings"])
                s["checks"] = Checks(**s["checks"])
            if kind == "offset_iteration":
                s["positions"] = tuple(s["positions"])
                s["settles"] = tuple(s["settles"])
                s["dwells"] = tuple(s.get("dwells", ()))
            steps.append(_STEP_TYPES[kind](**s))
        return cls(
            name=d["name"],
            level=d["level"],
            steps=tuple(steps),
            retries=int(d["retries"]),
            chunk=float(d["chunk"]),
            sample_rate=d.get("sample_rate"),
            description=d.get("description", ""),
        )
