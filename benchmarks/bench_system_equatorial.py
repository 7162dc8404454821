"""An uncompensated gyro drift across z_p at system level: what it does to the coefficients, drift by drift (issue 25).

The world (truth simulator, one sidereal day at 1 Hz, damped INS error dynamics): quartz accelerometer noise, 0.2″
angle noise, the default residuals, an unsurveyed base tilt of 10″ per axis and 2″ once-per-revolution errors on the
three angle sensors (drawn per seed, as ``bench_system_drift.py``), and a constant gyro drift ``--drifts`` °/h across
z_p (direction in the x_p–y_p plane drawn per seed; ``--z`` adds a z_p component).  Per seed the same instrument,
noise and errors without the drift is the reference.

The stage runs twice per drift: with its checks as they are (refused or not, and the message's first words) and with
the static-base and polar checks opened (``velocity_limit``, ``attitude_limit``, ``polar_tolerance``), which measures
what the drift does to the estimate the checks protect.  Printed per drift, over the seeds:

* refused (default checks) and by what;
* z_p's angle from the pole at the record's end, ``|ε_xy| T`` (T = the record);
* with the checks opened: the combined coefficients (x2..x5 and the pitch and roll harmonics) against the drift-free
  run of the same noise, ``Δ/σ``: rms and largest (the drift's own bias, without the noise's scatter), and against the
  truth, rms z (1 expected);
* ``gyro_drift_x/y`` against the truth, rms z.

docs/system-calibration.md §9 ("Across z_p") derives the bias's scaling and reads the achievable drift off this table.

Usage::

    python benchmarks/bench_system_equatorial.py [--seeds 4] [--first 1] [--drifts 0.0012 0.0024 0.005 0.01 0.05]
"""

from __future__ import annotations

import argparse
import math
import time
import warnings
from dataclasses import replace

import numpy as np

from stableins.conventions import ARCSEC, DEG_PER_HOUR, SIDEREAL_DAY
from stableins.data.chunks import ArraySource
from stableins.errors import InputError
from stableins.estimators.system.assembly import residuals_from_parameters
from stableins.estimators.system.separation import COMBINED_COEFFICIENTS, combination_matrix
from stableins.estimators.system.stage import SystemOptions, run_system_stage
from stableins.simulator import system
from stableins.simulator.truth import SimulatedSite, Truth

HARMONIC = [i for i, n in enumerate(COMBINED_COEFFICIENTS) if n not in ("theta_mean", "phi_mean", "x1")]
#: Of :data:`HARMONIC`, the specific-force harmonics x2..x5 (the first four); the rest are pitch and roll's.
FORCE = [k for k, i in enumerate(HARMONIC) if COMBINED_COEFFICIENTS[i].startswith("x")]
#: The checks the drift trips, opened to measure what it does to the estimate behind them.
OPEN = {"velocity_limit": 1e4, "attitude_limit": 1.0, "polar_tolerance": 1.0}


def world(seed: int, drift: float, z: float = 0.0) -> Truth:
    """The seed's laboratory world with ``drift`` [°/h] across z_p (drawn direction) and ``z`` [°/h] along it."""
    rng = np.random.default_rng([seed, 2526])
    effects = {"tilt_north": 10 * ARCSEC * rng.standard_normal(), "tilt_east": 10 * ARCSEC * rng.standard_normal()}
    for gimbal in ("platform", "inner", "middle"):
        effects[f"ang1_{gimbal}_c"] = 2 * ARCSEC * rng.standard_normal()
        effects[f"ang1_{gimbal}_s"] = 2 * ARCSEC * rng.standard_normal()
    direction = rng.uniform(0.0, 2 * math.pi)
    drifts = {"x": drift * math.cos(direction) * DEG_PER_HOUR, "y": drift * math.sin(direction) * DEG_PER_HOUR, "z": z * DEG_PER_HOUR}
    return Truth.draw(seed, site=SimulatedSite(sample_rate=1.0), effects=effects, gyro_drift=drifts)


def run(truth: Truth, seed: int, options: SystemOptions):
    """The stage on the seed's simulated day: its output, or the refusal's message."""
    cols = system.simulate_system(truth, SIDEREAL_DAY, 1.0, seed=seed + 100, earth_angle=0.3 * seed)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            return run_system_stage(ArraySource(cols), truth.site, truth.installed_calibration, options=options)
        except InputError as error:
            return str(error)


