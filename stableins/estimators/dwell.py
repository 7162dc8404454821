r"""Dwell statistics: the mean output of one static position and the noise of that mean.

Every device-level observation is the mean accelerometer output of a dwell.  Its 1σ
comes from the data of the same dwell, honestly for correlated noise:

* white-noise estimate ``σ_w = s / √n`` (``s`` the sample standard deviation);
* block-mean estimate ``σ_B = std(block means) / √B`` over ``B`` equal blocks, which
  also sees noise correlated on time scales up to the block length (flicker, bias
  instability; it is the Allan deviation at ``τ = T/B`` divided by ``√B`` for a
  constant signal).

With the unit's setting (gravity, surveyed base attitude, gimbal senses) the part of the outputs that the measured
turn of the platform within the dwell explains is taken out of the samples before their scatter is measured
(:func:`turn_explained_outputs`): a platform held by its gyros turns steadily (0.05 °/h moves a reading 30″ in 600 s,
``g·30″ ≈ 145 µg`` on the outputs), a ramp that is no noise.  The mean is that of the outputs as recorded.

Under white noise ``(σ_B/σ_w)² ~ χ²_{B−1}/(B−1)``.  When the ratio exceeds its 99.9 %
quantile the noise is correlated and ``σ_B`` is used (the dwell gets a note);
otherwise the more precise ``σ_w`` (``n − 1`` degrees of freedom instead of ``B − 1``).

Checks (:class:`~stableins.estimators.layout.DwellChecks`, from the procedure's ``[acceptance]`` table)
flag a dwell and leave it out: too few samples to measure noise, clipped or saturated samples, a slew inside
the dwell (angle readings depart from a steady trend: a steady gyro drift is not a slew), non-finite values.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stableins.conventions import ARCSEC
from stableins.errors import InputError
from stableins.estimators.layout import DwellChecks, StageLayout
from stableins.estimators.setting import DeviceSetting
from stableins.noise import NoiseModel
from stableins.platform import platform_specific_force

#: The checks of a dwell when none are given (the defaults of docs/procedures.md).
_DEFAULT_CHECKS = DwellChecks()


@dataclass(frozen=True)
class DwellSummary:
    """Statistics of one dwell.

    Attributes
    ----------
    position : int
        Position number in the procedure.
    stage : str
        ``"coarse"`` or ``"fine"``.
    pass_number : int
        Coarse pass (1, 2, ...) or 1 for the fine stage.
    command : ndarray (3,)
        Commanded angle-sensor readings (platform, inner, middle) [rad].
    angles : ndarray (3,)
        Mean measured angle-sensor readings [rad].
    mean : ndarray (3,)
        Mean accelerometer output [m/s²].
    sem : ndarray (3,)
        1σ of ``mean`` [m/s²] (see module docstring).
    noise : ndarray (3,)
        Sample standard deviation [m/s²].
    samples : int
    duration : float
        Time spanned by the samples used [s].
    flags : tuple of str
        Why the dwell must be left out (empty when usable).
    notes : tuple of str
        Remarks that do not exclude the dwell (e.g. correlated noise).
    white_sem : ndarray (3,) or None
        The white-noise 1σ of the mean before the noise floor is applied.
    allan_ratios : ndarray (k, 3) or None
        Overlapping Allan variance over its white-noise value, ``σ̂²_A(m) m / s²``, at the
        cluster sizes of :func:`stableins.estimators.slow_noise.dwell_test_clusters` (the slow-noise
        decision, :func:`stableins.estimators.slow_noise.slow_noise_test`).
    start : float
        Time of the first sample used [s].
    """

    position: int
    stage: str
    pass_number: int
    command: NDArray[np.float64]
    angles: NDArray[np.float64]
    mean: NDArray[np.float64]
    sem: NDArray[np.float64]
    noise: NDArray[np.float64]
    samples: int
    duration: float
    flags: tuple[str, ...] = ()
    notes: tuple[str, ...] = field(default=())
    white_sem: NDArray[np.float64] | None = field(default=None, repr=False)
    allan_ratios: NDArray[np.float64] | None = field(default=None, repr=False)
    start: float = float("nan")

    @property
    def usable(self) -> bool:
        """Whether the dwell passed every check (no flags)."""
        return not self.flags

    @property
    def rate(self) -> float:
        """Sample rate [Hz] of the samples used."""
        return (self.samples - 1) / self.duration if self.duration > 0 else float("nan")


def _clipped(x: NDArray[np.float64], full_scale: float = np.inf) -> bool:
    """Return whether the samples rail: at least 3 at an extreme value within one quantization step of the range.

    Clipping is read from the converter's range only (``full_scale``, the procedure's ``saturation``,
    or the range a raw log declares, :mod:`stableins.data.rawlog`), never from the shape of the
    histogram: a healthy dwell of coarse integer counts takes a few values whose counts need not thin
    out outwards (issue 26: real dwells 400–1300 counts from zero on a 16-bit converter were taken for
    rails).  Without a finite range nothing is taken as clipped.
    """
    if not np.isfinite(full_scale):
        return False
    finite = x[np.isfinite(x)]
    if finite.size == 0:
        return False
    low, high = float(finite.min()), float(finite.max())
    if max(abs(low), abs(high)) < full_scale - (high - low):
        # the step between levels is at most the range (rounding is monotone), so no extreme is within a step of
        # the converter's range: the answer without sorting the samples (issue 30: 3 sorts per dwell)
        return False
    levels, counts = np.unique(finite, return_counts=True)
    step = float(np.min(np.diff(levels))) if levels.size > 1 else 0.0
    return any(count >= 3 and abs(extreme) >= full_scale - step for extreme, count in ((levels[-1], counts[-1]), (levels[0], counts[0])))


def steady_trend_departure(time: ArrayLike, angles: ArrayLike) -> NDArray[np.float64]:
    """Return the peak-to-peak residual of each angle reading about its least-squares line [rad] (3,).

    A platform held by its gyros turns steadily within a dwell (a gyro drift of 0.05 °/h moves a reading 30″ in
    600 s; docs/conventions.md, "The platform during a dwell"): the dwell is still usable, and its slope is what the
    gyro stage measures.  A slew inside the dwell is not a steady trend, so the check is on what a line does not
    explain, not on the range.
    """
    t = np.asarray(time, dtype=float)
    a = np.asarray(angles, dtype=float).reshape(t.size, -1)
    if t.size < 3:
        return np.ptp(a, axis=0) if t.size else np.zeros(a.shape[1])
    x = t - t.mean()
    sxx = float(x @ x)
    slope = x @ (a - a.mean(axis=0)) / sxx if sxx > 0 else np.zeros(a.shape[1])
    return np.asarray(np.ptp(a - np.outer(x, slope), axis=0), dtype=np.float64)


def turn_explained_outputs(angles: ArrayLike, setting: DeviceSetting) -> NDArray[np.float64]:
    r"""Return the change of the outputs that the measured turn of the platform within a dwell explains [m/s²] (n, 3).

    .. math:: \Delta y(t) = f^p(r(t)) - \overline{f^p(r)}

    with ``f^p(r)`` the exact static specific force at the readings ``r`` (:func:`stableins.platform.platform_specific_force`:
    the gimbal chain under the surveyed base attitude, docs/conventions.md) and the bar the mean over the dwell, so the
    dwell mean is unchanged.  The instrument's own errors (scale factors, installation angles, zero offsets: ~1e-4
    relative) are left out: they change ``Δy`` by 1e-4 of itself, 0.015 µg for the 30″ a 0.05 °/h gyro drift turns the
    platform in 600 s.  The angle sensors' white noise (0.2″ per sample) enters as ``g·0.2″ ≈ 1 µg`` per sample against
    the outputs' ~100 µg: its share of the scatter is 1e-4.
    """
    a = np.asarray(angles, dtype=float).reshape(-1, 3)
    if a.shape[0] == 0:
        return np.zeros((0, 3))
    f_p = platform_specific_force(a, setting.gravity, base_attitude=setting.base_attitude, configuration=setting.configuration)
    return np.asarray(f_p - f_p.mean(axis=0), dtype=np.float64)


def _dwell_flags(f: NDArray[np.float64], a: NDArray[np.float64], checks: DwellChecks) -> list[str]:
    """Why a dwell must be left out whatever its clock: non-finite, too few or saturated/clipped samples (module docstring)."""
    n = f.shape[0]
    flags: list[str] = []
    if not (np.all(np.isfinite(f)) and np.all(np.isfinite(a))):
        flags.append("non-finite samples (NaN or inf)")
    if n < max(checks.min_samples, 2 * checks.noise_blocks):
        flags.append(f"too short to measure noise: {n} samples (need at least {max(checks.min_samples, 2 * checks.noise_blocks)})")
    if np.any(np.abs(f) >= checks.saturation):
        flags.append(f"saturated samples: |f| reaches {np.nanmax(np.abs(f)):.4g} m/s^2 (limit {checks.saturation:.4g})")
    elif n >= checks.min_samples and any(_clipped(f[:, i], checks.saturation) for i in range(3)):
        axes = [ax for i, ax in enumerate("xyz") if _clipped(f[:, i], checks.saturation)]
        flags.append(f"clipped samples on axis {', '.join(axes)}: output pinned at its extreme value")
    return flags


def _slew_flags(t: NDArray[np.float64], a: NDArray[np.float64], checks: DwellChecks) -> list[str]:
    """Return the flag of a slew inside the dwell: an angle reading departs from a steady trend in time (module docstring)."""
    span = steady_trend_departure(t, a)
    if np.any(span > checks.max_angle_span):
        gimbal = ("platform", "inner", "middle")[int(np.argmax(span))]
        return [
            f"slew inside the dwell: {gimbal} angle reading departs from a steady trend by {span.max() / ARCSEC:.1f} arcsec "
            f"peak to peak (limit {checks.max_angle_span / ARCSEC:.1f})"
        ]
    return []


@dataclass(frozen=True)
class _Scatter:
    """What a dwell's samples say of their noise, whatever their clock: mean, scatter, 1σ of the mean, the noise samples."""

    mean: NDArray[np.float64]
    noise: NDArray[np.float64]
    sem: NDArray[np.float64]  # before the noise floor
    notes: tuple[str, ...]
    samples: NDArray[np.float64]  # the outputs less the measured turn's share (the Allan ratios' input)


