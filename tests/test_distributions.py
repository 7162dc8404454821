"""stableins.estimators.distributions: scipy.stats's χ² and normal functions to the last bit, without importing it."""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest
from scipy import stats

from stableins.estimators.distributions import chi2_cdf, chi2_ppf, chi2_sf, norm_ppf

DOFS = (0.5, 1, 2, 3, 4.5, 6, 12, 17, 100, 2500)
POINTS = (-1.0, 0.0, 1e-300, 1e-12, 0.01, 0.5, 1.0, 3.0, 7.7, 20.0, 150.0, 4000.0, math.inf, math.nan)
PROBABILITIES = (-0.1, 0.0, 1e-300, 1e-12, 0.001, 0.025, 0.05, 0.5, 0.95, 0.975, 0.999, 1 - 1e-12, 1.0, 1.1, math.nan)


def same(a: float, b: float) -> bool:
    """Equal to the last bit (NaN equals NaN)."""
    return (math.isnan(a) and math.isnan(b)) or a == b


@pytest.mark.parametrize("dof", [*DOFS, 0.0, -1.0, math.nan])
def test_chi2_functions_are_scipy_stats(dof: float) -> None:
    for x in POINTS:
        assert same(chi2_sf(x, dof), float(stats.chi2.sf(x, dof))), (x, dof)
        assert same(chi2_cdf(x, dof), float(stats.chi2.cdf(x, dof))), (x, dof)
    for q in PROBABILITIES:
        assert same(chi2_ppf(q, dof), float(stats.chi2.ppf(q, dof))), (q, dof)


def test_norm_ppf_is_scipy_stats() -> None:
    for q in (*PROBABILITIES, *np.linspace(0.0, 1.0, 101)):
        assert same(norm_ppf(q), float(stats.norm.ppf(q))), q


def test_integer_degrees_of_freedom_as_numpy_integers() -> None:
    assert chi2_sf(5.0, np.int64(3)) == float(stats.chi2.sf(5.0, 3))
    assert chi2_ppf(0.95, np.int64(7)) == float(stats.chi2.ppf(0.95, 7))


def test_module_does_not_import_scipy_stats() -> None:
    code = "import sys; import stableins.estimators.distributions as d; d.chi2_sf(1.0, 2); print('scipy.stats' in sys.modules)"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert done.stdout.strip() == "False"
