"""Options of the system stage: :class:`SystemOptions`, the gyro-drift choice and their validation at construction."""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import StrEnum

from stableins.conventions import MICRO_G, PPM
from stableins.errors import InputError

#: Default prior σ of the sensitivities when the calibration record has none: 5 µg/K and 5 ppm/K (the library's
#: nominal magnitudes of navigation-grade quartz accelerometers).
DEFAULT_THERMAL_PRIOR = (5.0 * MICRO_G, 5.0 * PPM)
#: How the stage's messages name its inputs: parameters of :class:`SystemOptions`
#: (``stableins calibrate system`` translates them to its flags, a certificate to plain words).
GYRO_DRIFT_PARAMETER = "known_gyro_drift, rad/s"
ESTIMATE_K2_PARAMETER = "estimate_k2=True"


class GyroDrift(StrEnum):
    """What the system stage does about a constant gyro drift (:attr:`SystemOptions.gyro_drift`)."""

    #: Leave it out of the attitude fit (a known drift, :attr:`SystemOptions.known_gyro_drift`, is still removed).
    IGNORE = "ignore"
    #: Fit its response as a nuisance (σ of the fundamentals ×10).
    FIT = "fit"
    #: Fit it only to warn when it is significant.
    CHECK = "check"


@dataclass(frozen=True)
class SystemOptions:
    """Settings of the system stage (defaults follow docs/system-calibration.md).

    Validated at construction: a value of the wrong type or out of range, or an unknown ``gyro_drift``, raises
    :class:`~stableins.errors.InputError` naming the option and what it expects.
    """

    chunk_rows: int = 1 << 18
    attitude_decimation_seconds: float = 1.0
    attitude_block_seconds: float = 10.0
    filter_block_seconds: float = 600.0
    case_rotation_period: float | None = 480.0
    couplings: bool = True
    compensate_loop: bool = True
    velocity_limit: float = 5.0  # [m/s] beyond this the base is not static (3e-3 m/s² gives ~2.5 m/s of Schuler transient)
    attitude_limit: float = 5e-3  # [rad] excursion of pitch/roll around their mean beyond which the base is not static
    # relative deviation of the platform-angle rate from the Earth rate: a wrong sense s1 is off by 2, a caged platform by 1, a
    # turning base by its turn; a z_p gyro drift ε_z shifts it by ε_z/ω_ie (0.05: measured up to 0.75 °/h).  A base tilted
    # under a platform aligned for a level one moves it too (0.0117 rad: −2.6e-3): the polar alignment measured in the gimbal
    # readings refuses that (polar.py; without those readings the rate is held to polar.RATE_TOLERANCE_UNCHECKED), docs §9
    rate_tolerance: float = 0.05
    polar_tolerance: float = 1e-3  # [rad] angle between z_p and the Earth's axis (gimbal readings, polar.py; and the mean f_z/|f|)
    minimum_duration: float = 4 * 3600.0  # [s]
    noise_samples_per_chunk: int = 1 << 15  # second differences per chunk: N to 0.6 % from one day at 1 Hz
    run_filter: bool = True
    gyro_drift: GyroDrift = GyroDrift.IGNORE  # see GyroDrift
    known_gyro_drift: tuple[float, float, float] | None = None  # [rad/s] in the platform frame, response removed
    gyro_drift_uncertainty: float | None = None  # [rad/s] standard uncertainty per axis of the drift (given or assumed zero)
    estimate_k2: bool = False  # remove residual K2_x, K2_y (from the third harmonic) and update them in the record
    estimate_gyro_drift: bool = True  # measure ε^p in the gimbal readings, remove it, update gyro_drift_* (docs §9)
    noise_false_positive_rate: float = 0.05  # of the decision "the residuals carry low-frequency noise" (docs §1a)
    thermal_prior: tuple[float, float] = DEFAULT_THERMAL_PRIOR  # 1σ of Kt_bias [m/s²/K], Kt_sf [1/K] (docs §1b)

    def __post_init__(self) -> None:
        object.__setattr__(self, "gyro_drift", validate_options(self))


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
