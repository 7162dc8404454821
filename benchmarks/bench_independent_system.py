"""The system stage on records of the second, independent generator (benchmarks/worlds/independent_system.py).

Issue 25: "write a second, independent generator for the cases where your own simulator and estimator could share a
mistake".  Per world and seed this writes one static day with the independent generator, then runs the CLI as a user
would, with no noise flags::

    stableins check DIR/system.h5
    stableins calibrate system DIR/system.h5 --prior DIR/installed.json --out DIR/cal.json --estimate-k2 --json
    stableins diagnose DIR/system.h5 --record DIR/cal.json --json            (with --diagnose [WORLD ...])

and prints, per world, rms z = (estimate − truth)/σ per family of the combined coefficients (x1; x2–x5; pitch θ1c..θ2s;
roll φ1s..φ2c, docs/system-calibration.md §10) and of the gyro drift the record sees (§9), the mean χ²_ν of the
separation and the fraction with p < 0.05, the record's own slow-noise decision (on ``white`` its false-alarm rate) and,
with ``--diagnose``, diagnose's verdict.  The truth is the generator's (``truth-independent-system.json``: the
parameters in the θ10 = 0 gauge, the combined coefficients of §1–§2 to first order, less the K2_x, K2_y terms of §8
that ``--estimate-k2`` removes, x1 with its K2_z term ``gΔK_z sin³L``).  "x1 record" is the z of x1 in the updated
record (the posterior parameters against the truth).

Worlds (every one on the generator's unit and gyro: drift (0.001, −0.001, 0.02) °/h, D_g 0.001 °/h/g on the diagonal,
ζ = 0.6, vertical loop 400 s, 0.2″ angle noise, N = 4.5e-4 m/s/√s):

* ``white``: N only (no flicker, no random walk, no quantization), the false-alarm world;
* ``quartz``: + flicker B = 2 µg (Kasdin, one day of history) + random walk K = 1e-7 m/s²/√s, LSB 1e-5 m/s;
* ``flicker``: + flicker B = 2 µg only (Kasdin, one day of history), LSB 1e-5 m/s;
* ``flicker-long``: + flicker B = 2 µg only, ten days of history (1/f down to ~0.1 cycle/day);
* ``random-walk``: + random walk K = 3e-7 m/s²/√s only, LSB 1e-5 m/s.

Run: ``python benchmarks/bench_independent_system.py --seeds 20 [--first-seed 1] [--worlds white quartz] [--diagnose white]
[--gyro-drift X Y Z] [--dg-drawn]``
(``--summarize RUN.json ...`` prints the tables of earlier ``--json`` files)
(one worker; about 15 s of CPU per record at 1 Hz, 30 s with ``--diagnose``).
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent / "worlds"))
import independent_system as gen  # noqa: E402

FAMILIES = {
    "x1": ("x1",),
    "x2-x5": ("x2", "x3", "x4", "x5"),
    "pitch": ("theta_1c", "theta_1s", "theta_2c", "theta_2s"),
    "roll": ("phi_1s", "phi_1c", "phi_2s", "phi_2c"),
    "gyro": ("gyro_drift_x", "gyro_drift_y", "gyro_drift_z"),
    "x1 record": ("x1_record",),
}

WORLDS: dict[str, gen.Noise] = {
    "white": gen.Noise(bias_instability=0.0, random_walk=0.0, quantization=0.0),
    "quartz": gen.Noise(),
    "flicker": gen.Noise(random_walk=0.0),
    "flicker-long": gen.Noise(random_walk=0.0, flicker_history=10 * gen.SIDEREAL_DAY),
    "random-walk": gen.Noise(bias_instability=0.0, random_walk=3e-7),
}


@dataclass
class Outcome:
    """One record: z per quantity, the separation's χ²_ν and p, the slow-noise decision, diagnose's verdict."""

    world: str
    seed: int
    z: dict[str, float] = field(default_factory=dict)
    chi2_red: float = math.nan
    p_value: float = math.nan
    slow_detected: bool = False
    random_walk_zero: bool = False
    diagnose: str = ""
    error: str = ""
    seconds: float = 0.0


def stableins() -> list[str]:
    """The CLI of the interpreter running this script (its venv), as a user would call it."""
    exe = Path(sys.executable).with_name("stableins")
    return [str(exe)] if exe.exists() else [sys.executable, "-m", "stableins"]


def run_record(
    world: str,
    seed: int,
    *,
    rate: float,
    diagnose: bool,
    keep: Path | None,
    gyro_drift: tuple[float, float, float] = gen.World.gyro_drift_dph,
    g_sensitivity_drawn: bool = False,
) -> Outcome:
    """Generate, check, calibrate (and diagnose) one record; z against the generator's truth."""
    from scipy.stats import chi2

    t0 = time.perf_counter()
    out = Outcome(world, seed)
    directory = Path(tempfile.mkdtemp(prefix=f"indep-sys-{world}-{seed}-")) if keep is None else keep / f"{world}-{seed}"
    try:
        paths = gen.generate(
            seed, directory, gen.World(rate=rate, noise=WORLDS[world], gyro_drift_dph=gyro_drift, g_sensitivity_drawn=g_sensitivity_drawn)
        )
        cli = stableins()
        for command in (
            [*cli, "check", str(paths["record"])],
            [*cli, "calibrate", "system", str(paths["record"]), "--prior", str(paths["installed"]), "--out",
             str(directory / "cal.json"), "--estimate-k2", "--json"],
        ):  # fmt: skip
            done = subprocess.run(command, capture_output=True, text=True, check=False)
            if done.returncode != 0:
                out.error = f"{command[1]} exit {done.returncode}: {done.stderr.strip()[-300:]}"
                return out
        result = json.loads(done.stdout[: done.stdout.rindex("}") + 1])
        truth = json.loads(paths["truth"].read_text(encoding="utf-8"))
        reference = truth["combined"]["estimate_k2"]
        for entry in result["combined"]:
            if entry["name"] in reference and entry["sigma"]:
                out.z[entry["name"]] = (entry["value"] - reference[entry["name"]]) / entry["sigma"]
        seen = truth["gyro_drift_seen"]
        for entry in result["parameters"]:
            if entry["id"] in seen and entry.get("sigma"):
                out.z[entry["id"]] = (entry["value"] - seen[entry["id"]]) / entry["sigma"]
        out.z["x1_record"] = _record_x1_z(directory / "cal.json", truth)
        out.chi2_red = float(result["chi2_red"])
        out.p_value = float(chi2.sf(result["chi2"], result["dof"])) if result["dof"] > 0 else math.nan
        slow = result.get("low_frequency_noise") or {}
        out.slow_detected = bool(slow.get("detected"))
        model = result.get("noise_model") or {}
        walk = ((model.get("axes") or {}).get("x") or {}).get("random_walk") or {}
        out.random_walk_zero = out.slow_detected and not walk.get("value")
        if diagnose:
            done = subprocess.run(
                [*cli, "diagnose", str(paths["record"]), "--record", str(directory / "cal.json"), "--json", "--quiet"],
                capture_output=True,
                text=True,
                check=False,
            )
            if done.returncode != 0:
                out.diagnose = f"exit {done.returncode}"
            else:
                d = json.loads(done.stdout[: done.stdout.rindex("}") + 1])
                out.diagnose = "alarm" if d.get("alarm") else str(d.get("verdict"))
        return out
    finally:
        out.seconds = time.perf_counter() - t0
        if keep is None:
            shutil.rmtree(directory, ignore_errors=True)


