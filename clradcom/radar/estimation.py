"""Range and velocity at the Cramér–Rao bound: the bound itself, and the sub-bin
refinement of detected peaks on the un-windowed periodogram (docs/dsp.md §6).

Model (docs/dsp.md §2–4): after D_r/D, one target is the 2-D complex sinusoid

    F(n, μ) = b · e^{−j2π n x/N} · e^{+j2π μ y/M} + w(n, μ),   w ~ CN(0, σ²) per cell,

with x = r/Δr the range in range bins (Δr = c/(2NΔf)) and y = v/Δv the velocity in
Doppler bins (Δv = c/(2 f_c M T_sym)).  "SNR per cell" is |b|²/σ², the SNR of one
subcarrier–symbol cell; the periodogram integrates it to NM·|b|²/σ².

``cramer_rao_bound``  Rife & Boorstyn (1974) / Kay (1993, §3.7, Example 3.14) for a
                      complex sinusoid of unknown amplitude and phase, in 2-D (the two
                      frequencies decouple), converted to metres and m/s.
``refine_peaks``      the maximum-likelihood positions of the detections: the non-linear
                      least squares fit of one sinusoid per detection to F, all at once,
                      by Newton steps from the windowed image's peaks.  For one target its
                      optimum is the maximum of the un-windowed periodogram
                      |Σ_n Σ_μ F(n, μ) e^{+j2πnx/N} e^{−j2πμy/M}|²; with several, each
                      detection is fitted on F minus the others' sinusoids (the fixed
                      point RELAX iterates towards, Li & Stoica, IEEE T-SP 44(2), 1996),
                      so a strong neighbour's rectangular-window sidelobes do not pull a
                      weak target.
``estimate_detections``  a detection table (cfar.DETECTION_DTYPE) with range and
                      velocity replaced by the refined values.

The periodogram maximum of the un-windowed frame is the maximum-likelihood estimate of a
single sinusoid in white Gaussian noise (Rife & Boorstyn 1974; Braun, Sturm, Jondral,
RadarCon 2010) and reaches the bound above the threshold SNR.  A window costs variance:
on its own axis Σn²w²·Σn²/(Σn²w)² (n centred on the window; 3.7 dB for Hann, 2.2 dB for
Hamming), on the other axis its SNR loss (ENBW, 1.8 dB for Hann): the Hann x Hann
image's own peak is 5.5 dB above the bound at best.  A known window may be given.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from clradcom.errors import ArgumentError
from clradcom.radar.processing import get_window
from clradcom.radar.waveform import SPEED_OF_LIGHT, Waveform

__all__ = ["CramerRaoBound", "Refined", "cramer_rao_bound", "estimate_detections",
           "periodogram_at", "refine_peaks"]

#: Gauss-Newton iterations at most; each is one (3K x N) @ (N x M) matrix product.  From
#: the windowed image's interpolated peak (within ~0.02 bin) a target 30 dB or more over
#: the noise settles in two to four.
MAX_ITERATIONS = 20
#: a detection whose position step is below this (bins, both axes) has settled; 1e-6 bin
#: is 1.6 µm and 2 µm/s on the paper frame, 1/250 of the bound at 10 dB SNR per cell
STEP_TOLERANCE = 1e-6
#: largest position step per iteration (bins): the main lobe of the periodogram is
#: ±1 bin wide, so a step from inside it never needs more than half a bin
MAX_STEP = 0.5


class CramerRaoBound(NamedTuple):
    """Standard deviations (square roots of the bounds): ``range_m`` (m),
    ``velocity_mps`` (m/s); arrays shaped like the SNR given."""

    range_m: np.ndarray
    velocity_mps: np.ndarray


class Refined(NamedTuple):
    """Refined peak positions in bins of the critically sampled grid: ``range_bin`` x
    (r = x·Δr), ``doppler_bin`` y (v = y·Δv, signed, 0 at zero Doppler); ``amplitude``
    b̂ (the fitted complex amplitude per cell of F = b̂ e^{−j2πnx/N} e^{+j2πμy/M}, at the
    refined position); ``converged`` whether the
    Newton steps fell below :data:`STEP_TOLERANCE` and the end point is a maximum
    within one bin of the start (else the start is returned)."""

    range_bin: np.ndarray
    doppler_bin: np.ndarray
    amplitude: np.ndarray
    converged: np.ndarray


# ----------------------------------------------------------------------------------------
# the bound
# ----------------------------------------------------------------------------------------
def cramer_rao_bound(waveform: Waveform, snr_per_cell) -> CramerRaoBound:
    """Cramér–Rao bound on range and velocity of one target, SNR per cell |b|²/σ² (linear).

    For s(n, μ) = b e^{j(ω_r n + ω_v μ)} with b unknown (amplitude and phase) in CN(0, σ²)
    noise, the Fisher information of ω_r is (2|b|²/σ²)·Σ_{n,μ}(n − n̄)² = SNR·NM(N²−1)/6
    (the cross terms with the phase and with ω_v vanish about the centroid), so
    var(ω̂_r) ≥ 6/[SNR·NM(N²−1)] and likewise var(ω̂_v) ≥ 6/[SNR·NM(M²−1)]
    (Rife & Boorstyn 1974, eq. (16); Kay 1993, Example 3.14).  With ω_r = 2πΔf·2r/c and
    ω_v = 2πT_sym·2v f_c/c:

        var(r̂) ≥ 6c² / [(4πΔf)² SNR NM(N²−1)],
        var(v̂) ≥ 6c² / [(4πf_c T_sym)² SNR NM(M²−1)].

    Paper frame, SNR 0 dB per cell: σ_r ≥ 1.2 mm, σ_v ≥ 1.5 mm/s. An FMCW frame
    (``kind`` "fmcw": Δf = S/f_s, T_sym = T_r, f_c the ADC window's centre) has the same
    two-frequency model (docs/fmcw.md §3).
    """
    if not (isinstance(waveform, Waveform) or getattr(waveform, "kind", None) == "fmcw"):
        raise ArgumentError("must be a clradcom.radar.Waveform or FmcwWaveform",
                            argument="waveform", value=waveform)
    snr = np.asarray(snr_per_cell, dtype=float)
    if not np.all(np.isfinite(snr)) or np.any(snr <= 0):
        raise ArgumentError("must be positive and finite (linear, not dB)",
                            argument="snr_per_cell", value=snr_per_cell)
    n, m = float(waveform.n_subcarriers), float(waveform.n_symbols)
    if n < 2 or m < 2:
        raise ArgumentError("the bound needs N >= 2 and M >= 2 (a frequency needs two "
                            "samples)", argument="waveform", value=f"N x M = {n:.0f} x {m:.0f}")
    c = SPEED_OF_LIGHT
    var_r = 6 * c**2 / ((4 * np.pi * waveform.subcarrier_spacing_hz) ** 2
                        * snr * n * m * (n**2 - 1))
    var_v = 6 * c**2 / ((4 * np.pi * waveform.carrier_hz * waveform.symbol_duration) ** 2
                        * snr * n * m * (m**2 - 1))
    return CramerRaoBound(np.sqrt(var_r), np.sqrt(var_v))


# ----------------------------------------------------------------------------------------
# the periodogram and its derivatives at arbitrary points
# ----------------------------------------------------------------------------------------
def _steering(x, y, n, m):
    """Centred steering rows: u[k, n] = e^{j2π(n − n_c)x_k/N}, v[k, μ] = e^{−j2π(μ − μ_c)y_k/M}
    and the centred indices (centring only changes A by a phase, and keeps the derivative
    weights small)."""
    nc = np.arange(n) - (n - 1) / 2.0
    mc = np.arange(m) - (m - 1) / 2.0
    u = np.exp(2j * np.pi * np.outer(x, nc) / n)
    v = np.exp(-2j * np.pi * np.outer(y, mc) / m)
    return u, v, nc, mc


def _moments(f, u, v, nc, mc):
    """A_pq[k] = Σ_n Σ_μ (n−n_c)^p (μ−μ_c)^q u[k,n] F[n,μ] v[k,μ] for the six (p, q) with
    p + q ≤ 2, as a dict; one (3K x N) @ (N x M) product."""
    k = u.shape[0]
    b = np.concatenate([u, u * nc, u * nc**2]) @ f  # (3K, M)
    b0, b1, b2 = b[:k], b[k:2 * k], b[2 * k:]
    return {(0, 0): np.einsum("km,km->k", b0, v), (1, 0): np.einsum("km,km->k", b1, v),
            (2, 0): np.einsum("km,km->k", b2, v), (0, 1): np.einsum("km,km->k", b0, v * mc),
            (1, 1): np.einsum("km,km->k", b1, v * mc),
            (0, 2): np.einsum("km,km->k", b0, v * mc**2)}


def _grams(u, v, nc, mc, wn, wm, rows):
    """Cross terms of the fitted sinusoids: G_pq[k, j] = (Σ_n (n−n_c)^p w_n u_k u_j*)·
    (Σ_μ (μ−μ_c)^q w_μ v_k v_j*), the moment A_pq at detection k of a unit sinusoid placed
    at detection j; k over ``rows`` (a boolean mask), j over all."""
    ua, va = u[rows], v[rows]
    ur = np.split(np.concatenate([ua * (wn * nc**p) for p in range(3)]) @ u.conj().T, 3)
    vr = np.split(np.concatenate([va * (wm * mc**q) for q in range(3)]) @ v.conj().T, 3)
    return {(p, q): ur[p] * vr[q] for p, q in ((0, 0), (1, 0), (2, 0), (0, 1), (1, 1), (0, 2))}


def periodogram_at(spectral, range_bin, doppler_bin, window_range=None,
                   window_doppler=None) -> np.ndarray:
    """|A(x, y)|² / (Σw_n² Σw_μ²) at arbitrary fractional bins: the radar image
    (processing.radar_image's normalisation) evaluated off its grid, exactly."""
    f, wn, wm = _check_spectral(spectral, window_range, window_doppler)
    x = np.atleast_1d(np.asarray(range_bin, float))
    y = np.atleast_1d(np.asarray(doppler_bin, float))
    u, v, nc, mc = _steering(x, y, *f.shape)
    a = np.einsum("km,km->k", u @ (f * wn[:, None] * wm[None, :]), v)
    return np.abs(a) ** 2 / (np.sum(wn**2) * np.sum(wm**2))


def _check_spectral(spectral, window_range, window_doppler):
    f = np.asarray(spectral)
    if f.ndim != 2 or f.shape[0] < 2 or f.shape[1] < 2:
        raise ArgumentError("must be a 2-D (N, M) channel estimate with N, M >= 2",
                            argument="spectral", value=f"shape {f.shape}")
    if not np.all(np.isfinite(f)):
        raise ArgumentError("contains NaN or infinite values", argument="spectral")
    n, m = f.shape
    wn = np.ones(n) if window_range is None else get_window(window_range, n)
    wm = np.ones(m) if window_doppler is None else get_window(window_doppler, m)
    return f.astype(complex, copy=False), wn, wm


# ----------------------------------------------------------------------------------------
# the refinement
# ----------------------------------------------------------------------------------------
def refine_peaks(spectral, range_bin, doppler_bin, *, window_range=None,
                 window_doppler=None, joint: bool = True,
                 max_iterations: int = MAX_ITERATIONS) -> Refined:
    """Maximum-likelihood positions of K sinusoids in the channel estimate F (N, M),
    starting from (x_k, y_k) (bins of the critically sampled grid; y signed, 0 = zero
    Doppler): the non-linear least squares min ‖F − Σ_k b_k e^{−j2πnx_k/N}
    e^{+j2πμy_k/M}‖² over all positions and amplitudes, by Newton steps.

    Start: amplitudes by joint linear least squares at the start positions.  Each
    iteration: the moments of F at every position (one matrix product), the residual's
    moments (minus the Gram matrices of the sinusoids and their derivatives times b̂,
    closed forms of K x K products) and the 4K x 4K Newton system (Hδ = Re(Jᴴr),
    H = Re(JᴴJ) − Re Σ r̄ ∂²s, or the Gauss–Newton Re(JᴴJ) where H is not positive
    definite), position steps clipped to :data:`MAX_STEP`.  For one target its fixed point is the
    periodogram maximum, the ML estimate; with several it is the joint ML (what RELAX,
    Li & Stoica 1996, iterates towards), so a strong neighbour's rectangular-window
    sidelobes do not pull a weak target.  ``joint=False`` fits each detection alone (its
    own periodogram maximum).  A detection whose last step exceeds
    :data:`STEP_TOLERANCE` or that ends more than one bin from its start keeps its start
    (``converged`` False).  Windows default to none (rectangular: the ML estimate); a
    known window makes it the weighted least squares with those weights.
    """
    f, wn, wm = _check_spectral(spectral, window_range, window_doppler)
    n, m = f.shape
    x0 = np.atleast_1d(np.asarray(range_bin, float)).copy()
    y0 = np.atleast_1d(np.asarray(doppler_bin, float)).copy()
    if x0.shape != y0.shape or x0.ndim != 1:
        raise ArgumentError("range_bin and doppler_bin must be 1-D and of equal length",
                            argument="range_bin", value=f"shapes {x0.shape}, {y0.shape}")
    if not (np.all(np.isfinite(x0)) and np.all(np.isfinite(y0))):
        raise ArgumentError("contains NaN or infinite values", argument="range_bin")
    if isinstance(max_iterations, bool) or not isinstance(max_iterations, int | np.integer) \
            or max_iterations < 1:
        raise ArgumentError("must be a positive integer", argument="max_iterations",
                            value=max_iterations)
    k = x0.size
    if k == 0:
        return Refined(x0, y0, np.zeros(0, complex), np.zeros(0, bool))
    rect = window_range is None and window_doppler is None
    fw = f if rect else f * wn[:, None] * wm[None, :]
    x, y = x0.copy(), y0.copy()
    amp = _start_amplitudes(fw, x, y, wn, wm, joint)
    # detections still moving; a settled one is held while the others move, and every
    # time none is left moving one step over all confirms it (or wakes the ones that moved)
    active = np.ones(k, bool)
    settled = np.zeros(k, bool)
    for _ in range(max_iterations):
        dx, dy, da = _newton_step(fw, x, y, amp, wn, wm, joint, active)
        x[active] += dx
        y[active] += dy
        amp[active] += da
        settled[active] = (np.abs(dx) < STEP_TOLERANCE) & (np.abs(dy) < STEP_TOLERANCE)
        if settled.all():
            if active.all():
                break
            active[:] = True
        else:
            active = ~settled
    converged = settled & (np.abs(x - x0) <= 1.0) & (np.abs(y - y0) <= 1.0)
    x, y = np.where(converged, x, x0), np.where(converged, y, y0)
    # the steering rows are centred: refer the amplitudes back to cell (0, 0), F's model
    amp = amp * np.exp(1j * np.pi * (n - 1) * x / n - 1j * np.pi * (m - 1) * y / m)
    return Refined(x, y, amp, converged)


def _start_amplitudes(fw, x, y, wn, wm, joint):
    """Linear (weighted) least-squares amplitudes of all sinusoids at the start
    positions (centred phase reference); each alone without ``joint``."""
    n, m = fw.shape
    u, v, nc, mc = _steering(x, y, n, m)
    a00 = np.einsum("km,km->k", u @ fw, v)
    g00 = _grams(u, v, nc, mc, wn, wm, np.ones(x.size, bool))[0, 0]
    if not joint:
        return a00 / np.diag(g00)
    return np.linalg.lstsq(g00, a00, rcond=None)[0]


def _only(g, own):
    """Keep each row's own column (a detection fitted alone)."""
    out = np.zeros_like(g)
    rows = np.arange(own.size)
    out[rows, own] = g[rows, own]
    return out


def _newton_step(fw, x, y, amp, wn, wm, joint, active):
    """One Newton step (Gauss–Newton where the Hessian is not positive definite) of the
    weighted NLS over (x, y, Re b, Im b) of the ``active`` detections, the others held.
    Returns the steps of their positions and amplitudes (centred phase reference)."""
    n, m = fw.shape
    k = int(active.sum())
    u, v, nc, mc = _steering(x, y, n, m)
    mom = _moments(fw, u[active], v[active], nc, mc)
    gr = _grams(u, v, nc, mc, wn, wm, active)  # (active, all)
    if not joint:  # each detection alone: no cross terms
        own = np.nonzero(active)[0]
        gr = {pq: _only(g, own) for pq, g in gr.items()}
    # residual moments R_pq[k] = Σ (n−n_c)^p (μ−μ_c)^q u_k v_k (F − model)
    res = {pq: mom[pq] - g @ amp for pq, g in gr.items()}
    gr = {pq: g[:, active] for pq, g in gr.items()}  # the system: active with active
    amp = amp[active]
    kx, ky = 2 * np.pi / n, 2 * np.pi / m
    ac = np.conj(amp)[:, None]
    aj = amp[None, :]
    # JᴴJ blocks over (x, y, Re b, Im b); model column of x_k: b_k(−j kx)(n−n_c)φ_k,
    # of y_k: b_k(+j ky)(μ−μ_c)φ_k, of Re b_k: φ_k, of Im b_k: jφ_k
    cxx = kx**2 * ac * aj * gr[2, 0]
    cyy = ky**2 * ac * aj * gr[0, 2]
    cxy = -kx * ky * ac * aj * gr[1, 1]
    cxr = 1j * kx * ac * gr[1, 0]
    cyr = -1j * ky * ac * gr[0, 1]
    g0 = gr[0, 0]
    c = np.block([
        [cxx, cxy, cxr, 1j * cxr],
        [cxy.conj().T, cyy, cyr, 1j * cyr],
        [cxr.conj().T, cyr.conj().T, g0, 1j * g0],
        [(1j * cxr).conj().T, (1j * cyr).conj().T, (1j * g0).conj().T, g0],
    ])
    grad = np.concatenate([np.real(1j * kx * np.conj(amp) * res[1, 0]),
                           np.real(-1j * ky * np.conj(amp) * res[0, 1]),
                           np.real(res[0, 0]), np.imag(res[0, 0])])
    # Newton: subtract Re Σ r·conj(∂²s), non-zero only within one detection (x_k, y_k with
    # each other and with b_k), from the residual's moments; where that Hessian is not
    # positive definite (far from a maximum), the Gauss–Newton matrix alone
    hess = np.real(c)
    second = np.zeros_like(hess)
    i = np.arange(k)
    ix, iy, ire, iim = i, i + k, i + 2 * k, i + 3 * k
    second[ix, ix] = -kx**2 * np.real(np.conj(amp) * res[2, 0])
    second[iy, iy] = -ky**2 * np.real(np.conj(amp) * res[0, 2])
    second[ix, iy] = second[iy, ix] = kx * ky * np.real(np.conj(amp) * res[1, 1])
    second[ix, ire] = second[ire, ix] = -kx * np.imag(res[1, 0])
    second[ix, iim] = second[iim, ix] = kx * np.real(res[1, 0])
    second[iy, ire] = second[ire, iy] = ky * np.imag(res[0, 1])
    second[iy, iim] = second[iim, iy] = -ky * np.real(res[0, 1])
    try:
        np.linalg.cholesky(hess - second)
        hess = hess - second
    except np.linalg.LinAlgError:
        pass
    step = np.linalg.lstsq(hess, grad, rcond=None)[0]
    dx = np.clip(step[:k], -MAX_STEP, MAX_STEP)
    dy = np.clip(step[k:2 * k], -MAX_STEP, MAX_STEP)
    return dx, dy, step[2 * k:3 * k] + 1j * step[3 * k:]


def estimate_detections(detections, spectral, waveform: Waveform, *, zero_pad=(1, 1),
                        joint: bool = True) -> np.ndarray:
    """Detections (``cfar.DETECTION_DTYPE``, found on an image of F with zero padding
    ``zero_pad``) with ``range_m``, ``velocity_mps``, ``range_bin`` and ``doppler_bin``
    replaced by the periodogram maximiser's (:func:`refine_peaks`); power and SNR stay
    the image's.  Bins are given back in the image's own units, as before."""
    f = np.asarray(spectral)
    n, m = waveform.n_subcarriers, waveform.n_symbols
    if f.shape != (n, m):
        raise ArgumentError(f"must have the waveform's shape (N, M) = {(n, m)}",
                            argument="spectral", value=f"shape {f.shape}")
    zr, zd = int(zero_pad[0]), int(zero_pad[1])
    out = np.array(detections, copy=True)
    if out.size == 0:
        return out
    # image column c of an M'-point fftshifted axis is Doppler bin c − ⌊M'/2⌋ (of M')
    x0 = out["range_bin"] / zr
    y0 = (out["doppler_bin"] - (m * zd) // 2) / zd
    ref = refine_peaks(f, x0, y0, joint=joint)
    out["range_bin"] = ref.range_bin * zr
    out["doppler_bin"] = ref.doppler_bin * zd + (m * zd) // 2
    out["range_m"] = ref.range_bin * waveform.range_resolution
    out["velocity_mps"] = ref.doppler_bin * waveform.velocity_resolution
    return out
