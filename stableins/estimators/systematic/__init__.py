"""Systematic calibration of a space-stable platform: one Kalman filter and RTS smoother over indexed orientations.

Issue 18; docs/systematic-calibration.md.  :mod:`~stableins.estimators.systematic.model` defines the error model once
(states, ``F``, ``Q``, ``H``), :mod:`~stableins.estimators.systematic.observations` streams a record into filter steps,
:mod:`~stableins.estimators.systematic.kalman` runs filterpy's filter and RTS smoother and the batch least squares,
:mod:`~stableins.estimators.systematic.stage` the outer re-linearization loop.
"""
