"""``--quiet`` of every command in a successful run with its effect asserted (issue 31; tests/test_cli_options.py maps them).

``--quiet`` means: no progress bar, even on a terminal (``stableins.progress``).  Each command runs for real with
stderr a terminal double; the command's own ``run`` is wrapped (not replaced) to see whether :func:`silenced` is in
force while it works, and no bar may reach the terminal.  The control test shows a bar does reach that terminal
double without ``--quiet``, so the absence of one is evidence.
"""

from __future__ import annotations

import contextlib
import importlib
import io
import json
from pathlib import Path

import pytest

from stableins import cli, progress

#: What a drawn bar always shows (stableins.progress.BAR_FORMAT / COUNT_FORMAT): ``eta`` or ``done`` after the label.
BAR_MARKS = (" eta ", " done ")


class Terminal(io.StringIO):
    """A stderr that says it is a terminal, so progress bars are drawn into it unless silenced."""

    def isatty(self) -> bool:
        return True


def quiet_main(monkeypatch, argv: list, module: str) -> tuple[int, str, str, list[bool]]:
    """Run ``stableins ARGV`` with stderr a terminal; return status, stdout, stderr and ``silenced()`` as ``run`` began."""
    target = importlib.import_module(module)
    seen: list[bool] = []
    original = target.run

    def watched(args):
        seen.append(progress.silenced())
        return original(args)

    monkeypatch.setattr(target, "run", watched)
    out, err = io.StringIO(), Terminal()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        status = cli.main([str(a) for a in argv])
    return status, out.getvalue(), err.getvalue(), seen


@pytest.fixture(scope="module")
def ws(fuzz_workspace):
    return fuzz_workspace  # tests/conftest.py: built once per process


def test_a_terminal_sees_the_bar_and_quiet_removes_it(monkeypatch, tmp_path):
    """The control: simulate draws its bar on the terminal double; with --quiet none, and the same data."""
    import h5py
    import numpy as np

    base = ["simulate", "system", "--duration", "600", "--rate", "1", "--seed", "3"]
    status, _, err, seen = quiet_main(monkeypatch, [*base, "--out", tmp_path / "loud"], "stableins.commands.simulate")
    assert status == 0 and seen == [False] and any(mark in err for mark in BAR_MARKS), err[-500:]
    status, _, err, seen = quiet_main(monkeypatch, [*base, "--out", tmp_path / "quiet", "--quiet"], "stableins.commands.simulate")
    assert status == 0 and seen == [True] and not any(mark in err for mark in BAR_MARKS), err[-500:]
    with h5py.File(tmp_path / "loud" / "system.h5", "r") as loud, h5py.File(tmp_path / "quiet" / "system.h5", "r") as quiet:
        names = list(loud["columns"])
        assert names and all(np.array_equal(loud["columns"][n][...], quiet["columns"][n][...]) for n in names)  # same data


def _cases(ws, tmp: Path) -> dict[str, tuple[list, str]]:
    return {
        "budget": (["budget", ws.record, "--latitude", "40", "--duration", "5d"], "budget"),
        "calibrate device": (["calibrate", "device", ws.device_csv, "--out", tmp / "d.json"], "calibrate_device"),
        "calibrate system": (["calibrate", "system", ws.system_h5, "--prior", ws.record, "--out", tmp / "s.json"], "calibrate_system"),
        "check": (["check", ws.record], "check"),
        "design": (["design", "device-coarse", "--white", "4.5e-4"], "design"),
        "diagnose": (["diagnose", ws.device_csv, "--record", ws.record], "diagnose"),
        "history": (["history", ws.serial, "--store", tmp / "store", "--add", ws.record], "history"),
        "noise": (["noise", ws.system_h5], "noise"),
        "report": (["report", ws.record, "--out", tmp / "r.pdf"], "report"),
    }


@pytest.mark.parametrize(
    "command", ["budget", "calibrate device", "calibrate system", "check", "design", "diagnose", "history", "noise", "report"]
)
def test_quiet_silences_the_command(monkeypatch, tmp_path, ws, command):
    argv, module = _cases(ws, tmp_path)[command]
    status, out, err, seen = quiet_main(monkeypatch, [*argv, "--quiet"], f"stableins.commands.{module}")
    assert status == 0, err[-1000:]
    assert seen == [True]  # --quiet: silenced while the command works
    assert not any(mark in err for mark in BAR_MARKS), err[-500:]  # and nothing drawn on the terminal
    assert out or err  # the command still says what it did (--quiet silences bars, not results)


def test_campaign_json_and_quiet(monkeypatch, tmp_path):
    """campaign --json prints one summary document; --quiet keeps the terminal free of bars."""
    from test_campaign import _config

    config = _config(tmp_path, devices=1)
    argv = ["campaign", config, "--out", tmp_path / "out", "--workers", "1", "--no-plot", "--json", "--quiet"]
    status, out, err, seen = quiet_main(monkeypatch, argv, "stableins.commands.campaign")
    assert status == 0, err[-1000:]
    document = json.loads(out)  # --json: exactly one document on stdout
    assert (document["tasks"], document["ran"], document["workers"]) == (1, 1, 1)  # --workers 1
    assert all(Path(f).exists() for f in document["files"]) and not any(f.endswith(".png") for f in document["files"])  # --no-plot
    assert seen == [True] and not any(mark in err for mark in BAR_MARKS)


@pytest.mark.parametrize("flags", [[], ["--quiet"], ["--json"]])
def test_demo_quiet_reaches_every_step(monkeypatch, tmp_path, flags):
    """demo --quiet (or --json) runs its steps with --quiet: they share the demo's terminal and would draw bars on it.

    The steps are processes of their own; the first one is stood in for by a process that fails, so the demo stops
    there (exit 3, as a failed step stops it) after showing which command line it started.
    """
    import subprocess

    started: list[list[str]] = []

    def fake_run(argv, **kwargs):
        started.append([str(a) for a in argv])
        return subprocess.CompletedProcess(argv, 3, stdout="")

    monkeypatch.setattr(subprocess, "run", fake_run)
    out, err = io.StringIO(), Terminal()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        status = cli.main(["demo", "--out", str(tmp_path / "demo"), *flags])
    assert status == 3 and len(started) == 1  # the failed step's status, nothing after it
    assert started[0][-7:-1] == ["simulate", "device", "--seed", "2018", "--out", str(tmp_path / "demo")] or flags == []
    assert (started[0][-1] == "--quiet") == bool(flags), started[0]  # --quiet / --json: the step is silenced too
    assert not any(mark in err.getvalue() for mark in BAR_MARKS)
