r"""The noise model of the instrument: one per unit, under every σ, χ² and flag.

Per accelerometer axis, the four terms of IEEE Std 952-1997 Annex C (the simulator's
definitions, ``docs/simulator.md`` "Noise"; the estimators follow ``docs/noise.md``):

============================  ===========  ==================  ======================================
term                          symbol       SI unit             Allan variance ``σ_A²(τ)``
============================  ===========  ==================  ======================================
white (velocity random walk)  ``N``        m/s/√s              ``N²/τ``
bias instability (flicker)    ``B``        m/s²                ``≈ (2 ln2/π) B² = (0.664 B)²``
acceleration random walk      ``K``        m/s²/√s             ``K² τ/3``
quantization                  ``Q``        m/s                 ``3 Q²/τ²``
============================  ===========  ==================  ======================================

``N`` is the two-sided white PSD level ``N²`` [(m/s²)²/Hz] of the rate noise; ``B`` defines
the flicker PSD ``S(f) = B²/(2π f)``; ``K`` the random walk ``b(t) = K W(t)``; ``Q`` the
white phase (velocity) noise of standard deviation ``Q`` (a uniform quantizer of step
``Δ`` whose remainder is carried: ``Q = Δ/√12``).

**Flicker representation.**  As usual (and as in the simulator), flicker is a sum of
first-order Gauss-Markov processes one decade apart in correlation time,
:data:`FLICKER_TIME_CONSTANTS` = 1 s … 1e5 s, each of variance ``σ_c² = B² ln(10)/π``
(a density ``1/ln 10`` of processes per ``ln τ_c`` with PSD ``2σ_c²τ_c/(1 + (2πfτ_c)²)``
sums to ``B²/(2πf)``).  The Allan variance of this sum is within about ±10 % of
``(0.664 B)²`` from 10 s to 1e4 s; :meth:`NoiseModel.allan_variance` returns the sum's
exact Allan variance, so the plotted model is the model used.

**Window means.**  Everything follows from the covariance of the means of a rate noise
over windows ``[s_i, s_i + T_i]`` (one Gauss-Markov process of unit variance and
correlation time ``τ``, ``x = T/τ``)::

    Var = 2/x − 2(1 − e^{−x})/x²
    Cov = (τ²/(T_i T_j)) (1 − e^{−T_i/τ}) (1 − e^{−T_j/τ}) e^{−gap/τ}     (disjoint windows)

a random walk ``K W(t − t_0)`` started at the session's first window::

    Var = K² (s − t_0 + T/3),     Cov = K² (mid_i − t_0)   (window i before window j)

white noise ``N²/T`` on the diagonal, and quantization ``2 Q²/T²`` (the velocity error at
both ends of the window).  The Allan variance is ``Var − Cov`` of two adjacent windows of
length ``τ`` (:meth:`NoiseModel.allan_variance`); the covariance of dwell means of a stage
is :meth:`NoiseModel.dwell_mean_covariance`.

Dwells on separate time bases (a file or pass whose clock restarts, :func:`sessions`) are
independent draws of the slow noise.  That is exact for the truth simulator; for a real
instrument record the stages of one calibration on one time base.

This module is the physics layer: it imports numpy and the project's conventions, the user-error type
:class:`stableins.errors.InputError` (reading a document, :func:`noise_model_from_document`) and
:mod:`stableins.display` (how a model shows itself: one line, a table, ``repr``, Jupyter, pandas; engineering
units µg/√Hz, µg, µg/√s, µg·√s as :data:`ENGINEERING` scales them).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from enum import Enum
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stableins.conventions import AXES, MICRO_G
from stableins.display import clipped, html_result, html_table, require_pandas, unit_text
from stableins.errors import InputError
from stableins.noise.windows import gauss_markov_allan, gauss_markov_window_covariance, random_walk_window_covariance, sessions

#: Correlation times [s] of the Gauss-Markov sum representing flicker noise: 1 s to about
#: one day, the span over which an Allan floor is normally specified.  Flicker variance grows
#: with ln(τ_max); slower wander is a change of bias between calibrations.
FLICKER_TIME_CONSTANTS: tuple[float, ...] = tuple(10.0**k for k in range(0, 6))
#: Variance of each Gauss-Markov process per unit ``B²`` (one decade apart): ``ln(10)/π``.
FLICKER_VARIANCE_PER_B2 = math.log(10.0) / math.pi
#: Allan deviation floor of ideal flicker per unit ``B``: ``sqrt(2 ln 2/π) = 0.664``.
FLICKER_FLOOR = math.sqrt(2.0 * math.log(2.0) / math.pi)

#: The four terms, their SI units and engineering units (scale: SI per engineering unit).
TERMS: tuple[str, ...] = ("white", "bias_instability", "random_walk", "quantization")
SI_UNITS: Mapping[str, str] = {
    "white": "m/s/sqrt(s)",
    "bias_instability": "m/s^2",
    "random_walk": "m/s^2/sqrt(s)",
    "quantization": "m/s",
}
ENGINEERING: Mapping[str, tuple[str, float]] = {
    "white": ("ug/sqrt(Hz)", MICRO_G),
    "bias_instability": ("ug", MICRO_G),
    "random_walk": ("ug/sqrt(s)", MICRO_G),
    "quantization": ("mm/s", 1e-3),
}
LABELS: Mapping[str, str] = {
    "white": "white noise N (velocity random walk)",
    "bias_instability": "bias instability B",
    "random_walk": "acceleration random walk K",
    "quantization": "quantization Q",
}


class NoiseSource(Enum):
    """Where a noise model comes from."""

    #: Allan analysis of a long static record (a system-level record, a static run).
    STATIC_RECORD = "static record"
    #: Allan analysis of the dwells of a device-level session (weak for slow noise).
    DEVICE_DWELLS = "device dwells"
    #: Given: the instrument's datasheet or specification.
    DATASHEET = "datasheet"
    #: Nothing known: white noise is measured in every dwell, slow noise is not bounded.
    NONE = "none"


@dataclass(frozen=True)
class NoiseTerm:
    """One noise coefficient [SI] with its confidence interval ``[lower, upper]``.

    ``upper = inf`` means the data do not bound the term.  A term that was not detected
    has ``value = lower = 0`` and its upper limit.
    """

    value: float
    lower: float = math.nan
    upper: float = math.nan

    def __post_init__(self) -> None:
        value = float(self.value)
        lower = value if math.isnan(self.lower) else float(self.lower)
        upper = value if math.isnan(self.upper) else float(self.upper)
        if not (math.isfinite(value) and value >= 0.0):
            raise ValueError(f"noise term value must be finite and non-negative, got {value!r}")
        if not (0.0 <= lower <= value <= upper):
            raise ValueError(f"noise term interval must satisfy 0 <= lower <= value <= upper, got [{lower}, {value}, {upper}]")
        object.__setattr__(self, "value", value)
        object.__setattr__(self, "lower", lower)
        object.__setattr__(self, "upper", upper)

    @classmethod
    def exact(cls, value: float) -> NoiseTerm:
        """Return a given value (interval of zero width)."""
        return cls(float(value), float(value), float(value))

    @classmethod
    def unbounded(cls) -> NoiseTerm:
        """Not known at all: 0 assumed, no upper limit."""
        return cls(0.0, 0.0, math.inf)

    @property
    def detected(self) -> bool:
        """The interval excludes zero."""
        return self.lower > 0.0

    @property
    def bounded(self) -> bool:
        """Whether the upper limit is finite."""
        return math.isfinite(self.upper)


@dataclass(frozen=True)
class AxisNoise:
    """The four noise terms of one accelerometer axis."""

    white: NoiseTerm
    bias_instability: NoiseTerm = field(default_factory=lambda: NoiseTerm.exact(0.0))
    random_walk: NoiseTerm = field(default_factory=lambda: NoiseTerm.exact(0.0))
    quantization: NoiseTerm = field(default_factory=lambda: NoiseTerm.exact(0.0))

    def term(self, name: str) -> NoiseTerm:
        """Return the term ``name`` (one of :data:`TERMS`)."""
        if name not in TERMS:
            raise KeyError(name)
        return getattr(self, name)


@dataclass(frozen=True)
class SlowNoiseTest:
    """Decision whether slow noise is present (device dwells): statistic, p-value and level.

    Attributes
    ----------
    statistic : float
        Standardized excess of the pooled Allan variance over white noise (0 expected, 1σ = 1).
    p_value : float
        ``P(statistic ≥ observed)`` under white noise (its null distribution, docs/noise.md).
    alpha : float
        False-positive rate of the decision: slow noise is declared present when ``p < alpha``.
    """

    statistic: float
    p_value: float
    alpha: float

    @property
    def detected(self) -> bool:
        """Whether slow noise is detected at the false-positive rate."""
        return self.p_value < self.alpha


@dataclass(frozen=True)
class NoiseModel:
    """Per-axis noise model of the accelerometer triad (module docstring).

    Attributes
    ----------
    axes : tuple of three AxisNoise
        x, y, z.
    source : NoiseSource
        Where the numbers come from.
    provenance : str
        What was measured or given (files, durations, datasheet ...).
    confidence : float
        Confidence level of every term's interval (e.g. 0.95).
    test : SlowNoiseTest or None
        The slow-noise decision, for models measured from device dwells.
    """

    axes: tuple[AxisNoise, AxisNoise, AxisNoise]
    source: NoiseSource = NoiseSource.DATASHEET
    provenance: str = ""
    confidence: float = 0.95
    test: SlowNoiseTest | None = None

    def __post_init__(self) -> None:
        axes = tuple(self.axes)
        if len(axes) != 3 or not all(isinstance(a, AxisNoise) for a in axes):
            raise ValueError("NoiseModel.axes must be three AxisNoise (x, y, z)")
        object.__setattr__(self, "axes", axes)
        if not isinstance(self.source, NoiseSource):
            raise ValueError(f"NoiseModel.source must be a NoiseSource, got {self.source!r}")
        if not 0.0 < self.confidence < 1.0:
            raise ValueError("NoiseModel.confidence must lie in (0, 1)")

    # ------------------------------------------------------------------ build
    @classmethod
    def given(
        cls,
        white: float | Sequence[float] = 0.0,
        bias_instability: float | Sequence[float] = 0.0,
        random_walk: float | Sequence[float] = 0.0,
        quantization: float | Sequence[float] = 0.0,
        *,
        source: NoiseSource = NoiseSource.DATASHEET,
        provenance: str = "",
    ) -> NoiseModel:
        """Return a model from given values (scalars: the same on every axis), intervals of zero width."""
        values = {
            name: np.broadcast_to(np.asarray(v, dtype=float), (3,))
            for name, v in zip(TERMS, (white, bias_instability, random_walk, quantization))
        }
        axes = tuple(AxisNoise(**{name: NoiseTerm.exact(float(values[name][a])) for name in TERMS}) for a in range(3))
        return cls(axes, source, provenance)  # type: ignore[arg-type]

    @classmethod
    def unknown(cls, provenance: str = "no noise information given") -> NoiseModel:
        """Nothing known: white noise measured in every dwell (``N`` 0 here), slow terms not bounded."""
        axis = AxisNoise(NoiseTerm.unbounded(), NoiseTerm.unbounded(), NoiseTerm.unbounded(), NoiseTerm.unbounded())
        return cls((axis, axis, axis), NoiseSource.NONE, provenance)

    # ------------------------------------------------------------------ access
    def values(self, name: str) -> NDArray[np.float64]:
        """Per-axis values of one term, shape (3,) [SI]."""
        return np.array([a.term(name).value for a in self.axes])

    def limits(self, name: str) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Per-axis ``(lower, upper)`` of one term."""
        return np.array([a.term(name).lower for a in self.axes]), np.array([a.term(name).upper for a in self.axes])

    @property
    def has_slow_noise(self) -> bool:
        """Any bias instability or random walk in the values used."""
        return bool(np.any(self.values("bias_instability") > 0) or np.any(self.values("random_walk") > 0))

    @property
    def slow_noise_bounded(self) -> bool:
        """Both slow terms have a finite upper limit on every axis."""
        return all(a.bias_instability.bounded and a.random_walk.bounded for a in self.axes)

    def with_values(self, **per_term: ArrayLike) -> NoiseModel:
        """Return the same model with some terms replaced by given values (e.g. the upper limits)."""
        axes = []
        for a, axis in enumerate(self.axes):
            changes = {}
            for name, v in per_term.items():
                value = float(np.broadcast_to(np.asarray(v, dtype=float), (3,))[a])
                old = axis.term(name)
                changes[name] = NoiseTerm(value, min(old.lower, value), max(old.upper, value))
            axes.append(replace(axis, **changes))
        return replace(self, axes=(axes[0], axes[1], axes[2]))

    def at_upper_limits(self) -> NoiseModel:
        """Slow terms at their upper limits: the largest floor the data allow (needs bounded limits)."""
        if not self.slow_noise_bounded:
            raise ValueError("the slow noise is not bounded by the data")
        return self.with_values(bias_instability=self.limits("bias_instability")[1], random_walk=self.limits("random_walk")[1])

    # ------------------------------------------------------------------ physics
    def allan_variance(self, tau: ArrayLike) -> NDArray[np.float64]:
        r"""Allan variance ``σ_A²(τ)`` [(m/s²)²] of the model at ``τ`` [s], shape (len(τ), 3).

        ``N²/τ + 3Q²/τ² + K²τ/3`` plus the exact Allan variance of the flicker
        representation, ``Σ_c σ_c² (v(τ/τ_c) − c(τ/τ_c))`` (window-mean variance minus the
        covariance of two adjacent windows, module docstring); ``≈ (0.664 B)²`` from 10 s
        to 1e4 s.
        """
        t = np.atleast_1d(np.asarray(tau, dtype=float))
        if np.any(~np.isfinite(t)) or np.any(t <= 0):
            raise ValueError("Allan variance needs positive, finite τ")
        out = (
            self.values("white")[None] ** 2 / t[:, None]
            + 3.0 * self.values("quantization")[None] ** 2 / t[:, None] ** 2
            + self.values("random_walk")[None] ** 2 * t[:, None] / 3.0
        )
        flicker = FLICKER_VARIANCE_PER_B2 * np.asarray(sum(gauss_markov_allan(t / tc) for tc in FLICKER_TIME_CONSTANTS))
        return out + flicker[:, None] * self.values("bias_instability")[None] ** 2

    def allan_deviation(self, tau: ArrayLike) -> NDArray[np.float64]:
        """``σ_A(τ)`` [m/s²], shape (len(τ), 3)."""
        return np.sqrt(self.allan_variance(tau))

    def slow_covariance(self, start: ArrayLike, length: ArrayLike) -> NDArray[np.float64]:
        """Covariance of dwell means from bias instability and random walk, shape (3, m, m) [(m/s²)²].

        Dwells in acquisition order, ``start`` and ``length`` [s]; separate sessions
        (:func:`sessions`) are independent.
        """
        s = np.asarray(start, dtype=float).reshape(-1)
        t = np.asarray(length, dtype=float).reshape(-1)
        if s.shape != t.shape:
            raise ValueError("start and length must have the same length")
        b2 = self.values("bias_instability") ** 2
        k2 = self.values("random_walk") ** 2
        out = np.zeros((3, s.size, s.size))
        if not (np.any(b2 > 0) or np.any(k2 > 0)):
            return out
        labels = sessions(s, t)
        for k in range(int(labels[-1]) + 1 if labels.size else 0):
            idx = np.flatnonzero(labels == k)
            flicker = np.zeros((idx.size, idx.size))
            if np.any(b2 > 0):
                for tc in FLICKER_TIME_CONSTANTS:
                    flicker += gauss_markov_window_covariance(s[idx], t[idx], tc)
                flicker *= FLICKER_VARIANCE_PER_B2
            walk = random_walk_window_covariance(s[idx], t[idx])
            block = b2[:, None, None] * flicker[None] + k2[:, None, None] * walk[None]
            out[:, idx[:, None], idx[None, :]] = block
        return out

    def dwell_mean_covariance(self, start: ArrayLike, length: ArrayLike, white_variance: ArrayLike | None = None) -> NDArray[np.float64]:
        r"""Covariance of the dwell means of a stage, per axis: shape (3, m, m) [(m/s²)²].

        .. math:: R_a = \mathrm{diag}(\sigma^2_{w,a} + 2 Q_a^2/T^2) + C_{slow,a}

        ``white_variance`` (m, 3): the white-noise variance of each dwell mean as measured
        in the dwell (``s²/n``, :mod:`stableins.estimators.dwell`); by default ``N²/T`` of
        the model.  This is the one implementation of the uncertainty of a dwell mean used
        by the device stages and by model discovery.
        """
        s = np.asarray(start, dtype=float).reshape(-1)
        t = np.asarray(length, dtype=float).reshape(-1)
        if white_variance is None:
            white = self.values("white")[None] ** 2 / t[:, None]
        else:
            white = np.asarray(white_variance, dtype=float).reshape(s.size, 3)
        quant = 2.0 * self.values("quantization")[None] ** 2 / np.maximum(t, 1e-300)[:, None] ** 2
        cov = self.slow_covariance(s, t)
        diag = np.arange(s.size)
        cov[:, diag, diag] += (white + quant).T
        return cov

    # ------------------------------------------------------------------ text
    def describe(self) -> str:
        """Return one line: source and the slow terms (engineering units)."""
        return _text_describe(self)

    def summary(self) -> str:
        """Return one short line for tables (certificate settings): source, N, B and K with their upper limits, the decision."""
        return _text_summary(self)

    def report(self) -> str:
        """Return the table of every term per axis with its interval, in engineering units."""
        return _text_report(self)

    def __str__(self) -> str:
        return self.report()

    def __repr__(self) -> str:
        return _text_short_repr(self)

    def _repr_html_(self) -> str:  # Jupyter
        return _text_html(self)

    def to_dataframe(self) -> Any:
        """Return every term and axis as a :class:`pandas.DataFrame` (columns: :func:`_text_dataframe`)."""
        return _text_dataframe(self)

    # ------------------------------------------------------------------ documents
    def to_document(self) -> dict[str, Any]:
        """JSON-ready dict (``upper: null`` = not bounded); SI units, named in ``units``."""

        def term(t: NoiseTerm) -> dict[str, float | None]:
            return {"value": t.value, "lower": t.lower, "upper": t.upper if math.isfinite(t.upper) else None}

        doc: dict[str, Any] = {
            "source": self.source.value,
            "provenance": self.provenance,
            "confidence": self.confidence,
            "units": dict(SI_UNITS),
            "axes": {ax: {name: term(axis.term(name)) for name in TERMS} for ax, axis in zip(AXES, self.axes)},
        }
        if self.test is not None:
            doc["test"] = {"statistic": self.test.statistic, "p_value": self.test.p_value, "alpha": self.test.alpha}
        return doc

    @classmethod
    def from_document(cls, document: Any, path: str | None = None, prefix: str = "noise_model") -> NoiseModel:
        """Build and validate a model from :meth:`to_document`'s form; :class:`InputError` names the field.

        The reading is :func:`noise_model_from_document`.
        """
        return noise_model_from_document(document, path, prefix)


