"""The systematic stage: passes of the filter over the record, re-linearized until the estimate settles.

Each pass streams the record twice through :mod:`~stableins.estimators.systematic.observations` (a scan,
then the steps) and runs two filters on the same steps (:mod:`~stableins.estimators.systematic.kalman`):
the *estimate* filter (the record's prior on the accelerometer terms, the survey's on the base error, zero
offsets free) and the *rank* filter (every nuisance free), whose information is the data's alone
(:mod:`~stableins.estimators.systematic.rank`).  The next pass linearizes the forcing and the observations at
the estimate (the base error and the zero offsets, the accelerometer Jacobians), as PSINS iterates whole
passes, but feedforward.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from stableins.conventions import ARCSEC
from stableins.data.chunks import ChunkSource, source_path
from stableins.errormodel import ErrorModel, known_terms
from stableins.errors import InputError
from stableins.estimators.system.loop import DampingLoop
from stableins.estimators.systematic.kalman import FilterRun, run_filters, steps_of
from stableins.estimators.systematic.model import (
    GYRO_IDS,
    Discretization,
    StateLayout,
    accelerometer_ids,
    parameter_ids,
    slow_noise_times,
    white_density,
)
from stableins.estimators.systematic.observations import HoldSummary, Linearization, RecordScan, StepBuilder, scan_record
from stableins.estimators.systematic.rank import GroupRank, free_prior, group_rank, resolution
from stableins.noise import FLICKER_VARIANCE_PER_B2, NoiseModel
from stableins.site import SiteMetadata

#: Prior 1σ of the terms a record may not hold, by family [SI]: wide against what the data determine (0.01 °/h,
#: 0.01 °/h/g, 98 µg/g²); the record update removes it (:attr:`SystematicOptions.new_term_sigma`).
NEW_TERM_SIGMA: dict[str, float] = {"gyro_drift": 5e-8, "Dg": 5e-9, "Kcc": 1e-5}


@dataclass(frozen=True)
class SystematicOptions:
    """Settings of the systematic stage (docs/systematic-calibration.md).

    Attributes
    ----------
    step : float
        Filter step ``Δ`` [s] (observations pre-integrated over it).
    substeps : int
        Substeps ``m`` of the forcing per step.
    iterations : int
        Most passes of the outer re-linearization loop.
    tolerance : float
        Stop when no parameter moves by more than this many σ between passes.
    rows : int
        Samples per streamed chunk.
    base_sigma : tuple of float
        Survey uncertainty of the base (north, east, down rotations) [rad].
    misalignment_sigma : float
        Prior 1σ of the INS's initial attitude error ``φ(0)`` [rad].
    new_term_sigma : mapping
        Prior 1σ of terms the record does not hold, by family (``gyro_drift``, ``Dg``, ``Kcc``; the others from
        :data:`NEW_TERM_SIGMA`) [SI]; the record update removes it (they enter with the data's information alone).
    cross_coupling : bool
        Keyword only.  Estimate Cai et al. 2016's six cross-couplings (``Kcc_xxy, xxz, yxy, yyz, zxz, zyz``) besides
        the core residuals and any cross-coupling the record's error model holds (those are always estimated;
        :func:`~stableins.estimators.systematic.model.accelerometer_ids`).
    """

    step: float = 30.0
    substeps: int = 30
    iterations: int = 3
    tolerance: float = 0.01
    rows: int = 1 << 18
    base_sigma: tuple[float, float, float] = (20 * ARCSEC, 20 * ARCSEC, 120 * ARCSEC)
    misalignment_sigma: float = 1e-3
    new_term_sigma: Mapping[str, float] = field(default_factory=lambda: dict(NEW_TERM_SIGMA))
    cross_coupling: bool = field(default=False, kw_only=True)

    def term_sigma(self, term_id: str) -> float:
        """Prior 1σ [SI] of ``term_id`` when the record does not hold it: a core term's nominal, else by family."""
        term = known_terms().get(term_id)
        if term is not None and term_id not in GYRO_IDS:
            return term.nominal
        family = "Dg" if term_id.startswith("Dg_") else "Kcc" if term_id.startswith("Kcc_") else "gyro_drift"
        return {**NEW_TERM_SIGMA, **self.new_term_sigma}[family]


