r"""Device-level fine calibration: the squared-amplitude observation (Wu et al. 2018 Sec. 4).

At a static position the true specific force has the local gravity magnitude,
``|f^p| = g``, whatever the orientation.  With the exact inverse model (Eq. 8)
``f^p(p) = (C_p^a)^{-1} SF (u − K∘u²)``, ``u = ȳ − δb``, each dwell mean ``ȳ_j``
gives one scalar observation that does not depend on the gimbal pointing::

    z_j = ½ g² − ½ |f^p(p; ȳ_j)|² = 0 + v_j

(Eq. 10 with ``|f^p| = g``).  It is solved by Gauss-Newton on the exact model,
starting from the coarse estimate, so the result is a full-value update (not an
increment) with the exact Jacobian obtained by implicit differentiation of
``ȳ = F(f^p, p)``::

    ∂f^p/∂p = −(∂F/∂f^p)^{-1} ∂F/∂p,      ∂z/∂p = −f^pᵀ ∂f^p/∂p

and noise ``σ_z² = Σ_i (f^pᵀ (∂F/∂f^p)^{-1})_i² σ_i²`` from the dwell-mean 1σ.

Linearized at ``K̂ = 0`` with ``ŵ = SF̂ (ȳ − δb̂)`` this is (signs re-derived; see
``docs/device-calibration.md``)::

    z ≈ Σ_i ŵ_i² ΔSF_i/SF_i − Σ_i ŵ_i (SF_i Δb_i) − Σ_i ŵ_i³ (K_i/SF_i)
        − ŵ_x ŵ_y (Δβ_xz − Δβ_yz) − ŵ_x ŵ_z (Δβ_zy − Δβ_xy) − ŵ_y ŵ_z (Δβ_yx − Δβ_zx)

so 12 combinations are determined.  The norm only sees the symmetric part of the
installation matrix: the sums ``β_xz + β_yz``, ``β_zy + β_xy``, ``β_yx + β_zx`` are
null directions of the design.  They are detected from its SVD, held at the coarse
values (gauge), and the six angles are reported ``unidentifiable`` (coarse values
carried through), with the three determined differences stated with their 1σ.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from stableins.errormodel import BETA_IDS, CORE_IDS, ErrorModel, Term
from stableins.errors import InputError, NotDeterminedError
from stableins.estimators.design import DesignAnalysis, Gauge, aligned_null_space
from stableins.estimators.details import DeviceDetails, UsedDwell
from stableins.estimators.device_gauge import final_design, held_terms_note, hold_and_gauge
from stableins.estimators.device_settings import DeviceFitSettings
from stableins.estimators.dwell import DwellSummary, describe_left_out, screen_dwells, slow_covariance
from stableins.estimators.gauss_newton import GaussNewtonSolution, convergence_warning, gauss_newton, goodness_of_fit_warning
from stableins.estimators.result import FitResult, Likelihood, Stage
from stableins.noise import NoiseModel
from stableins.status import Status

#: Held at their coarse values (one of each pair the norm cannot separate).
FINE_GAUGE_PREFERENCE = ("beta_yz", "beta_xy", "beta_zx")


def fine_model(extra_terms: Sequence[Term] = (), *, nonlinear: bool = True) -> ErrorModel:
    """Scale factors, biases, installation angles and quadratic coefficients (15 terms; 12 without), + ``extra_terms``."""
    return ErrorModel.standard(nonlinear=nonlinear) + tuple(extra_terms)


@dataclass(frozen=True)
class FineProblem:
    """Batched fine observations: ``means``, ``sigma`` (T, m, 3), ``gravity`` float or (T,)."""

    means: NDArray[np.float64]
    sigma: NDArray[np.float64]
    gravity: float | NDArray[np.float64]
    model: ErrorModel

    def evaluate(self, x: NDArray[np.float64]):
        """``f^p (T,m,3)``, ``½|f^p|² (T,m)``, its Jacobian ``(T,m,n)`` and 1σ ``(T,m)``."""
        model = self.model
        values = {k: x[..., i, None] for i, k in enumerate(model.ids)}
        f_p = model.inverse(self.means, values)
        d_fa_d_fp = model.jacobian_specific_force(f_p, values)
        d_fa_d_p = model.jacobian(f_p, values)
        d_fp_d_fa = np.linalg.inv(d_fa_d_fp)
        d_fp_d_p = -d_fp_d_fa @ d_fa_d_p
        half_norm = 0.5 * np.einsum("...i,...i->...", f_p, f_p)
        d_h_d_p = np.einsum("...i,...ik->...k", f_p, d_fp_d_p)
        d_h_d_y = np.einsum("...i,...ik->...k", f_p, d_fp_d_fa)
        sigma_h = np.sqrt(np.einsum("...k,...k->...", d_h_d_y**2, self.sigma**2))
        return f_p, half_norm, d_h_d_p, sigma_h

    #: Optional covariance of the dwell means beyond their white 1σ, ``(T, 3, m, m)`` per axis
    #: (:func:`stableins.estimators.dwell.slow_covariance`).
    slow_covariance: NDArray[np.float64] | None = None

    def observation_covariance(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        """``Cov(z) = Σ_a (d_a d_aᵀ) ∘ (diag σ_a² + C_slow,a)`` with ``d_a = ∂z/∂ȳ_a``, ``(T, m, m)``."""
        *_, d_h_d_y = self._with_output_derivative(x)
        white = np.einsum("...k,...k->...", d_h_d_y**2, self.sigma**2)
        cov = white[..., None] * np.eye(white.shape[-1])
        if self.slow_covariance is not None:
            cov = cov + np.einsum("tia,tja,taij->tij", d_h_d_y, d_h_d_y, self.slow_covariance)
        return cov

    def _with_output_derivative(self, x: NDArray[np.float64]):
        model = self.model
        values = {k: x[..., i, None] for i, k in enumerate(model.ids)}
        f_p = model.inverse(self.means, values)
        d_fp_d_fa = np.linalg.inv(model.jacobian_specific_force(f_p, values))
        return f_p, values, d_fp_d_fa, np.einsum("...i,...ik->...k", f_p, d_fp_d_fa)

    def weighted(self, x: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Return whitened residuals ``½g² − h`` and Jacobian (with the slow-noise covariance when given)."""
        _, h, d_h, sigma_h = self.evaluate(x)
        g = np.asarray(self.gravity, dtype=float)
        g = g[..., None] if g.ndim else g
        if self.slow_covariance is None:
            return (0.5 * g**2 - h) / sigma_h, d_h / sigma_h[..., None]
        w = np.linalg.inv(np.linalg.cholesky(self.observation_covariance(x)))
        return np.einsum("tij,tj->ti", w, 0.5 * g**2 - h), np.einsum("tij,tjn->tin", w, d_h)


