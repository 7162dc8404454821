"""Speed and memory of the system stage on a week-long 100 Hz record read from disk.

Writes a synthetic static record of one sidereal week at 100 Hz (6.0e7 samples, ~6.8 GB) into
``--dir`` (default /tmp/stableins-bench) through the project's HDF5 format
(:class:`stableins.data.system.SystemRecordWriter`) with a fast vectorized writer (closed form,
not the truth simulator): accelerometer outputs of a polar-aligned platform with Table-2-sized
residuals and 5e-3 m/s² white noise, the platform angle, and small attitude/velocity errors.  A
file this run wrote is deleted at the end (``--keep`` keeps it); an existing file is reused.
Then, on the same file (page cache warmed first), minimum of ``--repeat`` runs:

1. baseline: one ``np.sum`` pass over ``f_x, f_y, f_z`` through the record reader (and the same
   with reused read buffers, the fastest read);
2. the whole system stage (:func:`stableins.estimators.system.stage.run_system_stage`);

for the first day and for the whole record.  Printed: both times, their ratio (target ≤ 2),
the per-sample cost, the peak memory of the stage (tracemalloc peak of Python/numpy
allocations: whole record, first day and 2, 3, 5 days, to show it bounded) and the process's max RSS (``ru_maxrss``).

Usage::

    python benchmarks/bench_system_stream.py [--dir /tmp/stableins-bench] [--days 7] [--rows 262144]
"""

from __future__ import annotations

import argparse
import math
import resource
import time
import tracemalloc
from pathlib import Path

import numpy as np

from stableins.conventions import EARTH_RATE, SIDEREAL_DAY, normal_gravity
from stableins.data.system import SystemRecordWriter, open_system_record
from stableins.estimators.system.stage import SystemOptions, run_system_stage
from stableins.site import SiteMetadata

RATE = 100.0


def write_record(path: Path, days: float, rows: int = 1 << 20) -> None:
    """Fast synthetic writer (vectorized closed form, not the truth simulator)."""
    lat = math.radians(40.0)
    g = float(normal_gravity(lat))
    a = math.pi / 648000.0
    meta = SiteMetadata("BENCH-1", lat, 0.0, g, "WGS-84 normal gravity", RATE, damping={"zeta": 0.5})
    n_total = int(round(days * SIDEREAL_DAY * RATE))
    rng = np.random.default_rng(1)
    c = np.array([[1.0, 5 * a, 10 * a], [-10 * a, 1.0, 5 * a], [-5 * a, 5 * a, 1.0]])  # C_p^a with residual angles
    sf = np.array([1e-4, 2e-4, -1e-4])
    bias = np.array([1e-3, 5e-4, -1e-3])
    with SystemRecordWriter(path, meta, chunk_samples=1 << 16) as writer:
        for start in range(0, n_total, rows):
            n = min(rows, n_total - start)
            t = (start + np.arange(n)) / RATE
            s = 0.4 + EARTH_RATE * t
            f_p = g * np.stack([np.cos(s) * math.cos(lat), np.sin(s) * math.cos(lat), np.full(n, math.sin(lat))], axis=1)
            f_a = (f_p @ c.T) * (1.0 - sf) + bias + rng.normal(0.0, 5e-3, (n, 3))
            tilt = 1e-4 * np.stack([np.cos(s + 0.1), np.sin(s - 0.2)], axis=1)
            writer.append(
                {
                    "time": t,
                    "angle_platform": -s,
                    "angle_inner": np.zeros(n),
                    "angle_middle": np.full(n, math.pi / 2 + lat),
                    "f_x": f_a[:, 0],
                    "f_y": f_a[:, 1],
                    "f_z": f_a[:, 2],
                    "velocity_north": 0.05 * np.sin(s),
                    "velocity_east": 0.05 * np.cos(s),
                    "velocity_down": np.zeros(n),
                    "roll": tilt[:, 1],
                    "pitch": tilt[:, 0],
                    "heading": np.zeros(n),
                    "temperature": np.full(n, 25.0),
                }
            )


