"""``stableins run``: carry out a calibration procedure on a platform, journaled and resumable.

::

    stableins run device-coarse --driver sim --unit INS-7 --out runs/coarse --seed 3
    stableins run device-fine --driver tcp://127.0.0.1:5025 --unit INS-7 --out runs/fine --prior runs/coarse/record.json
    stableins run --resume runs/fine            # after a crash, a power loss, kill -9 or a stop
    stableins run --resume runs/fine --re-estimate   # a finished run, estimated again from its journal

PROCEDURE is the name of a shipped definition (``device-coarse``, found from any directory), a ``.toml``
file, or a plan ``.json`` (``procedure.json`` of an earlier run).  ``--resume`` of a finished run says it
is finished and changes nothing (``--re-estimate`` estimates it again from its journal).  Exit status: 0 done, 2 bad input,
3 stopped (a step failed its retries, the link failed, a person declined): resume with --resume.
This module is the procedure run that ``stableins run`` and ``stableins recal`` both build on; the CLI's
``run`` is :mod:`stableins.commands.run_command`, which hands a field recalibration's run over to
:mod:`stableins.commands.recal` (so this module never imports the command that imports it).
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from stableins.console import Console
    from stableins.documents import JSONObject
    from stableins.procedures.rundir import RunOutcome

#: Exit status of a run that stopped and can be resumed (2 is bad input, 4 data that do not determine what was asked:
#: :mod:`stableins.cli`); defined here only, the command that returns it.
EXIT_STOPPED = 3
#: ``--timeout`` when none is given: the longest silence accepted from a network platform [s].
NETWORK_TIMEOUT = 10.0


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the arguments of ``stableins run`` to ``parser``."""
    from stableins.commands.arguments import effect_magnitude, input_file, integer, output_directory, real, seed
    from stableins.procedures.plan import CHUNK_RANGE, RETRIES_RANGE

    parser.add_argument("procedure", nargs="?", metavar="PROCEDURE", help="procedure name, .toml definition or .json plan")
    parser.add_argument("--driver", help="sim, tcp://HOST:PORT or replay:RUNDIR (on --resume: a new tcp:// address)")
    parser.add_argument("--unit", help="serial number of the unit (checked against the platform)")
    parser.add_argument("--out", type=output_directory, metavar="RUNDIR", help="new run directory (journal, data, records)")
    parser.add_argument("--resume", metavar="RUNDIR", help="continue the run in RUNDIR where it stopped (a finished run: says so)")
    parser.add_argument(
        "--re-estimate",
        action="store_true",
        help="with --resume of a finished run: estimate it again from its journal alone (no platform) and write its data, "
        "record and certificate anew",
    )
    parser.add_argument("--seed", type=seed, help="seed of the simulated platform (sim): same seed, same samples")
    parser.add_argument(
        "--truth",
        type=input_file,
        metavar="TRUTH.json",
        help="sim: simulate this world (a truth.json of 'stableins simulate') instead of drawing one from --seed; "
        "the run directory keeps the truth it ran (truth.json)",
    )
    parser.add_argument(
        "--hidden",
        type=effect_magnitude,
        action="append",
        default=[],
        metavar="ID=VALUE",
        help="sim: inject an effect of the simulator's catalogue (as 'stableins simulate --hidden'; repeatable)",
    )
    parser.add_argument("--yes", action="store_true", help="unattended: confirm every prompt, take defaults")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="value for a person step (repeatable)")
    parser.add_argument("--prior", metavar="RECORD", help="the unit's previous record (zero offsets to re-point; fine stage builds on it)")
    parser.add_argument("--store", metavar="DIR", help="history store: use the unit's record in force as --prior")
    parser.add_argument(
        "--new-calibration",
        action="store_true",
        help="the run starts a new calibration from --prior (default with --store: the record in force is a previous calibration; "
        "with --prior the run continues the prior's calibration, e.g. the fine stage after the coarse stage)",
    )
    parser.add_argument(
        "--retries", type=integer(*RETRIES_RANGE), help="repeats of a rejected dwell before stopping (default: the procedure's, 2)"
    )
    parser.add_argument(
        "--chunk",
        type=real(*CHUNK_RANGE, unit="seconds"),
        help=f"journal dwells in pieces of at most this many seconds, {CHUNK_RANGE[0]:g} to {CHUNK_RANGE[1]:g} (default: the procedure's)",
    )
    parser.add_argument(
        "--link-failures", type=integer(1, 100), default=3, help="consecutive link failures of one step before stopping (1 to 100)"
    )
    parser.add_argument(
        "--timeout",
        type=real(0.1, 3600.0, unit="seconds"),
        help=f"network driver: longest silence accepted [s], 0.1 to 3600 (default {NETWORK_TIMEOUT:g}); refused with another driver",
    )
    parser.add_argument("--quiet", action="store_true", help="say nothing but errors")