def _scatter(
    f: NDArray[np.float64], a: NDArray[np.float64], *, usable: bool, checks: DwellChecks, setting: DeviceSetting | None
) -> _Scatter:
    """Mean, scatter and honest 1σ of a dwell's outputs (module docstring); the measured turn taken out when ``usable``."""
    from stableins.estimators.distributions import chi2_ppf

    n = f.shape[0]
    notes: list[str] = []
    with np.errstate(invalid="ignore"):
        mean = f.mean(axis=0)
        if setting is not None and usable:
            f = f - turn_explained_outputs(a, setting)  # the scatter about the measured turn (the mean is unchanged)
        noise = f.std(axis=0, ddof=1) if n > 1 else np.full(3, np.nan)
    sem = noise / np.sqrt(n)
    if n >= 2 * checks.noise_blocks:
        b = checks.noise_blocks
        m = n // b
        block_means = f[: m * b].reshape(b, m, 3).mean(axis=1)
        sem_block = block_means.std(axis=0, ddof=1) / np.sqrt(b)
        with np.errstate(invalid="ignore", divide="ignore"):
            ratio = (sem_block / np.maximum(sem, checks.noise_floor)) ** 2
        limit = chi2_ppf(checks.correlation_quantile, b - 1) / (b - 1)
        if np.any(ratio > limit):
            notes.append(f"correlated noise (block/white variance ratio {np.nanmax(ratio):.1f} > {limit:.2f}): 1σ from {b} block means")
            sem = np.where(ratio > limit, sem_block, sem)
    return _Scatter(mean, noise, sem, tuple(notes), f)


