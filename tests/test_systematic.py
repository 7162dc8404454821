"""Systematic calibration over indexed orientations (issue 18): the model against the truth simulator, the filter,
the RTS smoother and batch least squares against each other, the rank report, the record update and the CLI.

The observation and state equations (stableins/estimators/systematic/model.py, docs/systematic-calibration.md) are
derived independently of the simulator's kinematics and error dynamics; these tests check the one against the
other with fixed seeds and k·σ bounds (the Monte Carlo campaign is benchmarks/bench_systematic.py).
"""

import argparse
import json
import math
from dataclasses import replace

import numpy as np
import pytest
from systematic_world import (
    DRIFT,
    indexed_record,
    indexed_truth,
    prior_pull,
    prior_record,
    true_values,
    turns,
    unit_prior,
    with_cross_coupling,
)

from stableins.commands import calibrate_system
from stableins.conventions import DEG_PER_HOUR, DEG_PER_HOUR_PER_G, skew
from stableins.data.chunks import ArraySource
from stableins.data.system import SystemRecordWriter
from stableins.errormodel import GIMBAL_IDS, ErrorModel
from stableins.errors import InputError
from stableins.estimators.drift.holds import small_angle_vector
from stableins.estimators.system.loop import DampingLoop
from stableins.estimators.systematic import SystematicOptions, systematic_calibration
from stableins.estimators.systematic.kalman import batch_least_squares, rts_smooth, run_filter, steps_of
from stableins.estimators.systematic.model import Discretization, StateLayout, accelerometer_ids, slow_noise_times
from stableins.estimators.systematic.observations import Linearization, StepBuilder, scan_record
from stableins.estimators.systematic.passes import initial_covariance, noise_inputs, prior_mean
from stableins.platform import rotation_about
from stableins.procedures.definition import load_procedure
from stableins.records import CalibrationRecord
from stableins.simulator.indexing import IndexedMotion, earth_rotation
from stableins.simulator.noise import NoiseSettings
from stableins.simulator.system import SystemWorld
from stableins.terms import CROSS_COUPLING_TERMS
from stableins.turns import IndexAxis, PlatformTurn


def _steps(truth, record, lin, layout=None, step=30.0, substeps=30):
    """The model's steps for a record, linearized at ``lin``."""
    site = truth.site
    scan = scan_record(ArraySource(record), site.sample_rate, 1 << 14)
    layout = layout or StateLayout(scan.holds, slow_noise_times())
    loop = DampingLoop.from_metadata(site.damping, site.latitude, site.gravity)
    disc = Discretization.of(loop, step, substeps)
    white, quantization, slow = noise_inputs(unit_prior(truth).noise_model)
    slow = (slow[0], slow[1][: len(layout.slow_times)])
    builder = StepBuilder(
        site, scan, lin, step=step, substeps=substeps, noise=(white, quantization, layout.noise.stop - layout.noise.start)
    )
    return layout, list(steps_of(builder.batches(ArraySource(record), 1 << 14), layout, disc, slow))


# ----------------------------------------------------------------------------- the model against the world
#: Cross-couplings of the noise-free world check [s²/m]: large (100 µg/g²) so that a wrong column would show.
WORLD_KCC = {"Kcc_xxy": 1e-5, "Kcc_xxz": -1e-5, "Kcc_yyz": 8e-6, "Kcc_zxz": 6e-6, "Kcc_zyz": -8e-6, "Kcc_yxy": 5e-6}


def _world_residuals(truth, cross_coupling):
    """Largest residuals and signals of the noise-free record against ``F``, ``H`` with the true parameters."""
    record = indexed_record(truth, 7200.0, rate=10.0)
    residual = truth.calibration_residual()
    offsets = np.array([residual[g] for g in GIMBAL_IDS])
    base = np.array([truth.effects["tilt_north"], truth.effects["tilt_east"], truth.effects["azimuth_error"]])
    prior = unit_prior(truth)
    ids = accelerometer_ids(prior.error_model, cross_coupling=cross_coupling)
    accel = true_values(truth, ids) - np.array([truth.installed_calibration.get(i, 1.0 if i.startswith("sf_") else 0.0) for i in ids])
    lin = Linearization(dict(truth.installed_calibration), prior.error_model, accel, offsets, base, ids=ids)
    layout = StateLayout(2, slow_noise_times(), accelerometer_ids=ids)
    layout, steps = _steps(truth, record, lin, layout=layout)
    x = np.zeros(layout.size)
    names = layout.names
    x[layout.accelerometer] = accel
    x[layout.gyro] = true_values(truth, names[layout.gyro])
    x = x / layout.scales()
    worst = np.zeros(12)
    signal = np.zeros(12)
    hold_first = {}
    for k, step in enumerate(steps):
        x = step.F @ x
        r = step.z - step.H @ x
        if len(r) == 12:  # per-hold constants of ρ and d: the first step of the hold defines them
            hold = 0 if step.time < 3600 else 1
            hold_first.setdefault(hold, r[3:9].copy())
            r[3:9] -= hold_first[hold]
        worst[: len(r)] = np.maximum(worst[: len(r)], np.abs(r))
        signal[: len(r)] = np.maximum(signal[: len(r)], np.abs(step.z))
        assert k < 2 or np.all(np.isfinite(r))
    return worst, signal


