"""A run directory: its layout, the data a run exports, and the pieces :mod:`stableins.runs` starts and resumes runs with.

Layout of ``RUNDIR`` (see ``docs/procedures.md``)::

    journal.bin       every operation and decision, append-only (the ground truth of the run)
    procedure.json    the plan that runs (also in the journal's start record)
    procedure.toml    copy of the procedure definition the run was started with (if any)
    prior.json        copy of the record used as prior / for the zero offsets (if any)
    device.h5         accepted dwells in the device-level data format read by ``stableins calibrate`` (HDF5)
    system.h5         the static record of a system-level procedure
    record.json       the one calibration record this run produces: the prior updated by the stage (a Bayesian
                      update), or the stage's own record when it has no prior to update; it carries the stage
                      run (data identities and times, settings, entries, fits, likelihood)
    report.pdf        the certificate of record.json (when the report writer is installed)
    truth.json        the simulated world of a run with ``--driver sim --truth`` or ``--hidden`` (the answer to compare with)
    run.lock          while a process runs in the directory: its lock (:mod:`stableins.procedures.runlock`)
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from stableins.documents import JSONObject
from stableins.drivers.base import PlatformDriver
from stableins.errors import InputError
from stableins.identifiers import utc_now
from stableins.procedures.entries import accepted_columns
from stableins.procedures.journal import Journal, metadata_from_start
from stableins.procedures.plan import Plan
from stableins.procedures.replay import open_run_driver
from stableins.procedures.runner import RunConsole, Runner
from stableins.schema import Columns
from stableins.site import SiteMetadata

DATASET_NAME = "device.h5"
SYSTEM_NAME = "system.h5"
PLAN_NAME = "procedure.json"
DEFINITION_NAME = "procedure.toml"
PRIOR_NAME = "prior.json"
RECORD_NAME = "record.json"
REPORT_NAME = "report.pdf"
TRUTH_NAME = "truth.json"


@dataclass
class RunOutcome:
    """What a finished run left in its directory."""

    rundir: Path
    runner: Runner
    dataset: Path | None
    replayed: int
    superseded: tuple[int, int] | None = None
    record: Path | None = None
    report: Path | None = None
    #: the certificate's conformity verdict (PASS, FAIL, ..., NO STATEMENT) and its statement in plain text
    verdict: str | None = None
    conformity: tuple[str, ...] = ()


class RunFinished(Exception):
    """``--resume`` of a run whose journal says it is complete: there is nothing to continue.

    Attributes
    ----------
    rundir : Path
    completed : str
        UTC time the run completed (from the journal).
    outputs : list of Path
        What the run left in its directory (data, record, certificate) that exists now.
    """

    def __init__(self, rundir: Path, completed: str, outputs: list[Path]) -> None:
        self.rundir = rundir
        self.completed = completed
        self.outputs = outputs
        listed = ", ".join(p.name for p in outputs) or "no output files"
        super().__init__(f"the run in {rundir} is finished (completed {completed or 'at an unrecorded time'}): {listed}")


class JournalOnlyDriver:
    """The platform of a finished run, for re-estimating it.

    Every answer comes from the journal, so nothing is asked of a platform (none need be connected); anything beyond
    the journal is refused.
    """

    deterministic = False

    def __init__(self, metadata: SiteMetadata) -> None:
        self.metadata = metadata

    def _refuse(self, *args: Any) -> Any:
        from stableins.drivers.errors import DriverError

        raise DriverError("re-estimating a finished run: the journal holds no more operations (the run is not complete)")

    command = read_angles = acquire = static_record = _refuse

    def status(self) -> dict[str, object]:
        """Return the replay's state."""
        return {"driver": "journal of a finished run"}

    def close(self) -> None:
        """Release nothing: the journal is read, not held."""
        pass


