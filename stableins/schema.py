"""Column names and units of the data files (the contract of ``docs/formats.md``).

Column headers carry their unit in brackets, e.g. ``f_x[m/s^2]``; a reader accepts a
column only with the unit listed here.  Tag columns (stage, pass, position) have no
unit.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Column:
    """One column of a data file: name, unit, type and meaning."""

    name: str
    unit: str | None
    dtype: str  # "float64", "int32" or "str"
    meaning: str

    @property
    def header(self) -> str:
        """The column's header: ``name[unit]``, or ``name`` without a unit."""
        return self.name if self.unit is None else f"{self.name}[{self.unit}]"


SCHEMA_VERSION = 1

#: One row per sample of a device-level session (coarse passes and fine dwells).
DEVICE_COLUMNS: tuple[Column, ...] = (
    Column("time", "s", "float64", "session time"),
    Column("stage", None, "str", "'coarse' or 'fine'"),
    Column("pass", None, "int32", "coarse pass number (1, 2, ...) or fine pass (1)"),
    Column("position", None, "int32", "position number in the procedure (1..18)"),
    Column("time_since_command", "s", "float64", "time since the position was commanded (settling is early)"),
    Column("command_platform", "rad", "float64", "commanded platform-axis angle-sensor reading"),
    Column("command_inner", "rad", "float64", "commanded inner-gimbal angle-sensor reading"),
    Column("command_middle", "rad", "float64", "commanded middle-gimbal angle-sensor reading"),
    Column("angle_platform", "rad", "float64", "measured platform-axis angle-sensor reading"),
    Column("angle_inner", "rad", "float64", "measured inner-gimbal angle-sensor reading"),
    Column("angle_middle", "rad", "float64", "measured middle-gimbal angle-sensor reading"),
    Column("f_x", "m/s^2", "float64", "x accelerometer output"),
    Column("f_y", "m/s^2", "float64", "y accelerometer output"),
    Column("f_z", "m/s^2", "float64", "z accelerometer output"),
    Column("temperature", "degC", "float64", "instrument temperature"),
)

#: One row per sample of a system-level static record (platform fixed in inertial space).
SYSTEM_COLUMNS: tuple[Column, ...] = (
    Column("time", "s", "float64", "time since the start of the record"),
    Column("angle_platform", "rad", "float64", "platform-axis angle-sensor reading"),
    Column("angle_inner", "rad", "float64", "inner-gimbal angle-sensor reading"),
    Column("angle_middle", "rad", "float64", "middle-gimbal angle-sensor reading"),
    Column("f_x", "m/s^2", "float64", "x accelerometer output"),
    Column("f_y", "m/s^2", "float64", "y accelerometer output"),
    Column("f_z", "m/s^2", "float64", "z accelerometer output"),
    Column("velocity_north", "m/s", "float64", "INS north velocity output (the error, on a static base)"),
    Column("velocity_east", "m/s", "float64", "INS east velocity output"),
    Column("velocity_down", "m/s", "float64", "INS down velocity output"),
    Column("roll", "rad", "float64", "INS roll output"),
    Column("pitch", "rad", "float64", "INS pitch output"),
    Column("heading", "rad", "float64", "INS heading output"),
    Column("temperature", "degC", "float64", "instrument temperature"),
)


def column(columns: tuple[Column, ...], name: str) -> Column:
    """Return the column called ``name`` (KeyError when there is none)."""
    for c in columns:
        if c.name == name:
            return c
    raise KeyError(name)
