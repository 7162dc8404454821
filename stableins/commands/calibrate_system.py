"""``stableins calibrate system RECORD --prior CAL.json --out CAL2.json``: the third stage.

Reads a static, polar-aligned system-level record (``.h5`` or ``.csv``) and the
calibration the INS was running with (``--prior``), estimates the fifteen combined
coefficients (Earth-rate harmonics of the specific-force error, loop-compensated pitch
and roll harmonics) and updates the prior record with what they say (a Bayesian update:
no σ grows, nothing moves along what the data do not determine; docs/system-calibration.md
§4), then writes the updated record (``--out``, atomically).  A record that determines
nothing (shorter than about half a sidereal day) writes no record and exits 2 saying why.

The stage continues the prior's calibration (its record, e.g. the device-level one made for
this calibration); ``--new-calibration`` starts a new one from a record in force instead
(a system-level recalibration).  The console table, ``--json`` and the certificate show the
record's own statuses and σ.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any, cast

from stableins.commands import add_entries_option, add_new_calibration_option, check_same_unit
from stableins.status import Status


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the arguments of ``stableins calibrate system`` to ``parser``."""
    from stableins.commands.arguments import integer, output_file, png_file, real

    parser.add_argument("record", metavar="RECORD", help="system-level record (.h5, or .csv for short records)")
    parser.add_argument("--prior", required=True, metavar="CAL.json", help="calibration record the INS compensated the record with")
    parser.add_argument("--out", required=True, type=output_file, metavar="CAL2.json", help="updated calibration record to write")
    parser.add_argument(
        "--case-rotation-period",
        type=real(60.0, 3600.0, unit="seconds", or_zero=True),
        default=480.0,
        metavar="SECONDS",
        help="period of the gyro case-rotation residual fitted as a nuisance, 60 to 3600 s (default 480 s; 0 leaves it out)",
    )
    parser.add_argument(
        "--no-loop-compensation",
        action="store_true",
        help="read the attitude harmonics quasi-statically as the paper does (biased; for comparison only)",
    )
    parser.add_argument(
        "--no-couplings", action="store_true", help="loop model without Earth-rate/Coriolis couplings (for comparison only)"
    )
    parser.add_argument(
        "--chunk-rows",
        type=integer(1024, 1 << 26),
        default=1 << 18,
        metavar="N",
        help="samples per streamed chunk, 1024 to 2^26 (memory ~ 100 bytes x N)",
    )
    parser.add_argument(
        "--estimate-k2",
        action="store_true",
        help="also estimate the residual quadratic coefficients K2_x, K2_y from the third harmonic, remove their bias (not in the paper)",
    )
    parser.add_argument(
        "--thermal-prior",
        type=real(1e-6, 1e6),
        nargs=2,
        metavar=("UG_PER_K", "PPM_PER_K"),
        help=(
            "1σ of the accelerometers' bias [ug/K] and scale-factor [ppm/K] temperature sensitivities, the thermal terms of the "
            "system model when the prior record has none (default 5 5); a daily temperature cycle makes them alias the Earth-rate "
            "harmonics, and the coefficients they could move are reported as not separable (docs/system-calibration.md §1b)"
        ),
    )
    parser.add_argument(
        "--gyro-drift",
        type=real(-100.0, 100.0, unit="deg/h"),
        nargs=3,
        metavar=("X", "Y", "Z"),
        help=(
            "constant gyro drift in the platform frame [deg/h] known from elsewhere (a gyro calibration): held exactly and removed "
            "from pitch and roll, or with --gyro-drift-uncertainty combined with what the record's gimbal readings measure.  "
            "Without it the stage measures the drift in the gimbal readings (inner and middle angles needed), removes it and "
            "writes gyro_drift_x/y/z with their sigma to the record (docs/system-calibration.md section 9)"
        ),
    )
    parser.add_argument(
        "--gyro-drift-uncertainty",
        type=real(0.0, 100.0, unit="deg/h"),
        metavar="U",
        help=(
            "standard uncertainty of the gyro drift per platform axis [deg/h] (of the value given, or of zero when none is given), "
            "from the gyro calibration: a given drift with it is a measurement the stage combines with the gimbal readings'; "
            "when the drift is not measured the certificate's uncertainty budget uses it (default: the procedure's or "
            "0.00058 deg/h, a rectangular distribution over the 0.001 deg/h bound of Wu et al. 2018)"
        ),
    )
    parser.add_argument("--plot", type=png_file, metavar="PNG", help="also write the filter convergence and attitude residual plot")
    from stableins.commands.noise import add_noise_options

    add_noise_options(parser)  # default: the prior record's noise model (docs/system-calibration.md §1a)
    parser.add_argument(
        "--allow-gaps",
        action="store_true",
        help="accept gaps in the time column (warned about; the fits use the samples present), as 'stableins check --allow-gaps'",
    )
    parser.add_argument(
        "--systematic",
        action="store_true",
        help=(
            "systematic calibration of an indexed record (stableins run system-indexed): one Kalman filter and RTS smoother "
            "over the platform's orientations, accelerometer residuals, gyro drift and g-sensitivity (docs/systematic-calibration.md)"
        ),
    )
    parser.add_argument(
        "--cross-coupling",
        action="store_true",
        help=(
            "with --systematic: also estimate Cai et al. 2016's six accelerometer cross-couplings (Kcc_xxy, xxz, yxy, yyz, zxz, "
            "zyz); those the prior record holds are always estimated.  A new one is written only if the orientations determine "
            "it (docs/systematic-calibration.md section 5)"
        ),
    )
    add_new_calibration_option(parser)
    add_entries_option(parser)


