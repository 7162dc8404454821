"""Property-based fuzzing of every reader and writer (issue 14): no traceback, no bad input accepted, nothing left behind.

Each test mutates a valid file of one kind (hypothesis draws the operator and its random choices, derandomized so
that CI sees the same cases every run) and runs the command that consumes it; :mod:`fuzzing` says what counts as a
failure.  ``benchmarks/bench_fuzz.py`` runs the same cases thousands of times with fresh seeds.
"""

from __future__ import annotations

import random

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
def workspace(tmp_path_factory):
    return fz.Workspace(tmp_path_factory.mktemp("fuzz"))


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
