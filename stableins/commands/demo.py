"""``stableins demo --out DIR``: the main job on the embedded simulated platform.

Runs the whole three-stage calibration the way a user would, each step through the
same CLI command a user types (printed before it runs), and leaves every file in ``DIR``:

1. ``simulate device``: a drawn instrument (``truth.json``) on the simulated platform:
   the 18-position coarse passes of the zero-offset iteration, then the fine dwells at
   the re-pointed positions (``--hidden ID=VALUE`` hides an effect in the instrument);
2. ``calibrate device``: coarse + fine stages → ``cal-device.json``;
3. the discovery loop: ``diagnose`` the device-level data against the record in force
   (``discovery/round-K.txt``, ``.json`` and plots); when an effect is flagged, the demo
   adds the best one and recalibrates (``calibrate device --add ID ...`` → ``cal-device.json``,
   now with the effect and the discovery history), then diagnoses again, until nothing is
   flagged (at most :data:`MAX_ROUNDS` effects).  An effect a calibration cannot carry ends
   the loop with the next step printed as a command;
4. ``simulate system --installed cal-device.json``: one sidereal day on a static base
   with the INS compensating by the device-level calibration, discovered effects included;
5. ``calibrate system`` → ``calibration.json`` (the final record);
6. ``report``: the PDF calibration report ``calibration-report.pdf`` (with the discovery
   history the record carries and the last diagnosis);
7. the verdict: every determined parameter of the final record against the simulator's
   truth, in engineering units and in σ (``verdict.json``), discovered effects included.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import TypedDict, cast

from stableins.status import Status

#: Effects the discovery loop adds at most (one per round).
MAX_ROUNDS = 3


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the arguments of ``stableins demo`` to ``parser``."""
    from stableins.commands.arguments import effect_magnitude, output_directory, real, seed
    from stableins.commands.simulate import parse_duration

    parser.add_argument(
        "--out", type=output_directory, default=Path("demo-output"), metavar="DIR", help="output directory (default demo-output)"
    )
    parser.add_argument("--seed", type=seed, default=2018, help="random seed (default 2018)")
    parser.add_argument(
        "--duration", type=parse_duration, default=None, help="length of the system-level record (default one sidereal day)"
    )
    parser.add_argument(
        "--hidden",
        type=effect_magnitude,
        action="append",
        default=[],
        metavar="ID=VALUE",
        help="hide an effect in the simulated instrument for model discovery to find: VALUE in its engineering unit "
        "(Kcc_xxy=60ug/g2) or SI (a bare number); repeatable; see 'stableins simulate --list-effects'",
    )
    parser.add_argument(
        "--rate",
        type=real(0.0, 10000.0, above=True, unit="Hz"),
        default=10.0,
        metavar="HZ",
        help="system-level sample rate [Hz] (default 10)",
    )


def _step(title: str, argv: list[str], stdout: Path | None = None) -> None:
    """Run one CLI command as a user would type it, in a process of its own (``python -m stableins.cli ARGV``).

    Its standard output goes to ``stdout`` if given, else to stderr: the demo's own standard output is its result alone
    (the final table, or with ``--json`` one JSON document), and the steps' reports are progress, on stderr like every
    command's messages.  With the demo silenced (``--quiet`` or ``--json``) every step runs with ``--quiet``: the
    steps share the demo's terminal, so their progress bars would reach it.
    """
    import subprocess
    import sys

    from stableins.progress import silenced

    if silenced():
        argv = [*argv, "--quiet"]
    print(f"\n== {title}: stableins {' '.join(argv)}", file=sys.stderr, flush=True)
    sys.stdout.flush()
    if stdout is None:
        result = subprocess.run([sys.executable, "-m", "stableins.cli", *argv], stdout=subprocess.PIPE, text=True, check=False)
        sys.stderr.write(result.stdout)
        status = result.returncode
    else:
        with open(stdout, "w", encoding="utf-8") as sink:
            status = subprocess.run([sys.executable, "-m", "stableins.cli", *argv], stdout=sink, check=False).returncode
    if status != 0:
        raise SystemExit(status)


def _datasheet(truth_path: Path) -> list[str]:
    """``--bias-instability`` / ``--random-walk`` from the instrument's Allan parameters (its datasheet)."""
    from stableins.conventions import MICRO_G
    from stableins.data.truth import load_truth

    noise = load_truth(truth_path).noise
    return ["--bias-instability", f"{noise.bias_instability / MICRO_G:.6g}", "--random-walk", f"{noise.acceleration_random_walk:.6g}"]


