"""A radar with antenna arrays on a traced link: its TDM-MIMO frame, the radar cube, CFAR,
the point cloud, and the cars' truth set against the detections in range, velocity and
azimuth (``clradcom cube``; docs/dsp.md §9).

The channel of every element pair comes one of three ways (``channel``,
:data:`ARRAY_CHANNELS`; docs/dsp.md §9):

* ``"synthetic"`` (default): from the paths of the radar's reference point, plane-wave
  phases along each path's departure and arrival directions
  (:func:`clradcom.radar.array.synthetic_channels`), exact in the far field of the array,
  D²/(λR) ≪ 1 (the street's 12-element array is 6.9 cm wide, D²/λ = 0.4 m);
* ``"corrected"``: the same paths with their first and last legs recomputed from the
  elements (:func:`clradcom.radar.array.exact_channels`);
* ``"exact"``: the scene traced for every element pair
  (:func:`clradcom.radar.element_trace.trace_elements`), the paths of each pair its own.

Each element's own pattern and polarisation (``ArrayLayout.patterns``) enter the first
two through the paths' polarimetric matrices and directions
(:func:`clradcom.radar.array.element_gains`); the traced pairs carry them already.
Transmit element i sends symbols μ = m·E_tx + i (TDM); every receive element gets its own
thermal noise at the radar's power and noise figure.

Truth (:func:`array_truth`): a car's range is the interval from its nearest triangle to
its bounding-box centre (the echo comes from the faces turned to the radar, the paper's
R is the centre), its radial velocity and azimuth those of its centre
(:func:`clradcom.radar.truth.detection_truth`). A detection is within one cell when its
range lies within one range cell of that interval, its velocity within one velocity cell
and sin(azimuth) within one azimuth FFT bin (λ/(A·d), A the FFT size, d the virtual
element spacing) of the centre's.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from clradcom.errors import ArgumentError
from clradcom.radar.array import element_gains, exact_channels, synthetic_channels
from clradcom.radar.cube import (
    detect_cube,
    point_cloud,
    radar_cube,
    refine_detections,
    tdm_channels,
)
from clradcom.radar.element_trace import pair_channel_arrays
from clradcom.radar.fmcw import FmcwWaveform, correct_coupling, synthesize_beat
from clradcom.radar.mimo import mimo_received, tdm_range_doppler, virtual_positions
from clradcom.radar.synthesis import (
    SYNTHESIS_ACCURACY,
    add_thermal_noise,
    channel_transfer_function,
    check_noise_figure,
    check_tx_power,
)
from clradcom.radar.waveform import Waveform, random_symbols

#: how :func:`run_array_radar` places its detections: the joint maximum-likelihood fit
#: on the raw channels (default) or the cube's 3-point dB parabola
REFINEMENTS = ("ml", "parabola")
#: where the channel of every element pair comes from (module docstring)
ARRAY_CHANNELS = ("synthetic", "corrected", "exact")

__all__ = ["ARRAY_CHANNELS", "REFINEMENTS", "ArrayResult", "element_channels",
           "tdm_received_pairs", "array_offsets", "array_truth", "mimo_waveform",
           "run_array_radar", "tdm_frame", "truth_table"]


def array_offsets(radar):
    """(tx, rx, virtual): world offsets (E, 3) of the transmit and receive elements from
    the radar's position, and the virtual elements (E_tx·E_rx, 3) in the radar's own
    frame. A radar without ``tx_array``/``rx_array`` is refused."""
    if radar.tx_array is None and radar.rx_array is None:
        raise ArgumentError("has no tx_array/rx_array (or array) in the scene: nothing to "
                            "make a MIMO frame from", argument="radar", value=radar.name)
    zero = np.zeros((1, 3))
    tx_l = zero if radar.tx_array is None else np.asarray(radar.tx_array.positions_local)
    rx_l = zero if radar.rx_array is None else np.asarray(radar.rx_array.positions_local)
    r = np.asarray(radar.orientation, dtype=np.float64)
    return tx_l @ r.T, rx_l @ r.T, virtual_positions(tx_l, rx_l)


def mimo_waveform(waveform: Waveform | FmcwWaveform, n_tx: int) -> Waveform | FmcwWaveform:
    """The waveform with its symbol (an FMCW one's chirp) count cut down to a multiple of
    the transmitters (TDM: each sends every n_tx-th symbol or chirp); unchanged when it
    already is one."""
    m = (waveform.n_symbols // n_tx) * n_tx
    if m < n_tx:
        raise ArgumentError(f"has fewer symbols than the {n_tx} transmitters",
                            argument="waveform", value=waveform.n_symbols)
    if m == waveform.n_symbols:
        return waveform
    if isinstance(waveform, FmcwWaveform):
        return dataclasses.replace(waveform, n_chirps=m)
    return dataclasses.replace(waveform, n_symbols=m)


def element_channels(paths, radar, waveform: Waveform, channel: str = "synthetic",
                     pair_paths=None):
    """Gains, delays (s) and Dopplers (Hz) of every element pair, each (E_tx, E_rx, P):
    ``channel`` "synthetic" or "corrected" from the reference ``paths``, "exact" from
    ``pair_paths`` ([i][j] Paths of the traced element pairs, zero-gain padded to one P)
    (module docstring)."""
    if channel not in ARRAY_CHANNELS:
        raise ArgumentError(f"must be one of {ARRAY_CHANNELS}", argument="channel",
                            value=channel)
    tx, rx, _ = array_offsets(radar)
    if channel == "exact":
        if pair_paths is None:
            raise ArgumentError("the exact channel needs the traced element pairs "
                                "(clradcom.radar.element_trace.trace_elements)",
                                argument="pair_paths", value=None)
        g, tau, fd = pair_channel_arrays(pair_paths)
        if g.shape[:2] != (tx.shape[0], rx.shape[0]):
            raise ArgumentError(f"must be {tx.shape[0]} x {rx.shape[0]} element pairs",
                                argument="pair_paths", value=f"{g.shape[0]} x {g.shape[1]}")
        return g, tau, fd
    lam = waveform.wavelength
    p = len(paths.gain)
    fd = np.broadcast_to(np.asarray(paths.doppler_hz), (tx.shape[0], rx.shape[0], p))
    # each element's own pattern and polarisation in place of the radar's (the paths'
    # own gains where the arrays give none)
    own = None if radar_patterns_shared(radar) else element_gains(paths, radar)
    if channel == "synthetic":
        g = synthetic_channels(paths, tx, rx, lam, gains=own)
        tau = np.broadcast_to(np.asarray(paths.delay_s), g.shape)
    else:
        g, tau = exact_channels(paths, tx, rx, lam, gains=own)
    return g, tau, fd


def tdm_received_pairs(symbols, gains, delays_s, dopplers_hz, waveform: Waveform):
    """Received symbols (E_rx, N, M) of a TDM frame whose element pairs each have their
    own paths: gains, delays and Dopplers (E_tx, E_rx, P) (fast model, no noise); symbol
    μ from transmitter μ mod E_tx, time origin the FFT window centre (as
    :func:`clradcom.radar.mimo.mimo_received`, which shares one Doppler per path)."""
    d = np.asarray(symbols)
    return _tdm_by_pairs(
        gains, delays_s, dopplers_hz, (waveform.n_subcarriers, waveform.n_symbols),
        lambda g, tau, fd: d * channel_transfer_function(g, tau, fd, waveform,
                                                         waveform.fft_window_centre))


def _tdm_by_pairs(gains, delays, dopplers, shape, pair_frame):
    """(E_rx, *shape) of a TDM frame from its element pairs' own paths (E_tx, E_rx, P):
    ``pair_frame(gains, delays, dopplers)`` of a pair's nonzero paths gives its whole
    (*shape) frame, of which receiver j keeps the slots (last axis) μ that transmitter
    μ mod E_tx sends."""
    g = np.asarray(gains)
    et, er, _ = g.shape
    owner = np.arange(shape[-1]) % et
    out = np.zeros((er, *shape), complex)
    for i in range(et):
        for j in range(er):
            keep = g[i, j] != 0
            if keep.any():
                frame = pair_frame(g[i, j][keep], np.asarray(delays)[i, j][keep],
                                   np.asarray(dopplers)[i, j][keep])
                out[j][:, owner == i] = frame[:, owner == i]
    return out


def _with_thermal_noise(received, tx_power_w, noise_figure_db, bandwidth_hz, seed: int):
    """``received`` with thermal noise over ``bandwidth_hz`` per receive element when both
    ``tx_power_w`` and ``noise_figure_db`` are given (seeded with seed + 1)."""
    if tx_power_w is None or noise_figure_db is None:
        return received
    check_tx_power(tx_power_w)
    check_noise_figure(noise_figure_db)
    return add_thermal_noise(received, tx_power_w, noise_figure_db, bandwidth_hz,
                             rng=np.random.default_rng(seed + 1))


def tdm_frame(paths, radar, waveform: Waveform, *, seed: int = 0,
              tx_power_w: float | None = None, noise_figure_db: float | None = None,
              channel: str = "synthetic", pair_paths=None):
    """Transmit symbols D (N, M) and received symbols (E_rx, N, M) of a TDM-MIMO frame of
    the radar's own echoes (module docstring; ``channel``/``pair_paths`` as
    :func:`element_channels`); thermal noise per receive element when both
    ``tx_power_w`` and ``noise_figure_db`` are given (noise seeded with seed + 1)."""
    gains, delays, dopplers = element_channels(paths, radar, waveform, channel, pair_paths)
    if isinstance(waveform, FmcwWaveform):
        return _fmcw_tdm_frame(gains, delays, dopplers, waveform, seed=seed,
                               tx_power_w=tx_power_w, noise_figure_db=noise_figure_db)
    d = random_symbols(waveform, seed)
    if channel == "synthetic" and radar_patterns_shared(radar):
        received = mimo_received(d, gains, np.asarray(paths.delay_s),
                                 np.asarray(paths.doppler_hz), waveform, mode="tdm")
    else:
        received = tdm_received_pairs(d, gains, delays, dopplers, waveform)
    return d, _with_thermal_noise(received, tx_power_w, noise_figure_db, waveform.bandwidth,
                                  seed)


def _fmcw_tdm_frame(gains, delays, dopplers, waveform: FmcwWaveform, *, seed, tx_power_w,
                    noise_figure_db):
    """(D, received) of an FMCW TDM-MIMO frame: transmitter i sends chirps μ = m·E_tx + i,
    every receiver dechirps each (fast synthesis per element pair, its own paths); D is
    all ones, so that the OFDM chain's F = D_r/D is the beat frame itself (docs/fmcw.md
    §3). I/Q noise kT·f_s·F/P_tx per sample and receiver, seeded with seed + 1."""
    if waveform.if_type != "complex":
        raise ArgumentError("an array radar's FMCW frame needs I/Q samples (if_type "
                            '"complex"): the real IF\'s mirrored half has no cube yet',
                            argument="if_type", value=waveform.if_type)
    received = _tdm_by_pairs(
        gains, delays, dopplers, (waveform.samples_per_chirp, waveform.n_chirps),
        lambda g, tau, fd: synthesize_beat(g, tau, fd, waveform))
    received = _with_thermal_noise(received, tx_power_w, noise_figure_db,
                                   waveform.adc_rate_hz, seed)
    return np.ones(received.shape[1:], complex), received


def radar_patterns_shared(radar) -> bool:
    """True when no array of the radar gives its elements their own patterns."""
    return all(a is None or a.patterns is None for a in (radar.tx_array, radar.rx_array))


class ArrayResult:
    """What :func:`run_array_radar` returns: ``waveform`` (the TDM one), ``rd``
    (per virtual channel spectra), ``cube``, ``detections`` (cube CFAR, strongest first),
    ``points`` (world point cloud) and the cells: ``range_cell_m``,
    ``velocity_cell_mps``, ``u_cell`` (one azimuth FFT bin in sin az)."""

    def __init__(self, waveform, rd, cube, detections, points):
        self.waveform, self.rd, self.cube = waveform, rd, cube
        self.detections, self.points = detections, points
        self.range_cell_m = float(cube.range_m[1] - cube.range_m[0])
        self.velocity_cell_mps = float(cube.velocity_mps[1] - cube.velocity_mps[0])
        self.u_cell = float(cube.u_y[1] - cube.u_y[0]) if cube.u_y.size > 1 else 2.0


def run_array_radar(paths, radar, waveform: Waveform, *, seed: int = 0,
                    tx_power_w: float | None = None, noise_figure_db: float | None = None,
                    n_azimuth: int | None = None, p_fa: float = 1e-6,
                    refine: str = "ml", channel: str = "synthetic",
                    pair_paths=None) -> ArrayResult:
    """TDM frame, range–Doppler spectra with the motion-induced phase compensated, the
    cube (Hann over range, Doppler and the virtual array), CA-CFAR over it, each
    detection's range, velocity and direction refined (``refine``: "ml", the joint
    maximum-likelihood fit on the raw channels, :func:`clradcom.radar.cube.
    refine_detections`; "parabola", the cube's 3-point dB parabola) and the point cloud
    in the world (radar position and orientation). ``channel``/``pair_paths``: how the
    element pairs' channels are made (:func:`element_channels`)."""
    if refine not in REFINEMENTS:
        raise ArgumentError(f"must be one of {REFINEMENTS}", argument="refine", value=refine)
    tx, rx, virt = array_offsets(radar)
    wf = mimo_waveform(waveform, tx.shape[0])
    d, received = tdm_frame(paths, radar, wf, seed=seed, tx_power_w=tx_power_w,
                            noise_figure_db=noise_figure_db, channel=channel,
                            pair_paths=pair_paths)
    rd = tdm_range_doppler(received, d, wf, tx.shape[0])
    cube = radar_cube(rd, virt, wf.wavelength, n_azimuth=n_azimuth)
    # a noiseless frame: no CFAR noise estimate below the synthesis' numerical floor
    noiseless = tx_power_w is None or noise_figure_db is None
    det = detect_cube(cube, p_fa=p_fa, accuracy=SYNTHESIS_ACCURACY if noiseless else None)
    if refine == "ml" and virt.shape[0] > 1 and wf.n_symbols // tx.shape[0] > 1:
        f, slow = tdm_channels(received, d, wf, tx.shape[0])
        det = refine_detections(det, cube, f, slow, virt, wf)
    if isinstance(wf, FmcwWaveform):  # the beat's range-Doppler coupling (docs/fmcw.md §3)
        det["range_m"], det["velocity_mps"] = correct_coupling(det["range_m"],
                                                               det["velocity_mps"], wf)
    pts = point_cloud(det, radar.position, radar.orientation)
    return ArrayResult(wf, rd, cube, det, pts)


