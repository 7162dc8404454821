"""Signed certificates: PAdES signatures with pyHanko (the optional ``sign`` extra), and their verification.

``stableins report --sign KEY.pem`` signs the certificate (a PAdES baseline signature, ETSI EN 319 142-1: CMS
signed data with the signing certificate, sub-filter ``ETSI.CAdES.detached``) before it is written;
``stableins check CERT.pdf`` verifies it: that the signed bytes are unchanged (the digest the signature covers),
that the signature is mathematically valid for the signing certificate, and — with a trust anchor given — that the
signer is trusted.  The certificate also carries, in its document information (``Keywords``), the SHA-256 of
every input it names (:data:`MANIFEST_PREFIX`), which ``check`` compares with the files beside it.
"""

from __future__ import annotations

import io
import json
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from stableins.errors import InputError

#: The document-information ``Keywords`` of a certificate start with this, then the manifest as ASCII JSON.
MANIFEST_PREFIX = "stableins-inputs "
#: How to get the optional dependency.
INSTALL = "pip install 'stableins[sign]' (pyHanko)"


def manifest_text(inputs: Sequence[tuple[str, str, str]]) -> str:
    """Return the manifest of a certificate: ``(role, file name, SHA-256)`` of every input it names, as keywords text."""
    rows = [{"role": role, "name": name, "sha256": digest} for role, name, digest in inputs if len(digest) == 64]
    return MANIFEST_PREFIX + json.dumps(rows, ensure_ascii=True, separators=(",", ":"))


def read_manifest(data: bytes) -> list[dict[str, str]]:
    """Return the manifest rows of a certificate's bytes (empty when it has none)."""
    match = re.search(rb"/Keywords \(((?:[^()\\]|\\.)*)\)", data)
    if match is None:
        return []
    text = re.sub(r"\\(.)", r"\1", match.group(1).decode("latin-1"))
    if not text.startswith(MANIFEST_PREFIX):
        return []
    try:
        rows = json.loads(text[len(MANIFEST_PREFIX) :])
    except json.JSONDecodeError:
        return []
    return [r for r in rows if isinstance(r, dict) and {"role", "name", "sha256"} <= set(r)]


def _pyhanko() -> Any:
    try:
        import pyhanko.sign  # noqa: F401
    except ImportError:
        raise InputError("signing and verifying need pyHanko, which is not installed", expected=INSTALL) from None
    return pyhanko


def sign(pdf: bytes, key: str | Path, certificate: str | Path | None = None, *, passphrase: bytes | None = None) -> bytes:
    """Return ``pdf`` signed with the private key ``key`` (PEM) and its X.509 ``certificate`` (PEM; default: in ``key``).

    Raises
    ------
    InputError
        pyHanko missing, or a key or certificate that cannot be read (naming the file).
    """
    _pyhanko()
    from pyhanko.pdf_utils.incremental_writer import IncrementalPdfFileWriter
    from pyhanko.sign import fields, signers

    cert = Path(certificate) if certificate is not None else Path(key)
    for path, what in ((Path(key), "a PEM private key"), (cert, "a PEM X.509 certificate")):
        if not path.is_file():
            raise InputError("no such file", path=str(path), expected=what)
    try:
        signer = signers.SimpleSigner.load(str(key), str(cert), key_passphrase=passphrase)
    except Exception as error:  # pyHanko and cryptography raise many kinds for an unreadable key or certificate
        raise InputError(f"cannot read the key or its certificate: {error}", path=str(key), expected="a PEM key and certificate") from None
    if signer is None:
        raise InputError("cannot read the key or its certificate", path=str(key), expected="a PEM private key and its X.509 certificate")
    writer = IncrementalPdfFileWriter(io.BytesIO(pdf))
    metadata = signers.PdfSignatureMetadata(field_name="Certificate", subfilter=fields.SigSeedSubFilter.PADES, md_algorithm="sha256")
    out = signers.sign_pdf(writer, metadata, signer=signer)
    return bytes(out.getvalue())


@dataclass(frozen=True)
class SignatureCheck:
    """What ``check`` found about the signature of a PDF.

    Attributes
    ----------
    intact : bool
        The bytes the signature covers are unchanged (their digest matches the signed one).
    valid : bool
        The signature is valid for the signing certificate.
    trusted : bool or None
        The signer chains to a given trust anchor (None: no anchor was given).
    signer : str
        The signing certificate's subject.
    covers_whole_file : bool
        Nothing was appended after the signature.
    """

    intact: bool
    valid: bool
    trusted: bool | None
    signer: str
    covers_whole_file: bool


def is_signed(data: bytes) -> bool:
    """Return whether a PDF carries a signature (a signature dictionary with a byte range)."""
    return b"/ByteRange" in data


def verify(data: bytes, path: str, trust: Sequence[str | Path] = ()) -> SignatureCheck:
    """Verify the signature of a signed PDF's bytes; any defect is an :class:`InputError` saying what is wrong.

    The signed digest must match the bytes it covers (one byte changed anywhere in them fails), the signature must
    be valid for its certificate, nothing may be appended after it, and with ``trust`` anchors the signer must chain to one.
    """
    _pyhanko()
    from pyhanko.keys import load_cert_from_pemder
    from pyhanko.pdf_utils.reader import PdfFileReader
    from pyhanko.sign.validation import validate_pdf_signature
    from pyhanko_certvalidator import ValidationContext

    try:
        reader = PdfFileReader(io.BytesIO(data))
        signatures = reader.embedded_signatures
    except Exception as error:  # a changed byte can break the file's structure before the digest is even compared
        raise InputError(f"the signed PDF cannot be read ({error}): it was changed after signing", path=path, field="signature") from None
    if not signatures:
        raise InputError("a signature dictionary without a signature", path=path, field="signature")
    signature = signatures[-1]
    anchors = [load_cert_from_pemder(str(t)) for t in trust]
    context = ValidationContext(trust_roots=anchors, allow_fetching=False)  # no anchor given: nothing is trusted
    import logging

    quiet = logging.getLogger("pyhanko")
    level = quiet.level
    quiet.setLevel(logging.CRITICAL)  # an untrusted signer is reported below, not as a logged traceback
    try:
        status = validate_pdf_signature(signature, context)
    except Exception as error:
        raise InputError(f"the signature cannot be validated ({error})", path=path, field="signature") from None
    finally:
        quiet.setLevel(level)
    signer = status.signing_cert.subject.human_friendly if status.signing_cert is not None else "unknown"
    if not status.intact:
        raise InputError(
            "the signed bytes were changed after signing: their SHA-256 does not match the digest the signature covers",
            path=path,
            field="signature",
            expected=f"the certificate as {signer} signed it",
        )
    if not status.valid:
        raise InputError("the signature is not valid for its signing certificate", path=path, field="signature")
    whole = signature.coverage.name == "ENTIRE_FILE"
    if not whole:
        raise InputError("bytes were appended after the signature (it no longer covers the whole file)", path=path, field="signature")
    trusted = bool(status.trusted) if anchors else None
    if trusted is False:
        raise InputError(f"the signer {signer} does not chain to the trust anchor given", path=path, field="signature")
    return SignatureCheck(True, True, trusted, signer, whole)
