"""Truth files: realistic draws, round trips, bad input, effect catalogue."""

import json

import numpy as np
import pytest

from stableins.conventions import ARCSEC, MICRO_G
from stableins.data.truth import load_truth, save_truth
from stableins.errormodel import ErrorModel
from stableins.errors import InputError
from stableins.simulator.effects import CATALOGUE, catalogue_table
from stableins.simulator.noise import NoiseSettings
from stableins.simulator.truth import PARAMETER_IDS, Truth


def test_draw_has_realistic_magnitudes():
    draws = [Truth.draw(s) for s in range(60)]
    model = ErrorModel.standard(gimbals=True)
    for term in model:
        values = np.array([d.parameters[term.id] for d in draws]) - term.reference
        spread = values.std()
        assert 0.6 * term.nominal < spread < 1.5 * term.nominal, term.id
    offsets = np.array([d.parameters["theta20"] for d in draws])
    assert 30 * ARCSEC < offsets.std() < 90 * ARCSEC
    residual = np.array([d.calibration_residual()["bias_x"] for d in draws])
    assert 2 * MICRO_G < residual.std() < 8 * MICRO_G
    assert Truth.draw(3).parameters == Truth.draw(3).parameters
    assert Truth.draw(3).parameters != Truth.draw(4).parameters


def test_round_trip_through_a_file(tmp_path):
    truth = Truth.draw(5, effects={"K3_x": 1e-8, "tilt_north": 1e-5}, gyro_drift={"z": 1e-9}, noise=NoiseSettings.quartz())
    path = tmp_path / "truth.json"
    save_truth(truth, path)
    back = load_truth(path)
    assert back == truth
    assert json.loads(path.read_text())["schema_version"] == 1
    assert set(back.site.damping) >= {"zeta", "omega_s", "R", "k1", "k2", "k3"}


@pytest.mark.parametrize(
    ("mutate", "field"),
    [
        (lambda d: d.pop("parameters"), "parameters"),
        (lambda d: d["parameters"].update(sf_w=1.0), "parameters"),
        (lambda d: d["parameters"].update(bias_x="abc"), "parameters.bias_x"),
        (lambda d: d["effects"].update(K9_x=1.0), "effects"),
        (lambda d: d.update(schema_version=99), "schema_version"),
        (lambda d: d["site"].update(gimbal_senses=[1, 2, 1, 1]), "site"),
        (lambda d: d.update(paramters={}), "paramters"),
        (lambda d: d["gyro_drift"].update(w=1.0), "gyro_drift"),
    ],
)
def test_bad_truth_files_name_file_and_field(tmp_path, mutate, field):
    d = Truth.draw(1).to_dict()
    mutate(d)
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(d))
    with pytest.raises(InputError) as info:
        load_truth(path)
    assert info.value.field == field
    assert str(path) in str(info.value)


def test_unreadable_files(tmp_path):
    with pytest.raises(InputError, match="not found"):
        load_truth(tmp_path / "missing.json")
    (tmp_path / "x.json").write_text("{not json")
    with pytest.raises(InputError, match="JSON"):
        load_truth(tmp_path / "x.json")


def test_catalogue_has_units_nominals_and_meanings():
    ids = set(CATALOGUE)
    for a in "xyz":
        assert {f"K3_{a}", f"Koq_{a}", f"Ksa_{a}", f"Kt_bias_{a}", f"Kt_sf_{a}", f"Kd_bias_{a}", f"Kh_{a}", f"Dg_{a}{a}"} <= ids
    assert {"Kcc_xxy", "Kcc_xyz", "Kcc_zxy", "Kcq_xy", "Kcq_zx", "lever_x_y", "nonorth_12", "nonorth_23", "tilt_north", "tilt_east"} <= ids
    assert "Kcq_xx" not in ids and "Kcc_xyx" not in ids
    assert {"ang1_platform_c", "ang1_inner_s", "ang1_middle_c"} <= ids
    for eid, unit, nominal, meaning in catalogue_table():
        assert unit and nominal > 0 and len(meaning) > 10, eid
    assert not set(PARAMETER_IDS) & ids


def test_docs_list_every_effect():
    import pathlib

    text = (pathlib.Path(__file__).resolve().parents[1] / "docs" / "simulator.md").read_text()
    missing = [e for e in CATALOGUE if f"`{e}`" not in text]
    assert not missing, f"docs/simulator.md does not list {missing}"


def test_truth_is_immutable():
    truth = Truth.draw(2)
    with pytest.raises(TypeError):
        truth.parameters["bias_x"] = 0.0
    changed = truth.with_changes(parameters={**truth.parameters, "bias_x": 0.0})
    assert changed.parameters["bias_x"] == 0.0 and truth.parameters["bias_x"] != 0.0
