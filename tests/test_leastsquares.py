"""The dwell forward model is written once (issue 29): the coarse stage and discovery evaluate the same function.

:func:`stableins.estimators.leastsquares.dwell_forward` against finite differences for every kind of term (instrument
terms, zero offsets and kinematic effects through ``f^p``, additive terms reading temperature and slew history), and
the coarse stage's :meth:`CoarseProblem.predict` and discovery's :meth:`DwellProblem.evaluate` giving the same numbers
on the same dwells; the linear problem and the dwell problem both meet the declared :class:`Problem` interface.
"""

import numpy as np
from device_world import GRAVITY, draw_truth

from stableins.conventions import DEFAULT_GIMBALS, GimbalConfiguration, dcm_nav_to_body
from stableins.discovery.dwells import DwellSet, slew_directions
from stableins.discovery.library import LIBRARY
from stableins.discovery.linear import LinearProblem
from stableins.discovery.problem import DwellProblem
from stableins.errormodel import ErrorModel, TermInputs
from stableins.estimators.coarse import CoarseProblem, coarse_model
from stableins.estimators.leastsquares import Problem, dwell_forward
from stableins.platform import platform_specific_force
from stableins.procedures.definition import load_procedure

READINGS = np.array([s.command for s in load_procedure("device-coarse").steps])
BASE = (0.3, 2e-4, -1e-4)
CONFIGURATION = GimbalConfiguration((1, -1, 1, 1))
KINEMATIC = {"nonorth_12": 30e-6, "tilt_north": -20e-6, "ang1_inner_c": 15e-6, "ang1_middle_s": -10e-6}
ADDITIVE = ("Kcc_xxy", "Kt_bias_y", "Kh_z", "K3_x")


def _model() -> ErrorModel:
    kinematic = tuple(LIBRARY[i].term for i in KINEMATIC)
    return coarse_model(nonlinear=True) + kinematic + tuple(LIBRARY[i].term for i in ADDITIVE)


def _values(model: ErrorModel, additive: float = 0.0) -> dict[str, float]:
    """Drawn instrument terms and offsets (30× their size), the kinematic effects above, the additive ones at ``additive`` × size."""
    truth = draw_truth(np.random.default_rng(29), quadratic=True, offset_scale=30.0)
    values = {i: float(truth.get(i, 0.0)) for i in model.ids}
    values.update({i: v for i, v in KINEMATIC.items() if i in model})
    values.update({i: additive * model[i].nominal for i in ADDITIVE if i in model})
    return values


def _inputs(m: int) -> TermInputs:
    rng = np.random.default_rng(7)
    f_p = platform_specific_force(READINGS, GRAVITY, base_attitude=BASE, configuration=CONFIGURATION)
    return TermInputs(
        np.zeros((m, 3)),
        temperature=rng.normal(0.0, 2.0, m),
        time=np.linspace(0.0, 3600.0, m),
        slew_direction=slew_directions(f_p, initial=f_p[-1]),
        extra={"time_since_command": np.full(m, 20.0)},
    )


def _forward(model, values, inputs):
    return dwell_forward(model, values, READINGS, GRAVITY, base_dcm=dcm_nav_to_body(*BASE), configuration=CONFIGURATION, inputs=inputs)


def _finite_difference_errors(additive: float) -> dict[str, float]:
    """``max |numeric − analytic| / scale`` of every column of the dwell forward model's Jacobian."""
    model = _model()
    values = _values(model, additive)
    inputs = _inputs(len(READINGS))
    forward = _forward(model, values, inputs)
    assert forward.jacobian.shape == (len(READINGS), 3, len(model))
    errors = {}
    for k, term in enumerate(model):
        step = 1e-3 * term.nominal
        up = _forward(model, values | {term.id: values[term.id] + step}, inputs).output
        down = _forward(model, values | {term.id: values[term.id] - step}, inputs).output
        numeric = (up - down) / (2 * step)
        scale = max(np.abs(numeric).max(), np.abs(forward.jacobian[..., k]).max())
        assert scale > 0, term.id  # every term moves these outputs
        errors[term.id] = float(np.abs(numeric - forward.jacobian[..., k]).max() / scale)
    return errors


