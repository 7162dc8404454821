"""The one gimbal-kinematics implementation (:mod:`stableins.platform`): forward against the
conventions, the platform model and the inverse kinematics, and its analytic Jacobian against
central differences."""

import numpy as np
import pytest

from stableins.conventions import GimbalConfiguration, dcm_body_to_platform, dcm_nav_to_body
from stableins.errormodel import GIMBAL_IDS, ErrorModel
from stableins.estimators.coarse import CoarseProblem
from stableins.platform import (
    KINEMATIC_IDS,
    GimbalPlatform,
    platform_specific_force,
    specific_force_and_jacobian,
)

G = 9.80170


def _random_effects(rng):
    return {k: rng.normal(0, 1e-3) for k in KINEMATIC_IDS}


def _platform(offsets, cfg, base, effects):
    return GimbalPlatform(
        zero_offsets=tuple(offsets),
        configuration=cfg,
        base_attitude=tuple(base),
        base_tilt=(effects["tilt_north"], effects["tilt_east"]),
        base_azimuth=effects["azimuth_error"],
        nonorthogonality=(effects["nonorth_12"], effects["nonorth_23"]),
        angle_sensor_errors={k: v for k, v in effects.items() if k.startswith("ang1_")},
    )


@pytest.mark.parametrize("senses", [(1, 1, 1, 1), (1, -1, 1, 1), (-1, 1, -1, 1)])
def test_platform_jacobian_matches_central_differences(senses):
    rng = np.random.default_rng(11)
    cfg = GimbalConfiguration(senses)
    readings = rng.uniform(-np.pi, np.pi, (6, 3))
    offsets = rng.normal(0, 1e-3, 3)
    base = rng.normal(0, 0.05, 3)
    effects = _random_effects(rng)
    _, jac = specific_force_and_jacobian(readings, G, zero_offsets=offsets, base_attitude=base, effects=effects, configuration=cfg)
    h = 1e-6
    for k, pid in enumerate(GIMBAL_IDS + KINEMATIC_IDS):

        def f(d, pid=pid):
            o, e = offsets.copy(), dict(effects)
            if pid in GIMBAL_IDS:
                o[GIMBAL_IDS.index(pid)] += d
            else:
                e[pid] += d
            return platform_specific_force(readings, G, zero_offsets=o, base_attitude=base, effects=e, configuration=cfg)

        fd = (f(h) - f(-h)) / (2 * h)
        np.testing.assert_allclose(jac[..., k], fd, atol=1e-8, err_msg=pid)


def test_kinematics_reduce_to_conventions_without_effects():
    rng = np.random.default_rng(2)
    r = rng.uniform(-3, 3, (5, 3))
    base = (0.1, -0.02, 0.03)
    expected = np.einsum("...ij,j->...i", dcm_body_to_platform(r[:, 0], r[:, 1], r[:, 2]) @ dcm_nav_to_body(*base), [0, 0, -G])
    np.testing.assert_allclose(platform_specific_force(r, G, base_attitude=base), expected, atol=1e-12)


def test_kinematics_agree_with_the_platform_model():
    rng = np.random.default_rng(21)
    cfg = GimbalConfiguration((1, -1, 1, 1))
    readings = rng.uniform(-np.pi, np.pi, (9, 3))
    offsets = tuple(rng.normal(0, 1e-3, 3))
    base = tuple(rng.normal(0, 0.05, 3))
    effects = _random_effects(rng)
    platform = _platform(offsets, cfg, base, effects)
    forward = platform_specific_force(readings, G, zero_offsets=offsets, base_attitude=base, effects=effects, configuration=cfg)
    np.testing.assert_allclose(forward, platform.specific_force_platform(readings, G), atol=1e-12)


def test_inverse_kinematics_returns_the_readings_of_the_forward_model():
    """Forward ``C_n^p(r)`` then the inverse gives back ``r``; ``f^p`` of the inverse's readings is the forward one."""
    rng = np.random.default_rng(5)
    cfg = GimbalConfiguration((1, -1, 1, 1))
    readings = np.column_stack([rng.uniform(-3, 3, 20), rng.uniform(-1.2, 1.2, 20), rng.uniform(-3, 3, 20)])
    effects = {k: 0.0 for k in KINEMATIC_IDS} | {"nonorth_12": 2e-4, "nonorth_23": -1e-4, "tilt_north": 3e-5}
    platform = _platform(rng.normal(0, 1e-3, 3), cfg, rng.normal(0, 0.05, 3), effects)
    inverse = platform.readings_from_dcm_nav_to_platform(platform.dcm_nav_to_platform(readings), initial_readings=readings + 1e-3)
    np.testing.assert_allclose(inverse, readings, atol=1e-11)
    np.testing.assert_allclose(platform.specific_force_platform(inverse, G), platform.specific_force_platform(readings, G), atol=1e-12)


def test_coarse_problem_uses_the_platform_kinematics():
    """The coarse fit's ``f^p`` and offset columns are those of :func:`specific_force_and_jacobian` (no second chain)."""
    rng = np.random.default_rng(8)
    cfg = GimbalConfiguration((1, 1, -1, 1))
    readings = rng.uniform(-3, 3, (1, 18, 3))
    model = ErrorModel.standard(gimbals=True)
    x = model.vector({"theta10": 0.0, "theta20": 2e-4, "theta30": -3e-4})[None]
    base = dcm_nav_to_body(0.2, 0.01, -0.01)
    problem = CoarseProblem(readings, np.zeros((1, 18, 3)), np.ones((1, 18, 3)), G, base, cfg, model)
    out, jac = problem.predict(x)
    f_p, d_theta = specific_force_and_jacobian(
        readings, G, zero_offsets=(0.0, 2e-4, -3e-4), base_dcm=base, configuration=cfg, ids=GIMBAL_IDS
    )
    values = {k: x[..., i, None] for i, k in enumerate(model.ids)}
    np.testing.assert_array_equal(out, model.forward(f_p, values))
    np.testing.assert_array_equal(jac[..., model.index("theta20")], (model.jacobian_specific_force(f_p, values) @ d_theta)[..., 1])
