r"""Block means of the decimated attitude record in bounded memory (:class:`AttitudeBlocks`; the attitude fit's input).

:class:`GimbalBlocks` keeps the gimbal readings on the same bins (the gyro drift, :mod:`.gyro_drift`).  docs/system-calibration.md §2, §6.

The one pass over every sample
------------------------------
Per-block sums of the squared-amplitude observation: the system stage's one pass over every sample.

For each sample the installed calibration is applied in closed form (Wu et al. 2018 Eq. 8, see
:class:`stableins.estimators.system.stage._Compensation`) and the squared-amplitude observation of
:mod:`~stableins.estimators.system.harmonics` is formed:

.. math::

    u = f^a - \delta b,\qquad w_i = u_i - K_{2i} u_i^2,\qquad
    z = \tfrac12\left(w^\mathsf{T} Q w / g^2 - 1\right),\qquad Q = M^\mathsf{T} M .

For each block of ``B`` samples with mean time :math:`\bar t` and :math:`\delta_n = \omega_{ie}(t_n - \bar t)`
(the Earth-rate angle's offset from the block centre) the pass returns

.. math::

    n_p = \sum z_n \delta_n^p\ (p = 0..3),\qquad m_p = \sum \delta_n^p\ (p = 1..3),\qquad B,

with :math:`\bar t`, :math:`\sum z^2` and the number of time steps outside an accepted range (the
sampling check: only a chunk with such steps is examined step by step).  The stage turns these into
the harmonic information by a third-order expansion of :math:`\cos k(S_c + \delta)` (module docstring of
:mod:`.stage`).  Exact time stamps are used, so jittered sampling needs no second path.

The pass is numpy, a few passes per sample over sub-chunks of :data:`SUB_CHUNK` samples whose work arrays stay
in the processor's cache (about 5 ns/sample on a time grid; 2-MB temporaries per chunk cost 40-50 ns/sample in
page faults).  On a time grid every full block has the same offsets :math:`\delta_j`, so the four moments of all
blocks are one matrix product, taken with numpy's own loops (``einsum``): a threaded BLAS, a library user's
default, stalled on a loaded machine (1.8 s of CPU for the pass over a day at 100 Hz instead of 0.18 s).  It was
compiled with numba (about 1 ns/sample), whose import and compiled-code cache cost a fresh process about 0.5 s of
CPU: more than the numpy pass over two weeks at 100 Hz (issue 30).  A NaN or ±inf input propagates into
:math:`\sum z^2`, which is how the stage detects one without a separate pass.
:func:`block_sums_reference` is the numpy reference it is tested against.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np
from numpy.typing import NDArray

from stableins.conventions import EARTH_RATE
from stableins.estimators.system import harmonics as hm


@dataclass
class AttitudeBlocks:
    """Block means of the attitude record (streaming accumulator) in bounded memory.

    Blocks are fixed time bins of ``block_seconds`` from ``start_time``; each keeps the sample
    count and the sums of time, ``cos S``, ``sin S``, pitch and roll.  When the record would need
    more than ``max_blocks`` bins, adjacent pairs are merged and ``block_seconds`` doubles (sums
    add exactly, so this equals accumulating with the doubled width from the start): memory is
    bounded by ``6 · max_blocks`` values whatever the record length, and so is the cost of the fit.  The
    default, 2¹⁴ bins, keeps the 10-s blocks up to 1.9 days; a week gets 40-s blocks, still 126 times shorter
    than the Schuler period.  They attenuate the 8-minute case-rotation nuisance by 1.1 % (its amplitude is
    free, so nothing is biased) and the Earth-rate harmonics by about 1e-6 of their size (the block means of
    ``cos S`` and ``sin S`` are exact; ``cos 2S`` from them is second order in the block's angle).
    """

    block_seconds: float
    start_time: float
    max_blocks: int = 1 << 14
    sums: dict[str, NDArray[np.float64]] = field(default_factory=dict)

    _KEYS: ClassVar[tuple[str, ...]] = ("count", "time", "cos", "sin", "pitch", "roll")

    def add(
        self,
        time: NDArray[np.float64],
        cos_s: NDArray[np.float64],
        sin_s: NDArray[np.float64],
        pitch: NDArray[np.float64],
        roll: NDArray[np.float64],
    ) -> None:
        """Add decimated samples (time, ``cos S``, ``sin S``, pitch, roll) to their blocks."""
        self._accumulate(time, {"cos": cos_s, "sin": sin_s, "pitch": pitch, "roll": roll})

    def _accumulate(self, time: NDArray[np.float64], columns: dict[str, NDArray[np.float64]]) -> None:
        """Add samples of ``columns`` (the keys of :attr:`_KEYS` but count and time) at ``time`` to their blocks."""
        while True:
            index = np.floor((time - self.start_time) / self.block_seconds).astype(np.int64)
            if int(index[-1]) < self.max_blocks:
                break
            self._merge_pairs()
        lo = int(index[0])
        local = index - lo
        size = int(local[-1]) + 1
        values = {"count": None, "time": time - self.start_time, **columns}
        needed = lo + size
        for key in self._KEYS:
            arr = self.sums.get(key)
            if arr is None:
                arr = np.zeros(min(max(needed, 1024), self.max_blocks))
            elif arr.size < needed:
                arr = np.concatenate([arr, np.zeros(min(max(needed - arr.size, arr.size), self.max_blocks - arr.size))])
            arr[lo:needed] += np.bincount(local, weights=values[key], minlength=size)
            self.sums[key] = arr

    def _merge_pairs(self) -> None:
        """Merge bins ``(2j, 2j+1)`` into bin ``j`` and double ``block_seconds``."""
        for key, arr in self.sums.items():
            if arr.size % 2:
                arr = np.append(arr, 0.0)
            self.sums[key] = arr.reshape(-1, 2).sum(axis=1)
        self.block_seconds *= 2.0

    def means(self) -> dict[str, NDArray[np.float64]]:
        """Return the block means of the non-empty blocks (``count``, ``time`` since the start, ``cos``, ``sin``, pitch, roll)."""
        count = self.sums["count"]
        keep = count > 0
        out = {"count": count[keep]}
        for key in self._KEYS[1:]:
            out[key] = self.sums[key][keep] / count[keep]
        norm = np.hypot(out["cos"], out["sin"])  # block averaging shrinks (cos, sin) by ~1 − (ωT)²/24
        out["cos"], out["sin"] = out["cos"] / norm, out["sin"] / norm
        return out


#: The readings besides the platform angle that the drift needs (read at the attitude decimation).
GIMBAL_COLUMNS = ("angle_inner", "angle_middle")

#: Blocks of gimbal readings at most (pairs merge beyond: 43-s blocks for one day, 5 min for a week).
GIMBAL_BLOCKS = 1 << 11


@dataclass
class GimbalBlocks(AttitudeBlocks):
    """Block means of the three gimbal readings (platform angle unwrapped), on the attitude blocks' time bins.

    Same bins and merging as :class:`.blocks.AttitudeBlocks`, at most :data:`GIMBAL_BLOCKS` of them: the readings are
    linear in time within a block (the platform angle turns at the Earth rate, the others stand still), so the mean
    readings are the readings at the mean time whatever the width, and the fit's cost stays small.
    """

    _KEYS: ClassVar[tuple[str, ...]] = ("count", "time", "platform", "inner", "middle")
    _last_platform: float | None = None

    def add_readings(
        self, time: NDArray[np.float64], platform: NDArray[np.float64], inner: NDArray[np.float64], middle: NDArray[np.float64]
    ) -> None:
        """Add decimated readings [rad]; the platform angle is unwrapped across chunks (a record may wrap it)."""
        if time.size == 0:
            return
        previous = platform[:1] if self._last_platform is None else np.array([self._last_platform])
        unwrapped = np.unwrap(np.concatenate([previous, platform]))[1:]  # continuous with the previous chunk's last value
        self._last_platform = float(unwrapped[-1])
        self._accumulate(time, {"platform": unwrapped, "inner": inner, "middle": middle})

    def means(self) -> dict[str, NDArray[np.float64]]:
        """Return the block means of the non-empty blocks (``count``, ``time`` since the start, the three readings)."""
        count = self.sums["count"]
        keep = count > 0
        out = {"count": count[keep]}
        for key in self._KEYS[1:]:
            out[key] = self.sums[key][keep] / count[keep]
        return out


#: Columns of the per-block sums: n0, n1, n2, n3 (Σ z δ^p), m1, m2, m3 (Σ δ^p), count.
SUM_COLUMNS = ("n0", "n1", "n2", "n3", "m1", "m2", "m3", "count")

#: Samples per numpy pass inside a chunk (a power of two, so a multiple of every block length up to it): the pass's
#: five work arrays, 128 KiB each, stay in the cache and are reused, where arrays of a whole chunk cost page faults.
SUB_CHUNK = 1 << 14


def coefficients(
    matrix: NDArray[np.float64], bias: NDArray[np.float64], quadratic: NDArray[np.float64], gravity: float
) -> NDArray[np.float64]:
    """Packed ``(δb_x, δb_y, δb_z, q00, 2q01, 2q02, q11, 2q12, q22, K2_x, K2_y, K2_z)`` with ``q = MᵀM/(2g²)``."""
    q = np.einsum("ki,kj->ij", matrix, matrix) / (2.0 * gravity**2)
    return np.array([*bias, q[0, 0], 2 * q[0, 1], 2 * q[0, 2], q[1, 1], 2 * q[1, 2], q[2, 2], *quadratic], dtype=float)


def _observation(x, y, z, p):  # floats or arrays alike
    """``z = ½(wᵀQw/g² − 1)`` of each sample (Q/(2g²) and the bias, K2 packed in ``p``: :func:`coefficients`)."""
    w0 = x - p[0]
    w1 = y - p[1]
    w2 = z - p[2]
    w0 = w0 - p[9] * w0 * w0
    w1 = w1 - p[10] * w1 * w1
    w2 = w2 - p[11] * w2 * w2
    return w0 * (p[3] * w0 + p[4] * w1 + p[5] * w2) + w1 * (p[6] * w1 + p[7] * w2) + p[8] * w2 * w2 - 0.5


def _observation_into(
    force: tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]],
    p: list[float],
    out: NDArray[np.float64],
    work: tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]],
) -> None:
    """:func:`_observation` of the samples ``force = (fx, fy, fz)`` into ``out``, in place with the four work arrays (no temporaries)."""
    w0, w1, w2, tmp = work
    for w, f, bias, k2 in ((w0, force[0], p[0], p[9]), (w1, force[1], p[1], p[10]), (w2, force[2], p[2], p[11])):
        np.subtract(f, bias, out=w)
        np.multiply(w, w, out=tmp)
        tmp *= k2
        w -= tmp
    np.multiply(w0, p[3], out=out)
    np.multiply(w1, p[4], out=tmp)
    out += tmp
    np.multiply(w2, p[5], out=tmp)
    out += tmp
    out *= w0  # w0 (q00 w0 + 2q01 w1 + 2q02 w2)
    np.multiply(w1, p[6], out=tmp)
    np.multiply(w2, p[7], out=w0)
    tmp += w0
    tmp *= w1  # w1 (q11 w1 + 2q12 w2)
    out += tmp
    np.multiply(w2, w2, out=tmp)
    tmp *= p[8]
    out += tmp
    out -= 0.5


def _grid_moments(size: int, angle_step: float) -> NDArray[np.float64]:
    """``(4, size)``: ``δ_j^p`` (p = 0..3) of a block of ``size`` samples on a grid, ``δ_j = (j − (size − 1)/2)·angle_step``."""
    d = (np.arange(size) - 0.5 * (size - 1)) * angle_step
    return np.stack([np.ones(size), d, d * d, d * d * d])


def _stamped_moments(
    z: NDArray[np.float64], times: NDArray[np.float64], omega: float, rows: NDArray[np.float64], work: tuple[NDArray[np.float64], ...]
) -> NDArray[np.float64]:
    """Fill ``rows`` ``(k, 8)`` with the sums of ``k`` blocks of stamped samples ``z, times (k, size)``; return their mean times."""
    centre = times.sum(axis=1) / times.shape[1]
    d = np.subtract(times, centre[:, None], out=work[0][: times.size].reshape(times.shape))
    d *= omega
    zd = np.multiply(z, d, out=work[1][: times.size].reshape(times.shape))
    dd = np.multiply(d, d, out=work[2][: times.size].reshape(times.shape))
    rows[:, 0] = z.sum(axis=1)
    rows[:, 1] = zd.sum(axis=1)
    rows[:, 4] = d.sum(axis=1)
    rows[:, 5] = dd.sum(axis=1)
    zd *= d
    rows[:, 2] = zd.sum(axis=1)
    zd *= d
    rows[:, 3] = zd.sum(axis=1)
    dd *= d
    rows[:, 6] = dd.sum(axis=1)
    rows[:, 7] = times.shape[1]
    return centre


@dataclass(frozen=True)
class BlockPass:
    """What the per-block pass needs besides the samples: the installed calibration and the record's sampling.

    Attributes
    ----------
    packed : ndarray (12,)
        :func:`coefficients` of the installed calibration.
    block : int
        Samples per block (the last block of a chunk may be shorter).
    omega : float
        Rate of the Earth-rate angle [rad/s].
    step_range : (float, float)
        Accepted time steps ``[low, high]`` [s]; steps outside are counted.
    """

    packed: NDArray[np.float64]
    block: int
    omega: float
    step_range: tuple[float, float]


def block_sums(
    fx: NDArray[np.float64],
    fy: NDArray[np.float64],
    fz: NDArray[np.float64],
    time: NDArray[np.float64] | None,
    settings: BlockPass,
    *,
    grid: tuple[float, float] | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.float64], float, int]:
    """Per-block sums of one chunk (the pass over every sample, in sub-chunks of :data:`SUB_CHUNK`).

    Parameters
    ----------
    fx, fy, fz : ndarray (n,)
        Raw accelerometer outputs [m/s²] (finite).
    time : ndarray (n,) or None
        Time stamps [s]; None with ``grid``.
    settings : BlockPass
        The installed calibration, block length, Earth-rate-angle rate and accepted time steps.
    grid : (float, float), optional
        ``(t_0, period)``: uniformly sampled chunk, ``t_j = t_0 + j·period`` (the stamps are not read).

    Returns
    -------
    sums : ndarray (n_blocks, 8)
        :data:`SUM_COLUMNS` per block.
    centres : ndarray (n_blocks,)
        Mean time of each block [s].
    sum_z2 : float
        ``Σ z²`` over the chunk.
    irregular : int
        Number of time steps inside the chunk outside ``step_range``.
    """
    p = [float(v) for v in settings.packed]
    block, omega = int(settings.block), float(settings.omega)
    low, high = float(settings.step_range[0]), float(settings.step_range[1])
    force = tuple(np.asarray(f, dtype=float) for f in (fx, fy, fz))
    n = force[0].size
    n_blocks = -(-n // block)
    sums = np.empty((n_blocks, len(SUM_COLUMNS)))
    centres = np.empty(n_blocks)
    sub = max(1, SUB_CHUNK // block) * block  # whole blocks
    work = tuple(np.empty(min(sub, n)) for _ in range(5))
    stamps = None if grid is not None else np.asarray(time, dtype=float)
    moments: dict[int, NDArray[np.float64]] = {}  # δ^p of a block on the grid, per block length
    total = 0.0
    with np.errstate(invalid="ignore", over="ignore"):  # a non-finite force shows in Σz² (the caller then names its row)
        for a in range(0, n, sub):
            m = min(sub, n - a)
            z = work[4][:m]
            piece = (force[0][a : a + m], force[1][a : a + m], force[2][a : a + m])
            _observation_into(piece, p, z, (work[0][:m], work[1][:m], work[2][:m], work[3][:m]))
            total += float(np.einsum("i,i->", z, z))  # einsum, not BLAS: a threaded BLAS stalls on a loaded machine
            full = m // block
            short = m - full * block
            for first, count, size in ((0, full, block), (full * block, int(short > 0), short)):  # the full blocks, a short last one
                if count == 0:
                    continue
                rows = slice((a + first) // block, (a + first) // block + count)
                zb = z[first : first + count * size].reshape(count, size)
                if grid is None:
                    assert stamps is not None
                    times = stamps[a + first : a + first + count * size].reshape(count, size)
                    centres[rows] = _stamped_moments(zb, times, omega, sums[rows], work)
                    continue
                if size not in moments:
                    moments[size] = _grid_moments(size, omega * float(grid[1]))
                powers = moments[size]
                sums[rows, 0:4] = np.einsum("bj,pj->bp", zb, powers)  # not BLAS (above); both operands contiguous in j
                sums[rows, 4:7] = powers[1:].sum(axis=1)
                sums[rows, 7] = size
                centres[rows] = float(grid[0]) + (a + first + np.arange(count) * size + 0.5 * (size - 1)) * float(grid[1])
    if grid is not None:
        irregular = 0 if low <= float(grid[1]) <= high else max(n - 1, 0)
    else:
        assert stamps is not None
        irregular = 0
        for a in range(0, n - 1, sub):  # the steps t[j+1] − t[j], sub-chunk by sub-chunk
            e = min(a + sub, n - 1)
            steps = np.subtract(stamps[a + 1 : e + 1], stamps[a:e], out=work[0][: e - a])
            irregular += int(np.count_nonzero(steps < low)) + int(np.count_nonzero(steps > high))
    return sums, centres, total, irregular


def harmonic_sums(
    centre_angle: NDArray[np.float64],
    sums: NDArray[np.float64],
    order: int,
    cos_latitude: float,
    trig_sums: NDArray[np.float64],
    *,
    z_sums: NDArray[np.float64],
) -> NDArray[np.float64]:
    r"""Trigonometric and z sums of the blocks, accumulated into ``trig_sums`` and ``z_sums`` in place.

    With :math:`S = S_c + \delta` in each block and :math:`\cos k\delta`, :math:`\sin k\delta` to third order in
    :math:`\delta` (:math:`(k\delta)^4/24 < 10^{-15}` for the block lengths used):

    .. math::

        \sum \cos kS = \cos kS_c\,(B - \tfrac{k^2}{2} m_2) - \sin kS_c\,(k m_1 - \tfrac{k^3}{6} m_3),

    likewise :math:`\sum \sin kS` and, with :math:`n_p` for :math:`m_p`, :math:`\sum z\cos kS`,
    :math:`\sum z \sin kS`.  ``trig_sums`` holds :math:`C_0..C_{2m}, S_0..S_{2m}` and ``z_sums``
    :math:`ZC_0..ZC_m, ZS_0..ZS_m` (``m = order``).  Returns the per-block ``ΣH`` rows ``(n_blocks, 2m+1)``:
    ``B, a C_1, a S_1, a² C_2, ...`` with ``a = cos L`` (the filter bins).
    """
    nk = 2 * order + 1
    n0, n1, n2, n3, m1, m2, m3, count = (np.asarray(sums[:, i], dtype=float) for i in range(len(SUM_COLUMNS)))
    angle = np.asarray(centre_angle, dtype=float)
    h = np.empty((angle.size, nk))
    c1, s1 = np.cos(angle), np.sin(angle)
    ck, sk = np.ones_like(c1), np.zeros_like(c1)
    trig_sums[0] += count.sum()
    z_sums[0] += n0.sum()
    h[:, 0] = count
    weight = 1.0
    for k in range(1, nk):
        ck, sk = ck * c1 - sk * s1, sk * c1 + ck * s1  # cos kS_c, sin kS_c by the angle-sum recurrence
        even = count - 0.5 * k * k * m2
        odd = k * m1 - k * k * k * m3 / 6.0
        cos_sum = ck * even - sk * odd
        sin_sum = sk * even + ck * odd
        trig_sums[k] += cos_sum.sum()
        trig_sums[nk + k] += sin_sum.sum()
        if k <= order:
            weight *= cos_latitude
            h[:, 2 * k - 1] = weight * cos_sum
            h[:, 2 * k] = weight * sin_sum
            zeven = n0 - 0.5 * k * k * n2
            zodd = k * n1 - k * k * k * n3 / 6.0
            z_sums[k] += (ck * zeven - sk * zodd).sum()
            z_sums[order + 1 + k] += (sk * zeven + ck * zodd).sum()
    return h


def second_difference_sums(
    fx: NDArray[np.float64], fy: NDArray[np.float64], fz: NDArray[np.float64], m: int, out: NDArray[np.float64]
) -> int:
    r"""Add :math:`\sum (\Delta^2 f)^2` of the first ``m`` samples of each axis to ``out`` (3,); returns the terms added.

    For white noise of variance :math:`\sigma^2`, :math:`E[(\Delta^2 n)^2] = 6\sigma^2`; the Earth-rate signal
    (:math:`\omega_{ie}^2 g /\text{rate}^2` per step) does not reach it.
    """
    m = min(int(m), fx.size)
    if m < 3:
        return 0
    for axis, f in enumerate((fx, fy, fz)):
        f = np.asarray(f[:m], dtype=float)
        second = f[2:] - 2.0 * f[1:-1]
        second += f[:-2]
        out[axis] += float(np.einsum("i,i->", second, second))  # not BLAS (block_sums)
    return m - 2


def observation(
    fx: NDArray[np.float64], fy: NDArray[np.float64], fz: NDArray[np.float64], packed: NDArray[np.float64]
) -> NDArray[np.float64]:
    """``z = ½(|f^p|²/g² − 1)`` of each sample: the formula of the pass (:func:`block_sums` applies it in place)."""
    return _observation(
        np.asarray(fx, dtype=float), np.asarray(fy, dtype=float), np.asarray(fz, dtype=float), np.asarray(packed, dtype=float)
    )


def block_sums_reference(
    fx: NDArray[np.float64],
    fy: NDArray[np.float64],
    fz: NDArray[np.float64],
    time: NDArray[np.float64],
    settings: BlockPass,
) -> tuple[NDArray[np.float64], NDArray[np.float64], float, int]:
    """Compute the same sums with numpy array operations (the reference :func:`block_sums` is tested against)."""
    packed, block, omega, step_range = settings.packed, settings.block, settings.omega, settings.step_range
    z = observation(fx, fy, fz, packed)
    n = z.size
    starts = np.arange(0, n, block)
    counts = np.minimum(block, n - starts).astype(float)
    centres = np.add.reduceat(time, starts) / counts
    d = omega * (time - np.repeat(centres, counts.astype(int)))
    sums = np.stack(
        [np.add.reduceat(v, starts) for v in (z, z * d, z * d * d, z * d**3, d, d * d, d**3)] + [counts],
        axis=1,
    )
    steps = np.diff(time)
    irregular = int(np.count_nonzero((steps < step_range[0]) | (steps > step_range[1])))
    return sums, centres, float(np.sum(z * z)), irregular


# --------------------------------------------------------------------------- the harmonic information from the block sums
def harmonic_information(
    earth_angle: NDArray[np.float64], z: NDArray[np.float64], latitude: float, order: int = 3
) -> hm.InformationAccumulator:
    """Per-sample reference: ``Σ HᵀH``, ``Σ Hᵀz`` with ``H`` evaluated sample by sample."""
    acc = hm.InformationAccumulator(n_states=2 * order + 1)
    acc.add(hm.harmonic_rows(earth_angle, latitude, order=order), z)
    return acc


@dataclass
class BlockHarmonics:
    """Block-Taylor accumulation of the harmonic information (see the module docstring)."""

    latitude: float
    block: int
    order: int = 3  # highest harmonic of S in H
    trig_sums: NDArray[np.float64] = field(init=False)  # C_0..C_2m, S_0..S_2m
    z_sums: NDArray[np.float64] = field(init=False)  # ZC_0..ZC_m, ZS_0..ZS_m
    sum_z2: float = 0.0
    count: int = 0

    def __post_init__(self) -> None:
        self.trig_sums = np.zeros(2 * (2 * self.order + 1))
        self.z_sums = np.zeros(2 * (self.order + 1))

    @property
    def columns(self) -> list[tuple[int, int]]:
        """``(k, kind)`` of the H columns, kind 0 = cos, 1 = sin: 1, cos S, sin S, cos 2S, ..."""
        return [(0, 0)] + [(k, t) for k in range(1, self.order + 1) for t in (0, 1)]

    def add_sums(
        self, centre_angle: NDArray[np.float64], sums: NDArray[np.float64], sum_z2: float
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """Accumulate one chunk's per-block sums (:func:`.blocks.block_sums`).

        ``centre_angle`` is ``S`` at each block's mean time; within the block ``S = S_c + δ`` with
        ``δ = ω_ie (t − t̄)`` (the platform is inertially held, so ``S`` advances at the Earth rate).
        Returns per-block ``(Σz, ΣH (n_blocks, 2·order+1), n)`` for the filter bins.
        """
        self.sum_z2 += float(sum_z2)
        self.count += int(round(float(sums[:, 7].sum())))
        h = harmonic_sums(centre_angle, sums, self.order, math.cos(self.latitude), self.trig_sums, z_sums=self.z_sums)
        return sums[:, 0], h, sums[:, 7]

    def accumulator(self) -> hm.InformationAccumulator:
        """``Σ HᵀH`` from the trigonometric sums by product-to-sum identities; ``Σ Hᵀz`` from the z sums."""
        nk = 2 * self.order + 1
        c_sum = self.trig_sums[:nk]
        s_sum = self.trig_sums[nk:]

        def cos_sum(k: int) -> float:
            return float(c_sum[abs(k)])

        def sin_sum(k: int) -> float:
            return float(np.sign(k) * s_sum[abs(k)])

        a = math.cos(self.latitude)
        cols = self.columns
        lam = np.empty((len(cols), len(cols)))
        for i, (ki, ti) in enumerate(cols):
            for j, (kj, tj) in enumerate(cols):
                if ti == 0 and tj == 0:
                    v = 0.5 * (cos_sum(ki - kj) + cos_sum(ki + kj))
                elif ti == 1 and tj == 1:
                    v = 0.5 * (cos_sum(ki - kj) - cos_sum(ki + kj))
                elif ti == 0:  # cos ki · sin kj
                    v = 0.5 * (sin_sum(ki + kj) - sin_sum(ki - kj))
                else:  # sin ki · cos kj
                    v = 0.5 * (sin_sum(ki + kj) + sin_sum(ki - kj))
                lam[i, j] = a ** (ki + kj) * v
        zc = self.z_sums[: self.order + 1]
        zs = self.z_sums[self.order + 1 :]
        acc = hm.InformationAccumulator(n_states=len(cols))
        acc.information = 0.5 * (lam + lam.T)
        acc.projection = np.array([a**k * (zc[k] if t == 0 else zs[k]) for k, t in cols])
        acc.sum_squares = self.sum_z2
        acc.count = self.count
        return acc


def block_length(sample_rate: float, limit: float = 2e-4) -> int:
    """Largest power of two ``B`` with ``B·ω_ie/rate ≤ limit`` (at least 1)."""
    b = max(1.0, limit * sample_rate / EARTH_RATE)
    return 1 << int(math.floor(math.log2(b)))


__all__ = [
    "GIMBAL_BLOCKS",
    "GIMBAL_COLUMNS",
    "GimbalBlocks",
    "AttitudeBlocks",
    "BlockHarmonics",
    "BlockPass",
    "SUM_COLUMNS",
    "block_length",
    "block_sums",
    "block_sums_reference",
    "coefficients",
    "harmonic_information",
    "harmonic_sums",
    "observation",
    "second_difference_sums",
]
