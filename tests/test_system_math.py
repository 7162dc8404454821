"""Math of the system-level stage: states, attitude coefficients, loop, solvers, separation.

These tests check the derivations against independent routes (exact error model, exact
gimbal kinematics, time-domain loop simulation, finite differences) on synthetic signals.
"""

import numpy as np
import pytest

from stableins import conventions as cv
from stableins.errormodel import ErrorModel
from stableins.estimators.system import harmonics as hm
from stableins.estimators.system.assembly import residuals_from_parameters
from stableins.estimators.system.attitude import AttitudeDrift, AttitudeModel, attitude_combinations, fit_attitude
from stableins.estimators.system.blocks import BlockHarmonics, harmonic_information, observation
from stableins.estimators.system.loop import DampingLoop
from stableins.estimators.system.separation import COMBINED_COEFFICIENTS, combination_matrix, separate

LAT = np.radians(40.0)
G = float(cv.normal_gravity(LAT))


def random_parameters(rng, size=1e-4):
    a = cv.ARCSEC
    true = {f"sf_{x}": 1.0 + rng.normal(0, size) for x in "xyz"}
    true |= {f"bias_{x}": rng.normal(0, size * G) for x in "xyz"}
    true |= {b: rng.normal(0, 10 * a) for b in ("beta_xy", "beta_xz", "beta_yx", "beta_yz", "beta_zx", "beta_zy")}
    return true


def platform_force(s, lat=LAT):
    return G * np.stack([np.cos(s) * np.cos(lat), np.sin(s) * np.cos(lat), np.full_like(s, np.sin(lat))], axis=-1)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_states_reproduce_exact_squared_amplitude(seed):
    """z from the exact forward/inverse error model equals H·x(residuals) up to second order (|δ|²/2)."""
    rng = np.random.default_rng(seed)
    true, installed = random_parameters(rng), random_parameters(rng)
    model = ErrorModel.standard(nonlinear=False)
    s = np.linspace(0, 2 * np.pi, 500)
    f_p = platform_force(s)
    compensated = model.inverse(model.forward(f_p, true), installed)
    z = hm.squared_amplitude_observation(compensated, G)
    x = hm.state_combinations(LAT) @ residuals_from_parameters(true, installed, G)
    delta = np.linalg.norm(compensated - f_p, axis=1) / G
    assert np.abs(z - hm.harmonic_rows(s, LAT) @ x).max() < 2.0 * delta.max() ** 2 + 1e-12
    assert np.abs(x).max() > 1e-5  # the test has signal


def test_attitude_coefficients_from_gimbal_kinematics():
    """Quasi-static pitch/roll coefficients equal the n-frame error through C_p^n of the exact gimbal chain."""
    rng = np.random.default_rng(5)
    p = rng.normal(0, 1e-4, 12)
    s = np.linspace(0, 2 * np.pi, 720, endpoint=False)
    d = hm.specific_force_error_platform(s, LAT, p)
    c_bp = cv.dcm_body_to_platform(-s, 0.0, np.pi / 2 + LAT)  # level north base: b = n
    dn = np.einsum("kji,kj->ki", c_bp, d)
    pitch, roll = dn[:, 0], -dn[:, 1]
    m = attitude_combinations(LAT) @ p
    basis = np.stack([np.ones_like(s), np.cos(s), np.sin(s), np.cos(2 * s), np.sin(2 * s)], 1)
    np.testing.assert_allclose(basis @ m[:5], pitch, atol=1e-15)
    np.testing.assert_allclose(basis[:, [0, 2, 1, 4, 3]] @ m[5:], roll, atol=1e-15)
    # the n-frame error is horizontal-consistent: the down component equals −u·δ (along-gravity error)
    assert np.abs(dn[:, 2] + hm.harmonic_rows(s, LAT) @ (hm.state_combinations(LAT) @ p)).max() < 1e-15


