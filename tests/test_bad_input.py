"""Regression tests of issue 14: every class of bad input the attack found, one message naming the file and field, exit 2.

Classes: JSON everywhere it is read; TOML and paths; HDF5 internals and declared sizes; valid but thin data; option
values; the platform link; procedures; two readers, two verdicts; CSV numbers.  (The history store is in
``test_history_store.py``, the fuzz suite in ``test_fuzz.py``.)
"""

from __future__ import annotations

import contextlib
import io
import json
import math
import shutil
import socket
import threading
import time
import tracemalloc
from pathlib import Path

import fuzzing as fz
import h5py
import numpy as np
import pytest

from stableins import cli
from stableins.errors import InputError
from stableins.records import CalibrationRecord

DEEP = "[" * 300 + "]" * 300
HUGE = "9" * 5000


def run(argv: list[str]) -> tuple[int, str]:
    """``stableins ARGV`` in this process: (exit status, stderr); a traceback fails the test."""
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        status = cli.main([str(a) for a in argv])
    assert "Traceback" not in err.getvalue(), err.getvalue()
    return status, err.getvalue()


def refused(argv: list[str], *fragments: str) -> str:
    status, err = run(argv)
    assert status == 2, err
    assert err.startswith("stableins: error: ") or "stableins: error: " in err, err
    for fragment in fragments:
        assert fragment in err, (fragment, err)
    return err


def with_value(text: str, path: tuple, token: str) -> str:
    """The JSON document ``text`` with the value at ``path`` replaced by the literal JSON text ``token``."""
    tree = json.loads(text)
    node = tree
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = "\u0000X\u0000"
    return json.dumps(tree).replace('"\\u0000X\\u0000"', token)


@pytest.fixture(scope="module")
def ws(fuzz_workspace):
    return fuzz_workspace  # tests/conftest.py: built once per process


# =========================================================================== JSON everywhere it is read
RECORD_MUTATIONS = [
    (("notes",), DEEP, "field 'notes", "nested more than 64 levels"),
    (("parameters", 0, "value"), HUGE, "field 'parameters[0].value'", "integer of 5000 digits"),
    (("parameters", 2, "sigma"), '"small"', "field 'parameters[2].sigma'", "not a finite number"),
    (("covariance", "matrix", 1), '{"a": 1}', "field 'covariance.matrix'", "square list"),
    (("site",), "[1, 2]", "field", "not a JSON object"),
    (("stages", 0, "inputs", 0, "sha256"), '"abc"', "field 'stages[0].inputs'", "not a SHA-256"),
    # issue 31: these passed check, diagnose, report and run --prior
    (("serial_number",), '"../../x"', "field 'serial_number'", "cannot name a history folder"),
    (("calibration", "created"), '"yesterday"', "field 'calibration.created'", "as a date"),
    (("stages", 0, "data_end"), '"soon"', "field 'stages[0].data_end'", "as a date"),
]


def _record_consumers(ws: fz.Workspace, bad: Path, tmp: Path) -> list[list]:
    good = ws.record
    (tmp / "store").mkdir(exist_ok=True)
    return [
        ["check", bad],
        ["calibrate", "system", ws.system_h5, "--prior", bad, "--out", tmp / "o1.json"],
        ["diagnose", ws.device_csv, "--record", bad],
        ["simulate", "system", "--installed", bad, "--out", tmp / "sim", "--duration", "60"],
        ["run", "device-fine", "--driver", "sim", "--prior", bad, "--out", tmp / "run", "--yes"],
        ["recal", "--unit", ws.serial, "--prior", good, "--estimate", bad, "--out", tmp / "recal"],
        ["history", ws.serial, "--store", tmp / "store", "--add", bad],
        ["report", bad, "--out", tmp / "r.pdf"],
        ["report", good, "--previous", bad, "--out", tmp / "r2.pdf"],
    ]


@pytest.mark.parametrize(("path", "token", "field", "message"), RECORD_MUTATIONS)
def test_bad_records_are_refused_by_every_command_that_reads_one(ws, tmp_path, path, token, field, message):
    bad = tmp_path / "bad.json"
    bad.write_text(with_value(ws.record.read_text(), path, token))
    for argv in _record_consumers(ws, bad, tmp_path):
        err = refused(argv, str(bad), field)
        assert message in err, (argv, err)
    assert not (tmp_path / "o1.json").exists() and not (tmp_path / "run").exists() and not (tmp_path / "r.pdf").exists()
    assert not list((tmp_path / "store").iterdir())  # nothing filed, no index created


