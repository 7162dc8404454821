"""Real data (issue 26): two public logs shipped in tests/data/real (sources and licences in its README)."""

import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest

from stableins.cli import main
from stableins.data.holds import detect_holds
from stableins.estimators.dwell import slow_covariance
from stableins.estimators.poses import calibrate_poses, summarize_holds

ROOT = Path(__file__).resolve().parent.parent
_spec = importlib.util.spec_from_file_location("bench_real_data", ROOT / "benchmarks" / "bench_real_data.py")
assert _spec is not None and _spec.loader is not None
bench = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(bench)


def test_raw_count_log_of_hand_placed_poses_agrees_with_an_independent_fit(tmp_path, capsys):
    out = tmp_path / "cal.json"
    argv = ["calibrate", "poses", str(bench.XSENS), "--columns", "time=1,f_x=2,f_y=3,f_z=4", "--units", "counts:4100/g"]
    argv += ["--zero", "32768", "--range", "0:65535", "--gravity", str(bench.XSENS_GRAVITY), "--out", str(out), "--json"]
    assert main(argv) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["holds"] >= 30 and result["left_out"] == {}  # every hold found is used: none taken for clipped
    assert result["model"] == "TWELVE" and np.isfinite(result["chi2_red"])
    # the same fit in Python, against least squares written from the model alone (scipy), with the same covariance
    log = bench.xsens_log()
    holds = detect_holds(log.time, log.specific_force, resolution=log.resolution).holds
    dwells = summarize_holds(log.time, log.specific_force, log.railed, [(h.first, h.stop) for h in holds])
    from stableins.estimators.device import noise_from_dwells

    noise = noise_from_dwells(dwells)
    assert noise.has_slow_noise
    fit = calibrate_poses(dwells, gravity=bench.XSENS_GRAVITY, noise=noise)
    for name in ("sf_x", "bias_z", "K2_y"):
        assert fit[name][0] == pytest.approx(result["parameters"][name]["value"], rel=1e-12)
    means = np.array([d.mean for d in dwells])
    start = [1.0, 1.0, 1.0, *(0.5 * (means.max(0) + means.min(0))), 0, 0, 0, 0, 0, 0]
    p, sigma, chi2, dof = bench.independent_fit(
        means, np.array([d.sem for d in dwells]), bench.XSENS_GRAVITY, start, slow_covariance(dwells, noise)
    )
    mine, mine_sigma = bench.stableins_vector(fit)
    assert np.max(np.abs(mine - p) / mine_sigma) < 0.1
    np.testing.assert_allclose(mine_sigma, sigma, rtol=1e-3)
    assert fit.chi2 == pytest.approx(chi2, rel=1e-6) and fit.dof == dof


def test_six_position_session_reproduces_imucals_published_result():
    log, parts = bench.imucal_log()
    assert len(detect_holds(log.time, log.specific_force, resolution=log.resolution).holds) == 6
    from stableins.conventions import STANDARD_GRAVITY
    from stableins.data.holds import Hold
    from stableins.estimators.poses import six_position

    holds = [Hold(int(np.flatnonzero(parts == p)[0]), int(np.flatnonzero(parts == p)[-1]) + 1, lab) for p, lab in bench.LABELS.items()]
    dwells = summarize_holds(log.time, log.specific_force, log.railed, [(h.first, h.stop) for h in holds])
    fit = six_position(dwells, [h.orientation for h in holds], gravity=bench.IMUCAL_GRAVITY)
    scale = bench.IMUCAL_COUNTS_PER_G / STANDARD_GRAVITY
    np.testing.assert_allclose([fit[f"bias_{a}"][0] * scale for a in "xyz"], bench.IMUCAL_B_A, rtol=1e-9)
    # imucal's K_a adds the off-axis readings (its Eq. 23); the on-axis part is the six-position scale factor
    k_on_axis = np.array([scale / fit[f"sf_{a}"][0] for a in "xyz"])
    assert np.all(np.abs(k_on_axis / bench.IMUCAL_K_A - 1) < 5e-4)
