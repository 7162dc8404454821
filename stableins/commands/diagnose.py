"""``stableins diagnose DATA --record CAL.json [--add ID ...]``: what is the error model missing?

::

    stableins diagnose session.h5 --record record.json
    stableins diagnose session.h5 --record record.json --add nonorth_12 --add Kcc_xxy --json
    stableins diagnose session.h5 --record record.json --plots figures/

Fits the standard model (with the zero offsets and any discovery terms already in the
record) to the device-level dwell means (fine stage when present, else coarse) or to the
bins of one system-level record (``--bin`` seconds; adds the residual spectra at the
Earth-rate harmonics), starting from the record, adds the effects given with ``--add`` one step at a time, then prints the
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
    from stableins.commands.arguments import integer, number, output_directory

    parser.add_argument("data", nargs="+", type=Path, metavar="DATA", help="device-level data files or one system record (CSV or HDF5)")
    parser.add_argument(
        "--bin", type=number(1.0, 86400.0, unit="seconds"), default=60.0, metavar="S", help="system records: bin length [s] (default 60)"
    )
    parser.add_argument("--record", type=Path, required=True, metavar="CAL.json", help="calibration record to start from")
    parser.add_argument("--add", action="append", default=[], metavar="ID", help="add this effect and refit (repeatable, in order)")
    parser.add_argument("--stage", choices=("coarse", "fine"), help="which dwells to use (default: fine if present, else coarse)")
    parser.add_argument(
        "--alpha",
        type=number(0.0, 0.5, above=True),
        default=0.05,
        help="family-wise false-alarm level for flagging candidates, in (0, 0.5] (default 0.05)",
    )
    parser.add_argument("--top", type=integer(1, 10000), default=10, help="candidates to show in the text report (default 10)")
    parser.add_argument("--plots", type=output_directory, metavar="DIR", help="write residual and history plots (PNG) into DIR")
    from stableins.commands.noise import add_noise_options

    add_noise_options(parser)
    parser.add_argument(
        "--allow-gaps", action="store_true", help="system records: accept gaps in the time column (as 'stableins check --allow-gaps')"
    )


def run(args: argparse.Namespace) -> int:
    from stableins.data.device import load_device
    from stableins.discovery.dwells import dwells_from_dataset
    from stableins.discovery.history import Discovery
    from stableins.discovery.library import LIBRARY
    from stableins.discovery.problem import DwellProblem
    from stableins.errormodel import ErrorModel
    from stableins.errors import InputError
    from stableins.output import emit, note
    from stableins.procedures.definition import device_layouts
    from stableins.records import CalibrationRecord

    for effect in args.add:
        if effect not in LIBRARY:
            raise InputError(f"unknown effect {effect!r}", field="--add", expected=f"one of {', '.join(LIBRARY.ids)}")
    if len(set(args.add)) != len(args.add):
        raise InputError("an effect is given twice", field="--add")
    record = CalibrationRecord.load(args.record)
    from stableins.data.validation import FORMAT_TAGS, read_format_tag

    system = [str(p) for p in args.data if read_format_tag(p) == FORMAT_TAGS["system"]]
    if system and len(args.data) > 1:
        raise InputError("give one system-level record alone, or device-level files", path=system[0], expected="DATA of one kind")
    if system:
        from stableins.data.system import open_system_record

        opened = open_system_record(system[0])
        import warnings

        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            opened.validate(allow_gaps=args.allow_gaps)  # the validation 'stableins check' runs
        for w in caught:
            note(f"stableins: warning: {w.message}")
        serial = opened.metadata.serial_number
    else:
        datasets = [load_device(path) for path in args.data]
        serial = datasets[0].metadata.serial_number
    if record.serial_number != serial:
        note(f"warning: record {args.record} is for unit {record.serial_number}, data for {serial}")
    model = ErrorModel.standard(nonlinear=True, gimbals=True)
    model = model + [LIBRARY[i].term for i in record.ids if i in LIBRARY and i not in model]
    for effect in args.add:
        if effect in model:
            raise InputError(f"effect {effect!r} is already in the model of {args.record}", field="--add")
    if system:
        return _system(args, opened, record, model)
    noise, origin = _device_noise(args, datasets, record.noise_model)
    dwells = dwells_from_dataset(datasets, layouts=device_layouts(), stage=args.stage, noise=noise)
    note(f"noise ({origin}): {dwells.noise['slow_noise']}")
    for line in dwells.noise.get("left_out", []):
        note(f"left out: {line}")
    problem = DwellProblem(dwells, stage=f"{dwells.noise['stage']} dwells")
    session = Discovery(problem, model, alpha=args.alpha, start={k: v for k, v in record.values().items() if k in model})
    for effect in args.add:
        session.add(effect)
    diagnosis = session.diagnose()
    ranking = session.rank()
    drift = session.drift()
    if drift is None:
        for line in getattr(session, "drift_notes", ()):
            note(f"drift analysis: {line}")
    if args.plots is not None:
        _write_plots(args.plots, session, ranking)
    parts = [diagnosis.report(), ranking.report(top=args.top)]
    if drift is not None:
        parts.append("platform drift within dwells (angle-reading slopes):\n" + drift.report(top=3))
    model_used = dwells.noise.get("model")
    steps = next_steps(args, record, ranking.flagged, system=False)
    text = "\n\n".join(parts + [session.history.report(), "\n".join(steps)])
    result = {
        "stage": dwells.noise.get("stage"),
        "noise_model": None if model_used is None else model_used.to_document(),
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
        "next": steps,
        "drift": None
        if drift is None
        else {
            "chi2_red": drift.result.chi2_red,
            "dof": drift.result.dof,
            "candidates": drift.to_json(),
            "left_out": list(getattr(session, "drift_notes", ())),
        },
        "spectra": {},
    }
    if args.json:
        for line in steps:
            note(line)
    emit(args, result, text)
    return 0


def _system(args: argparse.Namespace, opened, record, model) -> int:
    """A system-level record: discovery under the noise model the system stage measures in it (docs/discovery.md)."""
    from stableins.commands.noise import system_noise_prior
    from stableins.discovery.system import diagnose_system_record, measure_noise
    from stableins.output import emit, note

    prior, _ = system_noise_prior(args, default=record.noise_model)
    values = record.values()
    covariance = {(a, b): float(record.covariance[i, j]) for i, a in enumerate(record.ids) for j, b in enumerate(record.ids)}
    from stableins.discovery.library import record_terms

    noise, duration, notes = measure_noise(opened, values, covariance, prior, record_terms(record.ids))
    result = diagnose_system_record(
        opened,
        model,
        {k: v for k, v in values.items() if k in model},
        noise,
        bin_seconds=args.bin,
        duration=duration,
        alpha=args.alpha,
        add=args.add,
        notes=notes,
    )
    session, diagnosis, ranking = result.session, result.diagnosis, result.ranking
    if args.plots is not None:
        _write_plots(args.plots, session, ranking, result.spectra)
    steps = next_steps(args, record, ranking.flagged, system=True)
    text = "\n\n".join([result.report(top=args.top), session.history.report(), "\n".join(steps)])
    flagged = {(name, k) for name, k, _ in result.flagged_harmonics}
    data = {
        "stage": "system",
        "noise_model": noise.to_document(),
        "chi2_red": session.result.chi2_red,
        "chi2_red_range": list(result.chi2_range),
        "dof": session.result.dof,
        "expected_spread": diagnosis.spread,
        "p_value": diagnosis.p_value,
        "consistent": diagnosis.consistent,
        "alarm": result.alarm,
        "bin_seconds": result.bin_seconds,
        "model": list(session.result.ids),
        "residual_rms": diagnosis.rms,
        "noise_floor": diagnosis.noise_floor,
        "candidates": ranking.to_json(),
        "history": session.history.to_json(),
        "left_out": [],
        "next": steps,
        "drift": None,
        "notes": list(result.notes),
        "spectra": {
            name: {
                "harmonics": sp.harmonics,
                "amplitude": sp.amplitude,
                "sigma": sp.sigma,
                "chi2": sp.chi2,
                "dof": sp.dof,
                "p_value": sp.p_value,
                "flagged": [bool((name, int(k)) in flagged) for k in sp.harmonics],
                "unit": "m/s^2",
            }
            for name, sp in result.spectra.items()
        },
    }
    if args.json:
        for line in steps:
            note(line)
    emit(args, data, text)
    return 0


def _device_noise(args: argparse.Namespace, datasets, default):
    """The device stages' noise model: flags, ``--noise``, the record's, or (None) measured in all dwells as calibrate does."""
    from stableins.commands.noise import noise_from_options
    from stableins.estimators.dwell import dwells_from_columns
    from stableins.procedures.definition import device_layouts

    layouts = device_layouts()

    def summaries():
        return [s for ds in datasets for s in dwells_from_columns(ds.columns, layouts=layouts, source=str(ds.path))]

    given = args.bias_instability is not None or args.random_walk is not None
    noise, origin = noise_from_options(args, summaries() if given else [], default=default)
    if noise is None:
        from stableins.estimators.device import noise_from_dwells

        noise = noise_from_dwells(summaries(), source=", ".join(str(ds.path) for ds in datasets))
    return noise, origin


def _write_plots(directory: Path, session, ranking, spectra=None) -> None:
    """The session's figures (residuals, orientation: before and after ``--add``; history) and the harmonic spectra, as PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from stableins.output import note

    directory.mkdir(parents=True, exist_ok=True)
    figures = session.figures(next_step=ranking.next_step())
    for name, spectrum in (spectra or {}).items():
        figures[f"spectrum_{name}"] = spectrum.plot(unit="µg", scale=9.80665e-6, name=name, next_step=ranking.next_step())
    for name, figure in figures.items():
        figure.savefig(directory / f"{name}.png", dpi=110)
        plt.close(figure)
    note(f"plots written to {directory}")