def test_uncoupled_loop_gain_and_lag():
    loop = DampingLoop(LAT, G, 0.5, couplings=False)
    for k in (1, 2):
        r = k * cv.EARTH_RATE / loop.schuler_frequency
        g = loop.frequency_response(k * cv.EARTH_RATE)
        assert np.angle(g[0, 0]) == pytest.approx(-np.arctan2(2 * 0.5 * r, 1 - r * r), rel=1e-9)
        assert abs(g[0, 0]) == pytest.approx(1 / np.hypot(1 - r * r, 2 * 0.5 * r), rel=1e-9)
        assert abs(g[0, 1]) < 1e-12
    assert np.degrees(-np.angle(loop.frequency_response(cv.EARTH_RATE)[0, 0])) == pytest.approx(3.376, abs=1e-3)
    np.testing.assert_allclose(loop.frequency_response(1e-12)[:, :2], np.eye(2), atol=1e-8)


def test_coupled_loop_finite_at_earth_rate_and_matches_time_domain():
    """The Earth-rate mode is not excited by Δf: G is continuous at ω_ie; the time-domain response agrees."""
    loop = DampingLoop(LAT, G, 0.5)
    w = cv.EARTH_RATE
    g0 = loop.frequency_response(w)
    np.testing.assert_allclose(loop.frequency_response(w * (1 + 1e-7)), g0, atol=1e-9)
    assert abs(g0[0, 1]) > 1e-3  # couplings matter at the 1e-6 rad level for 1e-4 rad signals
    t = np.arange(0.0, 4 * cv.SIDEREAL_DAY, 60.0)
    u = np.stack([np.cos(w * t), np.zeros_like(t)], 1)
    y = loop.simulate(t, u)
    late = t > 2 * cv.SIDEREAL_DAY  # Schuler transient long gone
    expected = np.real(g0[:, 0][None, :] * np.exp(1j * w * t[late])[:, None])
    # first-order hold at 60 s shrinks a sinusoid by (ω dt)²/12 ≈ 1.6e-6
    np.testing.assert_allclose(y[late], expected, atol=3e-6)
    assert np.abs(y[late][:, 1] - expected[:, 1]).max() < 1e-2 * np.abs(expected[:, 1]).max()


def test_loop_from_metadata_requires_damping():
    from stableins.errors import InputError

    with pytest.raises(InputError, match="damping"):
        DampingLoop.from_metadata({}, LAT, G)
    loop = DampingLoop.from_metadata({"zeta": 0.5, "earth_radius": 6.4e6}, LAT, G)
    assert loop.schuler_frequency == pytest.approx(np.sqrt(G / 6.4e6))


@pytest.mark.parametrize("couplings", [True, False])
def test_attitude_fit_compensates_loop_exactly(couplings):
    rng = np.random.default_rng(3)
    p = rng.normal(0, 5e-5, 12)
    t = np.arange(0.0, cv.SIDEREAL_DAY, 10.0)
    s = 0.3 + cv.EARTH_RATE * t
    d = hm.specific_force_error_platform(s, LAT, p)
    dn = np.einsum("kji,kj->ki", cv.dcm_body_to_platform(-s, 0.0, np.pi / 2 + LAT), d)
    loop = DampingLoop(LAT, G, 0.5, couplings=couplings)
    y = loop.simulate(t, np.stack([dn[:, 0], -dn[:, 1]], 1))
    blocks = dict(count=np.ones_like(t), time=t, cos=np.cos(s), sin=np.sin(s), pitch=y[:, 0], roll=y[:, 1])
    ref = attitude_combinations(LAT) @ p
    fit = fit_attitude(blocks, AttitudeModel(loop), (5e-4, 5e-4))
    assert np.abs(fit.values - ref).max() < 1e-10
    biased = fit_attitude(blocks, AttitudeModel(loop, compensate_loop=False), (5e-4, 5e-4))
    assert np.abs(biased.values - ref).max() > 2e-6  # the quasi-static reading is off by several 1e-6 rad


