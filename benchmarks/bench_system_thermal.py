"""Temperature and the third harmonic in the system stage (issue 16 parts 2 and 3): figures and what they compare against.

Records from the truth simulator (one sidereal day, 1 Hz, white accelerometer noise N = 5e-4 m/s/√s: the paper's
Table 4 noise of 5e-3 m/s² at 100 Hz has the same white level, so the same σ at a hundredth of the simulation cost; the
paper's Table 2/3 residuals, damping on).  Cases:

* ``thermal``: a 5 µg/K bias sensitivity on each axis with a 2 K (amplitude) daily temperature cycle.  Compared
  against the truth (combined coefficients of true − installed): every coefficient within its σ, or reported "not
  separable" with the reason — and against the stage without the temperature column (what main did: biased, nothing
  reported).
* ``ramp``: the same sensitivity with a non-daily history (a 2 K ramp over the day plus a 0.5 K cycle of 7 h): the
  record separates part of the sensitivities; detection and coefficients.
* ``kcc``: a 10 µg/g² cross-coupling Kcc_xxy: the third-harmonic note (which effects it names, whether it advises the
  K2 estimation), and the coefficients with and without ``estimate_k2`` (the correction the note must not advise).
* ``diagnose``: discovery on system records (``stableins diagnose``) with a thermal cycle and with Kcc_xxy: the ranking
  and the notes that name the thermal term and the K2/Kcc alias pair.
* ``drawn``: the sensitivities drawn from the stage's prior under the daily cycle: σ right on average (rms z ≈ 1)?
* ``prior`` (issue 25): a 5 µg/K bias sensitivity with a 2 K peak-to-peak daily cycle, with the default thermal prior
  and with the prior of the device-level thermal stage (``stableins calibrate thermal`` on a simulated device-thermal
  session of the same unit): every combination the stage calls determined against the same record without the cycle
  (acceptance: within 3σ and 1e-6 rad).  Not in the default ``--cases`` (3 system records and a device session a seed).
* ``clean``: false alarms on clean records (no thermal sensitivity, the daily cycle or the ramp present; no third
  harmonic): the share of records where the thermal test fires (target: the stage's false-positive rate, 5 %), where the
  third harmonic is flagged (3σ rule on x6, x7), and where a clean record gets "not separable" labels.

Usage::

    python benchmarks/bench_system_thermal.py [--cases thermal ramp kcc clean drawn prior] [--seeds 20] [--rate 1] [--drift 0.001]

``--drift 0.001`` adds an unknown 0.001 °/h gyro drift per axis to the thermal case: the joint Table 4 acceptance of issue
16 (drift and temperature), which needs the drift estimation of the system stage as well.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from bench_paper_table4 import SimulatorSource, paper_truth  # noqa: E402

from stableins.conventions import DEG_PER_HOUR, MICRO_G, SIDEREAL_DAY, STANDARD_GRAVITY  # noqa: E402
from stableins.estimators.system.assembly import residuals_from_parameters  # noqa: E402
from stableins.estimators.system.separation import COMBINED_COEFFICIENTS, combination_matrix  # noqa: E402
from stableins.estimators.system.stage import SystemOptions, run_system_stage  # noqa: E402
from stableins.schema import SYSTEM_COLUMNS  # noqa: E402
from stableins.simulator.noise import NoiseSettings, TemperatureProfile  # noqa: E402

BIAS_SENSITIVITY = 5 * MICRO_G  # [m/s²/K] on each axis
DEVICE_CYCLE = 5.0  # [K] amplitude of the device-level thermal test's chamber cycle
DEVICE_PERIOD = 3.3 * 3600.0  # [s] its period (the device-thermal procedure's length)
KCC = 10 * MICRO_G / STANDARD_GRAVITY**2  # 10 µg/g²


class _Source(SimulatorSource):
    def __init__(self, truth, duration, rate, seed, *, temperature=True):
        super().__init__(truth, duration, rate, seed)
        names = [c.name for c in SYSTEM_COLUMNS]
        self.columns = tuple(n for n in names if temperature or n != "temperature")


def _truth(rate, seed, effects, temperature, drift=0.0):
    truth = paper_truth(rate, seed)
    noise = NoiseSettings(velocity_random_walk=5e-4, temperature=temperature)
    gyro = {"x": drift, "y": drift, "z": drift} if drift else {}
    return replace(truth, noise=noise, effects=effects, gyro_drift=gyro)


def _run(truth, rate, seed, *, temperature=True, estimate_k2=False, prior=None):
    """The stage on the truth's record; ``prior``: (values, covariance) added to the installed calibration (a thermal prior)."""
    values, covariance = ({}, None) if prior is None else prior
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        source = _Source(truth, SIDEREAL_DAY, rate, seed, temperature=temperature)
        return run_system_stage(
            source, truth.site, {**truth.installed_calibration, **values}, covariance, options=SystemOptions(estimate_k2=estimate_k2)
        )


