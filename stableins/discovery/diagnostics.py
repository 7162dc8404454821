r"""Compare a fitted model with the measurements and see where it fails.

For any fitted stage (a :class:`~stableins.estimators.result.FitResult`):

* residuals per position and axis against the noise floor measured independently of the
  fit (within-dwell scatter, :func:`stableins.discovery.dwells.dwell_means`);
* ``χ²_ν = χ²/ν`` with its expected spread ``sqrt(2/ν)`` and the probability of a larger
  value under the model, ``P(χ²_ν' ≥ χ²_ν)``;
* plots: residuals per position with 1σ bars, residuals against orientation (``f^p/g`` per
  axis), and for system records the residual amplitude at the Earth-rate harmonics
  (:func:`harmonic_spectrum`).
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stableins.conventions import EARTH_RATE, MICRO_G
from stableins.discovery.problem import DiscoveryDetails
from stableins.display import layout_with_caption
from stableins.errormodel import TermKind
from stableins.estimators.result import FitResult

if TYPE_CHECKING:  # pragma: no cover
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

    from stableins.discovery.problem import Problem

AXIS_NAMES = ("x", "y", "z")
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

    @property
    def normalized(self) -> NDArray[np.float64]:
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
    def consistent(self) -> bool:
        """χ²_ν within its two-sided 99 % range under the model."""
        return 0.005 < self.p_value < 0.995

    def worst(self, count: int = 5) -> list[tuple[str, str, float]]:
        """The largest normalized residuals: (position, axis, residual/σ)."""
        z = self.normalized
        k = z.shape[1]
        order = np.argsort(-np.abs(z), axis=None)[:count]
        return [(self.position_labels[i // k], self.outputs[i % k], float(z.flat[i])) for i in order]

    @property
    def verdict(self) -> str:
        """``consistent with the noise floor`` or ``NOT consistent ...: something is missing``."""
        return "consistent with the noise floor" if self.consistent else "NOT consistent with the noise floor: something is missing"

    def _fit_line(self) -> str:
        return (
            f"{self.result.stage}: χ²_ν = {self.chi2_red:.3f} (ν = {self.result.dof}, expected 1 ± {self.spread:.3f}); "
            f"P(χ² ≥ observed) = {self.p_value:.3g} — {self.verdict}"
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
        if not self.consistent:
            lines.append("next: rank the candidate effects (Discovery.rank(), or stableins diagnose prints the ranking)")
        return clipped(lines, "(print(diagnosis) for the report, diagnosis.to_dataframe() for the residuals, diagnosis.plot_positions())")

    def _repr_html_(self) -> str:
        from stableins.display import html_result, html_table

        table = html_table(["output", "residual RMS", "noise floor", "ratio"], self._axis_rows(), numeric=(1, 2, 3))
        notes = [self.noise["method"]] if self.noise.get("method") else []
        return html_result("Diagnosis", [self._fit_line(), self._worst_line()], [table], [("noise floor", notes)])

    def to_dataframe(self) -> Any:
        """The residuals as a :class:`pandas.DataFrame`, one row per position and output.

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
        """What the x axis of the per-position plots shows, with an example of a label explained."""
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
            x = diagnosis.time / 3600.0 if by_time else np.arange(len(diagnosis.position_labels))
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
                ax.set_ylabel(f"{self.outputs[i]} residual [{self.unit}]")
                ax.grid(alpha=0.3)
            head = f"{'before' if diagnosis is before else 'after' if before is not None else 'model'}: {diagnosis.model_name}"
            axes[0, column].set_title(f"{head}\nχ²_ν = {diagnosis.chi2_red:.3g} (expected 1 ± {diagnosis.spread:.2g})", fontsize=10)
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
        """Normalized residual of each axis against each component of ``f^p`` [g] (3 × 3 panels).

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
                        label=f"before: {before.model_name} (χ²_ν = {before.chi2_red:.3g})",
                    )  # fmt: skip
                ax.scatter(
                    self.orientation[:, j], self.normalized[:, i], s=12, color="C0",
                    label=f"{'after' if before is not None else 'model'}: {self.model_name} (χ²_ν = {self.chi2_red:.3g})",
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


def _layout(labels: Sequence[str], m: int) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """Position names and output names from residual labels ``"<position> <output>"``.

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

    positions, outputs = _layout(result.residual_labels, result.residuals.size)
    k = len(outputs)
    residuals = result.residuals.reshape(-1, k)
    sigma = result.residual_sigma.reshape(-1, k)
    if problem is not None and hasattr(problem, "dwells"):
        positions = tuple(problem.dwells.labels)
    orientation = problem.orientation(result)[::3] if problem is not None and hasattr(problem, "orientation") else None
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
        time=np.asarray(problem.dwells.time, dtype=float) if problem is not None and hasattr(problem, "dwells") else None,
    )