def _record_x1_z(path: Path, truth: dict) -> float:
    """The z of x1 = −(D_x + D_y)/2 cos²L − D_z sin²L + b_z sinL in the updated record (posterior against the truth).

    The stage's note says "K2_z is not observed and keeps its prior", while x1 carries ``gΔK_z sin³L``
    (docs/system-calibration.md §8): this z shows whether the record's x1 direction is right.
    """
    record = json.loads(path.read_text(encoding="utf-8"))
    lat = math.radians(truth["world"]["latitude_deg"])
    g = truth["world"]["gravity"]
    weights = {
        "sf_x": -(math.cos(lat) ** 2) / 2,
        "sf_y": -(math.cos(lat) ** 2) / 2,
        "sf_z": -(math.sin(lat) ** 2),
        "bias_z": math.sin(lat) / g,
    }
    ids = record["covariance"]["ids"]
    cov = np.array(record["covariance"]["matrix"], dtype=float)
    a = np.array([weights.get(i, 0.0) for i in ids])
    values = {p["id"]: p["value"] for p in record["parameters"]}
    true = truth["parameters_gauge_theta10"]
    error = sum(w * (values[k] - true[k]) for k, w in weights.items())
    return float(error / math.sqrt(a @ cov @ a))


def rms(values: list[float]) -> float:
    return float(np.sqrt(np.mean(np.square(values)))) if values else math.nan


