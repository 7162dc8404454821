"""A procedure run, from its first command to its filed record and certificate.

:func:`start_run` and :func:`resume_run` execute a plan on a platform through the runner
(:mod:`stableins.procedures.runner`, journaled, resumable), write the accepted data
(:mod:`stableins.procedures.rundir`), run the stage's estimation and file what the run produced: the one
calibration record (the prior updated by the stage, or the stage's own record) and its certificate.  Filing
and certifying are the records-and-reports layer's (docs/architecture.md), so this module sits there, above
the procedures.  The layout of a run directory is in :mod:`stableins.procedures.rundir` and docs/procedures.md.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

import stableins
from stableins.documents import JSONObject
from stableins.drivers.base import PlatformDriver
from stableins.drivers.select import is_deterministic
from stableins.errors import InputError
from stableins.procedures.entries import accepted_columns, resume_script
from stableins.procedures.journal import JOURNAL_NAME, Journal, has_start, remove_unlinked, scan
from stableins.procedures.plan import Plan, StaticRecordStep, SystemEstimation
from stableins.procedures.reachable import check_reachable
from stableins.procedures.replay import open_run_driver
from stableins.procedures.rundir import (
    DEFINITION_NAME,
    PLAN_NAME,
    PRIOR_NAME,
    RECORD_NAME,
    REPORT_NAME,
    TRUTH_NAME,
    RunOutcome,
    check_capabilities,
    check_settings,
    copy_input,
    export,
    exported_columns,
    install_prior,
    journal_finished,
    model_terms,
    resume_driver,
    resume_mode,
    resume_spec,
    utc_now,
    write_plan,
)
from stableins.procedures.runlock import RunLock
from stableins.procedures.runner import RunConsole, Runner, RunOptions
from stableins.procedures.session import Session
from stableins.schema import Columns
from stableins.site import SiteMetadata


@dataclass(frozen=True)
class RunSetup:
    """What a new run starts with besides its plan, its platform and its console.

    Parameters
    ----------
    definition_file : path, optional
        The procedure TOML, copied into the run directory.
    prior_file : path, optional
        A calibration record whose zero offsets re-point the gimbals and which a fine or system stage
        updates; copied into the run directory.
    new_calibration : bool
        The run starts a new calibration from the prior (a record in force, e.g. a field
        recalibration) instead of continuing the prior's calibration (e.g. the fine stage after the
        coarse stage of the same calibration).
    fields : mapping of str to str
        ``--set`` values: the answers to the procedure's prompts and the calibration's own fields.
    options : RunOptions, optional
        Runner options that are not part of the procedure.
    timeout : float
        Seconds a network platform may take to answer.
    recal : mapping, optional
        The run is a field recalibration (``stableins recal``): ``store`` (the history store its record is filed in,
        or None) and ``file`` (whether to file it); kept in the start record so that a resume, by ``recal --resume``
        or ``run --resume``, files the one new record and prints its changes as the recalibration would have.
    truth : Truth, optional
        The simulated platform simulates this :class:`~stableins.simulator.truth.Truth` (``run --truth``,
        ``--hidden``) instead of drawing one from the seed; written into the run directory (``truth.json``), which
        a resume simulates again.
    """

    definition_file: str | os.PathLike[str] | None = None
    prior_file: str | os.PathLike[str] | None = None
    new_calibration: bool = False
    fields: Mapping[str, str] = field(default_factory=dict)
    options: RunOptions | None = None
    timeout: float = 10.0
    recal: Mapping[str, Any] | None = None
    truth: Any = None


def start_run(
    plan: Plan,
    rundir: str | os.PathLike[str],
    *,
    driver_spec: str,
    seed: int | None = None,
    unit: str | None = None,
    console: RunConsole,
    driver: PlatformDriver | None = None,
    setup: RunSetup | None = None,
) -> RunOutcome:
    """Start a new run of ``plan`` in ``rundir`` (which must not hold a journal yet).

    The definition file and the prior record of ``setup`` (:class:`RunSetup`) are copied into the
    run directory first, so that a resumed run needs nothing from outside it.
    """
    rundir = Path(rundir)
    with RunLock.acquire(rundir):  # before anything is written: one run per directory
        return _start_locked(plan, rundir, driver_spec=driver_spec, seed=seed, unit=unit, console=console, driver=driver, setup=setup)


def _needed_prior(plan: Plan, prior_file: str | os.PathLike[str] | None, *, unit: str | None, definition: bool) -> Any:
    """Return the unit's record the run starts from (None without ``--prior``): checked before anything moves.

    A procedure's system-level stage and its fine stage need one (they estimate corrections to it, or re-point by its
    zero offsets); it must be of ``unit``.
    """
    prior = _load_record(prior_file) if prior_file is not None else None
    fine = any(getattr(step, "stage", "") == "fine" for step in plan.steps)
    if definition and plan.level == "system" and prior is None:
        raise InputError(
            "the system-level stage estimates corrections to the calibration the INS navigates with",
            field="prior_file",
            expected="--prior RECORD (the unit's record in force) or --store DIR",
        )
    if definition and fine and prior is None:
        raise InputError(
            "the fine stage starts from the unit's coarse estimate and re-points by its zero offsets",
            field="prior_file",
            expected="--prior RECORD (e.g. the coarse run's record.json) or --store DIR with the unit's history",
        )
    if prior is not None and unit is not None and prior.serial_number != unit:
        raise InputError(f"the prior record is of unit {prior.serial_number!r}", path=prior_file, field="unit", expected=repr(unit))
    return prior


def _start_locked(
    plan: Plan,
    rundir: Path,
    *,
    driver_spec: str,
    seed: int | None,
    unit: str | None,
    console: RunConsole,
    driver: PlatformDriver | None,
    setup: RunSetup | None,
) -> RunOutcome:
    """:func:`start_run` while this process holds the run directory's lock."""
    setup = setup or RunSetup()
    definition_file, prior_file, options = setup.definition_file, setup.prior_file, setup.options
    journal_file = rundir / JOURNAL_NAME
    remove_unlinked(journal_file)  # a start killed before its journal existed: nothing happened
    if journal_file.exists():
        if has_start(journal_file):
            raise InputError(
                "this run directory already holds a run", path=rundir, expected="a new directory, or 'stableins run --resume RUNDIR'"
            )
        journal_file.unlink()  # a start that died before its first record (an earlier version): nothing happened, start afresh
    prior = _needed_prior(plan, prior_file, unit=unit, definition=definition_file is not None)
    check_settings(plan, console.values)
    rate, truth = plan.sample_rate, setup.truth
    driver = driver or open_run_driver(driver_spec, seed=seed, unit=unit, sample_rate=rate, timeout=setup.timeout, truth=truth)
    try:
        install_prior(driver, plan, prior, prior_file)  # a simulated INS navigates with --prior, as a real one is loaded
        metadata = driver.metadata
        if unit is not None and metadata.serial_number != unit:
            raise InputError(f"the platform reports unit {metadata.serial_number!r}", field="unit", expected=repr(unit))
        check_reachable(plan, metadata, definition_file)  # an index that locks the gimbals: refused before anything moves
        if definition_file is not None:  # the platform holds its dwells as the procedure declares
            from stableins.procedures.definition import load_procedure

            load_procedure(Path(definition_file)).check_dwell_mode(metadata)
        check_capabilities(driver, plan)  # a network platform without the INS's outputs: refused before anything moves
        digests = {}
        for source, name in ((definition_file, DEFINITION_NAME), (prior_file, PRIOR_NAME)):
            if source is not None:
                digests[name] = copy_input(Path(source), rundir / name)
        if setup.truth is not None:  # the world the simulated platform runs, kept with the run (and simulated again on resume)
            from stableins.data.truth import save_truth
            from stableins.records import file_sha256

            save_truth(setup.truth, rundir / TRUTH_NAME)
            digests[TRUTH_NAME] = file_sha256(rundir / TRUTH_NAME)
        write_plan(rundir, plan)
        journal = Journal.create(
            journal_file,
            first=(
                "start",
                {
                    "version": stableins.__version__,
                    "utc": utc_now(),
                    "plan": plan.to_dict(),
                    "driver": driver_spec,
                    "seed": seed,
                    "unit": metadata.serial_number,
                    "metadata": metadata.to_dict(),
                    "deterministic": is_deterministic(driver),
                    "options": vars(options or RunOptions()),
                    "definition": DEFINITION_NAME if definition_file is not None else None,
                    "prior": PRIOR_NAME if prior_file is not None else None,
                    "prior_path": str(prior_file) if prior_file is not None else None,
                    "new_calibration": bool(setup.new_calibration),
                    "fields": dict(setup.fields),
                    "inputs": digests,  # SHA-256 of the copies: a resume verifies every file it reads again
                    "recal": dict(setup.recal) if setup.recal is not None else None,
                    "truth": TRUTH_NAME if setup.truth is not None else None,
                },
            ),
        )
        with journal:
            console.say(f"run of {plan.name!r} on unit {metadata.serial_number} ({driver_spec}) in {rundir}")
            runner = _runner(rundir, plan, Session(journal, [], driver, forward=False), console, options=options, start=journal.records[0])
            runner.execute()
            outcome = finish(rundir, runner, metadata, journal.records[0], replayed=0)
            journal_finished(journal, outcome)
            return outcome
    finally:
        driver.close()