def next_steps(args: argparse.Namespace, record, flagged, *, system: bool) -> list[str]:
    """What to do next, as commands that run as written: carry the best flagged effect into the calibration, look at
    an effect a calibration cannot carry, or certify the record when nothing is missing."""
    import shlex

    from stableins.commands.noise import noise_arguments
    from stableins.discovery.library import LIBRARY, calibration_limit

    data = [str(p) for p in args.data]
    record_path = Path(args.record)
    if not flagged:
        certificate = record_path.with_name(f"{record_path.stem}-report.pdf")
        command = ["stableins", "report", str(record_path), "--data", *data, "--out", str(certificate)]
        return [
            f"next: nothing is flagged at α = {args.alpha:g}: the model in force reaches the noise floor; its certificate:",
            f"  {shlex.join(command)}",
        ]
    best = flagged[0]
    why = calibration_limit(best.id)
    if system or why is not None:
        reason = f"a calibration cannot carry it: {why}" if why is not None else "the system stage does not estimate added effects"
        command = ["stableins", "diagnose", *data, "--record", str(record_path), *noise_arguments(args), "--add", best.id]
        return [f"next: {best.id} is flagged ({reason}); see it in the model and what it changes:", f"  {shlex.join(command)}"]
    kept = [i for i in record.ids if i in LIBRARY]  # the discovered effects of the model in force stay in it
    out = record_path.with_name(f"{record_path.stem}-{best.id}.json")
    command = ["stableins", "calibrate", "device", *data, *noise_arguments(args)]
    command += [item for effect in (*kept, best.id) for item in ("--add", effect)] + ["--out", str(out)]
    confused = f"; with these data it is indistinguishable from {', '.join(best.confused_with)}" if best.confused_with else ""
    return [
        f"next: carry {best.id} into the calibration (it is tested again there and kept only if the data show it{confused}):",
        f"  {shlex.join(command)}",
    ]
