"""What a set of orientations determines: the rank report of the systematic stage.

The *rank* filter runs on the same steps as the estimate with every parameter and nuisance under a free prior, so
``Λ = P_post⁻¹ − P_free⁻¹`` is the information of the data alone (everything else marginalized).  For a group of
parameters, in units of their :data:`RESOLUTION` (what a calibration engineer would call resolved), the eigen-
directions of ``Λ`` are the combinations the data see, with ``σ = 1/√λ``: a direction is *determined* when
``σ ≤ 1`` (the data alone resolve it), else it is *not determined* by this set of orientations — the estimate
leaves it to the record's prior (the Bayesian update moves nothing the data do not determine).  A direction is
named by its largest loadings, or recognized when it is one the docs derive (:data:`KNOWN_GAUGES`).  The rank
grows with the record's length for weakly seen directions; exact gauges (zero information) never enter it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from stableins.conventions import ARCSEC, DEG_PER_HOUR, MICRO_G, PPM, STANDARD_GRAVITY
from stableins.errormodel import MICRO_G_PER_G2

#: Prior 1σ of the parameters in the rank filter [SI], by id prefix: free (100× their resolution and more), yet
#: narrow enough to keep the filter's covariance well conditioned.
FREE_PRIOR: dict[str, float] = {
    "sf_": 1e-3,
    "bias_": 1e-2,
    "beta_": 1e-3,
    "K2_": 1e-4,
    "Kcc_": 1e-4,
    "gyro_drift_": 0.01 * DEG_PER_HOUR,
    "Dg_": 0.01 * DEG_PER_HOUR / STANDARD_GRAVITY,
}


def free_prior(name: str) -> float:
    """:data:`FREE_PRIOR` of parameter ``name`` [SI]."""
    return next(v for k, v in FREE_PRIOR.items() if name.startswith(k))


#: The resolution each kind of parameter must reach to count as determined [SI], by id prefix.
RESOLUTION: dict[str, float] = {
    "sf_": 10 * PPM,
    "bias_": 10 * MICRO_G,
    "beta_": 3 * ARCSEC,
    "K2_": 5 * MICRO_G_PER_G2,
    "Kcc_": 5 * MICRO_G_PER_G2,
    "gyro_drift_": 1e-4 * DEG_PER_HOUR,
    "Dg_": 1e-4 * DEG_PER_HOUR / STANDARD_GRAVITY,
    "base_": 5 * ARCSEC,
    "theta": 5 * ARCSEC,
}
#: Gauge directions the docs derive (docs/systematic-calibration.md §3): unit loadings → name.
KNOWN_GAUGES: dict[str, dict[str, float]] = {
    "a rotation of the triad about z_p (aliased with the platform zero offset θ10)": {"beta_xz": 1.0, "beta_yz": 1.0},
    "the platform zero offset θ10 (aliased with a rotation of the triad about z_p)": {"theta10_residual": 1.0},
    "base tilt about east and the middle zero offset θ30 (aliased)": {"base_east": 1.0, "theta30_residual": 1.0},
    "the common scale factor of the triad (aliased with the vertical loop's integrator)": {"sf_x": 1.0, "sf_y": 1.0, "sf_z": 1.0},
}


def resolution(name: str) -> float:
    """:data:`RESOLUTION` of parameter ``name`` [SI]."""
    return next(v for k, v in RESOLUTION.items() if name.startswith(k))


@dataclass(frozen=True)
class Direction:
    """One eigen-direction of a group: its loadings (resolution units), its data-only σ (same units), its name."""

    loadings: tuple[tuple[str, float], ...]
    sigma: float
    name: str

    @property
    def determined(self) -> bool:
        """Whether the data alone resolve it (``σ ≤ 1`` resolution unit)."""
        return self.sigma <= 1.0


@dataclass(frozen=True)
class GroupRank:
    """The rank of one group of parameters.

    Attributes
    ----------
    group : str
        ``"accelerometer"``, ``"nonlinearity"`` (``K2`` and any cross-couplings), ``"gyro"`` or ``"nuisance"``.
    ids : tuple of str
    directions : tuple of Direction
        Most determined first.
    """

    group: str
    ids: tuple[str, ...]
    directions: tuple[Direction, ...]

    @property
    def rank(self) -> int:
        """Number of determined directions."""
        return sum(d.determined for d in self.directions)

    @property
    def gauge(self) -> tuple[Direction, ...]:
        """The directions the data do not determine."""
        return tuple(d for d in self.directions if not d.determined)

    def describe(self) -> str:
        """One line: ``group: r of n determined; gauge: …``."""
        text = f"{self.group}: {self.rank} of {len(self.ids)} determined"
        if self.gauge:
            text += "; not determined: " + "; ".join(d.name for d in self.gauge)
        return text


def group_rank(group: str, ids: tuple[str, ...], information: NDArray[np.float64], units: NDArray[np.float64]) -> GroupRank:
    """Eigen-directions of a group's data-only information ``Λ`` (state units), expressed in resolution units.

    ``units`` is the resolution of each parameter in state units; directions are sorted best-determined first.
    """
    scaled = information * np.outer(units, units)
    values, vectors = np.linalg.eigh(0.5 * (scaled + scaled.T))
    directions = []
    for k in np.argsort(-values):
        v = vectors[:, k]
        if v[np.argmax(np.abs(v))] < 0:
            v = -v
        sigma = 1.0 / np.sqrt(values[k]) if values[k] > 0 else np.inf
        directions.append(Direction(_loadings(ids, v), float(sigma), _name(ids, v)))
    return GroupRank(group, ids, tuple(directions))


def _loadings(ids: tuple[str, ...], v: NDArray[np.float64]) -> tuple[tuple[str, float], ...]:
    order = np.argsort(-np.abs(v))
    return tuple((ids[i], float(v[i])) for i in order if abs(v[i]) >= 0.1)


def _name(ids: tuple[str, ...], v: NDArray[np.float64]) -> str:
    """Return the known gauge this direction is (cosine ≥ 0.9), else its largest loadings."""
    for name, loading in KNOWN_GAUGES.items():
        ref = np.array([loading.get(i, 0.0) for i in ids])
        if np.linalg.norm(ref) > 0 and abs(ref @ v) / np.linalg.norm(ref) >= 0.9:
            return name
    return " ".join(f"{c:+.2f} {i}" for i, c in _loadings(ids, v)[:4])
