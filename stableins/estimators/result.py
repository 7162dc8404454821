"""Frozen fit results shared by every estimator (model / fitter / result separation).

A fitter returns a :class:`FitResult`: parameters with 1σ from a covariance built on
noise measured in the data, residuals, χ²_ν, rank, singular values and null space of
the design, and the status of every parameter.  Results print a report and plot
themselves; records and reports are built from them.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from stableins.errormodel import Term

if TYPE_CHECKING:  # pragma: no cover
    from matplotlib.figure import Figure

#: Allowed parameter statuses (also used in calibration records).
STATUSES = ("estimated", "fixed", "gauge", "unidentifiable")


def parameter_table(
    rows: Sequence[tuple[str, float, float, str, str]], determined: Sequence[str] = (), notes: Sequence[str] = ()
) -> list[str]:
    """Text lines of a parameter table ``(id, value, 1σ, unit, status)`` in engineering units.

    Unidentifiable parameters show no numbers (their value in a record is only the prior
    carried through).  Shared by :meth:`FitResult.report` and the calibration record's report.
    """
    lines = [f"{'parameter':<12} {'value':>14} {'1 sigma':>10} {'unit':<8} status"]
    for parameter_id, value, sigma, unit, status in rows:
        if status == "unidentifiable":
            lines.append(f"{parameter_id:<12} {'—':>14} {'—':>10} {unit:<8} {status}")
        else:
            lines.append(f"{parameter_id:<12} {value:>14.4f} {sigma:>10.4f} {unit:<8} {status}")
    if determined:
        lines += ["", "determined combinations:"] + [f"  {d}" for d in determined]
    if notes:
        lines += ["", "notes:"] + [f"  {n}" for n in notes]
    return lines


@dataclass(frozen=True)
class FitResult:
    """Outcome of one estimation stage.

    Attributes
    ----------
    stage : str
        ``"coarse"``, ``"fine"``, ``"system"`` ...
    terms : tuple of Term
        Parameters in vector order (ids, units, meaning).
    values : ndarray (n,)
        Estimates [SI].  For ``gauge`` parameters the gauge value; for
        ``unidentifiable`` parameters the prior value carried through (never a fit).
    covariance : ndarray (n, n)
        Absolute covariance [SI²], from noise measured in the data (not scaled by χ²_ν).
    status : tuple of str
        One of :data:`STATUSES` per parameter.
    residuals : ndarray (m,)
        Weighted-fit residuals (observed − model) [SI of the observation].
    residual_sigma : ndarray (m,)
        1σ of each observation, from the noise measured in the data.
    residual_labels : tuple of str
        What each residual is, e.g. ``"pos 3 f_y"``.
    rank : int
        Numerical rank of the (weighted) design.
    singular_values : ndarray
        Singular values of the column-scaled weighted design.
    null_space : ndarray (n, k)
        Unit vectors spanning the design's null space (in parameter space).
    determined : tuple of str
        Human-readable combinations that the data do determine (when rank-deficient).
    notes : tuple of str
        Gauges applied, positions left out and why, warnings.
    extra : dict
        Stage-specific details (pass history, convergence curves ...).
    whitened_residuals : ndarray (m,) or None
        ``L⁻¹ (observed − model)`` with ``L Lᵀ`` the full covariance of the observations,
        when it is not diagonal (correlated noise).  Then :attr:`chi2` is the exact
        ``rᵀ R⁻¹ r`` (``‖L⁻¹ r‖²``) rather than the diagonal approximation
        ``Σ (r_i/σ_i)²``.  None: the observations are independent.
    """

    stage: str
    terms: tuple[Term, ...]
    values: NDArray[np.float64]
    covariance: NDArray[np.float64]
    status: tuple[str, ...]
    residuals: NDArray[np.float64]
    residual_sigma: NDArray[np.float64]
    residual_labels: tuple[str, ...] = ()
    rank: int = 0
    singular_values: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))
    null_space: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 0)))
    determined: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()
    extra: dict[str, Any] = field(default_factory=dict)
    whitened_residuals: NDArray[np.float64] | None = None

    def __post_init__(self) -> None:
        n = len(self.terms)
        if self.values.shape != (n,) or self.covariance.shape != (n, n) or len(self.status) != n:
            raise ValueError("FitResult: values, covariance and status must match the terms")
        bad = set(self.status) - set(STATUSES)
        if bad:
            raise ValueError(f"FitResult: unknown status {sorted(bad)}")
        if self.whitened_residuals is not None and self.whitened_residuals.shape != self.residuals.shape:
            raise ValueError("FitResult: whitened_residuals must match residuals")
        for name in ("values", "covariance", "residuals", "residual_sigma", "singular_values", "null_space", "whitened_residuals"):
            if getattr(self, name) is not None:
                getattr(self, name).setflags(write=False)

    # ----------------------------------------------------------------- access
    @property
    def ids(self) -> tuple[str, ...]:
        return tuple(t.id for t in self.terms)

    @property
    def sigma(self) -> NDArray[np.float64]:
        return np.sqrt(np.clip(np.diag(self.covariance), 0.0, None))

    @property
    def chi2(self) -> float:
        """``rᵀ R⁻¹ r``: exact with :attr:`whitened_residuals`, else ``Σ (r_i/σ_i)²``."""
        if self.whitened_residuals is not None:
            return float(self.whitened_residuals @ self.whitened_residuals)
        r = self.residuals / self.residual_sigma
        return float(r @ r)

    @property
    def dof(self) -> int:
        return int(self.residuals.size - self.rank)

    @property
    def chi2_red(self) -> float:
        """χ²_ν = χ² / (m − rank); expected 1 ± sqrt(2/ν)."""
        return self.chi2 / self.dof if self.dof > 0 else float("nan")

    def correlation(self) -> NDArray[np.float64]:
        s = self.sigma
        with np.errstate(invalid="ignore", divide="ignore"):
            c = self.covariance / np.outer(s, s)
        return np.where(np.outer(s, s) > 0, c, 0.0)

    def __getitem__(self, term_id: str) -> tuple[float, float, str]:
        """``(value, sigma, status)`` of one parameter [SI]."""
        k = self.ids.index(term_id)
        return float(self.values[k]), float(self.sigma[k]), self.status[k]

    def as_dict(self) -> dict[str, float]:
        return dict(zip(self.ids, map(float, self.values), strict=True))

    # ----------------------------------------------------------------- report
    def report(self) -> str:
        """Plain-text report in engineering units."""
        lines = [
            f"stage: {self.stage}",
            f"chi2_red = {self.chi2_red:.3f} (nu = {self.dof}, expected 1 ± {np.sqrt(2 / max(self.dof, 1)):.2f})",
            f"rank = {self.rank} of {len(self.terms)}",
            "",
        ]
        rows = [
            (t.id, float(t.to_engineering(v)), float(t.sigma_to_engineering(s)), t.unit, st)
            for t, v, s, st in zip(self.terms, self.values, self.sigma, self.status, strict=True)
        ]
        return "\n".join(lines + parameter_table(rows, self.determined, self.notes))

    def __str__(self) -> str:
        return self.report()

    def plot(self, ax: Any = None) -> Figure:
        """Normalized residuals (residual / 1σ) per observation with ±1 bands."""
        import matplotlib.pyplot as plt

        fig = ax.figure if ax is not None else plt.figure(figsize=(10, 4))
        ax = ax if ax is not None else fig.add_subplot(111)
        k = np.arange(self.residuals.size)
        ax.errorbar(k, self.residuals / self.residual_sigma, yerr=1.0, fmt="o", ms=3, lw=0.8)
        ax.axhline(0.0, color="k", lw=0.6)
        ax.set_xlabel("observation")
        ax.set_ylabel("residual / 1σ")
        ax.set_title(f"{self.stage}: χ²_ν = {self.chi2_red:.2f}")
        if self.residual_labels and len(self.residual_labels) <= 60:
            ax.set_xticks(k, self.residual_labels, rotation=90, fontsize=6)
        fig.tight_layout()
        return fig
