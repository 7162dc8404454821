"""``stableins history``: a unit's calibration records, the one in force, staleness, drift; the fleet at a glance.

::

    stableins history INS-7 --store cal/ --add runs/fine/record.json     # file a record
    stableins history INS-7 --store cal/                                  # index, in force now, changes, drift
    stableins history INS-7 --store cal/ --at 2026-03-01 --plot drift.png
    stableins history --store cal/ --fleet                                # every unit: in force, age, due, drifting
    stableins history --store cal/ --fleet --due --drifted               # only the units that need attention
    stableins history --store cal/ --verify                               # every filed record against its SHA-256
    stableins history --migrate cal/ postgresql://lab@db/history          # copy a store into another (SQLite <-> PostgreSQL)

The store is a SQLite index beside the records, or a PostgreSQL database shared by several stations
(``--store postgresql://...``; :mod:`stableins.history_store`); every record read is checked against the SHA-256 the
index holds.
"""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING, NotRequired, TypedDict

if TYPE_CHECKING:
    from datetime import datetime

    from stableins.history import ChangeDocument, Trend
    from stableins.history_store import HistoryStore

#: The changes between two consecutive records of a unit (``stableins history SERIAL --json``, ``changes``).
RecordChanges = TypedDict(
    "RecordChanges",
    {
        "from": str,
        "to": str,
        "relation": str,
        "parameters": "list[ChangeDocument]",
        "significant": list[str],
        "not_compared": list[str],
    },
)


class TrendDocument(TypedDict):
    """The drift per year of one parameter (``trends``)."""

    id: str
    unit: str
    records: int
    slope_per_year: float
    sigma: float
    significance: float


class UnitHistory(TypedDict):
    """The document of ``stableins history SERIAL --json``: the records, the one in force, changes, drift, the plot."""

    serial_number: str
    entries: list[dict[str, object]]
    in_force: NotRequired[str]
    stale: NotRequired[str | None]
    changes: NotRequired[list[RecordChanges]]
    trends: NotRequired[list[TrendDocument]]
    plot: NotRequired[str]


