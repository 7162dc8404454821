"""CSV files with a ``#``-comment JSON header (small data; see ``docs/formats.md``).

Layout::

    # stableins-device data file, see docs/formats.md. ...
    # BEGIN HEADER
    # { "format": "stableins-device", "schema_version": 1, "end_marker": true, "metadata": {...} }
    # END HEADER
    time[s],stage,pass,position,...
    0.01,coarse,1,1,...
    # END OF DATA: 2000 rows

Every line starting with ``#`` is a comment for pandas (``read_csv(path, comment="#")``),
numpy (``genfromtxt((l for l in open(path) if l[0] != "#"), delimiter=",", names=True,
dtype=None, encoding="utf-8")``), the ``csv`` module and spreadsheets; the JSON between ``BEGIN HEADER`` and ``END HEADER`` is the header
document.  The trailer line carries the row count: a file that lacks it (when the header
announces it with ``"end_marker": true``) or whose count disagrees was cut short.
"""

from __future__ import annotations

import json
import os
import re
from collections.abc import Iterable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import IO, Any

from stableins.data.validation import check_finite, check_header_document, match_columns, parse_header
from stableins.errors import InputError
from stableins.schema import Column, Columns

BEGIN = "# BEGIN HEADER"
END = "# END HEADER"
TRAILER = "# END OF DATA:"
#: Longest line read [characters]: a data row is ~300; a longer line is refused after reading this much.
MAX_LINE = 1 << 20
#: Largest JSON header block [characters].
MAX_HEADER = 1 << 20
#: A chunk of rows holds at most this many characters of text (whatever ``rows`` asks for).
MAX_CHUNK_TEXT = 16 << 20
#: A number field: ASCII digits only, no underscores (Python's float() accepts both); nan/inf pass to be named as not finite.
_NUMBER = re.compile(r"\s*[+-]?(?:(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?|nan|inf|infinity)\s*", re.ASCII | re.IGNORECASE)
_TRAILER_COUNT = re.compile(r"([0-9]{1,19})(?:\s+rows?)?", re.ASCII)


def header_text(kind: str, document: Mapping[str, Any], schema: Sequence[Column]) -> str:
    """Comment block with the JSON header, then the column-header line."""
    body = _layout(document)
    lines = [
        f"# stableins-{kind} data file, format described in docs/formats.md of the stableins sources.",
        "# Lines starting with '#' are comments: pandas.read_csv(path, comment='#') reads the table;",
        "# the JSON between BEGIN HEADER and END HEADER holds format, schema version and site metadata (units explicit).",
        BEGIN,
        *("# " + line for line in body.splitlines()),
        END,
        ",".join(c.header for c in schema),
    ]
    return "\n".join(lines) + "\n"


def _layout(value: Any, depth: int = 0) -> str:
    """JSON with the top two levels of objects one key per line and everything deeper inline."""
    if isinstance(value, dict) and depth < 2 and value:
        pad = "  " * (depth + 1)
        items = [f"{pad}{json.dumps(k)}: {_layout(v, depth + 1)}" for k, v in value.items()]
        return "{\n" + ",\n".join(items) + "\n" + "  " * depth + "}"
    return json.dumps(value, allow_nan=False)


def format_rows(data: Mapping[str, Any], schema: Sequence[Column]) -> str:
    """Rows as text; floats with ``repr`` (shortest string that reads back exactly)."""
    import numpy as np

    columns = []
    for c in schema:
        values = np.asarray(data[c.name])
        if c.dtype == "float64":
            columns.append(list(map(repr, values.astype(float).tolist())))
        elif c.dtype == "int32":
            columns.append(list(map(str, values.astype(int).tolist())))
        else:
            columns.append([str(v) for v in values.tolist()])
    if not columns or not columns[0]:
        return ""
    return "\n".join(",".join(row) for row in zip(*columns)) + "\n"


