r"""Earth-rate harmonics of the specific-force error: observation, states and solvers.

Derivation (docs/system-calibration.md §1).  On a polar-aligned platform fixed in inertial
space the true specific force is ``f^p/g = u = (cos S cos L, sin S cos L, sin L)`` with the
Earth-rate angle ``S = −s1 α1`` (:func:`stableins.conventions.earth_rate_angle`).  The INS
compensates the raw outputs with its installed calibration; with residuals
``Δ = true − installed``, ``D_i = ΔSF_i/SF_i``, ``b_i = Δδb_i/g`` and ``ΔC`` the residual of
``C_p^a`` (Wu et al. 2018 Eq. 5), the compensated specific force is, to first order,

.. math:: \hat f^p/g = u + \delta,\qquad \delta = -D u + \Delta C\,u + b.

The squared-amplitude observation (Wu et al. 2018 Eq. 20)

.. math:: z = \tfrac12\left(|\hat f^p/g|^2 - 1\right) = u^T\delta + \tfrac12|\delta|^2

is linear in five states, ``z = H x + v`` with (Eq. 27)

.. math:: H = [1,\ \cos S\cos L,\ \sin S\cos L,\ \cos 2S\cos^2 L,\ \sin 2S\cos^2 L]

and

.. math::
    x_1 &= -\tfrac{D_x + D_y}{2}\cos^2 L - D_z \sin^2 L + b_z \sin L\\
    x_2 &= b_x - \Delta\beta_{xy}\sin L + \Delta\beta_{zy}\sin L\\
    x_3 &= b_y + \Delta\beta_{yx}\sin L - \Delta\beta_{zx}\sin L\\
    x_4 &= -\tfrac{D_x - D_y}{2}\\
    x_5 &= \tfrac{\Delta\beta_{xz} - \Delta\beta_{yz}}{2}

(Eqs. 21–25 with the lost leading minus signs of x1, x4 and x5 restored).  The white
accelerometer noise ``n`` adds ``E|n|²/(2g²)`` to ``z``; it is removed from ``x1`` with
the noise variance measured in the data.

Solvers
-------
The state is static, so the Kalman filter, the RTS smoother and batch least squares
give the same final estimate.  :class:`InformationAccumulator` is the chunked
information form ``Λ = P0⁻¹ + Σ HᵀH/R``, ``η = P0⁻¹x0 + Σ Hᵀz/R`` (exact, any prior
including a fully diffuse one); :func:`kalman_filter` runs filterpy's
``KalmanFilter`` (Joseph-form update, symmetrized) sample by sample for convergence
curves; :func:`rts_smooth` applies filterpy's RTS smoother, useful when a process noise
``Q`` (e.g. a slow bias drift) makes the state non-static.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

#: The five harmonic states (Wu et al. 2018 Eqs. 21–25, signs derived in this module).
HARMONIC_STATES = ("x1", "x2", "x3", "x4", "x5")
STATE_MEANING = (
    "mean of the specific-force error along gravity",
    "cos S fundamental: b_x − Δβxy·sinL + Δβzy·sinL",
    "sin S fundamental: b_y + Δβyx·sinL − Δβzx·sinL",
    "cos 2S second harmonic: −(D_x − D_y)/2",
    "sin 2S second harmonic: (Δβxz − Δβyz)/2",
)
#: Third-harmonic states, not in the paper: a residual quadratic coefficient ΔK (output += K u²) adds
#: ``g ΔK_i u_i³`` to z, and ``cos³S = (3 cos S + cos 3S)/4``: x6 = g ΔK_x/4, x7 = −g ΔK_y/4 (H columns
#: ``cos³L cos 3S``, ``cos³L sin 3S``), while x2 gains ``3 cos²L x6``, x3 gains ``−3 cos²L x7`` and x1 gains
#: ``g ΔK_z sin³L``.
THIRD_HARMONIC_NAMES = ("x6", "x7")

#: Order of the residual parameters used by the combination matrices of this package:
#: relative scale-factor residuals D_i = ΔSF_i/SF_i, bias residuals / g, angle residuals [rad].
RESIDUAL_NAMES = ("D_x", "D_y", "D_z", "b_x", "b_y", "b_z", "beta_xy", "beta_xz", "beta_yx", "beta_yz", "beta_zx", "beta_zy")


def harmonic_rows(earth_angle: ArrayLike, latitude: float, order: int = 2) -> NDArray[np.float64]:
    """Rows of ``H`` (Wu et al. 2018 Eq. 27) for Earth-rate angles ``S``, shape ``(n, 5)``.

    ``order=3`` appends the third-harmonic columns ``cos³L (cos 3S, sin 3S)`` (shape ``(n, 7)``).
    """
    s = np.asarray(earth_angle, dtype=float)
    c1, s1 = np.cos(s), np.sin(s)
    rows = _rows_from_trig(c1, s1, np.cos(latitude))
    if order >= 3:
        a3 = np.cos(latitude) ** 3
        rows = np.concatenate([rows, np.stack([a3 * np.cos(3 * s), a3 * np.sin(3 * s)], axis=-1)], axis=-1)
    return rows


def _rows_from_trig(c1: NDArray[np.float64], s1: NDArray[np.float64], cos_lat: float) -> NDArray[np.float64]:
    h = np.empty(c1.shape + (5,))
    h[..., 0] = 1.0
    h[..., 1] = cos_lat * c1
    h[..., 2] = cos_lat * s1
    h[..., 3] = cos_lat**2 * (c1 * c1 - s1 * s1)
    h[..., 4] = cos_lat**2 * (2.0 * c1 * s1)
    return h


def squared_amplitude_observation(specific_force_platform: ArrayLike, gravity: float) -> NDArray[np.float64]:
    r"""``z = ½(|f̂^p|²/g² − 1)`` (Wu et al. 2018 Eq. 20), shape ``(n,)``."""
    f = np.asarray(specific_force_platform, dtype=float)
    return 0.5 * (np.einsum("...i,...i->...", f, f) / gravity**2 - 1.0)


def state_combinations(latitude: float) -> NDArray[np.float64]:
    """Matrix ``(5, 12)`` mapping residuals (:data:`RESIDUAL_NAMES`) to ``x1..x5``."""
    s, c = np.sin(latitude), np.cos(latitude)
    m = np.zeros((5, 12))
    ix = {n: i for i, n in enumerate(RESIDUAL_NAMES)}
    m[0, ix["D_x"]] = m[0, ix["D_y"]] = -0.5 * c * c
    m[0, ix["D_z"]] = -s * s
    m[0, ix["b_z"]] = s
    m[1, ix["b_x"]], m[1, ix["beta_xy"]], m[1, ix["beta_zy"]] = 1.0, -s, s
    m[2, ix["b_y"]], m[2, ix["beta_yx"]], m[2, ix["beta_zx"]] = 1.0, s, -s
    m[3, ix["D_x"]], m[3, ix["D_y"]] = -0.5, 0.5
    m[4, ix["beta_xz"]], m[4, ix["beta_yz"]] = 0.5, -0.5
    return m


def specific_force_error_platform(earth_angle: ArrayLike, latitude: float, residuals: ArrayLike) -> NDArray[np.float64]:
    """First-order ``δ = Δf^p/g`` for residuals (:data:`RESIDUAL_NAMES`), shape ``(n, 3)``.

    Used for reference values and tests; the estimator never needs it.
    """
    from stableins.conventions import INSTALLATION_ENTRIES, dcm_platform_to_accelerometer

    s = np.asarray(earth_angle, dtype=float)
    p = dict(zip(RESIDUAL_NAMES, np.asarray(residuals, dtype=float), strict=True))
    u = np.stack([np.cos(s) * np.cos(latitude), np.sin(s) * np.cos(latitude), np.full_like(s, np.sin(latitude))], axis=-1)
    dc = dcm_platform_to_accelerometer(**{b: p[b] for b in INSTALLATION_ENTRIES}) - np.eye(3)
    d = np.array([p["D_x"], p["D_y"], p["D_z"]])
    b = np.array([p["b_x"], p["b_y"], p["b_z"]])
    return -d * u + u @ dc.T + b


# --------------------------------------------------------------------------- solvers
@dataclass
class InformationAccumulator:
    """Chunked information form of the static linear model ``z = H x + v``.

    Accumulates ``Σ HᵀH``, ``Σ Hᵀz``, ``Σ z²`` and the count over chunks (unit weight;
    the noise variance ``R`` is applied at :meth:`solve`).  Exactly equivalent to the
    Kalman filter and to batch least squares on the same data.
    """

    n_states: int = 5
    information: NDArray[np.float64] = field(init=False)
    projection: NDArray[np.float64] = field(init=False)
    sum_squares: float = field(init=False, default=0.0)
    count: int = field(init=False, default=0)

    def __post_init__(self) -> None:
        self.information = np.zeros((self.n_states, self.n_states))
        self.projection = np.zeros(self.n_states)

    def add(self, h: ArrayLike, z: ArrayLike) -> None:
        """Add a chunk of rows ``h (n, k)`` and observations ``z (n,)``."""
        h = np.asarray(h, dtype=float)
        z = np.asarray(z, dtype=float)
        hz = np.concatenate([h, z[:, None]], axis=1)
        g = hz.T @ hz  # one BLAS call: [HᵀH, Hᵀz; zᵀH, zᵀz]
        k = self.n_states
        self.information += g[:k, :k]
        self.projection += g[:k, k]
        self.sum_squares += float(g[k, k])
        self.count += int(z.size)

    def merge(self, other: InformationAccumulator) -> None:
        """Add another accumulator's sums (information, projection, sum of squares, count)."""
        self.information += other.information
        self.projection += other.projection
        self.sum_squares += other.sum_squares
        self.count += other.count

    def solve(
        self,
        noise_variance: float,
        prior_mean: ArrayLike | None = None,
        prior_covariance: ArrayLike | None = None,
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Posterior mean and covariance.

        ``prior_covariance=None`` is a fully diffuse prior (plain least squares).
        """
        lam = self.information / noise_variance
        eta = self.projection / noise_variance
        if prior_covariance is not None:
            p0_inv = np.linalg.inv(np.asarray(prior_covariance, dtype=float))
            x0 = np.zeros(self.n_states) if prior_mean is None else np.asarray(prior_mean, dtype=float)
            lam = lam + p0_inv
            eta = eta + p0_inv @ x0
        covariance = _symmetric_inverse(lam)
        return covariance @ eta, covariance

    def residual_variance(self, x: ArrayLike) -> float:
        """Mean square residual ``(Σz² − 2xᵀΣHᵀz + xᵀΣHᵀH x)/(n − k)`` of an estimate ``x``."""
        x = np.asarray(x, dtype=float)
        rss = self.sum_squares - 2.0 * x @ self.projection + x @ self.information @ x
        return float(max(rss, 0.0) / max(self.count - self.n_states, 1))


def _symmetric_inverse(matrix: NDArray[np.float64]) -> NDArray[np.float64]:
    """Inverse of a symmetric positive-definite matrix by scaled Cholesky (well conditioned in scaled form)."""
    d = np.sqrt(np.diag(matrix))
    scaled = matrix / np.outer(d, d)
    chol = np.linalg.cholesky(scaled)
    inv_chol = np.linalg.inv(chol)
    inv = inv_chol.T @ inv_chol
    inv = inv / np.outer(d, d)
    return 0.5 * (inv + inv.T)


def regularized_least_squares(
    h: ArrayLike, z: ArrayLike, noise_variance: float, prior_mean: ArrayLike | None = None, prior_covariance: ArrayLike | None = None
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Batch (regularized) least squares by QR of the stacked, whitened system."""
    h = np.asarray(h, dtype=float)
    z = np.asarray(z, dtype=float)
    w = 1.0 / np.sqrt(noise_variance)
    a, y = h * w, z * w
    if prior_covariance is not None:
        chol = np.linalg.cholesky(np.linalg.inv(np.asarray(prior_covariance, dtype=float)))
        x0 = np.zeros(h.shape[1]) if prior_mean is None else np.asarray(prior_mean, dtype=float)
        a = np.vstack([a, chol.T])
        y = np.concatenate([y, chol.T @ x0])
    q, r = np.linalg.qr(a)
    x = np.linalg.solve(r, q.T @ y)
    r_inv = np.linalg.inv(r)
    return x, r_inv @ r_inv.T


@dataclass(frozen=True)
class FilterHistory:
    """Sequential estimates of the Kalman filter (and, optionally, the RTS smoother)."""

    means: NDArray[np.float64]  # (n, k)
    covariances: NDArray[np.float64]  # (n, k, k)
    smoothed_means: NDArray[np.float64] | None = None
    smoothed_covariances: NDArray[np.float64] | None = None


def kalman_filter(
    h: ArrayLike,
    z: ArrayLike,
    noise_variance: ArrayLike,
    prior_mean: ArrayLike,
    prior_covariance: ArrayLike,
    *,
    process_noise: ArrayLike | None = None,
    smooth: bool = False,
) -> FilterHistory:
    """Sequential Kalman filter (``F = I``; Joseph-form update), filterpy's ``KalmanFilter`` step for step.

    The steps are filterpy's ``predict`` and ``update`` (``x = F x``, ``P = F P Fᵀ + Q``; ``y = z − H x``,
    ``S = H P Hᵀ + R``, ``K = P Hᵀ S⁻¹``, ``x = x + K y``, ``P = (I − K H) P (I − K H)ᵀ + K R Kᵀ``; Brown & Hwang,
    *Introduction to Random Signals and Applied Kalman Filtering*, 4th ed., §4.2), the same numpy calls in the same
    order, so the numbers are filterpy's to the last bit; written out here because importing ``filterpy.kalman``
    imports ``scipy.stats`` (through its EKF module), which cost ``calibrate system`` about a second (issue 30).
    The RTS smoother (``smooth``) is filterpy's.

    Parameters
    ----------
    h, z : array_like
        Observation rows ``(n, k)`` and observations ``(n,)``.
    noise_variance : float or array_like (n,)
        ``R`` of each observation.
    prior_mean, prior_covariance : array_like
        ``x0 (k,)`` and ``P0 (k, k)`` (finite; use :class:`InformationAccumulator` for a
        diffuse prior).
    process_noise : array_like (k, k), optional
        ``Q`` per step (default 0: static state).
    smooth : bool
        Also run filterpy's RTS smoother.
    """
    h = np.asarray(h, dtype=float)
    z = np.asarray(z, dtype=float)
    n, k = h.shape
    r = np.broadcast_to(np.asarray(noise_variance, dtype=float), (n,))
    q = np.zeros((k, k)) if process_noise is None else np.asarray(process_noise, dtype=float)
    x = np.asarray(prior_mean, dtype=float).reshape(k, 1).copy()
    p = np.asarray(prior_covariance, dtype=float).copy()
    f = identity = np.eye(k)
    means = np.empty((n, k))
    covs = np.empty((n, k, k))
    r_mat = np.empty((1, 1))
    for i in range(n):
        x = np.dot(f, x)  # predict
        p = np.dot(np.dot(f, p), f.T) + q
        r_mat[0, 0] = r[i]
        row = h[i : i + 1]
        y = z[i : i + 1].reshape(1, 1) - np.dot(row, x)  # update
        pht = np.dot(p, row.T)
        gain = np.dot(pht, np.linalg.inv(np.dot(row, pht) + r_mat))
        x = x + np.dot(gain, y)
        i_kh = identity - np.dot(gain, row)
        p = np.dot(np.dot(i_kh, p), i_kh.T) + np.dot(np.dot(gain, r_mat), gain.T)
        p = 0.5 * (p + p.T)
        means[i] = x[:, 0]
        covs[i] = p
    if not smooth:
        return FilterHistory(means, covs)
    from filterpy.kalman import KalmanFilter

    kf = KalmanFilter(dim_x=k, dim_z=1)
    xs, ps, _, _ = kf.rts_smoother(means[:, :, None], covs, Fs=[np.eye(k)] * n, Qs=[q] * n)
    return FilterHistory(means, covs, xs[:, :, 0], ps)
