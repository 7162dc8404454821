r"""Model discovery on a system-level record under the instrument's noise model.

A system-level record is a day of static data; over a day the accelerometers' slow noise (bias instability, random
walk) wanders by several times the white floor of a bin, and it is correlated from bin to bin, so a white floor makes
any slow wander look like a missing effect (a drift, a harmonic).  Here everything rests on the noise model the system
stage measures in the same record (:func:`stableins.estimators.system.stage.run_system_stage`, its
:attr:`~stableins.estimators.system.stage.SystemCalibration.noise_model`): white noise per axis from the second
differences of the raw outputs (free of the Earth-rate signal, which first differences are not: +14 % on x and y at
1 Hz), bias instability and random walk from the residual spectra with their confidence intervals, and the record's own
noise model (datasheet, earlier measurement) as the stage uses it.  The bins (:func:`.problem.bins_from_chunks`) get the
model's covariance: ``N²/T`` per bin and axis plus the slow noise correlated between bins; the fit is generalized least
squares (:class:`.problem.DwellProblem`).

One day cannot pin the slow noise: its amplitudes are known only within their intervals.  A statement that something
is missing must hold for every noise model the data allow (the supremum p-value over a confidence set of the nuisance
parameters, Berger & Boos 1994), so

* ``χ²_ν`` is shown under the measured model; the verdict "something is missing" needs ``χ²`` too high even with the
  slow terms at their upper limits, "the floor is too high" needs it too low even at their lower limits;
* candidates are ranked and flagged (:mod:`.ranking`, Bonferroni over the candidates) and the Earth-rate harmonics of the
  residuals are tested (:func:`.diagnostics.harmonic_tests`) against the slow terms at their upper limits: what is
  flagged is needed by the data under the largest slow noise they allow.

docs/discovery.md "System records".
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from stableins.conventions import MICRO_G
from stableins.discovery.diagnostics import Diagnosis
from stableins.discovery.dwells import DwellSet
from stableins.discovery.harmonics import HarmonicSpectrum
from stableins.discovery.history import Discovery
from stableins.discovery.ranking import Ranking
from stableins.errormodel import ErrorModel
from stableins.estimators.result import Stage
from stableins.noise import NoiseModel

if TYPE_CHECKING:  # pragma: no cover
    from stableins.estimators.system.stage import SystemNoise

#: At most this many bins enter the generalized least squares (each axis' covariance is ``(P, P)``): records longer than
#: ``MAX_BINS`` bins of the requested width get wider bins.  The platform turns by ``ω_ie T`` within a bin; averaging
#: shrinks the turning components of ``f^p`` by ``1 − (ω_ie T)²/24`` in every bin alike, which the scale factors absorb.
MAX_BINS = 2048


@dataclass(frozen=True)
class SystemDiagnosis:
    """What discovery finds in a system-level record, and under which noise models.

    Attributes
    ----------
    noise_model : NoiseModel
        The instrument's noise model measured in the record by the system stage (or given), under ``diagnosis``.
    upper_model, lower_model : NoiseModel
        The same with the slow terms (bias instability, random walk) at their upper and lower limits.
    diagnosis : Diagnosis
        Residuals against the floor under ``noise_model``, with ``P(χ² ≥ observed)`` under it (a continuous function of
        the χ²_ν printed beside it) and its range over the allowed models (``p_range``: the upper model's, the lower
        model's), on which the verdict rests (see the module docstring).
    chi2_range : (float, float)
        ``χ²_ν`` with the slow terms at their upper and at their lower limits.
    ranking : Ranking
        Every library candidate, ranked and flagged against ``upper_model``.
    spectra : dict
        Earth-rate harmonic tests of each output's residual against ``upper_model``.
    session : Discovery
        The discovery session under ``noise_model`` (its history, for ``--add``).
    bin_seconds : float
        Width of the bins used.
    notes : tuple of str
    """

    noise_model: NoiseModel
    upper_model: NoiseModel
    lower_model: NoiseModel
    diagnosis: Diagnosis
    chi2_range: tuple[float, float]
    ranking: Ranking
    spectra: dict[str, HarmonicSpectrum]
    session: Discovery
    bin_seconds: float
    notes: tuple[str, ...] = ()

    @property
    def flagged_harmonics(self) -> tuple[tuple[str, int, float], ...]:
        """``(output, harmonic, p)`` of the harmonics significant at the family-wise level (Bonferroni over those tested)."""
        tested = [
            (name, int(k), float(p))
            for name, sp in self.spectra.items()
            for k, p, d in zip(sp.harmonics, sp.p_value, _dof(sp), strict=True)
            if d > 0
        ]
        level = self.ranking.alpha / max(len(tested), 1)
        return tuple(t for t in tested if t[2] < level)

    @property
    def alarm(self) -> bool:
        """Anything that says the model is missing something: the verdict, a flagged candidate or a flagged harmonic."""
        from stableins.discovery.diagnostics import FitVerdict

        too_high = self.diagnosis.fit_verdict is FitVerdict.ABOVE
        return too_high or bool(self.ranking.flagged) or bool(self.flagged_harmonics)

    def report(self, top: int = 10) -> str:
        """Return the noise model, the diagnosis with its verdict, the ranking and the harmonic tests."""
        hi, lo = self.chi2_range
        given = self.upper_model == self.noise_model and self.lower_model == self.noise_model
        span = (
            "χ²_ν under the one noise model: its slow terms are given without an interval"
            if given
            else f"χ²_ν over the noise models the record allows: {hi:.3f} (slow terms at their upper limits) to {lo:.3f} "
            "(lower limits); the verdict holds for all of them"
        )
        lines = [
            self.noise_model.describe(),
            f"bins of {self.bin_seconds:g} s; white floor N²/T per bin and axis, slow noise correlated between bins "
            "(generalized least squares)",
            self.diagnosis.report(),
            span,
        ]
        parts = ["\n".join(lines + list(self.notes))]
        against = (
            "ranked against the noise model"
            if given
            else "ranked against the largest slow noise the record allows (a candidate is flagged only if every noise model the "
            "data allow needs it)"
        )
        parts.append(against + ":\n" + self.ranking.report(top=top))
        flagged = {(name, k) for name, k, _ in self.flagged_harmonics}
        for name, spectrum in self.spectra.items():
            marks = ", ".join(f"harmonic {k}" for n, k in sorted(flagged) if n == name)
            head = f"residual of {name} at the Earth-rate harmonics" + ("" if given else " (against the upper-limit noise model)")
            parts.append(head + (f"; significant: {marks}" if marks else "") + ":\n" + spectrum.report(unit="µg", scale=MICRO_G))
        return "\n\n".join(parts)


def _dof(spectrum: HarmonicSpectrum) -> np.ndarray:
    return np.full(spectrum.harmonics.size, 2.0) if spectrum.dof is None else spectrum.dof


def measure_noise(
    record: Any,
    calibration: Mapping[str, float],
    covariance: Mapping[tuple[str, str], float] | None,
    prior: NoiseModel | None,
    compensation_terms: Sequence[Any] = (),
) -> SystemNoise:
    """Return the noise of the instrument in a system-level record, exactly as the system stage measures it.

    :func:`stableins.estimators.system.stage.measure_noise_model` on the record (the installed ``calibration``, the
    ``prior`` noise model as the stage uses it): the model, the record's duration [s] and the stage's note.
    """
    import warnings

    from stableins.estimators.system.stage import measure_noise_model

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the stage's warnings are about its calibration, not about the noise
        return measure_noise_model(
            record, record.metadata, calibration, covariance, compensation_terms=compensation_terms, noise_model=prior
        )


def diagnose_system_record(
    record: Any,
    model: ErrorModel,
    start: Mapping[str, float],
    noise: SystemNoise,
    *,
    bin_seconds: float = 60.0,
    alpha: float = 0.05,
    add: Sequence[str] = (),
) -> SystemDiagnosis:
    """Bin a system-level record and run discovery under the measured noise model and its limits (module docstring).

    ``record``: a :class:`stableins.data.system.SystemRecord` (``metadata``, ``iter_chunks``); ``start`` the parameter
    values to start from (the calibration record's); ``noise`` the instrument's noise in the record (:func:`measure_noise`:
    its model, the record's duration, which bounds the number of bins, and the notes carried into the diagnosis);
    ``add`` effects added one step at a time before ranking.
    """
    from stableins.conventions import GimbalConfiguration
    from stableins.discovery.harmonics import residual_spectra
    from stableins.discovery.linear import bins_from_chunks
    from stableins.discovery.problem import DwellProblem

    site = record.metadata
    noise_model, duration = noise.noise_model, noise.duration
    width = float(bin_seconds)
    extra = list(noise.notes)
    if duration is not None and duration / width > MAX_BINS:
        width = math.ceil(duration / MAX_BINS)
        extra.append(f"bins widened from {bin_seconds:g} s to {width:g} s (at most {MAX_BINS} bins under the correlated noise)")
    bounded = noise_model.slow_noise_bounded
    upper = noise_model.at_upper_limits() if bounded else noise_model
    lower = noise_model.with_values(
        bias_instability=noise_model.limits("bias_instability")[0], random_walk=noise_model.limits("random_walk")[0]
    )
    if not bounded:
        extra.append(
            "the slow noise is not bounded by the data: flags are against the measured model only, and slow wander may look like drift"
        )

    binned = bins_from_chunks(
        record.iter_chunks(),
        gravity=site.gravity,
        bin_seconds=width,
        reference_temperature=site.reference_temperature,
        base_attitude=tuple(site.base_attitude),
        configuration=GimbalConfiguration(tuple(site.gimbal_senses)),
    )

    def session(noise: NoiseModel) -> Discovery:
        s = Discovery(DwellProblem(with_noise(binned, noise), stage=Stage.SYSTEM_BINS, static=False), model, alpha=alpha, start=start)
        for effect in add:
            s.add(effect)
        return s

    main = session(noise_model)
    sessions = {"measured": main}
    for name, other in (("upper", upper), ("lower", lower)):
        sessions[name] = main if other == noise_model else session(other)
    diagnosis = main.diagnose()
    chi2_hi, chi2_lo = sessions["upper"].result.chi2_red, sessions["lower"].result.chi2_red
    nu = main.result.dof
    from scipy.stats import chi2 as chi2_dist

    # the verdict over the allowed models: too high needs even the upper model's P below the limit, too low the lower
    # model's above it (Diagnosis.fit_verdict); P printed is the measured model's, the one of the χ²_ν printed
    p_hi = float(chi2_dist.sf(chi2_hi * nu, nu))
    p_lo = float(chi2_dist.sf(chi2_lo * nu, nu))
    diagnosis = replace(diagnosis, p_range=(p_hi, p_lo))
    ranking = sessions["upper"].rank(refit_top=1, propose=False)
    spectra = residual_spectra(binned.time, sessions["upper"].diagnose(), problem=sessions["upper"].problem)
    return SystemDiagnosis(
        noise_model=noise_model,
        upper_model=upper,
        lower_model=lower,
        diagnosis=diagnosis,
        chi2_range=(float(chi2_hi), float(chi2_lo)),
        ranking=ranking,
        spectra=spectra,
        session=main,
        bin_seconds=width,
        notes=tuple(extra),
    )


def with_noise(dwells: DwellSet, noise: NoiseModel) -> DwellSet:
    """Return the bins of a system record under ``noise``: white ``N_a²/T`` per bin and axis, slow noise correlated between bins.

    ``dwells`` from :func:`.problem.bins_from_chunks` (its ``noise["lengths"]`` are the bins' durations).  The slow
    covariance is :meth:`stableins.noise.NoiseModel.slow_covariance` of the bins' windows, per axis.
    """
    lengths = np.asarray(dwells.noise["lengths"], dtype=float)
    sigma = noise.values("white")[None, :] / np.sqrt(lengths)[:, None]
    slow = None
    if noise.has_slow_noise:
        slow = noise.slow_covariance(dwells.time - lengths / 2.0, lengths)
    info = dict(
        dwells.noise,
        method=f"the instrument's noise model: white N²/T per bin and axis, slow noise correlated between bins; "
        f"{float(np.median(lengths)):g} s bins",
        white_noise=noise.values("white"),
        slow_noise=noise.describe(),
        model=noise,
    )
    return replace(dwells, sigma=sigma, slow_covariance=slow, noise=info)
