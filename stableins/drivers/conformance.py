"""Conformance of a platform controller to docs/protocol.md (``stableins protocol-check tcp://HOST:PORT``).

A controller vendor runs it against an implementation before it moves a unit under calibration: every clause of
the protocol is exercised over a raw connection (not through the driver, which would hide what it tolerates) and
reported pass or fail with what was received.  The platform moves only within the envelope the user gives: the
gimbals are commanded to at most ``envelope`` from where they are found (half of it, on the inner axis) and back.

Clauses, in order (:data:`CLAUSES`): the greeting and version; each request and its reply (``META``, ``ANG``,
``CMD``, ``ACQ`` with its count, numbers, times, trailer and CRC-32); error replies (an unknown verb, a malformed
request); request ids; timing (every reply within ``timeout``, an ``ACQ`` within ``timeout + 2 × duration``);
reconnection (the platform's state survives it) and idempotent resend (a ``CMD`` sent twice); the navigation stream
(``REC``/``NAV``, when the greeting states ``NAV``).
"""

from __future__ import annotations

import contextlib
import json
import math
import re
import socket
import time
import zlib
from collections.abc import Callable
from dataclasses import dataclass

from stableins.drivers.server import NAV_CAPABILITY, NAV_FIELDS
from stableins.drivers.tcp import ACQ_COUNT_MARGIN, ACQ_COUNT_SLACK, ACQ_TIME_FACTOR, parse_greeting
from stableins.errors import InputError, NotDeterminedError

#: The clauses of docs/protocol.md the check reports, with what each requires.
CLAUSES: dict[str, str] = {
    "greeting": "the greeting is 'STABLEINS-PLATFORM <version> [<capability> ...]' of a known version",
    "meta": "META answers '<id> OK <json>' with site metadata (serial_number, sample_rate > 0, ...)",
    "ang": "ANG answers three finite decimal numbers",
    "cmd": "CMD answers the session time it was issued (a finite number)",
    "acq": "ACQ answers '<id> OK <n>', n sample lines 'S' + 8 numbers with increasing times, then '<id> END <n> <crc32>'",
    "acq-count": "an ACQ's count is a whole number within 1.1 x duration x rate + 16 and at least half of duration x rate",
    "crc": "the END trailer's CRC-32 is that of the sample lines, newlines included",
    "error-replies": "an unknown verb and a malformed request are answered '<id> ERR protocol ...' and the session goes on",
    "ids": "every reply carries the id of its request",
    "timing": "every reply within timeout; an ACQ within timeout + 2 x duration",
    "clock": "sample times increase across acquisitions",
    "reconnect": "after a reconnection the platform is where it was left (ANG unchanged)",
    "idempotent": "a CMD sent again (as after a lost reply) is answered again and leaves the platform at the same command",
    "nav": "with NAV stated: REC answers OK and NAV chunks of 'N' + 14 numbers with increasing times and a matching trailer",
}
_NUMBER = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?", re.ASCII)


class ClauseFailure(Exception):
    """A clause of the protocol that the controller broke (``clause``: a key of :data:`CLAUSES`)."""

    def __init__(self, clause: str, message: str) -> None:
        super().__init__(message)
        self.clause = clause


@dataclass(frozen=True)
class ClauseResult:
    """The verdict on one clause: ``passed`` (True, False, or None when not applicable) and what was seen."""

    clause: str
    passed: bool | None
    detail: str

    def describe(self) -> str:
        """Return the report line: ``PASS``/``FAIL``/``N/A``, the clause, what it requires or what broke it."""
        mark = {True: "PASS", False: "FAIL", None: "N/A "}[self.passed]
        return f"{mark} {self.clause:<13} {self.detail}"


