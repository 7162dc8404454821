"""``stableins design``'s options, each in a successful run with its effect asserted (issue 31; tests/test_cli_options.py maps them).

Every run is the Cramér-Rao evaluation of a shipped procedure (well under a second) or one dwell optimization; each
option is compared with the run without it, so an option that stopped reaching the design fails here.
"""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from stableins import cli
from stableins.procedures.definition import load_procedure

WHITE = ["--white", "4.5e-4"]


def _design(capsys, *argv: str) -> dict:
    assert cli.main(["design", "device-coarse", *argv, "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def _sigma(document: dict) -> dict[str, float]:
    return {p["id"]: p["sigma"] for p in document["parameters"] if p["sigma"]}  # theta10's gauge (0) left out


def _designed(document: dict) -> dict[str, float]:
    return {p["id"]: p["designed_sigma"] for p in document["parameters"] if p["sigma"] and p["designed_sigma"] is not None}


def test_design_noise_options_set_the_noise_model(capsys, tmp_path):
    """--white, --bias-instability, --random-walk, --quantization each raise σ; --noise CAL.json gives the same model."""
    from fuzzing import _record

    from stableins.conventions import MICRO_G
    from stableins.noise import NoiseModel

    base = _sigma(_design(capsys, *WHITE))
    doubled = _sigma(_design(capsys, "--white", "9e-4"))
    assert all(doubled[k] == pytest.approx(2 * base[k], rel=0.02) for k in base)  # --white: white noise alone, σ ∝ N
    for option, value in (("--bias-instability", "20"), ("--random-walk", "1e-6"), ("--quantization", "1e-4")):
        grown = _sigma(_design(capsys, *WHITE, option, value))
        assert all(grown[k] >= base[k] for k in base) and any(grown[k] > 1.001 * base[k] for k in base), option
    sheet = _sigma(_design(capsys, *WHITE, "--bias-instability", "20", "--random-walk", "1e-6"))
    model = NoiseModel.given(4.5e-4, 20 * MICRO_G, 1e-6, 0.0, provenance="datasheet for the options test")
    record = tmp_path / "noise.json"
    replace(_record("SYN-1"), noise_model=model).save(record)
    assert cli.main(["design", "device-coarse", "--noise", str(record)]) == 0
    assert "datasheet for the options test" in capsys.readouterr().out  # --noise: the record's model, named
    from_record = _sigma(_design(capsys, "--noise", str(record)))
    assert from_record == pytest.approx(sheet, rel=1e-9)


def test_design_plan_options_change_the_evaluated_plan(capsys):
    """--passes repeats the coarse stage, --fine adds the fine stage: more lab time, smaller σ."""
    two = _design(capsys, *WHITE)
    one = _design(capsys, *WHITE, "--passes", "1")
    assert 1.9 < two["lab_time"] / one["lab_time"] < 2.1  # --passes 1: one pass of the 18 positions, not two
    assert _sigma(one) == pytest.approx({k: np.sqrt(2) * v for k, v in _sigma(two).items()}, rel=0.01)  # white noise: half the data
    fine = _design(capsys, *WHITE, "--passes", "1", "--fine", "device-fine")
    assert fine["lab_time"] > 2 * one["lab_time"]  # --fine: its positions and long dwells are added
    assert all(_sigma(fine)[k] <= _sigma(one)[k] for k in _sigma(one)) and any(_sigma(fine)[k] < 0.9 * _sigma(one)[k] for k in _sigma(one))


def test_design_match_bounds_out_and_name(capsys, tmp_path):
    """--match meets the procedure's own σ within --min-dwell/--max-dwell; --out/--name/--sample-rate shape the files."""
    argv = [*WHITE, "--passes", "1", "--match", "--min-dwell", "20", "--max-dwell", "40", "--sample-rate", "10"]
    document = _design(capsys, *argv, "--out", str(tmp_path), "--name", "matched")
    given, designed = _sigma(document), _designed(document)
    assert set(designed) == set(given)
    dwells = np.array(document["designed_dwells"]["coarse"])
    assert dwells.min() >= 20 and dwells.max() <= 40  # --min-dwell, --max-dwell
    assert document["procedures"] == [str(tmp_path / "matched-coarse.toml")]  # --out, --name
    written = load_procedure(tmp_path / "matched-coarse.toml")
    assert written.name == "matched-coarse" and len(written.steps) == 18
    assert {s.sample_rate for s in written.steps} == {10.0}  # --sample-rate: every designed dwell
    assert [s.dwell for s in written.steps] == pytest.approx(dwells.tolist())


def test_design_budget_and_criterion(capsys, tmp_path):
    """--budget caps the lab time, --criterion D gives another design than A."""
    a = _design(capsys, *WHITE, "--passes", "1", "--budget", "0.25")
    d = _design(capsys, *WHITE, "--passes", "1", "--budget", "0.25", "--criterion", "D")
    for document in (a, d):
        assert document["designed_lab_time"] <= 0.25 * 3600 * 1.001  # --budget 0.25 h
    assert not np.allclose(a["designed_dwells"]["coarse"], d["designed_dwells"]["coarse"])  # --criterion D: not A's dwells


@pytest.mark.slow
def test_design_grid_chooses_positions_on_the_grid(capsys, tmp_path):
    """--grid DEG: the exchange algorithm replaces positions by candidates of the grid (about 4 s of CPU)."""
    gridded = _design(capsys, *WHITE, "--passes", "1", "--budget", "0.4", "--grid", "90", "--out", str(tmp_path), "--name", "grid")
    assert gridded["designed_lab_time"] <= 0.4 * 3600 * 1.001
    given = {tuple(np.round(np.degrees(s.command), 6)) for s in load_procedure("device-coarse").steps}
    chosen = {tuple(np.round(np.degrees(s.command), 6)) for s in load_procedure(tmp_path / "grid-coarse.toml").steps}
    new = chosen - given
    assert new  # --grid 90: positions exchanged for candidates of the grid
    # the grid: platform and inner at multiples of 90°, the middle gimbal at -135° or -45°
    assert all(p % 90 == 0 and i % 90 == 0 and m in (-135.0, -45.0) for p, i, m in new), sorted(new)
