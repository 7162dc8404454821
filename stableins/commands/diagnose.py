"""``stableins diagnose DATA --record CAL.json [--add ID ...]``: what is the error model missing.

::

    stableins diagnose session.h5 --record record.json
    stableins diagnose session.h5 --record record.json --add nonorth_12 --add Kcc_xxy --json
    stableins diagnose session.h5 --record record.json --plots figures/

Parses the arguments, reads the record and the data and hands them to
:func:`stableins.discovery.diagnose.diagnose_data`, which fits the standard model (with the zero offsets and any
discovery terms already in the record) to the device-level dwell means (fine stage when present, else coarse) or to
the bins of one system-level record (``--bin`` seconds; adds the residual spectra at the Earth-rate harmonics),
starting from the record, adds the effects given with ``--add`` one step at a time, and returns the residual
diagnostics, the ranking of every candidate effect not in the model and the history of steps (docs/discovery.md).
This command prints them, and the next step as a command that runs as written.

``--json`` prints one document (:class:`stableins.discovery.diagnose_report.DiagnoseReport`, keys in its module
docstring): ``chi2_red``, ``dof``, ``expected_spread``, ``stage``, ``model``, ``residual_rms`` / ``noise_floor``
[m/s², per axis], ``candidates`` (best first: ``id``, ``statistic``, ``p_value``, ``delta_bic``, ``predicted``,
``identifiable``, ``aliases`` ...), ``history``, ``next``, and ``drift``: the platform-drift candidates ``Dg_*``
ranked on the angle-reading slopes within dwells (:mod:`stableins.discovery.drift`).
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # pragma: no cover
    from matplotlib.figure import Figure

    from stableins.discovery.diagnose import NoiseOrigin
    from stableins.discovery.diagnose_report import NextStep


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the arguments of ``stableins diagnose``."""
    from stableins.commands.arguments import integer, output_directory, real

    parser.add_argument("data", nargs="+", type=Path, metavar="DATA", help="device-level data files or one system record (CSV or HDF5)")
    parser.add_argument(
        "--bin", type=real(1.0, 86400.0, unit="seconds"), default=60.0, metavar="S", help="system records: bin length [s] (default 60)"
    )
    parser.add_argument("--record", type=Path, required=True, metavar="CAL.json", help="calibration record to start from")
    parser.add_argument("--add", action="append", default=[], metavar="ID", help="add this effect and refit (repeatable, in order)")
    parser.add_argument("--stage", choices=("coarse", "fine"), help="which dwells to use (default: fine if present, else coarse)")
    parser.add_argument(
        "--alpha",
        type=real(0.0, 0.5, above=True),
        default=0.025,
        help="family-wise false-alarm level for flagging candidates, in (0, 0.5] (default 0.025: with the χ² verdict's 0.5 %%, "
        "a clean session raises an alarm 3 %% of the time)",
    )
    parser.add_argument("--top", type=integer(1, 10000), default=10, help="candidates to show in the text report (default 10)")
    parser.add_argument("--plots", type=output_directory, metavar="DIR", help="write residual and history plots (PNG) into DIR")
    from stableins.commands.noise import add_noise_options

    add_noise_options(parser)
    parser.add_argument(
        "--allow-gaps", action="store_true", help="system records: accept gaps in the time column (as 'stableins check --allow-gaps')"
    )


def run(args: argparse.Namespace) -> int:
    """Read the record and the data, diagnose them (:func:`stableins.discovery.diagnose.diagnose_data`), print the result."""
    from dataclasses import replace

    from stableins.commands.noise import given_noise
    from stableins.discovery.diagnose import DiagnoseOptions, DiagnoseStage, diagnose_data
    from stableins.output import emit, note
    from stableins.procedures.definition import device_layouts
    from stableins.records import CalibrationRecord

    options = DiagnoseOptions(add=tuple(args.add), stage=None if args.stage is None else DiagnoseStage(args.stage), alpha=args.alpha)
    record = CalibrationRecord.load(args.record)
    data, serial = _load(args.data, allow_gaps=args.allow_gaps)
    if record.serial_number != serial:
        note(f"warning: record {args.record} is for unit {record.serial_number}, data for {serial}")
    options = replace(options, noise=given_noise(args), bin_seconds=args.bin)
    result = diagnose_data(data, record, options=options, layouts=device_layouts(), record_name=str(args.record))
    report = result.report
    if result.system is None:
        if report.noise_model is not None:  # device dwells are always weighted with one
            note(f"noise ({_origin(args, result.noise_origin)}): {report.noise_model.describe()}")
        for line in report.left_out:
            note(f"left out: {line}")
        if result.drift is None:
            for line in result.drift_notes:
                note(f"drift analysis: {line}")
    if args.plots is not None:
        _write_plots(args.plots, result.figures())
    steps = diagnosis_next_steps(args, report.next_step)
    if args.json:
        for line in steps:
            note(line)
    emit(args, replace(report, next=tuple(steps)).to_json(), "\n\n".join([result.text(top=args.top), "\n".join(steps)]))
    return 0


