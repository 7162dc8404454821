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
arcsec, µg/g²) exist only at the edges through :meth:`Term.to_engineering`.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass, field, replace
from enum import StrEnum
from types import MappingProxyType
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stableins.conventions import (
    ARCSEC,
    AXES,
    DEG_PER_HOUR,
    GIMBAL_OFFSET_MEANING,
    INSTALLATION_ENTRIES,
    INSTALLATION_MEANING,
    MICRO_G,
    PPM,
    STANDARD_GRAVITY,
)
from stableins.coremodel import CoreValues, solve_quadratic
from stableins.units import QUANTITY, normalize_unit


class TermKind(StrEnum):
    """What a :class:`Term` is, and so how it enters the model (docs/conventions.md, "Term kinds").

    A ``TermKind`` is a ``str``: records, JSON and reports keep the words below.
    """

    #: Scale factor ``SF`` of one accelerometer (dimensionless, near 1; Wu et al. 2018 Eq. 6).
    SCALE_FACTOR = "scale_factor"
    #: Bias ``δb`` of one accelerometer [m/s²] (Eq. 6).
    BIAS = "bias"
    #: One of the six installation angles ``β`` of ``C_p^a`` [rad] (Eq. 5).
    INSTALLATION = "installation"
    #: Quadratic nonlinearity ``K2`` of one accelerometer [s²/m] (Eq. 6).
    NONLINEARITY = "nonlinearity"
    #: Zero offset ``θi0`` of a gimbal angle sensor [rad] (Section 3); enters through the kinematics.
    GIMBAL = "gimbal"
    #: An effect outside the core model; enters through its regressor (model discovery, hidden effects).
    ADDITIVE = "additive"
    #: A combined quasi-static pitch/roll coefficient of the system stage [rad] (Eqs. 21-25, 29-38): a
    #: combination of core parameters the system stage estimates; it does not enter :meth:`ErrorModel.forward`.
    COMBINED = "combined"
    #: Constant drift ``ε^p`` of one platform gyro [rad/s] (output error in the platform frame; the platform
    #: turns at ``−ε^p`` in inertial space): a property of the platform the accelerometers ride on, estimated
    #: from system records or the two-position drift test (Zhang et al. 2023); it does not enter
    #: :meth:`ErrorModel.forward`.
    GYRO_DRIFT = "gyro_drift"
    #: Lever arm ``lever_a_b`` [m] (:mod:`stableins.rotationterms`): zero at rest, not in :meth:`ErrorModel.forward`.
    LEVER_ARM = "lever_arm"
    #: Time asynchrony ``t_async`` [s] (:mod:`stableins.rotationterms`): zero at rest, not in :meth:`ErrorModel.forward`.
    TIME_ASYNCHRONY = "time_asynchrony"


@dataclass(frozen=True)
class TermInputs:
    """What a regressor may look at, sample by sample (leading dims ``...``).

    Attributes
    ----------
    specific_force : ndarray (..., 3)
        Platform-frame specific force ``f^p`` [m/s²] (the input along the nominal
        sensitive axes).
    temperature : ndarray (...), optional
        Instrument temperature minus the reference temperature [K].
    time : ndarray (...), optional
        Time since the start of the session [s].
    slew_direction : ndarray (..., 3), optional
        Sign (+1/−1/0) of the last slew seen by each sensitive axis' input (hysteresis).
    angular_rate, angular_acceleration : ndarray (..., 3), optional
        Platform angular rate [rad/s] and acceleration [rad/s²] in the p-frame.
    extra : mapping, optional
        Further named arrays for user-defined regressors.
    """

    specific_force: NDArray[np.float64]
    temperature: NDArray[np.float64] | None = None
    time: NDArray[np.float64] | None = None
    slew_direction: NDArray[np.float64] | None = None
    angular_rate: NDArray[np.float64] | None = None
    angular_acceleration: NDArray[np.float64] | None = None
    extra: Mapping[str, NDArray[np.float64]] = field(default_factory=lambda: MappingProxyType({}))

    def require(self, name: str, term_id: str) -> NDArray[np.float64]:
        """Return input ``name`` or raise a message naming the term that needs it."""
        value = getattr(self, name, None) if name != "extra" else None
        if value is None:
            value = self.extra.get(name)
        if value is None:
            raise ValueError(f"term {term_id!r} needs the input {name!r}, which these data do not provide")
        return np.asarray(value, dtype=float)


