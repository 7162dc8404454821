"""``stableins design PROCEDURE [--fine FINE] [--passes N] NOISE [--target ID=SIGMA ... | --match | --budget T] [--out DIR]``.

Before the platform moves: the expected 1σ of every parameter of a device-level procedure (the Cramér-Rao bound of
the joint fit under the unit's noise model, slow noise included), the design's rank and null space and the lab time;
then, on request, the dwell times (and with ``--grid`` the positions) that reach σ targets in the least lab time, or
the best design for a time budget (A- or D-optimal).  ``--out DIR`` writes the designed procedures as TOML files that
``stableins run`` executes (docs/design.md).
"""

from __future__ import annotations

import argparse
import fnmatch
import math
from pathlib import Path
from typing import Any

from stableins.commands.arguments import file_stem, integer, output_directory, real
from stableins.commands.noise import add_noise_options

_HELP = "expected σ of a procedure before the platform moves; dwells and positions for σ targets or a time budget"


def _target(text: str) -> tuple[str, float]:
    """``ID=SIGMA`` (engineering unit of the term; ``ID`` may be a pattern such as ``sf_*``)."""
    name, sep, value = text.partition("=")
    try:
        sigma = float(value)
    except ValueError:
        sigma = math.nan
    if not sep or not name or not (math.isfinite(sigma) and sigma > 0):
        raise argparse.ArgumentTypeError(f"{text!r} is not ID=SIGMA (a parameter or pattern such as sf_*, and a positive 1σ)")
    return name, sigma


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the arguments of ``stableins design`` to ``parser``."""
    parser.description = __doc__.split("\n\n")[1].replace("\n", " ") if __doc__ else _HELP
    parser.add_argument("procedure", metavar="PROCEDURE", help="coarse procedure: a shipped name (device-coarse) or a TOML file")
    parser.add_argument("--fine", metavar="FINE", help="fine procedure run after the coarse passes (e.g. device-fine)")
    parser.add_argument("--passes", type=integer(1, 20), default=2, help="coarse passes (the zero-offset iteration; default 2)")
    parser.add_argument("--sample-rate", type=real(0.0, 1e4, above=True, unit="Hz"), metavar="HZ", help="sample rate of every dwell")
    add_noise_options(parser)
    parser.add_argument(
        "--white",
        type=real(0.0, 1.0, above=True, unit="m/s/sqrt(s)"),
        metavar="N",
        help="white noise N [m/s/sqrt(s)] of the datasheet (with --bias-instability, --random-walk); --noise CAL.json gives all",
    )
    parser.add_argument("--quantization", type=real(0.0, 1.0, unit="m/s"), default=0.0, metavar="Q", help="velocity quantum [m/s]")
    goal = parser.add_mutually_exclusive_group()
    goal.add_argument("--target", type=_target, action="append", default=[], metavar="ID=SIGMA", help="1σ target [engineering unit]")
    goal.add_argument("--match", action="store_true", help="targets: this procedure's own σ on every parameter (least time for it)")
    goal.add_argument("--budget", type=real(0.0, 1e7, above=True, unit="h"), metavar="HOURS", help="lab-time budget [h]")
    parser.add_argument("--criterion", choices=("A", "D"), help="optimality criterion with --budget (default A)")
    parser.add_argument("--grid", type=real(1.0, 90.0, unit="deg"), metavar="DEG", help="also choose positions from a grid of this step")
    parser.add_argument("--min-dwell", type=real(0.1, 86400.0, unit="s"), default=5.0, metavar="S", help="shortest dwell (default 5 s)")
    parser.add_argument(
        "--max-dwell", type=real(1.0, 86400.0, unit="s"), default=3600.0, metavar="S", help="longest dwell (default 3600 s)"
    )
    parser.add_argument(
        "--out", type=output_directory, metavar="DIR", help="write the designed procedures here (NAME-coarse.toml, NAME-fine.toml)"
    )
    parser.add_argument("--name", type=file_stem, default="designed", help="name of the designed procedures (default 'designed')")
    parser.add_argument("--json", action="store_true", help="print the result as JSON on stdout")


def _noise(args: argparse.Namespace) -> Any:
    """Return the noise model of the options: a record's, or the datasheet's N, B, K, Q."""
    from stableins.commands.noise import record_noise
    from stableins.conventions import MICRO_G
    from stableins.errors import InputError
    from stableins.noise import NoiseModel

    if args.noise is not None:
        if args.white is not None or args.bias_instability is not None or args.random_walk is not None:
            raise InputError("give either --noise CAL.json or the datasheet values, not both", field="--noise")
        return record_noise(args.noise)
    if args.white is None:
        raise InputError(
            "the design needs a noise model",
            field="--white",
            expected="--noise CAL.json, or --white N (+ --bias-instability, --random-walk)",
        )
    return NoiseModel.given(
        args.white,
        (args.bias_instability or 0.0) * MICRO_G,
        args.random_walk or 0.0,
        args.quantization,
        provenance="datasheet values given to stableins design",
    )


def _targets(args: argparse.Namespace, start: Any) -> dict[str, float] | None:
    """Targets in SI from ``--target`` patterns or ``--match``; None for a budget or no optimization."""
    from stableins.errors import InputError

    if args.match:
        return {k: v for k, v in start.sigma.items() if v > 0}
    if not args.target:
        return None
    out: dict[str, float] = {}
    for pattern, sigma in args.target:
        ids = [k for k in start.ids if fnmatch.fnmatchcase(k, pattern) and start.sigma[k] > 0]
        if not ids:
            raise InputError(
                f"no estimated parameter matches {pattern!r}",
                field="--target",
                expected=", ".join(k for k in start.ids if start.sigma[k] > 0),
            )
        out.update({k: sigma * start.model[k].scale for k in ids})
    return out


def _plan(args: argparse.Namespace) -> tuple[Any, Any, Any]:
    from stableins.errors import InputError
    from stableins.procedures.definition import load_procedure
    from stableins.procedures.designed import device_plan

    coarse = load_procedure(args.procedure)
    fine = None if args.fine is None else load_procedure(args.fine)
    for definition, stage, where in ((coarse, "coarse", "PROCEDURE"), (fine, "fine", "--fine")):
        if definition is not None and definition.stage != stage:
            raise InputError(f"a {definition.stage} procedure", path=definition.path, field=where, expected=f"a {stage} procedure")
    return coarse, fine, device_plan(coarse, fine, passes=args.passes, sample_rate=args.sample_rate)


def run(args: argparse.Namespace) -> int:
    """Evaluate the procedure, optimize on request, print; write the designed procedures last."""
    import numpy as np

    from stableins.conventions import STANDARD_GRAVITY
    from stableins.errors import InputError
    from stableins.estimators.experiment import (
        Criterion,
        DwellBounds,
        exchange_positions,
        expected_precision,
        grid_candidates,
        optimize_dwells,
    )
    from stableins.estimators.setting import DeviceSetting
    from stableins.output import emit

    if args.min_dwell >= args.max_dwell:
        raise InputError("--min-dwell must be below --max-dwell", field="--min-dwell")
    if args.criterion is not None and args.budget is None:
        raise InputError(
            "the optimality criterion applies to a lab-time budget only (targets are met in least lab time)",
            field="--criterion",
            expected="--budget HOURS with --criterion, or no --criterion",
        )
    if args.grid is not None and args.budget is None and not args.match and not args.target:
        raise InputError(
            "a position grid needs something to optimize", field="--grid", expected="--budget, --match or --target with --grid"
        )
    noise = _noise(args)
    coarse, fine, plan = _plan(args)
    setting = DeviceSetting(STANDARD_GRAVITY)
    start = expected_precision(plan, noise, setting)
    targets = _targets(args, start)
    result = None
    criterion = Criterion(args.criterion or "A")
    if targets is not None or args.budget is not None:
        if args.grid is not None:
            d = math.radians
            candidates = grid_candidates(
                d(args.grid), platform=(0.0, d(360 - args.grid)), inner=(0.0, d(360 - args.grid)), middle=(d(-135), 0.0)
            )
            scales = targets or {k: start.model[k].nominal for k in start.ids}
            plan = exchange_positions(
                plan, candidates, noise, setting, scales=scales, criterion=criterion if targets is None else Criterion.A
            )
        bounds = DwellBounds(args.min_dwell, args.max_dwell)
        budget = None if args.budget is None else args.budget * 3600.0
        result = optimize_dwells(plan, noise, setting, targets=targets, budget=budget, criterion=criterion, bounds=bounds)
        rounded = [s.with_dwell(np.round(s.dwell, 1)) for s in result.plan.stages]
        from dataclasses import replace

        result = expected_precision(replace(result.plan, coarse=rounded[0], fine=rounded[1] if len(rounded) > 1 else None), noise, setting)
    written = _write(args, coarse, fine, result) if result is not None else []
    data, text = _report(args, start, result, targets, written=written, noise=noise)
    emit(args, data, text)
    return 0


def _write(args: argparse.Namespace, coarse: Any, fine: Any, result: Any) -> list[str]:
    from stableins.procedures.designed import write_procedure

    if args.out is None:
        return []
    source = f"stableins design {Path(coarse.path).stem}" + (f" --fine {Path(fine.path).stem}" if fine is not None else "")
    out = [
        str(
            write_procedure(
                args.out / f"{args.name}-coarse.toml", coarse, result.plan.coarse, name=f"{args.name}-coarse", source=source
            ).path
        )
    ]
    if fine is not None:
        out.append(
            str(write_procedure(args.out / f"{args.name}-fine.toml", fine, result.plan.fine, name=f"{args.name}-fine", source=source).path)
        )
    return out


def _report(
    args: argparse.Namespace, start: Any, result: Any, targets: Any, *, written: list[str], noise: Any
) -> tuple[dict[str, Any], str]:
    from stableins.estimators.design import describe_design

    lines = [f"noise model: {noise.describe()}", "", f"{'parameter':<10}{'unit':<8}{'σ (given)':>11}"]
    if result is not None:
        lines[-1] += f"{'σ (designed)':>14}{'target':>9}"
    given, designed = start.sigma_engineering(), result.sigma_engineering() if result is not None else {}
    rows = []
    for k in start.ids:
        line = f"{k:<10}{start.model[k].unit:<8}{given[k]:>11.4g}" if start.sigma[k] > 0 else f"{k:<10}{'':<8}{'gauge (0)':>11}"
        if result is not None and start.sigma[k] > 0:
            tgt = "" if not targets or k not in targets else f"{targets[k] / start.model[k].scale:.4g}"
            line += f"{designed[k]:>14.4g}{tgt:>9}"
        lines.append(line)
        rows.append({"id": k, "unit": start.model[k].unit, "sigma": given[k], "designed_sigma": designed.get(k)})
    for name, r in (("given", start), ("designed", result)):
        if r is None:
            continue
        times = ", ".join(f"{s} {t / 3600:.3f} h" for s, t in r.plan.stage_times().items())
        lines.append(f"{name}: lab time {r.lab_time / 3600:.3f} h ({times}); rank {r.analysis.rank} of {len(r.ids)}")
        lines += ["  " + x for x in describe_design(r.ids, r.analysis.singular_values, r.analysis.null_space)[1:]]
    if result is not None:
        lines.append(f"designed / given lab time: {result.lab_time / start.lab_time:.3f}")
        criterion = "least lab time for the targets"
        if args.budget is not None:
            criterion = f"{args.criterion or 'A'}-optimal within {args.budget:g} h"
        lines.append(f"criterion: {criterion}" + (f"; positions from a {args.grid:g}° grid" if args.grid else "; positions as given"))
        for s in result.plan.stages:
            lines.append(f"{s.stage} dwells [s]: " + " ".join(f"{t:g}" for t in s.dwell))
    lines += [f"wrote {p}" for p in written]
    data = {
        "parameters": rows,
        "lab_time": start.lab_time,
        "rank": start.analysis.rank,
        "designed_lab_time": None if result is None else result.lab_time,
        "procedures": written,
        "designed_dwells": None if result is None else {s.stage: s.dwell.tolist() for s in result.plan.stages},
    }
    return data, "\n".join(lines)
