"""The lever-arm stage on a device-level data set that keeps its slews, its text report, and the stage a run ends with."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
from numpy.typing import NDArray

from stableins.conventions import MICRO_G, MILLIMETRE, MILLISECOND
from stableins.errors import InputError
from stableins.estimators.lever.model import LeverDetails, LeverOptions, estimate_lever
from stableins.estimators.result import FitResult
from stableins.terms import TIME_ASYNC_TERM

#: Stage of the device-level data set that keeps its slews (``stableins run device-rotating``).
ROTATING_STAGE = "rotating"


def rotating_columns(columns: Mapping[str, NDArray[Any]], source: str) -> dict[str, NDArray[Any]]:
    """Return the rows of a device data set's rotating stage (all of them when it has no stage column), in time order.

    Raises :class:`InputError` naming ``source`` when the data set holds no rotating stage.
    """
    stage = np.asarray(columns["stage"]).astype(str) if "stage" in columns else None
    if stage is None:
        return dict(columns)
    keep = stage == ROTATING_STAGE
    if not np.any(keep):
        found = ", ".join(sorted(set(stage.tolist()))) or "none"
        raise InputError(
            f"no rows of the rotating stage (stages found: {found})", path=source, field="stage",
            expected="a device data set that keeps its slews: the device.h5 of 'stableins run device-rotating'",
        )  # fmt: skip
    return {k: np.asarray(v)[keep] for k, v in columns.items()}


def lever_from_dataset(dataset: Any, prior: Any, options: LeverOptions | None = None) -> FitResult:
    """:func:`estimate_lever` on a device data set (:class:`stableins.data.device.DeviceDataset`) with the prior record.

    ``prior`` is the unit's calibration record (``values()``, ``error_model()``, ``noise_model``).
    """
    source = str(dataset.path or "data")
    columns = rotating_columns(dataset.columns, source)
    return estimate_lever(
        columns, dataset.metadata, prior.values(), error_model=prior.error_model(), noise_model=prior.noise_model, options=options,
        source=source,
    )  # fmt: skip


def lever_report(result: FitResult) -> str:
    """Text report: the lever arms (mm) and ``τ`` (ms) with 1σ, the flags, the fit's χ²_ν and the measured noise."""
    details = result.details
    assert isinstance(details, LeverDetails)
    lines = [f"lever arms and time asynchrony from {len(details.slews)} slews ({details.windows} window means):"]
    for term, value, sigma in zip(result.terms, result.values, result.sigma, strict=True):
        scale, unit = (MILLISECOND, "ms") if term.id == TIME_ASYNC_TERM.id else (MILLIMETRE, "mm")
        lines.append(f"  {term.id:<10} {value / scale:+9.4f} ± {sigma / scale:.4f} {unit}")
    lines += [f"  {flag.describe()}" for flag in details.flags]
    if details.correlation:
        lines.append(f"  largest |correlation| of t_async with a lever arm: {details.correlation:.3f}")
    white = ", ".join(f"{w / MICRO_G:.3g}" for w in details.white)
    lines.append(f"fit: χ²_ν = {result.chi2_red:.3f} (ν = {result.dof}); measured noise of a window mean (x, y, z): {white} µg")
    lines += [f"note: {n}" for n in result.notes if n.startswith("χ²_ν")]
    return "\n".join(lines)


def lever_stage(columns: Mapping[str, NDArray[Any]], metadata: Any, prior: Any, say: Callable[[str], None]) -> FitResult:
    """Return the fit a rotating procedure's run ends with (Cai's three arms and ``τ``), its report said."""
    fit = estimate_lever(
        rotating_columns(columns, "run"), metadata, prior.values(), error_model=prior.error_model(), noise_model=prior.noise_model,
        source="run",
    )  # fmt: skip
    say(lever_report(fit))
    return fit
