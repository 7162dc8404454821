"""Fused coarse+fine record and joint fit of the coarse passes, judged against the truth simulator."""

import fcntl
import pickle
from dataclasses import replace

import numpy as np
import pytest
from device_world import GRAVITY, ExactPlatform, device_columns, draw_truth, outputs

from stableins.estimators.coarse import calibrate_coarse
from stableins.estimators.device import calibrate_device
from stableins.estimators.device_gauge import gauge_equivalent
from stableins.estimators.dwell import DwellSummary, dwells_from_columns
from stableins.estimators.joint import fit_joint
from stableins.estimators.result import FitResult
from stableins.estimators.setting import DeviceSetting
from stableins.noise import NoiseModel, sessions
from stableins.procedures.definition import load_procedure
from stableins.records import CalibrationRecord
from stableins.simulator.device import simulate_dwells
from stableins.simulator.truth import Truth

COARSE = load_procedure("device-coarse")
FINE = load_procedure("device-fine")
LAYOUTS = {"coarse": COARSE.layout, "fine": FINE.layout}


def _simulated_calibration(seed):
    """Quartz noise (white + 2 µg bias instability + random walk), two coarse passes and a fine stage."""
    truth = Truth.draw(seed)
    dwells = []
    for p in (1, 2):
        columns = simulate_dwells(
            truth, [s.command for s in COARSE.steps], dwell=20.0, settle=5.0, rate=50.0, seed=seed + 977 * p, stage="coarse", pass_number=p
        )
        dwells += dwells_from_columns(columns, layouts=LAYOUTS)
    columns = simulate_dwells(truth, [s.command for s in FINE.steps], dwell=120.0, settle=5.0, rate=5.0, seed=seed + 5003, stage="fine")
    dwells += dwells_from_columns(columns, layouts=LAYOUTS)
    noise = truth.noise
    slow = NoiseModel.given(noise.velocity_random_walk, noise.bias_instability, noise.acceleration_random_walk, provenance="datasheet")
    return calibrate_device(dwells, truth.site, layouts=LAYOUTS, noise=slow), gauge_equivalent(truth.parameters)


