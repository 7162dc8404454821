"""Issue 30: ``calibrate system`` reads its record once, validating it in the stage's own pass.

:meth:`SystemRecord.validating` hands the stage the same chunks :meth:`SystemRecord.iter_chunks` would (thinned
columns included), checks what :meth:`SystemRecord.validate` checks, at any chunk length, and names the same row.
"""

import shutil

import h5py
import numpy as np
import pytest
from system_synthetic import paper_residuals, record

from stableins.data.system import SystemRecordWriter, open_system_record
from stableins.errors import InputError


@pytest.fixture(scope="module")
def day(tmp_path_factory):
    """Two hours at 10 Hz (an /overview every 10 rows and a /time_grid), written in chunks of 4096 rows."""
    tmp = tmp_path_factory.mktemp("one-pass")
    true, installed = paper_residuals()
    cols, meta = record(true, installed, rate=10.0, duration=7200.0, seed=3)
    path = tmp / "day.h5"
    with SystemRecordWriter(path, meta, chunk_samples=4096) as writer:
        writer.append(cols)
    return tmp, path


def _chunks(source, rows):
    columns = ["f_x", "f_y", "f_z", "time", "pitch", "roll", "temperature"]
    thin = ["pitch", "roll", "temperature", "time"]
    return [{k: np.array(v) for k, v in c.items()} for c in source.iter_chunks(columns, rows, thin=thin, step=20, reuse=True)]


def test_the_validating_source_yields_what_the_record_yields(day):
    _, path = day
    opened = open_system_record(path)
    assert opened.time_grid is not None and opened._reader.overview_step == 10  # both derived datasets are checked
    for rows in (4096, 5003):  # a chunk length that is not a multiple of the overview's step
        source = opened.validating()
        mine, theirs = _chunks(source, rows), _chunks(opened, rows)
        assert len(mine) == len(theirs) == -(-opened.n_samples // rows)
        for a, b in zip(mine, theirs, strict=True):
            assert a.keys() == b.keys()
            for k in a:
                np.testing.assert_array_equal(a[k], b[k])
        assert source.validation == opened.validate()


@pytest.mark.parametrize(
    ("edit", "row", "field"),
    [
        (lambda f: f["overview/pitch"].__setitem__(1203, 1.0), 12031, "/overview/pitch"),  # overview row 1203 = row 12031
        (lambda f: f["columns/velocity_down"].__setitem__(9000, np.nan), 9001, "velocity_down"),
        (lambda f: f["columns/time"].__setitem__(6000, 1e9), 6001, "/time_grid"),
    ],
)
def test_a_problem_is_named_by_its_row_whatever_the_chunks(day, edit, row, field):
    tmp, good = day
    path = tmp / "bad.h5"
    shutil.copyfile(good, path)
    with h5py.File(path, "r+") as f:
        edit(f)
    opened = open_system_record(path)
    with pytest.raises(InputError) as checked:
        opened.validate()
    for rows in (4096, 5003):
        with pytest.raises(InputError) as passed:
            for _ in opened.validating().iter_chunks(["f_x", "pitch"], rows, thin=["pitch"], step=20, reuse=True):
                pass
        assert str(passed.value) == str(checked.value)
        assert f"row {row}" in str(passed.value) and field in str(passed.value)
