"""Two OFDM RadCom radars on one channel: mutual interference and its cancellation.

Radar A receives its own echoes plus radar D's transmit signal through the D->A link,
with D's own random data, its own symbol timing and its own carrier (oscillator) offset,
plus thermal noise.  A then (i) processes as usual, (ii) cancels D with the true data and
channel (genie, the upper bound) or (iii) cancels D with what it can estimate from the
received signal alone: one-stage selective cancellation after Sit, Sturm & Zwick (GeMiC
2012).  Formulas, choices and sources: docs/interference.md.

Time bases (docs/interference.md §2).  Everything happens on a *capture*: A's receive
samples from one symbol before A's frame to one symbol after it, (M+2)·L samples at
f_s = NΔf; A's frame occupies capture samples [L, L + M·L).  The guard symbols exist
because a real receiver samples continuously: D's symbols that straddle A's frame edges
can only be demodulated whole.  D transmits an endless stream of CP-OFDM symbols; here
``stream_symbols`` = M + 4 of them, stream symbol j leaving D at A-frame time
``timing_offset_s`` + (j − STREAM_LEAD)·T_sym, so stream symbol μ + STREAM_LEAD is the
one D sends in step with A's symbol μ.

Why the interferer is synthesised in the time domain: the per-cell model D_r = D·H holds
only when every delay lies inside the cyclic prefix of the receiver's FFT window.  D's
symbol boundaries are unrelated to A's, so D's signal straddles A's FFT windows (ISI) and
its carrier offset rotates the phase within a symbol (ICI); ``interference_signal``
therefore always uses the exact superposition ``synthesize_time_domain``.

Every function takes and returns plain arrays (plus the ``Waveform``), so each stage can
be tested alone.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, replace

import numpy as np

from clradcom.errors import AliasingWarning, ArgumentError, CyclicPrefixWarning
from clradcom.radar.pipeline import frame_result, radar_frame_parts
from clradcom.radar.processing import get_window, radar_image, spectral_estimate
from clradcom.radar.synthesis import (
    channel_transfer_function,
    check_paths,
    synthesize_frequency_domain,
    synthesize_time_domain,
    thermal_noise_power,
)
from clradcom.radar.waveform import (
    Waveform,
    check_symbols,
    constellation,
    ofdm_demodulate,
    ofdm_modulate,
    random_symbols,
)

#: D's stream symbol that is sent in step with A's symbol 0 (A-frame time 0).
STREAM_LEAD = 2
#: A carrier offset plus Doppler beyond this many subcarrier spacings is refused: the
#: cyclic-prefix frequency estimate is unambiguous only within ±Δf/2.
MAX_FREQUENCY_OFFSET = 0.4

#: rotational symmetry of each constellation: the blind decisions are ambiguous by it.
_SYMMETRY = {"bpsk": 2, "qpsk": 4, "8psk": 8, "16psk": 16, "16qam": 4, "64qam": 4,
             "256qam": 4}


# ----------------------------------------------------------------------------------------
# capture layout and signals
# ----------------------------------------------------------------------------------------
#: the stages of :func:`two_radar_run`, in order: its ``progress`` hears one line per
#: stage as it starts (the command's bar counts them)
INTERFERENCE_STAGES = ("A's frame", "A's echoes on the capture", "D's signal at A",
                       "D estimated", "D cancelled", "images", "detections", "error figures")


def capture_length(waveform: Waveform) -> int:
    """Samples of a capture: one guard symbol, A's M symbols, one guard symbol."""
    return (waveform.n_symbols + 2) * waveform.samples_per_symbol


def frame_slice(waveform: Waveform) -> slice:
    """A's frame inside a capture."""
    ell = waveform.samples_per_symbol
    return slice(ell, ell + waveform.n_samples)


def stream_symbols(waveform: Waveform) -> int:
    """Number of D stream symbols that cover a capture whatever the timing offset."""
    return waveform.n_symbols + 4


def _finite(name, value) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ArgumentError(f"{name} must be a real number, got {value!r}") from None
    if not math.isfinite(v):
        raise ArgumentError(f"{name} must be finite, got {value!r}")
    return v


