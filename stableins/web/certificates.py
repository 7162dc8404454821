"""The certificates and technical reports under a run root, found by the SHA-256 of the record they certify.

Every certificate stableins writes names its inputs in its metadata (:func:`stableins.reporting.signing.read_manifest`),
the calibration record among them with its SHA-256.  The index maps that digest to the PDFs, so a unit's page offers
exactly the certificates of its filed records; a PDF whose named record is not filed is not offered.  The statement of
conformity is read from the certificate's own text ("Verdict: PASS", with pypdf), so the fleet shows what the
certificate states.  The index is rebuilt only for PDFs whose size or modification time changed.
"""

from __future__ import annotations

import hashlib
import os
import re
from dataclasses import dataclass
from pathlib import Path

#: How deep below the run root PDFs are looked for (a run directory, or a folder of runs).
MAX_CERTIFICATE_DEPTH = 3
#: Largest PDF read [bytes].
MAX_PDF_BYTES = 64 << 20
_VERDICT = re.compile(r"Verdict:\s*(CONDITIONAL PASS|CONDITIONAL FAIL|NOT ASSESSED|NO STATEMENT|PASS|FAIL)")


@dataclass(frozen=True)
class Certificate:
    """One PDF under the run root that names a calibration record."""

    path: Path
    kind: str  # "certificate" or "technical report"
    title: str
    record_sha256: str
    sha256: str  # of the PDF itself
    verdict: str  # the certificate's statement ("PASS", "FAIL", ...), "" for a technical report or none found


class CertificateIndex:
    """The PDFs under ``root`` by the SHA-256 of the record they certify (rescanned on :meth:`refresh`)."""

    def __init__(self, root: Path | None) -> None:
        self.root = root.resolve() if root is not None else None
        self._seen: dict[Path, tuple[int, int, Certificate | None]] = {}

    def refresh(self) -> None:
        """Read the PDFs that are new or changed since the last refresh; forget the ones that are gone."""
        if self.root is None or not self.root.is_dir():
            self._seen = {}
            return
        found = {}
        for path in _pdfs(self.root):
            try:
                stat = path.stat()
            except OSError:
                continue
            known = self._seen.get(path)
            if known is not None and known[:2] == (stat.st_size, stat.st_mtime_ns):
                found[path] = known
            else:
                found[path] = (stat.st_size, stat.st_mtime_ns, _read(path, stat.st_size))
        self._seen = found

    def of_record(self, digest: str) -> list[Certificate]:
        """Return the certificates and technical reports of the record with SHA-256 ``digest`` (certificates first)."""
        out = [c for _, _, c in self._seen.values() if c is not None and c.record_sha256 == digest]
        return sorted(out, key=lambda c: (c.kind != "certificate", str(c.path)))

    def by_sha256(self, digest: str) -> Certificate | None:
        """Return the indexed PDF whose own SHA-256 is ``digest`` (None if none)."""
        for _, _, c in self._seen.values():
            if c is not None and c.sha256 == digest:
                return c
        return None


def _pdfs(root: Path) -> list[Path]:
    """Return the ``*.pdf`` files under ``root`` down to :data:`MAX_CERTIFICATE_DEPTH` levels (symbolic links not followed)."""
    out = []
    for folder, directories, files in os.walk(root, followlinks=False):
        depth = len(Path(folder).relative_to(root).parts)
        if depth >= MAX_CERTIFICATE_DEPTH:
            directories[:] = []
        directories[:] = [d for d in directories if not d.startswith(".")]
        out += [Path(folder) / f for f in files if f.lower().endswith(".pdf") and not (Path(folder) / f).is_symlink()]
    return sorted(out)


def _read(path: Path, size: int) -> Certificate | None:
    """Return what a PDF certifies (None when it is not a stableins certificate or technical report)."""
    from stableins.reporting.signing import read_manifest

    if size > MAX_PDF_BYTES:
        return None
    try:
        data = path.read_bytes()
    except OSError:
        return None
    rows = [r for r in read_manifest(data) if r.get("role") == "calibration record"]
    if not rows:
        return None
    title_match = re.search(rb"/Title \(((?:[^()\\]|\\.)*)\)", data)
    title = title_match.group(1).decode("latin-1") if title_match else path.name
    technical = title.startswith("Technical report")
    return Certificate(
        path,
        "technical report" if technical else "certificate",
        title,
        rows[0]["sha256"],
        hashlib.sha256(data).hexdigest(),
        "" if technical else _verdict(path),
    )


def _verdict(path: Path) -> str:
    """Return the statement of conformity the certificate prints ("Verdict: ..."), "" when none is found."""
    try:
        from pypdf import PdfReader
        from pypdf.errors import PyPdfError
    except ImportError:  # pragma: no cover - pypdf comes with the [web] extra
        return ""
    try:
        reader = PdfReader(path)
        for page in reader.pages:
            match = _VERDICT.search(page.extract_text() or "")
            if match:
                return match.group(1)
    except (PyPdfError, OSError, ValueError):
        return ""
    return ""
