"""How the platform is held during a dwell (issue 25 part 5): declared, simulated exactly, expected by the gyro stage.

docs/conventions.md, "The platform during a dwell".  Fast, fixed seeds; the Monte Carlo (rms z over ≥ 20 sessions) is
``benchmarks/bench_device_gsensitivity.py --drift 0.05 --mode earth_rate``.
"""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from stableins.conventions import ARCSEC, AXES, DEG_PER_HOUR, DEG_PER_HOUR_PER_G, dwell_platform_rate, earth_rate_nav
from stableins.data.metadata import metadata_from_document, metadata_to_document
from stableins.dwell_mode import DEFAULT_DWELL_MODE, DwellMode
from stableins.errors import InputError
from stableins.estimators.dwell import steady_trend_departure
from stableins.estimators.gyro_sensitivity import ReadingSlopes, SlopeGeometry, estimate_gyro_sensitivity, remove_earth_turn
from stableins.procedures.definition import load_procedure
from stableins.simulator.device import simulate_dwells
from stableins.simulator.noise import NoiseSettings
from stableins.simulator.truth import Truth

QUIET = NoiseSettings(velocity_random_walk=0.0, angle_noise=0.0)
WHITE = NoiseSettings(velocity_random_walk=4.5e-4, quantization=1e-5, angle_noise=0.2 * ARCSEC)
DRIFT = {a: 0.05 * DEG_PER_HOUR for a in AXES}


def _truth(mode, *, noise=QUIET, seed=3, effects=None, drift=DRIFT):
    truth = Truth.draw(seed, noise=noise, gyro_drift=drift, effects=effects or {})
    return truth.with_changes(site=replace(truth.site, dwell_mode=mode))


def _commands(count=18):
    return [s.command for s in load_procedure("device-coarse").steps][:count]


def _pieces(columns):
    pieces, readings = [], []
    for p in np.unique(columns["position"]):
        rows = columns["position"] == p
        angles = np.stack([columns["angle_platform"][rows], columns["angle_inner"][rows], columns["angle_middle"][rows]], -1)
        pieces.append((columns["time"][rows], angles))
        readings.append(angles.mean(axis=0))
    return pieces, np.array(readings)


def test_platform_rate_of_each_mode():
    w, earth, k = np.array([1e-8, -2e-8, 3e-8]), np.array([4e-5, 0.0, -6e-5]), np.array([1e-4, 2e-4, -1e-4])
    assert np.array_equal(dwell_platform_rate(DwellMode.CAGED, w, earth, k), np.zeros(3))
    assert np.allclose(dwell_platform_rate(DwellMode.EARTH_RATE, w, earth, k), w + k * earth)
    assert np.allclose(dwell_platform_rate(DwellMode.INERTIAL, w, earth, k), w - earth)
    assert DEFAULT_DWELL_MODE is DwellMode.EARTH_RATE


def test_metadata_declares_the_mode_and_old_files_take_the_default():
    site = Truth.draw(1).site
    document = metadata_to_document(replace(site, dwell_mode=DwellMode.CAGED))
    assert document["dwell_mode"] == "caged"
    assert metadata_from_document(document).dwell_mode is DwellMode.CAGED
    del document["dwell_mode"]  # a file written before the mode existed
    assert metadata_from_document(document).dwell_mode is DwellMode.EARTH_RATE
    document["dwell_mode"] = "slaved"
    with pytest.raises(InputError, match="dwell_mode"):
        metadata_from_document(document, "x.csv")


def test_procedure_declares_the_mode(tmp_path):
    procedure = load_procedure("device-coarse")
    assert procedure.dwell_mode is DwellMode.EARTH_RATE
    text = Path(procedure.path).read_text().replace('dwell_mode = "earth_rate"', 'dwell_mode = "sometimes"')
    bad = tmp_path / "bad.toml"
    bad.write_text(text)
    with pytest.raises(InputError, match="procedure.dwell_mode"):
        load_procedure(bad)


