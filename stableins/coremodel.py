"""The core accelerometer model (Wu et al. 2018 Eq. 6) in arrays.

The scale factors, biases, quadratic nonlinearities and installation matrix that a value mapping gives, and the
cancellation-free root of the quadratic.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from stableins.conventions import AXES, INSTALLATION_ENTRIES, dcm_platform_to_accelerometer


@dataclass(frozen=True)
class CoreValues:
    """The core terms' values broadcast to arrays (absent terms at their reference: scale factor 1, the rest 0)."""

    scale_factor: NDArray[np.float64]  # (..., 3)
    bias: NDArray[np.float64]  # (..., 3)
    quadratic: NDArray[np.float64]  # (..., 3)
    installation: NDArray[np.float64]  # (..., 3, 3)

    @classmethod
    def from_mapping(cls, values: Mapping[str, Any], *, nonlinear: bool) -> CoreValues:
        """Read the core values in ``values`` (term id → value, arrays broadcast together); ``K2`` only if ``nonlinear``."""

        def get(key: str, default: float) -> NDArray[np.float64]:
            return np.asarray(values.get(key, default), dtype=float)

        stack = lambda prefix, default: np.stack(np.broadcast_arrays(*(get(f"{prefix}_{a}", default) for a in AXES)), axis=-1)  # noqa: E731
        return cls(
            scale_factor=stack("sf", 1.0),
            bias=stack("bias", 0.0),
            quadratic=stack("K2", 0.0) if nonlinear else np.zeros(3),
            installation=dcm_platform_to_accelerometer(**{b: get(b, 0.0) for b in INSTALLATION_ENTRIES}),
        )


def solve_quadratic(w: NDArray[np.float64], k: NDArray[np.float64]) -> NDArray[np.float64]:
    """Root of ``u − k u² = w`` that tends to ``w`` as ``k → 0`` (cancellation-free form)."""
    discriminant = 1.0 - 4.0 * k * w
    if np.any(discriminant <= 0.0):
        raise ValueError("quadratic nonlinearity too large: K2·f reaches the fold of Eq. 6 (1 − 4 K w ≤ 0)")
    return 2.0 * w / (1.0 + np.sqrt(discriminant))