def summarize(outcomes: list[Outcome], diagnose: bool) -> str:
    lines = []
    header = "| world | records | " + " | ".join(FAMILIES) + " | max abs z | mean χ²_ν | p < .05 | slow noise detected | K = 0 |"
    if diagnose:
        header += " diagnose alarms |"
    lines += [header, "|" + "---|" * (header.count("|") - 1)]
    for world in dict.fromkeys(o.world for o in outcomes):
        done = [o for o in outcomes if o.world == world and not o.error]
        failed = [o for o in outcomes if o.world == world and o.error]
        fam = [rms([o.z[k] for o in done for k in keys if k in o.z]) for keys in FAMILIES.values()]
        every = [abs(v) for o in done for keys in list(FAMILIES.values())[:4] for k in keys if k in o.z for v in [o.z[k]]]
        row = f"| {world} | {len(done)}" + (f" (+{len(failed)} failed)" if failed else "") + " | "
        row += " | ".join(f"{v:.2f}" for v in fam)
        row += f" | {max(every, default=math.nan):.1f} | {np.mean([o.chi2_red for o in done]):.3f}"
        row += f" | {np.mean([o.p_value < 0.05 for o in done]):.0%} | {sum(o.slow_detected for o in done)}/{len(done)}"
        row += f" | {sum(o.random_walk_zero for o in done)} |"
        if diagnose:
            ran = [o for o in done if o.diagnose]
            row += f" {sum(o.diagnose != 'consistent' for o in ran)}/{len(ran)} |" if ran else " — |"
        lines.append(row)
        for o in failed:
            lines.append(f"  {world} seed {o.seed}: {o.error}")
    lines += ["", "Split by the random walk's boundary (records where slow noise is detected; docs/system-calibration.md §1a):", ""]
    lines += ["| world | random walk estimated | records | x1 | x2-x5 | pitch | roll |", "|---|---|---|---|---|---|---|"]
    for world in dict.fromkeys(o.world for o in outcomes):
        for label, zero in (("0", True), ("> 0", False)):
            part = [o for o in outcomes if o.world == world and not o.error and o.slow_detected and o.random_walk_zero == zero]
            if part:
                fam = [rms([o.z[k] for o in part for k in FAMILIES[f] if k in o.z]) for f in ("x1", "x2-x5", "pitch", "roll")]
                lines.append(f"| {world} | {label} | {len(part)} | " + " | ".join(f"{v:.2f}" for v in fam) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n")[0])
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--first-seed", type=int, default=1)
    parser.add_argument("--worlds", nargs="+", default=["white", "quartz", "flicker", "random-walk"], choices=sorted(WORLDS))
    parser.add_argument("--rate", type=float, default=1.0)
    parser.add_argument("--diagnose", nargs="*", metavar="WORLD", help="also run diagnose on each record of these worlds (none given: all)")
    parser.add_argument("--keep", type=Path, help="keep the records in this directory")
    parser.add_argument(
        "--gyro-drift", type=float, nargs=3, default=gen.World.gyro_drift_dph, metavar=("X", "Y", "Z"), help="ε^p [deg/h] (platform axes)"
    )
    parser.add_argument(
        "--dg-drawn", action="store_true", help="the installed record's D_g drawn about the truth with its σ (1e-5 deg/h/g)"
    )
    parser.add_argument("--json", type=Path, help="write every record's outcome here (after each record)")
    parser.add_argument("--summarize", type=Path, nargs="+", help="print the tables of --json files written before, and stop")
    args = parser.parse_args(argv)
    if args.summarize:
        outcomes = [Outcome(**o) for path in args.summarize for o in json.loads(path.read_text(encoding="utf-8"))]
        print(summarize([o for o in outcomes if o.world in args.worlds], any(o.diagnose for o in outcomes)))
        return 0
    print(
        f"independent system generator: one sidereal day per record at {args.rate:g} Hz, seeds {args.first_seed}.."
        f"{args.first_seed + args.seeds - 1}; gyro drift {tuple(args.gyro_drift)} deg/h"
        f"{', installed D_g drawn about the truth' if args.dg_drawn else ''}; calibrate system --estimate-k2, no noise flags",
        flush=True,
    )
    outcomes = []
    for seed in range(args.first_seed, args.first_seed + args.seeds):  # seeds outermost: a run cut short is balanced
        for world in args.worlds:
            diagnose = args.diagnose is not None and (not args.diagnose or world in args.diagnose)
            o = run_record(
                world,
                seed,
                rate=args.rate,
                diagnose=diagnose,
                keep=args.keep,
                gyro_drift=tuple(args.gyro_drift),
                g_sensitivity_drawn=args.dg_drawn,
            )
            outcomes.append(o)
            zs = " ".join(f"{k}={v:+.2f}" for k, v in o.z.items())
            print(
                f"{world} {seed}: {o.error or zs} chi2_red={o.chi2_red:.3f} slow={o.slow_detected} {o.diagnose} ({o.seconds:.0f} s)",
                flush=True,
            )
            if args.json:
                args.json.write_text(json.dumps([x.__dict__ for x in outcomes], indent=1), encoding="utf-8")
    print()
    print(summarize(outcomes, args.diagnose is not None))
    return 0


if __name__ == "__main__":
    sys.exit(main())
