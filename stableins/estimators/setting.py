"""What every device-level fit of one unit shares: where the unit stands, its noise model, its discovered terms."""

from __future__ import annotations

from dataclasses import dataclass

from stableins.conventions import DEFAULT_GIMBALS, GimbalConfiguration
from stableins.errormodel import Term
from stableins.noise import NoiseModel
from stableins.site import SiteMetadata


@dataclass(frozen=True)
class DeviceSetting:
    """The plain values a device-level fit (coarse pass, joint fit, zero-offset iteration) works in.  SI inside.

    Attributes
    ----------
    gravity : float
        Local gravity [m/s²].
    base_attitude : tuple of float
        Base attitude (yaw, pitch, roll) from the site survey [rad].
    configuration : GimbalConfiguration
        Gimbal rotation senses.
    noise : NoiseModel or None
        The instrument's noise model: its bias instability / random walk add the correlated covariance of the
        dwell means (:meth:`stableins.noise.NoiseModel.dwell_mean_covariance`); None: white noise measured in each
        dwell only.
    extra_terms : tuple of Term
        Additive terms (discovered effects, e.g. the library's ``Kcc_xxy``) estimated with the standard ones.

    Examples
    --------
    >>> DeviceSetting(9.80).configuration.senses
    (1, 1, 1, 1)
    """

    gravity: float
    base_attitude: tuple[float, float, float] = (0.0, 0.0, 0.0)
    configuration: GimbalConfiguration = DEFAULT_GIMBALS
    noise: NoiseModel | None = None
    extra_terms: tuple[Term, ...] = ()

    @classmethod
    def from_site(cls, site: SiteMetadata, *, noise: NoiseModel | None = None, extra_terms: tuple[Term, ...] = ()) -> DeviceSetting:
        """Return the setting of a unit at ``site`` (its gravity, base attitude and gimbal senses)."""
        senses = site.gimbal_senses
        return cls(
            float(site.gravity),
            site.base_attitude,
            GimbalConfiguration((senses[0], senses[1], senses[2], senses[3])),
            noise,
            tuple(extra_terms),
        )
