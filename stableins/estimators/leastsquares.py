r"""The least-squares problem of a fit: its interface, and the device dwell forward model written once.

:class:`Problem` is the one interface a fitted problem offers (data + model → prediction, Jacobian, whitening, fit):
discovery ranks, refits and diagnoses through it, whatever the rows are (device dwells, a system record's bins, the
reading slopes of the gyro drift).  Its implementations are the dwell problem of discovery
(:class:`stableins.discovery.problem.DwellProblem`) and the linear problem (:class:`stableins.discovery.linear.LinearProblem`).

:func:`dwell_forward` is the device forward model of a static dwell and its analytic Jacobian, the one the coarse stage
fits (:class:`stableins.estimators.coarse.CoarseProblem`, hence the joint fit and the design's Cramér–Rao bound) and
the one discovery ranks against (:meth:`stableins.discovery.problem.DwellProblem.evaluate`):

.. math::
    \bar y_j = F\big(f^p(r_j;\ \theta, \kappa),\ p\big),\qquad
    f^p = C_b^p(r_j + \theta;\ \kappa)\, C_n^b(\kappa)\, (0, 0, -g)^T

(Wu et al. 2018 Eqs. 6–7 with the exact gimbal kinematics of :func:`stableins.platform.specific_force_and_jacobian`),
``F`` the exact forward model of :meth:`stableins.errormodel.ErrorModel.forward`, ``θ`` the angle-sensor zero offsets
and ``κ`` the kinematic (test-equipment) effects of :data:`stableins.platform.KINEMATIC_IDS`.  The Jacobian of every
instrument term is :meth:`~stableins.errormodel.ErrorModel.jacobian`; the zero offsets and kinematic effects act through
``f^p``, so their columns are the chain rule

.. math:: \frac{\partial \bar y}{\partial q} = \frac{\partial F}{\partial f^p}\,\frac{\partial f^p}{\partial q}.

``∂F/∂f^p`` is :meth:`~stableins.errormodel.ErrorModel.jacobian_specific_force`, which holds the additive terms fixed:
exact where they are 0 (a candidate's column), off by a relative amount of the order of their size otherwise
(``tests/test_leastsquares.py`` measures both).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stableins.conventions import GimbalConfiguration
from stableins.errormodel import GIMBAL_IDS, ErrorModel, Term, TermInputs
from stableins.estimators.result import FitResult, Stage
from stableins.platform import KINEMATIC_IDS, specific_force_and_jacobian


class Problem(Protocol):
    """A fitted least-squares problem: data + model → prediction, Jacobian, whitening, fit.

    Attributes
    ----------
    stage : Stage
        What the rows are (the ``stage`` of the :class:`FitResult` the problem returns).
    static : bool
        The rows are the static dwells of a device session, independent once whitened: the ranking then fixes its
        flags' level from the exact null distribution and tests a laboratory-fixed signature
        (:func:`stableins.discovery.ranking.rank`); False for a system record's bins and for linear problems.
    """

    stage: Stage
    static: bool

    def fit(self, model: ErrorModel, start: Mapping[str, float] | None = None) -> FitResult:
        """Return the fit of ``model`` to the data, from ``start`` (ids missing there start at their reference)."""
        ...

    def design(self, result: FitResult) -> NDArray[np.float64]:
        """Return ``∂prediction/∂p`` at the estimate for the parameters with status ``"estimated"``, shape (m, k)."""
        ...

    def candidate_columns(self, terms: Sequence[Term], result: FitResult) -> NDArray[np.float64]:
        """Return ``∂prediction/∂p`` of terms not in the model (at value 0), shape (m, len(terms))."""
        ...

    def whiten(self, v: ArrayLike) -> NDArray[np.float64]:
        """Return ``R^{-1/2} v`` for observation-ordered vectors (m,) or matrices (m, k), ``R`` the rows' covariance."""
        ...


