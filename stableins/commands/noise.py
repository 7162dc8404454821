"""``stableins noise DATA...``: measure the instrument's noise model (Allan analysis) and write it into a record.

::

    stableins noise sim/system.h5 --plot allan.png                      # a static record (a day on the base)
    stableins noise sim/device-fine.h5 --record cal.json --out cal2.json  # the dwells of a device session
    stableins noise static.h5 --json

A system-level record is a static record: the platform turns only at the Earth rate, and
the slowly turning gravity signal (with the instrument's scale factors, misalignments and
quadratic terms) is removed by a least-squares fit on the nominal ``f^p`` before the Allan
analysis.  Device files give their usable dwells (after settling) as segments.  The command
prints every term per axis with its confidence interval, plots the Allan deviation with the
fitted model and its bounds (``--plot``), and writes the model into a copy of a calibration
record (``--record CAL.json --out CAL2.json``, atomically) for later stages
(``stableins calibrate device --noise CAL2.json``, ``diagnose``, ``recal``).  docs/noise.md.

This module also holds the noise options shared by ``calibrate device`` and ``diagnose``.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

#: Block length [s] of the block means that carry the long averaging times.
BLOCK_SECONDS = 1.0


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the arguments of ``stableins noise`` to ``parser``."""
    parser.add_argument("data", nargs="+", type=Path, metavar="DATA", help="a static (system-level) record, or device-level files")
    from stableins.commands.arguments import input_file, output_file, png_file, real

    parser.add_argument("--record", type=input_file, metavar="CAL.json", help="calibration record to copy with the measured noise model")
    parser.add_argument(
        "--out", type=output_file, metavar="CAL2.json", help="where to write the record with the noise model (needs --record)"
    )
    parser.add_argument("--plot", type=png_file, metavar="PNG", help="plot the Allan deviation with the fitted model and its bounds")
    parser.add_argument(
        "--confidence", type=real(0.5, 1.0, above=True), default=0.95, help="confidence level of the intervals (default 0.95)"
    )


# ----------------------------------------------------------------------------- shared options
def add_noise_options(parser: argparse.ArgumentParser) -> None:
    """``--noise CAL.json``, ``--bias-instability UG``, ``--random-walk K`` (calibrate device and system, diagnose)."""
    from stableins.commands.arguments import input_file, real

    parser.add_argument(
        "--noise",
        type=input_file,
        metavar="CAL.json",
        help="use the noise model of this calibration record (measured with 'stableins noise'); docs/noise.md",
    )
    parser.add_argument(
        "--bias-instability",
        type=real(0.0, 1e5, unit="µg"),
        metavar="UG",
        help="instrument bias instability B [ug] (Allan floor 0.664 B) from a datasheet; white noise is measured in the dwells",
    )
    parser.add_argument(
        "--random-walk",
        type=real(0.0, 1.0, unit="m/s^2/sqrt(s)"),
        metavar="K",
        help="acceleration random walk K [m/s^2/sqrt(s)] from a datasheet",
    )


def noise_arguments(args: argparse.Namespace) -> list[str]:
    """Return the noise options of :func:`add_noise_options` this command was given, to pass on to the next command it suggests."""
    out = []
    if getattr(args, "noise", None) is not None:
        out += ["--noise", str(args.noise)]
    if getattr(args, "bias_instability", None) is not None:
        out += ["--bias-instability", f"{args.bias_instability:g}"]
    if getattr(args, "random_walk", None) is not None:
        out += ["--random-walk", f"{args.random_walk:g}"]
    return out


#: The provenance of a noise model made from the datasheet flags.
COMMAND_LINE = "bias instability and random walk given on the command line"


def _datasheet_given(args: argparse.Namespace) -> bool:
    """Whether datasheet flags were given (InputError when ``--noise`` was given too)."""
    from stableins.errors import InputError

    given = args.bias_instability is not None or args.random_walk is not None
    if given and args.noise is not None:
        raise InputError("give either --noise CAL.json or --bias-instability/--random-walk, not both", field="--noise")
    return given


def given_noise(args: argparse.Namespace):
    """Return the noise the options give, for :class:`stableins.discovery.diagnose.DiagnoseOptions`.

    ``--noise CAL.json``: that record's model; the datasheet flags: their slow noise in SI; neither: None (the
    calibration record's model, else measured in the data).
    """
    from stableins.conventions import MICRO_G
    from stableins.discovery.diagnose import SlowNoiseGiven

    if _datasheet_given(args):  # ranges checked when parsed
        return SlowNoiseGiven((args.bias_instability or 0.0) * MICRO_G, args.random_walk or 0.0, provenance=COMMAND_LINE)
    return None if args.noise is None else record_noise(args.noise)