def solve_fine(problem: FineProblem, x0: NDArray[np.float64], fixed: Sequence[str] = FINE_GAUGE_PREFERENCE, max_iterations: int = 12):
    """Batched Gauss-Newton; ``fixed`` ids keep their ``x0`` values (the gauge)."""
    model = problem.model
    free = np.array([k not in fixed for k in model.ids])
    scales = np.array([t.nominal for t in model])
    return gauss_newton(problem.weighted, np.array(x0, dtype=float), free, scales, max_iterations=max_iterations)


def _start_values(model: ErrorModel, coarse: FitResult | Mapping[str, float]) -> tuple[dict[str, float], dict[str, float]]:
    if isinstance(coarse, FitResult):
        values = coarse.as_dict()
        sig = dict(zip(coarse.ids, map(float, coarse.sigma), strict=True))
    else:
        values, sig = dict(coarse), {}
    return {k: float(values.get(k, model[k].reference)) for k in model.ids}, sig


def _fine_problem(
    usable: Sequence[DwellSummary], model: ErrorModel, *, gravity: float, noise: NoiseModel | None, source: str
) -> FineProblem:
    """Return the squared-amplitude problem of the usable fine dwells (with their slow-noise covariance)."""
    slow = slow_covariance(usable, noise, source) if usable else None
    return FineProblem(
        means=np.array([d.mean for d in usable])[None] if usable else np.zeros((1, 0, 3)),
        sigma=np.array([d.sem for d in usable])[None] if usable else np.zeros((1, 0, 3)),
        gravity=float(gravity),
        model=model,
        slow_covariance=slow[None] if slow is not None else None,
    )


