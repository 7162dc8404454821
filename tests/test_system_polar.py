"""The polar-alignment check of the system stage (docs/system-calibration.md §9, issue 25).

The gimbal readings give the platform's orientation in inertial space, so they tell a platform whose z_p misses the
pole (a base tilted under a platform aligned for a level one) from a gyro drift along z_p (the platform turns about its
own axis): the first is refused, the second measured, whatever the platform-axis angle's rate says.
"""

import numpy as np
import pytest

from stableins.conventions import DEG_PER_HOUR, EARTH_RATE, SIDEREAL_DAY
from stableins.data.chunks import ArraySource
from stableins.errors import InputError
from stableins.estimators.system.options import SystemOptions
from stableins.estimators.system.polar import DRIFT_TURN_LIMIT, RATE_TOLERANCE_UNCHECKED, PolarAlignment, check_polar_alignment
from stableins.estimators.system.stage import run_system_stage
from tests.test_system_recovery import HARMONIC, reference, simulated_day

TILTED = (0.0, 0.01, -0.006)  # the base's attitude; the simulator aligns the platform for a level base: 0.0117 rad off


def _polar(start, end, drift=(0.0, 0.0, 0.0)):
    return PolarAlignment(np.array(start), np.array(end), np.array([1e-9, 1e-9]), 86164.0, np.array(drift))


def test_check_refuses_a_misalignment_names_an_equatorial_drift_and_holds_the_rate_without_readings():
    options = SystemOptions()
    check_polar_alignment(_polar((2e-4, -3e-4), (2e-4, -3e-4)), 1.0 + 0.05 * DEG_PER_HOUR / EARTH_RATE, options, "r.h5")
    with pytest.raises(InputError, match="not polar aligned") as tilt:
        check_polar_alignment(_polar((1.2e-3, 0.0), (1.2e-3, 0.0)), 1.0, options, "r.h5")
    assert tilt.value.field == "angle_inner/angle_middle" and "base tilted" in str(tilt.value)
    # a measured equatorial drift is calibrated through up to DRIFT_TURN_LIMIT (the stage removes its response) ...
    drift = 0.05 * DEG_PER_HOUR
    check_polar_alignment(_polar((2e-4, 0.0), (2e-4, drift * 86164.0), (drift, 0.0, 0.0)), 1.0, options, "r.h5")
    # ... not beyond it, nor when its response is not removed (the drift not estimated), nor with z_p off at the start
    for drift_per_hour, removed, start in ((0.15, True, 0.0), (0.005, False, 0.0), (0.05, True, 1.2e-3)):
        drift = drift_per_hour * DEG_PER_HOUR
        polar = _polar((start, 0.0), (start, drift * 86164.0), (drift, 0.0, 0.0))
        with pytest.raises(InputError, match="not polar aligned") as turning:
            check_polar_alignment(polar, 1.0, options, "r.h5", drift_removed=removed)
        assert ("base tilted" if start else f"+{drift_per_hour:g}") in str(turning.value)
        assert start or f"{(DRIFT_TURN_LIMIT if removed else 5e-4) * 1e3:.3g} mrad" in str(turning.value)
    # without the inner and middle readings the rate is the only sign of a tilt: 2e-3 (0.03 °/h along z_p)
    check_polar_alignment(None, 1.0 + 0.02 * DEG_PER_HOUR / EARTH_RATE, options, "r.h5")
    with pytest.raises(InputError, match="not measured") as rate:
        check_polar_alignment(None, 1.0 + 0.05 * DEG_PER_HOUR / EARTH_RATE, options, "r.h5")
    assert rate.value.field == "angle_platform" and f"{RATE_TOLERANCE_UNCHECKED:g}" in str(rate.value)


def test_a_tilted_base_is_refused_by_the_polar_alignment():
    """0.0117 rad of tilt: the rate moves by −2.6e-3 (inside the 0.05 tolerance), the readings see z_p 10.7 mrad off."""
    truth, cols = simulated_day(12, base_attitude=TILTED)
    with pytest.raises(InputError, match="not polar aligned") as err:
        run_system_stage(ArraySource(cols), truth.site, truth.installed_calibration)
    assert "base tilted" in str(err.value) and "10.7" in str(err.value)


