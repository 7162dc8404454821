"""Filing records in the store: reading and checking their bytes, staging their files, indexing their rows."""

from __future__ import annotations

import contextlib
import hashlib
import json
import math
import os
import re
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from stableins.errors import InputError
from stableins.history import data_only, parse_date
from stableins.history_store.schema import MAX_RECORD_BYTES, Connection, HistoryEntry
from stableins.identifiers import check_serial_number, utc_now

if TYPE_CHECKING:  # pragma: no cover
    from stableins.records import CalibrationRecord

#: A SHA-256 digest as the index keeps it.
SHA256 = re.compile(r"[0-9a-f]{64}")


def check_serial(serial: str) -> str:
    """Return ``serial`` if it can name a unit's folder (:func:`stableins.identifiers.check_serial_number`).

    Raises
    ------
    InputError
        The serial number cannot name a folder.
    """
    return check_serial_number(serial, field="serial")


@dataclass(frozen=True)
class Filing:
    """A record about to be filed: its bytes, the record read from them, the estimate kept beside it, its entry."""

    data: bytes
    record: CalibrationRecord
    evidence_data: bytes | None
    evidence_record: CalibrationRecord | None
    entry: HistoryEntry


def read_filing(record_path: str | os.PathLike[str], *, prior: str, evidence: str | os.PathLike[str] | None) -> Filing:
    """Return what filing the record at ``record_path`` writes, validated from the very bytes that are filed.

    Raises
    ------
    InputError
        ``prior`` is not a SHA-256 digest, a file is refused, the estimate is of another unit, the record has no time.
    """
    data, record = read_record(record_path)
    evidence_data, evidence_record = read_record(evidence) if evidence is not None else (None, None)
    return filing_of(data, record, prior=prior, evidence_data=evidence_data, evidence_record=evidence_record, source=record_path)


def filing_of(
    data: bytes,
    record: CalibrationRecord,
    *,
    prior: str,
    evidence_data: bytes | None = None,
    evidence_record: CalibrationRecord | None = None,
    source: str | os.PathLike[str],
) -> Filing:
    """Return the filing of a record's bytes (and of the estimate kept beside it), read from ``source``.

    Raises
    ------
    InputError
        ``prior`` is not a SHA-256 digest, the estimate is of another unit, the record has no time.
    """
    if prior and not SHA256.fullmatch(prior):
        raise InputError(f"prior {prior[:70]!r} is not a SHA-256 digest", field="prior", expected="64 lower-case hexadecimal digits")
    digest = hashlib.sha256(data).hexdigest()
    if evidence_record is not None and evidence_record.serial_number != record.serial_number:
        raise InputError(
            f"the estimate is of unit {evidence_record.serial_number!r}, the record of {record.serial_number!r}",
            path=source,
            field="serial_number",
            expected="the data-only estimate of the same unit",
        )
    check_serial(record.serial_number)
    valid_from = record.provenance.data_end or record.provenance.created
    if not valid_from:
        raise InputError("record has neither a data end time nor a creation time", path=source, field="provenance.data_end")
    stamp = parse_date(valid_from, "provenance.data_end").strftime("%Y%m%dT%H%M%SZ")
    entry = HistoryEntry(
        f"{stamp}-{digest[:8]}.json",
        valid_from,
        record.provenance.created,
        digest,
        record.provenance.procedure,
        record.provenance.stages,
        prior,
        f"{stamp}-{digest[:8]}.evidence.json" if evidence_data is not None else "",
        hashlib.sha256(evidence_data).hexdigest() if evidence_data is not None else "",
    )
    return Filing(data, record, evidence_data, evidence_record, entry)


def insert_entry(
    connection: Connection, serial: str, entry: HistoryEntry, record: CalibrationRecord, evidence: CalibrationRecord | None
) -> None:
    """Index a record: its row, and the values of its parameters, of the estimate beside it and of its data alone."""
    now = utc_now()
    connection.execute("INSERT INTO units (serial, first_filed) VALUES (?, ?) ON CONFLICT DO NOTHING", (serial, now))
    cursor = connection.execute(
        "INSERT INTO records (serial, file, sha256, valid_from, valid_from_utc, created, procedure, stages, prior, evidence, "
        "evidence_sha256, filed) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?) RETURNING id",
        (
            serial,
            entry.file,
            entry.sha256,
            entry.valid_from,
            entry.time.timestamp(),
            entry.created,
            entry.procedure,
            json.dumps(list(entry.stages)),
            entry.prior,
            entry.evidence,
            entry.evidence_sha256,
            now,
        ),
    )
    record_id = cursor.fetchone()[0]
    rows = []
    for source, which in (("record", record), ("evidence", evidence)):
        if which is None:
            continue
        for p in which.parameters:
            sigma = p.sigma if math.isfinite(p.sigma) else None
            rows.append((record_id, source, p.id, p.value, sigma, p.unit, getattr(p.status, "value", str(p.status))))
    # what the record's own calibration determines from its data alone: the points of the drift (fleet queries)
    for pid, (value, sigma) in data_only(record).items():
        rows.append((record_id, "data_only", pid, value, sigma, record[pid].unit, "estimated"))
    connection.executemany("INSERT INTO parameters (record, source, id, value, sigma, unit, status) VALUES (?, ?, ?, ?, ?, ?, ?)", rows)


def read_record(path: str | os.PathLike[str]) -> tuple[bytes, CalibrationRecord]:
    """Return a record's bytes and the record validated from those very bytes."""
    from stableins.data.jsonio import parse_json, read_input_bytes
    from stableins.records import CalibrationRecord

    what = "a calibration record (JSON) written by stableins"
    data = read_input_bytes(path, max_bytes=MAX_RECORD_BYTES, what=what)
    return data, CalibrationRecord.from_document(parse_json(data, path=path, what=what), str(path))


def verified_bytes(path: Path, digest: str) -> bytes:
    """Return the bytes of a filed file, refused unless their SHA-256 is ``digest`` (the index's).

    Raises
    ------
    InputError
        The file is missing or its SHA-256 differs.
    """
    from stableins.data.jsonio import read_input_bytes

    if not path.exists():
        raise InputError(
            "the filed record is missing", path=path, field="sha256", expected=f"the file the history index lists, SHA-256 {digest}"
        )
    data = read_input_bytes(path, max_bytes=MAX_RECORD_BYTES, what="a filed calibration record")
    return checked_digest(data, digest, path)


def checked_digest(data: bytes, digest: str, where: str | os.PathLike[str]) -> bytes:
    """Return ``data``, refused unless its SHA-256 is ``digest`` (the index's); ``where`` names the file in the message.

    Raises
    ------
    InputError
        The SHA-256 of ``data`` differs.
    """
    found = hashlib.sha256(data).hexdigest()
    if found != digest:
        raise InputError(
            f"the filed record was changed after it was filed (its SHA-256 is now {found})",
            path=where,
            field="sha256",
            expected=f"SHA-256 {digest}, as the history index holds",
        )
    return data


def stage_file(directory: Path, name: str, data: bytes) -> tuple[str, Path]:
    """Write ``data`` to a temporary file beside ``directory/name`` (fsync'ed); return (temporary, final)."""
    fd, temporary = tempfile.mkstemp(prefix=f".{name}.", suffix=".partial", dir=directory)
    try:
        with os.fdopen(fd, "wb") as handle:
            handle.write(data)
            handle.flush()
            os.fsync(handle.fileno())
        mask = os.umask(0)
        os.umask(mask)
        os.chmod(temporary, 0o666 & ~mask)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(temporary)
        raise
    return temporary, directory / name
