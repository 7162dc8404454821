"""What a reviewer checks on a rendered certificate and its technical report (pdftoppm, pdftotext): used by the report, recal
and budget tests.

:func:`review` returns the defects found (an empty list for a certificate a quality manager would sign).  The certificate:

* at most :data:`MAX_CERTIFICATE_PAGES` pages, ending with "End of certificate.";
* a statement of conformity: a verdict with its decision rule and specification, or "No statement of conformity";
* the technical report named by the SHA-256 of the file beside it (``NAME-technical.pdf``);
* every results row with a unit, GUM-rounded, and the same value and U as the technical report's results table.

The technical report:

* no near-empty page: on every page but the last, the text frame is used down to at least
  :data:`MIN_FILL` of its height (the old certificate's page 3, the tail of one table, ended at 40 %);
* no machine path (``/work/...``, ``C:\\...``, ``demo-output/system.h5``) and no command-line syntax (``--flag``);
* a unit on every row of the results and budget tables;
* GUM rounding the same everywhere: a parameter's value, u and U read the same in the results table, the
  budget table and the statement of conformity; U has two significant digits and the value its decimals.
"""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

from stableins.discovery.library import all_terms
from stableins.reporting.symbols import plain

MIN_FILL = 0.75
#: The text frame of the A4 page [mm from the top]: below the header, above the footer (stableins.reporting.document).
FRAME_TOP, FRAME_BOTTOM, PAGE_HEIGHT = 23.6, 297.0 - 20.8, 297.0
UNITS = {"ppm", "µg", "arcsec", "µg/g²", "µg/g³", "µg/K", "ppm/K", "µg/h", "mm", "°/h", "°/h/g"}
STATUSES = ("estimated", "gauge", "fixed", "unidentifiable")
_PATH = re.compile(r"(?<![\w.°])/(?:[\w.+-]+/)+[\w.+-]*|[A-Za-z]:\\|\b[\w.-]+/[\w.-]+\.(?:h5|csv|json|toml|pdf|bin|txt)\b")
_FLAG = re.compile(r"(?<![\w-])--[a-z]")


def pages_text(pdf: Path) -> list[str]:
    """The text layer of every page (``pdftotext -layout``)."""
    text = subprocess.run(["pdftotext", "-layout", str(pdf), "-"], check=True, capture_output=True, text=True, timeout=60).stdout
    return text.split("\f")[:-1] if text.endswith("\f") else text.split("\f")


def fill(pdf: Path, folder: Path) -> list[float]:
    """How far down its text frame each page is used: the last row with ink, as a fraction of the frame's height
    (pdftoppm at 30 dpi, grey levels below 235; the header and footer are outside the frame)."""
    from PIL import Image

    stem = folder / f"{pdf.stem}-fill"
    subprocess.run(["pdftoppm", "-r", "30", "-gray", "-png", str(pdf), str(stem)], check=True, timeout=120)
    out = []
    for page in sorted(folder.glob(f"{pdf.stem}-fill-*.png")):
        image = Image.open(page).convert("L")
        width, height = image.size
        top, bottom = (round(height * y / PAGE_HEIGHT) for y in (FRAME_TOP, FRAME_BOTTOM))
        pixels = image.load()
        inked = [y for y in range(top, bottom) if any(pixels[x, y] < 235 for x in range(width))]
        out.append((max(inked) - top) / (bottom - top) if inked else 0.0)
        page.unlink()
    return out


def table_rows(text: str, start: str, end: str) -> dict[str, list[str]]:
    """Rows of a table between two headings (regular expressions), keyed by the typeset symbol that starts them (``δbx``)."""
    first = re.search(start, text)
    if first is None:
        return {}
    section = text[first.end() :]
    last = re.search(end, section)
    section = section[: last.start()] if last else section
    symbols = {plain(t) for t in all_terms()}
    rows = {}
    for line in section.splitlines():
        tokens = line.split()
        if tokens and tokens[0] in symbols and tokens[0] not in rows:
            rows[tokens[0]] = tokens[1:]
    return rows


def value_checks(text: str) -> dict[str, list[str]]:
    """``{symbol: [measured, U, limit, unit, result]}`` of the value checks of the statement of conformity."""
    if "Statement of conformity" not in text:
        return {}
    section = text[text.rindex("Statement of conformity") :]
    return {t[1]: t[2:] for t in (line.split() for line in section.splitlines()) if len(t) > 3 and t[0] == "value"}


def decimals(text: str) -> int:
    return len(mantissa(text).partition(".")[2])


def mantissa(text: str) -> str:
    """The number before a ``×10ⁿ`` (tiny values are written ``m×10ⁿ``, 1 ≤ m < 10)."""
    return text.partition("×10")[0]


def power(text: str) -> str:
    return text.partition("×10")[2]


def last_place(text: str) -> int:
    """The power of ten of a number's last digit (``7×10⁻⁶`` → −6, ``1.3×10⁻⁵`` → −6, ``2.4`` → −1): GUM 7.2.6 puts the
    value's last digit where U's is."""
    exponent = power(text).translate(str.maketrans("⁻⁰¹²³⁴⁵⁶⁷⁸⁹", "-0123456789"))
    return (int(exponent) if exponent else 0) - decimals(text)


def one_style(text: str) -> bool:
    """Whether a number in ``m×10ⁿ`` has its mantissa in [1, 10) (one exponent style in a column), or is fixed point."""
    if "×10" not in text:
        return True
    digits = mantissa(text).lstrip("\u2212-")
    return digits[:1] in set("123456789")


MAX_CERTIFICATE_PAGES = 3


