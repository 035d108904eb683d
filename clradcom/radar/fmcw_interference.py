"""One FMCW radar's chirps in another's beat signal: the interference, its closed forms,
and the burst detection and repair that mitigates it (docs/fmcw.md §5).

The interferer's chirps reach the victim through a link's paths (gain a_k at the traced
carrier, one-way delay τ_k, Doppler f_D,k); the victim mixes them with the conjugate of
its own chirp. Their difference frequency

    Δf(t) = (f_0,I − f_0,V) + S_I t_I − S_V t_V + f_D

(t_I, t_V the interferer's and the victim's fast times at t) sweeps at S_I − S_V; the IF
filter passes it while |Δf| < B_IF. Sampled as a_k H_IF(Δf(t)) e^{jψ(t)}: the filter
taken as quasi-static along the sweep, good while the sweep crosses the filter's band
slowly against its response time, |S_I − S_V| ≪ B_IF² (docs/fmcw.md §5; Kim, Lee et al.
and Toth et al. use the same picture: M. Toth, P. Meissner, A. Melzer, K. Witrisal,
"Analytical investigation of non-coherent mutual FMCW radar interference", EuRAD 2018).

Closed forms: a burst of duration 2B_IF/|S_I − S_V| (at −3 dB of the filter) and energy
|a|² f_s ∫|H|² df / |S_I − S_V| per crossing, spread over every range bin; for equal
slopes a constant Δf, i.e. a ghost target at R = c(τ + t_d − (f_0,I − f_0,V)/S)/2 (t_d the
interferer's chirp start after the victim's).
"""

from __future__ import annotations

import math

import numpy as np

from clradcom.errors import ArgumentError
from clradcom.radar.fmcw import FINUFFT_THREADS, FmcwWaveform, _grid, if_response
from clradcom.radar.synthesis import _wrap_phase, check_paths
from clradcom.radar.waveform import SPEED_OF_LIGHT, Waveform, check_symbols

__all__ = ["burst_duration", "burst_energy", "burst_floor_power", "chirp_interference",
           "chirp_into_ofdm",
           "floor_rise_db", "ghost_range", "ofdm_burst_energy", "ofdm_floor_rise_db",
           "ofdm_into_fmcw", "ofdm_energy_per_chirp",
           "repair_bursts", "butterworth_noise_bandwidth"]


def _check_waveforms(victim, interferer):
    for name, wf in (("victim", victim), ("interferer", interferer)):
        if not isinstance(wf, FmcwWaveform):
            raise ArgumentError("must be an FmcwWaveform", argument=name, value=wf)


def chirp_interference(victim: FmcwWaveform, interferer: FmcwWaveform, gains, delays_s,
                       dopplers_hz, start_offset_s: float = 0.0) -> np.ndarray:
    """The interferer's chirps in the victim's ADC frame (N, M), through the link's paths
    (``gains`` at the traced carrier, one-way ``delays_s``, ``dopplers_hz``); its frame
    starts ``start_offset_s`` after the victim's (either may be earlier: its chirps are
    taken to run before and after the frame as within it). Complex I/Q; the real part is
    what a real IF keeps."""
    _check_waveforms(victim, interferer)
    a, tau, fd = check_paths(gains, delays_s, dopplers_hz)
    t_off = float(start_offset_s)
    if not math.isfinite(t_off):
        raise ArgumentError("must be finite", argument="start_offset_s", value=start_offset_s)
    t_fast, u = _grid(victim)
    t = u[None, :] + t_fast[:, None]  # (N, M) absolute time of every sample
    fc = victim.traced_carrier_hz
    f0v, sv = victim.start_hz, victim.slope
    f0i, si = interferer.start_hz, interferer.slope
    out = np.zeros(t.shape, complex)
    for k in range(a.size):
        t_rx = t - tau[k] - t_off  # the interferer's own time of what arrives at t
        nu = np.floor(t_rx / interferer.chirp_interval)
        t_i = t_rx - nu * interferer.chirp_interval
        on = t_i < interferer.chirp_s
        # the oscillators run continuously; each chirp ramps the frequency from f_0
        cycles = ((f0i - f0v) * t - (f0i - fc) * tau[k] + 0.5 * si * t_i * t_i
                  - 0.5 * sv * t_fast[:, None] ** 2 + fd[k] * t)
        delta_f = (f0i - f0v) + si * t_i - sv * t_fast[:, None] + fd[k]
        out += np.where(on, a[k] * if_response(victim, delta_f)
                        * np.exp(2j * np.pi * (cycles - np.floor(cycles))), 0.0)
    return out


