r"""Calibration history of each unit: change significance and drift across a unit's records.

The records themselves are kept by the history store (:mod:`stableins.history_store`: SQLite index, records
verified by their SHA-256 when read); ``HistoryStore`` and ``Entry`` are importable from here too.  An entry
is *in force* from its ``valid_from`` time (the end of the data it was estimated from, or its creation time)
until the next entry's.  A record older than ``max_age`` at the date asked about is *stale*: it is still
returned, with a warning.

Significance of a change between two records (``old`` → ``new``) of a parameter
------------------------------------------------------------------------------
Independent calibrations: under "nothing changed" the difference has variance
:math:`\sigma^2_\Delta = \sigma^2_{old} + \sigma^2_{new}`.  A recalibration that used the old
record as its prior (:mod:`stableins.recalibration`) is correlated with it: for the linear
Gaussian update :math:`\hat x_1 = \hat x_0 + K(y - H\hat x_0)` the errors obey
:math:`\mathrm{Cov}(e_1, e_0) = (I - KH)P_0 = P_1`, so
:math:`\mathrm{Var}(\hat x_1 - \hat x_0) = P_0 + P_1 - 2P_1 = P_0 - P_1`.
The significance is :math:`z = \Delta / \sigma_\Delta` (a standard normal under "no change").

Drift trend of a parameter across records
-----------------------------------------
Weighted least-squares line :math:`x_k = a + b\,(t_k - \bar t) + e_k`, weights
:math:`1/\sigma_k^2`, using each record's *data-only* estimate where one is kept (a
recalibration stores it beside the record) so that the points are independent.
:math:`\sigma_b = (\sum w_k (t_k - \bar t)^2)^{-1/2}`, significance :math:`z = b/\sigma_b`;
:math:`\chi^2_\nu` of the constant model says whether the scatter exceeds the σ's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from typing import TYPE_CHECKING, Any

from stableins.data.errors import InputError

if TYPE_CHECKING:  # pragma: no cover
    from matplotlib.figure import Figure

    from stableins.records import CalibrationRecord

#: Default age after which the record in force is reported stale.
DEFAULT_MAX_AGE = timedelta(days=180)
SECONDS_PER_YEAR = 365.25 * 86400.0


def parse_date(text: str, field: str = "date") -> datetime:
    """ISO 8601 date or date-time; naive times are UTC."""
    try:
        value = datetime.fromisoformat(text.replace("Z", "+00:00"))
    except (ValueError, AttributeError):
        raise InputError(
            f"cannot read {text!r} as a date", field=field, expected="ISO 8601, e.g. 2026-03-01 or 2026-03-01T12:00:00Z"
        ) from None
    return value if value.tzinfo else value.replace(tzinfo=UTC)


@dataclass(frozen=True)
class Change:
    """Change of one parameter between two records and its significance."""

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
        return self.new - self.old

    @property
    def significance(self) -> float:
        """Difference in σ of the difference (NaN when not determinable)."""
        if not (self.sigma_difference > 0):
            return math.nan
        return self.difference / self.sigma_difference


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

    @property
    def significance(self) -> float:
        return self.slope / self.slope_sigma if self.slope_sigma > 0 else math.nan


# --------------------------------------------------------------------------- significance
def compare(old: CalibrationRecord, new: CalibrationRecord, prior_used: bool = False) -> list[Change]:
    """Every parameter both records determine, old → new, with σ of the difference (module docstring)."""
    changes = []
    for p in new.parameters:
        if p.id not in old.ids:
            continue
        q = old[p.id]
        if p.status != "estimated" or q.status != "estimated":  # gauge, fixed or unidentifiable: not an estimate to compare
            continue
        if prior_used:
            variance = q.sigma**2 - p.sigma**2
            sigma = math.sqrt(variance) if variance > 0 else math.nan
        else:
            sigma = math.hypot(q.sigma, p.sigma)
        changes.append(Change(p.id, p.unit, q.value, p.value, q.sigma, p.sigma, sigma, prior_used))
    return changes


def format_changes(changes: list[Change]) -> str:
    """Table of changes in engineering units where the id is a known term."""
    from stableins.errormodel import known_terms

    terms = known_terms()
    lines = [f"{'parameter':<12} {'old':>14} {'new':>14} {'change':>12} {'σ(change)':>10} {'unit':<8} {'z':>6}"]
    for c in changes:
        term = terms.get(c.id)
        unit = term.unit if term else c.unit
        z = c.significance
        flag = "  <-- significant" if abs(z) >= 3 else ""
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
    """Weighted straight-line drift of ``(time, value, sigma)`` points (module docstring)."""
    import numpy as np

    times = [p[0] for p in points]
    t = np.array([(p[0] - times[0]).total_seconds() / SECONDS_PER_YEAR for p in points])
    x = np.array([p[1] for p in points])
    s = np.array([p[2] for p in points])
    if len(points) < 2 or not np.all(s > 0):
        return Trend(parameter, unit, tuple(times), tuple(x), tuple(s), math.nan, math.nan, math.nan)
    w = 1.0 / s**2
    mean_t = np.sum(w * t) / np.sum(w)
    dt = t - mean_t
    sxx = np.sum(w * dt**2)
    mean_x = np.sum(w * x) / np.sum(w)
    chi2_constant = float(np.sum(w * (x - mean_x) ** 2) / (len(x) - 1))
    if sxx <= 0:
        return Trend(parameter, unit, tuple(times), tuple(x), tuple(s), math.nan, math.nan, chi2_constant)
    slope = float(np.sum(w * dt * (x - mean_x)) / sxx)
    return Trend(
        parameter, unit, tuple(times), tuple(map(float, x)), tuple(map(float, s)), slope, float(1.0 / math.sqrt(sxx)), chi2_constant
    )


def format_trends(trends: list[Trend]) -> str:
    from stableins.errormodel import known_terms

    terms = known_terms()
    lines = [f"{'parameter':<12} {'records':>7} {'drift / year':>14} {'σ':>10} {'unit':<8} {'z':>6} {'χ²_ν const':>10}"]
    for t in trends:
        term = terms.get(t.id)
        unit = term.unit if term else t.unit
        z = t.significance
        flag = "  <-- drifting" if abs(z) >= 3 else ""
        slope, sigma = float(_spread(term, t.slope)), float(_spread(term, t.slope_sigma))
        lines.append(f"{t.id:<12} {len(t.values):>7} {slope:>14.4f} {sigma:>10.4f} {unit:<8} {z:>6.2f} {t.chi2_red_constant:>10.2f}{flag}")
    return "\n".join(lines)


def plot_trends(trends: list[Trend], serial: str) -> Figure:
    """One panel per parameter: values ±1σ against date and the fitted drift line."""

    import matplotlib.pyplot as plt
    import numpy as np

    from stableins.errormodel import known_terms

    terms = known_terms()
    n = max(1, len(trends))
    columns = min(3, n)
    rows = math.ceil(n / columns)
    fig, axes = plt.subplots(rows, columns, figsize=(4.5 * columns, 2.8 * rows), squeeze=False)
    for ax, t in zip(axes.flat, trends):
        term = terms.get(t.id)
        ax.errorbar(t.times, _value(term, t.values), yerr=_spread(term, t.sigmas), fmt="o", ms=4, capsize=2)
        if math.isfinite(t.slope):
            years = np.array([(d - t.times[0]).total_seconds() / SECONDS_PER_YEAR for d in t.times])
            w = 1.0 / np.asarray(t.sigmas) ** 2
            mean_t = np.sum(w * years) / np.sum(w)
            mean_x = np.sum(w * np.asarray(t.values)) / np.sum(w)
            line = mean_x + t.slope * (years - mean_t)
            ax.plot(t.times, _value(term, line), "-", lw=1, label=f"{t.significance:+.1f}σ drift")
            ax.legend(fontsize=7)
        ax.set_title(f"{t.id} [{term.unit if term else t.unit}]", fontsize=9)
        ax.tick_params(axis="x", labelrotation=30, labelsize=7)
    for ax in list(axes.flat)[len(trends) :]:
        ax.set_visible(False)
    fig.suptitle(f"calibration history of {serial}")
    fig.tight_layout()
    return fig


#: The store lives in :mod:`stableins.history_store`; these names are importable from here as well.
_STORE_NAMES = ("HistoryStore", "Entry", "UnitStatus", "default_store", "INDEX_NAME", "INDEX_FORMAT", "STORE_NAME")


def __getattr__(name: str) -> Any:
    if name in _STORE_NAMES:
        from stableins import history_store

        return getattr(history_store, name)
    raise AttributeError(f"module 'stableins.history' has no attribute {name!r}")