def resume_run(
    rundir: str | os.PathLike[str],
    *,
    console: RunConsole,
    driver_spec: str | None = None,
    driver_factory: Callable[[JSONObject], PlatformDriver] | None = None,
    timeout: float = 10.0,
    re_estimate: bool = False,
) -> RunOutcome:
    """Continue the run in ``rundir`` where it stopped.

    ``driver_spec`` may replace the journaled one for a network platform that moved
    (``tcp://`` to ``tcp://``); the simulated platform is rebuilt from the journaled seed.

    A finished run (its journal holds the ``complete`` record) is not run again: :class:`RunFinished` says so.
    ``re_estimate`` estimates a finished run again from its journal alone (no platform is opened, nothing is
    appended to the journal) and writes its data set, record and certificate anew, e.g. with a newer stableins.
    A run killed after its last step but before its outputs were all written (no ``finished`` record,
    :data:`FINISHED`) is finished that way on resume, and then journaled as finished.

    Raises
    ------
    RunFinished
        The run is complete and ``re_estimate`` is false.
    InputError
        ``re_estimate`` of a run that is not complete; a changed input; a journal without a start record.
    """
    rundir = Path(rundir)
    if not rundir.is_dir():
        raise InputError("no run journal here (no such directory)", path=rundir, expected="a run directory made by 'stableins run'")
    with RunLock.acquire(rundir):  # before anything is written: one run per directory
        return _resume_locked(rundir, console=console, driver_spec=driver_spec, driver_factory=driver_factory, timeout=timeout,
                              re_estimate=re_estimate)  # fmt: skip


