"""Argument types of the command line: every numeric option is checked for its range when it is parsed.

A value out of range (``nan``, ``inf``, a negative timeout, a chunk of 1e-300 s) stops the command before
anything is read or written, with argparse's one-line message and exit status 2:
``stableins: error: argument --timeout: -1 is out of range (expected a number of seconds in [0.1, 3600])``.
The ranges are listed in ``docs/cli.md``.  Path types refuse a directory where a file is written and a
file where a directory is.
"""

from __future__ import annotations

import argparse
import math
import os
from collections.abc import Callable
from pathlib import Path

from stableins.identifiers import FILE_STEM_RULE, SEED_RANGE, is_file_stem

#: Seeds of the random generators (numpy's SeedSequence takes non-negative integers).


def _bounds(minimum: float | None, maximum: float | None, *, above: bool) -> str:
    low = "-inf" if minimum is None else f"{minimum:g}"
    high = "inf" if maximum is None else f"{maximum:g}"
    return f"{'(' if above or minimum is None else '['}{low}, {high}{']' if maximum is not None else ')'}"


def real(
    minimum: float | None = None,
    maximum: float | None = None,
    *,
    above: bool = False,
    unit: str = "",
    or_zero: bool = False,
) -> Callable[[str], float]:
    """Return a type that accepts a finite float in ``[minimum, maximum]``.

    ``above`` excludes the minimum (``(minimum, maximum]``); ``or_zero`` also allows 0.
    """
    what = f"a number{' of ' + unit if unit else ''} in {_bounds(minimum, maximum, above=above)}{' or 0' if or_zero else ''}"

    def parse(text: str) -> float:
        try:
            if not text.isascii() or "_" in text:  # float() also reads 1_0 and full-width digits
                raise ValueError(text)
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a number (expected {what})") from None
        if or_zero and value == 0.0:
            return 0.0
        if (
            not math.isfinite(value)
            or (minimum is not None and (value <= minimum if above else value < minimum))
            or (maximum is not None and value > maximum)
        ):
            raise argparse.ArgumentTypeError(f"{text} is out of range (expected {what})")
        return value

    parse.__name__ = "number"
    return parse


def integer(minimum: int | None = None, maximum: int | None = None, *, what: str = "an integer") -> Callable[[str], int]:
    """Return a type that accepts a whole number in ``[minimum, maximum]`` (decimal digits; ``1e3`` and ``1.5`` are refused)."""
    expected = f"{what} in {_bounds(minimum, maximum, above=False)}"

    def parse(text: str) -> int:
        stripped = text.strip()
        digits = stripped[1:] if stripped[:1] in "+-" else stripped
        if not digits.isascii() or not digits.isdigit() or len(digits) > 30:
            raise argparse.ArgumentTypeError(f"{text!r} is not a whole number (expected {expected})")
        value = int(stripped)
        if (minimum is not None and value < minimum) or (maximum is not None and value > maximum):
            raise argparse.ArgumentTypeError(f"{text} is out of range (expected {expected})")
        return value

    parse.__name__ = "integer"
    return parse


#: ``--seed``: a non-negative integer.
seed = integer(*SEED_RANGE, what="a seed")


def output_file(text: str) -> Path:
    """Accept a file to write: not an existing directory, and not inside something that is not a directory."""
    path = Path(text)
    if not text.strip():
        raise argparse.ArgumentTypeError("an empty path (expected a file to write)")
    if path.is_dir():
        raise argparse.ArgumentTypeError(f"{text} is a directory (expected a file to write)")
    parent = path.parent
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    if parent.exists() and not parent.is_dir():
        raise argparse.ArgumentTypeError(f"{parent} is a file, not a directory (expected a file to write in a directory)")
    return path


def png_file(text: str) -> Path:
    """Accept a PNG figure to write (``--plot``): a file to write whose name ends in ``.png``.

    A figure written as PNG bytes under another suffix (``--plot a.txt``) would be a file no program reads as what its
    name says (issue 31).
    """
    path = output_file(text)
    if path.suffix.lower() != ".png":
        raise argparse.ArgumentTypeError(f"{text}: a PNG figure is written here (expected a file name ending in .png)")
    return path


def output_directory(text: str) -> Path:
    """Accept a directory to write into: an existing directory or a path that can become one."""
    path = Path(text)
    if not text.strip():
        raise argparse.ArgumentTypeError("an empty path (expected a directory)")
    probe = path
    while not probe.exists() and probe != probe.parent:
        probe = probe.parent
    if probe.exists() and not probe.is_dir():
        raise argparse.ArgumentTypeError(f"{probe} is a file, not a directory (expected a directory)")
    return path


def file_stem(text: str) -> str:
    """Accept a name that becomes part of a file name inside an output directory (``stableins.identifiers``)."""
    if not is_file_stem(text):
        raise argparse.ArgumentTypeError(f"{text[:70]!r} cannot name a file (expected {FILE_STEM_RULE})")
    return text


def input_file(text: str) -> str:
    """Accept a file to read: it exists and is not a directory (what it holds is checked by the reader)."""
    if os.path.isdir(text):
        raise argparse.ArgumentTypeError(f"{text} is a directory (expected a file)")
    if not os.path.exists(text):
        raise argparse.ArgumentTypeError(f"{text}: no such file")
    return text


def effect_magnitude(text: str) -> tuple[str, float]:
    """``ID=VALUE`` → ``(ID, VALUE in SI)``: an effect of the simulator's catalogue and its magnitude (argparse type).

    The one parser of every option that takes an effect magnitude (``simulate --hidden``, ``demo --hidden``).  VALUE is
    a number with the effect's engineering unit (``Kcc_xxy=60ug/g2``, ``K3_x=100 µg/g³``, ``nonorth_12=30arcsec``) or
    its SI unit, or a bare number in SI (``Kcc_xxy=6e-6``); ``stableins simulate --list-effects`` lists both units.
    """
    key, sep, value = text.partition("=")
    key = key.strip()
    if not sep or not key or not value.strip():
        raise argparse.ArgumentTypeError(f"{text!r} is not ID=VALUE (e.g. Kcc_xxy=60ug/g2; see stableins simulate --list-effects)")
    from stableins.discovery.library import all_terms
    from stableins.simulator.effects import CATALOGUE

    effect, term = CATALOGUE.get(key), all_terms().get(key)
    if effect is None or term is None:
        expected = "an id of 'stableins simulate --list-effects'"
        raise argparse.ArgumentTypeError(f"{key!r} is not an effect of the simulator (expected {expected})")
    try:
        return key, term.parse_value(value, si_units=(effect.unit,))
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None