#: Options of the static stage that the systematic stage has no use for: (option, attribute, value when not given).
STATIC_ONLY_OPTIONS: tuple[tuple[str, str, Any], ...] = (
    ("--case-rotation-period", "case_rotation_period", 480.0),
    ("--no-loop-compensation", "no_loop_compensation", False),
    ("--no-couplings", "no_couplings", False),
    ("--chunk-rows", "chunk_rows", 1 << 18),
    ("--estimate-k2", "estimate_k2", False),
    ("--thermal-prior", "thermal_prior", None),
    ("--gyro-drift", "gyro_drift", None),
    ("--gyro-drift-uncertainty", "gyro_drift_uncertainty", None),
    ("--plot", "plot", None),
)


def _check_mode(args: Any) -> None:
    """Refuse the options that do not apply to the mode asked for (issue 31: they were silently ignored)."""
    from stableins.errors import InputError

    if getattr(args, "systematic", False):
        given = [option for option, name, unset in STATIC_ONLY_OPTIONS if getattr(args, name, unset) != unset]
        if given:  # parameters were bit-identical to without them
            raise InputError(
                f"{', '.join(given)} {'applies' if len(given) == 1 else 'apply'} to the static stage, not to --systematic",
                field=given[0],
                expected="--systematic with the prior, the noise model, --cross-coupling, --allow-gaps, --set (docs/cli.md)",
            )
    elif getattr(args, "cross_coupling", False):
        raise InputError("--cross-coupling needs --systematic (the stage over indexed orientations)", field="--cross-coupling")


def run(args: Any) -> int:
    """Run ``stableins calibrate system``: the system-level stage on a static record; return the exit code."""
    _check_mode(args)
    if getattr(args, "systematic", False):
        from stableins.commands.calibrate_systematic import run as run_systematic

        return run_systematic(args)
    import warnings
    from dataclasses import replace

    from stableins.commands.noise import system_noise_prior
    from stableins.data.system import open_system_record
    from stableins.discovery.library import record_terms
    from stableins.output import emit, note
    from stableins.records import CalibrationRecord, InputFile, PriorReference, RunInfo, data_times, file_sha256, parse_entries

    prior = CalibrationRecord.load(args.prior)
    record = open_system_record(args.record)
    check_same_unit(record.metadata, prior, args.prior)
    values = prior.values()
    covariance = {(a, b): float(prior.covariance[i, j]) for i, a in enumerate(prior.ids) for j, b in enumerate(prior.ids)}
    options = _options(args)
    entries = parse_entries(args.set)
    noise, _ = system_noise_prior(args, default=prior.noise_model)
    from concurrent.futures import ThreadPoolExecutor

    # issue 30: the record's SHA-256 is computed in a thread while the pass reads the file (both from the page cache,
    # the hash releasing the interpreter), and the validation 'stableins check' runs is made inside the pass
    with ThreadPoolExecutor(max_workers=1) as hashing, warnings.catch_warnings(record=True) as caught:
        digest = hashing.submit(file_sha256, args.record)
        warnings.simplefilter("always")
        outcome = _stage(record, values, covariance, options, terms=record_terms(prior.ids), noise=noise, allow_gaps=args.allow_gaps)
        data_file = InputFile(str(args.record), digest.result())
    for w in caught:
        note(f"stableins: warning: {flag_text(str(w.message))}")
    start, end = data_times(record.metadata, *outcome.diagnostics.time_span)
    temperature = outcome.diagnostics.temperature
    reference = PriorReference(file_sha256(args.prior), str(args.prior), prior.calibration.created)
    procedure = str(record.metadata.extra.get("procedure", "system-static"))
    environment = {"temperature": {**temperature.to_dict(), "unit": "degC"}} if temperature else {}
    run = RunInfo(
        procedure=procedure, inputs=[data_file], data_start=start, data_end=end, sample_rate=record.sample_rate, environment=environment
    )
    updated = prior.updated(
        outcome.result, run, new_calibration=args.new_calibration, prior=reference, calibration_entries=entries, site=record.metadata
    )
    updated = replace(updated, noise_model=outcome.noise_model)  # the model under this stage's σ
    updated.save(args.out)
    if args.plot:
        plot(outcome, str(args.plot))

    data = _document(args, outcome, prior, updated)
    import shlex

    certificate = Path(args.out).with_name(f"{Path(args.out).stem}-report.pdf")
    command = shlex.join(["stableins", "report", str(args.out), "--data", str(args.record), "--out", str(certificate)])
    data["next"] = [command]
    emit(args, data, text=flag_text(system_report(outcome, updated, str(args.out))))
    import sys

    sys.stdout.flush()  # the next step is the last line, not scrolled away above the report
    note(f"next: the calibration certificate of {args.out}:\n  {command}")
    return 0