def test_filter_smoother_batch_information_agree():
    rng = np.random.default_rng(7)
    s = np.linspace(0, 2 * np.pi, 3000)
    h = hm.harmonic_rows(s, LAT)
    x_true = rng.normal(0, 1e-4, 5)
    r = (5e-4) ** 2
    z = h @ x_true + rng.normal(0, 5e-4, s.size)
    x0, p0 = rng.normal(0, 1e-4, 5), np.diag(rng.uniform(1, 4, 5) * 1e-8)
    acc = hm.InformationAccumulator()
    for k in range(0, s.size, 700):
        acc.add(h[k : k + 700], z[k : k + 700])
    xi, pi = acc.solve(r, x0, p0)
    xb, pb = hm.regularized_least_squares(h, z, r, x0, p0)
    hist = hm.kalman_filter(h, z, r, x0, p0, smooth=True)
    scale = np.abs(xi).max()
    assert np.abs(xb - xi).max() < 1e-9 * scale
    assert np.abs(hist.means[-1] - xi).max() < 1e-9 * scale
    assert np.abs(hist.smoothed_means - xi).max() < 1e-9 * scale  # static state: every smoothed value is the final one
    np.testing.assert_allclose(hist.covariances[-1], pi, rtol=1e-9, atol=1e-9 * np.abs(pi).max())
    np.testing.assert_allclose(pb, pi, rtol=1e-9, atol=1e-9 * np.abs(pi).max())
    # diffuse prior: the information form still solves (plain least squares)
    xd, _ = acc.solve(r)
    np.testing.assert_allclose(xd, np.linalg.lstsq(h, z, rcond=None)[0], rtol=1e-9, atol=1e-12)


def test_rts_smoother_with_process_noise():
    """With Q > 0 the state is not static: smoothed and filtered differ, the smoother is never less certain at the end."""
    rng = np.random.default_rng(8)
    s = np.linspace(0, 2 * np.pi, 400)
    h = hm.harmonic_rows(s, LAT)
    z = h @ rng.normal(0, 1e-4, 5) + rng.normal(0, 5e-4, s.size)
    q = np.eye(5) * 1e-12
    hist = hm.kalman_filter(h, z, (5e-4) ** 2, np.zeros(5), np.eye(5) * 1e-8, process_noise=q, smooth=True)
    np.testing.assert_allclose(hist.smoothed_means[-1], hist.means[-1], rtol=1e-9)
    assert np.abs(hist.smoothed_means[0] - hist.means[0]).max() > 1e-7
    assert np.all(np.diagonal(hist.smoothed_covariances, axis1=1, axis2=2) <= np.diagonal(hist.covariances, axis1=1, axis2=2) * (1 + 1e-9))


def test_separation_rank_and_singular_directions():
    rng = np.random.default_rng(2)
    p = rng.normal(0, 1e-4, 12)
    c = combination_matrix(LAT) @ np.r_[p, 2e-5, -1e-5]
    sep = separate(COMBINED_COEFFICIENTS, c, np.eye(15) * 1e-14, LAT)
    assert sep.rank == 9
    assert sep.null_space.shape == (14, 5)
    for name, (value, _sigma, determined) in sep.combinations.items():
        assert determined, name
        assert value == pytest.approx(float(sep_vector(name) @ np.r_[p, 0, 0]), abs=1e-12)
    # b_x and beta_xy act only together: moving along (b_x, beta_xy) = (sinL, 1) changes nothing
    names = sep.names
    v = np.zeros(14)
    v[names.index("b_x")], v[names.index("beta_xy")] = np.sin(LAT), 1.0
    assert np.linalg.norm(combination_matrix(LAT) @ v) < 1e-15
    proj = sep.null_space @ np.linalg.lstsq(sep.null_space, v, rcond=None)[0]
    np.testing.assert_allclose(proj, v, atol=1e-12)
    assert sep.determined[names.index("beta_zy")] and sep.determined[names.index("beta_zx")]
    assert not sep.determined[names.index("b_x")] and not sep.determined[names.index("beta_xy")]