def baseline(path: Path, rows: int, reuse: bool = False, limit_days: float | None = None) -> float:
    """One ``np.sum`` pass over f_x, f_y, f_z through the record reader (``reuse``: into reused buffers, the fastest read)."""
    record = open_system_record(path)
    total = 0.0
    stop = None if limit_days is None else int(limit_days * SIDEREAL_DAY * RATE)
    seen = 0
    start = time.perf_counter()
    for chunk in record.iter_chunks(["f_x", "f_y", "f_z"], rows=rows, reuse=reuse):
        total += float(np.sum(chunk["f_x"])) + float(np.sum(chunk["f_y"])) + float(np.sum(chunk["f_z"]))
        seen += rows
        if stop is not None and seen >= stop:
            break
    return time.perf_counter() - start


def baseline_plain(path: Path, rows: int, limit_days: float | None = None, chunk_cache: bool = True) -> float:
    """The literal baseline: h5py slices of f_x, f_y, f_z, ``np.sum`` of each (no validation, one allocation per slice).

    ``chunk_cache=False`` opens the file with HDF5's chunk cache off (``rdcc_nbytes=0``), as the stage's reader does for
    its in-order passes: whole chunks then go straight into the destination (the fastest read of these columns).
    """
    import h5py

    stop = None if limit_days is None else int(limit_days * SIDEREAL_DAY * RATE)
    total = 0.0
    start = time.perf_counter()
    with h5py.File(path, "r", **({} if chunk_cache else {"rdcc_nbytes": 0})) as f:
        columns = [f["columns"][name] for name in ("f_x", "f_y", "f_z")]
        n = columns[0].shape[0] if stop is None else min(stop, columns[0].shape[0])
        for k in range(0, n, rows):
            for d in columns:
                total += float(np.sum(d[k : min(k + rows, n)]))
    return time.perf_counter() - start


def stage(path: Path, rows: int, limit_days: float | None = None, trace: bool = False) -> tuple[float, float, int]:
    """Run the stage; time it (``trace=False``) or measure its peak traced memory (``trace=True``, slower)."""
    record = open_system_record(path)
    source = record
    if limit_days is not None:
        limit = int(limit_days * SIDEREAL_DAY * RATE)

        class First:
            path = record.path

            def iter_chunks(self, columns=None, rows=rows, **options):
                seen = 0
                for chunk in record.iter_chunks(columns, rows, **options):
                    if seen >= limit:
                        return
                    yield chunk
                    seen += rows

        source = First()
    if trace:
        tracemalloc.start()
    start = time.perf_counter()
    out = run_system_stage(source, record.metadata, {}, options=SystemOptions(chunk_rows=rows))
    elapsed = time.perf_counter() - start
    peak = 0
    if trace:
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
    return elapsed, peak, int(out.diagnostics.samples)


def validation(path: Path) -> float:
    """Seconds of the validation pass that ``stableins check`` and ``stableins calibrate system`` run before the stage."""
    from stableins.data.system import open_system_record

    t0 = time.perf_counter()
    open_system_record(path).validate()
    return time.perf_counter() - t0


def breakdown(path: Path, rows: int) -> tuple[float, dict[str, float]]:
    """Where one run of the stage spends its time: the source's reads and the stage's parts (section timers).

    The parts are wrapped with timers for this run only (the module is restored afterwards); what is left of the
    total is the streaming loop's own numpy work on the 1-Hz columns and the post-processing not listed.
    """
    from stableins.estimators.system import accumulate, blocks, solve
    from stableins.estimators.system.checks import StaticChecks

    record = open_system_record(path)
    timers: dict[str, float] = {}

    class TimedSource:
        path = record.path
        time_grid = record.time_grid

        def grid_time(self, start: int, stop: int):
            return record.grid_time(start, stop)

        def iter_chunks(self, *args, **options):
            chunks = record.iter_chunks(*args, **options)
            while True:
                start = time.perf_counter()
                chunk = next(chunks, None)
                timers["reads (forces at full rate, 1-Hz overview)"] = timers.get("reads (forces at full rate, 1-Hz overview)", 0.0) + (
                    time.perf_counter() - start
                )
                if chunk is None:
                    return
                yield chunk

    parts = {
        (accumulate, "block_sums"): "pass over every sample (z, block moments, sampling check)",
        (blocks, "harmonic_sums"): "harmonic block sums",
        (accumulate, "second_difference_sums"): "noise second differences",
        (StaticChecks, "slow"): "static checks on the 1-Hz columns",
        (accumulate.AttitudeBlocks, "add"): "attitude blocks",
        (solve.hm, "kalman_filter"): "Kalman-filter curve",
        (solve, "fit_attitude"): "attitude fit",
        (solve, "coloured_covariance"): "coloured-noise model",
    }
    saved = {key: getattr(*key) for key in parts}

    def timed(function, label):
        def wrapper(*args, **kwargs):
            start = time.perf_counter()
            try:
                return function(*args, **kwargs)
            finally:
                timers[label] = timers.get(label, 0.0) + time.perf_counter() - start

        return wrapper

    try:
        for (owner, name), label in parts.items():
            setattr(owner, name, timed(saved[(owner, name)], label))
        start = time.perf_counter()
        run_system_stage(TimedSource(), record.metadata, {}, options=SystemOptions(chunk_rows=rows))
        total = time.perf_counter() - start
    finally:
        for (owner, name), function in saved.items():
            setattr(owner, name, function)
    return total, timers


