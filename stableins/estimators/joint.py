r"""Joint device-level fit: every coarse pass and the fine stage in one generalized least squares.

The coarse passes of the zero-offset iteration and the fine stage measure the same
instrument parameters ``p`` (scale factors, biases, installation angles, ``K2``) and
offsets ``θ``; only the commanded readings differ.  Their best combination is the
generalized-least-squares (GLS) solution of all observations together::

    o = [ ȳ_c,1 … ȳ_c,N ; z_f,1 … z_f,M ],     o = h(p, θ) + v,     Cov(v) = R
    x̂ = argmin (o − h(x))ᵀ R⁻¹ (o − h(x)),      P = (Hᵀ R⁻¹ H)⁻¹ at x̂

* coarse rows (:mod:`stableins.estimators.coarse`): the three dwell-mean outputs of
  every usable position of every pass, each with its *own* measured readings;
* fine rows (:mod:`stableins.estimators.fine`): ``h_j = ½|f^p(p; ȳ_j)|²`` with the
  observed value ``½ g²``, a function of the fine dwell mean ``ȳ_j``.

Why not an update of the coarse result with the fine stage's result?  The fine stage's
estimate is conditioned on the coarse values: it is linearized around them, and it
holds the three installation-angle sums at the coarse values (its gauge), so its
covariance is *not* information independent of the coarse covariance; adding the two
informations counts the coarse data twice along the sums.  The information of the
fine *data* is ``J_fᵀ R_f⁻¹ J_f`` with ``J_f = ∂h_f/∂p`` on all 15 parameters (rank
12: the sums are its null space); in the linearized problem the fused estimate is the
information-form update of the coarse estimate ``(x̂_c, P_c)`` by the fine observations,

.. math::
    P^{-1} = P_c^{-1} + J_f^T R_f^{-1} J_f,\qquad
    \hat x = \hat x_c + P J_f^T R_f^{-1} (z_f - h_f(\hat x_c))

and the GLS above is that update iterated to the common solution (relinearized at
``x̂``, so the result does not depend on where the fine stage was linearized).  With
slow noise ``R`` is not block-diagonal: coarse and fine dwells of one time base share
the bias wander (:meth:`stableins.noise.NoiseModel.dwell_mean_covariance`), and
the information form above would miss that cross-covariance; the joint GLS carries it
exactly:

.. math::
    \mathrm{Cov}(\bar y_{i,a}, \bar y_{j,b}) = \delta_{ab} (\sigma_{i,a}^2 \delta_{ij} + C_{slow,ij}),\qquad
    \mathrm{Cov}(o) = M\,\mathrm{Cov}(\bar y)\,M^T

with ``M`` the identity on the coarse rows and ``∂h_j/∂ȳ_j`` on the fine rows.  The
fine rows determine the installation-angle differences (``β_xz − β_yz`` …); fused with
the coarse rows, which see every angle, all six angles are estimated.  ``θ10`` stays
the gauge (held at 0, status ``gauge``): the norm observation does not see it and the
coarse rows cannot.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from stableins.conventions import dcm_nav_to_body
from stableins.errormodel import ErrorModel
from stableins.estimators.coarse import CoarseProblem, coarse_model, quality_notes
from stableins.estimators.details import DeviceDetails, UsedDwell
from stableins.estimators.device_gauge import GAUGE_PREFERENCE, final_design, held_terms_note, hold_and_gauge
from stableins.estimators.device_settings import DeviceFitSettings
from stableins.estimators.dwell import DwellSummary, slow_covariance
from stableins.estimators.fine import FineProblem, fine_model
from stableins.estimators.gauss_newton import gauss_newton
from stableins.estimators.result import FitResult, Stage
from stableins.estimators.sensitivity import angle_reading_sensitivity
from stableins.estimators.setting import DeviceSetting


@dataclass(frozen=True)
class JointProblem:
    """Coarse rows of all passes plus (optionally) fine rows, with the full observation covariance.

    Attributes
    ----------
    coarse : CoarseProblem
        All usable coarse dwells (``slow_covariance`` unused here).
    fine : FineProblem or None
        Usable fine dwells (``slow_covariance`` unused here).
    columns : ndarray of int
        Index in the joint parameter vector of each fine-model parameter.
    slow : ndarray (3, N+M, N+M) or None
        Covariance of all dwell means (coarse first) beyond their white 1σ, per axis.
    """

    coarse: CoarseProblem
    fine: FineProblem | None
    columns: NDArray[np.int64]
    slow: NDArray[np.float64] | None

    def raw(self, x: NDArray[np.float64]):
        """Residuals ``o − h(x)`` (T, 3N+M), model Jacobian (T, 3N+M, n) and ``Cov(o)`` (T, 3N+M, 3N+M)."""
        out, jac = self.coarse.predict(x)
        t, m_c = out.shape[:2]
        n = x.shape[-1]
        residual = (self.coarse.means - out).reshape(t, -1)
        jacobian = jac.reshape(t, -1, n)
        sigma = self.coarse.sigma
        derivative = np.zeros((t, 0, 3))
        if self.fine is not None:
            xf = x[..., self.columns]
            _, h, d_h_d_p, _ = self.fine.evaluate(xf)
            *_, d_h_d_y = self.fine._with_output_derivative(xf)
            g = np.asarray(self.fine.gravity, dtype=float)
            g = g[..., None] if g.ndim else g
            fine_jac = np.zeros((t, h.shape[-1], n))
            fine_jac[..., self.columns] = d_h_d_p
            residual = np.concatenate([residual, 0.5 * g**2 - h], axis=-1)
            jacobian = np.concatenate([jacobian, fine_jac], axis=1)
            sigma = np.concatenate([sigma, self.fine.sigma], axis=1)
            derivative = -d_h_d_y  # residual of row j moves by −∂h/∂ȳ_j · δȳ_j
        m_f = derivative.shape[1]
        dwells = m_c + m_f
        # Cov(ȳ) over (dwell, axis), then o = M ȳ.
        cov_y = np.zeros((t, dwells, 3, dwells, 3))
        for a in range(3):
            block = sigma[..., a, None] ** 2 * np.eye(dwells)
            if self.slow is not None:
                block = block + self.slow[a]
            cov_y[:, :, a, :, a] = block
        cov_y = cov_y.reshape(t, 3 * dwells, 3 * dwells)
        mapping = np.zeros((t, 3 * m_c + m_f, 3 * dwells))
        mapping[:, np.arange(3 * m_c), np.arange(3 * m_c)] = 1.0
        for j in range(m_f):
            mapping[:, 3 * m_c + j, 3 * (m_c + j) : 3 * (m_c + j) + 3] = derivative[:, j]
        cov_o = mapping @ cov_y @ np.swapaxes(mapping, -1, -2)
        return residual, jacobian, cov_o

    def weighted(self, x: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Whitened residuals and Jacobian ``L⁻¹ r``, ``L⁻¹ H`` with ``L Lᵀ = Cov(o)``."""
        residual, jacobian, cov_o = self.raw(x)
        w = np.linalg.inv(np.linalg.cholesky(cov_o))
        return np.einsum("tij,tj->ti", w, residual), w @ jacobian


