"""Migration of stores written before the database (``DIR/<serial>/index.json``), on first use.

Each unit's entries are checked against their files' digests and indexed in one transaction; the old index is
then renamed ``index.json.migrated``.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import sqlite3
from collections.abc import Iterator
from datetime import datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any

from stableins.errors import InputError
from stableins.history import parse_date
from stableins.history_store.filing import SHA256, insert_entry, verified_bytes
from stableins.history_store.schema import MAX_RECORD_BYTES, HistoryEntry, find_entry, transaction
from stableins.identifiers import utc_now

if TYPE_CHECKING:  # pragma: no cover
    from stableins.records import CalibrationRecord

#: The index of stores written before the database (migrated on first use).
INDEX_NAME = "index.json"
INDEX_FORMAT = "stableins-history-index"


def legacy_units(root: Path) -> list[Path]:
    """Return the unit folders that still carry an index of the JSON store (not yet migrated)."""
    if not root.is_dir():
        return []
    try:
        return sorted(p for p in root.iterdir() if (p / INDEX_NAME).is_file())
    except OSError as error:
        raise InputError(f"cannot list the history store ({error.strerror})", path=root) from None


def migrate(connection: sqlite3.Connection, root: Path) -> None:
    """Index every unit of an old JSON store under ``root``, one transaction per unit (entries verified against their files)."""
    for folder in legacy_units(root):
        index = folder / INDEX_NAME
        with transaction(connection):
            if connection.execute("SELECT 1 FROM migrations WHERE serial = ?", (folder.name,)).fetchone() is None:
                for entry, _, record, evidence in legacy_entries(index, folder):
                    if find_entry(connection, folder.name, entry.sha256) is None:
                        insert_entry(connection, folder.name, entry, record, evidence)
                connection.execute(
                    "INSERT INTO migrations (serial, source, migrated) VALUES (?, ?, ?)", (folder.name, str(index), utc_now())
                )
        with contextlib.suppress(OSError):  # after the commit; a failed rename is retried on the next use
            os.replace(index, folder / f"{INDEX_NAME}.migrated")


def legacy_entries(index: Path, folder: Path) -> Iterator[tuple[HistoryEntry, datetime, CalibrationRecord, CalibrationRecord | None]]:
    """Yield the entries of an old ``index.json``, each checked against its file (and read for its parameters).

    Raises
    ------
    InputError
        The index is unreadable, an entry malformed, a file missing or changed.
    """
    from stableins.data.jsonio import expect_list, expect_mapping, load_json_file

    document = load_json_file(index, what=f"a {INDEX_FORMAT} file (history index unreadable)")
    document = expect_mapping(document, index, "", f"a {INDEX_FORMAT} file (history index unreadable)")
    if document.get("format") != INDEX_FORMAT:
        raise InputError(f"history index unreadable: format {str(document.get('format'))[:40]!r}", path=index, expected=f"'{INDEX_FORMAT}'")
    for k, raw in enumerate(expect_list(document.get("entries"), index, "entries", "a list of entries")):
        yield _legacy_entry(raw, index, folder, f"entries[{k}]")


def _legacy_fields(raw: Any, index: Path, where: str) -> tuple[dict[str, str], tuple[str, ...]]:
    """Return the text fields and the stages of one entry of an old index, checked."""
    from stableins.data.jsonio import expect_list, expect_mapping, expect_text

    raw = expect_mapping(raw, index, where)
    fields = {
        key: expect_text(raw.get(key, ""), index, f"{where}.{key}")
        for key in ("file", "valid_from", "created", "sha256", "procedure", "prior", "evidence")
    }
    stages = tuple(expect_text(s, index, f"{where}.stages") for s in expect_list(raw.get("stages", []), index, f"{where}.stages"))
    if not SHA256.fullmatch(fields["sha256"]):
        raise InputError(f"{fields['sha256'][:70]!r} is not a SHA-256 digest", path=index, field=f"{where}.sha256")
    for key in ("file", "evidence"):
        if fields[key] and (Path(fields[key]).name != fields[key] or fields[key].startswith(".")):
            raise InputError(f"{fields[key][:70]!r} is not a file of this folder", path=index, field=f"{where}.{key}")
    return fields, stages


def _legacy_entry(
    raw: Any, index: Path, folder: Path, where: str
) -> tuple[HistoryEntry, datetime, CalibrationRecord, CalibrationRecord | None]:
    """Return one entry of an old index with its time, its record (verified) and the estimate kept beside it."""
    from stableins.data.jsonio import parse_json, read_input_bytes
    from stableins.records import CalibrationRecord

    fields, stages = _legacy_fields(raw, index, where)
    when = parse_date(fields["valid_from"], f"{where}.valid_from")
    data = verified_bytes(folder / fields["file"], fields["sha256"])
    record = CalibrationRecord.from_document(parse_json(data, path=folder / fields["file"]), str(folder / fields["file"]))
    evidence = None
    evidence_digest = ""
    if fields["evidence"]:  # the old index kept no digest of the estimate: it is taken as found (and kept from now on)
        evidence_path = folder / fields["evidence"]
        evidence_data = read_input_bytes(evidence_path, max_bytes=MAX_RECORD_BYTES, what="the estimate the history index lists")
        evidence = CalibrationRecord.from_document(parse_json(evidence_data, path=evidence_path), str(evidence_path))
        evidence_digest = hashlib.sha256(evidence_data).hexdigest()
    entry = HistoryEntry(
        fields["file"],
        fields["valid_from"],
        fields["created"],
        fields["sha256"],
        fields["procedure"],
        stages,
        fields["prior"],
        fields["evidence"],
        evidence_digest,
    )
    return entry, when, record, evidence
