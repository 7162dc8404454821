"""The calibration record of one unit: its content, and how it is built, written, read and shown.

:class:`CalibrationRecord` is :class:`~stableins.records.content.RecordContent` (the data, the questions they
answer, the check at construction) with the methods people use: building (below), the JSON file
(:mod:`stableins.records.writer`, :mod:`stableins.records.reader`) and what people see
(:mod:`stableins.records.display`).  Those modules take a content and never import this one.

Building records
----------------
The first record of a calibration (from a fit, from a device calibration) and its Bayesian updates.

A stage that updates a record is a Bayesian update (:func:`stableins.estimators.posterior.bayesian_update`):
it never raises a σ and never moves what its data do not determine.
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterable, Mapping
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Self, TypedDict, Unpack

from stableins.data.jsonio import load_json_file
from stableins.errors import InputError, NotDeterminedError
from stableins.records import display
from stableins.records.content import RecordContent, _RecordT
from stableins.records.parameters import DeterminedBy, Entry, Parameter
from stableins.records.reader import read_document
from stableins.records.stages import UNDESCRIBED, Calibration, PriorReference, RunInfo, StageRun
from stableins.records.writer import record_document, save_record
from stableins.site import SiteMetadata
from stableins.status import Determination, Status

if TYPE_CHECKING:
    from stableins.documents import JSONObject
    from stableins.estimators.device import DeviceCalibration
    from stableins.estimators.result import FitResult
    from stableins.noise import NoiseModel


class CalibrationRecord(RecordContent):
    """A calibration of one unit: parameters, covariance, the calibration and every stage run it rests on, site.

    Build the first record of a calibration with :meth:`from_fit_result`, update it with a later stage
    (a Bayesian update) with :meth:`updated`, write it with :meth:`save`, read it with :meth:`load`.
    The covariance rows follow :attr:`ids` (the parameter order).
    """

    # ------------------------------------------------------------------ build
    @classmethod
    def from_device(
        cls, calibration: DeviceCalibration, site: SiteMetadata, run: RunInfo = UNDESCRIBED, *, entries: Iterable[Entry] = ()
    ) -> Self:
        """Return the record of a device-level calibration: its ``final`` fit (coarse and fine fused by joint GLS, not replaced).

        The record's stage run (``coarse+fine``, or ``coarse``) keeps the evidence of every fit (coarse, fine alone,
        fused, each with its χ²_ν), the fused likelihood and the calibration's ``settings``; ``entries`` are the
        calibration's fields.  The record carries ``calibration.noise`` (the noise model every σ rests on).

        Parameters
        ----------
        calibration : DeviceCalibration
            The device-level calibration.
        site : SiteMetadata
            Site metadata of the data.
        run : RunInfo
            What describes the stage run: ``inputs`` (hashed), ``procedure``, ``data_start``, ``data_end``,
            ``environment`` (its sample rate is the site's).
        entries : iterable of Entry
            The calibration's own fields (laboratory, customer, operator ...).

        Returns
        -------
        CalibrationRecord
            The first record of a new calibration.
        """
        return record_from_device(cls, calibration, site, run, entries=entries)

    @classmethod
    def from_fit_result(
        cls,
        result: FitResult,
        run: RunInfo | StageRun = UNDESCRIBED,
        *,
        site: SiteMetadata | None = None,
        serial_number: str | None = None,
        notes: Iterable[str] = (),
        calibration_entries: Iterable[Entry] = (),
        noise_model: NoiseModel | None = None,
    ) -> Self:
        """Return the first record of a calibration: one data-only stage (no prior).

        Parameters
        ----------
        result : FitResult
            The stage's result (its terms give ids and SI units).
        run : RunInfo or StageRun
            What describes the stage run (its procedure names the calibration's; the sample rate defaults to the
            site's), or the stage run itself (:meth:`StageRun.from_fit`; it joins the new calibration).
        site : SiteMetadata, optional
            Site metadata of the data.
        serial_number : str, optional
            Defaults to ``site.serial_number``.
        notes : iterable of str
            Added to the result's own notes.
        calibration_entries : iterable of Entry
            The calibration's own fields (laboratory, customer, operator ...).
        noise_model : NoiseModel, optional
            The noise model the stage's σ rest on (docs/noise.md).

        Returns
        -------
        CalibrationRecord
            The record.
        """
        return record_from_fit(
            cls, result, run, site=site, serial_number=serial_number, notes=notes, calibration_entries=calibration_entries,
            noise_model=noise_model,
        )  # fmt: skip

    def updated(
        self,
        result: FitResult,
        run: RunInfo | StageRun = UNDESCRIBED,
        *,
        new_calibration: bool = False,
        prior: PriorReference | None = None,
        calibration_entries: Iterable[Entry] = (),
        site: SiteMetadata | None = None,
        noise_model: NoiseModel | None = None,
    ) -> Self:
        """Return this record updated by a later stage: the Bayesian update with the stage's likelihood.

        Parameters
        ----------
        result : FitResult
            The stage's result; its :attr:`~FitResult.likelihood` is what enters (values and covariance
            of the result are not used: the posterior is computed over every parameter of the record).
        run : RunInfo or StageRun
            What describes the stage run (procedure, data files, times, sample rate, entries, environment; the
            sample rate defaults to the site's), or the stage run itself.
        new_calibration : bool
            Start a new calibration (a recalibration from the record in force, with ``prior`` naming it) instead of
            continuing this record's.
        prior : PriorReference, optional
            The record in force a new calibration starts from.
        calibration_entries : iterable of Entry
            The calibration's own fields (laboratory, customer ...); a later key replaces an earlier one.
        site : SiteMetadata, optional
            Site of the new data (defaults to the record's).
        noise_model : NoiseModel, optional
            A noise model the stage measured (by default the record's is carried over unchanged).

        Returns
        -------
        CalibrationRecord
            The posterior record, the stage run appended.

        Raises
        ------
        InputError
            The stage has no likelihood, or its data determine no parameter of the record.
        """
        return update_record(
            self, result, run, new_calibration=new_calibration, prior=prior, calibration_entries=calibration_entries, site=site,
            noise_model=noise_model,
        )  # fmt: skip

    def updated_by_run(
        self, stage: StageRun, *, new_calibration: bool = False, prior: PriorReference | None = None, site: SiteMetadata | None = None
    ) -> Self:
        """Return this record updated by a stage run of another record (its stored likelihood), e.g. ``stableins recal --estimate``."""
        return update_by_run(self, stage, new_calibration=new_calibration, prior=prior, site=site)

    # ------------------------------------------------------------------ files
    def to_document(self) -> JSONObject:
        """Return the JSON-ready dict (non-finite numbers as ``null``; docs/formats.md)."""
        return record_document(self)

    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write the record atomically (a reader sees the old file or the whole new one); return its path."""
        return save_record(self, path)

    @classmethod
    def from_document(cls, document: Any, path: str | None = None) -> Self:
        """Build and validate a record from its JSON document (version 1 is migrated, :func:`migrate_v1`)."""
        return read_document(cls, document, path)

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> Self:
        """Read and validate a record.

        Raises
        ------
        InputError
            Unknown schema version, missing keys, bad status, a covariance that is not
            square, symmetric, positive semi-definite or consistent with the σ's, ...
        """
        document = load_json_file(path, what="a calibration record (JSON) written by stableins")
        return cls.from_document(document, str(path))

    # ------------------------------------------------------------------ people
    def rows(self) -> list[tuple[str, float, float, str, str, str]]:
        """Return ``(id, value, σ, unit, status, determined by)`` in engineering units where the id is a known term."""
        return display.record_rows(self)

    def source_text(self, parameter_id: str) -> str:
        """Return which stage last determined the parameter, how, and whether in this calibration (console and certificate)."""
        return display.source_text(self, parameter_id)

    def report(self) -> str:
        """Return a plain-text table in engineering units: value, 1σ, status and the stage that last determined each parameter."""
        return display.report(self)

    def __str__(self) -> str:
        return self.report()

    def __repr__(self) -> str:
        return display.text_repr(self)

    def _repr_html_(self) -> str:
        return display.html_repr(self)

    def to_dataframe(self) -> Any:
        """Return the parameter table as a :class:`pandas.DataFrame` indexed by parameter id.

        Columns ``value``, ``sigma``, ``unit`` (engineering units where the id is a known term), ``status``,
        ``determined_by`` (the stage that last determined it, :meth:`source_text`), ``value_si``, ``sigma_si``,
        ``si_unit``; an ``unidentifiable`` parameter has no value.  Needs pandas (``pip install stableins[pandas]``).
        """
        return display.dataframe(self)


class Carried(TypedDict, total=False):
    """What a stage may replace in the record it updates: the site of its data, a noise model it measured."""

    site: SiteMetadata | None
    noise_model: NoiseModel | None


def record_from_device(
    cls: type[_RecordT], calibration: DeviceCalibration, site: SiteMetadata, run: RunInfo = UNDESCRIBED, *, entries: Iterable[Entry] = ()
) -> _RecordT:
    """Return the record of a device-level calibration (:meth:`CalibrationRecord.from_device`)."""
    started = Calibration.new(run.procedure, entries)
    fits = [calibration.coarse] + [f for f in (calibration.fine, calibration.fused) if f is not None]
    settings = calibration.settings or calibration.final.settings
    stage = StageRun.from_fit(
        calibration.final, calibration=started.id, run=replace(run, sample_rate=site.sample_rate), fits=fits, settings=settings
    )
    final, serial = calibration.final, site.serial_number
    return _first_record(cls, final, stage, calibration=started, site=site, serial_number=serial, notes=(), noise_model=calibration.noise)


def record_from_fit(
    cls: type[_RecordT],
    result: FitResult,
    run: RunInfo | StageRun = UNDESCRIBED,
    *,
    site: SiteMetadata | None = None,
    serial_number: str | None = None,
    notes: Iterable[str] = (),
    calibration_entries: Iterable[Entry] = (),
    noise_model: NoiseModel | None = None,
) -> _RecordT:
    """Return the first record of a calibration, one data-only stage (:meth:`CalibrationRecord.from_fit_result`)."""
    if serial_number is None:
        if site is None:
            raise ValueError("from_fit_result needs a serial_number or site metadata")
        serial_number = site.serial_number
    _check_run(run)
    calibration = Calibration.new(run.procedure, calibration_entries)
    if isinstance(run, RunInfo):
        given = run if run.sample_rate is not None or site is None else replace(run, sample_rate=site.sample_rate)
        stage = StageRun.from_fit(result, calibration=calibration.id, run=given)
    else:
        stage = replace(run, calibration=calibration.id)
    return _first_record(
        cls, result, stage, calibration=calibration, site=site, serial_number=serial_number, notes=tuple(notes), noise_model=noise_model
    )


def _check_run(run: object) -> None:
    """Refuse a ``run`` that is neither a :class:`RunInfo` nor a :class:`StageRun` (a serial number in its place)."""
    if not isinstance(run, RunInfo | StageRun):
        raise TypeError(f"run must be a RunInfo or a StageRun, not {type(run).__name__} (serial_number is a keyword)")


def _first_record(
    cls: type[_RecordT],
    result: FitResult,
    stage: StageRun,
    *,
    calibration: Calibration,
    site: SiteMetadata | None,
    serial_number: str,
    notes: tuple[str, ...],
    noise_model: NoiseModel | None,
) -> _RecordT:
    """Return the record of ``result``'s parameters with ``stage`` its one stage run, of ``calibration``."""
    import numpy as np

    covariance = np.array(result.covariance, dtype=float)
    parameters = _first_parameters(result, stage.id, covariance)
    return cls(
        serial_number=serial_number,
        parameters=parameters,
        covariance=covariance,
        calibration=calibration,
        stages=(stage,),
        site=site,
        determined=tuple(result.determined),
        notes=tuple(result.notes) + notes,
        noise_model=noise_model,
    )


def _first_parameters(result: FitResult, stage_id: str, covariance: Any) -> tuple[Parameter, ...]:
    """Return the parameters of a result's first record; blank the covariance rows of unidentifiable ones (in place)."""
    import numpy as np

    sigma = np.sqrt(np.clip(np.diag(result.covariance), 0.0, None))
    estimable = _estimable(result)
    parameters = []
    for k, (term, status) in enumerate(zip(result.terms, result.status, strict=True)):
        s = float(sigma[k])
        how: tuple[DeterminedBy, ...] = ()
        if status is Status.UNIDENTIFIABLE:
            s = math.nan
            covariance[k, :] = math.nan
            covariance[:, k] = math.nan
        if status is Status.ESTIMATED:
            how = (DeterminedBy(stage_id, Determination.ALONE if estimable.get(term.id, True) else Determination.COMBINATION),)
        parameters.append(Parameter(term.id, float(result.values[k]), term.si_unit, s, Status(status), how))
    return tuple(parameters)


def _estimable(result: FitResult) -> dict[str, bool]:
    """Return which of the result's parameters its likelihood determines by itself (all, without a likelihood)."""
    if result.likelihood is None:
        return {}
    held = {t.id: float(v) for t, v, s in zip(result.terms, result.values, result.status, strict=True) if s is Status.GAUGE}
    lik = result.likelihood.conditioned({i: v for i, v in held.items() if i in result.likelihood.ids})
    return dict(zip(lik.ids, map(bool, lik.estimable()), strict=True))


def update_record(
    record: _RecordT,
    result: FitResult,
    run: RunInfo | StageRun = UNDESCRIBED,
    *,
    new_calibration: bool = False,
    prior: PriorReference | None = None,
    calibration_entries: Iterable[Entry] = (),
    site: SiteMetadata | None = None,
    noise_model: NoiseModel | None = None,
) -> _RecordT:
    """Return ``record`` updated by a later stage's likelihood (:meth:`CalibrationRecord.updated`)."""
    if result.likelihood is None:
        raise InputError(
            f"the {result.stage} stage gives no likelihood: it cannot update a record", field="stage", expected="a Bayesian stage"
        )
    _check_run(run)
    calibration = next_calibration(record, run.procedure, calibration_entries, new_calibration=new_calibration, prior=prior)
    if isinstance(run, RunInfo):
        where = site or record.site
        given = run if run.sample_rate is not None or where is None else replace(run, sample_rate=where.sample_rate)
        stage = StageRun.from_fit(result, calibration=calibration.id, run=given)
    else:
        stage = run
    units = {t.id: t.si_unit for t in result.terms}
    return apply_stage(record, replace(stage, likelihood=result.likelihood), calibration, units, site=site, noise_model=noise_model)


def update_by_run(
    record: _RecordT,
    stage: StageRun,
    *,
    new_calibration: bool = False,
    prior: PriorReference | None = None,
    site: SiteMetadata | None = None,
) -> _RecordT:
    """Return ``record`` updated by a stage run of another record (:meth:`CalibrationRecord.updated_by_run`)."""
    if stage.likelihood is None:
        raise InputError(f"stage run {stage.id} carries no likelihood: it cannot update a record", field="stages")
    calibration = next_calibration(record, stage.procedure, (), new_calibration=new_calibration, prior=prior)
    return apply_stage(record, stage, calibration, {}, site=site)


def next_calibration(
    record: RecordContent, procedure: str, entries: Iterable[Entry], *, new_calibration: bool, prior: PriorReference | None
) -> Calibration:
    """Return the calibration a stage run joins: a new one (a recalibration), or the record's with the procedure and entries added."""
    if new_calibration:
        return Calibration.new(procedure, entries, prior)
    names = [n for n in (*record.calibration.procedure.split(" + "), *procedure.split(" + ")) if n]
    merged = {e.key: e for e in (*record.calibration.entries, *entries)}
    return replace(record.calibration, procedure=" + ".join(dict.fromkeys(names)), entries=tuple(merged.values()))


def apply_stage(
    record: _RecordT, stage: StageRun, calibration: Calibration, units: Mapping[str, str], **carried: Unpack[Carried]
) -> _RecordT:
    """Return the posterior of ``record`` given ``stage.likelihood``, with ``stage`` appended (as a run of ``calibration``).

    Parameters
    ----------
    record : CalibrationRecord
        The prior (the posterior is of its type).
    stage : StageRun
        The stage run; its likelihood must not be None.
    calibration : Calibration
        The calibration the run belongs to (:func:`next_calibration`).
    units : mapping
        SI units of parameters the record does not hold yet ("SI" where missing).
    **carried
        :class:`Carried`: ``site`` (default: the record's), ``noise_model`` (default: the record's).

    Returns
    -------
    CalibrationRecord
        The posterior record.

    Raises
    ------
    InputError
        The stage run is already part of the record, or its data determine no parameter of it.
    """
    from stableins.estimators.posterior import bayesian_update

    likelihood = stage.likelihood
    assert likelihood is not None
    stage = replace(stage, calibration=calibration.id)
    if stage.id in {s.id for s in record.stages}:
        raise InputError(f"stage run {stage.id} is already part of this record", field="stages", expected="a new stage run")
    post = bayesian_update(record.ids, record.values_array(), record.covariance, [p.status for p in record.parameters], likelihood)
    if not any(d is not None for d in post.determination):
        raise NotDeterminedError(
            f"the {stage.name} stage's data determine no parameter of the record; no record written",
            field="stage",
            expected="data that determine at least one parameter",
        )
    parameters = []
    sigma = post.sigma
    for k, pid in enumerate(post.ids):
        before = record[pid] if pid in record.ids else None
        sources = before.determined_by if before is not None else ()
        how = post.determination[k]
        if how is not None:
            sources = sources + (DeterminedBy(stage.id, how),)
        unit = before.unit if before is not None else units.get(pid, "SI")
        s = float(sigma[k]) if post.status[k] is not Status.UNIDENTIFIABLE else math.nan
        parameters.append(Parameter(pid, float(post.values[k]), unit, s, post.status[k], sources))
    noise_model = carried.get("noise_model")
    return type(record)(
        serial_number=record.serial_number,
        parameters=tuple(parameters),
        covariance=post.covariance,
        calibration=calibration,
        stages=record.stages + (stage,),
        site=carried.get("site") or record.site,
        determined=tuple(dict.fromkeys(record.determined + stage.determined)),
        notes=record.notes + tuple(f"[{stage.name}] {n}" for n in stage.notes),
        discovery=record.discovery,
        noise_model=noise_model if noise_model is not None else record.noise_model,
    )
