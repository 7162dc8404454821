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
from typing import Any, TypedDict

import numpy as np
from numpy.typing import NDArray

from stableins.conventions import ARCSEC, DEG_PER_HOUR
from stableins.display import number, unit_text
from stableins.errormodel import GIMBAL_IDS, GYRO_DRIFT_TERMS, ErrorModel, Term, TermKind, known_terms
from stableins.errors import InputError, NotDeterminedError
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
    BudgetDriftSource,
    ErrorSummary,
    Quantity,
    QuantityDocument,
    TermBudget,
    magnitudes,
    magnitudes_covariance,
    magnitudes_rss,
)

#: Default step of the time grid [s].
DEFAULT_STEP = 60.0
#: Most time steps of a budget (a longer duration takes a longer step).
MAX_TIME_STEPS = 20000


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
    drift : BudgetDriftSource
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
    drift: BudgetDriftSource
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
        if self.drift == BudgetDriftSource.NONE:
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
        return _budget_text(self, rows=rows)

    def __str__(self) -> str:
        return self.report()

    def __repr__(self) -> str:
        return (
            f"<NavigationBudget {self.serial_number or 'unit'}: {len(self.terms)} terms over {self.duration / 86400:.3g} d, "
            f"total peak position {self.total.position.peak:.4g} m, heading {self.total.heading.peak / ARCSEC:.4g}″; print() for the table>"
        )

    def to_dict(self) -> BudgetDocument:
        """Return the JSON document of ``stableins budget --json`` (engineering units: m, m/s, arcsec; σ in the term's unit)."""
        return _budget_document(self)

    def plot(self, path: str | None = None, *, top: int = 6, file_format: str | None = None) -> Any:
        """Figure: the largest error up to each time, per term (the ``top`` largest) and the totals (log scale).

        With ``path`` it is written there (``file_format``: png, pdf or svg; default from the suffix) and closed.
        """
        return _budget_figure(self, path, top=top, file_format=file_format)

    def compare(self, other: NavigationBudget, *, labels: tuple[str, str] = ("", "")) -> BudgetComparison:
        """Return the difference ``other − self`` term by term and in the totals (``labels``: how to name the two, e.g. files)."""
        return BudgetComparison(self, other, labels)

    def _repr_html_(self) -> str:
        return _budget_html(self)


@dataclass(frozen=True)
class BudgetComparison:
    """Two budgets side by side (``stableins budget A.json --compare B.json``): ``other − base``."""

    base: NavigationBudget
    other: NavigationBudget
    labels: tuple[str, str] = ("", "")

    def report(self) -> str:
        """Return the side-by-side table (text)."""
        return _comparison_text(self)

    def __str__(self) -> str:
        return self.report()

    def to_dict(self) -> ComparisonDocument:
        """Return both budgets and the differences (JSON of ``--compare``)."""
        return _comparison_document(self)


def _step_for(duration: float, step: float) -> tuple[float, int]:
    count = max(1, int(math.ceil(duration / step - 1e-9)))
    if count > MAX_TIME_STEPS:
        count = MAX_TIME_STEPS
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
        except InputError:
            raise
        except NotDeterminedError:
            raise  # a described error passes through as it is (issue 29)
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


def _choose(calibration: CalibrationTerms, drift_sigma: Sequence[float] | None) -> tuple[list[_Chosen], list[LeftOut], BudgetDriftSource]:
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
        return chosen, left_out, BudgetDriftSource.GIVEN
    return chosen, left_out, BudgetDriftSource.RECORD if drift_ids & set(calibration.ids) else BudgetDriftSource.NONE


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
        Time grid [s] (at most :data:`MAX_TIME_STEPS` steps).
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


# --------------------------------------------------------------------------- how a budget shows itself
#: Columns of the text table: (header, quantity, peak or final).
_TABLE_COLUMNS = (
    ("pos peak", "position", "peak"),
    ("pos final", "position", "final"),
    ("vel peak", "velocity", "peak"),
    ("vel final", "velocity", "final"),
    ("pitch pk", "pitch", "peak"),
    ("roll pk", "roll", "peak"),
    ("head pk", "heading", "peak"),
    ("head final", "heading", "final"),
)


