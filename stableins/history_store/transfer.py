"""Copying a whole history store into another (``stableins history --migrate SRC DST``): SQLite ↔ PostgreSQL.

Every record (and the estimate kept beside it) is read from the source verified against the SHA-256 its index holds,
validated as a calibration record, and filed in the target as :meth:`HistoryStore.add` files it: the same bytes, so
the same SHA-256, file name, valid-from time, prior and parameters.  Records the target already holds are left as
they are (filing is idempotent), so a migration interrupted at any point is finished by running it again.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

from stableins.errors import InputError
from stableins.history_store.filing import Filing, filing_of
from stableins.history_store.store import HistoryStore


@dataclass(frozen=True)
class Transfer:
    """What :func:`transfer` did: units and records read from the source, records newly filed in the target."""

    units: int
    records: int
    filed: int


def transfer(source: HistoryStore, target: HistoryStore) -> Transfer:
    """Copy every record of ``source`` into ``target`` (records already there are kept); return the counts.

    Raises
    ------
    InputError
        The source is empty or missing, or one of its records fails its SHA-256 check (nothing after it is filed).
    """
    serials = source.serials()
    if not serials:
        raise InputError("the history store holds no records", path=source.location, expected="a store with filed records")
    if source.location == target.location:
        raise InputError("source and target are the same store", path=target.location, field="DST", expected="another store")
    before = sum(len(target.entries(s)) for s in target.serials())
    counted: list[int] = []
    target.add_filings(_filings(source, serials, counted))
    after = sum(len(target.entries(s)) for s in target.serials())
    return Transfer(len(serials), sum(counted), after - before)


def _filings(source: HistoryStore, serials: list[str], counted: list[int]) -> Iterator[Filing]:
    """Yield the filing of every record of ``source``, read verified, unit by unit, oldest first."""
    from stableins.data.jsonio import parse_json
    from stableins.records import CalibrationRecord

    for serial in serials:
        for entry in source.entries(serial):
            where = f"{source.location} {serial}/{entry.file}"
            data = source.verified_data(serial, entry)
            record = CalibrationRecord.from_document(parse_json(data, path=where, what="a filed calibration record"), where)
            evidence_data = evidence = None
            if entry.evidence:
                evidence_data = source.verified_data(serial, entry, evidence=True)
                evidence = CalibrationRecord.from_document(parse_json(evidence_data, path=where, what="a filed estimate"), where)
            counted.append(1)
            yield filing_of(data, record, prior=entry.prior, evidence_data=evidence_data, evidence_record=evidence, source=where)