def joint_problem(
    coarse_dwells: Sequence[DwellSummary], fine_dwells: Sequence[DwellSummary], *, setting: DeviceSetting, model: ErrorModel
) -> JointProblem:
    """Return the :class:`JointProblem` of usable coarse dwells (any passes) and fine dwells under ``setting``'s noise model.

    ``model`` is the joint model (:func:`~stableins.estimators.coarse.coarse_model`, with ``K2_*`` when there are fine
    dwells).  Also the design's Cramér-Rao bound (:mod:`stableins.estimators.experiment`) is evaluated on this problem.
    """
    base = dcm_nav_to_body(*setting.base_attitude)
    coarse = CoarseProblem.from_dwells(coarse_dwells, setting.gravity, base, setting.configuration, model)
    fine = None
    columns = np.zeros(0, dtype=np.int64)
    if fine_dwells:
        fm = fine_model(setting.extra_terms)
        means = np.array([d.mean for d in fine_dwells])[None]
        fine = FineProblem(means, np.array([d.sem for d in fine_dwells])[None], float(setting.gravity), fm)
        columns = np.array([model.index(k) for k in fm.ids], dtype=np.int64)
    return JointProblem(coarse, fine, columns, slow_covariance([*coarse_dwells, *fine_dwells], setting.noise))


