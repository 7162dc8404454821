r"""The simulator's own accelerometer physics: Wu et al. 2018 Eqs. 5, 6 and 8, written again from docs/conventions.md.

The truth simulator does not use the estimators' model (:mod:`stableins.errormodel`, :mod:`stableins.terms`,
:mod:`stableins.coremodel`): a sign or axis error there would be invisible to every simulate-then-fit test.  This
module is a second, separate implementation of what docs/conventions.md ("Accelerometer frame and error model")
states, and ``tests/test_simulator_physics.py`` checks that the two agree term by term and sign by sign.

Installation matrix (Eq. 5, signs restored; ``β_ij`` turns sensitive axis ``i`` right-handedly about platform
axis ``j``)::

    C_p^a = [[1, βxz, −βxy], [−βyz, 1, βyx], [βzy, −βzx, 1]]

Output (Eq. 6, signs restored, element-wise square) with the additive effects ``Σ_k p_k r_k`` evaluated on ``f^p``::

    f^a = SF⁻¹ C_p^a f^p + Σ_k p_k r_k + δb + K ∘ (f^a − δb)²

solved exactly on each axis: ``u = f^a − δb`` obeys ``u − K u² = w`` with ``w = SF⁻¹ C_p^a f^p + Σ_k p_k r_k``, and
the root that tends to ``w`` as ``K → 0`` is ``u = 2w / (1 + √(1 − 4Kw))``.  Its inverse (Eq. 8, what the simulated
navigation computer compensates with) is ``f^p = (C_p^a)⁻¹ SF (u − K u² − Σ_k p_k r_k)``, by fixed-point iteration in
``f^p`` when additive effects are installed.

The parameter table below (ids, kinds, reference values, nominal sizes) is the simulator's own too: it is what
:meth:`stableins.simulator.truth.Truth.draw` draws from.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stableins.conventions import ARCSEC, AXES, GIMBAL_IDS, MICRO_G, MICRO_G_PER_G2

#: The six installation angles, in the order of the parameter table.
INSTALLATION_IDS = ("beta_xy", "beta_xz", "beta_yx", "beta_yz", "beta_zx", "beta_zy")
#: The platform's gyro numbers a calibration record may carry and the simulated navigation computer does not
#: install: constant drifts ``gyro_drift_a`` and g-sensitivities ``Dg_ab`` (docs/conventions.md, "Term kinds").
UNINSTALLED_GYRO_IDS = tuple(f"gyro_drift_{a}" for a in AXES) + tuple(f"Dg_{a}{b}" for a in AXES for b in AXES)


@dataclass(frozen=True)
class ParameterSpec:
    """One parameter of the simulated instrument: id, kind, the value of an ideal instrument and a typical size [SI]."""

    id: str
    kind: str
    reference: float
    nominal: float


def _parameter_table() -> tuple[ParameterSpec, ...]:
    """Return the instrument's parameters in the order drawn (docs/conventions.md, "Parameter ids")."""
    table = [ParameterSpec(f"sf_{a}", "scale_factor", 1.0, 1e-4) for a in AXES]
    table += [ParameterSpec(f"bias_{a}", "bias", 0.0, 100 * MICRO_G) for a in AXES]
    table += [ParameterSpec(b, "installation", 0.0, 30 * ARCSEC) for b in INSTALLATION_IDS]
    table += [ParameterSpec(f"K2_{a}", "nonlinearity", 0.0, 20 * MICRO_G_PER_G2) for a in AXES]
    table += [ParameterSpec(g, "gimbal", 0.0, 60 * ARCSEC) for g in GIMBAL_IDS]
    return tuple(table)


