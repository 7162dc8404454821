"""The dwell set discovery fits: dwell means of the device stage, their 1σ from noise measured in the data, and slew directions."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stableins.conventions import DEFAULT_GIMBALS, HYSTERESIS_THRESHOLD, GimbalConfiguration
from stableins.dwell_mode import DEFAULT_DWELL_MODE, DwellMode
from stableins.estimators.layout import StageLayout

if TYPE_CHECKING:  # pragma: no cover
    from stableins.estimators.dwell import DwellSummary
    from stableins.noise import NoiseModel
    from stableins.samples import SampleBlock
    from stableins.site import SiteMetadata


# ----------------------------------------------------------------------------- device dwells
@dataclass(frozen=True)
class DwellSet:
    """Dwell means of a device-level procedure (one row per position).

    Attributes
    ----------
    readings : ndarray (P, 3)
        Mean angle-sensor readings (platform, inner, middle) during the dwell [rad].
    output : ndarray (P, 3)
        Dwell-mean accelerometer outputs ``f^a`` [m/s²].
    sigma : ndarray (P, 3)
        1σ of each dwell mean, from noise measured in the data [m/s²].
    gravity : float
        Local gravity [m/s²].
    time : ndarray (P,)
        Mid-dwell session time [s].
    time_since_command : ndarray (P,)
        Mean time since the position was commanded [s].
    temperature : ndarray (P,)
        Mean temperature minus the reference temperature [K].
    slew_direction : ndarray (P, 3)
        Hysteresis state of each axis at each dwell: the sign of the last slew that moved its input
        beyond :data:`HYSTERESIS_THRESHOLD` (+1 rose, −1 fell, 0 before any such slew), over every
        position the platform visited before the dwell, in the nominal geometry
        (:func:`slew_directions`; dwells left out by the checks and the dwells of an earlier stage
        included, :func:`dwells_from_dataset`).  :class:`DwellProblem` uses it as it is: the
        threshold (about 3.5′ of tilt) makes it independent of the arcsecond-level geometry the fit
        estimates.
    labels : tuple of str
        Name of each position.
    base_attitude : tuple
        Nominal (yaw, pitch, roll) of the base [rad].
    configuration : GimbalConfiguration
        Gimbal rotation senses.
    noise : dict
        How ``sigma`` was measured (method, per-axis floors ...).
    initial_readings : tuple or None
        Angle-sensor readings before the first command of these dwells (the slew into the first
        position); None: unknown.  Where the platform stood before the dwells: the start of
        :meth:`following` (proposals of further positions, :mod:`stableins.discovery.separation`).
    slow_covariance : ndarray (3, P, P), optional
        Covariance of the dwell means beyond their white 1σ, per axis: slow noise (bias
        instability, random walk) correlated between dwells, and quantization
        (:func:`stableins.estimators.dwell.slow_covariance`, the device stages' own).  The fit
        is then generalized least squares with ``R_a = diag(σ_a²) + C_slow,a`` per axis.
    reading_slope, reading_slope_sigma : ndarray (P, 3), optional
        Slope of each angle reading within the dwell [rad/s] and its 1σ: platform drift
        (:mod:`stableins.discovery.drift`).
    dwell_mode : DwellMode
        How the platform was held during the dwells (the data files' metadata).
    latitude : float
        Site latitude [rad] (the Earth rate of the torqued dwells).
    reading_centre : ndarray (P, 3), optional
        Mean reading of the samples each reading slope is fitted on [rad]
        (:attr:`stableins.estimators.gyro_sensitivity.ReadingSlopes.centre`): where the drift analysis evaluates the
        geometry (None: :attr:`readings`).
    """

    readings: NDArray[np.float64]
    output: NDArray[np.float64]
    sigma: NDArray[np.float64]
    gravity: float
    time: NDArray[np.float64]
    time_since_command: NDArray[np.float64]
    temperature: NDArray[np.float64]
    slew_direction: NDArray[np.float64]
    labels: tuple[str, ...]
    base_attitude: tuple[float, float, float] = (0.0, 0.0, 0.0)
    configuration: GimbalConfiguration = DEFAULT_GIMBALS
    noise: dict = field(default_factory=dict)
    initial_readings: tuple[float, float, float] | None = (0.0, 0.0, 0.0)
    slow_covariance: NDArray[np.float64] | None = None
    reading_slope: NDArray[np.float64] | None = None
    reading_slope_sigma: NDArray[np.float64] | None = None
    dwell_mode: DwellMode = DEFAULT_DWELL_MODE
    latitude: float = 0.0
    reading_centre: NDArray[np.float64] | None = None

    def __post_init__(self) -> None:
        p = self.readings.shape[0]
        for name in ("readings", "output", "sigma", "slew_direction"):
            if getattr(self, name).shape != (p, 3):
                raise ValueError(f"DwellSet.{name} must have shape ({p}, 3), got {getattr(self, name).shape}")
        for name in ("time", "time_since_command", "temperature"):
            if getattr(self, name).shape != (p,):
                raise ValueError(f"DwellSet.{name} must have shape ({p},), got {getattr(self, name).shape}")
        if len(self.labels) != p:
            raise ValueError("DwellSet.labels must name every position")
        if not np.all(np.isfinite(self.sigma)) or np.any(self.sigma <= 0):
            raise ValueError("DwellSet.sigma must be finite and positive")

    @property
    def n_positions(self) -> int:
        """Number of dwells (positions)."""
        return self.readings.shape[0]

    @property
    def final_readings(self) -> tuple[float, float, float]:
        """Mean readings of the last dwell (where the platform stands after these dwells) [rad]."""
        last = self.readings[-1]
        return (float(last[0]), float(last[1]), float(last[2]))

    def nominal_specific_force(self) -> NDArray[np.float64]:
        """``f^p`` of every dwell in the nominal geometry (no zero offsets, no equipment effects) [m/s²]."""
        from stableins.platform import platform_specific_force

        return platform_specific_force(self.readings, self.gravity, base_attitude=self.base_attitude, configuration=self.configuration)

    def following(self, previous: DwellSet) -> DwellSet:
        """Return these dwells as visited after ``previous``: the hysteresis states continue from its last dwell.

        For positions proposed after the data (:mod:`stableins.discovery.separation`): the first slew starts at the
        last dwell of ``previous`` with its hysteresis state (:func:`slew_directions`).
        """
        from dataclasses import replace

        start = previous.nominal_specific_force()[-1]
        states = slew_directions(self.nominal_specific_force(), start, state=previous.slew_direction[-1])
        return replace(self, slew_direction=states, initial_readings=previous.final_readings)

    def subset(self, index: ArrayLike) -> DwellSet:
        """Return the dwells at ``index`` (positions to leave out, cross-validation)."""
        i = np.asarray(index)
        return DwellSet(
            self.readings[i],
            self.output[i],
            self.sigma[i],
            self.gravity,
            self.time[i],
            self.time_since_command[i],
            self.temperature[i],
            self.slew_direction[i],
            tuple(np.asarray(self.labels, dtype=object)[i]),
            self.base_attitude,
            self.configuration,
            dict(self.noise),
            None,
            None if self.slow_covariance is None else self.slow_covariance[:, i][:, :, i],
            None if self.reading_slope is None else self.reading_slope[i],
            None if self.reading_slope_sigma is None else self.reading_slope_sigma[i],
            self.dwell_mode,
            self.latitude,
            None if self.reading_centre is None else self.reading_centre[i],
        )


def dwells_from_dataset(
    datasets: Sequence,
    *,
    layouts: Mapping[str, StageLayout],
    stage: str | None = None,
    initial_readings: tuple[float, float, float] | None = (0.0, 0.0, 0.0),
    noise: NoiseModel | None = None,
    summaries: Sequence[Sequence[DwellSummary]] | None = None,
) -> DwellSet:
    """Dwell means of device datasets (``stableins.data.device.DeviceDataset``) for discovery.

    ``layouts`` (``{"coarse": ..., "fine": ...}``, e.g. :func:`stableins.procedures.definition.device_layouts`)
    give each position's settle time and the dwell checks.  The mean, its 1σ and the acceptance checks come from the device stage's dwell
    statistics (:func:`stableins.estimators.dwell.dwells_from_columns`: settling dropped,
    correlated noise detected per dwell); flagged dwells are left out (listed in
    ``noise["left_out"]``).  ``stage`` defaults to ``"fine"`` when fine dwells are present,
    else ``"coarse"`` (all passes, in time order).  ``noise``
    (:class:`stableins.noise.NoiseModel`, e.g. the calibration record's) adds the covariance
    of slow bias wander between dwells exactly as the device stages do
    (:func:`stableins.estimators.dwell.slow_covariance`); None measures it from the dwells as
    ``stableins calibrate device`` does (:func:`stableins.estimators.device.noise_from_dwells`).

    The hysteresis state of each dwell (``slew_direction``) follows every position the platform visited from
    ``initial_readings`` on: the dwells the checks leave out, and those of an earlier stage in the data (give the
    coarse file with the fine one: a fine stage starts in the state the coarse stage left).  Files whose clocks
    overlap are separate sessions, each starting at ``initial_readings``.

    ``summaries``, one sequence per dataset, are the dwell statistics
    :func:`~stableins.estimators.dwell.dwells_from_columns` makes of that dataset's columns with ``layouts`` and the
    dataset's setting, when the caller has them already (a campaign's task has them from its calibration): the same
    numbers, not computed again.  None: computed here.
    """
    from stableins.errors import InputError
    from stableins.estimators.dwell import dwells_from_columns
    from stableins.estimators.setting import DeviceSetting

    if not datasets:
        raise InputError("no data files given", field="DATA")
    site = datasets[0].metadata
    # the device stage's one path from samples to dwell statistics, per file; paired with the raw dwells by
    # (file, stage, pass, position), which a file holds once each (dwells_from_columns refuses repeats)
    if summaries is not None and len(summaries) != len(datasets):
        raise ValueError(f"dwells_from_dataset: {len(summaries)} lists of dwell summaries for {len(datasets)} datasets")
    pairs = []
    for k, ds in enumerate(datasets):
        made = (
            summaries[k]
            if summaries is not None
            else dwells_from_columns(ds.columns, layouts=layouts, source=str(ds.path), setting=DeviceSetting.from_site(ds.metadata))
        )
        statistics = {(s.stage, s.pass_number, s.position): s for s in made}
        pairs += [(d, statistics[(d.stage, d.pass_number, d.position)]) for d in ds.dwells()]
    if stage is None:
        stage = "fine" if any(d.stage == "fine" for d, _ in pairs) else "coarse"
    pairs = sorted(pairs, key=lambda pair: _start_time(pair[0]))
    ours = [p for p in pairs if p[0].stage == stage]
    if not ours:
        raise InputError(f"no {stage}-stage dwells in the data", field="stage", expected="rows with stage 'coarse' or 'fine'")
    first, last = _start_time(ours[0][0]), _start_time(ours[-1][0])
    if any(first <= _start_time(d) <= last for d, _ in pairs if d.stage != stage):
        pairs = ours  # the other stage's clock overlaps this one's: separate sessions, each starting afresh
    visited = _visited_states(pairs, site, initial_readings)  # every dwell the platform visited, left-out ones included
    pairs, visited = ours, [v for p, v in zip(pairs, visited, strict=True) if p[0].stage == stage]
    raw = [d for d, _ in pairs]
    stats = [s for _, s in pairs]
    keep = [k for k, sm in enumerate(stats) if sm.usable]
    left_out = [
        f"{stage} pass {stats[k].pass_number} position {stats[k].position}: {'; '.join(stats[k].flags)}"
        for k in range(len(raw))
        if k not in keep
    ]
    if len(keep) < 6:
        raise InputError(f"only {len(keep)} usable {stage} dwells", field="position", expected="at least 6 usable dwells")
    extras = []
    for k in keep:
        d = raw[k]
        layout = layouts.get(stage)
        settle = layout.settle(d.position) if layout is not None and d.position in layout.positions else 0.0
        use = np.asarray(d.time_since_command) >= settle
        extras.append(
            (
                np.asarray(d.time)[use],
                np.asarray(d.time_since_command)[use],
                np.asarray(d.temperature)[use] - site.reference_temperature,
                np.asarray(d.angles)[use],
            )
        )
    return _dwell_set(
        [stats[k] for k in keep],
        extras,
        site=site,
        labels=tuple(f"{stage[0]}{stats[k].pass_number}/{stats[k].position}" for k in keep),
        initial_readings=initial_readings,
        noise=noise,
        info={"left_out": left_out, "stage": stage},
        states=np.array([visited[k] for k in keep]),
    )


def _start_time(dwell) -> float:
    return float(dwell.time[0]) if len(dwell.time) else 0.0


def _visited_states(pairs: Sequence, site: SiteMetadata, initial_readings: tuple[float, float, float] | None) -> list[NDArray[np.float64]]:
    """Hysteresis state at each raw dwell of ``pairs`` (time order, every stage): the platform's whole visit history.

    The truth simulator's state carries over every command of the session (:func:`stableins.simulator.effects.hysteresis_state`):
    a fine stage starts in the state the coarse stage left, and a dwell the checks leave out was visited all the same.
    """
    from stableins.platform import platform_specific_force

    s1, s2, s3, s4 = site.gimbal_senses
    configuration = GimbalConfiguration((s1, s2, s3, s4))
    yaw, pitch, roll = site.base_attitude
    attitude = (yaw, pitch, roll)
    readings = []
    for d, summary in pairs:
        angles = np.asarray(d.angles, dtype=float).reshape(-1, 3)
        readings.append(angles.mean(axis=0) if len(angles) else np.asarray(summary.angles, dtype=float))
    f = platform_specific_force(np.array(readings), site.gravity, base_attitude=attitude, configuration=configuration)
    start = None if initial_readings is None else _initial(initial_readings, site.gravity, attitude, configuration)
    return list(slew_directions(f, start))


def _dwell_set(summaries, extras, *, site: SiteMetadata, labels, initial_readings, noise, info, states=None) -> DwellSet:
    """Return a :class:`DwellSet` from the device stage's dwell summaries (the one dwell-mean uncertainty) and per-dwell raw extras.

    ``extras``: per dwell ``(time, time_since_command, temperature − reference, angles)`` of the
    samples used.  ``site`` gives gravity, base attitude and gimbal senses.  ``noise`` None: measured
    from the dwells as the device stage does.
    """
    from stableins.estimators.device import noise_from_dwells
    from stableins.estimators.dwell import slow_covariance
    from stableins.estimators.gyro_sensitivity import ReadingSlopes
    from stableins.platform import platform_specific_force

    gravity = site.gravity
    yaw, pitch, roll = site.base_attitude
    base_attitude = (yaw, pitch, roll)
    s1, s2, s3, s4 = site.gimbal_senses
    configuration = GimbalConfiguration((s1, s2, s3, s4))
    if noise is None:
        noise = noise_from_dwells(summaries)
    lines = ReadingSlopes.of([(t, angles) for t, _, _, angles in extras])
    readings = np.array([x.angles for x in summaries])
    start = None if initial_readings is None else _initial(initial_readings, gravity, base_attitude, configuration)
    nominal = platform_specific_force(readings, gravity, base_attitude=base_attitude, configuration=configuration)
    return DwellSet(
        readings=readings,
        output=np.array([x.mean for x in summaries]),
        sigma=np.array([x.sem for x in summaries]),
        gravity=float(gravity),
        time=np.array([float(np.mean(t)) for t, *_ in extras]),
        time_since_command=np.array([float(np.mean(tc)) for _, tc, _, _ in extras]),
        temperature=np.array([float(np.mean(temp)) for _, _, temp, _ in extras]),
        slew_direction=slew_directions(nominal, start) if states is None else np.asarray(states, dtype=float).reshape(-1, 3),
        labels=tuple(labels),
        base_attitude=base_attitude,
        configuration=configuration,
        noise={
            "method": "dwell statistics of the device stage (white noise within each dwell, block means where correlated)",
            "slow_noise": noise.describe(),
            "model": noise,
            **info,
        },
        initial_readings=initial_readings,
        slow_covariance=slow_covariance(summaries, noise),
        reading_slope=lines.slope,
        reading_slope_sigma=lines.sigma(),
        dwell_mode=site.dwell_mode,
        latitude=float(site.latitude),
        reading_centre=lines.centre,
    )


def slew_directions(
    specific_force_platform: ArrayLike,
    initial: ArrayLike | None = None,
    tolerance: float = HYSTERESIS_THRESHOLD,
    *,
    state: ArrayLike | None = None,
) -> NDArray[np.float64]:
    """Hysteresis state of each axis: sign of the last slew that moved its input by more than ``tolerance``.

    A slew that changes an axis' input by less than ``tolerance`` [m/s²] leaves its state
    as it was (the input did not travel; nothing reverses the hysteresis loop).  This
    makes the state independent of arcsecond-level geometry such as the unobservable
    zero offset ``θ10``.  ``initial`` is ``f^p`` at the initial readings, before the first
    command: the first slew's change is measured from it; ``state`` is the state there (default 0:
    no slew has moved the input yet; the truth simulator starts so,
    :func:`stableins.simulator.effects.hysteresis_state`).  With ``initial=None`` the first dwell
    sets no state.  The recursion is the simulator's: ``h⁺ = sign(Δf)`` where ``|Δf| > tolerance``, else ``h``.
    """
    f = np.asarray(specific_force_platform, dtype=float)
    before = f[:1] if initial is None else np.asarray(initial, dtype=float).reshape(1, 3)
    d = np.diff(f, axis=0, prepend=before)
    out = np.zeros_like(f)
    current = np.zeros(f.shape[1:]) if state is None else np.asarray(state, dtype=float).reshape(f.shape[1:])
    for k in range(f.shape[0]):
        moved = np.abs(d[k]) > tolerance
        current = np.where(moved, np.sign(d[k]), current)
        out[k] = current
    return out


def dwell_means(
    samples: SampleBlock,
    position: ArrayLike,
    time_since_command: ArrayLike,
    *,
    site: SiteMetadata,
    labels: Sequence[str] | None = None,
    initial_readings: tuple[float, float, float] | None = (0.0, 0.0, 0.0),
    noise: NoiseModel | None = None,
) -> DwellSet:
    """Reduce samples (one dwell per distinct ``position``, in order of appearance) to dwell means.

    ``samples`` holds time [s], accelerometer outputs [m/s²], angle readings [rad] and temperature [°C];
    ``site`` gives gravity, reference temperature, base attitude and gimbal senses.

    Each dwell's mean and 1σ come from the device stage's dwell statistics
    (:func:`stableins.estimators.dwell.summarize_dwell`: white noise from the sample
    scatter, block means where the noise is correlated within the dwell), and slow noise
    correlated between dwells from ``noise`` (:class:`stableins.noise.NoiseModel`; None:
    measured from the dwells as ``stableins calibrate device`` does).  Platform pointing
    enters through the measured angle readings.  A dwell too short to measure its noise, or
    with non-finite samples, raises ``ValueError``.
    """
    from stableins.estimators.dwell import summarize_dwell

    t = np.asarray(samples.time, dtype=float)
    f = np.asarray(samples.specific_force, dtype=float).reshape(-1, 3)
    r = np.asarray(samples.angles, dtype=float).reshape(-1, 3)
    temp = np.asarray(samples.temperature, dtype=float)
    pos = np.asarray(position)
    since = np.asarray(time_since_command, dtype=float)
    order = list(dict.fromkeys(pos.tolist()))
    summaries, extras = [], []
    for k, p in enumerate(order):
        sel = pos == p
        summary = summarize_dwell(t[sel], f[sel], r[sel], r[sel].mean(axis=0), position=k + 1, stage="dwells")
        fatal = [x for x in summary.flags if x.startswith(("too short", "non-finite", "no samples"))]
        if fatal:  # the other checks (clipping, slews ...) are the acquisition's; the caller's samples are taken as they are
            raise ValueError(f"position {p}: {'; '.join(fatal)}")
        summaries.append(summary)
        extras.append((t[sel], since[sel], temp[sel] - site.reference_temperature, r[sel]))
    return _dwell_set(
        summaries,
        extras,
        site=site,
        labels=tuple(labels) if labels is not None else tuple(f"pos {p}" for p in order),
        initial_readings=initial_readings,
        noise=noise,
        info={},
    )


def _initial(readings, gravity, base_attitude, configuration, offsets=(0.0, 0.0, 0.0)) -> NDArray[np.float64]:
    from stableins.platform import platform_specific_force

    return platform_specific_force(
        np.asarray(readings, dtype=float), gravity, zero_offsets=offsets, base_attitude=base_attitude, configuration=configuration
    )
