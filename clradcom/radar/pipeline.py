"""From a snapshot link to a radar image and detections (the radar half of a run).

``radar_frame``  paths of a monostatic link -> received symbols D_r (plus noise)
``process``      D_r and D -> radar image -> CFAR detections -> range and velocity at the
                 periodogram maximum (``find_targets``)
``frame_memory_bytes`` / ``check_frame_memory``  what a frame holds at its peak, refused
                 over the memory budget before anything is allocated

Each is a plain function so tools/trace.py, the benchmarks and tests share them.
"""

from __future__ import annotations

import numpy as np

from clradcom.errors import ArgumentError
from clradcom.memory import check_memory
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
from clradcom.radar.cfar import RADAR_GUARD, RADAR_TRAIN
from clradcom.radar.estimation import estimate_detections
from clradcom.radar.processing import RadarImage
from clradcom.radar.synthesis import SYNTHESIS_ACCURACY, check_noise_figure, check_tx_power
from clradcom.radar.waveform import ofdm_demodulate

SYNTHESIS_METHODS = ("fast", "exact")

#: N x M complex128 arrays held at the peak of each stage (tracemalloc on a 512 x 128
#: frame, finufft's own oversampled grids added): the fast synthesis (D, H, D_r, the noise
#: and its temporaries, finufft's 2 x 2 oversampled grid), the exact one (the frame in time
#: and up to four Chebyshev nodes' (N, M) grids and transforms at a time, their finufft
#: grids), and processing: D, D_r and F = D_r/D plus 2.5 per zero-padded image cell
#: (the padded spectrum, its transform, its power in float64) for the display image
#: and the critically sampled one.
FRAME_ARRAYS = {"fast": 9.0, "exact": 30.0}
PROCESS_ARRAYS = 3.0
IMAGE_ARRAYS_PER_CELL = 2.5


def frame_memory_bytes(waveform: Waveform, method: str = "fast", zero_pad=(2, 2)) -> int:
    """Bytes that :func:`radar_frame` and :func:`process` hold at their peak for one
    N x M frame (16 N M bytes per complex128 array; :data:`FRAME_ARRAYS`)."""
    if not isinstance(waveform, Waveform):
        raise ArgumentError("must be a clradcom.radar.Waveform", argument="waveform",
                            value=waveform)
    if method not in SYNTHESIS_METHODS:
        raise ArgumentError(f"must be one of {SYNTHESIS_METHODS}", argument="method",
                            value=method)
    cell = 16.0 * waveform.n_subcarriers * waveform.n_symbols
    pad = float(np.prod(zero_pad))
    arrays = max(FRAME_ARRAYS[method], PROCESS_ARRAYS + IMAGE_ARRAYS_PER_CELL * (pad + 1))
    return int(arrays * cell)


def check_frame_memory(waveform: Waveform, method: str = "fast", zero_pad=(2, 2), *,
                       budget_bytes: float | None = None, argument: str = "waveform",
                       value=None, advice: str = "choose fewer subcarriers or symbols",
                       copies: int = 1) -> None:
    """Refuse a frame (``copies`` of it held at once) whose estimate exceeds the memory
    budget (:func:`clradcom.memory.check_memory`), before anything is allocated, with
    :class:`~clradcom.errors.MemoryBudgetError` naming ``argument`` (default the
    waveform's N x M) and ``advice``."""
    need = copies * frame_memory_bytes(waveform, method, zero_pad)
    n, m = waveform.n_subcarriers, waveform.n_symbols
    check_memory(need, what=f"the {n} x {m} radar frame ({method} synthesis"
                            + (f", {copies} at once" if copies > 1 else "") + ")",
                 argument=argument, value=f"N x M = {n} x {m}" if value is None else value,
                 advice=advice, budget_bytes=budget_bytes)


def radar_frame(paths, waveform: Waveform, *, seed: int = 0, method: str = "fast",
                tx_power_w: float | None = None, noise_figure_db: float | None = None,
                rng=None):
    """Transmit symbols D and received symbols D_r (N, M) for one link's paths.

    method "fast" is the frequency-domain model (no ICI/ISI); "exact" the
    time-domain superposition. Thermal noise is added when both tx power and
    noise figure are given (power positive, noise figure >= 0 dB). A frame over the
    memory budget is refused first (:func:`check_frame_memory`).
    """
    if method not in SYNTHESIS_METHODS:
        raise ArgumentError(f"must be one of {SYNTHESIS_METHODS}", argument="method",
                            value=method)
    if tx_power_w is not None and noise_figure_db is not None:
        check_tx_power(tx_power_w)
        check_noise_figure(noise_figure_db)
    check_frame_memory(waveform, method)
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


def find_targets(spectral, waveform: Waveform, *, window="hann", p_fa=1e-6, cfar="ca",
                 guard=RADAR_GUARD, train=RADAR_TRAIN,
                 accuracy: float = SYNTHESIS_ACCURACY,
                 refine: bool = True, critical: RadarImage | None = None) -> np.ndarray:
    """Detections of the channel estimate F (N, M): CFAR on the critically sampled
    windowed image (``critical``, computed here when not given), then each detection's
    range and velocity at the un-windowed periodogram's maximum, all detections fitted
    jointly (:func:`clradcom.radar.estimation.estimate_detections`; docs/dsp.md §6).
    ``refine=False`` keeps the windowed image's 3-point parabola on dB (biased by up to
    ~0.016 bin: 20-35 dB above the Cramér-Rao bound on the paper frame).  ``accuracy`` is
    the relative accuracy of the frame (the synthesis tolerance): no CFAR noise estimate
    is taken below the numerical floor it sets (cfar.numerical_floor), so a noiseless
    frame's empty cells are never detections."""
    if critical is None:
        critical = radar_image(spectral, waveform, window, window, 1, 1)
    detections = detect(critical, guard=guard, train=train, p_fa=p_fa, method=cfar,
                        accuracy=accuracy)
    return estimate_detections(detections, spectral, waveform) if refine else detections


def process(D, Dr, waveform: Waveform, *, window="hann", zero_pad=(2, 2), p_fa=1e-6,
            cfar="ca", guard=RADAR_GUARD, train=RADAR_TRAIN,
            accuracy: float = SYNTHESIS_ACCURACY,
            refine: bool = True):
    """Radar image (zero-padded, for display) and CFAR detections from transmit and
    received symbols.

    CFAR runs on the critically sampled image. Its cells are not independent: the window
    correlates neighbours (Hann: coefficient −2/3 at one bin, 1/6 at two, in each axis),
    so the training cells are fewer independent samples than they count. The threshold
    is designed for that correlation (the image's ``correlation``;
    :func:`clradcom.radar.cfar.cfar_alpha`, docs/dsp.md §5), so ``p_fa`` is the rate of
    threshold crossings per cell on noise (the α of independent cells gave 3-5x it).
    A zero-padded image would also correlate its cells, and sample each noise peak near
    its crest: it is kept for display. Range and velocity of each detection are then
    the maximum of the un-windowed periodogram of F = D_r/D near it (:func:`find_targets`:
    at the Cramér-Rao bound above the threshold SNR); power and SNR are the windowed
    image's.
    """
    F = spectral_estimate(Dr, D, "divide")
    image = radar_image(F, waveform, window, window, zero_pad[0], zero_pad[1])
    critical = image if tuple(zero_pad) == (1, 1) else None
    detections = find_targets(F, waveform, window=window, p_fa=p_fa, cfar=cfar, guard=guard,
                              train=train, accuracy=accuracy, refine=refine,
                              critical=critical)
    return image, detections
