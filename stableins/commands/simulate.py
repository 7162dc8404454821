"""``stableins simulate device|system``: data with a known truth, written to a directory.

::

    stableins simulate device --seed 3 --out sim/ [--procedure device-coarse --procedure device-fine]
    stableins simulate system --seed 3 --out sim/ [--duration 1d] [--rate 100]
    stableins simulate device --truth sim/truth.json --hidden Kcc_xxy=60ug/g2 --out sim2/
    stableins simulate --list-effects
    stableins simulate device --world lab --out sim/   # a named world (docs/simulator.md, "Worlds"; --list-worlds)

The directory receives the data (``device-coarse.csv``, ``device-fine.h5`` ... one file
per procedure, or ``system.h5``) and
``truth.json``, the simulated world (parameters, injected effects, noise, seed).  The data
files carry only what a real site would know (site metadata), never the truth.
"""

from __future__ import annotations

import argparse
import math
import os
from pathlib import Path
from typing import Any, TypedDict

from stableins.errors import InputError
from stableins.estimators.device_settings import DEFAULT_PROCEDURES
from stableins.schema import Columns

#: Suffixes accepted by ``--duration`` and their length in seconds.
DURATION_UNITS = {"s": 1.0, "min": 60.0, "h": 3600.0, "d": 86400.0}
#: Longest record ``--duration`` accepts [s] (30 days).
MAX_DURATION = 30 * 86400.0
#: Above this many rows a device file defaults to HDF5 (a 10-min-per-position fine stage is 1 M rows).
CSV_ROW_LIMIT = 100_000


def parse_duration(text: str) -> float:
    """``"90"``, ``"90s"``, ``"30min"``, ``"6h"``, ``"1d"`` → seconds (argparse type)."""
    text = text.strip()
    for unit in sorted(DURATION_UNITS, key=len, reverse=True):
        if text.endswith(unit):
            number, factor = text[: -len(unit)], DURATION_UNITS[unit]
            break
    else:
        number, factor = text, 1.0
    try:
        value = float(number) * factor
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a duration (expected e.g. 600, 600s, 30min, 6h, 1d)") from None
    if not math.isfinite(value) or value <= 0 or value > MAX_DURATION:
        raise argparse.ArgumentTypeError(f"{text!r}: a duration must be positive and at most {MAX_DURATION / 86400:g} days")
    return value


class EffectRow(TypedDict):
    """One effect the simulator can hide (``simulate --list-effects``): its nominal size in SI and in engineering units."""

    id: str
    unit: str
    nominal: float
    engineering_unit: str
    nominal_engineering: float
    meaning: str


class WrittenFile(TypedDict):
    """A device data file ``simulate device`` wrote: its rows, procedure, stage and coarse passes."""

    path: str
    rows: int
    procedure: str
    stage: str
    passes: int


class SystemFile(TypedDict):
    """The system record ``simulate system`` wrote."""

    path: str
    rows: int
    duration_s: float
    rate_hz: float


def effect_rows() -> list[EffectRow]:
    """Return the simulator's effects with their nominal size in SI (``unit``, ``nominal``) and in engineering units."""
    from stableins.discovery.library import all_terms
    from stableins.simulator.effects import catalogue_table

    terms = all_terms()
    rows: list[EffectRow] = []
    for effect_id, unit, nominal, meaning in catalogue_table():
        term = terms[effect_id]
        rows.append(
            {
                "id": effect_id,
                "unit": unit,
                "nominal": nominal,
                "engineering_unit": term.unit,
                "nominal_engineering": float(term.sigma_to_engineering(nominal)),
                "meaning": meaning,
            }
        )
    return rows


