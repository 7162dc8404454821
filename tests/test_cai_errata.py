"""Cai et al. 2016 errata the docs state (docs/discovery.md, "Cai et al. 2016: what we use and errata"), measured.

* Eq. 8, the iterative compensation as printed, ``f⁽ⁿ⁾ = f⁽ⁿ⁻¹⁾ − K_a2 (f⁽ⁿ⁻¹⁾)² − K_cross (f⁽ⁿ⁻¹⁾)_cross``, subtracts the
  nonlinear term again at every step: it has no fixed point but ``K(f) = 0`` and runs away; the fixed point of Eq. 6
  needs the linear value as the base, ``f⁽ⁿ⁾ = f⁽⁰⁾ − K(f⁽ⁿ⁻¹⁾)``.
* Eq. 12's printed size-effect matrix contradicts Eqs. 9–11 (and the centripetal acceleration ``ω × (ω × r)``).
* RTS smoothing cannot improve parameters modelled as constants (Eq. 21): the smoothed value at every time equals
  the filter's final value.
"""

import numpy as np

from stableins.conventions import STANDARD_GRAVITY

G = STANDARD_GRAVITY
MICRO_G_PER_G2 = 1e-6 * G / G**2


def _nonlinear(f, k2, kcross):
    """Cai Eq. 6's nonlinear part ``K_a2 f⁽²⁾ + K_cross f⁽cross⁾`` (K_cross rows: x: xy, xz; y: yx, yz; z: zx, zy)."""
    squares = k2 * f**2
    x, y, z = f
    cross = np.array([kcross[0] * x * y + kcross[1] * x * z, kcross[2] * y * x + kcross[3] * y * z, kcross[4] * z * x + kcross[5] * z * y])
    return squares + cross


def test_eq8_as_printed_runs_away_and_the_corrected_iteration_converges():
    k2 = np.full(3, 300 * MICRO_G_PER_G2)  # Cai's simulated 300 µg/g²
    kcross = np.full(6, 300 * MICRO_G_PER_G2)
    truth = np.array([0.3, -0.5, -9.7])
    linear = truth + _nonlinear(truth, k2, kcross)  # Eq. 7: what the linear compensation gives (forward Eq. 4 inverted)
    printed, corrected = linear.copy(), linear.copy()
    history = []
    for _ in range(200):
        printed = printed - _nonlinear(printed, k2, kcross)  # Eq. 8 as printed
        corrected = linear - _nonlinear(corrected, k2, kcross)  # the base is f⁽⁰⁾
        history.append(np.linalg.norm(printed - truth))
    assert np.linalg.norm(corrected - truth) < 1e-12 * G
    # each printed step subtracts ≈ K f² again: the error grows linearly, ~2.8e-3 m/s² (290 µg) per step here
    assert history[-1] > 150 * history[0] and history[-1] > 0.5
    step = np.diff(history[:50])
    assert np.all(step > 0.9 * step[0])


def test_eq12_printed_size_effect_matrix_contradicts_eqs_9_to_11():
    omega, r = np.array([0.0, 0.0, 0.1]), np.array([0.04, 0.02, 0.03])  # a rotation about z, offsets along each axis
    wx2, wy2, wz2 = omega**2
    centripetal = np.cross(omega, np.cross(omega, r))  # acceleration of a point at r in the rotating frame
    eqs_9_11 = -np.array([(wy2 + wz2) * r[0], (wx2 + wz2) * r[1], (wx2 + wy2) * r[2]])  # each along its own axis
    printed = np.array([[0, wy2, wz2], [wx2, 0, wz2], [wx2, wy2, 0]]) @ r
    corrected = np.diag([wy2 + wz2, wx2 + wz2, wx2 + wy2]) @ r
    assert np.allclose(eqs_9_11, centripetal * np.array([1, 1, 0]) + np.array([0, 0, eqs_9_11[2]]))
    assert np.allclose(eqs_9_11, -corrected)  # Eq. 12 with the diagonal matrix (F29's) and Eq. 9's sign
    assert not np.allclose(printed, corrected) and not np.allclose(-printed, eqs_9_11)
    assert np.isclose(printed[0], wz2 * r[2])  # the x row reads the z offset: a_x from r_z, not r_x


def test_rts_smoothing_leaves_constant_parameters_at_the_final_filtered_value():
    """A navigation-like state (random walk driven by a constant bias) and the bias as a constant parameter (Eq. 21)."""
    from filterpy.kalman import KalmanFilter

    rng = np.random.default_rng(17)
    dt, n = 1.0, 150
    kf = KalmanFilter(dim_x=3, dim_z=1)
    kf.F = np.array([[1.0, dt, 0.5 * dt**2], [0.0, 1.0, dt], [0.0, 0.0, 1.0]])  # position, velocity, constant acceleration bias
    kf.Q = np.diag([0.0, 1e-4, 0.0])  # process noise on the velocity, none on the parameter
    kf.H = np.array([[1.0, 0.0, 0.0]])
    kf.R = np.array([[0.5**2]])
    kf.P = np.diag([1.0, 1.0, 1e-2])
    truth = np.array([0.0, 0.0, 0.02])
    means, covariances = [], []
    for _ in range(n):
        truth = kf.F @ truth + np.array([0.0, rng.normal(0.0, 1e-2), 0.0])
        kf.predict()
        kf.update(truth[0] + rng.normal(0.0, 0.5))
        means.append(kf.x.copy())
        covariances.append(kf.P.copy())
    smoothed, smoothed_cov, _, _ = kf.rts_smoother(np.array(means), np.array(covariances))
    final = means[-1][2]
    assert np.allclose(smoothed[:, 2], final, rtol=1e-9, atol=1e-12 * abs(final))
    assert np.allclose(smoothed_cov[:, 2, 2], covariances[-1][2, 2], rtol=1e-9)
    assert abs(means[n // 2][2] - final) > 1e-3 * abs(final)  # the filter's own history does change: smoothing fills it in
