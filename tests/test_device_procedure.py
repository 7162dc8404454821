"""Procedure definitions: Table 1 reconstruction, kinematics of every position, loader validation."""

import numpy as np
import pytest

from stableins import conventions as cv
from stableins.errors import InputError
from stableins.procedures.definition import load_procedure

COARSE = load_procedure("device-coarse")
FINE = load_procedure("device-fine")


def _f_over_g(readings, offsets=None, senses=(1, 1, 1, 1)):
    a = np.asarray(readings) + (0.0 if offsets is None else offsets)
    return cv.dcm_body_to_platform(*a, 0.0, cv.GimbalConfiguration(senses)) @ np.array([0.0, 0.0, -1.0])


def _first_order(readings):
    """∂(f^p/g)/∂θ_i0 by central differences (columns θ10, θ20, θ30)."""
    h = 1e-7
    return np.array([(_f_over_g(readings, h * e) - _f_over_g(readings, -h * e)) / (2 * h) for e in np.eye(3)]).T


def test_procedures_load_with_defaults():
    assert COARSE.positions == tuple(range(1, 19)) and FINE.positions == COARSE.positions
    assert all(s.dwell == 20.0 for s in COARSE.steps) and all(s.dwell == 600.0 for s in FINE.steps)
    assert COARSE.offset_iteration.threshold == pytest.approx(0.1 * cv.ARCSEC)
    for a, b in zip(COARSE.steps, FINE.steps):
        assert a.command == b.command


@pytest.mark.parametrize("step", COARSE.steps, ids=lambda s: f"pos{s.position}")
def test_expected_axis_directions_match_exact_kinematics(step):
    f = _f_over_g(step.command)
    words = {"up": 1.0, "down": -1.0, "level": 0.0, "+45": np.sqrt(0.5), "-45": -np.sqrt(0.5)}
    expected = [words[w.split()[1]] for w in step.expect.split(",")]
    np.testing.assert_allclose(f, expected, atol=1e-12)


def test_each_axis_points_up_and_down_with_default_handedness():
    for down, up, axis in ((1, 7, 2), (3, 9, 1), (5, 11, 0)):
        assert _f_over_g(COARSE.step(down).command)[axis] == pytest.approx(-1.0)
        assert _f_over_g(COARSE.step(up).command)[axis] == pytest.approx(1.0)


@pytest.mark.parametrize("senses", [(1, -1, 1, 1), (-1, 1, 1, 1), (1, 1, -1, 1), (-1, -1, -1, 1)])
def test_other_handedness_leaves_x_and_y_one_sided(senses):
    f = np.array([_f_over_g(s.command, senses=senses) for s in COARSE.steps])
    for axis in (0, 1):  # x and y each see only one of +g, -g
        assert f[:, axis].max() < 0.99 or f[:, axis].min() > -0.99
    assert f[:, 2].max() == pytest.approx(1.0) and f[:, 2].min() == pytest.approx(-1.0)


# First-order offset terms of Table 1 whose relative sign survived the extraction ('+'
# printed, or two products with no operator between them, which had a '−').
# (position, component, {offset index: coefficient up to a common sign}).
TABLE1_TERMS = [
    (1, 0, {2: 1.0}),
    (1, 1, {1: 1.0}),
    (2, 0, {0: np.sqrt(0.5), 2: -1.0}),
    (3, 0, {0: 1.0, 2: -1.0}),
    (3, 2, {1: 1.0}),
    (5, 1, {2: 1.0, 0: -1.0}),
    (6, 1, {2: 1.0, 0: -np.sqrt(0.5)}),
    (7, 0, {1: 1.0}),
    (7, 1, {2: 1.0}),
    (8, 0, {0: np.sqrt(0.5), 1: np.sqrt(0.5)}),
    (9, 0, {0: 1.0}),
    (9, 2, {2: 1.0}),
    (11, 1, {0: 1.0}),
    (12, 1, {0: np.sqrt(0.5), 1: np.sqrt(0.5)}),
    (13, 0, {0: np.sqrt(0.5), 2: 1.0}),
    (14, 2, {1: 1.0}),  # printed as √2/2·g·θ20: a misprint (exact kinematics: g·θ20)
    (17, 2, {2: 1.0}),
    (18, 1, {0: np.sqrt(0.5), 1: np.sqrt(0.5)}),
]


@pytest.mark.parametrize("position, component, terms", TABLE1_TERMS)
def test_sequence_reproduces_table1_first_order_terms(position, component, terms):
    jac = _first_order(COARSE.step(position).command)[component]
    k0 = next(iter(terms))
    sign = np.sign(jac[k0]) * np.sign(terms[k0])
    for k, c in terms.items():
        assert jac[k] == pytest.approx(sign * c, abs=1e-6)


def test_table1_row16_sign_differs_from_kinematics():
    # Table 1 prints (θ10 + θ20)·√2/2·g for g_x at position 16; no proper gimbal chain with
    # handedness +1 gives that: θ20 enters with the opposite relative sign.
    jac = _first_order(COARSE.step(16).command)[0]
    assert jac[0] == pytest.approx(-jac[1], abs=1e-6) and abs(jac[0]) == pytest.approx(np.sqrt(0.5), abs=1e-6)


def _write(tmp_path, text):
    p = tmp_path / "p.toml"
    p.write_text(text)
    return p


BASE = """
[procedure]
name = "t"
stage = "coarse"
[defaults]
dwell = 20.0
sample_rate = 100.0
"""


@pytest.mark.parametrize(
    "body, field",
    [
        (
            "[[step]]\nposition = 1\nplatform = 0.0\ninner = 0.0\nmiddle = 0.0\n" * 2,
            "step.position",
        ),
        ("[[step]]\nposition = 1\nplatform = 0.0\ninner = 0.0\n", "step.middle"),
        ("[[step]]\nposition = 1\nplatform = 'a'\ninner = 0.0\nmiddle = 0.0\n", "step.platform"),
        ("[[step]]\nposition = 1\nplatform = 0.0\ninner = 1e4\nmiddle = 0.0\n", "step.inner"),
        ("[[step]]\nposition = 1\nplatform = 0.0\ninner = 0.0\nmiddle = 0.0\ndwel = 3\n", "step"),
        ("[[step]]\nposition = 1\nplatform = 0.0\ninner = 0.0\nmiddle = 0.0\nexpect = 'z sideways'\n", "step.expect"),
    ],
)
def test_loader_rejects_bad_definitions(tmp_path, body, field):
    with pytest.raises(InputError) as info:
        load_procedure(_write(tmp_path, BASE + body))
    assert info.value.field == field and str(tmp_path) in str(info.value)


def test_loader_reports_missing_file_and_bad_toml(tmp_path):
    with pytest.raises(InputError, match="not found"):
        load_procedure(tmp_path / "none.toml")
    with pytest.raises(InputError, match="not valid TOML"):
        load_procedure(_write(tmp_path, "[procedure\n"))
