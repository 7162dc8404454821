"""The independent system-level generator (benchmarks/worlds/independent_system.py), written from the docs alone.

It imports nothing from stableins; its physics follows the documented statements (the polar platform's specific force,
the θ10 gauge, the flicker level), and one of its records goes through ``stableins check`` and ``calibrate system`` with
the combined coefficients and the gyro drift within 5σ of its truth.
"""

from __future__ import annotations

import importlib.util
import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest

from stableins import cli

PATH = Path(__file__).resolve().parents[1] / "benchmarks" / "worlds" / "independent_system.py"


def _module():
    spec = importlib.util.spec_from_file_location("independent_system_world", PATH)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules["independent_system_world"] = module
    spec.loader.exec_module(module)
    return module


def test_the_generator_imports_nothing_from_stableins():
    text = PATH.read_text(encoding="utf-8")
    assert "import stableins" not in text and "from stableins" not in text


def test_the_gauge_turn_leaves_every_output_unchanged():
    """docs/device-calibration.md "Gauge": the parameters in the θ10 = 0 gauge give the same outputs, exactly."""
    gen = _module()
    unit = gen.draw_unit(3)
    gauged = gen.gauge_theta10(unit.true, senses=(1, 1, 1, 1))
    rng = np.random.default_rng(1)
    readings = rng.uniform(-3.0, 3.0, (20, 3))
    offsets = np.array([unit.true[f"theta{i}0"] for i in (1, 2, 3)])
    f_n = np.array([0.0, 0.0, -9.8])
    physical = np.stack([gen.chain(r + offsets, (1, 1, 1, 1)) @ f_n for r in readings])
    in_gauge = np.stack([gen.chain(r + offsets * [0, 1, 1], (1, 1, 1, 1)) @ f_n for r in readings])
    assert unit.true["theta10"] != 0.0 and gauged["theta10"] == 0.0
    np.testing.assert_allclose(gen.forward(gauged, in_gauge), gen.forward(unit.true, physical), rtol=0, atol=1e-13)


def test_the_polar_platform_sees_the_documented_specific_force():
    """docs/conventions.md "Polar alignment": f^p/g = (cos St cos L, sin St cos L, sin L), St = −s1 α1, no errors."""
    gen = _module()
    unit = gen.Unit({}, {}, {})
    world = gen.World(duration=7200.0, gyro_drift_dph=(0.0, 0.0, 0.0), g_sensitivity_dphg=0.0,
                      noise=gen.Noise(0.0, 0.0, 0.0, 0.0, 0.0, 0.0))  # fmt: skip
    columns, _ = gen.simulate(unit, world, seed=1)
    lat, g = world.latitude, world.gravity
    st = -columns["angle_platform"]
    expected = g * np.stack([np.cos(st) * math.cos(lat), np.sin(st) * math.cos(lat), np.full_like(st, math.sin(lat))], -1)
    outputs = np.stack([columns[f"f_{a}"] for a in "xyz"], -1)
    np.testing.assert_allclose(outputs, expected, rtol=0, atol=1e-11)
    np.testing.assert_allclose(np.diff(st), gen.EARTH_RATE, rtol=1e-9)  # the base turns under the platform at Ω
    for name in ("pitch", "roll", "velocity_north", "velocity_east"):  # an error-free unit navigates without error
        assert np.max(np.abs(columns[name])) < 1e-12


def test_kasdin_flicker_has_the_documented_level():
    """Two-sided PSD B²/(2πf): the variance of 600-s block means grows by B² ln(10)/π... checked as the Allan variance
    of a flicker floor, σ_A² = 2 ln2 B²/π (IEEE 952 Annex C, B²/(2πf) two-sided), within 10 % over 300 draws."""
    gen = _module()
    rng = np.random.default_rng(7)
    tau, b = 64, 1.0
    draws = gen.kasdin_flicker(4096, 4096, b, rng)  # (n, 3)
    avar = []
    for _ in range(100):
        x = gen.kasdin_flicker(4096, 4096, b, rng)
        means = x[: 4096 // tau * tau].reshape(-1, tau, 3).mean(axis=1)
        avar.append(0.5 * np.mean(np.diff(means, axis=0) ** 2))
    assert draws.shape == (4096, 3)
    assert np.mean(avar) == pytest.approx(2.0 * math.log(2.0) * b**2 / math.pi, rel=0.1)


@pytest.mark.slow
def test_one_record_round_trips_through_check_and_calibrate_system(tmp_path, capsys):
    gen = _module()
    paths = gen.generate(5, tmp_path, gen.World())
    assert cli.main(["check", str(paths["record"])]) == 0
    capsys.readouterr()
    out = tmp_path / "cal.json"
    code = cli.main(["calibrate", "system", str(paths["record"]), "--prior", str(paths["installed"]), "--out", str(out),
                     "--estimate-k2", "--json"])  # fmt: skip
    assert code == 0
    text = capsys.readouterr().out
    result = json.loads(text[: text.rindex("}") + 1])
    truth = json.loads(paths["truth"].read_text(encoding="utf-8"))
    reference = truth["combined"]["estimate_k2"]
    z = {c["name"]: (c["value"] - reference[c["name"]]) / c["sigma"] for c in result["combined"] if c["name"] in reference}
    assert set(z) == set(reference)
    seen = truth["gyro_drift_seen"]
    z.update({p["id"]: (p["value"] - seen[p["id"]]) / p["sigma"] for p in result["parameters"] if p["id"] in seen})
    assert len(z) == len(reference) + 3
    assert max(abs(v) for v in z.values()) < 5.0, z
