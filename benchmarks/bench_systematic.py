"""Systematic calibration over indexed orientations (issue 18): rank, drift, equivalence, Monte Carlo, speed.

Prints, against the acceptance of issue 18:

1. **Rank** — what two orientations (procedures/system-indexed.toml: 12 h polar-aligned, 12 h with z_p tilted
   60° by an index about the middle gimbal) determine, group by group, and what stays gauge; compared with the
   system stage's 9 of 14 accelerometer combinations (docs/system-calibration.md §4: 7 of the 12 residuals and its
   two mean nuisances).  Target: at least 12 of 14 (10 of 12 residuals), all 12 gyro numbers, gauges named.
2. **Drift** — 0.001 °/h per axis from the 24-h record: within 3σ, 1σ ≤ 1e-4 °/h; then every ``Dg_ab`` with its
   ``z`` and the rms ``z`` of the gyro and accelerometer terms (a model error shows where the day shrinks σ).
3. **Equivalence** — filter, RTS smoother and batch least squares on the same linear model with zero process
   noise on the parameters: smoothed (at the first step) = filtered final = batch, to 1e-9 relative.
4. **Monte Carlo** — rms of ``(estimate − truth)/σ`` per parameter family over ``--seeds`` seeds (≥ 40): target
   [0.9, 1.1].  Records of ``--mc-hours`` hours (two holds) at 2 Hz; every seed draws a new instrument, residuals,
   base errors and noise.  Printed with its sampling σ and, for the accelerometer families, the mean z² split into
   the prior's pull and the data's part against their expectations (:func:`monte_carlo`).  With 40 seeds an rms z
   has a sampling σ of 0.05–0.08, so a correct filter leaves one of the six families outside the band in 56 % of
   campaigns (z drawn with the posterior's correlations); with 200 seeds (σ 0.024–0.038) in 1 %: use
   ``--parts 4 --seeds 200`` or more to test the band.  ``--mc-log FILE`` keeps the per-seed z (resumable).
5. **Speed and memory** — a day at 100 Hz (HDF5) through the whole stage: wall time (target ≤ 60 s on 2 cores)
   and the peak memory of the stage for half a day and a day (flat in record length).
6. **Cross-coupling** — ``SystematicOptions(cross_coupling=True)`` on the record of part 1 with Cai et al. 2016's
   six ``Kcc`` hidden (his Table 3 lab values, µg/g²): what the two orientations determine of the quadratic terms
   (``K2`` and ``Kcc``), which cross-couplings enter the record, and their ``z``.
7. **Cross-coupling Monte Carlo** — ``--seeds`` records of ``--mc-hours`` at 2 Hz with six cross-couplings drawn with
   σ 15 µg/g² hidden: rms z per family with ``cross_coupling=True`` under the quartz noise and under a tenth of it
   (which cross-couplings are written, and their z), and without the option (the unmodelled ``Kcc`` bias the rest).

Run: ``nice -n 10 .venv/bin/python benchmarks/bench_systematic.py`` (about 35 min on one core);
``--quick``-like settings: ``--seeds 4 --mc-hours 4 --hours 8 --speed-hours 2``; ``--parts 3`` runs one part (here
the equivalence, a few seconds), ``--parts 6 7`` the cross-coupling parts.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # small dense algebra: threads only contend on a shared machine

import argparse  # noqa: E402
import json  # noqa: E402
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
from systematic_world import indexed_record, indexed_truth, prior_pull, true_values, unit_prior, with_cross_coupling  # noqa: E402

from stableins.conventions import DEG_PER_HOUR, DEG_PER_HOUR_PER_G  # noqa: E402
from stableins.data.chunks import ArraySource  # noqa: E402
from stableins.errormodel import MICRO_G_PER_G2, ErrorModel  # noqa: E402
from stableins.estimators.system.loop import DampingLoop  # noqa: E402
from stableins.estimators.systematic import SystematicOptions, systematic_calibration  # noqa: E402
from stableins.estimators.systematic.kalman import batch_least_squares, rts_smooth, run_filter, steps_of  # noqa: E402
from stableins.estimators.systematic.model import Discretization, StateLayout  # noqa: E402
from stableins.estimators.systematic.observations import Linearization, StepBuilder, scan_record  # noqa: E402
from stableins.estimators.systematic.passes import initial_covariance, noise_inputs, prior_mean, run_passes  # noqa: E402
from stableins.estimators.systematic.rank import group_rank, resolution  # noqa: E402
from stableins.estimators.systematic.result import build_result  # noqa: E402
from stableins.simulator.noise import NoiseSettings  # noqa: E402

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
    z = (result.fit.values - true_values(truth, ids)) / result.fit.sigma
    print(f"== 2. drift: 0.001 deg/h per axis, {hours:g} h ==")
    for axis in "xyz":
        k = ids.index(f"gyro_drift_{axis}")
        value, sigma, true = result.fit.values[k], result.fit.sigma[k], true_values(truth, (ids[k],))[0]
        print(
            f"  {ids[k]}: {value / DEG_PER_HOUR:+.7f} ± {sigma / DEG_PER_HOUR:.2e} deg/h, truth {true / DEG_PER_HOUR:+.4f}, "
            f"z = {z[k]:+.2f}   (target |z| <= 3, sigma <= 1e-4 deg/h)"
        )
    print("  g-sensitivity (deg/h/g), every term:")
    for k, name in enumerate(ids):
        if name.startswith("Dg_"):
            value, sigma, true = (
                v / DEG_PER_HOUR_PER_G for v in (result.fit.values[k], result.fit.sigma[k], true_values(truth, (name,))[0])
            )
            print(f"  {name}: {value:+.4e} ± {sigma:.2e}, truth {true:+.4f}, z = {z[k]:+.2f}")
    gyro_terms = np.array([i.startswith(("gyro_", "Dg_")) for i in ids])
    for label, chosen in (("gyro", gyro_terms), ("accelerometer", ~gyro_terms)):
        worst = int(np.argmax(np.where(chosen, np.abs(z), -1.0)))
        rms = math.sqrt(float(np.mean(z[chosen] ** 2)))
        print(f"  {label} terms: rms z = {rms:.2f} over {int(chosen.sum())}, max |z| = {abs(z[worst]):.2f} ({ids[worst]})")


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


def monte_carlo(seeds: int, hours: float, log: Path | None = None) -> None:
    """Part 4: rms z per family, its sampling σ, and the z of the accelerometer families split into prior and data.

    Every seed draws its residuals from the device prior, so ``z = (x̂ − t)/σ`` of a term the record determines only
    weakly is mostly the prior's pull ``P P0⁻¹(x0 − t)`` (exact for the linear model: the test
    ``test_estimate_error_is_the_prior_pull_of_the_linear_bayesian_estimator``), whose mean square has the expectation
    ``diag(P P0⁻¹ P)/σ²``; the rest is the data's noise, expected ``1 −`` that.  ``log`` (JSON lines, one per seed)
    keeps the per-seed z as they come; a rerun skips the seeds it holds.
    """
    done: dict[int, dict[str, object]] = {}
    if log is not None and log.exists():
        done = {row["seed"]: row for row in map(json.loads, log.read_text().splitlines())}
    start = time.time()
    rows = []
    for seed in range(101, 101 + seeds):
        if seed not in done:
            done[seed] = _seed_scores(seed, hours)
            if log is not None:
                with log.open("a") as out:
                    out.write(json.dumps(done[seed]) + "\n")
        rows.append(done[seed])
    print(f"== 4. Monte Carlo: {seeds} seeds (101-{100 + seeds}), {hours:g} h records at 2 Hz ({time.time() - start:.0f} s) ==")
    z, pull, expected = (np.array([r[key] for r in rows]) for key in ("z", "pull", "expected"))
    for name, prefixes in FAMILIES.items():
        family = np.array([i.startswith(prefixes) for i in rows[0]["ids"]])
        z2 = z[:, family] ** 2
        rms = math.sqrt(float(z2.mean()))
        spread = float(z2.mean(axis=1).std(ddof=1)) / math.sqrt(len(rows)) / (2 * rms)  # σ of the rms, seeds independent
        line = f"  {name:<18} rms z = {rms:.3f} ± {spread:.3f} over {z2.size} values (target [0.9, 1.1]); max |z| {np.sqrt(z2.max()):.2f}"
        if all(i in rows[0]["held"] for i in np.array(rows[0]["ids"])[family]):  # terms the prior draws the residuals of
            prior, data, share = pull[:, family] ** 2, (z - pull)[:, family] ** 2, float(expected[:, family].mean())
            line += f"; mean z²: prior's pull {prior.mean():.3f} (expected {share:.3f}), data {data.mean():.3f} (expected {1 - share:.3f})"
        print(line)


def _seed_scores(seed: int, hours: float) -> dict[str, object]:
    """One Monte Carlo seed: ids, the ids the prior holds, ``z``, the prior's pull in σ and its expected mean square."""
    truth = indexed_truth(seed, rate=2.0)
    prior = unit_prior(truth)
    result = systematic_calibration(ArraySource(indexed_record(truth, hours * 3600.0, rate=2.0)), truth.site, prior)
    ids = tuple(t.id for t in result.fit.terms)
    true, sigma = true_values(truth, ids), result.fit.sigma
    pull, variance, held = prior_pull(result.fit, prior, true)
    scores = (result.fit.values - true) / sigma
    return {
        "seed": seed,
        "ids": ids,
        "held": [ids[k] for k in held],
        "z": scores.tolist(),
        "pull": (pull / sigma).tolist(),
        "expected": (variance / sigma**2).tolist(),
    }


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
    from stableins.simulator.system import indexed_record_chunks

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


