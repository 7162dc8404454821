"""What the system stage measured about the record besides its coefficients (:class:`SystemDiagnostics`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from stableins.estimators.system.accumulate import TemperatureSummary
from stableins.estimators.system.checks import SamplingSummary
from stableins.estimators.system.loop import DampingLoop


@dataclass(frozen=True)
class SystemDiagnostics:
    """What the system stage measured about the record besides its coefficients (:attr:`SystemCalibration.diagnostics`).

    Attributes
    ----------
    duration : float
        Last minus first time stamp [s].
    samples : int
        Samples in the record.
    block_length : int
        Samples per block of the harmonic sums.
    attitude_block_seconds : float
        Width of the attitude blocks [s] (doubled from the option's value beyond 2^14 blocks).
    axis_noise_sigma : ndarray, shape (3,)
        White noise of one sample per axis [m/s²] (second differences).
    z_residual_sigma : float
        rms of the ``z`` residuals of the harmonic fit.
    z_low_frequency_ratio : float
        Variance of x2 over its white-noise variance (1 without low-frequency noise).
    combined_sigma_white : ndarray, shape (15,)
        σ of the combined coefficients without the coloured part.
    noise_samples : int
        Second differences per axis.
    noise_bias_x1 : float
        ``E|n|²/(2g²)``, removed from x1.
    k2_residual, k2_residual_sigma : ndarray, shape (2,)
        Residual ``K2_x``, ``K2_y`` from the third harmonic [s²/m] and their σ.
    third_harmonic : ndarray, shape (2,)
        The third-harmonic states x6, x7.
    attitude_noise_sigma : tuple of float
        σ of one sample of pitch and roll from the accelerometer noise [rad].
    attitude_residual_rms : ndarray
        rms of the attitude fit's residuals (pitch, roll) [rad].
    attitude_noise_ratio : ndarray
        Those rms over the expected white-noise level.
    platform_rate_ratio : float
        Rate of the platform-axis angle over the Earth rate.
    polar_misalignment : float
        Largest angle between ``z_p`` and the Earth's axis over the record, from the gimbal readings [rad] (NaN when
        they are not in the record; :mod:`.polar`).
    max_velocity : float
        Largest horizontal velocity output [m/s].
    attitude_excursion : float
        Range of pitch or roll over the record [rad].
    loop : DampingLoop
        The damping-loop model the attitude fit used.
    sampling : SamplingSummary
        Gaps and jitter of the time column.
    temperature : TemperatureSummary or None
        Mean and range of the temperature column (None without one).
    time_span : tuple of float
        First and last time stamp [s].
    """

    duration: float
    samples: int
    block_length: int
    attitude_block_seconds: float
    axis_noise_sigma: NDArray[np.float64]
    z_residual_sigma: float
    z_low_frequency_ratio: float
    combined_sigma_white: NDArray[np.float64]
    noise_samples: int
    noise_bias_x1: float
    k2_residual: NDArray[np.float64]
    k2_residual_sigma: NDArray[np.float64]
    third_harmonic: NDArray[np.float64]
    attitude_noise_sigma: tuple[float, float]
    attitude_residual_rms: Any
    attitude_noise_ratio: Any
    platform_rate_ratio: float
    polar_misalignment: float
    max_velocity: float
    attitude_excursion: float
    loop: DampingLoop
    sampling: SamplingSummary
    temperature: TemperatureSummary | None
    time_span: tuple[float | None, float | None]

    def to_dict(self) -> dict[str, Any]:
        """Return the JSON form (``calibrate system --json``): every attribute but ``loop``, in order; sampling and temperature as dicts."""
        out: dict[str, Any] = {}
        for name in self.__dataclass_fields__:
            value = getattr(self, name)
            if name == "loop":
                continue
            if isinstance(value, SamplingSummary | TemperatureSummary):
                value = value.to_dict()
            out[name] = value
        return out


__all__ = ["SystemDiagnostics"]
