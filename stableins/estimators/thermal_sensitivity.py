r"""The device-level thermal stage: the accelerometers' temperature sensitivities from dwells over a temperature change.

docs/thermal-calibration.md.  The platform holds a few fixed orientations (procedure ``device-thermal``: each axis up and
down) again and again while the instrument's temperature is cycled (a chamber, a warm-up and cool-down).  For axis ``a``
the mean output of dwell ``k`` at orientation ``p`` is

.. math:: \bar y_{k,a} = c_{p,a} + Kt\_bias_a\,ΔT_k + Kt\_sf_a\,\bar f_{p,a}\,ΔT_k + d_a\,(t_k - \bar t) + n_{k,a}

(the library's terms ``Kt_bias`` [m/s²/K] and ``Kt_sf`` [1/K], IEEE Std 1293 environment sensitivities; ``ΔT`` the
dwell's mean temperature from the session's weighted mean, ``\bar f_{p,a}`` the orientation's mean output on the axis,
which is its specific force to the calibration's accuracy).  The intercepts ``c_{p,a}`` take the whole static model of
each orientation (bias, scale factor, misalignments, K2, the gimbal kinematics), so the stage needs no other
calibration and is not biased by one; the bias drift ``d_a`` (``Kd_bias``) is a nuisance, which is why the temperature
must go up *and* down: a ramp monotonic in time is indistinguishable from a drift (the stage refuses it).

Generalized least squares per axis under the dwell means' covariance: the white variance ``σ²_k = s²/n_k`` measured in
each dwell (``s²`` from the second differences, ``var(Δ²y)/6``, free of any slow change) plus the slow noise of the
record's noise model (bias instability and random walk, correlated between dwells:
:meth:`~stableins.noise.NoiseModel.dwell_mean_covariance`, the one implementation the device stages use).  The bias
wander of a flicker floor has power at the temperature cycle's period, so white weights alone understate σ(Kt_bias)
(measured: rms z 1.74 over 40 quartz sessions).  When the fit's own ``χ²_ν`` is above 1 (a slow noise larger than the
model's), the covariance is scaled by it (Birge ratio).  The result is a
:class:`~stableins.estimators.result.FitResult` over the six terms with the
stage's :class:`~stableins.estimators.result.Likelihood`, for the Bayesian update of a record; the system stage takes the
record's values and σ as its thermal prior (docs/system-calibration.md §1b).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from stableins.conventions import AXES, MICRO_G, PPM
from stableins.documents import DocumentFields, JSONObject
from stableins.errormodel import Term
from stableins.errors import InputError
from stableins.estimators.details import StageDetails
from stableins.estimators.result import FitResult, Likelihood, Stage
from stableins.noise import NoiseModel
from stableins.status import Status

if TYPE_CHECKING:
    from stableins.data.device import Dwell

#: The six terms, in the order of the stage's result (the library's ids).
THERMAL_TERM_IDS = tuple(f"Kt_bias_{a}" for a in AXES) + tuple(f"Kt_sf_{a}" for a in AXES)
#: Least peak-to-peak of the dwells' mean temperatures [K].
MIN_SPAN = 0.5
#: Largest absolute correlation of ΔT with time (after the orientation intercepts) that still separates the drift.
MAX_TIME_CORRELATION = 0.95
#: Dwells whose commanded readings agree within this [rad] are one orientation.
SAME_ORIENTATION = 1e-6


@dataclass(frozen=True)
class ThermalDetails(StageDetails):
    """What the device-level thermal stage measured besides the sensitivities.

    Attributes
    ----------
    dwells, orientations : int
        Dwells used and distinct orientations.
    temperature_span : float
        Peak-to-peak of the dwells' mean temperatures [K].
    time_correlation : float
        absolute correlation of ΔT with time after the intercepts (1: a ramp, not separable from a drift).
    drift, drift_sigma : ndarray (3,)
        The bias drift ``d_a`` per axis and its σ [m/s³] (a nuisance).
    chi2, dof : ndarray (3,), int
        Per axis, the white-weighted fit's χ² and ν.
    scale : ndarray (3,)
        Per axis, ``max(1, χ²_ν)``: the factor on the covariance.
    """

    dwells: int
    orientations: int
    temperature_span: float
    time_correlation: float
    drift: NDArray[np.float64]
    drift_sigma: NDArray[np.float64]
    chi2: NDArray[np.float64]
    dof: int
    scale: NDArray[np.float64]


@dataclass(frozen=True)
class ThermalSettings:
    """What a thermal run's record states of it: dwells, orientations, temperature span [K], ν and the χ² scale per axis."""

    dwells: int
    orientations: int
    temperature_span_K: float  # noqa: N815 - the record's key
    dof: int
    scale: tuple[float, ...]

    def to_document(self) -> JSONObject:
        """Return ``{"dwells", "orientations", "temperature_span_K", "dof", "scale"}`` (docs/formats.md)."""
        return {"dwells": self.dwells, "orientations": self.orientations, "temperature_span_K": self.temperature_span_K,
                "dof": self.dof, "scale": list(self.scale)}  # fmt: skip

    @classmethod
    def from_document(cls, fields: DocumentFields) -> ThermalSettings:
        """Return the settings :meth:`to_document` wrote (:class:`InputError` naming the field)."""
        return cls(fields.count("dwells"), fields.count("orientations"), fields.number("temperature_span_K"), fields.count("dof"),
                   fields.numbers("scale"))  # fmt: skip


