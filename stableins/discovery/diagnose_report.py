"""What model discovery found in a set of data: a frozen, typed result and its JSON document.

:class:`DiagnoseReport` is what :func:`stableins.discovery.diagnose.diagnose_data` returns as data (and what
``stableins diagnose --json`` prints); :meth:`DiagnoseReport.from_json` reads the document back, checking every field
(:class:`~stableins.errors.InputError` naming the file and the field, e.g. ``candidates[3].p_value``), for
``stableins report --discovery`` and ``stableins check``.  ``to_json`` of ``from_json`` of a document is the document.

The document, key by key (SI units; ``null`` where a number is not finite):

* ``stage``: ``"coarse"`` or ``"fine"`` (device dwells) or ``"system"`` (the bins of a system record);
* ``noise_model``: the noise model under every σ (:meth:`stableins.noise.NoiseModel.to_document`);
* ``chi2_red``, ``dof``, ``expected_spread`` (``sqrt(2/ν)``), ``p_value``: the fit of the model in force;
* ``model``: its parameter ids; ``residual_rms``, ``noise_floor``: per output [m/s²];
* ``candidates``: every candidate effect not in the model, best first (:class:`CandidateSummary`);
* ``history``: the steps (:meth:`stableins.discovery.history.Step.to_json`);
* ``left_out``: the dwells left out, in words; ``next``: the next step in words and as a command;
* ``drift``: the platform-drift candidates ranked on the angle-reading slopes (:class:`DriftSummary`), device only;
* ``spectra``: per output, the residual at the Earth-rate harmonics (:class:`SpectrumSummary`), system only;
* system records also: ``chi2_red_range`` (the slow noise at its upper and lower limits), ``consistent``, ``alarm``,
  ``bin_seconds``, ``notes`` (:class:`SystemFindings`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from enum import StrEnum
from os import PathLike
from typing import TYPE_CHECKING, Any

from stableins.discovery.history import Step
from stableins.errors import InputError
from stableins.noise import NoiseModel

if TYPE_CHECKING:  # pragma: no cover
    from stableins.discovery.diagnostics import HarmonicSpectrum
    from stableins.discovery.ranking import Ranking

#: What the document is, for messages.
DOCUMENT = "the output of 'stableins diagnose --json'"
#: χ²_ν is consistent with the noise floor when ``P(χ² ≥ observed)`` lies strictly between these (its two-sided 99 %
#: range): the rule of :attr:`stableins.discovery.diagnostics.Diagnosis.consistent`, pinned to it by a test.
CONSISTENT_P_VALUES = (0.005, 0.995)
#: The unit of a candidate's largest predicted change of an observation (:meth:`.ranking.CandidateScore.to_json`).
OBSERVATION_UNIT = "SI unit of the observation (m/s^2 for dwell means, rad/s for reading slopes)"


class DiagnoseStage(StrEnum):
    """What the data of a diagnosis are: device dwells of one stage, or the bins of a system record."""

    COARSE = "coarse"
    FINE = "fine"
    SYSTEM = "system"


class NextAction(StrEnum):
    """What to do after a diagnosis (:attr:`DiagnoseReport.next_step`)."""

    #: Nothing is flagged: the model in force reaches the noise floor; certify the record.
    CERTIFY = "certify"
    #: Carry the best flagged effect into the device calibration (which tests it again).
    CARRY = "carry"
    #: A calibration cannot carry the best flagged effect: add it in discovery and see what it changes.
    INSPECT = "inspect"


@dataclass(frozen=True)
class NextStep:
    """The next step after a diagnosis, as data (the interface words it and builds its command).

    Attributes
    ----------
    action : NextAction
        What to do.
    effect : str or None
        The best flagged effect (None for :attr:`NextAction.CERTIFY`).
    reason : str
        :attr:`NextAction.INSPECT`: why a calibration does not carry the effect.
    confused_with : tuple of str
        :attr:`NextAction.CARRY`: candidates the data cannot tell from the effect.
    keep : tuple of str
        :attr:`NextAction.CARRY`: the discovered effects of the model in force, which stay in it.
    """

    action: NextAction
    effect: str | None = None
    reason: str = ""
    confused_with: tuple[str, ...] = ()
    keep: tuple[str, ...] = ()


# ----------------------------------------------------------------------------- reading the document
def _join(where: str, key: str | int) -> str:
    if isinstance(key, int):
        return f"{where}[{key}]"
    return f"{where}.{key}" if where else key


class _Reader:
    """Field checks of one document: each returns the value with its type or raises InputError naming the field."""

    def __init__(self, path: str | PathLike[str] | None) -> None:
        self.path = path

    def fail(self, message: str, where: str, expected: str) -> InputError:
        return InputError(message, path=self.path, field=where or None, expected=expected)

    def mapping(self, value: Any, where: str, expected: str = "a JSON object") -> Mapping[str, Any]:
        if not isinstance(value, Mapping):
            raise self.fail(f"{value!r:.60} is not an object", where, expected)
        return value

    def get(self, item: Mapping[str, Any], key: str, where: str) -> Any:
        if key not in item:
            raise self.fail("missing", _join(where, key), f"the key {key!r} ({DOCUMENT})")
        return item[key]

    def text(self, value: Any, where: str) -> str:
        from stableins.data.jsonio import expect_text

        return expect_text(value, self.path, where)

    def boolean(self, value: Any, where: str) -> bool:
        if not isinstance(value, bool):
            raise self.fail(f"{value!r:.60} is not true or false", where, "a boolean")
        return value

    def number(self, value: Any, where: str, *, nullable: bool = True, minimum: float | None = None) -> float:
        """Return a finite number (kept an int when written as one), or NaN for null when ``nullable``."""
        from stableins.data.jsonio import expect_number

        if value is None and nullable:
            return math.nan
        expected = "a finite number" + (" or null" if nullable else "") + ("" if minimum is None else f" >= {minimum:g}")
        expect_number(value, self.path, where, minimum=minimum, expected=expected)
        return value if isinstance(value, int) else float(value)

    def integer(self, value: Any, where: str) -> int:
        if isinstance(value, bool) or not isinstance(value, int) or value < 0:
            raise self.fail(f"{value!r:.60} is not a non-negative integer", where, "a non-negative integer")
        return value

    def items(self, value: Any, where: str, read: Callable[[Any, str], Any]) -> tuple[Any, ...]:
        from stableins.data.jsonio import expect_list

        return tuple(read(item, _join(where, k)) for k, item in enumerate(expect_list(value, self.path, where)))

    def texts(self, value: Any, where: str) -> tuple[str, ...]:
        return self.items(value, where, self.text)

    def numbers(self, value: Any, where: str, *, nullable: bool = True, minimum: float | None = None) -> tuple[float, ...]:
        return self.items(value, where, lambda v, w: self.number(v, w, nullable=nullable, minimum=minimum))

    def step(self, value: Any, where: str) -> Step:
        """Return a history step (:meth:`.history.Step.from_json`, its ``ValueError`` as InputError naming the field)."""
        item = self.mapping(value, where)
        if item.get("residual_rms_unit", "m/s^2") != "m/s^2":
            raise self.fail(f"{item['residual_rms_unit']!r:.60}", _join(where, "residual_rms_unit"), "'m/s^2'")
        try:
            return Step.from_json(item, where)
        except ValueError as error:
            field, _, expected = str(error).partition(": ")
            raise self.fail("malformed", field, expected.removeprefix("expected ")) from None


def _finite(x: float) -> float | None:
    return x if math.isfinite(x) else None


# ----------------------------------------------------------------------------- parts of the document
@dataclass(frozen=True)
class CandidateSummary:
    """One candidate effect's standing against the model in force (:class:`.ranking.CandidateScore` as data).

    Attributes
    ----------
    id : str
        Candidate id.
    statistic, p_value, delta_bic : float
        ΔRSS in χ² units, the F-test p-value and the BIC change on adding the effect (negative favours it).
    estimate, sigma : float
        The effect's estimate and 1σ, in ``unit`` (its engineering unit).
    unit : str
        Engineering unit of ``estimate`` and ``sigma``.
    max_output_change : float
        Largest change of an observation the estimated effect causes, in ``max_output_change_unit``.
    max_output_change_unit : str
        The SI unit of the observation.
    identifiable, excited : bool
        Whether the data separate the effect from the model, and excite it at all.
    separability : float
        ``‖z⊥‖/‖z‖``.
    aliases : tuple of (str, float)
        Model parameters the effect goes into when left out, with the shift per unit effect.
    confused_with : tuple of str
        Candidates these data cannot tell from this one.
    refit : bool
        Whether the numbers come from a full refit.
    flagged : bool
        Whether the effect is flagged at the family-wise false-alarm level.
    advice : str
        What would separate or confirm it.
    """

    id: str
    statistic: float
    p_value: float
    delta_bic: float
    estimate: float
    sigma: float
    unit: str
    max_output_change: float
    max_output_change_unit: str
    identifiable: bool
    excited: bool
    separability: float
    aliases: tuple[tuple[str, float], ...]
    confused_with: tuple[str, ...]
    refit: bool
    flagged: bool
    advice: str

    @classmethod
    def from_ranking(cls, ranking: Ranking) -> tuple[CandidateSummary, ...]:
        """Every candidate of a ranking, best first, as written by :meth:`.ranking.Ranking.to_json` (the one JSON form)."""
        return tuple(cls.from_json(item, where=f"candidates[{k}]") for k, item in enumerate(ranking.to_json()))

    def to_json(self) -> dict[str, Any]:
        """Return the candidate as :meth:`.ranking.CandidateScore.to_json` writes it."""
        return {
            "id": self.id,
            "statistic": _finite(self.statistic),
            "p_value": _finite(self.p_value),
            "delta_bic": _finite(self.delta_bic),
            "predicted": {
                "estimate": _finite(self.estimate),
                "sigma": _finite(self.sigma),
                "unit": self.unit,
                "max_output_change": _finite(self.max_output_change),
                "max_output_change_unit": self.max_output_change_unit,
            },
            "identifiable": self.identifiable,
            "excited": self.excited,
            "separability": _finite(self.separability),
            "aliases": [{"id": pid, "shift_per_unit": _finite(c)} for pid, c in self.aliases],
            "confused_with": list(self.confused_with),
            "refit": self.refit,
            "flagged": self.flagged,
            "advice": self.advice,
        }

    @classmethod
    def from_json(cls, document: Any, path: str | PathLike[str] | None = None, *, where: str = "candidate") -> CandidateSummary:
        """Read a candidate written by :meth:`to_json` (InputError naming the field otherwise)."""
        r = _Reader(path)
        item = r.mapping(document, where)
        predicted = r.mapping(r.get(item, "predicted", where), _join(where, "predicted"))
        at = _join(where, "predicted")

        def alias(value: Any, place: str) -> tuple[str, float]:
            entry = r.mapping(value, place)
            shift = r.number(r.get(entry, "shift_per_unit", place), _join(place, "shift_per_unit"))
            return r.text(r.get(entry, "id", place), _join(place, "id")), shift

        def number(key: str) -> float:
            return r.number(r.get(item, key, where), _join(where, key))

        def flag(key: str) -> bool:
            return r.boolean(r.get(item, key, where), _join(where, key))

        return cls(
            id=r.text(r.get(item, "id", where), _join(where, "id")),
            statistic=number("statistic"),
            p_value=number("p_value"),
            delta_bic=number("delta_bic"),
            estimate=r.number(r.get(predicted, "estimate", at), _join(at, "estimate")),
            sigma=r.number(r.get(predicted, "sigma", at), _join(at, "sigma")),
            unit=r.text(r.get(predicted, "unit", at), _join(at, "unit")),
            max_output_change=r.number(r.get(predicted, "max_output_change", at), _join(at, "max_output_change")),
            max_output_change_unit=r.text(r.get(predicted, "max_output_change_unit", at), _join(at, "max_output_change_unit")),
            identifiable=flag("identifiable"),
            excited=flag("excited"),
            separability=number("separability"),
            aliases=r.items(r.get(item, "aliases", where), _join(where, "aliases"), alias),
            confused_with=r.texts(r.get(item, "confused_with", where), _join(where, "confused_with")),
            refit=flag("refit"),
            flagged=flag("flagged"),
            advice=r.text(r.get(item, "advice", where), _join(where, "advice")),
        )


@dataclass(frozen=True)
class DriftSummary:
    """The platform-drift candidates ``Dg_*`` ranked on the angle-reading slopes within dwells (:mod:`.drift`).

    Attributes
    ----------
    chi2_red : float
        ``χ²_ν`` of the slopes under the model without drift.
    dof : int
        Its degrees of freedom.
    candidates : tuple of CandidateSummary
        The drift candidates, best first.
    left_out : tuple of str
        Dwells left out of the drift analysis, and why.
    """

    chi2_red: float
    dof: int
    candidates: tuple[CandidateSummary, ...]
    left_out: tuple[str, ...] = ()

    def to_json(self) -> dict[str, Any]:
        """Return the ``drift`` section of the document."""
        return {
            "chi2_red": _finite(self.chi2_red),
            "dof": self.dof,
            "candidates": [c.to_json() for c in self.candidates],
            "left_out": list(self.left_out),
        }

    @classmethod
    def from_json(cls, document: Any, path: str | PathLike[str] | None = None, *, where: str = "drift") -> DriftSummary:
        """Read the section written by :meth:`to_json` (InputError naming the field otherwise)."""
        r = _Reader(path)
        item = r.mapping(document, where)
        candidates = r.items(
            r.get(item, "candidates", where), _join(where, "candidates"), lambda v, w: CandidateSummary.from_json(v, path, where=w)
        )
        return cls(
            chi2_red=r.number(r.get(item, "chi2_red", where), _join(where, "chi2_red")),
            dof=r.integer(r.get(item, "dof", where), _join(where, "dof")),
            candidates=candidates,
            left_out=r.texts(r.get(item, "left_out", where), _join(where, "left_out")),
        )


@dataclass(frozen=True)
class SpectrumSummary:
    """One output's residual at the Earth-rate harmonics (:class:`.diagnostics.HarmonicSpectrum` as data).

    Attributes
    ----------
    output : str
        The output (``f_x``, ``f_y``, ``f_z``).
    harmonics : tuple of int
        Harmonic numbers of the Earth rate.
    amplitude, sigma : tuple of float
        Residual amplitude at each harmonic and its 1σ, in ``unit``.
    chi2, p_value : tuple of float
        Test statistic of each harmonic and its p-value.
    dof : tuple of float or None
        Degrees of freedom of each test (None: 2 each).
    flagged : tuple of bool
        Whether each harmonic is significant at the family-wise level.
    unit : str
        Unit of the amplitudes.
    """

    output: str
    harmonics: tuple[int, ...]
    amplitude: tuple[float, ...]
    sigma: tuple[float, ...]
    chi2: tuple[float, ...]
    dof: tuple[float, ...] | None
    p_value: tuple[float, ...]
    flagged: tuple[bool, ...]
    unit: str = "m/s^2"

    def __post_init__(self) -> None:
        n = len(self.harmonics)
        lengths = [len(self.amplitude), len(self.sigma), len(self.chi2), len(self.p_value), len(self.flagged)]
        if self.dof is not None:
            lengths.append(len(self.dof))
        if any(m != n for m in lengths):
            raise ValueError(f"SpectrumSummary {self.output}: every list needs one entry per harmonic ({n})")

    @classmethod
    def from_spectrum(cls, output: str, spectrum: HarmonicSpectrum, flagged: Sequence[bool]) -> SpectrumSummary:
        """Summarize the spectrum of one output, with the flag of each harmonic."""
        return cls(
            output=output,
            harmonics=tuple(spectrum.harmonics.tolist()),
            amplitude=tuple(spectrum.amplitude.tolist()),
            sigma=tuple(spectrum.sigma.tolist()),
            chi2=tuple(spectrum.chi2.tolist()),
            dof=None if spectrum.dof is None else tuple(spectrum.dof.tolist()),
            p_value=tuple(spectrum.p_value.tolist()),
            flagged=tuple(bool(f) for f in flagged),
        )

    def to_json(self) -> dict[str, Any]:
        """Return the output's entry of the document's ``spectra``."""
        return {
            "harmonics": list(self.harmonics),
            "amplitude": [_finite(x) for x in self.amplitude],
            "sigma": [_finite(x) for x in self.sigma],
            "chi2": [_finite(x) for x in self.chi2],
            "dof": None if self.dof is None else [_finite(x) for x in self.dof],
            "p_value": [_finite(x) for x in self.p_value],
            "flagged": list(self.flagged),
            "unit": self.unit,
        }

    @classmethod
    def from_json(cls, output: str, document: Any, path: str | PathLike[str] | None = None) -> SpectrumSummary:
        """Read the entry of ``output`` written by :meth:`to_json` (InputError naming the field otherwise)."""
        r = _Reader(path)
        where = f"spectra.{output}"
        item = r.mapping(document, where)

        def numbers(key: str) -> tuple[float, ...]:
            return r.numbers(r.get(item, key, where), _join(where, key))

        dof = None if r.get(item, "dof", where) is None else numbers("dof")
        harmonics = r.items(r.get(item, "harmonics", where), _join(where, "harmonics"), r.integer)
        values = {key: numbers(key) for key in ("amplitude", "sigma", "chi2", "p_value")}
        flagged = r.items(r.get(item, "flagged", where), _join(where, "flagged"), r.boolean)
        lists = {**values, "flagged": flagged} | ({} if dof is None else {"dof": dof})
        for key, entries in lists.items():
            if len(entries) != len(harmonics):
                raise r.fail(f"{len(entries)} entries for {len(harmonics)} harmonics", _join(where, key), "one entry per harmonic")
        unit = r.text(r.get(item, "unit", where), _join(where, "unit"))
        return cls(output, harmonics, dof=dof, flagged=flagged, unit=unit, **values)


@dataclass(frozen=True)
class SystemFindings:
    """What only the diagnosis of a system record carries (:class:`.system.SystemDiagnosis` as data).

    Attributes
    ----------
    chi2_red_range : (float, float)
        ``χ²_ν`` with the slow noise at its upper and at its lower limits.
    bin_seconds : float
        Width of the bins [s].
    notes : tuple of str
        What the noise measurement and the binning said.
    """

    chi2_red_range: tuple[float, float]
    bin_seconds: float
    notes: tuple[str, ...] = ()


# ----------------------------------------------------------------------------- the document
@dataclass(frozen=True)
class DiagnoseReport:
    """What model discovery found in a set of data, against the calibration record in force.

    Attributes
    ----------
    stage : DiagnoseStage
        The data: device dwells of one stage, or the bins of a system record.
    noise_model : NoiseModel or None
        The noise model under every σ, χ² and flag.
    chi2_red, dof, expected_spread, p_value : float, int, float, float
        ``χ²_ν`` of the model (with the effects added), its degrees of freedom, ``sqrt(2/ν)`` and ``P(χ² ≥ observed)``
        (for a system record: the verdict over every noise model the data allow).
    model : tuple of str
        Parameter ids of the model.
    residual_rms, noise_floor : tuple of float
        Residual RMS and RMS of the measured 1σ per output [m/s²].
    candidates : tuple of CandidateSummary
        Every candidate effect not in the model, best first.
    history : tuple of Step
        The model at each step: the model in force, then one step per effect added.
    left_out : tuple of str
        Dwells left out (flagged by the dwell checks), in words.
    drift : DriftSummary or None
        Device dwells: the platform-drift candidates (None: too few usable angle-reading slopes, or a system record).
    spectra : tuple of SpectrumSummary
        System records: each output's residual at the Earth-rate harmonics.
    system : SystemFindings or None
        System records: the range of ``χ²_ν`` over the allowed noise models, the bins, the notes.
    next : tuple of str
        The next step in words and as a command, as the interface words :attr:`next_step` (``stableins diagnose``
        fills it; empty from :func:`stableins.discovery.diagnose.diagnose_data`).
    """

    stage: DiagnoseStage
    noise_model: NoiseModel | None
    chi2_red: float
    dof: int
    expected_spread: float
    p_value: float
    model: tuple[str, ...]
    residual_rms: tuple[float, ...]
    noise_floor: tuple[float, ...]
    candidates: tuple[CandidateSummary, ...]
    history: tuple[Step, ...]
    left_out: tuple[str, ...] = ()
    drift: DriftSummary | None = None
    spectra: tuple[SpectrumSummary, ...] = ()
    system: SystemFindings | None = None
    next: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if (self.stage is DiagnoseStage.SYSTEM) != (self.system is not None):
            raise ValueError("DiagnoseReport: the system findings go with stage 'system', and only with it")
        if not self.history:
            raise ValueError("DiagnoseReport: the history starts with the model in force")

    # ------------------------------------------------------------------ verdict
    @property
    def consistent(self) -> bool:
        """Whether ``χ²_ν`` lies within its two-sided 99 % range (:data:`CONSISTENT_P_VALUES`)."""
        low, high = CONSISTENT_P_VALUES
        return low < self.p_value < high

    @property
    def flagged(self) -> tuple[CandidateSummary, ...]:
        """The flagged candidates, best first."""
        return tuple(c for c in self.candidates if c.flagged)

    @property
    def alarm(self) -> bool:
        """Whether anything says the model misses something: the verdict, a flagged candidate or a flagged harmonic."""
        return (not self.consistent) or bool(self.flagged) or any(any(s.flagged) for s in self.spectra)

    @property
    def next_step(self) -> NextStep:
        """What to do next, as data.

        Carry the best flagged effect into the calibration; look at one a calibration cannot carry (or any, for a system
        record: the system stage does not estimate added effects); or certify the record when nothing is flagged.
        """
        from stableins.discovery.library import LIBRARY, calibration_limit

        if not self.flagged:
            return NextStep(NextAction.CERTIFY)
        best = self.flagged[0]
        why = calibration_limit(best.id)
        if why is not None:
            return NextStep(NextAction.INSPECT, best.id, reason=f"a calibration cannot carry it: {why}")
        if self.stage is DiagnoseStage.SYSTEM:
            return NextStep(NextAction.INSPECT, best.id, reason="the system stage does not estimate added effects")
        keep = tuple(i for i in self.history[0].model_ids if i in LIBRARY)  # the discovered effects of the model in force
        return NextStep(NextAction.CARRY, best.id, confused_with=best.confused_with, keep=keep)

    # ------------------------------------------------------------------ the document
    def to_json(self) -> dict[str, Any]:
        """Return the document of ``stableins diagnose --json`` (module docstring), JSON-ready."""
        system = self.system
        out: dict[str, Any] = {
            "stage": str(self.stage),
            "noise_model": None if self.noise_model is None else self.noise_model.to_document(),
            "chi2_red": _finite(self.chi2_red),
        }
        if system is not None:
            out["chi2_red_range"] = [_finite(x) for x in system.chi2_red_range]
        out |= {"dof": self.dof, "expected_spread": _finite(self.expected_spread), "p_value": _finite(self.p_value)}
        if system is not None:
            out |= {"consistent": self.consistent, "alarm": self.alarm, "bin_seconds": system.bin_seconds}
        out |= {
            "model": list(self.model),
            "residual_rms": list(self.residual_rms),
            "noise_floor": list(self.noise_floor),
            "candidates": [c.to_json() for c in self.candidates],
            "history": [s.to_json() for s in self.history],
            "left_out": list(self.left_out),
            "next": list(self.next),
            "drift": None if self.drift is None else self.drift.to_json(),
        }
        if system is not None:
            out["notes"] = list(system.notes)
        out["spectra"] = {s.output: s.to_json() for s in self.spectra}
        return out

    @classmethod
    def from_json(cls, document: Any, path: str | PathLike[str] | None = None) -> DiagnoseReport:
        """Read the document written by :meth:`to_json`; :class:`~stableins.errors.InputError` names the field otherwise."""
        r = _Reader(path)
        d = r.mapping(document, "", DOCUMENT)
        try:
            stage = DiagnoseStage(r.text(r.get(d, "stage", ""), "stage"))
        except ValueError:
            raise r.fail(f"{d['stage']!r:.60} is not a stage", "stage", " or ".join(repr(str(s)) for s in DiagnoseStage)) from None
        history = r.items(r.get(d, "history", ""), "history", r.step)
        if not history:
            raise r.fail("no steps", "history", "the model in force as the first step")
        noise, drift = r.get(d, "noise_model", ""), r.get(d, "drift", "")
        spectra = r.mapping(r.get(d, "spectra", ""), "spectra")
        report = cls(
            stage=stage,
            noise_model=None if noise is None else NoiseModel.from_document(noise, None if path is None else str(path)),
            chi2_red=r.number(r.get(d, "chi2_red", ""), "chi2_red"),
            dof=r.integer(r.get(d, "dof", ""), "dof"),
            expected_spread=r.number(r.get(d, "expected_spread", ""), "expected_spread"),
            p_value=r.number(r.get(d, "p_value", ""), "p_value"),
            model=r.texts(r.get(d, "model", ""), "model"),
            residual_rms=r.numbers(r.get(d, "residual_rms", ""), "residual_rms", nullable=False, minimum=0.0),
            noise_floor=r.numbers(r.get(d, "noise_floor", ""), "noise_floor", nullable=False, minimum=0.0),
            candidates=r.items(r.get(d, "candidates", ""), "candidates", lambda v, w: CandidateSummary.from_json(v, path, where=w)),
            history=history,
            left_out=r.texts(r.get(d, "left_out", ""), "left_out"),
            drift=None if drift is None else DriftSummary.from_json(drift, path),
            spectra=tuple(SpectrumSummary.from_json(name, item, path) for name, item in spectra.items()),
            system=_system_findings(r, d) if stage is DiagnoseStage.SYSTEM else None,
            next=r.texts(r.get(d, "next", ""), "next"),
        )
        if stage is DiagnoseStage.SYSTEM:  # written from the p-value and the flags: they must agree
            for key, derived in (("consistent", report.consistent), ("alarm", report.alarm)):
                if r.boolean(r.get(d, key, ""), key) != derived:
                    raise r.fail(f"{d[key]} contradicts the p-value and the flags of the document", key, str(derived).lower())
        return report


def _system_findings(r: _Reader, d: Mapping[str, Any]) -> SystemFindings:
    """Read the keys only a system record's document has."""
    span = r.numbers(r.get(d, "chi2_red_range", ""), "chi2_red_range")
    if len(span) != 2:
        raise r.fail(f"{len(span)} numbers", "chi2_red_range", "two numbers: χ²_ν at the upper and at the lower limits")
    from stableins.data.jsonio import expect_number

    bins = r.get(d, "bin_seconds", "")
    expect_number(bins, r.path, "bin_seconds", positive=True, expected="a positive number of seconds")
    return SystemFindings(chi2_red_range=(span[0], span[1]), bin_seconds=bins, notes=r.texts(r.get(d, "notes", ""), "notes"))
