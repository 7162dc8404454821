"""The runner: steps, acceptance checks, retries, prompts, resume, exactly-once (on the platform double)."""

from __future__ import annotations

import io

import numpy as np
import pytest

from stableins.console import Console
from stableins.procedures.entries import journal_columns
from stableins.procedures.journal import scan
from stableins.procedures.runner import RunStopped
from stableins.procedures.verdict import evaluate_dwell
from stableins.runs import resume_run, start_run
from stableins.samples import SampleBlock
from tests.platform_double import PlatformDouble
from tests.runner_fixtures import LOOSE, CrashAfter, short_plan


def _run(tmp_path, seed=4, plan=None, driver=None, name="run", **console):
    out = io.StringIO()
    outcome = start_run(
        plan or short_plan(),
        tmp_path / name,
        driver_spec="double",
        seed=seed,
        console=Console(yes=True, out=out, **console),
        driver=driver or PlatformDouble(seed),
    )
    return outcome, out.getvalue()


def test_a_run_accepts_every_position_and_says_why(tmp_path):
    outcome, text = _run(tmp_path)
    columns = journal_columns(scan(tmp_path / "run" / "journal.bin").records)
    assert list(np.unique(columns["position"])) == [1, 2, 3, 4, 5, 6]
    assert len(columns["time"]) == 6 * 40  # 2 s at 20 Hz each; settling not included
    assert np.all(columns["time_since_command"] >= 0.5)  # after the settle
    assert "test position" in text and "accepted" in text and "confirmed (--yes)" in text
    assert outcome.runner.inputs == {"lab_temperature": 21.5}


def test_same_seed_same_samples(tmp_path):
    _run(tmp_path, seed=9, name="a")
    _run(tmp_path, seed=9, name="b")
    a = journal_columns(scan(tmp_path / "a" / "journal.bin").records)
    b = journal_columns(scan(tmp_path / "b" / "journal.bin").records)
    for name in a:
        np.testing.assert_array_equal(a[name], b[name])


def test_checks():
    rng = np.random.default_rng(0)
    t = np.arange(40) / 20.0
    still = rng.normal(0, 1e-4, (40, 3)) + [0, 0, -9.8]
    angles = np.zeros((40, 3))
    command = np.zeros(3)
    block = SampleBlock(t, still, angles, np.full(40, 25.0))
    assert evaluate_dwell(command, block, LOOSE, 2.0, 20.0).accepted
    off = evaluate_dwell(command + [0, 1e-3, 0], block, LOOSE, 2.0, 20.0)
    assert not off.accepted and "not at the commanded angles" in off.reasons[0]
    creeping = SampleBlock(t, still + 1e-3 * t[:, None], angles, np.full(40, 25.0))
    assert any("slope" in r for r in evaluate_dwell(command, creeping, LOOSE, 2.0, 20.0).reasons)
    shaking = SampleBlock(t, still + rng.normal(0, 1e-2, (40, 3)), angles, np.full(40, 25.0))
    assert any("scatter" in r for r in evaluate_dwell(command, shaking, LOOSE, 2.0, 20.0).reasons)
    gappy = SampleBlock(t[:30], still[:30], angles[:30], np.full(30, 25.0))
    assert any("gaps" in r for r in evaluate_dwell(command, gappy, LOOSE, 2.0, 20.0).reasons)
    broken = SampleBlock(t, np.where(t[:, None] > 1, np.nan, still), angles, np.full(40, 25.0))
    assert not evaluate_dwell(command, broken, LOOSE, 2.0, 20.0).accepted
    # the angle check wraps: -pi and +pi are the same place
    wrapped = SampleBlock(t, still, np.tile([np.pi - 1e-7, 0, 0], (40, 1)), np.full(40, 25.0))
    assert evaluate_dwell(np.array([-np.pi, 0, 0]), wrapped, LOOSE, 2.0, 20.0).accepted


class ShakyDouble(PlatformDouble):
    """Creeps (output ramps at 5e-3 m/s² per s) after each of the first ``bad_commands`` commands of one position."""

    def __init__(self, seed, bad_commands, position=(0.0, 0.0, 0.0)):
        super().__init__(seed)
        self.bad_commands = bad_commands
        self.position = np.asarray(position)
        self.creeping_since = None

    def command(self, readings):
        t = super().command(readings)
        self.creeping_since = None
        if self.bad_commands > 0 and np.allclose(readings, self.position):
            self.bad_commands -= 1
            self.creeping_since = self.time
        return t

    def acquire(self, duration):
        block = super().acquire(duration)
        if self.creeping_since is not None:
            block.specific_force[:] += 5e-3 * (block.time - self.creeping_since)[:, None]
        return block


