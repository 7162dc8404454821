"""What the device-level stages ran with: the settings of one fit and of a device calibration, frozen, writing themselves.

A record's stage run stores them (docs/formats.md, "Stage settings"); a certificate says them in words and
re-runs the stages with them (:mod:`stableins.reporting.replay`).
"""

from __future__ import annotations

from dataclasses import dataclass

from stableins.documents import DocumentFields, JSONObject
from stableins.estimators.result import Stage
from stableins.noise import NoiseModel

#: The procedures ``stableins calibrate device`` takes the positions from unless told otherwise.
DEFAULT_PROCEDURES = ("device-coarse", "device-fine")


def _noise_model(fields: DocumentFields) -> NoiseModel | None:
    """Return the noise model a settings object holds under ``noise_model`` (None: null or missing)."""
    if fields.document.get("noise_model") is None:
        return None
    return NoiseModel.from_document(fields.value("noise_model"), fields.path, f"{fields.where}.noise_model")


@dataclass(frozen=True)
class StatedSlowNoise:
    """The slow-noise model the first schema-2 records state (``settings.slow_noise``; later records: ``noise_model``).

    ``modelled`` False: the record says white noise only (``"slow_noise": null``); otherwise the bias instability
    [m/s²] and random walk [m/s²/√s] it states and their source.
    """

    modelled: bool
    bias_instability: float = 0.0
    random_walk: float = 0.0
    source: str = ""

    def to_document(self) -> JSONObject | None:
        """Return the object the record held (None: white noise only)."""
        if not self.modelled:
            return None
        return {"bias_instability": self.bias_instability, "random_walk": self.random_walk, "source": self.source}


@dataclass(frozen=True)
class DeviceFitSettings:
    """The settings of one device-level fit: the coarse stage, the fine stage or their joint fit.

    Attributes
    ----------
    stage : Stage
        Which fit (``coarse``, ``fine``, ``coarse+fine``).
    noise_model : NoiseModel or None
        The noise model under the dwell means' covariance; None: white noise measured in each dwell only.
    nonlinear : bool or None
        Whether K₂ was fitted (the coarse and joint fits; None for the fine stage, which always fits it).
    slow_noise : StatedSlowNoise or None
        The slow-noise model of a record of the first schema-2 version (then no ``noise_model``; None for every later one).
    """

    stage: Stage
    noise_model: NoiseModel | None = None
    nonlinear: bool | None = None
    slow_noise: StatedSlowNoise | None = None

    def to_document(self) -> JSONObject:
        """Return ``{"stage", "nonlinear" (coarse and joint fits), "noise_model"}`` (docs/formats.md)."""
        out: JSONObject = {"stage": self.stage.value}
        if self.slow_noise is not None:
            out["slow_noise"] = self.slow_noise.to_document()
        if self.nonlinear is not None:
            out["nonlinear"] = self.nonlinear
        if self.slow_noise is None:
            out["noise_model"] = None if self.noise_model is None else self.noise_model.to_document()
        return out

    @classmethod
    def from_document(cls, fields: DocumentFields) -> DeviceFitSettings:
        """Return the settings :meth:`to_document` wrote (:class:`~stableins.errors.InputError` naming the field)."""
        try:
            stage = Stage(fields.text("stage"))
        except ValueError:
            raise fields.fail("stage", f"{fields.text('stage')!r} is not a device-level fit", "coarse, fine or coarse+fine") from None
        nonlinear = fields.flag("nonlinear") if fields.has("nonlinear") else None
        return cls(stage, _noise_model(fields), nonlinear, _slow_noise(fields))


@dataclass(frozen=True)
class DeviceSessionSettings:
    """The settings of a device-level calibration (``stableins calibrate device``): what its record's stage run states.

    Attributes
    ----------
    coarse_procedure, fine_procedure : str or None
        The procedures the positions come from (None: the record does not say; the defaults then).
    allow_missing : bool
        Whether positions of the procedure could be missing from the data.
    coarse_nonlinear : bool
        Whether the coarse stage fitted K₂.
    noise_model : NoiseModel or None
        The noise model the stages ran with (given, or measured in the dwells).
    effects : tuple of str
        Discovered terms estimated with the standard ones.
    slow_noise : StatedSlowNoise or None
        The slow-noise model of a record of the first schema-2 version (None for every later one).
    """

    coarse_procedure: str | None = DEFAULT_PROCEDURES[0]
    fine_procedure: str | None = DEFAULT_PROCEDURES[1]
    allow_missing: bool = False
    coarse_nonlinear: bool = True
    noise_model: NoiseModel | None = None
    effects: tuple[str, ...] = ()
    slow_noise: StatedSlowNoise | None = None

    @property
    def procedures(self) -> tuple[str, str]:
        """The coarse and fine procedures, the defaults where the record does not say."""
        return (self.coarse_procedure or DEFAULT_PROCEDURES[0], self.fine_procedure or DEFAULT_PROCEDURES[1])

    def to_document(self) -> JSONObject:
        """Return the stage run's settings: procedures, missing positions, K₂, noise model, effects (docs/formats.md)."""
        out: JSONObject = {}
        if self.slow_noise is not None:
            out["slow_noise"] = self.slow_noise.to_document()
        if self.coarse_procedure is not None:
            out["coarse_procedure"] = self.coarse_procedure
        if self.fine_procedure is not None:
            out["fine_procedure"] = self.fine_procedure
        out["allow_missing"] = self.allow_missing
        out["coarse_nonlinear"] = self.coarse_nonlinear
        if self.slow_noise is None:
            out["noise_model"] = None if self.noise_model is None else self.noise_model.to_document()
        out["effects"] = list(self.effects)
        return out

    @classmethod
    def from_document(cls, fields: DocumentFields) -> DeviceSessionSettings:
        """Return the settings :meth:`to_document` wrote, or those of a first schema-2 record (``slow_noise``)."""
        return cls(
            coarse_procedure=fields.optional_text("coarse_procedure"),
            fine_procedure=fields.optional_text("fine_procedure"),
            allow_missing=fields.flag("allow_missing") if fields.has("allow_missing") else False,
            coarse_nonlinear=fields.flag("coarse_nonlinear") if fields.has("coarse_nonlinear") else True,
            noise_model=_noise_model(fields),
            effects=fields.texts("effects") if fields.has("effects") else (),
            slow_noise=_slow_noise(fields),
        )


def _slow_noise(fields: DocumentFields) -> StatedSlowNoise | None:
    """Return the slow-noise model a first schema-2 record states (None: the key is missing, a later record)."""
    if not fields.has("slow_noise"):
        return None
    if fields.document["slow_noise"] is None:
        return StatedSlowNoise(False)
    s = fields.fields("slow_noise")
    bias, walk = s.optional_number("bias_instability") or 0.0, s.optional_number("random_walk") or 0.0
    return StatedSlowNoise(True, bias, walk, s.optional_text("source") or "")
