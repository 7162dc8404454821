"""Column names and units of the data files (the contract of ``docs/formats.md``).

Column headers carry their unit in brackets, e.g. ``f_x[m/s^2]``; a reader accepts a
column only with the unit listed here.  Tag columns (stage, pass, position) have no
unit.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, TypeAlias

if TYPE_CHECKING:  # pragma: no cover
    from numpy.typing import NDArray

#: Columns of a data file as a reader returns them: column name -> one array of its rows, of the column's
#: :attr:`Column.dtype` (``float64``, ``int32`` or ``str``; hence ``NDArray[Any]``).  Every ``read``/``iter_chunks``
#: of the data readers returns or yields this.
Columns: TypeAlias = "dict[str, NDArray[Any]]"


@dataclass(frozen=True)
class Column:
    """One column of a data file: name, unit, type, meaning and the range a physical instrument can give.

    ``limits`` (inclusive, in ``unit``) bound what any instrument stableins serves can write there: a value outside
    is a broken file or a wrong unit, refused by every reader naming the row (docs/formats.md, "What the readers
    check"); None for tag columns.
    """

    name: str
    unit: str | None
    dtype: str  # "float64", "int32" or "str"
    meaning: str
    limits: tuple[float, float] | None = None

    @property
    def header(self) -> str:
        """The column's header: ``name[unit]``, or ``name`` without a unit."""
        return self.name if self.unit is None else f"{self.name}[{self.unit}]"


SCHEMA_VERSION = 1

#: Time stamps [s]: any epoch a clock may count from, up to about 300 years.
TIME_LIMITS = (-1e10, 1e10)
#: Angle-sensor readings, commands and INS attitude [rad]: a few hundred turns of an unwrapped reading.
ANGLE_LIMITS = (-1e3, 1e3)
#: Specific force [m/s²]: about 1,000 g, beyond every navigation- and tactical-grade accelerometer's range.
SPECIFIC_FORCE_LIMITS = (-1e4, 1e4)
#: INS velocity [m/s]: a static base's velocity error, or any vehicle's velocity, stays far below 10 km/s.
VELOCITY_LIMITS = (-1e4, 1e4)
#: Instrument temperature [°C]: from absolute zero to 1,000 °C.
TEMPERATURE_LIMITS = (-273.15, 1e3)

#: One row per sample of a device-level session (coarse passes and fine dwells).
DEVICE_COLUMNS: tuple[Column, ...] = (
    Column("time", "s", "float64", "session time", TIME_LIMITS),
    Column("stage", None, "str", "'coarse' or 'fine'"),
    Column("pass", None, "int32", "coarse pass number (1, 2, ...) or fine pass (1)"),
    Column("position", None, "int32", "position number in the procedure (1..18)"),
    Column("time_since_command", "s", "float64", "time since the position was commanded (settling is early)", TIME_LIMITS),
    Column("command_platform", "rad", "float64", "commanded platform-axis angle-sensor reading", ANGLE_LIMITS),
    Column("command_inner", "rad", "float64", "commanded inner-gimbal angle-sensor reading", ANGLE_LIMITS),
    Column("command_middle", "rad", "float64", "commanded middle-gimbal angle-sensor reading", ANGLE_LIMITS),
    Column("angle_platform", "rad", "float64", "measured platform-axis angle-sensor reading", ANGLE_LIMITS),
    Column("angle_inner", "rad", "float64", "measured inner-gimbal angle-sensor reading", ANGLE_LIMITS),
    Column("angle_middle", "rad", "float64", "measured middle-gimbal angle-sensor reading", ANGLE_LIMITS),
    Column("f_x", "m/s^2", "float64", "x accelerometer output", SPECIFIC_FORCE_LIMITS),
    Column("f_y", "m/s^2", "float64", "y accelerometer output", SPECIFIC_FORCE_LIMITS),
    Column("f_z", "m/s^2", "float64", "z accelerometer output", SPECIFIC_FORCE_LIMITS),
    Column("temperature", "degC", "float64", "instrument temperature", TEMPERATURE_LIMITS),
)

#: One row per sample of a system-level static record (platform fixed in inertial space).
SYSTEM_COLUMNS: tuple[Column, ...] = (
    Column("time", "s", "float64", "time since the start of the record", TIME_LIMITS),
    Column("angle_platform", "rad", "float64", "platform-axis angle-sensor reading", ANGLE_LIMITS),
    Column("angle_inner", "rad", "float64", "inner-gimbal angle-sensor reading", ANGLE_LIMITS),
    Column("angle_middle", "rad", "float64", "middle-gimbal angle-sensor reading", ANGLE_LIMITS),
    Column("f_x", "m/s^2", "float64", "x accelerometer output", SPECIFIC_FORCE_LIMITS),
    Column("f_y", "m/s^2", "float64", "y accelerometer output", SPECIFIC_FORCE_LIMITS),
    Column("f_z", "m/s^2", "float64", "z accelerometer output", SPECIFIC_FORCE_LIMITS),
    Column("velocity_north", "m/s", "float64", "INS north velocity output (the error, on a static base)", VELOCITY_LIMITS),
    Column("velocity_east", "m/s", "float64", "INS east velocity output", VELOCITY_LIMITS),
    Column("velocity_down", "m/s", "float64", "INS down velocity output", VELOCITY_LIMITS),
    Column("roll", "rad", "float64", "INS roll output", ANGLE_LIMITS),
    Column("pitch", "rad", "float64", "INS pitch output", ANGLE_LIMITS),
    Column("heading", "rad", "float64", "INS heading output", ANGLE_LIMITS),
    Column("temperature", "degC", "float64", "instrument temperature", TEMPERATURE_LIMITS),
)


def column_limits() -> dict[str, tuple[float, float]]:
    """Return the limits of every bounded column by name (a name means the same quantity in every file kind)."""
    out: dict[str, tuple[float, float]] = {}
    for c in DEVICE_COLUMNS + SYSTEM_COLUMNS:
        if c.limits is not None:
            assert out.setdefault(c.name, c.limits) == c.limits, c.name
    return out


def column(columns: tuple[Column, ...], name: str) -> Column:
    """Return the column called ``name`` (KeyError when there is none)."""
    for c in columns:
        if c.name == name:
            return c
    raise KeyError(name)
