r"""The χ² and standard normal distribution functions the estimators' tests and intervals use, without :mod:`scipy.stats`.

:mod:`scipy.stats` costs a command about a second to import on a shared machine (it builds every distribution and parses
their docstrings; issue 30), while the estimators need only four functions of two distributions.  Each is the
:mod:`scipy.special` function :mod:`scipy.stats` itself evaluates (scipy 1.17, ``_continuous_distns.chi2_gen`` and
``norm_gen``) with its handling of the support's ends, so the numbers are :mod:`scipy.stats`'s to the last bit
(``tests/test_distributions.py`` compares them):

* ``chi2.sf(x, k) = Q(k/2, x/2)`` (``chdtrc``), 1 for ``x ≤ 0``;
* ``chi2.cdf(x, k) = P(k/2, x/2)`` (``chdtr``), 0 for ``x ≤ 0``;
* ``chi2.ppf(q, k) = 2 P⁻¹(k/2, q)`` (``gammaincinv``), 0 at ``q = 0`` and ∞ at ``q = 1``;
* ``norm.ppf(q) = Φ⁻¹(q)`` (``ndtri``).

Outside the domain (``k ≤ 0``, ``q`` outside [0, 1], NaN) each returns NaN, as :mod:`scipy.stats` does.
"""

from __future__ import annotations

import math

from scipy import special


def _valid_dof(dof: float) -> bool:
    return bool(dof > 0)


def chi2_sf(x: float, dof: float) -> float:
    """Survival function ``P(χ²_k > x)`` of the χ² distribution with ``dof`` degrees of freedom (``scipy.stats.chi2.sf``)."""
    x, dof = float(x), float(dof)
    if math.isnan(x) or math.isnan(dof) or not _valid_dof(dof):
        return math.nan
    if x <= 0.0:
        return 1.0
    return float(special.chdtrc(dof, x))


def chi2_cdf(x: float, dof: float) -> float:
    """Distribution function ``P(χ²_k ≤ x)`` (``scipy.stats.chi2.cdf``)."""
    x, dof = float(x), float(dof)
    if math.isnan(x) or math.isnan(dof) or not _valid_dof(dof):
        return math.nan
    if x <= 0.0:
        return 0.0
    return float(special.chdtr(dof, x))


def chi2_ppf(q: float, dof: float) -> float:
    """Quantile ``x`` with ``P(χ²_k ≤ x) = q`` (``scipy.stats.chi2.ppf``)."""
    q, dof = float(q), float(dof)
    if math.isnan(q) or math.isnan(dof) or not _valid_dof(dof) or not 0.0 <= q <= 1.0:
        return math.nan
    if q == 0.0:
        return 0.0
    if q == 1.0:
        return math.inf
    return float(2 * special.gammaincinv(dof / 2, q))


def norm_ppf(q: float) -> float:
    """Quantile ``z`` with ``Φ(z) = q`` of the standard normal distribution (``scipy.stats.norm.ppf``)."""
    q = float(q)
    if math.isnan(q) or not 0.0 <= q <= 1.0:
        return math.nan
    return float(special.ndtri(q))


__all__ = ["chi2_cdf", "chi2_ppf", "chi2_sf", "norm_ppf"]
