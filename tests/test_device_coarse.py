"""Coarse stage: exact recovery, gauge, order invariance, statistical honesty, offset iteration."""

from dataclasses import replace

import numpy as np
import pytest
from device_world import GRAVITY, TRUTH_MODEL, ExactPlatform, draw_truth, outputs
from scipy import stats

from stableins.conventions import ARCSEC, DEFAULT_GIMBALS, MICRO_G
from stableins.estimators.coarse import CoarseProblem, calibrate_coarse, coarse_model, solve_coarse
from stableins.estimators.design import analyze_design, choose_gauge
from stableins.estimators.device_gauge import gauge_equivalent
from stableins.estimators.dwell import DwellSummary
from stableins.estimators.setting import DeviceSetting
from stableins.procedures.definition import OffsetIteration, load_procedure
from stableins.procedures.iteration import OffsetIterationError, iterate_offsets, measure_pass

PROCEDURE = load_procedure("device-coarse")
READINGS = np.array([s.command for s in PROCEDURE.steps])
MODEL = coarse_model()


def _vector(values):
    return np.array([values[k] for k in MODEL.ids])


def _dwells(means, sigma, readings=READINGS, positions=None):
    positions = range(1, len(means) + 1) if positions is None else positions
    return [
        DwellSummary(p, "coarse", 1, r, r, m, np.full(3, sigma), np.full(3, sigma * 40), 2000, 20.0)
        for p, r, m in zip(positions, readings, means)
    ]


def test_exact_recovery_without_noise_in_the_theta10_gauge():
    truth = draw_truth(np.random.default_rng(11), quadratic=False)
    fit = calibrate_coarse(_dwells(outputs(truth, READINGS), 1e-9), setting=DeviceSetting(GRAVITY))
    expected = gauge_equivalent(truth)
    for k in MODEL.ids:
        assert fit[k][0] == pytest.approx(expected[k], abs=1e-6 * MODEL[k].nominal), k
    assert fit["theta10"] == (0.0, 0.0, "gauge")
    # the gauge is not arbitrary: β_xz, β_yz absorb θ10 exactly
    assert fit["beta_xz"][0] == pytest.approx(truth["beta_xz"] + truth["theta10"], abs=1e-3 * ARCSEC)
    assert fit["beta_yz"][0] == pytest.approx(truth["beta_yz"] + truth["theta10"], abs=1e-3 * ARCSEC)


def test_gauge_equivalent_reproduces_every_output():
    truth = draw_truth(np.random.default_rng(5), offset_scale=20.0)
    rng = np.random.default_rng(6)
    readings = rng.uniform(-np.pi, np.pi, size=(50, 3))
    np.testing.assert_allclose(outputs(gauge_equivalent(truth), readings), outputs(truth, readings), atol=1e-13)


def test_theta10_gauge_is_detected_from_the_design():
    truth = draw_truth(np.random.default_rng(2), quadratic=False)
    fit = calibrate_coarse(_dwells(outputs(truth, READINGS), 1e-5), setting=DeviceSetting(GRAVITY))
    assert fit.rank == 14 and fit.null_space.shape == (15, 1)
    v = dict(zip(MODEL.ids, fit.null_space[:, 0]))
    # first order: θ10 and β_xz, β_yz move together, β_xz − θ10·(−1) ...
    assert abs(v["beta_xz"]) == pytest.approx(abs(v["theta10"]), rel=1e-6)
    assert v["beta_xz"] == pytest.approx(v["beta_yz"], rel=1e-6) and v["beta_xz"] * v["theta10"] < 0
    assert fit.singular_values[-1] < 1e-8 * fit.singular_values[0] < fit.singular_values[-2]
    assert "beta_xz estimates beta_xz + theta10" in fit.determined
    assert "beta_yz estimates beta_yz + theta10" in fit.determined
    assert any(n.startswith("gauge: theta10") for n in fit.notes)
    assert fit.covariance[MODEL.index("theta10")].max() == 0.0


def test_gauge_choice_follows_preference_on_a_toy_design():
    a = np.array([[1.0, 1.0, 0.0], [2.0, 2.0, 1.0], [0.0, 0.0, 3.0], [1.0, 1.0, 1.0]])  # p0 and p1 only via p0 + p1
    design = analyze_design(a, ("p0", "p1", "p2"), np.ones(3))
    assert design.rank == 2
    gauge = choose_gauge(design, ("p1",))
    assert gauge.fixed == ("p1",) and gauge.combination("p0") == "p0 + p1"


