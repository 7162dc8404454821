"""The device-level thermal stage (issue 25): Kt_bias and Kt_sf from dwells over a temperature cycle, and its command.

The statistical campaign (rms z over 40 sessions with slow noise) is benchmarks/bench_device_thermal.py; here fixed
seeds and k·σ bounds on one simulated device-thermal session each.
"""

from __future__ import annotations

import argparse
from dataclasses import replace

import numpy as np
import pytest

from stableins.commands import calibrate_thermal
from stableins.conventions import MICRO_G, PPM
from stableins.data.device import DeviceDataset, save_device
from stableins.discovery.library import LIBRARY
from stableins.errormodel import CORE_TERMS
from stableins.errors import InputError
from stableins.estimators.result import FitResult
from stableins.estimators.thermal_sensitivity import THERMAL_TERM_IDS, ThermalDetails, estimate_thermal
from stableins.noise import NoiseModel
from stableins.procedures.definition import load_procedure
from stableins.records import CalibrationRecord, RunInfo
from stableins.simulator.device import simulate_dwells
from stableins.simulator.noise import NoiseSettings, TemperatureProfile
from stableins.simulator.truth import Truth

TRUE = {
    "Kt_bias_x": 4 * MICRO_G,
    "Kt_bias_y": -3 * MICRO_G,
    "Kt_bias_z": 6 * MICRO_G,
    "Kt_sf_x": 5 * PPM,
    "Kt_sf_y": -4 * PPM,
    "Kt_sf_z": 2 * PPM,
}
TERMS = tuple(LIBRARY[i].term for i in THERMAL_TERM_IDS)


def session(truth, seed):
    """The device-thermal procedure on the simulated platform (as benchmarks/bench_device_thermal.py)."""
    procedure = load_procedure("device-thermal")
    steps = procedure.steps
    rate = steps[0].sample_rate
    columns = simulate_dwells(
        truth,
        [s.command for s in steps],
        dwell=[s.dwell for s in steps],
        settle=[s.settle for s in steps],
        rate=rate,
        seed=seed,
        stage="fine",
    )
    return DeviceDataset(replace(truth.site, sample_rate=rate), columns)


def _truth(seed, profile, *, quartz=False):
    noise = (
        replace(NoiseSettings.quartz(), temperature=profile) if quartz else NoiseSettings(velocity_random_walk=4.5e-4, temperature=profile)
    )
    return Truth.draw(seed, effects=TRUE, noise=noise)


CYCLE = TemperatureProfile(amplitude=5.0, period=3.3 * 3600.0, phase=0.4, sensor_noise=0.01)


def test_sensitivities_recovered_within_their_sigma_and_drift_is_a_nuisance():
    """White noise plus a 10 µg/day bias drift on every axis: the six sensitivities within 4σ, χ²_ν in its band."""
    drift = {f"Kd_bias_{a}": 10 * MICRO_G / 86400.0 for a in "xyz"}
    truth = Truth.draw(3, effects=TRUE | drift, noise=NoiseSettings(velocity_random_walk=4.5e-4, temperature=CYCLE))
    data = session(truth, 3)
    fit = estimate_thermal(data.dwells(), TERMS, gravity=data.metadata.gravity)
    true = np.array([TRUE[i] for i in THERMAL_TERM_IDS])
    z = (fit.values - true) / fit.sigma
    assert np.all(np.abs(z) < 4), z
    assert np.all(fit.sigma[:3] < 0.5 * MICRO_G) and np.all(fit.sigma[3:] < 0.5 * PPM)
    details = fit.details
    assert isinstance(details, ThermalDetails) and details.orientations == 6 and details.dwells == 48
    assert np.all(np.abs(details.drift - 10 * MICRO_G / 86400.0) < 4 * details.drift_sigma)
    assert np.all(details.chi2 / details.dof < 1 + 4 * np.sqrt(2 / details.dof))


