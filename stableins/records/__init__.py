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

The package's public API is the names below (``from stableins.records import CalibrationRecord``);
its modules, by concern: :mod:`~stableins.records.schema` (format, version, migration),
:mod:`~stableins.records.parameters` (parameters and entries), :mod:`~stableins.records.stages`
(stage runs, calibrations, provenance), :mod:`~stableins.records.record` (the record, its first records and
Bayesian updates), :mod:`~stableins.records.writer`
and :mod:`~stableins.records.reader` (the JSON file), :mod:`~stableins.records.check` (consistency),
:mod:`~stableins.records.display` (tables for people).
"""

from stableins.records.parameters import DeterminedBy, Entry, Parameter, parse_entries
from stableins.records.record import CalibrationRecord
from stableins.records.schema import CALIBRATION_FIELDS, RECORD_FORMAT, RECORD_SCHEMA_VERSION, migrate_v1
from stableins.records.stages import (
    Calibration,
    InputFile,
    PriorReference,
    Provenance,
    RunInfo,
    StageRun,
    data_times,
    file_sha256,
    fit_evidence,
    temperature_summary,
)

__all__ = [
    "CALIBRATION_FIELDS",
    "RECORD_FORMAT",
    "RECORD_SCHEMA_VERSION",
    "Calibration",
    "CalibrationRecord",
    "DeterminedBy",
    "Entry",
    "InputFile",
    "Parameter",
    "PriorReference",
    "Provenance",
    "RunInfo",
    "StageRun",
    "data_times",
    "file_sha256",
    "fit_evidence",
    "migrate_v1",
    "parse_entries",
    "temperature_summary",
]
