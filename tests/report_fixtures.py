"""A real calibration fit for the report tests: 18 static positions, weighted Gauss-Newton on Eq. 6.

The observations are the exact forward model of a drawn instrument plus Gaussian noise
of known σ; the fit uses the model's analytic Jacobian.  This exercises the report with
a genuine covariance, χ²_ν and residuals (no number is typed in).
"""

from __future__ import annotations

import numpy as np

from stableins.conventions import MICRO_G
from stableins.data.metadata import metadata_from_document
from stableins.errormodel import GIMBAL_TERMS, ErrorModel
from stableins.estimators.device_settings import DeviceFitSettings, StatedSlowNoise
from stableins.estimators.result import FitResult, Stage
from stableins.records import CalibrationRecord, Entry, RunInfo, StageRun

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


SITE_DOCUMENT = {
    "serial_number": "ACC-0042",
    "latitude": {"value": 45.7733, "unit": "deg"},
    "height": {"value": 212.0, "unit": "m"},
    "gravity": {"value": GRAVITY, "unit": "m/s^2"},
    "gravity_source": "WGS-84 normal gravity (NIMA TR8350.2 Eq. 4-1, 4-3)",
    "sample_rate": {"value": 200.0, "unit": "Hz"},
    "gimbal_senses": [1, 1, 1, 1],
    "base_attitude": {"value": [0.0, 0.0, 0.0], "unit": "deg", "order": ["yaw", "pitch", "roll"]},
    "reference_temperature": {"value": 25.0, "unit": "degC"},
    "damping": {},
    "extra": {"laboratory": "Inertial Sensor Laboratory, Building 4", "customer": "Navigation Systems Division"},
}


def record(result: FitResult, *, started: str = "2026-11-20T08:00:00Z", inputs: tuple = ()) -> dict:
    """A calibration record document (stableins.records format) of ``result`` plus three gimbal offsets not estimated.

    Its stage run carries the fit's residual evidence, the instrument temperature the data carry, an
    entry a person made and the settings; the calibration carries the laboratory and customer fields.
    """
    n = len(result.terms)
    covariance = np.zeros((n + 3, n + 3))
    covariance[:n, :n] = result.covariance
    full = FitResult(
        stage=result.stage,
        terms=result.terms + GIMBAL_TERMS,
        values=np.concatenate([result.values, np.zeros(3)]),
        covariance=covariance,
        status=result.status + ("gauge", "unidentifiable", "unidentifiable"),
        residuals=result.residuals,
        residual_sigma=result.residual_sigma,
        residual_labels=result.residual_labels,
        rank=result.rank,
        notes=(
            "theta10: a rotation about the vertical leaves every gravity reading unchanged; fixed at 0 (gauge)",
            "theta20, theta30: positions were given as platform-frame specific force, so the data carry no angle-sensor information",
        ),
        settings=DeviceFitSettings(Stage.FINE, slow_noise=StatedSlowNoise(False)),  # a record of the first schema-2 version
    )
    run = RunInfo(
        procedure="wu2018-18-position",
        inputs=inputs,
        data_start=started,
        data_end=started.replace("08:00", "14:30"),
        sample_rate=200.0,
        entries=(Entry("lab_temperature", 21.5, "degC", "Laboratory temperature at the start"),),
        environment={"temperature": {"mean": 24.81, "min": 24.62, "max": 25.07, "unit": "degC"}},
        created=started.replace("08:00", "14:35"),
    )
    rec = CalibrationRecord.from_fit_result(
        full,
        StageRun.from_fit(full, calibration="", run=run, fits=(result,)),  # the evidence of the fit itself
        site=metadata_from_document(SITE_DOCUMENT),
        notes=["Platform warmed up for 2 h before the first position."],
        calibration_entries=(
            Entry("laboratory", "Inertial Sensor Laboratory, Building 4"),
            Entry("customer", "Navigation Systems Division"),
        ),
    )
    return rec.to_document()


def procedure_with(tables: str, base: str = "device-fine") -> str:
    """A shipped procedure whose conformity tables are ``tables`` (``report --procedure`` reads a whole procedure, as ``run`` does)."""
    from stableins.procedures.definition import PROCEDURE_DIRECTORY

    text = (PROCEDURE_DIRECTORY / f"{base}.toml").read_text(encoding="utf-8")
    return text[: text.index("\n[tolerances]\n")] + "\n" + tables
