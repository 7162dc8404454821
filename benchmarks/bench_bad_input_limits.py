"""What malicious inputs cost: time and peak memory of the command that refuses them (issue 14 acceptance).

Each case runs ``stableins`` in a fresh process and reports its wall time and its peak resident memory
(``ru_maxrss``), next to the same command on a valid small file (the cost of the imports alone):

* a device CSV with a 256 MB line without a newline (the reader stops after ``MAX_LINE`` characters);
* a CSV header block with a 256 MB comment line;
* a CSV whose trailer declares 1e9 rows;
* device and system HDF5 files (a few hundred kB) whose datasets and ``rows`` attribute declare 1e9 rows
  (HDF5 allocates nothing for chunks never written): ``check`` and ``calibrate system``;
* a 256 MB calibration record (refused by its size before it is read).

Target: every one refused (exit 2) in seconds, at most 256 MB.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

WRAPPER = (
    "import resource, sys, time\n"
    "from stableins import cli\n"
    "t = time.perf_counter()\n"
    "status = cli.main(sys.argv[1:])\n"
    "print('MEASURE', status, time.perf_counter() - t, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, file=sys.stderr)\n"
)


def measure(argv: list[str]) -> tuple[int, float, float, str]:
    """(exit status, seconds, peak RSS [MiB], message) of ``stableins ARGV`` in a fresh process."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    done = subprocess.run([sys.executable, "-c", WRAPPER, *map(str, argv)], capture_output=True, text=True, env=env, timeout=600)
    line = next(x for x in done.stderr.splitlines() if x.startswith("MEASURE"))
    _, status, seconds, rss = line.split()
    message = next((x for x in done.stderr.splitlines() if x.startswith("stableins: error")), "")
    return int(status), float(seconds), int(rss) / 1024.0, message


def build(directory: Path, size: int) -> list[tuple[str, list]]:
    import fuzzing as fz
    import h5py

    ws = fz.Workspace(directory / "valid")
    cases: list[tuple[str, list]] = [
        ("valid device CSV (imports only)", ["check", ws.device_csv]),
        ("valid system HDF5 (imports only)", ["check", ws.system_h5]),
    ]
    long_line = directory / "long-line.csv"
    with open(long_line, "wb") as handle:
        handle.write(ws.device_csv.read_bytes())
        for _ in range(size >> 20):
            handle.write(b"1" * (1 << 20))
    cases.append((f"CSV: a {size >> 20} MB line without newline", ["check", long_line]))
    text = ws.device_csv.read_bytes()
    at = text.index(b"# END HEADER")
    long_header = directory / "long-header.csv"
    with open(long_header, "wb") as handle:
        handle.write(text[:at] + b"# ")
        for _ in range(size >> 20):
            handle.write(b"x" * (1 << 20))
        handle.write(b"\n" + text[at:])
    cases.append((f"CSV: a {size >> 20} MB header line", ["check", long_header]))
    trailer = directory / "trailer.csv"
    trailer.write_bytes(text.replace(text[text.rindex(b"# END OF DATA") :], b"# END OF DATA: 1000000000 rows\n"))
    cases.append(("CSV: trailer declaring 1e9 rows", ["check", trailer]))
    for name, source in (("device", ws.device_h5), ("system", ws.system_h5)):
        sparse = directory / f"sparse-{name}.h5"
        shutil.copyfile(source, sparse)
        with h5py.File(sparse, "r+") as f:
            for column in f["columns"]:
                f["columns"][column].resize((1_000_000_000,))
            f.attrs["rows"] = 1_000_000_000
        cases.append((f"HDF5 {name}: {sparse.stat().st_size >> 10} kB declaring 1e9 rows", ["check", sparse]))
    cases.append(
        (
            "HDF5 system declaring 1e9 rows: calibrate system",
            ["calibrate", "system", directory / "sparse-system.h5", "--prior", ws.record, "--out", directory / "out.json"],
        )
    )
    big = directory / "big-record.json"
    with open(big, "wb") as handle:
        handle.write(b'{"format": "stableins-calibration-record", "notes": ["')
        for _ in range(size >> 20):
            handle.write(b"x" * (1 << 20))
        handle.write(b'"]}')
    cases.append((f"record: {size >> 20} MB JSON", ["check", big]))
    return cases


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--megabytes", type=int, default=256, help="size of the long line / large files [MB]")
    args = parser.parse_args()
    size = args.megabytes << 20
    met = True
    with tempfile.TemporaryDirectory(prefix="stableins-limits-") as directory:
        cases = build(Path(directory), size)
        print(f"{'case':<52} {'exit':>4} {'time [s]':>9} {'peak RSS [MiB]':>15}  message")
        for label, argv in cases:
            status, seconds, rss, message = measure(argv)
            refused = "valid" in label or status == 2
            met = met and refused and seconds < 10 and rss <= 256
            print(f"{label:<52} {status:>4} {seconds:>9.2f} {rss:>15.0f}  {message[18:118]}")
    print()
    print(
        "target (issue 14): a header declaring 1e9 rows or a 256 MB line costs at most 256 MB and fails in seconds ->",
        "met" if met else "NOT met",
    )
    return 0 if met else 1


if __name__ == "__main__":
    sys.exit(main())
