"""The independent truth simulator ("the world").

It computes instrument outputs from the full nonlinear error model, exact gimbal
kinematics and time-domain INS error dynamics, and never imports from
``stableins.estimators`` or ``stableins.discovery``.

Modules: :mod:`~stableins.simulator.truth` (what the world is),
:mod:`~stableins.simulator.noise`, :mod:`~stableins.simulator.effects`,
:mod:`~stableins.simulator.device` (device-level dwells, simulated platform driver),
:mod:`~stableins.simulator.system` (system-level static records).
"""
