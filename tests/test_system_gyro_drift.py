"""The gyro drift ε^p measured by the system stage from the gimbal readings (docs/system-calibration.md §9, issue 16).

Against the truth simulator, which turns the platform at −ε^p in inertial space and reads the gimbals through its own
exact kinematics: the model is exact on noise-free readings; with the simulator's default angle noise, quartz
accelerometer noise, base tilt and angle-sensor errors one day gives ε^p within 3σ at σ far below 5e-5 °/h, and the
attitude coefficients agree with the drift-free run.  benchmarks/bench_system_drift.py runs the Monte Carlo.
"""

import warnings

import numpy as np
import pytest

from stableins.conventions import ARCSEC, DEG_PER_HOUR, SIDEREAL_DAY, GimbalConfiguration
from stableins.data.chunks import ArraySource
from stableins.estimators.system.blocks import GimbalBlocks
from stableins.estimators.system.gyro_drift import DriftSource, fit_gimbal_drift
from stableins.estimators.system.separation import COMBINED_COEFFICIENTS
from stableins.estimators.system.stage import SystemOptions, run_system_stage
from stableins.simulator import system
from stableins.simulator.noise import NoiseSettings
from stableins.simulator.truth import SimulatedSite, Truth

ATTITUDE = [i for i, n in enumerate(COMBINED_COEFFICIENTS) if n.startswith(("theta", "phi")) and not n.endswith("mean")]
EFFECTS = {"tilt_north": 9 * ARCSEC, "tilt_east": -7 * ARCSEC, "ang1_platform_c": 2 * ARCSEC, "ang1_platform_s": -1.5 * ARCSEC,
           "ang1_inner_c": 1.5 * ARCSEC, "ang1_middle_s": -2 * ARCSEC}  # fmt: skip
DRIFT = {"x": 1e-3 * DEG_PER_HOUR, "y": -1e-3 * DEG_PER_HOUR, "z": 1e-3 * DEG_PER_HOUR}


def record_frame(truth):
    """The true drift in the record's platform frame: x_p, y_p turned about z_p by the θ10 residual (docs §9)."""
    true = np.array([truth.gyro_drift.get(a, 0.0) for a in "xyz"])
    turn = truth.parameters["theta10"] - truth.installed_calibration["theta10"]
    return true + turn * np.cross([0.0, 0.0, 1.0], true)


def gimbal_fit(truth, cols, chunk=20000):
    """The gimbal fit on a record's readings, fed in chunks with the platform angle wrapped to (−π, π]."""
    blocks = GimbalBlocks(10.0, 0.0)
    for lo in range(0, cols["time"].size, chunk):
        part = slice(lo, lo + chunk)
        wrapped = np.angle(np.exp(1j * cols["angle_platform"][part]))
        blocks.add_readings(cols["time"][part], wrapped, cols["angle_inner"][part], cols["angle_middle"][part])
    offsets = np.array([truth.installed_calibration[k] for k in ("theta10", "theta20", "theta30")])
    config = GimbalConfiguration(tuple(truth.site.gimbal_senses))
    return fit_gimbal_drift(blocks.means(), truth.site.latitude, config, offsets=offsets)


def test_gimbal_model_is_exact_on_noise_free_readings():
    """Noise-free readings (0.001-0.002 °/h, tilt, sensor errors, 2″ offset residuals): the model reproduces them to 1e-12 rad.

    What remains of ε^p's error is the sensors' local slope (a once-per-revolution error of 2″ scales the small inner and
    middle angle motion the drift causes by up to 1e-5), which the data cannot tell from the drift: its prior is in σ.
    """
    drift = {"x": 1e-3 * DEG_PER_HOUR, "y": -2e-3 * DEG_PER_HOUR, "z": 1.5e-3 * DEG_PER_HOUR}
    truth = Truth.draw(2, site=SimulatedSite(sample_rate=1.0), gyro_drift=drift, effects=EFFECTS, noise=NoiseSettings())
    cols = system.simulate_system(truth, SIDEREAL_DAY, 1.0, seed=102, earth_angle=0.6)
    fit = gimbal_fit(truth, cols)
    true = record_frame(truth)
    assert np.abs((fit.values - true) / fit.sigma).max() < 3.0
    assert fit.sigma.max() < 2e-5 * np.abs(true).max()
    assert fit.residual_rms.max() < 1e-12
    # the nuisances are what the world has: the platform sensor's once-per-revolution error (about z_p), the base rotation
    assert np.abs(np.abs(fit.sensor_error) - np.array([2.0, 1.5]) * ARCSEC).max() < 0.05 * ARCSEC
    assert 5 * ARCSEC < np.linalg.norm(fit.base_rotation) < 30 * ARCSEC