@dataclass(frozen=True)
class _DwellMeans:
    output: NDArray[np.float64]  # (K, 3) [m/s²]
    variance: NDArray[np.float64]  # (K, 3) of the means
    temperature: NDArray[np.float64]  # (K,) [°C]
    time: NDArray[np.float64]  # (K,) [s]
    orientation: NDArray[np.int64]  # (K,)
    start: NDArray[np.float64]  # (K,) [s]
    length: NDArray[np.float64]  # (K,) [s]


def _means(dwells: Sequence[Dwell], path: str | None) -> _DwellMeans:
    """Mean output, its white variance, mean temperature and time of each dwell; the orientation index of each."""
    outputs, variances, temperatures, times, keys, starts, lengths = [], [], [], [], [], [], []
    for d in dwells:
        f = np.asarray(d.specific_force, dtype=float)
        n = f.shape[0]
        if n < 8:
            continue
        second = np.diff(f, n=2, axis=0)
        outputs.append(f.mean(axis=0))
        variances.append(second.var(axis=0) / 6.0 / n)
        temperatures.append(float(np.mean(d.temperature)))
        times.append(float(np.mean(d.time)))
        step = float(np.median(np.diff(d.time)))
        starts.append(float(d.time[0]))
        lengths.append(float(d.time[-1] - d.time[0]) + step)
        keys.append(tuple(int(v) for v in np.round(np.asarray(d.command, dtype=float) / SAME_ORIENTATION)))
    if len(outputs) < 4:
        raise InputError(
            f"{len(outputs)} usable dwells", path=path, field="position", expected="repeated dwells at fixed orientations (device-thermal)"
        )
    index = {k: i for i, k in enumerate(dict.fromkeys(keys))}
    return _DwellMeans(
        np.array(outputs),
        np.array(variances),
        np.array(temperatures),
        np.array(times),
        np.array([index[k] for k in keys], dtype=np.int64),
        np.array(starts),
        np.array(lengths),
    )


