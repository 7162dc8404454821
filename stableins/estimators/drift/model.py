r"""Gyro drift of a space-stable platform from an indexing test (Zhang et al. 2023's two-position idea, re-derived).

Observation equations (derived here; the extracted paper has no method section and lost its signs)
---------------------------------------------------------------------------------------------------
The platform is held in inertial space by its gyros; a gyro drift ``ε^p`` (gyro output error, constant in
the platform frame) makes the stabilization loop turn the platform at ``−ε^p``.  From the angle-sensor
readings, the installed zero offsets and the surveyed base attitude the estimator forms the platform's
attitude relative to the inertial frame (the local frame at ``t = 0``)

.. math::
    \hat M(t) = \hat C_b^p(r(t))\, C_n^{b,s}\, E(t)^T, \qquad E(t) = C_{n(t)}^{n_0} = \exp(\Omega t\,[u\times]),

``u = ω_ie^n/Ω`` (NED ``(cos L, 0, −sin L)``).  Two things make ``\hat M`` move while the platform holds:

* **the drift**: ``M(t) M(t_0)^T = \mathrm{rot}(-\varepsilon^p (t - t_0))`` (frame rotation by ``−εΔt``,
  ``\mathrm{rot}(θ) = I − [θ×] + …``);
* **the base error** ``δ = (t_N, t_E, ψ_e)`` (the true base is the surveyed one turned by ``δ``,
  ``C_n^b = C_n^{b,s}(I − [δ×])``): ``\hat M = (I + [(C_n^p δ)×]) M``, a rotation by ``−C_n^p(t) δ`` that
  follows the Earth's turn, i.e. the Earth rate misprojected by ``Ω u × δ``.

So for the rotation vector ``φ(t)`` of ``\hat M(t) \hat M(t_k)^T`` in hold ``k`` (reference sample ``t_k``):

.. math::
    φ(t) = c_k - \varepsilon^p (t - t_k) - C_n^p(t)\,δ \;[+\; D_{g,z} f_z (t - t_k)\, e_z],

with a free constant ``c_k`` per hold (it absorbs the zero-offset residuals, the non-orthogonality and
``C_n^p(t_k) δ``).  Checked against the independent world (:mod:`stableins.simulator.indexing`) in
``tests/test_drift.py``.

What the data determine (the rank report)
-----------------------------------------
* ``δ`` along ``u`` is a rotation of the base about the Earth's axis: it commutes with ``E(t)`` and only
  shifts ``c_k``.  **Never observable**; gauge: held at the survey (``u·δ = 0``).
* The rest, ``δ_⊥`` (``t_E`` and ``t_N sin L + ψ_e cos L``), misprojects ``Ω u × δ`` — a constant vector
  in inertial space, perpendicular to the Earth's axis.  In one position it is a rate in the platform's
  equatorial plane, indistinguishable from ``ε_x, ε_y`` within the Earth's few degrees of turn: a single
  hold cannot tell them apart, so ``δ`` is held at the survey and ``ε_x, ε_y`` carry ``Ω |u × δ|``
  (5″ of azimuth: ``Ω cos L · 5″ = 2.8e-4 °/h`` at 40°).  An index of 180° about ``z_p`` (the polar axis of
  a polar-aligned platform) reverses that misprojection in the platform frame and leaves ``ε^p`` alone:
  both are determined.  The rule is numeric: ``δ_⊥`` is fitted when that inflates no drift σ more than
  :data:`SEPARATION_LIMIT` times, else held at the survey and the rank report says so.
* ``ε_z`` (the polar axis) sees no misprojection (``u × δ ⊥ u``) and is determined in any position, except
  from a drift proportional to ``f_z`` (a g-sensitive gyro, ``D_{g,z}``): ``f_z = g sin L`` in both
  positions of an index about ``z_p``.  A flip of ``z_p`` (``drift-three-position``: 180° about the middle
  gimbal) reverses ``f_z`` and separates them; the fit then carries ``D_{g,z}`` as a nuisance.
* A g-sensitive drift of the equatorial gyros rotates with ``f^p`` like a base tilt about East: the ``δ_⊥``
  nuisance absorbs it and ``ε_x, ε_y`` stay free of it.

The accelerometer biases are a cross-check, not an update: the mean compensated output of each hold minus
the specific force predicted from the readings and the fitted base, averaged over holds whose specific
force reverses on that axis (so scale-factor and misalignment residuals and the gauge cancel), compared
with the record (``z`` of the difference).  Without a reversal on an axis it says what the mean includes.

Noise: white angle noise; the σ per rotation-vector component is measured from the fit's residuals.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from stableins.conventions import (
    ARCSEC,
    DEG_PER_HOUR,
    EARTH_RATE,
    GimbalConfiguration,
    dcm_body_to_platform,
    dcm_nav_to_body,
    earth_rate_nav,
    skew,
)
from stableins.documents import DocumentFields, JSONObject
from stableins.errormodel import GIMBAL_IDS, GYRO_DRIFT_TERMS, ErrorModel
from stableins.errors import InputError
from stableins.estimators.details import StageDetails
from stableins.estimators.drift.accelerometer import BiasCheck, BiasInputs, bias_checks
from stableins.estimators.drift.holds import MIN_HOLD, StillHold, find_holds, small_angle_vector
from stableins.estimators.result import FitResult, Likelihood, Stage
from stableins.platform import GimbalPlatform
from stableins.site import SiteMetadata
from stableins.status import Status

#: Largest factor by which fitting the base error may inflate a drift σ and still count as separated.
SEPARATION_LIMIT = 10.0
#: Prior 1σ of the platform angle sensor's once-per-revolution error terms [rad] (the effect's nominal 2″;
#: the record carries no angle-sensor errors).
ANGLE_SENSOR_PRIOR = 2.0 * ARCSEC


@dataclass(frozen=True, eq=False)
class DriftDetails(StageDetails):
    """What the drift test worked with, beyond the drift.

    Attributes
    ----------
    holds : tuple of StillHold
    nuisance : mapping of str to (float, float)
        Fitted nuisances, value and 1σ [SI]: ``tilt_east``, ``tilt_north_sin_azimuth_cos`` (rad),
        ``Dg_zz`` (rad s/m), when determined.
    rank : tuple of str
        The rank report: what is determined, what is held and why.
    biases : tuple of BiasCheck
    residual_rms : tuple of float
        Rms of the rotation-vector residuals per platform axis [rad].
    base_separated : bool
        Whether the base error was fitted (an index reversed its misprojection).
    """

    holds: tuple[StillHold, ...]
    nuisance: Mapping[str, tuple[float, float]]
    rank: tuple[str, ...]
    biases: tuple[BiasCheck, ...]
    residual_rms: tuple[float, float, float]
    base_separated: bool


@dataclass(frozen=True)
class DriftSettings:
    """The settings of a gyro-drift run: how the base was treated, the holds used and the nuisances fitted."""

    #: ``"auto"`` (the base error fitted when the holds separate it) or ``"survey"`` (held at the survey).
    base: str
    holds: int
    nuisances: tuple[str, ...]

    def to_document(self) -> JSONObject:
        """Return ``{"base", "holds", "nuisances"}`` (docs/formats.md)."""
        return {"base": self.base, "holds": self.holds, "nuisances": list(self.nuisances)}

    @classmethod
    def from_document(cls, fields: DocumentFields) -> DriftSettings:
        """Return the settings :meth:`to_document` wrote (:class:`InputError` naming the field)."""
        return cls(fields.text("base"), fields.count("holds"), fields.texts("nuisances"))


def _inertial_attitude(
    time: NDArray[np.float64], actual: NDArray[np.float64], *, site: SiteMetadata, configuration: GimbalConfiguration
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``(M̂, Ĉ_n^p)`` from the actual angles (readings + installed offsets): platform to the inertial and to the local frame."""
    body_to_platform = dcm_body_to_platform(actual[:, 0], actual[:, 1], actual[:, 2], 0.0, configuration)
    nav_to_platform = body_to_platform @ dcm_nav_to_body(*site.base_attitude)
    k = skew(earth_rate_nav(site.latitude) / EARTH_RATE)
    theta = EARTH_RATE * time
    earth = np.eye(3) + np.sin(theta)[:, None, None] * k + (1.0 - np.cos(theta))[:, None, None] * (k @ k)
    return nav_to_platform @ earth.swapaxes(1, 2), nav_to_platform