def _resume_locked(
    rundir: Path,
    *,
    console: RunConsole,
    driver_spec: str | None,
    driver_factory: Callable[[JSONObject], PlatformDriver] | None,
    timeout: float,
    re_estimate: bool,
) -> RunOutcome:
    """:func:`resume_run` while this process holds the run directory's lock."""
    journal_file = rundir / JOURNAL_NAME
    started = journal_file.exists() or (rundir / PLAN_NAME).exists()
    if started and not has_start(journal_file) and not scan_has_records(journal_file):
        raise InputError(
            "the run in this directory was stopped before its first record: nothing was done, so there is nothing to resume",
            path=rundir,
            expected="the command that started it, run again (it starts afresh in the same directory)",
        )
    journal = Journal.open(journal_file)
    with journal:
        if not journal.records or journal.records[0].kind != "start":
            raise InputError(
                "the journal holds no start record: nothing to resume", path=journal.path, expected="a run started with 'stableins run'"
            )
        start = journal.records[0]
        plan = Plan.from_dict(start["plan"])
        re_estimate, journal_finish = resume_mode(rundir, journal, console, re_estimate=re_estimate)
        spec = resume_spec(start["driver"], driver_spec)
        check_settings(plan, console.values)
        verify_inputs(rundir, start)  # before the platform is touched: what is read again is what the run started with
        if journal.recovered is not None:
            torn = journal.recovered
            console.say(f"journal: dropped a torn last record ({torn.torn_bytes} bytes, {torn.torn_reason}) left by the interruption")
        truth = _kept_truth(rundir, start)  # a known world (run --truth): simulated again, as verified above
        driver = resume_driver(start, spec, plan, re_estimate=re_estimate, driver_factory=driver_factory, timeout=timeout, truth=truth)
        try:
            install_prior(driver, plan, _load_record(rundir / start["prior"]) if start.get("prior") else None, start.get("prior"))
            metadata = driver.metadata
            if metadata.serial_number != start["unit"]:
                raise InputError(
                    f"the platform reports unit {metadata.serial_number!r}, this run is of unit {start['unit']!r}", field="driver_spec"
                )
            if not re_estimate:
                check_capabilities(driver, plan)
            deterministic = is_deterministic(driver)
            script, superseded = resume_script(journal.records, deterministic=deterministic or re_estimate)
            if re_estimate:
                what = f"{plan.name!r} of unit {start['unit']}"
                console.say(f"estimating the finished run {what} again from its journal ({len(script)} records)")
            else:
                journal.append(
                    "resume",
                    {
                        "utc": utc_now(),
                        "superseded": list(superseded) if superseded else None,
                        "deterministic": deterministic,
                        "driver": spec,
                    },
                )
                how = "continuing exactly where it stopped" if deterministic else "repeating the interrupted attempt from its command"
                console.say(f"resuming {plan.name!r} on unit {start['unit']}: {len(script)} journaled records to replay, then {how}")
            session = Session(journal, script, driver, forward=deterministic and not re_estimate)
            if re_estimate:
                session.on_live = lambda replayed: None  # the journal is the whole run: nothing goes live
            runner = _runner(rundir, plan, session, console, options=RunOptions(**start.get("options", {})), start=start)
            runner.execute()
            outcome = finish(rundir, runner, metadata, start, replayed=session.replayed)
            outcome.superseded = superseded
            if journal_finish:
                journal_finished(journal, outcome)
            return outcome
        finally:
            driver.close()


