"""What the estimators know of a procedure, as plain values: the dwell checks and the positions of a stage.

Procedures (:mod:`stableins.procedures.definition`) are read and executed above the estimators; the
estimators never see a procedure object, a driver or a file.  A procedure hands them

* :class:`DwellChecks`, the one set of thresholds a dwell is checked against, on the platform while
  the runner records it (reached, still, complete) and in the estimators that use it (enough samples,
  no saturation or clipping, no slew inside it, the orientation it was commanded to);
* :class:`StageLayout`, the positions of a device-level stage with their settle times, the gimbal
  handedness the sequence was designed for and the checks of its dwells.

Thresholds and their defaults are listed in ``docs/procedures.md`` ("Checks of a dwell").
"""

from __future__ import annotations

from dataclasses import dataclass, field

from stableins.conventions import ARCSEC, STANDARD_GRAVITY


@dataclass(frozen=True)
class DwellChecks:
    """The thresholds a dwell is checked against (SI; one name and one default each).

    Procedure files give them in engineering units: ``[acceptance]`` the first five,
    ``[runner]`` the next four plus ``max_slew`` (docs/procedures.md).

    Attributes
    ----------
    min_samples : int
        Fewest samples that still measure the noise (the block estimate needs ``noise_blocks``
        blocks of at least 2 samples).
    noise_blocks : int
        Number of blocks of the block-mean noise estimate of a dwell mean.
    saturation : float
        Output magnitude at or beyond which a sample counts as saturated [m/s²] (default 3 g).
    max_angle_span : float
        Largest peak-to-peak span of an angle reading within the dwell [rad] (a slew inside it; default 20″).
    orientation_tolerance : float
        Largest difference between the measured and the commanded orientation's specific force [m/s²]
        (default 0.02 g).
    angle_tolerance : float
        Largest absolute difference of the measured readings' least-squares line at the dwell's start and the commanded
        reading of any gimbal [rad]: the platform has arrived (default 20″; a steady gyro drift after that is not an
        error, docs/conventions.md "The platform during a dwell").
    scatter_max : float
        Largest standard deviation of any accelerometer axis about its straight-line fit [m/s²]
        ("still"; default 5000 µg, well above the per-sample white noise of a navigation-grade
        accelerometer at 100 Hz, a few hundred µg).
    slope_max : float
        Largest absolute slope of that fit beyond 3σ of its own noise [m/s² per s] ("still": no creep;
        default 20 µg/s).
    min_fraction : float
        Smallest fraction of the expected number of samples (``dwell × rate``) accepted (gaps).
    max_slew : float
        Longest wait for the platform to arrive after a command [s]; the settle time starts on arrival.
    noise_floor : float
        Smallest 1σ of a dwell mean [m/s²]; keeps noiseless simulations finite.
    correlation_quantile : float
        Quantile of the white-noise ratio test above which the block estimate of a dwell mean's
        1σ is used.
    """

    min_samples: int = 20
    noise_blocks: int = 10
    saturation: float = 3.0 * STANDARD_GRAVITY
    max_angle_span: float = 20.0 * ARCSEC
    orientation_tolerance: float = 0.02 * STANDARD_GRAVITY
    angle_tolerance: float = 20.0 * ARCSEC
    scatter_max: float = 5e-3 * STANDARD_GRAVITY
    slope_max: float = 20e-6 * STANDARD_GRAVITY
    min_fraction: float = 0.98
    max_slew: float = 120.0
    noise_floor: float = 1e-9
    correlation_quantile: float = 0.999


@dataclass(frozen=True)
class StageLayout:
    """The positions of one device-level stage as the estimators see them.

    Attributes
    ----------
    name : str
        Name of the procedure the positions come from (recorded in the stage's settings).
    stage : str
        ``"coarse"`` or ``"fine"``.
    positions : tuple of int
        Position numbers, in order.
    settles : tuple of float
        Settle time of each position [s]: samples earlier after the command are dropped.
    handedness : int
        Gimbal handedness (+1 or −1) the sequence was designed for (docs/conventions.md).
    checks : DwellChecks
        The checks of every dwell of the stage.
    source : str
        Where the positions were defined (a procedure file), for messages.
    """

    name: str
    stage: str
    positions: tuple[int, ...]
    settles: tuple[float, ...]
    handedness: int = 1
    checks: DwellChecks = field(default_factory=DwellChecks)
    source: str = ""

    def settle(self, position: int) -> float:
        """Return the settle time of ``position`` [s] (KeyError when the stage has no such position)."""
        try:
            return self.settles[self.positions.index(position)]
        except ValueError:
            raise KeyError(position) from None
