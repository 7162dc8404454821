r"""Fourier fit of the level attitude errors, compensated for the damping loop.

Derivation (docs/system-calibration.md §2).  Mapping the first-order platform-frame
error ``δ = Δf^p/g`` of :mod:`~stableins.estimators.system.harmonics` to the n-frame through the gimbal angles of a
polar-aligned platform on a level, north-pointing base,
``C_p^n = R2(−(π/2 + L)) R3(S)``, gives

.. math::
    \Delta f_N/g = -\sin L\,(\cos S\,\delta_x + \sin S\,\delta_y) + \cos L\,\delta_z,\qquad
    \Delta f_E/g = -\sin S\,\delta_x + \cos S\,\delta_y .

The quasi-static attitude errors ``δθ = Δf_N/g`` (pitch) and ``δφ = −Δf_E/g`` (roll) are

.. math::
    \delta\theta &= \cos L\,[b_z - \sin L(D_z - \tfrac{D_x+D_y}{2})]
        + (-A\sin L + \Delta\beta_{zy}\cos^2 L)\cos S + (-B\sin L - \Delta\beta_{zx}\cos^2 L)\sin S\\
        &\quad + \sin L\cos L\,\tfrac{D_x-D_y}{2}\cos 2S + \sin L\cos L\,\tfrac{\Delta\beta_{yz}-\Delta\beta_{xz}}{2}\sin 2S\\
    \delta\phi &= \cos L\,\tfrac{\Delta\beta_{xz}+\Delta\beta_{yz}}{2} + A\sin S - B\cos S
        - \cos L\,\tfrac{D_x-D_y}{2}\sin 2S + \cos L\,\tfrac{\Delta\beta_{yz}-\Delta\beta_{xz}}{2}\cos 2S

with ``A = b_x − Δβxy sinL``, ``B = b_y + Δβyx sinL`` (Wu et al. 2018 Eqs. 29–38 with
signs restored; Eq. 36 printed ``−Δβyx sinL``, physics gives ``+``).

The observed attitude errors are these inputs filtered by the damping loop
(:class:`~stableins.estimators.system.loop.DampingLoop`): the k-th harmonic of the
observed pitch and roll is ``M_k`` times the quasi-static one.  The fit therefore
estimates the observed mean and harmonics with nuisance terms (the Schuler transient,
``e^{σt}cos ωt``, ``e^{σt}sin ωt`` for each Schuler mode of the loop, and the gyro
case-rotation residual at its period), then maps the harmonics back through ``M_k⁻¹``.

Noise: the attitude noise is the accelerometer noise filtered by the loop, so it is
coloured.  The covariance uses the per-sample quasi-static noise ``σ`` measured from the
accelerometer outputs and the loop gain at each column's frequency:
``cov = D (XᵀWX)⁻¹ D`` with ``D_jj = σ |G(jω_j)|`` (stationary-noise approximation of
the sandwich estimator, exact for white noise).  The residual periodogram between 3 and
8 cycles per day checks it.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from stableins.estimators.system.loop import DRIFT_SCALE, DampingLoop, drift_columns

#: Quasi-static combined coefficients of pitch (Eqs. 29–33) and roll (Eqs. 34–38), paper order.
PITCH_COEFFICIENTS = ("theta_mean", "theta_1c", "theta_1s", "theta_2c", "theta_2s")
ROLL_COEFFICIENTS = ("phi_mean", "phi_1s", "phi_1c", "phi_2s", "phi_2c")
ATTITUDE_COEFFICIENTS = PITCH_COEFFICIENTS + ROLL_COEFFICIENTS

#: Blocks per slice of the design matrix in :func:`fit_attitude`.  The slices are built once and shared by both channels
#: and all passes; with at most ``blocks.AttitudeBlocks.max_blocks`` (2¹⁴) blocks they hold about 3 MiB whatever the record length.
FIT_ROWS = 4096

#: Default period of the gyro case-rotation residual [s] (Wu et al. 2018 §6.2: 8 minutes).
CASE_ROTATION_PERIOD = 480.0


@dataclass(frozen=True)
class AttitudeModel:
    """What the observed pitch and roll pass through besides the accelerometer harmonics (:func:`fit_attitude`).

    Attributes
    ----------
    loop : DampingLoop
        The INS damping loop (from the record's metadata).
    case_rotation_period : float or None
        Period of the gyro case-rotation residual [s]; ``None`` leaves it out.
    compensate_loop : bool
        Map the harmonics through ``M_k⁻¹`` (default).  ``False`` reproduces the paper's quasi-static reading (biased
        by the loop's gain and phase).
    """

    loop: DampingLoop
    case_rotation_period: float | None = CASE_ROTATION_PERIOD
    compensate_loop: bool = True


@dataclass(frozen=True)
class AttitudeDrift:
    """How the attitude fit treats a constant gyro drift (:func:`fit_attitude`).

    Attributes
    ----------
    mode : {"check", "fit", "ignore"}
        The loop's response to a constant gyro drift along each platform axis (:meth:`DampingLoop.drift_responses`,
        from rest at the record start).  The equatorial components turn at the Earth rate in the n-frame and drive the
        undamped Earth-rate mode at resonance: 0.001°/h moves the attitude coefficients by ~2e-5 rad.  Over one day the
        response is nearly collinear with the fundamentals (fitting it as a nuisance, ``"fit"``, inflates their σ about
        tenfold; ``"check"`` fits it only to warn, which at 0.001°/h and 1 Hz is not significant either), so by default
        (``"ignore"``) it is left out: give ``known``.
    known : array (3,), optional
        Gyro drift in the platform frame [rad/s] known from elsewhere: its response is removed.
    jacobian : bool
        Also return ``∂values/∂ε`` (10, 3): the fit's linear map applied to the loop's unit-drift responses.
    """

    mode: str = "ignore"
    known: Sequence[float] | NDArray[np.float64] | None = None
    jacobian: bool = False


def attitude_combinations(latitude: float) -> NDArray[np.float64]:
    """Matrix ``(10, 12)`` mapping residuals (``harmonics.RESIDUAL_NAMES``) to the quasi-static coefficients.

    The means contain only the accelerometer part; base tilt and gimbal zero offsets
    add to them (:mod:`stableins.estimators.system.separation` gives them nuisance columns).
    """
    from stableins.estimators.system.harmonics import RESIDUAL_NAMES

    s, c = np.sin(latitude), np.cos(latitude)
    ix = {n: i for i, n in enumerate(RESIDUAL_NAMES)}
    m = np.zeros((10, 12))

    def put(row: int, **terms: float) -> None:
        for k, v in terms.items():
            m[row, ix[k]] += v

    # pitch
    put(0, b_z=c, D_z=-s * c, D_x=0.5 * s * c, D_y=0.5 * s * c)
    put(1, b_x=-s, beta_xy=s * s, beta_zy=c * c)  # -A sinL + Δβzy cos²L
    put(2, b_y=-s, beta_yx=-s * s, beta_zx=-c * c)  # -B sinL - Δβzx cos²L
    put(3, D_x=0.5 * s * c, D_y=-0.5 * s * c)
    put(4, beta_yz=0.5 * s * c, beta_xz=-0.5 * s * c)
    # roll
    put(5, beta_xz=0.5 * c, beta_yz=0.5 * c)
    put(6, b_x=1.0, beta_xy=-s)  # A
    put(7, b_y=-1.0, beta_yx=-s)  # -B
    put(8, D_x=-0.5 * c, D_y=0.5 * c)
    put(9, beta_yz=0.5 * c, beta_xz=-0.5 * c)
    return m


@dataclass(frozen=True)
class AttitudeFit:
    """Result of :func:`fit_attitude`.

    Attributes
    ----------
    names : tuple of str
        :data:`ATTITUDE_COEFFICIENTS`.
    values, covariance : ndarray
        Loop-compensated quasi-static coefficients (10,) and covariance (10, 10) [rad, rad²].
    observed, observed_covariance : ndarray
        Coefficients of the observed attitude before the loop compensation (same order).
    nuisance : dict
        Fitted nuisance amplitudes [rad] (Schuler, case rotation).
    noise_sigma : tuple of float
        Per-sample quasi-static noise σ of pitch and roll used for the covariance [rad].
    residual_noise_ratio : tuple of float
        Residual periodogram (3–8 cycles/day) over the predicted one, per channel (≈1 expected).
    residual_rms : tuple of float
        RMS of the block-mean residuals [rad].
    """

    names: tuple[str, ...]
    values: NDArray[np.float64]
    covariance: NDArray[np.float64]
    observed: NDArray[np.float64]
    observed_covariance: NDArray[np.float64]
    nuisance: dict[str, float]
    noise_sigma: tuple[float, float]
    residual_noise_ratio: tuple[float, float]
    residual_rms: tuple[float, float]
    block_residuals: NDArray[np.float64]
    vertical_jacobian: NDArray[np.float64]
    drift_estimate: NDArray[np.float64]
    drift_sigma: NDArray[np.float64]
    notes: tuple[str, ...] = ()
    block_map: NDArray[np.float64] | None = None  # (10, 2·bins): values ← (pitch, roll) summed over time bins (coloured noise)
    drift_jacobian: NDArray[np.float64] | None = None  # (10, 3): ∂values/∂ε [rad per rad/s] (``drift_jacobian=True``)


def _design(
    blocks: dict[str, NDArray[np.float64]], loop: DampingLoop, case_rotation_period: float | None
) -> tuple[NDArray, list[str], NDArray]:
    t = blocks["time"]
    c1, s1 = blocks["cos"], blocks["sin"]
    columns = [np.ones_like(t), c1, s1, c1 * c1 - s1 * s1, 2.0 * c1 * s1]
    names = ["mean", "1c", "1s", "2c", "2s"]
    freqs = [0.0, loop.earth_rate, loop.earth_rate, 2 * loop.earth_rate, 2 * loop.earth_rate]
    modes = loop.schuler_modes()
    unique: list[complex] = []
    for m in modes:
        if all(abs(m - u) > 1e-3 * abs(m) for u in unique):
            unique.append(m)
    for i, m in enumerate(unique):
        envelope = np.exp(m.real * t)
        columns += [envelope * np.cos(m.imag * t), envelope * np.sin(m.imag * t)]
        names += [f"schuler{i}_c", f"schuler{i}_s"]
        freqs += [m.imag, m.imag]
    for i, m in enumerate(loop.transient_modes()):  # vertical channel, decays in minutes
        envelope = np.exp(m.real * t)
        if abs(m.imag) < 1e-12:
            columns.append(envelope)
            names.append(f"vertical{i}")
            freqs.append(0.0)
        else:
            columns += [envelope * np.cos(m.imag * t), envelope * np.sin(m.imag * t)]
            names += [f"vertical{i}_c", f"vertical{i}_s"]
            freqs += [m.imag, m.imag]
    if case_rotation_period:
        # a drift vector turning at 2π/P in the platform frame appears in the n-frame at 2π/P and 2π/P ± ω_ie
        base = 2.0 * np.pi / case_rotation_period
        for j, w in enumerate((base - loop.earth_rate, base, base + loop.earth_rate)):
            columns += [np.cos(w * t), np.sin(w * t)]
            names += [f"case{j}_c", f"case{j}_s"]
            freqs += [w, w]
    return np.stack(columns, axis=1), names, np.array(freqs)


def fit_attitude(
    blocks: dict[str, NDArray[np.float64]],
    model: AttitudeModel,
    noise_sigma: tuple[float, float],
    *,
    vertical: NDArray[np.float64] | None = None,
    drift: AttitudeDrift = AttitudeDrift(),
    scale_low_frequency: bool = True,
    map_bin_seconds: float = 600.0,
    spectral_ratio: bool = True,
) -> AttitudeFit:
    """Fit mean, fundamental and second harmonic of pitch and roll with nuisance terms.

    Parameters
    ----------
    blocks : dict
        Block means from :meth:`.blocks.AttitudeBlocks.means` (``time`` since the record start).
    model : AttitudeModel
        The damping loop (compensated or not) and the gyro case-rotation period.
    noise_sigma : (float, float)
        Per-sample σ of the quasi-static pitch and roll inputs ``Δf_N/g``, ``Δf_E/g``,
        measured from the accelerometer noise [rad].
    vertical : ndarray (5,), optional
        Mean and harmonics ``(mean, cos S, sin S, cos 2S, sin 2S)`` of ``Δf_D/g``; their
        response through the vertical channel is removed before the compensation.  The
        result's ``vertical_jacobian`` is ``∂values/∂vertical`` for the covariance.
    drift : AttitudeDrift
        How a constant gyro drift is treated (left out by default), a known drift removed, its Jacobian.
    scale_low_frequency : bool
        Scale the covariance by the residual spectrum extrapolated to the harmonics (stand-alone use).  The
        system stage passes ``False`` and adds the coloured-noise covariance of its joint model
        (:func:`.whittle.fit_coloured_noise`) through ``block_map`` instead.
    map_bin_seconds : float
        Width of the time bins (from the record start) over which ``block_map``, the linear map from
        the block means to the coefficients, is summed (memory: 10 × 2 × bins, not × blocks).
    spectral_ratio : bool
        Measure the residuals' spectral ratio (``residual_noise_ratio``, the low-frequency notes).  ``False`` (only with
        ``scale_low_frequency=False``, which does not use it) leaves it NaN: the Type B re-runs of the system stage
        (:mod:`stableins.estimators.system.sensitivity`), which read the coefficients alone.

    Returns
    -------
    AttitudeFit
        The loop-compensated coefficients, their covariance and the fit's diagnostics.
    """
    n_blocks = blocks["time"].size
    loop = model.loop
    _, names, freqs = _design({k: blocks[k][:1] for k in ("time", "cos", "sin")}, loop, model.case_rotation_period)
    slices = [slice(i, min(i + FIT_ROWS, n_blocks)) for i in range(0, n_blocks, FIT_ROWS)]
    fits = _fit_channels(blocks, model, noise_sigma, drift, map_bin_seconds, layout=(len(names), freqs, slices))
    beta, residuals, cov_obs, maps, drift_estimate, drift_sigma, jacobian_obs = fits
    notes = _drift_notes(drift_estimate, drift_sigma) if drift.mode == "check" else []
    observed = np.concatenate([beta[:5, 0], beta[:5, 1]])  # (mean, 1c, 1s, 2c, 2s) per channel
    transform, vertical_map = _loop_compensation(loop, compensate_loop=model.compensate_loop)
    v = np.zeros(5) if vertical is None else np.asarray(vertical, dtype=float)
    qs = transform @ (observed - vertical_map @ v)
    jac_vertical = -transform @ vertical_map
    # reorder roll into the paper order (mean, 1s, 1c, 2s, 2c)
    order = np.array([0, 1, 2, 3, 4, 5, 7, 6, 9, 8])
    values, jac_vertical, observed_out = qs[order], jac_vertical[order], observed[order]
    nuisance = {f"{ch}_{n}": float(beta[j, i]) for j, n in enumerate(names) if j >= 5 for i, ch in enumerate(("pitch", "roll"))}
    if spectral_ratio or scale_low_frequency:
        ratio, factors, low_notes = _low_frequency(blocks, residuals, noise_sigma, loop)
    else:
        ratio, factors, low_notes = np.full(2, np.nan), np.ones(10), []
    notes += low_notes
    if not scale_low_frequency:
        factors = np.ones(10)
        notes = [n.replace("the covariance was scaled accordingly", "see the coloured-noise model") for n in notes]
    scale_obs = np.sqrt(factors)  # in the observed (mean, 1c, 1s, 2c, 2s) order of each channel
    cov_obs = cov_obs * np.outer(scale_obs, scale_obs)
    cov_qs = transform @ cov_obs @ transform.T
    covariance = cov_qs[np.ix_(order, order)]
    rms = np.sqrt(np.mean(residuals**2, axis=0))
    return AttitudeFit(
        names=ATTITUDE_COEFFICIENTS,
        values=values,
        covariance=covariance,
        observed=observed_out,
        observed_covariance=cov_obs[np.ix_(order, order)],
        nuisance=nuisance,
        noise_sigma=(float(noise_sigma[0]), float(noise_sigma[1])),
        residual_noise_ratio=(float(ratio[0]), float(ratio[1])),
        residual_rms=(float(rms[0]), float(rms[1])),
        block_residuals=residuals,
        vertical_jacobian=jac_vertical,
        drift_estimate=drift_estimate,
        drift_sigma=drift_sigma,
        notes=tuple(notes),
        block_map=(transform @ maps)[order],
        drift_jacobian=None if jacobian_obs is None else (transform @ jacobian_obs)[order],
    )


def _drift_notes(drift_estimate: NDArray[np.float64], drift_sigma: NDArray[np.float64]) -> list[str]:
    """``gyro_drift="check"``: a note when the fitted drift is significant (more than 5σ)."""
    if not np.isfinite(drift_estimate).all():
        return []
    z = np.abs(drift_estimate / drift_sigma)
    if z.max() <= 5.0:
        return []
    return [
        "the attitude errors carry the signature of a gyro drift (the Earth-rate resonance of the loop): fitted drift "
        f"{np.round(drift_estimate.mean(axis=0) / (np.pi / 180 / 3600), 5).tolist()} °/h (x, y, z, up to {z.max():.0f} sigma); "
        "over one day it cannot be told from the accelerometer harmonics of pitch and roll, which are biased (0.001 °/h gives "
        "~2e-5 rad); give the known drift, or rely on the specific-force states"
    ]


def _fit_channels(
    blocks: dict[str, NDArray[np.float64]],
    model: AttitudeModel,
    noise_sigma: tuple[float, float],
    drift_settings: AttitudeDrift,
    map_bin_seconds: float,
    *,
    layout: tuple[int, NDArray[np.float64], list[slice]],
) -> tuple[
    NDArray[np.float64],
    NDArray[np.float64],
    NDArray[np.float64],
    NDArray[np.float64],
    NDArray[np.float64],
    NDArray[np.float64],
    NDArray[np.float64] | None,
]:
    """Fit pitch and roll on the blocks (the drift responses as columns with ``gyro_drift="fit"``).

    ``drift_settings``: ``drift`` of :func:`fit_attitude`; ``layout``: the number of common columns, their frequencies
    and the slices of blocks the design is built in.  Returns ``(coefficients
    (n, 2), block residuals, covariance of the observed (mean, 1c, 1s, 2c, 2s) per channel, the map from the block means
    summed per time bin to them, drift estimate (2, 3), its σ, ∂observed/∂ε (10, 3) or None)``.
    """
    designs: dict[int, NDArray[np.float64]] = {}  # both channels and all passes share the rows: built once per slice
    loop, (n_common, freqs, slices) = model.loop, layout

    def common(rows: slice) -> NDArray[np.float64]:
        if rows.start not in designs:
            designs[rows.start] = _design({k: blocks[k][rows] for k in ("time", "cos", "sin")}, loop, model.case_rotation_period)[0]
        return designs[rows.start]

    gyro_drift, known_drift, want_jacobian = drift_settings.mode, drift_settings.known, drift_settings.jacobian
    w = blocks["count"]
    y = np.stack([blocks["pitch"], blocks["roll"]], axis=1)
    needed = gyro_drift in ("fit", "check") or known_drift is not None or want_jacobian
    drift = drift_columns(blocks, loop) if needed else None
    jacobian = np.zeros((10, 3)) if want_jacobian else None
    if known_drift is not None:  # a drift known from the gyro calibration: remove its response exactly
        assert drift is not None
        y = y - drift @ (np.asarray(known_drift, dtype=float) / DRIFT_SCALE)
    drift_estimate, drift_sigma = np.full((2, 3), np.nan), np.full((2, 3), np.nan)
    map_bin = np.floor(blocks["time"] / map_bin_seconds).astype(np.int64)
    n_map = int(map_bin.max()) + 1 if map_bin.size else 0
    maps = np.zeros((10, 2 * n_map))  # observed (mean, 1c, 1s, 2c, 2s per channel) ← block means summed per time bin
    beta = np.zeros((n_common, 2))
    residuals = np.zeros_like(y)
    cov_obs = np.zeros((10, 10))
    for ch in range(2):
        gains = np.array([np.abs(loop.frequency_response(f)).max(axis=1)[ch] if f > 0 else 1.0 for f in freqs[:5]])
        d = noise_sigma[ch] * gains
        coef, res, inv = _weighted_fit(common, y[:, ch], w, slices)
        columns, inv_full = common, inv
        if drift is not None and gyro_drift in ("fit", "check"):
            # the same fit with the drift responses of this channel as three more columns

            def with_drift(rows: slice, ch: int = ch, drift: NDArray[np.float64] = drift) -> NDArray[np.float64]:
                return np.concatenate([common(rows), drift[rows, ch, :]], axis=1)

            coef_d, res_d, inv_d = _weighted_fit(with_drift, y[:, ch], w, slices)
            sigma_d = noise_sigma[ch] * np.abs(loop.frequency_response(loop.earth_rate)).max(axis=1)[ch] * np.sqrt(np.diag(inv_d)[-3:])
            drift_estimate[ch], drift_sigma[ch] = coef_d[-3:] * DRIFT_SCALE, sigma_d * DRIFT_SCALE
            if gyro_drift == "fit":
                coef, res, inv = coef_d[:n_common], res_d, inv_d[:n_common, :n_common]
                columns, inv_full = with_drift, inv_d
        responses = None if jacobian is None or drift is None else drift[:, ch, :] / DRIFT_SCALE
        found = _coefficient_map(columns, inv_full, w, slices, map_bin, n_map=n_map, responses=responses)
        maps[5 * ch : 5 * ch + 5, ch * n_map : (ch + 1) * n_map] = found[0]
        if jacobian is not None:
            jacobian[5 * ch : 5 * ch + 5] = found[1]
        beta[:, ch] = coef
        residuals[:, ch] = res
        cov_obs[5 * ch : 5 * ch + 5, 5 * ch : 5 * ch + 5] = d[:, None] * inv[:5, :5] * d[None, :]
    return beta, residuals, cov_obs, maps, drift_estimate, drift_sigma, jacobian


def _coefficient_map(
    columns: Callable[[slice], NDArray[np.float64]],
    inv: NDArray[np.float64],
    w: NDArray[np.float64],
    slices: list[slice],
    map_bin: NDArray[np.int64],
    *,
    n_map: int,
    responses: NDArray[np.float64] | None,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Return the map from block means to a channel's five coefficients summed per time bin, and the drift Jacobian.

    The map is ``(5, n_map)`` (FIT_ROWS blocks at a time); applied to ``responses`` (blocks, 3), the loop's responses to a
    unit drift, it gives the Jacobian ``(5, 3)`` (zeros without them).
    """
    maps = np.zeros((5, n_map))
    jacobian = np.zeros((5, 3))
    for rows in slices:
        part = (columns(rows) @ inv[:5].T) * w[rows, None]
        for k in range(5):
            maps[k] += np.bincount(map_bin[rows], weights=part[:, k], minlength=n_map)
        if responses is not None:
            jacobian += part.T @ responses[rows]
    return maps, jacobian


