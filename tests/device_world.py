"""A minimal exact platform for the device-level tests (independent of the estimators).

Outputs come from ErrorModel.forward and the exact gimbal chain of stableins.conventions
with white noise; nothing here calls estimator code.  The full truth simulator
(stableins.simulator) is used where it is available.
"""

from __future__ import annotations

import numpy as np

from stableins import conventions as cv
from stableins.data.metadata import SiteMetadata
from stableins.drivers.base import SampleBlock
from stableins.errormodel import ErrorModel

GRAVITY = float(cv.normal_gravity(np.radians(40.0)))
TRUTH_MODEL = ErrorModel.standard(nonlinear=True, gimbals=True)


def draw_truth(rng, quadratic=True, offset_scale=1.0):
    """Random device: nominal magnitudes of every term (K2 zero unless ``quadratic``)."""
    v = {t.id: t.reference + rng.normal() * t.nominal for t in TRUTH_MODEL}
    for g in ("theta10", "theta20", "theta30"):
        v[g] *= offset_scale
    if not quadratic:
        for a in "xyz":
            v[f"K2_{a}"] = 0.0
    return v


def outputs(truth, readings, gravity=GRAVITY, senses=(1, 1, 1, 1), base=(0.0, 0.0, 0.0)):
    """Exact accelerometer outputs at angle-sensor readings ``(..., 3)``."""
    config = cv.GimbalConfiguration(tuple(senses))
    offsets = np.array([truth["theta10"], truth["theta20"], truth["theta30"]])
    alpha = cv.actual_gimbal_angles(readings, offsets)
    c = cv.dcm_body_to_platform(alpha[..., 0], alpha[..., 1], alpha[..., 2], 0.0, config)
    f_n = cv.specific_force_nav(gravity)
    f_p = np.einsum("...ij,jk,k->...i", c, cv.dcm_nav_to_body(*base), f_n)
    return TRUTH_MODEL.forward(f_p, truth)


class ExactPlatform:
    """PlatformDriver over the exact model with white noise ``sigma`` per sample."""

    def __init__(self, truth, sigma=1e-3, rate=100.0, seed=0, senses=(1, 1, 1, 1), gravity=GRAVITY, transform=None):
        self.truth = truth
        self.sigma = sigma
        self.rate = rate
        self.rng = np.random.default_rng(seed)
        self.senses = senses
        self.gravity = gravity
        self.transform = transform  # optional fault: f (n,3) -> f (n,3)
        self.readings = np.zeros(3)
        self.time = 0.0
        self.commands = []
        self._meta = SiteMetadata("TEST-1", np.radians(40.0), 0.0, gravity, "WGS-84 normal gravity", rate, tuple(senses))

    @property
    def metadata(self):
        return self._meta

    def command(self, readings):
        self.readings = np.array(readings, dtype=float)
        self.commands.append(tuple(readings))
        return self.time

    def read_angles(self):
        return self.readings.copy()

    def acquire(self, duration):
        n = int(round(duration * self.rate))
        t = self.time + np.arange(n) / self.rate
        self.time += n / self.rate
        f = outputs(self.truth, self.readings, self.gravity, self.senses) + self.sigma * self.rng.normal(size=(n, 3))
        if self.transform is not None:
            f = self.transform(f)
        return SampleBlock(t, f, np.tile(self.readings, (n, 1)), np.full(n, 25.0))

    def status(self):
        return {"time": self.time}

    def close(self):
        pass
