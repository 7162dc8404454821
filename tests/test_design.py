"""Design of a device-level procedure: the bound against the estimator, the null space, optimization, the TOML written."""

from __future__ import annotations

import math

import numpy as np
import pytest

from stableins.cli import main
from stableins.conventions import STANDARD_GRAVITY
from stableins.errors import InputError
from stableins.estimators.experiment import (
    Criterion,
    DevicePlan,
    PlannedStage,
    expected_precision,
    optimize_dwells,
    scaled_criterion,
    slew_time,
)
from stableins.estimators.setting import DeviceSetting
from stableins.noise import NoiseModel
from stableins.procedures.definition import load_procedure
from stableins.procedures.designed import device_plan, write_procedure

QUARTZ = NoiseModel.given(4.5e-4, 2e-6 * STANDARD_GRAVITY, 1e-7, 1e-5)
WHITE = NoiseModel.given(4.5e-4)
SETTING = DeviceSetting(STANDARD_GRAVITY)


def test_slew_time_is_the_simulated_platforms():
    # cosine rate profile with a 10°/s peak: 180° take π/2 · 18 s
    assert slew_time((0, 0, 0), (math.pi, 0, 0)) == pytest.approx(math.pi / 2 * 18.0)
    assert slew_time((0, 0, 0), (0.1, -0.3, 0.2)) == pytest.approx(math.pi / 2 * 0.3 / math.radians(10))


def test_paper_procedure_rank_null_space_and_lab_time():
    plan = device_plan(load_procedure("device-coarse"), load_procedure("device-fine"), passes=2)
    result = expected_precision(plan, QUARTZ, SETTING)
    assert result.analysis.rank == 17 and len(result.ids) == 18
    null = dict(zip(result.ids, result.analysis.null_space[:, 0]))
    assert null["beta_xz"] == pytest.approx(1 / math.sqrt(3), abs=2e-3)
    assert null["beta_yz"] == pytest.approx(1 / math.sqrt(3), abs=2e-3)
    assert null["theta10"] == pytest.approx(-1 / math.sqrt(3), abs=2e-3)
    assert result.sigma["theta10"] == 0.0
    # 36 coarse dwells of 25 s and 18 fine of 605 s, plus the slews
    dwell_settle = 36 * 25.0 + 18 * 605.0
    assert dwell_settle < result.lab_time < dwell_settle + 20 * 60
    # one coarse pass alone determines everything but the gauge (the zero-offset iteration re-points from it)
    assert result.coarse_pass.rank == 17


def test_white_noise_bound_scales_as_one_over_root_time():
    plan = device_plan(load_procedure("device-coarse"), passes=1)
    one = expected_precision(plan, WHITE, SETTING).sigma
    four = expected_precision(DevicePlan(plan.coarse.with_dwell(plan.coarse.dwell * 4)), WHITE, SETTING).sigma
    for k, v in one.items():
        assert four[k] == pytest.approx(v / 2, rel=1e-6)
    slow = expected_precision(DevicePlan(plan.coarse.with_dwell(plan.coarse.dwell * 4)), QUARTZ, SETTING).sigma
    assert slow["bias_x"] > four["bias_x"] * 1.05  # the bias instability does not average down


def test_bound_is_the_estimators_covariance_on_simulated_data():
    """The design's σ are the joint fit's σ for a simulated device (white σ measured in each dwell: a few % apart)."""
    from stableins.estimators.device import calibrate_device
    from stableins.estimators.dwell import dwells_from_columns
    from stableins.simulator.device import simulate_dwells
    from stableins.simulator.truth import Truth

    coarse = load_procedure("device-coarse")
    truth = Truth.draw(5)
    commands = [s.command for s in coarse.steps]
    columns = simulate_dwells(truth, commands * 2, dwell=20.0, settle=5.0, rate=20.0, seed=17)
    columns["pass"] = np.where(columns["position"] > 18, 2, 1).astype(np.int32)
    columns["position"] = ((columns["position"] - 1) % 18 + 1).astype(np.int32)
    noise = NoiseModel.given(
        truth.noise.velocity_random_walk, truth.noise.bias_instability, truth.noise.acceleration_random_walk, truth.noise.quantization
    )
    layouts = {"coarse": coarse.layout, "fine": load_procedure("device-fine").layout}
    dwells = dwells_from_columns(columns, layouts=layouts)
    fit = calibrate_device(dwells, truth.site, layouts=layouts, noise=noise).coarse
    design = expected_precision(device_plan(coarse, passes=2, sample_rate=20.0), noise, DeviceSetting.from_site(truth.site))
    for k in fit.ids:
        value, sigma, status = fit[k]
        if status == "estimated":
            assert sigma == pytest.approx(design.sigma[k], rel=0.08), k


def test_optimized_dwells_meet_the_targets_in_less_time():
    plan = device_plan(load_procedure("device-coarse"), passes=1)
    given = expected_precision(plan, WHITE, SETTING)
    targets = {k: 1.2 * v for k, v in given.sigma.items() if v > 0}
    designed = optimize_dwells(plan, WHITE, SETTING, targets=targets)
    for k, v in targets.items():
        assert designed.sigma[k] <= v * 1.001, k
    # white noise alone would allow every dwell 1/1.2² as long (30 % less dwell time); slews and settles stay
    assert designed.lab_time < given.lab_time - 0.25 * plan.coarse.dwell.sum()
    with pytest.raises(InputError) as error:
        optimize_dwells(plan, WHITE, SETTING, targets={"bias_x": 1e-9})
    assert error.value.field == "targets"


