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
from collections.abc import Iterable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import IO, Any

from stableins.data.errors import InputError
from stableins.data.schema import Column
from stableins.data.validation import check_finite, check_header_document, match_columns, parse_header

BEGIN = "# BEGIN HEADER"
END = "# END HEADER"
TRAILER = "# END OF DATA:"


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
    return f"{TRAILER} {rows} rows\n"


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
        try:
            self._handle = open(self.path, encoding="utf-8", newline="")  # noqa: SIM115 (closed in close())
        except FileNotFoundError:
            raise InputError("no such file", path=self.path) from None
        except OSError as error:
            raise InputError(f"cannot open: {error.strerror}", path=self.path) from None
        try:
            self.document, headers = self._read_header()
        except BaseException:
            self.close()
            raise
        check_header_document(self.document, kind, self.path)
        self.positions = match_columns([parse_header(h) for h in headers], self.schema, self.path)
        self.n_fields = len(headers)
        self.rows_read = 0
        self.trailer_rows: int | None = None

    # ------------------------------------------------------------------ header
    def _readline(self) -> str:
        assert self._handle is not None
        try:
            line = self._handle.readline()
        except UnicodeDecodeError:
            raise InputError("not a text file (bad UTF-8)", path=self.path, expected="a CSV file") from None
        self.line_number += 1
        return line

    def _read_header(self) -> tuple[Any, list[str]]:
        self.line_number = 0
        json_lines: list[str] = []
        state = "before"
        while True:
            line = self._readline()
            if not line:
                raise InputError("file ends before the column-header line", path=self.path, expected="a complete stableins CSV file")
            text = line.rstrip("\r\n")
            if text.startswith("#"):
                if text.strip() == BEGIN:
                    state = "inside"
                elif text.strip() == END:
                    state = "after"
                elif state == "inside":
                    json_lines.append(text[1:])
                continue
            if not text.strip():
                continue
            break
        if state == "before":
            raise InputError("no header block (BEGIN HEADER ... END HEADER)", path=self.path, expected="the JSON header of docs/formats.md")
        if state == "inside":
            raise InputError("header block has no END HEADER line", path=self.path, expected="a complete JSON header")
        try:
            document = json.loads("\n".join(json_lines))
        except json.JSONDecodeError as error:
            raise InputError(f"header JSON is invalid: {error.msg} (header line {error.lineno})", path=self.path) from None
        return document, [h for h in text.split(",")]

    # ------------------------------------------------------------------ rows
    def iter_chunks(self, rows: int = 65536) -> Iterator[dict[str, Any]]:
        """Yield dicts of column arrays of up to ``rows`` rows each, in file order."""
        while True:
            lines: list[tuple[int, str]] = []
            while len(lines) < rows:
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
                    fields = line.split(",")
                    if len(fields) != self.n_fields or self.document.get("end_marker"):
                        raise InputError(
                            f"file ends mid-row (line {self.line_number} is incomplete); the file was cut short",
                            path=self.path,
                            row=self.rows_read + len(lines) + 1,
                            expected="a complete file",
                        )
                lines.append((self.line_number, line))
            if lines:
                chunk = self._parse(lines)
                self.rows_read += len(lines)
                yield chunk
            if len(lines) < rows:
                break
        self._finish()

    def _trailer(self, line: str) -> None:
        text = line[len(TRAILER) :].strip()
        try:
            self.trailer_rows = int(text.split()[0])
        except (ValueError, IndexError):
            raise InputError(f"bad END OF DATA line {line.strip()!r}", path=self.path, expected="'# END OF DATA: <n> rows'") from None

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

    def _parse(self, lines: list[tuple[int, str]]) -> dict[str, Any]:
        """Columns of a block of data lines: numpy's C parser, or, on any problem, a line-by-line
        pass that names the row and field."""
        import io

        import numpy as np

        commas = self.n_fields - 1
        if all(line.count(",") == commas for _, line in lines):
            text = io.StringIO("".join(line for _, line in lines))
            numeric = [c for c in self.schema if c.dtype != "str"]
            try:
                values = np.loadtxt(
                    text, delimiter=",", usecols=[self.positions[c.name] for c in numeric], dtype=float, comments=None, ndmin=2
                )
            except ValueError:
                pass
            else:
                out: dict[str, Any] = {}
                for j, c in enumerate(numeric):
                    out[c.name] = self._typed(c, values[:, j], None, self.rows_read + 1)
                for c in self.schema:
                    if c.dtype == "str":
                        k = self.positions[c.name]
                        out[c.name] = np.array([line.split(",", k + 1)[k].strip() for _, line in lines])
                return {c.name: out[c.name] for c in self.schema}
        return self._parse_slowly(lines)

    def _typed(self, c: Column, values: Any, raw: Any, first_row: int) -> Any:
        import numpy as np

        if c.dtype == "int32":
            whole = np.isfinite(values) & (values == np.round(values))
            if not whole.all():
                k = int(np.argmin(whole))
                shown = raw[k] if raw is not None else repr(float(values[k]))
                raise InputError(f"{shown!r} is not an integer", path=self.path, row=first_row + k, field=c.name, expected="an integer")
            return values.astype(np.int32)
        check_finite(c.name, values, self.path, first_row=first_row)
        return values

    def _parse_slowly(self, lines: list[tuple[int, str]]) -> dict[str, Any]:
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
        out: dict[str, Any] = {}
        for c in self.schema:
            raw = table[self.positions[c.name]]
            if c.dtype == "str":
                out[c.name] = np.array([v.strip() for v in raw])
                continue
            try:
                values = np.array(raw, dtype=float)
            except ValueError:
                for k, v in enumerate(raw):
                    try:
                        float(v)
                    except ValueError:
                        raise InputError(
                            f"{v!r} is not a number (line {lines[k][0]})",
                            path=self.path,
                            row=first_row + k,
                            field=c.name,
                            expected="a number",
                        ) from None
                raise
            out[c.name] = self._typed(c, values, raw, first_row)
        return out

    def read_all(self) -> dict[str, Any]:
        """All rows at once (small files)."""
        import numpy as np

        chunks = list(self.iter_chunks(rows=1 << 20))
        if not chunks:
            return {c.name: np.zeros(0, dtype=str if c.dtype == "str" else c.dtype) for c in self.schema}
        return {c.name: np.concatenate([ch[c.name] for ch in chunks]) for c in self.schema}

    def close(self) -> None:
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
