"""Run the test suite several times under a background CPU load and print the pass counts (issue 31).

Issue 31's acceptance: "the full suite passes 5 of 5 under a background load of 4 processes on 2 cores".  This
command makes that load itself (``--load`` processes, each a busy loop of pure Python at the default priority, started
before the first run and stopped after the last) and runs ``pytest`` ``--runs`` times, one after the other, each in a
fresh process, printing per run its exit status and its pass/fail/skip/error counts (pytest's closing line), then
how many runs passed.

Usage::

    python benchmarks/bench_suite_under_load.py                              # the whole suite, 5 runs, 4 loaders
    python benchmarks/bench_suite_under_load.py --runs 5 -- -m "not slow" -n 0 tests/test_tcp_driver.py
    python benchmarks/bench_suite_under_load.py --runs 2 --load 0 -- tests/test_layers.py   # no load, for comparison

Arguments after ``--`` go to pytest (default: the whole suite as ``make test`` runs it, ``-n auto``).
"""

from __future__ import annotations

import argparse
import multiprocessing
import re
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: pytest's closing line, e.g. "12 passed, 1 skipped in 3.2s" or "1 failed, 11 passed in 4.0s".
SUMMARY = re.compile(r"(\d+) (passed|failed|skipped|errors?|xfailed|xpassed|deselected|warnings?)")
#: The whole closing line: counts, then the time, between optional rules of '='.
CLOSING = re.compile(rf"=*\s*{SUMMARY.pattern}(, {SUMMARY.pattern})*( in [\d.]+s.*)?\s*=*")


def burn(stop: multiprocessing.synchronize.Event) -> None:  # type: ignore[name-defined]
    """A background load: pure-Python arithmetic until ``stop`` is set."""
    x = 0
    while not stop.is_set():
        for k in range(100_000):
            x = (x + k * k) % 1_000_003


def counts(output: str) -> dict[str, int]:
    """The counts of pytest's last summary line in ``output``."""
    lines = [line for line in output.splitlines() if CLOSING.fullmatch(line.strip())]
    if not lines:
        return {}
    found: dict[str, int] = {}
    for number, word in SUMMARY.findall(lines[-1]):
        if not word.startswith("warning"):
            found["errors" if word.startswith("error") else word] = int(number)
    return found


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--runs", type=int, default=5, help="how many times to run the suite (default 5)")
    parser.add_argument("--load", type=int, default=4, help="background busy processes (default 4)")
    parser.add_argument("pytest_args", nargs="*", help="arguments for pytest after '--' (default: the whole suite, -n auto)")
    args = parser.parse_args()
    pytest_args = args.pytest_args or ["-n", "auto", "tests"]
    stop = multiprocessing.Event()
    loaders = [multiprocessing.Process(target=burn, args=(stop,), daemon=True) for _ in range(args.load)]
    for process in loaders:
        process.start()
    print(f"pytest {' '.join(pytest_args)}: {args.runs} runs under a background load of {args.load} busy processes "
          f"({multiprocessing.cpu_count()} cores)")  # fmt: skip
    passed_runs = 0
    try:
        for run in range(1, args.runs + 1):
            started = time.perf_counter()
            result = subprocess.run(
                [sys.executable, "-m", "pytest", "-p", "no:cacheprovider", *pytest_args],  # -q comes from pyproject's addopts
                cwd=ROOT,
                capture_output=True,
                text=True,
                check=False,
            )
            found = counts(result.stdout + result.stderr)
            ok = result.returncode == 0 and found.get("failed", 0) == 0 and found.get("errors", 0) == 0
            passed_runs += ok
            summary = ", ".join(f"{n} {w}" for w, n in found.items()) or "no summary line"
            print(f"run {run}: exit {result.returncode}; {summary}; {time.perf_counter() - started:.0f} s; {'PASS' if ok else 'FAIL'}")
            if not ok:
                failures = [line for line in result.stdout.splitlines() if line.startswith(("FAILED", "ERROR"))]
                for line in failures[:20]:
                    print("   ", line)
    finally:
        stop.set()
        for process in loaders:
            process.join(timeout=10)
            if process.is_alive():
                process.terminate()
    print(f"passed {passed_runs} of {args.runs} runs under a load of {args.load}")
    return 0 if passed_runs == args.runs else 1


if __name__ == "__main__":
    sys.exit(main())
