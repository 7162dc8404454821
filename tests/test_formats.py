"""Data formats: round trips, every class of bad input, atomic writes, streaming."""

from __future__ import annotations

import json
import math
import warnings

import h5py
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from stableins.data.device import DeviceDataset, load_device, save_device
from stableins.data.metadata import metadata_from_document, metadata_to_document
from stableins.data.sampling import SamplingWarning
from stableins.data.system import SystemRecordWriter, open_system_record
from stableins.errors import InputError
from stableins.schema import DEVICE_COLUMNS, SYSTEM_COLUMNS
from stableins.site import SiteMetadata

RATE = 50.0


def make_metadata(**changes) -> SiteMetadata:
    values = dict(
        serial_number="INS-7",
        latitude=math.radians(34.25),
        height=420.0,
        gravity=9.7966,
        gravity_source="survey 2024",
        sample_rate=RATE,
        gimbal_senses=(1, -1, -1, 1),
        base_attitude=(0.1, -0.002, 0.003),
        reference_temperature=22.5,
        damping={"zeta": 0.707, "gain_vertical": 0.03},
        extra={"operator": "A. N. Other"},
    )
    values.update(changes)
    return SiteMetadata(**values)


def make_device_columns(positions=(1, 2, 3), per_dwell=20, stages=("coarse", "fine"), seed=0) -> dict:
    """A small session: each stage dwells at each position for ``per_dwell`` samples."""
    rng = np.random.default_rng(seed)
    blocks = [(s, p) for s in stages for p in positions]
    n = len(blocks) * per_dwell
    columns = {
        "time": np.arange(n) / RATE + 0.5 * np.repeat(np.arange(len(blocks)), per_dwell),
        "stage": np.repeat([s for s, _ in blocks], per_dwell),
        "pass": np.ones(n, dtype=int),
        "position": np.repeat([p for _, p in blocks], per_dwell),
        "time_since_command": np.tile(np.arange(per_dwell) / RATE + 0.5, len(blocks)),
    }
    for k, name in enumerate(("command_platform", "command_inner", "command_middle")):
        columns[name] = np.repeat(rng.uniform(-3, 3, len(blocks)), per_dwell) + k
    for name in ("angle_platform", "angle_inner", "angle_middle", "f_x", "f_y", "f_z", "temperature"):
        columns[name] = rng.normal(size=n)
    return columns


def make_system_chunk(start: int, n: int, seed: int = 0) -> dict:
    rng = np.random.default_rng(seed)
    chunk = {c.name: rng.normal(size=n) for c in SYSTEM_COLUMNS}
    chunk["time"] = np.arange(start, start + n) / RATE
    return chunk


@pytest.fixture
def device_csv(tmp_path):
    path = tmp_path / "session.csv"
    save_device(path, make_device_columns(), make_metadata())
    return path


def edit_lines(path, edit):
    """Rewrite a text file through ``edit(lines) -> lines``."""
    lines = path.read_text().splitlines(keepends=True)
    path.write_text("".join(edit(lines)))


def data_line_index(lines, row):
    """Index in ``lines`` of 1-based data row ``row`` (after the column header)."""
    header = next(k for k, line in enumerate(lines) if not line.startswith("#"))
    return header + row


def expect_input_error(path, *fragments, loader=load_device):
    with pytest.raises(InputError) as info:
        loader(path)
    message = str(info.value)
    assert str(path) in message
    for fragment in fragments:
        assert fragment in message, f"{fragment!r} not in {message!r}"
    return info.value


# --------------------------------------------------------------------------- round trips
@pytest.mark.parametrize("suffix", [".csv", ".h5"])
def test_device_round_trip_keeps_every_value_and_metadata(tmp_path, suffix):
    columns = make_device_columns()
    metadata = make_metadata()
    path = save_device(tmp_path / f"s{suffix}", columns, metadata)
    dataset = load_device(path)
    for c in DEVICE_COLUMNS:
        np.testing.assert_array_equal(dataset.columns[c.name], columns[c.name], err_msg=c.name)
    assert dataset.metadata.serial_number == metadata.serial_number
    assert dataset.metadata.latitude == pytest.approx(metadata.latitude, rel=1e-15)
    assert dataset.metadata.base_attitude == pytest.approx(metadata.base_attitude, rel=1e-15)
    assert dataset.metadata.gimbal_senses == metadata.gimbal_senses
    assert dataset.metadata.damping == metadata.damping and dataset.metadata.extra == metadata.extra
    assert dataset.path == str(path)


