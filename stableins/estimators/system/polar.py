r"""The platform's polar alignment from the gimbal readings, and the platform-rate check that rests on it.

docs/system-calibration.md §9 ("The polar alignment from the gimbal readings").  The gimbal fit
(:func:`.gyro_drift.fit_gimbal_drift`) gives the platform's orientation in inertial space with the base-fixed
nuisances removed, ``C_{n_0}^p``, and the drift ``ε^p`` that turns it, so the Earth's axis in the platform frame over
the record is

.. math:: a(t) = \mathrm{rot}(−ε^p t)\, C_{n_0}^{p}\, (\cos L, 0, −\sin L)^T,

``(0, 0, 1)`` on a polar-aligned platform.  Its x, y components are the polar misalignment of ``z_p``; it is linear in
``t`` to first order, so its largest value is at the record's start or end.  What tells the causes apart:

* a base tilted (or turned) under a platform aligned for another base, or a zero-offset error of the inner or middle
  gimbal: a constant misalignment ``μ`` (the fit's constant ``c``; the readings' Earth-rate harmonic of the same size is
  the base-fixed ``ω_b``, which the constant is fitted against);
* a gyro drift along ``z_p``: ``a`` stays on ``z_p`` (a turn about the platform's own axis), the platform-axis reading
  ramps (rate ``1 + ε_z/ω_ie`` up to the sense ``s1``) and nothing else;
* an equatorial gyro drift: ``a`` leaves ``z_p`` by ``ε t``.

The specific-force channel sees a misalignment only at second order: ``z = ½(|f̂|²/g² − 1)`` does not depend on the
platform's orientation, and the rows ``u(S)`` of the harmonic model are off by ``μ × u``, which multiplies the
residuals ``δ``: an error ``μ |δ|`` (1e-3 rad × 1e-4 = 1e-7 against σ of about 1e-6 for the combined coefficients).  A
polar misalignment beyond ``polar_tolerance`` (1e-3 rad) is refused.  The measurement's own σ is below 1e-7 rad (the
angle sensors' noise over thousands of blocks), far inside the tolerance, so the check's false refusals on a polar-aligned
platform are those of a misalignment truly beyond it (``benchmarks/bench_system_polar.py --seeds 40``: 0 of 40 clean
records and 0 of 40 with 0.05 °/h along z_p refused, largest misalignment 0.11 mrad; 40 of 40 tilted bases of 2e-3 rad
refused).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from stableins.conventions import DEG_PER_HOUR, EARTH_RATE
from stableins.errors import InputError

if TYPE_CHECKING:
    from stableins.estimators.system.checks import StaticChecks
    from stableins.estimators.system.gyro_drift import GimbalDrift
    from stableins.estimators.system.loop import DampingLoop
    from stableins.estimators.system.options import SystemOptions

#: Platform-rate tolerance when the polar alignment is not measured (no inner and middle readings): a base tilted under a
#: platform aligned for a level one moves the rate's straight-line fit over a day by −2.6e-3 for 0.0117 rad (the
#: misalignment's Earth-rate modulation of the platform-axis angle, correlated −0.78 with the ramp), which nothing else
#: then refuses.  A z_p gyro drift up to 0.03 °/h is measured under it.
RATE_TOLERANCE_UNCHECKED = 2e-3


#: Largest turn of z_p off the pole by a measured equatorial gyro drift over the record, ``|ε_xy| T`` [rad], that the
#: stage calibrates through (docs/system-calibration.md §9, "Across z_p").  Measured over one sidereal day with the
#: static-base checks opened, once the second order of the attitude outputs is removed (:func:`.loop.drift_curvature_removed`):
#: the combined coefficients stay within 0.07σ of the drift-free run at 4.2 mrad (0.01 °/h), 0.35σ at 20.9 mrad
#: (0.05 °/h), 0.72σ at 41.8 mrad (0.1 °/h), growing about linearly; 30 mrad (0.072 °/h for a day, the ``gyro`` world's
#: 0.05 °/h on x_p and y_p) keeps that within about half a σ.
DRIFT_TURN_LIMIT = 0.03


@dataclass(frozen=True)
class PolarAlignment:
    """The polar misalignment of ``z_p`` the gimbal readings measure (:func:`polar_alignment`).

    Attributes
    ----------
    start, end : ndarray, shape (2,)
        x, y components of the Earth's axis in the platform frame at the first and the last block [rad] (0 on a
        polar-aligned platform; small angles: the misalignment of ``z_p``).
    sigma : ndarray, shape (2,)
        Their standard uncertainty (largest over the two axes) at the start and at the end [rad].
    span : float
        Time between the first and the last block [s].
    drift : ndarray, shape (3,)
        The gyro drift that turns the platform ``ε^p`` [rad/s] (:class:`.gyro_drift.GimbalDrift`).
    """

    start: NDArray[np.float64]
    end: NDArray[np.float64]
    sigma: NDArray[np.float64]
    span: float
    drift: NDArray[np.float64]

    @property
    def angle(self) -> float:
        """Largest angle between ``z_p`` and the Earth's axis over the record [rad] (start or end)."""
        return float(max(np.hypot(*self.start), np.hypot(*self.end)))

    @property
    def drift_turn(self) -> float:
        """How far the measured equatorial drift turns ``z_p`` over the record [rad]: ``|ε_xy| T``."""
        return float(np.hypot(*self.drift[:2]) * self.span)

    def describe(self) -> str:
        """One line: the misalignment at the start and end, in mrad."""
        return (
            f"polar alignment from the gimbal readings: z_p is {np.hypot(*self.start) * 1e3:.3f} mrad from the Earth's axis at "
            f"the record's start, {np.hypot(*self.end) * 1e3:.3f} mrad at its end (± {self.sigma.max() * 1e3:.1e} mrad)"
        )