@dataclass(frozen=True)
class DwellForward:
    """The dwell forward model evaluated at one set of parameter values (:func:`dwell_forward`).

    Attributes
    ----------
    output : ndarray (..., 3)
        Model accelerometer output ``F(f^p, p)`` of each dwell [m/s²].
    jacobian : ndarray (..., 3, n)
        ``∂output/∂p`` for every term of the model, zero offsets and kinematic effects by the chain rule.
    specific_force : ndarray (..., 3)
        Platform-frame specific force ``f^p`` of each dwell [m/s²].
    inputs : TermInputs
        What the model's additive terms were evaluated on.
    """

    output: NDArray[np.float64]
    jacobian: NDArray[np.float64]
    specific_force: NDArray[np.float64]
    inputs: TermInputs


def kinematic_ids(model: ErrorModel) -> tuple[str, ...]:
    """Return the ids whose columns go through ``f^p``: the three zero offsets and the model's kinematic effects."""
    return tuple(i for i in GIMBAL_IDS + KINEMATIC_IDS if i in GIMBAL_IDS or i in model)


def dwell_forward(
    model: ErrorModel,
    values: Mapping[str, ArrayLike],
    readings: ArrayLike,
    gravity: ArrayLike,
    *,
    base_dcm: ArrayLike,
    configuration: GimbalConfiguration,
    inputs: TermInputs | None = None,
) -> DwellForward:
    """Return the dwell forward model and its analytic Jacobian at ``values`` (module docstring).

    Parameters
    ----------
    model : ErrorModel
        The model; its zero offsets (absent: 0) and kinematic effects act through ``f^p``.
    values : mapping
        Parameter values [SI]: floats, or arrays ``(T, 1)`` for a batch of ``T`` trials (the coarse stage).
    readings : array_like (..., m, 3)
        Mean angle-sensor readings of each dwell [rad].
    gravity : float or array_like
        Local gravity [m/s²], broadcast against the leading dimensions of ``readings``.
    base_dcm : array_like (3, 3)
        Surveyed ``C_n^b`` of the base.
    configuration : GimbalConfiguration
        Rotation senses of the gimbals.
    inputs : TermInputs, optional
        What the additive terms of the dwells may look at besides ``f^p`` (temperature, time, slew direction, named
        arrays); its ``specific_force`` is replaced by the model's ``f^p``, and the platform is at rest in a dwell
        (angular rate and acceleration zero).

    Returns
    -------
    DwellForward
    """
    ids = kinematic_ids(model)
    offsets = np.stack(np.broadcast_arrays(*(np.asarray(values.get(i, 0.0) if i in model else 0.0) for i in GIMBAL_IDS)), axis=-1)
    effects = {i: values.get(i, 0.0) for i in KINEMATIC_IDS if i in model}  # a candidate not in values: at 0
    f_p, d_fp = specific_force_and_jacobian(
        readings,
        gravity,
        zero_offsets=offsets,
        base_dcm=base_dcm,
        effects=effects,  # type: ignore[arg-type]  # floats, or (T, 1) arrays for a batch
        configuration=configuration,
        ids=ids,
    )
    given = TermInputs(f_p) if inputs is None else inputs
    inputs = replace(
        given,
        specific_force=f_p,
        angular_rate=np.zeros_like(f_p),
        angular_acceleration=np.zeros_like(f_p),
        platform_jacobian=d_fp,
        platform_jacobian_ids=tuple(ids),
    )
    dynamic = {k: v for k, v in values.items() if k not in effects}  # the kinematic effects are already in f^p
    output = model.forward(f_p, dynamic, inputs)
    jacobian = model.jacobian(f_p, dynamic, inputs)
    through = [(k, ids.index(t.id)) for k, t in enumerate(model.terms) if t.id in ids]
    if through:
        chained = model.jacobian_specific_force(f_p, dynamic, inputs) @ d_fp  # (∂F/∂f^p)(∂f^p/∂q)
        for k, j in through:
            jacobian[..., k] = chained[..., j]
    return DwellForward(output, jacobian, f_p, inputs)
