"""What the system stage ran with: its options, the noise model it started from and where its gyro drift came from.

One frozen value, :class:`SystemSettings`, writes itself as the stage run's settings of a record (docs/formats.md,
"Stage settings") and reads them back, the form of records written before it included.  The gyro drift is one
object there: what the attitude fit did with it (``attitude_fit``), whether the stage measured it in the gimbal
readings (``measured``), the drift given (``known``) and its uncertainty, and where the drift removed came from
(``source``); the earlier form spread these over five keys, one of them saying ``"gyro_drift": "ignore"`` next to
``"estimate_gyro_drift": true`` (the attitude fit left it out, the gimbal readings measured it).
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from enum import Enum
from typing import Any, cast

from stableins.documents import DocumentFields, JSONObject, JSONValue
from stableins.errors import InputError
from stableins.estimators.result import Stage
from stableins.estimators.system.gyro_drift import DriftSource
from stableins.estimators.system.options import SystemOptions
from stableins.noise import NoiseModel, NoiseSource

#: The options of :class:`SystemOptions` the ``gyro_drift`` object of the settings holds, by their key there.
_DRIFT_OPTIONS = {"attitude_fit": "gyro_drift", "measured": "estimate_gyro_drift", "known": "known_gyro_drift",
                  "uncertainty": "gyro_drift_uncertainty"}  # fmt: skip
#: The keys of the settings that are not options of :class:`SystemOptions` (besides ``gyro_drift``).
_OWN_KEYS = ("stage", "noise_model", "gyro_drift", "gyro_drift_source")


@dataclass(frozen=True)
class SystemSettings:
    """The settings of one run of the system stage.

    Attributes
    ----------
    options : SystemOptions
        The options it ran with.
    noise_source : NoiseSource or None
        Where the noise model it started from came from (None: it started from none and measured one).
    gyro_drift_source : DriftSource or None
        Where the gyro drift removed from pitch and roll came from (None: a record written before the stage said).
    """

    options: SystemOptions
    noise_source: NoiseSource | None = None
    gyro_drift_source: DriftSource | None = None

    @classmethod
    def of(cls, options: SystemOptions, noise_model: NoiseModel | None, gyro_drift_source: DriftSource) -> SystemSettings:
        """Return the settings of a run with ``options``, started from ``noise_model`` (or none), its drift from ``gyro_drift_source``."""
        return cls(options, None if noise_model is None else noise_model.source, gyro_drift_source)

    @property
    def measures_gyro_drift(self) -> bool:
        """Whether the stage measured the gyro drift in the gimbal readings (then it is a parameter of the record)."""
        return self.gyro_drift_source in (DriftSource.GIMBALS, DriftSource.GIVEN_AND_GIMBALS)

    def to_document(self) -> JSONObject:
        """Return ``{"stage": "system", <options>, "gyro_drift": {...}, "noise_model": <source or "none">}`` (docs/formats.md)."""
        o = self.options
        out: JSONObject = {"stage": Stage.SYSTEM.value}
        for f in fields(o):
            if f.name not in _DRIFT_OPTIONS.values():
                out[f.name] = _json(getattr(o, f.name))
        drift: JSONObject = {key: _json(getattr(o, name)) for key, name in _DRIFT_OPTIONS.items()}
        drift["source"] = None if self.gyro_drift_source is None else self.gyro_drift_source.value
        out["gyro_drift"] = drift
        out["noise_model"] = "none" if self.noise_source is None else self.noise_source.value
        return out

    @classmethod
    def from_document(cls, document: DocumentFields) -> SystemSettings:
        """Return the settings :meth:`to_document` wrote, or those of a record written before (five gyro-drift keys).

        Every option is checked as :class:`SystemOptions` checks it; an error names the field of the document.
        """
        given: dict[str, JSONValue] = {}
        drift = document.document.get("gyro_drift")
        if isinstance(drift, dict):  # this form
            unknown = sorted(set(document.document) - {f.name for f in fields(SystemOptions)} - set(_OWN_KEYS))
            if unknown:
                raise document.fail(unknown[0], "not an option of the system stage", "the keys of docs/formats.md")
            inner = document.fields("gyro_drift")
            given |= {name: inner.value(key) for key, name in _DRIFT_OPTIONS.items()}
            source = inner.document.get("source")
        else:  # written before: the drift's options at the top, the drift's source beside them
            given["estimate_gyro_drift"] = False  # before the stage measured the drift, it did not
            source = document.document.get("gyro_drift_source")
        drift_options = _DRIFT_OPTIONS.values() if isinstance(drift, dict) else ()
        names = [f.name for f in fields(SystemOptions) if f.name not in drift_options]
        given |= {name: document.document[name] for name in names if name in document.document}
        return cls(_options(given, document), _noise_source(document), _drift_source(source, document))


def _json(value: object) -> JSONValue:
    """Return an option's value as JSON: an enum by its value, a tuple as a list."""
    if isinstance(value, Enum):
        return _json(value.value)
    if isinstance(value, tuple):
        return [_json(v) for v in value]
    if value is None or isinstance(value, str | int | float | bool):
        return value
    raise TypeError(f"system-stage option value {value!r} has no JSON form")


def _options(given: dict[str, JSONValue], document: DocumentFields) -> SystemOptions:
    """Return the options ``given`` holds (the defaults for the others), checked by :class:`SystemOptions`."""
    values = {name: tuple(value) if isinstance(value, list) else value for name, value in given.items()}
    try:  # SystemOptions checks every value's type and range itself (InputError naming the option)
        return SystemOptions(**cast("dict[str, Any]", values))
    except InputError as error:
        drift_key = {name: key for key, name in _DRIFT_OPTIONS.items()}.get(error.field or "")
        key = f"gyro_drift.{drift_key}" if drift_key is not None and isinstance(document.document.get("gyro_drift"), dict) else error.field
        where = f"{document.where}.{key}" if key else document.where
        raise InputError(error.message, path=document.path, field=where, expected=error.expected) from None


def _noise_source(document: DocumentFields) -> NoiseSource | None:
    """Return the source of the noise model the stage started from (``"none"``: none)."""
    text = document.text("noise_model") if document.has("noise_model") else "none"
    if text == "none":
        return None
    try:
        return NoiseSource(text)
    except ValueError:
        expected = "none or " + ", ".join(s.value for s in NoiseSource)
        raise document.fail("noise_model", f"{text!r} is not a noise-model source", expected) from None


def _drift_source(value: JSONValue, document: DocumentFields) -> DriftSource | None:
    """Return where the gyro drift came from (None: not stated)."""
    if value is None:
        return None
    try:
        return DriftSource(str(value))
    except ValueError:
        raise document.fail("gyro_drift.source", f"{value!r} is not a gyro-drift source", ", ".join(s.value for s in DriftSource)) from None