# --------------------------------------------------------------------------- how a model shows itself
def _triple(v: NDArray[np.float64], rtol: float = 1e-5) -> str:
    """One number when the three axes agree (to ``rtol``), else x/y/z."""
    return f"{np.max(v):.3g}" if np.allclose(v, np.max(v), rtol=rtol, atol=0.0) else "/".join(f"{x:.3g}" for x in v)


def _text_describe(model: NoiseModel) -> str:
    """Return one line: source and the slow terms (engineering units)."""
    b = model.values("bias_instability") / MICRO_G
    k = model.values("random_walk") / MICRO_G
    parts = [f"noise model ({model.source.value}"]
    if model.provenance:
        parts[0] += f": {model.provenance}"
    parts[0] += ")"
    if model.test is not None and not model.test.detected:  # the console's words: not detected, and what the data allow
        b_up = model.limits("bias_instability")[1] / MICRO_G
        k_up = model.limits("random_walk")[1] / MICRO_G
        b_text = f"up to {_triple(b_up, 0.01)} µg" if np.all(np.isfinite(b_up)) else "not bounded"
        k_text = f"up to {_triple(k_up, 0.01)} µg/√s" if np.all(np.isfinite(k_up)) else "not bounded"
        parts.append(f"slow noise not detected: bias instability {b_text}, random walk {k_text}")
        return "; ".join(parts)
    parts.append(f"bias instability {_triple(b)} µg, random walk {_triple(k)} µg/√s")
    if not model.slow_noise_bounded:
        parts.append("slow noise not bounded by the data")
    return "; ".join(parts)


