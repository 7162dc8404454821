r"""Slow noise from the residual scatter between passes: restricted maximum likelihood (REML) on contrasts.

Every dwell of a device session (coarse passes and fine stage) is a three-axis row ``ȳ − h(x̂)`` at its measured
readings.  The dwells at one orientation (the coarse passes and the fine dwell of a position) see the same
instrument and the same effects, missing ones included; what differs between them is what changes in time: white
noise (``s²/n`` measured in each dwell) and slow noise.  The *within-position contrasts* ``c = C r`` (Helmert
contrasts inside each group of dwells whose mean readings agree within 0.01 rad; re-pointing moves them by ~1e-3 rad,
which the model's geometry absorbs) therefore carry the slow noise and nothing the model misses at a position: a
between-dwell variance component fitted to all residuals would absorb a missing effect as "noise" and hide it from
model discovery.  (A drift or a temperature change is slow in time and is seen, as slow noise.)

With ``V(θ) = C (V_0 + b S_B + k S_K) Cᵀ`` per axis: ``V_0`` white, ``S_B`` and ``S_K`` the dwell-mean covariances of
a unit bias instability (1 µg) and random walk (1e-7 m/s²/√s) on the session's clock
(:meth:`stableins.noise.NoiseModel.slow_covariance`), ``θ = (b, k) ≥ 0`` (``B² = b µg²``, ``K² = k·1e-14``), the same
on the three axes.  The contrasts estimate nothing, so the restricted log-likelihood (Patterson & Thompson 1971;
Harville 1977, Eq. 4.2) is the likelihood of ``c``:

.. math::
    \ell_R(θ) = -\tfrac12\left[\log|V| + c^T V^{-1} c\right]

(the general form with a design ``H``, ``−½[log|V| + log|HᵀV⁻¹H| + rᵀPr]``, is kept for other uses and tested to
be independent of the linearization point).  The within-dwell Allan evidence
(:func:`stableins.estimators.slow_noise.slow_noise_test`: an unbiased estimate ``b̂_A`` of ``B²`` with its standard
error ``s_A``, from contrasts inside each dwell and so independent of the dwell means under white noise) is added as
the Gaussian term ``−½ (b − b̂_A)²/s_A²``.  The estimate ``θ̂`` maximizes the sum.

**The decision.** The score of ``ℓ_R`` at ``θ = 0`` along ``S = S_B/tr(V_0⁻¹ S_B) + S_K/tr(V_0⁻¹ S_K)`` is
``U = cᵀ V_0⁻¹ S V_0⁻¹ c``; under white noise it is a quadratic form with mean ``tr(V_0⁻¹ S)`` and variance
``2 tr((V_0⁻¹ S)²)`` (exact), and its p-value ``p_R`` comes from the scaled χ² with those two moments
(Satterthwaite).  With the within-dwell p-value ``p_A`` (independent under white noise) Fisher's combination
``−2(ln p_R + ln p_A) ~ χ²_4`` gives the session's p-value; slow noise is *detected* when it is below α (5 %).

**Where the data cannot resolve it.**  The common mode of the slow noise over a session is a bias: no contrast sees
it, only the model's spectrum extrapolates it from the pass-to-pass scatter (docs/noise.md §3).  The σ use ``θ̂``
whether or not it is detected; the decision only says whether the data exclude white noise.

**The amplitude the σ use** (issue 25).  ``b̂`` scatters by ±50–70 % from session to session, and a σ computed from
it is a noisy estimate of the true one: with ``z = e/σ̂`` and ``σ̂² = Φ(b̂)``, ``E z² = Φ(b) E[1/Φ(b̂)] > 1`` (Jensen;
1/x is convex), and the σ are too small on average where the slow part dominates them (the biases, whose
common-mode wander only the spectrum extrapolates).  To second order (delta method, ``Φ`` linear in ``b``),
``E[1/Φ(b̂)] = (1/Φ)(1 + Φ'² Var(b̂)/Φ²)``, and a parameter whose variance the slow noise carries a share
``ρ_p = b̂Φ'_p/Φ_p`` of has ``E z_p² = 1 + ρ_p² Var(b̂)/b̂²``.  One noise model must serve every σ, so the amplitude
corrects the parameter the slow noise dominates most (``ρ = max_p ρ_p``; the others are then conservative by at most
``ρ_p(ρ − ρ_p) Var(b̂)/b̂²``):

.. math::
    b_σ = \min\left(b̂ + ρ\,\frac{\mathrm{Var}(b̂)}{b̂},\; b_{up}\right), \qquad b̂ > 0

with ``Var(b̂)`` the inverse of the restricted likelihood's curvature in ``b`` at the optimum (``k`` at its value: the
observed information, Allan term included), capped at the profile upper limit ``b_up`` (the largest floor the dwells
allow).  At the boundary ``b̂ = 0`` the estimate is not a smooth function of the data (its curvature is not its
sampling variance; about half of the white sessions land there) and the σ stay white: ``b_σ = 0``.  ``k`` is used as
estimated: a session does not bound it above (its curvature says little).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from stableins.conventions import MICRO_G, dcm_nav_to_body
from stableins.estimators.coarse import CoarseProblem, coarse_model
from stableins.estimators.dwell import DwellSummary
from stableins.estimators.result import FitResult
from stableins.estimators.setting import DeviceSetting
from stableins.noise import NoiseModel, SlowNoiseTest

#: Units of the variance components: bias instability 1 µg, random walk 1e-7 m/s²/√s (the quartz figures' order).
UNIT_B = MICRO_G
UNIT_K = 1e-7


@dataclass(frozen=True)
class ResidualSlowNoise:
    """The slow noise the residuals between dwells (and the Allan variance inside them) show.

    Attributes
    ----------
    bias_instability, random_walk : float
        REML estimates of ``B`` [m/s²] and ``K`` [m/s²/√s] (0 at the boundary).
    bias_instability_upper : float
        Upper limit of ``B`` (random walk profiled out) where ``ℓ`` falls by ``z²/2`` (one-sided ``confidence``).
    test : SlowNoiseTest
        The combined decision (statistic: the residual score standardized; p: Fisher's combination).
    residual_p, allan_p : float
        The p-values of the residual score test and of the within-dwell Allan test.
    rows, dof : int
        Contrasts (observations of the likelihood) and their degrees of freedom (the same: the contrasts estimate nothing).
    bias_instability_variance : float
        ``Var(B̂²)`` [(m/s²)⁴]: the inverse curvature of the restricted likelihood (Allan term included) in ``B²`` at
        the optimum, ``K`` at its estimate (0 at the boundary ``B̂ = 0``).
    """

    bias_instability: float
    random_walk: float
    bias_instability_upper: float
    test: SlowNoiseTest
    residual_p: float
    allan_p: float
    rows: int
    dof: int
    bias_instability_variance: float = 0.0

    def bias_instability_for_sigma(self, slow_fraction: float) -> float:
        r"""Return the ``B`` [m/s²] the σ use: ``B̂²`` with the second-order (Jensen) correction of the σ it dominates.

        .. math:: B_σ^2 = \min\left(B̂^2 + ρ\,\mathrm{Var}(B̂^2)/B̂^2,\; B_{up}^2\right), \qquad B̂ > 0

        with ``ρ = slow_fraction`` the largest share of an estimated parameter's variance that ``B̂`` carries (module
        docstring, "The amplitude the σ use"); ``0`` at the boundary ``B̂ = 0``; the estimate when its variance is unknown.
        """
        b2 = self.bias_instability**2
        if b2 <= 0.0:
            return 0.0
        if not (math.isfinite(self.bias_instability_variance) and self.bias_instability_variance > 0.0):
            return self.bias_instability
        rho = min(max(float(slow_fraction), 0.0), 1.0)
        return math.sqrt(min(b2 + rho * self.bias_instability_variance / b2, max(self.bias_instability_upper**2, b2)))


@dataclass(frozen=True)
class _Components:
    residual: NDArray[np.float64]
    design: NDArray[np.float64]
    white: NDArray[np.float64]
    unit_b: NDArray[np.float64]
    unit_k: NDArray[np.float64]


#: Dwells whose mean readings agree within this [rad] are the same position (re-pointing moves them by ~1e-3 rad).
SAME_POSITION = 0.01


def _position_groups(dwells: Sequence[DwellSummary]) -> list[list[int]]:
    """Return the indices of the dwells at each orientation (mean readings within :data:`SAME_POSITION`), in acquisition order."""
    groups: list[list[int]] = []
    for i, d in enumerate(dwells):
        angles = np.asarray(d.angles, dtype=float)
        for g in groups:
            if np.max(np.abs(np.asarray(dwells[g[0]].angles, dtype=float) - angles)) < SAME_POSITION:
                g.append(i)
                break
        else:
            groups.append([i])
    return groups


def _contrasts(groups: list[list[int]], m: int) -> NDArray[np.float64]:
    """Return Helmert contrasts within each group: ``(q, m)``, rows orthonormal, each summing to zero inside one group."""
    rows = []
    for g in groups:
        for j in range(1, len(g)):
            row = np.zeros(m)
            row[g[:j]] = 1.0 / j
            row[g[j]] = -1.0
            rows.append(row / np.linalg.norm(row))
    return np.array(rows).reshape(-1, m)


def _components(
    coarse_dwells: Sequence[DwellSummary], fine_dwells: Sequence[DwellSummary], setting: DeviceSetting, fit: FitResult
) -> _Components:
    """Within-position contrasts of the dwell-mean residuals and their covariance components (module docstring).

    Every dwell (coarse and fine) is a three-axis row ``ȳ − h(x̂)``; contrasts between dwells at the same orientation
    (passes, stages) cancel whatever the model misses there (a hidden effect is the same at the same position), so
    only what changes in time is left: the slow noise, and a drift or thermal change (slow too).
    """
    dwells = [*coarse_dwells, *fine_dwells]
    model = coarse_model(nonlinear=any(i.startswith("K2_") for i in fit.ids), extra_terms=setting.extra_terms)
    values = fit.as_dict()
    x = model.vector({k: values.get(k, model[k].reference) for k in model.ids})[None]
    problem = CoarseProblem.from_dwells(dwells, setting.gravity, dcm_nav_to_body(*setting.base_attitude), setting.configuration, model)
    residual = problem.means[0] - problem.predict(x)[0][0]  # (m, 3)
    m = len(dwells)
    contrast = _contrasts(_position_groups(dwells), m)
    starts = np.array([d.start for d in dwells], dtype=float)
    lengths = np.array([d.duration for d in dwells], dtype=float)
    unit_b = NoiseModel.given(bias_instability=UNIT_B).slow_covariance(starts, lengths)
    unit_k = NoiseModel.given(random_walk=UNIT_K).slow_covariance(starts, lengths)
    sem = np.array([d.sem for d in dwells])

    def blocks(per_axis: list[NDArray[np.float64]]) -> NDArray[np.float64]:
        q = contrast.shape[0]
        out = np.zeros((3 * q, 3 * q))
        for a, block in enumerate(per_axis):
            out[a * q : (a + 1) * q, a * q : (a + 1) * q] = contrast @ block @ contrast.T
        return out

    return _Components(
        np.concatenate([contrast @ residual[:, a] for a in range(3)]),
        np.zeros((3 * contrast.shape[0], 0)),
        blocks([np.diag(sem[:, a] ** 2) for a in range(3)]),
        blocks([unit_b[a] for a in range(3)]),
        blocks([unit_k[a] for a in range(3)]),
    )


def _restricted_loglik(c: _Components, b: float, k: float) -> float:
    v = c.white + b * c.unit_b + k * c.unit_k
    try:
        lower = np.linalg.cholesky(v)
    except np.linalg.LinAlgError:
        return -math.inf
    wr = np.linalg.solve(lower, c.residual)
    logdet = 2.0 * float(np.sum(np.log(np.diag(lower))))
    if c.design.shape[1] == 0:  # contrasts: nothing estimated
        return -0.5 * (logdet + float(wr @ wr))
    wh = np.linalg.solve(lower, c.design)
    info = wh.T @ wh
    try:
        info_lower = np.linalg.cholesky(info)
    except np.linalg.LinAlgError:
        return -math.inf
    g = np.linalg.solve(info_lower, wh.T @ wr)
    quad = float(wr @ wr - g @ g)
    return -0.5 * (logdet + 2.0 * float(np.sum(np.log(np.diag(info_lower)))) + quad)


def _score_p(c: _Components) -> tuple[float, float]:
    """Residual score test at θ = 0 (module docstring): standardized statistic and p-value."""
    from stableins.estimators.distributions import chi2_sf

    vi = np.linalg.inv(c.white)
    p0 = vi
    if c.design.shape[1] > 0:
        vih = vi @ c.design
        p0 = vi - vih @ np.linalg.solve(c.design.T @ vih, vih.T)
    s = c.unit_b / max(float(np.trace(p0 @ c.unit_b)), 1e-300) + c.unit_k / max(float(np.trace(p0 @ c.unit_k)), 1e-300)
    pr = p0 @ c.residual
    u = float(pr @ s @ pr)
    ps = p0 @ s
    mean = float(np.trace(ps))
    var = 2.0 * float(np.sum(ps * ps.T))
    if not (mean > 0 and var > 0):
        return 0.0, 1.0
    g, h = var / (2.0 * mean), 2.0 * mean**2 / var
    return (u - mean) / math.sqrt(var), chi2_sf(u / g, h)


def residual_slow_noise(
    coarse_dwells: Sequence[DwellSummary],
    fine_dwells: Sequence[DwellSummary],
    *,
    setting: DeviceSetting,
    fit: FitResult,
    allan: tuple[float, float, float] | None = None,
    alpha: float = 0.05,
    confidence: float = 0.95,
) -> ResidualSlowNoise:
    """Return the REML estimate of the slow noise and the combined decision (module docstring).

    ``fit`` is a joint fit of these dwells (any noise model: the restricted likelihood does not depend on where it
    is linearized to first order); ``allan`` the within-dwell evidence ``(B̂², its standard error, p)`` [(m/s²)²] of
    :func:`stableins.estimators.slow_noise.slow_noise_test` (None: residuals alone).
    """
    from stableins.estimators.distributions import chi2_sf

    c = _components(coarse_dwells, fine_dwells, setting, fit)
    b_a = s_a = math.nan
    allan_p = 1.0
    if allan is not None and math.isfinite(allan[1]) and allan[1] > 0:
        b_a, s_a, allan_p = allan[0] / UNIT_B**2, allan[1] / UNIT_B**2, allan[2]
    b_hat, k_hat, hi, variance = _reml(c, b_a, s_a, confidence)
    statistic, residual_p = _score_p(c)
    combined = chi2_sf(-2.0 * (math.log(max(residual_p, 1e-300)) + math.log(max(allan_p, 1e-300))), 4)
    rows, params = c.design.shape
    return ResidualSlowNoise(
        math.sqrt(b_hat) * UNIT_B,
        math.sqrt(k_hat) * UNIT_K,
        math.sqrt(hi) * UNIT_B,
        SlowNoiseTest(statistic, combined, alpha),
        residual_p,
        allan_p,
        rows,
        rows - params,
        variance * UNIT_B**4,
    )


def _reml(c: _Components, b_a: float, s_a: float, confidence: float) -> tuple[float, float, float, float]:
    """Return ``(b̂, k̂, b_up, Var(b̂))`` in the units of ``b`` and ``k`` (module docstring).

    The restricted log-likelihood of ``c`` plus the Allan term ``−½ (b − b_a)²/s_a²`` (left out when ``s_a`` is NaN),
    maximized over ``b, k ≥ 0``; ``b_up`` where the objective, ``k`` profiled, falls by ``z²/2`` (one-sided
    ``confidence``); ``Var(b̂)`` from its curvature in ``b`` (:func:`_variance_of_b`).
    """
    from scipy.optimize import minimize

    from stableins.estimators.distributions import norm_ppf

    def objective(theta: NDArray[np.float64]) -> float:
        b, k = float(theta[0]), float(theta[1])
        value = _restricted_loglik(c, b, k)
        if math.isfinite(s_a):
            value -= 0.5 * ((b - b_a) / s_a) ** 2
        return -value if math.isfinite(value) else 1e300

    starts = ([0.0, 0.0], [4.0, 0.0], [0.0, 4.0], [4.0, 4.0])
    best = min((minimize(objective, np.array(s), method="L-BFGS-B", bounds=[(0.0, 1e6), (0.0, 1e6)]) for s in starts), key=lambda r: r.fun)
    b_hat, k_hat = (max(float(v), 0.0) for v in best.x)
    # upper limit of b with k profiled: where the objective rises by z²/2 (one-sided)
    z = norm_ppf(confidence)
    target = float(best.fun) + 0.5 * z**2

    def profile(b: float) -> float:
        r = minimize(lambda kk: objective(np.array([b, float(kk[0])])), np.array([k_hat]), method="L-BFGS-B", bounds=[(0.0, 1e6)])
        return float(r.fun)

    upper = max(b_hat, 1e-6) * 2.0
    while profile(upper) < target and upper < 1e6:
        upper *= 2.0
    lo, hi = b_hat, upper
    for _ in range(30):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if profile(mid) < target else (lo, mid)
    return b_hat, k_hat, hi, _variance_of_b(lambda b: objective(np.array([b, k_hat])), b_hat)


def _variance_of_b(objective: Callable[[float], float], b_hat: float) -> float:
    """Return ``1/∂²(−ℓ)/∂b²`` at ``b̂`` (the REML curvature; module docstring), 0 at the boundary or if not positive.

    Central second difference with step ``h = max(0.05 b̂, 0.01)`` [unit b], forward where ``b̂ < h``.
    """
    if b_hat <= 0.0:
        return 0.0
    h = max(0.05 * b_hat, 0.01)
    if b_hat >= h:
        d2 = (objective(b_hat + h) - 2.0 * objective(b_hat) + objective(b_hat - h)) / h**2
    else:
        d2 = (objective(b_hat + 2.0 * h) - 2.0 * objective(b_hat + h) + objective(b_hat)) / h**2
    return 1.0 / d2 if math.isfinite(d2) and d2 > 0.0 else 0.0


#: Level at which a given noise model (datasheet, another record's) is rejected by the residuals.
GIVEN_MODEL_ALPHA = 0.01


@dataclass(frozen=True)
class GivenNoiseTest:
    """Whether the residuals between dwells reject a given noise model (likelihood ratio against the REML optimum).

    Attributes
    ----------
    statistic : float
        ``2 (max ℓ_R − ℓ_R(θ_given))``, referred to χ²₂ (conservative at the boundary θ = 0).
    p_value, alpha : float
        The model is rejected when ``p_value < alpha``.
    bias_instability, random_walk : float
        The REML optimum of the residuals alone [m/s², m/s²/√s].
    """

    statistic: float
    p_value: float
    alpha: float
    bias_instability: float
    random_walk: float

    @property
    def rejected(self) -> bool:
        """Whether the data reject the given model at ``alpha``."""
        return self.p_value < self.alpha


def given_noise_test(
    coarse_dwells: Sequence[DwellSummary],
    fine_dwells: Sequence[DwellSummary],
    *,
    setting: DeviceSetting,
    fit: FitResult,
    model: NoiseModel,
    allan: tuple[float, float, float] | None = None,
    alpha: float = GIVEN_MODEL_ALPHA,
) -> GivenNoiseTest:
    """Return the likelihood-ratio test of ``model``'s slow noise (its mean ``B²``, ``K²`` over the axes).

    The likelihood is the residuals' restricted one plus the within-dwell Allan term (``allan`` as in
    :func:`residual_slow_noise`); the statistic ``2 (max ℓ − ℓ(θ_given))`` is referred to χ²₂.
    """
    from scipy.optimize import minimize

    from stableins.estimators.distributions import chi2_sf

    c = _components(coarse_dwells, fine_dwells, setting, fit)
    b_given = float(np.mean(model.values("bias_instability") ** 2)) / UNIT_B**2
    k_given = float(np.mean(model.values("random_walk") ** 2)) / UNIT_K**2
    b_a = s_a = math.nan
    if allan is not None and math.isfinite(allan[1]) and allan[1] > 0:
        b_a, s_a = allan[0] / UNIT_B**2, allan[1] / UNIT_B**2

    def loglik(b: float, k: float) -> float:
        value = _restricted_loglik(c, b, k)
        return value - 0.5 * ((b - b_a) / s_a) ** 2 if math.isfinite(s_a) else value

    given = loglik(b_given, k_given)

    def objective(theta: NDArray[np.float64]) -> float:
        value = loglik(float(theta[0]), float(theta[1]))
        return -value if math.isfinite(value) else 1e300

    starts = ([b_given, k_given], [0.0, 0.0], [4.0, 0.0], [0.0, 4.0])
    best = min((minimize(objective, np.array(s), method="L-BFGS-B", bounds=[(0.0, 1e6), (0.0, 1e6)]) for s in starts), key=lambda r: r.fun)
    statistic = max(2.0 * (-float(best.fun) - given), 0.0)
    b_hat, k_hat = (max(float(v), 0.0) for v in best.x)
    return GivenNoiseTest(statistic, chi2_sf(statistic, 2), alpha, math.sqrt(b_hat) * UNIT_B, math.sqrt(k_hat) * UNIT_K)
