"""The helpers of benchmarks/bench_system_sigma.py that turn a campaign into the figures of docs/system-calibration.md §10.

The p-values' fractions below each level (the slow-noise test's level on white records), the rms z that a plug-in random
walk gives by itself, and the noise model measured on a long static record (mode ``static``, the remedy for one day's
random walk).
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np

PATH = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_system_sigma.py"


def _module():
    spec = importlib.util.spec_from_file_location("bench_system_sigma", PATH)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules["bench_system_sigma"] = module
    spec.loader.exec_module(module)
    return module


def test_p_value_levels_count_the_records_below_each_level():
    bench = _module()
    p_values = np.r_[np.full(3, 0.005), np.full(7, 0.03), np.full(10, 0.5), np.ones(80)]  # 3 below 0.01, 10 below 0.05
    text = bench.p_value_levels(p_values, levels=(0.01, 0.05, 0.3))
    assert "p < 0.01: 3 of 100 (0.030" in text
    assert "p < 0.05: 10 of 100 (0.100" in text
    assert "p < 0.3: 10 of 100" in text


def test_plug_in_random_walk_gives_rms_z_one_at_the_truth_and_above_one_when_it_scatters():
    bench = _module()
    k = 3e-7
    truth = (k / 9.80665) ** 2
    z = np.ones((4, 17))
    exact = bench.random_walk_plug_in(np.full(4, truth), k, z)
    assert "median 1.00, zero in 0.00" in exact and "over the 4 records with it > 0: 1.000" in exact
    # half the records at half the truth, half at twice it: E[α/α̂] = (2 + 0.5)/2 = 1.25, rms z √1.25 = 1.118
    scattered = bench.random_walk_plug_in(np.r_[np.full(2, 0.5 * truth), np.full(2, 2.0 * truth)], k, z)
    assert "records with it > 0: 1.118" in scattered
    zero = bench.random_walk_plug_in(np.r_[0.0, np.full(3, truth)], k, z)
    assert "zero in 0.25" in zero and "over the 3 records" in zero


def test_static_noise_model_recovers_the_simulators_noise():
    """Six hours of the random-walk world's noise at 1 Hz: white noise to a few per cent and K inside its interval."""
    bench = _module()
    noise = bench.WORLDS["random-walk"]
    model = bench.static_noise_model(noise, 11, 0.25)
    white = model.values("white")
    assert np.all(np.abs(white / noise.velocity_random_walk - 1.0) < 0.05)
    low, high = model.limits("random_walk")
    k = noise.acceleration_random_walk
    assert np.all(low <= k) and np.all(k <= high)
    assert model.source.value == "static record"


def test_null_law_benchmark_shows_the_held_levels_move_the_rate_and_the_z_level_does_not():
    """benchmarks/bench_system_null_law.py on one white day, 300 draws: the held levels' error moves the false-alarm rate."""
    spec = importlib.util.spec_from_file_location("bench_system_null_law", PATH.parent / "bench_system_null_law.py")
    assert spec is not None and spec.loader is not None
    bench = importlib.util.module_from_spec(spec)
    sys.modules["bench_system_null_law"] = bench
    spec.loader.exec_module(bench)
    design, observed, channels, kwargs = bench.decision_inputs(7001)
    assert kwargs["offset"] is not None and np.count_nonzero(kwargs["offset"]) > 0  # pitch and roll held
    text = bench.level_shifts(design, observed, channels, kwargs, 300, [1.05])
    rates = dict(part.rsplit(" ", 1) for part in text.split("; ")[1:])
    assert abs(float(rates["z level x1.05"]) - 0.05) < 0.02  # common draws: the z level hardly moves the rate
    assert float(rates["held levels x1.05"]) > float(rates["z level x1.05"]) + 0.02


def test_without_flicker_wraps_the_stage_fit_and_restores_it():
    bench = _module()
    from stableins.estimators.system import coloured

    original = coloured.whittle.fit_coloured_noise
    with bench.without_flicker():
        assert coloured.whittle.fit_coloured_noise is not original
    assert coloured.whittle.fit_coloured_noise is original
