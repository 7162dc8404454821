"""``calibrate poses``'s options in successful runs, each effect asserted against the run without it (issue 31).

The log is test_poses.py's: 16 hand-placed holds of a triad in offset-binary counts (about a second of fitting per
run).  tests/test_cli_options.py maps the options to these tests.
"""

from __future__ import annotations

import contextlib
import io
import json
from dataclasses import replace

import numpy as np
import pytest
from test_cli_options_quiet import quiet_main
from test_poses import LAYOUT, RATE, _counts_log, _write_csv

from stableins import cli
from stableins.conventions import STANDARD_GRAVITY
from stableins.records import CalibrationRecord

COLUMNS = ["--columns", LAYOUT["columns"], "--units", LAYOUT["units"], "--zero", "32768"]


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    """The log in seconds, in milliseconds, without a time column, and with a first hold 5 s longer than the others."""
    root = tmp_path_factory.mktemp("poses-options")
    time, counts, _ = _counts_log(np.random.default_rng(7), poses=16)
    _write_csv(root / "log.csv", time, counts)
    _write_csv(root / "log-ms.csv", time * 1000.0, counts)
    (root / "no-time.csv").write_text("ax,ay,az\n" + "".join(f"{int(a)},{int(b)},{int(c)}\n" for a, b, c in counts), encoding="utf-8")
    longer = np.vstack([counts[: int(5 * RATE)], counts])
    _write_csv(root / "long-first.csv", np.arange(len(longer)) / RATE, longer)
    return root


