r"""Device-level coarse calibration: 15 parameters from 18 static positions, exact kinematics.

Observation (Wu et al. 2018 Eq. 7, signs restored; conventions in
:mod:`stableins.conventions`), position ``j``, dwell mean ``ȳ_j`` of the
accelerometer outputs and mean angle-sensor readings ``r_j``::

    ȳ_j = h(p, θ; r_j) + v_j,      h = F(f^p_j, p),
    f^p_j = C_b^p(r_j + θ) · C_n^b · [0, 0, −g]

``F`` is the exact forward model of :class:`stableins.errormodel.ErrorModel` (Eq. 6;
the coarse model leaves out the quadratic terms unless asked), ``C_b^p`` the exact gimbal
chain ``R3(s1 α1) R1(s2 α2) R2(s3 α3) R3(s4 q)``, ``θ = (θ10, θ20, θ30)`` the
angle-sensor zero offsets, and ``v_j`` the dwell-mean noise with the 1σ measured in
the dwell (:mod:`stableins.estimators.dwell`).  No small-angle table is used: the
solution is Gauss-Newton on the exact model (:mod:`stableins.estimators.gauss_newton`),
which converges in 3–4 steps from the ideal instrument.

Jacobian
--------
``∂h/∂p`` (scale factors, biases, installation angles) is
:meth:`ErrorModel.jacobian`; the offsets act through the specific force,
``∂h/∂θ_i = (∂F/∂f^p) · ∂f^p/∂α_i`` with (``R_i'(a) = −[e_i×] R_i(a)``)::

    ∂f^p/∂α1 = −s1 [e3×] f^p
    ∂f^p/∂α2 = −s2 A [e1×] Aᵀ f^p                      A = R3(s1 α1)
    ∂f^p/∂α3 = −s3 A B [e2×] Bᵀ Aᵀ f^p                 B = R1(s2 α2)

Gauge
-----
A rotation of the platform about ``z_p`` is indistinguishable from turning the triad
about ``z_p``: for any ``φ`` the model family is closed under
``C_p^a → C_p^a R3(φ)`` (see :func:`gauge_equivalent`), so the design has an exact
null direction that moves ``θ10``, ``β_xz``, ``β_yz`` (and, at second order,
``sf_x``, ``sf_y``, ``β_xy``, ``β_yx``, ``β_zx``, ``β_zy``).  It is found from the
SVD of the design (:mod:`stableins.estimators.design`), and the gauge
``θ10 = 0`` is applied: the platform-axis sensor zero defines the platform azimuth.
The estimates of ``β_xz`` and ``β_yz`` then determine ``β_xz + s1 θ10`` and
``β_yz + s1 θ10``.  ``θ30`` is determined relative to the base pitch given in the
site metadata (a base tilt about the middle-gimbal axis is the same rotation).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from stableins.conventions import (
    STANDARD_GRAVITY,
    GimbalConfiguration,
    dcm_nav_to_body,
)
from stableins.errormodel import ErrorModel, Term
from stableins.errors import InputError, NotDeterminedError
from stableins.estimators.design import DesignAnalysis, Gauge, choose_gauge
from stableins.estimators.details import CoarseDetails, UsedDwell
from stableins.estimators.device_gauge import GAUGE_PREFERENCE, final_design, gauge_preference, held_terms_note, hold_and_gauge
from stableins.estimators.device_settings import DeviceFitSettings
from stableins.estimators.dwell import DwellSummary, describe_left_out, screen_dwells, slow_covariance
from stableins.estimators.gauss_newton import GaussNewtonSolution, convergence_warning, gauss_newton, goodness_of_fit_warning
from stableins.estimators.leastsquares import dwell_forward
from stableins.estimators.orientation import check_orientation
from stableins.estimators.result import FitResult, Stage
from stableins.estimators.sensitivity import angle_reading_sensitivity
from stableins.estimators.setting import DeviceSetting


def coarse_model(*, nonlinear: bool = False, extra_terms: Sequence[Term] = ()) -> ErrorModel:
    """Return the coarse model: 12 linear terms + 3 zero offsets (+ ``K2_*`` when ``nonlinear``, + ``extra_terms``)."""
    return ErrorModel.standard(nonlinear=nonlinear, gimbals=True) + tuple(extra_terms)


@dataclass(frozen=True)
class CoarseProblem:
    """Batched coarse observations (trial axis ``T``, ``m`` positions).

    Attributes
    ----------
    readings : ndarray (T, m, 3)
        Mean angle-sensor readings [rad].
    means : ndarray (T, m, 3)
        Dwell-mean accelerometer outputs [m/s²].
    sigma : ndarray (T, m, 3)
        1σ of the dwell means [m/s²].
    gravity : float or ndarray (T,)
        Local gravity [m/s²].
    base_dcm : ndarray (3, 3)
        ``C_n^b`` of the base.
    configuration : GimbalConfiguration
    model : ErrorModel
    """

    readings: NDArray[np.float64]
    means: NDArray[np.float64]
    sigma: NDArray[np.float64]
    gravity: float | NDArray[np.float64]
    base_dcm: NDArray[np.float64]
    configuration: GimbalConfiguration
    model: ErrorModel

    @classmethod
    def from_dwells(
        cls,
        dwells: Sequence[DwellSummary],
        gravity: float,
        base_dcm: NDArray[np.float64],
        configuration: GimbalConfiguration,
        model: ErrorModel,
        *,
        slow_covariance: NDArray[np.float64] | None = None,
    ) -> CoarseProblem:
        """One trial from dwell summaries: measured readings, means and their 1σ."""
        return cls(
            readings=np.array([d.angles for d in dwells])[None],
            means=np.array([d.mean for d in dwells])[None],
            sigma=np.array([d.sem for d in dwells])[None],
            gravity=float(gravity),
            base_dcm=np.asarray(base_dcm, dtype=float),
            configuration=configuration,
            model=model,
            slow_covariance=slow_covariance,
        )

    def predict(self, x: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Return the model outputs ``(T, m, 3)`` and Jacobian ``(T, m, 3, n)`` at parameters ``x (T, n)``.

        The dwell forward model, :func:`stableins.estimators.leastsquares.dwell_forward`.
        """
        model = self.model
        values = {k: x[..., i, None] for i, k in enumerate(model.ids)}
        g = np.asarray(self.gravity, dtype=float)
        g = g[..., None] if g.ndim else g
        forward = dwell_forward(model, values, self.readings, g, base_dcm=self.base_dcm, configuration=self.configuration)
        return forward.output, forward.jacobian

    #: Optional covariance of the dwell means beyond their white 1σ, ``(T, 3, m, m)`` per axis
    #: (:func:`stableins.estimators.dwell.slow_covariance`).
    slow_covariance: NDArray[np.float64] | None = None

    def whitening(self) -> NDArray[np.float64] | None:
        """``L⁻¹`` per trial and axis ``(T, 3, m, m)`` with ``L Lᵀ = diag(σ_a²) + C_slow,a``."""
        if self.slow_covariance is None:
            return None
        sig2 = np.moveaxis(self.sigma, -1, 1) ** 2  # (T, 3, m)
        cov = self.slow_covariance + sig2[..., None] * np.eye(sig2.shape[-1])
        chol = np.linalg.cholesky(cov)
        return np.linalg.inv(chol)

    def weighted(self, x: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Return whitened residuals and Jacobian ``L⁻¹ r``, ``L⁻¹ H`` (``L Lᵀ`` the covariance of the dwell means)."""
        out, jac = self.predict(x)
        t = x.shape[0]
        w = self.whitening()
        if w is None:
            r = ((self.means - out) / self.sigma).reshape(t, -1)
            a = (jac / self.sigma[..., None]).reshape(t, -1, jac.shape[-1])
            return r, a
        resid = np.moveaxis(self.means - out, -1, 1)  # (T, 3, m)
        r = np.einsum("tamk,tak->tam", w, resid)
        a = np.einsum("tamk,tkan->tamn", w, jac)
        return np.moveaxis(r, 1, 2).reshape(t, -1), np.moveaxis(a, 1, 2).reshape(t, -1, jac.shape[-1])


def solve_coarse(
    problem: CoarseProblem,
    fixed: Mapping[str, float] | None = None,
    x0: NDArray[np.float64] | None = None,
    max_iterations: int = 12,
):
    """Batched Gauss-Newton for the coarse problem; ``fixed`` maps gauge ids to values.

    Returns a :class:`~stableins.estimators.gauss_newton.GaussNewtonSolution`.
    """
    model = problem.model
    fixed = {"theta10": 0.0} if fixed is None else dict(fixed)
    t = problem.means.shape[0]
    if x0 is None:
        x0 = np.broadcast_to(model.vector({}), (t, len(model))).copy()
    for k, v in fixed.items():
        x0[..., model.index(k)] = v
    free = np.array([k not in fixed for k in model.ids])
    scales = np.array([term.nominal for term in model])
    return gauss_newton(problem.weighted, x0, free, scales, max_iterations=max_iterations)


def calibrate_coarse(
    dwells: Sequence[DwellSummary],
    *,
    setting: DeviceSetting,
    expected_positions: Sequence[int] | None = None,
    allow_missing: bool = False,
    nonlinear: bool = False,
    orientation_tolerance: float = 0.02 * STANDARD_GRAVITY,
    prior: Mapping[str, float] | None = None,
    source: str = "data",
) -> FitResult:
    """Coarse stage: fit the 15 parameters to one pass of dwell summaries.

    Parameters
    ----------
    dwells : sequence of DwellSummary
        One pass (one dwell per position).
    setting : DeviceSetting
        Gravity, base attitude and gimbal senses of the unit, its noise model (None: white noise measured in each
        dwell only) and the additive ``extra_terms`` estimated with the standard ones (discovered effects, e.g.
        the library's ``Kcc_xxy``; regressors of the specific force); an extra term that these positions do not
        determine is held at its ``prior`` value with status ``unidentifiable``.
    expected_positions : sequence of int, optional
        Positions the procedure defines; a missing one raises :class:`InputError`
        unless ``allow_missing``.
    nonlinear : bool
        Also estimate ``K2_*`` (the paper ignores them in this stage).
    orientation_tolerance : float
        Largest allowed difference between a dwell mean and the ideal output [m/s²].
    prior : mapping, optional
        Prior values of ``extra_terms`` [SI] (default: their reference, 0).

    Returns
    -------
    FitResult
        Stage ``"coarse"``, with gauge ``θ10 = 0`` (status ``gauge``).
    """
    gravity, base_attitude, configuration, noise = setting.gravity, setting.base_attitude, setting.configuration, setting.noise
    base_dcm = dcm_nav_to_body(*base_attitude)
    model = coarse_model(nonlinear=nonlinear, extra_terms=setting.extra_terms)
    extra_ids = tuple(t.id for t in setting.extra_terms)
    usable, left_out, notes = _usable_dwells(
        dwells,
        setting,
        base_dcm,
        n=len(model),
        expected_positions=expected_positions,
        allow_missing=allow_missing,
        orientation_tolerance=orientation_tolerance,
        source=source,
    )
    slow = slow_covariance(usable, noise, source)
    problem = CoarseProblem.from_dwells(
        usable, gravity, base_dcm, configuration, model, slow_covariance=None if slow is None else slow[None]
    )
    if noise is not None:
        notes.append(noise.describe())
    scales = np.array([t.nominal for t in model])
    start_values = {i: float((prior or {}).get(i, model[i].reference)) for i in extra_ids}
    x_start = model.vector(start_values)[None]
    start, gauge, held = _start_gauge(problem, x_start, scales, extra_ids, left_out=left_out, source=source)
    standard_gauge = gauge.fixed
    fixed = {g: 0.0 for g in standard_gauge} | {h: start_values[h] for h in held}
    solution = solve_coarse(problem, fixed, x0=x_start.copy())
    design = final_design(solution.weighted_jacobian[0], model, scales, tuple(held))
    if design.deficiency == len(fixed):
        gauge = choose_gauge(design, gauge_preference(tuple(held)), scales)
    notes.extend(_setting_notes(held, start_values, model, left_out, standard_gauge=standard_gauge, start=start, nonlinear=nonlinear))
    residuals, residual_sigma, labels = _residuals(problem, solution.x, usable)
    notes.extend(quality_notes(solution, design, residuals / residual_sigma, labels))
    return FitResult.from_solution(
        Stage.COARSE,
        model.terms,
        solution,
        design,
        details=_details(
            gauge,
            design,
            usable,
            base_attitude,
            configuration,
            held={h: start_values[h] for h in held},
            gauge_values={g: 0.0 for g in standard_gauge},
            left_out={int(k): v for k, v in sorted(left_out.items())},
        ),
        residuals=residuals,
        residual_sigma=residual_sigma,
        residual_labels=labels,
        determined=gauge.describe() + tuple(f"{g} = 0 by gauge" for g in standard_gauge),
        notes=tuple(notes),
        gravity=float(gravity),
        whitened_residuals=None if problem.slow_covariance is None else solution.weighted_residuals[0].copy(),
        settings=DeviceFitSettings(Stage.COARSE, noise, nonlinear=bool(nonlinear)),
        sensitivities=(angle_reading_sensitivity(problem, solution.x[0], model.ids),),
    )


def _usable_dwells(
    dwells: Sequence[DwellSummary],
    setting: DeviceSetting,
    base_dcm: NDArray[np.float64],
    *,
    n: int,
    expected_positions: Sequence[int] | None,
    allow_missing: bool,
    orientation_tolerance: float,
    source: str,
) -> tuple[list[DwellSummary], dict[int, str], list[str]]:
    """Return the dwells a coarse fit of ``n`` parameters uses (sorted by position), those it leaves out and why, and its notes.

    Raises
    ------
    InputError
        Too few usable positions for ``n`` parameters.
    """
    usable, left_out, notes = screen_dwells(dwells, expected_positions, allow_missing=allow_missing, source=source)
    left_out.update(
        check_orientation(usable, setting.gravity, base_dcm, setting.configuration, tolerance=orientation_tolerance, source=source)
    )
    usable = sorted((d for d in usable if d.position not in left_out), key=lambda d: d.position)
    if 3 * len(usable) <= n:
        raise InputError(
            f"only {len(usable)} usable positions; the coarse stage needs more than {n // 3}. Left out: {describe_left_out(left_out)}",
            path=source,
            field="position",
        )
    return usable, left_out, notes


def _details(
    gauge: Gauge,
    design: DesignAnalysis,
    usable: Sequence[DwellSummary],
    base_attitude: Sequence[float],
    configuration: GimbalConfiguration,
    *,
    held: Mapping[str, float],
    gauge_values: Mapping[str, float],
    left_out: Mapping[int, str],
) -> CoarseDetails:
    """Return what the coarse fit worked with beyond its parameters: the dwells it used and left out, what it held and gauged."""
    return CoarseDetails(
        positions_used=tuple(UsedDwell(d.stage, d.pass_number, d.position) for d in usable),
        left_out=left_out,
        gauge_values=gauge_values,
        held=held,
        gauge_coefficients=gauge.coefficients,
        base_attitude=tuple(float(a) for a in base_attitude),
        gimbal_senses=tuple(configuration.senses),
        weak=tuple(design.weak),
        angles={d.position: d.angles.tolist() for d in usable},
    )


def _setting_notes(
    held: Mapping[str, Sequence[str]],
    start_values: Mapping[str, float],
    model: ErrorModel,
    left_out: Mapping[int, str],
    *,
    standard_gauge: Sequence[str],
    start: DesignAnalysis,
    nonlinear: bool,
) -> list[str]:
    """Return the notes of a coarse fit on its gauge, what it held, what it ignored and which positions it left out."""
    notes = []
    for g in standard_gauge:
        moved = ", ".join(start.involved()[0])
        notes.append(f"gauge: {g} held at 0 ({model[g].meaning}); the design cannot see it (null direction moves {moved})")
    if held:
        notes.append(held_terms_note(held, start_values, model, "coarse"))
    notes.append("theta30 is relative to the base pitch given in the site metadata (a base tilt about East is the same rotation)")
    if not nonlinear:
        notes.append("K2 (quadratic nonlinearity) ignored in the coarse stage (Wu et al. Eq. 7); estimated in the fine stage")
    for p, why in sorted(left_out.items()):
        notes.append(f"position {p} left out: {why}")
    return notes


def _residuals(
    problem: CoarseProblem, x: NDArray[np.float64], usable: Sequence[DwellSummary]
) -> tuple[NDArray[np.float64], NDArray[np.float64], tuple[str, ...]]:
    """Residuals of the dwell means at ``x``, their 1σ (white and, if any, slow noise) and their labels."""
    residuals = (problem.means[0] - problem.predict(x)[0][0]).reshape(-1)
    variance = problem.sigma[0] ** 2
    if problem.slow_covariance is not None:
        variance = variance + np.diagonal(problem.slow_covariance[0], axis1=-2, axis2=-1).T
    residual_sigma = np.sqrt(variance).reshape(-1)
    labels = tuple(f"pos {d.position} f_{ax}" for d in usable for ax in "xyz")
    return residuals, residual_sigma, labels


def _start_gauge(
    problem: CoarseProblem,
    x_start: NDArray[np.float64],
    scales: NDArray[np.float64],
    extra_ids: tuple[str, ...],
    *,
    left_out: Mapping[int, str],
    source: str,
) -> tuple[DesignAnalysis, Gauge, dict[str, tuple[str, ...]]]:
    """Return the design at the starting point, the gauge its null space decides, and the extra terms it holds.

    Raises
    ------
    InputError
        The usable positions leave more than the ``θ10`` gauge undetermined.
    """
    model = problem.model
    _, a_start = problem.weighted(x_start)
    start, gauge, held = hold_and_gauge(a_start[0], model, scales, extra_ids, GAUGE_PREFERENCE)
    if any(g not in GAUGE_PREFERENCE for g in gauge.fixed) or start.deficiency > 1:
        raise NotDeterminedError(
            f"the usable positions do not determine the parameters: null directions involve {start.involved()} "
            f"(left out: {describe_left_out(left_out)})",
            path=source,
            field="position",
            expected="the 18 positions of the procedure (only theta10 may be a gauge)",
        )
    return start, gauge, held


def quality_notes(
    solution: GaussNewtonSolution, design: DesignAnalysis, normalized: NDArray[np.float64], labels: tuple[str, ...]
) -> list[str]:
    """Return the notes of a device fit on its convergence, its goodness of fit and its weakly determined parameters."""
    notes = []
    chi2_whitened = float(solution.weighted_residuals[0] @ solution.weighted_residuals[0])
    if (stalled := convergence_warning(solution)) is not None:
        notes.append(stalled)
    warning = goodness_of_fit_warning(chi2_whitened, normalized.size - design.rank, normalized, labels)
    if warning is not None:
        notes.append(warning)
    if design.weak:
        notes.append(f"warning: weakly determined (1σ above the typical magnitude): {', '.join(design.weak)}")
    return notes
