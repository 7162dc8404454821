"""How well one static record can name a slow accelerometer bias drift under slow noise (issue 25; docs/system-calibration.md §8).

A bias drift ``d`` (``Kd_bias``, 10 µg/day in issue 25's ``drift`` world) is a ramp ``d t`` in an accelerometer's output.
Slow noise puts ramp-like wander into every record: a random walk ``K`` alone gives the best (generalized least squares)
drift estimate the variance ``K²/T`` (the increments of ``d t + K W(t)`` are white: ``d̂ = y(T)/T``), 3.0 µg/day for
the quartz figure ``K = 1e-7 m/s²/√s`` over one sidereal day, and flicker adds its own.  Whatever the test, its power
at a given false-alarm rate is bounded by the drift's σ with the noise model *known exactly*: that is what this prints.

Part 1, the bound from the raw outputs of one axis (no system stage): per-axis outputs on 600-s bins with the exact
bin covariance of white + flicker + random walk (:func:`stableins.estimators.system.spectrum.bin_process_kernel`), the
columns one axis' calibration needs (z: a mean; x and y: a mean and the first three Earth-rate harmonics) and the ramp;
σ of the ramp from the Fisher information, for 1, 2, 4 and 7 sidereal days, and the power of a χ² test at 5 % false
alarms (ν = 3 for a drift on every axis, ν = 1 for one axis).

Part 2 (``--seeds N``), the same on the system stage's own channels: simulated records of the ``drift`` world (truth
simulator, quartz noise + 10 µg/day per axis, 1 Hz), the stage's z, pitch and roll residuals on its coloured-noise bins
(:func:`stableins.estimators.system.coloured.low_band`, read by wrapping it), their exact covariance under the
simulator's noise (the residual makers, the Earth-rate loadings, the damping loop's bin mixing; the attitude channels'
white part from the stage's white levels and the loop's gain), the drift of each axis by generalized least squares,
its σ and ``χ²`` (ν = 3).  This is the best case (noise known); with the noise measured in the same record the power is
lower.

Usage::

    python benchmarks/bench_system_bias_drift.py [--seeds 0] [--days 1]
"""

from __future__ import annotations

import argparse
import math
import warnings

import numpy as np
from scipy.stats import chi2, ncx2

from stableins.conventions import EARTH_RATE, MICRO_G, SIDEREAL_DAY
from stableins.estimators.system.spectrum import allan_to_amplitudes, bin_process_kernel

GRAVITY = 9.80665
WHITE = 4.5e-4  # quartz white noise N [m/s/√s] (46 µg/√Hz)
BIAS_INSTABILITY = 2.0 * MICRO_G
RANDOM_WALK = 1e-7  # [m/s²/√s]
DRIFT = 10.0  # [µg/day] per axis, issue 25
BIN = 600.0  # [s]