def check_settings(plan: Plan, values: dict[str, str]) -> None:
    """Check that a ``--set KEY=VALUE`` that answers a person step of the plan is valid for it (checked before the platform moves).

    Other keys are the calibration's own fields (laboratory, operator ...), recorded as entries.
    """
    from stableins.procedures.plan import PersonStep
    from stableins.procedures.runner import parse_entry

    steps = {s.key: s for s in plan.steps if isinstance(s, PersonStep) and s.action == "enter" and s.key}
    for key, text in values.items():
        if key in steps:
            parse_entry(steps[key], text)


def model_terms(definition: Any, prior: Any) -> tuple[Any, ...]:
    """Return the discovered terms a stage of this run estimates: the prior record's, then the definition's ``[model] add``.

    A unit's model is the one its record in force carries; a procedure may add effects to it.
    """
    from stableins.discovery.library import calibration_terms, record_terms

    carried = record_terms(prior.ids) if prior is not None else ()
    named = tuple(definition.model_add) if definition is not None else ()
    return carried + calibration_terms([i for i in named if i not in {t.id for t in carried}], source="model.add")


#: Journal record written once every output of a run is on disk (after :func:`stableins.runs.finish`): a resume of a run with a
#: ``complete`` record but without this one writes the outputs from the journal instead of saying it is finished.
FINISHED = "finished"


def journal_finished(journal: Journal, outcome: RunOutcome) -> None:
    """Journal that the outputs of a finished run are all written (names of the files)."""
    files = [p for p in (outcome.dataset, outcome.record, outcome.report) if p is not None]
    journal.append(FINISHED, {"utc": utc_now(), "files": [Path(p).name for p in files]})


def exported_columns(runner: Runner, dataset: Path | None) -> Columns | None:
    """Return the accepted dwells as device-level columns, or None for a system-level run or an empty data set."""
    if runner.static_chunks or dataset is None:
        return None
    columns = accepted_columns(runner.entries)
    return columns if len(columns["time"]) else None


def copy_input(source: Path, target: Path) -> str:
    """Copy ``source`` to ``target`` (atomically); returns the SHA-256 of the bytes copied."""
    import hashlib

    from stableins.data.atomic import atomic_write
    from stableins.data.jsonio import MAX_DOCUMENT_BYTES, read_input_bytes

    data = read_input_bytes(source, max_bytes=MAX_DOCUMENT_BYTES, what="an input file of the run")
    if source.resolve() != target.resolve():
        with atomic_write(target, "wb") as handle:
            handle.write(data)
    return hashlib.sha256(data).hexdigest()


def export(rundir: Path, runner: Runner, metadata: SiteMetadata) -> Path | None:
    """Write the accepted data (atomically): dwells in the device-level format, a static record in the system format."""
    if runner.static_chunks:
        from stableins.data.system import SystemRecordWriter

        with SystemRecordWriter(rundir / SYSTEM_NAME, metadata) as writer:
            for record in runner.static_chunks:
                writer.append(record.arrays)
        return rundir / SYSTEM_NAME
    columns = accepted_columns(runner.entries)
    if not len(columns["time"]):
        return None
    extra = dict(metadata.extra)
    extra.update(procedure=runner.plan.name, inputs=dict(runner.inputs))
    metadata = SiteMetadata(**{**metadata.__dict__, "extra": extra})
    try:
        from stableins.data.device import save_device
    except ImportError:  # the data-format writers are not installed: the samples stay in the journal only
        runner.console.say("note: no device-level data writer in this installation; the accepted samples are in journal.bin")
        return None
    return save_device(rundir / DATASET_NAME, columns, metadata)


def write_plan(rundir: Path, plan: Plan) -> None:
    """Write the plan the run executes (``procedure.json``) into the run directory, atomically."""
    from stableins.data.atomic import atomic_write

    with atomic_write(rundir / PLAN_NAME) as handle:
        json.dump(plan.to_dict(), handle, indent=2)


