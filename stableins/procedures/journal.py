"""Append-only run journal: every driver operation and decision of a procedure run, on disk as it happens.

The journal is what makes a run survive a crash, a power loss or ``kill -9``: each record is
written with one ``write`` call, flushed and ``fsync``-ed before the runner acts on it, so
anything the runner has seen is on disk.  On resume the journal is read back, a torn last
record (the write the crash interrupted) is detected by its length or checksum and cut off,
and the run continues after the last whole record: nothing accepted is lost, nothing is
written twice.

File layout (all integers little-endian)::

    file    := FILE_MAGIC record*
    record  := RECORD_MAGIC  u32 payload_length  u32 crc32(payload)  payload
    payload := u32 header_length  header(JSON, UTF-8)  array_bytes*

The JSON header holds ``seq`` (0, 1, 2, ... without gaps), ``kind`` and the record's fields;
``arrays`` lists ``[name, dtype, shape]`` of the raw arrays that follow it, in order.
The format is described for users in ``docs/procedures.md``.
"""

from __future__ import annotations

import json
import os
import struct
import zlib
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from stableins.data.atomic import fsync_directory
from stableins.documents import JSONObject
from stableins.errors import InputError, NotDeterminedError
from stableins.samples import SampleBlock
from stableins.site import SiteMetadata

FILE_MAGIC = b"STABLEINS-JOURNAL 1\n"
RECORD_MAGIC = b"\xa5JR1"
_RECORD_HEAD = struct.Struct("<4sII")
_HEADER_LENGTH = struct.Struct("<I")
#: Largest payload accepted when reading (guards against a corrupted length field) [bytes].
MAX_PAYLOAD = 1 << 31
#: Test hook: with ``STABLEINS_KILL_AFTER_RECORDS=N`` in its environment, a process kills itself (SIGKILL, as
#: ``kill -9``) right after the journal it writes holds N records on disk: a deterministic crash for the resume
#: tests (tests/test_run_network_system.py), where killing from outside would depend on timing.
KILL_AFTER_ENV = "STABLEINS_KILL_AFTER_RECORDS"
#: Suffix of a journal being created under a temporary name (see :meth:`Journal.create`).
_UNLINKED_SUFFIX = ".new"
_DTYPES = {"float64": "<f8", "int64": "<i8", "uint8": "u1"}
ArrayLikeOrNone = Any

#: The journal's file name in a run directory.
JOURNAL_NAME = "journal.bin"


def journal_path(path: str | Path) -> Path:
    """Return the journal file of a run directory (or the journal file itself)."""
    path = Path(path)
    return path / JOURNAL_NAME if path.is_dir() else path


def live_operations(records: list[Any]) -> list[Any]:
    """Operation records that stand: drop those a resume superseded (see :mod:`stableins.procedures.runner`)."""
    superseded: set[int] = set()
    for record in records:
        if record.kind == "resume":
            first, last = record["superseded"] if record.get("superseded") else (0, -1)
            superseded.update(range(first, last + 1))
    return [r for r in records if r.kind == "op" and r.seq not in superseded]


def metadata_from_start(record: Any) -> SiteMetadata:
    """Return the site metadata a journal's start record holds."""
    d = dict(record["metadata"])
    d["gimbal_senses"] = tuple(d["gimbal_senses"])
    d["base_attitude"] = tuple(d["base_attitude"])
    return SiteMetadata(**d)


def block_from_record(record: Any) -> SampleBlock:
    """Return the samples a journaled acquisition holds."""
    a = record.arrays
    return SampleBlock(time=a["time"], specific_force=a["specific_force"], angles=a["angles"], temperature=a["temperature"])


