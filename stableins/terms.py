r"""The named terms of the error model: what a parameter is, its units and how it enters.

A :class:`Term` is one named parameter (``sf_x``, ``bias_y``, ``beta_xz``, ``K2_z``, ``theta10``,
``gyro_drift_x``, ``Dg_xz`` ...); its :class:`TermKind` says how it enters the model
(docs/conventions.md, "Term kinds").  This module holds the term tables; :mod:`stableins.errormodel`
composes them into the immutable :class:`~stableins.errormodel.ErrorModel` (and re-exports the names
below, so ``from stableins.errormodel import Term`` keeps working).  SI inside, engineering units
(ppm, µg, arcsec, µg/g², °/h, °/h/g) only at the edges through :meth:`Term.to_engineering`.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from enum import StrEnum
from types import MappingProxyType

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stableins.conventions import (
    ARCSEC,
    AXES,
    DEG_PER_HOUR,
    DEG_PER_HOUR_PER_G,
    GIMBAL_IDS,
    GIMBAL_OFFSET_MEANING,
    INSTALLATION_ENTRIES,
    INSTALLATION_MEANING,
    MICRO_G,
    MICRO_G_PER_G2,
    MILLIMETRE,
    MILLISECOND,
    PPM,
)
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
    #: G-sensitivity ``Dg_ab`` of the platform gyro about axis ``a`` to the specific force along axis ``b``
    #: [rad/s per m/s²] (a gyro output error like :attr:`GYRO_DRIFT`; the platform turns at ``−D_g f^p``,
    #: :func:`stableins.conventions.platform_drift_rate`; Cai et al. 2016 Eq. 1, coefficient G); it does not
    #: enter :meth:`ErrorModel.forward`.
    GYRO_G_SENSITIVITY = "gyro_g_sensitivity"
    #: Lever arm ``lever_a_b`` of accelerometer ``a`` along platform axis ``b`` [m] (size effect, Cai et al. 2016
    #: Eqs. 9-12): reads ``e_a·(ω̇×r + ω×(ω×r))`` while the platform turns; zero at rest, so it does not enter
    #: :meth:`ErrorModel.forward` (estimated from the slews of a rotating procedure, :mod:`stableins.estimators.lever`).
    LEVER_ARM = "lever_arm"
    #: Time asynchrony ``τ`` of the accelerometer samples against the angle readings [s] (``δf = τ ω×f^p``,
    #: :func:`stableins.conventions.asynchrony_error`); zero at rest, so it does not enter :meth:`ErrorModel.forward`.
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
    platform_jacobian : ndarray (..., 3, k), optional
        ``∂f^p/∂q`` of the gimbal-kinematic effects ``q`` (the columns their regressors are), with
        ``platform_jacobian_ids`` the ids of ``q`` in column order.
    platform_jacobian_ids : tuple of str
        The ids of :attr:`platform_jacobian`'s columns (empty without it).
    extra : mapping, optional
        Further named arrays for user-defined regressors.
    """

    specific_force: NDArray[np.float64]
    temperature: NDArray[np.float64] | None = None
    time: NDArray[np.float64] | None = None
    slew_direction: NDArray[np.float64] | None = None
    angular_rate: NDArray[np.float64] | None = None
    angular_acceleration: NDArray[np.float64] | None = None
    platform_jacobian: NDArray[np.float64] | None = None
    platform_jacobian_ids: tuple[str, ...] = ()
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


#: Order of the six installation angles (alphabetical) and their C_p^a positions.
BETA_IDS = ("beta_xy", "beta_xz", "beta_yx", "beta_yz", "beta_zx", "beta_zy")


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


#: The gyro g-sensitivities ``Dg_ab`` (row ``a``: gyro axis, column ``b``: specific-force axis, both platform
#: axes) [rad/s per m/s²], °/h/g at the edges.  ``Dg_aa`` is Cai et al.'s diagonal ``G_aa``.
GYRO_G_TERMS: tuple[Term, ...] = tuple(
    Term(
        f"Dg_{a}{b}",
        TermKind.GYRO_G_SENSITIVITY,
        "rad/s/(m/s^2)",
        "deg/h/g",
        DEG_PER_HOUR_PER_G,
        0.001 * DEG_PER_HOUR_PER_G,
        f"g-sensitivity of the {a}_p platform gyro to the specific force along {b}_p (output error Dg f_{b}; "
        f"the platform turns at -Dg f_{b} about {a}_p)",
        axis=i,
        excitation="dwells with the specific force along the axis reversed; seen in the slopes of the angle readings",
        source="Cai et al. 2016 Eq. 1 (coefficient G)",
    )
    for i, a in enumerate(AXES)
    for b in AXES
)


#: The nine lever arms ``lever_a_b`` [m], mm at the edges (:attr:`TermKind.LEVER_ARM`; a-major order).
LEVER_TERMS: tuple[Term, ...] = tuple(
    Term(
        f"lever_{a}_{b}",
        TermKind.LEVER_ARM,
        "m",
        "mm",
        MILLIMETRE,
        20 * MILLIMETRE,
        f"lever arm of the {a} accelerometer: its proof mass along {b}_p from the rotation centre (size effect)",
        axis=i,
        excitation="gimbal slews (stableins run device-rotating)",
        source="Cai et al. 2016 Eqs. 9-12 (along-axis components); the full vector: docs/conventions.md",
    )
    for i, a in enumerate(AXES)
    for b in AXES
)
#: Cai's three along-axis lever arms ``lever_x_x``, ``lever_y_y``, ``lever_z_z``.
CAI_LEVER_IDS: tuple[str, ...] = tuple(f"lever_{a}_{a}" for a in AXES)
#: The accelerometer–angle-reading time asynchrony ``τ`` [s], ms at the edges (:attr:`TermKind.TIME_ASYNCHRONY`).
TIME_ASYNC_TERM = Term(
    "t_async",
    TermKind.TIME_ASYNCHRONY,
    "s",
    "ms",
    MILLISECOND,
    MILLISECOND,
    "time asynchrony of the accelerometer samples against the angle readings (> 0: the accelerometers lag)",
    excitation="gimbal slews (stableins run device-rotating)",
    source="docs/conventions.md 'Lever arms and time asynchrony' (not in Cai et al. 2016)",
)
#: The record terms of a turning platform (lever arms, asynchrony): zero at rest, not in ``ErrorModel.forward``.
ROTATION_TERMS: tuple[Term, ...] = LEVER_TERMS + (TIME_ASYNC_TERM,)


