r"""The discovery loop: fit, rank, add an effect, refit — and the history of steps.

:class:`Discovery` keeps the current model and fit of one problem and a
:class:`History` of every step, so the user sees the error fall to the noise floor::

    session = Discovery(problem, ErrorModel.standard(gimbals=True))
    print(session.diagnose())          # where it fails
    print(session.rank())              # which effect is missing
    session.add("Kcc_xxy")             # model + effect, refit
    print(session.history)             # residual RMS, χ²_ν, BIC per step
    session.history.plot()

``BIC = χ² + k ln m`` with the measured σ (k estimated parameters, m observations).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from stableins.conventions import MICRO_G
from stableins.errormodel import ErrorModel, Term
from stableins.estimators.result import FitResult

if TYPE_CHECKING:  # pragma: no cover
    from matplotlib.figure import Figure

    from stableins.discovery.diagnostics import Diagnosis
    from stableins.discovery.library import Library
    from stableins.discovery.ranking import Ranking


@dataclass(frozen=True)
class Step:
    """One model in the history.

    Attributes
    ----------
    label : str
        ``"standard"`` or ``"+ Kcc_xxy"``.
    model_ids : tuple of str
        Parameter ids of the model.
    rms : ndarray (3,) or (1,)
        Residual RMS per output axis [SI].
    noise_floor : ndarray
        RMS of the measured 1σ per output axis [SI].
    chi2_red, dof, bic : float, int, float
        Goodness of fit.
    added : tuple of (id, value, sigma, unit)
        Estimates of the effects added at this step, in engineering units.
    shifts : dict
        Existing parameter id → (shift in engineering units, unit, shift / old 1σ).
    """

    label: str
    model_ids: tuple[str, ...]
    rms: np.ndarray
    noise_floor: np.ndarray
    chi2_red: float
    dof: int
    bic: float
    added: tuple[tuple[str, float, float, str], ...] = ()
    shifts: dict = field(default_factory=dict)

    def to_json(self) -> dict:
        return {
            "label": self.label,
            "model": list(self.model_ids),
            "residual_rms": [float(x) for x in self.rms],
            "residual_rms_unit": "m/s^2",
            "noise_floor": [float(x) for x in self.noise_floor],
            "chi2_red": float(self.chi2_red),
            "dof": int(self.dof),
            "bic": float(self.bic),
            "added": [{"id": i, "estimate": v, "sigma": s, "unit": u} for i, v, s, u in self.added],
            "shifts": {k: {"shift": v[0], "unit": v[1], "in_sigma": v[2]} for k, v in self.shifts.items()},
        }


def _per_axis(result: FitResult, values) -> np.ndarray:
    v = np.asarray(values, dtype=float)
    if v.size % 3 == 0 and all(lbl.endswith(("f_x", "f_y", "f_z")) for lbl in result.residual_labels[:3]):
        return np.sqrt(np.mean(v.reshape(-1, 3) ** 2, axis=0))
    return np.sqrt(np.mean(v**2, keepdims=True))


def make_step(result: FitResult, label: str, previous: FitResult | None = None) -> Step:
    """Summarize a fit as a history step (and what changed since ``previous``)."""
    from stableins.discovery.problem import fit_chi2, fit_chi2_red

    k = result.rank
    m = result.residuals.size
    added = ()
    shifts: dict = {}
    if previous is not None:
        old = dict(zip(previous.ids, zip(previous.values, previous.sigma, previous.status, strict=True), strict=True))
        new_ids = [t for t in result.terms if t.id not in old]
        added = tuple(
            (t.id, float(t.to_engineering(result[t.id][0])), float(t.sigma_to_engineering(result[t.id][1])), t.unit) for t in new_ids
        )
        for t in result.terms:
            if t.id in old and old[t.id][2] == "estimated":
                v0, s0, _ = old[t.id]
                dv = result[t.id][0] - v0
                shifts[t.id] = (float(dv / t.scale), t.unit, float(dv / s0) if s0 > 0 else float("nan"))
    return Step(
        label=label,
        model_ids=result.ids,
        rms=_per_axis(result, result.residuals),
        noise_floor=_per_axis(result, result.residual_sigma),
        chi2_red=fit_chi2_red(result),
        dof=result.dof,
        bic=float(fit_chi2(result) + k * np.log(m)),
        added=added,
        shifts=shifts,
    )


class History:
    """Steps of the discovery loop, printed and plotted."""

    def __init__(self, steps: Iterable[Step] = ()) -> None:
        self.steps: list[Step] = list(steps)

    def append(self, step: Step) -> None:
        self.steps.append(step)

    def __len__(self) -> int:
        return len(self.steps)

    def __getitem__(self, k: int) -> Step:
        return self.steps[k]

    def report(self) -> str:
        if not self.steps:
            return "(no steps)"
        n_ax = self.steps[0].rms.size
        axes = ("x", "y", "z") if n_ax == 3 else ("all",)
        head = f"{'step':>4} {'model':<26}" + "".join(f" {'RMS ' + a + ' [µg]':>11}" for a in axes) + f" {'χ²_ν':>8} {'±':>5} {'BIC':>10}"
        lines = [head]
        for k, s in enumerate(self.steps):
            spread = np.sqrt(2.0 / max(s.dof, 1))
            row = f"{k:>4} {s.label:<26}" + "".join(f" {x / MICRO_G:>11.3f}" for x in s.rms)
            lines.append(row + f" {s.chi2_red:>8.3f} {spread:>5.2f} {s.bic:>10.1f}")
        floor = self.steps[-1].noise_floor
        lines.append(f"{'':>4} {'noise floor':<26}" + "".join(f" {x / MICRO_G:>11.3f}" for x in floor) + f" {1.0:>8.3f}")
        for k, s in enumerate(self.steps):
            if not s.added:
                continue
            lines.append("")
            lines.append(f"step {k} ({s.label}): " + "; ".join(f"{i} = {v:+.4g} ± {sg:.2g} {u}" for i, v, sg, u in s.added))
            big = sorted(s.shifts.items(), key=lambda kv: -abs(kv[1][2]))[:6]
            if big:
                lines.append("  shifts of existing parameters (largest, in units of their previous 1σ):")
                lines += [f"    {pid:<10} {v:+.4g} {u} ({z:+.1f}σ)" for pid, (v, u, z) in big]
        return "\n".join(lines)

    def __str__(self) -> str:
        return self.report()

    def to_json(self) -> list[dict]:
        return [s.to_json() for s in self.steps]

    def plot(self, fig: Figure | None = None) -> Figure:
        """Residual RMS per axis against step (with the noise floor) and χ²_ν with its expected band."""
        import matplotlib.pyplot as plt

        fig = fig or plt.figure(figsize=(9, 4.5))
        ax1, ax2 = fig.subplots(1, 2)
        k = np.arange(len(self.steps))
        rms = np.array([s.rms for s in self.steps]) / MICRO_G
        floor = np.array([s.noise_floor for s in self.steps]) / MICRO_G
        names = ("x", "y", "z") if rms.shape[1] == 3 else ("all",)
        for i, a in enumerate(names):
            (line,) = ax1.semilogy(k, rms[:, i], "o-", label=f"residual RMS f_{a}")
            ax1.semilogy(k, floor[:, i], "--", color=line.get_color(), lw=0.8)
        ax1.set_ylabel("µg (dashed: noise floor)")
        ax1.legend(fontsize=8)
        chi = np.array([s.chi2_red for s in self.steps])
        spread = np.array([np.sqrt(2.0 / max(s.dof, 1)) for s in self.steps])
        ax2.semilogy(k, chi, "o-", label="χ²_ν")
        ax2.fill_between(k, np.maximum(1 - 2 * spread, 1e-2), 1 + 2 * spread, color="0.85", label="1 ± 2√(2/ν)")
        ax2.legend(fontsize=8)
        labels = [s.label for s in self.steps]
        for ax in (ax1, ax2):
            ax.set_xticks(k, labels, rotation=30, ha="right", fontsize=8)
            ax.grid(alpha=0.3, which="both")
        fig.tight_layout()
        return fig


class Discovery:
    """Fit → diagnose → rank → add → refit, with a history.

    Parameters
    ----------
    problem : Problem
        The stage's least-squares problem.
    model : ErrorModel
        The starting model.
    library : Library, optional
        Candidate effects (default: the default library with any registered custom effects).
    alpha : float
        Family-wise false-alarm level for flagging candidates.
    start : mapping, optional
        Starting parameter values (e.g. from a calibration record).
    """

    def __init__(self, problem, model: ErrorModel, library: Library | None = None, alpha: float = 0.05, start=None) -> None:
        from stableins.discovery.library import LIBRARY

        self.problem = problem
        self.library = library if library is not None else LIBRARY
        self.alpha = alpha
        self.model = model
        self.result = problem.fit(model, start=start)
        self.history = History([make_step(self.result, "standard model")])
        self._ranking: Ranking | None = None

    def diagnose(self) -> Diagnosis:
        from stableins.discovery.diagnostics import diagnose

        return diagnose(self.problem, self.result)

    def rank(self, refit_top: int = 3, propose: bool = True) -> Ranking:
        """Rank every library candidate not in the model (see :func:`stableins.discovery.ranking.rank`)."""
        from stableins.discovery.ranking import rank

        self._ranking = rank(
            self.problem,
            self.result,
            self.library.terms(),
            alpha=self.alpha,
            refit_top=refit_top,
            separation={c.id: c.separation for c in self.library},
            propose=propose,
        )
        return self._ranking

    def drift(self, refit_top: int = 3) -> Ranking | None:
        """Rank the platform-drift candidates ``Dg_*`` on the reading slopes within dwells (None: too few usable slopes,
        ``drift_notes`` says why).

        Uses the zero offsets of the current fit for the actual angles; see
        :mod:`stableins.discovery.drift`.  Needs a dwell problem whose dwells carry slopes.
        """
        from stableins.discovery.drift import drift_problem
        from stableins.discovery.ranking import rank

        dwells = getattr(self.problem, "dwells", None)
        if dwells is None or dwells.reading_slope is None:
            raise ValueError("these data carry no reading slopes (device dwells are needed)")
        values = self.result.as_dict()
        offsets = [values.get(i, 0.0) for i in ("theta10", "theta20", "theta30")]
        problem, null, terms, notes = drift_problem(dwells, dwells.reading_slope, dwells.reading_slope_sigma, offsets)
        if problem.y.size <= len(null) + len(terms):
            self.drift_notes = notes + (
                f"only {problem.y.size // 3} dwell(s) with usable reading slopes: too few to rank the drift candidates",
            )
            return None
        arcsec_per_hour = np.pi / 648000 / 3600
        fit = problem.fit(null)
        ranking = rank(
            problem, fit, terms, alpha=self.alpha, refit_top=refit_top, propose=False, output_unit='"/h', output_scale=arcsec_per_hour
        )
        self.drift_notes = notes
        return ranking

    def _term(self, effect: str | Term) -> Term:
        return effect if isinstance(effect, Term) else self.library[effect].term

    def add(self, *effects: str | Term) -> FitResult:
        """``model + effect`` and refit; the step goes into the history."""
        terms = [self._term(e) for e in effects]
        previous = self.result
        self.model = self.model + terms
        self.result = self.problem.fit(self.model, start=previous.as_dict())
        self.history.append(make_step(self.result, "+ " + ", ".join(t.id for t in terms), previous))
        self._ranking = None
        return self.result

    def auto(self, max_steps: int = 5) -> History:
        """Add the best flagged, identifiable candidate until none is flagged (or ``max_steps``)."""
        for _ in range(max_steps):
            best = self.rank(refit_top=1, propose=False).best
            if best is None or not best.flagged:
                break
            self.add(best.term)
        return self.history
