"""The operator console of ``stableins run``: whole step texts, prompts that ask again, one line per dwell of every
stage with its progress and verdict, replay marked as replay, a finished run reported as finished, the certificate's
conformity verdict printed (simulated platforms)."""

from __future__ import annotations

import io
import re
import shutil
import subprocess

import numpy as np
import pytest

from stableins.console import REPLAY_MARK, Console
from stableins.procedures.definition import PROCEDURE_DIRECTORY, load_procedure
from stableins.procedures.journal import scan
from stableins.procedures.plan import PersonStep, Plan
from stableins.procedures.planning import plan_from_definition
from stableins.procedures.rundir import RunFinished
from stableins.procedures.runner import RunStopped
from stableins.runs import RunSetup, resume_run, start_run
from tests.device_world import ExactPlatform, draw_truth
from tests.platform_double import PlatformDouble
from tests.runner_fixtures import CrashAfter, short_plan

HEADER = re.compile(r"command readings \([-0-9., ]+\) deg, settle [0-9.]+ s, dwell [0-9.]+ s")
VERDICT = re.compile(r"^(replay )?\s+(accepted|rejected|left out of this pass's fit): ")
LONG_PROMPT = (
    "The unit is powered, warmed up for at least two hours and the platform is free to move: the transport locks of the "
    "inner and middle gimbals are removed"
)


@pytest.fixture(autouse=True)
def no_fsync(monkeypatch):
    """Durability is tested in test_runner_journal/test_runner_kill; here fsync would only cost time."""
    monkeypatch.setattr("os.fsync", lambda fd: None)


def _final_lines(text: str) -> list[str]:
    """What a terminal shows: each line as its last carriage-return redraw left it."""
    return [line.split("\r")[-1].replace("\x1b[K", "") for line in text.split("\n")]


def _person_plan(prompt: str = LONG_PROMPT) -> Plan:
    plan = short_plan(person=False)
    people = (
        PersonStep(prompt, "confirm", prompt),
        PersonStep("lab_temperature", "enter", "Lab temperature", key="lab_temperature", unit="degC", minimum=-20, maximum=60),
    )
    return Plan(plan.name, plan.level, people + plan.steps, retries=plan.retries, chunk=plan.chunk)


def test_person_steps_show_their_whole_text_wrapped_and_ask_again_after_a_typo(tmp_path, monkeypatch):
    answers = iter(["yse", "", "y", "2O", "200", "21.5"])
    asked = []

    def answer(prompt):
        asked.append(prompt)
        return next(answers)

    monkeypatch.setattr("builtins.input", answer)
    out = io.StringIO()
    console = Console(out=out, width=50)
    outcome = start_run(_person_plan(), tmp_path / "run", driver_spec="double", console=console, driver=PlatformDouble(1))
    assert outcome.runner.inputs == {"lab_temperature": 21.5}  # the typos did not stop the run
    assert len(asked) == 6
    text = out.getvalue()
    lines = text.split("\n")
    assert all(len(line) <= 50 or " " not in line.strip() for line in lines), [line for line in lines if len(line) > 50]
    flat = " ".join(text.split())  # the text as words, whatever the wrapping
    assert flat.count(" ".join(LONG_PROMPT.split())) == 3  # asked three times, every word in order, nothing cut
    assert "'yse' is neither yes nor no: please answer y or n" in flat and flat.count("please answer y or n") == 2
    assert "'2O' is not a number" in flat and "200 degC is out of range" in flat and flat.count("please enter it again") == 2
    assert "(degC, -20 to 60)" in flat  # the entry prompt says its unit and range
    # the shipped procedures' person steps keep their whole text (they were cut at 40 characters)
    plan = plan_from_definition(load_procedure("field-recal-device"))
    confirms = [s for s in plan.steps if isinstance(s, PersonStep) and s.action == "confirm"]
    assert confirms and all(s.name == s.prompt for s in confirms)


def test_a_declined_confirmation_stops_and_closed_input_stops_without_looping(tmp_path, monkeypatch):
    monkeypatch.setattr("builtins.input", lambda prompt: "no")
    with pytest.raises(RunStopped, match="was not confirmed"):
        start_run(_person_plan(), tmp_path / "a", driver_spec="double", console=Console(out=io.StringIO()), driver=PlatformDouble(1))

    def closed(prompt):
        raise EOFError

    monkeypatch.setattr("builtins.input", closed)
    with pytest.raises(RunStopped, match="standard input is closed"):
        start_run(_person_plan(), tmp_path / "b", driver_spec="double", console=Console(out=io.StringIO()), driver=PlatformDouble(1))


