"""The TCP driver against a platform served by a separate process on loopback, with injected link faults."""

from __future__ import annotations

import socket
import threading
import time

import numpy as np
import pytest

from stableins.drivers.errors import AcquisitionInterrupted, DriverConnectionError, DriverError, DriverProtocolError
from stableins.drivers.select import simulated_platform
from stableins.drivers.server import greeting
from stableins.drivers.tcp import TcpDriver, connect, parse_address
from stableins.errors import InputError
from tests.platform_double import PlatformDouble
from tests.tcp_fixtures import FaultyRelay, ServerProcess


@pytest.fixture(scope="module")
def server():
    """'stableins serve-sim' in its own process: the simulated platform at 20 Hz on loopback."""
    with ServerProcess(seed=11, simulator=True, rate=20.0) as s:
        yield s


def test_simulator_samples_cross_the_wire_bit_for_bit():
    local = simulated_platform(5, "NET-1", 20.0)  # the same simulated platform, in this process
    with ServerProcess(seed=5, simulator=True, rate=20.0) as s:
        driver = connect(f"tcp://127.0.0.1:{s.port}", timeout=30)
        assert driver.metadata == local.metadata
        for readings in [(0.1, 0.2, -0.3), (1.0, -0.5, 0.25)]:
            assert driver.command(readings) == local.command(readings)
            np.testing.assert_array_equal(driver.read_angles(), local.read_angles())
            remote, here = driver.acquire(0.6), local.acquire(0.6)
            for name in ("time", "specific_force", "angles", "temperature"):
                np.testing.assert_array_equal(getattr(remote, name), getattr(here, name))
        assert driver.status()["address"] == f"tcp://127.0.0.1:{s.port}"
        driver.close()


def test_the_test_double_crosses_the_wire_bit_for_bit():
    local = PlatformDouble(seed=5)
    with ServerProcess(seed=5) as s:
        driver = connect(f"tcp://127.0.0.1:{s.port}", timeout=30)
        driver.command((0.1, 0.2, -0.3))
        local.command((0.1, 0.2, -0.3))
        np.testing.assert_array_equal(driver.acquire(0.6).specific_force, local.acquire(0.6).specific_force)
        driver.close()


def test_disconnect_in_the_middle_of_a_dwell(server):
    with FaultyRelay(server.port, fault=("cut", 3000)) as relay:
        driver = TcpDriver("127.0.0.1", relay.port, timeout=30, reconnect_delay=0.05)
        driver.command((0.0, 0.1, 0.2))
        with pytest.raises(AcquisitionInterrupted) as caught:
            driver.acquire(5.0)  # 100 samples of ~200 characters: the cut falls inside the stream
        assert 0 < caught.value.received < 100
        assert "reconnected" in str(caught.value)
        # the driver reconnected and the platform is still there, still at its position
        block = driver.acquire(1.0)
        assert len(block) == 20
        np.testing.assert_allclose(block.angles.mean(axis=0), [0.0, 0.1, 0.2], atol=1e-5)
        assert driver.reconnects == 1 and relay.connections == 2
        driver.close()


def test_idempotent_requests_are_resent_after_a_disconnect(server):
    with FaultyRelay(server.port, fault=("cut", len(greeting(("NAV", "METACRC")) + "\n") + 3)) as relay:  # serve-sim's greeting
        driver = TcpDriver("127.0.0.1", relay.port, timeout=30, reconnect_delay=0.05)
        driver.command((0.3, 0.0, 0.0))  # its reply is cut; sent again on a new connection
        driver.acquire(8.0)  # the slew (17° at 10°/s, 2.7 s) and its settling transient (~1e-5 rad at 4 s)
        np.testing.assert_allclose(driver.read_angles(), [0.3, 0.0, 0.0], atol=1e-5)
        assert driver.reconnects == 1
        driver.close()


def test_silence_times_out_with_a_clear_error(server):
    with FaultyRelay(server.port, fault=("stall", len(greeting(("NAV", "METACRC")) + "\n"))) as relay:  # after the greeting
        driver = TcpDriver("127.0.0.1", relay.port, timeout=0.3, reconnect_delay=0.05)
        driver.command((0.0, 0.0, 0.0))  # times out once, reconnects, answered on the clean connection
        assert driver.reconnects == 1 and relay.connections == 2  # one timeout, one new connection: no waiting it out
        driver.close()


def test_stall_during_acquisition_is_an_interruption_not_a_hang(server):
    with FaultyRelay(server.port, fault=("stall", 2000)) as relay:
        driver = TcpDriver("127.0.0.1", relay.port, timeout=0.3, reconnect_delay=0.05)
        with pytest.raises(AcquisitionInterrupted, match="did not answer within 0.3 s"):  # the silence timeout ended it
            driver.acquire(5.0)
        assert relay.connections <= 1 + driver.reconnect_attempts  # a bounded number of tries, not a hang
        driver.close()


def _damping_key_offset() -> int:
    """Where the served stream carries a free-form key of the META reply's ``damping`` table (serve-sim, seed 11, NET-1)."""
    import json

    text = json.dumps(simulated_platform(11, "NET-1", 20.0).metadata.to_dict(), allow_nan=False)
    return len(greeting(("NAV", "METACRC")) + "\n") + len("1 OK ") + text.index("horizontal_gain") + 3


