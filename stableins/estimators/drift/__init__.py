"""Gyro drift of a space-stable platform from an indexing test (docs/drift-test.md).

:mod:`~stableins.estimators.drift.model` holds the observation equations and the estimator,
:mod:`~stableins.estimators.drift.holds` finds the holds, :mod:`~stableins.estimators.drift.accelerometer`
the accelerometer cross-check, :mod:`~stableins.estimators.drift.record` the record-level entry and the report.
"""

from stableins.estimators.drift.accelerometer import BiasCheck
from stableins.estimators.drift.holds import StillHold, find_holds, small_angle_vector
from stableins.estimators.drift.model import DriftDetails, estimate_drift
from stableins.estimators.drift.record import DRIFT_COLUMNS, drift_from_record, drift_report, drift_stage

__all__ = [
    "DRIFT_COLUMNS",
    "BiasCheck",
    "DriftDetails",
    "StillHold",
    "drift_from_record",
    "drift_stage",
    "estimate_drift",
    "find_holds",
    "drift_report",
    "small_angle_vector",
]
