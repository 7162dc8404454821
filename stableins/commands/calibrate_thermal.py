"""``stableins calibrate thermal DATA --prior CAL.json --out CAL2.json``: the temperature sensitivities from a thermal test.

DATA is the device-level data of ``device-thermal`` (each axis up and down, repeated while the temperature is cycled),
or a run directory holding its ``device.h5``.  The dwell means give ``Kt_bias_a`` and ``Kt_sf_a`` with their σ
(:func:`stableins.estimators.thermal_sensitivity.estimate_thermal`, docs/thermal-calibration.md); the prior record is
updated with them (a Bayesian update) and written to ``--out`` atomically.  The system stage takes them as its thermal
prior (docs/system-calibration.md §1b).
"""

from __future__ import annotations

import argparse
from typing import Any

from stableins.commands import add_entries_option, add_new_calibration_option, check_same_unit, run_data_file, update_prior


def configure(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``stableins calibrate thermal``."""
    from stableins.commands.arguments import output_file

    parser.add_argument("data", metavar="DATA", help="device-level data of a thermal test (device-thermal), or its run directory")
    parser.add_argument("--prior", required=True, metavar="CAL.json", help="calibration record of the unit to update")
    parser.add_argument("--out", required=True, type=output_file, metavar="CAL2.json", help="updated calibration record to write")
    add_new_calibration_option(parser)
    add_entries_option(parser)


def run(args: Any) -> int:
    """Estimate the sensitivities, update the prior record, write it, print the report."""
    import numpy as np

    from stableins.conventions import MICRO_G, PPM
    from stableins.data.device import load_device
    from stableins.discovery.library import LIBRARY
    from stableins.estimators.thermal_sensitivity import THERMAL_TERM_IDS, estimate_thermal
    from stableins.output import emit
    from stableins.procedures.rundir import DATASET_NAME
    from stableins.records import CalibrationRecord

    prior = CalibrationRecord.load(args.prior)
    source = run_data_file(args.data, DATASET_NAME, missing="the run directory has no device-level data", expected="a device-thermal run")
    dataset = load_device(source)
    check_same_unit(dataset.metadata, prior, args.prior)
    terms = tuple(LIBRARY[i].term for i in THERMAL_TERM_IDS)
    fit = estimate_thermal(dataset.dwells(), terms, gravity=dataset.metadata.gravity, noise_model=prior.noise_model, path=str(source))
    time = np.asarray(dataset.columns["time"], dtype=float)
    updated = update_prior(args, prior, fit, data=(source, dataset.metadata, (time[0], time[-1])), procedure="device-thermal")
    scale = [MICRO_G] * 3 + [PPM] * 3
    units = ["ug/K"] * 3 + ["ppm/K"] * 3
    data = {
        "data": str(source),
        "prior": args.prior,
        "out": str(args.out),
        "sensitivities": {
            t.id: {"value": float(v) / s, "sigma": float(e) / s, "unit": u}
            for t, v, e, s, u in zip(fit.terms, fit.values, fit.sigma, scale, units, strict=True)
        },
        "settings": {} if fit.settings is None else fit.settings.to_document(),
        "notes": list(fit.notes),
    }
    text = "\n".join(
        [
            "thermal test (device level)",
            *(f"  {n}" for n in fit.notes),
            "",
            updated.report(),
            "",
            f"updated calibration written to {args.out}",
        ]
    )
    emit(args, data, text=text)
    return 0
