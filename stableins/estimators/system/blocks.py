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

The pass is compiled with numba: one loop over the samples with eight running sums, which LLVM vectorizes
when allowed to reassociate them (:data:`FASTMATH`; NaN and inf still propagate, so a non-finite input shows
in :math:`\sum z^2`).  A numpy pass needs about fifteen array operations per sample and cost 5-6 ns/sample;
this one costs about 1 ns/sample (0.9 on a time grid), below the cost of reading the samples from a file
(``benchmarks/bench_system_stream.py``).
:func:`block_sums_reference` is the numpy reference it is tested against.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, ClassVar

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

_KERNEL: Any = None
#: LLVM may reassociate sums (so it vectorizes them), but NaN and ±inf keep their meaning: a non-finite input
#: makes Σz² non-finite, which is how the stage detects one without a separate pass.
FASTMATH = {"reassoc", "nsz", "arcp", "contract", "afn"}


def coefficients(
    matrix: NDArray[np.float64], bias: NDArray[np.float64], quadratic: NDArray[np.float64], gravity: float
) -> NDArray[np.float64]:
    """Packed ``(δb_x, δb_y, δb_z, q00, 2q01, 2q02, q11, 2q12, q22, K2_x, K2_y, K2_z)`` with ``q = MᵀM/(2g²)``."""
    q = np.einsum("ki,kj->ij", matrix, matrix) / (2.0 * gravity**2)
    return np.array([*bias, q[0, 0], 2 * q[0, 1], 2 * q[0, 2], q[1, 1], 2 * q[1, 2], q[2, 2], *quadratic], dtype=float)


# The compiled functions are written at module level (numba's disk cache keys on the qualified name and source)
# and compiled on first use, so importing this module does not import numba.
def _observation(x, y, z, p):
    """``z = ½(wᵀQw/g² − 1)`` of one sample (Q/(2g²) and the bias, K2 packed in ``p``: :func:`coefficients`)."""
    w0 = x - p[0]
    w1 = y - p[1]
    w2 = z - p[2]
    w0 -= p[9] * w0 * w0
    w1 -= p[10] * w1 * w1
    w2 -= p[11] * w2 * w2
    return w0 * (p[3] * w0 + p[4] * w1 + p[5] * w2) + w1 * (p[6] * w1 + p[7] * w2) + p[8] * w2 * w2 - 0.5


def _centre(t, step_low, step_high):  # slices: indices from 0 let LLVM drop the negative-index checks
    """Mean time of a block and the number of its steps outside ``[step_low, step_high]``."""
    m = t.size
    s = t[0]
    irregular = 0.0
    for j in range(1, m):
        s += t[j]
        step = t[j] - t[j - 1]
        irregular += 1.0 if (step < step_low) | (step > step_high) else 0.0
    centre = s / m
    return centre, irregular


def _moments(fx, fy, fz, t, centre, omega, angle_step, p):  # noqa: PLR0913, PLR0917 - a numba kernel: njit takes no keyword-only arguments
    """Σ z δ^p, Σ δ^p, Σ z² of one block: ``δ = ω(t − t̄)``, or with no stamps (``t`` empty) ``δ_j = (j − (m−1)/2)·angle_step``."""
    m = fx.size
    stamped = t.size > 0
    half = 0.5 * (m - 1)
    n0 = n1 = n2 = n3 = m1 = m2 = m3 = zz = 0.0
    for j in range(m):
        d = omega * (t[j] - centre) if stamped else (j - half) * angle_step
        z = _observation(fx[j], fy[j], fz[j], p)
        zd = z * d
        dd = d * d
        n0 += z
        n1 += zd
        n2 += zd * d
        n3 += zd * dd
        m1 += d
        m2 += dd
        m3 += dd * d
        zz += z * z
    return n0, n1, n2, n3, m1, m2, m3, zz


def _block_pass(fx, fy, fz, t, start_time, period, omega, p, block, step_low, step_high, out, centres):  # noqa: PLR0913, PLR0917 - a numba kernel: njit takes no keyword-only arguments
    n = fx.size
    n_blocks = (n + block - 1) // block
    total = 0.0
    irregular = 0.0
    uniform = period > 0.0  # t is not given: t_j = start_time + j·period
    for b in range(n_blocks):
        a = b * block
        e = min(a + block, n)
        if uniform:
            centre = start_time + (a + 0.5 * (e - a - 1)) * period
            times = t[:0]
        else:
            times = t[a:e]
            centre, block_irregular = _centre(times, step_low, step_high)
            irregular += block_irregular
            if a > 0:
                step = t[a] - t[a - 1]
                irregular += 1.0 if (step < step_low) | (step > step_high) else 0.0
        n0, n1, n2, n3, m1, m2, m3, zz = _moments(fx[a:e], fy[a:e], fz[a:e], times, centre, omega, omega * period, p)
        centres[b] = centre
        out[b, 0] = n0
        out[b, 1] = n1
        out[b, 2] = n2
        out[b, 3] = n3
        out[b, 4] = m1
        out[b, 5] = m2
        out[b, 6] = m3
        out[b, 7] = e - a
        total += zz
    if uniform and not (step_low <= period <= step_high):
        irregular = max(n - 1, 0)
    return total, irregular


def _second_differences(fx, fy, fz, m, out):
    for j in range(2, m):
        a = fx[j] - 2.0 * fx[j - 1] + fx[j - 2]
        b = fy[j] - 2.0 * fy[j - 1] + fy[j - 2]
        c = fz[j] - 2.0 * fz[j - 1] + fz[j - 2]
        out[0] += a * a
        out[1] += b * b
        out[2] += c * c


