r"""Calibration history of each unit: change significance and drift across a unit's records.

The records themselves are kept by the history store (:mod:`stableins.history_store`: SQLite index, records
verified by their SHA-256 when read); ``HistoryStore`` and ``HistoryEntry`` are importable from :mod:`stableins.history_store`.  An entry
is *in force* from its ``valid_from`` time (the end of the data it was estimated from, or its creation time)
until the next entry's.  A record older than ``max_age`` at the date asked about is *stale*: it is still
returned, with a warning.

Significance of a change between two records (``old`` → ``new``) of a parameter
--------------------------------------------------------------------------------
One definition, used by ``stableins recal``, ``stableins history`` and the certificate
(:func:`compare`).  The two records are related in one of two ways, read from their stage runs:

* **independent** (no stage run in common): under "nothing changed" the difference has variance
  :math:`\sigma^2_\Delta = \sigma^2_{old} + \sigma^2_{new}`;
* **new descends from old** (every stage run of ``old`` is in ``new``: ``new`` is ``old`` updated by
  later stages, each a Bayesian update, :mod:`stableins.estimators.posterior`): the errors are
  correlated, :math:`\mathrm{Cov}(e_{new}, e_{old}) = P_{new}` (for one update
  :math:`(I - KH)P_0 = P_1`; by induction for a chain of them), so
  :math:`\mathrm{Var}(\hat x_{new} - \hat x_{old}) = P_{old} - P_{new}`.  A parameter no later stage
  saw has :math:`\Delta = 0` and :math:`\sigma_\Delta = 0`: it was not re-measured and is not compared.

Records that share some stage runs but not all (two branches from one calibration) cannot be
compared: their correlation is not recorded.  The significance is :math:`z = \Delta/\sigma_\Delta`
(standard normal under "no change"); a change is flagged when :math:`|z| \ge` :data:`CHANGE_THRESHOLD`
(3: a false-alarm probability of 0.27 % per parameter compared, two-sided).

Drift trend of a parameter across records
-----------------------------------------
Weighted least-squares line :math:`x_k = a + b\,(t_k - \bar t) + e_k`, weights
:math:`1/\sigma_k^2`, using each record's *data-only* estimate (:func:`data_only`: the
likelihoods of the stages its calibration ran, summed) so that the points are independent.
:math:`\sigma_b = (\sum w_k (t_k - \bar t)^2)^{-1/2}`, significance :math:`z = b/\sigma_b`;
:math:`\chi^2_\nu` of the constant model says whether the scatter exceeds the σ's.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import datetime, timedelta
from typing import TYPE_CHECKING, Any, TypedDict

from stableins.errors import InputError
from stableins.identifiers import parse_timestamp
from stableins.status import Status

if TYPE_CHECKING:  # pragma: no cover
    from matplotlib.figure import Figure

    from stableins.records import CalibrationRecord

#: ``|z|`` at and beyond which a change since the previous calibration is flagged (0.27 % false alarms per parameter).
CHANGE_THRESHOLD = 3.0
#: Default age after which the record in force is reported stale.
DEFAULT_MAX_AGE = timedelta(days=180)
SECONDS_PER_YEAR = 365.25 * 86400.0
#: The shortest span of records over which a drift per year is stated: two records minutes apart say nothing about a
#: year (their difference over 55 s, scaled to a year, is noise times 5.7e5), and a calibration interval is months.
MIN_DRIFT_SPAN_DAYS = 30.0


def parse_date(text: str, field: str = "date") -> datetime:
    """ISO 8601 date or date-time; naive times are UTC (:func:`stableins.identifiers.parse_timestamp`)."""
    return parse_timestamp(text, field=field)


class ChangeDocument(TypedDict):
    """A :class:`Change` as JSON: its fields, then its difference, significance and flag."""

    id: str
    unit: str
    old: float
    new: float
    sigma_old: float
    sigma_new: float
    sigma_difference: float
    correlated: bool
    difference: float
    significance: float
    significant: bool


@dataclass(frozen=True)
class Change:
    """Change of one parameter between two records and its significance (SI)."""

    id: str
    unit: str
    old: float
    new: float
    sigma_old: float
    sigma_new: float
    sigma_difference: float
    correlated: bool

    @property
    def difference(self) -> float:
        """New value minus old value [SI]."""
        return self.new - self.old

    @property
    def significance(self) -> float:
        """Difference in σ of the difference (NaN when not determinable)."""
        if not (self.sigma_difference > 0):
            return math.nan
        return self.difference / self.sigma_difference

    @property
    def significant(self) -> bool:
        """``|z| ≥`` :data:`CHANGE_THRESHOLD` (the flag of ``recal``, ``history`` and the certificate)."""
        return abs(self.significance) >= CHANGE_THRESHOLD

    def to_json(self) -> ChangeDocument:
        """Return the change as JSON values, with its difference, significance and flag."""
        return {
            "id": self.id,
            "unit": self.unit,
            "old": self.old,
            "new": self.new,
            "sigma_old": self.sigma_old,
            "sigma_new": self.sigma_new,
            "sigma_difference": self.sigma_difference,
            "correlated": self.correlated,
            "difference": self.difference,
            "significance": self.significance,
            "significant": self.significant,
        }


@dataclass(frozen=True)
class Comparison:
    """The changes between two records, how they are related, and what could not be compared (with why)."""

    relation: str  # "independent" or "descendant"
    changes: tuple[Change, ...]
    skipped: tuple[str, ...]

    @property
    def significant(self) -> tuple[str, ...]:
        """Ids of the parameters whose change is significant."""
        return tuple(c.id for c in self.changes if c.significant)

    def describe(self) -> str:
        """Return how σ(change) was computed for this relation, for people."""
        if self.relation == "descendant":
            return "the new record updates the old one (Bayesian update): σ²(change) = σ²_old − σ²_new"
        return "independent calibrations: σ²(change) = σ²_old + σ²_new"


@dataclass(frozen=True)
class Trend:
    """Weighted linear drift of one parameter across records (SI, per year)."""

    id: str
    unit: str
    times: tuple[datetime, ...]
    values: tuple[float, ...]
    sigmas: tuple[float, ...]
    slope: float
    slope_sigma: float
    chi2_red_constant: float
    #: the values the records themselves state (after every Bayesian update), beside the data-only ``values`` the
    #: drift is fitted to; empty when not given
    record_values: tuple[float, ...] = ()
    record_sigmas: tuple[float, ...] = ()

    @property
    def span_days(self) -> float:
        """Days from the first record to the last."""
        return (self.times[-1] - self.times[0]).total_seconds() / 86400.0 if self.times else 0.0

    @property
    def too_short(self) -> bool:
        """Whether the records span less than :data:`MIN_DRIFT_SPAN_DAYS`: no drift per year is stated."""
        return self.span_days < MIN_DRIFT_SPAN_DAYS

    @property
    def significance(self) -> float:
        """Slope in σ of the slope (NaN when not determinable)."""
        return self.slope / self.slope_sigma if self.slope_sigma > 0 else math.nan


# --------------------------------------------------------------------------- significance
def relation(old: CalibrationRecord, new: CalibrationRecord) -> str:
    """``"descendant"`` (every stage run of ``old`` is in ``new``), ``"independent"`` (none), else InputError."""
    old_runs = {s.id for s in old.stages}
    new_runs = {s.id for s in new.stages}
    if old_runs and old_runs <= new_runs:
        return "descendant"
    if not old_runs & new_runs:
        return "independent"
    raise InputError(
        f"the records share {len(old_runs & new_runs)} of {len(old_runs)} stage runs: one does not descend from the other and they "
        "are not independent, so the correlation of their errors is not known",
        field="stages",
        expected="a record and one it was updated from, or two independent calibrations",
    )


def compare(old: CalibrationRecord, new: CalibrationRecord) -> Comparison:
    """Every parameter both records estimate, old → new, with σ of the difference (module docstring)."""
    kind = relation(old, new)
    old_runs = {s.id for s in old.stages}
    changes, skipped = [], []
    for p in new.parameters:
        if p.id not in old.ids:
            skipped.append(f"{p.id}: not in the previous record")
            continue
        q = old[p.id]
        if p.status is not Status.ESTIMATED or q.status is not Status.ESTIMATED:
            skipped.append(f"{p.id}: {p.status.value} now, {q.status.value} before")
            continue
        if kind == "descendant":
            if all(d.stage in old_runs for d in p.determined_by):
                skipped.append(f"{p.id}: not re-measured (carried over from {new.source_text(p.id).removesuffix(', carried over')})")
                continue
            variance = q.sigma**2 - p.sigma**2
            sigma = math.sqrt(variance) if variance > 0 else math.nan
        else:
            sigma = math.hypot(q.sigma, p.sigma)
        changes.append(Change(p.id, p.unit, q.value, p.value, q.sigma, p.sigma, sigma, kind == "descendant"))
    new_ids = set(new.ids)
    skipped += [f"{q.id}: only in the previous record" for q in old.parameters if q.id not in new_ids]
    return Comparison(kind, tuple(changes), tuple(skipped))


def format_changes(changes: Sequence[Change]) -> str:
    """Table of changes in engineering units where the id is a known term."""
    from stableins.discovery.library import all_terms

    terms = all_terms()  # discovered terms in engineering units too
    lines = [f"{'parameter':<12} {'old':>14} {'new':>14} {'change':>12} {'σ(change)':>10} {'unit':<8} {'z':>6}"]
    for c in changes:
        term = terms.get(c.id)
        unit = term.unit if term else c.unit
        z = c.significance
        flag = f"  <-- significant (|z| ≥ {CHANGE_THRESHOLD:g})" if c.significant else ""
        old, new = _value(term, c.old), _value(term, c.new)
        difference, sigma = _spread(term, c.difference), _spread(term, c.sigma_difference)
        lines.append(f"{c.id:<12} {old:>14.4f} {new:>14.4f} {difference:>12.4f} {sigma:>10.4f} {unit:<8} {z:>6.2f}{flag}")
    return "\n".join(lines)


def _value(term: Any, value: Any) -> Any:
    """SI → engineering unit for a known term (arrays too); unchanged otherwise."""
    import numpy as np

    return term.to_engineering(value) if term is not None else np.asarray(value, dtype=float)


def _spread(term: Any, value: Any) -> Any:
    """SI σ or difference → engineering unit for a known term; unchanged otherwise."""
    import numpy as np

    return term.sigma_to_engineering(value) if term is not None else np.asarray(value, dtype=float)


def trend(points: list[tuple[datetime, float, float]], parameter: str = "", unit: str = "") -> Trend:
    """Weighted straight-line drift of ``(time, value, sigma)`` points (module docstring).

    Over a span shorter than :data:`MIN_DRIFT_SPAN_DAYS` no drift is stated (slope NaN, :attr:`Trend.too_short`).
    """
    times = [p[0] for p in points]  # plain floats: a fleet asks this of thousands of short series (numpy costs more there)
    t = [(p[0] - times[0]).total_seconds() / SECONDS_PER_YEAR for p in points]
    x = [float(p[1]) for p in points]
    s = [float(p[2]) for p in points]
    short = len(points) >= 2 and (max(times) - min(times)).total_seconds() < MIN_DRIFT_SPAN_DAYS * 86400.0
    if len(points) < 2 or not all(sk > 0 for sk in s) or short:
        return Trend(parameter, unit, tuple(times), tuple(x), tuple(s), math.nan, math.nan, math.nan)
    w = [1.0 / sk**2 for sk in s]
    total = sum(w)
    mean_t = sum(wk * tk for wk, tk in zip(w, t)) / total
    dt = [tk - mean_t for tk in t]
    sxx = sum(wk * dk**2 for wk, dk in zip(w, dt))
    mean_x = sum(wk * xk for wk, xk in zip(w, x)) / total
    chi2_constant = sum(wk * (xk - mean_x) ** 2 for wk, xk in zip(w, x)) / (len(x) - 1)
    if sxx <= 0:
        return Trend(parameter, unit, tuple(times), tuple(x), tuple(s), math.nan, math.nan, chi2_constant)
    slope = sum(wk * dk * (xk - mean_x) for wk, dk, xk in zip(w, dt, x)) / sxx
    return Trend(parameter, unit, tuple(times), tuple(x), tuple(s), slope, 1.0 / math.sqrt(sxx), chi2_constant)


def data_only(record: CalibrationRecord) -> dict[str, tuple[float, float]]:
    """``{id: (value, σ)}`` that the record's own calibration determines from its data alone (independent across records).

    The likelihoods of the stages run in the record's calibration are summed; a parameter they determine by
    themselves gives its data-only estimate.  A calibration without a prior (its first stage had none) is its
    own data-only estimate; stage runs without a likelihood (migrated records) give the record's values.
    """
    import numpy as np

    from stableins.estimators.result import Likelihood

    runs = record.stages_run
    if record.calibration.prior is None and all(s.likelihood is None for s in runs):
        return {p.id: (p.value, p.sigma) for p in record.parameters if p.status is Status.ESTIMATED and p.sigma > 0}
    likelihoods = [s.likelihood for s in runs if s.likelihood is not None]
    if not likelihoods:
        return {}
    ids = list(dict.fromkeys(i for lik in likelihoods for i in lik.ids))
    gauge = {p.id: p.value for p in record.parameters if p.status is Status.GAUGE}
    n = len(ids)
    information, gradient, point = np.zeros((n, n)), np.zeros(n), np.array([record[i].value if i in record.ids else 0.0 for i in ids])
    for lik in likelihoods:
        k = [ids.index(i) for i in lik.ids]
        information[np.ix_(k, k)] += lik.information
        gradient[k] += lik.gradient + lik.information @ (lik.point - point[k])
    combined = Likelihood(tuple(ids), point, information, gradient).conditioned({i: v for i, v in gauge.items() if i in ids})
    values, sigmas = combined.data_only()
    return {i: (float(v), float(s)) for i, v, s in zip(combined.ids, values, sigmas, strict=True) if np.isfinite(v) and s > 0}


def format_trends(trends: list[Trend]) -> str:
    """Return the drift table in engineering units: records, drift per year, σ, z and χ²_ν of a constant."""
    from stableins.discovery.library import all_terms

    terms = all_terms()  # discovered terms in engineering units too
    short = [t for t in trends if t.too_short]
    if short and len(short) == len(trends):
        span = max(t.span_days for t in trends)
        return (
            f"no drift stated: the records span {_span_text(span)}, less than the {MIN_DRIFT_SPAN_DAYS:g} days a drift per year "
            "needs (a difference over minutes, scaled to a year, is noise)"
        )
    lines = [f"{'parameter':<12} {'records':>7} {'drift / year':>14} {'σ':>10} {'unit':<8} {'z':>6} {'χ²_ν const':>10}"]
    for t in trends:
        term = terms.get(t.id)
        unit = term.unit if term else t.unit
        if t.too_short:
            lines.append(f"{t.id:<12} {len(t.values):>7} {'—':>14} {'—':>10} {unit:<8} {'—':>6}  (span {_span_text(t.span_days)})")
            continue
        z = t.significance
        flag = "  <-- drifting" if abs(z) >= 3 else ""
        slope, sigma = float(_spread(term, t.slope)), float(_spread(term, t.slope_sigma))
        lines.append(f"{t.id:<12} {len(t.values):>7} {slope:>14.4f} {sigma:>10.4f} {unit:<8} {z:>6.2f} {t.chi2_red_constant:>10.2f}{flag}")
    return "\n".join(lines)


def _span_text(days: float) -> str:
    """Return a span of time for people: seconds, hours or days."""
    seconds = days * 86400.0
    if seconds < 3600.0:
        return f"{seconds:.0f} s"
    return f"{seconds / 3600.0:.1f} h" if seconds < 86400.0 else f"{days:.1f} d"


def plot_trends(trends: list[Trend], serial: str) -> Figure:
    """One panel per parameter: values ±1σ against date and the fitted drift line."""
    import matplotlib.pyplot as plt
    import numpy as np

    from stableins.discovery.library import all_terms

    terms = all_terms()  # discovered terms in engineering units too
    n = max(1, len(trends))
    columns = min(3, n)
    rows = math.ceil(n / columns)
    fig, axes = plt.subplots(rows, columns, figsize=(4.5 * columns, 2.8 * rows), squeeze=False)
    for ax, t in zip(axes.flat, trends):
        term = terms.get(t.id)
        if t.record_values:  # what each record states, and the data-only estimates the drift is fitted to
            ax.errorbar(t.times, _value(term, t.record_values), yerr=_spread(term, t.record_sigmas), fmt="o", ms=4, capsize=2,
                        label="record")  # fmt: skip
            if not np.allclose(t.record_values, t.values, rtol=0.0, atol=1e-3 * float(np.min(t.sigmas))):
                ax.errorbar(t.times, _value(term, t.values), yerr=_spread(term, t.sigmas), fmt="s", ms=3, mfc="none", capsize=2,
                            alpha=0.7, label="its data alone")  # fmt: skip
        else:
            ax.errorbar(t.times, _value(term, t.values), yerr=_spread(term, t.sigmas), fmt="o", ms=4, capsize=2)
        if math.isfinite(t.slope):
            years = np.array([(d - t.times[0]).total_seconds() / SECONDS_PER_YEAR for d in t.times])
            w = 1.0 / np.asarray(t.sigmas) ** 2
            mean_t = np.sum(w * years) / np.sum(w)
            mean_x = np.sum(w * np.asarray(t.values)) / np.sum(w)
            line = mean_x + t.slope * (years - mean_t)
            ax.plot(t.times, _value(term, line), "-", lw=1, label=f"{t.significance:+.1f}σ drift")
        elif t.too_short:
            ax.set_xlabel(f"span {_span_text(t.span_days)}: no drift stated", fontsize=7)
        if t.record_values or math.isfinite(t.slope):
            ax.legend(fontsize=7)
        ax.set_title(f"{_mathtext(t.id)} [{_unit_text(term.unit if term else t.unit)}]", fontsize=9)
        ax.tick_params(axis="x", labelrotation=30, labelsize=7)
    for ax in list(axes.flat)[len(trends) :]:
        ax.set_visible(False)
    fig.suptitle(f"calibration history of {serial}")
    fig.tight_layout()
    return fig


def _mathtext(parameter: str) -> str:
    """Return a parameter id as matplotlib mathtext (``sf_x`` → sf with subscript x), never with a literal underscore."""
    base, _, sub = parameter.partition("_")
    return base if not sub else f"{base}$_{{{sub.replace('_', ',')}}}$"


def _unit_text(unit: str) -> str:
    """Return an engineering unit as printed (µg, °/h)."""
    return unit.replace("ug", "µg").replace("^2", "²").replace("^3", "³").replace("deg/h", "°/h")
