"""Site and unit metadata carried beside every dataset (see ``docs/formats.md``)."""

from __future__ import annotations

import math
from typing import Any

from stableins.documents import JSONObject
from stableins.dwell_mode import DEFAULT_DWELL_MODE, DwellMode
from stableins.site import SiteMetadata

# --------------------------------------------------------------------------- file documents
#: Units accepted in files for each physical quantity of :class:`SiteMetadata`, with the
#: factor that converts the file value to SI (the first unit is the one written).
ANGLE_UNITS: dict[str, float] = {"deg": math.radians(1.0), "rad": 1.0}  # math: this module must not load numpy (conventions does)
QUANTITY_UNITS: dict[str, dict[str, float]] = {
    "latitude": ANGLE_UNITS,
    "height": {"m": 1.0},
    "gravity": {"m/s^2": 1.0},
    "gravity_uncertainty": {"m/s^2": 1.0, "mGal": 1e-5},
    "sample_rate": {"Hz": 1.0},
    "base_attitude": ANGLE_UNITS,
    "reference_temperature": {"degC": 1.0},
}
#: Units of the known damping-loop parameters (see ``stableins.simulator.truth.damping_parameters``);
#: others are written with unit "SI".
DAMPING_UNITS: dict[str, str] = {
    "zeta": "1",
    "omega_s": "rad/s",
    "R": "m",
    "gravity": "m/s^2",
    "horizontal_gain": "1/s",
    "vertical_time_constant": "s",
    "k1": "1/s",
    "k2": "1/s^2",
    "k3": "1/s^3",
}
#: The order of the base-attitude angles in files.
BASE_ATTITUDE_ORDER = ("yaw", "pitch", "roll")
_REQUIRED = ("serial_number", "latitude", "height", "gravity", "gravity_source", "sample_rate")


def metadata_to_document(metadata: SiteMetadata) -> JSONObject:
    """JSON-ready document with every physical quantity as ``{"value": ..., "unit": ...}``.

    Angles are written in degrees (people read files), everything else in SI.
    """
    deg = ANGLE_UNITS["deg"]
    document: JSONObject = {
        "serial_number": metadata.serial_number,
        "latitude": {"value": metadata.latitude / deg, "unit": "deg"},
        "height": {"value": metadata.height, "unit": "m"},
        "gravity": {"value": metadata.gravity, "unit": "m/s^2"},
        "gravity_source": metadata.gravity_source,
        "sample_rate": {"value": metadata.sample_rate, "unit": "Hz"},
        "gimbal_senses": [int(s) for s in metadata.gimbal_senses],
        "base_attitude": {"value": [a / deg for a in metadata.base_attitude], "unit": "deg", "order": list(BASE_ATTITUDE_ORDER)},
        "reference_temperature": {"value": metadata.reference_temperature, "unit": "degC"},
        "damping": {k: {"value": v, "unit": DAMPING_UNITS.get(k, "SI")} for k, v in metadata.damping.items()},
        "extra": dict(metadata.extra),
        "dwell_mode": str(metadata.dwell_mode),
    }
    if metadata.start_time:
        document["start_time"] = metadata.start_time
    if metadata.gravity_uncertainty is not None:
        document["gravity_uncertainty"] = {"value": metadata.gravity_uncertainty, "unit": "m/s^2"}
    return document