@pytest.fixture(scope="module")
def monte_carlo(tmp_path_factory, worker_id):
    """The 20 simulated device calibrations, built once per test session.

    Under pytest-xdist every worker that runs a test of this module would build the module fixture again (about
    80 s of the suite each); the first worker builds it and pickles it into the session's shared temporary
    directory, the others wait on the lock and read it (the xdist documentation's pattern, with ``fcntl`` locks).
    """
    if worker_id == "master":  # not under xdist: nothing to share
        return [_simulated_calibration(400 + k) for k in range(20)]
    shared = tmp_path_factory.getbasetemp().parent / "device_fusion_monte_carlo.pickle"
    with open(shared.with_suffix(".lock"), "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if shared.is_file():
            return pickle.loads(shared.read_bytes())
        calibrations = [_simulated_calibration(400 + k) for k in range(20)]
        shared.write_bytes(pickle.dumps(calibrations))
        return calibrations


def _z(fit, expected):
    return {k: (fit[k][0] - expected[k]) / fit[k][1] for k in fit.ids if fit[k][2] == "estimated"}


@pytest.mark.slow
def test_fused_sigma_is_honest_through_the_simulator(monte_carlo):
    z = [_z(c.fused, expected) for c, expected in monte_carlo]
    ids = list(z[0])
    assert len(ids) == 17  # every parameter but the gauge θ10, the six angles included
    per_parameter = np.array([[row[k] for k in ids] for row in z])  # (devices, 17)
    # 20 devices: mean z² of one parameter ~ χ²_20/20, 99.99 % interval [0.24, 2.7]
    mean_z2 = np.mean(per_parameter**2, axis=0)
    assert np.all((mean_z2 > 0.2) & (mean_z2 < 2.7)), dict(zip(ids, mean_z2.round(2), strict=True))
    # pooled over 340 estimates (correlated within a device): within about ±4σ of 1
    assert 0.7 < np.mean(per_parameter**2) < 1.35
    assert np.abs(per_parameter).max() < 5.0


@pytest.mark.slow
def test_fused_is_better_than_either_stage(monte_carlo):
    coarse_errors, fused_errors = [], []
    for calibration, expected in monte_carlo:
        coarse, fine, fused = calibration.coarse, calibration.fine, calibration.fused
        for k in fused.ids:
            if fused[k][2] != "estimated":
                continue
            assert fused[k][1] <= coarse[k][1] * (1 + 1e-9), k
            if k in fine.ids and fine[k][2] == "estimated":
                assert fused[k][1] <= fine[k][1] * (1 + 1e-9), k
        # the fine differences sharpen every installation angle
        gains = []
        for k in ("beta_xz", "beta_yz", "beta_zy", "beta_xy", "beta_yx", "beta_zx"):
            assert fine[k][2] == "unidentifiable" and fused[k][2] == "estimated"
            gains.append(fused[k][1] / coarse[k][1])
        assert max(gains) < 0.97 and np.median(gains) < 0.9, gains
        coarse_errors += [coarse[k][0] - expected[k] for k in ("sf_x", "sf_y", "sf_z")]
        fused_errors += [fused[k][0] - expected[k] for k in ("sf_x", "sf_y", "sf_z")]
    # the gain is real, not only in the stated σ: 60 scale-factor errors
    assert np.sqrt(np.mean(np.square(fused_errors))) < 0.8 * np.sqrt(np.mean(np.square(coarse_errors)))


def test_joint_fit_of_the_passes_gains_sqrt_two(monte_carlo):
    ratios, z = [], []
    for calibration, expected in monte_carlo:
        assert len(calibration.passes) == 2 and calibration.coarse.details.passes == (1, 2)
        one = calibration.passes[-1]
        for k in ("sf_x", "bias_y", "beta_xz", "theta20", "theta30"):
            ratios.append(calibration.coarse[k][1] / one[k][1])
        z += list(_z(calibration.coarse, expected).values())
    # two independent passes of the same design: 1σ shrinks by about 1/√2
    assert 0.6 < np.median(ratios) < 0.78
    assert 0.7 < np.mean(np.square(z)) < 1.35


def test_record_holds_the_fused_result_with_gauge_and_statuses(monte_carlo):
    calibration, _ = monte_carlo[0]
    record = CalibrationRecord.from_device(calibration, Truth.draw(400).site)
    assert record.provenance.stages == ("coarse+fine",)
    run = record.stages_run[0]
    assert [f["stage"] for f in run.fits] == ["coarse", "fine", "coarse+fine"]  # the evidence of every fit is kept
    assert run.settings == calibration.settings  # and the settings it ran with
    assert record["theta10"].status == "gauge" and record["theta10"].value == 0.0 and record["theta10"].sigma == 0.0
    for k in calibration.fused.ids:
        if k != "theta10":
            assert record[k].status == "estimated"
            assert record[k].value == calibration.fused[k][0] and record[k].sigma == pytest.approx(calibration.fused[k][1])
    # the report's χ² is the exact (whitened) one under slow noise
    fused = calibration.fused
    assert fused.whitened_residuals is not None
    assert run.fits[-1]["chi2"] == pytest.approx(fused.chi2)
    assert fused.chi2 == pytest.approx(float(fused.whitened_residuals @ fused.whitened_residuals))


def test_other_handedness_fine_stage_cannot_spoil_the_fused_scale_factors():
    # y never points down with senses (1, −1, 1, 1) and the +1 procedures: the fine stage is nearly singular
    truth = draw_truth(np.random.default_rng(31), quadratic=False)
    senses = (1, -1, 1, 1)
    site = ExactPlatform(truth, senses=senses).metadata
    coarse = dwells_from_columns(device_columns(truth, COARSE, sigma=1e-3, seed=1, senses=senses), layouts=LAYOUTS)
    fine = dwells_from_columns(device_columns(truth, FINE, sigma=1e-3, seed=7, stage="fine", dwell=60.0, senses=senses), layouts=LAYOUTS)
    result = calibrate_device(coarse + fine, site, layouts=LAYOUTS)
    expected = gauge_equivalent(truth, _config(site))
    assert result.fine["sf_y"][1] > 100 * result.coarse["sf_y"][1]  # the fine stage alone is useless for sf_y
    for k in ("sf_x", "sf_y", "sf_z", "bias_x", "bias_y", "bias_z"):
        assert result.fused[k][1] <= result.coarse[k][1] * (1 + 1e-9), k
        assert abs(result.fused[k][0] - expected[k]) < 5 * result.fused[k][1], k
    record = CalibrationRecord.from_device(result, site)
    assert record["sf_y"].sigma == pytest.approx(result.fused["sf_y"][1]) and record["sf_y"].sigma < 1e-5


def test_fusion_equals_the_information_update_in_the_linear_white_noise_limit():
    # Small noise: the joint GLS is the information-form update of the coarse estimate by the fine rows.
    truth = draw_truth(np.random.default_rng(41))
    rng = np.random.default_rng(3)
    readings = np.array([s.command for s in COARSE.steps])

    def dwells(stage, sigma):
        means = outputs(truth, readings) + sigma * rng.normal(size=(18, 3))
        return [
            DwellSummary(p + 1, stage, 1, r, r, m, np.full(3, sigma), np.full(3, 1e-3), 1000, 60.0, start=100.0 * p)
            for p, (r, m) in enumerate(zip(readings, means, strict=True))
        ]

    coarse_dwells, fine_dwells = dwells("coarse", 2e-5), dwells("fine", 3e-6)
    config = ExactPlatform(truth).metadata
    coarse = calibrate_coarse(coarse_dwells, setting=DeviceSetting(GRAVITY), nonlinear=True)
    fused = fit_joint(
        coarse_dwells, fine_dwells, setting=DeviceSetting(GRAVITY, configuration=_config(config)), start=coarse, stage="coarse+fine"
    )
    # information update: P⁻¹ = P_c⁻¹ + J_fᵀ R_f⁻¹ J_f on the free parameters
    from stableins.estimators.fine import FineProblem, fine_model

    fm = fine_model()
    problem = FineProblem(np.array([d.mean for d in fine_dwells])[None], np.array([d.sem for d in fine_dwells])[None], GRAVITY, fm)
    columns = [coarse.ids.index(k) for k in fm.ids]
    _, a = problem.weighted(fused.values[columns][None])
    free = [i for i, st in enumerate(coarse.status) if st == "estimated"]
    info = np.linalg.inv(coarse.covariance[np.ix_(free, free)])
    j = np.zeros((a.shape[1], len(coarse.ids)))
    j[:, columns] = a[0]
    info_fused = info + j[:, free].T @ j[:, free]
    expected = np.linalg.inv(info_fused)
    scale = np.sqrt(np.outer(np.diag(expected), np.diag(expected)))
    # equal up to the relinearization (the coarse covariance is taken at the coarse estimate): 0.2 % of σ_i σ_j
    assert np.abs(fused.covariance[np.ix_(free, free)] - expected).max() < 2e-3 * scale.max() and np.all(
        np.abs(fused.covariance[np.ix_(free, free)] - expected) < 2e-3 * scale
    )


def _config(site):
    from stableins.conventions import GimbalConfiguration

    return GimbalConfiguration(tuple(site.gimbal_senses))


def test_sessions_on_separate_time_bases_are_independent():
    starts = np.array([0.0, 100.0, 200.0, 0.0, 100.0])  # second run restarts its clock
    lengths = np.full(5, 60.0)
    assert sessions(starts, lengths).tolist() == [0, 0, 0, 1, 1]
    slow = NoiseModel.given(bias_instability=2 * 9.80665e-6, random_walk=1e-6)
    cov = slow.slow_covariance(starts, lengths)
    assert np.all(cov[:, :3, 3:] == 0.0)
    np.testing.assert_allclose(cov[:, 3:, 3:], slow.slow_covariance(starts[3:], lengths[3:]))
    np.testing.assert_allclose(cov[:, :3, :3], slow.slow_covariance(starts[:3], lengths[:3]))
    assert np.all(cov[:, :3, :3] > 0)  # one time base: correlated


def test_fit_result_chi2_uses_whitened_residuals_when_given():
    base = calibrate_coarse(
        [
            DwellSummary(p + 1, "coarse", 1, r, r, m, np.full(3, 1e-5), np.full(3, 1e-3), 1000, 20.0)
            for p, (r, m) in enumerate(
                zip(
                    np.array([s.command for s in COARSE.steps]),
                    outputs(draw_truth(np.random.default_rng(5)), np.array([s.command for s in COARSE.steps]))
                    + 1e-5 * np.random.default_rng(6).normal(size=(18, 3)),
                    strict=True,
                )
            )
        ],
        setting=DeviceSetting(GRAVITY),
    )
    assert base.whitened_residuals is None
    assert base.chi2 == pytest.approx(float(np.sum((base.residuals / base.residual_sigma) ** 2)))
    whitened = np.full(base.residuals.shape, 0.5)
    exact = replace(base, whitened_residuals=whitened)
    assert exact.chi2 == pytest.approx(0.25 * base.residuals.size)
    assert f"chi2_red = {exact.chi2_red:.3f}" in exact.report()
    assert not exact.whitened_residuals.flags.writeable
    with pytest.raises(ValueError, match="whitened_residuals"):
        replace(base, whitened_residuals=np.zeros(3))
    assert isinstance(exact, FitResult)
