"""System-level world: Earth-rate kinematics, INS error dynamics, damping, reproducibility."""

import numpy as np
import pytest
from scipy.linalg import expm

from stableins import conventions as cv
from stableins.schema import SYSTEM_COLUMNS
from stableins.simulator.error_dynamics import ModalRecursion, error_dynamics
from stableins.simulator.noise import NoiseSettings
from stableins.simulator.system import SystemWorld, simulate_system
from stableins.simulator.truth import SimulatedSite, Truth

DEG_H = np.pi / 180 / 3600


def ideal(seed=3, senses=(1, 1, 1, 1), **changes):
    """Noise-free truth whose installed calibration equals the truth."""
    t = Truth.draw(seed, noise=NoiseSettings.quiet(), site=SimulatedSite(gimbal_senses=senses))
    return t.with_changes(installed_calibration=dict(t.parameters), **changes)


def with_residual(truth, **residual):
    installed = dict(truth.parameters)
    for key, value in residual.items():
        installed[key] = truth.parameters[key] - value
    return truth.with_changes(installed_calibration=installed)


def harmonic(t, y, order=1):
    """Mean and cosine/sine coefficients at ``order`` times the Earth rate, by least squares."""
    w = order * cv.EARTH_RATE
    x = np.column_stack([np.ones_like(t), np.cos(w * t), np.sin(w * t)])
    return np.linalg.lstsq(x, y, rcond=None)[0]


@pytest.mark.parametrize("senses", [(1, 1, 1, 1), (-1, 1, -1, 1)])
def test_platform_reading_follows_earth_rate_and_specific_force_is_eq19(senses):
    base = ideal(senses=senses)
    offsets = {k: v for k, v in base.parameters.items() if k.startswith("theta")}
    truth = base.with_changes(parameters=offsets, installed_calibration=offsets)  # ideal accelerometers
    d = simulate_system(truth, 6 * 3600, rate=0.05, earth_angle=0.3)
    slope = np.polyfit(d["time"], d["angle_platform"], 1)[0]
    assert slope == pytest.approx(-senses[0] * cv.EARTH_RATE, rel=1e-9)
    earth_angle = cv.earth_rate_angle(d["angle_platform"] + offsets["theta10"], cv.GimbalConfiguration(senses))
    np.testing.assert_allclose(earth_angle, 0.3 + cv.EARTH_RATE * d["time"], atol=1e-12)
    g, lat = truth.site.gravity, truth.site.latitude
    expected = g * np.column_stack(
        [np.cos(earth_angle) * np.cos(lat), np.sin(earth_angle) * np.cos(lat), np.full_like(earth_angle, np.sin(lat))]
    )
    np.testing.assert_allclose(np.column_stack([d["f_x"], d["f_y"], d["f_z"]]), expected, atol=1e-13)
    # inner and middle gimbals hold the polar alignment
    np.testing.assert_allclose(d["angle_inner"] + offsets["theta20"], 0.0, atol=1e-14)
    np.testing.assert_allclose(d["angle_middle"] + offsets["theta30"], senses[2] * (np.pi / 2 + lat), atol=1e-14)


def test_perfectly_calibrated_ins_shows_no_errors():
    truth = ideal()
    d = simulate_system(truth, 86400, rate=0.02)
    assert list(d) == [c.name for c in SYSTEM_COLUMNS]
    for name in ("velocity_north", "velocity_east", "velocity_down", "roll", "pitch", "heading"):
        assert np.abs(d[name]).max() < 1e-12, name
    assert {"zeta", "omega_s", "R", "k1", "k2", "k3"} <= set(truth.site.damping)


def test_constant_bias_residual_gives_pitch_plus_df_north_over_g():
    b = 1e-4  # true minus installed z bias [m/s^2]; on the polar axis it is constant in NED
    truth = with_residual(ideal(), bias_z=b)
    d = simulate_system(truth, 2 * 86400, rate=0.02, include_truth=True)
    g, lat = truth.site.gravity, truth.site.latitude
    late = d["time"] > 86400
    df_north = d["truth_df_north"][late]
    np.testing.assert_allclose(df_north, b * np.cos(lat), rtol=1e-3)  # SF, K2, beta of the instrument: ~1e-4
    np.testing.assert_allclose(d["pitch"][late], df_north / g, rtol=2e-3)  # pitch error = +Δf_N/g
    assert np.abs(d["roll"][late]).max() < 1e-3 * b / g
    # vertical damping: Δf_D is absorbed, the vertical velocity error dies out
    vd = d["velocity_down"]
    assert np.abs(vd).max() > 1e-3 and np.abs(vd[late]).max() < 1e-5 * np.abs(vd).max()


