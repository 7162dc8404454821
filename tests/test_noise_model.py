"""The instrument's noise model (stableins.noise): closed forms against brute force and the simulator, documents, validation."""

import json
import math

import numpy as np
import pytest

from stableins.errors import InputError
from stableins.noise import FLICKER_FLOOR, AxisNoise, NoiseModel, NoiseSource, NoiseTerm, SlowNoiseTest, sessions
from stableins.simulator.noise import NoiseGenerator, NoiseSettings, allan_deviation


def _brute_force_window_covariance(start, length, autocovariance, dt=0.05):
    grids = [np.arange(s, s + t, dt) + dt / 2 for s, t in zip(start, length)]
    out = np.zeros((len(grids), len(grids)))
    for i, gi in enumerate(grids):
        for j, gj in enumerate(grids):
            out[i, j] = autocovariance(gi[:, None], gj[None, :]).mean()
    return out


def test_flicker_window_covariance_matches_brute_force_of_the_gauss_markov_sum():
    from stableins.noise import FLICKER_TIME_CONSTANTS, FLICKER_VARIANCE_PER_B2

    start, length = np.array([0.0, 30.0, 100.0]), np.array([20.0, 20.0, 50.0])
    model = NoiseModel.given(bias_instability=1.0)

    def acf(s, t):
        return FLICKER_VARIANCE_PER_B2 * sum(np.exp(-np.abs(s - t) / tc) for tc in FLICKER_TIME_CONSTANTS)

    np.testing.assert_allclose(model.slow_covariance(start, length)[1], _brute_force_window_covariance(start, length, acf), rtol=3e-3)


def test_random_walk_window_covariance_matches_brute_force():
    start, length, k = np.array([0.0, 30.0, 100.0]), np.array([20.0, 20.0, 50.0]), 1e-6
    exact = NoiseModel.given(random_walk=k).slow_covariance(start, length)[2]
    np.testing.assert_allclose(exact, _brute_force_window_covariance(start, length, lambda s, t: k**2 * np.minimum(s, t)), rtol=2e-3)


def test_allan_variance_terms_follow_ieee_952():
    tau = np.array([0.01, 1.0, 100.0, 1e4])
    n, k, q = 4.5e-4, 1e-7, 3e-6
    np.testing.assert_allclose(NoiseModel.given(white=n).allan_variance(tau)[:, 0], n**2 / tau)
    np.testing.assert_allclose(NoiseModel.given(random_walk=k).allan_variance(tau)[:, 1], k**2 * tau / 3)
    np.testing.assert_allclose(NoiseModel.given(quantization=q).allan_variance(tau)[:, 2], 3 * q**2 / tau**2)
    floor = NoiseModel.given(bias_instability=1.0).allan_deviation(np.logspace(1, 4, 13))[:, 0]
    assert np.all(np.abs(floor / FLICKER_FLOOR - 1) < 0.06)  # flat to ±6 % from 10 s to 1e4 s


def test_allan_variance_is_var_minus_adjacent_covariance_of_window_means():
    model = NoiseModel.given(white=1e-4, bias_instability=5e-6, random_walk=1e-6)
    for tau in (3.0, 300.0, 3e4):
        c = model.dwell_mean_covariance([0.0, tau], [tau, tau])[0]
        np.testing.assert_allclose(0.5 * (c[0, 0] + c[1, 1]) - c[0, 1], model.allan_variance(tau)[0, 0], rtol=1e-9)


def test_allan_variance_matches_the_simulator_flicker_within_its_flat_band():
    """The simulator's Gauss-Markov sum (10 s ... 1e5 s) against the model's Allan floor, 64 realizations of 6 h at 1 Hz."""
    settings = NoiseSettings(bias_instability=2e-5)
    taus = np.array([100, 300, 1000])
    adev = np.array([allan_deviation(NoiseGenerator(settings, 1.0, seed).accelerometer(0, 21600), 1.0, taus) for seed in range(64)])
    measured = np.sqrt(np.mean(adev**2, axis=(0, 2)))
    expected = NoiseModel.given(bias_instability=2e-5).allan_deviation(taus)[:, 0]
    np.testing.assert_allclose(measured, expected, rtol=0.12)


