"""OFDM RadCom radar signal chain: waveform, received-signal synthesis, processing, CFAR.

See docs/dsp.md for the formulas, conventions and sources.  Plotting lives in
``clradcom.radar.plots`` (imported on demand, it pulls in matplotlib).
"""

from clradcom.radar.cfar import (
    DETECTION_DTYPE,
    ca_cfar_alpha,
    cfar_false_alarms,
    cfar_threshold,
    detect,
    interpolate_peaks,
    os_cfar_alpha,
    os_cfar_pfa,
    parabolic_offset,
    training_footprint,
)
from clradcom.radar.estimation import (
    CramerRaoBound,
    cramer_rao_bound,
    estimate_detections,
    periodogram_at,
    refine_peaks,
)
from clradcom.radar.processing import (
    RadarImage,
    get_window,
    radar_image,
    range_axis,
    spectral_estimate,
    velocity_axis,
)
from clradcom.radar.synthesis import (
    add_noise,
    add_thermal_noise,
    channel_transfer_function,
    check_paths,
    synthesize_frequency_domain,
    synthesize_time_domain,
    thermal_noise_power,
)
from clradcom.radar.waveform import (
    SPEED_OF_LIGHT,
    Waveform,
    constellation,
    ofdm_demodulate,
    ofdm_modulate,
    paper_waveform,
    random_symbols,
)

__all__ = [
    "DETECTION_DTYPE", "SPEED_OF_LIGHT", "CramerRaoBound", "RadarImage", "Waveform",
    "add_noise", "cramer_rao_bound", "estimate_detections", "periodogram_at", "refine_peaks",
    "add_thermal_noise", "ca_cfar_alpha", "cfar_false_alarms", "cfar_threshold",
    "channel_transfer_function", "check_paths", "constellation", "detect", "get_window",
    "interpolate_peaks", "ofdm_demodulate", "ofdm_modulate", "os_cfar_alpha", "os_cfar_pfa",
    "paper_waveform", "parabolic_offset", "radar_image", "random_symbols", "range_axis",
    "spectral_estimate", "synthesize_frequency_domain", "synthesize_time_domain",
    "thermal_noise_power", "training_footprint", "velocity_axis",
]
