"""``stableins campaign CONFIG --out DIR [--workers N | --scheduler ADDRESS] [--no-plot] [--json]``.

A Monte Carlo campaign of full simulated calibrations (docs/campaigns.md): every task (seed × procedure × noise model ×
hidden effect) is simulated, calibrated and diagnosed through the library on Dask, a local cluster by default or an
existing scheduler; finished tasks are kept in ``DIR/tasks/``, so the same command resumes an interrupted campaign.
At the end ``DIR/results.csv`` (one row per task and parameter), ``DIR/summary.txt`` and ``DIR/summary.png``.
"""

from __future__ import annotations

import argparse
import time

from stableins.commands.arguments import input_file, integer, output_directory

_HELP = "Monte Carlo campaign of simulated calibrations on Dask (seeds × procedures × noise models × hidden effects)"


def scheduler_address(text: str) -> str:
    """Accept a Dask scheduler address ``tcp://HOST:PORT`` or ``tls://HOST:PORT`` (argparse type)."""
    from urllib.parse import urlsplit

    try:
        parts = urlsplit(text)
        port = parts.port
    except ValueError:
        port = None
        parts = urlsplit("")
    if parts.scheme not in ("tcp", "tls") or not parts.hostname or port is None or parts.path not in ("", "/"):
        raise argparse.ArgumentTypeError(f"{text[:80]!r} is not a scheduler address (expected tcp://HOST:PORT or tls://HOST:PORT)")
    return text


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the arguments of ``stableins campaign`` to ``parser``."""
    parser.description = _HELP
    parser.add_argument("config", metavar="CONFIG", type=input_file, help="campaign file (TOML, docs/campaigns.md)")
    parser.add_argument(
        "--out", type=output_directory, required=True, metavar="DIR", help="results directory (resumed when it holds the campaign)"
    )
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--workers", type=integer(1, 1024), metavar="N", help="local cluster of N worker processes (default: one per CPU)")
    where.add_argument(
        "--scheduler", type=scheduler_address, metavar="ADDRESS", help="an existing Dask scheduler, e.g. tcp://127.0.0.1:8786"
    )
    parser.add_argument("--no-plot", action="store_true", help="do not draw summary.png")
    parser.add_argument("--json", action="store_true", help="print the summary as JSON on stdout")


def run(args: argparse.Namespace) -> int:
    """Validate the campaign, run the tasks it lacks, write the table, the summary and the plot."""
    from stableins.campaign.config import load_campaign
    from stableins.campaign.execution import run_campaign
    from stableins.campaign.summary import write_outputs
    from stableins.output import emit
    from stableins.progress import Progress

    config = load_campaign(args.config)
    start = time.perf_counter()
    with Progress(total=len(config.tasks()), label="tasks") as bar:
        ran = run_campaign(config, args.out, scheduler=args.scheduler, workers=args.workers, progress=bar.set)
    elapsed = time.perf_counter() - start
    outputs = write_outputs(config, args.out, plot=not args.no_plot)
    head = (
        f"campaign {config.name}: {ran.total} tasks ({ran.resumed} found finished, {ran.ran} run now on {ran.workers} worker(s), "
        f"{ran.scheduler}) in {elapsed:.1f} s"
    )
    files = [str(outputs.table), str(outputs.summary)] + ([str(outputs.plot)] if outputs.plot else [])
    data = {
        "campaign": config.name,
        "tasks": ran.total,
        "resumed": ran.resumed,
        "ran": ran.ran,
        "workers": ran.workers,
        "seconds": elapsed,
        "files": files,
        "parameters": [{**s.__dict__, "efficiency": s.efficiency} for s in outputs.parameters],
        "rates": [{**r.__dict__, "rate": r.rate, "sigma": r.sigma} for r in outputs.rates],
    }
    emit(args, data, "\n".join([head, outputs.text, *[f"wrote {f}" for f in files]]))
    return 0