def _short_definition(tmp_path, name):
    text = (PROCEDURE_DIRECTORY / f"{name}.toml").read_text()
    path = tmp_path / f"{name}.toml"
    path.write_text(text.replace("dwell = 20.0", "dwell = 2.0").replace("settle = 5.0", "settle = 0.5"))
    return path


class Saturating(ExactPlatform):
    """Saturates the z output at position 5 of every pass (x down, y and z level)."""

    def acquire(self, duration):
        block = super().acquire(duration)
        if np.allclose(self.readings[:2], [np.pi / 2, np.pi / 2], atol=1e-3) and abs(self.readings[2]) < 1e-3:
            block.specific_force[:, 2] = -40.0
        return block


def test_every_dwell_of_every_stage_has_its_line_settle_and_dwell_progress_and_verdict(tmp_path):
    # the coarse stage (dwells taken by the zero-offset iteration) ...
    coarse = _short_definition(tmp_path, "device-coarse")
    out = io.StringIO()
    outcome = start_run(
        plan_from_definition(load_procedure(coarse)),
        tmp_path / "coarse",
        driver_spec="exact",
        console=Console(yes=True, out=out, bars=True),
        driver=Saturating(draw_truth(np.random.default_rng(3)), seed=1),
        setup=RunSetup(definition_file=coarse),
    )
    passes = len(outcome.runner.iteration.history)
    dwells = 18 * passes
    lines = _final_lines(out.getvalue())
    assert sum(bool(HEADER.search(line)) and "pass " in line for line in lines) == dwells
    assert sum(line.startswith("  settle [") for line in lines) == dwells
    assert sum(line.startswith("  dwell [") for line in lines) == dwells
    assert sum(bool(VERDICT.match(line)) for line in lines) == dwells
    assert all("reached within" in line and "samples" in line for line in lines if VERDICT.match(line))
    # a dwell the estimator's checks flag is shown left out, with its reason
    flagged = [line for line in lines if "left out of this pass's fit" in line]
    assert len(flagged) == passes and all("saturated samples" in line for line in flagged)
    # ... and a stage of dwell steps (the fine stage's kind): the same line, the same bars, the same verdict
    out = io.StringIO()
    console = Console(yes=True, out=out, bars=True)
    start_run(short_plan(person=False), tmp_path / "fine", driver_spec="double", console=console, driver=PlatformDouble(2))
    lines = _final_lines(out.getvalue())
    assert sum(bool(HEADER.search(line)) for line in lines) == 6
    assert sum(line.startswith("  settle [") for line in lines) == 6 and sum(line.startswith("  dwell [") for line in lines) == 6
    assert sum(bool(VERDICT.match(line)) for line in lines) == 6
    # no bars where nobody watches (a log): one line per dwell and its verdict all the same
    out = io.StringIO()
    console = Console(yes=True, out=out)
    start_run(short_plan(person=False), tmp_path / "log", driver_spec="double", console=console, driver=PlatformDouble(2))
    assert "[" not in "".join(line for line in out.getvalue().split("\n") if "settle [" in line or "dwell [" in line)
    assert sum(bool(VERDICT.match(line)) for line in out.getvalue().split("\n")) == 6


def test_a_resumed_run_marks_what_it_replays_and_says_where_it_goes_live(tmp_path):
    with pytest.raises(KeyboardInterrupt):
        start_run(short_plan(), tmp_path / "run", driver_spec="double", console=Console(yes=True, quiet=True), driver=CrashAfter(5, 15))
    out = io.StringIO()
    outcome = resume_run(tmp_path / "run", console=Console(yes=True, out=out), driver_factory=lambda start: PlatformDouble(5))
    assert len(outcome.runner.entries) == 6
    lines = out.getvalue().split("\n")
    live = next(k for k, line in enumerate(lines) if "the run is live from here" in line)
    replayed, after = lines[1:live], [line for line in lines[live + 1 :] if line]
    assert replayed and all(line.startswith(f"{REPLAY_MARK} ") for line in replayed)
    assert any("entered before the run was interrupted" in line for line in replayed)  # the journal's answer, not a prompt
    assert any(VERDICT.match(line) for line in replayed) and any(HEADER.search(line) for line in replayed)
    assert after and not any(line.startswith(REPLAY_MARK) for line in after)
    assert any(VERDICT.match(line) for line in after)


