"""A second, independent generator of system-level records (one static day), written from the documentation alone.

It imports nothing from ``stableins``.  Sources, and only these: docs/conventions.md (frames, gimbal chain, Eq. 5/6
error model, the platform during a system-level day, the platform's drift rate, the gauge of θ10, attitude errors,
Earth constants), docs/formats.md ("System-level records", "HDF5 layout", "Header document and site metadata",
"Calibration records"), docs/system-calibration.md (§0–§3: geometry, the combined coefficients, the damping loop;
§8: the K2 terms; §9: the drift the record sees), docs/simulator.md ("Error dynamics", "Noise") and
docs/device-calibration.md ("Gauge").  Where the truth simulator's method is known, this one uses another:

* **platform**: the attitude ``C_{n0}^p(t) = X(t) C_{n0}^{p0}`` with ``X`` composed step by step from the gyro error
  rate ``w = −(ε^p + D_g f^p)`` (frame rotations, midpoint rule on a 1-s grid, the rotation vector interpolated
  between), then ``C_n^p(t) = C_{n0}^p(t) exp(Ω t [u×])``; the readings are the exact inverse kinematics of
  ``C_b^p = R3(s1 α1) R1(s2 α2) R2(s3 α3)`` minus the true zero offsets, plus white angle noise;
* **navigation computer**: the outputs compensated with the installed calibration (Eq. 8 inverted exactly by the matrix
  inverse of Eq. 5), ``Δf^n = C_p^n (f̂^p − f^p)`` averaged over each second (the computer's Δv per second) and the
  linear error dynamics of docs/simulator.md (horizontal damping ``c = 2ζω_s``, third-order vertical loop) stepped by
  the matrix exponential of the augmented system (Van Loan) on the 1-s grid, held between; output attitude
  ``C_b^{n'} = (I − [φ×]) C_p^n Ĉ_b^p`` with ``Ĉ_b^p`` from the measured readings plus the installed offsets, its 3-2-1
  Euler angles; velocity outputs the velocity errors;
* **noise** per axis: white ``N √rate``; flicker by Kasdin's fractional-difference filter (α = 1, two-sided PSD
  ``B²/(2πf)``; Kasdin 1995, Proc. IEEE 83(5) Eq. 116) run over a history of ``flicker_history`` seconds before the
  record (a 1/f process that started then: not the simulator's Gauss-Markov bank nor the device generator's FFT);
  random walk ``K √dt`` increments from the record's start; quantization of the accumulated Δv to whole LSBs with the
  remainder carried;
* **files**: the HDF5 record written with h5py from docs/formats.md (only ``header`` and ``/columns``, the minimum a
  file "made by other tools" needs: no ``/overview`` nor ``/time_grid``), the installed calibration as a
  ``stableins-calibration-record`` JSON written from docs/formats.md, and ``truth-independent-system.json``: the
  parameters in the record's gauge (θ10 = 0), the combined coefficients of docs/system-calibration.md §1–§2 (first
  order; the K2 terms of §8 apart; ``estimate_k2``: what ``--estimate-k2`` reports, x1 keeping its K2_z term) and
  the gyro drift the record sees (§9).

Use::

    python benchmarks/worlds/independent_system.py --seed 1 --out DIR [--rate 1] [--bias-instability 2e-5] ...
    stableins check DIR/system.h5
    stableins calibrate system DIR/system.h5 --prior DIR/installed.json --out DIR/cal.json --estimate-k2 --json
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from scipy.linalg import expm

ARCSEC = math.pi / 648000.0
G0 = 9.80665
MICRO_G = 1e-6 * G0
DEG_PER_HOUR = math.pi / 180.0 / 3600.0
#: WGS-84 (docs/conventions.md, "Earth").
EARTH_RATE = 7.292115e-5
SEMI_MAJOR = 6378137.0
FLATTENING = 1.0 / 298.257223563
GM = 3.986004418e14
#: Mean radius of the Schuler dynamics (docs/conventions.md).
MEAN_RADIUS = 6371000.0
#: One sidereal day [s] (2π / Ω).
SIDEREAL_DAY = 2.0 * math.pi / EARTH_RATE

COLUMNS = (
    ("time", "s", "time since the start of the record"),
    ("angle_platform", "rad", "platform-axis angle-sensor reading"),
    ("angle_inner", "rad", "inner-gimbal angle-sensor reading"),
    ("angle_middle", "rad", "middle-gimbal angle-sensor reading"),
    ("f_x", "m/s^2", "x accelerometer output"),
    ("f_y", "m/s^2", "y accelerometer output"),
    ("f_z", "m/s^2", "z accelerometer output"),
    ("velocity_north", "m/s", "INS north velocity output"),
    ("velocity_east", "m/s", "INS east velocity output"),
    ("velocity_down", "m/s", "INS down velocity output"),
    ("roll", "rad", "INS roll output"),
    ("pitch", "rad", "INS pitch output"),
    ("heading", "rad", "INS heading output"),
    ("temperature", "degC", "instrument temperature"),
)

CORE_IDS = (
    "sf_x", "sf_y", "sf_z", "bias_x", "bias_y", "bias_z",
    "beta_xy", "beta_xz", "beta_yx", "beta_yz", "beta_zx", "beta_zy",
    "K2_x", "K2_y", "K2_z", "theta10", "theta20", "theta30",
)  # fmt: skip
UNITS = {"sf": "1", "bias": "m/s^2", "beta": "rad", "K2": "s^2/m", "theta": "rad", "Dg": "rad s/m"}


def _kind(key: str) -> str:
    """``sf``, ``bias``, ``beta``, ``K2``, ``theta`` of a core parameter id."""
    return "theta" if key.startswith("theta") else key.split("_")[0]


def r1(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, s], [0.0, -s, c]])


def r2(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]])


def r3(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])


def skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def frame_rotations(phi: np.ndarray) -> np.ndarray:
    """``exp(−[φ×])`` for each row of ``phi`` (n, 3): the frame turned right-handedly by ``φ`` (Rodrigues), (n, 3, 3)."""
    angle = np.linalg.norm(phi, axis=1)
    k = np.zeros((len(phi), 3, 3))
    k[:, 0, 1], k[:, 0, 2], k[:, 1, 2] = -phi[:, 2], phi[:, 1], -phi[:, 0]
    k[:, 1, 0], k[:, 2, 0], k[:, 2, 1] = phi[:, 2], -phi[:, 1], phi[:, 0]
    small = angle < 1e-8
    safe = np.where(small, 1.0, angle)
    a = np.where(small, 1.0 - angle**2 / 6.0, np.sin(angle) / safe)[:, None, None]
    b = np.where(small, 0.5 - angle**2 / 24.0, (1.0 - np.cos(angle)) / safe**2)[:, None, None]
    return np.eye(3) - a * k + b * (k @ k)


def normal_gravity(latitude: float, height: float) -> float:
    """Somigliana's normal gravity with the second-order height term (NIMA TR8350.2 Eqs. 4-1 and 4-3)."""
    a, f, omega = SEMI_MAJOR, FLATTENING, EARTH_RATE
    b = a * (1.0 - f)
    e2 = 1.0 - (b / a) ** 2
    gamma_e, gamma_p = 9.7803253359, 9.8321849378
    k = (b * gamma_p) / (a * gamma_e) - 1.0
    s2 = math.sin(latitude) ** 2
    gamma = gamma_e * (1.0 + k * s2) / math.sqrt(1.0 - e2 * s2)
    m = omega**2 * a**2 * b / GM
    return gamma * (1.0 - 2.0 / a * (1.0 + f + m - 2.0 * f * s2) * height + 3.0 / a**2 * height**2)


