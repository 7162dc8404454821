"""Device-level calibration judged against the truth simulator (stableins.simulator)."""

from dataclasses import replace

import numpy as np
import pytest

from stableins.cli import main
from stableins.conventions import ARCSEC
from stableins.data.device import save_device
from stableins.estimators.device import calibrate_device
from stableins.estimators.device_gauge import gauge_equivalent
from stableins.estimators.dwell import dwells_from_columns
from stableins.noise import NoiseModel
from stableins.procedures.definition import load_procedure
from stableins.procedures.iteration import iterate_offsets
from stableins.records import CalibrationRecord
from stableins.simulator.device import SimulatedPlatform, simulate_dwells
from stableins.simulator.noise import NoiseSettings
from stableins.simulator.truth import SimulatedSite, Truth

COARSE = load_procedure("device-coarse")
FINE = load_procedure("device-fine")
LAYOUTS = {"coarse": COARSE.layout, "fine": FINE.layout}
WHITE = NoiseSettings(velocity_random_walk=4.5e-4, angle_noise=0.2 * ARCSEC)


def _session(truth, seed, fine_rate=10.0, fine_dwell=600.0):
    coarse = simulate_dwells(truth, [s.command for s in COARSE.steps], dwell=20.0, settle=5.0, seed=seed, stage="coarse")
    commands = [s.command for s in FINE.steps]
    fine = simulate_dwells(truth, commands, dwell=fine_dwell, settle=5.0, rate=fine_rate, seed=seed + 1, stage="fine")
    return coarse, fine


def _dwells(coarse, fine):
    coarse_dwells = dwells_from_columns(coarse, checks=COARSE.checks)
    return coarse_dwells + dwells_from_columns(fine, checks=FINE.checks)


def test_offset_iteration_converges_from_60_arcsec_through_the_simulated_platform():
    truth = Truth.draw(7, noise=NoiseSettings.quiet())
    parameters = dict(truth.parameters, theta20=60 * ARCSEC, theta30=-60 * ARCSEC)
    platform = SimulatedPlatform(truth.with_changes(parameters=parameters))
    result = iterate_offsets(platform, COARSE, stopping=replace(COARSE.offset_iteration, noise_sigmas=0.0))
    assert 2 <= len(result.history) <= 3
    assert result.history[0].residual[0] == pytest.approx(60 * ARCSEC, abs=0.1 * ARCSEC)
    assert all(abs(r) < 0.1 * ARCSEC for r in result.history[-1].residual)
    assert result.offsets[1] == pytest.approx(60 * ARCSEC, abs=0.01 * ARCSEC)
    assert result.offsets[2] == pytest.approx(-60 * ARCSEC, abs=0.01 * ARCSEC)
    # the last pass was re-pointed through the driver: inner command = nominal − θ̂20
    assert platform.history[-1]["readings"][1] == pytest.approx(COARSE.steps[-1].command[1] - result.history[-1].commanded_offsets[0])


def test_exact_recovery_of_the_simulator_truth_without_noise():
    truth = Truth.draw(11, noise=NoiseSettings.quiet())
    calibration = calibrate_device(_dwells(*_session(truth, 11, fine_rate=10.0, fine_dwell=60.0)), truth.site, layouts=LAYOUTS)
    expected = gauge_equivalent(truth.parameters)
    coarse, fine = calibration.coarse, calibration.fine
    for k in coarse.ids:
        if coarse[k][2] == "estimated":
            assert coarse[k][0] == pytest.approx(expected[k], abs=1e-6 * coarse.terms[coarse.ids.index(k)].nominal), k
    for k in fine.ids:
        if fine[k][2] == "estimated":
            assert fine[k][0] == pytest.approx(expected[k], abs=1e-6 * fine.terms[fine.ids.index(k)].nominal), k


