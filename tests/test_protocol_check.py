"""``stableins protocol-check`` (issue 27): passes on ``serve-sim`` and names the failing clause of each faulty controller.

Each faulty controller is ``serve-sim`` behind a small in-process proxy on 127.0.0.1 that rewrites, delays or drops
the lines it sends (one fault per proxy): a wrong CRC, a missing reply, out-of-order ids, a slow stream, a wrong
version, ...  The check must report that clause as failed (not merely "not reached").
"""

from __future__ import annotations

import contextlib
import socket
import threading
import time
from collections.abc import Callable

import pytest

from stableins import cli
from stableins.drivers.conformance import CLAUSES, ConformanceCheck
from stableins.drivers.tcp import TcpDriver
from tests.tcp_fixtures import ServerProcess

TIMEOUT = 2.0  # silence accepted by the check [s]; the faults that stall stall longer


@pytest.fixture(scope="module")
def upstream():
    with ServerProcess(seed=4, simulator=True, unit="CHECK-1", rate=20.0) as server:
        warm = TcpDriver("127.0.0.1", server.port, timeout=60)
        warm.acquire(0.2)  # the simulator sets itself up on the first acquisition: not the proxies' time
        warm.close()
        yield server


Fault = Callable[[str, dict], list]


class Proxy:
    """127.0.0.1 ↔ upstream; every line the upstream sends goes through ``fault(line, state)``, which returns what to send
    instead: lines, and numbers (seconds to wait first).  ``state`` holds ``verbs`` (request id → verb, from the client's
    lines), ``connection`` (its number, from 1) and ``count`` of lines per verb so far."""

    def __init__(self, upstream_port: int, fault: Fault) -> None:
        self.upstream_port, self.fault = upstream_port, fault
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.port = self.listener.getsockname()[1]
        self.state: dict = {"verbs": {}, "connection": 0, "count": {}}
        self.sockets: list[socket.socket] = []
        threading.Thread(target=self._accept, daemon=True).start()

    def _accept(self) -> None:
        while True:
            try:
                client, _ = self.listener.accept()
            except OSError:
                return
            upstream = socket.create_connection(("127.0.0.1", self.upstream_port))
            self.sockets += [client, upstream]
            self.state["connection"] += 1
            threading.Thread(target=self._requests, args=(client, upstream), daemon=True).start()
            threading.Thread(target=self._replies, args=(upstream, client), daemon=True).start()

    def _requests(self, client: socket.socket, upstream: socket.socket) -> None:
        with contextlib.suppress(OSError):
            for line in client.makefile("r", encoding="ascii", newline="\n"):
                words = line.split()
                if len(words) >= 2:
                    self.state["verbs"][words[0]] = words[1]
                upstream.sendall(line.encode("ascii"))
        with contextlib.suppress(OSError):
            upstream.shutdown(socket.SHUT_RDWR)

    def _replies(self, upstream: socket.socket, client: socket.socket) -> None:
        with contextlib.suppress(OSError):
            for line in upstream.makefile("r", encoding="ascii", newline="\n"):
                for item in self.fault(line.rstrip("\n"), self.state):
                    if isinstance(item, int | float):
                        time.sleep(item)
                    else:
                        client.sendall((item + "\n").encode("ascii"))
        with contextlib.suppress(OSError):
            client.shutdown(socket.SHUT_RDWR)

    def close(self) -> None:
        self.listener.close()
        for s in self.sockets:
            with contextlib.suppress(OSError):
                s.close()


def _verb(line: str, state: dict) -> str:
    """The verb of the request a reply line answers ('' for sample lines and the greeting)."""
    word = line.split(" ", 1)[0]
    return state["verbs"].get(word, "") if word.isdigit() else ""


def _counted(state: dict, key: str) -> int:
    state["count"][key] = state["count"].get(key, 0) + 1
    return state["count"][key]


def wrong_crc(line, state):
    words = line.split(" ")
    if len(words) == 4 and words[1] == "END" and _verb(line, state) == "ACQ":
        return [" ".join([*words[:3], "deadbeef"])]
    return [line]


def missing_reply(line, state):
    return [] if _verb(line, state) == "ANG" and _counted(state, "ang") == 1 else [line]


def out_of_order_ids(line, state):
    if _verb(line, state) == "META":
        request, rest = line.split(" ", 1)
        return [f"{int(request) + 1} {rest}"]
    return [line]


def slow_stream(line, state):
    return [0.5, line] if line.startswith("S ") else [line]


def wrong_version(line, state):
    return ["STABLEINS-PLATFORM 7 NAV"] if line.startswith("STABLEINS-PLATFORM") else [line]


def no_error_reply(line, state):
    words = line.split(" ", 2)
    if len(words) > 2 and words[1] == "ERR":
        return [f"{words[0]} OK"]
    return [line]


def count_too_large(line, state):
    words = line.split(" ")
    if _verb(line, state) == "ACQ" and len(words) == 3 and words[1] == "OK":
        return [f"{words[0]} OK 5000"]
    return [line]


def bad_sample_line(line, state):
    return [line.rsplit(" ", 1)[0]] if line.startswith("S ") else [line]


