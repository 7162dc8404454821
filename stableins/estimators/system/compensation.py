"""Compensation of the raw accelerometer outputs with the installed calibration (system stage).

:class:`Compensation`: Wu et al. 2018 Eq. 8 in closed form for the core terms (the per-sample pass,
:mod:`.blocks`); :class:`AdditiveCompensation`: the prior's discovered additive terms removed first.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from stableins.errormodel import ErrorModel, Term, TermKind
from stableins.errors import InputError, NotDeterminedError
from stableins.estimators.system.blocks import coefficients


@dataclass(frozen=True)
class Compensation:
    """Closed-form Eq. 8 for constant core parameters: ``f^p = M (u − K u²)``, ``u = f^a − δb``."""

    matrix: NDArray[np.float64]
    bias: NDArray[np.float64]
    quadratic: NDArray[np.float64]

    @classmethod
    def from_values(cls, values: Mapping[str, float]) -> Compensation:
        """Build the compensation from the installed calibration (record values of the core terms)."""
        model = ErrorModel.standard(nonlinear=True)
        known = {k: v for k, v in values.items() if k in model.ids}
        # M from the model's own inverse applied to unit vectors (no re-derivation of Eq. 8 here)
        zero_bias = dict(known, bias_x=0.0, bias_y=0.0, bias_z=0.0, K2_x=0.0, K2_y=0.0, K2_z=0.0)
        matrix = model.inverse(np.eye(3), zero_bias).T
        bias = np.array([known.get(f"bias_{a}", 0.0) for a in "xyz"])
        quadratic = np.array([known.get(f"K2_{a}", 0.0) for a in "xyz"])
        return cls(matrix, bias, quadratic)

    def packed(self, gravity: float) -> NDArray[np.float64]:
        """Return the coefficients of the per-sample pass (:func:`.blocks.coefficients`)."""
        return coefficients(self.matrix, self.bias, self.quadratic, gravity)


@dataclass(frozen=True)
class AdditiveCompensation:
    r"""The prior's discovered (additive) terms, removed from the raw outputs before the closed-form pass.

    The per-sample pass applies the core terms only.  With additive terms ``e(f^p)`` the installed
    model is ``f^a = δb + u``, ``u − K u² = SF⁻¹ C f^p + e(f^p)``; the outputs of the same
    instrument without them, at the same specific force, are

    .. math:: f^{a\prime} = F_{core}\big(F^{-1}_{full}(f^a)\big)

    (:meth:`ErrorModel.inverse` of the full model, exact, then :meth:`ErrorModel.forward` of the
    core), so the closed-form compensation of ``f^{a'}`` gives exactly the full model's ``f^p``.
    Only terms of the specific force are allowed (the instrument effects a record carries).
    """

    full: ErrorModel
    core: ErrorModel
    values: dict[str, float]

    @classmethod
    def from_prior(cls, terms: Sequence[Term], prior: Mapping[str, float], path: str) -> AdditiveCompensation | None:
        """Build it for the prior's discovered terms (None without any); each must be an additive term of the specific force."""
        if not terms:
            return None
        from stableins.errormodel import TermInputs

        for t in terms:
            if t.kind != TermKind.ADDITIVE or t.regressor is None:
                raise InputError(f"{t.id!r} is not an additive term", path=path, field=t.id)
            try:
                t.regressor(TermInputs(np.array([[0.0, 0.0, -9.8]])))
            except (InputError, NotDeterminedError):
                raise  # a described error passes through as it is (issue 29)
            except ValueError as error:
                raise InputError(
                    f"the prior's term {t.id!r} cannot be compensated from the specific force alone: {error}",
                    path=path,
                    field=t.id,
                    expected="discovered instrument terms (stableins.discovery.library.calibration_terms)",
                ) from None
        core = ErrorModel.standard(nonlinear=True)
        full = core + tuple(terms)
        return cls(full, core, {k: float(v) for k, v in prior.items() if k in full})

    def __call__(self, fx: NDArray, fy: NDArray, fz: NDArray) -> tuple[NDArray, NDArray, NDArray]:
        """Return the outputs of the same instrument without the additive terms, axis by axis."""
        f_p = self.full.inverse(np.stack([fx, fy, fz], axis=-1), self.values)
        out = self.core.forward(f_p, self.values)
        return out[:, 0], out[:, 1], out[:, 2]


__all__ = ["AdditiveCompensation", "Compensation"]
