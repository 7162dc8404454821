r"""Gyro drift and the full gyro g-sensitivity from the angle-reading slopes within device-level dwells.

Observation equation (derived here; Cai et al. 2016 Eq. 1 is the gyro model, not this estimator)
------------------------------------------------------------------------------------------------
How the platform is held during a dwell is the data's :class:`~stableins.dwell_mode.DwellMode` (docs/conventions.md,
"The platform during a dwell"; :func:`stableins.conventions.dwell_platform_rate`).  A stabilised platform whose gyro
about platform axis ``a`` reads ``ε_a + Σ_b Dg_ab f^p_b`` too much turns relative to the base at

.. math::
    \omega_{bp}^p = w + k \circ \omega_{ie}^p \ \text{(torqued at the Earth rate)}, \qquad
    \omega_{bp}^p = w - \omega_{ie}^p \ \text{(inertially held)}, \qquad w = -(\varepsilon^p + D_g f^p)

(:func:`stableins.conventions.platform_drift_rate`; ``k`` the torquers' scale-factor errors).  The angle sensors
measure the actual gimbal angles, so the turn is in the readings: with the exact gimbal-rate map
``ω_bp^p = J(α) α̇`` (:meth:`stableins.platform.GimbalPlatform.angular_rate`, column ``k`` the platform rate per
unit rate of gimbal ``k`` at the dwell's actual angles ``α = r + θ0``)

.. math::
    \dot r = J(\alpha)^{-1} \omega_{bp}^p, \qquad f^p = C_n^p(\alpha)\,(0, 0, -g)^T,

linear in the 12 numbers ``ε^p`` (``gyro_drift_x/y/z``) and ``D_g`` (``Dg_ab``) and in the mode's nuisances
(:attr:`SlopeGeometry.nuisance`): torqued, the three ``k`` (their columns ``J⁻¹(e_a ω_ie,a^p)``); inertially held,
the Earth's exact turn is subtracted from the readings first (:func:`remove_earth_turn`: 15 °/h is not a line over
a dwell) and the offsets and the base azimuth it depends on are the nuisances (finite-difference columns).  The
nuisances are estimated with the twelve and marginalized (the twelve's covariance is the block of the joint one,
their information the Schur complement).  Caged dwells carry no gyro information: the stage raises ``ValueError``
saying so.  The slope of each reading is a least-squares line over the second half of the dwell
(:data:`SLOPE_SKIP`: the servo's settling transient is in the first part).  ``f^p`` changes within a dwell by the
drift angle only (< 1e-4 rad), a 1e-4 relative effect.  ``J`` and ``f^p`` are evaluated at the centre of the samples
each line is fitted on (:attr:`ReadingSlopes.centre`), where a least-squares line's slope is the path's derivative to
second order: the drift turns the readings along ``J(α(t))⁻¹ w``, and at the dwell's mean reading instead (7″ away in
a 600-s dwell at 0.05 °/h) ``J`` errs by 4e-5 relative, 0.1–0.5σ of a fine dwell's slope.

Gauge
-----
The numbers are in the platform frame of the device gauge ``θ10 = 0`` (docs/device-calibration.md §2): with a true
``θ10`` the x and y indices of ``ε^p`` and ``D_g`` belong to ``p`` turned by ``θ10`` about ``z_p``
(:func:`gauge_statement`, printed and carried in the notes).

Noise model (measured, one for every σ and flag)
------------------------------------------------
White angle noise per gimbal, measured in the data: the residual scatter about each dwell's line, pooled over the
dwells used, ``σ_k² = Σ_dwells RSS / Σ_dwells (n − 2)``.  A slope's 1σ is ``σ_k / sqrt(Σ (t − t̄)²)``.  The
fit's covariance rests on it (not scaled by χ²_ν); χ²_ν of the slopes tests the model, and χ² beyond its 99.9 %
quantile gives the accelerometer stages' warning (:func:`stableins.estimators.gauss_newton.goodness_of_fit_warning`:
same rule, same wording, in the notes and :attr:`GyroSensitivityDetails.chi2_warning`).
``benchmarks/bench_device_gsensitivity.py`` measures the Monte Carlo rms z of the 12 numbers.

What the data determine (rank report)
-------------------------------------
The slopes give the full platform rate ``w`` at every dwell (``J`` is invertible away from gimbal lock; dwells
with ``cond J >`` :data:`MAX_CONDITION` are left out).  So the 12 numbers are determined exactly when the vectors
``(1, f^p)`` of the dwells span ``R⁴`` — Wu's 18 positions put ``f^p`` along ``±x, ±y, ±z`` and between.  Positions
that only turn about one axis (``f^p`` in a plane, or ``f_z`` never reversed) leave combinations free: the report
names the null directions of the column-scaled design.  Not visible at device level at all: the mounting of the
gyros in the platform (the frame ``p`` is defined by the gimbal kinematics), and a gyro scale factor beyond the
torquers' (the platform is torqued at most at the Earth rate during a dwell).

Flag
----
``D_g = 0`` is tested with ``W = \hat d^T C_d^{-1} \hat d`` over the g-sensitivities estimated (χ² with as many
degrees of freedom under ``D_g = 0``); flagged when its p-value is below :data:`FLAG_ALPHA`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stableins.conventions import (
    ARCSEC,
    AXES,
    DEFAULT_GIMBALS,
    DEG_PER_HOUR,
    DEG_PER_HOUR_PER_G,
    GimbalConfiguration,
    earth_rate_nav,
    platform_drift_rate,
)
from stableins.documents import DocumentFields, JSONObject
from stableins.dwell_mode import DEFAULT_DWELL_MODE, DwellMode
from stableins.errormodel import GYRO_DRIFT_TERMS, GYRO_G_TERMS, Term
from stableins.estimators.details import StageDetails
from stableins.estimators.distributions import chi2_sf
from stableins.estimators.gauss_newton import goodness_of_fit_warning
from stableins.estimators.result import FitResult, Likelihood, Stage
from stableins.platform import GIMBAL_LOCK_CONDITION, GIMBAL_NAMES, GimbalPlatform, platform_specific_force, rotation_about
from stableins.status import Status

#: Fraction of each dwell left out at its start before fitting reading slopes (servo settling).
SLOPE_SKIP = 0.5
#: Dwells whose gimbal-rate map is worse conditioned than this are left out (near gimbal lock; the platform is caged there).
MAX_CONDITION = GIMBAL_LOCK_CONDITION
#: Relative singular value (column-scaled design) below which a direction counts as not determined.  A direction
#: seen only through the arcsecond scatter of the mean readings (``f_z`` of positions that only turn the platform
#: axis varies by 1e-9 relative) would otherwise pass as determined with a σ 1e9 times the others'.
RANK_RTOL = 1e-6
#: False-alarm level of the ``D_g = 0`` test.
FLAG_ALPHA = 0.01
#: The twelve numbers of the stage, in vector order: ``gyro_drift_x/y/z``, then ``Dg_xx, Dg_xy, …, Dg_zz``.
GYRO_TERMS: tuple[Term, ...] = GYRO_DRIFT_TERMS + GYRO_G_TERMS


@dataclass(frozen=True, eq=False)
class ReadingSlopes:
    """Least-squares lines through the angle readings of each dwell (after the settling part).

    Attributes
    ----------
    slope : ndarray (P, 3)
        Reading rate per dwell and gimbal (platform, inner, middle) [rad/s].
    rss : ndarray (P, 3)
        Residual sum of squares about each line [rad²].
    dof : ndarray (P,)
        Samples used minus 2.
    sxx : ndarray (P,)
        ``Σ (t − t̄)²`` of the samples used [s²].
    distinct : ndarray (P, 3) of bool
        Whether the reading took at least 3 values (a quiet or coarsely quantized sensor has no scatter to weigh by).
    centre : ndarray (P, 3)
        The mean reading of the samples used [rad]: the line's value at their mean time, where its slope is the
        reading rate (a least-squares line through a smooth path has the path's derivative at the centre of the
        samples, to second order).  The geometry (:class:`SlopeGeometry`) is evaluated there.
    """

    slope: NDArray[np.float64]
    rss: NDArray[np.float64]
    dof: NDArray[np.float64]
    sxx: NDArray[np.float64]
    distinct: NDArray[np.bool_]
    centre: NDArray[np.float64]

    @classmethod
    def of(cls, dwells: Sequence[tuple[ArrayLike, ArrayLike]], skip: float = SLOPE_SKIP) -> ReadingSlopes:
        """Fit the lines of ``(time (n,), angles (n, 3))`` per dwell, leaving out the first ``skip`` of each."""
        rows = [_line(t, a, skip) for t, a in dwells]
        return cls(*(np.array([r[k] for r in rows]) for k in range(6)))

    def sigma(self) -> NDArray[np.float64]:
        """Return the 1σ of each slope from its own dwell's scatter (NaN where the reading is constant)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            s = np.sqrt(self.rss / np.maximum(self.dof, 1.0)[:, None] / self.sxx[:, None])
        return np.where(self.distinct & (self.sxx[:, None] > 0), s, np.nan)

    def angle_noise(self, keep: NDArray[np.bool_]) -> NDArray[np.float64]:
        """Return the white angle noise per gimbal [rad, 1σ per sample], pooled over the dwells ``keep``."""
        return np.sqrt(self.rss[keep].sum(axis=0) / max(float(self.dof[keep].sum()), 1.0))


