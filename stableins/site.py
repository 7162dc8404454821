"""Where and on what the data were taken: the site and unit metadata every layer shares (SI inside).

:class:`SiteMetadata` is a plain value: the simulator produces it, the data formats read and write it
(:mod:`stableins.data.metadata` holds its file document), drivers report it and records carry it.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

from stableins.documents import JSONObject
from stableins.dwell_mode import DEFAULT_DWELL_MODE, DwellMode


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
    gravity_uncertainty : float or None
        Standard uncertainty of ``gravity`` [m/s²] as its source states it (a survey's), or None when not
        stated; the certificate's uncertainty budget then assumes one from the source (docs/reports.md).
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
    start_time : str
        ISO 8601 UTC time of the data's time 0 (``time[s]`` counts from it); ``""`` when unknown.
        Gives the calibration date: the record's data start and end times.
    dwell_mode : DwellMode
        How the platform is held while it dwells at a position (caged, torqued at the computed Earth rate, or
        inertially held; docs/conventions.md, "The platform during a dwell").  Default
        :data:`~stableins.conventions.DEFAULT_DWELL_MODE` (torqued at the computed Earth rate), what files that do
        not declare it were taken with.
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
    extra: JSONObject = field(default_factory=dict)
    start_time: str = ""
    gravity_uncertainty: float | None = None
    dwell_mode: DwellMode = DEFAULT_DWELL_MODE

    def __post_init__(self) -> None:
        if not isinstance(self.dwell_mode, DwellMode):
            object.__setattr__(self, "dwell_mode", DwellMode(self.dwell_mode))

    def to_dict(self) -> JSONObject:
        """Return the metadata as a JSON-ready dict (:meth:`from_dict` reads it back)."""
        d = asdict(self)
        d["gimbal_senses"] = list(self.gimbal_senses)
        d["base_attitude"] = list(self.base_attitude)
        d["dwell_mode"] = str(self.dwell_mode)
        return d
