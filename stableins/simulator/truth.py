"""The truth of a simulated world: one instrument, its platform, site, noise and effects.

A :class:`Truth` is everything the simulator needs and everything an estimator is
judged against.  It is immutable, serializes to JSON (``schema_version`` 1) and can be
drawn at random with realistic magnitudes (:meth:`Truth.draw`).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field, replace
from types import MappingProxyType
from typing import Any

from stableins.conventions import ARCSEC, EARTH_RADIUS, MICRO_G, PPM, GimbalConfiguration, normal_gravity
from stableins.errors import InputError, NotDeterminedError
from stableins.simulator.effects import CATALOGUE, validate_effects
from stableins.simulator.noise import NoiseSettings
from stableins.simulator.physics import GIMBAL_IDS, MICRO_G_PER_G2, PARAMETER_IDS, REFERENCE, UNINSTALLED_GYRO_IDS, simulated_parameters
from stableins.site import SiteMetadata

TRUTH_SCHEMA_VERSION = 1
KIND = "stableins.truth"

#: Ids the installed calibration may also hold: output effects of the catalogue (discovered terms of a
#: calibration record, which the navigation computer compensates like the others).
INSTALLED_EFFECT_IDS = tuple(k for k, e in CATALOGUE.items() if e.kind == "output")

#: Default settling transient after a slew: damped oscillation of each gimbal by
#: ``gain × slew angle`` at ``frequency`` [Hz] with damping ratio ``damping``; slews
#: follow a cosine profile whose peak rate is ``slew_rate`` [rad/s].
DEFAULT_SETTLING = {"frequency": 0.5, "damping": 0.2, "gain": 1e-4, "slew_rate": math.radians(10.0)}

#: Default INS damping: horizontal damping ratio and vertical-loop time constant [s].
DEFAULT_DAMPING = {"zeta": 0.5, "vertical_time_constant": 300.0}

#: Default 1σ of the calibration residual (true − installed) per kind of parameter, [SI].
DEFAULT_RESIDUAL = {
    "scale_factor": 5 * PPM,
    "bias": 5 * MICRO_G,
    "installation": 3 * ARCSEC,
    "nonlinearity": 5 * MICRO_G_PER_G2,
    "gimbal": 2 * ARCSEC,
}


def damping_parameters(zeta: float, vertical_time_constant: float, gravity: float) -> dict[str, float]:
    r"""Full damping description stored in ``SiteMetadata.damping``.

    Horizontal: ``c = 2 ζ ω_s``, ``ω_s = sqrt(g/R)``.  Vertical third-order loop: the
    height error obeys ``(s³ + k1 s² + (k2 − 2ω_s²) s + k3) δh = s u`` (see
    :mod:`stableins.simulator.system`); the gains put its poles at ``-a`` and
    ``-a/2 ± i a √3/2`` with ``a = 1/τ`` (third-order Butterworth,
    ``(s + a)(s² + a s + a²)``): ``k1 = 2a``, ``k2 = 2a² + 2ω_s²``, ``k3 = a³``.
    """
    omega_s = math.sqrt(gravity / EARTH_RADIUS)
    a = 1.0 / vertical_time_constant
    return {
        "zeta": float(zeta),
        "omega_s": omega_s,
        "R": EARTH_RADIUS,
        "gravity": float(gravity),
        "horizontal_gain": 2.0 * zeta * omega_s,
        "vertical_time_constant": float(vertical_time_constant),
        "k1": 2.0 * a,
        "k2": 2.0 * a**2 + 2.0 * omega_s**2,
        "k3": a**3,
    }


def _float_dict(d: Any, name: str, source: str | None) -> dict[str, float]:
    if not isinstance(d, Mapping):
        raise InputError(f"'{name}' must be a mapping of id to number", path=source, field=name)
    out = {}
    for k, v in d.items():
        try:
            out[str(k)] = float(v)
        except (TypeError, ValueError):
            raise InputError(f"value {v!r} is not a number", path=source, field=f"{name}.{k}") from None
        if not math.isfinite(out[str(k)]):
            raise InputError("value is not finite", path=source, field=f"{name}.{k}")
    return out


def _check_parameter_ids(d: Mapping[str, float], name: str, source: str | None, *, effects: bool = False) -> None:
    allowed = PARAMETER_IDS + (INSTALLED_EFFECT_IDS if effects else ())
    unknown = sorted(set(d) - set(allowed))
    if unknown:
        what = f"ids among {', '.join(PARAMETER_IDS)}" + (" or output effects of the catalogue" if effects else "")
        raise InputError(f"unknown parameter ids {unknown}", path=source, field=name, expected=what)


def _triple(values: Iterable[float]) -> tuple[float, float, float]:
    """Three values as a tuple of floats (an angle triple: zero offsets, base attitude)."""
    x, y, z = (float(v) for v in values)
    return x, y, z


def _check_fields(d: Any, source: str | None) -> None:
    """Check a truth file's object, kind, schema version and field names; raise :class:`InputError` naming the field."""
    if not isinstance(d, Mapping):
        raise InputError("a truth file must hold a JSON object", path=source)
    if d.get("kind", KIND) != KIND:
        raise InputError(f"not a truth file (kind {d.get('kind')!r})", path=source, field="kind", expected=repr(KIND))
    version = d.get("schema_version")
    if version != TRUTH_SCHEMA_VERSION:
        raise InputError(f"unsupported schema_version {version!r}", path=source, field="schema_version", expected=str(TRUTH_SCHEMA_VERSION))
    for key in ("parameters", "site"):
        if key not in d:
            raise InputError("missing field", path=source, field=key)
    known = {
        "schema_version",
        "kind",
        "parameters",
        "effects",
        "site",
        "noise",
        "seed",
        "installed_calibration",
        "gyro_drift",
        "damping",
        "settling",
    }
    unknown = sorted(set(d) - known)
    if unknown:
        raise InputError(f"unknown fields {unknown}", path=source, field=unknown[0], expected=f"fields among {', '.join(sorted(known))}")