class _Link:
    """A raw connection to the controller: lines in and out, every read against a deadline."""

    def __init__(self, host: str, port: int, timeout: float) -> None:
        self.timeout = timeout
        self.socket = socket.create_connection((host, port), timeout=timeout)
        self.buffer = b""
        self.next_id = 1

    def line(self, deadline: float, clause: str) -> str:
        while b"\n" not in self.buffer:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise ClauseFailure("timing", f"no complete reply in time ({clause})")
            self.socket.settimeout(min(self.timeout, remaining))
            try:
                chunk = self.socket.recv(65536)
            except TimeoutError:
                raise ClauseFailure("timing", f"silent for {self.timeout:g} s waiting for a reply ({clause})") from None
            if not chunk:
                raise ClauseFailure(clause, "the controller closed the connection")
            self.buffer += chunk
        raw, _, self.buffer = self.buffer.partition(b"\n")
        try:
            return raw.decode("ascii").rstrip("\r")
        except UnicodeDecodeError:
            raise ClauseFailure(clause, f"non-ASCII bytes {raw[:40]!r}") from None

    def request(self, verb: str, *arguments: str) -> int:
        request_id = self.next_id
        self.next_id += 1
        self.socket.sendall((" ".join((str(request_id), verb, *arguments)) + "\n").encode("ascii"))
        return request_id

    def reply(self, request_id: int, clause: str, deadline: float | None = None) -> tuple[str, str]:
        """Return (status, payload) of the reply to ``request_id`` (status OK or ERR)."""
        line = self.line(deadline if deadline is not None else time.monotonic() + self.timeout, clause)
        words = line.split(" ", 2)
        if not words[0].isdigit():
            raise ClauseFailure(clause, f"reply {line[:60]!r} does not start with a request id")
        if int(words[0]) != request_id:
            raise ClauseFailure("ids", f"reply {line[:60]!r} to request {request_id}")
        if len(words) < 2 or words[1] not in ("OK", "ERR"):
            raise ClauseFailure(clause, f"reply {line[:60]!r} is neither OK nor ERR")
        return words[1], words[2] if len(words) > 2 else ""

    def close(self) -> None:
        with contextlib.suppress(OSError):
            self.socket.close()


def _numbers(text: str, count: int, clause: str) -> list[float]:
    words = text.split(" ")
    if len(words) != count or not all(_NUMBER.fullmatch(w) for w in words):
        raise ClauseFailure(clause, f"{text[:80]!r} is not {count} decimal numbers")
    values = [float(w) for w in words]
    if not all(math.isfinite(v) for v in values):
        raise ClauseFailure(clause, f"{text[:80]!r} holds a non-finite number")
    return values