def _text_summary(model: NoiseModel) -> str:
    """Return one short line for tables (certificate settings): source, N, B and K with their upper limits, the decision."""

    def term(name: str, unit: str, *, limit: bool = True) -> str:
        v = model.values(name) / MICRO_G
        up = model.limits(name)[1] / MICRO_G
        text = f"{_triple(v, 0.01)} {unit}"
        if not limit:
            return text
        if np.all(np.isinf(up)):
            return text + " (not bounded)" if np.all(v == 0) else text
        if not np.allclose(up, v):
            text += f" (≤ {_triple(up, 0.01)})"
        return text

    parts = [
        f"noise model ({model.source.value}): white {term('white', 'µg/√Hz', limit=False)}",
        f"bias instability {term('bias_instability', 'µg')}",
        f"random walk {term('random_walk', 'µg/√s')}",
    ]
    if model.test is not None:
        parts.append(f"slow noise {'detected' if model.test.detected else 'not detected'} (p = {model.test.p_value:.2g})")
    return ", ".join(parts[:3]) + ("; " + parts[3] if len(parts) > 3 else "")


def _text_report(model: NoiseModel) -> str:
    """Return the table of every term per axis with its interval, in engineering units."""
    level = f"{100 * model.confidence:g} %"
    lines = [f"noise model: {model.source.value}" + (f" ({model.provenance})" if model.provenance else "")]
    lines.append(f"{'term':<40} {'axis':>4} {'value':>12} {level + ' interval':>28}  unit")
    for label, axis, value, interval, unit in _text_term_rows(model):
        lines.append(f"{label if axis == AXES[0] else '':<40} {axis:>4} {value:>12} {interval:>28}  {unit}")
    decision = _text_test_line(model)
    if decision is not None:
        lines.append(decision)
    return "\n".join(lines)


