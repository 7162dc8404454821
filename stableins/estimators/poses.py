r"""Calibration from static poses of a triad held by hand or on a fixture: no gimbal, no commands.

Any accelerometer triad at rest measures ``|f| = g`` whatever its orientation, so the holds of a
continuous log (:mod:`stableins.data.holds`) are fine-stage dwells without commanded readings.
Two fits, chosen by what the poses determine:

**Unknown orientation** (the multi-position method; Tedaldi et al. 2014, imu_tk): the fine stage's
squared-amplitude fit, :func:`stableins.estimators.fine.calibrate_fine`, one forward model and one
set of analytic Jacobians (Wu et al. 2018 Sec. 4)::

    z_j = ½ g² − ½ |f^p(p; ȳ_j)|² = 0 + v_j

With ``N ≥ 13`` usable holds it estimates 12 combinations (scale factors, biases, the three
installation-angle differences, ``K2``); when the holds do not determine ``K2`` (fewer than 13, or a
design whose rank falls short, e.g. axes only ever near ±1 g), the 9-combination form without it
(imu_tk's scale, bias and non-orthogonality); fewer than 10 holds of unknown orientation determine
neither and are refused.  The start values come from the holds themselves: per axis the bias is the
mid-range and the scale factor the half-range of the hold means over ``g``, so raw converter counts
need no prior calibration.  The installation-angle sums the norm cannot see are held at 0 (there is
no coarse stage), and reported ``unidentifiable``.

**Known orientation** (the six-position or tumble test; IEEE Std 1293 §A, Ferraris et al. 1995):
each hold labelled with the axis that points up (``+x`` ... ``-z``) reads ``ȳ_i = δb_i ± g/SF_i`` on
that axis (output = f/SF + δb, Eq. 6, with the installation and ``K2`` neglected, as the
classic test does).  Per axis the weighted least-squares line through its ``+`` and ``−`` holds
gives ``δb_i`` and ``k_i = 1/SF_i``; with one hold each it is the half-sum and half-difference::

    δb_i = (ȳ₊ + ȳ₋)/2,     1/SF_i = (ȳ₊ − ȳ₋)/(2g),
    σ(δb_i) = ½ √(σ₊² + σ₋²),   σ(1/SF_i) = √(σ₊² + σ₋²)/(2g),   σ(SF_i) = SF_i² σ(1/SF_i)

(first order in σ for ``SF``).  Repeated labels give ``χ²`` with ``Σ_i (n_i − 2)`` degrees of freedom.
"""

from __future__ import annotations

import enum
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from stableins.documents import DocumentFields, JSONObject
from stableins.errormodel import ErrorModel, Term
from stableins.errors import InputError, NotDeterminedError
from stableins.estimators.details import DeviceDetails, UsedDwell
from stableins.estimators.device_settings import DeviceFitSettings
from stableins.estimators.dwell import DwellSummary, describe_left_out, summarize_dwell
from stableins.estimators.fine import calibrate_fine, fine_model
from stableins.estimators.layout import DwellChecks
from stableins.estimators.result import FitResult, Likelihood, Stage
from stableins.noise import NoiseModel
from stableins.status import Status

#: The stage name of a pose calibration in results and records.
STAGE = Stage.POSES

#: Dwell checks of a hold: the converter's range is checked by the reader (``railed`` samples), not here.
POSE_CHECKS = DwellChecks(saturation=np.inf)


class PoseModel(enum.Enum):
    """The model a pose calibration fitted (stated in its notes and settings)."""

    TWELVE = "12 combinations: scale factors, biases, 3 installation-angle differences, K2 (squared amplitude)"
    NINE = "9 combinations: scale factors, biases, 3 installation-angle differences (squared amplitude, imu_tk's form)"
    SIX_POSITION = "six-position test: bias and scale factor per axis from the labelled holds (half-sum / half-difference)"


@dataclass(frozen=True)
class PoseSettings:
    """The settings of a pose calibration: the model it fitted and, for the squared amplitude, the fine stage's noise model."""

    model: PoseModel
    noise_model: NoiseModel | None = None

    def to_document(self) -> JSONObject:
        """Return ``{"stage": "poses", "noise_model" (not for the six-position test), "model": <name>}`` (docs/formats.md)."""
        out: JSONObject = {"stage": STAGE.value}
        if self.model is not PoseModel.SIX_POSITION:
            out["noise_model"] = None if self.noise_model is None else self.noise_model.to_document()
        out["model"] = self.model.name
        return out

    @classmethod
    def from_document(cls, fields: DocumentFields) -> PoseSettings:
        """Return the settings :meth:`to_document` wrote (:class:`InputError` naming the field)."""
        name = fields.text("model")
        if name not in PoseModel.__members__:
            raise fields.fail("model", f"{name!r} is not a pose model", ", ".join(PoseModel.__members__))
        noise = fields.document.get("noise_model")
        model = None if noise is None else NoiseModel.from_document(noise, fields.path, f"{fields.where}.noise_model")
        return cls(PoseModel[name], model)


