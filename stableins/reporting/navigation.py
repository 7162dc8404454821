"""The navigation budget of a calibration record, and the certificate's section "What this calibration means for navigation".

:func:`record_navigation_budget` reads what the budget needs from the record (the error model, values, covariance,
the site's latitude, gravity, damping and gimbal senses) and calls :func:`stableins.navigation.navigation_budget`
(docs/navigation-budget.md).  Not the uncertainty budget of the coefficients (:mod:`stableins.reporting.budget`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING

from stableins.errors import InputError

if TYPE_CHECKING:  # pragma: no cover
    from reportlab.platypus import Flowable

    from stableins.navigation import ErrorSummary, NavigationBudget, NavigationScenario
    from stableins.records import CalibrationRecord
    from stableins.reporting.context import ReportContext

#: Navigation time of the certificate's section [s] (five days, the issue's horizon).
CERTIFICATE_DURATION = 5 * 86400.0


def record_scenario(
    record: CalibrationRecord, *, latitude: float | None = None, zeta: float | None = None, path: str | None = None
) -> NavigationScenario:
    """Return the navigation scenario of a record's site, with ``latitude`` [rad] and damping ratio ``zeta`` replaced when given."""
    from stableins.conventions import normal_gravity
    from stableins.navigation import NavigationScenario

    if record.site is None:
        if latitude is None:
            raise InputError("the record has no site metadata: give the latitude (--latitude)", path=path, field="site.latitude")
        return NavigationScenario(latitude=latitude, gravity=float(normal_gravity(latitude, 0.0)), zeta=0.0 if zeta is None else zeta)
    return NavigationScenario.from_site(record.site, latitude=latitude, zeta=zeta)


def record_navigation_budget(
    record: CalibrationRecord,
    *,
    duration: float,
    latitude: float | None = None,
    zeta: float | None = None,
    drift_sigma: Sequence[float] | None = None,
    scenario: NavigationScenario | None = None,
    path: str | None = None,
) -> NavigationBudget:
    """Return the navigation budget of a record (docs/navigation-budget.md).

    Parameters
    ----------
    record : CalibrationRecord
    duration : float
        Navigation time [s].
    latitude : float, optional
        [rad]; default the record's site.
    zeta : float, optional
        Damping ratio; default the site's (0 when the site has none).
    drift_sigma : sequence of 3 float, optional
        Gyro drift 1σ per platform axis [rad/s], replacing the record's ``gyro_drift_*`` σ.
    scenario : NavigationScenario, optional
        Use this scenario instead (``--compare``: both records in the first record's scenario).
    path : str, optional
        The record's file, for messages.
    """
    from stableins.navigation import CalibrationTerms, navigation_budget

    scenario = scenario if scenario is not None else record_scenario(record, latitude=latitude, zeta=zeta, path=path)
    return navigation_budget(
        CalibrationTerms(record.error_model(), record.values(), record.ids, record.covariance),
        scenario,
        duration=duration,
        drift_sigma=drift_sigma,
        serial_number=record.serial_number,
    )


def latitude_text(latitude: float) -> str:
    """``40.0000° N``."""
    return f"{abs(math.degrees(latitude)):.4f}° {'N' if latitude >= 0 else 'S'}"


#: Terms the certificate's table shows (the largest by peak position error; the rest are in the totals).
CERTIFICATE_ROWS = 8


