"""``stableins diagnose``: simulated files with a hidden effect, a record from ``calibrate device``, JSON out."""

import json
from dataclasses import replace

import pytest

from stableins.cli import main
from stableins.conventions import ARCSEC
from stableins.data.device import save_device
from stableins.procedures.definition import load_procedure
from stableins.simulator.device import simulate_dwells
from stableins.simulator.noise import NoiseSettings
from stableins.simulator.truth import Truth

WHITE = NoiseSettings(velocity_random_walk=4.5e-4, quantization=1e-5, angle_noise=0.2 * ARCSEC)


@pytest.fixture(scope="module")
def session_files(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("diagnose")
    truth = Truth.draw(21, noise=WHITE, effects={"nonorth_12": 30 * ARCSEC})
    files = []
    for name, dwell, rate, seed in (("coarse", 20.0, 20.0, 21), ("fine", 120.0, 10.0, 22)):
        procedure = load_procedure(f"device-{name}")
        columns = simulate_dwells(truth, [s.command for s in procedure.steps], dwell=dwell, settle=5.0, rate=rate, seed=seed, stage=name)
        files.append(str(save_device(tmp / f"device-{name}.csv", columns, replace(truth.site, extra={"procedure": name}))))
    record = tmp / "record.json"
    assert main(["calibrate", "device", *files, "--out", str(record), "--bias-instability", "0"]) == 0
    from stableins.data.system import SystemRecordWriter
    from stableins.simulator.system import simulate_system

    system = tmp / "system.h5"
    with SystemRecordWriter(system, replace(truth.site, sample_rate=5.0)) as writer:
        writer.append(simulate_system(truth, 6 * 3600.0, rate=5.0, seed=23))
    files.append(str(system))
    return files, str(record)


def test_diagnose_ranks_the_hidden_effect_first_and_adding_it_restores_chi2(session_files, capsys):
    files, record = session_files
    files = files[:2]
    capsys.readouterr()
    assert main(["diagnose", *files, "--record", record, "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["stage"] == "fine" and out["chi2_red"] > 3
    first = out["candidates"][0]
    assert first["id"] == "nonorth_12" and first["flagged"] and first["identifiable"]
    assert {"statistic", "p_value", "delta_bic", "predicted", "aliases"} <= set(first)
    assert first["predicted"]["unit"] == "arcsec" and abs(first["predicted"]["estimate"] - 30) < 5 * first["predicted"]["sigma"]
    assert main(["diagnose", *files, "--record", record, "--add", "nonorth_12", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert [s["label"] for s in out["history"]] == ["standard model", "+ nonorth_12"]
    assert 0.5 < out["chi2_red"] < 1.6  # ν ≈ 36: 1 ± 0.24
    assert out["history"][1]["added"][0]["id"] == "nonorth_12"
    assert not any(c["flagged"] for c in out["candidates"])
    # the record's gyro stage is in the model in force: its nine Dg_ab join the drift model, none is left to rank
    assert {m["id"] for m in out["drift"]["model"]} >= {f"Dg_{a}{b}" for a in "xyz" for b in "xyz"}
    assert out["drift"]["candidates"] == [] and out["drift"]["chi2_red"] < 1.6


def test_diagnose_text_and_plots(session_files, capsys, tmp_path):
    files, record = session_files
    capsys.readouterr()
    assert main(["diagnose", files[1], "--record", record, "--plots", str(tmp_path / "fig")]) == 0
    text = capsys.readouterr().out
    assert "χ²_ν" in text and "nonorth_12" in text and "noise floor" in text
    assert sorted(p.name for p in (tmp_path / "fig").iterdir()) == ["history.png", "orientation.png", "residuals.png"]


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--add", "K9_q"], "unknown effect"),
        (["--add", "K3_x", "--add", "K3_x"], "twice"),
        (["--alpha", "2"], "--alpha"),
    ],
)
def test_diagnose_bad_arguments_exit_2(session_files, capsys, extra, message):
    files, record = session_files
    assert main(["diagnose", files[1], "--record", record, *extra]) == 2
    assert message in capsys.readouterr().err


def test_diagnose_system_record(session_files, capsys):
    files, record = session_files
    capsys.readouterr()
    assert main(["diagnose", files[2], "--record", record, "--bin", "120", "--add", "nonorth_12", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["stage"] == "system" and out["drift"] is None
    assert set(out["spectra"]) == {"f_x", "f_y", "f_z"} and len(out["spectra"]["f_x"]["p_value"]) == 4
    # the hidden non-orthogonality is in the system record too: with it added the bins are at the floor
    assert abs(out["chi2_red"] - 1) < 4 * out["expected_spread"]
    assert main(["diagnose", files[0], files[2], "--record", record]) == 2  # one kind of data at a time
    assert "one system-level record" in capsys.readouterr().err


def test_diagnose_missing_record_exit_2(session_files, capsys, tmp_path):
    files, _ = session_files
    assert main(["diagnose", files[1], "--record", str(tmp_path / "none.json")]) == 2
    assert "none.json" in capsys.readouterr().err