# ----------------------------------------------------------------------------- system records
@dataclass(frozen=True)
class HarmonicSpectrum:
    """Least-squares amplitudes of a residual at multiples of the Earth rate."""

    harmonics: NDArray[np.int64]
    cosine: NDArray[np.float64]
    sine: NDArray[np.float64]
    sigma: NDArray[np.float64]
    amplitude: NDArray[np.float64]
    frequency: NDArray[np.float64]
    periodogram: NDArray[np.float64]
    chi2: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))
    p_value: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))
    dof: NDArray[np.float64] | None = None  # degrees of freedom of each χ² (2 unless the model explains part of the pair)

    def report(self, unit: str = "", scale: float = 1.0) -> str:
        dof = np.full(self.harmonics.size, 2.0) if self.dof is None else self.dof
        lines = [f"{'harmonic':>8} {'period [h]':>10} {'amplitude':>12} {'1σ':>10} {'χ²':>8} {'dof':>4} {'p':>9}"]
        for k, a, s, q, d, p in zip(self.harmonics, self.amplitude, self.sigma, self.chi2, dof, self.p_value, strict=True):
            period = 2 * np.pi / (k * EARTH_RATE) / 3600.0 if k else float("inf")
            if d == 0:
                lines.append(f"{k:>8d} {period:>10.2f} {'explained by the model':>34}")
                continue
            lines.append(f"{k:>8d} {period:>10.2f} {a / scale:>10.4g}{unit:>2} {s / scale:>10.3g} {q:>8.2f} {d:>4.0f} {p:>9.3g}")
        return "\n".join(lines)

    def __repr__(self) -> str:
        from stableins.display import clipped

        head = f"<HarmonicSpectrum: residual at harmonics {', '.join(map(str, self.harmonics))} of the Earth rate (amplitudes in SI)>"
        return clipped([head, *self.report().splitlines()], "(spectrum.plot(unit='µg', scale=MICRO_G) draws it)")

    def plot(
        self,
        ax: Axes | None = None,
        unit: str = "",
        scale: float = 1.0,
        *,
        name: str = "",
        cycles: float = 6.0,
        next_step: str | None = None,
    ) -> Figure:
        """The residual's amplitude at the Earth-rate harmonics (least-squares fit ± 1σ, p of each) over its amplitude spectrum.

        The x axis is in cycles per sidereal day (``k`` = the ``k``-th harmonic of ω_ie), zoomed on ``0 … cycles``; the
        harmonics are marked with their periods.  ``unit``/``scale``: how amplitudes are shown (e.g. ``"µg"``,
        ``MICRO_G``); ``name``: the output, for the title; ``next_step``: a caption under the figure.
        """
        import matplotlib.pyplot as plt

        fig = ax.figure if ax is not None else plt.figure(figsize=(8.5, 4.6 + (0.35 if next_step else 0.0)))
        ax = ax or fig.add_subplot(111)
        cpd = self.frequency / EARTH_RATE
        keep = (cpd > 0) & (cpd <= cycles)  # the zero-frequency bin is the removed mean
        # harmonics the fitted model explains entirely (no degree of freedom left, harmonic_tests) carry no amplitude
        tested = np.ones(self.harmonics.size, bool) if self.dof is None else self.dof > 0
        amplitude, sigma = self.amplitude / scale, self.sigma / scale
        ax.plot(cpd[keep], self.periodogram[keep] / scale, ".-", lw=0.8, ms=4, color="0.55", label="amplitude spectrum of the residual")
        ax.errorbar(
            self.harmonics[tested],
            amplitude[tested],
            yerr=sigma[tested],
            fmt="o",
            ms=6,
            capsize=3,
            color="C3",
            label="harmonic amplitude (fit ± 1σ)",
        )
        top = max(float(np.max((amplitude + sigma)[tested], initial=0.0)), float(np.max(self.periodogram[keep] / scale, initial=0.0)))
        top = top * 1.35 if top > 0 else 1.0
        p_values = self.p_value if self.p_value.size else np.full(self.harmonics.size, math.nan)
        for k, a, p, shown in zip(self.harmonics, amplitude, p_values, tested, strict=True):
            period = 2 * np.pi / (k * EARTH_RATE) / 3600.0
            ax.axvline(k, color="C3", lw=0.6, ls=":", zorder=0)
            ax.text(k, top * 0.98, f"{k}×ω_ie\n{period:.1f} h", ha="center", va="top", fontsize=7, color="C3")
            if not shown:
                ax.text(k, top * 0.80, "explained\nby the model", ha="center", va="top", fontsize=7, color="0.4")
            elif math.isfinite(p):
                ax.annotate(f"p = {p:.2g}", (k, a), xytext=(6, 0), textcoords="offset points", fontsize=7, va="center")
        ax.set_xlim(0.0, cycles + 0.3)
        ax.set_ylim(0.0, top)
        ax.set_xlabel("frequency [cycles per sidereal day] (k = k-th harmonic of the Earth rate ω_ie)")
        ax.set_ylabel(f"residual amplitude [{unit or 'SI'}]")
        ax.set_title(f"Residual{' of ' + name if name else ''} at the Earth-rate harmonics", fontsize=10)
        ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, 0.87), ncol=2)
        ax.grid(alpha=0.3)
        if ax is fig.axes[0] and len(fig.axes) == 1:
            layout_with_caption(fig, next_step, top=1.0)
        return fig


