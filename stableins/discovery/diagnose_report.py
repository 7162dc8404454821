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
* ``history``: the steps (:meth:`stableins.discovery.steps.ModelStep.to_json`);
* ``left_out``: the dwells left out, in words; ``next``: the next step in words and as a command;
* ``drift``: the platform-drift candidates ranked on the angle-reading slopes (:class:`DriftSummary`), device only;
* ``spectra``: per output, the residual at the Earth-rate harmonics (:class:`SpectrumSummary`), system only;
* ``verdict``: where ``χ²`` lies against its two-sided 99 % range (:class:`~stableins.discovery.diagnostics.FitVerdict`:
  ``consistent``, ``above the noise floor`` — something is missing —, ``below the noise floor``);
* ``outside_library``: χ² rejects the model and no candidate explains it; ``signature``: then, which outputs, positions
  and harmonics carry the residual (:class:`~stableins.discovery.signature.ResidualSignature`), else null;
* system records also: ``chi2_red_range`` and ``p_value_range`` (the slow noise at its upper and lower limits; the
  verdict holds for every model between), ``consistent``, ``alarm``, ``bin_seconds``, ``notes`` (:class:`SystemFindings`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from enum import StrEnum
from os import PathLike
from typing import Any

from stableins.discovery.diagnostics import FitVerdict
from stableins.discovery.fields import DOCUMENT, Reader, finite
from stableins.discovery.scores import not_named_because
from stableins.discovery.signature import ResidualSignature
from stableins.discovery.steps import ModelStep
from stableins.discovery.summaries import (
    OBSERVATION_UNIT,
    CandidateSummary,
    DriftEstimate,
    DriftSummary,
    SpectrumSummary,
)
from stableins.errors import InputError, NotDeterminedError
from stableins.noise import NoiseModel

__all__ = [
    "DOCUMENT",
    "OBSERVATION_UNIT",
    "CandidateSummary",
    "DiagnoseReport",
    "DiagnoseStage",
    "DriftEstimate",
    "DriftSummary",
    "NextAction",
    "NextStep",
    "SpectrumSummary",
    "SystemFindings",
]


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
    #: χ² rejects the model and no library effect explains it: look at the residual's signature; no certificate.
    OUTSIDE = "outside the library"


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
        :attr:`NextAction.INSPECT`: why a calibration does not carry the effect; :attr:`NextAction.OUTSIDE`: why the
        residual is outside the library; :attr:`NextAction.CERTIFY`: a residual below the noise floor, said.
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


@dataclass(frozen=True)
class SystemFindings:
    """What only the diagnosis of a system record carries (:class:`stableins.discovery.system.SystemDiagnosis` as data).

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
    history : tuple of ModelStep
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
    signature : ResidualSignature or None
        When the residual is outside the library (:attr:`outside_library`): which outputs, positions and harmonics
        carry it; else None.
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
    history: tuple[ModelStep, ...]
    left_out: tuple[str, ...] = ()
    drift: DriftSummary | None = None
    spectra: tuple[SpectrumSummary, ...] = ()
    system: SystemFindings | None = None
    next: tuple[str, ...] = ()
    signature: ResidualSignature | None = None

    def __post_init__(self) -> None:
        if (self.stage is DiagnoseStage.SYSTEM) != (self.system is not None):
            raise ValueError("DiagnoseReport: the system findings go with stage 'system', and only with it")
        if not self.history:
            raise ValueError("DiagnoseReport: the history starts with the model in force")

    # ------------------------------------------------------------------ verdict
    @property
    def p_value_range(self) -> tuple[float, float]:
        """``P(χ² ≥ observed)`` with the slow noise at its upper and at its lower limits (system records; else ``p_value`` twice)."""
        if self.system is None or self.dof <= 0:
            return (self.p_value, self.p_value)
        from scipy.stats import chi2

        hi, lo = self.system.chi2_red_range
        return (float(chi2.sf(hi * self.dof, self.dof)), float(chi2.sf(lo * self.dof, self.dof)))

    @property
    def verdict(self) -> FitVerdict:
        """Where ``χ²`` lies against its two-sided 99 % range for every noise model allowed (:class:`FitVerdict`)."""
        span = self.p_value_range
        return FitVerdict.of(max(span), min(span))

    @property
    def consistent(self) -> bool:
        """Whether ``χ²_ν`` lies within its two-sided 99 % range (:data:`stableins.discovery.diagnostics.CONSISTENT_P_VALUES`)."""
        return self.verdict is FitVerdict.CONSISTENT

    @property
    def outside_library(self) -> bool:
        """χ² rejects the model (too high) and no candidate explains it (none flagged): the effect is outside the library."""
        return self.verdict is FitVerdict.ABOVE and not self.flagged

    def outside_text(self) -> str:
        """Why the residual is outside the library, in words: ``χ²_ν`` and P the verdict rests on, and the best candidate's ``χ²_ν``.

        For a system record: with the slow noise at its upper limits (the first of ``chi2_red_range``, ``p_value_range``).
        """
        chi2_red = self.chi2_red if self.system is None else self.system.chi2_red_range[0]
        p = max(self.p_value_range)
        head = f"χ²_ν = {chi2_red:.3g} (ν = {self.dof}, P = {p:.2g}) and no library effect explains it"
        best = next((c for c in self.candidates if c.identifiable), None)
        if best is None:
            return head
        return f"{head} (the best, {best.id}, {not_named_because(best.chi2_red_with, best.leaves, best.signature_p)})"

    @property
    def flagged(self) -> tuple[CandidateSummary, ...]:
        """The flagged candidates, best first."""
        return tuple(c for c in self.candidates if c.flagged)

    @property
    def alarm(self) -> bool:
        """Whether anything says the model misses something: the verdict, a flagged candidate or a flagged harmonic."""
        too_high = self.verdict is FitVerdict.ABOVE  # a χ² below the range says the σ are conservative, not that anything is missing
        return too_high or bool(self.flagged) or any(any(s.flagged) for s in self.spectra)

    @property
    def next_step(self) -> NextStep:
        """What to do next, as data.

        Carry the best flagged effect into the calibration; look at one a calibration cannot carry (or any, for a system
        record: the system stage does not estimate added effects); say that the residual is outside the library when χ²
        rejects the model and no candidate explains it (a candidate is flagged only if it does,
        :func:`stableins.discovery.scores.explains`); or certify the record when nothing is flagged and χ² is not too high.
        """
        from stableins.discovery.library import LIBRARY, calibration_limit

        if not self.flagged:
            if self.outside_library:
                return NextStep(NextAction.OUTSIDE, reason=self.outside_text())
            if self.verdict is FitVerdict.BELOW:
                return NextStep(NextAction.CERTIFY, reason="the residuals are below the noise floor (its σ are conservative)")
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
            "chi2_red": finite(self.chi2_red),
        }
        if system is not None:
            out["chi2_red_range"] = [finite(x) for x in system.chi2_red_range]
        out |= {"dof": self.dof, "expected_spread": finite(self.expected_spread), "p_value": finite(self.p_value)}
        if system is not None:
            out["p_value_range"] = [finite(x) for x in self.p_value_range]
            out |= {"consistent": self.consistent, "alarm": self.alarm, "bin_seconds": system.bin_seconds}
        out |= {
            "verdict": str(self.verdict),
            "outside_library": self.outside_library,
            "signature": None if self.signature is None else self.signature.to_json(),
        }
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
        r = Reader(path)
        d = r.mapping(document, "", DOCUMENT)
        try:
            stage = DiagnoseStage(r.text(r.get(d, "stage", ""), "stage"))
        except (InputError, NotDeterminedError):
            raise  # a described error passes through as it is (issue 29)
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
            signature=None if d.get("signature") is None else ResidualSignature.from_json(d["signature"], path),
        )
        derived_keys: list[tuple[str, Any]] = []
        if stage is DiagnoseStage.SYSTEM:  # written from the p-values and the flags: they must agree
            derived_keys += [("consistent", report.consistent), ("alarm", report.alarm)]
        derived_keys += [("outside_library", report.outside_library)] if "outside_library" in d else []
        for key, derived in derived_keys:
            if r.boolean(r.get(d, key, ""), key) != derived:
                raise r.fail(f"{d[key]} contradicts the p-value and the flags of the document", key, str(derived).lower())
        if "verdict" in d and r.text(d["verdict"], "verdict") != str(report.verdict):
            raise r.fail(f"{d['verdict']!r:.60} contradicts the p-value of the document", "verdict", repr(str(report.verdict)))
        return report


def _system_findings(r: Reader, d: Mapping[str, Any]) -> SystemFindings:
    """Read the keys only a system record's document has."""
    span = r.numbers(r.get(d, "chi2_red_range", ""), "chi2_red_range")
    if len(span) != 2:
        raise r.fail(f"{len(span)} numbers", "chi2_red_range", "two numbers: χ²_ν at the upper and at the lower limits")
    from stableins.data.jsonio import expect_number

    bins = r.get(d, "bin_seconds", "")
    expect_number(bins, r.path, "bin_seconds", positive=True, expected="a positive number of seconds")
    return SystemFindings(chi2_red_range=(span[0], span[1]), bin_seconds=bins, notes=r.texts(r.get(d, "notes", ""), "notes"))
