"""A radar with antenna arrays on a traced link: its TDM-MIMO frame, the radar cube, CFAR,
the point cloud, and the cars' truth set against the detections in range, velocity and
azimuth (``clradcom cube``; docs/dsp.md §9).

The snapshot holds each link's paths between the radars' reference points; the channel of
every element pair comes from them by the synthetic array
(:func:`clradcom.radar.array.synthetic_channels`: plane-wave phases along each path's
departure and arrival directions, exact in the far field of the array, D²/(λR) ≪ 1: the
street's 12-element array is 6.9 cm wide, D²/λ = 0.4 m). Transmit element i sends symbols
μ = m·E_tx + i (TDM, :func:`clradcom.radar.mimo.mimo_received`); every receive element
gets its own thermal noise at the radar's power and noise figure.

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
from clradcom.radar.array import synthetic_channels
from clradcom.radar.cube import (
    detect_cube,
    point_cloud,
    radar_cube,
    refine_detections,
    tdm_channels,
)
from clradcom.radar.mimo import mimo_received, tdm_range_doppler, virtual_positions
from clradcom.radar.synthesis import (
    SYNTHESIS_ACCURACY,
    add_thermal_noise,
    check_noise_figure,
    check_tx_power,
)
from clradcom.radar.waveform import Waveform, random_symbols

#: how :func:`run_array_radar` places its detections: the joint maximum-likelihood fit
#: on the raw channels (default) or the cube's 3-point dB parabola
REFINEMENTS = ("ml", "parabola")

__all__ = ["REFINEMENTS", "ArrayResult", "array_offsets", "array_truth", "mimo_waveform",
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


def mimo_waveform(waveform: Waveform, n_tx: int) -> Waveform:
    """The waveform with its symbol count cut down to a multiple of the transmitters
    (TDM: each sends every n_tx-th symbol); unchanged when it already is one."""
    m = (waveform.n_symbols // n_tx) * n_tx
    if m < n_tx:
        raise ArgumentError(f"has fewer symbols than the {n_tx} transmitters",
                            argument="waveform", value=waveform.n_symbols)
    if m == waveform.n_symbols:
        return waveform
    return dataclasses.replace(waveform, n_symbols=m)


def tdm_frame(paths, radar, waveform: Waveform, *, seed: int = 0,
              tx_power_w: float | None = None, noise_figure_db: float | None = None):
    """Transmit symbols D (N, M) and received symbols (E_rx, N, M) of a TDM-MIMO frame of
    the radar's own echoes (module docstring); thermal noise per receive element when
    both ``tx_power_w`` and ``noise_figure_db`` are given (noise seeded with seed + 1)."""
    tx, rx, _ = array_offsets(radar)
    d = random_symbols(waveform, seed)
    gains = synthetic_channels(paths, tx, rx, waveform.wavelength)
    received = mimo_received(d, gains, np.asarray(paths.delay_s), np.asarray(paths.doppler_hz),
                             waveform, mode="tdm")
    if tx_power_w is not None and noise_figure_db is not None:
        check_tx_power(tx_power_w)
        check_noise_figure(noise_figure_db)
        rng = np.random.default_rng(seed + 1)
        received = add_thermal_noise(received, tx_power_w, noise_figure_db,
                                     waveform.bandwidth, rng=rng)
    return d, received


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
                    refine: str = "ml") -> ArrayResult:
    """TDM frame, range–Doppler spectra with the motion-induced phase compensated, the
    cube (Hann over range, Doppler and the virtual array), CA-CFAR over it, each
    detection's range, velocity and direction refined (``refine``: "ml", the joint
    maximum-likelihood fit on the raw channels, :func:`clradcom.radar.cube.
    refine_detections`; "parabola", the cube's 3-point dB parabola) and the point cloud
    in the world (radar position and orientation)."""
    if refine not in REFINEMENTS:
        raise ArgumentError(f"must be one of {REFINEMENTS}", argument="refine", value=refine)
    tx, rx, virt = array_offsets(radar)
    wf = mimo_waveform(waveform, tx.shape[0])
    d, received = tdm_frame(paths, radar, wf, seed=seed, tx_power_w=tx_power_w,
                            noise_figure_db=noise_figure_db)
    rd = tdm_range_doppler(received, d, wf, tx.shape[0])
    cube = radar_cube(rd, virt, wf.wavelength, n_azimuth=n_azimuth)
    # a noiseless frame: no CFAR noise estimate below the synthesis' numerical floor
    noiseless = tx_power_w is None or noise_figure_db is None
    det = detect_cube(cube, p_fa=p_fa, accuracy=SYNTHESIS_ACCURACY if noiseless else None)
    if refine == "ml" and virt.shape[0] > 1 and wf.n_symbols // tx.shape[0] > 1:
        f, slow = tdm_channels(received, d, wf, tx.shape[0])
        det = refine_detections(det, cube, f, slow, virt, wf)
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
