"""Temperature and the third harmonic in the system stage (docs/system-calibration.md §1b, §8): cheap fixed-seed checks.

The statistical campaign (false-alarm rates, rms z with sensitivities drawn from the prior) is
benchmarks/bench_system_thermal.py; here one synthetic day each, with k·σ bounds.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from system_synthetic import paper_residuals, record

from stableins import conventions as cv
from stableins.conventions import MICRO_G, STANDARD_GRAVITY
from stableins.data.chunks import ArraySource
from stableins.errormodel import MICRO_G_PER_G2, TermInputs
from stableins.errors import InputError
from stableins.estimators.system.assembly import k2_map, residuals_from_parameters
from stableins.estimators.system.loop import DampingLoop
from stableins.estimators.system.separation import COMBINED_COEFFICIENTS, combination_matrix
from stableins.estimators.system.stage import SystemOptions, run_system_stage
from stableins.estimators.system.third_harmonic import THIRD_HARMONIC_EFFECTS, explain_third_harmonic, signature

LATITUDE = math.radians(40.0)


def _reference(true, installed, meta):
    p = residuals_from_parameters(true, installed, meta.gravity)
    return combination_matrix(meta.latitude) @ np.r_[p, 0.0, 0.0]


def _thermal_record(sensitivity, temperature, *, seed=5, noise=5e-4):
    """A synthetic day whose accelerometers have a bias temperature sensitivity ``sensitivity`` [m/s²/K] per axis.

    ``temperature(t)`` is ΔT [K]; the outputs gain ``sensitivity·ΔT`` and the attitude the loop's response to it
    (the same construction as system_synthetic.record), the temperature column is 25 °C + ΔT.
    """
    true, installed = paper_residuals()
    cols, meta = record(true, installed, rate=1.0, seed=seed, noise=noise)
    t = cols["time"]
    delta = temperature(t)
    for k, axis in enumerate("xyz"):
        cols[f"f_{axis}"] = cols[f"f_{axis}"] + sensitivity[k] * delta
    step = 10.0
    tl = np.arange(0.0, t[-1] + step, step)
    sl = 0.4 + cv.EARTH_RATE * tl  # system_synthetic.record's start angle
    c_bp = cv.dcm_body_to_platform(-sl, 0.0, np.pi / 2 + meta.latitude)
    err_p = np.outer(temperature(tl), sensitivity)
    err_n = np.einsum("kji,kj->ki", c_bp, err_p) / meta.gravity
    y = DampingLoop(meta.latitude, meta.gravity, 0.5).simulate(tl, np.stack([err_n[:, 0], -err_n[:, 1]], axis=1))
    cols["pitch"] = cols["pitch"] + np.interp(t, tl, y[:, 0])
    cols["roll"] = cols["roll"] + np.interp(t, tl, y[:, 1])
    cols["temperature"] = 25.0 + delta
    # the stage determines the biases at the record's mean temperature (docs §1b)
    at_mean = dict(true, **{f"bias_{a}": true[f"bias_{a}"] + sensitivity[k] * float(np.mean(delta)) for k, a in enumerate("xyz")})
    return cols, meta, at_mean, installed


def _run(cols, meta, installed, **options):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return run_system_stage(ArraySource(cols), meta, installed, options=SystemOptions(run_filter=False, **options))


def _daily(t):
    return 2.0 * np.sin(2 * np.pi * t / 86400.0 + 0.3)


def test_daily_cycle_is_reported_not_separable_instead_of_biasing_the_coefficients():
    """5 µg/K per axis, 2 K daily cycle: without the column the coefficients are biased beyond 10σ and nothing is said;
    with it every coefficient is within 3σ of the truth or reported as not separable, and the note names the alias."""
    cols, meta, true, installed = _thermal_record([5 * MICRO_G] * 3, _daily)
    ref = _reference(true, installed, meta)
    blind = _run({k: v for k, v in cols.items() if k != "temperature"}, meta, installed)
    z_blind = np.abs(blind.combined.values - ref) / blind.combined.sigma
    assert z_blind.max() > 10
    assert any(n.startswith("no temperature column") for n in blind.notes)
    out = _run(cols, meta, installed)
    thermal = out.thermal
    assert thermal is not None and thermal.daily_fraction > 0.99 and thermal.dof == 0  # a pure daily cycle: nothing separable
    z = np.abs(out.combined.values - ref) / out.combined.sigma
    for name, value in zip(COMBINED_COEFFICIENTS, z, strict=True):
        assert value < 3 or name in thermal.not_separable, (name, value)
    assert {"x4", "phi_mean", "phi_2s"} <= set(thermal.not_separable)
    note = next(n for n in out.notes if n.startswith("temperature"))
    assert "not separable" in note and "daily temperature cycle is indistinguishable" in note and "ramp" in note


def test_non_daily_history_separates_and_detects_the_bias_sensitivity():
    """A ramp plus a 7-h cycle: the z residuals determine the bias sensitivities (flat prior): within 3σ of the truth."""
    truth = np.array([0.0, 0.0, 40 * MICRO_G])

    def history(t):
        return 4.0 * t / 86164.0 + 1.0 * np.sin(2 * np.pi * t / (7 * 3600.0))

    cols, meta, true, installed = _thermal_record(truth, history, seed=7)
    assert max(abs(true[f"bias_{a}"] - paper_residuals()[0][f"bias_{a}"]) for a in "xyz") > 5e-5  # 40 µg/K at a 2 K mean
    out = _run(cols, meta, installed, thermal_prior=(1e-3, 1e-3))
    thermal = out.thermal
    assert thermal.dof >= 3 and thermal.detected and thermal.p_value < 1e-6
    sigma = np.sqrt(np.diag(thermal.covariance))
    assert abs(thermal.estimate[2] - truth[2]) < 3 * sigma[2], (thermal.estimate[2], sigma[2])
    z = np.abs(out.combined.values - _reference(true, installed, meta)) / out.combined.sigma
    assert z.max() < 4


def test_constant_temperature_moves_nothing_and_says_so():
    """A temperature column that does not vary: the thermal part of σ is negligible, no flag, no coefficient labelled."""
    cols, meta, true, installed = _thermal_record([5 * MICRO_G] * 3, lambda t: np.zeros_like(t))
    out = _run(cols, meta, installed)
    assert not out.thermal.detected and out.thermal.not_separable == ()
    assert float(np.max(out.thermal.thermal_sigma)) < 1e-3 * float(np.min(out.thermal.data_sigma))
    assert any("negligible" in n for n in out.notes if n.startswith("temperature"))


def test_thermal_prior_option_is_validated():
    with pytest.raises(InputError, match="thermal_prior"):
        SystemOptions(thermal_prior=(0.0, 1e-6))


# ----------------------------------------------------------------------------- third harmonic
def test_k2_signatures_match_the_stages_k2_correction_and_the_closed_forms():
    """The quasi-static signature of ΔK2_x, ΔK2_y is exactly what estimate_k2 removes (k2_map), x6 = gK/4, x7 = −gK/4."""
    g = 9.8
    sig = {name: signature(d, axis, LATITUDE, g) for name, axis, d, _ in THIRD_HARMONIC_EFFECTS}
    m = k2_map(LATITUDE, estimate_k2=True)
    np.testing.assert_allclose(m @ sig["K2_x"], 0.0, atol=1e-12)
    np.testing.assert_allclose(m @ sig["K2_y"], 0.0, atol=1e-12)
    assert sig["K2_x"][5] == pytest.approx(g / 4) and sig["K2_y"][6] == pytest.approx(-g / 4)
    assert sig["Kcc_xxy"][6] == pytest.approx(g / 4) and sig["Kcc_yxy"][5] == pytest.approx(-g / 4)
    # on a polar platform u_x² + u_y² = cos²L: Kcq_yx is −K2_y plus a bias, exactly
    np.testing.assert_allclose(sig["Kcq_yx"][np.r_[5:7]], -sig["K2_y"][np.r_[5:7]], atol=1e-12)


def test_third_harmonic_effects_follow_the_library_regressors():
    """The stage's products are the library's regressors (discovery.catalogue) on f^p = g u."""
    from stableins.discovery.library import LIBRARY

    rng = np.random.default_rng(3)
    u = rng.normal(size=(50, 3))
    for name, axis, delta, _ in THIRD_HARMONIC_EFFECTS:
        if name.startswith("K2_"):
            continue
        term = LIBRARY[name].term
        output = term.regressor(TermInputs(specific_force=STANDARD_GRAVITY * u))
        np.testing.assert_allclose(output[:, axis] / STANDARD_GRAVITY, delta(u, STANDARD_GRAVITY), rtol=1e-12)


def _synthetic_v(effect, size, seed=0, sigma=3e-7):
    """``v`` of a record whose standard-model coefficients are zero plus ``size`` of ``effect``, white σ per coefficient."""
    g = 9.8
    column = next(signature(d, a, LATITUDE, g) for n, a, d, _ in THIRD_HARMONIC_EFFECTS if n == effect)
    rng = np.random.default_rng(seed)
    return size * column + rng.normal(0.0, sigma, 17), np.eye(17) * sigma**2


def test_cross_coupling_is_named_and_k2_not_advised():
    """A 10 µg/g² Kcc_xxy: the record rejects a residual K2, names Kcc_xxy and does not advise the K2 estimation."""
    v, cov = _synthetic_v("Kcc_xxy", 10 * MICRO_G_PER_G2)
    third = explain_third_harmonic(v, cov, LATITUDE, 9.8)
    assert third.significant == (False, True) and third.scale == 1.0
    assert third.accepted("x7") == ("Kcc_xxy",)
    assert not next(h for h in third.hypotheses if h.terms == ("K2_x", "K2_y")).consistent
    note = third.note(estimate_k2=False, parameter="estimate_k2=True")
    assert "Kcc_xxy" in note and "do not use the K2 estimation" in note and "rerun with the K2" not in note
    assert "does NOT explain" in third.note(estimate_k2=True, parameter="estimate_k2=True")


def test_residual_k2_is_named_with_its_exact_alias_and_no_correction_advised():
    """A residual ΔK2_y has an exact alias on a polar platform (Kcq_yx) and a near one (Ksa_y): all named, nothing advised."""
    v, cov = _synthetic_v("K2_y", 20 * MICRO_G_PER_G2)
    third = explain_third_harmonic(v, cov, LATITUDE, 9.8)
    assert {"K2_y", "Kcq_yx"} <= set(third.accepted("x7")) and "Kcc_xxy" not in third.accepted("x7")
    assert not third.k2_alone
    note = third.note(estimate_k2=False, parameter="estimate_k2=True")
    assert "cannot tell them apart" in note and "Kcq_yx" in note and "rerun with the K2" not in note


def test_two_causes_one_per_part_and_an_unmodelled_disturbance():
    """x6 from a residual K2_x, x7 from Kcc_xxy, and an attitude disturbance no hypothesis has: each part is named, relatively."""
    v6, cov = _synthetic_v("K2_x", 15 * MICRO_G_PER_G2, seed=1)
    v7, _ = _synthetic_v("Kcc_xxy", 10 * MICRO_G_PER_G2, seed=2)
    v = v6 + v7 - np.random.default_rng(2).normal(0.0, 3e-7, 17)  # one draw of noise
    v[8] += 5e-6  # θ1c moved by something else (e.g. an unknown gyro drift)
    third = explain_third_harmonic(v, cov, LATITUDE, 9.8)
    assert third.significant == (True, True) and third.scale > 1.0
    assert "K2_x" in third.accepted("x6") and "Kcc_xxy" in third.accepted("x7")
    assert "relative" in third.note(estimate_k2=False, parameter="p")


def test_no_third_harmonic_no_note():
    v, cov = _synthetic_v("K2_x", 0.0)
    third = explain_third_harmonic(v, cov, LATITUDE, 9.8)
    assert third.significant == (False, False) and third.note(estimate_k2=False, parameter="p") is None


def test_no_third_harmonic_with_k2_estimation_says_so_without_an_empty_list():
    """--estimate-k2 on a record with no third harmonic: the note says it is within 3σ, never "as well: ." (issue 25)."""
    v, cov = _synthetic_v("K2_x", 0.0)
    third = explain_third_harmonic(v, cov, LATITUDE, 9.8)
    note = third.note(estimate_k2=True, parameter="estimate_k2=True")
    assert note is not None and "within 3σ" in note and "as well: ." not in note and ": ." not in note


def _combinations(out):
    return {name: (value, sigma, ok) for name, (value, sigma, ok) in out.separation.combinations.items()}


def test_daily_cycle_grown_combinations_are_not_determined_and_the_device_prior_restores_them():
    """Issue 25: a combination whose σ the daily cycle grew more than 10× is not called determined; with the sensitivities
    of a device-level thermal test in the record (value and σ) every combination is determined again and within 3σ and
    1e-6 rad of the same record without the cycle."""
    sensitivity = [5 * MICRO_G] * 3
    still, still_meta, _, still_installed = _thermal_record(sensitivity, lambda t: np.zeros_like(t))
    reference = _combinations(_run(still, still_meta, still_installed))
    cols, meta, _, installed = _thermal_record(sensitivity, lambda t: 0.5 * _daily(t))  # 2 K peak to peak
    default = _run(cols, meta, installed)
    grown = [n for n, (_, s, ok) in _combinations(default).items() if not ok and s > 10 * reference[n][1]]
    assert grown and any(n.startswith("not determined by these data") for n in default.notes)
    for n, (_, s, ok) in _combinations(default).items():
        assert not ok or s <= 10 * reference[n][1]
    prior = {**installed, **{f"Kt_bias_{a}": 5 * MICRO_G for a in "xyz"}}
    covariance = {(f"Kt_bias_{a}", f"Kt_bias_{a}"): (0.3 * MICRO_G) ** 2 for a in "xyz"}
    covariance |= {(f"Kt_sf_{a}", f"Kt_sf_{a}"): (0.3 * 1e-6) ** 2 for a in "xyz"}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        informed = run_system_stage(ArraySource(cols), meta, prior, covariance, options=SystemOptions(run_filter=False))
    combos = _combinations(informed)
    assert all(ok for _, _, ok in combos.values())
    for name, (value, sigma, _) in combos.items():
        shift = abs(value - reference[name][0])
        assert shift < 1e-6 and shift < 3 * sigma, (name, shift, sigma)


def test_separable_directions_leave_out_what_z_does_not_reach():
    """Issue 25: two sensitivities that enter ``z`` as the same column (``k_z`` and ``s_z``: ΔT) give a direction ``z``
    does not reach; given the regressors it is not separable, whatever round-off the information matrices carry."""
    from stableins.estimators.system.thermal import separable_directions

    rng = np.random.default_rng(4)
    n = 144
    t = np.linspace(0.0, 1.0, n)
    cols = np.stack([t, np.sin(7 * t), np.cos(5 * t), t**2, np.sin(11 * t), 0.0 * t], axis=1)
    cols[:, 5] = 0.4 * cols[:, 3] * (1 + 1e-6 * rng.standard_normal(n))  # reached only to 1e-6: not separable
    noise = np.diag(rng.uniform(0.5, 2.0, 6)) * 1e-7  # round-off-like information along every direction
    info = cols.T @ cols + noise
    gradient = cols.T @ rng.standard_normal(n)
    directions, _, dof = separable_directions(info, info, gradient, regressors=cols)
    assert dof == 5, dof
    null = np.zeros(6)
    null[3], null[5] = 0.4, -1.0
    null /= np.linalg.norm(null)
    coef = np.linalg.lstsq(directions.T, null, rcond=None)[0]
    assert np.linalg.norm(directions.T @ coef - null) > 0.1  # the unreached direction is not in their span
    _, _, dof_without = separable_directions(info, info, gradient)
    assert dof_without == 6  # what the information matrices alone let through


@pytest.mark.parametrize("case", ["daily", "ramp"])
def test_type_b_re_runs_that_reuse_the_stage_equal_whole_re_runs(case):
    """The Type B re-runs take the loop-independent steps from the stage's run and, when its thermal test removed nothing
    (a daily cycle: nothing separable), hold that outcome: their sensitivities are those of whole re-runs of the stage."""
    from stableins.estimators.system.sensitivity import system_sensitivities

    if case == "daily":
        cols, meta, _, installed = _thermal_record([5 * MICRO_G] * 3, _daily)
        options = SystemOptions(run_filter=False)
    else:
        cols, meta, _, installed = _thermal_record(
            [0.0, 0.0, 40 * MICRO_G], lambda t: 4.0 * t / 86164.0 + 1.0 * np.sin(2 * np.pi * t / (7 * 3600.0)), seed=7
        )
        options = SystemOptions(run_filter=False, thermal_prior=(1e-3, 1e-3))
    source = ArraySource(cols)
    base = _run(cols, meta, installed, **{k: getattr(options, k) for k in ("thermal_prior",)})
    assert base.held is not None and base.held.thermal_removed is (case == "ramp")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        reused = system_sensitivities(source, meta, installed, None, options, base=base)
        whole = system_sensitivities(source, meta, installed, None, options, base=base, rerun=True)
    assert [s.input for s in reused] == [s.input for s in whole] and any(s.input.startswith("damping_loop") for s in reused)
    for a, b in zip(reused, whole, strict=True):
        assert np.abs(b.gradient).max() > 0
        np.testing.assert_allclose(a.gradient, b.gradient, rtol=0, atol=1e-9 * np.abs(b.gradient).max(), err_msg=a.input)