def summarize_dwell(
    time: ArrayLike,
    specific_force: ArrayLike,
    angles: ArrayLike,
    command: ArrayLike,
    *,
    position: int,
    stage: str = "coarse",
    pass_number: int = 1,
    checks: DwellChecks = _DEFAULT_CHECKS,
    setting: DeviceSetting | None = None,
) -> DwellSummary:
    """Mean, its honest 1σ and acceptance flags of one dwell (samples after settling).

    Parameters
    ----------
    time : array_like (n,)
        Sample times [s].
    specific_force : array_like (n, 3)
        Accelerometer outputs [m/s²].
    angles : array_like (n, 3)
        Angle-sensor readings [rad].
    command : array_like (3,)
        Commanded readings [rad].
    setting : DeviceSetting, optional
        Where the unit stands (gravity, base attitude, gimbal senses): the outputs' change that the measured turn
        explains (:func:`turn_explained_outputs`) is taken out before the noise (standard deviation, block means,
        Allan ratios) is measured.  None: the samples as recorded.
    """
    times = [np.asarray(time, dtype=float)]
    return _summaries_on_clocks(
        times, specific_force, angles, command, position=position, stage=stage, pass_number=pass_number, checks=checks, setting=setting
    )[0]


def _summaries_on_clocks(
    times: Sequence[NDArray[np.float64]],
    specific_force: ArrayLike,
    angles: ArrayLike,
    command: ArrayLike,
    *,
    position: int,
    stage: str,
    pass_number: int,
    checks: DwellChecks,
    setting: DeviceSetting | None,
) -> list[DwellSummary]:
    """:func:`summarize_dwell` of the same samples on several clocks ``times``, the clock-free statistics made once.

    A clock enters the slew check (a steady trend in time), the duration, the Allan ratios (at the rate it gives) and
    the start time; the flags of the samples, their mean, scatter, block means and measured turn do not depend on it.
    """
    f = np.asarray(specific_force, dtype=float).reshape(-1, 3)
    a = np.asarray(angles, dtype=float).reshape(-1, 3)
    n = f.shape[0]
    nan3 = np.full(3, np.nan)
    if n == 0:
        empty = DwellSummary(
            position, stage, pass_number, np.asarray(command, float), nan3, nan3, nan3, nan3, 0, 0.0, ("no samples after settling",)
        )
        return [empty for _ in times]
    samples_flags = _dwell_flags(f, a, checks)
    scatter: dict[bool, _Scatter] = {}
    out = []
    for t in times:
        duration = float(t[-1] - t[0]) if n > 1 else 0.0
        flags = samples_flags + _slew_flags(t, a, checks)
        usable = not flags
        if usable not in scatter:
            scatter[usable] = _scatter(f, a, usable=usable, checks=checks, setting=setting)
        made = scatter[usable]
        ratios = None
        if usable and duration > 0:
            # Allan variance over its white-noise value at n/4 ... n/32: the slow-noise decision of the stage
            from stableins.estimators.slow_noise import dwell_allan_ratios

            ratios = dwell_allan_ratios(made.samples, (n - 1) / duration)[1]
        out.append(
            DwellSummary(
                position,
                stage,
                pass_number,
                np.asarray(command, dtype=float),
                a.mean(axis=0),
                made.mean.copy(),
                np.maximum(made.sem, checks.noise_floor),
                made.noise.copy(),
                n,
                duration,
                tuple(flags),
                made.notes,
                made.sem.copy(),
                ratios,
                float(t[0]),
            )
        )
    return out


