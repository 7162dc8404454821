"""Whether the data match the commanded orientation.

Dwell means against the outputs of an ideal instrument, and the alternative explanations (other gimbal senses, an
inverted or swapped axis) when they do not.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stableins.conventions import (
    GimbalConfiguration,
)
from stableins.errors import InputError
from stableins.estimators.dwell import DwellSummary
from stableins.platform import platform_specific_force


def expected_outputs(readings: ArrayLike, gravity: float, base_dcm: ArrayLike, configuration: GimbalConfiguration) -> NDArray[np.float64]:
    """Return the outputs of an ideal instrument with zero offsets: ``f^p`` at the readings."""
    return platform_specific_force(readings, gravity, base_dcm=base_dcm, configuration=configuration)


def _orientation_hypotheses(configuration: GimbalConfiguration):
    """Alternative explanations of data that do not match the commanded orientation."""
    yield "as configured", configuration, None
    s = configuration.senses
    for s1 in (1, -1):
        for s2 in (1, -1):
            for s3 in (1, -1):
                senses = (s1, s2, s3, s[3])
                if senses != s:
                    other = GimbalConfiguration(senses)
                    hand = "the other gimbal handedness" if other.handedness != configuration.handedness else "other rotation senses"
                    yield f"gimbal senses {senses} ({hand})", other, None
    for i, ax in enumerate("xyz"):
        m = np.eye(3)
        m[i, i] = -1
        yield f"the {ax} axis sign inverted", configuration, m
    for i, j in ((0, 1), (0, 2), (1, 2)):
        m = np.eye(3)[[j if k == i else i if k == j else k for k in range(3)]]
        yield f"the {'xyz'[i]} and {'xyz'[j]} axes swapped", configuration, m


def check_orientation(
    dwells: Sequence[DwellSummary],
    gravity: float,
    base_dcm: ArrayLike,
    configuration: GimbalConfiguration,
    *,
    tolerance: float,
    source: str = "data",
) -> dict[int, str]:
    """Compare each dwell mean with the ideal output at its readings.

    Returns ``{position: reason}`` for isolated positions that do not match (to be left
    out).  Raises :class:`InputError` when the data as a whole fit another orientation
    hypothesis (an axis sign or order swapped, other gimbal senses) better, or when more
    than two positions mismatch.
    """
    if not dwells:
        return {}
    readings = np.array([d.angles for d in dwells])
    means = np.array([d.mean for d in dwells])
    scores = []
    for name, config, mapping in _orientation_hypotheses(configuration):
        pred = expected_outputs(readings, gravity, base_dcm, config)
        if mapping is not None:
            pred = pred @ mapping.T
        miss = np.abs(means - pred).max(axis=1) > tolerance
        scores.append((int(miss.sum()), name, miss))
    configured = scores[0]
    best = min(s[0] for s in scores)
    if best < configured[0] and configured[0] > 0:
        bad = [d.position for d, m in zip(dwells, configured[2], strict=True) if m]
        # Several explanations can fit equally well (e.g. a y sign flip and senses (-1, -1, 1)
        # give the same outputs for this sequence): name them all.
        names = " or ".join(s[1] for s in scores if s[0] == best)
        raise InputError(
            f"the data do not match the commanded orientations at positions {bad}; they fit {names} "
            f"({len(dwells) - best} of {len(dwells)} positions). Check the axis wiring and the gimbal_senses metadata",
            path=source,
            field="f_x, f_y, f_z",
            expected=f"outputs within {tolerance:.3g} m/s^2 of the ideal instrument at the commanded orientation",
        )
    if configured[0] > 2:
        bad = [d.position for d, m in zip(dwells, configured[2], strict=True) if m]
        raise InputError(
            f"{configured[0]} positions do not match their commanded orientation: {bad}",
            path=source,
            field="f_x, f_y, f_z",
            expected=f"outputs within {tolerance:.3g} m/s^2 of the ideal instrument at the commanded orientation",
        )
    out = {}
    pred = expected_outputs(readings, gravity, base_dcm, configuration)
    for d, p, m in zip(dwells, pred, configured[2], strict=True):
        if m:
            out[d.position] = (
                f"does not match the commanded orientation: mean output {np.round(d.mean, 3).tolist()} m/s^2, "
                f"expected about {np.round(p, 3).tolist()}"
            )
    return out
