"""The system stage's polar-alignment check (issue 25): false refusals on polar-aligned platforms, refusals of tilted bases.

The world (truth simulator, one sidereal day at 1 Hz): the simulator's quartz noise and 0.2″ angle noise, the default
residuals, a base tilt the survey does not know (``tilt_north``, ``tilt_east``, 10″ each, drawn) and once-per-revolution
angle-sensor errors on the three gimbals (2″ each, drawn): a polar-aligned platform as a laboratory has it.  Cases, per
seed:

* ``clean``: that world (the false-refusal rate of the check, target ≤ 5 %);
* ``z-drift``: plus a gyro drift of ``--drift`` °/h (default 0.05, Cai et al.'s figure before calibration) along z_p,
  sign drawn: measured, not refused (its false-refusal rate);
* ``tilt-T``: the base tilted by ``T`` rad in a drawn direction (the surveyed attitude in the metadata) under a platform
  commanded to the polar-alignment readings of a level base, so z_p misses the pole by about ``T`` (the refusal rate).

Printed per case: refused / records, the largest angle between z_p and the Earth's axis the gimbal readings measure
(median, largest), the platform-axis rate's deviation from the Earth rate (largest |ratio − 1|; the rate check's own
tolerance is 0.05).  The check runs on the stage's own pass (:func:`stableins.estimators.system.stage.record_sums`),
the gimbal fit and :func:`stableins.estimators.system.polar.check_polar_alignment`, as ``calibrate system`` does.

Usage::

    python benchmarks/bench_system_polar.py [--seeds 40] [--first 1] [--drift 0.05] [--tilts 5e-4 2e-3 1.17e-2]
"""

from __future__ import annotations

import argparse
import math
import time
import warnings

import numpy as np

from stableins.conventions import ARCSEC, DEG_PER_HOUR, SIDEREAL_DAY
from stableins.data.chunks import ArraySource
from stableins.errors import InputError
from stableins.estimators.system.gyro_drift import measure_gimbals
from stableins.estimators.system.polar import check_deferred, check_polar_alignment, polar_alignment
from stableins.estimators.system.stage import SystemOptions, record_sums
from stableins.simulator import system
from stableins.simulator.truth import SimulatedSite, Truth


def world(seed: int, *, drift: float = 0.0, tilt: float = 0.0) -> Truth:
    """The seed's polar-aligned laboratory world; ``drift`` [°/h] along z_p, a surveyed base tilt ``tilt`` [rad]."""
    rng = np.random.default_rng([seed, 2525])
    effects = {"tilt_north": 10 * ARCSEC * rng.standard_normal(), "tilt_east": 10 * ARCSEC * rng.standard_normal()}
    for gimbal in ("platform", "inner", "middle"):
        effects[f"ang1_{gimbal}_c"] = 2 * ARCSEC * rng.standard_normal()
        effects[f"ang1_{gimbal}_s"] = 2 * ARCSEC * rng.standard_normal()
    sign = rng.choice([-1.0, 1.0])
    direction = rng.uniform(0.0, 2 * math.pi)
    base = (0.0, tilt * math.cos(direction), tilt * math.sin(direction))  # yaw, pitch, roll
    site = SimulatedSite(sample_rate=1.0, base_attitude=base)
    return Truth.draw(seed, site=site, effects=effects, gyro_drift={"z": sign * drift * DEG_PER_HOUR})


def check(truth: Truth, seed: int, options: SystemOptions) -> tuple[bool, float, float]:
    """Run the stage's pass and polar check on one simulated day: (refused, misalignment [rad], |rate − 1|)."""
    cols = system.simulate_system(truth, SIDEREAL_DAY, 1.0, seed=seed + 100, earth_angle=0.3 * seed)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            sums = record_sums(ArraySource(cols), truth.site, truth.installed_calibration, options)
        except InputError:
            return True, math.nan, math.nan  # refused by the pass's own checks (rate beyond 0.05; without gimbal readings, a moving base)
    gimbal = measure_gimbals(sums, truth.site, truth.installed_calibration, None, latitude=truth.site.latitude)
    polar = None if gimbal is None else polar_alignment(gimbal)
    rate = abs(sums.checks.rate_ratio - 1.0)
    try:
        check_deferred(sums.checks, None, None, options)  # the pass's static-base refusals (no equatorial drift here)
        check_polar_alignment(polar, sums.checks.rate_ratio, options, "bench")
    except InputError:
        return True, math.nan if polar is None else polar.angle, rate
    return False, math.nan if polar is None else polar.angle, rate


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=40)
    parser.add_argument("--first", type=int, default=1)
    parser.add_argument("--drift", type=float, default=0.05, help="z_p gyro drift of the z-drift case [deg/h]")
    parser.add_argument("--tilts", type=float, nargs="*", default=[5e-4, 2e-3, 1.17e-2], help="base tilts [rad]")
    args = parser.parse_args()
    options = SystemOptions()
    cases = {"clean": {}, "z-drift": {"drift": args.drift}} | {f"tilt-{t:g}": {"tilt": t} for t in args.tilts}
    print(
        f"one sidereal day at 1 Hz per record, seeds {args.first}..{args.first + args.seeds - 1}; polar_tolerance "
        f"{options.polar_tolerance:g} rad, rate_tolerance {options.rate_tolerance:g}"
    )
    print(f"{'case':<14} {'refused':>9}  {'median angle':>12} {'largest':>10}  {'largest |rate-1|':>16}  seconds")
    for name, kwargs in cases.items():
        t0 = time.perf_counter()
        results = [check(world(seed, **kwargs), seed, options) for seed in range(args.first, args.first + args.seeds)]
        refused = sum(r[0] for r in results)
        angles = np.array([r[1] for r in results])
        rates = np.array([r[2] for r in results])
        print(
            f"{name:<14} {refused:>4}/{len(results):<4}  {np.nanmedian(angles) * 1e3:>9.4f} mrad {np.nanmax(angles) * 1e3:>7.4f} mrad"
            f"  {np.nanmax(rates):>16.2e}  {time.perf_counter() - t0:.0f}",
            flush=True,
        )


if __name__ == "__main__":
    main()
