"""One safe JSON reader for every JSON document stableins reads.

Calibration records, the header block of a CSV file, the ``header`` attribute of an HDF5
file, procedure plans, ``--discovery`` documents, truth files, the history index, the
journal's record headers and the platform's ``META``/``STATUS`` replies all go through
:func:`parse_json` (text already in memory) or :func:`load_json_file` (a file).  Before
anything is trusted:

* the document is at most ``max_bytes`` long (the file size is checked before it is read);
* it is UTF-8 (a leading byte-order mark is accepted and dropped);
* it nests at most :data:`MAX_DEPTH` levels (``[[[[...]]]]`` would otherwise exhaust the
  interpreter's recursion limit);
* integers have at most :data:`MAX_INTEGER_DIGITS` digits (larger ones overflow every
  numeric type stableins uses, and Python refuses to convert more than 4300 digits);
* numbers are finite (``1e999`` reads as infinity; ``NaN``/``Infinity`` are not JSON) unless
  the caller allows non-finite numbers (the journal writes them);
* no object has the same key twice (``json`` would silently keep the last one).

Every violation raises :class:`~stableins.errors.InputError` naming the file and the
field: the JSON path of the offending value (``parameters[3].value``), prefixed with the
``field`` the caller gives (``header`` for an HDF5 attribute).  Checking the types of the
fields is the caller's business; :func:`expect_mapping`, :func:`expect_list`,
:func:`expect_text` and :func:`expect_number` say what was
expected in the same form.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Mapping
from typing import Any

from stableins.documents import JSONObject, JSONValue
from stableins.errors import InputError

#: Largest JSON document read from a file [bytes] (a record of 1000 parameters is ~25 MB).
MAX_DOCUMENT_BYTES = 64 << 20
#: Deepest nesting accepted (stableins writes at most 5 levels).
MAX_DEPTH = 64
#: Most digits of an integer (int64 and uint64 have at most 20).
MAX_INTEGER_DIGITS = 20


class _Bad:
    """A value the parser met that the document may not hold; reported with its JSON path by :func:`_walk`."""

    def __init__(self, message: str, expected: str) -> None:
        self.message = message
        self.expected = expected


class _Pairs(dict):
    """An object that had a key twice (the first duplicate kept in ``duplicate``)."""

    duplicate: str = ""


def _pairs(items: list[tuple[str, JSONValue]]) -> JSONObject:
    out: JSONObject = {}
    for key, value in items:
        if key in out:
            bad = _Pairs(out)
            bad.duplicate = key
            return bad
        out[key] = value
    return out


def _integer(text: str) -> Any:
    digits = len(text) - (text[0] == "-")
    if digits > MAX_INTEGER_DIGITS:
        return _Bad(f"integer of {digits} digits ({text[:12]}...)", f"a number of at most {MAX_INTEGER_DIGITS} digits")
    return int(text)


def _float(text: str) -> Any:
    value = float(text)
    if not math.isfinite(value):
        return _Bad(f"number {text[:24]!r} overflows a double", "a finite number")
    return value


def _strict_constant(text: str) -> Any:
    return _Bad(f"{text} is not a JSON number", "a finite number (null where a value is missing)")


def _join(base: str, key: Any) -> str:
    if isinstance(key, int):
        return f"{base}[{key}]"
    return f"{base}.{key}" if base else str(key)


def _walk(document: Any, path: Any, field: str, max_depth: int) -> None:
    """Raise for the first sentinel, duplicated key or too deep nesting (iteratively: no recursion)."""
    stack: list[tuple[Any, str, int]] = [(document, field, 0)]
    while stack:
        value, where, depth = stack.pop()
        if isinstance(value, _Bad):
            raise InputError(value.message, path=path, field=where or None, expected=value.expected)
        if isinstance(value, dict):
            if isinstance(value, _Pairs):
                raise InputError(f"key {value.duplicate!r} appears twice", path=path, field=where or None, expected="each key once")
            children: Any = value.items()
        elif isinstance(value, list):
            children = enumerate(value)
        else:
            continue
        if depth >= max_depth:
            shown = where if len(where) <= 80 else where[:77] + "..."
            raise InputError(
                f"nested more than {max_depth} levels deep", path=path, field=shown or None, expected=f"at most {max_depth} levels"
            )
        stack.extend((child, _join(where, key), depth + 1) for key, child in children)


def parse_json(
    text: str | bytes | bytearray,
    *,
    path: str | os.PathLike[str] | None = None,
    field: str = "",
    max_bytes: int = MAX_DOCUMENT_BYTES,
    max_depth: int = MAX_DEPTH,
    allow_nan: bool = False,
    what: str = "a JSON document",
) -> Any:
    """Parse one JSON document under the limits of the module docstring.

    Parameters
    ----------
    text : str or bytes
        The document (bytes are decoded as UTF-8, a leading byte-order mark dropped).
    path : path-like, optional
        File it came from (for messages).
    field : str
        Where in the file the document is (``header``, ``META``): prefixes the JSON path in messages.
    allow_nan : bool
        Accept ``NaN``, ``Infinity`` and numbers beyond the double range (read as ±inf).
    what : str
        What the document should be, for messages ("a calibration record").

    Raises
    ------
    InputError
        Naming the file, the field (JSON path) and what was expected.
    """
    size = len(text)
    if size > max_bytes:
        raise InputError(f"{size} bytes of JSON", path=path, field=field or None, expected=f"{what} of at most {max_bytes} bytes")
    if isinstance(text, bytes | bytearray):
        raw = bytes(text)
        try:
            text = raw.decode("utf-8-sig")
        except UnicodeDecodeError as error:
            raise InputError(
                f"not UTF-8 text (byte {error.start} is {raw[error.start : error.start + 1]!r})",
                path=path,
                field=field or None,
                expected=what,
            ) from None
    elif text.startswith("\ufeff"):
        text = text[1:]
    try:
        document = json.loads(
            text,
            object_pairs_hook=_pairs,
            parse_int=_integer,
            parse_float=float if allow_nan else _float,
            parse_constant=float if allow_nan else _strict_constant,
        )
    except json.JSONDecodeError as error:
        raise InputError(
            f"not valid JSON: {error.msg} at line {error.lineno} column {error.colno}", path=path, field=field or None, expected=what
        ) from None
    except RecursionError:
        raise InputError(
            f"nested more than {max_depth} levels deep", path=path, field=field or None, expected=f"at most {max_depth} levels"
        ) from None
    _walk(document, path, field, max_depth)
    return document


def read_input_bytes(path: str | os.PathLike[str], *, max_bytes: int, what: str) -> bytes:
    """Return the bytes of an input file, refusing (InputError) a missing file, a directory, an unreadable or too large one.

    The size is checked on the open file before it is read, so a huge file costs nothing.
    """
    try:
        handle = open(path, "rb")  # noqa: SIM115 - closed below
    except FileNotFoundError:
        raise InputError("file not found", path=path, expected=what) from None
    except IsADirectoryError:
        raise InputError("is a directory", path=path, expected=what) from None
    except OSError as error:
        raise InputError(f"cannot be read ({error.strerror or error})", path=path, expected=what) from None
    with handle:
        stat = os.fstat(handle.fileno())
        import stat as stat_module

        if stat_module.S_ISDIR(stat.st_mode):
            raise InputError("is a directory", path=path, expected=what)
        if stat.st_size > max_bytes:
            raise InputError(f"file of {stat.st_size} bytes", path=path, expected=f"{what} of at most {max_bytes} bytes")
        try:
            data = handle.read(max_bytes + 1)
        except OSError as error:
            raise InputError(f"cannot be read ({error.strerror or error})", path=path, expected=what) from None
    if len(data) > max_bytes:  # a file that grew, or a device without a size
        raise InputError(f"more than {max_bytes} bytes", path=path, expected=f"{what} of at most {max_bytes} bytes")
    return data


#: First bytes of files stableins reads or writes that are not JSON, and what each is.
OTHER_KINDS = (
    (b"\x89HDF\r\n\x1a\n", "an HDF5 data file"),
    (b"%PDF-", "a PDF document"),
    (b"\x89PNG\r\n\x1a\n", "a PNG image"),
    (b"SQLite format 3\x00", "an SQLite database (a history store's index)"),
    (b"# stableins-device", "a device data file (CSV)"),
    (b"PK\x03\x04", "a ZIP archive"),
)


def _refuse_other_kinds(path: str | os.PathLike[str], what: str) -> None:
    """Raise :class:`InputError` when the file's first bytes say it is another kind of file than the JSON ``what``."""
    try:
        with open(path, "rb") as handle:
            head = handle.read(32)
    except OSError:
        return  # read_input_bytes says why
    for magic, kind in OTHER_KINDS:
        if head.startswith(magic):
            raise InputError(f"this is {kind}, not {what} (arguments swapped?)", path=path)


