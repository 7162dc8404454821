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

The same :class:`ModelStep` is the unit of the history a calibration record carries
(:class:`ModelHistory`, the record's ``discovery`` section, docs/formats.md): there every
step after the first tests one effect added to the calibration (``calibrate device --add``)
and carries its verdict (:class:`Decision`, Δχ², F-test p, ΔBIC).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from stableins.conventions import ARCSEC_PER_HOUR, MICRO_G
from stableins.discovery.problem import DwellProblem
from stableins.discovery.steps import Decision, ModelStep, is_number, make_step
from stableins.display import clipped, html_result, html_table, layout_with_caption, plot_text, require_pandas, unit_text, value_sigma
from stableins.errormodel import GIMBAL_IDS, ErrorModel, Term
from stableins.estimators.result import FitResult

if TYPE_CHECKING:  # pragma: no cover
    from matplotlib.figure import Figure

    from stableins.discovery.diagnostics import Diagnosis
    from stableins.discovery.library import Library
    from stableins.discovery.ranking import Ranking
    from stableins.estimators.leastsquares import Problem


@dataclass(frozen=True)
class ModelHistory:
    """The discovery history a calibration record carries (its ``discovery`` section).

    Attributes
    ----------
    stage : str
        The fit whose model grew (``"coarse+fine"``: the fused device-level fit).
    alpha : float
        False-alarm level of the F-test that keeps an added effect.
    steps : tuple of ModelStep
        The baseline first, then one step per effect tested, each with its :class:`Decision`.
    """

    stage: str
    alpha: float
    steps: tuple[ModelStep, ...]

    @property
    def effects(self) -> tuple[str, ...]:
        """Effects in the model in force: those whose step was kept."""
        return tuple(s.added[0][0] for s in self.steps[1:] if s.decision is not None and s.decision.in_model)

    def to_json(self) -> dict:
        """Return the JSON form stored in a calibration record."""
        return {"stage": self.stage, "alpha": self.alpha, "steps": [s.to_json() for s in self.steps]}

    @classmethod
    def from_json(cls, document: Any, where: str = "discovery") -> ModelHistory:
        """Validate the section; ``ValueError`` naming the key (the record reader adds the file)."""
        if not isinstance(document, Mapping):
            raise ValueError(f"{where}: expected an object with stage, alpha and steps")
        stage, alpha, steps = document.get("stage"), document.get("alpha"), document.get("steps")
        if not isinstance(stage, str) or not stage:
            raise ValueError(f"{where}.stage: expected the name of the fit, e.g. 'coarse+fine'")
        if not is_number(alpha) or not 0.0 < alpha < 1.0:
            raise ValueError(f"{where}.alpha: expected a false-alarm level between 0 and 1")
        if not isinstance(steps, list) or not steps:
            raise ValueError(f"{where}.steps: expected a non-empty list of steps")
        parsed = tuple(ModelStep.from_json(step, f"{where}.steps[{k}]") for k, step in enumerate(steps))
        if parsed[0].decision is not Decision.BASELINE:
            raise ValueError(f"{where}.steps[0].decision: expected 'baseline' (the model before any effect was added)")
        for k, step in enumerate(parsed[1:], start=1):
            if step.decision is None or step.decision is Decision.BASELINE or len(step.added) != 1:
                raise ValueError(f"{where}.steps[{k}]: expected one tested effect in 'added' and its decision")
        return cls(stage, float(alpha), parsed)

    def report(self) -> str:
        """Return the steps (:meth:`History.report`) and the verdict on every tested effect."""
        lines = [f"model discovery carried into the calibration ({self.stage} fit; an added effect stays when F-test p < {self.alpha:g}):"]
        lines.append(History(self.steps).report())
        verdicts = [s for s in self.steps[1:] if s.decision is not None]
        if verdicts:
            lines += ["", "verdicts:"] + [f"  {s.added[0][0]}: {s.decision}. {s.reason}" for s in verdicts]
        return "\n".join(lines)

    def __str__(self) -> str:
        return self.report()

    def _head(self) -> str:
        kept = self.effects
        return (
            f"model discovery of the {self.stage} fit, {len(self.steps)} steps; model in force: standard"
            + "".join(f" + {e}" for e in kept)
            + f" (an effect stays when F-test p < {self.alpha:g})"
        )

    def __repr__(self) -> str:
        history = History(self.steps)
        verdicts = [f"{s.added[0][0]}: {s.decision}" for s in self.steps[1:] if s.decision is not None and s.added]
        lines = [f"<ModelHistory: {self._head()}>", *history._table_lines(), *history._added_lines()]
        if verdicts:
            lines.append("verdicts: " + "; ".join(verdicts))
        return clipped(lines, "(print(history) for the verdicts in words, history.to_dataframe(), history.plot())")

    def _repr_html_(self) -> str:
        history = History(self.steps)
        table = html_table(history._columns(), history._rows(), numeric=range(2, len(history._columns()) - 1))
        verdicts = [f"{s.added[0][0]}: {s.decision}. {s.reason}" for s in self.steps[1:] if s.decision is not None and s.added]
        return html_result(self._head()[0].upper() + self._head()[1:], history._added_lines(), [table], [("verdicts", verdicts)])

    def to_dataframe(self) -> Any:
        """Return the steps with their verdicts (:meth:`History.to_dataframe`)."""
        return History(self.steps).to_dataframe()

    def plot(self, fig: Figure | None = None, *, title: str | None = None) -> Figure:
        """Plot the steps with their verdicts (:meth:`History.plot`)."""
        return History(self.steps).plot(fig, title=title)


class History:
    """Steps of the discovery loop, printed and plotted."""

    def __init__(self, steps: Iterable[ModelStep] = ()) -> None:
        self.steps: list[ModelStep] = list(steps)

    def append(self, step: ModelStep) -> None:
        """Append a step."""
        self.steps.append(step)

    def __len__(self) -> int:
        return len(self.steps)

    def __getitem__(self, k: int) -> ModelStep:
        return self.steps[k]

    def _columns(self) -> list[str]:
        """Column names of :meth:`_rows` (RMS per output channel in µg, χ²_ν and its spread, BIC, verdict columns if any)."""
        axes = [c.removeprefix("f_") for c in self.steps[0].channels]
        verdicts = any(s.decision is not None for s in self.steps)
        return ["step", "model", *(f"RMS {a} [µg]" for a in axes), "χ²_ν", "±", "BIC"] + (["p", "ΔBIC", "decision"] if verdicts else [])

    def _rows(self) -> list[list[str]]:
        """One row of text per step, then the noise floor."""
        verdicts = any(s.decision is not None for s in self.steps)
        rows = []
        for k, s in enumerate(self.steps):
            spread = np.sqrt(2.0 / max(s.dof, 1))
            row = [str(k), s.label, *(f"{x / MICRO_G:.3f}" for x in s.rms), f"{s.chi2_red:.3f}", f"{spread:.2f}", f"{s.bic:.1f}"]
            if verdicts:
                row += ["" if math.isnan(s.p_value) else f"{s.p_value:.2g}", "" if math.isnan(s.delta_bic) else f"{s.delta_bic:.1f}"]
                row.append(str(s.decision or ""))
            rows.append(row)
        floor = self.steps[-1].noise_floor
        rows.append(["", "noise floor", *(f"{x / MICRO_G:.3f}" for x in floor), "1.000"] + [""] * (len(rows[0]) - 3 - len(floor)))
        return rows

    def _table_lines(self) -> list[str]:
        """:meth:`_columns` and :meth:`_rows` as aligned text (the report's table)."""
        columns = self._columns()
        channels = len(self.steps[0].channels)
        widths = [4, -26, *([11] * channels), 8, 5, 10] + ([9, 8, -1] if columns[-1] == "decision" else [])
        lines = []
        for row in [columns, *self._rows()]:
            cells = [f"{cell:<{-w}}" if w < 0 else f"{cell:>{w}}" for cell, w in zip(row, widths, strict=True)]
            if columns[-1] == "decision":
                cells[-1] = " " + cells[-1]
            lines.append(" ".join(cells).rstrip())
        return lines

    def report(self) -> str:
        """Return the history in words: the table of steps, then the verdict and shifts of each."""
        if not self.steps:
            return "(no steps)"
        lines = self._table_lines()
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

    def _added_lines(self) -> list[str]:
        return [
            f"step {k} ({s.label}): " + "; ".join(f"{i} = {value_sigma(v, sg, unit_text(u))}" for i, v, sg, u in s.added)
            for k, s in enumerate(self.steps)
            if s.added
        ]

    def __repr__(self) -> str:
        if not self.steps:
            return "<History: no steps>"
        lines = [f"<History: {len(self.steps)} step{'s' if len(self.steps) != 1 else ''} of the discovery loop>", *self._table_lines()]
        return clipped(lines + self._added_lines(), "(print(history) for the shifts of every step, history.to_dataframe(), history.plot())")

    def _repr_html_(self) -> str:
        if not self.steps:
            return html_result("Discovery history: no steps")
        table = html_table(self._columns(), self._rows(), numeric=range(2, len(self._columns()) - 1))
        return html_result(f"Discovery history: {len(self.steps)} steps", self._added_lines(), [table])

    def to_dataframe(self) -> Any:
        """One row per step as a :class:`pandas.DataFrame` indexed by step number.

        Columns ``label``, ``model`` (the parameter ids, comma-separated), ``rms <channel> [µg]`` and
        ``noise floor <channel> [µg]`` per output channel, ``chi2_red``, ``dof``, ``spread`` (``sqrt(2/ν)``), ``bic``,
        ``added`` (the effects added at the step with estimate ± 1σ), and for a calibration's history ``decision``,
        ``delta_chi2``, ``p_value``, ``delta_bic``, ``reason``.  Needs pandas (``pip install stableins[pandas]``).
        """
        pandas = require_pandas()
        rows = []
        for k, s in enumerate(self.steps):
            row: dict[str, Any] = {"step": k, "label": s.label, "model": ", ".join(s.model_ids)}
            row.update({f"rms {c} [µg]": x / MICRO_G for c, x in zip(s.channels, s.rms, strict=True)})
            row.update({f"noise floor {c} [µg]": x / MICRO_G for c, x in zip(s.channels, s.noise_floor, strict=True)})
            row.update(chi2_red=s.chi2_red, dof=s.dof, spread=float(np.sqrt(2.0 / max(s.dof, 1))), bic=s.bic)
            row["added"] = "; ".join(f"{i} = {value_sigma(v, sg, unit_text(u))}" for i, v, sg, u in s.added)
            if s.decision is not None:
                row.update(decision=str(s.decision), delta_chi2=s.delta_chi2, p_value=s.p_value, delta_bic=s.delta_bic, reason=s.reason)
            rows.append(row)
        return pandas.DataFrame.from_records(rows, index="step")

    def to_json(self) -> list[dict]:
        """Return the JSON form of the steps."""
        return [s.to_json() for s in self.steps]

    def plot(self, fig: Figure | None = None, *, title: str | None = None, next_step: str | None = None) -> Figure:
        """Residual RMS per output channel against its noise floor, and χ²_ν against its expected band, per step.

        Left: for every step (named on the x axis, with its verdict in a calibration's history) the residual RMS of
        each channel [µg] as a coloured marker and that channel's noise floor as a black bar beside it, values
        written.  Right: χ²_ν with the band ``1 ± 2√(2/ν)`` of its step.  A single step is drawn as well as many.
        ``next_step``: a caption under the figure.
        """
        import matplotlib.pyplot as plt

        steps = self.steps
        if not steps:
            raise ValueError("the history has no steps to plot")
        fig = fig or plt.figure(figsize=(max(9.0, 3.2 + 2.2 * len(steps)), 4.8 + (0.35 if next_step else 0.0)))
        ax1, ax2 = fig.subplots(1, 2, gridspec_kw={"width_ratios": [3, 2]})
        k = np.arange(len(steps))
        _plot_rms(ax1, steps)
        _plot_chi2(ax2, steps)
        shown = [s.decision if s.decision is not None and s.decision is not Decision.BASELINE else None for s in steps]
        labels = [plot_text(s.label) + (f"\n({d})" if d is not None else "") for s, d in zip(steps, shown, strict=True)]
        for ax in (ax1, ax2):
            ax.set_xlim(-0.6, len(steps) - 0.4)
            ax.set_xticks(k, labels, rotation=20 if len(steps) > 3 else 0, ha="right" if len(steps) > 3 else "center", fontsize=8)
            ax.set_xlabel("model at each step (effect added)")
            ax.grid(alpha=0.3, which="both", axis="y")
        fig.suptitle(
            title or plot_text(f"Model discovery: {len(steps)} step{'s' if len(steps) != 1 else ''}, last model: {steps[-1].label}"),
            fontsize=11,
        )
        layout_with_caption(fig, next_step)
        return fig


def _plot_rms(ax1: Any, steps: Sequence[ModelStep]) -> None:
    """Draw each step's residual RMS per channel against that channel's noise floor [µg], values written."""
    k = np.arange(len(steps))
    channels = steps[0].channels
    rms = np.array([s.rms for s in steps]) / MICRO_G
    floor = np.array([s.noise_floor for s in steps]) / MICRO_G
    width = 0.7 / len(channels)
    for i, channel in enumerate(channels):
        x = k + (i - (len(channels) - 1) / 2) * width
        colour = f"C{i}"
        ax1.plot(x, rms[:, i], "o", color=colour, ms=7, label=plot_text(f"residual RMS {channel}"), zorder=3)
        if len(steps) > 1:
            ax1.plot(x, rms[:, i], "-", color=colour, lw=0.8, alpha=0.5)
        ax1.plot(x, floor[:, i], "_", color="k", ms=14, mew=2.0, label="noise floor of that output" if i == 0 else None, zorder=4)
        below = rms[-1, i] >= floor[-1, i]  # the floor's value on the side away from the RMS marker
        ax1.annotate(
            f"{floor[-1, i]:.3g}",
            (x[-1], floor[-1, i]),
            xytext=(0, -11 if below else 5),
            textcoords="offset points",
            ha="center",
            fontsize=7,
        )
        ax1.vlines(x, floor[:, i], rms[:, i], color=colour, lw=1.0, alpha=0.6)
        for xi, r, f in zip(x, rms[:, i], floor[:, i], strict=True):
            offset = 6 if r >= f else -13
            ax1.annotate(f"{r:.3g}", (xi, r), xytext=(0, offset), textcoords="offset points", ha="center", fontsize=7, color=colour)
    low, high = float(np.min(np.minimum(rms, floor))), float(np.max(np.maximum(rms, floor)))
    if high > 8 * low > 0:
        ax1.set_yscale("log")
        ax1.set_ylim(low / 1.6, high * 2.2)
        _plain_ticks(ax1)
    else:
        ax1.set_ylim(0.0, high * 1.25)
    ax1.set_ylabel("residual RMS [µg]")
    ax1.set_title("residual RMS per output against its noise floor", fontsize=10)
    ax1.legend(fontsize=7, loc="upper right")


def _plain_ticks(ax: Any) -> None:
    """Label a logarithmic y axis in plain numbers (``2``, ``10``, ``30``), the style of the values written beside the points."""
    from matplotlib.ticker import FuncFormatter

    plain = FuncFormatter(lambda value, _: f"{value:g}")
    ax.yaxis.set_major_formatter(plain)
    ax.yaxis.set_minor_formatter(plain)


def _plot_chi2(ax2: Any, steps: Sequence[ModelStep]) -> None:
    """Draw each step's χ²_ν with the band ``1 ± 2√(2/ν)``, values written."""
    k = np.arange(len(steps))
    chi = np.array([s.chi2_red for s in steps])
    spread = np.array([np.sqrt(2.0 / max(s.dof, 1)) for s in steps])
    for j in range(len(steps)):
        ax2.fill_between(
            [j - 0.3, j + 0.3], 1 - 2 * spread[j], 1 + 2 * spread[j], color="0.82", lw=0, label="1 ± 2√(2/ν)" if j == 0 else None
        )
    ax2.plot(k, chi, "o", color="C3", ms=7, label=plot_text("χ²_ν"), zorder=3)
    if len(steps) > 1:
        ax2.plot(k, chi, "-", color="C3", lw=0.8, alpha=0.5)
    for j, c in enumerate(chi):
        ax2.annotate(f"{c:.3g}\n(ν = {steps[j].dof})", (j, c), xytext=(8, 0), textcoords="offset points", fontsize=7, va="center")
    ax2.axhline(1.0, color="k", lw=0.6)
    top = float(np.max(np.r_[chi, 1 + 2 * spread]))
    bottom = float(np.min(np.r_[chi, 1 - 2 * spread]))
    if top > 10 * max(bottom, 0.1):
        ax2.set_yscale("log")
        ax2.set_ylim(max(min(bottom, 0.5) / 1.5, 1e-2), top * 2.0)
        _plain_ticks(ax2)
    else:
        ax2.set_ylim(max(0.0, bottom - 0.2 * (top - bottom) - 0.05), top + 0.25 * (top - bottom) + 0.05)
    ax2.set_ylabel(plot_text("χ²_ν (expected 1)"))
    ax2.set_title(plot_text("χ²_ν against its expected band"), fontsize=10)
    ax2.legend(fontsize=7, loc="best")


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

    def __init__(
        self,
        problem: Problem,
        model: ErrorModel,
        library: Library | None = None,
        alpha: float = 0.05,
        start: Mapping[str, float] | None = None,
    ) -> None:
        from stableins.discovery.library import LIBRARY

        self.problem = problem
        self.library = library if library is not None else LIBRARY
        self.alpha = alpha
        self.model = model
        self.result = problem.fit(model, start=start)
        #: The fit of every step, in the order of :attr:`history` (``results[0]``: the starting model).
        self.results: list[FitResult] = [self.result]
        self.history = History([make_step(self.result, "standard model")])
        self._ranking: Ranking | None = None
        #: Gyro g-sensitivities added to the drift model (:meth:`add` of a ``Dg_ab``): estimated from the reading slopes.
        self.drift_added: tuple[Term, ...] = ()

    def diagnose(self) -> Diagnosis:
        """Return the diagnosis of the current fit (:func:`stableins.discovery.diagnostics.diagnose`)."""
        from stableins.discovery.diagnostics import diagnose

        return diagnose(self.problem, self.result)

    def figures(self, *, next_step: str | None = None) -> dict[str, Figure]:
        """Return the discovery plots of the session (what ``stableins diagnose --plots`` writes), by name.

        ``residuals``: residuals per position of the current model, beside those of the starting model when effects
        were added (:meth:`Diagnosis.plot_positions`); ``orientation``: residuals against orientation, the starting
        model in grey (dwell problems); ``history``: :meth:`History.plot`.  ``next_step`` (e.g.
        :meth:`Ranking.next_step`) is the caption of each.
        """
        from stableins.discovery.diagnostics import diagnose

        now = self.diagnose()
        before = diagnose(self.problem, self.results[0]) if len(self.results) > 1 else None
        figures = {"residuals": now.plot_positions(before=before, next_step=next_step)}
        if now.orientation is not None:
            figures["orientation"] = now.plot_orientation(before=before, next_step=next_step)
        figures["history"] = self.history.plot(next_step=next_step)
        return figures

    def rank(self, refit_top: int = 3, *, propose: bool = True) -> Ranking:
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
        """Rank the platform-drift candidates ``Dg_ab`` on the reading slopes within dwells.

        The null model holds a constant reading rate per gimbal, the constant gyro drift and the ``Dg_ab`` added
        (:attr:`drift_added`); its fit is the ranking's ``result``.

        None when there are too few usable slopes (``drift_notes`` says why).  Uses the zero offsets of the current fit
        for the actual angles; see
        :mod:`stableins.discovery.drift`.  Needs a dwell problem whose dwells carry slopes.
        """
        from stableins.discovery.drift import drift_problem
        from stableins.discovery.ranking import rank
        from stableins.dwell_mode import DwellMode
        from stableins.units import DisplayUnit

        dwells = self.problem.dwells if isinstance(self.problem, DwellProblem) else None
        if dwells is None or dwells.reading_slope is None or dwells.reading_slope_sigma is None:
            raise ValueError("these data carry no reading slopes (device dwells are needed)")
        if dwells.dwell_mode is not DwellMode.EARTH_RATE:
            self.drift_notes: tuple[str, ...] = (
                f"dwell mode {dwells.dwell_mode}: the drift candidates are ranked on dwells torqued at the Earth rate only "
                + (
                    "(caged dwells carry no gyro information)"
                    if dwells.dwell_mode is DwellMode.CAGED
                    else "(the gyro stage, stableins.estimators.gyro_sensitivity.gyro_from_datasets, models inertially held dwells)"
                ),
            )
            return None
        values = self.result.as_dict()
        offsets = [values.get(i, 0.0) for i in GIMBAL_IDS]
        problem, null, terms, notes = drift_problem(
            dwells, dwells.reading_slope, dwells.reading_slope_sigma, offsets, added=self.drift_added
        )
        if problem.y.size <= len(null) + len(terms):
            self.drift_notes = notes + (
                f"only {problem.y.size // 3} dwell(s) with usable reading slopes: too few to rank the drift candidates",
            )
            return None
        fit = problem.fit(null)
        ranking = rank(
            problem, fit, terms, alpha=self.alpha, refit_top=refit_top, propose=False, output=DisplayUnit('"/h', ARCSEC_PER_HOUR)
        )
        self.drift_notes = notes
        return ranking

    def _term(self, effect: str | Term) -> Term:
        return effect if isinstance(effect, Term) else self.library[effect].term

    def add(self, *effects: str | Term) -> FitResult:
        """``model + effect`` and refit; the step goes into the history.

        A gyro g-sensitivity ``Dg_ab`` is not an accelerometer output: it joins the drift model instead
        (:attr:`drift_added`, as the record's ``GYRO_G_SENSITIVITY`` term, estimated by :meth:`drift` from the reading
        slopes) and the accelerometer fit is returned unchanged.
        """
        from stableins.errormodel import GYRO_G_TERMS

        gyro = {t.id: t for t in GYRO_G_TERMS}
        self.drift_added += tuple(gyro[e if isinstance(e, str) else e.id] for e in effects if (e if isinstance(e, str) else e.id) in gyro)
        terms = [self._term(e) for e in effects if (e if isinstance(e, str) else e.id) not in gyro]
        if not terms:
            return self.result
        previous = self.result
        self.model = self.model + terms
        self.result = self.problem.fit(self.model, start=previous.as_dict())
        self.results.append(self.result)
        self.history.append(make_step(self.result, "+ " + ", ".join(t.id for t in terms), previous))
        self._ranking = None
        return self.result

    def auto(self, max_steps: int = 5) -> History:
        """Add candidates one at a time, greedily, until χ² is in its band and nothing is flagged (or ``max_steps``).

        Each step adds the best candidate if it is flagged (significant and explaining the residual alone), or, while
        χ² rejects the model (:attr:`Ranking.outside_library`), if it is significant (F-test p below the Bonferroni
        level): two effects present at once explain the residual only together.  Greedy: with an effect outside the
        library the steps add the library effects that take part of it; the last step's χ²_ν says whether the
        model reached its band (:meth:`History.report`).
        """
        for _ in range(max_steps):
            ranking = self.rank(refit_top=1, propose=False)
            best = ranking.best
            if best is None:
                break
            significant = best.identifiable and best.p_value < ranking.alpha / ranking.n_tested
            if not (best.flagged or (ranking.outside_library and significant)):
                break
            self.add(best.term)
        return self.history
