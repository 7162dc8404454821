"""Reading a :class:`~stableins.noise.NoiseModel` back from its JSON form (:meth:`~stableins.noise.NoiseModel.to_document`).

Every field is validated; a bad one raises :class:`stableins.errors.InputError` naming the file, the field
(under ``prefix``, e.g. ``noise_model.axes.x.white.upper``) and what was expected.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from stableins.errors import InputError
from stableins.noise import AXES, SI_UNITS, TERMS, AxisNoise, NoiseModel, NoiseSource, NoiseTerm, SlowNoiseTest


@dataclass(frozen=True)
class _Fields:
    """Checks of the fields of one document, with the file and the prefix its error messages name."""

    path: str | None
    prefix: str

    def fail(self, message: str, key: str, expected: str) -> InputError:
        """Return the error for field ``key`` (the prefix alone when empty)."""
        return InputError(message, path=self.path, field=f"{self.prefix}.{key}" if key else self.prefix, expected=expected)

    def number(self, value: Any, key: str, *, allow_null: bool = False, lo: float = 0.0) -> float:
        """Return ``value`` as a finite number ``>= lo`` (null: infinite, when ``allow_null``)."""
        if value is None and allow_null:
            return math.inf
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value) or value < lo:
            raise self.fail(
                f"{value!r} is not a finite number >= {lo:g}", key, "a finite non-negative number" + (" or null" if allow_null else "")
            )
        return float(value)

    def header(self, document: Any) -> tuple[NoiseSource, str, float]:
        """Return source, provenance and confidence, with the units checked to be SI."""
        if not isinstance(document, dict):
            raise self.fail("not an object", "", '{"source", "provenance", "confidence", "axes": {"x": {...}, ...}}')
        sources = {s.value: s for s in NoiseSource}
        if document.get("source") not in sources:
            raise self.fail(f"unknown source {document.get('source')!r}", "source", " or ".join(repr(s) for s in sources))
        provenance = document.get("provenance", "")
        if not isinstance(provenance, str):
            raise self.fail(f"{provenance!r} is not a string", "provenance", "a string")
        confidence = self.number(document.get("confidence", 0.95), "confidence")
        if not 0.0 < confidence < 1.0:
            raise self.fail(f"{confidence!r} is not a probability", "confidence", "a number between 0 and 1")
        units = document.get("units", SI_UNITS)
        if not isinstance(units, dict) or any(units.get(k, SI_UNITS[k]) != SI_UNITS[k] for k in TERMS):
            raise self.fail(f"units {units!r}", "units", f"the SI units {dict(SI_UNITS)}")
        return sources[document["source"]], provenance, confidence

    def axes(self, axes_doc: Any) -> tuple[AxisNoise, AxisNoise, AxisNoise]:
        """Return the three axes' terms."""
        if not isinstance(axes_doc, dict) or set(axes_doc) != set(AXES):
            raise self.fail("missing or malformed", "axes", 'an object with keys "x", "y", "z"')
        x, y, z = (self.axis(axes_doc[ax], ax) for ax in AXES)
        return x, y, z

    def axis(self, entry: Any, ax: str) -> AxisNoise:
        """Return the terms of axis ``ax``."""
        if not isinstance(entry, dict) or set(entry) != set(TERMS):
            raise self.fail("missing or malformed", f"axes.{ax}", f"an object with the keys {', '.join(TERMS)}")
        terms = {}
        for name in TERMS:
            item = entry[name]
            key = f"axes.{ax}.{name}"
            if not isinstance(item, dict) or not {"value", "lower", "upper"} <= set(item):
                raise self.fail("missing or malformed", key, '{"value", "lower", "upper"}')
            value = self.number(item["value"], f"{key}.value")
            lower = self.number(item["lower"], f"{key}.lower")
            upper = self.number(item["upper"], f"{key}.upper", allow_null=True)
            if not lower <= value <= upper:
                raise self.fail(f"interval [{lower}, {upper}] does not hold the value {value}", key, "lower <= value <= upper")
            terms[name] = NoiseTerm(value, lower, upper)
        return AxisNoise(**terms)

    def test(self, t: Any) -> SlowNoiseTest | None:
        """Return the slow-noise test (None when the document has none)."""
        if t is None:
            return None
        if not isinstance(t, dict):
            raise self.fail("not an object", "test", '{"statistic", "p_value", "alpha"}')
        statistic = self.number(t.get("statistic"), "test.statistic", lo=-math.inf)
        p_value = self.number(t.get("p_value"), "test.p_value")
        alpha = self.number(t.get("alpha"), "test.alpha")
        if p_value > 1.0 or not 0.0 < alpha < 1.0:
            raise self.fail("p_value or alpha outside (0, 1)", "test", "probabilities")
        return SlowNoiseTest(statistic, p_value, alpha)


def noise_model_from_document(document: Any, path: str | None = None, prefix: str = "noise_model") -> NoiseModel:
    """Return the model a :meth:`~stableins.noise.NoiseModel.to_document` form describes, every field validated.

    Raises
    ------
    InputError
        A field is missing or malformed: names ``path`` and the field under ``prefix``, and what was expected.
    """
    fields = _Fields(path, prefix)
    source, provenance, confidence = fields.header(document)
    axes = fields.axes(document.get("axes"))
    return NoiseModel(axes, source, provenance, confidence, fields.test(document.get("test")))
