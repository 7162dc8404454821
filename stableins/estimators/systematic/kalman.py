"""The Kalman filter (filterpy, feedforward) and RTS smoother over the steps, and the same model in batch least squares.

Feedforward: the filter estimates the errors of the linearization point and never feeds them back into the
record's processing within a pass; the outer loop (:mod:`~stableins.estimators.systematic.passes`)
re-linearizes and runs a new pass.  Parameters are constants (zero process noise), so the smoothed
parameters equal the filter's final ones and the batch least-squares solution (tests).
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
import scipy.linalg
from numpy.typing import NDArray

if TYPE_CHECKING:  # pragma: no cover
    from filterpy.kalman import KalmanFilter

from stableins.estimators.systematic.model import (
    Discretization,
    StateLayout,
    noise_covariance,
    noise_decay,
    observation_rows,
    step_matrices,
)
from stableins.estimators.systematic.observations import StepBatch


@dataclass(frozen=True)
class FilterStep:
    """One filter step: ``x_k = F x_{k−1} + w``, ``w ~ N(0, Q)``; ``z = H x_k + v``, ``v ~ N(0, R)``."""

    F: NDArray[np.float64]
    Q: NDArray[np.float64]
    z: NDArray[np.float64]
    H: NDArray[np.float64]
    R: NDArray[np.float64]
    time: float


def steps_of(
    batches: Iterable[StepBatch], layout: StateLayout, disc: Discretization, slow: tuple[NDArray[np.float64], NDArray[np.float64]]
) -> Iterator[FilterStep]:
    """Yield the model's steps (:mod:`~stableins.estimators.systematic.model`) for the record's batches."""
    decay = noise_decay(layout, disc)
    for batch in batches:
        transitions = step_matrices(disc, layout, batch.inputs, decay)
        for k, geometry in enumerate(batch.geometry):
            rows = 3 if geometry.hold < 0 else 12
            h = observation_rows(layout, geometry, disc.step)[:rows]
            q = noise_covariance(disc, layout, batch.density_nav[k], slow)
            yield FilterStep(transitions[k], q, batch.observations[k, :rows], h, batch.covariances[k, :rows, :rows], float(batch.time[k]))


@dataclass
class FilterRun:
    """What a filter pass leaves: final mean and covariance, innovation statistics, and (on request) the history."""

    x: NDArray[np.float64]
    P: NDArray[np.float64]
    steps: int = 0
    chi2: float = 0.0
    dof: int = 0
    history: list[tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]] = field(default_factory=list)
    #: Whitened innovations ``L⁻¹ν`` (``L Lᵀ = S``) of every ``innovation_stride``-th step: each component ~ N(0, 1).
    innovations: list[NDArray[np.float64]] = field(default_factory=list)


def run_filter(steps: Iterable[FilterStep], x0: NDArray[np.float64], P0: NDArray[np.float64], *, keep_history: bool = False) -> FilterRun:
    """Filterpy's :class:`~filterpy.kalman.KalmanFilter` over ``steps`` (Joseph-form update, symmetrized).

    With ``keep_history`` the filtered ``(x, P)`` and the step's ``(F, Q)`` are kept for :func:`rts_smooth`
    (memory grows with the record: tests and short records only).
    """
    return run_filters(steps, x0, [P0], keep_history=keep_history)[0]


def run_filters(
    steps: Iterable[FilterStep],
    x0: NDArray[np.float64],
    priors: Sequence[NDArray[np.float64]],
    *,
    keep_history: bool = False,
    innovation_stride: int = 0,
) -> list[FilterRun]:
    """One filter per prior covariance, side by side over the same (streamed) steps.

    ``innovation_stride`` > 0 keeps the first filter's whitened innovations of every that many steps (bounded: the
    fit evidence of the record).
    """
    from filterpy.kalman import KalmanFilter  # here: reading a record's systematic settings needs no filter (issue 30)

    filters = []
    for P0 in priors:
        kf = KalmanFilter(dim_x=len(x0), dim_z=3)
        kf.x, kf.P = np.array(x0, dtype=float), np.array(P0, dtype=float)
        filters.append((kf, FilterRun(kf.x, kf.P)))
    for number, step in enumerate(steps):
        for kf, run in filters:
            _advance(kf, run, step, keep_history=keep_history)
        if innovation_stride and number % innovation_stride == 0:
            kf, run = filters[0]
            run.innovations.append(np.linalg.solve(np.linalg.cholesky(0.5 * (kf.S + kf.S.T)), kf.y))
    for kf, run in filters:
        run.x, run.P = kf.x.copy(), kf.P.copy()
    return [run for _, run in filters]


def _advance(kf: KalmanFilter, run: FilterRun, step: FilterStep, *, keep_history: bool) -> None:
    """Predict and update ``kf`` by one step; accumulate the normalized innovations."""
    kf.predict(F=step.F, Q=step.Q)
    kf.dim_z = len(step.z)
    kf.update(step.z, R=step.R, H=step.H)
    kf.P = 0.5 * (kf.P + kf.P.T)
    run.chi2 += float(kf.y @ np.linalg.solve(kf.S, kf.y))
    run.dof += len(step.z)
    run.steps += 1
    if keep_history:
        run.history.append((kf.x.copy(), kf.P.copy(), step.F, step.Q))


def rts_smooth(run: FilterRun) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Filterpy's RTS smoother over a kept history: smoothed means (N, n) and covariances (N, n, n)."""
    from filterpy.kalman import KalmanFilter

    kf = KalmanFilter(dim_x=len(run.x), dim_z=3)
    xs = np.array([h[0] for h in run.history])
    ps = np.array([h[1] for h in run.history])
    fs = np.array([h[2] for h in run.history])
    qs = np.array([h[3] for h in run.history])
    # filterpy pairs F[k+1] with the prediction from step k to k+1
    x_smooth, p_smooth, _, _ = kf.rts_smoother(xs, ps, Fs=fs, Qs=qs, inv=_spd_inverse)
    return x_smooth, p_smooth