_RSS_SCRIPT = """
import sys
def rss():  # VmHWM: this process's peak resident set (ru_maxrss would carry the parent's over fork and exec)
    with open("/proc/self/status") as status:
        return next(float(line.split()[1]) / 1024.0 for line in status if line.startswith("VmHWM:"))
import numpy, scipy.linalg, filterpy.kalman, h5py  # noqa: E401, F401
imports = rss()
from stableins.data.system import open_system_record
from stableins.estimators.system.stage import SystemOptions, run_system_stage
record = open_system_record(sys.argv[1])
run_system_stage(record, record.metadata, {}, options=SystemOptions(chunk_rows=int(sys.argv[2])))
print(imports, rss())
"""


def stage_rss(path: Path, rows: int) -> tuple[float, float]:
    """Maximum RSS [MiB] of a fresh process that runs the stage once on the file, and of its imports alone."""
    import subprocess
    import sys

    out = subprocess.run([sys.executable, "-c", _RSS_SCRIPT, str(path), str(rows)], capture_output=True, text=True, check=True)
    imports, total = map(float, out.stdout.split())
    return imports, total


def measure(path: Path, rows: int, days: float, r: int) -> dict:
    """Time the baselines, the validating reader, the stage and its sections; trace the memory; minimum of ``r`` runs."""
    import filterpy.kalman  # noqa: F401  one-time import cost (about 1-3 s), not part of the per-sample cost
    import scipy.linalg  # noqa: F401
    import scipy.optimize  # noqa: F401

    baseline(path, rows)  # warm the page cache so both passes read from memory
    stage(path, rows)
    m: dict = {}
    m["t_plain"] = min(baseline_plain(path, rows) for _ in range(r))
    m["t_plain_day"] = min(baseline_plain(path, rows, limit_days=1.0) for _ in range(r))
    m["t_base"] = min(baseline(path, rows) for _ in range(r))
    m["t_base_fast"] = min(baseline_plain(path, rows, chunk_cache=False) for _ in range(r))
    m["t_stage"], _, m["n"] = min(stage(path, rows) for _ in range(r))
    m["t_base_day"] = min(baseline(path, rows, limit_days=1.0) for _ in range(r))
    m["t_day"], _, m["n_day"] = min(stage(path, rows, limit_days=1.0) for _ in range(r))
    _, m["peak"], _ = stage(path, rows, trace=True)
    _, m["peak_day"], _ = stage(path, rows, limit_days=1.0, trace=True)
    m["lengths"] = [d for d in (2.0, 3.0, 5.0) if d < days]
    m["peaks"] = [stage(path, rows, limit_days=d, trace=True)[1] for d in m["lengths"]]
    m["split"] = min((breakdown(path, rows) for _ in range(r)), key=lambda run: run[0])
    m["t_validate"] = min(validation(path) for _ in range(r))
    m["rss"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    m["rss_imports"], m["rss_stage"] = stage_rss(path, rows)
    return m


def report(m: dict, rows: int, r: int) -> None:
    """Print the figures of :func:`measure` and the targets they are compared with."""
    n, t_stage, t_validate, peak, peak_day = m["n"], m["t_stage"], m["t_validate"], m["peak"], m["peak_day"]
    print(f"record: {n:.3e} samples ({n / RATE / 86400:.2f} days at {RATE:g} Hz), chunks of {rows} rows, minimum of {r} runs")
    for label, tp, tb, ts, count in (
        ("first day", m["t_plain_day"], m["t_base_day"], m["t_day"], m["n_day"]),
        ("whole record", m["t_plain"], m["t_base"], t_stage, n),
    ):
        print(f"{label}:")
        print(f"  baseline np.sum over f_x, f_y, f_z (h5py slices) : {tp:7.3f} s  ({tp / count * 1e9:5.1f} ns/sample)")
        print(f"  the same through the validating reader           : {tb:7.3f} s  ({tb / count * 1e9:5.1f} ns/sample)")
        print(
            f"  system stage                                     : {ts:7.3f} s  ({ts / count * 1e9:5.1f} ns/sample)  "
            f"ratio {ts / tp:.2f} to the h5py baseline (target <= 2), {ts / tb:.2f} to the reader's"
        )
    t_base_fast = m["t_base_fast"]
    print(f"  baseline, h5py slices with the chunk cache off   : {t_base_fast:7.3f} s  -> stage ratio {t_stage / t_base_fast:.2f}")
    print(
        f"  validation pass of check / calibrate system (every column, time base, /overview, /time_grid): {t_validate:7.3f} s "
        f"({t_validate / n * 1e9:5.1f} ns/sample; SystemRecord.validate, before the stage)"
    )
    total, timers = m["split"]
    print(f"where the stage's time goes (whole record, section timers, fastest of {r} runs: {total:.3f} s in all):")
    for label, seconds in sorted(timers.items(), key=lambda item: -item[1]):
        print(f"  {label:<48} {seconds:7.3f} s")
    print(f"  {'the rest (loop numpy work, other post-processing)':<48} {total - sum(timers.values()):7.3f} s")
    print(
        f"peak traced memory (tracemalloc): whole record {peak / 2**20:.1f} MiB, first day {peak_day / 2**20:.1f} MiB "
        "(target <= 256 MiB, flat)"
    )
    days_traced = [1.0, *m["lengths"], n / RATE / SIDEREAL_DAY]
    peaks_traced = [peak_day, *m["peaks"], peak]
    table = ", ".join(f"{d:.3g} d {p / 2**20:.1f} MiB" for d, p in zip(days_traced, peaks_traced, strict=True))
    print(f"peak traced memory against record length: {table}")
    print(
        "  (flat: the coloured-noise model holds (n, n) kernels of at most COLOURED_BINS = 160 bins, the attitude blocks are capped"
        " at 2^14, the filter curve at 512 steps; the chunk buffers do not depend on the record length)"
    )
    print(
        f"max RSS of a fresh process running the stage once on the whole record: {m['rss_stage']:.0f} MiB "
        f"(its imports of numpy, scipy, filterpy, h5py alone: {m['rss_imports']:.0f} MiB; target <= 256 MB = 244 MiB)"
    )
    print(f"max RSS of this benchmark process (includes the writer if it ran): {m['rss']:.0f} MiB")
    print("the stage reads f_x, f_y, f_z at the full rate; time, angle_platform, pitch, roll, velocity_north, velocity_east at 1 Hz")
    print("from /overview, and reconstructs the full-rate time from /time_grid (docs/formats.md); the baseline reads f_x, f_y, f_z")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dir", default="/tmp/stableins-bench")
    parser.add_argument("--days", type=float, default=7.0)
    parser.add_argument("--rows", type=int, default=1 << 18)
    parser.add_argument("--repeat", type=int, default=3, help="timed runs; the minimum is reported (shared machine)")
    parser.add_argument("--keep", action="store_true", help="keep a file this run wrote (it is deleted by default)")
    args = parser.parse_args(argv)
    path = Path(args.dir) / f"static-{args.days:g}d-100Hz.h5"
    wrote = False
    if not path.exists():
        path.parent.mkdir(parents=True, exist_ok=True)
        t0 = time.perf_counter()
        write_record(path, args.days)
        wrote = True
        print(f"wrote {path} ({path.stat().st_size / 1e9:.2f} GB) in {time.perf_counter() - t0:.0f} s")
    try:
        m = measure(path, args.rows, args.days, args.repeat)
    finally:
        if wrote and not args.keep:
            path.unlink()
            print(f"deleted {path}")
    report(m, args.rows, args.repeat)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