def burst_duration(victim: FmcwWaveform, interferer: FmcwWaveform) -> float:
    """2 B_IF/|S_I − S_V|: how long the difference frequency stays within the IF filter's
    −3 dB band (s); infinite for equal slopes."""
    _check_waveforms(victim, interferer)
    ds = abs(interferer.slope - victim.slope)
    return math.inf if ds == 0 else 2.0 * victim.if_cutoff_hz / ds


def butterworth_noise_bandwidth(cutoff_hz: float, order: int) -> float:
    """∫|H(f)|² df over all f (two-sided) of a Butterworth low-pass, 2 f_c (π/2n)/sin(π/2n)."""
    x = math.pi / (2.0 * order)
    return 2.0 * cutoff_hz * x / math.sin(x)


def burst_energy(victim: FmcwWaveform, interferer: FmcwWaveform, gain) -> float:
    """Σ|i(n)|² of one burst of a path of gain ``gain``: |a|² f_s ∫|H|²df / |S_I − S_V|
    (the samples within the burst, each |a H(Δf)|², Δf moving (S_I − S_V)/f_s per
    sample)."""
    _check_waveforms(victim, interferer)
    ds = abs(interferer.slope - victim.slope)
    if ds == 0:
        raise ArgumentError("equal slopes make no burst but a ghost (ghost_range)",
                            argument="interferer", value=interferer.slope)
    nb = butterworth_noise_bandwidth(victim.if_cutoff_hz, victim.if_filter_order)
    return abs(complex(gain)) ** 2 * victim.adc_rate_hz * nb / ds


def burst_floor_power(victim: FmcwWaveform, interferer: FmcwWaveform, gain,
                      beat_hz) -> np.ndarray:
    """The power per cell (rectangular windows, noise-normalised: a sample's noise σ²
    is a cell's σ²) that one burst per chirp of a path of gain ``gain`` leaves in the
    range bins of beat frequencies ``beat_hz``: the burst sweeps f at (S_I − S_V),
    spending df/|S_I − S_V| in each df, so a bin (df = f_s/N) gets
    |a H(f)|² f_s²/(N |S_I − S_V|); its phase, random from chirp to chirp, spreads it over
    the Doppler cells alike."""
    _check_waveforms(victim, interferer)
    ds = abs(interferer.slope - victim.slope)
    if ds == 0:
        raise ArgumentError("equal slopes make no burst but a ghost (ghost_range)",
                            argument="interferer", value=interferer.slope)
    h2 = np.abs(if_response(victim, beat_hz)) ** 2
    return abs(complex(gain)) ** 2 * h2 * victim.adc_rate_hz ** 2 \
        / (victim.samples_per_chirp * ds)


def floor_rise_db(victim: FmcwWaveform, interferer: FmcwWaveform, gain, noise_variance: float,
                  beat_hz) -> np.ndarray:
    """The rise of the range-Doppler image's floor (rectangular windows) at beat
    frequencies ``beat_hz`` when every chirp carries one burst of a path of gain ``gain``
    (:func:`burst_floor_power` over the noise's σ²):
    10 log10(1 + |a H(f)|² f_s² / (N |S_I − S_V| σ²)). Over the IF band, not beyond."""
    _check_waveforms(victim, interferer)
    if not (noise_variance > 0):
        raise ArgumentError("must be positive", argument="noise_variance", value=noise_variance)
    per_bin = burst_floor_power(victim, interferer, gain, beat_hz)
    return 10.0 * np.log10(1.0 + per_bin / noise_variance)