def sep_vector(name):
    from stableins.estimators.system.separation import determined_combinations

    return determined_combinations(LAT)[name]


def test_paper_eq41_restored_is_singular():
    """Eq. 41 with the angle terms of Eqs. 22–23 restored in rows 5–6 has rank 4 of 6."""
    s, c = np.sin(LAT), np.cos(LAT)
    # unknowns (b_x, b_y, beta_yx, beta_zx, beta_xy, beta_zy); rows phi1s, phi1c, theta1c, theta1s, x2, x3
    m = attitude_combinations(LAT)
    x = hm.state_combinations(LAT)
    cols = [3, 4, 8, 10, 6, 11]
    a = np.vstack([m[6, cols], m[7, cols], m[1, cols], m[2, cols], x[1, cols], x[2, cols]])
    assert np.linalg.matrix_rank(a, tol=1e-12) == 4
    assert s > 0 and c > 0


def test_vertical_channel_from_metadata_moves_roll():
    """k1..k3 in the metadata add the height-aided vertical loop; its Coriolis path reaches the roll harmonics."""
    a = 1.0 / 300.0
    ws2 = G / cv.EARTH_RADIUS
    damping = {"zeta": 0.5, "k1": 2 * a, "k2": 2 * a * a + 2 * ws2, "k3": a**3}
    loop = DampingLoop.from_metadata(damping, LAT, G)
    assert loop.vertical_gains is not None and loop.n_states == 9
    eig = np.linalg.eigvals(loop.state_matrix())
    assert np.all(eig.real < 1e-12)  # stable (the Earth-rate mode is marginal)
    m = loop.vertical_harmonic_matrix(1)
    assert np.abs(m[2:]).max() > 1e-3  # 1e-4 of along-gravity error → > 1e-7 rad in roll
    assert np.abs(m[:2]).max() < np.abs(m[2:]).max()
    np.testing.assert_allclose(loop.dc_gain(), np.c_[np.eye(2), np.zeros(2)], atol=1e-9)
    horizontal = DampingLoop.from_metadata({"zeta": 0.5}, LAT, G)
    np.testing.assert_allclose(horizontal.frequency_response(cv.EARTH_RATE)[:, 2], 0.0)


def test_stage_compensation_equals_error_model_inverse():
    """The closed-form z of the per-sample pass gives |f^p|² = |ErrorModel.inverse(f^a)|², K2 included."""
    from stableins.estimators.system.compensation import Compensation

    rng = np.random.default_rng(4)
    installed = random_parameters(rng) | {f"K2_{x}": rng.normal(0, 2e-7) for x in "xyz"}
    f_a = platform_force(rng.uniform(0, 6, 1000)) + rng.normal(0, 1e-2, (1000, 3))
    expected = np.sum(ErrorModel.standard().inverse(f_a, installed) ** 2, axis=1)
    z = observation(f_a[:, 0], f_a[:, 1], f_a[:, 2], Compensation.from_values(installed).packed(9.8))
    got = 2.0 * 9.8**2 * (z + 0.5)  # z = ½(|f^p|²/g² − 1)
    np.testing.assert_allclose(got, expected, rtol=1e-14)


