"""Field checks of a diagnosis document (``stableins diagnose --json``): each field read with its type, or one message.

Used by the document's parts (:mod:`stableins.discovery.summaries`, :mod:`stableins.discovery.signature`) and by
:class:`stableins.discovery.diagnose_report.DiagnoseReport`; a low module of its own, so the parts import it and not
each other.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from os import PathLike
from typing import Any

from stableins.discovery.steps import ModelStep
from stableins.errors import InputError, NotDeterminedError

#: What the document is, for messages.
DOCUMENT = "the output of 'stableins diagnose --json'"


# ----------------------------------------------------------------------------- reading the document
def join(where: str, key: str | int) -> str:
    """Return the field name of ``key`` within ``where`` (``candidates[3]``, ``history[0].chi2_red``)."""
    if isinstance(key, int):
        return f"{where}[{key}]"
    return f"{where}.{key}" if where else key


class Reader:
    """Field checks of one document: each returns the value with its type or raises InputError naming the field."""

    def __init__(self, path: str | PathLike[str] | None) -> None:
        self.path = path

    def fail(self, message: str, where: str, expected: str) -> InputError:
        """Return the InputError naming the file and the field."""
        return InputError(message, path=self.path, field=where or None, expected=expected)

    def mapping(self, value: Any, where: str, expected: str = "a JSON object") -> Mapping[str, Any]:
        """Return ``value`` if it is an object."""
        if not isinstance(value, Mapping):
            raise self.fail(f"{value!r:.60} is not an object", where, expected)
        return value

    def get(self, item: Mapping[str, Any], key: str, where: str) -> Any:
        """Return the value of a required key."""
        if key not in item:
            raise self.fail("missing", join(where, key), f"the key {key!r} ({DOCUMENT})")
        return item[key]

    def text(self, value: Any, where: str) -> str:
        """Return ``value`` if it is a string."""
        from stableins.data.jsonio import expect_text

        return expect_text(value, self.path, where)

    def boolean(self, value: Any, where: str) -> bool:
        """Return ``value`` if it is true or false."""
        if not isinstance(value, bool):
            raise self.fail(f"{value!r:.60} is not true or false", where, "a boolean")
        return value

    def number(self, value: Any, where: str, *, nullable: bool = True, minimum: float | None = None) -> float:
        """Return a finite number (kept an int when written as one), or NaN for null when ``nullable``."""
        from stableins.data.jsonio import expect_number

        if value is None and nullable:
            return math.nan
        expected = "a finite number" + (" or null" if nullable else "") + ("" if minimum is None else f" >= {minimum:g}")
        expect_number(value, self.path, where, minimum=minimum, expected=expected)
        return value if isinstance(value, int) else float(value)

    def integer(self, value: Any, where: str) -> int:
        """Return ``value`` if it is a non-negative integer."""
        if isinstance(value, bool) or not isinstance(value, int) or value < 0:
            raise self.fail(f"{value!r:.60} is not a non-negative integer", where, "a non-negative integer")
        return value

    def items(self, value: Any, where: str, read: Callable[[Any, str], Any]) -> tuple[Any, ...]:
        """Return each item of a list read by ``read(item, field)``."""
        from stableins.data.jsonio import expect_list

        return tuple(read(item, join(where, k)) for k, item in enumerate(expect_list(value, self.path, where)))

    def texts(self, value: Any, where: str) -> tuple[str, ...]:
        """Return a list of strings."""
        return self.items(value, where, self.text)

    def numbers(self, value: Any, where: str, *, nullable: bool = True, minimum: float | None = None) -> tuple[float, ...]:
        """Return a list of numbers (:meth:`number` each)."""
        return self.items(value, where, lambda v, w: self.number(v, w, nullable=nullable, minimum=minimum))

    def step(self, value: Any, where: str) -> ModelStep:
        """Return a history step (:meth:`~stableins.discovery.steps.ModelStep.from_json`; its ValueError as InputError naming the field)."""
        item = self.mapping(value, where)
        if item.get("residual_rms_unit", "m/s^2") != "m/s^2":
            raise self.fail(f"{item['residual_rms_unit']!r:.60}", join(where, "residual_rms_unit"), "'m/s^2'")
        try:
            return ModelStep.from_json(item, where)
        except (InputError, NotDeterminedError):
            raise  # a described error passes through as it is (issue 29)
        except ValueError as error:
            field, _, expected = str(error).partition(": ")
            raise self.fail("malformed", field, expected.removeprefix("expected ")) from None


def finite(x: float) -> float | None:
    """Return ``x``, or None (JSON null) when it is not finite."""
    return x if math.isfinite(x) else None
