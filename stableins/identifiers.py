"""Identifiers a user gives: names that become part of file names, and seeds of the simulated world.

A name the user types (``design --name``, a campaign's task names) becomes part of a file name under an output
directory.  It must neither leave that directory (``../x``, ``a/b``), nor hide (``.x``), nor be empty: one
pattern, :data:`FILE_STEM`, decides, so every command that writes ``DIR/NAME-something`` refuses the same names
(docs/formats.md, "Names").  A seed names a simulated unit and its random streams: every command and campaign
admits the same range, :data:`SEED_RANGE`.
"""

from __future__ import annotations

import re
from typing import TypeGuard

from stableins.errors import InputError

#: The seeds every command and campaign admits (inclusive): what ``numpy.random.SeedSequence`` takes as one
#: non-negative 64-bit word, kept below 2**63 so it is also a signed integer in every file format.
SEED_RANGE = (0, 2**63 - 1)

#: A file stem safe on every file system stableins runs on: a letter or digit, then up to 63 letters, digits,
#: ``_``, ``.`` or ``-``; no ``..`` (so no path can be spelled with it).
FILE_STEM = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}")
#: What :data:`FILE_STEM` admits, in words (the ``expected`` of every refusal).
FILE_STEM_RULE = "1 to 64 letters, digits, '_', '.' or '-', starting with a letter or digit, without '..' or '__'"


def is_file_stem(text: object) -> TypeGuard[str]:
    """Return whether ``text`` is a name :data:`FILE_STEM` admits (and holds neither ``..`` nor ``__``)."""
    return isinstance(text, str) and FILE_STEM.fullmatch(text) is not None and ".." not in text and "__" not in text


def check_file_stem(text: object, *, field: str, path: str | None = None) -> str:
    """Return ``text`` if it can name a file inside its output directory.

    Raises
    ------
    InputError
        ``text`` could leave the directory, hide, or is empty; the message names ``field`` (and ``path``).
    """
    if not is_file_stem(text):
        raise InputError(f"{str(text)[:70]!r} cannot name a file", path=path, field=field, expected=FILE_STEM_RULE)
    return text
