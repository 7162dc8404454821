"""Property-based fuzzing of every reader and writer (issue 14): no traceback, no bad input accepted, nothing left behind.

Each test mutates a valid file of one kind (hypothesis draws the operator and its random choices, derandomized so
that CI sees the same cases every run) and runs the command that consumes it; :mod:`fuzzing` says what counts as a
failure.  ``benchmarks/bench_fuzz.py`` runs the same cases thousands of times with fresh seeds.
"""

from __future__ import annotations

import random

import fuzz_commands as fc
import fuzzing as fz
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

SEEDS = st.integers(0, 2**32 - 1)


def fuzz_settings(examples: int):
    return settings(
        max_examples=examples,
        derandomize=True,
        deadline=None,
        database=None,
        suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
    )


@pytest.fixture(scope="module")
def workspace(fuzz_workspace):
    return fuzz_workspace  # tests/conftest.py: built once per process


def _check(result: fz.Result) -> None:
    assert result.traceback is None, result.describe()
    assert not result.bad_exit, result.describe()
    assert not result.accepted_bad, "bad input accepted: " + result.describe()
    assert not result.left, "files left behind: " + result.describe()


@fuzz_settings(150)
@given(op=st.sampled_from(fz.CSV_OPS), seed=SEEDS)
def test_device_csv_check(workspace, op, seed):
    _check(fz.case_device_csv(workspace, random.Random(seed), op))


@fuzz_settings(30)
@given(op=st.sampled_from(fz.CSV_OPS), seed=SEEDS)
def test_device_csv_calibrate(workspace, op, seed):
    _check(fz.case_device_csv(workspace, random.Random(seed), op, consumer="calibrate"))


@fuzz_settings(100)
@given(op=st.sampled_from(fz.H5_OPS), seed=SEEDS)
def test_device_h5_check(workspace, op, seed):
    _check(fz.case_h5(workspace, random.Random(seed), op, "device"))


@fuzz_settings(100)
@given(op=st.sampled_from(fz.H5_OPS), seed=SEEDS)
def test_system_h5_check(workspace, op, seed):
    _check(fz.case_h5(workspace, random.Random(seed), op, "system"))


@fuzz_settings(150)
@given(op=st.sampled_from(fz.JSON_OPS), seed=SEEDS)
def test_record_check(workspace, op, seed):
    _check(fz.case_record(workspace, random.Random(seed), op, "check"))


@fuzz_settings(60)
@given(op=st.sampled_from(fz.JSON_OPS), seed=SEEDS)
def test_record_filed_in_history(workspace, op, seed):
    _check(fz.case_record(workspace, random.Random(seed), op, "history"))


@fuzz_settings(15)
@given(op=st.sampled_from(fz.JSON_OPS), seed=SEEDS)
def test_record_as_prior_of_calibrate_system(workspace, op, seed):
    _check(fz.case_record(workspace, random.Random(seed), op, "prior"))


@fuzz_settings(200)
@given(op=st.sampled_from(fz.JSON_OPS), seed=SEEDS)
def test_plan(workspace, op, seed):
    _check(fz.case_plan(workspace, random.Random(seed), op))


@fuzz_settings(200)
@given(op=st.sampled_from(fz.TOML_OPS), seed=SEEDS)
def test_procedure(workspace, op, seed):
    _check(fz.case_procedure(workspace, random.Random(seed), op))


@fuzz_settings(100)
@given(op=st.sampled_from(fz.JSON_OPS), seed=SEEDS)
def test_discovery_document(workspace, op, seed):
    _check(fz.case_discovery(workspace, random.Random(seed), op))


@fuzz_settings(40)
@given(op=st.sampled_from(fz.PROTOCOL_OPS), seed=SEEDS)
def test_protocol_replies(op, seed):
    _check(fz.case_protocol(random.Random(seed), op))


@fuzz_settings(300)
@given(
    index=st.integers(0, len(fz.OPTIONS) - 1),
    value=st.one_of(
        st.sampled_from(fz.TRICKY_OPTION_VALUES),
        st.floats(allow_nan=True, allow_infinity=True).map(repr),
        st.integers(-(2**70), 2**70).map(str),
        st.text(max_size=8),
    ),
)
def test_option_values(index, value):
    _check(fz.case_option(index, value))


# --------------------------------------------------------------------------- the commands added since (issue 31)
@pytest.fixture(scope="module")
def command_inputs(workspace):
    return fc.CommandInputs(workspace)


