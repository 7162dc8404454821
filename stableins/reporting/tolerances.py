r"""Conformity: tolerances from the procedure definition and the decision rule (ILAC-G8:09/2019).

A procedure TOML may carry a ``[tolerances]`` table (schema proposal, see
``docs/reports.md``)::

    [tolerances]
    decision_rule = "guarded"   # "guarded" (default), "simple" or "non-binary"
    coverage_factor = 2.0       # k of the expanded uncertainty U = k u used by the rule

    [tolerances.limits]         # |value| <= limit, in the engineering unit of each term
    "bias_*" = 500.0            # µg
    "sf_*" = 300.0              # ppm (deviation of the scale factor from 1)
    "beta_*" = 60.0             # arcsec
    "K2_*" = 50.0               # µg/g²

    [tolerances.uncertainty]    # U (k = coverage_factor) <= limit: the calibration reached its accuracy
    "bias_*" = 20.0

    [tolerances.stability]      # |change since the previous calibration| <= limit
    "bias_*" = 100.0

    [tolerances.fit]
    interval = 0.95             # each fit's χ²_ν must not exceed the upper end of its central 95 % interval
                                # for noise alone (χ² distribution with the fit's ν): one criterion, the one
                                # the evidence of fit states

Keys are parameter ids or shell-style patterns (``fnmatch``); an exact id wins over a
pattern, then the longest pattern.

Decision rules (ILAC-G8:09/2019 Section 4.2, guard band ``w``, tolerance limit ``T``,
measured ``|x|``, expanded uncertainty ``U``):

* ``guarded`` (binary, ``w = U``): **pass** if ``|x| <= T − U``, else **fail**.  The
  probability of accepting a non-conforming unit is below 2.5 % for a normal
  distribution with ``k = 2`` (ILAC-G8 4.2.2).  This is the default: an accredited
  laboratory states conformity only where its uncertainty supports it.
* ``simple`` (binary, ``w = 0``, "shared risk"): **pass** if ``|x| <= T``.  The risk of
  false acceptance reaches 50 % at the limit; use only where the customer agreed.
* ``non-binary`` (ILAC-G8 4.2.3, ``w = U``): **pass** ``|x| <= T − U``;
  **conditional pass** ``T − U < |x| <= T``; **conditional fail** ``T < |x| <= T + U``;
  **fail** ``|x| > T + U``.

Uncertainty limits compare the stated ``U`` itself (no measurement of ``U``, so no guard
band); χ²_ν is compared with the upper end of its interval for noise alone, whose probability of failing a
good fit is (1 − interval)/2 whatever ν (a fixed χ²_ν ≤ 2.0 would fail about 6 % of good fits with ν = 6 and
none with ν = 1000).
"""

from __future__ import annotations

import fnmatch
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any

from stableins.errors import InputError


class DecisionRule(StrEnum):
    """Decision rule of a statement of conformity (ILAC-G8:09/2019; :data:`RULE_TEXT` says each in full)."""

    GUARDED = "guarded"
    SIMPLE = "simple"
    NON_BINARY = "non-binary"


class Verdict(StrEnum):
    """Verdict of one conformity check (the certificate prints the word)."""

    PASS = "pass"
    FAIL = "fail"
    CONDITIONAL_PASS = "conditional pass"
    CONDITIONAL_FAIL = "conditional fail"
    NOT_ASSESSED = "not assessed"


DECISION_RULES = tuple(r.value for r in DecisionRule)

RULE_TEXT = {
    DecisionRule.GUARDED: (
        "Binary guarded acceptance, ILAC-G8:09/2019 4.2.2, guard band w = U: a result passes when |x| ≤ T − U and fails "
        "otherwise. The probability of accepting a non-conforming value is below 2.5 % (normal distribution, k = 2)."
    ),
    DecisionRule.SIMPLE: (
        "Binary simple acceptance, ILAC-G8:09/2019 4.2.1, guard band w = 0 (shared risk, as agreed with the customer): a result "
        "passes when |x| ≤ T. The probability of false acceptance reaches 50 % at the limit."
    ),
    DecisionRule.NON_BINARY: (
        "Non-binary statement, ILAC-G8:09/2019 4.2.3, guard band w = U: pass |x| ≤ T − U; conditional pass T − U < |x| ≤ T; "
        "conditional fail T < |x| ≤ T + U; fail |x| > T + U."
    ),
}


