"""What a calibration record holds: parameters, covariance, the calibration and every stage run it rests on.

:class:`RecordContent` holds the data, answers questions about them and is checked at construction
(:func:`check_record`: ids, stages, statuses, the covariance and the σ's; run on every record built or
read).  Building (:mod:`stableins.records.record`), the JSON file (:mod:`stableins.records.writer`,
:mod:`stableins.records.reader`) and what people see (:mod:`stableins.records.display`) take a content;
:class:`stableins.records.record.CalibrationRecord` is the content with those as its methods.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any, Self, TypeVar

from stableins.errors import InputError
from stableins.records.parameters import Entry, Parameter
from stableins.records.schema import RECORD_SCHEMA_VERSION, SYMMETRY_TOLERANCE
from stableins.records.stages import Calibration, InputFile, Provenance, StageRun
from stableins.site import SiteMetadata
from stableins.status import STATUSES, Determination, Status

if TYPE_CHECKING:  # pragma: no cover
    import numpy as np
    from numpy.typing import NDArray

    from stableins.discovery.history import ModelHistory
    from stableins.errormodel import ErrorModel
    from stableins.noise import NoiseModel


@dataclass(frozen=True)
class RecordContent:
    """What a calibration record holds, checked at construction (:func:`check_record`), and the questions it answers.

    The parameters, covariance, the calibration and every stage run it rests on, site.  The covariance rows
    follow :attr:`ids` (the parameter order).  :class:`stableins.records.CalibrationRecord` is this content
    with how it is built, written, read and shown.
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

    def with_entries(self, entries: Iterable[Entry]) -> Self:
        """Return the same record with fields added to its calibration's entries (a later key replaces an earlier one)."""
        merged = {e.key: e for e in self.calibration.entries}
        merged.update({e.key: e for e in entries})
        return replace(self, calibration=replace(self.calibration, entries=tuple(merged.values())))


#: The record type a builder or the reader makes (:class:`stableins.records.CalibrationRecord`, given by its caller).
_RecordT = TypeVar("_RecordT", bound=RecordContent)


def check_record(record: RecordContent, path: str | None) -> None:
    """Check a record's consistency.

    Parameters
    ----------
    record : RecordContent
        The record.
    path : str or None
        The file it was read from, named by the error.

    Raises
    ------
    InputError
        Naming the key: an empty serial number, a parameter twice, a stage the record does not hold, a
        covariance of the wrong shape, not symmetric, not positive semi-definite or disagreeing with the σ's,
        a bad status, a value that is not finite, discovered effects that are not parameters.
    """
    _check_identity(record, path)
    _check_parameters(record, path)
    _check_covariance(record, path)


def _fail(path: str | None, message: str, key: str, expected: str | None = None) -> InputError:
    return InputError(message, path=path, field=key, expected=expected)


def _check_identity(record: RecordContent, path: str | None) -> None:
    """Check the serial number, unique ids, the stages named, the covariance's shape and the discovery history's effects."""
    if not record.serial_number:
        raise _fail(path, "empty serial number", "serial_number", "a non-empty string")
    ids = record.ids
    if len(set(ids)) != len(ids):
        duplicate = next(i for i in ids if ids.count(i) > 1)
        raise _fail(path, f"parameter {duplicate!r} appears twice", "parameters", "each id once")
    stage_ids = {s.id for s in record.stages}
    for k, p in enumerate(record.parameters):
        for d in p.determined_by:
            if d.stage not in stage_ids:
                raise _fail(path, f"{p.id!r} names stage {d.stage!r}, which the record does not hold", f"parameters[{k}].determined_by")
    n = len(ids)
    c = record.covariance
    if c.shape != (n, n):
        raise _fail(path, f"shape {c.shape}", "covariance", f"({n}, {n}) following the parameters")
    if record.discovery is not None:
        missing = [e for e in record.discovery.effects if e not in ids]
        if missing:
            raise _fail(
                path,
                f"the discovery history keeps {missing}, which are not parameters of the record",
                "discovery",
                "kept effects among the parameters",
            )


def _known(record: RecordContent) -> Any:
    """Return the mask of the parameters that are not unidentifiable."""
    import numpy as np

    return np.array([p.status is not Status.UNIDENTIFIABLE for p in record.parameters], dtype=bool)


def _check_parameters(record: RecordContent, path: str | None) -> None:
    """Check statuses, finite values, and finite covariance rows and σ of every parameter that is not unidentifiable."""
    import numpy as np

    known = _known(record)
    c = record.covariance
    for k, p in enumerate(record.parameters):
        if p.status not in STATUSES:
            raise _fail(path, f"bad status {p.status!r}", f"parameters[{k}].status", " or ".join(STATUSES))
        if not math.isfinite(p.value):
            raise _fail(path, "value is not finite", f"parameters[{k}].value", "a finite number")
        if known[k] and not (np.isfinite(c[k, known]).all() and math.isfinite(p.sigma)):
            raise _fail(
                path,
                f"covariance of {p.id!r} ({p.status}) is not finite",
                "covariance",
                "finite entries except for unidentifiable parameters",
            )


def _check_covariance(record: RecordContent, path: str | None) -> None:
    """Check the known block of the covariance: symmetric, positive semi-definite, its diagonal the σ's squared."""
    import numpy as np

    known = _known(record)
    ids = record.ids
    block = record.covariance[np.ix_(known, known)]
    if not block.size:
        return
    scale = float(np.abs(block).max()) or 1.0
    asymmetry = float(np.abs(block - block.T).max())
    if asymmetry > SYMMETRY_TOLERANCE * scale:
        i, j = np.unravel_index(int(np.argmax(np.abs(block - block.T))), block.shape)
        a, b = np.array(ids)[known][[i, j]]
        raise _fail(
            path, f"covariance is not symmetric: ({a}, {b}) differs from ({b}, {a}) by {asymmetry:.3g}", "covariance", "a symmetric matrix"
        )
    d = np.sqrt(np.clip(np.diag(block), 0.0, None))
    with np.errstate(divide="ignore", invalid="ignore"):
        correlation = np.where(np.outer(d, d) > 0, block / np.outer(d, d), 0.0)
    if (np.diag(block) < 0).any() or np.linalg.eigvalsh((correlation + correlation.T) / 2).min() < -1e-8:
        raise _fail(path, "covariance is not positive semi-definite", "covariance", "a valid covariance matrix")
    sigma = np.array([p.sigma for p in record.parameters])[known]
    bad = ~np.isclose(sigma, d, rtol=1e-6, atol=0.0)
    if bad.any():
        k = int(np.flatnonzero(known)[int(np.argmax(bad))])
        raise _fail(
            path,
            f"sigma {record.parameters[k].sigma!r} of {ids[k]!r} disagrees with the covariance diagonal",
            f"parameters[{k}].sigma",
            f"sqrt of the covariance diagonal = {d[int(np.argmax(bad))]!r}",
        )
