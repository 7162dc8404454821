"""Identifiers a user gives: names that become part of file names, serial numbers, seeds, time stamps.

A name the user types (``design --name``, a campaign's task names) becomes part of a file name under an output
directory.  It must neither leave that directory (``../x``, ``a/b``), nor hide (``.x``), nor be empty: one
pattern, :data:`FILE_STEM`, decides, so every command that writes ``DIR/NAME-something`` refuses the same names
(docs/formats.md, "Names").  A seed names a simulated unit and its random streams: every command and campaign
admits the same range, :data:`SEED_RANGE`.  A unit's serial number names its folder in the history store and its
report ids, so it obeys :data:`SERIAL_NUMBER` wherever it is read.  A time stamp of a record (``created``,
``data_start``, ``data_end``) is ISO 8601 with its offset (:func:`check_timestamp`).
"""

from __future__ import annotations

import re
from datetime import UTC, datetime
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


#: A serial number that can name a folder on every file system stableins runs on (the history store's unit folders).
SERIAL_NUMBER = re.compile(r"[^\x00-\x1f/\\:*?\"<>|]{1,128}")
#: What :data:`SERIAL_NUMBER` admits, in words.
SERIAL_NUMBER_RULE = "1 to 128 printable characters without / \\ : * ? \" < > |, not starting with '.' or a space"


def check_serial_number(serial: object, *, field: str = "serial_number", path: str | None = None) -> str:
    """Return ``serial`` if it can name a unit's folder and its reports.

    Raises
    ------
    InputError
        ``serial`` holds a path separator or a character a file system refuses, starts with ``.`` or a space, or is
        empty (docs/formats.md, "Names").
    """
    if not isinstance(serial, str) or not SERIAL_NUMBER.fullmatch(serial) or serial.strip() != serial or serial.startswith("."):
        raise InputError(
            f"serial number {str(serial)[:40]!r} cannot name a history folder or a report",
            path=path,
            field=field,
            expected=SERIAL_NUMBER_RULE,
        )
    return serial


def utc_now() -> str:
    """Return the current UTC time as ISO 8601, to the second (the time stamps stableins writes)."""
    return datetime.now(UTC).replace(microsecond=0).isoformat()


def parse_timestamp(text: object, *, field: str, path: str | None = None) -> datetime:
    """Read an ISO 8601 date or date-time (``2026-03-01``, ``2026-03-01T12:00:00Z``); a time without offset is UTC.

    Raises
    ------
    InputError
        Not a string, or not ISO 8601 (``"yesterday"``, ``"soon"``).
    """
    try:
        value = datetime.fromisoformat(text.replace("Z", "+00:00")) if isinstance(text, str) else None
    except ValueError:
        value = None
    if value is None:
        raise InputError(
            f"cannot read {str(text)[:40]!r} as a date",
            path=path,
            field=field,
            expected="ISO 8601, e.g. 2026-03-01 or 2026-03-01T12:00:00Z",
        )
    return value if value.tzinfo else value.replace(tzinfo=UTC)


def check_timestamp(text: object, *, field: str, path: str | None = None, optional: bool = False) -> str:
    """Return ``text`` if :func:`parse_timestamp` reads it; ``optional``: the empty string (a time not known) passes.

    Raises
    ------
    InputError
        As :func:`parse_timestamp`.
    """
    if optional and text == "":
        return ""
    parse_timestamp(text, field=field, path=path)
    assert isinstance(text, str)
    return text