#: Every parameter of the simulated instrument (scale factors, biases, installation angles, quadratic
#: nonlinearities, angle-sensor zero offsets), in the order :meth:`~stableins.simulator.truth.Truth.draw` draws them.
PARAMETERS: tuple[ParameterSpec, ...] = _parameter_table()
#: Parameter ids a truth may set.
PARAMETER_IDS: tuple[str, ...] = tuple(p.id for p in PARAMETERS)
#: The value of an ideal instrument for each parameter id (1 for scale factors, 0 otherwise).
REFERENCE: Mapping[str, float] = {p.id: p.reference for p in PARAMETERS}


def simulated_parameters(*, nonlinear: bool = True) -> tuple[ParameterSpec, ...]:
    """Return the parameter table, without the quadratic nonlinearities unless ``nonlinear``."""
    return tuple(p for p in PARAMETERS if nonlinear or p.kind != "nonlinearity")


@dataclass(frozen=True)
class SensorInputs:
    """What an additive effect may depend on, sample by sample (leading dims ``...``).

    Attributes
    ----------
    specific_force : ndarray (..., 3)
        ``f^p`` [m/s²], the input resolved on the nominal sensitive axes.
    temperature : ndarray (...), optional
        Instrument temperature minus the reference temperature [K].
    time : ndarray (...), optional
        Session time [s].
    slew_direction : ndarray (..., 3), optional
        Hysteresis state (+1/−1/0) of each axis (:func:`stableins.simulator.effects.hysteresis_state`).
    angular_rate, angular_acceleration : ndarray (..., 3), optional
        Platform angular rate [rad/s] and acceleration [rad/s²] relative to the base, p-frame.
    """

    specific_force: NDArray[np.float64]
    temperature: NDArray[np.float64] | None = None
    time: NDArray[np.float64] | None = None
    slew_direction: NDArray[np.float64] | None = None
    angular_rate: NDArray[np.float64] | None = None
    angular_acceleration: NDArray[np.float64] | None = None

    def require(self, name: str, effect_id: str) -> NDArray[np.float64]:
        """Return input ``name``, or raise ``ValueError`` naming the effect that needs it."""
        value = getattr(self, name)
        if value is None:
            raise ValueError(f"effect {effect_id!r} needs the input {name!r}, which this simulation does not provide")
        return np.asarray(value, dtype=float)


#: An additive effect's regressor: ``SensorInputs -> (..., 3)`` output change per unit value [m/s² per SI unit].
Regressor = Callable[[SensorInputs], NDArray[np.float64]]


def installation_matrix(values: Mapping[str, Any]) -> NDArray[np.float64]:
    r"""``C_p^a`` (Eq. 5, signs restored) from the installation angles in ``values`` (absent ones 0) [rad].

    .. math::
        C_p^a = \begin{bmatrix} 1 & \beta_{xz} & -\beta_{xy}\\ -\beta_{yz} & 1 & \beta_{yx}\\
                \beta_{zy} & -\beta_{zx} & 1\end{bmatrix}

    Row ``i`` is sensitive axis ``i`` in the platform frame: a right-handed turn ``β_ij`` of axis ``i`` about platform
    axis ``j`` tilts it toward the third axis ``k`` (``e_i + β_ij e_j × e_i``), e.g. ``β_xz`` tilts ``x`` toward ``+y``
    and ``β_xy`` toward ``−z`` (docs/conventions.md).
    """
    xy, xz, yx, yz, zx, zy = np.broadcast_arrays(*(np.asarray(values.get(b, 0.0), dtype=float) for b in INSTALLATION_IDS))
    out = np.zeros(xy.shape + (3, 3))
    out[..., 0, 0] = out[..., 1, 1] = out[..., 2, 2] = 1.0
    out[..., 0, 1], out[..., 0, 2] = xz, -xy
    out[..., 1, 0], out[..., 1, 2] = -yz, yx
    out[..., 2, 0], out[..., 2, 1] = zy, -zx
    return out


def _per_axis(values: Mapping[str, Any], prefix: str, default: float) -> NDArray[np.float64]:
    """``(values[prefix_x], values[prefix_y], values[prefix_z])`` broadcast to ``(..., 3)``, absent ones ``default``."""
    return np.stack(np.broadcast_arrays(*(np.asarray(values.get(f"{prefix}_{a}", default), dtype=float) for a in AXES)), axis=-1)


