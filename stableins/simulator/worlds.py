"""Named worlds: presets of what a real instrument and laboratory add to the simulator's default world.

A :class:`World` is a set of changes to a drawn :class:`~stableins.simulator.truth.Truth`: its noise (slow-noise
spectrum, quantization, temperature history), the injected effects (thermal sensitivities, a slow bias drift,
angle-sensor errors, gyro g-sensitivity) and the gyro drift.  The instrument's error-model parameters (scale
factors, biases, angles, ``K2``, offsets) stay those of :meth:`Truth.draw`, so the worlds of one seed are the same
unit in different laboratories (common random numbers).  ``default`` changes nothing: its truth, and every sample
drawn from it, is bit-identical to a plain :meth:`Truth.draw`.

Every number, with its source, is in docs/simulator.md ("Worlds"); ``stableins simulate --list-worlds`` prints
them.  Use::

    truth = apply_world(Truth.draw(7), "lab")            # Python
    stableins simulate device --world lab --out sim/     # CLI
    [[noise]] world = "lab"                              # a campaign file (docs/campaigns.md)
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

from stableins.conventions import ARCSEC, DEG_PER_HOUR, DEG_PER_HOUR_PER_G, MICRO_G, PPM
from stableins.errors import InputError
from stableins.simulator.noise import NoiseSettings, TemperatureProfile
from stableins.simulator.truth import Truth

#: One day [s] (the thermal cycle of a laboratory follows the solar day).
DAY = 86400.0
#: Slow bias drift of the ``drift`` and ``lab`` worlds, 10 µg/day per axis (issue 25's figure) [m/s³].
BIAS_DRIFT = 10.0 * MICRO_G / DAY
#: Bias temperature sensitivity, 5 µg/K (issue 25's figure; navigation-grade quartz: 5–50 µg/K) [m/s²/K].
BIAS_THERMAL = 5.0 * MICRO_G
#: Scale-factor temperature sensitivity, 1 ppm/K (navigation-grade quartz: 0.5–10 ppm/K) [1/K].
SF_THERMAL = 1.0 * PPM
#: Gyro drift before calibration, 0.05 °/h per axis (Cai et al. 2016, the figure before calibration) [rad/s].
GYRO_DRIFT = 0.05 * DEG_PER_HOUR
#: Gyro g-sensitivity, 0.001 °/h/g on the diagonal (issue 25's acceptance world) [rad/s per m/s²].
GYRO_G_SENSITIVITY = 0.001 * DEG_PER_HOUR_PER_G
#: Once-per-revolution angle-sensor error, 2″ cosine and sine per gimbal (an inductosyn/resolver's first harmonic) [rad].
ANGLE_SENSOR_HARMONIC = 2.0 * ARCSEC


@dataclass(frozen=True)
class World:
    """A named world: the noise, effects and gyro drift it puts on a drawn instrument (:func:`apply_world`).

    Attributes
    ----------
    name : str
    summary : str
        One line: what the world adds.
    noise : NoiseSettings or None
        The noise of the world (None: the drawn truth's, i.e. :meth:`NoiseSettings.quartz`).
    effects : Mapping[str, float]
        Effects injected (catalogue ids, SI); ``--hidden`` effects are added on top.
    gyro_drift : Mapping[str, float]
        Gyro drift ``x``, ``y``, ``z`` [rad/s] (None: unchanged).
    slow_noise : bool
        Whether the world has noise slower than white (bias instability, random walk, a Gauss-Markov bias).
    sources : tuple of str
        Where the numbers come from.
    """

    name: str
    summary: str
    noise: NoiseSettings | None = None
    effects: Mapping[str, float] = field(default_factory=dict)
    gyro_drift: Mapping[str, float] | None = None
    slow_noise: bool = True
    sources: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "effects", MappingProxyType(dict(self.effects)))
        if self.gyro_drift is not None:
            object.__setattr__(self, "gyro_drift", MappingProxyType(dict(self.gyro_drift)))

    def apply(self, truth: Truth) -> Truth:
        """Return ``truth`` in this world: its noise, the world's effects (the truth's own kept on top) and gyro drift."""
        changes: dict[str, object] = {}
        if self.noise is not None:
            changes["noise"] = self.noise
        if self.effects:
            changes["effects"] = {**self.effects, **truth.effects}
        if self.gyro_drift is not None:
            changes["gyro_drift"] = {**truth.gyro_drift, **self.gyro_drift}
        return truth.with_changes(**changes) if changes else truth

    def describe(self) -> list[str]:
        """Return the world's contents, one line each, in engineering units."""
        lines = [f"{self.name}: {self.summary}"]
        n = self.noise
        if n is not None:
            lines.append(
                f"  noise: white {n.velocity_random_walk:.3g} m/s/sqrt(s), bias instability {n.bias_instability / MICRO_G:.3g} ug "
                f"(Gauss-Markov time constants {', '.join(f'{t:g}' for t in n.bias_instability_time_constants)} s), "
                f"random walk {n.acceleration_random_walk:.3g} m/s^2/sqrt(s), LSB {n.quantization:.3g} m/s"
            )
            t = n.temperature
            if t.amplitude or t.warmup or t.ramp:
                lines.append(
                    f"  temperature: {t.amplitude:g} K amplitude over {t.period / 3600:g} h (phase {t.phase:g} rad), "
                    f"warm-up {t.warmup:g} K decaying in {t.warmup_time_constant:g} s, ramp {t.ramp:g} K/s, sensor {t.sensor_noise:g} K"
                )
        for k, v in sorted(self.effects.items()):
            lines.append(f"  {k} = {v:.4g} (SI)")
        if self.gyro_drift:
            lines.append("  gyro drift: " + ", ".join(f"{a} {v / DEG_PER_HOUR:.3g} deg/h" for a, v in self.gyro_drift.items()))
        lines += [f"  source: {s}" for s in self.sources]
        return lines


