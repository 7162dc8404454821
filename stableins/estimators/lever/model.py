r"""Lever arms and time asynchrony from the slews of a rotating record (Cai et al. 2016 Eqs. 9–12, re-derived).

Observation equation
--------------------
The prior record compensates the accelerometer outputs into the platform frame, ``f̂^p = inverse(f^a)``
(Wu et al. 2018 Eq. 8 with the record's terms); the angle readings give the specific force the platform
should sense, ``f^p(r) = C_n^p(r + θ_0) f^n``, and its motion ``ω``, ``ω̇``
(:mod:`~stableins.estimators.lever.kinematics`).  While the platform turns their difference is, per axis
``a`` (docs/conventions.md "Lever arms and time asynchrony"),

.. math::
    y_a = \hat f^p_a - f^p_a = \sum_b \ell_{ab}\, e_a\!\cdot\!\big(\dot\omega\times e_b + \omega\times(\omega\times e_b)\big)
          + \tau\, e_a\!\cdot\!(\omega\times f^p) + \sum_b M_{ab} f^p_b + k_a (f^p_a)^2
          + \sum_{i=2,3} \frac{\partial f^p_a}{\partial\theta_{i0}}\delta\theta_{i0} + c_{a,s} + n_a ,

* ``ℓ_ab`` the lever arms (``lever_a_b``; Cai's three ``ℓ_aa`` by default, all nine on request),
* ``τ`` the time asynchrony (``t_async``, :func:`stableins.conventions.asynchrony_error`),
* nuisances, marginalized (:data:`NUISANCE_NAMES`): ``M`` (9) the prior's residual scale factor,
  misalignment and platform zero offset (linear in ``f^p``), its residual ``K2`` (``(f^p_a)²``) and inner and
  middle zero offsets (``∂f^p/∂θ_{20}``, ``∂f^p/∂θ_{30}``), and a level ``c_{a,s}`` per slew ``s`` and axis
  (the prior's residual bias, the slow noise of that slew).  At Cai's noise level (1 µg per 100-Hz
  sample) the prior's residuals (5 µg/g² of ``K2``, 2″ of zero offsets) would otherwise bias the arms by
  15σ and more.

Data and noise
--------------
Each slew is analysed with :data:`~stableins.estimators.lever.kinematics.STILL_MARGIN` seconds of the still platform
before and after it, in window means of ``window`` seconds.  The covariance of the window means is the
project's noise model (:meth:`stableins.noise.NoiseModel.dwell_mean_covariance`): the white part measured in
the still margins of the record itself (accelerometer white noise, quantization and the readings' noise as
they reach ``f^p``), the slow part (bias instability, random walk) from the record's noise model.  Slews are
independent given their levels ``c``.  The fit is generalized least squares; when its ``χ²_ν`` exceeds
``1 + 3√(2/ν)`` the model leaves structure above the noise (at Cai's noise level with all nine arms: the
differentiated readings' noise and the smoothing at the slews' ends, ``χ²_ν ≈ 1.4``) and the σ are scaled
by ``√χ²_ν``, which the notes say; the lever arms and ``τ`` enter
the record through the marginal likelihood (the nuisances integrated out): a Bayesian update that moves
nothing else.

Flags
-----
``lever`` when ``ℓ̂ᵀ C_ℓ^{-1} ℓ̂`` exceeds the χ²_k quantile at ``1 − alpha``; ``asynchrony`` when
``(τ̂/σ_τ)²`` exceeds the χ²_1 quantile: the lever arms (or ``τ``) are significant and a compensation should
apply them.  With honest σ the false-alarm rate on clean data is ``alpha`` (measured in
``benchmarks/bench_lever_arms.py``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np
from numpy.typing import NDArray

from stableins.conventions import GimbalConfiguration, asynchrony_error
from stableins.documents import DocumentFields, JSONObject
from stableins.errormodel import ErrorModel, Term, TermInputs
from stableins.errors import InputError, NotDeterminedError
from stableins.estimators.details import StageDetails
from stableins.estimators.lever.kinematics import Motion, Segment, find_segments, motion, window_means
from stableins.estimators.result import FitResult, Likelihood, Stage
from stableins.noise import NoiseModel
from stableins.platform import GimbalPlatform
from stableins.site import SiteMetadata
from stableins.status import Status
from stableins.terms import CAI_LEVER_IDS, LEVER_TERMS, TIME_ASYNC_TERM

#: Default window of the means [s].
DEFAULT_WINDOW = 0.5
#: A parameter whose 1σ exceeds this many times its nominal size (20 mm, 1 ms) is not determined by the slews
#: (a lever arm along the only axis of rotation: its regressor is the readings' noise).
UNDETERMINED = 1e3


class LeverSet(StrEnum):
    """Which lever arms the fit estimates."""

    #: Cai et al. 2016's three along-axis arms ``lever_x_x``, ``lever_y_y``, ``lever_z_z``.
    CAI = "cai"
    #: All nine ``lever_a_b``.
    FULL = "full"


@dataclass(frozen=True)
class LeverOptions:
    """Options of the lever-arm fit.

    Attributes
    ----------
    arms : LeverSet
        Cai's three (default) or all nine.
    asynchrony : bool
        Fit the time asynchrony ``τ`` (default true); false holds it at zero.
    window : float
        Window of the means [s].
    alpha : float
        False-alarm probability of each flag.
    """

    arms: LeverSet = LeverSet.CAI
    asynchrony: bool = True
    window: float = DEFAULT_WINDOW
    alpha: float = 0.01

    def to_document(self) -> JSONObject:
        """Return the options as the lever stage's settings: ``{"arms", "asynchrony", "window", "alpha"}`` (docs/formats.md)."""
        return {"arms": self.arms.value, "asynchrony": self.asynchrony, "window": self.window, "alpha": self.alpha}

    @classmethod
    def from_document(cls, fields: DocumentFields) -> LeverOptions:
        """Return the options :meth:`to_document` wrote (:class:`InputError` naming the field)."""
        arms = fields.text("arms")
        if arms not in {s.value for s in LeverSet}:
            raise fields.fail("arms", f"{arms!r} is not a set of lever arms", ", ".join(s.value for s in LeverSet))
        return cls(LeverSet(arms), fields.flag("asynchrony"), fields.number("window"), fields.number("alpha"))


