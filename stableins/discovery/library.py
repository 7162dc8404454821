r"""The candidate-effect library: physical effects the standard model leaves out.

Every candidate is a :class:`stableins.errormodel.Term` of kind ``"additive"``: its
regressor returns the change of the accelerometer output ``f^a`` per unit of the
parameter (SI), evaluated on :class:`~stableins.errormodel.TermInputs`, so ``model +
effect`` is a valid :class:`~stableins.errormodel.ErrorModel` and every fitter that
handles additive terms can estimate it.  Ids are the simulator's (``docs/simulator.md``);
the regressors follow the IEEE Std 1293-2018 accelerometer model equation

.. math::
    E/K_1 = K_0 + a_i + K_2 a_i^2 + K_3 a_i^3 + K_{oq} a_i|a_i| + K_{ip} a_i a_p + K_{io} a_i a_o
            + K_{po} a_p a_o + K_{pp} a_p^2 + K_{oo} a_o^2 + \dots

and Cai et al. 2016 Eqs. 4, 9–12 (cross-coupling ``K_axy f_x f_y`` is our ``Kcc_xxy``; Cai's six are
``Kcc_xxy, xxz, yxy, yyz, zxz, zyz``, an accelerometer's own input times another; ``Kcc_xyz, Kcc_yxz, Kcc_zxy``
are not in Cai's model; size effect ``−(ω_y² + ω_z²) r_x``).  Inputs are platform-frame (``f^p`` on the nominal
sensitive axes), see :mod:`stableins.errormodel`.

Instrument terms (per axis ``a``; ``b ≠ a``; ``bc ∈ {xy, xz, yz}``):

==================  ======================================  ============
id                  regressor (on axis a)                   unit
==================  ======================================  ============
``K3_a``            ``f_a³``                                µg/g³
``Koq_a``           ``f_a |f_a|``                           µg/g²
``Ksa_a``           ``|f_a|`` (half the SF difference       ppm
                    between positive and negative input)
``Kcq_ab``          ``f_b²``                                µg/g²
``Kcc_abc``         ``f_b f_c``                             µg/g²
==================  ======================================  ============

Environment and time: ``Kt_bias_a`` (``ΔT``, µg/K), ``Kt_sf_a`` (``f_a ΔT``, ppm/K),
``Kd_bias_a`` (``t``, µg/h), ``Kh_a`` (direction ±1 of the last slew of the axis' input, µg).
Rotation and platform: ``lever_a_b`` (accelerometer ``a`` displaced by ``r`` along platform
axis ``b``: ``e_a·(ω̇×e_b + ω×(ω×e_b))``, mm), ``Dg_ab`` (gyro g-sensitivity, a gyro output
error ``Dg_ab f_b`` about ``p``-axis ``a``: the platform turns at ``−D_g f^p``, °/h/g; the angle sensors measure the drift, so
its regressor on ``f^a`` against measured readings is zero: it is found from the slopes of the
readings within dwells, :mod:`stableins.discovery.drift`).
Test equipment (through the exact kinematics of :mod:`stableins.platform`,
regressor ``∂f^p/∂p``): ``nonorth_12``, ``nonorth_23``, ``tilt_north``, ``tilt_east``,
``azimuth_error``, ``ang1_<gimbal>_c``/``_s``.

Custom effects: build a Term with :func:`custom_effect` (a Python function of
``TermInputs``) and :func:`register` it; it is then ranked like the library's own.

Carried into a calibration (``stableins calibrate device --add ID``, :func:`calibration_terms`):
the instrument group, whose regressors read the specific force only, so that the device
stages can estimate them and any compensation (:meth:`ErrorModel.inverse`) can apply them.
The other groups are diagnosed only; :func:`calibration_limit` says why.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable

from numpy.typing import NDArray

from stableins.discovery.catalogue import Candidate, default_candidates
from stableins.errormodel import Term, TermInputs, TermKind
from stableins.units import DisplayUnit

#: Groups whose effects a calibration carries (estimated by the device stages, applied by compensation).
CALIBRATION_GROUPS = ("instrument",)
#: Why the other groups are diagnosed but not carried into a calibration record.
_NOT_CARRIED = {
    "environment": "it needs the temperature, session time or slew history of every dwell, which the device stages do not model",
    "rotation": "it is not an output of the accelerometers at rest (lever arm: needs rotation; Dg: the gyros move the platform)",
    "equipment": "it acts through the gimbal kinematics or the base (a property of the platform or the site), not through the "
    "accelerometer outputs that a calibration record compensates",
    "custom": "a user-defined regressor may read inputs the device stages do not have",
}


class Library:
    """An ordered registry of candidates; the default one holds every built-in effect.

    Examples
    --------
    >>> lib = Library.default()
    >>> lib["Kcc_xxy"].term.unit
    'ug/g^2'
    """

    def __init__(self, candidates: Iterable[Candidate] = ()) -> None:
        self._items: dict[str, Candidate] = {}
        for c in candidates:
            self.register(c)

    @classmethod
    def default(cls) -> Library:
        """Return a library holding the built-in catalogue (:func:`stableins.discovery.catalogue.default_candidates`)."""
        return cls(default_candidates())

    def register(self, item: Candidate | Term, separation: str = "", group: str = "custom") -> Candidate:
        """Add a candidate (or a bare additive Term) to the library; its id must be new."""
        candidate = item if isinstance(item, Candidate) else Candidate(item, group, separation or item.excitation)
        if candidate.term.kind != TermKind.ADDITIVE or candidate.term.regressor is None:
            raise ValueError(f"candidate {candidate.id!r} must be an additive term with a regressor")
        if candidate.id in self._items:
            raise ValueError(f"candidate {candidate.id!r} is already in the library")
        self._items[candidate.id] = candidate
        return candidate

    def __getitem__(self, term_id: str) -> Candidate:
        try:
            return self._items[term_id]
        except KeyError:
            raise KeyError(f"no candidate effect {term_id!r} (known: {', '.join(self._items)})") from None

    def __contains__(self, term_id: object) -> bool:
        return term_id in self._items

    def __iter__(self):
        return iter(self._items.values())

    def __len__(self) -> int:
        return len(self._items)

    @property
    def ids(self) -> tuple[str, ...]:
        """Ids of the candidates, in registration order."""
        return tuple(self._items)

    def terms(self) -> tuple[Term, ...]:
        """Return the candidates' terms, in registration order."""
        return tuple(c.term for c in self._items.values())