def slow_covariance(dwells: Sequence[DwellSummary], noise: NoiseModel | None, source: str = "data") -> NDArray[np.float64] | None:
    """Covariance of the dwell means beyond their measured white noise, per axis ``(3, m, m)``, or None.

    ``R_a = diag(sem_a²) + slow_covariance[a]`` is
    :meth:`stableins.noise.NoiseModel.dwell_mean_covariance` with the white part measured in
    each dwell (``sem``): the one implementation of the uncertainty of a dwell mean, used by
    the coarse, fine and joint fits and by model discovery.  None when the model has no slow
    noise and no quantization (diagonal observations).
    """
    if noise is None or not (noise.has_slow_noise or np.any(noise.values("quantization") > 0)):
        return None
    starts = np.array([d.start for d in dwells], dtype=float)
    if not np.all(np.isfinite(starts)):
        raise InputError("dwell start times are needed for the slow-noise covariance", path=source, field="time")
    return noise.dwell_mean_covariance(starts, [d.duration for d in dwells], np.zeros((len(dwells), 3)))


def dwells_from_columns(
    columns: Mapping[str, ArrayLike],
    *,
    settle: float = 0.0,
    checks: DwellChecks = _DEFAULT_CHECKS,
    layouts: Mapping[str, StageLayout] | None = None,
    source: str = "data",
    setting: DeviceSetting | None = None,
) -> list[DwellSummary]:
    """Split device-level samples (``DEVICE_COLUMNS`` names) into dwells and summarize them.

    Samples with ``time_since_command < settle`` are dropped (settling).  With
    ``layouts`` (``{stage: StageLayout}``, e.g. a procedure's ``layout``), the settle time of each
    position and the stage's dwell checks are used instead of ``settle`` and ``checks``
    (a position the layout does not define keeps ``settle``/``checks``; the stage
    rejects it later).  A position that appears twice within one stage and pass, or is
    commanded twice (``time_since_command`` restarts), raises :class:`InputError`.
    This is the one path from samples to dwell summaries (CLI, tests, benchmarks).  With ``setting`` (the unit's
    :class:`~stableins.estimators.setting.DeviceSetting`, e.g. ``DeviceSetting.from_site(dataset.metadata)``) the
    outputs' change that the measured turn within each dwell explains is left out of its noise (:func:`summarize_dwell`).
    """
    return dwells_on_clocks(columns, (0.0,), settle=settle, checks=checks, layouts=layouts, source=source, setting=setting)[0]