def _text_term_rows(model: NoiseModel) -> list[list[str]]:
    """Return one row per term and axis: label, axis, value, interval (engineering units)."""
    rows = []
    for name in TERMS:
        unit, scale = ENGINEERING[name]
        for a, axis in enumerate(model.axes):
            term = axis.term(name)
            upper = "not bounded" if not term.bounded else f"{term.upper / scale:.4g}"
            rows.append([LABELS[name], AXES[a], f"{term.value / scale:.4g}", f"[{term.lower / scale:.4g}, {upper}]", unit])
    return rows


def _text_test_line(model: NoiseModel) -> str | None:
    """Return the slow-noise decision in one line, None without a test."""
    if model.test is None:
        return None
    t = model.test
    verdict = "detected" if t.detected else "not detected"
    return (
        f"slow noise {verdict}: statistic {t.statistic:+.2f} (0 ± 1 under white noise), p = {t.p_value:.3g} "
        f"(false-positive rate {t.alpha:g})"
    )


def _text_short_repr(model: NoiseModel) -> str:
    """Return the ``repr``: one line per term, clipped for a terminal."""
    lines = [f"<NoiseModel ({model.source.value}{': ' + model.provenance if model.provenance else ''})>"]
    for name in TERMS:
        unit, scale = ENGINEERING[name]
        cells = []
        for axis in model.axes:
            term = axis.term(name)
            upper = "∞" if not term.bounded else f"{term.upper / scale:.3g}"
            interval = "" if term.lower == term.value == term.upper else f" [{term.lower / scale:.3g}, {upper}]"
            cells.append(f"{term.value / scale:.3g}{interval}")
        same = len(set(cells)) == 1
        shown = f"{cells[0]} on every axis" if same else "   ".join(f"{a} {c}" for a, c in zip(AXES, cells, strict=True))
        lines.append(f"  {LABELS[name]} [{unit_text(unit)}]: {shown}")
    lines.append(_text_test_line(model) or f"intervals at {100 * model.confidence:g} % confidence")
    return clipped(lines, "(print(model) for the table)")


