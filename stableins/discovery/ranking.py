r"""Rank candidate effects against a fitted model to find the physical effect it misses.

Notation (whitened with the measured 1σ): residual ``r``, model design ``X`` (estimated
parameters only), candidate column ``z``, hat matrix ``H = X(XᵀX)⁻¹Xᵀ``.

* **Added-variable statistic** (score test; Cook & Weisberg 1982, *Residuals and Influence
  in Regression*, §2.3).  The part of the candidate the model cannot absorb is
  ``z⊥ = (I − H) z``.  One Gauss–Newton step from the fitted model gives

  .. math:: \hat\gamma = \frac{z_\perp^T r}{z_\perp^T z_\perp},\quad \sigma_\gamma = \|z_\perp\|^{-1},\quad
            \Delta RSS = \frac{(z_\perp^T r)^2}{z_\perp^T z_\perp}

  computed for every candidate in one pass (``ΔRSS ~ χ²₁`` under "no effect").
* **Refit** of the best candidates with the full fitter (``model + effect``):
  ``ΔRSS``, ``F = ΔRSS / (RSS₁/(ν−1))`` with its p-value from ``F(1, ν−1)`` (robust to a
  mis-scaled noise floor), and ``ΔBIC = χ²₁ − χ²₀ + ln m`` (known σ; negative favours the effect).
* **Identifiability.**  ``‖z⊥‖/‖z‖`` is the sine of the angle between the candidate and the
  model's column space; below ``1e-3`` (variance inflation 10⁶) the candidate cannot be separated.  The regression
  ``c = (XᵀX)⁻¹Xᵀz`` says where a left-out effect goes: with the effect ``γ`` present and left
  out, the estimates shift by ``c γ``.  The largest contributions ``|c_j|·‖X_j‖`` name the
  aliased parameters.  Candidates whose ``z⊥`` are nearly parallel (``|corr| > 0.99``) cannot be
  told apart from each other with these data; they are reported together.
* **The best group.**  When the best candidate is significant, every candidate whose ``ΔRSS`` is within
  :data:`~stableins.discovery.scores.GROUP_MARGIN` (``1.96²``) of the best's joins it as one group
  (:attr:`Ranking.group`, in :attr:`CandidateScore.confused_with`): a rival beats the true effect by more than that
  margin with probability at most 2.5 % whatever their correlation (the derivation at the constant), so the data
  cannot tell the group's members apart; the report names them together, with positions that would separate them.
* **Flagging** uses a family-wise false-alarm level ``α`` fixed from the null distribution of the largest statistic
  in this fit's own geometry (:func:`family_level`: with no effect the whitened residual is ``(I − H) e``,
  ``e ~ N(0, I)``, so the largest ``ΔRSS_j/RSS`` over the identifiable candidates is drawn exactly; its ``1 − α``
  quantile is the threshold, the per-candidate level it gives is at least Bonferroni's ``α / N``, and the rate is ``α``
  rather than at most ``α``): a candidate is flagged when its p-value is below that level, *and* adding it
  brings ``χ²_ν`` into its 95 % band (:func:`stableins.discovery.scores.explains`), no other candidate stays
  significant with it, and (device dwells) the residual with it leaves no signature along a direction fixed in the
  laboratory (:func:`stableins.discovery.signature.laboratory_columns`): a candidate is named only
  if it explains the residual.  When ``χ²`` rejects the model and no candidate explains it, the effect is
  outside the library (:attr:`Ranking.outside_library`; its signature: :mod:`stableins.discovery.signature`).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from stableins.conventions import MICRO_G
from stableins.discovery.problem import DwellProblem, whiten
from stableins.discovery.scores import (
    CONFUSION_CORRELATION,
    EXCITATION_TOLERANCE,
    GROUP_MARGIN,
    IDENTIFIABLE_TOLERANCE,
    SIGNATURE_ALPHA,
    CandidateScore,
    candidate_columns,
    effect_statistics,
    explains,
    not_named_because,
    refit,
)
from stableins.errormodel import ErrorModel, Term
from stableins.estimators.result import FitResult
from stableins.status import Status
from stableins.units import DisplayUnit

if TYPE_CHECKING:  # pragma: no cover
    from stableins.estimators.leastsquares import Problem

#: The unit a candidate's largest predicted change of an output is shown in by default.
MICRO_G_UNIT = DisplayUnit("µg", MICRO_G)


def _propose(problem: DwellProblem, result: FitResult, scores: list[CandidateScore], by_id: dict[str, Term]) -> list[CandidateScore]:
    """Add numerically tested separating procedures to the advice of unseparable or confused candidates."""
    from stableins.discovery.separation import describe, separations

    wanted = [c for c in scores if c.excited and (not c.identifiable or c.confused_with)]
    tested = dict(
        zip(
            (c.id for c in wanted),
            separations(problem, result, [(c.term, [by_id[i] for i in c.confused_with]) for c in wanted]),
            strict=True,
        )
    )
    out = []
    for c in scores:
        if c.id in tested:
            text = c.advice.removeprefix("confirm with ")
            head = f"to tell it from {', '.join(c.confused_with)}: " if c.confused_with else ""
            c = CandidateScore(**{**c.__dict__, "advice": f"{head}{text}; tested on these positions: {describe(tested[c.id])}"})
        out.append(c)
    return out


def _chi2_red(result: FitResult) -> float:
    from stableins.discovery.problem import fit_chi2_red

    return fit_chi2_red(result)


@dataclass(frozen=True)
class Ranking:
    """Candidates ranked best first, plus the fit they were ranked against."""

    result: FitResult
    candidates: tuple[CandidateScore, ...]
    alpha: float
    n_tested: int
    output_unit: str = "µg"
    output_scale: float = MICRO_G
    level: float | None = None

    @property
    def p_level(self) -> float:
        """The per-candidate p-value below which a candidate is significant (:func:`family_level`; Bonferroni without it)."""
        return self.level if self.level is not None else self.alpha / max(self.n_tested, 1)

    @property
    def best(self) -> CandidateScore | None:
        """The highest-ranked candidate (None without candidates)."""
        return self.candidates[0] if self.candidates else None

    @property
    def flagged(self) -> tuple[CandidateScore, ...]:
        """The flagged candidates, best first."""
        return tuple(c for c in self.candidates if c.flagged)

    @property
    def group(self) -> tuple[str, ...]:
        """The best candidate and those these data cannot tell from it (:attr:`CandidateScore.confused_with`); empty without one."""
        best = self.best
        if best is None or not best.identifiable:
            return ()
        return (best.id, *best.confused_with)

    def __getitem__(self, term_id: str) -> CandidateScore:
        for c in self.candidates:
            if c.id == term_id:
                return c
        raise KeyError(term_id)

    def position(self, term_id: str) -> int:
        """1-based rank of a candidate."""
        return [c.id for c in self.candidates].index(term_id) + 1

    def report(self, top: int = 10) -> str:
        """Return the ranking in words: the ``top`` candidates with statistic, p, ΔBIC, estimate, aliases and advice."""
        model = ErrorModel(self.result.terms)
        lines = [
            f"candidates ranked against the {self.result.stage} fit (χ²_ν = {_chi2_red(self.result):.3f}, ν = {self.result.dof}); "
            f"flag level α = {self.alpha:g} family-wise over {self.n_tested} identifiable candidates (p < {self.p_level:.2g}); "
            "* named: significant and bringing "
            "χ²_ν into its 95 % band",
            f"{'rank':>4} {'id':<14} {'ΔRSS':>9} {'p':>9} {'ΔBIC':>8} {'estimate ± 1σ':>26} {'max |Δobs|':>13}  identifiable / aliases",
        ]
        for k, c in enumerate(self.candidates[:top], 1):
            value, sigma = c.estimate_engineering
            est = f"{value:+.3g} ± {sigma:.2g} {c.term.unit}" if c.identifiable else "—"
            mark = "*" if c.flagged else " "
            ident = "yes" if c.identifiable else ("not excited" if not c.excited else "NO: aliases " + c.alias_text(model))
            if c.confused_with:
                ident += f"; indistinguishable from {', '.join(c.confused_with)}"
            if c.identifiable and c.p_value < self.p_level and not c.explains:
                if c.leaves:
                    ident += f"; significant, but with it {', '.join(c.leaves)} still significant: not named"
                elif c.signature_p < SIGNATURE_ALPHA:
                    ident += (
                        f"; significant, but the residual with it still follows a direction fixed in the laboratory "
                        f"(p = {c.signature_p:.2g}): not named"
                    )
                else:
                    ident += f"; significant, but χ²_ν with it {c.chi2_red_with:.3g} is above its 95 % band: not named"
            lines.append(
                f"{k:>4}{mark}{c.id:<14} {c.statistic:>9.2f} {c.p_value:>9.2g} {c.delta_bic:>8.1f} {est:>26} "
                f"{c.predicted / self.output_scale:>8.3g} {self.output_unit:<4}  {ident}{' (refit)' if c.refit else ''}"
            )
        hidden = [c for c in self.candidates[top:] if not c.identifiable and c.excited]
        if hidden:
            lines.append("")
            lines.append("not separable with these data (left out of the ranking):")
            for c in hidden:
                lines.append(f"  {c.id:<14} aliases {c.alias_text(model)}; to separate: {c.advice}")
        return "\n".join(lines)

    def __str__(self) -> str:
        return self.report()

    @property
    def p_value(self) -> float:
        """``P(χ² ≥ observed)`` of the fit the candidates are ranked against (NaN without degrees of freedom)."""
        from scipy import stats

        nu = self.result.dof
        return float(stats.chi2.sf(self.result.chi2, nu)) if nu > 0 else float("nan")

    @property
    def outside_library(self) -> bool:
        """Whether χ² rejects the model and no candidate explains it (the residual is outside the library).

        Rejected: ``P(χ² ≥ observed)`` below the lower limit of :data:`~stableins.discovery.diagnostics.CONSISTENT_P_VALUES`;
        explained: some candidate is flagged (:func:`stableins.discovery.scores.explains`).
        """
        from stableins.discovery.diagnostics import CONSISTENT_P_VALUES

        return self.p_value < CONSISTENT_P_VALUES[0] and not self.flagged

    def outside_text(self) -> str:
        """Why the residual is outside the library, in words: χ²_ν, P, and what the best candidate would leave."""
        head = f"χ²_ν = {_chi2_red(self.result):.3g} (ν = {self.result.dof}, P = {self.p_value:.2g}) and no library effect explains it"
        best = next((c for c in self.candidates if c.identifiable), None)
        if best is None:
            return head
        return f"{head} (the best, {best.id}, {not_named_because(best.chi2_red_with, best.leaves, best.signature_p)})"

    def next_step(self) -> str:
        """Return what to do next, in one sentence (the reports and the ``diagnose --plots`` captions end with it).

        The best flagged candidate: add it (and whether a calibration can carry it, :func:`stableins.discovery.library.calibration_limit`),
        or how to tell it from the candidates it cannot be told from; nothing flagged: whether χ²_ν is at the noise floor.
        """
        from stableins.discovery.library import LIBRARY, calibration_limit

        best = next((c for c in self.candidates if c.flagged), None)
        if best is None:
            if self.outside_library:
                return f"outside the library: {self.outside_text()}; no certificate until it is understood"
            return "nothing flagged and χ²_ν at the noise floor: the model is complete for these data; nothing to add"
        value, sigma = best.estimate_engineering
        from stableins.display import unit_text, value_sigma

        found = f"{best.id} = {value_sigma(value, sigma, unit_text(best.term.unit))} (p = {best.p_value:.2g})"
        if best.confused_with:
            advice = best.advice.removeprefix("confirm with ")
            group = " or ".join((best.id, *best.confused_with))
            return f"{group}: these data cannot tell them apart ({found}); a position set that separates them: {advice}"
        if best.id not in LIBRARY:
            return f"next: add {found} to the model and refit"
        why = calibration_limit(best.id)
        if why is None:
            return f"next: add {found} and recalibrate with it (calibrate device --add {best.id})"
        return f"next: add {found} to the model (diagnose --add {best.id}); a calibration cannot carry it: {why}"

    def _head(self) -> str:
        flagged = len(self.flagged)
        return (
            f"{len(self.candidates)} candidates against the {self.result.stage} fit "
            f"(χ²_ν = {_chi2_red(self.result):.3f}, ν = {self.result.dof}); "
            f"{flagged} flagged at α = {self.alpha:g} over {self.n_tested} identifiable"
        )

    def _rows(self, top: int | None = None) -> list[list[str]]:
        from stableins.display import number, unit_text, value_sigma

        rows = []
        for k, c in enumerate(self.candidates[:top], 1):
            value, sigma = c.estimate_engineering
            ident = "yes" if c.identifiable else ("not excited" if not c.excited else "no")
            rows.append(
                [
                    f"{k}{'*' if c.flagged else ''}",
                    c.id,
                    f"{c.statistic:.2f}",
                    number(c.p_value, 2),
                    f"{c.delta_bic:+.1f}",
                    value_sigma(value, sigma, unit_text(c.term.unit)) if c.identifiable else "—",
                    ident + (f"; like {', '.join(c.confused_with)}" if c.confused_with else ""),
                ]
            )
        return rows

    def __repr__(self) -> str:
        from stableins.display import clipped

        lines = [
            f"<Ranking: {self._head()}>",
            f"{'rank':>4} {'id':<14} {'ΔRSS':>10} {'p':>8} {'ΔBIC':>9}  {'estimate ± 1σ':<26} identifiable",
        ]
        lines += [f"{r[0]:>4} {r[1]:<14} {r[2]:>10} {r[3]:>8} {r[4]:>9}  {r[5]:<26} {r[6]}" for r in self._rows(top=8)]
        hidden = [c.id for c in self.candidates if not c.identifiable and c.excited]
        if hidden:
            lines.append(f"not separable with these data: {', '.join(hidden[:8])}{' …' if len(hidden) > 8 else ''}")
        lines.append(self.next_step())
        return clipped(lines, "(* flagged; print(ranking) for the report, ranking.to_dataframe() for every candidate)")

    def _repr_html_(self) -> str:
        from stableins.display import html_result, html_table

        shown = self._rows(top=15)
        table = html_table(
            ["rank", "id", "ΔRSS", "p", "ΔBIC", "estimate ± 1σ", "identifiable"],
            shown,
            numeric=(0, 2, 3, 4, 5),
            titles=[c.term.meaning for c in self.candidates[: len(shown)]],
        )
        hidden = [
            f"{c.id}: aliases {c.alias_text(ErrorModel(self.result.terms))}; to separate: {c.advice}"
            for c in self.candidates
            if not c.identifiable and c.excited
        ]
        return html_result(
            "Ranking of candidate effects",
            [self._head(), "* flagged (Bonferroni); the 15 best shown, to_dataframe() has all", self.next_step()],
            [table],
            [("not separable with these data", hidden)],
        )

    def to_dataframe(self) -> Any:
        """Every candidate, best first, as a :class:`pandas.DataFrame` indexed by rank (1 = best).

        Columns ``id``, ``statistic`` (ΔRSS), ``p_value``, ``delta_bic``, ``estimate``, ``sigma``, ``unit`` (engineering),
        ``max_output_change`` (in :attr:`output_unit`), ``identifiable``, ``excited``, ``flagged``, ``refit``, ``aliases``,
        ``confused_with``, ``advice``.  Needs pandas (``pip install stableins[pandas]``).
        """
        from stableins.display import require_pandas

        pandas = require_pandas()
        rows = []
        for k, c in enumerate(self.candidates, 1):
            value, sigma = c.estimate_engineering
            rows.append(
                {
                    "rank": k,
                    "id": c.id,
                    "statistic": c.statistic,
                    "p_value": c.p_value,
                    "delta_bic": c.delta_bic,
                    "estimate": value if c.identifiable else float("nan"),
                    "sigma": sigma if c.identifiable else float("nan"),
                    "unit": c.term.unit,
                    f"max_output_change [{self.output_unit}]": c.predicted / self.output_scale,
                    "identifiable": c.identifiable,
                    "excited": c.excited,
                    "flagged": c.flagged,
                    "refit": c.refit,
                    "aliases": ", ".join(pid for pid, _ in c.aliases),
                    "confused_with": ", ".join(c.confused_with),
                    "advice": c.advice,
                }
            )
        return pandas.DataFrame.from_records(rows, index="rank")

    def to_json(self) -> list[dict]:
        """Return the JSON form of every candidate."""
        model = ErrorModel(self.result.terms)
        return [c.to_json(model) for c in self.candidates]


def rank(
    problem: Problem,
    result: FitResult,
    candidates: Iterable[Term] | None = None,
    *,
    alpha: float = 0.05,
    refit_top: int = 3,
    separation: dict[str, str] | None = None,
    propose: bool = True,
    output: DisplayUnit = MICRO_G_UNIT,
) -> Ranking:
    """Rank every candidate not in the model; refit the best ``refit_top`` with the full fitter.

    Parameters
    ----------
    problem : Problem
        The stage's least-squares problem (:mod:`stableins.discovery.problem`).
    result : FitResult
        The current fit.
    candidates : iterable of Term, optional
        Candidates (default: the whole default library).
    alpha : float
        Family-wise false-alarm level for flagging.
    refit_top : int
        How many of the best identifiable candidates to refit fully.
    separation : dict, optional
        Advice per id on what separates the effect (default: the library's).
    propose : bool
        For device dwell problems, test numerically which standard procedure extensions
        (:mod:`stableins.discovery.separation`) separate the excited candidates that are not
        separable or are confused with another, and add the answer to their advice.
    output : DisplayUnit
        The unit the largest predicted change of an observation is shown in (default µg).
    """
    from stableins.discovery.library import LIBRARY

    if candidates is None:
        candidates = LIBRARY.terms()
    if separation is None:
        separation = {c.id: c.separation for c in LIBRARY}
    model_ids = set(result.ids)
    terms = [t for t in candidates if t.id not in model_ids]
    r = whiten(problem, result, result.residuals)
    x = whiten(problem, result, problem.design(result))
    est_ids = [t.id for t, st in zip(result.terms, result.status, strict=True) if st == Status.ESTIMATED]
    m = r.size
    nu = result.dof
    rss0 = float(r @ r)
    raw_columns = candidate_columns(problem, terms, result)
    columns = whiten(problem, result, raw_columns)
    z_perp, norm_z, norm_perp, separability = _separability(x, columns)
    nominal = np.array([abs(t.nominal) for t in terms])
    excited = norm_z * nominal > EXCITATION_TOLERANCE
    identifiable = excited & (separability > IDENTIFIABLE_TOLERANCE)
    coef_alias, *_ = np.linalg.lstsq(x, columns, rcond=None)
    x_norm = np.linalg.norm(x, axis=0)
    n_tested = max(int(identifiable.sum()), 1)

    # one-step statistics for every identifiable candidate
    gamma, gsig, delta = _one_step(z_perp, norm_perp, r, identifiable)

    # pairwise confusion among identifiable candidates
    unit_perp = np.where(identifiable, z_perp / np.where(norm_perp > 0, norm_perp, 1.0), 0.0)
    corr = np.abs(unit_perp.T @ unit_perp)

    scores: list[CandidateScore] = []
    for k, t in enumerate(terms):
        contrib = np.abs(coef_alias[:, k]) * x_norm
        total = np.linalg.norm(columns[:, k])
        aliases = tuple((est_ids[j], float(coef_alias[j, k])) for j in np.argsort(-contrib) if total > 0 and contrib[j] > 0.1 * total)[:4]
        confused = tuple(terms[j].id for j in np.flatnonzero(corr[k] > CONFUSION_CORRELATION) if j != k) if identifiable[k] else ()
        advice = separation.get(t.id, t.excitation)
        stat, p, dbic = effect_statistics(delta[k], rss0, nu, m) if identifiable[k] else (0.0, 1.0, float(np.log(m)))
        scores.append(
            CandidateScore(
                id=t.id,
                term=t,
                statistic=stat,
                p_value=p,
                delta_bic=dbic,
                estimate=float(gamma[k]),
                sigma=float(gsig[k]),
                predicted=float(np.max(np.abs(raw_columns[:, k] * gamma[k]))) if identifiable[k] else 0.0,
                identifiable=bool(identifiable[k]),
                excited=bool(excited[k]),
                separability=float(separability[k]),
                aliases=aliases,
                confused_with=confused,
                advice=advice if not identifiable[k] else f"confirm with {advice}",
            )
        )
    scores.sort(key=lambda c: (not c.identifiable, -c.statistic))
    if propose and isinstance(problem, DwellProblem):
        scores = _propose(problem, result, scores, {t.id: t for t in terms})

    scores = _refit_best(problem, result, scores, refit_top=refit_top, nu=nu, m=m)
    first = {t.id: f"confirm with {separation.get(t.id, t.excitation)}" for t in terms}
    # static dwells (DwellProblem.static): the exact family level and the laboratory signature; else Bonferroni's α/N
    level = family_level(x, z_perp[:, identifiable], nu=nu, alpha=alpha) if problem.static else alpha / n_tested
    scores = _best_group(problem, result, scores, {t.id: t for t in terms}, first, level=level, propose=propose)
    whitened = _Whitened(r, z_perp, identifiable, _laboratory(problem, result, x) if problem.static else None)
    flagged = _named(scores, [t.id for t in terms], whitened, rss0=rss0, nu=nu, level=level)
    return Ranking(result, tuple(flagged), alpha, n_tested, output.name, output.scale, level)


#: Draws of the null distribution of the largest statistic (:func:`family_level`), and the fixed seed that makes it
#: deterministic (the same data give the same flags).
NULL_DRAWS = 8000
NULL_SEED = 20251129


def family_level(x: NDArray[np.float64], z_perp: NDArray[np.float64], *, nu: int, alpha: float) -> float:
    r"""Return the per-candidate p-value level at which the family of candidates raises a false flag with probability ``α``.

    With no effect the whitened residual is ``r = (I − H) e``, ``e ~ N(0, I_m)``, and the F-test of candidate ``j``
    is monotone in ``t_j = (u_jᵀ r)²/‖r‖²`` (``u_j = z⊥_j/‖z⊥_j‖``).  The ``1 − α`` quantile ``t*`` of
    ``max_j t_j`` over :data:`NULL_DRAWS` draws (seed :data:`NULL_SEED`) gives ``F* = (ν − 1) t*/(1 − t*)`` and the
    level ``P(F(1, ν − 1) > F*)``: the family-wise rate is ``α`` in this fit's own geometry (Westfall & Young 1993,
    *Resampling-Based Multiple Testing*, the single-step max-T method), where Bonferroni's ``α/N`` is conservative for
    correlated candidates.  ``x`` is the whitened design, ``z_perp`` the identifiable candidates' columns orthogonal to it.
    """
    from scipy import stats

    norms = np.linalg.norm(z_perp, axis=0)
    n = int(np.count_nonzero(norms > 0))
    if n == 0 or nu < 2:
        return alpha / max(n, 1)
    units = z_perp[:, norms > 0] / norms[norms > 0]
    q, _ = np.linalg.qr(x)
    rng = np.random.default_rng(NULL_SEED)
    largest = []
    for _ in range(NULL_DRAWS // 500):
        e = rng.standard_normal((x.shape[0], 500))
        e -= q @ (q.T @ e)
        largest.append(np.max((units.T @ e) ** 2, axis=0) / np.sum(e * e, axis=0))
    t = float(np.quantile(np.concatenate(largest), 1.0 - alpha))
    f = (nu - 1) * t / max(1.0 - t, 1e-300)
    return max(float(stats.f.sf(f, 1, nu - 1)), alpha / n)


@dataclass(frozen=True)
class _Whitened:
    """The whitened residual, the candidates' columns orthogonal to the model, which are identifiable, the laboratory columns."""

    r: NDArray[np.float64]
    z_perp: NDArray[np.float64]
    identifiable: NDArray[np.bool_]
    laboratory: NDArray[np.float64] | None