def complex_amplitude(t, y, order):
    """``a`` with ``y ≈ mean + Re(a e^{i order Ω t})``."""
    _, c, s = harmonic(t, y, order)
    return c - 1j * s


@pytest.mark.parametrize(("residual", "order", "lag_deg"), [({"bias_x": 1e-4}, 1, 3.38), ({"sf_x": 1e-4}, 2, 6.80)])
def test_earth_rate_harmonics_lag_by_the_damped_schuler_loop(residual, order, lag_deg):
    # x bias: 24 h harmonic of the n-frame force error; x scale factor (f_x ∝ cos St): 12 h harmonic
    truth = with_residual(ideal(), **residual)
    d = simulate_system(truth, 3 * 86400, rate=0.05, include_truth=True)
    g = truth.site.gravity
    late = d["time"] > 86400
    t = d["time"][late]
    damping = truth.site.damping
    r = order * cv.EARTH_RATE / damping["omega_s"]
    lag = np.arctan2(2 * damping["zeta"] * r, 1 - r**2)
    gain = 1 / np.hypot(1 - r**2, 2 * damping["zeta"] * r)
    assert np.degrees(lag) == pytest.approx(lag_deg, abs=0.05)
    force = {k: complex_amplitude(t, d[f"truth_df_{k}"][late] / g, order) for k in ("north", "east", "down")}
    attitude = {"pitch": complex_amplitude(t, d["pitch"][late], order), "roll": complex_amplitude(t, d["roll"][late], order)}
    # per-channel damped Schuler loop: pitch ≈ H Δf_N/g, roll ≈ −H Δf_E/g
    for name, f in (("pitch", force["north"]), ("roll", -force["east"])):
        assert np.angle(f / attitude[name]) == pytest.approx(lag, abs=np.radians(0.1)), name
        assert abs(attitude[name] / f) == pytest.approx(gain, rel=2e-2), name
    if order == 2:
        # off the 24 h resonance the full coupled model's frequency response predicts the harmonic exactly,
        # including the ~1 % cross-channel coupling through the Earth-rate terms
        A, B = error_dynamics(truth.site.latitude, damping)
        response = np.linalg.solve(1j * order * cv.EARTH_RATE * np.eye(9) - A, B[:, :3]) * g
        forcing = np.array([force["north"], force["east"], force["down"]])
        predicted = {"pitch": -response[4] @ forcing, "roll": -response[3] @ forcing}
        for name in ("pitch", "roll"):
            assert abs(attitude[name] - predicted[name]) < 2e-3 * abs(attitude[name]), name


def test_equatorial_gyro_drift_makes_heading_error_grow():
    eps = 0.001 * DEG_H
    truth = ideal().with_changes(gyro_drift={"x": eps})
    d = simulate_system(truth, 3 * 86400, rate=0.01, include_truth=True)
    t, heading = d["time"], d["heading"]
    day = [np.abs(heading[(t >= k * 86400) & (t < (k + 1) * 86400)]).max() for k in range(3)]
    assert day[0] < day[1] < day[2]  # resonance of the 24 h mode: grows like t sin(Ω t)
    assert day[2] > 2 * day[0]
    # heading output of a level north base is -phi_D (conventions.attitude_error_from_misalignment)
    phi = np.column_stack([d["truth_phi_north"], d["truth_phi_east"], d["truth_phi_down"]])
    expected = cv.attitude_error_from_misalignment(phi)
    np.testing.assert_allclose(np.column_stack([heading, d["pitch"], d["roll"]]), expected, atol=1e-12 + 1e-6 * np.abs(expected).max())
    twice = simulate_system(ideal().with_changes(gyro_drift={"x": 2 * eps}), 3 * 86400, rate=0.01)
    np.testing.assert_allclose(twice["heading"], 2 * heading, atol=1e-3 * np.abs(heading).max())


def test_gimbal_offset_residual_is_a_constant_attitude_error():
    d_theta = 5e-6
    truth = with_residual(ideal(), theta20=d_theta)
    d = simulate_system(truth, 86400, rate=0.01)
    # computer thinks the inner angle is smaller than it is: a constant rotation, not growing
    errors = np.column_stack([d["roll"], d["pitch"], d["heading"]])
    assert np.ptp(errors, axis=0).max() < 1e-3 * d_theta
    assert np.linalg.norm(errors[0]) == pytest.approx(d_theta, rel=1e-3)


