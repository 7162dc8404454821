r"""Which effects explain the third Earth-rate harmonic of a system record, and which of them the record can tell apart.

A static, polar-aligned record sees the platform-frame specific force ``f^p = g u``, ``u = (cosL cos S, cosL sin S,
sinL)``.  An output term of accelerometer ``a`` that is a product of two inputs, ``δ_a = c·u_b u_c`` (``δ = Δf^p/g``),
adds ``u_a δ_a`` to ``z``: a cubic in ``(cos S, sin S)`` whose ``cos 3S`` or ``sin 3S`` part is the third harmonic the
stage fits as ``x6``, ``x7``.  Several library effects do that (docs/system-calibration.md §8, "Third harmonic"):

======================  ===========================  ===========================
effect                  ``δ`` per unit (SI)           third harmonic in ``z``
======================  ===========================  ===========================
``K2_x`` (core)         ``δ_x = g u_x²``              ``x6 = g K/4``
``K2_y`` (core)         ``δ_y = g u_y²``              ``x7 = −g K/4``
``Kcc_xxy``             ``δ_x = g u_x u_y``           ``x7 = g K/4``
``Kcc_yxy``             ``δ_y = g u_x u_y``           ``x6 = −g K/4``
``Kcq_xy``              ``δ_x = g u_y²``              ``x6 = −g K/4``
``Kcq_yx``              ``δ_y = g u_x²``              ``x7 = g K/4``
``Ksa_x``, ``Ksa_y``    ``δ_a = |u_a|``               ``x6``, ``x7`` (and odd harmonics above)
======================  ===========================  ===========================

Each also moves the means, fundamentals and second harmonics of ``z`` and of pitch and roll, differently: its
*signature* ``s_e`` in ``v = (x1..x7, attitude)`` (:func:`signature`, the quasi-static harmonic coefficients of
``z = u·δ``, pitch ``Δf_N/g`` and roll ``−Δf_E/g`` over one turn of ``S``).  What the standard model absorbs of it
(biases, scale factors, installation angles, the two mean nuisances: ``combination_matrix``) is invisible; what is left
is the effect's evidence.  :func:`explain_third_harmonic` fits the fifteen combined coefficients and ``x6``, ``x7``
with the standard model plus one hypothesis at a time (generalized least squares under the stage's covariance) and
keeps every hypothesis the data do not reject (``p ≥ α``, χ² with ``ν = 17 − rank``).  Two hypotheses the data both
accept are aliases of this record: the stage names them all and advises no correction (``estimate_k2``) that the data
cannot tell from its alias; device-level positions separate them (45° positions for a cross-coupling).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from stableins.errormodel import MICRO_G_PER_G2
from stableins.estimators.system.attitude import ATTITUDE_COEFFICIENTS
from stableins.estimators.system.separation import combination_matrix

#: Library effects with a third harmonic on a polar-aligned platform: ``(id, axis, δ per unit of the effect (SI) as a
#: function of u (n, 3), what separates it from its aliases)``.  The products follow the library's definitions
#: (``stableins.discovery.catalogue``; the test compares the two).
Effect = tuple[str, int, Callable[[NDArray[np.float64], float], NDArray[np.float64]], str]

_FORTY_FIVE = "device-level 45° positions with both signs of f_x·f_y (stableins diagnose DEVICE... --add {id})"
_PER_AXIS = "device-level positions with the {b} axis at ±1 g and at 0 g while the {a} axis is horizontal and vertical"

THIRD_HARMONIC_EFFECTS: tuple[Effect, ...] = (
    ("K2_x", 0, lambda u, g: g * u[:, 0] ** 2, "the device stages' ±1 g and intermediate positions of the x axis"),
    ("K2_y", 1, lambda u, g: g * u[:, 1] ** 2, "the device stages' ±1 g and intermediate positions of the y axis"),
    ("Kcc_xxy", 0, lambda u, g: g * u[:, 0] * u[:, 1], _FORTY_FIVE.format(id="Kcc_xxy")),
    ("Kcc_yxy", 1, lambda u, g: g * u[:, 0] * u[:, 1], _FORTY_FIVE.format(id="Kcc_yxy")),
    ("Kcq_xy", 0, lambda u, g: g * u[:, 1] ** 2, _PER_AXIS.format(a="x", b="y")),
    ("Kcq_yx", 1, lambda u, g: g * u[:, 0] ** 2, _PER_AXIS.format(a="y", b="x")),
    ("Ksa_x", 0, lambda u, g: np.abs(u[:, 0]), "device-level positions of the x axis at intermediate inputs (±0.7 g)"),
    ("Ksa_y", 1, lambda u, g: np.abs(u[:, 1]), "device-level positions of the y axis at intermediate inputs (±0.7 g)"),
)

#: Units in which the hypotheses' sizes are printed (SI per unit): µg/g² for the products, ppm for the asymmetry.
_UNIT = {"Ksa": (1e-6, "ppm")}

#: The hypothesis ``estimate_k2`` removes: ΔK2_x and ΔK2_y together.
K2_HYPOTHESIS = "K2_x + K2_y"

#: Points of the Earth-rate angle over one turn for the signatures (harmonics up to 8 are exact on 64 points; |u_a|
#: has all odd harmonics, whose aliases from above 64 are below 1e-5 of the third).
_GRID = 720


def _harmonic_design(angle: NDArray[np.float64], latitude: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Design of ``z`` (the stage's seven H columns) and of pitch/roll (mean, cos S, sin S, cos 2S, sin 2S)."""
    from stableins.estimators.system.harmonics import observation_rows

    h = observation_rows(angle, latitude, order=3)
    a = np.stack([np.ones_like(angle), np.cos(angle), np.sin(angle), np.cos(2 * angle), np.sin(2 * angle)], axis=1)
    return h, a