def _kept_truth(rundir: Path, start: Any) -> Any:
    """Return the simulated world a run started with ``--truth`` or ``--hidden`` keeps (``truth.json``), or None."""
    if not start.get("truth"):
        return None
    from stableins.data.truth import load_truth

    return load_truth(rundir / str(start["truth"]))


def scan_has_records(path: Path) -> bool:
    """Whether the journal at ``path`` exists and holds a whole record (False for a missing, empty or header-only file)."""
    if not path.exists():
        return False
    return bool(scan(path).records)


def verify_inputs(rundir: Path, start: Any) -> None:
    """Every file of the run directory a resume reads again has the SHA-256 the start record holds.

    Raises
    ------
    InputError
        Naming the file, the digest found and the digest the journal holds (edited acceptance limits or a replaced
        prior would otherwise change the estimation of a run in progress silently).
    """
    from stableins.records import file_sha256

    expected = start.get("inputs")
    if not isinstance(expected, dict):  # a journal written before digests were kept: nothing to compare with
        return
    for name, digest in expected.items():
        path = rundir / str(name)
        found = file_sha256(path)
        if found != digest:
            raise InputError(
                f"changed since the run started (SHA-256 {found}); a resumed run must read what it started with",
                path=path,
                field="sha256",
                expected=f"SHA-256 {digest}, as the journal's start record holds",
            )


def _runner(rundir: Path, plan: Plan, session: Session, console: RunConsole, *, options: RunOptions | None, start: Any) -> Runner:
    """Build the runner of ``plan`` with the definition, prior zero offsets and discovered terms the start record names."""
    definition = None
    if start.get("definition"):
        from stableins.procedures.definition import load_procedure

        definition = load_procedure(rundir / start["definition"])
    offsets = (0.0, 0.0, 0.0)
    prior = None
    if start.get("prior"):
        prior = _load_record(rundir / start["prior"])
        values = prior.values()
        offsets = cast("tuple[float, float, float]", tuple(float(values.get(k, 0.0)) for k in ("theta10", "theta20", "theta30")))
    extra = model_terms(definition, prior)
    return Runner(plan, session, console, options, definition=definition, offsets=offsets, extra_terms=extra)