@dataclass(frozen=True)
class Flag:
    """A significance test: statistic ``χ²`` with ``dof`` degrees of freedom, its p-value and whether it flags."""

    name: str
    chi2: float
    dof: int
    p_value: float
    flagged: bool

    def describe(self) -> str:
        """One line for the report."""
        verdict = "FLAGGED: significant, compensate it" if self.flagged else "not flagged (consistent with zero)"
        return f"{self.name}: χ² = {self.chi2:.2f} on {self.dof} dof, p = {self.p_value:.3g}: {verdict}"


@dataclass(frozen=True, eq=False)
class LeverDetails(StageDetails):
    """What the lever-arm fit worked with, beyond the parameters.

    Attributes
    ----------
    slews : tuple of str
        When each analysed slew ran.
    windows : int
        Window means used (all axes).
    white : tuple of float
        Measured 1σ of one window mean per axis [m/s²] (white part).
    flags : tuple of Flag
        ``lever`` and (when fitted) ``asynchrony``.
    nuisance : mapping of str to (float, float)
        The linear nuisance ``M_ab`` (value, 1σ) [1].
    correlation : float
        Largest absolute correlation between ``τ`` and a lever arm (0 when ``τ`` is held).
    """

    slews: tuple[str, ...]
    windows: int
    white: tuple[float, float, float]
    flags: tuple[Flag, ...]
    nuisance: Mapping[str, tuple[float, float]] = field(default_factory=dict)
    correlation: float = 0.0


