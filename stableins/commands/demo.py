"""``stableins demo --out DIR``: the main job on the embedded simulated platform.

Runs the whole three-stage calibration the way a user would, each step through the
same CLI command a user types, and leaves every file in ``DIR``:

1. ``simulate device``: a drawn instrument (``truth.json``) on the simulated platform:
   the 18-position coarse passes of the zero-offset iteration, then the fine dwells at
   the re-pointed positions;
2. ``calibrate device``: coarse + fine stages → ``cal-device.json``;
3. ``simulate system --installed cal-device.json``: one sidereal day on a static base
   with the INS compensating by the device-level calibration (the third stage corrects
   what the first two left);
4. ``calibrate system`` → ``calibration.json`` (the final record);
5. ``diagnose``: model discovery on the device-level data (plots in ``discovery/``;
   ``--hidden ID=VALUE`` hides an effect for it to find);
6. ``report``: the PDF calibration report ``calibration-report.pdf``;
7. the verdict: every determined parameter of the final record against the simulator's
   truth, in engineering units and in σ (``verdict.json``).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any


def configure(parser: argparse.ArgumentParser) -> None:
    from stableins.commands.arguments import number, output_directory, seed
    from stableins.commands.simulate import parse_duration, parse_hidden

    parser.add_argument(
        "--out", type=output_directory, default=Path("demo-output"), metavar="DIR", help="output directory (default demo-output)"
    )
    parser.add_argument("--seed", type=seed, default=2018, help="random seed (default 2018)")
    parser.add_argument(
        "--duration", type=parse_duration, default=86164.0905, help="length of the system-level record (default one sidereal day)"
    )
    parser.add_argument(
        "--hidden",
        type=parse_hidden,
        action="append",
        default=[],
        metavar="ID=VALUE",
        help="hide an effect in the simulated instrument (SI, repeatable) for model discovery to find",
    )
    parser.add_argument(
        "--rate",
        type=number(0.0, 10000.0, above=True, unit="Hz"),
        default=10.0,
        metavar="HZ",
        help="system-level sample rate [Hz] (default 10)",
    )


def _step(title: str, argv: list[str], stdout: Path | None = None) -> None:
    """Run one CLI command as a user would type it; its standard output goes to ``stdout`` if given."""
    import contextlib
    import sys

    from stableins import cli

    print(f"\n== {title}: stableins {' '.join(argv)}", file=sys.stderr, flush=True)
    with contextlib.ExitStack() as stack:
        if stdout is not None:
            stack.enter_context(contextlib.redirect_stdout(stack.enter_context(open(stdout, "w", encoding="utf-8"))))
        status = cli.main(argv)
    if status != 0:
        raise SystemExit(status)


def _datasheet(truth_path: Path) -> list[str]:
    """``--bias-instability`` / ``--random-walk`` from the instrument's Allan parameters (its datasheet)."""
    from stableins.conventions import MICRO_G
    from stableins.simulator.truth import Truth

    noise = Truth.read(truth_path).noise
    return ["--bias-instability", f"{noise.bias_instability / MICRO_G:.6g}", "--random-walk", f"{noise.acceleration_random_walk:.6g}"]


def verdict(record_path: Path, truth_path: Path) -> list[dict[str, Any]]:
    """Final record against the truth: error and error/σ of every estimated parameter.

    The truth is first put in the record's gauge (θ10 = 0, exactly equivalent
    parameters, :func:`stableins.estimators.coarse.gauge_equivalent`).
    """
    from stableins.conventions import GimbalConfiguration
    from stableins.errormodel import known_terms
    from stableins.estimators.coarse import gauge_equivalent
    from stableins.records import CalibrationRecord
    from stableins.simulator.truth import Truth

    record = CalibrationRecord.load(record_path)
    truth = Truth.read(truth_path)
    configuration = GimbalConfiguration(tuple(truth.site.gimbal_senses))
    reference = gauge_equivalent(dict(truth.parameters), configuration)
    terms = known_terms()
    rows = []
    for parameter in record.parameters:
        if parameter.status != "estimated" or parameter.id not in reference or parameter.id not in terms:
            continue
        term = terms[parameter.id]
        error = parameter.value - reference[parameter.id]
        rows.append(
            {
                "id": parameter.id,
                "unit": term.unit,
                "truth": float(term.to_engineering(reference[parameter.id])),
                "estimate": float(term.to_engineering(parameter.value)),
                "sigma": float(term.sigma_to_engineering(parameter.sigma)),
                "error": float(term.sigma_to_engineering(error)),
                "z": float(error / parameter.sigma) if parameter.sigma else float("nan"),
            }
        )
    return rows


def run(args: argparse.Namespace) -> int:
    import sys

    from stableins.commands.simulate import prepare_directory
    from stableins.output import emit

    out = prepare_directory(args.out)
    seed = str(args.seed)
    hidden = [item for name, value in args.hidden for item in ("--hidden", f"{name}={value}")]
    _step("device-level session", ["simulate", "device", "--seed", seed, "--out", str(out), *hidden])
    coarse, fine = out / "device-coarse.csv", out / "device-fine.h5"
    datasheet = _datasheet(out / "truth.json")  # what a user knows of the instrument: its Allan parameters
    _step(
        "device-level calibration",
        ["calibrate", "device", str(coarse), str(fine), "--out", str(out / "cal-device.json"), *datasheet],
    )
    _step(
        "system-level record",
        ["simulate", "system", "--truth", str(out / "truth.json"), "--seed", seed, "--installed", str(out / "cal-device.json"),
         "--duration", f"{args.duration}s", "--rate", str(args.rate), "--out", str(out)],
    )  # fmt: skip
    _step(
        "system-level calibration",
        ["calibrate", "system", str(out / "system.h5"), "--prior", str(out / "cal-device.json"), "--out", str(out / "calibration.json")],
    )
    diagnose = ["diagnose", str(coarse), str(fine), "--record", str(out / "cal-device.json"), *datasheet]
    _step("model discovery (is an effect missing from the model?)", [*diagnose, "--plots", str(out / "discovery")], out / "diagnosis.txt")
    print((out / "diagnosis.txt").read_text(encoding="utf-8"), file=sys.stderr)
    _step("model discovery, machine-readable for the report", [*diagnose, "--json"], out / "diagnosis.json")
    from stableins.procedures.definition import load_procedure

    _step(
        "calibration report",
        ["report", str(out / "calibration.json"), "--data", str(coarse), str(fine), str(out / "system.h5"),
         "--discovery", str(out / "diagnosis.json"), "--procedure", load_procedure("system-static").path,
         "--out", str(out / "calibration-report.pdf")],
    )  # fmt: skip
    rows = verdict(out / "calibration.json", out / "truth.json")
    (out / "verdict.json").write_text(json.dumps(rows, indent=1) + "\n")
    lines = ["", "final calibration against the simulator's truth (θ10 = 0 gauge):",
             f"{'parameter':<10} {'truth':>12} {'estimate':>12} {'error':>10} {'1σ':>9} {'error/σ':>8}  unit"]  # fmt: skip
    row = "{id:<10} {truth:>12.3f} {estimate:>12.3f} {error:>10.3f} {sigma:>9.3f} {z:>8.2f}  {unit}"
    lines += [row.format(**r) for r in rows]
    worst = max((abs(r["z"]) for r in rows), default=float("nan"))
    lines.append(f"largest |error|/σ = {worst:.2f} over {len(rows)} estimated parameters; files in {out}/")
    emit(args, {"out": str(out), "verdict": rows}, "\n".join(lines))
    return 0
