"""``stableins recal``: field recalibration, a new calibration that updates the unit's record in force.

::

    # run a short device-level set on the platform; its stage updates the record in force
    stableins recal field-recal-device --unit INS-7 --store cal/ --driver tcp://127.0.0.1:5025 --out runs/recal-2026-06
    # or apply a calibration made elsewhere from new data (e.g. 'stableins calibrate device' on field data, or
    # 'stableins calibrate system --new-calibration' with the record in force as --prior): its stages update the record in force
    stableins recal --unit INS-7 --store cal/ --estimate other.json --out runs/recal-2026-06
    # an interrupted recalibration (a prompt declined, the link lost, kill -9) continues as a recalibration
    stableins recal --resume runs/recal-2026-06      # or 'stableins run --resume runs/recal-2026-06': the same

Exactly one new record is written, ``OUT/record.json``: the record in force updated by the new
stage(s), a Bayesian update (no σ grows, nothing moves along what the new data do not see).  It
is filed in the history store (so it is the record in force from the end of its data) and its
certificate is ``OUT/report.pdf``.  The store is ``--store DIR``, else ``$STABLEINS_HISTORY``, else
``~/.local/share/stableins/history`` (as for ``stableins history``); ``--prior RECORD`` gives the record in
force directly.  Every parameter's change is printed with its significance
(:func:`stableins.history.compare`: the new record descends from the old one, σ² of a change =
σ²_old − σ²_new; flagged at |z| ≥ 3), the same numbers the certificate shows.

The run of a recalibration keeps the store and whether to file in its journal's start record, so a resume
(``recal --resume RUNDIR`` or ``run --resume RUNDIR``, no other option needed) files the one new record and
prints its changes exactly as the uninterrupted recalibration would have.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from stableins.history import Comparison


#: Who the certificate names (ISO/IEC 17025 7.8.2.1), as recal asks for them: the operator every time, the laboratory
#: and the customer when the record in force names none.
RECAL_IDENTIFICATION = {
    "operator": "Operator (the person performing this recalibration)",
    "laboratory": "Laboratory (the calibration laboratory issuing the certificate)",
    "customer": "Customer (for whom the unit is calibrated)",
}


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the arguments of ``stableins recal`` to ``parser``."""
    from stableins.commands import run as run_command

    run_command.configure(parser)
    parser.add_argument("--estimate", metavar="RECORD", help="a record of new data whose own stages update the record in force")
    parser.add_argument("--no-file", action="store_true", help="do not file the new record in the history store")
    for key, text in RECAL_IDENTIFICATION.items():
        parser.add_argument(
            f"--{key}", metavar="NAME", help=f"{text.lower()} (asked when not given; without all three the certificate is a DRAFT)"
        )
    for action in parser._actions:
        if action.dest == "store":
            action.help = "history store with the unit's record in force (default $STABLEINS_HISTORY or ~/.local/share/stableins/history)"


def apply_estimate(prior, prior_path: Path, estimate_path: Path):
    """Return the record in force updated by the stage runs of ``estimate``'s own calibration (their likelihoods), in order."""
    from stableins.errors import InputError
    from stableins.records import CalibrationRecord, PriorReference, file_sha256

    estimate = CalibrationRecord.load(estimate_path)
    if estimate.serial_number != prior.serial_number:
        raise InputError(
            f"the estimate is of unit {estimate.serial_number!r}, the record in force of {prior.serial_number!r}",
            path=estimate_path,
            field="serial_number",
            expected="the same unit",
        )
    known = {s.id for s in prior.stages}
    runs = [s for s in estimate.stages_run if s.id not in known]
    if not runs:
        raise InputError("the estimate holds no stage run that the record in force lacks", path=estimate_path, field="stages")
    missing = [s.name for s in runs if s.likelihood is None]
    if missing:
        raise InputError(
            f"stage run(s) {', '.join(missing)} carry no likelihood (a migrated record): they cannot update a record",
            path=estimate_path,
            field="stages",
            expected="a record written by this version of stableins",
        )
    record = prior
    reference = PriorReference(file_sha256(prior_path), str(prior_path), prior.calibration.created)
    for k, run in enumerate(runs):
        record = record.updated_by_run(run, new_calibration=k == 0, prior=reference, site=estimate.site)
    return record


