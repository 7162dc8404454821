r"""The coloured-noise decision of the system stage: the Whittle likelihood of the residual periodograms.

The expected periodograms (:func:`.spectrum.periodogram_design`) are linear in the white levels and the coloured
amplitudes; :func:`whittle_fit` finds the maximum of the Whittle likelihood under non-negativity, and
:func:`fit_coloured_noise` decides between white and coloured noise with a calibrated false-positive rate
(the χ̄² law of the likelihood ratio), gives the amplitudes (maximum likelihood, the posterior mode with a prior noise
model, or as given) and their profile-likelihood intervals: :class:`ColouredNoiseFit`.  docs/system-calibration.md §1a.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import Enum

import numpy as np
from numpy.typing import NDArray

from stableins.estimators.system.bootstrap import ZONE, OrdinateLaw, monte_carlo_p_value


# --------------------------------------------------------------------------- Whittle likelihood
def whittle_fit(
    design: NDArray[np.float64],
    observed: NDArray[np.float64],
    free: NDArray[np.bool_] | None = None,
    offset: NDArray[np.float64] | None = None,
    start: NDArray[np.float64] | None = None,
    *,
    penalty: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None,
) -> tuple[NDArray[np.float64], float]:
    r"""Maximum of the Whittle likelihood ``ℓ(θ) = −Σ_k [log E_k + P_k/E_k]``, ``E = design @ θ + offset``, over ``θ ≥ 0``.

    The ordinates are independent and exponentially distributed with means ``E_k`` (the Whittle approximation).
    ``free`` selects the columns fitted (the others stay 0; ``offset`` carries any fixed part of ``E``).  Projected Fisher
    scoring on columns scaled to the mean ordinate: the step solves ``I Δ = ∇ℓ`` with ``I = Dᵀ diag(E⁻²) D`` over the
    columns not held at their bound (a column at 0 whose gradient points below 0 is held), halved until ``ℓ`` increases;
    converged when the Newton decrement ``∇ℓᵀ I⁻¹ ∇ℓ < 1e-10``.  A few iterations of a few small matrix products: the
    stage runs dozens of these fits (decision, intervals) in milliseconds.  ``penalty = (mean, sd)`` per column adds a
    Gaussian prior ``−½ Σ ((θ_c − mean_c)/sd_c)²`` (``sd = inf``: none), an independent measurement of the levels; the
    maximum is then the posterior mode.  Returns ``θ`` and the (penalized) ``ℓ(θ)``.
    """
    p = design.shape[1]
    free = np.ones(p, dtype=bool) if free is None else np.asarray(free, dtype=bool)
    mean = float(observed.mean())
    scale = mean / np.maximum(design[:, free].mean(axis=0), 1e-300)
    a = design[:, free] * scale
    base = np.zeros(observed.size) if offset is None else np.asarray(offset, dtype=float)
    floor = 1e-12 * mean
    u = _scaled_start(a, base, floor, None if start is None else np.asarray(start, dtype=float)[free] / scale)
    centre, weight = _scaled_penalty(penalty, free, scale)

    def loglik(v: NDArray[np.float64]) -> tuple[float, NDArray[np.float64]]:
        e = np.maximum(a @ v + base, floor)
        return -float(np.sum(np.log(e) + observed / e)) - 0.5 * float(np.sum(weight * (v - centre) ** 2)), e

    value, e = loglik(u)
    for _ in range(200):
        gradient = a.T @ ((observed / e - 1.0) / e) - weight * (u - centre)
        moving = (u > 0.0) | (gradient > 0.0)
        if not moving.any():
            break
        scaled = a[:, moving] / e[:, None]
        fisher = scaled.T @ scaled + np.diag(weight[moving])
        try:
            step = np.linalg.solve(fisher, gradient[moving])
        except np.linalg.LinAlgError:
            step = np.linalg.lstsq(fisher, gradient[moving], rcond=None)[0]
        if float(gradient[moving] @ step) < 1e-10:
            break
        t = 1.0
        for _ in range(40):
            trial = u.copy()
            trial[moving] = np.maximum(u[moving] + t * step, 0.0)
            new, e_new = loglik(trial)
            if new >= value:
                break
            t *= 0.5
        else:
            break
        improved = new - value
        u, value, e = trial, new, e_new
        if improved < 1e-12 * max(1.0, abs(value)):
            break
    theta = np.zeros(p)
    theta[free] = u * scale
    return theta, value


def _scaled_start(
    a: NDArray[np.float64], base: NDArray[np.float64], floor: float, start: NDArray[np.float64] | None
) -> NDArray[np.float64]:
    """Return the start of :func:`whittle_fit` on the scaled columns ``a``: ``start`` clipped at 0, or equal weights.

    Equal weights ``1/p`` when no start is given or when the clipped start leaves every expectation at the floor.
    """
    if start is not None:
        u = np.maximum(start, 0.0)
        if np.any(a @ u + base > floor):
            return u
    return np.full(a.shape[1], 1.0 / a.shape[1])


def _scaled_penalty(
    penalty: tuple[NDArray[np.float64], NDArray[np.float64]] | None, free: NDArray[np.bool_], scale: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Return the Gaussian prior of :func:`whittle_fit` on the scaled free columns: ``(centre, 1/sd²)`` (weight 0: none)."""
    n = int(np.count_nonzero(free))
    if penalty is None:
        return np.zeros(n), np.zeros(n)
    sd = np.asarray(penalty[1], dtype=float)[free] / scale
    centre = np.asarray(penalty[0], dtype=float)[free] / scale
    weight = np.where(np.isfinite(sd) & (sd > 0), 1.0 / np.where(sd > 0, sd, 1.0) ** 2, 0.0)
    return np.where(weight > 0, centre, 0.0), weight


