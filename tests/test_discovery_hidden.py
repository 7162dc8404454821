"""Hidden effects in the independent truth simulator: ranked first, added, χ²_ν back to the noise floor.

Data: the device-fine positions (Wu et al. Table 1, 18 positions) run four times, alternately
forward and backward (69 dwells of 20 s at 10 Hz), by :mod:`stableins.simulator`, with one
effect injected and the standard model (with zero offsets) fitted.  Many short dwells give
ν ≈ 190, so the band 0.8 ≤ χ²_ν ≤ 1.3 spans about −2σ … +3σ (σ ≈ sqrt(2/ν) plus the scatter of
the noise-floor estimate).  Noise: the simulator's quartz white noise, quantization and angle
noise; its slow components (bias instability, acceleration random walk) are switched off
except in ``test_realistic_noise`` because the simulator generates them slowly and because
a within-dwell noise floor cannot see them (see the false-alarm test).  Temperature effects get a
temperature profile that is not linear in time.
"""

import dataclasses

import numpy as np
import pytest

from stableins.conventions import ARCSEC
from stableins.discovery.dwells import dwell_means
from stableins.discovery.history import Discovery
from stableins.discovery.library import LIBRARY
from stableins.discovery.problem import DwellProblem
from stableins.errormodel import ErrorModel
from stableins.procedures import definition as procedures
from stableins.samples import SampleBlock
from stableins.simulator import device as sim_device
from stableins.simulator.noise import NoiseSettings, TemperatureProfile
from stableins.simulator.truth import SimulatedSite, Truth

#: Injected magnitude per effect family [engineering unit of the library term].
MAGNITUDE = {"K3": 100, "Koq": 100, "Ksa": 100, "Kcq": 60, "Kcc": 60, "Kt_bias": 30, "Kt_sf": 60, "Kd_bias": 60, "Kh": 25}
MAGNITUDE.update({"nonorth": 30, "tilt": 30, "ang1": 10})
SEED = 3


def _magnitude(effect_id):
    family = next(k for k in sorted(MAGNITUDE, key=len, reverse=True) if effect_id.startswith(k))
    return MAGNITUDE[family] * LIBRARY[effect_id].term.scale


def simulate(effects, seed=SEED, temperature=False, slow_noise=False, passes=4):
    noise = NoiseSettings.quartz()
    if not slow_noise:
        noise = dataclasses.replace(noise, bias_instability=0.0, acceleration_random_walk=0.0)
    if temperature:
        noise = dataclasses.replace(noise, temperature=TemperatureProfile(ramp=1 / 1800, amplitude=1.0, period=3000.0, sensor_noise=0.01))
    truth = Truth.draw(seed, effects=effects, site=SimulatedSite(sample_rate=10.0), noise=noise)
    commands = [s.command for s in procedures.load_procedure("device-fine").steps]
    sequence = list(commands)
    for k in range(1, passes):
        sequence += (commands[::-1] if k % 2 else commands)[1:]
    c = sim_device.simulate_dwells(truth, sequence, dwell=20.0, settle=3.0, rate=10.0, seed=seed)
    samples = SampleBlock(
        c["time"],
        np.stack([c["f_x"], c["f_y"], c["f_z"]], -1),
        np.stack([c["angle_platform"], c["angle_inner"], c["angle_middle"]], -1),
        c["temperature"],
    )
    dwells = dwell_means(samples, c["position"], c["time_since_command"], site=truth.site)
    return dwells, truth


SEPARABLE = [
    i
    for i in LIBRARY.ids
    if i.split("_")[0] in ("K3", "Koq", "Ksa", "Kcq", "Kcc", "nonorth", "ang1") or i.startswith(("Kt_", "Kd_")) or i == "tilt_north"
]


