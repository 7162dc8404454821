r"""Field recalibration: combine a new, data-only estimate with the unit's previous record as the prior.

The new stage (system-level, or a short device-level set) is estimated from its data alone,
giving :math:`\hat x_d, P_d` for the parameters it determines.  That estimate is an
observation :math:`\hat x_d = H x + v`, :math:`v \sim N(0, P_d)` (``H`` selects those
parameters), of the unit's state whose prior is the previous record :math:`\hat x_0, P_0`.
The linear Gaussian update (Kalman, Gelb 1974 Eq. 4.2-5):

.. math::
    K = P_0 H^T (H P_0 H^T + P_d)^{-1},\qquad
    \hat x_1 = \hat x_0 + K(\hat x_d - H\hat x_0),\qquad
    P_1 = (I - KH) P_0

carries the correlations of the prior to the parameters the new data do not see.  A
parameter estimated by the new data but absent (or unidentifiable) in the prior has a
diffuse prior: it takes the data-only estimate, and its cross-covariances follow from the
information form (implemented as such: :math:`\Lambda_1 = \Lambda_0 + H^T P_d^{-1} H`).
Parameters that are ``fixed`` or ``gauge`` in the prior keep it.  The significance of every
change is :func:`stableins.history.compare` with ``prior_used=True`` (σ² = P0 − P1).
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import TYPE_CHECKING

from stableins.data.errors import InputError

if TYPE_CHECKING:  # pragma: no cover
    from stableins.records import CalibrationRecord


def fuse_with_prior(prior: CalibrationRecord, data: CalibrationRecord, *, prior_sha256: str = "") -> CalibrationRecord:
    """The recalibrated record: ``data`` (data-only estimate) applied to ``prior`` (module docstring)."""
    import numpy as np

    from stableins.records import Parameter, Provenance

    if prior.serial_number != data.serial_number:
        raise InputError(
            f"the previous record is of unit {prior.serial_number!r}, the new data of {data.serial_number!r}",
            field="serial_number",
            expected="the same unit",
        )
    prior_state = [p.id for p in prior.parameters if p.status == "estimated" and math.isfinite(p.sigma)]
    observed = [p.id for p in data.parameters if p.status == "estimated" and math.isfinite(p.sigma)]
    if not observed:
        raise InputError("the new estimate determines no parameter", field="parameters", expected="at least one 'estimated' parameter")
    state = prior_state + [i for i in observed if i not in prior_state]
    n = len(state)
    index = {pid: k for k, pid in enumerate(state)}
    # prior information (diffuse for parameters the prior does not determine)
    information = np.zeros((n, n))
    eta = np.zeros(n)
    k0 = [index[i] for i in prior_state]
    if prior_state:
        p0 = prior.covariance_of(prior_state)
        x0 = np.array([prior[i].value for i in prior_state])
        l0 = _inverse(p0, "previous record")
        information[np.ix_(k0, k0)] += l0
        eta[k0] += l0 @ x0
    pd = data.covariance_of(observed)
    xd = np.array([data[i].value for i in observed])
    ld = _inverse(pd, "new estimate")
    kd = [index[i] for i in observed]
    information[np.ix_(kd, kd)] += ld
    eta[kd] += ld @ xd
    covariance = _inverse(information, "combined information")
    covariance = 0.5 * (covariance + covariance.T)
    values = covariance @ eta
    # assemble: combined state, then everything else of the prior, then anything else of the data
    parameters = []
    for pid in state:
        source = data[pid] if pid in observed else prior[pid]
        k = index[pid]
        parameters.append(Parameter(pid, float(values[k]), source.unit, float(math.sqrt(max(covariance[k, k], 0.0))), "estimated"))
    kept = [p for p in prior.parameters if p.id not in index]
    kept += [p for p in data.parameters if p.id not in index and p.id not in prior.ids]
    ids = state + [p.id for p in kept]
    full = np.zeros((len(ids), len(ids)))
    full[:n, :n] = covariance
    for k, p in enumerate(kept, start=n):
        source = prior if p.id in prior.ids else data
        full[k, k] = source.covariance_of([p.id])[0, 0]
        if not math.isfinite(p.sigma):
            full[k, :] = math.nan
            full[:, k] = math.nan
    provenance = Provenance(
        software=data.provenance.software,
        procedure=data.provenance.procedure,
        stages=tuple(dict.fromkeys(prior.provenance.stages + data.provenance.stages + ("recal",))),
        inputs=prior.provenance.inputs + tuple(f for f in data.provenance.inputs if f not in prior.provenance.inputs),
        created=data.provenance.created,
        data_start=data.provenance.data_start,
        data_end=data.provenance.data_end,
    )
    note = f"field recalibration: prior = previous record{f' (sha256 {prior_sha256})' if prior_sha256 else ''}"
    return replace(
        data,
        parameters=tuple(parameters) + tuple(kept),
        covariance=full,
        provenance=provenance,
        site=data.site or prior.site,
        determined=tuple(dict.fromkeys(prior.determined + data.determined)),
        notes=data.notes + (note,),
        noise_model=data.noise_model if data.noise_model is not None else prior.noise_model,
    )


def _inverse(matrix, what: str):
    import numpy as np

    try:
        inverse = np.linalg.inv(matrix)
    except np.linalg.LinAlgError:
        raise InputError(
            f"the covariance of the {what} is singular", field="covariance", expected="a positive-definite block for 'estimated' parameters"
        ) from None
    if not np.all(np.isfinite(inverse)):
        raise InputError(f"the covariance of the {what} is not finite", field="covariance")
    return inverse
