r"""The error model of the systematic filter, defined once: states, ``F``, ``Γ``, ``Q`` and ``H`` (docs/systematic-calibration.md).

Continuous model (static base, NED, the damped loop of :class:`stableins.estimators.system.loop.DampingLoop`)::

    ẋ_nav = A x_nav + B_f Δf^n + B_ε ε^n,      Δf^n = C_p^n Δf^p,   ε^n = C_p^n ε^p_eff
    θ̇     = −ε^p_eff                           (the platform's drift angle, platform frame)
    Δf^p  = J_f⁻¹ J_p Δp + n_rw + Σ_τ n_τ + n_white                       (accelerometer residuals and noise)
    ε^p_eff   = ε^p + D_g f^p          (gyro error: drift and g-sensitivity; the platform turns at w = −ε^p_eff,
                                        :func:`stableins.conventions.platform_drift_rate`)

``J_p = ∂f^a/∂p`` and ``J_f = ∂f^a/∂f^p`` are :meth:`stableins.errormodel.ErrorModel.jacobian` and
``jacobian_specific_force`` at the linearization point (the installed calibration, then the estimate), so the
accelerometer part of ``F`` comes from the record's own error model; ``Δp = true − installed``.  ``n_rw`` is the
acceleration random walk, ``n_τ`` the Gauss-Markov processes of the flicker representation
(:data:`stableins.noise.FLICKER_TIME_CONSTANTS`) slower than :data:`FOLD_TIME`, the faster ones are folded into the
white noise (PSD ``2σ_τ²τ`` below their corner).  The parameters are constants (no process noise).

Observations at the end of each filter step (the rows of :func:`observation_rows`)::

    v      = (δv_N, δv_E, δv_D)                                          R = Q²I (quantization)
    ρ̄      = c^ρ_k + θ + (Δ/2) ε^p_eff − J̄_α Δθ_0 − C̄_n^p δ + n_α        (gimbal readings, step mean)
    d      = c^d_k + θ − C_n^p φ                                         (INS attitude with the readings)

``ρ`` is the turn of ``M̂ = Ĉ_b^p(r + θ_inst) C_n^{b,s} E(t)^T``, the platform's inertial attitude from the
readings, since the hold's reference; ``d`` that of the computer's ``P = C_n^{p'} E^T`` with ``C_n^{p'} = Ĉ_b^p
C_n^{b'}`` (the attitude output times the same readings: the angle noise cancels).  Both are sums of step increments
(:class:`stableins.estimators.systematic.observations.TurnSum`), not rotation vectors of products, so that they are
linear in ``θ`` and ``φ`` as written.  ``δ`` is the base error
(``C_n^b = C_n^{b,s}(I − [δ×])``), ``Δθ_0`` the zero-offset residuals, ``c_k`` a constant per hold.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property

import numpy as np
import scipy.linalg
from numpy.typing import NDArray

from stableins.conventions import AXES
from stableins.errormodel import CORE_IDS, GIMBAL_IDS, GYRO_DRIFT_TERMS, GYRO_G_TERMS, ErrorModel
from stableins.estimators.system.loop import LOOP_STATES, DampingLoop
from stableins.noise import FLICKER_TIME_CONSTANTS, FLICKER_VARIANCE_PER_B2
from stableins.terms import CAI_CROSS_COUPLING_IDS, CROSS_COUPLING_TERMS

#: Gauss-Markov processes of the flicker sum faster than this [s] are folded into the white noise.
FOLD_TIME = 999.0
#: The gyro terms: drift ``ε^p`` and g-sensitivity ``Dg_ab`` (:data:`stableins.errormodel.GYRO_G_TERMS`).
GYRO_IDS: tuple[str, ...] = tuple(t.id for t in GYRO_DRIFT_TERMS + GYRO_G_TERMS)
#: Base error ``δ`` (NED rotation vector of the true base relative to the survey) and zero-offset residuals.
BASE_IDS = ("base_north", "base_east", "base_down")
OFFSET_IDS = tuple(f"{g}_residual" for g in GIMBAL_IDS)
#: Nominal scales of the parameter states (the filter works in these units).
_SCALE = {"sf": 1e-6, "bias": 1e-5, "beta": 1e-6, "K2": 1e-7, "Kcc": 1e-7, "gyro": 5e-9, "Dg": 5e-10, "base": 1e-5, "theta": 1e-5}
#: The optional accelerometer terms of the block: the cross-couplings ``Kcc_abc`` (:data:`stableins.terms.CROSS_COUPLING_TERMS`).
CROSS_COUPLING_IDS: tuple[str, ...] = tuple(t.id for t in CROSS_COUPLING_TERMS)


def accelerometer_ids(error_model: ErrorModel, *, cross_coupling: bool = False) -> tuple[str, ...]:
    """Return the accelerometer residuals the filter estimates: the core ids, then the cross-couplings in library order.

    The cross-couplings are those the record's error model holds (a record calibrated with ``--add Kcc_xxy``), and
    with ``cross_coupling`` also Cai et al. 2016's six (:data:`stableins.terms.CAI_CROSS_COUPLING_IDS`).
    """
    wanted = {i for i in error_model.ids if i in CROSS_COUPLING_IDS} | (set(CAI_CROSS_COUPLING_IDS) if cross_coupling else set())
    return CORE_IDS + tuple(i for i in CROSS_COUPLING_IDS if i in wanted)


#: Units of the loop states (:data:`LOOP_STATES`: rad, m/s, rad, m, m/s, m/s²) and of ``θ`` [rad] in the filter.
_DYNAMIC_SCALE = np.array([1e-5, 1e-5, 1e-5, 1e-3, 1e-3, 1e-7, 1.0, 1e-3, 1e-5, 1e-6, 1e-6, 1e-6])
#: Unit of the slow accelerometer noise states [m/s²].
_NOISE_SCALE = 1e-5


def _scale_of(name: str) -> float:
    for prefix, value in (("Dg_", "Dg"), ("gyro_drift", "gyro"), ("base_", "base"), ("theta", "theta")):
        if name.startswith(prefix):
            return _SCALE[value]
    return _SCALE[name.split("_")[0]]


@dataclass(frozen=True)
class StateLayout:
    """Names and positions of the filter states.

    Order: the loop states (:data:`LOOP_STATES`), the drift angle ``θ`` (3), the slow accelerometer noise (random walk
    3, Gauss-Markov 3 per kept correlation time), the accelerometer residuals (:attr:`accelerometer_ids`), the gyro terms
    (:data:`GYRO_IDS`), the base error and zero-offset residuals, then per hold ``c^ρ_k`` and ``c^d_k``.

    Attributes
    ----------
    holds : int
        Number of holds ``K``.
    slow_times : tuple of float
        Correlation times [s] of the Gauss-Markov states.
    random_walk : bool
        Whether the random walk has states.
    accelerometer_ids : tuple of str
        The accelerometer residuals (:func:`accelerometer_ids`): the core ids, then any cross-couplings.  The one
        place the block's terms are named: the Jacobians, priors, rank groups and the record update follow it.
    """

    holds: int
    slow_times: tuple[float, ...]
    random_walk: bool = True
    accelerometer_ids: tuple[str, ...] = CORE_IDS

    def __post_init__(self) -> None:
        core, extra = self.accelerometer_ids[: len(CORE_IDS)], self.accelerometer_ids[len(CORE_IDS) :]
        if core != CORE_IDS or not set(extra) <= set(CROSS_COUPLING_IDS):
            raise ValueError(f"the accelerometer block is the core ids then cross-couplings, not {self.accelerometer_ids}")

    @property
    def turns(self) -> int:
        """Number of turns (``holds − 1``), each with a torquing-error state ``k_j`` (3)."""
        return max(self.holds - 1, 0)

    @cached_property
    def names(self) -> tuple[str, ...]:
        """State names, in order."""
        noise = [f"rw_{a}" for a in AXES] if self.random_walk else []
        noise += [f"gm{int(t)}_{a}" for t in self.slow_times for a in AXES]
        holds = [f"c_rho{k}_{a}" for k in range(self.holds) for a in AXES] + [f"c_att{k}_{a}" for k in range(self.holds) for a in AXES]
        holds = [f"turn{j}_{a}" for j in range(self.turns) for a in AXES] + holds
        theta = [f"theta_{a}" for a in AXES]
        return (*LOOP_STATES, *theta, *noise, *self.accelerometer_ids, *GYRO_IDS, *BASE_IDS, *OFFSET_IDS, *holds)

    @property
    def size(self) -> int:
        """Number of states."""
        return len(self.names)

    @property
    def dynamic(self) -> slice:
        """Loop states and ``θ``."""
        return slice(0, 12)

    @property
    def noise(self) -> slice:
        """Slow-noise states."""
        return slice(12, 12 + 3 * (int(self.random_walk) + len(self.slow_times)))

    @property
    def accelerometer(self) -> slice:
        """Accelerometer residuals (:attr:`accelerometer_ids`)."""
        start = self.noise.stop
        return slice(start, start + len(self.accelerometer_ids))

    @property
    def gyro(self) -> slice:
        """Gyro drift and g-sensitivity."""
        start = self.accelerometer.stop
        return slice(start, start + len(GYRO_IDS))

    @property
    def base(self) -> slice:
        """Base error ``δ``."""
        return slice(self.gyro.stop, self.gyro.stop + 3)

    @property
    def offsets(self) -> slice:
        """Zero-offset residuals."""
        return slice(self.base.stop, self.base.stop + 3)

    @property
    def turn_errors(self) -> slice:
        """Torquing errors ``k_j`` (3 per turn, platform frame, per radian turned)."""
        return slice(self.offsets.stop, self.offsets.stop + 3 * self.turns)

    def turn_error(self, turn: int) -> slice:
        """``e_j``."""
        return slice(self.offsets.stop + 3 * turn, self.offsets.stop + 3 * turn + 3)

    def hold_constant(self, kind: str, hold: int) -> slice:
        """``c^ρ_k`` (``kind="rho"``) or ``c^d_k`` (``"att"``)."""
        start = self.turn_errors.stop + (0 if kind == "rho" else 3 * self.holds) + 3 * hold
        return slice(start, start + 3)

    @property
    def parameters(self) -> slice:
        """Everything constant (no process noise): residuals, gyro terms, nuisances, hold constants."""
        return slice(self.accelerometer.start, self.size)

    def scales(self) -> NDArray[np.float64]:
        """Return (a copy of) the unit of each state."""
        return self._scales.copy()

    @cached_property
    def _scales(self) -> NDArray[np.float64]:
        """Return the unit of each state (:data:`_DYNAMIC_SCALE`, :data:`_SCALE`): the filter works near unit variances."""
        out = np.full(self.size, _NOISE_SCALE)
        out[:12] = _DYNAMIC_SCALE
        for k, name in enumerate(self.names[self.accelerometer.start : self.offsets.stop]):
            out[self.accelerometer.start + k] = _scale_of(name)
        out[self.offsets.stop :] = _SCALE["theta"]
        return out


def slow_noise_times() -> tuple[float, ...]:
    """Correlation times of the Gauss-Markov states (those of the flicker sum slower than :data:`FOLD_TIME`)."""
    return tuple(t for t in FLICKER_TIME_CONSTANTS if t > FOLD_TIME)


def white_density(white: NDArray[np.float64], bias_instability: NDArray[np.float64]) -> NDArray[np.float64]:
    """Per-axis white PSD [(m/s²)²/Hz]: ``N²`` plus ``2σ_τ²τ`` of every folded Gauss-Markov process."""
    folded = sum(2.0 * t for t in FLICKER_TIME_CONSTANTS if t <= FOLD_TIME)
    return np.asarray(white, dtype=float) ** 2 + folded * FLICKER_VARIANCE_PER_B2 * np.asarray(bias_instability, dtype=float) ** 2


def dynamic_matrix(loop: DampingLoop) -> NDArray[np.float64]:
    """``A_s`` (12×12): the loop's ``A`` for the nine loop states, zero for ``θ``."""
    a = np.zeros((12, 12))
    a[:9, :9] = loop.state_matrix()
    return a


