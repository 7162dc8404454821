"""Provenance of a record: the stage runs it rests on, the calibration (job) that produced it, its input files."""

from __future__ import annotations

import hashlib
import json
import math
import os
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from typing import TYPE_CHECKING, Any

from stableins.documents import JSONObject, JSONValue
from stableins.errors import InputError
from stableins.identifiers import utc_now
from stableins.records.parameters import Entry
from stableins.site import SiteMetadata

if TYPE_CHECKING:  # pragma: no cover
    from stableins.estimators.result import FitResult, InputSensitivity, Likelihood, StageSettings


def file_sha256(path: str | os.PathLike[str]) -> str:
    """Return the SHA-256 of a file's bytes, read in 1 MiB blocks.

    Raises
    ------
    InputError
        The file cannot be read.
    """
    digest = hashlib.sha256()
    try:
        with open(path, "rb") as handle:
            for block in iter(lambda: handle.read(1 << 20), b""):
                digest.update(block)
    except OSError as error:
        raise InputError(f"cannot read input file to hash it: {error.strerror}", path=path) from None
    return digest.hexdigest()


@dataclass(frozen=True)
class InputFile:
    """An input file by path and SHA-256 digest of its bytes."""

    path: str
    sha256: str

    @classmethod
    def of(cls, path: str | os.PathLike[str]) -> InputFile:
        """Return the input file at ``path`` with the digest of its bytes (:func:`file_sha256`)."""
        return cls(str(path), file_sha256(path))


@dataclass(frozen=True)
class RunInfo:
    """What describes a stage run besides its result: where its data came from, when, and what people entered.

    Attributes
    ----------
    procedure : str
        The procedure the data were taken with (name or file).
    inputs : tuple of path or InputFile
        The data files (a path is hashed when the run is made, :meth:`InputFile.of`).
    data_start, data_end : str
        ISO 8601 UTC times of the first and last sample ("" where the data do not say).
    sample_rate : float or None
        Sample rate of the data [Hz] (None: the site's, where a record update knows it).
    entries : tuple of Entry
        What people entered during the run (procedure prompts).
    environment : mapping
        What the data carry about the environment (:func:`temperature_summary`).
    created : str or None
        ISO 8601 UTC time of the run (None: now).
    name : str or None
        The run's name (None: the result's stage).
    """

    procedure: str = ""
    inputs: Sequence[str | os.PathLike[str] | InputFile] = ()
    data_start: str = ""
    data_end: str = ""
    sample_rate: float | None = None
    entries: Sequence[Entry] = ()
    environment: Mapping[str, JSONValue] = field(default_factory=dict)
    created: str | None = None
    name: str | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "inputs", tuple(self.inputs))
        object.__setattr__(self, "entries", tuple(self.entries))
        object.__setattr__(self, "environment", dict(self.environment))


#: A run described by its result alone: no procedure, data files, times or entries (the defaults of :class:`RunInfo`).
UNDESCRIBED = RunInfo()


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
    settings : StageSettings or None
        The options the stage ran with (the stage's own settings class: noise model, estimate K2, gyro drift ...);
        None: the record states none (a migrated record).
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
    settings: StageSettings | None = None
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
        run: RunInfo = UNDESCRIBED,
        fits: Sequence[FitResult] = (),
        settings: StageSettings | None = None,
    ) -> StageRun:
        """Return the run of the stage that produced ``result`` (its likelihood, settings, notes).

        Parameters
        ----------
        result : FitResult
            The stage's result.
        calibration : str
            Id of the calibration the run belongs to.
        run : RunInfo
            What describes the run: procedure, data files (hashed), data times, sample rate, entries, environment.
        fits : sequence of FitResult
            The fits whose residual evidence the run keeps (default: ``result``).
        settings : StageSettings, optional
            What the stage ran with (default: the result's).

        Returns
        -------
        StageRun
            The run, with id ``<name>-<8 hex>`` from a digest of name, creation time, calibration and input digests.
        """
        from stableins import __version__

        files = tuple(f if isinstance(f, InputFile) else InputFile.of(f) for f in run.inputs)
        created = run.created or utc_now()
        name = run.name or result.stage
        digest = hashlib.sha256(json.dumps([name, created, calibration, [f.sha256 for f in files]]).encode()).hexdigest()[:8]
        evidence = tuple(fit_evidence(f) for f in (tuple(fits) or (result,)))
        return cls(
            id=f"{name}-{digest}",
            name=name,
            calibration=calibration,
            procedure=run.procedure,
            software=f"stableins {__version__}",
            created=created,
            data_start=run.data_start,
            data_end=run.data_end,
            sample_rate=run.sample_rate,
            inputs=files,
            settings=settings if settings is not None else result.settings,
            entries=tuple(run.entries),
            environment=dict(run.environment),
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
        """Return a new calibration, id ``cal-<date>-<8 hex>``, created now by this stableins."""
        import uuid

        from stableins import __version__

        created = utc_now()
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


def fit_evidence(fit: FitResult) -> JSONObject:
    """Return a fit's residual evidence as stored in a stage run: residuals, 1σ, labels and its one χ², ν, χ²_ν.

    χ² is :attr:`FitResult.chi2` (whitened where the noise is correlated between observations); console,
    JSON and certificate all print this number.
    """
    from stableins.estimators.result import Stage

    def num(x: float) -> float | None:
        return float(x) if math.isfinite(x) else None

    return {
        "stage": fit.stage,
        "parameter_ids": list(fit.ids),
        "rank": int(fit.rank),
        "residual_labels": list(fit.residual_labels),
        "residuals": [float(x) for x in fit.residuals],
        "residual_sigma": [float(x) for x in fit.residual_sigma],
        "residual_unit": "m/s^2" if fit.stage != Stage.SYSTEM else "rad",
        "chi2": num(fit.chi2),
        "dof": int(fit.dof),
        "chi2_red": num(fit.chi2_red),
    }


def temperature_summary(values: Any) -> JSONObject:
    """Return ``{"temperature": {"mean", "min", "max", "unit": "degC"}}`` of the instrument temperature the data carry."""
    import numpy as np

    t = np.asarray(values, dtype=float)
    t = t[np.isfinite(t)]
    if not t.size:
        return {}
    return {"temperature": {"mean": float(t.mean()), "min": float(t.min()), "max": float(t.max()), "unit": "degC"}}


def data_times(metadata: SiteMetadata | None, first: float, last: float) -> tuple[str, str]:
    """Return ISO 8601 UTC times of the first and last sample, from the data's ``start_time`` (time 0) and session times [s]."""
    from datetime import timedelta

    if metadata is None or not metadata.start_time:
        return "", ""
    origin = datetime.fromisoformat(metadata.start_time.replace("Z", "+00:00"))
    if origin.tzinfo is None:
        origin = origin.replace(tzinfo=UTC)

    def at(t: float) -> str:
        return (origin + timedelta(seconds=float(t))).astimezone(UTC).replace(microsecond=0).isoformat()

    return at(first), at(last)