class VerdictRow(TypedDict):
    """One estimated parameter of the demo's ``verdict.json``: truth, estimate, 1σ and error in engineering units, z = error/σ."""

    id: str
    unit: str
    truth: float
    estimate: float
    sigma: float
    error: float
    z: float


def verdict(record_path: Path, truth_path: Path) -> list[VerdictRow]:
    """Compare the final record with the truth: error and error/σ of every estimated parameter.

    The truth is first put in the record's gauge (θ10 = 0, exactly equivalent
    parameters, :func:`stableins.estimators.device_gauge.gauge_equivalent`).  A discovered term
    is compared with the effect the simulator hid (0 when it hid none); the gauge moves
    its regressor's input by θ10 (about 1e-4 relative), which is neglected.
    """
    from stableins.conventions import GimbalConfiguration
    from stableins.data.truth import load_truth
    from stableins.discovery.library import LIBRARY, all_terms
    from stableins.estimators.device_gauge import gauge_equivalent
    from stableins.records import CalibrationRecord

    record = CalibrationRecord.load(record_path)
    truth = load_truth(truth_path)
    configuration = GimbalConfiguration(cast("tuple[int, int, int, int]", tuple(truth.site.gimbal_senses)))
    reference = gauge_equivalent(dict(truth.parameters), configuration)
    reference.update({i: float(truth.effects.get(i, 0.0)) for i in record.ids if i in LIBRARY})
    terms = all_terms()
    rows: list[VerdictRow] = []
    for parameter in record.parameters:
        if parameter.status != Status.ESTIMATED or parameter.id not in reference or parameter.id not in terms:
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


def discovery_loop(out: Path, data: list[str], datasheet: list[str], *, plots: bool = True) -> tuple[list[str], Path, list[str]]:
    """Diagnose, add the best flagged effect, recalibrate; until nothing is flagged.

    Returns the effects the record in force keeps, the last diagnosis (JSON) and what the loop
    said.  Each round runs ``diagnose`` on the device-level data against ``cal-device.json`` (the
    record in force) and, when a carried effect is flagged, ``calibrate device ... --add`` with the
    effects kept so far and the new one; the calibration's own test decides whether it stays.
    ``plots`` writes the diagnosis plots of every round (``discovery/round-K/``).
    """
    import sys

    from stableins.discovery.library import calibration_limit
    from stableins.records import CalibrationRecord
    from stableins.reporting.builder import read_discovery

    kept: list[str] = []
    tested: dict[str, str] = {}  # effect -> the calibration's verdict when it was left out
    said: list[str] = []
    (out / "discovery").mkdir(exist_ok=True)
    record = out / "cal-device.json"
    calibrate = ["calibrate", "device", *data, "--out", str(record), *datasheet]
    for round_ in range(MAX_ROUNDS + 1):
        diagnose = ["diagnose", *data, "--record", str(record), *datasheet]
        text, document = out / "discovery" / f"round-{round_}.txt", out / "discovery" / f"round-{round_}.json"
        figures = ["--plots", str(out / "discovery" / f"round-{round_}")] if plots else []
        _step(f"model discovery, round {round_}: is an effect missing from the model in force?", [*diagnose, *figures], text)
        print(text.read_text(encoding="utf-8"), file=sys.stderr)
        _step("the same, machine-readable for the report", [*diagnose, "--json"], document)
        found_report = read_discovery(document)
        flagged = [c for c in found_report.candidates if c.flagged]
        if not flagged and found_report.outside_library:
            said.append(f"round {round_}: outside the library: {found_report.outside_text()}; no certificate until the cause is found")
            break
        if not flagged:
            said.append(f"round {round_}: nothing flagged; the model in force reaches the noise floor")
            break
        best = flagged[0]
        found = f"{best.id} flagged (p = {best.p_value:.2g}, ΔBIC {best.delta_bic:+.1f})"
        why = calibration_limit(best.id)
        if why is not None:
            said.append(
                f"round {round_}: {found} but it cannot be carried into the calibration: {why}. "
                f"Next step (see it in the model): stableins {' '.join(diagnose)} --add {best.id}"
            )
            break
        if best.id in tested:
            said.append(
                f"round {round_}: {found} again, but the calibration left it out ({tested[best.id]}): its coarse dwells and "
                f"the fine stage's |f| do not determine it as the diagnosis of the fine dwells does. Next step: {best.advice}"
            )
            break
        if round_ == MAX_ROUNDS:
            said.append(
                f"round {round_}: {found}; the demo stops after {MAX_ROUNDS} effects. "
                f"Next step: stableins {' '.join(calibrate)} {' '.join('--add ' + a for a in kept)} --add {best.id}"
            )
            break
        said.append(f"round {round_}: {found}; the demo adds it and recalibrates")
        print(f"\n{said[-1]}", file=sys.stderr)
        _step("recalibration with the discovered effect (the calibration tests it again)",
              [*calibrate, *(item for a in (*kept, best.id) for item in ("--add", a))])  # fmt: skip
        history = CalibrationRecord.load(record).discovery
        verdict = history.steps[-1] if history is not None else None
        if verdict is not None and verdict.decision is not None and verdict.decision.in_model:
            kept.append(best.id)
        else:
            tested[best.id] = f"{verdict.decision}: {verdict.reason}" if verdict is not None else "no verdict"
            said.append(f"round {round_}: the calibration left {best.id} out ({tested[best.id]})")
    return kept, document, said


