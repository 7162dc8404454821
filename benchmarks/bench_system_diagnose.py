"""False alarms and detection power of ``diagnose`` on system-level records (docs/discovery.md "System records").

For each seed the truth simulator writes one sidereal day at 1 Hz (an HDF5 system record, as ``stableins simulate
system`` does) of a clean instrument, with

* ``white``: white noise only at the quartz level (46 µg/√Hz) and the angle noise;
* ``quartz``: the simulator's default quartz noise (bias instability 2 µg, random walk 1e-7 m/s²/√s).

and runs what ``stableins diagnose SYSTEM.h5 --record CAL.json`` runs: the system stage measures the noise model in the
record (:func:`stableins.discovery.system.measure_noise`), then discovery under that model and its limits
(:func:`stableins.discovery.system.diagnose_system_record`).  A false alarm is any of: the verdict "NOT consistent with
the noise floor", a flagged candidate (family-wise α = 5 %), a flagged Earth-rate harmonic (family-wise α = 5 %).
Printed per world: each rate and the rate of any alarm (target ≤ 5 %, with its binomial 1σ), χ²_ν under the measured
model (mean, sd, against 1 ± sqrt(2/ν)), and, for comparison, the same records under a white floor only (no slow
noise: what diagnose did before).

Detection power (``--power``): a hidden library effect in the quartz world; printed: the fraction of seeds in which it is
flagged and ranked first, and its signal ``√λ = |γ|/σ_γ`` (the size over its 1σ under the upper-limit noise model).

Usage::

    python benchmarks/bench_system_diagnose.py [--seeds 24] [--first 1] [--worlds white quartz] [--power]
"""

from __future__ import annotations

import argparse
import math
import tempfile
import time
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np

from stableins.conventions import ARCSEC, SIDEREAL_DAY
from stableins.data.system import SystemRecordWriter, open_system_record
from stableins.discovery.library import LIBRARY
from stableins.discovery.system import diagnose_system_record, measure_noise
from stableins.errormodel import ErrorModel
from stableins.simulator.noise import NoiseSettings
from stableins.simulator.system import system_record_chunks
from stableins.simulator.truth import SimulatedSite, Truth

WORLDS = {"white": NoiseSettings(velocity_random_walk=4.5e-4, angle_noise=0.2 * ARCSEC), "quartz": NoiseSettings.quartz()}
#: Hidden effects for the power check: [SI] values.
HIDDEN = {"K3_x": 100 * LIBRARY["K3_x"].term.scale, "Kcc_xxy": 30 * LIBRARY["Kcc_xxy"].term.scale}


def write_day(directory: Path, seed: int, noise: NoiseSettings, effects: dict[str, float] | None = None):
    truth = Truth.draw(seed, site=SimulatedSite(sample_rate=1.0), noise=noise, effects=effects or {})
    path = directory / f"system-{seed}.h5"
    with SystemRecordWriter(path, replace(truth.site, sample_rate=1.0), chunk_samples=65536) as writer:
        for chunk in system_record_chunks(truth, SIDEREAL_DAY, 1.0, seed, chunk_samples=65536):
            writer.append(chunk)
    return open_system_record(path), truth


def diagnose(record, truth, *, white_only: bool = False):
    model = ErrorModel.standard(nonlinear=True, gimbals=True)
    start = {k: v for k, v in truth.installed_calibration.items() if k in model}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        measured = measure_noise(record, dict(truth.installed_calibration), None, None)
        if white_only:
            noise = measured.noise_model
            white = replace(noise, axes=tuple(replace(a, bias_instability=_exact(0.0), random_walk=_exact(0.0)) for a in noise.axes))
            measured = replace(measured, noise_model=white)
        return diagnose_system_record(record, model, start, measured)


def _exact(value: float):
    from stableins.noise import NoiseTerm

    return NoiseTerm.exact(value)


def false_alarms(world: str, seeds: range) -> None:
    start = time.perf_counter()
    rows, white_rows, chi2 = [], [], []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in seeds:
            record, truth = write_day(Path(tmp), seed, WORLDS[world])
            for target, white in ((rows, False), (white_rows, True)):
                result = diagnose(record, truth, white_only=white)
                target.append((not result.diagnosis.consistent, bool(result.ranking.flagged), bool(result.flagged_harmonics), result.alarm))
                if not white:
                    chi2.append(result.diagnosis.chi2_red)
                    nu = result.session.result.dof
            Path(record.path).unlink()
    n = len(seeds)
    print(f"{world} noise: {n} clean one-day records at 1 Hz ({time.perf_counter() - start:.0f} s)")
    for label, table in (
        ("noise model measured by the system stage", rows),
        ("white floor only (no slow noise), for comparison", white_rows),
    ):
        a = np.array(table, dtype=float)
        rate = a[:, 3].mean()
        print(
            f"  {label}: NOT consistent {a[:, 0].mean():.3f}, flagged candidate {a[:, 1].mean():.3f}, "
            f"flagged harmonic {a[:, 2].mean():.3f}; "
            f"any false alarm {rate:.3f} ({int(a[:, 3].sum())}/{n}; target <= 0.05, binomial 1σ at 0.05: {math.sqrt(0.05 * 0.95 / n):.3f})"
        )
    chi2 = np.array(chi2)
    print(
        f"  χ²_ν under the measured model: mean {chi2.mean():.3f}, sd {chi2.std(ddof=1):.3f} "
        f"(expected 1 ± {math.sqrt(2 / nu):.3f}, ν = {nu})"
    )


def power(seeds: range) -> None:
    for effect, value in HIDDEN.items():
        start = time.perf_counter()
        first, flagged, signal, others = 0, 0, [], []
        with tempfile.TemporaryDirectory() as tmp:
            for seed in seeds:
                record, truth = write_day(Path(tmp), seed, WORLDS["quartz"], {effect: value})
                result = diagnose(record, truth)
                candidate = result.ranking[effect]
                first += result.ranking.best is not None and result.ranking.best.id == effect
                if result.ranking.best is not None and result.ranking.best.id != effect:
                    others.append(result.ranking.best.id)
                flagged += candidate.flagged
                signal.append(abs(value) / candidate.sigma)
                Path(record.path).unlink()
        term = LIBRARY[effect].term
        print(
            f"hidden {effect} = {term.to_engineering(value):g} {term.unit} "
            f"(quartz noise, {len(seeds)} seeds, {time.perf_counter() - start:.0f} s): "
            f"ranked first {first}/{len(seeds)}, flagged {flagged}/{len(seeds)}; signal |γ|/σ_γ median {np.median(signal):.1f} "
            f"(range {min(signal):.1f}-{max(signal):.1f}) under the upper-limit noise model"
            + (f"; first instead: {', '.join(sorted(set(others)))}" if others else "")
        )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=24)
    parser.add_argument("--first", type=int, default=1)
    parser.add_argument("--worlds", nargs="+", choices=sorted(WORLDS), default=["white", "quartz"])
    parser.add_argument("--power", action="store_true", help="also the detection power of hidden effects (10 seeds each)")
    args = parser.parse_args(argv)
    seeds = range(args.first, args.first + args.seeds)
    for world in args.worlds:
        false_alarms(world, seeds)
    if args.power:
        power(range(args.first, args.first + 10))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
