"""Discovery reaches the record: added effects in the device stages, verdicts, the record section, compensation."""

import copy
import functools
import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from stableins import cli
from stableins.conventions import MICRO_G
from stableins.data.truth import load_truth
from stableins.discovery.carry import carry_effects
from stableins.discovery.library import LIBRARY, calibration_limit, calibration_terms, record_terms
from stableins.discovery.steps import Decision
from stableins.errormodel import MICRO_G_PER_G2, ErrorModel, Term, TermInputs, TermKind
from stableins.errors import InputError
from stableins.estimators.device import calibrate_device
from stableins.estimators.device_gauge import gauge_equivalent
from stableins.estimators.dwell import dwells_from_columns
from stableins.noise import NoiseModel
from stableins.procedures.definition import load_procedure
from stableins.records import CalibrationRecord
from stableins.simulator.device import simulate_dwells
from stableins.simulator.effects import CATALOGUE
from stableins.simulator.physics import Accelerometer, SensorInputs
from stableins.simulator.truth import Truth

COARSE = load_procedure("device-coarse")
FINE = load_procedure("device-fine")
LAYOUTS = {"coarse": COARSE.layout, "fine": FINE.layout}
KCC = 60 * MICRO_G_PER_G2  # 60 µg/g²


def _session(seed, effects):
    """Two coarse passes and a fine stage of the truth simulator (quartz noise), with hidden ``effects``."""
    truth = Truth.draw(seed).with_changes(effects=effects)
    dwells = []
    for p in (1, 2):
        columns = simulate_dwells(
            truth, [s.command for s in COARSE.steps], dwell=20.0, settle=5.0, rate=20.0, seed=seed + 977 * p, stage="coarse", pass_number=p
        )
        dwells += dwells_from_columns(columns, layouts=LAYOUTS)
    columns = simulate_dwells(truth, [s.command for s in FINE.steps], dwell=300.0, settle=5.0, rate=2.0, seed=seed + 5003, stage="fine")
    dwells += dwells_from_columns(columns, layouts=LAYOUTS)
    noise = truth.noise
    slow = NoiseModel.given(noise.velocity_random_walk, noise.bias_instability, noise.acceleration_random_walk, provenance="datasheet")
    return truth, functools.partial(calibrate_device, dwells, truth.site, layouts=LAYOUTS, noise=slow)


@pytest.fixture(scope="module")
def hidden_kcc():
    return _session(11, {"Kcc_xxy": KCC})


@pytest.fixture(scope="module")
def clean():
    return _session(12, {})


def test_every_stage_estimates_an_added_effect_and_recovers_it(hidden_kcc):
    truth, calibrate = hidden_kcc
    calibration = calibrate(extra_terms=calibration_terms(["Kcc_xxy"]))
    fits = (*calibration.passes, calibration.coarse, calibration.fine, calibration.fused)
    for fit in fits:
        value, sigma, status = fit["Kcc_xxy"]
        assert status == "estimated"
        assert abs(value - KCC) < 4 * sigma, (fit.stage, value / MICRO_G_PER_G2, sigma / MICRO_G_PER_G2)
    value, sigma, _ = calibration.fused["Kcc_xxy"]
    assert sigma < calibration.coarse["Kcc_xxy"][1] and sigma < calibration.fine["Kcc_xxy"][1]
    # with the effect in the model the fused fit is back at its noise floor and the standard terms are unbiased
    nu = calibration.fused.dof
    assert abs(calibration.fused.chi2_red - 1.0) < 3 * math.sqrt(2 / nu)
    reference = gauge_equivalent(truth.parameters)
    z = [(calibration.fused[k][0] - reference[k]) / calibration.fused[k][1] for k in ("K2_x", "K2_y", "theta30", "bias_x", "beta_xy")]
    assert max(abs(v) for v in z) < 4.0, z


def test_the_standard_model_is_biased_by_the_hidden_effect(hidden_kcc):
    """The reason to carry the effect: left out, it spoils χ² (and the parameters it aliases into)."""
    _, calibrate = hidden_kcc
    fused = calibrate().fused
    assert fused.chi2_red > 1.0 + 5 * math.sqrt(2 / fused.dof)


