"""Read-only view of a calibration record for the report (the one place that knows the record's layout).

The report reads a calibration record (JSON, ``stableins.records.CalibrationRecord``)
only through :class:`RecordView`.  Keeping the record's layout in this single adapter
means the report follows the record format by changing one function
(:meth:`RecordView.from_mapping`).

Layout read (keys in brackets are alternatives accepted)::

    schema_version            int
    serial_number             str                       (else site.serial_number)
    parameters                list of {id, value, unit, sigma [std, uncertainty], status, note [reason]}
                              or {id: {...}}; value and sigma in SI
    covariance                {ids: [...], matrix: [[...]]}  (SI², optional)
    provenance                {software_version, inputs: {path: sha256} or [{path, sha256}],
                               procedure: str or {...}, started, finished, created}
    site                      SiteMetadata.to_dict()
    environment               {temperature: {mean, min, max} [degC]}  (optional)
    notes                     list of str
    stages                    list of FitResult dictionaries, see :func:`fit_to_dict` (optional)
    system                    {harmonics: [...], ...} (optional)
    discovery                 {steps: [...]} (optional)

Every problem is an :class:`~stableins.data.errors.InputError` naming the file and
the field.
"""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from os import PathLike
from pathlib import Path
from typing import Any

from stableins.data.errors import InputError
from stableins.data.metadata import SiteMetadata

#: Allowed parameter statuses (same as ``stableins.estimators.result.STATUSES``; repeated
#: here so that reading a record does not import numpy).
STATUSES = ("estimated", "fixed", "gauge", "unidentifiable")


@dataclass(frozen=True)
class ParameterEntry:
    """One parameter of a record [SI]."""

    id: str
    value: float
    sigma: float
    status: str
    unit: str = ""
    note: str = ""


