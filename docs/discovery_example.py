"""Worked example of model discovery (docs/discovery.md): regenerates the text and the plots in docs/img/.

Run from the repository root:  PYTHONPATH=. MPLBACKEND=Agg python docs/discovery_example.py

A simulated instrument (stableins.simulator) hides two effects the standard model lacks:
a cross-coupling Kcc_xxy = 60 µg/g² and a gimbal-axis non-orthogonality nonorth_12 = 15″.
The loop: fit, diagnose, rank, add the best candidate, refit — until χ²_ν reaches 1.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from stableins.conventions import ARCSEC, MICRO_G, STANDARD_GRAVITY
from stableins.discovery.diagnostics import diagnose
from stableins.discovery.dwells import dwell_means
from stableins.discovery.history import Discovery
from stableins.discovery.problem import DwellProblem
from stableins.errormodel import ErrorModel
from stableins.noise import NoiseModel
from stableins.procedures.definition import load_procedure
from stableins.samples import SampleBlock
from stableins.simulator.device import simulate_dwells
from stableins.simulator.truth import SimulatedSite, Truth

IMG = Path(__file__).parent / "img"
HIDDEN = {"Kcc_xxy": 60 * MICRO_G / STANDARD_GRAVITY**2, "nonorth_12": 15 * ARCSEC}


def main() -> None:
    import matplotlib

    matplotlib.use("Agg")
    IMG.mkdir(exist_ok=True)
    truth = Truth.draw(7, effects=HIDDEN, site=SimulatedSite(sample_rate=10.0))
    commands = [s.command for s in load_procedure("device-fine").steps]
    sequence = commands + commands[::-1][1:]
    c = simulate_dwells(truth, sequence, dwell=60.0, settle=3.0, rate=10.0, seed=7)
    samples = SampleBlock(
        c["time"],
        np.stack([c["f_x"], c["f_y"], c["f_z"]], -1),
        np.stack([c["angle_platform"], c["angle_inner"], c["angle_middle"]], -1),
        c["temperature"],
    )
    dwells = dwell_means(
        samples,
        c["position"],
        c["time_since_command"],
        site=truth.site,
        # the instrument's slow noise (datasheet values): bias wander correlated between dwells
        noise=NoiseModel.given(
            truth.noise.velocity_random_walk, truth.noise.bias_instability, truth.noise.acceleration_random_walk, provenance="specification"
        ),
    )
    problem = DwellProblem(dwells)
    session = Discovery(problem, ErrorModel.standard(gimbals=True))

    first = session.diagnose()
    print("== step 0: the standard model\n" + first.report() + "\n")
    ranking = session.rank(refit_top=3)
    first.plot_positions(next_step=ranking.next_step()).savefig(IMG / "discovery_residuals_before.png", dpi=110)
    first.plot_orientation(next_step=ranking.next_step()).savefig(IMG / "discovery_orientation_before.png", dpi=110)

    for step in range(1, 4):
        print(f"== ranking {step}\n" + ranking.report(top=8) + "\n" + ranking.next_step() + "\n")
        if not ranking.best.flagged:
            break
        session.add(ranking.best.term)
        ranking = session.rank(refit_top=3)

    last = diagnose(problem, session.result)
    print("== final model\n" + last.report() + "\n")
    # before and after, each named by its model, with what to do next under the figure
    last.plot_positions(before=first, next_step=ranking.next_step()).savefig(IMG / "discovery_residuals_after.png", dpi=110)
    last.plot_orientation(before=first, next_step=ranking.next_step()).savefig(IMG / "discovery_orientation_after.png", dpi=110)
    print("== history\n" + session.history.report())
    session.history.plot(next_step=ranking.next_step()).savefig(IMG / "discovery_history.png", dpi=110)
    print(
        "\ntruth: "
        + ", ".join(f"{k} = {v / (MICRO_G / STANDARD_GRAVITY**2 if k.startswith('K') else ARCSEC):g}" for k, v in HIDDEN.items())
    )


if __name__ == "__main__":
    main()
