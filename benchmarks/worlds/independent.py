"""A second, independent generator of device sessions, written from docs/conventions.md and docs/formats.md alone.

It imports nothing from ``stableins``: the frames, gimbal chain, installation matrix and error model (Eq. 6 solved
exactly) are re-implemented from docs/conventions.md, the files are written byte by byte from docs/formats.md
("Device-level data", "CSV layout", "Header document and site metadata"), and the slow noise is synthesized by a
different method than the simulator's (spectral shaping of white noise by FFT for the flicker floor, instead of a
Gauss-Markov bank).  Its purpose is the cases where the simulator and the estimators could share a mistake: a sign,
a frame, a unit, a column the documents do not define.  ``tests/test_independent_world.py`` checks that the two
generators give the same dwell means on a noise-free instrument (1e-9 relative): the documents are complete.

Physics (docs/conventions.md):

* ``C_n^b = R1(roll) R2(pitch) R3(yaw)``; ``C_b^p = R3(s1 α1) R1(s2 α2) R2(s3 α3) R3(s4 q)``, ``q = 0``,
  ``α_i = r_i + θ_i0``; ``f^p = C_b^p C_n^b (0, 0, −g)``;
* ``C_p^a = [[1, βxz, −βxy], [−βyz, 1, βyx], [βzy, −βzx, 1]]``; ``w = SF⁻¹ C_p^a f^p`` (row-wise);
  ``u = 2w / (1 + √(1 − 4Kw))``; ``f^a = u + δb`` plus additive terms (here the temperature and drift terms
  ``Kt ΔT`` and ``Kd t`` of the simulator's effect table, evaluated as docs/simulator.md defines them);
* the platform reaches the commanded readings at the command (no slew, no settling transient): the dwell starts
  ``settle`` seconds after the command and lasts ``dwell`` seconds, on one session clock;
* with a gyro (:class:`Gyro`; docs/conventions.md, "The platform's drift rate" and "The platform during a dwell",
  mode ``earth_rate``, the one the files' metadata default to): from the command on, the platform turns relative to
  the base at ``ω_bp^p = w + k ∘ ω_ie^p``, ``w = −(ε^p + D_g f^p)``, ``ω_ie^p = C_n^p Ω (cos L, 0, −sin L)``, both at
  the commanded orientation; ``C_b^p(τ) = exp(−[τ ω_bp^p ×]) C_b^p(0)`` (the DCM kinematics ``Ċ = −[ω×] C``), the
  readings are the gimbal angles of ``C_b^p(τ)`` (the 3-1-2 Euler angles of the chain above, the branch nearest the
  command) and ``f^p`` follows the turned platform sample by sample.  Where the gimbal-rate map (``ω_bp^p = J α̇``,
  here by differentiating the chain numerically) has ``cond J > 1e3`` the platform is held to the base; the readings
  carry white noise ``angle_noise`` per sample (default none: then they are the commanded readings).

Noise (per axis, independent): white ``N √rate`` per sample; flicker with two-sided PSD ``B²/(2π f)`` (docs/noise.md
§1) between ``1/(session length)`` and the Nyquist frequency, made by FFT shaping of one white sequence for the whole
session (flat below the lowest frequency); random walk ``K √dt`` increments; no quantization.

Use::

    python benchmarks/worlds/independent.py --seed 1 --out DIR [--bias-instability 2e-5] [--random-walk 1e-7] ...

writes ``DIR/device-coarse.csv`` (two coarse passes of the 18 positions of Wu et al. 2018 Table 1) and
``DIR/device-fine.csv`` (18 fine dwells) and ``DIR/truth-independent.json`` (the parameters, SI), readable by
``stableins calibrate device DIR/device-coarse.csv DIR/device-fine.csv``.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

ARCSEC = math.pi / 648000.0
G0 = 9.80665
MICRO_G = 1e-6 * G0

#: Positions of the coarse and fine stages: (platform, inner, middle) readings [deg], Wu et al. 2018 Table 1 as the
#: shipped procedures list them (device-coarse and device-fine: the same 18 positions).
POSITIONS_DEG = (
    (0, 0, 0), (0, 45, 0), (0, 90, 0), (45, 90, 0), (90, 90, 0), (90, 45, 0),
    (90, 180, 0), (90, 180, -45), (90, 180, -90), (135, 180, -90), (180, 180, -90), (180, 180, -45),
    (180, 225, 0), (135, 270, 0), (90, 315, 0), (90, 0, -45), (45, 0, -90), (0, 0, -135),
)  # fmt: skip


def r1(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, s], [0.0, -s, c]])


def r2(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]])


def r3(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])


@dataclass(frozen=True)
class Instrument:
    """The truth of the independent world (SI), keyed by the parameter ids of docs/conventions.md."""

    parameters: Mapping[str, float]
    gravity: float
    latitude_deg: float = 40.0
    senses: tuple[int, int, int, int] = (1, 1, 1, 1)
    base_attitude: tuple[float, float, float] = (0.0, 0.0, 0.0)  # yaw, pitch, roll [rad]
    thermal_bias: tuple[float, float, float] = (0.0, 0.0, 0.0)  # Kt_bias [m/s²/K]
    drift_bias: tuple[float, float, float] = (0.0, 0.0, 0.0)  # Kd_bias [m/s³]
    reference_temperature: float = 25.0
    temperature: Mapping[str, float] = field(default_factory=dict)  # amplitude, period, warmup, warmup_time_constant

    def value(self, key: str) -> float:
        return float(self.parameters.get(key, 1.0 if key.startswith("sf_") else 0.0))

    def specific_force_platform(self, readings: Sequence[float]) -> np.ndarray:
        """``f^p`` at the commanded readings (platform, inner, middle) [rad]."""
        s1, s2, s3, s4 = self.senses
        a1, a2, a3 = (readings[i] + self.value(f"theta{i + 1}0") for i in range(3))
        yaw, pitch, roll = self.base_attitude
        c_nb = r1(roll) @ r2(pitch) @ r3(yaw)
        c_bp = r3(s1 * a1) @ r1(s2 * a2) @ r2(s3 * a3) @ r3(s4 * 0.0)
        return c_bp @ c_nb @ np.array([0.0, 0.0, -self.gravity])

    def chain(self, readings: Sequence[float]) -> np.ndarray:
        """``C_b^p`` at the readings (platform, inner, middle) [rad]."""
        s1, s2, s3, s4 = self.senses
        a1, a2, a3 = (readings[i] + self.value(f"theta{i + 1}0") for i in range(3))
        return r3(s1 * a1) @ r1(s2 * a2) @ r2(s3 * a3) @ r3(s4 * 0.0)

    def base(self) -> np.ndarray:
        """``C_n^b``."""
        yaw, pitch, roll = self.base_attitude
        return r1(roll) @ r2(pitch) @ r3(yaw)

    def rate_map(self, readings: Sequence[float], step: float = 1e-6) -> np.ndarray:
        """``J``: the platform's rate relative to the base [rad/s] per unit rate of each reading (columns), numerically.

        From ``Ċ_b^p = −[ω×] C_b^p``: ``[ω×] = −Ċ_b^p (C_b^p)ᵀ`` for each reading moved alone (central differences).
        """
        c = self.chain(readings)
        columns = []
        for k in range(3):
            up, down = list(readings), list(readings)
            up[k] += step
            down[k] -= step
            skew = -((self.chain(up) - self.chain(down)) / (2.0 * step)) @ c.T
            columns.append([skew[2, 1], skew[0, 2], skew[1, 0]])
        return np.array(columns).T

    def output(self, f_p: np.ndarray) -> np.ndarray:
        """Noise-free accelerometer output (Eq. 6 solved exactly), before the additive thermal and drift terms."""
        b = self.value
        c_pa = np.array(
            [
                [1.0, b("beta_xz"), -b("beta_xy")],
                [-b("beta_yz"), 1.0, b("beta_yx")],
                [b("beta_zy"), -b("beta_zx"), 1.0],
            ]
        )
        sf = np.array([b("sf_x"), b("sf_y"), b("sf_z")])
        k2 = np.array([b("K2_x"), b("K2_y"), b("K2_z")])
        bias = np.array([b("bias_x"), b("bias_y"), b("bias_z")])
        w = (f_p @ c_pa.T) / sf  # f_p (3,) or (n, 3)
        u = np.where(k2 != 0.0, 2.0 * w / (1.0 + np.sqrt(np.maximum(1.0 - 4.0 * k2 * w, 0.0))), w)
        return u + bias

    def temperature_at(self, t: np.ndarray) -> np.ndarray:
        p = self.temperature
        out = self.reference_temperature + p.get("amplitude", 0.0) * np.sin(2.0 * math.pi * t / p.get("period", 86400.0))
        if p.get("warmup", 0.0):
            out = out + p["warmup"] * np.exp(-t / p.get("warmup_time_constant", 1800.0))
        return out


#: The Earth's rotation rate (WGS-84) [rad/s].
EARTH_RATE = 7.292115e-5
#: Condition number of the gimbal-rate map above which the platform is held to the base (docs/conventions.md).
GIMBAL_LOCK_CONDITION = 1e3


@dataclass(frozen=True)
class Gyro:
    """Gyro errors of the platform: drift ``ε^p`` [rad/s], g-sensitivity ``D_g`` [rad/s per m/s²], torquers' ``k``."""

    drift: tuple[float, float, float] = (0.0, 0.0, 0.0)
    g_sensitivity: tuple[tuple[float, float, float], ...] = ((0.0, 0.0, 0.0),) * 3
    torquer_scale: tuple[float, float, float] = (0.0, 0.0, 0.0)


