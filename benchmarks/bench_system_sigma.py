"""Monte Carlo of the system stage's σ: normalized errors z = (estimate − truth)/σ over many seeded simulated days.

For each seed the truth simulator (stableins.simulator.system) draws a world and simulates one sidereal
day at 1 Hz; the stage estimates the combined coefficients (with --estimate-k2, as the default residuals
include K2) and the errors against the truth's combined coefficients are divided by the reported σ.
Printed: rms of z per coefficient and overall, the largest |z|, the fraction beyond 2 and 3, for

* the simulator's default quartz noise (white + bias instability + random walk + quantization + angle noise);
* white noise only (5e-3 m/s² per sample, the paper's level).

An honest σ gives rms z ≈ 1 (±1/√(2N) for N independent errors) and 0.27 % beyond 3σ.  Also printed: the
fitted coloured-noise amplitudes against the simulator's own settings (read here, never by the estimator):
random walk ``(K/g)²`` [1/s] and flicker ``σ²/g²`` per Gauss-Markov process (``σ² = B² ln 10/π``), and the
factor by which the coloured part raises the variance of x2.

With ``--memory``: tracemalloc peaks of the stage on ArraySource records of 1, 2, 4 and 7 days at 1 Hz (the
whole stage with 16384-row chunks, so that the chunk buffers do not grow with the record, and with the default
2^18-row chunks), and of ``_coloured_covariance`` alone (peak above its start).

Usage::

    python benchmarks/bench_system_sigma.py [--seeds 40] [--first 100] [--memory]
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np

from stableins.conventions import SIDEREAL_DAY
from stableins.estimators.system import stage
from stableins.estimators.system.separation import COMBINED_COEFFICIENTS, combination_matrix
from stableins.estimators.system.stage import ArraySource, SystemOptions, residuals_from_parameters, run_system_stage
from stableins.simulator import system
from stableins.simulator.noise import NoiseSettings
from stableins.simulator.truth import Truth

HARMONIC = [i for i, n in enumerate(COMBINED_COEFFICIENTS) if n not in ("theta_mean", "phi_mean", "x1")]


def normalized_errors(seed: int, noise: NoiseSettings | None) -> tuple[np.ndarray, float, dict, NoiseSettings]:
    truth = Truth.draw(seed, sample_rate=1.0, **({} if noise is None else {"noise": noise}))
    cols = system.simulate_system(truth, SIDEREAL_DAY, 1.0, seed=seed)
    p = residuals_from_parameters(truth.parameters, truth.installed_calibration, truth.site.gravity)
    ref = combination_matrix(truth.site.latitude) @ np.r_[p, 0.0, 0.0]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        out = run_system_stage(ArraySource(cols), truth.site, truth.installed_calibration, options=SystemOptions(estimate_k2=True))
    z = ((out.combined.values - ref) / out.combined.sigma)[HARMONIC]
    return z, float(out.diagnostics["z_low_frequency_ratio"]), out.diagnostics["coloured_noise"], truth.noise


def memory(days_list: tuple[int, ...] = (1, 2, 4, 7)) -> None:
    """tracemalloc peaks of the stage and of its coloured-noise model against the record length (1 Hz)."""
    import tracemalloc

    truth = Truth.draw(100, sample_rate=1.0)
    original = stage._coloured_covariance
    peaks: dict[str, float] = {}

    def traced(*args, **kwargs):  # peak of the coloured-noise model above the memory in use when it starts
        start = tracemalloc.get_traced_memory()[0]
        tracemalloc.reset_peak()
        result = original(*args, **kwargs)
        peaks["coloured"] = tracemalloc.get_traced_memory()[1] - start
        return result

    print("memory (tracemalloc peak, MiB): record | stage, 16384-row chunks | stage, 2^18-row chunks | _coloured_covariance")
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
        stage._coloured_covariance = traced
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                tracemalloc.start()
                small = SystemOptions(estimate_k2=True, chunk_rows=1 << 14)
                run_system_stage(source, truth.site, truth.installed_calibration, options=small)
                tracemalloc.stop()
        finally:
            stage._coloured_covariance = original
        print(f"  {days} d | {row[0]:.1f} | {row[1]:.1f} | {peaks['coloured'] / 2**20:.2f}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=40)
    parser.add_argument("--first", type=int, default=100)
    parser.add_argument("--memory", action="store_true", help="also print the memory table")
    args = parser.parse_args(argv)
    names = [COMBINED_COEFFICIENTS[i] for i in HARMONIC]
    for label, noise in (("quartz (simulator default)", None), ("white 5e-3 m/s^2", NoiseSettings(velocity_random_walk=5e-3))):
        start = time.perf_counter()
        rows, ratios, amplitudes = [], [], []
        for seed in range(args.first, args.first + args.seeds):
            z, ratio, coloured, settings = normalized_errors(seed, noise)
            rows.append(z)
            ratios.append(ratio)
            amplitudes.append([coloured["amplitudes"].get(k, 0.0) for k in ("random_walk", "flicker")])
        z = np.array(rows)
        print(f"{label}: {args.seeds} seeds x {len(HARMONIC)} coefficients ({time.perf_counter() - start:.0f} s)")
        print("  rms z per coefficient: " + ", ".join(f"{n} {v:.2f}" for n, v in zip(names, np.sqrt(np.mean(z**2, axis=0)), strict=True)))
        print(
            f"  overall rms z {np.sqrt(np.mean(z**2)):.3f} (expected 1 ± {1 / np.sqrt(2 * z.size):.3f}), max |z| {np.abs(z).max():.1f}, "
            f"|z| > 2: {np.mean(np.abs(z) > 2):.3f} (0.046), |z| > 3: {np.mean(np.abs(z) > 3):.4f} (0.0027)"
        )
        ratios = np.array(ratios)
        print(
            f"  variance factor of x2 over white: median {np.median(ratios):.2f}, 90 % {np.percentile(ratios, 90):.2f}, "
            f"max {ratios.max():.1f}; coloured part non-zero in {np.mean(ratios > 1.0001):.0%} of the records"
        )
        g = 9.80665
        taus = settings.bias_instability_time_constants
        truth_amplitudes = np.array(
            [(settings.acceleration_random_walk / g) ** 2, (settings.bias_instability / g) ** 2 * np.log(taus[1] / taus[0]) / np.pi]
        )
        a = np.array(amplitudes)
        for k, name in enumerate(("random walk (K/g)^2 [1/s]", "flicker sigma^2/g^2 per process")):
            print(
                f"  {name}: simulator {truth_amplitudes[k]:.3g}; fitted median {np.median(a[:, k]):.3g}, mean {a[:, k].mean():.3g}, "
                f"zero in {np.mean(a[:, k] == 0):.0%}"
            )
    if args.memory:
        memory()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