def _load(paths: list[Path], *, allow_gaps: bool) -> tuple[Any, str]:
    """Return the device datasets, or the one system record validated as 'stableins check' does, and the serial number."""
    from stableins.data.format_tag import read_format_tag
    from stableins.data.validation import FORMAT_TAGS
    from stableins.errors import InputError
    from stableins.output import note

    system = [str(p) for p in paths if read_format_tag(p) == FORMAT_TAGS["system"]]
    if system and len(paths) > 1:
        raise InputError("give one system-level record alone, or device-level files", path=system[0], expected="DATA of one kind")
    if not system:
        from stableins.data.device import load_device

        datasets = [load_device(path) for path in paths]
        return datasets, datasets[0].metadata.serial_number
    import warnings

    from stableins.data.system import open_system_record

    opened = open_system_record(system[0])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        opened.validate(allow_gaps=allow_gaps)  # the validation 'stableins check' runs
    for w in caught:
        note(f"stableins: warning: {w.message}")
    return opened, opened.metadata.serial_number


def _origin(args: argparse.Namespace, origin: NoiseOrigin) -> str:
    """Where the device noise model comes from, in the words of this command's options."""
    from stableins.discovery.diagnose import NoiseOrigin

    return {
        NoiseOrigin.DATASHEET: "given on the command line (datasheet)",
        NoiseOrigin.GIVEN: f"the noise model of {args.noise}",
        NoiseOrigin.RECORD: "the record's noise model",
        NoiseOrigin.MEASURED: "measured in the dwells",
    }[origin]


def _write_plots(directory: Path, figures: dict[str, Figure]) -> None:
    """Write the figures of a diagnosis (:meth:`stableins.discovery.diagnose.DiagnoseResult.figures`) into ``directory`` as PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from stableins.output import note

    directory.mkdir(parents=True, exist_ok=True)
    for name, figure in figures.items():
        figure.savefig(directory / f"{name}.png", dpi=110)
        plt.close(figure)
    note(f"plots written to {directory}")


def diagnosis_next_steps(args: argparse.Namespace, step: NextStep) -> list[str]:
    """Word the next step of a diagnosis and give it as a command that runs as written.

    Carry the best flagged effect into the calibration, look at an effect a calibration cannot carry, say that the
    residual is outside the library (no certificate; the plots of the residuals), or certify the record when nothing is
    flagged (:attr:`stableins.discovery.diagnose_report.DiagnoseReport.next_step`).
    """
    import shlex

    from stableins.commands.noise import noise_arguments
    from stableins.discovery.diagnose_report import NextAction

    data = [str(p) for p in args.data]
    record_path = Path(args.record)
    if step.action is NextAction.OUTSIDE:
        plots = record_path.with_name(f"{record_path.stem}-residuals")
        command = ["stableins", "diagnose", *data, "--record", str(record_path), *noise_arguments(args), "--plots", str(plots)]
        return [
            f"next: outside the library: {step.reason}. No certificate until the cause is found: the signature above says "
            "which outputs, positions and harmonics carry the residual; see them:",
            f"  {shlex.join(command)}",
        ]
    if step.action is NextAction.CERTIFY or step.effect is None:
        certificate = record_path.with_name(f"{record_path.stem}-report.pdf")
        command = ["stableins", "report", str(record_path), "--data", *data, "--out", str(certificate)]
        floor = step.reason or "the model in force reaches the noise floor"
        return [
            f"next: nothing is flagged at α = {args.alpha:g}: {floor}; its certificate:",
            f"  {shlex.join(command)}",
        ]
    if step.action is NextAction.INSPECT:
        command = ["stableins", "diagnose", *data, "--record", str(record_path), *noise_arguments(args), "--add", step.effect]
        return [f"next: {step.effect} is flagged ({step.reason}); see it in the model and what it changes:", f"  {shlex.join(command)}"]
    out = record_path.with_name(f"{record_path.stem}-{step.effect}.json")
    command = ["stableins", "calibrate", "device", *data, *noise_arguments(args)]
    command += [item for effect in (*step.keep, step.effect) for item in ("--add", effect)] + ["--out", str(out)]
    group = " or ".join((step.effect, *step.confused_with))
    confused = f"; {group}: these data cannot tell them apart, the ranking names positions that separate them" if step.confused_with else ""
    return [
        f"next: carry {step.effect} into the calibration (it is tested again there and kept only if the data show it{confused}):",
        f"  {shlex.join(command)}",
    ]
