"""From a snapshot link to a radar image and detections (the radar half of a run).

``radar_frame``  paths of a monostatic link -> received symbols D_r (plus noise)
``process``      D_r and D -> radar image -> CFAR detections
``match_truth``  detections against the scene's ground truth (nearest in range and velocity)

Each is a plain function so tools/trace.py, the benchmarks and tests share them.
"""

from __future__ import annotations

import numpy as np

from clradcom.radar import (
    Waveform,
    add_thermal_noise,
    detect,
    radar_image,
    random_symbols,
    spectral_estimate,
    synthesize_frequency_domain,
    synthesize_time_domain,
)
from clradcom.radar.waveform import ofdm_demodulate

SYNTHESIS_METHODS = ("fast", "exact")


def radar_frame(paths, waveform: Waveform, *, seed: int = 0, method: str = "fast",
                tx_power_w: float | None = None, noise_figure_db: float | None = None,
                rng=None):
    """Transmit symbols D and received symbols D_r (N, M) for one link's paths.

    method "fast" is the frequency-domain model (no ICI/ISI); "exact" the
    time-domain superposition. Thermal noise is added when both tx power and
    noise figure are given.
    """
    if method not in SYNTHESIS_METHODS:
        raise ValueError(f"method must be one of {SYNTHESIS_METHODS}, got {method!r}")
    D = random_symbols(waveform, seed)
    gains = np.asarray(paths.gain)
    if method == "fast":
        Dr = synthesize_frequency_domain(D, gains, paths.delay_s, paths.doppler_hz, waveform,
                                         time_origin_s=waveform.fft_window_centre)
    else:
        rx = synthesize_time_domain(D, gains, paths.delay_s, paths.doppler_hz, waveform)
        Dr = ofdm_demodulate(rx, waveform)
    if tx_power_w is not None and noise_figure_db is not None:
        rng = rng if rng is not None else np.random.default_rng(seed + 1)
        Dr = add_thermal_noise(Dr, tx_power_w, noise_figure_db, waveform.bandwidth, rng=rng)
    return D, Dr


def process(D, Dr, waveform: Waveform, *, window="hann", zero_pad=(2, 2), p_fa=1e-6,
            cfar="ca", guard=(2, 1), train=(4, 2)):
    """Radar image (zero-padded, for display) and CFAR detections from transmit and
    received symbols.

    CFAR runs on the critically sampled image: there its cells are (nearly) independent,
    as the threshold formula assumes. On a zero-padded image the noise is oversampled, the
    training cells are fewer than they count and each noise peak is sampled near its
    crest, which multiplies the false-alarm rate (about 4 per frame instead of 0.3 at
    p_fa = 1e-6, 2x2 padding, paper frame). Peak positions are then interpolated on the
    same image (parabolic on dB, within a few hundredths of a cell).
    """
    F = spectral_estimate(Dr, D, "divide")
    image = radar_image(F, waveform, window, window, zero_pad[0], zero_pad[1])
    critical = image if tuple(zero_pad) == (1, 1) else radar_image(F, waveform, window,
                                                                    window, 1, 1)
    detections = detect(critical, guard=guard, train=train, p_fa=p_fa, method=cfar)
    return image, detections