def array_truth(truth_rows, result: ArrayResult) -> list[dict]:
    """Each truth row (:func:`clradcom.radar.truth.detection_truth`) with the detection
    that matches it best and its errors in cells: among the detections within one range
    cell of [range_nearest_m, range_centre_m] and one velocity cell of v_rel_m_s, the one
    nearest in sin(azimuth) to the centre's (ties: the stronger). Adds ``detection``
    (a detection row or None), ``range_error_cells`` (distance to the interval),
    ``velocity_error_cells`` and ``azimuth_error_cells``."""
    det = result.detections
    out = []
    for t in truth_rows:
        lo, hi = t["range_nearest_m"], t["range_centre_m"]
        r = det["range_m"]
        dr = np.maximum(np.maximum(lo - r, r - hi), 0.0) / result.range_cell_m
        dv = np.abs(det["velocity_mps"] - t["v_rel_m_s"]) / result.velocity_cell_mps
        du = np.abs(det["u_y"] - np.sin(np.radians(t["azimuth_deg"]))) / result.u_cell
        ok = np.flatnonzero((dr <= 1.0) & (dv <= 1.0))
        row = dict(t)
        if ok.size:
            k = ok[np.lexsort((-det["power_db"][ok], du[ok]))[0]]
            row.update(detection=det[k], range_error_cells=float(dr[k]),
                       velocity_error_cells=float(dv[k]), azimuth_error_cells=float(du[k]))
        else:
            row.update(detection=None, range_error_cells=np.inf,
                       velocity_error_cells=np.inf, azimuth_error_cells=np.inf)
        out.append(row)
    return out