def network_timeout(args: argparse.Namespace) -> float:
    """Return ``--timeout`` (default :data:`NETWORK_TIMEOUT`): the silence a network platform may keep.

    The simulated and the replayed platforms never wait, so there it would be ignored: refused instead (issue 31).
    """
    from stableins.errors import InputError

    if args.timeout is None:
        return NETWORK_TIMEOUT
    if args.driver and not str(args.driver).startswith("tcp://"):
        raise InputError(
            f"--timeout is the silence a network platform may keep; the {args.driver} platform does not wait",
            field="--timeout",
            expected="--driver tcp://HOST:PORT with --timeout, or no --timeout",
        )
    return float(args.timeout)


def parse_settings(items: list[str]) -> dict[str, str]:
    """Return the ``--set KEY=VALUE`` items as a mapping; InputError naming the item that is not ``KEY=VALUE``."""
    from stableins.errors import InputError

    values = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise InputError(f"cannot read {item!r}", field="--set", expected="KEY=VALUE")
        values[key.strip()] = value.strip()
    return values


def load_plan(procedure: str, retries: int | None, chunk: float | None) -> tuple[Any, Path | None]:
    """Return the plan for PROCEDURE, and the definition file to copy into the run directory (if any)."""
    import dataclasses

    from stableins.procedures.plan import Plan

    path = Path(procedure)
    if path.suffix == ".json":
        from stableins.data.jsonio import load_json_file

        plan = Plan.from_dict(load_json_file(path, what="a procedure plan (procedure.json written by 'stableins run')"), path)
        definition_file = None
    else:
        from stableins.procedures.definition import load_procedure, resolve
        from stableins.procedures.planning import plan_from_definition

        definition_file = resolve(procedure)
        definition = load_procedure(definition_file)
        plan = plan_from_definition(definition)
        if definition.tolerances is not None:  # read by the report at the end of the run: checked before the platform moves
            from stableins.reporting.tolerances import Tolerances

            Tolerances.from_mapping(definition.tolerances, source=str(definition_file))
        if definition.uncertainty is not None:  # the certificate's Type B inputs: checked before the platform moves too
            from stableins.reporting.budget import UncertaintyInputs

            UncertaintyInputs.from_mapping(definition.uncertainty, source=str(definition_file))
    if retries is not None:
        plan = dataclasses.replace(plan, retries=retries)
    if chunk is not None:
        plan = dataclasses.replace(plan, chunk=chunk)
    return plan, definition_file


def simulated_truth(args: argparse.Namespace, sample_rate: float | None) -> Any:
    """Return the world of ``--truth`` / ``--hidden`` for the simulated platform, or None (a truth drawn from ``--seed``).

    ``--truth`` is read as written (its sample rate set to the procedure's); ``--hidden`` alone adds effects to the
    truth drawn from ``--seed`` with serial number ``--unit``.  Checked before anything is written or moves.
    """
    from stableins.errors import InputError

    if args.truth is None and not args.hidden:
        return None
    if args.driver != "sim":
        field = "--truth" if args.truth is not None else "--hidden"
        raise InputError(f"{field} describes the world of the simulated platform", field=field, expected="--driver sim")
    from dataclasses import replace

    from stableins.data.truth import load_truth
    from stableins.simulator.effects import validate_effects
    from stableins.simulator.truth import SimulatedSite, Truth

    if args.truth is not None:
        truth = load_truth(args.truth)
        if sample_rate:
            truth = truth.with_changes(site=replace(truth.site, sample_rate=float(sample_rate)))
    else:
        site = SimulatedSite(serial_number=args.unit)
        if sample_rate:
            site = replace(site, sample_rate=float(sample_rate))
        truth = Truth.draw(0 if args.seed is None else args.seed, site=site)
    if args.hidden:
        effects = dict(truth.effects) | dict(args.hidden)
        truth = truth.with_changes(effects=validate_effects(effects, source="--hidden"))
    return truth


def prior_file(args: argparse.Namespace) -> Path | None:
    """Return the prior record of the run: ``--prior``, or the record in force of ``--unit`` in ``--store``."""
    from stableins.errors import InputError

    if args.prior:
        return Path(args.prior)
    if args.store:
        if not args.unit:
            raise InputError("--store needs --unit to find the unit's record", field="--unit")
        from stableins.history_store import HistoryStore

        store = HistoryStore(args.store)
        entry = store.in_force(args.unit)
        warning = store.staleness(entry)
        if warning:
            print(f"stableins: warning: {warning}", file=sys.stderr)
        return store.record_path(args.unit, entry)  # its SHA-256 checked against the index
    return None


def _resumable(rundir: str | None) -> bool:
    """Whether RUNDIR holds a run that ``--resume`` can continue (a journal that starts with its start record)."""
    from stableins.procedures.journal import JOURNAL_NAME, has_start

    return rundir is not None and has_start(Path(rundir) / JOURNAL_NAME)


def recal_settings(rundir: str | os.PathLike[str]) -> JSONObject | None:
    """Return the field-recalibration settings the run in RUNDIR was started with (``stableins recal``), or None."""
    from stableins.procedures.journal import JOURNAL_NAME, start_record

    start = start_record(Path(rundir) / JOURNAL_NAME)
    settings = start.get("recal") if start is not None else None
    return dict(settings) if isinstance(settings, dict) else None


