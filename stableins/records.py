"""Calibration records: what a calibration found, with its uncertainty and provenance.

A record is a JSON file (format in ``docs/formats.md``)::

    {
      "format": "stableins-calibration-record", "schema_version": 1,
      "serial_number": "INS-0042",
      "parameters": [{"id": "sf_x", "value": 1.000123, "unit": "1", "sigma": 1.1e-6, "status": "estimated"}, ...],
      "covariance": {"ids": ["sf_x", ...], "unit": "products of the parameter units", "matrix": [[...], ...]},
      "provenance": {"software": "stableins 0.1.0", "procedure": ..., "stages": [...],
                     "inputs": [{"path": ..., "sha256": ...}], "created": ..., "data_start": ..., "data_end": ...},
      "site": {...site metadata with units...},
      "determined": [...], "notes": [...],
      "noise_model": {...}     (optional: the instrument's noise model, stableins.noise.NoiseModel)
    }

Values are SI (``unit`` says which); ``sigma`` is the square root of the covariance
diagonal and is stored only for people (the loader checks that it agrees).  Parameters
whose status is ``unidentifiable`` have no σ (``null``): the data say nothing about them.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, replace
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any

from stableins.data.errors import InputError
from stableins.data.metadata import SiteMetadata, metadata_from_document, metadata_to_document

if TYPE_CHECKING:  # pragma: no cover
    import numpy as np
    from numpy.typing import NDArray

    from stableins.estimators.result import FitResult
    from stableins.noise import NoiseModel

RECORD_FORMAT = "stableins-calibration-record"
RECORD_SCHEMA_VERSION = 1
#: Allowed statuses (the same as :data:`stableins.estimators.result.STATUSES`, repeated here
#: so that reading a record does not import numpy-heavy estimator modules).
STATUSES = ("estimated", "fixed", "gauge", "unidentifiable")
#: Relative asymmetry tolerated in a stored covariance.
SYMMETRY_TOLERANCE = 1e-9


@dataclass(frozen=True)
class Parameter:
    """One calibrated parameter.

    Attributes
    ----------
    id : str
        Term id (``sf_x``, ``bias_x``, ``beta_xy``, ``K2_x``, ``theta10``, additive ids ...).
    value : float
        Value [SI].
    unit : str
        SI unit of ``value`` (``"1"`` for dimensionless).
    sigma : float
        1σ [SI]; NaN for ``unidentifiable``.
    status : str
        One of :data:`STATUSES`.
    """

    id: str
    value: float
    unit: str
    sigma: float
    status: str


@dataclass(frozen=True)
class InputFile:
    """An input file by path and SHA-256 digest of its bytes."""

    path: str
    sha256: str

    @classmethod
    def of(cls, path: str | os.PathLike[str]) -> InputFile:
        return cls(str(path), file_sha256(path))


@dataclass(frozen=True)
class Provenance:
    """Where a record comes from.

    Attributes
    ----------
    software : str
        ``"stableins <version>"``.
    procedure : str
        Procedure name or file.
    stages : tuple of str
        Stages that contributed, in order (``"coarse"``, ``"fine"``, ``"system"`` ...).
    inputs : tuple of InputFile
        Every input file with its SHA-256.
    created : str
        ISO 8601 UTC time the record was made.
    data_start, data_end : str
        ISO 8601 times of the first and last data used (``""`` if unknown).
    """

    software: str
    procedure: str = ""
    stages: tuple[str, ...] = ()
    inputs: tuple[InputFile, ...] = ()
    created: str = ""
    data_start: str = ""
    data_end: str = ""


def file_sha256(path: str | os.PathLike[str]) -> str:
    """SHA-256 of a file's bytes, read in 1 MiB blocks."""
    digest = hashlib.sha256()
    try:
        with open(path, "rb") as handle:
            for block in iter(lambda: handle.read(1 << 20), b""):
                digest.update(block)
    except OSError as error:
        raise InputError(f"cannot read input file to hash it: {error.strerror}", path=path) from None
    return digest.hexdigest()


def _now() -> str:
    return datetime.now(UTC).replace(microsecond=0).isoformat()


