"""The JSON documents of ``stableins serve``'s API as pydantic models: what ``/api/openapi.json`` describes.

Values are in engineering units where a parameter has one (µg, ppm, arcsec, µg/g²: the unit is named beside them);
significances are z = difference / σ; times are ISO 8601 in UTC.
"""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field


class Drifting(BaseModel):
    """A parameter whose drift per year reaches 3σ."""

    id: str
    significance: float = Field(description="z = drift / σ of the drift, per year")


class FleetUnit(BaseModel):
    """One unit of the fleet."""

    serial: str
    records: int = Field(description="records filed")
    in_force: str | None = Field(description="file of the record in force (None: none yet)")
    in_force_sha256: str | None
    procedure: str = Field(description="procedure of the record in force")
    calibrated: str | None = Field(description="time the record in force is valid from")
    due: str | None = Field(description="due date: calibrated + the interval of the policy")
    days_left: float | None = Field(description="days to the due date (negative: overdue)")
    overdue: bool
    conformity: str | None = Field(description="the verdict the certificate of the record in force states (None: no certificate found)")
    drifting: list[Drifting]


class Fleet(BaseModel):
    """The fleet: every unit, overdue first."""

    store: str
    units: int
    overdue: int
    drifting: int
    interval_source: str = Field(description="where the calibration intervals come from (a policy file or the default)")
    shown: list[FleetUnit] = Field(description="the units the filters keep, overdue first, then by due date")


class Document(BaseModel):
    """A certificate or technical report of a record, found under the run root."""

    kind: str
    title: str
    sha256: str = Field(description="SHA-256 of the PDF: /units/{serial}/documents/{sha256} downloads it")
    verdict: str | None
    name: str


class RecordEntry(BaseModel):
    """One record of a unit's history."""

    file: str
    sha256: str = Field(description="/units/{serial}/records/{sha256} downloads it, verified")
    valid_from: str
    procedure: str
    stages: list[str]
    prior: str = Field(description="SHA-256 of the record it updates ('' for an independent calibration)")
    in_force: bool
    documents: list[Document]


class ParameterChange(BaseModel):
    """One parameter's change between two consecutive records (stableins.history.compare)."""

    id: str
    unit: str
    old: float | None
    new: float | None
    difference: float | None
    sigma_difference: float | None
    significance: float | None = Field(description="z = change / σ of the change")
    significant: bool = Field(description="|z| ≥ 3")


class RecordChange(BaseModel):
    """The changes from one record to the next."""

    model_config = ConfigDict(populate_by_name=True)  # built with from_=..., serialized as "from"

    from_: str = Field(validation_alias="from", serialization_alias="from")
    to: str
    valid_from: str
    relation: str = Field(description="independent, or descendant (the new record updates the old one)")
    parameters: list[ParameterChange]
    significant: list[str]
    not_compared: list[str]


class TrendSeries(BaseModel):
    """One parameter's trend: each record's data-only estimate with σ, the record's value, the weighted line."""

    id: str
    unit: str
    times: list[str]
    values: list[float | None]
    sigmas: list[float | None]
    record_values: list[float | None]
    record_sigmas: list[float | None]
    line: list[float | None] = Field(description="the fitted straight line at each time (empty when no drift is stated)")
    slope_per_year: float | None
    slope_sigma: float | None
    significance: float | None = Field(description="z = drift / σ of the drift")
    chi2_red_constant: float | None
    too_short: bool = Field(description="the records span less than 30 days: no drift per year is stated")


class Unit(BaseModel):
    """A unit's history."""

    serial: str
    store: str
    in_force: str | None
    due: str | None
    interval_source: str
    change_threshold: float
    drift_threshold: float
    records: list[RecordEntry]
    changes: list[RecordChange]
    trends: list[TrendSeries]


class QuickLookDocument(BaseModel):
    """The running quick look at a system-level static record (stableins.procedures.quicklook)."""

    text: str
    hours: float
    amplitude: list[float] | None = Field(description="Earth-rate amplitude of the north and east velocity so far [m/s]")
    residual_rms: list[float] | None = Field(description="rms of their residuals [m/s]")


class RunProgress(BaseModel):
    """One run's progress, read from its journal."""

    model_config = ConfigDict(populate_by_name=True)  # built with pass_=..., serialized as "pass"

    name: str = Field(description="the run directory, relative to the run root")
    unit: str
    procedure: str
    state: str = Field(description="running, finished, stopped or complete")
    reason: str | None
    started: str
    updated: str = Field(description="last change of the journal")
    journal_records: int
    step: int | None
    steps: int
    step_name: str | None
    stage: str | None
    phase: str | None
    position: int | None
    pass_: int | None = Field(validation_alias="pass", serialization_alias="pass")
    dwell_seconds: float = Field(description="seconds of samples at the position so far")
    dwell_planned: float = Field(description="settle + dwell the plan gives the position")
    samples: int
    remaining_seconds: float | None = Field(description="platform time the plan still needs")
    remaining_is_lower_bound: bool
    quicklook: QuickLookDocument | None
    error: str | None


class Runs(BaseModel):
    """Every run under the run root."""

    run_root: str | None
    runs: list[RunProgress]
