"""``stableins history SERIAL``: a unit's calibration records, the one in force, staleness, drift.

::

    stableins history INS-7 --store cal/ --add runs/fine/record.json     # file a record
    stableins history INS-7 --store cal/                                  # index, in force now, changes, drift
    stableins history INS-7 --store cal/ --at 2026-03-01 --plot drift.png
"""

from __future__ import annotations

import argparse


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("serial", metavar="SERIAL", help="unit serial number")
    parser.add_argument("--store", metavar="DIR", help="history store (default $STABLEINS_HISTORY or ~/.local/share/stableins/history)")
    parser.add_argument("--add", nargs="+", default=[], metavar="RECORD", help="file these calibration records first")
    parser.add_argument("--at", metavar="DATE", help="which record was in force at this ISO 8601 date (default: now)")
    parser.add_argument("--max-age", type=float, default=180.0, metavar="DAYS", help="older records in force are stale (default 180)")
    parser.add_argument("--plot", metavar="FILE", help="write the drift plot (PNG, PDF, SVG by suffix)")


def run(args: argparse.Namespace) -> int:
    from datetime import timedelta

    from stableins.data.errors import InputError
    from stableins.history import CHANGE_THRESHOLD, HistoryStore, format_changes, format_trends, parse_date, plot_trends
    from stableins.output import emit, note
    from stableins.records import CalibrationRecord

    store = HistoryStore(args.store)
    for path in args.add:
        record = CalibrationRecord.load(path)
        if record.serial_number != args.serial:
            raise InputError(f"record of unit {record.serial_number!r}", path=path, field="serial_number", expected=repr(args.serial))
        entry = store.add(path)
        note(f"filed {path} as {entry.file} (valid from {entry.valid_from})")
    entries = store.entries(args.serial)
    if not entries:
        raise InputError(f"no calibration records for unit {args.serial!r}", path=store.root, expected="records filed with --add")
    date = parse_date(args.at, "--at") if args.at else None
    lines = [f"calibration history of {args.serial} ({store.root})", ""]
    lines.append(f"{'valid from':<26} {'stages':<22} {'procedure':<20} file")
    for e in entries:
        lines.append(f"{e.valid_from:<26} {','.join(e.stages):<22} {e.procedure:<20} {e.file}")
    data: dict = {"serial_number": args.serial, "entries": [e.__dict__ for e in entries]}
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
    if args.plot:
        if not trends:
            raise InputError("a drift plot needs at least two records that estimate the same parameter", field="--plot")
        from stableins.data.atomic import atomic_path

        figure = plot_trends(trends, args.serial)
        suffix = args.plot.rsplit(".", 1)[-1] if "." in args.plot else "png"
        with atomic_path(args.plot) as temporary:
            figure.savefig(temporary, format=suffix)
        note(f"drift plot written: {args.plot}")
        data["plot"] = args.plot
    emit(args, data, "\n".join(lines))
    return 0
