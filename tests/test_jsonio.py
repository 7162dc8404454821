"""The one JSON reader (stableins.data.jsonio): its limits exactly at their edges, and the JSON path in every message."""

import math

import pytest

from stableins.data.jsonio import MAX_DEPTH, MAX_INTEGER_DIGITS, load_json_file, parse_json
from stableins.errors import InputError


def test_depth_limit_is_exact():
    assert parse_json("[" * MAX_DEPTH + "]" * MAX_DEPTH) is not None
    with pytest.raises(InputError, match=f"nested more than {MAX_DEPTH} levels"):
        parse_json("[" * (MAX_DEPTH + 1) + "]" * (MAX_DEPTH + 1))
    with pytest.raises(InputError, match="nested more than"):  # deeper than Python's recursion limit: no RecursionError
        parse_json("[" * 100_000 + "]" * 100_000)


def test_integers_numbers_and_keys():
    assert parse_json("-" + "9" * MAX_INTEGER_DIGITS) == -int("9" * MAX_INTEGER_DIGITS)
    with pytest.raises(InputError, match=r"field 'a\[1\]'.*integer of 21 digits"):
        parse_json('{"a": [0, ' + "1" * 21 + "]}", path="x.json")
    with pytest.raises(InputError, match=r"field 'a.b': number '1e400' overflows"):
        parse_json('{"a": {"b": 1e400}}')
    with pytest.raises(InputError, match="field 'h.a': NaN is not a JSON number"):
        parse_json('{"a": NaN}', field="h")
    assert math.isnan(parse_json('{"a": NaN}', allow_nan=True)["a"])  # the journal's own headers
    with pytest.raises(InputError, match="key 'a' appears twice"):
        parse_json('{"a": 1, "b": 2, "a": 3}')
    assert parse_json("\ufeff[1]") == [1] and parse_json(b"\xef\xbb\xbf[2]") == [2]
    with pytest.raises(InputError, match="not UTF-8 text"):
        parse_json(b'["\xff"]')
    with pytest.raises(InputError, match="not valid JSON: .* line 1 column 6"):
        parse_json('{"a":')


def test_files_are_sized_before_they_are_read(tmp_path):
    big = tmp_path / "big.json"
    big.write_bytes(b"[" + b"1," * 600 + b"1]")
    with pytest.raises(InputError, match="file of 1203 bytes"):
        load_json_file(big, max_bytes=1000)
    assert len(load_json_file(big)) == 601
    with pytest.raises(InputError, match="is a directory"):
        load_json_file(tmp_path)
    with pytest.raises(InputError, match="file not found"):
        load_json_file(tmp_path / "none.json")