def test_dwells_group_contiguous_blocks_and_filter(device_csv):
    dataset = load_device(device_csv)
    dwells = dataset.dwells()
    assert [(d.stage, d.position) for d in dwells] == [(s, p) for s in ("coarse", "fine") for p in (1, 2, 3)]
    fine = dataset.dwells(stage="fine", pass_number=1)
    assert len(fine) == 3 and all(d.stage == "fine" for d in fine)
    assert dataset.dwells(pass_number=2) == ()
    d = fine[1]
    rows = slice(d.first_row - 1, d.first_row - 1 + len(d))
    assert d.angles.shape == (20, 3) and d.specific_force.shape == (20, 3) and d.command.shape == (3,)
    np.testing.assert_array_equal(d.specific_force[:, 1], dataset.columns["f_y"][rows])
    np.testing.assert_array_equal(d.angles[:, 2], dataset.columns["angle_middle"][rows])
    assert d.command[2] == dataset.columns["command_middle"][d.first_row - 1]
    assert dataset.stages == ("coarse", "fine")


def test_csv_is_readable_without_stableins(device_csv):
    import csv

    text = device_csv.read_text()
    lines = text.splitlines()
    block = lines[lines.index("# BEGIN HEADER") + 1 : lines.index("# END HEADER")]
    header = json.loads("\n".join(line[1:] for line in block))
    assert header["metadata"]["latitude"] == {"value": pytest.approx(34.25), "unit": "deg"}
    rows = list(csv.DictReader(line for line in lines if not line.startswith("#")))
    assert len(rows) == 120 and float(rows[3]["f_x[m/s^2]"]) == load_device(device_csv).columns["f_x"][3]
    table = np.genfromtxt((line for line in lines if not line.startswith("#")), delimiter=",", names=True, dtype=None, encoding="utf-8")
    assert table.shape == (120,)


def test_h5_is_readable_with_plain_h5py(tmp_path):
    path = save_device(tmp_path / "s.h5", make_device_columns(), make_metadata())
    with h5py.File(path, "r") as f:
        assert f["columns/f_x"].attrs["unit"] == "m/s^2"
        assert f["columns/f_x"].chunks is not None
        header = json.loads(f.attrs["header"])
        assert header["metadata"]["gravity"] == {"value": 9.7966, "unit": "m/s^2"}
        assert f["columns/stage"][0] == b"coarse"


def test_metadata_document_states_units_and_is_validated():
    document = metadata_to_document(make_metadata())
    assert document["latitude"]["unit"] == "deg" and document["height"]["unit"] == "m"
    assert document["sample_rate"] == {"value": RATE, "unit": "Hz"}
    document["latitude"] = {"value": 34.25, "unit": "grad"}
    with pytest.raises(InputError, match=r"meta.json.*metadata.latitude.*unit 'grad' found.*'deg' or 'rad'"):
        metadata_from_document(document, "meta.json")
    document["latitude"] = 34.25
    with pytest.raises(InputError, match="no explicit unit"):
        metadata_from_document(document, "meta.json")
    document = metadata_to_document(make_metadata())
    document["gravity"]["value"] = 9806.65
    with pytest.raises(InputError, match="gravity.*between 9.7 and 9.9"):
        metadata_from_document(document, "meta.json")
    del document["serial_number"]
    with pytest.raises(InputError, match="serial_number"):
        metadata_from_document(document, "meta.json")


# --------------------------------------------------------------------------- bad input, CSV
def test_missing_column(device_csv):
    def drop_temperature(lines):
        k = data_line_index(lines, 0)
        out = []
        for j, line in enumerate(lines):
            if j >= k and not line.startswith("#"):
                line = ",".join(line.rstrip("\n").split(",")[:-1]) + "\n"
            out.append(line)
        return out

    edit_lines(device_csv, drop_temperature)
    expect_input_error(device_csv, "field 'temperature'", "missing column", "temperature[degC]")


