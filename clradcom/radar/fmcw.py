"""FMCW chirp-sequence radar: waveform, beat-signal synthesis from a snapshot's paths
(exact and fast), IF filter and ADC, oscillator phase noise, and the range-Doppler
processing that hands over to the OFDM chain's CFAR and sub-bin estimation.

Model (docs/fmcw.md; Winkler, EuRAD 2007; Patole et al., IEEE SPM 34(2), 2017):
chirp μ starts at u = μ·T_r (T_r = chirp + idle) and sweeps f(t') = f_0 + S t'
(S = B/T_chirp) over its fast time t'. A path k of the traced channel has delay
τ_k(t) = τ_k − β_k t (β_k = f_D,k/f_c, t = u + t' the time since the frame began,
f_c the carrier the scene was traced at) and complex gain a_k, which already holds the
carrier phase −2π f_c τ_k and the antenna patterns and polarisation. The receiver mixes
the echo with the conjugate of the chirp it transmits (y = rx·tx*), so sample n of chirp
μ (t' = t_adc + n/f_s) is

    s(n, μ) = Σ_k a_k H_IF(f_b,k) e^{jΦ_k(t', u)} [t' >= τ_k(t)],
    Φ_k = −2π[(f_0 − f_c) τ_k(t) + S t' τ_k(t) − S τ_k(t)²/2] + 2π f_D,k t,

the phase −2π f(t') τ plus the residual video phase πSτ², with the carrier phase a_k
holds moved from f_c to the instantaneous frequency: the channel is taken as flat over
the sweep (pattern and material responses at the traced carrier; docs/fmcw.md). Before
its echo arrives (t' < τ) a chirp's window holds the previous chirp's tail, whose beat
lies near the sweep bandwidth, far beyond the IF filter: zero. The beat frequency
∂Φ/∂t'/2π ≈ −S·2R/c + f_D is negative: a closer target sits at a lower IDFT bin, as in
the OFDM chain (range by an IDFT over fast time, velocity by a DFT over chirps), so the
frame is an OFDM spectral estimate F(n, μ) and the same image, CFAR and refinement run
on it. Φ_k is a quadratic polynomial in (t', u): the range-Doppler coupling, the range
migration across chirps (the t'·u term) and the Doppler changing within a chirp (t'²) are
all in it.

``synthesize_beat_exact``  Φ_k evaluated at every sample for every path (the reference,
                           and what the "obvious numpy sum" of tools/bench_dsp.py is)
``synthesize_beat``        the same polynomial split into its separable part (a 2-D
                           type-1 NUFFT of the paths, finufft) and its second-order part,
                           whose coefficient is proportional to β_k and is interpolated
                           at Chebyshev nodes in β (the OFDM exact synthesis' device)
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np
from scipy import signal as ss

from clradcom.errors import AliasingWarning, ArgumentError
from clradcom.radar.estimation import CramerRaoBound, cramer_rao_bound
from clradcom.radar.processing import CellCorrelation, RadarImage, radar_image
from clradcom.radar.synthesis import (
    SYNTHESIS_ACCURACY,
    _lagrange_weights,
    _wrap_phase,
    chebyshev_order,
    check_paths,
    thermal_noise_power,
)
from clradcom.radar.waveform import SPEED_OF_LIGHT

__all__ = ["IF_TYPES", "FmcwWaveform", "beat_frequencies", "correct_coupling",
           "fmcw_cramer_rao_bound", "fmcw_frame", "fmcw_image", "if_response",
           "phase_noise_psd", "residual_phase_noise", "synthesize_beat",
           "synthesize_beat_exact"]

IF_TYPES = ("complex", "real")
#: finufft threads for the frame-sized transforms here (see synthesize_beat)
FINUFFT_THREADS = 1


def _positive(name: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float | np.floating | np.integer):
        raise ArgumentError("must be a real number", argument=name, value=value)
    v = float(value)
    if not math.isfinite(v) or v <= 0.0:
        raise ArgumentError("must be positive and finite", argument=name, value=value)
    return v


def _non_negative(name: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float | np.floating | np.integer):
        raise ArgumentError("must be a real number", argument=name, value=value)
    v = float(value)
    if not math.isfinite(v) or v < 0.0:
        raise ArgumentError("must be non-negative and finite", argument=name, value=value)
    return v


def _count(name: str, value, minimum: int = 1) -> int:
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < minimum:
        raise ArgumentError(f"must be an integer >= {minimum}", argument=name, value=value)
    return int(value)


@dataclass(frozen=True)
class FmcwWaveform:
    """FMCW chirp-sequence frame (SI units). ``traced_carrier_hz`` is the carrier the
    channel was traced at (the scene's ``carrier_hz``): the sweep must contain it, since
    the paths' gains, patterns and Dopplers hold for it.

    Defaults: a 77 GHz corner radar, 1 GHz in 40 µs (S = 25 MHz/µs), 10 µs idle,
    128 chirps, 256 complex samples at 10 MHz from 2 µs into the chirp; the radar figures
    (Δr, r_max, Δv, v_max) are properties computed from these, never typed in.

    The attributes the OFDM chain reads (``n_subcarriers``, ``n_symbols``,
    ``subcarrier_spacing_hz``, ``symbol_duration``, ``carrier_hz``, the resolutions and
    unambiguous limits) are given FMCW meanings so that its image, CFAR, Cramér-Rao
    bound and refinement run unchanged (docs/fmcw.md §3)."""

    traced_carrier_hz: float = 77.5e9
    start_hz: float = 77e9
    sweep_bandwidth_hz: float = 1e9
    chirp_s: float = 40e-6
    idle_s: float = 10e-6
    n_chirps: int = 128
    adc_rate_hz: float = 10e6
    samples_per_chirp: int = 256
    adc_start_s: float = 2e-6
    if_type: str = "complex"
    if_bandwidth_hz: float | None = None
    if_filter_order: int = 4
    #: the oscillator's phase-noise mask L(f) (dBc/Hz at offsets in Hz), or None for a
    #: clean oscillator (:func:`phase_noise_psd`)
    phase_noise_offsets_hz: tuple | None = None
    phase_noise_dbc_per_hz: tuple | None = None

    kind = "fmcw"

    def __post_init__(self):
        fc = _positive("traced_carrier_hz", self.traced_carrier_hz)
        f0 = _positive("start_hz", self.start_hz)
        b = _positive("sweep_bandwidth_hz", self.sweep_bandwidth_hz)
        tc = _positive("chirp_s", self.chirp_s)
        _non_negative("idle_s", self.idle_s)
        _count("n_chirps", self.n_chirps)
        fs = _positive("adc_rate_hz", self.adc_rate_hz)
        n = _count("samples_per_chirp", self.samples_per_chirp, 2)
        t_adc = _non_negative("adc_start_s", self.adc_start_s)
        _count("if_filter_order", self.if_filter_order)
        if self.if_type not in IF_TYPES:
            raise ArgumentError(f"must be one of {IF_TYPES}", argument="if_type",
                                value=self.if_type)
        window_end = t_adc + n / fs
        if window_end > tc * (1.0 + 1e-12):
            raise ArgumentError(
                f"the ADC window (adc_start_s + samples_per_chirp/adc_rate_hz = {t_adc!r} + "
                f"{n}/{fs!r} = {window_end!r} s) is longer than the chirp ({tc!r} s): its "
                "last samples would see no sweep", argument="samples_per_chirp", value=n)
        if self.if_bandwidth_hz is not None:
            bif = _positive("if_bandwidth_hz", self.if_bandwidth_hz)
            if bif > self.nyquist_hz * (1.0 + 1e-12):
                raise ArgumentError(
                    f"exceeds what the ADC can take unaliased ({self.if_type} IF at "
                    f"{fs!r} Hz: {self.nyquist_hz!r} Hz): noise and echoes passed by the "
                    "filter above it would fold onto nearer ranges", argument="if_bandwidth_hz",
                    value=self.if_bandwidth_hz)
        offsets, levels = self.phase_noise_offsets_hz, self.phase_noise_dbc_per_hz
        if (offsets is None) != (levels is None):
            raise ArgumentError("the phase-noise mask needs its offsets and its levels",
                                argument="phase_noise_dbc_per_hz" if levels is None
                                else "phase_noise_offsets_hz", value=None)
        if offsets is not None:
            phase_noise_psd(offsets, levels)
        if not (f0 <= fc <= f0 + b):
            raise ArgumentError(
                f"the sweep [{f0!r}, {f0 + b!r}] Hz does not contain the carrier the "
                f"channel was traced at ({fc!r} Hz): trace the scene at a carrier inside "
                "the sweep", argument="start_hz", value=self.start_hz)

    # --- sweep -------------------------------------------------------------------------
    @property
    def slope(self) -> float:
        """S = B/T_chirp (Hz/s)."""
        return self.sweep_bandwidth_hz / self.chirp_s

    @property
    def chirp_interval(self) -> float:
        """T_r = T_chirp + T_idle, the chirp repetition interval."""
        return self.chirp_s + self.idle_s

    @property
    def nyquist_hz(self) -> float:
        """The widest one-sided beat band the ADC takes unaliased: f_s for complex (I/Q)
        samples (the echoes' beats are all negative), f_s/2 for real ones."""
        return self.adc_rate_hz if self.if_type == "complex" else self.adc_rate_hz / 2.0

    @property
    def if_cutoff_hz(self) -> float:
        """The IF filter's cutoff: ``if_bandwidth_hz``, else the ADC's limit."""
        return self.nyquist_hz if self.if_bandwidth_hz is None else float(self.if_bandwidth_hz)

    @property
    def window_centre_s(self) -> float:
        """Fast time of the centre of the ADC window, t_adc + (N − 1)/(2 f_s)."""
        return self.adc_start_s + (self.samples_per_chirp - 1) / (2.0 * self.adc_rate_hz)

    @property
    def sampled_bandwidth(self) -> float:
        """The part of the sweep the ADC sees, S·N/f_s (what sets the range resolution)."""
        return self.slope * self.samples_per_chirp / self.adc_rate_hz

    # --- the OFDM chain's names ----------------------------------------------------------
    @property
    def n_subcarriers(self) -> int:
        """Fast-time samples per chirp (the range transform's length)."""
        return self.samples_per_chirp

    @property
    def n_symbols(self) -> int:
        """Chirps per frame (the Doppler transform's length)."""
        return self.n_chirps

    @property
    def subcarrier_spacing_hz(self) -> float:
        """S/f_s: the sweep's advance per ADC sample; c/(2NΔf) is then the range bin."""
        return self.slope / self.adc_rate_hz

    @property
    def symbol_duration(self) -> float:
        return self.chirp_interval

    @property
    def carrier_hz(self) -> float:
        """The frequency at the centre of the ADC window, f_0 + S·t_c: the Doppler across
        chirps is β times this (docs/fmcw.md §2), so velocities are converted with it."""
        return self.start_hz + self.slope * self.window_centre_s

    @property
    def wavelength(self) -> float:
        return SPEED_OF_LIGHT / self.carrier_hz

    @property
    def sample_rate(self) -> float:
        return self.adc_rate_hz

    @property
    def bandwidth(self) -> float:
        """The noise bandwidth of a sample: f_s (complex), f_s/2 (real)."""
        return self.adc_rate_hz if self.if_type == "complex" else self.adc_rate_hz / 2.0

    @property
    def frame_duration(self) -> float:
        return self.n_chirps * self.chirp_interval

    @property
    def range_resolution(self) -> float:
        """Δr = c/(2 S N/f_s)."""
        return SPEED_OF_LIGHT / (2.0 * self.sampled_bandwidth)

    @property
    def max_range(self) -> float:
        """Range where the IDFT wraps: c f_s/(2S) for complex samples, half for real."""
        return SPEED_OF_LIGHT * self.nyquist_hz / (2.0 * self.slope)

    @property
    def if_range(self) -> float:
        """Range whose beat sits at the IF filter's cutoff, c B_IF/(2S)."""
        return SPEED_OF_LIGHT * self.if_cutoff_hz / (2.0 * self.slope)

    @property
    def max_velocity(self) -> float:
        """±λ/(4 T_r)."""
        return self.wavelength / (4.0 * self.chirp_interval)

    @property
    def velocity_resolution(self) -> float:
        """Δv = λ/(2 M T_r)."""
        return self.wavelength / (2.0 * self.n_chirps * self.chirp_interval)

    # --- conversions ---------------------------------------------------------------------
    def range_to_delay(self, range_m):
        return 2.0 * np.asarray(range_m, dtype=float) / SPEED_OF_LIGHT

    def velocity_to_doppler(self, velocity_mps):
        """f_D = 2v f_c/c at the traced carrier: the snapshot's Doppler convention."""
        return 2.0 * np.asarray(velocity_mps, dtype=float) * self.traced_carrier_hz \
            / SPEED_OF_LIGHT

    def summary(self) -> dict:
        names = ("slope", "chirp_interval", "carrier_hz", "sampled_bandwidth",
                 "range_resolution", "max_range", "if_range", "max_velocity",
                 "velocity_resolution", "frame_duration")
        return {k: getattr(self, k) for k in names}


# ----------------------------------------------------------------------------------------
# IF filter
# ----------------------------------------------------------------------------------------
def if_response(waveform: FmcwWaveform, beat_hz) -> np.ndarray:
    """H_IF(f): the analog Butterworth low-pass of order ``if_filter_order`` and cutoff
    ``if_cutoff_hz`` (−3 dB) on I and Q, at the (signed) beat frequencies; steady state
    (a tone's filter transient lasts ~order/(2π B_IF), a fraction of a sample)."""
    f = np.asarray(beat_hz, dtype=float)
    b, a = ss.butter(waveform.if_filter_order, 2.0 * np.pi * waveform.if_cutoff_hz,
                     analog=True)
    _, h = ss.freqs(b, a, worN=2.0 * np.pi * f.ravel())
    return h.reshape(f.shape)


# ----------------------------------------------------------------------------------------
# synthesis
# ----------------------------------------------------------------------------------------
def _grid(waveform: FmcwWaveform):
    """Fast times t' (N,) and chirp starts u (M,)."""
    t_fast = waveform.adc_start_s + np.arange(waveform.samples_per_chirp) / waveform.adc_rate_hz
    u = np.arange(waveform.n_chirps) * waveform.chirp_interval
    return t_fast, u


def _phase(t_fast, u, tau0, fd, waveform: FmcwWaveform):
    """Φ_k(t', u) of the module docstring (radians), broadcasting over its arguments."""
    fc, f0, s = waveform.traced_carrier_hz, waveform.start_hz, waveform.slope
    t = u + t_fast
    tau = tau0 - (fd / fc) * t
    return (-2.0 * np.pi * ((f0 - fc) * tau + s * t_fast * tau - 0.5 * s * tau * tau)
            + 2.0 * np.pi * fd * t)


def beat_frequencies(delays_s, dopplers_hz, waveform: FmcwWaveform):
    """(f_fast, f_slow) of each path at the frame's centre: ∂Φ/∂t'/2π, the beat frequency
    (Hz, negative for an echo: ≈ −S·2R/c + f_D), and ∂Φ/∂u/2π, the Doppler across chirps
    (≈ f_D·f(t_c)/f_c), with the delay at the centre time t' = t_c, u = (M − 1)T_r/2."""
    tau0 = np.asarray(delays_s, dtype=float)
    fd = np.asarray(dopplers_hz, dtype=float)
    beta = fd / waveform.traced_carrier_hz
    s, f0 = waveform.slope, waveform.start_hz
    tc = waveform.window_centre_s
    uc = 0.5 * (waveform.n_chirps - 1) * waveform.chirp_interval
    tau = tau0 - beta * (uc + tc)
    f_fast = beta * f0 - s * tau + s * beta * tc - s * beta * tau
    f_slow = beta * (f0 + s * tc - s * tau)
    return f_fast, f_slow


def warn_fmcw_unmodelled(delays_s, dopplers_hz, waveform: FmcwWaveform, *, fast: bool,
                         stacklevel: int = 3) -> None:
    """Loud warnings for paths the frame cannot show where they are: a beat beyond the
    ADC's band folds onto a nearer range (``AliasingWarning``), a Doppler beyond
    ±1/(2T_r) wraps; and for the fast synthesis, an echo that arrives after the ADC
    window opens (its first samples are modelled as if it had)."""
    tau = np.asarray(delays_s, dtype=float)
    if tau.size == 0:
        return
    f_fast, f_slow = beat_frequencies(tau, dopplers_hz, waveform)
    lim = waveform.nyquist_hz
    low = -f_fast if waveform.if_type == "complex" else np.abs(f_fast)
    far = (low >= lim) | (low < 0.0) if waveform.if_type == "complex" else low >= lim
    far &= np.abs(f_fast) > 0.5 * waveform.adc_rate_hz / waveform.samples_per_chirp
    if far.any():
        i = int(np.argmax(tau))
        warnings.warn(
            f"{int(far.sum())} of {tau.size} paths beat outside the ADC's band "
            f"({float(-f_fast[i]):.6g} Hz for delays_s[{i}] = {float(tau[i])!r} s; "
            f"{waveform.if_type} IF at "
            f"{waveform.adc_rate_hz!r} Hz takes {lim!r} Hz, r_max = "
            f"{waveform.max_range:.2f} m): they fold onto nearer ranges, attenuated by the IF "
            f"filter (cutoff {waveform.if_cutoff_hz!r} Hz)", AliasingWarning,
            stacklevel=stacklevel)
    f_lim = 0.5 / waveform.chirp_interval
    wrap = (f_slow >= f_lim) | (f_slow < -f_lim)
    if wrap.any():
        i = int(np.argmax(np.abs(f_slow)))
        warnings.warn(
            f"{int(wrap.sum())} of {tau.size} paths have Doppler beyond ±1/(2T_r) = "
            f"±{f_lim:.1f} Hz (dopplers_hz[{i}]; v_max = {waveform.max_velocity:.2f} m/s): "
            "they wrap into [-v_max, v_max)", AliasingWarning, stacklevel=stacklevel)
    if fast:
        late = tau > waveform.adc_start_s
        if late.any():
            i = int(np.argmax(tau))
            warnings.warn(
                f"{int(late.sum())} of {tau.size} paths arrive after the ADC window opens "
                f"(delays_s[{i}] = {float(tau[i])!r} s > adc_start_s = "
                f"{waveform.adc_start_s!r} s): "
                "the fast synthesis gives them echo from the first sample; "
                "synthesize_beat_exact zeroes it", AliasingWarning, stacklevel=stacklevel)


def _weights(a, tau, fd, waveform):
    """a_k·H_IF at each path's beat frequency."""
    f_fast, _ = beat_frequencies(tau, fd, waveform)
    return a * if_response(waveform, f_fast)


def synthesize_beat_exact(gains, delays_s, dopplers_hz, waveform: FmcwWaveform,
                          chunk_elems: int = 1 << 22) -> np.ndarray:
    """The beat frame s(n, μ), shape (N, M), every path's Φ_k evaluated at every sample
    (module docstring), an echo counted only from the sample it has arrived at. Complex
    (I/Q); :func:`fmcw_frame` takes the real part for a real IF."""
    a, tau, fd = check_paths(gains, delays_s, dopplers_hz)
    warn_fmcw_unmodelled(tau, fd, waveform, fast=False)
    w = _weights(a, tau, fd, waveform)
    t_fast, u = _grid(waveform)
    n, m = t_fast.size, u.size
    out = np.zeros((n, m), complex)
    per = max(1, chunk_elems // (n * m))
    tf, uu = t_fast[None, :, None], u[None, None, :]
    for k0 in range(0, a.size, per):
        sl = slice(k0, k0 + per)
        t0, f = tau[sl, None, None], fd[sl, None, None]
        phase = _phase(tf, uu, t0, f, waveform)
        arrived = tf >= t0 - (f / waveform.traced_carrier_hz) * (uu + tf)
        out += np.einsum("k,knm->nm", w[sl], np.exp(1j * phase) * arrived)
    return out


def synthesize_beat(gains, delays_s, dopplers_hz, waveform: FmcwWaveform,
                    tol: float = SYNTHESIS_ACCURACY) -> np.ndarray:
    """The beat frame s(n, μ) of :func:`synthesize_beat_exact`, fast (docs/fmcw.md §2).

    Φ_k is quadratic in x = t' − t_c and y = u − u_c (centre of the frame): Φ_k = Φ_k(0)
    + 2π f_fast x + 2π f_slow y + Q_k(x, y) with Q_k = πS[2β_k x(x + y) + β_k²(x + y)²]
    (the range migration and the Doppler change within a chirp; τ_k(t) is linear in
    t). The linear part of all paths is one 2-D type-1 NUFFT (finufft, accuracy ``tol``);
    e^{jQ_k} is interpolated in β at Chebyshev nodes (error <= ``tol`` per unit path
    amplitude; one node, exact, when all β are equal), one NUFFT per node. Echoes are
    taken to have arrived before the ADC window opens (a warning says when not)."""
    import finufft

    a, tau, fd = check_paths(gains, delays_s, dopplers_hz)
    if not (1e-15 < tol < 1e-1):
        raise ArgumentError("must lie in (1e-15, 0.1)", argument="tol", value=tol)
    warn_fmcw_unmodelled(tau, fd, waveform, fast=True)
    n, m = waveform.samples_per_chirp, waveform.n_chirps
    if a.size == 0:
        return np.zeros((n, m), complex)
    t_fast, u = _grid(waveform)
    tc = waveform.window_centre_s
    uc = 0.5 * (m - 1) * waveform.chirp_interval
    x = (t_fast - tc)[:, None]
    y = (u - uc)[None, :]
    beta = fd / waveform.traced_carrier_hz
    s = waveform.slope
    f_fast, f_slow = beat_frequencies(tau, fd, waveform)
    w = _weights(a, tau, fd, waveform) * np.exp(1j * _phase(tc, uc, tau, fd, waveform))
    # index phases: sample n sits at x = (n − (N−1)/2)/f_s, chirp μ at y = (μ − (M−1)/2)T_r
    cx = f_fast / waveform.adc_rate_hz
    cy = f_slow * waveform.chirp_interval
    px, py = _wrap_phase(cx), _wrap_phase(cy)
    centre = np.exp(-2j * np.pi * (cx * (n - 1) / 2.0 + cy * (m - 1) / 2.0))
    # finufft's modes run k = −⌊N/2⌋..; n = k + ⌊N/2⌋
    shift = np.exp(1j * (n // 2 * px + m // 2 * py))
    coeff = w * centre * shift

    xy = x + y
    quad1 = 2.0 * np.pi * s * x * xy            # multiplies β
    quad2 = np.pi * s * xy * xy                 # multiplies β²
    lo, hi = float(beta.min()), float(beta.max())
    mid, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
    # the phase's β-derivative: |quad1| + 2|β|·|quad2|, bounded over the frame
    theta = float(np.abs(quad1).max() + 2.0 * max(abs(lo), abs(hi)) * np.abs(quad2).max())
    nodes_n = chebyshev_order(theta, half, tol) + (1 if half > 0 else 0)
    if nodes_n == 1:
        nodes = np.array([mid])
        ell = np.ones((beta.size, 1))
    else:
        j = np.arange(nodes_n)
        nodes = mid + half * np.cos((2 * j + 1) * np.pi / (2 * nodes_n))
        ell = _lagrange_weights(beta, nodes)
    # one plan for all nodes (n_trans = R): the points are spread once. One thread: a
    # frame-sized grid transforms in ~10 ms on one, and OpenMP's start-up and contention
    # cost more (12 transforms of 1000 points into 256 x 128 modes: 82 ms on one thread,
    # 472 ms on finufft's default, 2 cores under load)
    per_node = np.ascontiguousarray((coeff[:, None] * ell).T)
    lin = finufft.nufft2d1(px, py, per_node if nodes_n > 1 else per_node[0],
                           n_modes=(n, m), eps=tol, isign=1,
                           nthreads=FINUFFT_THREADS).reshape(nodes_n, n, m)
    out = lin[0] * np.exp(1j * (nodes[0] * quad1 + nodes[0] ** 2 * quad2))
    for r in range(1, nodes_n):
        out += lin[r] * np.exp(1j * (nodes[r] * quad1 + nodes[r] ** 2 * quad2))
    return out


# ----------------------------------------------------------------------------------------
# phase noise
# ----------------------------------------------------------------------------------------
def phase_noise_psd(offsets_hz, dbc_per_hz):
    """A single-sideband phase-noise mask L(f) (dBc/Hz at offsets, as data sheets give it)
    as a function f -> S_φ(f) (rad²/Hz, one-sided: 2·10^{L/10}), interpolated linearly
    in log f, flat beyond the ends."""
    try:
        f = np.asarray(offsets_hz, dtype=float)
        level = np.asarray(dbc_per_hz, dtype=float)
    except (TypeError, ValueError):
        raise ArgumentError("must be lists of numbers", argument="phase_noise_offsets_hz",
                            value=offsets_hz) from None
    if f.ndim != 1 or f.size < 1 or f.shape != level.shape:
        raise ArgumentError(f"must be as many levels as offsets ({f.size})",
                            argument="phase_noise_dbc_per_hz", value=dbc_per_hz)
    if not (np.all(np.isfinite(f)) and np.all(f > 0) and np.all(np.diff(f) > 0)):
        raise ArgumentError("must be positive and increasing",
                            argument="phase_noise_offsets_hz", value=offsets_hz)
    if not np.all(np.isfinite(level)):
        raise ArgumentError("must be finite", argument="phase_noise_dbc_per_hz",
                            value=dbc_per_hz)
    logf = np.log10(f)

    def psd(freq):
        q = np.log10(np.maximum(np.abs(np.asarray(freq, dtype=float)), f[0]))
        return 2.0 * 10.0 ** (np.interp(q, logf, level) / 10.0)

    return psd


def residual_phase_noise(psd, delays_s, times_s, period_s: float, rng=None) -> np.ndarray:
    """φ(t − τ_k) − φ(t) at ``times_s`` for every delay: the phase noise left in a beat
    signal after mixing with the same oscillator's chirp (shape (K, len(times))).

    φ is a stationary Gaussian process of one-sided PSD ``psd`` (rad²/Hz), drawn as a
    random Fourier series of period ``period_s`` (lines at i/period, i >= 1, variance
    S_φ(f_i)/period of φ each) and evaluated exactly at t and t − τ by a type-2 NUFFT (no
    interpolation, so nanosecond delays are resolved). Its PSD is 2(1 − cos 2πfτ)·S_φ(f):
    a close reflector's phase noise cancels (range correlation; Budge & Burt, 1993)."""
    import finufft

    tau = np.atleast_1d(np.asarray(delays_s, dtype=float))
    t = np.asarray(times_s, dtype=float).ravel()
    period = _positive("period_s", period_s)
    span = float(t.max() - t.min()) if t.size else 0.0
    if span > period * (1.0 + 1e-12):
        # the series repeats after one period: a longer record would see it again
        raise ArgumentError(f"must be at least the span of the times ({span!r} s)",
                            argument="period_s", value=period_s)
    rng = np.random.default_rng(rng)
    # lines up to the Nyquist frequency of the finest time step (the ADC's f_s/2:
    # anything above would fold), rounded up to a power of two
    steps = np.diff(np.unique(t))
    finest = float(steps.min()) if steps.size else period
    n_lines = 1 << int(math.ceil(math.log2(max(8.0, period / (2.0 * finest)))))
    f = np.arange(1, n_lines + 1) / period
    # φ(t) = 2 Re Σ_i c_i e^{j2π f_i t} with E|c_i|² = S_φ(f_i)/(2 period):
    # E φ² = Σ_i 2 E|c_i|² = Σ_i S_φ(f_i)/period ≈ ∫ S_φ df
    amp = np.sqrt(psd(f) / (2.0 * period))
    c = amp * (rng.standard_normal(n_lines) + 1j * rng.standard_normal(n_lines)) / math.sqrt(2)
    modes = np.zeros(2 * n_lines + 1, complex)
    modes[n_lines + 1:] = c
    phi = []
    for shift in np.concatenate([[0.0], tau]):
        x = _wrap_phase((t - shift) / period)
        phi.append(2.0 * finufft.nufft1d2(x, modes, isign=1, eps=1e-12,
                                          nthreads=FINUFFT_THREADS).real)
    return np.asarray(phi[1:]) - phi[0][None, :]


# ----------------------------------------------------------------------------------------
# the frame of a link, its image and its estimates
# ----------------------------------------------------------------------------------------
def fmcw_frame(paths, waveform: FmcwWaveform, *, seed: int = 0, method: str = "fast",
               tx_power_w: float | None = None, noise_figure_db: float | None = None,
               phase_noise=None, rng=None) -> np.ndarray:
    """The ADC frame (N, M) of one link's paths: ``method`` "fast" or "exact" synthesis,
    optional residual phase noise (``phase_noise``: a PSD function, as
    :func:`phase_noise_psd` returns, by default the waveform's mask where it has one;
    the frame is then built path by path), thermal
    noise kT·B·F/P_tx per I/Q sample (B = f_s, noise drawn from ``seed`` + 1), and the
    real part for a real IF (the I channel alone: 3 dB less SNR than I/Q)."""
    gains = np.asarray(paths.gain)
    if phase_noise is None and waveform.phase_noise_offsets_hz is not None:
        phase_noise = phase_noise_psd(waveform.phase_noise_offsets_hz,
                                      waveform.phase_noise_dbc_per_hz)
    if phase_noise is not None:
        s = _frame_with_phase_noise(gains, paths.delay_s, paths.doppler_hz, waveform,
                                    phase_noise, seed, method)
    elif method == "fast":
        s = synthesize_beat(gains, paths.delay_s, paths.doppler_hz, waveform)
    elif method == "exact":
        s = synthesize_beat_exact(gains, paths.delay_s, paths.doppler_hz, waveform)
    else:
        raise ArgumentError("must be 'fast' or 'exact'", argument="method", value=method)
    if tx_power_w is not None and noise_figure_db is not None:
        rng = np.random.default_rng(rng if rng is not None else seed + 1)
        var = thermal_noise_power(waveform.adc_rate_hz, noise_figure_db) / tx_power_w
        s = s + math.sqrt(var / 2.0) * (rng.standard_normal(s.shape)
                                        + 1j * rng.standard_normal(s.shape))
    return s.real.astype(complex) if waveform.if_type == "real" else s


def _frame_with_phase_noise(gains, delays_s, dopplers_hz, waveform, psd, seed, method):
    a, tau, fd = check_paths(gains, delays_s, dopplers_hz)
    t_fast, u = _grid(waveform)
    times = (u[None, :] + t_fast[:, None]).ravel()
    resid = residual_phase_noise(psd, tau, times, 2.0 * waveform.frame_duration,
                                 rng=np.random.default_rng([seed, 7]))
    synth = synthesize_beat if method == "fast" else synthesize_beat_exact
    out = np.zeros((t_fast.size, u.size), complex)
    for k in range(a.size):
        out += synth(a[k:k + 1], tau[k:k + 1], fd[k:k + 1], waveform) \
            * np.exp(1j * resid[k].reshape(out.shape))
    return out


def fmcw_image(frame, waveform: FmcwWaveform, window="hann", zero_pad=(1, 1)):
    """The range-Doppler image of a beat frame (processing.radar_image: IDFT over fast
    time, DFT over chirps, noise-normalised), cut to the range bins below the wrap for a
    real IF (its positive-frequency half mirrors the echoes)."""
    img = radar_image(frame, waveform, window, window, zero_pad[0], zero_pad[1])
    if waveform.if_type == "complex":
        return img
    half = img.power.shape[0] // 2
    # the cut map's lags: its small positive lags first, its negative ones (the full
    # map's last entries) last, as the CFAR's circular indexing reads them
    lags = img.correlation.range
    cut = np.concatenate([lags[:half - half // 2], lags[lags.size - half // 2:]])
    return RadarImage(img.power[:half], img.power_db[:half], img.range_m[:half],
                      img.velocity_mps, CellCorrelation(cut, img.correlation.doppler))


def correct_coupling(range_m, velocity_mps, waveform: FmcwWaveform):
    """Range and velocity from an image's raw (bin-scaled) estimates: the beat holds
    −S·2R/c + f_D·f(t_c)/f_c, so a moving target sits v·f(t_c)/S too near, and the
    Doppler across chirps is scaled by 1 − S·2R/(c f(t_c)) (docs/fmcw.md §3)."""
    r = np.asarray(range_m, dtype=float)
    v = np.asarray(velocity_mps, dtype=float)
    fw, s = waveform.carrier_hz, waveform.slope
    r_true = r
    for _ in range(3):
        v_true = v / (1.0 - 2.0 * s * r_true / (SPEED_OF_LIGHT * fw))
        r_true = r + v_true * fw / s
    return r_true, v_true


def fmcw_cramer_rao_bound(waveform: FmcwWaveform, snr_per_cell):
    """Cramér-Rao bound of range and velocity for one target in the beat frame: the OFDM
    bound of the (independent) two frequencies (estimation.cramer_rao_bound, with
    Δf = S/f_s, T_sym = T_r), the range's carrying the velocity's through the coupling
    correction R = r_raw + v f(t_c)/S."""
    raw = cramer_rao_bound(waveform, snr_per_cell)
    lever = waveform.carrier_hz / waveform.slope
    return CramerRaoBound(np.sqrt(raw.range_m ** 2 + (lever * raw.velocity_mps) ** 2),
                          raw.velocity_mps)