def frame_rotation(phi: np.ndarray) -> np.ndarray:
    """``exp(−[φ×])`` for each row of ``phi`` (n, 3): the frame turned by ``φ`` (Rodrigues), ``(n, 3, 3)``."""
    angle = np.linalg.norm(phi, axis=1)
    k = np.zeros((len(phi), 3, 3))
    k[:, 0, 1], k[:, 0, 2], k[:, 1, 2] = -phi[:, 2], phi[:, 1], -phi[:, 0]
    k[:, 1, 0], k[:, 2, 0], k[:, 2, 1] = phi[:, 2], -phi[:, 1], phi[:, 0]
    small = angle < 1e-8
    safe = np.where(small, 1.0, angle)
    a = np.where(small, 1.0, np.sin(angle) / safe)[:, None, None]
    b = np.where(small, 0.5, (1.0 - np.cos(angle)) / safe**2)[:, None, None]
    return np.eye(3) - a * k + b * (k @ k)


def gimbal_angles(c_bp: np.ndarray, near: Sequence[float]) -> np.ndarray:
    """The angles ``(s1 α1, s2 α2, s3 α3)`` of ``C_b^p = R3(a) R1(b) R2(c)`` (n, 3, 3), the branch nearest ``near``.

    ``R3(a) R1(b) R2(c)`` has row 2 ``(cos b sin c, −sin b, cos b cos c)`` and column 1 ``(sin a cos b, cos a cos b, ·)``.
    """
    sb = -c_bp[:, 2, 1]
    cb = np.hypot(c_bp[:, 0, 1], c_bp[:, 1, 1])
    first = np.stack([np.arctan2(c_bp[:, 0, 1], c_bp[:, 1, 1]), np.arctan2(sb, cb), np.arctan2(c_bp[:, 2, 0], c_bp[:, 2, 2])], -1)
    second = np.stack([first[:, 0] + math.pi, math.pi - first[:, 1], first[:, 2] + math.pi], -1)  # cos b < 0

    def wrapped(x: np.ndarray) -> np.ndarray:
        return x - 2.0 * math.pi * np.round((x - np.asarray(near)) / (2.0 * math.pi))

    first, second = wrapped(first), wrapped(second)
    pick = np.abs(first - near).sum(axis=1) <= np.abs(second - near).sum(axis=1)
    return np.where(pick[:, None], first, second)


