"""``stableins demo`` run to completion in the suite, its verdict checked (issue 31).

Every option of the command is given (``--out``, ``--seed``, ``--duration``, ``--hidden``, ``--rate``, ``--json``,
``--quiet``: each step, a process of its own, runs with ``--quiet`` too) and
its effect asserted: the directory, the seed and hidden effect of the simulated truth, the length and rate of the
system record (one day at 1 Hz: the system stage needs a sidereal day), and the JSON document on stdout, whose verdict
must be the ``verdict.json`` the demo writes.  The verdict itself is checked as a k·σ bound: every estimated parameter
of the final record within 4.5 σ of the simulator's truth (for 26 normal errors the chance of one beyond is 2e-4),
and the hidden effect found and kept.
"""

from __future__ import annotations

import contextlib
import io
import json

import h5py
import numpy as np
import pytest

from stableins import cli


@pytest.mark.slow
def test_demo_runs_to_completion_with_every_option_and_its_verdict_holds(tmp_path, monkeypatch):
    import subprocess

    out = tmp_path / "demo"
    stdout, stderr = io.StringIO(), io.StringIO()
    started: list[list[str]] = []
    original = subprocess.run

    def watched(argv, **kwargs):
        started.append([str(a) for a in argv])
        return original(argv, **kwargs)

    monkeypatch.setattr(subprocess, "run", watched)
    with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
        status = cli.main(["demo", "--out", str(out), "--seed", "2018", "--duration", "24h", "--rate", "1",
                           "--hidden", "Kcc_xxy=60ug/g2", "--json", "--quiet"])  # fmt: skip
    assert status == 0, stderr.getvalue()[-2000:]
    assert len(started) >= 7 and all(argv[-1] == "--quiet" for argv in started)  # --quiet: every step silenced too
    document = json.loads(stdout.getvalue())
    truth = json.loads((out / "truth.json").read_text())
    assert document["out"] == str(out) and truth["seed"] == 2018
    assert truth["effects"]["Kcc_xxy"] == pytest.approx(60e-6 * 9.80665 / 9.80665**2, rel=1e-12)
    with h5py.File(out / "system.h5", "r") as f:
        time = f["columns/time"][...]
    assert len(time) == 24 * 3600 and np.allclose(np.diff(time), 1.0)  # --duration 24h at --rate 1 Hz
    rows = json.loads((out / "verdict.json").read_text())
    assert document["verdict"] == rows
    assert "Kcc_xxy" in document["added"] and "Kcc_xxy" in {r["id"] for r in rows}
    assert len(rows) >= 20
    z = np.array([r["z"] for r in rows])
    assert np.all(np.isfinite(z)) and np.max(np.abs(z)) < 4.5, {r["id"]: r["z"] for r in rows}
    assert (out / "calibration-report.pdf").stat().st_size > 10_000
