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
