"""Run journal: cost of durability, and the time a resume takes to read and replay a journal.

Prints
- append rate of a 10 s dwell piece at 100 Hz (1000 samples, ~64 kB) with write + fsync, against the
  rate the data arrive (one piece per 10 s): the fraction of real time spent making data durable;
- scan rate (headers and CRC of every record: what a resume reads first), in MB/s;
- a whole device-level run of 18 positions on the simulated platform, live and resumed from its
  complete journal (replay with every operation re-simulated and compared), in seconds.
"""

from __future__ import annotations

import math
import tempfile
import time
from pathlib import Path

import numpy as np

from stableins.procedures.journal import Journal, scan
from stableins.procedures.plan import Checks, DwellStep, Plan
from stableins.procedures.rundir import resume_run, start_run
from stableins.procedures.runner import Console


def append_rate(directory: Path, pieces: int = 200) -> tuple[float, float]:
    rng = np.random.default_rng(0)
    block = {
        "time": np.arange(1000) / 100.0,
        "specific_force": rng.normal(size=(1000, 3)),
        "angles": rng.normal(size=(1000, 3)),
        "temperature": np.full(1000, 25.0),
    }
    path = directory / "journal.bin"
    with Journal.create(path) as journal:
        start = time.perf_counter()
        for k in range(pieces):
            journal.append("op", {"operation": "acquire", "arguments": [10.0], "step": k}, block)
        elapsed = time.perf_counter() - start
    return pieces / elapsed, path.stat().st_size / elapsed / 1e6


def scan_rate(directory: Path) -> float:
    path = directory / "journal.bin"
    start = time.perf_counter()
    records = scan(path).records
    elapsed = time.perf_counter() - start
    assert records
    return path.stat().st_size / elapsed / 1e6


def device_run(directory: Path) -> tuple[float, float, int]:
    positions = [(0.0, 0.0, 0.0), (0.0, math.pi / 2, 0.0), (math.pi / 2, math.pi / 2, 0.0)] * 6
    checks = Checks(angle_tolerance=math.radians(0.01), scatter_max=2e-2, slope_max=2e-4)
    steps = tuple(DwellStep(f"position {k}", "coarse", 1, k, p, 5.0, 20.0, checks) for k, p in enumerate(positions, start=1))
    plan = Plan("bench", "device", steps, retries=2, chunk=10.0, sample_rate=100.0)
    start = time.perf_counter()
    start_run(plan, directory / "run", driver_spec="sim", seed=1, unit="BENCH", console=Console(yes=True, quiet=True))
    live = time.perf_counter() - start
    start = time.perf_counter()
    outcome = resume_run(directory / "run", console=Console(yes=True, quiet=True), re_estimate=True)
    return live, time.perf_counter() - start, outcome.replayed


def main() -> None:
    with tempfile.TemporaryDirectory() as name:
        directory = Path(name)
        rate, throughput = append_rate(directory)
        print(f"journal append (1000-sample piece, write + fsync): {rate:.0f} pieces/s, {throughput:.1f} MB/s")
        print(f"  data arrive at 0.1 piece/s (10 s pieces at 100 Hz): durability costs {0.1 / rate * 100:.3f} % of real time")
        print(f"journal scan on resume (headers + CRC): {scan_rate(directory):.0f} MB/s")
        live, resumed, replayed = device_run(directory)
        print(
            f"18-position device run on the simulated platform: {live:.2f} s live; re-estimate of the complete journal "
            f"(--resume --re-estimate: {replayed} records replayed, no platform): {resumed:.2f} s"
        )


if __name__ == "__main__":
    main()
