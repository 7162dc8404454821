"""From a streamed system record to the filter's steps: turns, reading noise, substep geometry, pre-integrated observations.

Two passes over the record, both in bounded memory (:mod:`stableins.data.chunks`): :func:`scan_record` finds the
turns (the gimbal readings at 1 Hz moving faster than :data:`stableins.estimators.drift.holds.MOVING_RATE`, with
:data:`~stableins.estimators.drift.holds.MOVE_MARGIN` either side) and measures the angle-sensor noise; then
:class:`StepBuilder` turns each filter step of ``Δ`` seconds into its input maps at ``m`` substeps (geometry from the
substep means of the readings) and its observations (module docstring of :mod:`~stableins.estimators.systematic.model`).
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from stableins.conventions import EARTH_RATE, GimbalConfiguration, dcm_body_to_platform, dcm_nav_to_body, earth_rate_nav, skew
from stableins.data.chunks import ChunkSource, source_path
from stableins.errormodel import CORE_IDS, GIMBAL_IDS, ErrorModel, known_terms
from stableins.errors import InputError
from stableins.estimators.drift.holds import MOVE_MARGIN, MOVING_RATE, small_angle_vector
from stableins.estimators.systematic.model import StepGeometry, input_map
from stableins.platform import rotation_about
from stableins.site import SiteMetadata
from stableins.terms import CROSS_COUPLING_TERMS

#: Record columns the systematic stage reads.
RECORD_COLUMNS = (
    "time",
    "angle_platform",
    "angle_inner",
    "angle_middle",
    "velocity_north",
    "velocity_east",
    "velocity_down",
    "roll",
    "pitch",
    "heading",
)
_ANGLES = ("angle_platform", "angle_inner", "angle_middle")
#: Gimbal-angle step of the numerical ``J_α`` [rad].
_ANGLE_STEP = 1e-6


@dataclass(frozen=True)
class RecordScan:
    """What the first pass finds.

    Attributes
    ----------
    start, rate : float
        First time stamp [s] and sample rate [Hz].
    samples : int
    turns : tuple of (float, float)
        Time intervals [s] with a gimbal moving, margins included.
    angle_noise : ndarray (3,)
        White noise of the three angle sensors [rad] (second differences, robust).
    """

    start: float
    rate: float
    samples: int
    turns: tuple[tuple[float, float], ...]
    angle_noise: NDArray[np.float64]

    @property
    def holds(self) -> int:
        """Number of holds (``turns + 1``)."""
        return len(self.turns) + 1

    def turn_rates(self, time: NDArray[np.float64], rates: NDArray[np.float64]) -> NDArray[np.float64]:
        """``(n, turns)``: the platform's inertial rate [rad/s] at ``time`` in the column of the turn it belongs to."""
        out = np.zeros((len(time), len(self.turns)))
        for j, (a, b) in enumerate(self.turns):
            inside = (time >= a) & (time <= b)
            out[inside, j] = rates[inside]
        return out

    def hold_of(self, first: float, last: float) -> int:
        """Hold index of the window ``[first, last]``, −1 when it overlaps a turn."""
        for k, (a, b) in enumerate(self.turns):
            if last >= a and first <= b:
                return -1
            if last < a:
                return k
        return len(self.turns)


def scan_record(source: ChunkSource, rate: float, rows: int) -> RecordScan:
    """First pass: turns and angle noise (:class:`RecordScan`)."""
    lag = max(1, int(round(rate)))
    moving: list[list[float]] = []
    noise: list[NDArray[np.float64]] = []
    last: NDArray[np.float64] | None = None
    start, count = np.nan, 0
    for chunk in source.iter_chunks(["time", *_ANGLES], rows):
        time = np.asarray(chunk["time"], dtype=float)
        angles = np.stack([np.asarray(chunk[a], dtype=float) for a in _ANGLES], axis=1)
        if count == 0 and len(time):
            start = float(time[0])
        offset = (-count) % lag
        count += len(time)
        if len(angles) > 2:
            second = np.diff(angles, 2, axis=0)
            noise.append(1.4826 * np.median(np.abs(second - np.median(second, axis=0)), axis=0) / np.sqrt(6.0))
        thin, t_thin = angles[offset::lag], time[offset::lag]
        if last is not None and len(thin):
            thin, t_thin = np.vstack([last[1:][None, :], thin]), np.concatenate([[last[0]], t_thin])
        if len(thin) > 1:
            speed = np.abs(np.diff(thin, axis=0)).max(axis=1) / np.diff(t_thin)
            for t in t_thin[1:][speed > MOVING_RATE]:
                _add_moving(moving, float(t) - 1.0, float(t))
            last = np.concatenate([[t_thin[-1]], thin[-1]])
        elif len(thin):
            last = np.concatenate([[t_thin[-1]], thin[-1]])
    if count < 2:
        raise InputError("fewer than two samples", path=source_path(source), field="time", expected="a system-level record")
    turns = tuple((a - MOVE_MARGIN, b + MOVE_MARGIN) for a, b in moving)
    return RecordScan(start, rate, count, turns, np.median(np.array(noise), axis=0))


