"""The parts of a diagnosis document as data: candidates, drift, Earth-rate spectra, and the checks that read them.

Each part has ``to_json`` (the form :class:`stableins.discovery.diagnose_report.DiagnoseReport` writes) and
``from_json``, which checks every field (:class:`~stableins.errors.InputError` naming the file and the field).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from os import PathLike
from typing import TYPE_CHECKING, Any, TypedDict

from stableins.discovery.fields import Reader, finite, join

if TYPE_CHECKING:  # pragma: no cover
    from stableins.discovery.harmonics import HarmonicSpectrum
    from stableins.discovery.ranking import Ranking

#: The unit of a candidate's largest predicted change of an observation (:meth:`stableins.discovery.ranking.CandidateScore.to_json`).
OBSERVATION_UNIT = "SI unit of the observation (m/s^2 for dwell means, rad/s for reading slopes)"


# ----------------------------------------------------------------------------- parts of the document
class PredictedDocument(TypedDict):
    """What adding a candidate predicts: its estimate and 1σ in its unit, and the largest change of the outputs."""

    estimate: float | None
    sigma: float | None
    unit: str
    max_output_change: float | None
    max_output_change_unit: str


class AliasDocument(TypedDict):
    """A parameter a candidate aliases with: the shift of its estimate per unit of the candidate."""

    id: str
    shift_per_unit: float | None


class CandidateDocument(TypedDict):
    """A ranked candidate in a diagnosis (:meth:`CandidateSummary.to_json`); NaN written as null."""

    id: str
    statistic: float | None
    p_value: float | None
    delta_bic: float | None
    predicted: PredictedDocument
    identifiable: bool
    excited: bool
    separability: float | None
    aliases: list[AliasDocument]
    confused_with: list[str]
    refit: bool
    flagged: bool
    chi2_red_with: float | None
    explains: bool
    leaves: list[str]
    signature_p: float | None
    advice: str


class DriftEstimateDocument(TypedDict):
    """An estimated drift term (:meth:`DriftEstimate.to_json`)."""

    id: str
    value: float | None
    sigma: float | None
    unit: str


class DriftDocument(TypedDict):
    """The ``drift`` section of a diagnosis (:meth:`DriftSummary.to_json`)."""

    chi2_red: float | None
    dof: int
    candidates: list[CandidateDocument]
    left_out: list[str]
    model: list[DriftEstimateDocument]


class SpectrumDocument(TypedDict):
    """One output's entry of a diagnosis's ``spectra`` (:meth:`SpectrumSummary.to_json`)."""

    harmonics: list[int]
    amplitude: list[float | None]
    sigma: list[float | None]
    chi2: list[float | None]
    dof: list[float | None] | None
    p_value: list[float | None]
    flagged: list[bool]
    unit: str


@dataclass(frozen=True)
class CandidateSummary:
    """One candidate effect's standing against the model in force (:class:`stableins.discovery.ranking.CandidateScore` as data).

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
        Whether the effect is named: significant at the family-wise false-alarm level and explaining the residual.
    advice : str
        What would separate or confirm it.
    chi2_red_with : float
        ``χ²_ν`` with the effect added (NaN when not identifiable).
    explains : bool
        Whether it alone explains the residual: adding it brings ``χ²_ν`` into its 95 % band
        (:func:`stableins.discovery.scores.explains`) and leaves no other candidate significant.
    leaves : tuple of str
        The candidates still significant once it is added.
    signature_p : float
        p-value of the residual with it added along directions fixed in the laboratory (NaN: not tested).
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
    chi2_red_with: float = math.nan
    explains: bool = False
    leaves: tuple[str, ...] = ()
    signature_p: float = math.nan

    @classmethod
    def from_ranking(cls, ranking: Ranking) -> tuple[CandidateSummary, ...]:
        """Every candidate of a ranking, best first, as :meth:`stableins.discovery.ranking.Ranking.to_json` writes them."""
        return tuple(cls.from_json(item, where=f"candidates[{k}]") for k, item in enumerate(ranking.to_json()))

    def to_json(self) -> CandidateDocument:
        """Return the candidate as :meth:`stableins.discovery.ranking.CandidateScore.to_json` writes it."""
        return {
            "id": self.id,
            "statistic": finite(self.statistic),
            "p_value": finite(self.p_value),
            "delta_bic": finite(self.delta_bic),
            "predicted": {
                "estimate": finite(self.estimate),
                "sigma": finite(self.sigma),
                "unit": self.unit,
                "max_output_change": finite(self.max_output_change),
                "max_output_change_unit": self.max_output_change_unit,
            },
            "identifiable": self.identifiable,
            "excited": self.excited,
            "separability": finite(self.separability),
            "aliases": [{"id": pid, "shift_per_unit": finite(c)} for pid, c in self.aliases],
            "confused_with": list(self.confused_with),
            "refit": self.refit,
            "flagged": self.flagged,
            "chi2_red_with": finite(self.chi2_red_with),
            "explains": self.explains,
            "leaves": list(self.leaves),
            "signature_p": finite(self.signature_p),
            "advice": self.advice,
        }

    @classmethod
    def from_json(cls, document: Any, path: str | PathLike[str] | None = None, *, where: str = "candidate") -> CandidateSummary:
        """Read a candidate written by :meth:`to_json` (InputError naming the field otherwise)."""
        r = Reader(path)
        item = r.mapping(document, where)
        predicted = r.mapping(r.get(item, "predicted", where), join(where, "predicted"))
        at = join(where, "predicted")

        def alias(value: Any, place: str) -> tuple[str, float]:
            entry = r.mapping(value, place)
            shift = r.number(r.get(entry, "shift_per_unit", place), join(place, "shift_per_unit"))
            return r.text(r.get(entry, "id", place), join(place, "id")), shift

        def number(key: str) -> float:
            return r.number(r.get(item, key, where), join(where, key))

        def flag(key: str) -> bool:
            return r.boolean(r.get(item, key, where), join(where, key))

        return cls(
            id=r.text(r.get(item, "id", where), join(where, "id")),
            statistic=number("statistic"),
            p_value=number("p_value"),
            delta_bic=number("delta_bic"),
            estimate=r.number(r.get(predicted, "estimate", at), join(at, "estimate")),
            sigma=r.number(r.get(predicted, "sigma", at), join(at, "sigma")),
            unit=r.text(r.get(predicted, "unit", at), join(at, "unit")),
            max_output_change=r.number(r.get(predicted, "max_output_change", at), join(at, "max_output_change")),
            max_output_change_unit=r.text(r.get(predicted, "max_output_change_unit", at), join(at, "max_output_change_unit")),
            identifiable=flag("identifiable"),
            excited=flag("excited"),
            separability=number("separability"),
            aliases=r.items(r.get(item, "aliases", where), join(where, "aliases"), alias),
            confused_with=r.texts(r.get(item, "confused_with", where), join(where, "confused_with")),
            refit=flag("refit"),
            flagged=flag("flagged"),
            advice=r.text(r.get(item, "advice", where), join(where, "advice")),
            # documents written before these keys existed read as they were meant: a flagged candidate explained
            chi2_red_with=r.number(item.get("chi2_red_with"), join(where, "chi2_red_with")),
            explains=r.boolean(item.get("explains", flag("flagged")), join(where, "explains")),
            leaves=r.texts(item.get("leaves", []), join(where, "leaves")),
            signature_p=r.number(item.get("signature_p"), join(where, "signature_p")),
        )


