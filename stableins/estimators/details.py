"""The stage-specific, typed details a :class:`~stableins.estimators.result.FitResult` carries in its ``details`` field."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray


class UsedDwell(NamedTuple):
    """One dwell a device fit used: its sequence (``"coarse"`` or ``"fine"``), pass and position."""

    stage: str
    pass_number: int
    position: int


@dataclass(frozen=True)
class StageDetails:
    """Base of the stage-specific, typed details a :class:`FitResult` carries in :attr:`FitResult.details`."""


@dataclass(frozen=True, eq=False, kw_only=True)
class DeviceDetails(StageDetails):
    """What a device-level fit (coarse, fine, joint, poses) did with its dwells, and what it fixed.

    Attributes
    ----------
    positions_used : tuple of UsedDwell
        The dwells the fit used (sequence, pass, position).
    left_out : mapping of int to str
        Positions left out, with the reason.
    gauge_values : mapping of str to float
        Parameters fixed by the gauge, with the value they were fixed at [SI].
    held : mapping of str to float
        Parameters the data do not determine, held at their starting value [SI].
    passes : tuple of int
        Joint device fit: the coarse passes it combined.
    """

    positions_used: tuple[UsedDwell, ...] = ()
    left_out: Mapping[int, str] = field(default_factory=dict)
    gauge_values: Mapping[str, float] = field(default_factory=dict)
    held: Mapping[str, float] = field(default_factory=dict)
    passes: tuple[int, ...] = ()

    def __post_init__(self) -> None:
        for name in ("left_out", "gauge_values", "held"):
            object.__setattr__(self, name, dict(getattr(self, name)))
        object.__setattr__(self, "positions_used", tuple(UsedDwell(*u) for u in self.positions_used))

    def positions(self, stage: str | None = None) -> frozenset[int]:
        """Positions of the dwells the fit used (of one ``stage``, ``"coarse"`` or ``"fine"``, when given)."""
        return frozenset(u.position for u in self.positions_used if stage is None or u.stage == stage)


@dataclass(frozen=True, eq=False, kw_only=True)
class CoarseDetails(DeviceDetails):
    """What the coarse (18-position) fit worked with, beyond the parameters and the dwells (:class:`DeviceDetails`).

    Attributes
    ----------
    gauge_coefficients : mapping
        Coefficients of the gauge the fit applied (:class:`stableins.estimators.design.Gauge`).
    base_attitude : tuple of float
        Base attitude (roll, pitch, yaw) [rad] of the site.
    gimbal_senses : tuple of int
        Rotation senses ``s1..s4`` of the gimbal configuration.
    weak : tuple of str
        Parameters whose 1σ exceeds their typical magnitude.
    angles : mapping of int to list of float
        The measured gimbal angles [rad] of each position used.
    """

    gauge_coefficients: Any
    base_attitude: tuple[float, ...]
    gimbal_senses: tuple[int, ...]
    weak: tuple[str, ...]
    angles: Mapping[int, list[float]]


@dataclass(frozen=True, eq=False)
class SystemDetails(StageDetails):
    """What the system stage's separation worked with, beyond the parameters.

    Attributes
    ----------
    nuisance : ndarray
        Values of the nuisance parameters (pitch and roll offsets) of the separation.
    determination : mapping of str to Determination or None
        How the stage's data saw each parameter (:class:`stableins.status.Determination`).
    k2_data_only : tuple of (ndarray, ndarray) or None
        Data-only estimate of ``K2_*`` and its covariance, when the stage estimated them.
    temperature : mapping or None
        Instrument temperature summary of the record (mean, minimum, maximum), filled by a run.
    """

    nuisance: NDArray[np.float64]
    determination: Mapping[str, Any]
    k2_data_only: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None
    temperature: Mapping[str, Any] | None = None


@dataclass(frozen=True, eq=False)
class CombinedDetails(StageDetails):
    """What the system stage's combined-coefficient fit worked with.

    Attributes
    ----------
    observed_attitude : ndarray
        Pitch/roll Fourier coefficients observed in the record [rad].
    observed_attitude_covariance : ndarray
        Their covariance [rad²].
    transform : ndarray
        Linear map from the separated parameters to the combined coefficients.
    """

    observed_attitude: NDArray[np.float64]
    observed_attitude_covariance: NDArray[np.float64]
    transform: NDArray[np.float64]
