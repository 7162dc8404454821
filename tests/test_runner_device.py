"""The runner on the device-level procedures: zero-offset iteration through the journal, fine stage on the prior, resume."""

from __future__ import annotations

import io

import numpy as np
import pytest

from stableins.console import Console
from stableins.data.device import load_device
from stableins.estimators.setting import DeviceSetting
from stableins.procedures.definition import PROCEDURE_DIRECTORY, load_procedure
from stableins.procedures.entries import journal_columns
from stableins.procedures.journal import scan
from stableins.procedures.planning import plan_from_definition
from stableins.records import CalibrationRecord
from stableins.runs import RunSetup, resume_run, start_run
from tests.device_world import ExactPlatform, draw_truth


def short_definition(tmp_path, name, settle=0.5):
    text = (PROCEDURE_DIRECTORY / f"{name}.toml").read_text()
    text = text.replace("dwell = 20.0", "dwell = 2.0").replace("settle = 5.0", f"settle = {settle}")
    path = tmp_path / f"{name}-short.toml"
    path.write_text(text)
    return path


class Crash(Exception):
    pass


class CrashingPlatform(ExactPlatform):
    """Raises (as a crash would stop the process) after ``limit`` operations."""

    def __init__(self, *args, limit=10**9, **kwargs):
        super().__init__(*args, **kwargs)
        self.limit = limit
        self.calls = 0
        self.deterministic = True

    def _tick(self):
        self.calls += 1
        if self.calls > self.limit:
            raise Crash("power lost")

    def command(self, readings):
        self._tick()
        return super().command(readings)

    def acquire(self, duration):
        self._tick()
        return super().acquire(duration)


@pytest.fixture(autouse=True)
def no_fsync(monkeypatch):
    """Durability is tested in test_runner_journal/test_runner_kill; here fsync (~5 ms each) would only cost time."""
    monkeypatch.setattr("os.fsync", lambda fd: None)


@pytest.fixture(scope="module")
def truth():
    return draw_truth(np.random.default_rng(7), offset_scale=1.0)


def test_coarse_iteration_then_fine_on_the_prior(tmp_path, truth):
    coarse_file = short_definition(tmp_path, "device-coarse")
    definition = load_procedure(coarse_file)
    plan = plan_from_definition(definition)
    out = io.StringIO()
    coarse = start_run(
        plan,
        tmp_path / "coarse",
        driver_spec="exact",
        console=Console(yes=True, out=out),
        driver=CrashingPlatform(truth, seed=1),
        setup=RunSetup(definition_file=coarse_file),
    )
    text = out.getvalue()
    assert "zero-offset iteration" in text and "converged after" in text
    record = CalibrationRecord.load(coarse.record)
    passes = coarse.runner.iteration.history
    # the gimbals were re-pointed by the last pass's estimate; the record carries the joint fit of all passes
    iteration = coarse.runner.iteration
    assert iteration.offsets[1] == pytest.approx(iteration.last["theta20"][0])
    assert record["theta20"].value == pytest.approx(iteration.fit["theta20"][0])
    for gimbal in ("theta20", "theta30"):
        assert abs(record[gimbal].value - truth[gimbal]) < 5 * record[gimbal].sigma
    data = load_device(coarse.dataset)
    assert len(data.dwells()) == 18 * len(passes)
    for dwell in data.dwells():  # the dwells proper: after arrival and settling, whole, still
        assert dwell.time_since_command[0] >= 0.5 and len(dwell) == 200
        assert np.ptp(dwell.angles, axis=0).max() < definition.checks.max_angle_span
    assert {d.pass_number for d in data.dwells()} == set(range(1, len(passes) + 1))
    # the journal alone gives the same data set (exactly once, in order)
    from_journal = journal_columns(scan(tmp_path / "coarse" / "journal.bin").records)
    np.testing.assert_array_equal(from_journal["f_x"], data.columns["f_x"])
    np.testing.assert_array_equal(from_journal["position"], data.columns["position"])

    fine_file = short_definition(tmp_path, "device-fine")
    fine_plan = plan_from_definition(load_procedure(fine_file))
    fine = start_run(
        fine_plan,
        tmp_path / "fine",
        driver_spec="exact",
        console=Console(yes=True, quiet=True),
        driver=CrashingPlatform(truth, seed=2),
        setup=RunSetup(definition_file=fine_file, prior_file=coarse.record),
    )
    final = CalibrationRecord.load(fine.record)
    assert "fine" in final.provenance.stages and "coarse" in final.provenance.stages
    # the fine dwells were commanded re-pointed by the coarse offsets: r = r_nominal - theta_hat
    fine_data = load_device(fine.dataset)
    first = fine_data.dwells()[0]
    nominal = fine_plan.steps[0].readings
    np.testing.assert_allclose(first.command[1:], np.array(nominal[1:]) - [record["theta20"].value, record["theta30"].value], atol=1e-12)


