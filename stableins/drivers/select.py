"""Open a platform driver from a ``--driver`` specification: ``sim``, ``tcp://HOST:PORT`` or ``replay:PATH``."""

from __future__ import annotations

from typing import Any

from stableins.drivers.base import PlatformDriver
from stableins.errors import InputError

SPEC_HELP = "sim, tcp://HOST:PORT or replay:PATH"


def is_deterministic(driver: Any) -> bool:
    """Whether the driver answers the same operations with the same results (sim, replay)."""
    return bool(getattr(driver, "deterministic", False))


def open_driver(
    spec: str,
    *,
    seed: int | None = None,
    unit: str | None = None,
    sample_rate: float | None = None,
    timeout: float = 10.0,
    truth: Any = None,
) -> PlatformDriver:
    """Open the driver named by ``spec``.

    ``sim`` builds the embedded simulated platform (:mod:`stableins.simulator`) with a truth
    drawn from ``seed`` and serial number ``unit``, or with ``truth`` (a
    :class:`~stableins.simulator.truth.Truth`, its noise drawn from ``seed``); it is deterministic:
    the same truth, the same seed and the same sequence of operations give the same samples.
    ``replay:PATH`` (a recorded run) is opened by :func:`stableins.procedures.replay.open_run_driver`,
    which reads the run's journal.
    """
    if truth is not None and spec != "sim":
        raise InputError("a known truth is simulated by the simulated platform only", field="--truth", expected="--driver sim")
    if spec == "sim":
        if truth is not None:
            return SimulatedDriver(truth, truth.seed if seed is None else seed)
        return simulated_platform(seed=0 if seed is None else seed, unit=unit, sample_rate=sample_rate)
    if spec.startswith("tcp://"):
        from stableins.drivers.tcp import connect

        return connect(spec, timeout=timeout)
    raise InputError(f"unknown driver {spec!r}", field="driver_spec", expected=SPEC_HELP)


def simulated_platform(seed: int, unit: str | None = None, sample_rate: float | None = None) -> SimulatedDriver:
    """Open the embedded simulated platform: truth drawn from ``seed``, noise from ``seed``."""
    try:
        from stableins.simulator.truth import SimulatedSite, Truth
    except ImportError as error:  # pragma: no cover - the simulator ships with stableins
        raise InputError(
            f"the simulated platform is not available ({error})", field="driver_spec", expected="tcp://HOST:PORT or replay:PATH"
        ) from None
    site = SimulatedSite(sample_rate=sample_rate, serial_number=unit) if sample_rate else SimulatedSite(serial_number=unit)
    truth = Truth.draw(seed, site=site)
    return SimulatedDriver(truth, seed)


class SimulatedDriver:
    """The simulated platform as a driver, plus the system-level recorder of the same truth.

    Device-level operations go to :class:`stableins.simulator.device.SimulatedPlatform`;
    :meth:`static_record` streams a system-level static record (INS outputs included) from
    :func:`stableins.simulator.system.system_record_chunks`.  Deterministic: the same seed and
    the same operations give the same samples.
    """

    deterministic = True

    def __init__(self, truth: Any, seed: int) -> None:
        from stableins.simulator.device import SimulatedPlatform

        self.truth = truth
        self.seed = seed
        self.platform = SimulatedPlatform(truth, seed=seed)

    @property
    def metadata(self) -> Any:
        """Return the simulated platform's site metadata."""
        return self.platform.metadata

    def command(self, readings: tuple[float, float, float]) -> float:
        """Command the simulated gimbals to ``readings`` [rad]; return the platform time."""
        return self.platform.command(readings)

    def read_angles(self) -> Any:
        """Return the simulated angle-sensor readings [rad]."""
        return self.platform.read_angles()

    def acquire(self, duration: float) -> Any:
        """Record ``duration`` seconds of simulated samples."""
        return self.platform.acquire(duration)

    def status(self) -> dict[str, object]:
        """Return the simulated platform's state."""
        return self.platform.status()

    def close(self) -> None:
        """Close the simulated platform."""
        self.platform.close()

    def install(self, values: Any, *, source: str | None = None) -> None:
        """Load the navigation computer with a calibration record's values (``Truth.with_installed``).

        A system-level run starts from the calibration the INS navigates with (``--prior``), which on a real platform
        is what was loaded into it; the simulated INS is loaded with it the same way.  Device-level samples do not
        depend on it.
        """
        self.truth = self.truth.with_installed(values, source=source)

    def static_record(self, duration: float, chunk: float, turns: Any = ()) -> Any:
        """Chunks (dicts of :data:`~stableins.schema.SYSTEM_COLUMNS`) of a static record of ``duration`` s.

        ``turns``: :class:`stableins.turns.PlatformTurn` indexing the platform by torquing during the record.
        """
        try:
            from stableins.simulator.system import indexed_record_chunks, system_record_chunks
        except ImportError as error:
            raise InputError(f"the simulated system-level recorder is not available ({error})", field="driver_spec") from None
        rate = self.platform.rate
        samples = max(1, int(round(chunk * rate)))
        if turns:
            return indexed_record_chunks(self.truth, duration, tuple(turns), rate=rate, seed=self.seed, chunk_samples=samples)
        return system_record_chunks(self.truth, duration, rate, self.seed, chunk_samples=samples)