def _chi_bar_squared_sf(statistic: float, correlation: float | None) -> float:
    r"""``P(χ̄² ≥ statistic)`` for the likelihood ratio of ``θ = 0`` against ``θ ≥ 0`` (one or two amplitudes).

    Two amplitudes whose unconstrained estimates have correlation ``ρ``: ``χ̄² = w₁ χ²₁ + w₂ χ²₂`` with ``w₁ = ½``,
    ``w₂ = ¼ + arcsin(ρ)/(2π)`` (and ``w₀ = ½ − w₂`` at zero); one amplitude: ``½ χ²₁`` (Shapiro 1985; Self & Liang 1987).
    """
    from scipy.special import gammaincc  # χ²_k survival function: Q(k/2, x/2) (scipy.stats costs the stage's memory)

    if statistic <= 0.0:
        return 1.0
    if correlation is None:
        return 0.5 * float(gammaincc(0.5, 0.5 * statistic))
    w2 = 0.25 + math.asin(max(-1.0, min(1.0, correlation))) / (2.0 * math.pi)
    return 0.5 * float(gammaincc(0.5, 0.5 * statistic)) + w2 * float(gammaincc(1.0, 0.5 * statistic))


#: Confidence of the amplitudes' profile-likelihood intervals (:attr:`ColouredNoiseFit.lower`, ``upper``).
INTERVAL_CONFIDENCE = 0.95


class ColouredSource(Enum):
    """Where the coloured-noise amplitudes under σ come from."""

    #: The record alone: a decision with a calibrated false-positive rate, then the maximum-likelihood amplitudes.
    DATA = "the record alone"
    #: The record and the prior noise model (an earlier measurement): the posterior mode.
    PRIOR = "the record and the prior noise model"
    #: Given (a datasheet): the amplitudes are the given ones; the record's own fit is reported beside them.
    GIVEN = "given"
    #: Given, but the record rejects the given amplitudes (:func:`given_rejected`): the record's own are used.
    CONTRADICTED = "contradicted"


