"""From a snapshot link to a radar image and detections (the radar half of a run).

``radar_frame``  paths of a monostatic link -> received symbols D_r (plus noise)
``process``      D_r and D -> radar image -> CFAR detections -> range and velocity at the
                 periodogram maximum (``find_targets``)
``radar_chain``  both, and the detections sorted against the paths (``frame_result``):
                 the one chain every tool runs on a radar's own echoes (clradcom trace,
                 radar, drive, interference's image without D, the benchmarks)
``frame_memory_bytes`` / ``check_frame_memory``  what a frame holds at its peak, refused
                 over the memory budget before anything is allocated

Each is a plain function so tools/trace.py, the benchmarks and tests share them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from clradcom.errors import ArgumentError
from clradcom.memory import check_memory
from clradcom.radar import (
    SPEED_OF_LIGHT,
    Waveform,
    detect,
    radar_image,
    random_symbols,
    spectral_estimate,
    synthesize_frequency_domain,
    synthesize_time_domain,
)
from clradcom.radar.array_frame import run_array_radar
from clradcom.radar.cfar import RADAR_GUARD, RADAR_TRAIN
from clradcom.radar.cube import point_cloud
from clradcom.radar.estimation import estimate_detections
from clradcom.radar.fmcw import FmcwWaveform, correct_coupling, fmcw_frame, fmcw_image
from clradcom.radar.processing import RadarImage
from clradcom.radar.synthesis import (
    SYNTHESIS_ACCURACY,
    check_noise_figure,
    check_tx_power,
    thermal_noise_power,
)
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
    if not isinstance(waveform, Waveform | FmcwWaveform):
        raise ArgumentError("must be a clradcom.radar.Waveform or FmcwWaveform",
                            argument="waveform", value=waveform)
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
    D, Dr, noise = radar_frame_parts(paths, waveform, seed=seed, method=method,
                                     tx_power_w=tx_power_w, noise_figure_db=noise_figure_db,
                                     rng=rng)
    return D, Dr if noise is None else Dr + noise


def radar_frame_parts(paths, waveform: Waveform, *, seed: int = 0, method: str = "fast",
                      tx_power_w: float | None = None, noise_figure_db: float | None = None,
                      rng=None):
    """:func:`radar_frame` in its parts: (D, the noiseless D_r, the thermal noise per cell
    or None); D_r + noise is :func:`radar_frame`'s frame bit for bit. The two-radar run
    puts the same noise into the FFT windows of its time-domain capture, so that A's
    frame without D is this one (:func:`clradcom.radar.interference.two_radar_run`)."""
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
    noise = None
    if tx_power_w is not None and noise_figure_db is not None:
        rng = np.random.default_rng(rng if rng is not None else seed + 1)
        # add_thermal_noise's draw, kept apart
        var = thermal_noise_power(waveform.bandwidth, noise_figure_db) / tx_power_w
        noise = np.sqrt(var / 2.0) * (rng.standard_normal(Dr.shape)
                                      + 1j * rng.standard_normal(Dr.shape))
    return D, Dr, noise


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


#: a detection farther than the longest path by more than this many range cells is no
#: echo of the paths (the Hann window's main lobe reaches 2 cells to a side, the
#: periodogram refinement moves a peak by less than one)
ECHO_MARGIN_CELLS = 3


@dataclass(frozen=True)
class FrameResult:
    """What :func:`radar_chain` gives for one frame of a radar's own echoes.

    ``image``: the zero-padded range-Doppler image (display; an array radar's: its cube's
    power summed over the angle bins); ``detections`` (``DETECTION_DTYPE``, or the cube's
    ``CUBE_DETECTION_DTYPE``; strongest first): what CFAR found that the paths can have
    made; ``aliased`` (bool per detection): made only by paths beyond the unambiguous range
    or velocity, shown folded there; ``beyond``: CFAR detections farther than the longest
    path's range (by :data:`ECHO_MARGIN_CELLS` cells) that no folded path explains, noise
    false alarms, left out of ``detections``; ``longest_range_m``: c tau_max / 2;
    ``array``: an array radar's :class:`clradcom.radar.array_frame.ArrayResult` (its
    detections and point cloud those kept here), else None."""

    image: RadarImage
    detections: np.ndarray
    aliased: np.ndarray
    beyond: np.ndarray
    longest_range_m: float
    array: object | None = None


def path_ranges_velocities(paths, waveform: Waveform) -> tuple[np.ndarray, np.ndarray]:
    """Where each path's echo lies before the image folds it: range c tau / 2 (m) and
    velocity lambda f_D / 2 (m/s, closing positive, as the image's velocity axis)."""
    tau = np.asarray(paths.delay_s, dtype=np.float64)
    fd = np.asarray(paths.doppler_hz, dtype=np.float64)
    # the snapshot's Doppler is at the traced carrier (an FMCW frame's centre differs)
    return SPEED_OF_LIGHT * tau / 2.0, fd / waveform.velocity_to_doppler(1.0)


def sort_detections(detections, paths, waveform: Waveform, *,
                    max_velocity: float | None = None):
    """(kept, aliased, beyond): the detections the paths can explain, whether each was put
    there by folding only, and those left out (:class:`FrameResult`).

    A path at range r and Doppler f_D shows at (r mod r_max, v folded into [-v_max,
    v_max)) with v = lambda f_D / 2. A detection farther than the longest path's range by
    more than :data:`ECHO_MARGIN_CELLS` range cells is none of the paths' echoes, unless
    a path beyond r_max or v_max folds to within that many cells of it in range and
    velocity: then it stays, marked aliased. A detection within the paths' reach that
    only a folded path explains (and no unfolded one) is marked aliased too.
    ``max_velocity``: the frame's unambiguous velocity where it is not the waveform's
    (a TDM-MIMO frame: the waveform's / E_tx)."""
    det = np.asarray(detections)
    r_path, v_path = path_ranges_velocities(paths, waveform)
    r_max = waveform.max_range
    v_max = waveform.max_velocity if max_velocity is None else float(max_velocity)
    tol_r = ECHO_MARGIN_CELLS * waveform.range_resolution
    tol_v = ECHO_MARGIN_CELLS * waveform.velocity_resolution
    longest = float(r_path.max()) if r_path.size else 0.0
    folds = (r_path >= r_max) | (np.abs(v_path) > v_max)

    def near(rr, vv):
        """(detections, paths) bool: within the tolerances, range circular over r_max and
        velocity over 2 v_max (the image's axes wrap)."""
        dr = np.abs(det["range_m"][:, None] - rr[None, :]) % r_max
        dv = np.abs(det["velocity_mps"][:, None] - vv[None, :]) % (2.0 * v_max)
        return (np.minimum(dr, r_max - dr) <= tol_r) & (np.minimum(dv, 2 * v_max - dv) <= tol_v)

    by_folded = near(r_path[folds] % r_max,
                     (v_path[folds] + v_max) % (2.0 * v_max) - v_max).any(axis=1)
    by_direct = near(r_path[~folds], v_path[~folds]).any(axis=1)
    aliased = by_folded & ~by_direct
    # (a wrapped echo of a path at ~0 m lies near r_max: the circular match keeps it)
    out = (det["range_m"] > longest + tol_r) & ~by_folded & ~by_direct
    return det[~out], aliased[~out], det[out]


def frame_result(D, Dr, paths, waveform: Waveform) -> FrameResult:
    """:func:`process` (image, CFAR on the critical grid, periodogram refinement) and the
    detections sorted against the paths that made the frame (:func:`sort_detections`)."""
    image, dets = process(D, Dr, waveform)
    kept, aliased, beyond = sort_detections(dets, paths, waveform)
    r_path, _ = path_ranges_velocities(paths, waveform)
    return FrameResult(image, kept, aliased, beyond,
                       float(r_path.max()) if r_path.size else 0.0)


def fmcw_process(frame, waveform: FmcwWaveform, *, window="hann", zero_pad=(2, 2),
                 p_fa=1e-6, cfar="ca", guard=RADAR_GUARD, train=RADAR_TRAIN,
                 accuracy: float = SYNTHESIS_ACCURACY, refine: bool = True):
    """:func:`process` for an FMCW beat frame (N, M): the frame is the spectral estimate
    (docs/fmcw.md §3), so the same image, CFAR on the critical grid and periodogram
    refinement run on it; then each detection's range and velocity are freed of the
    range-Doppler coupling (:func:`clradcom.radar.fmcw.correct_coupling`). A real IF's
    image holds only the range bins below the wrap."""
    image = fmcw_image(frame, waveform, window, zero_pad)
    critical = image if tuple(zero_pad) == (1, 1) else fmcw_image(frame, waveform, window)
    detections = find_targets(frame, waveform, window=window, p_fa=p_fa, cfar=cfar,
                              guard=guard, train=train, accuracy=accuracy, refine=refine,
                              critical=critical)
    r, v = correct_coupling(detections["range_m"], detections["velocity_mps"], waveform)
    detections["range_m"], detections["velocity_mps"] = r, v
    return image, detections


def fmcw_frame_result(frame, paths, waveform: FmcwWaveform) -> FrameResult:
    """:func:`frame_result` for an FMCW beat frame."""
    image, dets = fmcw_process(frame, waveform)
    kept, aliased, beyond = sort_detections(dets, paths, waveform)
    r_path, _ = path_ranges_velocities(paths, waveform)
    return FrameResult(image, kept, aliased, beyond,
                       float(r_path.max()) if r_path.size else 0.0)


def radar_chain(paths, waveform: Waveform, *, radar=None, seed: int = 0,
                method: str = "fast", tx_power_w: float | None = None,
                noise_figure_db: float | None = None, refine: str = "ml",
                channel: str = "synthetic", pair_paths=None) -> FrameResult:
    """The radar chain of a radar's own echoes, the same in every tool.

    A single-antenna radar (``radar`` None or without an array): the frame
    (:func:`radar_frame`: data from ``seed``, noise from ``seed`` + 1, synthesis
    ``method``) and :func:`frame_result`. A radar with ``tx_array``/``rx_array``: its
    TDM-MIMO frame and cube (:func:`clradcom.radar.array_frame.run_array_radar` with
    ``refine``, ``channel`` and ``pair_paths``), the image its cube's power summed over
    the angle bins, the detections sorted against ``paths`` at the TDM frame's unambiguous
    velocity (the element pairs' paths with ``channel`` "exact": ``paths`` None, nothing
    sorted out), and the point cloud of those kept."""
    has_array = radar is not None and (radar.tx_array is not None
                                       or radar.rx_array is not None)
    if isinstance(waveform, FmcwWaveform) and not has_array:
        frame = fmcw_frame(paths, waveform, seed=seed, method=method,
                           tx_power_w=tx_power_w, noise_figure_db=noise_figure_db)
        return fmcw_frame_result(frame, paths, waveform)
    if has_array:
        return _array_chain(paths, waveform, radar, seed=seed, tx_power_w=tx_power_w,
                            noise_figure_db=noise_figure_db, refine=refine, channel=channel,
                            pair_paths=pair_paths)
    D, Dr = radar_frame(paths, waveform, seed=seed, method=method, tx_power_w=tx_power_w,
                        noise_figure_db=noise_figure_db)
    return frame_result(D, Dr, paths, waveform)


def _array_chain(paths, waveform, radar, *, seed, tx_power_w, noise_figure_db, refine,
                 channel, pair_paths) -> FrameResult:
    res = run_array_radar(paths, radar, waveform, seed=seed, tx_power_w=tx_power_w,
                          noise_figure_db=noise_figure_db, refine=refine, channel=channel,
                          pair_paths=pair_paths)
    power = res.cube.power.sum(axis=(2, 3))
    with np.errstate(divide="ignore"):
        image = RadarImage(power, 10 * np.log10(power), res.cube.range_m,
                           res.cube.velocity_mps)
    det = res.detections
    if paths is None:
        return FrameResult(image, det, np.zeros(len(det), bool), det[:0], math.inf, res)
    n_tx = 1 if radar.tx_array is None else radar.tx_array.n_elements
    kept, aliased, beyond = sort_detections(det, paths, res.waveform,
                                            max_velocity=res.waveform.max_velocity / n_tx)
    res.detections = kept
    res.points = point_cloud(kept, radar.position, radar.orientation)
    r_path, _ = path_ranges_velocities(paths, waveform)
    return FrameResult(image, kept, aliased, beyond,
                       float(r_path.max()) if r_path.size else 0.0, res)
