r"""Commanded platform orientations and indexing mid-record by torquing (system level).

A space-stable platform is moved in inertial space only through its gyros: the torquers add a
commanded rate ``ω_cmd`` to the platform's inertial rate, and the gimbal servos follow.  With the
gyro drift ``ε^p`` (the stabilization loop nulls the gyro output, so the platform turns at
``−ε^p``) and a g-sensitive gyro error ``D_g f^p`` the platform's inertial rate in its own frame is

.. math::
    \omega_{ip}^p = \omega_{cmd}^p(t) + w(t), \qquad w = -(\varepsilon^p(t) + D_g f^p)

(:func:`stableins.conventions.platform_drift_rate`), ``f^p`` of the true, drifted orientation (the gyros sense
the specific force along their own axes; :meth:`IndexedMotion.orientation`).

Write the platform attitude as ``C_i^p(t) = T(t)\,X(t)\,C_i^{p_0}`` where ``T`` is the commanded
rotation alone: the product, in time order, of one frame rotation per turn of
:class:`stableins.turns.PlatformTurn`, ``T = R_{a_k}(ψ_k) ⋯ R_{a_1}(ψ_1)``, each about its axis
``a_k`` in the platform frame, so that ``\dot T = -[\omega_{cmd}\times] T``.  Then
``\dot C = -[\omega_{ip}\times] C`` leaves

.. math::
    \dot X = -[(T^T w)\times]\, X \quad\Rightarrow\quad X(t) = \mathrm{rot}(\theta), \quad
    \dot\theta = T^T w + \tfrac12\, \theta \times T^T w + O(\theta^2 w)

(Bortz 1971): the sum ``∫ T^T w`` alone is exact only while the direction of ``T^T w`` is fixed; when it
turns (a hold after an index, a g-sensitive drift) the drift rotations compose, and the second-order term
matters to an estimator that resolves the drift to 1e-7 °/h (issue 18: ``½|θ₁||w|`` ≈ 1e-12 rad/s after
12 h of 0.001 °/h); the term left out is third order (~1e-15 rad/s after a day).  Large commanded
angles are exact; the drift is integrated in the frame of the platform before the turns, so a drift
during a turn and a drift after it act about the right axes.  ``C_n^p = T X C_{n_0}^{p_0}
\exp(\Omega t[u\times])`` as in :mod:`stableins.simulator.system`.  The integral is the trapezoid rule
on the sample clock (exact for a constant drift while ``T`` is constant, ~1e-12 rad per 180° turn at
10 Hz), carried from chunk to chunk.

The readings are the exact inverse kinematics of ``C_b^p``
(:meth:`stableins.platform.GimbalPlatform.actual_from_dcm`) on the branch of the initial
orientation, made continuous by whole revolutions counted from sample to sample (so a turn of any
size keeps the readings continuous, and the samples do not depend on the chunking).  A record that
brings the inner gimbal within 0.06° of ±90° (the lock of the three-gimbal chain) is refused.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from stableins.conventions import EARTH_RATE, earth_rate_nav, platform_drift_rate, skew
from stableins.platform import GimbalPlatform, rotation_about
from stableins.turns import IndexAxis, PlatformTurn, check_turns

#: Absolute cosine of the inner gimbal angle below which the three-gimbal chain is at lock.
LOCK_COSINE = 1e-3


def earth_rotation(axis: NDArray[np.float64], time: NDArray[np.float64]) -> NDArray[np.float64]:
    """``C_{n(t)}^{n_0} = exp(ω_ie t [u×])`` (n, 3, 3) for ``axis = [u×]``."""
    theta = EARTH_RATE * np.asarray(time, dtype=float)
    return np.eye(3) + np.sin(theta)[:, None, None] * axis + (1.0 - np.cos(theta))[:, None, None] * (axis @ axis)


def in_frame(rotation: NDArray[np.float64], vectors: NDArray[np.float64]) -> NDArray[np.float64]:
    """``Rᵀ v`` for each sample (n, 3): vectors of the platform frame in the frame before the rotations ``R`` (n, 3, 3)."""
    return np.einsum("nji,nj->ni", rotation, vectors)


class DriftIntegral:
    r"""The rotation vector ``θ`` of ``X`` with ``\dot X = -[r\times] X``, ``X(0) = I``, sample by sample, carried across chunks.

    ``\dot\theta = r + \tfrac12\, \theta \times r`` (Bortz 1971, second order; the term left out is
    ``\tfrac1{12}\, \theta \times (\theta \times r)``), the trapezoid rule on the sample clock; the sums run
    sequentially from the carried state, so the samples do not depend on the chunking.  :meth:`angle` evaluates the
    next samples from the state (callable again, e.g. a corrector's second pass); :meth:`advance` commits the last
    evaluation.

    Parameters
    ----------
    rate : float
        Sample rate [Hz].
    """

    def __init__(self, rate: float) -> None:
        self.dt = 1.0 / float(rate)
        self._integral = np.zeros(3)  # θ up to the last committed sample (Bortz, second order)
        self._first_order = np.zeros(3)  # ∫ r dt up to the last committed sample
        self._last_integrand: NDArray[np.float64] | None = None
        self._pending: tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]] | None = None

    def angle(self, integrand: NDArray[np.float64]) -> NDArray[np.float64]:
        """``θ`` (n, 3) at the next samples, for the rate ``r`` (n, 3) [rad/s] at them (the first call's first sample is ``t = 0``)."""
        previous = integrand[0] if self._last_integrand is None else self._last_integrand
        steps = 0.5 * self.dt * (np.vstack([previous[None, :], integrand[:-1]]) + integrand)
        if self._last_integrand is None:
            steps[0] = 0.0  # the first sample of the record is t = 0
        first = np.cumsum(np.vstack([self._first_order[None, :], steps]), axis=0)[1:]  # sequential sums: chunking-proof
        before = np.vstack([self._first_order[None, :], first[:-1]])
        # Bortz: θ' = r + ½ θ × r, so that the drift rotations compose (second order) when r turns
        cumulative = np.cumsum(np.vstack([self._integral[None, :], steps + 0.5 * np.cross(before, steps)]), axis=0)[1:]
        self._pending = (cumulative[-1].copy(), first[-1].copy(), integrand[-1].copy())
        return cumulative

    def advance(self) -> None:
        """Commit the last :meth:`angle` evaluation: the next call continues after its samples."""
        assert self._pending is not None
        self._integral, self._first_order, self._last_integrand = self._pending
        self._pending = None


class IndexedMotion:
    """Orientation of a platform started at a commanded orientation and indexed by the given turns.

    Parameters
    ----------
    platform : GimbalPlatform
        The true platform (zero offsets, senses, base, non-orthogonality, sensor errors).
    nav_to_platform_0 : ndarray (3, 3)
        ``C_n^p`` at ``t = 0``.
    turns : sequence of PlatformTurn
        In time order, not overlapping.
    latitude : float
        [rad] (the Earth's turn ``C_{n(t)}^{n_0} = exp(Ωt[u×])``, :func:`earth_rotation`).
    initial_actual : ndarray (3,)
        Actual gimbal angles at ``t = 0`` (chooses the branch and the revolution count).
    rate : float
        Sample rate [Hz].
    """

    def __init__(
        self,
        platform: GimbalPlatform,
        nav_to_platform_0: NDArray[np.float64],
        turns: Sequence[PlatformTurn],
        *,
        latitude: float,
        initial_actual: NDArray[np.float64],
        rate: float,
    ) -> None:
        check_turns(turns, np.inf)
        self.platform = platform
        self.nav_to_platform_0 = np.asarray(nav_to_platform_0, dtype=float)
        self.earth_axis = skew(earth_rate_nav(latitude) / EARTH_RATE)
        self.turns = tuple(turns)
        self.dt = 1.0 / float(rate)
        self.nav_to_body = platform.dcm_nav_to_body()
        self.alternate_branch = bool(np.cos(platform.configuration.senses[1] * initial_actual[1]) < 0.0)
        self.axes = self._resolve_axes()
        self._previous_actual = np.asarray(initial_actual, dtype=float).copy()
        self._drift = DriftIntegral(rate)

    # ------------------------------------------------------------------ commanded rotation
    def _resolve_axes(self) -> tuple[NDArray[np.float64], ...]:
        """Each turn's axis in the platform frame at its start (drift-free commanded orientation)."""
        axes: list[NDArray[np.float64]] = []
        for k, turn in enumerate(self.turns):
            start = np.array([turn.start])
            before = self._commanded(start, axes, upto=k)
            free = before @ self.nav_to_platform_0 @ earth_rotation(self.earth_axis, start)
            actual = self._actual(free @ self.nav_to_body.T)[0]
            gimbal = 0 if turn.axis is IndexAxis.PLATFORM else 2
            axis = self.platform.angular_rate(actual, np.eye(3)[gimbal])
            axes.append(axis / np.linalg.norm(axis))
        return tuple(axes)

    def _commanded(self, time: NDArray[np.float64], axes: Sequence[NDArray[np.float64]], upto: int) -> NDArray[np.float64]:
        rotation = np.broadcast_to(np.eye(3), (len(time), 3, 3)).copy()
        for turn, axis in zip(self.turns[:upto], axes, strict=False):
            psi = turn.angle_at(time)
            rotation = rotation_about(psi[:, None] * axis[None, :]) @ rotation
        return rotation

    def commanded(self, time: NDArray[np.float64]) -> NDArray[np.float64]:
        """``T(t)`` (n, 3, 3): the commanded rotation of the platform frame."""
        return self._commanded(time, self.axes, len(self.turns))

    # ------------------------------------------------------------------ orientation
    def orientation(
        self, time: NDArray[np.float64], drift: NDArray[np.float64], *, g_sensitivity: NDArray[np.float64], gravity: float
    ) -> NDArray[np.float64]:
        """Return the true ``C_n^p`` (n, 3, 3) at the next samples ``time`` (consecutive, continuing the last call).

        ``drift``: ``ε^p(t)`` (n, 3) [rad/s]; ``g_sensitivity``: ``D_g`` (3, 3) [rad/s per m/s²], with ``f^p`` of the
        true (drifted) orientation: a predictor with ``f^p`` of the drift-free orientation, then a corrector with
        ``f^p`` of the predicted one (the predictor's error, ``D_g (θ × f)`` ≈ ``|D_g g| |θ|``, would be 1e-12 rad/s
        after a day of 0.002 °/h/g, whose own ``θ`` swings by ``|D_g g|/Ω`` ≈ 1e-4 rad; the corrector leaves
        ``|D_g g|² |θ| /Ω``).
        """
        commanded = self.commanded(time)
        tail = self.nav_to_platform_0 @ earth_rotation(self.earth_axis, time)
        free = commanded @ tail
        cumulative = self._drift.angle(in_frame(commanded, platform_drift_rate(drift, g_sensitivity, -gravity * free[:, :, 2])))
        if np.any(g_sensitivity):
            predicted = commanded @ rotation_about(cumulative) @ tail
            cumulative = self._drift.angle(in_frame(commanded, platform_drift_rate(drift, g_sensitivity, -gravity * predicted[:, :, 2])))
        self._drift.advance()
        return commanded @ rotation_about(cumulative) @ tail

    # ------------------------------------------------------------------ readings
    def _actual(self, body_to_platform: NDArray[np.float64]) -> NDArray[np.float64]:
        """Actual gimbal angles on the branch of the initial orientation (wrapped)."""
        actual = self.platform.actual_from_dcm(body_to_platform)
        if self.alternate_branch:
            s = np.asarray(self.platform.configuration.senses[:3], dtype=float)
            a, b, c = (s * actual).T
            alternate = s * np.stack([a + np.pi, np.pi - b, c + np.pi], axis=-1)
            actual = self.platform.actual_from_dcm(body_to_platform, initial=alternate)
        return actual

    def readings(self, nav_to_platform: NDArray[np.float64]) -> NDArray[np.float64]:
        """Noise-free, continuous angle-sensor readings of the next samples' orientations ``C_n^p``."""
        actual = self._actual(nav_to_platform @ self.nav_to_body.T)
        inner = np.cos(self.platform.configuration.senses[1] * actual[:, 1])
        if np.any(np.abs(inner) < LOCK_COSINE):
            raise ValueError("the commanded orientations bring the inner gimbal to ±90° (gimbal lock): choose other turns")
        # whole revolutions from sample to sample (integers: the same for any chunking)
        first = np.round((self._previous_actual - actual[0]) / (2 * np.pi)).astype(np.int64)
        steps = -np.round(np.diff(actual, axis=0) / (2 * np.pi)).astype(np.int64)
        revolutions = first + np.vstack([np.zeros((1, 3), dtype=np.int64), np.cumsum(steps, axis=0)])
        actual = actual + 2 * np.pi * revolutions
        self._previous_actual = actual[-1].copy()
        return self.platform.readings_from_actual(actual)


def inner_gimbal_lock(
    platform: GimbalPlatform,
    turns: Sequence[PlatformTurn],
    duration: float,
    *,
    latitude: float,
    initial_readings: Sequence[float],
    rate: float,
) -> float | None:
    r"""First time [s] at which the commanded orientations bring the inner gimbal to lock, or None if they never do.

    The drift-free orientation ``C_n^p(t) = T(t) C_n^{p_0} \exp(Ωt[u×])`` of :class:`IndexedMotion` (the platform held
    in inertial space from ``initial_readings`` and indexed by ``turns``, the Earth turning under it) on a 1-s grid in
    the holds and on the record's clock (``rate``, at least 100 Hz) during the turns; lock as in
    :meth:`IndexedMotion.readings`, ``|cos α₂| <`` :data:`LOCK_COSINE`.  Between grid points ``sin α₂ = −M₂₁`` moves
    at most as fast as the platform turns relative to the base, so the grid misses a lock by less than
    ``(ω h)²/8`` in ``sin α₂`` (3e-8 at the turn's 10°/s and 100 Hz; 7e-10 in a hold), against the band
    ``1 − \sqrt{1 − LOCK\_COSINE^2}`` = 5e-7.  What a procedure asks of a platform, checked before it moves
    (:func:`stableins.runs.start_run`); the world itself refuses a lock sample by sample.
    """
    readings = np.asarray(initial_readings, dtype=float)
    motion = IndexedMotion(
        platform,
        platform.dcm_nav_to_platform(readings),
        turns,
        latitude=latitude,
        initial_actual=platform.actual_angles(readings),
        rate=rate,
    )
    spacing = min(1.0 / rate, 0.01)
    grid = [np.arange(0.0, duration, 1.0), np.array([duration])]
    grid += [np.arange(turn.start, min(turn.end, duration), spacing) for turn in turns]
    times = np.unique(np.concatenate(grid))
    for chunk in np.array_split(times, len(times) // (1 << 16) + 1):
        free = motion.commanded(chunk) @ motion.nav_to_platform_0 @ earth_rotation(motion.earth_axis, chunk)
        actual = motion._actual(free @ motion.nav_to_body.T)
        locked = np.flatnonzero(np.abs(np.cos(platform.configuration.senses[1] * actual[:, 1])) < LOCK_COSINE)
        if locked.size:
            return float(chunk[locked[0]])
    return None
