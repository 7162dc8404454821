"""Slow-noise covariance of dwell means: closed forms vs brute force, and honest fine-stage σ on the simulator's noise."""

import numpy as np
from device_world import GRAVITY, draw_truth, outputs

from stableins.estimators.dwell import overlapping_allan_variance, summarize_dwell
from stableins.estimators.fine import GAUGE_PREFERENCE, FineProblem, fine_model, solve_fine
from stableins.estimators.noise_model import SlowNoise, _gauss_markov_window_covariance, dwell_mean_covariance
from stableins.procedures.definition import load_procedure
from stableins.simulator.noise import NoiseGenerator, NoiseSettings


def _brute_force_window_covariance(start, length, autocovariance, dt=0.05):
    grids = [np.arange(s, s + t, dt) + dt / 2 for s, t in zip(start, length)]
    m = len(grids)
    out = np.zeros((m, m))
    for i in range(m):
        for j in range(m):
            out[i, j] = autocovariance(grids[i][:, None], grids[j][None, :]).mean()
    return out


def test_gauss_markov_window_covariance_matches_brute_force():
    start, length, tau = np.array([0.0, 30.0, 100.0]), np.array([20.0, 20.0, 50.0]), 15.0
    exact = _gauss_markov_window_covariance(start, length, tau)
    brute = _brute_force_window_covariance(start, length, lambda s, t: np.exp(-np.abs(s - t) / tau))
    np.testing.assert_allclose(exact, brute, rtol=2e-3, atol=1e-6)


def test_random_walk_window_covariance_matches_brute_force():
    start, length, k = np.array([0.0, 30.0, 100.0]), np.array([20.0, 20.0, 50.0]), 1e-6
    exact = dwell_mean_covariance(start, length, SlowNoise(0.0, k))
    brute = _brute_force_window_covariance(start, length, lambda s, t: k**2 * np.minimum(s, t))
    np.testing.assert_allclose(exact, brute, rtol=2e-3)


def test_overlapping_allan_variance_of_white_noise():
    x = np.random.default_rng(1).normal(size=(200000, 1))
    m = np.array([1, 10, 100])
    np.testing.assert_allclose(overlapping_allan_variance(x, m)[:, 0] * m, 1.0, rtol=0.05)


def test_fine_stage_sigma_is_honest_only_with_the_slow_noise_model():
    """Simulator quartz noise (white + 2 µg bias instability + random walk), 18 × 600 s at 2 Hz."""
    readings = np.array([s.command for s in load_procedure("device-fine").steps])
    model = fine_model()
    free = np.array([k not in GAUGE_PREFERENCE for k in model.ids])
    settings = NoiseSettings.quartz()
    slow = SlowNoise(settings.bias_instability, settings.acceleration_random_walk, "datasheet")
    rate, n, gap = 2.0, 1200, 70
    starts = np.array([(j * (n + gap) + gap) / rate for j in range(18)])
    cov_slow = dwell_mean_covariance(starts, np.full(18, n / rate), slow)[None]
    rng = np.random.default_rng(3)
    nees = {"slow": [], "white": []}
    for trial in range(30):
        truth = draw_truth(rng)
        noise = NoiseGenerator(settings, rate, 500 + trial).accelerometer(0, 18 * (n + gap)).reshape(18, n + gap, 3)[:, gap:]
        exact = outputs(truth, readings)
        time = np.arange(n) / rate
        dwells = [summarize_dwell(time, exact[j] + noise[j], np.zeros((n, 3)), readings[j], position=j + 1) for j in range(18)]
        means, sigma = np.array([d.mean for d in dwells])[None], np.array([d.sem for d in dwells])[None]
        x_true = np.array([truth[k] for k in model.ids])[None]
        for label, c in (("slow", cov_slow), ("white", None)):
            sol = solve_fine(FineProblem(means, sigma, GRAVITY, model, c), x_true)
            e = (sol.x - x_true)[0, free]
            p = sol.covariance[0][np.ix_(free, free)]
            nees[label].append(e @ np.linalg.solve(p, e))
    assert 9.0 < np.mean(nees["slow"]) < 15.5  # χ²_12 mean 12, sd of a 30-trial mean 0.9
    assert np.mean(nees["white"]) > 25.0  # white-only σ is far too small


def test_undetectable_slow_noise_comparable_to_the_white_noise_is_warned_about():
    from stableins.estimators.device import estimate_slow_noise, hidden_slow_noise_warning

    rng = np.random.default_rng(8)
    n = 1200  # 10 min at 2 Hz, white noise only: nothing to detect, but little to exclude either
    dwells = [
        summarize_dwell(np.arange(n) / 2.0, 1e-3 * rng.normal(size=(n, 3)), np.zeros((n, 3)), np.zeros(3), position=j + 1, stage="fine")
        for j in range(18)
    ]
    estimated = estimate_slow_noise(dwells)
    assert estimated.is_zero and estimated.undetected_bound > 0
    white = np.median([np.median(d.sem) for d in dwells])
    warning = hidden_slow_noise_warning(estimated, dwells)
    assert (0.664 * estimated.undetected_bound > 0.5 * white) == (warning is not None)
    assert warning is not None and "fine-stage 1σ may be too small" in warning
    # given by the user (even as zero): no warning
    assert hidden_slow_noise_warning(SlowNoise(0.0, 0.0, "datasheet"), dwells) is None
    # a bound well below the white noise of a mean: no warning
    assert hidden_slow_noise_warning(SlowNoise(0.0, 0.0, "x", undetected_bound=0.1 * white), dwells) is None
