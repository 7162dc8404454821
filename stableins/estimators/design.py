r"""Rank, singular values, null space and gauge of a least-squares design.

Used by the coarse and fine device-level stages, and reusable by model discovery.
The design is the *weighted* Jacobian ``A = R^{-1/2} H`` (rows: observations divided
by their 1σ, columns: parameters).  To make the singular values comparable across
parameters of different units, columns are scaled by a typical magnitude ``d_k``
(:attr:`stableins.errormodel.Term.nominal`)::

    A_s = A · diag(d),     A_s = U S V^T

A singular value ``s`` then reads: "a unit-nominal change along the right singular
vector ``v`` moves the data by ``s`` noise sigmas".  A direction is *unobservable*
when ``s < rtol · s_max`` (default ``rtol = 1e-8``, far below any physical
second-order effect and far above round-off); it is *weak* when ``s < 1`` (the data
determine it worse than its typical magnitude).

Gauge
-----
For every null direction ``n`` (unscaled, parameter units), one parameter ``g`` with
``n_g ≠ 0`` is held at a documented value (the *gauge*).  All other parameters ``k``
with ``n_k ≠ 0`` are then estimated as the combination that the data do determine::

    p_k − (n_k / n_g) · p_g

(moving along ``n`` changes both by amounts in that ratio and leaves the data
unchanged).  With several null directions the null basis is first rotated so that
each gauge parameter appears in exactly one basis vector (reduced row-echelon form on
the gauge rows).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

#: A parameter combination whose 1σ exceeds this many times its typical size (``Term.nominal``) is not
#: determined by the data: an added (discovered) term in it is held at its prior value.  Model discovery
#: uses the same limit for its gauges (:mod:`stableins.discovery.problem`).
UNDETERMINED_RATIO = 100.0


@dataclass(frozen=True)
class DesignAnalysis:
    """Singular-value analysis of a weighted design.

    Attributes
    ----------
    ids : tuple of str
        Parameter ids (columns).
    singular_values : ndarray
        Singular values of the column-scaled weighted design, descending.
    rank : int
        Number of singular values above ``rtol · s_max``.
    null_space : ndarray (n, k)
        Unit vectors (in parameter units, i.e. unscaled) spanning the null space.
    scaled_null_space : ndarray (n, k)
        The same directions in nominal-scaled coordinates.
    weak : tuple of str
        Ids whose posterior 1σ (pseudo-inverse) exceeds their nominal magnitude.
    """

    ids: tuple[str, ...]
    singular_values: NDArray[np.float64]
    rank: int
    null_space: NDArray[np.float64]
    scaled_null_space: NDArray[np.float64]
    weak: tuple[str, ...]

    @property
    def deficiency(self) -> int:
        """Number of directions the design does not determine."""
        return len(self.ids) - self.rank

    def involved(self, tol: float = 1e-2) -> list[tuple[str, ...]]:
        """Per null vector, the ids it moves (component above ``tol`` of its largest)."""
        out = []
        for v in self.scaled_null_space.T:
            big = np.abs(v) > tol * np.abs(v).max()
            out.append(tuple(i for i, b in zip(self.ids, big, strict=True) if b))
        return out


def analyze_design(weighted_jacobian: ArrayLike, ids: Sequence[str], scales: ArrayLike, rtol: float = 1e-8) -> DesignAnalysis:
    """SVD of the column-scaled weighted design ``A·diag(d)``.

    Parameters
    ----------
    weighted_jacobian : array_like (m, n)
        ``∂(residual/σ)/∂p``.
    ids : sequence of str
        Column ids.
    scales : array_like (n,)
        Typical magnitude of each parameter (SI).
    rtol : float
        Relative singular-value threshold for the null space.
    """
    a = np.asarray(weighted_jacobian, dtype=float)
    d = np.asarray(scales, dtype=float)
    u, s, vt = np.linalg.svd(a * d, full_matrices=True)
    s_full = np.zeros(a.shape[1])
    s_full[: s.size] = s
    smax = s_full.max() if s_full.size else 0.0
    rank = int(np.sum(s_full > rtol * smax))
    scaled_null = vt[rank:].T.copy()
    null = scaled_null * d[:, None]
    null /= np.linalg.norm(null, axis=0, keepdims=True)
    for v, w in zip(null.T, scaled_null.T, strict=True):  # deterministic sign: largest component positive
        k = np.argmax(np.abs(w))
        if w[k] < 0:
            v *= -1.0
            w *= -1.0
    with np.errstate(divide="ignore"):
        inv_s = np.where(s_full[:rank] > 0, 1.0 / s_full[:rank], 0.0)
    posterior = np.sqrt(((vt[:rank].T * inv_s) ** 2).sum(axis=1))  # σ in nominal units (pseudo-inverse)
    weak = tuple(i for i, p in zip(ids, posterior, strict=True) if p > 1.0)
    return DesignAnalysis(tuple(ids), s_full, rank, null, scaled_null, weak)


@dataclass(frozen=True)
class Gauge:
    """Parameters held fixed to remove the null space, and what is then determined.

    Attributes
    ----------
    fixed : tuple of str
        Gauge parameters (one per null direction).
    coefficients : dict
        ``coefficients[k][g] = −n_k / n_g``: the estimate of parameter ``k`` is the
        determined combination ``p_k + Σ_g c_kg p_g``.
    """

    fixed: tuple[str, ...]
    coefficients: dict[str, dict[str, float]]
    significance: dict[str, dict[str, float]] = field(default_factory=dict)

    def combination(self, term_id: str, tol: float = 1e-2) -> str:
        """Human-readable combination determined by the estimate of ``term_id``.

        Coefficients whose effect ``|c_kg| d_g / d_k`` (typical gauge value relative to
        the typical parameter value) is below ``tol`` are second-order and not shown.
        """
        parts = [term_id]
        for g, c in self.coefficients.get(term_id, {}).items():
            if self.significance.get(term_id, {}).get(g, 1.0) < tol:
                continue
            sign = "+" if c > 0 else "−"
            mag = abs(c)
            parts.append(f"{sign} {g}" if abs(mag - 1.0) < 1e-6 else f"{sign} {mag:.6g}·{g}")
        return " ".join(parts)

    def describe(self, tol: float = 1e-2) -> tuple[str, ...]:
        """One line per estimated parameter that a null direction moves at first order."""
        out = []
        for k in self.coefficients:
            text = self.combination(k, tol)
            if text != k:
                out.append(f"{k} estimates {text}")
        return tuple(out)


def choose_gauge(analysis: DesignAnalysis, preference: Sequence[str] = (), scales: ArrayLike | None = None, tol: float = 1e-6) -> Gauge:
    """Pick one gauge parameter per null direction and derive the determined combinations.

    Parameters
    ----------
    analysis : DesignAnalysis
    preference : sequence of str
        Ids to use as gauge parameters first, in order (e.g. ``("theta10",)``); any
        other involved id is used only if none of the preferred ones can be.
    scales : array_like (n,), optional
        Typical magnitudes, to rate each coefficient's significance.
    tol : float
        Relative size below which a null-vector component counts as zero.
    """
    ids = list(analysis.ids)
    basis, fixed = _pivoted_null_space(analysis.null_space, ids, [i for i in preference if i in ids] + ids, tol)
    d = np.ones(len(ids)) if scales is None else np.asarray(scales, dtype=float)
    coefficients: dict[str, dict[str, float]] = {}
    significance: dict[str, dict[str, float]] = {}
    for r, kid in enumerate(ids):
        if kid in fixed:
            continue
        terms = {}
        for col, g in enumerate(fixed):
            c = basis[r, col]  # basis[g_row, col] == 1
            if abs(c) > tol * np.abs(basis[:, col]).max():
                terms[g] = -float(c)
        if terms:
            coefficients[kid] = terms
            significance[kid] = {g: abs(c) * d[ids.index(g)] / d[r] for g, c in terms.items()}
    return Gauge(tuple(fixed), coefficients, significance)


def _pivoted_null_space(
    null_space: NDArray[np.float64], ids: list[str], order: list[str], tol: float
) -> tuple[NDArray[np.float64], list[str]]:
    """Return the null space reduced so that gauge parameter ``i`` has component 1 in vector ``i`` and 0 in the others.

    The gauge parameters are the first ids of ``order`` with a non-zero component (relative ``tol``), one per vector.
    """
    basis = null_space.copy()  # (n, k)
    k = basis.shape[1]
    fixed: list[str] = []
    for col in range(k):
        pivot = None
        for candidate in order:
            if candidate in fixed:
                continue
            r = ids.index(candidate)
            if abs(basis[r, col]) > tol * np.abs(basis[:, col]).max():
                pivot = candidate
                break
        if pivot is None:  # pragma: no cover - a null vector always has a non-zero component
            raise RuntimeError("no gauge parameter found for a null direction")
        r = ids.index(pivot)
        basis[:, col] /= basis[r, col]
        for other in range(k):  # eliminate the pivot row from the other vectors
            if other != col:
                basis[:, other] -= basis[r, other] * basis[:, col]
        fixed.append(pivot)
    return basis, fixed


def undetermined(
    weighted_jacobian: ArrayLike,
    ids: Sequence[str],
    scales: ArrayLike,
    candidates: Sequence[str] | Mapping[str, float],
    *,
    fixed: Sequence[str] = (),
    ratio: float = UNDETERMINED_RATIO,
    tolerance: float = 0.0,
    smallest_only: bool = False,
) -> dict[str, tuple[str, ...]]:
    """Which ``candidates`` to hold so that no free combination has 1σ above ``ratio`` typical sizes.

    The one gauge-and-hold rule of the package (device stages for added terms, discovery fits
    for every parameter).  In the nominal-scaled design a singular value ``s`` is the noise-σ
    change of the data per unit-nominal move along its vector, so the combination's 1σ is ``1/s``
    typical sizes.  A candidate whose column is zero is held at once; then, while a vector with
    ``s < max(tolerance·s_max, 1/ratio)`` (only the smallest one with ``smallest_only``) involves
    candidates (component above 0.1), the candidate first in the order is held, the one with the
    largest share among equals.  With ``candidates`` a sequence the last is first (the effect
    added last gives way to those already established); a mapping gives each candidate's rank,
    lowest first.  Exact null directions (``|f| = g`` makes ``Kcq_xy`` and ``Kcq_xz`` one with the
    bias and ``K2``) and near ones (the same at the calibrated point, off by the installation
    angles) are both caught; parameters that are not candidates are never held.

    Returns
    -------
    dict
        Held id → ids of the other parameters in its undetermined direction, in the order held.
    """
    a = np.asarray(weighted_jacobian, dtype=float)
    d = np.asarray(scales, dtype=float)
    ids = list(ids)
    rank = dict(candidates) if isinstance(candidates, Mapping) else {c: -float(k) for k, c in enumerate(candidates)}
    held: dict[str, tuple[str, ...]] = {}
    while True:
        cols = [k for k, i in enumerate(ids) if i not in fixed and i not in held]
        zero = [k for k in cols if ids[k] in rank and not np.any(a[:, k])]
        if zero:
            held.update({ids[k]: () for k in zero})
            continue
        cols = [k for k in cols if np.any(a[:, k])]
        if not cols or not any(ids[k] in rank for k in cols):
            return held
        _, s, vt = np.linalg.svd(a[:, cols] * d[cols], full_matrices=False)
        limit = max(tolerance * s[0], 1.0 / ratio)
        weak = [vector for value, vector in zip(s, vt, strict=True) if value < limit]
        options = [
            (rank[ids[c]], -abs(vector[j]), ids[c], vector)
            for vector in (weak[-1:] if smallest_only else weak)
            for j, c in enumerate(cols)
            if ids[c] in rank and abs(vector[j]) > 0.1
        ]
        if not options:
            return held
        *_, chosen, vector = min(options, key=lambda o: (o[0], o[1]))
        big = np.abs(vector) > 0.1 * np.abs(vector).max()
        held[chosen] = tuple(ids[c] for c, b in zip(cols, big, strict=True) if b and ids[c] != chosen)


def describe_design(ids: Sequence[str], singular_values: ArrayLike, null_space: ArrayLike, tol: float = 1e-3) -> list[str]:
    """Lines for a report: singular values (nominal-scaled, in noise σ) and each null vector's components."""
    s = np.asarray(singular_values, dtype=float)
    lines = ["singular values of the nominal-scaled weighted design: " + ", ".join(f"{v:.3g}" for v in s)]
    n = np.asarray(null_space, dtype=float)
    for k, v in enumerate(n.T if n.size else []):
        big = np.abs(v) > tol * np.abs(v).max()
        parts = ", ".join(f"{i} {c:+.4f}" for i, c, b in zip(ids, v, big, strict=True) if b)
        lines.append(f"null direction {k + 1} (unit vector, SI): {parts}")
    return lines


def aligned_null_space(analysis: DesignAnalysis, gauge: Gauge) -> NDArray[np.float64]:
    """Return the null space rotated so that each gauge parameter moves in exactly one unit vector.

    For the fine stage this gives the readable basis ``β_xz + β_yz``, ``β_zy + β_xy``,
    ``β_yx + β_zx`` instead of an arbitrary rotation of it.
    """
    n = analysis.null_space
    if n.shape[1] != len(gauge.fixed) or n.shape[1] == 0:
        return n
    rows = [analysis.ids.index(g) for g in gauge.fixed]
    basis = n @ np.linalg.inv(n[rows])
    basis /= np.linalg.norm(basis, axis=0, keepdims=True)
    return basis
