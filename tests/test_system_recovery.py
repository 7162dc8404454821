"""Recovery of the truth simulator's world by the system stage (one day at 1 Hz, damped dynamics on).

The simulator (stableins.simulator.system) integrates the INS error dynamics in the time
domain from the exact forward model and gimbal kinematics; it shares nothing with the
estimator but the conventions.  References are the combined coefficients of the true
residuals (true − installed) through this package's derived formulas.
"""

import math

import numpy as np
import pytest

from stableins.conventions import ARCSEC, DEG_PER_HOUR, SIDEREAL_DAY
from stableins.data.chunks import ArraySource
from stableins.estimators.system.assembly import residuals_from_parameters
from stableins.estimators.system.separation import COMBINED_COEFFICIENTS, combination_matrix, determined_combinations
from stableins.estimators.system.stage import run_system_stage
from stableins.simulator import system
from stableins.simulator.noise import NoiseSettings
from stableins.simulator.truth import SimulatedSite, Truth

HARMONIC = [i for i, n in enumerate(COMBINED_COEFFICIENTS) if n not in ("theta_mean", "phi_mean")]


def simulated_day(seed, rate=1.0, noise=5e-3, gyro_drift=None, **site):
    """One sidereal day; white accelerometer noise ``noise`` per sample (the paper's 5e-3 m/s²)."""
    residual = {"scale_factor": 1e-4, "bias": 1e-3, "installation": 10 * ARCSEC, "nonlinearity": 0.0}
    noise_settings = NoiseSettings(velocity_random_walk=noise / math.sqrt(rate))
    truth = Truth.draw(seed, site=SimulatedSite(sample_rate=rate, **site), noise=noise_settings, residual=residual, gyro_drift=gyro_drift)
    cols = system.simulate_system(truth, SIDEREAL_DAY, rate, seed=seed + 100, earth_angle=0.3 * seed)
    return truth, cols


def reference(truth):
    p = residuals_from_parameters(truth.parameters, truth.installed_calibration, truth.site.gravity)
    return p, combination_matrix(truth.site.latitude) @ np.r_[p, 0.0, 0.0]


@pytest.mark.parametrize("seed", [1, 2])
def test_recovers_combined_coefficients_within_k_sigma(seed):
    truth, cols = simulated_day(seed)
    out = run_system_stage(ArraySource(cols), truth.site, truth.installed_calibration)
    _, ref = reference(truth)
    z = (out.combined.values - ref) / out.combined.sigma
    assert np.abs(z[HARMONIC]).max() < 4.0, dict(zip(COMBINED_COEFFICIENTS, np.round(z, 2), strict=True))
    # white noise: the white-noise σ has the expected size; the coloured-noise fit (maximum likelihood, no detection
    # threshold) may add to it in a white record, never subtract (docs/system-calibration.md §1a)
    white = out.diagnostics.combined_sigma_white
    assert np.abs(ref[HARMONIC]).max() > 20 * white.max()  # real signal, not noise
    assert 1e-6 < white[HARMONIC].max() < 5e-6
    assert np.all(out.combined.sigma >= white * (1 - 1e-9))
    assert out.result.rank == 12  # the separation's 9 and the gyro drift's 3 (measured by the gimbal readings)
    assert 0.1 < out.result.chi2_red < 4.0


def test_corrected_calibration_removes_determined_errors():
    truth, cols = simulated_day(3)
    out = run_system_stage(ArraySource(cols), truth.site, truth.installed_calibration)
    p_before, _ = reference(truth)
    p_after = residuals_from_parameters(truth.parameters, out.result.as_dict(), truth.site.gravity)
    for name, vec in determined_combinations(truth.site.latitude).items():
        value, sigma, ok = out.separation.combinations[name]
        assert ok, name
        assert abs(vec[:12] @ p_after) < 4 * sigma, name  # what remains is noise
        assert abs(value - vec[:12] @ p_before) < 4 * sigma, name
    # the residual specific-force harmonics of the corrected calibration are small: run the stage again on the same world
    installed = {k: v for k, v in out.result.as_dict().items() if not k.startswith("gyro_drift")}  # the gyros are not compensated
    corrected = truth.with_changes(installed_calibration={**truth.installed_calibration, **installed})
    cols2 = system.simulate_system(corrected, SIDEREAL_DAY, 1.0, seed=103, earth_angle=0.9)
    again = run_system_stage(ArraySource(cols2), corrected.site, corrected.installed_calibration)
    assert np.abs(again.combined.values[1:5] / again.combined.sigma[1:5]).max() < 4.0  # x2..x5 now consistent with zero