def test_a_realistic_z_gyro_drift_is_measured_not_refused():
    """0.05 °/h along z_p (Cai et al.'s figure before calibration): the rate is 1 + 3.3e-3, z_p stays on the pole.

    Without the inner and middle readings the polar alignment is not measured, and the rate is held to 2e-3.
    """
    drift = 0.05 * DEG_PER_HOUR
    truth, cols = simulated_day(12, gyro_drift={"z": drift})
    out = run_system_stage(ArraySource(cols), truth.site, truth.installed_calibration)
    diagnostics = out.diagnostics
    assert abs(diagnostics.platform_rate_ratio - 1.0) == pytest.approx(drift / EARTH_RATE, rel=1e-3)
    assert diagnostics.polar_misalignment < 1e-4  # the installed zero offsets' residuals, a few arcsec
    assert any(n.startswith("polar alignment from the gimbal readings") for n in out.notes)
    value, sigma, _ = out.result["gyro_drift_z"]
    assert abs(value - drift) < 4 * sigma and sigma < 1e-4 * drift
    _, ref = reference(truth)
    assert np.abs(((out.combined.values - ref) / out.combined.sigma)[HARMONIC]).max() < 4.0
    bare = {k: v for k, v in cols.items() if k not in ("angle_inner", "angle_middle")}
    with pytest.raises(InputError, match="not measured"):
        run_system_stage(ArraySource(bare), truth.site, truth.installed_calibration)


def test_an_equatorial_drift_that_turns_z_p_off_the_pole_is_measured_not_refused():
    """0.05 °/h along x_p (Cai et al.'s figure before calibration, uncompensated) turns z_p 20.9 mrad off the pole in a
    day and drives the velocity error to 9.7 m/s: the readings measure it, its response (second order included) is
    removed, and the static-base checks the pass kept are explained by it, not refused."""
    drift = 0.05 * DEG_PER_HOUR
    truth, cols = simulated_day(12, gyro_drift={"x": drift})
    assert np.abs(np.hypot(cols["velocity_north"], cols["velocity_east"])).max() > 5.0  # beyond velocity_limit
    out = run_system_stage(ArraySource(cols), truth.site, truth.installed_calibration)
    assert any(n.startswith("the measured equatorial gyro drift explains") for n in out.notes)
    value, sigma, _ = out.result["gyro_drift_x"]
    assert abs(value - drift) < 1e-4 * drift and sigma < 1e-5 * drift
    _, ref = reference(truth)
    assert np.abs(((out.combined.values - ref) / out.combined.sigma)[HARMONIC]).max() < 4.0
    # with the drift not estimated its response is not removed: the velocity refusal the pass kept stands
    with pytest.raises(InputError, match="not static"):
        run_system_stage(ArraySource(cols), truth.site, truth.installed_calibration, options=SystemOptions(estimate_gyro_drift=False))


@pytest.mark.slow
def test_cli_gyro_z_and_gyro_worlds_run(tmp_path, capsys):
    """`simulate system --world gyro-z` and `--world gyro` (0.05 °/h on every axis, uncompensated: z_p leaves the pole
    by 1.2° in the day), `calibrate system`, `diagnose`: exit 0, no traceback; the gyro world's note says the measured
    drift explains what the static-base checks saw."""
    from stableins import cli
    from stableins.data.truth import load_truth
    from tests.test_system_cli import prior_record

    for name in ("gyro-z", "gyro"):
        sim = tmp_path / name
        assert cli.main(["simulate", "system", "--world", name, "--seed", "3", "--rate", "1", "--out", str(sim)]) == 0
        prior = tmp_path / f"{name}-prior.json"
        prior_record(load_truth(sim / "truth.json").installed_calibration, serial="SIM-3").save(prior)
        out = tmp_path / f"{name}-cal.json"
        capsys.readouterr()
        assert cli.main(["calibrate", "system", str(sim / "system.h5"), "--prior", str(prior), "--out", str(out)]) == 0
        captured = capsys.readouterr()
        assert "Traceback" not in captured.err
        assert "gyro drift from the gimbal readings" in captured.out
        assert ("the measured equatorial gyro drift explains" in captured.out) is (name == "gyro")
        assert cli.main(["diagnose", str(sim / "system.h5"), "--record", str(out)]) == 0


def _twin_days(rate: float, drift: dict[str, float], seed: int = 12) -> tuple[dict, dict]:
    """One sidereal day with ``drift`` and without it: the same instrument, its installed calibration exact, no noise."""
    from stableins.simulator import system
    from stableins.simulator.noise import NoiseSettings
    from stableins.simulator.truth import SimulatedSite, Truth

    truth = Truth.draw(seed, site=SimulatedSite(sample_rate=rate), noise=NoiseSettings())
    truth = truth.with_changes(installed_calibration=dict(truth.parameters))
    days = [
        system.simulate_system(truth.with_changes(gyro_drift=d), SIDEREAL_DAY, rate, seed=seed, earth_angle=0.3, include_truth=True)
        for d in (drift, {})
    ]
    return days[0], days[1]


