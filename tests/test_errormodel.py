"""Forward/inverse round trips and analytic Jacobians of the error model."""

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from stableins.errormodel import CORE_IDS, ErrorModel, Term, TermInputs, TermKind


def _draw(model, rng, scale=1.0):
    return {t.id: t.reference + scale * rng.normal() * t.nominal for t in model}


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**31 - 1))
def test_forward_inverse_round_trip(seed):
    rng = np.random.default_rng(seed)
    model = ErrorModel.standard()
    values = _draw(model, rng, scale=5.0)
    f_p = rng.normal(size=(7, 3)) * 9.8
    np.testing.assert_allclose(model.inverse(model.forward(f_p, values), values), f_p, atol=1e-12)


def test_forward_solves_implicit_eq6_exactly():
    rng = np.random.default_rng(3)
    model = ErrorModel.standard()
    values = _draw(model, rng, scale=50.0)  # large K2 to make the implicit part visible
    f_p = rng.normal(size=(11, 3)) * 9.8
    f_a = model.forward(f_p, values)
    sf = np.array([values[f"sf_{a}"] for a in "xyz"])
    b = np.array([values[f"bias_{a}"] for a in "xyz"])
    k = np.array([values[f"K2_{a}"] for a in "xyz"])
    from stableins.conventions import dcm_platform_to_accelerometer

    c = dcm_platform_to_accelerometer(**{i: values[i] for i in ("beta_xz", "beta_xy", "beta_yz", "beta_yx", "beta_zy", "beta_zx")})
    residual = f_a - ((c @ f_p.T).T / sf + b + k * (f_a - b) ** 2)
    assert np.abs(residual).max() < 1e-13


def test_jacobian_matches_central_differences():
    rng = np.random.default_rng(7)

    def cube_x(inputs):
        out = np.zeros_like(inputs.specific_force)
        out[..., 0] = inputs.specific_force[..., 0] ** 3
        return out

    cubic = Term("K3_x", "additive", "s^4/m^3", "ug/g^3", 1e-9, 1e-9, "cubic", axis=0, regressor=cube_x)
    model = ErrorModel.standard() + cubic
    values = _draw(model, rng, scale=3.0)
    f_p = rng.normal(size=(9, 3)) * 9.8
    jac = model.jacobian(f_p, values)
    for k, term in enumerate(model):
        step = 1e-2 * term.nominal  # central differences: error O(step^2)
        plus, minus = dict(values), dict(values)
        plus[term.id] += step
        minus[term.id] -= step
        numeric = (model.forward(f_p, plus) - model.forward(f_p, minus)) / (2 * step)
        scale = np.abs(jac[..., k]).max()
        assert scale > 0, term.id
        assert np.abs(numeric - jac[..., k]).max() <= 1e-6 * scale, term.id


def test_jacobian_wrt_specific_force():
    rng = np.random.default_rng(8)
    model = ErrorModel.standard()
    values = _draw(model, rng, scale=10.0)
    f_p = rng.normal(size=3) * 9.8
    jac = model.jacobian_specific_force(f_p, values)
    for j in range(3):
        d = np.zeros(3)
        d[j] = 1e-4
        numeric = (model.forward(f_p + d, values) - model.forward(f_p - d, values)) / 2e-4
        np.testing.assert_allclose(numeric, jac[:, j], rtol=1e-7, atol=1e-9)  # entries are O(1)


def test_additive_term_round_trip_with_inputs():
    def temperature_x(inputs):
        out = np.zeros_like(inputs.specific_force)
        out[..., 0] = inputs.require("temperature", "Kt_bias_x")
        return out

    temp = Term("Kt_bias_x", "additive", "m/s^2/K", "ug/K", 9.8e-6, 1e-5, "bias temperature sensitivity", axis=0, regressor=temperature_x)
    model = ErrorModel.standard() + temp
    values = _draw(model, np.random.default_rng(2))
    values["Kt_bias_x"] = 3e-5
    f_p = np.random.default_rng(4).normal(size=(5, 3)) * 9.8
    inputs = TermInputs(np.zeros((5, 3)), temperature=np.linspace(-5, 5, 5))
    f_a = model.forward(f_p, values, inputs)
    np.testing.assert_allclose(model.inverse(f_a, values, inputs), f_p, atol=1e-12)
    with pytest.raises(ValueError, match="temperature"):
        model.forward(f_p, values)


def test_model_is_immutable_composition():
    base = ErrorModel.standard(nonlinear=False)
    assert len(base) == 12 and "K2_x" not in base
    full = ErrorModel.standard(gimbals=True)
    assert full.ids == CORE_IDS + ("theta10", "theta20", "theta30")
    smaller = full - "theta10"
    assert "theta10" in full and "theta10" not in smaller
    with pytest.raises(ValueError, match="duplicate"):
        full + full["sf_x"]
    with pytest.raises(KeyError, match="not in the model"):
        base["K2_x"]
    v = full.vector({"sf_x": 1.5})
    assert v.shape == (len(full),) and full.mapping(v)["sf_x"] == 1.5 and full.mapping(v)["sf_y"] == 1.0


def test_engineering_units():
    model = ErrorModel.standard(gimbals=True)
    assert model["sf_x"].to_engineering(1 + 3e-6) == pytest.approx(3.0)
    assert model["bias_y"].to_engineering(9.80665e-5) == pytest.approx(10.0)
    assert model["beta_xz"].to_engineering(np.radians(1 / 3600)) == pytest.approx(1.0)
    assert model["K2_z"].from_engineering(1.0) == pytest.approx(9.80665e-6 / 9.80665**2)


def test_term_kind_is_an_enum_that_serializes_as_its_word() -> None:
    model = ErrorModel.standard(nonlinear=True, gimbals=True)
    assert {t.kind for t in model.terms} == {
        TermKind.SCALE_FACTOR,
        TermKind.BIAS,
        TermKind.INSTALLATION,
        TermKind.NONLINEARITY,
        TermKind.GIMBAL,
    }
    assert all(isinstance(t.kind, TermKind) for t in model.terms)
    assert json.dumps(model["sf_x"].kind) == '"scale_factor"'
    term = Term("k3", "additive", "s^2/m^2", "1", 1.0, 1.0, "cubic", regressor=lambda i: i.specific_force**3)
    assert term.kind is TermKind.ADDITIVE
    with pytest.raises(ValueError, match="unknown kind 'additve'"):
        Term("k3", "additve", "1", "1", 1.0, 1.0, "typo")


def test_cross_coupling_aliases_are_the_installation_angles_that_read_alike():
    """With f_a held, ``Kcc_a·a·o f_a f_o`` is linear in f_o: the same column as the angle of row a that takes f_o in."""
    from stableins.errormodel import ErrorModel
    from stableins.terms import CAI_CROSS_COUPLING_IDS, CROSS_COUPLING_TERMS, TermInputs

    rng = np.random.default_rng(7)
    model = ErrorModel.standard(nonlinear=False)
    values = {t.id: t.reference for t in model.terms}
    for term in (t for t in CROSS_COUPLING_TERMS if t.id in CAI_CROSS_COUPLING_IDS):
        a = "xyz".index(term.id[4])
        f = rng.normal(size=(50, 3)) * 9.8
        f[:, a] = 5.0  # f_a held
        kcc = term.regressor(TermInputs(specific_force=f))[:, a]
        beta = term.aliases[0]
        column = model.jacobian(f, values)[:, a, model.ids.index(beta)]
        assert abs(np.corrcoef(kcc, column)[0, 1]) > 1 - 1e-9, (term.id, beta)