@pytest.fixture(scope="module")
def drift_day():
    """One day at 1 Hz: quartz noise, 0.2″ angle noise, tilt, sensor errors, 0.001 °/h per axis; and the drift-free world."""
    truth = Truth.draw(3, site=SimulatedSite(sample_rate=1.0), gyro_drift=DRIFT, effects=EFFECTS)
    still = truth.with_changes(gyro_drift={"x": 0.0, "y": 0.0, "z": 0.0})
    runs, records = [], []
    for world in (truth, still):
        records.append(system.simulate_system(world, SIDEREAL_DAY, 1.0, seed=103, earth_angle=0.9))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            options = SystemOptions(estimate_k2=True)
            runs.append(run_system_stage(ArraySource(records[-1]), world.site, world.installed_calibration, options=options))
    return truth, records[0], runs[0], runs[1]


def test_drift_from_one_day_with_noise_tilt_and_sensor_errors(drift_day):
    """The acceptance of issue 16 part 1 on one fixed seed (the Monte Carlo is benchmarks/bench_system_drift.py)."""
    truth, _, out, free = drift_day
    result = out.result
    index = [result.ids.index(f"gyro_drift_{a}") for a in "xyz"]
    sigma = result.sigma[index]
    z = (result.values[index] - record_frame(truth)) / sigma
    assert np.abs(z).max() < 3.0 and sigma.max() < 5e-5 * DEG_PER_HOUR
    assert sigma.max() < 1e-6 * DEG_PER_HOUR  # 0.2″ per reading at 1 Hz: a few 1e-8 °/h
    assert all(result.status[k] == "estimated" for k in index) and result.details.determination["gyro_drift_z"] == "alone"
    # the attitude coefficients use it: within 2σ of the drift-free run (0.001 °/h unremoved moves them by ~2e-5 rad)
    shift = np.abs(out.combined.values - free.combined.values)[ATTITUDE] / out.combined.sigma[ATTITUDE]
    assert shift.max() < 2.0
    assert not any("gyro drift not supplied" in n for n in out.notes)
    assert any(n.startswith("gyro drift from the gimbal readings") for n in out.notes)
    assert out.result.settings.gyro_drift_source is DriftSource.GIMBALS


def test_drift_given_without_uncertainty_is_held_and_compared(drift_day):
    """A drift given exactly is removed as given, not updated; the note says how far the gimbal readings put it."""
    truth, cols, out, _ = drift_day
    given = tuple(float(v) for v in record_frame(truth))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        held = run_system_stage(
            ArraySource(cols), truth.site, truth.installed_calibration, options=SystemOptions(estimate_k2=True, known_gyro_drift=given)
        )
    assert "gyro_drift_x" not in held.result.ids
    assert any("is held exactly" in n for n in held.notes)
    np.testing.assert_allclose(held.combined.values, out.combined.values, atol=0.01 * out.combined.sigma.min())


def test_drift_jacobian_of_the_attitude_fit_is_the_fit_of_the_drift_responses(drift_day):
    """∂(attitude values)/∂ε from the fit's own linear map equals three fits of the loop's unit-drift responses."""
    from stableins.estimators.system.attitude import AttitudeDrift, AttitudeModel, fit_attitude
    from stableins.estimators.system.gyro_drift import attitude_drift_jacobian
    from stableins.estimators.system.loop import DampingLoop

    truth, _, out, _ = drift_day
    loop = out.diagnostics.loop
    rng = np.random.default_rng(4)
    t = np.arange(0.0, SIDEREAL_DAY, 10.0)
    s = 0.9 + 7.292115e-5 * t
    blocks = {"time": t, "count": np.full(t.size, 10.0), "cos": np.cos(s), "sin": np.sin(s),
              "pitch": 1e-6 * rng.standard_normal(t.size), "roll": 1e-6 * rng.standard_normal(t.size)}  # fmt: skip
    options = SystemOptions()
    fit = fit_attitude(blocks, AttitudeModel(loop), (1e-6, 1e-6), scale_low_frequency=False, drift=AttitudeDrift(jacobian=True))
    reference = attitude_drift_jacobian(blocks, loop, (1e-6, 1e-6), options, 600.0)
    assert isinstance(loop, DampingLoop)
    np.testing.assert_allclose(fit.drift_jacobian, reference, rtol=1e-9, atol=1e-12 * np.abs(reference).max())
    assert np.abs(reference).max() > 1e3  # rad per rad/s: 0.001 °/h (4.8e-9 rad/s) moves them by ~1e-5 rad


