"""Procedure files: the shipped definitions, the runner's sections, bad files (message names file and field, exit 2)."""

from __future__ import annotations

import math

import pytest
from inprocess import run_cli

from stableins.errors import InputError
from stableins.procedures.definition import PROCEDURE_DIRECTORY, load_procedure
from stableins.procedures.plan import DwellStep, OffsetIterationStep, PersonStep, StaticRecordStep
from stableins.procedures.planning import plan_from_definition

SHIPPED = sorted(p.stem for p in PROCEDURE_DIRECTORY.glob("*.toml"))

MINIMAL_FINE = """
[procedure]
name = "tiny"
stage = "fine"
[defaults]
settle = 1.0
dwell = 2.0
sample_rate = 50.0
[[step]]
position = 1
platform = 0.0
inner = 0.0
middle = 0.0
[[step]]
position = 2
platform = 0.0
inner = 90.0
middle = 0.0
"""


def test_every_shipped_definition_loads_and_plans():
    assert {"device-coarse", "device-fine", "system-static", "field-recal-device"} <= set(SHIPPED)
    for name in SHIPPED:
        plan = plan_from_definition(load_procedure(name))
        assert plan.steps and plan.sample_rate


def test_runner_section_units_and_person_placement(tmp_path):
    path = tmp_path / "p.toml"
    path.write_text(
        MINIMAL_FINE
        + """
[runner]
retries = 4
chunk = 5.0
angle_tolerance = 10.0
scatter_max = 300.0
slope_max = 2.0
max_slew = 30.0
[[person]]
before = 2
action = "enter"
prompt = "Temperature now"
key = "t_mid"
unit = "degC"
minimum = 0.0
maximum = 50.0
[[person]]
before = 0
action = "confirm"
prompt = "Ready?"
[[person]]
before = 3
action = "confirm"
prompt = "Done, power down"
"""
    )
    plan = plan_from_definition(load_procedure(path))
    kinds = [type(s).__name__ for s in plan.steps]
    assert kinds == ["PersonStep", "DwellStep", "PersonStep", "DwellStep", "PersonStep"]
    assert [s.prompt for s in plan.steps if isinstance(s, PersonStep)] == ["Ready?", "Temperature now", "Done, power down"]
    dwell = plan.steps[1]
    assert isinstance(dwell, DwellStep) and dwell.offset_corrected is False
    assert dwell.checks.angle_tolerance == pytest.approx(math.radians(10 / 3600))
    assert dwell.checks.scatter_max == pytest.approx(300e-6 * 9.80665)
    assert dwell.checks.slope_max == pytest.approx(2e-6 * 9.80665)
    assert dwell.checks.max_slew == 30.0
    assert (plan.retries, plan.chunk, plan.sample_rate) == (4, 5.0, 50.0)
    assert plan_from_definition(load_procedure(path), retries=0, chunk=1.0).retries == 0


def test_coarse_and_system_plans():
    coarse = plan_from_definition(load_procedure("device-coarse"))
    assert isinstance(coarse.steps[0], OffsetIterationStep) and len(coarse.steps[0].positions) == 18
    system = plan_from_definition(load_procedure("system-static"))
    record = [s for s in system.steps if isinstance(s, StaticRecordStep)]
    assert len(record) == 1 and record[0].duration == 86400.0 and system.level == "system"


BAD = [
    ("[nonsense]\nx = 1\n", "unknown sections", None),
    ("[runner]\nspeed = 3\n", "unknown keys", "runner"),
    ("[runner]\nretries = 1.5\n", "whole number", "runner.retries"),
    ("[runner]\nangle_tolerance = -1.0\n", "must be positive", "angle_tolerance"),
    ("[runner]\nchunk = 'ten'\n", "not a finite number", "chunk"),
    ('[[person]]\nbefore = 1\naction = "dance"\nprompt = "x"\n', "action 'dance'", "person.action"),
    ('[[person]]\nbefore = 1\naction = "confirm"\n', "missing", "person.prompt"),
    ('[[person]]\nbefore = 1\naction = "enter"\nprompt = "T"\n', "names its value", "person.key"),
    ('[[person]]\nbefore = 9\naction = "confirm"\nprompt = "x"\n', "before = 9", "person.before"),
    (
        '[[person]]\nbefore = 1\naction = "enter"\nprompt = "T"\nkey = "t"\nminimum = 5.0\nmaximum = 1.0\n',
        "minimum above maximum",
        "person.minimum",
    ),
    ("[record]\nduration = 10.0\nsample_rate = 10.0\n", "belongs to system-level", "record"),
]


