r"""Accelerometer, angle-sensor and temperature noise, reproducible sample by sample.

Parameterization (IEEE Std 952/1293 Allan-variance terms, per accelerometer axis)
---------------------------------------------------------------------------------
white noise
    velocity random walk ``N`` [m/s/√s]; per sample of period ``dt`` the output
    noise has ``σ = N / √dt``.  Allan deviation ``N/√τ`` (slope −1/2).
bias instability
    ``B`` [m/s²], flicker (1/f) noise with two-sided PSD ``S(f) = B²/(2π f)``
    (IEEE Std 952-1997 Annex C: Allan deviation ``B sqrt(2 ln 2/π) = 0.664 B``),
    approximated by a sum of first-order Gauss-Markov processes with correlation
    times a ratio ``r`` (one decade) apart
    (:attr:`NoiseSettings.bias_instability_time_constants`).  One process of variance
    ``σ²`` and correlation time ``τ_c`` has the two-sided PSD
    ``2σ²τ_c/(1 + (2π f τ_c)²)``; a density ``1/ln r`` of them per ``ln τ_c`` sums to
    ``σ²/(2 f ln r)``, hence ``σ² = B² ln(r)/π``.  The Allan deviation is then flat
    within about ±10 % of ``0.664 B`` from ten times the shortest to a tenth of the
    longest ``τ_c``.
acceleration random walk
    ``K`` [m/s²/√s]: ``b_k = b_{k-1} + K √dt w_k``; Allan deviation ``K √(τ/3)``
    (slope +1/2).
quantization
    velocity-increment LSB ``q`` [m/s].  The instrument accumulates the exact
    velocity increment and outputs whole LSBs; the remainder is carried to the next
    sample, so the quantization error of the *integrated* output stays below one LSB.
    At device level the accumulator restarts with a seeded uniform remainder at each
    noise block (every :data:`BLOCK_SAMPLES` samples) so that any sample can be
    recomputed from the seed and the commands alone (the restart adds at most one LSB
    per block to a velocity sum); system-level records carry the remainder throughout.

Temperature
    deterministic profile ``T(t) = T_ref + offset + ramp·t + A sin(2π t/P + φ)``
    [°C]; the temperature sensor adds white noise.

Reproducibility
---------------
Every random number comes from a generator keyed by ``(seed, stream name, block
index)`` through :class:`numpy.random.SeedSequence`, blocks of :data:`BLOCK_SAMPLES`
samples on the session's sample clock.  Accumulating states (random walk,
Gauss-Markov states) at the start of a block are computed from the preceding blocks,
so sample ``k`` depends only on the seed and ``k``, never on how acquisition was split.
"""

from __future__ import annotations

import zlib
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from stableins.conventions import ARCSEC, STANDARD_GRAVITY

#: Samples per random block.
BLOCK_SAMPLES = 16384


@dataclass(frozen=True)
class TemperatureProfile:
    """Instrument temperature ``T(t) = reference + offset + ramp·t + amplitude·sin(2π t/period + phase) + warmup·e^{−t/τ_w}`` [°C].

    ``sensor_noise`` is the white noise of the temperature sensor [K, 1σ per sample].  ``warmup`` [K] is the
    excess of a warm-up transient at session time 0 (negative: the unit starts cold) decaying with the time
    constant ``warmup_time_constant`` ``τ_w`` [s]; 0 (the default) leaves it out, and the dict of the
    settings then omits both fields, so files written without one are unchanged.
    """

    reference: float = 25.0
    offset: float = 0.0
    ramp: float = 0.0
    amplitude: float = 0.0
    period: float = 86400.0
    phase: float = 0.0
    sensor_noise: float = 0.0
    warmup: float = 0.0
    warmup_time_constant: float = 1800.0

    def __call__(self, time: NDArray[np.float64]) -> NDArray[np.float64]:
        """Return the true temperature [°C] at session time ``time`` [s]."""
        t = np.asarray(time, dtype=float)
        out = self.reference + self.offset + self.ramp * t + self.amplitude * np.sin(2 * np.pi * t / self.period + self.phase)
        if self.warmup != 0.0:
            out = out + self.warmup * np.exp(-t / self.warmup_time_constant)
        return out