# in META's serial number key, inside a free-form key of its damping table, in the first ACQ reply, in a later one
@pytest.mark.parametrize("at", [48, _damping_key_offset(), 900, 2500])
def test_garbage_in_a_reply_is_detected(server, at):
    """A byte replaced in a reply is refused: the ACQ replies carry their CRC-32, and so does the META reply of a platform
    that states METACRC (a byte changed inside a free-form key of its ``damping`` table is still valid JSON)."""
    with FaultyRelay(server.port, fault=("corrupt", at)) as relay:
        driver = TcpDriver("127.0.0.1", relay.port, timeout=30, reconnect_delay=0.05)
        driver.command((0.0, 0.5, 0.0))
        with pytest.raises(DriverProtocolError, match="garbage|CRC|does not match"):
            for _ in range(3):
                driver.acquire(3.0)
        # the connection was dropped; the next request opens a clean one
        assert len(driver.acquire(0.5)) == 10
        driver.close()


def test_meta_crc_is_asked_only_of_a_platform_that_states_it():
    """A version-2 platform without METACRC gets the plain ``META`` and is read as before (docs/protocol.md)."""
    import json

    listener = socket.create_server(("127.0.0.1", 0))
    port = listener.getsockname()[1]
    metadata = simulated_platform(3, "OLD-2", 20.0).metadata
    asked = []

    def answer():
        connection, _ = listener.accept()
        stream = connection.makefile("rw", newline="\n")
        stream.write(greeting(("NAV",)) + "\n")
        stream.flush()
        for line in stream:
            request_id, *words = line.split()
            asked.append(" ".join(words))
            stream.write(f"{request_id} OK {json.dumps(metadata.to_dict())}\n" if words[0] == "META" else f"{request_id} OK\n")
            stream.flush()
            if words[0] == "BYE":
                break
        connection.close()

    thread = threading.Thread(target=answer, daemon=True)
    thread.start()
    driver = TcpDriver("127.0.0.1", port, timeout=5, reconnect_attempts=1)
    assert driver.metadata == metadata and asked[0] == "META"
    driver.close()
    thread.join(timeout=5)
    listener.close()


def test_a_server_that_is_not_a_platform():
    listener = socket.create_server(("127.0.0.1", 0))
    port = listener.getsockname()[1]

    def answer():
        connection, _ = listener.accept()
        connection.sendall(b"HTTP/1.1 400 Bad Request\r\n\r\n")
        time.sleep(0.5)
        connection.close()

    thread = threading.Thread(target=answer, daemon=True)
    thread.start()
    with pytest.raises(DriverProtocolError, match="not a stableins platform"):
        TcpDriver("127.0.0.1", port, timeout=2, reconnect_attempts=1)
    listener.close()


def test_nobody_listening():
    listener = socket.create_server(("127.0.0.1", 0))
    port = listener.getsockname()[1]
    listener.close()
    with pytest.raises(DriverConnectionError, match="after 2 attempts"):
        TcpDriver("127.0.0.1", port, timeout=1, reconnect_attempts=2, reconnect_delay=0.01)


def test_platform_errors_are_reported_not_fatal(server):
    driver = TcpDriver("127.0.0.1", server.port, timeout=30)
    with pytest.raises(DriverError, match="refused ACQ"):
        driver.acquire(-1.0)
    assert len(driver.acquire(0.5)) == 10  # still usable
    driver.close()


@pytest.mark.parametrize("spec", ["tcp://localhost", "tcp://:80", "tcp://host:abc", "tcp://host:70000"])
def test_bad_addresses(spec):
    with pytest.raises(InputError, match="driver_spec"):
        parse_address(spec)


def test_the_timeout_counts_silence_not_the_length_of_a_dwell():
    # a platform streaming in real time: a 1.5 s acquisition with a 0.4 s timeout arrives whole
    with ServerProcess(seed=2, simulator=True, rate=20.0, realtime=1.0) as s:
        warm = TcpDriver("127.0.0.1", s.port, timeout=30)
        warm.acquire(0.1)  # the simulator's first call sets itself up (seconds of silence)
        warm.close()
        driver = TcpDriver("127.0.0.1", s.port, timeout=0.4)
        block = driver.acquire(1.5)  # streamed in real time (realtime=1.0): 1.5 s, far more than the 0.4 s timeout
        assert len(block) == 30 and block.time[-1] - block.time[0] == pytest.approx(1.45)
        driver.close()


def test_a_new_client_takes_over_from_one_that_vanished(server):
    # a client whose host lost power never closes its connection; the next client must not wait for it
    stale = socket.create_connection(("127.0.0.1", server.port), timeout=30)
    assert stale.recv(100).startswith(b"STABLEINS-PLATFORM ")
    driver = TcpDriver("127.0.0.1", server.port, timeout=30)
    assert len(driver.acquire(0.5)) == 10
    assert driver.reconnects == 0  # served on its first connection, not after the stale one timed out
    driver.close()
    assert stale.recv(100) == b""  # the stale connection was closed by the platform
    stale.close()
