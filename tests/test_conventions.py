"""Frames, DCMs, gimbal kinematics and Earth constants (stableins.conventions)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from stableins import conventions as cv

angles = st.floats(-10.0, 10.0, allow_nan=False)


@settings(max_examples=60, deadline=None)
@given(angles, angles, angles, angles)
def test_gimbal_dcm_is_proper_rotation(a1, a2, a3, q):
    for senses in [(1, 1, 1, 1), (-1, 1, -1, 1), (1, -1, 1, -1)]:
        c = cv.dcm_body_to_platform(a1, a2, a3, q, cv.GimbalConfiguration(senses))
        np.testing.assert_allclose(c @ c.T, np.eye(3), atol=1e-13)
        assert np.linalg.det(c) == pytest.approx(1.0, abs=1e-13)


@settings(max_examples=60, deadline=None)
@given(angles, st.floats(-1.5, 1.5), angles)
def test_euler_round_trip(yaw, pitch, roll):
    c = cv.dcm_nav_to_body(yaw, pitch, roll)
    np.testing.assert_allclose(c @ c.T, np.eye(3), atol=1e-13)
    y, p, r = cv.euler_from_dcm(c)
    np.testing.assert_allclose(cv.dcm_nav_to_body(y, p, r), c, atol=1e-12)


def test_elementary_rotations_small_angle_limit():
    a = 1e-7
    for i, rot in enumerate((cv.R1, cv.R2, cv.R3)):
        e = np.zeros(3)
        e[i] = 1.0
        np.testing.assert_allclose(rot(a), np.eye(3) - a * cv.skew(e), atol=1e-13)


def test_frame_rotation_sense_is_right_handed():
    # A frame turned +90 deg about z sees the old x axis along its -y axis.
    np.testing.assert_allclose(cv.R3(np.pi / 2) @ [1.0, 0, 0], [0, -1.0, 0], atol=1e-15)


def test_euler_matches_paper_eq3_first_row():
    yaw, pitch, roll = 0.3, -0.2, 0.1
    c = cv.dcm_nav_to_body(yaw, pitch, roll)
    expected = [np.cos(yaw) * np.cos(pitch), np.sin(yaw) * np.cos(pitch), -np.sin(pitch)]
    np.testing.assert_allclose(c[0], expected, atol=1e-15)


def test_installation_matrix_small_angle_is_rotation_of_each_axis():
    b = 1e-6
    c = cv.dcm_platform_to_accelerometer(beta_xz=b, beta_xy=0, beta_yz=0, beta_yx=0, beta_zy=0, beta_zx=0)  # beta_xz: x axis turned about z
    # the x sensitive axis, turned right-handedly by b about z_p, is R3(b)^T x = (cos b, sin b, 0)
    np.testing.assert_allclose(c[0], cv.R3(b).T @ [1.0, 0, 0], atol=1e-12)


@pytest.mark.parametrize("latitude_deg", [0.0, 23.0, 40.0, 67.5, -35.0])
@pytest.mark.parametrize("earth_angle", [0.0, 0.7, 2.5, -1.2])
def test_polar_aligned_platform_reproduces_paper_eq19(latitude_deg, earth_angle):
    latitude = np.radians(latitude_deg)
    for senses in [(1, 1, 1, 1), (-1, -1, 1, 1)]:
        config = cv.GimbalConfiguration(senses)
        _, middle = cv.polar_alignment_readings(latitude, config)
        platform = -config.senses[0] * earth_angle
        c = cv.dcm_body_to_platform(platform, 0.0, middle, 0.0, config)
        f_over_g = c @ (cv.specific_force_nav(1.0))
        expected = [np.cos(earth_angle) * np.cos(latitude), np.sin(earth_angle) * np.cos(latitude), np.sin(latitude)]
        np.testing.assert_allclose(f_over_g, expected, atol=1e-14)
        assert cv.earth_rate_angle(platform, config) == pytest.approx(earth_angle)
        # z_p is the spin axis: Earth rate seen in the platform frame lies along z_p.
        np.testing.assert_allclose(c @ cv.earth_rate_nav(latitude), [0, 0, cv.EARTH_RATE], atol=1e-18)


def test_normal_gravity_reference_values():
    # Somigliana reference values at the equator and pole (TR8350.2 Table 3.4).
    assert cv.normal_gravity(0.0) == pytest.approx(9.7803253359, abs=1e-10)
    assert cv.normal_gravity(np.pi / 2) == pytest.approx(9.8321849378, abs=1e-9)
    # Free-air gradient about -3.086e-6 s^-2 at mid latitude.
    g0, g1 = cv.normal_gravity(np.radians(45), 0.0), cv.normal_gravity(np.radians(45), 1000.0)
    assert (g1 - g0) / 1000 == pytest.approx(-3.086e-6, rel=2e-3)
    assert cv.normal_gravity(np.radians(40.0)) == pytest.approx(9.8017, abs=1e-4)


def test_attitude_error_of_level_north_body_is_minus_misalignment():
    phi = np.array([2e-5, -3e-5, 4e-5])
    d = cv.attitude_error_from_misalignment(phi)
    np.testing.assert_allclose(d, -phi[::-1], rtol=1e-4)


def test_gimbal_configuration_validates():
    with pytest.raises(ValueError, match="senses"):
        cv.GimbalConfiguration((1, 1, 0, 1))
    assert cv.GimbalConfiguration((1, -1, -1, 1)).handedness == 1
    assert cv.GimbalConfiguration((1, -1, 1, 1)).handedness == -1
