"""``stableins calibrate device``: coarse (and fine) device-level calibration from data files.

::

    stableins calibrate device sim/device-device-coarse.csv sim/device-device-fine.csv --out record.json
    stableins calibrate device session.h5 --out record.json --json
    stableins calibrate device sim/device-coarse.csv sim/device-fine.h5 --add Kcc_xxy --out record.json

Runs the coarse stage on every coarse pass in the data (the last pass is the coarse
result), then the fine stage when fine dwells are present, prints the report and writes
the calibration record (atomically: a failed run never leaves a half-written record).

``--add ID`` (repeatable; and ``[model] add = [...]`` in the procedure files) carries
effects found by ``stableins diagnose`` into the calibration: every stage estimates them
with the standard parameters, each gets a verdict from the fused fit (F-test p against
``--alpha``, ΔBIC; :mod:`stableins.discovery.carry`), an effect the data do not show is left
out of the record (``--keep-unsupported`` keeps it) and the record carries the history.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

from stableins.commands import add_entries_option
from stableins.status import Status

if TYPE_CHECKING:  # pragma: no cover
    from stableins.records import RunInfo

#: The gyro g-sensitivity ids (``--add Dg_ab`` goes to the gyro stage, not to the accelerometer model).
G_SENSITIVITY_IDS = frozenset(f"Dg_{a}{b}" for a in "xyz" for b in "xyz")


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the arguments of ``stableins calibrate device`` to ``parser``."""
    from stableins.commands.arguments import output_file, real

    parser.add_argument("data", nargs="+", type=Path, metavar="DATA", help="device-level data files (CSV or HDF5), coarse and/or fine")
    parser.add_argument("--out", type=output_file, required=True, metavar="RECORD.json", help="calibration record to write")
    parser.add_argument("--coarse-procedure", default="device-coarse", metavar="NAME", help="coarse procedure name or TOML file")
    parser.add_argument("--fine-procedure", default="device-fine", metavar="NAME", help="fine procedure name or TOML file")
    parser.add_argument(
        "--allow-missing", action="store_true", help="leave out missing positions (noted in the record) instead of stopping with an error"
    )
    parser.add_argument(
        "--coarse-linear",
        action="store_true",
        help="the paper's 15-parameter coarse stage (ignores K2; biased for instruments with quadratic terms)",
    )
    parser.add_argument(
        "--report", type=output_file, metavar="FILE", help="also write the full text report (every stage, noise model, gyro stage) to FILE"
    )
    parser.add_argument(
        "--verbose", action="store_true", help="print the full text report (by default: the record's summary, about a screen)"
    )
    from stableins.commands.noise import add_noise_options

    add_noise_options(parser)
    parser.add_argument(
        "--add",
        action="append",
        default=[],
        metavar="ID",
        help="estimate this discovered effect with the standard parameters (repeatable, tested in order; see 'stableins diagnose')",
    )
    parser.add_argument(
        "--alpha",
        type=real(0.0, 0.5, above=True),
        default=0.05,
        help="false-alarm level of the F-test that keeps an added effect (default 0.05)",
    )
    parser.add_argument(
        "--keep-unsupported",
        action="store_true",
        help="keep an added effect even when the data do not show it (default: left out of the record, with its verdict)",
    )
    parser.add_argument(
        "--no-gyro",
        action="store_true",
        help="skip the gyro stage (gyro drift and the nine g-sensitivities from the reading slopes); with --add Dg_ab "
        "it estimates the drift and only the g-sensitivities added",
    )
    add_entries_option(parser)


def _same_site(datasets) -> None:
    from stableins.errors import InputError

    first = datasets[0]
    for other in datasets[1:]:
        for name in ("serial_number", "gravity", "gimbal_senses", "base_attitude"):
            a, b = getattr(first.metadata, name), getattr(other.metadata, name)
            if a != b:
                raise InputError(
                    f"metadata differ between {first.path} and {other.path}: {a!r} vs {b!r}",
                    path=other.path,
                    field=name,
                    expected="all files of one calibration from the same unit and site",
                )
    from stableins.dwell_mode import DwellMode

    for dataset in datasets:  # the accelerometer stages take dwells held to the base (docs/conventions.md)
        if dataset.metadata.dwell_mode is DwellMode.INERTIAL:
            raise InputError(
                "the platform was inertially held during the dwells: it turns 15 deg/h against gravity (2.5 deg in a "
                "600-s dwell), and the accelerometer stages take dwells held to the base",
                path=dataset.path, field="metadata.dwell_mode",
                expected='caged or earth_rate (docs/conventions.md, "The platform during a dwell")',
            )  # fmt: skip


