"""A real calibration fit for the report tests: 18 static positions, weighted Gauss-Newton on Eq. 6.

The observations are the exact forward model of a drawn instrument plus Gaussian noise
of known σ; the fit uses the model's analytic Jacobian.  This exercises the report with
a genuine covariance, χ²_ν and residuals (no number is typed in).
"""

from __future__ import annotations

import numpy as np

from stableins.conventions import MICRO_G
from stableins.errormodel import GIMBAL_TERMS, ErrorModel
from stableins.estimators.result import FitResult
from stableins.reporting.evidence import fit_to_dict

GRAVITY = 9.8015


def positions() -> np.ndarray:
    """18 platform-frame specific-force directions: ±each axis, and 45° in each plane."""
    out = [s * e for e in np.eye(3) for s in (1.0, -1.0)]
    for i, j in ((0, 1), (1, 2), (0, 2)):
        for si in (1.0, -1.0):
            for sj in (1.0, -1.0):
                v = np.zeros(3)
                v[i], v[j] = si, sj
                out.append(v / np.sqrt(2.0))
    return GRAVITY * np.array(out)


def truth(seed: int) -> dict[str, float]:
    rng = np.random.default_rng(seed)
    return {t.id: t.reference + 2.0 * rng.normal() * t.nominal for t in ErrorModel.standard()}


def fit(seed: int = 1, noise_ug: float = 3.0, values: dict[str, float] | None = None, passes: int = 2) -> FitResult:
    """Weighted least-squares fit of the 15 core parameters to noisy simulated dwell means."""
    rng = np.random.default_rng(seed)
    model = ErrorModel.standard()
    true = values or truth(seed)
    f_p = np.tile(positions(), (passes, 1))
    n = f_p.shape[0]
    sigma = noise_ug * MICRO_G * rng.uniform(0.7, 1.3, size=(n, 3))
    observed = model.forward(f_p, true) + sigma * rng.normal(size=(n, 3))
    x = model.vector(model.nominal_values())
    for _ in range(4):
        current = model.mapping(x)
        jac = model.jacobian(f_p, current).reshape(3 * n, len(model))
        r = (observed - model.forward(f_p, current)).reshape(-1)
        w = 1.0 / sigma.reshape(-1)
        step, *_ = np.linalg.lstsq(jac * w[:, None], r * w, rcond=None)
        x = x + step
    current = model.mapping(x)
    jac = model.jacobian(f_p, current).reshape(3 * n, len(model))
    w = 1.0 / sigma.reshape(-1)
    normal = (jac * w[:, None]).T @ (jac * w[:, None])
    covariance = np.linalg.inv(normal)
    residuals = (observed - model.forward(f_p, current)).reshape(-1)
    labels = tuple(f"pos {k % 18 + 1} f_{a}" for k in range(n) for a in "xyz")
    return FitResult(
        stage="fine",
        terms=model.terms,
        values=x,
        covariance=covariance,
        status=("estimated",) * len(model),
        residuals=residuals,
        residual_sigma=sigma.reshape(-1),
        residual_labels=labels,
        rank=int(np.linalg.matrix_rank(jac * w[:, None])),
    )


SITE = {
    "serial_number": "ACC-0042",
    "latitude": np.radians(45.7733),
    "height": 212.0,
    "gravity": GRAVITY,
    "gravity_source": "WGS-84 normal gravity (NIMA TR8350.2 Eq. 4-1, 4-3)",
    "sample_rate": 200.0,
    "gimbal_senses": [1, 1, 1, 1],
    "base_attitude": [0.0, 0.0, 0.0],
    "reference_temperature": 25.0,
    "damping": {},
    "extra": {"laboratory": "Inertial Sensor Laboratory, Building 4", "customer": "Navigation Systems Division"},
}


def record(result: FitResult, *, started: str = "2026-11-20T08:00:00Z", inputs: dict[str, str] | None = None) -> dict:
    """A calibration record (JSON mapping) carrying ``result`` and three gimbal offsets not estimated."""
    params = [
        {"id": t.id, "value": float(v), "unit": t.si_unit, "sigma": float(s), "status": st}
        for t, v, s, st in zip(result.terms, result.values, result.sigma, result.status, strict=True)
    ]
    params.append(
        {
            "id": GIMBAL_TERMS[0].id,
            "value": 0.0,
            "unit": "rad",
            "sigma": 0.0,
            "status": "gauge",
            "note": "a rotation about the vertical leaves every gravity reading unchanged; fixed at 0 (gauge)",
        }
    )
    for term in GIMBAL_TERMS[1:]:
        params.append(
            {
                "id": term.id,
                "value": None,
                "unit": "rad",
                "sigma": None,
                "status": "unidentifiable",
                "note": "positions were given as platform-frame specific force: the data carry no angle-sensor information",
            }
        )
    return {
        "schema_version": 1,
        "serial_number": SITE["serial_number"],
        "parameters": params,
        "covariance": {"ids": list(result.ids), "matrix": result.covariance.tolist()},
        "provenance": {
            "software_version": "0.1.0",
            "inputs": inputs or {},
            "procedure": {
                "name": "wu2018-18-position",
                "version": "1",
                "positions": 18,
                "dwell": 600,
                "settle": 30,
                "passes": 2,
                "stages": ["coarse", "fine"],
            },
            "started": started,
            "finished": started.replace("08:00", "14:30"),
        },
        "site": SITE,
        "environment": {"temperature": {"mean": 24.81, "min": 24.62, "max": 25.07}},
        "notes": ["Platform warmed up for 2 h before the first position."],
        "stages": [fit_to_dict(result)],
    }
