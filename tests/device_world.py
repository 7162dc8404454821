"""A minimal exact platform for the device-level tests (independent of the estimators).

Outputs come from ErrorModel.forward and the exact gimbal chain of stableins.conventions
with white noise; nothing here calls estimator code.  The full truth simulator
(stableins.simulator) is used where it is available.
"""

from __future__ import annotations

import numpy as np

from stableins import conventions as cv
from stableins.errormodel import ErrorModel
from stableins.samples import SampleBlock
from stableins.site import SiteMetadata

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


def outputs(truth, readings, gravity=GRAVITY, senses=(1, 1, 1, 1), base=(0.0, 0.0, 0.0), model=TRUTH_MODEL):
    """Exact accelerometer outputs at angle-sensor readings ``(..., 3)`` (``model`` may add the simulator's effect terms)."""
    config = cv.GimbalConfiguration(tuple(senses))
    offsets = np.array([truth["theta10"], truth["theta20"], truth["theta30"]])
    alpha = cv.actual_gimbal_angles(readings, offsets)
    c = cv.dcm_body_to_platform(alpha[..., 0], alpha[..., 1], alpha[..., 2], 0.0, config)
    f_n = cv.specific_force_nav(gravity)
    f_p = np.einsum("...ij,jk,k->...i", c, cv.dcm_nav_to_body(*base), f_n)
    return model.forward(f_p, truth)


class ExactPlatform:
    """PlatformDriver over the exact model with white noise ``sigma`` per sample."""

    def __init__(self, truth, sigma=1e-3, rate=100.0, seed=0, senses=(1, 1, 1, 1), gravity=GRAVITY, transform=None, model=TRUTH_MODEL):
        self.truth = truth
        self.model = model  # the world's error model (the standard one, or with the simulator's effect terms)
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
        f = outputs(self.truth, self.readings, self.gravity, self.senses, model=self.model) + self.sigma * self.rng.normal(size=(n, 3))
        if self.transform is not None:
            f = self.transform(f)
        return SampleBlock(t, f, np.tile(self.readings, (n, 1)), np.full(n, 25.0))

    def status(self):
        return {"time": self.time}

    def close(self):
        pass


def device_columns(
    truth,
    procedure,
    sigma=1e-3,
    seed=0,
    stage="coarse",
    pass_number=1,
    offsets=(0.0, 0.0, 0.0),
    senses=(1, 1, 1, 1),
    rate=100.0,
    dwell=None,
    settle=None,
    model=TRUTH_MODEL,
):
    """Samples of one pass as DEVICE_COLUMNS arrays (settle samples included, tagged by time_since_command)."""
    rng = np.random.default_rng(seed)
    cols = {
        k: []
        for k in (
            "time",
            "stage",
            "pass",
            "position",
            "time_since_command",
            "command_platform",
            "command_inner",
            "command_middle",
            "angle_platform",
            "angle_inner",
            "angle_middle",
            "f_x",
            "f_y",
            "f_z",
            "temperature",
        )
    }
    t0 = 0.0
    for step in procedure.steps:
        command = np.array([step.command[0], step.command[1] - offsets[1], step.command[2] - offsets[2]])
        s = step.settle if settle is None else settle
        d = step.dwell if dwell is None else dwell
        n = int(round((s + d) * rate))
        since = np.arange(n) / rate
        f = outputs(truth, command, senses=senses, model=model) + sigma * rng.normal(size=(n, 3))
        cols["time"].append(t0 + since)
        cols["time_since_command"].append(since)
        cols["stage"].append(np.full(n, stage))
        cols["pass"].append(np.full(n, pass_number))
        cols["position"].append(np.full(n, step.position))
        for i, g in enumerate(("platform", "inner", "middle")):
            cols[f"command_{g}"].append(np.full(n, command[i]))
            cols[f"angle_{g}"].append(np.full(n, command[i]))
        for i, a in enumerate("xyz"):
            cols[f"f_{a}"].append(f[:, i])
        cols["temperature"].append(np.full(n, 25.0))
        t0 += n / rate + 3.0
    return {k: np.concatenate(v) for k, v in cols.items()}
