"""TCP client for a platform speaking the line-based ASCII protocol of ``docs/protocol.md``.

Failure handling, in one place:

* every read and write has a timeout (``timeout`` seconds of silence, not of total time, so a
  long dwell whose samples keep streaming never times out);
* anything that is not the protocol (bad greeting, wrong request id, unparsable numbers, a
  sample count or CRC-32 that does not match) raises :class:`DriverProtocolError` and drops
  the connection, so a late or corrupted reply can never be mistaken for a later one;
* idempotent requests (``META``, ``CMD``, ``ANG``, ``STATUS``) are sent again once after a
  reconnect; an acquisition is not (time has moved on): it raises
  :class:`AcquisitionInterrupted` and the runner repeats the step;
* reconnects are bounded (``reconnect_attempts`` tries, ``reconnect_delay`` apart).
"""

from __future__ import annotations

import contextlib
import math
import re
import socket
import time
import zlib
from collections.abc import Iterator
from typing import Any

import numpy as np
from numpy.typing import NDArray

from stableins.drivers.errors import AcquisitionInterrupted, DriverConnectionError, DriverError, DriverProtocolError
from stableins.drivers.server import (
    META_CRC_CAPABILITY,
    NAV_CAPABILITY,
    NAV_FIELDS,
    PROTOCOL_NAME,
    PROTOCOL_VERSION,
    format_float,
    metadata_checksum,
)
from stableins.errors import InputError, NotDeterminedError
from stableins.samples import SampleBlock
from stableins.site import SiteMetadata

#: Longest line accepted from the platform [characters] (a sample line is ~200).
MAX_REPLY_LINE = 65536
#: An ``ACQ`` reply must be complete within ``timeout + ACQ_TIME_FACTOR × duration`` seconds (a platform streams a
#: dwell in real time; twice that allows a slow link), any other reply within ``timeout``: a controller that
#: trickles bytes cannot hold a request for longer.
ACQ_TIME_FACTOR = 2.0
#: An ``ACQ`` may announce at most ``ACQ_COUNT_MARGIN × duration × rate + ACQ_COUNT_SLACK`` samples.
ACQ_COUNT_MARGIN = 1.1
ACQ_COUNT_SLACK = 16
_COUNT = re.compile(r"[0-9]{1,15}", re.ASCII)
#: A number of the protocol: decimal ASCII (Python's float() would also take ``1_0``).
_NUMBER = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?", re.ASCII)


def parse_address(spec: str) -> tuple[str, int]:
    """``tcp://HOST:PORT`` → ``(host, port)``; raises :class:`InputError` naming the parameter (``driver_spec``)."""
    rest = spec[len("tcp://") :] if spec.startswith("tcp://") else spec
    host, _, port = rest.rpartition(":")
    if not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise InputError(f"cannot read {spec!r} as a platform address", field="driver_spec", expected="tcp://HOST:PORT")
    return host.strip("[]"), int(port)