@dataclass(frozen=True)
class _Design:
    """Whitened observations ``b`` and design ``A`` with the column names."""

    b: NDArray[np.float64]
    A: NDArray[np.float64]
    names: list[str]
    windows: int
    white: NDArray[np.float64]
    slews: tuple[str, ...]


def estimate_lever(
    columns: Mapping[str, NDArray[np.float64]],
    site: SiteMetadata,
    prior_values: Mapping[str, float],
    *,
    error_model: ErrorModel | None = None,
    noise_model: NoiseModel | None = None,
    options: LeverOptions | None = None,
    source: str = "record",
) -> FitResult:
    """Estimate the lever arms (and ``τ``) from the slews in ``columns`` (module docstring).

    Parameters
    ----------
    columns : mapping
        ``time``, ``angle_platform``, ``angle_inner``, ``angle_middle``, ``f_x``, ``f_y``, ``f_z`` and optionally
        ``temperature`` (SI) of a record that keeps its slews (``stableins run device-rotating``), on one clock.
    site : SiteMetadata
        Gravity, base attitude, gimbal senses, sample rate, reference temperature.
    prior_values : mapping
        The unit's record: zero offsets and the accelerometer model that compensates the outputs.
    error_model : ErrorModel, optional
        The record's error model (default: the standard one with ``K2``).
    noise_model : NoiseModel, optional
        The record's noise model (its slow part is used; the white part is measured here).
    options : LeverOptions, optional
    source : str
        Names the data in messages.

    Returns
    -------
    FitResult
        Stage ``"lever"``: the lever arms and ``t_async`` with their marginal covariance and likelihood;
        :class:`LeverDetails` in ``details``.

    Raises
    ------
    InputError
        No slew in the data, or slews that do not determine the arms asked for.
    """
    options = options or LeverOptions()
    time = np.asarray(columns["time"], dtype=float)
    readings = np.stack([np.asarray(columns[f"angle_{g}"], dtype=float) for g in ("platform", "inner", "middle")], axis=1)
    output = np.stack([np.asarray(columns[f"f_{a}"], dtype=float) for a in "xyz"], axis=1)
    platform = GimbalPlatform(
        zero_offsets=tuple(float(prior_values.get(g, 0.0)) for g in ("theta10", "theta20", "theta30")),  # type: ignore[arg-type]
        configuration=GimbalConfiguration(tuple(site.gimbal_senses)),  # type: ignore[arg-type]
        base_attitude=site.base_attitude,
    )
    record = _Record(time, readings, output, _pieces(time, site.sample_rate, source))
    terms = _terms(options)
    context = _Context(platform, site, prior_values, error_model, columns.get("temperature"))
    design = _design(record, context, terms, options, noise_model or NoiseModel.unknown())
    if not design.windows:
        raise InputError(
            f"{source}: no slew found (the platform never turned faster than 0.06 °/s)", field="angle_middle",
            expected="a record that keeps its slews: stableins run device-rotating",
        )  # fmt: skip
    return _solve(design, terms, options, source, site.gravity)


@dataclass(frozen=True)
class _Record:
    """The samples: time, readings, outputs, and the sample ranges recorded without a gap."""

    time: NDArray[np.float64]
    readings: NDArray[np.float64]
    output: NDArray[np.float64]
    pieces: list[tuple[int, int]]


@dataclass(frozen=True)
class _Context:
    platform: GimbalPlatform
    site: SiteMetadata
    values: Mapping[str, float]
    model: ErrorModel | None
    temperature: NDArray[np.float64] | None


def _terms(options: LeverOptions) -> tuple[Term, ...]:
    arms = tuple(t for t in LEVER_TERMS if options.arms is LeverSet.FULL or t.id in CAI_LEVER_IDS)
    return arms + ((TIME_ASYNC_TERM,) if options.asynchrony else ())


