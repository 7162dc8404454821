"""Serve a platform driver over the line-based TCP protocol of ``docs/protocol.md``.

``stableins serve-sim --port N`` uses :func:`serve` to put a simulated platform behind a
socket on the loopback interface, so that the TCP driver, the runner and their failure
handling are exercised against a separate process exactly as against real hardware.  The
platform's state (session time, gimbal positions) lives in the server and survives client
disconnects, as it would on a real platform.
"""

from __future__ import annotations

import contextlib
import json
import math
import socket
import threading
import time
import zlib
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from typing import Any, TextIO, TypedDict

import numpy as np

from stableins.drivers.base import PlatformDriver
from stableins.errors import InputError, NotDeterminedError

#: The protocol's name, first word of the greeting ``STABLEINS-PLATFORM <version> [<capability> ...]``.
PROTOCOL_NAME = "STABLEINS-PLATFORM"
#: Version of docs/protocol.md this server speaks (1: device level only; 2: the greeting states capabilities).
PROTOCOL_VERSION = 2
#: Capability of a platform whose INS streams its navigation outputs (``REC`` and ``NAV``, docs/protocol.md).
NAV_CAPABILITY = "NAV"
#: Capability of a platform that answers ``META CRC`` with the metadata's CRC-32 after its JSON (docs/protocol.md).
META_CRC_CAPABILITY = "METACRC"
#: The greeting of a version-1 platform (no capabilities).
PROTOCOL_GREETING = f"{PROTOCOL_NAME} 1"
#: Order of the values of an ``N`` line (the system-level record's columns, :data:`stableins.schema.SYSTEM_COLUMNS`).
NAV_FIELDS = (
    "time",
    "angle_platform",
    "angle_inner",
    "angle_middle",
    "f_x",
    "f_y",
    "f_z",
    "velocity_north",
    "velocity_east",
    "velocity_down",
    "roll",
    "pitch",
    "heading",
    "temperature",
)


def greeting(capabilities: tuple[str, ...]) -> str:
    """Return the greeting of a version-2 platform with ``capabilities``."""
    return " ".join((PROTOCOL_NAME, str(PROTOCOL_VERSION), *capabilities))


class TurnDocument(TypedDict):
    """One indexing turn in a ``REC`` request: start [s], angle [rad], axis, rate [rad/s]."""

    start: float
    angle: float
    axis: str
    rate: float


@dataclass
class _RecordInProgress:
    """The static record a platform is streaming (``REC``, then ``NAV`` chunk by chunk); the server keeps it across connections."""

    chunks: Iterator[Mapping[str, Any]] | None = None
    sent: int = 0


def turns_to_json(turns: Any) -> list[TurnDocument]:
    """Return the indexing turns of a static record as the JSON of a ``REC`` request."""
    return [{"start": t.start, "angle": t.angle, "axis": t.axis.value, "rate": t.rate} for t in turns]


def turns_from_json(items: Any) -> tuple[Any, ...]:
    """Return the turns of a ``REC`` request (ValueError on anything else)."""
    from stableins.turns import IndexAxis, PlatformTurn

    if not isinstance(items, list):
        raise ValueError("turns must be a list")
    turns = []
    for item in items:
        if not isinstance(item, dict) or set(item) != {"start", "angle", "axis", "rate"}:
            raise ValueError("a turn has start, angle, axis and rate")
        turns.append(PlatformTurn(float(item["start"]), float(item["angle"]), IndexAxis(item["axis"]), float(item["rate"])))
    return tuple(turns)


#: The server binds this address only: a calibration platform is not a network service.
LOOPBACK = "127.0.0.1"


def format_float(value: float) -> str:
    """Shortest text that reads back as exactly the same double (``repr``)."""
    return repr(float(value))