def load_json_file(
    path: str | os.PathLike[str],
    *,
    max_bytes: int = MAX_DOCUMENT_BYTES,
    max_depth: int = MAX_DEPTH,
    allow_nan: bool = False,
    what: str = "a JSON document",
) -> Any:
    """Read and parse a JSON file under the limits of the module docstring (InputError naming the file and field).

    A file that is recognizably something else (an HDF5 data file, a PDF, a device CSV ...) is named as what it is,
    before its size is judged: "this is an HDF5 data file, not a calibration record (arguments swapped?)".
    """
    _refuse_other_kinds(path, what)
    data = read_input_bytes(path, max_bytes=max_bytes, what=what)
    return parse_json(data, path=path, max_bytes=max_bytes, max_depth=max_depth, allow_nan=allow_nan, what=what)


# --------------------------------------------------------------------------- field checks
def expect_mapping(value: Any, path: Any, field: str, expected: str = "a JSON object") -> Mapping[str, Any]:
    """Return ``value`` if it is a JSON object, else raise :class:`InputError` naming ``path`` and ``field``."""
    if not isinstance(value, Mapping):
        raise InputError(f"{_shown(value)} is not an object", path=path, field=field, expected=expected)
    return value


def expect_list(value: Any, path: Any, field: str, expected: str = "a list") -> list[Any]:
    """Return ``value`` if it is a list, else raise :class:`InputError` naming ``path`` and ``field``."""
    if not isinstance(value, list):
        raise InputError(f"{_shown(value)} is not a list", path=path, field=field, expected=expected)
    return value


def expect_text(value: Any, path: Any, field: str, expected: str = "a string") -> str:
    """Return ``value`` if it is a string, else raise :class:`InputError` naming ``path`` and ``field``."""
    if not isinstance(value, str):
        raise InputError(f"{_shown(value)} is not a string", path=path, field=field, expected=expected)
    return value


def expect_number(
    value: Any,
    path: Any,
    field: str,
    *,
    minimum: float | None = None,
    maximum: float | None = None,
    positive: bool = False,
    expected: str = "a finite number",
) -> float:
    """Return a finite JSON number (not a boolean) within the bounds given."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise InputError(f"{_shown(value)} is not a number", path=path, field=field, expected=expected)
    try:
        number = float(value)
    except OverflowError:
        raise InputError(f"{_shown(value)} is out of range", path=path, field=field, expected=expected) from None
    if not math.isfinite(number):
        raise InputError(f"{_shown(value)} is not finite", path=path, field=field, expected=expected)
    if (positive and not number > 0) or (minimum is not None and number < minimum) or (maximum is not None and number > maximum):
        raise InputError(f"{_shown(value)} is out of range", path=path, field=field, expected=expected)
    return number


def _shown(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."