def resume_mode(rundir: Path, journal: Journal, console: RunConsole, *, re_estimate: bool) -> tuple[bool, bool]:
    """Decide how a resume proceeds: ``(re_estimate, journal_finish)``.

    A finished run is not run again (:class:`RunFinished`) unless ``re_estimate``; a run whose last step was done but
    whose outputs were not all written is estimated again from its journal, and then journaled as finished.
    """
    complete = next((r for r in journal.records if r.kind == "complete"), None)
    names = (DATASET_NAME, SYSTEM_NAME, RECORD_NAME, REPORT_NAME)
    written = any(r.kind == FINISHED for r in journal.records) or (rundir / REPORT_NAME).exists()
    if complete is not None and not re_estimate:
        if written:
            raise RunFinished(rundir, str(complete.get("utc") or ""), [rundir / n for n in names if (rundir / n).exists()])
        # the last step was done but the run was interrupted while writing its outputs: write them from the journal
        console.say("the run completed its last step but was interrupted before writing all its outputs: writing them from the journal")
        re_estimate = True
    journal_finish = not re_estimate or (complete is not None and not written)
    if complete is None and re_estimate:
        raise InputError(
            "the run is not finished: there is nothing to estimate again yet",
            path=rundir,
            field="re_estimate",
            expected=f"a finished run, or 'stableins run --resume {rundir}' to continue this one",
        )
    return re_estimate, journal_finish


def resume_spec(journaled: str, driver_spec: str | None) -> str:
    """Return the driver a resumed run uses: the journaled one, or a new ``tcp://`` address of a network platform that moved."""
    if driver_spec is None or driver_spec == journaled:
        return journaled
    if not (driver_spec.startswith("tcp://") and journaled.startswith("tcp://")):
        raise InputError(
            f"this run was made with --driver {journaled}",
            field="driver_spec",
            expected=f"{journaled} (only a tcp:// address may change on resume)",
        )
    return driver_spec


def resume_driver(
    start: Any,
    spec: str,
    plan: Plan,
    *,
    re_estimate: bool,
    driver_factory: Callable[[JSONObject], PlatformDriver] | None,
    timeout: float,
    truth: Any = None,
) -> PlatformDriver:
    """Open the platform of a resumed run: the journal alone (re-estimating), the factory's, or the one ``spec`` opens.

    ``truth``: the known world of a simulated run started with one (``RUNDIR/truth.json``).
    """
    if re_estimate:
        return JournalOnlyDriver(metadata_from_start(start))
    if driver_factory is not None:
        return driver_factory(start.fields)
    return open_run_driver(spec, seed=start["seed"], unit=start["unit"], sample_rate=plan.sample_rate, timeout=timeout, truth=truth)


def check_capabilities(driver: PlatformDriver, plan: Plan) -> None:
    """Refuse, before the platform moves, a platform that cannot do what the plan needs (a network platform without ``NAV``).

    Raises
    ------
    DriverProtocolError
        Naming the protocol version and capabilities the platform stated and the one the plan needs.
    """
    from stableins.drivers.server import NAV_CAPABILITY
    from stableins.procedures.plan import StaticRecordStep

    require = getattr(driver, "require", None)
    if require is not None and any(isinstance(step, StaticRecordStep) for step in plan.steps):
        require(NAV_CAPABILITY, f"the static record of {plan.name!r} (the INS's velocity and attitude outputs)")


def install_prior(driver: PlatformDriver, plan: Plan, prior: Any, source: str | os.PathLike[str] | None) -> None:
    """Load a simulated INS with the record a system-level run starts from (what a real INS runs with), if it can be loaded.

    ``prior``: the :class:`~stableins.records.CalibrationRecord` of ``--prior`` (None: nothing to load).  A network
    platform is loaded by its operator; the simulated one (:meth:`~stableins.drivers.select.SimulatedDriver.install`)
    here, at the start of the run and again when it is resumed, so that the samples replay.
    """
    install = getattr(driver, "install", None)
    if prior is not None and plan.level == "system" and install is not None:
        install(prior.values(), source=None if source is None else str(source))