def sample_lines(block: Any) -> list[str]:
    """``S t fx fy fz ap ai am T`` lines of a :class:`~stableins.samples.SampleBlock`."""
    lines = []
    for k in range(len(block.time)):
        values = [block.time[k], *block.specific_force[k], *block.angles[k], block.temperature[k]]
        lines.append("S " + " ".join(format_float(v) for v in values) + "\n")
    return lines


def metadata_checksum(text: str) -> str:
    """CRC-32 (hex) of a ``META`` reply's JSON text, as ``META CRC`` sends it after the JSON (docs/protocol.md)."""
    return f"{zlib.crc32(text.encode('ascii')):08x}"


def checksum(lines: list[str]) -> str:
    """CRC-32 (hex) of the concatenated sample lines, newlines included."""
    crc = 0
    for line in lines:
        crc = zlib.crc32(line.encode("ascii"), crc)
    return f"{crc:08x}"


class _Session:
    """One client connection: reads requests, answers them from the driver."""

    def __init__(
        self,
        driver: PlatformDriver,
        reader: TextIO,
        writer: TextIO,
        log: Callable[[str], None],
        realtime: float = 0.0,
        *,
        record: _RecordInProgress | None = None,
    ) -> None:
        self.driver = driver
        self.reader = reader
        self.writer = writer
        self.log = log
        self.realtime = realtime
        #: the static record in progress (its chunk iterator), kept by the server across connections
        self.record = record if record is not None else _RecordInProgress()

    def send(self, text: str) -> None:
        self.writer.write(text)
        self.writer.flush()

    @property
    def capabilities(self) -> tuple[str, ...]:
        """What this platform offers beyond version 1: ``NAV`` when its driver records the INS's outputs; ``METACRC``."""
        return ((NAV_CAPABILITY,) if callable(getattr(self.driver, "static_record", None)) else ()) + (META_CRC_CAPABILITY,)

    def run(self) -> None:
        self.send(greeting(self.capabilities) + "\n")
        for line in self.reader:
            words = line.split()
            if not words:
                continue
            request_id = words[0]
            if not request_id.isdigit() or len(words) < 2:
                self.send(f"0 ERR protocol malformed request {line.strip()[:60]!r}\n")
                continue
            verb, arguments = words[1].upper(), words[2:]
            try:
                if not self.handle(request_id, verb, arguments):
                    return
            except Exception as error:
                if isinstance(error, ValueError | IndexError) and not isinstance(error, InputError | NotDeterminedError):
                    self.send(f"{request_id} ERR protocol {verb}: {error}\n")
                else:  # the platform failed (or refused a value): tell the client, keep serving
                    message = str(error).replace("\n", " ")
                    self.send(f"{request_id} ERR driver {type(error).__name__}: {message}\n")

    def handle(self, request_id: str, verb: str, arguments: list[str]) -> bool:
        """Answer one request; False when the client said goodbye."""
        handlers: dict[str, Callable[[str, list[str]], bool]] = {
            "META": self._meta,
            "CMD": self._command,
            "ANG": self._angles,
            "ACQ": self._acquire,
            "STATUS": self._status,
            "BYE": self._bye,
        }
        if NAV_CAPABILITY in self.capabilities:
            handlers.update(REC=self._start_record, NAV=self._navigation)
        handler = handlers.get(verb)
        if handler is None:
            self.send(f"{request_id} ERR protocol unknown verb {verb!r}\n")
            return True
        return handler(request_id, arguments)

    def _meta(self, request_id: str, arguments: list[str]) -> bool:
        if [a.upper() for a in arguments] not in ([], ["CRC"]):
            raise ValueError("expected nothing, or CRC")
        text = json.dumps(self.driver.metadata.to_dict(), allow_nan=False)
        crc = f" {metadata_checksum(text)}" if arguments else ""  # META CRC (capability METACRC); plain META as in version 2
        self.send(f"{request_id} OK {text}{crc}\n")
        return True

    def _command(self, request_id: str, arguments: list[str]) -> bool:
        if len(arguments) != 3:
            raise ValueError("expected three angle-sensor readings [rad]")
        issued = self.driver.command((_finite(arguments[0]), _finite(arguments[1]), _finite(arguments[2])))
        self.send(f"{request_id} OK {format_float(issued)}\n")
        return True

    def _angles(self, request_id: str, arguments: list[str]) -> bool:
        angles = self.driver.read_angles()
        self.send(f"{request_id} OK {' '.join(format_float(a) for a in angles)}\n")
        return True

    def _acquire(self, request_id: str, arguments: list[str]) -> bool:
        if len(arguments) != 1:
            raise ValueError("expected one duration [s]")
        duration = _finite(arguments[0])
        if duration <= 0:
            raise ValueError("duration must be positive")
        block = self.driver.acquire(duration)
        lines = sample_lines(block)
        self.send(f"{request_id} OK {len(lines)}\n")
        try:
            self._stream(block, lines)
        except OSError:
            raise
        except Exception as error:  # after OK only samples may follow: a failure drops the connection
            raise ConnectionAbortedError(f"acquisition failed while streaming: {error}") from error
        self.send(f"{request_id} END {len(lines)} {checksum(lines)}\n")
        return True

    def _start_record(self, request_id: str, arguments: list[str]) -> bool:
        """``REC <json>``: start a static record of the INS's outputs (``duration``, ``chunk`` [s], ``turns``)."""
        request = json.loads(" ".join(arguments))
        if not isinstance(request, dict) or set(request) != {"duration", "chunk", "turns"}:
            raise ValueError("expected a JSON object with duration, chunk and turns")
        duration, chunk = float(request["duration"]), float(request["chunk"])
        if not (math.isfinite(duration) and duration > 0 and math.isfinite(chunk) and chunk > 0):
            raise ValueError("duration and chunk must be positive")
        turns = turns_from_json(request["turns"])
        recorder = self.driver.static_record  # type: ignore[attr-defined]
        chunks = recorder(duration, chunk, turns=turns) if turns else recorder(duration, chunk)
        self.record.chunks, self.record.sent = iter(chunks), 0
        self.send(f"{request_id} OK\n")
        return True

    def _navigation(self, request_id: str, arguments: list[str]) -> bool:
        """``NAV``: the next chunk of the record in progress, ``N`` lines of the INS's outputs (time, angles, f, v, attitude, T)."""
        chunks = self.record.chunks
        if chunks is None:
            raise RuntimeError("no record in progress (send REC first)")
        piece = next(chunks, None)
        if piece is None:
            raise RuntimeError(f"the record is complete ({self.record.sent} samples sent)")
        columns = [np.asarray(piece[name], dtype=float) for name in NAV_FIELDS]
        lines = ["N " + " ".join(format_float(c[k]) for c in columns) + "\n" for k in range(len(columns[0]))]
        self.record.sent += len(lines)
        self.send(f"{request_id} OK {len(lines)}\n")
        try:
            self._stream(columns[0], lines)
        except OSError:
            raise
        except Exception as error:  # after OK only lines of the chunk may follow: a failure drops the connection
            raise ConnectionAbortedError(f"record failed while streaming: {error}") from error
        self.send(f"{request_id} END {len(lines)} {checksum(lines)}\n")
        return True

    def _stream(self, block: Any, lines: list[str]) -> None:
        """Write the lines, paced at ``realtime`` × real time when it is positive (each sample when it is measured).

        ``block``: the samples (a :class:`~stableins.samples.SampleBlock`) or their times.
        """
        if self.realtime <= 0:
            for line in lines:
                self.writer.write(line)
            return
        times = np.asarray(getattr(block, "time", block), dtype=float)
        start, first = time.monotonic(), float(times[0]) if len(lines) else 0.0
        for k, line in enumerate(lines):
            delay = (float(times[k]) - first) / self.realtime - (time.monotonic() - start)
            if delay > 0:
                self.writer.flush()
                time.sleep(delay)
            self.writer.write(line)

    def _status(self, request_id: str, arguments: list[str]) -> bool:
        self.send(f"{request_id} OK {json.dumps(_jsonable(self.driver.status()))}\n")
        return True

    def _bye(self, request_id: str, arguments: list[str]) -> bool:
        self.send(f"{request_id} OK\n")
        return False


