"""JSON (and TOML) documents: the value types, and one object's fields read with their types at the boundary.

A document stableins writes (a record, a stage's settings, a command's ``--json`` output) is built from
:data:`JSONValue`; one it reads is checked field by field by :class:`DocumentFields`, every problem an
:class:`~stableins.errors.InputError` naming the file and the field (``stages[1].settings.gyro_drift.known``).
"""

from __future__ import annotations

import datetime as dt
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import TypeAlias

from stableins.errors import InputError

#: A JSON value (RFC 8259): what :func:`json.loads` returns and :func:`json.dumps` writes.
JSONValue: TypeAlias = "str | int | float | bool | None | list[JSONValue] | dict[str, JSONValue]"
#: A JSON object.
JSONObject: TypeAlias = "dict[str, JSONValue]"
#: A value of a parsed TOML document (:mod:`tomllib`): JSON's, without null, plus dates and times.
TOMLValue: TypeAlias = "str | int | float | bool | dt.datetime | dt.date | dt.time | list[TOMLValue] | dict[str, TOMLValue]"
#: A TOML table: a parsed TOML file before its sections are validated (each reader checks the fields it knows).
TOMLTable: TypeAlias = "dict[str, TOMLValue]"


@dataclass(frozen=True)
class DocumentFields:
    """The fields of one JSON object, each read with its type.

    Parameters
    ----------
    document : mapping
        The object (as :func:`json.loads` returned it).
    where : str
        Its key in the file (``stages[2].settings``): errors name ``where.key``.
    path : str, optional
        The file it was read from.
    """

    document: Mapping[str, JSONValue]
    where: str
    path: str | None = None

    @classmethod
    def of(cls, value: JSONValue, where: str, path: str | None = None) -> DocumentFields:
        """Return the fields of ``value``, which must be a JSON object (:class:`InputError` otherwise)."""
        if not isinstance(value, dict):
            raise InputError("not an object", path=path, field=where, expected="a JSON object")
        return cls(value, where, path)

    def fail(self, key: str, message: str, expected: str) -> InputError:
        """Return the error of one field: what is wrong and what was expected."""
        return InputError(message, path=self.path, field=f"{self.where}.{key}", expected=expected)

    def has(self, key: str) -> bool:
        """Whether the object holds ``key``."""
        return key in self.document

    def value(self, key: str) -> JSONValue:
        """Return the value of ``key`` as it is (:class:`InputError` when missing)."""
        if key not in self.document:
            raise self.fail(key, "missing key", "the keys of docs/formats.md")
        return self.document[key]

    def text(self, key: str) -> str:
        """Return the string ``key`` holds."""
        value = self.value(key)
        if not isinstance(value, str):
            raise self.fail(key, f"{value!r} is not a string", "a string")
        return value

    def optional_text(self, key: str) -> str | None:
        """Return the string ``key`` holds, or None when it is missing."""
        return self.text(key) if key in self.document else None

    def flag(self, key: str) -> bool:
        """Return the true/false ``key`` holds."""
        value = self.value(key)
        if not isinstance(value, bool):
            raise self.fail(key, f"{value!r} is not true or false", "true or false")
        return value

    def number(self, key: str) -> float:
        """Return the finite number ``key`` holds."""
        value = self.value(key)
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
            raise self.fail(key, f"{value!r} is not a finite number", "a finite number")
        return float(value)

    def optional_number(self, key: str) -> float | None:
        """Return the finite number ``key`` holds, or None (null or missing)."""
        return None if self.document.get(key) is None else self.number(key)

    def count(self, key: str) -> int:
        """Return the whole number ≥ 0 ``key`` holds."""
        value = self.value(key)
        if isinstance(value, bool) or not isinstance(value, int) or value < 0:
            raise self.fail(key, f"{value!r} is not a count", "a whole number >= 0")
        return value

    def numbers(self, key: str) -> tuple[float, ...]:
        """Return the list of finite numbers ``key`` holds."""
        value = self.value(key)
        if not isinstance(value, list) or not all(_finite(x) for x in value):
            raise self.fail(key, f"{value!r} is not a list of finite numbers", "a list of finite numbers")
        return tuple(float(x) for x in value if isinstance(x, int | float))

    def texts(self, key: str) -> tuple[str, ...]:
        """Return the list of strings ``key`` holds."""
        value = self.value(key)
        if not isinstance(value, list) or not all(isinstance(x, str) for x in value):
            raise self.fail(key, f"{value!r} is not a list of strings", "a list of strings")
        return tuple(x for x in value if isinstance(x, str))

    def fields(self, key: str) -> DocumentFields:
        """Return the fields of the object ``key`` holds."""
        return DocumentFields.of(self.value(key), f"{self.where}.{key}", self.path)

    def objects(self, key: str) -> tuple[DocumentFields, ...]:
        """Return the fields of each object of the list ``key`` holds."""
        value = self.value(key)
        if not isinstance(value, list):
            raise self.fail(key, "not a list", "a list of objects")
        return tuple(DocumentFields.of(item, f"{self.where}.{key}[{k}]", self.path) for k, item in enumerate(value))


def _finite(value: JSONValue) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)