def _pieces(time: NDArray[np.float64], rate: float, source: str) -> list[tuple[int, int]]:
    """Sample ranges recorded without a gap (a gap is longer than 1.5 sample intervals)."""
    if time.size < 3 or not np.all(np.isfinite(time)) or np.any(np.diff(time) <= 0):
        raise InputError(f"{source}: time must increase strictly", field="time", expected="a record on one clock")
    breaks = np.flatnonzero(np.diff(time) > 1.5 / rate) + 1
    edges = [0, *breaks.tolist(), time.size]
    return [(a, b) for a, b in zip(edges[:-1], edges[1:], strict=True) if b - a > 1]


def _regressors(motion_: Motion, f_p: NDArray[np.float64], terms: Sequence[Term]) -> NDArray[np.float64]:
    """Regressors (N, 3, p) of the lever arms and ``τ`` (module docstring)."""
    out = np.zeros(f_p.shape + (len(terms),))
    w, wd = motion_.rate, motion_.acceleration
    for k, term in enumerate(terms):
        if term.id == TIME_ASYNC_TERM.id:
            out[..., k] = asynchrony_error(1.0, w, f_p)
            continue
        a, b = "xyz".index(term.id[6]), "xyz".index(term.id[8])
        e = np.zeros(3)
        e[b] = 1.0
        acc = np.cross(wd, e) + np.cross(w, np.cross(w, e))
        out[:, a, k] = acc[:, a]
    return out


def _design(record: _Record, context: _Context, terms: Sequence[Term], options: LeverOptions, noise: NoiseModel) -> _Design:
    """Window means of every slew, whitened by the noise model (module docstring)."""
    time, readings, output, pieces = record.time, record.readings, record.output, record.pieces
    rate = context.site.sample_rate
    length = max(1, int(round(options.window * rate)))
    slews: list[tuple[NDArray, NDArray, NDArray, Segment]] = []  # (y windows, X windows, starts, segment)
    for a, b in pieces:
        moved = motion(readings[a:b], rate, context.platform)
        smooth_f = np.einsum("...ij,j->...i", _nav_to_platform(context.platform, moved.actual), _f_nav(context.site.gravity))
        residual = _compensated(output[a:b], smooth_f, time[a:b], context) - smooth_f
        nuisance = _nuisance_regressors(readings[a:b], smooth_f, context)
        regressors = np.concatenate([_regressors(moved, smooth_f, terms), nuisance], axis=-1)
        for segment in find_segments(time[a:b], moved.rate):
            y = window_means(residual, segment.first, segment.stop, length)
            x = window_means(regressors, segment.first, segment.stop, length)
            starts = window_means(time[a:b], segment.first, segment.stop, length) - 0.5 * (length - 1) / rate
            slews.append((y, x, starts, Segment(segment.first + a, segment.stop + a, segment.moving_first + a, segment.moving_stop + a)))
    if not slews:
        return _Design(np.zeros(0), np.zeros((0, 0)), [], 0, np.zeros(3), ())
    white = _white_variance(slews, time, length, rate, noise)
    described = tuple(s[3].describe(time) for s in slews)
    return _whiten(slews, white, noise, window=length / rate, names=[t.id for t in terms], described=described)


def _nav_to_platform(platform: GimbalPlatform, actual: NDArray[np.float64]) -> NDArray[np.float64]:
    return platform.dcm_body_to_platform_actual(actual) @ platform.dcm_nav_to_body()


def _f_nav(gravity: float) -> NDArray[np.float64]:
    from stableins.conventions import specific_force_nav

    return specific_force_nav(gravity)


def _compensated(output: NDArray, f_p: NDArray, time: NDArray, context: _Context) -> NDArray[np.float64]:
    """Compensate the accelerometer outputs by the prior record into the platform frame."""
    model = context.model or ErrorModel.standard(nonlinear=True)
    temperature = None if context.temperature is None else np.asarray(context.temperature, dtype=float)
    inputs = TermInputs(f_p, None if temperature is None else temperature - context.site.reference_temperature, time)
    return model.inverse(output, context.values, inputs)