def _poses(*argv) -> tuple[int, dict, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        status = cli.main(["calibrate", "poses", *(str(a) for a in argv), "--json"])
    return status, (json.loads(out.getvalue()) if status == 0 else {}), err.getvalue()


@pytest.fixture(scope="module")
def base(logs):
    status, document, err = _poses(logs / "log.csv", *COLUMNS, "--out", logs / "base.json")
    assert status == 0, err
    return document


def _values(document: dict) -> dict[str, float]:
    return {k: v["value"] for k, v in document["parameters"].items()}


def test_poses_gravity_serial_and_range(logs, base, tmp_path):
    """--gravity scales the scale factors by g'/g; --serial names the unit; --range leaves the clipped holds out."""
    out = tmp_path / "g.json"
    status, document, err = _poses(logs / "log.csv", *COLUMNS, "--gravity", "9.79", "--serial", "POSE-9", "--out", out)
    assert status == 0, err
    for axis in "xyz":
        ratio = document["parameters"][f"sf_{axis}"]["value"] / base["parameters"][f"sf_{axis}"]["value"]
        assert ratio == pytest.approx(9.79 / STANDARD_GRAVITY, rel=1e-6)  # --gravity: the norm each hold is fitted to
    assert CalibrationRecord.load(out).serial_number == "POSE-9"  # --serial
    assert CalibrationRecord.load(logs / "base.json").serial_number == "log"  # default: the log's file name
    # --range 0:36000: a +1 g axis (36864 counts) is at the rail, those holds are left out and K2 is not determined
    status, clipped, err = _poses(logs / "log.csv", *COLUMNS, "--range", "0:36000", "--out", tmp_path / "r.json")
    assert status == 0, err
    assert not base["left_out"] and sorted(clipped["left_out"], key=int) == ["1", "2", "3", "13"]
    assert all("saturated" in why for why in clipped["left_out"].values()) and clipped["model"] == "NINE" != base["model"]


def test_poses_time_unit_and_rate_read_the_same_log(logs, base, tmp_path):
    """--time-unit ms reads a millisecond clock, --rate HZ a log with no clock: the same fit as the log in seconds."""
    status, ms, err = _poses(logs / "log-ms.csv", *COLUMNS, "--time-unit", "ms", "--out", tmp_path / "ms.json")
    assert status == 0, err
    assert ms["holds"] == base["holds"] and _values(ms) == pytest.approx(_values(base), rel=1e-9, abs=1e-12)
    columns = ["--columns", "f_x=ax,f_y=ay,f_z=az", *COLUMNS[2:]]
    status, rated, err = _poses(logs / "no-time.csv", *columns, "--rate", str(RATE), "--out", tmp_path / "rate.json")
    assert status == 0, err
    assert rated["holds"] == base["holds"] and _values(rated) == pytest.approx(_values(base), rel=1e-9, abs=1e-12)
    status, _, err = _poses(logs / "no-time.csv", *columns, "--out", tmp_path / "none.json")
    assert status == 2 and "--rate" in err  # without --rate such a log is refused


def test_poses_detection_options_and_edited_holds(logs, base, tmp_path):
    """--detect-only, --window, --false-split, --min-hold change the detection; --holds fits the holds of a table."""
    table = tmp_path / "holds.csv"
    argv = [logs / "log.csv", *COLUMNS, "--detect-only", "--window", "1", "--false-split", "0.01", "--write-holds", table]
    status, detected, err = _poses(*argv)
    assert status == 0, err
    assert "50-sample windows (1 s)" in detected["detection"] and "25-sample windows (0.5 s)" in base["detection"]  # --window 1
    assert "α = 1.0e-02" in detected["detection"] and "α = 1.0e-06" in base["detection"]  # --false-split
    assert "record" not in detected and not list(tmp_path.glob("*.json"))  # --detect-only: nothing fitted, no record
    status, longest, err = _poses(logs / "long-first.csv", *COLUMNS, "--detect-only", "--min-hold", "10")
    assert status == 0, err
    assert longest["holds"] == 1  # --min-hold 10: only the 12-s first hold is long enough; by default all 16 are found
    assert _poses(logs / "long-first.csv", *COLUMNS, "--detect-only")[1]["holds"] == 16
    lines = table.read_text(encoding="utf-8").splitlines()
    edited = tmp_path / "edited.csv"
    edited.write_text("\n".join(lines[:-2]) + "\n", encoding="utf-8")  # the last two holds deleted by hand
    status, fitted, err = _poses(logs / "log.csv", *COLUMNS, "--holds", edited, "--out", tmp_path / "edited.json")
    assert status == 0, err
    assert fitted["holds"] == 14 and base["holds"] == 16  # --holds: the table's holds, not detected ones


def test_poses_noise_options_and_quiet(logs, tmp_path, monkeypatch):
    """--noise CAL.json and the datasheet's --bias-instability/--random-walk set the record's noise model; --quiet."""
    from fuzzing import _record

    from stableins.noise import NoiseModel, NoiseSource

    model = NoiseModel.given(3e-3, 2e-4, 1e-6, provenance="noise record for the poses options test")
    noisy = tmp_path / "noise.json"
    replace(_record("log"), noise_model=model).save(noisy)
    status, _, err = _poses(logs / "log.csv", *COLUMNS, "--noise", noisy, "--out", tmp_path / "n.json")
    assert status == 0, err
    written = CalibrationRecord.load(tmp_path / "n.json").noise_model
    assert "noise record for the poses options test" in written.provenance  # --noise
    np.testing.assert_array_equal(written.values("random_walk"), model.values("random_walk"))
    argv = [logs / "log.csv", *COLUMNS, "--bias-instability", "30", "--random-walk", "2e-6", "--out", tmp_path / "d.json"]
    status, _, err = _poses(*argv)
    assert status == 0, err
    sheet = CalibrationRecord.load(tmp_path / "d.json").noise_model
    assert sheet.source is NoiseSource.DATASHEET and sheet.values("random_walk")[0] == 2e-6  # --random-walk
    assert sheet.values("bias_instability")[0] == pytest.approx(30e-6 * STANDARD_GRAVITY)  # --bias-instability [µg]
    argv = ["calibrate", "poses", logs / "log.csv", *COLUMNS, "--out", tmp_path / "q.json", "--quiet"]
    status, _, err, seen = quiet_main(monkeypatch, argv, "stableins.commands.calibrate_poses")
    assert status == 0 and seen == [True], err  # --quiet: silenced while it works