@dataclass(frozen=True)
class Record:
    """One journal record: a JSON-able header and named arrays.

    The arrays of a record read from (or written to) a file are not kept in memory: they are
    read back from ``path`` at ``offset`` (CRC checked) each time :attr:`arrays` is used, so a
    run of any length is resumed and exported in bounded memory.
    """

    seq: int
    kind: str
    fields: JSONObject
    offset: int = 0
    path: str | None = None
    loaded: dict[str, NDArray[Any]] | None = field(default=None, repr=False, compare=False)

    @property
    def arrays(self) -> dict[str, NDArray[Any]]:
        """The record's arrays (read back from the journal file unless they are held in memory)."""
        if self.loaded is not None:
            return self.loaded
        if self.path is None or not self.fields.get("_has_arrays"):
            return {}
        return _read_arrays(self.path, self.offset)

    def __getitem__(self, key: str) -> Any:
        return self.fields[key]

    def get(self, key: str, default: Any = None) -> Any:
        """Return the field ``key`` of the record, or ``default``."""
        return self.fields.get(key, default)


@dataclass(frozen=True)
class ScanResult:
    """What :func:`scan` found in a journal file."""

    records: list[Record]
    valid_length: int
    torn_bytes: int
    torn_reason: str | None


def encode(seq: int, kind: str, fields: Mapping[str, Any], arrays: Mapping[str, ArrayLikeOrNone] | None = None) -> bytes:
    """Serialize one record (magic, length, CRC-32 and payload)."""
    names: list[list[Any]] = []
    blobs: list[bytes] = []
    for name, value in (arrays or {}).items():
        if value is None:
            continue
        a = np.asarray(value)
        dtype = _canonical_dtype(a.dtype, name)
        a = np.ascontiguousarray(a, dtype=_DTYPES[dtype])
        names.append([name, dtype, list(a.shape)])
        blobs.append(a.tobytes())
    header = dict(fields)
    header.update(seq=int(seq), kind=kind, arrays=names)
    text = json.dumps(header, separators=(",", ":"), allow_nan=True).encode("utf-8")
    payload = _HEADER_LENGTH.pack(len(text)) + text + b"".join(blobs)
    return _RECORD_HEAD.pack(RECORD_MAGIC, len(payload), zlib.crc32(payload)) + payload


def _canonical_dtype(dtype: np.dtype, name: str) -> str:
    if dtype.kind == "f":
        return "float64"
    if dtype.kind in "iu":
        return "int64"
    if dtype.kind == "b":
        return "uint8"
    raise TypeError(f"journal array {name!r}: unsupported dtype {dtype}")


def _decode(payload: bytes, offset: int, path: str | None = None, *, with_arrays: bool = True) -> Record:
    from stableins.data.jsonio import parse_json

    (n,) = _HEADER_LENGTH.unpack_from(payload, 0)
    if n > len(payload) - 4:
        raise ValueError("header length beyond the payload")
    try:
        header = parse_json(payload[4 : 4 + n], path=path, field="journal record", allow_nan=True, what="a journal record header")
    except InputError as error:
        raise ValueError(error.describe()) from None
    if not isinstance(header, dict) or not isinstance(header.get("arrays"), list):
        raise ValueError("the record header is not an object with an array list")
    position = 4 + n
    arrays: dict[str, NDArray[Any]] = {}
    specs = header.pop("arrays")
    for spec in specs:
        if not (isinstance(spec, list) and len(spec) == 3 and spec[1] in _DTYPES and isinstance(spec[2], list)):
            raise ValueError(f"bad array description {str(spec)[:80]}")
        name, dtype, shape = spec
        if not all(isinstance(d, int) and 0 <= d < 1 << 40 for d in shape):
            raise ValueError(f"bad array shape {str(shape)[:80]}")
        count = int(np.prod(shape, dtype=object)) if shape else 1
        if count * np.dtype(_DTYPES[dtype]).itemsize > len(payload) - position:
            raise ValueError("arrays longer than the payload")
        size = count * np.dtype(_DTYPES[dtype]).itemsize
        if with_arrays:
            a = np.frombuffer(payload, dtype=_DTYPES[dtype], count=count, offset=position).reshape(shape)
            arrays[name] = a.astype(a.dtype.newbyteorder("="), copy=True)
        position += size
    if position != len(payload):
        raise ValueError("payload length does not match its arrays")
    seq = int(header.pop("seq"))
    kind = str(header.pop("kind"))
    header["_has_arrays"] = bool(specs)
    return Record(seq=seq, kind=kind, fields=header, offset=offset, path=path, loaded=arrays if with_arrays and path is None else None)


