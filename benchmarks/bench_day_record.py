"""One day of 100 Hz system-level record through SystemRecordWriter: throughput and memory.

Usage::

    python benchmarks/bench_day_record.py [--hours 24] [--rate 100] [--source simulator|synthetic] [--dir DIR]

What it prints and what it compares against:

- the writer: samples/s and MB/s of ``SystemRecordWriter.append`` (time spent inside the
  writer only, so the simulator's own cost does not count against it), and the file size;
- the simulator (``--source simulator``): samples/s of ``system_record_chunks``;
- baseline 1: raw h5py (fsynced, like the writer), the same number of float64 columns and rows written chunk by
  chunk into resizable chunked datasets, with no validation and no atomic rename: the
  floor for any HDF5 writer on this disk;
- baseline 2: ``numpy.ndarray.tofile`` of the same bytes, fsynced: the disk's sequential bandwidth;
- controlled comparison: the same hour of chunks written alternately by the writer and by
  raw h5py (best of N), the fairest measure of the writer's own overhead (validation,
  buffering, atomic rename);
- reading back: ``open_system_record`` + ``check_sampling`` + ``iter_chunks`` over all columns;
- peak memory: tracemalloc peak of Python/numpy allocations during the writer run, and the
  process's maximum resident set size (``ru_maxrss``).  A day is 0.97 GB of float64: a peak
  far below that shows the record is streamed, not held.
"""

from __future__ import annotations

import argparse
import math
import os
import resource
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

import h5py
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from stableins.data.system import SystemRecordWriter, open_system_record  # noqa: E402
from stableins.schema import SYSTEM_COLUMNS  # noqa: E402
from stableins.site import SiteMetadata  # noqa: E402

CHUNK = 65536
NAMES = [c.name for c in SYSTEM_COLUMNS]


def synthetic_chunks(duration: float, rate: float, chunk: int = CHUNK):
    """Independent source of realistic-size chunks (white noise around a static INS)."""
    rng = np.random.default_rng(1)
    n_total = int(math.ceil(duration * rate))
    for start in range(0, n_total, chunk):
        n = min(chunk, n_total - start)
        out = {name: rng.normal(scale=1e-3, size=n) for name in NAMES}
        out["time"] = np.arange(start, start + n) / rate
        out["f_z"] -= 9.8
        yield out


def simulator_chunks(duration: float, rate: float, chunk: int = CHUNK):
    from stableins.simulator.system import system_record_chunks
    from stableins.simulator.truth import Truth

    truth = Truth.draw(1, sample_rate=rate)
    return system_record_chunks(truth, duration, rate, 1, chunk_samples=chunk), truth.site


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hours", type=float, default=24.0)
    parser.add_argument("--rate", type=float, default=100.0)
    parser.add_argument("--source", choices=("simulator", "synthetic"), default="simulator")
    parser.add_argument("--repeat", type=int, default=3, help="repetitions of each baseline")
    parser.add_argument("--dir", type=Path, default=None, help="where to write (default: a temporary directory)")
    args = parser.parse_args()
    duration = args.hours * 3600.0
    n_total = int(math.ceil(duration * args.rate))
    ncol = len(NAMES)
    payload_mb = n_total * ncol * 8 / 1e6
    print(f"record: {args.hours:g} h at {args.rate:g} Hz = {n_total} samples x {ncol} float64 columns = {payload_mb:.0f} MB")

    with tempfile.TemporaryDirectory(dir=args.dir) as tmp:
        directory = Path(tmp)
        if args.source == "simulator":
            chunks, site = simulator_chunks(duration, args.rate)
        else:
            chunks = synthetic_chunks(duration, args.rate)
            site = SiteMetadata("BENCH-1", math.radians(40.0), 0.0, 9.8017, "WGS-84 normal gravity", args.rate)
        path = directory / "day.h5"
        t_writer = write_day(path, site, chunks, n_total, payload_mb, args.source)
        read_back(path, n_total, payload_mb)
        baselines(directory, n_total, payload_mb, t_writer, args.repeat)
        controlled(directory, site, args.rate, args.repeat)

    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e3  # kB on Linux
    print(f"\nprocess max resident set size (ru_maxrss, whole run incl. interpreter and libraries): {rss:.0f} MB")


def write_day(path, site, chunks, n_total, payload_mb, source) -> float:
    """Write the record with SystemRecordWriter; print the writer's and the source's time and the peak memory; return the writer's time."""
    tracemalloc.start()
    t_source = t_writer = 0.0
    t0 = time.perf_counter()
    with SystemRecordWriter(path, site, chunk_samples=CHUNK) as writer:
        iterator = iter(chunks)
        while True:
            a = time.perf_counter()
            try:
                chunk = next(iterator)
            except StopIteration:
                break
            b = time.perf_counter()
            writer.append(chunk)
            c = time.perf_counter()
            t_source += b - a
            t_writer += c - b
        a = time.perf_counter()
    t_writer += time.perf_counter() - a  # final flush, fsync and rename
    total = time.perf_counter() - t0
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    size_mb = path.stat().st_size / 1e6
    print(f"\nSystemRecordWriter ({source} source), {total:.1f} s in all:")
    print(f"  writer:  {t_writer:6.2f} s  {n_total / t_writer:12.0f} samples/s  {payload_mb / t_writer:7.1f} MB/s   file {size_mb:.0f} MB")
    print(f"  source:  {t_source:6.2f} s  {n_total / t_source:12.0f} samples/s  ({source})")
    print(f"  peak traced memory (tracemalloc) during the run: {peak / 1e6:.1f} MB  (record: {payload_mb:.0f} MB)")
    return t_writer


