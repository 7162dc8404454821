"""Options of the system stage: the gyro-drift choice and the validation of :class:`.stage.SystemOptions`."""

from __future__ import annotations

import math
from enum import StrEnum
from typing import TYPE_CHECKING

from stableins.errors import InputError

if TYPE_CHECKING:  # pragma: no cover
    from stableins.estimators.system.stage import SystemOptions


class GyroDrift(StrEnum):
    """What the system stage does about a constant gyro drift (:attr:`SystemOptions.gyro_drift`)."""

    #: Leave it out of the attitude fit (a known drift, :attr:`SystemOptions.known_gyro_drift`, is still removed).
    IGNORE = "ignore"
    #: Fit its response as a nuisance (σ of the fundamentals ×10).
    FIT = "fit"
    #: Fit it only to warn when it is significant.
    CHECK = "check"


_POSITIVE_INTS = ("chunk_rows", "noise_samples_per_chunk")
_POSITIVE_FLOATS = (
    "attitude_decimation_seconds",
    "attitude_block_seconds",
    "filter_block_seconds",
    "velocity_limit",
    "attitude_limit",
    "rate_tolerance",
    "polar_tolerance",
)
_FLAGS = ("couplings", "compensate_loop", "run_filter", "estimate_k2", "estimate_gyro_drift")


def _option_error(name: str, value: object, expected: str) -> InputError:
    return InputError(f"system-stage option {name} = {value!r} is not valid", field=name, expected=expected)


def _is_number(value: object) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def _check_thermal_prior(prior: object) -> None:
    if not isinstance(prior, tuple | list) or len(prior) != 2 or not all(_is_number(v) and v > 0 for v in prior):
        raise _option_error("thermal_prior", prior, "two positive numbers: 1σ of Kt_bias [m/s²/K] and of Kt_sf [1/K]")


def validate_options(options: SystemOptions) -> GyroDrift:
    """Check every option of ``options`` (InputError naming the option and what it expects); the ``gyro_drift`` choice."""
    _check_counts_and_scales(options)
    for name in _FLAGS:
        if not isinstance(getattr(options, name), bool):
            raise _option_error(name, getattr(options, name), "True or False")
    gyro_drift = _check_drift(options)
    _check_thermal_prior(options.thermal_prior)
    if not _is_number(options.noise_false_positive_rate) or not 0 < options.noise_false_positive_rate < 1:
        raise _option_error("noise_false_positive_rate", options.noise_false_positive_rate, "a probability between 0 and 1")
    return gyro_drift


def _check_counts_and_scales(options: SystemOptions) -> None:
    """Check the integer counts, the positive scales, the minimum duration and the case-rotation period."""
    for name in _POSITIVE_INTS:
        value = getattr(options, name)
        if not isinstance(value, int) or isinstance(value, bool) or value < 1:
            raise _option_error(name, value, "a positive integer")
    for name in _POSITIVE_FLOATS:
        if not _is_number(getattr(options, name)) or getattr(options, name) <= 0:
            raise _option_error(name, getattr(options, name), "a positive finite number")
    if not _is_number(options.minimum_duration) or options.minimum_duration < 0:
        raise _option_error("minimum_duration", options.minimum_duration, "a finite number of seconds ≥ 0")
    if options.case_rotation_period is not None and (not _is_number(options.case_rotation_period) or options.case_rotation_period <= 0):
        raise _option_error("case_rotation_period", options.case_rotation_period, "a positive number of seconds, or None")


def _check_drift(options: SystemOptions) -> GyroDrift:
    """Check the gyro-drift options (choice, known drift, its uncertainty) and return the ``gyro_drift`` choice."""
    try:
        gyro_drift = GyroDrift(options.gyro_drift)
    except ValueError:
        raise _option_error("gyro_drift", options.gyro_drift, "one of " + ", ".join(repr(g.value) for g in GyroDrift)) from None
    drift = options.known_gyro_drift
    if drift is not None and (not isinstance(drift, tuple | list) or len(drift) != 3 or not all(_is_number(v) for v in drift)):
        raise _option_error("known_gyro_drift", drift, "three finite numbers [rad/s] (platform x, y, z), or None")
    if options.gyro_drift_uncertainty is not None and (
        not _is_number(options.gyro_drift_uncertainty) or options.gyro_drift_uncertainty < 0
    ):
        raise _option_error("gyro_drift_uncertainty", options.gyro_drift_uncertainty, "a finite number [rad/s] ≥ 0, or None")
    return gyro_drift