@pytest.mark.parametrize("seed", [21, 22, 23])
def test_recovery_within_k_sigma_of_the_simulator_truth(seed):
    truth = Truth.draw(seed, noise=WHITE)
    calibration = calibrate_device(
        _dwells(*_session(truth, seed)), truth.site, layouts=LAYOUTS, noise=NoiseModel.given(provenance="white noise only")
    )
    expected = gauge_equivalent(truth.parameters)
    z = []
    for fit in (calibration.coarse, calibration.fine):
        for k in fit.ids:
            value, sigma, status = fit[k]
            if status == "estimated":
                z.append((value - expected[k]) / sigma)
    for name, (value, sigma) in calibration.fine.combinations.items():
        a, _, b = name.split()
        z.append((value - (expected[a] - expected[b])) / sigma)
    z = np.array(z)
    assert np.abs(z).max() < 4.5
    assert 0.3 < np.mean(z**2) < 2.0  # 29 estimates: χ²/29 within about ±2.6 standard deviations


def test_cli_calibrates_simulated_files_and_writes_a_record(tmp_path, capsys):
    truth = Truth.draw(5, noise=WHITE)
    coarse, fine = _session(truth, 5, fine_rate=10.0, fine_dwell=120.0)
    files = []
    for name, columns in (("coarse", coarse), ("fine", fine)):
        files.append(str(save_device(tmp_path / f"device-{name}.csv", columns, replace(truth.site, extra={"procedure": name}))))
    out = tmp_path / "record.json"
    assert main(["calibrate", "device", *files, "--out", str(out), "--bias-instability", "0", "--verbose"]) == 0
    text = capsys.readouterr().out
    assert "rank = 17 of 18" in text and "rank = 12 of 15" in text and "beta_xz − beta_yz" in text
    record = CalibrationRecord.load(out)
    assert record["theta10"].status == "gauge"
    assert record["K2_x"].status == "estimated" and record["beta_xz"].status == "estimated"  # β from the coarse stage
    assert record.provenance.stages == ("coarse+fine", "gyro") and record.calibration.procedure == "device-coarse + device-fine"
    assert record.stages[0].environment["temperature"]["unit"] == "degC"
    expected = gauge_equivalent(truth.parameters)
    assert abs(record["sf_x"].value - expected["sf_x"]) < 5 * record["sf_x"].sigma


def test_cli_bad_input_exits_2_without_writing_a_record(tmp_path, capsys):
    truth = Truth.draw(6, noise=WHITE)
    coarse, _ = _session(truth, 6, fine_rate=1.0, fine_dwell=30.0)
    coarse["f_x"] = -coarse["f_x"]  # x axis wired backwards
    path = save_device(tmp_path / "coarse.csv", coarse, truth.site)
    out = tmp_path / "record.json"
    assert main(["calibrate", "device", str(path), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "x axis sign inverted" in err and "Traceback" not in err
    assert not out.exists()


@pytest.mark.parametrize(
    "site, sign",
    [(dict(base_attitude=(0.3, 0.01, -0.02)), "+"), (dict(gimbal_senses=(-1, -1, 1, 1)), "−"), (dict(gimbal_senses=(1, -1, -1, 1)), "+")],
)
def test_exact_recovery_for_tilted_bases_and_other_senses(site, sign):
    from stableins.conventions import GimbalConfiguration

    truth = Truth.draw(12, noise=NoiseSettings.quiet(), site=SimulatedSite(**site))
    calibration = calibrate_device(_dwells(*_session(truth, 12, fine_rate=5.0, fine_dwell=60.0)), truth.site, layouts=LAYOUTS)
    expected = gauge_equivalent(truth.parameters, GimbalConfiguration(truth.site.gimbal_senses))
    for fit in (calibration.coarse, calibration.fine):
        for k, term in zip(fit.ids, fit.terms):
            if fit[k][2] == "estimated":
                assert fit[k][0] == pytest.approx(expected[k], abs=1e-6 * term.nominal), k
    # the determined combination follows the platform-axis sense s1: β_xz + s1·θ10
    assert f"beta_xz estimates beta_xz {sign} theta10" in calibration.coarse.determined