def run(args: argparse.Namespace) -> int:
    """Run ``stableins demo``: simulate, calibrate, discover and certify on the embedded simulated platform."""
    import sys

    from stableins.commands.simulate import prepare_directory
    from stableins.output import emit

    out = prepare_directory(args.out)
    seed = str(args.seed)
    hidden = [item for name, value in args.hidden for item in ("--hidden", f"{name}={value!r}")]  # SI, exactly
    _step("device-level session", ["simulate", "device", "--seed", seed, "--out", str(out), *hidden])
    data = [str(out / "device-coarse.csv"), str(out / "device-fine.h5")]
    datasheet = _datasheet(out / "truth.json")  # what a user knows of the instrument: its Allan parameters
    _step("device-level calibration", ["calibrate", "device", *data, "--out", str(out / "cal-device.json"), *datasheet])
    added, diagnosis, said = discovery_loop(out, data, datasheet)
    duration = [] if args.duration is None else ["--duration", f"{args.duration}s"]
    _step(
        "system-level record",
        ["simulate", "system", "--truth", str(out / "truth.json"), "--seed", seed, "--installed", str(out / "cal-device.json"),
         *duration, "--rate", str(args.rate), "--out", str(out)],
    )  # fmt: skip
    _step(
        "system-level calibration",
        ["calibrate", "system", str(out / "system.h5"), "--prior", str(out / "cal-device.json"), "--out", str(out / "calibration.json")],
    )
    _step(
        "calibration report",
        ["report", str(out / "calibration.json"), "--data", *data, str(out / "system.h5"),
         "--discovery", str(diagnosis), "--procedure", "system-static",
         "--out", str(out / "calibration-report.pdf")],
    )  # fmt: skip
    rows = verdict(out / "calibration.json", out / "truth.json")
    (out / "verdict.json").write_text(json.dumps(rows, indent=1) + "\n")
    lines = ["", "model discovery:"] + [f"  {line}" for line in said]
    hidden_ids = ", ".join(n for n, _ in args.hidden) or "none"
    lines.append(f"  effects added to the calibration: {', '.join(added) or 'none'}; hidden in the simulated instrument: {hidden_ids}")
    lines += ["", "final calibration against the simulator's truth (θ10 = 0 gauge):",
              f"{'parameter':<10} {'truth':>12} {'estimate':>12} {'error':>10} {'1σ':>9} {'error/σ':>8}  unit"]  # fmt: skip
    lines += [_verdict_row(r) for r in rows]
    worst = max((abs(r["z"]) for r in rows), default=float("nan"))
    lines.append(f"largest |error|/σ = {worst:.2f} over {len(rows)} estimated parameters; files in {out}/")
    print("", file=sys.stderr)
    emit(args, {"out": str(out), "added": added, "discovery": said, "verdict": rows}, "\n".join(lines))
    return 0


def _verdict_row(row: VerdictRow) -> str:
    """One line of the demo's final table: three decimals, or enough for two significant digits of a tiny 1σ."""
    sigma = abs(float(row["sigma"]))
    decimals = 3 if not math.isfinite(sigma) or sigma <= 0 or sigma >= 0.01 else min(9, 1 - math.floor(math.log10(sigma)))
    return (
        f"{row['id']:<10} {row['truth']:>12.{decimals}f} {row['estimate']:>12.{decimals}f} {row['error']:>10.{decimals}f} "
        f"{row['sigma']:>9.{decimals}f} {row['z']:>8.2f}  {row['unit']}"
    )
