"""Deliberate twins pinned together.

The simulator's effect formulas (:mod:`stableins.simulator.effects`, the independent world) and the
discovery library's candidate terms (:mod:`stableins.discovery.library`, what the estimators fit)
are written apart on purpose.  For the same parameter value they must put the same signal into the
accelerometer output at random attitudes: exactly for the output effects, to first order in the
value for the test-equipment (kinematic) effects, whose library term is the analytic column
``∂f^p/∂p`` while the simulator turns its :class:`~stableins.platform.GimbalPlatform`.
"""

import numpy as np
import pytest

from stableins.discovery.library import LIBRARY
from stableins.errormodel import ErrorModel, TermInputs
from stableins.platform import KINEMATIC_IDS, GimbalPlatform, specific_force_and_jacobian
from stableins.simulator.effects import CATALOGUE
from stableins.simulator.physics import Accelerometer, SensorInputs

G = 9.80170
OUTPUT_IDS = tuple(k for k, e in CATALOGUE.items() if e.kind == "output")


def _world(seed: int, n: int = 40):
    """Random attitudes (readings over the full gimbal ranges), a random base and a random instrument."""
    rng = np.random.default_rng(seed)
    readings = rng.uniform(-np.pi, np.pi, (n, 3))
    base = tuple(rng.normal(0, 0.05, 3))
    model = ErrorModel.standard(nonlinear=True)
    values = {t.id: t.reference + rng.normal() * t.nominal for t in model}
    return rng, readings, base, model, values


def _signal(model, values, f_p, inputs, term, value):
    """Output with the term at ``value`` minus the output without it (the estimators' model)."""
    return (model + (term,)).forward(f_p, values | {term.id: value}, inputs) - model.forward(f_p, values, inputs)


def _simulated_signal(values, f_p, inputs, effect_id, value):
    """The same with the simulator's own model and its definition of the effect (:mod:`stableins.simulator.physics`)."""
    effect = ((effect_id, CATALOGUE[effect_id].regressor),)
    return Accelerometer(values | {effect_id: value}, effect).output(f_p, inputs) - Accelerometer(values).output(f_p, inputs)


def test_every_simulated_effect_has_its_library_candidate():
    # the timing effect t_async is zero at rest: the lever stage estimates it from slews (a record term), not discovery
    timing = {k for k, e in CATALOGUE.items() if e.kind == "timing"}
    assert timing == {"t_async"}
    assert set(CATALOGUE) - timing == set(LIBRARY.ids)


@pytest.mark.parametrize("seed", [1, 2])
def test_output_effects_give_the_library_signal(seed):
    rng, readings, base, model, values = _world(seed)
    f_p = GimbalPlatform(base_attitude=base).specific_force_platform(readings, G)
    n = len(readings)
    sampled = {
        "temperature": rng.normal(0, 2, n),
        "time": rng.uniform(0, 1e4, n),
        "slew_direction": rng.choice([-1.0, 0.0, 1.0], (n, 3)),
        "angular_rate": rng.normal(0, 0.3, (n, 3)),
        "angular_acceleration": rng.normal(0, 0.3, (n, 3)),
    }
    inputs = TermInputs(f_p, **sampled)
    for tid in OUTPUT_IDS:
        value = 3.0 * CATALOGUE[tid].nominal
        simulated = _simulated_signal(values, f_p, SensorInputs(f_p, **sampled), tid, value)
        library = _signal(model, values, f_p, inputs, LIBRARY[tid].term, value)
        assert np.max(np.abs(simulated)) > 0.0, tid  # the random attitudes and inputs excite every effect
        np.testing.assert_allclose(library, simulated, rtol=1e-12, atol=1e-12 * np.max(np.abs(simulated)), err_msg=tid)


@pytest.mark.parametrize("seed", [3, 4])
def test_kinematic_effects_give_the_library_signal_to_first_order(seed):
    """``f^a(platform turned by v) − f^a(platform)`` against ``v (∂f^a/∂f^p)(∂f^p/∂p)``: the difference is O(v²)."""
    _, readings, base, model, values = _world(seed)
    offsets = (1e-4, -2e-4, 3e-4)
    nominal = GimbalPlatform(zero_offsets=offsets, base_attitude=base)
    f_p = nominal.specific_force_platform(readings, G)
    j_fp = model.jacobian_specific_force(f_p, values)
    _, columns = specific_force_and_jacobian(readings, G, zero_offsets=offsets, base_attitude=base, ids=KINEMATIC_IDS)
    inputs = TermInputs(f_p, platform_jacobian=columns, platform_jacobian_ids=tuple(KINEMATIC_IDS))
    value = 1e-5  # rad: the second-order remainder is ~1e-5 of the signal
    for tid in KINEMATIC_IDS:
        turned = GimbalPlatform(
            zero_offsets=offsets,
            base_attitude=base,
            base_tilt=(value if tid == "tilt_north" else 0.0, value if tid == "tilt_east" else 0.0),
            base_azimuth=value if tid == "azimuth_error" else 0.0,
            nonorthogonality=(value if tid == "nonorth_12" else 0.0, value if tid == "nonorth_23" else 0.0),
            angle_sensor_errors={tid: value} if tid.startswith("ang1_") else {},
        )
        simulated = model.forward(turned.specific_force_platform(readings, G), values) - model.forward(f_p, values)
        library = value * np.einsum("...ij,...j->...i", j_fp, LIBRARY[tid].term.regressor(inputs))
        scale = np.max(np.abs(library))
        if tid == "azimuth_error":  # invisible to gravity in both
            assert scale < 1e-12 and np.max(np.abs(simulated)) < 1e-12
            continue
        assert scale > 1e-6 * G * value, tid
        np.testing.assert_allclose(library, simulated, atol=1e-4 * scale, err_msg=tid)