#: Keys of a truth's ``gyro_drift``: the constant drift, the gyro-case-rotation residual, the torquers' scale-factor error.
GYRO_KEYS = ("x", "y", "z", "case_amplitude", "case_period", "case_phase", "torquer_scale_x", "torquer_scale_y", "torquer_scale_z")


def _site(d: Any, source: str | None) -> SiteMetadata:
    """Read the ``site`` field of a truth file; raise :class:`InputError` on bad content."""
    if not isinstance(d, Mapping):
        raise InputError("must be an object", path=source, field="site")
    try:
        d = dict(d)
        d["gimbal_senses"] = tuple(int(s) for s in d.get("gimbal_senses", (1, 1, 1, 1)))
        d["base_attitude"] = tuple(float(s) for s in d.get("base_attitude", (0.0, 0.0, 0.0)))
        site = SiteMetadata(**d)
        GimbalConfiguration(site.gimbal_senses)
    except (InputError, NotDeterminedError):
        raise  # a described error passes through as it is (issue 29)
    except (TypeError, ValueError) as exc:
        raise InputError(f"bad site metadata: {exc}", path=source, field="site") from None
    return site


@dataclass(frozen=True)
class SimulatedSite:
    """Where a drawn instrument sits and how it samples (:meth:`Truth.draw`).  SI inside.

    Attributes
    ----------
    latitude : float
        Geodetic latitude [rad].
    height : float
        Ellipsoidal height [m].
    sample_rate : float
        Accelerometer sample rate [Hz].
    gimbal_senses : tuple of int
        Rotation senses ``(s1, s2, s3, s4)``, see :mod:`stableins.conventions`.
    base_attitude : tuple of float
        True (yaw, pitch, roll) of the base [rad].
    serial_number : str or None
        Unit serial number (None: ``SIM-<seed>``).
    """

    latitude: float = math.radians(40.0)
    height: float = 0.0
    sample_rate: float = 100.0
    gimbal_senses: tuple[int, int, int, int] = (1, 1, 1, 1)
    base_attitude: tuple[float, float, float] = (0.0, 0.0, 0.0)
    serial_number: str | None = None

    def metadata(self, *, serial_number: str, reference_temperature: float) -> SiteMetadata:
        """Return the site metadata of the simulated world: its gravity is WGS-84 normal gravity, exact there."""
        senses = self.gimbal_senses
        return SiteMetadata(
            serial_number=serial_number,
            latitude=float(self.latitude),
            height=float(self.height),
            gravity=float(normal_gravity(self.latitude, self.height)),
            # the simulated world's gravity is the normal-gravity formula itself: the site's g is exact there
            gravity_source="WGS-84 normal gravity (the simulated world's gravity: exact)",
            gravity_uncertainty=0.0,
            sample_rate=float(self.sample_rate),
            gimbal_senses=(senses[0], senses[1], senses[2], senses[3]),
            base_attitude=_triple(self.base_attitude),
            reference_temperature=reference_temperature,
        )