def _spd_inverse(matrix: NDArray[np.float64]) -> NDArray[np.float64]:
    r"""Inverse of a predicted covariance for the smoother's gain: equilibrated Cholesky, one step of refinement.

    filterpy's RTS smoother uses the inverse only in its gain ``K = P_k Fᵀ P_{k+1|k}⁻¹``.  With zero process noise on
    the parameters their rows of ``P_k Fᵀ`` are the rows of ``P_{k+1|k}`` itself, so those rows of ``K`` are unit rows
    ``e_pᵀ P_{k+1|k} X`` and the smoothed parameters stay at the filter's final values to within the residual
    ``I − P_{k+1|k} X`` of the computed inverse ``X``.  A plain Cholesky inverse leaves a residual of order
    ``κ ε`` (κ up to 3e10 here: a free prior against 1e-7-rad observations).  With ``D = diag(P)``, ``A = D^{-1/2} P
    D^{-1/2}`` (symmetric diagonal equilibration) and ``A = L Lᵀ``:

    .. math::
        X_0 = L^{-T} L^{-1}, \qquad X_1 = X_0 + L^{-T} L^{-1} (I - A X_0), \qquad P^{-1} = D^{-1/2} X_1 D^{-1/2}

    (one step of fixed-precision iterative refinement with the same factor, Higham 2002, *Accuracy and Stability of
    Numerical Algorithms*, §12.1-12.2), which shrinks the residual that enters the gain.  ``X_1`` is not symmetrized:
    that would bring the residual back (measured).  Measured on ``benchmarks/bench_systematic.py --parts 3``: smoothed
    vs filtered 1.09e-9 relative with ``X_0``, 1.8e-10 with ``X_1``.
    """
    symmetric = 0.5 * (matrix + matrix.T)
    diagonal = np.diag(symmetric)
    if not np.all(diagonal > 0):  # not a covariance the smoother can invert: the plain inverse says so itself
        return np.asarray(np.linalg.inv(symmetric), dtype=np.float64)
    scale = 1.0 / np.sqrt(diagonal)
    equilibrated = symmetric * np.outer(scale, scale)
    identity = np.eye(len(matrix))
    try:
        factor = scipy.linalg.cho_factor(equilibrated)
    except np.linalg.LinAlgError:  # numerically semi-definite (no process noise anywhere): the plain inverse
        return np.asarray(np.linalg.inv(symmetric), dtype=np.float64)
    inverse = scipy.linalg.cho_solve(factor, identity)
    inverse = inverse + scipy.linalg.cho_solve(factor, identity - equilibrated @ inverse)
    return np.asarray(inverse * np.outer(scale, scale), dtype=np.float64)


