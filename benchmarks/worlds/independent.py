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
* the platform holds the commanded readings exactly (no slew, no settling transient, no gyro drift): the dwell
  starts ``settle`` seconds after the command and lasts ``dwell`` seconds, on one session clock.

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
        w = (c_pa @ f_p) / sf
        u = np.where(k2 != 0.0, 2.0 * w / (1.0 + np.sqrt(np.maximum(1.0 - 4.0 * k2 * w, 0.0))), w)
        return u + bias

    def temperature_at(self, t: np.ndarray) -> np.ndarray:
        p = self.temperature
        out = self.reference_temperature + p.get("amplitude", 0.0) * np.sin(2.0 * math.pi * t / p.get("period", 86400.0))
        if p.get("warmup", 0.0):
            out = out + p["warmup"] * np.exp(-t / p.get("warmup_time_constant", 1800.0))
        return out


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
) -> dict[str, dict[str, np.ndarray]]:
    """Columns per stage: ``stages`` is ``(stage, pass, readings [rad] per position, settle [s], dwell [s])`` in order."""
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
        f = instrument.output(instrument.specific_force_platform(r))[None, :].repeat(count, axis=0)
        f = f + np.outer(temperature - instrument.reference_temperature, instrument.thermal_bias)
        f = f + np.outer(t, instrument.drift_bias)
        f = f + noise.white * math.sqrt(rate) * rng.standard_normal((count, 3)) + slow[index]
        columns = {
            "time": t,
            "stage": np.full(count, stage),
            "pass": np.full(count, pass_number),
            "position": np.full(count, k),
            "time_since_command": t - command_time,
            **{f"command_{g}": np.full(count, r[i]) for i, g in enumerate(("platform", "inner", "middle"))},
            **{f"angle_{g}": np.full(count, r[i]) for i, g in enumerate(("platform", "inner", "middle"))},
            **{f"f_{a}": f[:, i] for i, a in enumerate("xyz")},
            "temperature": temperature,
        }
        target = out.setdefault(stage, {})
        for name, values in columns.items():
            target.setdefault(name, []).append(np.asarray(values))
    return {stage: {name: np.concatenate(parts) for name, parts in cols.items()} for stage, cols in out.items()}


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


def write_csv(path: Path, columns: Mapping[str, np.ndarray], instrument: Instrument, rate: float, procedure: str) -> Path:
    """Write a ``stableins-device`` CSV file as docs/formats.md describes it (header JSON, rows, end marker)."""
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
    columns = session(instrument, stages, rate=args.rate, noise=noise, seed=args.seed)
    args.out.mkdir(parents=True, exist_ok=True)
    write_csv(args.out / "device-coarse.csv", columns["coarse"], instrument, args.rate, "device-coarse")
    write_csv(args.out / "device-fine.csv", columns["fine"], instrument, args.rate, "device-fine")
    truth = {"parameters": dict(instrument.parameters), "noise": noise.__dict__, "gravity": instrument.gravity}
    (args.out / "truth-independent.json").write_text(json.dumps(truth, indent=1), encoding="utf-8")
    print(f"wrote {args.out}/device-coarse.csv, device-fine.csv, truth-independent.json")
    return 0


if __name__ == "__main__":
    sys.exit(main())
