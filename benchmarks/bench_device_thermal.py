"""The device-level thermal stage (issue 25, part 3): Kt_bias and Kt_sf with σ from dwells over a temperature cycle.

For each seed the truth simulator draws an instrument (``Truth.draw``, the quartz noise: white 46 µg/√Hz, bias
instability 2 µg, random walk 1e-7 m/s²/√s) with ``Kt_bias_a`` drawn N(0, 5 µg/K) and ``Kt_sf_a`` N(0, 5 ppm/K) and a
temperature cycle of ``--amplitude`` K (sine) over ``--period`` hours, and simulates the ``device-thermal`` procedure
(each axis up and down, 8 rounds of 4-min dwells at 10 Hz; the dwell means carry the physics, 10 Hz keeps the cost).
:func:`stableins.estimators.thermal_sensitivity.estimate_thermal` estimates the six sensitivities.

Printed: per seed the errors over σ; over all seeds the rms z per family (bias, scale factor) with the 95 % band for
that many values, the mean σ and the mean χ²_ν of the dwell fit.

Usage::

    python benchmarks/bench_device_thermal.py [--seeds 20] [--first 1] [--amplitude 5] [--period 3.3] [--white]
"""

from __future__ import annotations

import argparse
import math
import time
from dataclasses import replace

import numpy as np

from stableins.conventions import MICRO_G, PPM
from stableins.data.device import DeviceDataset
from stableins.estimators.thermal_sensitivity import THERMAL_TERM_IDS, ThermalDetails, estimate_thermal
from stableins.noise import NoiseModel
from stableins.procedures.definition import load_procedure
from stableins.simulator.device import simulate_dwells
from stableins.simulator.noise import NoiseSettings, TemperatureProfile
from stableins.simulator.truth import Truth


def thermal_truth(seed: int, amplitude: float, period: float, *, white: bool = False) -> Truth:
    """A drawn instrument with drawn thermal sensitivities under a temperature cycle (``amplitude`` K, ``period`` s)."""
    rng = np.random.default_rng([seed, 2525])
    effects = {f"Kt_bias_{a}": 5 * MICRO_G * rng.standard_normal() for a in "xyz"}
    effects |= {f"Kt_sf_{a}": 5 * PPM * rng.standard_normal() for a in "xyz"}
    profile = TemperatureProfile(amplitude=amplitude, period=period, phase=float(rng.uniform(0, 2 * math.pi)), sensor_noise=0.01)
    quartz = replace(NoiseSettings.quartz(), temperature=profile)
    noise = NoiseSettings(velocity_random_walk=4.5e-4, temperature=profile) if white else quartz
    return Truth.draw(seed, effects=effects, noise=noise)


def session(truth: Truth, seed: int) -> DeviceDataset:
    """The device-thermal procedure on the simulated platform, as a validated dataset."""
    procedure = load_procedure("device-thermal")
    readings = [s.command for s in procedure.steps]
    columns = simulate_dwells(
        truth,
        readings,
        dwell=[s.dwell for s in procedure.steps],
        settle=[s.settle for s in procedure.steps],
        rate=procedure.steps[0].sample_rate,
        seed=seed,
        stage="fine",
    )
    return DeviceDataset(replace(truth.site, sample_rate=procedure.steps[0].sample_rate), columns)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--first", type=int, default=1)
    parser.add_argument("--amplitude", type=float, default=5.0, help="temperature cycle amplitude [K]")
    parser.add_argument("--period", type=float, default=3.3, help="temperature cycle period [h]")
    parser.add_argument("--white", action="store_true", help="white noise only (no slow noise)")
    parser.add_argument("--white-weights", action="store_true", help="fit without the noise model's slow terms (what σ misses)")
    args = parser.parse_args(argv)
    print(__doc__.splitlines()[0])
    z_all, sig_all, chi_red = [], [], []
    start = time.perf_counter()
    for seed in range(args.first, args.first + args.seeds):
        truth = thermal_truth(seed, args.amplitude, args.period * 3600.0, white=args.white)
        data = session(truth, seed)
        model = None if args.white_weights else NoiseModel.given(4.5e-4, truth.noise.bias_instability, truth.noise.acceleration_random_walk)
        fit = estimate_thermal(data.dwells(), _terms(), gravity=data.metadata.gravity, noise_model=model)
        true = np.array([truth.effects[i] for i in THERMAL_TERM_IDS])
        z = (fit.values - true) / fit.sigma
        z_all.append(z)
        sig_all.append(fit.sigma)
        details = fit.details
        assert isinstance(details, ThermalDetails)
        chi_red.append(details.chi2 / details.dof)
        reduced = " ".join(f"{c:.2f}" for c in details.chi2 / details.dof)
        print(f"  seed {seed:3d}: z " + " ".join(f"{v:+.2f}" for v in z) + f"   χ²_ν {reduced}")
    z = np.array(z_all)
    sig = np.array(sig_all)
    n = z.shape[0] * 3
    from scipy.stats import chi2

    band = (math.sqrt(chi2.ppf(0.025, n) / n), math.sqrt(chi2.ppf(0.975, n) / n))
    world = "white" if args.white else "quartz (white, bias instability 2 µg, random walk 1e-7 m/s²/√s)"
    print(f"\n{args.seeds} seeds, {world}, cycle ±{args.amplitude:g} K over {args.period:g} h  ({time.perf_counter() - start:.0f} s)")
    rms_bias, rms_sf = math.sqrt(np.mean(z[:, :3] ** 2)), math.sqrt(np.mean(z[:, 3:] ** 2))
    print(f"  rms z Kt_bias {rms_bias:.3f}, Kt_sf {rms_sf:.3f}  (95 % band {band[0]:.2f}–{band[1]:.2f} for {n} values)")
    sig_bias, sig_sf = np.mean(sig[:, :3]) / MICRO_G, np.mean(sig[:, 3:]) / PPM
    print(f"  mean σ Kt_bias {sig_bias:.3f} µg/K, Kt_sf {sig_sf:.3f} ppm/K; mean χ²_ν of the dwell fit {np.mean(chi_red):.2f}")
    return 0


def _terms():
    from stableins.discovery.library import LIBRARY

    return tuple(LIBRARY[i].term for i in THERMAL_TERM_IDS)


if __name__ == "__main__":
    raise SystemExit(main())