def test_carry_keeps_a_present_effect_and_leaves_out_an_absent_one(hidden_kcc):
    truth, calibrate = hidden_kcc
    carried = carry_effects(lambda extra: calibrate(extra_terms=extra), calibration_terms(["Kcc_xxy", "Kcc_yyz"]))
    steps = carried.history.steps
    assert [s.decision for s in steps] == [Decision.BASELINE, Decision.KEPT, Decision.NOT_SUPPORTED]
    assert steps[1].p_value < 1e-6 and steps[1].delta_bic < -20
    assert steps[2].p_value > 0.05 and steps[2].delta_bic > 0
    assert "left out of the record" in steps[2].reason
    assert carried.kept == ("Kcc_xxy",)
    assert "Kcc_yyz" not in carried.calibration.final.ids and "Kcc_xxy" in carried.calibration.final.ids
    assert steps[1].chi2_red < steps[0].chi2_red
    # the record in force is the last kept step's fit: the same χ²_ν in the history and in the fit
    assert steps[1].chi2_red == pytest.approx(carried.calibration.final.chi2_red, rel=1e-9)


def test_keep_unsupported_keeps_it_with_its_verdict(clean):
    _, calibrate = clean
    alpha = 1e-3  # one clean session: an absent effect passes 5 % of the time at the default α = 0.05
    carried = carry_effects(lambda extra: calibrate(extra_terms=extra), calibration_terms(["Kcc_xxy"]), alpha=alpha, keep_unsupported=True)
    step = carried.history.steps[1]
    assert step.p_value > alpha
    assert step.decision is Decision.KEPT_ON_REQUEST and "kept on request" in step.reason
    value, sigma, status = carried.calibration.final["Kcc_xxy"]
    assert status == "estimated" and abs(value) < 4 * sigma


def test_an_effect_the_data_cannot_separate_is_held_and_not_determined(clean):
    """``|f| = g`` at rest: Kcq_xy f_y² + Kcq_xz f_z² is bias and K2 of x; the second of the pair is held."""
    _, calibrate = clean
    calibration = calibrate(extra_terms=calibration_terms(["Kcq_xy", "Kcq_xz"]))
    for fit in (calibration.coarse, calibration.fine, calibration.fused):
        statuses = {fit["Kcq_xy"][2], fit["Kcq_xz"][2]}
        assert "unidentifiable" in statuses, fit.stage
        assert any(n.startswith("not determined") for n in fit.notes), fit.stage
    assert calibration.fused["theta10"][2] == "gauge"
    carried = carry_effects(lambda extra: calibrate(extra_terms=extra), calibration_terms(["Kcq_xy", "Kcq_xz"]), keep_unsupported=True)
    assert carried.history.steps[2].decision is Decision.NOT_DETERMINED
    assert "Kcq_xz" not in carried.calibration.final.ids


def test_record_carries_the_effect_and_the_history(hidden_kcc, tmp_path):
    truth, calibrate = hidden_kcc
    carried = carry_effects(lambda extra: calibrate(extra_terms=extra), calibration_terms(["Kcc_xxy", "Kcc_yyz"]))
    record = replace(CalibrationRecord.from_device(carried.calibration, truth.site), discovery=carried.history)
    path = record.save(tmp_path / "cal.json")
    again = CalibrationRecord.load(path)
    assert again["Kcc_xxy"].unit == "s^2/m" and again["Kcc_xxy"].status == "estimated"
    assert again["Kcc_xxy"].sigma == pytest.approx(math.sqrt(again.covariance_of(["Kcc_xxy"])[0, 0]))
    assert again.discovery is not None and again.discovery.effects == ("Kcc_xxy",)
    assert again.discovery.to_json() == record.discovery.to_json()
    assert [s.decision for s in again.discovery.steps] == [Decision.BASELINE, Decision.KEPT, Decision.NOT_SUPPORTED]
    assert again.error_model().ids[-1] == "Kcc_xxy"
    text = again.report()
    assert "ug/g^2" in text.split("Kcc_xxy", 1)[1].splitlines()[0]  # engineering units for discovered terms
    assert "not supported" in text
    # a later stage's Bayesian update carries the history with the model
    later = again.updated(carried.calibration.fine)
    assert later.discovery is not None and later.discovery.effects == ("Kcc_xxy",) and "Kcc_xxy" in later.ids


@pytest.fixture(scope="module")
def kcc_document(hidden_kcc):
    truth, calibrate = hidden_kcc
    carried = carry_effects(lambda extra: calibrate(extra_terms=extra), calibration_terms(["Kcc_xxy"]))
    return replace(CalibrationRecord.from_device(carried.calibration, truth.site), discovery=carried.history).to_document()


