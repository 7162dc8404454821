"""Reading a record: a version-2 JSON document validated key by key, version 1 migrated first.

Every problem is an :class:`stableins.errors.InputError` naming the file and the key (``stages[2].likelihood.point``).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, TypedDict

from stableins.data.metadata import metadata_from_document
from stableins.documents import JSONObject
from stableins.errors import InputError, NotDeterminedError
from stableins.identifiers import check_serial_number, check_timestamp
from stableins.records.content import _RecordT, check_record
from stableins.records.parameters import DeterminedBy, Entry, Parameter
from stableins.records.schema import RECORD_FORMAT, RECORD_SCHEMA_VERSION, migrate_v1
from stableins.records.settings import settings_from_document
from stableins.records.stages import Calibration, InputFile, PriorReference, StageRun
from stableins.status import STATUSES, Determination, Status

if TYPE_CHECKING:  # pragma: no cover
    from stableins.discovery.history import ModelHistory
    from stableins.estimators.result import InputSensitivity, Likelihood
    from stableins.noise import NoiseModel

#: What a parameter object holds (errors show it).
_PARAMETER_KEYS = '{"id", "value", "unit", "sigma", "status", "determined_by"}'


def read_document(cls: type[_RecordT], document: Any, path: str | None = None) -> _RecordT:
    """Return the record (of type ``cls``) a JSON document holds, validated (:meth:`CalibrationRecord.from_document`)."""
    if isinstance(document, dict) and document.get("format") == RECORD_FORMAT and document.get("schema_version") == 1:
        document = migrate_v1(document, path)
    return _Reader(path).record(cls, document)


class _OptionalSections(TypedDict, total=False):
    """The optional sections of a record, read: its noise model and its discovery history."""

    noise_model: NoiseModel
    discovery: ModelHistory


class _Reader:
    """Validation of a version-2 document, every problem an :class:`InputError` naming the file and key."""

    def __init__(self, path: str | None) -> None:
        self.path = path

    def fail(self, message: str, key: str | None = None, expected: str | None = None) -> InputError:
        return InputError(message, path=self.path, field=key, expected=expected)

    # ------------------------------------------------------------------ values
    def text(self, value: Any, key: str) -> str:
        if not isinstance(value, str):
            raise self.fail(f"{value!r} is not a string", key, "a string")
        return value

    def timestamp(self, value: Any, key: str, *, optional: bool) -> str:
        return check_timestamp(value, field=key, path=self.path, optional=optional)

    def texts(self, value: Any, key: str) -> tuple[str, ...]:
        if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
            raise self.fail(f"{value!r} is not a list of strings", key, "a list of strings")
        return tuple(value)

    def mapping(self, value: Any, key: str) -> JSONObject:
        if not isinstance(value, dict):
            raise self.fail("not an object", key, "a JSON object")
        return value

    def number(self, value: Any, key: str) -> float:
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
            raise self.fail(f"{value!r} is not a finite number", key, "a finite number")
        return float(value)

    def vector(self, value: Any, n: int, key: str) -> Any:
        import numpy as np

        if not isinstance(value, list) or len(value) != n:
            raise self.fail("not a list of one number per id", key, f"{n} numbers")
        return np.array([self.number(x, key) for x in value])

    def matrix(self, rows: Any, n: int, key: str, *, nulls: bool) -> Any:
        import numpy as np

        if not isinstance(rows, list) or len(rows) != n or not all(isinstance(r, list) and len(r) == n for r in rows):
            raise self.fail("not a square list of rows", key, f"{n} rows of {n} numbers")
        ok = (
            (lambda x: x is None or (isinstance(x, int | float) and not isinstance(x, bool)))
            if nulls
            else (lambda x: isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x))
        )
        if not all(ok(x) for r in rows for x in r):
            raise self.fail("not a numeric matrix", key, "numbers (null only for unidentifiable parameters)" if nulls else "finite numbers")
        return np.array([[math.nan if x is None else float(x) for x in r] for r in rows], dtype=float).reshape(n, n)

    # ------------------------------------------------------------------ parts
    def entries(self, value: Any, key: str) -> tuple[Entry, ...]:
        if not isinstance(value, list):
            raise self.fail("not a list", key, '[{"key", "value", "unit"}]')
        out = []
        for k, item in enumerate(value):
            where = f"{key}[{k}]"
            item = self.mapping(item, where)
            if "key" not in item or "value" not in item:
                raise self.fail("missing key or value", where, '{"key", "value", "unit"}')
            v = item["value"]
            if isinstance(v, bool) or not isinstance(v, str | int | float) or (isinstance(v, float) and not math.isfinite(v)):
                raise self.fail(f"{v!r} is not a number or text", f"{where}.value", "a finite number or a string")
            out.append(
                Entry(
                    self.text(item["key"], f"{where}.key"),
                    float(v) if isinstance(v, int | float) else v,
                    self.text(item.get("unit", ""), f"{where}.unit"),
                    self.text(item.get("prompt", ""), f"{where}.prompt"),
                )
            )
        return tuple(out)

    def inputs(self, value: Any, key: str) -> tuple[InputFile, ...]:
        if not isinstance(value, list) or not all(
            isinstance(f, dict) and isinstance(f.get("path"), str) and isinstance(f.get("sha256"), str) for f in value
        ):
            raise self.fail("malformed input list", key, '[{"path": ..., "sha256": ...}]')
        for f in value:
            if len(f["sha256"]) != 64 or any(c not in "0123456789abcdef" for c in f["sha256"].lower()):
                raise self.fail(f"not a SHA-256 hex digest for {f['path']!r}: {f['sha256']!r}", key, "64 hex digits")
        return tuple(InputFile(f["path"], f["sha256"]) for f in value)

    def likelihood(self, value: Any, key: str) -> Likelihood | None:
        if value is None:
            return None
        from stableins.estimators.result import Likelihood

        value = self.mapping(value, key)
        ids = self.texts(value.get("ids"), f"{key}.ids")
        n = len(ids)
        point = self.vector(value.get("point"), n, f"{key}.point")
        gradient = self.vector(value.get("gradient"), n, f"{key}.gradient")
        information = self.matrix(value.get("information"), n, f"{key}.information", nulls=False)
        try:
            return Likelihood(ids, point, information, gradient)
        except (InputError, NotDeterminedError):
            raise  # a described error passes through as it is (issue 29)
        except ValueError as error:
            raise self.fail(str(error), key) from None

    def sample_rate(self, value: Any, key: str) -> float | None:
        if value is None:
            return None
        rate = self.mapping(value, key)
        if rate.get("unit") != "Hz":
            raise self.fail(f"unit {rate.get('unit')!r}", key, "unit 'Hz'")
        return self.number(rate.get("value"), key)

    def stage(self, value: Any, k: int) -> StageRun:
        where = f"stages[{k}]"
        s = self.mapping(value, where)
        for name in ("id", "name", "calibration"):
            if name not in s:
                raise self.fail("missing key", f"{where}.{name}", "the keys of docs/formats.md")
        rate = self.sample_rate(s.get("sample_rate"), f"{where}.sample_rate")
        fits = s.get("fits", [])
        if not isinstance(fits, list) or not all(isinstance(f, dict) for f in fits):
            raise self.fail("not a list of objects", f"{where}.fits", "fit evidence objects")
        objects = [f for f in fits if isinstance(f, dict)]  # all of them
        for j, fit in enumerate(objects):
            self.fit(fit, f"{where}.fits[{j}]")
        texts = {name: self.text(s[name], f"{where}.{name}") for name in ("id", "name", "calibration")}
        for name in ("procedure", "software"):
            texts[name] = self.text(s.get(name, ""), f"{where}.{name}")
        for name in ("created", "data_start", "data_end"):
            texts[name] = self.timestamp(s.get(name, ""), f"{where}.{name}", optional=True)
        return StageRun(
            **texts,
            sample_rate=rate,
            inputs=self.inputs(s.get("inputs", []), f"{where}.inputs"),
            settings=settings_from_document(texts["name"], s.get("settings", {}), f"{where}.settings", self.path),
            entries=self.entries(s.get("entries", []), f"{where}.entries"),
            environment=dict(self.mapping(s.get("environment", {}), f"{where}.environment")),
            fits=tuple(dict(f) for f in objects),
            likelihood=self.likelihood(s.get("likelihood"), f"{where}.likelihood"),
            determined=self.texts(s.get("determined", []), f"{where}.determined"),
            notes=self.texts(s.get("notes", []), f"{where}.notes"),
            sensitivities=self.sensitivities(s.get("sensitivities", []), f"{where}.sensitivities"),
        )

    def fit(self, fit: JSONObject, where: str) -> None:
        """Check the fields of one fit's residual evidence (:func:`stableins.records.stages.fit_evidence`) that are present."""
        checks = {
            "stage": self.text, "residual_unit": self.text, "parameter_ids": self.texts, "residual_labels": self.texts,
            "rank": self.count, "dof": self.count, "residuals": self.numbers, "residual_sigma": self.numbers,
            "chi2": self.optional_number, "chi2_red": self.optional_number,
        }  # fmt: skip
        for name, check in checks.items():
            if name in fit:
                check(fit[name], f"{where}.{name}")

    def count(self, value: Any, key: str) -> int:
        if isinstance(value, bool) or not isinstance(value, int) or value < 0:
            raise self.fail(f"{value!r} is not a count", key, "a whole number >= 0")
        return value

    def numbers(self, value: Any, key: str) -> tuple[float, ...]:
        if not isinstance(value, list):
            raise self.fail("not a list", key, "a list of finite numbers")
        return tuple(self.number(x, key) for x in value)

    def optional_number(self, value: Any, key: str) -> float | None:
        return None if value is None else self.number(value, key)

    def sensitivities(self, value: Any, key: str) -> tuple[InputSensitivity, ...]:
        if not isinstance(value, list):
            raise self.fail("not a list", key, "a list of input sensitivities (docs/formats.md)")
        return tuple(self.sensitivity(item, f"{key}[{k}]") for k, item in enumerate(value))

    def sensitivity(self, value: Any, where: str) -> InputSensitivity:
        from stableins.estimators.result import InputSensitivity

        item = self.mapping(value, where)
        ids = self.texts(item.get("ids"), f"{where}.ids")
        n = len(ids)
        gradient = self.vector(item["gradient"], n, f"{where}.gradient") if "gradient" in item else None
        covariance = self.matrix(item["covariance"], n, f"{where}.covariance", nulls=False) if "covariance" in item else None
        try:
            return InputSensitivity(
                self.text(item.get("input"), f"{where}.input"),
                self.text(item.get("unit", ""), f"{where}.unit"),
                ids,
                self.number(item.get("value", 0.0), f"{where}.value"),
                gradient,
                covariance,
                self.number(item.get("step", 0.0), f"{where}.step"),
            )
        except (InputError, NotDeterminedError):
            raise  # a described error passes through as it is (issue 29)
        except ValueError as error:
            raise self.fail(str(error), where, "a gradient or a covariance over the ids") from None

    def parameter(self, item: Any, k: int, stage_ids: set[str]) -> Parameter:
        where = f"parameters[{k}]"
        if not isinstance(item, dict):
            raise self.fail("not an object", where, _PARAMETER_KEYS)
        for key in ("id", "value", "unit", "sigma", "status"):
            if key not in item:
                raise self.fail("missing key", f"{where}.{key}", _PARAMETER_KEYS)
        parameter_id = self.text(item["id"], f"{where}.id")
        if item["status"] not in STATUSES:
            raise self.fail(f"bad status {item['status']!r} for {parameter_id!r}", f"{where}.status", " or ".join(STATUSES))
        value = self.number(item["value"], f"{where}.value")
        sigma = math.nan if item["sigma"] is None else self.number(item["sigma"], f"{where}.sigma")
        given = item.get("determined_by", [])
        if not isinstance(given, list):
            raise self.fail("not a list", f"{where}.determined_by", '[{"stage": ..., "how": ...}]')
        sources = tuple(self.determined_by(d, f"{where}.determined_by[{j}]", stage_ids) for j, d in enumerate(given))
        return Parameter(parameter_id, value, self.text(item["unit"], f"{where}.unit"), sigma, Status(item["status"]), sources)

    def determined_by(self, value: Any, at: str, stage_ids: set[str]) -> DeterminedBy:
        if not isinstance(value, dict) or not isinstance(value.get("stage"), str) or value["stage"] not in stage_ids:
            raise self.fail(f"{value!r} does not name a stage of the record", at, "the id of one of the record's stages")
        hows = tuple(h.value for h in Determination)
        if value.get("how") not in hows:
            raise self.fail(f"how {value.get('how')!r}", f"{at}.how", " or ".join(hows))
        return DeterminedBy(value["stage"], Determination(value["how"]))

    def calibration(self, value: Any) -> Calibration:
        c = self.mapping(value, "calibration")
        if "id" not in c:
            raise self.fail("missing key", "calibration.id", "the keys of docs/formats.md")
        given = c.get("prior")
        prior = None
        if given is not None:
            written = self.mapping(given, "calibration.prior")
            prior = PriorReference(
                self.text(written.get("sha256", ""), "calibration.prior.sha256"),
                self.text(written.get("path", ""), "calibration.prior.path"),
                self.timestamp(written.get("created", ""), "calibration.prior.created", optional=True),
            )
        return Calibration(
            id=self.text(c["id"], "calibration.id"),
            procedure=self.text(c.get("procedure", ""), "calibration.procedure"),
            software=self.text(c.get("software", ""), "calibration.software"),
            created=self.timestamp(c.get("created", ""), "calibration.created", optional=True),
            prior=prior,
            entries=self.entries(c.get("entries", []), "calibration.entries"),
        )

    # ------------------------------------------------------------------ the record
    def header(self, document: Any) -> JSONObject:
        if not isinstance(document, dict):
            raise self.fail("not a JSON object", expected="a calibration record (docs/formats.md)")
        if document.get("format") != RECORD_FORMAT:
            raise self.fail(f"format {document.get('format')!r}", "format", f"'{RECORD_FORMAT}'")
        if document.get("schema_version") != RECORD_SCHEMA_VERSION:
            raise self.fail(
                f"unknown schema version {document.get('schema_version')!r}; this stableins reads versions 1 and {RECORD_SCHEMA_VERSION}",
                "schema_version",
                str(RECORD_SCHEMA_VERSION),
            )
        for key in ("serial_number", "parameters", "covariance", "calibration", "stages"):
            if key not in document:
                raise self.fail("missing key", key, "the keys of docs/formats.md")
        return document

    def stages(self, value: Any) -> tuple[StageRun, ...]:
        if not isinstance(value, list):
            raise self.fail("not a list", "stages", "a list of stage runs")
        stages = tuple(self.stage(s, k) for k, s in enumerate(value))
        if len({s.id for s in stages}) != len(stages):
            raise self.fail("a stage id appears twice", "stages", "unique stage ids")
        return stages

    def parameters(self, value: Any, stage_ids: set[str]) -> tuple[Parameter, ...]:
        if not isinstance(value, list) or not value:
            shown = "not a list" if not isinstance(value, list) else "empty"
            raise self.fail(shown, "parameters", "a non-empty list of parameter objects")
        return tuple(self.parameter(item, k, stage_ids) for k, item in enumerate(value))

    def covariance(self, value: Any, ids: list[str]) -> Any:
        if not isinstance(value, dict) or "ids" not in value or "matrix" not in value:
            raise self.fail("malformed", "covariance", '{"ids": [...], "matrix": [[...]]}')
        if value["ids"] != ids:
            raise self.fail(f"ids {value['ids']!r} do not follow the parameters {ids}", "covariance.ids", "the parameter ids in order")
        return self.matrix(value["matrix"], len(ids), "covariance.matrix", nulls=True)

    def optional(self, document: JSONObject) -> _OptionalSections:
        """Return the optional sections present (``noise_model``, ``discovery``), read."""
        optional: _OptionalSections = {}
        if document.get("noise_model") is not None:
            from stableins.noise import NoiseModel

            optional["noise_model"] = NoiseModel.from_document(document["noise_model"], self.path)
        if document.get("discovery") is not None:
            from stableins.discovery.history import ModelHistory

            try:
                optional["discovery"] = ModelHistory.from_json(document["discovery"])
            except (InputError, NotDeterminedError):
                raise  # a described error passes through as it is (issue 29)
            except ValueError as error:
                where, _, what = str(error).partition(": ")
                raise self.fail(what, where, "the discovery section of docs/formats.md") from None
        return optional

    def record(self, cls: type[_RecordT], document: Any) -> _RecordT:
        document = self.header(document)
        stages = self.stages(document["stages"])
        parameters = self.parameters(document["parameters"], {s.id for s in stages})
        matrix = self.covariance(document["covariance"], [p.id for p in parameters])
        calibration = self.calibration(document["calibration"])
        site = None if document.get("site") is None else metadata_from_document(document["site"], self.path)
        optional = self.optional(document)
        record = cls.__new__(cls)
        fields = {
            "serial_number": check_serial_number(document["serial_number"], field="serial_number", path=self.path),
            "parameters": parameters,
            "covariance": matrix,
            "calibration": calibration,
            "stages": stages,
            "site": site,
            "determined": self.texts(document.get("determined", []), "determined"),
            "notes": self.texts(document.get("notes", []), "notes"),
            "discovery": optional.get("discovery"),
            "noise_model": optional.get("noise_model"),
            "schema_version": RECORD_SCHEMA_VERSION,
        }
        for name, value in fields.items():
            object.__setattr__(record, name, value)
        matrix.setflags(write=False)
        check_record(record, self.path)
        return record