def test_bad_truth_file_plan_discovery_and_history_index(ws, tmp_path):
    from stableins.data.truth import save_truth
    from stableins.simulator.truth import Truth

    truth = tmp_path / "truth.json"
    save_truth(Truth.draw(0), truth)
    bad = tmp_path / "bad-truth.json"
    bad.write_text(with_value(truth.read_text(), ("seed",), HUGE))
    refused(["simulate", "device", "--truth", bad, "--out", tmp_path / "s"], str(bad), "field 'seed'", "5000 digits")

    plan = tmp_path / "plan.json"
    for path, token, field in ((("steps",), DEEP, "steps"), (("retries",), '"2"', "retries"), (("steps", 0, "dwell"), "1e999", "dwell")):
        plan.write_text(with_value(ws.plan.read_text(), path, token))
        refused(["run", plan, "--driver", "sim", "--out", tmp_path / "runplan", "--prior", ws.record], str(plan), field)
    assert not (tmp_path / "runplan").exists()

    discovery = tmp_path / "diag.json"
    for path, token, field in (
        (("candidates", 0, "p_value"), '"small"', "candidates[0].p_value"),
        (("history", 0, "residual_rms", 1), HUGE, "history[0].residual_rms[1]"),
        (("candidates",), DEEP, "candidates"),
    ):
        discovery.write_text(with_value(ws.discovery.read_text(), path, token))
        refused(["report", ws.record, "--discovery", discovery, "--out", tmp_path / "r.pdf"], str(discovery), field)
    assert not (tmp_path / "r.pdf").exists()

    # the index of an old (JSON) history store, read when the store is first used
    store = tmp_path / "store"
    (store / ws.serial).mkdir(parents=True)
    index = store / ws.serial / "index.json"
    for token, field in ((DEEP, "entries"), ('[{"file": 3}]', "entries[0].file")):
        index.write_text('{"format": "stableins-history-index", "entries": ' + token + "}")
        refused(["history", ws.serial, "--store", store], str(index), field)


def test_bad_json_in_data_headers(ws, tmp_path):
    text = ws.device_csv.read_text()
    start, stop = text.index("# BEGIN HEADER\n") + 15, text.index("# END HEADER")
    header = "".join(line[1:] + "\n" for line in text[start:stop].splitlines())
    for path, token, field in (
        (("metadata", "latitude", "value"), HUGE, "header.metadata.latitude.value"),
        (("metadata", "extra"), DEEP, "header.metadata.extra"),
        (("metadata", "gravity"), '"9.8"', "metadata.gravity"),
    ):
        bad = tmp_path / "bad.csv"
        bad.write_text(text[:start] + "# " + with_value(header, path, token) + "\n" + text[stop:])
        refused(["check", bad], str(bad), field)
        refused(["calibrate", "device", bad, "--out", tmp_path / "o.json"], str(bad), field)
        h5 = tmp_path / "bad.h5"
        shutil.copyfile(ws.device_h5, h5)
        with h5py.File(h5, "r+") as f:
            f.attrs["header"] = with_value(f.attrs["header"], path, token)
        refused(["check", h5], str(h5), field)
    assert not (tmp_path / "o.json").exists()


# =========================================================================== TOML and paths
def test_procedure_that_is_not_utf8(ws, tmp_path):
    bad = tmp_path / "latin1.toml"
    bad.write_bytes(ws.procedure.read_bytes().replace(b"Wu et al.", "Wu \u00e9t al.".encode("latin-1")))
    refused(["run", bad, "--driver", "sim", "--out", tmp_path / "run", "--prior", ws.record], str(bad), "not UTF-8")
    refused(["calibrate", "device", ws.device_csv, "--out", tmp_path / "o.json", "--fine-procedure", bad], str(bad), "not UTF-8")
    assert not (tmp_path / "run").exists()


def test_directories_and_files_mixed_up(ws, tmp_path):
    folder = tmp_path / "folder"
    folder.mkdir()
    plain = tmp_path / "plain.txt"
    plain.write_text("x")
    refused(["check", folder], str(folder), "is a directory")
    refused(["check", tmp_path / "folder.h5"], "no such file")
    (tmp_path / "dir.h5").mkdir()
    refused(["check", tmp_path / "dir.h5"], "is a directory")
    refused(["calibrate", "device", ws.device_csv, "--out", folder], "argument --out", "is a directory")
    refused(["report", ws.record, "--out", folder], "is a directory")
    refused(["run", "device-fine", "--driver", "sim", "--out", plain], "argument --out", "is a file, not a directory")
    refused(["simulate", "device", "--out", plain / "sub"], "is a file, not a directory")
    refused(["history", ws.serial, "--store", plain], str(plain), "is a file, not a directory")
    refused(["run", folder, "--driver", "sim", "--out", tmp_path / "r"], str(folder), "is a directory")
    refused(["diagnose", ws.device_csv, "--record", folder], str(folder), "is a directory")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dir.h5", "folder", "plain.txt"]