def _add_moving(intervals: list[list[float]], first: float, last: float) -> None:
    """Append ``[first, last]``, merged with the previous interval when they are within two margins."""
    if intervals and first <= intervals[-1][1] + 2 * MOVE_MARGIN:
        intervals[-1][1] = last
    else:
        intervals.append([first, last])


@dataclass(frozen=True)
class Linearization:
    """Where the model is linearized: the installed calibration plus the current estimate of the residuals.

    Attributes
    ----------
    values : mapping
        The installed calibration (record values) [SI].
    error_model : ErrorModel
        The record's model (its Jacobians define the accelerometer part of ``F``).
    accelerometer : ndarray (a,), optional
        Current estimate of the residuals ``ids`` (default zero), added to ``values`` for the Jacobians.
    offsets, base : ndarray (3,)
        Current estimate of the zero-offset residuals and the base error (geometry of the forcing).
    ids : tuple of str
        The residuals, :attr:`~stableins.estimators.systematic.model.StateLayout.accelerometer_ids` (the core ids by
        default); a cross-coupling the record's model does not hold joins it at its reference value (0).
    """

    values: Mapping[str, float]
    error_model: ErrorModel
    accelerometer: NDArray[np.float64] | None = None
    offsets: NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))
    base: NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))
    ids: tuple[str, ...] = CORE_IDS

    def __post_init__(self) -> None:
        if self.accelerometer is None:
            object.__setattr__(self, "accelerometer", np.zeros(len(self.ids)))
        elif len(self.accelerometer) != len(self.ids):
            raise ValueError(f"{len(self.accelerometer)} residuals for {len(self.ids)} ids")

    @property
    def residuals(self) -> NDArray[np.float64]:
        """The current estimate of the residuals ``ids`` [SI]."""
        assert self.accelerometer is not None  # set in __post_init__
        return self.accelerometer

    def installed_offsets(self) -> NDArray[np.float64]:
        """Installed zero offsets ``θ_i0`` [rad]."""
        return np.array([float(self.values.get(g, 0.0)) for g in GIMBAL_IDS])

    def model(self) -> ErrorModel:
        """Return the record's error model with every term of ``ids`` it lacks (the core terms, a new cross-coupling)."""
        terms = known_terms(CROSS_COUPLING_TERMS)
        return self.error_model + tuple(terms[i] for i in self.ids if i not in self.error_model)

    def accelerometer_map(self, specific_force: NDArray[np.float64]) -> NDArray[np.float64]:
        """``J_f⁻¹ J_p`` (n, 3, a) at the linearization point for ``ids`` (:meth:`ErrorModel.jacobian`, additive terms too)."""
        model = self.model()
        values = dict(self.values)
        for name, delta in zip(self.ids, self.residuals, strict=True):
            values[name] = float(values.get(name, model[name].reference)) + float(delta)
        jac = model.jacobian(specific_force, values)[..., [model.index(i) for i in self.ids]]
        return np.asarray(np.linalg.solve(model.jacobian_specific_force(specific_force, values), jac), dtype=np.float64)


@dataclass(frozen=True)
class HoldSummary:
    """One orientation the record held: when, and the specific force it showed in the platform frame.

    Attributes
    ----------
    index : int
    start, end : float
        First and last step end in the hold [s].
    specific_force : tuple of float
        Mean ``f^p/g`` over the hold.
    polar_angle : float
        Mean angle between ``z_p`` and the Earth's axis [rad] (0: polar-aligned).
    """

    index: int
    start: float
    end: float
    specific_force: tuple[float, float, float]
    polar_angle: float


@dataclass
class _HoldSums:
    count: int = 0
    start: float = np.inf
    end: float = -np.inf
    force: NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))
    polar: float = 0.0


