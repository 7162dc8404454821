"""System-level (third-stage) calibration on a static, polar-aligned base (Wu et al. 2018 §5).

Modules: :mod:`~stableins.estimators.system.harmonics` (z observation, H, states, filters), :mod:`.loop` (damping-loop
transfer function), :mod:`.attitude` (Fourier fit of pitch and roll), :mod:`.separation`
(weighted least squares of the combined coefficients), :mod:`.stage` (the streaming stage,
:func:`~stableins.estimators.system.stage.run_system_stage`).  See docs/system-calibration.md.
"""