# =========================================================================== HDF5
def test_corrupt_hdf5_metadata_is_refused_naming_the_file(ws, tmp_path):
    """Damage the internal metadata at many places: every outcome is a refusal naming the file (or a file that still reads)."""
    original = ws.device_h5.read_bytes()
    metadata_end = min(len(original), 8192)
    statuses = []
    for k, start in enumerate(range(64, metadata_end, 97)):
        bad = tmp_path / f"corrupt{k}.h5"
        data = bytearray(original)
        data[start : start + 24] = bytes((b * 37 + 11) % 256 for b in data[start : start + 24])
        bad.write_bytes(bytes(data))
        status, err = run(["check", bad])
        statuses.append(status)
        assert status in (0, 2), err
        if status == 2:
            assert str(bad) in err, err
    assert statuses.count(2) >= len(statuses) // 3


def test_sparse_file_declaring_300_million_rows_fails_fast_in_bounded_memory(ws, tmp_path):
    sparse = tmp_path / "sparse.h5"
    shutil.copyfile(ws.device_h5, sparse)
    with h5py.File(sparse, "r+") as f:
        for name in f["columns"]:
            f["columns"][name].resize((300_000_000,))
        f.attrs["rows"] = 300_000_000
    assert sparse.stat().st_size < 1 << 20
    tracemalloc.start()
    with _elements_read() as read:
        err = refused(["check", sparse], str(sparse), "declares 300000000 rows but stores only")
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    # work and memory bounded by what is stored (a few thousand rows), not by the 300 million declared
    assert read.elements < 1_000_000 and peak < 32 << 20, (read.elements, peak, err)


class _Counter:
    elements = 0


@contextlib.contextmanager
def _elements_read():
    """Count the elements every ``h5py`` dataset read returns (the work of a reader, independent of the machine's load)."""
    counter = _Counter()
    original = h5py.Dataset.__getitem__

    def counted(self, key):
        value = original(self, key)
        counter.elements += int(np.size(value))
        return value

    h5py.Dataset.__getitem__ = counted
    try:
        yield counter
    finally:
        h5py.Dataset.__getitem__ = original


def _bytes_read() -> int:
    """Bytes this process has read so far (Linux ``/proc/self/io`` ``rchar``): the work of a reader, not its time."""
    for line in Path("/proc/self/io").read_text().splitlines():
        if line.startswith("rchar:"):
            return int(line.split()[1])
    raise AssertionError("no rchar in /proc/self/io")


def test_position_stored_as_float_is_refused_like_csv(ws, tmp_path):
    bad = tmp_path / "float-position.h5"
    shutil.copyfile(ws.device_h5, bad)
    with h5py.File(bad, "r+") as f:
        values = f["columns/position"][()].astype(float)
        values[41] = 1.5
        del f["columns/position"]
        f["columns"].create_dataset("position", data=values)
    refused(["check", bad], str(bad), "row 42", "field 'position'", "1.5", "not an integer")
    with h5py.File(bad, "r+") as f:
        values[41] = 3e9  # whole, but beyond int32: would wrap round
        f["columns/position"][...] = values
    refused(["check", bad], "row 42", "field 'position'", "not an integer")


# =========================================================================== valid but thin data
def test_empty_device_file_is_refused_by_check_as_by_calibrate(ws, tmp_path):
    text = ws.device_csv.read_text()
    cut = text.index("\n", text.index("\ntime[s]") + 1) + 1
    empty = tmp_path / "empty.csv"
    empty.write_text(text[:cut] + "# END OF DATA: 0 rows\n")
    message = refused(["check", empty], str(empty), "holds no data rows")
    assert refused(["calibrate", "device", empty, "--out", tmp_path / "o.json"]) == message
    assert refused(["diagnose", empty, "--record", ws.record]) == message
    assert not (tmp_path / "o.json").exists()


@pytest.fixture(scope="module")
def short_dwells(tmp_path_factory):
    """``simulate device --dwell 2 --settle 1``: the session that made diagnose and the fine fit fail."""
    out = tmp_path_factory.mktemp("thin")
    status, err = run(["simulate", "device", "--dwell", "2", "--settle", "1", "--seed", "3", "--out", out / "sim"])
    assert status == 0, err
    return out


def test_two_second_dwells_give_a_flagged_result_not_a_traceback(short_dwells):
    sim = short_dwells / "sim"
    status, err = run(["calibrate", "device", sim / "device-coarse.csv", sim / "device-fine.csv", "--out", short_dwells / "cal.json"])
    assert status == 0 and "fine stage: warning" in err, err  # weakly determined terms, flagged
    status, err = run(["diagnose", sim / "device-coarse.csv", sim / "device-fine.csv", "--record", short_dwells / "cal.json"])
    assert status == 0, err