@dataclass(frozen=True)
class Unit:
    """The instrument (physical truth, SI, ids of docs/conventions.md) and its installed calibration."""

    true: Mapping[str, float]
    installed: Mapping[str, float]
    installed_sigma: Mapping[str, float]
    senses: tuple[int, int, int, int] = (1, 1, 1, 1)

    @staticmethod
    def value(p: Mapping[str, float], key: str) -> float:
        return float(p.get(key, 1.0 if key.startswith("sf_") else 0.0))


def installation(p: Mapping[str, float]) -> np.ndarray:
    """``C_p^a`` (Eq. 5, docs/conventions.md)."""
    b = lambda k: Unit.value(p, k)  # noqa: E731
    return np.array([[1.0, b("beta_xz"), -b("beta_xy")], [-b("beta_yz"), 1.0, b("beta_yx")], [b("beta_zy"), -b("beta_zx"), 1.0]])


def forward(p: Mapping[str, float], f_p: np.ndarray) -> np.ndarray:
    """Accelerometer output ``f^a`` (n, 3) for the platform-frame specific force (n, 3): Eq. 6 solved exactly."""
    sf = np.array([Unit.value(p, f"sf_{a}") for a in "xyz"])
    k2 = np.array([Unit.value(p, f"K2_{a}") for a in "xyz"])
    bias = np.array([Unit.value(p, f"bias_{a}") for a in "xyz"])
    w = (f_p @ installation(p).T) / sf
    disc = np.sqrt(1.0 - 4.0 * k2 * w)
    return 2.0 * w / (1.0 + disc) + bias


def inverse(p: Mapping[str, float], f_a: np.ndarray) -> np.ndarray:
    """``f^p`` from the output (Eq. 8): ``C_a^p SF (u − K u²)``, ``u = f^a − δb``, ``C_a^p`` the exact inverse of Eq. 5."""
    sf = np.array([Unit.value(p, f"sf_{a}") for a in "xyz"])
    k2 = np.array([Unit.value(p, f"K2_{a}") for a in "xyz"])
    bias = np.array([Unit.value(p, f"bias_{a}") for a in "xyz"])
    u = f_a - bias
    return ((u - k2 * u**2) * sf) @ np.linalg.inv(installation(p)).T


def chain(alpha: np.ndarray, senses: Sequence[int]) -> np.ndarray:
    """``C_b^p = R3(s1 α1) R1(s2 α2) R2(s3 α3)`` (q = 0) for actual angles ``alpha`` (3,)."""
    s1, s2, s3, _ = senses
    return r3(s1 * alpha[0]) @ r1(s2 * alpha[1]) @ r2(s3 * alpha[2])