def summarize_holds(
    time: NDArray[np.float64],
    specific_force: NDArray[np.float64],
    railed: NDArray[np.bool_],
    holds: Sequence[tuple[int, int]],
    *,
    checks: DwellChecks = POSE_CHECKS,
) -> list[DwellSummary]:
    """Return one dwell summary per hold ``(first, stop)`` (position = hold number, stage ``poses``).

    A hold with a sample at the converter's range (``railed``) is flagged ``saturated`` and left out of the fits.
    """
    zeros = np.zeros((0, 3))
    out = []
    for k, (first, stop) in enumerate(holds, 1):
        angles = np.zeros((stop - first, 3)) if stop > first else zeros
        summary = summarize_dwell(time[first:stop], specific_force[first:stop], angles, np.zeros(3), position=k, stage=STAGE, checks=checks)
        rails = int(np.count_nonzero(railed[first:stop]))
        if rails:
            summary = replace(summary, flags=(*summary.flags, f"saturated samples: {rails} at the converter's range"))
        out.append(summary)
    return out


def start_values(dwells: Sequence[DwellSummary], gravity: float) -> dict[str, float]:
    """Return start values from the hold means: per axis bias = mid-range, ``SF = 2g / range`` (module docstring)."""
    means = np.array([d.mean for d in dwells])
    high, low = means.max(axis=0), means.min(axis=0)
    span = high - low
    values = {f"bias_{a}": float(0.5 * (high[i] + low[i])) for i, a in enumerate("xyz")}
    values.update({f"sf_{a}": float(2.0 * gravity / span[i]) if span[i] > 0 else 1.0 for i, a in enumerate("xyz")})
    return values


def calibrate_poses(
    dwells: Sequence[DwellSummary],
    *,
    gravity: float,
    orientations: Sequence[str] | None = None,
    noise: NoiseModel | None = None,
    start: Mapping[str, float] | FitResult | None = None,
    extra_terms: Sequence[Term] = (),
    source: str = "log",
) -> FitResult:
    """Calibrate from the holds of a log (module docstring): known orientation when every hold is labelled.

    Parameters
    ----------
    dwells : sequence of DwellSummary
        One per hold (:func:`summarize_holds`).
    gravity : float
        Local gravity [m/s²].
    orientations : sequence of str, optional
        Per hold, ``+x`` ... ``-z`` or "" (unknown); all labelled: the six-position test.
    noise : NoiseModel, optional
        Slow noise correlated between holds (the fine stage's); white noise measured in each hold when None.
    start : mapping or FitResult, optional
        Start values (default: :func:`start_values`).  With the fine stage's coarse start the
        unknown-orientation fit is the fine stage's, term for term.
    extra_terms : sequence of Term
        Discovered effects estimated with the standard terms (unknown orientation only; model discovery on the
        holds, :mod:`stableins.discovery.poses`).

    Returns
    -------
    FitResult
        Stage ``poses``; its settings name the model (:class:`PoseModel`).
    """
    labels = list(orientations) if orientations is not None else [""] * len(dwells)
    if len(labels) != len(dwells):
        raise InputError("one orientation per hold", path=source, field="orientation")
    if any(labels):
        if not all(labels):
            missing = [d.position for d, lab in zip(dwells, labels, strict=True) if not lab]
            raise InputError(
                f"holds {missing} have no orientation while others do",
                path=source,
                field="orientation",
                expected="every hold labelled (+x ... -z: the six-position test) or none (unknown orientation)",
            )
        if extra_terms:
            raise InputError(
                "the six-position test estimates no added effect", path=source, field="--add", expected="holds of unknown orientation"
            )
        return six_position(dwells, labels, gravity=gravity, source=source)
    usable = [d for d in dwells if d.usable]
    left_out = {d.position: "; ".join(d.flags) for d in dwells if not d.usable}
    if len(usable) < 10:
        raise InputError(
            f"only {len(usable)} usable holds of unknown orientation; the 9-combination model needs at least 10 "
            f"(left out: {describe_left_out(left_out)})",
            path=source,
            field="holds",
            expected="more poses, or an orientation label per hold (the six-position test: --holds TABLE with +x ... -z)",
        )
    first = start if start is not None else start_values(usable, gravity)
    tried: list[str] = []
    for model in (PoseModel.TWELVE, PoseModel.NINE):
        try:
            fit = calibrate_fine(
                dwells,
                first,
                gravity=gravity,
                noise=noise,
                source=source,
                model=fine_model(extra_terms, nonlinear=model is PoseModel.TWELVE),
            )
        except (InputError, NotDeterminedError) as error:
            if model is PoseModel.NINE:
                raise type(error)(
                    f"the holds determine neither model: {'; '.join(tried)}; {error.message}",
                    path=source,
                    field="holds",
                    expected="poses with every axis near +1 g, -1 g and in between",
                ) from None
            tried.append(f"K2 not determined ({error.message})")
            continue
        stated = f"model: {model.value}" + (f"; {tried[0]}" if tried else "")
        installation = (
            "installation angles: the norm determines only the differences of the pairs (xz, yz), (zy, xy), (yx, zx); "
            "with no coarse stage the sums it cannot see are held at 0 (reported unidentifiable)"
        )
        own = tuple(_hold_wording(n) for n in fit.notes if not n.startswith("installation angles: the fine stage"))
        notes = (stated, installation, *own)
        noise_model = fit.settings.noise_model if isinstance(fit.settings, DeviceFitSettings) else None
        return replace(fit, stage=STAGE, notes=notes, settings=PoseSettings(model, noise_model))
    raise AssertionError("unreachable")


