"""The coloured-noise model of the system stage (stableins.estimators.system.spectrum): each piece against its definition.

* ``component_quadratic`` against the stacked covariance it avoids forming;
* ``loop_bin_mixing`` against the loop's frequency response and its DC gain;
* ``periodogram_design`` expectations against the mean periodogram of noise drawn from the same Gaussian model;
* ``whittle_fit`` against exponential ordinates with known means (k·σ from the Fisher information);
* the stage's attitude residual maker on bins against the block-level fit it stands for.

The end-to-end check (σ against the simulator's scatter) is test_system_recovery.test_monte_carlo_sigma_with_quartz_noise.
"""

import math
import tracemalloc

import numpy as np
import pytest

from stableins.conventions import EARTH_RATE, SIDEREAL_DAY
from stableins.estimators.system import spectrum, whittle
from stableins.estimators.system.loop import DampingLoop
from stableins.noise import FLICKER_TIME_CONSTANTS

LATITUDE = math.radians(40.0)
WIDTH = 600.0


def bins(n=144, start=0.4):
    time = (np.arange(n) + 0.5) * WIDTH
    angle = start + EARTH_RATE * time
    return time, np.cos(angle), np.sin(angle)


def harmonic_maker(cos_s, sin_s, count):
    x = np.stack([np.ones_like(cos_s), cos_s, sin_s, cos_s**2 - sin_s**2, 2 * sin_s * cos_s], axis=1)
    return np.eye(cos_s.size) - x @ np.linalg.solve(x.T @ (x * count[:, None]), (x * count[:, None]).T)


def loop():
    return DampingLoop(LATITUDE, 9.80, 0.5)