def test_caged_platform_does_not_move_and_the_gyro_stage_says_why():
    truth = _truth(DwellMode.CAGED)
    columns = simulate_dwells(truth, _commands(6), dwell=20.0, settle=5.0, rate=10.0, seed=1)
    pieces, readings = _pieces(columns)
    for (_, angles), command in zip(pieces, _commands(6), strict=True):
        assert np.allclose(angles, command, atol=1e-12)  # the angle loops hold the command (settled)
    geometry = SlopeGeometry.of(readings, truth.site.gravity, latitude=truth.site.latitude, mode=DwellMode.CAGED)
    with pytest.raises(ValueError, match="caged"):
        estimate_gyro_sensitivity(ReadingSlopes.of(pieces), geometry)


def test_torqued_platform_slopes_equal_the_expectation_with_the_torquer_error():
    """Noise-free: the reading slopes equal J⁻¹(w + k ∘ ω_ie^p) to 1e-10 rad/s (the torquer column is exact)."""
    drift = {**DRIFT, "torquer_scale_x": 3e-4, "torquer_scale_y": -2e-4, "torquer_scale_z": 1e-4}
    effects = {"Dg_xz": 0.002 * DEG_PER_HOUR_PER_G}
    truth = _truth(DwellMode.EARTH_RATE, drift=drift, effects=effects)
    columns = simulate_dwells(truth, _commands(), dwell=20.0, settle=5.0, rate=10.0, seed=1)
    pieces, readings = _pieces(columns)
    offsets = [truth.parameters[k] for k in ("theta10", "theta20", "theta30")]
    geometry = SlopeGeometry.of(
        readings, truth.site.gravity, zero_offsets=offsets, base_attitude=truth.site.base_attitude, latitude=truth.site.latitude
    )
    predicted = sum(DRIFT[a] * geometry.column(f"gyro_drift_{a}") for a in AXES) + effects["Dg_xz"] * geometry.column("Dg_xz")
    predicted = predicted + sum(drift[name] * column for name, column in geometry.nuisance)
    measured = ReadingSlopes.of(pieces, skip=0.5).slope
    free = ~geometry.locked
    assert np.allclose(measured[free], predicted[free], rtol=1e-3, atol=1e-10)
    torquer = sum(drift[name] * column for name, column in geometry.nuisance)
    assert np.max(np.abs(torquer[free])) > 1e-9  # the torquer error is seen, and is in the expectation
    assert np.all(geometry.locked[[2, 3, 4, 13]])  # Wu's positions 3, 4, 5, 14: inner gimbal at 90°
    for k in (2, 3, 4, 13):  # held to the base at gimbal lock: the readings stay at the command
        assert np.allclose(pieces[k][1], _commands()[k], atol=1e-12)


def test_inertially_held_platform_turns_with_the_earth_and_the_stage_removes_it_exactly():
    truth = _truth(DwellMode.INERTIAL, drift={})
    commands = [_commands()[k] for k in (0, 1, 5)]  # away from gimbal lock
    columns = simulate_dwells(truth, commands, dwell=120.0, settle=5.0, rate=2.0, seed=1)
    pieces, _ = _pieces(columns)
    platform = truth.platform()
    for t, angles in pieces:
        moved = np.ptp(angles, axis=0).max()
        assert moved > 100 * ARCSEC  # 15 °/h over 2 minutes
        remainder, centre = remove_earth_turn(t, angles, platform, earth_rate_nav(truth.site.latitude))
        used = t >= t[0] + 0.5 * (t[-1] - t[0])  # the part the slope is fitted on (the servo settles before)
        assert np.max(np.abs(remainder[used] - centre)) < 5e-9  # nothing but the Earth's turn was there (0.2″ noise: 1e-6)


def test_inertial_data_fitted_as_torqued_show_the_torquers_at_minus_one():
    """Inertially held is torqued with ``k = −1``: the torquer nuisance takes the Earth rate, not ``D_g``."""
    truth = _truth(DwellMode.INERTIAL, noise=WHITE, drift=DRIFT)
    columns = simulate_dwells(truth, _commands(), dwell=20.0, settle=5.0, rate=20.0, seed=2)
    pieces, readings = _pieces(columns)
    offsets = [truth.parameters[k] for k in ("theta10", "theta20", "theta30")]
    wrong = SlopeGeometry.of(readings, truth.site.gravity, zero_offsets=offsets, latitude=truth.site.latitude)
    fit = estimate_gyro_sensitivity(ReadingSlopes.of(pieces), wrong)
    assert all(abs(value + 1.0) < 5 * sigma + 1e-3 for _, value, sigma in fit.details.nuisance)