def _days(seconds: float) -> str:
    days = seconds / 86400.0
    return f"{number(days, 4)} d" if days >= 1 else f"{number(seconds / 3600.0, 4)} h"


def _scenario_text(budget: NavigationBudget) -> str:
    """One line: unit, duration, latitude, damping."""
    s = budget.scenario
    hemisphere = "N" if s.latitude >= 0 else "S"
    damping = f"damping ζ = {number(s.zeta, 3)}" if s.zeta > 0 else "undamped (pure inertial, ζ = 0)"
    vertical = "vertical channel held by a height reference" if s.vertical_gains is not None else "vertical channel left out"
    return (
        f"Navigation budget of {budget.serial_number or 'the unit'} over {_days(budget.duration)} at "
        f"{abs(math.degrees(s.latitude)):.4f}° {hemisphere}, {damping}, {vertical}"
    )


def _cell(summary: ErrorSummary, quantity: str, which: str) -> str:
    pf = summary[quantity]
    value = getattr(pf, which)
    return number(value / ARCSEC if quantity in ("pitch", "roll", "heading") else value, 3)


def _sigma_text(sigma: float, unit: str) -> str:
    return f"{number(sigma, 3)} {unit_text(unit)}".strip()


def _budget_text(budget: NavigationBudget, *, rows: int | None = None) -> str:
    """Return the ranked table of :meth:`NavigationBudget.report`."""
    head = ["term", "1σ"] + [c[0] for c in _TABLE_COLUMNS]
    body = []
    shown = budget.terms if rows is None else budget.terms[:rows]
    for t in shown:
        body.append([t.id, _sigma_text(t.sigma_engineering, t.unit)] + [_cell(t.summary, q, w) for _, q, w in _TABLE_COLUMNS])
    if rows is not None and len(budget.terms) > rows:
        body.append([f"({len(budget.terms) - rows} more)", ""] + [""] * len(_TABLE_COLUMNS))
    body.append(["RSS of the terms", ""] + [_cell(budget.rss, q, w) for _, q, w in _TABLE_COLUMNS])
    body.append(["total (correlated)", ""] + [_cell(budget.total, q, w) for _, q, w in _TABLE_COLUMNS])
    widths = [max(len(r[i]) for r in [head, *body]) for i in range(len(head))]
    line = lambda r: "  ".join(c.ljust(widths[i]) if i < 2 else c.rjust(widths[i]) for i, c in enumerate(r))  # noqa: E731
    lines = [
        _scenario_text(budget),
        "Each term: a residual of +1σ alone.  Position and velocity horizontal [m, m/s], attitude [arcsec] of a",
        "level, north-pointing INS; peak over the navigation time and the final value.",
        "",
        line(head),
        *(line(r) for r in body),
    ]
    notes = budget.notes
    if notes:
        lines.append("")
        lines.extend(f"note: {n}" for n in notes)
    return "\n".join(lines)


class ScenarioDocument(TypedDict):
    """The scenario of a budget in JSON (``stableins budget --json``, ``scenario``)."""

    latitude_deg: float
    gravity: float
    zeta: float
    radius: float
    vertical_loop: bool
    earth_angle_deg: float
    duration_s: float
    step_s: float


class TermDocument(TypedDict):
    """One term of a budget in JSON: its 1σ in its unit and the errors it alone makes (:class:`QuantityDocument` each)."""

    id: str
    kind: str
    sigma: float
    unit: str
    errors: dict[str, QuantityDocument]


class LeftOutDocument(TypedDict):
    """A term not propagated, and why."""

    id: str
    reason: str


class BudgetDocument(TypedDict):
    """The JSON document of ``stableins budget --json`` (engineering units: m, m/s, arcsec)."""

    serial_number: str
    scenario: ScenarioDocument
    drift: str
    terms: list[TermDocument]
    rss: dict[str, QuantityDocument]
    total: dict[str, QuantityDocument]
    left_out: list[LeftOutDocument]
    notes: list[str]