def reference(truth: Truth) -> np.ndarray:
    """The true combined coefficients."""
    p = residuals_from_parameters(truth.parameters, truth.installed_calibration, truth.site.gravity)
    return combination_matrix(truth.site.latitude) @ np.r_[p, 0.0, 0.0]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=4)
    parser.add_argument("--first", type=int, default=1)
    parser.add_argument("--drifts", type=float, nargs="*", default=[0.0012, 0.0024, 0.005, 0.01, 0.05], help="across z_p [deg/h]")
    parser.add_argument("--z", type=float, default=0.0, help="drift along z_p as well [deg/h]")
    args = parser.parse_args()
    default, opened = SystemOptions(), replace(SystemOptions(), **OPEN)
    seeds = range(args.first, args.first + args.seeds)
    print(f"one sidereal day at 1 Hz, seeds {args.first}..{args.first + args.seeds - 1}; drift across z_p (direction drawn)"
          f"{f', {args.z:g} deg/h along z_p' if args.z else ''}; checks opened: {OPEN}")  # fmt: skip
    start = time.perf_counter()
    free = {seed: run(world(seed, 0.0, args.z), seed, opened) for seed in seeds}
    for seed, out in free.items():
        if isinstance(out, str):
            raise SystemExit(f"seed {seed}: the drift-free record is refused: {out}")
    z_free = np.concatenate([((free[s].combined.values - reference(world(s, 0.0))) / free[s].combined.sigma)[HARMONIC] for s in seeds])
    print(f"drift-free: combined coefficients rms z {np.sqrt(np.mean(z_free**2)):.3f} over {z_free.size}")
    header = (
        "drift °/h  refused (default checks)                     |ε_xy|T mrad  Δ/σ rms  Δ/σ max  (x2..x5 rms, pitch/roll rms)  "
        "rms z (truth)  gyro_x,y rms z  seconds"
    )
    print(header)
    for drift in args.drifts:
        t0 = time.perf_counter()
        refusals, shifts, z_truth, z_gyro = [], [], [], []
        for seed in seeds:
            truth = world(seed, drift, args.z)
            refused = run(truth, seed, default)
            if isinstance(refused, str):
                refusals.append(refused)
            out = run(truth, seed, opened)
            if isinstance(out, str):
                refusals.append(f"(opened) {out}")
                continue
            shifts.append(((out.combined.values - free[seed].combined.values) / out.combined.sigma)[HARMONIC])
            z_truth.append(((out.combined.values - reference(truth)) / out.combined.sigma)[HARMONIC])
            ids = out.result.ids
            k = [ids.index(f"gyro_drift_{a}") for a in "xy"]
            true = np.array([truth.gyro_drift[a] for a in "xy"])
            turn = truth.parameters["theta10"] - truth.installed_calibration["theta10"]
            true = true + turn * np.array([-true[1], true[0]])  # the record's x_p, y_p (the θ10 residual, docs §9)
            z_gyro.append((out.result.values[k] - true) / out.result.sigma[k])
        turn = drift * DEG_PER_HOUR * SIDEREAL_DAY * 1e3
        d, zt, zg = np.concatenate(shifts), np.concatenate(z_truth), np.concatenate(z_gyro)
        force = np.array(shifts)[:, FORCE]
        level = np.delete(np.array(shifts), FORCE, axis=1)
        what = sorted({r.split("': ", 1)[-1][:40] for r in refusals})
        print(
            f"{drift:<9g}  {len(refusals)}/{args.seeds} {'; '.join(what) or '-':<40} {turn:>12.2f}  {np.sqrt(np.mean(d**2)):>7.3f}  "
            f"{np.abs(d).max():>7.3f}  ({np.sqrt(np.mean(force**2)):.3f}, {np.sqrt(np.mean(level**2)):.3f}){'':<17}  "
            f"{np.sqrt(np.mean(zt**2)):>13.3f}  {np.sqrt(np.mean(zg**2)):>14.3f}  "
            f"{time.perf_counter() - t0:.0f}",
            flush=True,
        )
    print(f"{time.perf_counter() - start:.0f} s")


if __name__ == "__main__":
    main()
