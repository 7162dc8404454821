r"""Compare a fitted model with the measurements and see where it fails.

For any fitted stage (a :class:`~stableins.estimators.result.FitResult`):

* residuals per position and axis against the noise floor measured independently of the
  fit (within-dwell scatter, :func:`stableins.discovery.dwells.dwell_means`);
* ``χ²_ν = χ²/ν`` with its expected spread ``sqrt(2/ν)`` and the probability of a larger
  value under the model, ``P(χ²_ν' ≥ χ²_ν)``;
* plots: residuals per position with 1σ bars, residuals against orientation (``f^p/g`` per
  axis), and for system records the residual amplitude at the Earth-rate harmonics
  (:func:`~stableins.discovery.harmonics.harmonic_spectrum`).
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass
from enum import StrEnum
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from stableins.conventions import MICRO_G
from stableins.discovery.problem import DiscoveryDetails, DwellProblem
from stableins.display import layout_with_caption, plot_text
from stableins.errormodel import TermKind
from stableins.estimators.result import FitResult

if TYPE_CHECKING:  # pragma: no cover
    from matplotlib.figure import Figure

    from stableins.estimators.leastsquares import Problem

AXIS_NAMES = ("x", "y", "z")
#: χ²_ν is consistent with the noise floor when ``P(χ² ≥ observed)`` lies strictly between these (its two-sided 99 %
#: range): the rule of :attr:`Diagnosis.consistent` and of
#: :attr:`stableins.discovery.diagnose_report.DiagnoseReport.consistent`.  Below the lower limit χ² is too high (the
#: model misses something); above the upper limit it is too low (the noise model overstates the scatter): :class:`FitVerdict`.
CONSISTENT_P_VALUES = (0.005, 0.995)


class FitVerdict(StrEnum):
    """Where ``χ²`` of a fit lies against its two-sided 99 % range (:data:`CONSISTENT_P_VALUES`): the tail matters."""

    #: Within the range: the residuals are at the noise floor.
    CONSISTENT = "consistent"
    #: Too high (``P(χ² ≥ observed)`` below 0.005, for every noise model allowed): the model misses something.
    ABOVE = "above the noise floor"
    #: Too low (``P`` above 0.995, for every noise model allowed): the noise model overstates the scatter; nothing is missing.
    BELOW = "below the noise floor"
    #: No degrees of freedom (``P`` undefined): χ² tests nothing.
    UNTESTED = "untested"

    @classmethod
    def of(cls, p_most: float, p_least: float) -> FitVerdict:
        """Return the verdict from ``P(χ² ≥ observed)`` under the largest noise allowed (``p_most``) and the smallest (``p_least``)."""
        low, high = CONSISTENT_P_VALUES
        if math.isnan(p_most) or math.isnan(p_least):
            return cls.UNTESTED
        if p_most <= low:
            return cls.ABOVE
        if p_least >= high:
            return cls.BELOW
        return cls.CONSISTENT

    def words(self) -> str:
        """Return the verdict as the diagnosis prints it."""
        return {
            FitVerdict.CONSISTENT: "consistent with the noise floor",
            FitVerdict.ABOVE: "NOT consistent with the noise floor: something is missing",
            FitVerdict.BELOW: "below the noise floor: the residuals scatter less than the noise model says (its σ are conservative); "
            "nothing is missing",
            FitVerdict.UNTESTED: "untested: no degrees of freedom",
        }[self]


#: Above this many positions the per-position plots are drawn against time, without per-point labels.
MAX_NAMED_POSITIONS = 80


@dataclass(frozen=True)
class Diagnosis:
    """Where a fitted model fails.

    Attributes
    ----------
    result : FitResult
        The fit.
    position_labels : tuple of str
        Name of each position (rows of the per-position arrays).
    residuals, sigma : ndarray (P, 3)
        Residuals (observed − model) and their 1σ noise floor [m/s²].
    orientation : ndarray (P, 3) or None
        ``f^p/g`` at each position.
    chi2_red, spread, p_value : float
        ``χ²_ν``, ``sqrt(2/ν)`` and ``P(χ² ≥ observed)`` under the model.
    noise : dict
        How the noise floor was measured.
    outputs : tuple of str
        Name of each output (columns of the per-position arrays).
    unit, scale : str, float
        How residuals are shown (default µg).
    time : ndarray (P,) or None
        Time of each position [s] (dwell problems), for plots of many bins against time.
    p_range : (float, float) or None
        System records: ``P(χ² ≥ observed)`` with the slow noise at its upper and at its lower limits (the verdict holds
        for every noise model between); None: the one noise model, ``(p_value, p_value)``.
    """

    result: FitResult
    position_labels: tuple[str, ...]
    residuals: NDArray[np.float64]
    sigma: NDArray[np.float64]
    orientation: NDArray[np.float64] | None
    chi2_red: float
    spread: float
    p_value: float
    noise: dict
    outputs: tuple[str, ...] = ("f_x", "f_y", "f_z")
    unit: str = "µg"
    scale: float = MICRO_G
    time: NDArray[np.float64] | None = None
    p_range: tuple[float, float] | None = None

    @property
    def normalized(self) -> NDArray[np.float64]:
        """Residuals divided by their 1σ."""
        return self.residuals / self.sigma

    @property
    def rms(self) -> NDArray[np.float64]:
        """Residual RMS per output [SI of the observation]."""
        return np.sqrt(np.mean(self.residuals**2, axis=0))

    @property
    def noise_floor(self) -> NDArray[np.float64]:
        """RMS of the measured 1σ per axis [m/s²] (what the residual RMS should come down to)."""
        return np.sqrt(np.mean(self.sigma**2, axis=0))

    @property
    def fit_verdict(self) -> FitVerdict:
        """Where χ² lies against its two-sided 99 % range, for every noise model allowed (:class:`FitVerdict`)."""
        span = self.p_range if self.p_range is not None else (self.p_value, self.p_value)
        return FitVerdict.of(max(span), min(span))

    @property
    def consistent(self) -> bool:
        """Whether χ²_ν lies within its two-sided 99 % range under the model (:data:`CONSISTENT_P_VALUES`)."""
        return self.fit_verdict is FitVerdict.CONSISTENT

    def worst(self, count: int = 5) -> list[tuple[str, str, float]]:
        """Return the largest normalized residuals: (position, axis, residual/σ)."""
        z = self.normalized
        k = z.shape[1]
        order = np.argsort(-np.abs(z), axis=None)[:count]
        return [(self.position_labels[i // k], self.outputs[i % k], float(z.flat[i])) for i in order]

    @property
    def verdict(self) -> str:
        """The verdict in words (:meth:`FitVerdict.words`): consistent, above the floor (something missing) or below it."""
        return self.fit_verdict.words()

    def _fit_line(self) -> str:
        span = ""
        if self.p_range is not None and self.p_range != (self.p_value, self.p_value):
            span = f" ({self.p_range[0]:.3g} to {self.p_range[1]:.3g} over the noise models allowed)"
        return (
            f"{self.result.stage}: χ²_ν = {self.chi2_red:.3f} (ν = {self.result.dof}, expected 1 ± {self.spread:.3f}); "
            f"P(χ² ≥ observed) = {self.p_value:.3g}{span} — {self.verdict}"
        )

    def _axis_rows(self) -> list[list[str]]:
        u, sc = self.unit, self.scale
        return [
            [a, f"{rms / sc:.3f} {u}", f"{floor / sc:.3f} {u}", f"{rms / floor:.2f}"]
            for a, rms, floor in zip(self.outputs, self.rms, self.noise_floor, strict=True)
        ]

    def _worst_line(self) -> str:
        return "largest residuals: " + ", ".join(f"{p} {a} {z:+.1f}σ" for p, a, z in self.worst())

    def report(self) -> str:
        """Return the diagnosis in words: fit line, residual RMS against the noise floor per axis, the worst residuals."""
        lines = [self._fit_line(), f"{'axis':<5} {'residual RMS':>14} {'noise floor':>12} {'ratio':>7}"]
        lines += [f"{a:<5} {rms:>14} {floor:>12} {ratio:>7}" for a, rms, floor, ratio in self._axis_rows()]
        if self.noise:
            lines.append(f"noise floor: {self.noise.get('method', '')}")
        lines.append(self._worst_line())
        return "\n".join(lines)

    def __str__(self) -> str:
        return self.report()

    def __repr__(self) -> str:
        from stableins.display import clipped

        lines = [f"<Diagnosis of {len(self.position_labels)} positions × {len(self.outputs)} outputs>", self._fit_line()]
        lines += [
            f"  {a:<5} residual RMS {rms:>12}   noise floor {floor:>12}   ratio {ratio:>5}" for a, rms, floor, ratio in self._axis_rows()
        ]
        lines.append(self._worst_line())
        if self.fit_verdict is FitVerdict.ABOVE:
            lines.append("next: rank the candidate effects (Discovery.rank(), or stableins diagnose prints the ranking)")
        return clipped(lines, "(print(diagnosis) for the report, diagnosis.to_dataframe() for the residuals, diagnosis.plot_positions())")

    def _repr_html_(self) -> str:
        from stableins.display import html_result, html_table

        table = html_table(["output", "residual RMS", "noise floor", "ratio"], self._axis_rows(), numeric=(1, 2, 3))
        notes = [self.noise["method"]] if self.noise.get("method") else []
        return html_result("Diagnosis", [self._fit_line(), self._worst_line()], [table], [("noise floor", notes)])

    def to_dataframe(self) -> Any:
        """Return the residuals as a :class:`pandas.DataFrame`, one row per position and output.

        Columns ``position``, ``output``, ``residual`` and ``sigma`` (in :attr:`unit`), ``normalized`` (residual / 1σ),
        and ``f_x/g``, ``f_y/g``, ``f_z/g`` (the orientation) when known.  Needs pandas (``pip install stableins[pandas]``).
        """
        from stableins.display import require_pandas

        pandas = require_pandas()
        rows = []
        for i, position in enumerate(self.position_labels):
            for j, output in enumerate(self.outputs):
                row = {
                    "position": position,
                    "output": output,
                    f"residual [{self.unit}]": self.residuals[i, j] / self.scale,
                    f"sigma [{self.unit}]": self.sigma[i, j] / self.scale,
                    "normalized": self.residuals[i, j] / self.sigma[i, j],
                }
                if self.orientation is not None:
                    row.update({f"f_{a}/g": float(self.orientation[i, k]) for k, a in enumerate(AXIS_NAMES)})
                rows.append(row)
        return pandas.DataFrame.from_records(rows)

    # ------------------------------------------------------------------ plots
    @property
    def model_name(self) -> str:
        """``standard model`` plus the effects the fit added (``standard model + nonorth_12``), as plots name it."""
        added = [t.id for t in self.result.terms if t.kind == TermKind.ADDITIVE]
        return "standard model" + "".join(f" + {i}" for i in added)

    def _by_time(self) -> bool:
        """Plot against time (system records: many bins) rather than against named positions."""
        return self.time is not None and len(self.position_labels) > MAX_NAMED_POSITIONS

    def _position_axis(self) -> str:
        """Return what the x axis of the per-position plots shows, with an example of a label explained."""
        if self._by_time():
            return "time since the start of the record [h]"
        first = self.position_labels[0] if self.position_labels else ""
        match = re.fullmatch(r"([cf])(\d+)/(\d+)", first)
        if match:
            stage = {"c": "coarse", "f": "fine"}[match.group(1)]
            return f"dwell (stage, pass / procedure position: {first} = {stage} stage, pass {match.group(2)}, position {match.group(3)})"
        return "dwell (in acquisition order)"

    def plot_positions(
        self,
        fig: Figure | None = None,
        title: str | None = None,
        *,
        before: Diagnosis | None = None,
        next_step: str | None = None,
    ) -> Figure:
        """Residuals per position and output with 1σ bars (in :attr:`unit`), the noise floor as a grey band.

        ``before``: the diagnosis of the model before effects were added (same positions): drawn in a left column,
        this one in a right column, each named by its model and χ²_ν.  ``next_step``: a caption under the figure
        (e.g. :meth:`stableins.discovery.ranking.Ranking.next_step`).  Many positions (system records) are drawn
        against time, without per-point bars.
        """
        import matplotlib.pyplot as plt

        panels = [d for d in (before, self) if d is not None]
        fig = fig or plt.figure(figsize=(7.5 * len(panels) + 2.5, 6.8 + (0.35 if next_step else 0.0)))
        axes = np.atleast_2d(fig.subplots(len(self.outputs), len(panels), sharex=True, squeeze=False))
        by_time = self._by_time()
        for column, diagnosis in enumerate(panels):
            x = diagnosis.time / 3600.0 if by_time and diagnosis.time is not None else np.arange(len(diagnosis.position_labels))
            for i, ax in enumerate(axes[:, column]):
                r, sg = diagnosis.residuals[:, i] / self.scale, diagnosis.sigma[:, i] / self.scale
                ax.fill_between(x, -sg, sg, color="0.88", step="mid", lw=0, label="±1σ noise floor")
                if by_time:
                    ax.plot(x, r, ".", ms=2.5, color="C0" if diagnosis is self else "0.45", label="residual")
                else:
                    ax.errorbar(
                        x, r, yerr=sg, fmt="o", ms=3.5, lw=1, capsize=2, color="C0" if diagnosis is self else "0.45", label="residual ± 1σ"
                    )
                ax.axhline(0.0, color="k", lw=0.6)
                ax.set_ylabel(plot_text(f"{self.outputs[i]} residual [{self.unit}]"))
                ax.grid(alpha=0.3)
            head = f"{'before' if diagnosis is before else 'after' if before is not None else 'model'}: {diagnosis.model_name}"
            title_text = plot_text(f"{head}\nχ²_ν = {diagnosis.chi2_red:.3g} (expected 1 ± {diagnosis.spread:.2g})")
            axes[0, column].set_title(title_text, fontsize=10)
            axes[-1, column].set_xlabel(self._position_axis() if column == len(panels) - 1 or len(panels) == 1 else "", fontsize=9)
            if not by_time and len(x) <= MAX_NAMED_POSITIONS:
                axes[-1, column].set_xticks(x, diagnosis.position_labels, rotation=90, fontsize=7)
        axes[0, -1].legend(fontsize=7, loc="upper right")
        if len(panels) > 1:
            axes[-1, 0].set_xlabel(self._position_axis(), fontsize=9)
        fig.suptitle(title or f"Residuals of the {self.result.stage} fit per {'bin' if by_time else 'dwell'}", fontsize=11)
        layout_with_caption(fig, next_step)
        return fig

    def plot_orientation(self, fig: Figure | None = None, *, before: Diagnosis | None = None, next_step: str | None = None) -> Figure:
        """Plot the normalized residual of each axis against each component of ``f^p`` [g] (3 × 3 panels).

        A residual that grows with one component of the specific force points at a missing term in that input
        (a scale-factor or cross-coupling effect); ``before`` draws the model before effects were added in grey.
        """
        import matplotlib.pyplot as plt

        if self.orientation is None:
            raise ValueError("this diagnosis has no orientation (not a dwell problem)")
        fig = fig or plt.figure(figsize=(10, 8.6 + (0.35 if next_step else 0.0)))
        axes = fig.subplots(3, 3, sharex=True, sharey=True)
        for i in range(3):
            for j in range(3):
                ax = axes[i, j]
                if before is not None and before.orientation is not None:
                    ax.scatter(
                        before.orientation[:, j], before.normalized[:, i], s=14, facecolors="none", edgecolors="0.55",
                        label=plot_text(f"before: {before.model_name} (χ²_ν = {before.chi2_red:.3g})"),
                    )  # fmt: skip
                ax.scatter(
                    self.orientation[:, j], self.normalized[:, i], s=12, color="C0",
                    label=plot_text(f"{'after' if before is not None else 'model'}: {self.model_name} (χ²_ν = {self.chi2_red:.3g})"),
                )  # fmt: skip
                ax.axhspan(-1.0, 1.0, color="0.9", zorder=0)
                ax.axhline(0.0, color="k", lw=0.6)
                ax.grid(alpha=0.3)
                if i == 2:
                    ax.set_xlabel(f"platform specific force $f^p_{AXIS_NAMES[j]}$ [g]")
                if j == 0:
                    ax.set_ylabel(f"$f_{AXIS_NAMES[i]}$ residual [σ]")
        if before is not None and float(np.max(np.abs(before.normalized))) > 10 * max(float(np.max(np.abs(self.normalized))), 1.0):
            axes[0, 0].set_yscale("symlog", linthresh=3.0)  # linear within ±3σ (the model after), logarithmic beyond (before)
            top = float(np.max(np.abs(before.normalized)))
            ticks = [t for t in (1, 3, 10, 30, 100, 300, 1000, 3000, 10000) if t <= 1.5 * top]
            axes[0, 0].set_yticks([-t for t in ticks[::-1]] + [0] + ticks, [f"−{t}" for t in ticks[::-1]] + ["0"] + [str(t) for t in ticks])
        handles, labels = axes[0, 0].get_legend_handles_labels()
        fig.legend(handles, labels, loc="upper center", bbox_to_anchor=(0.5, 0.96), ncol=1, fontsize=8, frameon=False)
        scale = "; logarithmic beyond ±3σ" if axes[0, 0].get_yscale() == "symlog" else ""
        fig.suptitle(f"Residuals of the {self.result.stage} fit against orientation (grey band: ±1σ{scale})", fontsize=11)
        layout_with_caption(fig, next_step, top=0.92 if before is not None else 0.94)
        return fig


def residual_layout(labels: Sequence[str], m: int) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """Return the position names and output names of ``m`` residuals from their labels ``"<position> <output>"``.

    Three outputs per position when the labels end in ``f_x, f_y, f_z`` in turn (device
    dwells); otherwise one output per observation (the fine stage's ``|f|``, system records).
    """
    if len(labels) == m and m % 3 == 0 and all(lbl.endswith(f" f_{a}") for lbl, a in zip(labels, AXIS_NAMES * (m // 3), strict=False)):
        return tuple(lbl.rsplit(" ", 1)[0] for lbl in labels[::3]), tuple(f"f_{a}" for a in AXIS_NAMES)
    if len(labels) == m and all(" " in lbl for lbl in labels):
        outputs = {lbl.rsplit(" ", 1)[1] for lbl in labels}
        if len(outputs) == 1:
            return tuple(lbl.rsplit(" ", 1)[0] for lbl in labels), (outputs.pop(),)
    return tuple(labels) if len(labels) == m else tuple(f"obs {k + 1}" for k in range(m)), ("residual",)


def diagnose(problem: Problem | None, result: FitResult, unit: str = "µg", scale: float = MICRO_G) -> Diagnosis:
    """Residual diagnostics of any fitted stage.

    ``problem`` may be None: the residuals, their 1σ and labels of ``result`` are enough
    (e.g. a FitResult of the device estimators).  With a discovery problem the χ² is the one
    its fit minimized (generalized when slow noise correlates the dwells) and the
    orientation of each position is known.  ``unit``/``scale`` set how residuals are shown
    (default µg for specific force; e.g. ``"µrad", 1e-6`` for attitude residuals).
    """
    from scipy import stats

    from stableins.discovery.problem import fit_chi2, fit_chi2_red

    positions, outputs = residual_layout(result.residual_labels, result.residuals.size)
    k = len(outputs)
    residuals = result.residuals.reshape(-1, k)
    sigma = result.residual_sigma.reshape(-1, k)
    dwells = problem if isinstance(problem, DwellProblem) else None  # device dwells: their labels, orientation and times
    if dwells is not None:
        positions = tuple(dwells.dwells.labels)
    orientation = dwells.orientation(result)[::3] if dwells is not None else None
    nu = result.dof
    return Diagnosis(
        result=result,
        position_labels=positions,
        residuals=residuals,
        sigma=sigma,
        orientation=orientation,
        chi2_red=fit_chi2_red(result),
        spread=float(np.sqrt(2.0 / max(nu, 1))),
        p_value=float(stats.chi2.sf(fit_chi2(result), nu)) if nu > 0 else float("nan"),
        noise=dict(result.details.noise) if isinstance(result.details, DiscoveryDetails) else {},
        outputs=outputs,
        unit=unit,
        scale=scale,
        time=np.asarray(dwells.dwells.time, dtype=float) if dwells is not None else None,
    )
