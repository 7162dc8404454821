r"""The signature of a residual no library effect explains: which outputs, positions and harmonics carry it.

When χ² rejects the model and no candidate brings it back into its band (the effect is outside the library,
:attr:`stableins.discovery.ranking.Ranking.outside_library`), discovery cannot name the effect; it says where it is.
With normalized residuals ``z = r/σ`` (diagonal 1σ; ``P`` positions × ``c`` outputs, ``ν`` degrees of freedom over the
``m = P c`` residuals):

* **outputs**: each output's ``χ²_a = Σ_p z_{pa}²`` against its share of the degrees of freedom ``ν P / m``; the excess
  ``max(χ²_a − ν P/m, 0)`` as a fraction of the summed excess;
* **positions**: each position's ``χ²_p = Σ_a z_{pa}²`` against ``ν c / m``, the largest excesses first;
* **gimbal-angle harmonics** (device dwells): for each gimbal ``g``, harmonic ``k = 1 … 4`` and output ``a``, the fraction
  of ``χ²_a`` that the least-squares fit of ``[cos kθ_g, sin kθ_g]`` to ``z_{·a}`` takes (``θ_g`` the mean reading of the
  dwell), shown when above three times what two columns take from pure noise (``2/P``);
* **Earth-rate harmonics** (system records): the harmonics of the residual spectra flagged at the family-wise level
  (:class:`stableins.discovery.system.SystemDiagnosis`), carried in from the spectra.

It describes; it does not name a cause.  docs/discovery.md "Outside the library".

**A signature left after a candidate** (device dwells, :func:`laboratory_columns`): the library's effects are
functions of the specific force in the platform frame (the vertical seen by the platform), of the gimbal angles and of
time; an effect that follows a direction fixed in the laboratory *other than the vertical* (a magnetic field, a
heat source, an air flow: each output's direction cosines with north and east, ``(C_n^p)_{aN}``, ``(C_n^p)_{aE}``,
six columns over the three outputs) is none of them.  Before a candidate is named, the residual with it added is
tested on these columns (:func:`stableins.discovery.ranking.rank`): a significant part left there means the
candidate takes only part of an effect it is not (the residual still has a signature), so it is not named.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from stableins.platform import GIMBAL_NAMES  # the gimbal angles, columns of the dwell readings

if TYPE_CHECKING:  # pragma: no cover
    from numpy.typing import NDArray

    from stableins.discovery.diagnostics import Diagnosis

#: Harmonics of the gimbal angles tested.
GIMBAL_HARMONICS = (1, 2, 3, 4)
#: At most this many positions and harmonics are shown.
SHOWN = 5
#: An output carries the residual when it holds at least this share of the excess χ²; only those are searched for harmonics.
CARRYING_SHARE = 0.2


@dataclass(frozen=True)
class OutputShare:
    """One output's part of the residual: ``χ²`` of its residuals, what the noise alone gives, and its share of the excess."""

    output: str
    chi2: float
    expected: float
    share: float


@dataclass(frozen=True)
class PositionShare:
    """One position's part of the residual: ``χ²`` over its outputs, what noise alone gives, its share of the excess."""

    position: str
    chi2: float
    expected: float
    share: float


@dataclass(frozen=True)
class GimbalHarmonic:
    """A harmonic of a gimbal angle that carries much of one output's residual: the fraction of its ``χ²`` it takes."""

    gimbal: str
    harmonic: int
    output: str
    fraction: float


@dataclass(frozen=True)
class EarthHarmonic:
    """An Earth-rate harmonic of one output's residual flagged at the family-wise level, with its p-value."""

    output: str
    harmonic: int
    p_value: float


