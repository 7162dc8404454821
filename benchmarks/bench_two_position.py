"""Two-position gyro-drift test (issue 16 part 4): Monte Carlo against the independent world.

Prints, for 100 seeds (``--seeds N``), the fraction of seeds in which each axis of the estimated gyro drift
is within 10 % of the truth (0.005 °/h per axis, random signs), for

* case A, a realistic base: tilts about North and East and the azimuth error drawn with their nominal σ
  (10″, 10″, 30″), once-per-revolution angle-sensor errors drawn (2″), zero-offset residuals of the installed
  calibration drawn (2″), quartz accelerometer noise, 0.2″ angle noise at 10 Hz;
* case B, the same instrument with the base errors replaced by a 5″ azimuth error alone;

each with the two-position test (``drift-two-position``: 600 s hold, 180° index about z_p, 620 s hold; the
estimator fits the base error as a nuisance) and with a one-position estimate (the same 1258 s without the
index; the base held at its survey, the only choice one position leaves).

Compared against: the acceptance of issue 16 (each axis within 10 % in at least 95 % of 100 seeds; with 5″ of
azimuth error the two-position result stays within that while a one-position estimate does not), Zhang et al.
2023 (maximum relative error 13.16 %, all others below 10 %), and the predicted one-position error
``Ω cos L · 5″ = 2.79e-4 °/h`` (5.6 % of 0.005 °/h) on the axis pointing East.  Also the rms of
``(ε̂ − ε)/σ`` (1 for honest σ) and the spread of the estimates.

Run: ``nice -n 10 .venv/bin/python benchmarks/bench_two_position.py`` (about 5 min on one core).
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

from stableins.conventions import ARCSEC, DEG_PER_HOUR, EARTH_RATE
from stableins.estimators.drift import estimate_drift
from stableins.simulator.system import simulate_system
from stableins.simulator.truth import SimulatedSite, Truth
from stableins.turns import PlatformTurn

DRIFT = 0.005  # °/h per axis
RATE = 10.0  # Hz, as the procedure
DURATION = 1258.0  # s, as drift-two-position
TURN = PlatformTurn(600.0, math.pi)
LIMIT = 0.10


def world(seed: int, case: str) -> Truth:
    rng = np.random.default_rng([seed, 16])
    signs = rng.choice([-1.0, 1.0], size=3)
    effects = {f"ang1_{g}_{k}": 2 * ARCSEC * rng.standard_normal() for g in ("platform", "inner", "middle") for k in "cs"}
    if case == "A":
        effects |= {
            "tilt_north": 10 * ARCSEC * rng.standard_normal(),
            "tilt_east": 10 * ARCSEC * rng.standard_normal(),
            "azimuth_error": 30 * ARCSEC * rng.standard_normal(),
        }
    else:
        effects["azimuth_error"] = 5 * ARCSEC
    drift = {a: s * DRIFT * DEG_PER_HOUR for a, s in zip("xyz", signs, strict=True)}
    return Truth.draw(seed, site=SimulatedSite(sample_rate=RATE), effects=effects, gyro_drift=drift)


def estimate(truth: Truth, seed: int, *, indexed: bool) -> tuple[np.ndarray, np.ndarray]:
    record = simulate_system(truth, DURATION, rate=RATE, seed=seed, turns=(TURN,) if indexed else ())
    site = truth.site
    fit = estimate_drift(
        record,
        site,
        prior_values=truth.installed_calibration,
        base="auto" if indexed else "survey",
    )
    return fit.values, fit.sigma


def summary(name: str, errors: np.ndarray, sigmas: np.ndarray, truth: np.ndarray) -> bool:
    relative = np.abs(errors) / np.abs(truth)
    within = np.mean(relative <= LIMIT, axis=0)
    z = errors / sigmas
    print(f"  {name}:")
    print("    fraction within 10 %  (x, y, z): " + ", ".join(f"{100 * w:5.1f} %" for w in within) + "   (criterion >= 95 %)")
    print(
        "    largest relative error (x, y, z): " + ", ".join(f"{100 * r:6.2f} %" for r in relative.max(axis=0)) + "   (Zhang 2023: 13.16 %)"
    )
    print("    mean error (x, y, z) [1e-4 °/h]: " + ", ".join(f"{m / DEG_PER_HOUR * 1e4:+7.3f}" for m in errors.mean(axis=0)))
    print(
        "    rms error  (x, y, z) [1e-4 °/h]: " + ", ".join(f"{r / DEG_PER_HOUR * 1e4:7.3f}" for r in np.sqrt(np.mean(errors**2, axis=0)))
    )
    print("    median 1σ  (x, y, z) [1e-4 °/h]: " + ", ".join(f"{s / DEG_PER_HOUR * 1e4:7.3f}" for s in np.median(sigmas, axis=0)))
    print("    rms (ε̂ − ε)/σ (x, y, z): " + ", ".join(f"{r:6.2f}" for r in np.sqrt(np.mean(z**2, axis=0))) + "   (1 for honest σ)")
    return bool(np.all(within >= 0.95))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=100)
    args = parser.parse_args()
    seeds = range(1, args.seeds + 1)
    latitude = Truth.draw(1).site.latitude
    predicted = EARTH_RATE * math.cos(latitude) * 5 * ARCSEC
    print(f"two-position gyro-drift test: {args.seeds} seeds, {DRIFT} °/h per axis (random signs), {DURATION:g} s at {RATE:g} Hz")
    print(f"  predicted one-position error from 5″ of azimuth: Ω cos L · 5″ = {predicted / DEG_PER_HOUR:.3e} °/h "
          f"= {100 * predicted / (DRIFT * DEG_PER_HOUR):.1f} % of {DRIFT} °/h (on the axis pointing East)")  # fmt: skip
    print(f"  a one-position estimate leaves 10 % once |u × δ| > {0.1 * DRIFT * DEG_PER_HOUR / EARTH_RATE / ARCSEC:.1f}″ "
          "(base azimuth·cos L + tilt_north·sin L, tilt_east; zero-offset residuals of the inner and middle gimbals add)")  # fmt: skip
    started = time.perf_counter()
    verdicts = {}
    for case, title in (("A", "case A: realistic base (tilts 10″, azimuth 30″ σ; ang1 2″; offset residuals 2″)"),
                        ("B", "case B: 5″ base azimuth error alone (ang1 2″; offset residuals 2″)")):  # fmt: skip
        print(title)
        results: dict[str, list] = {"two": [], "one": []}
        truths = []
        for seed in seeds:
            truth = world(seed, case)
            eps = np.array([truth.gyro_drift[a] for a in "xyz"])
            truths.append(eps)
            for key, indexed in (("two", True), ("one", False)):
                value, sigma = estimate(truth, seed, indexed=indexed)
                results[key].append((value - eps, sigma))
        eps_all = np.array(truths)
        for key, name in (("two", "two-position (index 180° about z_p, base fitted)"), ("one", "one-position (no index, base at survey)")):
            errors = np.array([e for e, _ in results[key]])
            sigmas = np.array([s for _, s in results[key]])
            verdicts[(case, key)] = summary(name, errors, sigmas, eps_all)
            if case == "B" and key == "one":
                print(f"    mean error on y_p (East at the start) {errors[:, 1].mean() / DEG_PER_HOUR:+.3e} °/h "
                      f"against −Ω cos L · 5″ = {-predicted / DEG_PER_HOUR:+.3e} °/h")  # fmt: skip
    print("acceptance:")
    print(f"  (a) two-position, each axis within 10 % in >= 95 % of seeds (case A): {'PASS' if verdicts[('A', 'two')] else 'FAIL'}")
    print(f"  (b) 5″ azimuth: two-position stays within (a): {'PASS' if verdicts[('B', 'two')] else 'FAIL'}; "
          f"one-position does not: {'yes' if not verdicts[('B', 'one')] else 'NO: within 10 % (5.6 % bias, see above)'}")  # fmt: skip
    print(f"      realistic base (case A): one-position within 10 % in >= 95 %: {'yes' if verdicts[('A', 'one')] else 'no'}")
    print(f"time: {time.perf_counter() - started:.0f} s")


if __name__ == "__main__":
    main()