def _installation_combinations(
    gauge: Gauge, model: ErrorModel, x: NDArray[np.float64], cov: NDArray[np.float64]
) -> tuple[dict[str, tuple[float, float]], list[str]]:
    """Return the installation-angle differences the fit determines (value, 1σ) and their description."""
    combos: dict[str, tuple[float, float]] = {}
    determined = []
    arcsec = model["beta_xz"].scale
    for k, coefficients in gauge.coefficients.items():
        pairs = {held_id: c for held_id, c in coefficients.items() if held_id in FINE_GAUGE_PREFERENCE}
        if k not in BETA_IDS or not pairs:
            continue
        (held_id, c), *_ = sorted(pairs.items(), key=lambda kv: -abs(kv[1]))
        name = f"{k} {'+' if c > 0 else '−'} {held_id}"
        value = x[model.index(k)] + c * x[model.index(held_id)]
        sigma = float(np.sqrt(cov[model.index(k), model.index(k)]))
        combos[name] = (float(value), sigma)
        determined.append(f"{name} = {value / arcsec:+.3f} ± {sigma / arcsec:.3f} arcsec")
    determined.append(
        "the norm sees only the symmetric part of C_p^a: beta_xz + beta_yz, beta_zy + beta_xy, beta_yx + beta_zx are not observed"
    )
    return combos, determined


