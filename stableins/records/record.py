"""The calibration record of one unit: parameters, covariance, the calibration and every stage run it rests on.

The class holds the data and answers questions about them; building (:mod:`stableins.records.build`),
the JSON file (:mod:`stableins.records.writer`, :mod:`stableins.records.reader`), validation
(:mod:`stableins.records.check`) and what people see (:mod:`stableins.records.display`) live in their
own modules, and the methods here delegate to them.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Unpack

from stableins.records.check import check_record
from stableins.records.parameters import Entry, Parameter
from stableins.records.schema import RECORD_SCHEMA_VERSION
from stableins.records.stages import Calibration, InputFile, Provenance, StageRun
from stableins.site import SiteMetadata
from stableins.status import Determination

if TYPE_CHECKING:  # pragma: no cover
    import numpy as np
    from numpy.typing import NDArray

    from stableins.discovery.history import ModelHistory
    from stableins.errormodel import ErrorModel
    from stableins.estimators.device import DeviceCalibration
    from stableins.estimators.result import FitResult
    from stableins.noise import NoiseModel
    from stableins.records.build import DeviceFields, RecordFields, UpdateFields
    from stableins.records.stages import PriorReference


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
        check_record(self, path=None)

    # ------------------------------------------------------------------ access
    @property
    def ids(self) -> tuple[str, ...]:
        """The parameter ids, in the order of the parameters and of the covariance rows."""
        return tuple(p.id for p in self.parameters)

    def __getitem__(self, parameter_id: str) -> Parameter:
        for p in self.parameters:
            if p.id == parameter_id:
                return p
        raise KeyError(parameter_id)

    def values(self) -> dict[str, float]:
        """Return ``{id: value}`` [SI], e.g. for :meth:`stableins.errormodel.ErrorModel.forward`."""
        return {p.id: p.value for p in self.parameters}

    def values_array(self) -> NDArray[np.float64]:
        """Return the values [SI] in the order of :attr:`ids`."""
        import numpy as np

        return np.array([p.value for p in self.parameters])

    def error_model(self) -> ErrorModel:
        """Return the error model this record calibrates: the standard terms with ``K2`` and the discovered terms it carries.

        Compensation is ``record.error_model().inverse(output, record.values())`` (Wu et al.
        2018 Eq. 8 with the additive terms, :meth:`stableins.errormodel.ErrorModel.inverse`).
        """
        from stableins.discovery.library import record_terms
        from stableins.errormodel import ErrorModel

        return ErrorModel.standard(nonlinear=True) + record_terms(self.ids)

    def covariance_of(self, ids: Sequence[str]) -> NDArray[np.float64]:
        """Return the covariance block of the given parameters."""
        import numpy as np

        index = [self.ids.index(i) for i in ids]
        return self.covariance[np.ix_(index, index)]

    def stage(self, stage_id: str) -> StageRun:
        """Return the stage run with this id (KeyError if the record holds none)."""
        for s in self.stages:
            if s.id == stage_id:
                return s
        raise KeyError(stage_id)

    @property
    def stages_run(self) -> tuple[StageRun, ...]:
        """The stage runs of this record's calibration (the others are carried over from earlier calibrations)."""
        return tuple(s for s in self.stages if s.calibration == self.calibration.id)

    def last_determined_by(self, parameter_id: str) -> tuple[StageRun, Determination] | None:
        """Return the stage that last saw the parameter, and how; None if no stage's data did."""
        sources = self[parameter_id].determined_by
        if not sources:
            return None
        last = sources[-1]
        return self.stage(last.stage), last.how

    def measured_in_this_calibration(self, parameter_id: str) -> bool:
        """Tell whether a stage of this record's calibration saw the parameter."""
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
    def from_device(cls, calibration: DeviceCalibration, site: SiteMetadata, **fields: Unpack[DeviceFields]) -> CalibrationRecord:
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
        **fields
            :class:`stableins.records.build.DeviceFields`: ``inputs`` (hashed), ``procedure``, ``data_start``,
            ``data_end``, ``environment``, ``entries``.

        Returns
        -------
        CalibrationRecord
            The first record of a new calibration.
        """
        from stableins.records.build import record_from_device

        return record_from_device(calibration, site, **fields)

    @classmethod
    def from_fit_result(cls, result: FitResult, serial_number: str | None = None, **fields: Unpack[RecordFields]) -> CalibrationRecord:
        """Return the first record of a calibration: one data-only stage (no prior).

        Parameters
        ----------
        result : FitResult
            The stage's result (its terms give ids and SI units).
        serial_number : str, optional
            Defaults to ``site.serial_number``.
        **fields
            :class:`stableins.records.build.RecordFields`.  ``site`` (SiteMetadata): site metadata of the data;
            ``inputs``, ``procedure``, ``data_start``, ``data_end``, ``created``: describe the stage run when
            ``stage`` is not given (inputs are hashed); ``notes``: added to the result's own notes; ``stage``
            (StageRun, :meth:`StageRun.from_fit`): the stage run, its ``calibration`` must be ``calibration.id``;
            ``calibration``: the calibration this record starts (a new one by default); ``entries``: the
            calibration's own fields (laboratory, customer, operator ...); ``noise_model``: the noise model the
            stage's σ rest on (docs/noise.md).

        Returns
        -------
        CalibrationRecord
            The record.
        """
        from stableins.records.build import record_from_fit

        return record_from_fit(result, serial_number, **fields)

    def updated(self, result: FitResult, **fields: Unpack[UpdateFields]) -> CalibrationRecord:
        """Return this record updated by a later stage: the Bayesian update with the stage's likelihood.

        Parameters
        ----------
        result : FitResult
            The stage's result; its :attr:`~FitResult.likelihood` is what enters (values and covariance
            of the result are not used: the posterior is computed over every parameter of the record).
        **fields
            :class:`stableins.records.build.UpdateFields`.  ``stage`` (StageRun): the stage run, by default
            :meth:`StageRun.from_fit` with ``procedure`` and the stage fields (``inputs``, ``data_start``,
            ``data_end``, ``sample_rate``, ``entries``, ``environment`` ...); ``new_calibration`` (bool): start
            a new calibration (a recalibration from the record in force, with ``prior`` naming it) instead of
            continuing this record's; ``procedure``: of the stage run; ``calibration_entries``: the calibration's
            own fields (laboratory, customer ...), a later key replaces an earlier one; ``site``: site of the new
            data (defaults to the record's); ``noise_model``: a noise model the stage measured (by default the
            record's is carried over unchanged).

        Returns
        -------
        CalibrationRecord
            The posterior record, the stage run appended.

        Raises
        ------
        InputError
            The stage has no likelihood, or its data determine no parameter of the record.
        """
        from stableins.records.build import update_record

        return update_record(self, result, **fields)

    def updated_by_run(
        self, stage: StageRun, *, new_calibration: bool = False, prior: PriorReference | None = None, site: SiteMetadata | None = None
    ) -> CalibrationRecord:
        """Return this record updated by a stage run of another record (its stored likelihood), e.g. ``stableins recal --estimate``."""
        from stableins.records.build import update_by_run

        return update_by_run(self, stage, new_calibration=new_calibration, prior=prior, site=site)

    def with_entries(self, entries: Iterable[Entry]) -> CalibrationRecord:
        """Return the same record with fields added to its calibration's entries (a later key replaces an earlier one)."""
        merged = {e.key: e for e in self.calibration.entries}
        merged.update({e.key: e for e in entries})
        return replace(self, calibration=replace(self.calibration, entries=tuple(merged.values())))

    # ------------------------------------------------------------------ files
    def to_document(self) -> dict[str, Any]:
        """Return the JSON-ready dict (non-finite numbers as ``null``; docs/formats.md)."""
        from stableins.records.writer import record_document

        return record_document(self)

    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write the record atomically (a reader sees the old file or the whole new one); return its path."""
        from stableins.records.writer import save_record

        return save_record(self, path)

    @classmethod
    def from_document(cls, document: Any, path: str | None = None) -> CalibrationRecord:
        """Build and validate a record from its JSON document (version 1 is migrated, :func:`migrate_v1`)."""
        from stableins.records.reader import read_document

        return read_document(document, path)

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
        """Return ``(id, value, σ, unit, status, determined by)`` in engineering units where the id is a known term."""
        from stableins.records.display import parameter_rows

        return parameter_rows(self)

    def source_text(self, parameter_id: str) -> str:
        """Return which stage last determined the parameter, how, and whether in this calibration (console and certificate)."""
        from stableins.records.display import source_text

        return source_text(self, parameter_id)

    def report(self) -> str:
        """Return a plain-text table in engineering units: value, 1σ, status and the stage that last determined each parameter."""
        from stableins.records.display import report

        return report(self)

    def __str__(self) -> str:
        return self.report()

    def __repr__(self) -> str:
        from stableins.records.display import text_repr

        return text_repr(self)

    def _repr_html_(self) -> str:
        from stableins.records.display import html_repr

        return html_repr(self)

    def to_dataframe(self) -> Any:
        """Return the parameter table as a :class:`pandas.DataFrame` indexed by parameter id.

        Columns ``value``, ``sigma``, ``unit`` (engineering units where the id is a known term), ``status``,
        ``determined_by`` (the stage that last determined it, :meth:`source_text`), ``value_si``, ``sigma_si``,
        ``si_unit``; an ``unidentifiable`` parameter has no value.  Needs pandas (``pip install stableins[pandas]``).
        """
        from stableins.records.display import dataframe

        return dataframe(self)
