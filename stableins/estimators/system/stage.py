r"""The system-level stage over a whole record, streaming in bounded memory.

One pass over the record (chunks of ``chunk_rows`` samples):

* specific force: raw outputs compensated with the installed calibration (Wu et al.
  2018 Eq. 8, :meth:`stableins.errormodel.ErrorModel.inverse` in closed form; discovered
  additive terms of the prior, when it has any, through :class:`_AdditiveCompensation`), the
  squared-amplitude observation ``z`` and its harmonic information ``Σ HᵀH``, ``Σ Hᵀz``
  (:mod:`.harmonics`) accumulated at full rate.  The Earth-rate angle moves by
  ``ω_ie/rate`` per sample, so within a block of ``B`` samples (``B/rate·ω_ie ≤ 2e-4``)
  ``cos k(S_c + δ)`` is expanded to third order in ``δ``: the trigonometric functions are
  evaluated once per block and the per-sample work is a few multiply-adds.  The
  truncation (``(4δ)⁴/24 < 1e-15``) is far below double-precision round-off of the sums;
  :func:`harmonic_information` is the per-sample reference it is tested against;
* noise: per-axis variance from second differences of the raw outputs on the first
  samples of each chunk (insensitive to the Earth-rate signal);
* attitude, velocity and time at a decimated rate (``attitude_decimation_seconds``):
  block means of pitch and roll (:class:`.attitude.AttitudeBlocks`), the static-base
  checks and the platform-rate check;
* Kalman-filter bins: ``Σz``, ``ΣH`` over ``filter_block_seconds`` for the convergence
  curves of filterpy's filter (decimated, ``R/n`` per bin).

Then the harmonic states (x1..x5 of the paper plus the third harmonic x6, x7 that measures a
residual K2), the loop-compensated attitude coefficients and their separation into
accelerometer corrections (:mod:`.separation`).  On a turned or tilted base the Earth-rate
angle comes from the full gimbal kinematics; a known gyro drift's response is removed from
pitch and roll.  Checks: sampling (gaps, jitter, order), static base (velocity, attitude
excursion), platform turning at the Earth rate, polar alignment, record length (short records
keep only the combinations they determine).  See docs/system-calibration.md.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from stableins.conventions import EARTH_RATE, MICRO_G, SIDEREAL_DAY, GimbalConfiguration, dcm_body_to_platform, dcm_nav_to_body
from stableins.data.errors import InputError
from stableins.data.metadata import SiteMetadata
from stableins.data.validation import check_finite
from stableins.errormodel import CORE_TERMS, MICRO_G_PER_G2, ErrorModel, Term, TermKind
from stableins.estimators.result import CombinedDetails, FitResult, Likelihood, SystemDetails
from stableins.estimators.system import harmonics as hm
from stableins.estimators.system.attitude import ATTITUDE_COEFFICIENTS, AttitudeBlocks, AttitudeFit, fit_attitude
from stableins.estimators.system.blocksums import block_sums, coefficients, harmonic_sums, second_difference_sums
from stableins.estimators.system.loop import DampingLoop
from stableins.estimators.system.separation import COMBINED_COEFFICIENTS, Separation, separate
from stableins.estimators.system.spectrum import ColouredNoiseFit, ColouredSource
from stableins.noise import AxisNoise, NoiseModel, NoiseSource, NoiseTerm
from stableins.status import Determination, Status

#: Read at the full rate: the accelerometer outputs carry the information, the time stamps the sampling checks
#: (HDF5 records with a /time_grid: time only at the attitude decimation, the rest reconstructed).
FAST_COLUMNS = ("time", "f_x", "f_y", "f_z")
#: Checked for NaN/inf by the stage's own pass (a non-finite force makes Σz² non-finite), not by the reader.
FORCE_COLUMNS = ("f_x", "f_y", "f_z")
#: Read at the attitude decimation only (slowly varying outputs; docs/system-calibration.md §6).
SLOW_COLUMNS = ("angle_platform", "pitch", "roll", "velocity_north", "velocity_east")

#: Steps of the sequential Kalman filter's convergence curve at most (filter bins merged beyond 3.5 days).
FILTER_STEPS = 512

#: Base pitch/roll [rad] above which the base counts as tilted (φ is then taken from the full output DCM).
LEVEL_TOLERANCE = 1e-4

#: Variance-inflation factor above which a coefficient counts as not observable in a short record.
VIF_LIMIT = 30.0


class ChunkSource(Protocol):
    """What the stage reads: ``iter_chunks(columns, rows)`` yielding ``{column: ndarray}``.

    A source may also offer ``time_grid`` (uniform segments of the time column, ``(n, 3)`` rows first_row,
    first_time, period) and ``grid_time(start, stop)``, as :class:`stableins.data.system.SystemRecord` does for
    HDF5 files: the stage then reads the time stamps at the attitude decimation only.
    """

    path: str

    def iter_chunks(
        self,
        columns: Sequence[str] | None = None,
        rows: int = ...,
        *,
        thin: Sequence[str] = (),
        step: int = 1,
        reuse: bool = False,
        unchecked: Sequence[str] = (),
    ) -> Iterator[dict[str, Any]]: ...


@dataclass(frozen=True)
class ArraySource:
    """In-memory columns as a :class:`ChunkSource` (tests, small records).  Checks NaN/inf."""

    columns: Mapping[str, NDArray[np.float64]]
    path: str = "<arrays>"

    def iter_chunks(
        self,
        columns: Sequence[str] | None = None,
        rows: int = 1 << 16,
        *,
        thin: Sequence[str] = (),
        step: int = 1,
        reuse: bool = False,
        unchecked: Sequence[str] = (),
    ) -> Iterator[dict[str, Any]]:
        """Same contract as :meth:`stableins.data.system.SystemRecord.iter_chunks` (``reuse``, ``unchecked`` have no effect)."""
        names = list(self.columns if columns is None else columns)
        for name in names:
            if name not in self.columns:
                raise InputError("missing column", path=self.path, field=name, expected="the system-record columns")
        n = len(self.columns[names[0]])
        for start in range(0, n, rows):
            phase = (-start) % step
            chunk = {}
            for name in names:
                values = np.asarray(self.columns[name][start : start + rows], dtype=float)
                if name in thin:
                    values = values[phase::step]
                    check_finite(name, values, self.path, first_row=start + phase + 1, row_step=step)
                else:
                    check_finite(name, values, self.path, first_row=start + 1)
                chunk[name] = values
            yield chunk


class GyroDrift(StrEnum):
    """What the system stage does about a constant gyro drift (:attr:`SystemOptions.gyro_drift`)."""

    #: Leave it out of the attitude fit (a known drift, :attr:`SystemOptions.known_gyro_drift`, is still removed).
    IGNORE = "ignore"
    #: Fit its response as a nuisance (σ of the fundamentals ×10).
    FIT = "fit"
    #: Fit it only to warn when it is significant.
    CHECK = "check"


_POSITIVE_INTS = ("chunk_rows", "noise_samples_per_chunk")
_POSITIVE_FLOATS = (
    "attitude_decimation_seconds",
    "attitude_block_seconds",
    "filter_block_seconds",
    "velocity_limit",
    "attitude_limit",
    "rate_tolerance",
    "polar_tolerance",
)
_FLAGS = ("couplings", "compensate_loop", "run_filter", "estimate_k2")


def _option_error(name: str, value: object, expected: str) -> InputError:
    return InputError(f"system-stage option {name} = {value!r} is not valid", field=name, expected=expected)


def _is_number(value: object) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


@dataclass(frozen=True)
class SystemOptions:
    """Settings of the system stage (defaults follow docs/system-calibration.md).

    Validated at construction: a value of the wrong type or out of range, or an unknown ``gyro_drift``, raises
    :class:`~stableins.data.errors.InputError` naming the option and what it expects.
    """

    chunk_rows: int = 1 << 18
    attitude_decimation_seconds: float = 1.0
    attitude_block_seconds: float = 10.0
    filter_block_seconds: float = 600.0
    case_rotation_period: float | None = 480.0
    couplings: bool = True
    compensate_loop: bool = True
    velocity_limit: float = 5.0  # [m/s] beyond this the base is not static (3e-3 m/s² gives ~2.5 m/s of Schuler transient)
    attitude_limit: float = 5e-3  # [rad] excursion of pitch/roll around their mean beyond which the base is not static
    rate_tolerance: float = 2e-3  # relative deviation of the platform-angle rate from the Earth rate
    polar_tolerance: float = 1e-3  # [rad] angle between z_p and the Earth's axis (from the mean f_z/|f|)
    minimum_duration: float = 4 * 3600.0  # [s]
    noise_samples_per_chunk: int = 1 << 15  # second differences per chunk: N to 0.6 % from one day at 1 Hz
    run_filter: bool = True
    gyro_drift: GyroDrift = GyroDrift.IGNORE  # see GyroDrift
    known_gyro_drift: tuple[float, float, float] | None = None  # [rad/s] in the platform frame, response removed
    gyro_drift_uncertainty: float | None = None  # [rad/s] standard uncertainty per axis of the drift (given or assumed zero)
    estimate_k2: bool = False  # remove residual K2_x, K2_y (from the third harmonic) and update them in the record
    noise_false_positive_rate: float = 0.05  # of the decision "the residuals carry low-frequency noise" (docs §1a)

    def __post_init__(self) -> None:
        for name in _POSITIVE_INTS:
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise _option_error(name, value, "a positive integer")
        for name in _POSITIVE_FLOATS:
            if not _is_number(getattr(self, name)) or getattr(self, name) <= 0:
                raise _option_error(name, getattr(self, name), "a positive finite number")
        if not _is_number(self.minimum_duration) or self.minimum_duration < 0:
            raise _option_error("minimum_duration", self.minimum_duration, "a finite number of seconds ≥ 0")
        if self.case_rotation_period is not None and (not _is_number(self.case_rotation_period) or self.case_rotation_period <= 0):
            raise _option_error("case_rotation_period", self.case_rotation_period, "a positive number of seconds, or None")
        for name in _FLAGS:
            if not isinstance(getattr(self, name), bool):
                raise _option_error(name, getattr(self, name), "True or False")
        try:
            object.__setattr__(self, "gyro_drift", GyroDrift(self.gyro_drift))
        except ValueError:
            raise _option_error("gyro_drift", self.gyro_drift, "one of " + ", ".join(repr(g.value) for g in GyroDrift)) from None
        drift = self.known_gyro_drift
        if drift is not None and (not isinstance(drift, tuple | list) or len(drift) != 3 or not all(_is_number(v) for v in drift)):
            raise _option_error("known_gyro_drift", drift, "three finite numbers [rad/s] (platform x, y, z), or None")
        if self.gyro_drift_uncertainty is not None and (not _is_number(self.gyro_drift_uncertainty) or self.gyro_drift_uncertainty < 0):
            raise _option_error("gyro_drift_uncertainty", self.gyro_drift_uncertainty, "a finite number [rad/s] ≥ 0, or None")
        if not _is_number(self.noise_false_positive_rate) or not 0 < self.noise_false_positive_rate < 1:
            raise _option_error("noise_false_positive_rate", self.noise_false_positive_rate, "a probability between 0 and 1")


class _SystemCalibrationView:
    """How a :class:`SystemCalibration` shows itself (:mod:`stableins.display`): repr, HTML, DataFrame."""

    result: FitResult
    combined: FitResult
    separation: Separation
    corrections: dict[str, float]
    notes: tuple[str, ...]
    diagnostics: dict[str, Any]

    def _summary_lines(self) -> list[str]:
        d = self.diagnostics
        hours = float(d.get("duration", math.nan)) / 3600.0
        sep = self.separation
        return [
            f"{hours:.2f} h record, {int(d.get('samples', 0))} samples; "
            f"separation χ²_ν = {sep.chi2 / max(sep.dof, 1):.2f} (ν = {sep.dof}); "
            f"the data determine {self.result.rank} of {len(self.result.terms)} directions of the accelerometer terms"
        ]

    def _rows(self) -> list[tuple[str, float, float, str, Status, str, str]]:
        """``(id, updated value, 1σ, unit, status, correction, determination)`` in engineering units."""
        how = self.result.details.determination if isinstance(self.result.details, SystemDetails) else {}
        rows = []
        for (pid, value, sigma, unit, status), term in zip(self.result.rows(), self.result.terms, strict=True):
            correction = self.corrections.get(pid)
            shown = "—" if correction is None else f"{float(term.sigma_to_engineering(correction)):+.4g}"
            rows.append((pid, value, sigma, unit, status, shown, str(how.get(pid) or "not seen")))
        return rows

    def __repr__(self) -> str:
        from stableins.display import clipped, parameter_lines, plural

        lines = [f"<SystemCalibration: the system stage's update of {len(self.result.terms)} accelerometer terms>", *self._summary_lines()]
        lines += parameter_lines(r[:5] for r in self._rows())
        lines.append("combined coefficients [µrad]: " + ", ".join(f"{i} {v:+.2f}" for i, v, *_ in self.combined.rows()[:5]) + " …")
        more = f"{plural(len(self.notes), 'note')}; " if self.notes else ""
        return clipped(lines, f"({more}print(calibration.result) for the report, calibration.to_dataframe() for the table)")

    def _repr_html_(self) -> str:
        from stableins.display import html_result, html_table, unit_text, value_sigma

        rows = [
            [pid, value_sigma(v, s if st == Status.ESTIMATED else math.nan), correction, unit_text(u), str(st), how]
            for pid, v, s, u, st, correction, how in self._rows()
        ]
        parameters = html_table(
            ["parameter", "updated value ± 1σ", "correction", "unit", "status", "these data determine it"],
            rows,
            numeric=(1, 2),
            titles=[t.meaning for t in self.result.terms],
            status_column=4,
        )
        combined = html_table(
            ["combined coefficient", "value ± 1σ", "unit"],
            [[i, value_sigma(v, s), unit_text(u)] for i, v, s, u, _ in self.combined.rows()],
            numeric=(1,),
            titles=[t.meaning for t in self.combined.terms],
        )
        return html_result("System-level stage", self._summary_lines(), [parameters, combined], [("notes", self.notes)])

    def to_dataframe(self) -> Any:
        """The updated accelerometer terms (:meth:`FitResult.to_dataframe`) with ``correction`` (engineering units) and
        ``determination`` (``alone``, ``in combination`` or ``not seen`` by these data).  Needs pandas."""
        frame = self.result.to_dataframe()
        terms = {t.id: t for t in self.result.terms}
        frame["correction"] = [
            float(terms[i].sigma_to_engineering(self.corrections[i])) if i in self.corrections else math.nan for i in frame.index
        ]
        how = self.result.details.determination if isinstance(self.result.details, SystemDetails) else {}
        frame["determination"] = [str(how.get(i) or "not seen") for i in frame.index]
        return frame


@dataclass(frozen=True, repr=False)
class SystemCalibration(_SystemCalibrationView):
    """Everything the system stage found.

    Attributes
    ----------
    result : FitResult
        Stage ``"system"`` over the accelerometer terms of the prior: updated values
        (prior + correction), covariance of the updated values, status
        (``estimated`` when a parameter is determined by itself, ``gauge`` when only
        combinations are, ``fixed`` for terms this stage does not touch).
    combined : FitResult
        The fifteen combined coefficients (``x1..x5``, pitch and roll) [rad].
    separation : Separation
        The weighted least-squares separation (residual space).
    attitude : AttitudeFit
        The Fourier fit of pitch and roll.
    history : hm.FilterHistory or None
        Kalman-filter convergence on the decimated bins (``history_time`` gives the bin ends).
    coloured_noise : ColouredNoiseFit or None
        The low-frequency noise of the accelerometers found in the residuals: decision, amplitudes, intervals
        (None when the record is too short for the model).
    noise_model : NoiseModel
        The instrument's noise model under every σ of this stage, per axis (:func:`_measured_noise_model`): white noise
        from second differences, bias instability and random walk from the residual spectra, with intervals; the given
        model when a datasheet model was given.  It goes into the calibration record.
    """

    result: FitResult
    combined: FitResult
    separation: Separation
    attitude: AttitudeFit
    history: hm.FilterHistory | None
    history_time: NDArray[np.float64]
    corrections: dict[str, float]
    notes: tuple[str, ...] = ()
    diagnostics: dict[str, Any] = field(default_factory=dict)
    coloured_noise: ColouredNoiseFit | None = None
    noise_model: NoiseModel | None = None


@dataclass(frozen=True)
class SystemNoise:
    """The instrument's noise in a system-level record, as the stage measures it (:func:`measure_noise_model`).

    Attributes
    ----------
    noise_model : NoiseModel
        The model under the stage's σ (:attr:`SystemCalibration.noise_model`).
    coloured_noise : ColouredNoiseFit or None
        The decision and the amplitudes (None when the record is too short for the model).
    duration : float
        Length of the record [s].
    notes : tuple of str
        What the decision found (the stage's note).
    """

    noise_model: NoiseModel
    coloured_noise: ColouredNoiseFit | None
    duration: float
    notes: tuple[str, ...] = ()


def measure_noise_model(
    source: ChunkSource,
    metadata: SiteMetadata,
    prior: Mapping[str, float],
    prior_covariance: Mapping[tuple[str, str], float] | None = None,
    options: SystemOptions = SystemOptions(),
    *,
    compensation_terms: Sequence[Term] = (),
    noise_model: NoiseModel | None = None,
) -> SystemNoise:
    """The noise model of the instrument in a system-level record, exactly as :func:`run_system_stage` measures it.

    The same pass, fits and decision (docs/system-calibration.md §1a), without the separation: a record too short to
    determine the coefficients the separation needs (e.g. six hours) still gives its noise (``stableins diagnose``).
    """
    return run_system_stage(  # type: ignore[return-value]
        source, metadata, prior, prior_covariance, options, compensation_terms=compensation_terms, noise_model=noise_model, _noise_only=True
    )


# --------------------------------------------------------------------------- harmonic information
def harmonic_information(
    earth_angle: NDArray[np.float64], z: NDArray[np.float64], latitude: float, order: int = 3
) -> hm.InformationAccumulator:
    """Per-sample reference: ``Σ HᵀH``, ``Σ Hᵀz`` with ``H`` evaluated sample by sample."""
    acc = hm.InformationAccumulator(n_states=2 * order + 1)
    acc.add(hm.observation_rows(earth_angle, latitude, order=order), z)
    return acc


@dataclass
class _BlockHarmonics:
    """Block-Taylor accumulation of the harmonic information (see the module docstring)."""

    latitude: float
    block: int
    order: int = 3  # highest harmonic of S in H
    trig_sums: NDArray[np.float64] = field(init=False)  # C_0..C_2m, S_0..S_2m
    z_sums: NDArray[np.float64] = field(init=False)  # ZC_0..ZC_m, ZS_0..ZS_m
    sum_z2: float = 0.0
    count: int = 0

    def __post_init__(self) -> None:
        self.trig_sums = np.zeros(2 * (2 * self.order + 1))
        self.z_sums = np.zeros(2 * (self.order + 1))

    @property
    def columns(self) -> list[tuple[int, int]]:
        """``(k, kind)`` of the H columns, kind 0 = cos, 1 = sin: 1, cos S, sin S, cos 2S, ..."""
        return [(0, 0)] + [(k, t) for k in range(1, self.order + 1) for t in (0, 1)]

    def add_sums(
        self, centre_angle: NDArray[np.float64], sums: NDArray[np.float64], sum_z2: float
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """Accumulate one chunk's per-block sums (:func:`.blocksums.block_sums`).

        ``centre_angle`` is ``S`` at each block's mean time; within the block ``S = S_c + δ`` with
        ``δ = ω_ie (t − t̄)`` (the platform is inertially held, so ``S`` advances at the Earth rate).
        Returns per-block ``(Σz, ΣH (n_blocks, 2·order+1), n)`` for the filter bins.
        """
        self.sum_z2 += float(sum_z2)
        self.count += int(round(float(sums[:, 7].sum())))
        h = harmonic_sums(centre_angle, sums, self.order, math.cos(self.latitude), self.trig_sums, self.z_sums)
        return sums[:, 0], h, sums[:, 7]

    def accumulator(self) -> hm.InformationAccumulator:
        """``Σ HᵀH`` from the trigonometric sums by product-to-sum identities; ``Σ Hᵀz`` from the z sums."""
        nk = 2 * self.order + 1
        c_sum = self.trig_sums[:nk]
        s_sum = self.trig_sums[nk:]

        def cos_sum(k: int) -> float:
            return float(c_sum[abs(k)])

        def sin_sum(k: int) -> float:
            return float(np.sign(k) * s_sum[abs(k)])

        a = math.cos(self.latitude)
        cols = self.columns
        lam = np.empty((len(cols), len(cols)))
        for i, (ki, ti) in enumerate(cols):
            for j, (kj, tj) in enumerate(cols):
                if ti == 0 and tj == 0:
                    v = 0.5 * (cos_sum(ki - kj) + cos_sum(ki + kj))
                elif ti == 1 and tj == 1:
                    v = 0.5 * (cos_sum(ki - kj) - cos_sum(ki + kj))
                elif ti == 0:  # cos ki · sin kj
                    v = 0.5 * (sin_sum(ki + kj) - sin_sum(ki - kj))
                else:  # sin ki · cos kj
                    v = 0.5 * (sin_sum(ki + kj) + sin_sum(ki - kj))
                lam[i, j] = a ** (ki + kj) * v
        zc = self.z_sums[: self.order + 1]
        zs = self.z_sums[self.order + 1 :]
        acc = hm.InformationAccumulator(n_states=len(cols))
        acc.information = 0.5 * (lam + lam.T)
        acc.projection = np.array([a**k * (zc[k] if t == 0 else zs[k]) for k, t in cols])
        acc.sum_squares = self.sum_z2
        acc.count = self.count
        return acc


def block_length(sample_rate: float, limit: float = 2e-4) -> int:
    """Largest power of two ``B`` with ``B·ω_ie/rate ≤ limit`` (at least 1)."""
    b = max(1.0, limit * sample_rate / EARTH_RATE)
    return 1 << int(math.floor(math.log2(b)))


@dataclass
class _SampleBins:
    """Sums of ``z``, of the ``H`` rows and sample counts over bins of ``samples`` consecutive samples (global index).

    Blocks never straddle a bin (``samples`` is a multiple of the block length and so is every chunk).  With ``cap``,
    the record never needs more than ``cap`` bins: adjacent pairs merge and ``samples`` doubles (sums add exactly, so
    this equals accumulating with the doubled width from the start), which bounds memory whatever the record length.
    """

    samples: int
    cap: int | None = None
    z: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))
    h: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 7)))
    n: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))

    def add(self, starts: NDArray[np.int64], zs: NDArray[np.float64], hs: NDArray[np.float64], counts: NDArray[np.float64]) -> None:
        """Add per-block sums; ``starts`` are the blocks' first global sample indices (in order)."""
        while self.cap is not None and int(starts[-1]) // self.samples >= self.cap:
            self._merge_pairs()
        bins = starts // self.samples
        size = int(bins[-1]) + 1
        if self.n.size < size:
            new = max(size, 2 * self.n.size)
            if self.cap is not None:
                new = min(new, self.cap)
            self.z = np.concatenate([self.z, np.zeros(new - self.z.size)])
            self.n = np.concatenate([self.n, np.zeros(new - self.n.size)])
            self.h = np.concatenate([self.h, np.zeros((new - self.h.shape[0], self.h.shape[1]))])
        first_of_bin = np.flatnonzero(np.r_[True, bins[1:] != bins[:-1]])  # blocks are in order: bins are runs
        ids = bins[first_of_bin]
        self.z[ids] += np.add.reduceat(zs, first_of_bin)
        self.h[ids] += np.add.reduceat(hs, first_of_bin, axis=0)
        self.n[ids] += np.add.reduceat(counts, first_of_bin)

    def _merge_pairs(self) -> None:
        if self.n.size % 2:
            self.z, self.n = np.append(self.z, 0.0), np.append(self.n, 0.0)
            self.h = np.vstack([self.h, np.zeros((1, self.h.shape[1]))])
        self.z = self.z.reshape(-1, 2).sum(axis=1)
        self.n = self.n.reshape(-1, 2).sum(axis=1)
        self.h = self.h.reshape(-1, 2, self.h.shape[1]).sum(axis=1)
        self.samples *= 2


# --------------------------------------------------------------------------- compensation
@dataclass(frozen=True)
class _Compensation:
    """Closed-form Eq. 8 for constant core parameters: ``f^p = M (u − K u²)``, ``u = f^a − δb``."""

    matrix: NDArray[np.float64]
    bias: NDArray[np.float64]
    quadratic: NDArray[np.float64]

    @classmethod
    def from_values(cls, values: Mapping[str, float]) -> _Compensation:
        model = ErrorModel.standard(nonlinear=True)
        known = {k: v for k, v in values.items() if k in model.ids}
        # M from the model's own inverse applied to unit vectors (no re-derivation of Eq. 8 here)
        zero_bias = dict(known, bias_x=0.0, bias_y=0.0, bias_z=0.0, K2_x=0.0, K2_y=0.0, K2_z=0.0)
        matrix = model.inverse(np.eye(3), zero_bias).T
        bias = np.array([known.get(f"bias_{a}", 0.0) for a in "xyz"])
        quadratic = np.array([known.get(f"K2_{a}", 0.0) for a in "xyz"])
        return cls(matrix, bias, quadratic)

    def packed(self, gravity: float) -> NDArray[np.float64]:
        """The coefficients of the compiled per-sample pass (:func:`.blocksums.coefficients`)."""
        return coefficients(self.matrix, self.bias, self.quadratic, gravity)


@dataclass(frozen=True)
class _AdditiveCompensation:
    r"""The prior's discovered (additive) terms, removed from the raw outputs before the closed-form pass.

    The compiled pass applies the core terms only.  With additive terms ``e(f^p)`` the installed
    model is ``f^a = δb + u``, ``u − K u² = SF⁻¹ C f^p + e(f^p)``; the outputs of the same
    instrument without them, at the same specific force, are

    .. math:: f^{a\prime} = F_{core}\big(F^{-1}_{full}(f^a)\big)

    (:meth:`ErrorModel.inverse` of the full model, exact, then :meth:`ErrorModel.forward` of the
    core), so the closed-form compensation of ``f^{a'}`` gives exactly the full model's ``f^p``.
    Only terms of the specific force are allowed (the instrument effects a record carries).
    """

    full: ErrorModel
    core: ErrorModel
    values: dict[str, float]

    @classmethod
    def from_prior(cls, terms: Sequence[Term], prior: Mapping[str, float], path: str) -> _AdditiveCompensation | None:
        if not terms:
            return None
        from stableins.errormodel import TermInputs

        for t in terms:
            if t.kind != TermKind.ADDITIVE or t.regressor is None:
                raise InputError(f"{t.id!r} is not an additive term", path=path, field=t.id)
            try:
                t.regressor(TermInputs(np.array([[0.0, 0.0, -9.8]])))
            except ValueError as error:
                raise InputError(
                    f"the prior's term {t.id!r} cannot be compensated from the specific force alone: {error}",
                    path=path,
                    field=t.id,
                    expected="discovered instrument terms (stableins.discovery.library.calibration_terms)",
                ) from None
        core = ErrorModel.standard(nonlinear=True)
        full = core + tuple(terms)
        return cls(full, core, {k: float(v) for k, v in prior.items() if k in full})

    def __call__(self, fx: NDArray, fy: NDArray, fz: NDArray) -> tuple[NDArray, NDArray, NDArray]:
        f_p = self.full.inverse(np.stack([fx, fy, fz], axis=-1), self.values)
        out = self.core.forward(f_p, self.values)
        return out[:, 0], out[:, 1], out[:, 2]


# --------------------------------------------------------------------------- the stage
def _residual_scale(values: Mapping[str, float], gravity: float) -> dict[str, float]:
    """d(record value)/d(residual): sf = sf/(1 − D) → sf; bias = g·b → g; beta → 1."""
    out = {}
    for name in hm.RESIDUAL_NAMES:
        if name.startswith("D_"):
            out[name] = float(values.get(f"sf_{name[2]}", 1.0))
        elif name.startswith("b_"):
            out[name] = gravity
        else:
            out[name] = 1.0
    return out


def _term_id(residual: str) -> str:
    if residual.startswith("D_"):
        return f"sf_{residual[2]}"
    if residual.startswith("b_"):
        return f"bias_{residual[2]}"
    return residual


def residuals_from_parameters(true: Mapping[str, float], installed: Mapping[str, float], gravity: float) -> NDArray[np.float64]:
    """Residual vector (:data:`harmonics.RESIDUAL_NAMES`) for true and installed parameters (reference values)."""
    out = []
    for name in hm.RESIDUAL_NAMES:
        tid = _term_id(name)
        t, i = float(true.get(tid, 1.0 if tid.startswith("sf") else 0.0)), float(installed.get(tid, 1.0 if tid.startswith("sf") else 0.0))
        if name.startswith("D_"):
            out.append((t - i) / t)
        elif name.startswith("b_"):
            out.append((t - i) / gravity)
        else:
            out.append(t - i)
    return np.array(out)


def _combined_terms() -> tuple[Term, ...]:
    meaning = dict(zip(hm.STATE_NAMES, hm.STATE_MEANING, strict=True))
    terms = []
    for name in COMBINED_COEFFICIENTS:
        terms.append(
            Term(
                name,
                TermKind.COMBINED,
                "rad",
                "urad",
                1e-6,
                1e-4,
                meaning.get(name, f"quasi-static {'pitch' if name.startswith('theta') else 'roll'} coefficient {name}"),
                source="Wu et al. 2018 Eqs. 21-25, 29-38 (signs derived in docs/system-calibration.md)",
            )
        )
    return tuple(terms)


def run_system_stage(
    source: ChunkSource,
    metadata: SiteMetadata,
    prior: Mapping[str, float],
    prior_covariance: Mapping[tuple[str, str], float] | None = None,
    options: SystemOptions = SystemOptions(),
    *,
    compensation_terms: Sequence[Term] = (),
    noise_model: NoiseModel | None = None,
    _noise_only: bool = False,
) -> SystemCalibration:
    """Run the system-level stage on a static, polar-aligned record.

    Parameters
    ----------
    source : ChunkSource
        The record (``stableins.data`` reader or :class:`ArraySource`).
    metadata : SiteMetadata
        Latitude, gravity, sample rate, gimbal senses, base attitude, damping.
    prior : mapping
        Installed calibration the INS compensates with (record values) [SI].
    prior_covariance : mapping, optional
        ``{(id_i, id_j): cov}`` of the prior; sets the gauge metric and the
        uncertainty carried into directions the data do not see.  Default: nominal
        magnitudes of the terms.
    options : SystemOptions
    compensation_terms : sequence of Term
        Discovered (additive) terms of the prior, whose values are in ``prior``: the INS applies
        them, so the stage compensates the raw outputs with them too (the record's
        :meth:`~stableins.records.CalibrationRecord.error_model`).  This stage does not update them.
    noise_model : NoiseModel, optional
        The instrument's noise model as known before this record (the calibration record's).  A datasheet model gives
        the amplitudes of the low-frequency noise as they are; a measured one (device dwells, an earlier static record)
        is a prior on them (docs/system-calibration.md §1a).  The white level is always measured in the record.

    Returns
    -------
    SystemCalibration
        With :attr:`SystemCalibration.noise_model`, the noise model under its σ: measured in this record (source
        ``static record``), or with a datasheet model its slow terms as given and the record's white noise.
    """
    path = getattr(source, "path", "<record>")
    latitude, gravity, rate = _check_metadata(metadata, path)
    loop = DampingLoop.from_metadata(metadata.damping, latitude, gravity, couplings=options.couplings)
    config = GimbalConfiguration(tuple(metadata.gimbal_senses))
    sense = -float(config.senses[0])
    theta10 = float(prior.get("theta10", 0.0))
    base = tuple(float(a) for a in (metadata.base_attitude or (0.0, 0.0, 0.0)))
    cos_yaw, sin_yaw = math.cos(base[0]), math.sin(base[0])
    # level base: (δpitch, δroll) = R(ψ)(−φ_E, −φ_N) exactly to first order.  A tilted base mixes the azimuth
    # error φ_D into pitch and roll (tilt × φ_D, 1e-6 rad per degree): then φ comes from the full output DCM.
    tilted = max(abs(base[1]), abs(base[2])) > LEVEL_TOLERANCE
    base_dcm_t = dcm_nav_to_body(*base).T
    columns = list(FAST_COLUMNS + SLOW_COLUMNS) + (["heading"] if tilted else [])
    # Earth-rate angle: on a level, north-pointing base S = −s1·α1 (conventions.earth_rate_angle).  Otherwise the
    # gimbal angles no longer separate that way: S = atan2(u_y, u_x) with u = f^p/g = −C_n^p e_D from the exact
    # kinematics C_n^p = C_b^p(α) C_n^b(base), evaluated on the decimated samples and interpolated (S is smooth).
    general = tilted or abs(base[0]) > LEVEL_TOLERANCE
    offsets = np.array([float(prior.get(k, 0.0)) for k in ("theta10", "theta20", "theta30")])
    nav_to_body = dcm_nav_to_body(*base)
    if general:
        columns += ["angle_inner", "angle_middle"]
    has_temperature = "temperature" in getattr(source, "columns", ())
    if has_temperature:
        columns.append("temperature")  # read at the attitude decimation: what the data carry about the environment
    temperature = [math.inf, -math.inf, 0.0, 0]  # min, max, sum, count
    compensation = _Compensation.from_values(prior)
    additive = _AdditiveCompensation.from_prior(compensation_terms, prior, path)
    block = block_length(rate)
    chunk_rows = max(block, (options.chunk_rows // block) * block)
    decimation = max(1, int(round(options.attitude_decimation_seconds * rate)))
    filter_samples = max(block, int(round(options.filter_block_seconds * rate / block)) * block)

    accumulator = _BlockHarmonics(latitude, block)
    packed = compensation.packed(gravity)
    step_range = (0.99 / rate, 1.01 / rate)
    attitude_blocks: AttitudeBlocks | None = None
    noise_sums = np.zeros(3)
    noise_count = 0
    filter_bins = _SampleBins(filter_samples)
    fine_bins = _SampleBins(max(block, int(round(FINE_BIN_SECONDS * rate / block)) * block), cap=FINE_BINS)
    checks = _StaticChecks(options, rate, path)
    checks.latitude = latitude
    seen = 0
    first_time = None
    thin = [c for c in columns if c not in FAST_COLUMNS]
    # an HDF5 record's /time_grid: uniformly sampled stretches are reconstructed, not read (time then comes at 1 Hz only)
    grid = getattr(source, "time_grid", None)
    if grid is not None:
        thin.append("time")
    knot_time: float | None = None  # last Earth-rate-angle knot of the previous chunk
    knot_angle = 0.0
    for chunk in source.iter_chunks(columns, rows=chunk_rows, thin=thin, step=decimation, reuse=True, unchecked=FORCE_COLUMNS):
        n = len(chunk["f_x"])
        if n == 0:
            continue
        fx, fy, fz = chunk["f_x"], chunk["f_y"], chunk["f_z"]
        if additive is not None:
            fx, fy, fz = additive(fx, fy, fz)
        phase = (-seen) % decimation
        uniform = None
        if grid is None:
            time = chunk["time"]
            t_d = time[phase::decimation]
        else:
            t_d = chunk["time"]
            k = int(np.searchsorted(grid[:, 0], seen, side="right")) - 1
            inside = (k + 1 == len(grid) or seen + n <= grid[k + 1, 0]) and (seen == 0 or grid[k, 0] < seen)
            if inside:  # one segment, not starting at this chunk: t = t_0 + j·period
                uniform = (float(grid[k, 1] + (seen - grid[k, 0]) * grid[k, 2]), float(grid[k, 2]))
                time = None
            else:  # a segment boundary (gap or irregular steps) in this chunk: the stamps from the grid
                time = source.grid_time(seen, seen + n)
        # the one pass over every sample: z and its per-block moments, block mean times, irregular steps
        sums, block_time, sum_z2, irregular = block_sums(fx, fy, fz, time, packed, block, EARTH_RATE, step_range, grid=uniform)
        if not (math.isfinite(sum_z2) and np.isfinite(sums[:, 0]).all()):  # a NaN or ±inf force propagates into Σz²
            for name, values in zip(FORCE_COLUMNS, (fx, fy, fz), strict=True):
                check_finite(name, values, path, first_row=seen + 1)
        span = (float(time[0]), float(time[-1])) if uniform is None else (uniform[0], uniform[0] + (n - 1) * uniform[1])
        checks.time(time, span, seen, irregular)
        if first_time is None:
            first_time = span[0]
            attitude_blocks = AttitudeBlocks(options.attitude_block_seconds, first_time)
        if general:
            s_d = _earth_angle_from_kinematics(chunk, slice(None), offsets, nav_to_body, config)
        else:
            s_d = sense * (chunk["angle_platform"] + theta10)
        pitch_d, roll_d = chunk["pitch"], chunk["roll"]
        # static checks and the unwrapped Earth-rate angle at the decimated samples
        s_knots = checks.slow(t_d, s_d, pitch_d, roll_d, chunk["velocity_north"], chunk["velocity_east"])
        # S at each block's mean time: linear between the knots (1 s apart, S is smooth), the previous chunk's last knot
        # before the first and the Earth rate after the last (the platform is inertially held: dS/dt = ω_ie)
        kt = t_d if knot_time is None else np.concatenate([[knot_time], t_d])
        ks = s_knots if knot_time is None else np.concatenate([[knot_angle], s_knots])
        kt = np.concatenate([kt, [span[1] + 1.0]])
        ks = np.concatenate([ks, [ks[-1] + EARTH_RATE * (span[1] + 1.0 - kt[-2])]])
        if kt[0] > span[0]:  # no knot yet before the first block (first chunk starts at a knot; kept for safety)
            kt = np.concatenate([[span[0]], kt])
            ks = np.concatenate([[ks[0] - EARTH_RATE * (kt[1] - span[0])], ks])
        centre_angle = np.interp(block_time, kt, ks)
        knot_time, knot_angle = float(t_d[-1]), float(s_knots[-1])
        zs, hs, counts = accumulator.add_sums(centre_angle, sums, sum_z2)
        # filter bins (600 s) and the fine bins of the coloured-noise model's high band, by global sample index
        starts = seen + np.arange(len(counts)) * block
        filter_bins.add(starts, zs, hs, counts)
        fine_bins.add(starts, zs, hs, counts)
        # noise from second differences of the raw outputs
        noise_count += second_difference_sums(fx, fy, fz, options.noise_samples_per_chunk, noise_sums)
        # level base with heading ψ: (δpitch, δroll) = R(ψ)(−φ_E, −φ_N) (conventions.attitude_error_from_misalignment);
        # rotate back to the north-pointing pair the loop model outputs
        if tilted:  # C_n^b' = C_n^b (I + [φ×]) (conventions): φ from the antisymmetric part
            rel = base_dcm_t @ dcm_nav_to_body(chunk["heading"], pitch_d, roll_d)
            p0 = -0.5 * (rel[:, 0, 2] - rel[:, 2, 0])
            r0 = -0.5 * (rel[:, 2, 1] - rel[:, 1, 2])
        else:
            p0 = cos_yaw * pitch_d + sin_yaw * roll_d
            r0 = -sin_yaw * pitch_d + cos_yaw * roll_d
        attitude_blocks.add(t_d, np.cos(s_d), np.sin(s_d), p0, r0)
        sparse = slice(phase, None, 10 * decimation)  # the polar check is a record mean: one sample per 10 decimated ones
        checks.polar(fx[sparse], fy[sparse], fz[sparse])
        if has_temperature and chunk["temperature"].size:
            tc = chunk["temperature"]
            temperature = [
                min(temperature[0], float(tc.min())),
                max(temperature[1], float(tc.max())),
                temperature[2] + float(tc.sum()),
                temperature[3] + tc.size,
            ]
        seen += n

    if seen == 0 or attitude_blocks is None:
        raise InputError("the record has no samples", path=path)
    notes: list[str] = []
    checks.finish(seen, notes)
    duration = checks.duration
    if duration < options.minimum_duration:
        raise InputError(
            f"the record lasts {duration / 3600:.2f} h; the Earth-rate harmonics cannot be separated from the mean and the Schuler "
            f"transient in less than {options.minimum_duration / 3600:.1f} h",
            path=path,
            field="time",
            expected=f"at least {options.minimum_duration / 3600:.1f} h, ideally one sidereal day ({SIDEREAL_DAY / 3600:.2f} h) or more",
        )

    # ---------------------------------------------------------------- noise
    if noise_count < 10:
        raise InputError("too few samples to measure the accelerometer noise", path=path)
    axis_variance = noise_sums / noise_count / 6.0  # E[(Δ²n)²] = 6σ² for white noise
    sin_l, cos_l = math.sin(latitude), math.cos(latitude)
    var_xy = 0.5 * (axis_variance[0] + axis_variance[1])
    sigma_pitch = math.sqrt(sin_l**2 * var_xy + cos_l**2 * axis_variance[2]) / gravity
    sigma_roll = math.sqrt(var_xy) / gravity

    # ---------------------------------------------------------------- harmonics
    info = accumulator.accumulator()
    x_ls, cov_unit = info.solve(1.0)  # LS estimate is independent of R
    r_var = info.residual_variance(x_ls)
    noise_bias = float(axis_variance.sum()) / (2.0 * gravity**2)
    x_hat = x_ls.copy()
    x_hat[0] -= noise_bias
    cov_x = cov_unit * r_var

    # ---------------------------------------------------------------- bins for the coloured-noise model (after the attitude fit)
    keep_bins = filter_bins.n > 0

    # ---------------------------------------------------------------- filter convergence
    history = None
    history_time = np.zeros(0)
    prior_res_cov = _prior_residual_covariance(prior, prior_covariance, gravity)
    if options.run_filter:
        keep = filter_bins.n > 0
        nn = filter_bins.n[keep]
        zb = filter_bins.z[keep] / nn - noise_bias
        hb = filter_bins.h[keep] / nn[:, None]
        m_x = hm.state_combinations(latitude)
        p0 = np.zeros((7, 7))
        p0[:5, :5] = m_x @ prior_res_cov @ m_x.T
        k2_var = _fixed_variance(prior_covariance)
        p0[5, 5], p0[6, 6] = (gravity**2 / 16.0) * k2_var["K2_x"], (gravity**2 / 16.0) * k2_var["K2_y"]
        # at most FILTER_STEPS steps: consecutive bins merged (exact: sums add), so a week costs what two days do
        merge = -(-nn.size // FILTER_STEPS)
        if merge > 1:
            group = np.arange(nn.size) // merge
            size = int(group[-1]) + 1
            zsum = np.bincount(group, weights=zb * nn, minlength=size)
            hsum = np.stack([np.bincount(group, weights=hb[:, k] * nn, minlength=size) for k in range(hb.shape[1])], axis=1)
            nn = np.bincount(group, weights=nn, minlength=size)
            zb, hb = zsum / nn, hsum / nn[:, None]
        history = hm.kalman_filter(hb, zb, r_var / nn, np.zeros(7), p0)
        history_time = (np.cumsum(nn)) / rate

    # ---------------------------------------------------------------- attitude
    blocks = attitude_blocks.means()
    cos_l = math.cos(latitude)
    along = np.array([1.0, cos_l, cos_l, cos_l**2, cos_l**2])
    vertical = -along * x_hat[:5]  # Δf_D/g = −u·δ = −H x: (mean, cos S, sin S, cos 2S, sin 2S)
    att = fit_attitude(
        blocks,
        loop,
        (sigma_pitch / math.sqrt(decimation), sigma_roll / math.sqrt(decimation)),
        case_rotation_period=options.case_rotation_period,
        compensate_loop=options.compensate_loop,
        vertical=vertical,
        gyro_drift=options.gyro_drift,
        known_drift=options.known_gyro_drift,
        scale_low_frequency=False,
        map_bin_seconds=filter_samples / rate,
    )
    notes += list(att.notes)
    if options.known_gyro_drift is None:
        notes.append(
            "gyro drift not supplied: the attitude coefficients assume none.  A constant drift of 0.001 deg/h along a platform "
            "axis drives the loop's undamped Earth-rate mode and biases them by up to 1.9e-5 rad (x1..x5 do not see it); one day "
            "of pitch and roll cannot separate it from the accelerometer harmonics.  Supply the drift in the platform frame from "
            "the gyro calibration (--gyro-drift X Y Z, deg/h) for unbiased attitude coefficients"
        )

    # ---------------------------------------------------------------- observability (short records)
    # v = (x1..x7, ten attitude coefficients) with its covariance; cross terms from the vertical path
    cov_v = np.zeros((17, 17))
    cov_v[:7, :7] = cov_x
    jac_x = np.zeros((10, 7))
    jac_x[:, :5] = att.vertical_jacobian @ np.diag(-along)  # ∂attitude/∂x through the vertical channel
    cov_v[7:, 7:] = att.covariance + jac_x @ cov_x @ jac_x.T
    cov_v[7:, :7] = jac_x @ cov_x
    cov_v[:7, 7:] = cov_v[7:, :7].T
    # coloured (low-frequency) accelerometer noise measured in the residuals: joint covariance of x and the attitude
    given, noise_prior, prior_detected = _noise_prior(noise_model, gravity)
    units, coloured_fit = _coloured_covariance(
        filter_bins,
        fine_bins,
        keep_bins,
        rate,
        x_ls,
        blocks,
        att,
        jac_x,
        latitude,
        loop,
        options.case_rotation_period,
        alpha=options.noise_false_positive_rate,
        prior=noise_prior,
        prior_detected=prior_detected,
        given=given,
    )
    if coloured_fit is not None:
        amplitudes = coloured_fit.amplitudes
    else:  # too short for the model: given amplitudes still apply (propagated on no bins: nothing), measured ones do not exist
        amplitudes = np.zeros(units.shape[:2])
    coloured = np.einsum("ca,caij->ij", amplitudes, units)
    white_x2 = cov_v[1, 1]
    cov_v = cov_v + coloured
    cov_x = cov_v[:7, :7]
    low_frequency_ratio = float(cov_v[1, 1] / white_x2)
    if coloured_fit is not None:
        notes.append(_coloured_note(coloured_fit, units, white_x2, gravity))
    else:
        notes.append(
            "the record is too short for the low-frequency noise model (fewer than 16 bins of "
            f"{filter_samples / rate:.0f} s or four Fourier frequencies): σ is the white-noise σ"
        )
    measured = _measured_noise_model(axis_variance, noise_count, rate, coloured_fit, gravity, noise_model, path, duration)
    if _noise_only:  # measure_noise: the record's noise, whether or not its coefficients can be separated
        return SystemNoise(measured, coloured_fit, duration, tuple(notes[-1:]))  # the decision's note, appended just above
    v = np.concatenate([x_hat, att.values])
    # third harmonic: residual quadratic coefficients (x6 = gΔK_x/4, x7 = −gΔK_y/4)
    k2_values = np.array([4.0 * x_hat[5] / gravity, -4.0 * x_hat[6] / gravity])
    k2_sigma = 4.0 * np.sqrt(np.diag(cov_x)[5:7]) / gravity
    k2_significant = np.abs(k2_values) > 3.0 * k2_sigma
    to_combined = _k2_map(latitude, estimate_k2=options.estimate_k2)
    if k2_significant.any() and not options.estimate_k2:
        text = (
            "third harmonic of Earth rate in the specific-force error: residual quadratic coefficients "
            f"ΔK2_x = {k2_values[0] / MICRO_G_PER_G2:.1f} ± {k2_sigma[0] / MICRO_G_PER_G2:.1f} µg/g², "
            f"ΔK2_y = {k2_values[1] / MICRO_G_PER_G2:.1f} ± {k2_sigma[1] / MICRO_G_PER_G2:.1f} µg/g²; they bias x2, x3 and the "
            f"fundamentals of pitch and roll by up to {3 * cos_l**2 * np.abs(x_hat[5:7]).max():.2e} rad (the paper's model has no K2); "
            "rerun with the K2 estimation on (--estimate-k2) to remove them"
        )
        notes.append(text)
        warnings.warn(f"{path}: {text}", UserWarning, stacklevel=2)
    combined_values = to_combined @ v
    combined_cov = to_combined @ cov_v @ to_combined.T
    transform, observable, kept = _observable_directions(combined_cov)
    if duration < 0.98 * SIDEREAL_DAY or not observable.all():
        hidden = [n for n, ok in zip(COMBINED_COEFFICIENTS, observable, strict=True) if not ok]
        notes.append(
            f"record of {duration / 3600:.2f} h (< one sidereal day): the data determine {kept} of 15 combinations of the combined "
            f"coefficients (variance inflation ≤ {VIF_LIMIT:g}); "
            + (
                f"not observable on their own and reported as unidentifiable: {', '.join(hidden)}; the separation uses only the "
                "determined combinations"
                if hidden
                else "every coefficient remains observable, with larger uncertainty than over a full day"
            )
        )
        if hidden:
            warnings.warn(f"{path}: {notes[-1]}", UserWarning, stacklevel=2)
    names_used = list(COMBINED_COEFFICIENTS)

    # ---------------------------------------------------------------- what the data determine (data-only separation)
    scale = _residual_scale(prior, gravity)
    prior_sigma = {n: math.sqrt(prior_res_cov[i, i]) for i, n in enumerate(hm.RESIDUAL_NAMES)}
    sep = separate(names_used, combined_values, combined_cov, latitude, prior_sigma=prior_sigma, transform=transform)
    if sep.dof < 1 or not any(ok for _, _, ok in sep.combinations.values()):
        what = (
            f"none of the combinations the separation needs ({'; '.join(sep.combinations)}) is determined"
            if not any(ok for _, _, ok in sep.combinations.values())
            else f"the {kept} combinations it resolves are all used by the {sep.rank} the separation estimates (ν = 0): its χ²_ν is "
            "undefined and nothing is left to test the model"
        )
        raise InputError(
            f"the record of {duration / 3600:.2f} h determines nothing the stage can certify: {what}; over less than one sidereal day "
            "the Earth-rate harmonics are not separable from one another (the data lack one sidereal day). Nothing was estimated "
            "and no record was written",
            path=path,
            field="time",
            expected=f"a static record of one sidereal day ({SIDEREAL_DAY / 3600:.2f} h) or more",
        )
    k2_covariance = cov_x[5:7, 5:7] * np.outer([4.0 / gravity, -4.0 / gravity], [4.0 / gravity, -4.0 / gravity])
    likelihood, fit = _likelihood(prior, latitude, gravity, v, cov_v, to_combined, transform, estimate_k2=options.estimate_k2)
    result, corrections = _fit_result(
        sep,
        fit,
        likelihood,
        prior,
        prior_res_cov,
        scale,
        gravity,
        transform,
        notes,
        _prior_term_covariance(prior_covariance, prior_res_cov, scale),
        _settings(options, noise_model),
        k2=(k2_values, k2_covariance) if options.estimate_k2 else None,
    )

    status = tuple(Status.ESTIMATED if ok else Status.UNIDENTIFIABLE for ok in observable)
    combined = FitResult(
        stage="system-combined",
        terms=_combined_terms(),
        values=combined_values,
        covariance=combined_cov,
        status=status,
        residuals=np.zeros(0),
        residual_sigma=np.zeros(0),
        rank=int(observable.sum()),
        notes=(f"x1 corrected for the noise bias E|n|²/(2g²) = {noise_bias:.3e}",),
        details=CombinedDetails(observed_attitude=att.observed, observed_attitude_covariance=att.observed_covariance, transform=transform),
    )
    diagnostics = {
        "duration": duration,
        "samples": seen,
        "block_length": block,
        "attitude_block_seconds": attitude_blocks.block_seconds,  # doubled from the option's value beyond 2^14 blocks
        "axis_noise_sigma": np.sqrt(axis_variance),
        "z_residual_sigma": math.sqrt(r_var),
        "z_low_frequency_ratio": low_frequency_ratio,
        "combined_sigma_white": np.sqrt(np.diag(to_combined @ (cov_v - coloured) @ to_combined.T)),  # without the coloured part
        "noise_samples": noise_count,
        "noise_bias_x1": noise_bias,
        "k2_residual": k2_values,
        "k2_residual_sigma": k2_sigma,
        "third_harmonic": x_hat[5:7],
        "attitude_noise_sigma": (sigma_pitch, sigma_roll),
        "attitude_residual_rms": att.residual_rms,
        "attitude_noise_ratio": att.residual_noise_ratio,
        "platform_rate_ratio": checks.rate_ratio,
        "max_velocity": checks.max_velocity,
        "attitude_excursion": checks.excursion,
        "loop": loop,
        "sampling": checks.summary(),
        "temperature": None
        if temperature[3] == 0
        else {"mean": temperature[2] / temperature[3], "min": temperature[0], "max": temperature[1]},
        "time_span": (checks.first_time, checks.last_time),
    }
    return SystemCalibration(
        result=result,
        combined=combined,
        separation=sep,
        attitude=att,
        history=history,
        history_time=history_time,
        corrections=corrections,
        notes=tuple(notes),
        diagnostics=diagnostics,
        coloured_noise=coloured_fit,
        noise_model=measured,
    )


#: At most this many bins enter the coloured-noise model (longer records: wider bins, so its memory, about 4 MiB,
#: does not depend on the record's length; one day has 144 bins of 600 s).  Monte Carlo of 4-day records (30 seeds):
#: rms z 1.03 with 160 bins, 1.22 with 320 (docs/system-calibration.md §1a).
COLOURED_BINS = 160

#: Fine bins of z for the coloured-noise model's high band [s] (a whole number of blocks), at most :data:`FINE_BINS` of
#: them (pairs merge beyond: a week gets 240-s bins).  They carry the z channel's periodogram from the top of the low band
#: (30 cycles/day) to 0.45/width (650 cycles/day for 60 s), where the white level is pinned (docs/system-calibration.md §1a).
FINE_BIN_SECONDS = 60.0
FINE_BINS = 1 << 12


def _coloured_covariance(
    filter_bins: _SampleBins,
    fine_bins: _SampleBins,
    keep_bins: NDArray[np.bool_],
    rate: float,
    x_ls: NDArray[np.float64],
    blocks: dict[str, NDArray[np.float64]],
    att: AttitudeFit,
    jac_x: NDArray[np.float64],
    latitude: float,
    loop: DampingLoop,
    case_rotation_period: float | None = None,
    alpha: float = 0.05,
    confidence: float = 0.95,
    prior: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None,
    *,
    prior_detected: bool = False,
    given: NDArray[np.float64] | None = None,
) -> tuple[NDArray[np.float64], Any]:
    """Unit covariances ``(2, 3, 17, 17)`` of ``(x1..x7, attitude)`` per coloured component and axis, and the amplitudes.

    The z, pitch and roll residuals on the filter bins (merged to at most :data:`COLOURED_BINS`) give the low band: residual
    periodograms between 3.5 and 30 cycles/day (at most 0.45/bin width) with exact expectations for what the fits absorb
    (:func:`_attitude_residual_maker` for pitch and roll), for the Earth-rate modulation of x and y
    (:func:`.spectrum.axis_loadings`) and for the damping loop (:func:`.spectrum.loop_bin_mixing`).  The z residual on the
    fine bins gives the high band, from the top of the low band to 0.45/fine-bin width, with the closed-form expectations
    of :func:`.spectrum.z_bin_expectations`; it shares the z channel's white level with the low band, which pins that
    level where the coloured noise is weak and makes the coloured excess below it visible.  The decision (coloured noise
    or not, false-positive rate ``alpha``), the amplitudes and their intervals: :func:`.spectrum.fit_coloured_noise`.
    Each component of unit amplitude is propagated through the linear maps of the harmonic fit and of the attitude fit,
    ``J Σ_c Jᵀ`` (:func:`.spectrum.component_quadratic`, ``(n, n)`` matrices only): the stage's covariance adds
    ``Σ_c α_c J Σ_c Jᵀ``.  This carries the low-frequency noise at the harmonic frequencies themselves (a slowly drifting
    x bias is, over the record, part of x2 and of φ1s) and the correlation it creates between the specific-force and
    attitude coefficients.  docs/system-calibration.md §1a.  Returns ``(units, fit)``; ``fit`` is None when the record is
    too short for the model (the covariance is then white).
    """
    from stableins.estimators.system import spectrum

    units = np.zeros((len(spectrum.COLOURED_KINDS), 3, 17, 17))
    n_keep = int(keep_bins.sum())
    if n_keep < 16 or att.block_map is None:
        return units, None
    width = filter_bins.samples / rate
    merge = max(1, -(-n_keep // COLOURED_BINS))
    ids = np.flatnonzero(keep_bins) // merge
    groups, index = np.unique(ids, return_inverse=True)
    n = groups.size
    count = np.bincount(index, weights=filter_bins.n[keep_bins], minlength=n)
    zsum = np.bincount(index, weights=filter_bins.z[keep_bins], minlength=n)
    hsum = np.stack([np.bincount(index, weights=filter_bins.h[keep_bins][:, k], minlength=n) for k in range(7)], axis=1)
    x_bins = hsum / count[:, None]
    residual = zsum / count - x_bins @ x_ls
    time = (groups + 0.5) * width * merge
    wide = width * merge
    a_z = np.linalg.solve(x_bins.T @ (x_bins * count[:, None]), (x_bins * count[:, None]).T)  # (7, n)
    r_z = np.eye(n) - x_bins @ a_z
    cos_l = math.cos(latitude)
    cos_s, sin_s = x_bins[:, 1] / cos_l, x_bins[:, 2] / cos_l
    loads = [spectrum.axis_loadings(ch, cos_s, sin_s, latitude) for ch in ("z", "pitch", "roll")]
    kernels = [spectrum.bin_process_kernel(kind, time, wide) for kind in spectrum.COLOURED_KINDS]  # (n, n) each
    high = min(30.0 * spectrum.EARTH_FREQUENCY, 0.45 / wide)
    # pitch and roll: the loop filters (Δf_N/g, −Δf_E/g, Δf_D/g) = (pitch, roll, −z loadings) · n/g, bin by bin
    mixing = [[loads[0][:, a] for a in range(3)]] + spectrum.loop_bin_mixing(
        loop._controllable_modes(), time, wide, [loads[1], loads[2], -loads[0]]
    )
    # attitude residuals on the same bins (block residuals aggregated; the fit's residual maker approximated on bins)
    block_bin = np.clip(np.searchsorted(groups, np.floor(blocks["time"] / wide).astype(np.int64)), 0, n - 1)
    att_count = np.bincount(block_bin, weights=blocks["count"], minlength=n)
    channels, makers, weights = [residual], [r_z], [count]
    gains: list[Any] = [None]
    if (att_count > 0).all():
        r_att = _attitude_residual_maker(blocks, block_bin, att_count, loop, case_rotation_period)
        for ch in range(2):
            res = np.bincount(block_bin, weights=blocks["count"] * att.block_residuals[:, ch], minlength=n) / att_count
            channels.append(res)
            makers.append(r_att)
            weights.append(att_count)
            # white accelerometer noise through the loop (three independent inputs), then averaged over the bin: the
            # bin means of a loop-filtered white noise have the spectrum Σ_i |G_pi(f)|² sinc²(f w) (no aliases: |G| ≪ 1
            # beyond the bins' Nyquist frequency)
            gains.append(lambda f, ch=ch: float(np.sum(np.abs(loop.frequency_response(2.0 * np.pi * f)[ch]) ** 2) * np.sinc(f * wide) ** 2))
    # low band: every Fourier frequency of the record up to `high` but the harmonics the fits absorb (one day: from 4 cycles
    # per day; longer records also between the harmonics, where the random walk's power is largest)
    low = (0.0, high)
    harmonics = tuple(j * spectrum.EARTH_FREQUENCY for j in range(4))
    built = spectrum.periodogram_design(
        channels, makers, weights, time, kernels, mixing[: len(channels)], low, white_gains=gains, exclude=harmonics
    )
    if built is None:
        return units, None
    design, observed, n_ch = built
    # high band: the z residual on the fine bins (a trailing partial bin left out), above the low band
    fine_count = fine_bins.n.copy()
    last = int(np.flatnonzero(fine_count > 0)[-1]) + 1 if np.any(fine_count > 0) else 0
    if last and fine_count[last - 1] < fine_bins.samples:
        last -= 1
    fine_count = fine_count[:last]
    top = low[1]
    n_high = 0
    if last >= 16:
        fine_width = fine_bins.samples / rate
        k = np.arange(int(math.floor(high * last * fine_width)) + 1, int(math.floor(0.45 * last)) + 1)
        k = k[k / (last * fine_width) > high]
        if k.size:
            filled = fine_count > 0
            fine_residual = np.zeros(last)
            fine_residual[filled] = (fine_bins.z[:last][filled] - fine_bins.h[:last][filled] @ x_ls) / fine_count[filled]
            expected = spectrum.z_bin_expectations(k, last, fine_width, latitude, float(fine_count.sum()) / last)
            rows = np.zeros((k.size, design.shape[1]))
            rows[:, 0] = expected[:, 0]  # the z channel's white level, shared with the low band
            rows[:, n_ch:] = expected[:, 1:]
            design = np.vstack([design, rows])
            observed = np.concatenate([observed, spectrum.z_bin_periodogram(fine_residual, fine_count, k)])
            n_high = int(k.size)
            top = float(k[-1] / (last * fine_width))
    fit = spectrum.fit_coloured_noise(
        design,
        observed,
        n_ch,
        alpha=alpha,
        confidence=confidence,
        ordinates=(int(observed.size - n_high), n_high),
        band=(_lowest_frequency(time, wide, harmonics), high, top),
        prior=prior,
        prior_detected=prior_detected,
        given=given,
    )
    # attitude blocks → the same bins (block time since the record start)
    n_map = att.block_map.shape[1] // 2
    map_group = np.clip(np.searchsorted(groups, np.arange(n_map) // merge), 0, n - 1)  # 600-s bins of the fit → groups
    a_att = np.zeros((10, 2 * n))
    for ch in range(2):
        part = att.block_map[:, ch * n_map : (ch + 1) * n_map]
        for k in range(10):
            a_att[k, ch * n : (ch + 1) * n] = np.bincount(map_group, weights=part[k], minlength=n)
    j = np.zeros((17, 3 * n))
    j[:7, :n] = a_z
    j[7:, :n] = jac_x @ a_z
    j[7:, n:] = a_att
    for c, kernel in enumerate(kernels):
        unit = spectrum.component_quadratic(j, j, mixing, kernel, per_axis=True)
        units[c] = 0.5 * (unit + unit.transpose(0, 2, 1))
    return units, fit


def _lowest_frequency(time: NDArray[np.float64], width: float, harmonics: tuple[float, ...]) -> float:
    """The lowest Fourier frequency of the low band (the first not within half a spacing of an absorbed harmonic)."""
    span = float(time[-1] - time[0]) + width
    k = 1
    while any(abs(k - f * span) < 0.5 for f in harmonics):
        k += 1
    return k / span


def _coloured_note(fit: ColouredNoiseFit, units: NDArray[np.float64], white_x2: float, gravity: float) -> str:
    """What the decision on low-frequency noise found and what it does to σ (docs/system-calibration.md §1a)."""
    from stableins.estimators.system.spectrum import amplitudes_to_allan

    upper = amplitudes_to_allan(fit.upper, gravity)
    allowed = float(np.einsum("c,ca->", fit.upper, units[:, :, 1, 1]))
    bound = (
        f"the data allow up to bias instability {upper[1] / MICRO_G:.3g} ug and random walk {upper[0]:.3g} m/s^2/sqrt(s) "
        f"({100 * fit.confidence:g} % upper limits), with which the variance of x2 would be "
        f"{(white_x2 + allowed) / white_x2:.1f}x the white-noise value"
    )
    factor = (white_x2 + float(np.einsum("ca,ca->", fit.amplitudes, units[:, :, 1, 1]))) / white_x2
    used = amplitudes_to_allan(fit.amplitudes.mean(axis=1), gravity)
    levels = f"bias instability {used[1] / MICRO_G:.3g} ug and random walk {used[0]:.3g} m/s^2/sqrt(s)"
    if fit.source is ColouredSource.GIVEN:
        return (
            f"low-frequency noise as given in the noise model ({levels}) makes the variance of x2 {factor:.1f}x the white-noise "
            f"value; the record's own fit: {fit.describe()}; {bound}"
        )
    if fit.detected:
        how = "posterior mode with the prior noise model" if fit.source is ColouredSource.PRIOR else "maximum likelihood"
        return (
            f"the residuals carry low-frequency noise of the accelerometers ({fit.describe()}): {levels} ({how}, one value for "
            f"the three axes) make the variance of x2 {factor:.1f}x the white-noise value; the covariance of all coefficients "
            f"includes it; {bound}"
        )
    return f"no low-frequency noise ({fit.describe()}): σ is the white-noise σ; {bound}"


def _noise_prior(
    model: NoiseModel | None, gravity: float
) -> tuple[NDArray[np.float64] | None, tuple[NDArray[np.float64], NDArray[np.float64]] | None, bool]:
    """What a prior noise model says about the coloured amplitudes: ``(given, prior, prior_detected)``.

    A datasheet model: the amplitudes per axis, used as they are (``given``, ``(2, 3)``).  A measured model (device dwells,
    an earlier static record): a Gaussian prior on each amplitude (one value for the three axes, the mean over the axes)
    with its centre at the model's value and its standard deviation from the model's interval (two-sided when the term
    was detected, one-sided from its upper limit otherwise; none when the term is not bounded); ``prior_detected`` when
    a slow term was detected.  Nothing known (no model, source ``none``): no prior.
    """
    from scipy.special import ndtri  # the normal quantile

    from stableins.estimators.system.spectrum import allan_to_amplitudes

    if model is None or model.source is NoiseSource.NONE:
        return None, None, False
    values = allan_to_amplitudes(model.values("random_walk"), model.values("bias_instability"), gravity)  # (2, 3)
    if model.source is NoiseSource.DATASHEET:
        return values, None, False
    (k_lo, k_hi), (b_lo, b_hi) = model.limits("random_walk"), model.limits("bias_instability")
    lower = allan_to_amplitudes(k_lo, b_lo, gravity).mean(axis=1)
    upper = allan_to_amplitudes(k_hi, b_hi, gravity).mean(axis=1)
    centre = values.mean(axis=1)
    two_sided, one_sided = float(ndtri(0.5 + 0.5 * model.confidence)), float(ndtri(model.confidence))
    sd = np.where(lower > 0, (upper - lower) / (2.0 * two_sided), (upper - centre) / one_sided)
    sd = np.where(np.isfinite(upper) & (sd > 0), sd, np.inf)
    detected = bool(np.any(np.concatenate([k_lo, b_lo]) > 0))
    return None, (centre, sd), detected


#: Effective degrees of freedom per second difference of white noise: consecutive second differences are correlated
#: (−2/3 at lag 1, 1/6 at lag 2), so the variance of their mean square is ``2(1 + 2(4/9 + 1/36))/n`` times its square.
SECOND_DIFFERENCE_DOF = 1.0 / (1.0 + 2.0 * (4.0 / 9.0 + 1.0 / 36.0))


def _measured_noise_model(
    axis_variance: NDArray[np.float64],
    count: int,
    rate: float,
    fit: ColouredNoiseFit | None,
    gravity: float,
    given: NoiseModel | None,
    path: str,
    duration: float,
) -> NoiseModel:
    """The noise model of the instrument measured in this record (source ``static record``), per axis.

    * White noise ``N = σ/√rate`` per axis from the second differences of the raw outputs (``σ²``, insensitive to the
      Earth-rate signal), interval from ``χ²`` with ``SECOND_DIFFERENCE_DOF · count`` degrees of freedom;
    * bias instability ``B`` and random walk ``K``: the amplitudes under σ (one value for the three axes) with their
      profile-likelihood intervals (:class:`.spectrum.ColouredNoiseFit`); not detected: 0 with the upper limit;
    * quantization: not separable from the white noise at the sample rate: 0, with the upper limit at which it would make
      all of the second differences' variance (``20 Q²/dt²``).
    With a datasheet model given to the stage, its bias instability, random walk and quantization are the ones used and
    are kept (source ``datasheet``); the white noise is the record's, as under every σ of the stage.
    """
    from dataclasses import replace

    from scipy.special import gammaincinv

    from stableins.estimators.system.spectrum import amplitudes_to_allan

    confidence = 0.95 if fit is None else fit.confidence
    dof = max(1.0, SECOND_DIFFERENCE_DOF * count)
    tail = 0.5 * (1.0 - confidence)
    white = np.sqrt(axis_variance / rate)
    white_lo = white * math.sqrt(dof / (2.0 * float(gammaincinv(0.5 * dof, 1.0 - tail))))  # χ²_dof quantiles
    white_hi = white * math.sqrt(dof / (2.0 * float(gammaincinv(0.5 * dof, tail))))
    q_upper = np.sqrt(6.0 * axis_variance / 20.0) / rate
    whites = [NoiseTerm(float(white[a]), float(white_lo[a]), float(white_hi[a])) for a in range(3)]
    if given is not None and given.source is NoiseSource.DATASHEET:
        axes = tuple(replace(axis, white=whites[a]) for a, axis in enumerate(given.axes))
        provenance = (
            f"white noise measured in the system-level record {path} ({count} second differences per axis); bias instability, "
            f"random walk and quantization as given ({given.provenance or 'datasheet'})"
        )
        return replace(given, axes=axes, provenance=provenance)
    if fit is None:
        slow = {"random_walk": NoiseTerm.unbounded(), "bias_instability": NoiseTerm.unbounded()}
        slow_text = "bias instability and random walk not measured (record too short for the residual-spectrum model)"
    else:
        value = amplitudes_to_allan(fit.amplitudes.mean(axis=1), gravity)
        lower = amplitudes_to_allan(fit.lower, gravity)
        upper = amplitudes_to_allan(fit.upper, gravity)
        slow = {}
        for k, name in enumerate(("random_walk", "bias_instability")):
            v = float(value[k])
            lo = min(float(lower[k]), v) if fit.detected else 0.0
            slow[name] = NoiseTerm(v, lo, max(float(upper[k]), v))
        slow_text = (
            "bias instability and random walk from the residual spectra, one value for the three axes ("
            + fit.describe()
            + ("; with the prior noise model" if fit.source is ColouredSource.PRIOR else "")
            + ")"
        )
    axes = tuple(
        AxisNoise(
            white=whites[a],
            bias_instability=slow["bias_instability"],
            random_walk=slow["random_walk"],
            quantization=NoiseTerm(0.0, 0.0, float(q_upper[a])),
        )
        for a in range(3)
    )
    provenance = (
        f"system-level record {path}: {duration / 3600:.2f} h at {rate:g} Hz; white noise from {count} second differences "
        f"per axis; {slow_text}; quantization not separable from the white noise at this rate (upper limit)"
    )
    return NoiseModel(axes, NoiseSource.STATIC_RECORD, provenance, confidence)  # type: ignore[arg-type]


def _attitude_residual_maker(
    blocks: dict[str, NDArray[np.float64]],
    block_bin: NDArray[np.int64],
    bin_count: NDArray[np.float64],
    loop: DampingLoop,
    case_rotation_period: float | None,
) -> NDArray[np.float64]:
    """Residual maker ``(n, n)`` of the attitude fit on the bins: ``R = I − X̄ (XᵀWX)⁻¹ X̄ᵀ W̄``.

    The attitude fit runs on the blocks with all its columns (mean, harmonics, the decaying Schuler and vertical
    transients, the case-rotation terms: :func:`.attitude._design`).  For noise that is constant within a bin, the
    binned residual is ``R`` applied to the binned noise, with ``X̄`` the bin means of the columns, ``W̄`` the bin
    counts and ``XᵀWX`` the fit's block-level normal matrix.  The transient columns matter: over the first hour they
    absorb a large part of a random walk's low-frequency power (the residual variance on the bins drops by up to a
    half), which a residual maker with only the mean and the harmonics misses.  Built in slices of
    :data:`.attitude.FIT_ROWS` blocks (bounded memory).  Drift columns (``gyro_drift="fit"``) are not included.
    """
    from stableins.estimators.system.attitude import FIT_ROWS, _design

    n = bin_count.size
    columns = None
    normal = None
    for start in range(0, blocks["time"].size, FIT_ROWS):
        rows = slice(start, start + FIT_ROWS)
        x = _design({k: blocks[k][rows] for k in ("time", "cos", "sin")}, loop, case_rotation_period)[0]
        wx = x * blocks["count"][rows, None]
        part = np.einsum("bi,bj->ij", wx, x)  # einsum, not BLAS (docs §6)
        sums = np.stack([np.bincount(block_bin[rows], weights=wx[:, k], minlength=n) for k in range(x.shape[1])], axis=1)
        normal = part if normal is None else normal + part
        columns = sums if columns is None else columns + sums
    mean_columns = columns / bin_count[:, None]
    return np.eye(n) - mean_columns @ np.linalg.solve(normal, columns.T)


def _earth_angle_from_kinematics(
    chunk: Mapping[str, NDArray[np.float64]],
    sel: Any,
    offsets: NDArray[np.float64],
    nav_to_body: NDArray,
    config: GimbalConfiguration,
) -> NDArray[np.float64]:
    """Unwrapped Earth-rate angle ``S = atan2(u_y, u_x)``, ``u = −C_b^p(α) C_n^b e_D`` on the selected samples."""
    alpha = [chunk[name][sel] + offsets[k] for k, name in enumerate(("angle_platform", "angle_inner", "angle_middle"))]
    c_bp = dcm_body_to_platform(alpha[0], alpha[1], alpha[2], 0.0, config)
    u = -(c_bp @ nav_to_body[:, 2])
    return np.unwrap(np.arctan2(u[:, 1], u[:, 0]))


def _check_metadata(metadata: SiteMetadata, path: str) -> tuple[float, float, float]:
    lat = metadata.latitude
    if lat is None or not np.isfinite(lat) or abs(lat) > np.pi / 2:
        raise InputError("latitude is missing or not a latitude", path=path, field="metadata.latitude", expected="geodetic latitude in rad")
    if abs(lat) > np.radians(89.0):
        raise InputError("polar-aligned system calibration is degenerate within 1° of a pole", path=path, field="metadata.latitude")
    g = metadata.gravity
    if g is None or not np.isfinite(g) or not (9.7 < g < 9.9):
        raise InputError(f"gravity {g!r} is missing or implausible", path=path, field="metadata.gravity", expected="local gravity in m/s^2")
    rate = metadata.sample_rate
    if rate is None or not np.isfinite(rate) or rate <= 0:
        raise InputError("sample rate is missing", path=path, field="metadata.sample_rate", expected="a positive rate in Hz")
    return float(lat), float(g), float(rate)


def _k2_map(latitude: float, *, estimate_k2: bool) -> NDArray[np.float64]:
    """Matrix ``(15, 17)`` from ``(x1..x7, attitude)`` to the combined coefficients.

    With ``estimate_k2`` the residual-K2 parts are removed: ``δ_i += gΔK_i u_i²`` gives
    ``x2 += 3cos²L x6``, ``x3 −= 3cos²L x7``, ``θ1c −= 3 sinL cos²L x6``, ``θ1s += 3 sinL cos²L x7``,
    ``φ1s += cos²L x6``, ``φ1c += cos²L x7`` (docs/system-calibration.md §8).
    """
    m = np.zeros((15, 17))
    m[:5, :5] = np.eye(5)
    m[5:, 7:] = np.eye(10)
    if estimate_k2:
        s, c2 = math.sin(latitude), math.cos(latitude) ** 2
        x6, x7 = 5, 6
        row = {n: i for i, n in enumerate(COMBINED_COEFFICIENTS)}
        m[row["x2"], x6] = -3.0 * c2
        m[row["x3"], x7] = 3.0 * c2
        m[row["theta_1c"], x6] = 3.0 * s * c2
        m[row["theta_1s"], x7] = -3.0 * s * c2
        m[row["phi_1s"], x6] = -c2
        m[row["phi_1c"], x7] = -c2
    return m


def _prior_term_covariance(
    prior_covariance: Mapping[tuple[str, str], float] | None, prior_res_cov: NDArray[np.float64], scale: Mapping[str, float]
) -> NDArray[np.float64]:
    """Prior covariance over CORE_TERMS: the prior's own entries (all correlations), nominal magnitudes where it has none.

    The residual block is :func:`_prior_residual_covariance` mapped back to the terms; K2 terms and their cross terms
    with the others come from the prior as given (a record's covariance), their variance nominal² when missing.
    """
    terms = CORE_TERMS
    res_index = {_term_id(r): i for i, r in enumerate(hm.RESIDUAL_NAMES)}
    j = {_term_id(r): scale[r] for r in hm.RESIDUAL_NAMES}
    fixed = _fixed_variance(prior_covariance)
    cov = np.zeros((len(terms), len(terms)))
    for a, ta in enumerate(terms):
        for b, tb in enumerate(terms):
            if ta.id in res_index and tb.id in res_index:
                cov[a, b] = prior_res_cov[res_index[ta.id], res_index[tb.id]] * j[ta.id] * j[tb.id]
            elif a == b:
                cov[a, b] = fixed[ta.id]
            else:
                value = None if prior_covariance is None else prior_covariance.get((ta.id, tb.id))
                cov[a, b] = float(value) if value is not None and np.isfinite(value) else 0.0
    cov = 0.5 * (cov + cov.T)
    if np.linalg.eigvalsh(cov / np.sqrt(np.outer(np.diag(cov), np.diag(cov)))).min() <= 0.0:  # mixed sources broke it: no cross terms
        cov = np.where(np.outer([t.id in res_index for t in terms], [t.id in res_index for t in terms]), cov, np.diag(np.diag(cov)))
    return cov


def _fixed_variance(prior_covariance: Mapping[tuple[str, str], float] | None) -> dict[str, float]:
    """Prior variances of the terms this stage carries through unchanged (K2); nominal² where unknown."""
    out = {}
    for t in CORE_TERMS:
        if t.kind == TermKind.NONLINEARITY:
            v = None if prior_covariance is None else prior_covariance.get((t.id, t.id))
            out[t.id] = float(v) if v is not None and np.isfinite(v) and v > 0 else t.nominal**2
    return out


def _observable_directions(covariance: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.bool_], int]:
    """Combinations of the combined coefficients that the record determines.

    Per group (the five harmonic states; the ten attitude coefficients) the information
    matrix in correlation form ``Λ_s`` has unit eigenvalues for an orthogonal design (a
    whole number of days).  Directions with eigenvalue ``< 1/VIF_LIMIT`` (variance inflated
    more than ``VIF_LIMIT`` times) are not observable.  Returns the transform ``T`` whose
    rows are the kept combinations (``T c`` has covariance ``diag(1/λ)``), which coefficients
    remain individually observable, and the number of kept combinations.
    """
    rows = []
    observable = np.zeros(15, bool)
    for group in (slice(0, 5), slice(5, 15)):
        idx = np.arange(15)[group]
        info = np.linalg.pinv(covariance[np.ix_(idx, idx)], rcond=1e-15, hermitian=True)
        d = np.sqrt(np.clip(np.diag(info), 1e-300, None))
        eigenvalues, vectors = np.linalg.eigh(info / np.outer(d, d))
        keep = eigenvalues >= 1.0 / VIF_LIMIT
        v = vectors[:, keep]
        for column in v.T:
            row = np.zeros(15)
            row[idx] = column * d
            rows.append(row)
        inside = np.linalg.norm(v.T, axis=0)  # |projection of each unit coefficient direction on the kept span|
        observable[idx] = inside > 0.99
    transform = np.array(rows) if rows else np.zeros((0, 15))
    if transform.shape[0] == 15:
        transform = np.eye(15)  # everything is determined: use the coefficients themselves
    return transform, observable, len(rows)


def _prior_residual_covariance(
    prior: Mapping[str, float], prior_covariance: Mapping[tuple[str, str], float] | None, gravity: float
) -> NDArray[np.float64]:
    """Prior covariance of the residuals (:data:`harmonics.RESIDUAL_NAMES`); nominal term magnitudes where unknown."""
    scale = _residual_scale(prior, gravity)
    nominal = {t.id: t.nominal for t in CORE_TERMS}
    n = len(hm.RESIDUAL_NAMES)
    cov = np.zeros((n, n))
    for i, a in enumerate(hm.RESIDUAL_NAMES):
        for j, b in enumerate(hm.RESIDUAL_NAMES):
            ta, tb = _term_id(a), _term_id(b)
            value = None if prior_covariance is None else prior_covariance.get((ta, tb))
            if value is not None and np.isfinite(value):
                cov[i, j] = value / (scale[a] * scale[b])
            elif i == j:
                cov[i, j] = (nominal[ta] / scale[a]) ** 2
        if not (cov[i, i] > 0):
            cov[i, i] = (nominal[_term_id(a)] / scale[a]) ** 2
    return 0.5 * (cov + cov.T)


def _settings(options: SystemOptions, noise_model: NoiseModel | None = None) -> dict[str, Any]:
    """The stage's options as stage settings of a record (JSON values; gyro drift in rad/s, platform frame).

    ``noise_model``: the source of the noise model the stage started from (``none`` when there was none).
    """
    from dataclasses import asdict

    out = asdict(options)
    out["gyro_drift"] = options.gyro_drift.value
    if out["known_gyro_drift"] is not None:
        out["known_gyro_drift"] = [float(x) for x in out["known_gyro_drift"]]
    return {"stage": "system", **out, "noise_model": "none" if noise_model is None else noise_model.source.value}


@dataclass(frozen=True)
class _SeparationFit:
    """The measurement the stage hands to the Bayesian update, and its own least-squares fit (χ², ν)."""

    labels: tuple[str, ...]
    values: NDArray[np.float64]
    sigma: NDArray[np.float64]
    residuals: NDArray[np.float64]
    whitened: NDArray[np.float64]
    rank: int


def _likelihood(
    prior: Mapping[str, float],
    latitude: float,
    gravity: float,
    v: NDArray[np.float64],
    cov_v: NDArray[np.float64],
    to_combined: NDArray[np.float64],
    transform: NDArray[np.float64],
    *,
    estimate_k2: bool,
) -> tuple[Likelihood, _SeparationFit]:
    r"""What the record says about the accelerometer parameters: a :class:`Likelihood` (docs/system-calibration.md §4).

    Measurement ``w = T c`` (the combinations of the combined coefficients ``c`` the record resolves; with
    ``estimate_k2`` also the third-harmonic states ``x6 = gΔK2_x/4``, ``x7 = −gΔK2_y/4``), covariance ``R`` from
    ``cov_v``.  Model ``w = H q + e`` over the residuals ``q`` (true − installed, :data:`harmonics.RESIDUAL_NAMES`;
    ΔK2_x, ΔK2_y with ``estimate_k2``) and the two mean nuisances (base tilt and gimbal zero offsets in the pitch and
    roll means).  The nuisances have no prior: they are eliminated exactly by projecting the whitened measurement
    on the complement of their columns.  With whitened ``A = R^{-1/2} H`` and ``r = R^{-1/2} w`` (at ``q = 0``,
    the installed calibration), ``Λ_q = A_pᵀ A_p``, ``g_q = A_pᵀ r_p``; in the record's parameters
    ``x = x_0 + J q`` (``J``: the installed scale factor for ``D``, ``g`` for a bias residual, 1 for angles and K2),
    ``Λ = J⁻¹ Λ_q J⁻¹``, ``g = J⁻¹ g_q`` at the point ``x_0``.
    """
    from stableins.estimators.system.separation import combination_matrix

    n_res = len(hm.RESIDUAL_NAMES)
    rows = transform @ to_combined  # (k, 17)
    g_full = combination_matrix(latitude)  # (15, 14): residuals, then the two nuisances
    h_res = transform @ g_full[:, :n_res]
    h_nuisance = transform @ g_full[:, n_res:]
    labels = list(COMBINED_COEFFICIENTS) if transform.shape[0] == 15 else [f"combination {k + 1}" for k in range(transform.shape[0])]
    ids = [_term_id(r) for r in hm.RESIDUAL_NAMES]
    jac = [float(_residual_scale(prior, gravity)[r]) for r in hm.RESIDUAL_NAMES]
    if estimate_k2:
        rows = np.vstack([rows, np.eye(17)[5:7]])
        h_res = np.block([[h_res, np.zeros((h_res.shape[0], 2))], [np.zeros((2, n_res)), np.diag([gravity / 4.0, -gravity / 4.0])]])
        h_nuisance = np.vstack([h_nuisance, np.zeros((2, 2))])
        labels += ["x6", "x7"]
        ids += ["K2_x", "K2_y"]
        jac += [1.0, 1.0]
    w = rows @ v
    cov_w = rows @ cov_v @ rows.T
    sd = np.sqrt(np.diag(cov_w))
    chol = np.linalg.cholesky(cov_w / np.outer(sd, sd)) * sd[:, None]
    whiten = np.linalg.inv(chol)
    a_res, a_nui, r = whiten @ h_res, whiten @ h_nuisance, whiten @ w
    # eliminate the nuisances (flat prior): project on the orthogonal complement of their whitened columns
    pinv_n = np.linalg.pinv(a_nui, rcond=1e-10)
    a_p = a_res - a_nui @ (pinv_n @ a_res)
    r_p = r - a_nui @ (pinv_n @ r)
    j_inv = 1.0 / np.array(jac)
    information = (a_p.T @ a_p) * np.outer(j_inv, j_inv)
    gradient = (a_p.T @ r_p) * j_inv
    point = np.array([float(prior.get(i, 1.0 if i.startswith("sf_") else 0.0)) for i in ids])
    likelihood = Likelihood(tuple(ids), point, information, gradient)
    # the stage's own least-squares fit of the measurement (residuals, χ², ν = measurements − rank)
    a_full = np.hstack([a_res, a_nui])
    solution, *_ = np.linalg.lstsq(a_full, r, rcond=1e-10)
    rank = int(np.linalg.matrix_rank(a_full, tol=1e-10 * np.linalg.norm(a_full, 2)))
    whitened = r - a_full @ solution
    fit = _SeparationFit(tuple(labels), w, sd, chol @ whitened, whitened, rank)
    return likelihood, fit


def _fit_result(
    sep: Separation,
    fit: _SeparationFit,
    likelihood: Likelihood,
    prior: Mapping[str, float],
    prior_res_cov: NDArray[np.float64],
    scale: Mapping[str, float],
    gravity: float,
    transform: NDArray[np.float64],
    notes: list[str],
    prior_cov: NDArray[np.float64],
    settings: dict[str, Any],
    k2: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None,
) -> tuple[FitResult, dict[str, float]]:
    """The stage's result: the Bayesian update of the prior given to the stage (values, covariance over CORE_TERMS)."""
    from stableins.estimators.posterior import bayesian_update

    terms = tuple(CORE_TERMS)
    ids = [t.id for t in terms]
    prior_values = np.array([float(prior.get(t.id, t.reference)) for t in terms])
    post = bayesian_update(ids, prior_values, prior_cov, [Status.ESTIMATED] * len(ids), likelihood)
    corrections = {t.id: float(post.values[k] - prior_values[k]) for k, t in enumerate(terms) if post.determination[k] is not None}
    determined = tuple(
        f"{name} = {value:.4e} ± {sigma:.2e}" + ("" if ok else " (NOT determined by these data)")
        for name, (value, sigma, ok) in sep.combinations.items()
    )
    seen = [t.id for t, d in zip(terms, post.determination, strict=True) if d is not None]
    alone = [t.id for t, d in zip(terms, post.determination, strict=True) if d is Determination.ALONE]
    notes = list(notes) + [
        "Bayesian update of the installed calibration (the prior): the data's information on the combinations they determine "
        "is added to the prior's, so no uncertainty grows and nothing moves along what the data do not see; determined by "
        f"these data alone: {', '.join(alone) or 'none'}; in combination only: {', '.join(i for i in seen if i not in alone) or 'none'}",
        "b_x and beta_xy act only through b_x/g - beta_xy*sinL, b_y and beta_yx only through b_y/g + beta_yx*sinL "
        "(paper Eq. 41 is singular); (beta_xz+beta_yz)/2 is indistinguishable from the platform-axis zero offset; the scale factors "
        "and b_z enter only through x1",
        (
            "K2_x, K2_y measured by the third harmonic of Earth rate in z (not in the paper's model) and updated with the rest; "
            "K2_z is not observed and keeps its prior"
            if k2 is not None
            else "K2 terms are not seen by this stage and keep their prior values and variances (nominal magnitude when the prior "
            "has none); the third harmonic of Earth rate in z measures K2_x, K2_y (see diagnostics, --estimate-k2)"
        ),
    ]
    result = FitResult(
        stage="system",
        terms=terms,
        values=np.array(post.values, dtype=float),
        covariance=np.array(post.covariance, dtype=float),
        status=post.status,
        residuals=fit.residuals,
        residual_sigma=fit.sigma,
        residual_labels=fit.labels,
        rank=fit.rank,
        singular_values=sep.singular_values,
        null_space=np.zeros((len(terms), 0)),
        determined=determined,
        notes=tuple(notes),
        details=SystemDetails(
            nuisance=sep.values[len(hm.RESIDUAL_NAMES) :],
            determination=dict(zip(ids, post.determination, strict=True)),
            k2_data_only=None if k2 is None else (k2[0], k2[1]),
        ),
        whitened_residuals=fit.whitened,
        likelihood=likelihood,
        settings=settings,
    )
    return result, corrections


# --------------------------------------------------------------------------- checks
class _StaticChecks:
    """Sampling, static-base and platform-rate checks on the streamed record."""

    def __init__(self, options: SystemOptions, rate: float, path: str) -> None:
        self.options = options
        self.rate = rate
        self.path = path
        self.period = 1.0 / rate
        self.last_time: float | None = None
        self.first_time: float | None = None
        self.gaps: list[tuple[int, float]] = []
        self.gap_time = 0.0
        self.jitter = 0
        self.max_velocity = 0.0
        self.pitch_range = [np.inf, -np.inf]
        self.roll_range = [np.inf, -np.inf]
        self.excursion = 0.0
        self.rate_sums = np.zeros(5)  # n, Σt, Σt², ΣS, ΣtS (unwrapped)
        self.last_angle: float | None = None
        self.angle_offset = 0.0
        self.moving_at: float | None = None
        self.rate_ratio = float("nan")
        self.duration = 0.0
        self.polar_sums = np.zeros(2)
        self.latitude = 0.0

    def time(self, t: NDArray[np.float64] | None, span: tuple[float, float], seen: int, irregular: int) -> None:
        """Sampling checks of one chunk; ``irregular`` counts its steps off the nominal period by more than 1 %.

        ``span`` is the chunk's first and last time; ``t`` its stamps (None for a uniform stretch of a time grid).
        Only a chunk with irregular steps (or an irregular step from the previous chunk) is examined step by step.
        """
        if self.last_time is not None:  # the step across the chunk boundary
            across = span[0] - self.last_time
            irregular += not (0.99 * self.period <= across <= 1.01 * self.period)
        if irregular and t is not None:
            bad = ~np.isfinite(t)
            if bad.any():
                k = int(np.argmax(bad))
                raise InputError(
                    f"value {t[k]!r} is not finite", path=self.path, field="time", row=seen + k + 1, expected="a finite number"
                )
            series = t if self.last_time is None else np.concatenate([[self.last_time], t])
            step = np.diff(series)
            offset = seen + (1 if self.last_time is None else 0)
            if not (step > 0).all():
                k = int(np.flatnonzero(~(step > 0))[0])
                raise InputError(
                    "time does not increase", path=self.path, field="time", row=offset + k + 1, expected="strictly increasing time"
                )
            gap = step > 1.5 * self.period
            if gap.any():
                for k in np.flatnonzero(gap)[:100]:
                    self.gaps.append((offset + int(k) + 1, float(step[k])))
                self.gap_time += float(step[gap].sum() - gap.sum() * self.period)
            self.jitter += int(((np.abs(step - self.period) > 0.01 * self.period) & ~gap).sum())
        if self.first_time is None:
            self.first_time = span[0]
        self.last_time = span[1]

    def slow(self, t: NDArray, s: NDArray, pitch: NDArray, roll: NDArray, vn: NDArray, ve: NDArray) -> NDArray[np.float64]:
        """Static-base checks on the decimated samples; returns the Earth-rate angle unwrapped across chunks."""
        if t.size == 0:
            return s
        speed = np.hypot(vn, ve)
        vmax = float(speed.max())
        if vmax > self.options.velocity_limit and self.moving_at is None:
            self.moving_at = float(t[int(np.argmax(speed > self.options.velocity_limit))])
        self.max_velocity = max(self.max_velocity, vmax)
        self.pitch_range = [min(self.pitch_range[0], float(pitch.min())), max(self.pitch_range[1], float(pitch.max()))]
        self.roll_range = [min(self.roll_range[0], float(roll.min())), max(self.roll_range[1], float(roll.max()))]
        # unwrap the Earth-rate angle across chunks
        prev = self.last_angle if self.last_angle is not None else float(s[0])
        series = np.concatenate([[prev], s])
        if np.abs(np.diff(series)).max() > np.pi:  # a wrap of the reading in this chunk (rare: S moves 7e-5 rad/s)
            series = np.unwrap(series)
        series = series[1:] + self.angle_offset
        self.angle_offset = float(series[-1] - s[-1])
        self.last_angle = float(s[-1])
        tt = t - (self.first_time or 0.0)
        self.rate_sums += [t.size, tt.sum(), (tt * tt).sum(), series.sum(), (tt * series).sum()]
        return series

    def polar(self, fx: NDArray, fy: NDArray, fz: NDArray) -> None:
        """Accumulate the direction cosine of gravity with z_p (sin L on a polar-aligned platform)."""
        norm = np.sqrt(fx * fx + fy * fy + fz * fz)
        self.polar_sums += [fz.size, float(np.sum(fz / norm))]

    def finish(self, seen: int, notes: list[str]) -> None:
        self.duration = (self.last_time or 0.0) - (self.first_time or 0.0)
        n, st, stt, ss, sts = self.rate_sums
        denominator = n * stt - st * st
        if n > 2 and denominator > 0:
            slope = (n * sts - st * ss) / denominator
            self.rate_ratio = slope / EARTH_RATE
        excursion = max(self.pitch_range[1] - self.pitch_range[0], self.roll_range[1] - self.roll_range[0])
        self.excursion = excursion
        if self.moving_at is not None:
            raise InputError(
                f"the base is not static: horizontal velocity output reaches {self.max_velocity:.3g} m/s "
                f"(first beyond {self.options.velocity_limit:g} m/s at t = {self.moving_at:.1f} s)",
                path=self.path,
                field="velocity_north/velocity_east",
                expected="a static base (velocity outputs are then navigation errors: Schuler transients of Δf/ω_s, a few m/s at most)",
            )
        if excursion > self.options.attitude_limit:
            raise InputError(
                f"the base is not static or not level: pitch/roll vary by {excursion:.3g} rad over the record",
                path=self.path,
                field="pitch/roll",
                expected=f"attitude errors varying by less than {self.options.attitude_limit:g} rad on a static base",
            )
        if self.polar_sums[0] > 0:
            mean_uz = self.polar_sums[1] / self.polar_sums[0]
            polar_error = math.asin(max(-1.0, min(1.0, mean_uz))) - self.latitude
            if abs(polar_error) > self.options.polar_tolerance:
                raise InputError(
                    f"the platform is not polar aligned: gravity makes {math.degrees(math.asin(max(-1.0, min(1.0, mean_uz)))):.3f}° "
                    f"with the platform's x-y plane, the latitude is {math.degrees(self.latitude):.3f}°",
                    path=self.path,
                    field="f_z",
                    expected="z_p on the Earth's spin axis (f_z/g = sin L), as the system-level method requires",
                )
        if np.isfinite(self.rate_ratio) and abs(self.rate_ratio - 1.0) > self.options.rate_tolerance:
            raise InputError(
                f"the platform-axis angle turns at {self.rate_ratio:.4f} x the Earth rate",
                path=self.path,
                field="angle_platform",
                expected="a platform fixed in inertial space on a static base (angle rate = Earth rate, correct sense s1)",
            )
        if self.gaps:
            first = self.gaps[0]
            text = (
                f"{len(self.gaps)} gap(s) in the time column (first at row {first[0]}: step {first[1]:.6g} s; {self.gap_time:.1f} s "
                "missing in all); the fits use the samples present (the INS kept running), the Earth-rate angle is read per sample"
            )
            notes.append(text)
            warnings.warn(f"{self.path}: {text}", UserWarning, stacklevel=3)
        if self.jitter:
            text = (
                f"{self.jitter} time step(s) off the nominal {self.period:.6g} s by more than 1 %; the fits do not assume uniform sampling"
            )
            notes.append(text)
            warnings.warn(f"{self.path}: {text}", UserWarning, stacklevel=3)

    def summary(self) -> dict[str, Any]:
        return {"gaps": list(self.gaps[:10]), "gap_count": len(self.gaps), "missing_seconds": self.gap_time, "jitter_steps": self.jitter}


__all__ = [
    "ATTITUDE_COEFFICIENTS",
    "ArraySource",
    "SystemCalibration",
    "SystemOptions",
    "SystemNoise",
    "block_length",
    "harmonic_information",
    "measure_noise_model",
    "residuals_from_parameters",
    "run_system_stage",
]