def levels() -> tuple[str, ...]:
    """Return the simulation levels this installation provides (the system level needs ``stableins.simulator.system``)."""
    import importlib.util

    return ("device", "system") if importlib.util.find_spec("stableins.simulator.system") else ("device",)


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the arguments of ``stableins simulate`` to ``parser``."""
    from stableins.commands.arguments import effect_magnitude, output_directory, real, seed

    parser.add_argument("level", nargs="?", choices=levels(), help="device-level dwells or a system-level static record")
    parser.add_argument("--out", type=output_directory, metavar="DIR", help="output directory (created if needed)")
    parser.add_argument(
        "--seed", type=seed, default=None, help="random seed of the truth draw and the noise (default 0, or the truth file's)"
    )
    parser.add_argument("--truth", type=Path, metavar="FILE", help="simulate this truth (a truth.json) instead of drawing one")
    parser.add_argument(
        "--hidden",
        type=effect_magnitude,
        action="append",
        default=[],
        metavar="ID=VALUE",
        help="inject an effect of the catalogue: VALUE in its engineering unit (Kcc_xxy=60ug/g2) or SI (a bare number); "
        "repeatable; see --list-effects",
    )
    parser.add_argument(
        "--format",
        choices=("csv", "h5"),
        help=f"data format (default: csv for device files under {CSV_ROW_LIMIT} rows, h5 otherwise and for system records)",
    )
    parser.add_argument(
        "--rate", type=real(0.0, 10000.0, above=True, unit="Hz"), metavar="HZ", help="sample rate [Hz] (default: the truth's, 100 Hz)"
    )
    parser.add_argument(
        "--duration",
        type=parse_duration,
        default=None,
        help="system: record length, e.g. 30h, 2d (default one sidereal day, 23.93 h: the least that separates the Earth-rate harmonics)",
    )
    parser.add_argument(
        "--procedure",
        action="append",
        metavar="NAME",
        help="device: procedure name or TOML file, repeatable (default: device-coarse and device-fine)",
    )
    parser.add_argument(
        "--dwell",
        type=real(0.0, 86400.0, above=True, unit="seconds"),
        metavar="S",
        help="device: override the procedure's dwell time [s]",
    )
    parser.add_argument(
        "--settle", type=real(0.0, 86400.0, unit="seconds"), metavar="S", help="device: override the procedure's settling time [s]"
    )
    parser.add_argument(
        "--installed",
        type=Path,
        metavar="CAL.json",
        help="system: the INS compensates with this calibration record (default: the truth's installed calibration)",
    )
    parser.add_argument(
        "--no-iteration",
        action="store_true",
        help="device: one pass of every procedure at its nominal commands (default: the coarse zero-offset iteration, "
        "then fine dwells at the re-pointed positions)",
    )
    parser.add_argument(
        "--world",
        metavar="NAME",
        help="a named world on the drawn (or --truth) instrument: slow noise, thermal history, drift ... "
        "(default: the simulator's default world); see --list-worlds and docs/simulator.md 'Worlds'",
    )
    parser.add_argument("--list-worlds", action="store_true", help="list the named worlds (what each adds, its numbers, their source)")
    parser.add_argument(
        "--list-effects", action="store_true", help="list the injectable effects (id, nominal size in engineering and SI units, meaning)"
    )


def prepare_directory(out: Path | None) -> Path:
    """Create ``out`` and check it is writable (InputError naming ``--out`` otherwise)."""
    if out is None:
        raise InputError("no output directory given", field="--out", expected="--out DIR")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise InputError(f"cannot create the output directory: {error.strerror}", path=out, field="--out") from None
    if not out.is_dir() or not os.access(out, os.W_OK | os.X_OK):
        raise InputError("the output directory is not writable", path=out, field="--out", expected="a writable directory")
    return out


def _device_lead() -> float:
    """Return how long before now a simulated device session ends [s]: one sidereal day and ten minutes.

    A system day simulated next (ending now) then starts after the device calibration it is compensated with.
    """
    from stableins.conventions import SIDEREAL_DAY

    return float(SIDEREAL_DAY) + 600.0


def simulation_start(duration: float) -> str:
    """UTC time of time 0 of simulated data lasting ``duration`` seconds: they end now (to the second)."""
    from datetime import UTC, datetime, timedelta

    return (datetime.now(UTC) - timedelta(seconds=round(duration))).replace(microsecond=0).isoformat()


def installed_from_record(path: Path, truth: Any) -> dict[str, float]:
    """Parameter values of a calibration record, as the calibration the simulated INS runs with (:meth:`Truth.with_installed`).

    Unidentifiable parameters carry their prior value in a record, which is what an INS would be loaded with.
    """
    from stableins.records import CalibrationRecord

    record = CalibrationRecord.load(path)
    return dict(truth.with_installed(record.values(), source=str(path)).installed_calibration)


def build_truth(args: argparse.Namespace) -> Any:
    """Return the truth to simulate: read or drawn, with ``--hidden`` effects added and checked."""
    from stableins.data.truth import load_truth
    from stableins.simulator.effects import validate_effects
    from stableins.simulator.truth import DEFAULT_SITE, SimulatedSite, Truth

    if args.truth is not None:
        truth = load_truth(args.truth)
    else:
        site = DEFAULT_SITE if args.rate is None else SimulatedSite(sample_rate=args.rate)
        truth = Truth.draw(0 if args.seed is None else args.seed, site=site)
    if getattr(args, "world", None) is not None:
        from stableins.simulator.worlds import apply_world, world

        truth = apply_world(truth, world(args.world, field="--world"))
    if getattr(args, "installed", None) is not None:
        truth = truth.with_changes(installed_calibration=installed_from_record(args.installed, truth))
    if args.hidden:
        effects = dict(truth.effects)
        effects.update(dict(args.hidden))
        truth = truth.with_changes(effects=validate_effects(effects, source="--hidden"))
    return truth


def run(args: argparse.Namespace) -> int:
    """Run ``stableins simulate``: data with a known truth, written to a directory; return the exit code."""
    from stableins.data.truth import save_truth
    from stableins.output import emit, note

    if args.list_effects or getattr(args, "list_worlds", False):
        _list_catalogue(args)
        return 0
    if args.level is None:
        raise InputError("which level?", field="LEVEL", expected="'device' or 'system' (or --list-effects)")
    if args.level == "system" and (args.procedure or args.dwell is not None or args.settle is not None):
        raise InputError("--procedure, --dwell and --settle apply to device-level simulation only", field="--procedure")
    if args.level == "device" and args.duration is not None:
        raise InputError("--duration applies to system-level simulation only (device timing comes from the procedure)", field="--duration")
    truth = build_truth(args)
    procedures = _device_procedures(args) if args.level == "device" else []  # all checked before anything is written
    if procedures:
        truth = _held_as_declared(truth, procedures)
    existed = args.out is not None and Path(args.out).exists()
    out = prepare_directory(args.out)
    before = set(out.iterdir())
    seed = truth.seed if args.seed is None else args.seed
    truth_path = out / "truth.json"
    try:
        save_truth(truth, truth_path)  # first: every data file in DIR has its truth beside it
        note(f"truth written to {truth_path}")
        files = (
            simulate_device(truth, out, seed, args, procedures)
            if args.level == "device"
            else [simulate_system_file(truth, out, seed, args)]
        )
    except BaseException:  # nothing left behind: the files this run created go (what was there stays)
        for path in set(out.iterdir()) - before:
            if path.is_file():
                path.unlink()
        if not existed and not any(out.iterdir()):
            out.rmdir()
        raise
    result = {"out": str(out), "truth": str(truth_path), "seed": seed, "files": files}
    lines = [f"{f['path']}: {f['rows']} rows" for f in files] + [f"truth: {truth_path}"]
    emit(args, result, "\n".join(lines))
    return 0


def _list_catalogue(args: argparse.Namespace) -> None:
    """Print what the simulator can inject (``--list-effects``) or the worlds it draws (``--list-worlds``)."""
    from stableins.output import emit

    if args.list_effects:
        rows = effect_rows()
        lines = [f"{'id':<16} {'nominal':>9} {'unit':<9} {'nominal (SI)':>12} {'SI unit':<14} meaning"]
        row = "{id:<16} {nominal_engineering:>9.3g} {engineering_unit:<9} {nominal:>12.3g} {unit:<14} {meaning}"
        lines += [row.format(**r) for r in rows]
        lines.append("--hidden ID=VALUE takes VALUE in the engineering unit (Kcc_xxy=60ug/g2) or in SI (a bare number: Kcc_xxy=6e-6)")
        emit(args, {"effects": rows}, "\n".join(lines))
        return
    from stableins.simulator.worlds import WORLDS

    worlds = [{"name": w.name, "summary": w.summary, "slow_noise": w.slow_noise, "sources": list(w.sources)} for w in WORLDS.values()]
    emit(args, {"worlds": worlds}, "\n".join(line for w in WORLDS.values() for line in w.describe()))


def _held_as_declared(truth: Any, procedures: list[Any]) -> Any:
    """Return the truth whose platform holds its dwells as the procedures declare (``[procedure] dwell_mode``)."""
    from dataclasses import replace

    modes = {p.dwell_mode for p in procedures}
    if len(modes) > 1:
        named = ", ".join(f"{p.name}: {p.dwell_mode}" for p in procedures)
        raise InputError(f"the procedures declare different dwell modes ({named})", field="--procedure", expected="one dwell_mode")
    return truth.with_changes(site=replace(truth.site, dwell_mode=modes.pop()))


def _device_procedures(args: argparse.Namespace) -> list[Any]:
    """Return the device-level procedures of this simulation, loaded, validated and with the ``--dwell``/``--settle`` timing."""
    from stableins.procedures.definition import load_procedure

    return [_with_timing(load_procedure(name), args.dwell, args.settle) for name in args.procedure or DEFAULT_PROCEDURES]


def simulate_device(truth: Any, out: Path, seed: int, args: argparse.Namespace, procedures: list[Any]) -> list[WrittenFile]:
    """One file per procedure: ``<procedure name>.<format>`` (e.g. ``device-coarse.csv``).

    By default the session is what the device-level procedure does on a real platform,
    through the same driver interface: the coarse passes of the zero-offset iteration
    (the gimbals re-commanded by −θ̂20, −θ̂30 after each pass until the offsets vanish,
    :func:`stableins.procedures.iteration.iterate_offsets`), then the fine dwells
    at the re-pointed positions.  ``--no-iteration`` records one pass of every procedure
    at its nominal commands instead.
    """
    from dataclasses import replace

    from stableins.data.device import save_device
    from stableins.progress import Progress

    rate = args.rate or truth.site.sample_rate
    if getattr(args, "no_iteration", False):
        sessions = _single_passes(truth, procedures, rate, seed)
    else:
        sessions = _iterated_session(truth, procedures, rate, seed)
    files: list[WrittenFile] = []
    # dated so that the system day 'simulate system' writes next (ending now) starts after them, as on a real
    # platform: the device calibration first, then the day that compensates with it (DEVICE_LEAD before now)
    span = max(float(c["time"][-1]) for _, c in sessions if len(c["time"])) if sessions else 0.0
    start = simulation_start(span + _device_lead())
    with Progress(total=len(sessions), label="write device data") as progress:
        for procedure, columns in sessions:
            metadata = replace(truth.site, sample_rate=rate, extra={**truth.site.extra, "procedure": procedure.name}, start_time=start)
            n = len(columns["time"])
            suffix = args.format or ("csv" if n <= CSV_ROW_LIMIT else "h5")
            path = save_device(out / f"{procedure.name}.{suffix}", columns, metadata)
            passes = int(columns["pass"].max()) if n else 0
            files.append({"path": str(path), "rows": n, "procedure": procedure.name, "stage": procedure.stage, "passes": passes})
            progress.update()
    return files


def _with_timing(procedure: Any, dwell: float | None, settle: float | None) -> Any:
    """Return the procedure with ``--dwell`` / ``--settle`` applied to every step."""
    from dataclasses import replace

    if dwell is None and settle is None:
        return procedure
    steps = tuple(
        replace(s, dwell=s.dwell if dwell is None else dwell, settle=s.settle if settle is None else settle) for s in procedure.steps
    )
    return replace(procedure, steps=steps)


def _single_passes(truth: Any, procedures: list[Any], rate: float, seed: int) -> list[tuple[Any, Columns]]:
    from stableins.simulator.device import simulate_dwells

    sessions = []
    for k, procedure in enumerate(procedures):
        steps = procedure.steps
        columns = simulate_dwells(
            truth,
            [s.command for s in steps],
            dwell=steps[0].dwell,
            settle=steps[0].settle,
            rate=rate,
            seed=seed + k,
            stage=procedure.stage,
            pass_number=1,
        )
        sessions.append((procedure, columns))
    return sessions


def _iterated_session(truth: Any, procedures: list[Any], rate: float, seed: int) -> list[tuple[Any, Columns]]:
    """Coarse zero-offset iteration, then fine dwells, on one simulated platform session."""
    from stableins.drivers.recording import RecordingDriver
    from stableins.procedures.iteration import OffsetIterationError, iterate_offsets, measure_pass
    from stableins.simulator.device import SimulatedPlatform

    driver = RecordingDriver(SimulatedPlatform(truth, rate=rate, seed=seed))
    offsets = (0.0, 0.0, 0.0)
    sessions = []
    for procedure in procedures:
        positions = [s.position for s in procedure.steps]
        if procedure.stage == "coarse" and procedure.repoint:
            try:
                iteration = iterate_offsets(driver, procedure)
            except OffsetIterationError as error:
                raise InputError(
                    f"the zero-offset iteration did not converge on the simulated platform:\n{error}",
                    path=procedure.path or procedure.name,
                    field="offset_iteration",
                    expected="longer dwells or more passes",
                ) from None
            offsets = iteration.offsets
        else:
            measure_pass(driver, procedure, offsets, stage=procedure.stage, pass_number=1)
        sessions.append((procedure, driver.take(procedure.stage, positions)))
    return sessions


def simulate_system_file(truth: Any, out: Path, seed: int, args: argparse.Namespace) -> SystemFile:
    """``system.<format>``, streamed chunk by chunk."""
    from dataclasses import replace

    from stableins.data.system import SystemRecordWriter
    from stableins.progress import Progress
    from stableins.simulator.system import system_record_chunks

    suffix = args.format or "h5"
    rate = args.rate or truth.site.sample_rate
    from stableins.conventions import SIDEREAL_DAY

    duration = args.duration or SIDEREAL_DAY
    chunk_samples = 65536
    # the truth puts its damping-loop parameters in site.damping; time 0 of the record is the simulation's start
    metadata = replace(truth.site, sample_rate=rate, start_time=simulation_start(duration))
    path = out / f"system.{suffix}"
    total = int(round(duration * rate))
    with (
        SystemRecordWriter(path, metadata, chunk_samples=chunk_samples) as writer,
        Progress(total=total, label="simulate system") as progress,
    ):
        for chunk in system_record_chunks(truth, duration, rate, seed, chunk_samples=chunk_samples):
            writer.append(chunk)
            progress.update(len(chunk["time"]))
    return {"path": str(path), "rows": writer.n_samples, "duration_s": duration, "rate_hz": rate}