@dataclass(frozen=True)
class Tolerances:
    """Tolerance limits of a procedure, in engineering units."""

    decision_rule: DecisionRule = DecisionRule.GUARDED
    coverage_factor: float = 2.0
    limits: Mapping[str, float] = field(default_factory=dict)
    uncertainty: Mapping[str, float] = field(default_factory=dict)
    stability: Mapping[str, float] = field(default_factory=dict)
    chi2_interval: float | None = None
    source: str = ""

    @property
    def empty(self) -> bool:
        """Return whether no tolerance is set (no limits, uncertainty or stability limits and no χ² criterion)."""
        return not (self.limits or self.uncertainty or self.stability or self.chi2_interval is not None)

    @classmethod
    def from_mapping(cls, table: Any, source: str = "procedure") -> Tolerances:
        """Validate a ``[tolerances]`` table; problems raise :class:`InputError` naming ``source``."""
        if table is None:
            return cls(source=source)
        if not isinstance(table, Mapping):
            raise InputError("[tolerances] is not a table", path=source, field="tolerances")
        known = {"decision_rule", "coverage_factor", "limits", "uncertainty", "stability", "fit"}
        unknown = sorted(set(table) - known)
        if unknown:
            raise InputError(f"unknown keys {unknown}", path=source, field="tolerances", expected=", ".join(sorted(known)))
        rule = table.get("decision_rule", "guarded")
        if rule not in DECISION_RULES:
            raise InputError(
                f"unknown decision rule {rule!r}", path=source, field="tolerances.decision_rule", expected=" or ".join(DECISION_RULES)
            )
        k = _positive(table.get("coverage_factor", 2.0), source, "tolerances.coverage_factor")
        fit = table.get("fit", {})
        if isinstance(fit, Mapping) and "chi2_red_max" in fit:
            raise InputError(
                "chi2_red_max is replaced by interval: a fixed maximum of χ²_ν fails a share of good fits that depends on ν",
                path=source,
                field="tolerances.fit.chi2_red_max",
                expected="interval = 0.95 (each fit's χ²_ν within the upper end of its interval for noise alone)",
            )
        if not isinstance(fit, Mapping) or set(fit) - {"interval"}:
            raise InputError("[tolerances.fit] takes only interval", path=source, field="tolerances.fit")
        interval = fit.get("interval")
        if interval is not None and not (isinstance(interval, float) and 0.5 <= interval < 1.0):
            expected = "a number from 0.5 to 1, e.g. 0.95"
            raise InputError(f"not a probability: {interval!r}", path=source, field="tolerances.fit.interval", expected=expected)
        return cls(
            decision_rule=DecisionRule(rule),
            coverage_factor=k,
            limits=_limits(table.get("limits", {}), source, "limits"),
            uncertainty=_limits(table.get("uncertainty", {}), source, "uncertainty"),
            stability=_limits(table.get("stability", {}), source, "stability"),
            chi2_interval=interval,
            source=source,
        )

    @classmethod
    def from_procedure_file(cls, path: str) -> Tolerances:
        """Read the ``[tolerances]`` table of a procedure TOML file."""
        from stableins.procedures.definition import read_toml

        data = read_toml(path, what="a procedure definition (TOML)")
        return cls.from_mapping(data.get("tolerances"), source=str(path))


def limit_for(table: Mapping[str, float], parameter_id: str) -> float | None:
    """Limit for one parameter: exact id first, then the longest matching pattern."""
    if parameter_id in table:
        return table[parameter_id]
    matches = [p for p in table if fnmatch.fnmatchcase(parameter_id, p)]
    return table[max(matches, key=len)] if matches else None


def decide(value: float, expanded_uncertainty: float, limit: float, rule: DecisionRule) -> Verdict:
    """Verdict for ``|value|`` against the symmetric limit ``limit`` (see module docstring).

    Returns ``"pass"``, ``"fail"``, ``"conditional pass"`` or ``"conditional fail"``.
    """
    x, u, t = abs(value), expanded_uncertainty, limit
    if not (math.isfinite(x) and math.isfinite(u)):
        return Verdict.FAIL
    if rule == DecisionRule.SIMPLE:
        return Verdict.PASS if x <= t else Verdict.FAIL
    if rule == DecisionRule.GUARDED:
        return Verdict.PASS if x <= t - u else Verdict.FAIL
    if rule == DecisionRule.NON_BINARY:
        if x <= t - u:
            return Verdict.PASS
        if x <= t:
            return Verdict.CONDITIONAL_PASS
        if x <= t + u:
            return Verdict.CONDITIONAL_FAIL
        return Verdict.FAIL
    raise ValueError(f"unknown decision rule {rule!r}")


def _positive(value: Any, source: str, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not (math.isfinite(value) and value > 0):
        raise InputError(f"not a positive number: {value!r}", path=source, field=name, expected="a positive number")
    return float(value)


def _limits(table: Any, source: str, name: str) -> dict[str, float]:
    if not isinstance(table, Mapping):
        raise InputError("not a table", path=source, field=f"tolerances.{name}")
    return {str(k): _positive(v, source, f"tolerances.{name}.{k}") for k, v in table.items()}
