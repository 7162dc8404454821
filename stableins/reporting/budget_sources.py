r"""The Type B input groups of the uncertainty budget, one evaluation each (:mod:`stableins.reporting.budget`).

Each evaluation propagates one input group through the record, :math:`\delta x = P \sum_k \partial\eta_k/\partial q\,\delta q`
(the module docstring of :mod:`stableins.reporting.budget`), and returns the group's standard uncertainty of every
parameter with the :class:`~stableins.reporting.budget.Source` the certificate lists;
:func:`uncertainty_budget` gathers them into the record's :class:`~stableins.reporting.budget.Budget`.
"""

from __future__ import annotations

import fnmatch
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from stableins.conventions import ARCSEC, DEG_PER_HOUR
from stableins.errormodel import Term
from stableins.estimators.device_settings import DeviceFitSettings, DeviceSessionSettings
from stableins.estimators.poses import PoseSettings
from stableins.estimators.result import InputSensitivity, Stage
from stableins.estimators.system.settings import SystemSettings
from stableins.records import CalibrationRecord, StageRun
from stableins.reporting.budget import (
    ANGLE_SENSOR_BOUND,
    GROUPS,
    GYRO_DRIFT_BOUND,
    MGAL,
    NORMAL_GRAVITY_UNCERTAINTY,
    Budget,
    Source,
    UncertaintyInputs,
    gravity_direction,
)
from stableins.reporting.rounding import scientific
from stableins.status import Status

_NORMAL_GRAVITY_TEXT = (
    "assumed: the normal-gravity formula omits the local gravity anomaly (tens of mGal, beyond 100 mGal in mountains); "
    "a surveyed g removes most of it"
)
_UNSTATED_GRAVITY_TEXT = "assumed as for the normal-gravity formula: the site states no uncertainty for its g"
_ANGLE_TEXT = "assumed: ±1″ static accuracy (Wu et al. 2018 §6), rectangular"
_DRIFT_TEXT = "assumed: ±0.001 °/h (Wu et al. 2018 §6: drift below 0.001 °/h), rectangular"
_LOOP_TEXT = "software constants of the navigation computer, taken as exact"
_LOOP_NAMES = {"zeta": "ζ", "omega_s": "ω_s", "schuler_frequency": "ω_s", "k1": "k_1", "k2": "k_2", "k3": "k_3"}

#: The stored sensitivities of the record's stages by input group: ``(stage, sensitivity)`` pairs.
Stored = Mapping[str, Sequence[tuple[StageRun, InputSensitivity]]]


@dataclass(frozen=True)
class Propagation:
    """What every input group's evaluation shares: the record's parameters and covariance ``P``.

    ``covariance`` has the rows and columns of held parameters (gauge, unidentifiable) zeroed; ``type_a`` is the
    square root of its diagonal; ``terms`` gives the engineering units of the parameters.
    """

    ids: Sequence[str]
    covariance: NDArray[np.float64]
    type_a: NDArray[np.float64]
    terms: Mapping[str, Term]

    @property
    def n(self) -> int:
        """Return the number of parameters of the record."""
        return len(self.ids)

    def to_record(self, sensitivity_ids: Sequence[str], vector: NDArray[np.float64]) -> NDArray[np.float64]:
        """Return a stage's vector over ``sensitivity_ids`` as a vector over the record's parameters (zero elsewhere)."""
        out = np.zeros(self.n)
        for k, pid in enumerate(sensitivity_ids):
            if pid in self.ids:
                out[self.ids.index(pid)] += vector[k]
        return out

    def to_record_matrix(self, sensitivity_ids: Sequence[str], matrix: NDArray[np.float64]) -> NDArray[np.float64]:
        """Return a stage's matrix over ``sensitivity_ids`` as a matrix over the record's parameters (zero elsewhere)."""
        index = [self.ids.index(p) for p in sensitivity_ids if p in self.ids]
        keep = [k for k, p in enumerate(sensitivity_ids) if p in self.ids]
        out = np.zeros((self.n, self.n))
        out[np.ix_(index, index)] = matrix[np.ix_(keep, keep)]
        return out

    def largest(self, vector: NDArray[np.float64]) -> str:
        """Return the largest effect on a parameter, relative to its Type A, in engineering units as text."""
        best = None
        for k, pid in enumerate(self.ids):
            term = self.terms.get(pid)
            if term is None or not vector[k]:
                continue
            value = abs(float(term.sigma_to_engineering(vector[k])))
            relative = value / max(float(term.sigma_to_engineering(self.type_a[k])), 1e-300) if self.type_a[k] > 0 else 0.0
            if best is None or relative > best[0]:
                best = (relative, pid, value, term.unit)
        if best is None:
            return "no effect on the parameters"
        from stableins.reporting.content import printed_unit
        from stableins.reporting.rounding import significant_digits

        return f"largest on {best[1]}: {significant_digits(best[2], 2)} {printed_unit(best[3])}"