def test_modal_recursion_matches_direct_zoh_recursion():
    truth = ideal()
    A, B = error_dynamics(truth.site.latitude, truth.site.damping)
    dt = 0.5
    m = expm(np.block([[A, B], [np.zeros((6, 15))]]) * dt)
    phi, gamma = m[:9, :9], m[:9, 9:]
    rng = np.random.default_rng(1)
    u = rng.standard_normal((3000, 6)) * [1e-4, 1e-4, 1e-4, 1e-8, 1e-8, 1e-8]
    x0 = rng.standard_normal(9) * 1e-6
    rec = ModalRecursion.discretize(A, B, dt)
    x_modal, _ = rec.run(u, rec.to_modes @ x0)
    x, direct = x0.copy(), []
    for k in range(len(u)):
        direct.append(x)
        x = phi @ x + gamma @ u[k]
    direct = np.array(direct)
    assert np.all(np.abs(x_modal - direct) <= 1e-9 * np.abs(direct).max(axis=0))


def test_record_does_not_depend_on_chunk_size():
    truth = Truth.draw(5, gyro_drift={"x": 1e-9, "case_amplitude": 1e-8}, effects={"Dg_xx": 1e-9, "Kt_bias_x": 1e-5, "nonorth_12": 2e-5})
    a = simulate_system(truth, 200, rate=100, chunk_samples=1 << 16)
    b = simulate_system(truth, 200, rate=100, chunk_samples=7777)
    for name in a:
        assert np.array_equal(a[name], b[name]), name
    c = simulate_system(truth, 200, rate=100, seed=99)
    assert not np.array_equal(a["f_x"], c["f_x"])


def test_world_reports_the_damping_it_uses():
    truth = Truth.draw(1).with_changes(damping={"zeta": 0.7})
    world = SystemWorld(truth)
    d = truth.site.damping
    assert d["zeta"] == 0.7 and world.damping["horizontal_gain"] == pytest.approx(2 * 0.7 * np.sqrt(truth.site.gravity / cv.EARTH_RADIUS))
    # vertical loop poles: -a and -a/2 ± i a√3/2
    poles = np.sort_complex(np.roots([1, d["k1"], d["k2"] - 2 * d["omega_s"] ** 2, d["k3"]]))
    a = 1 / d["vertical_time_constant"]
    np.testing.assert_allclose(
        np.sort_complex(np.array([-a, -a / 2 + 1j * a * np.sqrt(3) / 2, -a / 2 - 1j * a * np.sqrt(3) / 2])), poles, atol=1e-12
    )


def test_perfect_ins_reports_the_true_base_attitude_with_tilt_and_azimuth_error():
    effects = {"azimuth_error": 1e-4, "tilt_north": 2e-5, "tilt_east": -3e-5}
    truth = ideal().with_changes(effects=effects)
    d = simulate_system(truth, 6 * 3600, rate=0.01)
    true_yaw, true_pitch, true_roll = cv.euler_from_dcm(truth.platform().dcm_nav_to_body())
    np.testing.assert_allclose(d["heading"], true_yaw, atol=1e-12)
    np.testing.assert_allclose(d["pitch"], true_pitch, atol=1e-12)
    np.testing.assert_allclose(d["roll"], true_roll, atol=1e-12)
    # the platform, aligned for a level north base, is off the pole: f_z now varies over the day
    assert np.ptp(d["f_z"]) > 1e-5 * truth.site.gravity


def test_white_noise_drives_the_damped_velocity_error_as_theory_says():
    # δv = s/(s² + c s + ω_s²) · w with two-sided PSD N² ⇒ var(δv) = N²/(2c) (per horizontal channel)
    vrw = 1e-3
    variances = []
    for seed in range(4):
        truth = ideal().with_changes(noise=NoiseSettings(velocity_random_walk=vrw))
        d = simulate_system(truth, 3 * 86400, rate=0.5, seed=seed)
        settled = d["time"] > 20000
        variances += [np.var(d["velocity_north"][settled]), np.var(d["velocity_east"][settled])]
    expected = vrw**2 / (2 * truth.site.damping["horizontal_gain"])
    variances = np.array(variances)
    assert abs(variances.mean() - expected) < 4 * variances.std(ddof=1) / np.sqrt(len(variances))


def test_system_quantization_error_does_not_accumulate():
    lsb = 1e-4
    base = ideal()
    quantized = base.with_changes(noise=NoiseSettings(quantization=lsb))
    a = simulate_system(base, 1000.0, rate=100, chunk_samples=9999)
    b = simulate_system(quantized, 1000.0, rate=100, chunk_samples=9999)
    assert len(a["f_x"]) > 5 * 16384  # several noise blocks
    for axis in ("f_x", "f_y", "f_z"):
        velocity_error = np.cumsum(b[axis] - a[axis]) / 100.0
        assert np.abs(velocity_error).max() <= lsb * (1 + 1e-6), axis


