"""Frozen fit results shared by every estimator (model / fitter / result separation).

A fitter returns a :class:`FitResult`: parameters with 1σ from a covariance built on
noise measured in the data, residuals, χ²_ν, rank, singular values and null space of
the design, and the status of every parameter.  Results print a report and plot
themselves; records and reports are built from them.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
from numpy.typing import NDArray

from stableins.documents import JSONObject
from stableins.errormodel import Term
from stableins.estimators.details import DeviceDetails, StageDetails
from stableins.status import STATUSES, Status

if TYPE_CHECKING:  # pragma: no cover
    from matplotlib.figure import Figure

    from stableins.estimators.design import DesignAnalysis
    from stableins.estimators.gauss_newton import GaussNewtonSolution

#: Relative eigenvalue below which a direction of a (correlation-scaled) information matrix counts as not determined.
INFORMATION_RTOL = 1e-9
#: A parameter is determined by the data alone when its share in every direction they do not determine is below this
#: (correlation-scaled).  The fine stage's null directions (the β sums) carry sf at 3e-4 through the nonlinear model:
#: the scale factors count as determined alone, as they are to that order.
ALONE_LOADING = 1e-2


@dataclass(frozen=True, eq=False)
class Likelihood:
    r"""What a stage's data say about the parameters, in canonical Gaussian form (linearized).

    .. math::
        \log L(x) = g^T (x - \hat x) - \tfrac12 (x - \hat x)^T \Lambda (x - \hat x) + \text{const}

    For weighted residuals :math:`r = W(y - h(x))` and Jacobian :math:`A = W\,\partial h/\partial x` at
    :math:`\hat x`: :math:`\Lambda = A^T A` (the Fisher information) and :math:`g = A^T r` (zero on the
    free parameters of a converged least-squares fit).  ``Λ`` may be singular: its null space is what the
    data do not determine (e.g. θ10 at device level, the β sums in the fine stage).  A stage that updates
    a prior record hands this over; :func:`stableins.estimators.posterior.bayesian_update` combines it with
    the prior.  Units are SI (``Λ`` in 1/(unit_i unit_j)).

    Attributes
    ----------
    ids : tuple of str
        Parameter ids, in the order of the arrays.
    point : ndarray (n,)
        Linearization point :math:`\hat x` [SI].
    information : ndarray (n, n)
        :math:`\Lambda`.
    gradient : ndarray (n,)
        :math:`g`.
    """

    ids: tuple[str, ...]
    point: NDArray[np.float64]
    information: NDArray[np.float64]
    gradient: NDArray[np.float64]

    def __post_init__(self) -> None:
        n = len(self.ids)
        for name, shape in (("point", (n,)), ("information", (n, n)), ("gradient", (n,))):
            array = np.array(getattr(self, name), dtype=float)
            if array.shape != shape:
                raise ValueError(f"Likelihood: {name} has shape {array.shape}, expected {shape}")
            if not np.all(np.isfinite(array)):
                raise ValueError(f"Likelihood: {name} is not finite")
            if name == "information":
                array = 0.5 * (array + array.T)
            array.setflags(write=False)
            object.__setattr__(self, name, array)
        if len(set(self.ids)) != n:
            raise ValueError("Likelihood: an id appears twice")

    @classmethod
    def from_weighted(
        cls, ids: Sequence[str], point: NDArray[np.float64], jacobian: NDArray[np.float64], residuals: NDArray[np.float64]
    ) -> Likelihood:
        """From whitened residuals ``r = W(y − h(x̂))`` and Jacobian ``A = W ∂h/∂x`` at ``x̂``."""
        a = np.asarray(jacobian, dtype=float)
        return cls(tuple(ids), np.asarray(point, dtype=float), a.T @ a, a.T @ np.asarray(residuals, dtype=float))

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Likelihood):
            return NotImplemented
        return self.ids == other.ids and all(
            np.array_equal(getattr(self, k), getattr(other, k)) for k in ("point", "information", "gradient")
        )

    __hash__ = None  # type: ignore[assignment]

    def index(self, parameter_id: str) -> int:
        """Return the position of ``parameter_id`` in :attr:`ids`."""
        return self.ids.index(parameter_id)

    def conditioned(self, held: dict[str, float]) -> Likelihood:
        """Return the likelihood of the other parameters with ``held`` ids fixed at the given values."""
        keep = [k for k, i in enumerate(self.ids) if i not in held]
        fixed = [k for k, i in enumerate(self.ids) if i in held]
        if not fixed:
            return self
        shift = np.array([held[self.ids[k]] for k in fixed]) - self.point[fixed]
        gradient = self.gradient[keep] - self.information[np.ix_(keep, fixed)] @ shift
        return Likelihood(tuple(self.ids[k] for k in keep), self.point[keep], self.information[np.ix_(keep, keep)], gradient)

    def seen(self) -> NDArray[np.bool_]:
        """Which parameters the data see at all (a non-zero column of the information)."""
        scale = np.sqrt(np.clip(np.diag(self.information), 0.0, None))
        return scale > 0.0

    def _scaled(self) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """``(d, Λ_s, null)``: column scale, correlation-scaled information, orthonormal basis of its null space."""
        d = np.sqrt(np.clip(np.diag(self.information), 0.0, None))
        inv = np.where(d > 0, 1.0 / np.where(d > 0, d, 1.0), 0.0)
        scaled = self.information * np.outer(inv, inv)
        eigenvalues, vectors = np.linalg.eigh(scaled)
        top = max(float(eigenvalues.max(initial=0.0)), 1e-300)
        null = vectors[:, eigenvalues <= INFORMATION_RTOL * top]
        return d, scaled, null

    def estimable(self) -> NDArray[np.bool_]:
        """Which parameters the data determine by themselves (unit vector in the row space of ``Λ``, to :data:`ALONE_LOADING`)."""
        d, _, null = self._scaled()
        loading = np.linalg.norm(null, axis=1) if null.size else np.zeros(len(self.ids))
        return (d > 0) & (loading < ALONE_LOADING)

    def rank(self) -> int:
        """Return the number of independent combinations the data determine."""
        return len(self.ids) - self._scaled()[2].shape[1]

    def data_only(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """``(value, σ)`` of each parameter from these data alone; NaN where not :meth:`estimable`.

        Estimable functions do not depend on the generalized inverse used: ``x̂ + Λ⁺ g`` and ``diag Λ⁺``.
        """
        d, scaled, _ = self._scaled()
        inv = np.where(d > 0, 1.0 / np.where(d > 0, d, 1.0), 0.0)
        pinv = np.linalg.pinv(scaled, rcond=INFORMATION_RTOL, hermitian=True) * np.outer(inv, inv)
        values = self.point + pinv @ self.gradient
        sigma = np.sqrt(np.clip(np.diag(pinv), 0.0, None))
        ok = self.estimable()
        return np.where(ok, values, np.nan), np.where(ok, sigma, np.nan)


@dataclass(frozen=True, eq=False)
class InputSensitivity:
    r"""How a stage's data-only result depends on an input the stage takes as known (a GUM Type B input).

    A stage enters a record through the information vector :math:`\eta = \Lambda\hat x + g` of its
    :class:`Likelihood`; the record's values are :math:`x = P \sum_k \eta_k` (the Bayesian updates in
    information form, :mod:`stableins.estimators.posterior`), so an error :math:`\delta q` of an input moves
    them by :math:`P \sum_k (\partial\eta_k/\partial q)\,\delta q` (docs/reports.md, "Uncertainty budget").

    Attributes
    ----------
    input : str
        ``<group>.<name>``: ``gyro_drift.x``, ``damping_loop.zeta``, ``angle_sensors.readings`` ...
    unit : str
        SI unit of the input (``rad/s``, ``1``, ``rad``).
    ids : tuple of str
        Parameters of the stage's likelihood, in the order of the arrays.
    value : float
        The value of the input the stage used.
    gradient : ndarray (n,) or None
        :math:`\partial\eta/\partial q` per unit of the input.
    covariance : ndarray (n, n) or None
        For a set of independent inputs of one kind with unit variance each (the angle reading of every
        dwell): :math:`\sum_j (\partial\eta/\partial q_j)(\partial\eta/\partial q_j)^T`.
    step : float
        The perturbation of a sensitivity computed by re-running the stage (0: derived analytically).
    """

    input: str
    unit: str
    ids: tuple[str, ...]
    value: float = 0.0
    gradient: NDArray[np.float64] | None = None
    covariance: NDArray[np.float64] | None = None
    step: float = 0.0

    def __post_init__(self) -> None:
        n = len(self.ids)
        if (self.gradient is None) == (self.covariance is None):
            raise ValueError("InputSensitivity: give either a gradient or a covariance")
        for name, shape in (("gradient", (n,)), ("covariance", (n, n))):
            value = getattr(self, name)
            if value is None:
                continue
            array = np.array(value, dtype=float)
            if array.shape != shape or not np.all(np.isfinite(array)):
                raise ValueError(f"InputSensitivity {self.input}: {name} must be finite with shape {shape}")
            array.setflags(write=False)
            object.__setattr__(self, name, array)

    @property
    def group(self) -> str:
        """The budget column the input belongs to (``gyro_drift``, ``damping_loop`` ...)."""
        return self.input.partition(".")[0]

    def to_json(self) -> JSONObject:
        """Return the JSON form stored in a calibration record (arrays as lists)."""
        out: JSONObject = {"input": self.input, "unit": self.unit, "ids": list(self.ids), "value": float(self.value)}
        if self.gradient is not None:
            out["gradient"] = self.gradient.tolist()
        if self.covariance is not None:
            out["covariance"] = self.covariance.tolist()
        out["step"] = float(self.step)
        return out


class Stage(StrEnum):
    """Which fit a :class:`FitResult` is: a stage of a calibration, or one of discovery's refits.

    A member is its string (``Stage.SYSTEM == "system"``): records, reports and JSON documents keep the names
    they always wrote, and a record's stage run read back compares equal to the member.
    """

    COARSE = "coarse"
    FINE = "fine"
    #: The device calibration: the coarse passes and the fine stage fused by joint GLS (:mod:`stableins.estimators.joint`).
    DEVICE = "coarse+fine"
    SYSTEM = "system"
    #: The system stage's fifteen combined coefficients (``x1..x5``, pitch and roll).
    SYSTEM_COMBINED = "system-combined"
    DRIFT = "drift"
    GYRO = "gyro"
    LEVER = "lever"
    SYSTEMATIC = "systematic"
    THERMAL = "thermal"
    POSES = "poses"
    #: Discovery's refit of device dwells (:class:`stableins.discovery.problem.DwellProblem`), of all of them ...
    DEVICE_DWELLS = "device dwells"
    #: ... of one device stage's dwells ...
    COARSE_DWELLS = "coarse dwells"
    FINE_DWELLS = "fine dwells"
    #: ... of a system record's bins, of the gimbal-reading slopes, or of a linear problem.
    SYSTEM_BINS = "system bins"
    READING_SLOPES = "reading slopes"
    LINEAR = "linear"


class StageSettings(Protocol):
    """What a stage ran with: a frozen value of the stage's own settings class that writes itself as JSON.

    Each stage has its class (:class:`stableins.estimators.device_settings.DeviceFitSettings`,
    :class:`~stableins.estimators.system.settings.SystemSettings`, :class:`~stableins.estimators.lever.model.LeverOptions`
    ...); a record stores :meth:`to_document` and reads it back with the class's ``from_document``
    (:func:`stableins.records.settings.settings_from_document`).
    """

    def to_document(self) -> JSONObject:
        """Return the settings as a record stores them (docs/formats.md, "Stage settings")."""
        ...


@dataclass(frozen=True)
class FitResult:
    """Outcome of one estimation stage.

    Attributes
    ----------
    stage : Stage
        Which fit this is (a string is converted: ``"coarse"``, ``"fine"``, ``"system"`` ...).
    terms : tuple of Term
        Parameters in vector order (ids, units, meaning).
    values : ndarray (n,)
        Estimates [SI].  For ``gauge`` parameters the gauge value; for
        ``unidentifiable`` parameters the prior value carried through (never a fit).
    covariance : ndarray (n, n)
        Absolute covariance [SI²], from noise measured in the data (not scaled by χ²_ν).
    status : tuple of Status
        One of :class:`stableins.status.Status` per parameter (strings are converted).
    residuals : ndarray (m,)
        Weighted-fit residuals (observed − model) [SI of the observation].
    residual_sigma : ndarray (m,)
        1σ of each observation, from the noise measured in the data.
    residual_labels : tuple of str
        What each residual is, e.g. ``"pos 3 f_y"``.
    rank : int
        Numerical rank of the (weighted) design.
    singular_values : ndarray
        Singular values of the column-scaled weighted design.
    null_space : ndarray (n, k)
        Unit vectors spanning the design's null space (in parameter space).
    determined : tuple of str
        Human-readable combinations that the data do determine (when rank-deficient).
    notes : tuple of str
        Gauges applied, positions left out and why, warnings.
    iterations : int
        Gauss–Newton iterations the fit took (0: linear or not iterated).
    gravity : float or None
        Local gravity the fit used [m/s²].
    combinations : mapping of str to (float, float)
        Value and 1σ of combinations the data determine when their terms are not all determined (the fine
        stage's installation-angle combinations) [SI].
    details : StageDetails or None
        Stage-specific typed details: a device fit's :class:`DeviceDetails` (the dwells it used and left out, what it
        held and gauged; :class:`CoarseDetails` for the coarse stage), :class:`SystemDetails`, :class:`CombinedDetails`,
        or the other stages' and the discovery problem's own.
    whitened_residuals : ndarray (m,) or None
        ``L⁻¹ (observed − model)`` with ``L Lᵀ`` the full covariance of the observations,
        when it is not diagonal (correlated noise).  Then :attr:`chi2` is the exact
        ``rᵀ R⁻¹ r`` (``‖L⁻¹ r‖²``) rather than the diagonal approximation
        ``Σ (r_i/σ_i)²``.  None: the observations are independent.
    likelihood : Likelihood or None
        What the stage's data say about its parameters (canonical form), for a Bayesian update of a
        prior record (:meth:`stableins.records.CalibrationRecord.updated`).
    settings : StageSettings or None
        The options the stage ran with (the stage's own frozen settings: noise model, estimate K2, gyro drift ...),
        so a record and a report can say, and recompute with, exactly what the calibration used; None: the fit
        states none (discovery's refits).
    sensitivities : tuple of InputSensitivity
        How the stage's likelihood depends on the inputs it takes as known (angle readings, gyro drift,
        damping loop): the Type B part of a certificate's uncertainty budget.
    """

    stage: Stage
    terms: tuple[Term, ...]
    values: NDArray[np.float64]
    covariance: NDArray[np.float64]
    status: tuple[str, ...]
    residuals: NDArray[np.float64]
    residual_sigma: NDArray[np.float64]
    residual_labels: tuple[str, ...] = ()
    rank: int = 0
    singular_values: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))
    null_space: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 0)))
    determined: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()
    iterations: int = 0
    gravity: float | None = None
    combinations: Mapping[str, tuple[float, float]] = field(default_factory=dict)
    details: StageDetails | None = None
    whitened_residuals: NDArray[np.float64] | None = None
    likelihood: Likelihood | None = None
    settings: StageSettings | None = None
    sensitivities: tuple[InputSensitivity, ...] = ()

    def __post_init__(self) -> None:
        n = len(self.terms)
        if self.values.shape != (n,) or self.covariance.shape != (n, n) or len(self.status) != n:
            raise ValueError("FitResult: values, covariance and status must match the terms")
        bad = set(self.status) - set(STATUSES)
        if bad:
            raise ValueError(f"FitResult: unknown status {sorted(bad)}")
        object.__setattr__(self, "stage", Stage(self.stage))
        object.__setattr__(self, "status", tuple(Status(s) for s in self.status))
        object.__setattr__(self, "combinations", dict(self.combinations))
        if self.whitened_residuals is not None and self.whitened_residuals.shape != self.residuals.shape:
            raise ValueError("FitResult: whitened_residuals must match residuals")
        for name in ("values", "covariance", "residuals", "residual_sigma", "singular_values", "null_space", "whitened_residuals"):
            if getattr(self, name) is not None:
                getattr(self, name).setflags(write=False)

    @classmethod
    def from_solution(
        cls,
        stage: Stage,
        terms: tuple[Term, ...],
        solution: GaussNewtonSolution,
        design: DesignAnalysis,
        *,
        details: DeviceDetails,
        residuals: NDArray[np.float64],
        residual_sigma: NDArray[np.float64],
        residual_labels: tuple[str, ...] = (),
        determined: tuple[str, ...] = (),
        notes: tuple[str, ...] = (),
        gravity: float | None = None,
        whitened_residuals: NDArray[np.float64] | None = None,
        settings: StageSettings | None = None,
        sensitivities: tuple[InputSensitivity, ...] = (),
    ) -> FitResult:
        """Return the result of a device fit solved by :func:`stableins.estimators.gauss_newton.gauss_newton`.

        Values, covariance, iterations and the likelihood come from the first batch member of ``solution``;
        rank, singular values and null space from ``design``.  A parameter in ``details.held`` has status
        ``unidentifiable``, one in ``details.gauge_values`` ``gauge``, every other ``estimated``.  The keyword arguments
        after them are the stage's own fields of :class:`FitResult` (residuals, labels, notes, settings ...),
        each as the class documents it.
        """
        ids = tuple(t.id for t in terms)
        held, gauged = details.held, details.gauge_values
        status = tuple(Status.UNIDENTIFIABLE if k in held else Status.GAUGE if k in gauged else Status.ESTIMATED for k in ids)
        return cls(
            stage=stage,
            terms=terms,
            values=solution.x[0].copy(),
            covariance=solution.covariance[0].copy(),
            status=status,
            rank=design.rank,
            singular_values=design.singular_values,
            null_space=design.null_space,
            iterations=solution.iterations,
            likelihood=Likelihood.from_weighted(ids, solution.x[0], solution.weighted_jacobian[0], solution.weighted_residuals[0]),
            residuals=residuals,
            residual_sigma=residual_sigma,
            residual_labels=residual_labels,
            determined=determined,
            notes=notes,
            gravity=gravity,
            details=details,
            whitened_residuals=whitened_residuals,
            settings=settings,
            sensitivities=sensitivities,
        )

    # ----------------------------------------------------------------- access
    @property
    def ids(self) -> tuple[str, ...]:
        """Parameter ids, in vector order."""
        return tuple(t.id for t in self.terms)

    def positions(self, stage: str | None = None) -> frozenset[int]:
        """Positions of the dwells a device fit used (of one ``stage``, ``"coarse"`` or ``"fine"``, when given); none for other fits.

        Read from the fit's :class:`DeviceDetails`.
        """
        return self.details.positions(stage) if isinstance(self.details, DeviceDetails) else frozenset()

    @property
    def sigma(self) -> NDArray[np.float64]:
        """1σ of every parameter [SI] (square root of the covariance diagonal)."""
        return np.sqrt(np.clip(np.diag(self.covariance), 0.0, None))

    @property
    def chi2(self) -> float:
        """``rᵀ R⁻¹ r``: exact with :attr:`whitened_residuals`, else ``Σ (r_i/σ_i)²``."""
        if self.whitened_residuals is not None:
            return float(self.whitened_residuals @ self.whitened_residuals)
        r = self.residuals / self.residual_sigma
        return float(r @ r)

    @property
    def dof(self) -> int:
        """Residual degrees of freedom ``m − rank``."""
        return int(self.residuals.size - self.rank)

    @property
    def chi2_red(self) -> float:
        """χ²_ν = χ² / (m − rank); expected 1 ± sqrt(2/ν)."""
        return self.chi2 / self.dof if self.dof > 0 else float("nan")

    def correlation(self) -> NDArray[np.float64]:
        """Return the correlation matrix of the parameters (0 where a σ is 0)."""
        s = self.sigma
        with np.errstate(invalid="ignore", divide="ignore"):
            c = self.covariance / np.outer(s, s)
        return np.where(np.outer(s, s) > 0, c, 0.0)

    def __getitem__(self, term_id: str) -> tuple[float, float, str]:
        """``(value, sigma, status)`` of one parameter [SI]."""
        k = self.ids.index(term_id)
        return float(self.values[k]), float(self.sigma[k]), self.status[k]

    def as_dict(self) -> dict[str, float]:
        """Return ``{id: value}`` of every parameter [SI]."""
        return dict(zip(self.ids, map(float, self.values), strict=True))

    # ----------------------------------------------------------------- report
    def rows(self) -> list[tuple[str, float, float, str, Status]]:
        """``(id, value, 1σ, unit, status)`` of every parameter in engineering units (report, repr, HTML, DataFrame)."""
        return [
            (t.id, float(t.to_engineering(v)), float(t.sigma_to_engineering(s)), t.unit, Status(st))
            for t, v, s, st in zip(self.terms, self.values, self.sigma, self.status, strict=True)
        ]

    def _fit_line(self) -> str:
        if self.dof <= 0:
            return f"no residual degrees of freedom (m = {self.residuals.size}); rank {self.rank} of {len(self.terms)}"
        spread = np.sqrt(2 / max(self.dof, 1))
        return f"χ²_ν = {self.chi2_red:.3f} (ν = {self.dof}, expected 1 ± {spread:.2f}); rank {self.rank} of {len(self.terms)}"

    def fit_warning(self) -> str | None:
        """Return a warning when χ²_ν lies above the upper end of its 95 % interval for noise alone (χ² distribution of ν).

        The same interval as the certificate's evidence of fit and its fit check (:mod:`stableins.reporting.tolerances`).
        """
        if self.dof <= 0 or not np.isfinite(self.chi2_red):
            return None
        from stableins.estimators.distributions import chi2_ppf

        high = chi2_ppf(0.975, self.dof) / self.dof
        if self.chi2_red <= high:
            return None
        return (
            f"warning: χ²_ν = {self.chi2_red:.3f} is above {high:.3f}, the upper end of its 95 % interval for noise alone "
            f"(ν = {self.dof}): effects outside the model, or a noise model too small; the σ may understate the errors"
        )

    def report(self) -> str:
        """Plain-text report in engineering units."""
        lines = [
            f"stage: {self.stage}",
            f"chi2_red = {self.chi2_red:.3f} (nu = {self.dof}, expected 1 ± {np.sqrt(2 / max(self.dof, 1)):.2f})",
            f"rank = {self.rank} of {len(self.terms)}",
            "",
        ]
        warning = self.fit_warning()
        if warning:
            lines.insert(2, warning)
        from stableins.display import parameter_table

        return "\n".join(lines + parameter_table(self.rows(), self.determined, self.notes))

    def __str__(self) -> str:
        return self.report()

    def __repr__(self) -> str:
        from stableins.display import clipped, parameter_lines, plural, status_counts

        lines = [f"<FitResult: stage '{self.stage}', {len(self.terms)} parameters ({status_counts(self.status)})>", self._fit_line()]
        warning = self.fit_warning()
        lines += [warning] if warning else []
        lines += parameter_lines(self.rows())
        more = f"{plural(len(self.notes), 'note')}; " if self.notes else ""
        return clipped(lines, f"({more}print(result) for the full report, result.to_dataframe() for the table)")

    def _repr_html_(self) -> str:
        from stableins.display import html_result, parameter_html

        return html_result(
            f"FitResult: stage '{self.stage}', {len(self.terms)} parameters",
            [self._fit_line(), self.fit_warning() or ""],
            [parameter_html(self.rows(), [t.meaning for t in self.terms])],
            [("determined combinations", self.determined), ("notes", self.notes)],
        )

    def to_dataframe(self) -> Any:
        """Return the parameter table as a :class:`pandas.DataFrame` indexed by parameter id.

        Columns ``value``, ``sigma``, ``unit`` (engineering), ``status``, ``value_si``, ``sigma_si``, ``si_unit``,
        ``meaning``; an ``unidentifiable`` parameter has no value (NaN: what a result carries there is only the prior).
        Needs pandas (``pip install stableins[pandas]``).
        """
        from stableins.display import require_pandas

        pandas = require_pandas()
        records = []
        for (pid, value, sigma, unit, status), t, v, s in zip(self.rows(), self.terms, self.values, self.sigma, strict=True):
            hidden = status == Status.UNIDENTIFIABLE
            nan = float("nan")
            records.append(
                {
                    "parameter": pid,
                    "value": nan if hidden else value,
                    "sigma": nan if hidden else sigma,
                    "unit": unit,
                    "status": str(status),
                    "value_si": nan if hidden else float(v),
                    "sigma_si": nan if hidden else float(s),
                    "si_unit": t.si_unit,
                    "meaning": t.meaning,
                }
            )
        return pandas.DataFrame.from_records(records, index="parameter")

    def plot(self, ax: Any = None) -> Figure:
        """Plot the normalized residuals (residual / 1σ) per observation with ±1 bands."""
        import matplotlib.pyplot as plt

        fig = ax.figure if ax is not None else plt.figure(figsize=(10, 4))
        ax = ax if ax is not None else fig.add_subplot(111)
        k = np.arange(self.residuals.size)
        ax.errorbar(k, self.residuals / self.residual_sigma, yerr=1.0, fmt="o", ms=3, lw=0.8)
        ax.axhline(0.0, color="k", lw=0.6)
        ax.set_xlabel("observation")
        ax.set_ylabel("residual / 1σ")
        ax.set_title(rf"{self.stage}: $\chi^2_\nu$ = {self.chi2_red:.2f}")
        if self.residual_labels and len(self.residual_labels) <= 60:
            ax.set_xticks(k, self.residual_labels, rotation=90, fontsize=6)
        fig.tight_layout()
        return fig