def _reference(truth):
    p = residuals_from_parameters(truth.parameters, truth.installed_calibration, truth.site.gravity)
    return combination_matrix(truth.site.latitude) @ np.r_[p, 0.0, 0.0]


def _table(label, out, reference):
    print(f"  {label}")
    print(f"  {'coef':<11}{'error':>11}{'1σ':>10}{'error/σ':>9}  status")
    flagged = set(out.thermal.not_separable) if out.thermal is not None else set()
    worst = 0.0
    for k, name in enumerate(COMBINED_COEFFICIENTS):
        err, sig = float(out.combined.values[k] - reference[k]), float(out.combined.sigma[k])
        status = "not separable (thermal cycle)" if name in flagged else "estimated"
        if name not in flagged:
            worst = max(worst, abs(err) / sig)
        print(f"  {name:<11}{err:>11.2e}{sig:>10.2e}{err / sig:>9.2f}  {status}")
    every = float(np.max(np.abs(out.combined.values - reference) / out.combined.sigma))
    shown = f"{worst:.2f}" if len(flagged) < len(COMBINED_COEFFICIENTS) else "— (none reported as estimated)"
    print(f"  largest |error|/σ among the coefficients reported as estimated: {shown}; over all fifteen: {every:.2f}")
    return worst


def case_thermal(rate, seed, drift=0.0):
    profile = TemperatureProfile(amplitude=2.0, period=86400.0, sensor_noise=0.01)
    effects = {f"Kt_bias_{a}": BIAS_SENSITIVITY for a in "xyz"}
    truth = _truth(rate, seed, effects, profile, drift)
    reference = _reference(truth)
    extra = f", unknown gyro drift {drift / DEG_PER_HOUR:g} °/h per axis" if drift else ""
    print(f"\n[thermal] 5 µg/K bias sensitivity per axis, 2 K daily cycle (24 h solar){extra}, seed {seed}, {rate:g} Hz")
    before = _run(truth, rate, seed, temperature=False)
    after = _run(truth, rate, seed)
    z_before = np.abs(before.combined.values - reference) / before.combined.sigma
    worst_name = COMBINED_COEFFICIENTS[int(z_before.argmax())]
    print(f"  without the temperature column (as main did): largest |error|/σ {z_before.max():.1f} ({worst_name})")
    _table("with the temperature column (this stage):", after, reference)
    print("  note: " + next(n for n in after.notes if n.startswith("temperature"))[:400] + " ...")


def case_ramp(rate, seed):
    profile = TemperatureProfile(ramp=2.0 / 86164.0, amplitude=0.5, period=7 * 3600.0, sensor_noise=0.01)
    effects = {f"Kt_bias_{a}": BIAS_SENSITIVITY for a in "xyz"}
    truth = _truth(rate, seed, effects, profile)
    reference = _reference(truth)
    print(f"\n[ramp] 5 µg/K bias sensitivity per axis, 2 K ramp plus a 0.5 K cycle of 7 h, seed {seed}, {rate:g} Hz")
    out = _run(truth, rate, seed)
    th = out.thermal
    sig = np.sqrt(np.diag(th.covariance)) / MICRO_G
    print(f"  separable directions {th.dof} of 6; test χ² = {th.chi2:.1f}, p = {th.p_value:.2g}, detected: {th.detected}")
    print(
        "  Kt_bias x, y, z [µg/K] (truth 5): "
        + ", ".join(f"{v / MICRO_G:.2f} ± {s:.2f}" for v, s in zip(th.estimate[:3], sig[:3], strict=True))
    )
    _table("coefficients:", out, reference)