@pytest.mark.parametrize("cross_coupling", [False, True], ids=["core", "cross-coupling"])
def test_model_reproduces_the_noise_free_world(cross_coupling):
    """F and H propagate the true parameters to the simulator's outputs (velocity, readings, attitude).

    With cross-couplings in the world (one the record holds, five new), the layout's ``Kcc`` columns carry them;
    without those states the same world is not reproduced (the columns matter).
    """
    truth = indexed_truth(3, rate=10.0, noise=NoiseSettings.quiet())
    if cross_coupling:
        truth = with_cross_coupling(truth, WORLD_KCC, {"Kcc_xxy": 7e-6})
    worst, signal = _world_residuals(truth, cross_coupling)
    assert np.all(worst[:3] < 5e-4 * signal[:3].max()), (worst[:3], signal[:3])  # velocity: 0.05 m/s to 2e-5 (in the turn)
    assert np.all(worst[3:12] < 1e-8), worst[3:12]  # readings, attitude with readings, attitude vs survey [rad]
    assert signal[3:6].max() > 1e-5  # the drift moved the readings
    if cross_coupling:
        worst, signal = _world_residuals(truth, False)  # the record's Kcc_xxy is a state; the five new ones are not
        assert worst[:3].max() > 5e-4 * signal[:3].max() * 4, (worst[:3], signal[:3])


def test_observations_carry_no_composition_terms():
    """``ρ`` and ``d`` stay linear in ``θ`` and ``φ`` when the drift angle is large (the sums of increments).

    Fifty times the drift and g-sensitivity of the acceptance world (0.05 °/h, 0.1 °/h/g): ``θ`` and ``φ_D`` reach
    1e-3 rad in 2 h.  The rotation vectors of the products (``M M_refᵀ``, ``P P_refᵀ``) would add Bortz's
    ``½∫θ × w`` and ``½ θ × C_n^p φ``; at the acceptance's size those biased the gyro terms of a day at 10 Hz by up to
    1.2σ after the simulator's fix (docs/systematic-calibration.md §3, §7).
    """
    truth = indexed_truth(3, rate=10.0, noise=NoiseSettings.quiet())
    large = {k: 50 * v for k, v in truth.effects.items() if k.startswith("Dg_")}
    truth = truth.with_changes(gyro_drift={a: 50 * v for a, v in DRIFT.items()}, effects={**truth.effects, **large})
    worst, signal = _world_residuals(truth, False)
    assert signal[3:6].max() > 1e-3  # θ is large
    # measured: ρ 1.6e-9 rad, d 2.8e-8 rad (the loop's discretization at 3 m/s of velocity error, as v's 4e-5 relative);
    # the rotation vectors of the products: ρ 3.7e-8, d 1.5e-6 rad
    assert np.all(worst[3:6] < 5e-9), worst[3:6]
    assert np.all(worst[6:9] < 1e-7), worst[6:9]