def _triple(values: NDArray[np.float64]) -> tuple[float, float, float]:
    return (float(values[0]), float(values[1]), float(values[2]))


def _base_basis(latitude: float) -> NDArray[np.float64]:
    """Return the orthonormal basis (3, 2) of base rotations ``δ`` (NED) perpendicular to the Earth's axis.

    Its columns are ``t_E`` and ``t_N sin L + ψ_e cos L``.
    """
    return np.array([[0.0, math.sin(latitude)], [1.0, 0.0], [0.0, math.cos(latitude)]])


def estimate_drift(
    columns: Mapping[str, NDArray[np.float64]],
    site: SiteMetadata,
    *,
    prior_values: Mapping[str, float],
    prior_covariance: tuple[Sequence[str], NDArray[np.float64]] | None = None,
    error_model: ErrorModel | None = None,
    holds: Sequence[tuple[int, int]] | None = None,
    base: str = "auto",
    source: str = "record",
) -> FitResult:
    """Estimate ``ε^p`` from the readings of an indexing test (module docstring).

    Parameters
    ----------
    columns : mapping
        ``time``, ``angle_platform``, ``angle_inner``, ``angle_middle`` and (for the bias cross-check)
        ``f_x``, ``f_y``, ``f_z``, ``temperature`` of a system-level record (SI).
    site : SiteMetadata
        Latitude, gravity, surveyed base attitude (yaw, pitch, roll), gimbal senses, reference temperature.
    prior_values : mapping
        The installed calibration (the record): zero offsets ``theta10..30`` and the accelerometer model.
    prior_covariance : (ids, ndarray), optional
        Covariance of the record's parameters (the bias cross-check's expected spread).
    error_model : ErrorModel, optional
        The record's error model (default: the standard one).
    holds : sequence of (int, int), optional
        Sample ranges of the holds (default: :func:`find_holds`).
    base : {"auto", "survey"}
        ``"auto"``: fit ``δ_⊥`` when the holds separate it; ``"survey"``: hold the base at the survey
        (the one-position estimate, for comparison).
    source : str
        Names the data in messages.

    Returns
    -------
    FitResult
        Stage ``"drift"``: ``gyro_drift_x/y/z`` with covariance and a likelihood for the record's
        Bayesian update; :class:`DriftDetails` in ``details``.
    """
    latitude, gravity = site.latitude, site.gravity
    s1, s2, s3, s4 = site.gimbal_senses
    configuration = GimbalConfiguration((s1, s2, s3, s4))
    time = np.asarray(columns["time"], dtype=float)
    readings = np.stack([np.asarray(columns[f"angle_{g}"], dtype=float) for g in ("platform", "inner", "middle")], axis=1)
    if holds is None:
        holds = find_holds(time, readings)
    if not holds:
        raise InputError(
            f"{source}: no hold of at least {MIN_HOLD:g} s with the platform still", field="angle_platform",
            expected="a drift test record (stableins run drift-two-position)",
        )  # fmt: skip
    offsets = [float(prior_values.get(g, 0.0)) for g in GIMBAL_IDS]
    inertial, nav_to_platform = _inertial_attitude(
        time, readings + np.asarray(offsets, dtype=float), site=site, configuration=configuration
    )
    f_model = -gravity * nav_to_platform[:, :, 2]
    hold_list = [StillHold(a, b, float(time[a]), float(time[b - 1]), _triple(f_model[a:b].mean(axis=0))) for a, b in holds]
    y, design, names = _design(time, readings + np.asarray(offsets, dtype=float), inertial, nav_to_platform, hold_list,
                               latitude=latitude, gravity=gravity, configuration=configuration)  # fmt: skip
    drift_names = ["eps_x", "eps_y", "eps_z"]
    used = [n for n in names if n.startswith(("c", "eps_", "ang1_")) or n in ("Dg_zz", "theta20_residual")]
    members = ["tilt_east", "tilt_north_sin_azimuth_cos"]
    chosen = {
        "base": base != "survey" and len(hold_list) > 1 and _separable(design, y, names, used=used, members=members, drift=drift_names)
    }
    if chosen["base"]:
        used = used + members
    cov, x, sigma_axis, residual = _covariance(design, y, [names.index(n) for n in used], _priors(used))
    d_idx = [used.index(n) for n in drift_names]
    eps, cov_eps = x[d_idx], cov[np.ix_(d_idx, d_idx)]
    nuisance = {n: (float(x[k]), float(math.sqrt(cov[k, k]))) for k, n in enumerate(used) if not n.startswith(("c", "eps_"))}
    beta = np.array([nuisance.get(n, (0.0, 0.0))[0] for n in ("tilt_east", "tilt_north_sin_azimuth_cos")])
    rank = _rank_report(latitude, len(hold_list), chosen, set(used), base)
    record = BiasInputs(prior_values, prior_covariance, error_model, site.reference_temperature)
    biases = bias_checks(columns, hold_list, nav_to_platform, delta=_base_basis(latitude) @ beta, gravity=gravity, record=record)
    likelihood = Likelihood(tuple(t.id for t in GYRO_DRIFT_TERMS), eps, np.asarray(np.linalg.inv(cov_eps), dtype=np.float64), np.zeros(3))
    details = DriftDetails(
        tuple(hold_list), nuisance, rank, biases, (float(sigma_axis[0]), float(sigma_axis[1]), float(sigma_axis[2])), chosen["base"]
    )
    return FitResult(
        stage=Stage.DRIFT,
        terms=GYRO_DRIFT_TERMS,
        values=eps,
        covariance=cov_eps,
        status=(Status.ESTIMATED,) * 3,
        residuals=residual.ravel(),
        residual_sigma=np.broadcast_to(sigma_axis, residual.shape).ravel().copy(),
        rank=len(used),
        notes=rank,
        details=details,
        likelihood=likelihood,
        gravity=gravity,
        settings=DriftSettings(base, len(hold_list), tuple(n for n in used if not n.startswith(("c", "eps_")))),
    )


