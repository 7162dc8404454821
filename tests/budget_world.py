"""The worlds of the budget tests and of benchmarks/bench_budget.py: a simulated quartz instrument's device
calibration, the joint coarse + fine problem at its solution, and the system stage on a synthetic day of it."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import system_synthetic as syn

from stableins.conventions import ARCSEC, GimbalConfiguration, dcm_nav_to_body
from stableins.data.chunks import ArraySource
from stableins.estimators.coarse import CoarseProblem, coarse_model
from stableins.estimators.device import calibrate_device
from stableins.estimators.dwell import dwells_from_columns
from stableins.estimators.fine import FineProblem, fine_model
from stableins.estimators.joint import JointProblem, fit_joint
from stableins.estimators.setting import DeviceSetting
from stableins.estimators.system.stage import SystemOptions, run_system_stage
from stableins.noise import NoiseModel
from stableins.procedures.definition import load_procedure
from stableins.records import CalibrationRecord
from stableins.simulator.device import simulate_dwells
from stableins.simulator.truth import Truth


def device(seed: int):
    """``(truth, dwells, noise, DeviceCalibration, record)``: a coarse pass (20-s dwells) and the fine stage (120-s dwells)."""
    coarse, fine = load_procedure("device-coarse"), load_procedure("device-fine")
    layouts = {"coarse": coarse.layout, "fine": fine.layout}
    truth = Truth.draw(seed)
    commands = [s.command for s in coarse.steps]
    dwells = dwells_from_columns(
        simulate_dwells(truth, commands, dwell=20.0, settle=5.0, rate=50.0, seed=seed * 10 + 1, stage="coarse"), layouts=layouts
    )
    columns = simulate_dwells(truth, [s.command for s in fine.steps], dwell=120.0, settle=5.0, rate=5.0, seed=seed * 10 + 2, stage="fine")
    dwells += dwells_from_columns(columns, layouts=layouts)
    n = truth.noise
    noise = NoiseModel.given(n.velocity_random_walk, n.bias_instability, n.acceleration_random_walk, provenance="datasheet")
    calibration = calibrate_device(dwells, truth.site, layouts=layouts, noise=noise)
    return truth, dwells, noise, calibration, CalibrationRecord.from_device(calibration, truth.site)


def joint(world):
    """``(fit, problem, coarse dwells, fine dwells, fit options)``: fit_joint of the world's usable dwells (white noise)."""
    truth, dwells, _, calibration, _ = world
    coarse = [d for d in dwells if d.stage == "coarse" and d.usable]
    fine = [d for d in dwells if d.stage == "fine" and d.usable]
    site = truth.site
    configuration = GimbalConfiguration(tuple(site.gimbal_senses))
    options = dict(setting=DeviceSetting.from_site(site), start=calibration.coarse)
    fit = fit_joint(coarse, fine, stage="coarse+fine", **options)
    model, fm = coarse_model(nonlinear=True), fine_model()
    problem = JointProblem(
        CoarseProblem.from_dwells(coarse, site.gravity, dcm_nav_to_body(*site.base_attitude), configuration, model),
        FineProblem(np.array([d.mean for d in fine])[None], np.array([d.sem for d in fine])[None], float(site.gravity), fm),
        np.array([model.index(k) for k in fm.ids]),
        None,
    )
    return fit, problem, coarse, fine, options


def refit_with_reading_moved(fit_options, coarse, fine, dwell: int, gimbal: int, by: float):
    """fit_joint with the reading of one gimbal in one coarse dwell moved by ``by`` [rad]."""
    moved = list(coarse)
    moved[dwell] = replace(moved[dwell], angles=moved[dwell].angles + by * np.eye(3)[gimbal])
    return fit_joint(moved, fine, stage="coarse+fine", **fit_options)


def system_day(prior, gravity_uncertainty: float | None = None):
    """``(run, metadata)``: the system stage on one synthetic day (1 Hz) of the unit, the device record as its prior.

    The truth differs from the installed calibration by 30 µg·g⁻¹ on δb_x and 2″ on β_zy; ``run(options, metadata)``
    runs the stage on it; by default with the gyro drift an input taken as known (``estimate_gyro_drift=False``), whose
    Type B sensitivity the budget evaluates (a drift measured from the gimbal readings is a parameter of the update
    instead, docs/system-calibration.md §9).
    """
    installed = {k: v for k, v in prior.values().items() if not k.startswith("theta")}
    true = dict(installed, bias_x=installed["bias_x"] + 3e-5, beta_zy=installed["beta_zy"] + 2.0 * ARCSEC)
    columns, meta = syn.record(true, installed, rate=1.0, noise=2e-3, seed=5)
    meta = replace(meta, serial_number=prior.serial_number, gravity=prior.site.gravity, gravity_uncertainty=gravity_uncertainty)
    covariance = {(a, b): float(prior.covariance[i, j]) for i, a in enumerate(prior.ids) for j, b in enumerate(prior.ids)}
    source, values = ArraySource(columns), prior.values()

    def run(options=None, metadata=meta):
        return run_system_stage(source, metadata, values, covariance, options or SystemOptions(estimate_gyro_drift=False))

    run.source, run.values, run.covariance = source, values, covariance  # type: ignore[attr-defined]
    return run, meta
