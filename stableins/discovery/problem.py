r"""Least-squares problems that model discovery works on.

Discovery needs four things from a fitted stage: the weighted residuals, their 1σ from
noise measured in the data, the design (∂prediction/∂parameter at the estimate) and the
column of any candidate term.  :class:`Problem` is that interface; two implementations:

* :class:`DwellProblem` — device level.  Observations are dwell means of the three
  accelerometer outputs per position; the prediction is the exact forward model
  ``f^a = forward(f^p(readings, θ_0, base), p)`` (Wu et al. 2018 Eq. 6 with the exact gimbal
  kinematics of :mod:`stableins.platform`).  The fit is Gauss–Newton; the
  zero offset ``θ10`` (and anything else in the null space of the design) is held at its
  prior value as an explicit gauge, marked ``"gauge"``.
* :class:`LinearProblem` — any linear(ized) problem given as observations, 1σ, model
  columns and candidate columns (system-level harmonics, user problems).

Both return a frozen :class:`~stableins.estimators.result.FitResult`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stableins.conventions import DEFAULT_GIMBALS, GimbalConfiguration
from stableins.errormodel import AXES, ErrorModel, Term, TermInputs
from stableins.estimators.design import UNDETERMINED_RATIO  # a combination with 1σ above this many typical sizes is a gauge
from stableins.estimators.result import FitResult, Likelihood

if TYPE_CHECKING:  # pragma: no cover
    from stableins.noise import NoiseModel


class Problem(Protocol):
    """What discovery needs from a fitted stage."""

    def fit(self, model: ErrorModel, start: Mapping[str, float] | None = None) -> FitResult: ...

    def design(self, result: FitResult) -> NDArray[np.float64]:
        """``∂prediction/∂p`` at the estimate for the parameters with status ``"estimated"``, shape (m, k)."""
        ...

    def candidate_columns(self, terms: Sequence[Term], result: FitResult) -> NDArray[np.float64]:
        """``∂prediction/∂p`` of terms not in the model (at value 0), shape (m, len(terms))."""
        ...


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
        Sign of the last change of each axis' input (+1 rose, −1 fell, 0 unchanged) from
        the nominal geometry; :class:`DwellProblem` recomputes it from the fitted ``f^p``.
    labels : tuple of str
        Name of each position.
    base_attitude : tuple
        Nominal (yaw, pitch, roll) of the base [rad].
    configuration : GimbalConfiguration
        Gimbal rotation senses.
    noise : dict
        How ``sigma`` was measured (method, per-axis floors ...).
    initial_readings : tuple or None
        Angle-sensor readings before the first command (for the slew into the first
        position); None: unknown, no slew direction for the first position.
    slow_covariance : ndarray (3, P, P), optional
        Covariance of the dwell means beyond their white 1σ, per axis: slow noise (bias
        instability, random walk) correlated between dwells, and quantization
        (:func:`stableins.estimators.dwell.slow_covariance`, the device stages' own).  The fit
        is then generalized least squares with ``R_a = diag(σ_a²) + C_slow,a`` per axis.
    reading_slope, reading_slope_sigma : ndarray (P, 3), optional
        Slope of each angle reading within the dwell [rad/s] and its 1σ: platform drift
        (:mod:`stableins.discovery.drift`).
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
        return self.readings.shape[0]

    def subset(self, index: ArrayLike) -> DwellSet:
        """The dwells at ``index`` (positions to leave out, cross-validation)."""
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
        )


def dwells_from_dataset(
    datasets: Sequence,
    stage: str | None = None,
    procedures: Mapping | None = None,
    initial_readings: tuple[float, float, float] | None = (0.0, 0.0, 0.0),
    noise: NoiseModel | None = None,
) -> DwellSet:
    """Dwell means of device datasets (``stableins.data.device.DeviceDataset``) for discovery.

    The mean, its 1σ and the acceptance checks come from the device stage's dwell
    statistics (:func:`stableins.estimators.dwell.dwells_from_columns`: settling dropped,
    correlated noise detected per dwell); flagged dwells are left out (listed in
    ``noise["left_out"]``).  ``stage`` defaults to ``"fine"`` when fine dwells are present,
    else ``"coarse"`` (all passes, in time order).  ``noise``
    (:class:`stableins.noise.NoiseModel`, e.g. the calibration record's) adds the covariance
    of slow bias wander between dwells exactly as the device stages do
    (:func:`stableins.estimators.dwell.slow_covariance`); None measures it from the dwells as
    ``stableins calibrate device`` does (:func:`stableins.estimators.device.noise_from_dwells`).
    """
    from stableins.data.errors import InputError
    from stableins.estimators.dwell import dwells_from_columns
    from stableins.procedures.definition import load_procedure

    if not datasets:
        raise InputError("no data files given", field="DATA")
    site = datasets[0].metadata
    procedures = dict(procedures) if procedures else {"coarse": load_procedure("device-coarse"), "fine": load_procedure("device-fine")}
    # the device stage's one path from samples to dwell statistics, per file; paired with the raw dwells by
    # (file, stage, pass, position), which a file holds once each (dwells_from_columns refuses repeats)
    pairs = []
    for ds in datasets:
        statistics = {
            (s.stage, s.pass_number, s.position): s for s in dwells_from_columns(ds.columns, procedures=procedures, source=str(ds.path))
        }
        pairs += [(d, statistics[(d.stage, d.pass_number, d.position)]) for d in ds.dwells()]
    if stage is None:
        stage = "fine" if any(d.stage == "fine" for d, _ in pairs) else "coarse"
    pairs = sorted(((d, s) for d, s in pairs if d.stage == stage), key=lambda pair: float(pair[0].time[0]) if len(pair[0].time) else 0.0)
    if not pairs:
        raise InputError(f"no {stage}-stage dwells in the data", field="stage", expected="rows with stage 'coarse' or 'fine'")
    raw = [d for d, _ in pairs]
    summaries = [s for _, s in pairs]
    keep = [k for k, sm in enumerate(summaries) if sm.usable]
    left_out = [
        f"{stage} pass {summaries[k].pass_number} position {summaries[k].position}: {'; '.join(summaries[k].flags)}"
        for k in range(len(raw))
        if k not in keep
    ]
    if len(keep) < 6:
        raise InputError(f"only {len(keep)} usable {stage} dwells", field="position", expected="at least 6 usable dwells")
    extras = []
    for k in keep:
        d = raw[k]
        procedure = procedures.get(stage)
        settle = procedure.step(d.position).settle if procedure is not None and d.position in procedure.positions else 0.0
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
        [summaries[k] for k in keep],
        extras,
        gravity=site.gravity,
        base_attitude=tuple(site.base_attitude),
        configuration=GimbalConfiguration(tuple(site.gimbal_senses)),
        labels=tuple(f"{stage[0]}{summaries[k].pass_number}/{summaries[k].position}" for k in keep),
        initial_readings=initial_readings,
        noise=noise,
        info={"left_out": left_out, "stage": stage},
    )


def _dwell_set(summaries, extras, *, gravity, base_attitude, configuration, labels, initial_readings, noise, info) -> DwellSet:
    """A :class:`DwellSet` from the device stage's dwell summaries (the one dwell-mean uncertainty) and per-dwell raw extras.

    ``extras``: per dwell ``(time, time_since_command, temperature − reference, angles)`` of the
    samples used.  ``noise`` None: measured from the dwells as the device stage does.
    """
    from stableins.discovery.drift import reading_slope
    from stableins.estimators.device import noise_from_dwells
    from stableins.estimators.dwell import slow_covariance
    from stableins.platform import platform_specific_force

    if noise is None:
        noise = noise_from_dwells(summaries)
    slopes, slope_sigma = zip(*(reading_slope(t, angles) for t, _, _, angles in extras), strict=True)
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
        slew_direction=slew_directions(nominal, start),
        labels=tuple(labels),
        base_attitude=tuple(base_attitude),
        configuration=configuration,
        noise={
            "method": "dwell statistics of the device stage (white noise within each dwell, block means where correlated)",
            "slow_noise": noise.describe(),
            "model": noise,
            **info,
        },
        initial_readings=initial_readings,
        slow_covariance=slow_covariance(summaries, noise),
        reading_slope=np.array(slopes),
        reading_slope_sigma=np.array(slope_sigma),
    )


#: Input change [m/s²] a slew must exceed to set an axis' hysteresis state (``Kh_a``); the truth
#: simulator uses the same definition (``stableins.simulator.effects.HYSTERESIS_THRESHOLD``, kept
#: equal by tests/test_discovery_hidden.py).
HYSTERESIS_THRESHOLD = 1e-2


def slew_directions(
    specific_force_platform: ArrayLike, initial: ArrayLike | None = None, tolerance: float = HYSTERESIS_THRESHOLD
) -> NDArray[np.float64]:
    """Hysteresis state of each axis: sign of the last slew that moved its input by more than ``tolerance``.

    A slew that changes an axis' input by less than ``tolerance`` [m/s²] leaves its state
    as it was (the input did not travel; nothing reverses the hysteresis loop).  This
    makes the state independent of arcsecond-level geometry such as the unobservable
    zero offset ``θ10``.  ``initial`` is ``f^p`` at the initial readings, before the first
    command: the first slew's change is measured from it; the state is 0 until a slew moves
    the input beyond ``tolerance`` (with ``initial=None`` the first dwell sets no state).
    """
    f = np.asarray(specific_force_platform, dtype=float)
    before = f[:1] if initial is None else np.asarray(initial, dtype=float).reshape(1, 3)
    d = np.diff(f, axis=0, prepend=before)
    state = np.zeros_like(f)
    current = np.zeros(f.shape[1:])
    for k in range(f.shape[0]):
        moved = np.abs(d[k]) > tolerance
        current = np.where(moved, np.sign(d[k]), current)
        state[k] = current
    return state


def dwell_means(
    time: ArrayLike,
    output: ArrayLike,
    readings: ArrayLike,
    temperature: ArrayLike,
    position: ArrayLike,
    time_since_command: ArrayLike,
    *,
    gravity: float,
    reference_temperature: float = 25.0,
    base_attitude: tuple[float, float, float] = (0.0, 0.0, 0.0),
    configuration: GimbalConfiguration = DEFAULT_GIMBALS,
    labels: Sequence[str] | None = None,
    initial_readings: tuple[float, float, float] | None = (0.0, 0.0, 0.0),
    noise: NoiseModel | None = None,
) -> DwellSet:
    """Reduce samples (one dwell per distinct ``position``, in order of appearance) to dwell means.

    Each dwell's mean and 1σ come from the device stage's dwell statistics
    (:func:`stableins.estimators.dwell.summarize_dwell`: white noise from the sample
    scatter, block means where the noise is correlated within the dwell), and slow noise
    correlated between dwells from ``noise`` (:class:`stableins.noise.NoiseModel`; None:
    measured from the dwells as ``stableins calibrate device`` does).  Platform pointing
    enters through the measured angle readings.  A dwell too short to measure its noise, or
    with non-finite samples, raises ``ValueError``.
    """
    from stableins.estimators.dwell import summarize_dwell

    t = np.asarray(time, dtype=float)
    f = np.asarray(output, dtype=float).reshape(-1, 3)
    r = np.asarray(readings, dtype=float).reshape(-1, 3)
    temp = np.asarray(temperature, dtype=float)
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
        extras.append((t[sel], since[sel], temp[sel] - reference_temperature, r[sel]))
    return _dwell_set(
        summaries,
        extras,
        gravity=gravity,
        base_attitude=tuple(base_attitude),
        configuration=configuration,
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


class DwellProblem:
    """Device-level dwell means under the exact forward model (see module docstring).

    Parameters
    ----------
    dwells : DwellSet
        The observations.
    fixed : mapping, optional
        Parameters held at a given value (status ``"fixed"``), e.g. from a record.
    """

    def __init__(self, dwells: DwellSet, fixed: Mapping[str, float] | None = None, stage: str = "device dwells") -> None:
        self.dwells = dwells
        self.fixed = dict(fixed or {})
        self.stage = stage
        self._inverse_factor = None
        if dwells.slow_covariance is not None:
            c = np.asarray(dwells.slow_covariance, dtype=float)
            self._inverse_factor = np.stack([np.linalg.inv(np.linalg.cholesky(c[a] + np.diag(dwells.sigma[:, a] ** 2))) for a in range(3)])

    @property
    def total_sigma(self) -> NDArray[np.float64]:
        """1σ of each observation (white and slow noise), flattened position-major."""
        d = self.dwells
        variance = d.sigma**2 + (0.0 if d.slow_covariance is None else np.diagonal(d.slow_covariance, axis1=1, axis2=2).T)
        return np.sqrt(variance).reshape(-1)

    def whiten(self, v: ArrayLike) -> NDArray[np.float64]:
        """``R^{-1/2} v`` for observation-ordered vectors (m,) or matrices (m, k): ``L_a^{-1}`` per axis."""
        v = np.asarray(v, dtype=float)
        if self._inverse_factor is None:
            s = self.dwells.sigma.reshape(-1)
            return v / (s if v.ndim == 1 else s[:, None])
        shaped = v.reshape((self.dwells.n_positions, 3) + v.shape[1:])
        out = np.stack([self._inverse_factor[a] @ shaped[:, a] for a in range(3)], axis=1)
        return out.reshape(v.shape)

    # ------------------------------------------------------------------ geometry
    @property
    def labels(self) -> tuple[str, ...]:
        return tuple(f"{p} f_{a}" for p in self.dwells.labels for a in AXES)

    @property
    def position_index(self) -> NDArray[np.int64]:
        return np.repeat(np.arange(self.dwells.n_positions), 3)

    @property
    def axis_index(self) -> NDArray[np.int64]:
        return np.tile(np.arange(3), self.dwells.n_positions)

    def _kinematic_ids(self, terms: Sequence[Term]) -> tuple[str, ...]:
        from stableins.errormodel import GIMBAL_IDS
        from stableins.platform import KINEMATIC_IDS

        return tuple(i for i in GIMBAL_IDS + KINEMATIC_IDS if i in {t.id for t in terms} or i in GIMBAL_IDS)

    def evaluate(self, model: ErrorModel, values: Mapping[str, float], extra_terms: Sequence[Term] = ()) -> tuple:
        """Prediction (P, 3), Jacobian (P, 3, n) over ``model + extra_terms``, ``f^p`` and inputs.

        Zero offsets and kinematic (test-equipment) effects act through the exact kinematics:
        ``f^p`` is computed with their values and their columns are ``(∂f^a/∂f^p)(∂f^p/∂p)``;
        every other term goes through :meth:`ErrorModel.forward` / :meth:`ErrorModel.jacobian`.
        """
        from stableins.errormodel import GIMBAL_IDS
        from stableins.platform import KINEMATIC_IDS, platform_specific_force, specific_force_and_jacobian

        d = self.dwells
        full = ErrorModel(model.terms + tuple(extra_terms)) if extra_terms else model
        offsets = np.array([float(values.get(i, 0.0)) if i in full else 0.0 for i in GIMBAL_IDS])
        effects = {i: float(values.get(i, 0.0)) for i in KINEMATIC_IDS if i in full}
        kin_ids = self._kinematic_ids(full.terms)
        geometry = {"zero_offsets": offsets, "base_attitude": d.base_attitude, "effects": effects, "configuration": d.configuration}
        f_p, d_fp = specific_force_and_jacobian(d.readings, d.gravity, ids=kin_ids, **geometry)
        initial = None
        if d.initial_readings is not None:
            initial = platform_specific_force(np.asarray(d.initial_readings, dtype=float), d.gravity, **geometry)
        inputs = TermInputs(
            f_p,
            temperature=d.temperature,
            time=d.time,
            slew_direction=slew_directions(f_p, initial),
            angular_rate=np.zeros_like(f_p),
            angular_acceleration=np.zeros_like(f_p),
            extra={"time_since_command": d.time_since_command, "platform_jacobian": d_fp, "platform_jacobian_ids": kin_ids},
        )
        through_kinematics = [k for k, t in enumerate(full.terms) if t.id in kin_ids]
        dynamic = {k: v for k, v in values.items() if k not in effects}  # kinematic effects are already in f^p
        prediction = full.forward(f_p, dynamic, inputs)
        jac = full.jacobian(f_p, dynamic, inputs)
        if through_kinematics:
            j_fp = full.jacobian_specific_force(f_p, dynamic, inputs)
            for k in through_kinematics:
                jac[..., k] = np.einsum("...ij,...j->...i", j_fp, d_fp[..., kin_ids.index(full.terms[k].id)])
        return prediction, jac, f_p, inputs

    # ------------------------------------------------------------------ fit
    def fit(self, model: ErrorModel, start: Mapping[str, float] | None = None, iterations: int = 8) -> FitResult:
        """Gauss–Newton fit of ``model`` to the dwell means (weighted by 1/σ², whitened where the noise is slow).

        The solver is the one of the device stages (:func:`stableins.estimators.gauss_newton.gauss_newton`,
        column-scaled by each term's typical size, step halved while the cost rises); the parameters
        these data do not determine are held (gauge, :func:`_gauge`) from the start and, should the
        design at the solution lose a direction, the fit is repeated with it held as well.
        """
        from stableins.estimators.gauss_newton import gauss_newton

        d = self.dwells
        values = model.nominal_values()
        if start:
            values.update({k: float(v) for k, v in start.items() if k in model})
        values.update({k: float(v) for k, v in self.fixed.items() if k in model})
        y = d.output.reshape(-1)
        ids = model.ids
        free = [t.id not in self.fixed for t in model.terms]
        scales = np.array([abs(t.nominal) or 1.0 for t in model.terms])

        def weighted(x: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
            prediction, jac, _, _ = self.evaluate(model, dict(zip(ids, x[0], strict=True)))
            return self.whiten(y - prediction.reshape(-1))[None], self.whiten(jac.reshape(-1, len(model)))[None]

        x = np.array([[values[i] for i in ids]])
        gauge: list[str] = []
        notes: list[str] = []
        solved = False
        while True:
            _, a = weighted(x)
            _, new_gauge = _gauge(a[0], [k for k in range(len(model)) if free[k] and ids[k] not in gauge], model.terms)
            for gid in new_gauge:
                gauge.append(gid)
                notes.append(
                    f"{gid} held at {x[0, ids.index(gid)]:.6g} (gauge): these data do not separate it from the other parameters "
                    f"(1σ of the combination > {UNDETERMINED_RATIO:g}× its typical size)"
                )
            if solved and not new_gauge:
                break
            mask = np.array([free[k] and ids[k] not in gauge for k in range(len(model))])
            if mask.any():
                x = gauss_newton(weighted, x, mask, scales, max_iterations=iterations).x
            solved = True
        values = dict(zip(ids, (float(v) for v in x[0]), strict=True))
        prediction, jac, f_p, _ = self.evaluate(model, values)
        a = self.whiten(jac.reshape(-1, len(model)))
        cols = [k for k in range(len(model)) if free[k] and model.terms[k].id not in gauge]
        normal = a[:, cols].T @ a[:, cols]
        cov_free = np.linalg.inv(normal)
        cov = np.zeros((len(model), len(model)))
        cov[np.ix_(cols, cols)] = cov_free
        status = tuple("estimated" if k in cols else ("gauge" if model.terms[k].id in gauge else "fixed") for k in range(len(model)))
        null_space, determined, sv = _design_report(a, model, free, gauge)
        residuals = y - prediction.reshape(-1)
        white = self.whiten(residuals)
        return FitResult(
            stage=self.stage,
            terms=model.terms,
            values=np.array([values[t.id] for t in model.terms]),
            covariance=cov,
            status=status,
            residuals=residuals,
            residual_sigma=self.total_sigma,
            residual_labels=self.labels,
            rank=len(cols),
            singular_values=sv,
            null_space=null_space,
            determined=determined,
            notes=tuple(notes),
            extra={
                "specific_force_platform": f_p,
                "prediction": prediction,
                "noise": d.noise,
                "slow_noise": d.slow_covariance is not None,
            },
            whitened_residuals=white,
            likelihood=Likelihood.from_weighted(model.ids, np.array([values[t.id] for t in model.terms]), a, white),
        )

    def design(self, result: FitResult) -> NDArray[np.float64]:
        model = ErrorModel(result.terms)
        _, jac, _, _ = self.evaluate(model, result.as_dict())
        cols = [k for k, st in enumerate(result.status) if st == "estimated"]
        return jac.reshape(-1, len(model))[:, cols]

    def candidate_columns(self, terms: Sequence[Term], result: FitResult) -> NDArray[np.float64]:
        model = ErrorModel(result.terms)
        _, jac, _, _ = self.evaluate(model, result.as_dict(), extra_terms=tuple(terms))
        return jac.reshape(-1, len(model) + len(terms))[:, len(model) :]

    def orientation(self, result: FitResult | None = None) -> NDArray[np.float64]:
        """``f^p/g`` per observation, shape (m, 3) (residuals against orientation)."""
        d = self.dwells
        from stableins.platform import platform_specific_force

        f_p = platform_specific_force(d.readings, d.gravity, base_attitude=d.base_attitude, configuration=d.configuration)
        return np.repeat(f_p / d.gravity, 3, axis=0)


def fit_chi2(result: FitResult) -> float:
    """χ² that the fit minimized (generalized when the observations are correlated): :attr:`FitResult.chi2`."""
    return result.chi2


def fit_chi2_red(result: FitResult) -> float:
    """:attr:`FitResult.chi2_red`, the one χ²_ν printed everywhere."""
    return result.chi2_red


def whiten(problem: Problem | None, result: FitResult, v: ArrayLike) -> NDArray[np.float64]:
    """``R^{-1/2} v`` with the problem's noise model (diagonal 1σ when it has none)."""
    w = getattr(problem, "whiten", None)
    if w is not None:
        return w(v)
    v = np.asarray(v, dtype=float)
    s = result.residual_sigma
    return v / (s if v.ndim == 1 else s[:, None])


def _design_report(a: NDArray, model: ErrorModel, free: Sequence[bool], gauge: Sequence[str]) -> tuple[NDArray, tuple[str, ...], NDArray]:
    """Null space (model order), determined combinations and singular values of the free parameters' design.

    Uses the device stage's design analysis (:mod:`stableins.estimators.design`) on the
    nominal-scaled whitened design, with the same threshold as the gauge choice here
    (a direction is undetermined when its 1σ exceeds ``UNDETERMINED_RATIO`` typical sizes).
    """
    from stableins.estimators.design import analyze_design, choose_gauge

    idx = [k for k in range(len(model)) if free[k]]
    ids = [model.terms[k].id for k in idx]
    scales = np.array([abs(model.terms[k].nominal) or 1.0 for k in idx])
    smax = np.linalg.norm(a[:, idx] * scales, ord=2) if idx else 0.0
    rtol = (1.0 / UNDETERMINED_RATIO) / smax if smax > 0 else 1e-8
    analysis = analyze_design(a[:, idx], ids, scales, rtol=max(rtol, 1e-12))
    null = np.zeros((len(model), analysis.null_space.shape[1]))
    null[idx] = analysis.null_space
    determined: tuple[str, ...] = ()
    if analysis.deficiency:
        chosen = choose_gauge(analysis, preference=tuple(gauge), scales=scales)
        determined = chosen.describe() + tuple(f"{g} = its prior value by gauge" for g in chosen.fixed)
    return null, determined, analysis.singular_values


_GAUGE_PREFERENCE = {"gimbal": 0, "additive": 1, "nonlinearity": 2, "scale_factor": 3, "installation": 4, "bias": 5}


def _gauge(a: NDArray, cols: list[int], terms: Sequence[Term], tolerance: float = 1e-9) -> tuple[list[int], list[str]]:
    """Hold columns until every direction of the design is determined (:func:`.design.undetermined`).

    Columns of the whitened design are scaled by each term's typical size (``nominal``; a term
    without one by its column's norm); a singular value ``s`` then means a combination with
    1σ = ``1/s`` typical sizes.  While the smallest is below ``max(tolerance·s_max,
    1/UNDETERMINED_RATIO)`` (exact null space, or a combination these data cannot determine), the
    parameter with the largest share of that direction is held, preferring gimbal offsets, then
    additive terms, quadratic coefficients, scale factors, installation angles and biases last.
    Returns the columns kept and the ids held.
    """
    from stableins.estimators.design import undetermined

    ids = [terms[c].id for c in cols]
    norms = np.linalg.norm(a[:, cols], axis=0)
    nominal = np.array([abs(terms[c].nominal) for c in cols])
    scales = np.where(nominal > 0, nominal, 1.0 / np.where(norms > 0, norms, 1.0))
    rank = {terms[c].id: _GAUGE_PREFERENCE.get(terms[c].kind, 6) for c in cols}
    held = undetermined(a[:, cols], ids, scales, rank, tolerance=tolerance, smallest_only=True)
    return [c for c in cols if terms[c].id not in held], list(held)


# ----------------------------------------------------------------------------- generic linear problem
class LinearProblem:
    """A linear least-squares problem ``y = X p + e``, ``e ~ N(0, diag σ²)``.

    Parameters
    ----------
    observations, sigma : array_like (m,)
        Observations and their 1σ (measured independently).
    terms : sequence of Term
        Model parameters; ``columns[term.id]`` is its column.
    columns : mapping id → array (m,)
        Design columns of model parameters *and* candidates.
    labels : sequence of str, optional
        Names of the observations.
    """

    def __init__(
        self,
        observations: ArrayLike,
        sigma: ArrayLike,
        columns: Mapping[str, ArrayLike],
        labels: Sequence[str] | None = None,
        stage: str = "linear",
    ) -> None:
        self.y = np.asarray(observations, dtype=float)
        self.s = np.broadcast_to(np.asarray(sigma, dtype=float), self.y.shape).copy()
        self.columns = {k: np.asarray(v, dtype=float) for k, v in columns.items()}
        self.labels = tuple(labels) if labels is not None else tuple(f"obs {i}" for i in range(self.y.size))
        self.stage = stage

    def _column(self, term: Term) -> NDArray:
        if term.id not in self.columns:
            raise KeyError(f"no design column for {term.id!r}")
        return self.columns[term.id]

    def fit(self, model: ErrorModel, start: Mapping[str, float] | None = None) -> FitResult:
        x = np.stack([self._column(t) for t in model.terms], axis=1) / self.s[:, None]
        cols, gauge = _gauge(x, list(range(len(model))), model.terms)
        p = np.zeros(len(model))
        sol, *_ = np.linalg.lstsq(x[:, cols], self.y / self.s, rcond=None)
        p[cols] = sol
        cov = np.zeros((len(model), len(model)))
        cov[np.ix_(cols, cols)] = np.linalg.inv(x[:, cols].T @ x[:, cols])
        residuals = self.y - (x * self.s[:, None]) @ p
        status = tuple("estimated" if k in cols else "gauge" for k in range(len(model)))
        return FitResult(
            stage=self.stage,
            terms=model.terms,
            values=p,
            covariance=cov,
            status=status,
            residuals=residuals,
            residual_sigma=self.s.copy(),
            residual_labels=self.labels,
            rank=len(cols),
            notes=tuple(f"{g} held at 0 (gauge)" for g in gauge),
        )

    def design(self, result: FitResult) -> NDArray[np.float64]:
        """Columns of the estimated terms (none: the data determine none of them, e.g. slopes of very short dwells)."""
        estimated = [self._column(t) for t, st in zip(result.terms, result.status, strict=True) if st == "estimated"]
        return np.stack(estimated, axis=1) if estimated else np.zeros((self.y.size, 0))

    def candidate_columns(self, terms: Sequence[Term], result: FitResult) -> NDArray[np.float64]:
        return np.stack([self._column(t) for t in terms], axis=1) if terms else np.zeros((self.y.size, 0))


# ----------------------------------------------------------------------------- system records
def bins_from_chunks(
    chunks,
    *,
    gravity: float,
    bin_seconds: float = 60.0,
    reference_temperature: float = 25.0,
    base_attitude: tuple[float, float, float] = (0.0, 0.0, 0.0),
    configuration: GimbalConfiguration = DEFAULT_GIMBALS,
    noise: NoiseModel | None = None,
) -> DwellSet:
    r"""Bin a system-level record (a stream of column chunks) into "dwells" for discovery.

    A space-stable platform turns at the Earth rate relative to the base, so its specific
    force moves slowly; a bin of length ``T`` averaged at the mean readings differs from the
    mean of the outputs by about ``g (ω_ie T)²/24`` (0.8 µg for 60 s), far below the bin's
    noise.  Each bin's 1σ is the white-noise floor of its axis (second differences, pooled
    over the record, free of the Earth-rate slope of the signal) over ``sqrt(n)``.  No slews: hysteresis is not excited; the time since
    the last command is the record time.  Memory is bounded by the number of bins.

    Parameters
    ----------
    chunks : iterable of mappings
        Column chunks with ``time``, ``angle_platform/inner/middle``, ``f_x/y/z`` and
        ``temperature`` (e.g. :meth:`stableins.data.system.SystemRecord.iter_chunks`).
    gravity : float
        Local gravity [m/s²].
    bin_seconds : float
        Bin length [s].
    noise : NoiseModel, optional
        The instrument's noise model: over a day the slow bias wander (bias instability,
        random walk) is correlated between bins and would otherwise look like drift or a harmonic.
    """
    sums: dict[int, NDArray] = {}
    squares = np.zeros(3)
    n_diff = 0
    t0 = None
    last = None  # (bins, f) of the previous chunk's last two samples, for differences across chunk boundaries
    for chunk in chunks:
        t = np.asarray(chunk["time"], dtype=float)
        if t.size == 0:
            continue
        t0 = t[0] if t0 is None else t0
        f = np.stack([np.asarray(chunk[k], dtype=float) for k in ("f_x", "f_y", "f_z")], axis=-1)
        r = np.stack([np.asarray(chunk[f"angle_{g}"], dtype=float) for g in ("platform", "inner", "middle")], axis=-1)
        temp = np.asarray(chunk["temperature"], dtype=float)
        b = np.floor((t - t0) / bin_seconds).astype(np.int64)
        if last is not None:
            b_all, f_all = np.concatenate([last[0], b]), np.vstack([last[1], f])
        else:
            b_all, f_all = b, f
        # second differences within a bin: E[(Δ²n)²] = 6σ² for white noise, and the platform's slow turning (a slope
        # of g ω_ie cosL per second in x and y, +14 % on a first-difference floor at 1 Hz) does not reach them
        same = b_all[2:] == b_all[:-2]
        d = (f_all[2:] - 2.0 * f_all[1:-1] + f_all[:-2])[same]
        squares += (d**2).sum(axis=0) / 6.0
        n_diff += d.shape[0]
        last = (b_all[-2:], f_all[-2:])
        for k in np.unique(b):
            m = b == k
            row = np.concatenate([[m.sum(), t[m].sum(), temp[m].sum()], f[m].sum(axis=0), r[m].sum(axis=0)])
            sums[int(k)] = sums.get(int(k), 0.0) + row
    if not sums or n_diff == 0:
        raise ValueError("the record has too few samples to form bins")
    keys = sorted(sums)
    table = np.array([sums[k] for k in keys])
    n = table[:, 0]
    full = n >= 0.5 * np.median(n)  # drop a short last bin
    table, n = table[full], n[full]
    sigma_white = np.sqrt(squares / n_diff)
    readings = table[:, 6:9] / n[:, None]
    time = table[:, 1] / n
    rate = float(np.median(n)) / bin_seconds
    lengths = n / rate
    slow = None if noise is None or not noise.has_slow_noise else noise.slow_covariance(time - lengths / 2.0, lengths)
    return DwellSet(
        readings=readings,
        output=table[:, 3:6] / n[:, None],
        sigma=sigma_white[None, :] / np.sqrt(n)[:, None],
        gravity=float(gravity),
        time=time,
        time_since_command=time - float(t0),
        temperature=table[:, 2] / n - reference_temperature,
        slew_direction=np.zeros((len(n), 3)),
        labels=tuple(f"{(tk - t0) / 3600:.2f}h" for tk in time),
        base_attitude=tuple(base_attitude),
        configuration=configuration,
        noise={
            "method": f"white noise from second differences, pooled over the record; {bin_seconds:g} s bins",
            "sigma_per_sample": sigma_white,
            "lengths": lengths,
            "slow_noise": "none" if noise is None else noise.describe(),
        },
        initial_readings=None,
        slow_covariance=slow,
    )
