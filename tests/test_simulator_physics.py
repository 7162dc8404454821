"""The truth simulator's own accelerometer physics against the estimators' model, term by term and sign by sign.

:mod:`stableins.simulator.physics` (what the world outputs) and :mod:`stableins.errormodel` (what the stages fit) are
two implementations of docs/conventions.md written apart on purpose.  Here they must agree for every parameter alone
and all together, forward and inverse; a sign flipped in either one's installation matrix must break that agreement;
and the expected values of the sign checks come from neither: each installation angle is applied as the exact
right-handed rotation of a sensitive axis (docs/conventions.md: "``β_ij`` is a right-handed rotation of sensitive axis
``i`` about platform axis ``j``"), and Eq. 6 is solved by hand in plain floats.
"""

from __future__ import annotations

import math
from types import MappingProxyType

import numpy as np
import pytest

from stableins import conventions
from stableins.errormodel import ErrorModel
from stableins.simulator import physics
from stableins.simulator.physics import INSTALLATION_IDS, PARAMETERS, Accelerometer

G = 9.80665
MODEL = ErrorModel.standard(nonlinear=True)


def _directions(seed: int, n: int = 64) -> np.ndarray:
    """``n`` specific forces of magnitude ``G`` in random directions, plus the six axis directions."""
    f = np.random.default_rng(seed).normal(size=(n, 3))
    f = G * f / np.linalg.norm(f, axis=1, keepdims=True)
    return np.vstack([f, G * np.eye(3), -G * np.eye(3)])


def _instrument(seed: int) -> dict[str, float]:
    """A random instrument: every core parameter at ``±(1 … 3) ×`` its nominal size (installation angles ≥ 30″)."""
    rng = np.random.default_rng(seed)
    return {p.id: p.reference + p.nominal * rng.choice([-1.0, 1.0]) * rng.uniform(1.0, 3.0) for p in PARAMETERS if p.kind != "gimbal"}


def assert_models_agree(values: dict[str, float], f_p: np.ndarray) -> None:
    """The simulator's output and the estimators' ``forward`` agree to 1e-12 of ``g``, and so do the inverses."""
    simulated = Accelerometer(values).output(f_p)
    fitted = MODEL.forward(f_p, values)
    np.testing.assert_allclose(simulated, fitted, rtol=0, atol=1e-12 * G)
    np.testing.assert_allclose(Accelerometer(values).specific_force(simulated), MODEL.inverse(simulated, values), rtol=0, atol=1e-12 * G)


def test_parameter_tables_agree():
    """Ids, order, kinds, reference values and nominal sizes: the simulator's table is the model's, written apart."""
    model = ErrorModel.standard(nonlinear=True, gimbals=True)
    assert tuple(p.id for p in PARAMETERS) == model.ids
    for spec, term in zip(PARAMETERS, model, strict=True):
        assert (spec.kind, spec.reference) == (term.kind.value, term.reference), spec.id
        assert spec.nominal == pytest.approx(term.nominal, rel=1e-15), spec.id
    assert pytest.approx(1e-6 / G, rel=1e-15) == physics.MICRO_G_PER_G2


@pytest.mark.parametrize("parameter", [p.id for p in PARAMETERS if p.kind != "gimbal"])
@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_each_term_alone_gives_the_same_signal_with_the_same_sign(parameter, sign):
    spec = next(p for p in PARAMETERS if p.id == parameter)
    values = {parameter: spec.reference + sign * 3.0 * spec.nominal}
    f_p = _directions(1)
    simulated = Accelerometer(values).output(f_p) - f_p
    fitted = MODEL.forward(f_p, values) - f_p
    assert np.max(np.abs(simulated)) > 1e-4  # the term is excited (60 µg for K2 at three times its nominal size, more for the rest)
    np.testing.assert_allclose(simulated, fitted, rtol=0, atol=1e-12 * np.max(np.abs(fitted)))
    assert np.array_equal(np.sign(simulated[np.abs(fitted) > 1e-9]), np.sign(fitted[np.abs(fitted) > 1e-9]))


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_whole_instruments_agree_forward_and_inverse(seed):
    assert_models_agree(_instrument(seed), _directions(seed))


def _rotated_axis(i: int, j: int, angle: float) -> np.ndarray:
    """Sensitive axis ``e_i`` turned right-handedly about platform axis ``e_j`` by ``angle`` (Rodrigues, exact)."""
    e_i, e_j = np.eye(3)[i], np.eye(3)[j]
    return e_i * math.cos(angle) + np.cross(e_j, e_i) * math.sin(angle) + e_j * np.dot(e_j, e_i) * (1 - math.cos(angle))


