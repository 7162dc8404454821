r"""Experimental design of the device-level calibration: Cramér-Rao bound, lab time, optimal dwells and positions.

A *plan* (:class:`DevicePlan`) is what the platform will do: the coarse positions, run ``passes`` times in one
session (one time base, as ``stableins run`` records the zero-offset iteration), then the fine positions in a
session of their own, each dwell with its settle and dwell time.  Before the platform moves, the plan's expected
1σ of every parameter is the Cramér-Rao bound of the joint device fit (:mod:`stableins.estimators.joint`, the
estimator that makes the record) under the unit's noise model:

.. math::
    P = (A^T A)^{-1},\qquad A = L^{-1} H,\quad L L^T = \mathrm{Cov}(o)

``H`` the exact Jacobian of every coarse output and fine squared-amplitude row at the nominal instrument, ``Cov(o)``
the observation covariance with the white noise ``N²/T`` of each dwell mean, quantization and the slow noise (bias
instability, random walk) between the dwells of a session
(:meth:`stableins.noise.NoiseModel.dwell_mean_covariance`); ``θ10`` is the gauge (held at 0, the null direction
of the coarse design).  The bound is evaluated by the estimator's own problem
(:func:`stableins.estimators.joint.joint_problem`) on noise-free dwell means, so design and calibration cannot
disagree on the model.

Lab time: for each dwell the slew from the previous command (cosine rate profile with peak ``slew_rate``:
``π/2 · max|Δα| / ω_peak``, as the simulated platform moves), the settle and the dwell.

Optimization (:func:`optimize_dwells`): the dwell time of every coarse position (the same in every pass) and every
fine position, on a log scale within ``[minimum, maximum]``, by sequential quadratic programming (SciPy SLSQP) on
the exact bound above:

* ``targets``: least lab time subject to ``σ_k ≤ target_k`` for every parameter with a target;
* ``budget``: the best design for a lab-time budget, by the criterion stated: **A-optimal** (minimize
  ``Σ_k (σ_k / s_k)²``, ``s_k`` the target or the parameter's typical size) or **D-optimal** (minimize
  ``log det`` of the covariance of the parameters scaled by ``s_k``).

Positions (:func:`exchange_positions`): a Fedorov exchange over a candidate set (e.g. every reachable gimbal triple
on a 15° grid, :func:`grid_candidates`): each position of a stage is replaced by the candidate that most improves
the criterion at the same dwell times, with the white-noise information ``T Jᵀ J / N²`` of each candidate (slow
noise couples dwells and is added back by the duration optimization that follows); a swap that would leave one
coarse pass unable to determine the offsets on its own (the zero-offset iteration re-points from one pass) is
refused.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from enum import StrEnum

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stableins.errormodel import ErrorModel
from stableins.errors import InputError
from stableins.estimators.coarse import CoarseProblem, coarse_model
from stableins.estimators.design import DesignAnalysis, analyze_design
from stableins.estimators.dwell import DwellSummary
from stableins.estimators.joint import joint_problem
from stableins.estimators.setting import DeviceSetting
from stableins.noise import NoiseModel

#: Peak slew rate of the platform [rad/s] (10°/s; docs/procedures.md: a 180° slew takes 28 s).
DEFAULT_SLEW_RATE = math.radians(10.0)
#: The gauge of the device stages (the platform azimuth the data cannot see).
GAUGE = "theta10"


class Criterion(StrEnum):
    """Optimality criterion of a design for a lab-time budget."""

    A = "A"  #: minimize the sum of the scaled variances (the average squared σ relative to its scale)
    D = "D"  #: minimize the log-determinant of the scaled covariance (the volume of the confidence ellipsoid)


@dataclass(frozen=True)
class PlannedStage:
    """Positions of one stage and their timing.

    Attributes
    ----------
    stage : str
        ``"coarse"`` or ``"fine"``.
    commands : ndarray (m, 3)
        Commanded angle-sensor readings (platform, inner, middle) [rad].
    dwell, settle : ndarray (m,)
        Dwell and settle time of every position [s].
    sample_rate : float
        Sample rate [Hz] (written to the procedure; the bound depends on ``N²/T`` only).
    passes : int
        How often the positions are run in the stage's session (the coarse zero-offset passes).
    """

    stage: str
    commands: NDArray[np.float64]
    dwell: NDArray[np.float64]
    settle: NDArray[np.float64]
    sample_rate: float = 100.0
    passes: int = 1

    def __post_init__(self) -> None:
        commands = np.asarray(self.commands, dtype=float).reshape(-1, 3)
        m = len(commands)
        object.__setattr__(self, "commands", commands)
        object.__setattr__(self, "dwell", np.broadcast_to(np.asarray(self.dwell, dtype=float), (m,)).copy())
        object.__setattr__(self, "settle", np.broadcast_to(np.asarray(self.settle, dtype=float), (m,)).copy())

    def with_dwell(self, dwell: ArrayLike) -> PlannedStage:
        """Return the stage with other dwell times."""
        return replace(self, dwell=np.asarray(dwell, dtype=float))

    def timeline(self, slew_rate: float) -> tuple[NDArray[np.float64], float]:
        """Dwell start times ``(passes·m,)`` in the stage's session and its lab time [s] (slews, settles, dwells)."""
        starts = []
        now = 0.0
        previous = np.zeros(3)
        for _ in range(self.passes):
            for command, settle, dwell in zip(self.commands, self.settle, self.dwell):
                now += slew_time(previous, command, slew_rate) + settle
                starts.append(now)
                now += dwell
                previous = command
        return np.array(starts), now