def _read_arrays(path: str, offset: int) -> dict[str, NDArray[Any]]:
    """Read the arrays of the record at ``offset`` (read back and CRC-checked)."""
    with open(path, "rb") as handle:
        handle.seek(offset)
        magic, length, crc = _RECORD_HEAD.unpack(handle.read(_RECORD_HEAD.size))
        payload = handle.read(length)
    if magic != RECORD_MAGIC or len(payload) != length or zlib.crc32(payload) != crc:
        raise InputError(f"journal record at byte {offset} changed on disk since it was read", path=path)
    return _decode(payload, offset).arrays


def scan(path: str | os.PathLike[str]) -> ScanResult:
    """Read every whole record of a journal (headers; arrays on demand); detect a torn tail.

    A record that is cut short, or whose checksum fails while it is the last thing in the
    file, is the write a crash interrupted: it is reported as torn (``torn_bytes``) and
    not returned.  Damage anywhere else is not explainable by a crash and raises.  The file
    is read one record at a time (bounded memory).

    Raises
    ------
    InputError
        The file is not a journal, or it is damaged before its last record.
    """
    path = Path(path)
    try:
        with open(path, "rb") as handle:
            return _scan_file(path, handle)
    except FileNotFoundError:
        raise InputError("no run journal here", path=path, expected="a run directory made by 'stableins run'") from None


def follow(path: str | os.PathLike[str], position: int = 0, first_seq: int = 0) -> ScanResult:
    """Read the whole records of a journal that follow byte ``position`` (a previous scan's ``valid_length``).

    What a reader watching a run uses (``stableins serve``): each call reads only what was appended since the last,
    and a record still being written is left for the next call (reported as torn, not returned).  ``first_seq`` is
    the sequence number the first new record must carry (the number of records read so far).

    Raises
    ------
    InputError
        The file is missing, not a journal, or damaged before its last record.
    """
    if position <= 0:
        return scan(path)
    path = Path(path)
    try:
        with open(path, "rb") as handle:
            handle.seek(position)
            return _scan_file(path, handle, position=position, first_seq=first_seq)
    except FileNotFoundError:
        raise InputError("no run journal here", path=path, expected="a run directory made by 'stableins run'") from None


def _scan_file(path: Path, handle: Any, *, position: int = 0, first_seq: int = 0) -> ScanResult:
    """Scan the open journal ``handle`` (:func:`scan`; from ``position`` for :func:`follow`)."""
    size = os.fstat(handle.fileno()).st_size
    if position == 0:
        start = handle.read(len(FILE_MAGIC))
        if start != FILE_MAGIC:
            if FILE_MAGIC.startswith(start):  # the crash hit while the file header was written
                return ScanResult([], 0, len(start), "file header incomplete")
            raise InputError("not a stableins run journal", path=path, expected=f"a file starting with {FILE_MAGIC!r}")
        position = len(FILE_MAGIC)
    records: list[Record] = []
    torn_reason = None
    while position < size:
        head = handle.read(_RECORD_HEAD.size)
        if len(head) < _RECORD_HEAD.size:
            torn_reason = "record head incomplete"
            break
        magic, length, crc = _RECORD_HEAD.unpack(head)
        end = position + _RECORD_HEAD.size + length
        if magic != RECORD_MAGIC or length > MAX_PAYLOAD:
            _damaged(path, handle, position, "bad record marker", size=size, end=end)
            torn_reason = "bad record marker"
            break
        if end > size:
            torn_reason = "record cut short"
            break
        payload = handle.read(length)
        if zlib.crc32(payload) != crc:
            _damaged(path, handle, position, "checksum mismatch", size=size, end=end)
            torn_reason = "checksum mismatch"
            break
        records.append(_scanned_record(path, payload, position, first_seq + len(records)))
        position = end
    return ScanResult(records, position, size - position, torn_reason)