def test_slow_noise_of_the_noise_model_widens_the_bias_sensitivity_sigma():
    """Quartz slow noise: the noise model's between-dwell covariance gives a larger σ(Kt_bias) than white weights."""
    truth = _truth(4, CYCLE, quartz=True)
    data = session(truth, 4)
    quartz = NoiseSettings.quartz()
    model = NoiseModel.given(quartz.velocity_random_walk, quartz.bias_instability, quartz.acceleration_random_walk)
    white = estimate_thermal(data.dwells(), TERMS, gravity=data.metadata.gravity)
    slow = estimate_thermal(data.dwells(), TERMS, gravity=data.metadata.gravity, noise_model=model)
    assert np.all(slow.sigma[:3] > 1.2 * white.sigma[:3])
    true = np.array([TRUE[i] for i in THERMAL_TERM_IDS])
    assert np.all(np.abs(slow.values - true) < 4 * slow.sigma)


def test_a_temperature_ramp_is_refused_as_not_separable_from_a_drift():
    ramp = TemperatureProfile(ramp=5.0 / 12000.0, sensor_noise=0.01)
    data = session(_truth(5, ramp), 5)
    with pytest.raises(InputError) as error:
        estimate_thermal(data.dwells(), TERMS, gravity=data.metadata.gravity, path="thermal.h5")
    assert error.value.field == "temperature" and "drift" in str(error.value) and "thermal.h5" in str(error.value)


def test_a_constant_temperature_is_refused():
    data = session(_truth(6, TemperatureProfile(sensor_noise=0.01)), 6)
    with pytest.raises(InputError) as error:
        estimate_thermal(data.dwells(), TERMS, gravity=data.metadata.gravity)
    assert error.value.field == "temperature"


def _prior_record(truth):
    terms = tuple(CORE_TERMS)
    fit = FitResult(
        "fine",
        terms,
        np.array([float(truth.installed_calibration.get(t.id, t.reference)) for t in terms]),
        np.diag([(t.nominal * 0.05) ** 2 for t in terms]),
        ("estimated",) * len(terms),
        np.zeros(0),
        np.zeros(0),
    )
    return CalibrationRecord.from_fit_result(fit, RunInfo(procedure="device-fine"), serial_number=truth.site.serial_number)


def _parse(argv):
    parser = argparse.ArgumentParser()
    calibrate_thermal.configure(parser)
    parser.add_argument("--json", action="store_true")
    return parser.parse_args(argv)


def test_cli_carries_the_sensitivities_in_the_record(tmp_path, capsys):
    truth = _truth(7, CYCLE)
    data = session(truth, 7)
    path = save_device(tmp_path / "device.h5", data.columns, data.metadata)
    prior = tmp_path / "prior.json"
    before = _prior_record(truth)
    before.save(prior)
    out = tmp_path / "cal2.json"
    assert calibrate_thermal.run(_parse([str(tmp_path), "--prior", str(prior), "--out", str(out)])) == 0
    assert "Kt_bias_x" in capsys.readouterr().out
    after = CalibrationRecord.load(out)
    for pid in THERMAL_TERM_IDS:
        assert abs(after[pid].value - TRUE[pid]) < 4 * after[pid].sigma
    for pid in before.ids:  # nothing else moves, no σ grows
        assert after[pid].value == pytest.approx(before[pid].value, abs=1e-12 * max(1.0, abs(before[pid].value)))
        assert after[pid].sigma <= before[pid].sigma * (1 + 1e-12)
    assert path.exists()


def test_cli_refuses_a_ramp_and_writes_nothing(tmp_path):
    truth = _truth(8, TemperatureProfile(ramp=5.0 / 12000.0, sensor_noise=0.01))
    data = session(truth, 8)
    save_device(tmp_path / "device.h5", data.columns, data.metadata)
    prior = tmp_path / "prior.json"
    _prior_record(truth).save(prior)
    with pytest.raises(InputError) as error:
        calibrate_thermal.run(_parse([str(tmp_path / "device.h5"), "--prior", str(prior), "--out", str(tmp_path / "out.json")]))
    assert error.value.field == "temperature"
    assert not (tmp_path / "out.json").exists()