def residual_spectra(
    time: ArrayLike, diagnosis: Diagnosis, harmonics: Sequence[int] = (1, 2, 3, 4), problem=None
) -> dict[str, HarmonicSpectrum]:
    """Earth-rate harmonic spectrum of each output's residual (system records binned into dwells).

    Without ``problem``: per output, the least-squares harmonics of the residual with the RMS of its 1σ as a white
    per-sample σ (:func:`harmonic_spectrum`).  With the discovery ``problem`` the residuals came from (its noise model:
    white floor and slow noise correlated between bins), each harmonic pair is tested as an added variable under that
    noise model instead (:func:`harmonic_tests`): what the fitted model already explains is projected out and the
    correlated noise is whitened, so ``χ²`` has its nominal distribution when nothing is missing.
    """
    t = np.asarray(time, dtype=float)
    if problem is not None:
        return harmonic_tests(problem, diagnosis.result, t, harmonics)
    return {
        name: harmonic_spectrum(t, diagnosis.residuals[:, k], float(np.sqrt(np.mean(diagnosis.sigma[:, k] ** 2))), harmonics)
        for k, name in enumerate(diagnosis.outputs)
    }


def harmonic_tests(problem, result: FitResult, time: ArrayLike, harmonics: Sequence[int] = (1, 2, 3, 4)) -> dict[str, HarmonicSpectrum]:
    r"""Test each Earth-rate harmonic of each output as a missing term, under the problem's noise model.

    For output ``a`` and harmonic ``k`` the candidate columns are ``cos kω_ie t``, ``sin kω_ie t`` on that output's
    observations (zero elsewhere).  With ``R^{-1/2}`` the problem's whitening (white floor and slow noise per axis,
    :func:`stableins.discovery.problem.whiten`), ``X̃`` the whitened design of the estimated parameters, ``Z̃`` the
    whitened columns and ``Z̃_⊥ = (I − Q Qᵀ) Z̃`` (``Q`` an orthonormal basis of ``X̃``), the added-variable statistic is

    .. math:: χ² = r̃ᵀ Z̃_⊥ (Z̃_⊥ᵀ Z̃_⊥)^+ Z̃_⊥ᵀ r̃ \sim χ²_d,\qquad d = \operatorname{rank} Z̃_⊥,

    the drop of the whitened RSS if the pair were added (exact for a linear refit; the generalized-least-squares form of
    :mod:`stableins.discovery.ranking`'s score).  A harmonic the model already explains (``d = 0``, e.g. the first
    harmonic of x and y, which the biases and scale factors carry; a direction whose ``‖z̃_⊥‖`` is below the ranking's
    identifiability tolerance times ``‖z̃‖``) gets ``χ² = 0``, ``p = 1``.  The cosine and sine
    amplitudes are the refit's, ``(Z̃_⊥ᵀ Z̃_⊥)^+ Z̃_⊥ᵀ r̃``, with their 1σ.
    """
    from scipy import stats

    from stableins.discovery.problem import whiten
    from stableins.discovery.ranking import IDENTIFIABLE_TOLERANCE

    t = np.asarray(time, dtype=float)
    h = np.asarray(harmonics, dtype=int)
    m = t.size
    r = whiten(problem, result, result.residuals)
    q, _ = np.linalg.qr(whiten(problem, result, problem.design(result)))
    residuals = result.residuals.reshape(m, -1)
    outputs = residuals.shape[1]
    names = _layout(result.residual_labels, result.residuals.size)[1]
    out = {}
    for a in range(outputs):
        cosine, sine, sigma, chi2, dof = (np.zeros(h.size) for _ in range(5))
        for j, k in enumerate(h):
            z = np.zeros((m * outputs, 2))
            z[a::outputs, 0] = np.cos(k * EARTH_RATE * (t - t[0]))
            z[a::outputs, 1] = np.sin(k * EARTH_RATE * (t - t[0]))
            zt = whiten(problem, result, z)
            perp = zt - q @ (q.T @ zt)
            u, sv, vt = np.linalg.svd(perp, full_matrices=False)
            keep = sv > IDENTIFIABLE_TOLERANCE * max(float(np.linalg.norm(zt)), 1e-300)
            if not keep.any():
                continue
            projection = u[:, keep].T @ r
            chi2[j] = float(projection @ projection)
            dof[j] = int(keep.sum())
            coef = vt[keep].T @ (projection / sv[keep])
            cov = vt[keep].T @ np.diag(1.0 / sv[keep] ** 2) @ vt[keep]
            cosine[j], sine[j] = coef
            sigma[j] = float(np.sqrt(np.mean(np.diag(cov))))
        p = np.where(dof > 0, stats.chi2.sf(chi2, np.maximum(dof, 1)), 1.0)
        n = residuals.shape[0]
        dt = float(np.median(np.diff(t))) if n > 1 else 1.0
        spectrum = np.abs(np.fft.rfft(residuals[:, a] - residuals[:, a].mean())) * 2.0 / n
        freq = 2 * np.pi * np.fft.rfftfreq(n, dt)
        out[names[a] if a < len(names) else f"output {a}"] = HarmonicSpectrum(
            h, cosine, sine, sigma, np.hypot(cosine, sine), freq, spectrum, chi2, p, dof
        )
    return out