def chain_angles(c_bp: np.ndarray, near: np.ndarray) -> np.ndarray:
    """``(a, b, c)`` of ``C_b^p = R3(a) R1(b) R2(c)`` (n, 3, 3), unwrapped along the record from ``near`` (3,).

    Row 2 of ``R3(a) R1(b) R2(c)`` is ``(cos b sin c, −sin b, cos b cos c)``; column 1 is ``(sin a cos b, cos a cos b, ·)``.
    """
    a = np.arctan2(c_bp[:, 0, 1], c_bp[:, 1, 1])
    b = np.arcsin(np.clip(-c_bp[:, 2, 1], -1.0, 1.0))
    c = np.arctan2(c_bp[:, 2, 0], c_bp[:, 2, 2])
    out = np.stack([a, b, c], axis=-1)
    out = np.unwrap(out, axis=0)
    out += 2.0 * math.pi * np.round((near - out[0]) / (2.0 * math.pi))
    return out


def euler_321(c_nb: np.ndarray) -> np.ndarray:
    """(roll, pitch, yaw) of ``C_n^b = R1(roll) R2(pitch) R3(yaw)`` (n, 3, 3)."""
    roll = np.arctan2(c_nb[:, 1, 2], c_nb[:, 2, 2])
    pitch = -np.arcsin(np.clip(c_nb[:, 0, 2], -1.0, 1.0))
    yaw = np.arctan2(c_nb[:, 0, 1], c_nb[:, 0, 0])
    return np.stack([roll, pitch, yaw], axis=-1)


@dataclass(frozen=True)
class Noise:
    """White ``N`` [m/s/√s], flicker ``B`` [m/s²] (PSD B²/(2πf)), random walk ``K`` [m/s²/√s], LSB ``Q`` [m/s]."""

    white: float = 4.5e-4
    bias_instability: float = 2.0 * MICRO_G
    random_walk: float = 1e-7
    quantization: float = 1e-5
    angle: float = 0.2 * ARCSEC
    temperature: float = 0.01
    flicker_history: float = SIDEREAL_DAY


def kasdin_flicker(n: int, history: int, sigma: float, rng: np.random.Generator) -> np.ndarray:
    """``n`` samples (n, 3) of 1/f noise from Kasdin's fractional-difference filter (α = 1) fed by ``history + n``
    white samples of standard deviation ``sigma``; the last ``n`` outputs.

    ``h_0 = 1``, ``h_k = h_{k−1} (k − 1 + α/2)/k``: ``(1 − z⁻¹)^{−α/2}``, whose output PSD is
    ``σ² dt |2 sin(π f dt)|^{−α}`` → ``σ²/(2π f)`` (two-sided) for ``f dt ≪ 1``; ``σ = B`` gives ``B²/(2πf)``.
    """
    total = history + n
    k = np.arange(1, total)
    h = np.concatenate([[1.0], np.cumprod((k - 0.5) / k)])
    size = 1 << int(math.ceil(math.log2(2 * total)))
    white = sigma * rng.standard_normal((total, 3))
    y = np.fft.irfft(np.fft.rfft(white, size, axis=0) * np.fft.rfft(h, size)[:, None], size, axis=0)[:total]
    return y[history:]


def error_dynamics(latitude: float, gravity: float, zeta: float, vertical_time_constant: float) -> tuple[np.ndarray, np.ndarray]:
    """``A`` (9, 9), ``B`` (9, 6) of docs/simulator.md "Error dynamics": states δL, δv_N, δv_E, φ_N, φ_E, φ_D, δh, δv_D,
    b; inputs Δf_N, Δf_E, Δf_D, ε_N, ε_E, ε_D.
    """
    om, r_ = EARTH_RATE, MEAN_RADIUS
    sl, cl, tl = math.sin(latitude), math.cos(latitude), math.tan(latitude)
    ws = math.sqrt(gravity / r_)
    c = 2.0 * zeta * ws
    a_ = 1.0 / vertical_time_constant
    k1, k2, k3 = 2.0 * a_, 2.0 * a_**2 + 2.0 * ws**2, a_**3
    a = np.zeros((9, 9))
    # δL' = δv_N / R
    a[0, 1] = 1.0 / r_
    # δv_N' = Δf_N + g φ_E − 2Ω sinL δv_E − c δv_N
    a[1, 4], a[1, 2], a[1, 1] = gravity, -2.0 * om * sl, -c
    # δv_E' = Δf_E − g φ_N + 2Ω sinL δv_N + 2Ω cosL δv_D − c δv_E
    a[2, 3], a[2, 1], a[2, 7], a[2, 2] = -gravity, 2.0 * om * sl, 2.0 * om * cl, -c
    # φ_N' = −Ω sinL δL − Ω sinL φ_E + δv_E/R − ε_N
    a[3, 0], a[3, 4], a[3, 2] = -om * sl, -om * sl, 1.0 / r_
    # φ_E' = Ω sinL φ_N + Ω cosL φ_D − δv_N/R − ε_E
    a[4, 3], a[4, 5], a[4, 1] = om * sl, om * cl, -1.0 / r_
    # φ_D' = −Ω cosL δL − Ω cosL φ_E − tanL δv_E/R − ε_D
    a[5, 0], a[5, 4], a[5, 2] = -om * cl, -om * cl, -tl / r_
    # δh' = −δv_D − k1 δh
    a[6, 7], a[6, 6] = -1.0, -k1
    # δv_D' = Δf_D − 2Ω cosL δv_E − (2g/R) δh + k2 δh + b
    a[7, 2], a[7, 6], a[7, 8] = -2.0 * om * cl, -2.0 * gravity / r_ + k2, 1.0
    # b' = k3 δh
    a[8, 6] = k3
    b = np.zeros((9, 6))
    b[1, 0], b[2, 1], b[7, 2] = 1.0, 1.0, 1.0
    b[3, 3], b[4, 4], b[5, 5] = -1.0, -1.0, -1.0
    return a, b


