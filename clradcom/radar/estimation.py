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
``refine_peaks``      the periodogram maximiser: Newton steps on log|A(x, y)|²,
                      A(x, y) = Σ_n Σ_μ F(n, μ) e^{+j2π n x/N} e^{−j2π μ y/M}, from each
                      detection's coarse position, all detections at once.  With several
                      detections each one is refined on F minus the others' fitted
                      sinusoids (amplitudes by joint least squares: the RELAX iteration of
                      Li & Stoica, IEEE T-SP 44(2), 1996), so a strong neighbour's
                      rectangular-window sidelobes do not pull a weak target.
``estimate_detections``  a detection table (cfar.DETECTION_DTYPE) with range and
                      velocity replaced by the refined values.

The periodogram maximum of the un-windowed frame is the maximum-likelihood estimate of a
single sinusoid in white Gaussian noise (Rife & Boorstyn 1974; Braun, Sturm, Jondral,
RadarCon 2010) and reaches the bound above the threshold SNR.  A window w costs
Σn²w²·Σn²/(Σn²w)² in variance (n centred on the window): 3.7 dB for Hann, 2.2 dB for
Hamming; an optional ``window`` is accepted for data that is known to be windowed.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from clradcom.errors import ArgumentError
from clradcom.radar.processing import get_window
from clradcom.radar.waveform import SPEED_OF_LIGHT, Waveform

__all__ = ["CramerRaoBound", "Refined", "cramer_rao_bound", "estimate_detections",
           "periodogram_at", "refine_peaks"]

#: Newton iterations at most; each is one (3K x N) @ (N x M) matrix product.  From the
#: windowed image's interpolated peak (within ~0.02 bin) two or three reach 1e-9 bin.
MAX_ITERATIONS = 8
#: a step this small (bins, both axes, every detection) ends the iteration
STEP_TOLERANCE = 1e-9
#: largest Newton step per iteration (bins): log|sinc| is concave on its main lobe
#: (±1 bin), so a step from inside it never needs more than half a bin
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

    Paper frame, SNR 0 dB per cell: σ_r ≥ 1.2 mm, σ_v ≥ 1.5 mm/s.
    """
    if not isinstance(waveform, Waveform):
        raise ArgumentError("must be a clradcom.radar.Waveform", argument="waveform",
                            value=waveform)
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


def _grams(u, v, nc, mc, wn, wm):
    """Cross terms of the fitted sinusoids: G_pq[k, j] = (Σ_n (n−n_c)^p w_n u_k u_j*)·
    (Σ_μ (μ−μ_c)^q w_μ v_k v_j*), the moment A_pq at detection k of a unit sinusoid placed
    at detection j."""
    ur = [(u * (wn * nc**p)) @ u.conj().T for p in range(3)]
    vr = [(v * (wm * mc**q)) @ v.conj().T for q in range(3)]
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
    """Maximise the periodogram |A(x, y)|² of the channel estimate F (N, M) around each
    start (x_k, y_k) (bins of the critically sampled grid; y signed, 0 = zero Doppler).

    Each iteration: the moments A_pq of F at every current position (one matrix product);
    with ``joint`` and more than one detection, the joint least-squares amplitudes
    b̂ = G⁻¹A_00 of all fitted sinusoids and, for each detection, the moments of F minus
    the others' sinusoids (G the sinusoids' Gram matrix); then one Newton step on
    log|A|² per detection (2x2 Hessian; per-axis steps where it is not negative
    definite; at most :data:`MAX_STEP` bins).  A detection whose end point is not a
    maximum, or lies more than one bin from its start, keeps its start
    (``converged`` False).  Windows default to none (rectangular: the ML estimate);
    a known window may be given.
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
    for _ in range(max_iterations):
        amp, dx, dy, concave = _newton_step(fw, x, y, wn, wm, joint)
        x, y = x + dx, y + dy
        small = (np.abs(dx) < STEP_TOLERANCE) & (np.abs(dy) < STEP_TOLERANCE)
        if small.all():
            break
    converged = small & concave & (np.abs(x - x0) <= 1.0) & (np.abs(y - y0) <= 1.0)
    x, y = np.where(converged, x, x0), np.where(converged, y, y0)
    # the steering rows are centred: refer the amplitudes back to cell (0, 0), F's model
    amp = amp * np.exp(1j * np.pi * (n - 1) * x / n - 1j * np.pi * (m - 1) * y / m)
    return Refined(x, y, amp, converged)


def _newton_step(fw, x, y, wn, wm, joint):
    """Amplitudes and one safeguarded Newton step on log|A|² at every (x_k, y_k)."""
    n, m = fw.shape
    k = x.size
    u, v, nc, mc = _steering(x, y, n, m)
    mom = _moments(fw, u, v, nc, mc)
    if joint and k > 1:
        grams = _grams(u, v, nc, mc, wn, wm)
        amp = np.linalg.lstsq(grams[0, 0], mom[0, 0], rcond=None)[0]
        for pq, g in grams.items():
            others = g.copy()
            np.fill_diagonal(others, 0.0)
            mom[pq] = mom[pq] - others @ amp
    else:
        amp = mom[0, 0] / (np.sum(wn) * np.sum(wm))
    kx, ky = 2 * np.pi / n, 2 * np.pi / m
    a = mom[0, 0]
    ax, ay = 1j * kx * mom[1, 0], -1j * ky * mom[0, 1]
    axx, ayy = -kx**2 * mom[2, 0], -ky**2 * mom[0, 2]
    axy = kx * ky * mom[1, 1]
    p = np.maximum(np.abs(a) ** 2, np.finfo(float).tiny)
    gx, gy = 2 * np.real(np.conj(a) * ax) / p, 2 * np.real(np.conj(a) * ay) / p
    hxx = 2 * (np.real(np.conj(a) * axx) + np.abs(ax) ** 2) / p - gx**2
    hyy = 2 * (np.real(np.conj(a) * ayy) + np.abs(ay) ** 2) / p - gy**2
    hxy = 2 * (np.real(np.conj(a) * axy) + np.real(np.conj(ax) * ay)) / p - gx * gy
    det = hxx * hyy - hxy**2
    concave = (hxx < 0) & (det > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        dx = np.where(concave, -(hyy * gx - hxy * gy) / det,
                      np.where(hxx < 0, -gx / hxx, np.sign(gx) * MAX_STEP))
        dy = np.where(concave, -(hxx * gy - hxy * gx) / det,
                      np.where(hyy < 0, -gy / hyy, np.sign(gy) * MAX_STEP))
    dx = np.clip(np.nan_to_num(dx), -MAX_STEP, MAX_STEP)
    dy = np.clip(np.nan_to_num(dy), -MAX_STEP, MAX_STEP)
    return amp, dx, dy, concave


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
