"""Fine stage: squared-amplitude observation, exact recovery, pair degeneracy, honest σ."""

import numpy as np
import pytest
from device_world import GRAVITY, draw_truth, outputs
from scipy import stats

from stableins.conventions import ARCSEC
from stableins.errormodel import BETA_IDS
from stableins.estimators.coarse import calibrate_coarse
from stableins.estimators.device_gauge import gauge_equivalent
from stableins.estimators.dwell import DwellSummary
from stableins.estimators.fine import FINE_GAUGE_PREFERENCE, FineProblem, calibrate_fine, fine_model, solve_fine
from stableins.estimators.setting import DeviceSetting
from stableins.procedures.definition import load_procedure

READINGS = np.array([s.command for s in load_procedure("device-fine").steps])
MODEL = fine_model()
FREE = np.array([k not in FINE_GAUGE_PREFERENCE for k in MODEL.ids])


def _vector(values):
    return np.array([values[k] for k in MODEL.ids])


def _dwells(means, sigma, stage):
    return [
        DwellSummary(p + 1, stage, 1, r, r, m, np.full(3, sigma), np.full(3, 1e-3), 1000, 600.0)
        for p, (r, m) in enumerate(zip(READINGS, means))
    ]


def _coarse_and_fine(truth, rng, sigma_coarse, sigma_fine):
    coarse_means = outputs(truth, READINGS) + sigma_coarse * rng.normal(size=(18, 3))
    coarse = calibrate_coarse(_dwells(coarse_means, max(sigma_coarse, 1e-9), "coarse"), setting=DeviceSetting(GRAVITY))
    fine_means = outputs(truth, READINGS) + sigma_fine * rng.normal(size=(18, 3))
    return coarse, calibrate_fine(_dwells(fine_means, max(sigma_fine, 1e-9), "fine"), coarse, gravity=GRAVITY)


def test_exact_recovery_without_noise():
    truth = draw_truth(np.random.default_rng(21))
    _, fine = _coarse_and_fine(truth, np.random.default_rng(0), 0.0, 0.0)
    # The carried angle sums are in the coarse gauge θ10 = 0; the norm is invariant under
    # that rotation, so the fine stage recovers the gauge-equivalent scale factors exactly.
    expected = gauge_equivalent(truth)
    for k in ("sf_x", "sf_y", "sf_z", "bias_x", "bias_y", "bias_z", "K2_x", "K2_y", "K2_z"):
        assert fine[k][0] == pytest.approx(expected[k], abs=1e-5 * MODEL[k].nominal), k  # second order in the carried angles
    combos = fine.combinations
    assert combos["beta_xz − beta_yz"][0] == pytest.approx(expected["beta_xz"] - expected["beta_yz"], abs=1e-3 * ARCSEC)
    assert combos["beta_zy − beta_xy"][0] == pytest.approx(expected["beta_zy"] - expected["beta_xy"], abs=1e-3 * ARCSEC)
    assert combos["beta_yx − beta_zx"][0] == pytest.approx(expected["beta_yx"] - expected["beta_zx"], abs=1e-3 * ARCSEC)


def test_pair_degeneracy_is_found_and_shown():
    truth = draw_truth(np.random.default_rng(22))
    coarse, fine = _coarse_and_fine(truth, np.random.default_rng(1), 3e-5, 5e-6)
    assert fine.rank == 12 and fine.null_space.shape == (15, 3)
    # the null space is spanned by the three sums β_xz+β_yz, β_zy+β_xy, β_yx+β_zx
    sums = np.zeros((15, 3))
    for col, (a, b) in enumerate((("beta_xz", "beta_yz"), ("beta_zy", "beta_xy"), ("beta_yx", "beta_zx"))):
        sums[MODEL.index(a), col] = sums[MODEL.index(b), col] = 1 / np.sqrt(2)
    projection = sums @ sums.T
    np.testing.assert_allclose(projection @ fine.null_space, fine.null_space, atol=1e-3)
    for k in BETA_IDS:
        value, _, status = fine[k]
        assert status == "unidentifiable" and value == coarse[k][0]
    assert "—" in fine.report().split("beta_xz")[1].split("\n")[0]
    assert any(d.startswith("beta_xz − beta_yz =") for d in fine.determined)


