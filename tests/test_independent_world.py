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


def test_same_gyro_turn_within_the_dwells():
    """Gyro drift, g-sensitivity and torquer errors (earth_rate): the generator's readings and outputs are the simulator's.

    The generator turns the platform from the command by ``exp(−[τ ω_bp^p×])`` and reads the gimbal angles back from
    its own chain (docs/conventions.md, "The platform during a dwell"); the simulator's slew is made instantaneous.
    Equal to 1e-10 rad (readings) and 1e-9 g (outputs) over 40 s at 0.5 °/h, positions near gimbal lock held.
    """
    from stableins.conventions import AXES, DEG_PER_HOUR, DEG_PER_HOUR_PER_G

    ind = _module()
    site = SimulatedSite(gimbal_senses=(1, -1, 1, 1), base_attitude=(0.2, 0.001, -0.002))
    drift = {"x": 0.5 * DEG_PER_HOUR, "y": -0.3 * DEG_PER_HOUR, "z": 0.4 * DEG_PER_HOUR}
    torquer = {"torquer_scale_x": 2e-3, "torquer_scale_y": -1e-3, "torquer_scale_z": 3e-3}
    sensitivity = np.array([[1.0, -2.0, 0.5], [0.3, 2.0, -1.0], [-0.7, 0.2, 1.5]]) * 0.05 * DEG_PER_HOUR_PER_G
    effects = {f"Dg_{a}{b}": float(sensitivity[i, j]) for i, a in enumerate(AXES) for j, b in enumerate(AXES)}
    truth = Truth.draw(6, site=site, noise=NoiseSettings.quiet(), effects=effects, gyro_drift={**drift, **torquer})
    truth = truth.with_changes(settling={"gain": 0.0, "slew_rate": 1e9, "frequency": 0.5, "damping": 0.2})
    readings = [tuple(math.radians(v) for v in p) for p in ind.POSITIONS_DEG][:8]
    simulated = simulate_dwells(truth, readings, dwell=40.0, settle=1.0, rate=1.0, seed=1)
    instrument = ind.Instrument(
        dict(truth.parameters), truth.site.gravity, senses=site.gimbal_senses, base_attitude=site.base_attitude,
        latitude_deg=math.degrees(truth.site.latitude),
    )  # fmt: skip
    gyro = ind.Gyro(tuple(drift[a] for a in AXES), tuple(map(tuple, sensitivity)), tuple(torquer.values()))
    columns = ind.session(instrument, [("coarse", 1, readings, 1.0, 40.0)], rate=1.0, noise=ind.Noise(), seed=1, gyro=gyro)["coarse"]
    commanded = np.repeat(np.array(readings), 40, axis=0)
    for name in ("angle_platform", "angle_inner", "angle_middle"):
        assert np.max(np.abs(simulated[name] - columns[name])) < 1e-10, name
    turned = np.stack([columns[n] for n in ("angle_platform", "angle_inner", "angle_middle")], -1) - commanded
    assert np.max(np.abs(turned)) > 1e-5  # the platform did turn (20″ in 41 s at 0.5 °/h)
    held = np.abs(turned).max(axis=1).reshape(8, 40).max(axis=1) == 0.0
    assert held.tolist() == [False, False, True, True, True, False, False, False]  # inner gimbal at 90°: held
    for axis in "xyz":
        assert np.max(np.abs(simulated[f"f_{axis}"] - columns[f"f_{axis}"])) < 1e-9 * truth.site.gravity, axis
