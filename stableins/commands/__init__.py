"""CLI subcommands, one module each (``configure(parser)`` and ``run(args) -> int``); see :mod:`stableins.cli`."""

from __future__ import annotations

from pathlib import Path
from typing import Any


def run_data_file(run: str, name: str, *, missing: str, expected: str) -> Path:
    """Return ``RUN/name`` for a run directory, else RUN itself; a directory without it is an InputError.

    ``missing`` says what the directory lacks and ``expected`` what RUN should be, in the message.
    """
    from stableins.errors import InputError

    path = Path(run)
    if path.is_dir():
        path = path / name
        if not path.exists():
            raise InputError(missing, path=run, field=name, expected=expected)
    return path


def add_entries_option(parser: Any) -> None:
    """``--set KEY=VALUE`` (repeatable): an entry of the calibration, recorded in the record and printed on the certificate."""
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="an entry of the calibration (laboratory, customer, operator, location, lab_temperature=21.5 degC ...); repeatable",
    )


def add_new_calibration_option(parser: Any) -> None:
    """``--new-calibration``: a stage that updates a prior record starts a new calibration from it."""
    parser.add_argument(
        "--new-calibration",
        action="store_true",
        help="start a new calibration from the prior (a record in force) instead of continuing the prior's calibration",
    )


def check_same_unit(metadata: Any, prior: Any, prior_path: Any) -> None:
    """Raise InputError naming ``prior_path`` when a record's unit (its site metadata) is not the prior record's."""
    from stableins.errors import InputError

    if metadata.serial_number and prior.serial_number and metadata.serial_number != prior.serial_number:
        raise InputError(
            f"the record is of unit {metadata.serial_number!r} but the prior calibration of {prior.serial_number!r}",
            path=prior_path,
            field="serial_number",
            expected="a calibration of the same unit",
        )


def update_prior(
    args: Any, prior: Any, fit: Any, *, data: tuple[Any, Any, tuple[float, float]], procedure: str, sample_rate: float | None = None
) -> Any:
    """Write the prior record updated by a stage's fit to ``args.out`` (a Bayesian update) and return it.

    ``args`` carries ``prior`` (its path), ``out``, ``new_calibration`` and ``set`` (the calibration's entries);
    ``data`` is ``(source file, site metadata, (first, last) session time [s])`` of the stage's data; ``sample_rate``
    [Hz] defaults to the metadata's.
    """
    from stableins.records import PriorReference, RunInfo, data_times, file_sha256, parse_entries

    source, metadata, (first, last) = data
    start, end = data_times(metadata, float(first), float(last))
    reference = PriorReference(file_sha256(args.prior), str(args.prior), prior.calibration.created)
    rate = metadata.sample_rate if sample_rate is None else sample_rate
    run = RunInfo(procedure=procedure, inputs=[str(source)], data_start=start, data_end=end, sample_rate=rate)
    updated = prior.updated(
        fit, run, new_calibration=args.new_calibration, prior=reference, calibration_entries=parse_entries(args.set), site=metadata
    )
    updated.save(args.out)
    return updated
