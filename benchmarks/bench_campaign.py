"""Campaigns on Dask: the design's σ against a Monte Carlo of full simulated calibrations, speed, and scaling.

A. The paper's procedure (device-coarse × 2 passes in one session + device-fine), ``--devices`` simulated quartz
   instruments (white + 2 µg bias instability + random walk + quantization + angle noise), each simulated,
   calibrated (the joint fit, datasheet noise model) through the library on a local Dask cluster of ``--workers``.
   Compared against: the design's Cramér-Rao bound (bench_design.py), target |measured σ / design σ − 1| ≤ 5 % for
   every parameter (measured σ = RMS of estimate − truth; its own 1σ is about 1/√(2n), 2.2 % for 1000 devices),
   rms z (1 for honest σ) and the speed target: 1000 full calibrations in ≤ 10 min on 2 cores.
B. ``--designed DIR``: the same for the procedures ``bench_design.py --out DIR`` wrote (same positions, optimized
   dwells): their measured σ against the paper's measured σ and the lab-time ratio (target ≤ 60 %).
C. ``--scaling N``: N devices with 1 worker, then with 2 workers (fresh directories): the speed-up (target ≥ 1.7).
   The machine is shared: ``uptime`` is printed before and after; run it when the machine is quiet.

``--diagnose`` makes part A's tasks simulate → calibrate → diagnose (issue 30's campaign); the line of part A gives the
CPU time of the run (workers and cluster included), tasks per CPU-second and tasks per second per worker.
``--in-process N`` (issue 30) runs N diagnosed tasks of the paper procedure (seeds ``--first-seed`` … after one warm-up
task of the seed before) in this one process, one BLAS thread, and prints the CPU seconds per task, tasks per
CPU-second, the projected wall time of 1,000 tasks on 2 idle workers and the SHA-256 of the tasks' rows without their
timing columns (the same on any commit that changes no output).  CPU time, not wall: the machine may be shared.
``--sample-rate`` (default 10 Hz) simulates every dwell at that rate: the white noise of a dwell mean is N/√T at any
rate, so the σ do not depend on it; the simulation time does (the coarse procedure's 100 Hz is 10× the samples).
Campaign directories are kept (``--out``): the same command resumes an interrupted run.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

from stableins.cli import single_threaded_blas

if "--in-process" in sys.argv:  # before numpy loads: part D's tasks with one BLAS thread, as a campaign's workers run them
    single_threaded_blas()

from stableins.campaign.config import load_campaign  # noqa: E402
from stableins.campaign.execution import run_campaign  # noqa: E402
from stableins.campaign.summary import write_outputs  # noqa: E402
from stableins.procedures.definition import load_procedure  # noqa: E402
from stableins.procedures.designed import device_plan  # noqa: E402

TARGET_SIGMA = 0.05
TARGET_MINUTES = 10.0
TARGET_SPEEDUP = 1.7
TARGET_LAB_TIME = 0.60


def _config(
    directory: Path, name: str, coarse: str, fine: str, devices: int, rate: float, first_seed: int = 1, *, diagnose: bool = False
) -> Path:
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / f"{name}.toml"
    text = (
        f'[campaign]\nname = "{name}"\nfirst_seed = {first_seed}\ndevices = {devices}\ndiagnose = {str(diagnose).lower()}\n\n'
        f'[[procedure]]\nname = "{name}"\ncoarse = "{coarse}"\nfine = "{fine}"\npasses = 2\nsample_rate = {rate}\n\n'
        '[[noise]]\nname = "quartz"\npreset = "quartz"\ncalibrate = "datasheet"\n\n[[hidden]]\nname = "none"\n'
    )
    if not path.exists() or path.read_text(encoding="utf-8") != text:
        path.write_text(text, encoding="utf-8")
    return path


def _uptime() -> str:
    return subprocess.run(["uptime"], capture_output=True, text=True, check=False).stdout.strip()


def _cpu() -> float:
    """CPU seconds (user + system) of this process and of its finished children (the local cluster's workers)."""
    mine, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return mine.ru_utime + mine.ru_stime + children.ru_utime + children.ru_stime


def _run(config_path: Path, out: Path, workers: int):
    config = load_campaign(config_path)
    t0, c0 = time.perf_counter(), _cpu()
    ran = run_campaign(config, out, workers=workers)
    elapsed, cpu = time.perf_counter() - t0, _cpu() - c0  # the workers are joined when the cluster closes
    outputs = write_outputs(config, out)
    return config, ran, (elapsed, cpu), outputs


def part_a(args) -> tuple[bool, dict]:
    name = "paper-diagnosed" if args.diagnose else "paper"
    config_path = _config(args.out, name, "device-coarse", "device-fine", args.devices, args.sample_rate, diagnose=args.diagnose)
    what = "simulate → calibrate → diagnose" if args.diagnose else "simulate → calibrate"
    print(f"A. paper procedure, {args.devices} devices ({what}), {args.workers} worker(s); {_uptime()}")
    _, ran, (elapsed, cpu), outputs = _run(config_path, args.out / name, args.workers)
    ok = True
    if ran.ran:
        per = elapsed / ran.ran
        print(
            f"  ran {ran.ran} tasks ({ran.resumed} found finished) in {elapsed:.0f} s: {per:.2f} s per calibration, "
            f"1000 calibrations in {1000 * per / 60:.1f} min (target ≤ {TARGET_MINUTES:g} min on 2 cores) -> "
            f"{'PASS' if 1000 * per / 60 <= TARGET_MINUTES else 'FAIL'}; {cpu:.1f} s of CPU in all (cluster included), "
            f"{cpu / ran.ran:.3f} s per task: {ran.ran / cpu:.2f} tasks per CPU-second, "
            f"{ran.ran / (elapsed * args.workers):.2f} tasks per second per worker (wall); {_uptime()}"
        )
        ok = 1000 * per / 60 <= TARGET_MINUTES
    else:
        print(f"  all {ran.total} tasks found finished in {args.out / 'paper'} (no timing: delete it to measure the speed)")
    n = outputs.parameters[0].n
    print(
        f"  {'parameter':<10}{'design σ':>10}{'measured σ':>12}{'ratio':>8}{'rms z':>8}  unit"
        f"   (ratio's own 1σ ≈ {1 / math.sqrt(2 * n):.3f})"
    )
    worst = 0.0
    for s in outputs.parameters:
        ratio = s.measured_sigma / s.design_sigma
        worst = max(worst, abs(ratio - 1))
        print(f"  {s.parameter:<10}{s.design_sigma:>10.4g}{s.measured_sigma:>12.4g}{ratio:>8.3f}{s.rms_z:>8.3f}  {s.unit}")
    sigma_ok = worst <= TARGET_SIGMA
    print(
        f"  requirement: design σ within {TARGET_SIGMA:.0%} of the measured σ for every parameter: worst {worst:.1%} over {n} devices -> "
        f"{'PASS' if sigma_ok else 'FAIL'}"
    )
    return ok and sigma_ok, {s.parameter: s.measured_sigma for s in outputs.parameters}


def part_b(args, paper_measured: dict) -> bool:
    designed = args.designed
    coarse, fine = load_procedure(designed / "designed-coarse.toml"), load_procedure(designed / "designed-fine.toml")
    paper_plan = device_plan(load_procedure("device-coarse"), load_procedure("device-fine"), passes=2)
    ratio = device_plan(coarse, fine, passes=2).lab_time / paper_plan.lab_time
    config_path = _config(
        args.out,
        "designed",
        str(designed / "designed-coarse.toml"),
        str(designed / "designed-fine.toml"),
        args.designed_devices,
        args.sample_rate,
    )
    print(f"\nB. designed procedure ({designed}), {args.designed_devices} devices; lab time {ratio:.1%} of the paper's")
    _, ran, (elapsed, _cpu_seconds), outputs = _run(config_path, args.out / "designed", args.workers)
    print(f"  ran {ran.ran} tasks in {elapsed:.0f} s")
    n = outputs.parameters[0].n
    print(f"  {'parameter':<10}{'paper meas. σ':>14}{'designed meas. σ':>17}{'ratio':>8}{'design σ':>10}{'rms z':>8}  unit")
    worst_z = 0.0
    for s in outputs.parameters:
        r = s.measured_sigma / paper_measured[s.parameter]
        se = math.sqrt(1 / (2 * n) + 1 / (2 * args.devices))  # 1σ of the ratio of two independent σ estimates
        worst_z = max(worst_z, (r - 1) / se)
        print(
            f"  {s.parameter:<10}{paper_measured[s.parameter]:>14.4g}{s.measured_sigma:>17.4g}{r:>8.3f}"
            f"{s.design_sigma:>10.4g}{s.rms_z:>8.3f}  {s.unit}"
        )
    ok = ratio <= TARGET_LAB_TIME and worst_z <= 3.0
    print(
        f"  requirement: lab time ≤ {TARGET_LAB_TIME:.0%} of the paper's ({ratio:.1%}) and no designed σ above the paper's beyond 3σ of "
        f"the comparison (worst {worst_z:+.2f}σ) -> {'PASS' if ok else 'FAIL'}"
    )
    return ok


def part_c(args) -> bool:
    print(f"\nC. scaling: {args.scaling} devices with 1 and with 2 workers; before: {_uptime()}")
    times = {}
    for workers in (1, 2):
        config_path = _config(
            args.out, f"scaling{workers}", "device-coarse", "device-fine", args.scaling, args.sample_rate, first_seed=5001
        )
        out = args.out / f"scaling-{workers}-{int(time.time())}"
        config = load_campaign(config_path)
        t0 = time.perf_counter()
        run_campaign(config, out, workers=workers)
        times[workers] = time.perf_counter() - t0
        print(f"  {workers} worker(s): {times[workers]:.1f} s ({times[workers] / args.scaling:.2f} s per calibration); {_uptime()}")
    speedup = times[1] / times[2]
    print(
        f"  requirement: 2 workers ≥ {TARGET_SPEEDUP}× faster than 1: {speedup:.2f}× -> {'PASS' if speedup >= TARGET_SPEEDUP else 'FAIL'}"
    )
    return speedup >= TARGET_SPEEDUP


def part_d(args) -> None:
    """Diagnosed tasks in this process: CPU per task, tasks per CPU-second, the rows' digest (see the module docstring)."""
    from stableins.campaign.task import TaskData, run_task

    config = load_campaign(
        _config(
            args.out,
            "in-process",
            "device-coarse",
            "device-fine",
            args.in_process + 1,
            args.sample_rate,
            args.first_seed - 1,
            diagnose=True,
        )
    )
    tasks = config.tasks()
    data = TaskData(config)
    run_task(tasks[0], data)  # warm-up: imports, procedure caches
    rows = []
    c0 = time.process_time()
    for task in tasks[1:]:
        rows += [{k: v for k, v in row.items() if not k.endswith("_s")} for row in run_task(task, data)]
    cpu = (time.process_time() - c0) / args.in_process
    digest = hashlib.sha256(json.dumps(rows, sort_keys=True, default=repr).encode()).hexdigest()
    print(
        f"D. {args.in_process} diagnosed tasks in one process (seeds {args.first_seed}..{args.first_seed + args.in_process - 1}, "
        f"{os.environ.get('OPENBLAS_NUM_THREADS', '?')} BLAS thread): {cpu:.3f} s of CPU per task, {1 / cpu:.2f} tasks per CPU-second; "
        f"1,000 tasks on 2 idle workers: {1000 * cpu / 2 / 60:.1f} min (target 1.5 min: ≤ 0.18 s per task); rows sha256 {digest[:16]}; "
        f"{_uptime()}"
    )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--devices", type=int, default=1000)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", type=Path, default=Path("campaign-bench"), help="campaign directories (kept; resumed)")
    parser.add_argument("--designed", type=Path, help="directory of bench_design.py --out (part B)")
    parser.add_argument("--designed-devices", type=int, default=1000)
    parser.add_argument("--scaling", type=int, default=0, help="devices of the 1-vs-2-worker comparison (0 skips)")
    parser.add_argument("--sample-rate", type=float, default=10.0)
    parser.add_argument("--diagnose", action="store_true", help="part A's tasks also diagnose (simulate → calibrate → diagnose, issue 30)")
    parser.add_argument("--skip-paper", action="store_true", help="part C only")
    parser.add_argument("--in-process", type=int, default=0, help="part D only: N diagnosed tasks in this process (issue 30)")
    parser.add_argument("--first-seed", type=int, default=2, help="part D's first seed (the one before is its warm-up)")
    args = parser.parse_args()
    if args.in_process:
        part_d(args)
        return 0
    ok = True
    paper: dict = {}
    if not args.skip_paper:
        ok, paper = part_a(args)
        if args.designed is not None:
            ok = part_b(args, paper) and ok
    if args.scaling:
        ok = part_c(args) and ok
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
