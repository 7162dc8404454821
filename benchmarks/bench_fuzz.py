"""Fuzz every reader and writer with thousands of generated cases (issue 14 acceptance: 0 / 0 / 0 over ≥ 2,000).

Issue 31 adds every command written since (``tests/fuzz_commands.py``): budget, design, campaign, noise, calibrate poses,
calibrate system --systematic, calibrate drift / thermal / lever, recal --estimate, report --procedure, the newer
procedure kinds, and numeric options given what is not a finite number; and counts hangs (a case that takes longer than
``--hang`` seconds).  A kind marked "base refused" has no valid input here (its stage needs a record of its own test):
there only tracebacks, bad exits, files left and hangs count.

The same mutation operators and oracle as ``tests/test_fuzz.py`` (``tests/fuzzing.py``), drawn by hypothesis with a
fresh seed instead of CI's fixed one, and many more of them.  Prints, per kind of input and in total: cases run,
inputs refused (exit 2), inputs accepted, and the four failure counts the acceptance criterion asks for:

* tracebacks (an exception escaped ``stableins.cli.main``, or a library call raised something else than its error),
* bad exits (a status other than 0 or 2 for an input problem),
* bad inputs accepted (exit 0 for an input the documented formats make invalid),
* files left behind (a refused command changed its output directory).

Usage::

    python benchmarks/bench_fuzz.py                  # about 2,400 cases, about a minute or two
    python benchmarks/bench_fuzz.py --scale 3 --seed 7
"""

from __future__ import annotations

import argparse
import random
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

import fuzz_commands as fc  # noqa: E402
import fuzzing as fz  # noqa: E402
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import seed as hypothesis_seed  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

SEEDS = st.integers(0, 2**32 - 1)


def kinds(ws: fz.Workspace) -> list[tuple[str, int, object, object]]:
    """(name, cases at scale 1, strategy, run(drawn) -> Result)."""
    option_values = st.one_of(
        st.sampled_from(fz.TRICKY_OPTION_VALUES),
        st.floats(allow_nan=True, allow_infinity=True).map(repr),
        st.integers(-(2**70), 2**70).map(str),
        st.text(max_size=8),
    )
    return [
        (
            "device CSV, check",
            300,
            st.tuples(st.sampled_from(fz.CSV_OPS), SEEDS),
            lambda d: fz.case_device_csv(ws, random.Random(d[1]), d[0]),
        ),
        (
            "device CSV, calibrate device",
            100,
            st.tuples(st.sampled_from(fz.CSV_OPS), SEEDS),
            lambda d: fz.case_device_csv(ws, random.Random(d[1]), d[0], consumer="calibrate"),
        ),
        (
            "device HDF5, check",
            250,
            st.tuples(st.sampled_from(fz.H5_OPS), SEEDS),
            lambda d: fz.case_h5(ws, random.Random(d[1]), d[0], "device"),
        ),
        (
            "system HDF5, check",
            250,
            st.tuples(st.sampled_from(fz.H5_OPS), SEEDS),
            lambda d: fz.case_h5(ws, random.Random(d[1]), d[0], "system"),
        ),
        (
            "record, check",
            250,
            st.tuples(st.sampled_from(fz.JSON_OPS), SEEDS),
            lambda d: fz.case_record(ws, random.Random(d[1]), d[0], "check"),
        ),
        (
            "record, history --add",
            150,
            st.tuples(st.sampled_from(fz.JSON_OPS), SEEDS),
            lambda d: fz.case_record(ws, random.Random(d[1]), d[0], "history"),
        ),
        (
            "record as --prior of calibrate system",
            50,
            st.tuples(st.sampled_from(fz.JSON_OPS), SEEDS),
            lambda d: fz.case_record(ws, random.Random(d[1]), d[0], "prior"),
        ),
        (
            "plan (procedure.json)",
            200,
            st.tuples(st.sampled_from(fz.JSON_OPS), SEEDS),
            lambda d: fz.case_plan(ws, random.Random(d[1]), d[0]),
        ),
        (
            "procedure (TOML)",
            200,
            st.tuples(st.sampled_from(fz.TOML_OPS), SEEDS),
            lambda d: fz.case_procedure(ws, random.Random(d[1]), d[0]),
        ),
        (
            "--discovery document",
            150,
            st.tuples(st.sampled_from(fz.JSON_OPS), SEEDS),
            lambda d: fz.case_discovery(ws, random.Random(d[1]), d[0]),
        ),
        (
            "protocol replies (TCP)",
            120,
            st.tuples(st.sampled_from(fz.PROTOCOL_OPS), SEEDS),
            lambda d: fz.case_protocol(random.Random(d[1]), d[0]),
        ),
        ("option values", 400, st.tuples(st.integers(0, len(fz.OPTIONS) - 1), option_values), lambda d: fz.case_option(d[0], d[1])),
    ]


