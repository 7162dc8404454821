"""Monte Carlo of the system stage's σ: normalized errors z = (estimate − truth)/σ over many seeded simulated days.

For each seed the truth simulator (stableins.simulator.system) draws a world and simulates one sidereal
day at 1 Hz; the stage estimates the combined coefficients (with --estimate-k2, as the default residuals
include K2) and the errors against the truth's combined coefficients are divided by the reported σ.
Printed: rms of z per coefficient and overall, the largest |z|, the fraction beyond 2 and 3, for

* the simulator's default quartz noise (white + bias instability + random walk + quantization + angle noise);
* white noise only (5e-3 m/s² per sample, the paper's level).

An honest σ gives rms z ≈ 1 (±1/√(2N) for N independent errors).

Usage::

    python benchmarks/bench_system_sigma.py [--seeds 40]
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np

from stableins.conventions import SIDEREAL_DAY
from stableins.estimators.system.separation import COMBINED_COEFFICIENTS, combination_matrix
from stableins.estimators.system.stage import ArraySource, SystemOptions, residuals_from_parameters, run_system_stage
from stableins.simulator import system
from stableins.simulator.noise import NoiseSettings
from stableins.simulator.truth import Truth

HARMONIC = [i for i, n in enumerate(COMBINED_COEFFICIENTS) if n not in ("theta_mean", "phi_mean", "x1")]


def normalized_errors(seed: int, noise: NoiseSettings | None) -> tuple[np.ndarray, float]:
    truth = Truth.draw(seed, sample_rate=1.0, **({} if noise is None else {"noise": noise}))
    cols = system.simulate_system(truth, SIDEREAL_DAY, 1.0, seed=seed)
    p = residuals_from_parameters(truth.parameters, truth.installed_calibration, truth.site.gravity)
    ref = combination_matrix(truth.site.latitude) @ np.r_[p, 0.0, 0.0]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        out = run_system_stage(ArraySource(cols), truth.site, truth.installed_calibration, options=SystemOptions(estimate_k2=True))
    return ((out.combined.values - ref) / out.combined.sigma)[HARMONIC], float(out.diagnostics["z_low_frequency_ratio"])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=40)
    parser.add_argument("--first", type=int, default=100)
    args = parser.parse_args(argv)
    names = [COMBINED_COEFFICIENTS[i] for i in HARMONIC]
    for label, noise in (("quartz (simulator default)", None), ("white 5e-3 m/s^2", NoiseSettings(velocity_random_walk=5e-3))):
        start = time.perf_counter()
        rows, ratios = [], []
        for seed in range(args.first, args.first + args.seeds):
            z, ratio = normalized_errors(seed, noise)
            rows.append(z)
            ratios.append(ratio)
        z = np.array(rows)
        print(f"{label}: {args.seeds} seeds x {len(HARMONIC)} coefficients ({time.perf_counter() - start:.0f} s)")
        print("  rms z per coefficient: " + ", ".join(f"{n} {v:.2f}" for n, v in zip(names, np.sqrt(np.mean(z**2, axis=0)), strict=True)))
        print(
            f"  overall rms z {np.sqrt(np.mean(z**2)):.3f} (expected 1 ± {1 / np.sqrt(2 * z.size):.3f}), max |z| {np.abs(z).max():.1f}, "
            f"|z| > 2: {np.mean(np.abs(z) > 2):.3f} (0.046), |z| > 3: {np.mean(np.abs(z) > 3):.4f} (0.0027)"
        )
        used = np.mean(np.array(ratios) > 1)
        print(f"  variance factor of x2 over white: median {np.median(ratios):.1f}, coloured model used in {used:.0%}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
