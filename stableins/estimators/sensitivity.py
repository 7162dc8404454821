r"""Type B sensitivity of the device-level coarse rows to the gimbal angle readings.

The coarse observation of dwell j is ``h_j(p, θ; r_j)`` with ``f^p_j = C_b^p(r_j + θ) C_n^b [0, 0, −g]``
(:mod:`stableins.estimators.coarse`): a reading enters exactly as the zero offset does, so an error
δr_{j,i} of the reading of gimbal i in dwell j moves that dwell's three outputs by
``D_{j,i} = ∂h_j/∂θ_i`` — the θ_i column of the Jacobian, restricted to the dwell.  A static reading
error common to every dwell is a zero offset, estimated as θ; what the budget needs is the part that
differs from dwell to dwell (the sensor's static accuracy at each angle), independent between dwells.

With ``W`` the whitening of the fit (``W Wᵀ = Cov(o)⁻¹``, slow noise included) and ``A = W H`` its
whitened Jacobian, the gradient of the likelihood ``g = Aᵀ W (o − h)`` moves by
``∂g/∂r_{j,i} = −Aᵀ W E_{j,i}`` (``E_{j,i}`` the column ``D_{j,i}`` on the rows of dwell j; the change
of ``A`` itself times the noise-sized residuals is smaller by the ratio of noise to signal, 1e-4).
So, per unit variance of every reading (fine rows do not read the angles: zero there),

.. math:: S = \sum_{j,i} (A^T W E_{j,i})(A^T W E_{j,i})^T = A^T W E E^T W^T A .

Tested against re-running the fit with one reading moved (``tests/test_budget.py``).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from stableins.errormodel import GIMBAL_IDS
from stableins.estimators.result import InputSensitivity


def angle_reading_sensitivity(problem: Any, x: NDArray[np.float64], ids: Sequence[str]) -> InputSensitivity:
    """:class:`InputSensitivity` ``angle_sensors.readings`` of a coarse (or joint coarse + fine) problem at ``x``.

    ``problem`` is a :class:`~stableins.estimators.coarse.CoarseProblem` or a
    :class:`~stableins.estimators.joint.JointProblem` with one trial; ``x`` the solution ``(n,)``.
    """
    gradients = angle_reading_gradients(problem, x)
    return InputSensitivity("angle_sensors.readings", "rad", tuple(ids), 0.0, covariance=gradients @ gradients.T)


def angle_reading_gradients(problem: Any, x: NDArray[np.float64]) -> NDArray[np.float64]:
    """``∂g/∂r_{j,i} = −Aᵀ W E_{j,i}`` ``(n, 3m)``, column ``3j + i`` for the reading of gimbal i (platform, inner, middle) in dwell j."""
    from scipy.linalg import solve_triangular

    x = np.asarray(x, dtype=float)[None]
    coarse = getattr(problem, "coarse", problem)
    model = coarse.model
    _, jacobian = coarse.predict(x)  # (1, m, 3, n)
    derivative = jacobian[0][..., [model.index(g) for g in GIMBAL_IDS]]  # (m, 3 outputs, 3 gimbals)
    m = derivative.shape[0]
    columns = np.zeros((3 * m, 3 * m))  # rows: dwell-major outputs (3j + a); columns: (3j + i) readings
    for j in range(m):
        columns[3 * j : 3 * j + 3, 3 * j : 3 * j + 3] = derivative[j]
    _, whitened_jacobian = problem.weighted(x)
    a = whitened_jacobian[0]
    if hasattr(problem, "raw"):  # joint problem: one full observation covariance (coarse rows first)
        _, _, cov_o = problem.raw(x)
        full = np.zeros((cov_o.shape[-1], 3 * m))
        full[: 3 * m] = columns
        whitened = solve_triangular(np.linalg.cholesky(cov_o[0]), full, lower=True)
    else:
        w = coarse.whitening()
        if w is None:
            whitened = columns / coarse.sigma[0].reshape(-1)[:, None]
        else:  # per axis a: rows 3j + a mix over the dwells with w[a]
            by_axis = columns.reshape(m, 3, 3 * m)
            whitened = np.einsum("ajk,kac->jac", w[0], by_axis).reshape(3 * m, 3 * m)
    return -a.T @ whitened
