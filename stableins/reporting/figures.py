"""Report figures (matplotlib, Agg, no pyplot state).

Figures are drawn at the size they are printed (the text width, 174 mm) with the
report's typeface (DejaVu Sans) at 8 pt, so lettering in figures matches the tables;
they are embedded as 300-dpi PNG.  Each function returns ``(png_bytes, aspect)`` with
``aspect = height / width``.
"""

from __future__ import annotations

import io
import math
from collections.abc import Sequence
from contextlib import contextmanager
from typing import TYPE_CHECKING, Any

from stableins.conventions import MICRO_G

if TYPE_CHECKING:
    from matplotlib.typing import RcKeyType

#: Printed width of a full-width figure [inch] (A4 minus 2 × 18 mm margins).
FULL_WIDTH = (210.0 - 36.0) / 25.4
DPI = 300
STYLE: dict[RcKeyType, Any] = {
    "font.family": "DejaVu Sans",
    "font.size": 8.0,
    "axes.titlesize": 8.5,
    "axes.labelsize": 8.0,
    "xtick.labelsize": 7.0,
    "ytick.labelsize": 7.0,
    "legend.fontsize": 7.0,
    "axes.linewidth": 0.6,
    "lines.linewidth": 0.9,
    "axes.grid": True,
    "grid.linewidth": 0.4,
    "grid.alpha": 0.5,
    "axes.axisbelow": True,
    "axes.unicode_minus": True,
    "savefig.dpi": DPI,
}
#: Printed width of the correlation heat map [inch]: drawn at this size, its 7.5-pt labels print at 7.5 pt.
CORRELATION_WIDTH = 4.3
AXIS_COLOURS = {"x": "#1f77b4", "y": "#2ca02c", "z": "#d62728"}


@contextmanager
def _style() -> Any:
    import matplotlib

    with matplotlib.rc_context(STYLE):
        yield


def _figure(width: float, height: float) -> Any:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def _png(fig: Any) -> tuple[bytes, float]:
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=DPI, metadata={"Software": None})
    width, height = fig.get_size_inches()
    return buffer.getvalue(), float(height / width)


def plotted_residual_scale(unit: str) -> tuple[float, str]:
    """Divisor and label turning residuals in ``unit`` into the unit plotted."""
    if unit in ("m/s^2", "m/s²"):
        return MICRO_G, "µg"
    return 1.0, unit


def correlation_matrix(ids: Sequence[str], matrix: Sequence[Sequence[float]], threshold: float = 0.3) -> tuple[bytes, float]:
    """Lower triangle of the correlation coefficients as a heat map, printed large enough to read.

    Typeset parameter names on both axes; the coefficients with ``|ρ| ≥ threshold`` are written in their
    cells (the rest are small: their colour says so), a colour bar with ticks every 0.5.
    """
    import numpy as np

    from stableins.reporting.symbols import mathtext

    n = len(ids)
    rho = np.array(matrix, dtype=float)
    shown = np.where(np.tril(np.ones((n, n), dtype=bool), k=-1), rho, np.nan)
    labels = [mathtext(i) for i in ids]
    with _style():
        fig = _figure(CORRELATION_WIDTH, CORRELATION_WIDTH - 0.7)
        ax = fig.add_subplot(111)
        image = ax.imshow(shown, cmap="RdBu_r", vmin=-1.0, vmax=1.0, interpolation="nearest")
        ax.set_xticks(range(n - 1), labels[:-1], rotation=90)
        ax.set_yticks(range(1, n), labels[1:])
        ax.set_xlim(-0.5, n - 1.5)
        ax.set_ylim(n - 0.5, 0.5)
        ax.tick_params(length=0, labelsize=8.0)
        ax.grid(False)
        for spine in ax.spines.values():
            spine.set_visible(False)
        for i in range(1, n):
            for j in range(i):
                value = rho[i, j]
                if abs(value) >= threshold:
                    text = f"{value:.2f}".replace("-", "\u2212")
                    ax.text(j, i, text, ha="center", va="center", fontsize=5.5, color="white" if abs(value) > 0.6 else "black")
        bar = fig.colorbar(image, ax=ax, shrink=0.7, pad=0.02, ticks=[-1.0, -0.5, 0.0, 0.5, 1.0])
        bar.ax.tick_params(labelsize=7.5)
        bar.set_label("correlation coefficient ρ (dimensionless)")
        return _png(fig)


