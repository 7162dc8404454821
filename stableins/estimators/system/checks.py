"""The system stage's checks on the streamed record: metadata, sampling, static base, platform rate, polar alignment."""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from stableins.conventions import DEG_PER_HOUR, EARTH_RATE
from stableins.errors import InputError
from stableins.site import SiteMetadata

if TYPE_CHECKING:
    from stableins.estimators.system.loop import DampingLoop
    from stableins.estimators.system.options import SystemOptions


@dataclass(frozen=True)
class RecordSite:
    """The checked site values of a record (:func:`check_metadata`).

    Attributes
    ----------
    latitude : float
        Geodetic latitude of the site [rad].
    gravity : float
        Local gravity [m/s²].
    rate : float
        Sample rate of the record [Hz].
    """

    latitude: float
    gravity: float
    rate: float


@dataclass(frozen=True)
class StageContext:
    """What every step of one run of the system stage knows: the record's name, its site, the damping loop, the options.

    Attributes
    ----------
    path : str
        The record's name in messages.
    site : RecordSite
        Checked latitude, gravity and sample rate.
    loop : DampingLoop
        The INS damping loop (from the record's metadata).
    options : SystemOptions
        The stage's settings.
    """

    path: str
    site: RecordSite
    loop: DampingLoop
    options: SystemOptions


@dataclass(frozen=True)
class SamplingSummary:
    """What the sampling checks found (:attr:`SystemDiagnostics.sampling`).

    Attributes
    ----------
    gaps : tuple of (int, float)
        The first ten gaps: row after the gap (1-based) and the time step [s].
    gap_count : int
        Gaps in the time column (steps longer than 1.5 periods; counted up to 100 per chunk).
    missing_seconds : float
        Time missing in all [s].
    jitter_steps : int
        Steps off the nominal period by more than 1 % that are not gaps.
    """

    gaps: tuple[tuple[int, float], ...]
    gap_count: int
    missing_seconds: float
    jitter_steps: int

    def to_dict(self) -> dict[str, Any]:
        """Return the JSON form (keys as the attribute names, gaps as lists)."""
        return {
            "gaps": list(self.gaps),
            "gap_count": self.gap_count,
            "missing_seconds": self.missing_seconds,
            "jitter_steps": self.jitter_steps,
        }


def check_metadata(metadata: SiteMetadata, path: str) -> RecordSite:
    """Return the latitude, gravity and sample rate of a system record, checked (:class:`RecordSite`)."""
    lat = metadata.latitude
    if lat is None or not np.isfinite(lat) or abs(lat) > np.pi / 2:
        raise InputError("latitude is missing or not a latitude", path=path, field="metadata.latitude", expected="geodetic latitude in rad")
    if abs(lat) > np.radians(89.0):
        raise InputError("polar-aligned system calibration is degenerate within 1° of a pole", path=path, field="metadata.latitude")
    g = metadata.gravity
    if g is None or not np.isfinite(g) or not (9.7 < g < 9.9):
        raise InputError(f"gravity {g!r} is missing or implausible", path=path, field="metadata.gravity", expected="local gravity in m/s^2")
    rate = metadata.sample_rate
    if rate is None or not np.isfinite(rate) or rate <= 0:
        raise InputError("sample rate is missing", path=path, field="metadata.sample_rate", expected="a positive rate in Hz")
    return RecordSite(float(lat), float(g), float(rate))


#: What a platform drifting in inertial space does to a static record: an equatorial gyro drift ``ε`` turns z_p off the
#: Earth's axis by ``ε t`` (0.05 °/h, Cai et al.'s figure before calibration: 1.2° over a day), far outside the polar
#: alignment the harmonic model rests on (``polar_tolerance``, 1e-3 rad: a mean offset ``ε T/2`` of 1e-3 rad over one
#: day is 0.005 °/h).  docs/system-calibration.md §9.
_GYRO_CAUSE = (
    "an uncompensated equatorial gyro drift does this too: it turns z_p off the Earth's axis by drift x time, 1.2 deg a "
    "day at 0.05 deg/h; the system stage needs the INS to compensate its gyros (the device-level gyro calibration "
    "installed) to about 0.005 deg/h or better"
)


