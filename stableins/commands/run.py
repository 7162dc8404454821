"""``stableins run``: carry out a calibration procedure on a platform, journaled and resumable.

::

    stableins run device-coarse --driver sim --unit INS-7 --out runs/coarse --seed 3
    stableins run device-fine --driver tcp://127.0.0.1:5025 --unit INS-7 --out runs/fine --prior runs/coarse/record.json
    stableins run --resume runs/fine            # after a crash, a power loss, kill -9 or a stop

PROCEDURE is a definition name (``procedures/<name>.toml``), a ``.toml`` file, or a plan
``.json`` (``procedure.json`` of an earlier run).  Exit status: 0 done, 2 bad input,
3 stopped (a step failed its retries, the link failed, a person declined): resume with --resume.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

EXIT_STOPPED = 3


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("procedure", nargs="?", metavar="PROCEDURE", help="procedure name, .toml definition or .json plan")
    parser.add_argument("--driver", help="sim, tcp://HOST:PORT or replay:RUNDIR (on --resume: a new tcp:// address)")
    parser.add_argument("--unit", help="serial number of the unit (checked against the platform)")
    parser.add_argument("--out", metavar="RUNDIR", help="new run directory (journal, data, records)")
    parser.add_argument("--resume", metavar="RUNDIR", help="continue the run in RUNDIR where it stopped")
    parser.add_argument("--seed", type=int, help="seed of the simulated platform (sim): same seed, same samples")
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
    parser.add_argument("--retries", type=int, help="repeats of a rejected dwell before stopping (default: the procedure's, 2)")
    parser.add_argument("--chunk", type=float, help="journal dwells in pieces of at most this many seconds (default 10)")
    parser.add_argument("--link-failures", type=int, default=3, help="consecutive link failures of one step before stopping")
    parser.add_argument("--timeout", type=float, default=10.0, help="network driver: longest silence accepted [s]")
    parser.add_argument("--quiet", action="store_true", help="say nothing but errors")


def parse_settings(items: list[str]) -> dict[str, str]:
    from stableins.data.errors import InputError

    values = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise InputError(f"cannot read {item!r}", field="--set", expected="KEY=VALUE")
        values[key.strip()] = value.strip()
    return values


def load_plan(procedure: str, retries: int | None, chunk: float | None) -> tuple[Any, Path | None]:
    """The plan for PROCEDURE, and the definition file to copy into the run directory (if any)."""
    import dataclasses
    import json

    from stableins.data.errors import InputError
    from stableins.procedures.plan import Plan

    path = Path(procedure)
    if path.suffix == ".json":
        try:
            plan = Plan.from_dict(json.loads(path.read_text(encoding="utf-8")))
        except FileNotFoundError:
            raise InputError("no such plan file", path=path) from None
        except (ValueError, KeyError, TypeError) as error:
            raise InputError(f"not a procedure plan ({error})", path=path, expected="a procedure.json written by 'stableins run'") from None
        definition_file = None
    else:
        from stableins.procedures.definition import load_procedure, resolve
        from stableins.procedures.planning import plan_from_definition

        definition_file = resolve(procedure)
        plan = plan_from_definition(load_procedure(definition_file))
    changes = {k: v for k, v in (("retries", retries), ("chunk", chunk)) if v is not None}
    return (dataclasses.replace(plan, **changes) if changes else plan), definition_file


def prior_file(args: argparse.Namespace) -> Path | None:
    from stableins.data.errors import InputError

    if args.prior:
        return Path(args.prior)
    if args.store:
        if not args.unit:
            raise InputError("--store needs --unit to find the unit's record", field="--unit")
        from stableins.history import HistoryStore

        store = HistoryStore(args.store)
        entry = store.in_force(args.unit)
        warning = store.staleness(entry)
        if warning:
            print(f"stableins: warning: {warning}", file=sys.stderr)
        return store.root / args.unit / entry.file
    return None


def run(args: argparse.Namespace) -> int:
    from stableins.data.errors import InputError
    from stableins.drivers.errors import DriverError
    from stableins.output import emit
    from stableins.procedures.rundir import resume_run, start_run
    from stableins.procedures.runner import Console, JournalMismatch, RunOptions, RunStopped

    console = Console(yes=args.yes, values=parse_settings(args.set), quiet=args.quiet)
    rundir = args.resume or args.out
    try:
        if args.resume:
            if args.procedure or args.out:
                raise InputError("--resume continues a run as it was started", field="--resume", expected="no PROCEDURE and no --out")
            outcome = resume_run(args.resume, console=console, driver_spec=args.driver, timeout=args.timeout)
        else:
            missing = [name for name, value in (("PROCEDURE", args.procedure), ("--driver", args.driver), ("--out", args.out)) if not value]
            if missing:
                raise InputError(
                    f"missing {', '.join(missing)}", field=missing[0], expected="PROCEDURE --driver SPEC --out RUNDIR, or --resume RUNDIR"
                )
            plan, definition_file = load_plan(args.procedure, args.retries, args.chunk)
            outcome = start_run(
                plan,
                args.out,
                driver_spec=args.driver,
                seed=args.seed,
                unit=args.unit,
                console=console,
                options=RunOptions(link_failures=args.link_failures),
                definition_file=definition_file,
                prior_file=prior_file(args),
                timeout=args.timeout,
                new_calibration=bool(args.new_calibration or (args.store and not args.prior)),
                fields=parse_settings(args.set),
            )
    except RunStopped as stop:
        print(
            f"stableins: run stopped: {stop}\n  everything accepted so far is in {rundir}; continue with: stableins run --resume {rundir}",
            file=sys.stderr,
        )
        return EXIT_STOPPED
    except DriverError as error:
        print(f"stableins: platform: {error}\n  continue with: stableins run --resume {rundir}", file=sys.stderr)
        return EXIT_STOPPED
    except JournalMismatch as error:
        print(f"stableins: error: {error}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(
            f"stableins: interrupted; everything accepted so far is in {rundir}; continue with: stableins run --resume {rundir}",
            file=sys.stderr,
        )
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
    }
    emit(args, data, "\n".join(f"{k}: {v}" for k, v in data.items() if v is not None))
    return 0
