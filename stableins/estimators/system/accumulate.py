r"""The system stage's one pass over the record: :class:`StageAccumulator` (``add(chunk)``, ``finish()``).

Per chunk (docs/system-calibration.md §6):

* specific force: raw outputs compensated with the installed calibration (:mod:`.compensation`), the squared-amplitude
  observation ``z`` and its harmonic information ``Σ HᵀH``, ``Σ Hᵀz``
  (:mod:`~stableins.estimators.system.harmonics`) accumulated at full rate.
  The Earth-rate angle moves by ``ω_ie/rate`` per sample, so within a block of ``B`` samples (``B/rate·ω_ie ≤ 2e-4``)
  ``cos k(S_c + δ)`` is expanded to third order in ``δ``: the trigonometric functions are evaluated once per block and
  the per-sample work is a few multiply-adds (:class:`.blocks.BlockHarmonics`).  The truncation (``(4δ)⁴/24 < 1e-15``) is far
  below double-precision round-off of the sums; :func:`.blocks.harmonic_information` is the per-sample reference it is tested
  against;
* noise: per-axis sums of squared second differences of the raw outputs on the first samples of each chunk;
* attitude, velocity and time at a decimated rate: block means of pitch and roll (:class:`.blocks.AttitudeBlocks`),
  the static-base checks and the platform-rate check (:class:`.checks.StaticChecks`);
* bins: ``Σz``, ``ΣH`` and counts over ``filter_block_seconds`` (the Kalman filter's curve and the low band of the
  coloured-noise model) and over :data:`FINE_BIN_SECONDS` (its high band) (:class:`SampleBins`).

:meth:`StageAccumulator.finish` runs the record-level checks and returns the sums as a frozen :class:`RecordSums`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, cast

import numpy as np
from numpy.typing import NDArray

from stableins.conventions import (
    EARTH_RATE,
    SIDEREAL_DAY,
    GimbalConfiguration,
    dcm_body_to_platform,
    dcm_nav_to_body,
    earth_rate_angle,
    heading_to_north_pointing,
    misalignment_pitch_roll,
)
from stableins.data.validation import check_finite
from stableins.errormodel import Term
from stableins.errors import InputError
from stableins.estimators.system import harmonics as hm
from stableins.estimators.system.blocks import (
    GIMBAL_BLOCKS,
    GIMBAL_COLUMNS,
    AttitudeBlocks,
    BlockHarmonics,
    BlockPass,
    GimbalBlocks,
    block_length,
    block_sums,
    second_difference_sums,
)
from stableins.estimators.system.checks import StageContext, StaticChecks
from stableins.estimators.system.compensation import AdditiveCompensation, Compensation
from stableins.site import SiteMetadata

#: Read at the full rate: the accelerometer outputs carry the information, the time stamps the sampling checks
#: (HDF5 records with a /time_grid: time only at the attitude decimation, the rest reconstructed).
FAST_COLUMNS = ("time", "f_x", "f_y", "f_z")
#: Checked for NaN/inf by the stage's own pass (a non-finite force makes Σz² non-finite), not by the reader.
FORCE_COLUMNS = ("f_x", "f_y", "f_z")
#: Read at the attitude decimation only (slowly varying outputs; docs/system-calibration.md §6).
SLOW_COLUMNS = ("angle_platform", "pitch", "roll", "velocity_north", "velocity_east")

#: Base pitch/roll [rad] above which the base counts as tilted (φ is then taken from the full output DCM).
LEVEL_TOLERANCE = 1e-4

#: Fine bins of z for the coloured-noise model's high band [s] (a whole number of blocks), at most :data:`FINE_BINS` of
#: them (pairs merge beyond: a week gets 240-s bins).  They carry the z channel's periodogram from the top of the low band
#: (30 cycles/day) to 0.45/width (650 cycles/day for 60 s), where the white level is pinned (docs/system-calibration.md §1a).
FINE_BIN_SECONDS = 60.0
FINE_BINS = 1 << 12


@dataclass
class SampleBins:
    """Sums of ``z``, of the ``H`` rows and sample counts over bins of ``samples`` consecutive samples (global index).

    Blocks never straddle a bin (``samples`` is a multiple of the block length and so is every chunk).  With ``cap``,
    the record never needs more than ``cap`` bins: adjacent pairs merge and ``samples`` doubles (sums add exactly, so
    this equals accumulating with the doubled width from the start), which bounds memory whatever the record length.
    """

    samples: int
    cap: int | None = None
    z: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))
    h: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 7)))
    n: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))

    def add(self, starts: NDArray[np.int64], zs: NDArray[np.float64], hs: NDArray[np.float64], counts: NDArray[np.float64]) -> None:
        """Add per-block sums; ``starts`` are the blocks' first global sample indices (in order)."""
        while self.cap is not None and int(starts[-1]) // self.samples >= self.cap:
            self._merge_pairs()
        bins = starts // self.samples
        size = int(bins[-1]) + 1
        if self.n.size < size:
            new = max(size, 2 * self.n.size)
            if self.cap is not None:
                new = min(new, self.cap)
            self.z = np.concatenate([self.z, np.zeros(new - self.z.size)])
            self.n = np.concatenate([self.n, np.zeros(new - self.n.size)])
            self.h = np.concatenate([self.h, np.zeros((new - self.h.shape[0], self.h.shape[1]))])
        first_of_bin = np.flatnonzero(np.r_[True, bins[1:] != bins[:-1]])  # blocks are in order: bins are runs
        ids = bins[first_of_bin]
        self.z[ids] += np.add.reduceat(zs, first_of_bin)
        self.h[ids] += np.add.reduceat(hs, first_of_bin, axis=0)
        self.n[ids] += np.add.reduceat(counts, first_of_bin)

    def _merge_pairs(self) -> None:
        if self.n.size % 2:
            self.z, self.n = np.append(self.z, 0.0), np.append(self.n, 0.0)
            self.h = np.vstack([self.h, np.zeros((1, self.h.shape[1]))])
        self.z = self.z.reshape(-1, 2).sum(axis=1)
        self.n = self.n.reshape(-1, 2).sum(axis=1)
        self.h = self.h.reshape(-1, 2, self.h.shape[1]).sum(axis=1)
        self.samples *= 2