@dataclass(frozen=True)
class NoiseSettings:
    """Noise of the three accelerometer axes (same on each axis), angle sensors and temperature.

    Attributes
    ----------
    velocity_random_walk : float
        White-noise coefficient ``N`` [m/s/√s].
    bias_instability : float
        Flicker floor ``B`` [m/s²].
    acceleration_random_walk : float
        ``K`` [m/s²/√s].
    quantization : float
        Velocity-increment LSB [m/s]; 0 = no quantization.
    angle_noise : float
        White noise of the angle-sensor readings [rad, 1σ per sample].
    bias_instability_time_constants : tuple of float
        Correlation times of the Gauss-Markov sum [s], one decade apart.
    temperature : TemperatureProfile
        Temperature profile and its sensor noise.
    """

    velocity_random_walk: float = 0.0
    bias_instability: float = 0.0
    acceleration_random_walk: float = 0.0
    quantization: float = 0.0
    angle_noise: float = 0.0
    bias_instability_time_constants: tuple[float, ...] = (10.0, 100.0, 1000.0, 10000.0, 100000.0)
    temperature: TemperatureProfile = field(default_factory=TemperatureProfile)

    @classmethod
    def quiet(cls) -> NoiseSettings:
        """No noise at all (exact forward model)."""
        return cls()

    @classmethod
    def quartz(cls) -> NoiseSettings:
        """Return a navigation-grade quartz pendulous accelerometer on a precise platform.

        ``N = 4.5e-4 m/s/√s`` (46 µg/√Hz: about 1e-4 m/s² for a 20 s average),
        ``B = 2 µg``, ``K = 1e-7 m/s²/√s`` (about 3 µg per day), LSB ``1e-5 m/s``,
        angle sensors 0.2″, temperature sensor 0.01 K.
        """
        return cls(
            velocity_random_walk=4.5e-4,
            bias_instability=2e-6 * STANDARD_GRAVITY,
            acceleration_random_walk=1e-7,
            quantization=1e-5,
            angle_noise=0.2 * ARCSEC,
            temperature=TemperatureProfile(sensor_noise=0.01),
        )

    def white_sigma(self, rate: float) -> float:
        """Per-sample standard deviation of the white noise at ``rate`` [Hz]: ``N √rate``."""
        return self.velocity_random_walk * np.sqrt(rate)

    @property
    def gauss_markov_sigma(self) -> float:
        """Standard deviation of each Gauss-Markov process, ``B √(ln r / π)`` (module docstring)."""
        taus = self.bias_instability_time_constants
        ratio = taus[1] / taus[0] if len(taus) > 1 else 10.0
        return self.bias_instability * np.sqrt(np.log(ratio) / np.pi)

    def to_dict(self) -> dict[str, Any]:
        """Return the settings as a JSON-ready dict (:meth:`from_dict` reads it back)."""
        d = asdict(self)
        d["bias_instability_time_constants"] = list(self.bias_instability_time_constants)
        if self.temperature.warmup == 0.0:  # no warm-up transient: the fields are left out (files as before)
            d["temperature"].pop("warmup")
            d["temperature"].pop("warmup_time_constant")
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> NoiseSettings:
        """Inverse of :meth:`to_dict` (missing fields take their defaults)."""
        d = dict(d)
        d["temperature"] = TemperatureProfile(**d.get("temperature", {}))
        d["bias_instability_time_constants"] = tuple(d.get("bias_instability_time_constants", (10.0, 100.0, 1000.0, 10000.0, 100000.0)))
        return cls(**d)


def stream_generator(seed: int, stream: str, block: int) -> np.random.Generator:
    """Random generator keyed by ``(seed, stream name, block index)``."""
    return np.random.Generator(np.random.PCG64(np.random.SeedSequence([int(seed) & 0xFFFFFFFF, zlib.crc32(stream.encode()), int(block)])))