@dataclass
class StepBatch:
    """Consecutive filter steps: end times, input maps, geometry, observations and their covariances."""

    time: NDArray[np.float64]
    inputs: NDArray[np.float64]
    geometry: list[StepGeometry]
    observations: NDArray[np.float64]
    covariances: NDArray[np.float64]
    density_nav: NDArray[np.float64]


class StepBuilder:
    """Second pass: the record's filter steps (:class:`StepBatch` per chunk).

    Parameters
    ----------
    site : SiteMetadata
    scan : RecordScan
    linearization : Linearization
    step : float
        ``Δ`` [s], a whole number of substeps.
    substeps : int
        ``m``.
    noise : tuple
        ``(white PSD per axis [(m/s²)²/Hz], quantization per axis [m/s], slow-noise columns)``.
    """

    def __init__(
        self,
        site: SiteMetadata,
        scan: RecordScan,
        linearization: Linearization,
        *,
        step: float,
        substeps: int,
        noise: tuple[NDArray[np.float64], NDArray[np.float64], int],
    ) -> None:
        self.site, self.scan, self.lin = site, scan, linearization
        self.rows_step = int(round(step * scan.rate))
        self.rows_sub = self.rows_step // substeps
        if self.rows_sub * substeps != self.rows_step or abs(self.rows_step / scan.rate - step) > 1e-9 * step:
            raise InputError(
                f"a filter step of {step:g} s is not a whole number of {substeps} substeps at {scan.rate:g} Hz",
                field="step", expected="a step that is a multiple of substeps/rate",
            )  # fmt: skip
        self.step, self.substeps = step, substeps
        self.configuration = GimbalConfiguration(tuple(site.gimbal_senses))  # type: ignore[arg-type]
        self.survey = dcm_nav_to_body(*site.base_attitude)
        self.axis = skew(earth_rate_nav(site.latitude) / EARTH_RATE)
        self.white, self.quantization, self.noise_columns = noise
        self.references: dict[tuple[str, int], NDArray[np.float64]] = {}
        self._sums: dict[tuple[str, int], TurnSum] = {}
        self._holds: dict[int, _HoldSums] = {}

    def _earth(self, time: NDArray[np.float64]) -> NDArray[np.float64]:
        theta = EARTH_RATE * (time - self.scan.start)
        return np.eye(3) + np.sin(theta)[..., None, None] * self.axis + (1.0 - np.cos(theta))[..., None, None] * (self.axis @ self.axis)

    def _body_to_platform(self, angles: NDArray[np.float64], offsets: NDArray[np.float64]) -> NDArray[np.float64]:
        a = angles + offsets
        return dcm_body_to_platform(a[..., 0], a[..., 1], a[..., 2], 0.0, self.configuration)

    def batches(self, source: ChunkSource, rows: int) -> Iterator[StepBatch]:
        """Yield the steps of the record, chunk by chunk (a trailing partial step is dropped)."""
        tail: dict[str, NDArray[np.float64]] | None = None
        for chunk in source.iter_chunks(list(RECORD_COLUMNS), rows):
            data = {c: np.asarray(chunk[c], dtype=float) for c in RECORD_COLUMNS}
            if tail is not None:
                data = {c: np.concatenate([tail[c], data[c]]) for c in RECORD_COLUMNS}
            whole = len(data["time"]) // self.rows_step * self.rows_step
            tail = {c: data[c][whole:] for c in RECORD_COLUMNS}
            if whole:
                yield self._batch({c: data[c][:whole] for c in RECORD_COLUMNS})

    def _batch(self, data: Mapping[str, NDArray[np.float64]]) -> StepBatch:
        s, m, r = len(data["time"]) // self.rows_step, self.substeps, self.rows_sub
        angles = np.stack([data[a] for a in _ANGLES], axis=1).reshape(s, m, r, 3)
        mean_angles = angles.mean(axis=2)
        mean_time = data["time"].reshape(s, m, r).mean(axis=2)
        installed = self.lin.installed_offsets()
        point = installed + self.lin.offsets
        # geometry at the linearization point (zero offsets and base corrected by the estimate): the forcing, ρ and ψ
        base = self.survey @ rotation_about(self.lin.base)  # exact: a first-order base leaves Ω×O(δ²) as an apparent drift
        nav_to_platform = self._body_to_platform(mean_angles, point) @ base
        f_p = -self.site.gravity * nav_to_platform[..., :, 2]
        flat = f_p.reshape(-1, 3)
        accel = self.lin.accelerometer_map(flat)
        inertial = nav_to_platform @ self._earth(mean_time).swapaxes(-1, -2)
        rates = self._inertial_rates(angles, data["time"].reshape(s, m, r), (point, base)).ravel()
        turn_rates = self.scan.turn_rates(mean_time.ravel(), rates)
        inputs = input_map(nav_to_platform.reshape(-1, 3, 3), accel, flat, turn_rates, self.noise_columns).reshape(s, m, 9, -1)
        end = slice(self.rows_step - 1, None, self.rows_step)
        end_angles = np.stack([data[a][end] for a in _ANGLES], axis=1)
        end_time = data["time"][end]
        output = dcm_nav_to_body(data["heading"][end], data["pitch"][end], data["roll"][end])
        # d: the computer's platform from its attitude output and the readings with the offsets it used (noise cancels)
        computed_inertial = self._body_to_platform(end_angles, installed) @ output @ self._earth(end_time).swapaxes(-1, -2)
        end_nav_to_platform = self._body_to_platform(end_angles, point) @ base
        end_inertial = end_nav_to_platform @ self._earth(end_time).swapaxes(-1, -2)  # M at the step ends (the point)
        offset_map = self._offset_map(mean_angles, point)
        offset_end = self._offset_map(end_angles, point)
        # ψ: the output against the base at the point; the computer's offsets are the installed ones
        known = np.einsum("sji,sjk,k->si", end_nav_to_platform, offset_end, self.lin.offsets)
        survey_attitude = small_angle_vector(output.swapaxes(1, 2) @ base) + known
        z = np.zeros((s, 12))
        cov = np.zeros((s, 12, 12))
        z[:, 0], z[:, 1], z[:, 2] = data["velocity_north"][end], data["velocity_east"][end], data["velocity_down"][end]
        q2 = self.quantization**2
        geometry = []
        for k in range(s):
            first = float(data["time"][k * self.rows_step])
            hold = self.scan.hold_of(first - 1.0 / self.scan.rate, float(end_time[k]))
            cov[k, :3, :3] = nav_to_platform[k, -1].T @ np.diag(q2) @ nav_to_platform[k, -1]
            means = (nav_to_platform[k].mean(axis=0), offset_map[k].mean(axis=0), f_p[k].mean(axis=0))
            geometry.append(StepGeometry(hold, end_nav_to_platform[k], *means, offset_end[k]))
            if hold < 0:
                continue
            self._summarize(hold, float(end_time[k]), means[2], end_nav_to_platform[k])
            # ρ and d: the platform's turn as the sum of its increments (θ = ∫w, no composition terms; TurnSum)
            z[k, 3:6] = self._turned("rho", hold, inertial[k, 0]) + small_angle_vector(inertial[k] @ inertial[k, 0].T).mean(axis=0)
            computer = small_angle_vector(computed_inertial[k] @ end_inertial[k].T)  # rv(P Mᵀ) = −C_n^p φ
            turned = self._turned("end", hold, end_inertial[k])
            z[k, 6:9] = computer + turned - self.references.setdefault(("att", hold), computer)
            jm = geometry[-1].offset_map_mean
            cov[k, 3:6, 3:6] = jm @ np.diag(self.scan.angle_noise**2) @ jm.T / self.rows_step
            cov[k, 6:9, 6:9] = np.eye(3) * ATTITUDE_FLOOR**2
            z[k, 9:12] = survey_attitude[k]
            je = end_nav_to_platform[k].T @ offset_end[k]
            cov[k, 9:12, 9:12] = je @ np.diag(self.scan.angle_noise**2) @ je.T
        density = np.einsum("sij,j,sjk->sik", nav_to_platform[:, m // 2].swapaxes(1, 2), self.white, nav_to_platform[:, m // 2])
        return StepBatch(end_time, inputs, geometry, z, cov, density)

    def _turned(self, kind: str, hold: int, attitude: NDArray[np.float64]) -> NDArray[np.float64]:
        """Return the sum of the increments of ``attitude`` (``M``) since the hold's first step (:class:`TurnSum`)."""
        turned = self._sums.setdefault((kind, hold), TurnSum(attitude))
        return turned.advance(attitude)

    def _summarize(self, hold: int, time: float, force: NDArray[np.float64], nav_to_platform: NDArray[np.float64]) -> None:
        sums = self._holds.setdefault(hold, _HoldSums())
        sums.count += 1
        sums.start, sums.end = min(sums.start, time), max(sums.end, time)
        sums.force += force / self.site.gravity
        axis = earth_rate_nav(self.site.latitude) / EARTH_RATE
        sums.polar += float(np.arccos(np.clip(nav_to_platform[2] @ axis, -1.0, 1.0)))

    def holds(self) -> tuple[HoldSummary, ...]:
        """Return the holds seen so far (:class:`HoldSummary`), in order."""
        out = []
        for k in sorted(self._holds):
            h = self._holds[k]
            f = h.force / h.count
            out.append(HoldSummary(k, h.start, h.end, (float(f[0]), float(f[1]), float(f[2])), h.polar / h.count))
        return tuple(out)

    def _inertial_rates(
        self, angles: NDArray[np.float64], time: NDArray[np.float64], point: tuple[NDArray[np.float64], NDArray[np.float64]]
    ) -> NDArray[np.float64]:
        """``|ω|`` [rad/s] (s, m): the platform's inertial turn from the first to the last sample of each substep (central)."""
        ends = [self._body_to_platform(angles[:, :, k], point[0]) @ point[1] @ self._earth(time[:, :, k]).swapaxes(-1, -2) for k in (0, -1)]
        span = time[:, :, -1] - time[:, :, 0]
        angle = np.linalg.norm(small_angle_vector(ends[1] @ ends[0].swapaxes(-1, -2)), axis=-1)
        return angle / np.where(span > 0, span, 1.0)

    def _offset_map(self, angles: NDArray[np.float64], installed: NDArray[np.float64]) -> NDArray[np.float64]:
        """``J_α`` (…, 3, 3): rotation vector of ``Ĉ_b^p(α + h e_i) Ĉ_b^p(α)ᵀ`` per radian (central differences)."""
        columns = []
        for i in range(3):
            step = np.zeros(3)
            step[i] = _ANGLE_STEP
            plus = self._body_to_platform(angles, installed + step)
            minus = self._body_to_platform(angles, installed - step)
            columns.append(small_angle_vector(plus @ minus.swapaxes(-1, -2)) / (2 * _ANGLE_STEP))
        return np.stack(columns, axis=-1)


@dataclass
class TurnSum:
    r"""The platform's inertial turn since a hold's first step as the sum of its step increments: the filter's ``θ``.

    The filter's ``θ̇ = −ε_eff`` (platform frame) is linear: ``θ = ∫w``.  The rotation vector of ``M M_refᵀ``
    (``M = C_n^p E^T`` from the readings) is not: it obeys Bortz's ``ρ̇ = w + ½ ρ × w + …``, and with a drift
    (``ρ ≈ ε t``, 2e-4 rad after 12 h of 0.001 °/h) across a g-sensitive drift turning at the Earth's rate
    (``|D_g g|`` ≈ 1e-8 rad/s) the term integrates to ~1e-8 rad, a systematic error the linear ``H`` cannot follow
    (docs/systematic-calibration.md §3, issue 18).  The sum of the increments ``rv(M_k M_{k−1}ᵀ)`` over filter steps
    is ``∫w`` to ``½|Δθ||w|Δ`` per step (1e-19 rad); the readings' noise telescopes (first order), so ``R`` is
    unchanged.  ``d`` is formed the same way: ``P = R M`` with ``R = P Mᵀ = rot(−C_n^p φ)`` exactly (``P`` the
    computer's inertial attitude), so

    .. math:: d = \mathrm{rv}(P M^T) + \textstyle\sum \mathrm{rv}(M_k M_{k-1}^T) - \mathrm{rv}(P_{ref} M_{ref}^T)
              = θ - C_n^p φ + c

    without the composition term ``½ θ × C_n^p φ`` of ``rv(P P_refᵀ)`` (1e-7 rad after a day of 0.001 °/h); the
    readings' noise cancels between the terms to first order, as it did in ``P``.

    Attributes
    ----------
    last : ndarray (3, 3)
        ``M`` of the last step.
    total : ndarray (3,)
        The sum of the increments so far [rad].
    """

    last: NDArray[np.float64]
    total: NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))

    def advance(self, attitude: NDArray[np.float64]) -> NDArray[np.float64]:
        """Add the increment from the last ``M`` to ``attitude``; return the sum."""
        self.total = self.total + small_angle_vector(attitude @ self.last.T)
        self.last = attitude
        return self.total


#: Standard deviation assigned to the attitude observation ``d`` [rad]: it carries no sensor noise (the angle noise
#: cancels); this covers single-precision attitude outputs (6e-8 rad near 1 rad) and the loop's discretization (the
#: composition term ``½ θ × C_n^p φ`` is taken out by :class:`TurnSum`).
ATTITUDE_FLOOR = 1e-7