@dataclass(frozen=True)
class DriftSummary:
    """The platform-drift candidates ``Dg_*`` ranked on the angle-reading slopes within dwells (:mod:`stableins.discovery.drift`).

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
    model : tuple of DriftEstimate
        The drift model's gyro numbers fitted to the slopes: ``gyro_drift_x/y/z`` (°/h) and each ``Dg_ab`` added
        (°/h/g), with 1σ.
    """

    chi2_red: float
    dof: int
    candidates: tuple[CandidateSummary, ...]
    left_out: tuple[str, ...] = ()
    model: tuple[DriftEstimate, ...] = ()

    def to_json(self) -> DriftDocument:
        """Return the ``drift`` section of the document."""
        return {
            "chi2_red": finite(self.chi2_red),
            "dof": self.dof,
            "candidates": [c.to_json() for c in self.candidates],
            "left_out": list(self.left_out),
            "model": [m.to_json() for m in self.model],
        }

    @classmethod
    def from_json(cls, document: Any, path: str | PathLike[str] | None = None, *, where: str = "drift") -> DriftSummary:
        """Read the section written by :meth:`to_json` (InputError naming the field otherwise)."""
        r = Reader(path)
        item = r.mapping(document, where)
        candidates = r.items(
            r.get(item, "candidates", where), join(where, "candidates"), lambda v, w: CandidateSummary.from_json(v, path, where=w)
        )
        return cls(
            chi2_red=r.number(r.get(item, "chi2_red", where), join(where, "chi2_red")),
            dof=r.integer(r.get(item, "dof", where), join(where, "dof")),
            candidates=candidates,
            left_out=r.texts(r.get(item, "left_out", where), join(where, "left_out")),
            model=r.items(item.get("model", []), join(where, "model"), lambda v, w: DriftEstimate.from_json(v, path, where=w)),
        )


