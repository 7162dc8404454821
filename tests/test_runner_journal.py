"""The run journal: durable appends, torn-tail recovery, damage detection, exactly-once sequence."""

from __future__ import annotations

import os

import numpy as np
import pytest

from stableins.errors import InputError
from stableins.procedures.journal import FILE_MAGIC, Journal, scan


def _fill(path, n=5):
    rng = np.random.default_rng(1)
    blocks = []
    with Journal.create(path) as journal:
        journal.append("start", {"procedure": "x", "seed": 3})
        for k in range(n):
            block = rng.normal(size=(7, 3))
            blocks.append(block)
            journal.append("op", {"op": "acquire", "duration": 0.5, "step": k}, {"f": block, "n": np.arange(7)})
    return blocks


def test_round_trip_is_exact(tmp_path):
    path = tmp_path / "journal.bin"
    blocks = _fill(path)
    result = scan(path)
    assert result.torn_bytes == 0
    assert [r.seq for r in result.records] == list(range(6))
    assert result.records[0]["seed"] == 3
    for block, record in zip(blocks, result.records[1:]):
        assert record.loaded is None  # headers only in memory; arrays read back on demand (bounded memory)
        np.testing.assert_array_equal(record.arrays["f"], block)
        assert record.arrays["n"].dtype == np.int64


@pytest.mark.parametrize("cut", [1, 5, 11, 40, 200])
def test_torn_last_record_is_dropped_and_appends_continue(tmp_path, cut):
    path = tmp_path / "journal.bin"
    _fill(path)
    size = path.stat().st_size
    whole = scan(path)
    last_start = whole.records[-1].offset
    # crash while writing the last record: only part of it reached the disk
    with open(path, "r+b") as handle:
        handle.truncate(min(last_start + cut, size - 1))
    result = scan(path)
    assert len(result.records) == 5
    assert result.valid_length == last_start
    assert result.torn_bytes == min(last_start + cut, size - 1) - last_start
    with Journal.open(path) as journal:
        assert journal.recovered is not None
        assert journal.next_seq == 5
        journal.append("op", {"op": "acquire", "step": 4}, {"f": np.ones((2, 3))})
    again = scan(path)
    assert again.torn_bytes == 0
    assert [r.seq for r in again.records] == list(range(6))
    np.testing.assert_array_equal(again.records[-1].arrays["f"], np.ones((2, 3)))


def test_garbled_last_record_counts_as_torn(tmp_path):
    path = tmp_path / "journal.bin"
    _fill(path)
    size = path.stat().st_size
    with open(path, "r+b") as handle:  # the length reached the disk but the payload did not
        handle.seek(size - 10)
        handle.write(b"\0" * 10)
    result = scan(path)
    assert len(result.records) == 5 and result.torn_reason == "checksum mismatch"


def test_damage_before_the_tail_is_an_error_not_a_silent_cut(tmp_path):
    path = tmp_path / "journal.bin"
    _fill(path)
    second = scan(path).records[2].offset
    with open(path, "r+b") as handle:
        handle.seek(second + 40)
        handle.write(b"XXXX")
    with pytest.raises(InputError, match="damaged at byte"):
        scan(path)


def test_not_a_journal_and_missing_journal(tmp_path):
    other = tmp_path / "other.bin"
    other.write_bytes(b"hello world, not a journal at all")
    with pytest.raises(InputError, match="not a stableins run journal"):
        scan(other)
    with pytest.raises(InputError, match="no run journal"):
        scan(tmp_path / "absent.bin")


def test_create_refuses_to_overwrite(tmp_path):
    path = tmp_path / "journal.bin"
    _fill(path, 1)
    before = path.read_bytes()
    with pytest.raises(InputError, match="already exists"):
        Journal.create(path)
    assert path.read_bytes() == before


def test_crash_inside_file_header(tmp_path):
    path = tmp_path / "journal.bin"
    path.write_bytes(FILE_MAGIC[:7])
    with Journal.open(path) as journal:
        journal.append("start", {"a": 1})
    assert path.read_bytes().startswith(FILE_MAGIC)
    assert [r.kind for r in scan(path).records] == ["start"]


def test_append_is_on_disk_when_it_returns(tmp_path):
    # another reader (as after kill -9) sees the record without any close or flush by the writer
    path = tmp_path / "journal.bin"
    journal = Journal.create(path)
    journal.append("op", {"k": 1}, {"x": np.arange(3.0)})
    fd = os.open(path, os.O_RDONLY)
    try:
        assert len(scan(path).records) == 1
    finally:
        os.close(fd)
        journal.close()


def test_one_writer_at_a_time(tmp_path):
    path = tmp_path / "journal.bin"
    first = Journal.create(path)
    first.append("start", {"a": 1})
    with pytest.raises(InputError, match="another stableins process"):
        Journal.open(path)
    first.close()
    with Journal.open(path) as again:  # the lock went with the writer
        again.append("op", {"b": 2})
    assert [r.kind for r in scan(path).records] == ["start", "op"]