def _quartz(**changes: object) -> NoiseSettings:
    return dataclasses.replace(NoiseSettings.quartz(), **changes)  # type: ignore[arg-type]


#: The thermal history of the ``thermal`` and ``lab`` worlds: a unit switched on 4 K cold that warms up with a
#: 30-min time constant, in a laboratory whose temperature cycles by 2 K peak to peak once a day (phase: the
#: session starts as the room warms), read by a 0.01 K sensor.
LAB_TEMPERATURE = TemperatureProfile(amplitude=1.0, period=DAY, phase=0.0, warmup=-4.0, warmup_time_constant=1800.0, sensor_noise=0.01)

_THERMAL_EFFECTS = {
    **{f"Kt_bias_{a}": s * BIAS_THERMAL for a, s in zip("xyz", (1.0, -1.0, 1.0), strict=True)},
    **{f"Kt_sf_{a}": s * SF_THERMAL for a, s in zip("xyz", (1.0, 1.0, -1.0), strict=True)},
}
_DRIFT_EFFECTS = {f"Kd_bias_{a}": s * BIAS_DRIFT for a, s in zip("xyz", (1.0, -1.0, 1.0), strict=True)}
_ANGLE_EFFECTS = {
    f"ang1_{g}_{c}": s * ANGLE_SENSOR_HARMONIC
    for (g, c), s in zip(
        ((g, c) for g in ("platform", "inner", "middle") for c in ("c", "s")), (1.0, -1.0, 0.5, 1.0, -0.5, 1.0), strict=True
    )
}
_GYRO_EFFECTS = {f"Dg_{a}{a}": GYRO_G_SENSITIVITY for a in "xyz"}

_QUARTZ_SOURCE = "quartz noise: NoiseSettings.quartz() (docs/simulator.md, 'Noise'): N 4.5e-4 m/s/sqrt(s), B 2 ug, K 1e-7 m/s^2/sqrt(s)"