@dataclass(frozen=True)
class World:
    """Site, loop, gyro and noise of one record."""

    latitude_deg: float = 40.0
    height: float = 0.0
    rate: float = 1.0
    duration: float = SIDEREAL_DAY
    zeta: float = 0.6
    vertical_time_constant: float = 400.0
    start_angle_deg: float = 30.0  # St0
    gyro_drift_dph: tuple[float, float, float] = (0.001, -0.001, 0.02)
    g_sensitivity_dphg: float = 0.001  # D_g = d·I [°/h/g] (invariant under the θ10 gauge turn)
    g_sensitivity_drawn: bool = False  # the installed D_g drawn about the truth with its σ (else the truth itself)
    noise: Noise = field(default_factory=Noise)

    @property
    def latitude(self) -> float:
        return math.radians(self.latitude_deg)

    @property
    def gravity(self) -> float:
        return normal_gravity(self.latitude, self.height)


def draw_unit(seed: int) -> Unit:
    """Nominal magnitudes of docs/simulator.md "The truth" (100 ppm, 100 µg, 30″, 20 µg/g², 60″); installed = true
    − a residual of 5 ppm, 5 µg, 3″, 5 µg/g², 2″ (the installed σ); the installed θ10 is 0 (the device-level gauge) and
    the installed angles are the true ones turned into that gauge (docs/device-calibration.md "Gauge") minus the
    residual.
    """
    rng = np.random.default_rng([seed, 25, 5])
    nominal = {"sf": 100e-6, "bias": 100 * MICRO_G, "beta": 30 * ARCSEC, "K2": 20 * MICRO_G / G0**2, "theta": 60 * ARCSEC}
    residual = {"sf": 5e-6, "bias": 5 * MICRO_G, "beta": 3 * ARCSEC, "K2": 5 * MICRO_G / G0**2, "theta": 2 * ARCSEC}
    true = {k: (1.0 if k.startswith("sf_") else 0.0) + nominal[_kind(k)] * rng.standard_normal() for k in CORE_IDS}
    gauged = gauge_theta10(true, senses=(1, 1, 1, 1))
    installed, sigma = {}, {}
    for k in CORE_IDS:
        kind = _kind(k)
        if k == "theta10":
            installed[k], sigma[k] = 0.0, 0.0
            continue
        sigma[k] = residual[kind]
        installed[k] = gauged[k] - residual[kind] * rng.standard_normal()
    return Unit(true, installed, sigma)


def gauge_theta10(p: Mapping[str, float], *, senses: Sequence[int]) -> dict[str, float]:
    """The parameters in the θ10 = 0 gauge (docs/device-calibration.md "Gauge", φ = s1·θ10), exact."""
    phi = senses[0] * Unit.value(p, "theta10")
    c, s = math.cos(phi), math.sin(phi)
    v = lambda k: Unit.value(p, k)  # noqa: E731
    kx, ky = c - v("beta_xz") * s, c - v("beta_yz") * s
    out = dict(p)
    out.update(
        beta_xz=(s + v("beta_xz") * c) / kx, beta_xy=v("beta_xy") / kx, sf_x=v("sf_x") / kx,
        beta_yz=(s + v("beta_yz") * c) / ky, beta_yx=v("beta_yx") / ky, sf_y=v("sf_y") / ky,
        beta_zy=v("beta_zy") * c + v("beta_zx") * s, beta_zx=v("beta_zx") * c - v("beta_zy") * s, theta10=0.0,
    )  # fmt: skip
    return out


