r"""Accelerometer-triad error model as an immutable composition of named terms.

The core model is Wu et al. 2018 Eq. 6 with the signs restored::

    f^a = SF^{-1} C_p^a f^p + δb + K ∘ (f^a − δb)^2            (element-wise square)

It is implicit in ``f^a``.  With ``u = f^a − δb`` and ``w = SF^{-1} C_p^a f^p + e``
each axis obeys ``u − K u² = w``, solved exactly by the root that tends to ``w`` as
``K → 0``::

    u = 2 w / (1 + sqrt(1 − 4 K w))

``e = Σ_k p_k r_k`` collects the *additive* terms (model discovery, hidden effects):
each has a regressor ``r_k`` evaluated on :class:`TermInputs` (the platform-frame
specific force ``f^p`` resolved on the nominal sensitive axes, temperature, time,
rates ...).  Using ``f^p`` rather than ``C_p^a f^p`` is a definition: it keeps the
additive terms independent of the core parameters (the difference, e.g.
``3 K3 f² β f``, is below 1e-9 m/s²), so the Jacobian stays exact and simple.  The inverse model
(Wu et al. Eq. 8) is::

    f^p = (C_p^a)^{-1} SF (u − K u² − e),   u = f^a − δb

solved exactly for the core terms and by fixed-point iteration when additive terms
depend on ``f^p`` (they are 1e-4 relative at most; three iterations reach 1e-16).

Parameter ids are stable (see ``docs/conventions.md``): ``sf_x`` (dimensionless
scale factor near 1), ``bias_x`` [m/s²], ``beta_xy`` ... ``beta_zy`` [rad], ``K2_x``
[s²/m], ``theta10``, ``theta20``, ``theta30`` [rad].  Engineering units (ppm, µg,
arcsec, µg/g²) exist only at the edges through :meth:`Term.to_engineering`.  The terms themselves
(:class:`Term`, :class:`TermKind`, :class:`TermInputs` and the tables of core, gimbal and gyro terms)
live in :mod:`stableins.terms` and are re-exported here.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stableins.conventions import INSTALLATION_ENTRIES
from stableins.coremodel import CoreValues, solve_quadratic
from stableins.terms import (
    BETA_IDS,
    CORE_IDS,
    CORE_TERMS,
    GIMBAL_IDS,
    GIMBAL_TERMS,
    GYRO_DRIFT_TERMS,
    GYRO_G_TERMS,
    MICRO_G_PER_G2,
    Regressor,
    Term,
    TermInputs,
    TermKind,
    known_terms,
)

__all__ = [
    "BETA_IDS",
    "CORE_IDS",
    "CORE_TERMS",
    "GIMBAL_IDS",
    "GIMBAL_TERMS",
    "GYRO_DRIFT_TERMS",
    "GYRO_G_TERMS",
    "MICRO_G_PER_G2",
    "ErrorModel",
    "Regressor",
    "Term",
    "TermInputs",
    "TermKind",
    "known_terms",
]


@dataclass(frozen=True)
class ErrorModel:
    """An immutable, ordered set of terms.

    ``model + term`` (or ``model + other_model``) returns a new model; ``model -
    "id"`` removes one.  The parameter vector order is the term order.

    Examples
    --------
    >>> model = ErrorModel.standard()
    >>> model.ids[:3]
    ('sf_x', 'sf_y', 'sf_z')
    """

    terms: tuple[Term, ...]

    def __post_init__(self) -> None:
        ids = [t.id for t in self.terms]
        duplicates = sorted({i for i in ids if ids.count(i) > 1})
        if duplicates:
            raise ValueError(f"duplicate term ids in error model: {duplicates}")
        for t in self.terms:
            if t.kind == TermKind.ADDITIVE and t.regressor is None:
                raise ValueError(f"additive term {t.id!r} needs a regressor")

    # ------------------------------------------------------------- constructors
    @classmethod
    def standard(cls, *, nonlinear: bool = True, gimbals: bool = False) -> ErrorModel:
        """Return the paper's model: 12 linear terms, plus ``K2_*`` and ``theta*0`` on request."""
        terms = [t for t in CORE_TERMS if nonlinear or t.kind != TermKind.NONLINEARITY]
        if gimbals:
            terms += list(GIMBAL_TERMS)
        return cls(tuple(terms))

    # ------------------------------------------------------------- composition
    def __add__(self, other: Term | ErrorModel | Iterable[Term]) -> ErrorModel:
        new = (other,) if isinstance(other, Term) else tuple(other.terms if isinstance(other, ErrorModel) else other)
        return ErrorModel(self.terms + new)

    def __sub__(self, term_id: str | Term) -> ErrorModel:
        key = term_id.id if isinstance(term_id, Term) else term_id
        if key not in self:
            raise KeyError(f"term {key!r} is not in the model")
        return ErrorModel(tuple(t for t in self.terms if t.id != key))

    def __contains__(self, term_id: object) -> bool:
        return any(t.id == term_id for t in self.terms)

    def __getitem__(self, term_id: str) -> Term:
        for t in self.terms:
            if t.id == term_id:
                return t
        raise KeyError(f"term {term_id!r} is not in the model (known: {', '.join(self.ids)})")

    def __iter__(self) -> Iterator[Term]:
        return iter(self.terms)

    def __len__(self) -> int:
        return len(self.terms)

    @property
    def ids(self) -> tuple[str, ...]:
        """Term ids in model order."""
        return tuple(t.id for t in self.terms)

    def index(self, term_id: str) -> int:
        """Return the position of ``term_id`` in the model."""
        return self.ids.index(term_id)

    @property
    def additive_terms(self) -> tuple[Term, ...]:
        """Terms of kind :attr:`TermKind.ADDITIVE`, in model order."""
        return tuple(t for t in self.terms if t.kind == TermKind.ADDITIVE)

    def nominal_values(self) -> dict[str, float]:
        """Ideal instrument: scale factors 1, everything else 0."""
        return {t.id: t.reference for t in self.terms}

    def vector(self, values: Mapping[str, ArrayLike]) -> NDArray[np.float64]:
        """Parameter mapping → array ``(..., n)`` in model order (missing ids → reference)."""
        unknown = set(values) - set(self.ids)
        if unknown:
            raise KeyError(f"parameters not in the model: {sorted(unknown)}")
        cols = [np.asarray(values.get(t.id, t.reference), dtype=float) for t in self.terms]
        return np.stack(np.broadcast_arrays(*cols), axis=-1)

    def mapping(self, vector: ArrayLike) -> dict[str, NDArray[np.float64]]:
        """Array ``(..., n)`` in model order → parameter mapping."""
        vector = np.asarray(vector, dtype=float)
        return {t.id: vector[..., i] for i, t in enumerate(self.terms)}

    # ------------------------------------------------------------- physics
    def forward(
        self, specific_force_platform: ArrayLike, values: Mapping[str, ArrayLike], inputs: TermInputs | None = None
    ) -> NDArray[np.float64]:
        """Map the true platform-frame specific force to the accelerometer output (Eq. 6, exact).

        Parameters
        ----------
        specific_force_platform : array_like (..., 3)
            ``f^p`` [m/s²].
        values : mapping
            Parameter values [SI]; ids absent from the mapping take their reference.
        inputs : TermInputs, optional
            Inputs for additive terms (``specific_force`` is filled in here).

        Returns
        -------
        ndarray (..., 3)
            ``f^a`` [m/s²].
        """
        p = self._core(values)
        f_p = np.asarray(specific_force_platform, dtype=float)
        f_ideal = np.einsum("...ij,...j->...i", p.installation, f_p)
        w = f_ideal / p.scale_factor + self._additive(values, f_p, inputs)
        return p.bias + solve_quadratic(w, p.quadratic)

    def inverse(
        self, output: ArrayLike, values: Mapping[str, ArrayLike], inputs: TermInputs | None = None, iterations: int = 4
    ) -> NDArray[np.float64]:
        """Accelerometer output → platform-frame specific force (Eq. 8, exact inverse)."""
        p = self._core(values)
        u = np.asarray(output, dtype=float) - p.bias
        w = u - p.quadratic * u**2
        inverse_installation = np.linalg.inv(p.installation)
        f_p = np.einsum("...ij,...j->...i", inverse_installation, p.scale_factor * w)
        for _ in range(iterations if self.additive_terms else 0):
            f_ideal = p.scale_factor * (w - self._additive(values, f_p, inputs))
            f_p = np.einsum("...ij,...j->...i", inverse_installation, f_ideal)
        return f_p

    def jacobian(
        self, specific_force_platform: ArrayLike, values: Mapping[str, ArrayLike], inputs: TermInputs | None = None
    ) -> NDArray[np.float64]:
        r"""Analytic ``∂f^a/∂p`` for every model parameter, shape ``(..., 3, n)``.

        Implicit differentiation of ``u − K u² = w``: ``du = (dw + u² dK)/(1 − 2Ku)``,
        with ``∂w_i/∂SF_i = −w_i^{core}/SF_i``, ``∂w/∂β = SF^{-1} (∂C_p^a/∂β) f^p``,
        ``∂f^a/∂δb = I``.  Gimbal offsets act through ``f^p`` (see
        :meth:`jacobian_specific_force`) and are left zero here.
        """
        p = self._core(values)
        f_p = np.asarray(specific_force_platform, dtype=float)
        f_ideal = np.einsum("...ij,...j->...i", p.installation, f_p)
        w = f_ideal / p.scale_factor + self._additive(values, f_p, inputs)
        u = solve_quadratic(w, p.quadratic)
        gain = 1.0 / (1.0 - 2.0 * p.quadratic * u)  # du/dw
        shape = np.broadcast_shapes(f_p.shape, p.bias.shape)
        jac = np.zeros(shape + (len(self),))
        for k, t in enumerate(self.terms):
            if t.kind == TermKind.SCALE_FACTOR:
                i = t.axis
                jac[..., i, k] = -gain[..., i] * f_ideal[..., i] / p.scale_factor[..., i] ** 2
            elif t.kind == TermKind.BIAS:
                jac[..., t.axis, k] = 1.0
            elif t.kind == TermKind.INSTALLATION:
                row, col, sign = INSTALLATION_ENTRIES[t.id]
                jac[..., row, k] = gain[..., row] * sign * f_p[..., col] / p.scale_factor[..., row]
            elif t.kind == TermKind.NONLINEARITY:
                i = t.axis
                jac[..., i, k] = gain[..., i] * u[..., i] ** 2
            elif t.kind == TermKind.ADDITIVE:
                assert t.regressor is not None  # an additive term has one (checked in __post_init__)
                jac[..., k] = gain * t.regressor(self._inputs(f_p, inputs))
        return jac

    def jacobian_specific_force(
        self, specific_force_platform: ArrayLike, values: Mapping[str, ArrayLike], inputs: TermInputs | None = None
    ) -> NDArray[np.float64]:
        """``∂f^a/∂f^p`` (core terms; additive terms treated as fixed), shape ``(..., 3, 3)``."""
        p = self._core(values)
        f_p = np.asarray(specific_force_platform, dtype=float)
        f_ideal = np.einsum("...ij,...j->...i", p.installation, f_p)
        w = f_ideal / p.scale_factor + self._additive(values, f_p, inputs)
        u = solve_quadratic(w, p.quadratic)
        gain = 1.0 / (1.0 - 2.0 * p.quadratic * u)
        return (gain / p.scale_factor)[..., :, None] * p.installation

    # ------------------------------------------------------------- internals
    def _core(self, values: Mapping[str, Any]) -> CoreValues:
        """Return the core terms' values in ``values`` as arrays (the quadratic term only if the model has it)."""
        return CoreValues.from_mapping(values, nonlinear=any(t.kind == TermKind.NONLINEARITY for t in self.terms))

    @staticmethod
    def _inputs(f_p: NDArray[np.float64], inputs: TermInputs | None) -> TermInputs:
        return TermInputs(f_p) if inputs is None else replace(inputs, specific_force=f_p)

    def _additive(
        self, values: Mapping[str, ArrayLike], f_p: NDArray[np.float64], inputs: TermInputs | None
    ) -> NDArray[np.float64] | float:
        terms = self.additive_terms
        if not terms:
            return 0.0
        full = self._inputs(f_p, inputs)
        total = np.zeros_like(f_p)
        for t in terms:
            value = np.asarray(values.get(t.id, t.reference), dtype=float)
            if np.any(value != 0.0):
                assert t.regressor is not None  # an additive term has one (checked in __post_init__)
                total = total + value[..., None] * t.regressor(full)
        return total
