"""Numbers as the certificate prints them: GUM 7.2.6 rounding, significant digits, a true minus sign.

One place for every rounding rule of the certificate: :func:`gum` rounds a value with its standard and
expanded uncertainty (``U = k u`` and ``u`` to two significant digits, the value to the decimal place of
``U``; below :data:`SMALLEST_FIXED_POINT` each written ``m×10ⁿ`` with ``1 ≤ m < 10``, to that digit, :func:`times_ten`);
:func:`like_uncertainty` writes a number the way :func:`gum` writes ``u`` (the budget's contributions);
:func:`significant_digits`, :func:`round_to_uncertainty` and :func:`scientific` the single numbers around it;
:func:`superscript` the exponents.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from stableins.reporting.symbols import MINUS

COVERAGE_FACTOR = 2.0


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
        return Rounded(significant_digits(value, 6), "—", "—")
    expanded = k * u
    if _rounded(expanded) < SMALLEST_FIXED_POINT:
        return _gum_scientific(value, u, expanded)
    decimals = max(1 - _power(expanded), 0)
    text = f"{value:.{decimals}f}"
    if float(text) == 0.0:
        text = text.lstrip("-")
    return Rounded(text.replace("-", MINUS), significant_digits(u, 2), significant_digits(expanded, 2))


#: Below this expanded uncertainty (in the engineering unit) the certificate writes ``m×10ⁿ``: a fixed-point
#: value to the last digit of ``U`` would need more than four zeros after the decimal point.
SMALLEST_FIXED_POINT = 1e-3


def _gum_scientific(value: float, u: float, expanded: float) -> Rounded:
    """Round as :func:`gum` does, each number written ``m×10ⁿ`` (``1 ≤ m < 10``) to ``U``'s last digit (``−3.6×10⁻⁸``)."""
    power = _power(expanded)
    return Rounded(times_ten(value, power, 1), times_ten(u, power, _u_decimals(u, power)), times_ten(expanded, power, 1))


def _u_decimals(u: float, power: int) -> int:
    """Return the decimals of ``u``'s mantissa at ``U``'s power (two significant digits).

    U's mantissa lies in [1, 10): one decimal is two significant digits; ``u = U/k`` may fall below 1 and then keeps two.
    """
    return 1 if _rounded(u) / 10.0**power >= 1 else 2


_SUPERSCRIPT = str.maketrans("-0123456789", "⁻⁰¹²³⁴⁵⁶⁷⁸⁹")


def superscript(power: int) -> str:
    """Return an integer in superscript digits (``−8`` → ``⁻⁸``), the exponent of ``×10ⁿ``."""
    return str(power).translate(_SUPERSCRIPT)


def times_ten(x: float, power: int, decimals: int) -> str:
    """Write ``x`` to the digit ``10^(power − decimals)`` in one style, ``m×10ⁿ`` with ``1 ≤ m < 10`` (``−3.6×10⁻⁸``).

    The last digit is where the GUM puts it (``power`` and ``decimals`` of ``U``'s mantissa, :func:`gum`); the power of
    ten is the number's own, so a column of a table never mixes ``0.8×10⁻⁵`` with ``1.8×10⁻⁵``: ``8×10⁻⁶`` beside it.
    A number below the last digit is ``0``.
    """
    place = power - decimals
    steps = round(x / 10.0**place)  # the number in units of its last digit
    if steps == 0:
        return "0"
    digits = str(abs(steps))
    mantissa = digits[0] + (f".{digits[1:]}" if len(digits) > 1 else "")
    sign = MINUS if steps < 0 else ""
    return f"{sign}{mantissa}×10{superscript(place + len(digits) - 1)}"


def like_uncertainty(x: float, u: float, k: float = COVERAGE_FACTOR) -> str:
    """Write ``x`` the way :func:`gum` writes the uncertainty ``u``: to the decimal place of ``u`` at two significant digits.

    Fixed point, or ``m×10ⁿ`` (``1 ≤ m < 10``) to ``u``'s last digit when ``U = k u`` is below
    :data:`SMALLEST_FIXED_POINT` (the contributions of the uncertainty budget beside ``u`` and ``U``); there a number
    below ``u``'s last digit is written ``0``, without a power of ten.
    """
    expanded = k * u
    if _rounded(expanded) < SMALLEST_FIXED_POINT:
        power = _power(expanded)
        return times_ten(x, power, _u_decimals(u, power))
    return f"{x:.{decimals_of(u)}f}".replace("-", MINUS)


def scientific(x: float, significant: int = 2) -> str:
    """Write a number in scientific notation for people, ``5.0 × 10⁻⁷`` (prose; tables use :func:`times_ten`)."""
    mantissa, exponent = f"{x:.{significant - 1}e}".split("e")
    return f"{mantissa} × 10{superscript(int(exponent))}".replace("-", MINUS)


def significant_digits(x: float, significant: int) -> str:
    """``x`` to ``significant`` significant digits, fixed-point, with a true minus sign."""
    if x == 0 or not math.isfinite(x):
        return "0" if x == 0 else str(x)
    decimals = max(significant - 1 - _power(x, significant), 0)
    return f"{x:.{decimals}f}".replace("-", MINUS)


def round_to_uncertainty(value: float, u: float) -> str:
    """Round the value to the last digit of ``u`` given to two significant digits (GUM 7.2.6)."""
    decimals = max(1 - _power(u), 0)
    return f"{value:.{decimals}f}".replace("-", MINUS)


def decimals_of(u: float) -> int:
    """Decimal places of ``u`` given to two significant digits."""
    return max(1 - _power(u), 0) if u > 0 and math.isfinite(u) else 0


def _rounded(x: float, significant: int = 2) -> float:
    """``|x|`` rounded to ``significant`` significant digits (9.989 → 10)."""
    return abs(float(f"{x:.{significant - 1}e}"))


def _power(x: float, significant: int = 2) -> int:
    """Return the power of ten of ``x`` rounded to ``significant`` digits: 9.989 at two digits is 10, power 1, not 0.

    Every decimal place above is counted from it, so that ``U = 9.989`` is written ``10`` (two significant digits, not
    ``10.0``) and the value to the units (GUM 7.2.6).
    """
    return math.floor(math.log10(_rounded(x, significant)))