class StaticChecks:
    """Sampling, static-base and platform-rate checks on the streamed record."""

    def __init__(self, options: SystemOptions, rate: float, path: str, *, defer_to_gimbals: bool = False) -> None:
        self.options = options
        self.rate = rate
        self.path = path
        self.period = 1.0 / rate
        self.last_time: float | None = None
        self.first_time: float | None = None
        self.gaps: list[tuple[int, float]] = []
        self.gap_time = 0.0
        self.jitter = 0
        self.max_velocity = 0.0
        self.pitch_range = [np.inf, -np.inf]
        self.roll_range = [np.inf, -np.inf]
        self.excursion = 0.0
        self.rate_sums = np.zeros(5)  # n, Σt, Σt², ΣS, ΣtS (unwrapped)
        self.last_angle: float | None = None
        self.angle_offset = 0.0
        self.moving_at: float | None = None
        self.rate_ratio = float("nan")
        self.duration = 0.0
        self.polar_sums = np.zeros(2)
        self.polar_error = 0.0  # mean angle of gravity with the platform's x-y plane minus the latitude [rad]
        self.latitude = 0.0
        #: With the inner and middle gimbal readings the static-base and polar refusals wait for the gimbal fit, which
        #: tells an uncompensated equatorial gyro drift (measured, its response predicted) from a moving or misaligned
        #: base (:func:`.polar.check_deferred`, docs/system-calibration.md §9); they are kept here, not raised.
        self.defer_to_gimbals = defer_to_gimbals
        self.deferred: list[InputError] = []

    def time(self, t: NDArray[np.float64] | None, span: tuple[float, float], seen: int, irregular: int) -> None:
        """Check the sampling of one chunk; ``irregular`` counts its steps off the nominal period by more than 1 %.

        ``span`` is the chunk's first and last time; ``t`` its stamps (None for a uniform stretch of a time grid).
        Only a chunk with irregular steps (or an irregular step from the previous chunk) is examined step by step.
        """
        if self.last_time is not None:  # the step across the chunk boundary
            across = span[0] - self.last_time
            irregular += not (0.99 * self.period <= across <= 1.01 * self.period)
        if irregular and t is not None:
            bad = ~np.isfinite(t)
            if bad.any():
                k = int(np.argmax(bad))
                raise InputError(
                    f"value {t[k]!r} is not finite", path=self.path, field="time", row=seen + k + 1, expected="a finite number"
                )
            series = t if self.last_time is None else np.concatenate([[self.last_time], t])
            step = np.diff(series)
            offset = seen + (1 if self.last_time is None else 0)
            if not (step > 0).all():
                k = int(np.flatnonzero(~(step > 0))[0])
                raise InputError(
                    "time does not increase", path=self.path, field="time", row=offset + k + 1, expected="strictly increasing time"
                )
            gap = step > 1.5 * self.period
            if gap.any():
                for k in np.flatnonzero(gap)[:100]:
                    self.gaps.append((offset + int(k) + 1, float(step[k])))
                self.gap_time += float(step[gap].sum() - gap.sum() * self.period)
            self.jitter += int(((np.abs(step - self.period) > 0.01 * self.period) & ~gap).sum())
        if self.first_time is None:
            self.first_time = span[0]
        self.last_time = span[1]

    def slow(self, t: NDArray, s: NDArray, pitch: NDArray, roll: NDArray, vn: NDArray, *, ve: NDArray) -> NDArray[np.float64]:
        """Static-base checks on the decimated samples; returns the Earth-rate angle unwrapped across chunks."""
        if t.size == 0:
            return s
        speed = np.hypot(vn, ve)
        vmax = float(speed.max())
        if vmax > self.options.velocity_limit and self.moving_at is None:
            self.moving_at = float(t[int(np.argmax(speed > self.options.velocity_limit))])
        self.max_velocity = max(self.max_velocity, vmax)
        self.pitch_range = [min(self.pitch_range[0], float(pitch.min())), max(self.pitch_range[1], float(pitch.max()))]
        self.roll_range = [min(self.roll_range[0], float(roll.min())), max(self.roll_range[1], float(roll.max()))]
        # unwrap the Earth-rate angle across chunks
        prev = self.last_angle if self.last_angle is not None else float(s[0])
        series = np.concatenate([[prev], s])
        if np.abs(np.diff(series)).max() > np.pi:  # a wrap of the reading in this chunk (rare: S moves 7e-5 rad/s)
            series = np.unwrap(series)
        series = series[1:] + self.angle_offset
        self.angle_offset = float(series[-1] - s[-1])
        self.last_angle = float(s[-1])
        tt = t - (self.first_time or 0.0)
        self.rate_sums += [t.size, tt.sum(), (tt * tt).sum(), series.sum(), (tt * series).sum()]
        return series

    def polar(self, fx: NDArray, fy: NDArray, fz: NDArray) -> None:
        """Accumulate the direction cosine of gravity with z_p (sin L on a polar-aligned platform)."""
        norm = np.sqrt(fx * fx + fy * fy + fz * fz)
        self.polar_sums += [fz.size, float(np.sum(fz / norm))]

    def _refuse(self, error: InputError) -> None:
        """Raise a static-base or polar refusal, or keep it for the gimbal fit (:attr:`defer_to_gimbals`)."""
        if not self.defer_to_gimbals:
            raise error
        self.deferred.append(error)

    def finish(self, seen: int, notes: list[str]) -> None:
        """Record-level checks once every chunk is in: raise on a moving, tilted, misaligned or turning base; notes for gaps and jitter."""
        self.duration = (self.last_time or 0.0) - (self.first_time or 0.0)
        n, st, stt, ss, sts = self.rate_sums
        denominator = n * stt - st * st
        if n > 2 and denominator > 0:
            slope = (n * sts - st * ss) / denominator
            self.rate_ratio = slope / EARTH_RATE
        excursion = max(self.pitch_range[1] - self.pitch_range[0], self.roll_range[1] - self.roll_range[0])
        self.excursion = excursion
        if self.moving_at is not None:
            self._refuse(InputError(
                f"the base is not static: horizontal velocity output reaches {self.max_velocity:.3g} m/s "
                f"(first beyond {self.options.velocity_limit:g} m/s at t = {self.moving_at:.1f} s)",
                path=self.path,
                field="velocity_north/velocity_east",
                expected=(
                    "a static base (velocity outputs are then navigation errors: Schuler transients of Δf/ω_s, a few m/s at most) "
                    f"and compensated gyros ({_GYRO_CAUSE})"
                ),
            ))  # fmt: skip
        if excursion > self.options.attitude_limit:
            self._refuse(InputError(
                f"the base is not static or not level: pitch/roll vary by {excursion:.3g} rad over the record",
                path=self.path,
                field="pitch/roll",
                expected=f"attitude errors varying by less than {self.options.attitude_limit:g} rad on a static base ({_GYRO_CAUSE})",
            ))  # fmt: skip
        if self.polar_sums[0] > 0:
            mean_uz = self.polar_sums[1] / self.polar_sums[0]
            self.polar_error = math.asin(max(-1.0, min(1.0, mean_uz))) - self.latitude
            if abs(self.polar_error) > self.options.polar_tolerance:
                self._refuse(InputError(
                    f"the platform is not polar aligned: gravity makes {math.degrees(math.asin(max(-1.0, min(1.0, mean_uz)))):.3f}° "
                    f"with the platform's x-y plane, the latitude is {math.degrees(self.latitude):.3f}°",
                    path=self.path,
                    field="f_z",
                    expected=f"z_p on the Earth's spin axis (f_z/g = sin L), as the system-level method requires ({_GYRO_CAUSE})",
                ))  # fmt: skip
        if np.isfinite(self.rate_ratio) and abs(self.rate_ratio - 1.0) > self.options.rate_tolerance:
            raise InputError(
                f"the platform-axis angle turns at {self.rate_ratio:.4f} x the Earth rate",
                path=self.path,
                field="angle_platform",
                expected=(
                    "a platform fixed in inertial space on a static base (angle rate = Earth rate, correct sense s1; a z_p gyro drift "
                    f"moves the rate by ε_z/ω_ie and is measured up to {self.options.rate_tolerance * EARTH_RATE / DEG_PER_HOUR:.2g} deg/h)"
                ),
            )
        if self.gaps:
            first = self.gaps[0]
            text = (
                f"{len(self.gaps)} gap(s) in the time column (first at row {first[0]}: step {first[1]:.6g} s; {self.gap_time:.1f} s "
                "missing in all); the fits use the samples present (the INS kept running), the Earth-rate angle is read per sample"
            )
            notes.append(text)
            warnings.warn(f"{self.path}: {text}", UserWarning, stacklevel=5)
        if self.jitter:
            text = (
                f"{self.jitter} time step(s) off the nominal {self.period:.6g} s by more than 1 %; the fits do not assume uniform sampling"
            )
            notes.append(text)
            warnings.warn(f"{self.path}: {text}", UserWarning, stacklevel=5)

    def summary(self) -> SamplingSummary:
        """Return what the sampling checks found."""
        return SamplingSummary(tuple(self.gaps[:10]), len(self.gaps), self.gap_time, self.jitter)


__all__ = ["RecordSite", "SamplingSummary", "StageContext", "StaticChecks", "check_metadata"]
