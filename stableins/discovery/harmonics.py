"""Harmonic tests of residuals: the spectrum of a residual series at chosen harmonics of the record length, and its significance."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stableins.conventions import EARTH_RATE
from stableins.discovery.diagnostics import Diagnosis, residual_layout
from stableins.display import layout_with_caption, plot_text
from stableins.estimators.result import FitResult

if TYPE_CHECKING:  # pragma: no cover
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure


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
        """Return the table of the harmonics: period, amplitude ± 1σ, χ², dof and p (amplitudes in ``unit``, divided by ``scale``)."""
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
        """Plot the residual's amplitude at the Earth-rate harmonics (least-squares fit ± 1σ, p of each) over its amplitude spectrum.

        The x axis is in cycles per sidereal day (``k`` = the ``k``-th harmonic of ω_ie), zoomed on ``0 … cycles``; the
        harmonics are marked with their periods.  ``unit``/``scale``: how amplitudes are shown (e.g. ``"µg"``,
        ``MICRO_G``); ``name``: the output, for the title; ``next_step``: a caption under the figure.
        """
        import matplotlib.pyplot as plt
        from matplotlib.figure import Figure as RootFigure

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
        ax.set_xlabel(r"frequency [cycles per sidereal day] (k = k-th harmonic of the Earth rate $\omega_{ie}$)")
        ax.set_ylabel(f"residual amplitude [{unit or 'SI'}]")
        ax.set_title(plot_text(f"Residual{' of ' + name if name else ''} at the Earth-rate harmonics"), fontsize=10)
        ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, 0.87), ncol=2)
        ax.grid(alpha=0.3)
        if ax is fig.axes[0] and len(fig.axes) == 1:
            layout_with_caption(fig, next_step, top=1.0)
        return fig if isinstance(fig, RootFigure) else fig.figure  # an axes of a subfigure: its figure


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
    from stableins.discovery.scores import IDENTIFIABLE_TOLERANCE

    t = np.asarray(time, dtype=float)
    h = np.asarray(harmonics, dtype=int)
    m = t.size
    r = whiten(problem, result, result.residuals)
    q, _ = np.linalg.qr(whiten(problem, result, problem.design(result)))
    residuals = result.residuals.reshape(m, -1)
    outputs = residuals.shape[1]
    names = residual_layout(result.residual_labels, result.residuals.size)[1]
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
        freq = np.asarray(2 * np.pi * np.fft.rfftfreq(n, dt), dtype=np.float64)
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
    freq = np.asarray(2 * np.pi * np.fft.rfftfreq(n, dt), dtype=np.float64)
    return HarmonicSpectrum(h, a, b, np.sqrt((sa**2 + sb**2) / 2.0), np.hypot(a, b), freq, spectrum, chi2, stats.chi2.sf(chi2, 2))