@dataclass(frozen=True)
class Noise:
    """White ``N`` [m/s/√s], flicker ``B`` [m/s²] (PSD B²/(2πf)), random walk ``K`` [m/s²/√s]."""

    white: float = 0.0
    bias_instability: float = 0.0
    random_walk: float = 0.0


def slow_noise(n: int, rate: float, noise: Noise, rng: np.random.Generator) -> np.ndarray:
    """Flicker + random walk for ``n`` samples on one clock, ``(n, 3)``: FFT shaping (flicker), cumulative sums (walk)."""
    out = np.zeros((n, 3))
    if noise.bias_instability > 0:
        size = 1 << int(math.ceil(math.log2(max(n, 2))))
        freqs = np.fft.rfftfreq(size, 1.0 / rate)
        psd = np.zeros_like(freqs)
        psd[1:] = noise.bias_instability**2 / (2.0 * math.pi * freqs[1:])  # two-sided B²/(2πf)
        psd[0] = 0.0
        # white sequence of unit variance → spectral density 1/rate per Hz (two-sided); scale by sqrt(psd · rate)
        white = rng.standard_normal((size, 3))
        spectrum = np.fft.rfft(white, axis=0) * np.sqrt(psd * rate)[:, None]
        out += np.fft.irfft(spectrum, n=size, axis=0)[:n]
    if noise.random_walk > 0:
        out += np.cumsum(rng.standard_normal((n, 3)) * noise.random_walk / math.sqrt(rate), axis=0)
    return out


