"""Slow noise from the residuals between dwells (stableins.estimators.residual_noise): REML and its score test.

Synthetic linear problems with a known covariance ``V = V_0 + b S_B + k S_K`` (a Gauss-Markov and a random-walk
shaped component on a dwell time line): the restricted likelihood does not depend on where the fit is linearized,
the estimate recovers a large component within its spread, and the score test fires at its designed rate on white
residuals.
"""

from __future__ import annotations

import numpy as np
import pytest

from stableins.estimators.residual_noise import _Components, _restricted_loglik, _score_p


def _problem(rng: np.random.Generator, rows: int = 60, params: int = 8) -> _Components:
    t = np.arange(rows) * 600.0
    white = np.diag(rng.uniform(0.5, 1.5, rows))
    gm = np.exp(-np.abs(t[:, None] - t[None, :]) / 3000.0)
    walk = np.minimum(t[:, None], t[None, :]) / t[-1] + 0.1
    design = rng.standard_normal((rows, params))
    return _Components(np.zeros(rows), design, white, gm, walk)


def _with_residual(c: _Components, b: float, k: float, rng: np.random.Generator) -> _Components:
    v = c.white + b * c.unit_b + k * c.unit_k
    r = np.linalg.cholesky(v) @ rng.standard_normal(len(c.residual)) + c.design @ rng.standard_normal(c.design.shape[1])
    return _Components(r, c.design, c.white, c.unit_b, c.unit_k)


def test_restricted_likelihood_does_not_depend_on_the_linearization_point():
    rng = np.random.default_rng(1)
    c = _with_residual(_problem(rng), 0.5, 0.2, rng)
    moved = _Components(c.residual + c.design @ rng.standard_normal(c.design.shape[1]), c.design, c.white, c.unit_b, c.unit_k)
    for b, k in ((0.0, 0.0), (0.7, 0.1), (2.0, 3.0)):
        assert abs(_restricted_loglik(c, b, k) - _restricted_loglik(moved, b, k)) < 1e-8


def test_reml_recovers_a_large_component():
    """Profile over b on a grid: the maximum lies within 3 of its curvature σ of the truth (b = 2, k = 0)."""
    rng = np.random.default_rng(2)
    c = _with_residual(_problem(rng, rows=200), 2.0, 0.0, rng)
    grid = np.linspace(0.0, 8.0, 161)
    values = np.array([_restricted_loglik(c, b, 0.0) for b in grid])
    best = int(np.argmax(values))
    curvature = -(values[best + 1] - 2 * values[best] + values[best - 1]) / (grid[1] - grid[0]) ** 2
    assert abs(grid[best] - 2.0) < 3.0 / np.sqrt(curvature)


def test_score_test_false_alarm_rate_on_white_residuals():
    """400 white residual vectors of one design: the test fires at 5 % ± 3.3σ (binomial, 1.1 %)."""
    rng = np.random.default_rng(3)
    c = _problem(rng)
    fired = sum(_score_p(_with_residual(c, 0.0, 0.0, rng))[1] < 0.05 for _ in range(400))
    assert abs(fired / 400 - 0.05) < 3.3 * np.sqrt(0.05 * 0.95 / 400)
    # and it has power against a component of the size of the white noise
    power = sum(_score_p(_with_residual(c, 1.0, 0.0, rng))[1] < 0.05 for _ in range(100))
    assert power > 50


def _session(noise, seed: int = 3):
    from stableins.estimators.dwell import dwells_from_columns
    from stableins.procedures.definition import device_layouts, load_procedure
    from stableins.simulator.device import simulate_dwells
    from stableins.simulator.truth import Truth

    truth = Truth.draw(seed, noise=noise)
    layouts = device_layouts()
    coarse, fine = load_procedure("device-coarse"), load_procedure("device-fine")
    runs = [
        simulate_dwells(truth, [s.command for s in coarse.steps], dwell=10.0, settle=5.0, rate=2.0, seed=seed, stage="coarse"),
        simulate_dwells(truth, [s.command for s in fine.steps], dwell=60.0, settle=5.0, rate=2.0, seed=seed + 1, stage="fine"),
    ]
    return truth, layouts, [d for c in runs for d in dwells_from_columns(c, layouts=layouts)]


def test_default_path_measures_slow_noise_by_reml_and_a_rejected_datasheet_is_said():
    """White session: the default path's model says REML; a datasheet of 300 µg flicker is rejected, warned, not used."""
    import dataclasses

    from stableins.conventions import MICRO_G
    from stableins.estimators.device import calibrate_device, with_given_slow_noise
    from stableins.simulator.noise import NoiseSettings

    white = dataclasses.replace(NoiseSettings.quartz(), bias_instability=0.0, acceleration_random_walk=0.0, quantization=0.0)
    truth, layouts, dwells = _session(white)
    default = calibrate_device(dwells, truth.site, layouts=layouts)
    assert "restricted maximum likelihood" in default.noise.provenance
    given = with_given_slow_noise(dwells, 300 * MICRO_G, 0.0, "a wrong datasheet")
    calibration = calibrate_device(dwells, truth.site, layouts=layouts, noise=given)
    warnings = [n for n in calibration.final.notes if n.startswith("warning: the given noise model")]
    assert warnings and "rejected" in warnings[0]
    assert float(calibration.noise.values("bias_instability").max()) < 100 * MICRO_G  # the σ follow the data
    # the true (white) datasheet is kept
    kept = calibrate_device(dwells, truth.site, layouts=layouts, noise=with_given_slow_noise(dwells, 0.0, 0.0, "right"))
    assert not any("rejected" in n for n in kept.final.notes)


