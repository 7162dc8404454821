"""Questions about a fleet answered from the index alone: which units are due, which drift."""

from __future__ import annotations

import math
from dataclasses import dataclass
from datetime import datetime, timedelta
from typing import Any

from stableins.history import parse_date, trend
from stableins.history_store.schema import HistoryEntry, entry_from_row

#: ``|drift| / σ`` beyond which a unit counts as drifting in fleet queries.
DRIFT_SIGMAS = 3.0


@dataclass(frozen=True)
class UnitStatus:
    """Where one unit of the fleet stands (:meth:`HistoryStore.fleet`).

    Attributes
    ----------
    serial : str
        The unit's serial number.
    records : int
        Records filed.
    in_force : HistoryEntry or None
        The record in force at the date asked about (None: none yet).
    age_days : float or None
        Age of the record in force at that date [days].
    due : bool
        No record in force, or one older than the age limit: recalibrate.
    drifting : tuple of (str, float)
        Parameters whose drift per year exceeds :data:`DRIFT_SIGMAS` of its σ, with the significance z.
    """

    serial: str
    records: int
    in_force: HistoryEntry | None
    age_days: float | None
    due: bool
    drifting: tuple[tuple[str, float], ...]


def fleet_status(
    rows: list[tuple[Any, ...]], values: list[tuple[Any, ...]], date: datetime, max_age: timedelta, drift_sigmas: float
) -> list[UnitStatus]:
    """Return where every unit stands at ``date``, from the index's record rows and data-only parameter values.

    Parameters
    ----------
    rows : list of tuple
        ``(id, serial, *ENTRY_COLUMNS)`` of every record, by serial and valid-from time.
    values : list of tuple
        ``(record, id, value, sigma)`` of every data-only estimate.
    date : datetime
        The date asked about.
    max_age : timedelta
        Age beyond which a unit is due.
    drift_sigmas : float
        ``|z|`` at which a parameter's drift counts.

    Returns
    -------
    list of UnitStatus
        One per unit, in the order of ``rows``.
    """
    by_record: dict[int, list[tuple[str, float, float]]] = {}
    for record_id, pid, value, sigma in values:
        by_record.setdefault(record_id, []).append((pid, value, sigma if sigma is not None else math.nan))
    units: dict[str, list[tuple[int, datetime, tuple[Any, ...]]]] = {}
    for row in rows:  # each time parsed once; an HistoryEntry is made only for the record in force
        units.setdefault(row[1], []).append((row[0], parse_date(row[3], "valid_from"), row))
    out = []
    for serial, items in units.items():
        earlier = [item for item in items if item[1] <= date]
        current = entry_from_row(earlier[-1][2][2:]) if earlier else None
        since = earlier[-1][1] if earlier else None
        age = (date - since).total_seconds() / 86400.0 if since is not None else None
        drifting = _drifting(items, by_record, drift_sigmas)
        due = since is None or (date - since) > max_age
        out.append(UnitStatus(serial, len(items), current, age, due, drifting))
    return out


def _drifting(
    items: list[tuple[int, datetime, tuple[Any, ...]]], by_record: dict[int, list[tuple[str, float, float]]], drift_sigmas: float
) -> tuple[tuple[str, float], ...]:
    """Return the parameters of one unit whose drift reaches ``drift_sigmas``, with their z, sorted by id."""
    series: dict[str, list[tuple[datetime, float, float]]] = {}
    for record_id, time, _ in items:
        for pid, value, sigma in by_record.get(record_id, []):
            if math.isfinite(sigma) and sigma > 0:
                series.setdefault(pid, []).append((time, value, sigma))
    drifting = []
    for pid, points in sorted(series.items()):
        if len(points) >= 2:
            z = trend(points, pid).significance
            if math.isfinite(z) and abs(z) >= drift_sigmas:
                drifting.append((pid, float(z)))
    return tuple(drifting)