@pytest.mark.parametrize(
    "change, field",
    [
        (lambda d: d["discovery"]["steps"][1].__setitem__("decision", "maybe"), "discovery.steps[1].decision"),
        (lambda d: d["discovery"]["steps"][0].__setitem__("decision", "kept"), "discovery.steps[0].decision"),
        (lambda d: d["discovery"]["steps"][1].__setitem__("residual_rms", [1e-5]), "discovery.steps[1].residual_rms"),
        (lambda d: d["discovery"]["steps"][1].__setitem__("p_value", 2.0), "discovery.steps[1].p_value"),
        (lambda d: d["discovery"].__setitem__("alpha", 0.0), "discovery.alpha"),
        (lambda d: d["discovery"].__setitem__("steps", []), "discovery.steps"),
    ],
)
def test_a_damaged_discovery_section_is_refused_naming_the_field(kcc_document, change, field):
    document = copy.deepcopy(kcc_document)
    change(document)
    with pytest.raises(InputError) as caught:
        CalibrationRecord.from_document(document, "cal.json")
    assert caught.value.field == field and caught.value.path == "cal.json"


def test_a_kept_effect_must_be_a_parameter_of_the_record(kcc_document):
    document = copy.deepcopy(kcc_document)
    k = document["covariance"]["ids"].index("Kcc_xxy")
    document["parameters"].pop(k)
    document["covariance"]["ids"].pop(k)
    document["covariance"]["matrix"] = [row[:k] + row[k + 1 :] for i, row in enumerate(document["covariance"]["matrix"]) if i != k]
    with pytest.raises(InputError, match="not parameters of the record") as caught:
        CalibrationRecord.from_document(document, "cal.json")
    assert caught.value.field == "discovery"


def test_compensation_with_the_record_inverts_the_model_with_its_discovered_terms():
    """``record.error_model().inverse`` undoes the instrument including the effect, defined by the simulator."""
    model = ErrorModel.standard(nonlinear=True)
    truth = {"sf_x": 1 + 3e-4, "bias_y": 40 * MICRO_G, "beta_xz": 2e-4, "K2_z": 30 * MICRO_G_PER_G2, "Kcc_xxy": KCC}
    world = Accelerometer(truth, (("Kcc_xxy", CATALOGUE["Kcc_xxy"].regressor),))  # the simulator's model and effect
    rng = np.random.default_rng(3)
    f_p = rng.normal(size=(200, 3))
    f_p *= 9.8 / np.linalg.norm(f_p, axis=1, keepdims=True)
    f_a = world.output(f_p)
    compensation = model + record_terms(["sf_x", "Kcc_xxy"])
    assert np.abs(compensation.inverse(f_a, truth) - f_p).max() < 1e-12
    assert np.abs(model.inverse(f_a, truth) - f_p).max() > 1e-5  # without the term: tens of µg


def test_library_and_simulator_define_the_carried_effects_alike():
    """The record's terms (library) and the world's effects (simulator) are the same physics, by id."""
    f = np.random.default_rng(5).normal(size=(50, 3)) * 7.0
    for term_id in (c.id for c in LIBRARY if calibration_limit(c.id) is None):
        ours = LIBRARY[term_id].term.regressor(TermInputs(f))
        world = CATALOGUE[term_id].regressor(SensorInputs(f))
        assert np.allclose(ours, world, rtol=1e-12, atol=0.0), term_id


def test_only_instrument_effects_can_be_carried():
    assert calibration_limit("Kcc_xxy") is None
    for term_id, word in (("nonorth_12", "kinematics"), ("Kt_bias_x", "temperature"), ("Dg_xx", "gyros"), ("lever_x_y", "rotation")):
        with pytest.raises(InputError, match=word):
            calibration_terms([term_id])
    with pytest.raises(InputError, match="unknown effect"):
        calibration_terms(["Kcc_xxq"])
    with pytest.raises(InputError, match="twice"):
        calibration_terms(["Kcc_xxy", "Kcc_xxy"])


def _procedure_with_model(tmp_path, table, name="device-coarse"):
    text = load_procedure(name).path
    path = tmp_path / f"{name}-model.toml"
    path.write_text(Path(text).read_text(encoding="utf-8") + "\n" + table + "\n", encoding="utf-8")
    return path


