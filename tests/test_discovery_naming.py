"""Issue 25: the naming rule of the ranking — the flags' level from the null, the best group, a signature left."""

from __future__ import annotations

import numpy as np
from scipy import stats

from stableins.discovery.ranking import _signature_left, family_level
from stableins.discovery.scores import GROUP_MARGIN


def _design(rng: np.random.Generator, m: int = 54, p: int = 17) -> tuple[np.ndarray, np.ndarray]:
    """A whitened design and an orthonormal basis of the space orthogonal to it."""
    x = rng.standard_normal((m, p))
    q, _ = np.linalg.qr(np.column_stack([x, rng.standard_normal((m, m - p))]))
    return x, q[:, p:]


def test_family_level_is_alpha_for_one_column_and_between_bonferroni_and_sidak_for_independent_ones():
    rng = np.random.default_rng(1)
    x, perp = _design(rng)
    nu, alpha = 54 - 17, 0.025
    one = np.repeat(perp[:, :1], 10, axis=1)  # ten copies of one candidate: one test
    assert abs(family_level(x, one, nu=nu, alpha=alpha) - alpha) < 4 * np.sqrt(alpha * (1 - alpha) / 8000)
    independent = perp[:, :10]  # ten orthogonal candidates
    level = family_level(x, independent, nu=nu, alpha=alpha)
    sidak = 1 - (1 - alpha) ** (1 / 10)
    assert alpha / 10 <= level <= 1.15 * sidak
    # the family's rate at that level is α: checked on fresh draws (not the function's own)
    e = rng.standard_normal((54, 20000))
    q, _ = np.linalg.qr(x)
    e -= q @ (q.T @ e)
    rss = np.sum(e * e, axis=0)
    delta = (independent.T @ e) ** 2
    p = stats.f.sf(delta / ((rss - delta) / (nu - 1)), 1, nu - 1)
    rate = float(np.mean(np.min(p, axis=0) < level))
    assert abs(rate - alpha) < 4 * np.sqrt(alpha * (1 - alpha) / 20000)


def test_a_rival_beats_the_true_effect_by_the_group_margin_at_most_2_5_percent():
    """The derivation at GROUP_MARGIN: at the worst separation s = √M, P(ΔRSS_rival − ΔRSS_true > M) ≈ Φ(−√M) = 2.5 %."""
    rng = np.random.default_rng(2)
    n, a = 40000, 6.0
    for s in (0.5 * np.sqrt(GROUP_MARGIN), np.sqrt(GROUP_MARGIN), 2.0 * np.sqrt(GROUP_MARGIN)):
        rho = np.sqrt(1.0 - (s / a) ** 2)
        u0, u1 = np.array([1.0, 0.0]), np.array([rho, np.sqrt(1.0 - rho**2)])
        r = a * u0[:, None] + rng.standard_normal((2, n))
        beaten = np.mean((u1 @ r) ** 2 - (u0 @ r) ** 2 > GROUP_MARGIN)
        assert beaten <= 0.025 + 4 * np.sqrt(0.025 * 0.975 / n), (s, beaten)


def test_a_residual_along_the_laboratory_columns_is_a_signature_left_and_noise_is_not():
    rng = np.random.default_rng(3)
    m, nu = 54, 37
    _, perp = _design(rng)
    candidate, laboratory = perp[:, :1], perp[:, 1:7]
    noise = perp[:, 7:] @ rng.standard_normal(perp.shape[1] - 7)
    # the candidate takes its own part; a part along the laboratory columns (5σ) is left
    r = 8.0 * candidate[:, 0] + 5.0 * laboratory[:, 0] + noise
    assert _signature_left(0, candidate, r, laboratory, nu=nu) < 0.01
    # pure noise besides the candidate: p uniform, so the rule refuses a true name at its level
    ps = []
    for _ in range(400):
        e = perp @ rng.standard_normal(perp.shape[1])
        ps.append(_signature_left(0, candidate, 8.0 * candidate[:, 0] + e, laboratory, nu=nu))
    assert abs(np.mean(np.array(ps) < 0.05) - 0.05) < 4 * np.sqrt(0.05 * 0.95 / 400)
    assert m == perp.shape[0]
