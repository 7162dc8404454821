"""The two servers' options, each in a successful run with its effect asserted (issue 31; tests/test_cli_options.py maps them).

``stableins serve`` and ``stableins serve-sim`` run in processes of their own on the loopback interface; the tests
talk to them as clients do (HTTP, the platform protocol) and read what each option changed.  No wall-clock bound
decides a verdict: a server that does not start fails on its first line, and the one pacing check (``--realtime``)
is a lower bound that load can only lengthen.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.request
from pathlib import Path

import numpy as np
import pytest

from stableins import cli

ROOT = Path(__file__).resolve().parents[1]
TOKEN = "options-token-of-the-lab-0123456789"
#: Silence accepted from a server [s]: a bound against a hang only (the simulator sets itself up on its first request,
#: which takes seconds on a loaded machine; no verdict here depends on it).
LINK_TIMEOUT = 120.0


def _start(*argv: str) -> tuple[subprocess.Popen, str]:
    """Start ``stableins ARGV`` and return the process and its first stdout line (the address it serves on)."""
    env = {k: v for k, v in os.environ.items() if k != "STABLEINS_SERVE_TOKEN"}
    process = subprocess.Popen(
        [sys.executable, "-m", "stableins.cli", *argv], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, cwd=ROOT
    )
    assert process.stdout is not None
    line = process.stdout.readline()
    if not line.strip():
        process.kill()
        raise AssertionError(f"stableins {argv[0]} did not start: {process.communicate()[1]}")
    return process, line.strip()


def _stop(process: subprocess.Popen) -> tuple[str, str]:
    if process.poll() is None:
        process.terminate()
    out, err = process.communicate(timeout=60)
    return out, err


def _get(url: str, token: str | None = None) -> tuple[int, dict[str, str], bytes]:
    request = urllib.request.Request(url, headers={"authorization": f"Bearer {token}"} if token else {})
    try:
        with urllib.request.urlopen(request, timeout=LINK_TIMEOUT) as answer:
            return answer.status, dict(answer.headers), answer.read()
    except urllib.error.HTTPError as error:
        return error.code, dict(error.headers), error.read()


# --------------------------------------------------------------------------- serve
def test_serve_options_reach_the_server(tmp_path):
    pytest.importorskip("uvicorn", reason="stableins serve needs the web extra: pip install -e '.[test]'")
    from test_history_store import record

    from stableins.history_store import HistoryStore
    from stableins.procedures.journal import Journal

    store = HistoryStore(tmp_path / "store")
    for serial, day in (("UNIT-A", 10), ("UNIT-B", 20)):
        record(serial, day).save(tmp_path / f"{serial}.json")
        store.add(tmp_path / f"{serial}.json")
    run = tmp_path / "runs" / "day1" / "r1"
    run.mkdir(parents=True)
    step = {"name": "check", "kind": "dwell", "stage": "fine", "pass_number": 1, "position": 7, "settle": 2.0, "dwell": 10.0}
    (run / "procedure.json").write_text(json.dumps({"name": "p", "sample_rate": 10.0, "chunk": 1.0, "steps": [step]}), encoding="utf-8")
    Journal.create(run / "journal.bin", ("start", {"unit": "UNIT-R", "utc": "2026-01-01T00:00:00+00:00"}))
    policy = tmp_path / "policy.toml"
    policy.write_text("[interval]\ndefault = 36500\n", encoding="utf-8")
    token = tmp_path / "token.txt"
    token.write_text(TOKEN + "\n", encoding="utf-8")
    argv = ["serve", "--store", str(tmp_path / "store"), "--runs", str(tmp_path / "runs"), "--policy", str(policy), "--host", "127.0.0.2",
            "--port", "0", "--token-file", str(token), "--rate", "0.001", "--burst", "6", "--secure-cookie"]  # fmt: skip
    process, line = _start(*argv)
    try:
        assert line.startswith("serving on http://127.0.0.2:")  # --host, --port 0: a free port of the address given
        url = line.split()[-1]
        port = int(url.rsplit(":", 1)[1])
        with pytest.raises(OSError):  # --host: bound to 127.0.0.2 only, not to 127.0.0.1
            socket.create_connection(("127.0.0.1", port), timeout=10).close()
        assert _get(f"{url}/api/fleet")[0] == 401  # --token-file: a request without the token is refused
        status, _, body = _get(f"{url}/api/fleet", TOKEN)
        fleet = json.loads(body)
        assert status == 200 and {u["serial"] for u in fleet["shown"]} == {"UNIT-A", "UNIT-B"}  # --store
        assert fleet["interval_source"] == str(policy) and fleet["overdue"] == 0  # --policy: 100-year intervals, nothing due
        status, _, body = _get(f"{url}/api/runs", TOKEN)
        assert status == 200 and "UNIT-R" in body.decode()  # --runs: the run below the root
        status, headers, _ = _get(f"{url}/fleet?token={TOKEN}")
        cookie = next(v for k, v in headers.items() if k.lower() == "set-cookie")
        assert status == 200 and "Secure" in cookie and "HttpOnly" in cookie  # --secure-cookie
        # --burst 6 at --rate 0.001/s: the four requests above and two more pass, the next is refused
        codes = [_get(f"{url}/api/runs", TOKEN)[0] for _ in range(3)]
        assert codes == [200, 200, 429]
    finally:
        _stop(process)
    assert process.returncode in (0, -signal.SIGTERM)  # it served until stopped (uvicorn ≥ 0.29 re-raises the SIGTERM after shutdown)


def test_serve_refuses_json_and_quiet(capsys):
    """A server has no result document and draws no progress: --json and --quiet are refused, not ignored (issue 31)."""
    for command in ("serve", "serve-sim"):
        for option in ("--json",) + (("--quiet",) if command == "serve" else ()):
            assert cli.main([command, "--port", "0", option]) == 2
            assert f"unrecognized arguments: {option}" in capsys.readouterr().err


# --------------------------------------------------------------------------- serve-sim
def _truth_file(tmp_path: Path) -> tuple[Path, object]:
    from stableins.data.truth import save_truth
    from stableins.simulator.truth import Truth

    truth = Truth.draw(17)
    path = tmp_path / "truth.json"
    save_truth(truth, path)
    return path, truth


def _pitch(port: int) -> np.ndarray:
    from stableins.drivers.tcp import TcpDriver

    driver = TcpDriver("127.0.0.1", port, timeout=LINK_TIMEOUT)
    try:
        columns = [c for c in driver.static_record(20.0, 10.0)]
    finally:
        driver.close()
    return np.concatenate([c["pitch"] for c in columns])


def test_serve_sim_options_reach_the_platform(tmp_path, ws_record):
    from stableins.drivers.tcp import TcpDriver

    argv = ["serve-sim", "--port", "0", "--seed", "23", "--unit", "OPT-7", "--rate", "5", "--connections", "1", "--realtime", "1"]
    process, line = _start(*argv)
    try:
        assert line.startswith("listening on 127.0.0.1:")  # --port 0
        driver = TcpDriver("127.0.0.1", int(line.rsplit(":", 1)[1]), timeout=LINK_TIMEOUT)
        platform = driver.status()["platform"]
        assert (platform["seed"], platform["serial_number"]) == (23, "OPT-7")  # --seed, --unit
        assert driver.metadata.sample_rate == 5.0  # --rate
        start = time.monotonic()
        block = driver.acquire(2.0)
        assert time.monotonic() - start >= 1.5  # --realtime 1: two seconds of samples take (at least) two seconds
        assert len(block.time) == 10  # at --rate 5 Hz
        driver.close()
        assert process.wait(timeout=60) == 0  # --connections 1: it stops after its one client
    finally:
        _, err = _stop(process)
    assert "serve-sim: client" in err  # connections are logged without --quiet

    truth_path, truth = _truth_file(tmp_path)
    process, line = _start("serve-sim", "--port", "0", "--truth", str(truth_path), "--connections", "1", "--quiet")
    try:
        driver = TcpDriver("127.0.0.1", int(line.rsplit(":", 1)[1]), timeout=LINK_TIMEOUT)
        platform = driver.status()["platform"]
        assert (platform["seed"], platform["serial_number"]) == (truth.seed, truth.site.serial_number)  # --truth: its world
        driver.close()
        assert process.wait(timeout=60) == 0
    finally:
        _, err = _stop(process)
    assert "serve-sim:" not in err  # --quiet: no connection logged

    pitches = []
    for extra in ([], ["--installed", str(ws_record)]):
        process, line = _start("serve-sim", "--port", "0", "--seed", "5", "--connections", "1", "--quiet", *extra)
        try:
            pitches.append(_pitch(int(line.rsplit(":", 1)[1])))
            assert process.wait(timeout=60) == 0
        finally:
            _stop(process)
    # --installed: the INS navigates with that record, so the same world's pitch output differs
    assert pitches[0].shape == pitches[1].shape and not np.allclose(pitches[0], pitches[1], rtol=0, atol=1e-12)


@pytest.fixture()
def ws_record(tmp_path):
    import fuzzing as fz

    path = tmp_path / "installed.json"
    fz._record("SIM-1").save(path)
    return path