def run(args: argparse.Namespace) -> int:
    """Run ``stableins calibrate device``: the coarse and fine stages on device-level data; return the exit code."""
    import functools
    from dataclasses import replace

    from stableins.commands.noise import noise_from_options
    from stableins.discovery.carry import carry_effects
    from stableins.discovery.library import calibration_terms
    from stableins.errors import InputError
    from stableins.estimators.device import calibrate_device
    from stableins.output import emit, note
    from stableins.procedures.definition import load_procedure
    from stableins.progress import Progress
    from stableins.records import CalibrationRecord, parse_entries

    if not 0.0 < args.alpha < 1.0:
        raise InputError("must lie between 0 and 1", field="--alpha", expected="a false-alarm level such as 0.05")
    coarse_procedure = load_procedure(args.coarse_procedure)
    fine_procedure = load_procedure(args.fine_procedure)
    layouts = {"coarse": coarse_procedure.layout, "fine": fine_procedure.layout}
    effect_ids = _effect_ids(args, coarse_procedure, fine_procedure)
    gyro_added = [e for e in effect_ids if e in G_SENSITIVITY_IDS]
    effects = calibration_terms([e for e in effect_ids if e not in G_SENSITIVITY_IDS])
    # the steps a person waits for: reading each file, its dwells, each fit of the calibration, the gyro stage
    bar = Progress(total=2 * len(args.data) + 1 + len(effects) + 1, label="calibrate device")
    datasets, per_file, summaries = _read(args.data, layouts, bar)  # each file summarized once (the gyro stage reuses them)
    bar.describe("calibrate device: the coarse and fine fits" + (f" (+ {len(effects)} added effects, one at a time)" if effects else ""))
    site = datasets[0].metadata
    noise, _ = noise_from_options(args, summaries)  # ranges checked when parsed (stableins.commands.arguments)
    calibrate = functools.partial(
        calibrate_device,
        summaries,
        site,
        layouts=layouts,
        allow_missing=args.allow_missing,
        noise=noise,
        coarse_nonlinear=not args.coarse_linear,
        source=", ".join(str(p) for p in args.data),
    )
    history = None
    if effects:
        carried = carry_effects(
            lambda extra: calibrate(extra_terms=extra),
            effects,
            alpha=args.alpha,
            keep_unsupported=args.keep_unsupported,
            progress=lambda step: bar.update(),
        )
        calibration, history = carried.calibration, carried.history
        for step in carried.left_out:
            note(f"stableins: warning: {step.added[0][0]} {step.decision}: {step.reason}")
    else:
        calibration = calibrate()
        bar.update()
    bar.describe("calibrate device: the gyro stage")
    for fit in [f for f in (*calibration.passes, calibration.fine, calibration.fused) if f is not None]:
        for line in fit.notes:
            if line.startswith("warning:"):
                note(f"stableins: {fit.stage} stage: {line}")
    record = CalibrationRecord.from_device(
        calibration,
        site,
        replace(
            data_description(datasets),
            procedure=f"{coarse_procedure.name} + {fine_procedure.name}" if calibration.fine is not None else coarse_procedure.name,
            inputs=[str(p) for p in args.data],
        ),
        entries=parse_entries(args.set),
    )
    record, gyro = _gyro_stage(args, datasets, layouts, record, gyro_added, summaries=per_file)
    bar.update()
    bar.close()
    if history is not None:
        record = replace(record, discovery=history)  # the record's report below shows it
    text = calibration.report() + _gyro_text(gyro) + "\n\n== calibration record (what the certificate shows) ==\n" + record.report()
    _write_all_or_nothing(record, args.out, text, args.report)
    note(f"calibration record written to {args.out}" + (f", report to {args.report}" if args.report is not None else ""))
    steps = device_next_steps(args, record)
    result = {
        "record": str(args.out),
        "stages": ["coarse"] + (["fine"] if calibration.fine is not None else []),
        "coarse": _summary(calibration.coarse),
        "fine": None if calibration.fine is None else _summary(calibration.fine),
        "fused": None if calibration.fused is None else _summary(calibration.fused),
        "passes": len(calibration.passes),
        "discovery": None if history is None else history.to_json(),
        "noise_model": None if calibration.noise is None else calibration.noise.to_document(),
        "largest_floor": None if calibration.floor is None else _summary(calibration.floor),
        "gyro": None if gyro is None else gyro_document(gyro),
        "next": [line.strip() for line in steps if line.startswith("  ")],
    }
    emit(args, result, text if args.verbose else _summary_text(record, calibration.final, args))
    _last_lines(steps)
    return 0


