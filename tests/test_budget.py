"""Type B uncertainty budget (issue 13): every sensitivity against a re-run of the fit with its input perturbed.

The device stages run on the truth simulator's quartz instrument (short dwells), the system stage on a
synthetic one-day record at 1 Hz (tests/system_synthetic.py); the three-stage record they make is
certified and its certificate reviewed as a quality manager would (tests/certificate_checks.py).
"""

from __future__ import annotations

import json
import math
import shutil
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))
import budget_world  # noqa: E402
import certificate_checks  # noqa: E402
import report_fixtures as rf  # noqa: E402

from stableins.conventions import ARCSEC, DEG_PER_HOUR  # noqa: E402
from stableins.discovery.library import all_terms  # noqa: E402
from stableins.errors import InputError  # noqa: E402
from stableins.estimators.device import calibrate_device  # noqa: E402
from stableins.estimators.sensitivity import angle_reading_gradients  # noqa: E402
from stableins.estimators.system import sensitivity as system_sensitivity  # noqa: E402
from stableins.estimators.system.stage import SystemOptions  # noqa: E402
from stableins.procedures.definition import load_procedure  # noqa: E402
from stableins.records import CalibrationRecord, RunInfo  # noqa: E402
from stableins.reporting import write_report  # noqa: E402
from stableins.reporting.budget import (  # noqa: E402
    MGAL,
    NORMAL_GRAVITY_UNCERTAINTY,
    UncertaintyInputs,
    gravity_direction,
)
from stableins.reporting.budget_sources import uncertainty_budget  # noqa: E402

COARSE = load_procedure("device-coarse")
FINE = load_procedure("device-fine")
LAYOUTS = {"coarse": COARSE.layout, "fine": FINE.layout}
POPPLER = shutil.which("pdftoppm") and shutil.which("pdftotext")
needs_poppler = pytest.mark.skipif(not POPPLER, reason="pdftoppm/pdftotext (Debian package poppler-utils) are not installed")


@pytest.fixture(scope="module")
def device():
    """One simulated quartz instrument (tests/budget_world.py): its datasheet noise, device calibration and record."""
    return budget_world.device(13)


def _differences(a: CalibrationRecord, b: CalibrationRecord) -> np.ndarray:
    return np.array([b[pid].value - a[pid].value for pid in a.ids])


def test_gravity_sensitivity_is_the_refit_with_g_perturbed(device):
    """δg moves the scale factors by SF δg/g and nothing else: the budget's c_g against calibrate_device re-run with g + δg."""
    truth, dwells, noise, _, record = device
    dg = 30.0 * MGAL
    moved = CalibrationRecord.from_device(
        calibrate_device(dwells, replace(truth.site, gravity=truth.site.gravity + dg), layouts=LAYOUTS, noise=noise), truth.site
    )
    predicted = np.array([gravity_direction(record, all_terms()).get(pid, 0.0) for pid in record.ids]) * dg
    observed = _differences(record, moved)
    sigma = np.array([p.sigma if p.sigma > 0 else 1.0 for p in record.parameters])
    for k, pid in enumerate(record.ids):
        if pid.startswith("sf_"):
            assert predicted[k] == pytest.approx(dg / truth.site.gravity * record[pid].value, rel=1e-12)
            assert observed[k] == pytest.approx(predicted[k], rel=1e-3), pid  # 31 ppm, to 0.03 ppm
        else:
            assert abs(observed[k]) < 1e-3 * sigma[k], pid
    # through the record (P Σ Λ_k v): the same
    budget = uncertainty_budget(replace(record, site=replace(record.site, gravity_uncertainty=dg)))
    contribution = budget.contributions["gravity"]
    np.testing.assert_allclose(contribution, np.abs(predicted), rtol=1e-6, atol=1e-18)


def test_angle_reading_sensitivity_is_the_refit_with_one_reading_moved(device):
    """∂x/∂r_{j,i} = P Aᵀ W E_{j,i}: against fit_joint re-run with one dwell's reading moved by 2″."""
    base, problem, coarse, fine, options = budget_world.joint(device)
    gradients = angle_reading_gradients(problem, base.values)
    np.testing.assert_allclose(base.sensitivities[0].covariance, gradients @ gradients.T, rtol=1e-9)  # what the record stores
    sigma = base.sigma
    for j, i in ((0, 1), (7, 2), (12, 0), (17, 1)):
        refit = budget_world.refit_with_reading_moved(options, coarse, fine, j, i, 2.0 * ARCSEC)
        predicted = base.covariance @ gradients[:, 3 * j + i] * 2.0 * ARCSEC
        assert np.abs(predicted / np.where(sigma > 0, sigma, 1.0)).max() > 0.02  # the reading moves something
        assert np.abs((refit.values - base.values - predicted) / np.where(sigma > 0, sigma, 1.0)).max() < 1e-3, (j, i)


