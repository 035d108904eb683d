"""Two radars of any kinds on one traced street: an FMCW radar and an OFDM radar (or two
FMCW radars) interfering through the traced link between them, each pair measured
against its closed form and mitigated (docs/interference.md §6, docs/fmcw.md §5).

The victim receives its own echoes (its monostatic link), the interferer's signal
through the interferer -> victim link's paths (one-way gains, delays, Dopplers, scaled
by √(P_I/P_V), with the interferer's carrier offset and phase) and thermal noise:

- FMCW -> FMCW (:func:`clradcom.radar.fmcw_interference.chirp_interference`): unequal
  slopes make a burst in every chirp the sweeps cross in, 2B_IF/|S_I − S_V| long, which
  raises the floor of every range bin inside the IF band; equal slopes (and chirp
  intervals) make a ghost target at R = c(τ + t_d − Δf_0/S)/2;
- OFDM -> FMCW (:func:`~clradcom.radar.fmcw_interference.ofdm_into_fmcw`): the OFDM
  band's power density through the IF filter while the chirp crosses it;
- FMCW -> OFDM (:func:`~clradcom.radar.fmcw_interference.chirp_into_ofdm`): the chirps'
  crossings of the OFDM band, white after the division by the victim's symbols.

The closed forms here take the link's frequency response H(ν) = Σ_k a_k
e^{−j2π(ν − f_c)τ_k} at the frequency each crossing happens at, in place of one path's
|a|² (a chirp through a few paths of nanosecond spread is the chirp with its amplitude
H at its instantaneous frequency). Mitigation: an FMCW victim repairs its bursts
(:func:`~clradcom.radar.fmcw_interference.repair_bursts`, detected on the frame less its
mean over chirps, where the victim's own returns that move with it cancel); an OFDM
victim bridges the symbols a chirp crossed along slow time
(:func:`bridge_crossed_symbols`). OFDM -> OFDM stays :func:`clradcom.radar.interference.
two_radar_run`, bit for bit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from clradcom.errors import ArgumentError
from clradcom.radar.fmcw import FmcwWaveform, fmcw_frame, fmcw_image, if_response
from clradcom.radar.fmcw_interference import (
    burst_duration,
    burst_floor_power,
    chirp_interference,
    chirp_into_ofdm,
    ghost_range,
    ofdm_into_fmcw,
    repair_bursts,
)
from clradcom.radar.interference import image_floor
from clradcom.radar.pipeline import fmcw_frame_result, frame_result, radar_frame_parts
from clradcom.radar.synthesis import check_paths, thermal_noise_power
from clradcom.radar.waveform import Waveform, ofdm_demodulate, random_symbols

__all__ = ["MIXED_IMAGES", "MIXED_STAGES", "MixedResult", "bridge_crossed_symbols",
           "chirp_band_energy", "fmcw_burst_floor", "link_response", "mixed_pair_run",
           "ofdm_band_floor", "strong_paths"]

#: the images of a mixed run, in order
MIXED_IMAGES = ("clean", "interfered", "mitigated")
#: the stages :func:`mixed_pair_run` announces to its ``progress``, in order
MIXED_STAGES = ("victim's frame", "interferer's signal through the link",
                "images, floors and closed forms", "mitigation")
#: link paths weaker than the strongest by more than this are left out of the
#: interferer's synthesis (their summed power is reported)
LINK_FLOOR_DB = 40.0


def strong_paths(gains, delays_s, dopplers_hz, floor_db: float = LINK_FLOOR_DB):
    """The paths within ``floor_db`` of the strongest: (gains, delays, Dopplers, the
    share of the link's summed power |a|² left out)."""
    a, tau, fd = check_paths(gains, delays_s, dopplers_hz)
    if a.size == 0:
        raise ArgumentError("the interferer -> victim link has no paths: the radars do not "
                            "reach each other", argument="link_paths", value=0)
    p = np.abs(a) ** 2
    keep = p >= p.max() * 10.0 ** (-floor_db / 10.0)
    return a[keep], tau[keep], fd[keep], float(p[~keep].sum() / p.sum())


def link_response(frequency_hz, gains, delays_s, carrier_hz: float) -> np.ndarray:
    """H(ν) = Σ_k a_k e^{−j2π(ν − f_c)τ_k}: the link's transfer function at RF
    frequencies ν (a_k holds the carrier phase −2πf_cτ_k)."""
    nu = np.asarray(frequency_hz, dtype=float)
    a = np.asarray(gains, complex)
    tau = np.asarray(delays_s, float)
    phase = -2.0 * np.pi * np.multiply.outer(nu - carrier_hz, tau)
    return np.exp(1j * phase) @ a


def fmcw_burst_floor(victim: FmcwWaveform, interferer: FmcwWaveform, gains, delays_s,
                     dopplers_hz, start_offset_s: float, beat_hz) -> np.ndarray:
    """The interference power per cell (rectangular windows, the image's noise-normalised
    units) that unequal-slope bursts through a link leave at beat frequencies ``beat_hz``,
    averaged over the victim's chirps: each victim chirp m and interferer chirp ν whose
    difference frequency (of the strongest path, delay τ, Doppler f_D) passes f inside
    the victim's ADC window and the interferer's chirp adds |H(ν_RF)|²|H_IF(f)|²
    f_s²/(N|S_I − S_V|) (:func:`~clradcom.radar.fmcw_interference.burst_floor_power`),
    ν_RF the interferer's frequency at that instant."""
    a, tau, fd = check_paths(gains, delays_s, dopplers_hz)
    ds = interferer.slope - victim.slope
    if ds == 0:
        raise ArgumentError("equal slopes make a ghost, not bursts", argument="interferer",
                            value=interferer.slope)
    ref = int(np.argmax(np.abs(a)))
    f = np.asarray(beat_hz, float)
    window = victim.samples_per_chirp / victim.adc_rate_hz
    t_ri, t_rv = interferer.chirp_interval, victim.chirp_interval
    delay = tau[ref] + float(start_offset_s)
    acc = np.zeros(f.shape)
    for m in range(victim.n_chirps):
        t0 = m * t_rv + victim.adc_start_s
        first = math.floor((t0 - delay - interferer.chirp_s) / t_ri)
        last = math.floor((t0 + window - delay) / t_ri)
        for nu in range(first, last + 1):
            start = delay + nu * t_ri  # the interferer's chirp ν arrives
            t_f = (f - (interferer.start_hz - victim.start_hz) - fd[ref]
                   + interferer.slope * start - victim.slope * m * t_rv) / ds
            t_i = t_f - start
            on = (t_f >= t0) & (t_f < t0 + window) & (t_i >= 0) & (t_i < interferer.chirp_s)
            if on.any():
                rf = interferer.start_hz + interferer.slope * t_i[on]
                acc[on] += np.abs(link_response(rf, a, tau, victim.traced_carrier_hz)) ** 2
    return burst_floor_power(victim, interferer, 1.0, f) * acc / victim.n_chirps


def ofdm_band_floor(victim: FmcwWaveform, interferer: Waveform, gains, delays_s,
                    beat_hz, samples: int = 4096) -> np.ndarray:
    """The interference power per cell (rectangular windows) an OFDM radar's band leaves
    in an FMCW victim at beat frequencies ``beat_hz``: its power density |H(ν)|²/B over
    [f_c, f_c + B), met by the chirp at ν = f_V(t) + f while it sweeps the ADC window,
    through the IF filter: |H_IF(f)|² f_s²/(N S) · (1/B)∫|H(ν)|²dν over the band's part
    the window sweeps (|a|²|H_IF|²f_s²/(N S) for one path whose band is crossed whole:
    :func:`~clradcom.radar.fmcw_interference.ofdm_energy_per_chirp` per bin)."""
    f = np.asarray(beat_hz, float)
    lo, b = interferer.carrier_hz, interferer.bandwidth
    nu = lo + (np.arange(samples) + 0.5) * b / samples
    h2 = np.abs(link_response(nu, gains, delays_s, victim.traced_carrier_hz)) ** 2
    f_start = victim.start_hz + victim.slope * victim.adc_start_s
    f_end = f_start + victim.slope * victim.samples_per_chirp / victim.adc_rate_hz
    out = np.empty(f.shape)
    for i, fi in np.ndenumerate(f):
        swept = (nu >= f_start + fi) & (nu < f_end + fi)
        out[i] = h2[swept].sum() * (b / samples) / b
    scale = np.abs(if_response(victim, f)) ** 2 * victim.adc_rate_hz ** 2 \
        / (victim.samples_per_chirp * victim.slope)
    return scale * out


def chirp_band_energy(victim: Waveform, interferer: FmcwWaveform, gains, delays_s,
                      dopplers_hz, start_offset_s: float, samples: int = 2048) -> float:
    """Σ|i|² that an FMCW radar's chirps leave in an OFDM victim's frame through a link:
    each chirp stays in the band [f_c, f_c + B) while its frequency ν (the strongest
    path's delay and Doppler) lies there, f_s = B samples a second, |H(ν)|² each, so a
    crossing whole holds (B/S)∫|H(ν)|²dν (|a|²B²/S for one path:
    :func:`~clradcom.radar.fmcw_interference.ofdm_burst_energy`); the crossings' parts
    inside the frame [0, M·L/f_s) are counted."""
    a, tau, fd = check_paths(gains, delays_s, dopplers_hz)
    ref = int(np.argmax(np.abs(a)))
    fs, b = victim.sample_rate, victim.bandwidth
    frame = victim.n_samples / fs
    s, t_r = interferer.slope, interferer.chirp_interval
    delay = tau[ref] + float(start_offset_s)
    # the chirp's time in the band: t_i in [t_lo, t_hi) within its ramp
    t_lo = max((victim.carrier_hz - interferer.start_hz - fd[ref]) / s, 0.0)
    t_hi = min((victim.carrier_hz + b - interferer.start_hz - fd[ref]) / s,
               interferer.chirp_s)
    if t_hi <= t_lo:
        return 0.0
    energy = 0.0
    for nu in range(math.floor((0.0 - delay - t_hi) / t_r),
                    math.floor((frame - delay - t_lo) / t_r) + 1):
        start = delay + nu * t_r
        lo, hi = max(start + t_lo, 0.0), min(start + t_hi, frame)
        if hi <= lo:
            continue
        t = lo + (np.arange(samples) + 0.5) * (hi - lo) / samples
        rf = interferer.start_hz + s * (t - start) + fd[ref]
        h2 = np.abs(link_response(rf, a, tau, victim.carrier_hz)) ** 2
        energy += fs * float(h2.mean()) * (hi - lo)
    return energy


def bridge_crossed_symbols(received, symbols, threshold: float = 6.0):
    """An OFDM victim's mitigation of an FMCW interferer: the symbols a chirp crossed
    carry more energy in F − F̄ (F = D_r/D, F̄ its mean over the symbols: the returns that
    move with the radar, the same in every symbol) than the others, whose share of it,
    the moving returns' and the noise's, is the same in every symbol. Those above the
    median by ``threshold`` robust spreads (1.4826·MAD) are replaced, subcarrier by
    subcarrier, by linear interpolation over the clean symbols around them (an echo
    turns by f_D·T_sym, a few hundredths of a cycle per symbol on the street: the
    burst repair of an FMCW victim, along slow time). Returns (the received symbols
    D_r with those replaced, mask of the symbols replaced)."""
    dr = np.asarray(received, complex)
    d = np.asarray(symbols, complex)
    f = dr / d
    energy = np.sum(np.abs(f - f.mean(axis=1, keepdims=True)) ** 2, axis=0)
    med = np.median(energy)
    spread = 1.4826 * np.median(np.abs(energy - med))
    hit = energy > med + threshold * spread
    mask = np.broadcast_to(hit[:, None], (hit.size, f.shape[0]))
    return _bridge(f.T, mask).T * d, hit


@dataclass
class MixedResult:
    """Numbers and images of one victim/interferer pair of any kinds."""

    victim_kind: str                # "ofdm" or "fmcw"
    interferer_kind: str
    results: dict                   # MIXED_IMAGES -> the radar chain's FrameResult
    floors: dict                    # MIXED_IMAGES -> image floor (median/ln 2, chain image)
    measured_floor_rise_db: float   # inside the IF band (FMCW) / the whole image (OFDM)
    predicted_floor_rise_db: float  # the closed form through the link
    link_paths_used: int
    link_power_left_out: float      # share of the link's Σ|a|² below LINK_FLOOR_DB
    mitigation: str                 # what the victim did
    mitigated_share: float          # samples (FMCW) or symbols (OFDM) replaced
    burst_duration_s: float = math.nan            # measured, FMCW victim, unequal slopes
    predicted_burst_duration_s: float = math.nan  # 2 B_IF/|S_I − S_V|
    ghost_range_m: float = math.nan               # measured, equal slopes
    predicted_ghost_range_m: float = math.nan


def _fmcw_noise(shape, waveform: FmcwWaveform, tx_power_w, noise_figure_db, seed):
    # fmcw_frame's draw (seed + 1), so the clean frame is the radar chain's bit for bit
    rng = np.random.default_rng(seed + 1)
    var = thermal_noise_power(waveform.adc_rate_hz, noise_figure_db) / tx_power_w
    return math.sqrt(var / 2.0) * (rng.standard_normal(shape)
                                   + 1j * rng.standard_normal(shape)), var


def _beat_axis(waveform: FmcwWaveform) -> np.ndarray:
    """The beat frequency of each range bin of an unpadded image (folded into
    [−f_s/2, f_s/2): a farther echo beats lower)."""
    n, fs = waveform.samples_per_chirp, waveform.adc_rate_hz
    beat = -np.arange(n) * fs / n
    return (beat + fs / 2) % fs - fs / 2


def _bin_floors(frame, waveform) -> np.ndarray:
    """Per range bin the floor of the rectangular-window image: median over the Doppler
    cells / ln 2 (a few cells hold targets)."""
    return np.median(fmcw_image(frame, waveform, window="rect").power, axis=1) / math.log(2)


def _burst_length(interference, waveform) -> float:
    """The measured burst length (s): the time the interference's own frequency (its
    phase step from sample to sample, where its power is within 20 dB of the bursts'
    peak, so nothing folds: the filter is −20 dB at 1.8 B_IF < f_s/2) stays within the
    IF filter's −3 dB band ±B_IF, averaged over the chirps whose burst lies whole inside
    the window. The frequency, not the power: the link's paths ripple the burst's power
    as it sweeps, not its frequency."""
    x = np.asarray(interference)
    p = np.abs(x) ** 2
    step = np.angle(x[1:] * np.conj(x[:-1])) * waveform.adc_rate_hz / (2.0 * np.pi)
    strong = (np.minimum(p[1:], p[:-1]) >= 0.01 * p.max(initial=0.0)) & (p[1:] > 0)
    inside = strong & (np.abs(step) <= waveform.if_cutoff_hz)
    counts = []
    for m in range(x.shape[1]):
        on = np.flatnonzero(inside[:, m])
        if on.size and on[0] > 0 and on[-1] < inside.shape[0] - 1:
            counts.append(on.size)
    return float(np.mean(counts)) / waveform.adc_rate_hz if counts else math.nan


def _ghost(clean, interfered, want_m, waveform) -> float:
    """Range of the interfered frame's detection nearest ``want_m`` that the clean frame
    has not (NaN when there is none)."""
    old = clean.detections
    best = math.nan
    for d in interfered.detections:
        known = old.size and np.min(np.abs(old["range_m"] - d["range_m"])
                                    + np.abs(old["velocity_mps"] - d["velocity_mps"])) < \
            waveform.range_resolution
        if not known and (math.isnan(best) or abs(d["range_m"] - want_m)
                          < abs(best - want_m)):
            best = float(d["range_m"])
    return best


def mixed_pair_run(own_paths, link_paths, victim, interferer, *, tx_power_w: float,
                   interferer_tx_power_w: float, noise_figure_db: float,
                   start_offset_s: float, cfo_hz: float = 0.0, phase_rad: float = 0.0,
                   seed: int = 0, method: str = "fast", progress=None) -> MixedResult:
    """One victim/interferer pair with at least one FMCW radar: the victim's frame
    (the radar chain's with ``seed``, ``method``), the interferer's signal through
    ``link_paths`` (interferer -> victim; its frame starting ``start_offset_s`` after the
    victim's, its carrier ``cfo_hz`` off and ``phase_rad`` turned, its power
    ``interferer_tx_power_w`` relative to the victim's ``tx_power_w``, the OFDM
    interferer's data from (``seed``, 13)), the images clean, interfered and mitigated,
    and the closed forms (module docstring)."""
    if not (isinstance(victim, FmcwWaveform) or isinstance(interferer, FmcwWaveform)):
        raise ArgumentError("two OFDM radars: run clradcom.radar.interference."
                            "two_radar_run", argument="victim", value=victim)
    for w, name in ((victim, "victim"), (interferer, "interferer")):
        if not isinstance(w, Waveform | FmcwWaveform):
            raise ArgumentError("must be a Waveform or an FmcwWaveform", argument=name,
                                value=w)
        if isinstance(w, FmcwWaveform) and w.if_type != "complex":
            raise ArgumentError("an FMCW radar with a real IF is not modelled in a pair "
                                "(its image folds the interference): use if_type complex",
                                argument=name, value=w.if_type)
    if not (tx_power_w > 0 and interferer_tx_power_w > 0):
        raise ArgumentError("transmit powers must be positive", argument="tx_power_w",
                            value=(tx_power_w, interferer_tx_power_w))
    say = progress or (lambda msg: None)
    a, tau, fd, left_out = strong_paths(link_paths.gain, link_paths.delay_s,
                                        link_paths.doppler_hz)
    a = a * math.sqrt(interferer_tx_power_w / tx_power_w) * np.exp(1j * phase_rad)
    fd = fd + cfo_hz
    kinds = (victim.kind if isinstance(victim, FmcwWaveform) else "ofdm",
             interferer.kind if isinstance(interferer, FmcwWaveform) else "ofdm")
    common = dict(victim_kind=kinds[0], interferer_kind=kinds[1], link_paths_used=a.size,
                  link_power_left_out=left_out)
    if isinstance(victim, FmcwWaveform):
        return _fmcw_victim(own_paths, a, tau, fd, victim, interferer, tx_power_w,
                            noise_figure_db, start_offset_s, seed, method, say, common)
    return _ofdm_victim(own_paths, a, tau, fd, victim, interferer, tx_power_w,
                        noise_figure_db, start_offset_s, seed, method, say, common)


def _fmcw_victim(own_paths, a, tau, fd, victim, interferer, tx_power_w, noise_figure_db,
                 start_offset_s, seed, method, say, common) -> MixedResult:
    say(f"victim's FMCW frame: {len(own_paths.gain)} own paths ({method} synthesis)")
    echo = fmcw_frame(own_paths, victim, seed=seed, method=method)
    noise, _ = _fmcw_noise(echo.shape, victim, tx_power_w, noise_figure_db, seed)
    clean = echo + noise
    say(f"interferer's {common['interferer_kind'].upper()} signal through {a.size} link "
        "paths")
    extra = {}
    if isinstance(interferer, FmcwWaveform):
        i = chirp_interference(victim, interferer, a, tau, fd, start_offset_s)
    else:
        d = random_symbols(interferer, np.random.default_rng((seed, 13)))
        i = ofdm_into_fmcw(victim, interferer, d, a, tau, fd, start_offset_s)
    hit = clean + i
    say("images, floors and closed forms")
    beat = _beat_axis(victim)
    inside = np.abs(beat) < 0.8 * victim.if_cutoff_hz
    floor_clean = _bin_floors(clean, victim)
    rise = 10 * np.log10(_bin_floors(hit, victim)[inside] / floor_clean[inside])
    equal = isinstance(interferer, FmcwWaveform) and interferer.slope == victim.slope
    if equal:
        # a ghost, not a floor (what the floor shows is its sidelobes); a ghost where the
        # chirps keep their offset, i.e. repeat alike: t_d the nearest chirp's
        p_i = np.full(beat.shape, np.nan)
        if interferer.chirp_interval == victim.chirp_interval:
            t_r = victim.chirp_interval
            t_d = start_offset_s - t_r * round(start_offset_s / t_r)
            extra["predicted_ghost_range_m"] = ghost_range(
                victim, interferer, float(tau[np.argmax(np.abs(a))]), t_d)
    elif isinstance(interferer, FmcwWaveform):
        p_i = fmcw_burst_floor(victim, interferer, a, tau, fd, start_offset_s, beat)
        extra["predicted_burst_duration_s"] = burst_duration(victim, interferer)
        extra["burst_duration_s"] = _burst_length(i, victim)
    else:
        p_i = ofdm_band_floor(victim, interferer, a, tau, beat)
    predicted = 10 * np.log10(1 + p_i[inside] / floor_clean[inside])
    if equal:
        rise = np.full(rise.shape, np.nan)
    say("mitigation: burst repair")
    # the returns that move with the radar are the same in every chirp: detect on the
    # frame less its mean over chirps, repair the frame itself
    _, mask = repair_bursts(hit - hit.mean(axis=1, keepdims=True))
    repaired = _bridge(hit, mask)
    results = {k: fmcw_frame_result(x, own_paths, victim)
               for k, x in zip(MIXED_IMAGES, (clean, hit, repaired), strict=True)}
    if "predicted_ghost_range_m" in extra:
        extra["ghost_range_m"] = _ghost(results["clean"], results["interfered"],
                                        extra["predicted_ghost_range_m"], victim)
    return MixedResult(
        results=results, floors={k: image_floor(r.image) for k, r in results.items()},
        measured_floor_rise_db=float(np.mean(rise)),
        predicted_floor_rise_db=float(np.mean(predicted)),
        mitigation="burst repair (zero and interpolate, per chirp)",
        mitigated_share=float(mask.mean()), **common, **extra)


def _bridge(frame, mask):
    """``frame`` with the samples of ``mask`` replaced by linear interpolation between the
    clean samples around them, chirp by chirp (repair_bursts' bridge on a given mask)."""
    x = np.array(frame, complex)
    n = np.arange(x.shape[0])
    for m in np.flatnonzero(mask.any(axis=0)):
        bad = mask[:, m]
        if (~bad).sum() < 2:
            x[:, m] = 0.0
            continue
        x[bad, m] = (np.interp(n[bad], n[~bad], x[~bad, m].real)
                     + 1j * np.interp(n[bad], n[~bad], x[~bad, m].imag))
    return x


def _ofdm_victim(own_paths, a, tau, fd, victim, interferer, tx_power_w, noise_figure_db,
                 start_offset_s, seed, method, say, common) -> MixedResult:
    say(f"victim's OFDM frame: {len(own_paths.gain)} own paths ({method} synthesis)")
    d, dr, noise = radar_frame_parts(own_paths, victim, seed=seed, method=method,
                                     tx_power_w=tx_power_w, noise_figure_db=noise_figure_db)
    clean = dr + noise
    say(f"interferer's FMCW chirps through {a.size} link paths")
    capture = chirp_into_ofdm(victim, interferer, a, tau, fd, start_offset_s)
    hit = clean + ofdm_demodulate(capture, victim)
    say("images, floors and closed forms")
    energy = chirp_band_energy(victim, interferer, a, tau, fd, start_offset_s)
    say("mitigation: crossed symbols bridged along slow time")
    blanked, mask = bridge_crossed_symbols(hit, d)
    results = {k: frame_result(d, x, own_paths, victim)
               for k, x in zip(MIXED_IMAGES, (clean, hit, blanked), strict=True)}
    floors = {k: image_floor(r.image) for k, r in results.items()}
    p_i = energy / (victim.samples_per_symbol * victim.n_symbols)
    return MixedResult(
        results=results, floors=floors,
        measured_floor_rise_db=10 * math.log10(floors["interfered"] / floors["clean"]),
        predicted_floor_rise_db=10 * math.log10(1 + p_i / floors["clean"]),
        mitigation="crossed symbols bridged along slow time, per subcarrier",
        mitigated_share=float(mask.mean()), **common)