def ghost_range(victim: FmcwWaveform, interferer: FmcwWaveform, delay_s: float,
                chirp_offset_s: float) -> float:
    """Range at which an equal-slope interferer shows as a target: its difference
    frequency (f_0,I − f_0,V) − S(τ + t_d) is the beat of an echo at
    R = c(τ + t_d − (f_0,I − f_0,V)/S)/2 (one-way delay τ, its chirps starting t_d after
    the victim's)."""
    _check_waveforms(victim, interferer)
    if not math.isclose(interferer.slope, victim.slope, rel_tol=1e-12):
        raise ArgumentError("a ghost needs equal slopes (unequal ones make bursts)",
                            argument="interferer", value=interferer.slope)
    s = victim.slope
    return SPEED_OF_LIGHT * (delay_s + chirp_offset_s
                             - (interferer.start_hz - victim.start_hz) / s) / 2.0


def repair_bursts(frame, threshold: float = 4.0, guard: int = 2):
    """Burst mitigation: in every chirp, the samples whose magnitude exceeds ``threshold``
    times the chirp's robust spread σ̂ = median|x|/0.8326 (the rms of complex Gaussian
    noise: its magnitude's median is σ·sqrt(ln 2); noise alone passes 4σ with probability
    e^{-16} ≈ 1e-7 per sample) are replaced, with ``guard`` samples on each side, by
    linear interpolation between the clean samples around them. Returns (repaired frame,
    mask of the replaced samples)."""
    x = np.array(frame, dtype=complex, copy=True)
    if x.ndim != 2:
        raise ArgumentError("must be (samples, chirps)", argument="frame", value=x.shape)
    if not (threshold > 0) or isinstance(guard, bool) or not isinstance(guard, int) \
            or guard < 0:
        raise ArgumentError("threshold > 0 and an integer guard >= 0", argument="threshold",
                            value=(threshold, guard))
    mag = np.abs(x)
    spread = np.median(mag, axis=0) / 0.8326
    hit = mag > threshold * spread[None, :]
    if guard:
        kernel = np.ones(2 * guard + 1)
        hit = np.apply_along_axis(lambda c: np.convolve(c, kernel, "same") > 0, 0, hit)
    n = np.arange(x.shape[0])
    for m in np.flatnonzero(hit.any(axis=0)):
        bad = hit[:, m]
        good = ~bad
        if good.sum() < 2:
            x[:, m] = 0.0
            continue
        x[bad, m] = (np.interp(n[bad], n[good], x[good, m].real)
                     + 1j * np.interp(n[bad], n[good], x[good, m].imag))
    return x, hit


# ----------------------------------------------------------------------------------------
# FMCW into OFDM
# ----------------------------------------------------------------------------------------
def chirp_into_ofdm(victim: Waveform, interferer: FmcwWaveform, gains, delays_s,
                    dopplers_hz, start_offset_s: float = 0.0) -> np.ndarray:
    """An FMCW radar's chirps in an OFDM radar's capture: the M·L samples at f_s = NΔf of
    :func:`clradcom.radar.synthesis.synthesize_time_domain` (t = 0 the frame's start),
    through the link's paths, its frame starting ``start_offset_s`` after the OFDM one's.
    The OFDM receiver takes its band [f_c, f_c + NΔf) (subcarrier n at f_c + nΔf) and no
    more: a chirp counts while its frequency lies there (an ideal anti-alias filter; the
    project's OFDM receiver has no other)."""
    if not isinstance(victim, Waveform):
        raise ArgumentError("must be an OFDM Waveform", argument="victim", value=victim)
    if not isinstance(interferer, FmcwWaveform):
        raise ArgumentError("must be an FmcwWaveform", argument="interferer", value=interferer)
    a, tau, fd = check_paths(gains, delays_s, dopplers_hz)
    t = np.arange(victim.n_samples) / victim.sample_rate
    fc, f0, s = victim.carrier_hz, interferer.start_hz, interferer.slope
    out = np.zeros(t.shape, complex)
    for k in range(a.size):
        t_rx = t - tau[k] - float(start_offset_s)
        t_i = t_rx - np.floor(t_rx / interferer.chirp_interval) * interferer.chirp_interval
        f_base = (f0 - fc) + s * t_i + fd[k]  # above the OFDM carrier
        inside = (t_i < interferer.chirp_s) & (f_base >= 0.0) & (f_base < victim.bandwidth)
        cycles = ((f0 - fc) * t - (f0 - interferer.traced_carrier_hz) * tau[k]
                  + 0.5 * s * t_i * t_i + fd[k] * t)
        out += np.where(inside, a[k] * np.exp(2j * np.pi * (cycles - np.floor(cycles))), 0.0)
    return out


