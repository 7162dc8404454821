r"""Static-base INS error dynamics of a space-stable INS, and the platform's orientation while it navigates.

This is the navigation budget's own model (docs/navigation-budget.md derives it); it does not use the
simulator's integrator.  States (NED, true-frame ``φ``, ``C_n^{n'} = I − [φ×]``; Britting 1971 ch. 6,
Titterton & Weston 2004 §12.2 with ``v = 0``; Zhang et al. 2023 Eqs. 4–6 with their lost signs restored)::

    δL'  = δv_N / R
    δλ'  = δv_E / (R cos L)
    δv_N' = Δf_N + g φ_E − 2Ω sinL δv_E − c δv_N
    δv_E' = Δf_E − g φ_N + 2Ω sinL δv_N + 2Ω cosL δv_D − c δv_E
    φ_N' = −Ω sinL δL − Ω sinL φ_E + δv_E / R − ε_N
    φ_E' =  Ω sinL φ_N + Ω cosL φ_D − δv_N / R − ε_E
    φ_D' = −Ω cosL δL − Ω cosL φ_E − tanL δv_E / R − ε_D
    δh'  = −δv_D − k1 δh
    δv_D' = Δf_D − 2Ω cosL δv_E − (2g/R − k2) δh + b
    b'   = k3 δh

``f^n × φ = (g φ_E, −g φ_N, 0)`` for ``f^n = (0, 0, −g)``; ``−2ω_ie^n × δv`` with ``ω_ie^n = Ω(cos L, 0, −sin L)``;
``−ω_ie^n × φ + δω_ie^n + δω_en^n`` in ``φ'``; gravity falls with height (``δg_D = −2g δh/R``).  The horizontal
damping feeds ``−c δv`` (``c = 2ζω_s``, ``ω_s = sqrt(g/R)``; ζ = 0 is the pure-inertial INS); the vertical
channel is held by an external height reference through ``k1, k2, k3`` (absent: the vertical channel is left
out, ``δv_D ≡ 0``).  The longitude error does not feed back on a static base.

The platform is polar aligned at ``t = 0`` (:func:`stableins.conventions.polar_alignment_readings` on a level,
north-pointing base, Earth-rate angle ``S0``) and then held fixed in inertial space while the local frame turns
with the Earth: ``C_n^p(t) = C_{n0}^{p0} exp(Ωt [u×])``, ``u = ω_ie^n/Ω``.  So ``f^p/g = (cos S cos L, sin S cos L,
sin L)``, ``S = S0 + Ωt``, and a constant platform-frame error appears in the navigation frame as harmonics of
``Ωt``: ``Δf^n = C_p^n(t) Δf^p(S)``, ``ε^n = C_p^n(t) ε^p``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stableins.conventions import (
    DEFAULT_GIMBALS,
    EARTH_RADIUS,
    EARTH_RATE,
    GimbalConfiguration,
    dcm_body_to_platform,
    earth_rate_nav,
    normal_gravity,
    polar_alignment_readings,
    skew,
)
from stableins.errors import InputError
from stableins.site import SiteMetadata

#: The error states, in order.
STATE_NAMES = (
    "latitude_error",
    "longitude_error",
    "velocity_north",
    "velocity_east",
    "phi_north",
    "phi_east",
    "phi_down",
    "height_error",
    "velocity_down",
    "vertical_integrator",
)
#: The inputs, in order: the n-frame specific-force error [m/s²] and the n-frame gyro drift [rad/s].
INPUT_NAMES = ("df_north", "df_east", "df_down", "drift_north", "drift_east", "drift_down")


@dataclass(frozen=True)
class NavigationScenario:
    """Where and how the INS navigates: the static-base scenario of a navigation budget.

    Attributes
    ----------
    latitude : float
        [rad].
    gravity : float
        Local gravity [m/s²].
    zeta : float
        Damping ratio of the horizontal (Schuler) loops; 0 is the pure-inertial INS.
    radius : float
        Earth radius of the Schuler loop [m].
    vertical_gains : tuple of 3 float or None
        ``(k1, k2, k3)`` of the vertical loop held by an external height reference; None leaves the vertical
        channel out.
    configuration : GimbalConfiguration
        Gimbal senses (polar alignment, gimbal-offset attitude errors).
    earth_angle : float
        Earth-rate angle ``S0`` at the start of navigation [rad].
    """

    latitude: float
    gravity: float
    zeta: float = 0.0
    radius: float = EARTH_RADIUS
    vertical_gains: tuple[float, float, float] | None = None
    configuration: GimbalConfiguration = DEFAULT_GIMBALS
    earth_angle: float = 0.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.latitude) and abs(self.latitude) < math.radians(89.0)):
            raise InputError(f"latitude {math.degrees(self.latitude):.6g}° is outside ±89°", field="latitude", expected="|latitude| < 89°")
        if not (math.isfinite(self.zeta) and 0.0 <= self.zeta <= 5.0):
            raise InputError(f"damping ratio {self.zeta!r} is outside [0, 5]", field="damping", expected="0 ≤ ζ ≤ 5 (0: pure inertial)")
        if not (math.isfinite(self.gravity) and self.gravity > 0) or not (math.isfinite(self.radius) and self.radius > 0):
            raise InputError("gravity and radius must be positive", field="gravity")

    @classmethod
    def from_site(cls, site: SiteMetadata, *, latitude: float | None = None, zeta: float | None = None) -> NavigationScenario:
        """Return the scenario of a record's site: its latitude, gravity, damping (``SiteMetadata.damping``) and gimbal senses.

        ``latitude`` [rad] replaces the site's (gravity then is normal gravity there, at the site's height);
        ``zeta`` replaces the site's damping ratio (no damping in the site: 0, the pure-inertial INS).
        """
        damping = dict(site.damping or {})
        gravity = site.gravity if latitude is None else float(normal_gravity(latitude, site.height))
        lat = site.latitude if latitude is None else float(latitude)
        gains = tuple(damping[k] for k in ("k1", "k2", "k3")) if all(k in damping for k in ("k1", "k2", "k3")) else None
        return cls(
            latitude=lat,
            gravity=gravity,
            zeta=float(damping.get("zeta", 0.0) if zeta is None else zeta),
            radius=float(damping.get("R", EARTH_RADIUS)),
            vertical_gains=gains,  # type: ignore[arg-type]
            configuration=GimbalConfiguration(tuple(site.gimbal_senses)),  # type: ignore[arg-type]
        )

    @property
    def schuler_frequency(self) -> float:
        """``ω_s = sqrt(g/R)`` [rad/s]."""
        return math.sqrt(self.gravity / self.radius)

    @property
    def horizontal_gain(self) -> float:
        """``c = 2ζω_s`` [1/s]."""
        return 2.0 * self.zeta * self.schuler_frequency

    def matrices(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """``x' = A x + B u`` of the module docstring: ``A`` (10, 10), ``B`` (10, 6) (:data:`STATE_NAMES`, :data:`INPUT_NAMES`)."""
        g, radius, c, w = self.gravity, self.radius, self.horizontal_gain, EARTH_RATE
        sl, cl, tl = math.sin(self.latitude), math.cos(self.latitude), math.tan(self.latitude)
        A = np.zeros((10, 10))
        B = np.zeros((10, 6))
        lat, lon, vn, ve, pn, pe, pd, h, vd, bv = range(10)
        A[lat, vn] = 1.0 / radius
        A[lon, ve] = 1.0 / (radius * cl)
        A[vn, pe], A[vn, ve], A[vn, vn] = g, -2.0 * w * sl, -c
        A[ve, pn], A[ve, vn], A[ve, ve] = -g, 2.0 * w * sl, -c
        A[pn, lat], A[pn, pe], A[pn, ve] = -w * sl, -w * sl, 1.0 / radius
        A[pe, pn], A[pe, pd], A[pe, vn] = w * sl, w * cl, -1.0 / radius
        A[pd, lat], A[pd, pe], A[pd, ve] = -w * cl, -w * cl, -tl / radius
        B[vn, 0] = B[ve, 1] = 1.0
        B[pn, 3] = B[pe, 4] = B[pd, 5] = -1.0
        if self.vertical_gains is not None:
            k1, k2, k3 = self.vertical_gains
            A[ve, vd] = 2.0 * w * cl
            A[h, vd], A[h, h] = -1.0, -k1
            A[vd, ve], A[vd, h], A[vd, bv] = -2.0 * w * cl, -2.0 * g / radius + k2, 1.0
            A[bv, h] = k3
            B[vd, 2] = 1.0
        return A, B

    def initial_nav_to_platform(self) -> NDArray[np.float64]:
        """``C_{n0}^{p0}``: the polar-alignment orientation on a level, north-pointing base at ``S0``."""
        s1 = self.configuration.senses[0]
        _, middle = polar_alignment_readings(self.latitude, self.configuration)
        return dcm_body_to_platform(-s1 * self.earth_angle, 0.0, middle, 0.0, self.configuration)

    def nav_to_platform(self, phase: ArrayLike) -> NDArray[np.float64]:
        """``C_n^p`` (..., 3, 3) at Earth-rate phases ``Ωt`` [rad] of the inertially held platform (no drift)."""
        theta = np.asarray(phase, dtype=float)
        k = skew(earth_rate_nav(self.latitude) / EARTH_RATE)
        rotation = np.eye(3) + np.sin(theta)[..., None, None] * k + (1.0 - np.cos(theta))[..., None, None] * (k @ k)
        return self.initial_nav_to_platform() @ rotation