@dataclass(frozen=True)
class Evaluation:
    """One input group's standard uncertainty of every parameter [SI], its source, and conditions of validity."""

    contribution: NDArray[np.float64]
    source: Source
    conditions: tuple[str, ...] = ()


def stored_sensitivities(record: CalibrationRecord) -> dict[str, list[tuple[StageRun, InputSensitivity]]]:
    """Return the ``(stage, sensitivity)`` pairs the record's stages store, by input group."""
    stored: dict[str, list[tuple[StageRun, InputSensitivity]]] = {}
    for stage in record.stages:
        for s in stage.sensitivities:
            stored.setdefault(s.group, []).append((stage, s))
    return stored


def _gravity_uncertainty(site: Any, inputs: UncertaintyInputs) -> tuple[float, str, str]:
    """Return ``(u_g, origin, distribution)``: the site's statement, the procedure's, or the normal-gravity default."""
    if site.gravity_uncertainty is not None:
        return float(site.gravity_uncertainty), "stated with the site", "normal"
    if inputs.gravity is not None:
        return inputs.gravity, f"procedure ({_name(inputs.source)})", "normal"
    if "normal" in site.gravity_source.lower():
        return NORMAL_GRAVITY_UNCERTAINTY, _NORMAL_GRAVITY_TEXT, "normal"
    return NORMAL_GRAVITY_UNCERTAINTY, _UNSTATED_GRAVITY_TEXT, "normal"


def gravity(record: CalibrationRecord, inputs: UncertaintyInputs, propagation: Propagation) -> Evaluation:
    """Evaluate the local gravity: ``c_g = P Σ Λ_k v`` with ``v = ∂x/∂g`` (:func:`~stableins.reporting.budget.gravity_direction`)."""
    site = record.site
    n, covariance = propagation.n, propagation.covariance
    if site is None:
        source = Source("gravity", "not recorded", "—", "—", "the record has no site metadata", "not evaluated", "not evaluated")
        return Evaluation(np.zeros(n), source)
    g = float(site.gravity)
    u_g, origin, distribution = _gravity_uncertainty(site, inputs)
    direction = gravity_direction(record, propagation.terms)
    gradient = np.zeros(n)
    likelihoods = [s.likelihood for s in record.stages if s.likelihood is not None]
    for lik in likelihoods:
        v = np.array([direction.get(pid, 0.0) for pid in lik.ids])
        gradient += propagation.to_record(lik.ids, lik.information @ v)
    c = covariance @ gradient if likelihoods else np.array([direction.get(pid, 0.0) for pid in propagation.ids])
    source = Source(
        "gravity",
        f"{g:.7f} m/s² ({site.gravity_source})",
        f"{_mgal(u_g)} mGal" + ("" if u_g == 0 else f" ({scientific(u_g)} m/s²)"),
        distribution,
        origin,
        "δSF/SF = δg/g on every scale factor (" + propagation.largest(c * u_g) + ")" if u_g > 0 else "δSF/SF = δg/g on every scale factor",
    )
    return Evaluation(np.abs(c) * u_g, source)


