"""Device-level world: exact forward model, kinematics, transients, effects, reproducibility."""

import numpy as np
import pytest
from test_simulator_physics import eq6_by_hand

from stableins import conventions as cv
from stableins.drivers.base import PlatformDriver
from stableins.errormodel import ErrorModel
from stableins.errors import InputError
from stableins.schema import DEVICE_COLUMNS
from stableins.simulator.device import SimulatedPlatform, simulate_dwells
from stableins.simulator.noise import NoiseSettings
from stableins.simulator.truth import SimulatedSite, Truth

QUIET = NoiseSettings.quiet()
STILL = {"gain": 0.0}


def quiet_truth(seed=1, parameters=None, effects=None, senses=(1, 1, 1, 1), settling=STILL):
    t = Truth.draw(seed, noise=QUIET, site=SimulatedSite(gimbal_senses=senses), effects=effects)
    return t.with_changes(parameters=t.parameters if parameters is None else parameters, settling=settling)


def position_means(d):
    return {p: np.array([d[c][d["position"] == p].mean() for c in ("f_x", "f_y", "f_z")]) for p in np.unique(d["position"])}


def test_ideal_instrument_points_each_axis_up_and_down():
    truth = quiet_truth(parameters={})
    g = truth.site.gravity
    readings = [(0, 0, 0), (0, np.pi, 0), (0, np.pi / 2, 0), (0, -np.pi / 2, 0), (0, 0, np.pi / 2), (0, 0, -np.pi / 2)]
    expected = [(0, 0, -g), (0, 0, g), (0, -g, 0), (0, g, 0), (g, 0, 0), (-g, 0, 0)]
    means = position_means(simulate_dwells(truth, readings, dwell=1.0, settle=0.5, rate=20))
    for k, e in enumerate(expected, start=1):
        np.testing.assert_allclose(means[k], e, atol=1e-12)


def test_columns_and_position_numbers():
    d = simulate_dwells(quiet_truth(), [(0, 0, 0), (0.1, 0.2, 0.3), (0, 0, 0)], dwell=0.5, settle=0.0, rate=10, stage="fine", pass_number=2)
    assert list(d) == [c.name for c in DEVICE_COLUMNS]
    assert list(np.unique(d["position"])) == [1, 2, 3]
    assert set(d["stage"]) == {"fine"} and set(d["pass"]) == {2}
    assert np.all(np.diff(d["time"]) > 0)
    np.testing.assert_array_equal(d["command_inner"][d["position"] == 2], 0.2)


@pytest.mark.parametrize("senses", [(1, 1, 1, 1), (-1, 1, -1, 1)])
def test_outputs_satisfy_the_full_forward_model(senses):
    truth = quiet_truth(seed=4, senses=senses)
    rng = np.random.default_rng(0)
    readings = rng.uniform(-np.pi, np.pi, (6, 3))
    d = simulate_dwells(truth, readings, dwell=0.5, settle=0.1, rate=10)
    platform = truth.platform()
    model = ErrorModel.standard()
    for k, r in enumerate(readings, start=1):
        rows = d["position"] == k
        f_p = platform.specific_force_platform(r, truth.site.gravity)
        expected = np.array(eq6_by_hand(truth.parameters, tuple(f_p)))  # Eq. 6 in plain floats, neither model's code
        got = np.column_stack([d["f_x"][rows], d["f_y"][rows], d["f_z"][rows]])
        np.testing.assert_allclose(got, np.broadcast_to(expected, got.shape), atol=1e-13, rtol=0)
        # angle readings are the commanded ones, actual = readings + offsets
        np.testing.assert_allclose(d["angle_inner"][rows], r[1], atol=1e-15)
        # the inverse model gives back the exact specific force (|f^p| = g)
        assert np.linalg.norm(model.inverse(got[0], truth.parameters)) == pytest.approx(truth.site.gravity, abs=1e-12)