@dataclass(frozen=True)
class ResidualSignature:
    """Where a residual no library effect explains lives (module docstring).

    Attributes
    ----------
    outputs : tuple of OutputShare
        Every output, in order.
    positions : tuple of PositionShare
        The positions with the largest excess, largest first (at most :data:`SHOWN`).
    gimbal_harmonics : tuple of GimbalHarmonic
        Device dwells: the gimbal-angle harmonics that carry most of an output's residual, largest first.
    earth_harmonics : tuple of EarthHarmonic
        System records: the flagged Earth-rate harmonics.
    """

    outputs: tuple[OutputShare, ...]
    positions: tuple[PositionShare, ...]
    gimbal_harmonics: tuple[GimbalHarmonic, ...] = ()
    earth_harmonics: tuple[EarthHarmonic, ...] = ()

    def lines(self) -> list[str]:
        """Return the signature in words, one line per part."""
        outputs = ", ".join(f"{o.output} {o.chi2:.1f}/{o.expected:.1f} ({100 * o.share:.0f} %)" for o in self.outputs)
        out = [f"outputs (χ² / what the noise gives; share of the excess): {outputs}"]
        if self.positions:
            shares = ", ".join(f"{p.position} {p.chi2:.1f}/{p.expected:.1f} ({100 * p.share:.0f} %)" for p in self.positions)
            out.append(f"positions carrying it: {shares}")
        if self.gimbal_harmonics:
            harmonics = ", ".join(
                f"{h.harmonic}× {h.gimbal} angle on {h.output} ({100 * h.fraction:.0f} % of its χ²)" for h in self.gimbal_harmonics
            )
            out.append(f"gimbal-angle harmonics: {harmonics}")
        if self.earth_harmonics:
            earth = ", ".join(f"{h.output} harmonic {h.harmonic} (p = {h.p_value:.2g})" for h in self.earth_harmonics)
            out.append(f"Earth-rate harmonics: {earth}")
        return out

    def to_json(self) -> dict[str, Any]:
        """Return the JSON form (``signature`` of the diagnosis document)."""
        return {
            "outputs": [{"output": o.output, "chi2": o.chi2, "expected": o.expected, "share": o.share} for o in self.outputs],
            "positions": [{"position": p.position, "chi2": p.chi2, "expected": p.expected, "share": p.share} for p in self.positions],
            "gimbal_harmonics": [
                {"gimbal": h.gimbal, "harmonic": h.harmonic, "output": h.output, "fraction": h.fraction} for h in self.gimbal_harmonics
            ],
            "earth_harmonics": [{"output": h.output, "harmonic": h.harmonic, "p_value": h.p_value} for h in self.earth_harmonics],
        }

    @classmethod
    def from_json(cls, document: Any, path: Any = None, where: str = "signature") -> ResidualSignature:
        """Read the form :meth:`to_json` writes (:class:`~stableins.errors.InputError` naming the field otherwise)."""
        from stableins.discovery.fields import Reader, join

        r = Reader(path)
        d = r.mapping(document, where)

        def share(kind: type, name: str) -> Any:
            def read(value: Any, at: str) -> Any:
                item = r.mapping(value, at)
                return kind(
                    r.text(r.get(item, name, at), join(at, name)),
                    r.number(r.get(item, "chi2", at), join(at, "chi2"), nullable=False, minimum=0.0),
                    r.number(r.get(item, "expected", at), join(at, "expected"), nullable=False, minimum=0.0),
                    r.number(r.get(item, "share", at), join(at, "share"), nullable=False, minimum=0.0),
                )

            return read

        def gimbal(value: Any, at: str) -> GimbalHarmonic:
            item = r.mapping(value, at)
            return GimbalHarmonic(
                r.text(r.get(item, "gimbal", at), join(at, "gimbal")),
                r.integer(r.get(item, "harmonic", at), join(at, "harmonic")),
                r.text(r.get(item, "output", at), join(at, "output")),
                r.number(r.get(item, "fraction", at), join(at, "fraction"), nullable=False, minimum=0.0),
            )

        def earth(value: Any, at: str) -> EarthHarmonic:
            item = r.mapping(value, at)
            return EarthHarmonic(
                r.text(r.get(item, "output", at), join(at, "output")),
                r.integer(r.get(item, "harmonic", at), join(at, "harmonic")),
                r.number(r.get(item, "p_value", at), join(at, "p_value"), nullable=False, minimum=0.0),
            )

        return cls(
            outputs=r.items(r.get(d, "outputs", where), join(where, "outputs"), share(OutputShare, "output")),
            positions=r.items(r.get(d, "positions", where), join(where, "positions"), share(PositionShare, "position")),
            gimbal_harmonics=r.items(r.get(d, "gimbal_harmonics", where), join(where, "gimbal_harmonics"), gimbal),
            earth_harmonics=r.items(r.get(d, "earth_harmonics", where), join(where, "earth_harmonics"), earth),
        )