@pytest.fixture(scope="module")
def system(device):
    """The system stage on a one-day synthetic record (1 Hz) of the same unit, with the device record as its prior."""
    prior = device[4]
    run, meta = budget_world.system_day(prior, gravity_uncertainty=0.05 * MGAL)
    source, values, covariance = run.source, run.values, run.covariance
    base = run()
    found = system_sensitivity.system_sensitivities(source, meta, values, covariance, SystemOptions(estimate_gyro_drift=False), base=base)
    record = prior.updated(replace(base.result, sensitivities=found), RunInfo(procedure="system-static"), site=meta)
    return run, base, found, record, meta


def test_system_gravity_sensitivity_is_the_scale_factor_direction(system):
    """The system stage sees g only through x1's normalization: its likelihood moves by Λ v, v the device stages' direction."""
    run, base, _, _, meta = system
    dg = 30.0 * MGAL
    moved = run(metadata=replace(meta, gravity=meta.gravity + dg))
    lik = base.result.likelihood
    observed = (moved.result.likelihood.gradient - lik.gradient) / dg
    v = np.array([lik.point[k] / meta.gravity if pid.startswith("sf_") else 0.0 for k, pid in enumerate(lik.ids)])
    predicted = lik.information @ v
    assert np.abs(predicted).max() > 0
    np.testing.assert_allclose(observed, predicted, atol=2e-3 * np.abs(predicted).max())


def test_system_sensitivities_are_linear_in_the_step_and_the_polar_drift_is_invisible(system):
    run, base, found, _, meta = system
    by_input = {s.input: s for s in found}
    assert set(by_input) == {"gyro_drift.x", "gyro_drift.y", "gyro_drift.z", "damping_loop.zeta"}
    lik = base.result.likelihood
    drift, zeta = 4 * system_sensitivity.DRIFT_STEP, 4 * system_sensitivity.LOOP_STEP * 0.5
    for name, options, metadata, step in (
        ("gyro_drift.x", SystemOptions(known_gyro_drift=(drift, 0.0, 0.0), estimate_gyro_drift=False), meta, drift),
        ("damping_loop.zeta", SystemOptions(estimate_gyro_drift=False), replace(meta, damping={"zeta": 0.5 + zeta}), zeta),
    ):
        again = (run(options, metadata).result.likelihood.gradient - lik.gradient) / step
        np.testing.assert_allclose(again, by_input[name].gradient, atol=0.01 * np.abs(by_input[name].gradient).max())
    # a drift along the platform z axis (the Earth's axis) is not modulated by the Earth rate: no effect
    assert np.abs(by_input["gyro_drift.z"].gradient).max() < 1e-6 * np.abs(by_input["gyro_drift.x"].gradient).max()


def test_system_sensitivities_reusing_the_stage_are_those_of_whole_re_runs(system):
    """The re-runs take the loop-independent steps from the stage's run (the drift step made again for a drift input)."""
    run, base, found, _, meta = system
    whole = system_sensitivity.system_sensitivities(
        run.source, meta, run.values, run.covariance, SystemOptions(estimate_gyro_drift=False), base=base, rerun=True
    )
    assert [s.input for s in found] == [s.input for s in whole]
    for a, b in zip(found, whole, strict=True):
        np.testing.assert_allclose(a.gradient, b.gradient, rtol=0, atol=1e-9 * np.abs(b.gradient).max(), err_msg=a.input)


