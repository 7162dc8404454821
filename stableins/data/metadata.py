"""Site and unit metadata carried beside every dataset (see ``docs/formats.md``)."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any


@dataclass(frozen=True)
class SiteMetadata:
    """Where and on what the data were taken.  SI inside (radians, metres, m/s²).

    Attributes
    ----------
    serial_number : str
        Unit serial number.
    latitude : float
        Geodetic latitude [rad].
    height : float
        Ellipsoidal height [m].
    gravity : float
        Local gravity magnitude [m/s²].
    gravity_source : str
        Where ``gravity`` comes from, e.g. ``"WGS-84 normal gravity"`` or a survey.
    sample_rate : float
        Accelerometer sample rate [Hz].
    gimbal_senses : tuple of int
        Rotation senses ``(s1, s2, s3, s4)``, see :mod:`stableins.conventions`.
    base_attitude : tuple of float
        True (yaw, pitch, roll) of the base [rad], as known from the site survey.
    reference_temperature : float
        Temperature the temperature terms are counted from [°C].
    damping : dict
        System-level only: damping-loop parameters of the INS (``zeta``, vertical gains...).
    extra : dict
        Anything else worth keeping (procedure, operator, ...).
    """

    serial_number: str
    latitude: float
    height: float
    gravity: float
    gravity_source: str
    sample_rate: float
    gimbal_senses: tuple[int, int, int, int] = (1, 1, 1, 1)
    base_attitude: tuple[float, float, float] = (0.0, 0.0, 0.0)
    reference_temperature: float = 25.0
    damping: dict[str, float] = field(default_factory=dict)
    extra: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["gimbal_senses"] = list(self.gimbal_senses)
        d["base_attitude"] = list(self.base_attitude)
        return d
