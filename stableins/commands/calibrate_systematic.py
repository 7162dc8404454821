"""``stableins calibrate system RECORD --prior CAL.json --systematic --out CAL2.json``: the fourth way to calibrate.

The systematic stage (docs/systematic-calibration.md) on a record of the platform indexed to several orientations
(``stableins run system-indexed``): the record gains every term the orientations determine, with σ (a Bayesian
update of the prior record: nothing the data do not determine moves, no σ grows).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

from stableins.conventions import DEG_PER_HOUR, DEG_PER_HOUR_PER_G
from stableins.errormodel import MICRO_G_PER_G2


def run(args: Any) -> int:
    """Run the systematic stage, update the prior record, write it, print the report; return the exit code."""
    from stableins.commands import check_same_unit
    from stableins.commands.noise import system_noise_prior
    from stableins.data.system import open_system_record
    from stableins.estimators.systematic import SystematicOptions, prior_from_record, systematic_calibration
    from stableins.output import emit
    from stableins.records import CalibrationRecord, PriorReference, RunInfo, data_times, file_sha256, parse_entries

    prior_record = CalibrationRecord.load(args.prior)
    record = open_system_record(args.record)
    check_same_unit(record.metadata, prior_record, args.prior)
    record.validate(allow_gaps=args.allow_gaps)
    noise, _ = system_noise_prior(args, default=prior_record.noise_model)
    prior = prior_from_record(prior_record)
    if noise is not None:
        prior = replace(prior, noise_model=noise)
    outcome = systematic_calibration(record, record.metadata, prior, SystematicOptions(cross_coupling=args.cross_coupling))
    holds = outcome.details.holds
    start, end = data_times(record.metadata, holds[0].start, holds[-1].end)
    procedure = str(record.metadata.extra.get("procedure", "system-indexed"))
    updated = prior_record.updated(
        outcome.fit,
        RunInfo(procedure=procedure, inputs=[args.record], data_start=start, data_end=end, sample_rate=record.sample_rate),
        new_calibration=args.new_calibration,
        prior=PriorReference(file_sha256(args.prior), str(args.prior), prior_record.calibration.created),
        calibration_entries=parse_entries(args.set),
        site=record.metadata,
    )
    updated.save(args.out)
    data = document(args, outcome, updated)
    emit(args, data, text="\n".join([outcome.report(), "", updated.report(), "", f"updated calibration written to {args.out}"]))
    return 0


def document(args: Any, outcome: Any, updated: Any) -> dict[str, Any]:
    """Return the ``--json`` document: orientations, rank, gyro terms (°/h, °/h/g), cross-couplings (µg/g²), the record's parameters.

    Every entry in an engineering unit names it (``"unit": "°/h"``); ``parameters`` are SI, as the record.

    ``gyro`` holds the updated record's gyro terms (the numbers the record and its certificate carry; for terms new to
    the record the data's own, without the stage's wide prior on them), ``null`` σ where the record has none;
    ``cross_coupling`` the record's cross-couplings and, ``"written": false``, those the stage left out.
    """
    scale = {"gyro_drift_": (DEG_PER_HOUR, "°/h"), "Dg_": (DEG_PER_HOUR_PER_G, "°/h/g")}
    gyro: dict[str, dict[str, float | str | None]] = {}
    cross: dict[str, dict[str, float | str | bool | None]] = {}
    for p in updated.parameters:
        unit = next((v for k, v in scale.items() if p.id.startswith(k)), None)
        sigma = p.sigma if p.sigma == p.sigma else None
        if unit is not None:
            gyro[p.id] = {"value": p.value / unit[0], "sigma": None if sigma is None else sigma / unit[0], "unit": unit[1]}
        elif p.id.startswith("Kcc_"):
            value, s = p.value / MICRO_G_PER_G2, None if sigma is None else sigma / MICRO_G_PER_G2
            cross[p.id] = {"value": value, "sigma": s, "unit": "µg/g²"}
    for term_id, sigma in outcome.details.left_out.items():
        cross[term_id] = {"value": None, "sigma": float(sigma) / MICRO_G_PER_G2, "unit": "µg/g²", "written": False}
    return {
        "record": str(args.record),
        "prior": str(args.prior),
        "out": str(args.out),
        "orientations": [
            {"start_s": h.start, "end_s": h.end, "specific_force_g": list(h.specific_force), "polar_angle_rad": h.polar_angle}
            for h in outcome.details.holds
        ],
        "rank": [g.describe() for g in outcome.details.rank],
        "gyro": gyro,
        "cross_coupling": cross,
        "chi2_per_dof": outcome.details.chi2 / max(outcome.details.dof, 1),
        "parameters": [
            {"id": p.id, "value": p.value, "sigma": p.sigma if p.sigma == p.sigma else None, "status": p.status.value}
            for p in updated.parameters
        ],
    }
