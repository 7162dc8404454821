r"""Error sources of a space-stable INS as harmonic forcings of the navigation error dynamics.

Per unit of one parameter (SI), on the polar-aligned platform of :mod:`stableins.navigation.dynamics`:

* **Accelerometer terms** (scale factor, bias, installation angle, K2, discovered output terms): a residual
  ``Δp = true − installed`` of the term makes the compensated specific force wrong by
  ``Δf^p = (∂f^a/∂f^p)^{-1} (∂f^a/∂p) Δp`` (the exact inverse of Eq. 8 linearized at the record's values:
  :meth:`stableins.errormodel.ErrorModel.jacobian` and ``jacobian_specific_force``), evaluated at
  ``f^p = C_n^p (0, 0, −g)`` around one sidereal revolution; the navigation frame sees ``Δf^n = C_p^n Δf^p``.
  For a bias ``b_x``, for example, ``Δf_N = −b_x sinL cos S``, ``Δf_E = −b_x sin S``, ``Δf_D = −b_x cosL cos S``.
* **Gyro drift** ``ε^p`` (``gyro_drift_*``): ``ε^n = C_p^n ε^p``.  The polar component (``z_p``) is constant in the
  navigation frame; the equatorial ones turn at exactly the Earth rate.
* **Gimbal zero offsets** (``theta10/20/30``): the computed attitude uses the readings plus the installed offsets,
  so a residual offset rotates the output attitude by a constant angle about that gimbal's axis (body-fixed for
  the inner and middle gimbals, the polar axis for the platform axis); positions and velocities do not see it
  (the navigation computer's platform-to-local DCM comes from the alignment, not from the readings).

Every forcing is sampled at :data:`stableins.navigation.propagation.HARMONIC_SAMPLES` phases of one revolution
and turned into harmonics (exact: the core model gives harmonics up to the third, K2 the highest).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from stableins.conventions import dcm_body_to_platform, euler_from_dcm, polar_alignment_readings
from stableins.errormodel import ErrorModel, Term, TermInputs, TermKind
from stableins.navigation.dynamics import NavigationScenario
from stableins.navigation.propagation import harmonics_of, phase_grid

#: Kinds that act on the accelerometer outputs.
ACCELEROMETER_KINDS = (TermKind.SCALE_FACTOR, TermKind.BIAS, TermKind.INSTALLATION, TermKind.NONLINEARITY, TermKind.ADDITIVE)
#: Perturbation of a gimbal offset used to take its (linear) attitude error [rad].
GIMBAL_STEP = 1e-6


@dataclass(frozen=True)
class UnitForcing:
    """What one unit (SI) of a parameter does: harmonic forcing of the dynamics and of the output attitude.

    Attributes
    ----------
    forcing : ndarray (K+1, 6) complex
        ``U_k`` of ``(Δf^n, ε^n)`` (:data:`stableins.navigation.dynamics.INPUT_NAMES`).
    attitude : ndarray (K+1, 3) complex
        ``O_k`` of a direct error of the output (pitch, roll, heading) [rad].
    """

    forcing: NDArray[np.complex128]
    attitude: NDArray[np.complex128]


@dataclass(frozen=True)
class LeftOut:
    """A record term the budget does not propagate, and why."""

    id: str
    reason: str


def _platform_samples(scenario: NavigationScenario) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    theta = phase_grid()
    nav_to_platform = scenario.nav_to_platform(theta)
    return nav_to_platform, -scenario.gravity * nav_to_platform[:, :, 2]


def _to_nav(nav_to_platform: NDArray[np.float64], vectors: NDArray[np.float64]) -> NDArray[np.float64]:
    return np.einsum("mji,mj->mi", nav_to_platform, vectors)


def _forcing(nav_samples: NDArray[np.float64] | None = None, drift_samples: NDArray[np.float64] | None = None) -> UnitForcing:
    m = len(phase_grid())
    u = np.zeros((m, 6))
    if nav_samples is not None:
        u[:, :3] = nav_samples
    if drift_samples is not None:
        u[:, 3:] = drift_samples
    harmonics = harmonics_of(u)
    return UnitForcing(harmonics, np.zeros((harmonics.shape[0], 3), dtype=complex))


def accelerometer_forcing(model: ErrorModel, values: Mapping[str, float], term: Term, scenario: NavigationScenario) -> UnitForcing:
    """Return the forcing of one unit of an accelerometer term (module docstring).

    Raises
    ------
    ValueError
        The term's regressor needs an input a static base at the reference temperature does not give
        (temperature, time, slew direction ...): the message names it.
    """
    core = ErrorModel(tuple(t for t in model if t.kind in ACCELEROMETER_KINDS and t.kind != TermKind.ADDITIVE))
    alone = core if term.id in core else ErrorModel(core.terms + (term,))
    nav_to_platform, f_p = _platform_samples(scenario)
    column = alone.jacobian(f_p, values, TermInputs(f_p))[..., alone.index(term.id)]
    gain = core.jacobian_specific_force(f_p, values)
    delta_platform = np.asarray(np.linalg.solve(gain, column[..., None])[..., 0], dtype=np.float64)
    return _forcing(nav_samples=_to_nav(nav_to_platform, delta_platform))


def drift_forcing(axis: int, scenario: NavigationScenario) -> UnitForcing:
    """Return the forcing of one rad/s of constant drift of platform gyro ``axis`` (0, 1, 2 = x_p, y_p, z_p)."""
    nav_to_platform, _ = _platform_samples(scenario)
    drift = np.zeros((len(nav_to_platform), 3))
    drift[:, axis] = 1.0
    return _forcing(drift_samples=_to_nav(nav_to_platform, drift))


def g_sensitivity_forcing(gyro_axis: int, force_axis: int, scenario: NavigationScenario) -> UnitForcing:
    r"""Return the forcing of one rad/s per m/s² of g-sensitivity ``Dg_ab`` (gyro ``gyro_axis``, specific force ``force_axis``).

    On a static base the specific force is the reaction to gravity, ``f_p = C_n^p (0, 0, −g)ᵀ`` (the samples of
    :func:`_platform_samples`), so the g-sensitivity is a drift :math:`\varepsilon_a = D_{g,ab} f_{p,b}` of gyro ``a``
    (output error, as ``gyro_drift_a``; Cai et al. 2016 Eq. 1): constant along the polar axis (``f_{p,z} = g sin L`` on a
    polar-aligned platform) and modulated at the Earth rate across it.
    """
    nav_to_platform, specific_force = _platform_samples(scenario)
    drift = np.zeros((len(nav_to_platform), 3))
    drift[:, gyro_axis] = specific_force[:, force_axis]
    return _forcing(drift_samples=_to_nav(nav_to_platform, drift))


def gimbal_forcing(index: int, scenario: NavigationScenario) -> UnitForcing:
    """Output-attitude error (pitch, roll, heading) of one radian of residual zero offset of gimbal ``index`` (0, 1, 2)."""
    config = scenario.configuration
    theta = phase_grid()
    nav_to_platform = scenario.nav_to_platform(theta)
    _, middle = polar_alignment_readings(scenario.latitude, config)
    actual = np.stack([-config.senses[0] * (scenario.earth_angle + theta), np.zeros_like(theta), np.full_like(theta, middle)], axis=-1)
    computed = actual.copy()
    computed[:, index] -= GIMBAL_STEP  # readings + installed offsets = actual − (true − installed)
    body_to_platform = dcm_body_to_platform(computed[:, 0], computed[:, 1], computed[:, 2], 0.0, config)
    nav_to_body_computed = body_to_platform.swapaxes(1, 2) @ nav_to_platform
    yaw, pitch, roll = euler_from_dcm(nav_to_body_computed)
    wrap = (yaw + np.pi) % (2 * np.pi) - np.pi
    samples = np.stack([pitch, roll, wrap], axis=-1) / GIMBAL_STEP
    harmonics = harmonics_of(samples)
    return UnitForcing(np.zeros((harmonics.shape[0], 6), dtype=complex), harmonics)