class TcpDriver:
    """:class:`~stableins.drivers.base.PlatformDriver` over TCP.

    Parameters
    ----------
    host, port : str, int
        Where the platform listens.
    timeout : float
        Longest silence accepted from the platform [s].
    reconnect_attempts : int
        Connection attempts before giving up (first connection and after a failure).
    reconnect_delay : float
        Pause between attempts [s].
    """

    deterministic = False

    def __init__(self, host: str, port: int, timeout: float = 10.0, reconnect_attempts: int = 5, reconnect_delay: float = 0.5) -> None:
        self.host, self.port = host, port
        self.timeout = timeout
        self.reconnect_attempts = max(1, int(reconnect_attempts))
        self.reconnect_delay = reconnect_delay
        self._socket: socket.socket | None = None
        self._buffer = b""
        self._next_id = 1
        self.reconnects = 0
        self._metadata: SiteMetadata | None = None
        #: protocol version and capabilities the platform's greeting states (docs/protocol.md)
        self.version, self.capabilities = 0, frozenset[str]()
        self._connect()

    # ------------------------------------------------------------------ link
    @property
    def address(self) -> str:
        """The ``tcp://host:port`` address of the platform."""
        return f"tcp://{self.host}:{self.port}"

    def _connect(self) -> None:
        last: Exception | None = None
        for attempt in range(self.reconnect_attempts):
            if attempt:
                time.sleep(self.reconnect_delay)
            try:
                sock = socket.create_connection((self.host, self.port), timeout=self.timeout)
            except OSError as error:
                last = error
                continue
            sock.settimeout(self.timeout)
            self._socket, self._buffer = sock, b""
            try:
                greeting = self._read_line(time.monotonic() + self.timeout)
            except DriverError as error:
                self._drop()
                last = error
                continue
            try:
                self.version, self.capabilities = parse_greeting(greeting)
            except (InputError, NotDeterminedError):
                raise  # a described error passes through as it is (issue 29)
            except ValueError as error:
                self._drop()
                raise DriverProtocolError(f"{self.address} is not a stableins platform: {error}") from None
            return
        raise DriverConnectionError(f"cannot connect to the platform at {self.address} after {self.reconnect_attempts} attempts: {last}")

    def _drop(self) -> None:
        if self._socket is not None:
            with contextlib.suppress(OSError):
                self._socket.close()
        self._socket, self._buffer = None, b""

    def _reconnect(self) -> None:
        self._drop()
        self.reconnects += 1
        self._connect()

    def _read_line(self, deadline: float) -> str:
        """Read the next line; the request it belongs to must be answered by ``deadline`` (``time.monotonic()``)."""
        assert self._socket is not None
        while b"\n" not in self._buffer:
            if len(self._buffer) > MAX_REPLY_LINE:
                raise DriverProtocolError(f"{self.address} sent a line longer than {MAX_REPLY_LINE} characters (garbage?)")
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise DriverConnectionError(f"{self.address} did not complete its reply in time (it sends, but too slowly)")
            self._socket.settimeout(min(self.timeout, remaining))
            try:
                chunk = self._socket.recv(65536)
            except TimeoutError:
                if time.monotonic() >= deadline - 1e-3:
                    raise DriverConnectionError(f"{self.address} did not complete its reply in time (it sends, but too slowly)") from None
                raise DriverConnectionError(f"{self.address} did not answer within {self.timeout:g} s") from None
            except OSError as error:
                raise DriverConnectionError(f"{self.address}: {error}") from None
            if not chunk:
                raise DriverConnectionError(f"{self.address} closed the connection")
            self._buffer += chunk
        line, _, self._buffer = self._buffer.partition(b"\n")
        try:
            return line.decode("ascii").rstrip("\r")
        except UnicodeDecodeError:
            raise DriverProtocolError(f"{self.address} sent non-ASCII bytes {line[:40]!r} (garbage)") from None

    def _send(self, request_id: int, verb: str, arguments: tuple[str, ...]) -> None:
        if self._socket is None:
            self._reconnect()
        assert self._socket is not None
        text = " ".join((str(request_id), verb, *arguments)) + "\n"
        try:
            self._socket.sendall(text.encode("ascii"))
        except OSError as error:
            raise DriverConnectionError(f"{self.address}: {error}") from None

    def _reply(self, request_id: int, verb: str, deadline: float) -> str:
        line = self._read_line(deadline)
        words = line.split(" ", 2)
        if len(words) < 2 or words[0] != str(request_id):
            raise DriverProtocolError(f"{self.address} answered {line[:80]!r} to request {request_id} {verb} (garbage or out of step)")
        if words[1] == "ERR":
            raise DriverError(f"the platform at {self.address} refused {verb}: {words[2] if len(words) > 2 else ''}")
        if words[1] != "OK":
            raise DriverProtocolError(f"{self.address} answered {line[:80]!r} to {verb} (expected OK or ERR)")
        return words[2] if len(words) > 2 else ""

    def _call(self, verb: str, *arguments: str, retry: bool = True) -> str:
        """One idempotent request/reply, sent again once after a reconnect if the link fails."""
        for attempt in (0, 1):
            request_id = self._next_id
            self._next_id += 1
            try:
                self._send(request_id, verb, arguments)
                return self._reply(request_id, verb, time.monotonic() + self.timeout)
            except DriverProtocolError:
                self._drop()
                raise
            except DriverConnectionError:
                self._drop()
                if attempt or not retry:
                    raise
                self._reconnect()
        raise AssertionError("unreachable")

    # ------------------------------------------------------------------ PlatformDriver
    @property
    def metadata(self) -> SiteMetadata:
        """Return the platform's site metadata (asked once, then kept)."""
        if self._metadata is None:
            from stableins.data.jsonio import parse_json
            from stableins.data.metadata import metadata_from_si

            payload = self._call("META", "CRC") if META_CRC_CAPABILITY in self.capabilities else self._call("META")
            if META_CRC_CAPABILITY in self.capabilities:
                payload, _, crc = payload.rpartition(" ")
                if crc != metadata_checksum(payload):
                    self._drop()
                    raise DriverProtocolError(
                        f"{self.address}: the META reply's CRC {crc[:8]!r} does not match its {len(payload)} characters "
                        f"(CRC {metadata_checksum(payload)}; garbage on the link?)"
                    )
            try:
                self._metadata = metadata_from_si(parse_json(payload, field="META", what="site metadata"), f"META reply of {self.address}")
            except InputError as error:
                raise DriverProtocolError(f"{self.address} sent unusable metadata (garbage?): {error}") from None
        return self._metadata

    def command(self, readings: tuple[float, float, float]) -> float:
        """Command the gimbals to ``readings`` [rad]; return the platform time."""
        payload = self._call("CMD", *(format_float(r) for r in readings))
        return _number(payload, self.address, "CMD")

    def read_angles(self) -> NDArray[np.float64]:
        """Return the angle-sensor readings [rad]."""
        payload = self._call("ANG")
        values = payload.split()
        if len(values) != 3:
            raise DriverProtocolError(f"{self.address} answered ANG with {payload[:80]!r} (expected three angles)")
        return np.array([_number(v, self.address, "ANG") for v in values])

    def status(self) -> dict[str, object]:
        """Return the link's state for logs and error messages."""
        from stableins.data.jsonio import parse_json

        try:
            remote = parse_json(self._call("STATUS"), field="STATUS", allow_nan=True, what="a status object")
        except InputError as error:
            raise DriverProtocolError(f"{self.address} sent an unreadable status ({error})") from None
        return {"driver": "tcp", "address": self.address, "reconnects": self.reconnects, "platform": remote}

    def acquire(self, duration: float) -> SampleBlock:
        """Record ``duration`` seconds of samples, checked as they arrive."""
        span = duration if math.isfinite(duration) and duration > 0 else 0.0  # the platform refuses other durations itself
        limit = int(math.ceil(ACQ_COUNT_MARGIN * span * float(self.metadata.sample_rate))) + ACQ_COUNT_SLACK
        request_id = self._next_id
        self._next_id += 1
        received = 0
        deadline = time.monotonic() + self.timeout + ACQ_TIME_FACTOR * span
        try:
            self._send(request_id, "ACQ", (format_float(duration),))
            count_text = self._reply(request_id, "ACQ", deadline)
            if not _COUNT.fullmatch(count_text) or int(count_text) > limit:
                raise DriverProtocolError(
                    f"{self.address} announced {count_text[:40]!r} samples for {duration:g} s at "
                    f"{self.metadata.sample_rate:g} Hz (expected a whole number up to {limit})"
                )
            count = int(count_text)
            rows = np.empty((count, 8))
            crc = 0
            for received in range(count):
                line = self._read_line(deadline)
                crc = zlib.crc32((line + "\n").encode("ascii"), crc)
                values = line.split(" ")
                if len(values) != 9 or values[0] != "S":
                    raise DriverProtocolError(f"{self.address} sent {line[:80]!r} as sample {received + 1} of {count} (garbage)")
                rows[received] = [_number(v, self.address, "ACQ") for v in values[1:]]
                if received and not rows[received, 0] > rows[received - 1, 0]:
                    raise DriverProtocolError(
                        f"{self.address}: sample {received + 1} of {count} has time {rows[received, 0]!r} s, "
                        f"not after the previous sample's {rows[received - 1, 0]!r} s"
                    )
            received = count
            end = self._read_line(deadline).split(" ")
            if end[:3] != [str(request_id), "END", str(count)] or len(end) != 4 or end[3] != f"{crc:08x}":
                raise DriverProtocolError(
                    f"{self.address}: acquisition trailer {' '.join(end)[:80]!r} does not match {count} samples with CRC {crc:08x}"
                )
        except DriverProtocolError:
            self._drop()
            raise
        except DriverConnectionError as error:
            self._drop()
            try:
                self._reconnect()
            except DriverConnectionError as again:
                raise AcquisitionInterrupted(f"{error}; {again}", received) from None
            raise AcquisitionInterrupted(f"acquisition interrupted after {received} samples ({error}); reconnected", received) from None
        return SampleBlock(
            time=rows[:, 0].copy(), specific_force=rows[:, 1:4].copy(), angles=rows[:, 4:7].copy(), temperature=rows[:, 7].copy()
        )

    def require(self, capability: str, purpose: str) -> None:
        """Raise :class:`DriverProtocolError` naming what is missing unless the platform's greeting states ``capability``.

        Called before the platform moves (a system-level run needs ``NAV``), so that a controller without it gets one
        clear message instead of a failure in the middle of a run.
        """
        if capability not in self.capabilities:
            stated = f"capabilities {' '.join(sorted(self.capabilities))}" if self.capabilities else "no capabilities"
            raise DriverProtocolError(
                f"the platform at {self.address} speaks protocol version {self.version} with {stated}: {purpose} needs the "
                f"capability {capability} (docs/protocol.md, version {PROTOCOL_VERSION}: greeting "
                f"'{PROTOCOL_NAME} {PROTOCOL_VERSION} {capability}', requests REC and NAV)"
            )

    def static_record(self, duration: float, chunk: float, turns: Any = ()) -> Iterator[dict[str, NDArray[np.float64]]]:
        """Chunks of a static record of the INS's outputs (dicts of :data:`~stableins.drivers.server.NAV_FIELDS`), as they arrive.

        ``REC`` starts the record on the platform (``turns``: the indexing it carries out during the record), then each
        ``NAV`` brings its next chunk, checked as an ``ACQ`` is (count, numbers, times, CRC-32).  A broken link ends the
        record (:class:`DriverConnectionError`): a record is not stitched across a gap, the run repeats it on resume.
        """
        import json

        from stableins.drivers.server import turns_to_json

        self.require(NAV_CAPABILITY, "a system-level static record (the INS's velocity and attitude outputs)")
        request = json.dumps({"duration": float(duration), "chunk": float(chunk), "turns": turns_to_json(turns)}, allow_nan=False)
        self._call("REC", request, retry=False)
        rate = float(self.metadata.sample_rate)
        total = int(round(duration * rate))
        done = 0
        last = -math.inf
        while done < total:
            columns = self._navigation_chunk(chunk, rate, last)
            if not len(columns["time"]):
                raise DriverProtocolError(f"{self.address} sent an empty chunk after {done} of {total} samples of the record")
            last = float(columns["time"][-1])
            done += len(columns["time"])
            yield columns

    def _navigation_chunk(self, chunk: float, rate: float, after: float) -> dict[str, NDArray[np.float64]]:
        """One ``NAV`` request: the next chunk of the record, checked as it arrives."""
        limit = int(math.ceil(ACQ_COUNT_MARGIN * chunk * rate)) + ACQ_COUNT_SLACK
        request_id = self._next_id
        self._next_id += 1
        deadline = time.monotonic() + self.timeout + ACQ_TIME_FACTOR * chunk
        width = len(NAV_FIELDS)
        try:
            self._send(request_id, "NAV", ())
            count_text = self._reply(request_id, "NAV", deadline)
            if not _COUNT.fullmatch(count_text) or int(count_text) > limit:
                raise DriverProtocolError(
                    f"{self.address} announced {count_text[:40]!r} navigation samples for a chunk of {chunk:g} s at {rate:g} Hz "
                    f"(expected a whole number up to {limit})"
                )
            count = int(count_text)
            rows = np.empty((count, width))
            crc = 0
            for k in range(count):
                line = self._read_line(deadline)
                crc = zlib.crc32((line + "\n").encode("ascii"), crc)
                values = line.split(" ")
                if len(values) != width + 1 or values[0] != "N":
                    raise DriverProtocolError(f"{self.address} sent {line[:80]!r} as navigation sample {k + 1} of {count} (garbage)")
                rows[k] = [_number(v, self.address, "NAV") for v in values[1:]]
                previous = rows[k - 1, 0] if k else after
                if not rows[k, 0] > previous:
                    raise DriverProtocolError(
                        f"{self.address}: navigation sample {k + 1} of {count} has time {rows[k, 0]!r} s, not after {previous!r} s"
                    )
            end = self._read_line(deadline).split(" ")
            if end[:3] != [str(request_id), "END", str(count)] or len(end) != 4 or end[3] != f"{crc:08x}":
                raise DriverProtocolError(
                    f"{self.address}: navigation trailer {' '.join(end)[:80]!r} does not match {count} samples with CRC {crc:08x}"
                )
        except DriverError:
            self._drop()
            raise
        return {name: rows[:, j].copy() for j, name in enumerate(NAV_FIELDS)}

    def close(self) -> None:
        """Close the connection (saying goodbye to the server when it is up)."""
        if self._socket is not None:
            with contextlib.suppress(DriverError):
                self._call("BYE", retry=False)
        self._drop()


