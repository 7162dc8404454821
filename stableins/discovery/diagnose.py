r"""Model discovery on measured data against the calibration record in force: the library behind ``stableins diagnose``.

:func:`diagnose_data` fits the standard model (the zero offsets and the discovered effects the record carries
included) to the data, starting from the record's values, adds the effects asked for one step at a time, and returns
the residual diagnostics, the ranking of every candidate effect not in the model and the history of steps as a
:class:`DiagnoseResult`: its :attr:`~DiagnoseResult.report` is the typed document
(:class:`~stableins.discovery.diagnose_report.DiagnoseReport`), the rest the live session for text and figures.

* **Device data** (one or more :class:`~stableins.data.device.DeviceDataset`): the dwell means of the fine stage when
  present, else the coarse stage (:func:`stableins.discovery.problem.dwells_from_dataset`), weighted with the device stages' one noise
  model (the noise section of docs/discovery.md), chosen in this order: a whole noise model given; a datasheet's slow
  noise (:class:`SlowNoiseGiven`) with the white noise measured in the dwells; the record's noise model; else measured
  in all dwells as ``stableins calibrate device`` does.  The platform-drift candidates are ranked on the angle-reading
  slopes within the dwells (:mod:`stableins.discovery.drift`).
* **A system record** (:class:`~stableins.data.system.SystemRecord`): the bins of the record under the noise model the
  system stage measures in it, with the given model, datasheet or the record's model as its prior; the verdict, flags
  and Earth-rate harmonic tests hold for every noise model the record allows (:mod:`stableins.discovery.system`).

Example::

    from stableins.data.device import load_device
    from stableins.discovery.diagnose import DiagnoseOptions, diagnose_data
    from stableins.procedures.definition import device_layouts
    from stableins.records import CalibrationRecord

    record = CalibrationRecord.load("cal.json")
    data = [load_device("sim/device-coarse.csv"), load_device("sim/device-fine.h5")]
    result = diagnose_data(data, record, layouts=device_layouts(), options=DiagnoseOptions(add=("Kcc_xxy",)))
    print(result.text())
    result.report.to_json()            # the document of 'stableins diagnose --json'
    result.report.next_step            # what to do next, as data
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from enum import StrEnum
from typing import TYPE_CHECKING, Any, Protocol

from stableins.discovery.diagnose_report import (
    CandidateSummary,
    DiagnoseReport,
    DiagnoseStage,
    DriftEstimate,
    DriftSummary,
    SpectrumSummary,
    SystemFindings,
)
from stableins.discovery.signature import residual_signature
from stableins.errors import InputError
from stableins.estimators.result import Stage
from stableins.noise import NoiseModel

if TYPE_CHECKING:  # pragma: no cover
    import numpy as np
    from matplotlib.figure import Figure
    from numpy.typing import NDArray

    from stableins.data.device import DeviceDataset
    from stableins.data.system import SystemRecord
    from stableins.discovery.diagnostics import Diagnosis
    from stableins.discovery.history import Discovery
    from stableins.discovery.ranking import Ranking
    from stableins.discovery.system import SystemDiagnosis
    from stableins.errormodel import ErrorModel, Term
    from stableins.estimators.dwell import DwellSummary
    from stableins.estimators.layout import StageLayout


class NoiseOrigin(StrEnum):
    """Where the noise model of a diagnosis comes from (for a system record: the prior of the system stage's)."""

    #: A whole noise model was given (e.g. another record's, measured with ``stableins noise``).
    GIVEN = "given"
    #: A datasheet's bias instability and random walk (:class:`SlowNoiseGiven`); white noise measured in the data.
    DATASHEET = "datasheet"
    #: The calibration record's noise model.
    RECORD = "record"
    #: Measured in the data (nothing given, the record carries none).
    MEASURED = "measured"


@dataclass(frozen=True)
class SlowNoiseGiven:
    """The instrument's slow noise from a datasheet; the white noise is measured in the data.

    Attributes
    ----------
    bias_instability : float
        Bias instability ``B`` [m/s²] (Allan floor ``0.664 B``).
    random_walk : float
        Acceleration random walk ``K`` [m/s²/√s].
    provenance : str
        Where the numbers come from (the noise model's provenance).
    """

    bias_instability: float = 0.0
    random_walk: float = 0.0
    provenance: str = "bias instability and random walk from a datasheet"

    def __post_init__(self) -> None:
        for name in ("bias_instability", "random_walk"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise InputError(f"{value!r} is not a finite non-negative number", field=name, expected="a value in SI units")


@dataclass(frozen=True)
class DiagnoseOptions:
    """How to diagnose (checked on construction: :class:`~stableins.errors.InputError` naming the parameter).

    Attributes
    ----------
    add : tuple of str
        Library effects to add to the model, one step each, in order (each once, none already in the model).
    stage : DiagnoseStage or None
        Device data: the dwells of this stage (``coarse`` or ``fine``); None: fine when present, else coarse.
    alpha : float
        Family-wise false-alarm level of the flags, in (0, 1) (:func:`stableins.discovery.ranking.family_level`).  With
        the χ² verdict's upper 0.5 % (the two-sided 99 % range) the default 0.025 makes a clean session raise an alarm
        3 % of the time (docs/discovery.md "False alarms").
    noise : NoiseModel, SlowNoiseGiven or None
        The noise model to use, or a datasheet's slow noise; None: the record's, else measured in the data.
    bin_seconds : float
        System records: bin length [s] (widened for very long records, :data:`stableins.discovery.system.MAX_BINS`).
    """

    add: tuple[str, ...] = ()
    stage: DiagnoseStage | None = None
    alpha: float = 0.025
    noise: NoiseModel | SlowNoiseGiven | None = None
    bin_seconds: float = 60.0

    def __post_init__(self) -> None:
        from stableins.discovery.library import LIBRARY

        for effect in self.add:
            if effect not in LIBRARY:
                raise InputError(f"unknown effect {effect!r}", field="add", expected=f"one of {', '.join(LIBRARY.ids)}")
        if len(set(self.add)) != len(self.add):
            raise InputError("an effect is given twice", field="add")
        if self.stage is DiagnoseStage.SYSTEM:
            raise InputError("'system' is not a stage of device dwells", field="stage", expected="'coarse', 'fine' or None")
        if not 0.0 < self.alpha < 1.0:
            raise InputError(f"{self.alpha!r} is not a false-alarm level", field="alpha", expected="a probability in (0, 1)")
        if not (math.isfinite(self.bin_seconds) and self.bin_seconds > 0.0):
            raise InputError(f"{self.bin_seconds!r} is not a bin length", field="bin_seconds", expected="a positive number of seconds")


class RecordInForce(Protocol):
    """What a diagnosis reads of the calibration record in force (:class:`stableins.records.CalibrationRecord` is one)."""

    @property
    def ids(self) -> tuple[str, ...]:
        """Parameter ids, in the order of :attr:`covariance`."""
        ...

    @property
    def covariance(self) -> NDArray[np.float64]:
        """Covariance of the parameters [SI]."""
        ...

    @property
    def noise_model(self) -> NoiseModel | None:
        """The unit's noise model, if the record carries one."""
        ...

    def values(self) -> dict[str, float]:
        """``{id: value}`` [SI]."""
        ...


@dataclass(frozen=True)
class DiagnoseResult:
    """A diagnosis: the document (:attr:`report`) and the live analysis behind it (for text and figures).

    Attributes
    ----------
    report : DiagnoseReport
        What was found, as data (``to_json`` is the document of ``stableins diagnose --json``).
    session : Discovery
        The discovery session (its fits and history; for a system record, under the measured noise model).
    diagnosis : Diagnosis
        Residuals of the model against the noise floor.
    ranking : Ranking
        Every candidate effect not in the model, ranked and flagged.
    noise_origin : NoiseOrigin
        Where the noise model (system record: the stage's prior) comes from.
    drift : Ranking or None
        Device data: the platform-drift candidates (None: too few usable angle-reading slopes, or a system record).
    drift_notes : tuple of str
        Device data: dwells left out of the drift analysis, or why there is none.
    system : SystemDiagnosis or None
        A system record: the diagnosis over the noise models it allows, with the harmonic spectra.
    """

    report: DiagnoseReport
    session: Discovery
    diagnosis: Diagnosis
    ranking: Ranking
    noise_origin: NoiseOrigin
    drift: Ranking | None = None
    drift_notes: tuple[str, ...] = ()
    system: SystemDiagnosis | None = None

    def text(self, top: int = 10) -> str:
        """Return the diagnosis, the ranking (its ``top`` candidates), the drift candidates and the history of steps as text."""
        if self.system is not None:
            parts = [self.system.report(top=top)]
        else:
            parts = [self.diagnosis.report(), self.ranking.report(top=top)]
            if self.drift is not None:
                model = "\n".join(
                    f"  {m.id:<13} {m.value:+.6f} ± {m.sigma:.6f} {m.unit}" for m in DriftEstimate.from_fit(self.drift.result)
                )
                fit = self.drift.result
                ranked = (
                    "\nthe g-sensitivities not in it, ranked:\n" + self.drift.report(top=9)
                    if self.drift.candidates
                    else f"\nall nine g-sensitivities are in it (the record's gyro stage): χ²_ν = {fit.chi2_red:.3f} (ν = {fit.dof}), "
                    "nothing to rank"
                )
                parts.append("platform drift within dwells (angle-reading slopes), the drift model fitted:\n" + model + ranked)
        if self.report.signature is not None:
            parts.append(
                "outside the library: "
                + self.report.outside_text()
                + "\nthe residual's signature:\n"
                + "\n".join(f"  {line}" for line in self.report.signature.lines())
            )
        return "\n\n".join([*parts, self.session.history.report()])

    def figures(self) -> dict[str, Figure]:
        """Return the figures of the diagnosis by name, captioned with the ranking's next step.

        ``residuals``, ``orientation`` and ``history`` (:meth:`stableins.discovery.history.Discovery.figures`), and for a system record
        each output's residual at the Earth-rate harmonics (``spectrum_f_x`` ...).
        """
        from stableins.conventions import MICRO_G

        figures = self.session.figures(next_step=self.ranking.next_step())
        for name, spectrum in (self.system.spectra if self.system is not None else {}).items():
            figures[f"spectrum_{name}"] = spectrum.plot(unit="µg", scale=MICRO_G, name=name, next_step=self.ranking.next_step())
        return figures


def diagnose_data(
    data: Sequence[DeviceDataset] | SystemRecord,
    record: RecordInForce,
    *,
    options: DiagnoseOptions | None = None,
    layouts: Mapping[str, StageLayout] | None = None,
    record_name: str = "the calibration record",
    summaries: Sequence[Sequence[DwellSummary]] | None = None,
) -> DiagnoseResult:
    """Diagnose device data or a system record against the calibration record in force (module docstring).

    Parameters
    ----------
    data : sequence of DeviceDataset, or SystemRecord
        Device-level datasets (:func:`stableins.data.device.load_device`) or one system-level record
        (:func:`stableins.data.system.open_system_record`, validated by the caller).
    record : RecordInForce
        The calibration record in force: its values start the fit, its discovered effects are in the model.
    options : DiagnoseOptions, optional
        Effects to add, stage, false-alarm level, noise model, bin length (default: :class:`DiagnoseOptions`).
    layouts : mapping of str to StageLayout, optional
        Device data: each stage's positions, settle times and dwell checks
        (:func:`stableins.procedures.definition.device_layouts`); needed for device data.
    record_name : str
        How messages name the record (e.g. its file).
    summaries : sequence of sequence of DwellSummary, optional
        Device data: each dataset's dwell statistics (:func:`stableins.estimators.dwell.dwells_from_columns` of its
        columns with ``layouts`` and its setting) when the caller has them (the same numbers); None: made here.

    Returns
    -------
    DiagnoseResult
        The document (``report``) and the session behind it.

    Raises
    ------
    InputError
        An effect to add is already in the model (``field="add"``); the data do not hold enough usable dwells.
    """
    from stableins.data.system import SystemRecord

    options = options if options is not None else DiagnoseOptions()
    model = _model_in_force(record, options.add, record_name)
    if isinstance(data, SystemRecord):
        return _system(data, record, model, options)
    if layouts is None:
        raise TypeError("diagnose_data: device data need the stage layouts (procedures.definition.device_layouts())")
    return _device(list(data), record, model, options, layouts, summaries=summaries)


def _model_in_force(record: RecordInForce, add: Sequence[str], record_name: str) -> ErrorModel:
    """Return the standard model with the zero offsets and the record's discovered effects (the effects to add not in it)."""
    from stableins.discovery.library import record_terms
    from stableins.errormodel import GYRO_G_TERMS, ErrorModel

    gyro = {t.id for t in GYRO_G_TERMS}
    model = ErrorModel.standard(nonlinear=True, gimbals=True)
    # the record's gyro numbers are not accelerometer outputs: the drift section ranks all nine Dg_ab on the slopes
    model = model + [t for t in record_terms(record.ids) if t.id not in model and t.id not in gyro]
    for effect in add:
        if effect in model:
            raise InputError(f"effect {effect!r} is already in the model of {record_name}", field="add")
    return model


def _fit(session: Discovery, diagnosis: Diagnosis) -> dict[str, Any]:
    """Return the fields of a :class:`DiagnoseReport` that say how the model fits (device dwells and system bins alike)."""
    return {
        "chi2_red": session.result.chi2_red,
        "dof": session.result.dof,
        "expected_spread": diagnosis.spread,
        "p_value": diagnosis.p_value,
        "model": tuple(session.result.ids),
        "residual_rms": tuple(diagnosis.rms.tolist()),
        "noise_floor": tuple(diagnosis.noise_floor.tolist()),
        "history": tuple(session.history.steps),
    }


def _record_g_sensitivities(record: RecordInForce, *, exclude: Sequence[str] = ()) -> tuple[Term, ...]:
    """Return the ``Dg_ab`` the record determines (finite σ), less ``exclude``: the model in force of the drift section."""
    import numpy as np

    from stableins.errormodel import GYRO_G_TERMS

    ids = list(record.ids)
    sigma = dict(zip(ids, np.sqrt(np.abs(np.diag(np.asarray(record.covariance, dtype=float)))), strict=True)) if ids else {}
    return tuple(t for t in GYRO_G_TERMS if t.id not in exclude and np.isfinite(sigma.get(t.id, np.nan)) and sigma[t.id] > 0)


def _start(record: RecordInForce, model: ErrorModel) -> dict[str, float]:
    return {k: v for k, v in record.values().items() if k in model}


# ----------------------------------------------------------------------------- device dwells
def _device_noise(
    datasets: Sequence[DeviceDataset],
    given: NoiseModel | SlowNoiseGiven | None,
    default: NoiseModel | None,
    layouts: Mapping[str, Any],
    made: Sequence[Sequence[DwellSummary]] | None,
) -> tuple[NoiseModel, NoiseOrigin]:
    """Return the device stages' noise model: ``given``, a datasheet's slow noise, the record's, or measured in the dwells."""
    from stableins.estimators.device import noise_from_dwells, with_given_slow_noise
    from stableins.estimators.dwell import dwells_from_columns
    from stableins.estimators.setting import DeviceSetting

    if isinstance(given, NoiseModel):
        return given, NoiseOrigin.GIVEN
    if given is None and default is not None:
        return default, NoiseOrigin.RECORD
    if made is None:
        made = [
            dwells_from_columns(ds.columns, layouts=layouts, source=str(ds.path), setting=DeviceSetting.from_site(ds.metadata))
            for ds in datasets
        ]
    summaries = [s for per_dataset in made for s in per_dataset]
    if isinstance(given, SlowNoiseGiven):
        return with_given_slow_noise(summaries, given.bias_instability, given.random_walk, given.provenance), NoiseOrigin.DATASHEET
    return noise_from_dwells(summaries, source=", ".join(str(ds.path) for ds in datasets)), NoiseOrigin.MEASURED


def _device(  # noqa: PLR0913 - the data (and their dwell statistics when made), the record, its model, how, the layouts
    datasets: list[DeviceDataset],
    record: RecordInForce,
    model: ErrorModel,
    options: DiagnoseOptions,
    layouts: Mapping[str, StageLayout],
    *,
    summaries: Sequence[Sequence[DwellSummary]] | None,
) -> DiagnoseResult:
    """Discovery on the dwell means of device data (module docstring)."""
    from stableins.discovery.dwells import dwells_from_dataset
    from stableins.discovery.history import Discovery
    from stableins.discovery.problem import DwellProblem

    noise, origin = _device_noise(datasets, options.noise, record.noise_model, layouts, summaries)
    stage = None if options.stage is None else str(options.stage)
    dwells = dwells_from_dataset(datasets, layouts=layouts, stage=stage, noise=noise, summaries=summaries)
    problem = DwellProblem(dwells, stage=Stage.FINE_DWELLS if dwells.noise["stage"] == Stage.FINE else Stage.COARSE_DWELLS)
    session = Discovery(problem, model, alpha=options.alpha, start=_start(record, model))
    for effect in options.add:
        session.add(effect)
    # the record's gyro stage is part of the model in force: its determined g-sensitivities join the drift model (the
    # drift section ranks only the Dg_ab the record lacks; a record made with --no-gyro keeps all nine as candidates)
    session.drift_added += _record_g_sensitivities(record, exclude=options.add)
    diagnosis = session.diagnose()
    ranking = session.rank()
    drift = session.drift()
    drift_notes = tuple(getattr(session, "drift_notes", ()))
    report = DiagnoseReport(
        stage=DiagnoseStage(dwells.noise["stage"]),
        noise_model=dwells.noise.get("model"),
        **_fit(session, diagnosis),
        candidates=CandidateSummary.from_ranking(ranking),
        left_out=tuple(dwells.noise.get("left_out", [])),
        drift=None
        if drift is None
        else DriftSummary(
            drift.result.chi2_red,
            drift.result.dof,
            CandidateSummary.from_ranking(drift),
            left_out=drift_notes,
            model=DriftEstimate.from_fit(drift.result),
        ),
    )
    if report.outside_library:
        report = replace(report, signature=residual_signature(diagnosis, readings=dwells.readings))
    return DiagnoseResult(report, session, diagnosis, ranking, origin, drift=drift, drift_notes=drift_notes)


# ----------------------------------------------------------------------------- a system record
def _system_prior(given: NoiseModel | SlowNoiseGiven | None, default: NoiseModel | None) -> tuple[NoiseModel | None, NoiseOrigin]:
    """Return the noise model the system stage starts from: given, a datasheet's slow noise, the record's, or none."""
    if isinstance(given, SlowNoiseGiven):
        return NoiseModel.given(0.0, given.bias_instability, given.random_walk, provenance=given.provenance), NoiseOrigin.DATASHEET
    if given is not None:
        return given, NoiseOrigin.GIVEN
    if default is not None:
        return default, NoiseOrigin.RECORD
    return None, NoiseOrigin.MEASURED


def _system(opened: SystemRecord, record: RecordInForce, model: ErrorModel, options: DiagnoseOptions) -> DiagnoseResult:
    """Discovery on the bins of a system record under the noise model the system stage measures in it."""
    from stableins.discovery.library import record_terms
    from stableins.discovery.system import diagnose_system_record, measure_noise

    prior, origin = _system_prior(options.noise, record.noise_model)
    ids = record.ids
    covariance = {(a, b): float(record.covariance[i, j]) for i, a in enumerate(ids) for j, b in enumerate(ids)}
    values = record.values()
    measured = measure_noise(opened, values, covariance, prior, record_terms(ids))
    noise = measured.noise_model
    found = diagnose_system_record(
        opened,
        model,
        {k: v for k, v in values.items() if k in model},
        measured,
        bin_seconds=options.bin_seconds,
        alpha=options.alpha,
        add=options.add,
    )
    session, diagnosis = found.session, found.diagnosis
    flagged = {(name, k) for name, k, _ in found.flagged_harmonics}
    report = DiagnoseReport(
        stage=DiagnoseStage.SYSTEM,
        noise_model=noise,
        **_fit(session, diagnosis),
        candidates=CandidateSummary.from_ranking(found.ranking),
        spectra=tuple(
            SpectrumSummary.from_spectrum(name, sp, [(name, int(k)) in flagged for k in sp.harmonics]) for name, sp in found.spectra.items()
        ),
        system=SystemFindings(found.chi2_range, found.bin_seconds, tuple(found.notes)),
    )
    if report.outside_library:
        report = replace(report, signature=residual_signature(diagnosis, earth_harmonics=found.flagged_harmonics))
    return DiagnoseResult(report, session, diagnosis, found.ranking, origin, system=found)
