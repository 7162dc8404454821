"""The drift test end to end through ``stableins run --driver sim --truth`` (issue 27): ``calibrate drift`` recovers the truth.

For each of ``--seeds`` seeds (default 20), a world with 0.005 °/h of gyro drift per axis (signs drawn from the seed) and
5″ of base azimuth error (tests/test_run_truth.py's ``drift_world``) is written as ``truth.json``, with the unit's record
(tests/systematic_world.py's ``prior_record``, the installed calibration the simulated INS navigates with) as
``cal.json``; then, as a user would, in separate processes::

    stableins run drift-two-position --driver sim --truth truth.json --prior cal.json --out RUN --yes --quiet
    stableins calibrate drift RUN --prior cal.json --out drift.json

and each axis of ``drift.json``'s ``gyro_drift_x/y/z`` is compared with the truth kept in ``RUN/truth.json``.

Prints per seed the three ``z = (ε̂ − ε)/σ``, then the number of seeds whose three axes are all within 3σ
(acceptance: at least 19 of 20), the rms ``z`` per axis (1 for honest σ) and the largest ``|z|``.

Run: ``nice -n 10 .venv/bin/python benchmarks/bench_run_truth_drift.py --seeds 20`` (two processes per seed, about
15 s of one core per seed).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT))
from systematic_world import prior_record  # noqa: E402
from test_run_truth import drift_world  # noqa: E402

from stableins.data.truth import load_truth, save_truth  # noqa: E402
from stableins.records import CalibrationRecord  # noqa: E402


def stableins(*argv: str) -> None:
    """Run ``stableins ARGV`` in its own process; raise with its error output if it fails."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    result = subprocess.run([sys.executable, "-m", "stableins.cli", *argv], cwd=ROOT, env=env, capture_output=True, text=True)
    if result.returncode != 0:
        raise RuntimeError(f"stableins {' '.join(argv)} failed ({result.returncode}):\n{result.stderr}")


def one_seed(seed: int, folder: Path) -> np.ndarray:
    """Run the drift test on the world of ``seed`` through the command line; return the three z of the drift."""
    truth = drift_world(seed)
    save_truth(truth, folder / "truth.json")
    prior_record(truth).save(folder / "cal.json")
    run = folder / "run"
    stableins("run", "drift-two-position", "--driver", "sim", "--truth", str(folder / "truth.json"), "--prior", str(folder / "cal.json"),
              "--out", str(run), "--yes", "--quiet")  # fmt: skip
    stableins("calibrate", "drift", str(run), "--prior", str(folder / "cal.json"), "--out", str(folder / "drift.json"))
    kept = load_truth(run / "truth.json")  # the world the run ran, as the run directory keeps it
    record = CalibrationRecord.load(folder / "drift.json")
    return np.array([(record[f"gyro_drift_{a}"].value - kept.gyro_drift[a]) / record[f"gyro_drift_{a}"].sigma for a in "xyz"])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20)
    args = parser.parse_args()
    print(f"drift test through 'run --driver sim --truth' and 'calibrate drift': {args.seeds} seeds, 0.005 °/h per axis, 5″ azimuth")
    started = time.perf_counter()
    zs = []
    for seed in range(1, args.seeds + 1):
        with tempfile.TemporaryDirectory() as tmp:
            z = one_seed(seed, Path(tmp))
        zs.append(z)
        print(f"  seed {seed:3d}: z (x, y, z) = " + ", ".join(f"{v:+6.2f}" for v in z), flush=True)
    z = np.array(zs)
    within = int(np.sum(np.all(np.abs(z) <= 3.0, axis=1)))
    print(f"seeds with all three axes within 3σ: {within} of {args.seeds}   (acceptance: at least 19 of 20)")
    print("rms z (x, y, z): " + ", ".join(f"{r:.2f}" for r in np.sqrt(np.mean(z**2, axis=0))) + "   (1 for honest σ)")
    print(f"largest |z|: {np.abs(z).max():.2f};  {time.perf_counter() - started:.0f} s wall")


if __name__ == "__main__":
    main()
