"""Consistency of a record (run on every record built or read): ids, stages, statuses, the covariance and the σ's."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

from stableins.errors import InputError
from stableins.records.schema import SYMMETRY_TOLERANCE
from stableins.status import STATUSES, Status

if TYPE_CHECKING:  # pragma: no cover
    from stableins.records.record import CalibrationRecord


def check_record(record: CalibrationRecord, path: str | None) -> None:
    """Check a record's consistency.

    Parameters
    ----------
    record : CalibrationRecord
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


def _check_identity(record: CalibrationRecord, path: str | None) -> None:
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


def _known(record: CalibrationRecord) -> Any:
    """Return the mask of the parameters that are not unidentifiable."""
    import numpy as np

    return np.array([p.status is not Status.UNIDENTIFIABLE for p in record.parameters], dtype=bool)


def _check_parameters(record: CalibrationRecord, path: str | None) -> None:
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


def _check_covariance(record: CalibrationRecord, path: str | None) -> None:
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
