"""Run every benchmark at small fixed-seed settings, and compare two such runs figure by figure.

``run_all.py --quick --out DIR`` runs each ``benchmarks/bench_*.py`` with the flags of the table ``QUICK``
below (fewer seeds, shorter records, fixed seeds), under ``nice -n 10`` (the machine is shared), one after the
other.  Each benchmark's standard output and error go to ``DIR/<name>.txt``; ``DIR/index.json`` holds, per
benchmark, the exact command line, the wall time, the CPU time and the exit status, and the commit and Python of the run.

``run_all.py --compare BEFORE AFTER`` reads two such directories and reports, per benchmark:

* ``identical``: the two outputs are the same text (absolute paths masked, timings aside);
* ``equal within rtol``: the same lines with every number equal within ``--rtol`` (relative, default 1e-9);
* ``different``: the first lines that differ, with the numbers that differ.

Wall-clock figures (a number followed by a time unit ``s``/``ms``/``µs``/``min`` or a rate ``…/s``, and the
figures a benchmark's ``volatile`` patterns name, see ``QUICK``) are not compared as figures: they are printed
as an after/before speed ratio.  The exit status is 1 when any figure differs beyond the tolerance, a
benchmark's exit status changed, or a benchmark is missing from one run.

Usage::

    .venv/bin/python benchmarks/run_all.py --quick --out /tmp/bench-before
    .venv/bin/python benchmarks/run_all.py --quick --out /tmp/bench-after [--only bench_truth bench_budget]
    .venv/bin/python benchmarks/run_all.py --compare /tmp/bench-before /tmp/bench-after [--rtol 1e-9]
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import os
import platform
import re
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BENCHMARKS = ROOT / "benchmarks"


@dataclass(frozen=True)
class Quick:
    """The quick settings of one benchmark.

    Attributes
    ----------
    arguments
        Command-line arguments after the script; ``{work}`` is replaced by a scratch directory of its own
        (removed after the run).
    why
        What the settings keep and what they cut, against the benchmark's defaults.
    volatile
        Regular expressions naming run-to-run varying figures (wall times, rates and ratios of times):
        every number inside a match (inside its first group if it has groups) is reported with the timings,
        never compared.  Found by comparing two quick runs of the same commit.
    unordered
        Regular expressions of lines whose order varies run to run (a table sorted by time): left out of the
        comparison.
    """

    arguments: tuple[str, ...]
    why: str
    volatile: tuple[str, ...] = field(default=())
    unordered: tuple[str, ...] = field(default=())


# The quick table: one entry per benchmarks/bench_*.py (run_all refuses to run with a script missing here).
# Wall times are those of --quick on the 2-core development machine under nice -n 10 (see benchmarks/README.md).
QUICK: dict[str, Quick] = {
    "bench_bad_input_limits": Quick(
        ("--megabytes", "16"),
        "16 MB long line / JSON / declared-rows files instead of 256 MB",
        volatile=(r"\s{2,}\d+\s+(\d+\.\d+)\s+\d+",),  # the 'time [s]' column of the table
    ),
    "bench_fleet": Quick(
        ("--units", "20", "--records", "5"),
        "20 units x 5 records instead of 1,000 x 20 (the pages' times are not the acceptance figure at this size)",
        volatile=(
            r"^built .*: ([\d.]+ s)$",
            r"load average of the machine: (.*)$",
            r"^/\S*\s+\d+ KiB\s+(.*)$",
            r"^/fleet as served\s+(.*)$",
            r"^slowest page: (.*)$",
        ),
    ),
    "bench_cli": Quick(
        ("--dir", "{work}", "--rate", "10", "--repeat", "1"),
        "the system record at 10 Hz instead of 100 Hz, one run of each command and read instead of the best of 3",
        volatile=(
            r"^(?:calibrate-\w+|diagnose|report|help|import)\s+(.*)$",  # the table: times and their ratios
            r"load average ([\d.]+)",
            r"^setup: .*: (.*)$",
            r"^stage only .*: (.*)$",
        ),
    ),
    "bench_budget": Quick(("--seed", "13"), "the default run (one device world, one synthetic day at 1 Hz); seed pinned"),
    "bench_campaign": Quick(
        ("--devices", "4", "--out", "{work}"),
        "4 devices of the paper procedure instead of 1000, no designed procedure, no scaling run",
        volatile=(r"ran \d+ tasks.*$", r"^A\. .*$"),  # wall times, per-calibration time and the uptime lines
    ),
    "bench_day_record": Quick(
        ("--hours", "0.5", "--repeat", "1", "--dir", "{work}"),
        "half an hour at 100 Hz instead of 24 h, one repetition",
        volatile=(r"\d[\d.]*\.\.\s*\d[\d.]*", r"writer / raw = [\d.]+"),  # best..worst of the baselines, their ratios
    ),
    "bench_cai_table3": Quick(("--seeds", "2", "--rate", "10"), "2 sessions at 10 Hz instead of 10 at 100 Hz (same dwell means)"),
    "bench_design": Quick(("--quick",), "the bound of the paper procedure only (no optimization)"),
    "bench_demo_loop": Quick(("--seed", "2018", "Kcc_xxy=6e-6"), "one hidden-effect case (Kcc_xxy) of the four; the demo itself unchanged"),
    "bench_device_montecarlo": Quick(
        ("--trials", "1000", "--sim-devices", "2", "--workers", "1", "--seed", "20260101"),
        "1,000 Part A trials (the minimum) instead of 10,000; 2 simulator devices instead of 48; one worker",
    ),
    "bench_device_thermal": Quick(("--seeds", "2", "--first", "1"), "2 thermal sessions instead of 20"),
    "bench_device_gsensitivity": Quick(("--seeds", "2"), "2 sessions with g-sensitivity and 2 clean ones instead of 20 each"),
    "bench_discovery_false_alarms": Quick(("--seeds", "2"), "2 sessions per case (clean, 4σ, 5σ, each outside effect) instead of 20"),
    "bench_fuzz": Quick(
        ("--scale", "0.05", "--seed", "7"),
        "5 % of the cases (about 120), hypothesis seed 7 instead of the clock",
        volatile=(r"\d\s+(\d+\.\d)$",),  # the last column of the table: seconds per kind of input
    ),
    "bench_history_concurrency": Quick(
        ("--trials", "5", "--writers", "4", "--kills", "5", "--seed", "14"), "5 trials of 4 writers, 5 kills"
    ),
    "bench_journal": Quick((), "the default run (its figures are durations and rates)", volatile=(r"durability costs ([\d.]+) %",)),
    "bench_navigation_budget": Quick(("--days", "2", "--rate", "0.1"), "2 days with the simulator at 0.1 Hz instead of 5 days at 1 Hz"),
    "bench_noise_device": Quick(("--seeds", "2", "--workers", "1", "--first-seed", "1"), "2 seeds per case instead of 40; one worker"),
    "bench_paper_table4": Quick(("--rate", "1", "--seed", "1"), "one sidereal day at 1 Hz instead of 100 Hz"),
    "bench_real_data": Quick(("--seeds", "2"), "2 static logs for the false-split rate instead of 10; the real logs unchanged"),
    "bench_simulator": Quick(("--hours", "0.5"), "half an hour at 100 Hz instead of 24 h", volatile=(r"simulator/floor = ([\d.]+)",)),
    "bench_suite_under_load": Quick(
        ("--runs", "1", "--load", "1", "--", "-q", "-n", "0", "tests/test_layers.py"),
        "one run of tests/test_layers.py under one busy process instead of five runs of the suite under four",
        volatile=(r"; (\d+) s;",),
    ),
    "bench_system_diagnose": Quick(("--seeds", "2", "--first", "1"), "2 seeds per world instead of 24"),
    "bench_system_drift": Quick(("--seeds", "2", "--first", "1"), "2 seeds instead of 20"),
    "bench_system_bias_drift": Quick((), "the default run: the bound only (part 2, the stage's channels, is --seeds N)"),
    "bench_flicker_below_record": Quick((), "the default run (closed forms, under a second)"),
    "bench_system_polar": Quick(("--seeds", "2"), "2 seeds per case instead of 40 (the false-refusal and tilt figures)"),
    "bench_system_platform": Quick((), "the default run (two ODE integrations of a day, about 2 s)", volatile=(r"^\((\d+) s\)$",)),
    "bench_system_equatorial": Quick(
        ("--seeds", "1", "--first", "11", "--drifts", "0.05"),
        "1 seed and the gyro world's drift instead of 6 seeds and 4 drifts",
        volatile=(r"\d\s+(\d+)$", r"^(\d+) s$"),  # the seconds column of the table, the total
    ),
    "bench_system_null_law": Quick(
        ("--seeds", "2", "--first", "7001", "--law-records", "1", "--draws", "200"),
        "2 white records instead of 60, one record's law drawn 200 times instead of two records' 2000 (issue 25)",
    ),
    "bench_system_sigma": Quick(("--seeds", "2", "--first", "100"), "2 seeds per world and mode instead of 40 (all worlds and modes)"),
    "bench_system_thermal": Quick(
        ("--cases", "thermal", "kcc", "clean", "--seeds", "2", "--first", "100"),
        "the daily-cycle and Kcc_xxy cases and 2 clean records per temperature history instead of all six cases with 20 seeds",
        volatile=(r"\((\d+) s\)",),  # the wall time of each history
    ),
    "bench_system_stream": Quick(
        ("--dir", "{work}", "--days", "1", "--repeat", "1"),
        "one day at 100 Hz instead of a week, one timed run",
        volatile=(r"ratio ([\d.]+) to the h5py", r"([\d.]+) to the reader's", r"stage ratio ([\d.]+)"),  # ratios of times
        unordered=(r"^  [\w(].{46,}\s\d+\.\d{3} s$",),  # "where the stage's time goes", sorted by time
    ),
    "bench_run_truth_drift": Quick(("--seeds", "1"), "1 seed of run --truth + calibrate drift instead of 20"),
    "bench_truth": Quick(("--seed", "2018"), "the default run; seed pinned"),
    "bench_two_position": Quick(("--seeds", "5"), "5 seeds per case instead of 100"),
    "bench_worlds": Quick(("--seeds", "2", "--first-seed", "1"), "2 device sessions per world instead of 10"),
    "bench_independent_system": Quick(
        ("--seeds", "1", "--worlds", "white", "quartz", "--diagnose", "white"), "1 record per world (white, quartz) instead of 20 in four"
    ),
    "bench_lever_arms": Quick(("--seeds", "1", "--cai-seeds", "1", "--clean", "2"), "1 seed per case (2 clean) instead of 4, 2 and 20"),
    "bench_systematic": Quick(
        ("--seeds", "4", "--mc-hours", "4", "--hours", "8", "--speed-hours", "2"),
        "8-h rank and drift record, 4 Monte Carlo seeds of 4 h, 2-h speed record instead of 24 h, 40 seeds of 8 h, a day",
    ),
}

TIME_UNIT = r"(?:s|ms|µs|us|ns|min|seconds?|sec)\b"
# rates of work per wall-clock second, not physical units (m/s, rad/s stay figures)
_WORK = r"(?:[kMG]?samples?|[kMG]i?B|pieces?|cases?|records?|rows?|files?|trials?|steps?)"
RATE_UNIT = rf"{_WORK}\s?/\s?s\b|/(?:sample|step|case)\b|[×x]\s*(?:real[- ]time|faster)"
NUMBER = r"(?<!\w)(?<!\w\.)[-+−]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+−]?\d+)?"  # not the digits of a name (phi_1s, x1, K2_x)
_NUMBER = re.compile(NUMBER)
_TIMING = re.compile(rf"({NUMBER})(?=\s*(?:{TIME_UNIT}|{RATE_UNIT}))")
_PATH = re.compile(r"(?<![\w.~])/[^\s'\"(),;:\]]+")
_CLOCK = re.compile(
    r"\d{4}-\d\d-\d\d(?:[T ]\d\d:\d\d(?::\d\d(?:\.\d+)?)?(?:Z|[+-]\d\d:?\d\d)?)?"  # ISO 8601 date (and time)
    r"|\b\d{8}T\d{4,6}Z?"  # compact stamps (history file names)
    r"|\b(?=[0-9a-f]*[a-f])(?=[0-9a-f]*\d)[0-9a-f]{8,}\b"  # hex digests and ids
)


def scripts() -> list[str]:
    """Names of the benchmark scripts, ``bench_*.py`` in ``benchmarks/`` (without the suffix)."""
    return sorted(path.stem for path in BENCHMARKS.glob("bench_*.py"))


# ----------------------------------------------------------------------------------------------- running


def command_of(name: str, work: Path) -> list[str]:
    """The command line of one benchmark's quick run (``nice -n 10``, this interpreter, repository root)."""
    arguments = [a.replace("{work}", str(work)) for a in QUICK[name].arguments]
    return ["nice", "-n", "10", sys.executable, f"benchmarks/{name}.py", *arguments]


