"""One step of a model history: the decision on an added effect, the fit statistics before and after, per channel."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import StrEnum
from typing import TYPE_CHECKING, Any, TypeGuard

import numpy as np

from stableins.conventions import MICRO_G
from stableins.estimators.result import FitResult
from stableins.status import Status

if TYPE_CHECKING:  # pragma: no cover
    pass


class Decision(StrEnum):
    """What became of a step's model in a calibration (the record's discovery history)."""

    BASELINE = "baseline"  #: the model before any effect was added
    KEPT = "kept"  #: the effect is supported by the data (F-test p < α) and stays in the model
    NOT_SUPPORTED = "not supported"  #: p ≥ α: the data do not show it; left out of the record
    NOT_DETERMINED = "not determined"  #: the data cannot separate it from the model; left out of the record
    KEPT_ON_REQUEST = "kept on request"  #: p ≥ α but kept (``--keep-unsupported``)

    @property
    def in_model(self) -> bool:
        """Whether the step's model is the one the following steps build on."""
        return self in (Decision.BASELINE, Decision.KEPT, Decision.KEPT_ON_REQUEST)


#: Output channels a residual label may end with (device dwell means per axis, the fine stage's ``|f|``).
CHANNELS = ("f_x", "f_y", "f_z", "|f|")


@dataclass(frozen=True)
class ModelStep:
    """One model in the history.

    Attributes
    ----------
    label : str
        ``"standard model"`` or ``"+ Kcc_xxy"``.
    model_ids : tuple of str
        Parameter ids of the model.
    rms : ndarray (c,)
        Residual RMS per output channel [SI].
    noise_floor : ndarray (c,)
        RMS of the measured 1σ per output channel [SI].
    chi2_red, dof, bic : float, int, float
        Goodness of fit.
    added : tuple of (id, value, sigma, unit)
        Estimates of the effects added at this step, in engineering units.
    shifts : dict
        Existing parameter id → (shift in engineering units, unit, shift / old 1σ).
    channels : tuple of str
        Name of each entry of ``rms`` (``f_x``, ``f_y``, ``f_z``, ``|f|``, or ``all``).
    decision : Decision or None
        In a calibration's history: what became of this step's model.
    delta_chi2, p_value, delta_bic : float
        In a calibration's history: Δχ² of adding the tested effect to the model in force,
        its F-test p-value (``F(1, ν−1)``) and the BIC change (negative favours the effect);
        NaN for the baseline.
    reason : str
        The verdict in words.
    """

    label: str
    model_ids: tuple[str, ...]
    rms: np.ndarray
    noise_floor: np.ndarray
    chi2_red: float
    dof: int
    bic: float
    added: tuple[tuple[str, float, float, str], ...] = ()
    shifts: dict = field(default_factory=dict)
    channels: tuple[str, ...] = ("f_x", "f_y", "f_z")
    decision: Decision | None = None
    delta_chi2: float = math.nan
    p_value: float = math.nan
    delta_bic: float = math.nan
    reason: str = ""

    def __repr__(self) -> str:
        spread = np.sqrt(2.0 / max(self.dof, 1))
        rms = ", ".join(f"{c} {x / MICRO_G:.3g}" for c, x in zip(self.channels, self.rms, strict=True))
        verdict = (
            f"; {self.decision}" + (f" (p = {self.p_value:.2g})" if math.isfinite(self.p_value) else "")
            if self.decision is not None
            else ""
        )
        return f"<ModelStep {self.label!r}: χ²_ν = {self.chi2_red:.3f} ± {spread:.2f} (ν = {self.dof}); residual RMS [µg] {rms}{verdict}>"

    def to_json(self) -> dict:
        """Return the JSON form stored in a calibration record."""
        out = {
            "label": self.label,
            "model": list(self.model_ids),
            "channels": list(self.channels),
            "residual_rms": [float(x) for x in self.rms],
            "residual_rms_unit": "m/s^2",
            "noise_floor": [float(x) for x in self.noise_floor],
            "chi2_red": _finite(self.chi2_red),
            "dof": int(self.dof),
            "bic": _finite(self.bic),
            "added": [{"id": i, "estimate": v, "sigma": s, "unit": u} for i, v, s, u in self.added],
            "shifts": {k: {"shift": v[0], "unit": v[1], "in_sigma": _finite(v[2])} for k, v in self.shifts.items()},
        }
        if self.decision is not None:
            out.update(
                decision=str(self.decision),
                delta_chi2=_finite(self.delta_chi2),
                p_value=_finite(self.p_value),
                delta_bic=_finite(self.delta_bic),
                reason=self.reason,
            )
        return out

    @classmethod
    def from_json(cls, document: Any, where: str = "step") -> ModelStep:
        """Validate a step written by :meth:`to_json`; ``ValueError`` naming the key otherwise."""
        fields = _StepFields(where)
        label, model, channels = fields.head(document)
        arrays = fields.per_channel(document, channels)
        dof, numbers = fields.numbers(document)
        added = fields.added(document.get("added", []))
        shifts = fields.shifts(document.get("shifts", {}))
        decision, reason = fields.verdict(document)
        return cls(
            label=label,
            model_ids=tuple(model),
            rms=arrays["residual_rms"],
            noise_floor=arrays["noise_floor"],
            chi2_red=numbers["chi2_red"],
            dof=dof,
            bic=numbers["bic"],
            added=tuple(added),
            shifts=shifts,
            channels=tuple(channels),
            decision=decision,
            delta_chi2=numbers["delta_chi2"],
            p_value=numbers["p_value"],
            delta_bic=numbers["delta_bic"],
            reason=reason,
        )