def noise_from_options(args: argparse.Namespace, dwells, default=None):
    """Return the noise model the options ask for: a datasheet (flags), a record's (``--noise``), ``default``, or None (measure it).

    Returns ``(model or None, text saying where it comes from)``.
    """
    from stableins.conventions import MICRO_G

    given = _datasheet_given(args)
    if given:  # ranges checked when parsed
        from stableins.estimators.device import with_given_slow_noise

        model = with_given_slow_noise(
            dwells,
            (args.bias_instability or 0.0) * MICRO_G,
            args.random_walk or 0.0,
            COMMAND_LINE,
        )
        return model, "given on the command line (datasheet)"
    if args.noise is not None:
        return record_noise(args.noise), f"the noise model of {args.noise}"
    if default is not None:
        return default, "the record's noise model"
    return None, "measured in the dwells"


def system_noise_prior(args: argparse.Namespace, default=None):
    """Return the noise model a system-level record starts from (``calibrate system``, ``diagnose`` on a system record).

    Datasheet flags: the bias instability and random walk as given (the system stage measures the white noise in the
    record); ``--noise CAL.json``: that record's model; else ``default`` (the calibration record's), or None (the stage
    decides from the record alone).  Returns ``(model or None, text saying where it comes from)``.
    """
    from stableins.conventions import MICRO_G
    from stableins.noise import NoiseModel

    given = _datasheet_given(args)
    if given:
        model = NoiseModel.given(
            0.0,
            (args.bias_instability or 0.0) * MICRO_G,
            args.random_walk or 0.0,
            provenance=COMMAND_LINE,
        )
        return model, "given on the command line (datasheet)"
    if args.noise is not None:
        return record_noise(args.noise), f"the noise model of {args.noise}"
    if default is not None:
        return default, "the calibration record's noise model"
    return None, "measured in the record"


def record_noise(path: Path):
    """Return the ``noise_model`` section of a calibration record (InputError when it has none)."""
    from stableins.errors import InputError
    from stableins.records import CalibrationRecord

    record = CalibrationRecord.load(path)
    if record.noise_model is None:
        raise InputError(
            "the record carries no noise model", path=path, field="noise_model", expected="a record written by 'stableins noise ... --out'"
        )
    return record.noise_model


# ----------------------------------------------------------------------------- measuring
def static_record_points(record) -> tuple[Any, str]:
    """Allan points of a system-level (static) record with the slowly turning gravity signal removed.

    Two passes over the record in chunks (bounded memory).  The first sums 1-s blocks; the signal is
    the least-squares fit, per axis, of ``1, f^p_i, f^p_i f^p_j`` to the block means (nominal ``f^p`` from
    the angle readings): bias, scale factor, misalignment and quadratic terms, whatever their values.
    The block means of the residual carry the long averaging times.  The second pass removes the signal
    from every sample and accumulates the overlapping Allan variance of the whole record at the short
    ones (:class:`stableins.estimators.streaming_allan.StreamingAllan`; a gap in the time column ends a
    segment).
    """
    import numpy as np

    from stableins.conventions import GimbalConfiguration, dcm_nav_to_body
    from stableins.estimators.allan import allan_points, merge_points
    from stableins.estimators.streaming_allan import StreamingAllan, octave_clusters
    from stableins.platform import platform_specific_force

    site = record.metadata
    configuration = GimbalConfiguration(tuple(site.gimbal_senses))
    base = dcm_nav_to_body(*site.base_attitude)

    def regressors(readings):
        f_p = platform_specific_force(readings, site.gravity, base_dcm=base, configuration=configuration)
        u = f_p / site.gravity
        cols = [np.ones(u.shape[0])] + [u[:, i] for i in range(3)] + [u[:, i] * u[:, j] for i in range(3) for j in range(i, 3)]
        return np.stack(cols, axis=-1)

    keys, table, rate = _static_blocks(record)
    full = table[:, 0] >= 0.5 * np.median(table[:, 0])
    contiguous = np.flatnonzero(full)
    table = table[full]
    means_f = table[:, 1:4] / table[:, :1]
    means_r = table[:, 4:7] / table[:, :1]
    x_blocks = regressors(means_r)
    coefficients, *_ = np.linalg.lstsq(x_blocks, means_f, rcond=None)
    residual_blocks = means_f - x_blocks @ coefficients
    # block means of a gap-free stretch only (a missing block would join two windows across a gap)
    breaks = np.flatnonzero(np.diff(keys[contiguous]) != 1) + 1
    segments = np.split(residual_blocks, breaks)
    span = (int(keys[-1]) + 1) * BLOCK_SECONDS
    # short averaging times: every sample, up to the block length (the block means take over from 2 blocks on)
    short = StreamingAllan(octave_clusters(int(4 * BLOCK_SECONDS * rate), max_fraction=1), rate)
    samples = 0
    previous = None
    for chunk in record.iter_chunks(("time", "f_x", "f_y", "f_z", "angle_platform", "angle_inner", "angle_middle")):
        t = np.asarray(chunk["time"], dtype=float)
        if t.size == 0:
            continue
        f = np.stack([np.asarray(chunk[k], dtype=float) for k in ("f_x", "f_y", "f_z")], axis=-1)
        r = np.stack([np.asarray(chunk[f"angle_{g}"], dtype=float) for g in ("platform", "inner", "middle")], axis=-1)
        residual = f - regressors(r) @ coefficients
        steps = np.diff(np.r_[t[0] if previous is None else previous, t])
        for k, piece in enumerate(np.split(residual, np.flatnonzero(steps > 1.5 / rate))):  # a gap before each piece but the first
            if k:
                short.gap()
            short.add(piece)
        samples += t.size
        previous = t[-1]
    long = allan_points(segments, 1.0 / BLOCK_SECONDS, max_fraction=8)
    text = (
        f"{record.path}: {span / 3600:.2f} h static record at {rate:g} Hz; gravity signal (1, f^p, f^p f^p per axis) removed; "
        f"all {samples} samples at full rate for the short averaging times, {len(residual_blocks)} block means of {BLOCK_SECONDS:g} s"
    )
    return merge_points(short.points(), long, BLOCK_SECONDS * 2), text