def run(args: argparse.Namespace) -> int:
    """Run ``stableins recal``: a field recalibration against the unit's record in force; return the exit code."""
    from stableins.commands import run as run_command
    from stableins.data.atomic import atomic_write
    from stableins.errors import InputError
    from stableins.history import compare
    from stableins.history_store import HistoryStore
    from stableins.output import emit, note
    from stableins.records import CalibrationRecord

    prior_path = _resumed_prior(args) if args.resume and not args.estimate else _prior_path(args)
    prior = CalibrationRecord.load(prior_path)
    if args.unit and prior.serial_number != args.unit:  # the record in force is named, not the estimate checked against it
        raise InputError(
            f"the record in force is of unit {prior.serial_number!r}", path=prior_path, field="serial_number", expected=repr(args.unit)
        )
    if args.estimate:  # read (and refused) before anyone is asked who they are
        CalibrationRecord.load(args.estimate)
    if not args.resume:  # a resumed recalibration has them in its journal's start record
        args.set = [*args.set, *identification_entries(args, prior)]
    if args.estimate:
        if args.procedure or args.resume:
            raise InputError("give either --estimate or a PROCEDURE to run", field="--estimate")
        out = Path(args.out) if args.out else Path(args.estimate).parent
        record, record_path = _estimate_record(args, prior, prior_path, out)
    else:
        args.prior = str(prior_path)
        args.new_calibration = True  # a recalibration starts a new calibration from the record in force
        args.recal = {"store": str(args.store) if args.store else None, "file": not args.no_file}  # kept for its resume
        args.emit_result = False  # one result on stdout: the recalibration's
        status = run_command.run(args)
        if status != 0:
            return status
        if args.finished is not None:  # --resume of a finished recalibration: its record was filed when it finished
            emit(args, {"rundir": str(args.finished.rundir), "finished": True, "completed": args.finished.completed},
                 f"finished: {args.finished.rundir} (completed {args.finished.completed}); nothing was filed again")  # fmt: skip
            return 0
        out = Path(args.resume or args.out)
        record_path = out / "record.json"
        if not record_path.exists():
            raise InputError("the procedure produced no record", path=record_path, expected="a procedure whose stage estimates")
        record = CalibrationRecord.load(record_path)
    comparison = compare(prior, record)
    heading = f"field recalibration of {args.unit}: {prior_path} -> {record_path} (certificate {out / 'report.pdf'})"
    text = [heading, *_changes_text(comparison)]
    if args.store and not args.no_file:
        entry = HistoryStore(args.store).add(record_path)
        note(f"filed in {args.store} as {entry.file}: the record in force from {entry.valid_from}")
    with atomic_write(out / "recal-changes.txt") as handle:
        handle.write("\n".join(text) + "\n")
    data = {
        "record": str(record_path),
        "prior": str(prior_path),
        "report": str(out / "report.pdf"),
        "relation": comparison.relation,
        "changes": [c.to_json() for c in comparison.changes],
        "significant": list(comparison.significant),
        "not_compared": list(comparison.skipped),
    }
    emit(args, data, "\n".join(text))
    sys.stdout.flush()
    return 0


def _estimate_record(args: argparse.Namespace, prior, prior_path: Path, out: Path):
    """Write ``OUT/record.json`` (the record in force updated by ``--estimate``, with who) and its certificate; return both."""
    from stableins.commands.run import parse_settings
    from stableins.output import note
    from stableins.records import parse_entries
    from stableins.reporting import write_report

    given = parse_settings(args.set)
    record = apply_estimate(prior, prior_path, Path(args.estimate))
    record = record.with_entries(parse_entries(f"{k}={given[k]}" for k in RECAL_IDENTIFICATION if given.get(k)))
    record_path = record.save(out / "record.json")
    summary = write_report(out / "report.pdf", record_path, previous=prior_path)
    note("statement of conformity of the certificate:\n" + "\n".join(f"  {line}" for line in summary.conformity))
    if summary.missing:
        note(f"the certificate is a DRAFT: {', '.join(summary.missing)} not stated (give --{' NAME --'.join(summary.missing)} NAME)")
    return record, record_path


