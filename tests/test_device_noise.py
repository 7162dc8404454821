"""Dwell-mean noise: the slow-noise decision of the device stages (null distribution, false-positive rate) and honest σ."""

import numpy as np
import pytest
from device_world import GRAVITY, draw_truth, outputs

from stableins.estimators.device import noise_from_dwells
from stableins.estimators.dwell import slow_covariance, summarize_dwell
from stableins.estimators.fine import FINE_GAUGE_PREFERENCE, FineProblem, fine_model, solve_fine
from stableins.estimators.slow_noise import dwell_allan_ratios, dwell_test_clusters, slow_noise_test, white_allan_covariance
from stableins.noise import NoiseModel, NoiseSource
from stableins.procedures.definition import load_procedure
from stableins.simulator.noise import NoiseGenerator, NoiseSettings


def _brute_trace(n, mi, mj):
    def matrix(m):
        h = np.zeros((n - 2 * m + 1, n))
        for k in range(h.shape[0]):
            h[k, k : k + m], h[k, k + m : k + 2 * m] = -1 / m, 1 / m
        return h.T @ h / (2 * h.shape[0])

    return 2 * mi * mj * np.trace(matrix(mi) @ matrix(mj))


def test_null_covariance_of_the_allan_ratios_is_exact():
    n = 64
    clusters = dwell_test_clusters(n)
    exact = white_allan_covariance(n, clusters)
    brute = np.array([[_brute_trace(n, a, b) for b in clusters] for a in clusters])
    np.testing.assert_allclose(exact, brute, rtol=1e-10)


def test_allan_ratios_of_white_noise_have_mean_one_and_the_derived_covariance():
    rng = np.random.default_rng(1)
    n = 256
    r = np.array([dwell_allan_ratios(rng.normal(size=(n, 3)), 10.0)[1].T for _ in range(400)]).reshape(-1, len(dwell_test_clusters(n)))
    cov = white_allan_covariance(n, dwell_test_clusters(n))
    se = np.sqrt(np.diag(cov) / r.shape[0])
    assert np.all(np.abs(r.mean(axis=0) - 1.0) < 4 * se)
    np.testing.assert_allclose(np.var(r, axis=0), np.diag(cov), rtol=0.15)  # 1200 draws: ~4 % sd, skewed


def _white_dwells(rng, count=18, n=1200, rate=2.0, sigma=1e-3):
    return [
        summarize_dwell(np.arange(n) / rate, sigma * rng.normal(size=(n, 3)), np.zeros((n, 3)), np.zeros(3), position=j + 1, stage="fine")
        for j in range(count)
    ]


@pytest.mark.slow
def test_slow_noise_decision_has_its_false_positive_rate_on_white_noise():
    """200 white sessions of 18 dwells: the 5 % decision fires in 10 ± 3σ(binomial) of them, the statistic is 0 ± 1."""
    rng = np.random.default_rng(7)
    p_values, statistics = [], []
    for _ in range(200):
        dwells = _white_dwells(rng, count=18, n=400)
        test = slow_noise_test([(d.samples, d.allan_ratios, d.noise**2, d.rate) for d in dwells])
        p_values.append(test.test.p_value)
        statistics.append(test.test.statistic)
    alarms = np.sum(np.array(p_values) < 0.05)
    assert abs(alarms - 10) <= 3 * np.sqrt(200 * 0.05 * 0.95), alarms
    assert abs(np.mean(statistics)) < 4 / np.sqrt(200) and 0.8 < np.std(statistics) < 1.2


def test_noise_from_dwells_measures_white_noise_and_detects_strong_flicker():
    rng = np.random.default_rng(3)
    white = noise_from_dwells(_white_dwells(rng))
    assert white.source is NoiseSource.DEVICE_DWELLS
    np.testing.assert_allclose(white.values("white"), 1e-3 / np.sqrt(2.0), rtol=0.02)  # N = σ/√rate
    lo, hi = white.limits("white")
    assert np.all(lo < 1e-3 / np.sqrt(2.0)) and np.all(hi > 1e-3 / np.sqrt(2.0))
    # flicker 5× the quartz instrument's: detected, estimate within its interval of the truth
    settings = NoiseSettings(velocity_random_walk=4.5e-4, bias_instability=5 * 2e-6 * 9.80665)
    rate, n = 2.0, 1200
    noise = NoiseGenerator(settings, rate, 11).accelerometer(0, 18 * n).reshape(18, n, 3)
    dwells = [
        summarize_dwell(j * n / rate + np.arange(n) / rate, noise[j], np.zeros((n, 3)), np.zeros(3), position=j + 1, stage="fine")
        for j in range(18)
    ]
    model = noise_from_dwells(dwells)
    assert model.test.detected
    lo, hi = model.limits("bias_instability")
    assert np.all(lo < settings.bias_instability) and np.all(settings.bias_instability < hi)


