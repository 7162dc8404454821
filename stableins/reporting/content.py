r"""The numbers a report states, computed from the record (no layout here).

* Parameter table: value, standard uncertainty ``u`` and expanded uncertainty
  ``U = k u`` (``k = 2``) in engineering units through :meth:`Term.to_engineering`;
  rounded per GUM 7.2.6 (``u`` to two significant digits, the value to the same place).
* Correlation matrix of the estimated parameters: ``ρ_ij = P_ij / (σ_i σ_j)``.
* Change since the previous calibration: ``Δ = x_new − x_old`` with
  ``u(Δ) = sqrt(u_new² + u_old²)`` (two calibrations with independent noise) and the
  normalized error ``E_n = |Δ| / sqrt(U_new² + U_old²)`` (ISO 13528:2022 9.7 with k = 2);
  ``E_n > 1`` is a significant change at about 95 %.
* Conformity against the procedure's tolerances (see :mod:`stableins.reporting.tolerances`).
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from stableins.errormodel import Term, known_terms  # noqa: F401 - known_terms is part of this module's interface (builder)
from stableins.reporting.evidence import StageEvidence
from stableins.reporting.record_view import RecordView
from stableins.reporting.tolerances import Tolerances, decide, limit_for

#: Coverage factor of the expanded uncertainty (GUM 6.2; about 95 % for a normal distribution).
COVERAGE_FACTOR = 2.0

MINUS = "\u2212"

STATUS_TEXT = {
    "estimated": "estimated",
    "fixed": "fixed",
    "gauge": "gauge",
    "unidentifiable": "not identifiable",
}

STATUS_WHY = {
    "fixed": "held at a stated value by the procedure (not estimated)",
    "gauge": "the data do not determine it; fixed by an explicit, documented gauge",
    "unidentifiable": "the data do not determine it; no value is stated",
}


@dataclass(frozen=True)
class ParameterRow:
    """One row of the results table, in engineering units (``nan`` where no value is stated)."""

    id: str
    meaning: str
    unit: str
    value: float
    u: float
    expanded: float
    status: str
    why: str

    @property
    def estimated(self) -> bool:
        return self.status == "estimated"

    def formatted(self) -> tuple[str, str, str]:
        """``(value, u, U)`` as text, rounded per GUM 7.2.6."""
        if self.status == "unidentifiable" or not math.isfinite(self.value):
            return "not stated", "—", "—"
        if self.status in ("fixed", "gauge") or not (self.u > 0):
            return f"{number(self.value, 6)}", "—", "—"
        return round_to_uncertainty(self.value, self.u), number(self.u, 2), number(self.expanded, 2)


def number(x: float, significant: int) -> str:
    """``x`` to ``significant`` significant digits, fixed-point, with a true minus sign."""
    if x == 0 or not math.isfinite(x):
        return "0" if x == 0 else str(x)
    decimals = max(significant - 1 - math.floor(math.log10(abs(x))), 0)
    return f"{x:.{decimals}f}".replace("-", MINUS)


def round_to_uncertainty(value: float, u: float) -> str:
    """The value rounded to the last digit of ``u`` given to two significant digits (GUM 7.2.6)."""
    decimals = max(1 - math.floor(math.log10(u)), 0)
    return f"{value:.{decimals}f}".replace("-", MINUS)


def parameter_rows(record: RecordView, terms: Mapping[str, Term], k: float = COVERAGE_FACTOR) -> list[ParameterRow]:
    """Results table rows in record order."""
    rows = []
    for p in record.parameters:
        term = terms.get(p.id)
        if term is not None:
            value = float(term.to_engineering(p.value)) if math.isfinite(p.value) else math.nan
            u = float(term.sigma_to_engineering(p.sigma)) if math.isfinite(p.sigma) else math.nan
            unit, meaning = unit_text(term.unit), term.meaning
        else:
            value, u, unit, meaning = p.value, p.sigma, p.unit or "SI", "parameter not in the standard model (SI units)"
        if p.status == "unidentifiable":  # the record may carry the prior value: never show it as a result
            value = u = math.nan
        why = p.note
        if not why and p.status != "estimated":
            mentions = [n for n in record.notes if re.search(rf"\b{re.escape(p.id)}\b", n)]
            why = "; ".join(mentions) or STATUS_WHY.get(p.status, "")
        rows.append(ParameterRow(p.id, meaning, unit, value, u, k * u if math.isfinite(u) else math.nan, p.status, why))
    return rows


def unit_text(unit: str) -> str:
    """Engineering unit as printed (``ug`` → ``µg``, ``^2`` → ``²``)."""
    return unit.replace("ug", "µg").replace("^2", "²").replace("^3", "³")


def unit_words(text: str) -> str:
    """:func:`unit_text` applied to the units inside a sentence (``ug`` only as a word of its own)."""
    return re.sub(r"(?<![A-Za-z])ug(?![A-Za-z])", "µg", text).replace("^2", "²").replace("^3", "³")


def correlation(record: RecordView) -> tuple[tuple[str, ...], list[list[float]]]:
    """Correlation matrix of the estimated parameters with a positive variance."""
    if not record.covariance_ids:
        return (), []
    status = {p.id: p.status for p in record.parameters}
    keep = [
        i
        for i, pid in enumerate(record.covariance_ids)
        if status.get(pid) == "estimated" and math.isfinite(record.covariance[i][i]) and record.covariance[i][i] > 0
    ]
    ids = tuple(record.covariance_ids[i] for i in keep)
    sigma = [math.sqrt(record.covariance[i][i]) for i in keep]
    matrix = [[record.covariance[i][j] / (sigma[a] * sigma[b]) for b, j in enumerate(keep)] for a, i in enumerate(keep)]
    return ids, matrix


@dataclass(frozen=True)
class Change:
    """Change of one parameter since the previous calibration (engineering units)."""

    id: str
    unit: str
    new: float
    old: float
    u_new: float
    u_old: float

    @property
    def delta(self) -> float:
        return self.new - self.old

    @property
    def u_delta(self) -> float:
        return math.hypot(self.u_new, self.u_old)

    @property
    def normalized_error(self) -> float:
        """``E_n = |Δ| / sqrt(U_new² + U_old²)`` with ``U = 2u``."""
        return abs(self.delta) / (COVERAGE_FACTOR * self.u_delta) if self.u_delta > 0 else math.inf

    @property
    def significant(self) -> bool:
        return self.normalized_error > 1.0


def compare(current: Sequence[ParameterRow], previous: Sequence[ParameterRow]) -> tuple[list[Change], list[str]]:
    """Changes of the parameters estimated in both calibrations, and the ids that could not be compared (with why)."""
    old = {r.id: r for r in previous}
    changes, skipped = [], []
    for row in current:
        before = old.get(row.id)
        if before is None:
            skipped.append(f"{row.id}: not in the previous record")
        elif not (row.estimated and before.estimated):
            skipped.append(f"{row.id}: {STATUS_TEXT[row.status]} now, {STATUS_TEXT[before.status]} before")
        else:
            changes.append(Change(row.id, row.unit, row.value, before.value, row.u, before.u))
    current_ids = {r.id for r in current}
    skipped += [f"{r.id}: only in the previous record" for r in previous if r.id not in current_ids]
    return changes, skipped


@dataclass(frozen=True)
class Check:
    """One conformity check."""

    kind: str  # "value", "uncertainty", "stability", "fit"
    subject: str
    measured: float
    expanded: float
    limit: float
    unit: str
    verdict: str  # pass, fail, conditional pass, conditional fail, not assessed
    reason: str = ""


def conformity(
    rows: Sequence[ParameterRow],
    changes: Sequence[Change] | None,
    stages: Sequence[StageEvidence],
    tolerances: Tolerances,
) -> list[Check]:
    """Every check the tolerances ask for, in table order."""
    rule, k = tolerances.decision_rule, tolerances.coverage_factor
    checks: list[Check] = []
    for row in rows:
        limit = limit_for(tolerances.limits, row.id)
        if limit is None:
            continue
        if not row.estimated:
            checks.append(Check("value", row.id, row.value, math.nan, limit, row.unit, "not assessed", STATUS_TEXT[row.status]))
        else:
            expanded = k * row.u
            checks.append(Check("value", row.id, row.value, expanded, limit, row.unit, decide(row.value, expanded, limit, rule)))
    for row in rows:
        limit = limit_for(tolerances.uncertainty, row.id)
        if limit is None:
            continue
        if not row.estimated:
            checks.append(Check("uncertainty", row.id, math.nan, math.nan, limit, row.unit, "not assessed", STATUS_TEXT[row.status]))
        else:
            expanded = k * row.u
            checks.append(Check("uncertainty", row.id, expanded, math.nan, limit, row.unit, "pass" if expanded <= limit else "fail"))
    if tolerances.stability:
        by_id = {c.id: c for c in changes or ()}
        for row in rows:
            limit = limit_for(tolerances.stability, row.id)
            if limit is None:
                continue
            change = by_id.get(row.id)
            if change is None:
                reason = "no previous calibration given" if changes is None else "not estimated in both calibrations"
                checks.append(Check("stability", row.id, math.nan, math.nan, limit, row.unit, "not assessed", reason))
            else:
                expanded = k * change.u_delta
                checks.append(
                    Check("stability", row.id, change.delta, expanded, limit, row.unit, decide(change.delta, expanded, limit, rule))
                )
    if tolerances.chi2_red_max is not None:
        if not stages:
            checks.append(Check("fit", "χ²_ν", math.nan, math.nan, tolerances.chi2_red_max, "", "not assessed", "no residual evidence"))
        for stage in stages:
            value = stage.chi2_red
            verdict = "pass" if value <= tolerances.chi2_red_max else "fail"
            checks.append(Check("fit", f"χ²_ν ({stage.stage})", value, math.nan, tolerances.chi2_red_max, "", verdict))
    return checks


def overall_verdict(checks: Sequence[Check]) -> str:
    """FAIL if any check fails; CONDITIONAL FAIL / CONDITIONAL PASS next; PASS when every assessed check passes."""
    verdicts = {c.verdict for c in checks}
    if not (verdicts - {"not assessed"}):
        return "NOT ASSESSED"
    for word in ("fail", "conditional fail", "conditional pass"):
        if word in verdicts:
            return word.upper()
    return "PASS"


def describe_procedure(procedure: Mapping[str, Any]) -> list[tuple[str, str]]:
    """Procedure and method as (label, text) pairs, in a fixed order, from whatever the record states."""
    labels = [
        ("name", "procedure"),
        ("version", "procedure version"),
        ("method", "method"),
        ("positions", "positions"),
        ("dwell", "dwell per position [s]"),
        ("coarse_dwell", "coarse dwell [s]"),
        ("fine_dwell", "fine dwell [s]"),
        ("settle", "settling time discarded [s]"),
        ("passes", "coarse passes"),
        ("stages", "stages run"),
        ("system_record_duration", "system-level record [s]"),
    ]
    out = []
    for key, label in labels:
        if key in procedure:
            value = procedure[key]
            if isinstance(value, list | tuple):
                value = ", ".join(map(str, value)) if len(value) <= 20 else f"{len(value)} entries"
            out.append((label, str(value)))
    known = {k for k, _ in labels}
    for key, value in procedure.items():
        if key not in known and isinstance(value, str | int | float):
            out.append((key.replace("_", " "), str(value)))
    return out