def _named(scores: list[CandidateScore], ids: list[str], w: _Whitened, *, rss0: float, nu: int, level: float) -> list[CandidateScore]:
    """Return the scores with the naming rule applied (module docstring, "Flagging").

    Named: significant at ``level`` (Bonferroni), adding it brings ``χ²_ν`` into its band, no other candidate stays
    significant with it, and (device dwells) the residual with it has no signature left along a laboratory-fixed
    direction (:func:`_signature_left`).
    """
    flagged = []
    index = {i: k for k, i in enumerate(ids)}
    for c in scores:
        after, explained = explains(rss0, c.statistic, nu) if c.identifiable else (float("nan"), False)
        significant = bool(c.identifiable and c.p_value < level)
        remaining: tuple[int, ...] = ()
        if significant and explained:
            remaining = _still_significant(index[c.id], w.z_perp, w.r, w.identifiable, nu=nu, level=level)
        signature_p = float("nan")
        if significant and explained and not remaining and w.laboratory is not None:
            signature_p = _signature_left(index[c.id], w.z_perp, w.r, w.laboratory, nu=nu)
        alone = explained and not remaining and not signature_p < SIGNATURE_ALPHA
        named = {"flagged": significant and alone, "chi2_red_with": after, "explains": alone, "signature_p": signature_p}
        flagged.append(CandidateScore(**{**c.__dict__, **named, "leaves": tuple(ids[j] for j in remaining)}))
    return flagged