class NoiseGenerator:
    """Noise of a session at sample rate ``rate`` [Hz], as a pure function of the sample index.

    Parameters
    ----------
    settings : NoiseSettings
    rate : float
        Sample rate [Hz].
    seed : int
    channels : int
        Number of accelerometer axes (3).
    """

    def __init__(self, settings: NoiseSettings, rate: float, seed: int, channels: int = 3) -> None:
        self.settings = settings
        self.rate = float(rate)
        self.dt = 1.0 / self.rate
        self.seed = int(seed)
        self.channels = channels
        taus = np.asarray(settings.bias_instability_time_constants, dtype=float)
        self._gm_a = np.exp(-self.dt / taus)  # (m,)
        self._gm_c = settings.gauss_markov_sigma * np.sqrt(1.0 - self._gm_a**2)
        # state at the start of block b: (gauss-markov (channels, m), random walk (channels,))
        self._states: dict[int, tuple[NDArray[np.float64], NDArray[np.float64]]] = {}

    # ------------------------------------------------------------- accumulating states
    def _initial_state(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        m = len(self._gm_a)
        rng = stream_generator(self.seed, "bias_instability_initial", 0)
        gm = rng.standard_normal((self.channels, m)) * self.settings.gauss_markov_sigma
        return gm, np.zeros(self.channels)

    def _block_accumulating(
        self, block: int, state: tuple[NDArray[np.float64], NDArray[np.float64]]
    ) -> tuple[NDArray[np.float64], tuple[NDArray[np.float64], NDArray[np.float64]]]:
        """Bias-instability + random-walk noise of one whole block, and the state after it."""
        from scipy.signal import lfilter

        n = BLOCK_SAMPLES
        gm_state, rw_state = state
        out = np.zeros((n, self.channels))
        new_gm = gm_state.copy()
        if self.settings.bias_instability > 0:
            w = stream_generator(self.seed, "bias_instability", block).standard_normal((len(self._gm_a), n, self.channels))
            for j, (a, c) in enumerate(zip(self._gm_a, self._gm_c)):
                x, _ = lfilter([c], [1.0, -a], w[j], axis=0, zi=a * gm_state[None, :, j])
                out += x
                new_gm[:, j] = x[-1]
        new_rw = rw_state
        if self.settings.acceleration_random_walk > 0:
            w = stream_generator(self.seed, "acceleration_random_walk", block).standard_normal((n, self.channels))
            walk = rw_state + np.cumsum(w * (self.settings.acceleration_random_walk * np.sqrt(self.dt)), axis=0)
            out += walk
            new_rw = walk[-1].copy()
        return out, (new_gm, new_rw)

    def _state_at(self, block: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        if block in self._states:
            return self._states[block]
        if not self._states:
            self._states[0] = self._initial_state()
        start = max(b for b in self._states if b <= block)
        state = self._states[start]
        for b in range(start, block):
            _, state = self._block_accumulating(b, state)
            self._states[b + 1] = state
        return state

    def _accumulating_noise(self, block: int) -> NDArray[np.float64]:
        """Accumulating noise of one block (the last block is cached: sequential reads compute it once)."""
        cached = getattr(self, "_cached_block", None)
        if cached is not None and cached[0] == block:
            return cached[1]
        noise, state = self._block_accumulating(block, self._state_at(block))
        self._states.setdefault(block + 1, state)
        self._cached_block = (block, noise)
        return noise

    # ------------------------------------------------------------- public
    def accelerometer(self, start: int, count: int) -> NDArray[np.float64]:
        """Additive noise (white + bias instability + random walk) for samples ``start .. start+count-1``, ``(count, channels)``."""
        s = self.settings
        out = np.zeros((count, self.channels))
        if count == 0:
            return out
        accumulating = s.bias_instability > 0 or s.acceleration_random_walk > 0
        white_sigma = s.white_sigma(self.rate)
        for block, lo, hi in _blocks(start, count):
            offset = block * BLOCK_SAMPLES
            rows = slice(offset + lo - start, offset + hi - start)
            if white_sigma > 0:
                out[rows] += white_sigma * self._normals("white", block, self.channels)[lo:hi]
            if accumulating:
                out[rows] += self._accumulating_noise(block)[lo:hi]
        return out

    def angles(self, start: int, count: int) -> NDArray[np.float64]:
        """White angle-sensor noise ``(count, 3)`` [rad]."""
        return self._white("angle", start, count, 3, self.settings.angle_noise)

    def temperature_sensor(self, start: int, count: int) -> NDArray[np.float64]:
        """White temperature-sensor noise ``(count,)`` [K]."""
        return self._white("temperature", start, count, 1, self.settings.temperature.sensor_noise)[:, 0]

    def dither(self, block: int) -> NDArray[np.float64]:
        """Seeded uniform initial remainder of the quantizer at the start of ``block``, in LSB ``[0, 1)``."""
        return stream_generator(self.seed, "quantization", block).random(self.channels)

    def _white(self, stream: str, start: int, count: int, width: int, sigma: float) -> NDArray[np.float64]:
        out = np.zeros((count, width))
        if sigma <= 0 or count == 0:
            return out
        for block, lo, hi in _blocks(start, count):
            offset = block * BLOCK_SAMPLES
            out[offset + lo - start : offset + hi - start] = sigma * self._normals(stream, block, width)[lo:hi]
        return out

    def _normals(self, stream: str, block: int, width: int) -> NDArray[np.float64]:
        """Return the standard normals of one block of a stream, ``(BLOCK_SAMPLES, width)``.

        The last block of each stream is kept: a platform polled in short pieces (0.5 s while it slews) reads the same
        block many times, and drawing a whole block per piece cost about 1 ms each.  The values are those of
        :func:`stream_generator`, so caching changes nothing but the time.
        """
        cache = self.__dict__.setdefault("_normals_cache", {})
        key = (stream, width)
        cached = cache.get(key)
        if cached is None or cached[0] != block:
            cached = (block, stream_generator(self.seed, stream, block).standard_normal((BLOCK_SAMPLES, width)))
            cache[key] = cached
        return cached[1]


class Quantizer:
    """Velocity-increment quantizer with the remainder carried (module docstring).

    Call it with consecutive pieces of the unquantized output; a piece that does not
    continue the previous one must start at a block boundary (the accumulator then
    restarts from the seeded dither of that block), so the result is the same however
    the samples are split.  With ``restart_each_block=True`` (device level: any sample
    can be recomputed from the seed and the commands) the accumulator also restarts at
    every block boundary; with ``False`` (system level, always generated from the start)
    the remainder is carried through the whole record.
    """

    def __init__(self, noise: NoiseGenerator, *, restart_each_block: bool = True) -> None:
        self.noise = noise
        self.lsb = noise.settings.quantization
        self.restart_each_block = restart_each_block
        self._carry: tuple[int, NDArray[np.float64]] | None = None

    def continues(self, start: int) -> bool:
        """Whether ``start`` can be quantized now (continues the last piece or starts a block)."""
        return start % BLOCK_SAMPLES == 0 or (self._carry is not None and self._carry[0] == start)

    def _restart(self, k: int) -> bool:
        continuing = self._carry is not None and self._carry[0] == k
        return k % BLOCK_SAMPLES == 0 and (self.restart_each_block or not continuing)

    def __call__(self, start: int, specific_force: NDArray[np.float64]) -> NDArray[np.float64]:
        """Return ``specific_force`` (samples from ``start``) as the quantizing counter outputs it [m/s²]."""
        if self.lsb <= 0:
            return specific_force
        rate = self.noise.rate
        scale = 1.0 / (rate * self.lsb)
        out = np.empty_like(specific_force)
        k, done = start, 0
        while done < len(specific_force):
            block = k // BLOCK_SAMPLES
            n = min(len(specific_force) - done, (block + 1) * BLOCK_SAMPLES - k)
            if self._restart(k):
                accumulator = self.noise.dither(block)
            elif self._carry is not None and self._carry[0] == k:
                accumulator = self._carry[1]
            else:
                raise ValueError(f"quantizer: sample {k} neither continues the last piece nor starts a block")
            # sequential sums in the same order however the samples are split
            total = np.cumsum(np.vstack([accumulator[None, :], specific_force[done : done + n] * scale]), axis=0)
            out[done : done + n] = np.diff(np.floor(total), axis=0) * (self.lsb * rate)
            self._carry = (k + n, total[-1].copy())
            k += n
            done += n
        return out


def _blocks(start: int, count: int):
    """Yield ``(block, lo, hi)``: the part ``lo:hi`` of block ``block`` covering ``start .. start+count-1``."""
    end = start + count
    block = start // BLOCK_SAMPLES
    while block * BLOCK_SAMPLES < end:
        base = block * BLOCK_SAMPLES
        lo = max(start, base) - base
        hi = min(end, base + BLOCK_SAMPLES) - base
        yield block, lo, hi
        block += 1


def allan_deviation(samples: NDArray[np.float64], rate: float, cluster_sizes: NDArray[np.int64]) -> NDArray[np.float64]:
    """Overlapping Allan deviation of a rate signal ``samples`` (first axis: time) for cluster sizes ``m``.

    ``σ²(τ) = <(θ_{k+2m} - 2θ_{k+m} + θ_k)²> / (2 τ²)`` with ``θ`` the integrated signal,
    ``τ = m/rate`` (IEEE Std 952-1997 Annex C).
    """
    x = np.asarray(samples, dtype=float)
    theta = np.concatenate([np.zeros((1,) + x.shape[1:]), np.cumsum(x, axis=0)]) / rate
    out = []
    for m in np.asarray(cluster_sizes, dtype=int):
        tau = m / rate
        d = theta[2 * m :] - 2 * theta[m:-m] + theta[: -2 * m]
        out.append(np.sqrt(np.mean(d**2, axis=0) / (2 * tau**2)))
    return np.asarray(out)