#: Formats of the drift plot, by suffix.
PLOT_FORMATS = ("png", "pdf", "svg")


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the arguments of ``stableins history`` to ``parser``."""
    from stableins.commands.arguments import output_file, real

    parser.add_argument("serial", nargs="?", metavar="SERIAL", help="unit serial number (omit with --fleet or --verify)")
    parser.add_argument(
        "--store",
        metavar="DIR",
        help="history store: a directory or a postgresql:// URL (default $STABLEINS_HISTORY or ~/.local/share/stableins/history)",
    )
    parser.add_argument("--add", nargs="+", default=[], metavar="RECORD", help="file these calibration records first")
    parser.add_argument("--at", metavar="DATE", help="which record was in force at this ISO 8601 date (default: now)")
    parser.add_argument(
        "--max-age",
        type=real(0.0, 36525.0, unit="days"),
        default=180.0,
        metavar="DAYS",
        help="older records in force are stale, 0 to 36525 days (default 180)",
    )
    parser.add_argument("--plot", type=output_file, metavar="FILE", help="write the drift plot (PNG, PDF, SVG by suffix)")
    parser.add_argument("--fleet", action="store_true", help="every unit of the store: record in force, age, due, drifting parameters")
    parser.add_argument("--due", action="store_true", help="with --fleet: only units without a record in force or with a stale one")
    parser.add_argument("--drifted", action="store_true", help="with --fleet: only units with a parameter drifting beyond 3σ per year")
    parser.add_argument(
        "--verify", action="store_true", help="check the index and every filed record against its SHA-256 (exit 2 if any fails)"
    )
    parser.add_argument(
        "--migrate",
        nargs=2,
        metavar=("SRC", "DST"),
        help="copy every record of store SRC into store DST (directories or postgresql:// URLs), each verified by its SHA-256",
    )


def run(args: argparse.Namespace) -> int:
    """Run ``stableins history``: file, list, verify or summarize calibration records; return the exit code."""
    from stableins.errors import InputError

    if args.migrate:
        if args.serial or args.add or args.fleet or args.verify or args.store or args.plot:
            raise InputError("--migrate SRC DST copies a whole store", field="--migrate", expected="no SERIAL, --store or other action")
        return _migrate(args)
    if (args.due or args.drifted) and not args.fleet:
        raise InputError("--due and --drifted select units of the fleet", field="--due", expected="--fleet as well")
    if args.fleet or (args.verify and not args.serial):
        if args.serial or args.add or args.plot:
            raise InputError(
                "--fleet and --verify without SERIAL look at the whole store", field="SERIAL", expected="no SERIAL, --add or --plot"
            )
        return _fleet(args) if args.fleet else _verify(args)
    if not args.serial:
        raise InputError("which unit?", field="SERIAL", expected="a serial number, or --fleet / --verify for the whole store")
    if args.verify:
        return _verify(args)
    return _unit(args)


def _migrate(args: argparse.Namespace) -> int:
    from stableins.errors import InputError
    from stableins.history_store import HistoryStore
    from stableins.history_store.transfer import transfer
    from stableins.output import emit

    source, target = HistoryStore(args.migrate[0]), HistoryStore(args.migrate[1])
    done = transfer(source, target)
    problems = target.verify()
    text = (
        f"migrated {source.location} -> {target.location}: {done.units} unit(s), {done.records} record(s) read verified, "
        f"{done.filed} filed ({done.records - done.filed} already there); target verified: {len(problems)} problem(s)"
    )
    emit(args, {"source": source.location, "target": target.location, "units": done.units, "records": done.records,
                "filed": done.filed, "problems": problems}, text)  # fmt: skip
    if problems:
        raise InputError(f"{len(problems)} problem(s) in the migrated store; the first: {problems[0]}", path=target.location)
    return 0


def _verify(args: argparse.Namespace) -> int:
    from stableins.errors import InputError
    from stableins.history_store import HistoryStore
    from stableins.output import emit

    store = HistoryStore(args.store)
    problems = store.verify(args.serial)
    emit(args, {"store": store.location, "problems": problems}, "\n".join(problems) or f"{store.location}: every filed record verified")
    if problems:
        raise InputError(f"{len(problems)} problem(s) in the history store; the first: {problems[0]}", path=store.location)
    return 0


def _fleet(args: argparse.Namespace) -> int:
    from datetime import timedelta

    from stableins.history import parse_date
    from stableins.history_store import HistoryStore
    from stableins.output import emit

    store = HistoryStore(args.store)
    date = parse_date(args.at, "--at") if args.at else None
    units = store.fleet(date, timedelta(days=args.max_age))
    shown = [u for u in units if (not args.due or u.due) and (not args.drifted or u.drifting)]
    lines = [
        f"fleet of {store.location}: {len(units)} unit(s), {sum(u.due for u in units)} due, "
        f"{sum(bool(u.drifting) for u in units)} drifting",
        "",
    ]
    lines.append(f"{'unit':<16} {'records':>7} {'in force since':<26} {'age [d]':>8} {'due':<4} drifting (z = drift/σ per year)")
    for u in shown:
        since = u.in_force.valid_from if u.in_force else "none"
        age = f"{u.age_days:.0f}" if u.age_days is not None else "-"
        drift = ", ".join(f"{p} {z:+.1f}" for p, z in u.drifting) or "-"
        lines.append(f"{u.serial:<16} {u.records:>7} {since:<26} {age:>8} {'yes' if u.due else 'no':<4} {drift}")
    data = {
        "store": store.location,
        "max_age_days": args.max_age,
        "units": [
            {
                "serial": u.serial,
                "records": u.records,
                "in_force": None if u.in_force is None else u.in_force.file,
                "valid_from": None if u.in_force is None else u.in_force.valid_from,
                "age_days": u.age_days,
                "due": u.due,
                "drifting": [{"id": p, "significance": z} for p, z in u.drifting],
            }
            for u in shown
        ],
    }
    emit(args, data, "\n".join(lines))
    return 0


def _unit(args: argparse.Namespace) -> int:
    """File the records of ``--add``, then show one unit's history: its records, the one in force, changes and drift."""
    from stableins.errors import InputError
    from stableins.history import parse_date
    from stableins.history_store import HistoryStore
    from stableins.output import emit

    if args.plot and args.plot.suffix.lower().lstrip(".") not in PLOT_FORMATS:
        raise InputError(
            f"cannot draw a {args.plot.suffix or 'suffix-less'} file", path=args.plot, field="--plot", expected=".png, .pdf or .svg"
        )
    store = HistoryStore(args.store)
    store.unit_directory(args.serial)  # a serial number that cannot name a folder is refused before anything is read
    date = parse_date(args.at, "--at") if args.at else None
    _file_records(args, store)
    entries = store.entries(args.serial)
    if not entries:
        raise InputError(f"no calibration records for unit {args.serial!r}", path=store.location, expected="records filed with --add")
    lines = [f"calibration history of {args.serial} ({store.location})", ""]
    lines.append(f"{'valid from':<26} {'stages':<22} {'procedure':<20} file")
    for e in entries:
        lines.append(f"{e.valid_from:<26} {','.join(e.stages):<22} {e.procedure:<20} {e.file}")
    data: UnitHistory = {"serial_number": args.serial, "entries": [e.__dict__ for e in entries]}
    _in_force(args, store, date, lines, data)
    _changes(args, store, lines, data)
    trends = _trends(args, store, lines, data)
    if args.plot:
        _plot(args, trends, data)
    emit(args, data, "\n".join(lines))
    return 0