def _check(m: _DwellMeans, path: str | None) -> tuple[float, float, NDArray[np.float64]]:
    """Refuse a session that cannot separate the sensitivities; return the span, the time correlation and the intercepts."""
    k, p = m.output.shape[0], int(m.orientation.max()) + 1
    counts = np.bincount(m.orientation, minlength=p)
    if p < 2 or np.count_nonzero(counts >= 2) < 2:
        raise InputError(
            f"{p} orientation(s) with {counts.tolist()} dwells", path=path, field="position",
            expected="at least two orientations, each held at two temperatures or more",
        )  # fmt: skip
    if k - p - 3 < 1:
        raise InputError(f"{k} dwells at {p} orientations leave no degree of freedom", path=path, field="position", expected="more dwells")
    span = float(np.ptp(m.temperature))
    if span < MIN_SPAN:
        raise InputError(
            f"the dwells' temperature spans {span:.3f} K", path=path, field="temperature",
            expected=f"a temperature change of at least {MIN_SPAN:g} K over the session (a chamber cycle, a warm-up)",
        )  # fmt: skip
    intercepts = np.zeros((k, p))
    intercepts[np.arange(k), m.orientation] = 1.0

    def residual_of(x: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.asarray(x - intercepts @ np.linalg.lstsq(intercepts, x, rcond=None)[0], dtype=np.float64)

    rt, rd = residual_of(m.time - m.time.mean()), residual_of(m.temperature - m.temperature.mean())
    correlation = float(abs(rt @ rd)) / math.sqrt(max(float(rt @ rt) * float(rd @ rd), 1e-300))
    if correlation > MAX_TIME_CORRELATION:
        raise InputError(
            f"the temperature changes almost linearly in time (|correlation| {correlation:.3f} with time after the orientation "
            "means): its sensitivity is not separable from a bias drift",
            path=path,
            field="temperature",
            expected="a temperature that goes up and down during the session (a chamber cycle), not a ramp",
        )
    return span, correlation, intercepts


def _notes(details: ThermalDetails, values: NDArray[np.float64], sigma: NDArray[np.float64]) -> tuple[str, ...]:
    """Return the stage's notes: the session, the fit's χ²_ν, the sensitivities and the drift."""
    scale = [MICRO_G] * 3 + [PPM] * 3
    units = ["µg/K"] * 3 + ["ppm/K"] * 3
    day = 86400.0 / MICRO_G
    return (
        f"{details.dwells} dwells at {details.orientations} orientations over a temperature span of {details.temperature_span:.2f} K "
        f"(|correlation| with time {details.time_correlation:.2f}); per axis a weighted fit of the dwell means with an intercept per "
        "orientation, the two sensitivities and a bias drift",
        "χ²_ν per axis (white dwell σ): "
        + ", ".join(f"{AXES[a]} {details.chi2[a] / details.dof:.2f}" for a in range(3))
        + f" (ν = {details.dof}); σ scaled by √χ²_ν where above 1 (the slow noise between dwells)",
        "sensitivities: "
        + ", ".join(
            f"{i} = {v / s:.3f} ± {e / s:.3f} {u}" for i, v, e, s, u in zip(THERMAL_TERM_IDS, values, sigma, scale, units, strict=True)
        ),
        "bias drift (nuisance): "
        + ", ".join(f"{AXES[a]} {details.drift[a] * day:.2f} ± {details.drift_sigma[a] * day:.2f} µg/day" for a in range(3)),
    )


def estimate_thermal(
    dwells: Sequence[Dwell], terms: Sequence[Term], *, gravity: float, noise_model: NoiseModel | None = None, path: str | None = None
) -> FitResult:
    """Estimate ``Kt_bias_a`` and ``Kt_sf_a`` from dwells over a temperature change (module docstring).

    Parameters
    ----------
    dwells : sequence of :class:`stableins.data.device.Dwell`
        The session's dwells (repeated orientations).
    terms : sequence of Term
        The library's six terms in :data:`THERMAL_TERM_IDS` order (``stableins.discovery.library.LIBRARY[id].term``).
    gravity : float
        Local gravity [m/s²].
    noise_model : NoiseModel, optional
        The instrument's noise model (the record's): its bias instability and random walk make the dwell means'
        covariance (:meth:`~stableins.noise.NoiseModel.dwell_mean_covariance`, with the white variance measured in each
        dwell).  Without one, or with no slow terms, the dwell means are independent.
    path : str, optional
        The data file, for error messages.

    Raises
    ------
    InputError
        Too few dwells or orientations, a temperature that does not change, or one that changes linearly in time.
    """
    if tuple(t.id for t in terms) != THERMAL_TERM_IDS:
        raise ValueError(f"terms must be {THERMAL_TERM_IDS}")
    m = _means(dwells, path)
    span, correlation, intercepts = _check(m, path)
    k, p = intercepts.shape
    delta = m.temperature - np.average(m.temperature)
    elapsed = m.time - np.average(m.time)
    mean_f = np.array([[m.output[m.orientation == j, a].mean() for a in range(3)] for j in range(p)])
    values = np.zeros(6)
    covariance = np.zeros((6, 6))
    drift, drift_sigma, chi2, scale = np.zeros(3), np.zeros(3), np.zeros(3), np.ones(3)
    residuals = np.zeros((k, 3))
    sigma = np.sqrt(m.variance)
    dof = k - p - 3
    model = noise_model if noise_model is not None else NoiseModel.given()
    dwell_cov = model.dwell_mean_covariance(m.start, m.length, white_variance=m.variance)
    for a in range(3):
        design = np.column_stack([intercepts, delta, delta * mean_f[m.orientation, a], elapsed])
        whiten = np.linalg.inv(np.linalg.cholesky(dwell_cov[a]))
        a_w = whiten @ design
        y_w = whiten @ m.output[:, a]
        info = a_w.T @ a_w
        if np.linalg.cond(info) > 1e14:
            raise InputError(
                f"the {AXES[a]} axis' scale-factor sensitivity is not separable: the orientations do not change its specific force",
                path=path, field="position", expected="each axis up and down (device-thermal)",
            )  # fmt: skip
        cov = np.linalg.inv(info)
        x = cov @ (a_w.T @ y_w)
        r = y_w - a_w @ x
        chi2[a] = float(r @ r)
        scale[a] = max(1.0, chi2[a] / dof)
        cov = cov * scale[a]
        values[a], values[3 + a] = x[p], x[p + 1]
        block = np.ix_([a, 3 + a], [a, 3 + a])
        covariance[block] = cov[p : p + 2, p : p + 2]
        drift[a], drift_sigma[a] = x[p + 2], math.sqrt(cov[p + 2, p + 2])
        residuals[:, a] = m.output[:, a] - design @ x
    details = ThermalDetails(k, p, span, correlation, drift, drift_sigma, chi2, dof, scale)
    ids = THERMAL_TERM_IDS
    information = np.asarray(np.linalg.inv(covariance), dtype=np.float64)
    likelihood = Likelihood(ids, values.copy(), information, np.zeros(6))
    notes = _notes(details, values, np.sqrt(np.diag(covariance)))
    return FitResult(
        stage=Stage.THERMAL,
        terms=tuple(terms),
        values=values,
        covariance=0.5 * (covariance + covariance.T),
        status=(Status.ESTIMATED,) * 6,
        residuals=residuals.ravel(),
        residual_sigma=sigma.ravel(),
        rank=6,
        notes=notes,
        details=details,
        likelihood=likelihood,
        gravity=gravity,
        settings=ThermalSettings(k, p, float(span), dof, tuple(float(s) for s in scale)),
    )


__all__ = ["MAX_TIME_CORRELATION", "MIN_SPAN", "THERMAL_TERM_IDS", "ThermalDetails", "estimate_thermal"]