def test_fine_stage_sigma_is_honest_only_with_the_slow_noise_model():
    """Simulator quartz noise (white + 2 µg bias instability + random walk), 18 × 600 s at 2 Hz."""
    readings = np.array([s.command for s in load_procedure("device-fine").steps])
    model = fine_model()
    free = np.array([k not in FINE_GAUGE_PREFERENCE for k in model.ids])
    settings = NoiseSettings.quartz()
    noise_model = NoiseModel.given(settings.velocity_random_walk, settings.bias_instability, settings.acceleration_random_walk)
    rate, n, gap = 2.0, 1200, 70
    rng = np.random.default_rng(3)
    nees = {"slow": [], "white": []}
    for trial in range(30):
        truth = draw_truth(rng)
        noise = NoiseGenerator(settings, rate, 500 + trial).accelerometer(0, 18 * (n + gap)).reshape(18, n + gap, 3)[:, gap:]
        exact = outputs(truth, readings)
        dwells = [
            summarize_dwell((j * (n + gap) + gap + np.arange(n)) / rate, exact[j] + noise[j], np.zeros((n, 3)), readings[j], position=j + 1)
            for j in range(18)
        ]
        means, sigma = np.array([d.mean for d in dwells])[None], np.array([d.sem for d in dwells])[None]
        x_true = np.array([truth[k] for k in model.ids])[None]
        for label, c in (("slow", slow_covariance(dwells, noise_model)[None]), ("white", None)):
            sol = solve_fine(FineProblem(means, sigma, GRAVITY, model, c), x_true)
            e = (sol.x - x_true)[0, free]
            p = sol.covariance[0][np.ix_(free, free)]
            nees[label].append(e @ np.linalg.solve(p, e))
    assert 9.0 < np.mean(nees["slow"]) < 15.5  # χ²_12 mean 12, sd of a 30-trial mean 0.9
    assert np.mean(nees["white"]) > 25.0  # white-only σ is far too small


@pytest.mark.parametrize("detected", [False, True])
def test_the_decision_sets_the_model_used(detected):
    rng = np.random.default_rng(5)
    dwells = _white_dwells(rng)
    if detected:  # a common slow wander far above the white noise of a mean
        dwells = [
            summarize_dwell(
                np.arange(1200) / 2.0,
                1e-3 * rng.normal(size=(1200, 3)) + np.cumsum(2e-4 * rng.normal(size=(1200, 3)), axis=0),
                np.zeros((1200, 3)),
                np.zeros(3),
                position=j + 1,
                stage="fine",
            )
            for j in range(18)
        ]
    model = noise_from_dwells(dwells)
    assert model.test.detected == detected
    b = model.values("bias_instability")
    assert np.all(b > 0) if detected else np.all(b == 0)
    assert np.all(np.isfinite(model.limits("bias_instability")[1]))
    assert not model.slow_noise_bounded  # the random walk cannot be told from bias instability in dwells


def test_the_measured_turn_within_a_dwell_is_not_taken_for_noise():
    """A platform turning steadily (30″ in 600 s, a 0.05 °/h gyro drift) moves the outputs by a ramp the readings explain.

    With the unit's setting the ramp the exact kinematics predict from the readings is taken out of the scatter: the
    noise is the white level and no correlated noise is noted; the mean is the recorded one.  Without it the ramp is
    read as noise.
    """
    from stableins.estimators.dwell import turn_explained_outputs
    from stableins.estimators.setting import DeviceSetting
    from stableins.platform import platform_specific_force

    rate, seconds, sigma = 10.0, 600.0, 1e-4
    t = np.arange(int(seconds * rate)) / rate
    rng = np.random.default_rng(7)
    turn = np.radians(30.0 / 3600.0) * t[:, None] / seconds * np.array([1.0, -0.7, 0.5])
    readings = np.radians([90.0, 45.0, 0.0]) + turn + np.radians(0.2 / 3600.0) * rng.normal(size=(t.size, 3))
    setting = DeviceSetting(GRAVITY, (0.3, 0.01, -0.02))
    exact = platform_specific_force(np.radians([90.0, 45.0, 0.0]) + turn, GRAVITY, base_attitude=setting.base_attitude)
    samples = exact + sigma * rng.normal(size=exact.shape)
    change = turn_explained_outputs(readings, setting)
    assert np.allclose(change.mean(axis=0), 0.0, atol=1e-12)
    assert np.sqrt(np.mean((change - (exact - exact.mean(axis=0))) ** 2)) < 0.15 * sigma  # the readings' noise: g·0.2″ ≈ 1 µg
    plain = summarize_dwell(t, samples, readings, readings[0], position=6, stage="fine")
    turned = summarize_dwell(t, samples, readings, readings[0], position=6, stage="fine", setting=setting)
    assert np.all(np.abs(turned.noise / sigma - 1.0) < 0.05)
    assert not turned.notes
    assert np.array_equal(turned.mean, plain.mean)
    assert np.max(plain.noise / sigma) > 1.2  # the ramp (g·30″ ≈ 1.4e-3 m/s² end to end) taken for noise
