"""``stableins calibrate poses``: calibrate a triad from the static poses of a real log (any columns, any units).

::

    stableins calibrate poses imu.csv --columns time=t,f_x=ax,f_y=ay,f_z=az --units counts:4096/g --out cal.json
    stableins calibrate poses imu.csv --columns map.toml --detect-only --write-holds holds.csv --plot holds.png
    stableins calibrate poses imu.csv --columns map.toml --holds holds.csv --out cal.json   # edited or labelled holds

Reads the log (:mod:`stableins.data.rawlog`), finds its holds (:mod:`stableins.data.holds`) or reads them from
an edited holds table, and fits them (:mod:`stableins.estimators.poses`): the squared-amplitude fit for holds of
unknown orientation, the six-position test for holds labelled ``+x`` ... ``-z``.  Writes the calibration record,
and on request the holds table and the plot of the log with its holds; nothing is written when the input is bad.
"""

from __future__ import annotations

import argparse
from pathlib import Path


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the arguments of ``stableins calibrate poses`` to ``parser``."""
    from stableins.commands.arguments import input_file, output_file, png_file, real
    from stableins.commands.noise import add_noise_options

    parser.add_argument("log", type=input_file, metavar="LOG", help="the log: CSV (any delimiter, header optional) or HDF5")
    parser.add_argument(
        "--columns",
        required=True,
        metavar="MAP",
        help="what the columns are: time=COL,f_x=COL,f_y=COL,f_z=COL[,temperature=COL] (header names, 1-based numbers "
        "without a header, HDF5 dataset[:column]) or a mapping file MAP.toml (docs/formats.md, 'Real logs')",
    )
    parser.add_argument(
        "--units", metavar="UNIT", help="m/s2, g, counts:S/g, counts:S/(m/s2), dv:W; one for all axes or f_x=...,f_y=...,f_z=..."
    )
    parser.add_argument(
        "--zero", metavar="C0", help="the converter's zero in counts, one or three (e.g. 32768 for offset binary); default 0"
    )
    parser.add_argument(
        "--range", dest="full_scale", metavar="LOW:HIGH", help="the converter's range in the file's units (clipping is read from it)"
    )
    parser.add_argument(
        "--time-unit",
        choices=("s", "ms", "us", "ns", "samples", "iso"),
        help="unit of the time column (default s; samples: a counter at --rate; iso: ISO 8601)",
    )
    parser.add_argument(
        "--rate", type=real(0.0, 1e7, above=True, unit="Hz"), metavar="HZ", help="sample rate, when the log has no time column"
    )
    parser.add_argument("--gravity", type=real(9.7, 9.9, unit="m/s^2"), metavar="G", help="local gravity [m/s^2] (default 9.80665, stated)")
    parser.add_argument("--serial", metavar="SN", help="serial number of the unit (default: the log's file name)")
    parser.add_argument(
        "--window",
        type=real(0.0, 60.0, above=True, unit="s"),
        default=0.5,
        metavar="S",
        help="hold detection: test window [s] (default 0.5)",
    )
    parser.add_argument(
        "--min-hold", type=real(0.0, 3600.0, above=True, unit="s"), default=1.5, metavar="S", help="shortest hold kept [s] (default 1.5)"
    )
    parser.add_argument(
        "--false-split",
        type=real(0.0, 0.5, above=True),
        default=1e-6,
        metavar="ALPHA",
        help="probability that a static window is taken for motion (default 1e-6)",
    )
    parser.add_argument(
        "--holds",
        type=input_file,
        metavar="HOLDS.csv",
        help="use these holds (an edited holds table, optionally labelled +x ... -z) instead of detecting",
    )
    parser.add_argument(
        "--write-holds", type=output_file, metavar="HOLDS.csv", help="write the holds table (start, end, mean, std, orientation)"
    )
    parser.add_argument("--plot", type=png_file, metavar="PNG", help="draw the log with its holds")
    parser.add_argument("--detect-only", action="store_true", help="find the holds, write --write-holds/--plot, fit nothing")
    parser.add_argument(
        "--out", type=output_file, metavar="RECORD.json", help="calibration record to write (required unless --detect-only)"
    )
    parser.add_argument(
        "--diagnose", action="store_true", help="model discovery on the holds: refit with each instrument effect of the library, rank, flag"
    )
    parser.add_argument(
        "--add",
        action="append",
        default=[],
        metavar="ID",
        help="estimate this effect with the standard terms (repeatable; kept when its F-test p < 0.05)",
    )
    add_noise_options(parser)


def run(args: argparse.Namespace) -> int:
    """Run ``stableins calibrate poses``; return the exit code."""
    from stableins.conventions import STANDARD_GRAVITY
    from stableins.data.holds import detect_holds, read_holds
    from stableins.data.logmap import layout_from_options
    from stableins.data.rawlog import read_raw_log
    from stableins.errors import InputError
    from stableins.estimators.details import DeviceDetails
    from stableins.estimators.poses import PoseSettings
    from stableins.output import emit, note

    if args.out is None and not args.detect_only:
        raise InputError("no record to write", field="--out", expected="--out RECORD.json, or --detect-only")
    layout = layout_from_options(
        args.columns, args.units, zero=args.zero, full_scale=args.full_scale, time_unit=args.time_unit, rate=args.rate
    )
    log = read_raw_log(args.log, layout)
    source = str(args.log)
    if args.holds is not None:
        holds = read_holds(args.holds, log.time)
        how = f"{len(holds)} holds read from {args.holds}"
    else:
        detection = detect_holds(
            log.time,
            log.specific_force,
            window=args.window,
            min_hold=args.min_hold,
            false_split=args.false_split,
            resolution=log.resolution,
            source=source,
        )
        holds = detection.holds
        how = detection.describe(log.rate)
    if not holds:
        raise InputError(
            f"no static hold found ({how})",
            path=source,
            field="holds",
            expected=f"holds of at least --min-hold {args.min_hold:g} s at rest (or another --window, a smaller --min-hold, --holds TABLE)",
        )
    clipping = "clipping read from the converter's range " + (
        f"({log.range_source}: {log.full_scale[0][0]:g} ... {log.full_scale[0][1]:g})"
        if log.full_scale
        else "(none declared: no sample taken as clipped; give --range)"
    )
    if args.detect_only:
        _write_views(args, log, holds)
        emit(args, {"holds": len(holds), "detection": how}, f"{how}\n{clipping}")
        return 0
    gravity = args.gravity if args.gravity is not None else STANDARD_GRAVITY
    fit, record, noise_text, refit = _calibrate(args, log, holds, gravity, source)
    text = (
        f"{how}\n{clipping}\n"
        + ("" if args.gravity is not None else f"local gravity not given: standard gravity {STANDARD_GRAVITY} m/s^2 (--gravity G)\n")
        + f"noise model: {noise_text}\n\n"
        + fit.report()
        + "\n\n== calibration record (what the certificate shows) ==\n"
        + record.report()
    )
    scan = None
    if args.diagnose and not any(h.orientation for h in holds):  # model discovery on the holds of unknown orientation
        from stableins.discovery.poses import scan_poses

        scan = scan_poses(refit)
    if scan is not None:
        text += "\n\n" + scan.report()
    _write_all(args, log, holds, record)
    note(f"calibration record written to {args.out}")
    steps = _next_steps(args, fit, scan)
    for line in steps:
        note(line)
    emit(
        args,
        {
            "record": str(args.out),
            "holds": len(holds),
            "detection": how,
            "model": fit.settings.model.name if isinstance(fit.settings, PoseSettings) else None,
            "chi2_red": fit.chi2_red,
            "dof": fit.dof,
            "parameters": {
                t.id: {"value": float(v), "sigma": float(s), "status": str(st)}
                for t, v, s, st in zip(fit.terms, fit.values, fit.sigma, fit.status, strict=True)
            },
            "left_out": {str(k): v for k, v in fit.details.left_out.items()} if isinstance(fit.details, DeviceDetails) else {},
            "notes": list(fit.notes),
            "diagnose": None if scan is None else {"flagged": scan.flagged, "report": scan.report()},
            "next": [line.strip() for line in steps if line.startswith("  ")],
        },
        text,
    )
    return 0


def _calibrate(args: argparse.Namespace, log, holds, gravity: float, source: str):
    """Return the fit, its record, where the noise model comes from, and the fit as a function of added terms (``--diagnose``)."""
    from stableins.commands.noise import noise_from_options
    from stableins.estimators.device import noise_from_dwells
    from stableins.estimators.poses import calibrate_poses, summarize_holds
    from stableins.records import CalibrationRecord, RunInfo, temperature_summary

    dwells = summarize_holds(log.time, log.specific_force, log.railed, [(h.first, h.stop) for h in holds])
    given, noise_text = noise_from_options(args, dwells)
    noise = given if given is not None else noise_from_dwells(dwells, source=f"the holds of {source}")
    fit_noise = noise if (given is not None or noise.has_slow_noise) else None

    def refit(extra):
        return calibrate_poses(
            dwells, gravity=gravity, orientations=[h.orientation for h in holds], noise=fit_noise, extra_terms=extra, source=source
        )

    fit = _with_added(refit, args.add)
    start, end = _data_times(log)
    environment = {} if log.temperature is None else temperature_summary(log.temperature)
    run = RunInfo(procedure="poses", inputs=[source], data_start=start, data_end=end, sample_rate=log.rate, environment=environment)
    serial = args.serial or Path(source).name.removesuffix(".xz").removesuffix(".gz").rsplit(".", 1)[0]
    record = CalibrationRecord.from_fit_result(fit, run, serial_number=serial, noise_model=noise)
    return fit, record, noise_text if given is not None else noise.describe(), refit


def _with_added(refit, added: list[str]):
    """Return the pose fit with the ``--add`` effects the data show (each F-tested in order at 0.05; a note for each)."""
    from dataclasses import replace

    from stableins.discovery.library import calibration_terms
    from stableins.discovery.scores import effect_statistics
    from stableins.status import Status

    fit = refit(())
    kept: list = []
    notes: list[str] = []
    for term in calibration_terms(added):
        trial = refit((*kept, term))
        value, sigma, status = trial[term.id]
        estimate = f"{term.id} = {float(term.to_engineering(value)):+.4g} ± {float(term.sigma_to_engineering(sigma)):.2g} {term.unit}"
        if status != Status.ESTIMATED:
            notes.append(f"added effect {term.id}: not determined by these holds; left out")
            continue
        _, p, _ = effect_statistics(max(fit.chi2 - trial.chi2, 0.0), fit.chi2, fit.dof, fit.residuals.size)
        if p < 0.05:
            kept.append(term)
            fit = trial
            notes.append(f"added effect {estimate}: F-test p = {p:.2g} < 0.05, kept")
        else:
            notes.append(f"added effect {estimate}: F-test p = {p:.2g} >= 0.05, the holds do not show it; left out")
    return replace(fit, notes=fit.notes + tuple(notes)) if notes else fit


def _data_times(log) -> tuple[str, str]:
    """Return the ISO 8601 times of the first and last sample ("" when the log has no timestamps)."""
    import numpy as np

    if not log.start_time:
        return "", ""
    first = np.datetime64(log.start_time, "s")
    last = first + np.timedelta64(int(round(float(log.time[-1]))), "s")
    return f"{first}Z", f"{last}Z"


def _write_views(args: argparse.Namespace, log, holds) -> None:
    from stableins.data.holds import plot_holds, write_holds

    if args.write_holds is not None:
        write_holds(args.write_holds, log.time, log.specific_force, holds)
    if args.plot is not None:
        plot_holds(args.plot, log.time, log.specific_force, holds, title=f"{Path(log.path).name}: {len(holds)} holds (shaded)")


def _write_all(args: argparse.Namespace, log, holds, record) -> None:
    """Write the record, then the holds table and plot (each atomically)."""
    from stableins.data.atomic import atomic_path
    from stableins.errors import InputError

    try:
        with atomic_path(args.out) as target:
            record.save(target)
    except OSError as error:
        raise InputError(f"cannot write the record: {error.strerror or error}", path=str(args.out), field="--out") from None
    _write_views(args, log, holds)


def _next_steps(args: argparse.Namespace, fit, scan) -> list[str]:
    """Return what to do next: model discovery when the model does not fit, the flagged effect carried in when it found one."""
    import shlex

    command = ["stableins", "calibrate", "poses", str(args.log), "--columns", args.columns]
    options = (("--units", args.units), ("--zero", args.zero), ("--range", args.full_scale), ("--time-unit", args.time_unit))
    command += [x for pair in options if pair[1] for x in pair]
    command += [
        x for pair in (("--rate", args.rate), ("--gravity", args.gravity)) if pair[1] is not None for x in (pair[0], f"{pair[1]:g}")
    ]
    command += ["--holds", str(args.holds)] if args.holds is not None else []
    if scan is not None and scan.flagged:
        added = [x for a in (*args.add, scan.flagged) for x in ("--add", a)]
        return [
            f"next: carry the flagged effect {scan.flagged} into the calibration",
            f"  {shlex.join([*command, *added, '--out', str(args.out)])}",
        ]
    if fit.dof > 0 and fit.chi2_red > 1 + 3 * (2 / fit.dof) ** 0.5:
        if scan is None:
            return [
                f"next: the model does not fit the holds (chi2_red {fit.chi2_red:.3g} for nu = {fit.dof}); is it missing an effect? "
                "(model discovery on the holds)",
                f"  {shlex.join([*command, '--diagnose', '--out', str(args.out)])}",
            ]
        return [
            "next: no library effect explains the misfit; look at the holds and the largest residuals named above "
            "(motion inside a hold?), or give the noise model of a static record (--noise CAL.json from 'stableins noise')",
            f"  {shlex.join([*command, '--detect-only', '--write-holds', 'holds.csv', '--plot', 'holds.png'])}",
        ]
    return []