@pytest.mark.parametrize("effect_id", SEPARABLE)
def test_hidden_effect_is_ranked_first_and_adding_it_restores_chi2(effect_id):
    value = _magnitude(effect_id)
    dwells, _ = simulate({effect_id: value}, temperature=effect_id.startswith("Kt_"))
    session = Discovery(DwellProblem(dwells), ErrorModel.standard(gimbals=True))
    ranking = session.rank(refit_top=2, propose=False)
    best = ranking.best
    assert best.flagged
    # first, or tied with a candidate the data cannot tell apart (reported as such)
    assert best.id == effect_id or effect_id in best.confused_with, ranking.report()
    session.add(effect_id)
    assert 0.8 <= session.result.chi2_red <= 1.3, session.history.report()
    estimate, sigma, _ = session.result[effect_id]
    assert abs(estimate - value) < 5 * sigma
    assert session.history[1].bic < session.history[0].bic


def test_indistinguishable_pairs_are_reported():
    dwells, _ = simulate({"Kcq_xy": _magnitude("Kcq_xy"), "K3_z": _magnitude("K3_z")})
    ranking = Discovery(DwellProblem(dwells), ErrorModel.standard(gimbals=True)).rank(refit_top=0)
    # |f| = g at every static position: f_y² and f_z² differ only by terms of the model
    assert "Kcq_xz" in ranking["Kcq_xy"].confused_with
    # on 0, ±45°, ±90° inputs f³ and f|f| leave the same pattern after the scale factor
    assert "Koq_z" in ranking["K3_z"].confused_with


@pytest.mark.parametrize("axis", "xyz")
def test_hysteresis_is_ranked_first_and_adding_it_restores_chi2(axis):
    effect_id = f"Kh_{axis}"
    value = _magnitude(effect_id)
    dwells, _ = simulate({effect_id: value})
    session = Discovery(DwellProblem(dwells), ErrorModel.standard(gimbals=True))
    ranking = session.rank(refit_top=1, propose=False)
    assert ranking.best.id == effect_id and ranking.best.flagged
    session.add(effect_id)
    assert 0.8 <= session.result.chi2_red <= 1.3, session.history.report()
    estimate, sigma, _ = session.result[effect_id]
    assert abs(estimate - value) < 5 * sigma
    assert session.history[1].bic < session.history[0].bic


def test_hysteresis_state_is_defined_alike_in_simulator_and_discovery():
    """Same threshold, same memory, same initial state (0 until a slew moves the input beyond it)."""
    from stableins.discovery.dwells import HYSTERESIS_THRESHOLD, slew_directions
    from stableins.simulator import effects as sim_effects

    assert sim_effects.HYSTERESIS_THRESHOLD == HYSTERESIS_THRESHOLD == 1e-2
    rng = np.random.default_rng(7)
    # steps of g/√2 and g size mixed with sub-threshold (arcsecond-level), near- and above-threshold changes
    sizes = rng.choice([1e-4, 0.5e-2, 2e-2, 6.9, 9.8], size=(60, 3))
    steps = sizes * rng.choice([-1.0, 1.0], size=(60, 3))
    steps[0] = [1e-4, 6.9, -0.5e-2]  # first slew: only y travels beyond the threshold
    initial = np.array([0.0, 0.0, -9.8])
    f = initial + np.cumsum(steps, axis=0)
    state = np.zeros(3)
    simulated = []
    for before, after in zip(np.vstack([initial, f[:-1]]), f):
        state = sim_effects.hysteresis_state(state, after - before)
        simulated.append(state)
    discovered = slew_directions(f, initial)
    np.testing.assert_array_equal(np.array(simulated), discovered)
    np.testing.assert_array_equal(discovered[0], [0.0, 1.0, 0.0])  # initial state 0, set only by a travelling input
    assert np.any(np.diff(discovered, axis=0) != 0)
    # a sub-threshold change keeps the state; the same change above the threshold sets it
    assert sim_effects.hysteresis_state(np.array([1.0]), np.array([-0.9e-2]))[0] == 1.0
    assert sim_effects.hysteresis_state(np.array([1.0]), np.array([-1.1e-2]))[0] == -1.0


