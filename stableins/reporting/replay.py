"""Residual evidence recomputed from the calibration's data files (when the record carries none).

A calibration record states parameters, not residuals.  Given the device-level data
files (already checked against the record's SHA-256), the report re-runs the
device-level stages exactly as ``stableins calibrate device`` does with its default
procedures, and shows their residuals, noise floor and χ²_ν.  The report says that the
evidence was recomputed, and with what.
"""

from __future__ import annotations

from collections.abc import Sequence
from os import PathLike
from typing import Any

from stableins.data.errors import InputError


def device_fits(paths: Sequence[str | PathLike[str]], noise: Any = None) -> tuple[list[Any], list[str]]:
    """FitResults of the coarse (last pass) and fine stages re-run on the device-level files among ``paths``.

    ``noise``: the record's noise model (:class:`stableins.noise.NoiseModel`), under which the
    stages are re-run; None: measured in the dwells, as ``stableins calibrate device`` does.

    Returns
    -------
    fits : list of FitResult
        Empty when no file is a device-level session.
    notes : list of str
        What was done, and which files were not device-level sessions.
    """
    from stableins.data.device import load_device
    from stableins.estimators.device import calibrate_device
    from stableins.estimators.dwell import dwells_from_columns
    from stableins.procedures.definition import load_procedure

    datasets, notes = [], []
    for path in paths:
        try:
            datasets.append(load_device(path))
        except InputError as error:
            notes.append(f"{path}: not used for device-level residuals ({error.message})")
    if not datasets:
        return [], notes
    procedures = {"coarse": load_procedure("device-coarse"), "fine": load_procedure("device-fine")}
    summaries = []
    for dataset in datasets:
        summaries += dwells_from_columns(dataset.columns, procedures=procedures, source=str(dataset.path))
    source = ", ".join(str(d.path) for d in datasets)
    calibration = calibrate_device(
        summaries,
        datasets[0].metadata,
        coarse_procedure=procedures["coarse"],
        fine_procedure=procedures["fine"],
        source=source,
        noise=noise,
    )
    fits = [calibration.coarse] + ([calibration.fine] if calibration.fine is not None else [])
    notes.insert(
        0,
        f"device-level residuals recomputed from {source} by re-running the coarse and fine stages "
        "(procedures device-coarse and device-fine, as 'stableins calibrate device' does)",
    )
    return fits, notes
