r"""Batched weighted Gauss-Newton with fixed (gauge) parameters.

Solves many independent least-squares problems at once (a leading trial axis ``T``),
so that a Monte Carlo of thousands of calibrations is one vectorized loop.  Each step
solves the column-scaled normal equations

.. math::
    (A_s^T A_s)\,\delta z = A_s^T r,\qquad A_s = A\,\mathrm{diag}(d),\qquad
    \delta p = \mathrm{diag}(d)\,\delta z

with ``r = (y − h(p))/σ`` and ``A = ∂h/∂p / σ`` on the free parameters only; fixed
parameters keep their value.  The covariance of the free parameters is
``diag(d) (A_s^T A_s)^{-1} diag(d)`` at the solution: the Cramér-Rao bound of the
linearized problem with the σ given (absolute, never scaled by χ²_ν).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from stableins.errors import InputError, NotDeterminedError

Evaluate = Callable[[NDArray[np.float64]], tuple[NDArray[np.float64], NDArray[np.float64]]]


@dataclass(frozen=True)
class GaussNewtonSolution:
    """Batched solution of :func:`gauss_newton`.

    ``x (T, n)``, ``covariance (T, n, n)`` (zero rows for fixed parameters), weighted residuals ``(T, m)``,
    weighted Jacobian ``(T, m, n)``, iterations used, the last scaled step and whether it fell below the
    tolerance ``(T,)``.
    """

    x: NDArray[np.float64]
    covariance: NDArray[np.float64]
    weighted_residuals: NDArray[np.float64]
    weighted_jacobian: NDArray[np.float64]
    iterations: int
    last_step: NDArray[np.float64]
    converged: NDArray[np.bool_] | None = None


def gauss_newton(
    evaluate: Evaluate,
    x0: NDArray[np.float64],
    free: NDArray[np.bool_],
    scales: NDArray[np.float64],
    *,
    max_iterations: int = 12,
    tolerance: float = 1e-9,
) -> GaussNewtonSolution:
    """Iterate until the largest scaled step is below ``tolerance`` (in nominal units).

    Parameters
    ----------
    evaluate : callable
        ``x (T, n) -> (r (T, m), A (T, m, n))``, weighted residuals and Jacobian.
    x0 : ndarray (T, n)
    free : ndarray of bool (n,)
    scales : ndarray (n,)
        Typical magnitude of each parameter (column scaling).
    """
    x = np.array(x0, dtype=float, copy=True)
    d = np.asarray(scales, dtype=float)[free]
    step = np.full(x.shape[:-1], np.inf)
    iterations = 0
    r, a = evaluate(x)
    cost = np.einsum("tm,tm->t", r, r)
    for iterations in range(1, max_iterations + 1):  # noqa: B007
        a_s = a[..., free] * d
        normal = np.einsum("tmi,tmj->tij", a_s, a_s)
        rhs = np.einsum("tmi,tm->ti", a_s, r)
        dz = _solve(normal, rhs)
        x, r, a, cost, factor = _damped_step(evaluate, x, free, dz * d, cost)
        step = np.abs(dz).max(axis=-1) * factor
        if np.all(step < tolerance):
            break
    a_s = a[..., free] * d
    normal = np.einsum("tmi,tmj->tij", a_s, a_s)
    covariance = np.zeros(x.shape + (x.shape[-1],))
    inv = _inverse(normal) * d[:, None] * d[None, :]
    idx = np.flatnonzero(free)
    covariance[..., idx[:, None], idx[None, :]] = inv
    return GaussNewtonSolution(x, covariance, r, a, iterations, step, step < tolerance)


#: A Gauss-Newton step is halved until the cost falls (at most this many times): a step that diverges (a weakly
#: determined direction, a quadratic model taken beyond its fold) is shortened instead of followed.
MAX_HALVINGS = 40
#: Relative increase of the cost still accepted as "not larger" (rounding near the minimum).
COST_SLACK = 1e-6


def _damped_step(
    evaluate: Evaluate, x: NDArray[np.float64], free: NDArray[np.bool_], delta: NDArray[np.float64], cost: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Return the full Gauss-Newton step where it does not raise the cost, else the longest of its halvings that does not.

    A well-posed problem takes the full step every time (the iteration is the plain Gauss-Newton one, result for
    result); a trial whose cost rises (or whose model cannot be evaluated at the new point) takes half the step, and so on.
    Returns the new point, its residuals, Jacobian and cost, and the step factor taken per trial (0: no step).
    """
    factor = np.ones(x.shape[:-1])
    for _ in range(MAX_HALVINGS + 1):
        trial = x.copy()
        trial[..., free] += factor[:, None] * delta
        try:
            with np.errstate(all="ignore"):
                r, a = evaluate(trial)
                new_cost = np.einsum("tm,tm->t", r, r)
            ok = np.isfinite(new_cost) & np.isfinite(a).all(axis=(-2, -1)) & (new_cost <= cost * (1.0 + COST_SLACK) + 1e-300)
        except (InputError, NotDeterminedError):
            raise  # a described error passes through as it is (issue 29)
        except (ValueError, np.linalg.LinAlgError, FloatingPointError):  # e.g. the quadratic model's fold
            ok = np.zeros(x.shape[:-1], dtype=bool)
        if ok.all():
            return trial, r, a, new_cost, factor
        factor = np.where(ok, factor, 0.5 * factor)
    factor = np.where(ok, factor, 0.0)  # no step lowers the cost: stay (at a minimum within rounding)
    trial = x.copy()
    trial[..., free] += factor[:, None] * delta
    r, a = evaluate(trial)
    return trial, r, a, np.einsum("tm,tm->t", r, r), factor


