"""The system-level platform's attitude with gyro drift and g-sensitivity against an ODE integration (issue 25).

The platform turns at ``w = −(ε^p + D_g f^p)`` in its own frame, ``f^p`` of its true orientation
(docs/simulator.md, "System level").  For one configuration, noise off, this integrates ``Ẋ = −[w×] X`` with
``scipy.integrate.solve_ivp`` (DOP853, rtol 1e-13) and prints the largest rotation between it and

* the truth simulator's polar world (``SystemWorld``: ``X = rot(−ε t) Z``, ``Z`` by Bortz with a corrector), and
* the independent generator (``benchmarks/worlds/independent_system.py``: stepwise composition on a 10-s grid),

each with its own start orientation, latitude and gravity, and the scale ``ε_z A T`` of what summing the drift's and
the g-sensitive angles left (``A = g cosL D/Ω`` the wobble; the simulator before issue 25: 1.05e-6 rad for 0.05 °/h on
z_p and 0.001 °/h/g over a sidereal day, measured with this integration on main 7519df0).

Run: ``python benchmarks/bench_system_platform.py [--hours 23.93] [--rate 0.1]``
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp

from stableins.conventions import DEG_PER_HOUR, DEG_PER_HOUR_PER_G, EARTH_RATE, earth_rate_nav, skew
from stableins.platform import rotation_vector
from stableins.simulator.noise import NoiseSettings
from stableins.simulator.system import SystemWorld
from stableins.simulator.truth import Truth

sys.path.insert(0, str(Path(__file__).resolve().parent / "worlds"))
import independent_system as gen  # noqa: E402

#: (ε^p [°/h], D_g on the diagonal [°/h/g]): the gyro-z world's gyro and the gyro world's.
CONFIGURATIONS = (((0.0, 0.0, 0.05), 0.001), ((0.05, 0.05, 0.05), 0.001))


def reference(held, eps: np.ndarray, dg: np.ndarray, gravity: float, t: np.ndarray) -> np.ndarray:
    """``X(t) C_held(t)`` (n, 3, 3) from ``Ẋ = −[w×] X``, ``w = −(ε + D_g X C_held(t) (0, 0, −g))``, DOP853."""

    def rhs(tt: float, y: np.ndarray) -> np.ndarray:
        x = y.reshape(3, 3)
        f = x @ held(tt) @ np.array([0.0, 0.0, -gravity])
        return np.asarray(-skew(-(eps + dg @ f)) @ x).ravel()

    sol = solve_ivp(rhs, (0.0, float(t[-1])), np.eye(3).ravel(), t_eval=t, method="DOP853", rtol=1e-13, atol=1e-16)
    return np.stack([x.reshape(3, 3) @ held(tt) for x, tt in zip(sol.y.T, t, strict=True)])


def simulator_error(eps_dph: tuple[float, float, float], dg_dphg: float, t: np.ndarray, rate: float) -> tuple[float, float]:
    """Largest rotation [rad] between the simulator's polar world and the ODE; and ``ε_z A T``."""
    eps = np.array(eps_dph) * DEG_PER_HOUR
    d = dg_dphg * DEG_PER_HOUR_PER_G
    base = Truth.draw(3, noise=NoiseSettings.quiet())
    truth = base.with_changes(
        installed_calibration=dict(base.parameters), gyro_drift=dict(zip("xyz", eps, strict=True)), effects={f"Dg_{a}{a}": d for a in "xyz"}
    )
    world = SystemWorld(truth, rate=rate)
    dcm = world._g_sensitive_orientation(t)
    axis = skew(earth_rate_nav(world.latitude) / EARTH_RATE)

    def held(tt: float) -> np.ndarray:
        angle = EARTH_RATE * tt
        return np.asarray(world.nav_to_platform_0 @ (np.eye(3) + math.sin(angle) * axis + (1.0 - math.cos(angle)) * axis @ axis))

    ref = reference(held, eps, d * np.eye(3), world.gravity, t)
    error = np.linalg.norm(rotation_vector(dcm @ ref.swapaxes(1, 2)), axis=-1).max()
    wobble = world.gravity * math.cos(world.latitude) * d / EARTH_RATE
    return float(error), float(abs(eps[2]) * wobble * t[-1])


def generator_error(eps_dph: tuple[float, float, float], dg_dphg: float, t: np.ndarray) -> float:
    """Largest rotation [rad] between the independent generator's platform attitude and the ODE."""
    world = gen.World(gyro_drift_dph=eps_dph, g_sensitivity_dphg=dg_dphg)
    lat, g = world.latitude, world.gravity
    start = gen.chain(np.array([0.0, 0.0, math.pi / 2 + lat]), (1, 1, 1, 1))
    c_np = gen.platform_attitude(start, t, world)
    earth_n = EARTH_RATE * np.array([math.cos(lat), 0.0, -math.sin(lat)])

    def held(tt: float) -> np.ndarray:
        return np.asarray(start @ gen.frame_rotations(np.array([-tt * earth_n]))[0])

    eps = np.array(eps_dph) * gen.DEG_PER_HOUR
    ref = reference(held, eps, dg_dphg * gen.DEG_PER_HOUR / gen.G0 * np.eye(3), g, t)
    return float(np.linalg.norm(rotation_vector(c_np @ ref.swapaxes(1, 2)), axis=-1).max())


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n")[0])
    parser.add_argument("--hours", type=float, default=23.9345, help="span [h] (default one sidereal day)")
    parser.add_argument("--rate", type=float, default=0.1, help="the simulator's sample rate [Hz]")
    args = parser.parse_args(argv)
    t0 = time.perf_counter()
    t = np.arange(int(args.hours * 3600.0 * args.rate)) / args.rate
    gen_t = np.arange(0.0, t[-1] + 1e-9, 10.0)
    print(f"platform attitude against DOP853 (rtol 1e-13), {args.hours:g} h, simulator at {args.rate:g} Hz; largest rotation [rad]")
    print(f"{'eps [deg/h]':<22} {'D_g [deg/h/g]':>13} {'simulator':>11} {'independent':>12} {'eps_z A T':>11}")
    for eps, dg in CONFIGURATIONS:
        sim, scale = simulator_error(eps, dg, t, args.rate)
        ind = generator_error(eps, dg, gen_t)
        print(f"{str(eps):<22} {dg:>13g} {sim:>11.2e} {ind:>12.2e} {scale:>11.2e}")
    print(f"({time.perf_counter() - t0:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
