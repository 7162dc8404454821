r"""The navigation budget: what each calibration term's 1σ (and the gyro drift) does to navigation.

Every term of a calibration record is a parameter with a standard uncertainty.  After compensation with the
record, the unit's true residual of a term is of the order of that σ; the budget propagates a residual of
``+1σ`` of each term, alone, through the static-base INS error dynamics (:mod:`stableins.navigation.dynamics`,
exactly: :mod:`stableins.navigation.propagation`) over the navigation time, and reports per term the peak and
final position, velocity and attitude errors.  Two totals:

* **RSS of the terms** — ``sqrt(Σ_k y_k(t)²)`` at each time (the terms taken as independent);
* **total** — ``sqrt(s(t)ᵀ P s(t))`` with the record's full covariance ``P`` and the per-unit responses ``s(t)``:
  the standard deviation of the navigation error the calibration's uncertainty leaves.  The two differ by the
  correlations the calibration created (a system stage determines ``b_x − β_xy sinL``, not each alone: their errors
  are correlated and partly cancel, or add).

Peaks are taken over the time grid (step ``h``; the Schuler period is 84 min, so a 60-s step misses a peak by
at most ``1 − cos(π·60/5064) = 0.07 %``).  Horizontal quantities are ``sqrt(N² + E²)``.  Attitude errors are those
of a level, north-pointing body: ``(δroll, δpitch, δheading) = −(φ_N, φ_E, φ_D)`` (:mod:`stableins.conventions`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from stableins.conventions import ARCSEC, DEG_PER_HOUR
from stableins.errormodel import GIMBAL_IDS, GYRO_DRIFT_TERMS, ErrorModel, Term, TermKind, known_terms
from stableins.navigation.dynamics import NavigationScenario
from stableins.navigation.propagation import Propagator
from stableins.navigation.sources import (
    ACCELEROMETER_KINDS,
    LeftOut,
    UnitForcing,
    accelerometer_forcing,
    drift_forcing,
    g_sensitivity_forcing,
    gimbal_forcing,
)
from stableins.navigation.summary import (
    COMPONENTS,
    HORIZONTAL,
    DriftSource,
    ErrorSummary,
    Quantity,
    TermBudget,
    magnitudes,
    magnitudes_covariance,
    magnitudes_rss,
)

#: Default step of the time grid [s].
DEFAULT_STEP = 60.0
#: Most time steps of a budget (a longer duration takes a longer step).
MAX_STEPS = 20000


@dataclass(frozen=True)
class NavigationBudget:
    """A navigation budget (module docstring): per term, the RSS and the total with correlations.

    Attributes
    ----------
    scenario : NavigationScenario
    duration, step : float
        [s].
    terms : tuple of TermBudget
        Ranked by peak horizontal position error, largest first.
    rss, total : ErrorSummary
        RSS of the terms (independent), and the total with the record's covariance.
    left_out : tuple of LeftOut
        Record terms not propagated, with the reason.
    drift : DriftSource
        Where the gyro-drift σ comes from (none: the budget has no gyro drift, and says so).
    time : ndarray (steps,)
        [s].
    responses : ndarray (steps, len(Quantity), terms)
        Magnitudes of each term's errors (order of :attr:`terms`) [SI].
    rss_series, total_series : ndarray (steps, len(Quantity))
        [SI].
    serial_number : str
        The unit's.
    """

    scenario: NavigationScenario
    duration: float
    step: float
    terms: tuple[TermBudget, ...]
    rss: ErrorSummary
    total: ErrorSummary
    left_out: tuple[LeftOut, ...]
    drift: DriftSource
    time: NDArray[np.float64]
    responses: NDArray[np.float64]
    rss_series: NDArray[np.float64]
    total_series: NDArray[np.float64]
    serial_number: str = ""

    def term(self, term_id: str) -> TermBudget:
        """Return the contribution of one term (KeyError if not propagated)."""
        for t in self.terms:
            if t.id == term_id:
                return t
        raise KeyError(term_id)

    @property
    def notes(self) -> tuple[str, ...]:
        """What the reader must know to read the numbers right."""
        out = []
        if self.drift == DriftSource.NONE:
            out.append(
                "no gyro drift: the record carries no gyro_drift_* terms and none was given (--drift X Y Z); "
                "on a real platform the drift usually dominates position and heading errors"
            )
        if self.scenario.vertical_gains is None:
            out.append("no vertical-loop gains in the site's damping: the vertical channel is left out (height error 0)")
        out.extend(f"{item.id} not propagated: {item.reason}" for item in self.left_out)
        return tuple(out)

    def report(self, *, rows: int | None = None) -> str:
        """Return the ranked table (text)."""
        from stableins.navigation.report import budget_text

        return budget_text(self, rows=rows)

    def __str__(self) -> str:
        return self.report()

    def __repr__(self) -> str:
        return (
            f"<NavigationBudget {self.serial_number or 'unit'}: {len(self.terms)} terms over {self.duration / 86400:.3g} d, "
            f"total peak position {self.total.position.peak:.4g} m, heading {self.total.heading.peak / ARCSEC:.4g}″; print() for the table>"
        )

    def to_dict(self) -> dict[str, Any]:
        """Return the JSON document of ``stableins budget --json`` (engineering units: m, m/s, arcsec; σ in the term's unit)."""
        from stableins.navigation.report import budget_document

        return budget_document(self)

    def plot(self, path: str | None = None, *, top: int = 6, file_format: str | None = None) -> Any:
        """Figure: the largest error up to each time, per term (the ``top`` largest) and the totals (log scale).

        With ``path`` it is written there (``file_format``: png, pdf or svg; default from the suffix) and closed.
        """
        from stableins.navigation.report import budget_figure

        return budget_figure(self, path, top=top, file_format=file_format)

    def compare(self, other: NavigationBudget, *, labels: tuple[str, str] = ("", "")) -> BudgetComparison:
        """Return the difference ``other − self`` term by term and in the totals (``labels``: how to name the two, e.g. files)."""
        return BudgetComparison(self, other, labels)

    def _repr_html_(self) -> str:
        from stableins.navigation.report import budget_html

        return budget_html(self)


@dataclass(frozen=True)
class BudgetComparison:
    """Two budgets side by side (``stableins budget A.json --compare B.json``): ``other − base``."""

    base: NavigationBudget
    other: NavigationBudget
    labels: tuple[str, str] = ("", "")

    def report(self) -> str:
        """Return the side-by-side table (text)."""
        from stableins.navigation.report import comparison_text

        return comparison_text(self)

    def __str__(self) -> str:
        return self.report()

    def to_dict(self) -> dict[str, Any]:
        """Return both budgets and the differences (JSON of ``--compare``)."""
        from stableins.navigation.report import comparison_document

        return comparison_document(self)


def _step_for(duration: float, step: float) -> tuple[float, int]:
    count = max(1, int(math.ceil(duration / step - 1e-9)))
    if count > MAX_STEPS:
        count = MAX_STEPS
    return duration / count, count


def _term_forcing(term: Term, model: ErrorModel, values: Mapping[str, float], scenario: NavigationScenario) -> UnitForcing | str:
    """Return the unit forcing of a term, or the reason it is left out."""
    if term.kind == TermKind.GYRO_DRIFT:
        return drift_forcing(term.axis if term.axis is not None else 0, scenario)
    if term.kind == TermKind.GYRO_G_SENSITIVITY:  # Dg_ab: a drift of gyro a proportional to the specific force along b
        gyro_axis, force_axis = ("xyz".index(c) for c in term.id.removeprefix("Dg_"))
        return g_sensitivity_forcing(gyro_axis, force_axis, scenario)
    if term.kind == TermKind.GIMBAL:
        return gimbal_forcing(GIMBAL_IDS.index(term.id), scenario)
    if term.kind == TermKind.COMBINED:
        return "a combined coefficient of the system stage (a combination of the core terms, which are propagated)"
    if term.kind in ACCELEROMETER_KINDS:
        try:
            return accelerometer_forcing(model, values, term, scenario)
        except ValueError as error:
            return f"{error}; on a static base at the reference temperature it adds nothing the budget can compute"
    return f"kind {term.kind} does not act on navigation"  # pragma: no cover - every kind is listed above


@dataclass(frozen=True)
class CalibrationTerms:
    """What a budget propagates: a calibration's error model, values (the linearization point), ids and covariance [SI].

    :func:`stableins.reporting.navigation.record_navigation_budget` takes them from a calibration record.
    """

    model: ErrorModel
    values: Mapping[str, float]
    ids: tuple[str, ...]
    covariance: NDArray[np.float64]


@dataclass(frozen=True)
class _Chosen:
    term: Term
    sigma: float
    row: int | None  # row in the covariance (None: a given drift, uncorrelated)
    forcing: UnitForcing | None = None


def _choose(calibration: CalibrationTerms, drift_sigma: Sequence[float] | None) -> tuple[list[_Chosen], list[LeftOut], DriftSource]:
    """Return the terms with a finite, positive 1σ, those left out and why, and where the drift comes from."""
    terms = known_terms(calibration.model.terms)
    cov = np.asarray(calibration.covariance, dtype=float)
    drift_ids = {t.id for t in GYRO_DRIFT_TERMS}
    chosen: list[_Chosen] = []
    left_out: list[LeftOut] = []
    for row, pid in enumerate(calibration.ids):
        if drift_sigma is not None and pid in drift_ids:
            continue
        term, variance = terms.get(pid), float(cov[row, row])
        if term is None:
            left_out.append(LeftOut(pid, "not a term of the record's error model"))
        elif not math.isfinite(variance):
            left_out.append(LeftOut(pid, "the record gives it no finite 1σ (not determined): its effect is unknown"))
        elif variance <= 0.0:
            left_out.append(LeftOut(pid, "1σ = 0 in the record (held, or fixed by a gauge): no contribution"))
        else:
            chosen.append(_Chosen(term, math.sqrt(variance), row))
    if drift_sigma is not None:
        chosen.extend(_Chosen(t, float(sigma), None) for t, sigma in zip(GYRO_DRIFT_TERMS, drift_sigma, strict=True))
        return chosen, left_out, DriftSource.GIVEN
    return chosen, left_out, DriftSource.RECORD if drift_ids & set(calibration.ids) else DriftSource.NONE


def _covariance_of(chosen: Sequence[_Chosen], covariance: NDArray[np.float64]) -> NDArray[np.float64]:
    """Covariance of the propagated terms: the record's block; a given drift uncorrelated with the rest."""
    m = len(chosen)
    P = np.zeros((m, m))
    for a, first in enumerate(chosen):
        for b, second in enumerate(chosen):
            if first.row is not None and second.row is not None:
                P[a, b] = covariance[first.row, second.row]
            elif a == b:
                P[a, b] = first.sigma**2
    return P


def navigation_budget(
    calibration: CalibrationTerms,
    scenario: NavigationScenario,
    *,
    duration: float,
    step: float = DEFAULT_STEP,
    drift_sigma: Sequence[float] | None = None,
    serial_number: str = "",
) -> NavigationBudget:
    """Propagate each term's 1σ (and the gyro drift) through the INS error dynamics (module docstring).

    Parameters
    ----------
    calibration : CalibrationTerms
        The record's error model (:meth:`stableins.records.CalibrationRecord.error_model`), values, ids and covariance.
    scenario : NavigationScenario
    duration : float
        Navigation time [s].
    step : float
        Time grid [s] (at most :data:`MAX_STEPS` steps).
    drift_sigma : sequence of 3 float, optional
        1σ of the constant platform gyro drift ``(x_p, y_p, z_p)`` [rad/s]: replaces the record's ``gyro_drift_*``
        σ (uncorrelated with the other terms), or adds them when the record has none.
    serial_number : str
    """
    if not (math.isfinite(duration) and duration > 0):
        raise ValueError(f"duration must be positive, got {duration!r}")
    if not (math.isfinite(step) and step > 0):
        raise ValueError(f"step must be positive, got {step!r}")
    chosen, left_out, drift = _choose(calibration, drift_sigma)
    propagated: list[_Chosen] = []
    for item in chosen:
        forcing = _term_forcing(item.term, calibration.model, calibration.values, scenario)
        if isinstance(forcing, str):
            left_out.append(LeftOut(item.term.id, forcing))
        else:
            propagated.append(replace(item, forcing=forcing))
    h, count = _step_for(duration, step)
    time = np.arange(count + 1, dtype=np.float64) * h
    unit = _unit_responses(scenario, [p.forcing for p in propagated if p.forcing is not None], h, count, time)  # per unit
    scaled = unit * np.array([p.sigma for p in propagated])[None, None, :]
    responses = magnitudes(scaled)  # (steps, Q, m)
    rss_series = magnitudes_rss(scaled)
    total_series = magnitudes_covariance(unit, _covariance_of(propagated, np.asarray(calibration.covariance, dtype=float)))
    budgets = [
        TermBudget(p.term.id, p.term.kind, p.sigma, p.term.unit, p.term.scale, ErrorSummary.of(responses[:, :, k]))
        for k, p in enumerate(propagated)
    ]
    order = sorted(range(len(budgets)), key=lambda k: (-budgets[k].summary.position.peak, -budgets[k].summary.heading.peak, budgets[k].id))
    return NavigationBudget(
        scenario=scenario,
        duration=float(duration),
        step=h,
        terms=tuple(budgets[k] for k in order),
        rss=ErrorSummary.of(rss_series),
        total=ErrorSummary.of(total_series),
        left_out=tuple(left_out),
        drift=drift,
        time=time,
        responses=responses[:, :, order] if budgets else responses,
        rss_series=rss_series,
        total_series=total_series,
        serial_number=serial_number,
    )


def _unit_responses(
    scenario: NavigationScenario, forcings: Sequence[UnitForcing], step: float, count: int, time: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Signed component errors (steps, 9, m) per unit of each source, in :data:`COMPONENTS` order."""
    m = len(forcings)
    if m == 0:
        return np.zeros((count + 1, len(COMPONENTS), 0))
    kmax = max(f.forcing.shape[0] for f in forcings)
    forcing = np.zeros((kmax, 6, m), dtype=complex)
    attitude = np.zeros((kmax, 3, m), dtype=complex)
    for j, f in enumerate(forcings):
        forcing[: f.forcing.shape[0], :, j] = f.forcing
        attitude[: f.attitude.shape[0], :, j] = f.attitude
    states = navigation_states(scenario, forcing, step, count)
    return components_from_states(scenario, states, time, attitude)


def navigation_states(scenario: NavigationScenario, forcing: NDArray[np.complex128], step: float, count: int) -> NDArray[np.float64]:
    """Error states (count+1, 10, m) for harmonic forcings ``U`` (K+1, 6, m) from ``x(0) = 0`` (:class:`Propagator`)."""
    propagator = Propagator.build(scenario, step, forcing.shape[0] - 1)
    return propagator.run(forcing, count)


def components_from_states(
    scenario: NavigationScenario, states: NDArray[np.float64], time: NDArray[np.float64], attitude: NDArray[np.complex128] | None = None
) -> NDArray[np.float64]:
    """Position (N, E, height), velocity (N, E, D) and attitude (pitch, roll, heading) errors from the states [SI].

    ``R δL``, ``R cosL δλ``, ``δh``; ``δv``; ``(−φ_E, −φ_N, −φ_D)`` plus any direct output-attitude error ``attitude``
    (K+1, 3, m) (gimbal offsets).
    """
    radius, cl = scenario.radius, math.cos(scenario.latitude)
    out = np.empty((states.shape[0], len(COMPONENTS), states.shape[2]))
    out[:, 0] = radius * states[:, 0]
    out[:, 1] = radius * cl * states[:, 1]
    out[:, 2] = states[:, 7]
    out[:, 3] = states[:, 2]
    out[:, 4] = states[:, 3]
    out[:, 5] = states[:, 8]
    out[:, 6] = -states[:, 5]
    out[:, 7] = -states[:, 4]
    out[:, 8] = -states[:, 6]
    if attitude is not None and np.any(attitude):
        from stableins.conventions import EARTH_RATE

        phase = np.exp(1j * EARTH_RATE * np.outer(time, np.arange(attitude.shape[0])))  # (steps, K+1)
        out[:, 6:9] += np.einsum("tk,kqm->tqm", phase, attitude).real
    return out


def drift_sigma_from_engineering(values: Sequence[float]) -> tuple[float, float, float]:
    """°/h → rad/s (the gyro drift's unit at the edges is °/h, :data:`stableins.conventions.DEG_PER_HOUR`)."""
    x, y, z = (float(v) * DEG_PER_HOUR for v in values)
    return x, y, z


@dataclass(frozen=True)
class NavigationErrors:
    """Signed navigation errors of given residuals (all acting together), on the budget's time grid.

    Attributes
    ----------
    time : ndarray (steps,)
        [s].
    components : ndarray (steps, 9)
        :data:`COMPONENTS` [SI: m, m/s, rad].
    """

    time: NDArray[np.float64]
    components: NDArray[np.float64]

    def __getitem__(self, quantity: Quantity | str) -> NDArray[np.float64]:
        """Return the signed series of a component, or the magnitude of a horizontal quantity."""
        q = Quantity(quantity)
        if q in HORIZONTAL:
            return magnitudes(self.components[:, :, None])[:, list(Quantity).index(q), 0]
        return self.components[:, COMPONENTS.index(q)]


def navigation_errors(
    model: ErrorModel,
    values: Mapping[str, float],
    residuals: Mapping[str, float],
    scenario: NavigationScenario,
    *,
    duration: float,
    step: float = DEFAULT_STEP,
) -> NavigationErrors:
    """Return the navigation errors of residuals ``{id: true − installed}`` [SI] (``gyro_drift_*``: the drift itself).

    Linear superposition of each term's response (the budget's model); ``values`` are the installed calibration
    (the linearization point).  Raises ValueError for a term the budget cannot propagate.
    """
    terms = known_terms(model.terms)
    forcings, amounts = [], []
    for pid, amount in residuals.items():
        if pid not in terms:
            raise ValueError(f"{pid!r} is not a term of the error model")
        forcing = _term_forcing(terms[pid], model, values, scenario)
        if isinstance(forcing, str):
            raise ValueError(f"{pid} cannot be propagated: {forcing}")
        forcings.append(forcing)
        amounts.append(float(amount))
    h, count = _step_for(duration, step)
    time = np.arange(count + 1, dtype=np.float64) * h
    unit = _unit_responses(scenario, forcings, h, count, time)
    return NavigationErrors(time, unit @ np.array(amounts) if amounts else np.zeros((count + 1, len(COMPONENTS))))