def _loop_compensation(loop: DampingLoop, *, compensate_loop: bool) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Loop compensation of the harmonics, vectors (pitch c, pitch s, roll c, roll s): ``(M_k⁻¹ blocks, vertical map)``."""
    transform = np.eye(10)
    vertical_map = np.zeros((10, 5))  # observed ← Δf_D/g coefficients
    if compensate_loop:
        for k, (ic, is_) in ((1, (1, 2)), (2, (3, 4))):
            m_inv = np.linalg.inv(loop.harmonic_matrix(k))
            idx = [ic, is_, 5 + ic, 5 + is_]
            transform[np.ix_(idx, idx)] = m_inv
            vertical_map[np.ix_(idx, [ic, is_])] = loop.vertical_harmonic_matrix(k)
        dc = loop.dc_gain()
        vertical_map[0, 0], vertical_map[5, 0] = dc[0, 2], dc[1, 2]
    return transform, vertical_map


def _low_frequency(
    blocks: dict[str, NDArray[np.float64]], residuals: NDArray[np.float64], noise_sigma: tuple[float, float], loop: DampingLoop
) -> tuple[NDArray[np.float64], NDArray[np.float64], list[str]]:
    """Measure the coloured (low-frequency) noise of the residuals from their spectrum extrapolated to the harmonics.

    Returns ``(mean spectral ratio per channel, covariance factors at 1 and 2 cycles/day in the observed order, notes)``.
    """
    from stableins.estimators.system.spectrum import EARTH_FREQUENCY, inflation, spectral_ratios

    w = blocks["count"]
    notes: list[str] = []
    ratio = np.full(2, np.nan)
    factors = np.ones(10)
    grid = np.linspace(0.5, 40.0, 160) * EARTH_FREQUENCY
    for ch in range(2):
        gain = np.array([np.abs(loop.frequency_response(2 * np.pi * f)).max(axis=1)[ch] for f in grid])
        freqs, rho = spectral_ratios(
            blocks["time"],
            residuals[:, ch],
            w,
            noise_sigma[ch] ** 2,
            (3.5 * EARTH_FREQUENCY, 30.0 * EARTH_FREQUENCY),
            gain=gain,
            gain_frequencies=grid,
            max_frequencies=64,
        )
        if rho.size:
            ratio[ch] = float(np.mean(rho))
        at = np.array([1.0, 1.0, 1.0, 2.0, 2.0]) * EARTH_FREQUENCY
        factors[5 * ch : 5 * ch + 5] = inflation(freqs, rho, at)
        if factors[5 * ch + 1] > 2.0:
            notes.append(
                f"{ch and 'roll' or 'pitch'} residuals carry low-frequency noise (bias instability / random walk): the spectrum "
                f"extrapolated to one cycle per day is {factors[5 * ch + 1]:.1f}x the white level; the covariance was scaled accordingly"
            )
    return ratio, factors, notes


def _weighted_fit(
    design: Callable[[slice], NDArray[np.float64]], y: NDArray[np.float64], w: NDArray[np.float64], slices: list[slice]
) -> tuple[NDArray, NDArray, NDArray]:
    """Weighted least squares ``(coefficients, residuals, (XᵀWX)⁻¹)`` with column scaling.

    ``design(rows)`` returns the rows of ``X`` for a slice of blocks: the normal equations
    ``XᵀWX``, ``XᵀWy`` are accumulated over ``slices`` so that ``X`` is never held whole
    (memory independent of the record length but for the block means themselves).
    """
    xtwx: NDArray[np.float64] | float = 0.0
    xtwy: NDArray[np.float64] | float = 0.0
    for rows in slices:
        x = design(rows)
        xw = x * w[rows, None]
        xtwx = xtwx + x.T @ xw
        xtwy = xtwy + xw.T @ y[rows]
    scale = np.sqrt(np.diag(xtwx))
    scale = np.where(scale > 0, scale, 1.0)
    inv = np.linalg.pinv(xtwx / np.outer(scale, scale), rcond=1e-13) / np.outer(scale, scale)
    coef = inv @ xtwy
    residuals = np.empty_like(y)
    for rows in slices:
        residuals[rows] = y[rows] - design(rows) @ coef
    return coef, residuals, inv