def test_resume_of_a_finished_run_changes_nothing(tmp_path):
    start_run(short_plan(), tmp_path / "run", driver_spec="double", console=Console(yes=True, quiet=True), driver=PlatformDouble(3))
    journal = (tmp_path / "run" / "journal.bin").read_bytes()
    device = (tmp_path / "run" / "device.h5").stat().st_mtime_ns
    with pytest.raises(RunFinished, match="is finished") as finished:
        resume_run(tmp_path / "run", console=Console(yes=True, quiet=True), driver_factory=lambda start: pytest.fail("platform opened"))
    assert [p.name for p in finished.value.outputs] == ["device.h5"] and finished.value.completed
    assert (tmp_path / "run" / "journal.bin").read_bytes() == journal
    assert (tmp_path / "run" / "device.h5").stat().st_mtime_ns == device
    # estimating again is explicit, reads the journal alone and appends nothing to it
    again = resume_run(tmp_path / "run", console=Console(yes=True, quiet=True), re_estimate=True)
    assert len(again.runner.entries) == 6 and (tmp_path / "run" / "journal.bin").read_bytes() == journal
    assert [r.kind for r in scan(tmp_path / "run" / "journal.bin").records].count("resume") == 0


def test_run_cli_prints_the_certificates_conformity_and_a_finished_run_is_left_alone(tmp_path, monkeypatch, capsys):
    from stableins import cli

    text = (PROCEDURE_DIRECTORY / "device-coarse.toml").read_text()
    for old, new in (("dwell = 20.0", "dwell = 2.0"), ("settle = 5.0", "settle = 2.0"), ("sample_rate = 100.0", "sample_rate = 20.0")):
        text = text.replace(old, new)
    start, end = text.index("\n[tolerances]\n"), text.index("\n[offset_iteration]\n")  # the shipped limits, replaced by the test's
    text = text[:start] + text[end:]
    text += '\n[tolerances]\ndecision_rule = "simple"\n\n[tolerances.limits]\n"bias_*" = 100000.0\n"sf_*" = 0.001\n'
    (tmp_path / "short-coarse.toml").write_text(text)
    monkeypatch.chdir(tmp_path)
    status = cli.main(["run", "short-coarse.toml", "--driver", "sim", "--seed", "4", "--unit", "C-1", "--out", "r1", "--yes"])
    out, err = capsys.readouterr()
    assert status == 0, err
    # the verdict and the reasons, on the console and in the result, with the certificate's rows
    assert "statement of conformity of the certificate:\n  Verdict: FAIL (3 pass, 3 fail)" in err
    failing = re.findall(r"value (sf_[xyz]): measured \|x\| ([0-9.]+) ppm, U [0-9.]+, limit T 0.001000 ppm: fail", out)
    assert [f[0] for f in failing] == ["sf_x", "sf_y", "sf_z"] and "verdict: FAIL" in out
    if shutil.which("pdftotext"):
        pdf = subprocess.run(["pdftotext", "-layout", "r1/report.pdf", "-"], capture_output=True, text=True, check=True).stdout
        assert "FAIL" in pdf and all(value in pdf for _, value in failing)
    record = (tmp_path / "r1" / "record.json").read_bytes()
    report = (tmp_path / "r1" / "report.pdf").read_bytes()
    # --resume of the finished run: says so, rewrites nothing
    assert cli.main(["run", "--resume", "r1"]) == 0
    out, err = capsys.readouterr()
    assert "is finished" in err and "--re-estimate" in err and out.startswith("finished: r1")
    assert (tmp_path / "r1" / "record.json").read_bytes() == record and (tmp_path / "r1" / "report.pdf").read_bytes() == report
    # --re-estimate: the same estimates from the journal alone, a new record and certificate
    assert cli.main(["run", "--resume", "r1", "--re-estimate", "--json"]) == 0
    out, err = capsys.readouterr()
    import json

    from stableins.records import CalibrationRecord

    document = json.loads(out)
    assert document["verdict"] == "FAIL" and document["replayed_records"] > 0
    assert CalibrationRecord.load(tmp_path / "r1" / "record.json").values() == pytest.approx(_values(record), rel=0, abs=1e-15)
    assert cli.main(["run", "--re-estimate", "short-coarse.toml", "--driver", "sim", "--out", "r2"]) == 2


def _values(document: bytes) -> dict:
    import json

    return {p["id"]: p["value"] for p in json.loads(document)["parameters"]}