@dataclass(frozen=True)
class DevicePlan:
    """Coarse stage (its passes in one session) and, optionally, the fine stage (a session of its own)."""

    coarse: PlannedStage
    fine: PlannedStage | None = None
    slew_rate: float = DEFAULT_SLEW_RATE

    @property
    def lab_time(self) -> float:
        """Platform time of the whole plan [s]."""
        return sum(s.timeline(self.slew_rate)[1] for s in self.stages)

    @property
    def stages(self) -> tuple[PlannedStage, ...]:
        """The planned stages in order."""
        return (self.coarse,) if self.fine is None else (self.coarse, self.fine)

    def stage_times(self) -> dict[str, float]:
        """Lab time of each stage [s]."""
        return {s.stage: s.timeline(self.slew_rate)[1] for s in self.stages}


def slew_time(start: ArrayLike, end: ArrayLike, slew_rate: float = DEFAULT_SLEW_RATE) -> float:
    """Slew duration [s] between two commands: cosine rate profile, ``π/2 · max|Δα| / ω_peak``."""
    return float(np.pi / 2 * np.max(np.abs(np.asarray(end, dtype=float) - np.asarray(start, dtype=float))) / slew_rate)


@dataclass(frozen=True)
class DesignResult:
    """Expected precision of a plan.

    Attributes
    ----------
    plan : DevicePlan
    ids : tuple of str
        Parameters of the joint model (``θ10`` the gauge, σ 0).
    covariance : ndarray (n, n)
        Cramér-Rao bound [SI]; the gauge row and column are zero.
    analysis : DesignAnalysis
        Rank, singular values and null space of the whole weighted design (gauge column included).
    coarse_pass : DesignAnalysis
        The same for one coarse pass alone (the zero-offset iteration re-points from it).
    model : ErrorModel
    """

    plan: DevicePlan
    ids: tuple[str, ...]
    covariance: NDArray[np.float64]
    analysis: DesignAnalysis
    coarse_pass: DesignAnalysis
    model: ErrorModel = field(repr=False)

    @property
    def sigma(self) -> dict[str, float]:
        """1σ of every parameter [SI] (0 for the gauge)."""
        return dict(zip(self.ids, np.sqrt(np.clip(np.diagonal(self.covariance), 0.0, None)).tolist()))

    def sigma_engineering(self) -> dict[str, float]:
        """1σ in the engineering unit of each term (ppm, µg, arcsec, µg/g²)."""
        return {k: float(self.model[k].sigma_to_engineering(v)) for k, v in self.sigma.items()}

    @property
    def lab_time(self) -> float:
        """Platform time of the plan [s]."""
        return self.plan.lab_time


def _dwells(stage: PlannedStage, setting: DeviceSetting, noise: NoiseModel, model: ErrorModel, slew_rate: float) -> list[DwellSummary]:
    """Noise-free dwells of a planned stage at the nominal instrument, with the white 1σ ``N/√T`` of the noise model."""
    starts, _ = stage.timeline(slew_rate)
    commands = np.tile(stage.commands, (stage.passes, 1))
    dwell = np.tile(stage.dwell, stage.passes)
    nominal = model.vector({k: model[k].reference for k in model.ids})
    from stableins.conventions import dcm_nav_to_body

    probe = CoarseProblem(
        commands[None],
        np.zeros((1, len(commands), 3)),
        np.ones((1, len(commands), 3)),
        setting.gravity,
        dcm_nav_to_body(*setting.base_attitude),
        setting.configuration,
        model,
    )
    means = probe.predict(nominal[None])[0][0]
    white = noise.values("white")
    out = []
    m = len(stage.commands)
    for k, (command, mean, t, start) in enumerate(zip(commands, means, dwell, starts)):
        out.append(
            DwellSummary(
                position=k % m + 1,
                stage=stage.stage,
                pass_number=k // m + 1,
                command=command,
                angles=command,
                mean=mean,
                sem=white / math.sqrt(t),
                noise=white * math.sqrt(stage.sample_rate),
                samples=int(t * stage.sample_rate) + 1,
                duration=float(t),
                start=float(start),
            )
        )
    return out


