"""``stableins budget CAL.json --duration 5d [--latitude DEG] [--damping ZETA] [--drift X Y Z] [--compare OTHER.json] [--plot F] [--json]``.

The navigation budget of a calibration record: each term's 1σ (and the gyro drift) propagated through the INS
error dynamics of a space-stable INS on a static base (docs/navigation-budget.md).  Not the uncertainty budget of
the coefficients the certificate prints.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Mapping
from pathlib import Path

from stableins.commands.arguments import input_file, output_file, real
from stableins.commands.simulate import parse_duration

_HELP = "navigation budget: what each calibration term's 1σ and the gyro drift do to position, velocity and attitude"


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the arguments of ``stableins budget`` to ``parser``."""
    parser.description = (
        "Propagate every term's 1σ of a calibration record (and the gyro drift) through the static-base INS error "
        "dynamics of a space-stable INS: per term the peak and final position, velocity and attitude errors, the RSS of "
        "the terms and the total with the record's correlations (docs/navigation-budget.md)."
    )
    parser.add_argument("record", metavar="CAL.json", type=input_file, help="calibration record")
    parser.add_argument(
        "--duration",
        type=duration_with_unit,
        default=5 * 86400.0,
        metavar="DURATION",
        help="navigation time with its unit, e.g. 12h, 5d, 3600s (default 5d)",
    )
    parser.add_argument(
        "--latitude", type=real(-89.0, 89.0, unit="degrees"), metavar="DEG", help="latitude [deg] (default: the record's site)"
    )
    parser.add_argument(
        "--damping",
        type=real(0.0, 5.0),
        metavar="ZETA",
        help="damping ratio of the horizontal loops, 0 = pure inertial (default: the site's, 0 without one)",
    )
    parser.add_argument(
        "--drift",
        nargs=3,
        type=real(0.0, 10.0, unit="deg/h"),
        metavar=("X", "Y", "Z"),
        help="1σ of the constant platform gyro drift per axis [deg/h] (default: the record's gyro_drift_* terms)",
    )
    parser.add_argument("--compare", type=input_file, metavar="OTHER.json", help="a second record: both budgets and the difference")
    parser.add_argument("--plot", type=output_file, metavar="FILE", help="figure: the largest errors up to each time (PNG, PDF, SVG)")
    parser.add_argument("--json", action="store_true", help="print the result as JSON on stdout")


PLOT_SUFFIXES = (".png", ".pdf", ".svg")


def duration_with_unit(text: str) -> float:
    """Return a navigation time with its unit (``5d``, ``12h``, ``3600s``) in seconds; refuse a bare number (not read as seconds)."""
    if text.strip().replace(".", "", 1).isdigit():
        raise argparse.ArgumentTypeError(f"{text!r} has no unit: give one, e.g. {text.strip()}d (days), {text.strip()}h or {text.strip()}s")
    return parse_duration(text)


def run(args: argparse.Namespace) -> int:
    """Read the record(s), compute the budget(s), print; write the plot last (nothing half-written)."""
    from stableins.errors import InputError
    from stableins.navigation.budget import drift_sigma_from_engineering
    from stableins.output import emit
    from stableins.records import CalibrationRecord
    from stableins.reporting.navigation import record_navigation_budget

    if args.plot is not None and args.plot.suffix.lower() not in PLOT_SUFFIXES:
        raise InputError(
            f"cannot write a figure to {args.plot.name}", path=str(args.plot), field="--plot", expected="a .png, .pdf or .svg file"
        )
    record = CalibrationRecord.load(args.record)
    latitude = None if args.latitude is None else math.radians(args.latitude)
    drift = None if args.drift is None else drift_sigma_from_engineering(args.drift)
    budget = record_navigation_budget(
        record, duration=args.duration, latitude=latitude, zeta=args.damping, drift_sigma=drift, path=args.record
    )
    data: Mapping[str, object]
    if args.compare is not None:
        other_record = CalibrationRecord.load(args.compare)
        other = record_navigation_budget(
            other_record, duration=args.duration, drift_sigma=drift, scenario=budget.scenario, path=args.compare
        )
        comparison = budget.compare(other, labels=(Path(args.record).name, Path(args.compare).name))
        data, text = comparison.to_dict(), comparison.report()
    else:
        data, text = budget.to_dict(), budget.report()
    if args.plot is not None:
        from stableins.data.atomic import atomic_path

        with atomic_path(args.plot) as temporary:
            budget.plot(str(temporary), file_format=args.plot.suffix.lower().lstrip("."))
        data = {**data, "plot": str(args.plot)}
        text += f"\nplot: {args.plot}"
    emit(args, data, text)
    return 0