@dataclass(frozen=True)
class DriftEstimate:
    """One gyro number of the drift model fitted to the reading slopes, in its engineering unit.

    Attributes
    ----------
    id : str
        ``gyro_drift_a`` or ``Dg_ab``.
    value, sigma : float
        Estimate and 1σ in ``unit``.
    unit : str
        ``°/h`` or ``°/h/g``.
    """

    id: str
    value: float
    sigma: float
    unit: str

    @classmethod
    def from_fit(cls, fit: Any) -> tuple[DriftEstimate, ...]:
        """Return the gyro numbers of a drift-model fit (its terms of kind GYRO_DRIFT and GYRO_G_SENSITIVITY)."""
        from stableins.errormodel import TermKind

        kinds = (TermKind.GYRO_DRIFT, TermKind.GYRO_G_SENSITIVITY)
        return tuple(
            cls(t.id, float(v) / t.scale, float(s) / t.scale, "°/h" if t.kind is TermKind.GYRO_DRIFT else "°/h/g")
            for t, v, s in zip(fit.terms, fit.values, fit.sigma, strict=True)
            if t.kind in kinds
        )

    def to_json(self) -> DriftEstimateDocument:
        """Return the JSON form."""
        return {"id": self.id, "value": finite(self.value), "sigma": finite(self.sigma), "unit": self.unit}

    @classmethod
    def from_json(cls, document: Any, path: str | PathLike[str] | None = None, *, where: str = "model") -> DriftEstimate:
        """Read the form written by :meth:`to_json` (InputError naming the field otherwise)."""
        r = Reader(path)
        item = r.mapping(document, where)
        return cls(
            id=r.text(r.get(item, "id", where), join(where, "id")),
            value=r.number(r.get(item, "value", where), join(where, "value")),
            sigma=r.number(r.get(item, "sigma", where), join(where, "sigma")),
            unit=r.text(r.get(item, "unit", where), join(where, "unit")),
        )


@dataclass(frozen=True)
class SpectrumSummary:
    """One output's residual at the Earth-rate harmonics (:class:`stableins.discovery.diagnostics.HarmonicSpectrum` as data).

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

    def to_json(self) -> SpectrumDocument:
        """Return the output's entry of the document's ``spectra``."""
        return {
            "harmonics": list(self.harmonics),
            "amplitude": [finite(x) for x in self.amplitude],
            "sigma": [finite(x) for x in self.sigma],
            "chi2": [finite(x) for x in self.chi2],
            "dof": None if self.dof is None else [finite(x) for x in self.dof],
            "p_value": [finite(x) for x in self.p_value],
            "flagged": list(self.flagged),
            "unit": self.unit,
        }

    @classmethod
    def from_json(cls, output: str, document: Any, path: str | PathLike[str] | None = None) -> SpectrumSummary:
        """Read the entry of ``output`` written by :meth:`to_json` (InputError naming the field otherwise)."""
        r = Reader(path)
        where = f"spectra.{output}"
        item = r.mapping(document, where)

        def numbers(key: str) -> tuple[float, ...]:
            return r.numbers(r.get(item, key, where), join(where, key))

        dof = None if r.get(item, "dof", where) is None else numbers("dof")
        harmonics = r.items(r.get(item, "harmonics", where), join(where, "harmonics"), r.integer)
        values = {key: numbers(key) for key in ("amplitude", "sigma", "chi2", "p_value")}
        flagged = r.items(r.get(item, "flagged", where), join(where, "flagged"), r.boolean)
        lists = {**values, "flagged": flagged} | ({} if dof is None else {"dof": dof})
        for key, entries in lists.items():
            if len(entries) != len(harmonics):
                raise r.fail(f"{len(entries)} entries for {len(harmonics)} harmonics", join(where, key), "one entry per harmonic")
        unit = r.text(r.get(item, "unit", where), join(where, "unit"))
        return cls(output, harmonics, dof=dof, flagged=flagged, unit=unit, **values)
