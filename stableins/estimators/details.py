"""The stage-specific, typed details a :class:`~stableins.estimators.result.FitResult` carries in its ``details`` field."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
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


@dataclass(frozen=True, eq=False)
class CoarseDetails(StageDetails):
    """What the coarse (18-position) fit worked with, beyond the parameters.

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