def input_matrix() -> NDArray[np.float64]:
    """``B_in`` (12×9) for the inputs ``(Δf^n, ε^n, θ̇)``: ``δv̇ += Δf^n``, ``φ̇ −= ε^n``, ``θ̇ = θ̇``."""
    b = np.zeros((12, 9))
    b[3, 0] = b[4, 1] = b[7, 2] = 1.0
    b[0, 3] = b[1, 4] = b[2, 5] = -1.0
    b[9:12, 6:9] = np.eye(3)
    return b


def input_map(
    nav_to_platform: NDArray[np.float64],
    accelerometer: NDArray[np.float64],
    specific_force: NDArray[np.float64],
    turn_rates: NDArray[np.float64],
    noise_columns: int,
) -> NDArray[np.float64]:
    """``U(t)`` (n, 9, m): inputs ``(Δf^n, ε^n, θ̇)`` per unit of ``[accelerometer residuals, gyro terms, torquing, slow noise]``.

    Parameters
    ----------
    nav_to_platform : ndarray (n, 3, 3)
        ``C_n^p`` at the substeps.
    accelerometer : ndarray (n, 3, a)
        ``J_f⁻¹ J_p``: platform specific-force error per residual (the layout's accelerometer block).
    specific_force : ndarray (n, 3)
        ``f^p``.
    turn_rates : ndarray (n, T)
        ``|ω_cmd|`` of each turn [rad/s] (zero outside it): the torquing error ``k_j`` (platform frame, per radian
        turned) turns the platform at ``|ω_cmd| k_j`` like a drift ``ε = −|ω_cmd| k_j``.
    noise_columns : int
        Slow-noise states (3 per process); each adds ``C_p^n`` to ``Δf^n``.
    """
    n, turns, accel = len(nav_to_platform), turn_rates.shape[1], accelerometer.shape[2]
    to_nav = nav_to_platform.swapaxes(1, 2)
    gyro = accel + 12 + 3 * turns
    out = np.zeros((n, 9, gyro + noise_columns))
    out[:, 0:3, 0:accel] = to_nav @ accelerometer
    eps = np.zeros((n, 3, 12 + 3 * turns))  # ε_eff per gyro term and torquing error
    eps[:, :, 0:3] = np.eye(3)
    for a in range(3):
        eps[:, a, 3 + 3 * a : 6 + 3 * a] = specific_force
    for j in range(turns):
        eps[:, :, 12 + 3 * j : 15 + 3 * j] = -turn_rates[:, j, None, None] * np.eye(3)
    out[:, 3:6, accel:gyro] = to_nav @ eps
    out[:, 6:9, accel:gyro] = -eps
    for k in range(noise_columns // 3):
        out[:, 0:3, gyro + 3 * k : gyro + 3 + 3 * k] = to_nav
    return out


@dataclass(frozen=True)
class Discretization:
    """The constant pieces of one filter step of ``Δ = m h`` (``A_s`` is time-invariant on a static base).

    Attributes
    ----------
    step : float
        ``Δ`` [s].
    substeps : int
        ``m``.
    transition : ndarray (12, 12)
        ``Φ_s = e^{A_s Δ}``.
    weights : ndarray (m, 12, 9)
        ``e^{A_s(Δ − (j+1)h)} ∫_0^h e^{A_s r} dr B_in``: the step's response to inputs held over substep ``j``.
    white : ndarray (3, 3, 12, 12)
        ``∫_0^Δ e^{A_s s} B_f E_ab B_fᵀ e^{A_sᵀ s} ds`` for the symmetric unit matrices ``E_ab``.
    """

    step: float
    substeps: int
    transition: NDArray[np.float64]
    weights: NDArray[np.float64]
    white: NDArray[np.float64]

    @classmethod
    def of(cls, loop: DampingLoop, step: float, substeps: int) -> Discretization:
        """Compute the pieces for ``loop`` (Van Loan 1978 for the white-noise integrals)."""
        a, b = dynamic_matrix(loop), input_matrix()
        h = step / substeps
        block = np.zeros((24, 24))
        block[:12, :12], block[:12, 12:] = a, np.eye(12)
        integral = scipy.linalg.expm(block * h)[:12, 12:]  # ∫_0^h e^{A r} dr
        weights = np.stack([scipy.linalg.expm(a * (step - (j + 1) * h)) @ integral @ b for j in range(substeps)])
        white = np.zeros((3, 3, 12, 12))
        for i in range(3):
            for j in range(i, 3):
                unit = np.zeros((3, 3))
                unit[i, j] = unit[j, i] = 1.0
                white[i, j] = white[j, i] = _van_loan(a, b[:, 0:3] @ unit @ b[:, 0:3].T, step)
        return cls(step, substeps, scipy.linalg.expm(a * step), weights, white)

    def white_covariance(self, density_nav: NDArray[np.float64]) -> NDArray[np.float64]:
        """``Q`` of the dynamic states for an n-frame white PSD matrix ``S`` (3×3): ``Σ_ab S_ab Q_ab``."""
        return np.einsum("ab,abij->ij", np.triu(density_nav), self.white)


def _van_loan(a: NDArray[np.float64], qc: NDArray[np.float64], step: float) -> NDArray[np.float64]:
    """``∫_0^Δ e^{As} Q_c e^{Aᵀs} ds`` (Van Loan 1978)."""
    n = len(a)
    block = np.zeros((2 * n, 2 * n))
    block[:n, :n], block[:n, n:], block[n:, n:] = -a, qc, a.T
    e = scipy.linalg.expm(block * step)
    phi = e[n:, n:].T
    return 0.5 * (phi @ e[:n, n:] + (phi @ e[:n, n:]).T)


def step_matrices(
    disc: Discretization,
    layout: StateLayout,
    inputs: NDArray[np.float64],
    decay_steps: NDArray[np.float64],
) -> NDArray[np.float64]:
    """``F_k`` (s, n, n) for ``s`` steps from the input maps ``U`` at their substeps (s, m, 9, a + 12 + 3T + noise).

    ``decay_steps`` (m, noise) is ``e^{−(j+½)h/τ}`` per substep and noise column (1 for the random walk), so a
    Gauss-Markov state's decay inside the step enters its forcing.
    """
    s = inputs.shape[0]
    n = layout.size
    scales = layout.scales()
    out = np.zeros((s, n, n))
    out[:, :12, :12] = disc.transition
    params = layout.gyro.stop - layout.accelerometer.start  # accelerometer residuals and gyro terms
    gyro = params + 3 * layout.turns
    out[:, :12, layout.accelerometer.start : layout.gyro.stop] = np.einsum("jab,sjbc->sac", disc.weights, inputs[:, :, :, :params])
    out[:, :12, layout.turn_errors] = np.einsum("jab,sjbc->sac", disc.weights, inputs[:, :, :, params:gyro])
    noise = inputs[:, :, :, gyro:] * decay_steps[None, :, None, :]
    out[:, :12, layout.noise] = np.einsum("jab,sjbc->sac", disc.weights, noise)
    k = layout.noise.start
    if layout.random_walk:
        out[:, k : k + 3, k : k + 3] = np.eye(3)
        k += 3
    for tau in layout.slow_times:
        out[:, k : k + 3, k : k + 3] = np.exp(-disc.step / tau) * np.eye(3)
        k += 3
    idx = np.arange(layout.parameters.start, n)
    out[:, idx, idx] = 1.0
    return out * (scales[None, None, :] / scales[None, :, None])  # in state units


def noise_covariance(
    disc: Discretization, layout: StateLayout, density_nav: NDArray[np.float64], slow: tuple[NDArray[np.float64], NDArray[np.float64]]
) -> NDArray[np.float64]:
    """``Q_k`` (n, n): white noise of the dynamic states and the driving noise of the slow-noise states.

    ``slow = (K, σ_τ)``: per-axis random-walk density [m/s²/√s] and Gauss-Markov standard deviations (per kept τ, 3).
    """
    q = np.zeros((layout.size, layout.size))
    q[:12, :12] = disc.white_covariance(density_nav)
    k = layout.noise.start
    walk, sigmas = slow
    if layout.random_walk:
        q[range(k, k + 3), range(k, k + 3)] = np.asarray(walk, dtype=float) ** 2 * disc.step
        k += 3
    for tau, sigma in zip(layout.slow_times, sigmas, strict=True):
        q[range(k, k + 3), range(k, k + 3)] = np.asarray(sigma, dtype=float) ** 2 * (1.0 - np.exp(-2.0 * disc.step / tau))
        k += 3
    scales = layout.scales()
    return q / np.outer(scales, scales)  # in state units


@dataclass(frozen=True)
class StepGeometry:
    """What one filter step's observations need (means over its substeps, values at its end).

    Attributes
    ----------
    hold : int
        Index of the hold the step lies in, −1 in a turn (no attitude observations).
    nav_to_platform_end : ndarray (3, 3)
        ``Ĉ_n^p`` at the step's end.
    nav_to_platform_mean : ndarray (3, 3)
        Mean ``Ĉ_n^p`` over the step.
    offset_map_mean : ndarray (3, 3)
        Mean ``J_α`` (columns: rotation of the platform per radian of each gimbal angle).
    specific_force_mean : ndarray (3,)
        Mean ``f^p``.
    offset_map_end : ndarray (3, 3)
        ``J_α`` at the step's end.
    """

    hold: int
    nav_to_platform_end: NDArray[np.float64]
    nav_to_platform_mean: NDArray[np.float64]
    offset_map_mean: NDArray[np.float64]
    specific_force_mean: NDArray[np.float64]
    offset_map_end: NDArray[np.float64]


def observation_rows(layout: StateLayout, geometry: StepGeometry, step: float) -> NDArray[np.float64]:
    """``H`` (12, n) for ``(v, ρ̄, d, ψ)`` (module docstring); only the first three rows apply in a turn."""
    scales = layout.scales()
    h = np.zeros((12, layout.size))
    h[0, 3] = h[1, 4] = h[2, 7] = 1.0
    if geometry.hold < 0:
        return h * scales
    theta = slice(9, 12)
    h[3:6, layout.hold_constant("rho", geometry.hold)] = np.eye(3)
    h[3:6, theta] = np.eye(3)
    eps = np.zeros((3, 12))
    eps[:, :3] = np.eye(3)
    for a in range(3):
        eps[a, 3 + 3 * a : 6 + 3 * a] = geometry.specific_force_mean
    h[3:6, layout.gyro] = 0.5 * step * eps
    h[3:6, layout.offsets] = -geometry.offset_map_mean
    h[3:6, layout.base] = -geometry.nav_to_platform_mean
    h[6:9, layout.hold_constant("att", geometry.hold)] = np.eye(3)
    h[6:9, theta] = np.eye(3)
    h[6:9, 0:3] = -geometry.nav_to_platform_end
    h[9:12, 0:3] = np.eye(3)
    h[9:12, layout.offsets] = -geometry.nav_to_platform_end.T @ geometry.offset_map_end
    h[9:12, layout.base] = -np.eye(3)
    return h * scales


def parameter_ids(layout: StateLayout) -> tuple[str, ...]:
    """Ids of the accelerometer and gyro parameters (the record's terms)."""
    return layout.names[layout.accelerometer.start : layout.gyro.stop]


def noise_decay(layout: StateLayout, disc: Discretization) -> NDArray[np.float64]:
    """``e^{−(j+½)h/τ}`` (m, noise columns): 1 for the random walk."""
    h = disc.step / disc.substeps
    mid = (np.arange(disc.substeps) + 0.5) * h
    taus: Sequence[float] = ([np.inf] if layout.random_walk else []) + list(layout.slow_times)
    columns = [np.exp(-mid / t) for t in taus for _ in range(3)]
    return np.stack(columns, axis=1) if columns else np.zeros((disc.substeps, 0))
