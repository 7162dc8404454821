"""Lever arms and time asynchrony from the slews of a rotating record (docs/device-calibration.md §9).

:mod:`~stableins.estimators.lever.kinematics` finds the slews and the platform's motion from the readings,
:mod:`~stableins.estimators.lever.model` holds the observation equation and the estimator,
:mod:`~stableins.estimators.lever.record` the record-level entry, the report and the stage a run ends with.
"""

from stableins.estimators.lever.model import Flag, LeverDetails, LeverOptions, LeverSet, estimate_lever
from stableins.estimators.lever.record import lever_from_dataset, lever_report, lever_stage, rotating_columns

__all__ = [
    "Flag",
    "LeverDetails",
    "LeverOptions",
    "LeverSet",
    "estimate_lever",
    "lever_from_dataset",
    "lever_stage",
    "lever_report",
    "rotating_columns",
]