def _weighted_design(
    plan: DevicePlan, noise: NoiseModel, setting: DeviceSetting
) -> tuple[ErrorModel, NDArray[np.float64], list[DwellSummary]]:
    """Return the joint model, the whitened Jacobian ``A`` of the whole plan at the nominal instrument, and the coarse dwells."""
    if not np.all(noise.values("white") > 0):
        raise InputError("the noise model needs a white noise N > 0 on every axis", field="noise_model.white", expected="N [m/s/√s] > 0")
    model = coarse_model(nonlinear=True, extra_terms=setting.extra_terms)
    coarse = _dwells(plan.coarse, setting, noise, model, plan.slew_rate)
    fine = [] if plan.fine is None else _dwells(plan.fine, setting, noise, model, plan.slew_rate)
    x = model.vector({k: model[k].reference for k in model.ids})[None]
    return model, joint_problem(coarse, fine, setting=replace(setting, noise=noise), model=model).weighted(x)[1][0], coarse


def _bound(model: ErrorModel, a: NDArray[np.float64]) -> NDArray[np.float64]:
    """``(A_fᵀ A_f)⁻¹`` on the free parameters (``θ10`` the gauge: zero row and column)."""
    free = np.array([k != GAUGE for k in model.ids])
    cov = np.zeros((len(model), len(model)))
    cov[np.ix_(free, free)] = np.linalg.inv(a[:, free].T @ a[:, free])
    return cov


def expected_precision(plan: DevicePlan, noise: NoiseModel, setting: DeviceSetting) -> DesignResult:
    """Cramér-Rao bound of ``plan`` under ``noise`` (module docstring): σ, rank, null space, lab time.

    Raises
    ------
    InputError
        The noise model has no white noise (the bound would be infinite information), or the design does not
        determine the parameters beyond the ``θ10`` gauge.
    """
    model, a, coarse = _weighted_design(plan, noise, setting)
    scales = np.array([t.nominal for t in model])
    analysis = analyze_design(a, model.ids, scales)
    x = model.vector({k: model[k].reference for k in model.ids})[None]
    m = len(plan.coarse.commands)
    one = joint_problem(coarse[:m], [], setting=replace(setting, noise=noise), model=model).weighted(x)[1][0]
    coarse_pass = analyze_design(one, model.ids, scales)
    if analysis.rank < len(model) - 1:
        from stableins.estimators.design import describe_design

        lines = describe_design(model.ids, analysis.singular_values, analysis.null_space)
        raise InputError("the design does not determine the parameters beyond the θ10 gauge: " + "; ".join(lines[1:]), field="positions")
    return DesignResult(plan, model.ids, _bound(model, a), analysis, coarse_pass, model)


def scaled_criterion(result: DesignResult, criterion: Criterion, scales: Mapping[str, float]) -> float:
    """Return the criterion: A ``Σ (σ_k/s_k)²``, D ``log det`` of the covariance scaled by ``s_k`` (gauge excluded)."""
    idx = [result.ids.index(k) for k in scales if k != GAUGE]
    s = np.array([scales[result.ids[i]] for i in idx])
    cov = result.covariance[np.ix_(idx, idx)] / np.outer(s, s)
    if criterion is Criterion.A:
        return float(np.trace(cov))
    return float(np.linalg.slogdet(cov)[1])


@dataclass(frozen=True)
class DwellBounds:
    """Smallest and largest dwell the optimizer may choose [s] (a dwell must hold enough samples to measure its noise)."""

    minimum: float = 5.0
    maximum: float = 3600.0


def _scaled_dwells(plan: DevicePlan, u: NDArray[np.float64]) -> DevicePlan:
    """Return the plan with dwell times ``exp(u)``: coarse positions first, then fine."""
    m = len(plan.coarse.commands)
    t = np.exp(u)
    coarse = plan.coarse.with_dwell(t[:m])
    fine = None if plan.fine is None else plan.fine.with_dwell(t[m:])
    return replace(plan, coarse=coarse, fine=fine)


