"""``stableins calibrate lever RUN --prior CAL.json --out CAL2.json``: lever arms and time asynchrony from slews.

RUN is the run directory of ``stableins run device-rotating`` (or its ``device.h5``): a device-level data set
that keeps its slews.  The accelerometer outputs, compensated by the prior record, are compared during each
slew with the specific force the angle readings predict; the difference gives the lever arms (Cai's three
``lever_x_x``, ``lever_y_y``, ``lever_z_z`` by default, all nine with ``--all-arms``) from the centripetal and
tangential accelerations, and the time asynchrony ``t_async`` of the accelerometer samples against the readings
(docs/device-calibration.md §9).  The prior record is updated (a Bayesian update: the new parameters enter with
their σ, nothing else moves) and written to ``--out`` atomically.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from stableins.commands import add_entries_option, add_new_calibration_option, check_same_unit, run_data_file, update_prior


def configure(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``stableins calibrate lever``."""
    from stableins.commands.arguments import output_file, real

    parser.add_argument("run", metavar="RUN", help="run directory of device-rotating (or its device.h5)")
    parser.add_argument(
        "--prior", required=True, metavar="CAL.json", help="the unit's calibration record (zero offsets, accelerometer model, noise)"
    )
    parser.add_argument("--out", required=True, type=output_file, metavar="CAL2.json", help="updated calibration record to write")
    parser.add_argument(
        "--all-arms", action="store_true", help="estimate all nine lever_a_b (default: Cai's three along-axis arms lever_a_a)"
    )
    parser.add_argument("--no-asynchrony", action="store_true", help="hold the time asynchrony t_async at zero instead of estimating it")
    parser.add_argument(
        "--window", type=real(0.05, 5.0, unit="seconds"), default=0.5, help="window of the means [s], 0.05 to 5 (default 0.5)"
    )
    add_new_calibration_option(parser)
    add_entries_option(parser)


def lever_data_file(run: str) -> Path:
    """Return the device data set of RUN: ``RUN/device.h5`` for a run directory, else RUN itself."""
    from stableins.procedures.rundir import DATASET_NAME

    return run_data_file(
        run,
        DATASET_NAME,
        missing="the run directory has no device-level data set",
        expected="a run directory of 'stableins run device-rotating'",
    )


def run(args: Any) -> int:
    """Estimate the lever arms and τ, update the prior record, write it, print the report."""
    from stableins.data.device import load_device
    from stableins.estimators.lever import LeverDetails, LeverOptions, LeverSet, lever_from_dataset, lever_report
    from stableins.output import emit
    from stableins.records import CalibrationRecord

    prior = CalibrationRecord.load(args.prior)
    source = lever_data_file(args.run)
    dataset = load_device(source)
    check_same_unit(dataset.metadata, prior, args.prior)
    options = LeverOptions(
        arms=LeverSet.FULL if args.all_arms else LeverSet.CAI, asynchrony=not args.no_asynchrony, window=float(args.window)
    )
    fit = lever_from_dataset(dataset, prior, options)
    time = dataset.columns["time"]
    procedure = str(dataset.metadata.extra.get("procedure", "device-rotating"))
    updated = update_prior(args, prior, fit, data=(source, dataset.metadata, (time[0], time[-1])), procedure=procedure)
    ids = {t.id for t in fit.terms}
    assert isinstance(fit.details, LeverDetails)
    data = {
        "data": str(source),
        "prior": args.prior,
        "out": str(args.out),
        "lever": _document(fit),
        "flags": [{"name": f.name, "chi2": f.chi2, "dof": f.dof, "p_value": f.p_value, "flagged": f.flagged} for f in fit.details.flags],
        "chi2_reduced": fit.chi2_red,
        "settings": {} if fit.settings is None else fit.settings.to_document(),
        "parameters": [
            {"id": p.id, "value": p.value, "sigma": p.sigma if p.sigma == p.sigma else None, "status": p.status.value}
            for p in updated.parameters
            if p.id in ids
        ],
    }
    emit(args, data, text="\n".join([lever_report(fit), "", updated.report(), "", f"updated calibration written to {args.out}"]))
    return 0


def _document(fit: Any) -> dict[str, dict[str, float | str]]:
    """Return the estimates in engineering units (mm, ms) with 1σ, as the report prints them."""
    return {
        t.id: {"value": float(v) / t.scale, "sigma": float(s) / t.scale, "unit": t.unit}
        for t, v, s in zip(fit.terms, fit.values, fit.sigma, strict=True)
    }
