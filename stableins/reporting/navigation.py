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
    from stableins.navigation import NavigationBudget, NavigationScenario
    from stableins.records import CalibrationRecord

#: Navigation time of the certificate's section [s] (five days, the issue's horizon).
CERTIFICATE_DURATION = 5 * 86400.0


def record_scenario(
    record: CalibrationRecord, *, latitude: float | None = None, zeta: float | None = None, path: str | None = None
) -> NavigationScenario:
    """The navigation scenario of a record's site, with ``latitude`` [rad] and damping ratio ``zeta`` replaced when given."""
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
    """The navigation budget of a record (docs/navigation-budget.md).

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
    from stableins.navigation import navigation_budget

    scenario = scenario if scenario is not None else record_scenario(record, latitude=latitude, zeta=zeta, path=path)
    return navigation_budget(
        record.error_model(),
        record.values(),
        record.ids,
        record.covariance,
        scenario,
        duration=duration,
        drift_sigma=drift_sigma,
        serial_number=record.serial_number,
    )


def latitude_text(latitude: float) -> str:
    """``40.0000° N``."""
    return f"{abs(math.degrees(latitude)):.4f}° {'N' if latitude >= 0 else 'S'}"
