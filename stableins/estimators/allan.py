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

The slow-noise test of device dwells is :mod:`stableins.estimators.slow_noise`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stableins.noise import TERMS, AxisNoise, NoiseModel, NoiseSource, NoiseTerm

#: Noise type (power-law exponent α of the fractional-frequency PSD) of each term, for the edf.
_ALPHA = {"white": 0, "bias_instability": -1, "random_walk": -2, "quantization": 2}


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
        out[:, k] = NoiseModel.given(*(1.0 if term == name else 0.0 for term in TERMS)).allan_variance(tau)[:, 0]
    return out


def _edf_for(points: AllanPoints, theta: NDArray[np.float64], basis: NDArray[np.float64]) -> NDArray[np.float64]:
    """Return the edf of each point and axis from the dominant term of the fitted model."""
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


def _geometric_search(excess: Callable[[float], float], lo: float, hi: float) -> float:
    """Return the upper end of a geometric bisection of ``[lo, hi]`` for the root of ``excess`` (to 1 % of it)."""
    for _ in range(30):
        mid = math.sqrt(lo * hi) if lo > 0 else 0.5 * hi
        if excess(mid) > 0:
            hi = mid
        else:
            lo = mid
        if hi - lo <= 0.01 * hi:
            break
    return hi


def _profile_interval(a: NDArray, e: NDArray, basis: NDArray, theta: NDArray, *, k: int, confidence: float) -> tuple[float, float]:
    """Profile-likelihood interval of ``θ_k`` (one-sided upper limit when the estimate is 0)."""
    from scipy.stats import chi2

    best = _nll(theta, a, e, basis)
    at_zero = theta[k] <= 0.0
    level = chi2.ppf(2 * confidence - 1 if at_zero else confidence, 1) / 2.0

    def excess(value: float) -> float:
        _, nll = _fit_axis(a, e, basis, {k: value})
        return nll - best - level

    hi = max(2.0 * theta[k], 1e-3 * _term_scale(a, basis, k))
    for _ in range(40):
        if excess(hi) > 0:
            break
        hi *= 4
    else:
        return (0.0 if at_zero else theta[k], math.inf)
    upper = _geometric_search(excess, max(theta[k], 0.0), hi)
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
            lower, upper = _profile_interval(points.variance[:, a], edf[:, a], basis, theta[a], k=k, confidence=confidence)
            fitted[name] = NoiseTerm(math.sqrt(theta[a, k]), math.sqrt(min(lower, theta[a, k])), math.sqrt(max(upper, theta[a, k])))
        axes.append(AxisNoise(**fitted))
    model = NoiseModel(tuple(axes), source, provenance, confidence)  # type: ignore[arg-type]
    from dataclasses import replace

    return model, replace(points, edf=edf)


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
    """Return the points with the edf of the noise types that dominate ``model`` at each ``τ``."""
    from dataclasses import replace

    theta = np.stack([model.values(name) ** 2 for name in TERMS], axis=-1)
    return replace(points, edf=_edf_for(points, theta, _basis(points.tau)))


def plot_allan(points: AllanPoints, model: NoiseModel, *, title: str = "", confidence: float = 0.68268949213708585):
    """Allan deviation per axis [µg] against τ [s]: measured points with their interval, the model and its bounds."""
    import matplotlib.pyplot as plt

    from stableins.conventions import AXES, MICRO_G

    lo, hi = points.interval(confidence)
    tau = np.logspace(np.log10(points.tau.min()), np.log10(points.tau.max()), 200)
    fitted = model.allan_deviation(tau)
    lower_model = _bound_model(model, "lower")
    assert lower_model is not None  # lower limits are finite (an unbounded term has lower limit 0)
    lower = lower_model.allan_deviation(tau)
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
                alone = NoiseModel.given(*(value if term == name else 0.0 for term in TERMS)).allan_deviation(tau)[:, a] / MICRO_G
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
    return replace(model, axes=(axes[0], axes[1], axes[2]))
