r"""Model discovery on the holds of a real log: the instrument effects the pose fit may miss.

The pose fit (:func:`stableins.estimators.poses.calibrate_poses`, unknown orientation) has only the
norm observation ``½(g² − |f|²)`` per hold, no commanded orientation; model discovery on it refits the
same holds with each instrument candidate of the library (``CALIBRATION_GROUPS``) added in turn, with
the same noise model, so the fits are nested and their χ² comparable (as :mod:`stableins.discovery.carry`
tests an effect)::

    Δχ² = χ²₀ − χ²₁,   F = Δχ² / (χ²₁/(ν − 1)) ~ F(1, ν − 1),   ΔBIC = −Δχ² + ln m

(:func:`stableins.discovery.scores.effect_statistics`).  With ``k`` candidates tested the family-wise
false-alarm rate is held at ``α`` by Bonferroni: an effect is flagged when ``p < α/k``.  A candidate the
norm cannot separate from the model (held by the fit, e.g. a cross-coupling whose regressor is a
function of ``|f|`` at rest) is reported ``not determined``.  With a flagged effect the next step is the
same command with ``--add ID``; with none, the misfit (if any) is outside the library: motion inside the
holds, a noise model that understates the noise, or an effect the library lacks.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

from stableins.discovery.library import CALIBRATION_GROUPS, LIBRARY, Library
from stableins.discovery.scores import effect_statistics
from stableins.errormodel import Term
from stableins.errors import InputError, NotDeterminedError
from stableins.estimators.result import FitResult
from stableins.status import Status


@dataclass(frozen=True)
class PoseCandidate:
    """One candidate effect refitted on the holds.

    Attributes
    ----------
    id : str
    determined : bool
        Whether the norm fit separates it from the model (else held, no statistics).
    value, sigma : float
        Its estimate and 1σ in engineering units (``unit``) when determined, else NaN.
    unit : str
    delta_chi2, p_value, delta_bic : float
        The statistics of adding it (NaN when not determined).
    """

    id: str
    determined: bool
    value: float
    sigma: float
    unit: str
    delta_chi2: float
    p_value: float
    delta_bic: float


@dataclass(frozen=True)
class PoseScan:
    """The candidates refitted on the holds, ranked by p-value, and the decision.

    Attributes
    ----------
    baseline_chi2_red : float
        χ²_ν of the fit without any candidate.
    candidates : tuple of PoseCandidate
        Determined ones by increasing p, then the undetermined.
    alpha : float
        Family-wise false-alarm rate (Bonferroni over the determined candidates).
    flagged : str or None
        The id of the best candidate when its ``p < α/k``.
    skipped : tuple of str
        Candidates whose inputs the poses lack (temperature, time, slews ...), not tested.
    """

    baseline_chi2_red: float
    candidates: tuple[PoseCandidate, ...]
    alpha: float
    flagged: str | None
    skipped: tuple[str, ...] = ()

    @property
    def tested(self) -> int:
        """Number of determined candidates (the Bonferroni ``k``)."""
        return sum(1 for c in self.candidates if c.determined)

    def report(self, shown: int = 5) -> str:
        """Return the ranking as text: the best ``shown`` candidates and the decision."""
        lines = [
            f"model discovery on the holds: {self.tested} instrument effects of the library refitted one at a time "
            f"(baseline chi2_red {self.baseline_chi2_red:.3g}; flagged when p < alpha/k = {self.alpha:g}/{max(self.tested, 1)})"
        ]
        for c in [c for c in self.candidates if c.determined][:shown]:
            test = f"Δχ² = {c.delta_chi2:.1f}, F-test p = {c.p_value:.2g}, ΔBIC = {c.delta_bic:+.1f}"
            lines.append(f"  {c.id:<9} {c.value:+.4g} ± {c.sigma:.2g} {c.unit}: {test}")
        undetermined = [c.id for c in self.candidates if not c.determined]
        if undetermined:
            lines.append(f"  not determined by these holds (held by the fit): {', '.join(undetermined)}")
        if self.skipped:
            lines.append(f"  not tested (inputs the poses lack): {', '.join(self.skipped)}")
        lines.append(
            f"  flagged: {self.flagged}"
            if self.flagged
            else "  none flagged (p >= alpha/k for every effect tested); a misfit the baseline shows is outside the library "
            "(motion inside holds, the noise model, or an effect the library lacks)"
        )
        return "\n".join(lines)


def scan_poses(refit: Callable[[Sequence[Term]], FitResult], *, alpha: float = 0.05, library: Library | None = None) -> PoseScan:
    """Refit the holds with each instrument candidate of the library in turn (module docstring).

    Parameters
    ----------
    refit : callable
        ``extra_terms -> FitResult``: the pose fit of the same holds, noise model and model with these terms added.
    alpha : float
        Family-wise false-alarm rate.
    """
    library = library if library is not None else LIBRARY
    base = refit(())
    found: list[PoseCandidate] = []
    skipped: list[str] = []
    for candidate in library:
        if candidate.group not in CALIBRATION_GROUPS:
            continue
        term = candidate.term
        try:
            fit = refit((term,))
        except NotDeterminedError:
            raise  # a described error passes through as it is (issue 29)
        except (InputError, ValueError, TypeError, AttributeError, KeyError, IndexError):  # its inputs are not in the poses
            skipped.append(term.id)
            continue
        value, sigma, status = fit[term.id]
        if status != Status.ESTIMATED or fit.dof < 2:
            nan = float("nan")
            found.append(PoseCandidate(term.id, False, nan, nan, term.unit, nan, nan, nan))
            continue
        delta = max(base.chi2 - fit.chi2, 0.0)
        _, p, dbic = effect_statistics(delta, base.chi2, base.dof, base.residuals.size)
        engineering = (float(term.to_engineering(value)), float(term.sigma_to_engineering(sigma)))
        found.append(PoseCandidate(term.id, True, *engineering, term.unit, delta, p, dbic))
    determined = sorted((c for c in found if c.determined), key=lambda c: c.p_value)
    k = len(determined)
    flagged = determined[0].id if determined and determined[0].p_value < alpha / k else None
    undetermined = tuple(c for c in found if not c.determined)
    return PoseScan(base.chi2_red, tuple(determined) + undetermined, float(alpha), flagged, tuple(skipped))