def test_misnamed_column_suggests_the_closest(device_csv):
    edit_lines(device_csv, lambda lines: [line.replace("f_x[m/s^2]", "fx[m/s^2]") if line.startswith("time[") else line for line in lines])
    expect_input_error(device_csv, "field 'f_x'", "found 'fx'", "did you mean 'f_x[m/s^2]'")


def test_wrong_unit(device_csv):
    edit_lines(device_csv, lambda lines: [line.replace("f_y[m/s^2]", "f_y[g]") if line.startswith("time[") else line for line in lines])
    expect_input_error(device_csv, "field 'f_y'", "unit 'g' found", "expected unit 'm/s^2'")


@pytest.mark.parametrize("bad", ["nan", "inf", "-inf"])
def test_non_finite_value_names_row_and_field(device_csv, bad):
    def poison(lines):
        k = data_line_index(lines, 7)
        fields = lines[k].split(",")
        fields[12] = bad  # f_y
        lines[k] = ",".join(fields)
        return lines

    edit_lines(device_csv, poison)
    expect_input_error(device_csv, "row 7", "field 'f_y'", "not finite")


def test_text_in_a_number_field(device_csv):
    def poison(lines):
        k = data_line_index(lines, 3)
        fields = lines[k].split(",")
        fields[0] = "12:00:01"
        lines[k] = ",".join(fields)
        return lines

    edit_lines(device_csv, poison)
    expect_input_error(device_csv, "row 3", "field 'time'", "'12:00:01' is not a number")


def test_non_monotonic_time(device_csv):
    def swap(lines):
        k = data_line_index(lines, 10)
        lines[k], lines[k + 1] = lines[k + 1], lines[k]
        return lines

    edit_lines(device_csv, swap)
    expect_input_error(device_csv, "row 11", "field 'time'", "does not increase")


def test_duplicate_position_in_two_blocks(tmp_path):
    columns = make_device_columns(positions=(1, 2, 3), stages=("coarse",))
    columns["position"] = np.repeat([1, 2, 1], 20)
    path = tmp_path / "dup.csv"
    with pytest.raises(InputError, match="row 41.*position 1 occurs again.*row 1"):
        save_device(path, columns, make_metadata())
    assert not path.exists()
    # the same file written by another tool is refused on load
    good = tmp_path / "good.csv"
    save_device(good, make_device_columns(positions=(1, 2, 3), stages=("coarse",)), make_metadata())

    def renumber(lines):
        for row in range(41, 61):
            k = data_line_index(lines, row)
            fields = lines[k].split(",")
            fields[3] = "1"
            lines[k] = ",".join(fields)
        return lines

    edit_lines(good, renumber)
    expect_input_error(good, "row 41", "field 'position'", "occurs again")


def test_unknown_stage_and_changing_command(tmp_path):
    columns = make_device_columns()
    columns["stage"] = columns["stage"].astype(object)
    columns["stage"][4] = "coarse2"
    with pytest.raises(InputError, match="row 5.*field 'stage'.*unknown stage 'coarse2'"):
        DeviceDataset(make_metadata(), columns, "x.csv")
    columns = make_device_columns()
    columns["command_inner"][5] += 1e-3
    with pytest.raises(InputError, match="row 6.*command_inner.*command changes within the dwell"):
        DeviceDataset(make_metadata(), columns, "x.csv")


def test_unknown_schema_version(device_csv):
    edit_lines(device_csv, lambda lines: [line.replace('"schema_version": 1', '"schema_version": 7') for line in lines])
    expect_input_error(device_csv, "unknown schema version 7", "field 'schema_version'")