#: Cases per newer command at scale 1 (those that write a certificate when the input is valid: fewer).
NEWER_CASES = {"recal --estimate": 20, "report --procedure": 40}


def newer_kinds(ci: fc.CommandInputs) -> list[tuple[str, int, object, object]]:
    """The commands added since the fuzz suite was written (issue 31), same shape as :func:`kinds`."""
    out = []
    for name, ops, case, valid in fc.KINDS:
        label = name if valid else f"{name} (base refused)"
        strategy = st.tuples(st.sampled_from(ops), SEEDS)
        out.append((label, NEWER_CASES.get(name, 80), strategy, lambda d, c=case: c(ci, random.Random(d[1]), d[0])))
    out.append(
        (
            "newer numeric options, not a number",
            150,
            st.tuples(st.integers(0, len(fc.NUMERIC_OPTIONS) - 1), st.sampled_from(fc.NOT_A_NUMBER)),
            lambda d: fc.case_numeric_option(ci, d[0], d[1]),
        )
    )
    return out


def _runner(
    seed: int, examples: int, strategy: object, function: object, name: str, tallies: tuple[fz.Tally, ...], hang: float, hangs: list[str]
) -> object:
    """A hypothesis-driven loop over ``examples`` drawn cases of one kind, each added to the tallies; slow cases to ``hangs``."""

    @hypothesis_seed(seed)
    @settings(max_examples=examples, deadline=None, database=None, suppress_health_check=list(HealthCheck))
    @given(drawn=strategy)
    def one(drawn: object) -> None:
        started = time.perf_counter()
        result = function(drawn)
        if time.perf_counter() - started > hang:
            hangs.append(f"{name}: {result.what} took {time.perf_counter() - started:.0f} s")
        for tally in tallies:
            tally.add(name, result)

    return one


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--scale", type=float, default=1.0, help="multiply the number of cases (1: about 2,400)")
    parser.add_argument("--seed", type=int, default=int(time.time()) % 100000, help="hypothesis seed (default: from the clock)")
    parser.add_argument("--hang", type=float, default=60.0, help="a case slower than this [s] counts as a hang (default 60)")
    parser.add_argument("--only-newer", action="store_true", help="only the commands added since issue 14 (issue 31)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="stableins-fuzz-") as directory:
        ws = fz.Workspace(Path(directory))
        ci = fc.CommandInputs(ws)
        tally = fz.Tally()
        hangs: list[str] = []
        print(f"fuzzing with hypothesis seed {args.seed}, scale {args.scale:g}")
        print(
            f"{'input':<40} {'cases':>6} {'refused':>8} {'accepted':>9} {'tracebacks':>11} {'bad exit':>9} "
            f"{'accepted bad':>13} {'files left':>11} {'s':>6}"
        )
        started = time.perf_counter()
        for name, count, strategy, function in ([] if args.only_newer else kinds(ws)) + newer_kinds(ci):
            part = fz.Tally()
            examples = max(1, int(round(count * args.scale)))

            one = _runner(args.seed, examples, strategy, function, name, (part, tally), args.hang, hangs)
            t0 = time.perf_counter()
            one()
            print(
                f"{name:<40} {part.cases:>6} {part.refused:>8} {part.accepted:>9} {part.tracebacks:>11} {part.bad_exits:>9} "
                f"{part.accepted_bad:>13} {part.files_left:>11} {time.perf_counter() - t0:>6.1f}"
            )
        print(
            f"{'all':<40} {tally.cases:>6} {tally.refused:>8} {tally.accepted:>9} {tally.tracebacks:>11} {tally.bad_exits:>9} "
            f"{tally.accepted_bad:>13} {tally.files_left:>11} {time.perf_counter() - started:>6.1f}"
        )
        print()
        print("acceptance (issues 14, 31): 0 tracebacks, 0 bad inputs accepted, 0 files left, 0 hangs")
        print(
            f"measured: {tally.tracebacks} tracebacks (+{tally.bad_exits} bad exits), {tally.accepted_bad} bad inputs accepted, "
            f"{tally.files_left} files left, {len(hangs)} hangs (cases over {args.hang:g} s) over {tally.cases} cases: "
            f"{'met' if tally.failures == 0 and not hangs else 'NOT met'}"
        )
        for example in tally.examples + hangs:
            print("  ", example[:300])
    return 0 if tally.failures == 0 and not hangs else 1


if __name__ == "__main__":
    sys.exit(main())
