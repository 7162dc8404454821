"""The systematic stage's optional cross-coupling states (issue 18): Cai et al. 2016's six ``Kcc`` terms.

The accelerometer block of the state is :attr:`StateLayout.accelerometer_ids`: the core ids, the cross-couplings the
record's error model holds, and Cai's six with ``SystematicOptions(cross_coupling=True)``.  The model's ``Kcc``
columns against the truth simulator and against central differences are in tests/test_systematic.py
(``test_model_reproduces_the_noise_free_world[cross-coupling]``, ``test_accelerometer_block_is_the_error_model_jacobian``).
Fixed seeds and k·σ bounds.
"""

import argparse
import json
from dataclasses import replace

import numpy as np
import pytest
from systematic_world import CROSS_COUPLING_SIGMA, indexed_record, indexed_truth, true_values, unit_prior, with_cross_coupling

from stableins.commands import calibrate_system
from stableins.data.chunks import ArraySource
from stableins.data.system import SystemRecordWriter
from stableins.errormodel import CORE_IDS, CORE_TERMS, GIMBAL_TERMS, MICRO_G_PER_G2, ErrorModel
from stableins.errors import InputError
from stableins.estimators.result import FitResult
from stableins.estimators.system.loop import LOOP_STATES
from stableins.estimators.systematic import SystematicOptions, systematic_calibration
from stableins.estimators.systematic.model import GYRO_IDS, OFFSET_IDS, StateLayout, accelerometer_ids, slow_noise_times
from stableins.estimators.systematic.passes import NEW_TERM_SIGMA, RANK_GROUPS, initial_covariance
from stableins.estimators.systematic.rank import FREE_PRIOR
from stableins.records import CalibrationRecord
from stableins.simulator.noise import NoiseSettings
from stableins.terms import CAI_CROSS_COUPLING_IDS, CROSS_COUPLING_TERMS


def _with_terms(*ids):
    return ErrorModel.standard(nonlinear=True) + tuple(t for t in CROSS_COUPLING_TERMS if t.id in ids)


def test_layout_carries_the_record_cross_couplings():
    """The block: core ids; the record's Kcc terms; Cai's six on request; library order; one place for every slice."""
    assert accelerometer_ids(ErrorModel.standard(nonlinear=True)) == CORE_IDS
    assert accelerometer_ids(_with_terms("Kcc_xxy")) == (*CORE_IDS, "Kcc_xxy")
    both = accelerometer_ids(_with_terms("Kcc_zyz", "Kcc_xyz"), cross_coupling=True)  # a non-Cai term the record holds stays
    assert both == (*CORE_IDS, "Kcc_xxy", "Kcc_xxz", "Kcc_xyz", "Kcc_yxy", "Kcc_yyz", "Kcc_zxz", "Kcc_zyz")
    assert set(CAI_CROSS_COUPLING_IDS) == {"Kcc_xxy", "Kcc_xxz", "Kcc_yxy", "Kcc_yyz", "Kcc_zxz", "Kcc_zyz"}
    plain, layout = StateLayout(2, slow_noise_times()), StateLayout(2, slow_noise_times(), accelerometer_ids=both)
    assert layout.names[layout.accelerometer] == both and layout.names[layout.gyro] == GYRO_IDS
    assert layout.size == plain.size + 7 and layout.gyro.start == plain.gyro.start + 7
    assert np.all(layout.scales()[layout.accelerometer][15:] == 1e-7)  # state unit of a Kcc: 0.98 µg/g²
    assert layout.names[layout.offsets] == OFFSET_IDS
    with pytest.raises(ValueError, match="core ids then cross-couplings"):
        StateLayout(2, (), accelerometer_ids=("K2_x",))


def test_without_the_option_nothing_changes():
    """A record without cross-couplings and the default options: the states of the stage before the option existed."""
    model = ErrorModel.standard(nonlinear=True)
    layout = StateLayout(
        2, slow_noise_times(), accelerometer_ids=accelerometer_ids(model, cross_coupling=SystematicOptions().cross_coupling)
    )
    noise = [f"{k}_{a}" for k in ("rw", *(f"gm{int(t)}" for t in slow_noise_times())) for a in "xyz"]
    holds = [f"turn0_{a}" for a in "xyz"] + [f"c_{k}{h}_{a}" for k in ("rho", "att") for h in (0, 1) for a in "xyz"]
    base = ("base_north", "base_east", "base_down")
    before = (*LOOP_STATES, "theta_x", "theta_y", "theta_z", *noise, *CORE_IDS, *GYRO_IDS, *base, *OFFSET_IDS, *holds)
    assert layout.names == before and layout == StateLayout(2, slow_noise_times())
    assert [name for name, _ in RANK_GROUPS] == ["accelerometer", "nonlinearity", "gyro", "nuisance"]
    with pytest.raises(TypeError):
        SystematicOptions(30.0, 30, 3, 0.01, 1 << 18, (1e-4, 1e-4, 6e-4), 1e-3, {}, True)  # keyword only