def clock_runs_back(line, state):
    if line.startswith("S "):
        words = line.split(" ")
        if state["count"].get("acq-ok", 0) >= 2:
            words[1] = repr(float(words[1]) - 100.0)
        return [" ".join(words)]
    if _verb(line, state) == "ACQ" and line.split(" ")[1] == "OK":
        _counted(state, "acq-ok")
    return [line]


def state_lost_on_reconnect(line, state):
    if _verb(line, state) == "ANG" and state["connection"] >= 4:
        request, ok, first, rest = line.split(" ", 3)
        return [f"{request} {ok} {float(first) + 0.01!r} {rest}"]
    return [line]


def resend_refused(line, state):
    if _verb(line, state) == "CMD" and _counted(state, "cmd") == 2:
        return [f"{line.split(' ', 1)[0]} ERR driver busy"]
    return [line]


def nav_field_missing(line, state):
    return [line.rsplit(" ", 1)[0]] if line.startswith("N ") else [line]


def ang_not_decimal(line, state):
    if _verb(line, state) == "ANG":
        request, ok, first, rest = line.split(" ", 3)
        return [f"{request} {ok} 1_0 {rest}"]
    return [line]


def meta_not_json(line, state):
    return [f"{line.split(' ', 1)[0]} OK {{site: ?"] if _verb(line, state) == "META" else [line]


FAULTS = {
    "crc": wrong_crc,
    "timing": missing_reply,
    "ids": out_of_order_ids,
    "greeting": wrong_version,
    "error-replies": no_error_reply,
    "acq-count": count_too_large,
    "acq": bad_sample_line,
    "clock": clock_runs_back,
    "reconnect": state_lost_on_reconnect,
    "idempotent": resend_refused,
    "nav": nav_field_missing,
    "ang": ang_not_decimal,
    "meta": meta_not_json,
}


def _check(port: int) -> dict:
    results = ConformanceCheck("127.0.0.1", port, envelope=0.02, timeout=TIMEOUT, duration=0.5).run()
    assert [r.clause for r in results] == list(CLAUSES)
    return {r.clause: r for r in results}


def test_serve_sim_conforms(upstream, capsys):
    results = _check(upstream.port)
    assert all(r.passed for r in results.values()), [r.describe() for r in results.values() if not r.passed]
    assert cli.main(["protocol-check", f"tcp://127.0.0.1:{upstream.port}", "--envelope", "1"]) == 0
    out = capsys.readouterr().out
    assert "CONFORMS: every clause passed" in out and out.count("PASS ") == len(CLAUSES)


def test_protocol_check_options_duration_timeout_json_quiet(upstream, capsys, monkeypatch):
    """Issue 31: --duration sets the length of the test acquisitions, --timeout the silence accepted; --json, --quiet."""
    import json

    from test_cli_options_quiet import quiet_main

    samples: dict[str, int] = {}

    def counted(key: str) -> Fault:
        def fault(line, state):
            samples[key] = samples.get(key, 0) + line.startswith("S ")
            return [line]

        return fault

    for duration in ("0.25", "1"):
        proxy = Proxy(upstream.port, counted(duration))
        try:
            argv = ["protocol-check", f"tcp://127.0.0.1:{proxy.port}", "--envelope", "1", "--duration", duration, "--json"]
            assert cli.main(argv) == 0
        finally:
            proxy.close()
        document = json.loads(capsys.readouterr().out)  # --json: one document, every clause passed
        assert document["conforms"] and [c["clause"] for c in document["clauses"]] == list(CLAUSES)
    assert samples["1"] == pytest.approx(4 * samples["0.25"], rel=0.2)  # --duration: 4x longer acquisitions, 4x the samples

    def late_angles(line, state):  # every ANG reply 0.6 s late: beyond a 0.3 s --timeout, well within 60 s
        return [0.6, line] if state["verbs"].get(line.split(" ", 1)[0]) == "ANG" else [line]

    for timeout, expected in (("0.3", 1), ("60", 0)):
        proxy = Proxy(upstream.port, late_angles)
        try:
            argv = ["protocol-check", f"tcp://127.0.0.1:{proxy.port}", "--envelope", "1", "--timeout", timeout, "--quiet"]
            status, out, _, seen = quiet_main(monkeypatch, argv, "stableins.commands.protocol_check")
        finally:
            proxy.close()
        assert status == expected and seen == [True], out  # --timeout; --quiet: silenced while it works
    assert "CONFORMS: every clause passed" in out


@pytest.mark.parametrize("clause", sorted(FAULTS))
def test_a_faulty_controller_fails_the_clause_it_breaks(upstream, clause):
    proxy = Proxy(upstream.port, FAULTS[clause])
    try:
        results = _check(proxy.port)
    finally:
        proxy.close()
    result = results[clause]
    assert result.passed is False and not result.detail.startswith("not reached"), [r.describe() for r in results.values()]


def test_slow_stream_fails_timing(upstream, capsys):
    proxy = Proxy(upstream.port, slow_stream)
    try:
        status = cli.main(["protocol-check", f"tcp://127.0.0.1:{proxy.port}", "--envelope", "1", "--timeout", str(TIMEOUT)])
    finally:
        proxy.close()
    out = capsys.readouterr().out
    assert status == 1 and "FAIL timing" in out and "DOES NOT CONFORM: failed" in out, out
