"""The fleet and a unit's history as the web pages and the JSON API show them, from the history store.

Every number comes from the code ``stableins history`` runs: the record in force and the drifting parameters with
their significance from :meth:`HistoryStore.fleet` (the index alone: a fleet of 1,000 units is one query), a unit's
changes from :meth:`HistoryStore.changes` (:func:`stableins.history.compare`, the certificate's change statistic)
and its trends from :meth:`HistoryStore.trends` (:func:`stableins.history.trend`), every record read verified by its
SHA-256.  What is added here: the due date (:mod:`stableins.web.policy`) and the conformity the certificate of the
record in force states (:mod:`stableins.web.certificates`).  Values are shown in engineering units
(:meth:`stableins.terms.Term.to_engineering`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

from stableins.history import CHANGE_THRESHOLD, SECONDS_PER_YEAR
from stableins.history_store import DRIFT_SIGMAS, HistoryStore, UnitStatus
from stableins.web.certificates import CertificateIndex
from stableins.web.models import Document, Drifting, FleetUnit, ParameterChange, RecordChange, RecordEntry, TrendSeries, Unit
from stableins.web.policy import Policy


@dataclass(frozen=True)
class FleetRow:
    """One unit of the fleet page."""

    serial: str
    records: int
    in_force: str | None  # file of the record in force
    in_force_sha256: str | None
    procedure: str
    calibrated: str | None  # valid-from time of the record in force
    due: str | None  # due date (ISO 8601)
    days_left: float | None  # negative: overdue
    overdue: bool
    conformity: str  # the certificate's statement of the record in force ("" when no certificate is found)
    drifting: tuple[tuple[str, float], ...]  # (parameter, z of its drift per year)

    def to_json(self) -> FleetUnit:
        """Return the row as the API's document (:class:`~stableins.web.models.FleetUnit`)."""
        return FleetUnit(
            serial=self.serial,
            records=self.records,
            in_force=self.in_force,
            in_force_sha256=self.in_force_sha256,
            procedure=self.procedure,
            calibrated=self.calibrated,
            due=self.due,
            days_left=self.days_left,
            overdue=self.overdue,
            conformity=self.conformity or None,
            drifting=[Drifting(id=p, significance=z) for p, z in self.drifting],
        )


def fleet_rows(units: list[UnitStatus], policy: Policy, certificates: CertificateIndex, date: datetime | None = None) -> list[FleetRow]:
    """Return the units of :meth:`HistoryStore.fleet`, overdue first (most overdue first), then by due date, then by serial."""
    date = date or datetime.now(UTC)
    rows = []
    for unit in units:
        entry = unit.in_force
        if entry is None:
            rows.append(FleetRow(unit.serial, unit.records, None, None, "", None, None, None, True, "", unit.drifting))
            continue
        due = entry.time + policy.interval(unit.serial, entry.procedure)
        left = (due - date).total_seconds() / 86400.0
        found = [c for c in certificates.of_record(entry.sha256) if c.kind == "certificate"]
        conformity = found[0].verdict if found else ""
        rows.append(
            FleetRow(
                unit.serial,
                unit.records,
                entry.file,
                entry.sha256,
                entry.procedure,
                entry.valid_from,
                due.isoformat(),
                left,
                left < 0,
                conformity,
                unit.drifting,
            )  # fmt: skip
        )
    return sorted(rows, key=lambda r: (not r.overdue, r.days_left if r.days_left is not None else -math.inf, r.serial))


def select(
    rows: list[FleetRow], *, search: str = "", overdue: bool = False, drifting: bool = False, conformity: str = ""
) -> list[FleetRow]:
    """Return the rows a filter keeps: serial or procedure containing ``search`` (any case), overdue, drifting, a verdict."""
    needle = search.strip().lower()
    return [
        r
        for r in rows
        if (not needle or needle in r.serial.lower() or needle in r.procedure.lower())
        and (not overdue or r.overdue)
        and (not drifting or r.drifting)
        and (not conformity or r.conformity == conformity.upper())
    ]