def polar_alignment(gimbal: GimbalDrift) -> PolarAlignment:
    """Return the polar misalignment over the record from the gimbal fit (module docstring)."""
    first, last = gimbal.span
    axis = gimbal.earth_axis(np.array([first, last]))
    # a(t)_xy ≈ a_ref,xy + (−e_y, e_x), e = c − ε t: σ from the constant's and the drift's σ (their small correlation left out)
    constant = float(np.max(gimbal.orientation_sigma[:2]))
    drift = float(np.max(gimbal.sigma[:2]))
    sigma = np.array([math.hypot(constant, drift * first), math.hypot(constant, drift * last)])
    return PolarAlignment(axis[0, :2], axis[1, :2], sigma, float(last - first), np.asarray(gimbal.values, dtype=float))


def check_polar_alignment(
    polar: PolarAlignment | None, rate_ratio: float, options: SystemOptions, path: str, *, drift_removed: bool = True
) -> None:
    """Refuse a platform that is not polar aligned (gimbal readings), or without them a platform rate beyond 2e-3.

    With the polar alignment measured, the platform-rate check keeps ``options.rate_tolerance`` (a wrong sense, a caged
    platform, a turning base; :class:`.checks.StaticChecks`) and a z_p gyro drift within it is measured.  Without it
    (no inner and middle readings, or a record too short for the gimbal fit) the rate is the only sign of a tilted base:
    :data:`RATE_TOLERANCE_UNCHECKED`.  A measured equatorial drift (``drift_removed``: the stage removes its response) may
    turn z_p by up to :data:`DRIFT_TURN_LIMIT`; the misalignment at the record's start is held to ``polar_tolerance``.
    """
    if polar is None:
        if math.isfinite(rate_ratio) and abs(rate_ratio - 1.0) > min(RATE_TOLERANCE_UNCHECKED, options.rate_tolerance):
            limit = min(RATE_TOLERANCE_UNCHECKED, options.rate_tolerance)
            raise InputError(
                f"the platform-axis angle turns at {rate_ratio:.4f} x the Earth rate, and without the inner and middle gimbal "
                "readings (or with a record too short to fit them) the polar alignment is not measured",
                path=path,
                field="angle_platform",
                expected=(
                    f"a rate within {limit:g} of the Earth rate (a base tilted under a platform aligned for a level one moves it "
                    f"too; a z_p gyro drift moves it by ε_z/ω_ie and is measured up to {limit * EARTH_RATE / DEG_PER_HOUR:.2g} deg/h), "
                    "or the angle_inner and angle_middle columns, with which the polar alignment is measured"
                ),
            )
        return
    drifting = drift_removed and polar.drift_turn > 0.5 * options.polar_tolerance
    # a measured equatorial drift is calibrated through up to DRIFT_TURN_LIMIT; the misalignment it did not cause (at the
    # record's start) is held to the tolerance as before
    misaligned = float(np.hypot(*polar.start)) if drifting else polar.angle
    limit = DRIFT_TURN_LIMIT if drift_removed else 0.5 * options.polar_tolerance
    if misaligned > options.polar_tolerance or (polar.drift_turn > limit and polar.angle > options.polar_tolerance):
        drift = polar.drift / DEG_PER_HOUR
        cause = (
            "a base tilted or turned under a platform aligned for another base (the surveyed base attitude of the metadata), "
            "or a zero-offset error of the inner or middle gimbal"
        )
        if polar.drift_turn > limit:
            cause = (
                f"an uncompensated equatorial gyro drift: the readings measure ({drift[0]:+.3g}, {drift[1]:+.3g}) deg/h along "
                f"x_p, y_p, which turns z_p off the pole by {polar.drift_turn * 1e3:.2f} mrad over the record, beyond the "
                f"{limit * 1e3:.3g} mrad the stage calibrates through (about {limit / max(polar.span, 1.0) / DEG_PER_HOUR:.2g} "
                "deg/h along x_p and y_p over this record"
                + ("" if drift_removed else "; with the gyro drift not estimated its response is not removed")
                + "); compensate the gyros in the INS (the device-level gyro calibration installed) or record a shorter span"
            )
        raise InputError(
            f"the platform is not polar aligned: z_p is {np.hypot(*polar.start) * 1e3:.2f} mrad from the Earth's axis at the "
            f"record's start and {np.hypot(*polar.end) * 1e3:.2f} mrad at its end (gimbal readings); cause: {cause}",
            path=path,
            field="angle_inner/angle_middle",
            expected=(
                f"z_p within {options.polar_tolerance:g} rad of the Earth's axis at the record's start (polar_tolerance: the "
                "harmonic model's rows are off by the misalignment times the residuals), and a measured equatorial gyro "
                f"drift turning it by at most {DRIFT_TURN_LIMIT:g} rad over the record"
            ),
        )


