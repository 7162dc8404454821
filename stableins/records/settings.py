"""A stage run's settings read back: the stage's own frozen settings class, from the JSON object a record stores.

Each stage's settings write themselves (``to_document``, :class:`stableins.estimators.result.StageSettings`); this
module is the one place that knows which class reads which object: by the object's ``stage`` when it states one
(the coarse, fine, joint, system and pose fits), else by the stage run's name (a device stage's run without one holds
the settings of ``stableins calibrate device``).  Records written before the settings
were typed read the same way; the system stage's earlier form (five gyro-drift keys) and the first schema-2 records'
``slow_noise`` are mapped by the classes' readers (docs/formats.md, "Stage settings").
"""

from __future__ import annotations

from collections.abc import Callable

from stableins.documents import DocumentFields, JSONValue
from stableins.errors import InputError
from stableins.estimators.device_settings import DeviceFitSettings, DeviceSessionSettings
from stableins.estimators.result import Stage, StageSettings


def reader(stage: str) -> Callable[[DocumentFields], StageSettings] | None:  # noqa: PLR0911 - one return per stage
    """Return the reader of the settings class of the stage named ``stage`` (or the object's ``stage``); None for another name.

    Each stage's module is imported when a record holding that stage is read, and only then: the systematic, gyro, lever
    and drift stages' modules cost a command that reads a device or system record (``calibrate system``, ``report``)
    their imports for nothing (issue 30).
    """
    if stage in (Stage.COARSE, Stage.FINE):
        return DeviceFitSettings.from_document
    if stage == Stage.SYSTEM:
        from stableins.estimators.system.settings import SystemSettings

        return SystemSettings.from_document
    if stage == Stage.POSES:
        from stableins.estimators.poses import PoseSettings

        return PoseSettings.from_document
    if stage == Stage.LEVER:
        from stableins.estimators.lever.model import LeverOptions

        return LeverOptions.from_document
    if stage == Stage.DRIFT:
        from stableins.estimators.drift.model import DriftSettings

        return DriftSettings.from_document
    if stage == Stage.SYSTEMATIC:
        from stableins.estimators.systematic.result import SystematicSettings

        return SystematicSettings.from_document
    if stage == Stage.THERMAL:
        from stableins.estimators.thermal_sensitivity import ThermalSettings

        return ThermalSettings.from_document
    if stage == Stage.GYRO:
        from stableins.estimators.gyro_sensitivity import GyroSettings

        return GyroSettings.from_document
    return None


#: The stages whose run a device calibration's settings describe (``stableins calibrate device``: the coarse stage alone,
#: or the coarse and fine stages fused), told from a fit's own settings by their having no ``stage``.
DEVICE_FIT_STAGES = (Stage.COARSE, Stage.FINE, Stage.DEVICE)


def settings_from_document(name: str, value: JSONValue, where: str, path: str | None = None) -> StageSettings | None:
    """Return the settings of a stage run named ``name`` from the object a record stores (None: ``{}``, none stated).

    Parameters
    ----------
    name : str
        The stage run's name (``coarse+fine``, ``system``, ``lever`` ...).
    value : JSON value
        The run's ``settings`` object.
    where, path : str
        Its key in the record (``stages[2].settings``) and the record's file, for errors.

    Raises
    ------
    InputError
        Not an object, a stage that stores no settings, or a field of the wrong type (named ``where.key``).
    """
    fields = DocumentFields.of(value, where, path)
    if not fields.document:
        return None
    stated = fields.document.get("stage")
    if stated == Stage.DEVICE:  # the joint fit's own settings
        return DeviceFitSettings.from_document(fields)
    if stated is None and name in DEVICE_FIT_STAGES:  # the device calibration's (stableins calibrate device)
        return DeviceSessionSettings.from_document(fields)
    key = stated if isinstance(stated, str) else name
    read = reader(key)
    if read is None:
        field = where if stated is None else f"{where}.stage"
        expected = "the settings of a stage of docs/formats.md"
        raise InputError(f"settings of a stage stableins does not know ({key!r})", path=path, field=field, expected=expected)
    return read(fields)