@pytest.mark.parametrize("jitter", [0.0, 0.2])
def test_block_sums_equal_reference(jitter):
    """The per-sample pass equals its ``reduceat`` reference (z, moments, block times, Σz², irregular steps)."""
    from stableins.estimators.system.blocks import BlockPass, block_sums, block_sums_reference
    from stableins.estimators.system.compensation import Compensation

    rng = np.random.default_rng(6)
    installed = random_parameters(rng) | {f"K2_{x}": rng.normal(0, 2e-7) for x in "xyz"}
    for n in (1, 2, 255, 256, 257, 70_001):
        t = 50.0 + np.arange(n) / 100.0 + (rng.uniform(-jitter, jitter, n) / 100.0 if jitter else 0.0)
        f_a = platform_force(rng.uniform(0, 6, n)) + rng.normal(0, 1e-2, (n, 3))
        packed = Compensation.from_values(installed).packed(9.8)
        args = (*(f_a[:, k].copy() for k in range(3)), t, BlockPass(packed, 256, cv.EARTH_RATE, (0.0099, 0.0101)))
        got, expected = block_sums(*args), block_sums_reference(*args)
        # round-off scale per block and column: Σ|z||δ|^p, Σ|δ|^p, plus p·Σ|z||δ|^(p−1)·ε_c for the round-off ε_c of the centre
        z = observation(f_a[:, 0], f_a[:, 1], f_a[:, 2], packed)
        d = np.abs(cv.EARTH_RATE * (t - np.repeat(expected[1], expected[0][:, 7].astype(int))))
        eps_c = cv.EARTH_RATE * 1e-14 * np.abs(t).max()
        starts = np.arange(0, n, 256)

        def rsum(v, starts=starts):
            return np.add.reduceat(v, starts)

        scale = np.stack([rsum(np.abs(z) * d**p) for p in range(4)] + [rsum(d**p) for p in (1, 2, 3)] + [expected[0][:, 7]], axis=1)
        centre = np.stack(
            [p * eps_c * rsum(np.abs(z) * d ** max(p - 1, 0)) for p in range(4)] + [p * eps_c * rsum(d ** (p - 1)) for p in (1, 2, 3)],
            axis=1,
        )
        tolerance = 1e-12 * scale + np.c_[centre, np.zeros(len(centre))] + 1e-300
        excess = np.abs(got[0] - expected[0]) / tolerance
        assert excess.max() <= 1.0, (n, np.unravel_index(np.argmax(excess), excess.shape), excess.max())
        np.testing.assert_allclose(got[1], expected[1], rtol=1e-15)
        assert got[2] == pytest.approx(expected[2], rel=1e-12)
        assert got[3] == expected[3] and (jitter == 0 or n < 3 or got[3] > 0)
        if jitter == 0:  # stamps not given: t_j = t_0 + j·period (the time-grid path)
            uniform = block_sums(*args[:3], None, *args[4:], grid=(50.0, 0.01))
            excess = np.abs(uniform[0] - expected[0]) / tolerance
            assert excess.max() <= 1.0, (n, np.unravel_index(np.argmax(excess), excess.shape), excess.max())
            np.testing.assert_allclose(uniform[1], expected[1], rtol=1e-15)
            assert uniform[2] == pytest.approx(expected[2], rel=1e-12) and uniform[3] == 0


@pytest.mark.parametrize("block", [3, 100, 1 << 15])
def test_block_sums_blocks_across_sub_chunks(block):
    """Blocks of any length, longer or shorter than a sub-chunk and not dividing it, are summed whole (stamps and grid)."""
    from stableins.estimators.system.blocks import SUB_CHUNK, BlockPass, block_sums, block_sums_reference
    from stableins.estimators.system.compensation import Compensation

    rng = np.random.default_rng(8)
    n = 2 * SUB_CHUNK + 2 * block + 1
    t = 50.0 + np.arange(n) / 100.0
    f_a = platform_force(rng.uniform(0, 6, n)) + rng.normal(0, 1e-2, (n, 3))
    settings = BlockPass(Compensation.from_values(random_parameters(rng)).packed(9.8), block, cv.EARTH_RATE, (0.0099, 0.0101))
    force = [f_a[:, k].copy() for k in range(3)]
    expected = block_sums_reference(*force, t, settings)
    z = np.abs(observation(*force, settings.packed))
    for got in (block_sums(*force, t, settings), block_sums(*force, None, settings, grid=(50.0, 0.01))):
        np.testing.assert_array_equal(got[0][:, 7], expected[0][:, 7])
        # z = (a quadratic form ≈ ½) − ½: each sample's z is known to the rounding of ½, 1.1e-16
        tolerance = 1e-13 * np.add.reduceat(z, np.arange(0, n, block)) + 2.3e-16 * expected[0][:, 7]
        assert np.all(np.abs(got[0][:, 0] - expected[0][:, 0]) <= tolerance)
        np.testing.assert_allclose(got[1], expected[1], rtol=1e-15)
        assert got[2] == pytest.approx(expected[2], rel=1e-12) and got[3] == expected[3] == 0