def session(
    instrument: Instrument,
    stages: Sequence[tuple[str, int, Sequence[Sequence[float]], float, float]],
    *,
    rate: float,
    noise: Noise,
    seed: int,
    gyro: Gyro | None = None,
    angle_noise: float = 0.0,
) -> dict[str, dict[str, np.ndarray]]:
    """Columns per stage: ``stages`` is ``(stage, pass, readings [rad] per position, settle [s], dwell [s])`` in order.

    ``gyro`` turns the platform within each dwell (module docstring); ``angle_noise`` [rad, 1σ per sample] is the
    readings' white noise.  Without either the random streams are those of the generator before they existed.
    """
    rng = np.random.default_rng(seed)
    dt = 1.0 / rate
    plan = []
    clock = 0.0
    for stage, pass_number, readings, settle, dwell in stages:
        for k, r in enumerate(readings, start=1):
            count = int(round(dwell * rate))
            start = int(round((clock + settle) * rate))
            plan.append((stage, pass_number, k, r, clock, start, count))
            clock = (start + count) * dt
    total = plan[-1][5] + plan[-1][6]
    slow = slow_noise(total, rate, noise, rng)
    out: dict[str, dict[str, list[np.ndarray]]] = {}
    for stage, pass_number, k, r, command_time, start, count in plan:
        index = np.arange(start, start + count)
        t = index * dt
        temperature = instrument.temperature_at(t)
        angles = np.broadcast_to(np.asarray(r, dtype=float), (count, 3)).copy()
        if gyro is None:
            f = instrument.output(instrument.specific_force_platform(r))[None, :].repeat(count, axis=0)
        else:
            angles, f_p = _turned(instrument, gyro, r, t - command_time)
            f = instrument.output(f_p)
        f = f + np.outer(temperature - instrument.reference_temperature, instrument.thermal_bias)
        f = f + np.outer(t, instrument.drift_bias)
        f = f + noise.white * math.sqrt(rate) * rng.standard_normal((count, 3)) + slow[index]
        if angle_noise > 0:
            angles = angles + angle_noise * rng.standard_normal((count, 3))
        columns = {
            "time": t,
            "stage": np.full(count, stage),
            "pass": np.full(count, pass_number),
            "position": np.full(count, k),
            "time_since_command": t - command_time,
            **{f"command_{g}": np.full(count, r[i]) for i, g in enumerate(("platform", "inner", "middle"))},
            **{f"angle_{g}": angles[:, i] for i, g in enumerate(("platform", "inner", "middle"))},
            **{f"f_{a}": f[:, i] for i, a in enumerate("xyz")},
            "temperature": temperature,
        }
        target = out.setdefault(stage, {})
        for name, values in columns.items():
            target.setdefault(name, []).append(np.asarray(values))
    return {stage: {name: np.concatenate(parts) for name, parts in cols.items()} for stage, cols in out.items()}


