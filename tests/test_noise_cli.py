"""The noise model end to end: 'stableins noise', the record's noise_model section, --noise, diagnose's one χ²."""

import json
from dataclasses import replace

import numpy as np
import pytest

from stableins.cli import main
from stableins.data.device import save_device
from stableins.data.truth import save_truth
from stableins.errors import InputError
from stableins.noise import NoiseModel, NoiseSource
from stableins.procedures.definition import device_layouts, load_procedure
from stableins.records import CalibrationRecord
from stableins.simulator.device import simulate_dwells
from stableins.simulator.truth import Truth


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    """One simulator unit (quartz noise): a coarse pass (20 s at 100 Hz) and the fine stage (18 × 120 s at 10 Hz), and its record."""
    out = tmp_path_factory.mktemp("noise")
    truth = Truth.draw(21)
    coarse, fine = load_procedure("device-coarse"), load_procedure("device-fine")
    c = simulate_dwells(truth, [s.command for s in coarse.steps], dwell=20.0, settle=5.0, seed=5, stage="coarse")
    f = simulate_dwells(truth, [s.command for s in fine.steps], dwell=120.0, settle=5.0, rate=10.0, seed=6, stage="fine")
    save_device(out / "coarse.csv", c, truth.site)
    save_device(out / "fine.h5", f, truth.site)
    assert main(["calibrate", "device", str(out / "coarse.csv"), str(out / "fine.h5"), "--out", str(out / "cal.json")]) == 0
    return out, truth


def test_calibrate_device_records_the_noise_model_it_used(session):
    out, _ = session
    record = CalibrationRecord.load(out / "cal.json")
    assert record.noise_model is not None and record.noise_model.source is NoiseSource.DEVICE_DWELLS
    assert record.noise_model.test is not None
    np.testing.assert_allclose(record.noise_model.values("white"), 4.5e-4, rtol=0.03)  # the simulator's N