def test_norm_observation_is_blind_to_antisymmetric_installation_change():
    truth = draw_truth(np.random.default_rng(23))
    means = outputs(truth, READINGS)[None]
    problem = FineProblem(means, np.full(means.shape, 1e-5), GRAVITY, MODEL)
    x = _vector(truth)[None]
    shifted = x.copy()
    for a, b in (("beta_xz", "beta_yz"), ("beta_zy", "beta_xy"), ("beta_yx", "beta_zx")):
        shifted[0, MODEL.index(a)] += 5e-5
        shifted[0, MODEL.index(b)] += 5e-5
    r0 = problem.weighted(x)[0]
    r1 = problem.weighted(shifted)[0]
    assert np.abs(r0).max() < 1e-6  # truth fits exactly
    assert np.abs(r1).max() < 0.05  # sums move the norm only at second order (β·Δβ ~ 1e-8 g)
    diff = x.copy()
    diff[0, MODEL.index("beta_xz")] += 5e-5
    assert np.abs(problem.weighted(diff)[0]).max() > 10.0  # a difference is seen


def test_jacobian_matches_finite_differences():
    truth = draw_truth(np.random.default_rng(24))
    means = outputs(truth, READINGS)[None] * (1 + 1e-4)
    problem = FineProblem(means, np.full(means.shape, 1e-5), GRAVITY, MODEL)
    x = _vector(truth)[None]
    _, h, jac, _ = problem.evaluate(x)
    for k, term in enumerate(MODEL):
        step = np.zeros_like(x)
        step[0, k] = 1e-3 * term.nominal
        numeric = (problem.evaluate(x + step)[1] - problem.evaluate(x - step)[1]) / (2 * step[0, k])
        assert np.abs(numeric - jac[..., k]).max() <= 1e-6 * np.abs(jac[..., k]).max(), term.id


def test_recovery_and_honest_sigma_over_seeds():
    rng = np.random.default_rng(77)
    trials, sigma = 400, 4e-6
    truths = [draw_truth(rng) for _ in range(trials)]
    means = np.stack([outputs(t, READINGS) for t in truths]) + sigma * rng.normal(size=(trials, 18, 3))
    problem = FineProblem(means, np.full(means.shape, sigma), GRAVITY, MODEL)
    x0 = np.stack([_vector(t) for t in truths])
    start = x0.copy()
    start[:, ~FREE] = x0[:, ~FREE]  # sums at truth: errors then measure the determined combinations only
    noise = np.array([t.nominal for t in MODEL]) * 0.05 * rng.normal(size=x0.shape)
    start[:, FREE] += noise[:, FREE]
    sol = solve_fine(problem, start)
    err = (sol.x - x0)[:, FREE]
    cov = sol.covariance[:, FREE][:, :, FREE]
    z = err / np.sqrt(np.diagonal(cov, axis1=1, axis2=2))
    assert np.all(np.abs(z.mean(axis=0)) < 4 / np.sqrt(trials))
    assert np.all(np.abs(z.std(axis=0) - 1) < 0.12)
    nees = np.einsum("ti,tij,tj->t", err, np.linalg.inv(cov), err)
    lo, hi = stats.chi2.ppf([0.001, 0.999], 12 * trials) / trials
    assert lo < nees.mean() < hi


def test_fine_position_off_the_model_is_not_silent():
    truth = draw_truth(np.random.default_rng(25))
    rng = np.random.default_rng(2)
    coarse_means = outputs(truth, READINGS) + 3e-5 * rng.normal(size=(18, 3))
    coarse = calibrate_coarse(_dwells(coarse_means, 3e-5, "coarse"), setting=DeviceSetting(GRAVITY))
    fine_means = outputs(truth, READINGS) + 5e-6 * rng.normal(size=(18, 3))
    clean = calibrate_fine(_dwells(fine_means, 5e-6, "fine"), coarse, gravity=GRAVITY)
    assert not any(n.startswith("warning:") for n in clean.notes)
    fine_means[10, 0] += 2e-3  # position 11 (x up): 0.2 mg on x, 400σ of the mean
    bad = calibrate_fine(_dwells(fine_means, 5e-6, "fine"), coarse, gravity=GRAVITY)
    warnings = [n for n in bad.notes if n.startswith("warning:")]
    assert len(warnings) == 1 and "pos 11 |f|" in warnings[0]