def finish(rundir: Path, runner: Runner, metadata: SiteMetadata, start: Any, *, replayed: int) -> RunOutcome:
    """After the last step: write the data set, run the stage's estimation, write the one record and its certificate."""
    from dataclasses import replace

    if not metadata.start_time:  # time 0 of the platform's session: the run's start, to the second
        metadata = replace(metadata, start_time=start.get("utc", ""))
    dataset = export(rundir, runner, metadata)
    outcome = RunOutcome(rundir, runner, dataset, replayed)
    fit = _estimate(rundir, runner, metadata, dataset, start)
    if fit is None:
        return outcome
    from stableins.records import CalibrationRecord, PriorReference, RunInfo, file_sha256

    columns = exported_columns(runner, dataset)
    # the calibration date: when the run took its data, by the wall clock of the journal (a simulated platform's
    # session clock runs faster than the wall clock; a real platform's follows it)
    complete = next((r for r in runner.session.journal.records if r.kind == "complete"), None)
    data_start, data_end = start.get("utc", ""), complete.get("utc", "") if complete is not None else ""
    run = RunInfo(
        procedure=runner.plan.name,
        inputs=[dataset] if dataset else [],
        data_start=data_start,
        data_end=data_end,
        sample_rate=float(metadata.sample_rate),
        entries=run_entries(runner),
        environment=_environment(runner, columns, fit),
    )
    calibration_entries = _calibration_entries(runner, start)
    prior_path = rundir / start["prior"] if start.get("prior") else None
    if prior_path is not None and runner.iteration is None:
        # the stage updates the prior record (fine, system): a Bayesian update, one new record
        prior = _load_record(prior_path)
        reference = PriorReference(file_sha256(prior_path), str(start.get("prior_path") or prior_path), prior.calibration.created)
        new = bool(start.get("new_calibration"))
        record = prior.updated(fit, run, new_calibration=new, prior=reference, calibration_entries=calibration_entries, site=metadata)
    else:
        record = CalibrationRecord.from_fit_result(fit, run, site=metadata, calibration_entries=calibration_entries)
    outcome.record = record.save(rundir / RECORD_NAME)
    runner.console.say(f"calibration record written: {outcome.record}")
    runner.console.say(record.report())
    outcome.report = _write_report(rundir, runner, outcome, start)
    return outcome


def _calibration_entries(runner: Runner, start: Any) -> tuple[Any, ...]:
    """Return the ``--set`` values no prompt of the procedure asked for: the calibration's own fields (laboratory, customer ...)."""
    from stableins.procedures.plan import PersonStep
    from stableins.records import parse_entries

    asked = {s.key for s in runner.plan.steps if isinstance(s, PersonStep) and s.key}
    return parse_entries([f"{k}={v}" for k, v in (start.get("fields") or {}).items() if k not in asked])


def run_entries(runner: Runner) -> tuple[Any, ...]:
    """Return what people entered at the procedure's prompts, with the prompt and the unit."""
    from stableins.procedures.plan import PersonStep
    from stableins.records import Entry

    steps = {s.key: s for s in runner.plan.steps if isinstance(s, PersonStep) and s.key}
    out = []
    for key, value in runner.inputs.items():
        step = steps.get(key)
        value = float(value) if isinstance(value, int | float) and not isinstance(value, bool) else str(value)
        out.append(Entry(key, value, step.unit if step else "", step.prompt if step else ""))
    return tuple(out)


def _environment(runner: Runner, columns: Columns | None, fit: Any) -> JSONObject:
    """Summarize what the data carry about the environment: the instrument temperature's mean, minimum and maximum."""
    from stableins.estimators.details import SystemDetails
    from stableins.records import temperature_summary

    if columns is not None:
        return temperature_summary(columns["temperature"])
    temperature = fit.details.temperature if isinstance(fit.details, SystemDetails) else None
    return {"temperature": {**temperature, "unit": "degC"}} if temperature else {}


def _write_report(rundir: Path, runner: Runner, outcome: RunOutcome, start: Any) -> Path:
    """Write the certificate of the run's record (``stableins.reporting``) and return its path.

    It renders ``record.json`` with the evidence stored in it; the change section compares it with the
    record it started from when the run began a new calibration (a recalibration).
    """
    from stableins.reporting import write_report

    target = rundir / REPORT_NAME
    assert outcome.record is not None  # filed by _file before the report is written
    summary = write_report(
        target,
        outcome.record,
        data=[outcome.dataset] if outcome.dataset else [],
        previous=rundir / start["prior"] if start.get("prior") and start.get("new_calibration") else None,
        procedure=rundir / start["definition"] if start.get("definition") else None,
    )
    runner.console.say(f"report written: {target}")
    outcome.verdict, outcome.conformity = summary.verdict, tuple(summary.conformity)
    runner.console.say("statement of conformity of the certificate:\n" + "\n".join(f"  {line}" for line in summary.conformity))
    if summary.missing:  # who calibrated what for whom (ISO/IEC 17025 7.8.2.1): asked for with --set, else a DRAFT
        given = " ".join(f"--set {k}=..." for k in summary.missing)
        runner.console.say(f"the certificate is a DRAFT: {', '.join(summary.missing)} not stated (give {given})")
    return target