def test_without_loop_compensation_the_attitude_coefficients_are_biased():
    """At 1e-4 rad signals the quasi-static reading misses by several 1e-6 rad (noise-free record)."""
    from stableins.estimators.system.stage import SystemOptions

    truth, cols = simulated_day(4, noise=1e-6)
    _, ref = reference(truth)
    good = run_system_stage(ArraySource(cols), truth.site, truth.installed_calibration)
    naive = run_system_stage(ArraySource(cols), truth.site, truth.installed_calibration, options=SystemOptions(compensate_loop=False))
    attitude = [i for i in HARMONIC if i >= 5]
    assert np.abs(good.combined.values - ref)[attitude].max() < 3e-7
    assert np.abs(naive.combined.values - ref)[attitude].max() > 2e-6


def test_monte_carlo_sigma():
    """The reported σ matches the scatter of the errors over several simulated days."""
    normalized = []
    for seed in range(5, 11):
        truth, cols = simulated_day(seed)
        out = run_system_stage(ArraySource(cols), truth.site, truth.installed_calibration)
        _, ref = reference(truth)
        normalized.append(((out.combined.values - ref) / out.combined.sigma)[HARMONIC])
    z = np.array(normalized)
    assert np.abs(z).max() < 4.0
    rms = float(np.sqrt(np.mean(z**2)))
    assert 0.7 < rms < 1.35, rms  # 78 normalized errors


def test_platform_not_polar_aligned_is_refused():
    """The simulator aligns the platform for a level base; on a tilted base z_p misses the pole by the tilt."""
    from stableins.errors import InputError

    truth, cols = simulated_day(12, base_attitude=(0.0, 0.01, -0.006))
    with pytest.raises(InputError, match="polar aligned|Earth rate"):
        run_system_stage(ArraySource(cols), truth.site, truth.installed_calibration)


def test_residual_k2_from_third_harmonic():
    """The simulator's residual K2 (20 µg/g²) biases the paper's coefficients; --estimate-k2 recovers K2_x, K2_y and removes it."""
    import warnings

    from stableins.errormodel import MICRO_G_PER_G2
    from stableins.estimators.system.stage import SystemOptions

    residual = {"scale_factor": 1e-4, "bias": 1e-3, "installation": 10 * ARCSEC, "nonlinearity": 20 * MICRO_G_PER_G2}
    truth = Truth.draw(3, site=SimulatedSite(sample_rate=1.0), noise=NoiseSettings(velocity_random_walk=2e-3), residual=residual)
    cols = system.simulate_system(truth, SIDEREAL_DAY, 1.0, seed=3)
    _, ref = reference(truth)
    harmonic = [i for i in HARMONIC if COMBINED_COEFFICIENTS[i] != "x1"]  # x1 also carries K2_z, not observable
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        plain = run_system_stage(ArraySource(cols), truth.site, truth.installed_calibration)
    assert any("third harmonic" in str(w.message) for w in caught)
    assert np.abs(((plain.combined.values - ref) / plain.combined.sigma)[harmonic]).max() > 5
    fixed = run_system_stage(ArraySource(cols), truth.site, truth.installed_calibration, options=SystemOptions(estimate_k2=True))
    assert np.abs(((fixed.combined.values - ref) / fixed.combined.sigma)[harmonic]).max() < 4
    for axis in "xy":
        value, sigma, status = fixed.result[f"K2_{axis}"]
        assert status == "estimated" and abs(value - truth.parameters[f"K2_{axis}"]) < 4 * sigma


def test_gyro_drift_biases_attitude_unless_known_or_measured():
    """0.001°/h of gyro drift drives the loop's Earth-rate resonance: the attitude coefficients are biased unless the drift
    is given or measured (the gimbal readings, docs/system-calibration.md §9)."""
    from stableins.estimators.system.stage import SystemOptions

    drift = {"x": 1e-3 * ARCSEC, "y": -2e-3 * ARCSEC, "z": 1.5e-3 * ARCSEC}  # 1°/h = 3600″ per 3600 s = 1″/s
    truth, cols = simulated_day(2, gyro_drift=drift)
    _, ref = reference(truth)
    plain = run_system_stage(ArraySource(cols), truth.site, truth.installed_calibration, options=SystemOptions(estimate_gyro_drift=False))
    z_plain = ((plain.combined.values - ref) / plain.combined.sigma)[HARMONIC]
    assert np.abs(z_plain[:4]).max() < 4.0  # x2..x5: the specific-force states do not see the gyros
    assert np.abs(z_plain).max() > 5.0
    assert any("gyro drift not supplied" in n for n in plain.notes)
    known = SystemOptions(known_gyro_drift=(drift["x"], drift["y"], drift["z"]))
    fixed = run_system_stage(ArraySource(cols), truth.site, truth.installed_calibration, options=known)
    assert np.abs(((fixed.combined.values - ref) / fixed.combined.sigma)[HARMONIC]).max() < 4.0
    assert "gyro_drift_x" not in fixed.result.ids  # held exactly: not a parameter of the update
    measured = run_system_stage(ArraySource(cols), truth.site, truth.installed_calibration)
    assert np.abs(((measured.combined.values - ref) / measured.combined.sigma)[HARMONIC]).max() < 4.0
    assert not any("gyro drift not supplied" in n for n in measured.notes)
    result = measured.result
    index = [result.ids.index(f"gyro_drift_{a}") for a in "xyz"]
    # x_p, y_p as the installed θ10 defines them (the platform-axis zero offset, not observable from gravity): the truth
    # turned by its residual, ε + δθ10 (e_z × ε) (noise-free angles here: σ is the model floor, 3e-11 °/h)
    true = np.array([drift[a] for a in "xyz"])
    turn = truth.parameters["theta10"] - truth.installed_calibration["theta10"]
    z = (result.values[index] - true - turn * np.cross([0.0, 0.0, 1.0], true)) / result.sigma[index]
    assert np.abs(z).max() < 4.0 and result.sigma[index].max() < 5e-5 * DEG_PER_HOUR