def read_back(path, n_total, payload_mb) -> None:
    """Open the record, check its sampling and read every chunk back; print the time."""
    t0 = time.perf_counter()
    record = open_system_record(path)
    report = record.check_sampling()
    rows = 0
    for chunk in record.iter_chunks(rows=CHUNK):
        rows += len(chunk["time"])
    t_read = time.perf_counter() - t0
    assert rows == n_total == record.n_samples
    print(f"\nread back (open + check_sampling + iter_chunks, all columns, NaN checks): {t_read:.2f} s")
    print(f"  {n_total / t_read:.0f} samples/s  {payload_mb / t_read:.1f} MB/s")
    print(f"  mean rate {report.mean_rate:.6f} Hz, gaps {len(report.gaps)}")


def raw_h5py(directory, block, n_total) -> float:
    """Write ``n_total`` rows of ``block`` with plain h5py chunked appends (and fsync); return the time."""
    raw = directory / "raw.h5"
    t0 = time.perf_counter()
    with h5py.File(raw, "w") as f:
        datasets = [f.create_dataset(name, shape=(0,), maxshape=(None,), dtype="f8", chunks=(CHUNK,)) for name in NAMES]
        for start in range(0, n_total, CHUNK):
            n = min(CHUNK, n_total - start)
            for j, d in enumerate(datasets):
                d.resize((start + n,))
                d[start:] = block[j, :n]
    with open(raw, "rb+") as handle:
        os.fsync(handle.fileno())  # the writer fsyncs too
    elapsed = time.perf_counter() - t0
    raw.unlink()
    return elapsed


def raw_tofile(directory, block, n_total) -> float:
    """Write ``n_total`` rows of ``block`` with numpy tofile (and fsync); return the time."""
    flat = directory / "raw.bin"
    t0 = time.perf_counter()
    with open(flat, "wb") as handle:
        for start in range(0, n_total, CHUNK):
            n = min(CHUNK, n_total - start)
            block[:, :n].tofile(handle)
        handle.flush()
        os.fsync(handle.fileno())
    elapsed = time.perf_counter() - t0
    flat.unlink()
    return elapsed


def baselines(directory, n_total, payload_mb, t_writer, repeat) -> None:
    """Print the raw h5py and numpy tofile baselines for the same rows and columns, and the writer's time against them."""
    block = np.random.default_rng(2).normal(size=(len(NAMES), CHUNK))
    t_raw = [raw_h5py(directory, block, n_total) for _ in range(repeat)]
    t_flat = [raw_tofile(directory, block, n_total) for _ in range(repeat)]
    print(f"\nbaselines (same rows x columns of float64; best and worst of {repeat}):")
    for label, times in (("raw h5py chunked append", t_raw), ("numpy tofile", t_flat)):
        lo, hi = min(times), max(times)
        rates = f"{n_total / hi:10.0f}..{n_total / lo:10.0f} samples/s  {payload_mb / hi:6.1f}..{payload_mb / lo:6.1f} MB/s"
        print(f"  {label:<24} {lo:6.2f}..{hi:6.2f} s  {rates}")
    print(f"  writer time / raw h5py time: {t_writer / max(t_raw):.2f}..{t_writer / min(t_raw):.2f}")
    print("  (disk figures swing by 2x or more with page-cache state and machine load; compare within one run)")


def controlled(directory, site, rate, repeat) -> None:
    """Print the writer against raw h5py on the same hour of chunks, alternating, best of several."""
    hour = list(synthetic_chunks(3600.0, rate))
    n_hour = sum(len(c["time"]) for c in hour)

    def writer_hour() -> float:
        t0 = time.perf_counter()
        with SystemRecordWriter(directory / "hour.h5", site, chunk_samples=CHUNK) as w:
            for c in hour:
                w.append(c)
        return time.perf_counter() - t0

    def raw_hour() -> float:
        t0 = time.perf_counter()
        with h5py.File(directory / "hour-raw.h5", "w") as f:
            datasets = [f.create_dataset(name, shape=(0,), maxshape=(None,), dtype="f8", chunks=(CHUNK,)) for name in NAMES]
            start = 0
            for c in hour:
                n = len(c["time"])
                for name, d in zip(NAMES, datasets):
                    d.resize((start + n,))
                    d[start:] = c[name]
                start += n
        with open(directory / "hour-raw.h5", "rb+") as handle:
            os.fsync(handle.fileno())
        return time.perf_counter() - t0

    pairs = [(writer_hour(), raw_hour()) for _ in range(max(3, repeat))]
    w_best, r_best = min(p[0] for p in pairs), min(p[1] for p in pairs)
    print(f"\ncontrolled: the same 1 h of chunks ({n_hour} samples), writer and raw h5py alternating, best of {len(pairs)}:")
    print(f"  writer {w_best:.3f} s ({n_hour / w_best:.0f} samples/s), raw h5py {r_best:.3f} s; writer / raw = {w_best / r_best:.2f}")


if __name__ == "__main__":
    main()
