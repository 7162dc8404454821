"""Loopback helpers for the network-driver tests: a platform server in a separate process and a fault-injecting relay."""

from __future__ import annotations

import contextlib
import os
import socket
import subprocess
import sys
import threading
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

SERVER_SCRIPT = """
import sys
sys.path.insert(0, {root!r})
from tests.platform_double import PlatformDouble
from stableins.drivers.server import serve
serve(PlatformDouble(seed={seed}), 0, ready=lambda port: print(port, flush=True), log=lambda m: None)
"""


class ServerProcess:
    """A platform server in its own process on 127.0.0.1 (killed on exit).

    ``simulator=True`` runs ``stableins serve-sim`` (the simulated platform); otherwise the
    test double is served (exact, simple outputs for bit-for-bit comparisons).
    """

    def __init__(
        self,
        seed: int = 0,
        simulator: bool = False,
        unit: str = "NET-1",
        rate: float | None = None,
        realtime: float = 0.0,
        installed: str | os.PathLike[str] | None = None,
    ) -> None:
        if simulator:
            argv = [sys.executable, "-m", "stableins.cli", "serve-sim", "--port", "0", "--seed", str(seed), "--unit", unit, "--quiet"]
            argv += ["--rate", str(rate)] if rate else []
            argv += ["--realtime", str(realtime)] if realtime else []
            argv += ["--installed", str(installed)] if installed is not None else []
        else:
            argv = [sys.executable, "-c", SERVER_SCRIPT.format(root=str(ROOT), seed=seed)]
        env = dict(os.environ, PYTHONPATH=str(ROOT))
        self.process = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
        line = self.process.stdout.readline()
        if not line.strip():
            self.process.kill()
            raise RuntimeError(f"server did not start: {self.process.stderr.read()}")
        self.port = int(line.split()[-1].rsplit(":", 1)[-1])

    def stop(self) -> None:
        if self.process.poll() is None:
            self.process.kill()
        self.process.wait(timeout=10)
        for stream in (self.process.stdout, self.process.stderr):
            stream.close()

    def __enter__(self) -> ServerProcess:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


class FaultyRelay:
    """Relays 127.0.0.1:port ↔ upstream; on the first connection injects one fault into the server→client stream.

    fault: None, ("cut", n) close both sides after n bytes, ("stall", n) stop forwarding after n bytes,
    ("corrupt", n) replace byte n with garbage.
    """

    def __init__(self, upstream_port: int, fault: tuple[str, int] | None = None) -> None:
        self.upstream_port = upstream_port
        self.fault = fault
        self.connections = 0
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.port = self.listener.getsockname()[1]
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._sockets: list[socket.socket] = []
        thread = threading.Thread(target=self._accept, daemon=True)
        thread.start()

    def _accept(self) -> None:
        self.listener.settimeout(0.2)
        while not self._stop.is_set():
            try:
                client, _ = self.listener.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            upstream = socket.create_connection(("127.0.0.1", self.upstream_port))
            self._sockets += [client, upstream]
            fault = self.fault if self.connections == 0 else None
            self.connections += 1
            for source, sink, f in ((client, upstream, None), (upstream, client, fault)):
                t = threading.Thread(target=self._pump, args=(source, sink, f, client, upstream), daemon=True)
                t.start()
                self._threads.append(t)

    def _pump(self, source, sink, fault, client, upstream) -> None:
        with contextlib.suppress(OSError):
            self._relay(source, sink, fault)
        for s in (client, upstream):
            with contextlib.suppress(OSError):
                s.shutdown(socket.SHUT_RDWR)
            s.close()

    def _relay(self, source, sink, fault) -> None:
        """Copy ``source`` to ``sink`` until either closes, applying ``fault`` (kind, byte offset) once on the way."""
        count = 0
        stalled = False
        while not self._stop.is_set():
            data = source.recv(4096)
            if not data:
                return
            if stalled:
                continue
            if fault is not None:
                kind, at = fault
                if count + len(data) > at:
                    cut = at - count
                    if kind == "cut":
                        sink.sendall(data[:cut])
                        return
                    if kind == "stall":
                        sink.sendall(data[:cut])
                        stalled = True
                        continue
                    if kind == "corrupt":
                        data = data[:cut] + b"#" + data[cut + 1 :]
                        fault = None
            count += len(data)
            sink.sendall(data)

    def close(self) -> None:
        self._stop.set()
        self.listener.close()
        for s in self._sockets:
            with contextlib.suppress(OSError):
                s.close()

    def __enter__(self) -> FaultyRelay:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