def signature(
    delta: Callable[[NDArray[np.float64], float], NDArray[np.float64]], axis: int, latitude: float, gravity: float
) -> NDArray[np.float64]:
    r"""Quasi-static signature ``(17,)`` in ``v = (x1..x7, attitude)`` of ``δ_axis = delta(u, g)`` per unit of the effect.

    ``z = u·δ`` on the stage's seven H columns; pitch ``Δf_N/g = −sinL(cos S δ_x + sin S δ_y) + cosL δ_z`` and roll
    ``−Δf_E/g = sin S δ_x − cos S δ_y`` on mean, fundamental and second harmonic, in the order of
    :data:`ATTITUDE_COEFFICIENTS` (docs/system-calibration.md §1–2).  Least squares over one turn of ``S``.
    """
    angle: NDArray[np.float64] = np.arange(_GRID, dtype=np.float64) * (2 * np.pi / _GRID)
    c, s = math.cos(latitude), math.sin(latitude)
    u = np.stack([c * np.cos(angle), c * np.sin(angle), np.full_like(angle, s)], axis=1)
    d = np.zeros_like(u)
    d[:, axis] = delta(u, gravity)
    z = np.einsum("ni,ni->n", u, d)
    pitch = -s * (np.cos(angle) * d[:, 0] + np.sin(angle) * d[:, 1]) + c * d[:, 2]
    roll = np.sin(angle) * d[:, 0] - np.cos(angle) * d[:, 1]
    h, a = _harmonic_design(angle, latitude)
    x = np.linalg.lstsq(h, z, rcond=None)[0]
    coefficients = {}
    for name, series in (("theta", pitch), ("phi", roll)):
        fit = np.linalg.lstsq(a, series, rcond=None)[0]
        for k, suffix in enumerate(("mean", "1c", "1s", "2c", "2s")):
            coefficients[f"{name}_{suffix}"] = fit[k]
    return np.concatenate([x, [coefficients[n] for n in ATTITUDE_COEFFICIENTS]])


@dataclass(frozen=True)
class Hypothesis:
    """One explanation of the third harmonic and how the record's coefficients receive it.

    Attributes
    ----------
    name : str
        The effect (or ``K2_x + K2_y``, what ``estimate_k2`` removes).
    size : tuple of float
        Least-squares size of each of its terms [SI], with the standard model fitted alongside.
    sigma : tuple of float
        Their 1σ.
    chi2, dof, p_value : float, int, float
        The fit of the fifteen combined coefficients and ``x6``, ``x7`` with the standard model plus this effect.
    consistent : bool
        ``p ≥ α``: the record does not reject it.
    separation : str
        What separates it from its aliases.
    """

    name: str
    size: tuple[float, ...]
    sigma: tuple[float, ...]
    chi2: float
    dof: int
    p_value: float
    consistent: bool
    separation: str

    def describe(self) -> str:
        """One phrase: the effect, its size ± 1σ in engineering units, χ²/ν and p."""
        parts = []
        for term, value, sigma in zip(self.name.split(" + "), self.size, self.sigma, strict=True):
            scale, unit = _UNIT.get(term.split("_")[0], (MICRO_G_PER_G2, "µg/g²"))
            parts.append(f"{term} = {value / scale:.1f} ± {sigma / scale:.1f} {unit}")
        return f"{', '.join(parts)} (χ² = {self.chi2:.1f}, ν = {self.dof}, p = {self.p_value:.2g})"


