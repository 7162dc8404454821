"""How the system stage's result shows itself (:mod:`stableins.display`): repr, HTML, DataFrame."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

from stableins.estimators.details import SystemDetails
from stableins.estimators.result import FitResult
from stableins.estimators.system.separation import Separation
from stableins.status import Status

if TYPE_CHECKING:
    from stableins.estimators.system.diagnostics import SystemDiagnostics


class SystemCalibrationView:
    """How a :class:`SystemCalibration` shows itself (:mod:`stableins.display`): repr, HTML, DataFrame."""

    result: FitResult
    combined: FitResult
    separation: Separation
    corrections: dict[str, float]
    notes: tuple[str, ...]
    diagnostics: SystemDiagnostics

    def _summary_lines(self) -> list[str]:
        d = self.diagnostics
        hours = d.duration / 3600.0
        sep = self.separation
        return [
            f"{hours:.2f} h record, {d.samples} samples; "
            f"separation χ²_ν = {sep.chi2 / max(sep.dof, 1):.2f} (ν = {sep.dof}); "
            f"the data determine {self.result.rank} of {len(self.result.terms)} directions of the {self._what()}"
        ]

    def _what(self) -> str:
        """Return what the result's terms are: the accelerometer terms, and the gyro drift when the record measured it."""
        drift = any(t.id.startswith("gyro_drift") for t in self.result.terms)
        return "accelerometer and gyro-drift terms" if drift else "accelerometer terms"

    def _rows(self) -> list[tuple[str, float, float, str, Status, str, str]]:
        """``(id, updated value, 1σ, unit, status, correction, determination)`` in engineering units."""
        how = self.result.details.determination if isinstance(self.result.details, SystemDetails) else {}
        rows = []
        for (pid, value, sigma, unit, status), term in zip(self.result.rows(), self.result.terms, strict=True):
            correction = self.corrections.get(pid)
            shown = "—" if correction is None else f"{float(term.sigma_to_engineering(correction)):+.4g}"
            rows.append((pid, value, sigma, unit, status, shown, str(how.get(pid) or "not seen")))
        return rows

    def __repr__(self) -> str:
        from stableins.display import clipped, parameter_lines, plural

        lines = [f"<SystemCalibration: the system stage's update of {len(self.result.terms)} {self._what()}>", *self._summary_lines()]
        lines += parameter_lines(r[:5] for r in self._rows())
        lines.append("combined coefficients [µrad]: " + ", ".join(f"{i} {v:+.2f}" for i, v, *_ in self.combined.rows()[:5]) + " …")
        more = f"{plural(len(self.notes), 'note')}; " if self.notes else ""
        return clipped(lines, f"({more}print(calibration.result) for the report, calibration.to_dataframe() for the table)")

    def _repr_html_(self) -> str:
        from stableins.display import html_result, html_table, unit_text, value_sigma

        rows = [
            [pid, value_sigma(v, s if st == Status.ESTIMATED else math.nan), correction, unit_text(u), str(st), how]
            for pid, v, s, u, st, correction, how in self._rows()
        ]
        parameters = html_table(
            ["parameter", "updated value ± 1σ", "correction", "unit", "status", "these data determine it"],
            rows,
            numeric=(1, 2),
            titles=[t.meaning for t in self.result.terms],
            status_column=4,
        )
        combined = html_table(
            ["combined coefficient", "value ± 1σ", "unit"],
            [[i, value_sigma(v, s), unit_text(u)] for i, v, s, u, _ in self.combined.rows()],
            numeric=(1,),
            titles=[t.meaning for t in self.combined.terms],
        )
        return html_result("System-level stage", self._summary_lines(), [parameters, combined], [("notes", self.notes)])

    def to_dataframe(self) -> Any:
        """Return the updated accelerometer terms as a table (:meth:`FitResult.to_dataframe`); needs pandas.

        With ``correction`` (engineering units) and ``determination`` (``alone``, ``in combination`` or ``not seen`` by
        these data).
        """
        frame = self.result.to_dataframe()
        terms = {t.id: t for t in self.result.terms}
        frame["correction"] = [
            float(terms[i].sigma_to_engineering(self.corrections[i])) if i in self.corrections else math.nan for i in frame.index
        ]
        how = self.result.details.determination if isinstance(self.result.details, SystemDetails) else {}
        frame["determination"] = [str(how.get(i) or "not seen") for i in frame.index]
        return frame


__all__ = ["SystemCalibrationView"]