@dataclass(frozen=True)
class _StepFields:
    """The checks of :meth:`ModelStep.from_json`, in order, each ``ValueError`` naming ``where.key``."""

    where: str

    def fail(self, key: str, expected: str) -> ValueError:
        return ValueError(f"{self.where}.{key}: expected {expected}")

    def head(self, document: Any) -> tuple[str, list[str], list[str]]:
        """Return label, model ids and channels, with every required key checked present."""
        if not isinstance(document, Mapping):
            raise ValueError(f"{self.where}: expected an object")
        for key in ("label", "model", "channels", "residual_rms", "noise_floor", "chi2_red", "dof", "bic"):
            if key not in document:
                raise self.fail(key, "this key (docs/formats.md, discovery)")
        label, model, channels = document["label"], document["model"], document["channels"]
        if not isinstance(label, str) or not label:
            raise self.fail("label", "a non-empty string")
        if not isinstance(model, list) or not all(isinstance(i, str) for i in model):
            raise self.fail("model", "a list of parameter ids")
        if not isinstance(channels, list) or not channels or not all(isinstance(c, str) for c in channels):
            raise self.fail("channels", "a non-empty list of channel names")
        return label, model, channels

    def per_channel(self, document: Mapping[str, Any], channels: list[str]) -> dict[str, np.ndarray]:
        """Return the residual RMS and the noise floor, one non-negative number per channel."""
        arrays = {}
        for key in ("residual_rms", "noise_floor"):
            values = document[key]
            if not isinstance(values, list) or len(values) != len(channels) or not all(is_number(v) and v >= 0 for v in values):
                raise self.fail(key, f"{len(channels)} non-negative numbers [m/s^2], one per channel")
            arrays[key] = np.array(values, dtype=float)
        return arrays

    def numbers(self, document: Mapping[str, Any]) -> tuple[int, dict[str, float]]:
        """Return the degrees of freedom and the statistics (NaN for null)."""
        dof = document["dof"]
        if isinstance(dof, bool) or not isinstance(dof, int) or dof < 0:
            raise self.fail("dof", "a non-negative integer")
        numbers = {}
        for key in ("chi2_red", "bic", "delta_chi2", "p_value", "delta_bic"):
            value = document.get(key)
            if value is not None and not is_number(value):
                raise self.fail(key, "a finite number or null")
            numbers[key] = math.nan if value is None else float(value)
        if numbers["chi2_red"] < 0:
            raise self.fail("chi2_red", "a non-negative number")
        if not (math.isnan(numbers["p_value"]) or 0.0 <= numbers["p_value"] <= 1.0):
            raise self.fail("p_value", "a probability in [0, 1]")
        return dof, numbers

    def added(self, raw_added: Any) -> list[tuple[str, float, float, str]]:
        """Return the effects the step added: (id, estimate, sigma, unit)."""
        if not isinstance(raw_added, list):
            raise self.fail("added", "a list")
        added = []
        for k, item in enumerate(raw_added):
            if not (isinstance(item, Mapping) and isinstance(item.get("id"), str) and isinstance(item.get("unit"), str)):
                raise self.fail(f"added[{k}]", '{"id", "estimate", "sigma", "unit"}')
            if not (is_number(item.get("estimate")) and is_number(item.get("sigma"))):
                raise self.fail(f"added[{k}]", "finite numbers for estimate and sigma")
            added.append((item["id"], float(item["estimate"]), float(item["sigma"]), item["unit"]))
        return added

    def shifts(self, raw_shifts: Any) -> dict[str, tuple[float, str, float]]:
        """Return the parameter shifts: id → (shift, unit, shift in σ or NaN)."""
        if not isinstance(raw_shifts, Mapping):
            raise self.fail("shifts", "an object")
        shifts = {}
        for key, item in raw_shifts.items():
            if not (isinstance(item, Mapping) and is_number(item.get("shift")) and isinstance(item.get("unit"), str)):
                raise self.fail(f"shifts.{key}", '{"shift", "unit", "in_sigma"}')
            in_sigma = item.get("in_sigma")
            if in_sigma is not None and not is_number(in_sigma):
                raise self.fail(f"shifts.{key}.in_sigma", "a finite number or null")
            shifts[str(key)] = (float(item["shift"]), item["unit"], math.nan if in_sigma is None else float(in_sigma))
        return shifts

    def verdict(self, document: Mapping[str, Any]) -> tuple[Decision | None, str]:
        """Return the decision (None: not decided) and its reason."""
        decision = document.get("decision")
        if decision is not None:
            try:
                decision = Decision(decision)
            except ValueError:
                raise self.fail("decision", " or ".join(repr(str(d)) for d in Decision)) from None
        reason = document.get("reason", "")
        if not isinstance(reason, str):
            raise self.fail("reason", "a string")
        return decision, reason