@dataclass(frozen=True)
class ColouredNoiseFit:
    """The coloured-noise amplitudes of a record and how they were decided (docs/system-calibration.md §1a).

    Attributes
    ----------
    amplitudes : ndarray (2, 3)
        The amplitudes used for σ per kind (:data:`.spectrum.COLOURED_KINDS`: random walk ``(K/g)²`` [1/s]; flicker, the variance of
        each Gauss-Markov process of :data:`FLICKER_TIME_CONSTANTS`, ``σ²/g² = (B/g)² ln 10/π``) and accelerometer axis:
        the maximum-likelihood values (or the posterior mode) when coloured noise is detected, the given ones, else 0.
    maximum_likelihood : ndarray (2,)
        The maximum of the record's Whittle likelihood over amplitudes ≥ 0 (one value for the three axes).
    lower, upper : ndarray (2,)
        Profile-likelihood interval of each amplitude at ``confidence`` (with the prior when there is one); ``upper`` is
        the largest amplitude the data allow.
    statistic, p_value : float
        ``2(ℓ_coloured − ℓ_white)`` of the record alone and its p-value under white noise: from the record's own null law
        (:mod:`.bootstrap`, ``null_draws`` draws) near the decision, else the asymptotic χ̄² (:func:`_chi_bar_squared_sf`).
    alpha : float
        False-positive rate of the decision: coloured noise is detected when ``p_value < alpha``.
    source : ColouredSource
        Where :attr:`amplitudes` come from.
    white_levels : ndarray
        White levels of the channels (z, pitch, roll) [per-sample variance, z in g²; pitch and roll in rad² at the blocks].
    ordinates : tuple of int
        Periodogram ordinates in the low band (z, pitch, roll) and in the z channel's high band.
    band : tuple of float
        Frequencies [Hz]: low band start, low band end (= high band start), high band end.
    """

    amplitudes: NDArray[np.float64]
    maximum_likelihood: NDArray[np.float64]
    lower: NDArray[np.float64]
    upper: NDArray[np.float64]
    statistic: float
    p_value: float
    alpha: float
    confidence: float
    source: ColouredSource = ColouredSource.DATA
    white_levels: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))
    ordinates: tuple[int, int] = (0, 0)
    band: tuple[float, float, float] = (0.0, 0.0, 0.0)
    #: Draws of the Monte Carlo null law behind :attr:`p_value` (0: the asymptotic χ̄² law).
    null_draws: int = 0

    @property
    def detected(self) -> bool:
        """The amplitudes under σ are not zero (detected by the decision, or given, or known from the prior)."""
        return bool(np.any(self.amplitudes > 0))

    @property
    def data_detected(self) -> bool:
        """The record alone shows coloured noise (``p_value < alpha``)."""
        return self.p_value < self.alpha

    def describe(self) -> str:
        """Say in one line what the decision found (likelihood ratio, p-value, false-positive rate, ordinates)."""
        verdict = "detected" if self.data_detected else "not detected"
        law = f"{self.null_draws} draws of the record's null law" if self.null_draws else "asymptotic law"
        return (
            f"low-frequency noise {verdict} in the record: likelihood ratio {self.statistic:.2f} against white noise, "
            f"p = {self.p_value:.3g} ({law}; false-positive rate {self.alpha:g}; {self.ordinates[0]} + {self.ordinates[1]} "
            "periodogram ordinates)"
        )


@dataclass(frozen=True)
class NoisePrior:
    """What a noise model known before the record says about the coloured amplitudes (:func:`.coloured.noise_prior`).

    Attributes
    ----------
    given : ndarray (2, 3) or None
        The amplitudes per kind and axis, used as they are (a datasheet model).
    gaussian : (ndarray (2,), ndarray (2,)) or None
        ``(mean, sd)`` of a Gaussian prior on each amplitude, one value for the three axes (an earlier measurement of
        the instrument; ``sd = inf``: nothing known).
    detected : bool
        The earlier measurement detected a slow term.
    """

    given: NDArray[np.float64] | None = None
    gaussian: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None
    detected: bool = False