def test_block_sums_z_equals_error_model_inverse():
    """z of the per-sample pass is ½(|ErrorModel.inverse(f^a)|²/g² − 1), K2 included (one-sample blocks)."""
    from stableins.estimators.system.blocks import BlockPass, block_sums
    from stableins.estimators.system.compensation import Compensation

    rng = np.random.default_rng(5)
    installed = random_parameters(rng) | {f"K2_{x}": rng.normal(0, 2e-7) for x in "xyz"}
    n = 1000
    f_a = platform_force(rng.uniform(0, 6, n)) + rng.normal(0, 1e-2, (n, 3))
    expected = 0.5 * (np.sum(ErrorModel.standard().inverse(f_a, installed) ** 2, axis=1) / 9.8**2 - 1.0)
    packed = Compensation.from_values(installed).packed(9.8)
    sums, *_ = block_sums(*(f_a[:, k].copy() for k in range(3)), np.arange(n) / 100.0, BlockPass(packed, 1, cv.EARTH_RATE, (0.0, 1.0)))
    np.testing.assert_allclose(sums[:, 0], expected, rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("jitter", [0.0, 0.2])
def test_timed_block_information_equals_per_sample(jitter):
    """``S = S_c + ω_ie (t − t̄)`` per block (uniform grid or jittered stamps) equals the per-sample information."""
    from stableins.estimators.system.blocks import BlockPass, block_sums

    rng = np.random.default_rng(1)
    rate = 100.0
    n = 200_000 + 33
    t = 1000.0 + np.arange(n) / rate + (rng.uniform(-jitter, jitter, n) / rate if jitter else 0.0)
    s = 0.7 + cv.EARTH_RATE * (t - t[0])
    z = rng.normal(0, 5e-4, n) + 1e-4 * np.cos(s)
    ref = harmonic_information(s, z, LAT, order=3)
    # an identity calibration with q00 = 1, zero force on y and z: the pass's z is fx² − ½, so fx = √(z + ½)
    packed = np.array([0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    fx = np.sqrt(z + 0.5)
    block = BlockHarmonics(LAT, 256, order=3)
    for start in range(0, n, 65536):
        sl = slice(start, start + 65536)
        sums, centres, z2, _ = block_sums(
            fx[sl], np.zeros(fx[sl].size), np.zeros(fx[sl].size), t[sl], BlockPass(packed, 256, cv.EARTH_RATE, (0, 1))
        )
        block.add_sums(0.7 + cv.EARTH_RATE * (centres - t[0]), sums, z2)
    acc = block.accumulator()
    np.testing.assert_allclose(acc.information, ref.information, rtol=1e-11, atol=1e-11 * n)
    np.testing.assert_allclose(acc.projection, ref.projection, rtol=1e-9, atol=1e-12 * np.abs(z).sum())
    assert acc.count == n
    assert acc.sum_squares == pytest.approx(float(z @ z), rel=1e-10)


def test_attitude_blocks_merge_pairs_equals_wider_blocks_and_stays_bounded():
    from stableins.estimators.system.blocks import AttitudeBlocks

    rng = np.random.default_rng(11)
    t = 100.0 + np.arange(0.0, 20000.0, 1.0)
    s = 0.3 + cv.EARTH_RATE * t
    pitch, roll = rng.normal(0, 1e-4, (2, t.size))
    capped = AttitudeBlocks(10.0, 100.0, max_blocks=300)  # 2000 10-s blocks needed: merged three times, to 80 s
    for part in np.array_split(np.arange(t.size), 37):
        capped.add(t[part], np.cos(s[part]), np.sin(s[part]), pitch[part], roll[part])
    assert capped.block_seconds == 80.0
    assert max(a.size for a in capped.sums.values()) <= 300
    direct = AttitudeBlocks(80.0, 100.0)
    direct.add(t, np.cos(s), np.sin(s), pitch, roll)
    a, b = capped.means(), direct.means()
    assert a["count"].size == 250 and np.array_equal(a["count"], b["count"])
    for key in ("time", "cos", "sin", "pitch", "roll"):
        np.testing.assert_allclose(a[key], b[key], rtol=1e-12, atol=1e-15)


def test_attitude_fit_independent_of_row_slicing(monkeypatch):
    import stableins.estimators.system.attitude as attitude_module

    rng = np.random.default_rng(5)
    t = np.arange(0.0, cv.SIDEREAL_DAY, 10.0)
    s = 0.3 + cv.EARTH_RATE * t
    y = 1e-5 * np.stack([np.cos(s + 0.2), np.sin(s - 0.1)], axis=1) + rng.normal(0, 1e-6, (t.size, 2))
    blocks = dict(count=np.full_like(t, 10.0), time=t, cos=np.cos(s), sin=np.sin(s), pitch=y[:, 0], roll=y[:, 1])
    loop = DampingLoop(LAT, G, 0.5)
    whole = fit_attitude(blocks, AttitudeModel(loop), (5e-4, 5e-4), drift=AttitudeDrift("check"))
    monkeypatch.setattr(attitude_module, "FIT_ROWS", 97)  # 90 slices, the last partial
    sliced = fit_attitude(blocks, AttitudeModel(loop), (5e-4, 5e-4), drift=AttitudeDrift("check"))
    assert whole.block_residuals.shape == (t.size, 2)
    np.testing.assert_allclose(sliced.values, whole.values, rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(sliced.covariance, whole.covariance, rtol=1e-9, atol=1e-24)
    np.testing.assert_allclose(sliced.block_residuals, whole.block_residuals, rtol=0, atol=1e-15)
    np.testing.assert_allclose(sliced.block_map, whole.block_map, rtol=1e-9, atol=1e-12 * np.abs(whole.block_map).max())


def test_second_difference_sums_equal_numpy_and_measure_white_noise():
    from stableins.estimators.system.blocks import second_difference_sums

    rng = np.random.default_rng(8)
    sigma = np.array([1e-3, 2e-3, 5e-4])
    f = rng.normal(0, 1, (3, 200_000)) * sigma[:, None] + np.array([[1.0], [2.0], [9.0]]) + 1e-6 * np.arange(200_000)
    out = np.zeros(3)
    assert second_difference_sums(*f, 150_000, out) == 149_998
    expected = [float(np.sum(np.diff(x[:150_000], 2) ** 2)) for x in f]
    np.testing.assert_allclose(out, expected, rtol=1e-10)
    # E[(Δ²n)²] = 6σ²: the estimate's relative σ is about √(35/18/N) ≈ 0.4 % here
    np.testing.assert_allclose(np.sqrt(out / 149_998 / 6.0), sigma, rtol=0.015)
    assert second_difference_sums(*f, 2, out) == 0


@pytest.mark.parametrize("complex_modes", [True, False])
def test_modal_recursion_is_lfilter_to_the_last_bit(complex_modes: bool) -> None:
    """The loop's modal recursion (written out so that scipy.signal is not imported) computes lfilter's numbers exactly."""
    from scipy.signal import lfilter

    from stableins.estimators.system.loop import modal_recursion

    rng = np.random.default_rng(30)
    lam = 0.999 * np.exp(rng.normal(0.0, 0.01, 7) + (1j * rng.normal(0.0, 0.1, 7) if complex_modes else 0.0))
    drive = rng.normal(size=(500, 7)) + (1j * rng.normal(size=(500, 7)) if complex_modes else 0.0)
    expected = np.stack([lfilter([1.0], [1.0, -lam[i]], drive[:, i]) for i in range(7)], axis=1)
    found = modal_recursion(lam, drive)
    assert found.dtype == expected.dtype
    assert np.array_equal(found, expected)
