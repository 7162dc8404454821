"""The polar-alignment check of the system stage (docs/system-calibration.md §9, issue 25).

The gimbal readings give the platform's orientation in inertial space, so they tell a platform whose z_p misses the
pole (a base tilted under a platform aligned for a level one) from a gyro drift along z_p (the platform turns about its
own axis): the first is refused, the second measured, whatever the platform-axis angle's rate says.
"""

import math

import numpy as np
import pytest

from stableins.conventions import DEG_PER_HOUR, EARTH_RATE
from stableins.data.chunks import ArraySource
from stableins.errors import InputError
from stableins.estimators.system.options import SystemOptions
from stableins.estimators.system.polar import RATE_TOLERANCE_UNCHECKED, PolarAlignment, check_polar_alignment
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
    drift = 0.005 * DEG_PER_HOUR
    with pytest.raises(InputError, match="equatorial gyro drift") as turning:
        check_polar_alignment(_polar((0.0, 0.0), (0.0, drift * 86164.0), (drift, 0.0, 0.0)), 1.0, options, "r.h5")
    assert "+0.005" in str(turning.value)
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


def test_an_equatorial_drift_that_turns_z_p_off_the_pole_is_refused_naming_it():
    """0.005 °/h along x_p turns z_p 2.1 mrad off the pole in a day (the velocity stays under 1 m/s)."""
    truth, cols = simulated_day(12, gyro_drift={"x": 0.005 * DEG_PER_HOUR})
    with pytest.raises(InputError, match="equatorial gyro drift") as err:
        run_system_stage(ArraySource(cols), truth.site, truth.installed_calibration)
    assert "compensate its gyros" in str(err.value)
    assert math.isfinite(float(str(err.value).split("mrad at its end")[0].split()[-1]))


@pytest.mark.slow
def test_cli_gyro_z_world_runs_and_the_gyro_world_is_refused_naming_the_drift(tmp_path, capsys):
    """`simulate system --world gyro-z`, `calibrate system`, `diagnose`: exit 0; the `gyro` world (0.05 °/h on every axis,
    uncompensated): `calibrate system` exits 2 naming the gyro drift, no traceback."""
    from stableins import cli
    from stableins.data.truth import load_truth
    from tests.test_system_cli import prior_record

    for name, code in (("gyro-z", 0), ("gyro", 2)):
        sim = tmp_path / name
        assert cli.main(["simulate", "system", "--world", name, "--seed", "3", "--rate", "1", "--out", str(sim)]) == 0
        prior = tmp_path / f"{name}-prior.json"
        prior_record(load_truth(sim / "truth.json").installed_calibration, serial="SIM-3").save(prior)
        out = tmp_path / f"{name}-cal.json"
        capsys.readouterr()
        assert cli.main(["calibrate", "system", str(sim / "system.h5"), "--prior", str(prior), "--out", str(out)]) == code
        captured = capsys.readouterr()
        assert "Traceback" not in captured.err
        if code:
            assert "gyro" in captured.err and not out.exists()
            continue
        assert "gyro drift from the gimbal readings" in captured.out
        assert cli.main(["diagnose", str(sim / "system.h5"), "--record", str(out)]) == 0