def residuals_by_position(stage: Any) -> tuple[bytes, float]:
    """Residual of every position, one panel per axis, with the ±1σ noise floor of each observation."""
    import numpy as np

    scale, unit = plotted_residual_scale(stage.unit)
    groups = stage.by_position_axis()
    keys = [k for k in ("x", "y", "z", "|f|") if k in groups]
    colours = dict(AXIS_COLOURS, **{"|f|": "#1f3a5f"})
    with _style():
        fig = _figure(FULL_WIDTH, 0.8 + 1.05 * len(keys))
        axes = np.atleast_1d(fig.subplots(len(keys), 1, sharex=True))
        for ax, axis in zip(axes, keys, strict=True):
            name = "|f|" if axis == "|f|" else f"$f_{axis}$"
            points = sorted(groups[axis])
            position = np.array([p[0] for p in points], dtype=float)
            residual = np.array([p[1] for p in points]) / scale
            sigma = np.array([p[2] for p in points]) / scale
            # Observations may repeat a position (passes); offset them slightly so all are visible.
            offsets = np.zeros_like(position)
            for value in np.unique(position):
                same = np.flatnonzero(position == value)
                if same.size > 1:
                    offsets[same] = np.linspace(-0.2, 0.2, same.size)
            x = position + offsets
            ax.fill_between(x, -sigma, sigma, step="mid", color="0.85", label="noise floor (±1σ)", linewidth=0)
            ax.errorbar(
                x, residual, yerr=sigma, fmt="o", ms=2.8, color=colours[axis], elinewidth=0.6, capsize=1.5, label=f"{name} residual"
            )
            ax.axhline(0.0, color="black", linewidth=0.6)
            ax.set_ylabel(f"{name} residual [{unit}]")
            ax.legend(loc="upper right", ncols=2, frameon=False)
            limit = max(float(np.max(np.abs(residual) + sigma)), 1e-12) * 1.35
            ax.set_ylim(-limit, limit)
        axes[-1].set_xlabel("position number")
        positions = sorted({p[0] for points in groups.values() for p in points})
        if positions and len(positions) <= 40:
            axes[-1].set_xticks(positions)
        per = "per position" if "|f|" in groups else "per position and axis"
        axes[0].set_title(rf"{stage.stage} stage: residual (observed − model) {per}; $\chi^2_\nu$ = {stage.chi2_red:.3f}, ν = {stage.dof}")
        return _png(fig)


def normalized_residuals(stage: Any) -> tuple[bytes, float]:
    """Residual / 1σ of every observation (named on the axis when the labels are few), with the ±1 band."""
    import numpy as np

    from stableins.estimators.result import Stage

    r = np.asarray(stage.residuals) / np.asarray(stage.sigma)
    names = [coefficient_label(x) for x in stage.labels] if stage.labels and len(stage.labels) <= 40 else None
    with _style():
        fig = _figure(FULL_WIDTH, 2.5 if names and len(names) > 24 else 2.2)
        ax = fig.add_subplot(111)
        x = np.arange(1, r.size + 1)
        ax.axhspan(-1, 1, color="0.85", label="±1σ (noise alone)", linewidth=0, zorder=0)
        ax.plot(x, r, "o", ms=3.0, color="#1f3a5f", label="residual / σ", zorder=2)
        ax.axhline(0, color="black", linewidth=0.6, zorder=1)
        limit = max(3.0, 1.25 * float(np.max(np.abs(r), initial=0.0)))
        ax.set_ylim(-limit, limit)
        if names:
            ax.set_xticks(x, names)
            if len(names) > 24:  # many labels: turned and smaller, so that neighbours never overlap
                ax.tick_params(axis="x", labelrotation=60, labelsize=6.5)
                for label in ax.get_xticklabels():
                    label.set_horizontalalignment("right")
                    label.set_rotation_mode("anchor")
            ax.set_xlabel("combined coefficient" if stage.stage == Stage.SYSTEM else "observation")
        else:
            ax.set_xlabel("observation number")
        ax.set_xlim(0.4, r.size + 0.6)
        ax.set_ylabel("residual / σ")
        ax.set_title(rf"{stage.stage} stage: residual / σ; $\chi^2_\nu$ = {stage.chi2_red:.3f}, ν = {stage.dof}", loc="left")
        ax.legend(loc="lower right", bbox_to_anchor=(1.0, 1.0), frameon=False, ncols=2, borderaxespad=0.1)
        return _png(fig)


def coefficient_label(name: str) -> str:
    """Mathtext of a system stage's combined coefficient (``x1`` → x₁, ``theta_1c`` → θ₁c, ``phi_mean`` → φ̄)."""
    import re

    if re.fullmatch(r"x\d", name):
        return f"$x_{name[1]}$"
    drift = re.fullmatch(r"gyro drift ([xyz])\b.*", name)  # the system stage's measured drift: ε with its platform axis
    if drift:
        return rf"$\varepsilon_{{{drift.group(1)}}}$"
    head, _, tail = name.partition("_")
    greek = {"theta": r"\theta", "phi": r"\varphi"}.get(head)
    if greek is None:
        return name
    return rf"$\bar{{{greek}}}$" if tail == "mean" else rf"${greek}_{{{tail}}}$"


