"""Systematic calibration over indexed orientations (issue 18): rank, drift, equivalence, Monte Carlo, speed.

Prints, against the acceptance of issue 18:

1. **Rank** — what two orientations (procedures/system-indexed.toml: 12 h polar-aligned, 12 h with z_p tilted
   60° by an index about the middle gimbal) determine, group by group, and what stays gauge; compared with the
   system stage's 9 of 14 accelerometer combinations (docs/system-calibration.md §4: 7 of the 12 residuals and its
   two mean nuisances).  Target: at least 12 of 14 (10 of 12 residuals), all 12 gyro numbers, gauges named.
2. **Drift** — 0.001 °/h per axis from the 24-h record: within 3σ, 1σ ≤ 1e-4 °/h.
3. **Equivalence** — filter, RTS smoother and batch least squares on the same linear model with zero process
   noise on the parameters: smoothed (at the first step) = filtered final = batch, to 1e-9 relative.
4. **Monte Carlo** — rms of ``(estimate − truth)/σ`` per parameter family over ``--seeds`` seeds (≥ 40): target
   [0.9, 1.1].  Records of ``--mc-hours`` hours (two holds) at 2 Hz; every seed draws a new instrument, residuals,
   base errors and noise.
5. **Speed and memory** — a day at 100 Hz (HDF5) through the whole stage: wall time (target ≤ 60 s on 2 cores)
   and the peak memory of the stage for half a day and a day (flat in record length).

Run: ``nice -n 10 .venv/bin/python benchmarks/bench_systematic.py`` (about 25 min on one core);
``--quick``-like settings: ``--seeds 4 --mc-hours 4 --hours 8 --speed-hours 2``; ``--parts 3`` runs one part (here
the equivalence, a few seconds).
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # small dense algebra: threads only contend on a shared machine

import argparse  # noqa: E402
import math  # noqa: E402
import resource  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from dataclasses import replace  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))
from systematic_world import indexed_record, indexed_truth, true_values, unit_prior  # noqa: E402

from stableins.conventions import DEG_PER_HOUR  # noqa: E402
from stableins.data.chunks import ArraySource  # noqa: E402
from stableins.errormodel import ErrorModel  # noqa: E402
from stableins.estimators.system.loop import DampingLoop  # noqa: E402
from stableins.estimators.systematic import SystematicOptions, systematic_calibration  # noqa: E402
from stableins.estimators.systematic.kalman import batch_least_squares, rts_smooth, run_filter, steps_of  # noqa: E402
from stableins.estimators.systematic.model import Discretization, StateLayout  # noqa: E402
from stableins.estimators.systematic.observations import Linearization, StepBuilder, scan_record  # noqa: E402
from stableins.estimators.systematic.passes import initial_covariance, noise_inputs, prior_mean  # noqa: E402

FAMILIES = {
    "scale factor": ("sf_",),
    "bias": ("bias_",),
    "installation β": ("beta_",),
    "K2": ("K2_",),
    "gyro drift": ("gyro_drift_",),
    "g-sensitivity Dg": ("Dg_",),
}


def rank_and_drift(hours: float, seed: int) -> None:
    """Parts 1 and 2 on one record of ``hours`` (two holds) at 10 Hz."""
    truth = indexed_truth(seed, rate=10.0)
    record = indexed_record(truth, hours * 3600.0, rate=10.0)
    result = systematic_calibration(ArraySource(record), truth.site, unit_prior(truth))
    print(f"== 1. rank: two orientations, {hours:g} h at 10 Hz (seed {seed}) ==")
    print(result.report().split("gyro terms")[0].rstrip())
    accel = next(g for g in result.details.rank if g.group == "accelerometer")
    gyro = next(g for g in result.details.rank if g.group == "gyro")
    print(f"accelerometer residual combinations: {accel.rank} of 12 = {accel.rank + 2} of 14 counted as the system stage counts")
    print("  (compare: the system stage, one polar orientation: 7 of 12 = 9 of 14; target: at least 12 of 14)")
    print(f"gyro numbers (drift 3 + Dg 9): {gyro.rank} of 12 (target: 12 of 12)")
    ids = tuple(t.id for t in result.fit.terms)
    print(f"== 2. drift: 0.001 deg/h per axis, {hours:g} h ==")
    for axis in "xyz":
        k = ids.index(f"gyro_drift_{axis}")
        value, sigma, true = result.fit.values[k], result.fit.sigma[k], true_values(truth, (ids[k],))[0]
        print(
            f"  {ids[k]}: {value / DEG_PER_HOUR:+.7f} ± {sigma / DEG_PER_HOUR:.2e} deg/h, truth {true / DEG_PER_HOUR:+.4f}, "
            f"z = {(value - true) / sigma:+.2f}   (target |z| <= 3, sigma <= 1e-4 deg/h)"
        )


def equivalence() -> None:
    """Part 3: filter, smoother and batch on the same steps (40 min, two holds, observation σ ×100 for conditioning)."""
    truth = indexed_truth(6, rate=2.0)
    record = indexed_record(truth, 2400.0, rate=2.0)
    site = truth.site
    layout = StateLayout(2, (), random_walk=False)
    scan = scan_record(ArraySource(record), site.sample_rate, 1 << 14)
    disc = Discretization.of(DampingLoop.from_metadata(site.damping, site.latitude, site.gravity), 60.0, 30)
    white, quantization, slow = noise_inputs(unit_prior(truth).noise_model)
    lin = Linearization(dict(truth.installed_calibration), ErrorModel.standard(nonlinear=True))
    builder = StepBuilder(site, scan, lin, step=60.0, substeps=30, noise=(white, quantization, 0))
    steps = [replace(s, R=s.R * 1e4) for s in steps_of(builder.batches(ArraySource(record), 1 << 14), layout, disc, (slow[0], slow[1][:0]))]
    prior = unit_prior(truth)
    x0, p0 = prior_mean(layout, prior), initial_covariance(layout, prior, SystematicOptions(), diffuse=False)
    run = run_filter(steps, x0, p0, keep_history=True)
    smoothed, _ = rts_smooth(run)
    batch, _ = batch_least_squares(steps, x0, p0)
    record_slice = slice(layout.accelerometer.start, layout.gyro.stop)
    final = run.x[record_slice]
    size = np.abs(final).max()
    print("== 3. equivalence: zero process noise on the parameters, loop white noise on ==")
    print(f"  smoothed (first step) vs filtered final: {np.abs(smoothed[0][record_slice] - final).max() / size:.2e} relative (target 1e-9)")
    print(f"  batch least squares vs filtered final:   {np.abs(batch[record_slice] - final).max() / size:.2e} relative (target 1e-9)")


def monte_carlo(seeds: int, hours: float) -> None:
    """Part 4."""
    z: dict[str, list[float]] = {name: [] for name in FAMILIES}
    start = time.time()
    for seed in range(1, seeds + 1):
        truth = indexed_truth(100 + seed, rate=2.0)
        record = indexed_record(truth, hours * 3600.0, rate=2.0)
        result = systematic_calibration(ArraySource(record), truth.site, unit_prior(truth))
        ids = tuple(t.id for t in result.fit.terms)
        scores = (result.fit.values - true_values(truth, ids)) / result.fit.sigma
        for name, prefixes in FAMILIES.items():
            z[name] += [float(s) for i, s in zip(ids, scores, strict=True) if i.startswith(prefixes)]
    print(f"== 4. Monte Carlo: {seeds} seeds, {hours:g} h records at 2 Hz ({time.time() - start:.0f} s) ==")
    for name, values in z.items():
        rms = math.sqrt(float(np.mean(np.square(values))))
        print(f"  {name:<18} rms z = {rms:.3f} over {len(values)} values (target [0.9, 1.1]); max |z| = {np.max(np.abs(values)):.2f}")


STAGE = """
import sys, time, resource
from stableins.data.system import open_system_record
from stableins.estimators.systematic import systematic_calibration
sys.path.insert(0, {tests!r})
from systematic_world import indexed_truth, unit_prior
record = open_system_record({path!r})
truth = indexed_truth({seed}, rate=100.0)
start = time.time()
result = systematic_calibration(record, record.metadata, unit_prior(truth))
print(time.time() - start, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0, result.details.passes)
"""


def speed(hours: float, seed: int) -> None:
    """Part 5: records of ``hours`` and ``hours/2`` at 100 Hz written to HDF5, the stage in a fresh process."""
    from systematic_world import turns

    from stableins.data.system import SystemRecordWriter
    from stableins.simulator.indexing import indexed_record_chunks

    print(f"== 5. speed and memory at 100 Hz ({os.cpu_count()} cores) ==")
    for duration in (hours * 1800.0, hours * 3600.0):
        truth = indexed_truth(seed, rate=100.0)
        with tempfile.TemporaryDirectory() as folder:
            path = Path(folder) / "system.h5"
            with SystemRecordWriter(path, truth.site) as writer:
                for chunk in indexed_record_chunks(truth, duration, turns(duration), rate=100.0, chunk_samples=1 << 18):
                    writer.append(chunk)
            code = STAGE.format(tests=str(ROOT / "tests"), path=str(path), seed=seed)
            out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True).stdout.split()
        wall, peak, passes = float(out[0]), float(out[1]), int(out[2])
        print(
            f"  {duration / 3600:g} h at 100 Hz ({duration * 100:.3g} samples): {wall:.1f} s wall ({passes} passes), "
            f"peak memory {peak:.0f} MiB   (target: a day in <= 60 s; memory flat in record length)"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hours", type=float, default=24.0, help="record length of parts 1-2 [h] (default 24)")
    parser.add_argument("--seeds", type=int, default=40, help="Monte Carlo seeds (default 40)")
    parser.add_argument("--mc-hours", type=float, default=8.0, help="Monte Carlo record length [h] (default 8)")
    parser.add_argument("--speed-hours", type=float, default=24.0, help="record length of the speed test [h] (default 24)")
    parser.add_argument("--seed", type=int, default=3)
    parser.add_argument(
        "--parts", type=int, nargs="+", choices=(1, 2, 3, 4, 5), default=[1, 2, 3, 4, 5], help="parts to run (1 and 2 run together)"
    )
    args = parser.parse_args()
    if {1, 2} & set(args.parts):
        rank_and_drift(args.hours, args.seed)
    if 3 in args.parts:
        equivalence()
    if 4 in args.parts:
        monte_carlo(args.seeds, args.mc_hours)
    if 5 in args.parts:
        speed(args.speed_hours, args.seed)
    print(f"cpu {resource.getrusage(resource.RUSAGE_SELF).ru_utime:.0f} s")


if __name__ == "__main__":
    main()
