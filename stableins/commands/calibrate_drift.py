"""``stableins calibrate drift RUN --prior CAL.json --out CAL2.json``: the gyro drift from an indexing test.

RUN is the run directory of ``stableins run drift-two-position`` (or ``drift-three-position``), or its
``system.h5``.  The platform's gimbal readings during the holds give the constant gyro drift ``ε^p``
(``gyro_drift_x/y/z``), with the base azimuth and tilt as nuisances and a rank report of what the
data determine (docs/drift-test.md); the accelerometer hold means are a cross-check against the
record.  The prior record is updated with the drift (a Bayesian update: no σ grows, nothing else
moves but through its prior correlation with the drift) and written to ``--out`` atomically.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from stableins.commands import add_entries_option, add_new_calibration_option, check_same_unit, run_data_file, update_prior


def configure(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``stableins calibrate drift``."""
    from stableins.commands.arguments import output_file

    parser.add_argument("run", metavar="RUN", help="run directory of a drift test (or its system.h5)")
    parser.add_argument(
        "--prior", required=True, metavar="CAL.json", help="calibration record the INS ran with (zero offsets, accelerometer model)"
    )
    parser.add_argument("--out", required=True, type=output_file, metavar="CAL2.json", help="updated calibration record to write")
    parser.add_argument(
        "--one-position",
        action="store_true",
        help="hold the base at its survey instead of fitting its error (what a single position can do; for comparison only)",
    )
    add_new_calibration_option(parser)
    add_entries_option(parser)


def drift_record_file(run: str) -> Path:
    """Return the system-level record of RUN: ``RUN/system.h5`` for a run directory, else RUN itself."""
    from stableins.procedures.rundir import SYSTEM_NAME

    return run_data_file(run, SYSTEM_NAME, missing="the run directory has no system-level record", expected="a drift-test run directory")


def run(args: Any) -> int:
    """Estimate the drift, update the prior record, write it, print the report."""
    from stableins.data.system import open_system_record
    from stableins.estimators.drift import DriftDetails, drift_from_record, drift_report
    from stableins.output import emit
    from stableins.records import CalibrationRecord

    prior = CalibrationRecord.load(args.prior)
    source = drift_record_file(args.run)
    record = open_system_record(source)
    record.validate()  # the validation 'stableins check' runs, before any estimate (a row of inf, time going back)
    check_same_unit(record.metadata, prior, args.prior)
    fit = drift_from_record(
        record,
        prior.values(),
        prior_covariance=(prior.ids, prior.covariance),
        error_model=prior.error_model(),
        base="survey" if args.one_position else "auto",
    )
    time = record.read(["time"])["time"]
    procedure = str(record.metadata.extra.get("procedure", "drift-two-position"))
    times = (source, record.metadata, (time[0], time[-1]))
    updated = update_prior(args, prior, fit, data=times, procedure=procedure, sample_rate=record.sample_rate)
    data = {
        "record": str(source),
        "prior": args.prior,
        "out": str(args.out),
        "gyro_drift_deg_per_hour": _drift_document(fit),
        "rank": list(fit.details.rank) if isinstance(fit.details, DriftDetails) else [],
        "settings": {} if fit.settings is None else fit.settings.to_document(),
        "parameters": [
            {"id": p.id, "value": p.value, "sigma": p.sigma if p.sigma == p.sigma else None, "status": p.status.value}
            for p in updated.parameters
            if p.id.startswith("gyro_drift_")
        ],
    }
    emit(args, data, text="\n".join([drift_report(fit), "", updated.report(), "", f"updated calibration written to {args.out}"]))
    return 0


def _drift_document(fit: Any) -> dict[str, dict[str, float]]:
    from stableins.conventions import DEG_PER_HOUR

    return {
        t.id: {"value": float(v) / DEG_PER_HOUR, "sigma": float(s) / DEG_PER_HOUR}
        for t, v, s in zip(fit.terms, fit.values, fit.sigma, strict=True)
    }
