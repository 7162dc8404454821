"""Type B uncertainty budget (issue 13): every sensitivity coefficient against a re-run with its input perturbed.

Prints, with what each is compared against:

1. local gravity, device stages: ``calibrate_device`` re-run with g + 30 mGal on a simulated quartz
   instrument; the scale factors' change against c_g δg = SF δg/g, every other parameter's change in σ;
2. gimbal angle readings: ``fit_joint`` re-run with one dwell's reading moved by 2″, for every third reading;
   the change against P Aᵀ W E δr, in σ;
3. the system stage (synthetic one-day record at 1 Hz): its likelihood's change with g + 30 mGal against
   Λ v; the gyro-drift and ζ sensitivities with steps ×1 and ×4; the record re-made through the Bayesian
   update with a known drift of 1e-5 °/h and of 1e-3 °/h against c δq (linearity over the input's
   uncertainty);
4. with ``--record CAL.json``: the budget of that record (e.g. ``demo-output/calibration.json``), per parameter.

Usage::

    python benchmarks/bench_budget.py [--seed 13] [--record demo-output/calibration.json]
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
import budget_world  # noqa: E402


def sigma_of(record) -> np.ndarray:
    return np.array([p.sigma if p.sigma > 0 else 1.0 for p in record.parameters])


def gravity(world) -> None:
    from stableins.discovery.library import all_terms
    from stableins.estimators.device import calibrate_device
    from stableins.procedures.definition import device_layouts
    from stableins.records import CalibrationRecord
    from stableins.reporting.budget import MGAL, gravity_direction

    truth, dwells, noise, _, record = world
    dg = 30.0 * MGAL
    moved = CalibrationRecord.from_device(
        calibrate_device(dwells, replace(truth.site, gravity=truth.site.gravity + dg), layouts=device_layouts(), noise=noise), truth.site
    )
    direction = gravity_direction(record, all_terms())
    sigma = sigma_of(record)
    print("1. local gravity, device stages: calibrate_device re-run with g + 30 mGal")
    worst = 0.0
    for k, pid in enumerate(record.ids):
        change = moved[pid].value - record[pid].value
        if pid.startswith("sf_"):
            predicted = direction[pid] * dg
            print(f"   {pid}: re-run {change * 1e6:9.4f} ppm   c_g δg = SF δg/g {predicted * 1e6:9.4f} ppm   "
                  f"ratio {change / predicted:.5f}")  # fmt: skip
        else:
            worst = max(worst, abs(change) / sigma[k])
    print(f"   every other parameter: largest |change|/σ = {worst:.2e}   (compared against: 0)")


def angles(world) -> None:
    from stableins.conventions import ARCSEC
    from stableins.estimators.sensitivity import angle_reading_gradients

    base, problem, coarse, fine, options = budget_world.joint(world)
    gradients = angle_reading_gradients(problem, base.values)
    sigma = np.where(base.sigma > 0, base.sigma, 1.0)
    print("2. gimbal angle readings: fit_joint re-run with one dwell's reading moved by 2″ (every third reading)")
    errors, largest = [], []
    for column in range(0, gradients.shape[1], 3):
        j, i = divmod(column, 3)
        refit = budget_world.refit_with_reading_moved(options, coarse, fine, j, i, 2.0 * ARCSEC)
        predicted = base.covariance @ gradients[:, column] * 2.0 * ARCSEC
        errors.append(np.abs((refit.values - base.values - predicted) / sigma).max())
        largest.append(np.abs(predicted / sigma).max())
    print(f"   {len(errors)} readings: largest predicted change {max(largest):.3f} σ; largest |re-run − predicted| {max(errors):.2e} σ")
    print("   (compared against: 0; the change of the Jacobian times noise-sized residuals is neglected, ~1e-4)")


def system(world) -> None:

    from stableins.conventions import DEG_PER_HOUR
    from stableins.estimators.system import sensitivity
    from stableins.estimators.system.stage import SystemOptions
    from stableins.records import RunInfo
    from stableins.reporting.budget import MGAL

    prior = world[4]
    run, meta = budget_world.system_day(prior)
    source, values, covariance = run.source, run.values, run.covariance

    start = time.perf_counter()
    base = run()
    one = time.perf_counter() - start
    start = time.perf_counter()
    as_input = SystemOptions(estimate_gyro_drift=False)  # the drift an input taken as known (its Type B sensitivity)
    found = {s.input: s for s in sensitivity.system_sensitivities(source, meta, values, covariance, as_input, base=base)}
    print(f"3. system stage (synthetic day at 1 Hz): one run {one:.2f} s; {len(found)} sensitivities {time.perf_counter() - start:.2f} s")
    lik = base.result.likelihood
    dg = 30.0 * MGAL
    observed = (run(metadata=replace(meta, gravity=meta.gravity + dg)).result.likelihood.gradient - lik.gradient) / dg
    v = np.array([lik.point[k] / meta.gravity if pid.startswith("sf_") else 0.0 for k, pid in enumerate(lik.ids)])
    predicted = lik.information @ v
    relative = np.abs(observed - predicted).max() / np.abs(predicted).max()
    print(f"   gravity: |re-run − Λ v| / |Λ v| = {relative:.2e}   (compared against: 0)")
    drift, zeta = 4 * sensitivity.DRIFT_STEP, 4 * sensitivity.LOOP_STEP * 0.5
    for name, options, metadata, step in (
        ("gyro_drift.x", SystemOptions(known_gyro_drift=(drift, 0.0, 0.0), estimate_gyro_drift=False), meta, drift),
        ("damping_loop.zeta", SystemOptions(estimate_gyro_drift=False), replace(meta, damping={"zeta": 0.5 + zeta}), zeta),
    ):
        again = (run(options, metadata).result.likelihood.gradient - lik.gradient) / step
        reference = found[name].gradient
        print(f"   {name}: step ×4 against ×1, largest difference {np.abs(again - reference).max() / np.abs(reference).max():.2%} "
              "of the largest component (compared against: < 1 %)")  # fmt: skip
    z = np.abs(found["gyro_drift.z"].gradient).max() / np.abs(found["gyro_drift.x"].gradient).max()
    print(f"   gyro drift along z_p against x_p: {z:.1e}   (compared against: 0, the Earth's axis)")
    record = prior.updated(replace(base.result, sensitivities=tuple(found.values())), RunInfo(procedure="system-static"), site=meta)
    sigma = sigma_of(record)
    p = np.nan_to_num(np.asarray(record.covariance))
    gradient = np.array([found["gyro_drift.x"].gradient[lik.ids.index(i)] if i in lik.ids else 0.0 for i in record.ids])
    for degrees in (1e-5, 1e-3):
        moved = run(SystemOptions(known_gyro_drift=(degrees * DEG_PER_HOUR, 0.0, 0.0), estimate_gyro_drift=False))
        remade = prior.updated(moved.result, RunInfo(procedure="system-static"), site=meta)
        change = np.array([remade[i].value - record[i].value for i in record.ids]) / sigma
        linear = p @ gradient * degrees * DEG_PER_HOUR / sigma
        k = int(np.argmax(np.abs(linear)))
        print(f"   record re-made with a known x drift of {degrees:g} °/h: {record.ids[k]} moves {change[k]:+.3f} σ, "
              f"c δq gives {linear[k]:+.3f} σ (largest |difference| {np.abs(change - linear).max():.3f} σ)")  # fmt: skip
    print("   (compared against: equal in the linear regime; over the input's full uncertainty the stage's coloured-noise")
    print("    model takes part of the drift's response as noise and the record moves less: the linear term is the larger)")


def budget_of(path: str) -> None:
    from stableins.discovery.library import all_terms
    from stableins.records import CalibrationRecord
    from stableins.reporting.budget import GROUPS
    from stableins.reporting.budget_sources import uncertainty_budget

    record = CalibrationRecord.load(path)
    budget = uncertainty_budget(record)
    terms = all_terms()
    print(f"4. budget of {path} (standard uncertainties, engineering units)")
    for s in budget.sources:
        print(f"   {s.group:<14} {s.state:<15} u = {s.uncertainty}; {s.origin}")
    print("   " + f"{'parameter':<10} {'type A':>8} " + " ".join(f"{g[:10]:>10}" for g in GROUPS) + f" {'u_c':>8} {'U (k=2)':>8}")
    for k, pid in enumerate(budget.ids):
        if record[pid].status.value != "estimated":
            continue
        t = terms[pid]

        def eng(x: float, t=t) -> float:
            return float(t.sigma_to_engineering(x))

        parts = " ".join(f"{eng(budget.contributions[g][k]):>10.3f}" for g in GROUPS)
        combined = eng(budget.combined[k])
        print(f"   {pid:<10} {eng(budget.type_a[k]):>8.3f} {parts} {combined:>8.3f} {2 * combined:>8.3f} {t.unit}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=13)
    parser.add_argument("--record", help="also print the budget of this calibration record")
    args = parser.parse_args()
    world = budget_world.device(args.seed)
    gravity(world)
    angles(world)
    system(world)
    if args.record:
        budget_of(args.record)


if __name__ == "__main__":
    main()
