"""The record's file format: its name and schema version, and the migration of version-1 documents.

A version-1 record had one ``provenance`` (procedure, stage names, inputs, times) and no stage runs;
:func:`migrate_v1` turns it into a version-2 document (docs/formats.md, "Calibration record").
"""

from __future__ import annotations

import hashlib
import json

from stableins.documents import JSONObject, JSONValue
from stableins.errors import InputError
from stableins.status import Status

RECORD_FORMAT = "stableins-calibration-record"
RECORD_SCHEMA_VERSION = 2
#: Relative asymmetry tolerated in a stored covariance.
SYMMETRY_TOLERANCE = 1e-9
#: Keys of a calibration's own entries a person may give (``--set KEY=VALUE``), besides the prompts of a procedure.
CALIBRATION_FIELDS = ("laboratory", "customer", "operator", "location")


def migrate_v1(document: JSONObject, path: str | None = None) -> JSONObject:
    """Return a schema-version-1 document as version 2.

    Version 1 had one ``provenance`` (procedure, stage names, inputs, times) and no stage runs:
    the migrated record has one stage run named after the stages (``coarse+fine+system``) that holds
    them, with no likelihood and no fits, and every estimated parameter determined by it.  A note says so.

    Parameters
    ----------
    document : dict
        The version-1 document (not modified).
    path : str, optional
        The file it came from, named by errors.

    Returns
    -------
    dict
        The version-2 document.

    Raises
    ------
    InputError
        The document has no ``provenance`` object.
    """
    prov = document.get("provenance")
    if not isinstance(prov, dict):
        raise InputError("malformed", path=path, field="provenance", expected="an object with software, procedure, stages, inputs, created")
    stages = prov.get("stages", [])
    names = [s for s in stages if isinstance(s, str)] if isinstance(stages, list) else []
    name = "+".join(names) if isinstance(stages, list) and len(names) == len(stages) and stages else "calibration"
    created = prov.get("created", "") if isinstance(prov.get("created", ""), str) else ""
    calibration_id = f"cal-v1-{hashlib.sha256(json.dumps([document.get('serial_number'), created]).encode()).hexdigest()[:8]}"
    stage_id = f"{name}-v1{calibration_id[-6:]}"
    out = {k: v for k, v in document.items() if k not in ("provenance", "parameters", "schema_version")}
    out["schema_version"] = RECORD_SCHEMA_VERSION
    out["parameters"] = _v1_parameters(document, stage_id)
    out["calibration"] = {
        "id": calibration_id,
        "procedure": prov.get("procedure", ""),
        "software": prov.get("software", ""),
        "created": created,
        "prior": None,
        "entries": [],
    }
    out["stages"] = [_v1_stage(document, prov, stage_id=stage_id, name=name, calibration_id=calibration_id)]
    notes = document.get("notes", [])
    if isinstance(notes, list):
        out["notes"] = [*notes, "record migrated from schema version 1 (docs/formats.md)"]
    else:
        out["notes"] = notes
    return out


def _v1_parameters(document: JSONObject, stage_id: str) -> list[JSONValue]:
    """Return the parameters of a version-1 document, every estimated one determined (alone) by the migrated stage."""
    parameters = []
    given = document.get("parameters")
    for item in given if isinstance(given, list) else []:
        if isinstance(item, dict):
            item = dict(item)
            item["determined_by"] = [{"stage": stage_id, "how": "alone"}] if item.get("status") == Status.ESTIMATED else []
        parameters.append(item)
    return parameters


def _v1_stage(document: JSONObject, prov: JSONObject, *, stage_id: str, name: str, calibration_id: str) -> JSONObject:
    """Return the one stage run of a migrated record, from the version-1 provenance ``prov``."""
    created = prov.get("created", "") if isinstance(prov.get("created", ""), str) else ""
    site = document.get("site")
    sample_rate = None
    if isinstance(site, dict) and isinstance(site.get("sample_rate"), dict):
        sample_rate = site["sample_rate"]
    return {
        "id": stage_id,
        "name": name,
        "calibration": calibration_id,
        "procedure": prov.get("procedure", ""),
        "software": prov.get("software", ""),
        "created": created,
        "data_start": prov.get("data_start", ""),
        "data_end": prov.get("data_end", ""),
        "sample_rate": sample_rate,
        "inputs": prov.get("inputs", []),
        "settings": {},
        "entries": [],
        "environment": {},
        "fits": [],
        "likelihood": None,
        "determined": [],
        "notes": ["migrated from a schema-version-1 record: the stages' settings, fits and likelihood were not recorded"],
    }