def git_commit() -> str:
    done = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "HEAD"], capture_output=True, text=True)
    dirty = subprocess.run(["git", "-C", str(ROOT), "status", "--porcelain", "--untracked-files=no"], capture_output=True, text=True)
    return done.stdout.strip() + ("+dirty" if dirty.stdout.strip() else "") if done.returncode == 0 else "unknown"


def _children_cpu() -> float:
    """User + system CPU seconds of the finished child processes (wall time swings with the machine's load)."""
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def run_quick(out: Path, only: list[str] | None, timeout: float) -> int:
    """Run the quick benchmarks into ``out``; returns 1 if one failed or timed out."""
    names = scripts()
    missing = [n for n in names if n not in QUICK]
    if missing:
        print(f"run_all: no quick settings for {', '.join(missing)}: add them to QUICK in benchmarks/run_all.py", file=sys.stderr)
        return 2
    if only:
        unknown = [n for n in only if n not in names]
        if unknown:
            print(f"run_all: --only: no benchmark named {', '.join(unknown)} (known: {', '.join(names)})", file=sys.stderr)
            return 2
        names = [n for n in names if n in only]
    out.mkdir(parents=True, exist_ok=True)
    index_path = out / "index.json"
    index = json.loads(index_path.read_text()) if index_path.exists() and only else {}
    index.update(
        {
            "commit": git_commit(),
            "python": platform.python_version(),
            "started": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
            "cwd": str(ROOT),
        }
    )
    results = index.setdefault("benchmarks", {})
    env = {**os.environ, "MPLBACKEND": "Agg", "PYTHONPATH": str(ROOT), "PYTHONHASHSEED": "0"}
    failed = 0
    for name in names:
        work = Path(tempfile.mkdtemp(prefix=f"stableins-{name}-"))
        command = command_of(name, work)
        print(f"{name:<30} ", end="", flush=True)
        start, cpu = time.perf_counter(), _children_cpu()
        with (out / f"{name}.txt").open("w") as sink:
            try:
                status = subprocess.run(command, cwd=ROOT, env=env, stdout=sink, stderr=subprocess.STDOUT, timeout=timeout).returncode
            except subprocess.TimeoutExpired:
                status = "timeout"
        wall, cpu = time.perf_counter() - start, _children_cpu() - cpu
        shutil.rmtree(work, ignore_errors=True)
        results[name] = {
            "command": command,
            "shell": " ".join(command),
            "wall_seconds": round(wall, 2),
            "cpu_seconds": round(cpu, 2),
            "exit_status": status,
        }
        failed += status != 0
        print(f"{wall:7.1f} s wall {cpu:7.1f} s CPU  exit {status}", flush=True)
        index_path.write_text(json.dumps(index, indent=2) + "\n")
    print(f"total {sum(r['wall_seconds'] for r in results.values()):.0f} s; outputs and index.json in {out}")
    return 1 if failed else 0


