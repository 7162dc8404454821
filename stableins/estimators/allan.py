r"""Measuring the noise model: Allan analysis of raw samples (static records, device dwells).

The overlapping Allan deviation and the equivalent degrees of freedom of each point come
from ``allantools`` (the time-and-frequency community's reference implementation:
``oadev`` and Greenhall's edf, NIST SP 1065).  Accelerometer output is a *rate* (like
fractional frequency): ``data_type="freq"``.  Segments (dwells, gaps in a record) are
pooled point by point: the pooled Allan variance is the mean over segments weighted by
their number of terms, and the edf add up (independent segments).

**Fit of the four terms** (:func:`fit_allan`).  Each pooled point is modelled as
``σ̂²_A(τ_i) ~ σ²_A(τ_i; θ) χ²_{ν_i}/ν_i`` with ``ν_i`` the edf and
``σ²_A(τ; θ) = Σ_k θ_k g_k(τ)`` linear in ``θ = (N², B², K², Q²) ≥ 0`` (the basis
``g_k`` is :meth:`stableins.noise.NoiseModel.allan_variance` of unit terms).  ``θ`` is the
maximum-likelihood estimate; each term's interval is the profile-likelihood interval
(``2ΔlnL = χ²_1`` quantile; one-sided upper limit when the term sits at zero).  The noise
type that sets each point's edf is the fitted model's dominant term at that ``τ``
(white → α = 0, flicker → −1, random walk → −2, quantization → +2), iterated twice.
Points at adjacent octaves share data, so their errors are correlated; the intervals'
coverage is measured by ``benchmarks/bench_noise_device.py`` (docs/noise.md).

**Slow noise in device dwells** (:func:`slow_noise_test`).  The dwells of a device session
measure white noise precisely but bias instability only weakly.  The decision uses, per
dwell and axis, the normalized overlapping Allan variances ``r_j = σ̂²_A(m_j) m_j / s²``
at ``m_j = n/4, n/8, n/16, n/32`` samples (``s²`` the sample variance).  Under white noise
each ``σ̂²_A(m)`` is a quadratic form ``xᵀA_m x`` of the samples, ``E r_j = 1`` and

.. math:: \mathrm{Cov}(r_i, r_j) = 2 m_i m_j \,\mathrm{tr}(A_{m_i} A_{m_j})
          = \frac{m_i m_j}{2 M_i M_j} \sum_\delta c_{ij}(\delta)\, g_{ij}(\delta)^2

exactly (``M = n − 2m + 1`` terms, ``g_ij`` the cross-correlation of the two Allan
kernels, ``c_ij(δ)`` the number of kernel pairs ``δ`` apart).  The statistic
``S = Σ_{dwell, axis} wᵀ(r − 1)`` with ``w = max(C⁻¹μ, 0)`` (``μ_j`` the excess that a
unit ``B²`` adds) is a positive combination of quadratic forms: under white noise it is
approximated by a scaled χ² with the exact mean and variance (Satterthwaite), which gives
the p-value; slow noise is declared present when ``p < α``.  ``S/D`` (``D = Σ wᵀμ``) is an
unbiased estimate of ``B²`` with standard error ``sqrt(V)/D``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stableins.noise import TERMS, AxisNoise, NoiseModel, NoiseSource, NoiseTerm, SlowNoiseTest

#: Noise type (power-law exponent α of the fractional-frequency PSD) of each term, for the edf.
_ALPHA = {"white": 0, "bias_instability": -1, "random_walk": -2, "quantization": 2}
#: Cluster sizes of the dwell test, as fractions of the dwell's samples.
TEST_FRACTIONS = (4, 8, 16, 32)
#: False-positive rate of the slow-noise decision.
DEFAULT_ALPHA = 0.05


@dataclass(frozen=True)
class AllanPoints:
    """Pooled overlapping Allan variance of three axes.

    Attributes
    ----------
    tau : ndarray (k,)
        Averaging times [s].
    variance : ndarray (k, 3)
        Allan variance [(m/s²)²].
    terms : ndarray (k,)
        Number of overlapping differences pooled at each ``τ``.
    samples : ndarray (k,)
        Phase points of the segments used (for Greenhall's edf), summed.
    segments : ndarray (k,)
        Number of segments pooled at each ``τ``.
    edf : ndarray (k, 3)
        Equivalent degrees of freedom (after :func:`fit_allan` with the fitted noise types).
    """

    tau: NDArray[np.float64]
    variance: NDArray[np.float64]
    terms: NDArray[np.float64]
    cluster: NDArray[np.int64]
    segment_lengths: tuple[NDArray[np.int64], ...]
    rate: float
    edf: NDArray[np.float64] | None = None

    def interval(self, confidence: float = 0.68268949213708585) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Confidence interval of the Allan *deviation* at each point (allantools.confidence_interval)."""
        import allantools

        if self.edf is None:
            raise ValueError("no edf: fit the points first")
        lo = np.empty_like(self.variance)
        hi = np.empty_like(self.variance)
        for i in range(self.tau.size):
            for a in range(3):
                lo[i, a], hi[i, a] = allantools.confidence_interval(math.sqrt(self.variance[i, a]), float(self.edf[i, a]), ci=confidence)
        return lo, hi


def allan_points(segments: Sequence[ArrayLike], rate: float, *, max_fraction: int = 4, taus: ArrayLike | None = None) -> AllanPoints:
    """Overlapping Allan variance of rate samples pooled over segments (allantools.oadev, ``data_type="freq"``).

    ``segments``: arrays (n_s, 3) of samples at ``rate`` [Hz] (dwells, pieces of a record).
    ``τ`` defaults to octaves from one sample to ``1/max_fraction`` of the longest segment.
    """
    import allantools

    parts = [np.asarray(s, dtype=float).reshape(-1, 3) for s in segments]
    parts = [p for p in parts if p.shape[0] >= 8]
    if not parts:
        raise ValueError("no segment long enough for an Allan analysis (8 samples)")
    longest = max(p.shape[0] for p in parts)
    if taus is None:
        m = 2 ** np.arange(int(np.floor(np.log2(max(longest // max_fraction, 1)))) + 1)
    else:
        m = np.unique(np.maximum(np.rint(np.asarray(taus, dtype=float) * rate), 1).astype(np.int64))
    weighted = np.zeros((m.size, 3))
    count = np.zeros(m.size)
    for p in parts:
        usable = m[2 * m < p.shape[0]]
        if usable.size == 0:
            continue
        for a in range(3):
            tau_used, dev, _, ns = allantools.oadev(p[:, a], rate=rate, data_type="freq", taus=usable / rate)
            index = np.searchsorted(m, np.rint(np.asarray(tau_used) * rate).astype(np.int64))
            weighted[index, a] += np.asarray(ns) * np.asarray(dev) ** 2
            if a == 0:
                count[index] += np.asarray(ns)
    keep = count > 0
    lengths = tuple(np.array([p.shape[0] + 1 for p in parts if 2 * mm < p.shape[0]], dtype=np.int64) for mm in m[keep])
    return AllanPoints(m[keep] / rate, weighted[keep] / count[keep, None], count[keep], m[keep], lengths, float(rate))


@lru_cache(maxsize=256)
def _edf(alpha: int, m: int, n: int) -> float:
    import allantools

    try:
        return float(allantools.edf_greenhall(alpha=alpha, d=2, m=int(m), N=int(n), overlapping=True, modified=False))
    except (AssertionError, ValueError, ZeroDivisionError):  # outside Greenhall's tables: the simple count
        return max(float(n - 2 * m) / m, 1.0)


def _basis(tau: NDArray[np.float64]) -> NDArray[np.float64]:
    """Allan variance of unit terms, shape (k, 4) in the order of :data:`stableins.noise.TERMS`."""
    out = np.empty((tau.size, len(TERMS)))
    for k, name in enumerate(TERMS):
        out[:, k] = NoiseModel.given(**{name: 1.0}).allan_variance(tau)[:, 0]
    return out


def _edf_for(points: AllanPoints, theta: NDArray[np.float64], basis: NDArray[np.float64]) -> NDArray[np.float64]:
    """edf of each point and axis from the dominant term of the fitted model."""
    edf = np.empty((points.tau.size, 3))
    for a in range(3):
        dominant = np.argmax(basis * theta[a][None], axis=1)
        for i in range(points.tau.size):
            alpha = _ALPHA[TERMS[int(dominant[i])]]
            edf[i, a] = sum(_edf(alpha, int(points.cluster[i]), int(n)) for n in points.segment_lengths[i])
    return edf


def _nll(theta: NDArray, a: NDArray, e: NDArray, basis: NDArray) -> float:
    m = basis @ theta
    if np.any(m <= 0):
        return math.inf
    return float(np.sum(0.5 * e * (a / m + np.log(m))))


def _fit_axis(a: NDArray, e: NDArray, basis: NDArray, fixed: dict[int, float] | None = None) -> tuple[NDArray, float]:
    """ML θ ≥ 0 of one axis (``fixed``: terms held at a value), and the negative log-likelihood.

    Fisher scoring, which for this model is iteratively reweighted non-negative least squares:
    at the current model ``m``, ``θ ← argmin_{θ≥0} Σ (ν_i/2) (a_i − g_iᵀθ)²/m_i²``.
    """
    from scipy.optimize import nnls

    fixed = fixed or {}
    free = [k for k in range(basis.shape[1]) if k not in fixed]
    offset = basis[:, list(fixed)] @ np.array(list(fixed.values())) if fixed else np.zeros(a.size)
    scale = np.array([_term_scale(a, basis, k) for k in free])  # θ_k of term k alone at the point where it is tightest
    g = basis[:, free] * scale
    m = np.maximum(a, 1e-300)
    u = np.zeros(len(free))
    for _ in range(100):
        w = np.sqrt(0.5 * e) / m
        new, _ = nnls(g * w[:, None], (a - offset) * w)
        m_new = offset + g @ new
        if np.any(m_new <= 0):
            m_new = np.maximum(m_new, 1e-12 * np.max(a))
        done = np.max(np.abs(m_new - m) / m) < 1e-10
        u, m = new, m_new
        if done:
            break
    theta = np.zeros(basis.shape[1])
    for k, v in fixed.items():
        theta[k] = v
    theta[free] = u * scale
    return theta, _nll(theta, a, e, basis)


def _term_scale(a: NDArray, basis: NDArray, k: int) -> float:
    ratio = a / np.maximum(basis[:, k], 1e-300)
    return max(float(np.min(ratio[basis[:, k] > 0])) if np.any(basis[:, k] > 0) else 1.0, 1e-300)


def _profile_interval(a: NDArray, e: NDArray, basis: NDArray, theta: NDArray, k: int, confidence: float) -> tuple[float, float]:
    """Profile-likelihood interval of ``θ_k`` (one-sided upper limit when the estimate is 0)."""
    from scipy.stats import chi2

    best = _nll(theta, a, e, basis)
    at_zero = theta[k] <= 0.0
    level = chi2.ppf(2 * confidence - 1 if at_zero else confidence, 1) / 2.0

    def excess(value: float) -> float:
        _, nll = _fit_axis(a, e, basis, {k: value})
        return nll - best - level

    def search(lo: float, hi: float) -> float:
        for _ in range(30):
            mid = math.sqrt(lo * hi) if lo > 0 else 0.5 * hi
            if excess(mid) > 0:
                hi = mid
            else:
                lo = mid
            if hi - lo <= 0.01 * hi:
                break
        return hi

    hi = max(2.0 * theta[k], 1e-3 * _term_scale(a, basis, k))
    for _ in range(40):
        if excess(hi) > 0:
            break
        hi *= 4
    else:
        return (0.0 if at_zero else theta[k], math.inf)
    upper = search(max(theta[k], 0.0), hi)
    lower = 0.0
    if not at_zero and excess(0.0) > 0:
        lo_value = 0.0
        hi_value = theta[k]
        for _ in range(40):
            mid = 0.5 * (lo_value + hi_value)
            if excess(mid) > 0:
                lo_value = mid
            else:
                hi_value = mid
            if hi_value - lo_value <= 0.01 * theta[k]:
                break
        lower = lo_value
    return lower, upper


def fit_allan(
    points: AllanPoints, *, source: NoiseSource, provenance: str = "", confidence: float = 0.95, terms: Sequence[str] = TERMS
) -> tuple[NoiseModel, AllanPoints]:
    """Maximum-likelihood noise model and profile intervals from pooled Allan points (module docstring).

    ``terms``: the terms fitted; the others are held at zero (their upper limit not bounded).
    Returns the model and the points with the edf of the fitted noise types.
    """
    basis = _basis(points.tau)
    chosen = [k for k, name in enumerate(TERMS) if name in terms]
    held = {k: 0.0 for k in range(len(TERMS)) if k not in chosen}
    theta = np.zeros((3, len(TERMS)))
    theta[:, 0] = np.median(points.variance * points.tau[:, None], axis=0)
    edf = _edf_for(points, theta, basis)
    for _ in range(2):
        theta = np.array([_fit_axis(points.variance[:, a], edf[:, a], basis, held)[0] for a in range(3)])
        edf = _edf_for(points, theta, basis)
    axes = []
    for a in range(3):
        fitted = {}
        for k, name in enumerate(TERMS):
            if k in held:
                fitted[name] = NoiseTerm.unbounded()
                continue
            lower, upper = _profile_interval(points.variance[:, a], edf[:, a], basis, theta[a], k, confidence)
            fitted[name] = NoiseTerm(math.sqrt(theta[a, k]), math.sqrt(min(lower, theta[a, k])), math.sqrt(max(upper, theta[a, k])))
        axes.append(AxisNoise(**fitted))
    model = NoiseModel(tuple(axes), source, provenance, confidence)  # type: ignore[arg-type]
    from dataclasses import replace

    return model, replace(points, edf=edf)


# ----------------------------------------------------------------------------- device dwells
@lru_cache(maxsize=64)
def white_allan_covariance(n: int, clusters: tuple[int, ...]) -> NDArray[np.float64]:
    """Exact covariance of ``r_j = σ̂²_A(m_j) m_j/σ²`` for ``n`` white samples (module docstring)."""
    out = np.empty((len(clusters), len(clusters)))
    for i, mi in enumerate(clusters):
        for j, mj in enumerate(clusters[i:], start=i):
            big_i, big_j = n - 2 * mi + 1, n - 2 * mj + 1
            hi = np.r_[-np.ones(mi), np.ones(mi)] / mi
            hj = np.r_[-np.ones(mj), np.ones(mj)] / mj
            from scipy.signal import fftconvolve

            g = fftconvolve(hi, hj[::-1], mode="full")  # g[k]: h_j starting (k − len(h_j) + 1) samples after h_i
            delta = np.arange(g.size) - (hj.size - 1)
            count = np.clip(np.minimum(big_i, big_j - delta) - np.maximum(0, -delta), 0, None)
            trace = float(np.sum(count * g**2)) / (4.0 * big_i * big_j)
            out[i, j] = out[j, i] = 2.0 * mi * mj * trace
    return out


def dwell_test_clusters(n: int) -> tuple[int, ...]:
    """Cluster sizes ``n/4, n/8, n/16, n/32`` (at least 2 samples, distinct) of the dwell test."""
    return tuple(sorted({n // f for f in TEST_FRACTIONS if n // f >= 2}, reverse=True))


def dwell_allan_ratios(samples: ArrayLike, rate: float) -> tuple[tuple[int, ...], NDArray[np.float64]]:
    """Normalized overlapping Allan variances ``r_j`` (k, 3) of one dwell at :func:`dwell_test_clusters` (allantools.oadev)."""
    import allantools

    x = np.asarray(samples, dtype=float).reshape(-1, 3)
    clusters = dwell_test_clusters(x.shape[0])
    ratios = np.full((len(clusters), 3), np.nan)
    if not clusters:
        return clusters, ratios
    s2 = x.var(axis=0, ddof=1)
    m = np.array(clusters)
    for a in range(3):
        if not s2[a] > 0:
            continue
        tau_used, dev, _, _ = allantools.oadev(x[:, a], rate=rate, data_type="freq", taus=m / rate)
        index = np.searchsorted(-m, -np.rint(np.asarray(tau_used) * rate).astype(np.int64))
        ratios[index, a] = np.asarray(dev) ** 2 * m[index] / s2[a]
    return clusters, ratios


@dataclass(frozen=True)
class DwellSlowNoise:
    """What the dwells say about slow noise: the decision and the estimate of ``B²``.

    Attributes
    ----------
    test : SlowNoiseTest
    b2, b2_sigma : float
        Unbiased estimate of ``B²`` [(m/s²)²] (slow noise expressed as bias instability) and its 1σ.
    b_upper : float
        Upper confidence limit of ``B`` [m/s²] at ``confidence``.
    k_upper : float
        Upper limit of the random walk ``K`` if all the excess were random walk.
    dwells : int
        Dwell-axes used.
    """

    test: SlowNoiseTest
    b2: float
    b2_sigma: float
    b_upper: float
    k_upper: float
    dwells: int


def slow_noise_test(
    ratios: Sequence[tuple[int, NDArray[np.float64], NDArray[np.float64], float]],
    *,
    alpha: float = DEFAULT_ALPHA,
    confidence: float = 0.95,
) -> DwellSlowNoise:
    """The slow-noise decision over dwells (module docstring).

    ``ratios``: per dwell ``(n, r (k, 3), s² (3,), rate)`` with ``r`` at :func:`dwell_test_clusters` ``(n)``.
    """
    from scipy.stats import chi2, norm

    unit_b = NoiseModel.given(bias_instability=1.0)
    unit_k = NoiseModel.given(random_walk=1.0)
    s_total = v_total = d_total = dk_total = mean_total = 0.0
    used = 0
    for n, r, s2, rate in ratios:
        clusters = dwell_test_clusters(int(n))
        if len(clusters) < 2 or r.shape != (len(clusters), 3):
            continue
        m = np.array(clusters, dtype=float)
        tau = m / rate
        mu_b = unit_b.allan_variance(tau)[:, 0] * m
        mu_k = unit_k.allan_variance(tau)[:, 0] * m
        cov = white_allan_covariance(int(n), clusters)
        for a in range(3):
            if not (np.all(np.isfinite(r[:, a])) and s2[a] > 0):
                continue
            mu = mu_b / s2[a]
            w = np.clip(np.linalg.solve(cov, mu), 0.0, None)
            s_total += float(w @ (r[:, a] - 1.0))
            v_total += float(w @ cov @ w)
            d_total += float(w @ mu)
            dk_total += float(w @ (mu_k / s2[a]))
            mean_total += float(w.sum())
            used += 1
    if used == 0 or v_total <= 0:
        test = SlowNoiseTest(0.0, 1.0, alpha)
        return DwellSlowNoise(test, 0.0, math.inf, math.inf, math.inf, 0)
    # Satterthwaite: Σ wᵀr ≈ g χ²_h with the exact mean and variance under white noise
    g = v_total / (2.0 * mean_total)
    h = 2.0 * mean_total**2 / v_total
    p_value = float(chi2.sf((s_total + mean_total) / g, h))
    statistic = s_total / math.sqrt(v_total)
    b2 = s_total / d_total
    b2_sigma = math.sqrt(v_total) / d_total
    z = norm.ppf(confidence)
    b_upper = math.sqrt(max(b2, 0.0) + z * b2_sigma)
    k_upper = math.sqrt(max(s_total, 0.0) / dk_total + z * math.sqrt(v_total) / dk_total)
    return DwellSlowNoise(SlowNoiseTest(statistic, p_value, alpha), b2, b2_sigma, b_upper, k_upper, used)


def merge_points(short: AllanPoints, long: AllanPoints, threshold: float) -> AllanPoints:
    """Points of ``short`` below ``threshold`` [s] and of ``long`` from it on (full-rate head, block means)."""
    from dataclasses import replace

    keep_short = short.tau < threshold
    keep_long = long.tau >= threshold
    # keep each part's cluster sizes and segment lengths: the edf are those of the series the point comes from
    merged = AllanPoints(
        np.r_[short.tau[keep_short], long.tau[keep_long]],
        np.vstack([short.variance[keep_short], long.variance[keep_long]]),
        np.r_[short.terms[keep_short], long.terms[keep_long]],
        np.r_[short.cluster[keep_short], long.cluster[keep_long]],
        tuple(x for x, k in zip(short.segment_lengths, keep_short, strict=True) if k)
        + tuple(x for x, k in zip(long.segment_lengths, keep_long, strict=True) if k),
        short.rate,
    )
    return replace(merged)


def points_for_model(points: AllanPoints, model: NoiseModel) -> AllanPoints:
    """The points with the edf of the noise types that dominate ``model`` at each ``τ``."""
    from dataclasses import replace

    theta = np.stack([model.values(name) ** 2 for name in TERMS], axis=-1)
    return replace(points, edf=_edf_for(points, theta, _basis(points.tau)))


def plot_allan(points: AllanPoints, model: NoiseModel, *, title: str = "", confidence: float = 0.68268949213708585):
    """Allan deviation per axis [µg] against τ [s]: measured points with their interval, the model and its bounds."""
    import matplotlib.pyplot as plt

    from stableins.conventions import MICRO_G
    from stableins.noise import AXES

    lo, hi = points.interval(confidence)
    tau = np.logspace(np.log10(points.tau.min()), np.log10(points.tau.max()), 200)
    fitted = model.allan_deviation(tau)
    lower = _bound_model(model, "lower").allan_deviation(tau)
    upper_model = _bound_model(model, "upper")
    upper = upper_model.allan_deviation(tau) if upper_model is not None else None
    fig, axes = plt.subplots(1, 3, figsize=(13.5, 4.6), sharey=True, constrained_layout=True)
    for a, ax in enumerate(axes):
        dev = np.sqrt(points.variance[:, a])
        ax.errorbar(
            points.tau,
            dev / MICRO_G,
            yerr=[(dev - lo[:, a]) / MICRO_G, (hi[:, a] - dev) / MICRO_G],
            fmt="o",
            ms=3.5,
            color="C0",
            ecolor="C0",
            elinewidth=0.8,
            capsize=2,
            label=f"measured (overlapping, {100 * confidence:.0f} % interval)",
        )
        ax.loglog(tau, fitted[:, a] / MICRO_G, color="C3", lw=1.6, label="noise model")
        if upper is not None:
            ax.fill_between(tau, lower[:, a] / MICRO_G, upper[:, a] / MICRO_G, color="C3", alpha=0.15, lw=0, label="model bounds")
        else:
            ax.fill_between(
                tau, lower[:, a] / MICRO_G, fitted[:, a] / MICRO_G, color="C3", alpha=0.15, lw=0, label="model bounds (upper not bounded)"
            )
        for name, style, colour in (
            ("white", ":", "0.35"),
            ("bias_instability", "--", "0.35"),
            ("random_walk", "-.", "0.35"),
            ("quantization", ":", "C2"),
        ):
            value = model.axes[a].term(name).value
            if value > 0:
                alone = NoiseModel.given(**{name: value}).allan_deviation(tau)[:, a] / MICRO_G
                ax.loglog(tau, alone, color=colour, lw=0.9, ls=style, label=f"{name.replace('_', ' ')} alone")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_ylim(0.3 * float(np.min(lo[:, a])) / MICRO_G, 2.0 * float(np.max(hi[:, a])) / MICRO_G)
        ax.set_title(f"axis {AXES[a]}")
        ax.set_xlabel("averaging time τ [s]")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].set_ylabel("Allan deviation σ_A(τ) [µg]")
    handles: dict[str, object] = {}
    for ax in axes:
        for handle, label in zip(*ax.get_legend_handles_labels(), strict=True):
            handles.setdefault(label, handle)
    axes[0].legend(list(handles.values()), list(handles), fontsize=7.5, loc="lower left")
    if title:
        fig.suptitle(title)
    return fig


def _bound_model(model: NoiseModel, side: str) -> NoiseModel | None:
    """Every term at its lower (or upper) limit; None when an upper limit is not bounded."""
    from dataclasses import replace

    axes = []
    for axis in model.axes:
        changes = {}
        for name in TERMS:
            term = axis.term(name)
            value = term.lower if side == "lower" else term.upper
            if not math.isfinite(value):
                if name in ("random_walk", "quantization") and term.value == 0.0:
                    value = 0.0  # not measured: drawn at the value used
                else:
                    return None
            changes[name] = NoiseTerm.exact(value)
        axes.append(replace(axis, **changes))
    return replace(model, axes=tuple(axes))