def _scanned_record(path: Path, payload: bytes, position: int, expected_seq: int) -> Record:
    """Decode the record at ``position``; InputError when it cannot be decoded or is out of sequence."""
    try:
        record = _decode(payload, position, str(path), with_arrays=False)
    except (InputError, NotDeterminedError):
        raise  # a described error passes through as it is (issue 29)
    except (ValueError, KeyError, UnicodeDecodeError) as error:
        raise InputError(f"journal record at byte {position} cannot be decoded ({error})", path=path) from None
    if record.seq != expected_seq:
        raise InputError(f"journal record at byte {position} has sequence number {record.seq}", path=path, expected=str(expected_seq))
    return record


def has_start(path: str | os.PathLike[str]) -> bool:
    """Whether ``path`` is a journal whose first record is whole and a ``start``: a run that can be resumed.

    Reads only the file header and the first record.
    """
    return start_record(path) is not None


def start_record(path: str | os.PathLike[str]) -> Record | None:
    """Return the whole ``start`` record that opens the journal at ``path``, or None (no journal, or none that starts so).

    Reads only the file header and the first record.
    """
    try:
        with open(path, "rb") as handle:
            if handle.read(len(FILE_MAGIC)) != FILE_MAGIC:
                return None
            head = handle.read(_RECORD_HEAD.size)
            if len(head) < _RECORD_HEAD.size:
                return None
            magic, length, crc = _RECORD_HEAD.unpack(head)
            if magic != RECORD_MAGIC or length > MAX_PAYLOAD:
                return None
            payload = handle.read(length)
    except OSError:
        return None
    if len(payload) != length or zlib.crc32(payload) != crc:
        return None
    try:
        record = _decode(payload, len(FILE_MAGIC), str(path), with_arrays=False)
    except (InputError, NotDeterminedError):
        raise  # a described error passes through as it is (issue 29)
    except (ValueError, KeyError, UnicodeDecodeError):
        return None
    return record if record.kind == "start" else None


def remove_unlinked(path: str | os.PathLike[str]) -> None:
    """Remove what a :meth:`Journal.create` of ``path`` killed before it linked the journal left (temporary files).

    Call only while holding the run directory's lock (:mod:`stableins.procedures.runlock`): no other process creates
    the journal then.
    """
    path = Path(path)
    for leftover in path.parent.glob(f"{path.name}.*{_UNLINKED_SUFFIX}"):
        leftover.unlink(missing_ok=True)


def _damaged(path: Path, handle: Any, position: int, reason: str, *, size: int, end: int) -> None:
    """Raise unless the bad record is the last thing in the file (then it is a torn write)."""
    if end >= size:
        return
    handle.seek(position + 1)
    rest = handle.read()
    if rest.find(RECORD_MAGIC) != -1:
        raise InputError(f"journal damaged at byte {position} ({reason}) with whole records after it; not a torn last write", path=path)