def test_rejected_step_is_repeated_with_the_reason(tmp_path):
    # position 1 creeps after its first command: rejected once, accepted at the next attempt
    outcome, text = _run(tmp_path, driver=ShakyDouble(3, bad_commands=1), plan=short_plan(person=False))
    assert "rejected: not still: slope" in text and "(attempt 2)" in text
    verdicts = [r for r in scan(tmp_path / "run" / "journal.bin").records if r.kind == "verdict"]
    assert [v["accepted"] for v in verdicts[:2]] == [False, True]
    columns = journal_columns(scan(tmp_path / "run" / "journal.bin").records)
    assert np.sum(columns["position"] == 1) == 40  # only the accepted attempt is in the data


def test_stop_after_retries_then_resume_with_fresh_retries(tmp_path):
    plan = short_plan(retries=1, person=False)
    out = io.StringIO()
    with pytest.raises(RunStopped, match="rejected 2 times \\(retries = 1\\); last reason: not still"):
        start_run(
            plan,
            tmp_path / "run",
            driver_spec="double",
            seed=1,
            console=Console(yes=True, out=out),
            driver=ShakyDouble(1, bad_commands=10**6),
        )
    # the fault is fixed; resume: the journal replays the two rejections and the stop, then tries again
    # (a repaired platform is a different platform: it is resumed like real hardware, not re-simulated)
    repaired = ShakyDouble(1, bad_commands=1)
    repaired.deterministic = False
    outcome = resume_run(tmp_path / "run", console=Console(yes=True, out=out), driver_factory=lambda start: repaired)
    assert "fresh retries" in out.getvalue()
    records = scan(tmp_path / "run" / "journal.bin").records
    assert [r.kind for r in records].count("stop") == 1
    assert len(outcome.runner.entries) == 6


def test_prompts_without_yes(tmp_path, monkeypatch):
    answers = iter(["y", "19.25"])
    monkeypatch.setattr("builtins.input", lambda prompt: next(answers))
    outcome = start_run(short_plan(), tmp_path / "run", driver_spec="double", console=Console(quiet=True), driver=PlatformDouble(0))
    assert outcome.runner.inputs == {"lab_temperature": 19.25}
    # estimated again from the journal, nobody is asked again: the answers come from the journal
    monkeypatch.setattr("builtins.input", lambda prompt: pytest.fail("asked twice"))
    again = resume_run(tmp_path / "run", console=Console(quiet=True), re_estimate=True)
    assert again.runner.inputs == {"lab_temperature": 19.25}


def test_refused_confirmation_and_unattended_entry_without_default(tmp_path, monkeypatch):
    monkeypatch.setattr("builtins.input", lambda prompt: "n")
    with pytest.raises(RunStopped, match="not confirmed"):
        start_run(short_plan(), tmp_path / "a", driver_spec="double", console=Console(quiet=True), driver=PlatformDouble(0))
    from dataclasses import replace

    plan = short_plan()
    plan = replace(plan, steps=(plan.steps[0], replace(plan.steps[1], default=None)) + plan.steps[2:])
    with pytest.raises(RunStopped, match="--set lab_temperature=VALUE"):
        start_run(plan, tmp_path / "b", driver_spec="double", console=Console(yes=True, quiet=True), driver=PlatformDouble(0))
    outcome = start_run(
        plan,
        tmp_path / "c",
        driver_spec="double",
        console=Console(yes=True, quiet=True, values={"lab_temperature": "23"}),
        driver=PlatformDouble(0),
    )
    assert outcome.runner.inputs == {"lab_temperature": 23.0}


def test_a_run_directory_is_never_reused(tmp_path):
    from stableins.errors import InputError

    _run(tmp_path)
    before = (tmp_path / "run" / "journal.bin").read_bytes()
    with pytest.raises(InputError, match="already holds a run"):
        _run(tmp_path)
    assert (tmp_path / "run" / "journal.bin").read_bytes() == before


def test_a_start_that_died_before_its_first_record_can_start_again(tmp_path):
    from stableins.procedures.journal import FILE_MAGIC

    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "journal.bin").write_bytes(FILE_MAGIC)
    outcome, _ = _run(tmp_path)
    assert len(outcome.runner.entries) == 6


@pytest.mark.parametrize("cut", [1, 37, 300])
def test_a_torn_last_record_is_dropped_and_redone(tmp_path, cut):
    reference, _ = _run(tmp_path, seed=6, name="ref")
    with pytest.raises(KeyboardInterrupt):
        _run(tmp_path, seed=6, name="run", driver=CrashAfter(6, 17))
    journal = tmp_path / "run" / "journal.bin"
    last = scan(journal).records[-1]
    with open(journal, "r+b") as handle:  # the crash hit in the middle of writing the last record
        handle.truncate(max(last.offset + 1, journal.stat().st_size - cut))
    out = io.StringIO()
    again = resume_run(tmp_path / "run", console=Console(yes=True, out=out), driver_factory=lambda start: PlatformDouble(6))
    assert "dropped a torn last record" in out.getvalue()
    a = journal_columns(scan(tmp_path / "ref" / "journal.bin").records)
    b = journal_columns(scan(journal).records)
    for name in a:
        np.testing.assert_array_equal(a[name], b[name])
    assert len(again.runner.entries) == len(reference.runner.entries) == 6