def case_kcc(rate, seed):
    truth = _truth(rate, seed, {"Kcc_xxy": KCC}, TemperatureProfile(sensor_noise=0.01))
    reference = _reference(truth)
    print(f"\n[kcc] 10 µg/g² Kcc_xxy, seed {seed}, {rate:g} Hz (reference: the standard model's coefficients; Kcc moves x3, φ1c, θ1s)")
    for k2 in (False, True):
        out = _run(truth, rate, seed, estimate_k2=k2)
        z = (out.combined.values - reference) / out.combined.sigma
        chi = out.result.chi2_red
        print(f"  estimate_k2={k2}: x3 {z[2]:+.1f}σ, θ1s {z[7]:+.1f}σ, φ1c {z[12]:+.1f}σ; separation χ²_ν {chi:.2f}")
        note = next((n for n in out.notes if n.startswith("third harmonic") or n.startswith("K2 estimated")), "(no third-harmonic note)")
        print("  note: " + note)


def _device_prior(seed, effects):
    """The device-level thermal stage on a simulated device-thermal session of a unit with ``effects``: (values, covariance)."""
    from bench_device_thermal import session

    from stableins.discovery.library import LIBRARY
    from stableins.estimators.thermal_sensitivity import THERMAL_TERM_IDS, estimate_thermal
    from stableins.noise import NoiseModel
    from stableins.simulator.truth import Truth

    quartz = NoiseSettings.quartz()
    profile = TemperatureProfile(amplitude=DEVICE_CYCLE, period=DEVICE_PERIOD, sensor_noise=0.01)
    device_truth = Truth.draw(seed, effects=effects, noise=replace(quartz, temperature=profile))
    data = session(device_truth, seed)
    model = NoiseModel.given(quartz.velocity_random_walk, quartz.bias_instability, quartz.acceleration_random_walk)
    terms = tuple(LIBRARY[i].term for i in THERMAL_TERM_IDS)
    fit = estimate_thermal(data.dwells(), terms, gravity=data.metadata.gravity, noise_model=model)
    values = dict(zip(THERMAL_TERM_IDS, fit.values.tolist(), strict=True))
    covariance = {(a, b): float(fit.covariance[i, j]) for i, a in enumerate(THERMAL_TERM_IDS) for j, b in enumerate(THERMAL_TERM_IDS)}
    return values, covariance, fit


def _determined(out):
    """Names, values, σ and 'determined' of the named combinations the stage reports."""
    return {name: (value, sigma, ok) for name, (value, sigma, ok) in out.separation.combinations.items()}