def _hold_wording(note: str) -> str:
    """Return a fine-stage note in the words of a log: its positions are the holds."""
    return "hold " + note.removeprefix("position ") if note.startswith("position ") else note


def six_position(dwells: Sequence[DwellSummary], labels: Sequence[str], *, gravity: float, source: str = "log") -> FitResult:
    """Bias and scale factor per axis from holds labelled with the axis that points up (module docstring)."""
    model = ErrorModel(tuple(t for t in ErrorModel.standard(nonlinear=False).terms if t.id.startswith(("sf_", "bias_"))))
    usable_pairs = [(d, lab) for d, lab in zip(dwells, labels, strict=True) if d.usable]
    left_out = {d.position: "; ".join(d.flags) for d in dwells if not d.usable}
    values = np.zeros(6)
    cov = np.zeros((6, 6))
    residuals: list[float] = []
    sigmas: list[float] = []
    names: list[str] = []
    information = np.zeros((6, 6))
    for i, axis in enumerate("xyz"):
        rows = [(d, 1.0 if lab[0] == "+" else -1.0) for d, lab in usable_pairs if lab[1] == axis]
        signs = {s for _, s in rows}
        if signs != {1.0, -1.0}:
            missing = [f"{'+' if s > 0 else '-'}{axis}" for s in (1.0, -1.0) if s not in signs]
            raise InputError(
                f"no usable hold labelled {' or '.join(missing)} (left out: {describe_left_out(left_out)})",
                path=source,
                field="orientation",
                expected=f"at least one hold each with +{axis} and -{axis} up",
            )
        y = np.array([d.mean[i] for d, _ in rows])
        s = np.array([d.sem[i] for d, _ in rows])
        design = np.column_stack([np.ones(len(rows)), [sign * gravity for _, sign in rows]])
        weighted = design / s[:, None]
        normal = weighted.T @ weighted
        inverse = np.linalg.inv(normal)
        bias, k = inverse @ (weighted.T @ (y / s))
        if len(rows) == 2:  # the half-sum and half-difference exactly (no rounding from the normal equations)
            plus = next(j for j, (_, sign) in enumerate(rows) if sign > 0)
            minus = 1 - plus
            bias, k = 0.5 * (y[plus] + y[minus]), (y[plus] - y[minus]) / (2.0 * gravity)
        sf = 1.0 / k
        # (δb, 1/SF) → (SF, δb): d SF = −SF² d(1/SF)
        jac = np.array([[0.0, -(sf**2)], [1.0, 0.0]])
        block = jac @ inverse @ jac.T
        values[[i, 3 + i]] = sf, bias
        cov[np.ix_([i, 3 + i], [i, 3 + i])] = block
        information[np.ix_([i, 3 + i], [i, 3 + i])] = np.linalg.inv(block)
        r = y - design @ np.array([bias, k])
        residuals += list(r)
        sigmas += list(s)
        names += [f"hold {d.position} ({'+' if sign > 0 else '-'}{axis}) f_{axis}" for d, sign in rows]
    used = tuple(UsedDwell(STAGE, d.pass_number, d.position) for d, _ in usable_pairs)
    rank = 6
    dof = len(residuals) - rank
    notes = [
        f"model: {PoseModel.SIX_POSITION.value}; the installation angles and K2 are not estimated (neglected, as the classic test does)",
        f"local gravity {gravity:.7f} m/s^2 is the reference: an error δg scales sf_x, sf_y, sf_z by 1 + δg/g",
    ]
    if dof == 0:
        notes.append("no redundancy: one hold per label determines the six numbers exactly (no χ²); repeat poses to test the model")
    notes += [f"hold {p} left out: {why}" for p, why in sorted(left_out.items())]
    return FitResult(
        stage=STAGE,
        terms=model.terms,
        values=values,
        covariance=cov,
        status=(Status.ESTIMATED,) * 6,
        residuals=np.array(residuals),
        residual_sigma=np.array(sigmas),
        residual_labels=tuple(names),
        rank=rank,
        singular_values=np.sqrt(np.linalg.eigvalsh(information))[::-1],
        null_space=np.zeros((6, 0)),
        notes=tuple(notes),
        details=DeviceDetails(positions_used=used, left_out=left_out),
        gravity=float(gravity),
        likelihood=Likelihood(model.ids, values.copy(), information, np.zeros(6)),
        settings=PoseSettings(PoseModel.SIX_POSITION),
    )


__all__ = ["POSE_CHECKS", "STAGE", "PoseModel", "calibrate_poses", "six_position", "start_values", "summarize_holds"]