def test_drift_responses_mode_by_mode_equal_the_plain_recursion():
    from scipy.linalg import expm

    from stableins.conventions import dcm_body_to_platform
    from stableins.estimators.system.loop import DampingLoop

    loop = DampingLoop(0.7, 9.80, 0.5, vertical_gains=(0.01, 3e-5, 1e-8))
    t = np.arange(0.0, SIDEREAL_DAY, 10.0)
    angle = 0.3 + 7.292115e-5 * t
    fast = loop.drift_responses(t, angle)
    a, b = loop.state_matrix(), loop.drift_input_matrix()
    n = a.shape[0]
    big = np.zeros((n + 6, n + 6))
    big[:n, :n], big[:n, n : n + 3], big[n : n + 3, n + 3 :] = a * 10.0, b * 10.0, np.eye(3)
    e = expm(big)
    nav = dcm_body_to_platform(-angle, 0.0, np.pi / 2 + loop.latitude)
    slow = loop._drift_responses_stepwise(t, nav, e[:n, :n], e[:n, n : n + 3], e[:n, n + 3 :])
    assert np.abs(fast - slow).max() < 1e-9 * np.abs(slow).max()


def test_a_record_with_the_measured_drift_is_a_simulator_installed_calibration(drift_day, tmp_path):
    """The record carries gyro_drift_x/y/z; ``simulate system --installed`` takes it (the INS does not compensate its gyros)."""
    from stableins.commands.simulate import installed_from_record
    from stableins.records import CalibrationRecord

    truth, _, out, _ = drift_day
    record = CalibrationRecord.from_fit_result(out.result, serial_number=truth.site.serial_number, site=truth.site)
    assert np.isfinite(record["gyro_drift_x"].sigma) and record["gyro_drift_x"].unit == "rad/s"
    path = tmp_path / "cal.json"
    record.save(path)
    installed = installed_from_record(path, truth)
    assert "gyro_drift_x" not in installed and installed["beta_zy"] == record["beta_zy"].value


def test_g_sensitive_drift_response_removed_with_the_records_dg():
    """D_g 0.001 °/h/g turns a drift at the Earth rate in the platform frame (g cos L D_g e_x cos S ...): through the
    loop it moves the attitude coefficients; the record's D_g removes it (low-noise day, absolute bounds)."""
    import math

    from tests.test_system_recovery import reference

    dg = {"Dg_xx": 1e-3 * DEG_PER_HOUR / 9.80665, "Dg_yy": 1e-3 * DEG_PER_HOUR / 9.80665}
    residual = {"scale_factor": 1e-4, "bias": 1e-3, "installation": 10 * ARCSEC, "nonlinearity": 0.0}
    noise = NoiseSettings(velocity_random_walk=1e-6)  # white, no angle noise
    truth = Truth.draw(4, site=SimulatedSite(sample_rate=1.0), noise=noise, residual=residual, effects=dg)
    cols = system.simulate_system(truth, SIDEREAL_DAY, 1.0, seed=104, earth_angle=1.2)
    _, ref = reference(truth)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        plain = run_system_stage(ArraySource(cols), truth.site, truth.installed_calibration)
        known = run_system_stage(ArraySource(cols), truth.site, {**truth.installed_calibration, **dg})
    error_plain = np.abs(plain.combined.values - ref)[ATTITUDE].max()
    error_known = np.abs(known.combined.values - ref)[ATTITUDE].max()
    assert error_plain > 5 * error_known and error_known < 5e-7, (error_plain, error_known)
    assert any("g-sensitivity D_g" in n for n in known.notes)
    assert math.isfinite(known.result["gyro_drift_z"][0])