def fit_joint(
    coarse_dwells: Sequence[DwellSummary],
    fine_dwells: Sequence[DwellSummary] = (),
    *,
    setting: DeviceSetting,
    start: FitResult | Mapping[str, float],
    nonlinear: bool = True,
    stage: Stage = Stage.COARSE,
    notes: Sequence[str] = (),
) -> FitResult:
    """GLS fit of usable coarse dwells (any number of passes) and fine dwells; gauge ``θ10 = 0``.

    Parameters
    ----------
    coarse_dwells, fine_dwells : sequence of DwellSummary
        Dwells already screened by the coarse and fine stages (usable, in acquisition order).
    setting : DeviceSetting
        Gravity, base attitude and gimbal senses of the unit, its noise model and the additive ``extra_terms``
        (discovered effects) estimated with the standard ones, in the coarse and the fine rows; an extra term
        that the rows do not determine keeps its ``start`` value with status ``unidentifiable``.
    start : FitResult
        Start values (a coarse pass or the joint coarse fit); missing ids start at their reference.
    nonlinear : bool
        Estimate ``K2_*`` (always when fine dwells are given: the fine rows determine them).
    stage : Stage
        Which fit the result is (:attr:`Stage.COARSE` for all passes, :attr:`Stage.DEVICE` fused).
    notes : sequence of str
        Notes the result starts with.
    """
    gravity, noise, extra_terms = setting.gravity, setting.noise, setting.extra_terms
    model = coarse_model(nonlinear=nonlinear or bool(fine_dwells), extra_terms=extra_terms)
    extra_ids = tuple(t.id for t in extra_terms)
    problem = joint_problem(coarse_dwells, fine_dwells, setting=setting, model=model)
    given = start.as_dict() if isinstance(start, FitResult) else dict(start)
    x0 = model.vector({k: given.get(k, model[k].reference) for k in model.ids})[None]
    scales = np.array([t.nominal for t in model])
    _, gauge, undetermined = hold_and_gauge(problem.weighted(x0)[1][0], model, scales, extra_ids, GAUGE_PREFERENCE)
    held = tuple(undetermined)
    fixed = tuple(gauge.fixed) or ("theta10",)
    x0[0, [model.index(g) for g in fixed]] = 0.0
    free = np.array([k not in fixed and k not in held for k in model.ids])
    solution = gauss_newton(problem.weighted, x0, free, scales)
    residual, _, cov_o = problem.raw(solution.x)
    design = final_design(solution.weighted_jacobian[0], model, scales, held)
    m_c = 3 * len(coarse_dwells)
    g = float(gravity)
    residual_sigma = np.sqrt(np.diagonal(cov_o[0]))
    residuals = residual[0].copy()
    residuals[m_c:] /= g  # fine rows as g − |f^p| [m/s²]
    residual_sigma[m_c:] /= g
    multi = len({d.pass_number for d in coarse_dwells}) > 1
    labels = tuple(
        f"{'pass ' + str(d.pass_number) + ' ' if multi else ''}pos {d.position} f_{ax}" for d in coarse_dwells for ax in "xyz"
    ) + tuple(f"fine pos {d.position} |f|" for d in fine_dwells)
    whitened = solution.weighted_residuals[0].copy()
    out_notes = list(notes)
    out_notes += [f"gauge: {k} held at 0 ({model[k].meaning})" for k in fixed]
    if held:
        out_notes.append(held_terms_note(undetermined, dict(zip(model.ids, x0[0], strict=True)), model, stage))
    if noise is not None:
        out_notes.append(noise.describe())
    out_notes += quality_notes(solution, design, residuals / residual_sigma, labels)
    return FitResult.from_solution(
        stage,
        model.terms,
        solution,
        design,
        details=DeviceDetails(
            positions_used=tuple(UsedDwell(d.stage, d.pass_number, d.position) for d in (*coarse_dwells, *fine_dwells)),
            gauge_values={k: 0.0 for k in fixed},
            held={k: float(x0[0, model.index(k)]) for k in held},
            passes=tuple(sorted({d.pass_number for d in coarse_dwells})),
        ),
        residuals=residuals,
        residual_sigma=residual_sigma,
        residual_labels=labels,
        determined=tuple(gauge.describe()) + tuple(f"{k} = 0 by gauge" for k in fixed),
        notes=tuple(out_notes),
        gravity=g,
        whitened_residuals=whitened,
        settings=DeviceFitSettings(Stage(stage), noise, nonlinear=bool(nonlinear or bool(fine_dwells))),
        sensitivities=(angle_reading_sensitivity(problem, solution.x[0], model.ids),),
    )
