r"""The results table of a campaign, its summary against the design's bound, and its plots.

Per procedure, noise model, hidden-effect set and parameter (estimated parameters only: the ``θ10`` gauge and held
terms have no error to test):

* ``rms z``: :math:`\sqrt{\overline{z^2}}`, ``z = (estimate − truth)/σ`` with the σ the calibration reported (1 when the
  σ are right; its 99.9 % band for ``n`` tasks is :math:`\sqrt{\chi^2_{n;\,0.0005,\,0.9995}/n}`);
* ``measured σ``: the RMS of ``estimate − truth`` over the devices (what the procedure achieves);
* ``design σ``: the Cramér-Rao bound of the procedure under the calibration's noise model
  (:func:`stableins.estimators.experiment.expected_precision`), and ``efficiency = (design σ / measured σ)²``
  (1 for an efficient estimator);
* with ``diagnose``: the detection rate (a hidden effect is the best flagged candidate, or indistinguishable from
  it) and the false-alarm rate (anything flagged when nothing is hidden), each with its binomial 1σ.

The table is CSV (one row per task and parameter, :data:`stableins.campaign.task.COLUMNS`).  Parquet is not
written: it would need pyarrow (tens of MB) for a table that CSV holds in a few MB per 10 000 tasks and that
``pandas.read_csv`` reads in well under a second.
"""

from __future__ import annotations

import csv
import math
from collections import defaultdict
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from stableins.campaign.config import CalibrationNoise, CampaignConfig
from stableins.campaign.task import COLUMNS, calibration_noise
from stableins.data.atomic import atomic_path, atomic_write


def write_table(path: str | Path, rows: Sequence[Mapping[str, Any]]) -> None:
    """Write the results table as CSV (atomically), columns :data:`COLUMNS`; NaN cells empty."""

    def cell(v: Any) -> Any:
        if isinstance(v, float):
            return "" if math.isnan(v) else repr(v)
        return v

    with atomic_write(path, "w") as handle:
        writer = csv.writer(handle, lineterminator="\n")
        writer.writerow(COLUMNS)
        for row in rows:
            writer.writerow([cell(row[c]) for c in COLUMNS])


@dataclass(frozen=True)
class ParameterSummary:
    """Statistics of one parameter over the devices of one procedure, noise model and hidden-effect set."""

    procedure: str
    noise: str
    hidden: str
    parameter: str
    unit: str
    n: int
    rms_z: float
    mean_z: float
    measured_sigma: float
    reported_sigma: float
    design_sigma: float

    @property
    def efficiency(self) -> float:
        """``(design σ / measured σ)²``: 1 for an efficient estimator, below 1 when the bound is not reached."""
        return (self.design_sigma / self.measured_sigma) ** 2 if self.measured_sigma > 0 else math.nan

    @property
    def z_band(self) -> tuple[float, float]:
        """The 99.9 % band of ``rms z`` for ``n`` devices with honest σ."""
        from scipy import stats

        lo, hi = stats.chi2.ppf([0.0005, 0.9995], self.n) / self.n
        return math.sqrt(lo), math.sqrt(hi)


@dataclass(frozen=True)
class RateSummary:
    """Detection (hidden effect) or false-alarm (nothing hidden) rate of the diagnosis."""

    procedure: str
    noise: str
    hidden: str
    kind: str
    hits: int
    n: int

    @property
    def rate(self) -> float:
        """Fraction of the tasks."""
        return self.hits / self.n if self.n else math.nan

    @property
    def sigma(self) -> float:
        """Binomial 1σ of :attr:`rate`."""
        p = self.rate
        return math.sqrt(max(p * (1 - p), 1.0 / self.n) / self.n) if self.n else math.nan


