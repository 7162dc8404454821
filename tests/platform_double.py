"""A small deterministic platform for testing drivers and the runner before/independently of the simulator.

It is a test double, not a physics model: outputs are gravity seen through the gimbal chain of
:mod:`stableins.conventions` plus seeded white noise, so that checks (reached, still) and
sample-for-sample reproducibility can be asserted.  The truth simulator is tested elsewhere.
"""

from __future__ import annotations

import numpy as np

from stableins.conventions import dcm_body_to_platform, normal_gravity
from stableins.samples import SampleBlock
from stableins.site import SiteMetadata


class PlatformDouble:
    deterministic = True

    def __init__(self, seed: int = 0, rate: float = 20.0, noise: float = 2e-4, slew_rate: float = 0.5, offsets=(1e-3, -2e-3, 1.5e-3)):
        self.rng = np.random.default_rng(seed)
        self.rate = rate
        self.noise = noise
        self.slew_rate = slew_rate
        self.offsets = np.asarray(offsets)
        self.time = 0.0
        self.readings = np.zeros(3)
        self.drift = 0.0  # m/s^2 per s added to f (to make a dwell "not still")
        self.closed = False
        latitude = np.radians(40.0)
        self._metadata = SiteMetadata("DOUBLE-1", latitude, 50.0, float(normal_gravity(latitude, 50.0)), "WGS-84 normal gravity", rate)

    @property
    def metadata(self) -> SiteMetadata:
        return self._metadata

    def command(self, readings):
        t = self.time
        move = np.max(np.abs(np.asarray(readings, dtype=float) - self.readings))
        self.readings = np.asarray(readings, dtype=float)
        self.time += move / self.slew_rate
        return t

    def read_angles(self):
        return self.readings + self.rng.normal(0.0, 1e-6, 3)

    def acquire(self, duration):
        n = max(1, int(round(duration * self.rate)))
        t = self.time + np.arange(n) / self.rate
        self.time += n / self.rate
        c = dcm_body_to_platform(*(self.readings + self.offsets))
        f = c @ np.array([0.0, 0.0, -self._metadata.gravity])
        f = f + self.rng.normal(0.0, self.noise, (n, 3)) + self.drift * (t - t[0])[:, None]
        angles = self.readings + self.rng.normal(0.0, 1e-6, (n, 3))
        return SampleBlock(t, f, angles, 25.0 + 0.01 * self.rng.normal(size=n))

    def status(self):
        return {"driver": "double", "time": self.time, "readings": self.readings.tolist()}

    def close(self):
        self.closed = True