class _Reader:
    """The quantities of one metadata document, read with their units; each error names the file and the key."""

    def __init__(self, document: dict[str, Any], path: str | None) -> None:
        self.document = document
        self.path = path

    def fail(self, message: str, key: str, expected: str | None = None) -> Exception:
        """Return the :class:`~stableins.errors.InputError` of ``metadata.<key>``."""
        from stableins.errors import InputError

        return InputError(message, path=self.path, field=f"metadata.{key}", expected=expected)

    def number(self, value: Any, key: str) -> float:
        """Return ``value`` as a finite float."""
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise self.fail(f"not a number: {value!r}", key, "a number")
        if value != value or value in (float("inf"), float("-inf")):
            raise self.fail(f"not finite: {value!r}", key, "a finite number")
        return float(value)

    def quantity(self, key: str, vector: int = 0) -> Any:
        """Return the ``{"value": ..., "unit": ...}`` item ``key`` in SI (a tuple of ``vector`` numbers when ``vector``)."""
        item = self.document[key]
        if not isinstance(item, dict) or "value" not in item or "unit" not in item:
            raise self.fail(f"{item!r} has no explicit unit", key, '{"value": ..., "unit": ...}')
        units = QUANTITY_UNITS[key]
        if not isinstance(item["unit"], str) or item["unit"] not in units:
            raise self.fail(f"unit {item['unit']!r} found", key, "unit " + " or ".join(repr(u) for u in units))
        factor = units[item["unit"]]
        if vector:
            value = item["value"]
            if not isinstance(value, list) or len(value) != vector:
                raise self.fail(f"{value!r} is not a list of {vector} numbers", key, f"{vector} numbers")
            return tuple(self.number(v, key) * factor for v in value)
        return self.number(item["value"], key) * factor

    def gravity(self) -> tuple[float, float | None]:
        """Return the local gravity and its standard uncertainty (None: not stated) [m/s²]."""
        gravity = self.quantity("gravity")
        if not 9.7 < gravity < 9.9:
            expected = "a value in m/s^2 between 9.7 and 9.9"
            raise self.fail(f"gravity {gravity:g} m/s^2 is not a terrestrial gravity value", "gravity", expected)
        uncertainty = self.quantity("gravity_uncertainty") if self.document.get("gravity_uncertainty") is not None else None
        if uncertainty is not None and not 0.0 <= uncertainty <= 0.05:
            expected = "a standard uncertainty from 0 to 0.05 m/s^2"
            raise self.fail(f"gravity uncertainty {uncertainty:g} m/s^2", "gravity_uncertainty", expected)
        return gravity, uncertainty

    def attitude(self) -> tuple[list[int], tuple[float, float, float]]:
        """Return the gimbal senses and the base attitude (yaw, pitch, roll) [rad]."""
        document = self.document
        senses = document.get("gimbal_senses", [1, 1, 1, 1])
        if not isinstance(senses, list) or len(senses) != 4 or any(s not in (1, -1) or isinstance(s, bool) for s in senses):
            raise self.fail(f"gimbal senses {senses!r}", "gimbal_senses", "four values, each +1 or -1")
        base_attitude = self.quantity("base_attitude", vector=3) if "base_attitude" in document else (0.0, 0.0, 0.0)
        if "base_attitude" in document and document["base_attitude"].get("order", list(BASE_ATTITUDE_ORDER)) != list(BASE_ATTITUDE_ORDER):
            order = document["base_attitude"]["order"]
            expected = f"{list(BASE_ATTITUDE_ORDER)} (the only order stableins reads)"
            raise self.fail(f"order {str(order)[:60]!r}", "base_attitude.order", expected)
        return senses, base_attitude

    def damping(self) -> dict[str, float]:
        """Return the damping-loop parameters, each in its unit of :data:`DAMPING_UNITS`."""
        damping_doc = self.document.get("damping", {})
        if not isinstance(damping_doc, dict):
            raise self.fail("damping is not an object", "damping", '{"name": {"value": ..., "unit": ...}}')
        damping = {}
        for name, item in damping_doc.items():
            if not isinstance(item, dict) or "value" not in item or "unit" not in item:
                raise self.fail(f"{item!r} has no explicit unit", f"damping.{name}", '{"value": ..., "unit": ...}')
            expected_unit = DAMPING_UNITS.get(name, "SI")
            if item["unit"] != expected_unit:
                raise self.fail(f"unit {item['unit']!r} found", f"damping.{name}", f"unit {expected_unit!r}")
            damping[name] = self.number(item["value"], f"damping.{name}")
        return damping

    def strings(self) -> tuple[str, str, str]:
        """Return the serial number, the gravity source and the start time (ISO 8601, or empty)."""
        from stableins.identifiers import check_serial_number, check_timestamp

        serial = check_serial_number(self.document["serial_number"], field="metadata.serial_number", path=self.path)
        source = self.document["gravity_source"]
        if not isinstance(source, str):
            raise self.fail(f"gravity source {source!r}", "gravity_source", "a string")
        start_time = self.document.get("start_time", "")
        check_timestamp(start_time, field="metadata.start_time", path=self.path, optional=True)
        return serial, source, str(start_time)

    def dwell_mode(self) -> DwellMode:
        """Return how the platform was held during the dwells (the default when the document does not say)."""
        value = self.document.get("dwell_mode", str(DEFAULT_DWELL_MODE))
        if not isinstance(value, str) or value not in {m.value for m in DwellMode}:
            expected = " or ".join(repr(m.value) for m in DwellMode) + ' (docs/conventions.md, "The platform during a dwell")'
            raise self.fail(f"dwell mode {str(value)[:60]!r}", "dwell_mode", expected)
        return DwellMode(value)