def truth_table(rows, result: ArrayResult) -> list[str]:
    """Text lines: per object truth against detection in range, velocity and azimuth,
    errors in cells, the cell sizes first."""
    lines = [f"cells: range {result.range_cell_m:.3f} m, velocity "
             f"{result.velocity_cell_mps:.3f} m/s, azimuth {result.u_cell:.4f} in sin(az) "
             f"({np.degrees(np.arcsin(min(result.u_cell, 1.0))):.2f} deg at boresight)",
             f"{'object':<8} {'R near..centre':>15} {'R det':>7} {'v true':>7} {'v det':>7} "
             f"{'az true':>8} {'az det':>7} {'cells (R, v, az)':>18}"]
    for t in rows:
        d = t["detection"]
        rng = f"{t['range_nearest_m']:.2f}..{t['range_centre_m']:.2f}"
        if d is None:
            lines.append(f"{t['name']:<8} {rng:>15} {'missed':>7} {t['v_rel_m_s']:7.2f} "
                         f"{'':>7} {t['azimuth_deg']:8.2f}")
            continue
        cells = (f"{t['range_error_cells']:.2f}, {t['velocity_error_cells']:.2f}, "
                 f"{t['azimuth_error_cells']:.2f}")
        lines.append(f"{t['name']:<8} {rng:>15} {d['range_m']:7.2f} {t['v_rel_m_s']:7.2f} "
                     f"{d['velocity_mps']:7.2f} {t['azimuth_deg']:8.2f} "
                     f"{np.degrees(d['azimuth_rad']):7.2f} {cells:>18}")
    return lines