@pytest.mark.parametrize(("extra", "message", "field"), BAD)
def test_bad_runner_sections(tmp_path, extra, message, field):
    path = tmp_path / "bad.toml"
    path.write_text(MINIMAL_FINE + extra)
    with pytest.raises(InputError, match=message) as caught:
        load_procedure(path)
    assert caught.value.path == str(path)
    if field:
        assert field in (caught.value.field or "")


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ('[procedure]\nname = "s"\nstage = "system"\n', "needs a \\[record\\] table"),
        ('[procedure]\nname = "s"\nstage = "system"\n[record]\nduration = 5.0\n', "missing \\['sample_rate'\\]"),
        ('[procedure]\nname = "s"\nstage = "system"\n[record]\nduration = 5.0\nsample_rate = 10.0\ninner = 3000.0\n', "not a gimbal angle"),
        ('[procedure]\nname = "s"\nstage = "daily"\n', "unknown stage 'daily'"),
        ('[procedure\nname = "s"\n', "not valid TOML"),
    ],
)
def test_bad_system_and_syntax(tmp_path, text, message):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(InputError, match=message):
        load_procedure(path)


def test_cli_bad_procedure_is_exit_2_with_the_file_and_no_run(tmp_path):
    path = tmp_path / "bad.toml"
    path.write_text(MINIMAL_FINE + '[[person]]\nbefore = 1\naction = "dance"\nprompt = "x"\n')
    result = run_cli(["run", str(path), "--driver", "sim", "--out", str(tmp_path / "run"), "--yes"])
    assert result.returncode == 2
    assert "Traceback" not in result.stderr
    assert str(path) in result.stderr and "person.action" in result.stderr
    assert not (tmp_path / "run" / "journal.bin").exists()
    plan = tmp_path / "plan.json"
    plan.write_text('{"name": "x"}')
    result = run_cli(["run", str(plan), "--driver", "sim", "--out", str(tmp_path / "run2")])
    assert result.returncode == 2 and "missing key 'level'" in result.stderr and "Traceback" not in result.stderr
    result = run_cli(["run", "device-fine", "--out", str(tmp_path / "run3")])
    assert result.returncode == 2 and "--driver" in result.stderr
    result = run_cli(["run", "--resume", str(tmp_path / "nothing-here")])
    assert result.returncode == 2 and "no run journal" in result.stderr


def test_fine_stage_without_a_prior_is_refused_before_anything_runs(tmp_path):
    path = tmp_path / "p.toml"
    path.write_text(MINIMAL_FINE)
    result = run_cli(["run", str(path), "--driver", "sim", "--out", str(tmp_path / "run"), "--yes"])
    assert result.returncode == 2 and "--prior" in result.stderr
    assert not (tmp_path / "run" / "journal.bin").exists()


def test_a_stopped_run_says_how_to_resume(tmp_path):
    path = tmp_path / "p.toml"
    path.write_text(MINIMAL_FINE.replace('"fine"', '"coarse"') + "[runner]\nretries = 0\nscatter_max = 1.0\n")  # 1 µg: noise fails it
    result = run_cli(["run", str(path), "--driver", "sim", "--seed", "1", "--out", str(tmp_path / "run"), "--yes"])
    assert result.returncode == 3, result.stderr
    assert "rejected 1 times (retries = 0)" in result.stderr and f"stableins run --resume {tmp_path / 'run'}" in result.stderr
    assert "Traceback" not in result.stderr