#: The prior's residuals the fit carries as nuisances (module docstring): ``M_ab`` (linear), ``K2`` (quadratic),
#: the inner and middle zero offsets (the platform's is a rotation about ``z_p``, part of ``M``).
NUISANCE_NAMES: tuple[str, ...] = tuple(f"M_{a}{b}" for a in "xyz" for b in "xyz") + ("K2_x", "K2_y", "K2_z", "theta20", "theta30")


def _nuisance_regressors(readings: NDArray, f_p: NDArray[np.float64], context: _Context) -> NDArray[np.float64]:
    """Return the regressors (N, 3, 14) of the nuisances :data:`NUISANCE_NAMES`.

    ``M_ab f^p_b`` and ``K2_a (f^p_a)²`` on axis ``a``; ``∂f^p/∂θ_i0`` (central differences of the exact
    kinematics) on all axes.
    """
    out = np.zeros(f_p.shape + (len(NUISANCE_NAMES),))
    for a in range(3):
        out[:, a, 3 * a : 3 * a + 3] = f_p
        out[:, a, 9 + a] = f_p[:, a] ** 2
    h = 1e-6
    for k, gimbal in enumerate((1, 2)):
        step = np.zeros(3)
        step[gimbal] = h
        plus = context.platform.specific_force_platform(readings + step, context.site.gravity)
        minus = context.platform.specific_force_platform(readings - step, context.site.gravity)
        out[..., 12 + k] = (plus - minus) / (2 * h)
    return out


def _white_variance(slews: list, time: NDArray, length: int, rate: float, noise: NoiseModel) -> NDArray[np.float64]:
    """Variance of one window mean per axis from the still margins (white part: the model's quantization term removed)."""
    squares = np.zeros(3)
    count = 0
    for y, _, starts, segment in slews:
        before = starts < time[segment.moving_first] - 0.5
        after = starts > time[segment.moving_stop - 1] + 0.5
        for still in (before, after):
            if np.count_nonzero(still) > 2:
                part = y[still]
                squares += np.sum((part - part.mean(axis=0)) ** 2, axis=0)
                count += len(part) - 1
    if count < 10:
        raise InputError(
            f"{count} still windows around the slews: too few to measure the noise", field="time",
            expected="slews with still time before and after them (pauses of the rotating procedure)",
        )  # fmt: skip
    measured = squares / count
    quantization = 2.0 * noise.values("quantization") ** 2 / (length / rate) ** 2
    return np.maximum(measured - quantization, 0.1 * measured)


def _whiten(
    slews: list, white: NDArray[np.float64], noise: NoiseModel, *, window: float, names: list[str], described: tuple[str, ...]
) -> _Design:
    """Stack the slews, whitened per axis by the Cholesky factor of their window-mean covariance, with a level per slew and axis."""
    from scipy.linalg import cholesky, solve_triangular

    p = slews[0][1].shape[-1]
    blocks_b, blocks_a = [], []
    n_slews = len(slews)
    for s, (y, x, starts, _) in enumerate(slews):
        covariance = noise.dwell_mean_covariance(starts, np.full(starts.size, window), np.broadcast_to(white, (starts.size, 3)))
        for a in range(3):
            factor = cholesky(covariance[a], lower=True)
            level = np.zeros((starts.size, 3 * n_slews))
            level[:, 3 * s + a] = 1.0
            design = np.concatenate([x[:, a, :], level], axis=1)
            blocks_b.append(solve_triangular(factor, y[:, a], lower=True))
            blocks_a.append(solve_triangular(factor, design, lower=True))
    nuisance = list(NUISANCE_NAMES)
    levels = [f"c{s + 1}_{a}" for s in range(n_slews) for a in "xyz"]
    assert p == len(names) + len(nuisance)
    return _Design(
        np.concatenate(blocks_b), np.vstack(blocks_a), names + nuisance + levels, sum(len(s[0]) for s in slews) * 3, np.sqrt(white),
        described,
    )  # fmt: skip