def _best_group(
    problem: Problem,
    result: FitResult,
    scores: list[CandidateScore],
    by_id: dict[str, Term],
    advice: dict[str, str],
    *,
    level: float,
    propose: bool,
) -> list[CandidateScore]:
    """Return the scores with the best group joined (module docstring, "The best group"), when the best is significant.

    Every identifiable candidate whose ``ΔRSS`` is within :data:`GROUP_MARGIN` of the best's is added to the best's
    ``confused_with`` and the best to each of theirs; the best's advice then names positions that separate them.
    """
    best = scores[0] if scores else None
    if best is None or not best.identifiable or not best.p_value < level:
        return scores
    rivals = [c.id for c in scores[1:] if c.identifiable and best.statistic - c.statistic <= GROUP_MARGIN]
    joined = tuple(dict.fromkeys((*best.confused_with, *rivals)))
    if joined == best.confused_with:
        return scores
    out = []
    for c in scores:
        if c.id == best.id:
            c = CandidateScore(**{**c.__dict__, "confused_with": joined, "advice": advice[c.id]})
            if propose and isinstance(problem, DwellProblem):
                c = _propose(problem, result, [c], by_id)[0]
        elif c.id in rivals:
            c = CandidateScore(**{**c.__dict__, "confused_with": tuple(dict.fromkeys((*c.confused_with, best.id)))})
        out.append(c)
    return out