def harmonic_spectrum(time: ArrayLike, residual: ArrayLike, sigma: float, harmonics: Sequence[int] = (1, 2, 3, 4)) -> HarmonicSpectrum:
    r"""Residual amplitude at the Earth-rate harmonics ``k ω_ie`` and its periodogram.

    Fits ``r(t) = c_0 + Σ_k (a_k cos kω_ie t + b_k sin kω_ie t)`` by least squares with white
    noise ``sigma`` (per sample) and returns the amplitudes ``sqrt(a_k² + b_k²)``, the mean 1σ
    of the two coefficients, and the significance of each harmonic as
    ``χ²₂ = (a, b) C⁻¹ (a, b)ᵀ`` with the pair's 2×2 covariance ``C`` and its p-value (records
    shorter than a day correlate ``a`` and ``b``, so amplitude/σ would mislead).  A significant
    residual harmonic means a missing effect with that once- or twice-per-sidereal-day signature
    (Wu et al. 2018 Eqs. 22–38).
    """
    from scipy import stats

    t = np.asarray(time, dtype=float)
    r = np.asarray(residual, dtype=float)
    h = np.asarray(harmonics, dtype=int)
    cols = [np.ones_like(t)]
    for k in h:
        cols += [np.cos(k * EARTH_RATE * t), np.sin(k * EARTH_RATE * t)]
    x = np.stack(cols, axis=1)
    coef, *_ = np.linalg.lstsq(x, r, rcond=None)
    cov = sigma**2 * np.linalg.inv(x.T @ x)
    a, b = coef[1::2], coef[2::2]
    sa, sb = np.sqrt(np.diag(cov)[1::2]), np.sqrt(np.diag(cov)[2::2])
    chi2 = np.zeros(len(h))
    for j in range(len(h)):
        pair = [1 + 2 * j, 2 + 2 * j]
        chi2[j] = coef[pair] @ np.linalg.solve(cov[np.ix_(pair, pair)], coef[pair])
    # amplitude spectrum (one-sided) of the mean-removed residual
    n = r.size
    dt = float(np.median(np.diff(t))) if n > 1 else 1.0
    spectrum = np.abs(np.fft.rfft(r - r.mean())) * 2.0 / n
    freq = 2 * np.pi * np.fft.rfftfreq(n, dt)
    return HarmonicSpectrum(h, a, b, np.sqrt((sa**2 + sb**2) / 2.0), np.hypot(a, b), freq, spectrum, chi2, stats.chi2.sf(chi2, 2))