@dataclass(frozen=True)
class Prior:
    """What the stage starts from: the record's values, covariance, error model and noise model.

    Attributes
    ----------
    values : mapping
        Installed calibration [SI] (the linearization point of the first pass).
    ids : tuple of str
        Ids of ``covariance``.
    covariance : ndarray
    error_model : ErrorModel
    noise_model : NoiseModel
        The unit's noise model (white, bias instability, random walk, quantization per axis).
    """

    values: Mapping[str, float]
    ids: tuple[str, ...]
    covariance: NDArray[np.float64]
    error_model: ErrorModel
    noise_model: NoiseModel

    def sigma(self, term_id: str, default: float) -> float:
        """Prior 1σ of ``term_id`` (``default`` when the record does not hold it or has no finite σ)."""
        if term_id in self.ids:
            k = self.ids.index(term_id)
            value = float(self.covariance[k, k])
            if np.isfinite(value) and value > 0:
                return float(np.sqrt(value))
        return default


@dataclass(frozen=True)
class PassResult:
    """The outcome of the last pass: both filters, the layout, the scan, how many passes ran, and the last pass's point.

    The offset and base states of the filters are relative to ``point`` (:meth:`totals` adds it); the accelerometer and
    gyro states are relative to the installed calibration.
    """

    def totals(self, run: FilterRun) -> NDArray[np.float64]:
        """Return the states of ``run`` in SI, offsets and base error as totals (point + estimate)."""
        x = run.x * self.layout.scales()
        x[self.layout.offsets] += self.point.offsets
        x[self.layout.base] += self.point.base
        return x

    layout: StateLayout
    scan: RecordScan
    estimate: FilterRun
    rank: FilterRun
    prior_covariance: NDArray[np.float64]
    diffuse_covariance: NDArray[np.float64]
    passes: int
    changes: tuple[float, ...]
    point: Linearization
    holds: tuple[HoldSummary, ...]
    estimate_prior_mean: NDArray[np.float64]


#: About how many steps' innovations the result keeps as its fit evidence (bounded whatever the record's length).
EVIDENCE_STEPS = 200
#: Prior 1σ of the free nuisances (base error, zero-offset residuals) and of the hold constants [rad]: wide
#: against anything the data determine (arcseconds), narrow enough to keep the filter's covariance well conditioned
#: (the hold constants are near zero by construction: each hold's reference is its own first observation).
FREE_ANGLE = 1e-3


def initial_covariance(layout: StateLayout, prior: Prior, options: SystematicOptions, *, diffuse: bool) -> NDArray[np.float64]:
    """``P0`` in state units (the parameters scaled by :meth:`StateLayout.scales`)."""
    scales = layout.scales()
    sigma = np.zeros(layout.size)
    sigma[0:3] = options.misalignment_sigma
    sigma[3:5], sigma[7] = 0.1, 0.1
    sigma[5], sigma[6], sigma[8] = 1e-5, 10.0, 1e-2
    sigma[9:12] = 1e-7
    sigma[:12] /= scales[:12]
    sigma[layout.noise] = _noise_prior(layout, prior.noise_model) / scales[layout.noise]
    for k, name in enumerate(parameter_ids(layout)):
        index = layout.accelerometer.start + k
        sigma[index] = (free_prior(name) if diffuse else prior.sigma(name, options.term_sigma(name))) / scales[index]
    base = FREE_ANGLE if diffuse else np.asarray(options.base_sigma)
    sigma[layout.base] = base / scales[layout.base]
    sigma[layout.offsets.start :] = FREE_ANGLE / scales[layout.offsets.start :]
    return np.diag(sigma**2)


def prior_mean(layout: StateLayout, prior: Prior) -> NDArray[np.float64]:
    """``x₀`` in state units: zero, except the gyro terms, which are states themselves (the record's values, if any)."""
    x0 = np.zeros(layout.size)
    scales = layout.scales()
    for k, name in enumerate(layout.names[layout.gyro]):
        x0[layout.gyro.start + k] = float(prior.values.get(name, 0.0)) / scales[layout.gyro.start + k]
    return x0


def _noise_prior(layout: StateLayout, noise: NoiseModel) -> NDArray[np.float64]:
    """Stationary σ of the Gauss-Markov states; 0 for the random walk (it starts with the record)."""
    out = [np.zeros(3)] if layout.random_walk else []
    b = noise.values("bias_instability")
    out += [np.sqrt(FLICKER_VARIANCE_PER_B2) * b for _ in layout.slow_times]
    return np.concatenate(out) if out else np.zeros(0)


def noise_inputs(noise: NoiseModel) -> tuple[NDArray[np.float64], NDArray[np.float64], tuple[NDArray[np.float64], NDArray[np.float64]]]:
    """``(white PSD, quantization, (K, σ_τ))`` per axis from the noise model (:mod:`stableins.noise`)."""
    b = noise.values("bias_instability")
    sigmas = np.array([np.sqrt(FLICKER_VARIANCE_PER_B2) * b for _ in slow_noise_times()])
    return white_density(noise.values("white"), b), noise.values("quantization"), (noise.values("random_walk"), sigmas)