def case_prior(rate, seeds, first):
    """Issue 25 acceptance: a daily 2-K (peak to peak) cycle at 5 µg/K with the device-level thermal prior.

    Per seed: the record without the cycle (the reference), with the cycle and the default prior (5 µg/K, 5 ppm/K), and
    with the cycle and the prior from the device-level thermal stage on a simulated device-thermal session of the same
    unit (quartz noise, a ±5 K chamber cycle over 3.3 h).  For every combination the stage calls determined: its shift
    from the no-cycle value, in rad and over its σ (acceptance: within 3σ and 1e-6 rad).
    """
    print(
        f"\n[prior] 5 µg/K bias sensitivity per axis, 2 K peak-to-peak daily cycle, {seeds} seeds from {first}, {rate:g} Hz; "
        f"device-level prior from a device-thermal session (±{DEVICE_CYCLE:g} K over {DEVICE_PERIOD / 3600:.1f} h, quartz noise)"
    )
    cycle = TemperatureProfile(amplitude=1.0, period=86400.0, sensor_noise=0.01)
    effects = {f"Kt_bias_{a}": BIAS_SENSITIVITY for a in "xyz"}
    worst = {"default": [0.0, 0.0, 0, 0], "device": [0.0, 0.0, 0, 0]}  # |shift| rad, |shift|/σ, determined, failing
    for seed in range(first, first + seeds):
        start = time.perf_counter()
        reference = _determined(_run(_truth(rate, seed, effects, TemperatureProfile(sensor_noise=0.01)), rate, seed))
        truth = _truth(rate, seed, effects, cycle)
        values, covariance, fit = _device_prior(seed, effects)
        runs = {"default": _run(truth, rate, seed), "device": _run(truth, rate, seed, prior=(values, covariance))}
        line = []
        for label, out in runs.items():
            combos = _determined(out)
            shifts = [(abs(v - reference[n][0]), abs(v - reference[n][0]) / s, s) for n, (v, s, ok) in combos.items() if ok]
            named = sum(1 for _, _, ok in combos.values() if ok)
            bad = sum(1 for d, z, _ in shifts if d > 1e-6 or z > 3)
            w = worst[label]
            w[0] = max(w[0], max((d for d, _, _ in shifts), default=0.0))
            w[1] = max(w[1], max((z for _, z, _ in shifts), default=0.0))
            w[2] += named
            w[3] += bad
            top = max((d for d, _, _ in shifts), default=0.0)
            sig = max((s for _, _, s in shifts), default=0.0)
            line.append(f"{label}: {named}/7 determined, largest shift {top:.1e} rad, largest σ {sig:.1e}, failing {bad}")
        kt = ", ".join(f"{v / MICRO_G:.2f}±{e / MICRO_G:.2f}" for v, e in zip(fit.values[:3], fit.sigma[:3], strict=True))
        print(f"  seed {seed}: Kt_bias (device) {kt} µg/K | " + " | ".join(line) + f" ({time.perf_counter() - start:.0f} s)")
    for label, (d, z, named, bad) in worst.items():
        print(
            f"  {label:>7} prior: {named} determined combinations over {seeds} seeds, largest shift from the no-cycle value "
            f"{d:.2e} rad ({z:.2f}σ); outside 3σ or 1e-6 rad: {bad}"
        )


def case_clean(rate, seeds, first):
    print(f"\n[clean] false alarms over {seeds} clean records per history (no thermal sensitivity, no third-harmonic effect), {rate:g} Hz")
    histories = {
        "constant temperature": TemperatureProfile(sensor_noise=0.01),
        "2 K daily cycle": TemperatureProfile(amplitude=2.0, period=86400.0, sensor_noise=0.01),
        "2 K ramp + 0.5 K 7-h cycle": TemperatureProfile(ramp=2.0 / 86164.0, amplitude=0.5, period=7 * 3600.0, sensor_noise=0.01),
    }
    for label, profile in histories.items():
        fired = third = labelled = tested = 0
        z_all = []
        start = time.perf_counter()
        for seed in range(first, first + seeds):
            truth = _truth(rate, seed, {}, profile)
            out = _run(truth, rate, seed)
            th = out.thermal
            tested += th.dof > 0
            fired += th.detected
            third += any(n.startswith("third harmonic") for n in out.notes)
            labelled += bool(th.not_separable)
            z_all.append((out.combined.values - _reference(truth)) / out.combined.sigma)
        z = np.concatenate(z_all)
        print(
            f"  {label:<28} thermal test fired {fired}/{tested} ({100 * fired / max(tested, 1):.1f} %, target 5 %); third harmonic "
            f"flagged {third}/{seeds}; 'not separable' labels on {labelled}/{seeds} records; rms z {math.sqrt(np.mean(z**2)):.2f} "
            f"({time.perf_counter() - start:.0f} s)"
        )