def optimize_dwells(
    plan: DevicePlan,
    noise: NoiseModel,
    setting: DeviceSetting,
    *,
    targets: Mapping[str, float] | None = None,
    budget: float | None = None,
    criterion: Criterion = Criterion.A,
    bounds: DwellBounds = DwellBounds(),
) -> DesignResult:
    """Dwell times of every position that reach ``targets`` (1σ, SI) in the least lab time, or the best design within ``budget`` [s].

    Exactly one of ``targets`` and ``budget``.  With a budget, the criterion scales every parameter by its target
    when given, else by its typical size (:attr:`stableins.errormodel.Term.nominal`).  The result is evaluated by
    :func:`expected_precision` on the optimized plan; when the targets cannot be met within ``bounds`` an
    :class:`InputError` names the parameters that miss them.
    """
    from scipy.optimize import minimize

    if (targets is None) == (budget is None):
        raise ValueError("give exactly one of targets and budget")
    start = expected_precision(plan, noise, setting)
    ids = [k for k in start.ids if k != GAUGE]
    scales = {k: (targets or {}).get(k, start.model[k].nominal) for k in ids}
    u0 = np.log(np.clip(np.concatenate([s.dwell for s in plan.stages]), bounds.minimum, bounds.maximum))
    box = [(math.log(bounds.minimum), math.log(bounds.maximum))] * len(u0)

    cache: dict[bytes, tuple[tuple[str, ...], NDArray[np.float64]]] = {}

    def bound_of(u: NDArray[np.float64]) -> tuple[tuple[str, ...], NDArray[np.float64]]:
        key = np.asarray(u, dtype=float).tobytes()
        if key not in cache:
            model, a, _ = _weighted_design(_scaled_dwells(plan, u), noise, setting)
            cache[key] = (model.ids, _bound(model, a))
        return cache[key]

    def log_sigma(u: NDArray[np.float64], keys: Sequence[str]) -> NDArray[np.float64]:
        names, cov = bound_of(u)
        return 0.5 * np.log(np.array([cov[names.index(k), names.index(k)] for k in keys]))

    def criterion_of(u: NDArray[np.float64]) -> float:
        names, cov = bound_of(u)
        idx = [names.index(k) for k in ids]
        scale = np.array([scales[k] for k in ids])
        block = cov[np.ix_(idx, idx)] / np.outer(scale, scale)
        return float(np.trace(block)) if criterion is Criterion.A else float(np.linalg.slogdet(block)[1])

    def evaluate(u: NDArray[np.float64]) -> DesignResult:
        return expected_precision(_scaled_dwells(plan, u), noise, setting)

    if targets is not None:
        keys = [k for k in targets if k in ids]
        goal = np.log(np.array([targets[k] for k in keys]))
        time_scale = plan.lab_time
        solution = minimize(
            lambda u: _scaled_dwells(plan, u).lab_time / time_scale,
            u0,
            method="SLSQP",
            bounds=box,
            constraints=[{"type": "ineq", "fun": lambda u: goal - log_sigma(u, keys)}],
            options={"maxiter": 200, "ftol": 1e-6},
        )
        result = evaluate(solution.x)
        missed = [k for k in keys if result.sigma[k] > targets[k] * 1.001]
        if missed:
            raise InputError(
                f"the targets of {', '.join(missed)} cannot be reached with dwells of {bounds.minimum:g}–{bounds.maximum:g} s "
                "at these positions",
                field="targets",
                expected="larger targets, longer --max-dwell, or other positions",
            )
        return result
    solution = minimize(
        criterion_of,
        u0,
        method="SLSQP",
        bounds=box,
        constraints=[{"type": "ineq", "fun": lambda u: 1.0 - _scaled_dwells(plan, u).lab_time / float(budget or 1.0)}],
        options={"maxiter": 200, "ftol": 1e-8},
    )
    result = evaluate(solution.x)
    if result.lab_time > float(budget or 0.0) * 1.001:
        raise InputError(
            f"the budget {float(budget or 0.0) / 3600:.3g} h is shorter than the slews, settles and shortest dwells of these positions",
            field="budget",
            expected=f"at least {_scaled_dwells(plan, np.full_like(u0, box[0][0])).lab_time / 3600:.3g} h",
        )
    return result


def grid_candidates(
    step: float, *, platform: tuple[float, float], inner: tuple[float, float], middle: tuple[float, float]
) -> NDArray[np.float64]:
    """Every gimbal triple (platform, inner, middle) [rad] on a grid of ``step`` [rad] within the closed ranges given [rad]."""
    axes = [np.arange(lo, hi + 1e-9, step) for lo, hi in (platform, inner, middle)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)