def test_zero_offsets_move_gravity_as_conventions_say():
    theta = {"theta20": 3e-4, "theta30": -2e-4}
    truth = quiet_truth(parameters=theta)
    g = truth.site.gravity
    f = position_means(simulate_dwells(truth, [(0, 0, 0)], dwell=0.2, settle=0.0, rate=10))[1]
    expected = cv.dcm_body_to_platform(0.0, 3e-4, -2e-4) @ cv.specific_force_nav(g)
    np.testing.assert_allclose(f, expected, atol=1e-13)
    # Wu et al. Table 1, position 1 (g_x = g·theta30) holds exactly here: R1 does not touch x
    assert f[0] == pytest.approx(g * np.sin(-2e-4), rel=1e-12)


def test_settling_transient_is_visible_then_decays():
    truth = quiet_truth(settling={"gain": 1e-4, "frequency": 0.5, "damping": 0.2})
    d = simulate_dwells(truth, [(0, 0, 0), (0, np.pi / 2, 0)], dwell=20.0, settle=0.0, rate=20)
    rows = d["position"] == 2
    error = d["angle_inner"][rows] - np.pi / 2
    early, late = np.abs(error[:40]).max(), np.abs(error[-40:]).max()
    assert early > 0.3 * 1e-4 * np.pi / 2  # visible: a fraction of gain x slew
    assert late < 1e-3 * early  # e^{-zeta omega t} over ~18 s
    # the accelerometers see the motion: f_z departs from its final value early in the dwell
    fz = d["f_z"][rows]
    assert np.abs(fz[:40] - fz[-1]).max() > 1e3 * np.abs(fz[-40:] - fz[-1]).max()


def test_lever_arm_acts_only_while_rotating():
    base = quiet_truth(settling={"gain": 1e-4})
    lever = base.with_changes(effects={"lever_x_y": 0.05, "lever_y_x": 0.05})
    readings = [(0, 0, 0), (0.0, 1.0, 0.5)]
    p0, p1 = SimulatedPlatform(base, rate=50), SimulatedPlatform(lever, rate=50)
    for p in (p0, p1):
        p.command(readings[1])
    a, b = p0.acquire(40.0), p1.acquire(40.0)
    diff = b.specific_force - a.specific_force
    duration = p0.slew_duration()
    moving = a.time < duration
    assert np.abs(diff[moving]).max() > 1e-4  # omega^2 r ~ (0.17 rad/s)^2 x 0.05 m
    assert np.abs(diff[a.time > 35.0]).max() < 1e-10  # only the decayed settling motion is left


def test_hysteresis_depends_on_the_direction_of_approach():
    kh = 5e-5
    truth = quiet_truth(parameters={}, effects={"Kh_x": kh})
    # reach (0,0,0.3) from below (x input increasing) and from above (decreasing)
    d = simulate_dwells(truth, [(0, 0, 0.0), (0, 0, 0.3), (0, 0, 0.6), (0, 0, 0.3)], dwell=0.5, settle=0.0, rate=10)
    m = position_means(d)
    assert m[2][0] - m[4][0] == pytest.approx(2 * kh, rel=1e-9)


def test_g_sensitive_drift_moves_the_readings_during_the_dwell():
    dg = 1e-6  # exaggerated to be visible: rad/s per m/s^2
    truth = quiet_truth(parameters={}, effects={"Dg_zz": dg})
    # platform axis horizontal-ish: f^p_z = -g at zero readings; the gyro errs by dg f_z = -dg g, so the platform
    # turns about z_p at -dg f_z = +dg g (conventions.platform_drift_rate)
    d = simulate_dwells(truth, [(0, 0, 0.0)], dwell=10.0, settle=0.0, rate=10)
    slope = np.polyfit(d["time"], d["angle_platform"], 1)[0]
    # C_b^p = R3(alpha1)...: turning the platform frame by an angle w about z_p adds w to alpha1 (s1 = +1)
    assert slope == pytest.approx(dg * truth.site.gravity, rel=1e-6)


