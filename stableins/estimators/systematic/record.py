"""The systematic stage on a system-level record file and a calibration record (``calibrate system --systematic``)."""

from __future__ import annotations

from typing import Any

import numpy as np

from stableins.data.chunks import ChunkSource, source_columns, source_path
from stableins.errors import InputError
from stableins.estimators.systematic.observations import RECORD_COLUMNS
from stableins.estimators.systematic.passes import Prior, SystematicOptions, run_passes
from stableins.estimators.systematic.result import SystematicCalibration, build_result
from stableins.noise import NoiseModel
from stableins.site import SiteMetadata


def systematic_calibration(
    source: ChunkSource, site: SiteMetadata, prior: Prior, options: SystematicOptions | None = None
) -> SystematicCalibration:
    """Run the systematic stage (docs/systematic-calibration.md) on a streamed record.

    Parameters
    ----------
    source : ChunkSource
        A system-level record of an indexed platform (``stableins run system-indexed``): time, the three gimbal
        readings, the INS velocities and attitude (:data:`~stableins.estimators.systematic.observations.RECORD_COLUMNS`).
    site : SiteMetadata
        Latitude, gravity, surveyed base, gimbal senses, damping loop, sample rate.
    prior : Prior
        The record the INS compensated with: values, covariance, error model, noise model.
    options : SystematicOptions, optional

    Returns
    -------
    SystematicCalibration
    """
    options = options or SystematicOptions()
    names = source_columns(source)
    missing = [c for c in RECORD_COLUMNS if names and c not in names]
    if missing:
        raise InputError(f"no column {missing[0]!r}", path=source_path(source), field=missing[0], expected="a system-level record")
    if site.damping is None or "zeta" not in site.damping:
        raise InputError(
            "no damping loop in the metadata", path=source_path(source), field="damping.zeta", expected="the INS's damping ratio"
        )
    _check_noise(prior.noise_model, source_path(source))
    return build_result(run_passes(source, site, prior, options), prior, options.step)


def _check_noise(noise: NoiseModel, path: str) -> None:
    if not np.all(noise.values("white") > 0):
        raise InputError(
            "the prior record carries no accelerometer white noise", path=path, field="noise_model",
            expected="a prior record with the unit's noise model (device-level calibration or stableins noise)",
        )  # fmt: skip


def prior_from_record(record: Any) -> Prior:
    """:class:`Prior` of a :class:`stableins.records.CalibrationRecord` (its values, covariance, error and noise model)."""
    noise = record.noise_model if record.noise_model is not None else NoiseModel.unknown()
    return Prior(dict(record.values()), tuple(record.ids), np.asarray(record.covariance, dtype=float), record.error_model(), noise)


def systematic_stage(record: Any, prior: Any, say: Any) -> Any:
    """Return the fit a ``system-indexed`` run ends with (its report said): the stage on the record with the prior record."""
    outcome = systematic_calibration(record, record.metadata, prior_from_record(prior))
    say(outcome.report())
    return outcome.fit