def calibration_limit(term_id: str, library: Library | None = None) -> str | None:
    """Why an effect cannot be carried into a calibration record, or None when it can (:data:`CALIBRATION_GROUPS`)."""
    library = library if library is not None else LIBRARY
    if term_id not in library:
        return f"no candidate effect {term_id!r} in the library"
    group = library[term_id].group
    return None if group in CALIBRATION_GROUPS else _NOT_CARRIED.get(group, f"its group {group!r} is not carried")


def calibration_terms(term_ids: Iterable[str], *, source: str = "--add", library: Library | None = None) -> tuple[Term, ...]:
    """Return the library terms for effects to be estimated in a calibration, in order, each once.

    Raises
    ------
    InputError
        An unknown id, an id given twice, or an effect that a calibration cannot carry
        (:func:`calibration_limit`), naming ``source`` (an option or a procedure file).
    """
    from stableins.errors import InputError

    library = library if library is not None else LIBRARY
    ids = list(term_ids)
    carried = [c.id for c in library if c.group in CALIBRATION_GROUPS]
    seen: set[str] = set()
    for term_id in ids:
        if term_id in seen:
            raise InputError(f"effect {term_id!r} is given twice", field=source, expected="each effect once")
        seen.add(term_id)
        if term_id not in library:
            raise InputError(f"unknown effect {term_id!r}", field=source, expected=f"an effect of the library: {', '.join(carried)}")
        why = calibration_limit(term_id, library)
        if why is not None:
            raise InputError(
                f"effect {term_id!r} cannot be carried into a calibration: {why}; 'stableins diagnose --add {term_id}' tests it",
                field=source,
                expected=f"an instrument effect: {', '.join(carried)}",
            )
    return tuple(library[i].term for i in ids)


def record_terms(parameter_ids: Iterable[str], library: Library | None = None) -> tuple[Term, ...]:
    """Return the discovered (additive) terms among a record's parameter ids, in record order."""
    from stableins.errormodel import known_terms

    library = library if library is not None else LIBRARY
    own = known_terms()  # the record's own terms (lever arms, asynchrony ...) are not additive output terms
    return tuple(library[i].term for i in parameter_ids if i in library and i not in own)


def all_terms(library: Library | None = None) -> dict[str, Term]:
    """Every term a calibration record may carry, by id: the standard and gimbal terms and the library's."""
    from stableins.errormodel import known_terms

    own = known_terms()
    return known_terms(t for t in (library if library is not None else LIBRARY).terms() if t.id not in own)


def markdown_table(library: Library | None = None) -> str:
    """Return the candidates as a Markdown table (id, unit, meaning, excitation, aliases, separation) for the docs."""
    library = library if library is not None else LIBRARY
    rows = ["| id | unit | group | meaning | excitation | aliases into | separated by |", "|---|---|---|---|---|---|---|"]

    def cell(text: str) -> str:
        return text.replace("|", "\\|")

    for c in library:
        t = c.term
        aliases = ", ".join(f"`{a}`" for a in t.aliases) or "—"
        rows.append(f"| `{t.id}` | {t.unit} | {c.group} | {cell(t.meaning)} | {cell(t.excitation)} | {aliases} | {cell(c.separation)} |")
    return "\n".join(rows)


#: The process-wide default library; :func:`register` adds custom effects to it.
LIBRARY = Library.default()


def register(item: Candidate | Term, separation: str = "") -> Candidate:
    """Register a custom effect in the default library (it is then ranked like the built-in ones)."""
    return LIBRARY.register(item, separation)


def custom_effect(
    term_id: str,
    regressor: Callable[[TermInputs], NDArray],
    *,
    unit: DisplayUnit,
    nominal: float | None = None,
    meaning: str = "user-defined effect",
    excitation: str = "",
    aliases: tuple[str, ...] = (),
    axis: int | None = None,
) -> Term:
    """Build an additive Term from a user function ``TermInputs -> (..., 3)`` [m/s² per SI unit].

    ``unit`` is the unit the coefficient is shown in and its SI size; ``nominal`` its typical magnitude [SI]
    (default one ``unit``).

    Examples
    --------
    >>> import numpy as np
    >>> from stableins.conventions import MICRO_G, STANDARD_GRAVITY
    >>> def fourth(inputs):
    ...     out = np.zeros_like(inputs.specific_force)
    ...     out[..., 0] = inputs.specific_force[..., 0] ** 4
    ...     return out
    >>> from stableins.units import DisplayUnit
    >>> term = custom_effect("K4_x", fourth, unit=DisplayUnit("ug/g^4", MICRO_G / STANDARD_GRAVITY**4))
    >>> term.kind
    <TermKind.ADDITIVE: 'additive'>
    """
    return Term(
        term_id,
        TermKind.ADDITIVE,
        unit.si_name or f"({unit.name}) in SI",
        unit.name,
        unit.scale,
        unit.scale if nominal is None else nominal,
        meaning,
        axis=axis,
        regressor=regressor,
        excitation=excitation or "user-defined",
        aliases=aliases,
        source="user-defined",
    )