def _laboratory(problem: Problem, result: FitResult, x: NDArray[np.float64]) -> NDArray[np.float64] | None:
    """Return the laboratory-direction columns of device dwells, whitened, orthonormal and orthogonal to the model.

    :func:`stableins.discovery.signature.laboratory_columns`, less their part in the span of the whitened design ``x``;
    None for other problems or when the model spans them.
    """
    from stableins.discovery.signature import laboratory_columns

    if not isinstance(problem, DwellProblem):
        return None
    dwells = problem.dwells
    columns = whiten(problem, result, laboratory_columns(dwells.readings, dwells.base_attitude, dwells.configuration))
    q, _ = np.linalg.qr(x)
    columns = columns - q @ (q.T @ columns)
    u, s, _ = np.linalg.svd(columns, full_matrices=False)
    keep = s > 1e-6 * max(float(s[0]) if s.size else 0.0, 1e-300)
    return u[:, keep] if np.any(keep) else None


def _signature_left(k: int, z_perp: NDArray[np.float64], r: NDArray[np.float64], laboratory: NDArray[np.float64], *, nu: int) -> float:
    r"""Return the p-value of the residual, with candidate ``k`` added, along the laboratory directions (module docstring).

    One Gauss–Newton step as in :func:`_still_significant`: ``r' = r − u uᵀr``; the laboratory columns ``L`` (orthonormal,
    orthogonal to the model) less their part along ``u``; ``F = (‖Qᵀr'‖²/d) / ((‖r'‖² − ‖Qᵀr'‖²)/(ν − 1 − d))`` against
    ``F(d, ν − 1 − d)`` with ``Q`` an orthonormal basis of those ``d`` columns.
    """
    from scipy import stats

    u = z_perp[:, k] / np.linalg.norm(z_perp[:, k])
    rest = r - u * float(u @ r)
    columns = laboratory - np.outer(u, u @ laboratory)
    q, s, _ = np.linalg.svd(columns, full_matrices=False)
    q = q[:, s > 1e-6 * max(float(s[0]) if s.size else 0.0, 1e-300)]
    d = q.shape[1]
    dof = nu - 1 - d
    if d == 0 or dof < 1:
        return float("nan")
    taken = float(np.sum((q.T @ rest) ** 2))
    return float(stats.f.sf((taken / d) / max((float(rest @ rest) - taken) / dof, 1e-300), d, dof))


