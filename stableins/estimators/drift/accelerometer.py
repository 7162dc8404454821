"""The accelerometer cross-check of a drift test: the hold means against the record (docs/drift-test.md)."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from stableins.conventions import MICRO_G
from stableins.errormodel import ErrorModel, TermInputs
from stableins.estimators.drift.holds import StillHold

#: Accelerometer blocks per hold for the σ of its mean.
BIAS_BLOCKS = 10


@dataclass(frozen=True)
class BiasCheck:
    """Accelerometer cross-check of one axis [m/s²]: the mean compensated residual of the holds against the record.

    ``residual``: the holds' mean of ``f̂ − f^p`` (``f̂`` compensated with the record), ``sigma`` its noise;
    ``predicted``: the 1σ the record's own uncertainty gives that mean (bias, scale factor, misalignment,
    K2 through their covariance); ``reversed``: whether ``f^p`` on this axis reverses between holds (then
    scale-factor and misalignment residuals along it cancel and the mean is the bias change).
    """

    axis: str
    residual: float
    sigma: float
    predicted: float
    reversed: bool

    @property
    def z(self) -> float:
        """The residual in units of its total expected spread (noise and the record's uncertainty)."""
        total = math.hypot(self.sigma, self.predicted)
        return self.residual / total if total > 0 else math.nan

    def describe(self) -> str:
        """One line: the residual, the record's prediction, ``z`` and the verdict."""
        what = (
            f"f_{self.axis}: mean residual {self.residual / MICRO_G:+.2f} ± {self.sigma / MICRO_G:.2f} µg; "
            f"the record predicts 0 ± {self.predicted / MICRO_G:.2f} µg"
        )
        verdict = "consistent with the record" if abs(self.z) < 3 else "INCONSISTENT with the record"
        where = f" (f_{self.axis} reverses between holds: its scale-factor residual cancels)" if self.reversed else ""
        return f"{what}, z = {self.z:+.1f}: {verdict}{where}"


@dataclass(frozen=True)
class BiasInputs:
    """What the accelerometer cross-check compensates with: the record's values, covariance ``(ids, matrix)``, model, T_ref [°C]."""

    values: Mapping[str, float]
    covariance: tuple[Sequence[str], NDArray[np.float64]] | None
    error_model: ErrorModel | None
    reference_temperature: float


def bias_checks(
    columns: Mapping[str, NDArray[np.float64]],
    holds: Sequence[StillHold],
    nav_to_platform: NDArray[np.float64],
    *,
    delta: NDArray[np.float64],
    gravity: float,
    record: BiasInputs,
) -> tuple[BiasCheck, ...]:
    """Accelerometer cross-check against the record, from the hold means (module docstring)."""
    if not all(k in columns for k in ("f_x", "f_y", "f_z")):
        return ()
    values, covariance, error_model, reference_temperature = (
        record.values,
        record.covariance,
        record.error_model,
        record.reference_temperature,
    )
    model = error_model or ErrorModel.standard(nonlinear=True)
    raw = np.stack([np.asarray(columns[f"f_{a}"], dtype=float) for a in "xyz"], axis=1)
    # the true base is the survey turned by δ: f^p = Ĉ_n^p (f^n − δ × f^n)
    f_nav = np.array([0.0, 0.0, -gravity])
    f_nav_true = f_nav - np.cross(delta, f_nav)
    ids = [i for i in (covariance[0] if covariance else ()) if i in values and not i.startswith(("theta", "gyro_drift"))]
    means, sigmas, sensitivity = [], [], []
    for hold in holds:
        sl = slice(hold.first, hold.stop)
        f_p = nav_to_platform[sl] @ f_nav_true
        temperature = np.asarray(columns["temperature"], dtype=float)[sl] - reference_temperature if "temperature" in columns else None
        inputs = TermInputs(specific_force=f_p, temperature=temperature, time=np.asarray(columns["time"], dtype=float)[sl])
        residual = model.inverse(raw[sl], values, inputs) - f_p
        block_means = np.array([b.mean(axis=0) for b in np.array_split(residual, BIAS_BLOCKS)])
        means.append(residual.mean(axis=0))
        sigmas.append(block_means.std(axis=0, ddof=1) / math.sqrt(BIAS_BLOCKS))
        # how the record's parameters move the hold's mean compensated output (finite differences at the mean)
        mean_raw, mean_inputs = raw[sl].mean(axis=0)[None, :], TermInputs(specific_force=f_p.mean(axis=0)[None, :])
        base = model.inverse(mean_raw, values, mean_inputs)[0]
        columns_h = []
        for i in ids:
            step = 1e-6 * max(1.0, abs(values[i]))
            shifted = dict(values)
            shifted[i] = values[i] + step
            columns_h.append((model.inverse(mean_raw, shifted, mean_inputs)[0] - base) / step)
        sensitivity.append(np.array(columns_h).T if ids else np.zeros((3, 0)))
    means_a, sigmas_a = np.array(means), np.array(sigmas)
    h = np.mean(sensitivity, axis=0)  # (3, len(ids))
    cov = np.zeros((0, 0))
    if covariance is not None and ids:
        order = [list(covariance[0]).index(i) for i in ids]
        cov = np.nan_to_num(np.asarray(covariance[1], dtype=float)[np.ix_(order, order)])
    predicted = np.sqrt(np.clip(np.einsum("ij,jk,ik->i", h, cov, h), 0.0, None)) if ids else np.zeros(3)
    forces = np.array([h_.specific_force for h_ in holds])
    out = []
    for k, axis in enumerate("xyz"):
        signs = {int(np.sign(f)) for f in forces[:, k] if abs(f) > gravity / 4}
        out.append(
            BiasCheck(
                axis,
                float(means_a[:, k].mean()),
                float(math.sqrt(np.sum(sigmas_a[:, k] ** 2)) / len(holds)),
                float(predicted[k]),
                signs == {-1, 1},
            )
        )
    return tuple(out)