def _solve(normal: NDArray[np.float64], rhs: NDArray[np.float64]) -> NDArray[np.float64]:
    """``normal⁻¹ rhs`` per trial; the minimum-norm solution where ``normal`` is singular."""
    try:
        return np.asarray(np.linalg.solve(normal, rhs[..., None])[..., 0], dtype=np.float64)
    except np.linalg.LinAlgError:
        return np.asarray(np.einsum("tij,tj->ti", np.linalg.pinv(normal, hermitian=True), rhs), dtype=np.float64)


def _inverse(normal: NDArray[np.float64]) -> NDArray[np.float64]:
    try:
        return np.asarray(np.linalg.inv(normal), dtype=np.float64)
    except np.linalg.LinAlgError:
        return np.asarray(np.linalg.pinv(normal, hermitian=True), dtype=np.float64)


def convergence_warning(solution: GaussNewtonSolution, trial: int = 0) -> str | None:
    """Return a warning when Gauss-Newton stopped at its iteration limit without converging, else None."""
    if solution.converged is None or bool(solution.converged[trial]):
        return None
    return (
        f"warning: Gauss-Newton did not converge in {solution.iterations} iterations (last step {solution.last_step[trial]:.3g} "
        "of the typical parameter magnitudes): the estimates may not be the least-squares solution"
    )


def goodness_of_fit_warning(
    chi2: float,
    dof: int,
    normalized_residuals: NDArray[np.float64],
    labels: tuple[str, ...],
    *,
    quantile: float = 0.999,
    worst: int = 3,
) -> str | None:
    r"""Return a warning when :math:`\chi^2` exceeds its ``quantile`` under the measured noise, else None.

    With the covariance built on the measured noise (never scaled by χ²_ν), a χ² far
    beyond :math:`\chi^2_\nu` means the data do not fit the model (a position off its
    orientation, an unmodelled effect, noise that is not white): the 1σ then understate
    the errors, and the user must be told.  The message names the observations with the
    largest normalized residuals (``residual / 1σ``).
    """
    from stableins.estimators.distributions import chi2_ppf

    if dof <= 0 or not np.isfinite(chi2):
        return None
    limit = chi2_ppf(quantile, dof)
    if chi2 <= limit:
        return None
    z = np.asarray(normalized_residuals, dtype=float)
    order = np.argsort(-np.abs(z))[:worst]
    largest = ", ".join(f"{labels[k]} {z[k]:+.1f}" for k in order) if len(labels) == z.size else ""
    return (
        f"warning: chi2 = {chi2:.4g} for nu = {dof} (chi2_red {chi2 / dof:.3g}) exceeds its {100 * quantile:g} % quantile "
        f"({limit / dof:.3g}·nu): the data do not fit the model within the measured noise and the 1σ understate the errors"
        + (f"; largest normalized residuals: {largest}" if largest else "")
    )
