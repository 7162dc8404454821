r"""Horizontal error dynamics of a damped INS on a static base, and its transfer function.

The steady-state relation "attitude error = horizontal specific-force error / g" of
Wu et al. 2018 (Eq. 28) is the zero-frequency limit of a damped Schuler loop.  At the
Earth-rate harmonics the loop has gain and phase: for the uncoupled channel

.. math:: \frac{\delta\theta}{\Delta f_N/g} = \frac{\omega_s^2}{s^2 + 2\zeta\omega_s s + \omega_s^2},
          \qquad \arg = -\arctan\frac{2\zeta r}{1-r^2},\quad r = k\,\omega_{ie}/\omega_s

(3.4° at ζ = 0.5 for the 24 h harmonic, 6.8° for the 12 h one), which moves 6–12 % of
every sine coefficient into its cosine partner.  The Earth-rate and Coriolis couplings
change the lag by a further ~0.4° and add a 0.4 % cross-coupling between the channels,
so this module keeps them.

Model (phi-angle, true-frame error equations, Titterton & Weston 2004 §12.2, static
base ``v = 0``, NED, ``C_n^{n'} = I − [φ×]``, horizontal velocity damping ``−c δv``)::

    φ̇   = −ω_ie^n × φ + δω_ie^n + δω_en^n              (gyro errors left out: they are not an input here)
    δv̇_h = (f^n × φ)_h + Δf^n_h − (2 ω_ie^n × δv)_h − c δv_h
    δL̇  = δv_N / R

with ``f^n = (0, 0, −g)``, ``δω_ie^n = ω(−sinL δL, 0, −cosL δL)``,
``δω_en^n = (δv_E/R, −δv_N/R, −tanL δv_E/R)``, ``c = 2ζω_s``, ``ω_s = sqrt(g/R)``.
States ``(φ_N, φ_E, φ_D, δv_N, δv_E, δL)`` and, when the metadata give the vertical gains
``k1, k2, k3``, the height-aided third-order vertical channel (Widnall & Sinha 1980;
height error ``δh`` up, ``δv_D`` down, ``b`` the integrator)::

    δḣ   = −δv_D − k1 δh
    δv̇_D = Δf_D − 2ω cosL δv_E − (2g/R) δh + k2 δh + b
    ḃ    = k3 δh

which feeds the east channel through the Coriolis term ``+2ω cosL δv_D``.  This path is
not negligible: with the vertical error ``Δf_D`` at the Earth-rate harmonics it moves the
roll coefficients by up to ~2e-6 rad per 1e-4 of along-gravity error (measured against
the truth simulator), so ``Δf_D/g = −u·δ`` (known from the harmonic states) is a third
input of the loop.

For a level, north-pointing body the attitude errors are ``δpitch = −φ_E``,
``δroll = −φ_N`` (:mod:`stableins.conventions`); the quasi-static limit is
``δpitch = Δf_N/g``, ``δroll = −Δf_E/g``.  The transfer matrix returned here maps the
*quasi-static* attitude errors ``(Δf_N/g, −Δf_E/g)`` to the observed ones, so it is the
identity at low frequency.

The Earth-rate mode (eigenvalues ``±jω_ie``) of this model is not controllable from the
specific-force input, so the response at exactly the Earth rate is finite; it is computed
from the modal expansion over the controllable modes only.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from stableins.conventions import EARTH_RADIUS, EARTH_RATE, attitude_error_from_misalignment, heading_to_north_pointing
from stableins.errors import InputError

#: Names of the loop states, in order.
LOOP_STATES = (
    "phi_north",
    "phi_east",
    "phi_down",
    "velocity_north",
    "velocity_east",
    "latitude",
    "height",
    "velocity_down",
    "vertical_integrator",
)

#: The misalignment states ``φ_N, φ_E, φ_D`` and the horizontal velocity errors, as indices into :data:`LOOP_STATES`.
ANGLE_STATES = (0, 1, 2)
VELOCITY_STATES = (3, 4)


@dataclass(frozen=True)
class DampingLoop:
    """Linear horizontal error dynamics of a velocity-damped INS on a static base.

    Attributes
    ----------
    latitude : float
        Geodetic latitude [rad].
    gravity : float
        Local gravity [m/s²].
    zeta : float
        Damping ratio of the horizontal loop (0 = undamped Schuler loop).
    earth_radius : float
        Radius used in the error dynamics [m].
    schuler_frequency : float
        ω_s [rad/s]; the damping gain is ``c = 2 ζ ω_s``.
    earth_rate : float
        ω_ie [rad/s].
    couplings : bool
        Keep the Earth-rate and Coriolis couplings (default).  ``False`` gives two
        independent second-order channels.
    vertical_gains : (k1, k2, k3) or None
        Gains of the height-aided vertical loop; ``None`` leaves the vertical channel out.
    """

    latitude: float
    gravity: float
    zeta: float
    earth_radius: float = EARTH_RADIUS
    schuler_frequency: float = float("nan")
    earth_rate: float = EARTH_RATE
    couplings: bool = True
    vertical_gains: tuple[float, float, float] | None = None

    def __post_init__(self) -> None:
        if not np.isfinite(self.schuler_frequency):
            object.__setattr__(self, "schuler_frequency", float(np.sqrt(self.gravity / self.earth_radius)))
        if not (0.0 <= self.zeta < 10.0):
            raise ValueError(f"damping ratio zeta must be in [0, 10), got {self.zeta}")

    @classmethod
    def from_metadata(cls, damping: Mapping[str, float], latitude: float, gravity: float, *, couplings: bool = True) -> DampingLoop:
        """Build the loop from ``SiteMetadata.damping``.

        Keys: ``zeta`` (required), ``schuler_frequency`` [rad/s] and ``earth_radius`` [m]
        (optional: ``ω_s = sqrt(g/R)`` with ``R = conventions.EARTH_RADIUS``).  A
        ``damping_coefficient`` ``c`` [1/s] may be given instead of ``zeta``.
        """
        if damping is None or not ({"zeta", "damping_coefficient", "horizontal_gain"} & set(damping)):
            raise InputError(
                "the system record's metadata has no damping parameters; the attitude harmonics cannot be "
                "compensated for the damping loop's gain and phase",
                field="damping.zeta",
                expected="the horizontal damping ratio 'zeta' (and optionally 'schuler_frequency', 'earth_radius')",
            )
        radius = float(damping.get("earth_radius", damping.get("R", EARTH_RADIUS)))
        omega_s = float(damping.get("schuler_frequency", damping.get("omega_s", np.sqrt(gravity / radius))))
        if "zeta" in damping:
            zeta = float(damping["zeta"])
        else:
            zeta = float(damping.get("damping_coefficient", damping.get("horizontal_gain", np.nan))) / (2.0 * omega_s)
        if not np.isfinite(zeta) or zeta < 0:
            raise InputError(f"damping ratio must be a finite non-negative number, got {zeta}", field="damping.zeta")
        gains = None
        if all(k in damping for k in ("k1", "k2", "k3")):
            gains = (float(damping["k1"]), float(damping["k2"]), float(damping["k3"]))
        return cls(
            latitude=float(latitude),
            gravity=float(gravity),
            zeta=zeta,
            earth_radius=radius,
            schuler_frequency=omega_s,
            couplings=couplings,
            vertical_gains=gains,
        )

    # ------------------------------------------------------------------ model
    @property
    def damping_coefficient(self) -> float:
        """``c = 2 ζ ω_s`` [1/s]."""
        return 2.0 * self.zeta * self.schuler_frequency

    @property
    def n_states(self) -> int:
        """Return the number of states: 9 with the vertical channel, 6 without."""
        return 9 if self.vertical_gains is not None else 6

    def state_matrix(self) -> NDArray[np.float64]:
        """Return ``A`` of ``ẋ = A x + B u`` for the states :data:`LOOP_STATES` (first six without the vertical channel)."""
        w = self.earth_rate if self.couplings else 0.0
        s, c = np.sin(self.latitude), np.cos(self.latitude)
        r = self.earth_radius
        g = self.schuler_frequency**2 * r  # so that ω_s² = g/R exactly as configured
        k = 1.0 if self.couplings else 0.0
        a = np.zeros((self.n_states, self.n_states))
        # φ̇ = −ω×φ + δω_ie + δω_en,  ω×φ = ω(s φ_E, −s φ_N − c φ_D, c φ_E)
        a[0, 1], a[0, 5], a[0, 4] = -w * s, -w * s, 1.0 / r
        a[1, 0], a[1, 2], a[1, 3] = w * s, w * c, -1.0 / r
        a[2, 1], a[2, 5], a[2, 4] = -w * c, -w * c, -k * np.tan(self.latitude) / r
        # δv̇ = f×φ + Δf − 2ω×δv − c δv,  f×φ = (g φ_E, −g φ_N, 0)
        a[3, 1], a[3, 4], a[3, 3] = g, -2.0 * w * s, -self.damping_coefficient
        a[4, 0], a[4, 3], a[4, 4] = -g, 2.0 * w * s, -self.damping_coefficient
        a[5, 3] = 1.0 / r
        if self.vertical_gains is not None:
            k1, k2, k3 = self.vertical_gains
            a[4, 7] = 2.0 * w * c  # east Coriolis from δv_D
            a[6, 7], a[6, 6] = -1.0, -k1
            a[7, 4], a[7, 6], a[7, 8] = -2.0 * w * c, -2.0 * g / r + k2, 1.0
            a[8, 6] = k3
        return a

    def input_matrix(self) -> NDArray[np.float64]:
        """``B`` for the input ``u = (Δf_N/g, −Δf_E/g, Δf_D/g)`` (quasi-static pitch and roll errors, vertical error)."""
        g = self.schuler_frequency**2 * self.earth_radius
        b = np.zeros((self.n_states, 3))
        b[3, 0] = g
        b[4, 1] = -g
        if self.vertical_gains is not None:
            b[7, 2] = g
        return b

    def drift_input_matrix(self) -> NDArray[np.float64]:
        """``B_ε`` for a gyro drift ``ε^n`` [rad/s] in the n-frame: ``φ̇ = … − ε^n``."""
        b = np.zeros((self.n_states, 3))
        b[0, 0] = b[1, 1] = b[2, 2] = -1.0
        return b

    def drift_responses(
        self,
        time: NDArray[np.float64],
        earth_angle: NDArray[np.float64],
        *,
        rates: NDArray[np.float64] | None = None,
        states: Sequence[int] = (),
    ) -> NDArray[np.float64]:
        r"""Pitch and roll responses ``(n, 2, 3)`` to a unit constant gyro drift along each platform axis, from rest at ``time[0]``.

        With ``rates`` (n, 3) the drift along platform axis ``j`` is ``rates[:, j]`` [rad/s] at each time instead of 1
        (a drift that varies, e.g. the g-sensitive drift ``D_g f^p(t)``; linear between the times, as the unit drift).
        With ``states`` (indices into :data:`LOOP_STATES`) the responses ``(n, len(states), 3)`` of those states instead:
        ``(0, 1, 2)`` the misalignment ``φ_N, φ_E, φ_D`` (the azimuth error ``φ_D`` is not an output of the loop model;
        :func:`drift_curvature` needs it), ``(3, 4)`` the velocity errors.

        On the polar-aligned platform ``ε^n(t) = C_p^n(t) ε^p`` with ``C_p^n = (R3(−S) R2(π/2 + L))ᵀ``: the
        polar component is constant, the equatorial ones turn at the Earth rate and drive the undamped
        Earth-rate mode at resonance (a ``t·sin`` growth in the tilts).  Exact first-order-hold
        discretization on the given (uniform) grid, run mode by mode (:func:`modal_recursion` in the eigenbasis
        of the transition matrix; :meth:`_drift_responses_stepwise`, the plain recursion, is the reference).
        """
        from scipy.linalg import expm

        from stableins.conventions import dcm_body_to_platform

        t = np.asarray(time, dtype=float)
        dt = float(np.median(np.diff(t)))
        nav_to_platform = dcm_body_to_platform(-np.asarray(earth_angle, dtype=float), 0.0, np.pi / 2 + self.latitude)
        a, b = self.state_matrix(), self.drift_input_matrix()
        c = np.eye(self.n_states)[list(states)] if states else self.output_matrix()
        n = a.shape[0]
        big = np.zeros((n + 6, n + 6))
        big[:n, :n], big[:n, n : n + 3] = a * dt, b * dt
        big[n : n + 3, n + 3 :] = np.eye(3)
        e = expm(big)
        phi, gamma0, gamma1 = e[:n, :n], e[:n, n : n + 3], e[:n, n + 3 :]
        out = np.zeros((t.size, c.shape[0], 3))
        if t.size < 2:
            return out
        step = np.diff(t) / dt
        # x_{k+1} = Φ x_k + d_k from rest; in the eigenbasis of Φ each mode is a first-order recursion (lfilter)
        lam, vectors = np.linalg.eig(phi)
        if not np.linalg.cond(vectors) < 1e8:  # (nearly) defective: the plain recursion
            scaled = nav_to_platform if rates is None else nav_to_platform * rates[:, :, None]
            return self._drift_responses_stepwise(t, scaled, phi, gamma0, gamma1, outputs=c)
        to_modes = np.linalg.inv(vectors)
        modal = []
        for j in range(3):
            eps_n = nav_to_platform[:, j, :]  # row j of C_n^p = C_p^n e_j
            if rates is not None:
                eps_n = eps_n * rates[:, j : j + 1]
            drive = step[:, None] * (eps_n[:-1] @ gamma0.T + np.diff(eps_n, axis=0) @ gamma1.T)
            modal.append(drive @ to_modes.T)
        z = modal_recursion(np.tile(lam, 3), np.concatenate(modal, axis=1))  # the three axes' modes side by side
        for j in range(3):
            out[1:, :, j] = (z[:, j * n : (j + 1) * n] @ (c @ vectors).T).real
        return out

    def _drift_responses_stepwise(
        self,
        t: NDArray[np.float64],
        nav_to_platform: NDArray[np.float64],
        phi: NDArray[np.float64],
        gamma0: NDArray[np.float64],
        gamma1: NDArray[np.float64],
        *,
        outputs: NDArray[np.float64] | None = None,
    ) -> NDArray[np.float64]:
        """:meth:`drift_responses` by the plain state recursion (reference; used when Φ is nearly defective)."""
        c = self.output_matrix() if outputs is None else outputs
        dt = float(np.median(np.diff(t)))
        out = np.zeros((t.size, c.shape[0], 3))
        for j in range(3):
            eps_n = nav_to_platform[:, j, :]
            x = np.zeros(phi.shape[0])
            for k in range(t.size):
                out[k, :, j] = c @ x
                if k + 1 < t.size:
                    step = (t[k + 1] - t[k]) / dt
                    x = phi @ x + step * (gamma0 @ eps_n[k] + gamma1 @ (eps_n[k + 1] - eps_n[k]))
        return out

    def output_matrix(self) -> NDArray[np.float64]:
        """``C`` for the output ``(δpitch, δroll) = (−φ_E, −φ_N)``."""
        c = np.zeros((2, self.n_states))
        c[0, 1] = -1.0
        c[1, 0] = -1.0
        return c

    def _controllable_modes(self) -> tuple[NDArray[np.complex128], NDArray[np.complex128], NDArray[np.complex128]]:
        cached = self.__dict__.get("_modes")  # the loop is immutable: decompose once
        if cached is None:
            cached = self._decompose()
            object.__setattr__(self, "_modes", cached)
        return cached

    def _decompose(self) -> tuple[NDArray[np.complex128], NDArray[np.complex128], NDArray[np.complex128]]:
        a, b, c = self.state_matrix(), self.input_matrix(), self.output_matrix()
        # Balance the states (angles ~ 1, velocities ~ R ω, latitude ~ 1) for a well-conditioned eigenproblem.
        v = self.earth_radius * self.schuler_frequency
        scale = np.array([1.0, 1.0, 1.0, v, v, 1.0, self.earth_radius, v, v * self.schuler_frequency])[: self.n_states]
        a_s = a * scale[None, :] / scale[:, None]
        b_s, c_s = b / scale[:, None], c * scale[None, :]
        eigenvalues, right = np.linalg.eig(a_s)
        left = np.linalg.inv(right)
        residue_in = left @ b_s  # (modes, inputs)
        residue_out = c_s @ right  # (outputs, modes)
        strength = np.linalg.norm(residue_in, axis=1) * np.linalg.norm(residue_out, axis=0)
        keep = strength > 1e-9 * strength.max()
        return eigenvalues[keep], residue_out[:, keep], residue_in[keep]

    def frequency_response(self, omega: float) -> NDArray[np.complex128]:
        r"""Transfer matrix ``G(jω)`` (2×3) from ``(Δf_N/g, −Δf_E/g, Δf_D/g)`` to ``(δpitch, δroll)``.

        ``G(jω) = Σ_i (C v_i)(w_i^H B) / (jω − λ_i)`` over the controllable and
        observable modes ``i``; ``G(0) = I`` for a damped loop.
        """
        eigenvalues, out, inp = self._controllable_modes()
        return np.einsum("om,mi->oi", out / (1j * omega - eigenvalues)[None, :], inp)

    def harmonic_matrix(self, harmonic: int) -> NDArray[np.float64]:
        r"""Real 4×4 map from quasi-static to observed harmonic coefficients.

        With ``u_j(t) = a_j cos(kS) + b_j sin(kS) = Re{(a_j − i b_j) e^{ikS}}`` and
        ``S = S_0 + ω_ie t``, the steady response is ``Re{G(ikω_ie)(a − ib) e^{ikS}}``.
        Ordering of both vectors: ``(pitch cos, pitch sin, roll cos, roll sin)``.
        """
        return self._real_map(harmonic, (0, 1))

    def vertical_harmonic_matrix(self, harmonic: int) -> NDArray[np.float64]:
        """Real 4×2 map from the ``(cos, sin)`` harmonic of ``Δf_D/g`` to ``(pitch cos, pitch sin, roll cos, roll sin)``."""
        return self._real_map(harmonic, (2,))

    def _real_map(self, harmonic: int, inputs: tuple[int, ...]) -> NDArray[np.float64]:
        g = self.frequency_response(harmonic * self.earth_rate)
        m = np.zeros((4, 2 * len(inputs)))
        for o in range(2):
            for j, i in enumerate(inputs):
                re, im = g[o, i].real, g[o, i].imag
                # (re + i im)(a − i b) = (re a + im b) − i (re b − im a)
                m[2 * o : 2 * o + 2, 2 * j : 2 * j + 2] = [[re, im], [-im, re]]
        return m

    def dc_gain(self) -> NDArray[np.float64]:
        """Steady response (2×3) to constant inputs (the Earth-rate and integrator modes are not excited)."""
        return self.frequency_response(0.0).real

    def transient_modes(self) -> NDArray[np.complex128]:
        """Return the controllable modes other than the Schuler ones (vertical channel): eigenvalues with ``Im ≥ 0``."""
        eigenvalues, _, _ = self._controllable_modes()
        schuler = self.schuler_modes()
        out = [m for m in eigenvalues if m.imag >= 0 and all(abs(m - s) > 1e-9 for s in schuler) and abs(m) > 2.5 * self.earth_rate]
        return np.array(sorted(out, key=lambda m: (m.real, m.imag)))

    def schuler_modes(self) -> NDArray[np.complex128]:
        """Eigenvalues (upper half plane) of the controllable oscillatory modes (the Schuler modes)."""
        eigenvalues, _, _ = self._controllable_modes()
        near = np.abs(np.abs(eigenvalues) - self.schuler_frequency) < 0.5 * self.schuler_frequency
        modes = eigenvalues[(eigenvalues.imag > 2.5 * self.earth_rate) & near]
        return np.sort_complex(modes)

    def simulate(
        self, time: NDArray[np.float64], forcing: NDArray[np.float64], initial_state: NDArray[np.float64] | None = None
    ) -> NDArray[np.float64]:
        """Exact response to ``(Δf_N/g, −Δf_E/g)`` sampled on a uniform grid, linear between samples.

        First-order-hold discretization (``expm`` of the augmented matrix).  Used by the
        tests of this module (the truth simulator has its own integrator).
        Returns ``(n, 2)``: ``(δpitch, δroll)``.
        """
        from scipy.linalg import expm

        dt = float(time[1] - time[0])
        a, b, c = self.state_matrix(), self.input_matrix(), self.output_matrix()
        forcing = np.asarray(forcing, dtype=float)
        b = b[:, : forcing.shape[1]]
        n, m = a.shape[0], b.shape[1]
        big = np.zeros((n + 2 * m, n + 2 * m))
        big[:n, :n], big[:n, n : n + m] = a * dt, b * dt
        big[n : n + m, n + m :] = np.eye(m)
        e = expm(big)
        phi, gamma0, gamma1 = e[:n, :n], e[:n, n : n + m], e[:n, n + m :]
        x = np.zeros(n) if initial_state is None else np.asarray(initial_state, dtype=float)
        out = np.empty((len(time), 2))
        for k in range(len(time)):
            out[k] = c @ x
            if k + 1 < len(time):
                x = phi @ x + gamma0 @ forcing[k] + gamma1 @ (forcing[k + 1] - forcing[k])
        return out


def modal_recursion(lam: NDArray[np.complex128] | NDArray[np.float64], drive: NDArray[Any]) -> NDArray[Any]:
    r"""First-order recursions ``z_k = λ_i z_{k−1} + d_k`` from rest (``z_0 = d_0``), one per column ``i`` of ``drive``.

    What :func:`scipy.signal.lfilter` ``([1], [1, −λ_i], d[:, i])`` computes, with its arithmetic: a complex
    product as ``(λ_r z_r − λ_i z_i, λ_r z_i + λ_i z_r)`` with each product rounded, then ``+ d_k``, so the numbers are
    its to the last bit; stepped over all columns at once in numpy.  Written out because importing
    :mod:`scipy.signal` imports :mod:`scipy.stats` (its peak finding), a second of ``calibrate system`` (issue 30).

    Parameters
    ----------
    lam : ndarray (n,)
        The modes' factors ``λ_i`` (complex, or real when every one is real).
    drive : ndarray (steps, n)
        The inputs ``d_k`` of each mode.

    Returns
    -------
    ndarray (steps, n)
        ``z``, complex unless ``lam`` and ``drive`` are both real.
    """
    steps = drive.shape[0]
    if not (np.iscomplexobj(lam) or np.iscomplexobj(drive)):
        out = np.empty(drive.shape)
        if steps:
            out[0] = drive[0]
        for k in range(1, steps):
            out[k] = lam * out[k - 1] + drive[k]
        return out
    lam_r, lam_i = np.real(lam), np.imag(lam)
    d_r, d_i = np.ascontiguousarray(np.real(drive), dtype=float), np.ascontiguousarray(np.imag(drive), dtype=float)
    z_r, z_i = np.empty(drive.shape), np.empty(drive.shape)
    if steps:
        z_r[0], z_i[0] = d_r[0], d_i[0]
    for k in range(1, steps):
        a_r, a_i = z_r[k - 1], z_i[k - 1]
        z_r[k] = (lam_r * a_r - lam_i * a_i) + d_r[k]
        z_i[k] = (lam_r * a_i + lam_i * a_r) + d_i[k]
    out_c = np.empty(drive.shape, dtype=complex)
    out_c.real, out_c.imag = z_r, z_i
    return out_c


def drift_columns(
    blocks: Mapping[str, NDArray[np.float64]],
    loop: DampingLoop,
    *,
    rates: Callable[[NDArray[np.float64]], NDArray[np.float64]] | None = None,
    states: Sequence[int] = (),
) -> NDArray[np.float64]:
    """Return the drift responses ``(n_blocks, 2, 3)`` of pitch and roll on the attitude block times.

    ``rates``: the drift per platform axis as a function of the Earth-rate angle on the grid [rad/s] (n, 3)
    (:meth:`DampingLoop.drift_responses`); None: a unit constant drift.  ``states``: the responses ``(n_blocks, k, 3)``
    of those loop states instead (:meth:`DampingLoop.drift_responses`).

    :meth:`DampingLoop.drift_responses` in units of :data:`DRIFT_SCALE`, simulated on a uniform grid of the blocks' step
    (at least :data:`DRIFT_GRID_SECONDS`) and interpolated linearly (the responses are smooth: over 60 s the Earth-rate
    input departs from a straight line by ``(ω_ie Δt)²/8 = 2e-6`` of itself, the Schuler oscillation by 2e-5).
    """
    t = blocks["time"]
    angle = np.unwrap(np.arctan2(blocks["sin"], blocks["cos"]))
    step = max(float(np.median(np.diff(t))) if t.size > 1 else 1.0, DRIFT_GRID_SECONDS)
    grid = np.arange(0.0, t[-1] + step, step)
    earth_angle = np.interp(grid, t, angle)
    responses = loop.drift_responses(grid, earth_angle, rates=None if rates is None else rates(earth_angle), states=states)
    out = np.empty((t.size, responses.shape[1], 3))
    for ch in range(responses.shape[1]):
        for j in range(3):
            out[:, ch, j] = np.interp(t, grid, responses[:, ch, j])
    return out * DRIFT_SCALE  # columns of the order of the others


def drift_curvature(phi: NDArray[np.float64], yaw: float) -> NDArray[np.float64]:
    r"""Return the second-order part ``(n, 2)`` of the north-pointing pitch and roll errors a misalignment ``φ`` causes.

    The navigation computer's attitude is the exact rotation ``C_n^{b'} = C_n^b \exp([φ×])``, and a level base's
    outputs are its Euler angles (:func:`stableins.conventions.attitude_error_from_misalignment`, rotated to the
    north-pointing pair by :func:`stableins.conventions.heading_to_north_pointing`): ``(−φ_E, −φ_N)`` to first order
    (the loop model's outputs, :meth:`DampingLoop.output_matrix`) plus products such as ``φ_D φ_N`` and ``φ_D φ_E``.
    Those are the even part of the map, ``½ (e(φ) + e(−φ))``, returned here (to fourth order).  They matter when a gyro
    drift across z_p turns the azimuth error ``φ_D`` far (0.027 rad in a day at 0.05 °/h: products of 5e-6 rad in
    pitch and roll at twice the Earth rate, several σ of a day's attitude coefficients; docs/system-calibration.md §9).
    A tilted base's outputs are the antisymmetric part of the relative DCM (:func:`stableins.conventions.misalignment_pitch_roll`),
    odd in ``φ``: no second order there.
    """
    angles = np.asarray(phi, dtype=float)
    even = 0.5 * (attitude_error_from_misalignment(angles, yaw) + attitude_error_from_misalignment(-angles, yaw))
    pitch, roll = heading_to_north_pointing(even[:, 1], even[:, 2], yaw)
    return np.stack([pitch, roll], axis=1)


def drift_curvature_removed(
    blocks: Mapping[str, NDArray[np.float64]], loop: DampingLoop, drift: NDArray[np.float64], *, yaw: float
) -> dict[str, NDArray[np.float64]]:
    """Return the attitude blocks of a level base with the second order of the drift's response taken out of pitch and roll.

    The loop's linear response to the drift ``ε_0`` (``drift`` [rad/s], platform frame) is removed by the attitude fit
    (its drift columns); what the linear model leaves is :func:`drift_curvature` of the misalignment that response
    builds (:func:`drift_columns` of :data:`ANGLE_STATES`), removed here.  ``ε_0`` is known to 1e-6 of itself from the gimbal
    readings, so the term's uncertainty (twice its size times that) is left out.  ``yaw``: the base's heading [rad].
    """
    phi = drift_columns(blocks, loop, states=ANGLE_STATES) @ (np.asarray(drift, dtype=float) / DRIFT_SCALE)
    curvature = drift_curvature(phi, yaw)
    out = dict(blocks)
    out["pitch"] = blocks["pitch"] - curvature[:, 0]
    out["roll"] = blocks["roll"] - curvature[:, 1]
    return out


#: Smallest step of the grid the drift responses are computed on [s] (:func:`drift_columns`).
DRIFT_GRID_SECONDS = 60.0

#: Unit of the drift columns [rad/s] (about 0.002 °/h).
DRIFT_SCALE = 1e-8