def test_base_tilt_east_is_reported_unseparable():
    dwells, _ = simulate({"tilt_east": _magnitude("tilt_east")})
    session = Discovery(DwellProblem(dwells), ErrorModel.standard(gimbals=True))
    ranking = session.rank(refit_top=0)
    tilt = ranking["tilt_east"]
    assert not tilt.identifiable and tilt.excited
    assert tilt.aliases[0][0] == "theta30" and tilt.aliases[0][1] == pytest.approx(1.0, abs=1e-3)
    assert not ranking.flagged
    assert "not separable" in ranking.report() and "tilt_east" in ranking.report()
    assert "azimuth_180" in tilt.advice  # tested numerically: turning the base separates it


def test_base_azimuth_error_is_not_excited_by_gravity():
    dwells, _ = simulate({"azimuth_error": 60 * ARCSEC}, passes=2)
    session = Discovery(DwellProblem(dwells), ErrorModel.standard(gimbals=True))
    assert abs(session.result.chi2_red - 1) < 4 * np.sqrt(2 / session.result.dof)  # nothing to see
    ranking = session.rank(refit_top=0, propose=False)
    assert not ranking["azimuth_error"].excited and not ranking.flagged


def test_false_alarm_rate_on_clean_data():
    """White noise, quantization and angle noise (what the within-dwell floor measures).

    With the quartz bias instability and random walk switched on, the slow bias wander of
    a long session is a real drift and can be flagged as ``Kd_bias`` (docs/discovery.md,
    limitations).
    """
    alarms = []
    chi2 = []
    for seed in range(20):
        dwells, _ = simulate({}, seed=100 + seed, passes=2)
        session = Discovery(DwellProblem(dwells), ErrorModel.standard(gimbals=True))
        chi2.append(session.result.chi2_red)
        alarms.append(bool(session.rank(refit_top=0, propose=False).flagged))
    # family-wise level 5 %: at most 1 alarm in 20 seeds is what the issue allows
    assert sum(alarms) <= 1, alarms
    # the measured noise floor is honest: mean χ²_ν over 20 seeds within 1 ± 3·sqrt(2/(20ν))
    nu = 3 * 35 - 17
    assert abs(np.mean(chi2) - 1.0) < 3 * np.sqrt(2 / (20 * nu)) + 0.05


@pytest.mark.parametrize("effect_id", ["Kcc_xxy", "nonorth_12"])
def test_realistic_noise(effect_id):
    """Quartz noise with bias instability and random walk: still found first and recovered."""
    value = _magnitude(effect_id)
    dwells, _ = simulate({effect_id: value}, slow_noise=True, passes=2)
    session = Discovery(DwellProblem(dwells), ErrorModel.standard(gimbals=True))
    ranking = session.rank(refit_top=1, propose=False)
    assert ranking.best.id == effect_id and ranking.best.flagged
    session.add(effect_id)
    estimate, sigma, _ = session.result[effect_id]
    assert abs(estimate - value) < 5 * sigma
    assert session.result.chi2_red < 1.5


def test_platform_drift_is_found_in_the_reading_slopes():
    """``Dg``: the angle sensors follow the drifting platform; the reading slopes within dwells show it."""
    from stableins.discovery.drift import drift_problem

    for effect_id in ("Dg_xx", "Dg_yy", "Dg_zz", None):
        value = 0.05 * LIBRARY["Dg_xx"].term.scale  # 0.05 °/h/g
        dwells, truth = simulate({effect_id: value} if effect_id else {}, passes=2)
        session = Discovery(DwellProblem(dwells), ErrorModel.standard(gimbals=True))
        assert not session.rank(refit_top=0, propose=False)["Dg_xx" if effect_id is None else effect_id].excited
        ranking = session.drift()
        if effect_id is None:
            assert not ranking.flagged
            continue
        assert ranking.best.id == effect_id and ranking.best.flagged
        offsets = [session.result.as_dict()[i] for i in ("theta10", "theta20", "theta30")]
        problem, null, terms, _ = drift_problem(dwells, dwells.reading_slope, dwells.reading_slope_sigma, offsets)
        fit = problem.fit(null + [t for t in terms if t.id == effect_id])
        estimate, sigma, _ = fit[effect_id]
        assert abs(estimate - value) < 5 * sigma
        assert 0.6 < fit.chi2_red < 1.5