def _design(
    time: NDArray[np.float64],
    actual: NDArray[np.float64],
    inertial: NDArray[np.float64],
    nav_to_platform: NDArray[np.float64],
    holds: Sequence[StillHold],
    *,
    latitude: float,
    gravity: float,
    configuration: GimbalConfiguration,
) -> tuple[NDArray[np.float64], NDArray[np.float64], list[str]]:
    """Observations ``φ`` (N, 3), design (N, 3, p) and the column names (module docstring's equation).

    Columns: per hold 3 intercepts ``c{k}_{i}``; ``eps_x/y/z``; the base ``δ = B β`` (``tilt_east``,
    ``tilt_north_sin_azimuth_cos``); ``Dg_zz`` when ``f_z`` reverses; ``theta20_residual`` when the inner axis
    reverses in the local frame; the platform angle sensor's once-per-revolution error ``ang1_platform_c/s``.
    """
    platform = GimbalPlatform(configuration=configuration)
    # a zero-offset or sensor error Δα of gimbal i turns the computed platform by J_i Δα (J_i = ∂ω/∂α_i)
    inner_p = platform.angular_rate(actual, np.array([0.0, 1.0, 0.0]))
    outer_p = platform.angular_rate(actual, np.array([1.0, 0.0, 0.0]))
    inner_n = np.einsum("nji,nj->ni", nav_to_platform, inner_p)
    directions = np.array([inner_n[(h.first + h.stop) // 2] for h in holds])
    fz_signs = {int(np.sign(h.specific_force[2])) for h in holds if abs(h.specific_force[2]) > gravity / 4}
    names = [f"c{k}_{i}" for k in range(len(holds)) for i in "xyz"] + ["eps_x", "eps_y", "eps_z", "tilt_east", "tilt_north_sin_azimuth_cos"]
    if fz_signs == {-1, 1}:
        names.append("Dg_zz")
    if np.min(directions @ directions.T) < -0.5:
        names.append("theta20_residual")
    names += ["ang1_platform_c", "ang1_platform_s"]
    column = {n: k for k, n in enumerate(names)}
    basis = _base_basis(latitude)
    rows_y, rows_a = [], []
    for index, hold in enumerate(holds):
        sl = slice(hold.first, hold.stop)
        mid = (hold.first + hold.stop) // 2
        dt = time[sl] - time[mid]
        a = np.zeros((len(dt), 3, len(names)))
        a[:, :, column[f"c{index}_x"] : column[f"c{index}_x"] + 3] = np.eye(3)
        a[:, :, column["eps_x"] : column["eps_x"] + 3] = -dt[:, None, None] * np.eye(3)
        a[:, :, column["tilt_east"] : column["tilt_east"] + 2] = -nav_to_platform[sl] @ basis
        if "Dg_zz" in column:
            # the platform turns at -Dg_zz f_z about z_p (conventions.platform_drift_rate), f_z = -g C_n^p[2, 2]
            a[:, 2, column["Dg_zz"]] = dt * gravity * nav_to_platform[sl, 2, 2]
        if "theta20_residual" in column:
            a[:, :, column["theta20_residual"]] = inner_p[sl]
        reading = actual[sl, 0]  # the sensor's angle: reading + offset (the error is a function of the reading; same to 1e-4)
        a[:, :, column["ang1_platform_c"]] = -outer_p[sl] * np.cos(reading)[:, None]
        a[:, :, column["ang1_platform_s"]] = -outer_p[sl] * np.sin(reading)[:, None]
        rows_y.append(small_angle_vector(inertial[sl] @ inertial[mid].T))
        rows_a.append(a)
    return np.concatenate(rows_y), np.concatenate(rows_a), names


def _separable(
    design: NDArray[np.float64], y: NDArray[np.float64], names: list[str], *, used: list[str], members: list[str], drift: list[str]
) -> bool:
    """Whether adding ``members`` inflates no drift σ more than :data:`SEPARATION_LIMIT` times."""
    held = _covariance(design, y, [names.index(n) for n in used], _priors(used))[0]
    free = _covariance(design, y, [names.index(n) for n in used + members], _priors(used + members))[0]
    before = np.diag(held)[[used.index(n) for n in drift]]
    after = np.diag(free)[[(used + members).index(n) for n in drift]]
    return bool(np.all(np.sqrt(after / before) < SEPARATION_LIMIT))


def _priors(used: Sequence[str]) -> NDArray[np.float64]:
    """Prior precision of each used column: the platform angle sensor's once-per-revolution error, none elsewhere."""
    return np.array([ANGLE_SENSOR_PRIOR**-2 if n.startswith("ang1_") else 0.0 for n in used])


def _covariance(
    design: NDArray[np.float64], y: NDArray[np.float64], columns: Sequence[int], precision: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Weighted least squares on the chosen columns with a zero-mean prior of ``precision``: ``(cov, x, σ per axis, residuals)``.

    The σ of each rotation-vector component is measured from the residuals (three passes); normal equations on
    unit-scaled columns (a dozen columns, well conditioned once scaled).
    """
    a = design[:, :, list(columns)]
    sigma = np.ones(3)
    p = a.shape[2]
    for _ in range(3):
        w = a / sigma[None, :, None]
        normal = np.einsum("nip,niq->pq", w, w) + np.diag(precision)
        scale = np.sqrt(np.diag(normal))
        scale[scale == 0] = 1.0
        inverse = np.linalg.inv(normal / np.outer(scale, scale)) / np.outer(scale, scale)
        x = inverse @ np.einsum("nip,ni->p", w, y / sigma[None, :])
        residual = y - np.einsum("nip,p->ni", a, x)
        dof = max(1.0, len(y) - p / 3.0)
        sigma = np.sqrt(np.sum(residual**2, axis=0) / dof)
        sigma[sigma == 0] = 1e-300
    return inverse, x, sigma, residual


def _rank_report(latitude: float, holds: int, chosen: Mapping[str, bool], used: set[str], base: str) -> tuple[str, ...]:
    """Return the rank report: what the data determine and the gauge held for what they do not (module docstring)."""
    per_arcsec = EARTH_RATE * math.cos(latitude) * ARCSEC / DEG_PER_HOUR
    lines = [f"{holds} hold{'s' if holds != 1 else ''}; gyro_drift_x, gyro_drift_y, gyro_drift_z: estimated"]
    lines.append(
        "base rotation about the Earth's axis (t_N cos L - azimuth sin L): not observable (commutes with the Earth's turn); "
        "gauge: held at the survey"
    )
    if chosen["base"]:
        lines.append("base tilt East and t_N sin L + azimuth cos L: estimated as nuisances (the index reverses their misprojection)")
    else:
        why = "held at the survey by request" if base == "survey" else "no index reverses its misprojection"
        lines.append(
            f"base tilt East and t_N sin L + azimuth cos L: not separable from gyro_drift_x/y ({why}); gauge: held at the survey, "
            f"so gyro_drift_x/y carry Ω·|u×δ| ({per_arcsec:.2g} °/h per arcsec of azimuth error)"
        )
    if "Dg_zz" in used:
        lines.append("g-sensitive drift along z_p (Dg_zz): estimated as a nuisance (f_z reverses)")
    else:
        lines.append("gyro_drift_z includes any g-sensitive drift Dg_zz·f_z (f_z never reverses; drift-three-position separates it)")
    if "theta20_residual" in used:
        lines.append("inner zero-offset residual: estimated as a nuisance (the middle gimbal's flip reverses the inner axis)")
    else:
        lines.append("inner and middle zero-offset residuals: rotations about axes fixed in the local frame, absorbed by the base nuisance")
    lines.append(
        "platform angle sensor's once-per-revolution error (ang1_platform_c/s): a nuisance with a 2″ prior (the record carries "
        "none); its slope reverses with a 180° index, without one it shares gyro_drift_z's σ"
    )
    return tuple(lines)