@dataclass(frozen=True)
class RecordView:
    """What the report needs from a calibration record.

    Attributes
    ----------
    path : str
        File the record was read from ("" for an in-memory record).
    sha256 : str
        SHA-256 of the record file ("" for an in-memory record).
    parameters : tuple of ParameterEntry
        Parameters in record order [SI].
    covariance_ids, covariance : tuple of str, list of list of float
        Covariance [SI²] and the id order of its rows (empty when the record has none).
    inputs : tuple of (str, str)
        ``(path, sha256)`` of every input the calibration read, from the provenance.
    procedure : dict
        Procedure identification and method (name, positions, dwells, stages ...).
    """

    path: str
    sha256: str
    schema_version: int
    serial_number: str
    parameters: tuple[ParameterEntry, ...]
    covariance_ids: tuple[str, ...]
    covariance: tuple[tuple[float, ...], ...]
    software_version: str
    inputs: tuple[tuple[str, str], ...]
    procedure: dict[str, Any]
    times: dict[str, str]
    site: SiteMetadata | None
    environment: dict[str, Any]
    notes: tuple[str, ...]
    determined: tuple[str, ...] = ()
    stages: tuple[dict[str, Any], ...] = ()
    system: dict[str, Any] = field(default_factory=dict)
    discovery: dict[str, Any] = field(default_factory=dict)
    #: The record's noise model (:class:`stableins.noise.NoiseModel`), or None.
    noise_model: Any = None

    # ------------------------------------------------------------------ access
    def __getitem__(self, parameter_id: str) -> ParameterEntry:
        for p in self.parameters:
            if p.id == parameter_id:
                return p
        raise KeyError(parameter_id)

    @property
    def ids(self) -> tuple[str, ...]:
        return tuple(p.id for p in self.parameters)

    # ------------------------------------------------------------------ readers
    @classmethod
    def load(cls, path: str | PathLike[str]) -> RecordView:
        """Read a record file; every problem is an :class:`InputError` naming the file."""
        path = Path(path)
        try:
            raw = path.read_bytes()
        except FileNotFoundError:
            raise InputError("no such file", path=path, expected="a calibration record (JSON)") from None
        except OSError as error:
            raise InputError(f"cannot read the file ({error.strerror})", path=path) from None
        try:
            data = json.loads(raw.decode("utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError) as error:
            raise InputError(f"not valid JSON ({error})", path=path, expected="a calibration record written by stableins") from None
        return cls.from_mapping(data, path=str(path), sha256=hashlib.sha256(raw).hexdigest())

    @classmethod
    def from_any(cls, record: Any) -> RecordView:
        """A view of a record given as a path, a mapping, a view, or an object with ``to_dict()``."""
        if isinstance(record, RecordView):
            return record
        if isinstance(record, str | PathLike):
            return cls.load(record)
        if isinstance(record, Mapping):
            return cls.from_mapping(record)
        for name in ("to_document", "to_dict"):
            method = getattr(record, name, None)
            if callable(method):
                return cls.from_mapping(method())
        raise TypeError(f"cannot read a calibration record from {type(record).__name__}")

    @classmethod
    def from_mapping(cls, data: Any, *, path: str = "", sha256: str = "") -> RecordView:
        """Validate and view the record's JSON mapping (the single place that knows its layout)."""
        where = path or "calibration record"
        if not isinstance(data, Mapping):
            raise InputError("the top level is not a JSON object", path=where, expected="a calibration record")
        if "format" in data:
            # The record format's own validation (schema, σ vs covariance, symmetry, PSD ...).
            from stableins.records import CalibrationRecord

            CalibrationRecord.from_document(dict(data), where)
        version = data.get("schema_version")
        if not isinstance(version, int):
            raise InputError("missing or non-integer schema version", path=where, field="schema_version", expected="an integer")
        provenance = _mapping(data.get("provenance", {}), where, "provenance")
        site = _site(data.get("site"), where)
        serial = data.get("serial_number") or (site.serial_number if site else "")
        if not isinstance(serial, str) or not serial:
            raise InputError("missing unit serial number", path=where, field="serial_number", expected="a non-empty string")
        parameters = _parameters(data.get("parameters"), where)
        cov_ids, cov = _covariance(data.get("covariance"), where, {p.id for p in parameters})
        procedure = provenance.get("procedure", data.get("procedure", {}))
        if isinstance(procedure, str):
            procedure = {"name": procedure} if procedure else {}
        procedure = dict(_mapping(procedure, where, "provenance.procedure"))
        if provenance.get("stages") and "stages" not in procedure:
            procedure["stages"] = list(provenance["stages"])
        times = {k: str(provenance[k]) for k in ("started", "finished", "created", "issued") if provenance.get(k)}
        times.setdefault("started", str(provenance.get("data_start") or ""))
        times.setdefault("finished", str(provenance.get("data_end") or ""))
        times = {k: v for k, v in times.items() if v}
        software = str(provenance.get("software_version", provenance.get("software", data.get("software_version", ""))))
        software = software.removeprefix("stableins ").strip()
        notes = list(data.get("notes", [])) if not isinstance(data.get("notes"), str) else [data["notes"]]
        stages = data.get("stages", [])
        if not isinstance(stages, Sequence) or isinstance(stages, str) or not all(isinstance(s, Mapping) for s in stages):
            raise InputError("stages must be a list of objects", path=where, field="stages")
        return cls(
            path=path,
            sha256=sha256,
            schema_version=version,
            serial_number=serial,
            parameters=parameters,
            covariance_ids=cov_ids,
            covariance=cov,
            software_version=software,
            inputs=_inputs(provenance.get("inputs", provenance.get("input_sha256", {})), where),
            procedure=procedure,
            times=times,
            site=site,
            environment=dict(_mapping(data.get("environment", {}), where, "environment")),
            notes=tuple(str(n) for n in notes),
            determined=tuple(str(d) for d in data.get("determined", [])),
            stages=tuple(dict(s) for s in stages),
            system=dict(_mapping(data.get("system", {}), where, "system")),
            discovery=dict(_mapping(data.get("discovery", {}), where, "discovery")),
            noise_model=_noise_model(data.get("noise_model"), where),
        )


# ---------------------------------------------------------------------- helpers
def _noise_model(document: Any, where: str) -> Any:
    if document is None:
        return None
    from stableins.noise import NoiseModel

    return NoiseModel.from_document(document, where)


def _mapping(value: Any, where: str, name: str) -> Mapping[str, Any]:
    if not isinstance(value, Mapping):
        raise InputError(f"{name} is not a JSON object", path=where, field=name)
    return value


def _number(value: Any, where: str, name: str, *, allow_none: bool = False) -> float:
    if value is None and allow_none:
        return math.nan
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(float(value)):
        raise InputError(f"not a finite number: {value!r}", path=where, field=name, expected="a finite number in SI units")
    return float(value)


def _site(value: Any, where: str) -> SiteMetadata | None:
    if value is None:
        return None
    value = _mapping(value, where, "site")
    if isinstance(value.get("latitude"), Mapping):  # the record format: quantities with explicit units
        from stableins.data.metadata import metadata_from_document

        return metadata_from_document(dict(value), where)
    required = ("serial_number", "latitude", "height", "gravity", "gravity_source", "sample_rate")
    missing = [k for k in required if k not in value]
    if missing:
        raise InputError(f"site metadata lacks {', '.join(missing)}", path=where, field="site", expected=", ".join(required))
    for name in ("latitude", "height", "gravity", "sample_rate"):
        _number(value[name], where, f"site.{name}")
    known = set(SiteMetadata.__dataclass_fields__)
    kwargs = {k: v for k, v in value.items() if k in known}
    for name in ("gimbal_senses", "base_attitude"):
        if name in kwargs:
            kwargs[name] = tuple(kwargs[name])
    return SiteMetadata(**kwargs)


def _parameters(value: Any, where: str) -> tuple[ParameterEntry, ...]:
    if isinstance(value, Mapping):
        items = [{"id": k, **_mapping(v, where, f"parameters.{k}")} for k, v in value.items()]
    elif isinstance(value, Sequence) and not isinstance(value, str):
        items = [dict(_mapping(v, where, f"parameters[{i}]")) for i, v in enumerate(value)]
    else:
        raise InputError("missing parameter list", path=where, field="parameters", expected="a list of {id, value, sigma, status}")
    if not items:
        raise InputError("the record has no parameters", path=where, field="parameters")
    out = []
    for item in items:
        pid = item.get("id")
        if not isinstance(pid, str) or not pid:
            raise InputError("parameter without an id", path=where, field="parameters", expected="a string id such as 'bias_x'")
        status = item.get("status", "estimated")
        if status not in STATUSES:
            raise InputError(f"unknown status {status!r}", path=where, field=f"parameters.{pid}.status", expected=" or ".join(STATUSES))
        sigma_value = next((item[k] for k in ("sigma", "std", "uncertainty") if k in item), None)
        value_ = _number(item.get("value"), where, f"parameters.{pid}.value", allow_none=status == "unidentifiable")
        sigma = _number(sigma_value, where, f"parameters.{pid}.sigma", allow_none=status != "estimated")
        if sigma < 0:
            raise InputError(f"negative standard uncertainty {sigma}", path=where, field=f"parameters.{pid}.sigma")
        note = str(item.get("note", item.get("reason", "")) or "")
        out.append(ParameterEntry(pid, value_, sigma, status, str(item.get("unit", "")), note))
    ids = [p.id for p in out]
    duplicates = sorted({i for i in ids if ids.count(i) > 1})
    if duplicates:
        raise InputError(f"duplicate parameter ids {duplicates}", path=where, field="parameters")
    return tuple(out)


def _covariance(value: Any, where: str, ids: set[str]) -> tuple[tuple[str, ...], tuple[tuple[float, ...], ...]]:
    if value is None:
        return (), ()
    value = _mapping(value, where, "covariance")
    order = value.get("ids", value.get("order"))
    matrix = value.get("matrix", value.get("values"))
    if not isinstance(order, Sequence) or not isinstance(matrix, Sequence):
        raise InputError("covariance needs 'ids' and 'matrix'", path=where, field="covariance")
    n = len(order)
    unknown = sorted(set(order) - ids)
    if unknown:
        raise InputError(f"covariance names parameters not in the record: {unknown}", path=where, field="covariance.ids")
    if len(matrix) != n or any(not isinstance(row, Sequence) or len(row) != n for row in matrix):
        raise InputError(f"covariance matrix is not {n}×{n}", path=where, field="covariance.matrix")
    rows = tuple(tuple(_number(x, where, "covariance.matrix", allow_none=True) for x in row) for row in matrix)
    for i in range(n):
        if not math.isfinite(rows[i][i]):
            continue
        if rows[i][i] < 0:
            raise InputError(f"negative variance for {order[i]}", path=where, field="covariance.matrix")
        for j in range(i):
            if not math.isfinite(rows[j][j]):
                continue
            if abs(rows[i][j] - rows[j][i]) > 1e-9 * math.sqrt(abs(rows[i][i] * rows[j][j])):
                raise InputError(f"covariance is not symmetric at ({order[i]}, {order[j]})", path=where, field="covariance.matrix")
    return tuple(str(o) for o in order), rows


def _inputs(value: Any, where: str) -> tuple[tuple[str, str], ...]:
    if isinstance(value, Mapping):
        pairs = [(str(k), str(v)) for k, v in value.items()]
    elif isinstance(value, Sequence) and not isinstance(value, str):
        pairs = []
        for i, item in enumerate(value):
            item = _mapping(item, where, f"provenance.inputs[{i}]")
            pairs.append((str(item.get("path", item.get("name", ""))), str(item.get("sha256", ""))))
    else:
        raise InputError("inputs must map file names to SHA-256", path=where, field="provenance.inputs")
    for name, digest in pairs:
        if len(digest) != 64 or any(c not in "0123456789abcdef" for c in digest.lower()):
            raise InputError(f"not a SHA-256 hex digest for {name!r}: {digest!r}", path=where, field="provenance.inputs")
    return tuple(pairs)


def sha256_file(path: str | PathLike[str]) -> str:
    """SHA-256 of a file, streamed in 1 MiB blocks (bounded memory)."""
    digest = hashlib.sha256()
    try:
        with open(path, "rb") as handle:
            for block in iter(lambda: handle.read(1 << 20), b""):
                digest.update(block)
    except FileNotFoundError:
        raise InputError("no such file", path=path) from None
    except OSError as error:
        raise InputError(f"cannot read the file ({error.strerror})", path=path) from None
    return digest.hexdigest()
