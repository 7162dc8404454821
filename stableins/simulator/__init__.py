"""The independent truth simulator ("the world").

It computes instrument outputs from the full nonlinear error model, exact gimbal
kinematics and time-domain INS error dynamics, and never imports from
``stableins.estimators`` or ``stableins.discovery``, nor the estimators' model
(``stableins.errormodel``, ``stableins.terms``, ``stableins.coremodel``): the accelerometer
output is its own implementation of docs/conventions.md (:mod:`~stableins.simulator.physics`),
checked against the estimators' model term by term (``tests/test_simulator_physics.py``).

Modules: :mod:`~stableins.simulator.truth` (what the world is),
:mod:`~stableins.simulator.physics` (the accelerometer output, Eqs. 5, 6, 8),
:mod:`~stableins.simulator.noise`, :mod:`~stableins.simulator.effects`,
:mod:`~stableins.simulator.device` (device-level dwells, simulated platform driver),
:mod:`~stableins.simulator.system` (system-level static records).
"""
