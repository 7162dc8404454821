r"""Type B sensitivities of the system stage: the stage re-run with each input it takes as known perturbed.

The system stage takes as known the constant gyro drift in the platform frame when it does not measure it (zero
unless given, ``SystemOptions.known_gyro_drift``; a drift measured from the gimbal readings is a parameter of the
update instead, docs/system-calibration.md §9, and has no sensitivity here) and the parameters of the INS damping loop
(``SiteMetadata.damping``: ζ, ω_s, vertical gains k1, k2, k3), through which it reads the attitude
harmonics.  An error in either moves the attitude coefficients and, through the separation, the
stage's likelihood: its information vector :math:`\eta = \Lambda\hat x + g` (at :math:`\hat x = x_0`, the
installed calibration, so only :math:`g` moves).  Each input :math:`q` is perturbed by a small step
:math:`h` and the stage's solve steps re-run (the same data, the same code path)::

    ∂η/∂q = (g(q + h) − g(q)) / h

The pass over the record (:func:`~stableins.estimators.system.stage.record_sums`) does not depend on either input, so
it is made once and every re-run starts from its sums (issue 30: the pass is most of the stage's time on a long
record); the Kalman filter's convergence curve, which does not enter the likelihood, is not re-run either.  Nor are
the steps that depend on neither input (issue 30; :class:`~stableins.estimators.system.stage.HeldSteps`, the stage's
:attr:`~stableins.estimators.system.stage.SystemCalibration.held`): the white noise, the harmonic fit, the drift step
and the polar alignment from the gimbal readings (the drift step is made again for a drift input), nor the attitude
fit's spectral diagnostic; and when the stage's thermal test removed nothing, a re-run holds that outcome (a discrete
choice, as a derivative holds it) and does not make the test's provisional noise decision.  Every step the inputs
reach is re-run: the sensitivities equal those of whole re-runs (``rerun=True``; ``tests/test_budget.py``,
``tests/test_system_thermal.py``) to the last bits, at about half their cost.

The steps are small against the inputs' uncertainty (1e-6 °/h for the drift, 1e-4 relative for the
loop), where the stage is linear: the coloured-noise model it re-fits to the residuals moves by
1e-4 of its information, and halving or doubling the step changes ∂η/∂q by less than 1 %
(``tests/test_budget.py``).  The local gravity needs no re-run: the stage compares ``|f|`` with
``g`` only through the normalization of x1, so a gravity error is the scale-factor change
``δSF_i = SF_i δg/g`` that the device stages see too (docs/reports.md, "Uncertainty budget");
the report derives it from the likelihood alone, and the test checks it against a re-run.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from stableins.errormodel import Term
from stableins.estimators.result import InputSensitivity
from stableins.site import SiteMetadata

#: Perturbation of the gyro drift [rad/s] (1e-6 °/h).
DRIFT_STEP = math.radians(1e-6) / 3600.0
#: Relative perturbation of a damping-loop parameter.
LOOP_STEP = 1e-4
#: Damping-loop parameters perturbed when the metadata state them (``omega_s`` also under its long name).
LOOP_PARAMETERS = ("zeta", "omega_s", "schuler_frequency", "k1", "k2", "k3")


def system_sensitivities(  # noqa: PLR0913 - run_system_stage's inputs, its result and its pass
    source: Any,
    metadata: SiteMetadata,
    prior: Mapping[str, float],
    prior_covariance: Mapping[tuple[str, str], float] | None,
    options: Any,
    *,
    compensation_terms: Sequence[Term] = (),
    noise_model: Any = None,
    base: Any = None,
    sums: Any = None,
    rerun: bool = False,
) -> tuple[InputSensitivity, ...]:
    """:class:`InputSensitivity` of the stage's likelihood to the gyro drift (x, y, z) and the damping-loop parameters.

    Parameters are those of :func:`stableins.estimators.system.stage.run_system_stage`; ``base`` is its
    result with the inputs as given (run here when not given); ``noise_model`` is the noise model the stage was
    given (docs/system-calibration.md §1a), the same in every re-run; ``sums`` is the stage's pass over ``source``
    (:func:`~stableins.estimators.system.stage.record_sums`, made here when not given).  Each input costs one more
    run of the stage's solve steps on those sums, less the steps it does not reach (module docstring); ``rerun`` re-runs
    every step (the reference the tests compare with).
    """
    from stableins.estimators.system.stage import record_sums, run_system_stage

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        if sums is None:
            sums = record_sums(source, metadata, prior, options, compensation_terms=compensation_terms)

    def run(opts: Any, meta: SiteMetadata, *, curve: bool = False, held: Any = None) -> Any:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return run_system_stage(
                source,
                meta,
                prior,
                prior_covariance,
                opts if curve else replace(opts, run_filter=False),
                compensation_terms=compensation_terms,
                noise_model=noise_model,
                sums=sums,
                held=held,
            )

    base = base if base is not None else run(options, metadata, curve=True)
    likelihood = base.result.likelihood
    if likelihood is None:
        return ()
    held = None if rerun else (base.held if base.held is not None else run(options, metadata).held)

    def gradient(outcome: Any) -> np.ndarray:
        other = outcome.result.likelihood
        if other is None or other.ids != likelihood.ids or not np.array_equal(other.point, likelihood.point):
            raise RuntimeError("the perturbed system stage changed its parameters or linearization point")
        return np.asarray(other.gradient - likelihood.gradient, dtype=float)

    out = []
    drift = np.zeros(3) if options.known_gyro_drift is None else np.asarray(options.known_gyro_drift, dtype=float)
    inputs = perturbed_inputs(base, metadata)
    for axis, name in enumerate("xyz"):
        if f"gyro_drift.{name}" not in inputs:
            continue
        moved = drift.copy()
        moved[axis] += DRIFT_STEP
        outcome = run(replace(options, known_gyro_drift=tuple(float(x) for x in moved)), metadata, held=held and replace(held, drift=None))
        out.append(InputSensitivity(f"gyro_drift.{name}", "rad/s", likelihood.ids, float(drift[axis]), gradient(outcome) / DRIFT_STEP,
                                    step=DRIFT_STEP))  # fmt: skip
    damping = dict(metadata.damping or {})
    for key in LOOP_PARAMETERS:
        value = damping.get(key)
        if f"damping_loop.{key}" not in inputs or not isinstance(value, int | float):
            continue
        step = LOOP_STEP * abs(float(value))
        outcome = run(options, replace(metadata, damping={**damping, key: float(value) + step}), held=held)
        out.append(
            InputSensitivity(
                f"damping_loop.{key}", _LOOP_UNITS.get(key, "SI"), likelihood.ids, float(value), gradient(outcome) / step, step=step
            )
        )
    return tuple(out)


def perturbed_inputs(base: Any, metadata: SiteMetadata) -> tuple[str, ...]:
    """Return the inputs :func:`system_sensitivities` perturbs, one re-run of the stage each (a console shows their count).

    ``gyro_drift.x/y/z`` unless the record measured the drift (the gimbal readings: it is then a parameter of the
    update, not an input taken as known), then ``damping_loop.KEY`` for each parameter of :data:`LOOP_PARAMETERS` the
    metadata state as a finite, non-zero number.  None when the stage's result has no likelihood.
    """
    if base.result.likelihood is None:
        return ()
    measured = getattr(base, "drift", None) is not None and base.drift.in_likelihood
    drift = () if measured else tuple(f"gyro_drift.{axis}" for axis in "xyz")
    damping = dict(metadata.damping or {})
    loop = tuple(
        f"damping_loop.{key}"
        for key in LOOP_PARAMETERS
        if isinstance(damping.get(key), int | float) and math.isfinite(damping[key]) and damping[key] != 0.0
    )
    return drift + loop


def with_sensitivities(
    outcome: Any,
    source: Any,
    prior: Mapping[str, float],
    prior_covariance: Mapping[tuple[str, str], float] | None,
    options: Any,
    *,
    compensation_terms: Sequence[Term] = (),
    noise_model: Any = None,
    sums: Any = None,
) -> Any:
    """Return the stage's outcome (``SystemCalibration``) with :func:`system_sensitivities` on its result, for the record.

    ``sums``: the stage's pass over ``source`` that gave ``outcome`` (made again here when not given).
    """
    found = system_sensitivities(
        source,
        source.metadata,
        prior,
        prior_covariance,
        options,
        compensation_terms=compensation_terms,
        noise_model=noise_model,
        base=outcome,
        sums=sums,
    )
    return replace(outcome, result=replace(outcome.result, sensitivities=found))


_LOOP_UNITS = {"zeta": "1", "omega_s": "rad/s", "schuler_frequency": "rad/s", "k1": "1/s", "k2": "1/s^2", "k3": "1/s^3"}
