r"""System level: a static record of a space-stable INS, with INS error dynamics integrated in time.

The world
---------
The base is static at latitude ``L`` with the true attitude of
:meth:`stableins.platform.GimbalPlatform.dcm_nav_to_body` (survey plus tilt).  At
``t = 0`` the platform is commanded to the polar-alignment readings
(:func:`stableins.conventions.polar_alignment_readings`, platform angle ``-s1 St0``)
corrected with the *installed* zero offsets, and from then on held fixed in inertial
space by its gyros.  The local frame turns with the Earth, so

.. math::
    C_n^p(t) = C_{p_0}^{p}(t)\, C_{n_0}^{p_0}\, C_{n(t)}^{n_0},\qquad
    C_{n(t)}^{n_0} = \exp(\omega_{ie} t\,[u\times]),\ u = \omega_{ie}^n/\omega_{ie}

and the platform-axis reading falls as ``-s1 ω_ie t`` (``St = St0 + ω_ie t``,
:func:`stableins.conventions.earth_rate_angle`).  ``C_{p0}^p(t)`` is the platform drift:
the stabilization loop nulls the gyro outputs, so a gyro drift ``ε^p`` (output error,
constant in the platform frame, plus an optional gyro-case-rotation residual
``a (cos(2πt/P + φ), sin(2πt/P + φ), 0)``) turns the platform at ``-ε^p`` in inertial
space; g-sensitivity effects ``Dg_ab`` add the gyro error ``D_g f^p``, so the platform turns at
``w = −(ε^p + D_g f^p)`` (:func:`stableins.conventions.platform_drift_rate`) and the navigation
computer's attitude error is driven by the same total gyro error.  The gimbal readings
are the exact inverse kinematics of ``C_b^p = C_n^p C_b^n`` (continuous, not wrapped).
The accelerometers output :meth:`stableins.simulator.physics.Accelerometer.output` (the
simulator's own Eq. 6, not the estimators' model) of ``f^p = C_n^p (0, 0, -g)`` with the true
parameters and output effects, plus noise and quantization.

The navigation computer
-----------------------
It compensates the raw outputs with ``installed_calibration`` (exact inverse model,
:meth:`stableins.simulator.physics.Accelerometer.specific_force`), giving ``\hat f^p``; the
specific-force error in the navigation frame is
``Δf^n = C_p^n (\hat f^p − f^p)`` (noise included).  It keeps its platform-to-local
DCM ``C_p^{n'} = C_n^{n'} C_p^n`` with ``C_n^{n'} = I − [φ×]`` and outputs the attitude
``C_b^{n'} = C_p^{n'} \hat C_b^p`` where ``\hat C_b^p`` is
:func:`stableins.conventions.dcm_body_to_platform` of the measured readings plus the
installed offsets (so gimbal-offset residuals appear as constant attitude errors,
Wu et al. 2018 Eq. 28).  ``φ(0)`` is the initial misalignment (default 0: the
computer starts with the true platform orientation).

Error dynamics (static base, NED, ``v = 0``; Britting 1971 ch. 6; Titterton & Weston
2004 Sec. 12.3.1, ψ-angle form with ``C_n^{n'} = I − [φ×]``)::

    δL'  = δv_N / R
    δv_N' = Δf_N + g φ_E − 2Ω sinL δv_E − c δv_N
    δv_E' = Δf_E − g φ_N + 2Ω sinL δv_N + 2Ω cosL δv_D − c δv_E
    φ_N' = −Ω sinL δL − Ω sinL φ_E + δv_E / R − ε_N
    φ_E' =  Ω sinL φ_N + Ω cosL φ_D − δv_N / R − ε_E
    φ_D' = −Ω cosL δL − Ω cosL φ_E − tanL δv_E / R − ε_D
    δh'  = −δv_D − k1 δh
    δv_D' = Δf_D − 2Ω cosL δv_E − (2g/R) δh + k2 δh + b
    b'   = k3 δh

``−φ×f^n = (g φ_E, −g φ_N, 0)`` for ``f^n = (0, 0, −g)``; ``−2ω_ie×δv`` the Coriolis
terms; ``δω_in^n = (−Ω sinL δL + δv_E/R, −δv_N/R, −Ω cosL δL − tanL δv_E/R)``.  The
horizontal damping feeds ``−c (v − v_ref)``, ``v_ref = 0``, into the velocity
integration with ``c = 2 ζ ω_s``, ``ω_s = sqrt(g/R)``; per channel, neglecting the
Earth-rate couplings, ``δv_N = s Δf_N/(s² + c s + ω_s²)`` and
``φ_E = −(Δf_N/g) ω_s²/(s² + 2ζω_s s + ω_s²)``: pitch error ``−φ_E`` lags ``+Δf_N/g``,
roll error ``−φ_N`` lags ``−Δf_E/g``.  The vertical loop against an external height
reference gives ``(s³ + k1 s² + (k2 − 2ω_s²) s + k3) δh = −s Δf_D``.  The constants
are in ``site.damping`` (:func:`stableins.simulator.truth.damping_parameters`).

Numerics
--------
``x' = A x + B u`` is discretized exactly for inputs held over each sample (ZOH):
with ``A = V diag(μ) V⁻¹`` each mode obeys ``z_{k+1} = λ z_k + (e^{μ dt} − 1)/μ ·
(V⁻¹ B u_k)``, ``λ = e^{μ dt}``, run by :func:`scipy.signal.lfilter` per mode (a complex
first-order IIR) with its state carried between chunks.  Everything else is
vectorized per chunk, so memory is bounded by the chunk size and the samples do not
depend on it (noise is keyed by sample index, :mod:`stableins.simulator.noise`).
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from stableins.conventions import (
    EARTH_RATE,
    dcm_body_to_platform,
    earth_rate_nav,
    euler_from_dcm,
    platform_drift_rate,
    polar_alignment_readings,
    skew,
)
from stableins.platform import rotation_about
from stableins.schema import SYSTEM_COLUMNS
from stableins.simulator import effects as fx
from stableins.simulator.error_dynamics import ModalRecursion, error_dynamics
from stableins.simulator.indexing import DriftIntegral, IndexedMotion, in_frame
from stableins.simulator.noise import NoiseGenerator, Quantizer
from stableins.simulator.physics import GIMBAL_IDS, Accelerometer, SensorInputs
from stableins.simulator.truth import Truth
from stableins.turns import PlatformTurn, check_turns

TRUTH_COLUMNS = ("truth_phi_north", "truth_phi_east", "truth_phi_down", "truth_df_north", "truth_df_east", "truth_df_down")


class SystemWorld:
    """The system-level world of a truth at one sample rate (see the module docstring).

    Parameters
    ----------
    truth : Truth
    rate : float, optional
        Sample rate [Hz] (default ``truth.site.sample_rate``).
    seed : int, optional
        Seed of the random streams (default ``truth.seed``).
    earth_angle : float
        Earth-rate angle ``St0`` at ``t = 0`` [rad].
    initial_misalignment : sequence of 3 float
        ``φ(0)`` in NED [rad].
    initial_readings, turns : optional
        Commanded readings at ``t = 0`` [rad] (default: the polar alignment, corrected with the installed
        offsets) and :class:`stableins.turns.PlatformTurn` during the record (:mod:`stableins.simulator.indexing`).
    """

    def __init__(
        self,
        truth: Truth,
        rate: float | None = None,
        seed: int | None = None,
        earth_angle: float = 0.0,
        initial_misalignment: Sequence[float] = (0.0, 0.0, 0.0),
        *,
        initial_readings: Sequence[float] | None = None,
        turns: Sequence[PlatformTurn] = (),
    ) -> None:
        self.truth = truth
        self.rate = float(rate if rate is not None else truth.site.sample_rate)
        self.seed = int(truth.seed if seed is None else seed)
        site = truth.site
        self.latitude = site.latitude
        self.gravity = site.gravity
        self.damping = truth.damping_parameters()
        self.platform = truth.platform()
        self.configuration = truth.configuration
        s1 = self.configuration.senses[0]
        # polar alignment commanded with the installed offsets
        _, middle = polar_alignment_readings(self.latitude, self.configuration)
        nominal = np.array([-s1 * earth_angle, 0.0, middle])
        installed_offsets = np.array([truth.installed_calibration.get(g, 0.0) for g in GIMBAL_IDS])
        self.installed_offsets = installed_offsets
        self.initial_readings = nominal - installed_offsets if initial_readings is None else np.asarray(initial_readings, dtype=float)
        self.initial_actual = self.platform.actual_angles(self.initial_readings)
        self.nav_to_platform_0 = self.platform.dcm_nav_to_platform(self.initial_readings)
        self.nav_to_body = self.platform.dcm_nav_to_body()
        axis = earth_rate_nav(self.latitude) / EARTH_RATE
        k = skew(axis)
        self._ck, self._ck2 = self.nav_to_platform_0 @ k, self.nav_to_platform_0 @ k @ k
        # error model of the world and of the navigation computer
        values = dict(truth.parameters)
        values.update({key: v for key, v in truth.effects.items() if fx.CATALOGUE[key].kind == "output"})
        self._accelerometer = Accelerometer(values, fx.output_effects(truth.effects))
        # the INS compensates with its installed calibration: the standard terms and any installed output effects
        self._installed = dict(truth.installed_calibration)
        self._computer = Accelerometer(self._installed, fx.output_effects({k: v for k, v in self._installed.items() if k in fx.CATALOGUE}))
        self._needs_rates = fx.needs(truth.effects, "lever_")
        self._g_sensitivity = fx.g_sensitivity(truth.effects)
        drift = truth.gyro_drift
        self._drift = np.array([drift.get(a, 0.0) for a in "xyz"])
        self._case = (drift.get("case_amplitude", 0.0), drift.get("case_period", 480.0), drift.get("case_phase", 0.0))
        # noise and dynamics
        self.noise = NoiseGenerator(truth.noise, self.rate, self.seed)
        self.quantizer = Quantizer(self.noise, restart_each_block=False)
        A, B = error_dynamics(self.latitude, self.damping)
        self.A, self.B = A, B
        self.recursion = ModalRecursion.discretize(A, B, 1.0 / self.rate)
        x0 = np.zeros(9)
        x0[3:6] = np.asarray(initial_misalignment, dtype=float)
        self._z: NDArray[np.inexact[Any]] = self.recursion.to_modes @ x0
        self._g_drift = DriftIntegral(self.rate)  # the g-sensitive drift's rotation Z, composed on the drift's
        self._next = 0
        self._indexed = None  # a commanded start or indexing: the general kinematics of stableins.simulator.indexing
        if initial_readings is not None or turns:
            self._indexed = IndexedMotion(
                self.platform, self.nav_to_platform_0, turns, latitude=self.latitude, initial_actual=self.initial_actual, rate=self.rate
            )

    # --------------------------------------------------------------- world pieces
    def gyro_drift(self, time: NDArray[np.float64]) -> NDArray[np.float64]:
        """Gyro drift ``ε^p(t)`` [rad/s] (n, 3)."""
        eps = np.broadcast_to(self._drift, (len(time), 3)).copy()
        amplitude, period, phase = self._case
        if amplitude:
            arg = 2 * np.pi * time / period + phase
            eps[:, 0] += amplitude * np.cos(arg)
            eps[:, 1] += amplitude * np.sin(arg)
        return eps

    def _drift_angle(self, time: NDArray[np.float64]) -> NDArray[np.float64]:
        """``-∫_0^t ε^p dt`` (analytic)."""
        angle = -np.outer(time, self._drift)
        amplitude, period, phase = self._case
        if amplitude:
            omega = 2 * np.pi / period
            angle[:, 0] -= amplitude / omega * (np.sin(omega * time + phase) - np.sin(phase))
            angle[:, 1] += amplitude / omega * (np.cos(omega * time + phase) - np.cos(phase))
        return angle

    def _held(self, time: NDArray[np.float64]) -> NDArray[np.float64]:
        """``C_{n0}^{p0} exp(ω_ie t [u×])`` (n, 3, 3): the platform held in inertial space, the local frame turning."""
        theta = EARTH_RATE * time
        s, c = np.sin(theta), np.cos(theta)
        return self.nav_to_platform_0 + s[:, None, None] * self._ck + (1.0 - c)[:, None, None] * self._ck2

    def platform_orientation(self, time: NDArray[np.float64]) -> NDArray[np.float64]:
        """Return the true ``C_n^p(t)`` (n, 3, 3) of the inertially held platform turned by ``ε^p`` (no ``D_g``)."""
        dcm = self._held(time)
        if np.any(self._drift) or self._case[0]:
            dcm = rotation_about(self._drift_angle(time)) @ dcm
        return dcm

    def _g_sensitive_orientation(self, time: NDArray[np.float64]) -> NDArray[np.float64]:
        r"""Return ``C_n^p`` (n, 3, 3) with the g-sensitive drift ``−D_g f^p`` composed on the drift's rotation.

        With ``R = rot(−∫ε^p dt)`` (:meth:`_drift_angle`; exact for a constant drift) and ``C_n^p = R Z C_{n0}^{p0} E(t)``,
        the platform's kinematics ``\dot C = −[w×] C``, ``w = −(ε^p + D_g f^p)``, leave ``\dot Z = −[(Rᵀ w_g)×] Z`` with
        ``w_g = −D_g f^p``, ``f^p`` of the true (drifted) orientation.  ``Z`` is integrated by
        :class:`stableins.simulator.indexing.DriftIntegral` (second order; its angle is the wobble's ``g cosL |D_g|/Ω``,
        5e-5 rad for 0.001 °/h/g, so the third-order term is ~1e-17 rad/s) with a predictor (``f^p`` of ``R C_{n0}^{p0} E``)
        and a corrector (``f^p`` of the predicted ``Z``).  docs/simulator.md, "System level".
        """
        held = self._held(time)
        rotation = rotation_about(self._drift_angle(time))
        drifted = rotation @ held
        zeros = np.zeros(3)
        angle = self._g_drift.angle(in_frame(rotation, platform_drift_rate(zeros, self._g_sensitivity, -self.gravity * drifted[:, :, 2])))
        predicted = rotation @ rotation_about(angle) @ held
        angle = self._g_drift.angle(in_frame(rotation, platform_drift_rate(zeros, self._g_sensitivity, -self.gravity * predicted[:, :, 2])))
        self._g_drift.advance()
        return rotation @ rotation_about(angle) @ held

    def readings(self, nav_to_platform: NDArray[np.float64], time: NDArray[np.float64]) -> NDArray[np.float64]:
        """Angle-sensor readings (noise-free, continuous) of orientations ``C_n^p``."""
        s1 = self.configuration.senses[0]
        guess = self.initial_actual + np.outer(time, [-s1 * EARTH_RATE, 0.0, 0.0])
        body_to_platform = nav_to_platform @ self.nav_to_body.T
        actual = self.platform.actual_from_dcm(body_to_platform)  # closed form (+ Newton for non-orthogonal axes)
        actual += 2 * np.pi * np.round((guess - actual) / (2 * np.pi))  # continuous, not wrapped
        return self.platform.readings_from_actual(actual)

    # --------------------------------------------------------------- generation
    def chunk(self, count: int, *, include_truth: bool = False) -> dict[str, NDArray[np.float64]]:
        """Return the next ``count`` samples as columns of :data:`stableins.schema.SYSTEM_COLUMNS`."""
        start = self._next
        index = np.arange(start, start + count)
        time = index / self.rate
        truth = self.truth
        if self._indexed is not None:
            dcm = self._indexed.orientation(time, self.gyro_drift(time), g_sensitivity=self._g_sensitivity, gravity=self.gravity)
            readings = self._indexed.readings(dcm)
        else:
            dcm = self._g_sensitive_orientation(time) if np.any(self._g_sensitivity) else self.platform_orientation(time)
            readings = self.readings(dcm, time)
        f_p = -self.gravity * dcm[:, :, 2]
        temperature = truth.noise.temperature(time)
        zeros = np.zeros((count, 3))
        inputs = SensorInputs(
            specific_force=f_p,
            temperature=temperature - truth.site.reference_temperature,
            time=time,
            slew_direction=zeros,
            angular_rate=zeros if self._needs_rates else None,
            angular_acceleration=zeros if self._needs_rates else None,
        )
        f_a = self._accelerometer.output(f_p, inputs) + self.noise.accelerometer(start, count)
        f_a = self.quantizer(start, f_a)
        measured = readings + self.noise.angles(start, count)
        # navigation computer
        f_hat = self._computer.specific_force(f_a, inputs)
        df_n = np.einsum("nji,nj->ni", dcm, f_hat - f_p)
        eps_n = np.einsum("nji,nj->ni", dcm, -platform_drift_rate(self.gyro_drift(time), self._g_sensitivity, f_p))
        x, self._z = self.recursion.run(np.hstack([df_n, eps_n]), self._z)
        phi = x[:, 3:6]
        body_to_platform_hat = dcm_body_to_platform(
            measured[:, 0] + self.installed_offsets[0],
            measured[:, 1] + self.installed_offsets[1],
            measured[:, 2] + self.installed_offsets[2],
            0.0,
            self.configuration,
        )
        nav_to_body_computed = body_to_platform_hat.swapaxes(1, 2) @ dcm @ rotation_about(phi).swapaxes(1, 2)
        yaw, pitch, roll = euler_from_dcm(nav_to_body_computed)
        self._next += count
        out = {
            "time": time,
            "angle_platform": measured[:, 0],
            "angle_inner": measured[:, 1],
            "angle_middle": measured[:, 2],
            "f_x": f_a[:, 0],
            "f_y": f_a[:, 1],
            "f_z": f_a[:, 2],
            "velocity_north": x[:, 1],
            "velocity_east": x[:, 2],
            "velocity_down": x[:, 7],
            "roll": roll,
            "pitch": pitch,
            "heading": yaw,
            "temperature": temperature + self.noise.temperature_sensor(start, count),
        }
        out = {c.name: out[c.name] for c in SYSTEM_COLUMNS}
        if include_truth:
            for k, name in enumerate(("north", "east", "down")):
                out[f"truth_phi_{name}"] = phi[:, k]
                out[f"truth_df_{name}"] = df_n[:, k]
        return out


def system_record_chunks(
    truth: Truth,
    duration: float,
    rate: float | None = None,
    seed: int | None = None,
    chunk_samples: int = 1 << 16,
    *,
    earth_angle: float = 0.0,
    initial_misalignment: Sequence[float] = (0.0, 0.0, 0.0),
    include_truth: bool = False,
) -> Iterator[dict[str, NDArray[np.float64]]]:
    """Stream a static system-level record in chunks of ``chunk_samples`` (bounded memory).

    Parameters
    ----------
    truth : Truth
    duration : float
        Record length [s]; ``round(duration·rate)`` samples.
    rate : float, optional
        Sample rate [Hz] (default ``truth.site.sample_rate``).
    seed : int, optional
        Seed (default ``truth.seed``).
    chunk_samples : int
        Samples per yielded chunk; the samples do not depend on it.
    earth_angle : float
        ``St0`` [rad].
    initial_misalignment : sequence of float
        ``φ(0)`` [rad] (NED).
    include_truth : bool
        Also yield ``truth_phi_*`` and ``truth_df_*`` (the error states and the n-frame
        specific-force error) for validation.

    Yields
    ------
    dict of str to ndarray
        Columns named as :data:`stableins.schema.SYSTEM_COLUMNS`.
    """
    if chunk_samples < 1:
        raise ValueError("chunk_samples must be positive")
    world = SystemWorld(truth, rate, seed, earth_angle, initial_misalignment)
    yield from stream_world(world, duration, chunk_samples, include_truth=include_truth)


def stream_world(
    world: SystemWorld, duration: float, chunk_samples: int, *, include_truth: bool
) -> Iterator[dict[str, NDArray[np.float64]]]:
    """Yield ``duration`` [s] of ``world`` in chunks of ``chunk_samples``."""
    total = int(round(duration * world.rate))
    done = 0
    while done < total:
        n = min(chunk_samples, total - done)
        yield world.chunk(n, include_truth=include_truth)
        done += n


def indexed_record_chunks(
    truth: Truth,
    duration: float,
    turns: Sequence[PlatformTurn],
    *,
    rate: float | None = None,
    seed: int | None = None,
    chunk_samples: int = 1 << 16,
    initial_readings: Sequence[float] | None = None,
    include_truth: bool = False,
) -> Iterator[dict[str, NDArray[np.float64]]]:
    """Stream a system-level record of a platform indexed by torquing (bounded memory).

    As :func:`system_record_chunks` (``St0 = 0``, ``φ(0) = 0``), with ``turns``
    (:class:`stableins.turns.PlatformTurn`, in time order, ending within ``duration``) and, optionally, the
    commanded readings ``initial_readings`` [rad] at ``t = 0`` instead of the polar alignment.
    """
    if chunk_samples < 1:
        raise ValueError("chunk_samples must be positive")
    check_turns(turns, duration)
    world = SystemWorld(truth, rate, seed, initial_readings=initial_readings, turns=turns)
    yield from stream_world(world, duration, chunk_samples, include_truth=include_truth)


def simulate_system(
    truth: Truth,
    duration: float,
    rate: float | None = None,
    seed: int | None = None,
    **options,
) -> dict[str, NDArray[np.float64]]:
    """Return a whole (short) system-level record as one dict of columns.

    Options of :func:`system_record_chunks`; with ``turns`` or ``initial_readings`` those of
    :func:`indexed_record_chunks`.
    """
    if "turns" in options or "initial_readings" in options:
        pieces = list(indexed_record_chunks(truth, duration, options.pop("turns", ()), rate=rate, seed=seed, **options))
    else:
        pieces = list(system_record_chunks(truth, duration, rate, seed, **options))
    if not pieces:
        return {c.name: np.zeros(0) for c in SYSTEM_COLUMNS}
    return {name: np.concatenate([p[name] for p in pieces]) for name in pieces[0]}