@pytest.mark.parametrize("cross_coupling", [False, True], ids=["core", "cross-coupling"])
def test_accelerometer_block_is_the_error_model_jacobian(cross_coupling):
    """``J_f⁻¹ J_p`` equals finite differences of inverse(forward(f, true), installed), cross-couplings included.

    With ``cross_coupling`` the record holds ``Kcc_xxy`` and ``Kcc_xyz`` (installed, non-zero) and the block adds
    Cai's other five at zero: their columns come from the additive terms' regressors in the same error model.
    """
    truth = indexed_truth(4, rate=10.0)
    values = dict(truth.installed_calibration)
    model = ErrorModel.standard(nonlinear=True)
    if cross_coupling:
        values |= {"Kcc_xxy": 3e-6, "Kcc_xyz": -2e-6}
        model = model + tuple(t for t in CROSS_COUPLING_TERMS if t.id in values)
    ids = accelerometer_ids(model, cross_coupling=cross_coupling)
    assert len(ids) == (15 + 7 if cross_coupling else 15)
    lin = Linearization(values, model, ids=ids)
    full = lin.model()
    f = np.array([[3.1, -4.0, 7.9], [0.0, 0.0, 9.8], [-6.9, 6.9, 0.5]])
    jac = lin.accelerometer_map(f)
    # ErrorModel.jacobian_specific_force holds the additive terms fixed: J_f is off by about Σ|Kcc||f| (5e-5 here, a
    # 1e-9 m/s² error of Δf^p), mixing the axes; with the record's cross-couplings at zero it is exact.
    coupled = 2 * sum(abs(v) for k, v in values.items() if k.startswith("Kcc_")) * np.abs(f).max()
    for k, name in enumerate(ids):
        step = 1e-6 if not name.startswith(("K2", "Kcc")) else 1e-7
        plus, minus = dict(values), dict(values)
        plus[name], minus[name] = values.get(name, full[name].reference) + step, values.get(name, full[name].reference) - step
        delta = full.inverse(full.forward(f, plus), values) - full.inverse(full.forward(f, minus), values)
        assert np.allclose(delta / (2 * step), jac[:, :, k], rtol=1e-5 + coupled, atol=(1e-7 + coupled) * np.abs(jac[:, :, k]).max()), name
        if name.startswith("Kcc_"):  # e_a f_b f_c to first order
            a, b, c = ("xyz".index(name[4]), "xyz".index(name[5]), "xyz".index(name[6]))
            assert np.allclose(jac[:, a, k], f[:, b] * f[:, c], rtol=1e-3), name


def test_indexed_drift_composes_rotations():
    """After an index the world's drift is the product of the drift rotations (Bortz), not the rotation of their sum."""
    truth = indexed_truth(5, rate=1.0, noise=NoiseSettings.quiet(), g_sensitivity=False)
    truth = truth.with_changes(gyro_drift={"x": 0.3 * DEG_PER_HOUR, "y": 0.0, "z": 0.0})
    index = (PlatformTurn(600.0, math.radians(60.0), IndexAxis.MIDDLE),)
    world = SystemWorld(truth, 1.0, initial_readings=SystemWorld(truth, 1.0).initial_readings, turns=index)
    motion = world._indexed
    assert isinstance(motion, IndexedMotion)
    time = np.arange(0.0, 7201.0)
    dcm = motion.orientation(time, world.gyro_drift(time), g_sensitivity=np.zeros((3, 3)), gravity=world.gravity)
    w = -world.gyro_drift(time[:1])[0]  # constant drift: Tᵀw is constant in each hold, turns during the index
    end = index[0].end
    fine = np.arange(600.0 + 0.005, end, 0.01)  # the index itself: sequential composition at 100 Hz
    exact = rotation_about(w * 600.0)
    for step in np.einsum("nji,j->ni", motion.commanded(fine), w) * 0.01:
        exact = rotation_about(step) @ exact
    after = motion.commanded(np.array([end]))[0].T @ w
    exact = rotation_about(after * (7200.0 - end)) @ exact
    u = np.vstack([np.tile(w * 0.01, (60000, 1)), np.einsum("nji,j->ni", motion.commanded(fine), w) * 0.01, after * (7200.0 - end)])
    earth = earth_rotation(motion.earth_axis, time[-1:])[0]
    x_world = motion.commanded(time[-1:])[0].T @ dcm[-1] @ (motion.nav_to_platform_0 @ earth).T
    first_order = rotation_about(u.sum(axis=0))
    assert np.linalg.norm(small_angle_vector(first_order @ exact.T)) > 1e-6  # what a sum of drift angles would leave
    assert np.linalg.norm(small_angle_vector(x_world @ exact.T)) < 1e-8  # third order: θ³ ~ 1e-6 · 1e-2


