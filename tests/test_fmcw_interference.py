"""FMCW into FMCW interference against its closed forms (clradcom.radar.fmcw_interference):
the burst's duration 2B_IF/|S_I − S_V| and energy, the image floor's rise, the
equal-slope ghost's range, and the burst repair's recovered SINR."""

import numpy as np
import pytest

from clradcom.errors import ArgumentError
from clradcom.radar import (
    Waveform,
    ofdm_demodulate,
    radar_image,
    random_symbols,
    spectral_estimate,
)
from clradcom.radar.fmcw import FmcwWaveform, fmcw_image, synthesize_beat
from clradcom.radar.fmcw_interference import (
    burst_duration,
    burst_energy,
    chirp_interference,
    chirp_into_ofdm,
    floor_rise_db,
    ghost_range,
    ofdm_burst_energy,
    ofdm_energy_per_chirp,
    ofdm_floor_rise_db,
    ofdm_into_fmcw,
    repair_bursts,
)
from clradcom.radar.pipeline import fmcw_process

C = 299_792_458.0

# victim: 25 MHz/µs; the interferer sweeps 5 % slower, so its difference frequency moves
# at 1.25 MHz/µs and stays 2 x 2 MHz / 1.25 MHz/µs = 3.2 µs (32 samples) in the IF band.
# Its chirps start 0.52 µs before the victim's (0.42 µs before, after the 30 m link), so
# they cross at 0.95 x 0.42 / 0.05 = 8 µs into the chirp, and repeat every 49.98 µs, so
# the crossing moves 0.38 µs later each chirp (the burst's phase with it)
VICTIM = dict(chirp_s=40e-6, idle_s=10e-6, n_chirps=32, samples_per_chirp=256,
              adc_rate_hz=10e6, adc_start_s=2e-6, if_bandwidth_hz=2e6)


OFFSET = -0.52e-6


def _pair(slope_ratio=0.95, **kw):
    victim = FmcwWaveform(**VICTIM)
    chirp = VICTIM["chirp_s"] / slope_ratio
    interferer = FmcwWaveform(**{**VICTIM, "chirp_s": chirp, "idle_s": 49.98e-6 - chirp,
                                 "samples_per_chirp": 16, **kw})
    return victim, interferer


def _burst_samples(x, level):
    return int(np.count_nonzero(np.abs(x) ** 2 >= level))


def test_burst_lasts_two_if_bandwidths_over_the_slope_difference():
    victim, interferer = _pair()
    a = 1e-3
    x = chirp_interference(victim, interferer, [a], [30.0 / C], [0.0], OFFSET)
    want = burst_duration(victim, interferer)
    assert want == pytest.approx(2 * 2e6 / (0.05 * victim.slope))
    # samples at or above the filter's −3 dB, per chirp with a burst: the duration in
    # samples to within one sample at each edge (32 samples: ±3 %), and on average 1 %
    counts = [_burst_samples(x[:, m], 0.5 * a ** 2) for m in range(victim.n_chirps)]
    counts = [c for c in counts if c > 0]
    assert len(counts) >= victim.n_chirps // 2
    assert np.all(np.abs(np.array(counts) - want * victim.adc_rate_hz) <= 1.01)
    assert np.mean(counts) == pytest.approx(want * victim.adc_rate_hz, rel=0.01)


def test_burst_energy_and_floor_rise_follow_the_closed_forms():
    victim, interferer = _pair()
    a = 1e-3
    x = chirp_interference(victim, interferer, [a], [30.0 / C], [0.0], OFFSET)
    energy = np.sum(np.abs(x) ** 2, axis=0)
    full = energy > 0.9 * energy.max()  # chirps with a whole burst inside the window
    want = burst_energy(victim, interferer, a)
    assert 10 * np.log10(np.mean(energy[full]) / want) == pytest.approx(0.0, abs=0.5)
    # the image's floor: noise σ² per sample plus the bursts, rectangular windows
    sigma2 = want / victim.samples_per_chirp / 3.0
    rng = np.random.default_rng(2)
    noise = np.sqrt(sigma2 / 2) * (rng.standard_normal(x.shape)
                                   + 1j * rng.standard_normal(x.shape))
    chirps = np.flatnonzero(full)
    only = fmcw_image(noise[:, chirps], _sub(victim, chirps.size), window="rect")
    both = fmcw_image((noise + x)[:, chirps], _sub(victim, chirps.size), window="rect")
    # per range bin (its beat frequency f, folded into [−f_s/2, f_s/2)), averaged over
    # the Doppler cells: within 0.5 dB of the closed form inside the IF band, and as
    # small as it says beyond 2 B_IF (the filter's −24 dB)
    rise = 10 * np.log10(both.power.mean(axis=1) / only.power.mean(axis=1))
    n = victim.samples_per_chirp
    beat = -np.arange(n) * victim.adc_rate_hz / n
    beat = (beat + victim.adc_rate_hz / 2) % victim.adc_rate_hz - victim.adc_rate_hz / 2
    want_rise = floor_rise_db(victim, interferer, a, sigma2, beat)
    inside = np.abs(beat) < 0.8 * victim.if_cutoff_hz
    outside = np.abs(beat) > 2 * victim.if_cutoff_hz
    assert want_rise[inside].min() > 8.0
    assert np.mean(rise[inside]) == pytest.approx(np.mean(want_rise[inside]), abs=0.5)
    assert np.all(np.abs(rise[inside] - want_rise[inside]) < 2.5)  # 30 chirps per cell
    assert np.mean(rise[outside]) == pytest.approx(np.mean(want_rise[outside]), abs=0.3)
    assert np.mean(want_rise[outside]) < 0.5


