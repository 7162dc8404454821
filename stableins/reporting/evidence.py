"""Fit evidence for the report: the residuals of each fit, grouped per position and axis.

A fit's evidence is what a record's stage run stores (:func:`stableins.records.fit_evidence`:
residuals, 1σ, labels and the fit's one χ², ν, χ²_ν), or a
:class:`~stableins.estimators.result.FitResult` recomputed by the report
(:mod:`stableins.reporting.replay`).  Both become a :class:`StageEvidence`, the only form the
report draws from; its χ²_ν is the number the calibration printed.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from stableins.errors import InputError

#: "pos 3 f_y", "position 12 y", "p3 f_x" → (3, "y"); "pos 3 |f|" → (3, "|f|") (squared-amplitude stage)
_LABEL = re.compile(r"p(?:os(?:ition)?)?\s*(\d+)\D*?(?:f_)?([xyz])\b", re.IGNORECASE)
_MAGNITUDE = re.compile(r"p(?:os(?:ition)?)?\s*(\d+)\s*\|f\|", re.IGNORECASE)


@dataclass(frozen=True)
class StageEvidence:
    """Residual evidence of one estimation stage.

    Attributes
    ----------
    stage : str
        Stage name (coarse, fine, system ...).
    labels : tuple of str
        What each residual is, e.g. ``"pos 3 f_y"``.
    residuals, sigma : tuple of float
        Observed − model, and the 1σ noise floor of each observation, in ``unit``.
    unit : str
        Unit of the observations (``"m/s^2"`` for specific force).
    rank, n_parameters : int
        Rank of the design and number of parameters.
    notes, determined : tuple of str
        Gauges applied, warnings; combinations the data determine.
    chi2 : float
        The fit's χ² (whitened where the noise is correlated between observations), as the fit computed it.
    run : str
        The stage run the fit belongs to (its name), "" when recomputed.
    """

    stage: str
    labels: tuple[str, ...]
    residuals: tuple[float, ...]
    sigma: tuple[float, ...]
    unit: str
    rank: int
    n_parameters: int
    chi2: float
    notes: tuple[str, ...] = ()
    determined: tuple[str, ...] = ()
    run: str = ""

    @property
    def dof(self) -> int:
        """Return the degrees of freedom: residuals minus the rank of the fit."""
        return len(self.residuals) - self.rank

    @property
    def chi2_red(self) -> float:
        """χ²_ν = χ² / (m − rank)."""
        return self.chi2 / self.dof if self.dof > 0 else math.nan

    def chi2_red_interval(self, probability: float = 0.95) -> tuple[float, float]:
        """Central interval of χ²_ν expected from noise alone (χ² distribution with ν degrees of freedom)."""
        from scipy.stats import chi2

        nu = max(self.dof, 1)
        tail = (1.0 - probability) / 2.0
        return float(chi2.ppf(tail, nu) / nu), float(chi2.ppf(1.0 - tail, nu) / nu)

    def by_position_axis(self) -> dict[str, list[tuple[int, float, float]]]:
        """Residuals grouped by axis: ``{"x": [(position, residual, sigma), ...], ...}``.

        Observations whose label names no position and axis are left out; see
        :attr:`unlabelled`.  Only keys with observations are present (``"|f|"`` for the
        fine stage's specific-force magnitude).
        """
        out: dict[str, list[tuple[int, float, float]]] = {"x": [], "y": [], "z": [], "|f|": []}
        for label, r, s in zip(self.labels, self.residuals, self.sigma, strict=True):
            magnitude = _MAGNITUDE.search(label)
            match = _LABEL.search(label)
            if magnitude:
                out["|f|"].append((int(magnitude.group(1)), r, s))
            elif match:
                out[match.group(2).lower()].append((int(match.group(1)), r, s))
        return {k: v for k, v in out.items() if v}

    @property
    def unlabelled(self) -> int:
        """Return the number of residuals whose label names no position or magnitude."""
        if not self.labels:
            return len(self.residuals)
        return sum(1 for label in self.labels if not (_LABEL.search(label) or _MAGNITUDE.search(label)))


def stage_evidence(source: Any, where: str = "calibration record", run: str = "") -> StageEvidence:
    """:class:`StageEvidence` from a FitResult or from a fit stored in a stage run (:func:`stableins.records.fit_evidence`)."""
    if not isinstance(source, Mapping):
        from stableins.records import fit_evidence

        notes, determined = tuple(source.notes), tuple(source.determined)
        source = fit_evidence(source)
    else:
        notes, determined = tuple(str(x) for x in source.get("notes", [])), tuple(str(x) for x in source.get("determined", []))
    name = str(source.get("stage", "stage"))
    field = f"stages[{name}]"
    residuals = source.get("residuals")
    sigma = source.get("residual_sigma")
    if not isinstance(residuals, list) or not isinstance(sigma, list) or len(residuals) != len(sigma):
        raise InputError("residuals and residual_sigma must be lists of equal length", path=where, field=field)
    try:
        residuals_f = tuple(float(x) for x in residuals)
        sigma_f = tuple(float(x) for x in sigma)
    except (TypeError, ValueError):
        raise InputError("residuals must be numbers", path=where, field=field) from None
    if any(not math.isfinite(x) for x in residuals_f) or any(not (s > 0 and math.isfinite(s)) for s in sigma_f):
        raise InputError("residuals must be finite and residual_sigma positive", path=where, field=field)
    labels = tuple(str(x) for x in source.get("residual_labels", []))
    if labels and len(labels) != len(residuals_f):
        raise InputError("residual_labels must match residuals", path=where, field=field)
    chi2 = source.get("chi2")
    if chi2 is None:  # not stored: Σ(r/σ)² (observations independent)
        chi2 = sum((r / s) ** 2 for r, s in zip(residuals_f, sigma_f, strict=True))
    return StageEvidence(
        stage=name,
        labels=labels,
        residuals=residuals_f,
        sigma=sigma_f,
        unit=str(source.get("residual_unit", "m/s^2")),
        rank=int(source.get("rank", 0)),
        n_parameters=len(source.get("parameter_ids", [])),
        chi2=float(chi2),
        notes=notes,
        determined=determined,
        run=run,
    )