def test_the_budget_of_a_record_is_the_record_re_made_with_the_input_perturbed(system, device):
    """c_q = P Σ ∂η_k/∂q through the Bayesian update: against the whole record re-made with a known drift.

    1e-5 °/h: the linear regime.  A drift error as large as its uncertainty (1e-3 °/h) is partly absorbed by the
    stage's coloured-noise model, which then weighs the system data less: the record moves less than the linear
    (GUM 5.1.2) coefficient says — benchmarks/bench_budget.py prints both.
    """
    run, _, found, record, meta = system
    prior = device[4]
    drift = 1e-5 * DEG_PER_HOUR
    moved = run(SystemOptions(known_gyro_drift=(drift, 0.0, 0.0), estimate_gyro_drift=False))
    remade = prior.updated(moved.result, RunInfo(procedure="system-static"), site=meta)
    observed = _differences(record, remade)
    x_axis = next(s for s in found if s.input == "gyro_drift.x")
    gradient = np.array([x_axis.gradient[x_axis.ids.index(pid)] if pid in x_axis.ids else 0.0 for pid in record.ids])
    covariance = np.nan_to_num(np.asarray(record.covariance))
    predicted = covariance @ gradient * drift
    sigma = np.array([p.sigma if p.sigma > 0 else 1.0 for p in record.parameters])
    assert np.abs(predicted / sigma).max() > 0.03  # 1e-5 °/h moves the attitude-determined parameters by a few % of σ
    np.testing.assert_allclose(observed / sigma, predicted / sigma, atol=0.02 * np.abs(predicted / sigma).max())
    # the budget: each group as stated, combined in quadrature, gravity exactly v on the scale factors
    budget = uncertainty_budget(record, UncertaintyInputs(gyro_drift=0.002 * DEG_PER_HOUR, damping_loop=0.01))
    assert budget.state("gyro_drift") == "evaluated" and budget.state("damping_loop") == "evaluated"
    per_axis = [covariance @ np.array([s.gradient[s.ids.index(p)] if p in s.ids else 0.0 for p in record.ids]) * 0.002 * DEG_PER_HOUR
                for s in found if s.group == "gyro_drift"]  # fmt: skip
    np.testing.assert_allclose(budget.contributions["gyro_drift"], np.sqrt(sum(c**2 for c in per_axis)), rtol=1e-9)
    total = budget.type_a**2 + sum(c**2 for c in budget.contributions.values())
    np.testing.assert_allclose(budget.combined, np.sqrt(total), rtol=1e-12)
    direction = gravity_direction(record, all_terms())
    k = record.ids.index("sf_x")
    assert budget.contributions["gravity"][k] == pytest.approx(direction["sf_x"] * 0.05 * MGAL, rel=1e-6)
    assert budget.contributions["gravity"][record.ids.index("bias_x")] < 1e-6 * budget.type_a[record.ids.index("bias_x")]


def test_sensitivities_survive_the_record_file(system, tmp_path):
    record = system[3]
    path = record.save(tmp_path / "record.json")
    again = CalibrationRecord.load(path)
    assert [s.input for st in again.stages for s in st.sensitivities] == [s.input for st in record.stages for s in st.sensitivities]
    np.testing.assert_allclose(uncertainty_budget(again).combined, uncertainty_budget(record).combined, rtol=1e-12)
    document = json.loads(path.read_text())
    document["stages"][-1]["sensitivities"][0]["gradient"] = [1.0]
    with pytest.raises(InputError, match="sensitivities"):
        CalibrationRecord.from_document(document, "bad.json")


PROCEDURE = rf.procedure_with(
    """[uncertainty]
gyro_drift = 0.001
damping_loop = 0.01
[uncertainty.temperature_sensitivity]
"bias_*" = 5.0
[tolerances.uncertainty]
"bias_*" = 20.0
"sf_*" = 20.0
"beta_*" = 10.0
[tolerances.fit]
interval = 0.95
"""
)


@needs_poppler
def test_three_stage_certificate_passes_review(system, tmp_path):
    """The budget on the certificate of a device + system record, reviewed page by page (tests/certificate_checks.py)."""
    record = system[3]
    (tmp_path / "proc.toml").write_text(PROCEDURE)
    out = tmp_path / "cal.pdf"
    write_report(out, record, procedure=tmp_path / "proc.toml")
    assert certificate_checks.review(out, tmp_path) == []
    text = " ".join("\n".join(certificate_checks.pages_text(certificate_checks.technical_of(out))).split())
    assert "Type B inputs" in text and "k = 2" in text and "0.001 °/h per" in text and "procedure (proc.toml)" in text
    assert "0.050 mGal (5.0 × 10⁻⁷ m/s²)" in text and "stated with the site" in text
    assert "δb x − g βxy sin L" in text or "δbx − g βxy sin L" in text  # the system stage's combinations, typeset


def test_uncertainty_table_is_validated_and_read():
    table = UncertaintyInputs.from_mapping(
        {"gravity": 0.1, "angle_sensor": 0.5, "gyro_drift": 0.002, "damping_loop": 0.02, "temperature_sensitivity": {"sf_*": 2.0}}
    )
    assert table.gravity == pytest.approx(1e-6) and table.angle_sensor == pytest.approx(0.5 * ARCSEC)
    assert table.gyro_drift == pytest.approx(0.002 * DEG_PER_HOUR) and table.temperature_sensitivity == {"sf_*": 2.0}
    for bad, match in (({"gravity": -1.0}, "uncertainty.gravity"), ({"angles": 1.0}, "unknown keys"),
                       ({"temperature_sensitivity": {"bias_*": "x"}}, "temperature_sensitivity.bias_")):  # fmt: skip
        with pytest.raises(InputError, match=match):
            UncertaintyInputs.from_mapping(bad, source="p.toml")


