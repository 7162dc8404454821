"""``stableins diagnose DATA --record CAL.json [--add ID ...]``: what is the error model missing?

::

    stableins diagnose session.h5 --record record.json
    stableins diagnose session.h5 --record record.json --add nonorth_12 --add Kcc_xxy --json
    stableins diagnose session.h5 --record record.json --plots figures/

Fits the standard model (with the zero offsets and any discovery terms already in the
record) to the device-level dwell means (fine stage when present, else coarse), starting
from the record, adds the effects given with ``--add`` one step at a time, then prints the
residual diagnostics, the ranking of every candidate effect not in the model and the
history of steps (docs/discovery.md).

``--json`` prints one document: ``chi2_red``, ``dof``, ``expected_spread``, ``stage``,
``model``, ``residual_rms`` / ``noise_floor`` [m/s², per axis], ``candidates`` (best first:
``id``, ``statistic``, ``p_value``, ``delta_bic``, ``predicted``, ``identifiable``,
``aliases`` ...), ``history``, and ``drift``: the platform-drift candidates ``Dg_*`` ranked on
the angle-reading slopes within dwells (:mod:`stableins.discovery.drift`).
"""

from __future__ import annotations

import argparse
from pathlib import Path


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("data", nargs="+", type=Path, metavar="DATA", help="device-level data files (CSV or HDF5)")
    parser.add_argument("--record", type=Path, required=True, metavar="CAL.json", help="calibration record to start from")
    parser.add_argument("--add", action="append", default=[], metavar="ID", help="add this effect and refit (repeatable, in order)")
    parser.add_argument("--stage", choices=("coarse", "fine"), help="which dwells to use (default: fine if present, else coarse)")
    parser.add_argument("--alpha", type=float, default=0.05, help="family-wise false-alarm level for flagging candidates (default 0.05)")
    parser.add_argument("--top", type=int, default=10, help="candidates to show in the text report (default 10)")
    parser.add_argument("--plots", type=Path, metavar="DIR", help="write residual and history plots (PNG) into DIR")
    parser.add_argument(
        "--bias-instability",
        type=float,
        metavar="UG",
        help="bias instability B [ug]: slow bias wander correlated between dwells (default: estimated from the dwells if detectable)",
    )
    parser.add_argument("--random-walk", type=float, default=0.0, metavar="K", help="acceleration random walk K [m/s^2/sqrt(s)]")


def run(args: argparse.Namespace) -> int:
    from stableins.data.device import load_device
    from stableins.data.errors import InputError
    from stableins.discovery.history import Discovery
    from stableins.discovery.library import LIBRARY
    from stableins.discovery.problem import DwellProblem, dwells_from_dataset
    from stableins.errormodel import ErrorModel
    from stableins.output import emit, note
    from stableins.records import CalibrationRecord

    if not 0.0 < args.alpha < 1.0:
        raise InputError("must lie between 0 and 1", field="--alpha", expected="a false-alarm level such as 0.05")
    for effect in args.add:
        if effect not in LIBRARY:
            raise InputError(f"unknown effect {effect!r}", field="--add", expected=f"one of {', '.join(LIBRARY.ids)}")
    if len(set(args.add)) != len(args.add):
        raise InputError("an effect is given twice", field="--add")
    record = CalibrationRecord.load(args.record)
    datasets = [load_device(path) for path in args.data]
    if record.serial_number != datasets[0].metadata.serial_number:
        note(f"warning: record {args.record} is for unit {record.serial_number}, data for {datasets[0].metadata.serial_number}")
    model = ErrorModel.standard(nonlinear=True, gimbals=True)
    model = model + [LIBRARY[i].term for i in record.ids if i in LIBRARY and i not in model]
    for effect in args.add:
        if effect in model:
            raise InputError(f"effect {effect!r} is already in the model of {args.record}", field="--add")
    slow_noise = None
    if args.bias_instability is not None or args.random_walk:
        from stableins.estimators.noise_model import SlowNoise

        for name, value in (("--bias-instability", args.bias_instability or 0.0), ("--random-walk", args.random_walk)):
            if not 0.0 <= value < float("inf"):
                raise InputError("must be a finite non-negative number", field=name)
        slow_noise = SlowNoise((args.bias_instability or 0.0) * 9.80665e-6, args.random_walk, source="given on the command line")
    dwells = dwells_from_dataset(datasets, stage=args.stage, slow_noise=slow_noise)
    note(f"noise: {dwells.noise['slow_noise']}")
    for line in dwells.noise.get("left_out", []):
        note(f"left out: {line}")
    session = Discovery(DwellProblem(dwells), model, alpha=args.alpha, start={k: v for k, v in record.values().items() if k in model})
    for effect in args.add:
        session.add(effect)
    diagnosis = session.diagnose()
    ranking = session.rank()
    drift = session.drift()
    if args.plots is not None:
        import matplotlib

        matplotlib.use("Agg")
        args.plots.mkdir(parents=True, exist_ok=True)
        diagnosis.plot_positions().savefig(args.plots / "residuals.png", dpi=110)
        diagnosis.plot_orientation().savefig(args.plots / "orientation.png", dpi=110)
        session.history.plot().savefig(args.plots / "history.png", dpi=110)
        note(f"plots written to {args.plots}")
    drift_text = "platform drift within dwells (angle-reading slopes):\n" + drift.report(top=3)
    text = "\n\n".join([diagnosis.report(), ranking.report(top=args.top), drift_text, session.history.report()])
    result = {
        "stage": dwells.noise.get("stage"),
        "chi2_red": session.result.chi2_red,
        "dof": session.result.dof,
        "expected_spread": diagnosis.spread,
        "p_value": diagnosis.p_value,
        "model": list(session.result.ids),
        "residual_rms": diagnosis.rms,
        "noise_floor": diagnosis.noise_floor,
        "candidates": ranking.to_json(),
        "history": session.history.to_json(),
        "left_out": dwells.noise.get("left_out", []),
        "drift": {
            "chi2_red": drift.result.chi2_red,
            "dof": drift.result.dof,
            "candidates": drift.to_json(),
            "left_out": list(getattr(session, "drift_notes", ())),
        },
    }
    emit(args, result, text)
    return 0
