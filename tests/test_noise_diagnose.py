"""diagnose under the one noise model: χ²_ν of clean quartz sessions is 1 with the true noise model."""

import numpy as np

from stableins.data.device import DeviceDataset
from stableins.discovery.dwells import dwells_from_dataset
from stableins.discovery.history import Discovery
from stableins.discovery.problem import DwellProblem
from stableins.errormodel import ErrorModel
from stableins.estimators.device import with_given_slow_noise
from stableins.estimators.dwell import dwells_from_columns
from stableins.procedures.definition import device_layouts, load_procedure
from stableins.simulator.device import simulate_dwells
from stableins.simulator.truth import Truth

FINE = load_procedure("device-fine")


def _fine_session(seed):
    truth = Truth.draw(seed)
    columns = simulate_dwells(truth, [s.command for s in FINE.steps], dwell=600.0, settle=5.0, rate=5.0, seed=seed + 17, stage="fine")
    return truth, DeviceDataset(truth.site, columns, f"fine-{seed}"), dwells_from_columns(columns, layouts={"fine": FINE.layout})


def test_clean_quartz_sessions_have_chi2_one_with_the_true_noise_model():
    """6 simulator units, 18 × 600 s: mean χ²_ν (ν = 37) within 1 ± 3·sqrt(2/(6·37)); the diagonal χ² of old was 0.33-0.58."""
    chi2 = []
    for seed in range(30, 36):
        truth, dataset, summaries = _fine_session(seed)
        noise = with_given_slow_noise(summaries, truth.noise.bias_instability, truth.noise.acceleration_random_walk, "truth")
        dwells = dwells_from_dataset([dataset], layouts=device_layouts(), noise=noise)
        session = Discovery(DwellProblem(dwells), ErrorModel.standard(nonlinear=True, gimbals=True), start=truth.parameters)
        assert session.result.whitened_residuals is not None
        chi2.append(session.result.chi2_red)
    assert abs(np.mean(chi2) - 1.0) < 3 * np.sqrt(2 / (6 * 37)), chi2
