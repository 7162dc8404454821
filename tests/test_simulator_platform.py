"""GimbalPlatform: exact kinematics, imperfections, inverse kinematics, angular rate."""

import numpy as np
import pytest

from stableins import conventions as cv
from stableins.platform import GimbalPlatform, _rotation_vector, rotation_about

SENSES = [(1, 1, 1, 1), (-1, 1, -1, 1), (1, -1, 1, 1)]


@pytest.mark.parametrize("senses", SENSES)
def test_perfect_platform_is_the_conventions_chain(senses):
    config = cv.GimbalConfiguration(senses)
    p = GimbalPlatform(zero_offsets=(1e-4, -2e-4, 3e-4), configuration=config, base_attitude=(0.3, 0.01, -0.02))
    r = np.random.default_rng(0).uniform(-3, 3, (20, 3))
    alpha = r + [1e-4, -2e-4, 3e-4]
    expected = cv.dcm_body_to_platform(alpha[:, 0], alpha[:, 1], alpha[:, 2], 0.0, config) @ cv.dcm_nav_to_body(0.3, 0.01, -0.02)
    np.testing.assert_allclose(p.dcm_nav_to_platform(r), expected, atol=1e-15)
    np.testing.assert_allclose(p.specific_force_platform(r, 9.8), expected @ [0, 0, -9.8], atol=1e-14)


def test_nonorthogonality_is_the_angle_between_gimbal_axes():
    nu12, nu23 = 3e-4, -5e-4
    p = GimbalPlatform(nonorthogonality=(nu12, nu23))
    # platform axis z and inner axis: the inner gimbal frame axis x seen from the platform frame at zero angles
    c_inner_to_platform = cv.R2(nu12)  # chain R3(0) R2(nu12) R1(.)
    inner_axis = c_inner_to_platform.T @ [1.0, 0, 0]
    assert np.arccos(inner_axis @ [0, 0, 1.0]) == pytest.approx(np.pi / 2 + nu12, abs=1e-12)
    middle_axis_in_inner = cv.R3(nu23).T @ [0, 1.0, 0]
    assert np.arccos(middle_axis_in_inner @ [1.0, 0, 0]) == pytest.approx(np.pi / 2 + nu23, abs=1e-12)
    # and the full chain uses them: rotating only the inner gimbal turns about the tilted axis
    c0, c1 = p.dcm_body_to_platform([0, 0, 0]), p.dcm_body_to_platform([0, 1e-6, 0])
    turn = _rotation_vector(c1 @ c0.T) / 1e-6
    np.testing.assert_allclose(turn, cv.R2(nu12) @ [1.0, 0, 0], atol=1e-9)


def test_base_tilt_and_azimuth():
    g = 9.8
    tilted = GimbalPlatform(base_tilt=(2e-4, 0.0))
    np.testing.assert_allclose(tilted.specific_force_platform([0, 0, 0], g), [0, -g * np.sin(2e-4), -g * np.cos(2e-4)], atol=1e-15)
    tilted = GimbalPlatform(base_tilt=(0.0, 2e-4))
    np.testing.assert_allclose(tilted.specific_force_platform([0, 0, 0], g), [g * np.sin(2e-4), 0, -g * np.cos(2e-4)], atol=1e-15)
    turned = GimbalPlatform(base_azimuth=1e-3)
    yaw, pitch, roll = cv.euler_from_dcm(turned.dcm_nav_to_body())
    assert (yaw, pitch, roll) == pytest.approx((1e-3, 0, 0), abs=1e-15)
    r = np.random.default_rng(1).uniform(-3, 3, (5, 3))
    np.testing.assert_allclose(turned.specific_force_platform(r, g), GimbalPlatform().specific_force_platform(r, g), atol=1e-14)


def test_once_per_revolution_sensor_error():
    p = GimbalPlatform(zero_offsets=(0, 1e-4, 0), angle_sensor_errors={"ang1_inner_c": 2e-5, "ang1_inner_s": -1e-5})
    r = np.array([[0.0, 0.7, 0.0]])
    assert p.actual_angles(r)[0, 1] == pytest.approx(0.7 + 1e-4 + 2e-5 * np.cos(0.7) - 1e-5 * np.sin(0.7), abs=1e-16)
    np.testing.assert_allclose(p.readings_from_actual(p.actual_angles(r)), r, atol=1e-15)
    with pytest.raises(ValueError, match="ang1_inner_c"):
        GimbalPlatform(angle_sensor_errors={"ang1_outer_c": 1e-5})


@pytest.mark.parametrize("senses", SENSES)
def test_inverse_kinematics_round_trip(senses):
    p = GimbalPlatform(
        zero_offsets=(1e-4, -2e-4, 3e-4),
        configuration=cv.GimbalConfiguration(senses),
        base_attitude=(0.2, -0.01, 0.02),
        base_tilt=(1e-5, -2e-5),
        nonorthogonality=(3e-5, -4e-5),
        angle_sensor_errors={"ang1_middle_s": 2e-5},
    )
    rng = np.random.default_rng(2)
    r = rng.uniform(-3, 3, (50, 3))
    r[:, 1] = rng.uniform(-1.5, 1.5, 50)
    back = p.readings_from_dcm_nav_to_platform(p.dcm_nav_to_platform(r))
    np.testing.assert_allclose((back - r + np.pi) % (2 * np.pi) - np.pi, 0.0, atol=1e-12)
    # with a guess on another branch (inner beyond 90 deg) Newton keeps that branch
    r2 = r.copy()
    r2[:, 1] += np.pi
    back2 = p.readings_from_dcm_nav_to_platform(p.dcm_nav_to_platform(r2), initial_readings=r2 + 1e-4)
    np.testing.assert_allclose(back2, r2, atol=1e-12)


def test_angular_rate_is_the_derivative_of_the_chain():
    p = GimbalPlatform(configuration=cv.GimbalConfiguration((1, -1, 1, 1)), nonorthogonality=(3e-2, -4e-2))
    a, ad, h = np.array([0.3, 0.5, -0.7]), np.array([0.1, -0.2, 0.3]), 1e-7
    c0, c1 = p.dcm_body_to_platform_actual(a - h * ad), p.dcm_body_to_platform_actual(a + h * ad)
    np.testing.assert_allclose(p.angular_rate(a, ad), _rotation_vector(c1 @ c0.T) / (2 * h), rtol=1e-7)


def test_rotation_about_is_a_frame_rotation():
    for k, rot in enumerate((cv.R1, cv.R2, cv.R3)):
        v = np.zeros(3)
        v[k] = 0.4
        np.testing.assert_allclose(rotation_about(v), rot(0.4), atol=1e-15)
    small = np.array([1e-9, -2e-9, 3e-9])
    np.testing.assert_allclose(rotation_about(small), np.eye(3) - cv.skew(small), atol=1e-17)