def test_angle_readings_constant_within_every_dwell(short_dwells):
    from stableins.data.device import load_device, save_device

    sim = short_dwells / "sim"
    names = []
    for name in ("device-coarse.csv", "device-fine.csv"):
        dataset = load_device(sim / name)
        columns = {k: np.array(v) for k, v in dataset.columns.items()}
        for axis in ("platform", "inner", "middle"):
            columns[f"angle_{axis}"] = columns[f"command_{axis}"].copy()  # a quiet sensor: exactly the command
        names.append(save_device(short_dwells / f"quiet-{name}", columns, dataset.metadata))
    status, err = run(["calibrate", "device", *names, "--out", short_dwells / "quiet.json"])
    assert status == 0, err
    status, err = run(["diagnose", *names, "--record", short_dwells / "quiet.json"])
    assert status == 0 and "readings constant within the dwell" in err, err


# =========================================================================== option values
@pytest.mark.parametrize(
    ("argv", "option"),
    [
        (["history", "SN", "--max-age", "1e20"], "--max-age"),
        (["history", "SN", "--max-age", "nan"], "--max-age"),
        (
            ["calibrate", "system", "r.h5", "--prior", "p.json", "--out", "o.json", "--case-rotation-period", "nan"],
            "--case-rotation-period",
        ),
        (
            ["calibrate", "system", "r.h5", "--prior", "p.json", "--out", "o.json", "--case-rotation-period", "-480"],
            "--case-rotation-period",
        ),
        (["calibrate", "system", "r.h5", "--prior", "p.json", "--out", "o.json", "--gyro-drift", "nan", "0", "0"], "--gyro-drift"),
        (["run", "device-fine", "--driver", "sim", "--out", "r", "--timeout", "-1"], "--timeout"),
        (["run", "device-fine", "--driver", "sim", "--out", "r", "--chunk", "1e-300"], "--chunk"),
        (["run", "device-fine", "--driver", "sim", "--out", "r", "--retries", "1e3"], "--retries"),
        (["diagnose", "d.csv", "--record", "r.json", "--alpha", "1"], "--alpha"),
        (["simulate", "device", "--settle", "-1"], "--settle"),
        (["serve-sim", "--port", "70000"], "--port"),
        (["demo", "--seed", "-3"], "--seed"),
    ],
)
def test_option_values_are_checked_when_parsed(tmp_path, monkeypatch, argv, option):
    monkeypatch.chdir(tmp_path)
    err = refused(argv, f"argument {option}", "expected")
    assert "r.h5" not in err and "p.json" not in err  # refused before any file is looked at
    assert list(tmp_path.iterdir()) == []


# =========================================================================== platform link
class _Server:
    """A listening socket whose connections get ``handler(connection)`` (in a thread)."""

    def __init__(self, handler) -> None:
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.port = self.listener.getsockname()[1]
        self.handler = handler
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()

    def _serve(self) -> None:
        with contextlib.suppress(OSError):
            while True:
                connection, _ = self.listener.accept()
                threading.Thread(target=self._one, args=(connection,), daemon=True).start()

    def _one(self, connection) -> None:
        with connection, contextlib.suppress(OSError):
            self.handler(connection)

    def close(self) -> None:
        self.listener.close()


def test_acq_sample_count_is_validated_before_anything_is_allocated():
    from stableins.drivers.errors import DriverProtocolError
    from stableins.drivers.tcp import TcpDriver

    for count in ("1000000000000", "-5", "1.5", "10 samples"):

        def reply(request, verb, arguments, count=count):
            if verb == "META":
                return f"{request} OK {fz._meta_payload()}\n".encode()
            return f"{request} OK {count}\n".encode()

        server = fz.ScriptedPlatform(reply)
        try:
            driver = TcpDriver("127.0.0.1", server.port, timeout=2.0, reconnect_attempts=1)
            tracemalloc.start()
            with pytest.raises(DriverProtocolError, match=r"announced .* samples .*expected a whole number up to 27"):
                driver.acquire(1.0)  # 10 Hz: at most 1.1 × 10 + 16 samples
            assert tracemalloc.get_traced_memory()[1] < 1 << 20
            tracemalloc.stop()
        finally:
            server.close()


def test_a_controller_that_trickles_cannot_hold_a_request():
    from stableins.drivers.errors import DriverConnectionError
    from stableins.drivers.tcp import TcpDriver

    sent = [0]

    def trickle(connection) -> None:
        connection.sendall(b"STABLEINS-PLATFORM 1\n")
        connection.recv(100)
        for byte in b"1 OK " + b"0" * 1000:  # one byte every 0.1 s, never a newline
            connection.sendall(bytes([byte]))
            sent[0] += 1
            time.sleep(0.1)

    server = _Server(trickle)
    try:
        # a silence of 2 s (20 trickle intervals) would need a thread starved that long: the reply's deadline fires first
        driver = TcpDriver("127.0.0.1", server.port, timeout=2.0, reconnect_attempts=1)
        with pytest.raises(DriverConnectionError, match="in time"):  # the deadline of the reply, not the silence timeout
            driver.command((0.0, 0.0, 0.0))
        # bytes the platform got out before the driver gave up: about 20 (2 s at one byte every 0.1 s), a few more while
        # the driver closes under load, never the 1005 a silence timeout would wait for (a byte comes every 0.1 s)
        assert sent[0] < 500, sent
    finally:
        server.close()