@dataclass(frozen=True)
class DriftPrediction:
    """What the loop's response to the measured drift does to the static-base checks' quantities (:func:`drift_prediction`).

    Attributes
    ----------
    speed : float
        Largest horizontal velocity error of the response over the record [m/s].
    excursion : float
        Largest range of its pitch or roll error over the record [rad].
    """

    speed: float
    excursion: float


def drift_prediction(blocks: dict[str, NDArray[np.float64]], loop: DampingLoop, drift: NDArray[np.float64]) -> DriftPrediction:
    """Return the velocity and attitude excursions the loop's response to ``drift`` [rad/s] builds (at the attitude blocks)."""
    from stableins.estimators.system.loop import DRIFT_SCALE, VELOCITY_STATES, drift_columns

    scale = np.asarray(drift, dtype=float) / DRIFT_SCALE
    velocity = drift_columns(blocks, loop, states=VELOCITY_STATES) @ scale
    attitude = drift_columns(blocks, loop) @ scale
    span = attitude.max(axis=0) - attitude.min(axis=0)
    return DriftPrediction(float(np.hypot(velocity[:, 0], velocity[:, 1]).max()), float(span.max()))


def check_deferred(
    checks: StaticChecks, polar: PolarAlignment | None, predicted: DriftPrediction | None, options: SystemOptions
) -> str | None:
    """Raise the static-base and polar refusals the pass kept (:attr:`.checks.StaticChecks.deferred`) unless the drift explains them.

    An uncompensated equatorial gyro drift (the gimbal readings measure it: ``|ε_xy| T`` beyond half the tolerance)
    builds navigation errors of its own: the velocity error passes 5 m/s (9.7 m/s in a day at 0.05 °/h), pitch and roll
    swing, and the mean of ``f_z/|f|`` leaves ``sin L`` by a part of the turn.  Each kept refusal stands unless its
    quantity is within its limit plus what the drift's predicted response (``predicted``) or turn accounts for; a base
    that moves or is misaligned beyond that is still refused.  Returns a note when the drift explained them.
    """
    if not checks.deferred:
        return None
    if polar is None or predicted is None or polar.drift_turn <= 0.5 * options.polar_tolerance:
        raise checks.deferred[0]
    for error in checks.deferred:
        beyond = {
            "velocity_north/velocity_east": checks.max_velocity > options.velocity_limit + predicted.speed,
            "pitch/roll": checks.excursion > options.attitude_limit + predicted.excursion,
            "f_z": abs(checks.polar_error) > options.polar_tolerance + polar.drift_turn,
        }.get(error.field or "", True)
        if beyond:
            raise error
    return (
        f"the measured equatorial gyro drift explains the navigation errors the static-base checks saw (horizontal velocity "
        f"up to {checks.max_velocity:.3g} m/s, its predicted response {predicted.speed:.3g} m/s; pitch/roll range "
        f"{checks.excursion:.3g} rad, predicted {predicted.excursion:.3g} rad; z_p turned {polar.drift_turn * 1e3:.2f} mrad "
        "off the pole): calibrated through it, its response removed from pitch and roll to second order (docs §9)"
    )


__all__ = [
    "DRIFT_TURN_LIMIT",
    "RATE_TOLERANCE_UNCHECKED",
    "DriftPrediction",
    "PolarAlignment",
    "check_deferred",
    "check_polar_alignment",
    "drift_prediction",
    "polar_alignment",
]