def trailer_text(rows: int) -> str:
    """Return the trailer line that closes a file of ``rows`` data rows."""
    return f"{TRAILER} {rows} rows\n"


def open_text(path: str) -> IO[str]:
    """Open a CSV file for reading (UTF-8; a byte-order mark, as spreadsheets write, is dropped)."""
    try:
        return open(path, encoding="utf-8-sig", newline="")  # noqa: SIM115 - the caller closes it
    except FileNotFoundError:
        raise InputError("no such file", path=path) from None
    except IsADirectoryError:
        raise InputError("is a directory", path=path, expected="a CSV file") from None
    except OSError as error:
        raise InputError(f"cannot open: {error.strerror or error}", path=path) from None


def read_line(handle: IO[str], path: str, line_number: int) -> str:
    """One line of at most :data:`MAX_LINE` characters (a longer one is refused after reading that much: bounded memory)."""
    try:
        line = handle.readline(MAX_LINE + 1)
    except UnicodeDecodeError:
        raise InputError("not a text file (bad UTF-8)", path=path, expected="a CSV file") from None
    except IsADirectoryError:
        raise InputError("is a directory", path=path, expected="a CSV file") from None
    except OSError as error:
        raise InputError(f"cannot be read ({error.strerror or error})", path=path) from None
    if len(line) > MAX_LINE:
        raise InputError(
            f"line {line_number} is longer than {MAX_LINE} characters (a data row has a few hundred)",
            path=path,
            expected="a stableins CSV file",
        )
    return line


def _scan_header(readline: Any, path: str) -> tuple[str, list[str], str]:
    """Read lines up to the column-header line: return where the header block stood, its JSON lines and that line.

    The state is ``"before"`` (no BEGIN HEADER seen), ``"inside"`` (no END HEADER) or ``"after"``.
    """
    json_lines: list[str] = []
    size = 0
    state = "before"
    while True:
        line = readline()
        if not line:
            raise InputError("file ends before the column-header line", path=path, expected="a complete stableins CSV file")
        text = line.rstrip("\r\n")
        if text.startswith("#"):
            if text.strip() == BEGIN:
                state = "inside"
            elif text.strip() == END:
                state = "after"
            elif state == "inside":
                json_lines.append(text[1:])
                size += len(text)
                if size > MAX_HEADER:
                    raise InputError(f"header block longer than {MAX_HEADER} characters", path=path, field="header")
            continue
        if text.strip():
            return state, json_lines, text


def read_header_block(readline: Any, path: str) -> tuple[Any, list[str]]:
    """Read the JSON header document and the column headers, lines with ``readline()`` up to the column-header line."""
    from stableins.data.jsonio import parse_json

    state, json_lines, text = _scan_header(readline, path)
    if state == "before":
        raise InputError("no header block (BEGIN HEADER ... END HEADER)", path=path, expected="the JSON header of docs/formats.md")
    if state == "inside":
        raise InputError("header block has no END HEADER line", path=path, expected="a complete JSON header")
    document = parse_json("\n".join(json_lines), path=path, field="header", what="the JSON header of docs/formats.md")
    return document, text.split(",")


def integer_column(values: Any, raw: Any, name: str, path: str, first_row: int) -> Any:
    """Return a float column that must hold whole numbers in the int32 range, as int32 (InputError naming the row otherwise)."""
    import numpy as np

    values = np.asarray(values)
    with np.errstate(invalid="ignore"):
        whole = np.isfinite(values) & (values == np.round(values)) & (np.abs(values) <= np.iinfo(np.int32).max)
    if not whole.all():
        k = int(np.argmin(whole))
        shown = raw[k] if raw is not None else repr(values[k].item())
        raise InputError(
            f"{shown!r} is not an integer", path=path, row=first_row + k, field=name, expected=f"an integer below {np.iinfo(np.int32).max}"
        )
    return values.astype(np.int32)


