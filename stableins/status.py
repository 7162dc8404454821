"""The one vocabulary of parameter statuses, shared by stage results, records, console, JSON and PDF.

A status says what is known about a parameter's value *given everything the result is
built on*: a stage's data alone for a data-only fit, the prior record and the stage's data
for a Bayesian update (docs/formats.md, "Statuses").  The same word means the same thing
wherever it is printed.

:class:`Determination` says how one stage's data saw a parameter: by itself, or only
through combinations with others.  A record lists, per parameter, every stage whose data
saw it (``determined_by``), so a certificate can tell a parameter measured in this
calibration from one carried over from an earlier one.

No numpy here: reading a record must not import the numerical stack.
"""

from __future__ import annotations

from enum import StrEnum


class Status(StrEnum):
    """Status of a parameter's value (one meaning in every output)."""

    #: Value and standard uncertainty determined by calibration data (the stages in ``determined_by``),
    #: combined with the prior where the stage was a Bayesian update of one.
    ESTIMATED = "estimated"
    #: Held at a stated value, not estimated from data; the uncertainty, if any, is the one stated with the value.
    FIXED = "fixed"
    #: Not observable; fixed by an explicit, documented convention (e.g. θ10 = 0); uncertainty 0 by definition.
    GAUGE = "gauge"
    #: Neither the data nor the prior determine it: no value is stated.
    UNIDENTIFIABLE = "unidentifiable"

    @property
    def why(self) -> str:
        """One-line explanation for a parameter that is not estimated."""
        return _WHY[self]


_WHY = {
    Status.ESTIMATED: "determined by the calibration data",
    Status.FIXED: "held at a stated value (not estimated)",
    Status.GAUGE: "the data do not determine it; fixed by an explicit, documented gauge",
    Status.UNIDENTIFIABLE: "the data do not determine it; no value is stated",
}


class Determination(StrEnum):
    """How the data of one stage determined a parameter."""

    #: The stage's data determine the parameter by itself (it is an estimable function of them).
    ALONE = "alone"
    #: The stage's data determine only combinations containing it; the prior shares the rest.
    COMBINATION = "in combination"


#: Every status word, in the order tables list them.
STATUSES: tuple[str, ...] = tuple(s.value for s in Status)


def parse_status(value: object) -> Status | None:
    """Return the :class:`Status` named by ``value``, or None when it names none."""
    try:
        return Status(value)  # type: ignore[arg-type]
    except ValueError:
        return None


__all__ = ["STATUSES", "Determination", "Status", "parse_status"]