def _static_blocks(record) -> tuple[Any, Any, float]:
    """Read a static record once, in chunks: its sums over blocks.

    Returns the block numbers (:data:`BLOCK_SECONDS` since the first sample), the per-block
    ``(count, Σf, Σangles)`` table (a block split across two chunks is summed) and the sample rate.
    """
    import numpy as np

    block_index: list[Any] = []
    block_rows: list[Any] = []
    t0 = None
    rate = None
    for chunk in record.iter_chunks(("time", "f_x", "f_y", "f_z", "angle_platform", "angle_inner", "angle_middle")):
        t = np.asarray(chunk["time"], dtype=float)
        if t.size == 0:
            continue
        if t0 is None:
            t0 = t[0]
        if rate is None and t.size > 1:
            rate = 1.0 / float(np.median(np.diff(t)))
        f = np.stack([np.asarray(chunk[k], dtype=float) for k in ("f_x", "f_y", "f_z")], axis=-1)
        r = np.stack([np.asarray(chunk[f"angle_{g}"], dtype=float) for g in ("platform", "inner", "middle")], axis=-1)
        b = np.floor((t - t0) / BLOCK_SECONDS).astype(np.int64)
        keys, inverse = np.unique(b, return_inverse=True)
        sums = np.zeros((keys.size, 7))
        np.add.at(sums, inverse, np.column_stack([np.ones(t.size), f, r]))
        block_index.append(keys)
        block_rows.append(sums)
    if rate is None or not block_index:
        from stableins.errors import InputError

        raise InputError("too few samples for an Allan analysis", path=str(record.path))
    all_keys = np.concatenate(block_index)
    keys, inverse = np.unique(all_keys, return_inverse=True)  # a block split across two chunks is summed
    table = np.zeros((keys.size, 7))
    np.add.at(table, inverse, np.vstack(block_rows))
    return keys, table, rate


def device_segments(datasets) -> tuple[list, list, float, str]:
    """Usable dwells of device files: their summaries, their samples after settling, the sample rate of the longest, a description."""
    import numpy as np

    from stableins.estimators.dwell import dwells_from_columns
    from stableins.estimators.setting import DeviceSetting
    from stableins.procedures.definition import device_layouts

    layouts = device_layouts()
    summaries, segments = [], []
    for ds in datasets:
        setting = DeviceSetting.from_site(ds.metadata)
        stats = {
            (s.stage, s.pass_number, s.position): s
            for s in dwells_from_columns(ds.columns, layouts=layouts, source=str(ds.path), setting=setting)
        }
        for d in ds.dwells():
            s = stats[(d.stage, d.pass_number, d.position)]
            if not s.usable:
                continue
            layout = layouts.get(d.stage)
            settle = layout.settle(d.position) if layout is not None and d.position in layout.positions else 0.0
            use = np.asarray(d.time_since_command) >= settle
            summaries.append(s)
            segments.append(np.asarray(d.specific_force)[use])
    if not summaries:
        from stableins.errors import InputError

        raise InputError("no usable dwells in the device files", path=str(datasets[0].path), expected="device-level dwells")
    longest = max(summaries, key=lambda s: s.duration)
    rate = longest.rate
    chosen = [seg for s, seg in zip(summaries, segments, strict=True) if abs(s.rate - rate) <= 1e-3 * rate]
    text = (
        f"{len(summaries)} usable dwells of {', '.join(str(d.path) for d in datasets)} (Allan points from the {len(chosen)} at {rate:g} Hz)"
    )
    return summaries, chosen, rate, text


