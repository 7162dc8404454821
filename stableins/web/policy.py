"""When a unit is due: the calibration interval of its procedure, or the laboratory's policy file.

A policy file (TOML, ``stableins serve --policy FILE``)::

    [interval]
    default = 180            # days after the record in force becomes valid (default: history's --max-age, 180 d)

    [interval.procedure]     # by the procedure the record in force was made with
    device-fine = 365
    field-recal-device = 90

    [interval.unit]          # a unit's own interval overrides its procedure's
    SN042 = 30

The due date is the record in force's valid-from time plus the interval; a unit without a record in force is due
at once.  Every value is checked (a positive number of days up to 100 years); anything else is an
:class:`~stableins.errors.InputError` naming the file and the key.
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from datetime import timedelta
from pathlib import Path
from typing import Any

from stableins.errors import InputError
from stableins.history import DEFAULT_MAX_AGE

#: The longest interval a policy may state [days].
MAX_INTERVAL_DAYS = 36525.0


@dataclass(frozen=True)
class Policy:
    """Calibration intervals [days]: the default, by procedure, by unit."""

    default: float = DEFAULT_MAX_AGE.days
    procedures: Mapping[str, float] = field(default_factory=dict)
    units: Mapping[str, float] = field(default_factory=dict)
    source: str = "default (stableins history --max-age)"

    def interval(self, serial: str, procedure: str) -> timedelta:
        """Return the calibration interval of ``serial`` whose record in force was made with ``procedure``."""
        days = self.units.get(serial, self.procedures.get(procedure, self.default))
        return timedelta(days=days)

    @classmethod
    def load(cls, path: str | Path) -> Policy:
        """Read a policy file (TOML, see the module docstring).

        Raises
        ------
        InputError
            The file cannot be read, is not TOML, or a key or value is not what is expected.
        """
        try:
            with open(path, "rb") as handle:
                document = tomllib.load(handle)
        except OSError as error:
            raise InputError(f"cannot read the policy file ({error.strerror})", path=path) from None
        except tomllib.TOMLDecodeError as error:
            raise InputError(f"not TOML ({error})", path=path, expected="a laboratory policy file (docs/fleet.md)") from None
        unknown = set(document) - {"interval"}
        if unknown:
            raise InputError(f"unknown table {sorted(unknown)[0]!r}", path=path, field=sorted(unknown)[0], expected="[interval]")
        table = document.get("interval", {})
        if not isinstance(table, dict):
            raise InputError("[interval] is not a table", path=path, field="interval")
        unknown = set(table) - {"default", "procedure", "unit"}
        if unknown:
            key = sorted(unknown)[0]
            raise InputError(f"unknown key {key!r}", path=path, field=f"interval.{key}", expected="default, procedure or unit")
        return cls(
            default=_days(table.get("default", DEFAULT_MAX_AGE.days), path, "interval.default"),
            procedures=_table(table.get("procedure", {}), path, "interval.procedure"),
            units=_table(table.get("unit", {}), path, "interval.unit"),
            source=str(path),
        )


def _table(value: Any, path: str | Path, where: str) -> dict[str, float]:
    if not isinstance(value, dict):
        raise InputError("is not a table", path=path, field=where, expected="name = days")
    return {str(k): _days(v, path, f"{where}.{k}") for k, v in value.items()}


def _days(value: Any, path: str | Path, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value) or not 0 < value <= MAX_INTERVAL_DAYS:
        raise InputError(f"{str(value)[:40]!r} is not an interval", path=path, field=where, expected=f"days, 0 < d ≤ {MAX_INTERVAL_DAYS:g}")
    return float(value)