@pytest.mark.parametrize(("senses", "latitude_deg"), [((-1, 1, -1, 1), 40.0), ((1, 1, 1, 1), -35.0), ((-1, -1, 1, -1), 60.0)])
def test_other_gimbal_senses_and_latitudes(senses, latitude_deg):
    truth, cols = simulated_day(7, gimbal_senses=senses, latitude=math.radians(latitude_deg))
    out = run_system_stage(ArraySource(cols), truth.site, truth.installed_calibration)
    _, ref = reference(truth)
    assert np.abs(((out.combined.values - ref) / out.combined.sigma)[HARMONIC]).max() < 4.0


def test_quartz_noise_low_frequency_power_is_seen():
    """The simulator's quartz noise (bias instability, random walk) is coloured: the stage measures it and says so."""
    import warnings

    from stableins.estimators.system.stage import SystemOptions

    truth = Truth.draw(1, site=SimulatedSite(sample_rate=1.0))  # default residuals (with K2) and quartz noise
    cols = system.simulate_system(truth, SIDEREAL_DAY, 1.0, seed=1)
    _, ref = reference(truth)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        out = run_system_stage(ArraySource(cols), truth.site, truth.installed_calibration, options=SystemOptions(estimate_k2=True))
    assert any("low-frequency noise" in n for n in out.notes)
    assert out.diagnostics.z_low_frequency_ratio > 3.0
    fit = out.coloured_noise
    assert fit.detected and fit.statistic > 6.0 and fit.p_value < 1e-3
    harmonic = [i for i in HARMONIC if COMBINED_COEFFICIENTS[i] != "x1"]
    assert np.abs(((out.combined.values - ref) / out.combined.sigma)[harmonic]).max() < 4.0


@pytest.mark.slow
def test_monte_carlo_sigma_with_quartz_noise():
    """With the simulator's default quartz noise the σ built from the coloured-noise model matches the scatter.

    Without the model the normalized errors have rms ~6.7 (seeds 1-8).  With it, seeds 1-40 (480 errors): rms 1.13,
    largest 4.3, 1.0 % beyond 3σ, low-frequency noise detected in all 40 (this batch is the least favourable of seeds
    1-199: one day cannot pin the random walk, docs/system-calibration.md §1a; seeds 100-199 give 0.99).  The
    previous models gave 1.28 (threshold) and 1.08 (maximum likelihood always) on the same seeds.
    benchmarks/bench_system_sigma.py runs more seeds and the datasheet and prior modes.

    Here seeds 1-16 (192 errors; rms 1.11, largest 3.1, 0.5 % beyond 3σ).  The 12 errors of a record are correlated
    and one day's noise model is uncertain, so the spread is set by the records: the mean square of one record's 12
    has a standard deviation of 1.07 (seeds 1-40), so 16 records give σ(mean square) = 0.27 and σ(rms) ≈ 0.13 at
    rms 1: the bounds are 1 ± 2.5σ(rms).
    """
    import warnings

    from stableins.estimators.system.stage import SystemOptions

    harmonic = [i for i in HARMONIC if COMBINED_COEFFICIENTS[i] != "x1"]  # x1 also carries K2_z
    normalized = []
    for seed in range(1, 17):
        truth = Truth.draw(seed, site=SimulatedSite(sample_rate=1.0))
        cols = system.simulate_system(truth, SIDEREAL_DAY, 1.0, seed=seed)
        _, ref = reference(truth)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            out = run_system_stage(ArraySource(cols), truth.site, truth.installed_calibration, options=SystemOptions(estimate_k2=True))
        normalized.append(((out.combined.values - ref) / out.combined.sigma)[harmonic])
    z = np.array(normalized)
    rms = float(np.sqrt(np.mean(z**2)))
    assert 1.0 - 2.5 * 0.13 < rms < 1.0 + 2.5 * 0.13, rms  # 192 normalized errors (12 per record, correlated within a record)
    assert np.abs(z).max() < 6.0  # the tail left by the uncertainty of one day's amplitudes (was 8.2 with the previous model)
    assert np.mean(np.abs(z) > 3.0) < 0.02
