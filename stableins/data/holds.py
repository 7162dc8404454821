r"""Static intervals (holds) of a continuous log: detection, the holds table, and its plot.

Detection (:func:`detect_holds`) cuts the log into consecutive windows of ``w`` samples and tests
each for motion with the within-window variance of the three axes.  Under white noise of
per-axis variance ``σ_a²`` a static window gives::

    T = Σ_a (w − 1) s_a² / σ_a²  ~  χ²_{3(w−1)}

and the window is called moving when ``T > χ²_{3(w−1)}(1 − α)``: ``α`` is the false-split rate,
the probability that the test takes a static window for motion (a hold of ``L`` windows is split by
mistake with probability about ``1 − (1 − 2α)^L`` with the mean test below; ``α = 1e-6`` with 0.5 s
windows is one false split in about 70 hours of static data).  ``σ_a²`` is measured in the log itself: the 10th percentile of
the window variances divided by the same percentile of ``χ²_{w−1}/(w−1)`` (valid when at least
a tenth of the log is static), and never below the quantization variance ``q²/12`` of one
least significant bit ``q``.  A slow turn keeps every window quiet but moves its mean, so a window whose mean differs from the previous
static window's by more than the same false-split rate allows (``Σ_a w (m_k − m_{k−1})²/(2σ_a²) > χ²_3(1 − α)``)
ends the hold.  Either test calls a static window moving with probability ``α``, so the false-split
rate is at most ``2α`` per static window (measured by ``benchmarks/bench_real_data.py``: 1.5α to 1.9α on
static white-noise logs).  A hold is a run of static windows lasting at least the minimum hold
after its first and last window are dropped (the settling margin).  Detection needs no gravity,
no model and no orientation.

The holds table (:func:`write_holds`, :func:`read_holds`) is a CSV file a person can edit and give
back: one row per hold with ``start`` and ``end`` in seconds from the first sample, the samples, the
mean and the sample standard deviation of each axis (m/s²), and an optional ``orientation`` label
(``+x``, ``-x``, ``+y``, ``-y``, ``+z``, ``-z``: which axis points up, the known-orientation
six-position test).  Reading it back uses only ``start``, ``end`` and ``orientation``; the
statistics are recomputed from the log.
"""

from __future__ import annotations

import csv
import os
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from stableins.errors import InputError

#: The orientation labels of the six-position test (the axis that points up, i.e. reads +g).
ORIENTATIONS = ("+x", "-x", "+y", "-y", "+z", "-z")

#: The percentile of the window variances that measures the static noise.
NOISE_PERCENTILE = 10.0

#: Columns of the holds table.
TABLE_COLUMNS = ("hold", "start", "end", "samples", "mean_x", "mean_y", "mean_z", "std_x", "std_y", "std_z", "orientation")


@dataclass(frozen=True)
class Hold:
    """One static interval: samples ``first`` ... ``stop − 1`` of the log.

    Attributes
    ----------
    first, stop : int
        Sample indices (``stop`` exclusive).
    orientation : str
        One of :data:`ORIENTATIONS`, or "" (unknown).
    """

    first: int
    stop: int
    orientation: str = ""


@dataclass(frozen=True)
class HoldDetection:
    """The holds found and how (what the console and the docs state).

    Attributes
    ----------
    holds : tuple of Hold
    window : int
        Samples per test window.
    false_split : float
        α, the probability that a static window is taken for motion.
    noise : ndarray (3,)
        Per-axis static noise σ_a [m/s²] the test used.
    threshold : float
        The χ² quantile a window's statistic is compared with.
    static_fraction : float
        Fraction of the windows found static.
    """

    holds: tuple[Hold, ...]
    window: int
    false_split: float
    noise: NDArray[np.float64]
    threshold: float
    static_fraction: float

    def describe(self, rate: float) -> str:
        """Return one sentence on the detection and its false-split rate."""
        per_hour = 2.0 * self.false_split * 3600.0 * rate / self.window
        return (
            f"{len(self.holds)} holds detected: moving-variance and mean tests on {self.window}-sample windows "
            f"({self.window / rate:.3g} s), each at α = {self.false_split:.1e}: false-split rate at most 2α per static window "
            f"({per_hour:.2g} false splits per hour of static data), static noise "
            f"{', '.join(f'{s:.3g}' for s in self.noise)} m/s^2 (x, y, z)"
        )