def quadratic_root(w: NDArray[np.float64], k: NDArray[np.float64]) -> NDArray[np.float64]:
    """Return the root of ``u − k u² = w`` that tends to ``w`` as ``k → 0``: ``u = 2w / (1 + √(1 − 4kw))`` (no cancellation).

    Raises
    ------
    ValueError
        ``1 − 4kw ≤ 0``: the quadratic nonlinearity folds the output (no real instrument).
    """
    discriminant = 1.0 - 4.0 * k * w
    if np.any(discriminant <= 0.0):
        raise ValueError("quadratic nonlinearity too large: K2·f reaches the fold of Eq. 6 (1 − 4 K w ≤ 0)")
    return 2.0 * w / (1.0 + np.sqrt(discriminant))


@dataclass(frozen=True)
class Accelerometer:
    """The accelerometer triad of a simulated world: parameter values and the additive effects it carries.

    Parameters
    ----------
    values : mapping
        Parameter values [SI] by id (the table :data:`PARAMETERS`; absent ids at their reference) and the values of
        the additive effects.
    effects : sequence of (id, regressor)
        The additive effects, in the order their outputs are summed (an effect whose value is 0 adds nothing).
    """

    values: Mapping[str, Any]
    effects: Sequence[tuple[str, Regressor]] = ()

    def _core(self) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """Scale factors, biases, quadratic coefficients (each ``(..., 3)``) and ``C_p^a``."""
        v = self.values
        return _per_axis(v, "sf", 1.0), _per_axis(v, "bias", 0.0), _per_axis(v, "K2", 0.0), installation_matrix(v)

    def _additive(self, f_p: NDArray[np.float64], inputs: SensorInputs | None) -> NDArray[np.float64] | float:
        """``Σ_k p_k r_k(f^p, ...)`` [m/s²] (0.0 without additive effects)."""
        if not self.effects:
            return 0.0
        at = SensorInputs(f_p) if inputs is None else replace(inputs, specific_force=f_p)
        total = np.zeros_like(f_p)
        for effect_id, regressor in self.effects:
            value = np.asarray(self.values.get(effect_id, 0.0), dtype=float)
            if np.any(value != 0.0):
                total = total + value[..., None] * regressor(at)
        return total

    def output(self, specific_force_platform: ArrayLike, inputs: SensorInputs | None = None) -> NDArray[np.float64]:
        """Return the accelerometer output ``f^a`` [m/s²] ``(..., 3)`` of the platform-frame specific force ``f^p`` (Eq. 6, exact)."""
        scale_factor, bias, quadratic, installation = self._core()
        f_p = np.asarray(specific_force_platform, dtype=float)
        w = np.einsum("...ij,...j->...i", installation, f_p) / scale_factor + self._additive(f_p, inputs)
        return bias + quadratic_root(w, quadratic)

    def specific_force(self, output: ArrayLike, inputs: SensorInputs | None = None, *, iterations: int = 4) -> NDArray[np.float64]:
        """Return the platform-frame specific force ``f^p`` [m/s²] whose output is ``output`` (Eq. 8, the exact inverse).

        With additive effects, ``iterations`` fixed-point steps in ``f^p`` (their regressors are evaluated on ``f^p``;
        they are 1e-4 relative at most, so each step gains four orders of magnitude).
        """
        scale_factor, bias, quadratic, installation = self._core()
        u = np.asarray(output, dtype=float) - bias
        w = u - quadratic * u**2
        to_platform = np.linalg.inv(installation)
        f_p = np.einsum("...ij,...j->...i", to_platform, scale_factor * w)
        for _ in range(iterations if self.effects else 0):
            f_p = np.einsum("...ij,...j->...i", to_platform, scale_factor * (w - self._additive(f_p, inputs)))
        return f_p
