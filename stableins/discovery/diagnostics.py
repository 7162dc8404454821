r"""Compare a fitted model with the measurements and see where it fails.

For any fitted stage (a :class:`~stableins.estimators.result.FitResult`):

* residuals per position and axis against the noise floor measured independently of the
  fit (within-dwell scatter, :func:`stableins.discovery.problem.dwell_means`);
* ``χ²_ν = χ²/ν`` with its expected spread ``sqrt(2/ν)`` and the probability of a larger
  value under the model, ``P(χ²_ν' ≥ χ²_ν)``;
* plots: residuals per position with 1σ bars, residuals against orientation (``f^p/g`` per
  axis), and for system records the residual amplitude at the Earth-rate harmonics
  (:func:`harmonic_spectrum`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stableins.conventions import EARTH_RATE, MICRO_G
from stableins.estimators.result import FitResult

if TYPE_CHECKING:  # pragma: no cover
    from matplotlib.figure import Figure

AXIS_NAMES = ("x", "y", "z")


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

    def report(self) -> str:
        r = self.result
        verdict = "consistent with the noise floor" if self.consistent else "NOT consistent with the noise floor: something is missing"
        lines = [
            f"{r.stage}: χ²_ν = {self.chi2_red:.3f} (ν = {r.dof}, expected 1 ± {self.spread:.3f}); "
            f"P(χ² ≥ observed) = {self.p_value:.3g} — {verdict}",
            f"{'axis':<5} {'residual RMS':>14} {'noise floor':>12} {'ratio':>7}",
        ]
        for a, rms, floor in zip(self.outputs, self.rms, self.noise_floor, strict=True):
            u, sc = self.unit, self.scale
            lines.append(f"{a:<5} {rms / sc:>11.3f} {u:<2} {floor / sc:>9.3f} {u:<2} {rms / floor:>7.2f}")
        if self.noise:
            lines.append(f"noise floor: {self.noise.get('method', '')}")
        lines.append("largest residuals: " + ", ".join(f"{p} {a} {z:+.1f}σ" for p, a, z in self.worst()))
        return "\n".join(lines)

    def __str__(self) -> str:
        return self.report()

    # ------------------------------------------------------------------ plots
    def plot_positions(self, fig: Figure | None = None, title: str | None = None) -> Figure:
        """Residuals per position and output with 1σ bars (in :attr:`unit`)."""
        import matplotlib.pyplot as plt

        fig = fig or plt.figure(figsize=(10, 6.5))
        k = np.arange(len(self.position_labels))
        axes = np.atleast_1d(fig.subplots(len(self.outputs), 1, sharex=True))
        for i, ax in enumerate(axes):
            ax.errorbar(k, self.residuals[:, i] / self.scale, yerr=self.sigma[:, i] / self.scale, fmt="o", ms=3.5, lw=1, capsize=2)
            ax.axhline(0.0, color="k", lw=0.6)
            ax.set_ylabel(f"{self.outputs[i]} residual [{self.unit}]")
            ax.grid(alpha=0.3)
        if len(k) <= 80:
            axes[-1].set_xticks(k, self.position_labels, rotation=90, fontsize=7)
        axes[0].set_title(title or f"{self.result.stage}: χ²_ν = {self.chi2_red:.2f} (expected 1 ± {self.spread:.2f})")
        fig.tight_layout()
        return fig

    def plot_orientation(self, fig: Figure | None = None) -> Figure:
        """Normalized residual of each axis against each component of ``f^p/g`` (3 × 3 panels)."""
        import matplotlib.pyplot as plt

        if self.orientation is None:
            raise ValueError("this diagnosis has no orientation (not a dwell problem)")
        fig = fig or plt.figure(figsize=(9, 8))
        axes = fig.subplots(3, 3, sharex=True, sharey=True)
        z = self.normalized
        for i in range(3):
            for j in range(3):
                ax = axes[i, j]
                ax.scatter(self.orientation[:, j], z[:, i], s=12)
                ax.axhline(0.0, color="k", lw=0.6)
                ax.grid(alpha=0.3)
                if i == 2:
                    ax.set_xlabel(f"f^p_{AXIS_NAMES[j]} / g")
                if j == 0:
                    ax.set_ylabel(f"f_{AXIS_NAMES[i]} residual / σ")
        fig.suptitle("residuals against orientation")
        fig.tight_layout()
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


def diagnose(problem, result: FitResult, unit: str = "µg", scale: float = MICRO_G) -> Diagnosis:
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
        noise=dict(result.extra.get("noise", {})),
        outputs=outputs,
        unit=unit,
        scale=scale,
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

    def plot(self, ax=None, unit: str = "", scale: float = 1.0):
        """The residual's amplitude spectrum up to a few harmonics beyond those tested, and each tested harmonic ± 1σ.

        Harmonics the fitted model explains (no degree of freedom left) are not drawn; error bars stop at a tenth of
        the amplitude on the logarithmic axis.
        """
        import matplotlib.pyplot as plt

        fig = ax.figure if ax is not None else plt.figure(figsize=(8, 4))
        ax = ax or fig.add_subplot(111)
        top = float(self.harmonics.max()) + 4.0 if self.harmonics.size else 8.0
        x = self.frequency / EARTH_RATE
        shown = (x > 0) & (x <= top)
        ax.semilogy(x[shown], self.periodogram[shown] / scale, lw=0.8, label="residual amplitude spectrum")
        tested = self.amplitude > 0 if self.dof is None else (self.dof > 0) & (self.amplitude > 0)
        amplitude, sigma = self.amplitude[tested] / scale, self.sigma[tested] / scale
        ax.errorbar(
            self.harmonics[tested],
            amplitude,
            yerr=np.stack([np.minimum(sigma, 0.9 * amplitude), sigma]),
            fmt="o",
            capsize=3,
            label="Earth-rate harmonics (fit, ±1σ)",
        )
        values = np.concatenate([self.periodogram[shown] / scale, amplitude + sigma, 0.1 * amplitude])
        values = values[np.isfinite(values) & (values > 0)]
        if values.size:
            ax.set_ylim(values.min() / 2.0, values.max() * 2.0)
        ax.set_xlim(0.0, top)
        ax.set_xlabel("frequency / ω_ie")
        ax.set_ylabel(f"amplitude [{unit}]")
        ax.legend()
        ax.grid(alpha=0.3, which="both")
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
