"""bench_worlds ``--exact``: the world's exact dwell-mean covariance and the σ's predicted E z² (issue 25, docs/noise.md §5 H).

The campaign figures are in benchmarks/bench_worlds.py; here the two functions it adds are checked against an
independent implementation (the noise model's dwell-mean covariance) and on one session per case.
"""

from __future__ import annotations

import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

from bench_worlds import device_session, exact_dwell_covariance  # noqa: E402

from stableins.noise import FLICKER_TIME_CONSTANTS, NoiseModel  # noqa: E402
from stableins.simulator.noise import NoiseSettings  # noqa: E402


def test_exact_covariance_equals_the_noise_models_for_the_same_spectrum():
    # the noise model's Gauss-Markov sum, random walk and white part on one clock (docs/noise.md §1 "Dwell means")
    starts = np.array([0.0, 30.0, 60.0, 500.0, 1200.0, 4000.0])
    lengths = np.array([20.0, 20.0, 20.0, 600.0, 600.0, 600.0])
    dwells = [SimpleNamespace(start=s, duration=t) for s, t in zip(starts, lengths, strict=True)]
    settings = NoiseSettings(
        velocity_random_walk=4.5e-4,
        bias_instability=2e-5,
        acceleration_random_walk=1e-7,
        bias_instability_time_constants=FLICKER_TIME_CONSTANTS,
    )
    model = NoiseModel.given(4.5e-4, 2e-5, 1e-7, provenance="test")
    expected = model.dwell_mean_covariance(starts, lengths)
    np.testing.assert_allclose(exact_dwell_covariance(settings, dwells), expected, rtol=1e-12, atol=0.0)


def test_quantization_adds_its_window_variance():
    dwells = [SimpleNamespace(start=0.0, duration=20.0), SimpleNamespace(start=30.0, duration=20.0)]
    cov = exact_dwell_covariance(NoiseSettings(quantization=1e-3), dwells)
    np.testing.assert_allclose(cov[0], np.diag([2.0 * (1e-3**2 / 12.0) / 400.0] * 2), rtol=1e-12)


def test_true_white_model_predicts_unit_z2_and_the_flicker_form_misses_a_single_gauss_markov():
    # white world, its true noise given: the fit's R is diag(s²/n), the world's N²/T; E z² = 1 within the s² scatter
    # (seed 5 is one of the ~5 % of white sessions whose dwells reject white noise: there the σ follow the measured
    # slow noise and E z² is below 1)
    white = device_session("white", 6, 10.0, ("none", "true"), exact=True)
    values = np.array(list(white.predicted_given.values()))
    assert white.predicted_given and np.all(np.abs(values - 1.0) < 0.05), values
    # gauss-markov world (one 300-s process), default path: the flicker form's σ are too small for K2 and too large
    # for the biases (docs/noise.md §5 H)
    gm = device_session("gauss-markov", 6, 10.0, ("none",), exact=True)
    k2 = np.mean([gm.predicted_default[f"K2_{a}"] for a in "xyz"])
    bias = np.mean([gm.predicted_default[f"bias_{a}"] for a in "xyz"])
    assert k2 > 1.05 and bias < 0.8, (k2, bias)
