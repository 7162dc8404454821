"""CLI subcommands, one module each (``configure(parser)`` and ``run(args) -> int``); see :mod:`stableins.cli`."""

from __future__ import annotations

from typing import Any


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