def test_platform_drift_integrates_the_gyro_drift_including_case_rotation():
    drift = {"x": 2e-9, "y": -1e-9, "z": 3e-9, "case_amplitude": 1e-7, "case_period": 480.0, "case_phase": 0.4}
    world = SystemWorld(ideal().with_changes(gyro_drift=drift), rate=10.0)
    t = np.linspace(0.0, 2000.0, 4001)
    h = 1e-3
    rate = (world._drift_angle(t + h) - world._drift_angle(t - h)) / (2 * h)
    np.testing.assert_allclose(rate, -world.gyro_drift(t), atol=1e-15)  # the platform turns at -ε^p
    np.testing.assert_allclose(world._drift_angle(np.array([0.0])), 0.0, atol=0)
    # the case-rotation residual is a drift vector of the given amplitude turning about z_p once per period
    eps = world.gyro_drift(t)
    np.testing.assert_allclose(np.hypot(eps[:, 0] - 2e-9, eps[:, 1] + 1e-9), 1e-7, rtol=1e-12)
    # and the gimbal readings follow the drifting platform: a 480 s wobble of about a·P/(2π)
    d = simulate_system(ideal().with_changes(gyro_drift={"case_amplitude": 1e-7}), 1920.0, rate=1.0)
    amplitude = 1e-7 * 480.0 / (2 * np.pi)
    for name in ("angle_inner", "angle_middle"):  # the Earth turns the platform by only 8° in 32 min
        assert np.ptp(d[name]) / 2 == pytest.approx(amplitude, rel=0.1), name


def test_specific_force_error_matches_the_first_order_system_level_states():
    # Independent first-order derivation (docs/paper-notes, Wu et al. 2018 Eqs. 21-27 with signs restored):
    # z = (|f̂^p|² − |f^p|²)/(2g²) = H x,  H = [1, f_x/g, f_y/g, (f_x² − f_y²)/g², 2 f_x f_y/g²]
    from stableins.errormodel import ErrorModel

    truth = Truth.draw(11, noise=NoiseSettings.quiet(), nonlinear=False)
    installed = dict(truth.installed_calibration)
    installed.update({k: truth.parameters[k] for k in ("theta10", "theta20", "theta30")})
    truth = truth.with_changes(installed_calibration=installed)
    d = simulate_system(truth, 86400, rate=0.02)
    g, lat = truth.site.gravity, truth.site.latitude
    f_hat = ErrorModel.standard(nonlinear=False).inverse(np.column_stack([d["f_x"], d["f_y"], d["f_z"]]), installed)
    st = cv.earth_rate_angle(d["angle_platform"] + truth.parameters["theta10"])
    fx, fy = np.cos(st) * np.cos(lat), np.sin(st) * np.cos(lat)
    z = 0.5 * (np.sum(f_hat**2, axis=1) / g**2 - 1.0)
    h = np.column_stack([np.ones_like(st), fx, fy, fx**2 - fy**2, 2 * fx * fy])
    x = np.linalg.lstsq(h, z, rcond=None)[0]
    r = truth.calibration_residual()
    dsf = {a: r[f"sf_{a}"] / truth.parameters[f"sf_{a}"] for a in "xyz"}
    b = {a: r[f"bias_{a}"] / g for a in "xyz"}
    sl, cl = np.sin(lat), np.cos(lat)
    expected = [
        -(dsf["x"] + dsf["y"]) / 2 * cl**2 - dsf["z"] * sl**2 + b["z"] * sl,
        b["x"] - r["beta_xy"] * sl + r["beta_zy"] * sl,
        b["y"] + r["beta_yx"] * sl - r["beta_zx"] * sl,
        -(dsf["x"] - dsf["y"]) / 2,
        (r["beta_xz"] - r["beta_yz"]) / 2,
    ]
    assert np.max(np.abs(expected)) > 1e-6  # a real residual
    np.testing.assert_allclose(x, expected, atol=1e-8)  # second-order terms ~ residual × parameters


