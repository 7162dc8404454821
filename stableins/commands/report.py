"""``stableins report RECORD.json [--data ...] [--previous OLD.json] [--procedure PROC.toml] --out REPORT.pdf``.

Writes the PDF calibration report of a calibration record (see ``docs/reports.md``).
Heavy imports (reportlab, matplotlib, numpy) happen inside :func:`run`.
"""

from __future__ import annotations

import argparse
import sys

HELP = "write the PDF calibration report of a calibration record"


def configure(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        "Write the calibration report (ISO/IEC 17025 7.8) of a calibration record: identification, results with expanded "
        "uncertainty, evidence that the model fits, change since the previous calibration and conformity."
    )
    parser.add_argument("record", metavar="RECORD.json", help="calibration record written by stableins")
    parser.add_argument(
        "--data", nargs="+", default=[], metavar="FILE", help="data files of the calibration (SHA-256 checked against the record)"
    )
    parser.add_argument("--previous", metavar="OLD.json", help="previous calibration record of the unit (change and its significance)")
    parser.add_argument(
        "--procedure", metavar="PROC.toml", help="procedure definition whose [tolerances] table gives the conformity limits"
    )
    parser.add_argument("--report-id", help="report id to print (default: derived from the serial number, date and input digests)")
    parser.add_argument("--out", required=True, metavar="REPORT.pdf", help="PDF to write (written atomically)")


def run(args: argparse.Namespace) -> int:
    from stableins.data.errors import InputError

    try:
        from stableins.reporting.builder import write_report

        summary = write_report(
            args.out, args.record, data=args.data, previous=args.previous, procedure=args.procedure, report_id=args.report_id
        )
    except InputError as error:
        print(f"stableins report: {error.describe()}", file=sys.stderr)
        return InputError.exit_status
    print(f"{summary.path}: report {summary.report_id}, {summary.pages} pages, conformity: {summary.verdict}")
    return 0


def main(argv: list[str] | None = None) -> int:
    """Run the command on its own (until it is registered in stableins/cli.py)."""
    parser = argparse.ArgumentParser(prog="stableins report")
    configure(parser)
    return run(parser.parse_args(argv))


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