def _cross_coupling_source(a: str, b: str, c: str) -> str:
    """Cai et al. 2016 Eq. 4's symbol for ``Kcc_abc``, or that Cai does not model it.

    Cai's K_cross (Eq. 6) couples accelerometer ``a`` to ``f_a`` times one other axis: ``K_axy, K_axz`` (x),
    ``K_ayx, K_ayz`` (y), ``K_azx, K_azy`` (z), i.e. ``Kcc_xxy, xxz, yxy, yyz, zxz, zyz``.  The three products of the
    two *other* axes (``Kcc_xyz, Kcc_yxz, Kcc_zxy``) are not in Cai's model.
    """
    if a not in (b, c):
        return "not in Cai et al. 2016, whose K_cross couples an accelerometer to its own input times another"
    other = c if b == a else b
    return f"Cai et al. 2016 Eq. 4 K_a{a}{other}"


def _installation_aliases(a: str, b: str, c: str) -> tuple[str, ...]:
    """Return the installation angles that read like ``Kcc_abc`` where one factor of ``f_b·f_c`` stays constant.

    Row ``a`` of ``C_p^a`` takes the other axis ``o`` in through the angle at ``[a, o]``
    (:data:`stableins.conventions.INSTALLATION_ENTRIES`; row x: ``f_y`` through ``beta_xz``, ``f_z`` through
    ``beta_xy``).  With ``f_a`` constant, ``Kcc_a·a·o`` reads as that angle (``Kcc_xxy`` as ``beta_xz``, ``Kcc_zxz`` as
    ``beta_zy``); a product of the two other axes reads as either of row ``a``'s angles.
    """
    others = [o for o in (b, c) if o != a] if a in (b, c) else [b, c]
    at = {(row, col): beta for beta, (row, col, _) in INSTALLATION_ENTRIES.items()}
    return tuple(at[AXES.index(a), AXES.index(o)] for o in others)


def _product_on_axis(i: int, j: int, k: int) -> Regressor:
    """Regressor ``e_i f_j f_k`` (``f = f^p`` on the nominal sensitive axes)."""

    def regressor(inputs: TermInputs) -> NDArray[np.float64]:
        f = np.asarray(inputs.specific_force, dtype=float)
        out = np.zeros(f.shape)
        out[..., i] = f[..., j] * f[..., k]
        return out

    return regressor


def _cross_coupling_terms() -> tuple[Term, ...]:
    terms = []
    for i, a in enumerate(AXES):
        for b, c in (("x", "y"), ("x", "z"), ("y", "z")):
            j, k = AXES.index(b), AXES.index(c)
            terms.append(
                Term(
                    f"Kcc_{a}{b}{c}",
                    TermKind.ADDITIVE,
                    "s^2/m",
                    "ug/g^2",
                    MICRO_G_PER_G2,
                    10 * MICRO_G_PER_G2,
                    f"cross-coupling of the {a} accelerometer to the product f_{b}·f_{c} ({_cross_coupling_source(a, b, c)}"
                    ", IEEE 1293 Kip/Kio/Kpo)",
                    axis=i,
                    regressor=_product_on_axis(i, j, k),
                    excitation=f"positions with f_{b} and f_{c} both non-zero (45° between the two axes), both signs",
                    aliases=(*_installation_aliases(a, b, c), f"bias_{a}"),
                    source="Cai et al. 2016 Eqs. 4 and 6; IEEE Std 1293" if a in (b, c) else "IEEE Std 1293 (not in Cai et al. 2016)",
                )
            )
    return tuple(terms)


#: The nine cross-couplings ``Kcc_abc`` [s²/m], µg/g² at the edges: accelerometer ``a`` + ``Kcc f_b f_c`` (``b < c``),
#: an additive term (:attr:`TermKind.ADDITIVE`; the discovery library's instrument candidates, carried into a record
#: by ``calibrate device --add``).  Not in :func:`known_terms`: a record holds them as discovered terms.
CROSS_COUPLING_TERMS: tuple[Term, ...] = _cross_coupling_terms()
#: Cai et al. 2016's six (K_cross, Eq. 4): an accelerometer's own input times another's.
CAI_CROSS_COUPLING_IDS: tuple[str, ...] = tuple(t.id for t in CROSS_COUPLING_TERMS if t.id[4] in t.id[5:])


def known_terms(extra: Iterable[Term] = ()) -> dict[str, Term]:
    """Terms by id: the core, gimbal, gyro, lever-arm and asynchrony terms, plus any given (e.g. discovered additive terms)."""
    out = {t.id: t for t in CORE_TERMS + GIMBAL_TERMS + GYRO_DRIFT_TERMS + GYRO_G_TERMS + ROTATION_TERMS}
    out.update({t.id: t for t in extra})
    return out
