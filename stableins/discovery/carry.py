r"""Carry discovered effects into the device calibration: estimate, test, keep what the data show.

Model discovery (``stableins diagnose``) says which effect the standard model misses; this
module puts it into the calibration.  The device stages (:func:`stableins.estimators.device.calibrate_device`)
estimate the chosen effects jointly with the standard parameters in the coarse passes, the fine
stage and the fused fit, and every effect gets a verdict from the fused fit, the one the
record holds:

* the model in force starts as the standard one (the *baseline*);
* each effect, in the order given, is added to the model in force and the whole device
  calibration is run again; with ``χ²₀`` the whitened χ² of the model in force (``ν`` degrees of
  freedom, ``m`` observations) and ``χ²₁`` that with the effect,

  .. math:: \Delta\chi^2 = \chi^2_0 - \chi^2_1,\qquad F = \frac{\Delta\chi^2}{\chi^2_1/(\nu - 1)} \sim F(1, \nu - 1),
            \qquad \Delta\mathrm{BIC} = -\Delta\chi^2 + \ln m

  (the statistics of :func:`stableins.discovery.scores.effect_statistics`, as the ranking uses);
* **kept** when ``p < α`` (default 5 % for one named effect): the model in force grows;
* **not supported** when ``p ≥ α``: the data do not show the effect, and it is *left out of
  the record* (compensating with a noisy estimate of nothing adds error, and its aliases would
  lose precision); ``keep_unsupported`` keeps it anyway (decision ``kept on request``);
* **not determined** when the fused fit cannot separate it from the model (it is held,
  status ``unidentifiable``, e.g. ``Kcq_xy`` with ``Kcq_xz`` since ``|f| = g`` at rest): left out.

The steps, with χ²_ν, residual RMS per output channel, BIC and the verdicts, form the record's
``discovery`` section (:class:`stableins.discovery.history.ModelHistory`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any

from stableins.discovery.history import ModelHistory
from stableins.discovery.steps import Decision, ModelStep, make_step
from stableins.errormodel import Term, TermKind
from stableins.estimators.device import DeviceCalibration
from stableins.estimators.result import FitResult
from stableins.status import Status

#: Default false-alarm level of the test that keeps one named effect.
KEEP_ALPHA = 0.05
#: Shifts of existing parameters a step keeps (the largest in units of their previous 1σ).
SHIFTS_KEPT = 6


@dataclass(frozen=True)
class CarriedCalibration:
    """A device calibration with discovered effects, and the history that decided which stay.

    Attributes
    ----------
    calibration : DeviceCalibration
        The calibration with the model in force (the standard terms and the kept effects).
    history : ModelHistory
        The baseline and one step per tested effect, with its verdict.
    """

    calibration: DeviceCalibration
    history: ModelHistory

    @property
    def kept(self) -> tuple[str, ...]:
        """Ids of the effects carried into the calibration."""
        return self.history.effects

    @property
    def left_out(self) -> tuple[ModelStep, ...]:
        """Steps of effects that did not stay in the model."""
        return tuple(s for s in self.history.steps[1:] if s.decision is not None and not s.decision.in_model)


def carry_effects(
    calibrate: Callable[[Sequence[Term]], DeviceCalibration],
    effects: Sequence[Term],
    *,
    alpha: float = KEEP_ALPHA,
    keep_unsupported: bool = False,
    progress: Callable[[ModelStep], Any] | None = None,
) -> CarriedCalibration:
    """Add ``effects`` one by one to the device calibration and keep those the data show.

    Parameters
    ----------
    calibrate : callable
        ``extra_terms -> DeviceCalibration``: the device calibration of the data at hand with
        these additive terms (e.g. a :func:`functools.partial` of
        :func:`stableins.estimators.device.calibrate_device`).  Every call sees the same dwells
        and noise model, so the fits are nested and their χ² comparable.
    effects : sequence of Term
        Library terms (:func:`stableins.discovery.library.calibration_terms`), in the order to test.
    alpha : float
        False-alarm level of the F-test for one effect.
    keep_unsupported : bool
        Keep an effect the data do not show (its verdict still says so).
    progress : callable, optional
        Called with every step as it is decided.
    """
    from stableins.discovery.problem import fit_chi2
    from stableins.discovery.scores import effect_statistics

    if not 0.0 < alpha < 1.0:
        raise ValueError("alpha must lie between 0 and 1")
    current = calibrate(())
    base = current.final
    steps = [replace(make_step(base, "standard model"), decision=Decision.BASELINE, reason="the model before any effect was added")]
    if progress is not None:
        progress(steps[0])
    accepted: list[Term] = []
    for term in effects:
        trial = calibrate((*accepted, term))
        fit, previous = trial.final, current.final
        step = make_step(fit, f"+ {term.id}", previous)
        value, sigma, status = fit[term.id]
        estimate = f"{term.id} = {float(term.to_engineering(value)):+.4g} ± {float(term.sigma_to_engineering(sigma)):.2g} {term.unit}"
        if status != Status.ESTIMATED:
            why = next((n for n in fit.notes if n.startswith("not determined")), "the fit holds it")
            decision = Decision.NOT_DETERMINED
            reason = f"the {fit.stage} fit cannot separate {term.id} from the model ({why}); left out of the record"
            step = replace(step, added=((term.id, float(term.to_engineering(value)), 0.0, term.unit),))
        else:
            delta = max(fit_chi2(previous) - fit_chi2(fit), 0.0)
            _, p, dbic = effect_statistics(delta, fit_chi2(previous), previous.dof, previous.residuals.size)
            step = replace(step, delta_chi2=delta, p_value=p, delta_bic=dbic)
            test = f"Δχ² = {delta:.1f}, ΔBIC = {dbic:+.1f}, F-test p = {p:.2g}"
            if p < alpha:
                decision, reason = Decision.KEPT, f"{estimate}; {test} < α = {alpha:g}: the data show it; kept in the record"
            elif keep_unsupported:
                decision = Decision.KEPT_ON_REQUEST
                reason = f"{estimate}; {test} ≥ α = {alpha:g}: the data do not show it; kept on request (--keep-unsupported)"
            else:
                decision = Decision.NOT_SUPPORTED
                reason = (
                    f"{estimate}; {test} ≥ α = {alpha:g}: the data do not show it; left out of the record (--keep-unsupported keeps it)"
                )
        largest = sorted(step.shifts.items(), key=lambda kv: -abs(kv[1][2]) if kv[1][2] == kv[1][2] else 0.0)[:SHIFTS_KEPT]
        step = replace(step, decision=decision, reason=reason, shifts=dict(largest))
        steps.append(step)
        if progress is not None:
            progress(step)
        if decision.in_model:
            accepted.append(term)
            current = trial
    history = ModelHistory(stage=current.final.stage, alpha=float(alpha), steps=tuple(steps))
    return CarriedCalibration(current, history)


def stage_effects(fit: FitResult) -> tuple[str, ...]:
    """Return the additive (discovered) terms a stage result estimates or holds."""
    return tuple(t.id for t in fit.terms if t.kind == TermKind.ADDITIVE)