def _dwell_keys(
    stage: NDArray[np.str_], pass_: NDArray[np.int64], position: NDArray[np.int64], source: str
) -> tuple[list[tuple[str, int, int]], NDArray[np.int64]]:
    """Return the (stage, pass, position) of each run of rows and the run's first row; a key run twice raises InputError."""
    keys = np.rec.fromarrays([stage, pass_, position])
    order: list[tuple[str, int, int]] = []
    seen: set[tuple[str, int, int]] = set()
    starts = np.flatnonzero(np.r_[True, (stage[1:] != stage[:-1]) | (pass_[1:] != pass_[:-1]) | (position[1:] != position[:-1])])
    for s in starts:
        key = (str(keys[s][0]), int(keys[s][1]), int(keys[s][2]))
        if key in seen:
            raise InputError(
                f"position {key[2]} appears twice in {key[0]} pass {key[1]}",
                path=source,
                field="position",
                row=int(s) + 1,
                expected="each position once per stage and pass",
            )
        seen.add(key)
        order.append(key)
    return order, starts


def dwells_on_clocks(
    columns: Mapping[str, ArrayLike],
    offsets: Sequence[float],
    *,
    settle: float = 0.0,
    checks: DwellChecks = _DEFAULT_CHECKS,
    layouts: Mapping[str, StageLayout] | None = None,
    source: str = "data",
    setting: DeviceSetting | None = None,
) -> list[list[DwellSummary]]:
    """Return :func:`dwells_from_columns` of ``columns`` with their time moved by each of ``offsets`` [s].

    The summaries are those that :func:`dwells_from_columns` makes of the moved columns (``time + offset``), to the bit;
    what does not depend on the clock (the flags of the samples, their mean, scatter, block means and measured turn) is
    made once for all the offsets (issue 30: a campaign task's discovery sees its stages on one session clock).

    The other parameters are those of :func:`dwells_from_columns`; one list of summaries per offset.
    """
    required = ("stage", "pass", "position", "time", "time_since_command", "f_x", "f_y", "f_z")
    for name in required:
        if name not in columns:
            raise InputError("device data lack a column", path=source, field=name, expected="the device-level columns of docs/formats.md")
    stage = np.asarray(columns["stage"]).astype(str)
    pass_ = np.asarray(columns["pass"]).astype(int)
    position = np.asarray(columns["position"]).astype(int)
    time = np.asarray(columns["time"], dtype=float)
    since = np.asarray(columns["time_since_command"], dtype=float)
    f = np.stack([np.asarray(columns[k], dtype=float) for k in ("f_x", "f_y", "f_z")], axis=-1)

    def three(prefix: str) -> NDArray[np.float64]:
        names = [f"{prefix}_{g}" for g in ("platform", "inner", "middle")]
        if all(k in columns for k in names):
            return np.stack([np.asarray(columns[k], dtype=float) for k in names], axis=-1)
        raise InputError("device data lack angle columns", path=source, field=names[0], expected=", ".join(names))

    angles = three("angle")
    commands = three("command")
    order, starts = _dwell_keys(stage, pass_, position, source)
    clocks = [time if offset == 0.0 else time + offset for offset in offsets]
    out: list[list[DwellSummary]] = [[] for _ in offsets]
    ends = np.r_[starts[1:], stage.size]
    for key, first, end in zip(order, starts, ends, strict=True):
        rows = np.arange(first, end)  # a key is one run of rows: a second run of it raised above
        if np.any(np.diff(since[rows]) < 0):
            raise InputError(
                f"position {key[2]} was commanded twice in {key[0]} pass {key[1]} (time_since_command restarts)",
                path=source,
                field="time_since_command",
                row=int(rows[0]) + 1,
                expected="each position once per stage and pass",
            )
        step_settle, step_checks = settle, checks
        layout = (layouts or {}).get(key[0])
        if layout is not None and key[2] in layout.positions:
            step_settle, step_checks = layout.settle(key[2]), layout.checks
        use = rows[since[rows] >= step_settle]
        made = _summaries_on_clocks(
            [clock[use] for clock in clocks],
            f[use],
            angles[use],
            commands[rows[0]],
            position=key[2],
            stage=key[0],
            pass_number=key[1],
            checks=step_checks,
            setting=setting,
        )
        for per_clock, summary in zip(out, made, strict=True):
            per_clock.append(summary)
    return out


