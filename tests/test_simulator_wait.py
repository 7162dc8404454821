"""Issue 30: the simulated platform's wait computes nothing where nothing carries over, and changes no output."""

import numpy as np
import pytest

from stableins.simulator.device import SimulatedPlatform
from stableins.simulator.noise import NoiseSettings
from stableins.simulator.truth import Truth


def _session(truth, *, wait):
    """Two slews, each waited for (or recorded and dropped) for 37.3 s, then 40 s recorded; the recorded rows."""
    platform = SimulatedPlatform(truth, rate=50, seed=9)
    rows = []
    for command in [(0.0, 0.4, 0.1), (1.2, -0.3, 2.0)]:
        platform.command(command)
        if wait:
            platform.wait(platform.slew_duration() + 37.3)
        else:
            platform.acquire(platform.slew_duration() + 37.3)
        block = platform.acquire(40.0)
        rows.append(np.column_stack([block.time, block.specific_force, block.angles, block.temperature]))
    return np.vstack(rows), platform.time


@pytest.mark.parametrize("quantization", [0.0, 1e-5])
def test_waiting_gives_the_outputs_recording_gives(quantization):
    noise = NoiseSettings.quartz()
    noise = NoiseSettings(**{**noise.__dict__, "quantization": quantization})
    truth = Truth.draw(4, noise=noise, effects={"Kh_x": 5e-5, "Dg_zz": 1e-8})
    waited, t_waited = _session(truth, wait=True)
    recorded, t_recorded = _session(truth, wait=False)
    assert t_waited == t_recorded
    np.testing.assert_array_equal(waited, recorded)
    assert np.std(waited[:, 1]) > 0  # noise and motion are in it


@pytest.mark.parametrize("world_effects", [{}, {"tilt_north": 2e-5, "ang1_inner_c": 3e-6}])
def test_platform_matrices_per_run_of_equal_readings_are_those_row_by_row(world_effects):
    """Issue 30: ``C_n^p`` is made once per run of equal noise-free readings (a settled dwell), equal to the bit."""
    truth = Truth.draw(5, effects=world_effects)
    platform = SimulatedPlatform(truth, rate=10, seed=3)
    platform.command((0.0, 0.7853981633974483, 0.0))
    index = np.arange(0, int(round((platform.slew_duration() + 200.0) * 10)))
    readings, *_ = platform._path(index)
    repeated = np.all(readings[1:] == readings[:-1], axis=1)
    assert 0 < repeated.sum() < len(repeated)  # the slew and the transient differ, the settled readings repeat
    fast = platform._dcm_nav_to_platform(readings)
    slow = np.stack([platform.platform.dcm_nav_to_platform(r) for r in readings])
    np.testing.assert_array_equal(fast, slow)
