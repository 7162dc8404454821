"""The gauge of the device stages.

Which zero offset the positions cannot see, which added terms the data do not determine, and the equivalent values
under another gauge.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from stableins.conventions import (
    DEFAULT_GIMBALS,
    GimbalConfiguration,
)
from stableins.errormodel import ErrorModel
from stableins.estimators.design import UNDETERMINED_RATIO, DesignAnalysis, Gauge, analyze_design, choose_gauge, undetermined

#: Ids tried first as gauge parameters (platform azimuth, then the offsets).
GAUGE_PREFERENCE = ("theta10", "theta30", "theta20")


def gauge_preference(extra_ids: Sequence[str]) -> tuple[str, ...]:
    """Gauge candidates in order: the platform azimuth ``θ10``, then added (discovered) terms, then the other offsets.

    An added term that these data cannot separate from the model is held at its prior value
    (status ``unidentifiable``) rather than letting a standard parameter become the gauge.
    """
    return GAUGE_PREFERENCE[:1] + tuple(extra_ids) + GAUGE_PREFERENCE[1:]


def held_terms_note(held: Mapping[str, Sequence[str]], values: Mapping[str, float], model: ErrorModel, stage: str) -> str:
    """Note for added terms held at their prior value because these data do not determine them (:func:`.design.undetermined`)."""
    parts = "; ".join(
        f"{h} = {float(model[h].to_engineering(values[h])):.4g} {model[h].unit} (with {', '.join(involved) or 'the model'})"
        for h, involved in held.items()
    )
    return (
        f"not determined by the {stage} data, held at the prior value (status unidentifiable): {parts}; "
        f"the combination's 1σ would exceed {UNDETERMINED_RATIO:g}× its typical size"
    )


def hold_and_gauge(
    weighted_jacobian: NDArray[np.float64],
    model: ErrorModel,
    scales: NDArray[np.float64],
    extra_ids: Sequence[str],
    preference: Sequence[str],
) -> tuple[DesignAnalysis, Gauge, dict[str, tuple[str, ...]]]:
    """Design analysis and gauge of the standard parameters, and the added terms these data do not determine.

    The gauge is chosen on the standard columns alone (so a discovered term never becomes a
    gauge of the standard model); then :func:`.design.undetermined` names the added terms to hold.
    """
    standard = [k for k, i in enumerate(model.ids) if i not in extra_ids]
    analysis = analyze_design(weighted_jacobian[:, standard], [model.ids[k] for k in standard], scales[standard])
    gauge = choose_gauge(analysis, preference, scales[standard])
    held = undetermined(weighted_jacobian, model.ids, scales, extra_ids, fixed=gauge.fixed)
    return analysis, gauge, held


def final_design(
    weighted_jacobian: NDArray[np.float64], model: ErrorModel, scales: NDArray[np.float64], held: Sequence[str]
) -> DesignAnalysis:
    """Analysis of the design at the solution with the held terms' columns removed (they are not estimated)."""
    a = np.array(weighted_jacobian, dtype=float)
    a[:, [model.index(h) for h in held]] = 0.0
    return analyze_design(a, model.ids, scales)


def gauge_equivalent(values: Mapping[str, float], configuration: GimbalConfiguration = DEFAULT_GIMBALS) -> dict[str, float]:
    r"""Exactly equivalent parameters with ``θ10 = 0`` (the coarse gauge).

    With ``φ = s1 θ10``, ``SF^{-1} C_p^a R3(φ) = SF'^{-1} C'`` where, row by row
    (``c = cos φ``, ``s = sin φ``)::

        k_x = c − β_xz s:  β_xz' = (s + β_xz c)/k_x,  β_xy' = β_xy/k_x,  SF_x' = SF_x / k_x
        k_y = c − β_yz s:  β_yz' = (s + β_yz c)/k_y,  β_yx' = β_yx/k_y,  SF_y' = SF_y / k_y
        β_zy' = β_zy c + β_zx s,  β_zx' = β_zx c − β_zy s

    Outputs are identical for every orientation (biases and ``K2`` unchanged), so this is
    what a calibration in the gauge ``θ10 = 0`` recovers from noiseless data.
    """
    v = dict(values)
    phi = configuration.senses[0] * float(v.get("theta10", 0.0))
    c, s = np.cos(phi), np.sin(phi)
    bxz, bxy, byz, byx = (float(v.get(k, 0.0)) for k in ("beta_xz", "beta_xy", "beta_yz", "beta_yx"))
    bzy, bzx = float(v.get("beta_zy", 0.0)), float(v.get("beta_zx", 0.0))
    kx, ky = c - bxz * s, c - byz * s
    v.update(
        beta_xz=(s + bxz * c) / kx,
        beta_xy=bxy / kx,
        beta_yz=(s + byz * c) / ky,
        beta_yx=byx / ky,
        beta_zy=bzy * c + bzx * s,
        beta_zx=bzx * c - bzy * s,
        sf_x=float(v.get("sf_x", 1.0)) / kx,
        sf_y=float(v.get("sf_y", 1.0)) / ky,
        theta10=0.0,
    )
    return v
