"""A stage's settings are its own frozen class (issue 29): written by it, read back by it, records of before included.

The record in ``tests/data/records`` was written by stableins 402dc18, before the settings were typed: its system
stage states the gyro drift in five keys beside the options (``"gyro_drift": "ignore"`` next to
``"estimate_gyro_drift": true``).  It still loads, says the same in words, gives the same uncertainty budget, and is
saved in the one-object form; nothing else of it changes.
"""

from __future__ import annotations

import ast
import copy
import json
import lzma
from pathlib import Path

import pytest

import stableins
from stableins.errors import InputError
from stableins.estimators.device_settings import DeviceSessionSettings
from stableins.estimators.gyro_sensitivity import GyroSettings
from stableins.estimators.system.gyro_drift import DriftSource
from stableins.estimators.system.options import GyroDrift
from stableins.estimators.system.settings import SystemSettings
from stableins.noise import NoiseSource
from stableins.records import CalibrationRecord
from stableins.records.settings import settings_from_document
from stableins.reporting.content import describe_settings

OLD_RECORD = Path(__file__).parent / "data" / "records" / "system-402dc18.json.xz"
DEG_PER_HOUR = 4.84813681109536e-06  # rad/s


@pytest.fixture(scope="module")
def old() -> dict:
    return json.loads(lzma.decompress(OLD_RECORD.read_bytes()))


def test_a_record_of_before_loads_with_its_settings_mapped(old):
    record = CalibrationRecord.from_document(copy.deepcopy(old))
    device, gyro, system = (s.settings for s in record.stages)
    assert isinstance(device, DeviceSessionSettings) and device.procedures == ("device-coarse", "device-fine")
    assert device.noise_model is not None and device.noise_model.source is NoiseSource.DEVICE_DWELLS
    assert isinstance(gyro, GyroSettings)
    assert isinstance(system, SystemSettings)
    stated = old["stages"][2]["settings"]
    assert stated["gyro_drift"] == "ignore" and stated["estimate_gyro_drift"] is True  # the earlier form
    options = system.options
    assert options.gyro_drift is GyroDrift.IGNORE and options.estimate_gyro_drift is True and options.estimate_k2 is True
    assert options.known_gyro_drift == tuple(stated["known_gyro_drift"]) and options.gyro_drift_uncertainty is None
    assert system.gyro_drift_source is DriftSource.GIVEN and not system.measures_gyro_drift
    assert system.noise_source is NoiseSource.DEVICE_DWELLS
    words = describe_settings(system)
    assert "gyro drift given: 1e-09, 2e-09, 0 °/h (platform x, y, z)" in words and "from the third harmonic" in words
    assert "measured from the gimbal readings" not in words  # the source says the drift was given, not measured


def test_saved_again_only_the_system_settings_change_form(old):
    document = CalibrationRecord.from_document(copy.deepcopy(old)).to_document()
    new = document["stages"][2]["settings"]
    assert new["gyro_drift"] == {
        "attitude_fit": "ignore",
        "measured": True,
        "known": old["stages"][2]["settings"]["known_gyro_drift"],
        "uncertainty": None,
        "source": "given",
    }
    gone = {"known_gyro_drift", "gyro_drift_uncertainty", "estimate_gyro_drift", "gyro_drift_source"}
    assert not gone & set(new)
    before = {k: v for k, v in old["stages"][2]["settings"].items() if k not in gone | {"gyro_drift"}}
    assert {k: v for k, v in new.items() if k != "gyro_drift"} == before  # every other option as it was
    rest = copy.deepcopy(old)
    document["stages"][2]["settings"] = rest["stages"][2]["settings"] = None
    assert document == rest  # and nothing else of the record
    saved = CalibrationRecord.from_document(copy.deepcopy(old)).to_document()
    assert CalibrationRecord.from_document(copy.deepcopy(saved)).to_document() == saved  # the new form reads back as written
    read = CalibrationRecord.from_document(copy.deepcopy(old)).stages[2].settings
    assert CalibrationRecord.from_document(saved).stages[2].settings == read


def test_the_budget_of_the_record_is_the_same_in_either_form(old):
    from stableins.reporting.budget_sources import uncertainty_budget

    before = CalibrationRecord.from_document(copy.deepcopy(old))
    after = CalibrationRecord.from_document(before.to_document())
    a, b = uncertainty_budget(before), uncertainty_budget(after)
    assert repr(a) == repr(b)


@pytest.mark.parametrize(
    ("change", "field"),
    [
        (lambda s: s.update(known_gyro_drift="x"), "stages[2].settings.known_gyro_drift"),
        (lambda s: s.update(noise_model="a guess"), "stages[2].settings.noise_model"),
        (lambda s: s.update(gyro_drift_source="the gyros"), "stages[2].settings.gyro_drift.source"),
        (lambda s: s.update(chunk_rows=-1), "stages[2].settings.chunk_rows"),
    ],
)
def test_a_bad_setting_of_before_is_refused_naming_its_field(old, change, field):
    document = copy.deepcopy(old)
    change(document["stages"][2]["settings"])
    with pytest.raises(InputError) as error:
        CalibrationRecord.from_document(document)
    assert error.value.field == field


def test_a_bad_setting_in_the_new_form_is_refused_naming_its_field(old):
    document = CalibrationRecord.from_document(copy.deepcopy(old)).to_document()
    document["stages"][2]["settings"]["gyro_drift"]["measured"] = "yes"
    with pytest.raises(InputError) as error:
        CalibrationRecord.from_document(document)
    assert error.value.field == "stages[2].settings.gyro_drift.measured"
    document["stages"][2]["settings"]["gyro_drift"]["measured"] = True
    document["stages"][2]["settings"]["polar_check"] = True
    with pytest.raises(InputError, match="not an option of the system stage"):
        CalibrationRecord.from_document(document)


def test_settings_of_a_stage_stableins_does_not_know_are_refused():
    with pytest.raises(InputError, match="does not know"):
        settings_from_document("warm-up", {"minutes": 30}, "stages[0].settings")
    assert settings_from_document("coarse+fine+system", {}, "stages[0].settings") is None  # a migrated record: none stated


def test_no_stage_settings_are_read_by_string_key():
    """No ``x.settings[...]`` or ``x.settings.get(...)`` in the package: a stage's settings are read by attribute."""
    package = Path(stableins.__file__).resolve().parent
    found = []
    for path in sorted(package.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            target = None
            if isinstance(node, ast.Subscript):
                target = node.value
            elif isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == "get":
                target = node.func.value
            if isinstance(target, ast.Attribute) and target.attr == "settings":
                found.append(f"{path.relative_to(package)}:{node.lineno}")
    assert not found, f"settings read by string key: {found}"
