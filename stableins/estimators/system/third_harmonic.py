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

#: Points of the Earth-rate angle over one turn for the signatures (harmonics up to 8 are exact on 64 points; |u_a|
#: has all odd harmonics, whose aliases from above 64 are below 1e-5 of the third).
_GRID = 720


def _harmonic_design(angle: NDArray[np.float64], latitude: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Design of ``z`` (the stage's seven H columns) and of pitch/roll (mean, cos S, sin S, cos 2S, sin 2S)."""
    from stableins.estimators.system.harmonics import harmonic_rows

    h = harmonic_rows(angle, latitude, order=3)
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
    """One explanation of the third harmonic (an effect for its cosine part x6 and one for its sine part x7).

    Attributes
    ----------
    terms : tuple of str
        The effects, one or two (``K2_x``, ``K2_y`` is what ``estimate_k2`` removes).
    size, sigma : tuple of float
        Least-squares size of each [SI] with the standard model fitted alongside, and its 1σ.
    chi2, dof, p_value : float, int, float
        The fit of the fifteen combined coefficients and ``x6``, ``x7`` with the standard model plus these effects
        (``p_value`` with σ scaled when no hypothesis fits, :attr:`ThirdHarmonic.scale`).
    consistent : bool
        ``p ≥ α``: the record does not reject it.
    """

    terms: tuple[str, ...]
    size: tuple[float, ...]
    sigma: tuple[float, ...]
    chi2: float
    dof: int
    p_value: float
    consistent: bool

    @property
    def name(self) -> str:
        """The effects joined by ``+``."""
        return " + ".join(self.terms)

    def describe(self) -> str:
        """One phrase: the effects, their sizes ± 1σ in engineering units, χ²/ν and p."""
        return f"{_sizes(self.terms, self.size, self.sigma)} (χ² = {self.chi2:.1f}, ν = {self.dof}, p = {self.p_value:.2g})"


def _sizes(terms: Sequence[str], size: Sequence[float], sigma: Sequence[float]) -> str:
    parts = []
    for term, value, error in zip(terms, size, sigma, strict=True):
        scale, unit = _UNIT.get(term.split("_")[0], (MICRO_G_PER_G2, "µg/g²"))
        if term.startswith("Kt_sf"):
            scale, unit = 1e-6, "ppm/K"
        parts.append(f"{term} = {value / scale:.1f} ± {error / scale:.1f} {unit}")
    return ", ".join(parts)


#: The two parts of the third harmonic: its cosine (x6) and sine (x7) in z.
THIRD_HARMONIC_STATES = ("x6", "x7")


@dataclass(frozen=True)
class ThirdHarmonic:
    """What explains the third harmonic of a record (:func:`explain_third_harmonic`).

    Attributes
    ----------
    significant : tuple of bool
        ``x6``, ``x7`` beyond 3σ (the stage's flag of a third harmonic).
    baseline_chi2, baseline_dof : float, int
        The standard model alone on the same seventeen numbers.
    hypotheses : tuple of Hypothesis
        Every hypothesis (one effect for x6 and one for x7, or one thermal term), best (smallest χ²) first.
    alpha : float
        Level below which a hypothesis is rejected.
    scale : float
        χ²/ν of the best hypothesis when even that one is rejected (something else moves the coefficients, e.g. an
        unknown gyro drift in pitch and roll): the comparison is then relative, with σ scaled by its square root; else 1.
    candidates : dict
        ``{component: {effect: separation}}``: the effects that make x6 and those that make x7.
    """

    significant: tuple[bool, bool]
    baseline_chi2: float
    baseline_dof: int
    hypotheses: tuple[Hypothesis, ...]
    alpha: float
    scale: float
    candidates: Mapping[str, Mapping[str, str]]

    @property
    def consistent(self) -> tuple[Hypothesis, ...]:
        """The hypotheses the record does not reject."""
        return tuple(h for h in self.hypotheses if h.consistent)

    def accepted(self, component: str) -> tuple[str, ...]:
        """Return the effects of ``component`` (``x6`` or ``x7``) found in a hypothesis the record accepts, best first."""
        names = self.candidates[component]
        out: list[str] = []
        for h in self.consistent:
            for term in h.terms:
                if term in names and term not in out:
                    out.append(term)
        return tuple(out)

    @property
    def k2_alone(self) -> bool:
        """A residual K2 is the only accepted explanation of every significant part (then ``estimate_k2`` is the correction)."""
        parts = [c for c, sig in zip(THIRD_HARMONIC_STATES, self.significant, strict=True) if sig]
        return bool(parts) and all(self.accepted(c) == (f"K2_{'x' if c == 'x6' else 'y'}",) for c in parts)

    def _k2(self) -> Hypothesis:
        return next(h for h in self.hypotheses if h.terms == ("K2_x", "K2_y"))

    def _parts(self) -> str:
        out = []
        for component, sig in zip(THIRD_HARMONIC_STATES, self.significant, strict=True):
            if not sig:
                continue
            accepted = self.accepted(component)
            best = {t: h for h in reversed(self.consistent) for t in h.terms}
            what = "cos 3S" if component == "x6" else "sin 3S"
            named = "; ".join(
                _sizes((t,), (best[t].size[best[t].terms.index(t)],), (best[t].sigma[best[t].terms.index(t)],)) for t in accepted
            )
            out.append(f"its {what} part ({component}): " + (named if accepted else "no library effect"))
        return "; ".join(out)

    def note(self, *, estimate_k2: bool, parameter: str, reading: str = "") -> str | None:
        """Return the stage's note on the third harmonic (None when it is not significant and K2 is not being estimated).

        ``reading``: the third harmonic read as residual K2 (the stage's sizes), put in the head.
        """
        if not any(self.significant) and not estimate_k2:
            return None
        k2 = self._k2()
        reading = f"; {reading}" if reading else ""
        head = (
            f"third harmonic of Earth rate in the specific-force error (x6, x7 beyond 3σ; the paper's model has none{reading})"
            if any(self.significant)
            else "K2 estimated from the third harmonic of Earth rate"
        )
        relative = (
            f" (no hypothesis fits the coefficients: the best leaves χ²_ν = {self.scale:.1f}, something else moves them, e.g. an "
            "unknown gyro drift in pitch and roll; the comparison is relative, σ scaled by its square root)"
            if self.scale > 1.0
            else ""
        )
        separations = {t: sep for names in self.candidates.values() for t, sep in names.items()}
        significant = [c for c, sig in zip(THIRD_HARMONIC_STATES, self.significant, strict=True) if sig] or list(THIRD_HARMONIC_STATES)
        accepted = [t for c in significant for t in self.accepted(c)]
        separate = "; ".join(f"{t}: {separations[t]}" for t in dict.fromkeys(accepted))
        if estimate_k2:
            if not any(self.significant):
                return (
                    f"{head}: removed as a residual K2, {k2.describe()}{relative}; the third harmonic is within 3σ, so the "
                    "record neither needs the correction nor tells K2 from another effect; what separates them: "
                    + ("; ".join(f"{t}: {sep}" for t, sep in separations.items() if not t.startswith("K2_")) or "device-level data")
                )
            if self.k2_alone:
                return f"{head}: removed as a residual K2, {k2.describe()}{relative}"
            if k2.consistent:
                return (
                    f"{head}: removed as a residual K2 ({k2.describe()}), but the record cannot tell K2 from other effects that "
                    f"explain it as well{relative}: {self._parts()}.  The K2 correction ({parameter}) is right only if the "
                    f"device-level data show the effect is K2; what separates them: {separate}"
                )
            return (
                f"{head}: a residual K2 does NOT explain the coefficients ({k2.describe()}; the standard model alone: χ² = "
                f"{self.baseline_chi2:.1f}, ν = {self.baseline_dof}){relative}; the K2 correction ({parameter}) biases them. "
                f"Explanations the record accepts: {self._parts()}"
            )
        if not accepted:
            return (
                f"{head}: no library effect explains the coefficients (standard model: χ² = {self.baseline_chi2:.1f}, "
                f"ν = {self.baseline_dof}); do not correct it with K2 (stableins diagnose on the record ranks the candidates)"
            )
        if self.k2_alone:
            return (
                f"{head}: explained by a residual K2 and by no other library effect{relative}: {k2.describe()}. It biases x2, x3 "
                f"and the fundamentals of pitch and roll; rerun with the K2 estimation on ({parameter}) to remove it"
            )
        several = any(len(self.accepted(c)) > 1 for c, sig in zip(THIRD_HARMONIC_STATES, self.significant, strict=True) if sig)
        k2_text = (
            "the K2 estimation (" + parameter + ") is right only if the device-level data show the effect is K2"
            if k2.consistent
            else f"the record rejects a residual K2 ({k2.describe()}): do not use the K2 estimation ({parameter}), it would bias "
            "x2, x3 and the fundamentals"
        )
        if not several:
            return (
                f"{head}{relative}. Explained by {self._parts()} alone among the library's effects; {k2_text}. An instrument term "
                f"the device calibration carries: confirm and estimate it there ({separate})"
            )
        return (
            f"{head}{relative}. Several effects explain it and this record cannot tell them apart: {self._parts()}. Each moves "
            f"x2, x3 and the fundamentals of pitch and roll differently, so no correction is applied or advised; {k2_text}. "
            f"What separates them: {separate}"
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

    ``w = (x1..x5, attitude, x6, x7)``, model ``w = G q + S a`` (``G`` the standard model's combined coefficients from the
    residuals and the two mean nuisances, nothing in ``x6``, ``x7``; ``S`` the signatures of one effect making x6 and one
    making x7), generalized least squares under ``cov_v``, every pair.  ``extra``: further single hypotheses ``{name:
    (signature (17,) per unit, separation)}`` that make both parts (a scale-factor temperature sensitivity under the
    record's daily cycle).  When even the best hypothesis is rejected, σ is scaled by its ``sqrt(χ²/ν)`` (Birge) and the
    hypotheses are compared relative to it.  A part is significant when it is beyond 3σ.
    """
    from stableins.estimators.distributions import chi2_sf

    order = np.r_[0:5, 7:17, 5:7]  # v → w
    w, cov = v[order], cov_v[np.ix_(order, order)]
    sd = np.sqrt(np.diag(cov))
    whiten = np.linalg.inv(np.linalg.cholesky(cov / np.outer(sd, sd)) * sd[:, None])
    g = np.zeros((17, 14))
    g[:15] = combination_matrix(latitude)
    chi0, nu0, _, _ = _gls(w, whiten, g)
    columns = {name: signature(d, ax, latitude, gravity) for name, ax, d, _ in effects}
    candidates: dict[str, dict[str, str]] = {"x6": {}, "x7": {}}
    for name, _, _, separation in effects:
        candidates["x6" if abs(columns[name][5]) > abs(columns[name][6]) else "x7"][name] = separation
    sets: list[tuple[str, ...]] = [(a, b) for a in candidates["x6"] for b in candidates["x7"]]
    for name, (column, separation) in (extra or {}).items():
        columns[name] = np.asarray(column, dtype=float).reshape(17)
        candidates["x6"][name] = separation
        candidates["x7"][name] = separation
        sets.append((name,))
    fits = []
    for terms in sets:
        design = np.hstack([g, np.stack([columns[t][order] for t in terms], axis=1)])
        chi, nu, coef, cov_coef = _gls(w, whiten, design)
        k = len(terms)
        fits.append((terms, tuple(coef[-k:]), tuple(np.sqrt(np.diag(cov_coef))[-k:]), chi, nu))
    best = min(fits, key=lambda f: f[3])
    p_best = chi2_sf(best[3], best[4]) if best[4] > 0 else 1.0
    scale = max(1.0, best[3] / max(best[4], 1)) if p_best < alpha else 1.0
    hypotheses = []
    for terms, size, sigma, chi, nu in sorted(fits, key=lambda f: f[3]):
        p = chi2_sf(chi / scale, nu) if nu > 0 else 1.0
        hypotheses.append(Hypothesis(terms, size, tuple(s * math.sqrt(scale) for s in sigma), chi, nu, p, p >= alpha))
    third = np.abs(v[5:7]) / np.sqrt(np.diag(cov_v)[5:7])
    return ThirdHarmonic((bool(third[0] > 3.0), bool(third[1] > 3.0)), chi0, nu0, tuple(hypotheses), alpha, scale, candidates)


def record_note(
    v: NDArray[np.float64],
    cov_v: NDArray[np.float64],
    site: tuple[float, float],
    alpha: float,
    extra: Mapping[str, tuple[NDArray[np.float64], str]] | None = None,
) -> tuple[str, ...]:
    """Return the note on a record's third harmonic without the K2 estimation (empty when it is not significant).

    ``site``: latitude [rad] and gravity [m/s²].  What ``stableins diagnose`` reports of a system record
    (:func:`stableins.estimators.system.stage.measure_noise_model`).
    """
    from stableins.estimators.system.options import ESTIMATE_K2_PARAMETER

    third = explain_third_harmonic(v, cov_v, site[0], site[1], alpha=alpha, extra=extra)
    text = third.note(estimate_k2=False, parameter=ESTIMATE_K2_PARAMETER)
    return () if text is None else (text,)


__all__ = [
    "THIRD_HARMONIC_EFFECTS",
    "THIRD_HARMONIC_STATES",
    "Hypothesis",
    "ThirdHarmonic",
    "explain_third_harmonic",
    "record_note",
    "signature",
]