def _stage(record: Any, values: Any, covariance: Any, options: Any, *, terms: Any, noise: Any, allow_gaps: bool) -> Any:
    """Return the system stage's outcome on ``record`` with its Type B sensitivities, a progress bar over the one pass.

    The pass over the record (:func:`~stableins.estimators.system.stage.record_sums`) is made once: it validates the
    record as it reads it (:meth:`~stableins.data.system.SystemRecord.validating`: what ``stableins check`` runs, the
    two never disagree; a problem raises before anything is written), and the stage and every re-run of the
    sensitivities start from its sums (issue 30).
    """
    from stableins.estimators.system.sensitivity import with_sensitivities
    from stableins.estimators.system.stage import record_sums, run_system_stage
    from stableins.progress import CountedSource, Progress

    source = record.validating(allow_gaps=allow_gaps)
    with Progress(total=record.n_samples, label="system stage: one pass over the record") as bar:
        sums = record_sums(CountedSource(source, bar), record.metadata, values, options, compensation_terms=terms)
    outcome = run_system_stage(record, record.metadata, values, covariance, options, compensation_terms=terms, noise_model=noise, sums=sums)
    return with_sensitivities(outcome, record, values, covariance, options, compensation_terms=terms, noise_model=noise, sums=sums)


def _options(args: Any) -> Any:
    """Return the system stage's options (:class:`~stableins.estimators.system.stage.SystemOptions`) the flags set, in SI."""
    import math

    from stableins.conventions import MICRO_G, PPM
    from stableins.estimators.system.stage import SystemOptions
    from stableins.estimators.system.thermal import DEFAULT_THERMAL_PRIOR

    return SystemOptions(
        chunk_rows=args.chunk_rows,
        case_rotation_period=args.case_rotation_period or None,
        compensate_loop=not args.no_loop_compensation,
        couplings=not args.no_couplings,
        estimate_k2=args.estimate_k2,
        thermal_prior=DEFAULT_THERMAL_PRIOR
        if args.thermal_prior is None
        else (args.thermal_prior[0] * MICRO_G, args.thermal_prior[1] * PPM),
        known_gyro_drift=None
        if args.gyro_drift is None
        else cast("tuple[float, float, float]", tuple(math.radians(v) / 3600.0 for v in args.gyro_drift)),
        gyro_drift_uncertainty=None if args.gyro_drift_uncertainty is None else math.radians(args.gyro_drift_uncertainty) / 3600.0,
    )