def _line(time: ArrayLike, angles: ArrayLike, skip: float) -> tuple[NDArray, NDArray, float, float, NDArray, NDArray]:
    t_all = np.asarray(time, dtype=float)
    keep = t_all >= t_all[0] + skip * (t_all[-1] - t_all[0])
    t = t_all[keep]
    a = np.asarray(angles, dtype=float).reshape(t_all.size, -1)[keep]
    x = t - t.mean()
    sxx = float(x @ x)
    slope = x @ (a - a.mean(axis=0)) / sxx if sxx > 0 else np.zeros(a.shape[1])
    residual = a - a.mean(axis=0) - np.outer(x, slope)
    distinct = np.array([np.unique(a[:, k]).size >= 3 for k in range(a.shape[1])])
    return slope, (residual**2).sum(axis=0), float(max(t.size - 2, 0)), sxx, distinct, a.mean(axis=0)


def reading_slope(time: ArrayLike, angles: ArrayLike, skip: float = SLOPE_SKIP) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Least-squares slope of each angle reading [rad/s] and its 1σ from the scatter about the line (one dwell).

    The first ``skip`` fraction of the dwell is left out: the gimbal servo's settling transient (a damped oscillation
    after the slew) is in the readings there and biases a slope although it hardly moves a mean.  Simulated with the
    default settling (0.5 Hz, ζ = 0.2) and a 3 s settle, slopes over whole dwells gave χ²_ν ≈ 3 on clean data; over
    the second half 0.83–1.24 (3 or 10 s settle, 20 or 60 s dwells, ν ≈ 78).  A reading that takes fewer than 3
    values has NaN σ.
    """
    lines = ReadingSlopes.of([(time, angles)], skip)
    return lines.slope[0], lines.sigma()[0]


@dataclass(frozen=True, eq=False)
class SlopeGeometry:
    """The dwells' geometry for the reading-slope equation: gimbal-rate maps, specific force, Earth rate and the mode.

    Attributes
    ----------
    rate_map : ndarray (P, 3, 3)
        ``J(α)``: platform rate [rad/s] per unit rate of each gimbal (columns platform, inner, middle).
    specific_force : ndarray (P, 3)
        ``f^p`` of each dwell [m/s²].
    locked : ndarray (P,) of bool
        Dwells near gimbal lock (``cond J >`` :data:`MAX_CONDITION`).
    mode : DwellMode
        How the platform was held during the dwells (docs/conventions.md, "The platform during a dwell").
    earth_rate : ndarray (P, 3)
        ``ω_ie^p`` of each dwell [rad/s].
    nuisance : tuple of (str, ndarray (P, 3))
        The mode's nuisance parameters and their reading-rate columns: the torquers' scale-factor errors
        ``torquer_scale_x/y/z`` (torqued at the Earth rate), or the attitude errors the Earth rate reveals
        (inertially held: ``theta10``, ``theta20``, ``theta30`` [rad] and the base azimuth ``azimuth_error`` [rad]).
    """

    rate_map: NDArray[np.float64]
    specific_force: NDArray[np.float64]
    locked: NDArray[np.bool_]
    mode: DwellMode = DEFAULT_DWELL_MODE
    earth_rate: NDArray[np.float64] | None = None
    nuisance: tuple[tuple[str, NDArray[np.float64]], ...] = ()

    @classmethod
    def of(
        cls,
        readings: ArrayLike,
        gravity: float,
        *,
        zero_offsets: ArrayLike = (0.0, 0.0, 0.0),
        base_attitude: ArrayLike = (0.0, 0.0, 0.0),
        configuration: GimbalConfiguration | None = None,
        latitude: float,
        mode: DwellMode = DEFAULT_DWELL_MODE,
    ) -> SlopeGeometry:
        """From the dwells' mean readings (P, 3) [rad], the zero offsets ``θ10, θ20, θ30``, the site and the dwell mode.

        ``latitude`` [rad] gives the Earth rate ``ω_ie^n`` of the mode's expectation (:func:`earth_rate_nav`).
        """
        offsets = np.asarray(zero_offsets, dtype=float)
        base = np.asarray(base_attitude, dtype=float)
        config = configuration or DEFAULT_GIMBALS
        r = np.asarray(readings, dtype=float)

        def earth_rates(offsets: NDArray[np.float64], base: NDArray[np.float64]) -> tuple[NDArray, NDArray, NDArray]:
            platform = GimbalPlatform(
                zero_offsets=(offsets[0], offsets[1], offsets[2]), configuration=config, base_attitude=(base[0], base[1], base[2])
            )
            rate_map = platform.rate_map(platform.actual_angles(r))
            omega = np.einsum("pij,j->pi", platform.dcm_nav_to_platform(r), earth_rate_nav(latitude))
            return rate_map, omega, platform.near_gimbal_lock(platform.actual_angles(r))

        rate_map, omega, locked = earth_rates(offsets, base)
        f_p = platform_specific_force(r, gravity, zero_offsets=offsets, base_attitude=base, configuration=config)
        safe = np.where(locked[:, None, None], np.eye(3), rate_map)

        def readings_rate(platform_rate: NDArray[np.float64], maps: NDArray[np.float64] = safe) -> NDArray[np.float64]:
            return np.where(locked[:, None], 0.0, np.linalg.solve(maps, platform_rate[..., None])[..., 0])

        nuisance: list[tuple[str, NDArray[np.float64]]] = []
        if mode is DwellMode.EARTH_RATE:
            for k, axis in enumerate(AXES):
                nuisance.append((f"torquer_scale_{axis}", readings_rate(np.eye(3)[k] * omega)))
        elif mode is DwellMode.INERTIAL:
            # the Earth-rate slope -J⁻¹ ω_ie^p depends on the attitude: its derivative in each offset and the azimuth
            step = 1e-6
            for name, change in (
                ("theta10", (0, step)), ("theta20", (1, step)), ("theta30", (2, step)), ("azimuth_error", (3, step)),
            ):  # fmt: skip
                index, h = change
                moved_offsets, moved_base = offsets.copy(), base.copy()
                if index < 3:
                    moved_offsets[index] += h
                else:
                    moved_base[0] += h  # yaw of the base: the azimuth
                maps, moved, _ = earth_rates(moved_offsets, moved_base)
                maps = np.where(locked[:, None, None], np.eye(3), maps)
                nuisance.append((name, (readings_rate(-moved, maps) - readings_rate(-omega)) / h))
        return cls(rate_map, f_p, locked, mode, omega, tuple(nuisance))

    def column(self, term_id: str) -> NDArray[np.float64]:
        """Return the reading rates (P, 3) [rad/s] per unit of ``gyro_drift_a`` or ``Dg_ab`` [SI] (module docstring)."""
        drift, sensitivity = np.zeros(3), np.zeros((3, 3))
        axis = term_id.removeprefix("gyro_drift_").removeprefix("Dg_")
        if term_id.startswith("gyro_drift_") and axis in AXES:
            drift[AXES.index(axis)] = 1.0
        elif term_id.startswith("Dg_") and len(axis) == 2 and set(axis) <= set(AXES):
            sensitivity[AXES.index(axis[0]), AXES.index(axis[1])] = 1.0
        else:
            raise ValueError(f"{term_id!r} is not a gyro drift or g-sensitivity id")
        omega = platform_drift_rate(drift, sensitivity, self.specific_force)
        safe = np.where(self.locked[:, None, None], np.eye(3), self.rate_map)
        return np.where(self.locked[:, None], 0.0, np.linalg.solve(safe, omega[..., None])[..., 0])


@dataclass(frozen=True, eq=False)
class GyroSensitivityDetails(StageDetails):
    """What the gyro-sensitivity stage worked with, beyond the twelve numbers.

    Attributes
    ----------
    angle_noise : tuple of float
        Measured white angle noise per gimbal (platform, inner, middle) [rad, 1σ per sample].
    dwells_used : tuple of str
        Labels of the dwells whose slopes entered.
    left_out : tuple of str
        Dwells left out and why (near gimbal lock, constant readings).
    rank_report : tuple of str
        What the dwells determine and what they do not.
    chi2 : float
        ``Σ (r/σ)²`` of the slope residuals.
    dof : int
        Slopes minus parameters.
    statistic : float
        ``W`` of the ``D_g = 0`` test (NaN without g-sensitivities).
    p_value : float
        Its p-value (χ² with :attr:`test_dof` degrees of freedom).
    test_dof : int
        Number of g-sensitivities tested.
    alpha : float
        The test's false-alarm level.
    mode : DwellMode
        How the platform was held during the dwells (what the slopes' expectation assumes).
    nuisance : tuple of (str, float, float)
        The mode's nuisance parameters, estimated with the twelve and marginalized out of their covariance:
        ``(id, value, 1σ)`` in SI (``torquer_scale_*`` dimensionless, the attitude errors in rad).
    chi2_warning : str or None
        The goodness-of-fit warning (χ² beyond its 99.9 % quantile; the accelerometer stages' rule and wording,
        :func:`stableins.estimators.gauss_newton.goodness_of_fit_warning`), None when the fit is within it.
    gauge : str
        The frame the numbers are in (the device gauge ``θ10 = 0``; module docstring).
    """

    angle_noise: tuple[float, float, float]
    dwells_used: tuple[str, ...]
    left_out: tuple[str, ...]
    rank_report: tuple[str, ...]
    chi2: float
    dof: int
    statistic: float
    p_value: float
    test_dof: int
    alpha: float
    mode: DwellMode = DEFAULT_DWELL_MODE
    nuisance: tuple[tuple[str, float, float], ...] = ()
    chi2_warning: str | None = None
    gauge: str = ""

    @property
    def flagged(self) -> bool:
        """Whether the data show a g-sensitivity (``D_g = 0`` rejected at :attr:`alpha`)."""
        return bool(self.p_value < self.alpha)


def estimate_gyro_sensitivity(
    slopes: ReadingSlopes,
    geometry: SlopeGeometry,
    *,
    labels: Sequence[str] | None = None,
    terms: Sequence[Term] = GYRO_TERMS,
    alpha: float = FLAG_ALPHA,
) -> FitResult:
    """Estimate ``gyro_drift_*`` and ``Dg_ab`` from the reading slopes (module docstring).

    Parameters
    ----------
    slopes : ReadingSlopes
        The lines through the readings of each dwell.
    geometry : SlopeGeometry
        The dwells' gimbal-rate maps and specific force (same order).
    labels : sequence of str, optional
        Dwell labels for the report (default ``"dwell k"``).
    terms : sequence of Term
        The parameters to estimate (default all twelve, :data:`GYRO_TERMS`; a subset, e.g. the three drifts and
        one ``Dg_ab``, is what ``stableins diagnose --add Dg_xz`` carries).
    alpha : float
        False-alarm level of the ``D_g = 0`` flag.

    Returns
    -------
    FitResult
        Stage ``"gyro"``: the parameters with covariance from the measured angle noise, the slope residuals,
        a :class:`~stableins.estimators.result.Likelihood` for the record's Bayesian update and
        :class:`GyroSensitivityDetails`.  Raises ``ValueError`` when too few dwells have usable slopes.
    """
    n_dwells = slopes.slope.shape[0]
    names = list(labels) if labels is not None else [f"dwell {k + 1}" for k in range(n_dwells)]
    if geometry.mode is DwellMode.CAGED:
        raise ValueError(
            "the platform was caged to the base by its angle loops during the dwells (dwell_mode caged): the readings "
            "carry no gyro information"
        )
    unweighable = ~np.all(slopes.distinct & np.isfinite(slopes.slope), axis=1) | ~(slopes.sxx > 0)
    keep = ~geometry.locked & ~unweighable
    left_out = tuple(
        f"{lbl} ({'near gimbal lock' if lock else 'readings constant within the dwell: the slope cannot be weighed'})"
        for lbl, lock, bad in zip(names, geometry.locked, unweighable, strict=True)
        if lock or bad
    )
    ids = [t.id for t in terms]
    nuisance_ids = [name for name, _ in geometry.nuisance]
    n_all = len(ids) + len(nuisance_ids)
    if 3 * int(keep.sum()) <= n_all:
        raise ValueError(f"only {int(keep.sum())} dwell(s) with usable reading slopes: too few for {n_all} parameters")
    noise = slopes.angle_noise(keep)
    sigma = noise[None, :] / np.sqrt(slopes.sxx[keep])[:, None]
    y = (slopes.slope[keep] / sigma).ravel()
    columns = [geometry.column(i)[keep] for i in ids] + [column[keep] for _, column in geometry.nuisance]
    design = np.stack([(c / sigma).ravel() for c in columns], axis=1)
    scale = np.linalg.norm(design, axis=0)
    scale[scale == 0] = 1.0
    u, s, vt = np.linalg.svd(design / scale, full_matrices=False)
    rank = int(np.sum(s > s[0] * RANK_RTOL))
    inverse = vt[:rank].T / s[:rank]
    x_all = inverse @ (u[:, :rank].T @ y) / scale
    covariance_all = (inverse @ inverse.T) / np.outer(scale, scale)
    residual = y - design @ x_all
    null_all = vt[rank:].T
    n = len(ids)
    x, covariance = x_all[:n], covariance_all[:n, :n]  # the nuisances marginalized out (a Gaussian's marginal)
    null = _null_of_subset(null_all[:n])
    statistic, p_value, test_dof = _flag_test(x, covariance, ids, null)
    chi2, dof = float(residual @ residual), int(residual.size - rank)
    residual_labels = tuple(f"{lbl} d{g}/dt" for lbl, k in zip(names, keep, strict=True) if k for g in GIMBAL_NAMES)
    warning = goodness_of_fit_warning(chi2, dof, residual, residual_labels)
    gauge = gauge_statement(geometry.mode)
    determined = [np.linalg.norm(null_all[k]) < 1e-6 for k in range(n_all)]
    nuisance = tuple(
        (name, float(x_all[n + j]), float(np.sqrt(covariance_all[n + j, n + j])) if determined[n + j] else float("nan"))
        for j, name in enumerate(nuisance_ids)
    )
    details = GyroSensitivityDetails(
        angle_noise=(float(noise[0]), float(noise[1]), float(noise[2])),
        dwells_used=tuple(n for n, k in zip(names, keep, strict=True) if k),
        left_out=left_out,
        rank_report=gyro_rank_report(ids, null, int(keep.sum()), mode=geometry.mode, nuisance=nuisance_ids),
        chi2=chi2,
        dof=dof,
        statistic=statistic,
        p_value=p_value,
        test_dof=test_dof,
        alpha=alpha,
        mode=geometry.mode,
        nuisance=nuisance,
        chi2_warning=warning,
        gauge=gauge,
    )
    status = tuple(Status.ESTIMATED if determined[k] else Status.UNIDENTIFIABLE for k in range(n))
    information = _marginal_information(design / scale, scale, n)
    residual_sigma = np.broadcast_to(sigma, (int(keep.sum()), 3)).ravel()
    notes = details.rank_report + ((f"{len(left_out)} dwell(s) left out: " + "; ".join(left_out),) if left_out else ())
    return FitResult(
        stage=Stage.GYRO,
        terms=tuple(terms),
        values=x,
        covariance=covariance,
        status=status,
        residuals=residual * residual_sigma,
        residual_sigma=residual_sigma.copy(),
        residual_labels=residual_labels,
        rank=rank,  # of the whole design, nuisances included (as the drift test's): ν = slopes − rank everywhere
        singular_values=s,
        null_space=null,
        notes=(gauge,) + notes + ((warning,) if warning is not None else ()),
        likelihood=Likelihood(tuple(ids), x, information, np.zeros(len(ids))),
        settings=GyroSettings(SLOPE_SKIP, alpha, tuple(ids), geometry.mode, tuple(nuisance_ids)),
        details=details,
    )


@dataclass(frozen=True)
class GyroSettings:
    """The settings of a gyro run.

    The slope skip [fraction of a dwell], α of its flags, the parameters and nuisances it fitted and how the platform
    was held; its noise is the white angle noise per gimbal, pooled (the one model it has).
    """

    skip: float
    alpha: float
    parameters: tuple[str, ...]
    dwell_mode: DwellMode
    nuisance: tuple[str, ...]

    #: The noise model the stage's σ rest on, as its settings state it.
    NOISE = "white angle noise per gimbal, pooled"

    def to_document(self) -> JSONObject:
        """Return ``{"skip", "alpha", "parameters", "noise", "dwell_mode", "nuisance"}`` (docs/formats.md)."""
        return {"skip": self.skip, "alpha": self.alpha, "parameters": list(self.parameters), "noise": self.NOISE,
                "dwell_mode": self.dwell_mode.value, "nuisance": list(self.nuisance)}  # fmt: skip

    @classmethod
    def from_document(cls, fields: DocumentFields) -> GyroSettings:
        """Return the settings :meth:`to_document` wrote (:class:`InputError` naming the field)."""
        mode = fields.text("dwell_mode")
        if mode not in {m.value for m in DwellMode}:
            raise fields.fail("dwell_mode", f"{mode!r} is not a dwell mode", ", ".join(m.value for m in DwellMode))
        nuisance = fields.texts("nuisance")
        return cls(fields.number("skip"), fields.number("alpha"), fields.texts("parameters"), DwellMode(mode), nuisance)


def gauge_statement(mode: DwellMode) -> str:
    """Return the sentence that says which frame the gyro numbers are in and how the platform was held."""
    held = {
        DwellMode.EARTH_RATE: "torqued at the computed Earth rate (torquer scale factors estimated as nuisances)",
        DwellMode.INERTIAL: "inertially held (the Earth rate subtracted; the offsets and the base azimuth estimated as nuisances)",
        DwellMode.CAGED: "caged",
    }[mode]
    return (
        f"gauge: the platform frame of the device gauge θ10 = 0 (x_p, y_p as the platform-gimbal reading 0 puts them, "
        f"z_p the platform axis): with a true θ10 the x and y indices of ε^p and D_g belong to p turned by θ10 about "
        f"z_p; dwells {held}"
    )


def _null_of_subset(rows: NDArray[np.float64]) -> NDArray[np.float64]:
    """Orthonormal basis (n, k) of the null directions' projection on the first ``n`` parameters (empty when none)."""
    if rows.shape[1] == 0:
        return np.zeros((rows.shape[0], 0))
    u, s, _ = np.linalg.svd(rows, full_matrices=False)
    return np.asarray(u[:, s > 1e-6], dtype=np.float64)


def _marginal_information(scaled: NDArray[np.float64], scale: NDArray[np.float64], n: int) -> NDArray[np.float64]:
    """Return the information on the first ``n`` parameters with the others marginalized (Schur complement of ``AᵀA``)."""
    full = scaled.T @ scaled * np.outer(scale, scale)
    if full.shape[0] == n:
        return np.asarray(full, dtype=np.float64)
    a, b, c = full[:n, :n], full[:n, n:], full[n:, n:]
    return np.asarray(a - b @ np.linalg.pinv(c, hermitian=True) @ b.T, dtype=np.float64)


def _flag_test(
    x: NDArray[np.float64], covariance: NDArray[np.float64], ids: Sequence[str], null: NDArray[np.float64]
) -> tuple[float, float, int]:
    """``(W, p, dof)`` of the ``D_g = 0`` test over the determined g-sensitivities (NaN, NaN, 0 without any)."""
    tested = [k for k, i in enumerate(ids) if i.startswith("Dg_") and np.linalg.norm(null[k]) < 1e-6]
    if not tested:
        return float("nan"), float("nan"), 0
    block = covariance[np.ix_(tested, tested)]
    statistic = float(x[tested] @ np.linalg.solve(block, x[tested]))
    return statistic, chi2_sf(statistic, len(tested)), len(tested)


def gyro_rank_report(
    ids: Sequence[str], null: NDArray[np.float64], dwells: int, *, mode: DwellMode = DEFAULT_DWELL_MODE, nuisance: Sequence[str] = ()
) -> tuple[str, ...]:
    """Return the rank report: how many of the parameters the dwells determine, the free combinations, what no dwell shows."""
    determined = int(sum(np.linalg.norm(null[k]) < 1e-6 for k in range(len(ids))))
    lines = [f"{dwells} dwells, 3 reading slopes each: {determined} of {len(ids)} gyro numbers determined"]
    for k in range(null.shape[1]):
        v = null[:, k] / np.abs(null[:, k]).max()
        combo = " ".join(f"{c:+.2f}·{i}" for c, i in zip(v, ids, strict=True) if abs(c) > 1e-3)
        lines.append(f"not observable (the dwells' (1, f^p) do not span R⁴, or a nuisance takes it): {combo}; reported unidentifiable")
    if nuisance:
        lines.append(
            f"nuisance parameters of the dwell mode {mode}, estimated with them and marginalized (the design's rank and ν count "
            f"them): {', '.join(nuisance)}"
        )
    scale_factors = {
        DwellMode.EARTH_RATE: "their scale factors beyond the torquers' (the platform is torqued only at the Earth rate)",
        DwellMode.INERTIAL: "their scale factors (the platform is not torqued within a dwell)",
        DwellMode.CAGED: "anything (the angle loops hold the platform)",
    }[mode]
    lines.append(f"not visible at device level: the gyros' mounting in the platform (p is defined by the gimbals) and {scale_factors}")
    return tuple(lines)


def gyro_from_datasets(
    datasets: Sequence[Any],
    *,
    layouts: Mapping[str, Any],
    zero_offsets: ArrayLike,
    terms: Sequence[Term] = GYRO_TERMS,
    alpha: float = FLAG_ALPHA,
    summaries: Sequence[Sequence[Any]] | None = None,
) -> FitResult:
    """:func:`estimate_gyro_sensitivity` on the usable dwells of device-level data files (coarse and fine alike).

    Parameters
    ----------
    datasets : sequence of DeviceDataset
        :func:`stableins.data.device.load_device` results of one unit and site.
    layouts : mapping of str to StageLayout
        Each stage's positions, settle times and dwell checks (the samples before the settle time are dropped,
        and dwells the device stages leave out are left out here too).
    zero_offsets : array_like (3,)
        ``θ10, θ20, θ30`` of the calibration, for the actual angles.
    terms, alpha
        As :func:`estimate_gyro_sensitivity`.
    summaries : sequence of sequences of DwellSummary, optional
        Each dataset's dwell summaries, :func:`stableins.estimators.dwell.dwells_from_columns` with these ``layouts``
        (``calibrate device`` has them already: each file is summarized once); made here when not given.
    """
    from stableins.estimators.dwell import dwells_from_columns
    from stableins.estimators.setting import DeviceSetting

    site = datasets[0].metadata
    pieces, labels = [], []
    for i, ds in enumerate(datasets):
        found = (
            dwells_from_columns(ds.columns, layouts=layouts, source=str(ds.path), setting=DeviceSetting.from_site(ds.metadata))
            if summaries is None
            else summaries[i]
        )
        usable = {(s.stage, s.pass_number, s.position) for s in found if s.usable}
        for d in ds.dwells():
            if (d.stage, d.pass_number, d.position) not in usable:
                continue
            layout = layouts.get(d.stage)
            settle = layout.settle(d.position) if layout is not None and d.position in layout.positions else 0.0
            use = np.asarray(d.time_since_command) >= settle
            if int(use.sum()) < 6:
                continue
            pieces.append((np.asarray(d.time)[use], np.asarray(d.angles)[use]))
            labels.append(f"{d.stage} pass {d.pass_number} position {d.position}")
    if not pieces:
        raise ValueError("no usable dwells with readings")
    modes = sorted({str(ds.metadata.dwell_mode) for ds in datasets})
    if len(modes) > 1:
        raise ValueError(f"the data files declare different dwell modes ({', '.join(modes)}): run the gyro stage on one mode")
    mode = site.dwell_mode
    s1, s2, s3, s4 = site.gimbal_senses
    configuration = GimbalConfiguration((s1, s2, s3, s4))
    if mode is DwellMode.INERTIAL:
        platform = GimbalPlatform(
            zero_offsets=tuple(np.asarray(zero_offsets, dtype=float)), configuration=configuration, base_attitude=site.base_attitude
        )
        removed = [remove_earth_turn(t, a, platform, earth_rate_nav(site.latitude)) for t, a in pieces]
        pieces = [(t, a) for (t, _), (a, _) in zip(pieces, removed, strict=True)]
    slopes = ReadingSlopes.of(pieces)
    # the geometry where each line's slope is the reading rate: the centre of the samples fitted (ReadingSlopes.centre);
    # a 0.05 °/h drift moves the readings 7″ between the dwell's mean and that centre in a 600-s dwell, a 4e-5 relative
    # change of J, 0.1–0.5σ of such a dwell's slope
    geometry = SlopeGeometry.of(
        slopes.centre, site.gravity, zero_offsets=zero_offsets, base_attitude=site.base_attitude,
        configuration=configuration, mode=mode, latitude=site.latitude,
    )  # fmt: skip
    return estimate_gyro_sensitivity(slopes, geometry, labels=labels, terms=terms, alpha=alpha)


def remove_earth_turn(
    time: ArrayLike,
    angles: ArrayLike,
    platform: GimbalPlatform,
    earth_rate: ArrayLike,
    *,
    skip: float = SLOPE_SKIP,
    iterations: int = 3,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    r"""Return the readings of an inertially held dwell less the Earth's turn, and the readings at its centre.

    An inertially held platform turns relative to the base exactly as ``C_n^p(t) = C_n^p(t_c) exp((t − t_c)[ω_ie^n×])``
    without gyro errors (docs/conventions.md, "The platform during a dwell"): 15 °/h, 2.5° in a 600-s dwell, so the
    readings are not a line (their curvature is ~10″ over 300 s).  The exact path through the centre reading
    ``r_c`` (at ``t_c``, the mean time of the part :func:`reading_slope` fits) is computed by inverse kinematics and
    subtracted; what stays is the gyro errors' turn, a line.  ``r_c`` is the mean of what stays (a line's mean is its
    value at ``t_c``), iterated.  The attitude this uses (offsets, base) errs: the gyro stage estimates the errors as
    nuisances (:class:`SlopeGeometry`).
    """
    t = np.asarray(time, dtype=float)
    a = np.asarray(angles, dtype=float).reshape(t.size, 3)
    used = t >= t[0] + skip * (t[-1] - t[0])
    t_c = float(t[used].mean())
    centre = a[used].mean(axis=0)
    remainder = a
    for _ in range(iterations):
        start = platform.dcm_nav_to_platform(centre)
        turned = start @ rotation_about(-(t - t_c)[:, None] * np.asarray(earth_rate, dtype=float))
        path = platform.readings_from_dcm_nav_to_platform(turned, np.broadcast_to(centre, (t.size, 3)))
        remainder = a - (path - centre)
        centre = remainder[used].mean(axis=0)
    return remainder, centre


def gyro_report(result: FitResult) -> str:
    """Text report: drifts in °/h, g-sensitivities in °/h/g with σ and z, the ``D_g = 0`` test, the noise and rank."""
    details = result.details
    assert isinstance(details, GyroSensitivityDetails)
    lines = [f"gyro drift and g-sensitivity from the reading slopes within dwells (platform frame; dwell mode {details.mode}):"]
    for term, value, sig, status in zip(result.terms, result.values, result.sigma, result.status, strict=True):
        unit, scale = ("°/h", DEG_PER_HOUR) if term.id.startswith("gyro_drift_") else ("°/h/g", DEG_PER_HOUR_PER_G)
        if status is Status.UNIDENTIFIABLE:
            lines.append(f"  {term.id:<13} unidentifiable")
            continue
        lines.append(f"  {term.id:<13} {value / scale:+.6f} ± {sig / scale:.6f} {unit:<6} z = {value / sig:+.1f}")
    if details.test_dof:
        verdict = "FLAGGED: the gyros are g-sensitive" if details.flagged else "not flagged"
        lines.append(
            f"D_g = 0 test: W = {details.statistic:.1f} on {details.test_dof} dof, p = {details.p_value:.3g} "
            f"(flag below α = {details.alpha:g}): {verdict}"
        )
    for name, value, sig in details.nuisance:
        unit, scale = ("ppm", 1e-6) if name.startswith("torquer_scale_") else ("arcsec", ARCSEC)
        lines.append(f"  nuisance {name:<15} {value / scale:+.3f} ± {sig / scale:.3f} {unit}")
    noise = ", ".join(f"{n / ARCSEC:.3f}" for n in details.angle_noise)
    lines.append(f"angle noise measured within the dwells (platform, inner, middle): {noise} arcsec per sample")
    lines.append(f"χ²_ν of the slopes = {details.chi2 / max(details.dof, 1):.2f} (ν = {details.dof})")
    if details.chi2_warning is not None:
        lines.append(details.chi2_warning)
    lines.append(details.gauge)
    lines += [f"  {line}" for line in details.rank_report]
    lines += [f"  {line}" for line in details.left_out]
    return "\n".join(lines)


__all__ = [
    "FLAG_ALPHA",
    "GYRO_TERMS",
    "MAX_CONDITION",
    "SLOPE_SKIP",
    "GyroSensitivityDetails",
    "ReadingSlopes",
    "SlopeGeometry",
    "estimate_gyro_sensitivity",
    "gyro_from_datasets",
    "gauge_statement",
    "gyro_rank_report",
    "reading_slope",
    "remove_earth_turn",
    "gyro_report",
]