@dataclass(frozen=True)
class ThirdHarmonic:
    """What explains the third harmonic of a record (:func:`explain_third_harmonic`).

    Attributes
    ----------
    significant : bool
        ``x6`` or ``x7`` beyond 3σ (the stage's flag of a third harmonic).
    baseline_chi2, baseline_dof, baseline_p : float, int, float
        The standard model alone on the same seventeen numbers.
    hypotheses : tuple of Hypothesis
        Every hypothesis, best (smallest χ²) first.
    alpha : float
        Level below which a hypothesis is rejected.
    """

    significant: bool
    baseline_chi2: float
    baseline_dof: int
    baseline_p: float
    hypotheses: tuple[Hypothesis, ...]
    alpha: float

    @property
    def consistent(self) -> tuple[Hypothesis, ...]:
        """The hypotheses the record does not reject."""
        return tuple(h for h in self.hypotheses if h.consistent)

    @property
    def k2_alone(self) -> bool:
        """A residual K2 is the only explanation the record accepts (then ``estimate_k2`` is the correction to make)."""
        names = [h.name for h in self.consistent]
        return bool(names) and all(n in (K2_HYPOTHESIS, "K2_x", "K2_y") for n in names)

    def note(self, *, estimate_k2: bool, parameter: str, reading: str = "") -> str | None:
        """Return the stage's note on the third harmonic (None when it is not significant and K2 is not being estimated).

        ``reading``: the third harmonic read as residual K2 (the stage's sizes), put in the head.
        """
        if not self.significant and not estimate_k2:
            return None
        k2 = next(h for h in self.hypotheses if h.name == K2_HYPOTHESIS)
        accepted = self.consistent
        reading = f"; {reading}" if reading else ""
        head = (
            f"third harmonic of Earth rate in the specific-force error (x6, x7 beyond 3σ; the paper's model has none{reading})"
            if self.significant
            else "K2 estimated from the third harmonic of Earth rate"
        )
        rejected = [h.name for h in self.hypotheses if not h.consistent]
        if estimate_k2:
            if k2.consistent:
                alias = [h.name for h in accepted if h.name not in (K2_HYPOTHESIS, "K2_x", "K2_y")]
                tail = (
                    f"; the record cannot tell it from {', '.join(alias)}, which explain the coefficients as well: the K2 correction is "
                    "right only if the device-level data show the effect is K2 ("
                    + "; ".join(f"{h.name}: {h.separation}" for h in accepted if h.name in alias)
                    + ")"
                    if alias
                    else ""
                )
                return f"{head}: removed as a residual K2, {k2.describe()}{tail}"
            return (
                f"{head}: a residual K2 does NOT explain the coefficients ({k2.describe()}; the standard model alone: χ² = "
                f"{self.baseline_chi2:.1f}, ν = {self.baseline_dof}); the K2 correction ({parameter}) biases them. "
                + (
                    "Explanations the record accepts: " + "; ".join(h.describe() for h in accepted)
                    if accepted
                    else "No single library effect explains them"
                )
            )
        if not accepted:
            return (
                f"{head}: no single library effect explains the coefficients (standard model: χ² = {self.baseline_chi2:.1f}, "
                f"ν = {self.baseline_dof}; rejected at α = {self.alpha:g}: {', '.join(rejected)}); do not correct it with K2 "
                "(stableins diagnose on the record ranks the candidates)"
            )
        named = "; ".join(h.describe() for h in accepted)
        if len(accepted) == 1 and not self.k2_alone:
            only = accepted[0]
            return (
                f"{head}. Explained by {only.name} alone among the library's effects: {named}; the record rejects a residual K2 "
                f"({k2.describe()}) and {', '.join(n for n in rejected if n != K2_HYPOTHESIS)} at α = {self.alpha:g}. Do not use the K2 "
                f"estimation ({parameter}): it would bias x2, x3 and the fundamentals. {only.name} is an instrument term the device "
                f"calibration carries; confirm and estimate it there ({only.separation})"
            )
        if self.k2_alone:
            return (
                f"{head}. Explained by a residual K2 and by no other library effect (rejected at α = {self.alpha:g}: "
                f"{', '.join(rejected)}): {named}. It biases x2, x3 and the fundamentals of pitch and roll; rerun with the K2 "
                f"estimation on ({parameter}) to remove it"
            )
        return (
            f"{head}. Several effects explain it equally and this record cannot tell them apart: {named}. Each biases x2, x3 "
            "and the fundamentals of pitch and roll differently, so no correction is applied or advised: the K2 estimation "
            f"({parameter}) is right only if the device-level data show the effect is K2. What separates them: "
            + "; ".join(f"{h.name}: {h.separation}" for h in accepted)
            + (f". Rejected by the record at α = {self.alpha:g}: {', '.join(rejected)}" if rejected else "")
        )


