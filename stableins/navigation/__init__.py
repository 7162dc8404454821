"""Navigation errors of a space-stable INS on a static base, and the navigation budget of a calibration.

Layer 0 (physics).  :mod:`~stableins.navigation.dynamics`: the INS error dynamics and the polar-aligned
platform; :mod:`~stableins.navigation.sources`: each error source as a harmonic forcing;
:mod:`~stableins.navigation.propagation`: their exact propagation; :mod:`~stableins.navigation.budget`: the
budget (docs/navigation-budget.md).  Not to be confused with :mod:`stableins.reporting.budget`, the
*uncertainty budget* of the calibration coefficients.
"""

from stableins.navigation.budget import (
    BudgetComparison,
    CalibrationTerms,
    NavigationBudget,
    NavigationErrors,
    navigation_budget,
    navigation_errors,
)
from stableins.navigation.dynamics import NavigationScenario
from stableins.navigation.sources import LeftOut
from stableins.navigation.summary import BudgetDriftSource, ErrorSummary, PeakFinal, Quantity, TermBudget

__all__ = [
    "BudgetComparison",
    "CalibrationTerms",
    "BudgetDriftSource",
    "ErrorSummary",
    "LeftOut",
    "NavigationBudget",
    "NavigationErrors",
    "NavigationScenario",
    "PeakFinal",
    "Quantity",
    "TermBudget",
    "navigation_budget",
    "navigation_errors",
]