def ofdm_burst_energy(victim: Waveform, interferer: FmcwWaveform, gain) -> float:
    """Σ|i|² of one chirp's crossing of the OFDM band: it stays B/S there, f_s = B samples
    per second, |a|² each: |a|² B²/S."""
    b = victim.bandwidth
    return abs(complex(gain)) ** 2 * b * b / interferer.slope


def ofdm_floor_rise_db(victim: Waveform, interferer: FmcwWaveform, gain, crossings: int,
                       noise_variance: float) -> float:
    """The OFDM image floor's rise from ``crossings`` chirp crossings in its frame:
    the receiver keeps N of every L samples (the cyclic prefixes dropped), its unitary DFT
    and the division by unit-modulus symbols keep the power and whiten it over the N·M
    cells: 10 log10(1 + crossings·|a|²B²/S / (L·M·σ²))."""
    if not (noise_variance > 0):
        raise ArgumentError("must be positive", argument="noise_variance", value=noise_variance)
    e = crossings * ofdm_burst_energy(victim, interferer, gain)
    return 10.0 * math.log10(1.0 + e / (victim.samples_per_symbol * victim.n_symbols
                                        * noise_variance))


# ----------------------------------------------------------------------------------------
# OFDM into FMCW
# ----------------------------------------------------------------------------------------
#: the IF filter is taken to stop everything beyond this many cutoffs (a 4th-order
#: Butterworth: −72 dB at 8 B_IF); the OFDM signal is mixed only where the chirp is
#: within that of its band
IF_REACH = 8.0


