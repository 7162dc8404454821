"""One campaign task through the library: simulate → calibrate → diagnose, as rows of the results table.

A task is a pure function of its identity (:class:`~stableins.campaign.config.Task`): the instrument is
``Truth.draw(seed)`` (the same device for every procedure, noise model and hidden effect of a seed: common random
numbers make the comparisons sharper), the noise streams are seeded by the task's identity, so a task gives the same
rows on any worker, in any order, in any process.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from stableins.campaign.config import CalibrationNoise, CampaignConfig, ProcedureSpec, Task
from stableins.noise import NoiseModel

if TYPE_CHECKING:  # pragma: no cover
    from stableins.estimators.dwell import DwellSummary
    from stableins.estimators.layout import StageLayout
    from stableins.estimators.setting import DeviceSetting

#: Columns of the results table, in order (docs/campaigns.md).
COLUMNS = (
    "task",
    "procedure",
    "noise",
    "hidden",
    "seed",
    "parameter",
    "unit",
    "truth",
    "estimate",
    "sigma",
    "z",
    "status",
    "chi2_red",
    "warnings",
    "flagged",
    "best_effect",
    "detected",
    "simulate_s",
    "calibrate_s",
    "diagnose_s",
)


@dataclass(frozen=True)
class TaskData:
    """Everything a worker needs to run tasks: the campaign (procedures loaded) and whether to diagnose."""

    config: CampaignConfig


def _stage_columns(truth: Any, spec: ProcedureSpec, stage: str, seed: int) -> dict[str, NDArray[Any]]:
    """Simulate one stage's session: every pass of its positions on one time base (as ``stableins run`` records them)."""
    from stableins.simulator.device import simulate_dwells

    definition = spec.coarse if stage == "coarse" else spec.fine
    assert definition is not None
    passes = spec.passes if stage == "coarse" else 1
    steps = list(definition.steps) * passes
    rate = spec.sample_rate or definition.steps[0].sample_rate
    columns = simulate_dwells(
        truth,
        [s.command for s in steps],
        dwell=[s.dwell for s in steps],
        settle=[s.settle for s in steps],
        rate=rate,
        seed=seed,
        stage=stage,
    )
    m = len(definition.steps)
    index = columns["position"] - 1
    columns["position"] = (index % m + 1).astype(np.int32)
    columns["pass"] = (index // m + 1).astype(np.int32)
    return columns


def calibration_noise(settings: Any, calibrate: CalibrationNoise) -> NoiseModel | None:
    """Return the noise model a task's calibration is given: the simulated instrument's datasheet, or none (measured in the dwells)."""
    if calibrate is CalibrationNoise.DWELLS:
        return None
    return NoiseModel.given(
        settings.velocity_random_walk, settings.bias_instability, settings.acceleration_random_walk, settings.quantization
    )


@dataclass(frozen=True)
class _RecordInForce:
    """The fused fit as the record in force of a diagnosis (:class:`stableins.discovery.diagnose.RecordInForce`)."""

    ids: tuple[str, ...]
    covariance: NDArray[np.float64]
    noise_model: NoiseModel | None
    estimates: Mapping[str, float]

    def values(self) -> dict[str, float]:
        return dict(self.estimates)


def _statistics(
    columns: Mapping[str, Mapping[str, NDArray[Any]]],
    stages: list[str],
    layouts: Mapping[str, StageLayout],
    setting: DeviceSetting,
    *,
    session: bool,
) -> tuple[dict[str, list[DwellSummary]], list[DwellSummary]]:
    """Return each stage's dwell statistics on its own clock (the calibration's) and, with ``session``, on the session's.

    On the session's clock (:func:`_session`) stage ``k`` starts ``1e6·k`` s later: its start times and their rounding
    change, so its statistics are those of its moved rows (``dwells_from_columns`` of them, to the bit); the
    statistics that do not depend on the clock are made once for both (:func:`stableins.estimators.dwell.dwells_on_clocks`).
    """
    from stableins.estimators.dwell import dwells_on_clocks

    own: dict[str, list[DwellSummary]] = {}
    on_session: list[DwellSummary] = []
    for k, stage in enumerate(stages):
        made = dwells_on_clocks(columns[stage], (0.0, 1e6 * k) if session and k else (0.0,), layouts=layouts, setting=setting)
        own[stage] = made[0]
        on_session += made[-1]
    return own, on_session


def _session(columns: Mapping[str, Mapping[str, NDArray[Any]]], stages: list[str]) -> dict[str, NDArray[Any]]:
    """Return the task's stages as one session: stage ``k`` goes ``1e6·k`` s later on one clock (the hysteresis states carry over)."""
    merged: dict[str, NDArray[Any]] = {name: np.concatenate([columns[s][name] for s in stages]) for name in columns[stages[0]]}
    merged["time"] = np.concatenate([columns[s]["time"] + 1e6 * k for k, s in enumerate(stages)])
    return merged


def _diagnose(
    columns: Mapping[str, Any], truth: Any, final: Any, noise: NoiseModel | None, layouts: Any, *, summaries: list[DwellSummary]
) -> dict[str, Any]:
    """Model discovery on the task's data against its own calibration: flagged candidates, the best one."""
    from stableins.data.device import DeviceDataset
    from stableins.discovery.diagnose import DiagnoseOptions, diagnose_data

    record = _RecordInForce(final.ids, final.covariance, noise, final.as_dict())
    data = [DeviceDataset(truth.site, columns)]
    result = diagnose_data(data, record, layouts=layouts, options=DiagnoseOptions(noise=noise), summaries=[summaries])
    flagged = [c.id for c in result.ranking.flagged]
    best = result.ranking.flagged[0] if flagged else None
    return {"flagged": flagged, "best": None if best is None else (best.id, tuple(best.confused_with))}


def run_task(task: Task, data: TaskData) -> list[dict[str, Any]]:
    """Simulate, calibrate (and diagnose) one task; one row per parameter of the record (columns :data:`COLUMNS`)."""
    from stableins.estimators.device import calibrate_device
    from stableins.estimators.device_gauge import gauge_equivalent
    from stableins.estimators.setting import DeviceSetting
    from stableins.procedures.definition import load_procedure
    from stableins.simulator.truth import Truth
    from stableins.simulator.worlds import apply_world

    config = data.config
    spec, noise_spec, hidden = config.procedure(task.procedure), config.noise(task.noise), config.hidden_effects(task.hidden)
    t0 = time.perf_counter()
    truth = apply_world(Truth.draw(task.seed, noise=noise_spec.settings, effects=dict(hidden.effects)), noise_spec.world)
    stages = ["coarse"] + (["fine"] if spec.fine is not None else [])
    columns = {stage: _stage_columns(truth, spec, stage, task.stream_seed + k) for k, stage in enumerate(stages)}
    # a coarse-only procedure still names the fine layout calibrate_device expects (unused without fine dwells)
    layouts = {"coarse": spec.coarse.layout, "fine": (spec.fine or load_procedure("device-fine")).layout}
    t1 = time.perf_counter()
    setting = DeviceSetting.from_site(truth.site)
    summaries, on_session = _statistics(columns, stages, layouts, setting, session=config.diagnose)
    dwells = [d for stage in stages for d in summaries[stage]]
    noise = calibration_noise(noise_spec.settings, noise_spec.calibrate)
    calibration = calibrate_device(dwells, truth.site, layouts=layouts, noise=noise)
    final = calibration.fused or calibration.coarse
    t2 = time.perf_counter()
    found: dict[str, Any] = {"flagged": [], "best": None}
    if config.diagnose:
        found = _diagnose(_session(columns, stages), truth, final, calibration.noise, layouts, summaries=on_session)
    t3 = time.perf_counter()
    truth_values = gauge_equivalent(truth.parameters, truth.configuration)
    detected = ""
    if config.diagnose and hidden.effects:
        best = found["best"]
        detected = "yes" if best is not None and (best[0] in hidden.effects or set(best[1]) & set(hidden.effects)) else "no"
    warnings = sum(1 for n in final.notes if n.startswith("warning"))
    common = {
        "task": task.key,
        "procedure": task.procedure,
        "noise": task.noise,
        "hidden": task.hidden,
        "seed": task.seed,
        "chi2_red": round(float(final.chi2_red), 6),
        "warnings": warnings,
        "flagged": " ".join(found["flagged"]),
        "best_effect": "" if found["best"] is None else found["best"][0],
        "detected": detected,
        "simulate_s": round(t1 - t0, 3),
        "calibrate_s": round(t2 - t1, 3),
        "diagnose_s": round(t3 - t2, 3),
    }
    rows = []
    for term in final.terms:
        value, sigma, status = final[term.id]
        true = truth_values.get(term.id, term.reference)
        z = (value - true) / sigma if sigma > 0 and status == "estimated" else math.nan
        rows.append(
            {
                **common,
                "parameter": term.id,
                "unit": term.unit,
                "truth": float(term.to_engineering(true)),
                "estimate": float(term.to_engineering(value)),
                "sigma": float(term.sigma_to_engineering(sigma)),
                "z": z,
                "status": status,
            }
        )
    return rows