def test_g_sensitive_drift_uses_the_drifted_specific_force():
    """The g-sensitive drift ``−D_g f^p`` acts with ``f^p`` of the drifted orientation (an RK4 integration of ``Ẋ``).

    ``D_g g`` = 0.1 °/h makes ``θ`` swing by ``|D_g g|/Ω`` ≈ 7e-3 rad in the polar hold; ``f^p`` of the drift-free
    orientation errs by ``θ × f`` and the drift by up to ``|D_g g||θ|`` ≈ 3e-9 rad/s (measured 5.6e-6 rad in 3 h).  The same error
    at 0.002 °/h/g biased ``Dg_xz`` of a day at 10 Hz by 3.9σ (docs/systematic-calibration.md §7).
    """
    g_sensitivity = {"Dg_xy": 0.1 * DEG_PER_HOUR_PER_G, "Dg_zx": -0.05 * DEG_PER_HOUR_PER_G, "Dg_yz": 0.05 * DEG_PER_HOUR_PER_G}
    truth = indexed_truth(5, rate=1.0, noise=NoiseSettings.quiet(), g_sensitivity=False)
    truth = truth.with_changes(gyro_drift={}, effects={**truth.effects, **g_sensitivity})
    index = (PlatformTurn(20000.0, math.radians(60.0), IndexAxis.MIDDLE),)  # after the span: T = I here
    world = SystemWorld(truth, 1.0, initial_readings=SystemWorld(truth, 1.0).initial_readings, turns=index)
    motion = world._indexed
    assert isinstance(motion, IndexedMotion)
    dg = np.array([[g_sensitivity.get(f"Dg_{a}{b}", 0.0) for b in "xyz"] for a in "xyz"])
    time = np.arange(0.0, 10801.0)
    dcm = motion.orientation(time, np.zeros((len(time), 3)), g_sensitivity=dg, gravity=world.gravity)
    start = motion.nav_to_platform_0

    def rate(t, x):  # Ẋ = −[w×] X, w = −D_g f^p, f^p = −g X C_n0^p0 C_n(t)^n0 e_D
        f_p = -world.gravity * (x @ start @ earth_rotation(motion.earth_axis, np.array([t]))[0])[:, 2]
        return -skew(-dg @ f_p) @ x

    x, h = np.eye(3), 10.0
    for t in np.arange(0.0, 10800.0, h):  # RK4 (error ~ (Ωh)⁴: negligible)
        k1 = rate(t, x)
        k2 = rate(t + h / 2, x + h / 2 * k1)
        k3 = rate(t + h / 2, x + h / 2 * k2)
        k4 = rate(t + h, x + h * k3)
        x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    x_world = dcm[-1] @ (start @ earth_rotation(motion.earth_axis, time[-1:])[0]).T
    swing = np.linalg.norm(small_angle_vector(x_world))
    assert swing > 1e-3  # θ moved (the effect scales with it)
    # measured 1.1e-6 of the swing (the trapezoid and Bortz's third order); f^p of the drift-free orientation: 1.9e-3
    assert np.linalg.norm(small_angle_vector(x_world @ x.T)) < 1e-5 * swing


# ----------------------------------------------------------------------------- filter, smoother, batch
@pytest.fixture(scope="module")
def short_steps():
    """An hour, two holds, the loop's white noise; the observation σ ×100 (conditioning of the identity, not physics)."""
    truth = indexed_truth(6, rate=2.0)
    record = indexed_record(truth, 2400.0, rate=2.0)
    lin = Linearization(dict(truth.installed_calibration), ErrorModel.standard(nonlinear=True))
    layout = StateLayout(2, (), random_walk=False)
    layout, steps = _steps(truth, record, lin, layout=layout, step=60.0, substeps=30)
    steps = [replace(s, R=s.R * 1e4) for s in steps]
    prior = unit_prior(truth)
    return layout, steps, prior_mean(layout, prior), initial_covariance(layout, prior, SystematicOptions(), diffuse=False)