def screen_dwells(
    dwells: Sequence[DwellSummary],
    expected_positions: Sequence[int] | None = None,
    *,
    allow_missing: bool = False,
    source: str = "data",
    stage: str = "",
) -> tuple[list[DwellSummary], dict[int, str], list[str]]:
    """Screen the dwells of one stage and pass against the procedure (shared by the coarse and fine stages).

    Raises :class:`InputError` for a position that appears twice, a position that is not
    in ``expected_positions``, and (unless ``allow_missing``) a missing position.

    Returns
    -------
    usable : list of DwellSummary
        Unflagged dwells, sorted by position.
    left_out : dict
        ``{position: reason}`` of missing and flagged positions.
    notes : list of str
        Dwell notes (e.g. correlated noise) prefixed with their position.
    """
    label = f"{stage}-stage " if stage else ""
    positions = [d.position for d in dwells]
    duplicates = sorted({p for p in positions if positions.count(p) > 1})
    if duplicates:
        raise InputError(f"{label}positions {duplicates} appear more than once in one pass", path=source, field="position")
    left_out: dict[int, str] = {}
    if expected_positions is not None:
        missing = sorted(set(expected_positions) - set(positions))
        extra = sorted(set(positions) - set(expected_positions))
        if extra:
            raise InputError(
                f"{label}positions {extra} are not in the procedure",
                path=source,
                field="position",
                expected=f"{sorted(expected_positions)}",
            )
        if missing and not allow_missing:
            raise InputError(
                f"{label}positions {missing} are missing (the procedure stopped early or rows were lost)",
                path=source,
                field="position",
                expected=f"all of {sorted(expected_positions)}",
            )
        for p in missing:
            left_out[p] = "missing from the data"
    notes: list[str] = []
    for d in dwells:
        if d.flags:
            left_out[d.position] = "; ".join(d.flags)
        notes += [f"position {d.position}: {n}" for n in d.notes]
    return sorted((d for d in dwells if d.usable), key=lambda d: d.position), left_out, notes


def describe_left_out(left_out: Mapping[int, str]) -> str:
    """Why positions were left out, grouped by reason: ``"saturated samples (positions 1, 2); ..."``.

    Reasons are grouped by their text before the first ``:`` (the numbers after it differ
    from dwell to dwell).
    """
    groups: dict[str, list[int]] = {}
    for position, reason in sorted(left_out.items()):
        for part in reason.split("; "):
            groups.setdefault(part.split(":")[0].strip(), []).append(int(position))
    return "; ".join(f"{reason} (position{'s' if len(p) > 1 else ''} {', '.join(map(str, p))})" for reason, p in groups.items()) or "none"