def test_budget_design_is_no_worse_than_the_given_one():
    plan = device_plan(load_procedure("device-coarse"), passes=1)
    given = expected_precision(plan, WHITE, SETTING)
    scales = {k: given.model[k].nominal for k in given.ids if k != "theta10"}
    for criterion in (Criterion.A, Criterion.D):
        designed = optimize_dwells(plan, WHITE, SETTING, budget=given.lab_time, criterion=criterion)
        assert designed.lab_time <= given.lab_time * 1.001
        assert scaled_criterion(designed, criterion, scales) <= scaled_criterion(given, criterion, scales) + 1e-9


def test_design_without_white_noise_is_refused():
    plan = device_plan(load_procedure("device-coarse"), passes=1)
    with pytest.raises(InputError):
        expected_precision(plan, NoiseModel.given(0.0, 1e-5), SETTING)


def test_designed_procedure_is_written_loaded_and_keeps_the_templates_sections(tmp_path):
    template = load_procedure("device-fine")
    commands = np.array([s.command for s in template.steps])
    stage = PlannedStage("fine", commands, np.linspace(10, 100, 18), 3.0, 10.0)
    loaded = write_procedure(tmp_path / "d.toml", template, stage, name="d-fine", source="test")
    assert loaded.name == "d-fine" and loaded.stage == "fine"
    assert [s.dwell for s in loaded.steps] == pytest.approx(np.linspace(10, 100, 18), abs=0.05)
    assert np.allclose([s.command for s in loaded.steps], commands, atol=1e-9)
    assert loaded.checks == template.checks and loaded.tolerances == template.tolerances
    with pytest.raises(InputError):
        write_procedure(tmp_path / "x.toml", load_procedure("device-coarse"), stage, name="x", source="test")
    assert not (tmp_path / "x.toml").exists()


def test_design_cli(tmp_path, capsys):
    noise = ["--white", "4.5e-4", "--bias-instability", "2", "--random-walk", "1e-7"]
    assert main(["design", "device-coarse", *noise]) == 0
    out = capsys.readouterr().out
    assert "rank 17 of 18" in out and "null direction 1" in out and "lab time" in out
    assert main(["design", "device-coarse"]) == 2
    assert "--white" in capsys.readouterr().err
    quick = ["--white", "4.5e-4", "--passes", "1", "--target", "sf_*=5", "--out", str(tmp_path)]
    assert main(["design", "device-coarse", *quick]) == 0
    out = capsys.readouterr().out
    designed = load_procedure(tmp_path / "designed-coarse.toml")
    assert len(designed.steps) == 18 and "wrote" in out
    assert main(["design", "device-coarse", *noise, "--target", "nothing*=3"]) == 2


@pytest.mark.parametrize(
    ("extra", "field"),
    [
        (["--match", "--name", "../../escaped"], "--name"),  # issue 31: wrote two directories above --out
        (["--match", "--name", ""], "--name"),
        (["--match", "--name", "a/b"], "--name"),
        (["--match", "--name", ".hidden"], "--name"),
        (["--match", "--criterion", "D"], "--criterion"),  # issue 31: the criterion applies to --budget only
        (["--grid", "45"], "--grid"),  # nothing to optimize: the grid would be ignored
    ],
)
def test_design_refuses_names_and_options_that_would_not_apply(tmp_path, capsys, extra, field):
    """A name that could leave ``--out`` and an option that would be ignored: exit 2 naming it; nothing written."""
    out = tmp_path / "sub" / "O"
    code = main(["design", "device-coarse", "--white", "2e-5", "--passes", "1", "--out", str(out), *extra])
    assert code == 2
    assert field in capsys.readouterr().err
    assert not any(tmp_path.rglob("*.toml"))


def test_stableins_run_executes_the_designed_procedure_with_its_dwells(tmp_path, capsys):
    """Issue 19: the TOML that ``design --out`` writes is what ``stableins run`` executes, position by position."""
    from stableins.data.device import load_device

    quick = ["--white", "4.5e-4", "--passes", "1", "--target", "sf_*=5", "--out", str(tmp_path / "d")]
    assert main(["design", "device-coarse", *quick]) == 0
    designed = load_procedure(tmp_path / "d" / "designed-coarse.toml")
    dwells = np.array([s.dwell for s in designed.steps])
    assert dwells.min() < 0.5 * dwells.max()  # the design made the dwells unequal: the check below can fail
    run = tmp_path / "run"
    assert main(["run", str(tmp_path / "d" / "designed-coarse.toml"), "--driver", "sim", "--unit", "SN19", "--out", str(run)]) == 0
    capsys.readouterr()
    assert (run / "record.json").exists() and (run / "report.pdf").exists()
    recorded = load_device(run / "device.h5").dwells(stage="coarse")
    assert len(recorded) == 2 * len(designed.steps)  # the zero-offset iteration's two passes
    for dwell in recorded:
        duration = len(dwell.time) / designed.steps[dwell.position - 1].sample_rate
        assert duration == pytest.approx(dwells[dwell.position - 1], abs=0.11)
        if dwell.pass_number == 1:  # pass 2 re-commands with the estimated zero offsets taken out
            assert np.allclose(dwell.command, designed.steps[dwell.position - 1].command, atol=1e-9)