def angle_sensors(record: CalibrationRecord, inputs: UncertaintyInputs, propagation: Propagation, stored: Stored) -> Evaluation:
    """Evaluate the static reading error of every dwell's angle sensors, independent from dwell to dwell: ``u² P (Σ S_k) P``."""
    n, covariance = propagation.n, propagation.covariance
    u_angle, angle_origin = (
        (inputs.angle_sensor, f"procedure ({_name(inputs.source)})")
        if inputs.angle_sensor is not None
        else (ANGLE_SENSOR_BOUND / math.sqrt(3.0), _ANGLE_TEXT)
    )
    angle = stored.get("angle_sensors", [])
    if angle:
        total = np.zeros((n, n))
        for _, s in angle:
            if s.covariance is not None:
                total += propagation.to_record_matrix(s.ids, s.covariance)
        cov = covariance @ total @ covariance * u_angle**2
        contribution = np.sqrt(np.clip(np.diag(cov), 0.0, None))
        effect = f"each dwell's readings as independent errors of the coarse stage's orientations ({propagation.largest(contribution)})"
        source = Source("angle_sensors", "static readings of the three gimbal angle sensors", f"{u_angle / ARCSEC:.2g}″ per reading",
                        "rectangular" if inputs.angle_sensor is None else "normal", angle_origin, effect)  # fmt: skip
        return Evaluation(contribution, source)
    device = [s for s in record.stages if s.name in (Stage.COARSE, Stage.DEVICE)]
    why = (
        "no stage of the record reads the gimbal angles (the fine and system stages do not)"
        if not device
        else "the record's coarse stage stores no angle-sensor sensitivity (written by an earlier version): not evaluated"
    )
    source = Source("angle_sensors", "static readings of the gimbal angle sensors", f"{u_angle / ARCSEC:.2g}″ per reading",
                    "rectangular", angle_origin, why, "not evaluated" if device else "not applicable")  # fmt: skip
    return Evaluation(np.zeros(n), source)


def _drift_uncertainty(stage: StageRun, inputs: UncertaintyInputs) -> tuple[float, str]:
    """Return ``(u, origin)`` of the gyro drift per axis: the stage's setting, the procedure's, or the paper's bound."""
    stated = stage.settings.options.gyro_drift_uncertainty if isinstance(stage.settings, SystemSettings) else None
    if stated is not None and math.isfinite(stated):
        return float(stated), "given with the system stage"
    if inputs.gyro_drift is not None:
        return inputs.gyro_drift, f"procedure ({_name(inputs.source)})"
    return GYRO_DRIFT_BOUND / math.sqrt(3.0), _DRIFT_TEXT


def gyro_drift(record: CalibrationRecord, inputs: UncertaintyInputs, propagation: Propagation, stored: Stored) -> Evaluation:
    """Evaluate the gyro drift, the system stage's input, per platform axis (axes independent)."""
    n, covariance = propagation.n, propagation.covariance
    drift = stored.get("gyro_drift", [])
    systems = [s.settings for s in record.stages if s.name == Stage.SYSTEM]
    measured = any(isinstance(s, SystemSettings) and s.measures_gyro_drift for s in systems)
    if not drift and measured:  # a parameter of the record (Type A), not an input: its σ is in the covariance
        source = Source("gyro_drift", "constant drift in the platform frame, measured by the system stage (gimbal readings)",
                        "—", "—", "the record (gyro_drift_x, gyro_drift_y, gyro_drift_z)",
                        "estimated with the accelerometer terms: its uncertainty is in their σ (Type A)", "not applicable")  # fmt: skip
        return Evaluation(np.zeros(n), source)
    if not drift:
        return Evaluation(np.zeros(n), _system_input_missing(record, "gyro_drift", "constant drift in the platform frame"))
    vectors: dict[Any, NDArray[np.float64]] = {}
    origins = set()
    for stage, s in drift:
        u, origin = _drift_uncertainty(stage, inputs)
        origins.add((u, origin))
        if s.gradient is not None:
            vectors[s.input] = vectors.get(s.input, np.zeros(n)) + propagation.to_record(s.ids, s.gradient) * u
    per_axis = [covariance @ v for v in vectors.values()]
    contribution = np.sqrt(sum(np.abs(c) ** 2 for c in per_axis)) if per_axis else np.zeros(n)
    given = [stage.settings.options.known_gyro_drift if isinstance(stage.settings, SystemSettings) else None for stage, _ in drift]
    value = (
        "not given: assumed zero"
        if all(x is None for x in given)
        else "given: " + ", ".join(f"{float(v) / DEG_PER_HOUR:.4g}" for v in next(x for x in given if x is not None)) + " °/h (x, y, z)"
    )
    u_text = "; ".join(sorted({f"{u / DEG_PER_HOUR:.2g} °/h per axis" for u, _ in origins}))
    origin = "; ".join(sorted({o for _, o in origins}))
    source = Source(
        "gyro_drift",
        f"constant drift in the platform frame, {value}",
        u_text,
        "rectangular" if origin == _DRIFT_TEXT else "normal",
        origin,
        "the system stage re-run with each axis perturbed; the drift drives the loop's Earth-rate mode and moves the "
        f"attitude coefficients ({propagation.largest(contribution)})",
    )
    return Evaluation(contribution, source)


