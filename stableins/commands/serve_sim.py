"""``stableins serve-sim --port N``: the simulated platform behind the TCP protocol (docs/protocol.md), on 127.0.0.1 only.

Prints ``listening on 127.0.0.1:PORT`` on stdout once it accepts connections (``--port 0``
picks a free port).  The platform keeps its state across client connections, like hardware.
"""

from __future__ import annotations

import argparse
import sys


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the arguments of ``stableins serve-sim`` to ``parser``."""
    from stableins.commands.arguments import input_file, integer, real, seed

    parser.add_argument("--port", type=integer(0, 65535), required=True, help="TCP port on 127.0.0.1 (0: any free port)")
    parser.add_argument("--seed", type=seed, help="seed of the simulated truth and noise (default 0, or the --truth file's)")
    parser.add_argument("--unit", help="serial number the simulated unit reports")
    parser.add_argument("--rate", type=real(0.0, 10000.0, above=True, unit="Hz"), help="sample rate [Hz] (default: the simulator's)")
    parser.add_argument(
        "--connections", type=integer(1, 10**9), help="stop after this many client connections (default: serve until interrupted)"
    )
    parser.add_argument(
        "--realtime",
        type=real(0.0, 1000.0),
        default=0.0,
        metavar="FACTOR",
        help="stream samples at FACTOR x real time (1: like hardware; 0: at once)",
    )
    parser.add_argument(
        "--installed",
        type=input_file,
        metavar="CAL.json",
        help="the calibration record the simulated INS navigates with (an operator loads a real INS so); "
        "the navigation outputs of a system-level record depend on it",
    )
    parser.add_argument("--truth", type=input_file, metavar="TRUTH.json", help="simulate this world (a truth.json) instead of drawing one")
    parser.add_argument("--quiet", action="store_true", help="do not log connections")


def run(args: argparse.Namespace) -> int:
    """Run ``stableins serve-sim``: serve a simulated platform over TCP on the loopback interface."""
    from stableins.drivers.select import simulated_platform
    from stableins.drivers.server import LOOPBACK, serve
    from stableins.errors import InputError

    if not 0 <= args.port < 65536:
        raise InputError(f"port {args.port}", field="--port", expected="0 to 65535")
    if args.truth is not None:
        from dataclasses import replace

        from stableins.data.truth import load_truth
        from stableins.drivers.select import SimulatedDriver

        truth = load_truth(args.truth)
        if args.rate:
            truth = truth.with_changes(site=replace(truth.site, sample_rate=float(args.rate)))
        driver = SimulatedDriver(truth, truth.seed if args.seed is None else args.seed)
    else:
        driver = simulated_platform(0 if args.seed is None else args.seed, args.unit, args.rate)
    if args.installed is not None:  # checked before the server listens
        from stableins.records import CalibrationRecord

        driver.install(CalibrationRecord.load(args.installed).values(), source=str(args.installed))

    def ready(port: int) -> None:
        print(f"listening on {LOOPBACK}:{port}", flush=True)

    def log(message: str) -> None:
        if not args.quiet:
            print(f"serve-sim: {message}", file=sys.stderr, flush=True)

    try:
        serve(driver, args.port, ready=ready, log=log, max_connections=args.connections, realtime=args.realtime)
    except OSError as error:
        raise InputError(f"cannot listen on {LOOPBACK}:{args.port}: {error.strerror}", field="--port") from None
    return 0