def batch_least_squares(
    steps: list[FilterStep], x0: NDArray[np.float64], P0: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Solve the same linear model at once: ``(x_N, P_N)`` of the final state (tests; dense, short records).

    Unknowns: the initial state and every step's process noise ``w_k = L_k η_k`` (``Q_k = L_k L_kᵀ``), with the
    priors ``x_0 ~ N(x0, P0)``, ``η_k ~ N(0, I)``; the stacked whitened system is solved by least squares, and
    ``x_N = Φ_{N,0} x_0 + Σ Φ_{N,k} L_k η_k`` with its covariance.
    """
    n = len(x0)
    factors = [_factor(s.Q) for s in steps]
    widths = [f.shape[1] for f in factors]
    total = n + sum(widths)
    # x_k = T_k u, u = (x_0, η_1, …): T_k built step by step
    transfer = np.zeros((n, total))
    transfer[:, :n] = np.eye(n)
    first, value = _whiten(P0, np.eye(n, total), np.asarray(x0, dtype=float))
    rows: list[NDArray[np.float64]] = [first]
    rhs: list[NDArray[np.float64]] = [value]
    col = n
    for step, factor, width in zip(steps, factors, widths, strict=True):
        transfer = step.F @ transfer
        transfer[:, col : col + width] += factor
        noise_row = np.zeros((width, total))
        noise_row[:, col : col + width] = np.eye(width)
        rows.append(noise_row)
        rhs.append(np.zeros(width))
        a, b = _whiten(step.R, step.H @ transfer, step.z)
        rows.append(a)
        rhs.append(b)
        col += width
    matrix, vector = np.vstack(rows), np.concatenate(rhs)
    q, r = np.linalg.qr(matrix)
    u = np.linalg.solve(r, q.T @ vector)
    r_inv = np.linalg.solve(r, np.eye(total))
    cov_u = r_inv @ r_inv.T
    return transfer @ u, transfer @ cov_u @ transfer.T


def _factor(q: NDArray[np.float64]) -> NDArray[np.float64]:
    """``L`` with ``L Lᵀ = Q`` over Q's non-zero eigen-directions."""
    w, v = np.linalg.eigh(0.5 * (q + q.T))
    keep = w > 1e-14 * max(float(w.max(initial=0.0)), 1e-300)
    return v[:, keep] * np.sqrt(w[keep])


def _whiten(
    cov: NDArray[np.float64], matrix: NDArray[np.float64], value: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Rows ``W A``, ``W y`` with ``Wᵀ W = cov⁻¹`` over cov's non-zero directions (zero-variance directions: exact, weight 1e12)."""
    w, v = np.linalg.eigh(0.5 * (cov + cov.T))
    top = max(float(w.max(initial=0.0)), 1e-300)
    weight = 1.0 / np.sqrt(np.maximum(w, 1e-24 * top))
    return (v.T * weight[:, None]) @ matrix, (v.T * weight[:, None]) @ value
