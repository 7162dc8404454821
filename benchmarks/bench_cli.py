"""Speed of the commands as users type them, each next to a fresh-process read of every column of its input.

Issue 30: what a user waits for is the command as typed (a fresh process: imports, reading, the fit, the
record, the report), not the stage alone.  This benchmark writes realistic records with the toolkit's own
simulator into ``--dir`` (kept and reused when present):

* the demo's device files: ``stableins simulate device --seed S`` (``device-coarse.csv``, ``device-fine.h5``)
  and their calibration ``cal-device.json``;
* one sidereal day at ``--rate`` Hz (default 100) from ``stableins simulate system --truth ... --installed
  cal-device.json``: temperature, gimbal readings and gyro drift included, and its ``calibration.json``.

Then, alternating ``--repeat`` times in one run (so that both see the same machine), each command in a fresh
process and a fresh-process read of every column of the same files through the toolkit's readers
(:func:`stableins.data.device.load_device` for device files; every column of the system record through
:func:`stableins.data.system.open_system_record`'s chunks).  Printed per command: the best wall and CPU
(user + system of the child) time of the command and of the read, their ratio (the issue's acceptance:
``calibrate system`` ≤ 3×, ``calibrate device`` ≤ 4×, ``diagnose`` ≤ 4×, ``report`` ≤ 6×), ``stableins
--help`` (≤ 0.15 s) and ``import stableins`` (≤ 0.2 s), the load average, and (``--profile``) where the time goes:
the functions with the most own time in a cProfile of the command (a fresh process, imports included).

A second line, labelled "stage only", times :func:`stableins.estimators.system.stage.run_system_stage`
in-process on the same file (imports, validation, sensitivities and the record left out), which is what
``bench_system_stream.py`` measures.  ``--background N`` runs N busy processes during the timed runs (the
issue's "under a load of 4"); they are this script's children and are stopped at the end.

Usage::

    python benchmarks/bench_cli.py [--dir /tmp/stableins-bench-cli] [--rate 100] [--repeat 3] [--profile]
        [--only calibrate-system calibrate-device diagnose report help import] [--background 4]
"""

from __future__ import annotations

import argparse
import os
import pstats
import resource
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

PYTHON = sys.executable
STABLEINS = [PYTHON, "-c", "import sys; from stableins.cli import main; sys.argv[0] = 'stableins'; sys.exit(main())"]

#: A fresh-process read of every column of each file given: device files through load_device, system
#: records chunk by chunk through the system reader (every column; buffers reused, as the stage reads).
READ = r"""
import sys
import numpy as np
total = 0.0
for path in sys.argv[1:]:
    if path.endswith("system.h5"):
        from stableins.data.system import open_system_record
        record = open_system_record(path)
        for chunk in record.iter_chunks(None, reuse=True):
            total += sum(float(np.sum(v)) for v in chunk.values() if np.issubdtype(np.asarray(v).dtype, np.number))
    else:
        from stableins.data.device import load_device
        data = load_device(path)
        total += sum(float(np.sum(v)) for v in data.columns.values() if np.issubdtype(np.asarray(v).dtype, np.number))
print(total)
"""

#: The stage alone, in-process, on a system record (what bench_system_stream.py times): its time on stdout.
STAGE_ONLY = r"""
import sys, time, warnings
from stableins.data.system import open_system_record
from stableins.discovery.library import record_terms
from stableins.estimators.system.stage import SystemOptions, run_system_stage
from stableins.records import CalibrationRecord
prior = CalibrationRecord.load(sys.argv[2])
record = open_system_record(sys.argv[1])
values = prior.values()
cov = {(a, b): float(prior.covariance[i, j]) for i, a in enumerate(prior.ids) for j, b in enumerate(prior.ids)}
warnings.simplefilter("ignore")
wall, cpu = time.perf_counter(), time.process_time()
run_system_stage(record, record.metadata, values, cov, SystemOptions(), compensation_terms=record_terms(prior.ids),
                 noise_model=prior.noise_model)
print(time.perf_counter() - wall, time.process_time() - cpu)
"""

#: A command under cProfile in a fresh process (imports included): ``PROFILE OUT ARGS...``.
PROFILE = r"""
import cProfile, sys
out, args = sys.argv[1], sys.argv[2:]
sys.argv = ["stableins", *args]
profile = cProfile.Profile()
profile.enable()
try:
    from stableins.cli import main
    main(args)
except SystemExit:
    pass
profile.disable()
profile.dump_stats(out)
"""