def _still_significant(
    k: int, z_perp: NDArray[np.float64], r: NDArray[np.float64], identifiable: NDArray[np.bool_], *, nu: int, level: float
) -> tuple[int, ...]:
    r"""Return the candidates still significant once candidate ``k`` is added: then ``k`` alone does not explain the residual.

    One Gauss–Newton step: with ``u = z⊥_k/‖z⊥_k‖`` the residual becomes ``r' = r − u uᵀr`` and each other column
    ``z'_j = z⊥_j − u uᵀz⊥_j``; ``ΔRSS_j = (z'_jᵀr')²/‖z'_j‖²`` against ``F(1, ν − 2)``, significant below the same
    Bonferroni level.  A column ``k`` takes (nearly) whole (``‖z'_j‖ < 1e-3 ‖z⊥_j‖``: indistinguishable) is skipped.
    """
    from scipy import stats

    u = z_perp[:, k] / np.linalg.norm(z_perp[:, k])
    rest = r - u * float(u @ r)
    columns = z_perp - np.outer(u, u @ z_perp)
    norms = np.linalg.norm(columns, axis=0)
    rss1 = float(rest @ rest)
    dof = max(nu - 2, 1)
    out = []
    for j in np.flatnonzero(identifiable):
        if j == k or norms[j] < 1e-3 * max(float(np.linalg.norm(z_perp[:, j])), 1e-300):
            continue
        delta = float(columns[:, j] @ rest) ** 2 / norms[j] ** 2
        if float(stats.f.sf(delta / max((rss1 - delta) / dof, 1e-300), 1, dof)) < level:
            out.append(int(j))
    return tuple(out)