@dataclass(frozen=True)
class CalibrationRecord:
    """A calibration of one unit: parameters, covariance, provenance, site.

    Build one with :meth:`from_fit_result`, refine it with :meth:`update`, write it with
    :meth:`save` and read it with :meth:`load`.  The covariance rows follow
    :attr:`ids` (the parameter order).
    """

    serial_number: str
    parameters: tuple[Parameter, ...]
    covariance: NDArray[np.float64]
    provenance: Provenance
    site: SiteMetadata | None = None
    determined: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()
    schema_version: int = RECORD_SCHEMA_VERSION
    #: The instrument's noise model (docs/noise.md); carried through every stage unchanged
    #: unless a stage measures it.
    noise_model: NoiseModel | None = None

    def __post_init__(self) -> None:
        import numpy as np

        covariance = np.array(self.covariance, dtype=float)
        covariance.setflags(write=False)
        object.__setattr__(self, "covariance", covariance)
        _check(self, path=None)

    # ------------------------------------------------------------------ access
    @property
    def ids(self) -> tuple[str, ...]:
        return tuple(p.id for p in self.parameters)

    def __getitem__(self, parameter_id: str) -> Parameter:
        for p in self.parameters:
            if p.id == parameter_id:
                return p
        raise KeyError(parameter_id)

    def values(self) -> dict[str, float]:
        """``{id: value}`` [SI], e.g. for :meth:`stableins.errormodel.ErrorModel.forward`."""
        return {p.id: p.value for p in self.parameters}

    def covariance_of(self, ids: Sequence[str]) -> NDArray[np.float64]:
        """The covariance block of the given parameters."""
        import numpy as np

        index = [self.ids.index(i) for i in ids]
        return self.covariance[np.ix_(index, index)]

    # ------------------------------------------------------------------ build
    @classmethod
    def from_fit_result(
        cls,
        result: FitResult,
        serial_number: str | None = None,
        *,
        site: SiteMetadata | None = None,
        inputs: Iterable[str | os.PathLike[str] | InputFile] = (),
        procedure: str = "",
        data_start: str = "",
        data_end: str = "",
        notes: Iterable[str] = (),
        created: str | None = None,
        noise_model: NoiseModel | None = None,
    ) -> CalibrationRecord:
        """Record of one estimation stage.

        Parameters
        ----------
        result : FitResult
            The stage's result (its terms give ids and SI units).
        serial_number : str, optional
            Defaults to ``site.serial_number``.
        site : SiteMetadata, optional
            Site metadata of the data.
        inputs : iterable of path or InputFile
            Input data files; each is hashed (SHA-256).
        procedure : str
            Procedure name or file.
        data_start, data_end : str
            ISO 8601 times of the data (``""`` if unknown).
        notes : iterable of str
            Added to the result's own notes (gauges, warnings).
        created : str, optional
            Creation time; now (UTC) by default.
        noise_model : NoiseModel, optional
            The noise model the stage's σ rest on.
        """
        import numpy as np

        from stableins import __version__

        if serial_number is None:
            if site is None:
                raise ValueError("from_fit_result needs a serial_number or site metadata")
            serial_number = site.serial_number
        sigma = np.sqrt(np.clip(np.diag(result.covariance), 0.0, None))
        covariance = np.array(result.covariance, dtype=float)
        parameters = []
        for k, (term, status) in enumerate(zip(result.terms, result.status, strict=True)):
            s = float(sigma[k])
            if status == "unidentifiable":
                s = math.nan
                covariance[k, :] = math.nan
                covariance[:, k] = math.nan
            parameters.append(Parameter(term.id, float(result.values[k]), term.si_unit, s, status))
        files = tuple(f if isinstance(f, InputFile) else InputFile.of(f) for f in inputs)
        provenance = Provenance(
            software=f"stableins {__version__}",
            procedure=procedure,
            stages=(result.stage,),
            inputs=files,
            created=created or _now(),
            data_start=data_start,
            data_end=data_end,
        )
        return cls(
            serial_number=serial_number,
            parameters=tuple(parameters),
            covariance=covariance,
            provenance=provenance,
            site=site,
            determined=tuple(result.determined),
            notes=tuple(result.notes) + tuple(notes),
            noise_model=noise_model,
        )

    def update(self, newer: CalibrationRecord | FitResult, **kwargs: Any) -> CalibrationRecord:
        """Refine some parameters with a later stage, keeping the others.

        Parameters estimated (or fixed, gauged) by ``newer`` replace those of ``self``;
        parameters that ``newer`` leaves ``unidentifiable`` or does not carry keep their
        values and their covariance block.  Covariances between a kept and a replaced
        parameter are set to zero: the later stage's data are independent of the earlier
        one's, and the later estimate does not depend on the kept values — this holds
        when the later stage does not use the kept parameters as inputs; otherwise the
        caller should pass a combined result.

        ``newer`` may be a :class:`~stableins.estimators.result.FitResult` (then
        ``kwargs`` go to :meth:`from_fit_result`) or another record of the same unit.
        """
        import numpy as np

        if not isinstance(newer, CalibrationRecord):
            kwargs.setdefault("site", self.site)
            newer = CalibrationRecord.from_fit_result(newer, self.serial_number, **kwargs)
        if newer.serial_number != self.serial_number:
            raise InputError(
                f"cannot merge records of different units ({self.serial_number!r} and {newer.serial_number!r})",
                field="serial_number",
                expected="the same serial number",
            )
        replaced = {p.id for p in newer.parameters if p.status != "unidentifiable"} | (set(newer.ids) - set(self.ids))
        order = list(self.ids) + [i for i in newer.ids if i not in self.ids]
        from_newer = np.array([i in replaced for i in order])
        parameters = tuple(newer[i] if i in replaced else self[i] for i in order)
        covariance = np.zeros((len(order), len(order)))
        for source, mask in ((newer, from_newer), (self, ~from_newer)):
            rows = np.flatnonzero(mask)
            covariance[np.ix_(rows, rows)] = source.covariance_of([order[k] for k in rows])
        for k, p in enumerate(parameters):
            if p.status == "unidentifiable":
                covariance[k, :] = math.nan
                covariance[:, k] = math.nan
        inputs = self.provenance.inputs + tuple(f for f in newer.provenance.inputs if f not in self.provenance.inputs)
        provenance = Provenance(
            software=newer.provenance.software,
            procedure=newer.provenance.procedure or self.provenance.procedure,
            stages=self.provenance.stages + tuple(s for s in newer.provenance.stages if s not in self.provenance.stages),
            inputs=inputs,
            created=newer.provenance.created,
            data_start=min(filter(None, (self.provenance.data_start, newer.provenance.data_start)), default=""),
            data_end=max(filter(None, (self.provenance.data_end, newer.provenance.data_end)), default=""),
        )
        stage = ",".join(newer.provenance.stages)
        return replace(
            self,
            parameters=parameters,
            covariance=covariance,
            provenance=provenance,
            site=newer.site or self.site,
            determined=self.determined + tuple(d for d in newer.determined if d not in self.determined),
            notes=self.notes + tuple(f"[{stage}] {n}" for n in newer.notes),
            noise_model=newer.noise_model if newer.noise_model is not None else self.noise_model,
        )

    #: ``merge`` is the same operation as :meth:`update`.
    merge = update

    # ------------------------------------------------------------------ files
    def to_document(self) -> dict[str, Any]:
        """JSON-ready dict (non-finite numbers as ``null``)."""

        def num(x: float) -> float | None:
            return float(x) if math.isfinite(x) else None

        return {
            "format": RECORD_FORMAT,
            "schema_version": self.schema_version,
            "serial_number": self.serial_number,
            "parameters": [
                {"id": p.id, "value": p.value, "unit": p.unit, "sigma": num(p.sigma), "status": p.status} for p in self.parameters
            ],
            "covariance": {
                "ids": list(self.ids),
                "unit": "SI: product of the two parameters' units",
                "matrix": [[num(x) for x in row] for row in self.covariance.tolist()],
            },
            "provenance": {
                "software": self.provenance.software,
                "procedure": self.provenance.procedure,
                "stages": list(self.provenance.stages),
                "inputs": [{"path": f.path, "sha256": f.sha256} for f in self.provenance.inputs],
                "created": self.provenance.created,
                "data_start": self.provenance.data_start,
                "data_end": self.provenance.data_end,
            },
            "site": None if self.site is None else metadata_to_document(self.site),
            "determined": list(self.determined),
            "notes": list(self.notes),
        } | ({} if self.noise_model is None else {"noise_model": self.noise_model.to_document()})

    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write the record atomically (a reader sees the old file or the whole new one)."""
        from stableins.data.atomic import atomic_write

        text = _layout(self.to_document())
        with atomic_write(path) as handle:
            handle.write(text)
        return Path(path)

    @classmethod
    def from_document(cls, document: Any, path: str | None = None) -> CalibrationRecord:
        """Build and validate a record from its JSON document."""
        import numpy as np

        def fail(message: str, key: str | None = None, expected: str | None = None) -> InputError:
            return InputError(message, path=path, field=key, expected=expected)

        if not isinstance(document, dict):
            raise fail("not a JSON object", expected="a calibration record (docs/formats.md)")
        if document.get("format") != RECORD_FORMAT:
            raise fail(f"format {document.get('format')!r}", "format", f"'{RECORD_FORMAT}'")
        if document.get("schema_version") != RECORD_SCHEMA_VERSION:
            raise fail(
                f"unknown schema version {document.get('schema_version')!r}; this stableins reads version {RECORD_SCHEMA_VERSION}",
                "schema_version",
                str(RECORD_SCHEMA_VERSION),
            )
        for key in ("serial_number", "parameters", "covariance", "provenance"):
            if key not in document:
                raise fail("missing key", key, "the keys of docs/formats.md")

        def text(value: Any, key: str) -> str:
            if not isinstance(value, str):
                raise fail(f"{value!r} is not a string", key, "a string")
            return value

        def texts(value: Any, key: str) -> tuple[str, ...]:
            if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
                raise fail(f"{value!r} is not a list of strings", key, "a list of strings")
            return tuple(value)

        if not isinstance(document["parameters"], list):
            raise fail("not a list", "parameters", "a list of parameter objects")
        parameters = []
        for k, item in enumerate(document["parameters"]):
            where = f"parameters[{k}]"
            if not isinstance(item, dict):
                raise fail("not an object", where, '{"id", "value", "unit", "sigma", "status"}')
            for key in ("id", "value", "unit", "sigma", "status"):
                if key not in item:
                    raise fail("missing key", f"{where}.{key}", '{"id", "value", "unit", "sigma", "status"}')
            parameter_id = text(item["id"], f"{where}.id")
            if item["status"] not in STATUSES:
                raise fail(f"bad status {item['status']!r} for {parameter_id!r}", f"{where}.status", " or ".join(STATUSES))
            value = _number(item["value"], path, f"{where}.value")
            sigma = math.nan if item["sigma"] is None else _number(item["sigma"], path, f"{where}.sigma")
            parameters.append(Parameter(parameter_id, value, text(item["unit"], f"{where}.unit"), sigma, item["status"]))
        cov = document["covariance"]
        if not isinstance(cov, dict) or "ids" not in cov or "matrix" not in cov:
            raise fail("malformed", "covariance", '{"ids": [...], "matrix": [[...]]}')
        ids = [p.id for p in parameters]
        if cov["ids"] != ids:
            raise fail(f"ids {cov['ids']!r} do not follow the parameters {ids}", "covariance.ids", "the parameter ids in order")
        rows = cov["matrix"]
        n = len(ids)
        if not isinstance(rows, list) or len(rows) != n or not all(isinstance(r, list) and len(r) == n for r in rows):
            raise fail("not a square list of rows", "covariance.matrix", f"{n} rows of {n} numbers")
        if not all(x is None or (isinstance(x, int | float) and not isinstance(x, bool)) for r in rows for x in r):
            raise fail("not a numeric matrix", "covariance.matrix", "numbers (null only for unidentifiable parameters)")
        matrix = np.array([[math.nan if x is None else float(x) for x in r] for r in rows], dtype=float).reshape(n, n)
        prov = document["provenance"]
        if not isinstance(prov, dict) or "software" not in prov:
            raise fail("malformed", "provenance", "an object with software, procedure, stages, inputs, created")
        files = prov.get("inputs", [])
        if not isinstance(files, list) or not all(
            isinstance(f, dict) and isinstance(f.get("path"), str) and isinstance(f.get("sha256"), str) for f in files
        ):
            raise fail("malformed input list", "provenance.inputs", '[{"path": ..., "sha256": ...}]')
        provenance = Provenance(
            software=text(prov["software"], "provenance.software"),
            procedure=text(prov.get("procedure", ""), "provenance.procedure"),
            stages=texts(prov.get("stages", []), "provenance.stages"),
            inputs=tuple(InputFile(f["path"], f["sha256"]) for f in files),
            created=text(prov.get("created", ""), "provenance.created"),
            data_start=text(prov.get("data_start", ""), "provenance.data_start"),
            data_end=text(prov.get("data_end", ""), "provenance.data_end"),
        )
        site = None if document.get("site") is None else metadata_from_document(document["site"], path)
        record = cls.__new__(cls)
        fields = {
            "serial_number": text(document["serial_number"], "serial_number"),
            "parameters": tuple(parameters),
            "covariance": matrix,
            "provenance": provenance,
            "site": site,
            "determined": texts(document.get("determined", []), "determined"),
            "notes": texts(document.get("notes", []), "notes"),
            "schema_version": RECORD_SCHEMA_VERSION,
            "noise_model": _noise_model(document.get("noise_model"), path),
        }
        for name, value in fields.items():
            object.__setattr__(record, name, value)
        matrix.setflags(write=False)
        _check(record, path)
        return record

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> CalibrationRecord:
        """Read and validate a record.

        Raises
        ------
        InputError
            Unknown schema version, missing keys, bad status, a covariance that is not
            square, symmetric, positive semi-definite or consistent with the σ's, ...
        """
        try:
            with open(path, encoding="utf-8") as handle:
                document = json.load(handle)
        except FileNotFoundError:
            raise InputError("no such file", path=path) from None
        except json.JSONDecodeError as error:
            raise InputError(f"not valid JSON: {error.msg} at line {error.lineno}; the file is damaged or truncated", path=path) from None
        except (OSError, UnicodeDecodeError) as error:
            raise InputError(f"cannot read: {error}", path=path) from None
        return cls.from_document(document, str(path))

    def report(self) -> str:
        """Plain-text table in engineering units where the id is a known term."""
        from stableins.errormodel import known_terms
        from stableins.estimators.result import parameter_table

        terms = known_terms()
        lines = [f"calibration record of {self.serial_number} ({', '.join(self.provenance.stages)}; {self.provenance.software})", ""]
        rows = []
        for p in self.parameters:
            t = terms.get(p.id)
            value, sigma, unit = (
                (float(t.to_engineering(p.value)), float(t.sigma_to_engineering(p.sigma)), t.unit) if t else (p.value, p.sigma, p.unit)
            )
            rows.append((p.id, value, sigma, unit, p.status))
        return "\n".join(lines + parameter_table(rows, self.determined, self.notes))

    def __str__(self) -> str:
        return self.report()


def _layout(document: dict[str, Any]) -> str:
    """JSON for people and diffs: one parameter, one covariance row, one input per line."""

    def dump(value: Any) -> str:
        return json.dumps(value, allow_nan=False)

    def block(items: list[str], indent: str) -> str:
        return "[\n" + ",\n".join(indent + "  " + i for i in items) + "\n" + indent + "]" if items else "[]"

    lines = []
    for key, value in document.items():
        if key == "parameters":
            text = block([dump(p) for p in value], "  ")
        elif key == "covariance":
            text = (
                "{\n"
                + ",\n".join(
                    f"    {dump(k)}: " + (block([dump(row) for row in v], "    ") if k == "matrix" else dump(v)) for k, v in value.items()
                )
                + "\n  }"
            )
        elif isinstance(value, dict) and value:
            inner = [
                f"    {dump(k)}: "
                + (block([dump(x) for x in v], "    ") if isinstance(v, list) and v and isinstance(v[0], dict) else dump(v))
                for k, v in value.items()
            ]
            text = "{\n" + ",\n".join(inner) + "\n  }"
        elif isinstance(value, list):
            text = block([dump(x) for x in value], "  ")
        else:
            text = dump(value)
        lines.append(f"  {dump(key)}: {text}")
    return "{\n" + ",\n".join(lines) + "\n}\n"


def _noise_model(document: Any, path: str | None) -> NoiseModel | None:
    """The optional ``noise_model`` section, validated by :meth:`stableins.noise.NoiseModel.from_document`."""
    if document is None:
        return None
    from stableins.noise import NoiseModel

    return NoiseModel.from_document(document, path)


def _number(value: Any, path: str | None, key: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise InputError(f"{value!r} is not a finite number", path=path, field=key, expected="a finite number")
    return float(value)


def _check(record: CalibrationRecord, path: str | None) -> None:
    """Consistency of a record; raises InputError naming the key."""
    import numpy as np

    def fail(message: str, key: str, expected: str | None = None) -> InputError:
        return InputError(message, path=path, field=key, expected=expected)

    if not record.serial_number:
        raise fail("empty serial number", "serial_number", "a non-empty string")
    ids = record.ids
    if len(set(ids)) != len(ids):
        duplicate = next(i for i in ids if ids.count(i) > 1)
        raise fail(f"parameter {duplicate!r} appears twice", "parameters", "each id once")
    n = len(ids)
    c = record.covariance
    if c.shape != (n, n):
        raise fail(f"shape {c.shape}", "covariance", f"({n}, {n}) following the parameters")
    known = np.array([p.status != "unidentifiable" for p in record.parameters], dtype=bool)
    for k, p in enumerate(record.parameters):
        if p.status not in STATUSES:
            raise fail(f"bad status {p.status!r}", f"parameters[{k}].status", " or ".join(STATUSES))
        if not math.isfinite(p.value):
            raise fail("value is not finite", f"parameters[{k}].value", "a finite number")
        if known[k] and not (np.isfinite(c[k, known]).all() and math.isfinite(p.sigma)):
            raise fail(
                f"covariance of {p.id!r} ({p.status}) is not finite", "covariance", "finite entries except for unidentifiable parameters"
            )
    block = c[np.ix_(known, known)]
    if block.size:
        scale = float(np.abs(block).max()) or 1.0
        asymmetry = float(np.abs(block - block.T).max())
        if asymmetry > SYMMETRY_TOLERANCE * scale:
            i, j = np.unravel_index(int(np.argmax(np.abs(block - block.T))), block.shape)
            a, b = np.array(ids)[known][[i, j]]
            raise fail(
                f"covariance is not symmetric: ({a}, {b}) differs from ({b}, {a}) by {asymmetry:.3g}", "covariance", "a symmetric matrix"
            )
        d = np.sqrt(np.clip(np.diag(block), 0.0, None))
        with np.errstate(divide="ignore", invalid="ignore"):
            correlation = np.where(np.outer(d, d) > 0, block / np.outer(d, d), 0.0)
        if (np.diag(block) < 0).any() or np.linalg.eigvalsh((correlation + correlation.T) / 2).min() < -1e-8:
            raise fail("covariance is not positive semi-definite", "covariance", "a valid covariance matrix")
        sigma = np.array([p.sigma for p in record.parameters])[known]
        bad = ~np.isclose(sigma, d, rtol=1e-6, atol=0.0)
        if bad.any():
            k = int(np.flatnonzero(known)[int(np.argmax(bad))])
            raise fail(
                f"sigma {record.parameters[k].sigma!r} of {ids[k]!r} disagrees with the covariance diagonal",
                f"parameters[{k}].sigma",
                f"sqrt of the covariance diagonal = {d[int(np.argmax(bad))]!r}",
            )


__all__ = ["CalibrationRecord", "InputFile", "Parameter", "Provenance", "STATUSES", "file_sha256"]
