"""What a navigation budget reports: the quantities, their peak and final values, and one term's contribution."""

from __future__ import annotations

from dataclasses import dataclass, fields
from enum import StrEnum
from typing import TypedDict

import numpy as np
from numpy.typing import NDArray

from stableins.conventions import ARCSEC
from stableins.errormodel import TermKind


class Quantity(StrEnum):
    """A navigation error the budget reports."""

    POSITION = "position"
    POSITION_NORTH = "position_north"
    POSITION_EAST = "position_east"
    HEIGHT = "height"
    VELOCITY = "velocity"
    VELOCITY_NORTH = "velocity_north"
    VELOCITY_EAST = "velocity_east"
    VELOCITY_DOWN = "velocity_down"
    PITCH = "pitch"
    ROLL = "roll"
    HEADING = "heading"

    @property
    def unit(self) -> str:
        """Engineering unit (m, m/s, arcsec)."""
        if self in (Quantity.PITCH, Quantity.ROLL, Quantity.HEADING):
            return "arcsec"
        return "m/s" if self.value.startswith("velocity") else "m"

    @property
    def scale(self) -> float:
        """SI value of one engineering unit."""
        return ARCSEC if self.unit == "arcsec" else 1.0


#: Component channels of the response arrays (the horizontal ones are derived from them).
COMPONENTS = (
    Quantity.POSITION_NORTH,
    Quantity.POSITION_EAST,
    Quantity.HEIGHT,
    Quantity.VELOCITY_NORTH,
    Quantity.VELOCITY_EAST,
    Quantity.VELOCITY_DOWN,
    Quantity.PITCH,
    Quantity.ROLL,
    Quantity.HEADING,
)
#: Horizontal quantities and their (north, east) components.
HORIZONTAL = {
    Quantity.POSITION: (Quantity.POSITION_NORTH, Quantity.POSITION_EAST),
    Quantity.VELOCITY: (Quantity.VELOCITY_NORTH, Quantity.VELOCITY_EAST),
}


class BudgetDriftSource(StrEnum):
    """Where the budget's gyro drift σ comes from."""

    RECORD = "record"
    GIVEN = "given"
    NONE = "none"


class QuantityDocument(TypedDict):
    """One quantity of an error summary in JSON: peak and final in engineering units (null: no value), and the unit."""

    peak: float | None
    final: float | None
    unit: str


@dataclass(frozen=True)
class PeakFinal:
    """Largest magnitude over the navigation time and magnitude at its end [SI]."""

    peak: float
    final: float


@dataclass(frozen=True)
class ErrorSummary:
    """Peak and final of every :class:`Quantity` [SI: m, m/s, rad]."""

    position: PeakFinal
    position_north: PeakFinal
    position_east: PeakFinal
    height: PeakFinal
    velocity: PeakFinal
    velocity_north: PeakFinal
    velocity_east: PeakFinal
    velocity_down: PeakFinal
    pitch: PeakFinal
    roll: PeakFinal
    heading: PeakFinal

    def __getitem__(self, quantity: Quantity | str) -> PeakFinal:
        return getattr(self, Quantity(quantity).value)

    @classmethod
    def of(cls, series: NDArray[np.float64]) -> ErrorSummary:
        """Summary of magnitudes ``series`` (steps, len(Quantity)) in :class:`Quantity` order."""
        values = {q.value: PeakFinal(float(np.max(series[:, i])), float(series[-1, i])) for i, q in enumerate(Quantity)}
        return cls(**values)

    def to_dict(self) -> dict[str, QuantityDocument]:
        """``{quantity: {"peak", "final", "unit"}}`` in engineering units."""
        out: dict[str, QuantityDocument] = {}
        for f in fields(self):
            q = Quantity(f.name)
            pf = getattr(self, f.name)
            out[q.value] = {"peak": pf.peak / q.scale, "final": pf.final / q.scale, "unit": q.unit}
        return out


def magnitudes(components: NDArray[np.float64]) -> NDArray[np.float64]:
    """Magnitudes in :class:`Quantity` order from signed components (steps, 9, ...) in :data:`COMPONENTS` order."""
    index = {q: i for i, q in enumerate(COMPONENTS)}
    out = []
    for q in Quantity:
        if q in HORIZONTAL:
            north, east = HORIZONTAL[q]
            out.append(np.hypot(components[:, index[north]], components[:, index[east]]))
        else:
            out.append(np.abs(components[:, index[q]]))
    return np.stack(out, axis=1)


@dataclass(frozen=True)
class TermBudget:
    """One term's contribution: its 1σ [SI] in the record's unit, and the errors a +1σ residual causes."""

    id: str
    kind: TermKind
    sigma: float
    unit: str
    scale: float
    summary: ErrorSummary

    @property
    def sigma_engineering(self) -> float:
        """1σ in :attr:`unit`."""
        return self.sigma / self.scale


def magnitudes_rss(components: NDArray[np.float64]) -> NDArray[np.float64]:
    """RSS over the terms (last axis) of :func:`magnitudes`: (steps, len(Quantity))."""
    if components.shape[-1] == 0:
        return np.zeros((components.shape[0], len(Quantity)))
    return magnitudes(np.sqrt(np.sum(components**2, axis=-1)))


def magnitudes_covariance(unit: NDArray[np.float64], covariance: NDArray[np.float64]) -> NDArray[np.float64]:
    """σ of each quantity with the full covariance: components ``sqrt(sᵀPs)``, horizontal ``sqrt(σ_N² + σ_E²)``."""
    if unit.shape[-1] == 0:
        return np.zeros((unit.shape[0], len(Quantity)))
    variance = np.einsum("tqa,ab,tqb->tq", unit, covariance, unit)
    return magnitudes(np.sqrt(np.maximum(variance, 0.0)))