def _file_records(args: argparse.Namespace, store: HistoryStore) -> None:
    """File the records of ``--add`` in the store, every one checked to be of the unit before the first is filed."""
    from stableins.errors import InputError
    from stableins.output import note
    from stableins.records import CalibrationRecord

    for path in args.add:
        record = CalibrationRecord.load(path)
        if record.serial_number != args.serial:
            raise InputError(f"record of unit {record.serial_number!r}", path=path, field="serial_number", expected=repr(args.serial))
    for path in args.add:
        entry = store.add(path)
        note(f"filed {path} as {entry.file} (valid from {entry.valid_from})")


def _in_force(args: argparse.Namespace, store: HistoryStore, date: datetime | None, lines: list[str], data: UnitHistory) -> None:
    """Add the record in force (at ``--at``, or now) and its staleness to the text and the JSON document."""
    from datetime import timedelta

    from stableins.errors import InputError
    from stableins.output import note

    try:
        current = store.in_force(args.serial, date)
    except InputError as error:
        current = None
        lines += ["", f"in force: none ({error.message})"]
    if current is not None:
        warning = store.staleness(current, date, timedelta(days=args.max_age))
        lines += ["", f"in force{' at ' + args.at if args.at else ''}: {current.file} (valid from {current.valid_from})"]
        if warning:
            lines.append(f"WARNING: {warning}")
            note(f"stableins: warning: {warning}")
        data["in_force"] = current.file
        data["stale"] = warning


def _changes(args: argparse.Namespace, store: HistoryStore, lines: list[str], data: UnitHistory) -> None:
    """Add the changes between consecutive records to the text and the JSON document."""
    from stableins.history import CHANGE_THRESHOLD, format_changes

    changes = store.changes(args.serial)
    for old, new, comparison in changes:
        lines += ["", f"{old.valid_from} -> {new.valid_from} ({comparison.describe()}; z = change / σ of the change):"]
        lines.append(format_changes(comparison.changes))
        if comparison.significant:
            lines.append(f"changed (|z| ≥ {CHANGE_THRESHOLD:g}): {', '.join(comparison.significant)}")
    data["changes"] = [
        {
            "from": o.file,
            "to": n.file,
            "relation": c.relation,
            "parameters": [x.to_json() for x in c.changes],
            "significant": list(c.significant),
            "not_compared": list(c.skipped),
        }
        for o, n, c in changes
    ]


def _trends(args: argparse.Namespace, store: HistoryStore, lines: list[str], data: UnitHistory) -> list[Trend]:
    """Add the drift per year of every parameter to the text and the JSON document; return the trends."""
    from stableins.history import format_trends

    trends = store.trends(args.serial)
    if trends:
        lines += ["", "drift per year (weighted straight line; z = drift / σ):", format_trends(trends)]
        data["trends"] = [
            {
                "id": t.id,
                "unit": t.unit,
                "records": len(t.values),
                "slope_per_year": t.slope,
                "sigma": t.slope_sigma,
                "significance": t.significance,
            }
            for t in trends
        ]
    return trends


def _plot(args: argparse.Namespace, trends: list[Trend], data: UnitHistory) -> None:
    """Draw the drift plot of ``--plot`` (atomically)."""
    from stableins.data.atomic import atomic_path
    from stableins.errors import InputError
    from stableins.history import plot_trends
    from stableins.output import note

    if not trends:
        raise InputError("a drift plot needs at least two records that estimate the same parameter", field="--plot")
    figure = plot_trends(trends, args.serial)
    suffix = args.plot.suffix.lower().lstrip(".")
    with atomic_path(args.plot) as temporary:
        figure.savefig(temporary, format=suffix)
    note(f"drift plot written: {args.plot}")
    data["plot"] = str(args.plot)
