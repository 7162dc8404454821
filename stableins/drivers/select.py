"""Open a platform driver from a ``--driver`` specification: ``sim``, ``tcp://HOST:PORT`` or ``replay:PATH``."""

from __future__ import annotations

from typing import Any

from stableins.data.errors import InputError
from stableins.drivers.base import PlatformDriver

SPEC_HELP = "sim, tcp://HOST:PORT or replay:PATH"


def is_deterministic(driver: Any) -> bool:
    """Whether the driver answers the same operations with the same results (sim, replay)."""
    return bool(getattr(driver, "deterministic", False))


def open_driver(
    spec: str, *, seed: int | None = None, unit: str | None = None, sample_rate: float | None = None, timeout: float = 10.0
) -> PlatformDriver:
    """The driver named by ``spec``.

    ``sim`` builds the embedded simulated platform (:mod:`stableins.simulator`) with a truth
    drawn from ``seed`` and serial number ``unit``; it is deterministic: the same seed and
    the same sequence of operations give the same samples.
    """
    if spec == "sim":
        return simulated_platform(seed=0 if seed is None else seed, unit=unit, sample_rate=sample_rate)
    if spec.startswith("tcp://"):
        from stableins.drivers.tcp import connect

        return connect(spec, timeout=timeout)
    if spec.startswith("replay:"):
        from stableins.drivers.replay import ReplayDriver

        return ReplayDriver(spec[len("replay:") :])
    raise InputError(f"unknown driver {spec!r}", field="--driver", expected=SPEC_HELP)


def simulated_platform(seed: int, unit: str | None = None, sample_rate: float | None = None) -> PlatformDriver:
    """The embedded simulated platform: truth drawn from ``seed``, noise from ``seed``."""
    try:
        from stableins.simulator.device import SimulatedPlatform
        from stableins.simulator.truth import Truth
    except ImportError as error:  # pragma: no cover - the simulator ships with stableins
        raise InputError(
            f"the simulated platform is not available ({error})", field="--driver", expected="tcp://HOST:PORT or replay:PATH"
        ) from None
    truth = Truth.draw(seed, **({"sample_rate": sample_rate} if sample_rate else {}), serial_number=unit)
    driver = SimulatedPlatform(truth, seed=seed)
    driver.deterministic = True  # the same seed and operations give the same samples
    return driver
