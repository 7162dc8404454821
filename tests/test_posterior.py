"""A stage as a Bayesian update: the posterior against the Kalman filter, no σ grows, nothing moves where the data are blind."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from stableins.estimators.posterior import bayesian_update
from stableins.estimators.result import Likelihood
from stableins.status import Determination, Status


def problem(seed: int, n: int = 6, m: int = 3):
    """A correlated prior over ``n`` parameters of mixed scales and a rank-``m`` measurement of them."""
    rng = np.random.default_rng(seed)
    scale = np.exp(rng.uniform(np.log(1e-7), np.log(1e-3), n))
    a = rng.normal(size=(n, n + 2))
    p0 = (a @ a.T / n) * np.outer(scale, scale)
    x0 = rng.normal(size=n) * scale
    h = rng.normal(size=(m, n)) / scale[None, :] * rng.uniform(0.3, 3.0, size=(m, 1))
    truth = x0 + rng.multivariate_normal(np.zeros(n), p0)
    y = h @ truth + rng.normal(size=m)
    point = x0 + rng.normal(size=n) * scale  # the likelihood is linearized elsewhere than the prior
    return [f"p{i}" for i in range(n)], x0, p0, h, y, Likelihood.from_weighted([f"p{i}" for i in range(n)], point, h, y - h @ point)


@pytest.mark.parametrize("seed", range(5))
def test_posterior_is_the_kalman_update(seed):
    ids, x0, p0, h, y, likelihood = problem(seed)
    post = bayesian_update(ids, x0, p0, [Status.ESTIMATED] * len(ids), likelihood)
    s = h @ p0 @ h.T + np.eye(len(y))
    k = p0 @ h.T @ np.linalg.inv(s)
    np.testing.assert_allclose(post.values, x0 + k @ (y - h @ x0), rtol=0, atol=1e-9 * np.sqrt(np.diag(p0)).max())
    np.testing.assert_allclose(post.covariance, p0 - k @ h @ p0, rtol=0, atol=1e-9 * np.abs(p0).max())
    assert post.determination == (Determination.COMBINATION,) * len(ids)  # rank 3 of 6: no parameter alone


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 10_000), st.integers(1, 5))
def test_no_sigma_grows_and_nothing_moves_where_the_data_are_blind(seed, m):
    ids, x0, p0, h, _, likelihood = problem(seed, n=6, m=m)
    post = bayesian_update(ids, x0, p0, [Status.ESTIMATED] * 6, likelihood)
    assert np.all(post.sigma <= np.sqrt(np.diag(p0)) * (1 + 1e-9))
    # directions the data do not see: information and (information-weighted) update are the prior's
    lam0, lam1 = np.linalg.inv(p0), np.linalg.inv(post.covariance)
    null = np.linalg.svd(h)[2][m:]
    for w in null:
        prior_information = w @ lam0 @ w
        assert abs(w @ lam1 @ w - prior_information) <= 1e-7 * prior_information
        delta = post.values - x0
        # Cauchy-Schwarz bounds |wᵀΛ₁δ| by sqrt(wᵀΛ₁w · δᵀΛ₁δ); the update has no component along w at all
        assert abs(w @ lam1 @ delta) <= 1e-7 * np.sqrt((w @ lam1 @ w) * (delta @ lam1 @ delta))


def test_gauge_is_held_and_unseen_parameters_keep_value_and_sigma():
    ids = ["a", "b", "gauge", "c"]
    p0 = np.diag([4.0, 9.0, 0.0, 1.0])
    p0[0, 1] = p0[1, 0] = 3.0  # a and b correlated; c independent of both
    x0 = np.array([1.0, 2.0, 0.0, 5.0])
    # the data see a and the gauge: the gauge must not move, c must not change at all, b moves by its correlation with a
    a = np.array([[2.0, 0.0, 1.0, 0.0]])
    likelihood = Likelihood.from_weighted(ids, np.array([1.5, 2.0, 0.0, 5.0]), a, np.array([0.0]))
    post = bayesian_update(ids, x0, p0, [Status.ESTIMATED, Status.ESTIMATED, Status.GAUGE, Status.ESTIMATED], likelihood)
    assert post.values[2] == 0.0 and post.covariance[2, 2] == 0.0 and post.status[2] is Status.GAUGE
    assert post.values[3] == 5.0 and post.covariance[3, 3] == 1.0 and post.determination[3] is None
    gain = 4.0 * 2.0 / (2.0 * 4.0 * 2.0 + 1.0)  # measurement 2a = 3 with unit noise
    assert post.values[0] == pytest.approx(1.0 + gain * (3.0 - 2.0))
    assert post.values[1] == pytest.approx(2.0 + 3.0 * 2.0 / 17.0 * (3.0 - 2.0))
    assert post.determination[0] is Determination.ALONE and post.determination[1] is None


def test_parameters_new_to_the_record_and_what_nothing_determines():
    # the prior knows a; the data determine a + b and b − c: b and c enter from the data; d is seen by nobody
    likelihood = Likelihood(("a", "b", "c"), np.zeros(3), np.array([[1.0, 1.0, 0.0], [1.0, 2.0, -1.0], [0.0, -1.0, 1.0]]), np.zeros(3))
    post = bayesian_update(
        ["a", "d"], np.array([0.0, 7.0]), np.array([[1.0, np.nan], [np.nan, np.nan]]), ["estimated", "unidentifiable"], likelihood
    )
    assert post.ids == ("a", "d", "b", "c")
    assert post.status == (Status.ESTIMATED, Status.UNIDENTIFIABLE, Status.ESTIMATED, Status.ESTIMATED)
    assert np.isnan(post.covariance[1, 1]) and post.values[1] == 7.0
    # without a prior on a, the same data leave one direction free: then b and c are not identified either
    free = bayesian_update([], np.zeros(0), np.zeros((0, 0)), [], likelihood)
    assert set(free.status) == {Status.UNIDENTIFIABLE}


def test_likelihood_data_only_matches_least_squares():
    rng = np.random.default_rng(3)
    a = rng.normal(size=(20, 4))
    a[:, 3] = a[:, 0] + a[:, 1]  # rank 3: p0 + p1 + ... aliasing
    truth = np.array([1.0, 2.0, 3.0, 0.5])
    r = a @ truth + rng.normal(size=20)
    likelihood = Likelihood.from_weighted(["a", "b", "c", "d"], np.zeros(4), a, r)
    values, sigma = likelihood.data_only()
    assert list(likelihood.estimable()) == [False, False, True, False] and likelihood.rank() == 3
    solution, *_ = np.linalg.lstsq(a, r, rcond=None)
    assert values[2] == pytest.approx(solution[2]) and np.isnan(values[0])
    assert sigma[2] == pytest.approx(np.sqrt(np.linalg.pinv(a.T @ a)[2, 2]))


@pytest.mark.parametrize("seed", range(4))
def test_parameters_the_data_leave_free_are_integrated_out_not_held(seed):
    """New parameters the data determine only in part (here only c + d) are marginalized: the record's parameters get the
    σ of a joint Kalman update with the new ones under an uninformative prior, and keep their prior status."""
    rng = np.random.default_rng(seed)
    ids = ["a", "b", "c", "d"]
    p0 = np.diag([1.0, 4.0])
    # observations of a, b and of c + d together (the direction c − d is free): c + d is coupled to a and b
    h = rng.normal(size=(5, 4))
    h[:, 3] = h[:, 2]
    y = rng.normal(size=5)
    likelihood = Likelihood.from_weighted(ids, np.zeros(4), h, y)
    post = bayesian_update(["a", "b"], np.zeros(2), p0, [Status.ESTIMATED] * 2, likelihood)
    assert post.status == (Status.ESTIMATED, Status.ESTIMATED, Status.UNIDENTIFIABLE, Status.UNIDENTIFIABLE)
    # reference: the data see c and d only as s = c + d; with s free (no prior) the joint posterior of (a, b, s) is regular
    reduced = h[:, :3]
    information = reduced.T @ reduced
    information[:2, :2] += np.linalg.inv(p0)
    covariance = np.linalg.inv(information)
    np.testing.assert_allclose(post.covariance[:2, :2], covariance[:2, :2], rtol=1e-9)
    np.testing.assert_allclose(post.values[:2], (covariance @ reduced.T @ y)[:2], rtol=1e-9)
    assert np.all(post.sigma[:2] <= np.sqrt(np.diag(p0)) * (1 + 1e-9))


def test_a_weakly_determined_new_direction_never_takes_a_stated_prior_with_it():
    """New parameters c, d that the data see as c + d well and as c − d barely (below the rank tolerance), coupled to a
    parameter with a prior: c and d are left undetermined, the prior's parameter keeps an estimate and a σ (before,
    rounding put a into the undetermined direction and the record lost its σ: issue 18, a short system-indexed run)."""
    h = np.array([[1e3, 1e3, 1e3 * (1 + 1e-5)], [0.0, 1.0, 1.0], [0.0, 1e-4, -1e-4]])  # rows: a + c + d, c + d, c − d
    likelihood = Likelihood(("a", "c", "d"), np.zeros(3), h.T @ h, np.zeros(3))
    post = bayesian_update(["a"], np.zeros(1), np.array([[1.0]]), [Status.ESTIMATED], likelihood)
    assert post.status == (Status.ESTIMATED, Status.UNIDENTIFIABLE, Status.UNIDENTIFIABLE)
    assert 0.0 < post.sigma[0] <= 1.0