def _carry_from_coarse(
    solution: GaussNewtonSolution, model: ErrorModel, carried: Sequence[str], start: Mapping[str, float], coarse_sigma: Mapping[str, float]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Return values and covariance with the ``carried`` ids at their coarse value and σ, uncorrelated."""
    x = solution.x[0].copy()
    cov = solution.covariance[0].copy()
    for k in carried:
        i = model.index(k)
        x[i] = start[k]
        cov[i, :] = 0.0
        cov[:, i] = 0.0
        cov[i, i] = coarse_sigma.get(k, 0.0) ** 2
    return x, cov


def _stage_notes(gravity: float, left_out: Mapping[int, str]) -> list[str]:
    """Return the fine stage's fixed notes: installation angles, local gravity, positions left out."""
    notes = [
        "installation angles: the fine stage determines only the differences of the pairs (xz, yz), (zy, xy), (yx, zx); its own "
        "result carries the coarse values, a record it updates takes the differences in combination with the coarse information",
        f"local gravity {gravity:.7f} m/s^2 is the reference: an error δg scales sf_x, sf_y, sf_z by 1 + δg/g "
        "(a Type B input of the certificate's uncertainty budget)",
    ]
    return notes + [f"position {p} left out: {why}" for p, why in sorted(left_out.items())]


def _quality_notes(
    solution: GaussNewtonSolution, design: DesignAnalysis, normalized: NDArray[np.float64], labels: tuple[str, ...]
) -> list[str]:
    """Return the warnings on convergence, goodness of fit and weakly determined parameters (installation angles aside)."""
    notes = []
    chi2_whitened = float(solution.weighted_residuals[0] @ solution.weighted_residuals[0])
    if (stalled := convergence_warning(solution)) is not None:
        notes.append(stalled)
    warning = goodness_of_fit_warning(chi2_whitened, normalized.size - design.rank, normalized, labels)
    if warning is not None:
        notes.append(warning)
    weak = [k for k in design.weak if k not in BETA_IDS]
    if weak:
        notes.append(
            f"warning: weakly determined (1σ above the typical magnitude): {', '.join(weak)}; "
            "the positions used do not excite these terms (an axis that never points both up and down?)"
        )
    return notes


def _check_determined(left_out: Mapping[int, str], start_design: DesignAnalysis, gauge: Gauge, source: str) -> None:
    """Raise :class:`NotDeterminedError` unless the usable positions determine the 12 combinations (pairs held as the gauge)."""
    if start_design.deficiency != 3 or set(gauge.fixed) != set(FINE_GAUGE_PREFERENCE):
        raise NotDeterminedError(
            f"the usable fine-stage positions do not determine the model's combinations: null directions involve {start_design.involved()} "
            f"(left out: {describe_left_out(left_out)})",
            path=source,
            field="position",
            expected="positions with every axis near +1 g, −1 g and in between",
        )


def calibrate_fine(
    dwells: Sequence[DwellSummary],
    coarse: FitResult | Mapping[str, float],
    *,
    gravity: float,
    expected_positions: Sequence[int] | None = None,
    allow_missing: bool = False,
    noise: NoiseModel | None = None,
    model: ErrorModel | None = None,
    source: str = "data",
) -> FitResult:
    """Run the fine stage: 12 determined combinations from the squared-amplitude observation.

    Parameters
    ----------
    dwells : sequence of DwellSummary
        Fine-stage dwells (one per position).
    coarse : FitResult or mapping
        Coarse estimate (start values; the installation-angle sums are carried from it).
    gravity : float
        Local gravity [m/s²]; an error ``δg`` scales all three scale factors by ``1 + δg/g``.
    expected_positions : sequence of int, optional
        Positions the fine procedure holds (a missing one is an error unless ``allow_missing``).
    allow_missing : bool
        Fit without the positions that are missing or unusable.
    noise : NoiseModel, optional
        The instrument's noise model (slow noise correlated between dwells,
        :func:`stableins.estimators.dwell.slow_covariance`); white noise only when None.
    model : ErrorModel, optional
        Default :func:`fine_model`.  ``fine_model(extra_terms)``: discovered effects, from ``coarse``; one the norm does
        not determine is carried through (``unidentifiable``).  ``fine_model(nonlinear=False)``: 9 combinations, no K2.
    source : str
        What the dwells were read from (named in messages).

    Returns
    -------
    FitResult
        Stage ``"fine"``: the installation angles carry the coarse values (status ``unidentifiable``),
        their determined differences are in :attr:`FitResult.combinations`.
    """
    usable, left_out, notes = screen_dwells(dwells, expected_positions, allow_missing=allow_missing, source=source, stage="fine")
    model = fine_model() if model is None else model
    extra_ids = tuple(k for k in model.ids if k not in CORE_IDS)
    combinations = 9 + sum(1 for k in model.ids if k.startswith("K2_"))
    start, coarse_sigma = _start_values(model, coarse)
    x0 = model.vector(start)[None]
    problem = _fine_problem(usable, model, gravity=gravity, noise=noise, source=source)
    if noise is not None:
        notes.append(noise.describe())
    if len(usable) <= combinations:
        need = f"{combinations} combinations need at least {combinations + 1}. Left out: {describe_left_out(left_out)}"
        raise InputError(f"only {len(usable)} usable fine-stage positions; {need}", path=source, field="position")
    scales = np.array([t.nominal for t in model])
    _, a0 = problem.weighted(x0)
    start_design, gauge, undetermined = hold_and_gauge(a0[0], model, scales, extra_ids, FINE_GAUGE_PREFERENCE)
    held = tuple(undetermined)
    _check_determined(left_out, start_design, gauge, source)
    solution = solve_fine(problem, x0, gauge.fixed + held)
    design = final_design(solution.weighted_jacobian[0], model, scales, held)
    # Installation angles: the fit moves only the determined differences; report those.
    combos, determined = _installation_combinations(gauge, model, solution.x[0], solution.covariance[0])
    x, cov = _carry_from_coarse(solution, model, BETA_IDS + held, start, coarse_sigma)
    if held:
        notes.append(held_terms_note(undetermined, start, model, "fine"))
    notes += _stage_notes(gravity, left_out)
    _, h, _, sigma_h = problem.evaluate(solution.x)
    if problem.slow_covariance is not None:
        sigma_h = np.sqrt(np.diagonal(problem.observation_covariance(solution.x), axis1=-2, axis2=-1))
    g = float(gravity)
    residuals = ((0.5 * g**2 - h) / g)[0]  # ≈ g − |f^p| [m/s²]
    labels = tuple(f"pos {d.position} |f|" for d in usable)
    notes += _quality_notes(solution, design, residuals / (sigma_h / g)[0], labels)
    return FitResult(
        stage=Stage.FINE,
        terms=model.terms,
        values=x,
        covariance=cov,
        status=tuple(Status.UNIDENTIFIABLE if k in BETA_IDS or k in held else Status.ESTIMATED for k in model.ids),
        residuals=residuals,
        residual_sigma=(sigma_h / g)[0],
        residual_labels=labels,
        rank=design.rank,
        singular_values=design.singular_values,
        null_space=aligned_null_space(design, gauge),
        determined=tuple(determined),
        notes=tuple(notes),
        details=DeviceDetails(
            positions_used=tuple(UsedDwell(d.stage, d.pass_number, d.position) for d in usable),
            left_out={int(k): v for k, v in sorted(left_out.items())},
            gauge_values={gid: float(start[gid]) for gid in gauge.fixed},
            held={h: float(start[h]) for h in held},
        ),
        iterations=solution.iterations,
        gravity=g,
        combinations=combos,
        whitened_residuals=None if problem.slow_covariance is None else solution.weighted_residuals[0].copy(),
        likelihood=Likelihood.from_weighted(model.ids, solution.x[0], solution.weighted_jacobian[0], solution.weighted_residuals[0]),
        settings=DeviceFitSettings(Stage.FINE, noise),
    )
