"""Synthetic system-level records built from this package's own derivation (unit tests of the math only).

The recovery tests against the independent truth simulator live in test_system_recovery.py.
Here the accelerometer outputs come from the exact error model (ErrorModel.forward) on the
exact polar-aligned platform kinematics, and the attitude errors from the linear loop model
(DampingLoop.simulate) driven by the n-frame specific-force error of the *compensated* outputs.
"""

from __future__ import annotations

import numpy as np

from stableins import conventions as cv
from stableins.errormodel import ErrorModel
from stableins.site import SiteMetadata

LATITUDE = np.radians(40.0)


def metadata(rate: float, zeta: float = 0.5, latitude: float = LATITUDE, yaw: float = 0.0, base=None) -> SiteMetadata:
    return SiteMetadata(
        serial_number="SYN-1",
        latitude=latitude,
        height=0.0,
        gravity=float(cv.normal_gravity(latitude)),
        gravity_source="WGS-84 normal gravity",
        sample_rate=rate,
        base_attitude=tuple(base) if base is not None else (yaw, 0.0, 0.0),
        damping={"zeta": zeta},
    )


def gimbal_angles(body_to_platform):
    """Actual angles (α1, α2, α3) with C_b^p = R3(α1) R1(α2) R2(α3) (senses +1), by closed-form decomposition."""
    c = body_to_platform
    a2 = -np.arcsin(np.clip(c[..., 2, 1], -1, 1))
    a3 = np.arctan2(c[..., 2, 0], c[..., 2, 2])
    m = cv.R1(a2) @ cv.R2(a3)
    r = c @ np.swapaxes(m, -1, -2)
    a1 = np.arctan2(r[..., 0, 1], r[..., 0, 0])
    return a1, a2, a3


def record(
    true, installed, rate=1.0, duration=cv.SIDEREAL_DAY, noise=5e-3, seed=0, zeta=0.5, start_angle=0.4, yaw=0.0, loop_step=10.0, base=None
):
    """Columns of a static polar-aligned record (dict of arrays) and its metadata.

    ``base = (yaw, pitch, roll)`` puts the polar-aligned platform on a turned/tilted base: the gimbal
    readings then come from the exact kinematics and the attitude outputs from ``C_n^b (I + [φ×])``.
    """
    from stableins.estimators.system.loop import DampingLoop

    meta = metadata(rate, zeta, yaw=yaw, base=base)
    rng = np.random.default_rng(seed)
    model = ErrorModel.standard()
    n = int(round(duration * rate))
    t = np.arange(n) / rate
    s = start_angle + cv.EARTH_RATE * t
    g = meta.gravity
    lat = meta.latitude
    f_p = g * np.stack([np.cos(s) * np.cos(lat), np.sin(s) * np.cos(lat), np.full(n, np.sin(lat))], axis=1)
    f_a = model.forward(f_p, true) + rng.normal(0.0, noise, (n, 3))
    theta10 = installed.get("theta10", 0.0)
    angle = -(s) - theta10  # reading r = alpha - theta10, alpha = -St (s1 = +1)
    # attitude: loop response to the compensated, noise-free n-frame error on a coarse grid
    tl = np.arange(0.0, duration + loop_step, loop_step)
    sl = start_angle + cv.EARTH_RATE * tl
    f_pl = g * np.stack([np.cos(sl) * np.cos(lat), np.sin(sl) * np.cos(lat), np.full(tl.size, np.sin(lat))], axis=1)
    comp = model.inverse(model.forward(f_pl, true), installed)
    err_p = comp - f_pl
    c_bp = cv.dcm_body_to_platform(-sl, 0.0, np.pi / 2 + lat)
    err_n = np.einsum("kji,kj->ki", c_bp, err_p) / g
    loop = DampingLoop(lat, g, zeta)
    y = loop.simulate(tl, np.stack([err_n[:, 0], -err_n[:, 1]], axis=1))
    pitch0 = np.interp(t, tl, y[:, 0])
    roll0 = np.interp(t, tl, y[:, 1])
    # attitude noise: accelerometer noise through the loop (white input at the loop step)
    wn = rng.normal(0.0, noise / g / np.sqrt(loop_step * rate), (tl.size, 2))
    yn = loop.simulate(tl, wn)
    pitch0 += np.interp(t, tl, yn[:, 0])
    roll0 += np.interp(t, tl, yn[:, 1])
    c, sn = np.cos(yaw), np.sin(yaw)
    angle_inner, angle_middle = np.zeros(n), np.full(n, np.pi / 2 + lat)
    pitch_out, roll_out, heading = c * pitch0 - sn * roll0, sn * pitch0 + c * roll0, np.full(n, yaw)
    if base is not None:
        nav_to_platform = cv.dcm_body_to_platform(-s, 0.0, np.pi / 2 + lat)  # polar aligned (level-north gimbal chain = C_n^p)
        nav_to_body = cv.dcm_nav_to_body(*base)
        a1, a2, a3 = gimbal_angles(nav_to_platform @ nav_to_body.T)
        angle = a1 - theta10
        angle_inner = a2 - installed.get("theta20", 0.0)
        angle_middle = a3 - installed.get("theta30", 0.0)
        phi = np.stack([-roll0, -pitch0, np.zeros(n)], axis=1)
        computed = nav_to_body @ (np.eye(3) + cv.skew(phi))
        heading, pitch_out, roll_out = cv.euler_from_dcm(computed)
    cols = {
        "time": t,
        "angle_platform": angle,
        "angle_inner": angle_inner,
        "angle_middle": angle_middle,
        "f_x": f_a[:, 0],
        "f_y": f_a[:, 1],
        "f_z": f_a[:, 2],
        "velocity_north": rng.normal(0, 0.01, n),
        "velocity_east": rng.normal(0, 0.01, n),
        "velocity_down": np.zeros(n),
        "pitch": pitch_out,
        "roll": roll_out,
        "heading": heading,
        "temperature": np.full(n, 25.0),
    }
    return cols, meta


def paper_residuals():
    """Wu et al. 2018 Tables 2 and 3 (signs of Table 2 unknown in the extracted text; chosen +,+,-)."""
    a = cv.ARCSEC
    true = {
        "sf_x": 1.0 + 1e-4,
        "sf_y": 1.0 + 2e-4,
        "sf_z": 1.0 - 1e-4,
        "bias_x": 1e-3,
        "bias_y": 5e-4,
        "bias_z": -1e-3,
        "beta_xz": 5 * a,
        "beta_yz": 10 * a,
        "beta_zy": -5 * a,
        "beta_xy": -10 * a,
        "beta_yx": 5 * a,
        "beta_zx": -5 * a,
    }
    return true, {}