def test_quantization_carries_the_remainder():
    lsb = 1e-4
    base = quiet_truth(parameters={})
    q = base.with_changes(noise=NoiseSettings(quantization=lsb))
    a = simulate_dwells(base, [(0, 0, 0.2)], dwell=50.0, settle=0.0, rate=100)
    b = simulate_dwells(q, [(0, 0, 0.2)], dwell=50.0, settle=0.0, rate=100)
    # outputs are whole LSBs per sample ...
    steps = b["f_x"] * 0.01 / lsb
    np.testing.assert_allclose(steps, np.round(steps), atol=1e-6)
    # ... and the integrated error never exceeds one LSB of velocity (within a noise block)
    dv_error = np.cumsum(b["f_x"] - a["f_x"]) * 0.01
    assert np.abs(dv_error).max() <= 2 * lsb
    assert abs(b["f_x"].mean() - a["f_x"].mean()) < 2 * lsb / 50.0


def test_reproducible_across_block_splits_and_restore():
    truth = Truth.draw(2, effects={"lever_x_y": 0.02, "Dg_zz": 1e-8, "Kh_x": 5e-5, "nonorth_12": 5e-5, "Kt_bias_x": 1e-5})

    def run(splits):
        p = SimulatedPlatform(truth, rate=100, seed=5)
        out = []
        for cmd in [(0, 0.3, 0), (1, 0, 2)]:
            p.command(cmd)
            for s in splits:
                b = p.acquire(s)
                out.append(np.column_stack([b.time, b.specific_force, b.angles, b.temperature]))
        return np.vstack(out)

    a = run([200.0])
    assert np.array_equal(a, run([3.3, 150.01, 0.69, 46.0]))
    assert np.array_equal(a, run([0.01] * 37 + [199.63]))
    assert not np.array_equal(a[:, 1:4], np.vstack([a[:1, 1:4]] * len(a)))  # there is noise
    # a platform rebuilt from its command history continues identically (kill -9 / resume)
    p = SimulatedPlatform(truth, rate=100, seed=5)
    p.command((0, 0.3, 0))
    p.acquire(100.0)
    p.command((1, 0, 2))
    p.acquire(33.33)
    q = SimulatedPlatform.restore(truth, p.history, p.time, rate=100, seed=5)
    x, y = p.acquire(20.0), q.acquire(20.0)
    assert np.array_equal(x.specific_force, y.specific_force) and np.array_equal(x.angles, y.angles)
    # a different seed gives different noise
    other = SimulatedPlatform(truth, rate=100, seed=6)
    other.command((0, 0.3, 0))
    assert not np.array_equal(other.acquire(1.0).specific_force, run([1.0])[:100, 1:4])


def test_simulated_platform_is_a_platform_driver():
    p = SimulatedPlatform(quiet_truth())
    assert isinstance(p, PlatformDriver)
    assert p.metadata.sample_rate == p.rate
    assert p.command((0, 0.1, 0)) == 0.0
    assert p.status()["commands"] == 1
    p.close()
    with pytest.raises(RuntimeError):
        p.acquire(1.0)


def test_unknown_effect_is_an_input_error_listing_known_ids():
    with pytest.raises(InputError, match="K3_x"):
        Truth.draw(1, effects={"K4_x": 1.0})


@pytest.mark.parametrize(
    ("effect", "value", "readings", "axis", "expected"),
    [
        # x axis up (+g): middle gimbal at +90 deg gives f^p = (g, 0, 0)
        ("K3_x", 1e-8, (0, 0, np.pi / 2), 0, lambda g: 1e-8 * g**3),
        ("Koq_x", 1e-7, (0, 0, -np.pi / 2), 0, lambda g: -1e-7 * g**2),  # x down: f|f| < 0
        ("Ksa_x", 1e-5, (0, 0, -np.pi / 2), 0, lambda g: 1e-5 * g),  # |f| > 0 either way
        ("Kcq_zx", 1e-7, (0, 0, np.pi / 4), 2, lambda g: 1e-7 * (g / np.sqrt(2)) ** 2),
        ("Kcc_zxz", 1e-7, (0, 0, np.pi / 4), 2, lambda g: 1e-7 * (g / np.sqrt(2)) * (-g / np.sqrt(2))),
        ("Kcc_yxy", 1e-7, (0, 0, np.pi / 4), 1, lambda g: 0.0),  # f_y = 0
    ],
)
def test_output_effects_follow_their_definitions(effect, value, readings, axis, expected):
    base = quiet_truth(parameters={})
    hidden = base.with_changes(effects={effect: value})
    a = position_means(simulate_dwells(base, [readings], dwell=0.3, settle=0.0, rate=10))[1]
    b = position_means(simulate_dwells(hidden, [readings], dwell=0.3, settle=0.0, rate=10))[1]
    g = base.site.gravity
    assert b[axis] - a[axis] == pytest.approx(expected(g), rel=1e-9, abs=1e-15)
    others = [k for k in range(3) if k != axis]
    np.testing.assert_allclose(b[others], a[others], atol=1e-15)