class ConformanceCheck:
    """Run the clauses of :data:`CLAUSES` against ``tcp://host:port`` (:meth:`run`), moving within ``envelope`` [rad]."""

    def __init__(self, host: str, port: int, *, envelope: float, timeout: float = 10.0, duration: float = 0.5) -> None:
        self.host, self.port = host, port
        self.envelope = envelope
        self.timeout = timeout
        self.duration = duration
        self.results: dict[str, ClauseResult] = {}
        self.capabilities: frozenset[str] = frozenset()
        self.rate = 0.0
        self.last_time = -math.inf

    # ------------------------------------------------------------------ driving
    def run(self) -> list[ClauseResult]:
        """Check every clause; return the results in the order of :data:`CLAUSES` (a clause not reached: FAIL, naming why)."""
        steps: list[tuple[tuple[str, ...], Callable[[], None]]] = [
            (("greeting",), self._greeting),
            (("meta", "ang", "cmd", "acq", "acq-count", "crc", "clock", "error-replies", "idempotent"), self._session),
            (("reconnect",), self._reconnect),
            (("nav",), self._navigation),
        ]
        for clauses, step in steps:
            try:
                step()
            except ClauseFailure as failure:
                self._fail(failure.clause, str(failure))
                for clause in clauses:  # what this step did not get to
                    if clause not in self.results:
                        self.results[clause] = ClauseResult(clause, False, f"not reached: {failure.clause} failed first")
            except OSError as error:
                for clause in clauses:
                    if clause not in self.results:
                        self.results[clause] = ClauseResult(clause, False, f"connection failed: {error}")
            if "greeting" in self.results and not self.results["greeting"].passed:
                break
        for clause in ("ids", "timing"):  # held by every reply so far
            self.results.setdefault(clause, ClauseResult(clause, True, CLAUSES[clause]))
        return [self.results.get(c, ClauseResult(c, False, "not reached: the greeting failed")) for c in CLAUSES]

    def _pass(self, clause: str, detail: str = "") -> None:
        self.results.setdefault(clause, ClauseResult(clause, True, detail or CLAUSES[clause]))

    def _fail(self, clause: str, detail: str) -> None:
        self.results[clause] = ClauseResult(clause, False, detail)

    def _open(self) -> _Link:
        link = _Link(self.host, self.port, self.timeout)
        greeting = link.line(time.monotonic() + self.timeout, "greeting")
        try:
            version, self.capabilities = parse_greeting(greeting)
        except (InputError, NotDeterminedError):
            raise  # a described error passes through as it is (issue 29)
        except ValueError as error:
            link.close()
            raise ClauseFailure("greeting", str(error)) from None
        self._pass("greeting", f"version {version}, capabilities: {' '.join(sorted(self.capabilities)) or 'none'}")
        return link

    # ------------------------------------------------------------------ clauses
    def _greeting(self) -> None:
        self._open().close()

    def _session(self) -> None:
        link = self._open()
        try:
            self._meta(link)
            start = self._angles(link)
            self._acquire(link)
            target = [start[0], start[1] + 0.5 * self.envelope, start[2]]  # within the envelope: half of it, inner axis
            self._command(link, target)
            self._idempotent(link, target)
            self._acquire(link)
            self._command(link, start)  # back where it was found
            self._errors(link)
        finally:
            link.close()

    def _meta(self, link: _Link) -> None:
        status, payload = link.reply(link.request("META"), "meta")
        if status != "OK":
            raise ClauseFailure("meta", f"META refused: {payload[:80]}")
        try:
            meta = json.loads(payload)
        except ValueError:
            raise ClauseFailure("meta", f"{payload[:80]!r} is not JSON") from None
        rate = meta.get("sample_rate") if isinstance(meta, dict) else None
        if not isinstance(meta, dict) or not isinstance(meta.get("serial_number"), str) or not isinstance(rate, int | float) or rate <= 0:
            raise ClauseFailure("meta", "the metadata lack a serial_number or a positive sample_rate")
        self.rate = float(rate)
        self._pass("meta", f"unit {meta['serial_number']}, {self.rate:g} Hz")

    def _angles(self, link: _Link) -> list[float]:
        status, payload = link.reply(link.request("ANG"), "ang")
        if status != "OK":
            raise ClauseFailure("ang", f"ANG refused: {payload[:80]}")
        angles = _numbers(payload, 3, "ang")
        self._pass("ang")
        return angles

    def _command(self, link: _Link, readings: list[float]) -> float:
        status, payload = link.reply(link.request("CMD", *(repr(float(r)) for r in readings)), "cmd")
        if status != "OK":
            raise ClauseFailure("cmd", f"CMD within the envelope refused: {payload[:80]}")
        (issued,) = _numbers(payload, 1, "cmd")
        self._pass("cmd")
        return issued

    def _idempotent(self, link: _Link, target: list[float]) -> None:
        """Send the same CMD again, as a client does after a lost reply: answered again, the platform commanded the same."""
        status, payload = link.reply(link.request("CMD", *(repr(float(r)) for r in target)), "idempotent")
        if status != "OK":
            raise ClauseFailure("idempotent", f"the same CMD sent again was refused: {payload[:80]}")
        _numbers(payload, 1, "idempotent")
        self._pass("idempotent")

    def _acquire(self, link: _Link) -> None:
        duration = self.duration
        deadline = time.monotonic() + self.timeout + ACQ_TIME_FACTOR * duration
        request_id = link.request("ACQ", repr(duration))
        status, payload = link.reply(request_id, "acq", deadline)
        if status != "OK":
            raise ClauseFailure("acq", f"ACQ refused: {payload[:80]}")
        limit = int(math.ceil(ACQ_COUNT_MARGIN * duration * self.rate)) + ACQ_COUNT_SLACK
        if not payload.isdigit() or not 0.5 * duration * self.rate <= int(payload) <= limit:
            raise ClauseFailure("acq-count", f"count {payload[:20]!r} for {duration:g} s at {self.rate:g} Hz (expected about "
                                             f"{duration * self.rate:g}, at most {limit})")  # fmt: skip
        count = int(payload)
        self._pass("acq-count")
        crc = 0
        previous = self.last_time
        for k in range(count):
            line = link.line(deadline, "acq")
            crc = zlib.crc32((line + "\n").encode("ascii"), crc)
            if not line.startswith("S "):
                raise ClauseFailure("acq", f"sample {k + 1} of {count} is {line[:60]!r}")
            t = _numbers(line[2:], 8, "acq")[0]
            if not t > previous:
                clause = "acq" if k else "clock"
                raise ClauseFailure(clause, f"sample {k + 1} of {count} has time {t!r} s, not after {previous!r} s")
            previous = t
        self.last_time = previous
        end = link.line(deadline, "acq").split(" ")
        if end[:3] != [str(request_id), "END", str(count)] or len(end) != 4:
            raise ClauseFailure("acq", f"trailer {' '.join(end)[:60]!r} (expected '{request_id} END {count} <crc32>')")
        if end[3] != f"{crc:08x}":
            raise ClauseFailure("crc", f"trailer CRC {end[3][:12]!r}, the sample lines' is {crc:08x}")
        for clause in ("acq", "crc", "clock"):
            self._pass(clause)

    def _errors(self, link: _Link) -> None:
        for verb, arguments, what in (("FROBNICATE", (), "an unknown verb"), ("CMD", ("0.0",), "CMD with one reading")):
            status, payload = link.reply(link.request(verb, *arguments), "error-replies")
            if status != "ERR" or not payload.startswith("protocol"):
                raise ClauseFailure("error-replies", f"{what} answered {status} {payload[:60]!r} (expected ERR protocol ...)")
        self._angles(link)  # the session goes on
        self._pass("error-replies")

    def _reconnect(self) -> None:
        link = self._open()
        try:
            before = self._angles(link)
        finally:
            link.close()
        link = self._open()
        try:
            after = self._angles(link)
        finally:
            link.close()
        if max(abs(a - b) for a, b in zip(before, after, strict=True)) > 1e-6:
            raise ClauseFailure("reconnect", f"angles {before} before the reconnection, {after} after (the platform's state was lost)")
        self._pass("reconnect")

    def _navigation(self) -> None:
        if NAV_CAPABILITY not in self.capabilities:
            self.results["nav"] = ClauseResult("nav", None, "the greeting does not state NAV (device level only)")
            return
        link = self._open()
        try:
            chunk = self.duration
            status, payload = link.reply(link.request("REC", json.dumps({"duration": 2 * chunk, "chunk": chunk, "turns": []})), "nav")
            if status != "OK":
                raise ClauseFailure("nav", f"REC refused: {payload[:80]}")
            previous = -math.inf
            for _ in range(2):
                deadline = time.monotonic() + self.timeout + ACQ_TIME_FACTOR * chunk
                request_id = link.request("NAV")
                status, payload = link.reply(request_id, "nav", deadline)
                if status != "OK" or not payload.isdigit():
                    raise ClauseFailure("nav", f"NAV answered {status} {payload[:60]!r}")
                count, crc = int(payload), 0
                for k in range(count):
                    line = link.line(deadline, "nav")
                    crc = zlib.crc32((line + "\n").encode("ascii"), crc)
                    if not line.startswith("N "):
                        raise ClauseFailure("nav", f"navigation sample {k + 1} of {count} is {line[:60]!r}")
                    t = _numbers(line[2:], len(NAV_FIELDS), "nav")[0]
                    if not t > previous:
                        raise ClauseFailure("nav", f"navigation sample {k + 1} has time {t!r} s, not after {previous!r} s")
                    previous = t
                end = link.line(deadline, "nav").split(" ")
                if end != [str(request_id), "END", str(count), f"{crc:08x}"]:
                    raise ClauseFailure("nav", f"trailer {' '.join(end)[:60]!r} (expected '{request_id} END {count} {crc:08x}')")
            self._pass("nav", f"REC and 2 NAV chunks of {len(NAV_FIELDS)} columns")
        finally:
            link.close()


__all__ = ["CLAUSES", "ClauseFailure", "ClauseResult", "ConformanceCheck"]