def combined_coefficients(gauged: Mapping[str, float], installed: Mapping[str, float], latitude: float, gravity: float) -> dict[str, float]:
    """x1..x5, the pitch and roll coefficients (docs/system-calibration.md §1, §2, first order) and the K2 terms (§8)."""
    sl, cl = math.sin(latitude), math.cos(latitude)
    d = {a: (Unit.value(gauged, f"sf_{a}") - Unit.value(installed, f"sf_{a}")) / Unit.value(installed, f"sf_{a}") for a in "xyz"}
    b = {a: (Unit.value(gauged, f"bias_{a}") - Unit.value(installed, f"bias_{a}")) / gravity for a in "xyz"}
    db = {k: Unit.value(gauged, k) - Unit.value(installed, k) for k in CORE_IDS if k.startswith("beta")}
    dk = {a: Unit.value(gauged, f"K2_{a}") - Unit.value(installed, f"K2_{a}") for a in "xyz"}
    big_a = b["x"] - db["beta_xy"] * sl
    big_b = b["y"] + db["beta_yx"] * sl
    out = {
        "x1": -(d["x"] + d["y"]) / 2 * cl**2 - d["z"] * sl**2 + b["z"] * sl,
        "x2": b["x"] - db["beta_xy"] * sl + db["beta_zy"] * sl,
        "x3": b["y"] + db["beta_yx"] * sl - db["beta_zx"] * sl,
        "x4": -(d["x"] - d["y"]) / 2,
        "x5": (db["beta_xz"] - db["beta_yz"]) / 2,
        "theta_1c": -big_a * sl + db["beta_zy"] * cl**2,
        "theta_1s": -big_b * sl - db["beta_zx"] * cl**2,
        "theta_2c": sl * cl * (d["x"] - d["y"]) / 2,
        "theta_2s": sl * cl * (db["beta_yz"] - db["beta_xz"]) / 2,
        "phi_1s": big_a,
        "phi_1c": -big_b,
        "phi_2s": -cl * (d["x"] - d["y"]) / 2,
        "phi_2c": cl * (db["beta_yz"] - db["beta_xz"]) / 2,
    }
    x6, x7 = gravity * dk["x"] / 4, -gravity * dk["y"] / 4
    k2_terms = {
        "x6": x6, "x7": x7, "x1": gravity * dk["z"] * sl**3,
        "x2": 3 * cl**2 * x6, "x3": -3 * cl**2 * x7,
        "theta_1c": -3 * sl * cl**2 * x6, "theta_1s": 3 * sl * cl**2 * x7, "phi_1s": cl**2 * x6, "phi_1c": cl**2 * x7,
    }  # fmt: skip
    # what --estimate-k2 reports: the K2_x, K2_y terms removed, x1's K2_z term kept (not separable, §8)
    reported = {**out, "x1": out["x1"] + k2_terms["x1"]}
    return {"first_order": out, "k2_terms": k2_terms, "estimate_k2": reported}  # type: ignore[dict-item]


def platform_attitude(c_n0p0: np.ndarray, t: np.ndarray, world: World) -> np.ndarray:
    """``C_n^p(t) = X(t) C_{n0}^{p0} exp(Ω t [u×])`` (n, 3, 3): the platform held in inertial space by gyros with errors.

    ``X`` turns the platform at ``w = −(ε^p + D_g f^p)`` (docs/conventions.md, "The platform's drift rate"), composed
    on a 10-s grid (midpoint rule; ``f^p`` turns at Ω, 7e-4 rad a step), the rotation vector interpolated between.
    """
    lat, g = world.latitude, world.gravity
    earth_n = EARTH_RATE * np.array([math.cos(lat), 0.0, -math.sin(lat)])
    gravity_n = np.array([0.0, 0.0, -g])
    eps = np.array(world.gyro_drift_dph) * DEG_PER_HOUR
    dg = world.g_sensitivity_dphg * DEG_PER_HOUR / G0 * np.eye(3)
    step = 10.0
    grid = np.arange(0.0, t[-1] + 2.0 * step, step)
    earth_mid = frame_rotations(np.outer(-(grid[:-1] + step / 2), earth_n))  # exp(Ω t [u×]) at the midpoints
    x = np.eye(3)
    rotvec = np.zeros((len(grid), 3))
    for k in range(len(grid) - 1):
        w = -(eps + dg @ (x @ c_n0p0 @ earth_mid[k] @ gravity_n))
        x = frame_rotations((w * step)[None, :])[0] @ x
        m = x - x.T  # X = exp(−[θ×]) ⇒ vee(X − Xᵀ) = −2 θ sin|θ|/|θ|
        vee = -0.5 * np.array([m[2, 1], m[0, 2], m[1, 0]])
        sn = np.linalg.norm(vee)
        rotvec[k + 1] = vee if sn < 1e-12 else vee * math.asin(min(sn, 1.0)) / sn
    rot_t = np.stack([np.interp(t, grid, rotvec[:, i]) for i in range(3)], axis=-1)
    return frame_rotations(rot_t) @ c_n0p0 @ frame_rotations(np.outer(-t, earth_n))


def accelerometer_outputs(p: Mapping[str, float], f_p: np.ndarray, noise: Noise, rate: float, rng: np.random.Generator) -> np.ndarray:
    """Eq. 6 exactly, then white, flicker and random-walk noise, then Δv quantized to whole LSBs (remainder carried)."""
    n = len(f_p)
    f_a = forward(p, f_p) + noise.white * math.sqrt(rate) * rng.standard_normal((n, 3))
    if noise.bias_instability > 0:
        f_a += kasdin_flicker(n, int(round(noise.flicker_history * rate)), noise.bias_instability, rng)
    if noise.random_walk > 0:
        f_a += np.cumsum(noise.random_walk / math.sqrt(rate) * rng.standard_normal((n, 3)), axis=0)
    if noise.quantization > 0:
        counts = np.floor(np.cumsum(f_a / rate, axis=0) / noise.quantization)
        f_a = np.diff(np.vstack([np.zeros((1, 3)), counts]), axis=0) * noise.quantization * rate
    return f_a