@pytest.mark.parametrize("implementation", ["simulator", "estimators"])
@pytest.mark.parametrize("beta", INSTALLATION_IDS)
def test_installation_angle_turns_its_axis_right_handedly(beta, implementation):
    """Each angle alone, against the exact rotation of the axis it names (an expected value from neither model)."""
    i, j = "xyz".index(beta[5]), "xyz".index(beta[6])
    angle = 30.0 * conventions.ARCSEC
    f_p = _directions(4)
    expected = f_p @ _rotated_axis(i, j, angle)  # the output of axis i: its unit vector · f^p
    values = {beta: angle}
    got = Accelerometer(values).output(f_p) if implementation == "simulator" else MODEL.forward(f_p, values)
    # first order in the angle: the matrix rows are the rotated axes up to β²/2 (docs/conventions.md)
    np.testing.assert_allclose(got[:, i], expected, rtol=0, atol=0.6 * angle**2 * G)
    np.testing.assert_allclose(np.delete(got, i, axis=1), np.delete(f_p, i, axis=1), rtol=0, atol=1e-15 * G)
    moved = np.abs(got[:, i] - f_p[:, i]) > 0.5 * angle * G
    assert np.any(moved)  # the check can fail: the angle moves the output by ~β g


def eq6_by_hand(values: dict[str, float], f: tuple[float, float, float]) -> list[float]:
    """Eq. 6 in plain floats, one axis at a time (docs/conventions.md), with no array code and no shared helper."""
    b = {k: values.get(k, 0.0) for k in INSTALLATION_IDS}
    fx, fy, fz = f
    rows = (
        fx + b["beta_xz"] * fy - b["beta_xy"] * fz,
        -b["beta_yz"] * fx + fy + b["beta_yx"] * fz,
        b["beta_zy"] * fx - b["beta_zx"] * fy + fz,
    )
    out = []
    for a, row in zip("xyz", rows, strict=True):
        w = row / values.get(f"sf_{a}", 1.0)
        k = values.get(f"K2_{a}", 0.0)
        u = 2.0 * w / (1.0 + math.sqrt(1.0 - 4.0 * k * w))  # the root of u − K u² = w that tends to w (docs/conventions.md)
        out.append(values.get(f"bias_{a}", 0.0) + u)
    return out


@pytest.mark.parametrize("seed", [5, 6])
def test_output_matches_eq6_solved_by_hand(seed):
    values = _instrument(seed)
    f_p = _directions(seed, n=16)
    got = Accelerometer(values).output(f_p)
    for row, f in zip(got, f_p, strict=True):
        np.testing.assert_allclose(row, eq6_by_hand(values, tuple(f)), rtol=0, atol=1e-12 * G)


def _flip_in_simulator(monkeypatch: pytest.MonkeyPatch, beta: str) -> None:
    original = physics.installation_matrix
    monkeypatch.setattr(physics, "installation_matrix", lambda values: original({**values, beta: -values.get(beta, 0.0)}))


def _flip_in_estimators(monkeypatch: pytest.MonkeyPatch, beta: str) -> None:
    entries = dict(conventions.INSTALLATION_ENTRIES)
    row, col, sign = entries[beta]
    entries[beta] = (row, col, -sign)
    monkeypatch.setattr(conventions, "INSTALLATION_ENTRIES", MappingProxyType(entries))


@pytest.mark.parametrize("flip", [_flip_in_simulator, _flip_in_estimators], ids=["simulator", "estimators"])
@pytest.mark.parametrize("beta", INSTALLATION_IDS)
def test_a_flipped_installation_sign_in_either_implementation_breaks_the_agreement(monkeypatch, beta, flip):
    values, f_p = _instrument(1), _directions(1)
    assert_models_agree(values, f_p)  # unflipped, they agree
    flip(monkeypatch, beta)
    with pytest.raises(AssertionError):
        assert_models_agree(values, f_p)


def test_additive_effects_are_summed_before_the_quadratic_and_inverted():
    """An effect enters ``w`` (before ``K``); the inverse with the effect installed gives ``f^p`` back."""
    values = _instrument(7) | {"Kcc_xxy": 1e-5}

    def product_on_x(inputs: physics.SensorInputs) -> np.ndarray:
        f = inputs.specific_force
        return np.stack([f[:, 0] * f[:, 1], np.zeros(len(f)), np.zeros(len(f))], axis=-1)

    effect = (("Kcc_xxy", product_on_x),)
    f_p = _directions(7, n=16)
    got = Accelerometer(values, effect).output(f_p)
    for row, f in zip(got, f_p, strict=True):
        k = values["K2_x"]
        w = (f[0] + values["beta_xz"] * f[1] - values["beta_xy"] * f[2]) / values["sf_x"] + 1e-5 * f[0] * f[1]
        assert row[0] == pytest.approx(values["bias_x"] + 2.0 * w / (1.0 + math.sqrt(1.0 - 4.0 * k * w)), abs=1e-12 * G)
    back = Accelerometer(values, effect).specific_force(got)
    np.testing.assert_allclose(back, f_p, rtol=0, atol=1e-12 * G)
    assert np.max(np.abs(Accelerometer(values).specific_force(got) - f_p)) > 1e-5  # without the effect it does not invert