def _document(args: Any, outcome: Any, prior: Any, updated: Any) -> dict[str, Any]:
    """Return the JSON document of the command (``--json``): the combinations, the record's parameters and the fit."""
    combined = outcome.combined
    fit = outcome.coloured_noise
    return {
        "record": args.record,
        "prior": args.prior,
        "out": str(args.out),
        "combined": [
            {"name": n, "value": float(v), "sigma": float(s), "status": st}
            for n, v, s, st in zip(combined.ids, combined.values, combined.sigma, combined.status, strict=True)
        ],
        "determined": [
            {"combination": name, "value": value, "sigma": sigma, "determined": ok}
            for name, (value, sigma, ok) in outcome.separation.combinations.items()
        ],
        "parameters": [
            {
                "id": p.id,
                "value": p.value,
                "sigma": p.sigma if p.sigma == p.sigma else None,
                "status": p.status.value,
                "prior_sigma": prior[p.id].sigma if p.id in prior.ids and prior[p.id].sigma == prior[p.id].sigma else None,
                "correction": p.value - prior[p.id].value if p.id in prior.ids else None,
                "last_determined_by": updated.source_text(p.id),
            }
            for p in updated.parameters
        ],
        "rank": outcome.result.rank,
        "chi2": outcome.result.chi2,
        "dof": outcome.result.dof,
        "chi2_red": outcome.result.chi2_red,
        "notes": [flag_text(n) for n in outcome.result.notes],  # the record's notes: the stage's and the update's
        "noise_model": outcome.noise_model.to_document(),
        "low_frequency_noise": None
        if fit is None
        else {
            "source": fit.source.name.lower(),
            "detected": fit.data_detected,
            "used_in_sigma": fit.detected,
            "likelihood_ratio": fit.statistic,
            "p_value": fit.p_value,
            "false_positive_rate": fit.alpha,
        },
        "diagnostics": outcome.diagnostics.to_dict(),
        "thermal": None if outcome.thermal is None else outcome.thermal.to_dict(),
    }


def flag_text(text: str) -> str:
    """Replace the system stage's parameter names in a library message by this command's flags.

    The parameters are named as the library's messages name them
    (:data:`stableins.estimators.system.assembly.GYRO_DRIFT_PARAMETER` and ``ESTIMATE_K2_PARAMETER``); the flags
    are those of this command that set them: what the command prints speaks of its flags.
    """
    from stableins.estimators.system.assembly import ESTIMATE_K2_PARAMETER, GYRO_DRIFT_PARAMETER

    for parameter, flag in ((GYRO_DRIFT_PARAMETER, "--gyro-drift X Y Z, deg/h"), (ESTIMATE_K2_PARAMETER, "--estimate-k2")):
        text = text.replace(parameter, flag)
    return text


def system_report(outcome: Any, record: Any, out: str) -> str:
    """Text report: combined coefficients, the stage's fit, and the record written (its statuses and σ, as in the PDF)."""
    c = outcome.combined
    r = outcome.result
    lines = ["combined coefficients (rad):", f"  {'name':<12} {'value':>12} {'1 sigma':>10}  status"]
    for n, v, s, st in zip(c.ids, c.values, c.sigma, c.status, strict=True):
        shown = f"{v:>12.4e} {s:>10.2e}" if st != Status.UNIDENTIFIABLE else f"{'—':>12} {'—':>10}"
        lines.append(f"  {n:<12} {shown}  {st}")
    fit = outcome.coloured_noise
    lines += ["", outcome.noise_model.report()]
    if fit is not None:
        lines.append(fit.describe())
    lines += [
        "",
        f"stage: system; chi2_red = {r.chi2_red:.3f} (nu = {r.dof}, expected 1 ± {(2 / max(r.dof, 1)) ** 0.5:.2f}); rank = {r.rank}",
        "",
        record.report(),
        "",
        f"updated calibration written to {out}",
    ]
    return "\n".join(lines)


def plot(outcome: Any, path: str) -> None:
    """Convergence of the five harmonic states and the attitude residuals."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from stableins.data.atomic import atomic_path

    fig, axes = plt.subplots(2, 1, figsize=(10, 7))
    if outcome.history is not None:
        hours = outcome.history_time / 3600.0
        sig = np.sqrt(np.diagonal(outcome.history.covariances, axis1=1, axis2=2))
        for k in range(5):
            line = axes[0].plot(hours, outcome.history.means[:, k] * 1e6, label=f"x{k + 1}")[0]
            axes[0].fill_between(
                hours,
                (outcome.history.means[:, k] - sig[:, k]) * 1e6,
                (outcome.history.means[:, k] + sig[:, k]) * 1e6,
                color=line.get_color(),
                alpha=0.15,
            )
        axes[0].set_xlabel("time [h]")
        axes[0].set_ylabel("state [µrad]")
        axes[0].legend(ncol=5, fontsize=8)
        axes[0].set_title("Kalman filter convergence (decimated bins, ±1σ)")
    res = outcome.attitude.block_residuals
    axes[1].plot(res[:, 0] * 1e6, lw=0.6, label="pitch")
    axes[1].plot(res[:, 1] * 1e6, lw=0.6, label="roll")
    axes[1].set_xlabel("attitude block")
    axes[1].set_ylabel("residual [µrad]")
    axes[1].legend()
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=110)
    plt.close(fig)
