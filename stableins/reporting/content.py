r"""The numbers a report states, computed from the record (no layout here).

* Parameter table: value, standard uncertainty ``u`` and expanded uncertainty
  ``U = k u`` (``k = 2``) in engineering units through :meth:`Term.to_engineering`;
  rounded per GUM 7.2.6 (``u`` to two significant digits, the value to the same place).
* Correlation matrix of the estimated parameters: ``ρ_ij = P_ij / (σ_i σ_j)``.
* Change since the previous calibration: :func:`stableins.history.compare`, the one definition
  ``recal`` and ``history`` use (σ of a change from how the records are related; flagged at
  ``|z| ≥ 3``), shown here in engineering units.
* Conformity against the procedure's tolerances (see :mod:`stableins.reporting.tolerances`).
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from enum import StrEnum
from typing import TYPE_CHECKING, Any

from stableins.errormodel import Term, known_terms  # noqa: F401 - known_terms is part of this module's interface (builder)
from stableins.history import Comparison
from stableins.records import CalibrationRecord
from stableins.reporting.evidence import StageEvidence
from stableins.reporting.rounding import COVERAGE_FACTOR, Rounded, gum, significant_digits
from stableins.reporting.tolerances import Tolerances, Verdict, decide, limit_for
from stableins.status import Status

if TYPE_CHECKING:  # pragma: no cover
    from stableins.estimators.device_settings import DeviceSessionSettings, StatedSlowNoise
    from stableins.estimators.result import StageSettings
    from stableins.estimators.system.settings import SystemSettings
    from stableins.noise import NoiseModel


#: Coverage factor of the expanded uncertainty (GUM 6.2; about 95 % for a normal distribution).
@dataclass(frozen=True)
class ParameterRow:
    """One row of the results table, in engineering units (``nan`` where no value is stated).

    ``u`` is the combined standard uncertainty (Type A ⊕ Type B, :mod:`stableins.reporting.budget`) and
    ``expanded = k u``; ``type_a`` the record's own σ.  ``source`` says which stage last determined the
    parameter (and whether in this calibration, :meth:`CalibrationRecord.source_text`); ``measured``
    whether a stage of this calibration saw it.
    """

    id: str
    meaning: str
    unit: str
    value: float
    u: float
    expanded: float
    status: Status
    why: str
    source: str = ""
    measured: bool = True
    type_a: float = math.nan
    coverage: float = COVERAGE_FACTOR

    @property
    def estimated(self) -> bool:
        """Whether the parameter was estimated."""
        return self.status is Status.ESTIMATED

    @property
    def symbol(self) -> str:
        """The typeset name (reportlab markup)."""
        from stableins.reporting.symbols import markup

        return markup(self.id)

    def rounded(self) -> Rounded:
        """Value, u and U as printed everywhere on the certificate (GUM 7.2.6)."""
        if self.status is Status.UNIDENTIFIABLE or not math.isfinite(self.value):
            return Rounded("not stated", "—", "—")
        if self.status in (Status.FIXED, Status.GAUGE) or not (self.u > 0):
            return Rounded(significant_digits(self.value, 6) if self.value else "0", "—", "—")
        return gum(self.value, self.u, self.coverage)

    def formatted(self) -> tuple[str, str, str]:
        """``(value, u, U)`` as text (:meth:`rounded`)."""
        r = self.rounded()
        return r.value, r.u, r.expanded


def chi2_text(x: float) -> str:
    """χ²_ν as printed everywhere on the certificate (three decimals, the console's)."""
    return f"{x:.3f}" if math.isfinite(x) else "—"


def parameter_rows(
    record: CalibrationRecord, terms: Mapping[str, Term], k: float = COVERAGE_FACTOR, budget: Any = None
) -> list[ParameterRow]:
    """Return the results table rows in record order.

    ``budget`` (:class:`~stableins.reporting.budget.Budget`) gives the combined standard uncertainty, else the
    record's σ (Type A) is used.
    """
    rows = []
    for p in record.parameters:
        term = terms.get(p.id)
        sigma = p.sigma
        combined = budget.combined_of(p.id) if budget is not None and p.id in budget.ids else sigma
        if term is not None:
            value = float(term.to_engineering(p.value)) if math.isfinite(p.value) else math.nan
            u = float(term.sigma_to_engineering(combined)) if math.isfinite(combined) else math.nan
            type_a = float(term.sigma_to_engineering(sigma)) if math.isfinite(sigma) else math.nan
            unit, meaning = printed_unit(term.unit), term.meaning
        else:
            value, u, type_a, unit, meaning = p.value, combined, sigma, p.unit or "SI", "parameter not in the standard model (SI units)"
        if p.status is Status.UNIDENTIFIABLE:  # the record may carry the prior value: never show it as a result
            value = u = type_a = math.nan
        why = ""
        if p.status is not Status.ESTIMATED:
            mentions = [n for n in record.notes if re.search(rf"\b{re.escape(p.id)}\b", n)]
            why = "; ".join(mentions) or p.status.why
        rows.append(
            ParameterRow(
                p.id,
                meaning,
                unit,
                value,
                u,
                k * u if math.isfinite(u) else math.nan,
                p.status,
                why,
                record.source_text(p.id),
                record.measured_in_this_calibration(p.id),
                type_a,
                k,
            )
        )
    return rows


def printed_unit(unit: str) -> str:
    """Engineering unit as printed (``ug`` → ``µg``, ``^2`` → ``²``, ``deg/h`` → ``°/h``)."""
    return unit.replace("ug", "µg").replace("^2", "²").replace("^3", "³").replace("deg/h", "°/h")


def unit_words(text: str) -> str:
    """:func:`printed_unit` applied to the units inside a sentence (``ug`` only as a word of its own)."""
    return re.sub(r"(?<![A-Za-z])ug(?![A-Za-z])", "µg", text).replace("^2", "²").replace("^3", "³")


def correlation(record: CalibrationRecord) -> tuple[tuple[str, ...], list[list[float]]]:
    """Correlation matrix of the estimated parameters with a positive variance."""
    c = record.covariance
    keep = [i for i, p in enumerate(record.parameters) if p.status is Status.ESTIMATED and math.isfinite(c[i, i]) and c[i, i] > 0]
    ids = tuple(record.ids[i] for i in keep)
    sigma = [math.sqrt(c[i, i]) for i in keep]
    matrix = [[float(c[i, j]) / (sigma[a] * sigma[b]) for b, j in enumerate(keep)] for a, i in enumerate(keep)]
    return ids, matrix


@dataclass(frozen=True)
class ChangeRow:
    """A change of :func:`stableins.history.compare` in the engineering unit of its term (presentation only)."""

    id: str
    unit: str
    new: float
    old: float
    delta: float
    u_delta: float
    significance: float
    significant: bool


def change_rows(comparison: Comparison, terms: Mapping[str, Term]) -> list[ChangeRow]:
    """Return the comparison's changes in engineering units (z and the flag are the comparison's own)."""
    rows = []
    for c in comparison.changes:
        term = terms.get(c.id)
        value = (lambda x, t=term: float(t.to_engineering(x))) if term else float
        spread = (lambda x, t=term: float(t.sigma_to_engineering(x))) if term else float
        unit = printed_unit(term.unit) if term else c.unit
        rows.append(
            ChangeRow(
                c.id, unit, value(c.new), value(c.old), spread(c.difference), spread(c.sigma_difference), c.significance, c.significant
            )
        )
    return rows


class CheckKind(StrEnum):
    """What a conformity check compares with its limit (:data:`CHECK_KINDS` has the certificate's words)."""

    VALUE = "value"
    UNCERTAINTY = "uncertainty"
    STABILITY = "stability"
    FIT = "fit"


@dataclass(frozen=True)
class Check:
    """One conformity check."""

    kind: CheckKind
    subject: str
    measured: float
    expanded: float
    limit: float
    unit: str
    verdict: Verdict
    reason: str = ""


def conformity(
    rows: Sequence[ParameterRow],
    changes: Sequence[ChangeRow] | None,
    stages: Sequence[StageEvidence],
    tolerances: Tolerances,
) -> list[Check]:
    """Return every check the tolerances ask for, in table order."""
    checks = _value_checks(rows, tolerances) + _uncertainty_checks(rows, tolerances)
    if tolerances.stability:
        checks += _stability_checks(rows, changes, tolerances)
    if tolerances.chi2_interval is not None:
        checks += _fit_checks(stages, tolerances.chi2_interval)
    return checks


def _value_checks(rows: Sequence[ParameterRow], tolerances: Tolerances) -> list[Check]:
    """Return the checks of ``|x|`` against ``[tolerances.limits]``, with the decision rule."""
    checks: list[Check] = []
    for row in rows:
        limit = limit_for(tolerances.limits, row.id)
        if limit is None:
            continue
        if not row.estimated:
            checks.append(Check(CheckKind.VALUE, row.id, row.value, math.nan, limit, row.unit, Verdict.NOT_ASSESSED, row.status.value))
        else:
            expanded = tolerances.coverage_factor * row.u
            verdict = decide(row.value, expanded, limit, tolerances.decision_rule)
            checks.append(Check(CheckKind.VALUE, row.id, row.value, expanded, limit, row.unit, verdict))
    return checks


def _uncertainty_checks(rows: Sequence[ParameterRow], tolerances: Tolerances) -> list[Check]:
    """Return the checks of ``U`` against ``[tolerances.uncertainty]``."""
    checks: list[Check] = []
    for row in rows:
        limit = limit_for(tolerances.uncertainty, row.id)
        if limit is None:
            continue
        if not row.estimated:
            checks.append(Check(CheckKind.UNCERTAINTY, row.id, math.nan, math.nan, limit, row.unit, Verdict.NOT_ASSESSED, row.status.value))
        else:
            expanded = tolerances.coverage_factor * row.u
            verdict = Verdict.PASS if expanded <= limit else Verdict.FAIL
            checks.append(Check(CheckKind.UNCERTAINTY, row.id, expanded, math.nan, limit, row.unit, verdict))
    return checks


def _stability_checks(rows: Sequence[ParameterRow], changes: Sequence[ChangeRow] | None, tolerances: Tolerances) -> list[Check]:
    """Return the checks of the change since the previous calibration against ``[tolerances.stability]``."""
    checks: list[Check] = []
    by_id = {c.id: c for c in changes or ()}
    for row in rows:
        limit = limit_for(tolerances.stability, row.id)
        if limit is None:
            continue
        change = by_id.get(row.id)
        if change is None:
            reason = "no previous calibration given" if changes is None else "not re-measured, or not estimated in both calibrations"
            checks.append(Check(CheckKind.STABILITY, row.id, math.nan, math.nan, limit, row.unit, Verdict.NOT_ASSESSED, reason))
        else:
            expanded = tolerances.coverage_factor * change.u_delta
            verdict = decide(change.delta, expanded, limit, tolerances.decision_rule)
            checks.append(Check(CheckKind.STABILITY, row.id, change.delta, expanded, limit, row.unit, verdict))
    return checks


def _fit_checks(stages: Sequence[StageEvidence], interval: float) -> list[Check]:
    """Return the checks of each fit's ``χ²_ν`` against the upper end of its central ``interval`` for noise alone.

    The limit is :meth:`StageEvidence.chi2_red_interval` — the χ² distribution with the fit's ν, the interval the
    evidence of fit states — so a good fit fails with probability (1 − interval)/2 whatever ν.
    """
    checks: list[Check] = []
    if not stages:
        checks.append(Check(CheckKind.FIT, "χ²_ν", math.nan, math.nan, math.nan, "", Verdict.NOT_ASSESSED, "no residual evidence"))
    for stage in stages:
        if stage.dof <= 0:
            checks.append(Check(CheckKind.FIT, f"χ²_ν ({stage.stage})", math.nan, math.nan, math.nan, "", Verdict.NOT_ASSESSED, "ν = 0"))
            continue
        value, limit = stage.chi2_red, stage.chi2_red_interval(interval)[1]
        verdict = Verdict.PASS if value <= limit else Verdict.FAIL
        checks.append(Check(CheckKind.FIT, f"χ²_ν ({stage.stage})", value, math.nan, limit, "", verdict))
    return checks


#: Words of the statement of conformity: the kinds of check, and the verdicts in the order they are counted.
CHECK_KINDS = {
    CheckKind.VALUE: "value",
    CheckKind.UNCERTAINTY: "uncertainty U",
    CheckKind.STABILITY: "change since previous",
    CheckKind.FIT: "model fit",
}
VERDICTS = tuple(Verdict)
CONFORMITY_HEADER = ("Check", "Subject", "Measured |x|", "U", "Limit T", "Unit", "Result")
NO_STATEMENT = (
    "No statement of conformity: no procedure of this calibration defines tolerances ([tolerances] table) and none were given, "
    "so none is made."
)
NOT_ASKED = "No statement of conformity: none was asked for."


def conformity_row(check: Check, coverage_factor: float = COVERAGE_FACTOR) -> tuple[str, str, str, str, str, str, str]:
    """One row of the statement of conformity, as the certificate prints it and the console repeats it (:data:`CONFORMITY_HEADER`).

    The measured value and U carry the certificate's one rounding (:func:`gum`, sections 4 and 9); χ²_ν its three decimals.
    """

    def fmt(x: float, significant: int) -> str:
        return significant_digits(x, significant) if math.isfinite(x) else "—"

    measured, expanded = "—", "—"
    if check.verdict != Verdict.NOT_ASSESSED and math.isfinite(check.measured):
        if check.kind == CheckKind.FIT:
            measured = chi2_text(abs(check.measured))
        elif check.kind == CheckKind.UNCERTAINTY:
            measured = significant_digits(abs(check.measured), 2)
        elif math.isfinite(check.expanded) and check.expanded > 0:
            rounded = gum(abs(check.measured), check.expanded / coverage_factor, coverage_factor)
            measured, expanded = rounded.value, rounded.expanded
        else:
            measured = fmt(abs(check.measured), 4)
    result = check.verdict + (f" ({check.reason})" if check.reason else "")
    return (CHECK_KINDS[check.kind], check.subject, measured, expanded, fmt(check.limit, 4), check.unit, result)


def conformity_counts(checks: Sequence[Check]) -> str:
    """``"23 pass, 1 fail"``: how many checks reached each verdict."""
    return ", ".join(f"{n} {v}" for v in VERDICTS if (n := sum(1 for c in checks if c.verdict == v)))


def no_statement_text(reason: str) -> str:
    """Return why a certificate makes no statement of conformity: none asked for, or no tolerances defined."""
    return NOT_ASKED if reason == NO_STATEMENT_ASKED else NO_STATEMENT


#: The source of the empty tolerances of a certificate whose statement of conformity was not asked for.
NO_STATEMENT_ASKED = "no statement asked for"


def conformity_text(checks: Sequence[Check], *, assessed: bool, coverage_factor: float = COVERAGE_FACTOR, reason: str = "") -> list[str]:
    """Return the statement of conformity in plain text, with the certificate's words and numbers.

    The verdict, the counts, and every check that did not pass (its row of the certificate's table).
    ``assessed``: tolerances were given; ``reason``: the source of the tolerances (:data:`NO_STATEMENT_ASKED` when none
    was asked for).
    """
    if not assessed:
        return [no_statement_text(reason)]
    lines = [f"Verdict: {overall_verdict(checks)} ({conformity_counts(checks)})"]
    for check in checks:
        if check.verdict != Verdict.PASS:
            kind, subject, measured, expanded, limit, unit, result = conformity_row(check, coverage_factor)
            unit = f" {unit}" if unit else ""
            lines.append(f"  {kind} {subject}: measured |x| {measured}{unit}, U {expanded}, limit T {limit}{unit}: {result}")
    return lines


def overall_verdict(checks: Sequence[Check]) -> str:
    """FAIL if any check fails; CONDITIONAL FAIL / CONDITIONAL PASS next; PASS when every assessed check passes."""
    verdicts = {c.verdict for c in checks}
    if not (verdicts - {Verdict.NOT_ASSESSED}):
        return "NOT ASSESSED"
    for word in (Verdict.FAIL, Verdict.CONDITIONAL_FAIL, Verdict.CONDITIONAL_PASS):
        if word in verdicts:
            return word.upper()
    return "PASS"


def noise_text(model: NoiseModel) -> str:
    """Describe the noise model a stage ran with, in words: what was given and what was measured (no command-line syntax)."""
    import numpy as np

    from stableins.noise import ENGINEERING, NoiseSource

    def amount(name: str) -> str:
        unit, scale = ENGINEERING[name]
        values = model.values(name) / scale
        shown = f"{np.max(values):.2g}" if np.allclose(values, np.max(values), rtol=0.02) else "/".join(f"{v:.2g}" for v in values)
        return f"{shown} {printed_unit(unit).replace('sqrt(Hz)', '√Hz').replace('sqrt(s)', '√s')}"

    def scale_of(name: str) -> float:
        return float(ENGINEERING[name][1])

    white = f"white noise measured in the dwells: {amount('white')}"
    slow = ("bias_instability", "random_walk")
    names = {"bias_instability": "bias instability", "random_walk": "random walk"}
    if model.source is NoiseSource.DATASHEET:
        given = [f"{names[n]} given: {amount(n)}" for n in slow if np.any(model.values(n) > 0)]
        return "; ".join(given + [white])
    if model.source is NoiseSource.NONE:
        return f"{white}; slow noise not given and not bounded"
    where = "in a static record" if model.source is NoiseSource.STATIC_RECORD else "in the dwells"
    if model.test is not None and not model.test.detected:  # the console's words: not detected, and the upper limit the data allow
        upper = model.limits("bias_instability")[1]
        bound = f"up to {float(np.max(upper)) / scale_of('bias_instability'):.2g} µg, in U" if np.all(np.isfinite(upper)) else "not bounded"
        return f"{white}; slow noise not detected {where} (bias instability {bound}; random walk not bounded)"
    measured = [f"{names[n]} measured {where}: {amount(n)}" for n in slow]
    return "; ".join([white, *measured])


def describe_settings(settings: StageSettings | None) -> str:
    """Describe the settings a stage ran with, as one line for people (noise model, options that change the estimates), in plain words."""
    from stableins.estimators.device_settings import DeviceFitSettings, DeviceSessionSettings
    from stableins.estimators.poses import PoseSettings
    from stableins.estimators.system.settings import SystemSettings
    from stableins.reporting.symbols import words_for_flags

    parts: list[str] = []
    if isinstance(settings, DeviceFitSettings | DeviceSessionSettings) and settings.slow_noise is not None:
        parts.append(_slow_noise_words(settings.slow_noise))
    if isinstance(settings, DeviceFitSettings | DeviceSessionSettings | PoseSettings) and settings.noise_model is not None:
        parts.append(noise_text(settings.noise_model))
    if isinstance(settings, DeviceSessionSettings):
        parts += _device_settings(settings)
    if isinstance(settings, DeviceFitSettings) and settings.nonlinear is False:
        parts.append("coarse stage without K₂")
    if isinstance(settings, SystemSettings):
        parts.append("K₂,x and K₂,y from the third harmonic" if settings.options.estimate_k2 else "K₂ not estimated")
        parts += _system_settings(settings)
    return words_for_flags("; ".join(parts)) or "defaults"


def _slow_noise_words(slow: StatedSlowNoise) -> str:
    """Return the slow-noise model a record of the first schema-2 version states, in words."""
    from stableins.conventions import MICRO_G

    if not slow.modelled:
        return "white noise only (no slow-noise model)"
    return f"bias instability {slow.bias_instability / MICRO_G:.2g} µg, random walk {slow.random_walk:.2g} m/s²/√s ({slow.source})"


def _device_settings(settings: DeviceSessionSettings) -> list[str]:
    """Return the procedures and the options of a device calibration's settings that change its estimates, in words."""
    from stableins.reporting.symbols import plain

    parts = []
    procedures = [p for p in (settings.coarse_procedure, settings.fine_procedure) if p is not None]
    if procedures:
        parts.append("procedures " + " and ".join(procedures))
    if not settings.coarse_nonlinear:
        parts.append("coarse stage without K₂")
    if settings.allow_missing:
        parts.append("missing positions allowed")
    if settings.effects:
        parts.append("discovered effects estimated: " + ", ".join(plain(e) for e in settings.effects))
    return parts


def _system_settings(settings: SystemSettings) -> list[str]:
    """Return the gyro-drift and damping-loop settings of a system stage, in words."""
    from stableins.estimators.system.options import GyroDrift

    parts = []
    options = settings.options
    drift = options.known_gyro_drift
    if settings.measures_gyro_drift:
        parts.append("gyro drift measured from the gimbal readings (gyro_drift_x, _y, _z in the record)")
    if drift is not None:
        parts.append("gyro drift given: " + ", ".join(f"{math.degrees(float(d)) * 3600.0:.4g}" for d in drift) + " °/h (platform x, y, z)")
    elif not settings.measures_gyro_drift:
        parts.append("gyro drift not given (assumed zero)")
    if options.gyro_drift_uncertainty is not None:
        parts.append(f"gyro drift uncertainty given: {math.degrees(options.gyro_drift_uncertainty) * 3600.0:.2g} °/h per axis")
    if options.gyro_drift is not GyroDrift.IGNORE:
        parts.append("gyro drift fitted as a nuisance" if options.gyro_drift is GyroDrift.FIT else "gyro drift checked")
    if not options.compensate_loop:
        parts.append("no damping-loop compensation")
    return parts
