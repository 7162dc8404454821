"""Why x1's slow-noise variance is 1.6-1.8x larger in the system stage than in the independent generator's records (issue 25).

x1 is, for the slow noise, the mean of the z axis' output over the record; the variance of a record's mean is the
spectrum *below one cycle per record*: ``var(mean) = ∫ S(f) sinc²(f T) df``.  The stage's flicker (and the truth
simulator's, and a quartz accelerometer's bias instability, which keeps wandering at lower frequencies) is a sum of
Gauss-Markov processes with τ up to 1e5 s (:data:`stableins.noise.FLICKER_TIME_CONSTANTS`): ``1/f`` down to 0.14
cycles/day and flat below.  The independent generator (benchmarks/worlds/independent.py, ``slow_noise``) shapes flicker
by one FFT on a grid of ``2^k ≥ n`` samples with the zero-frequency ordinate set to 0: nothing below ``1/(2^k dt)``,
0.66 cycles/day for one day at 1 Hz.  This prints the variance of the record's mean for both (exact, B = 2 µg) and with
the random walk both share (``K² T/3``, K = 1e-7 m/s²/√s).

Usage::

    python benchmarks/bench_flicker_below_record.py [--days 1] [--rate 1]
"""

from __future__ import annotations

import argparse
import math

import numpy as np

from stableins.conventions import MICRO_G, SIDEREAL_DAY
from stableins.noise import FLICKER_TIME_CONSTANTS, FLICKER_VARIANCE_PER_B2

B = 2.0 * MICRO_G
K = 1e-7


def stage_flicker_mean_variance(duration: float) -> float:
    """Variance of the record mean of the stage's flicker: Σ_τ σ² · 2(x − 1 + e^{−x})/x², x = T/τ."""
    x = duration / np.asarray(FLICKER_TIME_CONSTANTS, dtype=float)
    return float(B**2 * FLICKER_VARIANCE_PER_B2 * np.sum(2.0 * (x - 1.0 + np.exp(-x)) / x**2))


def fft_flicker_mean_variance(samples: int, rate: float) -> float:
    """Variance of the record mean of the independent generator's FFT flicker (its ``slow_noise``), exact.

    ``out = A w`` with ``A`` circulant (kernel ``irfft(√(psd·rate))`` on ``2^k`` points), so the mean ``vᵀ out`` has
    variance ``|Aᵀ v|²`` with ``v`` the averaging window on the first ``samples`` points.
    """
    size = 1 << int(math.ceil(math.log2(max(samples, 2))))
    freqs = np.fft.rfftfreq(size, 1.0 / rate)
    psd = np.zeros_like(freqs)
    psd[1:] = B**2 / (2.0 * math.pi * freqs[1:])
    kernel = np.fft.irfft(np.sqrt(psd * rate), n=size)
    window = np.zeros(size)
    window[:samples] = 1.0 / samples
    projected = np.fft.irfft(np.conj(np.fft.rfft(kernel)) * np.fft.rfft(window), n=size)
    return float(np.sum(projected**2))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--days", type=float, default=1.0, help="record length [sidereal days]")
    parser.add_argument("--rate", type=float, default=1.0, help="sample rate [Hz]")
    args = parser.parse_args(argv)
    duration = args.days * SIDEREAL_DAY
    samples = int(duration * args.rate)
    size = 1 << int(math.ceil(math.log2(samples)))
    stage = stage_flicker_mean_variance(duration)
    fft = fft_flicker_mean_variance(samples, args.rate)
    walk = K**2 * duration / 3.0
    print(
        f"record {args.days:g} sidereal day(s) at {args.rate:g} Hz; the FFT grid has {size} points: "
        f"no flicker below {86400 * args.rate / size:.2f} cycles/day"
    )
    print(
        f"variance of the record mean [(m/s^2)^2]: flicker, stage model {stage:.3e}; flicker, independent generator "
        f"{fft:.3e} (ratio {stage / fft:.1f})"
    )
    print(
        f"with the random walk both share ({walk:.3e}): stage {stage + walk:.3e}, independent {fft + walk:.3e}, "
        f"ratio {(stage + walk) / (fft + walk):.2f}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