def detect_holds(
    time: NDArray[np.float64],
    specific_force: NDArray[np.float64],
    *,
    window: float = 0.5,
    min_hold: float = 1.5,
    false_split: float = 1e-6,
    resolution: NDArray[np.float64] | None = None,
    source: str = "log",
) -> HoldDetection:
    """Find the holds of a log (module docstring: the test, its false-split rate, the margins).

    Parameters
    ----------
    time : ndarray (n,)
        [s], increasing.
    specific_force : ndarray (n, 3)
        [m/s²].
    window : float
        Test window [s].
    min_hold : float
        Shortest hold kept [s], after the margins.
    false_split : float
        α per static window.
    resolution : ndarray (3,), optional
        One least significant bit per axis [m/s²] (the quantization floor of the noise).
    """
    from scipy.stats import chi2

    n = time.size
    rate = (n - 1) / float(time[-1] - time[0])
    w = max(4, int(round(window * rate)))
    count = n // w
    if count < 3:
        raise InputError(
            f"the log is only {n} samples, fewer than three {w}-sample windows", path=source, expected="a longer log or a shorter --window"
        )
    blocks = specific_force[: count * w].reshape(count, w, 3)
    variance = blocks.var(axis=1, ddof=1)
    finite = np.all(np.isfinite(variance), axis=1)
    if not np.any(finite):
        raise InputError("no finite samples", path=source, field="f_x")
    ratio = chi2.ppf(NOISE_PERCENTILE / 100.0, w - 1) / (w - 1)
    noise_var = np.percentile(variance[finite], NOISE_PERCENTILE, axis=0) / ratio
    floor = (np.zeros(3) if resolution is None else np.asarray(resolution, dtype=float)) ** 2 / 12.0
    noise_var = np.maximum(noise_var, floor)
    if np.any(noise_var <= 0):
        noise_var = np.maximum(noise_var, np.max(noise_var) * 1e-12 + 1e-30)
    statistic = np.sum((w - 1) * variance / noise_var, axis=1)
    threshold = float(chi2.isf(false_split, 3 * (w - 1)))
    static = finite & (statistic <= threshold)
    # a slow turn keeps each window quiet but moves its mean: consecutive static windows must agree in mean
    means = blocks.mean(axis=1)
    jump = np.r_[0.0, np.sum(np.diff(means, axis=0) ** 2 * w / (2.0 * noise_var), axis=1)]
    static &= ~((jump > float(chi2.isf(false_split, 3))) & np.r_[False, static[:-1]])
    holds = []
    edges = np.flatnonzero(np.diff(np.r_[0, static.astype(int), 0]))
    for begin, end in zip(edges[::2], edges[1::2], strict=True):
        first, stop = (begin + 1) * w, (end - 1) * w  # drop the first and last window: settling margins
        if stop - first >= 2 and time[stop - 1] - time[first] >= min_hold:
            holds.append(Hold(int(first), int(stop)))
    return HoldDetection(tuple(holds), w, false_split, np.sqrt(noise_var), threshold, float(np.mean(static)))