def test_invariant_to_position_order():
    rng = np.random.default_rng(3)
    truth = draw_truth(rng, quadratic=False)
    means = outputs(truth, READINGS) + 2e-5 * rng.normal(size=(18, 3))
    dwells = _dwells(means, 2e-5)
    a = calibrate_coarse(dwells, setting=DeviceSetting(GRAVITY))
    b = calibrate_coarse([dwells[i] for i in rng.permutation(18)], setting=DeviceSetting(GRAVITY))
    np.testing.assert_allclose(a.values, b.values, rtol=0, atol=1e-12)
    np.testing.assert_allclose(a.covariance, b.covariance, rtol=1e-9, atol=1e-30)


def test_jacobian_matches_finite_differences():
    truth = draw_truth(np.random.default_rng(8), quadratic=False, offset_scale=30.0)
    problem = CoarseProblem(READINGS[None], np.zeros((1, 18, 3)), np.ones((1, 18, 3)), GRAVITY, np.eye(3), DEFAULT_GIMBALS, MODEL)
    x = _vector(truth)[None]
    _, jac = problem.predict(x)
    for k, term in enumerate(MODEL):
        h = np.zeros_like(x)
        h[0, k] = 1e-3 * term.nominal
        numeric = (problem.predict(x + h)[0] - problem.predict(x - h)[0]) / (2 * h[0, k])
        assert np.abs(numeric - jac[..., k]).max() <= 1e-6 * np.abs(jac[..., k]).max() + 1e-12, term.id


def _batch_means(truths, sigma, rng):
    """Dwell means of many devices at once (exact model, Gaussian noise of the mean)."""
    out = np.stack([outputs(t, READINGS) for t in truths])
    return out + sigma * rng.normal(size=out.shape)


def test_recovery_within_k_sigma_and_honest_covariance_over_seeds():
    rng = np.random.default_rng(2024)
    trials, sigma = 400, 3e-5
    truths = [draw_truth(rng, quadratic=False) for _ in range(trials)]
    means = _batch_means(truths, sigma, rng)
    problem = CoarseProblem(
        np.broadcast_to(READINGS, means.shape).copy(), means, np.full(means.shape, sigma), GRAVITY, np.eye(3), DEFAULT_GIMBALS, MODEL
    )
    sol = solve_coarse(problem)
    free = np.array([k != "theta10" for k in MODEL.ids])
    truth_vec = np.stack([_vector(gauge_equivalent(t)) for t in truths])
    err = (sol.x - truth_vec)[:, free]
    cov = sol.covariance[:, free][:, :, free]
    z = err / np.sqrt(np.diagonal(cov, axis1=1, axis2=2))
    nees = np.einsum("ti,tij,tj->t", err, np.linalg.inv(cov), err)
    assert np.all(np.abs(z.mean(axis=0)) < 4 / np.sqrt(trials))  # unbiased
    assert np.all(np.abs(z.std(axis=0) - 1) < 0.12)  # σ honest per parameter
    lo, hi = stats.chi2.ppf([0.001, 0.999], 14 * trials) / trials
    assert lo < nees.mean() < hi
    # single estimates within 5σ
    assert np.abs(z).max() < 5.0


def test_full_pass_through_the_platform_recovers_truth_within_k_sigma():
    for seed in (1, 2, 3):
        truth = draw_truth(np.random.default_rng(seed), quadratic=False)
        platform = ExactPlatform(truth, sigma=2e-3, seed=seed)
        dwells = measure_pass(platform, PROCEDURE, (0, 0, 0))
        fit = calibrate_coarse(dwells, setting=DeviceSetting(GRAVITY), expected_positions=PROCEDURE.positions)
        expected = gauge_equivalent(truth)
        for k in MODEL.ids:
            value, sigma, status = fit[k]
            if status == "estimated":
                assert abs(value - expected[k]) < 4.5 * sigma, (seed, k)
        assert 0.4 < fit.chi2_red < 1.8
        assert fit["bias_x"][1] < 5 * MICRO_G