def _turned(instrument: Instrument, gyro: Gyro, readings: Sequence[float], tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Readings (n, 3) and ``f^p`` (n, 3) of a platform held by its gyros ``tau`` [s] after the command (earth_rate)."""
    c_bp = instrument.chain(readings)
    c_np = c_bp @ instrument.base()
    f_p = c_np @ np.array([0.0, 0.0, -instrument.gravity])
    if np.linalg.cond(instrument.rate_map(readings)) > GIMBAL_LOCK_CONDITION:  # held to the base
        return np.broadcast_to(np.asarray(readings, dtype=float), (tau.size, 3)).copy(), np.broadcast_to(f_p, (tau.size, 3)).copy()
    latitude = math.radians(instrument.latitude_deg)
    earth_p = c_np @ (EARTH_RATE * np.array([math.cos(latitude), 0.0, -math.sin(latitude)]))
    w = -(np.asarray(gyro.drift) + np.asarray(gyro.g_sensitivity) @ f_p)
    rate = w + np.asarray(gyro.torquer_scale) * earth_p
    turned = frame_rotation(np.outer(tau, rate)) @ c_bp  # C_b^p(τ)
    s = np.asarray(instrument.senses[:3], dtype=float)
    offsets = np.array([instrument.value(f"theta{i}0") for i in (1, 2, 3)])
    nominal = s * (np.asarray(readings, dtype=float) + offsets)
    angles = gimbal_angles(turned, nominal) * s - offsets  # α_i = s_i (s_i α_i); the reading is α_i − θ_i0
    return angles, (turned @ instrument.base()) @ np.array([0.0, 0.0, -instrument.gravity])


HEADERS = (
    ("time", "time[s]"),
    ("stage", "stage"),
    ("pass", "pass"),
    ("position", "position"),
    ("time_since_command", "time_since_command[s]"),
    ("command_platform", "command_platform[rad]"),
    ("command_inner", "command_inner[rad]"),
    ("command_middle", "command_middle[rad]"),
    ("angle_platform", "angle_platform[rad]"),
    ("angle_inner", "angle_inner[rad]"),
    ("angle_middle", "angle_middle[rad]"),
    ("f_x", "f_x[m/s^2]"),
    ("f_y", "f_y[m/s^2]"),
    ("f_z", "f_z[m/s^2]"),
    ("temperature", "temperature[degC]"),
)


def write_csv(
    path: Path, columns: Mapping[str, np.ndarray], instrument: Instrument, rate: float, procedure: str, *, dwell_mode: str | None = None
) -> Path:
    """Write a ``stableins-device`` CSV file as docs/formats.md describes it (header JSON, rows, end marker).

    ``dwell_mode`` is written into the metadata when given (docs/formats.md: optional, ``earth_rate`` by default).
    """
    yaw, pitch, roll = instrument.base_attitude
    header = {
        "format": "stableins-device",
        "schema_version": 1,
        "end_marker": True,
        "metadata": {
            "serial_number": "INDEPENDENT-1",
            "latitude": {"value": instrument.latitude_deg, "unit": "deg"},
            "height": {"value": 0.0, "unit": "m"},
            "gravity": {"value": instrument.gravity, "unit": "m/s^2"},
            "gravity_source": "independent generator (exact)",
            "sample_rate": {"value": rate, "unit": "Hz"},
            "gimbal_senses": list(instrument.senses),
            "base_attitude": {"value": [math.degrees(yaw), math.degrees(pitch), math.degrees(roll)], "unit": "deg"},
            "reference_temperature": {"value": instrument.reference_temperature, "unit": "degC"},
            "extra": {"procedure": procedure},
        },
    }
    if dwell_mode is not None:
        header["metadata"]["dwell_mode"] = dwell_mode  # type: ignore[index]
    n = len(columns["time"])
    lines = ["# stableins-device data file, format described in docs/formats.md of the stableins sources.", "# BEGIN HEADER"]
    lines += ["# " + line for line in json.dumps(header, indent=2).splitlines()]
    lines += ["# END HEADER", ",".join(h for _, h in HEADERS)]
    for i in range(n):
        row = []
        for name, _ in HEADERS:
            v = columns[name][i]
            row.append(str(v) if isinstance(v, str | np.str_) else repr(int(v)) if name in ("pass", "position") else repr(float(v)))
        lines.append(",".join(row))
    lines.append(f"# END OF DATA: {n} rows")
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def draw_instrument(seed: int, gravity: float = 9.801698) -> Instrument:
    """A random instrument with the nominal magnitudes of docs/simulator.md (100 ppm, 100 µg, 30″, 20 µg/g², 60″)."""
    rng = np.random.default_rng([seed, 2525])
    p: dict[str, float] = {}
    for a in "xyz":
        p[f"sf_{a}"] = 1.0 + 100e-6 * rng.standard_normal()
        p[f"bias_{a}"] = 100 * MICRO_G * rng.standard_normal()
        p[f"K2_{a}"] = 20 * MICRO_G / G0**2 * rng.standard_normal()
    for key in ("beta_xy", "beta_xz", "beta_yx", "beta_yz", "beta_zx", "beta_zy"):
        p[key] = 30 * ARCSEC * rng.standard_normal()
    for key in ("theta10", "theta20", "theta30"):
        p[key] = 60 * ARCSEC * rng.standard_normal()
    return Instrument(p, gravity)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--rate", type=float, default=10.0)
    parser.add_argument("--white", type=float, default=4.5e-4, help="N [m/s/sqrt(s)]")
    parser.add_argument("--bias-instability", type=float, default=2 * MICRO_G, help="B [m/s^2]")
    parser.add_argument("--random-walk", type=float, default=1e-7, help="K [m/s^2/sqrt(s)]")
    parser.add_argument("--thermal", type=float, default=0.0, help="Kt_bias on every axis [m/s^2/K] (with a 4-K warm-up, 1-K daily cycle)")
    parser.add_argument("--drift", type=float, default=0.0, help="Kd_bias on every axis [m/s^3]")
    parser.add_argument("--gyro-drift", type=float, default=0.0, help="gyro drift on every platform axis [deg/h]")
    parser.add_argument("--g-sensitivity", type=float, default=0.0, help="every Dg_ab [deg/h/g]")
    parser.add_argument("--torquer", type=float, default=0.0, help="torquer scale-factor error on every axis [ppm]")
    parser.add_argument("--angle-noise", type=float, default=0.0, help="white angle noise [arcsec per sample]")
    args = parser.parse_args(argv)
    base = draw_instrument(args.seed)
    instrument = Instrument(
        base.parameters,
        base.gravity,
        thermal_bias=(args.thermal, -args.thermal, args.thermal),
        drift_bias=(args.drift, -args.drift, args.drift),
        temperature={"amplitude": 1.0, "warmup": -4.0} if args.thermal else {},
    )
    readings = [tuple(math.radians(v) for v in p) for p in POSITIONS_DEG]
    # the coarse passes re-commanded by −θ20, −θ30 as the zero-offset iteration would (known here: the truth's)
    fine_readings = [(r[0], r[1] - instrument.value("theta20"), r[2] - instrument.value("theta30")) for r in readings]
    stages = [("coarse", 1, readings, 5.0, 20.0), ("coarse", 2, fine_readings, 5.0, 20.0), ("fine", 1, fine_readings, 5.0, 600.0)]
    noise = Noise(args.white, args.bias_instability, args.random_walk)
    gyro = None
    if args.gyro_drift or args.g_sensitivity or args.torquer:
        per_hour = math.pi / 180.0 / 3600.0
        g_sensitivity = args.g_sensitivity * per_hour / G0  # °/h/g → rad/s per m/s² (g = 9.80665 m/s², docs/conventions.md)
        gyro = Gyro((args.gyro_drift * per_hour,) * 3, ((g_sensitivity,) * 3,) * 3, (args.torquer * 1e-6,) * 3)
    columns = session(instrument, stages, rate=args.rate, noise=noise, seed=args.seed, gyro=gyro, angle_noise=args.angle_noise * ARCSEC)
    args.out.mkdir(parents=True, exist_ok=True)
    mode = None if gyro is None else "earth_rate"
    write_csv(args.out / "device-coarse.csv", columns["coarse"], instrument, args.rate, "device-coarse", dwell_mode=mode)
    write_csv(args.out / "device-fine.csv", columns["fine"], instrument, args.rate, "device-fine", dwell_mode=mode)
    truth = {"parameters": dict(instrument.parameters), "noise": noise.__dict__, "gravity": instrument.gravity}
    if gyro is not None:
        truth["gyro"] = {"drift": list(gyro.drift), "g_sensitivity": [list(row) for row in gyro.g_sensitivity],
                         "torquer_scale": list(gyro.torquer_scale), "angle_noise": args.angle_noise * ARCSEC}  # fmt: skip
    (args.out / "truth-independent.json").write_text(json.dumps(truth, indent=1), encoding="utf-8")
    print(f"wrote {args.out}/device-coarse.csv, device-fine.csv, truth-independent.json")
    return 0


if __name__ == "__main__":
    sys.exit(main())