#: Examples per kind of :data:`fuzz_commands.KINDS`: the commands that write a certificate on success (recal, report) fewer.
COMMAND_EXAMPLES = {"recal --estimate": 4, "report --procedure": 8}


@pytest.mark.parametrize("kind", [k[0] for k in fc.KINDS])
def test_newer_commands(command_inputs, kind):
    _, ops, case, _ = next(k for k in fc.KINDS if k[0] == kind)

    @fuzz_settings(COMMAND_EXAMPLES.get(kind, 15))
    @given(op=st.sampled_from(ops), seed=SEEDS)
    def one(op, seed):
        _check(case(command_inputs, random.Random(seed), op))

    one()


@fuzz_settings(40)
@given(index=st.integers(0, len(fc.NUMERIC_OPTIONS) - 1), value=st.sampled_from(fc.NOT_A_NUMBER))
def test_numeric_options_of_newer_commands_refuse_what_is_not_a_finite_number(command_inputs, index, value):
    _check(fc.case_numeric_option(command_inputs, index, value))


def test_what_the_fuzz_found_is_refused(command_inputs, tmp_path):
    """The fuzz's findings on the newer commands (issue 31), each with one message naming the file and field, exit 2."""
    ws = command_inputs.ws
    out = tmp_path / "out"
    out.mkdir()
    # report --procedure: an empty file and an unknown section, refused as `run` refuses them
    for name, text, fragment in (("empty.toml", "", "missing [procedure] table"), ("bogus.toml", "[bogus]\nx = 1\n", "unknown sections")):
        path = tmp_path / name
        path.write_text(command_inputs.procedures["system-static"] + "\n" + text if text else "", encoding="utf-8")
        result = fz.run_cli(["report", str(ws.record), "--procedure", str(path), "--out", str(out / "r.pdf")], name, True, out)
        assert result.status == 2 and str(path) in result.stderr and fragment in result.stderr, result.describe()
    # noise on a system record whose time runs back: the validation check runs
    import h5py

    record = tmp_path / "system.h5"
    record.write_bytes(ws.system_h5.read_bytes())
    with h5py.File(record, "r+") as f:
        time = f["columns/time"][...]
        time[100], time[101] = time[101], time[100]
        f["columns/time"][...] = time
    result = fz.run_cli(["noise", str(record), "--record", str(ws.record), "--out", str(out / "n.json")], "time back", True, out)
    assert result.status == 2 and str(record) in result.stderr and "time" in result.stderr, result.describe()
    # calibrate poses: a converted specific force beyond any accelerometer
    lines = command_inputs.raw_log.read_text(encoding="utf-8").splitlines()
    lines[5000] = ",".join(lines[5000].split(",")[:1] + ["1e300", "0", "0"])
    log = tmp_path / "imu.csv"
    log.write_text("\n".join(lines) + "\n", encoding="utf-8")
    argv = ["calibrate", "poses", str(log), "--columns", "time=t,f_x=ax,f_y=ay,f_z=az", "--units", "m/s2", "--out", str(out / "c.json")]
    result = fz.run_cli(argv, "huge", True, out)
    assert result.status == 2 and "field 'f_x'" in result.stderr and "sample 5000" in result.stderr, result.describe()
    assert not list(out.iterdir())


def test_what_the_benchmark_found_is_refused(command_inputs, tmp_path):
    """bench_fuzz.py --only-newer (seed 31) found these two accepted: a fit's evidence of the wrong type in a record
    (recal --estimate wrote a record with it) and a full-width digit as --zero of calibrate poses."""
    import json

    document = json.loads(command_inputs.estimate.read_text(encoding="utf-8"))
    document["stages"][0]["fits"][0]["parameter_ids"][1] = [1]
    bad = tmp_path / "estimate.json"
    bad.write_text(json.dumps(document), encoding="utf-8")
    result = fz.run_cli(["check", str(bad)], "fits", True)
    assert result.status == 2 and "stages[0].fits[0].parameter_ids" in result.stderr, result.describe()
    out = tmp_path / "out"
    out.mkdir()
    argv = ["calibrate", "poses", str(command_inputs.raw_log), "--columns", "time=t,f_x=ax,f_y=ay,f_z=az", "--units",
            "counts:4096/g", "--zero", "\uff15", "--out", str(out / "c.json")]  # fmt: skip
    result = fz.run_cli(argv, "zero", True, out)
    assert result.status == 2 and "--zero" in result.stderr, result.describe()