def _ofdm_at(times_s, symbols, waveform: Waveform) -> np.ndarray:
    """The CP-OFDM transmit signal (synthesis.synthesize_time_domain's x(t), unit mean
    power) at arbitrary times, frames repeating back to back: inside symbol ν,
    x = (1/√N) Σ_n D(n, ν mod M) e^{j2πnΔf(t − νT_sym − T_CP)} (the prefix is the same
    polynomial's continuation). One type-2 NUFFT per symbol."""
    import finufft

    t = np.asarray(times_s, dtype=float)
    n = waveform.n_subcarriers
    nu_abs = np.floor(t / waveform.symbol_duration)
    t_loc = t - nu_abs * waveform.symbol_duration - waveform.cp_duration
    nu = (nu_abs % waveform.n_symbols).astype(np.int64)
    out = np.zeros(t.shape, complex)
    order = np.argsort(nu, kind="stable")
    uniq, first = np.unique(nu[order], return_index=True)
    bounds = np.append(first, order.size)
    for i, sym in enumerate(uniq):
        idx = order[bounds[i]:bounds[i + 1]]
        x = _wrap_phase(waveform.subcarrier_spacing_hz * t_loc[idx])
        modes = np.ascontiguousarray(symbols[:, sym])
        val = finufft.nufft1d2(x, modes, isign=1, eps=1e-12, nthreads=FINUFFT_THREADS)
        out[idx] = val * np.exp(1j * (n // 2) * x) / math.sqrt(n)
    return out


def ofdm_into_fmcw(victim: FmcwWaveform, interferer: Waveform, symbols, gains, delays_s,
                   dopplers_hz, start_offset_s: float = 0.0) -> np.ndarray:
    """An OFDM radar's frames (``symbols`` (N, M), repeated back to back, starting
    ``start_offset_s`` after the victim's frame) in an FMCW radar's ADC frame (N_V, M_V),
    through the link's paths. Each chirp is simulated at an oversampled rate from its
    start: the OFDM signal received, mixed with the conjugate of the chirp, the IF
    filter applied exactly (its analog response on the segment's spectrum, zero padded
    past its memory), then sampled at the ADC instants. Where the chirp is farther than
    :data:`IF_REACH` cutoffs from the OFDM band the mixed signal is left out."""
    if not isinstance(victim, FmcwWaveform):
        raise ArgumentError("must be an FmcwWaveform", argument="victim", value=victim)
    if not isinstance(interferer, Waveform):
        raise ArgumentError("must be an OFDM Waveform", argument="interferer",
                            value=interferer)
    d = check_symbols(symbols, interferer)
    a, tau, fd = check_paths(gains, delays_s, dopplers_hz)
    fs, b_if = victim.adc_rate_hz, victim.if_cutoff_hz
    band_lo = interferer.carrier_hz
    band_hi = interferer.carrier_hz + interferer.bandwidth
    q = max(2, int(math.ceil((interferer.bandwidth + 2 * IF_REACH * b_if) / fs)))
    f_fine = q * fs
    k0 = int(math.ceil(victim.adc_start_s * f_fine))
    n_fine = k0 + victim.samples_per_chirp * q
    t_fast = victim.adc_start_s + (np.arange(n_fine) - k0) / f_fine  # t' from ~0
    memory = int(math.ceil(50.0 / (2.0 * math.pi * b_if) * f_fine))
    n_fft = 1 << int(math.ceil(math.log2(n_fine + memory)))
    h = if_response(victim, np.fft.fftfreq(n_fft, 1.0 / f_fine))
    lo = victim.start_hz + victim.slope * t_fast  # the chirp's frequency
    near = (lo > band_lo - IF_REACH * b_if) & (lo < band_hi + IF_REACH * b_if) & (t_fast >= 0)
    sample_at = k0 + np.arange(victim.samples_per_chirp) * q
    f0v, s = victim.start_hz, victim.slope
    # every chirp's segment at once (M, samples near the band), path by path
    t = (np.arange(victim.n_chirps) * victim.chirp_interval)[:, None] + t_fast[near][None, :]
    seg = np.zeros((victim.n_chirps, n_fine), complex)
    for k in range(a.size):
        x = _ofdm_at((t - tau[k] - start_offset_s).ravel(), d, interferer).reshape(t.shape)
        cycles = ((band_lo - f0v) * t - 0.5 * s * t_fast[near] ** 2
                  - (band_lo - victim.traced_carrier_hz) * tau[k] + fd[k] * t)
        seg[:, near] += a[k] * x * np.exp(2j * np.pi * (cycles - np.floor(cycles)))
    filtered = np.fft.ifft(np.fft.fft(seg, n_fft, axis=1) * h[None, :], axis=1)[:, :n_fine]
    return np.ascontiguousarray(filtered[:, sample_at].T)


def ofdm_energy_per_chirp(victim: FmcwWaveform, gain) -> float:
    """Σ|i(n)|² in one chirp of an OFDM interferer whose band the chirp crosses inside the
    ADC window: the OFDM's power |a|² spread evenly over its band B (|a|²/B per Hz), the
    chirp spending df/S at each frequency, the filter passing ∫|H|²df around it:
    |a|² f_s ∫|H|²df / S, whatever B."""
    nb = butterworth_noise_bandwidth(victim.if_cutoff_hz, victim.if_filter_order)
    return abs(complex(gain)) ** 2 * victim.adc_rate_hz * nb / victim.slope