class DifferenceDocument(TypedDict):
    """``other − base`` of every term, of the RSS and of the total."""

    terms: dict[str, dict[str, QuantityDocument]]
    rss: dict[str, QuantityDocument]
    total: dict[str, QuantityDocument]


class ComparisonDocument(TypedDict):
    """The JSON of ``stableins budget A.json --compare B.json``: both budgets and the differences."""

    labels: list[str]
    base: BudgetDocument
    other: BudgetDocument
    difference: DifferenceDocument


def _scenario_document(budget: NavigationBudget) -> ScenarioDocument:
    s = budget.scenario
    return {
        "latitude_deg": math.degrees(s.latitude),
        "gravity": s.gravity,
        "zeta": s.zeta,
        "radius": s.radius,
        "vertical_loop": s.vertical_gains is not None,
        "earth_angle_deg": math.degrees(s.earth_angle),
        "duration_s": budget.duration,
        "step_s": budget.step,
    }


def _budget_html(budget: NavigationBudget) -> str:
    """Return the ranked table for Jupyter (:func:`stableins.display.html_result`)."""
    from stableins.display import html_result, html_table

    head = ["term", "1σ"] + [c[0] for c in _TABLE_COLUMNS]
    rows = [[t.id, _sigma_text(t.sigma_engineering, t.unit)] + [_cell(t.summary, q, w) for _, q, w in _TABLE_COLUMNS] for t in budget.terms]
    rows.append(["RSS of the terms", ""] + [_cell(budget.rss, q, w) for _, q, w in _TABLE_COLUMNS])
    rows.append(["total (correlated)", ""] + [_cell(budget.total, q, w) for _, q, w in _TABLE_COLUMNS])
    units = "position [m], velocity [m/s] (horizontal), attitude [arcsec]; +1σ of each term alone"
    table = html_table(head, rows, numeric=range(2, len(head)))
    return html_result(_scenario_text(budget), [units], [table], [("notes", list(budget.notes))])


def _budget_document(budget: NavigationBudget) -> BudgetDocument:
    """Return the JSON document (engineering units)."""
    return {
        "serial_number": budget.serial_number,
        "scenario": _scenario_document(budget),
        "drift": budget.drift.value,
        "terms": [
            {"id": t.id, "kind": t.kind.value, "sigma": t.sigma_engineering, "unit": t.unit, "errors": t.summary.to_dict()}
            for t in budget.terms
        ],
        "rss": budget.rss.to_dict(),
        "total": budget.total.to_dict(),
        "left_out": [{"id": item.id, "reason": item.reason} for item in budget.left_out],
        "notes": list(budget.notes),
    }


def _budget_figure(budget: NavigationBudget, path: str | None, *, top: int = 6, file_format: str | None = None) -> Any:
    """Three panels (horizontal position, horizontal velocity, heading): the largest error up to each time."""
    import matplotlib

    if path is not None:
        matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt
    import numpy as np

    from stableins.display import layout_with_caption

    panels = (
        (Quantity.POSITION, "horizontal position [m]", 1.0),
        (Quantity.VELOCITY, "horizontal velocity [m/s]", 1.0),
        (Quantity.HEADING, "heading [arcsec]", ARCSEC),
    )
    fig, axes = plt.subplots(1, 3, figsize=(13, 4.4))
    days = budget.time / 86400.0
    order = list(Quantity)
    shown = budget.terms[:top]
    for ax, (quantity, label, scale) in zip(axes, panels, strict=True):
        q = order.index(quantity)
        floor = None
        for k, term in enumerate(shown):
            series = np.maximum.accumulate(budget.responses[:, q, k]) / scale
            ax.plot(days, series, lw=1.2, label=f"{term.id} ({_sigma_text(term.sigma_engineering, term.unit)})")
            positive = series[series > 0]
            if positive.size:
                floor = positive.min() if floor is None else min(floor, positive.min())
        ax.plot(days, np.maximum.accumulate(budget.rss_series[:, q]) / scale, "k--", lw=1.6, label="RSS of the terms")
        ax.plot(days, np.maximum.accumulate(budget.total_series[:, q]) / scale, "k", lw=2.0, label="total (correlated)")
        ax.set_yscale("log")
        top_value = max(np.max(budget.rss_series[:, q]), np.max(budget.total_series[:, q])) / scale
        if top_value > 0:
            ax.set_ylim(max(floor or top_value * 1e-4, top_value * 1e-4), top_value * 2.0)
        ax.set_xlabel("navigation time [days]")
        ax.set_title(f"largest {label} up to t", fontsize=10)
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=7, loc="lower right")
    layout_with_caption(fig, _scenario_text(budget), top=0.88)
    if path is not None:
        fig.savefig(path, dpi=110, format=file_format)
        plt.close(fig)
    return fig