def test_csv_cut_mid_row(device_csv):
    text = device_csv.read_text()
    device_csv.write_text(text[: len(text) // 2])
    expect_input_error(device_csv, "cut short")


def test_csv_cut_at_a_row_boundary(device_csv):
    lines = device_csv.read_text().splitlines(keepends=True)
    device_csv.write_text("".join(lines[:-30]))  # whole rows gone, trailer gone
    expect_input_error(device_csv, "no END OF DATA line", "cut short")


def test_csv_rows_removed_in_the_middle(device_csv):
    edit_lines(device_csv, lambda lines: lines[:40] + lines[45:])
    expect_input_error(device_csv, "data rows found but the END OF DATA line says 120")


def test_csv_without_header_or_metadata(tmp_path, device_csv):
    bare = tmp_path / "bare.csv"
    bare.write_text("".join(line for line in device_csv.read_text().splitlines(keepends=True) if not line.startswith("#")))
    expect_input_error(bare, "no header block")


def test_unknown_suffix(tmp_path):
    path = tmp_path / "data.xlsx"
    path.write_text("x")
    expect_input_error(path, "unknown file type '.xlsx'")


# --------------------------------------------------------------------------- bad input, HDF5
@pytest.fixture
def device_h5(tmp_path):
    return save_device(tmp_path / "session.h5", make_device_columns(), make_metadata())


def test_h5_truncated(device_h5):
    data = device_h5.read_bytes()
    device_h5.write_bytes(data[: len(data) // 2])
    expect_input_error(device_h5, "truncated or corrupt")


def test_h5_garbage(tmp_path):
    path = tmp_path / "x.h5"
    path.write_bytes(b"\x89HDF\r\n\x1a\n" + bytes(300))
    expect_input_error(path, "truncated or corrupt")


def test_h5_misnamed_dataset_and_unit(device_h5):
    with h5py.File(device_h5, "a") as f:
        f.move("columns/temperature", "columns/temprature")
    expect_input_error(device_h5, "field 'temperature'", "found 'temprature'")


def test_h5_wrong_unit_and_nan(device_h5, tmp_path):
    with h5py.File(device_h5, "a") as f:
        f["columns/angle_inner"].attrs["unit"] = "deg"
    expect_input_error(device_h5, "field 'angle_inner'", "unit 'deg' found", "'rad'")
    path = save_device(tmp_path / "nan.h5", make_device_columns(), make_metadata())
    with h5py.File(path, "a") as f:
        f["columns/f_z"][17] = np.nan
    expect_input_error(path, "row 18", "field 'f_z'", "not finite")


def test_h5_unknown_schema_version_and_incomplete(device_h5):
    with h5py.File(device_h5, "a") as f:
        header = json.loads(f.attrs["header"])
        header["schema_version"] = 99
        f.attrs["header"] = json.dumps(header)
    expect_input_error(device_h5, "unknown schema version 99")
    with h5py.File(device_h5, "a") as f:
        header["schema_version"] = 1
        f.attrs["header"] = json.dumps(header)
        f.attrs["complete"] = False
    expect_input_error(device_h5, "did not finish")


# --------------------------------------------------------------------------- atomic writes
@pytest.mark.parametrize("suffix", [".csv", ".h5"])
def test_save_device_refuses_bad_data_before_touching_the_old_file(tmp_path, suffix):
    path = save_device(tmp_path / f"s{suffix}", make_device_columns(), make_metadata())
    before = path.read_bytes()
    columns = make_device_columns(seed=1)
    columns["f_x"][3] = np.nan
    with pytest.raises(InputError, match="row 4.*f_x"):
        save_device(path, columns, make_metadata())
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == [path.name]


@pytest.mark.parametrize("suffix", [".h5", ".csv"])
def test_system_writer_crash_leaves_nothing_or_the_old_file(tmp_path, suffix):
    path = tmp_path / f"rec{suffix}"
    with pytest.raises(RuntimeError), SystemRecordWriter(path, make_metadata(), chunk_samples=64) as writer:
        writer.append(make_system_chunk(0, 500))
        raise RuntimeError("power cut")
    assert list(tmp_path.iterdir()) == []
    with SystemRecordWriter(path, make_metadata(), chunk_samples=64) as writer:
        writer.append(make_system_chunk(0, 100))
    before = path.read_bytes()
    with pytest.raises(KeyboardInterrupt), SystemRecordWriter(path, make_metadata(), chunk_samples=64) as writer:
        writer.append(make_system_chunk(0, 300))
        raise KeyboardInterrupt
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == [path.name]


# --------------------------------------------------------------------------- system records
@pytest.mark.parametrize(("suffix", "chunk_samples"), [(".h5", 128), (".h5", 1000), (".h5", 4096), (".csv", 128)])
def test_system_record_streams_round_trip(tmp_path, suffix, chunk_samples):
    path = tmp_path / f"rec{suffix}"
    chunks = [make_system_chunk(k * 333, 333, seed=k) for k in range(4)]
    with SystemRecordWriter(path, make_metadata(), chunk_samples=chunk_samples) as writer:
        for chunk in chunks:
            writer.append(chunk)
            chunk["f_x"][:] = 0.0  # the writer must have copied what it has not written yet
    record = open_system_record(path)
    assert record.n_samples == 1332 and record.sample_rate == RATE and record.metadata.serial_number == "INS-7"
    read = list(record.iter_chunks(["time", "f_x"], rows=500))
    assert [len(c["time"]) for c in read] == [500, 500, 332] and set(read[0]) == {"time", "f_x"}
    expected = [make_system_chunk(k * 333, 333, seed=k) for k in range(4)]
    np.testing.assert_array_equal(np.concatenate([c["f_x"] for c in read]), np.concatenate([c["f_x"] for c in expected]))
    np.testing.assert_array_equal(record.read(["velocity_east"])["velocity_east"], np.concatenate([c["velocity_east"] for c in expected]))
    report = record.check_sampling()
    assert report.uniform and report.mean_rate == pytest.approx(RATE)


def test_system_h5_layout(tmp_path):
    path = tmp_path / "rec.h5"
    with SystemRecordWriter(path, make_metadata(), chunk_samples=256) as writer:
        writer.append(make_system_chunk(0, 1000))
    with h5py.File(path, "r") as f:
        assert f.attrs["rows"] == 1000 and bool(f.attrs["complete"])
        assert f["columns/velocity_north"].chunks == (256,) and f["columns/velocity_north"].maxshape == (None,)
        assert f["columns/heading"].attrs["unit"] == "rad"


def write_record(path, time):
    chunk = make_system_chunk(0, len(time))
    chunk["time"] = time
    with SystemRecordWriter(path, make_metadata(), chunk_samples=256) as writer:
        writer.append(chunk)
    return open_system_record(path)


def test_sampling_gap_is_an_error_naming_the_row(tmp_path):
    time = np.arange(1000) / RATE
    time[600:] += 2.0
    record = write_record(tmp_path / "gap.h5", time)
    with pytest.raises(InputError, match=r"gap\.h5, row 601, field 'time': gap in the record: time step 2.02 s"):
        record.check_sampling()
    with pytest.warns(SamplingWarning, match="row 601: gap") as caught:
        report = record.check_sampling(allow_gaps=True)
    assert caught[0].message.issues[0].row == 601 and len(report.gaps) == 1


def test_sampling_jitter_is_a_structured_warning(tmp_path):
    time = np.arange(1000) / RATE
    time[300] += 0.2 / RATE
    record = write_record(tmp_path / "jit.h5", time)
    with pytest.warns(SamplingWarning) as caught:
        report = record.check_sampling()
    warning = caught[0].message
    assert warning.path.endswith("jit.h5") and [i.row for i in warning.issues] == [301, 302]
    assert report.n_jitter == 2 and report.max_step_error == pytest.approx(0.2 / RATE)


def test_sampling_rate_disagreeing_with_metadata(tmp_path):
    record = write_record(tmp_path / "rate.h5", np.arange(1000) / (2 * RATE))
    with pytest.raises(InputError, match="100 Hz but the metadata say 50 Hz"):
        record.check_sampling()


def test_writer_refuses_time_going_back_across_chunks(tmp_path):
    path = tmp_path / "back.h5"
    with (
        pytest.raises(InputError, match=r"back\.h5, row 101, field 'time': time does not increase"),
        SystemRecordWriter(path, make_metadata()) as writer,
    ):
        writer.append(make_system_chunk(0, 100))
        writer.append(make_system_chunk(50, 100))
    assert not path.exists()


def test_writer_refuses_missing_column_and_nan(tmp_path):
    path = tmp_path / "bad.h5"
    chunk = make_system_chunk(0, 10)
    del chunk["roll"]
    with pytest.raises(InputError, match="field 'roll'"), SystemRecordWriter(path, make_metadata()) as writer:
        writer.append(chunk)
    chunk = make_system_chunk(0, 10)
    chunk["pitch"][4] = np.inf
    with pytest.raises(InputError, match="row 15, field 'pitch'"), SystemRecordWriter(path, make_metadata()) as writer:
        writer.append(make_system_chunk(-10, 10))
        writer.append(chunk)
    assert not path.exists()


def test_system_csv_non_monotonic_and_nan_found_by_streaming_reader(tmp_path):
    path = tmp_path / "rec.csv"
    with SystemRecordWriter(path, make_metadata()) as writer:
        writer.append(make_system_chunk(0, 200))

    def poison(lines):
        k = data_line_index(lines, 150)
        fields = lines[k].split(",")
        fields[7] = "nan"  # velocity_north
        lines[k] = ",".join(fields)
        return lines

    edit_lines(path, poison)
    with pytest.raises(InputError, match=r"rec\.csv, row 150, field 'velocity_north'"):
        open_system_record(path)


def test_system_h5_nan_found_when_reading_chunks(tmp_path):
    path = tmp_path / "rec.h5"
    with SystemRecordWriter(path, make_metadata()) as writer:
        writer.append(make_system_chunk(0, 300))
    with h5py.File(path, "a") as f:
        f["columns/f_y"][250] = np.nan
    record = open_system_record(path)
    with pytest.raises(InputError, match=r"rec\.h5, row 251, field 'f_y'"):
        for _ in record.iter_chunks(["f_y"], rows=100):
            pass


def test_open_system_record_refuses_device_file(device_h5):
    with warnings.catch_warnings():
        expect_input_error(device_h5, "format 'stableins-device' found", "'stableins-system'", loader=open_system_record)


def test_formats_doc_lists_every_column():
    from pathlib import Path

    text = (Path(__file__).resolve().parents[1] / "docs" / "formats.md").read_text()
    for column in DEVICE_COLUMNS + SYSTEM_COLUMNS:
        assert f"| `{column.header}` | {column.dtype} |" in text, column.header


def test_csv_column_order_is_free_and_extra_columns_ignored(device_csv):
    def reorder(lines):
        out = []
        for line in lines:
            if line.startswith("#"):
                out.append(line)
            else:
                fields = line.rstrip("\n").split(",")
                out.append(",".join(fields[::-1] + ["extra[V]" if fields[0] == "time[s]" else "1.5"]) + "\n")
        return out

    original = load_device(device_csv)
    edit_lines(device_csv, reorder)
    again = load_device(device_csv)
    for c in DEVICE_COLUMNS:
        np.testing.assert_array_equal(again.columns[c.name], original.columns[c.name])


@pytest.mark.parametrize("rows", [100, 600, 601, 65536])
def test_sampling_issue_rows_do_not_depend_on_chunking(tmp_path, rows):
    time = np.arange(1000) / RATE
    time[600:] += 1.0  # gap before row 601
    time[200] += 0.1 / RATE  # jitter at rows 201 and 202
    record = write_record(tmp_path / "r.h5", time)
    with pytest.warns(SamplingWarning):
        report = record.check_sampling(allow_gaps=True, rows=rows)
    assert [g.row for g in report.gaps] == [601]
    assert [j.row for j in report.jitter] == [201, 202]


@settings(max_examples=25, deadline=None)
@given(st.lists(st.floats(min_value=-1e4, max_value=1e4, allow_nan=False, width=64), min_size=1, max_size=30))
def test_csv_float_round_trip_is_exact(tmp_path_factory, values):
    """Every float the specific-force column admits (its physical limits, ±10⁴ m/s², subnormals included) round-trips."""
    path = tmp_path_factory.mktemp("rt") / "s.csv"
    n = len(values)
    columns = make_device_columns(positions=(1,), per_dwell=n, stages=("coarse",))
    columns["f_x"] = np.array(values)
    save_device(path, columns, make_metadata())
    np.testing.assert_array_equal(load_device(path).columns["f_x"], columns["f_x"])


def test_package_exports_are_lazy():
    import subprocess
    import sys

    code = (
        "import sys, stableins.data as d\n"
        "assert d.load_device.__module__ == 'stableins.data.device' and d.SystemRecordWriter.__module__ == 'stableins.data.system'\n"
        "assert not {'numpy', 'h5py'} & set(sys.modules), sorted({'numpy', 'h5py'} & set(sys.modules))\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr


def test_h5_written_by_another_tool(tmp_path):
    """Only the header attribute and unit-tagged datasets are needed (docs/formats.md)."""
    columns = make_device_columns()
    path = tmp_path / "other.h5"
    with h5py.File(path, "w") as f:
        f.attrs["header"] = json.dumps(
            {"format": "stableins-device", "schema_version": 1, "metadata": metadata_to_document(make_metadata())}
        )
        for c in DEVICE_COLUMNS:
            values = columns[c.name].astype("S") if c.dtype == "str" else columns[c.name]
            d = f.create_dataset(f"columns/{c.name}", data=values)
            if c.unit:
                d.attrs["unit"] = c.unit
    dataset = load_device(path)
    np.testing.assert_array_equal(dataset.columns["f_y"], columns["f_y"])
    assert len(dataset.dwells()) == 6
    with h5py.File(path, "a") as f:
        del f["columns/f_y"]
        f["columns/f_y"] = columns["f_y"][:-1]
        f["columns/f_y"].attrs["unit"] = "m/s^2"
    expect_input_error(path, "field 'f_y'", "shape (119,)")


@settings(max_examples=60, deadline=None)
@given(st.data())
def test_damaged_csv_gives_input_error_or_loads(tmp_path_factory, data):
    """Any cut, deletion or overwrite of a CSV file: a clean load or an InputError, nothing else."""
    path = tmp_path_factory.mktemp("fuzz") / "s.csv"
    save_device(path, make_device_columns(per_dwell=5), make_metadata())
    raw = bytearray(path.read_bytes())
    for _ in range(data.draw(st.integers(1, 3))):
        start = data.draw(st.integers(0, len(raw) - 1))
        stop = data.draw(st.integers(start, min(len(raw), start + 40)))
        action = data.draw(st.sampled_from(["cut", "delete", "overwrite"]))
        if action == "cut":
            raw = raw[:start]
        elif action == "delete":
            del raw[start:stop]
        else:
            raw[start:stop] = data.draw(st.binary(min_size=stop - start, max_size=stop - start))
        if not raw:
            break
    path.write_bytes(bytes(raw))
    try:
        load_device(path)
    except InputError as error:
        assert str(path) in str(error)


@pytest.mark.parametrize("fraction", [0.01, 0.1, 0.3, 0.5, 0.7, 0.9, 0.99])
def test_truncated_h5_at_any_length_gives_input_error(tmp_path, fraction):
    path = save_device(tmp_path / "s.h5", make_device_columns(per_dwell=200), make_metadata())
    raw = path.read_bytes()
    path.write_bytes(raw[: int(len(raw) * fraction)])
    expect_input_error(path, "truncated or corrupt")


@pytest.mark.parametrize(("suffix", "compression"), [(".h5", None), (".h5", "gzip"), (".csv", None)])
def test_system_thin_and_reused_reads_equal_plain_reads(tmp_path, suffix, compression):
    """``thin`` columns are the rows at multiples of ``step`` (any chunking); ``reuse`` buffers hold the same values."""
    path = tmp_path / f"thin{suffix}"
    extra = {"compression": compression} if compression else {}
    with SystemRecordWriter(path, make_metadata(), chunk_samples=1000, **extra) as writer:
        writer.append(make_system_chunk(0, 3500, seed=2))
        writer.append(make_system_chunk(3500, 1234, seed=3))
    record = open_system_record(path)
    full = record.read(["time", "pitch", "roll"])
    for rows, step in ((700, 7), (999, 100), (5000, 3)):
        pieces: dict[str, list] = {"time": [], "pitch": [], "roll": []}
        for chunk in record.iter_chunks(["time", "pitch", "roll"], rows=rows, thin=["pitch", "roll"], step=step, reuse=True):
            for name, values in chunk.items():
                pieces[name].append(np.array(values))  # copy: reused buffers change with the next chunk
        got = {name: np.concatenate(parts) for name, parts in pieces.items()}
        np.testing.assert_array_equal(got["time"], full["time"])
        np.testing.assert_array_equal(got["pitch"], full["pitch"][::step])
        np.testing.assert_array_equal(got["roll"], full["roll"][::step])


def test_system_thin_read_names_the_row_of_a_nan(tmp_path):
    import h5py

    path = tmp_path / "nan.h5"
    with SystemRecordWriter(path, make_metadata(), chunk_samples=1000) as writer:
        writer.append(make_system_chunk(0, 4000, seed=2))
    with h5py.File(path, "r+") as f:  # a NaN in the data and in its overview row
        assert f["overview"].attrs["step"] == RATE  # one overview row per second
        f["columns/pitch"][2500] = np.nan
        f["overview/pitch"][2500 // int(RATE)] = np.nan
    record = open_system_record(path)
    with pytest.raises(InputError, match="row 2501") as caught:
        for _ in record.iter_chunks(["time", "pitch"], rows=1000, thin=["pitch"], step=100):
            pass
    assert caught.value.field == "pitch"
    with pytest.raises(InputError, match="row 2501"):
        for _ in record.iter_chunks(["time", "pitch"], rows=1000, thin=["pitch"], step=1):
            pass
    # rows between the thinned ones are not read, hence not checked (docs/formats.md); a full read finds the NaN
    assert sum(len(c["pitch"]) for c in record.iter_chunks(["time", "pitch"], rows=1000, thin=["pitch"], step=7)) == 572


@pytest.mark.parametrize("rows", [333, 1000, 4096])
def test_system_overview_rows_equal_the_full_columns(tmp_path, rows):
    """Thin reads served by /overview equal every step-th row of the full columns, for any chunking and multiple steps."""
    path = tmp_path / "r.h5"
    with SystemRecordWriter(path, make_metadata(), chunk_samples=700) as writer:
        for start in range(0, 5001, 1237):  # appends that do not line up with chunks or overview rows
            writer.append(make_system_chunk(start, min(1237, 5001 - start), seed=3))
    record = open_system_record(path)
    full = record.read(["pitch", "velocity_east"])
    for step in (100, 300):
        got = list(record.iter_chunks(["time", "pitch", "velocity_east"], rows=rows, thin=["pitch", "velocity_east"], step=step))
        for name in ("pitch", "velocity_east"):
            np.testing.assert_array_equal(np.concatenate([c[name] for c in got]), full[name][::step])
    assert record.verify_derived() == (RATE, 1)


def test_system_overview_changed_after_writing_is_named(tmp_path):
    """A column edited by another tool no longer matches its overview: `check` names the file, row and dataset."""
    import h5py

    path = tmp_path / "edited.h5"
    with SystemRecordWriter(path, make_metadata(), chunk_samples=1000) as writer:
        writer.append(make_system_chunk(0, 4000, seed=2))
    with h5py.File(path, "r+") as f:
        f["columns/roll"][3100] = 0.5
    with pytest.raises(InputError, match="row 3101") as caught:
        open_system_record(path).verify_derived()
    assert caught.value.field == "/overview/roll"
    with h5py.File(path, "r+") as f:  # an overview of the wrong length is not used: the full columns are read
        f["overview/roll"].resize((7,))
    record = open_system_record(path)
    assert record.verify_derived() == (0, 1)
    assert sum(len(c["roll"]) for c in record.iter_chunks(["time", "roll"], rows=1000, thin=["roll"], step=100)) == 40


def test_system_time_grid_changed_after_writing_is_named(tmp_path):
    """A time stamp edited by another tool leaves its grid segment: `check` names the row and /time_grid."""
    import h5py

    path = tmp_path / "edited-time.h5"
    with SystemRecordWriter(path, make_metadata(), chunk_samples=1000) as writer:
        writer.append(make_system_chunk(0, 4000, seed=2))
    with h5py.File(path, "r+") as f:
        f["columns/time"][2345] += 0.5 / RATE  # still increasing, half a step late (not an overview row)
    with pytest.raises(InputError, match="row 2346") as caught:
        open_system_record(path).verify_derived()
    assert caught.value.field == "/time_grid"