def damping_loop(record: CalibrationRecord, inputs: UncertaintyInputs, propagation: Propagation, stored: Stored) -> Evaluation:
    """Evaluate the damping-loop parameters: software constants of the navigation computer unless the procedure says otherwise."""
    n, covariance = propagation.n, propagation.covariance
    loop = stored.get("damping_loop", [])
    if not loop:
        return Evaluation(np.zeros(n), _system_input_missing(record, "damping_loop", "damping-loop parameters"))
    relative = inputs.damping_loop if inputs.damping_loop is not None else 0.0
    per_parameter = [covariance @ (propagation.to_record(s.ids, s.gradient) * abs(s.value)) for _, s in loop if s.gradient is not None]
    contribution = relative * np.sqrt(sum(np.abs(c) ** 2 for c in per_parameter))
    one_percent = 0.01 * np.sqrt(sum(np.abs(c) ** 2 for c in per_parameter))
    names = ", ".join(dict.fromkeys(_LOOP_NAMES.get(s.input.partition(".")[2], s.input) for _, s in loop))
    source = Source(
        "damping_loop",
        f"{names} of the INS damping loop (site metadata)",
        f"{relative:.2g} relative" if relative else "0",
        "normal",
        f"procedure ({_name(inputs.source)})" if inputs.damping_loop is not None else _LOOP_TEXT,
        f"the system stage re-run with each parameter perturbed; a 1 % error of each would give {propagation.largest(one_percent)}",
    )
    return Evaluation(contribution, source)


def temperature(record: CalibrationRecord, inputs: UncertaintyInputs, propagation: Propagation) -> Evaluation:
    """Evaluate the instrument temperature: the recorded range, with a stated sensitivity or as a condition of validity."""
    low, high, mean = _temperature_range(record)
    contribution = np.zeros(propagation.n)
    if low is None or high is None or mean is None:
        condition = "The instrument temperature is not recorded in the data: the results apply to the conditions of the calibration."
        effect = "the results apply to the conditions of the calibration"
        return Evaluation(contribution, Source("temperature", "not recorded", "—", "—", "—", effect, "condition"), (condition,))
    spread = (high - low) / math.sqrt(12.0)
    stated = {pid: _pattern(inputs.temperature_sensitivity, pid) for pid in propagation.ids}
    for k, pid in enumerate(propagation.ids):
        sensitivity = stated[pid]
        term = propagation.terms.get(pid)
        if sensitivity is not None and term is not None and propagation.type_a[k] > 0:
            contribution[k] = float(term.from_engineering(sensitivity * spread) - term.from_engineering(0.0))
    known = any(v is not None for v in stated.values())
    source = Source(
        "temperature",
        f"recorded range {low:.2f} to {high:.2f} °C (mean {mean:.2f} °C)",
        f"{spread:.2g} K",
        "rectangular",
        f"recorded range; sensitivities from the procedure ({_name(inputs.source)})" if known else "recorded range",
        "u = |k_T| (T_max − T_min)/√12"
        if known
        else "no temperature sensitivity known to this calibration: not in the budget, stated as a condition of validity",
        "evaluated" if known else "condition",
    )
    condition = (
        f"The results apply to instrument temperatures from {low:.2f} to {high:.2f} °C (recorded during the calibration"
        f"{'' if known else '; no temperature sensitivity is known to it'})."
    )
    return Evaluation(contribution, source, (condition,))


def _system_input_missing(record: CalibrationRecord, group: str, value: str) -> Source:
    """Return the source of a system-stage input the record stores no sensitivity for: not applicable, or not evaluated."""
    system = any(s.name == Stage.SYSTEM for s in record.stages)
    effect = (
        "the record's system stage stores no sensitivity (written by an earlier version): not evaluated"
        if system
        else "no system-level stage in the record: the device stages do not depend on it"
    )
    return Source(group, value, "—", "—", "—", effect, "not evaluated" if system else "not applicable")


def _temperature_range(record: CalibrationRecord) -> tuple[float | None, float | None, float | None]:
    """Return the lowest, highest and mean instrument temperature the stages recorded [°C] (None: not recorded)."""
    lows, highs, means = [], [], []
    for stage in record.stages_run:
        t = stage.environment.get("temperature") if isinstance(stage.environment, Mapping) else None
        if isinstance(t, Mapping) and all(isinstance(t.get(k), int | float) for k in ("min", "max", "mean")):
            lows.append(float(t["min"]))
            highs.append(float(t["max"]))
            means.append(float(t["mean"]))
    if not lows:
        return None, None, None
    return min(lows), max(highs), float(np.mean(means))