def _separability(
    x: NDArray[np.float64], columns: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Candidate columns orthogonal to the whitened design ``x``, the norms before and after, and their ratio."""
    q, _ = np.linalg.qr(x)
    z_perp = columns - q @ (q.T @ columns)
    norm_z = np.linalg.norm(columns, axis=0)
    norm_perp = np.linalg.norm(z_perp, axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        separability = np.where(norm_z > 0, norm_perp / np.where(norm_z > 0, norm_z, 1.0), 0.0)
    return z_perp, norm_z, norm_perp, separability


def _one_step(
    z_perp: NDArray[np.float64], norm_perp: NDArray[np.float64], r: NDArray[np.float64], identifiable: NDArray[np.bool_]
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """One-step estimate ``γ``, its 1σ and the fall of the residual sum of squares of each identifiable candidate."""
    proj = z_perp.T @ r
    with np.errstate(invalid="ignore", divide="ignore"):
        gamma = np.where(identifiable, proj / np.where(identifiable, norm_perp**2, 1.0), 0.0)
        gsig = np.where(identifiable, 1.0 / np.where(identifiable, norm_perp, 1.0), np.inf)
    delta = np.where(identifiable, gamma * proj, 0.0)
    return gamma, gsig, delta


def _refit_best(
    problem: Problem, result: FitResult, scores: list[CandidateScore], *, refit_top: int, nu: int, m: int
) -> list[CandidateScore]:
    """Return the scores with the best ``refit_top`` identifiable candidates refitted by the full fitter, best first."""
    refits = []
    model = ErrorModel(result.terms)
    for c in [c for c in scores if c.identifiable][:refit_top]:
        refits.append(refit(problem, result, model, c, nu=nu, m=m))
    by_id = {c.id: c for c in refits}
    scores = [by_id.get(c.id, c) for c in scores]
    scores.sort(key=lambda c: (not c.identifiable, -c.statistic))
    return scores