def technical_of(certificate: Path) -> Path:
    """The technical report written beside ``certificate`` (``report.pdf`` → ``report-technical.pdf``)."""
    return certificate.with_name(f"{certificate.stem}-technical{certificate.suffix}")


def review(pdf: Path, folder: Path) -> list[str]:
    """Every defect a reviewer would see on the certificate ``pdf`` and its technical report (module docstring)."""
    import hashlib

    technical = technical_of(pdf)
    if not technical.exists():
        return [f"no technical report beside the certificate ({technical.name})"]
    defects = [f"technical report: {d}" for d in review_technical(technical, folder)]
    pages = pages_text(pdf)
    if len(pages) > MAX_CERTIFICATE_PAGES:
        defects.append(f"the certificate has {len(pages)} pages (at most {MAX_CERTIFICATE_PAGES})")
    if "End of certificate." not in pages[-1]:
        defects.append("the last page does not end the certificate")
    text = "\n".join(pages)
    flat = "".join(text.split())
    if hashlib.sha256(technical.read_bytes()).hexdigest() not in flat:
        defects.append("the certificate does not name the technical report by its SHA-256")
    if not (re.search(r"Verdict: (PASS|FAIL|CONDITIONAL PASS|CONDITIONAL FAIL|NOT ASSESSED)", text) and "Decision rule" in text) and (
        "No statement of conformity" not in text
    ):
        defects.append("no statement of conformity with its decision rule")
    defects += _machine_text(text)
    return defects + _certificate_rows(text, "\n".join(pages_text(technical)))


def _certificate_rows(text: str, technical: str) -> list[str]:
    """The defects of the certificate's results table: units, GUM rounding, the technical report's numbers."""
    defects = []
    rows = table_rows(text, r"\n\s*1\s+Results", r"\n\s*2\s+Statement of conformity")
    detail = table_rows(technical, r"\n\s*4\s+Results", r"\n\s*5\s+Uncertainty budget")
    if not rows:
        defects.append("no results table on the certificate")
    for symbol, tokens in rows.items():
        value, expanded, unit = (tokens + ["", "", ""])[:3]
        if unit not in UNITS:
            defects.append(f"certificate row {symbol}: no unit after its numbers ({tokens})")
        elif len(mantissa(expanded).replace(".", "").lstrip("0")) != 2 or (value != "0" and last_place(value) != last_place(expanded)):
            defects.append(f"certificate row {symbol}: {value} with U = {expanded} is not GUM-rounded")
        if not (one_style(value) and one_style(expanded)):
            defects.append(f"certificate row {symbol}: {value}, {expanded}: a mantissa outside [1, 10)")
        other = detail.get(symbol)
        if other is None or other[1:2] + other[3:4] != [value, expanded]:
            defects.append(f"certificate row {symbol}: {value}, {expanded} differs from the technical report ({other})")
    return defects


def _machine_text(text: str) -> list[str]:
    """Machine paths and command-line syntax in a document's text."""
    defects = [f"machine path on the certificate: {match.group(0)!r}" for match in _PATH.finditer(text)]
    return defects + [f"command-line syntax on the certificate: {line.strip()!r}" for line in text.splitlines() if _FLAG.search(line)]


def review_technical(pdf: Path, folder: Path) -> list[str]:
    """Every defect a reviewer would see on a technical report (module docstring)."""
    defects = []
    pages = pages_text(pdf)
    used = fill(pdf, folder)
    for i, share in enumerate(used, start=1):
        if i < len(pages) and share < MIN_FILL:
            defects.append(f"page {i} is used down to {share:.0%} of its text frame only")
    if "End of report." not in pages[-1]:
        defects.append("the last page does not end the report")
    text = "\n".join(pages)
    defects += _machine_text(text)
    results = table_rows(text, r"\n\s*4\s+Results", r"\n\s*5\s+Uncertainty budget")
    budget = table_rows(text, r"Budget per parameter", r"\n\s*6\s+Correlation")
    conformity = value_checks(text)
    if not results:
        defects.append("no results table found")
    for symbol, tokens in results.items():
        defects += _result_row_defects(symbol, tokens, budget, conformity)
    return defects


def _result_row_defects(symbol: str, tokens: list[str], budget: dict, conformity: dict) -> list[str]:
    """The defects of one row of the results table, and of its rows in the budget and conformity tables."""
    status = tokens[0] if tokens else ""
    if status not in STATUSES:
        return [f"results row {symbol}: no status ({tokens})"]
    if status != "estimated":
        return []
    defects = []
    value, u, expanded, unit = tokens[1:5]
    if unit not in UNITS:
        defects.append(f"results row {symbol}: no unit after its numbers ({tokens})")
    if (value != "0" and last_place(value) != last_place(expanded)) or len(mantissa(expanded).replace(".", "").lstrip("0")) != 2:
        defects.append(f"results row {symbol}: {value} with U = {expanded} is not GUM-rounded")
    if not all(one_style(x) for x in (value, u, expanded)):
        defects.append(f"results row {symbol}: {value}, {u}, {expanded}: a mantissa outside [1, 10)")
    row = budget.get(symbol)
    if row is None:
        defects.append(f"budget table has no row for {symbol}")
    else:
        if row[0] not in UNITS:
            defects.append(f"budget row {symbol}: no unit ({row})")
        if row[-2:] != [u, expanded]:
            defects.append(f"budget row {symbol}: u_c, U {row[-2:]} differ from the results table {[u, expanded]}")
    check = conformity.get(symbol)
    if check is not None and check[:2] != [value.lstrip("\u2212"), expanded]:
        defects.append(f"conformity row {symbol}: {check[:2]} differs from the results table ({value}, {expanded})")
    return defects