def test_variance_of_b_is_the_inverse_curvature_and_zero_at_the_boundary():
    from stableins.estimators.residual_noise import _variance_of_b

    def quadratic(b: float) -> float:
        return 0.5 * (b - 3.0) ** 2 / 0.8**2

    assert abs(_variance_of_b(quadratic, 3.0) - 0.8**2) < 1e-6
    assert abs(_variance_of_b(lambda b: 0.5 * (b - 0.004) ** 2 / 0.5**2, 0.004) - 0.25) < 1e-6  # forward difference near 0
    assert _variance_of_b(quadratic, 0.0) == 0.0
    assert _variance_of_b(lambda b: -(b**2), 1.0) == 0.0  # not a maximum: no variance claimed


def test_the_amplitude_the_sigma_use_is_the_second_order_correction_capped():
    from stableins.conventions import MICRO_G
    from stableins.estimators.residual_noise import ResidualSlowNoise
    from stableins.noise import SlowNoiseTest

    def residual(b: float, upper: float, variance: float) -> ResidualSlowNoise:
        return ResidualSlowNoise(b * MICRO_G, 0.0, upper * MICRO_G, SlowNoiseTest(0.0, 0.5, 0.05), 0.5, 0.5, 10, 10, variance * MICRO_G**4)

    # B² = 4 µg², Var(B²) = 4 µg⁴, ρ = 0.5: B_σ² = 4 + 0.5·4/4
    assert abs(residual(2.0, 5.0, 4.0).bias_instability_for_sigma(0.5) / MICRO_G - np.sqrt(4.5)) < 1e-9
    assert residual(2.0, 5.0, 4.0).bias_instability_for_sigma(0.0) == 2.0 * MICRO_G  # nothing carried: the estimate
    assert abs(residual(1.0, 1.5, 9.0).bias_instability_for_sigma(1.0) / MICRO_G - 1.5) < 1e-9  # capped at the upper limit
    assert residual(0.0, 2.0, 0.0).bias_instability_for_sigma(1.0) == 0.0  # the boundary stays white
    assert residual(2.0, 5.0, 0.0).bias_instability_for_sigma(1.0) == 2.0 * MICRO_G  # no curvature: the estimate


@pytest.mark.slow
def test_the_corrected_amplitude_makes_the_precision_of_a_slow_dominated_sigma_unbiased():
    """REML on 60 synthetic sessions with b = 2 (about 16 s of CPU): for a σ² = 1 + 2b (slow share 80 %), E[σ²(b)/σ²(b̂)] is > 1 at the
    estimate (Jensen) and closer to 1 with the corrected amplitude (residual_noise, "The amplitude the σ use")."""
    from stableins.estimators.residual_noise import _reml

    rng = np.random.default_rng(5)
    base = _problem(rng, rows=30, params=3)
    plug, corrected = [], []
    for _ in range(60):
        c = _with_residual(base, 2.0, 0.0, rng)
        b_hat, _, upper, variance = _reml(c, float("nan"), float("nan"), 0.95)
        rho = 2 * b_hat / (1 + 2 * b_hat)
        b_sigma = min(b_hat + rho * variance / b_hat, upper) if b_hat > 0 else 0.0
        plug.append((1 + 2 * 2.0) / (1 + 2 * b_hat))
        corrected.append((1 + 2 * 2.0) / (1 + 2 * b_sigma))
    assert np.mean(plug) > 1.1
    assert abs(np.mean(corrected) - 1.0) < abs(np.mean(plug) - 1.0)


def test_the_default_path_records_the_corrected_amplitude_between_the_estimate_and_its_upper_limit():
    """A session with strong flicker (30 µg): detected; the record's B is B̂ (its lower limit) moved up by the
    second-order correction and not beyond the profile upper limit; the slow share ρ it used is in (0, 1]."""
    import dataclasses

    from stableins.conventions import MICRO_G
    from stableins.estimators.device import calibrate_device
    from stableins.simulator.noise import NoiseSettings

    flicker = dataclasses.replace(NoiseSettings.quartz(), bias_instability=30 * MICRO_G, acceleration_random_walk=0.0, quantization=0.0)
    truth, layouts, dwells = _session(flicker)
    calibration = calibrate_device(dwells, truth.site, layouts=layouts)
    assert calibration.noise.test is not None and calibration.noise.test.detected
    term = calibration.noise.axes[0].bias_instability
    assert 0.0 < term.lower < term.value <= term.upper
    rho = float(calibration.noise.provenance.split("rho = ")[1].split()[0])
    assert 0.0 < rho <= 1.0