def unit_document(store: HistoryStore, serial: str, policy: Policy, certificates: CertificateIndex) -> Unit:
    """Return a unit's page as the API's document (:class:`~stableins.web.models.Unit`).

    Its records (with their certificates), changes and trends.

    Raises
    ------
    InputError
        The serial number cannot name a unit, the unit has no records, or a record fails its SHA-256 check.
    """
    from stableins.discovery.library import all_terms
    from stableins.errors import InputError

    store.unit_directory(serial)
    entries = store.entries(serial)
    if not entries:
        raise InputError(f"no calibration records for unit {serial!r}", path=store.location)
    terms = all_terms()
    now = datetime.now(UTC)
    in_force = [e for e in entries if e.time <= now]
    current = in_force[-1] if in_force else None
    records = []
    for e in entries:
        records.append(
            RecordEntry(
                file=e.file,
                sha256=e.sha256,
                valid_from=e.valid_from,
                procedure=e.procedure,
                stages=list(e.stages),
                prior=e.prior,
                in_force=current is not None and e.sha256 == current.sha256,
                documents=[
                    Document(kind=c.kind, title=c.title, sha256=c.sha256, verdict=c.verdict or None, name=c.path.name)
                    for c in certificates.of_record(e.sha256)
                ],
            )
        )
    changes = []
    for old, new, comparison in store.changes(serial):
        changes.append(
            RecordChange(
                from_=old.file,
                to=new.file,
                valid_from=new.valid_from,
                relation=comparison.relation,
                parameters=[_change(terms.get(c.id), c) for c in comparison.changes],
                significant=list(comparison.significant),
                not_compared=list(comparison.skipped),
            )
        )
    due = None
    if current is not None:
        due = (current.time + policy.interval(serial, current.procedure)).isoformat()
    return Unit(
        serial=serial,
        store=store.location,
        in_force=None if current is None else current.file,
        due=due,
        interval_source=policy.source,
        change_threshold=CHANGE_THRESHOLD,
        drift_threshold=DRIFT_SIGMAS,
        records=records,
        changes=changes,
        trends=[_trend(terms.get(t.id), t) for t in store.trends(serial)],
    )


def _engineering(term: Any, value: float, *, sigma: bool = False) -> float:
    if term is None or not math.isfinite(value):
        return value
    return float(term.sigma_to_engineering(value) if sigma else term.to_engineering(value))


def _number(value: float) -> float | None:
    return value if math.isfinite(value) else None


def _change(term: Any, change: Any) -> ParameterChange:
    """One parameter's change between two records, in engineering units, with its significance z."""
    return ParameterChange(
        id=change.id,
        unit=term.unit if term is not None else change.unit,
        old=_number(_engineering(term, change.old)),
        new=_number(_engineering(term, change.new)),
        difference=_number(_engineering(term, change.difference, sigma=True)),
        sigma_difference=_number(_engineering(term, change.sigma_difference, sigma=True)),
        significance=_number(change.significance),
        significant=change.significant,
    )


def _trend(term: Any, trend: Any) -> TrendSeries:
    """One parameter's trend: the data-only points with σ, the records' values, the fitted line and its z."""
    line: list[float | None] = []
    if math.isfinite(trend.slope):
        years = [(d - trend.times[0]).total_seconds() / SECONDS_PER_YEAR for d in trend.times]
        weights = [1.0 / s**2 for s in trend.sigmas]
        mean_t = sum(w * y for w, y in zip(weights, years)) / sum(weights)
        mean_x = sum(w * x for w, x in zip(weights, trend.values)) / sum(weights)
        line = [_number(_engineering(term, mean_x + trend.slope * (y - mean_t))) for y in years]
    return TrendSeries(
        id=trend.id,
        unit=term.unit if term is not None else trend.unit,
        times=[t.isoformat() for t in trend.times],
        values=[_number(_engineering(term, v)) for v in trend.values],
        sigmas=[_number(_engineering(term, s, sigma=True)) for s in trend.sigmas],
        record_values=[_number(_engineering(term, v)) for v in trend.record_values],
        record_sigmas=[_number(_engineering(term, s, sigma=True)) for s in trend.record_sigmas],
        line=line,
        slope_per_year=_number(_engineering(term, trend.slope, sigma=True)),
        slope_sigma=_number(_engineering(term, trend.slope_sigma, sigma=True)),
        significance=_number(trend.significance),
        chi2_red_constant=_number(trend.chi2_red_constant),
        too_short=trend.too_short,
    )