def _solve(design: _Design, terms: tuple[Term, ...], options: LeverOptions, source: str, gravity: float) -> FitResult:
    """Generalized least squares, the marginal covariance and likelihood of the arms and ``τ``, the flags."""
    A, b = design.A, design.b
    scale = np.sqrt(np.sum(A**2, axis=0))
    scale[scale == 0] = 1.0
    u, s, vt = np.linalg.svd(A / scale, full_matrices=False)
    if s[-1] < 1e-10 * s[0]:
        weak = [design.names[k] for k in np.argsort(-np.abs(vt[-1]))[:3]]
        raise NotDeterminedError(
            f"{source}: the slews do not determine {', '.join(weak)}", field="angle_middle",
            expected="slews about at least two platform axes (the device-rotating procedure), or the three lever arms of Cai",
        )  # fmt: skip
    x = (vt.T @ ((u.T @ b) / s)) / scale
    cov_all = (vt.T / s**2) @ vt / np.outer(scale, scale)
    residual = b - A @ x
    dof = A.shape[0] - A.shape[1]
    chi2_nu = float(residual @ residual) / dof if dof > 0 else math.nan
    misfit = dof > 0 and chi2_nu > 1.0 + 3.0 * math.sqrt(2.0 / dof)
    if misfit:  # the model leaves structure above the noise: σ scaled by √χ²_ν (Birge ratio), and said
        cov_all = cov_all * chi2_nu
    n = len(terms)
    loose = [t.id for k, t in enumerate(terms) if not math.sqrt(cov_all[k, k]) < UNDETERMINED * t.nominal]
    if loose:
        raise NotDeterminedError(
            f"{source}: the slews do not determine {', '.join(loose)}", field="angle_middle",
            expected="slews about at least two platform axes (the device-rotating procedure), or the three lever arms of Cai",
        )  # fmt: skip
    cov = 0.5 * (cov_all[:n, :n] + cov_all[:n, :n].T)
    values = x[:n]
    likelihood = Likelihood(tuple(t.id for t in terms), values, np.linalg.inv(cov), np.zeros(n))
    flags = _flags(values, cov, terms, options.alpha)
    sigma = np.sqrt(np.diag(cov))
    correlation = 0.0
    if options.asynchrony:
        correlation = float(np.max(np.abs(cov[-1, :-1] / (sigma[-1] * sigma[:-1])))) if n > 1 else 0.0
    nuisance = {name: (float(x[k]), float(math.sqrt(cov_all[k, k]))) for k, name in enumerate(design.names) if name in NUISANCE_NAMES}
    details = LeverDetails(
        design.slews, design.windows, (float(design.white[0]), float(design.white[1]), float(design.white[2])),
        flags, nuisance, correlation,
    )  # fmt: skip
    notes = tuple(f.describe() for f in flags)
    if misfit:
        notes += (f"χ²_ν = {chi2_nu:.2f} above 1 + 3√(2/ν): the σ are scaled by √χ²_ν = {math.sqrt(chi2_nu):.2f}",)
    return FitResult(
        stage=Stage.LEVER,
        terms=terms,
        values=values,
        covariance=cov,
        status=(Status.ESTIMATED,) * n,
        residuals=residual,
        residual_sigma=np.ones_like(residual),
        rank=A.shape[1],
        notes=notes,
        details=details,
        likelihood=likelihood,
        gravity=gravity,
        settings=options,
    )


def _flags(values: NDArray[np.float64], cov: NDArray[np.float64], terms: tuple[Term, ...], alpha: float) -> tuple[Flag, ...]:
    """Return the lever and asynchrony significance tests (module docstring)."""
    from scipy.stats import chi2

    arms = [k for k, t in enumerate(terms) if t.id != TIME_ASYNC_TERM.id]
    groups = [("lever arms", arms)] + [("time asynchrony", [k]) for k, t in enumerate(terms) if t.id == TIME_ASYNC_TERM.id]
    out = []
    for name, index in groups:
        v = values[index]
        stat = float(v @ np.linalg.solve(cov[np.ix_(index, index)], v))
        p = float(chi2.sf(stat, len(index)))
        out.append(Flag(name, stat, len(index), p, p < alpha))
    return tuple(out)