def discovery_steps(steps: Sequence[dict[str, Any]]) -> tuple[bytes, float]:
    """Residual RMS after each model-discovery step."""
    labels = [step_label(str(s.get("label", s.get("model", f"step {i}")))) for i, s in enumerate(steps)]
    rms = [float(s["residual_rms"]) for s in steps]
    unit = str(steps[0].get("unit", "µg")) if steps else "µg"
    with _style():
        fig = _figure(FULL_WIDTH, 2.4)
        ax = fig.add_subplot(111)
        ax.plot(range(len(rms)), rms, "o-", color="#1f3a5f", ms=4)
        floor = [float(s["noise_floor"]) for s in steps if s.get("noise_floor") is not None]
        if floor and len(floor) == len(steps):
            ax.plot(range(len(rms)), floor, "--", color="0.4", label="noise floor")
            ax.legend(frameon=False)
        ax.set_xticks(range(len(rms)), labels, rotation=20, ha="right")
        from matplotlib.ticker import FuncFormatter

        ax.set_yscale("log")
        plain = FuncFormatter(lambda v, _: f"{v:g}")
        ax.yaxis.set_major_formatter(plain)
        ax.yaxis.set_minor_formatter(plain)
        ax.set_ylabel(f"residual RMS [{unit}]")
        ax.set_xlabel("model after step")
        return _png(fig)


def model_history(steps: Sequence[dict[str, Any]]) -> tuple[bytes, float]:
    """Residual RMS per output channel after each step of a record's discovery history, with the noise floor."""
    from stableins.conventions import MICRO_G

    labels = [step_label(str(s.get("label", f"step {i}"))) for i, s in enumerate(steps)]
    channels = [str(c) for c in steps[0].get("channels", [])]
    rms = [[float(x) / MICRO_G for x in s.get("residual_rms", [])] for s in steps]
    floor = [float(x) / MICRO_G for x in steps[-1].get("noise_floor", [])]
    with _style():
        fig = _figure(FULL_WIDTH, 2.4)
        ax = fig.add_subplot(111)
        for k, channel in enumerate(channels):
            name = channel if channel.startswith("|") else f"${channel}$"
            (line,) = ax.plot(range(len(steps)), [r[k] for r in rms], "o-", ms=4, label=f"{name} residual")
            if k < len(floor):
                ax.axhline(floor[k], ls="--", lw=0.8, color=line.get_color())
        ax.set_xticks(range(len(steps)), labels, rotation=20, ha="right")
        ax.set_xlim(-0.3, len(steps) - 0.7)
        from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

        ax.set_yscale("log")
        ax.yaxis.set_major_locator(LogLocator(subs=(1.0, 2.0, 5.0)))
        ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
        ax.yaxis.set_minor_formatter(NullFormatter())
        ax.plot([], [], ls="--", lw=0.8, color="0.3", label="noise floor (same colour)")
        ax.set_ylabel("residual RMS [µg]")
        ax.set_xlabel("model after step")
        ax.legend(frameon=False, ncols=len(channels) + 1, loc="lower center", bbox_to_anchor=(0.5, 1.0))
        return _png(fig)


def changes(items: Sequence[Any], threshold: float = 3.0) -> tuple[bytes, float]:
    """Change since the previous calibration in units of its standard uncertainty (z = Δ/u(Δ), signed)."""
    from stableins.reporting.symbols import mathtext

    labels = [mathtext(c.id) for c in items]
    values = [c.significance for c in items]
    with _style():
        fig = _figure(FULL_WIDTH, 2.3)
        ax = fig.add_subplot(111)
        colours = ["#b3261e" if c.significant else "#1f3a5f" for c in items]
        finite = [v if math.isfinite(v) else 0.0 for v in values]
        ax.axhspan(-threshold, threshold, color="0.88", linewidth=0, label=f"|z| < {threshold:g}: not flagged", zorder=0)
        ax.bar(range(len(values)), finite, color=colours, width=0.6, zorder=2)
        ax.axhline(0, color="black", linewidth=0.6, zorder=3)
        ax.set_xticks(range(len(values)), labels, rotation=90 if len(values) > 12 else 0)
        from matplotlib.ticker import FuncFormatter

        limit = max([threshold + 1.0] + [1.2 * abs(v) for v in finite])
        if limit > 10 * threshold:  # a large change: a logarithmic scale beyond the flag level keeps the small ones visible
            ax.set_yscale("symlog", linthresh=threshold)
        ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}".replace("-", "\u2212")))
        ax.set_ylabel("z = Δ / u(Δ) (dimensionless)")
        ax.set_ylim(-limit, limit)
        ax.set_xlim(-0.6, len(values) - 0.4)
        ax.legend(loc="lower center", bbox_to_anchor=(0.5, 1.0), frameon=False)
        return _png(fig)


def step_label(label: str) -> str:
    """Return a discovery step's model label with typeset effect names (``+ K3_x`` → ``+ K₃,ₓ`` in mathtext)."""
    import re

    from stableins.reporting.symbols import mathtext

    return re.sub(r"[A-Za-z][A-Za-z0-9]*(?:_[A-Za-z0-9]+)+", lambda m: mathtext(m.group(0)), label)