def fit_coloured_noise(
    design: NDArray[np.float64],
    observed: NDArray[np.float64],
    channels: int,
    *,
    alpha: float = 0.05,
    prior: NoisePrior = NoisePrior(),
    offset: NDArray[np.float64] | None = None,
    law: OrdinateLaw | None = None,
) -> ColouredNoiseFit:
    """Decide whether the residuals carry coloured noise, with a calibrated false-positive rate, and fit its amplitudes.

    ``design`` columns: the channels' white levels, then the amplitudes of :data:`.spectrum.COLOURED_KINDS`.  The likelihood ratio of
    the coloured model against white noise alone, ``2(ℓ̂ − ℓ̂₀)``, has the χ̄² distribution under white noise
    (:func:`_chi_bar_squared_sf`, with the correlation of the amplitudes from the Fisher information at the white fit).
    Coloured noise is detected when its p-value is below ``alpha``; then the amplitudes are the maximum-likelihood ones
    (both, no further selection: dropping an amplitude that one day cannot pin leaves σ too small), otherwise 0.  The
    interval of each amplitude is the profile-likelihood one at :data:`INTERVAL_CONFIDENCE`; its upper end is what the data allow.
    Why a decision and not always the maximum: with white noise the maximum is above 0 in about 60 % of one-day records
    and a random-walk amplitude far below detection multiplies the variance at the harmonics (docs §1a).

    ``prior.gaussian = (mean, sd)`` of the amplitudes (an earlier measurement of the instrument; ``sd = inf``: nothing
    known): the amplitudes are then the posterior mode (:func:`whittle_fit` with the penalty) when the record or the prior
    (``prior.detected``) shows coloured noise, else 0.  ``prior.given`` ``(2, 3)``: the amplitudes per axis, used as they
    are (the record's own fit and decision are still reported).

    ``offset``: a known part of every expectation, ``E = design @ θ + offset`` (the pitch and roll channels' white
    levels held at the accelerometers' measured white noise through the loop, :func:`.coloured.coloured_covariance`).

    ``law``: the record's ordinates' own law (:class:`.bootstrap.OrdinateLaw`).  Given, a p-value within
    :data:`.bootstrap.ZONE` is the Monte Carlo one under the white fit (the asymptotic χ̄² assumes independent exponential
    ordinates, which the low band's are not: 6 % false alarms on white one-day records, docs §10); the same for the test
    of a given datasheet (:func:`given_rejected`).
    """
    from scipy.special import gammaincinv

    p = design.shape[1]
    kinds = p - channels
    base = np.zeros(observed.size) if offset is None else np.asarray(offset, dtype=float)
    theta0, loglik0, theta, loglik = _white_and_coloured(design, observed, channels, base)
    statistic = max(0.0, 2.0 * (loglik - loglik0))
    e0 = np.maximum(design @ theta0 + base, 1e-12 * float(observed.mean()) + 1e-300)  # a channel without noise has E = 0
    scaled = design / e0[:, None]
    scaled = scaled / np.maximum(np.linalg.norm(scaled, axis=0), 1e-300)
    covariance = np.linalg.pinv(scaled.T @ scaled)
    amp = slice(channels, p)
    block = covariance[amp, amp]
    correlation = None if block.shape[0] < 2 else float(block[0, 1] / math.sqrt(max(block[0, 0] * block[1, 1], 1e-300)))
    p_value = _chi_bar_squared_sf(statistic, correlation)
    null_draws = 0
    if law is not None and ZONE[0] <= p_value <= ZONE[1]:  # near the decision: the record's own null law

        def again(ordinates: NDArray[np.float64]) -> float:
            _, white, _, coloured = _white_and_coloured(design, ordinates, channels, base)
            return 2.0 * (coloured - white)

        p_value, null_draws = monte_carlo_p_value(again, statistic, law, law.levels(theta0[:channels]), np.zeros(kinds), record=observed)
    detected = p_value < alpha
    penalty = None
    best, best_loglik = theta, loglik
    source = ColouredSource.DATA
    if prior.given is not None:
        source = ColouredSource.GIVEN
        used = np.asarray(prior.given, dtype=float).reshape(kinds, 3)
        if given_rejected(design, observed, (theta, loglik), channels, given=used.mean(axis=1), alpha=alpha, offset=base, law=law):
            source = ColouredSource.CONTRADICTED  # the σ follow the data: the record's maximum-likelihood amplitudes
            used = np.repeat(theta[amp][:, None], 3, axis=1)
    elif prior.gaussian is not None:
        source = ColouredSource.PRIOR
        penalty = (
            np.concatenate([np.zeros(channels), np.asarray(prior.gaussian[0], dtype=float)]),
            np.concatenate([np.full(channels, np.inf), np.asarray(prior.gaussian[1], dtype=float)]),
        )
        best, best_loglik = whittle_fit(design, observed, offset=base, start=theta, penalty=penalty)
        used = np.repeat(best[amp][:, None], 3, axis=1) if (detected or prior.detected) else np.zeros((kinds, 3))
    else:
        used = np.repeat(theta[amp][:, None], 3, axis=1) if detected else np.zeros((kinds, 3))
    confidence = INTERVAL_CONFIDENCE
    level = 2.0 * float(gammaincinv(0.5, confidence))  # the χ²₁ quantile
    lower, upper = np.zeros(kinds), np.zeros(kinds)
    for c in range(channels, p):
        lower[c - channels], upper[c - channels] = _profile_interval(
            design, observed, best, best_loglik, c, level=level, penalty=penalty, offset=base
        )
    return ColouredNoiseFit(
        amplitudes=used,
        maximum_likelihood=theta[amp].copy(),
        lower=lower,
        upper=upper,
        statistic=statistic,
        p_value=p_value,
        alpha=alpha,
        confidence=confidence,
        source=source,
        white_levels=theta[:channels].copy(),
        null_draws=null_draws,
    )


