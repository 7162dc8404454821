"""The system stage's slow-noise test on white records: what its level depends on (issue 25, docs/system-calibration.md §1a, §10).

The decision on slow noise (:func:`stableins.estimators.system.whittle.fit_coloured_noise`) compares the likelihood ratio of
the record's residual ordinates with its null law: white noise with the z channel's white level fitted on the same
ordinates and the pitch and roll white levels held at the accelerometers' noise measured in the second differences
(near the decision, the record's own law drawn by :mod:`stableins.estimators.system.bootstrap`).  Two questions:

1. **Does a plugged-in level make the test liberal?**  On each of the first ``--law-records`` white records the benchmark
   draws ``--draws`` sets of ordinates from the record's own law (common random numbers) with the z white level and the
   held levels as fitted and scaled by ``--scales``, recomputes the statistic on each draw as the stage does, and prints
   ``P(S ≥ c)`` with ``c`` the 95 % point of the law as fitted: how far the false-alarm rate moves when a level is off.
2. **Are the held levels right on the records?**  For every record, the pitch and roll ordinates over their held white
   expectation (``offset`` of the fit: the loop's ``|G(f)|² sinc²`` times the residual maker's white term, times the
   measured level), per channel and per third of the band, with its standard error over the records.

One sidereal day at 1 Hz per seed through the truth simulator (white noise at the quartz level, 46 µg/√Hz, with the angle
noise), ``calibrate system`` with ``--estimate-k2`` and no noise model.

Usage::

    python benchmarks/bench_system_null_law.py [--seeds 60] [--first 7001] [--law-records 2] [--draws 2000]
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np

from stableins.conventions import ARCSEC, SIDEREAL_DAY
from stableins.data.chunks import ArraySource
from stableins.estimators.system import coloured, whittle
from stableins.estimators.system.stage import SystemOptions, run_system_stage
from stableins.simulator import system
from stableins.simulator.noise import NoiseSettings
from stableins.simulator.truth import SimulatedSite, Truth

WHITE = NoiseSettings(velocity_random_walk=4.5e-4, angle_noise=0.2 * ARCSEC)


def decision_inputs(seed: int) -> tuple[np.ndarray, np.ndarray, int, dict]:
    """Simulate one white day and return the arguments the stage passed to its slow-noise decision."""
    captured: dict[str, tuple] = {}
    original = coloured.whittle.fit_coloured_noise

    def capture(design, observed, channels, **kwargs):
        captured["args"] = (design, observed, channels, kwargs)
        return original(design, observed, channels, **kwargs)

    truth = Truth.draw(seed, site=SimulatedSite(sample_rate=1.0), noise=WHITE)
    cols = system.simulate_system(truth, SIDEREAL_DAY, 1.0, seed=seed)
    coloured.whittle.fit_coloured_noise = capture
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            run_system_stage(ArraySource(cols), truth.site, truth.installed_calibration, options=SystemOptions(estimate_k2=True))
    finally:
        coloured.whittle.fit_coloured_noise = original
    design, observed, channels, kwargs = captured["args"]
    return design, observed, channels, kwargs


def level_shifts(design, observed, channels, kwargs, draws: int, scales: list[float]) -> str:
    """``P(S ≥ c95)`` of the record's own null law with the z white level and the held levels scaled (common draws)."""
    law = kwargs["law"]
    base = kwargs["offset"] if kwargs["offset"] is not None else np.zeros(observed.size)
    theta0 = whittle._white_and_coloured(design, observed, channels, base)[0]
    kinds = design.shape[1] - channels

    def statistic(ordinates: np.ndarray) -> float:
        _, white, _, coloured_ = whittle._white_and_coloured(design, ordinates, channels, base)
        return 2.0 * (coloured_ - white)

    def law_at(z_scale: float, held_scale: float) -> np.ndarray:
        rng = np.random.default_rng(5)
        drawn = law.draw(law.levels(theta0[:channels] * z_scale, scale=held_scale), np.zeros(kinds), rng, draws)
        return np.array([statistic(o) for o in drawn])

    fitted = law_at(1.0, 1.0)
    c95 = float(np.quantile(fitted, 0.95))
    parts = [f"as fitted 0.050 (c95 = {c95:.2f})"]
    for s in scales:
        parts.append(f"z level x{s:g} {np.mean(law_at(s, 1.0) >= c95):.3f}")
    for s in scales:
        parts.append(f"held levels x{s:g} {np.mean(law_at(1.0, s) >= c95):.3f}")
    return "; ".join(parts)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=60)
    parser.add_argument("--first", type=int, default=7001)
    parser.add_argument("--law-records", type=int, default=2, help="records whose own law is drawn at scaled levels")
    parser.add_argument("--draws", type=int, default=2000, help="draws of each law")
    parser.add_argument("--scales", type=float, nargs="+", default=[0.96, 0.98, 1.02, 1.04])
    args = parser.parse_args(argv)
    start = time.perf_counter()
    ratios: list[np.ndarray] = []  # (2, m) per record: pitch and roll ordinates over their held expectation
    for k, seed in enumerate(range(args.first, args.first + args.seeds)):
        design, observed, channels, kwargs = decision_inputs(seed)
        if k < args.law_records:
            print(
                f"seed {seed}: false-alarm rate of the test at the levels' errors ({args.draws} draws of its own law): "
                + level_shifts(design, observed, channels, kwargs, args.draws, args.scales),
                flush=True,
            )
        offset = kwargs["offset"]
        held = np.flatnonzero(offset > 0)
        ratios.append((observed[held] / offset[held]).reshape(2, -1))
    r = np.array(ratios)  # (records, 2, m)
    m = r.shape[2]
    print(
        f"{r.shape[0]} white records (seeds {args.first}-{args.first + args.seeds - 1}), {m} ordinates per channel "
        f"({time.perf_counter() - start:.0f} s):"
    )
    for c, name in enumerate(("pitch", "roll")):
        per = r[:, c].mean(axis=1)
        thirds = [r[:, c, j * m // 3 : (j + 1) * m // 3].mean() for j in range(3)]
        print(
            f"  {name}: ordinates over their held white expectation {per.mean():.4f} ± {per.std(ddof=1) / np.sqrt(per.size):.4f} "
            f"(thirds of the band, low to high: {', '.join(f'{t:.3f}' for t in thirds)})"
        )
    both = r.mean(axis=(1, 2))
    print(f"  pitch and roll together: {both.mean():.4f} ± {both.std(ddof=1) / np.sqrt(both.size):.4f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