def _summary_text(record, fit, args: argparse.Namespace) -> str:
    """Return what ``calibrate device`` prints by default: the record's summary, its fit's χ²_ν and where the full report is."""
    from stableins.records.display import summary

    lines = summary(record)
    lines.insert(2, f"{fit.stage} fit: χ²_ν = {fit.chi2_red:.3f} (ν = {fit.dof})")
    where = f"in {args.report}" if args.report is not None else "with --verbose (or --report FILE)"
    return "\n".join([*lines, f"the full report (every stage, the noise model, the gyro stage, the discovery history): {where}"])


def _read(paths: list[Path], layouts, bar) -> tuple[list, list, list]:
    """Return the device datasets of ``paths`` (one unit, one site), each file's dwells and all of them, telling ``bar`` each step."""
    from stableins.data.device import load_device
    from stableins.estimators.dwell import dwells_from_columns
    from stableins.estimators.setting import DeviceSetting

    datasets = []
    for path in paths:
        bar.describe(f"calibrate device: reading {path}")
        datasets.append(load_device(path))
        bar.update()
    _same_site(datasets)
    per_file = []
    for dataset in datasets:
        bar.describe(f"calibrate device: the dwells of {dataset.path}")
        setting = DeviceSetting.from_site(dataset.metadata)
        per_file.append(dwells_from_columns(dataset.columns, layouts=layouts, source=str(dataset.path), setting=setting))
        bar.update()
    return datasets, per_file, [s for found in per_file for s in found]


def _last_lines(steps: list[str]) -> None:
    """Say the next steps after the report (stdout flushed first): the next step is the last line, not scrolled away above it."""
    import sys

    from stableins.output import note

    sys.stdout.flush()
    for line in steps:
        note(line)


def _effect_ids(args: argparse.Namespace, coarse_procedure, fine_procedure) -> list[str]:
    """Return the effects to carry: the procedures' ``[model] add``, then ``--add`` (each once, tested in this order).

    A gyro g-sensitivity ``Dg_ab`` among them is not an accelerometer output: the gyro stage estimates it from the
    reading slopes (:func:`_gyro_stage`).
    """
    effect_ids = list(dict.fromkeys([*coarse_procedure.model_add, *fine_procedure.model_add]))
    return effect_ids + [e for e in args.add if e not in effect_ids]


def _gyro_text(gyro) -> str:
    """Return the gyro stage's report, as a paragraph of the console text ("" without the stage)."""
    from stableins.estimators.gyro_sensitivity import gyro_report

    return "" if gyro is None else "\n\n" + gyro_report(gyro)


def _gyro_stage(args: argparse.Namespace, datasets, layouts, record, added: list[str], *, summaries=None):
    """Return the record updated by the gyro stage on the same dwells, and the stage's fit (None when skipped, with a note).

    A Bayesian update of the device record: the twelve gyro numbers join from the reading slopes alone, nothing
    else moves (docs/device-calibration.md, "Gyro drift and g-sensitivity").  ``summaries``: each file's dwell
    summaries, already made for the device stages.
    """
    from stableins.errormodel import GIMBAL_IDS, GYRO_DRIFT_TERMS, GYRO_G_TERMS
    from stableins.errors import InputError, NotDeterminedError
    from stableins.estimators.gyro_sensitivity import gyro_from_datasets
    from stableins.output import note
    from stableins.records import RunInfo

    if args.no_gyro and not added:
        return record, None
    terms = GYRO_DRIFT_TERMS + tuple(t for t in GYRO_G_TERMS if not args.no_gyro or t.id in added)
    values = record.values()
    try:
        fit = gyro_from_datasets(datasets, layouts=layouts, zero_offsets=[values[g] for g in GIMBAL_IDS], terms=terms, summaries=summaries)
    except InputError:
        raise  # bad input is refused, not skipped
    except NotDeterminedError:
        raise  # a described error passes through as it is (issue 29)
    except ValueError as error:
        note(f"stableins: gyro stage skipped: {error}")
        return record, None
    for line in fit.notes:
        if line.startswith("warning:"):
            note(f"stableins: {fit.stage} stage: {line}")
    description = data_description(datasets)
    inputs = [str(p) for p in args.data]
    run = RunInfo(procedure=record.calibration.procedure, inputs=inputs, data_start=description.data_start, data_end=description.data_end)
    updated = record.updated(fit, run, site=datasets[0].metadata)
    return updated, fit