Regressor = Callable[[TermInputs], NDArray[np.float64]]


@dataclass(frozen=True)
class Term:
    """One named parameter of the error model.

    Attributes
    ----------
    id : str
        Stable identifier used in records, reports and scripts.
    kind : TermKind
        :class:`TermKind` (a string given here is converted; an unknown one is an error): scale factor, bias,
        installation, nonlinearity, gimbal (angle-sensor zero offset), additive (enters through a regressor) or
        combined (a system-stage combined coefficient).
    si_unit, unit : str
        SI unit of the value, and the engineering unit shown to people.
    scale : float
        SI value of one engineering unit (``value_si = reference + value_eng*scale``).
    nominal : float
        Typical magnitude [SI], used for priors, simulation draws and plots.
    meaning : str
        Physical meaning, one sentence.
    axis : int or None
        Sensitive axis (0, 1, 2) the term belongs to, if any.
    reference : float
        Value the engineering unit is counted from (1 for scale factors, else 0).
    regressor : callable or None
        For additive terms: ``TermInputs -> (..., 3)`` output change per unit
        parameter [m/s² per SI unit].
    excitation : str
        What a procedure must do to excite the term.
    aliases : tuple of str
        Parameters the term is absorbed into when it is left out of the model.
    source : str
        Where the term's equation comes from.
    """

    id: str
    kind: TermKind
    si_unit: str
    unit: str
    scale: float
    nominal: float
    meaning: str
    axis: int | None = None
    reference: float = 0.0
    regressor: Regressor | None = field(default=None, compare=False)
    excitation: str = "static positions"
    aliases: tuple[str, ...] = ()
    source: str = "Wu et al. 2018 Eq. 6"

    def __post_init__(self) -> None:
        try:
            object.__setattr__(self, "kind", TermKind(self.kind))
        except ValueError:
            known = ", ".join(k.value for k in TermKind)
            raise ValueError(f"term {self.id!r}: unknown kind {self.kind!r} (expected one of {known})") from None

    def to_engineering(self, value: ArrayLike) -> NDArray[np.float64]:
        """SI value → engineering unit (deviation from :attr:`reference`)."""
        return (np.asarray(value, dtype=float) - self.reference) / self.scale

    def sigma_to_engineering(self, sigma: ArrayLike) -> NDArray[np.float64]:
        """SI standard deviation → engineering unit."""
        return np.asarray(sigma, dtype=float) / self.scale

    def from_engineering(self, value: ArrayLike) -> NDArray[np.float64]:
        """Engineering unit → SI value."""
        return self.reference + np.asarray(value, dtype=float) * self.scale

    def parse_value(self, text: str, *, si_units: Iterable[str] = ()) -> float:
        """Convert a value of this term written by a person to SI.

        ``text`` is a number followed by the term's engineering unit (``"60ug/g2"``, ``"60 µg/g²"``, ``"30 arcsec"``)
        or by its SI unit, or a bare number, which is SI.  Units are compared after :func:`normalize_unit` (``µ`` or
        ``u``, ``g2``, ``g^2`` or ``g²``, spaces ignored).  ``si_units`` are further spellings of the SI unit.

        Raises
        ------
        ValueError
            The number is not a finite ASCII decimal, or the unit is neither the engineering nor the SI unit; the message
            says what is expected.
        """
        match = QUANTITY.match(text.strip())
        spellings = [self.unit, self.si_unit, *si_units]
        si = " or ".join(dict.fromkeys(s for s in spellings[1:] if s and s != "1")) or "dimensionless"
        expected = f"a number in {self.unit}, or in SI ({si}; a bare number is SI), e.g. {self.id}=10{self.unit.replace('^', '')}"
        if match is None or not match.group(1).isascii():
            raise ValueError(f"{text!r} is not a value of {self.id} (expected {expected})")
        number, unit = float(match.group(1)), normalize_unit(match.group(2))
        if not np.isfinite(number):
            raise ValueError(f"{text!r}: a value of {self.id} must be finite (expected {expected})")
        if unit == "" or unit in {normalize_unit(s) for s in spellings[1:] if s}:
            return number
        if unit == normalize_unit(self.unit):
            return float(self.from_engineering(number))
        raise ValueError(f"{text!r}: {match.group(2).strip()!r} is not a unit of {self.id} (expected {expected})")


