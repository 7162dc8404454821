"""PDF calibration reports (ISO/IEC 17025 7.8, GUM), built from a calibration record and its data.

``write_report`` is the entry point; see ``docs/reports.md`` for each section and its
source.  The layout uses reportlab (platypus) and the figures matplotlib; both are
imported only when a report is written: ``stableins.reporting.write_report`` *is*
:func:`stableins.reporting.builder.write_report` (same signature and docstring), loaded on
first access (PEP 562).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # pragma: no cover
    from stableins.reporting.builder import ReportSummary, write_report

__all__ = ["ReportSummary", "write_report"]


def __getattr__(name: str) -> Any:
    if name in __all__:
        from stableins.reporting import builder

        return getattr(builder, name)
    raise AttributeError(f"module 'stableins.reporting' has no attribute {name!r}")