#: Cai et al. 2016's six cross-couplings, his Table 3 lab values (µg/g²; K_axy, K_axz, K_ayx, K_ayz, K_azx, K_azy).
CAI_KCC = {"Kcc_xxy": -2.0, "Kcc_xxz": -22.6, "Kcc_yxy": 7.8, "Kcc_yyz": 16.5, "Kcc_zxz": -0.5, "Kcc_zyz": 1.6}


def cross_coupling(hours: float, seed: int) -> None:
    """Part 6: the six cross-couplings as states on the record of part 1 with Cai's six hidden."""
    truth = with_cross_coupling(indexed_truth(seed, rate=10.0), {k: v * MICRO_G_PER_G2 for k, v in CAI_KCC.items()})
    record = indexed_record(truth, hours * 3600.0, rate=10.0)
    start = time.time()
    prior, options = unit_prior(truth), SystematicOptions(cross_coupling=True)
    passes = run_passes(ArraySource(record), truth.site, prior, options)
    result = build_result(passes, prior, options.step)
    print(f"== 6. cross-coupling: Cai's six as states, {hours:g} h at 10 Hz (seed {seed}, {time.time() - start:.0f} s) ==")
    for group in result.details.rank:
        print(f"  {group.describe()}")
        if group.group == "nonlinearity":
            for d in group.directions:
                print(f"      σ = {d.sigma:8.3g} resolution units: {d.name}")
    # all 21 accelerometer terms together, from the data alone (rank filter, everything else free), resolution units
    layout, scales = passes.layout, passes.layout.scales()
    index = list(range(layout.accelerometer.start, layout.accelerometer.stop))
    block = np.ix_(index, index)
    information = np.linalg.inv(passes.rank.P[block]) - np.linalg.inv(passes.diffuse_covariance[block])
    units = np.array([resolution(layout.names[k]) / scales[k] for k in index])
    joint = group_rank("accelerometer block", layout.accelerometer_ids, information, units)
    print(f"  all accelerometer terms together: {joint.rank} of {len(joint.ids)} determined; the others:")
    for d in joint.gauge:
        print(f"      σ = {d.sigma:8.3g} resolution units: {d.name}")
    covariance = np.linalg.inv(information * np.outer(units, units))
    combinations = {i: {i: 1.0} for i in CAI_KCC}
    combinations |= {f"radial f_{a}·f": {f"K2_{a}": 1.0, **{k: 1.0 for k in CAI_KCC if k[4] != a and a in k[5:]}} for a in "xyz"}
    for name, loading in combinations.items():
        v = np.array([loading.get(i, 0.0) for i in layout.accelerometer_ids])
        v /= np.linalg.norm(v)
        sigma = math.sqrt(v @ covariance @ v)
        print(f"  data alone, every other accelerometer term free: {name} σ = {sigma:.3g} resolution units ({' + '.join(loading)})")
    ids = tuple(t.id for t in result.fit.terms)
    z = (result.fit.values - true_values(truth, ids)) / result.fit.sigma
    for name in CAI_KCC:
        if name in ids:
            k = ids.index(name)
            value, sigma = result.fit.values[k] / MICRO_G_PER_G2, result.fit.sigma[k] / MICRO_G_PER_G2
            print(f"  {name}: {value:+7.2f} ± {sigma:5.2f} µg/g², truth {CAI_KCC[name]:+6.1f}, z = {z[k]:+.2f}  (written to the record)")
        else:
            sigma = result.details.left_out[name] / MICRO_G_PER_G2
            print(f"  {name}: σ {sigma:.1f} µg/g² > 5: not determined, left out of the record (truth {CAI_KCC[name]:+.1f})")
    accel = np.array([not i.startswith(("gyro_", "Dg_")) for i in ids])
    worst = max((k for k in range(len(ids)) if not accel[k]), key=lambda k: abs(z[k]))
    print(
        f"  accelerometer terms written: max |z| = {np.abs(z[accel]).max():.2f}, rms z = {math.sqrt(float(np.mean(z[accel] ** 2))):.3f} "
        f"over {int(accel.sum())}; gyro terms: max |z| = {abs(z[worst]):.2f} ({ids[worst]})"
    )