def case_drawn(rate, seeds, first):
    """Draw the sensitivities from the stage's prior (5 µg/K, 5 ppm/K, 1σ) under a 2 K daily cycle: is σ right (rms z ≈ 1)."""
    from stableins.estimators.system.thermal import DEFAULT_THERMAL_PRIOR

    print(f"\n[drawn] {seeds} records, sensitivities drawn from the prior (5 µg/K, 5 ppm/K 1σ per axis), 2 K daily cycle, {rate:g} Hz")
    profile = TemperatureProfile(amplitude=2.0, period=86400.0, sensor_noise=0.01)
    z_all, labelled = [], 0
    for seed in range(first, first + seeds):
        rng = np.random.default_rng(seed)
        effects = {f"Kt_bias_{a}": rng.normal(0.0, DEFAULT_THERMAL_PRIOR[0]) for a in "xyz"}
        effects |= {f"Kt_sf_{a}": rng.normal(0.0, DEFAULT_THERMAL_PRIOR[1]) for a in "xyz"}
        truth = _truth(rate, seed, effects, profile)
        out = _run(truth, rate, seed)
        labelled += len(out.thermal.not_separable)
        z_all.append((out.combined.values - _reference(truth)) / out.combined.sigma)
    z = np.array(z_all)
    blind = []
    for seed in range(first, first + min(seeds, 5)):
        rng = np.random.default_rng(seed)
        effects = {f"Kt_bias_{a}": rng.normal(0.0, DEFAULT_THERMAL_PRIOR[0]) for a in "xyz"}
        effects |= {f"Kt_sf_{a}": rng.normal(0.0, DEFAULT_THERMAL_PRIOR[1]) for a in "xyz"}
        truth = _truth(rate, seed, effects, profile)
        out = _run(truth, rate, seed, temperature=False)
        blind.append((out.combined.values - _reference(truth)) / out.combined.sigma)
    print(
        f"  with the temperature column: rms z {math.sqrt(np.mean(z**2)):.2f} over {z.size} coefficients (target 1; expected spread "
        f"±{math.sqrt(1 / (2 * z.size)):.2f}), largest |z| {np.abs(z).max():.1f}; {labelled / seeds:.1f} of 15 coefficients "
        "labelled not separable per record"
    )
    zb = np.array(blind)
    print(
        f"  without it (as main did), first {len(blind)} records: rms z {math.sqrt(np.mean(zb**2)):.1f}, largest |z| {np.abs(zb).max():.1f}"
    )


def case_diagnose(seed):
    """What ``stableins diagnose SYSTEM.h5 --record CAL.json`` says (bench_system_diagnose's pipeline) on two records."""
    import tempfile

    from bench_system_diagnose import diagnose, write_day

    worlds = {
        "thermal": (
            NoiseSettings(velocity_random_walk=4.5e-4, temperature=TemperatureProfile(amplitude=2.0, period=86400.0, sensor_noise=0.01)),
            {f"Kt_bias_{a}": BIAS_SENSITIVITY for a in "xyz"},
        ),
        "kcc": (NoiseSettings(velocity_random_walk=4.5e-4), {"Kcc_xxy": KCC}),
    }
    for label, (noise, effects) in worlds.items():
        with tempfile.TemporaryDirectory() as tmp:
            record, truth = write_day(Path(tmp), seed, noise, effects)
            result = diagnose(record, truth)
        hidden = ", ".join(effects)
        print(f"\n[diagnose/{label}] a drawn unit with {hidden} hidden, one day at 1 Hz, white 46 µg/√Hz, seed {seed}")
        top = result.ranking.candidates[:5]
        print("  ranking (top 5): " + "; ".join(f"{c.id} p={c.p_value:.2g}{' flagged' if c.flagged else ''}" for c in top))
        for note in result.notes:
            if note.startswith(("temperature", "third harmonic")):
                print("  note: " + note)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", nargs="+", default=["thermal", "ramp", "kcc", "diagnose", "clean", "drawn"])
    parser.add_argument("--seeds", type=int, default=20, help="clean records per temperature history")
    parser.add_argument("--first", type=int, default=100, help="first seed of the clean records")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--rate", type=float, default=1.0)
    parser.add_argument(
        "--drift", type=float, default=0.0, help="unknown gyro drift [°/h] per axis in the thermal case (Table 4 joint set-up)"
    )
    args = parser.parse_args(argv)
    print("Temperature and third harmonic in the system stage (truth simulator, one sidereal day, white N = 5e-4 m/s/√s)")
    for case in args.cases:
        if case == "clean":
            case_clean(args.rate, args.seeds, args.first)
        elif case == "diagnose":
            case_diagnose(args.seed)
        elif case == "drawn":
            case_drawn(args.rate, args.seeds, args.first)
        elif case == "prior":
            case_prior(args.rate, args.seeds, args.first)
        elif case == "thermal":
            case_thermal(args.rate, args.seed, args.drift * DEG_PER_HOUR)
        else:
            {"ramp": case_ramp, "kcc": case_kcc}[case](args.rate, args.seed)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
