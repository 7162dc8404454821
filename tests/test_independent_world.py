"""The independent generator (benchmarks/worlds/independent.py) against the simulator: the documents are complete.

The generator is written from docs/conventions.md and docs/formats.md alone (it imports nothing from stableins).  On a
noise-free instrument with large parameters, other gimbal senses and a tilted base, its dwell means equal the
simulator's to 1e-9 relative, and its CSV files are read by stableins' reader with every value intact.
"""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path

import numpy as np

from stableins.data.device import load_device
from stableins.simulator.device import simulate_dwells
from stableins.simulator.noise import NoiseSettings
from stableins.simulator.truth import SimulatedSite, Truth

PATH = Path(__file__).resolve().parents[1] / "benchmarks" / "worlds" / "independent.py"


def _module():
    spec = importlib.util.spec_from_file_location("independent_world", PATH)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules["independent_world"] = module
    spec.loader.exec_module(module)
    return module


def test_the_generator_imports_nothing_from_stableins():
    text = PATH.read_text(encoding="utf-8")
    assert "import stableins" not in text and "from stableins" not in text


def test_same_truth_same_dwell_means(tmp_path):
    ind = _module()
    site = SimulatedSite(gimbal_senses=(-1, 1, -1, 1), base_attitude=(0.3, 0.002, -0.001))
    truth = Truth.draw(5, site=site, noise=NoiseSettings.quiet()).with_changes(settling={"gain": 0.0})
    # large K2 and offsets make the nonlinear solution and the gimbal chain matter
    parameters = {**truth.parameters, "K2_x": 3e-5, "K2_z": -2e-5, "theta20": 1e-3, "theta30": -2e-3}
    truth = truth.with_changes(parameters=parameters)
    readings = [tuple(math.radians(v) for v in p) for p in ind.POSITIONS_DEG]
    simulated = simulate_dwells(truth, readings, dwell=4.0, settle=1.0, rate=2.0, seed=1)
    instrument = ind.Instrument(
        dict(truth.parameters), truth.site.gravity, senses=truth.site.gimbal_senses, base_attitude=truth.site.base_attitude
    )
    columns = ind.session(instrument, [("coarse", 1, readings, 1.0, 4.0)], rate=2.0, noise=ind.Noise(), seed=1)["coarse"]
    for k in range(1, 19):
        a = np.array([simulated[f"f_{x}"][simulated["position"] == k].mean() for x in "xyz"])
        b = np.array([columns[f"f_{x}"][columns["position"] == k].mean() for x in "xyz"])
        assert np.all(np.abs(a - b) <= 1e-9 * truth.site.gravity), (k, a - b)
    path = ind.write_csv(tmp_path / "device-coarse.csv", columns, instrument, 2.0, "device-coarse")
    data = load_device(path)
    assert data.metadata.gimbal_senses == (-1, 1, -1, 1)
    assert abs(data.metadata.base_attitude[0] - 0.3) < 1e-12 and data.metadata.gravity == truth.site.gravity
    for name in ("time", "f_x", "f_y", "f_z", "angle_inner", "temperature"):
        assert np.array_equal(np.asarray(data.columns[name], dtype=float), columns[name]), name


def test_flicker_synthesis_has_the_documented_allan_floor():
    """FFT-shaped flicker of B: Allan deviation ≈ 0.664 B at τ = 100 s (12 realizations, within 15 %)."""
    ind = _module()
    rng = np.random.default_rng(7)
    b, rate, n, m = 1e-5, 1.0, 1 << 15, 100
    values = []
    for _ in range(12):
        x = ind.slow_noise(n, rate, ind.Noise(bias_instability=b), rng)[:, 0]
        theta = np.concatenate([[0.0], np.cumsum(x)]) / rate
        d = theta[2 * m :] - 2 * theta[m:-m] + theta[: -2 * m]
        values.append(np.mean(d**2) / (2 * (m / rate) ** 2))
    assert abs(math.sqrt(np.mean(values)) / (0.664 * b) - 1.0) < 0.15