def test_crash_inside_the_iteration_resumes_to_the_same_result(tmp_path, truth):
    coarse_file = short_definition(tmp_path, "device-coarse")
    plan = plan_from_definition(load_procedure(coarse_file))
    reference = start_run(
        plan,
        tmp_path / "ref",
        driver_spec="exact",
        console=Console(yes=True, quiet=True),
        driver=CrashingPlatform(truth, seed=3),
        setup=RunSetup(definition_file=coarse_file),
    )
    with pytest.raises(Crash):
        start_run(
            plan,
            tmp_path / "run",
            driver_spec="exact",
            console=Console(yes=True, quiet=True),
            driver=CrashingPlatform(truth, seed=3, limit=50),
            setup=RunSetup(definition_file=coarse_file),
        )
    again = resume_run(
        tmp_path / "run", console=Console(yes=True, quiet=True), driver_factory=lambda start: CrashingPlatform(truth, seed=3)
    )
    assert again.replayed >= 49
    a = load_device(reference.dataset).columns
    b = load_device(again.dataset).columns
    for name in a:
        np.testing.assert_array_equal(a[name], b[name])
    ra, rb = CalibrationRecord.load(reference.record), CalibrationRecord.load(again.record)
    assert ra.values() == rb.values()


def test_exported_dwells_are_what_the_iteration_estimated_on_the_simulator(tmp_path):
    from stableins.estimators.coarse import calibrate_coarse
    from stableins.estimators.dwell import dwells_from_columns

    coarse_file = short_definition(tmp_path, "device-coarse", settle=5.0)  # the simulator's gimbals ring ~2 s after a slew
    definition = load_procedure(coarse_file)
    outcome = start_run(
        plan_from_definition(definition),
        tmp_path / "run",
        driver_spec="sim",
        seed=9,
        unit="SIM-9",
        console=Console(yes=True, quiet=True),
        setup=RunSetup(definition_file=coarse_file),
    )
    data = load_device(outcome.dataset)
    last = len(outcome.runner.iteration.history)
    for dwell in data.dwells():  # after arrival (slews of up to 180° at 10°/s) and the 5 s settle
        assert dwell.time_since_command[0] >= 5.0 and len(dwell) == 200
        assert np.ptp(dwell.angles, axis=0).max() < definition.checks.max_angle_span
    assert max(d.time_since_command[0] for d in data.dwells()) > 5.0
    # re-estimating the last pass from the exported file gives the iteration's own fit of that pass
    site = data.metadata
    columns = {k: np.asarray(v) for k, v in data.columns.items()}
    # (with the settle cut 'stableins calibrate device' applies: every exported sample is after settling)
    settle = definition.steps[0].settle
    setting = DeviceSetting.from_site(site)  # as calibrate device summarizes (the measured turn out of the noise)
    dwells = [d for d in dwells_from_columns(columns, settle=settle, checks=definition.checks, setting=setting) if d.pass_number == last]
    fit = calibrate_coarse(
        dwells,
        setting=DeviceSetting.from_site(site),
        expected_positions=definition.positions,
        orientation_tolerance=definition.checks.orientation_tolerance,
        nonlinear=True,  # as the iteration does
    )
    np.testing.assert_allclose(fit.values, outcome.runner.iteration.last.values, rtol=0, atol=1e-12)