def navigate(inputs: np.ndarray, world: World) -> np.ndarray:
    """States (seconds + 1, 9) of the error dynamics driven by the per-second inputs (seconds, 6), from rest.

    Zero-order hold over each second, exact: ``Φ``, ``Γ`` from the matrix exponential of ``[[A, B], [0, 0]]``.
    """
    a, b = error_dynamics(world.latitude, world.gravity, world.zeta, world.vertical_time_constant)
    aug = np.zeros((15, 15))
    aug[:9, :9], aug[:9, 9:] = a, b
    phi_gamma = expm(aug)
    phi_d, gamma_d = phi_gamma[:9, :9], phi_gamma[:9, 9:]
    state = np.zeros((len(inputs) + 1, 9))
    s_ = np.zeros(9)
    for k in range(len(inputs)):
        s_ = phi_d @ s_ + gamma_d @ inputs[k]
        state[k + 1] = s_
    return state


def simulate(unit: Unit, world: World, seed: int) -> tuple[dict[str, np.ndarray], dict[str, object]]:
    """The record's columns and the truth document."""
    rng = np.random.default_rng([seed, 25, 6])
    lat, g, rate, senses = world.latitude, world.gravity, world.rate, unit.senses
    steps = int(round(rate))
    if abs(steps - rate) > 1e-9 or steps < 1:
        raise ValueError("rate must be a whole number of Hz (the navigation computer steps each second)")
    seconds = int(math.floor(world.duration))
    n = seconds * steps
    t = np.arange(n) / rate
    # platform at t = 0: the polar-alignment readings re-commanded by the installed offsets (docs/conventions.md)
    nominal = np.array([-math.radians(world.start_angle_deg) / senses[0], 0.0, (math.pi / 2 + lat) / senses[2]])
    theta_true = np.array([Unit.value(unit.true, f"theta{i}0") for i in (1, 2, 3)])
    theta_inst = np.array([Unit.value(unit.installed, f"theta{i}0") for i in (1, 2, 3)])
    alpha0 = nominal - theta_inst + theta_true  # actual = reading + θ_i0, reading = nominal − θ̂_i0
    c_np = platform_attitude(chain(alpha0, senses), t, world)  # level, north-pointing base: C_n^b = I
    f_p = c_np @ np.array([0.0, 0.0, -g])
    # gimbal readings: exact inverse kinematics, minus the true offsets, plus angle noise
    sv = np.array(senses[:3], dtype=float)
    readings = chain_angles(c_np, sv * alpha0) * sv - theta_true + world.noise.angle * rng.standard_normal((n, 3))
    f_a = accelerometer_outputs(unit.true, f_p, world.noise, rate, rng)
    # navigation computer: compensation with the installed calibration, Δf^n and ε^n per second, error dynamics
    c_pn = np.transpose(c_np, (0, 2, 1))
    eps = np.array(world.gyro_drift_dph) * DEG_PER_HOUR
    dg = world.g_sensitivity_dphg * DEG_PER_HOUR / G0 * np.eye(3)
    delta_n = np.einsum("nij,nj->ni", c_pn, inverse(unit.installed, f_a) - f_p)
    eps_n = np.einsum("nij,nj->ni", c_pn, eps[None, :] + f_p @ dg.T)
    state = navigate(np.hstack([delta_n, eps_n]).reshape(seconds, steps, 6).mean(axis=1), world)
    held = state[:seconds].repeat(steps, axis=0)  # the computer's output during second k: the state at its start
    c_bn_out = (np.eye(3)[None] - _skews(held[:, 3:6])) @ c_pn @ _chains(readings + theta_inst, senses)
    euler = euler_321(np.transpose(c_bn_out, (0, 2, 1)))
    columns = {
        "time": t,
        **{f"angle_{name}": readings[:, i] for i, name in enumerate(("platform", "inner", "middle"))},
        **{f"f_{a}": f_a[:, i] for i, a in enumerate("xyz")},
        "velocity_north": held[:, 1],
        "velocity_east": held[:, 2],
        "velocity_down": held[:, 7],
        "roll": euler[:, 0],
        "pitch": euler[:, 1],
        "heading": np.unwrap(euler[:, 2]),
        "temperature": 25.0 + world.noise.temperature * rng.standard_normal(n),
    }
    gauged = gauge_theta10(unit.true, senses=senses)
    # §9: ε^p + D_g f̄^p, f̄^p the specific force along the Earth's axis in the platform frame at the start ((0, 0, g sinL)
    # on a polar-aligned platform; here z_p is off the pole by the installed offsets' residuals)
    axis = c_np[0] @ np.array([math.cos(lat), 0.0, -math.sin(lat)])
    seen = eps + dg @ (float(axis @ f_p[0]) * axis)
    seen_gauge = r3(-senses[0] * Unit.value(unit.true, "theta10")) @ seen  # in the θ10 = 0 frame (conventions.md)
    truth: dict[str, object] = {
        "generator": "benchmarks/worlds/independent_system.py",
        "seed": seed,
        "world": {**asdict(world), "gravity": g},
        "parameters_physical": dict(unit.true),
        "parameters_gauge_theta10": gauged,
        "installed": dict(unit.installed),
        "combined": combined_coefficients(gauged, unit.installed, lat, g),
        "gyro_drift_seen": {f"gyro_drift_{a}": float(v) for a, v in zip("xyz", seen_gauge, strict=True)},
        "units": "SI: combined coefficients dimensionless (rad); gyro drift rad/s",
    }
    return columns, truth