def _harmonic_pass(centre_angle, sums, order, cos_latitude, trig_sums, z_sums, h):  # noqa: PLR0913, PLR0917 - a numba kernel: njit takes no keyword-only arguments
    nk = 2 * order + 1
    for b in range(centre_angle.size):
        n0, n1, n2, n3 = sums[b, 0], sums[b, 1], sums[b, 2], sums[b, 3]
        m1, m2, m3, count = sums[b, 4], sums[b, 5], sums[b, 6], sums[b, 7]
        c1 = np.cos(centre_angle[b])
        s1 = np.sin(centre_angle[b])
        ck, sk = 1.0, 0.0
        trig_sums[0] += count
        z_sums[0] += n0
        h[b, 0] = count
        weight = 1.0
        for k in range(1, nk):
            ck, sk = ck * c1 - sk * s1, sk * c1 + ck * s1  # cos kS_c, sin kS_c by the angle-sum recurrence
            even = count - 0.5 * k * k * m2
            odd = k * m1 - k * k * k * m3 / 6.0
            cos_sum = ck * even - sk * odd
            sin_sum = sk * even + ck * odd
            trig_sums[k] += cos_sum
            trig_sums[nk + k] += sin_sum
            if k <= order:
                weight *= cos_latitude
                h[b, 2 * k - 1] = weight * cos_sum
                h[b, 2 * k] = weight * sin_sum
                zeven = n0 - 0.5 * k * k * n2
                zodd = k * n1 - k * k * k * n3 / 6.0
                z_sums[k] += ck * zeven - sk * zodd
                z_sums[order + 1 + k] += sk * zeven + ck * zodd


def _kernel() -> Any:
    """Compile once per process (numba caches the machine code on disk) and return the three passes."""
    global _KERNEL, _observation, _centre, _moments, _block_pass, _harmonic_pass, _second_differences
    if _KERNEL is None:
        from numba import njit

        _observation = njit(fastmath=FASTMATH, inline="always", cache=True)(_observation)
        _centre = njit(fastmath=FASTMATH, inline="always", cache=True)(_centre)
        _moments = njit(fastmath=FASTMATH, inline="always", cache=True)(_moments)
        _block_pass = njit(fastmath=FASTMATH, cache=True)(_block_pass)
        _harmonic_pass = njit(cache=True)(_harmonic_pass)
        _second_differences = njit(cache=True)(_second_differences)
        _KERNEL = (_block_pass, _harmonic_pass, _second_differences)
    return _KERNEL


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
    """Per-block sums of one chunk (compiled pass).

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
    packed, block, omega, step_range = settings.packed, settings.block, settings.omega, settings.step_range
    n = fx.size
    n_blocks = -(-n // block)
    sums = np.empty((n_blocks, len(SUM_COLUMNS)))
    centres = np.empty(n_blocks)
    start_time, period = (0.0, 0.0) if grid is None else (float(grid[0]), float(grid[1]))
    total, irregular = _kernel()[0](
        np.ascontiguousarray(fx, dtype=float),
        np.ascontiguousarray(fy, dtype=float),
        np.ascontiguousarray(fz, dtype=float),
        np.zeros(0) if grid is not None else np.ascontiguousarray(time, dtype=float),
        start_time,
        period,
        float(omega),
        np.ascontiguousarray(packed, dtype=float),
        int(block),
        float(step_range[0]),
        float(step_range[1]),
        sums,
        centres,
    )
    return sums, centres, float(total), int(irregular)


def harmonic_sums(
    centre_angle: NDArray[np.float64],
    sums: NDArray[np.float64],
    order: int,
    cos_latitude: float,
    trig_sums: NDArray[np.float64],
    *,
    z_sums: NDArray[np.float64],
) -> NDArray[np.float64]:
    r"""Trigonometric and z sums of the blocks (compiled), accumulated into ``trig_sums`` and ``z_sums`` in place.

    With :math:`S = S_c + \delta` in each block and :math:`\cos k\delta`, :math:`\sin k\delta` to third order in
    :math:`\delta` (:math:`(k\delta)^4/24 < 10^{-15}` for the block lengths used):

    .. math::

        \sum \cos kS = \cos kS_c\,(B - \tfrac{k^2}{2} m_2) - \sin kS_c\,(k m_1 - \tfrac{k^3}{6} m_3),

    likewise :math:`\sum \sin kS` and, with :math:`n_p` for :math:`m_p`, :math:`\sum z\cos kS`,
    :math:`\sum z \sin kS`.  ``trig_sums`` holds :math:`C_0..C_{2m}, S_0..S_{2m}` and ``z_sums``
    :math:`ZC_0..ZC_m, ZS_0..ZS_m` (``m = order``).  Returns the per-block ``ΣH`` rows ``(n_blocks, 2m+1)``:
    ``B, a C_1, a S_1, a² C_2, ...`` with ``a = cos L`` (the filter bins).
    """
    h = np.empty((centre_angle.size, 2 * order + 1))
    _kernel()[1](
        np.ascontiguousarray(centre_angle, dtype=float), np.ascontiguousarray(sums), int(order), float(cos_latitude), trig_sums, z_sums, h
    )
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
    _kernel()[2](fx, fy, fz, m, out)
    return m - 2


def observation(
    fx: NDArray[np.float64], fy: NDArray[np.float64], fz: NDArray[np.float64], packed: NDArray[np.float64]
) -> NDArray[np.float64]:
    """``z = ½(|f^p|²/g² − 1)`` of each sample with numpy: the formula the compiled pass inlines."""
    formula = getattr(_observation, "py_func", _observation)  # the Python function, compiled or not
    return formula(np.asarray(fx, dtype=float), np.asarray(fy, dtype=float), np.asarray(fz, dtype=float), np.asarray(packed, dtype=float))


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