def test_gyro_stage_warns_on_chi2_like_the_accelerometer_stages():
    """Slopes the model cannot explain (a creep of the inner reading alternating in sign): the 99.9 % χ² warning."""
    truth = _truth(DwellMode.EARTH_RATE, noise=WHITE, drift=DRIFT)
    columns = simulate_dwells(truth, _commands(), dwell=20.0, settle=5.0, rate=20.0, seed=2)
    pieces, readings = _pieces(columns)
    crept = [(t, a + np.outer(t - t[0], [0.0, (-1) ** k * 2e-7, 0.0])) for k, (t, a) in enumerate(pieces)]
    offsets = [truth.parameters[k] for k in ("theta10", "theta20", "theta30")]
    geometry = SlopeGeometry.of(readings, truth.site.gravity, zero_offsets=offsets, latitude=truth.site.latitude)
    clean = estimate_gyro_sensitivity(ReadingSlopes.of(pieces), geometry)
    assert clean.details.chi2_warning is None
    fit = estimate_gyro_sensitivity(ReadingSlopes.of(crept), geometry)
    warning = fit.details.chi2_warning
    assert warning is not None and warning.startswith("warning: chi2 = ") and "largest normalized residuals" in warning
    assert warning in fit.notes and fit.notes[0].startswith("gauge: the platform frame of the device gauge θ10 = 0")


def test_a_steady_drift_is_not_a_slew():
    t = np.linspace(0.0, 600.0, 6001)
    steady = np.outer(t, [30 * ARCSEC / 600, 0.0, -10 * ARCSEC / 600])  # 30″ in 600 s
    assert np.all(steady_trend_departure(t, steady) < 1e-9)
    slewed = steady.copy()
    slewed[3000:, 1] += 40 * ARCSEC
    assert steady_trend_departure(t, slewed)[1] > 20 * ARCSEC


def test_run_refuses_a_platform_that_holds_its_dwells_otherwise(tmp_path, capsys):
    """The procedure declares caged, the simulated platform torques at the Earth rate: exit 2 before anything moves."""
    from stableins.cli import main

    procedure = load_procedure("device-coarse")
    caged = tmp_path / "caged.toml"
    caged.write_text(Path(procedure.path).read_text().replace('dwell_mode = "earth_rate"', 'dwell_mode = "caged"'))
    assert main(["run", str(caged), "--driver", "sim", "--unit", "SN1", "--out", str(tmp_path / "run")]) == 2
    assert "procedure.dwell_mode" in capsys.readouterr().err
    assert not (tmp_path / "run").exists()  # nothing half-written


def test_runner_verdict_takes_a_steady_drift_after_arrival_as_reached():
    """A 600-s dwell whose readings drift 40″ from the command: reached (line at the start), not 'not at the angles'."""
    from stableins.estimators.layout import DwellChecks
    from stableins.procedures.verdict import evaluate_dwell
    from stableins.samples import SampleBlock

    rng = np.random.default_rng(7)
    t = np.arange(0.0, 600.0, 0.1)
    command = np.array([0.3, 0.2, -0.1])
    angles = command + np.outer(t, [40 * ARCSEC / 600, -20 * ARCSEC / 600, 0.0]) + 0.2 * ARCSEC * rng.standard_normal((t.size, 3))
    force = np.array([0.0, 0.0, -9.8]) + 4.5e-4 * rng.standard_normal((t.size, 3))
    block = SampleBlock(t, force, angles, np.full(t.size, 25.0))
    verdict = evaluate_dwell(command, block, DwellChecks(), 600.0, 10.0)
    assert verdict.accepted and verdict.angle_error < 0.1 * ARCSEC
    late = SampleBlock(t, force, angles + 30 * ARCSEC, block.temperature)  # never arrived
    assert not evaluate_dwell(command, late, DwellChecks(), 600.0, 10.0).accepted