def _sub(wf, m):
    return FmcwWaveform(**{**VICTIM, "n_chirps": int(m)})


def test_equal_slopes_make_a_ghost_at_the_closed_form_range():
    victim, _ = _pair()
    interferer = FmcwWaveform(**{**VICTIM, "start_hz": victim.start_hz + 2e6})
    tau, t_d = 40.0 / C, 0.0  # a ghost at 8 m, inside the IF's 12 m
    x = chirp_interference(victim, interferer, [1e-4], [tau], [0.0], t_d)
    want = ghost_range(victim, interferer, tau, t_d)
    assert want == pytest.approx(C * (tau + t_d - 2e6 / victim.slope) / 2)
    noise = 1e-12
    rng = np.random.default_rng(4)
    x = x + np.sqrt(noise / 2) * (rng.standard_normal(x.shape)
                                  + 1j * rng.standard_normal(x.shape))
    _, det = fmcw_process(x, victim)
    assert det.size >= 1
    assert det["range_m"][0] == pytest.approx(want, rel=0.01)
    with pytest.raises(ArgumentError):
        ghost_range(victim, _pair()[1], tau, t_d)


def test_burst_repair_recovers_the_targets_sinr():
    """A target 25 m away at 8 m/s, 20 dB SNR per sample, and a burst 40 dB over the
    noise in every chirp: the burst raises the floor by >10 dB; zeroing and bridging it
    brings the target's peak-to-floor back within 1.5 dB of the clean frame's."""
    victim, interferer = _pair()
    tau, fd = 2 * 25.0 / C, 2 * 8.0 * victim.traced_carrier_hz / C
    sigma2 = 1e-10
    echo = synthesize_beat([1e-4], [tau], [fd], victim)
    rng = np.random.default_rng(7)
    noise = np.sqrt(sigma2 / 2) * (rng.standard_normal(echo.shape)
                                   + 1j * rng.standard_normal(echo.shape))
    burst = chirp_interference(victim, interferer, [1e-3], [30.0 / C], [0.0], OFFSET)

    def sinr(frame):
        img = fmcw_image(frame, victim)
        p = img.power
        peak = p.max()
        i, j = np.unravel_index(np.argmax(p), p.shape)
        mask = np.ones(p.shape, bool)
        mask[max(i - 4, 0):i + 5] = False
        return 10 * np.log10(peak / np.median(p[mask]))

    clean = sinr(echo + noise)
    hit = sinr(echo + noise + burst)
    repaired, mask = repair_bursts(echo + noise + burst)
    fixed = sinr(repaired)
    assert clean - hit > 10.0
    assert fixed > clean - 1.5
    assert mask.any(axis=0).sum() >= victim.n_chirps // 2
    # nothing to repair in the clean frame
    assert not repair_bursts(echo + noise)[1].any()