def identification_entries(args: argparse.Namespace, prior) -> list[str]:
    """Return ``KEY=NAME`` settings of the operator, laboratory and customer, asked before the platform moves.

    Each is the flag's (``--operator`` ...), else ``--set KEY=NAME``'s, else (laboratory, customer) the record in force's,
    else asked as the procedure asks for the site temperature (:meth:`stableins.console.Console.name`; not asked with
    ``--yes``).  One not stated leaves the certificate a DRAFT, as ``stableins report`` does.
    """
    from stableins.commands.run import parse_settings
    from stableins.console import Console
    from stableins.reporting.context import entry_text

    given = parse_settings(args.set)
    console = Console(yes=args.yes, values={k: v for k, v in given.items() if k in RECAL_IDENTIFICATION}, quiet=args.quiet)
    out = []
    for key, prompt in RECAL_IDENTIFICATION.items():
        flag = getattr(args, key, None)
        carried = entry_text(prior, key) if key != "operator" and key not in given else None
        if flag:
            name = flag.strip()
        elif carried:
            name = carried
            console.say(f"  {prompt.split(' (')[0]}: {carried} (the record in force's)")
        elif key in given:
            continue  # already among --set
        else:
            name = console.name(key, prompt)
        if name:
            out.append(f"{key}={name}")
    return out


def resume_arguments(args: argparse.Namespace) -> argparse.Namespace:
    """Return the arguments of ``run --resume RUNDIR`` as ``recal --resume RUNDIR``'s (a recalibration's run resumes as one)."""
    values = vars(args) | {"estimate": None, "no_file": False}
    return argparse.Namespace(**values)


def _resumed_prior(args: argparse.Namespace) -> Path:
    """Set unit, store and filing of ``recal --resume RUNDIR`` from the run's start record; return the record in force it started from.

    The record in force is the run's copy (``RUNDIR/prior.json``, whose SHA-256 the resume checks against the journal).
    """
    from stableins.commands.run import recal_settings
    from stableins.errors import InputError
    from stableins.procedures.journal import JOURNAL_NAME, start_record
    from stableins.procedures.rundir import PRIOR_NAME

    rundir = Path(args.resume)
    settings = recal_settings(rundir)
    if settings is None:
        raise InputError(
            "this run directory holds no field recalibration that can be resumed",
            path=rundir,
            expected=f"a directory made by 'stableins recal PROCEDURE ... --out DIR' (a run of 'stableins run': run --resume {rundir})",
        )
    start = start_record(rundir / JOURNAL_NAME)
    assert start is not None  # recal_settings read it
    if args.unit and args.unit != start["unit"]:
        raise InputError(f"this recalibration is of unit {start['unit']!r}", path=rundir, field="--unit", expected=repr(start["unit"]))
    if args.store and str(args.store) != settings.get("store"):
        where = settings.get("store")
        raise InputError(f"this recalibration files its record in {where}", path=rundir, field="--store", expected="no --store, or it")
    args.unit = start["unit"]
    args.store = settings.get("store")
    args.no_file = bool(args.no_file or not settings.get("file", True))
    return rundir / PRIOR_NAME


def _prior_path(args: argparse.Namespace) -> Path:
    """Return the unit's record in force: ``--prior``, or the store's (``--store``, by default the history store)."""
    from stableins.commands import run as run_command
    from stableins.errors import InputError

    if not args.unit:
        raise InputError("which unit?", field="--unit", expected="the serial number")
    if not args.store and not args.prior:  # the history store of 'stableins history': $STABLEINS_HISTORY or the default
        from stableins.history_store import default_store

        args.store = str(default_store())
    prior_path = run_command.prior_file(args)
    if prior_path is None:
        raise InputError("a recalibration needs the unit's previous record", field="--store", expected="--store DIR or --prior RECORD")
    return prior_path


def _changes_text(comparison: Comparison) -> list[str]:
    """Return the comparison with the record in force as text: the relation, the changes, the significant and the skipped."""
    from stableins.history import CHANGE_THRESHOLD, format_changes

    text = [comparison.describe(), "", format_changes(comparison.changes)]
    if comparison.significant:
        text += ["", f"changed (|z| ≥ {CHANGE_THRESHOLD:g}): {', '.join(comparison.significant)}"]
    if comparison.skipped:
        text += ["", "not compared: " + "; ".join(comparison.skipped)]
    return text
