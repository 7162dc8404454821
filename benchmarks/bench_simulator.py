"""Speed and memory of the truth simulator.

Usage::

    python benchmarks/bench_simulator.py [--hours 24] [--rate 100]

What it prints and what it compares against:

- system level: samples/s of ``system_record_chunks`` for ``--hours`` at ``--rate`` with
  quartz noise, gyro drift and case-rotation residual (target: one day at 100 Hz,
  8.64e6 samples, in under 60 s on one core), and the tracemalloc peak (a day of the 14
  output columns is 0.97 GB: a peak of tens of MB shows the record is streamed);
- floor: the time numpy needs only to draw the white noise of the same samples
  (3 axes), which any simulator must at least spend;
- naive: a Python loop ``x = Φ x + Γ u`` over the 9 error states, timed on 20 000 steps
  and extrapolated, i.e. what the modal ``lfilter`` recursion replaces;
- device level: wall time of an 18-position ``simulate_dwells`` (20 s dwells, 5 s settle,
  100 Hz) with quartz noise.
"""

from __future__ import annotations

import argparse
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from stableins.simulator.device import simulate_dwells  # noqa: E402
from stableins.simulator.error_dynamics import error_dynamics  # noqa: E402
from stableins.simulator.system import system_record_chunks  # noqa: E402
from stableins.simulator.truth import SimulatedSite, Truth  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hours", type=float, default=24.0)
    parser.add_argument("--rate", type=float, default=100.0)
    args = parser.parse_args()
    duration = args.hours * 3600.0
    truth = Truth.draw(1, site=SimulatedSite(sample_rate=args.rate), gyro_drift={"x": 1e-9, "y": -2e-9, "z": 1e-9, "case_amplitude": 1e-8})
    for _ in system_record_chunks(truth, 10.0, args.rate):  # warm-up: imports, caches
        pass

    tracemalloc.start()
    start = time.perf_counter()
    n = 0
    for chunk in system_record_chunks(truth, duration, args.rate, seed=1, chunk_samples=65536):
        n += len(chunk["time"])
    elapsed = time.perf_counter() - start
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    print(f"system level: {n} samples ({args.hours:g} h at {args.rate:g} Hz) in {elapsed:.1f} s = {n / elapsed / 1e6:.3f} Msamples/s")
    print(f"  one day at 100 Hz would take {8.64e6 / (n / elapsed):.1f} s (target < 60 s); tracemalloc peak {peak / 2**20:.0f} MB")

    rng = np.random.default_rng(0)
    start = time.perf_counter()
    for k in range(0, n, 65536):
        rng.standard_normal((min(65536, n - k), 3))
    floor = time.perf_counter() - start
    print(f"  floor (white noise only): {floor:.1f} s, simulator/floor = {elapsed / floor:.1f}")

    from scipy.linalg import expm

    A, B = error_dynamics(truth.site.latitude, truth.site.damping)
    m = expm(np.block([[A, B], [np.zeros((6, 15))]]) / args.rate)
    phi, gamma = m[:9, :9], m[:9, 9:]
    u = rng.standard_normal((20000, 6))
    x = np.zeros(9)
    start = time.perf_counter()
    for k in range(len(u)):
        x = phi @ x + gamma @ u[k]
    per_step = (time.perf_counter() - start) / len(u)
    print(f"  naive Python recursion of the error states alone: {per_step * n:.1f} s for the same record")

    positions = [(0.0, k * np.pi / 4, j * np.pi / 2) for j in range(2) for k in range(9)]
    start = time.perf_counter()
    d = simulate_dwells(truth, positions, dwell=20.0, settle=5.0, rate=100.0, seed=1)
    print(f"device level: 18 positions x 20 s at 100 Hz ({len(d['time'])} recorded samples) in {time.perf_counter() - start:.2f} s")


if __name__ == "__main__":
    main()