def _white_and_coloured(
    design: NDArray[np.float64], observed: NDArray[np.float64], channels: int, base: NDArray[np.float64]
) -> tuple[NDArray[np.float64], float, NDArray[np.float64], float]:
    """Return the white-only fit and the full fit of :func:`fit_coloured_noise`: ``(θ₀, ℓ₀, θ, ℓ)`` with ``ℓ ≥ ℓ₀``."""
    white_only = np.zeros(design.shape[1], dtype=bool)
    white_only[:channels] = True
    theta0, loglik0 = whittle_fit(design, observed, white_only, base)
    theta, loglik = whittle_fit(design, observed, offset=base, start=theta0 + _small_amplitudes(design, theta0, channels, base))
    if loglik < loglik0:  # the nested white-only maximum is a point of the full model
        theta, loglik = theta0, loglik0
    return theta0, loglik0, theta, loglik


def given_rejected(
    design: NDArray[np.float64],
    observed: NDArray[np.float64],
    best: tuple[NDArray[np.float64], float],
    channels: int,
    *,
    given: NDArray[np.float64],
    alpha: float,
    offset: NDArray[np.float64] | None = None,
    law: OrdinateLaw | None = None,
) -> bool:
    """Whether the record rejects given amplitudes (a datasheet): a likelihood-ratio test at false-alarm rate ``alpha``.

    ``best = (θ̂, ℓ̂)``: the maximum of the record's likelihood (:func:`fit_coloured_noise`).

    ``2(ℓ̂ − max_{θ_c = given_c ∀c} ℓ)`` (the white levels free) against the χ² quantile with as many degrees of freedom
    as amplitudes (Wilks; on the boundary, a given 0 where the maximum is 0 adds nothing, which keeps the test at or below
    ``alpha``).  A datasheet the record contradicts is not used silently (issue 25): the stage then uses the record's
    amplitudes and says so.  ``offset``: the part of the expectations held at a measurement (the pitch and roll white
    levels, :func:`fit_coloured_noise`): in this test its scale is a free white level like the others, so that the test
    asks about the amplitudes alone.  Held instead, a small misfit of the held levels moved into the amplitudes and the
    true datasheet of quartz days was rejected on 10 of 100 (with it free: 1 of 40 before the levels were held; issue 25).

    That χ² law assumes independent exponential ordinates; with ``law`` (:class:`.bootstrap.OrdinateLaw`) a p-value within
    :data:`.bootstrap.ZONE` is the Monte Carlo one under the given amplitudes and the white levels fitted with them: the
    record's own law, with the correlations that left the χ² test at about 10 % false rejections of the true datasheet
    on one-day quartz records (docs/system-calibration.md §10).
    """
    from scipy.special import gammaincc  # χ²_k survival function: Q(k/2, x/2)

    theta, loglik = best
    given = np.asarray(given, dtype=float)
    scaled = offset is not None
    if offset is not None:  # the held part's scale free: one more white level
        design = np.column_stack([offset, design])
        channels += 1
        theta = np.concatenate([[1.0], theta])
    statistic, null = _given_statistic(design, observed, channels, given, theta, refit=scaled, loglik=loglik)
    kinds = design.shape[1] - channels
    p_value = float(gammaincc(0.5 * kinds, 0.5 * statistic))
    if law is not None and ZONE[0] <= p_value <= ZONE[1]:
        levels = law.levels(null[1:channels], scale=float(null[0])) if scaled else law.levels(null[:channels])
        p_value, _ = monte_carlo_p_value(
            lambda ordinates: _given_statistic(design, ordinates, channels, given, theta, refit=True)[0],
            statistic,
            law,
            levels,
            given,
            record=observed,
        )
    return p_value < alpha