def _comparison_text(comparison: BudgetComparison) -> str:
    """Term by term: peak horizontal position and heading of both records and the difference (other − base)."""
    base, other = comparison.base, comparison.other
    ids = list(dict.fromkeys([t.id for t in base.terms] + [t.id for t in other.terms]))
    head = ["term", "1σ A", "1σ B", "pos pk A", "pos pk B", "B − A", "head pk A", "head pk B", "B − A"]
    rows = []

    def cells(a: Any, b: Any) -> list[str]:
        pa = a.position.peak if a else math.nan
        pb = b.position.peak if b else math.nan
        ha = a.heading.peak / ARCSEC if a else math.nan
        hb = b.heading.peak / ARCSEC if b else math.nan
        return [number(pa, 3), number(pb, 3), number(pb - pa, 3), number(ha, 3), number(hb, 3), number(hb - ha, 3)]

    for pid in ids:
        ta = next((t for t in base.terms if t.id == pid), None)
        tb = next((t for t in other.terms if t.id == pid), None)
        sa = _sigma_text(ta.sigma_engineering, ta.unit) if ta else "—"
        sb = _sigma_text(tb.sigma_engineering, tb.unit) if tb else "—"
        rows.append([pid, sa, sb, *cells(ta.summary if ta else None, tb.summary if tb else None)])
    rows.append(["RSS of the terms", "", "", *cells(base.rss, other.rss)])
    rows.append(["total (correlated)", "", "", *cells(base.total, other.total)])
    widths = [max(len(r[i]) for r in [head, *rows]) for i in range(len(head))]
    line = lambda r: "  ".join(c.ljust(widths[i]) if i == 0 else c.rjust(widths[i]) for i, c in enumerate(r))  # noqa: E731
    return "\n".join(
        [
            f"A: {comparison.labels[0] + ': ' if comparison.labels[0] else ''}{_scenario_text(base)}",
            f"B: {comparison.labels[1] + ': ' if comparison.labels[1] else ''}{other.serial_number or 'the unit'} in the same scenario",
            "Peak horizontal position [m] and heading [arcsec] per term (+1σ alone); B − A < 0: B's calibration leaves less.",
            "",
            line(head),
            *(line(r) for r in rows),
        ]
    )


def _comparison_document(comparison: BudgetComparison) -> ComparisonDocument:
    """JSON of a comparison: both budgets and the differences (other − base) of every peak and final."""
    base, other = comparison.base, comparison.other

    def difference(a: ErrorSummary | None, b: ErrorSummary | None) -> dict[str, QuantityDocument]:
        out: dict[str, QuantityDocument] = {}
        for q in Quantity:
            if a is None or b is None:
                out[q.value] = {"peak": None, "final": None, "unit": q.unit}
            else:
                out[q.value] = {"peak": (b[q].peak - a[q].peak) / q.scale, "final": (b[q].final - a[q].final) / q.scale, "unit": q.unit}
        return out

    ids = list(dict.fromkeys([t.id for t in base.terms] + [t.id for t in other.terms]))
    by_a = {t.id: t for t in base.terms}
    by_b = {t.id: t for t in other.terms}
    return {
        "labels": list(comparison.labels),
        "base": _budget_document(base),
        "other": _budget_document(other),
        "difference": {
            "terms": {
                pid: difference(by_a[pid].summary if pid in by_a else None, by_b[pid].summary if pid in by_b else None) for pid in ids
            },
            "rss": difference(base.rss, other.rss),
            "total": difference(base.total, other.total),
        },
    }
