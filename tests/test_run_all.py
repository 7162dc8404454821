"""The comparison logic of benchmarks/run_all.py (figures against timings, tolerance), not the benchmarks themselves."""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def run_all():
    spec = importlib.util.spec_from_file_location("run_all", ROOT / "benchmarks" / "run_all.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules["run_all"] = module
    spec.loader.exec_module(module)
    return module


def test_quick_table_covers_every_benchmark(run_all):
    assert set(run_all.QUICK) == set(run_all.scripts())
    assert len(run_all.QUICK) >= 16


def test_timings_are_separated_from_figures(run_all):
    line = run_all.parse_line("stage: 1.234 s (5.6 ns/sample), ratio 1.70, 120 MB/s, χ²_ν = 1.02, 3/20 flagged, 0.5 h")
    assert line.figures == (1.70, 1.02, 3, 20, 0.5)  # 0.5 h is a record length, 3/20 a count
    assert line.timings == (1.234, 5.6, 120.0)
    assert run_all.parse_line("writer at 41.5× real time").timings == (41.5,)
    physical = run_all.parse_line("g = 9.80 m/s², random walk 1.3e-06 m/s^2/sqrt(s), Earth rate 7.29e-05 rad/s")
    assert physical.figures == (9.80, 1.3e-06, 2, 7.29e-05)
    assert physical.timings == ()
    named = run_all.parse_line("phi_1s     1.3319e-04  2.54e-06  agrees; K2_x 3")
    assert named.figures == (1.3319e-04, 2.54e-06, 3)
    assert named.timings == ()
    assert run_all.parse_line("took 3 min and 12 ms").timings == (3.0, 12.0)
    assert run_all.parse_line("rms z −1.5e-3").figures == (-1.5e-3,)
    # a column's padding follows the width of the timing before it
    assert run_all.parse_line("source:    9.71 s  (a)").template == run_all.parse_line("source:   49.78 s  (a)").template
    assert run_all.parse_line("stage ( 97.7 ns/sample)").template == run_all.parse_line("stage (145.5 ns/sample)").template


def test_paths_are_masked(run_all):
    a = run_all.parse_line("wrote /tmp/stableins-bench_x-ab12/static-1d-100Hz.h5 (0.21 GB)")
    b = run_all.parse_line("wrote /tmp/stableins-bench_x-zz98/static-1d-100Hz.h5 (0.21 GB)")
    assert a == b
    assert a.figures == (0.21,)
    done = run_all.parse_line("the run is finished (completed 2026-11-23T03:36:06+00:00): 3 files")
    assert done.figures == (3,)
    recal = "record in force: 20261123T040127Z-72c7824f.json; prior digest 064cff3f2ad8; (alone, 2026-11-23) 8616000 samples"
    assert run_all.parse_line(recal).figures == (8616000,)


def test_identical_within_tolerance_and_different(run_all):
    before = "rms z 1.0000000000 over 40 seeds\nwall 10.0 s\n"
    assert run_all.compare_outputs("x", before, before, rtol=1e-9).verdict == "identical"
    slower = "rms z 1.0000000000 over 40 seeds\nwall 25.0 s\n"
    timed = run_all.compare_outputs("x", before, slower, rtol=1e-9)
    assert timed.verdict == "identical"
    assert timed.timings == ((10.0, 25.0),)
    nudged = "rms z 1.0000000001 over 40 seeds\nwall 10.0 s\n"
    assert run_all.compare_outputs("x", before, nudged, rtol=1e-9).verdict == "equal within rtol"
    assert run_all.compare_outputs("x", before, nudged, rtol=1e-12).verdict == "different"
    changed = run_all.compare_outputs("x", before, "rms z 1.1 over 40 seeds\nwall 10.0 s\n", rtol=1e-9)
    assert changed.verdict == "different"
    assert "line 1: 1 -> 1.1" in changed.details[0]


def test_text_and_length_changes_are_differences(run_all):
    assert run_all.compare_outputs("x", "verdict PASS 3\n", "verdict FAIL 3\n", rtol=1e-9).verdict == "different"
    assert run_all.compare_outputs("x", "a 1\nb 2\n", "a 1\n", rtol=1e-9).verdict == "different"


def test_volatile_lines_are_timings(run_all):
    before, after = "peak RSS 120 MiB\nrank 7\n", "peak RSS 131 MiB\nrank 7\n"
    assert run_all.compare_outputs("x", before, after, rtol=1e-9).verdict == "different"
    result = run_all.compare_outputs("x", before, after, rtol=1e-9, volatile=(r"peak RSS \d+",))
    assert result.verdict == "identical"
    assert result.timings == ((120.0, 131.0),)
    # a group marks only the numbers inside it: the exit status stays a figure
    table = r"^case \w+\s+\d+\s+(\d+\.\d+\s+\d+)"
    row = run_all.parse_line("case a   2   0.47   95", (table,))
    assert row.figures == (2,)
    assert row.timings == (0.47, 95.0)
    changed = run_all.compare_outputs("x", "case a   2   0.47   95\n", "case a   0   0.52   99\n", rtol=1e-9, volatile=(table,))
    assert changed.verdict == "different"


def test_compare_runs_exit_status(run_all, tmp_path, capsys):
    def write(directory: Path, text: str, status: int) -> None:
        directory.mkdir()
        command = ["nice", "-n", "10", "python", "benchmarks/bench_x.py"]
        entry = {"command": command, "shell": " ".join(command), "wall_seconds": 2.0, "exit_status": status}
        (directory / "index.json").write_text(json.dumps({"commit": "c", "benchmarks": {"bench_x": entry}}))
        (directory / "bench_x.txt").write_text(text)

    write(tmp_path / "a", "z 1.0 in 2.0 s\n", 0)
    write(tmp_path / "b", "z 1.0 in 4.0 s\n", 0)
    write(tmp_path / "c", "z 1.5 in 2.0 s\n", 0)
    write(tmp_path / "d", "z 1.0 in 2.0 s\n", 1)
    assert run_all.compare_runs(tmp_path / "a", tmp_path / "b", 1e-9) == 0
    assert "geometric mean 2.00" in capsys.readouterr().out
    assert run_all.compare_runs(tmp_path / "a", tmp_path / "c", 1e-9) == 1
    assert run_all.compare_runs(tmp_path / "a", tmp_path / "c", 0.6) == 0
    assert run_all.compare_runs(tmp_path / "a", tmp_path / "d", 1e-9) == 1


def test_unordered_lines_are_left_out(run_all):
    before = "where the time goes:\n  reads 0.770 s\n  filter 0.059 s\nrank 9\n"
    after = "where the time goes:\n  filter 0.061 s\n  reads 0.500 s\nrank 9\n"
    assert run_all.compare_outputs("x", before, after, rtol=1e-9).verdict == "different"
    assert run_all.compare_outputs("x", before, after, rtol=1e-9, unordered=(r"^  \w+ [\d.]+ s$",)).verdict == "identical"
    assert (
        run_all.compare_outputs("x", before, after.replace("rank 9", "rank 8"), rtol=1e-9, unordered=(r"^  \w+ [\d.]+ s$",)).verdict
        == "different"
    )