def run(args: argparse.Namespace) -> int:
    """Run ``stableins noise``: measure the noise model (Allan analysis) and write it into a record; return the exit code."""
    from dataclasses import replace

    from stableins.errors import InputError
    from stableins.output import emit, note

    if not 0.5 < args.confidence < 1.0:
        raise InputError("must lie between 0.5 and 1", field="--confidence", expected="a confidence level such as 0.95")
    if args.out is not None and args.record is None:
        raise InputError("--out writes a copy of a calibration record with the noise model: give --record too", field="--out")
    record = None
    if args.record is not None:
        from stableins.records import CalibrationRecord

        record = CalibrationRecord.load(args.record)
    serial, model, points = _measure(args)
    if record is not None and record.serial_number != serial:  # one truth per unit: never another unit's noise model
        raise InputError(
            f"the record is of unit {record.serial_number!r}, the data of {serial!r}",
            path=str(args.record),
            field="serial_number",
            expected=f"the record of unit {serial!r}",
        )
    text = model.report()
    if args.plot is not None:
        _plot(args.plot, points, model, serial)
    if args.out is not None and record is not None:  # --out requires --record (checked above)
        updated = replace(
            record,
            noise_model=model,
            notes=record.notes + (f"noise model measured by 'stableins noise' from {', '.join(str(p) for p in args.data)}",),
        )
        try:
            updated.save(args.out)
        except OSError as error:
            raise InputError(f"cannot write the record: {error.strerror or error}", path=str(args.out), field="--out") from None
        note(f"record with the noise model written to {args.out}")
    result = {
        "noise_model": model.to_document(),
        "allan": {
            "tau": points.tau,
            "deviation": points.variance**0.5,
            "edf": points.edf,
            "model": model.allan_deviation(points.tau),
            "unit": "m/s^2",
        },
        "record": None if args.out is None else str(args.out),
    }
    emit(args, result, text)
    return 0


def _measure(args: argparse.Namespace) -> tuple[str, Any, Any]:
    """Measure the noise model of DATA: ``(serial number, noise model, Allan points)``.

    One static (system-level) record gives its Allan points fitted by :func:`~stableins.estimators.allan.fit_allan`;
    device-level files give the noise model of their usable dwells.
    """
    from stableins.data.format_tag import read_format_tag
    from stableins.data.validation import FORMAT_TAGS
    from stableins.errors import InputError
    from stableins.estimators.allan import allan_points, fit_allan, points_for_model
    from stableins.noise import NoiseSource

    system = [p for p in args.data if read_format_tag(p) == FORMAT_TAGS["system"]]
    if system and len(args.data) > 1:
        raise InputError("give one static (system-level) record alone, or device-level files", path=system[0], expected="DATA of one kind")
    if system:
        from stableins.data.system import open_system_record
        from stableins.progress import CountedSource, Progress

        opened = open_system_record(system[0])
        opened.validate(allow_gaps=True)  # what check runs (time order, rate, derived datasets); a gap ends an Allan segment
        with Progress(total=2 * opened.n_samples, label="Allan deviation: two passes over the record") as bar:
            points, described = static_record_points(CountedSource(opened, bar))
        model, points = fit_allan(points, source=NoiseSource.STATIC_RECORD, provenance=described, confidence=args.confidence)
        return opened.metadata.serial_number, model, points
    from stableins.data.device import load_device
    from stableins.estimators.device import noise_from_dwells

    datasets = [load_device(p) for p in args.data]
    summaries, segments, rate, described = device_segments(datasets)
    model = noise_from_dwells(summaries, confidence=args.confidence, source=", ".join(str(p) for p in args.data))
    return datasets[0].metadata.serial_number, model, points_for_model(allan_points(segments, rate), model)


def _plot(target: Any, points: Any, model: Any, serial: str) -> None:
    """Write the Allan deviation plot (PNG, atomically); InputError naming ``--plot`` when it cannot be written."""
    from stableins.data.atomic import atomic_path
    from stableins.errors import InputError
    from stableins.estimators.allan import plot_allan
    from stableins.output import note

    figure = plot_allan(points, model, title=f"{serial}: Allan deviation ({model.source.value})")
    try:
        with atomic_path(target) as path:
            figure.savefig(path, dpi=110, format="png")
    except OSError as error:
        raise InputError(f"cannot write the plot: {error.strerror or error}", path=str(target), field="--plot") from None
    note(f"Allan deviation plot written to {target}")