def test_the_drift_curvature_is_the_attitude_outputs_second_order():
    """0.05 °/h across z_p: the azimuth error φ_D reaches 0.027 rad and the pitch and roll outputs depart from the loop
    model's (−φ_E, −φ_N) by φ_D φ_N, φ_D φ_E (5e-6, 1.7e-5 rad); the even part of the exact map leaves < 5e-7."""
    from stableins.estimators.system.loop import drift_curvature

    drifting, still = _twin_days(0.1, {"x": 0.05 * DEG_PER_HOUR})
    phi = np.stack([drifting[f"truth_phi_{n}"] - still[f"truth_phi_{n}"] for n in ("north", "east", "down")], axis=1)
    assert np.abs(phi[:, 2]).max() > 0.02
    linear = np.stack([-phi[:, 1], -phi[:, 0]], axis=1)
    output = np.stack([drifting["pitch"] - still["pitch"], drifting["roll"] - still["roll"]], axis=1)
    curvature = drift_curvature(phi, 0.0)
    assert np.abs(output - linear).max() > 4e-6
    assert np.abs(output - linear - curvature).max() < 5e-7
    assert np.abs(drift_curvature(-phi, 0.0) - curvature).max() < 1e-15  # even in φ


def test_the_loop_predicts_the_misalignment_a_drift_builds():
    """The loop model's angle responses (what :func:`.loop.drift_curvature_removed` takes the curvature of) against the
    simulator's error states: φ_N, φ_E, φ_D of 0.05 °/h along x_p and y_p to 1 % of the largest."""
    from stableins.estimators.system.loop import ANGLE_STATES, DampingLoop, drift_columns
    from stableins.simulator.truth import Truth

    drift = np.array([0.03, -0.04, 0.0]) * DEG_PER_HOUR
    drifting, still = _twin_days(0.1, {"x": drift[0], "y": drift[1]})
    phi = np.stack([drifting[f"truth_phi_{n}"] - still[f"truth_phi_{n}"] for n in ("north", "east", "down")], axis=1)
    site = Truth.draw(12).site
    loop = DampingLoop.from_metadata(site.damping, site.latitude, site.gravity)  # as the stage builds it from the metadata
    t = drifting["time"]
    angle = 0.3 + EARTH_RATE * t
    blocks = {"time": t, "cos": np.cos(angle), "sin": np.sin(angle)}
    predicted = drift_columns(blocks, loop, states=ANGLE_STATES) @ (drift / 1e-8)
    assert np.abs(predicted - phi).max() < 0.01 * np.abs(phi).max()


def test_the_g_sensitive_turn_is_composed_out_of_the_gimbal_readings():
    """0.05 °/h on x_p and y_p tilt z_p 29.5 mrad in a day; an anisotropic D_g (its Earth-rate wobble turns partly the other
    way than the base-fixed nuisance ω_b, and the tilt ramps D_g f^p) puts 1e-4 °/h into ε_x, ε_y of a fit that ignores
    it; with the record's D_g composed out (``g_sensitive_turn``) the fit returns the drift the record sees,
    ``ε^p + D_g f̄^p`` (f̄^p the specific force along the Earth's axis), to the model's accuracy."""
    from stableins.conventions import DEG_PER_HOUR_PER_G, GimbalConfiguration, earth_rate_nav
    from stableins.estimators.system.gyro_drift import fit_gimbal_drift
    from stableins.simulator import system
    from stableins.simulator.noise import NoiseSettings
    from stableins.simulator.truth import SimulatedSite, Truth

    drift = {"x": 0.05 * DEG_PER_HOUR, "y": 0.05 * DEG_PER_HOUR}
    per_g = {"Dg_xx": 0.001, "Dg_yy": 0.0005, "Dg_xy": 0.0003, "Dg_zx": 0.0002, "Dg_zz": 0.001}
    effects = {k: v * DEG_PER_HOUR_PER_G for k, v in per_g.items()}
    truth = Truth.draw(3, site=SimulatedSite(sample_rate=0.1), noise=NoiseSettings(), effects=effects, gyro_drift=drift)
    cols = system.simulate_system(truth, SIDEREAL_DAY, 0.1, seed=3)
    blocks = {"time": cols["time"], "count": np.ones(cols["time"].size)}
    blocks |= {name: cols[f"angle_{name}"] for name in ("platform", "inner", "middle")}
    site = truth.site
    offsets = np.array([truth.parameters[k] for k in ("theta10", "theta20", "theta30")])
    sensitivity = np.array([[effects.get(f"Dg_{a}{b}", 0.0) for b in "xyz"] for a in "xyz"])
    config = GimbalConfiguration(site.gimbal_senses)
    plain = fit_gimbal_drift(blocks, site.latitude, config, offsets=offsets, base_attitude=site.base_attitude)
    fit = fit_gimbal_drift(
        blocks, site.latitude, config, offsets=offsets, base_attitude=site.base_attitude, g_sensitivity=sensitivity, gravity=site.gravity
    )
    start = system.SystemWorld(truth, 0.1).nav_to_platform_0  # the specific force along the Earth's axis, platform frame
    axis = start @ (earth_rate_nav(site.latitude) / EARTH_RATE)
    seen = np.array([drift["x"], drift["y"], 0.0]) + sensitivity @ ((axis @ start[:, 2]) * -site.gravity * axis)
    assert np.abs(plain.values - seen).max() / DEG_PER_HOUR > 5e-5  # measured 5.1e-5, −7.2e-5 °/h
    assert np.abs(fit.values - seen).max() / DEG_PER_HOUR < 1e-9  # measured 2e-11 °/h (no angle noise; σ 1.3e-8 °/h)


