"""Systematic calibration of a space-stable platform: one Kalman filter and RTS smoother over indexed orientations.

Issue 18; docs/systematic-calibration.md.  :mod:`~stableins.estimators.systematic.model` defines the error model once
(states, ``F``, ``Q``, ``H``), :mod:`~stableins.estimators.systematic.observations` streams a record into filter steps,
:mod:`~stableins.estimators.systematic.kalman` runs filterpy's filter and RTS smoother and the batch least squares,
:mod:`~stableins.estimators.systematic.passes` the outer re-linearization loop, :mod:`~stableins.estimators.systematic.rank`
the rank report, :mod:`~stableins.estimators.systematic.result` the result and the likelihood for the record.
"""

from stableins.estimators.systematic.passes import Prior, SystematicOptions
from stableins.estimators.systematic.rank import GroupRank
from stableins.estimators.systematic.record import prior_from_record, systematic_calibration, systematic_stage
from stableins.estimators.systematic.result import SystematicCalibration, SystematicDetails

__all__ = [
    "GroupRank",
    "Prior",
    "SystematicCalibration",
    "SystematicDetails",
    "SystematicOptions",
    "prior_from_record",
    "systematic_calibration",
    "systematic_stage",
]