def run_passes(source: ChunkSource, site: SiteMetadata, prior: Prior, options: SystematicOptions) -> PassResult:
    """Run the outer loop: scan once, then passes until no parameter moves by more than ``options.tolerance`` σ."""
    scan = scan_record(source, site.sample_rate, options.rows)
    if scan.holds < 2:  # before any pass: the filter needs the orientations
        raise InputError(
            "the record holds one orientation: the systematic stage needs the platform indexed to at least two",
            path=source_path(source), field="angle_platform", expected="a record of 'stableins run system-indexed'",
        )  # fmt: skip
    walk = bool(np.any(prior.noise_model.values("random_walk") > 0))
    block = accelerometer_ids(prior.error_model, cross_coupling=options.cross_coupling)
    layout = StateLayout(scan.holds, slow_noise_times(), random_walk=walk, accelerometer_ids=block)
    loop = DampingLoop.from_metadata(site.damping, site.latitude, site.gravity)
    disc = Discretization.of(loop, options.step, options.substeps)
    white, quantization, slow = noise_inputs(prior.noise_model)
    p0 = initial_covariance(layout, prior, options, diffuse=False)
    p0_diffuse = initial_covariance(layout, prior, options, diffuse=True)
    lin = Linearization(prior.values, prior.error_model, ids=layout.accelerometer_ids)
    changes: list[float] = []
    estimate = rank = None
    point = lin
    for number in range(1, options.iterations + 1):
        noise = (white, quantization, layout.noise.stop - layout.noise.start)
        builder = StepBuilder(site, scan, lin, step=options.step, substeps=options.substeps, noise=noise)
        steps = steps_of(builder.batches(source, options.rows), layout, disc, slow)
        x0 = prior_mean(layout, prior)
        x0[layout.base] = -lin.base / layout.scales()[layout.base]  # the survey's prior is on the total base error
        stride = max(1, scan.samples // builder.rows_step // EVIDENCE_STEPS)
        estimate, rank = run_filters(steps, x0, [p0, p0_diffuse], innovation_stride=stride)
        point, lin = lin, _linearization(lin, estimate, layout)
        changes.append(_change(point, lin, estimate, layout))
        if changes[-1] < options.tolerance or number == options.iterations:
            break
    assert estimate is not None and rank is not None
    return PassResult(layout, scan, estimate, rank, p0, p0_diffuse, len(changes), tuple(changes), point, builder.holds(), x0)


def _linearization(old: Linearization, run: FilterRun, layout: StateLayout) -> Linearization:
    """Return the linearization point of the next pass: the installed values plus the estimated residuals."""
    x = run.x * layout.scales()
    accelerometer, offsets, base = x[layout.accelerometer], old.offsets + x[layout.offsets], old.base + x[layout.base]
    return Linearization(old.values, old.error_model, accelerometer, offsets, base, ids=layout.accelerometer_ids)


def _change(old: Linearization, new: Linearization, run: FilterRun, layout: StateLayout) -> float:
    """Largest move of the linearization point between passes, in posterior σ."""
    sigma = np.sqrt(np.diag(run.P)) * layout.scales()
    moves = [
        (new.residuals - old.residuals) / sigma[layout.accelerometer],
        (new.offsets - old.offsets) / sigma[layout.offsets],
        (new.base - old.base) / sigma[layout.base],
    ]
    return float(max(np.max(np.abs(m)) for m in moves))


#: The groups of the rank report: name and the state names' test.
RANK_GROUPS = (
    ("accelerometer", lambda n: n.startswith(("sf_", "bias_", "beta_"))),
    ("nonlinearity", lambda n: n.startswith(("K2_", "Kcc_"))),  # the f_i f_j terms: K2 and any cross-couplings
    ("gyro", lambda n: n in GYRO_IDS),
    ("nuisance", lambda n: n.startswith("base_") or n.endswith("_residual")),
)


def rank_report(result: PassResult) -> tuple[GroupRank, ...]:
    """Return what the record's orientations determine, group by group, from the free-prior filter (module ``rank``)."""
    names = result.layout.names
    scales = result.layout.scales()
    out = []
    for group, member in RANK_GROUPS:
        index = [k for k, n in enumerate(names) if member(n)]
        block = np.ix_(index, index)
        information = np.linalg.inv(result.rank.P[block]) - np.linalg.inv(result.diffuse_covariance[block])
        units = np.array([resolution(names[k]) / scales[k] for k in index])
        out.append(group_rank(group, tuple(names[k] for k in index), information, units))
    return tuple(out)
