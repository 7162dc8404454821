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

Evaluate = Callable[[NDArray[np.float64]], tuple[NDArray[np.float64], NDArray[np.float64]]]


@dataclass(frozen=True)
class GaussNewtonSolution:
    """Batched solution: ``x (T, n)``, ``covariance (T, n, n)`` (zero rows for fixed
    parameters), weighted residuals ``(T, m)``, weighted Jacobian ``(T, m, n)``,
    iterations used and the last scaled step."""

    x: NDArray[np.float64]
    covariance: NDArray[np.float64]
    weighted_residuals: NDArray[np.float64]
    weighted_jacobian: NDArray[np.float64]
    iterations: int
    last_step: NDArray[np.float64]


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
    for iterations in range(1, max_iterations + 1):  # noqa: B007
        r, a = evaluate(x)
        a_s = a[..., free] * d
        normal = np.einsum("tmi,tmj->tij", a_s, a_s)
        rhs = np.einsum("tmi,tm->ti", a_s, r)
        dz = np.linalg.solve(normal, rhs[..., None])[..., 0]
        x[..., free] += dz * d
        step = np.abs(dz).max(axis=-1)
        if np.all(step < tolerance):
            break
    r, a = evaluate(x)
    a_s = a[..., free] * d
    normal = np.einsum("tmi,tmj->tij", a_s, a_s)
    covariance = np.zeros(x.shape + (x.shape[-1],))
    inv = np.linalg.inv(normal) * d[:, None] * d[None, :]
    idx = np.flatnonzero(free)
    covariance[..., idx[:, None], idx[None, :]] = inv
    return GaussNewtonSolution(x, covariance, r, a, iterations, step)
