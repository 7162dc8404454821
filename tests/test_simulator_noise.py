"""Noise statistics of the simulator (fixed seeds, k·sigma bounds)."""

import numpy as np
import pytest

from stableins.simulator.noise import BLOCK_SAMPLES, NoiseGenerator, NoiseSettings, TemperatureProfile, allan_deviation

K = 4.0  # bound in standard deviations


def test_white_noise_sigma_per_sample():
    settings = NoiseSettings(velocity_random_walk=4.5e-4)
    rate = 100.0
    x = NoiseGenerator(settings, rate, seed=11).accelerometer(0, 3 * BLOCK_SAMPLES + 123)
    n = x.shape[0]
    sigma = settings.white_sigma(rate)
    assert sigma == pytest.approx(4.5e-3)
    ratio = x.std(axis=0) / sigma
    assert np.all(np.abs(ratio - 1) < K / np.sqrt(2 * n))
    assert np.all(np.abs(x.mean(axis=0)) < K * sigma / np.sqrt(n))
    # axes and lags are uncorrelated
    c = np.corrcoef(x.T)
    assert np.all(np.abs(c[np.triu_indices(3, 1)]) < K / np.sqrt(n))
    lag1 = np.mean(x[1:] * x[:-1], axis=0) / sigma**2
    assert np.all(np.abs(lag1) < K / np.sqrt(n))


def test_white_noise_allan_slope_is_minus_one_half():
    settings = NoiseSettings(velocity_random_walk=1e-3)
    rate = 50.0
    x = NoiseGenerator(settings, rate, seed=3).accelerometer(0, 2**18)
    m = np.array([1, 4, 16, 64, 256])
    adev = allan_deviation(x, rate, m)
    tau = m / rate
    expected = settings.velocity_random_walk / np.sqrt(tau)
    # relative sigma of an overlapping white-noise Allan deviation ~ 1/sqrt(N/m) (loose, conservative)
    rel = 1.0 / np.sqrt(len(x) / m)
    assert np.all(np.abs(adev / expected[:, None] - 1) < K * rel[:, None])
    slope = np.polyfit(np.log(tau), np.log(adev.mean(axis=1)), 1)[0]
    assert slope == pytest.approx(-0.5, abs=0.03)


def test_random_walk_grows_as_sqrt_time():
    k_rw = 2e-6
    settings = NoiseSettings(acceleration_random_walk=k_rw)
    rate = 10.0
    n = 2 * BLOCK_SAMPLES
    ends = []
    for seed in range(150):
        x = NoiseGenerator(settings, rate, seed).accelerometer(0, n)
        ends.append(x[-1] - x[0])
    ends = np.concatenate(ends)
    expected_var = k_rw**2 * (n - 1) / rate
    m = len(ends)
    assert np.var(ends) / expected_var - 1 == pytest.approx(0, abs=K * np.sqrt(2 / m))
    # the walk continues across the block boundary (no reset): increments on either side are alike
    x = NoiseGenerator(settings, rate, 0).accelerometer(0, n)
    jump = np.abs(x[BLOCK_SAMPLES] - x[BLOCK_SAMPLES - 1])
    assert np.all(jump < K * k_rw / np.sqrt(rate))


def _gauss_markov_avar(q, tc, tau):
    x = tau / tc
    return 2 * q * tc / tau * (1 - (3 - 4 * np.exp(-x) + np.exp(-2 * x)) / (2 * x))


def test_bias_instability_allan_variance():
    b = 2e-5
    settings = NoiseSettings(bias_instability=b, bias_instability_time_constants=(1.0, 10.0, 100.0, 1000.0))
    rate = 10.0
    n = 8 * BLOCK_SAMPLES
    m = np.array([10, 100, 1000])
    tau = m / rate
    avars = np.vstack([allan_deviation(NoiseGenerator(settings, rate, seed).accelerometer(0, n), rate, m).T ** 2 for seed in range(10)])
    q = settings.gauss_markov_sigma**2
    model = sum(_gauss_markov_avar(q, tc, tau) for tc in settings.bias_instability_time_constants)
    mean, sem = avars.mean(axis=0), avars.std(axis=0, ddof=1) / np.sqrt(len(avars))
    assert np.all(np.abs(mean - model) < K * sem)
    # a decade inside the correlation times the Allan deviation is flat near 0.664 B (flicker floor)
    inside = (tau >= 10 * 1.0) & (tau <= 1000.0 / 10)
    assert np.all(np.abs(np.sqrt(model[inside]) / (0.664 * b) - 1) < 0.1)
    assert np.all(np.abs(np.sqrt(mean[inside]) / (0.664 * b) - 1) < 0.1 + K * np.sqrt(sem[inside] / mean[inside]))


def test_noise_is_a_function_of_sample_index_only():
    settings = NoiseSettings(velocity_random_walk=1e-3, bias_instability=1e-5, acceleration_random_walk=1e-6, angle_noise=1e-6)
    whole = NoiseGenerator(settings, 100.0, seed=9).accelerometer(0, 3 * BLOCK_SAMPLES)
    late = NoiseGenerator(settings, 100.0, seed=9).accelerometer(2 * BLOCK_SAMPLES + 17, 500)
    np.testing.assert_array_equal(late, whole[2 * BLOCK_SAMPLES + 17 : 2 * BLOCK_SAMPLES + 517])
    g = NoiseGenerator(settings, 100.0, seed=9)
    parts = np.vstack([g.angles(0, 1000), g.angles(1000, BLOCK_SAMPLES)])
    np.testing.assert_array_equal(parts, NoiseGenerator(settings, 100.0, seed=9).angles(0, 1000 + BLOCK_SAMPLES))


def test_temperature_profile_and_sensor_noise():
    profile = TemperatureProfile(reference=20.0, offset=1.0, ramp=1e-4, amplitude=0.5, period=3600.0, sensor_noise=0.02)
    t = np.array([0.0, 900.0, 1800.0])
    np.testing.assert_allclose(profile(t), 21.0 + 1e-4 * t + 0.5 * np.sin(2 * np.pi * t / 3600.0))
    x = NoiseGenerator(NoiseSettings(temperature=profile), 10.0, seed=1).temperature_sensor(0, 20000)
    assert x.std() / 0.02 - 1 == pytest.approx(0, abs=K / np.sqrt(2 * 20000))