def _how_to_continue(rundir: str | None, args: argparse.Namespace) -> str:
    """Return what the person can do next: resume only when there is something to resume (as a recalibration if it is one)."""
    if _resumable(rundir):
        assert rundir is not None
        command = "recal" if recal_settings(rundir) is not None else "run"
        return f"everything accepted so far is in {rundir}; continue with: stableins {command} --resume {rundir}"
    return "nothing was started (the run directory holds no journal); fix the problem and run the same command again"


def run(args: argparse.Namespace) -> int:
    """Start or resume a procedure on a platform (``stableins run``, and the run of ``stableins recal``); return the exit code."""
    from stableins.console import Console
    from stableins.drivers.errors import DriverError
    from stableins.output import emit
    from stableins.procedures.rundir import RunFinished
    from stableins.procedures.runner import RunStopped
    from stableins.procedures.session import JournalMismatch

    console = Console(yes=args.yes, values=parse_settings(args.set), quiet=args.quiet)
    rundir = args.resume or args.out
    args.finished = None
    try:
        outcome = _start_or_resume(args, console)
    except RunFinished as finished:
        args.finished = finished
        print(
            f"stableins: {finished}; nothing was run or rewritten.\n"
            f"  to estimate it again from its journal (e.g. with a newer stableins): stableins run --resume {rundir} --re-estimate",
            file=sys.stderr,
        )
        if getattr(args, "emit_result", True):
            files = {p.name: str(p) for p in finished.outputs}
            emit(args, {"rundir": str(finished.rundir), "finished": True, "completed": finished.completed, "files": files},
                 f"finished: {finished.rundir} (completed {finished.completed})")  # fmt: skip
        return 0
    except RunStopped as stop:
        print(f"stableins: run stopped: {stop}\n  {_how_to_continue(rundir, args)}", file=sys.stderr)
        return EXIT_STOPPED if _resumable(rundir) else 1
    except DriverError as error:
        print(f"stableins: platform: {error}\n  {_how_to_continue(rundir, args)}", file=sys.stderr)
        return EXIT_STOPPED if _resumable(rundir) else 1
    except JournalMismatch as error:
        print(f"stableins: error: {error}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"stableins: interrupted\n  {_how_to_continue(rundir, args)}", file=sys.stderr)
        return 130
    if not getattr(args, "emit_result", True):  # a command that runs a procedure and reports itself (recal)
        return 0
    data = {
        "rundir": str(outcome.rundir),
        "dataset": outcome.dataset,
        "record": outcome.record,
        "report": outcome.report,
        "dwells": len(outcome.runner.entries),
        "static_record_chunks": len(outcome.runner.static_chunks),
        "replayed_records": outcome.replayed,
        "verdict": outcome.verdict,
        "conformity": list(outcome.conformity),
    }
    text = [f"{k}: {v}" for k, v in data.items() if v is not None and k != "conformity"]
    emit(args, data, "\n".join(text + [f"  {line}" for line in outcome.conformity]))
    return 0


def _start_or_resume(args: argparse.Namespace, console: Console) -> RunOutcome:
    """Start the run of PROCEDURE in ``--out``, or resume the run in ``--resume``; return its outcome."""
    from stableins.errors import InputError
    from stableins.procedures.runner import RunOptions
    from stableins.runs import RunSetup, resume_run, start_run

    if args.re_estimate and not args.resume:
        raise InputError("--re-estimate estimates a finished run again", field="--re-estimate", expected="--resume RUNDIR as well")
    if args.resume:
        if args.procedure or args.out or args.truth is not None or args.hidden:
            raise InputError(
                "--resume continues a run as it was started", field="--resume", expected="no PROCEDURE, --out, --truth or --hidden"
            )
        timeout = network_timeout(args)
        return resume_run(args.resume, console=console, driver_spec=args.driver, timeout=timeout, re_estimate=args.re_estimate)
    missing = [name for name, value in (("PROCEDURE", args.procedure), ("--driver", args.driver), ("--out", args.out)) if not value]
    if missing:
        raise InputError(
            f"missing {', '.join(missing)}", field=missing[0], expected="PROCEDURE --driver SPEC --out RUNDIR, or --resume RUNDIR"
        )
    plan, definition_file = load_plan(args.procedure, args.retries, args.chunk)
    truth = simulated_truth(args, plan.sample_rate)
    return start_run(
        plan,
        args.out,
        driver_spec=args.driver,
        seed=args.seed,
        unit=args.unit,
        console=console,
        setup=RunSetup(
            definition_file=definition_file,
            prior_file=prior_file(args),
            new_calibration=bool(args.new_calibration or (args.store and not args.prior)),
            fields=parse_settings(args.set),
            options=RunOptions(link_failures=args.link_failures),
            timeout=network_timeout(args),
            recal=getattr(args, "recal", None),
            truth=truth,
        ),
    )
