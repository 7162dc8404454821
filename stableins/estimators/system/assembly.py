"""The system stage's last solve steps: what the record determines and the Bayesian update of the prior.

From the combined coefficients and their covariance: the combinations a record determines
(:func:`observable_directions`), the likelihood of the accelerometer parameters (:func:`separation_likelihood`), the prior's
covariance in the stage's parameters, and the stage's :class:`~stableins.estimators.result.FitResult`
(:func:`fit_result`).  docs/system-calibration.md §4, §8.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from stableins.errormodel import CORE_TERMS, Term, TermKind, known_terms
from stableins.estimators.details import SystemDetails
from stableins.estimators.result import FitResult, Likelihood, Stage
from stableins.estimators.system import harmonics as hm
from stableins.estimators.system.options import ESTIMATE_K2_PARAMETER, GYRO_DRIFT_PARAMETER
from stableins.estimators.system.separation import COMBINED_COEFFICIENTS, Separation
from stableins.status import Determination, Status

if TYPE_CHECKING:
    from stableins.estimators.system.checks import RecordSite
    from stableins.estimators.system.gyro_drift import DriftStep
    from stableins.estimators.system.settings import SystemSettings


#: Variance-inflation factor above which a coefficient counts as not observable in a short record.
VIF_LIMIT = 30.0


def residual_scale(values: Mapping[str, float], gravity: float) -> dict[str, float]:
    """d(record value)/d(residual): sf = sf/(1 − D) → sf; bias = g·b → g; beta → 1."""
    out = {}
    for name in hm.RESIDUAL_NAMES:
        if name.startswith("D_"):
            out[name] = float(values.get(f"sf_{name[2]}", 1.0))
        elif name.startswith("b_"):
            out[name] = gravity
        else:
            out[name] = 1.0
    return out


def term_id(residual: str) -> str:
    """Return the record term of a residual (:data:`harmonics.RESIDUAL_NAMES`): ``D_x`` → ``sf_x``, ``b_x`` → ``bias_x``."""
    if residual.startswith("D_"):
        return f"sf_{residual[2]}"
    if residual.startswith("b_"):
        return f"bias_{residual[2]}"
    return residual


def residuals_from_parameters(true: Mapping[str, float], installed: Mapping[str, float], gravity: float) -> NDArray[np.float64]:
    """Residual vector (:data:`harmonics.RESIDUAL_NAMES`) for true and installed parameters (reference values)."""
    out = []
    for name in hm.RESIDUAL_NAMES:
        tid = term_id(name)
        t, i = float(true.get(tid, 1.0 if tid.startswith("sf") else 0.0)), float(installed.get(tid, 1.0 if tid.startswith("sf") else 0.0))
        if name.startswith("D_"):
            out.append((t - i) / t)
        elif name.startswith("b_"):
            out.append((t - i) / gravity)
        else:
            out.append(t - i)
    return np.array(out)


def combined_terms() -> tuple[Term, ...]:
    """Return the fifteen combined coefficients as terms (x1..x5, the pitch and roll coefficients) [rad]."""
    meaning = dict(zip(hm.HARMONIC_STATES, hm.STATE_MEANING, strict=True))
    terms = []
    for name in COMBINED_COEFFICIENTS:
        terms.append(
            Term(
                name,
                TermKind.COMBINED,
                "rad",
                "urad",
                1e-6,
                1e-4,
                meaning.get(name, f"quasi-static {'pitch' if name.startswith('theta') else 'roll'} coefficient {name}"),
                source="Wu et al. 2018 Eqs. 21-25, 29-38 (signs derived in docs/system-calibration.md)",
            )
        )
    return tuple(terms)


def k2_map(latitude: float, *, estimate_k2: bool) -> NDArray[np.float64]:
    """Matrix ``(15, 17)`` from ``(x1..x7, attitude)`` to the combined coefficients.

    With ``estimate_k2`` the residual-K2 parts are removed: ``δ_i += gΔK_i u_i²`` gives
    ``x2 += 3cos²L x6``, ``x3 −= 3cos²L x7``, ``θ1c −= 3 sinL cos²L x6``, ``θ1s += 3 sinL cos²L x7``,
    ``φ1s += cos²L x6``, ``φ1c += cos²L x7`` (docs/system-calibration.md §8).
    """
    m = np.zeros((15, 17))
    m[:5, :5] = np.eye(5)
    m[5:, 7:] = np.eye(10)
    if estimate_k2:
        s, c2 = math.sin(latitude), math.cos(latitude) ** 2
        x6, x7 = 5, 6
        row = {n: i for i, n in enumerate(COMBINED_COEFFICIENTS)}
        m[row["x2"], x6] = -3.0 * c2
        m[row["x3"], x7] = 3.0 * c2
        m[row["theta_1c"], x6] = 3.0 * s * c2
        m[row["theta_1s"], x7] = -3.0 * s * c2
        m[row["phi_1s"], x6] = -c2
        m[row["phi_1c"], x7] = -c2
    return m


def prior_term_covariance(
    prior_covariance: Mapping[tuple[str, str], float] | None, prior_res_cov: NDArray[np.float64], scale: Mapping[str, float]
) -> NDArray[np.float64]:
    """Prior covariance over CORE_TERMS: the prior's own entries (all correlations), nominal magnitudes where it has none.

    The residual block is :func:`prior_residual_covariance` mapped back to the terms; K2 terms and their cross terms
    with the others come from the prior as given (a record's covariance), their variance nominal² when missing.
    """
    terms = CORE_TERMS
    res_index = {term_id(r): i for i, r in enumerate(hm.RESIDUAL_NAMES)}
    j = {term_id(r): scale[r] for r in hm.RESIDUAL_NAMES}
    fixed = fixed_variance(prior_covariance)
    cov = np.zeros((len(terms), len(terms)))
    for a, ta in enumerate(terms):
        for b, tb in enumerate(terms):
            if ta.id in res_index and tb.id in res_index:
                cov[a, b] = prior_res_cov[res_index[ta.id], res_index[tb.id]] * j[ta.id] * j[tb.id]
            elif a == b:
                cov[a, b] = fixed[ta.id]
            else:
                value = None if prior_covariance is None else prior_covariance.get((ta.id, tb.id))
                cov[a, b] = float(value) if value is not None and np.isfinite(value) else 0.0
    cov = 0.5 * (cov + cov.T)
    if np.linalg.eigvalsh(cov / np.sqrt(np.outer(np.diag(cov), np.diag(cov)))).min() <= 0.0:  # mixed sources broke it: no cross terms
        cov = np.where(np.outer([t.id in res_index for t in terms], [t.id in res_index for t in terms]), cov, np.diag(np.diag(cov)))
    return cov


def fixed_variance(prior_covariance: Mapping[tuple[str, str], float] | None) -> dict[str, float]:
    """Prior variances of the terms this stage carries through unchanged (K2); nominal² where unknown."""
    out = {}
    for t in CORE_TERMS:
        if t.kind == TermKind.NONLINEARITY:
            v = None if prior_covariance is None else prior_covariance.get((t.id, t.id))
            out[t.id] = float(v) if v is not None and np.isfinite(v) and v > 0 else t.nominal**2
    return out


def observable_directions(covariance: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.bool_], int]:
    """Find the combinations of the combined coefficients that the record determines.

    Per group (the five harmonic states; the ten attitude coefficients) the information
    matrix in correlation form ``Λ_s`` has unit eigenvalues for an orthogonal design (a
    whole number of days).  Directions with eigenvalue ``< 1/VIF_LIMIT`` (variance inflated
    more than ``VIF_LIMIT`` times) are not observable.  Returns the transform ``T`` whose
    rows are the kept combinations (``T c`` has covariance ``diag(1/λ)``), which coefficients
    remain individually observable, and the number of kept combinations.
    """
    rows = []
    observable = np.zeros(15, bool)
    for group in (slice(0, 5), slice(5, 15)):
        idx = np.arange(15)[group]
        info = np.linalg.pinv(covariance[np.ix_(idx, idx)], rcond=1e-15, hermitian=True)
        d = np.sqrt(np.clip(np.diag(info), 1e-300, None))
        eigenvalues, vectors = np.linalg.eigh(info / np.outer(d, d))
        keep = eigenvalues >= 1.0 / VIF_LIMIT
        v = vectors[:, keep]
        for column in v.T:
            row = np.zeros(15)
            row[idx] = column * d
            rows.append(row)
        inside = np.linalg.norm(v.T, axis=0)  # |projection of each unit coefficient direction on the kept span|
        observable[idx] = inside > 0.99
    transform = np.array(rows) if rows else np.zeros((0, 15))
    if transform.shape[0] == 15:
        transform = np.eye(15)  # everything is determined: use the coefficients themselves
    return transform, observable, len(rows)


def prior_residual_covariance(
    prior: Mapping[str, float], prior_covariance: Mapping[tuple[str, str], float] | None, gravity: float
) -> NDArray[np.float64]:
    """Prior covariance of the residuals (:data:`harmonics.RESIDUAL_NAMES`); nominal term magnitudes where unknown."""
    scale = residual_scale(prior, gravity)
    nominal = {t.id: t.nominal for t in CORE_TERMS}
    n = len(hm.RESIDUAL_NAMES)
    cov = np.zeros((n, n))
    for i, a in enumerate(hm.RESIDUAL_NAMES):
        for j, b in enumerate(hm.RESIDUAL_NAMES):
            ta, tb = term_id(a), term_id(b)
            value = None if prior_covariance is None else prior_covariance.get((ta, tb))
            if value is not None and np.isfinite(value):
                cov[i, j] = value / (scale[a] * scale[b])
            elif i == j:
                cov[i, j] = (nominal[ta] / scale[a]) ** 2
        if not (cov[i, i] > 0):
            cov[i, i] = (nominal[term_id(a)] / scale[a]) ** 2
    return 0.5 * (cov + cov.T)


@dataclass(frozen=True)
class SeparationFit:
    """The measurement the stage hands to the Bayesian update, and its own least-squares fit (χ², ν)."""

    labels: tuple[str, ...]
    values: NDArray[np.float64]
    sigma: NDArray[np.float64]
    residuals: NDArray[np.float64]
    whitened: NDArray[np.float64]
    rank: int


def separation_likelihood(
    prior: Mapping[str, float],
    site: RecordSite,
    v: NDArray[np.float64],
    cov_v: NDArray[np.float64],
    *,
    to_combined: NDArray[np.float64],
    transform: NDArray[np.float64],
    estimate_k2: bool,
    drift: tuple[NDArray[np.float64], DriftStep] | None = None,
) -> tuple[Likelihood, SeparationFit]:
    r"""Return what the record says about the accelerometer parameters: a :class:`Likelihood` (docs/system-calibration.md §4).

    Measurement ``w = T c`` (the combinations of the combined coefficients ``c`` the record resolves; with
    ``estimate_k2`` also the third-harmonic states ``x6 = gΔK2_x/4``, ``x7 = −gΔK2_y/4``), covariance ``R`` from
    ``cov_v``.  Model ``w = H q + e`` over the residuals ``q`` (true − installed, :data:`harmonics.RESIDUAL_NAMES`;
    ΔK2_x, ΔK2_y with ``estimate_k2``; always ΔK2_z, which enters x1 only as ``g ΔK2_z sin³L``, §8) and the two mean
    nuisances (base tilt and gimbal zero offsets in the pitch and
    roll means).  The nuisances have no prior: they are eliminated exactly by projecting the whitened measurement
    on the complement of their columns.  With whitened ``A = R^{-1/2} H`` and ``r = R^{-1/2} w`` (at ``q = 0``,
    the installed calibration), ``Λ_q = A_pᵀ A_p``, ``g_q = A_pᵀ r_p``; in the record's parameters
    ``x = x_0 + J q`` (``J``: the installed scale factor for ``D``, ``g`` for a bias residual, 1 for angles and K2),
    ``Λ = J⁻¹ Λ_q J⁻¹``, ``g = J⁻¹ g_q`` at the point ``x_0``.  With ``drift`` (the attitude coefficients' Jacobian
    and the drift step) the gyro drift ``gyro_drift_x/y/z`` joins ``q``, linearized at the drift removed
    (:func:`.gyro_drift.augment_measurement`).
    """
    from stableins.estimators.system.separation import combination_matrix

    latitude, gravity = site.latitude, site.gravity
    n_res = len(hm.RESIDUAL_NAMES)
    rows = transform @ to_combined  # (k, 17)
    g_full = combination_matrix(latitude)  # (15, 14): residuals, then the two nuisances
    h_res = transform @ g_full[:, :n_res]
    h_nuisance = transform @ g_full[:, n_res:]
    labels = list(COMBINED_COEFFICIENTS) if transform.shape[0] == 15 else [f"combination {k + 1}" for k in range(transform.shape[0])]
    ids = [term_id(r) for r in hm.RESIDUAL_NAMES]
    jac = [float(residual_scale(prior, gravity)[r]) for r in hm.RESIDUAL_NAMES]
    if estimate_k2:
        rows = np.vstack([rows, np.eye(17)[5:7]])
        h_res = np.block([[h_res, np.zeros((h_res.shape[0], 2))], [np.zeros((2, n_res)), np.diag([gravity / 4.0, -gravity / 4.0])]])
        h_nuisance = np.vstack([h_nuisance, np.zeros((2, 2))])
        labels += ["x6", "x7"]
        ids += ["K2_x", "K2_y"]
        jac += [1.0, 1.0]
    # K2_z: δ_z = g²ΔK_z u_z² with u_z = sinL puts gΔK_z sin³L into z's mean, x1 (§8); the record cannot tell it from the
    # scale factors and b_z, but its prior σ enters x1 through this column (without it x1 took the residual K2_z)
    k2_z = np.zeros(15)
    k2_z[list(COMBINED_COEFFICIENTS).index("x1")] = gravity * math.sin(latitude) ** 3
    h_res = np.hstack([h_res, np.concatenate([transform @ k2_z, np.zeros(h_res.shape[0] - transform.shape[0])])[:, None]])
    ids += ["K2_z"]
    jac += [1.0]
    w = rows @ v
    cov_w = rows @ cov_v @ rows.T
    if drift is not None:
        from stableins.estimators.system.gyro_drift import DRIFT_IDS, augment_measurement

        h_res, h_nuisance, cov_w, w, drift_scale = augment_measurement(rows, h_res, h_nuisance, cov_w, w, jacobian=drift[0], step=drift[1])
        labels += [f"gyro drift {a} (gimbal readings)" for a in "xyz"]
        ids += list(DRIFT_IDS)
        jac += [float(s) for s in drift_scale]
    sd = np.sqrt(np.diag(cov_w))
    chol = np.linalg.cholesky(cov_w / np.outer(sd, sd)) * sd[:, None]
    whiten = np.linalg.inv(chol)
    a_res, a_nui, r = whiten @ h_res, whiten @ h_nuisance, whiten @ w
    # eliminate the nuisances (flat prior): project on the orthogonal complement of their whitened columns
    pinv_n = np.linalg.pinv(a_nui, rcond=1e-10)
    a_p = a_res - a_nui @ (pinv_n @ a_res)
    r_p = r - a_nui @ (pinv_n @ r)
    j_inv = 1.0 / np.array(jac)
    information = (a_p.T @ a_p) * np.outer(j_inv, j_inv)
    gradient = (a_p.T @ r_p) * j_inv
    point = np.array([float(prior.get(i, 1.0 if i.startswith("sf_") else 0.0)) for i in ids])
    if drift is not None:
        point[-3:] = drift[1].values  # the measurement is linearized at the drift removed
    likelihood = Likelihood(tuple(ids), point, information, gradient)
    # the stage's own least-squares fit of the measurement (residuals, χ², ν = measurements − rank)
    a_full = np.hstack([a_res, a_nui])
    solution, *_ = np.linalg.lstsq(a_full, r, rcond=1e-10)
    rank = int(np.linalg.matrix_rank(a_full, tol=1e-10 * np.linalg.norm(a_full, 2)))
    whitened = r - a_full @ solution
    fit = SeparationFit(tuple(labels), w, sd, chol @ whitened, whitened, rank)
    return likelihood, fit


@dataclass(frozen=True)
class StagePrior:
    """The installed calibration the system stage updates (:func:`fit_result`).

    Attributes
    ----------
    values : mapping
        The record's values [SI].
    covariance : ndarray
        Their covariance over :data:`CORE_TERMS` (:func:`prior_term_covariance`).
    drift : (ndarray (3,), ndarray (3, 3)) or None
        Values and covariance of the gyro drift when the prior states one (:func:`.gyro_drift.prior_drift`).
    """

    values: Mapping[str, float]
    covariance: NDArray[np.float64]
    drift: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None


def fit_result(
    sep: Separation,
    fit: SeparationFit,
    likelihood: Likelihood,
    installed: StagePrior,
    notes: list[str],
    *,
    settings: SystemSettings,
    k2: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None,
) -> tuple[FitResult, dict[str, float]]:
    """Return the stage's result: the Bayesian update of the prior given to the stage (values, covariance over CORE_TERMS).

    When the likelihood measures the gyro drift its terms follow, with the prior's drift when it states one
    (``installed.drift``), else the drift comes from the data alone.  ``k2``: the residual ``K2_x``, ``K2_y`` of the
    third harmonic and their covariance when the stage estimates them.
    """
    from stableins.estimators.posterior import bayesian_update

    prior, prior_cov, drift_prior = installed.values, installed.covariance, installed.drift
    terms = tuple(CORE_TERMS)
    ids = [t.id for t in terms]
    prior_values = np.array([float(prior.get(t.id, t.reference)) for t in terms])
    if drift_prior is not None and "gyro_drift_x" in likelihood.ids:
        n = len(ids)
        ids += ["gyro_drift_x", "gyro_drift_y", "gyro_drift_z"]
        prior_values = np.concatenate([prior_values, drift_prior[0]])
        prior_cov = np.block([[prior_cov, np.zeros((n, 3))], [np.zeros((3, n)), drift_prior[1]]])
    post = bayesian_update(ids, prior_values, prior_cov, [Status.ESTIMATED] * len(ids), likelihood)
    catalogue = known_terms()
    terms = tuple(catalogue[i] for i in post.ids)
    ids = list(post.ids)
    prior_values = np.concatenate([prior_values, post.values[len(prior_values) :]])  # new parameters: no prior value
    corrections = {t.id: float(post.values[k] - prior_values[k]) for k, t in enumerate(terms) if post.determination[k] is not None}
    determined = tuple(
        f"{name} = {value:.4e} ± {sigma:.2e}" + ("" if ok else " (NOT determined by these data)")
        for name, (value, sigma, ok) in sep.combinations.items()
    )
    seen = [t.id for t, d in zip(terms, post.determination, strict=True) if d is not None]
    alone = [t.id for t, d in zip(terms, post.determination, strict=True) if d is Determination.ALONE]
    notes = list(notes) + [
        "Bayesian update of the installed calibration (the prior): the data's information on the combinations they determine "
        "is added to the prior's, so no uncertainty grows and nothing moves along what the data do not see; determined by "
        f"these data alone: {', '.join(alone) or 'none'}; in combination only: {', '.join(i for i in seen if i not in alone) or 'none'}",
        "b_x and beta_xy act only through b_x/g - beta_xy*sinL, b_y and beta_yx only through b_y/g + beta_yx*sinL "
        "(paper Eq. 41 is singular); (beta_xz+beta_yz)/2 is indistinguishable from the platform-axis zero offset; the scale factors "
        "and b_z enter only through x1",
        (
            "K2_x, K2_y measured by the third harmonic of Earth rate in z (not in the paper's model) and updated with the rest; "
            "K2_z enters only x1 (g K2_z sin^3 L), in combination with the scale factors and b_z"
            if k2 is not None
            else "K2 terms are not seen by this stage and keep their prior values and variances (nominal magnitude when the prior "
            f"has none); the third harmonic of Earth rate in z measures K2_x, K2_y (see diagnostics, {ESTIMATE_K2_PARAMETER})"
        ),
    ]
    result = FitResult(
        stage=Stage.SYSTEM,
        terms=terms,
        values=np.array(post.values, dtype=float),
        covariance=np.array(post.covariance, dtype=float),
        status=post.status,
        residuals=fit.residuals,
        residual_sigma=fit.sigma,
        residual_labels=fit.labels,
        rank=fit.rank,
        singular_values=sep.singular_values,
        null_space=np.zeros((len(terms), 0)),
        determined=determined,
        notes=tuple(notes),
        details=SystemDetails(
            nuisance=sep.values[len(hm.RESIDUAL_NAMES) :],
            determination=dict(zip(ids, post.determination, strict=True)),
            k2_data_only=None if k2 is None else (k2[0], k2[1]),
        ),
        whitened_residuals=fit.whitened,
        likelihood=likelihood,
        settings=settings,
    )
    return result, corrections


__all__ = [
    "ESTIMATE_K2_PARAMETER",
    "GYRO_DRIFT_PARAMETER",
    "VIF_LIMIT",
    "SeparationFit",
    "StagePrior",
    "combined_terms",
    "fit_result",
    "fixed_variance",
    "k2_map",
    "observable_directions",
    "prior_residual_covariance",
    "prior_term_covariance",
    "residual_scale",
    "residuals_from_parameters",
    "separation_likelihood",
    "term_id",
]