def test_offset_iteration_converges_from_60_arcsec():
    truth = draw_truth(np.random.default_rng(4), quadratic=False)
    truth.update(theta20=60 * ARCSEC, theta30=-60 * ARCSEC, theta10=45 * ARCSEC)
    platform = ExactPlatform(truth, sigma=1e-6, seed=4)  # nearly noiseless: the 0.1″ threshold itself is tested
    result = iterate_offsets(platform, PROCEDURE, stopping=replace(PROCEDURE.offset_iteration, noise_sigmas=0.0))
    assert len(result.history) <= 3
    assert abs(result.history[0].residual[0] - 60 * ARCSEC) < 0.1 * ARCSEC
    last = result.history[-1]
    assert all(abs(r) < 0.1 * ARCSEC for r in last.residual)
    assert result.offsets[1] == pytest.approx(60 * ARCSEC, abs=0.05 * ARCSEC)
    assert result.offsets[2] == pytest.approx(-60 * ARCSEC, abs=0.05 * ARCSEC)
    # the last pass was commanded re-pointed through the driver: inner = nominal − θ̂20
    assert platform.commands[-1][1] == pytest.approx(PROCEDURE.steps[-1].command[1] - result.history[-1].commanded_offsets[0])


def test_offset_iteration_with_noise_stops_at_the_noise_floor():
    truth = draw_truth(np.random.default_rng(9), quadratic=False)
    result = iterate_offsets(ExactPlatform(truth, sigma=1e-3, seed=9), PROCEDURE)
    assert 2 <= len(result.history) <= 3 and result.history[-1].converged


def test_offset_iteration_result_combines_every_pass():
    z, ratios = [], []
    for seed in (9, 19, 29):
        truth = draw_truth(np.random.default_rng(seed), quadratic=False)
        truth.update(theta20=30 * ARCSEC, theta30=-20 * ARCSEC)
        result = iterate_offsets(ExactPlatform(truth, sigma=1e-3, seed=seed), PROCEDURE, nonlinear=False)
        k = len(result.history)
        assert k >= 2 and result.fit.details.passes == tuple(range(1, k + 1)) and result.last is not None
        assert len(result.fit.residuals) == 3 * 18 * k  # every pass's dwells, each with its own readings
        for term in ("sf_x", "bias_z", "beta_yx", "theta20", "theta30"):
            ratios.append(result.fit[term][1] * np.sqrt(k) / result.last[term][1])
        expected = gauge_equivalent(truth)
        z += [
            (v - expected[i]) / s
            for i, v, s, st in zip(result.fit.ids, result.fit.values, result.fit.sigma, result.fit.status)
            if st == "estimated"
        ]
    # k equal independent passes: 1σ of the joint fit = 1σ of one pass / √k
    np.testing.assert_allclose(ratios, 1.0, atol=0.05)
    assert np.abs(z).max() < 4.5 and 0.5 < np.mean(np.square(z)) < 1.6


def test_offset_iteration_failure_reports_history():
    truth = draw_truth(np.random.default_rng(10), quadratic=False)
    stopping = OffsetIteration(threshold=1e-3 * ARCSEC, max_passes=2, noise_sigmas=0.0)
    with pytest.raises(OffsetIterationError) as info:
        iterate_offsets(ExactPlatform(truth, sigma=1e-3, seed=10), PROCEDURE, stopping=stopping)
    assert len(info.value.history) == 2 and "pass 1" in str(info.value) and "pass 2" in str(info.value)
    assert str(info.value).count("limit (0.001, 0.001)″ = max(threshold, noise_sigmas·σ): not converged") == 2


def test_report_and_result_are_frozen():
    truth = draw_truth(np.random.default_rng(12), quadratic=False)
    fit = calibrate_coarse(_dwells(outputs(truth, READINGS), 1e-5), setting=DeviceSetting(GRAVITY))
    text = fit.report()
    assert "rank = 14 of 15" in text and "gauge" in text
    with pytest.raises(ValueError):
        fit.values[0] = 1.0
    assert fit.residuals.shape == (54,) and fit.residual_labels[4] == "pos 2 f_y"
    assert set(MODEL.ids) <= set(TRUTH_MODEL.ids)  # the truth model is a superset of the coarse model


def test_gauss_newton_stopped_at_its_limit_is_reported():
    truth = draw_truth(np.random.default_rng(13), quadratic=False)
    means = outputs(truth, READINGS)[None]
    problem = CoarseProblem(READINGS[None], means, np.full(means.shape, 1e-5), GRAVITY, np.eye(3), DEFAULT_GIMBALS, MODEL)
    from stableins.estimators.gauss_newton import convergence_warning

    one = solve_coarse(problem, max_iterations=1)  # one step from the ideal instrument cannot reach 1e-9
    assert not one.converged[0] and "did not converge in 1 iterations" in convergence_warning(one)
    full = solve_coarse(problem)
    assert full.converged[0] and convergence_warning(full) is None