def _one_session(truth, stages, *, rate=10.0):
    """Columns of one simulated session running ``stages`` ((name, commands, dwell [s]) ...) on one platform, in order.

    Like :func:`stableins.simulator.device.simulate_dwells`, but the platform (and its hysteresis state) carries over
    from stage to stage, as on the instrument and in ``stableins simulate device``.
    """
    platform = sim_device.SimulatedPlatform(truth, rate=rate, seed=truth.seed)
    pieces = {}
    for stage, commands, dwell in stages:
        rows = []
        for position, readings in enumerate(commands, start=1):
            t_command = platform.command(tuple(readings))
            platform.wait(platform.slew_duration() + 6.0)
            block = platform.acquire(dwell)
            rows.append(block.device_columns(stage=stage, pass_number=1, position=position, command=readings, command_time=t_command))
        pieces[stage] = {k: np.concatenate([r[k] for r in rows]) for k in rows[0]}
    return pieces


def test_fine_stage_hysteresis_state_carries_over_from_the_coarse_stage(tmp_path):
    """Issue 25: the fine stage starts in the hysteresis state the coarse stage left (one platform, one session).

    Before the fix discovery restarted the state at 0 for the fine dwells, so the first fine dwells of an axis that
    had not travelled yet carried no hysteresis: adding the true ``Kh_x`` gave 0.98 of it and χ²_ν = 1.99 (ν = 36)
    here, 0.92 and χ²_ν = 4.6 on a ``stableins simulate device --hidden Kh_x=2e-4`` session.
    """
    from stableins.data.device import load_device, save_device
    from stableins.discovery.dwells import dwells_from_dataset
    from stableins.simulator.effects import hysteresis_state

    quiet = NoiseSettings(velocity_random_walk=2e-5, quantization=1e-7, angle_noise=0.05 * ARCSEC)
    kh = 5e-5  # 5.1 µg, ~8σ of one fine dwell mean
    truth = Truth.draw(11, effects={"Kh_x": kh}, site=SimulatedSite(sample_rate=10.0), noise=quiet)
    coarse = [s.command for s in procedures.load_procedure("device-coarse").steps]
    fine = [s.command for s in procedures.load_procedure("device-fine").steps]
    columns = _one_session(truth, [("coarse", coarse, 4.0), ("fine", fine, 10.0)])
    files = [save_device(tmp_path / f"{name}.csv", c, truth.site) for name, c in columns.items()]
    data = [load_device(f) for f in files]
    dwells = dwells_from_dataset(data, layouts=procedures.device_layouts(), stage="fine")
    # the simulator's own recursion over the commanded path, coarse then fine, from the readings (0, 0, 0)
    platform = sim_device.SimulatedPlatform(truth, rate=10.0)
    g = truth.site.gravity
    path = [platform.platform.specific_force_platform(np.asarray(r, dtype=float), g) for r in [(0.0, 0.0, 0.0), *coarse, *fine]]
    state, states = np.zeros(3), []
    for before, after in zip(path[:-1], path[1:]):
        state = hysteresis_state(state, after - before)
        states.append(state)
    np.testing.assert_array_equal(dwells.slew_direction, np.array(states[len(coarse) :]))
    session = Discovery(DwellProblem(dwells), ErrorModel.standard(nonlinear=True, gimbals=True))
    session.add("Kh_x")
    estimate, sigma, _ = session.result["Kh_x"]
    assert abs(estimate - kh) < 4 * sigma, (estimate / kh, sigma / kh)
    nu = session.result.dof
    assert session.result.chi2_red < 1 + 3 * np.sqrt(2 / nu), session.history.report()
