"""``stableins demo --out DIR``: simulate a platform and write everything to a directory.

For now: a device-level session (coarse and fine procedures) and a system-level record
from one drawn truth, plus ``truth.json``; later stages add calibration, discovery and
reports to the same directory.
"""

from __future__ import annotations

import argparse
from pathlib import Path


def configure(parser: argparse.ArgumentParser) -> None:
    from stableins.commands.simulate import parse_duration

    parser.add_argument("--out", type=Path, default=Path("demo-output"), metavar="DIR", help="output directory (default demo-output)")
    parser.add_argument("--seed", type=int, default=2018, help="random seed (default 2018)")
    parser.add_argument("--duration", type=parse_duration, default=2 * 3600.0, help="length of the system-level record (default 2h)")


def run(args: argparse.Namespace) -> int:
    from stableins.commands.simulate import build_truth, levels, prepare_directory, simulate_device, simulate_system
    from stableins.output import emit

    out = prepare_directory(args.out)
    options = argparse.Namespace(
        truth=None, hidden=[], seed=args.seed, rate=None, format=None, procedure=None, dwell=None, settle=None, duration=args.duration
    )
    truth = build_truth(options)
    truth.write(out / "truth.json")
    files = simulate_device(truth, out, args.seed, options)
    if "system" in levels():
        files.append(simulate_system(truth, out, args.seed, options))
    lines = [f"{f['path']}: {f['rows']} rows" for f in files] + [f"truth: {out / 'truth.json'}"]
    emit(args, {"out": str(out), "files": files, "truth": str(out / "truth.json")}, "\n".join(lines))
    return 0
