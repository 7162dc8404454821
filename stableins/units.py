"""Units written by people: a quantity's number and unit, and the one spelling units are compared in."""

from __future__ import annotations

import re

#: A number (ASCII decimal, scientific notation allowed) and whatever follows it (the unit).
QUANTITY = re.compile(r"^([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*(.*)$")
UNIT_SPELLINGS = (("μ", "u"), ("µ", "u"), ("²", "^2"), ("³", "^3"), ("⁴", "^4"), ("**", "^"), ("°", "deg"), ("·", "*"))


def normalize_unit(unit: str) -> str:
    """Return a unit as it is compared.

    No spaces, ``µ``/``μ`` → ``u``, ``²`` → ``^2``, ``g2`` → ``g^2`` (a letter followed by a digit is a power),
    ``°`` → ``deg``; ``"1"`` (dimensionless) → ``""``.


    >>> normalize_unit("µg/g²") == normalize_unit("ug/g2") == normalize_unit("ug / g^2") == "ug/g^2"
    True
    """
    text = "".join(unit.split())
    for old, new in UNIT_SPELLINGS:
        text = text.replace(old, new)
    text = re.sub(r"(?<=[A-Za-z])(\d)", r"^\1", text)
    return "" if text == "1" else text