def parse_greeting(line: str) -> tuple[int, frozenset[str]]:
    """``STABLEINS-PLATFORM <version> [<capability> ...]`` → ``(version, capabilities)``; ValueError naming what is wrong.

    Version 1 states no capabilities (device level only); version 2 states them; a later version is refused (this
    client does not know what it changed).
    """
    words = line.split(" ")
    if len(words) < 2 or words[0] != PROTOCOL_NAME or not words[1].isdigit():
        raise ValueError(f"it greeted with {line[:60]!r}, expected '{PROTOCOL_NAME} <version> [<capability> ...]'")
    version = int(words[1])
    if not 1 <= version <= PROTOCOL_VERSION:
        raise ValueError(f"it speaks protocol version {words[1][:10]}; this stableins speaks versions 1 to {PROTOCOL_VERSION}")
    capabilities = words[2:]
    if version == 1 and capabilities:
        raise ValueError(f"its version-1 greeting {line[:60]!r} states capabilities (only version 2 does)")
    if not all(c.isalnum() and c.isupper() for c in capabilities):
        raise ValueError(f"it greeted with {line[:60]!r}: capabilities are upper-case words")
    return version, frozenset(capabilities)


def _number(text: str, address: str, verb: str) -> float:
    if not _NUMBER.fullmatch(text):
        raise DriverProtocolError(f"{address} sent {text[:60]!r} where {verb} needs a number (garbage)")
    try:
        value = float(text)
    except ValueError:
        raise DriverProtocolError(f"{address} sent {text[:60]!r} where {verb} needs a number (garbage)") from None
    if not np.isfinite(value):
        raise DriverProtocolError(f"{address} sent a non-finite number {text!r} in reply to {verb}")
    return value


def connect(spec: str, **options: Any) -> TcpDriver:
    """Open ``tcp://HOST:PORT``."""
    host, port = parse_address(spec)
    return TcpDriver(host, port, **options)
