"""Discovery on system-level records (space-stable platform turning at the Earth rate), binned into dwells."""

from dataclasses import replace

import numpy as np
import pytest

from stableins.conventions import ARCSEC
from stableins.discovery.harmonics import residual_spectra
from stableins.discovery.history import Discovery
from stableins.discovery.library import LIBRARY
from stableins.discovery.linear import bins_from_chunks
from stableins.discovery.problem import DwellProblem
from stableins.errormodel import ErrorModel
from stableins.simulator.noise import NoiseSettings
from stableins.simulator.system import simulate_system
from stableins.simulator.truth import SimulatedSite, Truth

WHITE = NoiseSettings(velocity_random_walk=4.5e-4, angle_noise=0.2 * ARCSEC)
DAY = 86164.0


def _record(effects, seed=1, hours=DAY / 3600):
    truth = Truth.draw(seed, site=SimulatedSite(sample_rate=10.0), effects=effects, noise=WHITE)
    return simulate_system(truth, hours * 3600.0, rate=10.0, seed=seed), truth


def _bins(columns, truth, chunks=1):
    n = len(columns["time"])
    edges = np.linspace(0, n, chunks + 1).astype(int)
    pieces = [{k: v[a:b] for k, v in columns.items()} for a, b in zip(edges[:-1], edges[1:], strict=True)]
    return bins_from_chunks(pieces, gravity=truth.site.gravity, base_attitude=truth.site.base_attitude, configuration=truth.configuration)


@pytest.fixture(scope="module")
def clean():
    return _record({})


def test_binning_streams_in_chunks(clean):
    columns, truth = clean
    one, many = _bins(columns, truth, 1), _bins(columns, truth, 7)
    np.testing.assert_allclose(many.output, one.output, rtol=0, atol=1e-12)
    np.testing.assert_allclose(many.sigma, one.sigma, rtol=1e-12)
    np.testing.assert_allclose(many.readings, one.readings, atol=1e-15)


def test_clean_day_is_at_the_noise_floor_with_flat_harmonics(clean):
    columns, truth = clean
    dwells = _bins(columns, truth)
    session = Discovery(DwellProblem(dwells), ErrorModel.standard(gimbals=True))
    nu = session.result.dof
    assert abs(session.result.chi2_red - 1) < 4 * np.sqrt(2 / nu)
    assert not session.rank(refit_top=0, propose=False).flagged
    spectra = residual_spectra(dwells.time, session.diagnose())
    assert min(float(s.p_value.min()) for s in spectra.values()) > 1e-3
    # polar alignment: f_z is constant, so its scale factor and quadratic term are gauges
    assert {"sf_z", "K2_z"} <= {t.id for t, st in zip(session.result.terms, session.result.status, strict=True) if st == "gauge"}


def test_hidden_cubic_is_found_on_a_day_record():
    term = LIBRARY["K3_x"].term
    value = 100 * term.scale
    columns, truth = _record({"K3_x": value})
    session = Discovery(DwellProblem(_bins(columns, truth)), ErrorModel.standard(gimbals=True))
    ranking = session.rank(refit_top=1, propose=False)
    assert ranking.best.id == "K3_x" and ranking.best.flagged
    session.add("K3_x")
    assert abs(session.result.chi2_red - 1) < 4 * np.sqrt(2 / session.result.dof)
    estimate, sigma, _ = session.result["K3_x"]
    assert abs(estimate - value) < 5 * sigma


# --------------------------------------------------------------------------- under the system stage's noise model
class _Record:
    """An in-memory system record for the stage and discovery: ``metadata`` and ``iter_chunks``."""

    def __init__(self, columns, site):
        from stableins.data.chunks import ArraySource

        self.metadata = site
        self.path = "<arrays>"
        self._source = ArraySource(columns)

    def iter_chunks(self, columns=None, rows=1 << 16, **kwargs):
        return self._source.iter_chunks(columns, rows, **kwargs)


def _quartz_day(seed, effects=None):
    truth = Truth.draw(seed, site=SimulatedSite(sample_rate=1.0), effects=effects or {})  # the simulator's quartz noise
    return _Record(simulate_system(truth, DAY, rate=1.0, seed=seed), truth.site), truth


def _system_diagnosis(record, truth, white_only=False):
    from stableins.discovery.system import diagnose_system_record, measure_noise
    from stableins.noise import NoiseModel

    model = ErrorModel.standard(nonlinear=True, gimbals=True)
    measured = measure_noise(record, dict(truth.installed_calibration), None, None)
    if white_only:
        measured = replace(measured, noise_model=NoiseModel.given(measured.noise_model.values("white")))
    start = {k: v for k, v in truth.installed_calibration.items() if k in model}
    return diagnose_system_record(record, model, start, measured)


def test_clean_quartz_days_raise_no_alarm_under_the_stage_noise_model():
    """A clean quartz day: nothing is missing under the measured noise model and its limits; with a white floor only
    the slow wander looks like missing effects (the false alarms diagnose raised before, docs/discovery.md)."""
    for seed in (3,):
        record, truth = _quartz_day(seed)
        result = _system_diagnosis(record, truth)
        assert not result.alarm, (result.diagnosis.chi2_red, [c.id for c in result.ranking.flagged], result.flagged_harmonics)
        hi, lo = result.chi2_range
        assert hi <= result.diagnosis.chi2_red <= lo  # more slow noise, smaller χ²
        # P printed beside χ²_ν is that χ²_ν's (continuous in it; issue 25: it jumped from 0.5 to 0.415 between χ²_ν
        # 1.025 and 1.026); the verdict rests on its range over the noise models allowed
        from scipy.stats import chi2

        nu = result.diagnosis.result.dof
        assert result.diagnosis.p_value == pytest.approx(float(chi2.sf(result.diagnosis.chi2_red * nu, nu)), rel=1e-9)
        assert result.diagnosis.p_range == pytest.approx((float(chi2.sf(hi * nu, nu)), float(chi2.sf(lo * nu, nu))), rel=1e-9)
        assert abs(result.diagnosis.chi2_red - 1.0) < 4 * result.diagnosis.spread + 0.05
        assert result.noise_model.axes[0].bias_instability.detected
    white = _system_diagnosis(record, truth, white_only=True)
    assert white.alarm and not white.diagnosis.consistent


def test_hidden_cubic_is_found_under_the_largest_slow_noise():
    """A hidden K3_x of 100 µg/g³ on a quartz day: ranked first and flagged against the upper-limit noise model."""
    value = 100 * LIBRARY["K3_x"].term.scale
    record, truth = _quartz_day(5, {"K3_x": value})
    result = _system_diagnosis(record, truth)
    best = result.ranking.best
    assert best.id in ("K3_x", "Koq_x") and best.flagged  # K3 and Koq are close on polar geometry (docs/discovery.md)
    assert result.ranking["K3_x"].flagged
    assert abs(result.ranking["K3_x"].estimate - value) < 5 * result.ranking["K3_x"].sigma
