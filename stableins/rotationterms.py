"""The record terms of a turning platform: lever arms and time asynchrony (docs/conventions.md).

Both act only while the platform turns relative to the base, so neither enters
:meth:`stableins.errormodel.ErrorModel.forward`; a rotating procedure's slews determine them
(:mod:`stableins.estimators.lever`).  Kept apart from :mod:`stableins.errormodel`, which lists them in
:func:`~stableins.errormodel.known_terms`.
"""

from __future__ import annotations

from stableins.conventions import AXES, MILLIMETRE, MILLISECOND
from stableins.errormodel import Term, TermKind

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
#: Every term of this module, in record order.
ROTATION_TERMS: tuple[Term, ...] = LEVER_TERMS + (TIME_ASYNC_TERM,)