def gyro_document(fit) -> dict:
    """Return the gyro stage as JSON: each number in °/h or °/h/g with 1σ, the D_g = 0 test, the noise, the rank report."""
    from stableins.conventions import ARCSEC
    from stableins.estimators.gyro_sensitivity import GyroSensitivityDetails

    details = fit.details
    assert isinstance(details, GyroSensitivityDetails)
    return {
        "parameters": {
            t.id: {"value": float(v) / t.scale, "sigma": float(s) / t.scale, "unit": t.unit, "status": str(st)}
            for t, v, s, st in zip(fit.terms, fit.values, fit.sigma, fit.status, strict=True)
        },
        "g_sensitivity_test": {
            "statistic": details.statistic if details.test_dof else None,
            "dof": details.test_dof,
            "p_value": details.p_value if details.test_dof else None,
            "alpha": details.alpha,
            "flagged": details.flagged,
        },
        "angle_noise_arcsec": [n / ARCSEC for n in details.angle_noise],
        "chi2_red": details.chi2 / max(details.dof, 1),
        "dof": details.dof,
        "dwells_used": len(details.dwells_used),
        "rank": list(details.rank_report),
        "left_out": list(details.left_out),
        "dwell_mode": str(details.mode),
        "nuisance": {
            name: {"value": value, "sigma": sigma, "unit": "1" if name.startswith("torquer_") else "rad"}
            for name, value, sigma in details.nuisance
        },
        "gauge": details.gauge,
        "notes": list(fit.notes),
    }


def device_next_steps(args: argparse.Namespace, record) -> list[str]:
    """Return what to do next with a device-level record, as commands that run as written.

    First ask whether the model misses an effect (``stableins diagnose``); then the system stage on a static record
    taken with the INS compensating by it.
    """
    import shlex

    from stableins.commands.noise import noise_arguments

    command = ["stableins", "diagnose", *[str(p) for p in args.data], "--record", str(args.out), *noise_arguments(args)]
    return [
        "next: is the model missing an effect? (model discovery against this record)",
        f"  {shlex.join(command)}",
        f"then the system stage: one sidereal day on a static base with the INS compensating by {args.out} "
        f"('stableins run system-static --prior {shlex.quote(str(args.out))}' on the platform), then "
        f"'stableins calibrate system DAY.h5 --prior {shlex.quote(str(args.out))} --out calibration.json'",
    ]


def data_description(datasets) -> RunInfo:
    """Return the data start and end times (from each file's ``start_time`` and time column) and the instrument temperature they carry."""
    import numpy as np

    from stableins.records import RunInfo, data_times, temperature_summary  # noqa: F811 - at run time

    spans = [data_times(d.metadata, float(d.columns["time"][0]), float(d.columns["time"][-1])) for d in datasets if len(d.columns["time"])]
    starts = [a for a, _ in spans if a]
    ends = [b for _, b in spans if b]
    temperature = np.concatenate([np.asarray(d.columns["temperature"], dtype=float) for d in datasets])
    return RunInfo(data_start=min(starts, default=""), data_end=max(ends, default=""), environment=temperature_summary(temperature))


def _write_all_or_nothing(record, out: Path, text: str, report: Path | None) -> None:
    """Write the record and (optionally) the report, both or neither.

    Both go to temporary files first; they are renamed into place only when both are
    complete (report first, then record), so a report that cannot be written leaves no
    record behind (and an existing record untouched).
    """
    import contextlib

    from stableins.data.atomic import atomic_path
    from stableins.errors import InputError

    step = "record"
    try:
        with contextlib.ExitStack() as stack:
            record.save(stack.enter_context(atomic_path(out)))
            if report is not None:
                step = "report"
                stack.enter_context(atomic_path(report)).write_text(text + "\n", encoding="utf-8")
    except OSError as error:
        raise InputError(
            f"cannot write the {step}: {error.strerror or error}; nothing was written (no record, no report)",
            path=str(report if step == "report" else out),
            field="--report" if step == "report" else "--out",
            expected="a writable file path",
        ) from None


def _summary(fit) -> dict:
    return {
        "chi2_red": fit.chi2_red,
        "rank": fit.rank,
        "parameters": {
            i: {"value": None, "sigma": None, "status": st}
            if st == Status.UNIDENTIFIABLE
            else {"value": float(v), "sigma": float(s), "status": st}
            for i, v, s, st in zip(fit.ids, fit.values, fit.sigma, fit.status, strict=True)
        },
        "determined": list(fit.determined),
        "notes": list(fit.notes),
    }