def test_a_procedure_names_the_effects_of_its_model(tmp_path):
    path = _procedure_with_model(tmp_path, '[model]\nadd = ["Kcc_xxy", "Kcc_zxz"]')
    assert load_procedure(path).model_add == ("Kcc_xxy", "Kcc_zxz")
    assert load_procedure("device-coarse").model_add == ()


@pytest.mark.parametrize(
    "table, field, message",
    [
        ('[model]\nadd = ["nonorth_12"]', "model.add", "cannot be carried"),
        ('[model]\nadd = ["K9_x"]', "model.add", "unknown effect"),
        ('[model]\nadd = "Kcc_xxy"', "model.add", "not a list"),
        ('[model]\nremove = ["K2_x"]', "model", "unknown keys"),
    ],
)
def test_a_bad_model_table_names_file_and_field(tmp_path, table, field, message):
    path = _procedure_with_model(tmp_path, table)
    with pytest.raises(InputError, match=message) as caught:
        load_procedure(path)
    assert caught.value.field == field and caught.value.path == str(path)


def test_a_system_procedure_cannot_add_effects(tmp_path):
    path = _procedure_with_model(tmp_path, '[model]\nadd = ["Kcc_xxy"]', "system-static")
    with pytest.raises(InputError, match="compensates those of the prior") as caught:
        load_procedure(path)
    assert caught.value.field == "model.add"


@pytest.fixture(scope="module")
def simulated(tmp_path_factory):
    """A short device session of the truth simulator with a hidden Kcc_xxy (10 Hz; the demo's procedures)."""
    out = tmp_path_factory.mktemp("sim")
    assert cli.main(["simulate", "device", "--seed", "5", "--rate", "10", "--hidden", f"Kcc_xxy={KCC!r}", "--out", str(out)]) == 0
    return out


def test_calibrate_device_add_writes_the_effect_its_verdict_and_a_procedure_adds_too(simulated, tmp_path, capsys):
    data = [str(simulated / "device-coarse.csv"), str(simulated / "device-fine.h5")]
    out = tmp_path / "cal.json"
    status = cli.main(["calibrate", "device", *data, "--bias-instability", "2", "--random-walk", "1e-7",
                       "--add", "Kcc_xxy", "--add", "Kcc_yyz", "--out", str(out), "--json"])  # fmt: skip
    assert status == 0
    captured = capsys.readouterr()
    result = json.loads(captured.out)
    decisions = [s.get("decision") for s in result["discovery"]["steps"]]
    assert decisions == ["baseline", "kept", "not supported"]
    assert "Kcc_yyz not supported" in captured.err  # said, not silently dropped
    record = CalibrationRecord.load(out)
    assert "Kcc_xxy" in record.ids and "Kcc_yyz" not in record.ids
    assert abs(record["Kcc_xxy"].value - KCC) < 3 * record["Kcc_xxy"].sigma
    assert record.discovery is not None and record.discovery.steps[1].reason.startswith("Kcc_xxy = +")
    # the same model named by the procedure file
    fine = _procedure_with_model(tmp_path, '[model]\nadd = ["Kcc_xxy"]', "device-fine")
    out2 = tmp_path / "cal2.json"
    assert cli.main(["calibrate", "device", *data, "--fine-procedure", str(fine), "--bias-instability", "2", "--random-walk", "1e-7",
                     "--out", str(out2)]) == 0  # fmt: skip
    again = CalibrationRecord.load(out2)
    assert again["Kcc_xxy"].value == pytest.approx(record["Kcc_xxy"].value, rel=1e-9)


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--add", "nonorth_12"], "cannot be carried"),
        (["--add", "Kcc_xxy", "--add", "Kcc_xxy"], "twice"),
        (["--add", "Kxx"], "unknown effect"),
        (["--add", "Kcc_xxy", "--alpha", "1.5"], "--alpha: 1.5 is out of range"),
    ],
)
def test_calibrate_device_refuses_bad_effects_before_writing(simulated, tmp_path, capsys, extra, message):
    out = tmp_path / "cal.json"
    data = [str(simulated / "device-coarse.csv"), str(simulated / "device-fine.h5")]
    assert cli.main(["calibrate", "device", *data, "--out", str(out), *extra]) == 2
    assert message in capsys.readouterr().err
    assert not out.exists()