def _pattern(table: Mapping[str, float], parameter_id: str) -> float | None:
    """Return the sensitivity ``table`` states for a parameter: its id, else the longest matching glob pattern."""
    if parameter_id in table:
        return table[parameter_id]
    matches = [p for p in table if fnmatch.fnmatchcase(parameter_id, p)]
    return table[max(matches, key=len)] if matches else None


def _name(source: str) -> str:
    """Return a procedure file as the certificate names it (its file name)."""
    return Path(source).name if source else "procedure"


def _mgal(u: float) -> str:
    """Return an uncertainty of g in mGal as text."""
    from stableins.reporting.rounding import significant_digits

    return significant_digits(u / MGAL, 2) if u else "0"


def slow_noise(record: CalibrationRecord, propagation: Propagation, stored: Stored) -> Evaluation:
    """Evaluate the slow noise the device dwells allow but do not resolve: ``P (Σ S_k) P``, the upper limit taken whole.

    A device stage whose measured noise model found no slow noise stores ``S = Λ(Σ_f − Σ)Λ``, with ``Σ_f`` its estimate's
    covariance refitted at the largest floor the dwells allow (:func:`stableins.estimators.device.slow_noise_sensitivity`).
    """
    n, covariance = propagation.n, propagation.covariance
    entries = stored.get("slow_noise", [])
    if not entries:
        why = "the noise model was given or measured with its slow noise resolved (no device stage reported an unresolved floor)"
        return Evaluation(np.zeros(n), Source("slow_noise", "—", "—", "—", "—", why, "not applicable"))
    total = np.zeros((n, n))
    limits = []
    for stage, s in entries:
        if s.covariance is not None:
            total += propagation.to_record_matrix(s.ids, s.covariance)
        limits += _bias_instability_limit(stage)
    cov = covariance @ total @ covariance
    contribution = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    upper = f"up to {max(limits):.2g} µg (upper limit the dwells allow)" if limits else "the upper limit the dwells allow"
    source = Source(
        "slow_noise",
        "bias instability not detected in the dwells (the σ rest on white noise)",
        upper,
        "upper limit, taken whole",
        "the device stage's slow-noise test and the refit with the largest floor",
        f"the difference between the largest floor's covariance and the recorded one, through the record "
        f"({propagation.largest(contribution)})",
    )
    return Evaluation(contribution, source)


def _bias_instability_limit(stage: StageRun) -> list[float]:
    """Return the upper limit of the bias instability [µg] the stage's measured noise model states (empty if none)."""
    from stableins.conventions import MICRO_G

    settings = stage.settings
    model = settings.noise_model if isinstance(settings, DeviceFitSettings | DeviceSessionSettings | PoseSettings) else None
    if model is None:
        return []
    upper = model.limits("bias_instability")[1]
    return [float(np.max(upper)) / MICRO_G] if np.all(np.isfinite(upper)) else []


def uncertainty_budget(
    record: CalibrationRecord, inputs: UncertaintyInputs | None = None, terms: Mapping[str, Term] | None = None
) -> Budget:
    """Return the budget of every parameter of ``record`` (:mod:`stableins.reporting.budget`), with ``inputs`` from the procedure."""
    from stableins.discovery.library import all_terms

    inputs = inputs or UncertaintyInputs()
    covariance = np.nan_to_num(np.asarray(record.covariance, dtype=float))
    held = [k for k, p in enumerate(record.parameters) if p.status in (Status.GAUGE, Status.UNIDENTIFIABLE)]
    covariance[held, :] = 0.0
    covariance[:, held] = 0.0
    type_a = np.sqrt(np.clip(np.diag(covariance), 0.0, None))
    propagation = Propagation(record.ids, covariance, type_a, dict(terms or all_terms()))
    stored = stored_sensitivities(record)
    evaluations = {
        "gravity": gravity(record, inputs, propagation),
        "angle_sensors": angle_sensors(record, inputs, propagation, stored),
        "gyro_drift": gyro_drift(record, inputs, propagation, stored),
        "damping_loop": damping_loop(record, inputs, propagation, stored),
        "temperature": temperature(record, inputs, propagation),
        "slow_noise": slow_noise(record, propagation, stored),
    }
    return Budget(
        record.ids,
        type_a,
        {g: evaluations[g].contribution for g in GROUPS},
        tuple(evaluations[g].source for g in GROUPS),
        evaluations["temperature"].conditions,
    )
