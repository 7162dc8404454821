r"""The time-domain INS error dynamics of the system-level world, discretized exactly.

The equations (static base, NED, ``v = 0``; Britting 1971 ch. 6; Titterton & Weston 2004
Sec. 12.3.1) and the numerics (exact ZOH discretization per eigenmode, run by
:func:`scipy.signal.lfilter` with its state carried between chunks) are written out in
:mod:`stableins.simulator.system`, which drives them sample by sample.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from stableins.conventions import EARTH_RATE

SIMULATED_STATES = (
    "latitude_error",
    "velocity_north",
    "velocity_east",
    "phi_north",
    "phi_east",
    "phi_down",
    "height_error",
    "velocity_down",
    "vertical_integrator",
)
SIMULATED_INPUTS = ("df_north", "df_east", "df_down", "drift_north", "drift_east", "drift_down")


def error_dynamics(latitude: float, damping: dict[str, float]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Continuous INS error dynamics ``x' = A x + B u`` of the module docstring.

    Parameters
    ----------
    latitude : float
        [rad].
    damping : dict
        ``gravity``, ``R``, ``horizontal_gain`` (``c``), ``k1``, ``k2``, ``k3``
        (:func:`stableins.simulator.truth.damping_parameters`).

    Returns
    -------
    A : ndarray (9, 9), B : ndarray (9, 6)
        States :data:`SIMULATED_STATES`, inputs :data:`SIMULATED_INPUTS`.
    """
    g, radius, c = damping["gravity"], damping["R"], damping["horizontal_gain"]
    k1, k2, k3 = damping["k1"], damping["k2"], damping["k3"]
    w = EARTH_RATE
    sl, cl, tl = np.sin(latitude), np.cos(latitude), np.tan(latitude)
    A = np.zeros((9, 9))
    L, VN, VE, PN, PE, PD, H, VD, BV = range(9)
    A[L, VN] = 1 / radius
    A[VN, PE], A[VN, VE], A[VN, VN] = g, -2 * w * sl, -c
    A[VE, PN], A[VE, VN], A[VE, VD], A[VE, VE] = -g, 2 * w * sl, 2 * w * cl, -c
    A[PN, L], A[PN, PE], A[PN, VE] = -w * sl, -w * sl, 1 / radius
    A[PE, PN], A[PE, PD], A[PE, VN] = w * sl, w * cl, -1 / radius
    A[PD, L], A[PD, PE], A[PD, VE] = -w * cl, -w * cl, -tl / radius
    A[H, VD], A[H, H] = -1.0, -k1
    A[VD, VE], A[VD, H], A[VD, BV] = -2 * w * cl, -2 * g / radius + k2, 1.0
    A[BV, H] = k3
    B = np.zeros((9, 6))
    B[VN, 0] = B[VE, 1] = B[VD, 2] = 1.0
    B[PN, 3] = B[PE, 4] = B[PD, 5] = -1.0
    return A, B


@dataclass(frozen=True)
class ModalRecursion:
    """Exact ZOH discretization of ``x' = A x + B u`` in modal form (module docstring).

    The arrays are complex (real only when every eigenvalue of ``A`` is real, as numpy's ``eig`` returns them).

    Attributes
    ----------
    eigenvalues : ndarray (m,) complex
        ``λ = exp(μ dt)``.
    input_gain : ndarray (m, p) complex
        ``diag((λ − 1)/μ) V⁻¹ B``.
    modes : ndarray (m, m) complex
        ``V``.
    to_modes : ndarray (m, m) complex
        ``V⁻¹``.
    """

    eigenvalues: NDArray[np.inexact[Any]]
    input_gain: NDArray[np.inexact[Any]]
    modes: NDArray[np.inexact[Any]]
    to_modes: NDArray[np.inexact[Any]]

    @property
    def _partner(self) -> NDArray[np.int64]:
        """Index of each complex mode's conjugate partner (−1 for real modes).

        The real system's response is the sum over one mode of each pair, doubled, so only half
        of the complex modes are filtered.
        """
        cached = self.__dict__.get("_partner_cache")
        if cached is None:
            lam = self.eigenvalues
            cached = np.full(len(lam), -1)
            for i in range(len(lam)):
                if lam[i].imag != 0 and cached[i] < 0:
                    j = int(np.argmin(np.abs(lam - np.conj(lam[i])) + np.where(np.arange(len(lam)) == i, np.inf, 0)))
                    cached[i], cached[j] = j, i
            self.__dict__["_partner_cache"] = cached
        return cached

    @classmethod
    def discretize(cls, A: NDArray[np.float64], B: NDArray[np.float64], dt: float) -> ModalRecursion:
        """Return the exact zero-order-hold recursion of ``x' = A x + B u`` over ``dt`` [s], mode by mode ("Numerics" above)."""
        mu, v = np.linalg.eig(A)
        condition = np.linalg.cond(v)
        if not condition < 1e10:
            raise ValueError(f"error dynamics are (nearly) defective, eigenvector condition {condition:.2e}")
        v_inv = np.linalg.inv(v)
        phi = np.exp(mu * dt)
        with np.errstate(invalid="ignore", divide="ignore"):
            hold = np.where(mu != 0, np.expm1(mu * dt) / np.where(mu != 0, mu, 1.0), dt)
        return cls(phi, hold[:, None] * (v_inv @ B), v, v_inv)

    def run(self, u: NDArray[np.float64], z0: NDArray[np.inexact[Any]]) -> tuple[NDArray[np.float64], NDArray[np.inexact[Any]]]:
        """States ``x_k`` for inputs ``u_k`` (n, p), modal state ``z0`` at the first sample; returns (x, z after the last input)."""
        from scipy.signal import lfilter

        n, p = u.shape
        m = len(self.eigenvalues)
        x = np.zeros((n, m))
        z_end = np.empty(m, dtype=complex)
        for i in range(m):
            lam = self.eigenvalues[i]
            if lam.imag < 0 and self._partner[i] >= 0:
                continue  # the conjugate of its partner's mode: filled in below
            w = np.zeros(n, dtype=complex)
            for j in range(p):  # fixed summation order: identical results for any chunking
                if self.input_gain[i, j] != 0:
                    w += self.input_gain[i, j] * u[:, j]
            z, zf = lfilter([0.0, 1.0], [1.0, -lam], w, zi=[z0[i]])
            z_end[i] = zf[0]
            partner = self._partner[i]
            weight = 2.0 if partner >= 0 else 1.0  # a conjugate pair adds up to twice the real part
            x += weight * (self.modes[None, :, i] * z[:, None]).real
            if partner >= 0:
                z_end[partner] = np.conj(zf[0])
        return x, z_end
