r"""Least-squares problems that model discovery works on.

Discovery needs four things from a fitted stage: the weighted residuals, their 1σ from
noise measured in the data, the design (∂prediction/∂parameter at the estimate) and the
column of any candidate term.  :class:`stableins.estimators.leastsquares.Problem` is that
interface (declared in the estimators layer, beside the forward model); two implementations:

* :class:`DwellProblem` — device level.  Observations are dwell means of the three
  accelerometer outputs per position; the prediction is the coarse stage's dwell forward model
  ``f^a = forward(f^p(readings, θ_0, base), p)``, :func:`stableins.estimators.leastsquares.dwell_forward`
  (Wu et al. 2018 Eq. 6 with the exact gimbal kinematics of :mod:`stableins.platform`), defined
  once for the stages and discovery.  The fit is Gauss–Newton; the
  zero offset ``θ10`` (and anything else in the null space of the design) is held at its
  prior value as an explicit gauge, marked ``"gauge"``.
* :class:`LinearProblem` — any linear(ized) problem given as observations, 1σ, model
  columns and candidate columns (system-level harmonics, user problems).

Both return a frozen :class:`~stableins.estimators.result.FitResult`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stableins.conventions import AXES, dcm_nav_to_body
from stableins.discovery.dwells import DwellSet
from stableins.errormodel import ErrorModel, Term, TermInputs, TermKind
from stableins.estimators.design import UNDETERMINED_RATIO  # a combination with 1σ above this many typical sizes is a gauge
from stableins.estimators.details import StageDetails
from stableins.estimators.leastsquares import DwellForward, Problem, dwell_forward
from stableins.estimators.result import FitResult, Likelihood, Stage
from stableins.status import Status


@dataclass(frozen=True, eq=False)
class DiscoveryDetails(StageDetails):
    """What a discovery fit of dwells worked with, beyond the parameters.

    Attributes
    ----------
    specific_force_platform : ndarray (n, 3)
        Platform-frame specific force of each dwell [m/s²] at the fitted parameters.
    prediction : ndarray (n, 3)
        The model's output at each dwell [m/s²].
    noise : dict
        The noise description the dwells were weighted with (:attr:`DwellSet.noise`).
    slow_noise : bool
        Whether the weights include the slow-noise covariance between dwells.
    """

    specific_force_platform: NDArray[np.float64]
    prediction: NDArray[np.float64]
    noise: Mapping[str, Any]
    slow_noise: bool


class DwellProblem:
    """Device-level dwell means under the exact forward model (see module docstring).

    Parameters
    ----------
    dwells : DwellSet
        The observations.
    fixed : mapping, optional
        Parameters held at a given value (status ``"fixed"``), e.g. from a record.
    stage : Stage
        What the rows are.
    static : bool
        The rows are the static dwells of a device session (independent once whitened): the ranking fixes its flags'
        level from the exact null distribution and tests a candidate's residual for a laboratory-fixed signature
        (:func:`stableins.discovery.ranking.rank`).  False for a system record's bins.
    """

    def __init__(
        self, dwells: DwellSet, fixed: Mapping[str, float] | None = None, stage: Stage = Stage.DEVICE_DWELLS, *, static: bool = True
    ) -> None:
        self.dwells = dwells
        self.fixed = dict(fixed or {})
        self.stage = stage
        self.static = static
        self._inverse_factor = None
        self._last: tuple[tuple[Any, ...], DwellForward] | None = None  # the last evaluation (evaluate)
        if dwells.slow_covariance is not None:
            c = np.asarray(dwells.slow_covariance, dtype=float)
            self._inverse_factor = np.stack([np.linalg.inv(np.linalg.cholesky(c[a] + np.diag(dwells.sigma[:, a] ** 2))) for a in range(3)])

    @property
    def total_sigma(self) -> NDArray[np.float64]:
        """1σ of each observation (white and slow noise), flattened position-major."""
        d = self.dwells
        variance = d.sigma**2 + (0.0 if d.slow_covariance is None else np.diagonal(d.slow_covariance, axis1=1, axis2=2).T)
        return np.sqrt(variance).reshape(-1)

    def whiten(self, v: ArrayLike) -> NDArray[np.float64]:
        """``R^{-1/2} v`` for observation-ordered vectors (m,) or matrices (m, k): ``L_a^{-1}`` per axis."""
        v = np.asarray(v, dtype=float)
        if self._inverse_factor is None:
            s = self.dwells.sigma.reshape(-1)
            return v / (s if v.ndim == 1 else s[:, None])
        shaped = v.reshape((self.dwells.n_positions, 3) + v.shape[1:])
        out = np.stack([self._inverse_factor[a] @ shaped[:, a] for a in range(3)], axis=1)
        return out.reshape(v.shape)

    # ------------------------------------------------------------------ geometry
    @property
    def labels(self) -> tuple[str, ...]:
        """Residual label of every observation, ``"<position> f_<axis>"``."""
        return tuple(f"{p} f_{a}" for p in self.dwells.labels for a in AXES)

    @property
    def position_index(self) -> NDArray[np.int64]:
        """Position (dwell) of every observation."""
        return np.repeat(np.arange(self.dwells.n_positions), 3)

    @property
    def axis_index(self) -> NDArray[np.int64]:
        """Output axis of every observation."""
        return np.tile(np.arange(3), self.dwells.n_positions)

    def evaluate(self, model: ErrorModel, values: Mapping[str, float], extra_terms: Sequence[Term] = ()) -> DwellForward:
        """Return the dwell forward model over ``model + extra_terms`` at ``values`` on these dwells.

        Prediction (P, 3), Jacobian (P, 3, n), ``f^p`` and inputs: the coarse stage's
        :func:`stableins.estimators.leastsquares.dwell_forward`.

        Zero offsets and kinematic (test-equipment) effects act through the exact kinematics: ``f^p`` is computed with
        their values and their columns are ``(∂f^a/∂f^p)(∂f^p/∂p)``; every other term goes through
        :meth:`ErrorModel.forward` / :meth:`ErrorModel.jacobian`.

        The last evaluation is kept: a fit evaluates its solution again, and its design and candidate columns are
        evaluated there too (issue 30); the same terms at the same values return it (its arrays are read-only).
        """
        d = self.dwells
        full = ErrorModel(model.terms + tuple(extra_terms)) if extra_terms else model
        key = (full.terms, tuple((k, float(v)) for k, v in values.items()))
        if self._last is not None and self._last[0] == key:
            return self._last[1]
        forward = dwell_forward(
            full,
            values,
            d.readings,
            d.gravity,
            base_dcm=dcm_nav_to_body(*d.base_attitude),
            configuration=d.configuration,
            inputs=TermInputs(
                np.zeros((d.n_positions, 3)),  # f^p, given by the model
                temperature=d.temperature,
                time=d.time,
                slew_direction=d.slew_direction,  # the visit history's states (DwellSet.slew_direction)
                extra={"time_since_command": d.time_since_command},
            ),
        )
        for array in (forward.output, forward.jacobian, forward.specific_force):
            array.flags.writeable = False
        self._last = (key, forward)
        return forward

    # ------------------------------------------------------------------ fit
    def fit(self, model: ErrorModel, start: Mapping[str, float] | None = None, iterations: int = 8) -> FitResult:
        """Gauss–Newton fit of ``model`` to the dwell means (weighted by 1/σ², whitened where the noise is slow).

        The solver is the one of the device stages (:func:`stableins.estimators.gauss_newton.gauss_newton`,
        column-scaled by each term's typical size, step halved while the cost rises); the parameters
        these data do not determine are held (gauge, :func:`gauge_columns`) from the start and, should the
        design at the solution lose a direction, the fit is repeated with it held as well.
        """
        from stableins.estimators.gauss_newton import gauss_newton

        d = self.dwells
        values = model.nominal_values()
        if start:
            values.update({k: float(v) for k, v in start.items() if k in model})
        values.update({k: float(v) for k, v in self.fixed.items() if k in model})
        y = d.output.reshape(-1)
        ids = model.ids
        free = [t.id not in self.fixed for t in model.terms]
        scales = np.array([abs(t.nominal) or 1.0 for t in model.terms])

        def weighted(x: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
            forward = self.evaluate(model, dict(zip(ids, x[0], strict=True)))
            prediction, jac = forward.output, forward.jacobian
            return self.whiten(y - prediction.reshape(-1))[None], self.whiten(jac.reshape(-1, len(model)))[None]

        x = np.array([[values[i] for i in ids]])
        gauge: list[str] = []
        notes: list[str] = []
        solved = False
        while True:
            _, a = weighted(x)
            _, new_gauge = gauge_columns(a[0], [k for k in range(len(model)) if free[k] and ids[k] not in gauge], model.terms)
            for gid in new_gauge:
                gauge.append(gid)
                notes.append(
                    f"{gid} held at {x[0, ids.index(gid)]:.6g} (gauge): these data do not separate it from the other parameters "
                    f"(1σ of the combination > {UNDETERMINED_RATIO:g}× its typical size)"
                )
            if solved and not new_gauge:
                break
            mask = np.array([free[k] and ids[k] not in gauge for k in range(len(model))])
            if mask.any():
                x = gauss_newton(weighted, x, mask, scales, max_iterations=iterations).x
            solved = True
        values = dict(zip(ids, (float(v) for v in x[0]), strict=True))
        forward = self.evaluate(model, values)
        prediction, jac, f_p = forward.output, forward.jacobian, forward.specific_force
        a = self.whiten(jac.reshape(-1, len(model)))
        cols = [k for k in range(len(model)) if free[k] and model.terms[k].id not in gauge]
        normal = a[:, cols].T @ a[:, cols]
        cov_free = np.linalg.inv(normal)
        cov = np.zeros((len(model), len(model)))
        cov[np.ix_(cols, cols)] = cov_free
        status = tuple(
            Status.ESTIMATED if k in cols else (Status.GAUGE if model.terms[k].id in gauge else Status.FIXED) for k in range(len(model))
        )
        null_space, determined, sv = _design_report(a, model, free, gauge)
        residuals = y - prediction.reshape(-1)
        white = self.whiten(residuals)
        return FitResult(
            stage=self.stage,
            terms=model.terms,
            values=np.array([values[t.id] for t in model.terms]),
            covariance=cov,
            status=status,
            residuals=residuals,
            residual_sigma=self.total_sigma,
            residual_labels=self.labels,
            rank=len(cols),
            singular_values=sv,
            null_space=null_space,
            determined=determined,
            notes=tuple(notes),
            details=DiscoveryDetails(
                specific_force_platform=f_p, prediction=prediction, noise=d.noise, slow_noise=d.slow_covariance is not None
            ),
            whitened_residuals=white,
            likelihood=Likelihood.from_weighted(model.ids, np.array([values[t.id] for t in model.terms]), a, white),
        )

    def design(self, result: FitResult) -> NDArray[np.float64]:
        """Return ``∂prediction/∂p`` at the estimate for the parameters with status ``"estimated"``, shape (m, k)."""
        model = ErrorModel(result.terms)
        jac = self.evaluate(model, result.as_dict()).jacobian
        cols = [k for k, st in enumerate(result.status) if st == Status.ESTIMATED]
        return jac.reshape(-1, len(model))[:, cols]

    def candidate_columns(self, terms: Sequence[Term], result: FitResult) -> NDArray[np.float64]:
        """Return ``∂prediction/∂p`` of the candidate ``terms`` at the estimate, shape (m, len(terms))."""
        model = ErrorModel(result.terms)
        jac = self.evaluate(model, result.as_dict(), extra_terms=tuple(terms)).jacobian
        return jac.reshape(-1, len(model) + len(terms))[:, len(model) :]

    def orientation(self, result: FitResult | None = None) -> NDArray[np.float64]:
        """``f^p/g`` per observation, shape (m, 3) (residuals against orientation)."""
        d = self.dwells
        from stableins.platform import platform_specific_force

        f_p = platform_specific_force(d.readings, d.gravity, base_attitude=d.base_attitude, configuration=d.configuration)
        return np.repeat(f_p / d.gravity, 3, axis=0)


def fit_chi2(result: FitResult) -> float:
    """χ² that the fit minimized (generalized when the observations are correlated): :attr:`FitResult.chi2`."""
    return result.chi2


def fit_chi2_red(result: FitResult) -> float:
    """:attr:`FitResult.chi2_red`, the one χ²_ν printed everywhere."""
    return result.chi2_red


def whiten(problem: Problem | None, result: FitResult, v: ArrayLike) -> NDArray[np.float64]:
    """``R^{-1/2} v`` with the problem's noise model (:meth:`Problem.whiten`); the fit's diagonal 1σ without a problem."""
    if problem is not None:
        return problem.whiten(v)
    v = np.asarray(v, dtype=float)
    s = result.residual_sigma
    return v / (s if v.ndim == 1 else s[:, None])


def _design_report(a: NDArray, model: ErrorModel, free: Sequence[bool], gauge: Sequence[str]) -> tuple[NDArray, tuple[str, ...], NDArray]:
    """Null space (model order), determined combinations and singular values of the free parameters' design.

    Uses the device stage's design analysis (:mod:`stableins.estimators.design`) on the
    nominal-scaled whitened design, with the same threshold as the gauge choice here
    (a direction is undetermined when its 1σ exceeds ``UNDETERMINED_RATIO`` typical sizes).
    """
    from stableins.estimators.design import analyze_design, choose_gauge

    idx = [k for k in range(len(model)) if free[k]]
    ids = [model.terms[k].id for k in idx]
    scales = np.array([abs(model.terms[k].nominal) or 1.0 for k in idx])
    smax = np.linalg.norm(a[:, idx] * scales, ord=2) if idx else 0.0
    rtol = float((1.0 / UNDETERMINED_RATIO) / smax) if smax > 0 else 1e-8
    analysis = analyze_design(a[:, idx], ids, scales, rtol=max(rtol, 1e-12))
    null = np.zeros((len(model), analysis.null_space.shape[1]))
    null[idx] = analysis.null_space
    determined: tuple[str, ...] = ()
    if analysis.deficiency:
        chosen = choose_gauge(analysis, preference=tuple(gauge), scales=scales)
        determined = chosen.describe() + tuple(f"{g} = its prior value by gauge" for g in chosen.fixed)
    return null, determined, analysis.singular_values


_GAUGE_PREFERENCE = {
    TermKind.GIMBAL: 0,
    TermKind.ADDITIVE: 1,
    TermKind.NONLINEARITY: 2,
    TermKind.SCALE_FACTOR: 3,
    TermKind.INSTALLATION: 4,
    TermKind.BIAS: 5,
}


def gauge_columns(a: NDArray, cols: list[int], terms: Sequence[Term], tolerance: float = 1e-9) -> tuple[list[int], list[str]]:
    """Return the columns kept and the ids held so that every direction of the design is determined.

    Columns of the whitened design are scaled by each term's typical size (``nominal``; a term
    without one by its column's norm); a singular value ``s`` then means a combination with
    1σ = ``1/s`` typical sizes.  While the smallest is below ``max(tolerance·s_max,
    1/UNDETERMINED_RATIO)`` (exact null space, or a combination these data cannot determine), the
    parameter with the largest share of that direction is held, preferring gimbal offsets, then
    additive terms, quadratic coefficients, scale factors, installation angles and biases last
    (:func:`stableins.estimators.design.undetermined`).
    """
    from stableins.estimators.design import undetermined

    ids = [terms[c].id for c in cols]
    norms = np.linalg.norm(a[:, cols], axis=0)
    nominal = np.array([abs(terms[c].nominal) for c in cols])
    scales = np.where(nominal > 0, nominal, 1.0 / np.where(norms > 0, norms, 1.0))
    rank = {terms[c].id: _GAUGE_PREFERENCE.get(terms[c].kind, 6) for c in cols}
    held = undetermined(a[:, cols], ids, scales, rank, tolerance=tolerance, smallest_only=True)
    return [c for c in cols if terms[c].id not in held], list(held)