# ----------------------------------------------------------------------------------------------- comparing


@dataclass(frozen=True)
class Line:
    """One output line split into its text (numbers replaced by ``#``), its figures and its timings."""

    template: str
    figures: tuple[float, ...]
    timings: tuple[float, ...]


def _float(text: str) -> float:
    return float(text.replace("−", "-"))


def parse_line(text: str, volatile: tuple[str, ...] = ()) -> Line:
    """Split a line into template, figures and timings.

    Absolute paths, clock readings (ISO 8601 dates and times, compact stamps) and hex digests are masked (their digits are not figures)
    and white space is not compared (a column's padding follows the width of a timing).  A number
    followed by a time unit or a rate (``…/s``, ``…/sample``, ``× real time``) is a timing; so is every number inside a match of one of the
    ``volatile`` patterns (inside its first group when it has groups, else inside the whole match).
    """
    text = _CLOCK.sub("<clock>", _PATH.sub("<path>", text.rstrip()))
    spans = [m.span(1) for m in _TIMING.finditer(text)]
    for pattern in volatile:
        spans += [m.span(1 if m.re.groups else 0) for m in re.finditer(pattern, text)]
    figures, timings, pieces, last = [], [], [], 0
    for m in _NUMBER.finditer(text):
        timing = any(a <= m.start() and m.end() <= b for a, b in spans)
        (timings if timing else figures).append(_float(m.group()))
        pieces.append(text[last : m.start()] + ("~" if timing else "#"))
        last = m.end()
    pieces.append(text[last:])
    return Line("".join("".join(pieces).split()), tuple(figures), tuple(timings))


