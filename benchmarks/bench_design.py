"""Design of the device-level procedure: the paper procedure's expected σ and the least lab time that matches it.

1. The paper's procedure (``device-coarse`` run twice in one session, then ``device-fine``) under the simulator's
   quartz noise model (white N = 4.5e-4 m/s/√s, bias instability 2 µg, random walk 1e-7 m/s²/√s, quantization
   1e-5 m/s): the Cramér-Rao bound of every parameter of the joint fit, the rank and null space, the lab time
   (slews at 10°/s peak, settles, dwells).
2. ``stableins design --match``: the dwell time of every position (the same positions) that reaches the paper's σ on
   every parameter in the least lab time.  Target: ≤ 60 % of the paper's lab time (issue 19).  The designed
   procedures are written to ``--out`` (TOML that ``stableins run`` executes; each is loaded back by the procedure
   loader) for ``bench_campaign.py --designed DIR``, which confirms the σ by simulation.

``--quick``: the bound only (the optimization takes about a minute on an idle core).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from stableins.campaign.config import CalibrationNoise, noise_presets
from stableins.campaign.task import calibration_noise
from stableins.conventions import STANDARD_GRAVITY
from stableins.estimators.design import describe_design
from stableins.estimators.experiment import PlannedStage, expected_precision, optimize_dwells
from stableins.estimators.setting import DeviceSetting
from stableins.procedures.definition import load_procedure
from stableins.procedures.designed import device_plan, write_procedure

TARGET_RATIO = 0.60


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="the bound of the paper procedure only")
    parser.add_argument("--out", type=Path, help="write the designed procedures here (designed-coarse.toml, designed-fine.toml)")
    parser.add_argument("--sample-rate", type=float, default=10.0, help="sample rate written to the designed procedures [Hz]")
    args = parser.parse_args()
    noise = calibration_noise(noise_presets()["quartz"], CalibrationNoise.DATASHEET)
    assert noise is not None
    setting = DeviceSetting(STANDARD_GRAVITY)
    coarse, fine = load_procedure("device-coarse"), load_procedure("device-fine")
    plan = device_plan(coarse, fine, passes=2)
    t0 = time.perf_counter()
    paper = expected_precision(plan, noise, setting)
    print(f"noise model: {noise.describe()} (white {noise.values('white')[0]:.3g} m/s/√s, quantization 1e-5 m/s)")
    print(f"paper procedure (device-coarse × 2 passes in one session + device-fine): bound in {time.perf_counter() - t0:.3f} s")
    times = ", ".join(f"{k} {v / 3600:.3f} h" for k, v in paper.plan.stage_times().items())
    print(f"  lab time {paper.lab_time / 3600:.3f} h ({times}); rank {paper.analysis.rank} of {len(paper.ids)} (θ10 gauge)")
    for line in describe_design(paper.ids, paper.analysis.singular_values, paper.analysis.null_space)[1:]:
        print("  " + line)
    sigma = paper.sigma_engineering()
    if args.quick:
        print("  " + ", ".join(f"{k} {v:.4g} {paper.model[k].unit}" for k, v in sigma.items() if v > 0))
        return 0
    targets = {k: v for k, v in paper.sigma.items() if v > 0}
    t0 = time.perf_counter()
    designed = optimize_dwells(plan, noise, setting, targets=targets)
    elapsed = time.perf_counter() - t0
    ratio = designed.lab_time / paper.lab_time
    times = ", ".join(f"{k} {v / 3600:.3f} h" for k, v in designed.plan.stage_times().items())
    print(f"\ndesigned (same positions, dwell of every position optimized, SLSQP on the exact bound, {elapsed:.0f} s):")
    print(f"  lab time {designed.lab_time / 3600:.3f} h ({times})")
    for stage in designed.plan.stages:
        print(f"  {stage.stage} dwells [s]: " + " ".join(f"{t:.1f}" for t in stage.dwell))
    print(f"  {'parameter':<10}{'paper σ':>10}{'designed σ':>12}{'ratio':>8}  unit")
    worst = 0.0
    for k, v in designed.sigma_engineering().items():
        if sigma[k] > 0:
            worst = max(worst, v / sigma[k])
            print(f"  {k:<10}{sigma[k]:>10.4g}{v:>12.4g}{v / sigma[k]:>8.3f}  {paper.model[k].unit}")
    ok = ratio <= TARGET_RATIO and worst <= 1.001
    print(
        f"requirement: designed lab time ≤ {TARGET_RATIO:.0%} of the paper's with every σ ≤ the paper's: "
        f"{ratio:.1%}, worst σ ratio {worst:.4f} -> {'PASS' if ok else 'FAIL'} (confirmed by simulation: bench_campaign.py --designed)"
    )
    if args.out is not None:
        for template, stage in ((coarse, designed.plan.coarse), (fine, designed.plan.fine)):
            assert stage is not None
            written = write_procedure(
                args.out / f"designed-{template.stage}.toml",
                template,
                PlannedStage(stage.stage, stage.commands, stage.dwell.round(1), stage.settle, args.sample_rate, stage.passes),
                name=f"designed-{template.stage}",
                source="benchmarks/bench_design.py (stableins design --match)",
            )
            print(f"wrote {written.path} ({len(written.steps)} positions, loaded back by the procedure loader)")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
