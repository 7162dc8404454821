"""``stableins report RECORD.json [--data ...] [--previous OLD.json] [--procedure PROC.toml] --out REPORT.pdf``.

Writes the PDF calibration report of a calibration record (see ``docs/reports.md``).
Heavy imports (reportlab, matplotlib, numpy) happen inside :func:`run`.
"""

from __future__ import annotations

import argparse

_HELP = "write the PDF calibration report of a calibration record"


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the arguments of ``stableins report`` to ``parser``."""
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
        "--procedure",
        metavar="PROCEDURE",
        help="procedure (a shipped definition's name, e.g. system-static, or a TOML file) whose [tolerances] table gives the limits",
    )
    parser.add_argument("--discovery", metavar="DIAG.json", help="output of 'stableins diagnose --json' (model-discovery section)")
    parser.add_argument("--report-id", help="report id to print (default: derived from the serial number, date and input digests)")
    from stableins.commands.arguments import output_file

    parser.add_argument(
        "--out", required=True, type=output_file, metavar="REPORT.pdf", help="certificate to write (at most 3 pages; written atomically)"
    )
    parser.add_argument(
        "--technical",
        type=output_file,
        metavar="TECHNICAL.pdf",
        help="technical report the certificate names by its SHA-256 (default: REPORT-technical.pdf beside the certificate)",
    )
    who = {"laboratory": "the calibration laboratory", "customer": "the customer", "operator": "the person who performed it"}
    for key, text in who.items():
        parser.add_argument(f"--{key}", metavar="NAME", help=f"{text} (else the record's entry; without all three: a DRAFT)")
    parser.add_argument("--sign", metavar="KEY.pem", help="sign the certificate (PAdES; needs the 'sign' extra, pyHanko) with this PEM key")
    parser.add_argument("--sign-cert", metavar="CERT.pem", help="the signing key's X.509 certificate (default: in KEY.pem)")
    parser.add_argument(
        "--no-statement",
        action="store_true",
        help="make no statement of conformity (by default the tolerances of the calibration's procedure decide PASS or FAIL)",
    )


def run(args: argparse.Namespace) -> int:
    """Write the report; an :class:`~stableins.errors.InputError` reaches the CLI (message, exit status 2)."""
    from stableins.output import emit
    from stableins.progress import Progress
    from stableins.reporting.builder import ReportSettings, write_report

    with Progress(label="certificate and technical report: sections laid out") as bar:
        summary = write_report(
            args.out,
            args.record,
            data=args.data,
            previous=args.previous,
            procedure=args.procedure,
            discovery=args.discovery,
            settings=ReportSettings(
                report_id=args.report_id,
                laboratory=args.laboratory,
                customer=args.customer,
                operator=args.operator,
                no_statement=args.no_statement,
                sign_key=args.sign,
                sign_certificate=args.sign_cert,
                progress=bar.set,
            ),
            technical=args.technical,
        )
    data = {
        "path": summary.path,
        "report_id": summary.report_id,
        "pages": summary.pages,
        "verdict": summary.verdict,
        "sha256": summary.sha256,
        "technical_report": {"path": summary.technical, "pages": summary.technical_pages, "sha256": summary.technical_sha256},
        "draft": list(summary.missing),
    }
    data["conformity"] = list(summary.conformity)
    text = [f"{summary.path}: certificate {summary.report_id}, {summary.pages} pages, conformity: {summary.verdict}"]
    text += [f"  {line}" for line in summary.conformity if summary.verdict != "NO STATEMENT"]
    text.append(f"{summary.technical}: technical report, {summary.technical_pages} pages, SHA-256 {summary.technical_sha256}")
    if summary.missing:
        flags = " ".join(f"--{k} NAME" for k in summary.missing)
        text.append(f"DRAFT: {', '.join(summary.missing)} not stated; next: the same command with {flags}")
    elif args.sign is None:
        text.append(f"next: sign it (the same command with --sign KEY.pem), then: stableins check {summary.path}")
    else:
        text.append(f"signed; next: stableins check {summary.path} (signature and the SHA-256 of every input it names)")
    emit(args, data, "\n".join(text))
    return 0