def _text_html(model: NoiseModel) -> str:
    """Return the Jupyter rendering: the table of :func:`_text_term_rows`."""
    rows = [[label, axis, value, interval, unit_text(unit)] for label, axis, value, interval, unit in _text_term_rows(model)]
    table = html_table(["term", "axis", "value", f"{100 * model.confidence:g} % interval", "unit"], rows, numeric=(2, 3))
    return html_result(f"Noise model: {model.source.value}", [model.provenance, _text_test_line(model) or ""], [table])


def _text_dataframe(model: NoiseModel) -> Any:
    """Return every term and axis as a :class:`pandas.DataFrame` (needs pandas).

    Columns ``term``, ``axis``, ``value``, ``lower``, ``upper``, ``unit``; engineering units, ``upper``
    infinite where the data do not bound the term.
    """
    pandas = require_pandas()
    rows = []
    for name in TERMS:
        unit, scale = ENGINEERING[name]
        for a, axis in enumerate(model.axes):
            term = axis.term(name)
            rows.append(
                {
                    "term": name,
                    "axis": AXES[a],
                    "value": term.value / scale,
                    "lower": term.lower / scale,
                    "upper": term.upper / scale,
                    "unit": unit,
                }
            )
    return pandas.DataFrame.from_records(rows)


# --------------------------------------------------------------------------- its JSON form read back
@dataclass(frozen=True)
class _Fields:
    """Checks of the fields of one document, with the file and the prefix its error messages name."""

    path: str | None
    prefix: str

    def fail(self, message: str, key: str, expected: str) -> InputError:
        """Return the error for field ``key`` (the prefix alone when empty)."""
        return InputError(message, path=self.path, field=f"{self.prefix}.{key}" if key else self.prefix, expected=expected)

    def number(self, value: Any, key: str, *, allow_null: bool = False, lo: float = 0.0) -> float:
        """Return ``value`` as a finite number ``>= lo`` (null: infinite, when ``allow_null``)."""
        if value is None and allow_null:
            return math.inf
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value) or value < lo:
            raise self.fail(
                f"{value!r} is not a finite number >= {lo:g}", key, "a finite non-negative number" + (" or null" if allow_null else "")
            )
        return float(value)

    def header(self, document: Any) -> tuple[NoiseSource, str, float]:
        """Return source, provenance and confidence, with the units checked to be SI."""
        if not isinstance(document, dict):
            raise self.fail("not an object", "", '{"source", "provenance", "confidence", "axes": {"x": {...}, ...}}')
        sources = {s.value: s for s in NoiseSource}
        if document.get("source") not in sources:
            raise self.fail(f"unknown source {document.get('source')!r}", "source", " or ".join(repr(s) for s in sources))
        provenance = document.get("provenance", "")
        if not isinstance(provenance, str):
            raise self.fail(f"{provenance!r} is not a string", "provenance", "a string")
        confidence = self.number(document.get("confidence", 0.95), "confidence")
        if not 0.0 < confidence < 1.0:
            raise self.fail(f"{confidence!r} is not a probability", "confidence", "a number between 0 and 1")
        units = document.get("units", SI_UNITS)
        if not isinstance(units, dict) or any(units.get(k, SI_UNITS[k]) != SI_UNITS[k] for k in TERMS):
            raise self.fail(f"units {units!r}", "units", f"the SI units {dict(SI_UNITS)}")
        return sources[document["source"]], provenance, confidence

    def axes(self, axes_doc: Any) -> tuple[AxisNoise, AxisNoise, AxisNoise]:
        """Return the three axes' terms."""
        if not isinstance(axes_doc, dict) or set(axes_doc) != set(AXES):
            raise self.fail("missing or malformed", "axes", 'an object with keys "x", "y", "z"')
        x, y, z = (self.axis(axes_doc[ax], ax) for ax in AXES)
        return x, y, z

    def axis(self, entry: Any, ax: str) -> AxisNoise:
        """Return the terms of axis ``ax``."""
        if not isinstance(entry, dict) or set(entry) != set(TERMS):
            raise self.fail("missing or malformed", f"axes.{ax}", f"an object with the keys {', '.join(TERMS)}")
        terms = {}
        for name in TERMS:
            item = entry[name]
            key = f"axes.{ax}.{name}"
            if not isinstance(item, dict) or not {"value", "lower", "upper"} <= set(item):
                raise self.fail("missing or malformed", key, '{"value", "lower", "upper"}')
            value = self.number(item["value"], f"{key}.value")
            lower = self.number(item["lower"], f"{key}.lower")
            upper = self.number(item["upper"], f"{key}.upper", allow_null=True)
            if not lower <= value <= upper:
                raise self.fail(f"interval [{lower}, {upper}] does not hold the value {value}", key, "lower <= value <= upper")
            terms[name] = NoiseTerm(value, lower, upper)
        return AxisNoise(**terms)

    def test(self, t: Any) -> SlowNoiseTest | None:
        """Return the slow-noise test (None when the document has none)."""
        if t is None:
            return None
        if not isinstance(t, dict):
            raise self.fail("not an object", "test", '{"statistic", "p_value", "alpha"}')
        statistic = self.number(t.get("statistic"), "test.statistic", lo=-math.inf)
        p_value = self.number(t.get("p_value"), "test.p_value")
        alpha = self.number(t.get("alpha"), "test.alpha")
        if p_value > 1.0 or not 0.0 < alpha < 1.0:
            raise self.fail("p_value or alpha outside (0, 1)", "test", "probabilities")
        return SlowNoiseTest(statistic, p_value, alpha)


def noise_model_from_document(document: Any, path: str | None = None, prefix: str = "noise_model") -> NoiseModel:
    """Return the model a :meth:`~stableins.noise.NoiseModel.to_document` form describes, every field validated.

    Raises
    ------
    InputError
        A field is missing or malformed: names ``path`` and the field under ``prefix``, and what was expected.
    """
    fields = _Fields(path, prefix)
    source, provenance, confidence = fields.header(document)
    axes = fields.axes(document.get("axes"))
    return NoiseModel(axes, source, provenance, confidence, fields.test(document.get("test")))


__all__ = [
    "FLICKER_FLOOR",
    "FLICKER_TIME_CONSTANTS",
    "AxisNoise",
    "NoiseModel",
    "NoiseSource",
    "NoiseTerm",
    "SlowNoiseTest",
    "TERMS",
    "noise_model_from_document",
    "sessions",
]