def _skews(v: np.ndarray) -> np.ndarray:
    out = np.zeros((len(v), 3, 3))
    out[:, 0, 1], out[:, 0, 2], out[:, 1, 2] = -v[:, 2], v[:, 1], -v[:, 0]
    out[:, 1, 0], out[:, 2, 0], out[:, 2, 1] = v[:, 2], -v[:, 1], v[:, 0]
    return out


def _chains(alpha: np.ndarray, senses: Sequence[int]) -> np.ndarray:
    """``C_b^p`` for each row of actual angles (n, 3), vectorized."""

    def rot(axis: int, a: np.ndarray) -> np.ndarray:
        c, s = np.cos(a), np.sin(a)
        out = np.zeros((len(a), 3, 3))
        i, j = [(1, 2), (2, 0), (0, 1)][axis]
        out[:, axis, axis] = 1.0
        out[:, i, i], out[:, j, j], out[:, i, j], out[:, j, i] = c, c, s, -s
        return out

    s1, s2, s3, _ = senses
    return rot(2, s1 * alpha[:, 0]) @ rot(0, s2 * alpha[:, 1]) @ rot(1, s3 * alpha[:, 2])


def site_metadata(world: World, serial: str) -> dict[str, object]:
    """``metadata`` of the header (docs/formats.md, "Header document and site metadata")."""
    ws = math.sqrt(world.gravity / MEAN_RADIUS)
    a_ = 1.0 / world.vertical_time_constant
    return {
        "serial_number": serial,
        "latitude": {"value": world.latitude_deg, "unit": "deg"},
        "height": {"value": world.height, "unit": "m"},
        "gravity": {"value": world.gravity, "unit": "m/s^2"},
        "gravity_source": "WGS-84 normal gravity (independent generator)",
        "sample_rate": {"value": world.rate, "unit": "Hz"},
        "gimbal_senses": [1, 1, 1, 1],
        "base_attitude": {"value": [0.0, 0.0, 0.0], "unit": "deg", "order": ["yaw", "pitch", "roll"]},
        "reference_temperature": {"value": 25.0, "unit": "degC"},
        "damping": {
            "zeta": {"value": world.zeta, "unit": "1"},
            "omega_s": {"value": ws, "unit": "rad/s"},
            "R": {"value": MEAN_RADIUS, "unit": "m"},
            "gravity": {"value": world.gravity, "unit": "m/s^2"},
            "horizontal_gain": {"value": 2.0 * world.zeta * ws, "unit": "1/s"},
            "vertical_time_constant": {"value": world.vertical_time_constant, "unit": "s"},
            "k1": {"value": 2.0 * a_, "unit": "1/s"},
            "k2": {"value": 2.0 * a_**2 + 2.0 * ws**2, "unit": "1/s^2"},
            "k3": {"value": a_**3, "unit": "1/s^3"},
        },
        "start_time": "2026-03-01T00:00:00+00:00",
        "extra": {"generator": "benchmarks/worlds/independent_system.py"},
    }


def write_record(path: Path, columns: Mapping[str, np.ndarray], metadata: Mapping[str, object]) -> Path:
    """The HDF5 system record of docs/formats.md ("HDF5 layout"): ``header`` and ``/columns`` only."""
    import h5py

    header = {"format": "stableins-system", "schema_version": 1, "metadata": metadata}
    tmp = path.with_name(path.name + ".tmp")
    with h5py.File(tmp, "w") as f:
        f.attrs["format"] = "stableins-system"
        f.attrs["schema_version"] = 1
        f.attrs["rows"] = len(columns["time"])
        f.attrs["complete"] = True
        f.attrs["serial_number"] = metadata["serial_number"]
        f.attrs["header"] = json.dumps(header)
        group = f.create_group("columns")
        for name, unit, meaning in COLUMNS:
            ds = group.create_dataset(name, data=np.asarray(columns[name], dtype=np.float64), chunks=True, maxshape=(None,))
            ds.attrs["unit"] = unit
            ds.attrs["meaning"] = meaning
    tmp.replace(path)
    return path