def design_sigmas(config: CampaignConfig) -> dict[tuple[str, str], dict[str, float]]:
    """``{(procedure, noise): {parameter: design σ in engineering units}}`` of every procedure under every noise model."""
    from stableins.estimators.experiment import expected_precision
    from stableins.estimators.setting import DeviceSetting
    from stableins.procedures.designed import device_plan
    from stableins.simulator.truth import Truth

    setting = DeviceSetting.from_site(Truth.draw(config.first_seed).site)
    out = {}
    for p in config.procedures:
        plan = device_plan(p.coarse, p.fine, passes=p.passes, sample_rate=p.sample_rate)
        for n in config.noises:
            noise = calibration_noise(n.settings, CalibrationNoise.DATASHEET)
            assert noise is not None
            out[(p.name, n.name)] = expected_precision(plan, noise, setting).sigma_engineering()
    return out


def summarize(rows: Sequence[Mapping[str, Any]], design: Mapping[tuple[str, str], Mapping[str, float]]) -> list[ParameterSummary]:
    """One :class:`ParameterSummary` per procedure, noise model, hidden-effect set and estimated parameter."""
    groups: dict[tuple[str, str, str, str], list[Mapping[str, Any]]] = defaultdict(list)
    for row in rows:
        if row["status"] == "estimated":
            groups[(row["procedure"], row["noise"], row["hidden"], row["parameter"])].append(row)
    out = []
    for (procedure, noise, hidden, parameter), group in groups.items():
        z = np.array([r["z"] for r in group], dtype=float)
        err = np.array([r["estimate"] - r["truth"] for r in group], dtype=float)
        out.append(
            ParameterSummary(
                procedure,
                noise,
                hidden,
                parameter,
                str(group[0]["unit"]),
                len(group),
                float(np.sqrt(np.mean(z**2))),
                float(np.mean(z)),
                float(np.sqrt(np.mean(err**2))),
                float(np.median([r["sigma"] for r in group])),
                float(design.get((procedure, noise), {}).get(parameter, math.nan)),
            )
        )
    return out


def diagnosis_rates(rows: Sequence[Mapping[str, Any]]) -> list[RateSummary]:
    """Return the detection rate per hidden-effect set, false-alarm rate where nothing is hidden (tasks, not rows)."""
    tasks: dict[str, Mapping[str, Any]] = {}
    for row in rows:
        tasks.setdefault(row["task"], row)
    counts: dict[tuple[str, str, str, str], list[int]] = defaultdict(lambda: [0, 0])
    for row in tasks.values():
        if row["detected"] == "" and row["hidden"] != "none":
            continue
        if row["hidden"] == "none":
            key, hit = (row["procedure"], row["noise"], row["hidden"], "false alarm"), bool(row["flagged"])
        else:
            key, hit = (row["procedure"], row["noise"], row["hidden"], "detection"), row["detected"] == "yes"
        counts[key][0] += int(hit)
        counts[key][1] += 1
    return [RateSummary(*key, hits, n) for key, (hits, n) in counts.items()]


def summary_text(parameters: Sequence[ParameterSummary], rates: Sequence[RateSummary], *, diagnosed: bool) -> str:
    """Return the summary as a table for a terminal or a file."""
    lines = []
    head = f"{'procedure':<14}{'noise':<9}{'hidden':<12}{'parameter':<10}{'n':>6}{'rms z':>8}{'mean z':>8}"
    head += f"{'measured σ':>12}{'design σ':>11}{'meas/des':>9}{'effic.':>8}  unit"
    lines.append(head)
    for s in parameters:
        lines.append(
            f"{s.procedure:<14.14}{s.noise:<9.9}{s.hidden:<12.12}{s.parameter:<10}{s.n:>6}{s.rms_z:>8.3f}{s.mean_z:>+8.3f}"
            f"{s.measured_sigma:>12.4g}{s.design_sigma:>11.4g}{s.measured_sigma / s.design_sigma:>9.3f}{s.efficiency:>8.3f}  {s.unit}"
        )
    if parameters:
        lo, hi = parameters[0].z_band
        lines.append(
            f"rms z: 1 for honest σ (99.9 % band for n = {parameters[0].n}: [{lo:.3f}, {hi:.3f}]); efficiency = (design σ / measured σ)²"
        )
    if diagnosed:
        for r in rates:
            lines.append(f"{r.kind} rate, {r.procedure} / {r.noise} / {r.hidden}: {r.hits}/{r.n} = {r.rate:.3f} ± {r.sigma:.3f}")
    else:
        lines.append("diagnosis not run ([campaign] diagnose = false): no detection or false-alarm rates")
    return "\n".join(lines)