def _given_statistic(
    design: NDArray[np.float64],
    observed: NDArray[np.float64],
    channels: int,
    given: NDArray[np.float64],
    start: NDArray[np.float64],
    *,
    refit: bool,
    loglik: float = 0.0,
) -> tuple[float, NDArray[np.float64]]:
    """Return ``2(ℓ̂ − max_{θ_c = given_c} ℓ)`` of :func:`given_rejected` and the white levels' fit under the given amplitudes.

    ``refit``: the unconstrained maximum ``ℓ̂`` is fitted here (from ``start``), else it is ``loglik``.
    """
    if refit:
        start, loglik = whittle_fit(design, observed, start=start)
    free = np.zeros(design.shape[1], dtype=bool)
    free[:channels] = True
    held_part = design[:, channels:] @ given
    begin = np.asarray(start, dtype=float).copy()
    begin[channels:] = 0.0
    null, held = whittle_fit(design, observed, free, held_part, begin)
    return max(0.0, 2.0 * (loglik - held)), null


def _small_amplitudes(
    design: NDArray[np.float64], theta0: NDArray[np.float64], channels: int, offset: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Return a start for the full fit: each amplitude at 1 % of the mean ordinate of the white fit."""
    out = np.zeros(design.shape[1])
    level = 0.01 * float((design @ theta0 + offset).mean())
    out[channels:] = level / np.maximum(design[:, channels:].mean(axis=0), 1e-300)
    return out


def _profile_interval(
    design: NDArray[np.float64],
    observed: NDArray[np.float64],
    theta: NDArray[np.float64],
    loglik: float,
    column: int,
    *,
    level: float,
    penalty: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None,
    offset: NDArray[np.float64] | None = None,
) -> tuple[float, float]:
    """``{v : 2(ℓ̂ − max_{θ_c = v} ℓ) ≤ level}`` for amplitude ``column``: lower and upper end (lower 0 when 0 is inside).

    ``offset``: the known part of the expectations (:func:`fit_coloured_noise`).
    """
    from scipy.optimize import brentq

    free = np.ones(design.shape[1], dtype=bool)
    free[column] = False
    base = np.zeros(observed.size) if offset is None else offset
    best = float(theta[column])
    prior_term = 0.0, 0.0
    if penalty is not None and np.isfinite(penalty[1][column]) and penalty[1][column] > 0:
        prior_term = float(penalty[0][column]), float(penalty[1][column])

    def deficit(v: float) -> float:
        fitted, value = whittle_fit(design, observed, free, offset=v * design[:, column] + base, start=theta, penalty=penalty)
        if prior_term[1] > 0:  # the fixed column's own prior term
            value -= 0.5 * ((v - prior_term[0]) / prior_term[1]) ** 2
        return 2.0 * (loglik - value) - level

    # a scale: the amplitude whose column adds the mean ordinate over the band
    unit = float((design @ theta + base).mean()) / max(float(design[:, column].mean()), 1e-300)
    hi = max(2.0 * best, 0.05 * unit)
    for _ in range(60):
        if deficit(hi) > 0.0:
            break
        hi *= 4.0
    else:
        return 0.0, math.inf
    upper = brentq(deficit, best, hi, rtol=1e-3, xtol=1e-12 * unit)
    if best <= 0.0 or deficit(0.0) <= 0.0:
        return 0.0, float(upper)
    return float(brentq(deficit, 0.0, best, rtol=1e-3, xtol=1e-12 * unit)), float(upper)
