"""The navigation budget (issue 16 part 5, Zhang et al. 2023 error propagation): physics, totals, CLI, certificate.

Cheap versions of ``benchmarks/bench_navigation_budget.py``: one day against the truth simulator at 0.1 Hz (the
benchmark runs five days at 1 Hz).  Everything is deterministic (noise off), so the bounds are the model's
agreement, not statistics.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import report_fixtures as rf
from scipy.linalg import expm

from stableins import cli
from stableins.conventions import ARCSEC, DEG_PER_HOUR, EARTH_RATE, MICRO_G, PPM, SIDEREAL_DAY
from stableins.errormodel import MICRO_G_PER_G2, ErrorModel
from stableins.navigation import CalibrationTerms, NavigationScenario, Quantity, navigation_budget, navigation_errors
from stableins.navigation.propagation import Propagator, harmonics_of, phase_grid
from stableins.navigation.sources import accelerometer_forcing, drift_forcing
from stableins.simulator.noise import NoiseSettings
from stableins.simulator.system import simulate_system
from stableins.simulator.truth import DEFAULT_RESIDUAL, Truth

LATITUDE = math.radians(40.0)


@pytest.fixture(scope="module")
def quiet_truth() -> Truth:
    return Truth.draw(1, noise=NoiseSettings.quiet(), residual=dict.fromkeys(DEFAULT_RESIDUAL, 0.0))


def _truth_with(base: Truth, term_id: str, amount: float) -> Truth:
    if term_id.startswith("gyro_drift_"):
        return base.with_changes(gyro_drift={term_id[-1]: amount})
    installed = dict(base.installed_calibration)
    installed[term_id] = base.parameters[term_id] - amount
    return base.with_changes(installed_calibration=installed)


@pytest.mark.parametrize(
    ("term_id", "amount"),
    [
        ("bias_x", 5 * MICRO_G),
        ("sf_z", 5 * PPM),
        ("beta_zy", 3 * ARCSEC),
        ("K2_x", 5 * MICRO_G_PER_G2),
        ("gyro_drift_z", 0.001 * DEG_PER_HOUR),
        ("gyro_drift_x", 0.001 * DEG_PER_HOUR),
        ("theta20", 2 * ARCSEC),
    ],
)
def test_single_sources_match_the_truth_simulator_within_one_percent_of_the_peak(quiet_truth, term_id, amount):
    """Acceptance (cheap): one day, simulator at 0.1 Hz (its ZOH costs up to 0.7 % here; 0.07 % at 1 Hz)."""
    rate, step = 0.1, 60.0
    truth = _truth_with(quiet_truth, term_id, amount)
    record = simulate_system(truth, 86400.0, rate=rate)
    predicted = navigation_errors(
        ErrorModel.standard(nonlinear=True),
        dict(quiet_truth.installed_calibration),
        {term_id: amount},
        NavigationScenario.from_site(truth.site),
        duration=86400.0,
        step=step,
    )
    index = np.arange(0, len(record["time"]), int(step * rate))[: len(predicted.time)]
    heading = (record["heading"] + np.pi) % (2 * np.pi) - np.pi
    simulated = {
        Quantity.VELOCITY_NORTH: record["velocity_north"],
        Quantity.VELOCITY_EAST: record["velocity_east"],
        Quantity.VELOCITY_DOWN: record["velocity_down"],
        Quantity.PITCH: record["pitch"],
        Quantity.ROLL: record["roll"],
        Quantity.HEADING: heading,
    }
    compared = 0
    for quantity, series in simulated.items():
        peak = np.max(np.abs(series))
        error = np.max(np.abs(series[index] - predicted[quantity][: len(index)]))
        floor = 1e-10 if quantity in (Quantity.PITCH, Quantity.ROLL, Quantity.HEADING) else 1e-9
        if peak > floor:
            assert error <= 0.01 * peak, f"{term_id} {quantity}: {error:.3e} against peak {peak:.3e}"
            compared += 1
        else:
            assert np.max(np.abs(predicted[quantity])) <= 10 * floor  # zero in both
    assert compared >= 2


def test_polar_drift_gives_an_east_velocity_of_R_cosL_eps_and_a_longitude_rate_of_eps():
    """Derived in docs/navigation-budget.md: the constant part of δv_E is exactly R cosL ε (any damping)."""
    eps = 0.001 * DEG_PER_HOUR
    for zeta in (0.5, 0.0):
        scenario = NavigationScenario(LATITUDE, 9.8017, zeta=zeta, vertical_gains=(2 / 300, 2 / 300**2 + 2 * 9.8017 / 6371e3, 1 / 300**3))
        errors = navigation_errors(
            ErrorModel.standard(), {}, {"gyro_drift_z": eps}, scenario, duration=3 * SIDEREAL_DAY, step=SIDEREAL_DAY / 4000
        )
        day2 = (errors.time >= SIDEREAL_DAY) & (errors.time < 2 * SIDEREAL_DAY)
        expected = scenario.radius * math.cos(LATITUDE) * eps
        assert expected == pytest.approx(0.023661, abs=5e-7)
        tolerance = 1e-9 if zeta else 2e-3  # undamped: the Schuler transient does not average out over one day exactly
        assert np.mean(errors[Quantity.VELOCITY_EAST][day2]) == pytest.approx(expected, rel=tolerance)
        longitude = errors[Quantity.POSITION_EAST] / (scenario.radius * math.cos(LATITUDE))
        slope = (longitude[-1] - longitude[np.argmax(errors.time >= SIDEREAL_DAY)]) / (errors.time[-1] - SIDEREAL_DAY)
        assert slope == pytest.approx(eps, rel=tolerance)


def test_a_polar_g_sensitivity_is_a_polar_drift_of_dg_g_sinl_within_one_percent():
    """On a static base Dg_zz is a polar drift ε = Dg_zz g sinL: the budget propagates it (it once said "does not act on
    navigation"), and an independent propagation — the longitude error of a polar drift, R cosL ε t (the derivation
    the test above checks) — agrees within 1 %."""
    from stableins.conventions import DEG_PER_HOUR_PER_G

    gravity, duration = 9.8017, 5 * 86400.0
    sigma = 5.7e-6 * DEG_PER_HOUR_PER_G  # the σ(Dg_zz)
    scenario = NavigationScenario(LATITUDE, gravity, zeta=0.5, vertical_gains=(2 / 300, 2 / 300**2 + 2 * gravity / 6371e3, 1 / 300**3))
    model = ErrorModel.standard()  # the gyro terms are known to the budget by id (stableins.terms.known_terms)
    ids = ("Dg_zz",)
    budget = navigation_budget(CalibrationTerms(model, {}, ids, np.array([[sigma**2]])), scenario, duration=duration, step=120.0)
    eps = sigma * gravity * math.sin(LATITUDE)  # the polar drift it is
    expected = scenario.radius * math.cos(LATITUDE) * eps * duration  # m: the longitude error of a polar drift after 5 days
    assert 35.0 < expected < 39.0  # the 37 m
    assert budget.term("Dg_zz").summary.position.final == pytest.approx(expected, rel=0.01)
    # the same as a given polar drift ε through the budget's own drift path
    drift = navigation_errors(model, {}, {"gyro_drift_z": eps}, scenario, duration=duration, step=120.0)
    g_sensitive = navigation_errors(model, {}, {"Dg_zz": sigma}, scenario, duration=duration, step=120.0)
    np.testing.assert_allclose(g_sensitive[Quantity.POSITION_EAST], drift[Quantity.POSITION_EAST], rtol=1e-6, atol=1e-9)
    # across the polar axis the specific force turns with the Earth: a modulated drift, far smaller than the polar one
    across = navigation_budget(CalibrationTerms(model, {}, ("Dg_xx",), np.array([[sigma**2]])), scenario, duration=duration, step=120.0)
    assert across.term("Dg_xx").summary.position.final < 0.05 * expected


def test_budget_refuses_a_duration_without_a_unit(records, capsys):
    assert cli.main(["budget", str(records / "a.json"), "--duration", "5"]) == 2
    err = capsys.readouterr().err
    assert "--duration" in err and "5d" in err and "unit" in err
    assert cli.main(["budget", str(records / "a.json"), "--duration", "5d", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)


def test_navigation_frame_forcing_is_the_harmonic_model_of_the_system_docs():
    """Δf^n/g = (−sinL(cosS δx + sinS δy) + cosL δz, −sinS δx + cosS δy, −u·δ) with δ of docs/system-calibration.md §0."""
    scenario = NavigationScenario(LATITUDE, 9.80)
    model = ErrorModel.standard()
    values = {t.id: t.reference for t in model}
    sl, cl = math.sin(LATITUDE), math.cos(LATITUDE)
    s = np.linspace(0, 2 * np.pi, 7)
    cases = {
        "bias_x": np.stack([np.ones_like(s) / 9.80, 0 * s, 0 * s], 1),
        "beta_xz": np.stack([cl * np.sin(s), 0 * s, 0 * s], 1),
        "sf_y": np.stack([0 * s, -cl * np.sin(s), 0 * s], 1),
        "beta_zy": np.stack([0 * s, 0 * s, cl * np.cos(s)], 1),
    }
    for term_id, delta in cases.items():
        forcing = accelerometer_forcing(model, values, model[term_id], scenario).forcing
        df = np.real(np.exp(1j * np.outer(s, np.arange(forcing.shape[0]))) @ forcing)[:, :3] / 9.80
        u = np.stack([np.cos(s) * cl, np.sin(s) * cl, np.full_like(s, sl)], 1)
        north = -sl * (np.cos(s) * delta[:, 0] + np.sin(s) * delta[:, 1]) + cl * delta[:, 2]
        east = -np.sin(s) * delta[:, 0] + np.cos(s) * delta[:, 1]
        down = -np.sum(u * delta, axis=1)
        np.testing.assert_allclose(df, np.stack([north, east, down], 1), atol=1e-12, err_msg=term_id)


def test_propagation_is_the_exact_solution_also_at_the_earth_rate_resonance():
    """Against the matrix exponential of the system augmented with the harmonic oscillator (an independent exact solution)."""
    scenario = NavigationScenario(LATITUDE, 9.8017, zeta=0.3, vertical_gains=(2 / 300, 2 / 300**2 + 2 * 9.8017 / 6371e3, 1 / 300**3))
    forcing = drift_forcing(0, scenario).forcing  # equatorial drift: harmonic 1 drives the undamped ±jΩ mode
    A, B = scenario.matrices()
    assert np.min(np.abs(np.linalg.eigvals(A) - 1j * EARTH_RATE)) < 1e-9  # the resonance is there
    step, count = 600.0, 144
    states = Propagator.build(scenario, step, forcing.shape[0] - 1).run(forcing[:, :, None], count)[:, :, 0]
    # u(t) = U0 + Re(U1) cos Ωt − Im(U1) sin Ωt: oscillator state w = (1, cos Ωt, sin Ωt)
    n = A.shape[0]
    aug = np.zeros((n + 3, n + 3))
    aug[:n, :n] = A
    aug[:n, n] = B @ forcing[0].real
    aug[:n, n + 1] = B @ forcing[1].real
    aug[:n, n + 2] = -B @ forcing[1].imag
    aug[n + 1, n + 2], aug[n + 2, n + 1] = -EARTH_RATE, EARTH_RATE
    for k in (1, 50, 144):
        exact = (expm(aug * k * step) @ np.r_[np.zeros(n), 1.0, 1.0, 0.0])[:n]
        np.testing.assert_allclose(states[k], exact, rtol=1e-7, atol=1e-9 * np.max(np.abs(exact)))
    assert abs(states[count, 6]) > 5 * abs(states[count // 4, 6])  # heading error grows (t·sin Ωt), not bounded


def test_harmonics_are_exact_for_a_trigonometric_polynomial():
    theta = phase_grid()
    samples = 0.3 + 2 * np.cos(theta) - 0.5 * np.sin(3 * theta)
    h = harmonics_of(samples)
    assert h[0] == pytest.approx(0.3) and h[1] == pytest.approx(2.0) and h[3] == pytest.approx(0.5j)


def _diagonal_budget(covariance_scale: float = 1.0, correlation: float = 0.0):
    model = ErrorModel.standard()
    ids = ["bias_x", "beta_xy", "sf_z"]
    sigma = np.array([5 * MICRO_G, 3 * ARCSEC, 5 * PPM]) * covariance_scale
    cov = np.diag(sigma**2)
    cov[0, 1] = cov[1, 0] = correlation * sigma[0] * sigma[1]
    values = {t.id: t.reference for t in model}
    scenario = NavigationScenario(LATITUDE, 9.8017, zeta=0.5)
    return model, values, ids, sigma, cov, scenario


def test_rss_equals_total_without_correlations_and_the_total_uses_them():
    model, values, ids, sigma, cov, scenario = _diagonal_budget()
    budget = navigation_budget(CalibrationTerms(model, values, tuple(ids), cov), scenario, duration=86400.0, step=120.0)
    np.testing.assert_allclose(budget.total_series, budget.rss_series, rtol=1e-12, atol=0)
    assert [t.id for t in budget.terms][0] in ids and len(budget.terms) == 3
    # perfectly correlated bias_x and beta_xy: the total is the error of both residuals together
    model, values, ids, sigma, cov, scenario = _diagonal_budget(correlation=1.0)
    correlated = navigation_budget(CalibrationTerms(model, values, tuple(ids), cov), scenario, duration=86400.0, step=120.0)
    joint = navigation_errors(model, values, {"bias_x": sigma[0], "beta_xy": sigma[1]}, scenario, duration=86400.0, step=120.0)
    alone = navigation_errors(model, values, {"sf_z": sigma[2]}, scenario, duration=86400.0, step=120.0)
    for q in (Quantity.POSITION_NORTH, Quantity.VELOCITY_EAST, Quantity.PITCH):
        expected = np.sqrt(joint[q] ** 2 + alone[q] ** 2)
        got = correlated.total_series[:, list(Quantity).index(q)]
        np.testing.assert_allclose(got, expected, rtol=1e-9, atol=1e-12 * np.max(expected))
    assert correlated.total.position.peak != pytest.approx(correlated.rss.position.peak, rel=1e-3)


def test_a_budget_scales_linearly_with_sigma():
    model, values, ids, sigma, cov, scenario = _diagonal_budget()
    one = navigation_budget(CalibrationTerms(model, values, tuple(ids), cov), scenario, duration=43200.0, step=120.0)
    two = navigation_budget(CalibrationTerms(model, values, tuple(ids), 4 * cov), scenario, duration=43200.0, step=120.0)
    assert two.total.position.peak == pytest.approx(2 * one.total.position.peak, rel=1e-12)
    assert two.term("bias_x").summary.heading.final == pytest.approx(2 * one.term("bias_x").summary.heading.final, rel=1e-12)


@pytest.fixture(scope="module")
def records(tmp_path_factory):
    folder = tmp_path_factory.mktemp("navbudget")
    a = folder / "a.json"
    b = folder / "b.json"
    a.write_text(json.dumps(rf.record(rf.fit(1))))
    b.write_text(json.dumps(rf.record(rf.fit(2, noise_ug=1.0))))
    return folder


def test_cli_budget_table_json_compare_and_plot(records, capsys):
    assert cli.main(["budget", str(records / "a.json"), "--duration", "12h", "--drift", "0.001", "0.001", "0.001", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    ids = [t["id"] for t in doc["terms"]]
    assert ids[0].startswith("gyro_drift") and doc["drift"] == "given"
    assert doc["scenario"]["latitude_deg"] == pytest.approx(45.7733) and doc["scenario"]["zeta"] == 0.0  # the site's: no damping
    assert doc["total"]["position"]["peak"] >= max(t["errors"]["position"]["peak"] for t in doc["terms"]) * 0.999
    assert cli.main(["budget", str(records / "a.json"), "--duration", "12h", "--latitude", "30", "--damping", "0.7"]) == 0
    text = capsys.readouterr().out
    assert "30.0000° N, damping ζ = 0.7" in text and "RSS of the terms" in text and "no gyro drift" in text
    from stableins.records import CalibrationRecord
    from stableins.reporting.navigation import record_navigation_budget

    budget = record_navigation_budget(CalibrationRecord.load(records / "a.json"), duration=43200.0)
    assert "<table" in budget._repr_html_() and "total (correlated)" in budget._repr_html_()
    assert len(repr(budget).splitlines()) == 1
    assert cli.main(["budget", str(records / "a.json"), "--duration", "12h", "--compare", str(records / "b.json"), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    a = {t["id"]: t for t in doc["base"]["terms"]}
    b = {t["id"]: t for t in doc["other"]["terms"]}
    diff = doc["difference"]["terms"]["bias_x"]["position"]["peak"]
    assert diff == pytest.approx(b["bias_x"]["errors"]["position"]["peak"] - a["bias_x"]["errors"]["position"]["peak"])
    assert b["bias_x"]["sigma"] < a["bias_x"]["sigma"]  # 1 µg of noise instead of 3: a smaller σ, a smaller error
    assert diff < 0
    assert doc["labels"] == ["a.json", "b.json"]
    plot = records / "budget.png"
    assert cli.main(["budget", str(records / "a.json"), "--duration", "1d", "--plot", str(plot)]) == 0
    capsys.readouterr()
    assert plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_cli_bad_input_exits_2_and_writes_nothing(records, tmp_path, capsys):
    plot = tmp_path / "budget.gif"
    assert cli.main(["budget", str(records / "a.json"), "--plot", str(plot)]) == 2
    assert "--plot" in capsys.readouterr().err and not plot.exists()
    assert not list(tmp_path.iterdir())
    broken = tmp_path / "broken.json"
    broken.write_text('{"format": "stableins calibration record"')
    assert cli.main(["budget", str(broken)]) == 2
    assert "broken.json" in capsys.readouterr().err
    assert cli.main(["budget", str(records / "a.json"), "--damping", "-1"]) == 2
    assert "--damping: -1 is out of range" in capsys.readouterr().err
    assert cli.main(["budget", str(records / "a.json"), "--latitude", "95"]) == 2
    assert "--latitude: 95 is out of range" in capsys.readouterr().err
    capsys.readouterr()


def test_certificate_section_shows_the_budget_of_the_record(records):
    from stableins.records import CalibrationRecord
    from stableins.reporting.navigation import CERTIFICATE_DURATION, navigation_section, record_navigation_budget

    record = CalibrationRecord.load(records / "a.json")
    budget = record_navigation_budget(record, duration=CERTIFICATE_DURATION)

    class Context:  # the section reads only the record
        pass

    ctx = Context()
    ctx.record = record
    flowables = navigation_section(ctx)  # type: ignore[arg-type]
    text = " ".join(getattr(f, "text", "") for f in flowables)
    assert "What this calibration means for navigation" in text
    assert f"{float(f'{budget.total.position.peak:.3g}'):g}" in text.replace("−", "-")
    assert "no gyro drift" in text