def test_fmcw_into_ofdm_raises_the_floor_as_its_band_crossings_say():
    """An FMCW radar sweeping across an OFDM radar's 23 MHz band at 5 MHz/µs: each chirp
    crosses it in B/S = 4.6 µs (B samples per second, |a|² each); the OFDM image's floor
    rises by 10 log10(1 + C|a|²B²/S / (L M σ²)) (QPSK, divided out, the cyclic prefixes'
    share dropped): within 0.5 dB."""
    ofdm = Waveform(carrier_hz=24e9, n_subcarriers=256, subcarrier_spacing_hz=90.909e3,
                    cp_s=64 / (256 * 90.909e3), n_symbols=64)
    fmcw = FmcwWaveform(traced_carrier_hz=24e9, start_hz=23.95e9, sweep_bandwidth_hz=200e6,
                        chirp_s=40e-6, idle_s=10e-6, n_chirps=64, adc_rate_hz=5e6,
                        samples_per_chirp=128, adc_start_s=1e-6)
    a = 1e-3
    x = chirp_into_ofdm(ofdm, fmcw, [a], [30.0 / C], [0.0], 3e-6)
    b = ofdm.bandwidth
    # the crossing lasts B/S: count the samples of one
    on = np.flatnonzero(np.abs(x) > 0)
    first = on[: np.argmax(np.diff(on) > 1) + 1] if np.any(np.diff(on) > 1) else on
    assert first.size == pytest.approx(b * b / fmcw.slope, abs=1.0)
    crossings = int(np.sum(np.diff(np.concatenate([[0], (np.abs(x) > 0).astype(int)])) == 1))
    assert crossings == pytest.approx(ofdm.frame_duration / fmcw.chirp_interval, abs=1.0)
    energy = np.sum(np.abs(x) ** 2)
    assert energy == pytest.approx(crossings * ofdm_burst_energy(ofdm, fmcw, a), rel=0.02)
    # through the OFDM receiver: image floors with and without it
    # 13 dB over the noise: the prefixes' share (64 of 320 samples, 1 dB) shows
    sigma2 = energy / ofdm.n_samples / 20
    rng = np.random.default_rng(3)
    d = random_symbols(ofdm, 5)
    noise = np.sqrt(sigma2 / 2) * (rng.standard_normal(x.shape)
                                   + 1j * rng.standard_normal(x.shape))
    floors = []
    for capture in (noise, noise + x):
        f = spectral_estimate(ofdm_demodulate(capture, ofdm), d)
        floors.append(np.mean(radar_image(f, ofdm, "rect", "rect").power))
    rise = 10 * np.log10(floors[1] / floors[0])
    want = ofdm_floor_rise_db(ofdm, fmcw, a, crossings, sigma2)
    assert want > 10.0
    assert rise == pytest.approx(want, abs=0.5)


def test_ofdm_into_fmcw_leaves_the_energy_its_band_crossing_says():
    """A 23 MHz OFDM radar at 24.0 GHz heard by a chirp sweeping 23.96-24.088 GHz in its
    ADC window (5 MHz/µs, IF 5 MHz): the OFDM power, spread evenly over its band, passes
    the IF filter ∫|H|²df at a time: |a|² f_s ∫|H|²df / S per chirp whatever the band
    (within 0.5 dB), and the image floor (rectangular windows) rises by
    10 log10(1 + E/(N σ²)) (within 0.5 dB). Simulated at 11x the ADC rate with the
    analog filter applied exactly, not from the closed form."""
    ofdm = Waveform(carrier_hz=24e9, n_subcarriers=256, subcarrier_spacing_hz=90.909e3,
                    cp_s=64 / (256 * 90.909e3), n_symbols=64)
    fmcw = FmcwWaveform(traced_carrier_hz=24e9, start_hz=23.95e9, sweep_bandwidth_hz=200e6,
                        chirp_s=40e-6, idle_s=10e-6, n_chirps=16, adc_rate_hz=10e6,
                        samples_per_chirp=256, adc_start_s=2e-6, if_bandwidth_hz=5e6)
    a = 1e-3
    d = random_symbols(ofdm, 9)
    x = ofdm_into_fmcw(fmcw, ofdm, d, [a], [30.0 / C], [0.0], 1e-6)
    energy = np.sum(np.abs(x) ** 2, axis=0)
    want = ofdm_energy_per_chirp(fmcw, a)
    assert 10 * np.log10(np.mean(energy) / want) == pytest.approx(0.0, abs=0.5)
    # the interference sits where the chirp is in the OFDM band (±B_IF), none far from it
    t_fast = fmcw.adc_start_s + np.arange(fmcw.samples_per_chirp) / fmcw.adc_rate_hz
    lo = fmcw.start_hz + fmcw.slope * t_fast
    far = (lo < ofdm.carrier_hz - 3 * 5e6) | (lo > ofdm.carrier_hz + ofdm.bandwidth + 3 * 5e6)
    assert np.sum(np.abs(x[far]) ** 2) < 1e-3 * np.sum(np.abs(x) ** 2)
    sigma2 = want / fmcw.samples_per_chirp / 4.0
    rng = np.random.default_rng(8)
    noise = np.sqrt(sigma2 / 2) * (rng.standard_normal(x.shape)
                                   + 1j * rng.standard_normal(x.shape))
    floors = [np.mean(fmcw_image(f, fmcw, window="rect").power) for f in (noise, noise + x)]
    rise = 10 * np.log10(floors[1] / floors[0])
    assert rise == pytest.approx(10 * np.log10(1 + want / (fmcw.samples_per_chirp * sigma2)),
                                 abs=0.5)
