"""Named worlds of the simulator (stableins.simulator.worlds): presets, the default unchanged, CLI and campaign use."""

from __future__ import annotations

import json

import numpy as np
import pytest

from stableins.campaign.config import load_campaign
from stableins.campaign.task import TaskData, run_task
from stableins.cli import main
from stableins.conventions import MICRO_G
from stableins.data.truth import load_truth, save_truth
from stableins.errors import InputError
from stableins.simulator.device import simulate_dwells
from stableins.simulator.noise import NoiseSettings, TemperatureProfile
from stableins.simulator.truth import Truth
from stableins.simulator.worlds import BIAS_DRIFT, BIAS_THERMAL, WORLDS, apply_world, world

POSITIONS = [(0.0, 0.0, 0.0), (0.0, np.pi, 0.0), (0.0, np.pi / 2, 0.0)]


def _dwells(truth: Truth, seed: int = 5) -> dict:
    return simulate_dwells(truth, POSITIONS, dwell=20.0, settle=2.0, rate=5.0, seed=seed)


def test_default_world_is_the_drawn_truth_bit_for_bit():
    truth = Truth.draw(3)
    assert apply_world(truth, "default") is truth
    a, b = _dwells(truth), _dwells(apply_world(Truth.draw(3), "default"))
    for name in a:
        assert np.array_equal(a[name], b[name]), name
    # no warm-up: the truth file holds no warm-up fields (files written before worlds are unchanged)
    assert "warmup" not in truth.to_dict()["noise"]["temperature"]


@pytest.mark.parametrize("name", list(WORLDS))
def test_every_world_simulates_and_round_trips(tmp_path, name):
    truth = apply_world(Truth.draw(4), name)
    save_truth(truth, tmp_path / "truth.json")
    assert load_truth(tmp_path / "truth.json") == truth
    columns = _dwells(truth)
    assert np.all(np.isfinite(columns["f_x"]))
    # the instrument is the seed's: worlds change noise, effects and gyro drift, never the drawn parameters
    assert dict(truth.parameters) == dict(Truth.draw(4).parameters)
    assert WORLDS[name].slow_noise == (truth.noise.bias_instability > 0 or truth.noise.acceleration_random_walk > 0)


def test_world_effects_reach_the_output():
    """The drift world's 10 µg/day bias drift and the thermal world's warm-up act on the dwell means as their formulas say."""
    base = Truth.draw(2, noise=NoiseSettings.quiet())
    quiet = NoiseSettings.quiet()
    drift = WORLDS["drift"].apply(base).with_changes(noise=quiet)
    plain = _dwells(base)
    drifted = _dwells(drift)
    t = plain["time"]
    # + Kd t on x (sign +) and y (sign −), noise-free, through the scale factor (|sf − 1| < 1e-3)
    assert np.allclose(drifted["f_x"] - plain["f_x"], BIAS_DRIFT * t, rtol=1e-3, atol=1e-15)
    assert np.allclose(drifted["f_y"] - plain["f_y"], -BIAS_DRIFT * t, rtol=1e-3, atol=1e-15)
    profile = TemperatureProfile(warmup=-4.0, warmup_time_constant=1800.0)
    thermal = WORLDS["thermal"].apply(base).with_changes(noise=NoiseSettings(temperature=profile))
    warm = _dwells(thermal)
    expected_dt = -4.0 * np.exp(-t / 1800.0)
    assert np.allclose(warm["temperature"] - 25.0, expected_dt, atol=1e-12)
    # Kt_bias_z = +5 µg/K; the scale-factor term adds Kt_sf ΔT f_z (f_z ≤ g: ≤ 1e-6 × 4 K × g = 4e-5)
    dz = warm["f_z"] - plain["f_z"]
    assert np.all(np.abs(dz - BIAS_THERMAL * expected_dt) <= 1e-6 * 4.0 * 9.81 + 1e-12)
    assert abs(BIAS_THERMAL / MICRO_G - 5.0) < 1e-12


def test_unknown_world_names_the_field(tmp_path, capsys):
    with pytest.raises(InputError) as error:
        world("moon")
    assert error.value.field == "world" and "lab" in (error.value.expected or "")
    code = main(["simulate", "device", "--world", "moon", "--out", str(tmp_path / "x")])
    assert code == 2 and not (tmp_path / "x").exists()
    assert "--world" in capsys.readouterr().err


def test_cli_world_and_list(tmp_path, capsys):
    assert main(["simulate", "--list-worlds", "--json"]) == 0
    names = [w["name"] for w in json.loads(capsys.readouterr().out)["worlds"]]
    assert names == list(WORLDS)
    out = tmp_path / "sim"
    code = main(
        ["simulate", "device", "--world", "thermal", "--procedure", "device-coarse", "--dwell", "4", "--rate", "2", "--no-iteration"]
        + ["--hidden", "K3_x=100ug/g3", "--out", str(out)]
    )
    assert code == 0
    truth = load_truth(out / "truth.json")
    assert truth.noise.temperature.warmup == -4.0 and "Kt_bias_x" in truth.effects and "K3_x" in truth.effects


def test_campaign_noise_entry_may_name_a_world(tmp_path):
    path = tmp_path / "c.toml"
    text = (
        "[campaign]\ndevices = 1\nfirst_seed = 3\n[[procedure]]\nname='a'\ncoarse='device-coarse'\npasses=1\nsample_rate=2.0\n"
        "[[noise]]\nname='w'\nworld='drift'\ncalibrate='dwells'\n"
    )
    path.write_text(text, encoding="utf-8")
    config = load_campaign(path)
    assert config.noises[0].world == "drift" and config.noises[0].settings == WORLDS["drift"].noise
    rows = run_task(config.tasks()[0], TaskData(config))
    assert rows and all(np.isfinite(r["chi2_red"]) for r in rows)
    path.write_text(text.replace("world='drift'", "world='drift'\npreset='white'"), encoding="utf-8")
    with pytest.raises(InputError) as error:
        load_campaign(path)
    assert error.value.field == "noise[0].preset"
    path.write_text(text.replace("world='drift'", "world='mars'"), encoding="utf-8")
    with pytest.raises(InputError) as error:
        load_campaign(path)
    assert error.value.field == "noise[0].world"