class CsvReader:
    """Streaming reader of one stableins CSV file (validates as it goes).

    Parameters
    ----------
    path : path-like
        The file.
    kind : str
        ``"device"`` or ``"system"``.
    schema : sequence of Column
        Expected columns.
    """

    def __init__(self, path: str | os.PathLike[str], kind: str, schema: Sequence[Column]) -> None:
        self.path = str(path)
        self.kind = kind
        self.schema = tuple(schema)
        self._handle: IO[str] | None = None
        self.line_number = 0
        self._handle = open_text(self.path)
        try:
            self.document, headers = read_header_block(self._readline, self.path)
            check_header_document(self.document, kind, self.path)
            self.positions = match_columns([parse_header(h) for h in headers], self.schema, self.path)
        except BaseException:
            self.close()
            raise
        self.n_fields = len(headers)
        self.rows_read = 0
        self.trailer_rows: int | None = None

    # ------------------------------------------------------------------ header
    def _readline(self) -> str:
        assert self._handle is not None
        self.line_number += 1
        return read_line(self._handle, self.path, self.line_number)

    # ------------------------------------------------------------------ rows
    def iter_chunks(self, rows: int = 65536) -> Iterator[Columns]:
        """Yield dicts of column arrays of up to ``rows`` rows (and :data:`MAX_CHUNK_TEXT` characters) each, in file order."""
        while True:
            lines, full = self._data_lines(rows)
            if lines:
                chunk = self._parse(lines)
                self.rows_read += len(lines)
                yield chunk
            if len(lines) < rows and not full:
                break
        self._finish()

    def _data_lines(self, rows: int) -> tuple[list[tuple[int, str]], bool]:
        """Return the next data lines (line number, text), up to ``rows`` of them, and whether the text size limit stopped them."""
        lines: list[tuple[int, str]] = []
        text_size = 0
        while len(lines) < rows:
            if text_size >= MAX_CHUNK_TEXT:
                return lines, True
            line = self._readline()
            if not line:
                break
            if line.startswith("#"):
                if line.startswith(TRAILER):
                    self._trailer(line)
                continue
            if not line.strip():
                continue
            if self.trailer_rows is not None:
                raise InputError("data after the END OF DATA line", path=self.path, row=self.rows_read + len(lines) + 1)
            if not line.endswith("\n"):
                self._check_last_line(line, row=self.rows_read + len(lines) + 1)
            lines.append((self.line_number, line))
            text_size += len(line)
        return lines, False

    def _check_last_line(self, line: str, *, row: int) -> None:
        """Raise when a line without its newline (the file's last) is not a complete row."""
        fields = line.split(",")
        if len(fields) != self.n_fields or self.document.get("end_marker"):
            raise InputError(
                f"file ends mid-row (line {self.line_number} is incomplete); the file was cut short",
                path=self.path,
                row=row,
                expected="a complete file",
            )

    def _trailer(self, line: str) -> None:
        match = _TRAILER_COUNT.fullmatch(line[len(TRAILER) :].strip())
        if match is None:
            raise InputError(f"bad END OF DATA line {line.strip()[:80]!r}", path=self.path, expected="'# END OF DATA: <n> rows'")
        self.trailer_rows = int(match.group(1))

    def _finish(self) -> None:
        if self.trailer_rows is None:
            if self.document.get("end_marker"):
                raise InputError(
                    f"no END OF DATA line after row {self.rows_read}; the file was cut short",
                    path=self.path,
                    row=self.rows_read,
                    expected="a complete file ending with '# END OF DATA: <n> rows'",
                )
        elif self.trailer_rows != self.rows_read:
            raise InputError(
                f"{self.rows_read} data rows found but the END OF DATA line says {self.trailer_rows}; rows are missing",
                path=self.path,
                expected=f"{self.trailer_rows} rows",
            )

    def _parse(self, lines: list[tuple[int, str]]) -> Columns:
        """Return the columns of a block of data lines.

        Read by numpy's C parser, or, on any problem, by a line-by-line pass that names the row and field.
        """
        import io

        import numpy as np

        commas = self.n_fields - 1
        joined = "".join(line for _, line in lines)
        # numpy's parser for plain ASCII numbers only: Python's float() (the slow path) would take 1_0 and full-width digits
        if joined.isascii() and "_" not in joined and all(line.count(",") == commas for _, line in lines):
            text = io.StringIO(joined)
            numeric = [c for c in self.schema if c.dtype != "str"]
            try:
                values = np.loadtxt(
                    text, delimiter=",", usecols=[self.positions[c.name] for c in numeric], dtype=float, comments=None, ndmin=2
                )
            except ValueError:
                pass
            else:
                out: Columns = {}
                for j, c in enumerate(numeric):
                    out[c.name] = self._typed(c, values[:, j], None, self.rows_read + 1)
                for c in self.schema:
                    if c.dtype == "str":
                        k = self.positions[c.name]
                        out[c.name] = np.array([line.split(",", k + 1)[k].strip() for _, line in lines])
                return {c.name: out[c.name] for c in self.schema}
        return self._parse_slowly(lines)

    def _typed(self, c: Column, values: Any, raw: Any, first_row: int) -> Any:

        if c.dtype == "int32":
            return integer_column(values, raw, c.name, self.path, first_row)
        check_finite(c.name, values, self.path, first_row=first_row)
        return values

    def _parse_slowly(self, lines: list[tuple[int, str]]) -> Columns:
        import numpy as np

        first_row = self.rows_read + 1
        split = []
        for k, (line_number, line) in enumerate(lines):
            fields = line.rstrip("\r\n").split(",")
            if len(fields) != self.n_fields:
                raise InputError(
                    f"{len(fields)} fields on line {line_number}",
                    path=self.path,
                    row=first_row + k,
                    expected=f"{self.n_fields} comma-separated fields",
                )
            split.append(fields)
        table = list(zip(*split))
        out: Columns = {}
        for c in self.schema:
            raw = table[self.positions[c.name]]
            if c.dtype == "str":
                out[c.name] = np.array([v.strip() for v in raw])
                continue
            for k, v in enumerate(raw):
                if _NUMBER.fullmatch(v) is None:
                    raise InputError(
                        f"{v[:40]!r} is not a number (line {lines[k][0]})",
                        path=self.path,
                        row=first_row + k,
                        field=c.name,
                        expected="a decimal number in ASCII digits, e.g. 9.80665 or -1.2e-05",
                    )
            values = np.array(raw, dtype=float)
            out[c.name] = self._typed(c, values, raw, first_row)
        return out

    def read_all(self) -> Columns:
        """All rows at once (small files)."""
        import numpy as np

        chunks = list(self.iter_chunks(rows=1 << 20))
        if not chunks:
            return {c.name: np.zeros(0, dtype=str if c.dtype == "str" else c.dtype) for c in self.schema}
        return {c.name: np.concatenate([ch[c.name] for ch in chunks]) for c in self.schema}

    def close(self) -> None:
        """Close the file (idempotent)."""
        if self._handle is not None:
            self._handle.close()
            self._handle = None

    def __enter__(self) -> CsvReader:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def write_csv(
    path: str | os.PathLike[str], kind: str, schema: Sequence[Column], document: Mapping[str, Any], chunks: Iterable[Mapping[str, Any]]
) -> int:
    """Write a whole CSV file atomically; returns the number of rows."""
    from stableins.data.atomic import atomic_write

    rows = 0
    with atomic_write(Path(path)) as handle:
        handle.write(header_text(kind, document, schema))
        for chunk in chunks:
            handle.write(format_rows(chunk, schema))
            rows += len(chunk[schema[0].name])
        handle.write(trailer_text(rows))
    return rows
