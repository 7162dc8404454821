"""The calibration record of one unit: its content, and how it is built, written, read and shown.

:class:`CalibrationRecord` is :class:`~stableins.records.content.RecordContent` (the data, the questions they
answer, the check at construction) with the methods people use: building (:mod:`stableins.records.build`),
the JSON file (:mod:`stableins.records.writer`, :mod:`stableins.records.reader`) and what people see
(:mod:`stableins.records.display`).  Those modules take a content and never import this one.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING, Any, Self

from stableins.data.jsonio import load_json_file
from stableins.records import display
from stableins.records.build import record_from_device, record_from_fit, update_by_run, update_record
from stableins.records.content import RecordContent
from stableins.records.parameters import Entry
from stableins.records.reader import read_document
from stableins.records.stages import UNDESCRIBED, PriorReference, RunInfo, StageRun
from stableins.records.writer import record_document, save_record
from stableins.site import SiteMetadata

if TYPE_CHECKING:  # pragma: no cover
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