@dataclass(frozen=True)
class Case:
    """One timed command: its name, its arguments after ``stableins``, the files of its read pass, its target ratio."""

    name: str
    arguments: tuple[str, ...]
    reads: tuple[str, ...]
    target: float


@dataclass(frozen=True)
class Timing:
    """Wall and CPU (user + system of the child) seconds of one fresh process."""

    wall: float
    cpu: float


def timed(command: list[str], *, cwd: Path) -> Timing:
    """Run ``command`` in a fresh process (output discarded; a failure raises) and return its wall and CPU time."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    done = subprocess.run(command, cwd=cwd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, check=False)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode not in (0, 1):  # calibrate/diagnose may exit 1 when a check flags the data
        raise RuntimeError(f"{' '.join(command)} exited {done.returncode}: {done.stderr[-2000:]}")
    return Timing(wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime))


def prepare(directory: Path, *, seed: int, rate: float) -> None:
    """Write the demo's device files, their calibration, a sidereal day at ``rate`` and its calibration (once).

    The package's bytecode is compiled first, as an installation does: with ``PYTHONDONTWRITEBYTECODE`` set (as on the
    development machine) an editable install never caches it, and every fresh process compiled the ~100 modules a
    command imports again (about 0.1 s of CPU quiet, 0.4 s under load), which no user pays.
    """
    import compileall

    import stableins

    compileall.compile_dir(str(Path(stableins.__file__).parent), quiet=1)
    directory.mkdir(parents=True, exist_ok=True)
    steps = [
        ("device-fine.h5", ["simulate", "device", "--seed", str(seed), "--out", "."]),
        ("cal-device.json", ["calibrate", "device", "device-coarse.csv", "device-fine.h5", "--out", "cal-device.json"]),
        ("system.h5", ["simulate", "system", "--truth", "truth.json", "--seed", str(seed), "--installed", "cal-device.json",
                       "--rate", f"{rate:g}", "--out", "."]),
        ("calibration.json", ["calibrate", "system", "system.h5", "--prior", "cal-device.json", "--out", "calibration.json"]),
    ]  # fmt: skip
    for made, arguments in steps:
        if (directory / made).exists():
            continue
        taken = timed([*STABLEINS, *arguments], cwd=directory)
        print(f"setup: stableins {' '.join(arguments)}: {taken.wall:.1f} s wall, {taken.cpu:.1f} s CPU", flush=True)


def cases(out: Path) -> list[Case]:
    """The commands of the README's simulated walk-through, with the files each reads."""
    device = ("device-coarse.csv", "device-fine.h5")
    return [
        Case("calibrate-system", ("calibrate", "system", "system.h5", "--prior", "cal-device.json", "--out", str(out / "cal.json")),
             ("system.h5",), 3.0),
        Case("calibrate-device", ("calibrate", "device", *device, "--out", str(out / "cal-device.json")), device, 4.0),
        Case("diagnose", ("diagnose", *device, "--record", "cal-device.json"), device, 4.0),
        Case("report", ("report", "calibration.json", "--data", *device, "system.h5", "--out", str(out / "report.pdf")),
             (*device, "system.h5"), 6.0),
    ]  # fmt: skip


def best(timings: list[Timing]) -> Timing:
    """The least wall and the least CPU time of the repetitions (each its own minimum)."""
    return Timing(min(t.wall for t in timings), min(t.cpu for t in timings))