def test_resume_hint_only_when_something_can_be_resumed(ws, tmp_path):
    def greet_wrongly(connection) -> None:
        connection.sendall(b"HELLO 2\n")

    server = _Server(greet_wrongly)
    try:
        status, err = run(
            ["run", "device-fine", "--driver", f"tcp://127.0.0.1:{server.port}", "--out", tmp_path / "r", "--prior", ws.record]
        )
    finally:
        server.close()
    assert status == 1 and "is not a stableins platform" in err and "--resume" not in err and "nothing was started" in err
    assert not (tmp_path / "r" / "journal.bin").exists()


def test_samples_whose_time_runs_back_are_refused_before_journaling(tmp_path):
    from platform_double import PlatformDouble
    from runner_fixtures import short_plan

    from stableins.console import Console
    from stableins.procedures.journal import scan
    from stableins.procedures.runner import RunStopped
    from stableins.runs import resume_run, start_run

    class Rewinding(PlatformDouble):
        """Its clock jumps back 100 s once, in the middle of the run (a controller that restarted its clock)."""

        def acquire(self, duration):
            block = super().acquire(duration)
            if 20.0 < self.time < 21.0:
                self.time -= 100.0
            return block

    plan = short_plan(person=False)
    with pytest.raises(RunStopped, match="clock ran back"):
        start_run(plan, tmp_path / "run", driver_spec="double", console=Console(quiet=True), driver=Rewinding(0))
    records = scan(tmp_path / "run" / "journal.bin").records
    last = -math.inf
    for record in records:
        if record.kind == "op" and record["operation"] == "acquire" and not record.get("error"):
            times = record.arrays["time"]
            assert times[0] > last and (np.diff(times) > 0).all()  # nothing that runs back was journaled
            last = times[-1]
    assert any("clock ran back" in (r.get("error") or "") for r in records)
    # not stuck: a platform with a sane clock (a new session, resumed like real hardware) finishes the run
    fixed = PlatformDouble(0)
    fixed.deterministic = False
    fixed.time = last + 1000.0
    outcome = resume_run(tmp_path / "run", console=Console(quiet=True), driver_factory=lambda start: fixed)
    assert outcome.dataset is not None and outcome.dataset.exists()


# =========================================================================== procedures
BASE_PROCEDURE = """
[procedure]
name = "tiny"
stage = "coarse"
[defaults]
settle = 0.5
dwell = 1.0
sample_rate = 100.0
[[step]]
position = 1
platform = 0.0
inner = 0.0
middle = 0.0
[[step]]
position = 2
platform = 0.0
inner = 10.0
middle = 0.0
"""


def test_procedure_validated_completely_before_the_platform_moves(tmp_path):
    from stableins.procedures.definition import load_procedure

    cases = [
        ("[tolerances]\ndecision_rule = 'lenient'\n", "tolerances.decision_rule"),
        ("[acceptance]\nnoise_blocks = 0.5\n", "acceptance.noise_blocks"),
        ("[runner]\nchunk = 1e-300\n", "runner.chunk"),
        ("[[person]]\nbefore = 1\naction = 'enter'\nprompt = 'T'\nkey = 't'\nminimum = 10.0\nmaximum = 30.0\ndefault = 45.0\n", "person"),
    ]
    for extra, field in cases:
        path = tmp_path / "proc.toml"
        path.write_text(BASE_PROCEDURE + extra)
        err = refused(["run", path, "--driver", "sim", "--unit", "X", "--out", tmp_path / "run", "--yes"], str(path), field)
        assert not (tmp_path / "run").exists(), err
    path.write_text(BASE_PROCEDURE + "[[person]]\nbefore = 1\naction = 'enter'\nprompt = 'T'\nkey = 't'\nminimum = 10.0\nmaximum = 30.0\n")
    refused(["run", path, "--driver", "sim", "--out", tmp_path / "run", "--set", "t=45"], "field 't'", "out of range", "10.0 to 30.0")
    assert not (tmp_path / "run").exists()
    assert load_procedure(path).positions == (1, 2)