def cross_coupling_monte_carlo(seeds: int, hours: float) -> None:
    """Part 7."""
    quartz = NoiseSettings.quartz()
    tenth = replace(
        quartz,
        velocity_random_walk=0.1 * quartz.velocity_random_walk,
        bias_instability=0.1 * quartz.bias_instability,
        acceleration_random_walk=0.1 * quartz.acceleration_random_walk,
        quantization=0.1 * quartz.quantization,
    )
    families = {**FAMILIES, "cross-coupling Kcc": ("Kcc_",)}
    runs = (("quartz noise", quartz, True), ("a tenth of it", tenth, True), ("quartz, without the option", quartz, False))
    for label, noise, option in runs:
        z: dict[str, list[float]] = {name: [] for name in families}
        written: dict[str, int] = {}
        start = time.time()
        for seed in range(1, seeds + 1):
            rng = np.random.default_rng(1000 + seed)
            kcc = {i: rng.normal(0.0, 15.0) * MICRO_G_PER_G2 for i in CAI_KCC}
            truth = with_cross_coupling(indexed_truth(200 + seed, rate=2.0, noise=noise), kcc)
            record = indexed_record(truth, hours * 3600.0, rate=2.0)
            result = systematic_calibration(ArraySource(record), truth.site, unit_prior(truth), SystematicOptions(cross_coupling=option))
            ids = tuple(t.id for t in result.fit.terms)
            scores = (result.fit.values - true_values(truth, ids)) / result.fit.sigma
            for name, prefixes in families.items():
                z[name] += [float(s) for i, s in zip(ids, scores, strict=True) if i.startswith(prefixes)]
            for i in ids:
                if i.startswith("Kcc_"):
                    written[i] = written.get(i, 0) + 1
        print(f"== 7. cross-coupling Monte Carlo, {label}: {seeds} seeds, {hours:g} h at 2 Hz ({time.time() - start:.0f} s) ==")
        for name, values in z.items():
            if values:
                rms = math.sqrt(float(np.mean(np.square(values))))
                print(f"  {name:<18} rms z = {rms:.3f} over {len(values)} values; max |z| = {np.max(np.abs(values)):.2f}")
        print(f"  cross-couplings written (of {seeds} seeds): {written or 'none'}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hours", type=float, default=24.0, help="record length of parts 1-2 [h] (default 24)")
    parser.add_argument("--seeds", type=int, default=40, help="Monte Carlo seeds (default 40)")
    parser.add_argument("--mc-hours", type=float, default=8.0, help="Monte Carlo record length [h] (default 8)")
    parser.add_argument("--mc-log", type=Path, help="part 4: JSON lines of the per-seed z (appended as they come; a rerun resumes)")
    parser.add_argument("--speed-hours", type=float, default=24.0, help="record length of the speed test [h] (default 24)")
    parser.add_argument("--seed", type=int, default=3)
    parser.add_argument(
        "--parts", type=int, nargs="+", choices=range(1, 8), default=list(range(1, 8)), help="parts to run (1 and 2 run together)"
    )
    args = parser.parse_args()
    parts = {
        1: lambda: rank_and_drift(args.hours, args.seed),
        3: equivalence,
        4: lambda: monte_carlo(args.seeds, args.mc_hours, args.mc_log),
        5: lambda: speed(args.speed_hours, args.seed),
        6: lambda: cross_coupling(args.hours, args.seed),
        7: lambda: cross_coupling_monte_carlo(args.seeds, args.mc_hours),
    }
    wanted = set(args.parts) | ({1} if 2 in args.parts else set())
    for number, part in parts.items():
        if number in wanted:
            part()
    print(f"cpu {resource.getrusage(resource.RUSAGE_SELF).ru_utime:.0f} s")


if __name__ == "__main__":
    main()
