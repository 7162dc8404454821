"""``stableins recal``: field recalibration with the unit's previous record as the prior.

::

    # run a short device-level set on the platform, then combine it with the record in force
    stableins recal device-fine --unit INS-7 --store cal/ --driver tcp://127.0.0.1:5025 --out runs/recal-2026-06
    # or combine an estimate made elsewhere: a data-only device-level estimate (estimate.json of a run),
    # or a system-level correction ('stableins calibrate system' with the record in force as --prior)
    stableins recal --unit INS-7 --store cal/ --estimate estimate.json --out runs/recal-2026-06

Every parameter's change is printed with its significance (change / σ of the change, where
σ² = P_prior − P_new because the new record is built on the old one; see
:mod:`stableins.recalibration`).  The new record is filed in the history store.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def configure(parser: argparse.ArgumentParser) -> None:
    from stableins.commands import run as run_command

    run_command.configure(parser)
    parser.add_argument("--estimate", metavar="RECORD", help="data-only estimate to combine, instead of running PROCEDURE")
    parser.add_argument("--no-file", action="store_true", help="do not file the new record in the history store")


def run(args: argparse.Namespace) -> int:
    from stableins.commands import run as run_command
    from stableins.data.atomic import atomic_write
    from stableins.data.errors import InputError
    from stableins.history import compare, format_changes
    from stableins.history_store import HistoryStore
    from stableins.output import emit, note
    from stableins.recalibration import fuse_with_prior
    from stableins.records import CalibrationRecord, file_sha256

    if not args.unit:
        raise InputError("which unit?", field="--unit", expected="the serial number")
    prior_path = run_command.prior_file(args)
    if prior_path is None:
        raise InputError("a recalibration needs the unit's previous record", field="--store", expected="--store DIR or --prior RECORD")
    prior = CalibrationRecord.load(prior_path)
    if args.estimate:
        if args.procedure or args.resume:
            raise InputError("give either --estimate or a PROCEDURE to run", field="--estimate")
        estimate_path = Path(args.estimate)
        out = Path(args.out) if args.out else estimate_path.parent
    else:
        args.prior = str(prior_path)
        status = run_command.run(args)
        if status != 0:
            return status
        out = Path(args.resume or args.out)
        estimate_path = out / "estimate.json"
        if not estimate_path.exists():
            raise InputError(
                "the procedure produced no estimate to combine", path=estimate_path, expected="a procedure whose stage estimates"
            )
    estimate = CalibrationRecord.load(estimate_path)
    digest = file_sha256(prior_path)
    if "system" in estimate.provenance.stages:
        # the system-level stage already starts from the installed (prior) calibration and estimates
        # the correction to it from the data: fusing it with the prior again would count the prior twice
        fused = prior.update(estimate)
        prior_used = False
        how = "system-level correction applied to the previous record (the stage used it as its prior); σ² of a change = σ²_old + σ²_new"
    else:
        fused = fuse_with_prior(prior, estimate, prior_sha256=digest)
        prior_used = True
        how = "data-only estimate combined with the previous record as prior; σ² of a change = σ²_old − σ²_new"
    record_path = fused.save(out / "recal.json")
    changes = compare(prior, fused, prior_used=prior_used)
    significant = [c.id for c in changes if abs(c.significance) >= 3]
    text = [f"field recalibration of {args.unit}: {prior_path} -> {record_path}", how, "", format_changes(changes)]
    if significant:
        text += ["", f"changed beyond 3σ: {', '.join(significant)}"]
    if not prior_used and estimate.determined:
        # the system-level stage determines combinations of parameters; per-parameter changes along
        # directions it does not see are the prior's (gauge), so its own summary is the evidence
        text += ["", "what the new data determine (system-level stage):"] + [f"  {line}" for line in estimate.determined]
    if args.store and not args.no_file:
        entry = HistoryStore(args.store).add(record_path, prior=digest if prior_used else "", evidence=estimate_path)
        note(f"filed in {args.store} as {entry.file}")
    with atomic_write(out / "recal-changes.txt") as handle:
        handle.write("\n".join(text) + "\n")
    data = {
        "record": str(record_path),
        "prior": str(prior_path),
        "estimate": str(estimate_path),
        "changes": [{**c.__dict__, "significance": c.significance} for c in changes],
        "significant": significant,
    }
    emit(args, data, "\n".join(text))
    sys.stdout.flush()
    return 0
