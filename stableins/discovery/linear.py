"""Linear(ized) discovery problems: observations, 1σ, model columns and candidate columns (system-level harmonics, user problems)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stableins.conventions import DEFAULT_GIMBALS, GimbalConfiguration
from stableins.discovery.dwells import DwellSet
from stableins.discovery.problem import gauge_columns
from stableins.errormodel import ErrorModel, Term
from stableins.estimators.result import FitResult, Stage
from stableins.status import Status

if TYPE_CHECKING:  # pragma: no cover
    from stableins.noise import NoiseModel


# ----------------------------------------------------------------------------- generic linear problem
class LinearProblem:
    """A linear least-squares problem ``y = X p + e``, ``e ~ N(0, diag σ²)`` (a :class:`~stableins.estimators.leastsquares.Problem`).

    Parameters
    ----------
    observations, sigma : array_like (m,)
        Observations and their 1σ (measured independently).
    terms : sequence of Term
        Model parameters; ``columns[term.id]`` is its column.
    columns : mapping id → array (m,)
        Design columns of model parameters *and* candidates.
    labels : sequence of str, optional
        Names of the observations.
    """

    def __init__(
        self,
        observations: ArrayLike,
        sigma: ArrayLike,
        columns: Mapping[str, ArrayLike],
        labels: Sequence[str] | None = None,
        stage: Stage = Stage.LINEAR,
    ) -> None:
        self.y = np.asarray(observations, dtype=float)
        self.s = np.broadcast_to(np.asarray(sigma, dtype=float), self.y.shape).copy()
        self.columns = {k: np.asarray(v, dtype=float) for k, v in columns.items()}
        self.labels = tuple(labels) if labels is not None else tuple(f"obs {i}" for i in range(self.y.size))
        self.stage = stage
        self.static = False  # the ranking's Bonferroni level (Problem.static)

    def whiten(self, v: ArrayLike) -> NDArray[np.float64]:
        """``v / σ`` for observation-ordered vectors (m,) or matrices (m, k): the observations are independent."""
        v = np.asarray(v, dtype=float)
        return v / (self.s if v.ndim == 1 else self.s[:, None])

    def _column(self, term: Term) -> NDArray:
        if term.id not in self.columns:
            raise KeyError(f"no design column for {term.id!r}")
        return self.columns[term.id]

    def fit(self, model: ErrorModel, start: Mapping[str, float] | None = None) -> FitResult:
        """Return the weighted least-squares fit of ``model`` (terms the data do not determine held at 0 as the gauge)."""
        x = np.stack([self._column(t) for t in model.terms], axis=1) / self.s[:, None]
        cols, gauge = gauge_columns(x, list(range(len(model))), model.terms)
        p = np.zeros(len(model))
        sol, *_ = np.linalg.lstsq(x[:, cols], self.y / self.s, rcond=None)
        p[cols] = sol
        cov = np.zeros((len(model), len(model)))
        cov[np.ix_(cols, cols)] = np.linalg.inv(x[:, cols].T @ x[:, cols])
        residuals = self.y - (x * self.s[:, None]) @ p
        status = tuple(Status.ESTIMATED if k in cols else Status.GAUGE for k in range(len(model)))
        return FitResult(
            stage=self.stage,
            terms=model.terms,
            values=p,
            covariance=cov,
            status=status,
            residuals=residuals,
            residual_sigma=self.s.copy(),
            residual_labels=self.labels,
            rank=len(cols),
            notes=tuple(f"{g} held at 0 (gauge)" for g in gauge),
        )

    def design(self, result: FitResult) -> NDArray[np.float64]:
        """Columns of the estimated terms (none: the data determine none of them, e.g. slopes of very short dwells)."""
        estimated = [self._column(t) for t, st in zip(result.terms, result.status, strict=True) if st == Status.ESTIMATED]
        return np.stack(estimated, axis=1) if estimated else np.zeros((self.y.size, 0))

    def candidate_columns(self, terms: Sequence[Term], result: FitResult) -> NDArray[np.float64]:
        """Return the columns the ``terms`` would add to the design."""
        return np.stack([self._column(t) for t in terms], axis=1) if terms else np.zeros((self.y.size, 0))


# ----------------------------------------------------------------------------- system records
def bins_from_chunks(
    chunks,
    *,
    gravity: float,
    bin_seconds: float = 60.0,
    reference_temperature: float = 25.0,
    base_attitude: tuple[float, float, float] = (0.0, 0.0, 0.0),
    configuration: GimbalConfiguration = DEFAULT_GIMBALS,
    noise: NoiseModel | None = None,
) -> DwellSet:
    r"""Bin a system-level record (a stream of column chunks) into "dwells" for discovery.

    A space-stable platform turns at the Earth rate relative to the base, so its specific
    force moves slowly; a bin of length ``T`` averaged at the mean readings differs from the
    mean of the outputs by about ``g (ω_ie T)²/24`` (0.8 µg for 60 s), far below the bin's
    noise.  Each bin's 1σ is the white-noise floor of its axis (second differences, pooled
    over the record, free of the Earth-rate slope of the signal) over ``sqrt(n)``.  No slews: hysteresis is not excited; the time since
    the last command is the record time.  Memory is bounded by the number of bins.

    Parameters
    ----------
    chunks : iterable of mappings
        Column chunks with ``time``, ``angle_platform/inner/middle``, ``f_x/y/z`` and
        ``temperature`` (e.g. :meth:`stableins.data.system.SystemRecord.iter_chunks`).
    gravity : float
        Local gravity [m/s²].
    bin_seconds : float
        Bin length [s].
    noise : NoiseModel, optional
        The instrument's noise model: over a day the slow bias wander (bias instability,
        random walk) is correlated between bins and would otherwise look like drift or a harmonic.
    """
    sums: dict[int, NDArray] = {}
    squares = np.zeros(3)
    n_diff = 0
    t0 = None
    last = None  # (bins, f) of the previous chunk's last two samples, for differences across chunk boundaries
    for chunk in chunks:
        t = np.asarray(chunk["time"], dtype=float)
        if t.size == 0:
            continue
        t0 = t[0] if t0 is None else t0
        f = np.stack([np.asarray(chunk[k], dtype=float) for k in ("f_x", "f_y", "f_z")], axis=-1)
        r = np.stack([np.asarray(chunk[f"angle_{g}"], dtype=float) for g in ("platform", "inner", "middle")], axis=-1)
        temp = np.asarray(chunk["temperature"], dtype=float)
        b = np.floor((t - t0) / bin_seconds).astype(np.int64)
        if last is not None:
            b_all, f_all = np.concatenate([last[0], b]), np.vstack([last[1], f])
        else:
            b_all, f_all = b, f
        # second differences within a bin: E[(Δ²n)²] = 6σ² for white noise, and the platform's slow turning (a slope
        # of g ω_ie cosL per second in x and y, +14 % on a first-difference floor at 1 Hz) does not reach them
        same = b_all[2:] == b_all[:-2]
        d = (f_all[2:] - 2.0 * f_all[1:-1] + f_all[:-2])[same]
        squares += (d**2).sum(axis=0) / 6.0
        n_diff += d.shape[0]
        last = (b_all[-2:], f_all[-2:])
        for k in np.unique(b):
            m = b == k
            row = np.concatenate([[m.sum(), t[m].sum(), temp[m].sum()], f[m].sum(axis=0), r[m].sum(axis=0)])
            sums[int(k)] = sums.get(int(k), 0.0) + row
    if t0 is None or not sums or n_diff == 0:
        raise ValueError("the record has too few samples to form bins")
    keys = sorted(sums)
    table = np.array([sums[k] for k in keys])
    n = table[:, 0]
    full = n >= 0.5 * np.median(n)  # drop a short last bin
    table, n = table[full], n[full]
    sigma_white = np.sqrt(squares / n_diff)
    readings = table[:, 6:9] / n[:, None]
    time = table[:, 1] / n
    rate = float(np.median(n)) / bin_seconds
    lengths = n / rate
    slow = None if noise is None or not noise.has_slow_noise else noise.slow_covariance(time - lengths / 2.0, lengths)
    return DwellSet(
        readings=readings,
        output=table[:, 3:6] / n[:, None],
        sigma=sigma_white[None, :] / np.sqrt(n)[:, None],
        gravity=float(gravity),
        time=time,
        time_since_command=time - float(t0),
        temperature=table[:, 2] / n - reference_temperature,
        slew_direction=np.zeros((len(n), 3)),
        labels=tuple(f"{(tk - t0) / 3600:.2f}h" for tk in time),
        base_attitude=(*base_attitude,),
        configuration=configuration,
        noise={
            "method": f"white noise from second differences, pooled over the record; {bin_seconds:g} s bins",
            "sigma_per_sample": sigma_white,
            "lengths": lengths,
            "slow_noise": "none" if noise is None else noise.describe(),
        },
        initial_readings=None,
        slow_covariance=slow,
    )