def test_an_error_of_the_records_g_sensitivity_is_in_the_drifts_sigma():
    """An error of the record's ``D_g`` that wobbles against the base-fixed nuisance (``Dg_xx − Dg_yy``) leaks into
    ``ε_x``, ``ε_y``; the record's σ of ``Dg_ax``, ``Dg_ay`` as the prior of nuisance columns puts it in σ(ε)."""
    from stableins.conventions import DEG_PER_HOUR_PER_G, GimbalConfiguration, earth_rate_nav
    from stableins.estimators.system.gyro_drift import fit_gimbal_drift
    from stableins.simulator import system
    from stableins.simulator.noise import NoiseSettings
    from stableins.simulator.truth import SimulatedSite, Truth

    drift = {"z": 0.05 * DEG_PER_HOUR}
    sensitivity = np.eye(3) * 0.001 * DEG_PER_HOUR_PER_G
    effects = {f"Dg_{a}{a}": sensitivity[0, 0] for a in "xyz"}
    truth = Truth.draw(4, site=SimulatedSite(sample_rate=0.1), noise=NoiseSettings.quartz(), effects=effects, gyro_drift=drift)
    cols = system.simulate_system(truth, SIDEREAL_DAY, 0.1, seed=4)
    blocks = {"time": cols["time"], "count": np.ones(cols["time"].size)}
    blocks |= {name: cols[f"angle_{name}"] for name in ("platform", "inner", "middle")}
    site = truth.site
    offsets = np.array([truth.parameters[k] for k in ("theta10", "theta20", "theta30")])
    sigma = np.full((3, 3), 1e-4 * DEG_PER_HOUR_PER_G)
    recorded = sensitivity + np.diag([1.0, -1.0, 0.0]) * sigma  # 1σ each way: the wobble's counter-rotating part
    config = GimbalConfiguration(site.gimbal_senses)
    common = {"offsets": offsets, "base_attitude": site.base_attitude, "g_sensitivity": recorded, "gravity": site.gravity}
    without = fit_gimbal_drift(blocks, site.latitude, config, **common)
    with_sigma = fit_gimbal_drift(blocks, site.latitude, config, **common, g_sensitivity_sigma=sigma)
    start = system.SystemWorld(truth, 0.1).nav_to_platform_0
    axis = start @ (earth_rate_nav(site.latitude) / EARTH_RATE)
    axial = (axis @ start[:, 2]) * -site.gravity * axis
    seen = np.array([0.0, 0.0, drift["z"]]) + sensitivity @ axial
    assert np.abs((without.values - seen) / without.sigma).max() > 5  # measured 10.3 (4.5e-5 °/h on ε_x)
    assert np.all(np.abs((with_sigma.values - seen) / with_sigma.sigma) < 3)  # measured 0.84, 0.03, 1.10
    assert with_sigma.sigma.max() / DEG_PER_HOUR < 1e-6  # the data measure the wobble too: 2.3e-7 °/h (no σ: 4.4e-6)
