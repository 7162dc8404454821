"""How the platform is held while it dwells at a position: the one vocabulary (docs/conventions.md, "The platform during a dwell").

A plain value every layer shares (data files declare it in their metadata, procedures in ``[procedure] dwell_mode``);
its physics, the platform's rate relative to the base, is :func:`stableins.conventions.dwell_platform_rate`.  No numpy
here: the site metadata import it and stay light.
"""

from __future__ import annotations

from enum import StrEnum
from typing import Final


class DwellMode(StrEnum):
    """How the platform is held while it dwells at a position (docs/conventions.md, "The platform during a dwell").

    The one definition of the platform's motion relative to the base within a dwell, ``ω_bp^p``
    (:func:`stableins.conventions.dwell_platform_rate`); data files declare it (``metadata.dwell_mode``), procedures too
    (``[procedure] dwell_mode``), the simulator moves the platform by it and the gyro stage expects its readings'
    slopes from it.
    """

    #: Caged to the base by the angle loops: the gimbal servos hold the angle readings at the command; the gyros
    #: do not act, so the readings carry no gyro information (``ω_bp^p = 0``).
    CAGED = "caged"
    #: Gyro-stabilized and torqued at the computed Earth rate ``ω_ie^p``: the platform follows the base but for its
    #: gyro errors and the torquers' scale-factor error (``ω_bp^p = w + k ∘ ω_ie^p``).
    EARTH_RATE = "earth_rate"
    #: Gyro-stabilized and not torqued: held in inertial space, the base turns under it (``ω_bp^p = w − ω_ie^p``).
    INERTIAL = "inertial"


#: The mode of a file or procedure that does not declare one: the paper's device procedures (Wu et al. 2018 §3–4
#: turn the platform to its positions and hold it there with the gyros; the Earth rate is torqued out).
DEFAULT_DWELL_MODE: Final = DwellMode.EARTH_RATE


__all__ = ["DEFAULT_DWELL_MODE", "DwellMode"]