#: The named worlds (docs/simulator.md, "Worlds").
WORLDS: Mapping[str, World] = MappingProxyType(
    {
        w.name: w
        for w in (
            World("default", "the simulator's default world (quartz noise, constant temperature, no gyro drift): unchanged", None),
            World(
                "white",
                "white noise only (the quartz white level; no slow noise, no quantization): the false-alarm world",
                _quartz(bias_instability=0.0, acceleration_random_walk=0.0, quantization=0.0),
                slow_noise=False,
                sources=(_QUARTZ_SOURCE,),
            ),
            World(
                "flicker",
                "white + bias instability 2 ug as flicker (1/f from 10 s to 1e5 s), no random walk",
                _quartz(acceleration_random_walk=0.0),
                sources=(_QUARTZ_SOURCE,),
            ),
            World(
                "random-walk",
                "white + acceleration random walk 3e-7 m/s^2/sqrt(s) (1/f^2; 3x quartz), no bias instability",
                _quartz(bias_instability=0.0, acceleration_random_walk=3e-7),
                sources=(_QUARTZ_SOURCE, "random walk: 3x the quartz figure, about 9 ug over a day"),
            ),
            World(
                "gauss-markov",
                "white + one first-order Gauss-Markov bias of 3 ug and 300 s (a Lorentzian: white below 5e-4 Hz, 1/f^2 above)",
                # one time constant: NoiseSettings gives it the variance B² ln10/π, so B = 3 µg / sqrt(ln 10/π)
                _quartz(
                    bias_instability=3.0 * MICRO_G / math.sqrt(math.log(10.0) / math.pi),
                    bias_instability_time_constants=(300.0,),
                    acceleration_random_walk=0.0,
                ),
                sources=(_QUARTZ_SOURCE, "a thermal/electronic bias wander of a few ug with a 5-min correlation time"),
            ),
            World(
                "quartz",
                "white + flicker 2 ug + random walk 1e-7 m/s^2/sqrt(s) + 1e-5 m/s LSB: the default noise, nothing else",
                NoiseSettings.quartz(),
                sources=(_QUARTZ_SOURCE,),
            ),
            World(
                "thermal",
                "quartz noise + a warm-up (4 K cold, 30 min) and a daily 2 K peak-to-peak cycle through 5 ug/K and 1 ppm/K",
                _quartz(temperature=LAB_TEMPERATURE),
                _THERMAL_EFFECTS,
                sources=(_QUARTZ_SOURCE, "thermal: issue 25 (5 ug/K, 2 K peak to peak, one day); warm-up: a typical 30-min switch-on"),
            ),
            World(
                "drift",
                "quartz noise + a slow bias drift of 10 ug/day on every axis",
                NoiseSettings.quartz(),
                _DRIFT_EFFECTS,
                sources=(_QUARTZ_SOURCE, "drift: issue 25 (10 ug/day)"),
            ),
            World(
                "lab",
                "everything a laboratory adds at device level but the gyro: quartz noise and LSB, warm-up and daily cycle "
                "through 5 ug/K and 1 ppm/K, 10 ug/day bias drift, 2-arcsec angle-sensor harmonics (with gyro drift: the "
                "'gyro' world)",
                _quartz(temperature=LAB_TEMPERATURE),
                {**_THERMAL_EFFECTS, **_DRIFT_EFFECTS, **_ANGLE_EFFECTS},
                sources=(
                    _QUARTZ_SOURCE,
                    "thermal and drift: issue 25; angle sensors: a 2-arcsec first harmonic (once per revolution)",
                    "no gyro drift: a 0.05 deg/h platform turns 30 arcsec in a 600-s fine dwell, which ramps the horizontal "
                    "outputs by ~150 ug inside the dwell, which the device noise path read as slow noise until the dwell "
                    "statistics took out what the measured turn explains (docs/simulator.md, 'Worlds')",
                ),
            ),
            World(
                "gyro",
                "the lab world plus gyro drift 0.05 deg/h and g-sensitivity 0.001 deg/h/g per axis, the platform torqued at "
                "the Earth rate in its dwells (the paper's procedure): the lab world with a realistic gyro",
                _quartz(temperature=LAB_TEMPERATURE),
                {**_THERMAL_EFFECTS, **_DRIFT_EFFECTS, **_ANGLE_EFFECTS, **_GYRO_EFFECTS},
                {a: GYRO_DRIFT for a in "xyz"},
                sources=(
                    _QUARTZ_SOURCE,
                    "gyro drift 0.05 deg/h: Cai et al. 2016 (before calibration); g-sensitivity 0.001 deg/h/g: issue 25's acceptance world",
                ),
            ),
            World(
                "gyro-z",
                "quartz noise, 2-arcsec angle-sensor harmonics, gyro drift 0.05 deg/h along z_p and g-sensitivity 0.001 "
                "deg/h/g: the realistic gyro drift a system-level day carries uncompensated (along x_p, y_p it turns z_p off "
                "the pole, as in the 'gyro' world: calibrated through up to 30 mrad of turn, docs/system-calibration.md section 9)",
                NoiseSettings.quartz(),
                {**_ANGLE_EFFECTS, **_GYRO_EFFECTS},
                {"z": GYRO_DRIFT},
                sources=(
                    _QUARTZ_SOURCE,
                    "gyro drift 0.05 deg/h: Cai et al. 2016 (before calibration), along the platform's polar axis only; "
                    "g-sensitivity 0.001 deg/h/g: issue 25's acceptance world",
                ),
            ),
            World(
                "quartz-gyro",
                "quartz noise and the gyro world's gyro (drift 0.05 deg/h, g-sensitivity 0.001 deg/h/g), nothing else: the "
                "accelerometer noise path with a platform that turns within its dwells",
                _quartz(),
                _GYRO_EFFECTS,
                {a: GYRO_DRIFT for a in "xyz"},
                sources=(_QUARTZ_SOURCE, "gyro: as the 'gyro' world"),
            ),
        )
    }
)


def world(name: str, *, source: str | None = None, field: str = "world") -> World:
    """Return the world named ``name`` (:class:`InputError` naming ``source`` and ``field`` and listing the names otherwise)."""
    if name not in WORLDS:
        raise InputError(f"unknown world {name!r}", path=source, field=field, expected=", ".join(WORLDS))
    return WORLDS[name]


def apply_world(truth: Truth, name: str | World) -> Truth:
    """Return ``truth`` in the world ``name`` (:meth:`World.apply`)."""
    return (world(name) if isinstance(name, str) else name).apply(truth)