def test_dwell_mean_covariance_white_part_and_sessions():
    model = NoiseModel.given(white=1e-3, bias_instability=1e-5, quantization=1e-6)
    start, length = np.array([0.0, 30.0, 0.0, 30.0]), np.full(4, 20.0)
    assert sessions(start, length).tolist() == [0, 0, 1, 1]
    cov = model.dwell_mean_covariance(start, length)
    assert cov.shape == (3, 4, 4)
    assert np.all(cov[:, :2, 2:] == 0.0)  # separate sessions are independent
    white = model.dwell_mean_covariance(start, length) - model.slow_covariance(start, length)
    np.testing.assert_allclose(np.diagonal(white, axis1=1, axis2=2), 1e-6 / 20 + 2e-12 / 400)
    measured = np.full((4, 3), 7e-8)
    given = model.dwell_mean_covariance(start, length, measured) - model.slow_covariance(start, length)
    np.testing.assert_allclose(np.diagonal(given, axis1=1, axis2=2), 7e-8 + 2e-12 / 400)


def test_document_round_trip_keeps_unbounded_limits_and_the_test():
    axis = AxisNoise(NoiseTerm(4e-4, 3.9e-4, 4.1e-4), NoiseTerm(0.0, 0.0, 3e-5), NoiseTerm.unbounded(), NoiseTerm.exact(0.0))
    model = NoiseModel((axis, axis, axis), NoiseSource.DEVICE_DWELLS, "18 fine dwells", 0.95, SlowNoiseTest(0.4, 0.34, 0.05))
    doc = json.loads(json.dumps(model.to_document(), allow_nan=False))
    assert doc["axes"]["y"]["random_walk"]["upper"] is None
    back = NoiseModel.from_document(doc)
    assert back == model and not back.slow_noise_bounded and not back.test.detected
    assert "not bounded" in back.report()


@pytest.mark.parametrize(
    ("mutate", "field"),
    [
        (lambda d: d.update(source="guess"), "noise_model.source"),
        (lambda d: d["axes"].pop("z"), "noise_model.axes"),
        (lambda d: d["axes"]["x"]["white"].update(value=-1.0), "noise_model.axes.x.white.value"),
        (lambda d: d["axes"]["y"]["bias_instability"].update(upper=1e-9), "noise_model.axes.y.bias_instability"),
        (lambda d: d["axes"]["z"]["quantization"].update(lower=None), "noise_model.axes.z.quantization.lower"),
        (lambda d: d.update(confidence=1.5), "noise_model.confidence"),
        (lambda d: d.update(units={"white": "ug/sqrt(Hz)"}), "noise_model.units"),
        (lambda d: d.update(test={"statistic": 1.0, "p_value": 2.0, "alpha": 0.05}), "noise_model.test"),
        (lambda d: d["axes"]["x"].pop("random_walk"), "noise_model.axes.x"),
    ],
)
def test_bad_documents_name_the_field(mutate, field):
    doc = NoiseModel.given(4.5e-4, 2e-5, 1e-7).to_document()
    mutate(doc)
    with pytest.raises(InputError) as error:
        NoiseModel.from_document(doc, path="cal.json")
    assert error.value.field == field and "cal.json" in str(error.value)


def test_terms_validate_their_interval_and_upper_limits_scale_the_floor():
    with pytest.raises(ValueError):
        NoiseTerm(1.0, 2.0, 3.0)
    model = NoiseModel.given(white=4.5e-4).with_values(bias_instability=0.0)
    bounded = replace_slow(model, 3e-5, 1e-7)
    top = bounded.at_upper_limits()
    assert np.allclose(top.values("bias_instability"), 3e-5) and np.allclose(top.values("random_walk"), 1e-7)
    with pytest.raises(ValueError):
        NoiseModel.unknown().at_upper_limits()
    assert math.isinf(NoiseModel.unknown().axes[0].random_walk.upper)


def replace_slow(model, b_up, k_up):
    from dataclasses import replace

    axes = tuple(replace(a, bias_instability=NoiseTerm(0.0, 0.0, b_up), random_walk=NoiseTerm(0.0, 0.0, k_up)) for a in model.axes)
    return replace(model, axes=axes)
