"""Writing a record: its JSON document (docs/formats.md) laid out for people and diffs, written atomically."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

from stableins.data.metadata import metadata_to_document
from stableins.documents import JSONObject
from stableins.records.parameters import Entry
from stableins.records.schema import RECORD_FORMAT
from stableins.records.stages import Calibration, StageRun

if TYPE_CHECKING:  # pragma: no cover
    from stableins.records.content import RecordContent


def record_document(record: RecordContent) -> JSONObject:
    """Return the record's JSON-ready dict (non-finite numbers as ``null``; :meth:`CalibrationRecord.to_document`)."""
    document: JSONObject = {
        "format": RECORD_FORMAT,
        "schema_version": record.schema_version,
        "serial_number": record.serial_number,
        "parameters": [
            {
                "id": p.id,
                "value": p.value,
                "unit": p.unit,
                "sigma": _num(p.sigma),
                "status": p.status.value,
                "determined_by": [{"stage": d.stage, "how": d.how.value} for d in p.determined_by],
            }
            for p in record.parameters
        ],
        "covariance": {
            "ids": list(record.ids),
            "unit": "SI: product of the two parameters' units",
            "matrix": [[_num(x) for x in row] for row in record.covariance.tolist()],
        },
        "calibration": _calibration_document(record.calibration),
        "stages": [_stage_document(s) for s in record.stages],
        "site": None if record.site is None else metadata_to_document(record.site),
        "determined": list(record.determined),
        "notes": list(record.notes),
    }
    if record.discovery is not None:
        document["discovery"] = record.discovery.to_json()
    if record.noise_model is not None:
        document["noise_model"] = record.noise_model.to_document()
    return document


def save_record(record: RecordContent, path: str | os.PathLike[str]) -> Path:
    """Write the record atomically (a reader sees the old file or the whole new one) and return its path."""
    from stableins.data.atomic import atomic_write

    text = layout(record_document(record))
    with atomic_write(path) as handle:
        handle.write(text)
    return Path(path)


def layout(document: Any, indent: str = "", width: int = 160) -> str:
    """Return JSON for people and diffs: short values on one line, long objects one key, list item or matrix row per line."""
    text = json.dumps(document, allow_nan=False, ensure_ascii=False)
    if len(text) + len(indent) <= width or not isinstance(document, dict | list) or not document:
        return text
    inner = indent + "  "
    if isinstance(document, dict):
        items = [f"{inner}{json.dumps(k)}: {layout(v, inner, width)}" for k, v in document.items()]
        return "{\n" + ",\n".join(items) + "\n" + indent + "}"
    items = [inner + layout(v, inner, width) for v in document]
    return "[\n" + ",\n".join(items) + "\n" + indent + "]"


def _num(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def _calibration_document(calibration: Calibration) -> JSONObject:
    prior = calibration.prior
    return {
        "id": calibration.id,
        "procedure": calibration.procedure,
        "software": calibration.software,
        "created": calibration.created,
        "prior": None if prior is None else {"sha256": prior.sha256, "path": prior.path, "created": prior.created},
        "entries": [_entry_document(e) for e in calibration.entries],
    }


def _entry_document(e: Entry) -> JSONObject:
    out: JSONObject = {"key": e.key, "value": e.value, "unit": e.unit}
    if e.prompt:
        out["prompt"] = e.prompt
    return out


def _stage_document(s: StageRun) -> JSONObject:
    out: JSONObject = {
        "id": s.id,
        "name": s.name,
        "calibration": s.calibration,
        "procedure": s.procedure,
        "software": s.software,
        "created": s.created,
        "data_start": s.data_start,
        "data_end": s.data_end,
        "sample_rate": None if s.sample_rate is None else {"value": float(s.sample_rate), "unit": "Hz"},
        "inputs": [{"path": f.path, "sha256": f.sha256} for f in s.inputs],
        "settings": {} if s.settings is None else s.settings.to_document(),
        "entries": [_entry_document(e) for e in s.entries],
        "environment": dict(s.environment),
        "fits": [dict(f) for f in s.fits],
        "likelihood": None
        if s.likelihood is None
        else {
            "ids": list(s.likelihood.ids),
            "point": s.likelihood.point.tolist(),
            "information": s.likelihood.information.tolist(),
            "gradient": s.likelihood.gradient.tolist(),
        },
        "determined": list(s.determined),
        "notes": list(s.notes),
    }
    if s.sensitivities:
        out["sensitivities"] = [x.to_json() for x in s.sensitivities]
    return out
