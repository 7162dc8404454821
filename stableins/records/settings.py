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
from functools import cache

from stableins.documents import DocumentFields, JSONValue
from stableins.errors import InputError
from stableins.estimators.device_settings import DeviceFitSettings, DeviceSessionSettings
from stableins.estimators.result import Stage, StageSettings


@cache
def readers() -> dict[str, Callable[[DocumentFields], StageSettings]]:
    """Return the settings class's reader of each stage that stores settings, by the stage's name (or the object's ``stage``).

    Imported when a record is read, not with the package: the systematic and gyro stages' modules bring filterpy and
    scipy.stats, which a command that only reads records (``calibrate system``, ``report``) does not otherwise need.
    """
    from stableins.estimators.drift.model import DriftSettings
    from stableins.estimators.gyro_sensitivity import GyroSettings
    from stableins.estimators.lever.model import LeverOptions
    from stableins.estimators.poses import PoseSettings
    from stableins.estimators.system.settings import SystemSettings
    from stableins.estimators.systematic.result import SystematicSettings
    from stableins.estimators.thermal_sensitivity import ThermalSettings

    return {
        Stage.COARSE: DeviceFitSettings.from_document,
        Stage.FINE: DeviceFitSettings.from_document,
        Stage.SYSTEM: SystemSettings.from_document,
        Stage.POSES: PoseSettings.from_document,
        Stage.LEVER: LeverOptions.from_document,
        Stage.DRIFT: DriftSettings.from_document,
        Stage.SYSTEMATIC: SystematicSettings.from_document,
        Stage.THERMAL: ThermalSettings.from_document,
        Stage.GYRO: GyroSettings.from_document,
    }


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
    reader = readers().get(key)
    if reader is None:
        field = where if stated is None else f"{where}.stage"
        expected = "the settings of a stage of docs/formats.md"
        raise InputError(f"settings of a stage stableins does not know ({key!r})", path=path, field=field, expected=expected)
    return reader(fields)