def navigation_section(ctx: ReportContext) -> list[Flowable]:
    """Section 11: what the calibration's uncertainty does to navigation (the navigation budget of the record in force)."""
    from reportlab.platypus import KeepTogether

    from stableins.conventions import ARCSEC
    from stableins.reporting.content import printed_unit
    from stableins.reporting.context import fmt
    from stableins.reporting.context import paragraph as p
    from stableins.reporting.document import escape, heading, table
    from stableins.reporting.symbols import markup

    out: list[Flowable] = [*heading("11  What this calibration means for navigation", room_mm=60)]
    record = ctx.record
    try:
        budget = record_navigation_budget(record, duration=CERTIFICATE_DURATION)
    except InputError as error:
        out.append(p(f"<b>Not evaluated</b>: {escape(error.message)}."))
        return out
    if not budget.terms:
        out.append(p("<b>Not evaluated</b>: the record carries no term that acts on navigation."))
        return out
    s = budget.scenario
    damping = f"horizontal loops damped with ζ = {s.zeta:g}" if s.zeta > 0 else "undamped (pure inertial)"
    drift = {
        "record": "the gyro drift σ the record carries",
        "none": "<b>no gyro drift</b>: the record carries none, so the figures are those of the accelerometer and gimbal "
        "calibration alone; on a real platform the drift usually dominates position and heading",
    }.get(budget.drift.value, "a given gyro drift σ")
    total = budget.total
    out.append(
        p(
            "Each term's standard uncertainty (1σ, section 4) is a residual the navigation computer keeps after compensating with "
            "this calibration. Propagated through the static-base error dynamics of a space-stable INS (platform polar aligned and "
            f"held in inertial space, {latitude_text(s.latitude)}, {damping}) over {CERTIFICATE_DURATION / 86400:g} days, with "
            f"{drift}, the calibration's uncertainty alone gives a horizontal position error of "
            f"<b>{fmt(total.position.peak)} m</b> (1σ, largest over the {CERTIFICATE_DURATION / 86400:g} days; "
            f"{fmt(total.position.final)} m at the end), velocity {fmt(total.velocity.peak)} m/s, pitch {fmt(total.pitch.peak / ARCSEC)}″, "
            f"roll {fmt(total.roll.peak / ARCSEC)}″ and heading {fmt(total.heading.peak / ARCSEC)}″ (with the record's correlations). "
            "These are not the unit's total navigation errors: noise, temperature and the vehicle's motion add to them."
        )
    )
    head: list[object] = [
        "Term",
        "1σ",
        "Position peak [m]",
        "Position final [m]",
        "Velocity peak [m/s]",
        "Pitch peak [″]",
        "Roll peak [″]",
        "Heading peak [″]",
    ]
    rows: list[list[object]] = [head]

    def cells(summary: ErrorSummary) -> list[object]:
        return [
            fmt(summary.position.peak),
            fmt(summary.position.final),
            fmt(summary.velocity.peak),
            fmt(summary.pitch.peak / ARCSEC),
            fmt(summary.roll.peak / ARCSEC),
            fmt(summary.heading.peak / ARCSEC),
        ]

    for term in budget.terms[:CERTIFICATE_ROWS]:
        rows.append(
            [
                markup(term.id),
                f"{fmt(term.sigma_engineering)} {escape(printed_unit(term.unit).replace('deg/h', '°/h'))}",
                *cells(term.summary),
            ]
        )
    rows.append(["RSS of the terms", "", *cells(budget.rss)])
    rows.append(["<b>Total</b> (correlated)", "", *cells(total)])
    grid = table(rows, [0.17, 0.13, 0.12, 0.12, 0.12, 0.11, 0.11, 0.12], align_right=tuple(range(2, 8)), markup=True)
    rest = len(budget.terms) - CERTIFICATE_ROWS
    notes = (
        f"The {CERTIFICATE_ROWS} largest of {len(budget.terms)} terms by peak position error"
        + (f"; the other {rest} are in the totals" if rest > 0 else "")
        + ". A +1σ residual of each term alone; errors of a level, north-pointing INS. RSS: the terms taken as independent; total: "
        "with the record's covariance (the calibration correlates terms it determines only in combination). Method: "
        "docs/navigation-budget.md; the same numbers as the navigation budget command on this record."
    )
    if budget.left_out:
        notes += " Not propagated: " + "; ".join(f"{markup(item.id)}: {escape(item.reason)}" for item in budget.left_out) + "."
    out.append(KeepTogether([grid, p(notes, "small")]))  # the table and its notes on one page
    return out
