"""The parameters of a record and the entries people make (procedure prompts, ``--set KEY=VALUE``)."""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

from stableins.errors import InputError
from stableins.status import Determination, Status


@dataclass(frozen=True)
class DeterminedBy:
    """One stage whose data saw a parameter, and how (alone, or only in combination with others)."""

    stage: str
    how: Determination


@dataclass(frozen=True)
class Parameter:
    """One calibrated parameter.

    Attributes
    ----------
    id : str
        Term id (``sf_x``, ``bias_x``, ``beta_xy``, ``K2_x``, ``theta10``, discovered terms ...).
    value : float
        Value [SI].
    unit : str
        SI unit of ``value`` (``"1"`` for dimensionless).
    sigma : float
        1σ [SI]; NaN for ``unidentifiable``.
    status : Status
        :class:`stableins.status.Status` (strings are converted).
    determined_by : tuple of DeterminedBy
        Every stage whose data saw the parameter, oldest first; the last one determined it last.
    """

    id: str
    value: float
    unit: str
    sigma: float
    status: Status
    determined_by: tuple[DeterminedBy, ...] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "status", Status(self.status))


@dataclass(frozen=True)
class Entry:
    """A value a person entered (a procedure prompt, ``--set KEY=VALUE``) or a field of the calibration."""

    key: str
    value: float | str
    unit: str = ""
    prompt: str = ""

    def text(self) -> str:
        """Return the value with its unit, for people (``21.5 °C``)."""
        value = f"{self.value:g}" if isinstance(self.value, float) else str(self.value)
        unit = {"degC": "°C", "deg": "°"}.get(self.unit, self.unit)
        return f"{value} {unit}".strip()


def parse_entries(items: Iterable[str], field: str = "entries") -> tuple[Entry, ...]:
    """Read entries from ``KEY=VALUE`` or ``KEY=NUMBER UNIT`` (``laboratory=PTB``, ``lab_temperature=21.5 degC``).

    Parameters
    ----------
    items : iterable of str
        The ``KEY=VALUE`` texts; a later key replaces an earlier one.
    field : str
        The parameter errors name.

    Returns
    -------
    tuple of Entry
        One entry per key (a number with its unit, or a text).

    Raises
    ------
    InputError
        An item is not ``KEY=VALUE``, or its number is not finite.
    """
    out: dict[str, Entry] = {}
    for item in items:
        key, sep, value = item.partition("=")
        key, value = key.strip(), value.strip()
        if not sep or not key or not value:
            raise InputError(f"cannot read {item!r}", field=field, expected="KEY=VALUE, e.g. laboratory=PTB or lab_temperature=21.5 degC")
        number, _, unit = value.partition(" ")
        try:
            parsed = float(number)
        except ValueError:
            out[key] = Entry(key, value)
            continue
        if not math.isfinite(parsed):
            raise InputError(f"{item!r}: not a finite number", field=field, expected="a finite number")
        out[key] = Entry(key, parsed, unit.strip())
    return tuple(out.values())
