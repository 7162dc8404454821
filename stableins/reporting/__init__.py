"""PDF calibration reports (ISO/IEC 17025 7.8, GUM), built from a calibration record and its data.

``write_report`` is the entry point; see ``docs/reports.md`` for each section and its
source.  The layout uses reportlab (platypus) and the figures matplotlib; both are
imported only when a report is written.
"""

from __future__ import annotations

from typing import Any

__all__ = ["write_report"]


def write_report(*args: Any, **kwargs: Any) -> Any:
    """See :func:`stableins.reporting.builder.write_report`."""
    from stableins.reporting.builder import write_report as _write_report

    return _write_report(*args, **kwargs)
