"""The drift test on a system-level record file, its text report, and the stage a run ends with."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from stableins.conventions import ARCSEC, DEG_PER_HOUR
from stableins.errormodel import ErrorModel
from stableins.errors import InputError
from stableins.estimators.drift.holds import MIN_HOLD, find_holds
from stableins.estimators.drift.model import DriftDetails, estimate_drift
from stableins.estimators.result import FitResult

#: Columns the drift test reads.
DRIFT_COLUMNS = ("time", "angle_platform", "angle_inner", "angle_middle", "f_x", "f_y", "f_z", "temperature")
#: Longest record the drift test reads in one piece [samples] (a day at 10 Hz).
MAX_SAMPLES = 864_000


def drift_from_record(
    record: Any,
    prior_values: Mapping[str, float],
    *,
    prior_covariance: tuple[Sequence[str], NDArray[np.float64]] | None = None,
    error_model: ErrorModel | None = None,
    base: str = "auto",
) -> FitResult:
    """:func:`estimate_drift` on a system-level record (:class:`stableins.data.system.SystemRecord`), with its site metadata.

    Raises :class:`InputError` naming the file and field when the record is not a drift test (no two holds
    with the platform still, too long to read).
    """
    if record.n_samples > MAX_SAMPLES:
        raise InputError(
            f"{record.n_samples} samples: longer than a drift test", path=record.path, field="time",
            expected=f"at most {MAX_SAMPLES} samples (a drift-two-position or drift-three-position record)",
        )  # fmt: skip
    missing = [c for c in DRIFT_COLUMNS[:4] if c not in record.columns]
    if missing:
        raise InputError(
            f"no column {missing[0]!r}", path=record.path, field=missing[0], expected="a system-level record with the angle readings"
        )
    columns = record.read([c for c in DRIFT_COLUMNS if c in record.columns])
    site = record.metadata
    time = np.asarray(columns["time"], dtype=float)
    readings = np.stack([np.asarray(columns[f"angle_{g}"], dtype=float) for g in ("platform", "inner", "middle")], axis=1)
    holds = find_holds(time, readings)
    if len(holds) < 2 and base != "survey":
        raise InputError(
            f"{len(holds)} hold{'s' if len(holds) != 1 else ''} of at least {MIN_HOLD:g} s: the record has no index of the platform",
            path=record.path,
            field="angle_platform",
            expected="two or more holds separated by an index (a record of 'stableins run drift-two-position' or drift-three-position)",
        )
    return estimate_drift(
        columns,
        site,
        prior_values=prior_values,
        prior_covariance=prior_covariance,
        error_model=error_model,
        holds=holds,
        base=base,
        source=str(record.path),
    )


def drift_report(result: FitResult) -> str:
    """Text report of a drift test: the drift (°/h) with σ, the rank report, the nuisances, the accelerometer cross-check."""
    details = result.details
    assert isinstance(details, DriftDetails)
    lines = [f"gyro drift from {len(details.holds)} holds (platform frame):"]
    for term, value, sigma in zip(result.terms, result.values, result.sigma, strict=True):
        lines.append(f"  {term.id:<14} {value / DEG_PER_HOUR:+.6f} ± {sigma / DEG_PER_HOUR:.6f} °/h")
    lines.append("holds: " + ", ".join(f"{h.start:.0f}–{h.end:.0f} s" for h in details.holds))
    lines.append("what the data determine:")
    lines += [f"  {line}" for line in details.rank]
    if details.nuisance:
        lines.append("nuisances: " + ", ".join(f"{k} = {v:.3g} ± {s:.2g}" for k, (v, s) in details.nuisance.items()))
    rms = ", ".join(f"{r / ARCSEC:.3f}" for r in details.residual_rms)
    lines.append(f"residual rms of the platform attitude (x, y, z): {rms} arcsec")
    if details.biases:
        lines.append("accelerometer cross-check (hold means, compensated with the record):")
        lines += [f"  {b.describe()}" for b in details.biases]
    return "\n".join(lines)


def drift_stage(record: Any, prior: Any, say: Any) -> FitResult:
    """Return the fit a drift procedure's run ends with: :func:`drift_from_record` with the prior record, its report said.

    ``prior`` is the calibration record the INS ran with (``values()``, ``ids``, ``covariance``, ``error_model()``);
    ``say`` prints a text.
    """
    fit = drift_from_record(record, prior.values(), prior_covariance=(prior.ids, prior.covariance), error_model=prior.error_model())
    say(drift_report(fit))
    return fit