def plot_summary(parameters: Sequence[ParameterSummary], rows: Sequence[Mapping[str, Any]], path: str | Path) -> None:
    """Two panels: measured σ / design σ per parameter (with rms z), and the histogram of z against N(0, 1)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (left, right) = plt.subplots(1, 2, figsize=(12, 4.8), gridspec_kw={"width_ratios": [2, 1]})
    groups = sorted({(s.procedure, s.noise, s.hidden) for s in parameters})
    names = sorted({s.parameter for s in parameters}, key=[s.parameter for s in parameters].index)
    width = 0.8 / max(1, len(groups))
    x = np.arange(len(names))
    for k, group in enumerate(groups):
        by = {s.parameter: s for s in parameters if (s.procedure, s.noise, s.hidden) == group}
        ratio = [by[n].measured_sigma / by[n].design_sigma if n in by else np.nan for n in names]
        rms = [by[n].rms_z if n in by else np.nan for n in names]
        offset = x + (k - (len(groups) - 1) / 2) * width
        spread = [1 / math.sqrt(2 * by[n].n) if n in by else np.nan for n in names]  # 1σ of a σ estimated from n devices
        left.errorbar(offset, ratio, yerr=spread, fmt="o", capsize=2, label=f"{' / '.join(group)}: measured σ / design σ (±1σ)")
        left.plot(offset, rms, "k_", markersize=10, label="rms z" if k == 0 else None)
    left.axhline(1.0, color="grey", lw=0.8)
    left.axhspan(0.95, 1.05, color="green", alpha=0.12, label="±5 %")
    left.set_xticks(x, names, rotation=60, fontsize=8)
    left.set_ylabel("ratio")
    left.set_title(f"σ measured over {parameters[0].n if parameters else 0} devices vs the design's Cramér-Rao bound")
    left.legend(fontsize=7, loc="lower left")
    z = np.array([r["z"] for r in rows if r["status"] == "estimated"], dtype=float)
    z = z[np.isfinite(z)]
    right.hist(z, bins=60, range=(-5, 5), density=True, color="tab:blue", alpha=0.7, label=f"z = err/σ ({z.size})")
    grid = np.linspace(-5, 5, 201)
    right.plot(grid, np.exp(-0.5 * grid**2) / math.sqrt(2 * math.pi), "k", lw=1, label="N(0, 1)")
    right.set_xlabel("z")
    right.set_title(f"all parameters: rms z {math.sqrt(np.mean(z**2)) if z.size else math.nan:.3f}")
    right.legend(fontsize=8)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=110)
    plt.close(fig)


@dataclass(frozen=True)
class CampaignOutputs:
    """What :func:`write_outputs` wrote and the summary it computed."""

    table: Path
    summary: Path
    plot: Path | None
    parameters: tuple[ParameterSummary, ...]
    rates: tuple[RateSummary, ...]
    text: str


def write_outputs(config: CampaignConfig, out: str | Path, *, plot: bool = True) -> CampaignOutputs:
    """From the finished tasks in ``out``: ``results.csv``, ``summary.txt`` and ``summary.png`` (atomically each)."""
    from stableins.campaign.execution import load_rows

    out = Path(out)
    rows = load_rows(out, config.tasks())
    write_table(out / "results.csv", rows)
    parameters = tuple(summarize(rows, design_sigmas(config)))
    rates = tuple(diagnosis_rates(rows))
    text = summary_text(parameters, rates, diagnosed=config.diagnose)
    with atomic_write(out / "summary.txt") as handle:
        handle.write(text + "\n")
    figure = None
    if plot and parameters:
        figure = out / "summary.png"
        plot_summary(parameters, rows, figure)
    return CampaignOutputs(out / "results.csv", out / "summary.txt", figure, parameters, rates, text)
