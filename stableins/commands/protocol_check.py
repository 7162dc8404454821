"""``stableins protocol-check tcp://HOST:PORT --envelope DEG``: conformance of a platform controller to docs/protocol.md.

::

    stableins serve-sim --port 5025 &
    stableins protocol-check tcp://127.0.0.1:5025 --envelope 2

Exercises every clause of the protocol over a raw connection (:mod:`stableins.drivers.conformance`) and prints one
line per clause: ``PASS``, ``FAIL`` with what was received, or ``N/A`` (the navigation stream of a platform whose
greeting does not state ``NAV``).  The gimbals are commanded only within ``--envelope`` degrees of where they are
found (half of it about the inner axis) and back.  Exit status: 0 every clause passed, 1 a clause failed, 2 bad input.
"""

from __future__ import annotations

import argparse
import math


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the arguments of ``stableins protocol-check`` to ``parser``."""
    from stableins.commands.arguments import real

    parser.add_argument("address", metavar="tcp://HOST:PORT", help="the controller to check")
    parser.add_argument(
        "--envelope",
        type=real(0.0, 90.0, above=True, unit="degrees"),
        required=True,
        metavar="DEG",
        help="the gimbals move at most this far from where they are found [deg] (half of it about the inner axis, then back)",
    )
    parser.add_argument("--timeout", type=real(0.1, 3600.0, unit="seconds"), default=10.0, help="longest silence accepted [s] (default 10)")
    parser.add_argument(
        "--duration", type=real(0.05, 60.0, unit="seconds"), default=0.5, help="length of the test acquisitions [s] (default 0.5)"
    )


def run(args: argparse.Namespace) -> int:
    """Run ``stableins protocol-check``: print the conformance report; 0 when every clause passes, else 1."""
    from stableins.drivers.conformance import CLAUSES, ConformanceCheck
    from stableins.drivers.tcp import parse_address
    from stableins.output import emit

    host, port = parse_address(args.address)
    check = ConformanceCheck(host, port, envelope=math.radians(args.envelope), timeout=args.timeout, duration=args.duration)
    results = check.run()
    failed = [r.clause for r in results if r.passed is False]
    lines = [f"conformance of {args.address} to docs/protocol.md ({len(CLAUSES)} clauses):"]
    lines += [f"  {r.describe()}" for r in results]
    verdict = f"DOES NOT CONFORM: failed {', '.join(failed)}" if failed else "CONFORMS: every clause passed"
    lines.append(verdict)
    data = {
        "address": args.address,
        "conforms": not failed,
        "clauses": [{"clause": r.clause, "passed": r.passed, "detail": r.detail} for r in results],
    }
    emit(args, data, "\n".join(lines))
    return 0 if not failed else 1