def test_filter_and_smoother_agree(short_steps):
    """Zero process noise on the parameters: the smoothed parameters at any time are the filter's final ones."""
    layout, steps, x0, p0 = short_steps
    run = run_filter(steps, x0, p0, keep_history=True)
    smoothed, _ = rts_smooth(run)
    record = slice(layout.accelerometer.start, layout.gyro.stop)
    final = run.x[record]
    size = np.abs(final).max()
    for k in (0, len(steps) // 2):
        assert np.abs(smoothed[k][record] - final).max() < 1e-9 * size  # measured 1.8e-10 (1.1e-9 before the refined inverse)
    assert np.abs(final - x0[record]).max() > 1.0  # the data moved the parameters (state units: nominal)


def test_filter_and_batch_least_squares_agree(short_steps):
    """The same linear model solved at once (here without process noise: the batch's unknowns are the initial state)."""
    layout, steps, x0, p0 = short_steps
    steps = [replace(s, Q=np.zeros_like(s.Q)) for s in steps]
    run = run_filter(steps, x0, p0)
    batch, batch_cov = batch_least_squares(steps, x0, p0)
    record = slice(layout.accelerometer.start, layout.gyro.stop)
    final = run.x[record]
    assert np.abs(batch[record] - final).max() < 1e-9 * np.abs(final).max()
    assert np.allclose(np.sqrt(np.diag(batch_cov)[record]), np.sqrt(np.diag(run.P)[record]), rtol=1e-8)


# ----------------------------------------------------------------------------- the stage
@pytest.fixture(scope="module")
def eight_hours():
    truth = indexed_truth(7, rate=5.0)
    record = indexed_record(truth, 8 * 3600.0, rate=5.0)
    result = systematic_calibration(ArraySource(record), truth.site, unit_prior(truth), SystematicOptions(iterations=2))
    return truth, result


def test_stage_recovers_the_truth_within_k_sigma(eight_hours):
    truth, result = eight_hours
    ids = tuple(t.id for t in result.fit.terms)
    z = (result.fit.values - true_values(truth, ids)) / result.fit.sigma
    assert np.all(np.abs(z) < 4.5), dict(zip(ids, np.round(z, 2), strict=True))
    drift = result.fit.values[[ids.index(f"gyro_drift_{a}") for a in "xyz"]]
    sigma = result.fit.sigma[[ids.index(f"gyro_drift_{a}") for a in "xyz"]]
    assert np.all(sigma < 1e-4 * DEG_PER_HOUR)
    assert np.allclose(drift, [DRIFT[a] for a in "xyz"], atol=4 * sigma.max())


def test_estimate_error_is_the_prior_pull_of_the_linear_bayesian_estimator():
    """The stage is the linear Bayesian estimator of its model, in every column (K2 included): no model, linearization
    or prior error.

    Seed 117 drew K2 residuals of −2.8σ (x) and +2.2σ (y) of the device prior (the Monte Carlo's |z| = 4.3).  Its
    record is made twice with the accelerometer noise ×1e-3 and the same angle noise: once with the device residuals,
    once installed = truth.  For a linear-Gaussian posterior the difference of the two errors is the prior's pull
    ``P P0⁻¹ (x0 − t)`` (Bayes' rule with noise-free data); the angle noise's part cancels.
    """
    quartz = NoiseSettings.quartz()
    slow = ("velocity_random_walk", "bias_instability", "acceleration_random_walk", "quantization")
    quiet = replace(quartz, **{k: 1e-3 * getattr(quartz, k) for k in slow})
    unit_noise = unit_prior(indexed_truth(117, rate=2.0)).noise_model  # the filter keeps the unit's σ
    errors, results = [], []
    for exact in (False, True):
        truth = indexed_truth(117, rate=2.0, noise=quiet)
        if exact:
            installed = {k: truth.parameters.get(k, v) for k, v in truth.installed_calibration.items()}
            truth = truth.with_changes(installed_calibration=installed)
        prior = replace(unit_prior(truth), noise_model=unit_noise)
        result = systematic_calibration(ArraySource(indexed_record(truth, 4 * 3600.0, rate=2.0)), truth.site, prior)
        ids = tuple(t.id for t in result.fit.terms)
        errors.append(result.fit.values - true_values(truth, ids))
        results.append((result, prior, true_values(truth, ids)))
    (result, prior, true), sigma = results[0], results[0][0].fit.sigma
    pull, _, _ = prior_pull(result.fit, prior, true)
    assert np.abs(pull / sigma).max() > 2.0  # the residuals pull (K2_x by +3.4σ at 4 h): the check has something to check
    off = (errors[0] - errors[1] - pull) / sigma
    assert np.all(np.abs(off) < 0.02), dict(zip(ids, np.round(off, 4), strict=True))  # measured 0.0012


def test_rank_report_names_the_gauges(eight_hours):
    _, result = eight_hours
    rank = {g.group: g for g in result.details.rank}
    assert rank["gyro"].rank == 12
    gauges = " ".join(d.name for d in rank["accelerometer"].gauge)
    assert "rotation of the triad about z_p" in gauges and "common scale factor" in gauges
    assert any(set(dict(d.loadings)) == {"base_east", "theta30_residual"} for d in rank["nuisance"].gauge)
    assert [round(math.degrees(h.polar_angle)) for h in result.details.holds] == [0, 60]
    assert "orientation 2" in result.report() and "<pre>" in result._repr_html_()


def test_likelihood_moves_nothing_undetermined(eight_hours):
    """The record update (Bayesian): the data's information has the gauges in its null space, no σ grows."""
    truth, result = eight_hours
    lik = result.fit.likelihood
    ids = lik.ids
    triad = np.zeros(len(ids))
    triad[ids.index("beta_xz")] = triad[ids.index("beta_yz")] = 1.0
    common = np.zeros(len(ids))
    common[[ids.index(f"sf_{a}") for a in "xyz"]] = 1.0
    top = np.linalg.eigvalsh(lik.information).max()
    for v in (triad, common):
        v = v / np.linalg.norm(v)
        assert v @ lik.information @ v < 1e-6 * top
    record = prior_record(truth)
    updated = record.updated(result.fit)
    before = dict(zip(record.ids, np.sqrt(np.diag(record.covariance)), strict=True))
    after = dict(zip(updated.ids, np.sqrt(np.diag(updated.covariance)), strict=True))
    assert all(after[i] <= before[i] * (1 + 1e-9) for i in before if np.isfinite(after[i]))
    assert all(f"Dg_{a}{b}" in after and np.isfinite(after[f"Dg_{a}{b}"]) for a in "xyz" for b in "xyz")


# ----------------------------------------------------------------------------- procedure and CLI
def test_procedure_ships_with_its_index():
    definition = load_procedure("system-indexed")
    (step,) = [s for s in definition.steps if getattr(s, "turns", ())] or [definition.record]
    (turn,) = step.turns
    assert turn.axis is IndexAxis.MIDDLE and math.isclose(turn.angle, math.radians(60.0)) and turn.start == 43200.0


def _parse(argv):
    parser = argparse.ArgumentParser()
    calibrate_system.configure(parser)
    parser.add_argument("--json", action="store_true")
    return parser.parse_args(argv)


def _write(path, truth, duration, indexed=True):
    with SystemRecordWriter(path, truth.site) as writer:
        record = indexed_record(truth, duration, rate=truth.site.sample_rate) if indexed else None
        if record is None:
            from stableins.simulator.system import simulate_system

            record = simulate_system(truth, duration, rate=truth.site.sample_rate)
        writer.append(record)


def test_cli_updates_the_record(tmp_path, capsys):
    truth = indexed_truth(8, rate=2.0)
    _write(tmp_path / "system.h5", truth, 4 * 3600.0)
    record = prior_record(truth)
    record.save(tmp_path / "cal.json")
    args = _parse(
        [str(tmp_path / "system.h5"), "--prior", str(tmp_path / "cal.json"), "--systematic", "--out", str(tmp_path / "cal2.json"), "--json"]
    )
    assert calibrate_system.run(args) == 0
    document = json.loads(capsys.readouterr().out)
    assert len(document["orientations"]) == 2 and document["rank"]
    updated = CalibrationRecord.load(tmp_path / "cal2.json")
    ids = set(updated.ids)
    assert {"gyro_drift_x", "Dg_xy"} <= ids
    gyro = document["gyro"]["gyro_drift_y"]
    assert abs(gyro["value"] - DRIFT["y"] / DEG_PER_HOUR) < 5 * gyro["sigma"]


def test_cli_refuses_a_record_with_one_orientation(tmp_path, capsys):
    truth = indexed_truth(9, rate=1.0)
    _write(tmp_path / "system.h5", truth, 3600.0, indexed=False)
    record = prior_record(truth)
    record.save(tmp_path / "cal.json")
    args = _parse(
        [str(tmp_path / "system.h5"), "--prior", str(tmp_path / "cal.json"), "--systematic", "--out", str(tmp_path / "cal2.json")]
    )
    with pytest.raises(InputError) as error:
        calibrate_system.run(args)
    assert error.value.field == "angle_platform" and not (tmp_path / "cal2.json").exists()
    assert turns(100.0)[0].start == 50.0
