"""Numbers as the certificate prints them: GUM 7.2.6 rounding, significant digits, a true minus sign.

One place for every rounding rule of the certificate: :func:`gum` rounds a value with its standard and
expanded uncertainty (``U = k u`` and ``u`` to two significant digits, the value to the decimal place of
``U``; below :data:`SMALLEST_FIXED_POINT` written as ``m×10ⁿ``), :func:`number` and
:func:`round_to_uncertainty` the single numbers around it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

COVERAGE_FACTOR = 2.0

MINUS = "\u2212"


@dataclass(frozen=True)
class Rounded:
    """A value with its standard and expanded uncertainty as printed (GUM 7.2.6, :func:`gum`)."""

    value: str
    u: str
    expanded: str


def gum(value: float, u: float, k: float = COVERAGE_FACTOR) -> Rounded:
    """Round a value and its uncertainty the one way of the certificate (GUM 7.2.6).

    ``U = k u`` and ``u`` to two significant digits, the value to the decimal place of ``U``.  Every section prints
    a value and its uncertainty through this function.
    """
    if not math.isfinite(value):
        return Rounded("not stated", "—", "—")
    if not (math.isfinite(u) and u > 0):
        return Rounded(number(value, 6), "—", "—")
    expanded = k * u
    if expanded < SMALLEST_FIXED_POINT:
        return _gum_scientific(value, u, expanded)
    decimals = max(1 - math.floor(math.log10(expanded)), 0)
    text = f"{value:.{decimals}f}"
    if float(text) == 0.0:
        text = text.lstrip("-")
    return Rounded(text.replace("-", MINUS), number(u, 2), number(expanded, 2))


#: Below this expanded uncertainty (in the engineering unit) the certificate writes ``m×10ⁿ``: a fixed-point
#: value to the last digit of ``U`` would need more than four zeros after the decimal point.
SMALLEST_FIXED_POINT = 1e-3


def _gum_scientific(value: float, u: float, expanded: float) -> Rounded:
    """Round as :func:`gum` does, written as mantissa×10ⁿ with the power of ``U`` (``−3.6×10⁻⁸``)."""
    power = math.floor(math.log10(expanded))
    superscript = str(power).translate(str.maketrans("-0123456789", "⁻⁰¹²³⁴⁵⁶⁷⁸⁹"))

    def scaled(x: float, decimals: int = 1) -> str:
        text = f"{x / 10.0**power:.{decimals}f}"
        if float(text) == 0.0:
            text = text.lstrip("-")
        return f"{text}×10{superscript}".replace("-", MINUS)

    # U's mantissa lies in [1, 10): one decimal is two significant digits; u = U/k may fall below 1
    return Rounded(scaled(value), scaled(u, 1 if u / 10.0**power >= 1 else 2), scaled(expanded))


def number(x: float, significant: int) -> str:
    """``x`` to ``significant`` significant digits, fixed-point, with a true minus sign."""
    if x == 0 or not math.isfinite(x):
        return "0" if x == 0 else str(x)
    decimals = max(significant - 1 - math.floor(math.log10(abs(x))), 0)
    return f"{x:.{decimals}f}".replace("-", MINUS)


def round_to_uncertainty(value: float, u: float) -> str:
    """Round the value to the last digit of ``u`` given to two significant digits (GUM 7.2.6)."""
    decimals = max(1 - math.floor(math.log10(u)), 0)
    return f"{value:.{decimals}f}".replace("-", MINUS)


def decimals_of(u: float) -> int:
    """Decimal places of ``u`` given to two significant digits."""
    return max(1 - math.floor(math.log10(u)), 0) if u > 0 and math.isfinite(u) else 0