def test_dwell_forward_jacobian_matches_finite_differences_for_every_kind_of_term():
    """Instrument terms, zero offsets, kinematic effects, additive terms (at 0: where discovery evaluates a candidate)."""
    errors = _finite_difference_errors(additive=0.0)
    assert max(errors.values()) <= 1e-6, errors


def test_the_chain_rule_leaves_out_what_additive_terms_add_to_the_slope_of_f_p():
    """With additive terms of 3× their size in the model, the columns through ``f^p`` miss ``∂(additive)/∂f^p``.

    :meth:`ErrorModel.jacobian_specific_force` treats the additive terms as fixed, so the zero offsets' and kinematic
    effects' columns are off by a relative amount of the order of the additive terms' size (here ~1e-4); every other
    column stays exact.  (A Gauss–Newton step then converges more slowly, not to another point.)
    """
    errors = _finite_difference_errors(additive=3.0)
    through = {"theta10", "theta20", "theta30", *KINEMATIC}
    assert max(e for i, e in errors.items() if i not in through) <= 1e-6, errors
    assert 1e-6 < max(errors[i] for i in through) <= 1e-3, errors


def test_the_coarse_stage_and_discovery_evaluate_the_same_forward_model():
    model = coarse_model(nonlinear=True)
    values = _values(model)
    m = len(READINGS)
    base_attitude = (0.0, 1e-4, 2e-4)
    dwells = DwellSet(
        readings=READINGS,
        output=np.zeros((m, 3)),
        sigma=np.full((m, 3), 1e-5),
        gravity=GRAVITY,
        time=np.arange(m, dtype=float),
        time_since_command=np.full(m, 20.0),
        temperature=np.zeros(m),
        slew_direction=np.zeros((m, 3)),
        labels=tuple(str(p) for p in range(m)),
        base_attitude=base_attitude,
        configuration=DEFAULT_GIMBALS,
    )
    coarse = CoarseProblem(
        READINGS[None], np.zeros((1, m, 3)), np.ones((1, m, 3)), GRAVITY, dcm_nav_to_body(*base_attitude), DEFAULT_GIMBALS, model
    )
    output, jacobian = coarse.predict(np.array([[values[i] for i in model.ids]]))
    discovery = DwellProblem(dwells).evaluate(model, values)
    np.testing.assert_allclose(discovery.output, output[0], rtol=0, atol=1e-15)
    np.testing.assert_allclose(discovery.jacobian, jacobian[0], rtol=1e-12, atol=1e-15)


def test_a_batch_of_trials_is_each_trial_on_its_own():
    model = coarse_model()
    rng = np.random.default_rng(3)
    trials = np.stack([[draw_truth(rng, quadratic=False)[i] for i in model.ids] for _ in range(3)])
    batch = _forward(model, {i: trials[:, k, None] for k, i in enumerate(model.ids)}, None)
    for t in range(3):
        one = _forward(model, dict(zip(model.ids, trials[t], strict=True)), None)
        np.testing.assert_allclose(batch.output[t], one.output, rtol=0, atol=1e-15)
        np.testing.assert_allclose(batch.jacobian[t], one.jacobian, rtol=1e-13, atol=1e-18)


def test_the_problems_meet_the_declared_interface():
    """Every member :class:`Problem` declares is there on both implementations (discovery reads them without getattr)."""
    members = set(Problem.__annotations__) | {n for n in vars(Problem) if not n.startswith("_")}
    assert members == {"stage", "static", "fit", "design", "candidate_columns", "whiten"}
    m = len(READINGS)
    dwells = DwellSet(
        READINGS,
        np.zeros((m, 3)),
        np.full((m, 3), 1e-5),
        GRAVITY,
        np.arange(m, dtype=float),
        np.full(m, 20.0),
        np.zeros(m),
        np.zeros((m, 3)),
        tuple(map(str, range(m))),
    )
    linear = LinearProblem(np.ones(4), 0.1, {"a": np.ones(4)})
    for problem in (linear, DwellProblem(dwells)):
        assert all(hasattr(problem, name) for name in members), type(problem).__name__
    assert not linear.static and DwellProblem(dwells).static
    np.testing.assert_allclose(linear.whiten(np.ones(4)), np.full(4, 10.0))