def test_priors_of_the_cross_couplings():
    """A Kcc the record holds: its σ; a new one: the wide prior; the rank filter: free."""
    truth = with_cross_coupling(indexed_truth(4, rate=1.0), {"Kcc_xxy": 2e-6}, {"Kcc_xxy": 1e-6})
    prior = unit_prior(truth)
    assert "Kcc_xxy" in prior.ids and "Kcc_xxy" in prior.error_model
    ids = accelerometer_ids(prior.error_model, cross_coupling=True)
    layout = StateLayout(2, (), random_walk=False, accelerometer_ids=ids)
    scales = layout.scales()
    sigma = dict(
        zip(layout.names, np.sqrt(np.diag(initial_covariance(layout, prior, SystematicOptions(), diffuse=False))) * scales, strict=True)
    )
    free = dict(
        zip(layout.names, np.sqrt(np.diag(initial_covariance(layout, prior, SystematicOptions(), diffuse=True))) * scales, strict=True)
    )
    assert sigma["Kcc_xxy"] == pytest.approx(CROSS_COUPLING_SIGMA)
    assert all(sigma[i] == pytest.approx(NEW_TERM_SIGMA["Kcc"]) for i in CAI_CROSS_COUPLING_IDS if i != "Kcc_xxy")
    assert all(free[i] == pytest.approx(FREE_PRIOR["Kcc_"]) for i in CAI_CROSS_COUPLING_IDS)
    k = prior.ids.index("K2_x")
    assert sigma["K2_x"] == pytest.approx(np.sqrt(prior.covariance[k, k]))


def test_cross_coupling_flag_needs_systematic(tmp_path):
    parser = argparse.ArgumentParser()
    calibrate_system.configure(parser)
    args = parser.parse_args(["x.h5", "--prior", "cal.json", "--out", str(tmp_path / "out.json"), "--cross-coupling"])
    with pytest.raises(InputError) as error:
        calibrate_system.run(args)
    assert error.value.field == "--cross-coupling" and not (tmp_path / "out.json").exists()


# ----------------------------------------------------------------------------- the stage on a simulated record
#: Cai et al. 2016's Table 3 cross-couplings (µg/g²), hidden in the world.
CAI_TABLE_3 = {"Kcc_xxy": -2.0, "Kcc_xxz": -22.6, "Kcc_yxy": 7.8, "Kcc_yyz": 16.5, "Kcc_zxz": -0.5, "Kcc_zyz": 1.6}


@pytest.fixture(scope="module")
def hidden_kcc():
    """8 h at 2 Hz, two holds, Cai's six hidden; the record holds Kcc_xxy (installed 4 µg/g² off); the quartz noise ×0.1.

    With the quartz noise itself a day determines Kcc_xxy alone (benchmarks/bench_systematic.py part 6); a tenth of it
    lets eight hours determine three of the six, so that recovery and leaving out are both exercised, fast.
    """
    q = NoiseSettings.quartz()
    noise = replace(
        q,
        velocity_random_walk=0.1 * q.velocity_random_walk,
        bias_instability=0.1 * q.bias_instability,
        acceleration_random_walk=0.1 * q.acceleration_random_walk,
        quantization=0.1 * q.quantization,
    )
    kcc = {k: v * MICRO_G_PER_G2 for k, v in CAI_TABLE_3.items()}
    truth = with_cross_coupling(indexed_truth(11, rate=2.0, noise=noise), kcc, {"Kcc_xxy": kcc["Kcc_xxy"] + 4 * MICRO_G_PER_G2})
    record = indexed_record(truth, 8 * 3600.0, rate=2.0)
    options = SystematicOptions(iterations=2, cross_coupling=True)
    return truth, systematic_calibration(ArraySource(record), truth.site, unit_prior(truth), options)