def metadata_from_document(document: Any, path: str | None = None) -> SiteMetadata:
    """Inverse of :func:`metadata_to_document`, validating keys, units and ranges.

    Raises
    ------
    InputError
        Naming the file and the key, and what was expected.
    """
    import math

    from stableins.errors import InputError

    if not isinstance(document, dict):
        raise InputError(
            "metadata is not a JSON object", path=path, field="metadata", expected="an object with the keys of docs/formats.md"
        )
    read = _Reader(document, path)
    missing = [k for k in _REQUIRED if k not in document]
    if missing:
        raise read.fail(f"missing metadata key(s) {missing}", missing[0], "the keys " + ", ".join(_REQUIRED))
    latitude = read.quantity("latitude")
    if abs(latitude) > math.pi / 2:
        raise read.fail(f"latitude {math.degrees(latitude):g} deg is outside ±90 deg", "latitude", "a geodetic latitude in [-90, 90] deg")
    gravity, gravity_uncertainty = read.gravity()
    sample_rate = read.quantity("sample_rate")
    if sample_rate <= 0:
        raise read.fail(f"sample rate {sample_rate:g} Hz", "sample_rate", "a positive rate in Hz")
    senses, base_attitude = read.attitude()
    reference_temperature = read.quantity("reference_temperature") if "reference_temperature" in document else 25.0
    damping = read.damping()
    extra = document.get("extra", {})
    if not isinstance(extra, dict):
        raise read.fail("extra is not an object", "extra", "a JSON object")
    serial, source, start_time = read.strings()
    return SiteMetadata(
        serial_number=serial,
        latitude=latitude,
        height=read.quantity("height"),
        gravity=gravity,
        gravity_source=source,
        sample_rate=sample_rate,
        gimbal_senses=tuple(int(s) for s in senses),  # type: ignore[arg-type]
        base_attitude=base_attitude,
        reference_temperature=reference_temperature,
        damping=damping,
        extra=extra,
        start_time=start_time,
        gravity_uncertainty=gravity_uncertainty,
        dwell_mode=read.dwell_mode(),
    )


def metadata_from_si(values: Any, source: str | None = None) -> SiteMetadata:
    """Validate :meth:`SiteMetadata.to_dict` output (SI numbers, no units: a platform's ``META`` reply, a journal).

    The values get their SI units and go through :func:`metadata_from_document`, so the same keys, types and
    ranges are checked as in a file header.

    Raises
    ------
    InputError
        Naming ``source`` and the key.
    """
    from stableins.errors import InputError

    if not isinstance(values, dict):
        raise InputError("metadata is not a JSON object", path=source, expected="an object with the keys of SiteMetadata")
    unknown = sorted(set(values) - set(SiteMetadata.__dataclass_fields__))
    if unknown:
        raise InputError(
            f"unknown metadata key(s) {unknown[:5]}", path=source, field=f"metadata.{unknown[0]}", expected="SiteMetadata fields"
        )
    document = dict(values)
    if document.get("gravity_uncertainty", 0.0) is None:
        del document["gravity_uncertainty"]
    quantities = (("latitude", "rad"), ("height", "m"), ("gravity", "m/s^2"), ("gravity_uncertainty", "m/s^2"), ("sample_rate", "Hz"))
    for key, unit in (*quantities, ("reference_temperature", "degC")):
        if key in document:
            document[key] = {"value": document[key], "unit": unit}
    if "base_attitude" in document:
        document["base_attitude"] = {"value": document["base_attitude"], "unit": "rad"}
    damping = document.get("damping", {})
    if isinstance(damping, dict):
        document["damping"] = {k: {"value": v, "unit": DAMPING_UNITS.get(k, "SI")} for k, v in damping.items()}
    return metadata_from_document(document, source)