MICRO_G_PER_G2 = MICRO_G / STANDARD_GRAVITY**2

#: Order of the six installation angles (alphabetical) and their C_p^a positions.
BETA_IDS = ("beta_xy", "beta_xz", "beta_yx", "beta_yz", "beta_zx", "beta_zy")
GIMBAL_IDS = ("theta10", "theta20", "theta30")


def _core_terms() -> tuple[Term, ...]:
    terms: list[Term] = []
    for i, a in enumerate(AXES):
        meaning = f"scale factor of the {a} accelerometer (SF in Eq. 6, output = f/SF)"
        terms.append(Term(f"sf_{a}", TermKind.SCALE_FACTOR, "1", "ppm", PPM, 1e-4, meaning, axis=i, reference=1.0))
    for i, a in enumerate(AXES):
        terms.append(
            Term(f"bias_{a}", TermKind.BIAS, "m/s^2", "ug", MICRO_G, 100 * MICRO_G, f"bias of the {a} accelerometer (δb in Eq. 6)", axis=i)
        )
    for bid in BETA_IDS:
        meaning = f"{INSTALLATION_MEANING[bid]} (Eq. 5)"
        terms.append(Term(bid, TermKind.INSTALLATION, "rad", "arcsec", ARCSEC, 30 * ARCSEC, meaning, axis=AXES.index(bid[5])))
    for i, a in enumerate(AXES):
        meaning = f"quadratic nonlinearity of the {a} accelerometer (K_nl in Eq. 6)"
        excitation = "positions with the axis near +1 g and -1 g and in between"
        nominal = 20 * MICRO_G_PER_G2
        term = Term(f"K2_{a}", TermKind.NONLINEARITY, "s^2/m", "ug/g^2", MICRO_G_PER_G2, nominal, meaning, axis=i, excitation=excitation)
        terms.append(term)
    return tuple(terms)


CORE_TERMS: tuple[Term, ...] = _core_terms()
GIMBAL_TERMS: tuple[Term, ...] = tuple(
    Term(g, TermKind.GIMBAL, "rad", "arcsec", ARCSEC, 60 * ARCSEC, GIMBAL_OFFSET_MEANING[g], source="Wu et al. 2018 Section 3")
    for g in GIMBAL_IDS
)
CORE_IDS = tuple(t.id for t in CORE_TERMS)
#: The constant platform gyro drifts ``ε^p`` (x, y, z platform axes) [rad/s], °/h at the edges.
GYRO_DRIFT_TERMS: tuple[Term, ...] = tuple(
    Term(
        f"gyro_drift_{a}",
        TermKind.GYRO_DRIFT,
        "rad/s",
        "deg/h",
        DEG_PER_HOUR,
        0.001 * DEG_PER_HOUR,
        f"constant drift of the {a}_p platform gyro (output error; the platform turns at -ε about {a}_p)",
        axis=i,
        excitation="a static record (system level) or a two-position drift test",
        source="Wu et al. 2018 Section 4 (drift neglected there); Zhang et al. 2023 Eqs. 1-4",
    )
    for i, a in enumerate(AXES)
)


def known_terms(extra: Iterable[Term] = ()) -> dict[str, Term]:
    """Terms by id: the core, gimbal, gyro-drift, lever-arm and asynchrony terms, plus any given (e.g. discovered additive terms)."""
    from stableins.rotationterms import ROTATION_TERMS  # built from Term: imported here, not at the top

    out = {t.id: t for t in CORE_TERMS + GIMBAL_TERMS + GYRO_DRIFT_TERMS + ROTATION_TERMS}
    out.update({t.id: t for t in extra})
    return out


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