def _finite(x: float) -> float | None:
    x = float(x)
    return x if math.isfinite(x) else None


def is_number(value: Any) -> TypeGuard[float]:
    """Return whether a value read from a document is a finite number (a bool is not)."""
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def _per_channel(result: FitResult, values) -> tuple[tuple[str, ...], np.ndarray]:
    """RMS of ``values`` per output channel named by the residual labels (``... f_x``, ``... |f|``), else over all."""
    v = np.asarray(values, dtype=float)
    labels = result.residual_labels
    names = [next((c for c in CHANNELS if lbl.endswith(c)), None) for lbl in labels] if len(labels) == v.size else [None]
    if v.size and None not in names:
        channels = tuple(c for c in CHANNELS if c in names)
        index = np.array(names)
        return channels, np.array([np.sqrt(np.mean(v[index == c] ** 2)) for c in channels])
    return ("all",), np.sqrt(np.mean(v**2, keepdims=True))


def make_step(result: FitResult, label: str, previous: FitResult | None = None) -> ModelStep:
    """Summarize a fit as a history step (and what changed since ``previous``)."""
    from stableins.discovery.problem import fit_chi2, fit_chi2_red

    k = result.rank
    m = result.residuals.size
    added: tuple[tuple[str, float, float, str], ...] = ()
    shifts: dict = {}
    if previous is not None:
        old = dict(zip(previous.ids, zip(previous.values, previous.sigma, previous.status, strict=True), strict=True))
        new_ids = [t for t in result.terms if t.id not in old]
        added = tuple(
            (t.id, float(t.to_engineering(result[t.id][0])), float(t.sigma_to_engineering(result[t.id][1])), t.unit) for t in new_ids
        )
        for t in result.terms:
            if t.id in old and old[t.id][2] == Status.ESTIMATED and result[t.id][2] == Status.ESTIMATED:
                v0, s0, _ = old[t.id]
                dv = result[t.id][0] - v0
                shifts[t.id] = (float(dv / t.scale), t.unit, float(dv / s0) if s0 > 0 else float("nan"))
    channels, rms = _per_channel(result, result.residuals)
    _, floor = _per_channel(result, result.residual_sigma)
    return ModelStep(
        label=label,
        model_ids=result.ids,
        rms=rms,
        noise_floor=floor,
        chi2_red=fit_chi2_red(result),
        dof=result.dof,
        bic=float(fit_chi2(result) + k * np.log(m)),
        added=added,
        shifts=shifts,
        channels=channels,
    )