def _gls(
    w: NDArray[np.float64], whiten: NDArray[np.float64], design: NDArray[np.float64]
) -> tuple[float, int, NDArray[np.float64], NDArray[np.float64]]:
    """χ², ν, solution and covariance of the whitened least-squares fit of ``w`` with ``design``."""
    a, r = whiten @ design, whiten @ w
    u, sv, vt = np.linalg.svd(a, full_matrices=False)
    keep = sv > 1e-10 * sv[0]
    coef = vt[keep].T @ ((u[:, keep].T @ r) / sv[keep])
    cov = vt[keep].T @ np.diag(1.0 / sv[keep] ** 2) @ vt[keep]
    residual = r - a @ coef
    return float(residual @ residual), int(w.size - keep.sum()), coef, cov


def explain_third_harmonic(
    v: NDArray[np.float64],
    cov_v: NDArray[np.float64],
    latitude: float,
    gravity: float,
    *,
    alpha: float = 0.05,
    extra: Mapping[str, tuple[NDArray[np.float64], str]] | None = None,
    effects: Sequence[Effect] = THIRD_HARMONIC_EFFECTS,
) -> ThirdHarmonic:
    """Test each explanation of the third harmonic against the stage's ``v = (x1..x7, attitude)`` and its covariance.

    ``w = (x1..x5, attitude, x6, x7)``, model ``w = G q + s_e a`` (``G`` the standard model's combined coefficients
    from the residuals and the two mean nuisances, nothing in ``x6``, ``x7``), generalized least squares under
    ``cov_v``.  ``extra``: further hypotheses ``{name: (signature (17,) per unit, separation)}`` (e.g. a scale-factor
    temperature sensitivity under the record's thermal cycle).  The third harmonic is significant when ``x6`` or ``x7``
    is beyond 3σ.
    """
    from scipy.stats import chi2 as chi2_dist

    order = np.r_[0:5, 7:17, 5:7]  # v → w
    w, cov = v[order], cov_v[np.ix_(order, order)]
    sd = np.sqrt(np.diag(cov))
    whiten = np.linalg.inv(np.linalg.cholesky(cov / np.outer(sd, sd)) * sd[:, None])
    g = np.zeros((17, 14))
    g[:15] = combination_matrix(latitude)
    chi0, nu0, _, _ = _gls(w, whiten, g)
    columns: dict[str, tuple[NDArray[np.float64], str]] = {}
    k2 = [signature(d, ax, latitude, gravity) for name, ax, d, _ in effects if name in ("K2_x", "K2_y")]
    columns[K2_HYPOTHESIS] = (np.stack(k2, axis=1), "the device stages' ±1 g and intermediate positions of the x and y axes")
    for name, ax, d, separation in effects:
        columns[name] = (signature(d, ax, latitude, gravity)[:, None], separation)
    for name, (column, separation) in (extra or {}).items():
        columns[name] = (np.asarray(column, dtype=float).reshape(17, -1), separation)
    hypotheses = []
    for name, (column, separation) in columns.items():
        chi, nu, coef, cov_coef = _gls(w, whiten, np.hstack([g, column[order]]))
        p = float(chi2_dist.sf(chi, nu)) if nu > 0 else 1.0
        k = column.shape[1]
        hypotheses.append(Hypothesis(name, tuple(coef[-k:]), tuple(np.sqrt(np.diag(cov_coef))[-k:]), chi, nu, p, p >= alpha, separation))
    hypotheses.sort(key=lambda h: h.chi2)
    third = v[5:7] / np.sqrt(np.diag(cov_v)[5:7])
    p0 = float(chi2_dist.sf(chi0, nu0)) if nu0 > 0 else 1.0
    return ThirdHarmonic(bool(np.any(np.abs(third) > 3.0)), chi0, nu0, p0, tuple(hypotheses), alpha)


__all__ = ["K2_HYPOTHESIS", "THIRD_HARMONIC_EFFECTS", "Hypothesis", "ThirdHarmonic", "explain_third_harmonic", "signature"]