def test_procedure_steps_and_size_are_bounded_before_work(tmp_path):
    """At most MAX_PROCEDURE_STEPS steps, checked before each is validated; a file over 1 MiB is refused before it is parsed.

    Issue 31: a 64-MiB TOML with a million steps took 31 s and 937 MiB before it was refused.
    """
    from stableins.procedures.definition import MAX_FILE_BYTES, MAX_PROCEDURE_STEPS, load_procedure

    head = '[procedure]\nname = "long"\nstage = "coarse"\n[defaults]\ndwell = 1.0\nsample_rate = 100.0\n'

    def steps(n: int) -> str:
        return "".join(f"[[step]]\nposition = {k}\nplatform = 0.0\ninner = {k % 90}.0\nmiddle = 0.0\n" for k in range(1, n + 1))

    path = tmp_path / "long.toml"
    path.write_text(head + steps(MAX_PROCEDURE_STEPS))
    assert path.stat().st_size < MAX_FILE_BYTES
    assert len(load_procedure(path).steps) == MAX_PROCEDURE_STEPS
    path.write_text(path.read_text().replace("position = 4000\n", "position = 3999\n"))
    with pytest.raises(InputError, match=r"duplicated positions \[3999\]"):
        load_procedure(path)
    path.write_text(head + "[[step]]\nposition = 1\nplatform = 0.0\ninner = 1.0\nmiddle = 0.0\n" * (MAX_PROCEDURE_STEPS + 1))
    with pytest.raises(InputError) as error:
        load_procedure(path)
    assert error.value.field == "step" and f"at most {MAX_PROCEDURE_STEPS}" in str(error.value)
    path.write_text(head + "# padding\n" * (MAX_FILE_BYTES // 10 + 1))
    refused(["run", path, "--driver", "sim", "--out", tmp_path / "run"], str(path))
    assert not (tmp_path / "run").exists()


def test_resume_verifies_every_input_it_reads_again(ws, tmp_path):
    path = tmp_path / "proc.toml"
    path.write_text(BASE_PROCEDURE + "[[person]]\nbefore = 1\naction = 'enter'\nprompt = 'Lab temperature'\nkey = 'lab'\nunit = 'degC'\n")
    status, err = run(["run", path, "--driver", "sim", "--unit", "SIM-1", "--out", tmp_path / "run", "--yes", "--seed", "1"])
    assert status == 3 and "--set lab=VALUE" in err and "continue with: stableins run --resume" in err
    copy = tmp_path / "run" / "procedure.toml"
    started_with = copy.read_bytes()
    copy.write_text(copy.read_text().replace("settle = 0.5", "settle = 0.25"))  # edited after the start
    err = refused(["run", "--resume", tmp_path / "run", "--yes", "--set", "lab=21"], str(copy), "changed since the run started", "sha256")
    import hashlib

    assert hashlib.sha256(started_with).hexdigest() in err
    copy.write_bytes(started_with)
    status, err = run(["run", "--resume", tmp_path / "run", "--yes", "--set", "lab=21"])
    assert status == 0, err


def test_a_specific_force_no_instrument_gives_is_refused_by_check_as_by_calibrate(ws, tmp_path):
    """f_x = 1e300 in 200 rows passed ``check`` and ``calibrate device`` (issue 31): the schema's limits, every reader."""
    lines = ws.device_csv.read_text().splitlines(keepends=True)
    header = next(k for k, line in enumerate(lines) if line.startswith("time[s]"))
    names = [c.split("[")[0] for c in lines[header].strip().split(",")]
    column = names.index("f_x")
    for k in range(header + 11, header + 211):
        cells = lines[k].rstrip("\n").split(",")
        cells[column] = "1e300"
        lines[k] = ",".join(cells) + "\n"
    bad = tmp_path / "huge.csv"
    bad.write_text("".join(lines))
    message = refused(["check", bad], str(bad), "row 11", "field 'f_x'", "beyond what an instrument can give")
    assert refused(["calibrate", "device", bad, "--out", tmp_path / "o.json"]) == message
    assert refused(["diagnose", bad, "--record", ws.record]) == message
    assert not (tmp_path / "o.json").exists()


@pytest.mark.parametrize(
    ("key", "value", "message"), [("serial_number", "../../x", "cannot name a history folder"), ("start_time", "soon", "as a date")]
)
def test_data_file_metadata_serial_and_start_time_are_checked(ws, tmp_path, key, value, message):
    """A data file's serial number names folders and report ids; its start time is a date (issue 31)."""
    text = ws.device_csv.read_text()
    assert '#     "serial_number": "' in text
    entry = f'#     "{key}": {json.dumps(value)},\n'
    bad = tmp_path / "meta.csv"
    if key == "serial_number":
        start = text.index('#     "serial_number": ')
        bad.write_text(text[:start] + entry + text[text.index("\n", start) + 1 :])
    else:
        start = text.index('#     "serial_number": ')
        bad.write_text(text[:start] + entry + text[start:])
    refused(["check", bad], str(bad), f"field 'metadata.{key}'", message)


@pytest.mark.parametrize(
    "extra",
    [["--gyro-drift", "1", "0", "0"], ["--estimate-k2"], ["--case-rotation-period", "600"], ["--thermal-prior", "5", "5"]],
    ids=lambda extra: extra[0],
)
def test_systematic_refuses_the_static_stages_options(ws, tmp_path, extra):
    """Issue 31: with --systematic these were ignored (parameters bit-identical); now one message naming the option."""
    argv = ["calibrate", "system", ws.system_h5, "--prior", ws.record, "--systematic", "--out", tmp_path / "o.json", *extra]
    refused(argv, f"field '{extra[0]}'", "not to --systematic")
    assert not (tmp_path / "o.json").exists()


def test_noise_refuses_another_units_record_and_a_plot_that_is_not_png(ws, tmp_path):
    """Issue 31: ``noise system.h5 --record OTHER-UNIT.json`` wrote a record for the wrong unit with a warning only;
    ``noise --plot a.txt`` wrote PNG bytes to a .txt."""
    document = json.loads(ws.record.read_text())
    document["serial_number"] = "OTHER-UNIT"
    other = tmp_path / "other.json"
    other.write_text(json.dumps(document))
    refused(["noise", ws.system_h5, "--record", other, "--out", tmp_path / "o.json"], str(other), "OTHER-UNIT", "field 'serial_number'")
    refused(["noise", ws.system_h5, "--plot", tmp_path / "a.txt"], "--plot", "ending in .png")
    assert not (tmp_path / "o.json").exists() and not (tmp_path / "a.txt").exists()


def test_recal_names_the_prior_of_another_unit_not_the_estimate(ws, tmp_path):
    """Issue 31: ``recal --prior BAD.json --estimate GOOD.json`` named GOOD.json."""
    document = json.loads(ws.record.read_text())
    document["serial_number"] = "OTHER-UNIT"
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(document))
    err = refused(["recal", "--unit", ws.serial, "--prior", bad, "--estimate", ws.record, "--out", tmp_path / "r"], str(bad))
    assert str(ws.record) not in err and "OTHER-UNIT" in err
    assert not (tmp_path / "r").exists()


@pytest.mark.parametrize("content", [None, b""], ids=["device", "empty"])
def test_check_refuses_what_no_command_writes(tmp_path, content):
    """``check /dev/null`` said "ok (text report; lines 0)" (issue 31): a device file and an empty file are refused."""
    path = Path("/dev/null") if content is None else tmp_path / "empty.txt"
    if content is not None:
        path.write_bytes(content)
    refused(["check", path], str(path), "not a regular file" if content is None else "the file is empty")


# =========================================================================== two readers, two verdicts
@pytest.fixture(scope="module")
def system_files(tmp_path_factory):
    import system_synthetic

    from stableins.data.system import SystemRecordWriter

    tmp = tmp_path_factory.mktemp("two")
    true, installed = system_synthetic.paper_residuals()
    cols, meta = system_synthetic.record(true, installed, rate=1.0, seed=8)
    good = tmp / "good.h5"
    with SystemRecordWriter(good, meta, chunk_samples=4096) as writer:
        writer.append(cols)
    prior = tmp / "prior.json"
    fz._record(meta.serial_number).save(prior)
    return tmp, good, prior, cols, meta


def _agree(tmp: Path, path: Path, prior: Path, *fragments: str) -> None:
    check = refused(["check", path], str(path), *fragments)
    calibrate = refused(["calibrate", "system", path, "--prior", prior, "--out", tmp / "out.json"], str(path), *fragments)
    assert check == calibrate
    drift = refused(["calibrate", "drift", path, "--prior", prior, "--out", tmp / "out.json"], str(path), *fragments)
    assert check == drift  # issue 31: calibrate drift wrote a record from a file check refuses
    assert not (tmp / "out.json").exists()


def test_check_and_calibrate_system_give_one_verdict(system_files):
    import dataclasses

    from stableins.data.system import SystemRecordWriter

    tmp, good, prior, cols, meta = system_files
    assert run(["check", good])[0] == 0 and run(["calibrate", "system", good, "--prior", prior, "--out", tmp / "ok.json"])[0] == 0
    wrong_rate = tmp / "rate.h5"
    with SystemRecordWriter(wrong_rate, dataclasses.replace(meta, sample_rate=2.0), chunk_samples=4096) as writer:
        writer.append(cols)
    _agree(tmp, wrong_rate, prior, "field 'time'", "sample rate is wrong")
    for name, edit, fragments in (
        ("nan.h5", lambda f: f["columns/f_x"].__setitem__(1000, np.nan), ("row 1001", "field 'f_x'", "not finite")),
        ("pitch.h5", lambda f: f["columns/pitch"].__setitem__(700, np.inf), ("row 701", "field 'pitch'", "not finite")),
        ("back.h5", lambda f: f["columns/time"].__setitem__(500, 0.25), ("row 501", "time_grid")),
        ("grid.h5", lambda f: f["time_grid"].__setitem__((0, 2), 1e-12), ("time_grid",)),
        ("grid2.h5", lambda f: f["time_grid"].__setitem__((0, 2), -1.0), ("time_grid", "damaged")),
    ):
        path = tmp / name
        shutil.copyfile(good, path)
        with h5py.File(path, "r+") as f:
            edit(f)
        _agree(tmp, path, prior, *fragments)


def test_the_record_loader_and_the_report_give_one_verdict(ws, tmp_path):
    """Records the attack found accepted by one reader and refused by the other: now refused by every command."""
    text = ws.record.read_text()
    cases = {
        "empty": with_value(text, ("parameters",), "[]"),  # was filed and used as a prior
        "sha": with_value(text, ("stages", 0, "inputs", 0, "sha256"), '"ABCDEF"'),
    }
    for name, document in cases.items():
        path = tmp_path / f"{name}.json"
        path.write_text(document)
        with pytest.raises(InputError):
            CalibrationRecord.load(path)
        refused(["report", path, "--out", tmp_path / "r.pdf"], str(path))
        refused(["history", ws.serial, "--store", tmp_path / "store", "--add", path], str(path))
        refused(["check", path], str(path))
    assert not (tmp_path / "r.pdf").exists()


# =========================================================================== CSV numbers
def test_csv_numbers_are_ascii_decimal(ws, tmp_path):
    lines = ws.device_csv.read_text().splitlines(keepends=True)
    header = next(k for k, line in enumerate(lines) if line.startswith("time[s]"))
    columns = lines[header].rstrip("\n").split(",")
    row = header + 7
    for token in ("1_0", "\uff11.0", "\u0661"):
        fields = lines[row].rstrip("\n").split(",")
        fields[columns.index("f_x[m/s^2]")] = token
        bad = tmp_path / "bad.csv"
        bad.write_text("".join(lines[:row]) + ",".join(fields) + "\n" + "".join(lines[row + 1 :]))
        refused(["check", bad], str(bad), "row 7", "field 'f_x'", "is not a number")
    bom = tmp_path / "bom.csv"
    bom.write_bytes(b"\xef\xbb\xbf" + ws.device_csv.read_bytes())
    assert run(["check", bom])[0] == 0  # a spreadsheet's byte-order mark is accepted


def test_a_line_without_newline_costs_bounded_memory_and_time(ws, tmp_path):
    from stableins.data.csvformat import MAX_LINE

    long = tmp_path / "long.csv"
    with open(long, "wb") as handle:
        handle.write(ws.device_csv.read_bytes())
        handle.write(b"1" * (32 << 20))  # 32 MB, no newline (the benchmark goes to 256 MB)
    tracemalloc.start()
    before = _bytes_read()
    refused(["check", long], str(long), "longer than")
    read = _bytes_read() - before
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    # refused after reading what comes before the error (the valid rows and one line's limit), not the 32 MB
    assert read < len(ws.device_csv.read_bytes()) + 4 * MAX_LINE + (1 << 20) and peak < 16 * MAX_LINE, (read, peak)


def test_an_entry_out_of_range_is_asked_again_not_fatal(tmp_path, monkeypatch):
    from platform_double import PlatformDouble
    from runner_fixtures import short_plan

    from stableins.console import Console
    from stableins.runs import start_run

    answers = iter(["y", "200", "warm", "19.25"])  # the range is -20 .. 60 degC
    monkeypatch.setattr("builtins.input", lambda prompt: next(answers))
    out = io.StringIO()
    outcome = start_run(short_plan(), tmp_path / "run", driver_spec="double", console=Console(out=out), driver=PlatformDouble(0))
    assert outcome.runner.inputs == {"lab_temperature": 19.25}
    assert out.getvalue().count("please enter it again") == 2


def test_an_injected_effect_beyond_the_model_is_refused_and_leaves_nothing(tmp_path):
    err = refused(["simulate", "device", "--hidden", "K3_x=1e300", "--out", tmp_path / "sim"], "effects.K3_x", "nominal size")
    assert "Traceback" not in err and not (tmp_path / "sim").exists()


def test_a_file_of_another_kind_is_named_by_its_content_not_its_size(tmp_path, capsys):
    """calibrate system cal.json --prior system.h5: "this is an HDF5 data file, not a calibration record", not its size."""
    from stableins.records import CalibrationRecord

    h5 = tmp_path / "system.h5"
    h5.write_bytes(b"\x89HDF\r\n\x1a\n" + bytes(70 << 20))  # larger than any record may be
    with pytest.raises(InputError, match=r"this is an HDF5 data file, not a calibration record .*\(arguments swapped\?\)") as error:
        CalibrationRecord.load(h5)
    assert "bytes" not in str(error.value)
    pdf = tmp_path / "report.pdf"
    pdf.write_bytes(b"%PDF-1.4\n%%EOF\n")
    with pytest.raises(InputError, match="this is a PDF document, not"):
        CalibrationRecord.load(pdf)