def _finite(text: str) -> float:
    value = float(text)
    if not math.isfinite(value):
        raise ValueError(f"{text!r} is not a finite number")
    return value


def _jsonable(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_jsonable(v) for v in value]
    if hasattr(value, "tolist"):
        return value.tolist()
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    return value


def serve(
    driver: PlatformDriver,
    port: int = 0,
    *,
    ready: Callable[[int], None] | None = None,
    log: Callable[[str], None] = print,
    max_connections: int | None = None,
    realtime: float = 0.0,
) -> None:
    """Serve ``driver`` on ``127.0.0.1:port``, one client at a time, until interrupted.

    The latest client wins: a new connection closes the previous one (whose host may have
    lost power without closing it), then takes the platform over once that session has
    let go of it.

    Parameters
    ----------
    driver : PlatformDriver
        The platform to serve (its state persists across client connections).
    port : int
        TCP port; 0 picks a free one.
    ready : callable, optional
        Called with the bound port once the server accepts connections.
    max_connections : int, optional
        Stop after this many client connections have ended (tests); ``None`` serves forever.
    realtime : float
        Stream samples paced at ``realtime`` × real time (1: like hardware); 0: as fast as possible.
    """
    platform = threading.Lock()  # one session talks to the driver at a time
    state: dict[str, socket.socket | None] = {"current": None}
    record = _RecordInProgress()  # the static record in progress: the platform's, it survives a reconnection
    sessions: list[threading.Thread] = []

    def session(connection: socket.socket, peer: tuple[str, int]) -> None:
        with platform, connection:
            if state["current"] is not connection:  # replaced before it started
                return
            _serve_connection(driver, connection, peer, log=log, realtime=realtime, record=record)

    with socket.create_server((LOOPBACK, port), backlog=4) as listener:
        bound = listener.getsockname()[1]
        if ready is not None:
            ready(bound)
        accepted = 0
        while max_connections is None or accepted < max_connections:
            connection, peer = listener.accept()
            accepted += 1
            previous, state["current"] = state["current"], connection
            if previous is not None:
                log(f"client {peer[0]}:{peer[1]} connected; it replaces the previous client")
                with contextlib.suppress(OSError):
                    previous.shutdown(socket.SHUT_RDWR)
            else:
                log(f"client {peer[0]}:{peer[1]} connected")
            thread = threading.Thread(target=session, args=(connection, peer), daemon=True)
            thread.start()
            sessions.append(thread)
        for thread in sessions:
            thread.join()


def _serve_connection(
    driver: PlatformDriver,
    connection: socket.socket,
    peer: tuple[str, int],
    *,
    log: Callable[[str], None],
    realtime: float,
    record: _RecordInProgress | None = None,
) -> None:
    """Run one client's session on ``connection`` and log how it ended."""
    connection.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    reader = connection.makefile("r", encoding="ascii", newline="\n", errors="replace")
    writer = connection.makefile("w", encoding="ascii", newline="\n")
    try:
        _Session(driver, reader, writer, log, realtime, record=record).run()
    except (InputError, NotDeterminedError):
        raise  # a described error passes through as it is (issue 29)
    except (ConnectionError, BrokenPipeError, OSError, ValueError) as error:
        log(f"client {peer[0]}:{peer[1]} lost: {error}")
    else:
        log(f"client {peer[0]}:{peer[1]} disconnected")
    finally:
        for stream in (reader, writer):
            with contextlib.suppress(OSError, ValueError):
                stream.close()