def test_gravity_default_and_temperature_sensitivity():
    """A record without likelihoods (the report fixture): normal gravity gives 30 mGal; a stated k_T the rectangular range."""
    record = CalibrationRecord.from_document(rf.record(rf.fit(1)))
    budget = uncertainty_budget(record, UncertaintyInputs(temperature_sensitivity={"bias_*": 5.0}))
    terms = all_terms()
    k = record.ids.index("sf_x")
    expected = float(terms["sf_x"].sigma_to_engineering(record["sf_x"].value / record.site.gravity * NORMAL_GRAVITY_UNCERTAINTY))
    assert float(terms["sf_x"].sigma_to_engineering(budget.contributions["gravity"][k])) == pytest.approx(expected, rel=1e-9)
    assert 29.0 < expected < 32.0  # ppm: the size of a gravity anomaly the normal-gravity formula omits
    b = record.ids.index("bias_x")
    spread = (25.07 - 24.62) / math.sqrt(12.0)  # the recorded range of the fixture's stage, rectangular
    assert float(terms["bias_x"].sigma_to_engineering(budget.contributions["temperature"][b])) == pytest.approx(5.0 * spread, rel=1e-3)
    assert budget.contributions["temperature"][k] == 0.0 and budget.state("gyro_drift") == "not applicable"
    assert budget.state("temperature") == "evaluated"
    without = uncertainty_budget(record)
    assert without.state("temperature") == "condition" and "24.62 to 25.07 °C" in without.conditions[0]


def test_unresolved_slow_noise_enters_u_as_the_largest_floor(device):
    """The note "the σ would be up to n× larger" is in U: with the noise model measured in the dwells and no slow noise
    detected, u_A ⊕ u(slow noise) of a data-only record is the σ of the refit with the largest floor the dwells allow.

    Seed 1 of the quartz world: its dwells do not resolve the slow noise (the default path's test, REML on the
    contrasts between passes and the Allan variance inside the dwells, detects it in seed 13, the fixture's)."""
    truth, dwells, _, _, _ = budget_world.device(1)
    calibration = calibrate_device(dwells, truth.site, layouts=LAYOUTS)  # no noise model given: measured in the dwells
    assert calibration.noise is not None and calibration.noise.test is not None and not calibration.noise.test.detected
    floor = calibration.floor
    assert floor is not None
    record = CalibrationRecord.from_device(calibration, truth.site)
    budget = uncertainty_budget(record)
    assert budget.state("slow_noise") == "evaluated" and "up to" in budget.source("slow_noise").uncertainty
    # the record's notes say what the console says: not detected, up to the limit; never "bias instability 0 µg"
    described = [n for s in record.stages for n in s.notes if n.startswith("noise model (")]
    assert described and all("slow noise not detected: bias instability up to" in n and "instability 0 µg" not in n for n in described)
    compared = 0
    for k, pid in enumerate(record.ids):
        if budget.type_a[k] > 0 and pid in floor.ids and floor[pid][1] > 0:
            assert math.hypot(budget.type_a[k], budget.contributions["slow_noise"][k]) == pytest.approx(floor[pid][1], rel=1e-9), pid
            compared += 1
    assert compared >= 15
    assert max(budget.contributions["slow_noise"] / np.where(budget.type_a > 0, budget.type_a, np.inf)) > 0.3  # it matters
    # a datasheet noise model (the fixture's record): nothing unresolved, the column does not apply
    assert uncertainty_budget(device[4]).state("slow_noise") == "not applicable"


def test_calibrate_device_takes_what_load_device_returns(tmp_path):
    """calibrate_device(load_device(...)) works — the datasets summarized as the CLI does — and gives the dwells' result."""
    from stableins.data.device import load_device, save_device
    from stableins.discovery.dwells import dwells_from_dataset
    from stableins.estimators.dwell import dwells_from_columns
    from stableins.estimators.setting import DeviceSetting
    from stableins.simulator.device import simulate_dwells
    from stableins.simulator.truth import Truth

    truth = Truth.draw(21)
    columns = simulate_dwells(truth, [s.command for s in COARSE.steps], dwell=20.0, settle=5.0, rate=20.0, seed=211, stage="coarse")
    path = save_device(tmp_path / "coarse.csv", columns, replace(truth.site, sample_rate=20.0))
    dataset = load_device(path)
    from_files = calibrate_device(dataset, layouts=LAYOUTS)
    setting = DeviceSetting.from_site(dataset.metadata)  # the unit's setting: the turn within a dwell taken out (issue 25)
    summaries = dwells_from_columns(dataset.columns, layouts=LAYOUTS, source=str(path), setting=setting)
    from_dwells = calibrate_device(summaries, dataset.metadata, layouts=LAYOUTS)
    np.testing.assert_array_equal(from_files.final.values, from_dwells.final.values)
    assert calibrate_device([dataset], layouts=LAYOUTS).final.values.tolist() == from_files.final.values.tolist()
    with pytest.raises(TypeError, match="not a DwellSet"):
        calibrate_device(dwells_from_dataset([dataset], layouts=LAYOUTS), layouts=LAYOUTS)