def close(a: float, b: float, rtol: float) -> bool:
    """``a`` and ``b`` equal within the relative tolerance (NaN equals NaN)."""
    if math.isnan(a) or math.isnan(b):
        return math.isnan(a) and math.isnan(b)
    return a == b or abs(a - b) <= rtol * max(abs(a), abs(b))


@dataclass(frozen=True)
class Comparison:
    """The comparison of one benchmark's two outputs."""

    name: str
    verdict: str  # "identical", "equal within rtol", "different", "missing"
    details: tuple[str, ...]
    timings: tuple[tuple[float, float], ...]


def compare_outputs(
    name: str, before: str, after: str, *, rtol: float, volatile: tuple[str, ...] = (), unordered: tuple[str, ...] = ()
) -> Comparison:
    """Compare two outputs of a benchmark figure by figure (timings, volatile figures and unordered lines aside)."""
    if unordered:
        before, after = ("\n".join(t for t in x.splitlines() if not any(re.search(u, t) for u in unordered)) for x in (before, after))
    a = [parse_line(t, volatile) for t in before.splitlines()]
    b = [parse_line(t, volatile) for t in after.splitlines()]
    timings = tuple(
        (x, y)
        for la, lb in zip(a, b, strict=False)
        if len(la.timings) == len(lb.timings)
        for x, y in zip(la.timings, lb.timings, strict=True)
    )
    details: list[str] = []
    exact = True
    for k, (la, lb) in enumerate(zip(a, b, strict=False)):
        if la.template != lb.template or len(la.figures) != len(lb.figures):
            details.append(f"line {k + 1} text differs:\n      before: {before.splitlines()[k]}\n      after:  {after.splitlines()[k]}")
        else:
            off = [(x, y) for x, y in zip(la.figures, lb.figures, strict=True) if not close(x, y, rtol)]
            if off:
                shown = ", ".join(f"{x:g} -> {y:g}" for x, y in off[:4])
                details.append(f"line {k + 1}: {shown}\n      before: {before.splitlines()[k]}\n      after:  {after.splitlines()[k]}")
            exact = exact and la.figures == lb.figures
        if len(details) >= 3:
            break
    if len(a) != len(b) and len(details) < 3:
        details.append(f"{len(a)} lines before, {len(b)} after")
    if details:
        return Comparison(name, "different", tuple(details), timings)
    return Comparison(name, "identical" if exact else "equal within rtol", (), timings)