def earth_angle_from_kinematics(
    chunk: Mapping[str, NDArray[np.float64]],
    sel: Any,
    offsets: NDArray[np.float64],
    nav_to_body: NDArray,
    config: GimbalConfiguration,
) -> NDArray[np.float64]:
    """Unwrapped Earth-rate angle ``S = atan2(u_y, u_x)``, ``u = −C_b^p(α) C_n^b e_D`` on the selected samples."""
    alpha = [chunk[name][sel] + offsets[k] for k, name in enumerate(("angle_platform", "angle_inner", "angle_middle"))]
    c_bp = dcm_body_to_platform(alpha[0], alpha[1], alpha[2], 0.0, config)
    u = -(c_bp @ nav_to_body[:, 2])
    return np.unwrap(np.arctan2(u[:, 1], u[:, 0]))


@dataclass(frozen=True)
class TemperatureSummary:
    """The record's temperature column, when it has one [°C] (read at the attitude decimation)."""

    mean: float
    min: float
    max: float

    def to_dict(self) -> dict[str, float]:
        """Return the JSON form."""
        return {"mean": self.mean, "min": self.min, "max": self.max}


@dataclass
class TemperatureBins:
    """Sums and counts of the temperature column over bins of ``samples`` consecutive samples (global index), as the filter bins."""

    samples: int
    total: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))
    count: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))

    def add(self, rows: NDArray[np.int64], values: NDArray[np.float64]) -> None:
        """Add the temperatures read at global rows ``rows``."""
        bins = rows // self.samples
        size = int(bins[-1]) + 1
        if self.count.size < size:
            grow = max(size, 2 * self.count.size) - self.count.size
            self.total, self.count = np.concatenate([self.total, np.zeros(grow)]), np.concatenate([self.count, np.zeros(grow)])
        self.total += np.bincount(bins, weights=values, minlength=self.total.size)
        self.count += np.bincount(bins, minlength=self.count.size)

    def merged(self, samples: int) -> TemperatureBins:
        """Return the sums over bins of ``samples`` (a power-of-two multiple of :attr:`samples`, as :class:`SampleBins` merge)."""
        factor = samples // self.samples
        size = -(-self.count.size // factor) * factor
        total, count = np.zeros(size), np.zeros(size)
        total[: self.total.size], count[: self.count.size] = self.total, self.count
        return TemperatureBins(samples, total.reshape(-1, factor).sum(axis=1), count.reshape(-1, factor).sum(axis=1))


@dataclass(frozen=True)
class RecordSums:
    """What one pass over the record leaves for the solve steps (:meth:`StageAccumulator.finish`).

    Attributes
    ----------
    information : hm.InformationAccumulator
        ``Σ HᵀH``, ``Σ Hᵀz``, ``Σ z²`` and the sample count of the harmonic fit.
    filter_bins, fine_bins : SampleBins
        ``Σz``, ``ΣH``, counts over the filter bins and over the fine bins of the coloured-noise model.
    attitude_blocks : AttitudeBlocks
        Block means of pitch and roll (north-pointing pair) and of ``cos S``, ``sin S``.
    noise_sums : ndarray, shape (3,)
        Per-axis sums of squared second differences of the raw outputs; ``noise_count`` of them per axis.
    samples : int
        Samples in the record.
    duration : float
        Last minus first time stamp [s].
    block : int
        Samples per harmonic block (:func:`.blocks.block_length`).
    decimation : int
        Samples per attitude sample.
    checks : StaticChecks
        The sampling and static-base checks (their summary goes into the diagnostics).
    temperature : TemperatureSummary or None
        The temperature column's mean and range (None without one).
    notes : tuple of str
        What the record-level checks found (gaps, jitter).
    gimbal_blocks : GimbalBlocks or None
        Block means of the three gimbal readings (the gyro drift, :mod:`.gyro_drift`); None when the record has no
        inner and middle readings.
    temperature_bins : TemperatureBins or None
        Sums of the temperature column over the filter bins (the thermal model, :mod:`.thermal`; None without one).
    fine_temperature_bins : TemperatureBins or None
        The same over the fine bins (the thermal terms taken out of the high band before the noise decision).
    level_yaw : float or None
        The surveyed heading [rad] of a level base, whose pitch and roll are Euler angles turned to the north-pointing
        pair (their second order in a large misalignment is :func:`.loop.drift_curvature`); None for a tilted base (the
        pair from the antisymmetric part of the output DCM, odd in the misalignment).
    """

    information: hm.InformationAccumulator
    filter_bins: SampleBins
    fine_bins: SampleBins
    attitude_blocks: AttitudeBlocks
    noise_sums: NDArray[np.float64]
    noise_count: int
    samples: int
    duration: float
    block: int
    decimation: int
    checks: StaticChecks
    temperature: TemperatureSummary | None
    notes: tuple[str, ...]
    gimbal_blocks: GimbalBlocks | None = None
    temperature_bins: TemperatureBins | None = None
    fine_temperature_bins: TemperatureBins | None = None
    level_yaw: float | None = 0.0


@dataclass(frozen=True)
class SourceContents:
    """What a record's source provides besides the specific force and the attitude (:class:`StageAccumulator`).

    ``has_temperature``: a temperature column; ``has_gimbals``: the inner and middle gimbal readings (the gyro drift,
    :mod:`.gyro_drift`); ``time_grid``: the source's time grid (:class:`stableins.data.chunks.GriddedChunkSource`) and
    ``grid_time`` its reconstruction of the stamps of rows ``[start, stop)``.
    """

    has_temperature: bool = False
    has_gimbals: bool = True
    time_grid: NDArray[np.float64] | None = None
    grid_time: Callable[[int, int], NDArray[np.float64]] | None = None


class StageAccumulator:
    """The stage's streaming pass: ``add(chunk)`` for each chunk in order, then ``finish()`` (see the module docstring).

    Parameters
    ----------
    metadata : SiteMetadata
        Gimbal senses and base attitude of the record.
    prior : mapping
        Installed calibration (record values) the outputs are compensated with.
    context : StageContext
        The record's name, its checked site values (:func:`.checks.check_metadata`) and the options (chunk size,
        decimation, bin widths, limits of the checks).
    compensation_terms : sequence of Term
        Discovered additive terms of the prior (:class:`.compensation.AdditiveCompensation`).
    source : SourceContents
        What the source provides besides the specific force (temperature, gimbal readings, a time grid).
    """

    def __init__(
        self,
        metadata: SiteMetadata,
        prior: Mapping[str, float],
        context: StageContext,
        *,
        compensation_terms: Sequence[Term] = (),
        source: SourceContents = SourceContents(),
    ) -> None:
        path, options, site = context.path, context.options, context.site
        latitude, gravity, rate = site.latitude, site.gravity, site.rate
        has_temperature, has_gimbals, time_grid = source.has_temperature, source.has_gimbals, source.time_grid
        self.path, self.options = path, options
        self.config = GimbalConfiguration(cast("tuple[int, int, int, int]", tuple(metadata.gimbal_senses)))
        self.theta10 = float(prior.get("theta10", 0.0))
        base = tuple(float(a) for a in (metadata.base_attitude or (0.0, 0.0, 0.0)))
        self.yaw = base[0]
        # level base: (δpitch, δroll) = R(ψ)(−φ_E, −φ_N) exactly to first order.  A tilted base mixes the azimuth
        # error φ_D into pitch and roll (tilt × φ_D, 1e-6 rad per degree): then φ comes from the full output DCM.
        self.tilted = max(abs(base[1]), abs(base[2])) > LEVEL_TOLERANCE
        self.base_dcm_t = dcm_nav_to_body(*base).T
        columns = list(FAST_COLUMNS + SLOW_COLUMNS) + (["heading"] if self.tilted else [])
        # Earth-rate angle: on a level, north-pointing base S = −s1·α1 (conventions.earth_rate_angle).  Otherwise the
        # gimbal angles no longer separate that way: S = atan2(u_y, u_x) with u = f^p/g = −C_n^p e_D from the exact
        # kinematics C_n^p = C_b^p(α) C_n^b(base), evaluated on the decimated samples and interpolated (S is smooth).
        self.general = self.tilted or abs(base[0]) > LEVEL_TOLERANCE
        self.offsets = np.array([float(prior.get(k, 0.0)) for k in ("theta10", "theta20", "theta30")])
        self.nav_to_body = dcm_nav_to_body(*base)
        self.has_gimbals = has_gimbals
        if self.general or has_gimbals:
            columns += list(GIMBAL_COLUMNS)
        self.gimbal_blocks: GimbalBlocks | None = None
        self.has_temperature = has_temperature
        if has_temperature:
            columns.append("temperature")  # read at the attitude decimation: what the data carry about the environment
        self.temperature = [math.inf, -math.inf, 0.0, 0]  # min, max, sum, count
        compensation = Compensation.from_values(prior)
        self.additive = AdditiveCompensation.from_prior(compensation_terms, prior, path)
        self.block = block = block_length(rate)
        self.chunk_rows = max(block, (options.chunk_rows // block) * block)
        self.decimation = max(1, int(round(options.attitude_decimation_seconds * rate)))
        self.filter_samples = max(block, int(round(options.filter_block_seconds * rate / block)) * block)
        self.harmonics = BlockHarmonics(latitude, block)
        self.packed = compensation.packed(gravity)
        self.step_range = (0.99 / rate, 1.01 / rate)
        self.block_pass = BlockPass(self.packed, block, EARTH_RATE, self.step_range)
        self.attitude_blocks: AttitudeBlocks | None = None
        self.noise_sums = np.zeros(3)
        self.noise_count = 0
        self.filter_bins = SampleBins(self.filter_samples)
        self.temperature_bins = TemperatureBins(self.filter_samples)  # the thermal model's ΔT on the filter bins
        self.fine_bins = SampleBins(max(block, int(round(FINE_BIN_SECONDS * rate / block)) * block), cap=FINE_BINS)
        self.fine_temperature = TemperatureBins(self.fine_bins.samples)  # merged like the fine bins at the end
        self.checks = StaticChecks(options, rate, path, defer_to_gimbals=has_gimbals)  # the gimbal fit decides (polar.check_deferred)
        self.checks.latitude = latitude
        self.seen = 0
        self.first_time: float | None = None
        self.columns = columns
        self.thin = [c for c in columns if c not in FAST_COLUMNS]
        # an HDF5 record's /time_grid: uniformly sampled stretches are reconstructed, not read (time then comes at 1 Hz only)
        self.grid, self.grid_time = time_grid, source.grid_time
        if time_grid is not None:
            self.thin.append("time")
        self.knot_time: float | None = None  # last Earth-rate-angle knot of the previous chunk
        self.knot_angle = 0.0

    def add(self, chunk: Mapping[str, NDArray[np.float64]]) -> None:
        """One chunk of the record (columns :attr:`columns`, the :attr:`thin` ones at every :attr:`decimation`-th row)."""
        n = len(chunk["f_x"])
        if n == 0:
            return
        fx, fy, fz = chunk["f_x"], chunk["f_y"], chunk["f_z"]
        if self.additive is not None:
            fx, fy, fz = self.additive(fx, fy, fz)
        seen, decimation = self.seen, self.decimation
        phase = (-seen) % decimation
        time, t_d, uniform = self._time(chunk, n, phase)
        # the one pass over every sample: z and its per-block moments, block mean times, irregular steps
        sums, block_time, sum_z2, irregular = block_sums(fx, fy, fz, time, self.block_pass, grid=uniform)
        if not (math.isfinite(sum_z2) and np.isfinite(sums[:, 0]).all()):  # a NaN or ±inf force propagates into Σz²
            for name, values in zip(FORCE_COLUMNS, (fx, fy, fz), strict=True):
                check_finite(name, values, self.path, first_row=seen + 1)
        if uniform is None:
            assert time is not None  # stamps are read or reconstructed unless the chunk is on one uniform segment
            span = (float(time[0]), float(time[-1]))
        else:
            span = (uniform[0], uniform[0] + (n - 1) * uniform[1])
        self.checks.time(time, span, seen, irregular)
        if self.first_time is None:
            self.first_time = span[0]
            self.attitude_blocks = AttitudeBlocks(self.options.attitude_block_seconds, self.first_time)
            if self.has_gimbals:
                self.gimbal_blocks = GimbalBlocks(self.options.attitude_block_seconds, self.first_time, max_blocks=GIMBAL_BLOCKS)
        if self.general:
            s_d = earth_angle_from_kinematics(chunk, slice(None), self.offsets, self.nav_to_body, self.config)
        else:
            s_d = earth_rate_angle(chunk["angle_platform"] + self.theta10, self.config)
        pitch_d, roll_d = chunk["pitch"], chunk["roll"]
        # static checks and the unwrapped Earth-rate angle at the decimated samples
        s_knots = self.checks.slow(t_d, s_d, pitch_d, roll_d, chunk["velocity_north"], ve=chunk["velocity_east"])
        centre_angle = self._centre_angle(block_time, t_d, s_knots, span)
        zs, hs, counts = self.harmonics.add_sums(centre_angle, sums, sum_z2)
        # filter bins (600 s) and the fine bins of the coloured-noise model's high band, by global sample index
        starts = seen + np.arange(len(counts)) * self.block
        self.filter_bins.add(starts, zs, hs, counts)
        self.fine_bins.add(starts, zs, hs, counts)
        # noise from second differences of the raw outputs
        self.noise_count += second_difference_sums(fx, fy, fz, self.options.noise_samples_per_chunk, self.noise_sums)
        p0, r0 = self._north_attitude(chunk, pitch_d, roll_d)
        assert self.attitude_blocks is not None  # created at the first chunk
        self.attitude_blocks.add(t_d, np.cos(s_d), np.sin(s_d), p0, r0)
        self._add_readings(chunk, t_d)
        sparse = slice(phase, None, 10 * decimation)  # the polar check is a record mean: one sample per 10 decimated ones
        self.checks.polar(fx[sparse], fy[sparse], fz[sparse])
        if self.has_temperature and chunk["temperature"].size:
            tc = chunk["temperature"]
            t = self.temperature
            self.temperature = [min(t[0], float(tc.min())), max(t[1], float(tc.max())), t[2] + float(tc.sum()), t[3] + tc.size]
            rows = seen + phase + decimation * np.arange(tc.size)
            self.temperature_bins.add(rows, tc)
            self.fine_temperature.add(rows, tc)
        self.seen += n

    def _add_readings(self, chunk: Mapping[str, NDArray[np.float64]], t_d: NDArray[np.float64]) -> None:
        """Add the decimated gimbal readings to their blocks (the gyro drift, :mod:`.gyro_drift`)."""
        if self.gimbal_blocks is not None:
            self.gimbal_blocks.add_readings(t_d, chunk["angle_platform"], chunk["angle_inner"], chunk["angle_middle"])

    def _time(
        self, chunk: Mapping[str, NDArray[np.float64]], n: int, phase: int
    ) -> tuple[NDArray[np.float64] | None, NDArray[np.float64], tuple[float, float] | None]:
        """Return the chunk's full-rate stamps (None on a uniform grid segment), its decimated ones and ``(t_0, period)``."""
        seen, grid = self.seen, self.grid
        if grid is None:
            time = chunk["time"]
            return time, time[phase :: self.decimation], None
        t_d = chunk["time"]
        k = int(np.searchsorted(grid[:, 0], seen, side="right")) - 1
        inside = (k + 1 == len(grid) or seen + n <= grid[k + 1, 0]) and (seen == 0 or grid[k, 0] < seen)
        if inside:  # one segment, not starting at this chunk: t = t_0 + j·period
            return None, t_d, (float(grid[k, 1] + (seen - grid[k, 0]) * grid[k, 2]), float(grid[k, 2]))
        assert self.grid_time is not None  # a gridded source has both
        return self.grid_time(seen, seen + n), t_d, None  # a segment boundary (gap or irregular steps): stamps from the grid

    def _centre_angle(
        self, block_time: NDArray[np.float64], t_d: NDArray[np.float64], s_knots: NDArray[np.float64], span: tuple[float, float]
    ) -> NDArray[np.float64]:
        """``S`` at each block's mean time: linear between the knots (1 s apart, ``S`` is smooth).

        The previous chunk's last knot before the first and the Earth rate after the last (the platform is inertially
        held: ``dS/dt = ω_ie``).
        """
        kt = t_d if self.knot_time is None else np.concatenate([[self.knot_time], t_d])
        ks = s_knots if self.knot_time is None else np.concatenate([[self.knot_angle], s_knots])
        kt = np.concatenate([kt, [span[1] + 1.0]])
        ks = np.concatenate([ks, [ks[-1] + EARTH_RATE * (span[1] + 1.0 - kt[-2])]])
        if kt[0] > span[0]:  # no knot yet before the first block (first chunk starts at a knot; kept for safety)
            kt = np.concatenate([[span[0]], kt])
            ks = np.concatenate([[ks[0] - EARTH_RATE * (kt[1] - span[0])], ks])
        centre_angle = np.interp(block_time, kt, ks)
        self.knot_time, self.knot_angle = float(t_d[-1]), float(s_knots[-1])
        return centre_angle

    def _north_attitude(
        self, chunk: Mapping[str, NDArray[np.float64]], pitch_d: NDArray[np.float64], roll_d: NDArray[np.float64]
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Pitch and roll errors as the north-pointing pair the loop model outputs.

        Level base with heading ψ: :func:`stableins.conventions.heading_to_north_pointing`.  Tilted base:
        :func:`stableins.conventions.misalignment_pitch_roll` of ``C_n^b(base)ᵀ C_n^b'``.
        """
        if self.tilted:
            return misalignment_pitch_roll(self.base_dcm_t @ dcm_nav_to_body(chunk["heading"], pitch_d, roll_d))
        return heading_to_north_pointing(pitch_d, roll_d, self.yaw)

    def finish(self) -> RecordSums:
        """Record-level checks (no samples, moving or misaligned base, too short, too few noise samples) and the sums."""
        seen, options, path = self.seen, self.options, self.path
        if seen == 0 or self.attitude_blocks is None:
            raise InputError("the record has no samples", path=path)
        notes: list[str] = []
        self.checks.finish(seen, notes)
        duration = self.checks.duration
        if duration < options.minimum_duration:
            day = f"{SIDEREAL_DAY / 3600:.2f} h"
            raise InputError(
                f"the record lasts {duration / 3600:.2f} h; the Earth-rate harmonics cannot be separated from the mean and the Schuler "
                f"transient in less than {options.minimum_duration / 3600:.1f} h",
                path=path,
                field="time",
                expected=f"at least {options.minimum_duration / 3600:.1f} h, ideally one sidereal day ({day}) or more",
            )
        if self.noise_count < 10:
            raise InputError("too few samples to measure the accelerometer noise", path=path)
        t = self.temperature
        return RecordSums(
            information=self.harmonics.accumulator(),
            filter_bins=self.filter_bins,
            fine_bins=self.fine_bins,
            attitude_blocks=self.attitude_blocks,
            noise_sums=self.noise_sums,
            noise_count=self.noise_count,
            samples=seen,
            duration=duration,
            block=self.block,
            decimation=self.decimation,
            checks=self.checks,
            temperature=None if t[3] == 0 else TemperatureSummary(t[2] / t[3], t[0], t[1]),
            notes=tuple(notes),
            gimbal_blocks=self.gimbal_blocks,
            temperature_bins=self.temperature_bins if t[3] else None,
            fine_temperature_bins=self.fine_temperature.merged(self.fine_bins.samples) if t[3] else None,
            level_yaw=None if self.tilted else self.yaw,
        )


__all__ = [
    "FAST_COLUMNS",
    "FINE_BINS",
    "FINE_BIN_SECONDS",
    "SourceContents",
    "FORCE_COLUMNS",
    "SLOW_COLUMNS",
    "RecordSums",
    "SampleBins",
    "StageAccumulator",
    "TemperatureBins",
    "TemperatureSummary",
    "earth_angle_from_kinematics",
]