def _estimate(rundir: Path, runner: Runner, metadata: SiteMetadata, dataset: Path | None, start: Any) -> Any:
    """Run the stage's estimation: the converged coarse fit of the iteration, or the fine stage on the accepted dwells."""
    if runner.iteration is not None:
        return runner.iteration.fit
    if runner.static_chunks:
        return _estimate_system(rundir, runner, dataset, start)
    definition = runner.definition
    if definition is not None and definition.stage == "rotating":
        return _estimate_lever(rundir, runner, metadata, start)
    if definition is None or definition.stage != "fine":
        return None
    if not start.get("prior"):
        expected = "the unit's coarse record (--prior RECORD or --store)"
        raise InputError("the fine stage starts from a coarse estimate", field="prior_file", expected=expected)
    from stableins.estimators.dwell import dwells_from_columns
    from stableins.estimators.fine import calibrate_fine, fine_model
    from stableins.estimators.setting import DeviceSetting

    columns = accepted_columns(runner.entries)
    source = str(dataset or rundir / JOURNAL_NAME)
    setting = DeviceSetting.from_site(metadata)  # the measured turn within a dwell is not noise (docs/conventions.md)
    dwells = dwells_from_columns(columns, checks=definition.checks, source=source, setting=setting)
    prior = _load_record(rundir / start["prior"])
    return calibrate_fine(
        dwells,
        prior.values(),
        gravity=metadata.gravity,
        expected_positions=definition.positions,
        model=fine_model(runner.extra_terms),
        source=source,
    )


def _estimate_lever(rundir: Path, runner: Runner, metadata: SiteMetadata, start: Any) -> Any:
    """Run the lever-arm stage on the slews of a rotating run, starting from the unit's record (the prior)."""
    from stableins.estimators.lever import lever_stage

    if not start.get("prior"):
        runner.console.say("note: no calibration record (--prior) given; the slews are in device.h5 for 'stableins calibrate lever'")
        return None
    return lever_stage(accepted_columns(runner.entries), metadata, _load_record(rundir / start["prior"]), runner.console.say)


def _estimate_system(rundir: Path, runner: Runner, dataset: Path | None, start: Any) -> Any:
    """Run the system-level stage on the static record, starting from the installed calibration (the prior record)."""
    from dataclasses import replace

    from stableins.data.system import open_system_record
    from stableins.discovery.library import record_terms
    from stableins.estimators.drift import drift_stage
    from stableins.estimators.system.stage import SystemOptions, run_system_stage

    if not start.get("prior"):
        runner.console.say("note: no installed calibration (--prior) given; the record is in system.h5 for 'stableins calibrate system'")
        return None
    prior = _load_record(rundir / start["prior"])
    assert dataset is not None  # a run with a static record exports it (system.h5) before its estimation
    record = open_system_record(dataset)
    estimation = next(s.estimation for s in runner.plan.steps if isinstance(s, StaticRecordStep))
    if estimation is SystemEstimation.SYSTEMATIC:  # the systematic stage (docs/systematic-calibration.md)
        from stableins.estimators.systematic import systematic_stage

        return systematic_stage(record, prior, runner.console.say)
    if estimation is SystemEstimation.DRIFT:  # indexed: the drift test (docs/drift-test.md)
        return drift_stage(record, prior, runner.console.say)
    covariance = {(a, b): float(prior.covariance[i, j]) for i, a in enumerate(prior.ids) for j, b in enumerate(prior.ids)}
    import warnings

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        outcome = run_system_stage(
            record, record.metadata, prior.values(), covariance, SystemOptions(), compensation_terms=record_terms(prior.ids)
        )
        from stableins.estimators.system.sensitivity import with_sensitivities

        terms = record_terms(prior.ids)
        outcome = with_sensitivities(outcome, record, prior.values(), covariance, SystemOptions(), compensation_terms=terms)
    for warning in caught:
        runner.console.say(f"warning: {warning.message}")
    temperature = outcome.diagnostics.temperature
    details = replace(outcome.result.details, temperature=None if temperature is None else temperature.to_dict())
    return replace(outcome.result, details=details)


def _load_record(path: str | os.PathLike[str]) -> Any:
    """Load a calibration record."""
    from stableins.records import CalibrationRecord

    return CalibrationRecord.load(path)
