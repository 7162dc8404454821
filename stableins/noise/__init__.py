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

This module is the physics layer: it imports numpy and the project's conventions only (and,
when reading a document, the user-error type :class:`stableins.errors.InputError`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from enum import Enum
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stableins.conventions import MICRO_G
from stableins.noise.windows import gauss_markov_allan, gauss_markov_window_covariance, random_walk_window_covariance, sessions

#: Correlation times [s] of the Gauss-Markov sum representing flicker noise: 1 s to about
#: one day, the span over which an Allan floor is normally specified.  Flicker variance grows
#: with ln(τ_max); slower wander is a change of bias between calibrations.
FLICKER_TIME_CONSTANTS: tuple[float, ...] = tuple(10.0**k for k in range(0, 6))
#: Variance of each Gauss-Markov process per unit ``B²`` (one decade apart): ``ln(10)/π``.
FLICKER_VARIANCE_PER_B2 = math.log(10.0) / math.pi
#: Allan deviation floor of ideal flicker per unit ``B``: ``sqrt(2 ln 2/π) = 0.664``.
FLICKER_FLOOR = math.sqrt(2.0 * math.log(2.0) / math.pi)

AXES = ("x", "y", "z")
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
        from stableins.noise import text

        return text.describe(self)

    def summary(self) -> str:
        """Return one short line for tables (certificate settings): source, N, B and K with their upper limits, the decision."""
        from stableins.noise import text

        return text.summary(self)

    def report(self) -> str:
        """Return the table of every term per axis with its interval, in engineering units."""
        from stableins.noise import text

        return text.report(self)

    def __str__(self) -> str:
        return self.report()

    def __repr__(self) -> str:
        from stableins.noise import text

        return text.short_repr(self)

    def _repr_html_(self) -> str:  # Jupyter
        from stableins.noise import text

        return text.html(self)

    def to_dataframe(self) -> Any:
        """Return every term and axis as a :class:`pandas.DataFrame` (columns: :func:`stableins.noise.text.dataframe`)."""
        from stableins.noise import text

        return text.dataframe(self)

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

        The reading is :func:`stableins.noise.document.noise_model_from_document`.
        """
        from stableins.noise.document import noise_model_from_document

        return noise_model_from_document(document, path, prefix)


__all__ = [
    "AXES",
    "FLICKER_FLOOR",
    "FLICKER_TIME_CONSTANTS",
    "AxisNoise",
    "NoiseModel",
    "NoiseSource",
    "NoiseTerm",
    "SlowNoiseTest",
    "TERMS",
    "sessions",
]