def test_g_sensitivity_turns_the_platform_and_drives_the_attitude_error_alike():
    """System level: ``D_g f^p`` is a gyro error: the platform turns at ``−D_g f^p`` and ``φ' = −C_p^n D_g f^p``."""
    from stableins.platform import rotation_vector

    effects = {"Dg_xz": 3e-8, "Dg_yz": -2e-8, "Dg_zz": 4e-8, "Dg_xy": 1e-8}
    truth = ideal().with_changes(effects=effects)
    world, still = SystemWorld(truth, rate=10.0), SystemWorld(ideal(), rate=10.0)
    d, s = world.chunk(201, include_truth=True), still.chunk(201)
    t = d["time"]
    g_matrix = np.array([[effects.get(f"Dg_{a}{b}", 0.0) for b in "xyz"] for a in "xyz"])
    start = world.nav_to_platform_0
    f_p = -truth.site.gravity * start[:, 2]
    expected_rate = -(g_matrix @ f_p)  # conventions.platform_drift_rate with ε = 0

    # the platform, as its readings show it: after 20 s it has turned by w t from where the drift-free one is
    def nav_to_platform(columns, k):
        readings = np.array([columns[f"angle_{g}"][k] for g in ("platform", "inner", "middle")])
        return world.platform.dcm_body_to_platform(readings) @ world.nav_to_body

    turned = rotation_vector(nav_to_platform(d, -1) @ nav_to_platform(s, -1).T)
    np.testing.assert_allclose(turned, expected_rate * t[-1], rtol=1e-3, atol=1e-13)
    # the navigation computer's attitude error is driven by the same gyro error, in the local frame
    phi = np.stack([d[f"truth_phi_{n}"] for n in ("north", "east", "down")], axis=-1)
    rate = (phi[-1] - phi[0]) / (t[-1] - t[0])
    middle = still.platform_orientation(t[[100]])[0]  # C_n^p turns with the Earth (1.5e-3 rad in 20 s): mid-point rule
    f_middle = -truth.site.gravity * middle[:, 2]
    # the Earth-rate couplings (Ω φ ≈ Ω t/2 relative: 7e-4 over 20 s) are the only difference
    np.testing.assert_allclose(rate, middle.T @ (-(g_matrix @ f_middle)), rtol=2e-3, atol=1e-14)


def test_g_sensitive_drift_composes_with_the_drift_exactly_in_the_polar_world():
    """The polar world's platform obeys ``Ẋ = −[w×] X``, ``w = −(ε^p + D_g f^p)``, ``f^p`` of the drifted orientation.

    Against an RK4 integration of that equation (independent of the world's factorization ``X = rot(−ε t) Z``):
    a z_p drift of 0.5 °/h with ``D_g`` 0.01 °/h/g on the diagonal for 6 h.  Summing the two angles (the world
    before issue 25's fix) leaves up to ``ε_z A t`` (``A = g cosL D/Ω`` the wobble, ``ε_z A t`` = 2.7e-5 rad here;
    measured 5.3e-6 rad at the end); composed, the world agrees to 6e-11 rad (the trapezoid rule on a 10-s clock).
    """
    from stableins.platform import rotation_vector

    d = 0.01 * cv.DEG_PER_HOUR_PER_G
    truth = ideal().with_changes(gyro_drift={"z": 0.5 * cv.DEG_PER_HOUR}, effects={"Dg_xx": d, "Dg_yy": d, "Dg_zz": d})
    world = SystemWorld(truth, rate=0.1)
    time = np.arange(2161) * 10.0
    dcm = world._g_sensitive_orientation(time)
    eps = np.array([0.0, 0.0, 0.5 * cv.DEG_PER_HOUR])
    start, axis = world.nav_to_platform_0, cv.skew(cv.earth_rate_nav(world.latitude) / cv.EARTH_RATE)

    def held(t):
        angle = cv.EARTH_RATE * t
        return start @ (np.eye(3) + np.sin(angle) * axis + (1.0 - np.cos(angle)) * axis @ axis)

    def rate(t, x):
        f_p = x @ held(t) @ np.array([0.0, 0.0, -world.gravity])
        return -cv.skew(-(eps + d * f_p)) @ x

    x, h = np.eye(3), 10.0
    for t in time[:-1]:
        k1 = rate(t, x)
        k2 = rate(t + h / 2, x + h / 2 * k1)
        k3 = rate(t + h / 2, x + h / 2 * k2)
        k4 = rate(t + h, x + h * k3)
        x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    error = rotation_vector(dcm[-1] @ (x @ held(time[-1])).T)
    wobble = world.gravity * np.cos(world.latitude) * d / cv.EARTH_RATE
    assert eps[2] * wobble * time[-1] > 2e-5  # the scale of what summing the angles leaves
    assert np.linalg.norm(error) < 3e-10
