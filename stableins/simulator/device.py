r"""Device level: a simulated gimbaled platform that slews, settles and records.

:class:`SimulatedPlatform` implements :class:`stableins.drivers.base.PlatformDriver`.
How the platform is held within a dwell is the site's dwell mode (caged, torqued at the
computed Earth rate, inertially held; docs/conventions.md "The platform during a dwell").  Every sample is computed from first principles:

1. Gimbal readings follow the command: a cosine-profile slew from the readings at
   the command to the commanded readings (peak rate ``settling['slew_rate']``),
   then a settling transient ``δr_i(τ) = G Δr_i e^{-ζωτ} sin(ω_d τ)`` (``G`` =
   ``settling['gain']``, ``ω = 2π settling['frequency']``, ``ζ = settling['damping']``,
   ``ω_d = ω sqrt(1-ζ²)``, ``τ`` time since the end of the slew, ``Δr`` the slew).
   The angle sensors read the actual motion plus white noise.
2. Exact kinematics: ``C_n^p`` from :class:`stableins.platform.GimbalPlatform`
   (offsets, senses, base attitude and tilt, non-orthogonality, sensor errors).  From the end
   of each slew the platform moves relative to the base as the site's dwell mode says
   (``truth.site.dwell_mode``, docs/conventions.md "The platform during a dwell",
   :func:`stableins.conventions.dwell_platform_rate`): caged, not at all; torqued at the
   computed Earth rate, at ``w + k ∘ ω_ie^p`` with the gyro-error rate ``w = −(ε^p + D_g f^p)``
   (``truth.gyro_drift`` x, y, z and the ``Dg_ab`` effects) and the torquers' scale-factor
   error ``k`` (``truth.gyro_drift`` ``torquer_scale_x/y/z``); inertially held, exactly
   ``C_n^p(τ) = rot(τ w) C_n^p exp(τ [ω_ie^n ×])``.  ``w`` and ``ω_ie^p`` are those of the
   orientation at ``τ`` without the gyro-error turn (that turn stays below 1e-4 rad, so the
   change of ``f^p`` it causes is a 1e-4 relative effect on a 1e-4 rad angle).  A position near
   gimbal lock (:data:`stableins.platform.GIMBAL_LOCK_CONDITION`) is held to the base: no gimbal
   turns the platform about one direction, so the angle loops cage it.  The readings follow by
   exact inverse kinematics.  (The gyro-case-rotation residual of ``truth.gyro_drift`` is a
   system-level effect, left out here.)
3. ``f^p = C_n^p f^n`` with ``f^n = (0, 0, −g)``.
4. Accelerometer output from the full nonlinear model, the simulator's own
   (:meth:`stableins.simulator.physics.Accelerometer.output`, Eq. 6 written again from
   docs/conventions.md, not the estimators' :mod:`stableins.errormodel`) with the true parameters plus the
   injected output effects (:mod:`stableins.simulator.effects`), evaluated with the
   temperature, session time, slew direction and platform angular rate/acceleration
   (``ω_bp^p`` of the platform relative to the static base; the Earth rate is left
   out of the size effect, ``ω_ie² r < 1e-10 m/s²``).  With the timing effect ``t_async``
   (``τ``) the accelerometer's input of sample ``t`` (``f^p``, ``ω``, ``ω̇``) is that of the
   exact path at ``t − τ``; the angle readings stay at ``t``.
5. Additive noise, then quantization of the velocity increments with the remainder
   carried (:mod:`stableins.simulator.noise`).

Samples are indexed on a fixed clock ``t_k = k / rate``.  A sample depends only on
the truth, the seed and the commands issued before it, so acquisition can be split
into any blocks, and a platform can be rebuilt from its command history
(:meth:`SimulatedPlatform.restore`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stableins.conventions import dwell_platform_rate, earth_rate_nav, platform_drift_rate, specific_force_nav
from stableins.dwell_mode import DwellMode
from stableins.platform import rotation_about
from stableins.samples import SampleBlock
from stableins.simulator import effects as fx
from stableins.simulator.noise import BLOCK_SAMPLES, NoiseGenerator, Quantizer
from stableins.simulator.physics import Accelerometer, SensorInputs
from stableins.simulator.truth import Truth
from stableins.site import SiteMetadata


@dataclass(frozen=True)
class _Command:
    sample: int
    start: NDArray[np.float64]  # readings at the command
    target: NDArray[np.float64]  # commanded readings
    duration: float  # slew duration [s]
    slew_direction: NDArray[np.float64]  # hysteresis state per axis after the slew (effects.hysteresis_state)
    held: bool = False  # near gimbal lock: the angle loops cage the platform (platform.GIMBAL_LOCK_CONDITION)


class SimulatedPlatform:
    """The simulated platform of a :class:`~stableins.simulator.truth.Truth`.

    Parameters
    ----------
    truth : Truth
    rate : float, optional
        Sample rate [Hz] (default ``truth.site.sample_rate``).
    seed : int, optional
        Seed of the random streams (default ``truth.seed``).
    initial_readings : tuple of float
        Readings at session time 0 [rad].
    """

    def __init__(
        self, truth: Truth, rate: float | None = None, seed: int | None = None, initial_readings: Sequence[float] = (0.0, 0.0, 0.0)
    ):
        self.truth = truth
        self.rate = float(rate if rate is not None else truth.site.sample_rate)
        if not self.rate > 0:
            raise ValueError("sample rate must be positive")
        self.seed = int(truth.seed if seed is None else seed)
        self.platform = truth.platform()
        self.noise = NoiseGenerator(truth.noise, self.rate, self.seed)
        self.initial_readings = np.asarray(initial_readings, dtype=float)
        self._commands: list[_Command] = []
        self._sample = 0
        self._closed = False
        values = dict(truth.parameters)
        values.update({k: v for k, v in truth.effects.items() if fx.CATALOGUE[k].kind == "output"})
        self._accelerometer = Accelerometer(values, fx.output_effects(truth.effects))
        self._gravity_nav = specific_force_nav(truth.site.gravity)
        self._drift = np.array([truth.gyro_drift.get(a, 0.0) for a in "xyz"])
        self._torquer = np.array([truth.gyro_drift.get(f"torquer_scale_{a}", 0.0) for a in "xyz"])
        self._mode = truth.site.dwell_mode
        self._earth_rate_nav = earth_rate_nav(truth.site.latitude)
        self._g_sensitivity = fx.g_sensitivity(truth.effects)
        self._needs_rates = fx.needs(truth.effects, "lever_")
        #: time asynchrony τ [s]: the accelerometer input is the path's at t − τ (effects "timing")
        self._async = float(truth.effects.get("t_async", 0.0))
        s = truth.settling
        self._omega = 2 * np.pi * s["frequency"]
        self._zeta = s["damping"]
        self._omega_d = self._omega * np.sqrt(max(1.0 - self._zeta**2, 0.0))
        self._gain = s["gain"]
        self._slew_rate = s["slew_rate"]
        self._quantizer = Quantizer(self.noise)
        site = truth.site
        self._metadata = SiteMetadata(**{**site.__dict__, "sample_rate": self.rate})

    # ----------------------------------------------------------------- driver API
    @property
    def metadata(self) -> SiteMetadata:
        """Site metadata of the simulated unit (the truth's site at this platform's sample rate)."""
        return self._metadata

    @property
    def time(self) -> float:
        """Current session time [s] (time of the next sample)."""
        return self._sample / self.rate

    def command(self, readings: tuple[float, float, float]) -> float:
        """Slew to the commanded readings (platform, inner, middle) [rad]; returns the command time [s]."""
        self._check_open()
        target = np.asarray(readings, dtype=float)
        if target.shape != (3,) or not np.all(np.isfinite(target)):
            raise ValueError(f"command needs three finite readings, got {readings!r}")
        start = self._nominal_readings(self._sample)
        delta = target - start
        duration = float(np.pi / 2 * np.max(np.abs(delta)) / self._slew_rate)
        f_start = self.platform.specific_force_platform(start, self.truth.site.gravity)
        f_end = self.platform.specific_force_platform(target, self.truth.site.gravity)
        previous = self._commands[-1].slew_direction if self._commands else np.zeros(3)
        state = fx.hysteresis_state(previous, f_end - f_start)
        held = bool(self.platform.near_gimbal_lock(self.platform.actual_angles(target)))
        self._commands.append(_Command(self._sample, start, target, duration, state, held))
        return self.time

    def read_angles(self) -> NDArray[np.float64]:
        """Angle-sensor readings at the current time [rad] (with sensor noise)."""
        readings, *_ = self._motion(np.array([self._sample]))
        return readings[0] + self.noise.angles(self._sample, 1)[0]

    def acquire(self, duration: float) -> SampleBlock:
        """Record ``round(duration·rate)`` samples from the current time."""
        self._check_open()
        count = int(round(duration * self.rate))
        if count < 0:
            raise ValueError("duration must be non-negative")
        block = self.samples(self._sample, count)
        self._sample += count
        return block

    def wait(self, duration: float) -> None:
        """Let ``duration`` seconds pass without recording (the world goes on identically).

        Every output is a function of the sample index, the commands and the seed (the noise is generated by blocks
        of the index), except the quantizer's carried remainder, which sums every output in order.  Without
        quantization the samples passed over are therefore not computed at all (a slew and its settling cost
        nothing); with it their accelerometer outputs are, so that the remainder, and every output after it, stays the
        same (their angle and temperature readings, functions of the sample index, are not).
        """
        self._check_open()
        count = int(round(duration * self.rate))
        if count < 0:
            raise ValueError("duration must be non-negative")
        if self.truth.noise.quantization > 0 and count > 0:
            self._quantized(self._sample, self._raw(np.arange(self._sample, self._sample + count))[0])
        self._sample += count

    def slew_duration(self) -> float:
        """Duration [s] of the last commanded slew."""
        return self._commands[-1].duration if self._commands else 0.0

    def status(self) -> dict[str, object]:
        """Return the driver status: session time and sample, commands so far, seed, serial number, closed."""
        return {
            "driver": "simulated",
            "time": self.time,
            "sample": self._sample,
            "commands": len(self._commands),
            "last_command": None if not self._commands else self._commands[-1].target.tolist(),
            "seed": self.seed,
            "serial_number": self.truth.site.serial_number,
            "closed": self._closed,
        }

    def close(self) -> None:
        """Close the platform: further commands and acquisitions raise ``RuntimeError``."""
        self._closed = True

    # ----------------------------------------------------------------- history / resume
    @property
    def history(self) -> list[dict[str, Any]]:
        """Command history ``[{sample, readings}]``: with the truth and seed it defines the whole session."""
        return [{"sample": c.sample, "readings": c.target.tolist()} for c in self._commands]

    @classmethod
    def restore(
        cls,
        truth: Truth,
        history: Sequence[dict[str, Any]],
        time: float,
        *,
        rate: float | None = None,
        seed: int | None = None,
        initial_readings: Sequence[float] = (0.0, 0.0, 0.0),
    ) -> SimulatedPlatform:
        """Rebuild a platform from its command history and continue at session ``time`` [s]."""
        platform = cls(truth, rate=rate, seed=seed, initial_readings=initial_readings)
        for entry in history:
            platform._sample = int(entry["sample"])
            platform.command(tuple(entry["readings"]))
        platform._sample = int(round(time * platform.rate))
        return platform

    # ----------------------------------------------------------------- the world
    def samples(self, start: int, count: int) -> SampleBlock:
        """Return samples ``start .. start+count-1`` as the instrument outputs them (pure function of the commands so far)."""
        if count == 0:
            empty = np.zeros((0, 3))
            return SampleBlock(np.zeros(0), empty, empty.copy(), np.zeros(0))
        index = np.arange(start, start + count)
        f_a, readings, temperature = self._raw(index)
        f_a = self._quantized(start, f_a)
        angles = readings + self.noise.angles(start, count)
        temperature = temperature + self.noise.temperature_sensor(start, count)
        return SampleBlock(index / self.rate, f_a, angles, temperature)

    def _quantized(self, start: int, f_a: NDArray[np.float64]) -> NDArray[np.float64]:
        """Return the unquantized outputs ``f_a`` of samples ``start ..`` as the quantizing counter outputs them.

        A piece that does not continue the quantizer's last one starts its remainder from the sample block's
        beginning (:class:`stableins.simulator.noise.Quantizer`): the outputs before it in the block are made first.
        """
        if self.truth.noise.quantization > 0 and not self._quantizer.continues(start):
            begin = (start // BLOCK_SAMPLES) * BLOCK_SAMPLES
            self._quantizer(begin, self._raw(np.arange(begin, start))[0])
        return self._quantizer(start, f_a)

    def _raw(self, index: NDArray[np.int64]) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """Unquantized accelerometer output (with noise), noise-free readings and true temperature."""
        truth = self.truth
        time = index / self.rate
        readings, rates, dcm, segment, settle_time = self._motion(index)
        shift = -self._async  # the accelerometer samples the path at t − τ; the readings stay at t
        if shift:
            sampled, rates, dcm, _, _ = self._motion(index, shift)
        else:
            sampled = readings
        f_p = np.einsum("...ij,j->...i", dcm, self._gravity_nav)
        temperature = truth.noise.temperature(time)
        slew_direction = np.zeros((len(index), 3))
        has = segment >= 0
        if np.any(has):
            directions = np.array([c.slew_direction for c in self._commands])
            slew_direction[has] = directions[segment[has]]
        inputs = SensorInputs(
            specific_force=f_p,
            temperature=temperature - truth.site.reference_temperature,
            time=time,
            slew_direction=slew_direction,
        )
        if self._needs_rates:
            h = 1e-3
            w = self.platform.angular_rate(self.platform.actual_angles(sampled), rates)
            w_plus = self._angular_rate_at(index, shift + h)
            w_minus = self._angular_rate_at(index, shift - h)
            inputs = SensorInputs(f_p, inputs.temperature, inputs.time, slew_direction, w, (w_plus - w_minus) / (2 * h))
        f_a = self._accelerometer.output(f_p, inputs)
        f_a = f_a + self.noise.accelerometer(int(index[0]), len(index))
        return f_a, readings, temperature

    def _angular_rate_at(self, index: NDArray[np.int64], shift: float) -> NDArray[np.float64]:
        readings, rates, _, _ = self._path(index, shift)
        return self.platform.angular_rate(self.platform.actual_angles(readings), rates)

    def _segments(self, index: NDArray[np.int64]) -> NDArray[np.int64]:
        starts = np.array([c.sample for c in self._commands], dtype=np.int64)
        return np.searchsorted(starts, index, side="right") - 1

    def _path(self, index: NDArray[np.int64], shift: float = 0.0):
        """Noise-free readings and reading rates (slew + settling), segment index, time since slew end."""
        n = len(index)
        readings = np.broadcast_to(self.initial_readings, (n, 3)).copy()
        rates = np.zeros((n, 3))
        settle_time = np.full(n, -1.0)
        segment = self._segments(index) if self._commands else np.full(n, -1)
        for j in np.unique(segment[segment >= 0]):
            c = self._commands[j]
            rows = segment == j
            tau = (index[rows] - c.sample) / self.rate + shift
            delta = c.target - c.start
            if c.duration > 0 and tau.min() >= c.duration:  # the slew is over: the next branch's values at x = 1, made once
                r = np.tile(c.start + delta, (len(tau), 1))  # its 0.5 (1 − cos π) is exactly 1
                rd = np.tile(delta * 0.0, (len(tau), 1))  # its zero rate, signed as delta · 0
            elif c.duration > 0:
                x = np.clip(tau / c.duration, 0.0, 1.0)
                moving = (tau > 0) & (tau < c.duration)
                r = c.start + delta * (0.5 * (1.0 - np.cos(np.pi * x)))[:, None]
                rd = delta * (np.where(moving, 0.5 * np.pi / c.duration * np.sin(np.pi * x), 0.0))[:, None]
            else:
                r = np.broadcast_to(c.target, (len(tau), 3)).copy()
                rd = np.zeros((len(tau), 3))
            after = tau - c.duration
            settled = after > 0
            if np.any(settled) and self._gain:
                sel = slice(None) if settled.all() else settled  # a recorded dwell: every row, no gather and scatter
                a = after[sel]
                envelope = np.exp(-self._zeta * self._omega * a)
                sine = np.sin(self._omega_d * a)
                r[sel] += self._gain * delta * (envelope * sine)[:, None]
                rd[sel] += (
                    self._gain * delta * (envelope * (self._omega_d * np.cos(self._omega_d * a) - self._zeta * self._omega * sine))[:, None]
                )
            readings[rows] = r
            rates[rows] = rd
            settle_time[rows] = after
        return readings, rates, segment, settle_time

    def _motion(self, index: NDArray[np.int64], shift: float = 0.0):
        """Return the readings (as the sensors see them, noise-free), reading rates, ``C_n^p``, segment, time since slew end.

        ``shift`` [s]: the motion at ``t + shift`` (the time asynchrony's sampling instant).  From the end of each slew
        the platform moves relative to the base as the site's :class:`~stableins.dwell_mode.DwellMode` says
        (:func:`stableins.conventions.dwell_platform_rate`): caged, not at all; torqued at the computed Earth rate,
        ``C_n^p(τ) = rot(τ (w + k ∘ ω_ie^p)) C_n^p``; inertially held, exactly
        ``C_n^p(τ) = rot(τ w) C_n^p exp(τ [ω_ie^n ×])`` (the base turns under it).  ``rot`` is
        :func:`stableins.platform.rotation_about`; a position near gimbal lock is held to the base (:attr:`_Command.held`).
        """
        readings, rates, segment, settle_time = self._path(index, shift)
        dcm = self._dcm_nav_to_platform(readings)
        held = np.array([c.held for c in self._commands], dtype=bool)
        drifting = (settle_time > 0) & (segment >= 0)
        if np.any(drifting):
            drifting[drifting] = ~held[segment[drifting]]
        mode = self._mode
        if mode is DwellMode.CAGED or not np.any(drifting):
            return readings, rates, dcm, segment, settle_time
        if mode is DwellMode.EARTH_RATE and not (np.any(self._drift) or np.any(self._g_sensitivity) or np.any(self._torquer)):
            return readings, rates, dcm, segment, settle_time
        tau = np.clip(settle_time, 0.0, None)[drifting, None]
        moved = dcm[drifting]
        if mode is DwellMode.INERTIAL:
            moved = moved @ rotation_about(-tau * self._earth_rate_nav)  # exp(τ [ω_ie^n ×]): the base turns under it
        f_p = np.einsum("...ij,j->...i", moved, self._gravity_nav)
        earth_p = np.einsum("...ij,j->...i", moved, self._earth_rate_nav)
        w = platform_drift_rate(self._drift, self._g_sensitivity, f_p)
        # inertially held: the Earth's turn is already in ``moved``
        angle = w * tau if mode is DwellMode.INERTIAL else dwell_platform_rate(mode, w, earth_p, self._torquer) * tau
        dcm[drifting] = rotation_about(angle) @ moved
        readings = readings.copy()
        readings[drifting] = self.platform.readings_from_dcm_nav_to_platform(dcm[drifting], readings[drifting])
        return readings, rates, dcm, segment, settle_time

    def _dcm_nav_to_platform(self, readings: NDArray[np.float64]) -> NDArray[np.float64]:
        """Return ``C_n^p`` of each row of ``readings`` (:meth:`stableins.platform.GimbalPlatform.dcm_nav_to_platform`).

        It is computed once per run of equal consecutive rows: once the settling transient has decayed below the
        readings' last bit (about 50 s into a dwell of the shipped settling) the noise-free readings repeat to the bit,
        and equal readings give equal matrices, so the result is the same as row by row.
        """
        if len(readings) < 2:
            return self.platform.dcm_nav_to_platform(readings)
        new = np.empty(len(readings), dtype=bool)
        new[0] = True
        np.any(readings[1:] != readings[:-1], axis=1, out=new[1:])
        if new.all():
            return self.platform.dcm_nav_to_platform(readings)
        first = np.flatnonzero(new)
        return self.platform.dcm_nav_to_platform(readings[first])[np.cumsum(new) - 1]

    def _nominal_readings(self, sample: int) -> NDArray[np.float64]:
        """Return the readings on the slew path at ``sample`` without the settling transient (start of a new slew)."""
        if not self._commands:
            return self.initial_readings.copy()
        c = self._commands[-1]
        tau = (sample - c.sample) / self.rate
        if c.duration <= 0 or tau >= c.duration:
            return c.target.copy()
        x = tau / c.duration
        return c.start + (c.target - c.start) * 0.5 * (1.0 - np.cos(np.pi * x))

    def _check_open(self) -> None:
        if self._closed:
            raise RuntimeError("the simulated platform is closed")


def simulate_dwells(
    truth: Truth,
    readings_list: Sequence[ArrayLike],
    *,
    dwell: float | Sequence[float],
    settle: float | Sequence[float],
    rate: float | None = None,
    seed: int | None = None,
    stage: str = "coarse",
    pass_number: int = 1,
) -> dict[str, NDArray]:
    """Command each reading triple in turn, wait for the slew and ``settle`` seconds, record ``dwell`` seconds.

    The platform starts at readings (0, 0, 0) (:class:`SimulatedPlatform` for other starting readings).

    Parameters
    ----------
    truth : Truth
    readings_list : sequence of (3,) array_like
        Commanded angle-sensor readings (platform, inner, middle) [rad], in order;
        positions are numbered 1..N in this order.
    dwell : float or sequence of float
        Recorded time per position [s] (one for all, or one per reading).
    settle : float or sequence of float
        Time between the end of the slew and the start of recording [s] (0 keeps the
        settling transient in the record); one for all, or one per reading.
    rate : float, optional
        Sample rate [Hz] (default ``truth.site.sample_rate``).
    seed : int, optional
        Seed of the random streams (default ``truth.seed``).
    stage : str
        ``"coarse"`` or ``"fine"``.
    pass_number : int

    Returns
    -------
    dict of str to ndarray
        Columns named as :data:`stableins.schema.DEVICE_COLUMNS`.
    """
    platform = SimulatedPlatform(truth, rate=rate, seed=seed)
    pieces: list[dict[str, NDArray]] = []
    dwells = np.broadcast_to(np.asarray(dwell, dtype=float), (len(readings_list),))
    settles = np.broadcast_to(np.asarray(settle, dtype=float), (len(readings_list),))
    for position, readings in enumerate(readings_list, start=1):
        r = np.asarray(readings, dtype=float)
        t_command = platform.command(tuple(r))
        platform.wait(platform.slew_duration() + float(settles[position - 1]))
        block = platform.acquire(float(dwells[position - 1]))
        pieces.append(block.device_columns(stage=stage, pass_number=pass_number, position=position, command=r, command_time=t_command))
    from stableins.schema import DEVICE_COLUMNS

    names = [c.name for c in DEVICE_COLUMNS]
    if not pieces:
        return {name: np.zeros(0) for name in names}
    return {name: np.concatenate([p[name] for p in pieces]) for name in names}