def per_axis_sigma(days: float, random_walk: float, bias_instability: float, *, harmonics: bool) -> float:
    """σ of a bias drift [µg/day] from one axis' raw outputs on ``days`` sidereal days with the noise model known."""
    n = int(days * SIDEREAL_DAY // BIN)
    t = (np.arange(n) + 0.5) * BIN
    a_rw, a_fl = allan_to_amplitudes(random_walk, bias_instability, GRAVITY)
    cov = a_rw * bin_process_kernel("random_walk", t, BIN) + a_fl * bin_process_kernel("flicker", t, BIN)
    cov += (WHITE / GRAVITY) ** 2 / BIN * np.eye(n)
    s = EARTH_RATE * t
    columns = [np.ones(n)] + ([f(k * s) for k in (1, 2, 3) for f in (np.cos, np.sin)] if harmonics else []) + [t]
    x = np.stack(columns, axis=1)
    information = x.T @ np.linalg.solve(cov, x)
    return float(math.sqrt(np.linalg.inv(information)[-1, -1]) * GRAVITY * SIDEREAL_DAY / MICRO_G)


def part_one() -> None:
    alpha = 0.05
    print(
        f"Part 1: sigma of a bias drift from one axis' raw outputs, noise known exactly (white {WHITE:g} m/s/sqrt(s), "
        f"B {BIAS_INSTABILITY / MICRO_G:g} ug, K {RANDOM_WALK:g} m/s^2/sqrt(s)), 600-s bins; power of the chi2 test at "
        f"{alpha:g} false alarms for {DRIFT:g} ug/day"
    )
    head = ("days", "K/sqrt(T)", "z (RW only)", "z (flicker only)", "z", "x, y", "power, 3 axes", "power, 1 axis")
    print(" ".join(f"{h:>{w}}" for h, w in zip(head, (5, 10, 12, 17, 7, 7, 14, 14), strict=True)))
    for days in (1, 2, 4, 7):
        floor = RANDOM_WALK / math.sqrt(days * SIDEREAL_DAY) * SIDEREAL_DAY / MICRO_G
        z_rw = per_axis_sigma(days, RANDOM_WALK, 0.0, harmonics=False)
        z_fl = per_axis_sigma(days, 0.0, BIAS_INSTABILITY, harmonics=False)
        z = per_axis_sigma(days, RANDOM_WALK, BIAS_INSTABILITY, harmonics=False)
        xy = per_axis_sigma(days, RANDOM_WALK, BIAS_INSTABILITY, harmonics=True)
        lam3 = (DRIFT / z) ** 2 + 2 * (DRIFT / xy) ** 2
        lam1 = (DRIFT / xy) ** 2
        power3 = float(ncx2.sf(chi2.isf(alpha, 3), 3, lam3))
        power1 = float(ncx2.sf(chi2.isf(alpha, 1), 1, lam1))
        print(f"{days:>5} {floor:>10.2f} {z_rw:>12.2f} {z_fl:>17.2f} {z:>7.2f} {xy:>7.2f} {power3:>14.3f} {power1:>14.3f}")
    print("  (sigma in ug/day; every column has the white noise: 'RW only' is white + random walk, 'flicker only' white + flicker)")


def _white_covariance(time: np.ndarray, weights: np.ndarray, gain, level: float) -> np.ndarray:
    """Bin-mean covariance of a loop-filtered white noise: ``level W ∫ g(f) cos(2πfτ) df / sqrt(w_i w_j)`` up to the bins' Nyquist."""
    width = float(time[1] - time[0])
    f = np.linspace(0.0, 0.5 / width, 801)
    g = np.array([gain(x) for x in f])
    lag = np.abs(np.subtract.outer(time, time))
    kernel = np.zeros_like(lag)
    for k in range(f.size - 1):  # trapezoid over frequency, no (n, n, m) array
        df = f[k + 1] - f[k]
        kernel += 0.5 * df * (g[k] * np.cos(2 * np.pi * f[k] * lag) + g[k + 1] * np.cos(2 * np.pi * f[k + 1] * lag))
    return level * 2.0 * width * kernel / np.sqrt(np.outer(weights, weights))


def channel_drift(bins, white_levels: np.ndarray, amplitudes: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """Drift per axis [g/s] and its covariance from the stage's low-band channels under a given noise model (GLS)."""
    n = bins.time.size
    bases = []
    for p in range(len(bins.channels)):
        u, s, _ = np.linalg.svd(np.eye(n) - bins.makers[p])
        bases.append(u[:, int(np.sum(s > 1e-9 * s[0])) :])  # orthogonal to what the channel's fit absorbs

    def mixed(p: int, a: int) -> np.ndarray:
        m = np.asarray(bins.mixing[p][a])
        return np.diag(m) if m.ndim == 1 else m

    y = np.concatenate([q.T @ c for q, c in zip(bases, bins.channels, strict=True)])
    ramps = np.stack([np.concatenate([q.T @ (mixed(p, a) @ bins.time) for p, q in enumerate(bases)]) for a in range(3)], axis=1)
    cov = np.zeros((y.size, y.size))
    edges = np.cumsum([0] + [q.shape[1] for q in bases])
    for p, q in enumerate(bases):
        gain = bins.gains[p]
        if gain is None:
            white = np.diag(white_levels[p] / bins.weights[p])
        else:
            white = _white_covariance(bins.time, bins.weights[p], gain, white_levels[p])
        cov[edges[p] : edges[p + 1], edges[p] : edges[p + 1]] = q.T @ white @ q
    for amplitude, kernel in zip(amplitudes, bins.kernels, strict=True):
        for a in range(3):
            load = np.concatenate([q.T @ mixed(p, a) for p, q in enumerate(bases)])
            cov += amplitude * load @ kernel @ load.T
    solved = np.linalg.solve(cov, ramps)
    information = ramps.T @ solved
    drift = np.linalg.solve(information, solved.T @ y)
    return drift, np.linalg.inv(information)


def part_two(seeds: range, days: float) -> None:
    from stableins.data.chunks import ArraySource
    from stableins.estimators.system import coloured
    from stableins.estimators.system.stage import SystemOptions, run_system_stage
    from stableins.simulator import system
    from stableins.simulator.truth import SimulatedSite, Truth
    from stableins.simulator.worlds import apply_world

    captured = {}
    original = coloured.low_band

    def recording(*args, **kwargs):
        captured["bins"] = original(*args, **kwargs)
        return captured["bins"]

    coloured.low_band = recording
    amplitudes = tuple(float(v) for v in allan_to_amplitudes(RANDOM_WALK, BIAS_INSTABILITY, GRAVITY))
    from stableins.simulator.worlds import BIAS_DRIFT

    truth_drift = [apply_world(Truth.draw(1), "drift").effects[f"Kd_bias_{a}"] / BIAS_DRIFT * DRIFT for a in "xyz"]
    print(
        f"\nPart 2: the stage's z, pitch and roll channels, 'drift' world (truth {truth_drift} ug/day on x, y, z), "
        f"{days:g} sidereal day(s) at 1 Hz, noise known"
    )
    sigmas, stats = [], []
    for seed in seeds:
        truth = apply_world(Truth.draw(seed, site=SimulatedSite(sample_rate=1.0)), "drift")
        cols = system.simulate_system(truth, days * SIDEREAL_DAY, 1.0, seed=seed)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            out = run_system_stage(ArraySource(cols), truth.site, truth.installed_calibration, options=SystemOptions(estimate_k2=True))
        assert out.coloured_noise is not None
        drift, cov = channel_drift(captured["bins"], out.coloured_noise.white_levels, amplitudes)
        scale = SIDEREAL_DAY / MICRO_G * GRAVITY
        sigma = np.sqrt(np.diag(cov)) * scale
        stat = float(drift @ np.linalg.solve(cov, drift))
        sigmas.append(sigma)
        stats.append(stat)
        print(
            f"  seed {seed}: drift {np.array2string(drift * scale, precision=1)} +- {np.array2string(sigma, precision=2)} ug/day, "
            f"chi2 (nu 3) {stat:.1f}, p {chi2.sf(stat, 3):.2g}"
        )
    if stats:
        critical = chi2.isf(0.05, 3)
        print(
            f"  median sigma per axis {np.array2string(np.median(sigmas, axis=0), precision=2)} ug/day; named at 5 % "
            f"(chi2 > {critical:.2f}) in {sum(s > critical for s in stats)} of {len(stats)}"
        )
    coloured.low_band = original


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=0, help="records for part 2 (seeds 1..N; 0: part 1 only)")
    parser.add_argument("--days", type=float, default=1.0, help="record length of part 2 [sidereal days]")
    args = parser.parse_args(argv)
    part_one()
    part_two(range(1, args.seeds + 1), args.days)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