def laboratory_columns(readings: NDArray[np.float64], base_attitude: Sequence[float], configuration: Any) -> NDArray[np.float64]:
    """Return the six columns (``P·3``, 6) of an output along a direction fixed in the laboratory other than the vertical.

    Column ``(j, a)``: output ``a``'s direction cosine with the local-level axis ``j`` (north, east),
    ``(C_n^p)_{aj}`` with ``C_n^p = C_b^p(readings) C_n^b`` (docs/conventions.md), on output ``a`` only, rows in the
    dwell problem's order (position-major, outputs x, y, z).  Module docstring.
    """
    from stableins.conventions import dcm_body_to_platform, dcm_nav_to_body

    r = np.asarray(readings, dtype=float)
    c = dcm_body_to_platform(r[:, 0], r[:, 1], r[:, 2], configuration=configuration) @ dcm_nav_to_body(*base_attitude)
    p = r.shape[0]
    columns = []
    for j in (0, 1):
        for a in range(3):
            column = np.zeros((p, 3))
            column[:, a] = c[:, a, j]
            columns.append(column.reshape(-1))
    return np.stack(columns, axis=1)


def residual_signature(
    diagnosis: Diagnosis,
    readings: NDArray[np.float64] | None = None,
    earth_harmonics: Sequence[tuple[str, int, float]] = (),
) -> ResidualSignature:
    """Return the signature of a diagnosis' residual (module docstring).

    Parameters
    ----------
    diagnosis : Diagnosis
        The residuals and their 1σ per position and output, and the fit's degrees of freedom.
    readings : ndarray (P, 3), optional
        Device dwells: the mean gimbal-angle readings (platform, inner, middle) of each position [rad].
    earth_harmonics : sequence of (output, harmonic, p)
        System records: the flagged Earth-rate harmonics.
    """
    z = np.asarray(diagnosis.normalized, dtype=float)
    p, c = z.shape
    nu = max(int(diagnosis.result.dof), 0)
    per_output = np.sum(z**2, axis=0)
    per_position = np.sum(z**2, axis=1)
    expected_output = nu * p / max(p * c, 1)
    expected_position = nu * c / max(p * c, 1)
    excess_o = np.maximum(per_output - expected_output, 0.0)
    excess_p = np.maximum(per_position - expected_position, 0.0)
    outputs = tuple(
        OutputShare(name, float(x), float(expected_output), float(e / excess_o.sum()) if excess_o.sum() > 0 else 0.0)
        for name, x, e in zip(diagnosis.outputs, per_output, excess_o, strict=True)
    )
    carrying = tuple(o.output for o in outputs if o.share >= CARRYING_SHARE)
    order = [int(i) for i in np.argsort(-excess_p) if excess_p[i] > 0][:SHOWN]
    positions = tuple(
        PositionShare(diagnosis.position_labels[i], float(per_position[i]), float(expected_position), float(excess_p[i] / excess_p.sum()))
        for i in order
    )
    return ResidualSignature(
        outputs=outputs,
        positions=positions,
        gimbal_harmonics=() if readings is None else _gimbal_harmonics(z, np.asarray(readings, dtype=float), diagnosis.outputs, carrying),
        earth_harmonics=tuple(EarthHarmonic(name, int(k), float(pv)) for name, k, pv in earth_harmonics),
    )


def _gimbal_harmonics(
    z: NDArray[np.float64], readings: NDArray[np.float64], outputs: Sequence[str], carrying: Sequence[str]
) -> tuple[GimbalHarmonic, ...]:
    """Return the gimbal-angle harmonics that take much of the χ² of an output carrying the residual, largest first.

    Much: more than three times the chance share of two columns (``2/P``); ``carrying``: the outputs searched.
    """
    p = z.shape[0]
    found: list[GimbalHarmonic] = []
    for g, gimbal in enumerate(GIMBAL_NAMES):
        for k in GIMBAL_HARMONICS:
            x = np.stack([np.cos(k * readings[:, g]), np.sin(k * readings[:, g])], axis=1)
            if np.linalg.matrix_rank(x, tol=1e-9) == 0:
                continue
            fitted = x @ np.linalg.lstsq(x, z, rcond=None)[0]
            for a, name in enumerate(outputs):
                if name not in carrying:
                    continue
                total = float(z[:, a] @ z[:, a])
                fraction = float(fitted[:, a] @ fitted[:, a]) / total if total > 0 else 0.0
                if fraction > 3.0 * 2.0 / p:
                    found.append(GimbalHarmonic(gimbal, k, name, fraction))
    found.sort(key=lambda h: -h.fraction)
    return tuple(found[:SHOWN])