#: The default placement of a drawn instrument: 40° N, sea level, 100 Hz, positive senses, level base.
DEFAULT_SITE = SimulatedSite()


@dataclass(frozen=True)
class Truth:
    """The simulated world (immutable: the mappings are read-only views; use :meth:`with_changes`).

    Attributes
    ----------
    parameters : dict
        True error-model values by id [SI] (ids of :data:`PARAMETER_IDS`); absent ids take
        their reference (scale factor 1, others 0).
    site : SiteMetadata
        Latitude, gravity, sample rate, gimbal senses, base attitude ...
    effects : dict
        Injected extra effects by id [SI] (:mod:`stableins.simulator.effects`).
    noise : NoiseSettings
    seed : int
        Default seed of the random streams.
    installed_calibration : dict
        The calibration the INS navigation computer compensates with (system level);
        the residual true − installed drives the navigation errors.  Besides
        :data:`PARAMETER_IDS` it may hold output effects (:data:`INSTALLED_EFFECT_IDS`): the
        discovered terms of a calibration record, compensated like the others.
    gyro_drift : dict
        System level: ``x``, ``y``, ``z`` constant gyro drift in the platform frame
        [rad/s]; ``case_amplitude`` [rad/s], ``case_period`` [s] (default 480 s) and
        ``case_phase`` [rad] of the residual of gyro-case rotation (a drift vector of
        that amplitude rotating about ``z_p``); ``torquer_scale_x/y/z`` (dimensionless): the scale-factor error
        ``k`` of the gyro torquers (a torquer turns the platform at ``1 + k`` times the commanded rate; device
        dwells torqued at the computed Earth rate, :func:`stableins.conventions.dwell_platform_rate`).
    damping : dict
        ``zeta`` and ``vertical_time_constant`` [s] of the INS damping loops.
    settling : dict
        Slew and settling behaviour (:data:`DEFAULT_SETTLING`).
    """

    parameters: Mapping[str, float]
    site: SiteMetadata
    effects: Mapping[str, float] = field(default_factory=dict)
    noise: NoiseSettings = field(default_factory=NoiseSettings)
    seed: int = 0
    installed_calibration: Mapping[str, float] = field(default_factory=dict)
    gyro_drift: Mapping[str, float] = field(default_factory=dict)
    damping: Mapping[str, float] = field(default_factory=lambda: dict(DEFAULT_DAMPING))
    settling: Mapping[str, float] = field(default_factory=lambda: dict(DEFAULT_SETTLING))

    def __post_init__(self) -> None:
        _check_parameter_ids(self.parameters, "parameters", None)
        _check_parameter_ids(self.installed_calibration, "installed_calibration", None, effects=True)
        # read-only views: a Truth is immutable (use with_changes for a modified copy)
        object.__setattr__(self, "parameters", MappingProxyType(dict(self.parameters)))
        object.__setattr__(self, "installed_calibration", MappingProxyType(dict(self.installed_calibration)))
        object.__setattr__(self, "effects", MappingProxyType(validate_effects(self.effects)))
        object.__setattr__(self, "damping", MappingProxyType({**DEFAULT_DAMPING, **self.damping}))
        object.__setattr__(self, "settling", MappingProxyType({**DEFAULT_SETTLING, **self.settling}))
        object.__setattr__(self, "gyro_drift", MappingProxyType(dict(self.gyro_drift)))
        unknown = set(self.gyro_drift) - set(GYRO_KEYS)
        if unknown:
            raise InputError(f"unknown gyro_drift keys {sorted(unknown)}", field="gyro_drift", expected=", ".join(GYRO_KEYS))
        # the site carries the damping the world uses (derived from ``damping`` and the site's gravity)
        derived = self.damping_parameters()
        if self.site.damping != derived:
            object.__setattr__(self, "site", replace(self.site, damping=derived))

    # ----------------------------------------------------------------- derived
    def damping_parameters(self) -> dict[str, float]:
        """``zeta, omega_s, R, k1, k2, k3`` ... (see :func:`damping_parameters`)."""
        return damping_parameters(self.damping["zeta"], self.damping["vertical_time_constant"], self.site.gravity)

    @property
    def configuration(self) -> GimbalConfiguration:
        """The true gimbal configuration (the site's rotation senses)."""
        s1, s2, s3, s4 = self.site.gimbal_senses
        return GimbalConfiguration((s1, s2, s3, s4))

    def platform(self):
        """Return the true :class:`stableins.platform.GimbalPlatform` (offsets, senses, base, tilt, non-orthogonality, sensor errors)."""
        from stableins.platform import GimbalPlatform

        e = self.effects
        return GimbalPlatform(
            zero_offsets=_triple(self.parameters.get(g, 0.0) for g in GIMBAL_IDS),
            configuration=self.configuration,
            base_attitude=_triple(self.site.base_attitude),
            base_tilt=(e.get("tilt_north", 0.0), e.get("tilt_east", 0.0)),
            base_azimuth=e.get("azimuth_error", 0.0),
            nonorthogonality=(e.get("nonorth_12", 0.0), e.get("nonorth_23", 0.0)),
            angle_sensor_errors={k: v for k, v in e.items() if k.startswith("ang1_")},
        )

    def calibration_residual(self) -> dict[str, float]:
        """Return true minus installed calibration, by id [SI] (ids in either)."""
        ids = [i for i in PARAMETER_IDS if i in self.parameters or i in self.installed_calibration]
        return {i: self.parameters.get(i, REFERENCE[i]) - self.installed_calibration.get(i, REFERENCE[i]) for i in ids}

    def with_changes(self, **changes: Any) -> Truth:
        """Return a copy with some fields replaced (dataclasses.replace)."""
        return replace(self, **changes)

    def with_installed(self, values: Mapping[str, float], *, source: str | None = None) -> Truth:
        """Return the truth whose navigation computer compensates with ``values`` (a calibration record's values).

        The record's discovered (additive) terms are installed too: the navigation computer compensates with them
        (:meth:`stableins.simulator.physics.Accelerometer.specific_force` with the simulator's own definition of the
        effect, :mod:`stableins.simulator.effects`).
        Ids the record lacks keep this truth's installed value.  The gyro drift (``gyro_drift_x/y/z``) and
        g-sensitivity (``Dg_ab``) are not installed: the simulated navigation computer does not compensate its gyros
        (the platform drifts with the truth's ``gyro_drift`` and ``Dg_ab`` effects).  An id neither the error model
        nor the effect catalogue's output effects know is refused (:class:`InputError` naming ``source`` and the id).
        """
        installed = dict(self.installed_calibration)
        known = set(PARAMETER_IDS) | set(INSTALLED_EFFECT_IDS)
        drift_ids = set(UNINSTALLED_GYRO_IDS)
        for parameter_id, value in values.items():
            if parameter_id in drift_ids:
                continue
            if parameter_id not in known:
                raise InputError(
                    f"parameter {parameter_id!r} is not part of the simulated instrument",
                    path=source,
                    field=parameter_id,
                    expected="standard parameters or output effects of 'stableins simulate --list-effects'",
                )
            installed[parameter_id] = float(value)
        return replace(self, installed_calibration=installed)

    # ----------------------------------------------------------------- drawing
    @classmethod
    def draw(
        cls,
        seed: int,
        *,
        site: SimulatedSite = DEFAULT_SITE,
        effects: Mapping[str, float] | None = None,
        noise: NoiseSettings | None = None,
        nonlinear: bool = True,
        residual: Mapping[str, float] | None = None,
        gyro_drift: Mapping[str, float] | None = None,
        damping: Mapping[str, float] | None = None,
    ) -> Truth:
        """Draw a realistic random instrument.

        Each parameter is drawn as ``reference + nominal × N(0, 1)`` with the nominal
        magnitude of the simulator's parameter table (:data:`stableins.simulator.physics.PARAMETERS`: 100 ppm,
        100 µg, 30″, 20 µg/g², zero offsets 60″).  The installed calibration is the truth minus a
        residual drawn with :data:`DEFAULT_RESIDUAL` (override per kind with
        ``residual``).  Noise defaults to :meth:`NoiseSettings.quartz`.  ``site`` places
        the instrument (:class:`SimulatedSite`; its gravity is WGS-84 normal gravity there).
        """
        import numpy as np

        rng = np.random.default_rng(np.random.SeedSequence([int(seed), 7477]))
        table = simulated_parameters(nonlinear=nonlinear)
        drawn = {p.id: float(p.reference + p.nominal * rng.standard_normal()) for p in table}
        scales = {**DEFAULT_RESIDUAL, **(residual or {})}
        installed = {p.id: float(drawn[p.id] - scales[p.kind] * rng.standard_normal()) for p in table}
        metadata = site.metadata(
            serial_number=site.serial_number or f"SIM-{seed}",
            reference_temperature=(noise or NoiseSettings.quartz()).temperature.reference,
        )
        return cls(
            parameters=drawn,
            site=metadata,
            effects=dict(effects or {}),
            noise=noise if noise is not None else NoiseSettings.quartz(),
            seed=int(seed),
            installed_calibration=installed,
            gyro_drift=dict(gyro_drift or {}),
            damping={**DEFAULT_DAMPING, **(damping or {})},
        )

    # ----------------------------------------------------------------- serialization
    def to_dict(self) -> dict[str, Any]:
        """Return the truth as a JSON-ready dict (``schema_version`` 1; :meth:`from_dict` reads it back)."""
        return {
            "schema_version": TRUTH_SCHEMA_VERSION,
            "kind": KIND,
            "parameters": dict(self.parameters),
            "effects": dict(self.effects),
            "site": self.site.to_dict(),
            "noise": self.noise.to_dict(),
            "seed": self.seed,
            "installed_calibration": dict(self.installed_calibration),
            "gyro_drift": dict(self.gyro_drift),
            "damping": dict(self.damping),
            "settling": dict(self.settling),
        }

    @classmethod
    def from_dict(cls, d: Any, source: str | None = None) -> Truth:
        """Inverse of :meth:`to_dict`; raises :class:`InputError` naming the field on bad content."""
        _check_fields(d, source)
        parameters = _float_dict(d["parameters"], "parameters", source)
        _check_parameter_ids(parameters, "parameters", source)
        installed = _float_dict(d.get("installed_calibration", {}), "installed_calibration", source)
        _check_parameter_ids(installed, "installed_calibration", source, effects=True)
        effects = validate_effects(_float_dict(d.get("effects", {}), "effects", source), source)
        site = _site(d["site"], source)
        try:
            noise = NoiseSettings.from_dict(d.get("noise", {}))
        except (InputError, NotDeterminedError):
            raise  # a described error passes through as it is (issue 29)
        except (TypeError, ValueError) as exc:
            raise InputError(f"bad noise settings: {exc}", path=source, field="noise") from None
        try:
            seed = int(d.get("seed", 0))
        except (TypeError, ValueError):
            raise InputError("seed must be an integer", path=source, field="seed") from None
        try:
            return cls(
                parameters=parameters,
                site=site,
                effects=effects,
                noise=noise,
                seed=seed,
                installed_calibration=installed,
                gyro_drift=_float_dict(d.get("gyro_drift", {}), "gyro_drift", source),
                damping=_float_dict(d.get("damping", DEFAULT_DAMPING), "damping", source),
                settling=_float_dict(d.get("settling", DEFAULT_SETTLING), "settling", source),
            )
        except InputError as exc:
            raise InputError(exc.message, path=source, field=exc.field, expected=exc.expected) from None