def calibration_record(unit: Unit, world: World, serial: str, seed: int = 0) -> dict[str, object]:
    """The installed calibration as a ``stableins-calibration-record`` (docs/formats.md "Calibration records").

    Values in the θ10 = 0 gauge (θ10 status ``gauge``); σ the residual's (diagonal covariance); plus ``Dg_ab`` (the
    device-level gyro stage's, σ 1e-5 °/h/g: the truth, or with ``world.g_sensitivity_drawn`` the truth plus that σ times
    a normal draw, seeded by ``seed``).
    """
    created = "2026-02-28T12:00:00+00:00"
    stage = "device-independent"
    dg = world.g_sensitivity_dphg * DEG_PER_HOUR / G0
    entries: list[tuple[str, float, float, str]] = []
    for k in CORE_IDS:
        entries.append((k, unit.installed[k], unit.installed_sigma[k], UNITS[_kind(k)]))
    dg_sigma = 1e-5 * DEG_PER_HOUR / G0
    dg_error = np.random.default_rng([seed, 25, 9]).standard_normal((3, 3)) * dg_sigma if world.g_sensitivity_drawn else np.zeros((3, 3))
    for i, a in enumerate("xyz"):
        for j, b in enumerate("xyz"):
            entries.append((f"Dg_{a}{b}", (dg if a == b else 0.0) + float(dg_error[i, j]), dg_sigma, UNITS["Dg"]))
    parameters = []
    for k, value, sigma, unit_text in entries:
        gauge = k == "theta10"
        parameters.append(
            {
                "id": k,
                "value": value,
                "unit": unit_text,
                "sigma": 0.0 if gauge else sigma,
                "status": "gauge" if gauge else "estimated",
                "determined_by": [] if gauge else [{"stage": stage, "how": "alone"}],
            }
        )
    ids = [p["id"] for p in parameters]
    cov = np.diag([float(p["sigma"]) ** 2 for p in parameters])  # type: ignore[arg-type]
    return {
        "format": "stableins-calibration-record",
        "schema_version": 2,
        "serial_number": serial,
        "parameters": parameters,
        "covariance": {"ids": ids, "unit": "SI: product of the two parameters' units", "matrix": cov.tolist()},
        "calibration": {
            "id": "cal-independent",
            "procedure": "device (independent generator)",
            "software": "independent_system.py",
            "created": created,
            "prior": None,
            "entries": [],
        },  # fmt: skip
        "stages": [
            {
                "id": stage,
                "name": "coarse+fine",
                "calibration": "cal-independent",
                "procedure": "device (independent generator)",
                "software": "independent_system.py",
                "created": created,
                "data_start": created,
                "data_end": created,
                "sample_rate": {"value": 100.0, "unit": "Hz"},
                "inputs": [],
                "settings": {},
                "entries": [],
                "environment": {},
                "fits": [],
                "determined": [],
                "notes": [],
            }
        ],  # fmt: skip
        "site": site_metadata(world, serial),
        "determined": [],
        "notes": ["installed calibration written by benchmarks/worlds/independent_system.py (truth minus a drawn residual)"],
    }


def generate(seed: int, out: Path, world: World) -> dict[str, Path]:
    """Write ``system.h5``, ``installed.json`` and ``truth-independent-system.json`` into ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    serial = f"INDEP-SYS-{seed}"
    unit = draw_unit(seed)
    columns, truth = simulate(unit, world, seed)
    paths = {
        "record": write_record(out / "system.h5", columns, site_metadata(world, serial)),
        "installed": out / "installed.json",
        "truth": out / "truth-independent-system.json",
    }
    paths["installed"].write_text(json.dumps(calibration_record(unit, world, serial, seed), indent=1), encoding="utf-8")
    paths["truth"].write_text(json.dumps(truth, indent=1), encoding="utf-8")
    return paths


def world_from_args(args: argparse.Namespace) -> World:
    noise = Noise(
        args.white, args.bias_instability, args.random_walk, args.quantization, args.angle_noise * ARCSEC, 0.01, args.flicker_history
    )
    return World(
        rate=args.rate,
        duration=args.duration,
        zeta=args.zeta,
        vertical_time_constant=args.vertical_time_constant,
        gyro_drift_dph=tuple(args.gyro_drift),
        g_sensitivity_dphg=args.g_sensitivity,
        noise=noise,
    )


def add_world_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--rate", type=float, default=1.0, help="sample rate [Hz], a whole number")
    parser.add_argument("--duration", type=float, default=SIDEREAL_DAY, help="record length [s] (default one sidereal day)")
    parser.add_argument("--white", type=float, default=4.5e-4, help="N [m/s/sqrt(s)]")
    parser.add_argument("--bias-instability", type=float, default=2 * MICRO_G, help="B [m/s^2] (Kasdin flicker)")
    parser.add_argument("--random-walk", type=float, default=1e-7, help="K [m/s^2/sqrt(s)]")
    parser.add_argument("--quantization", type=float, default=1e-5, help="LSB of the velocity increments [m/s]")
    parser.add_argument("--angle-noise", type=float, default=0.2, help="white angle-sensor noise [arcsec per sample]")
    parser.add_argument("--flicker-history", type=float, default=SIDEREAL_DAY, help="seconds of flicker before the record")
    parser.add_argument("--zeta", type=float, default=0.6, help="horizontal damping ratio of the navigation computer")
    parser.add_argument("--vertical-time-constant", type=float, default=400.0, help="vertical loop time constant [s]")
    parser.add_argument("--gyro-drift", type=float, nargs=3, default=(0.001, -0.001, 0.02), help="ε^p [deg/h]")
    parser.add_argument("--g-sensitivity", type=float, default=0.001, help="D_g on the diagonal [deg/h/g]")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n")[0])
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--out", type=Path, required=True)
    add_world_arguments(parser)
    args = parser.parse_args(argv)
    paths = generate(args.seed, args.out, world_from_args(args))
    print("wrote " + ", ".join(str(p) for p in paths.values()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