def stream_signal(symbols, gains, delays_s, dopplers_hz, waveform: Waveform,
                  n_samples: int, tol: float = 1e-10) -> np.ndarray:
    """y_i = Σ_k a_k e^{j2π f_k t_i} x(t_i − Δ_k), t_i = i/f_s, i = 0..n_samples−1.

    x is the CP-OFDM stream of ``symbols`` (N, J) starting at t = 0 (symbol j from j·T_sym),
    silent before and after.  Unlike ``synthesize_time_domain`` a delay Δ_k may be
    negative (a stream that began before the capture).  The whole-sample part s0 of the
    smallest delay is taken out first, y_i = ŷ_{i−s0} with delays Δ_k − s0/f_s and gains
    a_k e^{j2π f_k s0/f_s}: exact, and it keeps the exact synthesis cheap, whose cost grows
    with the delays' offsets inside a symbol (its ISI correction, docs/dsp.md §3).
    """
    # check_paths refuses negative delays, which a stream may have: check those apart
    a, tau, fd = check_paths(gains, np.zeros(np.size(delays_s)), dopplers_hz)
    tau = np.atleast_1d(np.asarray(delays_s, dtype=float))
    if tau.shape != a.shape or not np.all(np.isfinite(tau)):
        raise ArgumentError(f"delays_s must be {a.size} finite values, got {delays_s!r}")
    d = np.asarray(symbols)
    n, ell = waveform.n_subcarriers, waveform.samples_per_symbol
    if d.ndim != 2 or d.shape[0] != n:
        raise ArgumentError(f"symbols must have shape (N={n}, J), got {d.shape}")
    if isinstance(n_samples, bool) or not isinstance(n_samples, int | np.integer) \
            or n_samples < 1:
        raise ArgumentError(f"n_samples must be a positive integer, got {n_samples!r}")
    n_out = int(n_samples)
    y = np.zeros(n_out, complex)
    if a.size == 0:
        return y
    fs = waveform.sample_rate
    s0 = int(math.floor(float(tau.min()) * fs))
    n_syn = n_out - s0
    if n_syn <= 0:  # the stream arrives after the capture
        return y
    n_sym = -(-n_syn // ell)
    grid = np.zeros((n, n_sym), complex)
    j = min(d.shape[1], n_sym)  # later symbols arrive after the end
    grid[:, :j] = d[:, :j]
    wf = replace(waveform, n_symbols=n_sym)
    with warnings.catch_warnings():
        # the stream's delay counts whole symbols of the stream: not a radar range, so the
        # range-aliasing warning of the synthesis does not apply here
        warnings.filterwarnings("ignore", message=r"\d+ of \d+ paths have delays beyond",
                                category=AliasingWarning)
        y_hat = synthesize_time_domain(grid, a * np.exp(2j * np.pi * fd * s0 / fs),
                                       np.maximum(tau - s0 / fs, 0.0), fd, wf, tol=tol)
    if s0 >= 0:
        y[s0:] = y_hat[:n_out - s0]
    else:
        y[:] = y_hat[-s0:-s0 + n_out]
    return y


def own_echo_signal(symbols, gains, delays_s, dopplers_hz, waveform: Waveform,
                    method: str = "exact", exact_within_db: float = 40.0) -> np.ndarray:
    """A's own echoes on the capture: A transmits its frame of ``symbols`` (N, M) from
    capture time T_sym (after one guard symbol) and nothing else.

    "exact": the time-domain superposition (ICI of moving echoes, ISI beyond the prefix,
    and the previous symbol's tail in the first prefix samples).  "fast": the paths within
    ``exact_within_db`` of the strongest exactly, the rest by the frequency-domain model
    D_r = D·H (docs/dsp.md §3) turned into the CP-OFDM samples whose FFT windows give
    that D_r.  The split matters: the fast model's prefixes are perfectly cyclic, which
    no delayed signal is, and D's FFT windows, unaligned with A's, see A's prefixes; a
    strong echo made the fast way differs from any physical rebuild by ~−28 dB.  For the
    street's ~30,000 own paths "fast" takes seconds where "exact" takes many minutes.
    """
    d = check_symbols(symbols, waveform, "own symbols")
    a, tau, fd = check_paths(gains, delays_s, dopplers_hz)
    # Doppler phases refer to A's frame start (t = 0 of the DESIGN contract), one symbol
    # into the capture
    a = a * np.exp(-2j * np.pi * fd * waveform.symbol_duration)
    if method == "exact":
        return stream_signal(d, a, tau + waveform.symbol_duration, fd, waveform,
                             capture_length(waveform))
    if method != "fast":
        raise ArgumentError(f"method must be 'exact' or 'fast', got {method!r}")
    within = _finite("exact_within_db", exact_within_db)
    y = np.zeros(capture_length(waveform), complex)
    if a.size == 0:
        return y
    p = np.abs(a) ** 2
    strong = p >= p.max() * 10.0 ** (-within / 10.0)
    y += stream_signal(d, a[strong], tau[strong] + waveform.symbol_duration, fd[strong],
                       waveform, y.size)
    if (~strong).any():
        weak = a[~strong] * np.exp(2j * np.pi * fd[~strong] * waveform.symbol_duration)
        dr = synthesize_frequency_domain(d, weak, tau[~strong], fd[~strong], waveform,
                                         time_origin_s=waveform.fft_window_centre)
        y[frame_slice(waveform)] += ofdm_modulate(dr, waveform)
    return y


def _check_offsets(waveform: Waveform, timing_offset_s, cfo_hz, dopplers_hz=()):
    t_off = _finite("timing_offset_s", timing_offset_s)
    if not 0.0 <= t_off < waveform.symbol_duration:
        raise ArgumentError(
            f"timing_offset_s={timing_offset_s!r} must lie in [0, T_sym) = "
            f"[0, {waveform.symbol_duration!r}) s: a whole symbol more only changes which "
            "random symbols fall into A's frame")
    cfo = _finite("cfo_hz", cfo_hz)
    fd = np.atleast_1d(np.asarray(dopplers_hz, dtype=float))
    worst = max([abs(cfo + f) for f in fd] or [abs(cfo)])
    limit = MAX_FREQUENCY_OFFSET * waveform.subcarrier_spacing_hz
    if worst > limit:
        raise ArgumentError(
            f"cfo_hz={cfo_hz!r} plus the D->A Doppler reaches {worst:.6g} Hz, beyond "
            f"{MAX_FREQUENCY_OFFSET}·Δf = {limit:.6g} Hz: the cyclic-prefix frequency "
            "estimate is ambiguous there")
    return t_off, cfo


def interference_signal(d_stream, gains, delays_s, dopplers_hz, waveform: Waveform,
                        timing_offset_s: float, cfo_hz: float, phase_rad: float = 0.0,
                        power_ratio: float = 1.0) -> np.ndarray:
    """D's signal at A on the capture (exact time-domain model, ISI and ICI included).

    ``d_stream`` (N, J) are D's stream symbols (J ≥ ``stream_symbols``), stream symbol j
    leaving D at A-frame time ``timing_offset_s`` + (j − STREAM_LEAD)·T_sym.  The D->A
    paths (one-way ``gains``, ``delays_s``, ``dopplers_hz``) carry it; D's oscillator adds
    ``cfo_hz`` to every path's frequency and a phase ``phase_rad``.  ``power_ratio`` =
    P_tx,D / P_tx,A scales the amplitude, because signals are in units of √P_tx,A.
    """
    a, tau, fd = check_paths(gains, delays_s, dopplers_hz)
    t_off, cfo = _check_offsets(waveform, timing_offset_s, cfo_hz, fd)
    ratio = _finite("power_ratio", power_ratio)
    if ratio <= 0:
        raise ArgumentError(f"power_ratio must be positive, got {power_ratio!r}")
    d = np.asarray(d_stream)
    if d.ndim != 2 or d.shape[0] != waveform.n_subcarriers \
            or d.shape[1] < stream_symbols(waveform):
        raise ArgumentError(
            f"d_stream must have shape (N={waveform.n_subcarriers}, J >= "
            f"{stream_symbols(waveform)}), got {d.shape}")
    # capture time of stream symbol 0: one guard symbol plus the lead, back in time.
    start = t_off + (1 - STREAM_LEAD) * waveform.symbol_duration
    amp = a * math.sqrt(ratio) * np.exp(1j * _finite("phase_rad", phase_rad))
    return stream_signal(d, amp, tau + start, fd + cfo, waveform, capture_length(waveform))


def predicted_interference_power(gains, delays_s, dopplers_hz, waveform: Waveform,
                                 power_ratio: float = 1.0, window_range=None,
                                 window_doppler=None) -> float:
    """Interference power per cell from the frequency-domain transfer function H_DA of the
    D->A paths: (P_D/P_A)·mean_{n,μ} |H_DA(n, μ)|² (Braun 2013: after A's division D's
    independent data is white, of this power).

    With windows the mean is weighted by w_n² w_μ² / (Σw_n² Σw_μ²): the floor of every
    image cell is the window-weighted mean of the per-cell variances, which differs from
    the plain mean when |H_DA|² varies over the band or the frame (several paths).
    """
    with warnings.catch_warnings():
        # only the power is used, which ISI beyond the prefix does not change
        warnings.simplefilter("ignore", CyclicPrefixWarning)
        h = channel_transfer_function(gains, delays_s, dopplers_hz, waveform, method="matmul")
    p = np.abs(h) ** 2
    wn = np.ones(p.shape[0]) if window_range is None else \
        get_window(window_range, p.shape[0]) ** 2
    wm = np.ones(p.shape[1]) if window_doppler is None else \
        get_window(window_doppler, p.shape[1]) ** 2
    return float(power_ratio) * float(wn @ p @ wm / (wn.sum() * wm.sum()))


def frame_symbols(capture, waveform: Waveform) -> np.ndarray:
    """A's received symbols D_r (N, M): A's frame cut from the capture, CP off, DFT."""
    y = np.asarray(capture)
    if y.shape != (capture_length(waveform),):
        raise ArgumentError(f"capture must have {capture_length(waveform)} samples, got {y.shape}")
    return ofdm_demodulate(y[frame_slice(waveform)], waveform)


def image_floor(image) -> float:
    """Mean power of the white floor of a radar image, median/ln 2: targets occupy few
    cells, and the median of exponential (square-law Gaussian) cells is ln 2 times the
    mean."""
    return float(np.median(image.power) / math.log(2.0))


# ----------------------------------------------------------------------------------------
# receiver stages
# ----------------------------------------------------------------------------------------
def decide(z, modulation: str) -> np.ndarray:
    """Nearest constellation point to every element of z (hard decision)."""
    pts = constellation(modulation)
    z = np.asarray(z)
    idx = np.argmin(np.abs(z[..., None] - pts), axis=-1)
    return pts[idx]


def cp_sync(signal, waveform: Waveform) -> tuple[int, float, np.ndarray]:
    """Symbol timing and frequency offset of the strongest CP-OFDM signal in ``signal``.

    Van de Beek, Sandell & Börjesson (IEEE T-SP 45(7), 1997): the cyclic prefix repeats
    the symbol's last N_cp samples, so Γ(θ) = Σ_j Σ_{p<N_cp} y[θ+jL+p]·y*[θ+jL+p+N] peaks
    where a symbol starts and its phase is −2πε.  Returns θ̂ in [0, L) samples (the first
    sample of a CP, mod L), ε̂ in subcarrier spacings, and |Γ| for every θ.
    """
    y = np.asarray(signal)
    n, ncp, ell = waveform.n_subcarriers, waveform.n_cp, waveform.samples_per_symbol
    if y.ndim != 1 or y.size < 2 * ell:
        raise ArgumentError(f"signal must be 1-D with at least 2L = {2 * ell} samples")
    if ncp == 0:
        raise ArgumentError("cp_sync needs a cyclic prefix (waveform.n_cp = 0)")
    z = y[:-n] * np.conj(y[n:])
    folded = np.zeros(ell, complex)
    full = z.size // ell
    folded += z[:full * ell].reshape(full, ell).sum(axis=0)
    folded[:z.size - full * ell] += z[full * ell:]
    ext = np.concatenate([folded, folded[:ncp]])
    cs = np.concatenate([[0], np.cumsum(ext)])
    gamma = cs[ncp:ncp + ell] - cs[:ell]
    theta = int(np.argmax(np.abs(gamma)))
    eps = float(-np.angle(gamma[theta]) / (2 * np.pi))
    return theta, eps, np.abs(gamma)


def demodulate_stream(signal, waveform: Waveform, theta: int, eps: float, backoff: int):
    """D's symbols R (N, J) from every whole FFT window inside ``signal``.

    The frequency offset ε̂ is removed first (y·e^{−j2πε̂ i/N}); window j starts at
    w0 + jL, w0 = θ̂ + N_cp − backoff (a few samples early, so paths arriving a little
    before the timing estimate stay inside the prefix).  Returns (R, w0).
    """
    y = np.asarray(signal)
    n, ncp, ell = waveform.n_subcarriers, waveform.n_cp, waveform.samples_per_symbol
    if not 0 <= backoff <= ncp:
        raise ArgumentError(f"backoff must lie in [0, N_cp={ncp}], got {backoff!r}")
    w0 = int(theta) + ncp - int(backoff)
    i = np.arange(y.size)
    yc = y * np.exp(-2j * np.pi * eps * i / n)
    n_win = (y.size - w0 - n) // ell + 1
    if n_win < 2:
        raise ArgumentError("signal too short for two D symbols")
    starts = w0 + ell * np.arange(n_win)
    blocks = yc[starts[:, None] + np.arange(n)[None, :]]
    return np.fft.fft(blocks, axis=1, norm="ortho").T.copy(), w0


@dataclass(frozen=True)
class Components:
    """2-D exponentials G(n, j) ≈ Σ_k c_k e^{−j2π nΔf d_k} e^{j2π f_k j T_sym} on a grid."""

    amplitude: np.ndarray
    delay_s: np.ndarray
    doppler_hz: np.ndarray

    def grid(self, n_sub: int, n_sym: int, df: float, t_sym: float) -> np.ndarray:
        u = np.exp(-2j * np.pi * np.outer(np.arange(n_sub), df * self.delay_s))
        v = np.exp(2j * np.pi * np.outer(self.doppler_hz, np.arange(n_sym) * t_sym))
        return u @ (self.amplitude[:, None] * v)


def _atoms(nu, mu, n_sub, n_sym):
    """Unit-modulus atoms for normalised frequencies nu (cycles/subcarrier, delay) and mu
    (cycles/symbol, Doppler)."""
    u = np.exp(-2j * np.pi * np.outer(np.arange(n_sub), nu))
    v = np.exp(2j * np.pi * np.outer(mu, np.arange(n_sym)))
    return u, v


def _ls_amplitudes(g, u, v):
    """Joint least-squares amplitudes of separable atoms u_k v_k^T (Gram matrix from the
    separable inner products, (u_i^H u_k)(v_k v_i^H))."""
    gram = (u.conj().T @ u) * (v.conj() @ v.T)
    rhs = np.einsum("nk,nm,km->k", u.conj(), g, v.conj())
    return np.linalg.solve(gram, rhs)


def fit_components(grid, df: float, t_sym: float, *, min_peak_to_floor_db: float,
                   max_components: int = 32, pad: int = 2,
                   relax_sweeps: int = 10, found=None) -> tuple[Components, float]:
    """Greedy fit (CLEAN with continuous refinement) of 2-D exponentials to ``grid`` (N, J).

    Each round: the unwindowed periodogram P = |Σ G e^{..}|²/(NJ) of the residual on a
    ``pad``-times finer grid gives the strongest peak; its delay and Doppler are refined
    off-grid by maximising |u^H G_k v*| (the single-tone ML estimate, Rife & Boorstyn
    1974) with every other component subtracted; all amplitudes are then re-solved jointly
    by least squares.  Stops when the peak is less than ``min_peak_to_floor_db`` above the
    floor (median(P)/ln 2: the mean per-cell power of what is not fitted) or after
    ``max_components``.  A component of per-cell power |c|² peaks at NJ|c|² over that
    floor.  Delays are returned in [−T/2, T/2), Dopplers in [−1/(2T_sym), 1/(2T_sym)).
    ``found(k)`` (optional) hears the count each time a component is fitted (the rounds
    grow dearer with k: a progress bar's tick).  Returns (components, floor).
    """
    g = np.asarray(grid, complex)
    if g.ndim != 2:
        raise ArgumentError(f"grid must be 2-D, got shape {g.shape}")
    n_sub, n_sym = g.shape
    thr = 10.0 ** (_finite("min_peak_to_floor_db", min_peak_to_floor_db) / 10.0)
    nu = np.zeros(0)
    mu = np.zeros(0)
    amp = np.zeros(0, complex)
    resid = g.copy()
    floor = float("nan")
    for _ in range(int(max_components)):
        spec = np.fft.fft(np.fft.ifft(resid, n=pad * n_sub, axis=0, norm="forward"),
                          n=pad * n_sym, axis=1)
        p = (spec.real ** 2 + spec.imag ** 2) / (n_sub * n_sym)
        floor = float(np.median(p) / math.log(2.0))
        r, c = np.unravel_index(int(np.argmax(p)), p.shape)
        if p[r, c] < thr * floor:
            break
        nu = np.append(nu, r / (pad * n_sub))
        mu = np.append(mu, c / (pad * n_sym))
        _relax(g, nu, mu, pad, sweeps=relax_sweeps)
        u, v = _atoms(nu, mu, n_sub, n_sym)
        amp = _ls_amplitudes(g, u, v)
        resid = g - u @ (amp[:, None] * v)
        if found is not None:
            found(nu.size)
    if nu.size > 1:
        # converge the joint fit: close (unresolved) components keep pulling each other;
        # a component picked up from a not yet converged residual then fades: drop it
        _relax(g, nu, mu, pad, sweeps=relax_sweeps)
        u, v = _atoms(nu, mu, n_sub, n_sym)
        amp = _ls_amplitudes(g, u, v)
        keep = n_sub * n_sym * np.abs(amp) ** 2 >= thr * floor
        if not keep.all():
            nu, mu = nu[keep], mu[keep]
            u, v = _atoms(nu, mu, n_sub, n_sym)
            amp = _ls_amplitudes(g, u, v)
    nu_c = (nu + 0.5) % 1.0 - 0.5
    mu_c = (mu + 0.5) % 1.0 - 0.5
    return Components(amp, nu_c / df, mu_c / t_sym), floor


def _relax(g, nu, mu, pad, sweeps):
    """RELAX (Li & Stoica, IEEE T-SP 44(2), 1996): refine each component in turn with all
    the others subtracted; ``nu``/``mu`` are updated in place.  The residual is updated
    by rank-one steps, so a sweep costs O(K·N·J), not O(K²·N·J)."""
    n_sub, n_sym = g.shape
    u, v = _atoms(nu, mu, n_sub, n_sym)
    amp = _ls_amplitudes(g, u, v)
    resid = g - u @ (amp[:, None] * v)
    for _ in range(int(sweeps)):
        before = np.concatenate([nu, mu])
        for k in range(nu.size):
            rest = resid + amp[k] * np.outer(u[:, k], v[k])
            nu[k], mu[k] = _refine(rest, nu[k], mu[k], pad)
            uk, vk = _atoms(nu[k:k + 1], mu[k:k + 1], n_sub, n_sym)
            u[:, k], v[k] = uk[:, 0], vk[0]
            amp[k] = (u[:, k].conj() @ rest @ v[k].conj()) / (n_sub * n_sym)
            resid = rest - amp[k] * np.outer(u[:, k], v[k])
        if np.max(np.abs(np.concatenate([nu, mu]) - before)) < 1e-6 / max(n_sub, n_sym):
            break


def _newton_tone(h, x, max_step):
    """A few Newton steps towards the maximum of f(x) = |Σ_n h_n e^{j2πnx}|² near x."""
    n = np.arange(h.size)
    w = 2 * np.pi * n
    for _ in range(4):
        e = h * np.exp(1j * w * x)
        s0, s1, s2 = e.sum(), (1j * w * e).sum(), (-(w ** 2) * e).sum()
        d1 = 2 * (s1 * np.conj(s0)).real
        d2 = 2 * (s2 * np.conj(s0)).real + 2 * abs(s1) ** 2
        step = -d1 / d2 if d2 < 0 else math.copysign(max_step, d1)
        x += float(np.clip(step, -max_step, max_step))
        if abs(step) < 1e-9 / h.size:
            break
    return x


def _refine(g, nu0, mu0, pad):
    """Maximise |u(ν)^H g v(μ)^*|² near (ν0, μ0): alternating one-dimensional Newton
    steps, each on the projection of g onto the other axis's current atom."""
    n_sub, n_sym = g.shape
    ni, mi = np.arange(n_sub), np.arange(n_sym)
    nu, mu = float(nu0), float(mu0)
    for _ in range(6):
        h = g @ np.exp(-2j * np.pi * mi * mu)  # Σ_m g e^{−j2πmμ}: a tone in ν
        nu = _newton_tone(h, nu, 0.5 / (pad * n_sub))
        k = np.exp(2j * np.pi * ni * nu) @ g   # Σ_n g e^{j2πnν}: a tone in −μ
        mu = -_newton_tone(k, -mu, 0.5 / (pad * n_sym))
    return nu, mu


def blind_channel(rx, modulation: str, df: float, t_sym: float,
                  max_components: int = 8) -> np.ndarray:
    """A first estimate of D's channel grid from its symbols alone, no pilots: power law.

    For a constellation with S-fold rotational symmetry E[d^S] ≠ 0 (π/4-QPSK: d⁴ = −1 for
    every point), so Z = R^S/E[d^S] ≈ H^S: the data drop out (the S-th-power carrier
    recovery of Viterbi & Viterbi, IEEE T-IT 29(4), 1983, on the 2-D grid).  H^S of a
    few paths is a few 2-D tones (the paths' S-fold sums), fitted by ``fit_components``;
    the S-th root is taken with its phase unwrapped along subcarriers, then symbols, so
    neighbouring cells keep the same branch.  H is known up to a rotation by the symmetry,
    which cancels in the product Ĥ·D̂ the reconstruction needs.  Returns Ĥ (N, J).
    """
    r = np.asarray(rx, complex)
    mod = str(modulation).lower()
    order = _SYMMETRY[mod]
    moment = np.mean(constellation(mod) ** order)
    comp, _ = fit_components(r ** order / moment, df, t_sym, min_peak_to_floor_db=15.0,
                             max_components=max_components)
    z = comp.grid(r.shape[0], r.shape[1], df, t_sym)
    phase = np.angle(z)
    phase[:, 0] = np.unwrap(phase[:, 0])
    phase = np.unwrap(phase, axis=1)
    return np.abs(z) ** (1.0 / order) * np.exp(1j * phase / order)


@dataclass(frozen=True)
class DEstimate:
    """What the realistic receiver learned about D."""

    symbols: np.ndarray        # D̂ (N, J) on D's windows
    components: Components     # D's channel on the windows (after ε̂ removal)
    theta: int                 # CP start of D's symbols in the capture, mod L
    eps: float                 # ε̂, subcarrier spacings
    w0: int                    # first FFT window start
    own: Components            # A's own strong echoes removed before decoding D
    sinr_db: float             # D's decision SINR as the receiver sees it (see below)
    cancel: bool               # reliable enough to subtract (``min_sinr_db``)


def _components_to_paths(comp: Components, w_first: int, first_symbol: int, eps_hz: float,
                         waveform: Waveform):
    """Grid components measured in FFT windows starting at capture samples w_first + jL,
    grid column j being stream symbol first_symbol + j → time-domain paths (gain, delay Δ,
    frequency) of that stream, whose symbol i starts at capture time i·T_sym + Δ.
    Derivation: docs/interference.md §4."""
    fs, n, ncp = waveform.sample_rate, waveform.n_subcarriers, waveform.n_cp
    df = waveform.subcarrier_spacing_hz
    w_stream0 = w_first - first_symbol * waveform.samples_per_symbol
    delay = comp.delay_s + (w_stream0 - ncp) / fs
    eps_k = comp.doppler_hz / df
    with np.errstate(invalid="ignore"):
        dirich = np.where(eps_k == 0, 1.0 + 0j, np.exp(1j * np.pi * eps_k * (n - 1) / n)
                          * np.sin(np.pi * eps_k) / (n * np.sin(np.pi * eps_k / n)))
    gain = comp.amplitude * np.exp(-2j * np.pi * comp.doppler_hz * w_first / fs) / dirich
    return gain, delay, comp.doppler_hz + eps_hz


def estimate_interferer(capture, own_symbols, waveform: Waveform, *,
                        own_margin_db: float = 20.0, min_peak_to_floor_db: float = 15.0,
                        backoff: int | None = None, iterations: int = 2,
                        max_components: int = 32, min_sinr_db: float = 6.0,
                        detail=None) -> DEstimate:
    """Realistic receiver: everything about D from the capture and A's own symbols.

    1. A's strong own echoes (per-cell power above the floor, which the interference
       dominates, minus ``own_margin_db``) are fitted on A's F = D_r/D_A and subtracted
       in the time domain, because they would swamp D's symbol decisions.  "Selective":
       only those.
    2. CP correlation gives D's symbol timing θ̂ and frequency offset ε̂ (``cp_sync``).
    3. D's symbols are demodulated on D's windows; the power law (``blind_channel``)
       gives a first channel and first decisions D̂ = dec(R/Ĥ); then ``iterations``
       rounds of: fit D's channel as 2-D exponentials (``fit_components``) on R/D̂,
       re-decide D̂ = dec(R/Ĥ).

    ``detail(text)`` (optional) hears where it is, step by step and component by
    component (the longest stage of ``clradcom interference``: a bar's postfix).
    """
    tell = detail or (lambda text: None)

    def fitting(what):
        return lambda k: tell(f"{what}: {k} of at most {max_components} components")

    d_a = check_symbols(own_symbols, waveform, "own_symbols")
    y = np.asarray(capture, complex)
    n, m = waveform.n_subcarriers, waveform.n_symbols
    ell = waveform.samples_per_symbol
    df, t_sym = waveform.subcarrier_spacing_hz, waveform.symbol_duration
    # 1. own echoes, selectively
    f_a = spectral_estimate(frame_symbols(y, waveform), d_a, "divide")
    own_thr = 10 * math.log10(n * m) - float(own_margin_db)
    tell("fitting A's strong own echoes")
    own, _ = fit_components(f_a, df, t_sym, min_peak_to_floor_db=own_thr,
                            max_components=max_components, found=fitting("A's own echoes"))
    y_d = y
    if own.amplitude.size:
        tell(f"removing {own.amplitude.size} own echoes (time domain)")
        # A's window of symbol μ starts at capture sample L + μL + N_cp.
        g_o, tau_o, f_o = _components_to_paths(own, ell + waveform.n_cp, 1, 0.0, waveform)
        own_stream = np.concatenate([np.zeros((n, 1)), d_a], axis=1)
        y_d = y - stream_signal(own_stream, g_o, tau_o, f_o, waveform, y.size)
    # 2. synchronise to D
    tell("synchronising to D's cyclic prefixes")
    theta, eps, _ = cp_sync(y_d, waveform)
    b = waveform.n_cp // 4 if backoff is None else int(backoff)
    r, w0 = demodulate_stream(y_d, waveform, theta, eps, b)
    # 3. decisions and channel
    mod = waveform.modulation
    comp = Components(np.zeros(0, complex), np.zeros(0), np.zeros(0))
    tell("D's channel from its symbols alone (power law)")
    h = blind_channel(r, mod, df, t_sym)
    with np.errstate(divide="ignore", invalid="ignore"):
        dh = decide(np.where(h != 0, r / h, 0.0), mod)
    for i in range(int(iterations)):
        comp, _ = fit_components(r / dh, df, t_sym, min_peak_to_floor_db=min_peak_to_floor_db,
                                 max_components=max_components,
                                 found=fitting(f"D's channel, round {i + 1} of "
                                               f"{int(iterations)}"))
        h = comp.grid(n, r.shape[1], df, t_sym)
        with np.errstate(divide="ignore", invalid="ignore"):
            dh = decide(np.where(h != 0, r / h, 0.0), mod)
    # Selective, once more: with right decisions G = R/D̂ is the smooth channel plus white
    # disturbance, and the fit explains the share SINR/(1 + SINR) of its energy; with
    # wrong ones G is white and the fit explains next to nothing.  Below ``min_sinr_db``
    # the rebuild would add more than it removes, so D is left alone.
    explained = float(np.sum(np.abs(h) ** 2) / max(np.sum(np.abs(r / dh) ** 2), 1e-300))
    explained = min(explained, 1.0 - 1e-12)
    sinr_db = 10 * math.log10(max(explained, 1e-300) / (1.0 - explained))
    return DEstimate(dh, comp, theta, eps, w0, own, sinr_db,
                     sinr_db >= _finite("min_sinr_db", min_sinr_db))


def reconstruct_interferer(est: DEstimate, waveform: Waveform, n_samples: int,
                           symbols=None) -> np.ndarray:
    """D's signal on the capture rebuilt from an estimate (time domain, so ISI and ICI of
    the estimated paths and offset are reproduced).  ``symbols`` replaces D̂ (for the
    channel-only error: true data through the estimated channel).  An estimate judged
    unreliable (``est.cancel`` false) rebuilds nothing."""
    if not est.cancel:
        return np.zeros(int(n_samples), complex)
    d = est.symbols if symbols is None else np.asarray(symbols)
    gain, delay, freq = _components_to_paths(est.components, est.w0, 0, est.eps
                                             * waveform.subcarrier_spacing_hz, waveform)
    return stream_signal(d, gain, delay, freq, waveform, n_samples)


def align_to_stream(d_hat, d_stream, modulation: str, max_shift: int = 3):
    """Match D̂ (N, J) to the true stream (N, J_s): the stream index of D̂'s column 0 and
    the global rotation (the blind decisions' ambiguity) that agree best.  Returns
    (shift, rotation, aligned true symbols (N, J) already multiplied by the rotation)."""
    d_hat = np.asarray(d_hat)
    d_s = np.asarray(d_stream)
    sym = _SYMMETRY[str(modulation).lower()]
    best = (-1.0, 0, 1.0 + 0j)
    j = d_hat.shape[1]
    for s in range(-max_shift, max_shift + 1):
        lo = max(0, -s)
        hi = min(j, d_s.shape[1] - s)
        if hi - lo < 1:
            continue
        ratio = d_hat[:, lo:hi] * np.conj(d_s[:, lo + s:hi + s])
        for q in range(sym):
            rot = np.exp(2j * np.pi * q / sym)
            agree = float(np.mean(np.abs(ratio - rot) < 1e-6))
            if agree > best[0]:
                best = (agree, s, rot)
    _, s, rot = best
    aligned = np.zeros_like(d_hat)
    lo, hi = max(0, -s), min(j, d_s.shape[1] - s)
    aligned[:, lo:hi] = d_s[:, lo + s:hi + s] * rot
    return s, rot, aligned


# ----------------------------------------------------------------------------------------
# the whole experiment
# ----------------------------------------------------------------------------------------
@dataclass
class InterferenceResult:
    """Images and figures of one two-radar run (see ``run_interference``)."""

    images: dict            # "clean", "interfered", "genie", "realistic" -> RadarImage
    floors: dict            # same keys -> image floor (mean power per cell)
    noise_variance: float
    interference_power: float      # measured, per sample of A's frame
    predicted_interference_power: float   # plain mean of (P_D/P_A)|H_DA|²
    predicted_floor_power: float   # the same, window-weighted: the interference floor
    predicted_floor_rise_db: float
    measured_floor_rise_db: float
    residual_power: float          # realistic: mean |y_D − ŷ_D|² over A's frame
    channel_nmse: float            # ‖rec(Ĥ, D) − y_D‖²/‖y_D‖² over A's frame
    symbol_error_rate: float       # D̂ against D on the windows inside A's frame
    symbols_decided: int           # how many decisions that rate counts
    mean_error_energy: float       # E|d − d̂|² over the wrong decisions
    predicted_residual_power: float  # P_I·(NMSE + SER·E|d − d̂|²), errors spread evenly
    predicted_residual_weighted: float  # P_I·NMSE + mean |Ĥ|²|d − d̂|²: errors where they fall
    estimate: DEstimate
    #: same keys -> the radar chain's result on that case's frame (images and detections,
    #: clradcom.radar.pipeline.frame_result), when A's own paths were given
    results: dict | None = None


def _own_frame(own_signal, waveform):
    y = np.asarray(own_signal, complex)
    if y.shape != (capture_length(waveform),):
        raise ArgumentError(f"own_signal must have {capture_length(waveform)} samples "
                         f"(capture_length), got {y.shape}")
    return y


def run_interference(own_signal, own_symbols, d_stream, gains, delays_s, dopplers_hz,
                     waveform: Waveform, *, timing_offset_s: float, cfo_hz: float,
                     phase_rad: float = 0.0, power_ratio: float = 1.0,
                     noise_variance: float = 0.0, rng=None, window="hann",
                     zero_pad=(2, 2), own_frame=None, frame_noise=None, own_paths=None,
                     progress=None, detail=None, **estimate_kw) -> InterferenceResult:
    """A's radar image without D, with D, after genie and after realistic cancellation.

    ``own_signal`` is A's echo on the capture (``own_echo_signal``), ``own_symbols`` A's
    frame (N, M), ``d_stream`` D's stream (N, ≥ ``stream_symbols``), the paths are the
    D->A link.  The same noise realisation is used in every case so the images differ by
    the interference and its residual only.

    Each case's frame is A's frame without D plus what D leaves in A's FFT windows (the
    capture's demodulation is linear): ``own_frame`` (N, M), when given, is that frame
    (the radar chain's, :func:`clradcom.radar.pipeline.radar_frame_parts`, noise
    included), else the clean capture's. ``frame_noise`` (N, M), when given, is the noise
    inside ``own_frame``: the capture's noise in A's FFT windows is made of it (their
    inverse DFTs), the cyclic prefixes and guard symbols get their own, so the receiver
    that estimates D sees the noise that the images hold. With ``own_paths`` (A's own
    echoes) every case also goes through the radar chain's detection
    (:func:`clradcom.radar.pipeline.frame_result`): ``results``. ``progress`` (optional)
    hears a line as each of the last six :data:`INTERFERENCE_STAGES` starts, ``detail``
    where D's estimation is (:func:`estimate_interferer`).
    """
    say = progress or (lambda msg: None)
    y_own = _own_frame(own_signal, waveform)
    d_a = check_symbols(own_symbols, waveform, "own_symbols")
    nv = _finite("noise_variance", noise_variance)
    if nv < 0:
        raise ArgumentError(f"noise_variance must be >= 0, got {noise_variance!r}")
    rng = np.random.default_rng(rng)
    noise = math.sqrt(nv / 2) * (rng.standard_normal(y_own.size)
                                 + 1j * rng.standard_normal(y_own.size))
    if frame_noise is not None:
        w = check_symbols(frame_noise, waveform, "frame_noise")
        ell, n_cp = waveform.samples_per_symbol, waveform.n_cp
        windows = noise[frame_slice(waveform)].reshape(waveform.n_symbols, ell)
        windows[:, n_cp:] = np.fft.ifft(w, axis=0, norm="ortho").T  # their DFT is w
    say(f"D's signal at A through {np.size(gains)} D->A paths (time domain)")
    y_int = interference_signal(d_stream, gains, delays_s, dopplers_hz, waveform,
                                timing_offset_s, cfo_hz, phase_rad, power_ratio)
    clean = y_own + noise
    rx = clean + y_int
    say("D estimated: its channel and data from A's capture")
    est = estimate_interferer(rx, d_a, waveform, detail=detail, **estimate_kw)
    say("D cancelled: rebuilt and subtracted from the capture")
    y_hat = reconstruct_interferer(est, waveform, rx.size)
    base = frame_symbols(clean, waveform) if own_frame is None else \
        check_symbols(own_frame, waveform, "own_frame")
    # genie: the true data and channel removed, the bound
    frames = {"clean": base, "interfered": base + frame_symbols(y_int, waveform),
              "genie": base, "realistic": base + frame_symbols(y_int - y_hat, waveform)}
    say("images without D, with D, genie and realistic cancellation")
    images = {}
    for key, fr_k in frames.items():
        f = spectral_estimate(fr_k, d_a, "divide")
        images[key] = radar_image(f, waveform, window, window, zero_pad[0], zero_pad[1])
    say("detections of the four images")
    results = None if own_paths is None else \
        {k: frame_result(d_a, fr_k, own_paths, waveform) for k, fr_k in frames.items()}
    say("error figures of D's estimate")
    floors = {k: image_floor(im) for k, im in images.items()}
    fr = frame_slice(waveform)
    p_i = float(np.mean(np.abs(y_int[fr]) ** 2))
    p_pred = predicted_interference_power(gains, delays_s, dopplers_hz, waveform, power_ratio)
    p_floor = predicted_interference_power(gains, delays_s, dopplers_hz, waveform,
                                           power_ratio, window, window)
    # The floor rises by the power D adds to every cell, over whatever floor A had without
    # D (noise, plus the ICI floor of A's own fast echoes).  With QAM the division by D_A
    # scales noise and interference alike (E 1/|D|²), so the ratio does not change.
    if floors["clean"] > 0:
        rise_pred = 10 * math.log10((floors["clean"] + p_floor) / floors["clean"])
        rise_meas = 10 * math.log10(floors["interfered"] / floors["clean"])
    else:  # nothing at all without D (no noise, no echoes)
        rise_pred = rise_meas = math.inf
    res = float(np.mean(np.abs(y_int[fr] - y_hat[fr]) ** 2))
    # error figures on the D windows that overlap A's frame
    n_win = est.symbols.shape[1]
    starts = est.w0 + waveform.samples_per_symbol * np.arange(n_win)
    inside = (starts + waveform.n_subcarriers > fr.start) & (starts < fr.stop)
    _, _, d_true = align_to_stream(est.symbols, _stream_from_capture(d_stream, est, waveform),
                                   waveform.modulation)
    wrong = np.abs(est.symbols - d_true)[:, inside] > 1e-6
    ser = float(np.mean(wrong))
    err_e = float(np.mean(np.abs(est.symbols - d_true)[:, inside][wrong] ** 2)) \
        if wrong.any() else 0.0
    # wrong decisions cost |Ĥ|²|d − d̂|² where they happen: in fades, where they are likely,
    # |Ĥ|² is small, so on a frequency-selective D channel this is below P_I·SER·E|d − d̂|²
    h_grid = est.components.grid(waveform.n_subcarriers, n_win, waveform.subcarrier_spacing_hz,
                                 waveform.symbol_duration)
    weighted = float(np.mean((np.abs(h_grid) ** 2 * np.abs(est.symbols - d_true) ** 2)
                             [:, inside]))
    # the estimate's own quality, whether or not the receiver dared to subtract it
    y_ch = reconstruct_interferer(replace(est, cancel=True), waveform, rx.size, symbols=d_true)
    nmse = float(np.sum(np.abs(y_ch[fr] - y_int[fr]) ** 2) / np.sum(np.abs(y_int[fr]) ** 2))
    pred, pred_w = (p_i * (nmse + ser * err_e), p_i * nmse + weighted) if est.cancel \
        else (p_i, p_i)
    return InterferenceResult(images, floors, nv, p_i, p_pred, p_floor, rise_pred, rise_meas, res,
                              nmse, ser, int(wrong.size), err_e, pred, pred_w, est, results)


def two_radar_run(own_paths, interferer_paths, waveform: Waveform, *, tx_power_w: float,
                  interferer_tx_power_w: float, noise_figure_db: float,
                  timing_offset_s: float, cfo_hz: float, phase_rad: float = 0.0,
                  seed: int = 0, own_synthesis: str = "fast",
                  progress=None, detail=None) -> InterferenceResult:
    """The whole two-radar experiment from traced paths: radar A's own echoes
    (``own_paths``, the A->A link) and radar D's signal through the D->A link
    (``interferer_paths``), each radar with its own random data, plus A's thermal noise
    (from ``tx_power_w`` and ``noise_figure_db``); D's power relative to A's is
    ``interferer_tx_power_w / tx_power_w``.

    A's frame without D is the radar chain's (:func:`clradcom.radar.pipeline.
    radar_frame_parts` with ``seed``: A's data from ``seed``, the noise in A's FFT windows
    from ``seed`` + 1, synthesised by ``own_synthesis``), so the image without D and its
    detections (``results``, :func:`clradcom.radar.pipeline.frame_result`) are
    ``clradcom trace``'s on the same paths and seed. D's data and the rest of the
    capture's noise come from (``seed``, 13). For D's estimator A's echoes are on the
    time-domain capture (``own_echo_signal`` with ``own_synthesis``; "fast": the strong
    echoes exact, there the cyclic prefixes are no copies). ``progress`` (optional) is
    called with a line as each of the :data:`INTERFERENCE_STAGES` starts, in order;
    ``detail`` (optional) hears the steps inside D's estimation, the longest stage.
    """
    for name, val in (("tx_power_w", tx_power_w), ("interferer_tx_power_w",
                                                   interferer_tx_power_w),
                      ("noise_figure_db", noise_figure_db)):
        _finite(name, val)
    if not (tx_power_w > 0 and interferer_tx_power_w > 0):
        raise ArgumentError(f"transmit powers must be positive, got A {tx_power_w!r} W, "
                         f"D {interferer_tx_power_w!r} W")
    say = progress or (lambda msg: None)
    noise_var = thermal_noise_power(waveform.bandwidth, noise_figure_db) / tx_power_w
    say(f"A's frame: {len(own_paths.gain)} own paths ({own_synthesis} synthesis)")
    d_a, dr_own, w = radar_frame_parts(own_paths, waveform, seed=seed, method=own_synthesis,
                                       tx_power_w=tx_power_w, noise_figure_db=noise_figure_db)
    rng = np.random.default_rng((seed, 13))
    d_d = random_symbols(replace(waveform, n_symbols=stream_symbols(waveform)), rng)
    say(f"A's echoes on the capture for D's estimator ({own_synthesis})")
    y_own = own_echo_signal(d_a, own_paths.gain, own_paths.delay_s, own_paths.doppler_hz,
                            waveform, method=own_synthesis)
    return run_interference(
        y_own, d_a, d_d, interferer_paths.gain, interferer_paths.delay_s,
        interferer_paths.doppler_hz, waveform, timing_offset_s=timing_offset_s, cfo_hz=cfo_hz,
        phase_rad=phase_rad, power_ratio=interferer_tx_power_w / tx_power_w,
        noise_variance=noise_var, rng=rng, own_frame=dr_own + w, frame_noise=w,
        own_paths=own_paths, progress=progress, detail=detail)


def _stream_from_capture(d_stream, est, waveform):
    """D's true stream re-indexed so that column j is the symbol whose CP starts at capture
    sample ≈ θ̂ + jL (the estimate's window j), to within ``align_to_stream``'s search."""
    # stream symbol 0 starts at capture time offset + (1 − STREAM_LEAD)·T_sym ≥ −T_sym,
    # and window 0 belongs to the first symbol starting at or after capture sample 0, so
    # its stream index is STREAM_LEAD − 1 or STREAM_LEAD (± the search range).
    first = STREAM_LEAD - 1
    return np.asarray(d_stream)[:, first:]
