"""Direction of arrival at the Cramér–Rao bound along a linear (virtual) array: the bound,
and the refinement that reaches it (docs/dsp.md §6a).

Model (the range–velocity model of :mod:`clradcom.radar.estimation` with one more axis):
virtual channel k at position p_k (m) along the array axis holds the channel estimate

    F_k(n, μ) = b · e^{−j2π n x/N} · e^{+j2π μ y/M} · e^{+j2π p_k u/λ} + w_k(n, μ),

w ~ CN(0, σ²) independent over cells and channels, u = sin θ the direction cosine along
the axis (θ from broadside; cube.py's sign: element at +p carries e^{+j2π p u/λ}).
"SNR per cell" is |b|²/σ² as for range and velocity; coherent integration over the
N·M cells of every channel and the K channels gives N·M·K·|b|²/σ².

``angle_cramer_rao_bound``  the 3-D single-tone bound (Rife & Boorstyn 1974; Kay 1993,
                   Example 3.14; Stoica & Nehorai 1989, for one source): with
                   centred indices and positions the Fisher information is diagonal in
                   (x, y, u), and J_uu = 2·SNR·NM·(2π/λ)²·Σ_k (p_k − p̄)²; for a ULA of
                   spacing d, Σ(p_k − p̄)² = d²K(K²−1)/12, so
                   var(û) ≥ 6λ² / [(2πd)² · SNR·NM · K(K²−1)] and var(θ̂) = var(û)/cos²θ.
``refine_angles``  the maximum of the un-windowed spatial periodogram
                   |Σ_k z_k e^{−j2π p_k u/λ}|² of the snapshot z_k = Σ_{n,μ} F_k(n, μ)
                   e^{+j2πnx/N} e^{−j2πμy/M} taken exactly at the detection's
                   (refined, fractional) range–Doppler position: a grid search at 1/8 of
                   the Rayleigh width, then Newton steps.  Given (x, y) this is the ML
                   estimate of u (the model is separable), and since the bound decouples,
                   the range–Doppler estimate's error costs the angle nothing to first
                   order.
``refine_range_doppler_angle``  the joint ML fit of one target per detection by
                   alternation: the angle at the start cell, the channels beamformed
                   towards it, range and Doppler refined on the beam
                   (:func:`clradcom.radar.estimation.refine_peaks`), the angle again at
                   the refined cell (coordinate ascent on the 3-D periodogram; twice).

A window, on the array or in range–Doppler, costs variance (its SNR loss, and on the
array its own-axis factor, as for range in estimation.py); the on-grid FFT cell loses up
to 3.9 dB per axis to scalloping: the cube's Hann FFT with a dB parabola is far from the
bound (tests/test_estimation_angle.py).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from clradcom.errors import ArgumentError
from clradcom.radar.estimation import refine_peaks

__all__ = ["AngleBound", "RefinedAngle", "RefinedTarget", "angle_cramer_rao_bound",
           "array_snapshots", "refine_angles", "refine_mimo_detections",
           "refine_range_doppler_angle", "spatial_periodogram"]

#: Newton iterations at most for the angle; from the 1/8-Rayleigh grid two to four suffice
MAX_ITERATIONS = 20
#: a direction cosine step below this (relative to the Rayleigh width λ/aperture) has
#: settled: 1e-9 of 1/6 (a 12-element λ/2 ULA) is 1.5e-5 of the bound at 10 dB per cell
#: on the paper frame
STEP_TOLERANCE = 1e-9
#: grid points per Rayleigh width of the start search
GRID_PER_RAYLEIGH = 8


class AngleBound(NamedTuple):
    """Standard deviations (square roots of the bounds): ``sin_theta`` (direction cosine
    along the array axis) and ``theta_deg`` (degrees from broadside); arrays shaped like
    the broadcast of the SNR and the angle given."""

    sin_theta: np.ndarray
    theta_deg: np.ndarray


class RefinedAngle(NamedTuple):
    """Per detection: ``sin_theta`` û, ``theta_rad`` asin û, ``amplitude`` b̂ (the fitted
    complex amplitude per cell, referred to cell (0, 0) and position 0: F's model),
    ``converged`` (Newton steps settled at a maximum within one Rayleigh width of the grid
    start; else the grid start is returned)."""

    sin_theta: np.ndarray
    theta_rad: np.ndarray
    amplitude: np.ndarray
    converged: np.ndarray


def _positions(positions_m, wavelength_m):
    p = np.asarray(positions_m, dtype=float)
    if p.ndim != 1 or p.size < 2 or not np.all(np.isfinite(p)):
        raise ArgumentError("must be 1-D finite element positions (m) along the array axis, "
                            "at least two", argument="positions_m",
                            value=f"shape {p.shape}")
    lam = float(wavelength_m)
    if not np.isfinite(lam) or lam <= 0:
        raise ArgumentError("must be positive and finite (m)", argument="wavelength_m",
                            value=wavelength_m)
    pc = p - p.mean()
    if not np.any(pc != 0):
        raise ArgumentError("the elements must not all sit at one position",
                            argument="positions_m", value=positions_m)
    return pc, lam


# ----------------------------------------------------------------------------------------
# the bound
# ----------------------------------------------------------------------------------------
def angle_cramer_rao_bound(snr_per_cell, positions_m, wavelength_m, *, n_cells: int,
                           theta_rad=0.0) -> AngleBound:
    """Cramér–Rao bound on the direction of one target, SNR per cell |b|²/σ² (linear),
    seen in ``n_cells`` range–Doppler cells (N·M; N·M/E_tx per channel for TDM) by every
    element of a linear array at ``positions_m`` (any layout along one axis):

        var(û) ≥ λ² / [8π² · SNR · n_cells · Σ_k (p_k − p̄)²],  var(θ̂) = var(û)/cos²θ

    (module docstring; for a ULA at spacing d the Σ is d²K(K²−1)/12).  Paper frame, 12
    elements at λ/2, SNR 0 dB per cell, broadside: σ_u ≥ 3.68e-5, σ_θ ≥ 2.1e-3°.
    """
    pc, lam = _positions(positions_m, wavelength_m)
    snr = np.asarray(snr_per_cell, dtype=float)
    if not np.all(np.isfinite(snr)) or np.any(snr <= 0):
        raise ArgumentError("must be positive and finite (linear, not dB)",
                            argument="snr_per_cell", value=snr_per_cell)
    if isinstance(n_cells, bool) or not isinstance(n_cells, int | np.integer) or n_cells < 1:
        raise ArgumentError("must be a positive integer (N·M)", argument="n_cells",
                            value=n_cells)
    theta = np.asarray(theta_rad, dtype=float)
    if not np.all(np.isfinite(theta)) or np.any(np.abs(theta) >= np.pi / 2):
        raise ArgumentError("must lie strictly inside (−π/2, π/2) (the bound on θ grows "
                            "without limit at endfire)", argument="theta_rad",
                            value=theta_rad)
    var_u = lam**2 / (8 * np.pi**2 * snr * n_cells * np.sum(pc**2))
    var_u, theta = np.broadcast_arrays(var_u, theta)
    sd_u = np.sqrt(var_u)
    return AngleBound(sd_u, np.degrees(sd_u / np.cos(theta)))


# ----------------------------------------------------------------------------------------
# the snapshot at a fractional range–Doppler position, the spatial periodogram
# ----------------------------------------------------------------------------------------
def _check_channels(channels):
    f = np.asarray(channels)
    if f.ndim != 3 or f.shape[0] < 2 or f.shape[1] < 2 or f.shape[2] < 2:
        raise ArgumentError("must be (K, N, M) channel estimates F_k = D_r/D, one per "
                            "virtual element, K, N, M >= 2", argument="channels",
                            value=f"shape {f.shape}")
    if not np.all(np.isfinite(f)):
        raise ArgumentError("contains NaN or infinite values", argument="channels")
    return f.astype(complex, copy=False)


def _bins(range_bin, doppler_bin):
    x = np.atleast_1d(np.asarray(range_bin, float))
    y = np.atleast_1d(np.asarray(doppler_bin, float))
    if x.shape != y.shape or x.ndim != 1:
        raise ArgumentError("range_bin and doppler_bin must be 1-D and of equal length",
                            argument="range_bin", value=f"shapes {x.shape}, {y.shape}")
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
        raise ArgumentError("contains NaN or infinite values", argument="range_bin")
    return x, y


def array_snapshots(channels, range_bin, doppler_bin) -> np.ndarray:
    """z[d, k] = Σ_n Σ_μ F_k(n, μ) e^{+j2πn x_d/N} e^{−j2πμ y_d/M} (un-windowed, at the
    fractional bins x_d, y_d; y signed, 0 = zero Doppler): each channel's range–Doppler
    DTFT at detection d, exactly (no scalloping).  (D, K)."""
    f = _check_channels(channels)
    x, y = _bins(range_bin, doppler_bin)
    _, n, m = f.shape
    u = np.exp(2j * np.pi * np.outer(x, np.arange(n)) / n)  # (D, N)
    v = np.exp(-2j * np.pi * np.outer(y, np.arange(m)) / m)  # (D, M)
    g = np.einsum("dn,knm->dkm", u, f)
    return np.einsum("dkm,dm->dk", g, v)


def spatial_periodogram(snapshots, positions_m, wavelength_m, sin_theta) -> np.ndarray:
    """|Σ_k z_k e^{−j2π p_k u/λ}|² / K for snapshots (D, K) (or (K,)) at direction cosines
    u (G,): (D, G) (or (G,))."""
    pc, lam = _positions(positions_m, wavelength_m)
    z = np.asarray(snapshots, complex)
    one = z.ndim == 1
    z = np.atleast_2d(z)
    if z.shape[1] != pc.size:
        raise ArgumentError(f"must have one column per element ({pc.size})",
                            argument="snapshots", value=f"shape {z.shape}")
    a = np.exp(-2j * np.pi * np.outer(pc, np.atleast_1d(np.asarray(sin_theta, float))) / lam)
    p = np.abs(z @ a) ** 2 / pc.size
    return p[0] if one else p


# ----------------------------------------------------------------------------------------
# the refinement
# ----------------------------------------------------------------------------------------
def refine_angles(channels, range_bin, doppler_bin, positions_m, wavelength_m, *,
                  max_iterations: int = MAX_ITERATIONS) -> RefinedAngle:
    """Direction cosine of each detection at its (fractional) range–Doppler position: the
    maximum of the un-windowed spatial periodogram of :func:`array_snapshots` (module
    docstring).  ``channels`` (K, N, M): F_k on a common cell grid (TDM: after the
    transmitter slot's Doppler phase is removed); ``positions_m`` (K,) along the axis."""
    z = array_snapshots(channels, range_bin, doppler_bin)
    ref = _refine_snapshots(z, positions_m, wavelength_m, max_iterations)
    # b̂ = Σ_k z_k e^{−j2π p_k û/λ} / (K·N·M) with the uncentred positions: F's model
    p = np.asarray(positions_m, float)
    _, n, m = np.shape(channels)
    amp = ref.amplitude * np.exp(-2j * np.pi * p.mean() * ref.sin_theta / float(wavelength_m))
    return ref._replace(amplitude=amp / (n * m))


def _refine_snapshots(z, positions_m, wavelength_m, max_iterations):
    pc, lam = _positions(positions_m, wavelength_m)
    if z.shape[1] != pc.size:
        raise ArgumentError(f"must have one position per channel ({z.shape[1]})",
                            argument="positions_m", value=f"{pc.size} positions")
    if isinstance(max_iterations, bool) or not isinstance(max_iterations, int | np.integer) \
            or max_iterations < 1:
        raise ArgumentError("must be a positive integer", argument="max_iterations",
                            value=max_iterations)
    d = z.shape[0]
    rayleigh = lam / (np.ptp(pc) + np.min(np.diff(np.unique(pc))))  # λ / aperture
    # start: grid over the visible region, 1/8 Rayleigh width
    n_grid = int(np.ceil(2.0 / rayleigh * GRID_PER_RAYLEIGH)) + 1
    grid = np.linspace(-1.0, 1.0, n_grid)
    u0 = grid[np.argmax(spatial_periodogram(z, pc, lam, grid), axis=1)] if d else \
        np.zeros(0)
    u = u0.copy()
    beta = 2 * np.pi / lam
    settled = np.zeros(d, bool)
    concave = np.zeros(d, bool)
    for _ in range(max_iterations):
        e = np.exp(-1j * beta * np.outer(u, pc)) * z  # (D, K)
        a0 = e.sum(1)
        a1 = (e * (-1j * beta * pc)).sum(1)
        a2 = (e * (-(beta * pc) ** 2)).sum(1)
        g = 2 * np.real(np.conj(a0) * a1)  # P'
        h = 2 * (np.abs(a1) ** 2 + np.real(np.conj(a0) * a2))  # P''
        concave = h < 0
        step = np.where(concave, -g / np.where(concave, h, -1.0), 0.0)
        step = np.clip(step, -rayleigh / 4, rayleigh / 4)
        step[settled] = 0.0
        u = u + step
        settled |= np.abs(step) < STEP_TOLERANCE * rayleigh
        if settled.all():
            break
    converged = settled & concave & (np.abs(u - u0) <= rayleigh) & (np.abs(u) <= 1.0)
    u = np.where(converged, u, u0)
    amp = np.sum(np.exp(-1j * beta * np.outer(u, pc)) * z, axis=1) / pc.size  # centred
    return RefinedAngle(u, np.arcsin(np.clip(u, -1.0, 1.0)), amp, converged)


def refine_range_doppler_angle(channels, range_bin, doppler_bin, positions_m,
                               wavelength_m, *, rounds: int = 2):
    """Joint range, Doppler and direction of one target per detection, from start bins
    (e.g. the cube's or the image's peaks): alternately the angle at the current cell
    (:func:`refine_angles`) and range–Doppler on the channels beamformed towards that
    angle (:func:`clradcom.radar.estimation.refine_peaks`, each detection alone),
    ``rounds`` times.  Returns (range_bin, doppler_bin, :class:`RefinedAngle`); the
    amplitude is per cell and per element (the beam's gain K divided out)."""
    f = _check_channels(channels)
    x, y = _bins(range_bin, doppler_bin)
    pc, lam = _positions(positions_m, wavelength_m)
    if pc.size != f.shape[0]:
        raise ArgumentError(f"must have one position per channel ({f.shape[0]})",
                            argument="positions_m", value=f"{pc.size} positions")
    if isinstance(rounds, bool) or not isinstance(rounds, int | np.integer) or rounds < 1:
        raise ArgumentError("must be a positive integer", argument="rounds", value=rounds)
    ang = refine_angles(f, x, y, pc, lam)
    for _ in range(rounds):
        for i in range(x.size):
            w = np.exp(-2j * np.pi * pc * ang.sin_theta[i] / lam)
            beam = np.tensordot(w, f, axes=(0, 0))
            ref = refine_peaks(beam, x[i:i + 1], y[i:i + 1], joint=False)
            x[i], y[i] = ref.range_bin[0], ref.doppler_bin[0]
        ang = refine_angles(f, x, y, pc, lam)
    return x, y, ang


# ----------------------------------------------------------------------------------------
# range, Doppler and direction of a MIMO frame's detections, jointly (the cube's ML step)
# ----------------------------------------------------------------------------------------
class RefinedTarget(NamedTuple):
    """Per detection: ``range_bin`` x, ``doppler_bin`` y (signed, in bins of the virtual
    channels' slow time), ``u`` (D, 2) direction cosines along the array's two axes,
    ``amplitude`` b̂ (per cell and element, referred to the centred indices), ``converged``
    (the Newton steps settled at a maximum within one cell of the start on every axis;
    else the start is returned)."""

    range_bin: np.ndarray
    doppler_bin: np.ndarray
    u: np.ndarray
    amplitude: np.ndarray
    converged: np.ndarray


#: Newton iterations per stage of :func:`refine_mimo_detections`
MIMO_ITERATIONS = 12


def _ascend(g, a, theta, max_step, iterations):
    """Newton ascent of P(θ) = |Σ_l g_l e^{−j a_l·θ}|² per row, batched: g (D, L) samples,
    a (L, Q) phase coefficients, θ (D, Q) start; steps clipped to ``max_step`` (Q,).
    Where the Hessian is not negative definite, each coordinate takes its own Newton step
    (a concave coordinate) or a clipped step up its gradient.  Returns (θ, settled)."""
    d, q = theta.shape
    theta = theta.copy()
    settled = np.zeros(d, bool)
    ac = a.astype(complex)
    aa = (a[:, :, None] * a[:, None, :]).reshape(a.shape[0], q * q).astype(complex)
    for _ in range(iterations):
        act = np.flatnonzero(~settled)
        th = theta[act]
        e = g[act] * np.exp(-1j * (th @ a.T))
        s0 = e.sum(1)
        s1 = -1j * (e @ ac)  # (D', Q)
        s2 = -(e @ aa).reshape(act.size, q, q)
        grad = 2 * np.real(np.conj(s0)[:, None] * s1)
        hess = 2 * np.real(np.conj(s1)[:, :, None] * s1[:, None, :]
                           + np.conj(s0)[:, None, None] * s2)
        diag = np.diagonal(hess, axis1=1, axis2=2)
        step = np.where(diag < 0, -grad / np.where(diag < 0, diag, -1.0),
                        np.sign(grad) * max_step)
        concave = np.all(np.linalg.eigvalsh(hess) < 0, axis=1)
        if concave.any():
            step[concave] = -np.linalg.solve(hess[concave], grad[concave][:, :, None])[..., 0]
        step = np.clip(step, -max_step, max_step)
        theta[act] = th + step
        settled[act] = np.all(np.abs(step) < STEP_TOLERANCE * max_step, axis=1)
        if settled.all():
            break
    return theta, settled


def refine_mimo_detections(channels, slow_time, positions_m, wavelength_m, range_bin,
                           doppler_bin, u_start, *, rounds: int = 1,
                           iterations: int = MIMO_ITERATIONS) -> RefinedTarget:
    """Joint maximum-likelihood range, Doppler and direction of one target per detection
    of a MIMO frame, from the raw channel estimates (not the windowed cube).

    Model: virtual channel k holds F_k(n, m) = b e^{−j2πnx/N} e^{+j2π(m + s_k)y/M_v}
    e^{+j2π p_k·u/λ} + noise, n < N subcarriers, m < M_v slow-time samples at times
    (m + s_k) in units of the channel's slow-time interval (``slow_time`` s_k: TDM
    transmitter i of E_tx sends at μ = m·E_tx + i, so s_k = i/E_tx and the Doppler phase
    of its slot is in the model instead of compensated per bin), p_k the element's (y, z)
    position (m), u = (u_y, u_z) the direction cosines.  The ML estimate maximises the
    3-D periodogram |Σ F_k(n,m) e^{+j2πnx/N} e^{−j2π(m+s_k)y/M_v} e^{−j2πp_k·u/λ}|²; with
    centred indices its Fisher information is block diagonal between x and (y, u)
    (:func:`angle_cramer_rao_bound`), so it is found by alternation: (y, u) by Newton on
    the range transform at x (one matrix product of all detections with the data), then
    x by Newton on the channels beamformed and Doppler-matched at (y, u) (another);
    ``rounds`` times.  One round is the ML estimate to first order: the error of the
    start's x moves (y, u) only to second order, decoupled as they are.  Starts: the
    cube's (fractional) bins and direction.

    ``channels`` (K, N, M_v); ``slow_time`` (K,); ``positions_m`` (K, 2) (a column of
    equal values is an axis without extent, its u held at the start); ``u_start`` (D, 2).
    Returns :class:`RefinedTarget` (y signed as given)."""
    f = _check_channels(channels)
    k, n, mv = f.shape
    x0, y0 = _bins(range_bin, doppler_bin)
    s = np.asarray(slow_time, float).reshape(-1)
    pos = np.asarray(positions_m, float)
    if s.size != k or pos.shape != (k, 2) or not np.all(np.isfinite(pos)) \
            or not np.all(np.isfinite(s)):
        raise ArgumentError(f"slow_time must be ({k},) and positions_m ({k}, 2), finite",
                            argument="positions_m", value=f"shapes {s.shape}, {pos.shape}")
    lam = float(wavelength_m)
    if not np.isfinite(lam) or lam <= 0:
        raise ArgumentError("must be positive and finite (m)", argument="wavelength_m",
                            value=wavelength_m)
    u0 = np.asarray(u_start, float).reshape(x0.size, 2)
    if isinstance(rounds, bool) or not isinstance(rounds, int | np.integer) or rounds < 1:
        raise ArgumentError("must be a positive integer", argument="rounds", value=rounds)
    d = x0.size
    if d == 0:
        return RefinedTarget(x0, y0, u0, np.zeros(0, complex), np.zeros(0, bool))
    pc = pos - pos.mean(axis=0)
    axes = np.flatnonzero(np.ptp(pc, axis=0) > 0)  # the axes with extent
    nn = np.arange(n) - (n - 1) / 2.0  # centred indices: decoupled Fisher information
    tm = (np.arange(mv)[None, :] + s[:, None]).reshape(-1)  # (K·M_v,) channel-major
    tm = tm - tm.mean()
    pk = np.repeat(pc, mv, axis=0)  # (K·M_v, 2)
    a_yu = np.concatenate([2 * np.pi * tm[:, None] / mv, 2 * np.pi * pk[:, axes] / lam],
                          axis=1)
    a_x = (-2 * np.pi * nn / n)[:, None]
    aperture = np.ptp(pc[:, axes], axis=0) + lam / 2 if axes.size else np.zeros(0)
    rayleigh = lam / aperture
    step_yu = np.concatenate([[0.25], 0.25 * rayleigh])
    x, yu = x0.copy(), np.concatenate([y0[:, None], u0[:, axes]], axis=1)
    # the two passes over the data in single precision (relative error ~1e-7·√(N·M_v),
    # far below the noise of any frame; halves their time), the Newton steps in double
    f32 = f.astype(np.complex64)
    ok = np.ones(d, bool)
    for _ in range(rounds):
        # (y, u) at x: the range transform of every channel at every detection's x
        ux = np.exp(2j * np.pi * np.outer(x, nn) / n).astype(np.complex64)  # (D, N)
        g = np.matmul(ux, f32).transpose(1, 0, 2).reshape(d, k * mv).astype(complex)
        yu, done = _ascend(g, a_yu, yu, step_yu, iterations)
        ok &= done
        # x at (y, u): the channels beamformed and Doppler-matched
        w = np.exp(-1j * yu @ a_yu.T).reshape(d, k, mv).astype(np.complex64)
        beam = np.matmul(f32, w.transpose(1, 2, 0)).sum(axis=0).T.astype(complex)  # (D, N)
        xs, done = _ascend(beam, a_x, x[:, None], np.array([0.25]), iterations)
        x = xs[:, 0]
        ok &= done
    u = u0.copy()
    u[:, axes] = yu[:, 1:]
    y = yu[:, 0]
    # amplitude per cell and element at the estimate (centred phase reference)
    amp = np.sum(beam * np.exp(2j * np.pi * np.outer(x, nn) / n), axis=1) / (k * n * mv)
    within = (np.abs(x - x0) <= 1.0) & (np.abs(y - y0) <= 1.0)
    if axes.size:
        within &= np.all(np.abs(u[:, axes] - u0[:, axes]) <= rayleigh, axis=1)
    conv = ok & within & np.all(np.abs(u) <= 1.0, axis=1)
    x = np.where(conv, x, x0)
    y = np.where(conv, y, y0)
    u = np.where(conv[:, None], u, u0)
    return RefinedTarget(x, y, u, amp, conv)