def test_noise_command_writes_the_model_into_a_record_and_plots(session, capsys, tmp_path):
    out, _ = session
    capsys.readouterr()
    code = main(
        [
            "noise",
            str(out / "fine.h5"),
            "--record",
            str(out / "cal.json"),
            "--out",
            str(tmp_path / "cal2.json"),
            "--plot",
            str(tmp_path / "a.png"),
            "--json",
        ]
    )
    assert code == 0
    document = json.loads(capsys.readouterr().out)
    written = CalibrationRecord.load(tmp_path / "cal2.json")
    assert written.noise_model == NoiseModel.from_document(document["noise_model"])
    assert written.values() == CalibrationRecord.load(out / "cal.json").values()
    assert (tmp_path / "a.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    tau = np.array(document["allan"]["tau"])
    assert tau.size > 5 and np.all(np.diff(tau) > 0)


def test_noise_command_bad_input_exits_2_and_writes_nothing(session, tmp_path):
    out, _ = session
    assert main(["noise", str(out / "fine.h5"), "--out", str(tmp_path / "x.json")]) == 2  # --out needs --record
    assert main(["noise", str(out / "fine.h5"), "--confidence", "1.5"]) == 2
    assert not (tmp_path / "x.json").exists()


def test_calibrate_device_uses_a_records_noise_model(session, tmp_path, capsys):
    out, truth = session
    given = NoiseModel.given(4.5e-4, truth.noise.bias_instability, truth.noise.acceleration_random_walk, provenance="datasheet")
    record = replace(CalibrationRecord.load(out / "cal.json"), noise_model=given)
    record.save(tmp_path / "with_noise.json")
    args = ["calibrate", "device", str(out / "coarse.csv"), str(out / "fine.h5")]
    assert main([*args, "--noise", str(tmp_path / "with_noise.json"), "--out", str(tmp_path / "cal3.json")]) == 0
    assert CalibrationRecord.load(tmp_path / "cal3.json").noise_model == given
    # a record without a noise model, or --noise together with datasheet flags: bad input
    bare = replace(record, noise_model=None)
    bare.save(tmp_path / "bare.json")
    capsys.readouterr()
    assert main([*args, "--noise", str(tmp_path / "bare.json"), "--out", str(tmp_path / "cal4.json")]) == 2
    assert "noise_model" in capsys.readouterr().err
    assert main([*args, "--noise", str(tmp_path / "with_noise.json"), "--bias-instability", "2", "--out", str(tmp_path / "cal4.json")]) == 2
    assert not (tmp_path / "cal4.json").exists()


def test_the_noise_model_is_carried_through_stage_updates(session):
    """A later stage keeps the record's noise model unless it measured one (CalibrationRecord.updated)."""
    from stableins.data.device import load_device
    from stableins.estimators.device import calibrate_device
    from stableins.estimators.dwell import dwells_from_columns

    out, truth = session
    record = CalibrationRecord.load(out / "cal.json")
    summaries = [s for name in ("coarse.csv", "fine.h5") for s in dwells_from_columns(load_device(out / name).columns)]
    later = calibrate_device(summaries, truth.site, layouts=device_layouts()).final
    assert record.updated(later).noise_model == record.noise_model
    measured = NoiseModel.given(1e-4, provenance="static record")
    assert record.updated(later, noise_model=measured).noise_model == measured
    assert CalibrationRecord.from_document(record.updated(later).to_document()).noise_model == record.noise_model


def test_a_damaged_noise_model_section_names_its_field(session, tmp_path):
    out, _ = session
    document = json.loads((out / "cal.json").read_text())
    document["noise_model"]["axes"]["y"]["white"]["value"] = -1.0
    (tmp_path / "bad.json").write_text(json.dumps(document))
    with pytest.raises(InputError) as error:
        CalibrationRecord.load(tmp_path / "bad.json")
    assert error.value.field == "noise_model.axes.y.white.value"


def test_diagnose_reports_one_chi2_and_uses_the_records_noise_model(session, capsys):
    out, _ = session
    capsys.readouterr()
    assert main(["diagnose", str(out / "fine.h5"), "--record", str(out / "cal.json"), "--json"]) == 0
    captured = capsys.readouterr()
    document = json.loads(captured.out)
    record = CalibrationRecord.load(out / "cal.json")
    assert NoiseModel.from_document(document["noise_model"]) == record.noise_model
    assert "the record's noise model" in captured.err
    # the JSON's χ²_ν is the generalized one the fit minimized (the first history step, the text report)
    assert document["chi2_red"] == pytest.approx(document["history"][0]["chi2_red"], rel=1e-12)


def test_noise_from_a_static_system_record_recovers_the_simulated_terms(tmp_path, capsys):
    """3 h at 2 Hz of a unit with a strong flicker floor (10 µg): N to 2 %, B within its interval and 30 %."""
    from stableins.simulator.noise import NoiseSettings

    noise = replace(NoiseSettings.quartz(), bias_instability=10 * 9.80665e-6)
    truth = replace(Truth.draw(4), noise=noise)
    save_truth(truth, tmp_path / "truth.json")
    args = ["simulate", "system", "--truth", str(tmp_path / "truth.json"), "--duration", "3h", "--rate", "2", "--out", str(tmp_path)]
    assert main(args) == 0
    capsys.readouterr()
    assert main(["noise", str(tmp_path / "system.h5"), "--json", "--plot", str(tmp_path / "allan.png")]) == 0
    model = NoiseModel.from_document(json.loads(capsys.readouterr().out)["noise_model"])
    assert model.source is NoiseSource.STATIC_RECORD
    np.testing.assert_allclose(model.values("white"), noise.velocity_random_walk, rtol=0.02)
    b = model.values("bias_instability")
    lo, hi = model.limits("bias_instability")
    assert np.all(np.abs(b / noise.bias_instability - 1) < 0.3) and np.all((lo < noise.bias_instability) & (noise.bias_instability < hi))
