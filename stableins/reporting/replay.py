"""Residual evidence recomputed from the calibration's data files (when the record stores none).

A record written by this version stores the residual evidence of every fit in its stage runs.
A record migrated from schema version 1 does not: given its device-level data files (already
checked against the record's SHA-256), the report re-runs the device-level stages with the
settings the record's stage run states (procedures, noise model, coarse nonlinearity)
— or, when the record states none, with the defaults of ``stableins calibrate device`` — and
says which.
"""

from __future__ import annotations

from collections.abc import Sequence
from os import PathLike
from typing import TYPE_CHECKING

from stableins.errors import InputError
from stableins.estimators.device_settings import DeviceSessionSettings

if TYPE_CHECKING:  # pragma: no cover
    from stableins.errormodel import Term
    from stableins.estimators.result import FitResult
    from stableins.noise import NoiseModel


def device_fits(
    paths: Sequence[str | PathLike[str]],
    settings: DeviceSessionSettings | None = None,
    *,
    noise: NoiseModel | None = None,
    effects: Sequence[Term] = (),
) -> tuple[list[FitResult], list[str]]:
    """FitResults of the coarse and fine stages (and their fusion) re-run on the device-level files among ``paths``.

    Parameters
    ----------
    paths : sequence of paths
        Data files given to the report.
    settings : DeviceSessionSettings, optional
        The settings the record's device stage run states (procedures, noise model, coarse nonlinearity, missing
        positions); None: the defaults of ``stableins calibrate device``.
    noise : NoiseModel, optional
        Without ``settings``: the record's noise model (None: the defaults measure one in the dwells).
    effects : sequence of Term
        The discovered (additive) terms of the record's model: the stages estimate them with the
        standard parameters, as ``stableins calibrate device --add`` did.

    Returns
    -------
    fits : list of FitResult
        Empty when no file is a device-level session.
    notes : list of str
        What was done and with which settings, and which files were not device-level sessions.
    """
    from stableins.data.device import load_device
    from stableins.estimators.device import calibrate_device
    from stableins.estimators.dwell import dwells_from_columns
    from stableins.estimators.setting import DeviceSetting
    from stableins.procedures.definition import load_procedure

    datasets, notes = [], []
    for path in paths:
        try:
            datasets.append(load_device(path))
        except InputError as error:
            notes.append(f"{path}: not used for device-level residuals ({error.message})")
    if not datasets:
        return [], notes
    stated = settings if settings is not None else DeviceSessionSettings(noise_model=noise)
    names = dict(zip(("coarse", "fine"), stated.procedures, strict=True))
    layouts = {stage: load_procedure(name).layout for stage, name in names.items()}
    summaries = []
    for dataset in datasets:
        setting = DeviceSetting.from_site(dataset.metadata)
        summaries += dwells_from_columns(dataset.columns, layouts=layouts, source=str(dataset.path), setting=setting)
    source = ", ".join(str(d.path) for d in datasets)
    calibration = calibrate_device(
        summaries,
        datasets[0].metadata,
        layouts=layouts,
        allow_missing=stated.allow_missing,
        noise=stated.noise_model,
        coarse_nonlinear=stated.coarse_nonlinear,
        extra_terms=tuple(effects),
        source=source,
    )
    fits = [calibration.coarse] + [f for f in (calibration.fine, calibration.fused) if f is not None]
    if settings is not None:
        how = "with the settings the record states (procedures, noise model, coarse nonlinearity)"
    elif noise is not None:
        how = "with the record's noise model and otherwise the defaults of 'stableins calibrate device'"
    else:
        how = "with the defaults of 'stableins calibrate device' (the record states no settings)"
    how += f" and the record's discovered effects {', '.join(t.id for t in effects)}" if effects else ""
    notes.insert(0, f"device-level residuals recomputed from {source} by re-running the coarse and fine stages {how}")
    return fits, notes