def profile_summary(arguments: tuple[str, ...], *, cwd: Path, top: int) -> list[str]:
    """Where a command's time goes: the ``top`` functions by own time in a cProfile of a fresh process, imports included."""
    with tempfile.TemporaryDirectory() as scratch:
        out = str(Path(scratch) / "profile.out")
        subprocess.run([PYTHON, "-c", PROFILE, out, *arguments], cwd=cwd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=False)
        stats = pstats.Stats(out)
    raw = stats.stats  # type: ignore[attr-defined]
    total = sum(entry[2] for entry in raw.values())
    imports = max((entry[3] for key, entry in raw.items() if key[2] == "_find_and_load"), default=0.0)
    rows = sorted(raw.items(), key=lambda item: -item[1][2])[:top]
    lines = [f"    profiled {total:.2f} s (cProfile inflates), of which imports {imports:.2f} s; own time by function:"]
    for (filename, line, function), entry in rows:
        where = filename.split("site-packages/")[-1].split("/wt-")[-1]
        where = where[where.find("stableins/") :] if "stableins/" in where else where
        lines.append(f"    {entry[2]:7.3f} s {entry[1]:6d} calls  {function} ({where}:{line})")
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dir", type=Path, default=Path(tempfile.gettempdir()) / "stableins-bench-cli", help="records (kept, reused)")
    parser.add_argument("--rate", type=float, default=100.0, help="sample rate of the system record [Hz]")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--repeat", type=int, default=3, help="runs of each command and of each read (the best is kept)")
    parser.add_argument("--only", nargs="+", default=None, help="calibrate-system calibrate-device diagnose report help import stage")
    parser.add_argument("--profile", action="store_true", help="print where each command's time goes (cProfile)")
    parser.add_argument("--top", type=int, default=12, help="functions in each profile")
    parser.add_argument("--background", type=int, default=0, help="busy processes running during the timed runs")
    args = parser.parse_args()
    wanted = set(args.only or ("calibrate-system", "calibrate-device", "diagnose", "report", "help", "import", "stage"))
    directory = args.dir.resolve()
    prepare(directory, seed=args.seed, rate=args.rate)
    busy = [subprocess.Popen([PYTHON, "-c", "while True: pass"]) for _ in range(args.background)]
    try:
        with tempfile.TemporaryDirectory() as scratch:
            run(args, wanted, directory, Path(scratch))
    finally:
        for process in busy:
            process.kill()
            process.wait()


def run(args: argparse.Namespace, wanted: set[str], directory: Path, scratch: Path) -> None:
    """Time the wanted commands against their read passes, alternating, and print the table (and the profiles)."""
    load = os.getloadavg()[0]
    print(f"{os.cpu_count()} cores, load average {load:.1f} before the run, {args.background} busy processes added; "
          f"best of {args.repeat} fresh processes each, command and read alternating")  # fmt: skip
    print(f"{'command':18s} {'wall [s]':>9s} {'CPU [s]':>8s} {'read wall':>10s} {'read CPU':>9s} {'× wall':>7s} {'× CPU':>6s} target")
    for case in (c for c in cases(scratch) if c.name in wanted):
        mine: list[Timing] = []
        read: list[Timing] = []
        for _ in range(args.repeat):
            read.append(timed([PYTHON, "-c", READ, *case.reads], cwd=directory))
            mine.append(timed([*STABLEINS, *case.arguments], cwd=directory))
        a, b = best(mine), best(read)
        print(f"{case.name:18s} {a.wall:9.2f} {a.cpu:8.2f} {b.wall:10.2f} {b.cpu:9.2f} {a.wall / b.wall:7.2f} {a.cpu / b.cpu:6.2f}"
              f" ≤ {case.target:g}×", flush=True)  # fmt: skip
        if args.profile:
            print("\n".join(profile_summary(case.arguments, cwd=directory, top=args.top)), flush=True)
    fixed = [("help", [*STABLEINS, "--help"], 0.15), ("import", [PYTHON, "-c", "import stableins"], 0.2)]
    for name, command, target in (f for f in fixed if f[0] in wanted):
        t = best([timed(command, cwd=directory) for _ in range(max(args.repeat, 5))])
        print(f"{name:18s} {t.wall:9.3f} {t.cpu:8.3f} {'':10s} {'':9s} {'':7s} {'':6s} ≤ {target:g} s", flush=True)
    if "stage" in wanted:
        stage = []
        for _ in range(args.repeat):
            done = subprocess.run([PYTHON, "-c", STAGE_ONLY, "system.h5", "cal-device.json"], cwd=directory, capture_output=True,
                                  text=True, check=True)  # fmt: skip
            wall, cpu = (float(x) for x in done.stdout.split())
            stage.append(Timing(wall, cpu))
        s = best(stage)
        print(f"stage only (in-process run_system_stage, no imports, validation, sensitivities or record; bench_system_stream's "
              f"figure): {s.wall:.2f} s wall, {s.cpu:.2f} s CPU")  # fmt: skip
    print(f"load average {os.getloadavg()[0]:.1f} after the run")


if __name__ == "__main__":
    main()