def test_component_quadratic_equals_stacked_covariance():
    rng = np.random.default_rng(3)
    n = 24
    time, c, s = bins(n)
    kernel = spectrum.bin_process_kernel("random_walk", time, WIDTH) + spectrum.bin_process_kernel("flicker", time, WIDTH)
    loads = [spectrum.axis_loadings(ch, c, s, LATITUDE) for ch in ("z", "pitch", "roll")]
    operator = rng.normal(size=(n, n))
    mixing = [
        [loads[0][:, a] for a in range(3)],
        [operator * loads[1][:, a][None, :] for a in range(3)],
        [loads[2][:, a] for a in range(3)],
    ]
    # the stacked covariance: channel p's noise is Σ_a M_pa n_a with independent axes of covariance `kernel`
    dense = [[np.diag(m) if m.ndim == 1 else m for m in ops] for ops in mixing]
    sigma = np.zeros((3 * n, 3 * n))
    for p in range(3):
        for q in range(3):
            sigma[p * n : (p + 1) * n, q * n : (q + 1) * n] = sum(dense[p][a] @ kernel @ dense[q][a].T for a in range(3))
    left, right = rng.normal(size=(5, 3 * n)), rng.normal(size=(4, 3 * n))
    np.testing.assert_allclose(spectrum.component_quadratic(left, right, mixing, kernel), left @ sigma @ right.T, rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(spectrum.component_quadratic(left, left, mixing, kernel), left @ sigma @ left.T, rtol=1e-10, atol=1e-10)


def test_bin_kernels_are_the_bin_means_of_the_processes():
    """Random walk: Var of a bin mean = a + w/3, covariance = earlier centre; flicker: unit Gauss-Markov sum."""
    time = np.array([300.0, 900.0, 4500.0])
    rw = spectrum.bin_process_kernel("random_walk", time, WIDTH)
    assert rw[0, 0] == pytest.approx(0.0 + WIDTH / 3)  # bin [0, 600]
    assert rw[1, 1] == pytest.approx(600.0 + WIDTH / 3)
    assert rw[0, 2] == pytest.approx(300.0) and rw[2, 1] == pytest.approx(900.0)
    fl = spectrum.bin_process_kernel("flicker", time, WIDTH)
    # a long Gauss-Markov process is almost constant over a bin: its bin-mean variance → 1 per process
    taus = np.array(FLICKER_TIME_CONSTANTS)
    x = WIDTH / taus
    assert fl[0, 0] == pytest.approx(np.sum(2 * (x - 1 + np.exp(-x)) / x**2))
    assert fl[0, 2] == pytest.approx(np.sum(np.exp(-4200.0 / taus) * (np.sinh(x / 2) / (x / 2)) ** 2))
    assert np.all(np.linalg.eigvalsh(fl) > 0) and np.all(np.linalg.eigvalsh(rw) > 0)


def test_loop_bin_mixing_reproduces_the_frequency_response_and_dc_gain():
    lp = loop()
    modes = lp._controllable_modes()
    n = 288
    time, c, s = bins(n)
    unit = [np.tile([1.0, 0.0, 0.0], (n, 1)), np.tile([0.0, 1.0, 0.0], (n, 1)), np.tile([0.0, 0.0, 1.0], (n, 1))]
    mixing = spectrum.loop_bin_mixing(modes, time, WIDTH, unit)  # axis k = input k
    dc = lp.frequency_response(0.0).real
    settled = slice(n // 2, None)  # the transients (hours) have decayed
    for o in range(2):
        for k in range(3):
            np.testing.assert_allclose((mixing[o][k] @ np.ones(n))[settled], dc[o, k], atol=1e-9)
    # a sinusoid at 3 cycles/day (bin means in, bin means out): Re{G(jω) e^{jωt}} times the bin-mean factor
    omega = 3.0 * EARTH_RATE
    mean_factor = np.sinc(omega * WIDTH / (2 * np.pi))
    u = mean_factor * np.cos(omega * time)
    g = lp.frequency_response(omega)
    for o in range(2):
        for k in range(2):
            expected = mean_factor * np.real(g[o, k] * np.exp(1j * omega * time))
            assert np.abs((mixing[o][k] @ u - expected)[settled]).max() < 2e-3 * abs(g[o, k]) + 1e-12


@pytest.mark.parametrize("kind", ["random_walk", "flicker"])
def test_expected_periodogram_matches_the_mean_periodogram_of_drawn_noise(kind):
    """Draw bin noise from the model itself (z: loadings; pitch: through the loop) and average the residual periodograms."""
    rng = np.random.default_rng(11)
    n = 144
    time, c, s = bins(n)
    count = np.full(n, 600.0)
    kernel = spectrum.bin_process_kernel(kind, time, WIDTH)
    loads = [spectrum.axis_loadings(ch, c, s, LATITUDE) for ch in ("z", "pitch", "roll")]
    mixing = [[loads[0][:, a] for a in range(3)]] + spectrum.loop_bin_mixing(
        loop()._controllable_modes(), time, WIDTH, [loads[1], loads[2], -loads[0]]
    )
    maker = harmonic_maker(c, s, count)
    chol = np.linalg.cholesky(kernel + 1e-9 * np.eye(n) * np.trace(kernel) / n)
    band = (3.5 * spectrum.EARTH_FREQUENCY, 30 * spectrum.EARTH_FREQUENCY)
    dense = [[np.diag(m) if m.ndim == 1 else m for m in ops] for ops in mixing]
    draws = 400
    total = None
    for _ in range(draws):
        axes = chol @ rng.standard_normal((n, 3))
        channels = [maker @ sum(dense[p][a] @ axes[:, a] for a in range(3)) for p in range(3)]
        residuals = spectrum.ResidualChannels(channels, [maker] * 3, [count] * 3)
        _, observed, _ = spectrum.periodogram_design(residuals, time, [], mixing, band)  # ordinates only
        total = observed if total is None else total + observed
    design, _, n_ch = spectrum.periodogram_design(residuals, time, [kernel], mixing, band)
    expected = design[:, n_ch]
    ratio = total / draws / expected
    # mean of 400 ordinates: ~5 % standard error each (coloured ordinates are close to exponential)
    assert abs(ratio.mean() - 1.0) < 0.04, ratio.mean()
    assert np.abs(ratio - 1.0).max() < 0.3, ratio


@pytest.mark.slow
def test_white_gain_of_a_loop_filtered_white_noise_on_bins():
    """Bin means of loop-filtered white noise: periodogram ∝ Σ|G(f)|² sinc²(f w), the white column's shape."""
    rng = np.random.default_rng(5)
    lp = loop()
    step = 30.0
    n_fine = int(SIDEREAL_DAY // step)
    fine_time = np.arange(n_fine) * step
    per_bin = int(WIDTH // step)
    n = n_fine // per_bin
    time, c, s = bins(n)
    count = np.full(n, float(per_bin))
    maker = harmonic_maker(c, s, count)
    band = (3.5 * spectrum.EARTH_FREQUENCY, 30 * spectrum.EARTH_FREQUENCY)
    gain = [lambda f: float(np.sum(np.abs(lp.frequency_response(2 * np.pi * f)[0]) ** 2) * np.sinc(f * WIDTH) ** 2)]
    zero = [[np.zeros(n)] * 3]
    total = None
    for _ in range(300):
        pitch = lp.simulate(fine_time, rng.standard_normal((n_fine, 2)))[:, 0]
        binned = pitch[: n * per_bin].reshape(n, per_bin).mean(axis=1)
        residuals = spectrum.ResidualChannels([maker @ binned], [maker], [count], gain)
        design, observed, _ = spectrum.periodogram_design(residuals, time, [], zero, band)
        total = observed if total is None else total + observed
    shape = total / design[:, 0]
    # the white column has the right shape across the band: the ratio is flat (level free), low vs high third
    # (without the bin-mean factor sinc² the ratio is ~1.12, 3.5 standard errors off)
    m = shape.size // 3
    assert abs(shape[:m].mean() / shape[-m:].mean() - 1.0) < 0.08, shape


def test_whittle_fit_recovers_known_levels_within_k_sigma():
    rng = np.random.default_rng(7)
    k = np.arange(4, 400)
    design = np.stack([np.ones(k.size), 30.0 / k, (30.0 / k) ** 2], axis=1)
    theta = np.array([1.0, 0.5, 0.2])
    observed = rng.exponential(design @ theta)
    fitted, _ = whittle.whittle_fit(design, observed)
    e = design @ fitted
    fisher = (design / e[:, None]).T @ (design / e[:, None])
    sigma = np.sqrt(np.diag(np.linalg.inv(fisher)))
    assert np.all(np.abs(fitted - theta) < 4 * sigma), (fitted, theta, sigma)
    fit = whittle.fit_coloured_noise(design, observed, 1)
    np.testing.assert_allclose(fit.maximum_likelihood, fitted[1:], rtol=1e-4)
    assert fit.statistic > 10 and fit.detected  # strongly coloured: far better than white
    np.testing.assert_allclose(fit.amplitudes, np.repeat(fit.maximum_likelihood[:, None], 3, axis=1))  # one value for the axes
    assert np.all(fit.lower <= fit.maximum_likelihood) and np.all(fit.maximum_likelihood <= fit.upper)


def test_component_quadratic_memory_does_not_grow_with_the_stacked_size():
    """320 bins, three channels: the stacked covariance alone would be 7.4 MB; the product stays near the kernel's 0.8 MB."""
    n = 320
    time, c, s = bins(n)
    kernel = spectrum.bin_process_kernel("random_walk", time, WIDTH)
    loads = [spectrum.axis_loadings(ch, c, s, LATITUDE) for ch in ("z", "pitch", "roll")]
    mixing = [[ld[:, a] for a in range(3)] for ld in loads]
    left = np.ones((17, 3 * n))
    tracemalloc.start()
    spectrum.component_quadratic(left, left, mixing, kernel)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert peak < 1.5e6, peak


def testattitude_residual_maker_equals_the_block_fit_for_noise_constant_within_bins():
    from stableins.estimators.system.attitude import AttitudeModel, _design
    from stableins.estimators.system.coloured import attitude_residual_maker

    rng = np.random.default_rng(2)
    lp = loop()
    block_time = np.arange(0.0, SIDEREAL_DAY, 10.0) + 5.0
    angle = 0.3 + EARTH_RATE * block_time
    blocks = {"time": block_time, "cos": np.cos(angle), "sin": np.sin(angle), "count": np.full(block_time.size, 10.0)}
    blocks["count"][::7] = 9.0  # uneven weights
    block_bin = np.floor(block_time / WIDTH).astype(np.int64)
    n = int(block_bin.max()) + 1
    bin_count = np.bincount(block_bin, weights=blocks["count"], minlength=n)
    maker = attitude_residual_maker(blocks, block_bin, bin_count, AttitudeModel(lp, 480.0))
    values = np.cumsum(rng.standard_normal(n))  # a random walk on the bins, constant within each
    y = values[block_bin]
    x = _design(blocks, lp, 480.0)[0]
    w = blocks["count"]
    beta = np.linalg.solve(x.T @ (x * w[:, None]), x.T @ (w * y))
    residual = np.bincount(block_bin, weights=w * (y - x @ beta), minlength=n) / bin_count
    np.testing.assert_allclose(maker @ values, residual, atol=1e-9 * np.abs(values).max())
    # the transient columns matter: mean and harmonics alone leave a different residual
    cos_s = np.bincount(block_bin, weights=w * blocks["cos"], minlength=n) / bin_count
    sin_s = np.bincount(block_bin, weights=w * blocks["sin"], minlength=n) / bin_count
    assert np.abs(harmonic_maker(cos_s, sin_s, bin_count) @ values - residual).max() > 1e-3 * np.abs(residual).max()


# --------------------------------------------------------------------------- the z channel's high band and the decision
def _z_bin_covariance(kind, n, width):
    """Brute force: covariance of the z bin means, ``Σ_a L_a(i) L_a(j) C(i, j)`` with the z loadings (S advancing at ω_ie)."""
    time = (np.arange(n) + 0.5) * width
    angle = 0.7 + EARTH_RATE * time
    loads = spectrum.axis_loadings("z", np.cos(angle), np.sin(angle), LATITUDE)
    kernel = spectrum.bin_process_kernel(kind, time, width)
    return sum(np.outer(loads[:, a], loads[:, a]) * kernel for a in range(3))


@pytest.mark.parametrize("kind", ["random_walk", "flicker"])
def test_z_bin_expectations_are_the_periodogram_of_the_bin_covariance(kind):
    """Closed forms (geometric sums, the random walk's min(i, j)) against ``E P_k = 2 vᵀ C v̄ / n²`` with ``v = e^{−iθ_k j}``."""
    n, width = 300, 60.0
    k = np.array([40, 57, 101, 133])
    cov = _z_bin_covariance(kind, n, width)
    v = np.exp(-2j * np.pi * np.outer(k, np.arange(n)) / n)
    brute = 2.0 * np.real(np.einsum("kn,nm,km->k", v, cov, v.conj())) / n**2
    column = 1 + spectrum.COLOURED_KINDS.index(kind)
    expected = spectrum.z_bin_expectations(k, n, width, LATITUDE, 60.0)[:, column]
    # the loadings use the bin-centre angle; the closed form modulates by cos(ω_ie (t_i − t_j)): the same thing
    np.testing.assert_allclose(expected, brute, rtol=1e-9)
    white = spectrum.z_bin_expectations(k, n, width, LATITUDE, 60.0)[:, 0]
    np.testing.assert_allclose(white, 2.0 / (n * 60.0))


def test_z_bin_periodogram_is_the_weighted_projection():
    rng = np.random.default_rng(4)
    n = 200
    residual, count = rng.normal(size=n), rng.integers(50, 61, n).astype(float)
    count[17] = 0.0
    k = np.array([20, 35, 80])
    w = count / count.sum()
    arg = 2 * np.pi * np.outer(k, np.arange(n)) / n
    a, b = 2 * (np.cos(arg) @ (w * residual)), 2 * (np.sin(arg) @ (w * residual))
    np.testing.assert_allclose(spectrum.z_bin_periodogram(residual, count, k), 0.5 * (a * a + b * b), rtol=1e-12)


def test_high_band_expectation_matches_drawn_noise_after_the_harmonic_fit():
    """Random walk and flicker drawn at 1-s steps over one sidereal day on the three axes, loaded into z, binned to 60 s:
    the mean periodogram above 30 cycles/day is the closed form's, and fitting out the mean and the harmonics (to the
    third) changes it by less than 1 % (draw by draw: the closed form leaves the fit out).  The random walk's ordinates
    share its end-point leakage, so its band mean scatters from draw to draw: the bound is 4 standard errors of the
    draws' own band means."""
    rng = np.random.default_rng(21)
    step, width = 1.0, 60.0
    m = int(SIDEREAL_DAY // width) * int(width // step)
    t = (np.arange(m) + 0.5) * step
    per = int(width // step)
    n = m // per
    angle = 0.7 + EARTH_RATE * t
    loads = spectrum.axis_loadings("z", np.cos(angle), np.sin(angle), LATITUDE)
    tb = (np.arange(n) + 0.5) * width
    sb = 0.7 + EARTH_RATE * tb
    x = np.stack([np.ones(n)] + [f(j * sb) for j in (1, 2, 3) for f in (np.cos, np.sin)], axis=1)
    maker = np.eye(n) - x @ np.linalg.pinv(x)
    k = np.arange(int(30 * n * width / SIDEREAL_DAY) + 1, int(0.45 * n) + 1)
    expected = spectrum.z_bin_expectations(k, n, width, LATITUDE, per)
    count = np.full(n, float(per))
    from scipy.signal import lfilter

    for kind, column in (("random_walk", 1), ("flicker", 2)):
        means, fitted, raw = [], 0.0, 0.0
        for _ in range(60):
            if kind == "random_walk":  # unit (K/g)²: increments of variance step, started at 0
                axes = np.cumsum(rng.normal(0.0, math.sqrt(step), (m, 3)), axis=0)
            else:  # unit-variance Gauss-Markov processes, stationary start
                axes = np.zeros((m, 3))
                for tau in FLICKER_TIME_CONSTANTS:
                    a = math.exp(-step / tau)
                    drive = rng.normal(0.0, math.sqrt(1 - a * a), (m, 3))
                    drive[0] = rng.normal(0.0, 1.0, 3)
                    axes += lfilter([1.0], [1.0, -a], drive, axis=0)
            z = np.sum(loads * axes, axis=1).reshape(n, per).mean(axis=1)
            unfitted = spectrum.z_bin_periodogram(z, count, k)
            residual = spectrum.z_bin_periodogram(maker @ z, count, k)
            means.append(np.mean(residual / expected[:, column]))
            fitted, raw = fitted + residual.sum(), raw + unfitted.sum()
        means = np.array(means)
        error = means.std(ddof=1) / math.sqrt(means.size)
        # sampling at 1 s instead of continuous time raises the bin means' ordinates by well under 1 %
        assert abs(means.mean() - 1.0) < 4.0 * error + 0.02, (kind, means.mean(), error)
        assert abs(fitted / raw - 1.0) < 0.01, (kind, fitted / raw)


def _white_design(rng):
    """A z channel low band (random columns of realistic shape) and the high band: white, random walk, flicker."""
    n, width = 1436, 60.0
    k = np.arange(30, int(0.45 * n) + 1)
    high = spectrum.z_bin_expectations(k, n, width, LATITUDE, 60.0)
    kl = np.arange(4, 30)
    low = np.stack([np.full(kl.size, 2.0 / 86164), 2.0 * 86164 / (2 * np.pi * kl) ** 2 / 86164, 2e4 / kl / 86164], axis=1)
    return np.vstack([low, high])


def test_decision_has_its_false_positive_rate_and_the_intervals_cover():
    """White ordinates (exponential, known means): coloured noise declared in α of the draws (χ̄² calibration); with a
    coloured truth the profile interval's upper end covers it at about the confidence level."""
    rng = np.random.default_rng(8)
    design = _white_design(rng)
    truth = np.array([1e-6, 0.0, 0.0])
    draws, alpha = 300, 0.05
    detected = 0
    for _ in range(draws):
        observed = rng.exponential(design @ truth)
        detected += whittle.fit_coloured_noise(design, observed, 1, alpha=alpha).detected
    rate = detected / draws
    assert abs(rate - alpha) < 3.5 * math.sqrt(alpha * (1 - alpha) / draws), rate  # ± 0.044
    coloured = np.array([1e-6, 0.0, 1e-6 * 0.4 / design[:, 2].mean() * design[:, 0].mean()])
    covered = 0
    for _ in range(100):
        fit = whittle.fit_coloured_noise(design, rng.exponential(design @ coloured), 1)
        covered += fit.lower[1] <= coloured[2] <= fit.upper[1]
        assert fit.detected
    assert covered >= 85, covered  # 95 % intervals


def test_decision_with_a_noiseless_channel():
    """A channel whose residuals are exactly zero (a synthetic record without attitude noise) has a zero white level."""
    rng = np.random.default_rng(9)
    z = _white_design(rng)
    m = z.shape[0]
    design = np.zeros((2 * m, 4))
    design[:m, 0], design[:m, 2:] = z[:, 0], z[:, 1:]
    design[m:, 1], design[m:, 2:] = z[:, 0], 0.1 * z[:, 1:]
    observed = np.concatenate([rng.exponential(z[:, 0] * 1e-6), np.zeros(m)])
    fit = whittle.fit_coloured_noise(design, observed, 2)
    assert np.isfinite(fit.p_value) and not fit.detected and fit.white_levels[1] == 0.0


def test_a_given_datasheet_is_rejected_at_its_false_alarm_rate_and_when_the_record_contradicts_it():
    """Issue 25: a datasheet whose slow amplitudes are true is rejected in about α of the draws (likelihood-ratio
    test with the white levels free); one with no slow noise on a record that has it is rejected, and the σ then follow
    the record's maximum-likelihood amplitudes (source CONTRADICTED)."""
    rng = np.random.default_rng(9)
    design = _white_design(rng)
    coloured = np.array([1e-6, 0.0, 1e-6 * 0.4 / design[:, 2].mean() * design[:, 0].mean()])
    true_sheet = whittle.NoisePrior(given=np.repeat(coloured[1:, None], 3, axis=1))
    draws, alpha = 300, 0.05
    rejected = 0
    for _ in range(draws):
        fit = whittle.fit_coloured_noise(design, rng.exponential(design @ coloured), 1, alpha=alpha, prior=true_sheet)
        rejected += fit.source is whittle.ColouredSource.CONTRADICTED
        if fit.source is whittle.ColouredSource.GIVEN:
            np.testing.assert_allclose(fit.amplitudes, true_sheet.given)
    assert rejected / draws < alpha + 3.5 * math.sqrt(alpha * (1 - alpha) / draws), rejected
    zero_sheet = whittle.NoisePrior(given=np.zeros((2, 3)))
    fit = whittle.fit_coloured_noise(design, rng.exponential(design @ coloured), 1, alpha=alpha, prior=zero_sheet)
    assert fit.source is whittle.ColouredSource.CONTRADICTED and fit.data_detected
    np.testing.assert_allclose(fit.amplitudes, np.repeat(fit.maximum_likelihood[:, None], 3, axis=1))


def test_held_white_levels_keep_the_decision_calibrated_and_narrow_the_amplitudes():
    """Issue 25: the pitch and roll white levels held at the measured noise (``offset``) instead of fitted.

    A second channel (26 low-band ordinates, the attitude's) whose white level is known: held, the decision keeps its
    false-positive rate on white ordinates, and with coloured ordinates the amplitudes scatter less than with the level
    fitted (the fitted level trades with them)."""
    rng = np.random.default_rng(11)
    z = _white_design(rng)
    kl = np.arange(4, 30)
    attitude = np.stack([np.full(kl.size, 2.0 / 86164), 3.0 * 86164 / (2 * np.pi * kl) ** 2 / 86164, 3e4 / kl / 86164], axis=1)
    design = np.zeros((z.shape[0] + kl.size, 4))
    design[: z.shape[0], [0, 2, 3]] = z
    design[z.shape[0] :, [1, 2, 3]] = attitude
    held = design[:, 1] * 1e-6  # the attitude channel's white level, known
    reduced = np.delete(design, 1, axis=1)
    white = np.array([1e-6, 1e-6, 0.0, 0.0])
    draws, alpha = 300, 0.05
    detected = sum(
        whittle.fit_coloured_noise(reduced, rng.exponential(design @ white), 1, alpha=alpha, offset=held).data_detected
        for _ in range(draws)
    )
    assert abs(detected / draws - alpha) < 3.5 * math.sqrt(alpha * (1 - alpha) / draws), detected
    coloured = white + np.array([0.0, 0.0, 2e-7 / z[:, 1].mean() * z[:, 0].mean(), 2e-7 / z[:, 2].mean() * z[:, 0].mean()])
    fitted, kept = [], []
    for _ in range(200):
        observed = rng.exponential(design @ coloured)
        fitted.append(whittle.fit_coloured_noise(design, observed, 2).maximum_likelihood)
        kept.append(whittle.fit_coloured_noise(reduced, observed, 1, offset=held).maximum_likelihood)
    spread_fitted, spread_held = np.std(fitted, axis=0), np.std(kept, axis=0)
    assert np.all(spread_held < spread_fitted), (spread_held, spread_fitted)
    assert np.all(np.abs(np.mean(kept, axis=0) - coloured[2:]) < 4 * spread_held / math.sqrt(200) + 0.3 * coloured[2:])


def test_loop_input_variances_of_isotropic_white_noise():
    """Equal white noise on the three axes: each loop input carries it, per attitude sample (d samples each)."""
    from stableins.estimators.system.coloured import loop_input_variances

    v = loop_input_variances(np.full(3, 4e-8), LATITUDE, 9.8, 10.0)
    np.testing.assert_allclose(v, np.full(3, 4e-8 / 9.8**2 / 10.0), rtol=1e-12)
    w = loop_input_variances(np.array([1.0, 3.0, 0.0]), 0.0, 1.0, 1.0)  # at the equator: N sees z, E and D see x, y
    np.testing.assert_allclose(w, [0.0, 2.0, 2.0], atol=1e-15)


def _three_channels(n=144):
    """z (loadings), pitch and roll (through the loop) on ``n`` bins: residual makers, white gains, kernels and mixing."""
    time, c, s = bins(n)
    count = np.full(n, 600.0)
    kernels = [spectrum.bin_process_kernel(kind, time, WIDTH) for kind in spectrum.COLOURED_KINDS]
    loads = [spectrum.axis_loadings(ch, c, s, LATITUDE) for ch in ("z", "pitch", "roll")]
    mixing = [[loads[0][:, a] for a in range(3)]] + spectrum.loop_bin_mixing(
        loop()._controllable_modes(), time, WIDTH, [loads[1], loads[2], -loads[0]]
    )
    maker = harmonic_maker(c, s, count)
    gain = [None, lambda f: 1.0 / (1.0 + f / 1e-4), lambda f: 0.5]
    channels = spectrum.ResidualChannels([np.zeros(n)] * 3, [maker] * 3, [count] * 3, gain)
    band = (3.5 * spectrum.EARTH_FREQUENCY, 30 * spectrum.EARTH_FREQUENCY)
    return channels, time, kernels, mixing, band


def test_ordinate_factors_carry_the_design_expectations_and_the_law_draws_them():
    """Issue 25: the Gaussian factors of the low band's projections give exactly the design's expectation per column
    (white per channel with its gain; each coloured kind summed over the axes), and the law's draws average to it."""
    from stableins.estimators.system.bootstrap import OrdinateLaw

    channels, time, kernels, mixing, band = _three_channels()
    design, _, n_ch = spectrum.periodogram_design(channels, time, kernels, mixing, band)
    white, coloured = spectrum.ordinate_factors(channels, time, kernels, mixing, band)
    m = design.shape[0] // n_ch

    def ordinates(factors):
        var = sum(np.einsum("kn,kn->k", f, f) for f in factors).reshape(n_ch, 2, m)
        return 0.5 * (var[:, 0] + var[:, 1]).ravel()

    for p in range(n_ch):
        np.testing.assert_allclose(ordinates([white[p]]), design[:, p], rtol=1e-10, atol=1e-14 * design[:, p].max())
    for c in range(len(kernels)):
        np.testing.assert_allclose(ordinates(coloured[c]), design[:, n_ch + c], rtol=1e-8)
    law = OrdinateLaw(lambda: (white, coloured), np.zeros((0, 3)), np.zeros(0))
    levels, amplitudes = np.array([2e-8, 1e-9, 3e-9]), np.array([1e-16, 4e-14])
    drawn = law.draw(levels, amplitudes, np.random.default_rng(4), 4000).mean(axis=0)
    expected = design @ np.concatenate([levels, amplitudes])
    # 4000 near-exponential ordinates per frequency: 1.6 % standard error each
    assert abs(np.mean(drawn / expected) - 1.0) < 0.01 and np.abs(drawn / expected - 1.0).max() < 0.08


def test_monte_carlo_p_value_has_its_level_under_a_simple_null():
    """Issue 25: records drawn from the law itself, a statistic recomputed on the law's draws: p ≤ α in α of the records."""
    from stableins.estimators.system import bootstrap

    channels, time, kernels, mixing, band = _three_channels(72)
    white, coloured = spectrum.ordinate_factors(channels, time, kernels, mixing, band)
    law = bootstrap.OrdinateLaw(lambda: (white, coloured), np.zeros((0, 3)), np.zeros(0))
    levels, amplitudes = np.array([2e-8, 1e-9, 3e-9]), np.array([3e-16, 0.0])
    m = white[0].shape[0] // 6

    def statistic(ordinates):  # the low third of the z band against the rest: sensitive to the random walk's leakage
        return float(ordinates[: m // 3].sum() / ordinates[:m].sum())

    rng = np.random.default_rng(12)
    records, alpha = 300, 0.1
    p_values = np.array(
        [
            bootstrap.monte_carlo_p_value(statistic, statistic(o), law, levels, amplitudes, record=o)[0]
            for o in law.draw(levels, amplitudes, rng, records)
        ]
    )
    assert np.all((p_values > 0) & (p_values <= 1))
    assert abs(np.mean(p_values <= alpha) - alpha) < 3.5 * math.sqrt(alpha * (1 - alpha) / records), np.mean(p_values <= alpha)


def test_decision_and_datasheet_test_draw_the_records_null_law_near_their_decision():
    """Issue 25: with the record's law, a p-value near the decision is the Monte Carlo one (``null_draws`` > 0), far from
    it the asymptotic one; a true datasheet is kept and one without slow noise is rejected on a record drawn from the law."""
    from stableins.estimators.system import bootstrap

    channels, time, kernels, mixing, band = _three_channels()
    design, _, n_ch = spectrum.periodogram_design(channels, time, kernels, mixing, band)
    white, coloured = spectrum.ordinate_factors(channels, time, kernels, mixing, band)
    law = bootstrap.OrdinateLaw(lambda: (white, coloured), np.zeros((0, 3)), np.zeros(0))
    levels = np.array([2e-8, 1e-9, 3e-9])
    rng = np.random.default_rng(21)
    draws = {}
    for record in law.draw(levels, np.zeros(2), rng, 40):
        fit = whittle.fit_coloured_noise(design, record, n_ch, law=law)
        assert (fit.null_draws > 0) == (bootstrap.ZONE[0] <= whittle.fit_coloured_noise(design, record, n_ch).p_value <= bootstrap.ZONE[1])
        draws[fit.null_draws > 0] = fit
        if len(draws) == 2:
            break
    assert set(draws) == {True, False}  # both laws met within 40 white records
    assert 0.0 < draws[True].p_value <= 1.0 and "draws of the record's null law" in draws[True].describe()
    amplitudes = np.array([2e-15, 0.0])  # a random walk the record shows clearly
    record = law.draw(levels, amplitudes, rng, 1)[0]
    true_sheet = whittle.NoisePrior(given=np.repeat(amplitudes[:, None], 3, axis=1))
    zero_sheet = whittle.NoisePrior(given=np.zeros((2, 3)))
    assert whittle.fit_coloured_noise(design, record, n_ch, law=law, prior=true_sheet).source is whittle.ColouredSource.GIVEN
    assert whittle.fit_coloured_noise(design, record, n_ch, law=law, prior=zero_sheet).source is whittle.ColouredSource.CONTRADICTED