def _unit_information(
    commands: NDArray[np.float64], model: ErrorModel, setting: DeviceSetting, noise: NoiseModel
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """White-noise information per second of dwell, ``(c, n, n)``, of a coarse and of a fine dwell at each command."""
    from stableins.conventions import dcm_nav_to_body
    from stableins.estimators.fine import FineProblem, fine_model

    c = len(commands)
    white = noise.values("white")
    x = model.vector({k: model[k].reference for k in model.ids})[None]
    probe = CoarseProblem(
        commands[None],
        np.zeros((1, c, 3)),
        np.ones((1, c, 3)),
        setting.gravity,
        dcm_nav_to_body(*setting.base_attitude),
        setting.configuration,
        model,
    )
    means, jac = probe.predict(x)
    weighted = jac[0] / white[None, :, None]  # (c, 3, n)
    coarse = np.einsum("cai,caj->cij", weighted, weighted)
    fm = fine_model(setting.extra_terms)
    xf = fm.vector({k: fm[k].reference for k in fm.ids})[None]
    _, _, d_h_d_p, sigma_h = FineProblem(means, np.broadcast_to(white, means.shape), float(setting.gravity), fm).evaluate(xf)
    columns = [model.index(k) for k in fm.ids]
    row = np.zeros((c, len(model)))
    row[:, columns] = d_h_d_p[0] / sigma_h[0][:, None]
    return coarse, np.einsum("ci,cj->cij", row, row)


def _criterion_batch(
    info: NDArray[np.float64], free: NDArray[np.bool_], scales: NDArray[np.float64], criterion: Criterion
) -> NDArray[np.float64]:
    """Return the A or D criterion of information matrices ``(b, n, n)``, free parameters scaled by ``scales``; inf if singular."""
    block = info[:, free][:, :, free] * np.outer(scales, scales)
    eigen = np.linalg.eigvalsh(block)
    ok = eigen[:, 0] > 1e-12 * eigen[:, -1]
    out = np.full(len(block), np.inf)
    if criterion is Criterion.D:
        out[ok] = -np.log(eigen[ok]).sum(axis=1)
    else:
        out[ok] = (1.0 / eigen[ok]).sum(axis=1)
    return out


def exchange_positions(
    plan: DevicePlan,
    candidates: NDArray[np.float64],
    noise: NoiseModel,
    setting: DeviceSetting,
    *,
    scales: Mapping[str, float],
    criterion: Criterion = Criterion.A,
    sweeps: int = 4,
) -> DevicePlan:
    """Replace positions by candidates (Fedorov exchange, module docstring) at the plan's dwell times; returns the new plan.

    ``scales`` (SI, per parameter) weight the criterion (the targets, or the typical sizes).  A coarse position is only
    replaced by one that keeps a single coarse pass able to determine every parameter beyond the ``θ10`` gauge.
    """
    model = coarse_model(nonlinear=True, extra_terms=setting.extra_terms)
    free = np.array([k != GAUGE for k in model.ids])
    s = np.array([scales.get(k, model[k].nominal) for k in model.ids])[free]
    cand = _unit_information(candidates, model, setting, noise)
    commands = {st.stage: st.commands.copy() for st in plan.stages}
    current = {st.stage: _unit_information(st.commands, model, setting, noise)[k] for k, st in enumerate(plan.stages)}
    weight = {st.stage: st.dwell * st.passes for st in plan.stages}
    for _ in range(sweeps):
        changed = False
        for k, st in enumerate(plan.stages):
            for j in range(len(st.commands)):
                total = sum(np.einsum("j,jab->ab", weight[name], current[name]) for name in current)
                values = _criterion_batch(
                    total[None] - weight[st.stage][j] * current[st.stage][j] + weight[st.stage][j] * cand[k], free, s, criterion
                )
                if st.stage == "coarse":  # one pass alone must still determine everything (the offsets it re-points by)
                    one = np.einsum("j,jab->ab", st.dwell, current["coarse"]) - st.dwell[j] * current["coarse"][j]
                    values[~np.isfinite(_criterion_batch(one[None] + st.dwell[j] * cand[0], free, s, Criterion.D))] = np.inf
                best = int(np.argmin(values))
                if values[best] < _criterion_batch(total[None], free, s, criterion)[0] - 1e-9 * abs(values[best]):
                    commands[st.stage][j] = candidates[best]
                    current[st.stage][j] = cand[k][best]
                    changed = True
        if not changed:
            break
    return replace(
        plan,
        coarse=replace(plan.coarse, commands=commands["coarse"]),
        fine=None if plan.fine is None else replace(plan.fine, commands=commands["fine"]),
    )
