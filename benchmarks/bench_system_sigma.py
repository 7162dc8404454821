"""Monte Carlo of the system stage's σ: normalized errors z = (estimate − truth)/σ over many seeded simulated days.

For each seed the truth simulator (stableins.simulator.system) draws a world and simulates one sidereal day at 1 Hz;
the stage estimates the combined coefficients (with --estimate-k2, as the default residuals include K2) and the
errors against the truth's combined coefficients are divided by the reported σ.  Worlds:

* ``quartz``: the simulator's default quartz noise (white 46 µg/√Hz, bias instability 2 µg, random walk 1e-7 m/s²/√s,
  quantization, angle noise);
* ``white``: white noise only at the quartz level (46 µg/√Hz) with the angle noise;
* ``white-5e-3``: white noise only, 5e-3 m/s² per sample (the paper's level);
* ``flicker``, ``random-walk``: the simulator's worlds of those names (white + 2 µg flicker; white + 3e-7 m/s²/√s random
  walk).

and two ways of running the stage:

* ``default``: nothing known about the noise (the record alone: the decision on low-frequency noise with its
  false-positive rate, then the maximum-likelihood amplitudes);
* ``datasheet``: the instrument's noise model given (the simulator's own settings as a datasheet ``NoiseModel``);
* ``static``: the instrument's noise model measured on a long static record (``--static-days``, default 7; the
  simulator's noise of the same world, another seed) with an Allan fit as ``stableins noise`` does, in force as the
  record's model (a prior with its intervals);
* ``prior``: the noise model the stage measured on an earlier day of the same instrument (another record of the
  same world, seed + 5000) as the prior, the way ``calibrate system`` uses the model in the calibration record.

Printed per world and mode: rms z per coefficient family (x2–x5, pitch θ, roll φ; target [0.9, 1.1], expected
1 ± 1/√(2N)), the overall rms z of each batch of 40 consecutive seeds, overall, the largest |z| and the fractions
beyond 2 and 3 (Gaussian: 4.6 %, 0.27 %); the fraction of
records in which low-frequency noise is detected (white worlds: the false-positive rate, nominal 5 %; quartz: the
detection power), the likelihood-ratio statistic's quantiles, the factor by which the coloured part raises the variance
of x2, and the measured noise model against the simulator's settings (read here, never by the estimator): white N per
axis, bias instability B and random walk K with the coverage of their 95 % intervals.

With ``--memory``: tracemalloc peaks of the stage on ArraySource records of 1, 2, 4 and 7 days at 1 Hz (the whole
stage with 16384-row chunks, so that the chunk buffers do not grow with the record, and with the default 2^18-row
chunks), and of ``_coloured_covariance`` alone (peak above its start).

Usage::

    python benchmarks/bench_system_sigma.py [--seeds 40] [--first 100] [--worlds quartz white white-5e-3]
                                            [--modes default datasheet prior static] [--days 1] [--memory]
                                            [--static-days 7] [--json FILE] [--pool FILE ...]
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import time
import warnings
from dataclasses import replace

import numpy as np

from stableins.conventions import ARCSEC, SIDEREAL_DAY
from stableins.data.chunks import ArraySource
from stableins.estimators.system import solve, stage
from stableins.estimators.system.assembly import residuals_from_parameters
from stableins.estimators.system.separation import COMBINED_COEFFICIENTS, combination_matrix
from stableins.estimators.system.spectrum import COLOURED_KINDS
from stableins.estimators.system.stage import SystemOptions, run_system_stage
from stableins.estimators.system.whittle import ColouredSource
from stableins.noise import NoiseModel
from stableins.simulator import system
from stableins.simulator.noise import NoiseSettings
from stableins.simulator.truth import SimulatedSite, Truth


def world_noise(name: str) -> NoiseSettings:
    """The noise of a named world of the simulator (stableins.simulator.worlds)."""
    from stableins.simulator.worlds import WORLDS as NAMED

    noise = NAMED[name].noise
    assert noise is not None
    return noise


HARMONIC = [i for i, n in enumerate(COMBINED_COEFFICIENTS) if n not in ("theta_mean", "phi_mean", "x1")]
FAMILIES = {
    "x2-x5": [i for i in HARMONIC if COMBINED_COEFFICIENTS[i].startswith("x")],
    "pitch": [i for i in HARMONIC if COMBINED_COEFFICIENTS[i].startswith("theta")],
    "roll": [i for i in HARMONIC if COMBINED_COEFFICIENTS[i].startswith("phi")],
}
WORLDS = {
    "quartz": NoiseSettings.quartz(),
    "white": NoiseSettings(velocity_random_walk=4.5e-4, angle_noise=0.2 * ARCSEC),
    "white-5e-3": NoiseSettings(velocity_random_walk=5e-3),
    # the slow-noise shapes of bench_worlds (docs/simulator.md "Worlds"), to see them per coefficient and with a datasheet
    "flicker": world_noise("flicker"),
    "random-walk": world_noise("random-walk"),
}


def datasheet(noise: NoiseSettings) -> NoiseModel:
    """The simulator's settings as the instrument's datasheet."""
    return NoiseModel.given(
        noise.velocity_random_walk, noise.bias_instability, noise.acceleration_random_walk, provenance="simulator settings"
    )


#: Length of the long static record of mode ``static`` [sidereal days] (``--static-days``).
STATIC_DAYS = 7.0


def static_noise_model(noise: NoiseSettings, seed: int, days: float) -> NoiseModel:
    """The instrument's noise model measured on a long static record, as ``stableins noise`` does (Allan fit, 95 % intervals).

    The record is the simulator's accelerometer noise alone at 1 Hz (another seed than the calibration day's): on a static
    record ``stableins noise`` removes the slowly turning gravity signal first, which leaves this noise.
    """
    from stableins.estimators.allan import allan_points, fit_allan
    from stableins.noise import NoiseSource
    from stableins.simulator.noise import NoiseGenerator

    samples = NoiseGenerator(noise, 1.0, seed).accelerometer(0, int(days * SIDEREAL_DAY))
    points = allan_points([samples], 1.0, max_fraction=8)
    model, _ = fit_allan(points, source=NoiseSource.STATIC_RECORD, provenance=f"{days:g}-day static record (simulated)")
    return model


def run(seed: int, noise: NoiseSettings, mode: str, days: float = 1.0, static_days: float = STATIC_DAYS) -> stage.SystemCalibration:
    model = datasheet(noise) if mode == "datasheet" else None
    if mode == "zero-datasheet":  # `--bias-instability 0 --random-walk 0`: a datasheet a slow-noise record contradicts
        model = NoiseModel.given(noise.velocity_random_walk, 0.0, 0.0, provenance="datasheet without slow noise")
    if mode == "prior":
        earlier, _ = run(seed + 5000, noise, "default", days)
        model = earlier.noise_model
    if mode == "static":
        model = static_noise_model(noise, seed + 9000, static_days)
    truth = Truth.draw(seed, site=SimulatedSite(sample_rate=1.0), noise=noise)
    cols = system.simulate_system(truth, days * SIDEREAL_DAY, 1.0, seed=seed)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        out = run_system_stage(
            ArraySource(cols), truth.site, truth.installed_calibration, options=SystemOptions(estimate_k2=True), noise_model=model
        )
    p = residuals_from_parameters(truth.parameters, truth.installed_calibration, truth.site.gravity)
    ref = combination_matrix(truth.site.latitude) @ np.r_[p, 0.0, 0.0]
    return out, (out.combined.values - ref) / out.combined.sigma


@contextlib.contextmanager
def without_flicker():
    """Diagnostic (``--without-flicker``): the stage's slow-noise fit with the flicker amplitude left out (random walk only).

    Wraps :func:`stableins.estimators.system.whittle.fit_coloured_noise` as the stage calls it: the design's flicker column
    is dropped (the decision's p-value then from the χ̄² law, not the record's null law), and the fit returned with a flicker
    amplitude of 0.  Not a way to calibrate: it measures how much of the random-walk world's σ error comes from estimating
    a flicker amplitude whose truth is 0, on its boundary (docs/system-calibration.md §10).
    """
    from stableins.estimators.system import coloured

    original = coloured.whittle.fit_coloured_noise
    flicker = COLOURED_KINDS.index("flicker")

    def pad(a: np.ndarray) -> np.ndarray:
        return np.insert(a, flicker, 0.0, axis=0)

    def fit(design, observed, channels, **kwargs):
        kwargs.pop("law", None)
        out = original(np.delete(design, channels + flicker, axis=1), observed, channels, **kwargs)
        return replace(
            out, amplitudes=pad(out.amplitudes), maximum_likelihood=pad(out.maximum_likelihood), lower=pad(out.lower), upper=pad(out.upper)
        )

    coloured.whittle.fit_coloured_noise = fit
    try:
        yield
    finally:
        coloured.whittle.fit_coloured_noise = original


def binomial(k: int, n: int) -> str:
    """``k of n (rate, 95 % Clopper-Pearson interval)``."""
    from scipy.stats import beta

    low = beta.ppf(0.025, k, n - k + 1) if k > 0 else 0.0
    high = beta.ppf(0.975, k + 1, n - k) if k < n else 1.0
    return f"{k} of {n} ({k / n:.3f}; 95 % interval {low:.3f}-{high:.3f})"


def p_value_levels(p_values: np.ndarray, levels: tuple[float, ...] = (0.01, 0.05, 0.1, 0.2, 0.3)) -> str:
    """The slow-noise test's p-values on white records against their null law (uniform): the fraction below each level.

    A test whose level is right has ``P(p < a) = a`` at every ``a`` below the null law's atom at ``p = 1`` (records whose
    maximum is white noise); the fractions at several levels see a liberal or conservative test with more power than the
    count at 5 % alone.
    """
    n = p_values.size
    parts = [f"p < {a:g}: {binomial(int(np.sum(p_values < a)), n)}" for a in levels]
    return "p-values of the slow-noise test (uniform under its null law below its atom at 1): " + "; ".join(parts)


def random_walk_plug_in(used: np.ndarray, random_walk: float, z: np.ndarray, gravity: float = 9.80665) -> str:
    """The random walk's amplitude under σ against the truth, and the rms z a plug-in amplitude gives by itself.

    With ``σ̂² = W + α̂ U`` and the error independent of ``α̂``, ``E z² = E[σ²/σ̂²]``; where the random walk carries nearly
    all of a coefficient's variance (the ``random-walk`` world: x2 ≈ 300× its white value), ``E z² ≈ E[α/α̂]``: the rms z
    that the one-day estimate's scatter and bias alone give, ``√mean(α/α̂)`` over the records with ``α̂ > 0``.
    """
    truth = (random_walk / gravity) ** 2
    ratio = used / truth
    positive = ratio > 0
    zz = z[:, HARMONIC]
    low = positive & (ratio < np.median(ratio[positive])) if positive.any() else positive
    text = f"random walk under sigma / truth (amplitude (K/g)^2): median {np.median(ratio):.2f}, zero in {np.mean(~positive):.2f}"
    if positive.any():
        plug_in = np.sqrt(np.mean(1.0 / ratio[positive]))
        spread = np.percentile(ratio[positive], [5, 95])
        below = np.sqrt(np.mean(zz[low] ** 2)) if low.any() else float("nan")
        above = np.sqrt(np.mean(zz[positive & ~low] ** 2)) if (positive & ~low).any() else float("nan")
        text += (
            f"; sqrt(mean(truth/used)) over the {int(positive.sum())} records with it > 0: {plug_in:.3f} "
            f"(5-95 % of used/truth {spread[0]:.2f}-{spread[1]:.2f}); rms z of the records below the median {below:.3f}, "
            f"above it {above:.3f}"
        )
    return text


def campaign(
    world: str, mode: str, seeds: range, days: float = 1.0, dump: list[dict] | None = None, static_days: float = STATIC_DAYS
) -> None:
    noise = WORLDS[world]
    start = time.perf_counter()
    z, detected, statistic, factor, models, rejected, drawn, p_values, used_rw = [], [], [], [], [], [], [], [], []
    for seed in seeds:
        out, normalized = run(seed, noise, mode, days, static_days)
        z.append(normalized)
        fit = out.coloured_noise
        p_values.append(fit.p_value)
        detected.append(fit.data_detected)
        statistic.append(fit.statistic)
        factor.append(out.diagnostics.z_low_frequency_ratio)
        models.append(out.noise_model)
        rejected.append(fit.source is ColouredSource.CONTRADICTED)
        used_rw.append(float(fit.amplitudes[COLOURED_KINDS.index("random_walk"), 0]))
        drawn.append(fit.null_draws > 0)
    z = np.array(z)
    n = len(seeds)
    print(
        f"{world} noise, {mode}: {n} records of {days:g} sidereal days at 1 Hz x {len(HARMONIC)} coefficients "
        f"({time.perf_counter() - start:.0f} s)"
    )
    families = ", ".join(f"{name} {np.sqrt(np.mean(z[:, idx] ** 2)):.3f}" for name, idx in FAMILIES.items())
    zz = z[:, HARMONIC]
    spread = 1.0 / math.sqrt(2 * len(FAMILIES["x2-x5"]) * n)
    print(f"  rms z per family: {families}   (target [0.9, 1.1]; expected 1 ± {spread:.3f} per family of 4)")
    print(
        f"  overall rms z {np.sqrt(np.mean(zz**2)):.3f}, max |z| {np.abs(zz).max():.1f}, "
        f"|z| > 2: {np.mean(np.abs(zz) > 2):.3f} (Gaussian 0.046), |z| > 3: {np.mean(np.abs(zz) > 3):.4f} (0.0027)"
    )
    if n >= 80:
        batches = [np.sqrt(np.mean(zz[k : k + 40] ** 2)) for k in range(0, n - 39, 20)]
        print(
            "  overall rms z of 40 consecutive seeds (starting every 20): "
            + ", ".join(f"{seeds[0] + 20 * j}-{seeds[0] + 20 * j + 39} {b:.3f}" for j, b in enumerate(batches))
        )
    print("  rms z per coefficient: " + ", ".join(f"{COMBINED_COEFFICIENTS[i]} {np.sqrt(np.mean(z[:, i] ** 2)):.2f}" for i in HARMONIC))
    white_world = noise.bias_instability == 0 and noise.acceleration_random_walk == 0
    expected = "false-positive rate, nominal 0.05" if white_world else "detection power"
    print(
        f"  low-frequency noise detected by the record alone in {binomial(int(np.sum(detected)), n)} of the records ({expected}; "
        f"±{math.sqrt(0.05 * 0.95 / n):.3f} at 0.05); p-value from the record's null law (Monte Carlo) in {int(np.sum(drawn))}; "
        "likelihood ratio quantiles 5/50/95 %: " + "/".join(f"{q:.1f}" for q in np.percentile(statistic, [5, 50, 95]))
    )
    if white_world:
        print("  " + p_value_levels(np.array(p_values)))
    if noise.acceleration_random_walk > 0:
        print("  " + random_walk_plug_in(np.array(used_rw), noise.acceleration_random_walk, z))
    if dump is not None:
        dump.append(
            {
                "world": world,
                "mode": mode,
                "seeds": [seeds[0], seeds[-1]],
                "p_values": [float(p) for p in p_values],
                "detected": [bool(d) for d in detected],
                "rejected": [bool(r) for r in rejected],
                "z": z[:, HARMONIC].tolist(),
            }
        )
    if mode in ("datasheet", "zero-datasheet"):
        what = "false rejections of the true datasheet (target ≤ 0.05)" if mode == "datasheet" else "the contradicted datasheet rejected"
        print(f"  given datasheet rejected by the record in {binomial(int(np.sum(rejected)), n)} of the records ({what})")
    factor = np.array(factor)
    print(
        f"  variance of x2 over its white-noise value: median {np.median(factor):.2f}, 90 % {np.percentile(factor, 90):.2f}, "
        f"max {factor.max():.1f}"
    )
    if mode == "default":
        white = np.array([m.values("white") for m in models])
        low, high = np.array([m.limits("white")[0] for m in models]), np.array([m.limits("white")[1] for m in models])
        truth_n = noise.velocity_random_walk
        covered = np.mean((low <= truth_n) & (truth_n <= high))
        print(
            f"  measured white noise N: median {np.median(white) / 9.80665e-6:.2f} ug/sqrt(Hz) "
            f"(simulator {truth_n / 9.80665e-6:.2f}); 95 % intervals cover it on {covered:.3f} of the axes"
        )
        for name, true in (("bias_instability", noise.bias_instability), ("random_walk", noise.acceleration_random_walk)):
            v = np.array([m.values(name)[0] for m in models])
            lo = np.array([m.limits(name)[0][0] for m in models])
            hi = np.array([m.limits(name)[1][0] for m in models])
            unit, scale = ("ug", 9.80665e-6) if name == "bias_instability" else ("m/s^2/sqrt(s)", 1.0)
            print(
                f"  measured {name}: simulator {true / scale:.3g} {unit}; median {np.median(v) / scale:.3g}, zero in {np.mean(v == 0):.2f} "
                f"of the records; 95 % interval covers the simulator's value in {np.mean((lo <= true) & (true <= hi)):.2f}, "
                f"median upper limit {np.median(hi) / scale:.3g}"
            )


def pool(paths: list[str]) -> None:
    """Pool the --json files of several runs per world and mode: decisions, rejections and the p-values against uniform."""
    runs: dict[tuple[str, str], list[dict]] = {}
    for path in paths:
        with open(path) as f:
            for run_ in json.load(f):
                runs.setdefault((run_["world"], run_["mode"]), []).append(run_)
    for (world, mode), parts in runs.items():
        seeds = ", ".join(f"{r['seeds'][0]}-{r['seeds'][1]}" for r in parts)
        p_values = np.concatenate([r["p_values"] for r in parts])
        detected = int(sum(sum(r["detected"]) for r in parts))
        zz = np.concatenate([np.array(r["z"]) for r in parts])
        print(f"{world}, {mode}: seeds {seeds} ({p_values.size} records); overall rms z {np.sqrt(np.mean(zz**2)):.3f}")
        print(f"  slow noise detected in {binomial(detected, p_values.size)}")
        if mode in ("datasheet", "zero-datasheet"):
            print(f"  given datasheet rejected in {binomial(int(sum(sum(r['rejected']) for r in parts)), p_values.size)}")
        print("  " + p_value_levels(p_values))


def memory(days_list: tuple[int, ...] = (1, 2, 4, 7)) -> None:
    """Tracemalloc peaks of the stage and of its coloured-noise model against the record length (1 Hz)."""
    import tracemalloc

    truth = Truth.draw(100, site=SimulatedSite(sample_rate=1.0))
    original = solve.coloured_covariance
    peaks: dict[str, float] = {}

    def traced(*args, **kwargs):  # peak of the coloured-noise model above the memory in use when it starts
        start = tracemalloc.get_traced_memory()[0]
        tracemalloc.reset_peak()
        result = original(*args, **kwargs)
        peaks["coloured"] = tracemalloc.get_traced_memory()[1] - start
        return result

    print("memory (tracemalloc peak, MiB): record | stage, 16384-row chunks | stage, 2^18-row chunks | coloured_covariance")
    for days in days_list:
        source = ArraySource(system.simulate_system(truth, days * SIDEREAL_DAY, 1.0, seed=100))
        row = []
        for rows in (1 << 14, 1 << 18):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                tracemalloc.start()
                run_system_stage(source, truth.site, truth.installed_calibration, options=SystemOptions(estimate_k2=True, chunk_rows=rows))
                row.append(tracemalloc.get_traced_memory()[1] / 2**20)
                tracemalloc.stop()
        solve.coloured_covariance = traced
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                tracemalloc.start()
                small = SystemOptions(estimate_k2=True, chunk_rows=1 << 14)
                run_system_stage(source, truth.site, truth.installed_calibration, options=small)
                tracemalloc.stop()
        finally:
            solve.coloured_covariance = original
        print(f"  {days} d | {row[0]:.1f} | {row[1]:.1f} | {peaks['coloured'] / 2**20:.2f}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=40)
    parser.add_argument("--first", type=int, default=100)
    parser.add_argument("--worlds", nargs="+", choices=sorted(WORLDS), default=["quartz", "white", "white-5e-3"])
    parser.add_argument(
        "--modes",
        nargs="+",
        choices=("default", "datasheet", "zero-datasheet", "prior", "static"),
        default=["default", "datasheet", "prior"],
    )
    parser.add_argument("--days", type=float, default=1.0, help="record length [sidereal days] (default 1)")
    parser.add_argument("--memory", action="store_true", help="also print the memory table")
    parser.add_argument("--static-days", type=float, default=STATIC_DAYS, help="mode static: the static record's length [days]")
    parser.add_argument(
        "--without-flicker",
        action="store_true",
        help="diagnostic: the slow-noise fit with the flicker amplitude left out (random walk only)",
    )
    parser.add_argument("--json", help="write per record p-values, decisions and z here (to pool runs: --pool)")
    parser.add_argument("--pool", nargs="+", help="print the white records' slow-noise test over these --json files, pooled")
    args = parser.parse_args(argv)
    if args.pool:
        pool(args.pool)
        return 0
    seeds = range(args.first, args.first + args.seeds)
    dump: list[dict] = []
    with without_flicker() if args.without_flicker else contextlib.nullcontext():
        for mode in args.modes:
            for world in args.worlds:
                campaign(world, mode, seeds, args.days, dump, args.static_days)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(dump, f)
    if args.memory:
        memory()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