def test_hidden_cross_couplings_recovered_when_determined(hidden_kcc):
    """Determined cross-couplings (σ ≤ 5 µg/g²) are written and recovered within 4σ; the others are named and left out."""
    truth, result = hidden_kcc
    ids = tuple(t.id for t in result.fit.terms)
    z = (result.fit.values - true_values(truth, ids)) / result.fit.sigma
    assert np.all(np.abs(z) < 4.5), dict(zip(ids, np.round(z, 2), strict=True))
    written = [i for i in CAI_CROSS_COUPLING_IDS if i in ids]
    assert set(written) | set(result.details.left_out) == set(CAI_CROSS_COUPLING_IDS)
    assert not set(written) & set(result.details.left_out)
    assert "Kcc_xxy" in written  # the record holds it: always updated
    resolution = 5 * MICRO_G_PER_G2
    new = [i for i in written if i != "Kcc_xxy"]
    assert len(new) >= 2 and all(result.fit.sigma[ids.index(i)] <= resolution for i in new)  # measured: Kcc_xxz, Kcc_yxy
    assert all(s > resolution for s in result.details.left_out.values()) and len(result.details.left_out) >= 2
    k = ids.index("Kcc_xxz")  # −22.6 µg/g²: seen by the data, not just consistent with zero
    assert abs(result.fit.values[k]) > 3 * result.fit.sigma[k] and abs(z[k]) < 4
    nonlinearity = next(g for g in result.details.rank if g.group == "nonlinearity")
    assert set(nonlinearity.ids) == {"K2_x", "K2_y", "K2_z", *CAI_CROSS_COUPLING_IDS}
    text = result.report()
    assert "cross-couplings (µg/g²)" in text and all(f"{i}" in text for i in CAI_CROSS_COUPLING_IDS)
    assert any("not written to the record" in n for n in result.fit.notes)


def test_record_update_with_cross_couplings(hidden_kcc):
    """The record gains the determined cross-couplings with σ, not the others; no σ grows."""
    truth, result = hidden_kcc
    prior = unit_prior(truth)
    terms = tuple(CORE_TERMS) + tuple(GIMBAL_TERMS) + tuple(t for t in CROSS_COUPLING_TERMS if t.id == "Kcc_xxy")
    values = np.array([float(truth.installed_calibration.get(t.id, t.reference)) for t in terms])
    fit = FitResult("fine", terms, values, prior.covariance, ("estimated",) * len(terms), np.zeros(0), np.zeros(0))
    record = CalibrationRecord.from_fit_result(fit, serial_number=truth.site.serial_number, noise_model=prior.noise_model)
    assert record.error_model().ids[-1] == "Kcc_xxy"
    updated = record.updated(result.fit)
    before = dict(zip(record.ids, np.sqrt(np.diag(record.covariance)), strict=True))
    after = dict(zip(updated.ids, np.sqrt(np.diag(updated.covariance)), strict=True))
    assert all(after[i] <= before[i] * (1 + 1e-9) for i in before)
    written = [i for i in CAI_CROSS_COUPLING_IDS if i in {t.id for t in result.fit.terms}]
    assert all(i in updated.ids and np.isfinite(after[i]) and updated[i].status == "estimated" for i in written)
    assert not set(result.details.left_out) & set(updated.ids)
    assert set(written) <= set(updated.error_model().ids)  # the INS compensates with them from now on
    for i in written:
        assert abs(updated[i].value - truth.effects[i]) < 4 * after[i], i


def test_cli_cross_coupling(tmp_path, capsys):
    """``--cross-coupling``: the JSON names Cai's six; the record holds those written, with σ, and not the others."""
    truth = indexed_truth(8, rate=1.0)
    with SystemRecordWriter(tmp_path / "system.h5", truth.site) as writer:
        writer.append(indexed_record(truth, 4 * 3600.0, rate=1.0))
    prior = unit_prior(truth)
    terms = tuple(CORE_TERMS) + tuple(GIMBAL_TERMS)
    values = np.array([float(truth.installed_calibration.get(t.id, t.reference)) for t in terms])
    fit = FitResult("fine", terms, values, prior.covariance, ("estimated",) * len(terms), np.zeros(0), np.zeros(0))
    serial = truth.site.serial_number
    CalibrationRecord.from_fit_result(fit, serial_number=serial, noise_model=prior.noise_model).save(tmp_path / "cal.json")
    parser = argparse.ArgumentParser()
    calibrate_system.configure(parser)
    parser.add_argument("--json", action="store_true")
    argv = [str(tmp_path / "system.h5"), "--prior", str(tmp_path / "cal.json"), "--systematic", "--cross-coupling"]
    assert calibrate_system.run(parser.parse_args([*argv, "--out", str(tmp_path / "cal2.json"), "--json"])) == 0
    document = json.loads(capsys.readouterr().out)
    assert set(document["cross_coupling"]) == set(CAI_CROSS_COUPLING_IDS)
    updated = CalibrationRecord.load(tmp_path / "cal2.json")
    for name, entry in document["cross_coupling"].items():
        if entry.get("written", True):
            assert name in updated.ids and entry["sigma"] <= 5.0 and entry["value"] is not None
        else:
            assert name not in updated.ids and entry["sigma"] > 5.0 and entry["value"] is None
