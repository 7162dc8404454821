"""The demo's discovery loop (diagnose → add → recalibrate) on simulated device sessions, fixed seeds.

Each case hides an effect (or none) in a simulated instrument (the demo's procedures at 10 Hz, the
instrument's datasheet noise given to the stages) and runs :func:`stableins.commands.demo.discovery_loop`:
the hidden effect must be found, added, estimated within 3σ and the fused χ²_ν back in its band; with
nothing hidden nothing is added.  The whole demo for the same effects (system stage and certificate
included) is ``benchmarks/bench_demo_loop.py``.
"""

import json
import math

import pytest

from stableins import cli
from stableins.commands.demo import _datasheet, discovery_loop
from stableins.discovery.steps import Decision
from stableins.errormodel import MICRO_G_PER_G2
from stableins.records import CalibrationRecord

KCC = 6e-6  # s²/m: 59 µg/g², the size of issue 12's example


def _loop(out, seed, hidden):
    flags = [item for name, value in hidden.items() for item in ("--hidden", f"{name}={value!r}")]
    assert cli.main(["simulate", "device", "--seed", str(seed), "--rate", "10", "--out", str(out), *flags]) == 0
    data = [str(out / "device-coarse.csv"), str(out / "device-fine.h5")]
    datasheet = _datasheet(out / "truth.json")
    assert cli.main(["calibrate", "device", *data, "--out", str(out / "cal-device.json"), *datasheet]) == 0
    return discovery_loop(out, data, datasheet, plots=False)


@pytest.mark.slow
@pytest.mark.parametrize("effect, seed", [("Kcc_xxy", 2018), ("Kcc_zxz", 31), ("Kcc_yxz", 47)])
def test_the_loop_finds_adds_and_estimates_the_hidden_effect(tmp_path, capsys, effect, seed):
    kept, diagnosis, said = _loop(tmp_path, seed, {effect: KCC})
    assert kept == [effect], said
    assert "nothing flagged" in said[-1]
    record = CalibrationRecord.load(tmp_path / "cal-device.json")
    value, sigma = record[effect].value, record[effect].sigma
    assert abs(value - KCC) < 3 * sigma, (value / MICRO_G_PER_G2, sigma / MICRO_G_PER_G2)
    steps = record.discovery.steps
    assert [s.decision for s in steps] == [Decision.BASELINE, Decision.KEPT]
    # the standard model misses the effect far beyond the noise; with it, χ²_ν is back in its band
    band = 3 * math.sqrt(2 / steps[1].dof)  # 3σ of χ²_ν
    assert steps[0].chi2_red > 1 + band
    assert abs(steps[1].chi2_red - 1) < band
    assert steps[1].p_value < 1e-6
    # the last diagnosis is the record in force's: nothing flagged
    assert not [c for c in json.loads(diagnosis.read_text())["candidates"] if c["flagged"]]


@pytest.mark.slow
def test_without_a_hidden_effect_nothing_is_added(tmp_path):
    kept, _, said = _loop(tmp_path, 2018, {})
    assert kept == [] and said == ["round 0: nothing flagged; the model in force reaches the noise floor"]
    record = CalibrationRecord.load(tmp_path / "cal-device.json")
    assert record.discovery is None and not any(p.id.startswith("K") and not p.id.startswith("K2") for p in record.parameters)