def test_the_simulated_ins_applies_the_installed_discovered_terms(simulated, tmp_path):
    """``simulate system --installed`` installs the record's effect and the navigation computer compensates with it."""
    from stableins.commands.simulate import installed_from_record
    from stableins.simulator.noise import NoiseSettings
    from stableins.simulator.system import SystemWorld

    truth = load_truth(simulated / "truth.json")
    record = tmp_path / "cal.json"
    data = [str(simulated / "device-coarse.csv"), str(simulated / "device-fine.h5")]
    assert cli.main(["calibrate", "device", *data, "--add", "Kcc_xxy", "--out", str(record)]) == 0
    installed = installed_from_record(record, truth)
    assert installed["Kcc_xxy"] == CalibrationRecord.load(record)["Kcc_xxy"].value
    # noise-free world with the hidden effect; the INS installed with the exact truth, with and without the effect
    world = truth.with_changes(noise=NoiseSettings.quiet(), installed_calibration=dict(truth.parameters))
    error = {}
    for name, calibration in (("without", dict(truth.parameters)), ("with", {**truth.parameters, **truth.effects})):
        simulator = SystemWorld(world.with_changes(installed_calibration=calibration), rate=1.0, seed=1)
        chunk = simulator.chunk(3600, include_truth=True)
        error[name] = max(np.abs(chunk[f"truth_df_{k}"]).max() for k in ("north", "east", "down"))
    assert error["without"] > 5 * MICRO_G  # the uncompensated effect: f_x f_y Kcc_xxy of order 30 µg on the polar platform
    assert error["with"] < 1e-6 * MICRO_G


def test_a_run_estimates_the_model_of_its_procedure_and_of_the_prior_record(tmp_path, monkeypatch):
    """``stableins run`` with ``[model] add`` (coarse) and then on that prior (fine): the effect is estimated in both."""
    import io

    from device_world import ExactPlatform, draw_truth

    from stableins.console import Console
    from stableins.procedures.planning import plan_from_definition
    from stableins.runs import RunSetup, start_run

    monkeypatch.setattr("os.fsync", lambda fd: None)
    truth = draw_truth(np.random.default_rng(21)) | {"Kcc_xxy": 4 * KCC}
    effect = CATALOGUE["Kcc_xxy"]  # the simulator's definition of the effect, as an additive term of the exact platform's model
    term = Term(
        effect.id,
        TermKind.ADDITIVE,
        effect.unit,
        effect.unit,
        1.0,
        effect.nominal,
        effect.meaning,
        axis=effect.axis,
        regressor=effect.regressor,
    )
    world = ErrorModel.standard(nonlinear=True, gimbals=True) + (term,)

    def short(name, table=""):
        text = Path(load_procedure(name).path).read_text(encoding="utf-8")
        text = text.replace("dwell = 20.0", "dwell = 4.0").replace("dwell = 600.0", "dwell = 20.0")
        path = tmp_path / f"{name}.toml"
        path.write_text(text + "\n" + table + "\n", encoding="utf-8")
        return path

    coarse_file = short("device-coarse", '[model]\nadd = ["Kcc_xxy"]')
    coarse = start_run(plan_from_definition(load_procedure(coarse_file)), tmp_path / "coarse", driver_spec="exact",
                       console=Console(yes=True, out=io.StringIO()), driver=ExactPlatform(truth, sigma=3e-4, seed=1, model=world),
                       setup=RunSetup(definition_file=coarse_file))  # fmt: skip
    record = CalibrationRecord.load(coarse.record)
    assert record["Kcc_xxy"].status == "estimated"
    assert abs(record["Kcc_xxy"].value - 4 * KCC) < 4 * record["Kcc_xxy"].sigma
    fine_file = short("device-fine")  # no [model]: the prior record's model is the unit's
    fine = start_run(plan_from_definition(load_procedure(fine_file)), tmp_path / "fine", driver_spec="exact",
                     console=Console(yes=True, quiet=True), driver=ExactPlatform(truth, sigma=3e-4, seed=2, model=world),
                     setup=RunSetup(definition_file=fine_file, prior_file=coarse.record))  # fmt: skip
    final = CalibrationRecord.load(fine.record)  # the coarse record updated by the fine stage's likelihood
    assert final["Kcc_xxy"].status == "estimated"
    assert [d.stage.split("-")[0] for d in final["Kcc_xxy"].determined_by][-1] == "fine"  # the fine data saw it too
    assert abs(final["Kcc_xxy"].value - 4 * KCC) < 4 * final["Kcc_xxy"].sigma
    assert final["Kcc_xxy"].sigma <= record["Kcc_xxy"].sigma