class Journal:
    """An open journal, appended to with :meth:`append` (durable when it returns).

    Use :meth:`create` for a new run and :meth:`open` to resume one; ``open`` drops a torn
    tail from the file (truncate + fsync) so that new records follow the last whole one.
    """

    def __init__(self, path: Path, records: list[Record], handle: int, torn: ScanResult | None = None) -> None:
        self.path = path
        self.records = records
        self._fd = handle
        self.recovered = torn
        kill = os.environ.get(KILL_AFTER_ENV, "")
        self._kill_after = int(kill) if kill.isdigit() else None

    # ------------------------------------------------------------------ open
    @classmethod
    def create(cls, path: str | os.PathLike[str], first: tuple[str, Mapping[str, Any]] | None = None) -> Journal:
        """Create a new journal file (InputError if it exists) and open it for appending.

        ``first``: the kind and fields of the first record (a run's ``start``), written with the file header in one
        step: the file is written and fsync-ed under a temporary name and then linked to ``path``, so a journal never
        exists without its first record (a process killed before the link leaves no journal, only the temporary file,
        which :func:`remove_unlinked` clears).
        """
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        if path.exists():
            raise InputError("a run journal already exists here", path=path, expected="a new run directory, or --resume")
        blob = FILE_MAGIC + (encode(0, first[0], first[1]) if first is not None else b"")
        temporary = path.with_name(f"{path.name}.{os.getpid()}{_UNLINKED_SUFFIX}")
        fd = os.open(temporary, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_APPEND, 0o644)
        try:
            _lock(fd, path)
            written = 0
            while written < len(blob):
                written += os.write(fd, blob[written:])
            os.fsync(fd)
            try:
                os.link(temporary, path)
            except FileExistsError:
                raise InputError("a run journal already exists here", path=path, expected="a new run directory, or --resume") from None
        except BaseException:
            os.close(fd)
            temporary.unlink(missing_ok=True)
            raise
        temporary.unlink()
        fsync_directory(path.parent)
        records = []
        if first is not None:
            payload = blob[len(FILE_MAGIC) + _RECORD_HEAD.size :]
            records.append(_decode(payload, len(FILE_MAGIC), str(path), with_arrays=False))
        return cls(path, records, fd)

    @classmethod
    def open(cls, path: str | os.PathLike[str]) -> Journal:
        """Open an existing journal for appending; its records are read back (a torn last record is dropped)."""
        path = Path(path)
        try:
            fd = os.open(path, os.O_WRONLY | os.O_APPEND)
        except FileNotFoundError:
            raise InputError("no run journal here", path=path, expected="a run directory made by 'stableins run'") from None
        try:
            _lock(fd, path)
            result = scan(path)
        except BaseException:
            os.close(fd)
            raise
        if result.torn_bytes:
            os.ftruncate(fd, result.valid_length)
            if result.valid_length == 0:
                os.write(fd, FILE_MAGIC)
            os.fsync(fd)
        return cls(path, result.records, fd, result if result.torn_bytes else None)

    # ------------------------------------------------------------------ write
    @property
    def next_seq(self) -> int:
        """The sequence number of the next record."""
        return len(self.records)

    def append(self, kind: str, fields: Mapping[str, Any] | None = None, arrays: Mapping[str, Any] | None = None) -> Record:
        """Append one record; returns once it is on disk (``write`` + ``fsync``)."""
        if self._fd < 0:
            raise RuntimeError("journal is closed")
        seq = self.next_seq
        blob = encode(seq, kind, fields or {}, arrays)
        offset = os.lseek(self._fd, 0, os.SEEK_END)
        written = 0
        view = memoryview(blob)
        while written < len(blob):
            written += os.write(self._fd, view[written:])
        os.fsync(self._fd)
        record = _decode(blob[_RECORD_HEAD.size :], offset, str(self.path), with_arrays=False)
        self.records.append(record)
        if self._kill_after is not None and len(self.records) >= self._kill_after:
            import signal

            os.kill(os.getpid(), signal.SIGKILL)  # the test hook (KILL_AFTER_ENV): dies as on kill -9, the record on disk
        return record

    def close(self) -> None:
        """Close the journal file."""
        if self._fd >= 0:
            os.close(self._fd)
            self._fd = -1

    def __enter__(self) -> Journal:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __iter__(self) -> Iterator[Record]:
        return iter(self.records)

    def __len__(self) -> int:
        return len(self.records)


def _lock(fd: int, path: Path) -> None:
    """Exclusive advisory lock for the writer's lifetime: two processes never append to one journal.

    The lock dies with the process (also on ``kill -9``), so a crashed run can always be resumed.
    """
    import fcntl

    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        raise InputError(
            "another stableins process is running this run right now", path=path, expected="that process to finish or stop"
        ) from None