def hold_statistics(specific_force: NDArray[np.float64], hold: Hold) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Return the mean and sample standard deviation of each axis over a hold [m/s²]."""
    samples = specific_force[hold.first : hold.stop]
    return samples.mean(axis=0), samples.std(axis=0, ddof=1)


def write_holds(
    path: str | os.PathLike[str], time: NDArray[np.float64], specific_force: NDArray[np.float64], holds: Sequence[Hold]
) -> None:
    """Write the holds table (CSV, module docstring) atomically."""
    from stableins.data.atomic import atomic_path

    with atomic_path(path) as target, open(target, "w", newline="", encoding="utf-8") as handle:
        writer = csv.writer(handle)
        writer.writerow(TABLE_COLUMNS)
        for k, hold in enumerate(holds, 1):
            mean, std = hold_statistics(specific_force, hold)
            writer.writerow(
                [k, f"{time[hold.first]:.6f}", f"{time[hold.stop - 1]:.6f}", hold.stop - hold.first]
                + [f"{v:.9g}" for v in (*mean, *std)]
                + [hold.orientation]
            )


def read_holds_table(path: str | os.PathLike[str]) -> list[tuple[float, float, str]]:
    """Read and check a holds table: ``(start, end, orientation)`` per row, in time order and disjoint (``stableins check``)."""
    source = str(path)
    try:
        with open(path, newline="", encoding="utf-8") as handle:
            rows = list(csv.DictReader(handle))
    except OSError as error:
        raise InputError(f"cannot read the holds table: {error.strerror}", path=source, field="--holds") from None
    out: list[tuple[float, float, str]] = []
    for k, row in enumerate(rows, 1):
        for name in ("start", "end"):
            if row.get(name) in (None, ""):
                raise InputError("no value", path=source, row=k, field=name, expected="seconds from the first sample of the log")
        try:
            start, end = float(row["start"]), float(row["end"])
        except ValueError:
            raise InputError("start and end must be numbers", path=source, row=k, field="start", expected="seconds") from None
        if not (0.0 <= start < end):
            raise InputError(
                f"hold {start:g} ... {end:g} s: start must be below end", path=source, row=k, field="start", expected="0 <= start < end"
            )
        orientation = (row.get("orientation") or "").strip()
        if orientation and orientation not in ORIENTATIONS:
            expected = ", ".join(ORIENTATIONS) + " or empty"
            raise InputError(f"unknown orientation {orientation!r}", path=source, row=k, field="orientation", expected=expected)
        if out and start <= out[-1][1]:
            raise InputError(
                "holds overlap or are not in time order", path=source, row=k, field="start", expected="increasing, disjoint holds"
            )
        out.append((start, end, orientation))
    if not out:
        raise InputError("the holds table has no rows", path=source, field="--holds", expected=", ".join(TABLE_COLUMNS))
    return out


def read_holds(path: str | os.PathLike[str], time: NDArray[np.float64]) -> tuple[Hold, ...]:
    """Read a holds table (``start``, ``end`` [s from the first sample], optional ``orientation``) against the log's time."""
    holds = []
    for k, (start, end, orientation) in enumerate(read_holds_table(path), 1):
        if end > time[-1] + 1e-9:
            raise InputError(f"hold {start:g} ... {end:g} s ends after the log (0 ... {time[-1]:g} s)", path=str(path), row=k, field="end")
        holds.append(Hold(int(np.searchsorted(time, start - 1e-9)), int(np.searchsorted(time, end + 1e-9)), orientation))
    return tuple(holds)


def plot_holds(
    path: str | os.PathLike[str], time: NDArray[np.float64], specific_force: NDArray[np.float64], holds: Sequence[Hold], *, title: str = ""
) -> None:
    """Draw the three axes of the log [g] with the holds shaded and numbered; write a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from stableins.conventions import STANDARD_GRAVITY

    step = max(1, time.size // 20000)
    fig, ax = plt.subplots(figsize=(10, 4), constrained_layout=True)
    for i, (axis, colour) in enumerate(zip("xyz", ("tab:blue", "tab:orange", "tab:green"), strict=True)):
        ax.plot(time[::step], specific_force[::step, i] / STANDARD_GRAVITY, lw=0.7, color=colour, label=f"f_{axis}")
    top = float(np.nanmax(specific_force[::step])) / STANDARD_GRAVITY
    for k, hold in enumerate(holds, 1):
        ax.axvspan(time[hold.first], time[hold.stop - 1], color="0.85", zorder=0)
        ax.text(0.5 * (time[hold.first] + time[hold.stop - 1]), top * 1.05, str(k), ha="center", fontsize=7)
    ax.set_xlabel("time from the first sample [s]")
    ax.set_ylabel("specific force [g]")
    ax.set_title(title or f"{len(holds)} holds detected (shaded)")
    ax.legend(loc="lower right", fontsize=8)
    from stableins.data.atomic import atomic_path

    with atomic_path(path) as target:
        fig.savefig(target, dpi=110, format="png")
    plt.close(fig)
