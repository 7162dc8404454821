"""Calibration records: the one carrier of a unit's model, its uncertainty, its provenance and its entries.

A record is a JSON file (format in ``docs/formats.md``, schema version 2)::

    {
      "format": "stableins-calibration-record", "schema_version": 2,
      "serial_number": "INS-0042",
      "parameters": [{"id": "sf_x", "value": 1.000123, "unit": "1", "sigma": 1.1e-6, "status": "estimated",
                      "determined_by": [{"stage": "coarse+fine-1a2b3c4d", "how": "alone"}]}, ...],
      "covariance": {"ids": ["sf_x", ...], "unit": "...", "matrix": [[...], ...]},
      "calibration": {"id": ..., "procedure": ..., "software": ..., "created": ..., "prior": {...} | null,
                      "entries": [{"key": "laboratory", "value": "...", "unit": ""}, ...]},
      "stages": [{"id", "name", "calibration", "procedure", "software", "created", "data_start", "data_end",
                  "sample_rate", "inputs", "settings", "entries", "environment", "fits", "likelihood",
                  "determined", "notes"}, ...],
      "site": {...site metadata with units...},
      "determined": [...], "notes": [...],
      "discovery": {"stage": "coarse+fine", "alpha": 0.05, "steps": [...]} (optional),
      "noise_model": {...} (optional, issue 11)
    }

Every stage the unit's model rests on is listed in ``stages`` (oldest first, carried over from
record to record); ``calibration`` names the job that produced this record, and the stages
whose ``calibration`` is its id are the stages run in it.  Each parameter names every stage
whose data saw it (``determined_by``): a certificate tells a parameter measured in this
calibration from one carried over.  A stage that updates a record is a Bayesian update
(:func:`stableins.estimators.posterior.bayesian_update`): it never raises a σ and never moves
what its data do not determine.  Statuses are :class:`stableins.status.Status`.

Values are SI (``unit`` says which); ``sigma`` is the square root of the covariance diagonal
and is stored only for people (the loader checks that it agrees).  Version-1 files are read
and migrated (:func:`migrate_v1`).

Discovered effects (``stableins calibrate device --add Kcc_xxy``) are parameters like any
other, with the ids of the discovery library; :meth:`CalibrationRecord.error_model` is the model
that compensation applies (:meth:`stableins.errormodel.ErrorModel.inverse`).  The optional
``discovery`` section is the history of the fit that added them (model, χ²_ν, residual RMS
and the verdict on every tested effect, :class:`stableins.discovery.history.ModelHistory`).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any

from stableins.data.metadata import metadata_from_document, metadata_to_document
from stableins.errors import InputError
from stableins.site import SiteMetadata
from stableins.status import STATUSES, Determination, Status

if TYPE_CHECKING:  # pragma: no cover
    import numpy as np
    from numpy.typing import NDArray

    from stableins.discovery.history import ModelHistory
    from stableins.errormodel import ErrorModel
    from stableins.estimators.device import DeviceCalibration
    from stableins.estimators.result import FitResult, InputSensitivity, Likelihood
    from stableins.noise import NoiseModel

RECORD_FORMAT = "stableins-calibration-record"
RECORD_SCHEMA_VERSION = 2
#: Relative asymmetry tolerated in a stored covariance.
SYMMETRY_TOLERANCE = 1e-9
#: Keys of a calibration's own entries a person may give (``--set KEY=VALUE``), besides the prompts of a procedure.
CALIBRATION_FIELDS = ("laboratory", "customer", "operator", "location")


# ---------------------------------------------------------------------- parts
@dataclass(frozen=True)
class DeterminedBy:
    """One stage whose data saw a parameter, and how (alone, or only in combination with others)."""

    stage: str
    how: Determination


@dataclass(frozen=True)
class Parameter:
    """One calibrated parameter.

    Attributes
    ----------
    id : str
        Term id (``sf_x``, ``bias_x``, ``beta_xy``, ``K2_x``, ``theta10``, discovered terms ...).
    value : float
        Value [SI].
    unit : str
        SI unit of ``value`` (``"1"`` for dimensionless).
    sigma : float
        1σ [SI]; NaN for ``unidentifiable``.
    status : Status
        :class:`stableins.status.Status` (strings are converted).
    determined_by : tuple of DeterminedBy
        Every stage whose data saw the parameter, oldest first; the last one determined it last.
    """

    id: str
    value: float
    unit: str
    sigma: float
    status: Status
    determined_by: tuple[DeterminedBy, ...] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "status", Status(self.status))


@dataclass(frozen=True)
class InputFile:
    """An input file by path and SHA-256 digest of its bytes."""

    path: str
    sha256: str

    @classmethod
    def of(cls, path: str | os.PathLike[str]) -> InputFile:
        return cls(str(path), file_sha256(path))


@dataclass(frozen=True)
class Entry:
    """A value a person entered (a procedure prompt, ``--set KEY=VALUE``) or a field of the calibration."""

    key: str
    value: float | str
    unit: str = ""
    prompt: str = ""

    def text(self) -> str:
        """The value with its unit, for people (``21.5 °C``)."""
        value = f"{self.value:g}" if isinstance(self.value, float) else str(self.value)
        unit = {"degC": "°C", "deg": "°"}.get(self.unit, self.unit)
        return f"{value} {unit}".strip()


@dataclass(frozen=True)
class StageRun:
    """One run of an estimation stage: what it read, how it was set up, what it found.

    Attributes
    ----------
    id : str
        Unique id, ``<name>-<8 hex>`` (a digest of name, creation time and input digests).
    name : str
        ``coarse``, ``fine``, ``coarse+fine`` (fused device stage), ``system`` ...
    calibration : str
        Id of the calibration (job) the run belongs to.
    procedure : str
        Procedure the data were taken with (name or file).
    software : str
        ``stableins <version>`` that ran the stage.
    created : str
        ISO 8601 UTC time of the run.
    data_start, data_end : str
        ISO 8601 UTC times of the first and last sample used ("" where the data do not say).
    sample_rate : float or None
        Sample rate of the data [Hz].
    inputs : tuple of InputFile
        The data files with their SHA-256.
    settings : dict
        The options the stage ran with (JSON values): noise model, estimate K2, gyro drift ...
    entries : tuple of Entry
        What people entered during the run (procedure prompts).
    environment : dict
        What the data carry about the environment, e.g. ``{"temperature": {"mean", "min", "max", "unit"}}``.
    fits : tuple of dict
        Residual evidence of each fit of the stage (:func:`fit_evidence`), one χ²_ν each.
    likelihood : Likelihood or None
        What the stage's data say about the parameters (canonical form; None for migrated records).
    determined, notes : tuple of str
        Combinations the data determine; the stage's notes.
    sensitivities : tuple of InputSensitivity
        How the stage's likelihood depends on inputs it took as known (Type B inputs of the uncertainty budget).
    """

    id: str
    name: str
    calibration: str
    procedure: str = ""
    software: str = ""
    created: str = ""
    data_start: str = ""
    data_end: str = ""
    sample_rate: float | None = None
    inputs: tuple[InputFile, ...] = ()
    settings: Mapping[str, Any] = field(default_factory=dict)
    entries: tuple[Entry, ...] = ()
    environment: Mapping[str, Any] = field(default_factory=dict)
    fits: tuple[Mapping[str, Any], ...] = ()
    likelihood: Likelihood | None = None
    determined: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()
    sensitivities: tuple[InputSensitivity, ...] = ()

    @classmethod
    def from_fit(
        cls,
        result: FitResult,
        *,
        calibration: str,
        procedure: str = "",
        inputs: Iterable[str | os.PathLike[str] | InputFile] = (),
        data_start: str = "",
        data_end: str = "",
        sample_rate: float | None = None,
        entries: Iterable[Entry] = (),
        environment: Mapping[str, Any] | None = None,
        fits: Iterable[FitResult] = (),
        settings: Mapping[str, Any] | None = None,
        name: str | None = None,
        created: str | None = None,
    ) -> StageRun:
        """The run of the stage that produced ``result`` (its likelihood, settings, notes; ``fits`` default: ``result``)."""
        from stableins import __version__

        files = tuple(f if isinstance(f, InputFile) else InputFile.of(f) for f in inputs)
        created = created or _now()
        name = name or result.stage
        digest = hashlib.sha256(json.dumps([name, created, calibration, [f.sha256 for f in files]]).encode()).hexdigest()[:8]
        evidence = tuple(fit_evidence(f) for f in (tuple(fits) or (result,)))
        return cls(
            id=f"{name}-{digest}",
            name=name,
            calibration=calibration,
            procedure=procedure,
            software=f"stableins {__version__}",
            created=created,
            data_start=data_start,
            data_end=data_end,
            sample_rate=sample_rate,
            inputs=files,
            settings=dict(settings if settings is not None else result.settings),
            entries=tuple(entries),
            environment=dict(environment or {}),
            fits=evidence,
            likelihood=result.likelihood,
            determined=tuple(result.determined),
            notes=tuple(result.notes),
            sensitivities=tuple(result.sensitivities),
        )


@dataclass(frozen=True)
class PriorReference:
    """The record a calibration started from (its digest identifies it in a unit's history)."""

    sha256: str
    path: str = ""
    created: str = ""


@dataclass(frozen=True)
class Calibration:
    """The calibration (job) that produced a record: its procedure, software, entries, and the record it started from."""

    id: str
    procedure: str = ""
    software: str = ""
    created: str = ""
    prior: PriorReference | None = None
    entries: tuple[Entry, ...] = ()

    @classmethod
    def new(cls, procedure: str = "", entries: Iterable[Entry] = (), prior: PriorReference | None = None) -> Calibration:
        import uuid

        from stableins import __version__

        created = _now()
        return cls(f"cal-{created[:10]}-{uuid.uuid4().hex[:8]}", procedure, f"stableins {__version__}", created, prior, tuple(entries))


@dataclass(frozen=True)
class Provenance:
    """Summary of the calibration a record completes (derived from its stages; read-only).

    ``stages`` are the names of the stages run in this calibration, ``inputs`` their data files,
    ``data_start``/``data_end`` the span of their data.
    """

    software: str
    procedure: str = ""
    stages: tuple[str, ...] = ()
    inputs: tuple[InputFile, ...] = ()
    created: str = ""
    data_start: str = ""
    data_end: str = ""


def file_sha256(path: str | os.PathLike[str]) -> str:
    """SHA-256 of a file's bytes, read in 1 MiB blocks."""
    digest = hashlib.sha256()
    try:
        with open(path, "rb") as handle:
            for block in iter(lambda: handle.read(1 << 20), b""):
                digest.update(block)
    except OSError as error:
        raise InputError(f"cannot read input file to hash it: {error.strerror}", path=path) from None
    return digest.hexdigest()


def parse_entries(items: Iterable[str], field: str = "entries") -> tuple[Entry, ...]:
    """Entries from ``KEY=VALUE`` or ``KEY=NUMBER UNIT`` (``laboratory=PTB``, ``lab_temperature=21.5 degC``)."""
    out: dict[str, Entry] = {}
    for item in items:
        key, sep, value = item.partition("=")
        key, value = key.strip(), value.strip()
        if not sep or not key or not value:
            raise InputError(f"cannot read {item!r}", field=field, expected="KEY=VALUE, e.g. laboratory=PTB or lab_temperature=21.5 degC")
        number, _, unit = value.partition(" ")
        try:
            parsed = float(number)
        except ValueError:
            out[key] = Entry(key, value)
            continue
        if not math.isfinite(parsed):
            raise InputError(f"{item!r}: not a finite number", field=field, expected="a finite number")
        out[key] = Entry(key, parsed, unit.strip())
    return tuple(out.values())


def _now() -> str:
    return datetime.now(UTC).replace(microsecond=0).isoformat()


def fit_evidence(fit: FitResult) -> dict[str, Any]:
    """A fit's residual evidence as stored in a stage run: residuals, 1σ, labels and its one χ², ν, χ²_ν.

    χ² is :attr:`FitResult.chi2` (whitened where the noise is correlated between observations); console,
    JSON and certificate all print this number.
    """

    def num(x: float) -> float | None:
        return float(x) if math.isfinite(x) else None

    return {
        "stage": fit.stage,
        "parameter_ids": list(fit.ids),
        "rank": int(fit.rank),
        "residual_labels": list(fit.residual_labels),
        "residuals": [float(x) for x in fit.residuals],
        "residual_sigma": [float(x) for x in fit.residual_sigma],
        "residual_unit": "m/s^2" if fit.stage != "system" else "rad",
        "chi2": num(fit.chi2),
        "dof": int(fit.dof),
        "chi2_red": num(fit.chi2_red),
    }


def temperature_summary(values: Any) -> dict[str, Any]:
    """``{"temperature": {"mean", "min", "max", "unit": "degC"}}`` of the instrument temperature the data carry."""
    import numpy as np

    t = np.asarray(values, dtype=float)
    t = t[np.isfinite(t)]
    if not t.size:
        return {}
    return {"temperature": {"mean": float(t.mean()), "min": float(t.min()), "max": float(t.max()), "unit": "degC"}}


def data_times(metadata: SiteMetadata | None, first: float, last: float) -> tuple[str, str]:
    """ISO 8601 UTC times of the first and last sample, from the data's ``start_time`` (time 0) and session times [s]."""
    from datetime import timedelta

    if metadata is None or not metadata.start_time:
        return "", ""
    origin = datetime.fromisoformat(metadata.start_time.replace("Z", "+00:00"))
    if origin.tzinfo is None:
        origin = origin.replace(tzinfo=UTC)

    def at(t: float) -> str:
        return (origin + timedelta(seconds=float(t))).astimezone(UTC).replace(microsecond=0).isoformat()

    return at(first), at(last)


# ---------------------------------------------------------------------- the record
@dataclass(frozen=True)
class CalibrationRecord:
    """A calibration of one unit: parameters, covariance, the calibration and every stage run it rests on, site.

    Build the first record of a calibration with :meth:`from_fit_result`, update it with a later stage
    (a Bayesian update) with :meth:`updated`, write it with :meth:`save`, read it with :meth:`load`.
    The covariance rows follow :attr:`ids` (the parameter order).
    """

    serial_number: str
    parameters: tuple[Parameter, ...]
    covariance: NDArray[np.float64]
    calibration: Calibration
    stages: tuple[StageRun, ...] = ()
    site: SiteMetadata | None = None
    determined: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()
    #: History of the fit that added discovered effects (validated; rendered by the certificate; docs/formats.md).
    discovery: ModelHistory | None = None
    #: The unit's noise model (:class:`stableins.noise.NoiseModel`, docs/noise.md): carried through every stage
    #: unchanged unless a stage measures it.
    noise_model: NoiseModel | None = None
    schema_version: int = RECORD_SCHEMA_VERSION

    def __post_init__(self) -> None:
        import numpy as np

        covariance = np.array(self.covariance, dtype=float)
        covariance.setflags(write=False)
        object.__setattr__(self, "covariance", covariance)
        _check(self, path=None)

    # ------------------------------------------------------------------ access
    @property
    def ids(self) -> tuple[str, ...]:
        return tuple(p.id for p in self.parameters)

    def __getitem__(self, parameter_id: str) -> Parameter:
        for p in self.parameters:
            if p.id == parameter_id:
                return p
        raise KeyError(parameter_id)

    def values(self) -> dict[str, float]:
        """``{id: value}`` [SI], e.g. for :meth:`stableins.errormodel.ErrorModel.forward`."""
        return {p.id: p.value for p in self.parameters}

    def error_model(self) -> ErrorModel:
        """The error model this record calibrates: the standard terms with ``K2`` and the discovered terms it carries.

        Compensation is ``record.error_model().inverse(output, record.values())`` (Wu et al.
        2018 Eq. 8 with the additive terms, :meth:`stableins.errormodel.ErrorModel.inverse`).
        """
        from stableins.discovery.library import record_terms
        from stableins.errormodel import ErrorModel

        return ErrorModel.standard(nonlinear=True) + record_terms(self.ids)

    def covariance_of(self, ids: Sequence[str]) -> NDArray[np.float64]:
        """The covariance block of the given parameters."""
        import numpy as np

        index = [self.ids.index(i) for i in ids]
        return self.covariance[np.ix_(index, index)]

    def stage(self, stage_id: str) -> StageRun:
        """The stage run with this id."""
        for s in self.stages:
            if s.id == stage_id:
                return s
        raise KeyError(stage_id)

    @property
    def stages_run(self) -> tuple[StageRun, ...]:
        """The stage runs of this record's calibration (the others are carried over from earlier calibrations)."""
        return tuple(s for s in self.stages if s.calibration == self.calibration.id)

    def last_determined_by(self, parameter_id: str) -> tuple[StageRun, Determination] | None:
        """The stage that last saw the parameter, and how; None if no stage's data did."""
        sources = self[parameter_id].determined_by
        if not sources:
            return None
        last = sources[-1]
        return self.stage(last.stage), last.how

    def measured_in_this_calibration(self, parameter_id: str) -> bool:
        """Whether a stage of this record's calibration saw the parameter."""
        run = {s.id for s in self.stages_run}
        return any(d.stage in run for d in self[parameter_id].determined_by)

    @property
    def provenance(self) -> Provenance:
        """Summary of this calibration (names of the stages run, their inputs and the span of their data)."""
        runs = self.stages_run
        inputs: list[InputFile] = []
        for s in runs:
            inputs += [f for f in s.inputs if f not in inputs]
        return Provenance(
            software=self.calibration.software,
            procedure=self.calibration.procedure,
            stages=tuple(s.name for s in runs),
            inputs=tuple(inputs),
            created=self.calibration.created,
            data_start=min((s.data_start for s in runs if s.data_start), default=""),
            data_end=max((s.data_end for s in runs if s.data_end), default=""),
        )

    @property
    def entries(self) -> tuple[Entry, ...]:
        """Every entry of this calibration: its own fields, then what was entered during its stage runs."""
        return self.calibration.entries + tuple(e for s in self.stages_run for e in s.entries)

    @property
    def valid_from(self) -> str:
        """When the record starts to be in force: the end of its calibration's data, else its creation time."""
        return self.provenance.data_end or self.calibration.created

    # ------------------------------------------------------------------ build
    @classmethod
    def from_device(
        cls,
        calibration: DeviceCalibration,
        site: SiteMetadata,
        inputs: Sequence[str] = (),
        procedure: str = "",
        *,
        data_start: str = "",
        data_end: str = "",
        environment: dict | None = None,
        entries: Sequence[Entry] = (),
    ) -> CalibrationRecord:
        """The record of a device-level calibration: its ``final`` fit (coarse and fine fused by joint GLS, not replaced).

        The record's stage run (``coarse+fine``, or ``coarse``) keeps the evidence of every fit (coarse, fine alone,
        fused, each with its χ²_ν), the fused likelihood and the calibration's ``settings``; ``entries`` are the
        calibration's fields.  The record carries ``calibration.noise`` (the noise model every σ rests on).
        """
        started = Calibration.new(procedure, entries)
        fits = [calibration.coarse] + [f for f in (calibration.fine, calibration.fused) if f is not None]
        stage = StageRun.from_fit(
            calibration.final,
            calibration=started.id,
            procedure=procedure,
            inputs=inputs,
            data_start=data_start,
            data_end=data_end,
            sample_rate=site.sample_rate,
            environment=environment,
            fits=fits,
            settings=calibration.settings or calibration.final.settings,
        )
        return cls.from_fit_result(calibration.final, site=site, stage=stage, calibration=started, noise_model=calibration.noise)

    @classmethod
    def from_fit_result(
        cls,
        result: FitResult,
        serial_number: str | None = None,
        *,
        site: SiteMetadata | None = None,
        inputs: Iterable[str | os.PathLike[str] | InputFile] = (),
        procedure: str = "",
        data_start: str = "",
        data_end: str = "",
        notes: Iterable[str] = (),
        created: str | None = None,
        stage: StageRun | None = None,
        calibration: Calibration | None = None,
        entries: Iterable[Entry] = (),
        noise_model: NoiseModel | None = None,
    ) -> CalibrationRecord:
        """The first record of a calibration: one data-only stage (no prior).

        Parameters
        ----------
        result : FitResult
            The stage's result (its terms give ids and SI units).
        serial_number : str, optional
            Defaults to ``site.serial_number``.
        site : SiteMetadata, optional
            Site metadata of the data.
        inputs, procedure, data_start, data_end, created
            Describe the stage run when ``stage`` is not given (inputs are hashed).
        notes : iterable of str
            Added to the result's own notes.
        stage : StageRun, optional
            The stage run (:meth:`StageRun.from_fit`); its ``calibration`` must be ``calibration.id``.
        calibration : Calibration, optional
            The calibration this record starts (a new one by default).
        entries : iterable of Entry
            The calibration's own fields (laboratory, customer, operator ...).
        noise_model : NoiseModel, optional
            The noise model the stage's σ rest on (docs/noise.md).
        """
        import numpy as np

        if serial_number is None:
            if site is None:
                raise ValueError("from_fit_result needs a serial_number or site metadata")
            serial_number = site.serial_number
        calibration = calibration or Calibration.new(procedure, entries)
        if stage is None:
            stage = StageRun.from_fit(
                result,
                calibration=calibration.id,
                procedure=procedure,
                inputs=inputs,
                data_start=data_start,
                data_end=data_end,
                sample_rate=None if site is None else site.sample_rate,
                created=created,
            )
        elif stage.calibration != calibration.id:
            stage = replace(stage, calibration=calibration.id)
        sigma = np.sqrt(np.clip(np.diag(result.covariance), 0.0, None))
        covariance = np.array(result.covariance, dtype=float)
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
                how = (DeterminedBy(stage.id, Determination.ALONE if estimable.get(term.id, True) else Determination.COMBINATION),)
            parameters.append(Parameter(term.id, float(result.values[k]), term.si_unit, s, status, how))
        return cls(
            serial_number=serial_number,
            parameters=tuple(parameters),
            covariance=covariance,
            calibration=calibration,
            stages=(stage,),
            site=site,
            determined=tuple(result.determined),
            notes=tuple(result.notes) + tuple(notes),
            noise_model=noise_model,
        )

    def updated(
        self,
        result: FitResult,
        *,
        stage: StageRun | None = None,
        new_calibration: bool = False,
        prior: PriorReference | None = None,
        procedure: str = "",
        calibration_entries: Iterable[Entry] = (),
        site: SiteMetadata | None = None,
        noise_model: NoiseModel | None = None,
        **stage_fields: Any,
    ) -> CalibrationRecord:
        """This record updated by a later stage: the Bayesian update with the stage's likelihood.

        Parameters
        ----------
        result : FitResult
            The stage's result; its :attr:`~FitResult.likelihood` is what enters (values and covariance
            of the result are not used: the posterior is computed over every parameter of the record).
        stage : StageRun, optional
            The stage run; by default :meth:`StageRun.from_fit` with ``procedure`` and ``stage_fields``
            (inputs, data_start, data_end, sample_rate, entries, environment ...).
        new_calibration : bool
            Start a new calibration (a recalibration from the record in force, with ``prior`` naming it)
            instead of continuing this record's.
        procedure : str
            Of the stage run.
        calibration_entries : iterable of Entry
            The calibration's own fields (laboratory, customer ...); a later key replaces an earlier one.
        site : SiteMetadata, optional
            Site of the new data (defaults to the record's).
        noise_model : NoiseModel, optional
            A noise model the stage measured; by default the record's is carried over unchanged.

        Raises
        ------
        InputError
            The stage has no likelihood, or its data determine no parameter of the record.
        """
        if result.likelihood is None:
            raise InputError(
                f"the {result.stage} stage gives no likelihood: it cannot update a record", field="stage", expected="a Bayesian stage"
            )
        calibration = self._next_calibration(new_calibration=new_calibration, prior=prior, procedure=procedure, entries=calibration_entries)
        if stage is None:
            where = site or self.site
            stage_fields.setdefault("sample_rate", None if where is None else where.sample_rate)
            stage = StageRun.from_fit(result, calibration=calibration.id, procedure=procedure, **stage_fields)
        units = {t.id: t.si_unit for t in result.terms}
        return self._apply(replace(stage, likelihood=result.likelihood), calibration, units, site, noise_model)

    def updated_by_run(
        self, stage: StageRun, *, new_calibration: bool = False, prior: PriorReference | None = None, site: SiteMetadata | None = None
    ) -> CalibrationRecord:
        """This record updated by a stage run of another record (its stored likelihood), e.g. ``stableins recal --estimate``."""
        if stage.likelihood is None:
            raise InputError(f"stage run {stage.id} carries no likelihood: it cannot update a record", field="stages")
        calibration = self._next_calibration(new_calibration=new_calibration, prior=prior, procedure=stage.procedure, entries=())
        return self._apply(stage, calibration, {}, site)

    def _next_calibration(
        self, *, new_calibration: bool, prior: PriorReference | None, procedure: str, entries: Iterable[Entry]
    ) -> Calibration:
        if new_calibration:
            return Calibration.new(procedure, entries, prior)
        names = [n for n in (*self.calibration.procedure.split(" + "), procedure) if n]
        merged = {e.key: e for e in (*self.calibration.entries, *entries)}
        return replace(self.calibration, procedure=" + ".join(dict.fromkeys(names)), entries=tuple(merged.values()))

    def _apply(
        self,
        stage: StageRun,
        calibration: Calibration,
        units: Mapping[str, str],
        site: SiteMetadata | None,
        noise_model: NoiseModel | None = None,
    ) -> CalibrationRecord:
        """The posterior of this record given ``stage.likelihood``, with ``stage`` appended (as a run of ``calibration``)."""
        from stableins.estimators.posterior import bayesian_update

        assert stage.likelihood is not None
        stage = replace(stage, calibration=calibration.id)
        if stage.id in {s.id for s in self.stages}:
            raise InputError(f"stage run {stage.id} is already part of this record", field="stages", expected="a new stage run")
        post = bayesian_update(self.ids, self.values_array(), self.covariance, [p.status for p in self.parameters], stage.likelihood)
        if not any(d is not None for d in post.determination):
            raise InputError(
                f"the {stage.name} stage's data determine no parameter of the record; no record written",
                field="stage",
                expected="data that determine at least one parameter",
            )
        parameters = []
        sigma = post.sigma
        for k, pid in enumerate(post.ids):
            before = self[pid] if pid in self.ids else None
            sources = before.determined_by if before is not None else ()
            how = post.determination[k]
            if how is not None:
                sources = sources + (DeterminedBy(stage.id, how),)
            unit = before.unit if before is not None else units.get(pid, "SI")
            s = float(sigma[k]) if post.status[k] is not Status.UNIDENTIFIABLE else math.nan
            parameters.append(Parameter(pid, float(post.values[k]), unit, s, post.status[k], sources))
        return CalibrationRecord(
            serial_number=self.serial_number,
            parameters=tuple(parameters),
            covariance=post.covariance,
            calibration=calibration,
            stages=self.stages + (stage,),
            site=site or self.site,
            determined=tuple(dict.fromkeys(self.determined + stage.determined)),
            notes=self.notes + tuple(f"[{stage.name}] {n}" for n in stage.notes),
            discovery=self.discovery,
            noise_model=noise_model if noise_model is not None else self.noise_model,
        )

    def values_array(self) -> NDArray[np.float64]:
        import numpy as np

        return np.array([p.value for p in self.parameters])

    def with_entries(self, entries: Iterable[Entry]) -> CalibrationRecord:
        """The same record with fields added to its calibration's entries (a later key replaces an earlier one)."""
        merged = {e.key: e for e in self.calibration.entries}
        merged.update({e.key: e for e in entries})
        return replace(self, calibration=replace(self.calibration, entries=tuple(merged.values())))

    # ------------------------------------------------------------------ files
    def to_document(self) -> dict[str, Any]:
        """JSON-ready dict (non-finite numbers as ``null``)."""
        document: dict[str, Any] = {
            "format": RECORD_FORMAT,
            "schema_version": self.schema_version,
            "serial_number": self.serial_number,
            "parameters": [
                {
                    "id": p.id,
                    "value": p.value,
                    "unit": p.unit,
                    "sigma": _num(p.sigma),
                    "status": p.status.value,
                    "determined_by": [{"stage": d.stage, "how": d.how.value} for d in p.determined_by],
                }
                for p in self.parameters
            ],
            "covariance": {
                "ids": list(self.ids),
                "unit": "SI: product of the two parameters' units",
                "matrix": [[_num(x) for x in row] for row in self.covariance.tolist()],
            },
            "calibration": {
                "id": self.calibration.id,
                "procedure": self.calibration.procedure,
                "software": self.calibration.software,
                "created": self.calibration.created,
                "prior": None
                if self.calibration.prior is None
                else {
                    "sha256": self.calibration.prior.sha256,
                    "path": self.calibration.prior.path,
                    "created": self.calibration.prior.created,
                },
                "entries": [_entry_document(e) for e in self.calibration.entries],
            },
            "stages": [_stage_document(s) for s in self.stages],
            "site": None if self.site is None else metadata_to_document(self.site),
            "determined": list(self.determined),
            "notes": list(self.notes),
        }
        if self.discovery is not None:
            document["discovery"] = self.discovery.to_json()
        if self.noise_model is not None:
            document["noise_model"] = self.noise_model.to_document()
        return document

    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write the record atomically (a reader sees the old file or the whole new one)."""
        from stableins.data.atomic import atomic_write

        text = _layout(self.to_document())
        with atomic_write(path) as handle:
            handle.write(text)
        return Path(path)

    @classmethod
    def from_document(cls, document: Any, path: str | None = None) -> CalibrationRecord:
        """Build and validate a record from its JSON document (version 1 is migrated, :func:`migrate_v1`)."""
        if isinstance(document, dict) and document.get("format") == RECORD_FORMAT and document.get("schema_version") == 1:
            document = migrate_v1(document, path)
        return _Reader(path).record(document)

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> CalibrationRecord:
        """Read and validate a record.

        Raises
        ------
        InputError
            Unknown schema version, missing keys, bad status, a covariance that is not
            square, symmetric, positive semi-definite or consistent with the σ's, ...
        """
        from stableins.data.jsonio import load_json_file

        document = load_json_file(path, what="a calibration record (JSON) written by stableins")
        return cls.from_document(document, str(path))

    # ------------------------------------------------------------------ people
    def rows(self) -> list[tuple[str, float, float, str, str, str]]:
        """``(id, value, σ, unit, status, determined by)`` in engineering units where the id is a known term."""
        from stableins.discovery.library import all_terms

        terms = all_terms()  # discovered terms in engineering units too
        out = []
        for p in self.parameters:
            t = terms.get(p.id)
            value, sigma, unit = (
                (float(t.to_engineering(p.value)), float(t.sigma_to_engineering(p.sigma)), t.unit) if t else (p.value, p.sigma, p.unit)
            )
            out.append((p.id, value, sigma, unit, p.status.value, self.source_text(p.id)))
        return out

    def source_text(self, parameter_id: str) -> str:
        """Which stage last determined the parameter, how, and whether in this calibration (console and certificate)."""
        last = self.last_determined_by(parameter_id)
        if last is None:
            return "—"
        run, how = last
        when = (run.data_end or run.created)[:10]
        text = f"{run.name} ({how.value}{', ' + when if when else ''})"
        return text if run.calibration == self.calibration.id else f"{text}, carried over"

    def report(self) -> str:
        """Plain-text table in engineering units: value, 1σ, status and the stage that last determined each parameter."""
        from stableins.estimators.result import parameter_table

        run = ", ".join(s.name for s in self.stages_run) or "none"
        lines = [f"calibration record of {self.serial_number} (stages run: {run}; {self.calibration.software})", ""]
        lines += parameter_table(self.rows(), self.determined, self.notes)
        if self.discovery is not None:
            lines += ["", self.discovery.report()]
        return "\n".join(lines)

    def __str__(self) -> str:
        return self.report()

    def _summary_lines(self) -> list[str]:
        from stableins.display import plural

        run = ", ".join(s.name for s in self.stages_run) or "none"
        lines = [f"calibration {self.calibration.id} ({self.calibration.software}); stages run: {run}; valid from {self.valid_from or '—'}"]
        carried = len(self.stages) - len(self.stages_run)
        if carried:
            lines[0] += f"; rests on {plural(carried, 'earlier stage run')}"
        return lines

    def _discovery_line(self) -> str | None:
        if self.discovery is None:
            return None
        verdicts = [f"{s.added[0][0]} {s.decision}" for s in self.discovery.steps[1:] if s.decision is not None and s.added]
        return "discovery: " + ("; ".join(verdicts) if verdicts else "baseline only")

    def _noise_line(self) -> str | None:
        model = self.noise_model
        if model is None:
            return None
        describe = getattr(model, "describe", None)
        if callable(describe):
            return str(describe())
        return f"noise model: {model.get('source', '')}" + (f" ({model['provenance']})" if model.get("provenance") else "")

    def __repr__(self) -> str:
        from stableins.display import clipped, parameter_lines, status_counts

        counts = status_counts(p.status for p in self.parameters)
        head = f"<CalibrationRecord of {self.serial_number}: {len(self.parameters)} parameters ({counts})>"
        lines = [head, *self._summary_lines(), *parameter_lines(row[:5] for row in self.rows())]
        lines += [line for line in (self._discovery_line(), self._noise_line()) if line]
        return clipped(lines, "(print(record) for the full report, record.to_dataframe() for the table)")

    def _repr_html_(self) -> str:
        from stableins.discovery.library import all_terms
        from stableins.display import html_result, parameter_html

        terms = all_terms()
        meanings = [terms[p.id].meaning if p.id in terms else "" for p in self.parameters]
        tables = [parameter_html(self.rows(), meanings, extra="last determined by")]
        if self.discovery is not None:
            tables.append(self.discovery._repr_html_())
        return html_result(
            f"Calibration record of {self.serial_number}",
            [*self._summary_lines(), self._noise_line() or ""],
            tables,
            [("determined combinations", self.determined), ("notes", self.notes)],
        )

    def to_dataframe(self) -> Any:
        """The parameter table as a :class:`pandas.DataFrame` indexed by parameter id.

        Columns ``value``, ``sigma``, ``unit`` (engineering units where the id is a known term), ``status``,
        ``determined_by`` (the stage that last determined it, :meth:`source_text`), ``value_si``, ``sigma_si``,
        ``si_unit``; an ``unidentifiable`` parameter has no value.  Needs pandas (``pip install stableins[pandas]``).
        """
        from stableins.display import require_pandas

        pandas = require_pandas()
        out = []
        for (pid, value, sigma, unit, status, source), p in zip(self.rows(), self.parameters, strict=True):
            hidden = p.status is Status.UNIDENTIFIABLE
            nan = math.nan
            out.append(
                {
                    "parameter": pid,
                    "value": nan if hidden else value,
                    "sigma": nan if hidden else sigma,
                    "unit": unit,
                    "status": status,
                    "determined_by": source,
                    "value_si": nan if hidden else p.value,
                    "sigma_si": nan if hidden else p.sigma,
                    "si_unit": p.unit,
                }
            )
        return pandas.DataFrame.from_records(out, index="parameter")


def _estimable(result: FitResult) -> dict[str, bool]:
    """Which of the result's parameters its likelihood determines by itself (all, without a likelihood)."""
    if result.likelihood is None:
        return {}
    held = {t.id: float(v) for t, v, s in zip(result.terms, result.values, result.status, strict=True) if s is Status.GAUGE}
    lik = result.likelihood.conditioned({i: v for i, v in held.items() if i in result.likelihood.ids})
    return dict(zip(lik.ids, map(bool, lik.estimable()), strict=True))


# ---------------------------------------------------------------------- JSON
def _num(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def _entry_document(e: Entry) -> dict[str, Any]:
    out: dict[str, Any] = {"key": e.key, "value": e.value, "unit": e.unit}
    if e.prompt:
        out["prompt"] = e.prompt
    return out


def _stage_document(s: StageRun) -> dict[str, Any]:
    out: dict[str, Any] = {
        "id": s.id,
        "name": s.name,
        "calibration": s.calibration,
        "procedure": s.procedure,
        "software": s.software,
        "created": s.created,
        "data_start": s.data_start,
        "data_end": s.data_end,
        "sample_rate": None if s.sample_rate is None else {"value": float(s.sample_rate), "unit": "Hz"},
        "inputs": [{"path": f.path, "sha256": f.sha256} for f in s.inputs],
        "settings": dict(s.settings),
        "entries": [_entry_document(e) for e in s.entries],
        "environment": dict(s.environment),
        "fits": [dict(f) for f in s.fits],
        "likelihood": None
        if s.likelihood is None
        else {
            "ids": list(s.likelihood.ids),
            "point": s.likelihood.point.tolist(),
            "information": s.likelihood.information.tolist(),
            "gradient": s.likelihood.gradient.tolist(),
        },
        "determined": list(s.determined),
        "notes": list(s.notes),
    }
    if s.sensitivities:
        out["sensitivities"] = [x.to_json() for x in s.sensitivities]
    return out


def _layout(document: Any, indent: str = "", width: int = 160) -> str:
    """JSON for people and diffs: short values on one line, long objects one key, list item or matrix row per line."""
    text = json.dumps(document, allow_nan=False, ensure_ascii=False)
    if len(text) + len(indent) <= width or not isinstance(document, dict | list) or not document:
        return text
    inner = indent + "  "
    if isinstance(document, dict):
        items = [f"{inner}{json.dumps(k)}: {_layout(v, inner, width)}" for k, v in document.items()]
        return "{\n" + ",\n".join(items) + "\n" + indent + "}"
    items = [inner + _layout(v, inner, width) for v in document]
    return "[\n" + ",\n".join(items) + "\n" + indent + "]"


def migrate_v1(document: dict[str, Any], path: str | None = None) -> dict[str, Any]:
    """A schema-version-1 document as version 2.

    Version 1 had one ``provenance`` (procedure, stage names, inputs, times) and no stage runs:
    the migrated record has one stage run named after the stages (``coarse+fine+system``) that holds
    them, with no likelihood and no fits, and every estimated parameter determined by it.  A note says so.
    """
    prov = document.get("provenance")
    if not isinstance(prov, dict):
        raise InputError("malformed", path=path, field="provenance", expected="an object with software, procedure, stages, inputs, created")
    stages = prov.get("stages", [])
    name = "+".join(stages) if isinstance(stages, list) and all(isinstance(s, str) for s in stages) and stages else "calibration"
    created = prov.get("created", "") if isinstance(prov.get("created", ""), str) else ""
    calibration_id = f"cal-v1-{hashlib.sha256(json.dumps([document.get('serial_number'), created]).encode()).hexdigest()[:8]}"
    stage_id = f"{name}-v1{calibration_id[-6:]}"
    parameters = []
    for item in document.get("parameters", []) if isinstance(document.get("parameters"), list) else []:
        if isinstance(item, dict):
            item = dict(item)
            item["determined_by"] = [{"stage": stage_id, "how": "alone"}] if item.get("status") == Status.ESTIMATED else []
        parameters.append(item)
    site = document.get("site")
    sample_rate = None
    if isinstance(site, dict) and isinstance(site.get("sample_rate"), dict):
        sample_rate = site["sample_rate"]
    out = {k: v for k, v in document.items() if k not in ("provenance", "parameters", "schema_version")}
    out["schema_version"] = RECORD_SCHEMA_VERSION
    out["parameters"] = parameters
    out["calibration"] = {
        "id": calibration_id,
        "procedure": prov.get("procedure", ""),
        "software": prov.get("software", ""),
        "created": created,
        "prior": None,
        "entries": [],
    }
    out["stages"] = [
        {
            "id": stage_id,
            "name": name,
            "calibration": calibration_id,
            "procedure": prov.get("procedure", ""),
            "software": prov.get("software", ""),
            "created": created,
            "data_start": prov.get("data_start", ""),
            "data_end": prov.get("data_end", ""),
            "sample_rate": sample_rate,
            "inputs": prov.get("inputs", []),
            "settings": {},
            "entries": [],
            "environment": {},
            "fits": [],
            "likelihood": None,
            "determined": [],
            "notes": ["migrated from a schema-version-1 record: the stages' settings, fits and likelihood were not recorded"],
        }
    ]
    out["notes"] = list(document.get("notes", [])) if isinstance(document.get("notes", []), list) else document.get("notes")
    if isinstance(out["notes"], list):
        out["notes"].append("record migrated from schema version 1 (docs/formats.md)")
    return out


class _Reader:
    """Validation of a version-2 document, every problem an :class:`InputError` naming the file and key."""

    def __init__(self, path: str | None) -> None:
        self.path = path

    def fail(self, message: str, key: str | None = None, expected: str | None = None) -> InputError:
        return InputError(message, path=self.path, field=key, expected=expected)

    def text(self, value: Any, key: str) -> str:
        if not isinstance(value, str):
            raise self.fail(f"{value!r} is not a string", key, "a string")
        return value

    def texts(self, value: Any, key: str) -> tuple[str, ...]:
        if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
            raise self.fail(f"{value!r} is not a list of strings", key, "a list of strings")
        return tuple(value)

    def mapping(self, value: Any, key: str) -> dict[str, Any]:
        if not isinstance(value, dict):
            raise self.fail("not an object", key, "a JSON object")
        return value

    def number(self, value: Any, key: str) -> float:
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
            raise self.fail(f"{value!r} is not a finite number", key, "a finite number")
        return float(value)

    def matrix(self, rows: Any, n: int, key: str, *, nulls: bool) -> Any:
        import numpy as np

        if not isinstance(rows, list) or len(rows) != n or not all(isinstance(r, list) and len(r) == n for r in rows):
            raise self.fail("not a square list of rows", key, f"{n} rows of {n} numbers")
        ok = (
            (lambda x: x is None or (isinstance(x, int | float) and not isinstance(x, bool)))
            if nulls
            else (lambda x: isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x))
        )
        if not all(ok(x) for r in rows for x in r):
            raise self.fail("not a numeric matrix", key, "numbers (null only for unidentifiable parameters)" if nulls else "finite numbers")
        return np.array([[math.nan if x is None else float(x) for x in r] for r in rows], dtype=float).reshape(n, n)

    def entries(self, value: Any, key: str) -> tuple[Entry, ...]:
        if not isinstance(value, list):
            raise self.fail("not a list", key, '[{"key", "value", "unit"}]')
        out = []
        for k, item in enumerate(value):
            where = f"{key}[{k}]"
            item = self.mapping(item, where)
            if "key" not in item or "value" not in item:
                raise self.fail("missing key or value", where, '{"key", "value", "unit"}')
            v = item["value"]
            if isinstance(v, bool) or not isinstance(v, str | int | float) or (isinstance(v, float) and not math.isfinite(v)):
                raise self.fail(f"{v!r} is not a number or text", f"{where}.value", "a finite number or a string")
            out.append(
                Entry(
                    self.text(item["key"], f"{where}.key"),
                    float(v) if isinstance(v, int | float) else v,
                    self.text(item.get("unit", ""), f"{where}.unit"),
                    self.text(item.get("prompt", ""), f"{where}.prompt"),
                )
            )
        return tuple(out)

    def inputs(self, value: Any, key: str) -> tuple[InputFile, ...]:
        if not isinstance(value, list) or not all(
            isinstance(f, dict) and isinstance(f.get("path"), str) and isinstance(f.get("sha256"), str) for f in value
        ):
            raise self.fail("malformed input list", key, '[{"path": ..., "sha256": ...}]')
        for f in value:
            if len(f["sha256"]) != 64 or any(c not in "0123456789abcdef" for c in f["sha256"].lower()):
                raise self.fail(f"not a SHA-256 hex digest for {f['path']!r}: {f['sha256']!r}", key, "64 hex digits")
        return tuple(InputFile(f["path"], f["sha256"]) for f in value)

    def likelihood(self, value: Any, key: str) -> Likelihood | None:
        if value is None:
            return None
        import numpy as np

        from stableins.estimators.result import Likelihood

        value = self.mapping(value, key)
        ids = self.texts(value.get("ids"), f"{key}.ids")
        n = len(ids)
        vectors = []
        for name in ("point", "gradient"):
            v = value.get(name)
            if not isinstance(v, list) or len(v) != n:
                raise self.fail("not a list of one number per id", f"{key}.{name}", f"{n} numbers")
            vectors.append(np.array([self.number(x, f"{key}.{name}") for x in v]))
        information = self.matrix(value.get("information"), n, f"{key}.information", nulls=False)
        try:
            return Likelihood(ids, vectors[0], information, vectors[1])
        except ValueError as error:
            raise self.fail(str(error), key) from None

    def stage(self, value: Any, k: int) -> StageRun:
        where = f"stages[{k}]"
        s = self.mapping(value, where)
        for name in ("id", "name", "calibration"):
            if name not in s:
                raise self.fail("missing key", f"{where}.{name}", "the keys of docs/formats.md")
        rate = s.get("sample_rate")
        if rate is not None:
            rate = self.mapping(rate, f"{where}.sample_rate")
            if rate.get("unit") != "Hz":
                raise self.fail(f"unit {rate.get('unit')!r}", f"{where}.sample_rate", "unit 'Hz'")
            rate = self.number(rate.get("value"), f"{where}.sample_rate")
        fits = s.get("fits", [])
        if not isinstance(fits, list) or not all(isinstance(f, dict) for f in fits):
            raise self.fail("not a list of objects", f"{where}.fits", "fit evidence objects")
        return StageRun(
            id=self.text(s["id"], f"{where}.id"),
            name=self.text(s["name"], f"{where}.name"),
            calibration=self.text(s["calibration"], f"{where}.calibration"),
            procedure=self.text(s.get("procedure", ""), f"{where}.procedure"),
            software=self.text(s.get("software", ""), f"{where}.software"),
            created=self.text(s.get("created", ""), f"{where}.created"),
            data_start=self.text(s.get("data_start", ""), f"{where}.data_start"),
            data_end=self.text(s.get("data_end", ""), f"{where}.data_end"),
            sample_rate=rate,
            inputs=self.inputs(s.get("inputs", []), f"{where}.inputs"),
            settings=dict(self.mapping(s.get("settings", {}), f"{where}.settings")),
            entries=self.entries(s.get("entries", []), f"{where}.entries"),
            environment=dict(self.mapping(s.get("environment", {}), f"{where}.environment")),
            fits=tuple(dict(f) for f in fits),
            likelihood=self.likelihood(s.get("likelihood"), f"{where}.likelihood"),
            determined=self.texts(s.get("determined", []), f"{where}.determined"),
            notes=self.texts(s.get("notes", []), f"{where}.notes"),
            sensitivities=self.sensitivities(s.get("sensitivities", []), f"{where}.sensitivities"),
        )

    def sensitivities(self, value: Any, key: str) -> tuple[InputSensitivity, ...]:
        import numpy as np

        from stableins.estimators.result import InputSensitivity

        if not isinstance(value, list):
            raise self.fail("not a list", key, "a list of input sensitivities (docs/formats.md)")
        out = []
        for k, item in enumerate(value):
            where = f"{key}[{k}]"
            item = self.mapping(item, where)
            ids = self.texts(item.get("ids"), f"{where}.ids")
            n = len(ids)
            gradient = covariance = None
            if "gradient" in item:
                v = item["gradient"]
                if not isinstance(v, list) or len(v) != n:
                    raise self.fail("not a list of one number per id", f"{where}.gradient", f"{n} numbers")
                gradient = np.array([self.number(x, f"{where}.gradient") for x in v])
            if "covariance" in item:
                covariance = self.matrix(item["covariance"], n, f"{where}.covariance", nulls=False)
            try:
                out.append(
                    InputSensitivity(
                        self.text(item.get("input"), f"{where}.input"),
                        self.text(item.get("unit", ""), f"{where}.unit"),
                        ids,
                        self.number(item.get("value", 0.0), f"{where}.value"),
                        gradient,
                        covariance,
                        self.number(item.get("step", 0.0), f"{where}.step"),
                    )
                )
            except ValueError as error:
                raise self.fail(str(error), where, "a gradient or a covariance over the ids") from None
        return tuple(out)

    def record(self, document: Any) -> CalibrationRecord:
        fail = self.fail
        if not isinstance(document, dict):
            raise fail("not a JSON object", expected="a calibration record (docs/formats.md)")
        if document.get("format") != RECORD_FORMAT:
            raise fail(f"format {document.get('format')!r}", "format", f"'{RECORD_FORMAT}'")
        if document.get("schema_version") != RECORD_SCHEMA_VERSION:
            raise fail(
                f"unknown schema version {document.get('schema_version')!r}; this stableins reads versions 1 and {RECORD_SCHEMA_VERSION}",
                "schema_version",
                str(RECORD_SCHEMA_VERSION),
            )
        for key in ("serial_number", "parameters", "covariance", "calibration", "stages"):
            if key not in document:
                raise fail("missing key", key, "the keys of docs/formats.md")
        if not isinstance(document["stages"], list):
            raise fail("not a list", "stages", "a list of stage runs")
        stages = tuple(self.stage(s, k) for k, s in enumerate(document["stages"]))
        stage_ids = {s.id for s in stages}
        if len(stage_ids) != len(stages):
            raise fail("a stage id appears twice", "stages", "unique stage ids")
        if not isinstance(document["parameters"], list) or not document["parameters"]:
            shown = "not a list" if not isinstance(document["parameters"], list) else "empty"
            raise fail(shown, "parameters", "a non-empty list of parameter objects")
        parameters = []
        keys = '{"id", "value", "unit", "sigma", "status", "determined_by"}'
        for k, item in enumerate(document["parameters"]):
            where = f"parameters[{k}]"
            if not isinstance(item, dict):
                raise fail("not an object", where, keys)
            for key in ("id", "value", "unit", "sigma", "status"):
                if key not in item:
                    raise fail("missing key", f"{where}.{key}", keys)
            parameter_id = self.text(item["id"], f"{where}.id")
            if item["status"] not in STATUSES:
                raise fail(f"bad status {item['status']!r} for {parameter_id!r}", f"{where}.status", " or ".join(STATUSES))
            value = self.number(item["value"], f"{where}.value")
            sigma = math.nan if item["sigma"] is None else self.number(item["sigma"], f"{where}.sigma")
            sources = []
            given = item.get("determined_by", [])
            if not isinstance(given, list):
                raise fail("not a list", f"{where}.determined_by", '[{"stage": ..., "how": ...}]')
            for j, d in enumerate(given):
                at = f"{where}.determined_by[{j}]"
                if not isinstance(d, dict) or not isinstance(d.get("stage"), str) or d["stage"] not in stage_ids:
                    raise fail(f"{d!r} does not name a stage of the record", at, "the id of one of the record's stages")
                if d.get("how") not in tuple(h.value for h in Determination):
                    raise fail(f"how {d.get('how')!r}", f"{at}.how", " or ".join(h.value for h in Determination))
                sources.append(DeterminedBy(d["stage"], Determination(d["how"])))
            parameters.append(
                Parameter(parameter_id, value, self.text(item["unit"], f"{where}.unit"), sigma, Status(item["status"]), tuple(sources))
            )
        cov = document["covariance"]
        if not isinstance(cov, dict) or "ids" not in cov or "matrix" not in cov:
            raise fail("malformed", "covariance", '{"ids": [...], "matrix": [[...]]}')
        ids = [p.id for p in parameters]
        if cov["ids"] != ids:
            raise fail(f"ids {cov['ids']!r} do not follow the parameters {ids}", "covariance.ids", "the parameter ids in order")
        matrix = self.matrix(cov["matrix"], len(ids), "covariance.matrix", nulls=True)
        c = self.mapping(document["calibration"], "calibration")
        if "id" not in c:
            raise fail("missing key", "calibration.id", "the keys of docs/formats.md")
        prior = c.get("prior")
        if prior is not None:
            prior = self.mapping(prior, "calibration.prior")
            prior = PriorReference(
                self.text(prior.get("sha256", ""), "calibration.prior.sha256"),
                self.text(prior.get("path", ""), "calibration.prior.path"),
                self.text(prior.get("created", ""), "calibration.prior.created"),
            )
        calibration = Calibration(
            id=self.text(c["id"], "calibration.id"),
            procedure=self.text(c.get("procedure", ""), "calibration.procedure"),
            software=self.text(c.get("software", ""), "calibration.software"),
            created=self.text(c.get("created", ""), "calibration.created"),
            prior=prior,
            entries=self.entries(c.get("entries", []), "calibration.entries"),
        )
        site = None if document.get("site") is None else metadata_from_document(document["site"], self.path)
        optional: dict[str, Any] = {}
        if document.get("noise_model") is not None:
            from stableins.noise import NoiseModel

            optional["noise_model"] = NoiseModel.from_document(document["noise_model"], self.path)
        if document.get("discovery") is not None:
            from stableins.discovery.history import ModelHistory

            try:
                optional["discovery"] = ModelHistory.from_json(document["discovery"])
            except ValueError as error:
                where, _, what = str(error).partition(": ")
                raise fail(what, where, "the discovery section of docs/formats.md") from None
        record = CalibrationRecord.__new__(CalibrationRecord)
        fields = {
            "serial_number": self.text(document["serial_number"], "serial_number"),
            "parameters": tuple(parameters),
            "covariance": matrix,
            "calibration": calibration,
            "stages": stages,
            "site": site,
            "determined": self.texts(document.get("determined", []), "determined"),
            "notes": self.texts(document.get("notes", []), "notes"),
            "discovery": optional.get("discovery"),
            "noise_model": optional.get("noise_model"),
            "schema_version": RECORD_SCHEMA_VERSION,
        }
        for name, value in fields.items():
            object.__setattr__(record, name, value)
        matrix.setflags(write=False)
        _check(record, self.path)
        return record


def _check(record: CalibrationRecord, path: str | None) -> None:
    """Consistency of a record; raises InputError naming the key."""
    import numpy as np

    def fail(message: str, key: str, expected: str | None = None) -> InputError:
        return InputError(message, path=path, field=key, expected=expected)

    if not record.serial_number:
        raise fail("empty serial number", "serial_number", "a non-empty string")
    ids = record.ids
    if len(set(ids)) != len(ids):
        duplicate = next(i for i in ids if ids.count(i) > 1)
        raise fail(f"parameter {duplicate!r} appears twice", "parameters", "each id once")
    stage_ids = {s.id for s in record.stages}
    for k, p in enumerate(record.parameters):
        for d in p.determined_by:
            if d.stage not in stage_ids:
                raise fail(f"{p.id!r} names stage {d.stage!r}, which the record does not hold", f"parameters[{k}].determined_by")
    n = len(ids)
    c = record.covariance
    if c.shape != (n, n):
        raise fail(f"shape {c.shape}", "covariance", f"({n}, {n}) following the parameters")
    if record.discovery is not None:
        missing = [e for e in record.discovery.effects if e not in ids]
        if missing:
            raise fail(
                f"the discovery history keeps {missing}, which are not parameters of the record",
                "discovery",
                "kept effects among the parameters",
            )
    known = np.array([p.status is not Status.UNIDENTIFIABLE for p in record.parameters], dtype=bool)
    for k, p in enumerate(record.parameters):
        if p.status not in STATUSES:
            raise fail(f"bad status {p.status!r}", f"parameters[{k}].status", " or ".join(STATUSES))
        if not math.isfinite(p.value):
            raise fail("value is not finite", f"parameters[{k}].value", "a finite number")
        if known[k] and not (np.isfinite(c[k, known]).all() and math.isfinite(p.sigma)):
            raise fail(
                f"covariance of {p.id!r} ({p.status}) is not finite", "covariance", "finite entries except for unidentifiable parameters"
            )
    block = c[np.ix_(known, known)]
    if block.size:
        scale = float(np.abs(block).max()) or 1.0
        asymmetry = float(np.abs(block - block.T).max())
        if asymmetry > SYMMETRY_TOLERANCE * scale:
            i, j = np.unravel_index(int(np.argmax(np.abs(block - block.T))), block.shape)
            a, b = np.array(ids)[known][[i, j]]
            raise fail(
                f"covariance is not symmetric: ({a}, {b}) differs from ({b}, {a}) by {asymmetry:.3g}", "covariance", "a symmetric matrix"
            )
        d = np.sqrt(np.clip(np.diag(block), 0.0, None))
        with np.errstate(divide="ignore", invalid="ignore"):
            correlation = np.where(np.outer(d, d) > 0, block / np.outer(d, d), 0.0)
        if (np.diag(block) < 0).any() or np.linalg.eigvalsh((correlation + correlation.T) / 2).min() < -1e-8:
            raise fail("covariance is not positive semi-definite", "covariance", "a valid covariance matrix")
        sigma = np.array([p.sigma for p in record.parameters])[known]
        bad = ~np.isclose(sigma, d, rtol=1e-6, atol=0.0)
        if bad.any():
            k = int(np.flatnonzero(known)[int(np.argmax(bad))])
            raise fail(
                f"sigma {record.parameters[k].sigma!r} of {ids[k]!r} disagrees with the covariance diagonal",
                f"parameters[{k}].sigma",
                f"sqrt of the covariance diagonal = {d[int(np.argmax(bad))]!r}",
            )


__all__ = [
    "CALIBRATION_FIELDS",
    "STATUSES",
    "Calibration",
    "CalibrationRecord",
    "DeterminedBy",
    "Entry",
    "InputFile",
    "Parameter",
    "PriorReference",
    "Provenance",
    "StageRun",
    "Status",
    "data_times",
    "file_sha256",
    "fit_evidence",
    "migrate_v1",
    "parse_entries",
    "temperature_summary",
]