def _ratio(timings: tuple[tuple[float, float], ...]) -> str:
    pairs = [(x, y) for x, y in timings if x > 0 and y > 0]
    if not pairs:
        return ""
    logs = [math.log(y / x) for x, y in pairs]
    return f"timings after/before: geometric mean {math.exp(sum(logs) / len(logs)):.2f} over {len(pairs)} figures"


def compare_runs(before: Path, after: Path, rtol: float) -> int:
    """Print the comparison of two run directories; 1 if a figure differs beyond ``rtol``."""
    index = [json.loads((d / "index.json").read_text()) for d in (before, after)]
    print(f"before: {before} (commit {index[0].get('commit')}); after: {after} (commit {index[1].get('commit')}); rtol {rtol:g}")
    names = sorted(set(index[0]["benchmarks"]) | set(index[1]["benchmarks"]))
    failed = False
    for name in names:
        runs = [ix["benchmarks"].get(name) for ix in index]
        if None in runs:
            print(f"{name:<30} missing from {'before' if runs[0] is None else 'after'}")
            failed = True
            continue
        texts = [(d / f"{name}.txt").read_text(errors="replace") for d in (before, after)]
        quick = QUICK.get(name, Quick((), ""))
        result = compare_outputs(name, texts[0], texts[1], rtol=rtol, volatile=quick.volatile, unordered=quick.unordered)
        status = [r["exit_status"] for r in runs]
        walls = [r["wall_seconds"] for r in runs]
        verdict = result.verdict if status[0] == status[1] else f"{result.verdict}; exit status {status[0]} -> {status[1]}"
        failed = failed or result.verdict == "different" or status[0] != status[1]
        cpus = [r.get("cpu_seconds") for r in runs]
        cpu = f", CPU {cpus[0]:.1f} s -> {cpus[1]:.1f} s" if None not in cpus else ""
        print(f"{name:<30} {verdict:<20} wall {walls[0]:7.1f} s -> {walls[1]:7.1f} s ({walls[1] / max(walls[0], 1e-9):.2f}×){cpu}")
        if [_PATH.sub("<path>", a) for a in runs[0]["command"][4:]] != [_PATH.sub("<path>", a) for a in runs[1]["command"][4:]]:
            print(f"    command differs: {runs[0]['shell']}  ->  {runs[1]['shell']}")
        for detail in result.details:
            print(f"    {detail}")
        if ratio := _ratio(result.timings):
            print(f"    {ratio}")
    print("result: " + ("figures DIFFER" if failed else "every figure equal within tolerance"))
    return 1 if failed else 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    action = parser.add_mutually_exclusive_group(required=True)
    action.add_argument("--quick", action="store_true", help="run every benchmark at the quick settings of QUICK")
    action.add_argument("--compare", nargs=2, type=Path, metavar=("BEFORE", "AFTER"), help="compare two --quick runs")
    action.add_argument("--list", action="store_true", help="print the quick table (benchmark, command, why)")
    parser.add_argument("--out", type=Path, help="directory of a --quick run's outputs and index.json")
    parser.add_argument("--only", nargs="+", metavar="NAME", help="run only these benchmarks (bench_x); index.json is updated")
    parser.add_argument("--timeout", type=float, default=1800.0, help="seconds allowed per benchmark (default 1800)")
    parser.add_argument("--rtol", type=float, default=1e-9, help="relative tolerance of --compare (default 1e-9)")
    args = parser.parse_args(argv)
    if args.list:
        for name in scripts():
            quick = QUICK.get(name)
            print(f"{name:<30} {' '.join(quick.arguments) if quick else '(missing)':<60} {quick.why if quick else ''}")
        return 0
    if args.quick:
        if args.out is None:
            parser.error("--quick needs --out DIR")
        return run_quick(args.out, args.only, args.timeout)
    return compare_runs(*args.compare, rtol=args.rtol)


if __name__ == "__main__":
    sys.exit(main())