def test_temperature_and_time_effects():
    from stableins.simulator.noise import TemperatureProfile

    profile = TemperatureProfile(reference=25.0, offset=2.0, ramp=0.01)
    base = quiet_truth(parameters={}).with_changes(noise=NoiseSettings(temperature=profile))
    effects = {"Kt_bias_y": 1e-5, "Kt_sf_z": 2e-5, "Kd_bias_x": 1e-6}
    a = simulate_dwells(base, [(0, 0, 0)], dwell=100.0, settle=0.0, rate=1)
    b = simulate_dwells(base.with_changes(effects=effects), [(0, 0, 0)], dwell=100.0, settle=0.0, rate=1)
    t = a["time"]
    d_t = 2.0 + 0.01 * t  # reference_temperature of the drawn site is the profile's reference
    np.testing.assert_allclose(b["temperature"], 25.0 + d_t)
    np.testing.assert_allclose(b["f_x"] - a["f_x"], 1e-6 * t, atol=1e-15)
    np.testing.assert_allclose(b["f_y"] - a["f_y"], 1e-5 * d_t, atol=1e-15)
    np.testing.assert_allclose(b["f_z"] - a["f_z"], 2e-5 * d_t * -base.site.gravity, rtol=1e-9)


def test_gyro_drift_and_g_sensitivity_turn_the_platform_at_minus_the_gyro_error():
    """Device level: between two samples of a dwell the platform turns by ``w Δt``, ``w = −(ε^p + D_g f^p)``."""
    drift = {"x": 2e-7, "y": -1e-7, "z": 3e-7}
    effects = {"Dg_xz": 4e-8, "Dg_yx": -3e-8, "Dg_zy": 5e-8, "Dg_yy": 2e-8}
    truth = quiet_truth(effects=effects).with_changes(gyro_drift=drift)
    readings = (0.2, 0.3, 0.4)
    d = simulate_dwells(truth, [readings], dwell=10.0, settle=0.0, rate=10)
    platform = truth.platform()
    angles = np.stack([d["angle_platform"], d["angle_inner"], d["angle_middle"]], axis=-1)
    dcm = platform.dcm_nav_to_platform(angles[[1, -1]])
    from stableins.platform import rotation_vector

    turned = rotation_vector(dcm[1] @ dcm[0].T)  # frame rotation C(t2) = rot(θ) C(t1)
    f_p = dcm[0] @ cv.specific_force_nav(truth.site.gravity)
    g_matrix = np.array([[effects.get(f"Dg_{a}{b}", 0.0) for b in "xyz"] for a in "xyz"])
    expected = -(np.array([drift[a] for a in "xyz"]) + g_matrix @ f_p) * (d["time"][-1] - d["time"][1])
    np.testing.assert_allclose(turned, expected, rtol=1e-4, atol=1e-12)
    np.testing.assert_allclose(expected, cv.platform_drift_rate([drift[a] for a in "xyz"], g_matrix, f_p) * (d["time"][-1] - d["time"][1]))


def test_the_wait_for_a_slew_lets_time_pass_at_one_sample_per_second():
    """At 1 Hz a half-second poll records no sample; the wait polls one sample period and the platform arrives."""
    from stableins.procedures.iteration import wait_until_arrived

    platform = SimulatedPlatform(quiet_truth(seed=3), rate=1.0, seed=3)
    command = (0.0, float(np.radians(45.0)), 0.0)
    platform.command(command)
    waited = wait_until_arrived(platform, command, tolerance=float(np.radians(1.0 / 3600.0)))
    assert 0.0 < waited < 300.0
    assert np.max(np.abs(platform.read_angles() - np.asarray(command))) <= np.radians(1.0 / 3600.0)
