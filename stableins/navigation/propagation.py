r"""Exact propagation of periodic error sources through the static-base INS error dynamics.

A constant error of the accelerometers or gyros of a polar-aligned, inertially held platform is, in the
navigation frame, a sum of harmonics of the Earth-rate phase ``Ωt`` (:mod:`stableins.navigation.dynamics`)::

    u(t) = Re Σ_k U_k e^{jkΩt}

(``U_0`` real).  With ``x(0) = 0`` and a step ``h``, the solution at ``t_{n+1} = t_n + h`` is exactly

    x_{n+1} = e^{Ah} x_n + Re Σ_k e^{jkΩ t_n} G_k B U_k,    G_k = ∫_0^h e^{A(h−s)} e^{jkΩs} ds

(variation of constants; ``G_k`` is the upper-right block of ``exp([[A, I], [0, jkΩ I]] h)``, Van Loan 1978).
There is no discretization error (the input is represented exactly, not held), and the resonance of the
undamped Earth-rate mode (eigenvalues ``±jΩ``, driven by an equatorial drift at exactly ``Ω``) needs no special
case: no eigen-decomposition is used, the ``t·sin Ωt`` growth comes out of ``G_1``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.linalg import expm

from stableins.conventions import EARTH_RATE
from stableins.navigation.dynamics import NavigationScenario

#: Samples of one sidereal revolution the harmonics are taken from (harmonics up to ``HARMONIC_SAMPLES/2 − 1``).
HARMONIC_SAMPLES = 32


def harmonics_of(samples: NDArray[np.float64]) -> NDArray[np.complex128]:
    """``U_k`` (K+1, ..., ) of periodic samples ``u(2πm/M)`` (M, ...), so that ``u(θ) = Re Σ_k U_k e^{jkθ}``.

    Exact for a trigonometric polynomial of degree below ``M/2``.
    """
    m = samples.shape[0]
    c = np.fft.fft(samples, axis=0) / m
    top = m // 2 - 1
    out = c[: top + 1].copy()
    out[1:] *= 2.0
    out[0] = out[0].real
    return out


def phase_grid(samples: int = HARMONIC_SAMPLES) -> NDArray[np.float64]:
    """Return the Earth-rate phases ``2πm/M`` the forcing is sampled at."""
    return 2.0 * np.pi * np.arange(samples) / samples


@dataclass(frozen=True)
class Propagator:
    """The exact one-step map of the error dynamics for harmonic inputs (module docstring).

    Attributes
    ----------
    step : float
        ``h`` [s].
    transition : ndarray (n, n)
        ``e^{Ah}``.
    input_maps : ndarray (K+1, n, p) complex
        ``G_k B``.
    """

    step: float
    transition: NDArray[np.float64]
    input_maps: NDArray[np.complex128]

    @classmethod
    def build(cls, scenario: NavigationScenario, step: float, harmonics: int) -> Propagator:
        """Return the map for ``harmonics + 1`` harmonics (0 … K) at step ``h`` [s]."""
        A, B = scenario.matrices()
        n = A.shape[0]
        transition = expm(A * step)
        maps = np.zeros((harmonics + 1, n, B.shape[1]), dtype=complex)
        for k in range(harmonics + 1):
            block = np.zeros((2 * n, 2 * n), dtype=complex)
            block[:n, :n] = A
            block[:n, n:] = np.eye(n)
            block[n:, n:] = 1j * k * EARTH_RATE * np.eye(n)
            maps[k] = expm(block * step)[:n, n:] @ B
        return cls(float(step), transition, maps)

    def run(self, forcing: NDArray[np.complex128], count: int) -> NDArray[np.float64]:
        """States at ``t = 0, h, …, count·h`` for forcings ``U`` (K+1, p, m) of ``m`` sources: (count+1, n, m)."""
        kmax = forcing.shape[0]
        drive = np.einsum("knp,kpm->knm", self.input_maps[:kmax], forcing)  # G_k B U_k per source
        n, m = self.transition.shape[0], forcing.shape[2]
        out = np.zeros((count + 1, n, m))
        phases = np.exp(1j * EARTH_RATE * self.step * np.outer(np.arange(count), np.arange(kmax)))  # e^{jkΩ t_n}
        x = np.zeros((n, m))
        for i in range(count):
            x = self.transition @ x + np.einsum("k,knm->nm", phases[i], drive).real
            out[i + 1] = x
        return out
