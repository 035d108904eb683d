"""The radar cube: range × Doppler × azimuth (× elevation) by FFT, CFAR over the cube,
the angle of every detection, a Capon (MVDR) super-resolution option, and the point
cloud (x, y, z, radial velocity, power, SNR) (docs/dsp.md §9).

Chain: the virtual channels' range–Doppler spectra (:mod:`clradcom.radar.mimo`) are put
on the virtual array's grid (element positions in the radar's y–z plane, multiples of one
spacing per axis; overlapping virtual elements are summed), windowed across it and
transformed by an FFT over each array axis. The virtual element at grid index g along an
axis of spacing d carries exp(+j2π g d u/λ) for a target at direction cosine u along that
axis (docs/dsp.md §9), so FFT bin b (fftshifted) is u_b = b·λ/(N_a d): azimuth
φ = asin(u_y / cos θ_el), elevation θ_el = asin(u_z), both in the radar's frame (azimuth
from boresight +x towards +y, as :func:`clradcom.radar.truth.detection_truth`).

CFAR: cell-averaging with the training band in range and Doppler of each angle bin
(:func:`clradcom.radar.cfar.training_sums`, cancellation-free, and its numerical floor),
threshold α·mean for the design P_fa; detections are the cells above it that are the
maximum of their 3 × 3 × 3 (× 3) neighbourhood; each axis refined by the 3-point parabola
on dB (:func:`clradcom.radar.cfar.parabolic_offset`).

Refinement (:func:`refine_detections`, the default of :func:`clradcom.radar.array_frame.
run_array_radar`): the parabola on a Hann-windowed FFT grid is biased (up to a tenth of a
cell; docs/dsp.md §6) and far from the Cramér–Rao bound; the maximum-likelihood range,
velocity and direction of each detection come instead from the raw TDM channel
estimates (:func:`tdm_channels`) by
:func:`clradcom.radar.angle_estimation.refine_mimo_detections`, the 3-D periodogram's
maximum found by Newton steps from the parabola's values (which stay where a detection
does not converge, flagged in ``refined``).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy import fft as sfft

from clradcom.errors import ArgumentError
from clradcom.radar.angle_estimation import refine_mimo_detections
from clradcom.radar.cfar import (
    RADAR_GUARD,
    RADAR_TRAIN,
    cfar_alpha,
    numerical_floor,
    parabolic_offset,
    training_footprint,
    training_sums,
)
from clradcom.radar.mimo import RangeDoppler
from clradcom.radar.processing import CellCorrelation, get_window
from clradcom.radar.waveform import Waveform, check_symbols

__all__ = ["CUBE_DETECTION_DTYPE", "POINT_DTYPE", "Cube", "angle_grid", "capon_angles",
           "capon_spectrum", "cube_threshold", "detect_cube", "point_cloud", "radar_cube",
           "refine_detections", "tdm_channels"]

CUBE_DETECTION_DTYPE = np.dtype([
    ("range_m", float), ("velocity_mps", float), ("azimuth_rad", float),
    ("elevation_rad", float), ("u_y", float), ("u_z", float), ("power_db", float),
    ("snr_db", float), ("range_bin", float), ("doppler_bin", float), ("azimuth_bin", float),
    ("elevation_bin", float), ("refined", bool),
])
#: a point of the point cloud: world position (m), radial velocity (m/s, positive when
#: approaching, the detections' sign), power (dB, image units) and SNR (dB over the CFAR
#: noise estimate)
POINT_DTYPE = np.dtype([("x", float), ("y", float), ("z", float), ("velocity_mps", float),
                        ("power_db", float), ("snr_db", float)])


class Cube(NamedTuple):
    """Power cube (N', M', A_y, A_z) float64, noise-normalised like the radar image
    (white noise σ² per cell of F keeps σ² per cell), and its axes; ``u_y``/``u_z`` are
    direction cosines along the radar's local y and z (ascending, fftshifted);
    ``correlation``: the range–Doppler correlation of the noise within an angle bin (that
    of the channels' spectra; None: independent cells)."""

    power: np.ndarray
    range_m: np.ndarray
    velocity_mps: np.ndarray
    u_y: np.ndarray
    u_z: np.ndarray
    correlation: CellCorrelation | None = None


def angle_grid(virtual_positions_local, wavelength_m, tol: float = 1e-6):
    """Grid indices (V, 2) of the virtual elements along local y and z, and the two
    spacings (m; 0 for an axis without extent). Refuses elements off the y–z plane or off
    a uniform grid (the FFT needs one; Capon takes any layout)."""
    pos = np.asarray(virtual_positions_local, dtype=np.float64)
    if pos.ndim != 2 or pos.shape[1] != 3 or not np.all(np.isfinite(pos)):
        raise ArgumentError("must be finite (V, 3) positions in the radar frame",
                            argument="virtual_positions", value=f"shape {pos.shape}")
    scale = tol * float(wavelength_m)
    if np.ptp(pos[:, 0]) > scale:
        raise ArgumentError("the angle FFT needs every virtual element in the radar's y-z "
                            "plane (equal x)", argument="virtual_positions",
                            value=f"x spread {np.ptp(pos[:, 0]):g} m")
    idx = np.zeros((pos.shape[0], 2), int)
    spacing = np.zeros(2)
    for a, col in enumerate((1, 2)):
        c = pos[:, col] - pos[:, col].min()
        steps = np.unique(np.round(c / scale)) * scale
        steps = steps[steps > 0]
        if steps.size == 0:
            continue
        d = steps.min()
        g = c / d
        if np.max(np.abs(g - np.round(g))) * d > scale:
            raise ArgumentError("the virtual elements along local "
                                f"{'yz'[a]} are not multiples of one spacing ({d:g} m): "
                                "no FFT grid; use capon_angles", argument="virtual_positions")
        idx[:, a] = np.round(g).astype(int)
        spacing[a] = d
    return idx, spacing


def _angle_bins(requested, extent, name):
    if requested is None:
        n = 1
        while n < extent:
            n *= 2
        return n if extent > 1 else 1
    if isinstance(requested, bool) or not isinstance(requested, int | np.integer) \
            or requested < extent:
        raise ArgumentError(f"must be an integer >= the array's {extent} grid points",
                            argument=name, value=requested)
    return int(requested)


#: the angle spectrum is a direct DFT (one matrix product) when virtual elements × angle
#: bins are at most this many (where it beats gridding and FFT), else an FFT
DIRECT_DFT_MAX = 4096


def _array_window(window, n):
    """An array taper of ``n`` elements: the DFT-even window of n + 1 points without its
    leading zero (symmetric, no element switched off: a 2-element Hann is [0.75, 0.75]);
    an explicit array of n weights as given."""
    if n == 1:
        return np.ones(1)
    if isinstance(window, np.ndarray | list):
        return get_window(window, n)
    return get_window(window, n + 1)[1:]


def radar_cube(rd: RangeDoppler, virtual_positions_local, wavelength_m, *, window="hann",
               n_azimuth: int | None = None, n_elevation: int | None = None,
               workers: int | None = None) -> Cube:
    """Range × Doppler × azimuth × elevation power by FFT over the virtual array grid
    (module docstring). ``n_azimuth``/``n_elevation``: FFT sizes (default: the next power
    of two at or above the grid's extent, 1 for an axis without extent)."""
    idx, spacing = angle_grid(virtual_positions_local, wavelength_m)
    if not isinstance(rd, RangeDoppler):
        raise ArgumentError("must be a clradcom.radar.mimo.RangeDoppler", argument="rd",
                            value=type(rd).__name__)
    s = np.asarray(rd.spectra)
    if s.ndim != 3 or s.shape[2] != idx.shape[0]:
        raise ArgumentError(f"must be (N, M, {idx.shape[0]}) spectra, one per virtual element",
                            argument="rd", value=f"shape {s.shape}")
    ny, nz = idx[:, 0].max() + 1, idx[:, 1].max() + 1
    ay = _angle_bins(n_azimuth, ny, "n_azimuth")
    az = _angle_bins(n_elevation, nz, "n_elevation")
    wy, wz = _array_window(window, ny), _array_window(window, nz)
    w = wy[idx[:, 0]] * wz[idx[:, 1]]
    w = w / np.sqrt(np.sum(w**2))
    if idx.shape[0] * ay * az <= DIRECT_DFT_MAX:
        # a small array: the windowed, zero-padded, centred angle DFT is one (V, A) matrix,
        # applied to every range-Doppler cell in a single product (six times faster than
        # gridding and FFT for 12 elements and 16 bins; the same power to ~1e-15)
        ky = np.fft.fftshift(np.arange(ay))
        kz = np.fft.fftshift(np.arange(az))
        phase = np.outer(idx[:, 0], ky)[:, :, None] / ay + np.outer(idx[:, 1], kz)[:, None, :] / az
        dft = (w[:, None, None] * np.exp(-2j * np.pi * phase)).reshape(idx.shape[0], ay * az)
        spec = (s.reshape(-1, s.shape[2]) @ dft).reshape(s.shape[:2] + (ay, az))
        power = spec.real**2 + spec.imag**2
    else:
        grid = np.zeros(s.shape[:2] + (ny, nz), complex)
        for v in range(idx.shape[0]):  # overlapping virtual elements add up
            grid[:, :, idx[v, 0], idx[v, 1]] += w[v] * s[:, :, v]
        spec = sfft.fft2(grid, s=(ay, az), axes=(2, 3), workers=workers)
        power = np.fft.fftshift(spec.real**2 + spec.imag**2, axes=(2, 3))
    lam = float(wavelength_m)
    u_y = ((np.arange(ay) - ay // 2) * lam / (ay * spacing[0]) if spacing[0] > 0
           else np.zeros(1))
    u_z = ((np.arange(az) - az // 2) * lam / (az * spacing[1]) if spacing[1] > 0
           else np.zeros(1))
    return Cube(power, np.asarray(rd.range_m), np.asarray(rd.velocity_mps), u_y, u_z,
                rd.correlation)


def _db(power, cells):
    return 10.0 * np.log10(np.maximum(power[tuple(cells)], 1e-300))


def _interp(power, cells, axis, n):
    """Parabolic offset and height (on dB) along one axis (wrapping) at the cells."""
    lo = list(cells)
    hi = list(cells)
    lo[axis] = (cells[axis] - 1) % n
    hi[axis] = (cells[axis] + 1) % n
    return parabolic_offset(_db(power, lo), _db(power, cells), _db(power, hi))


def _axis_value(axis_values, frac):
    if axis_values.size < 2:
        return np.full(frac.shape, axis_values[0] if axis_values.size else 0.0)
    return axis_values[0] + frac * (axis_values[1] - axis_values[0])


def _local_maxima(power, cells):
    """The cells (index arrays) that are at least every neighbour of their 3 × 3 × 3 (× 3)
    neighbourhood (wrapping); only the cells above threshold are looked at."""
    keep = np.ones(cells[0].size, bool)
    steps = [(-1, 0, 1) if k > 1 else (0,) for k in power.shape]
    p0 = power[cells]
    for offset in np.stack(np.meshgrid(*steps, indexing="ij"), -1).reshape(-1, 4):
        if not offset.any():
            continue
        nb = tuple((c + o) % k for c, o, k in zip(cells, offset, power.shape, strict=True))
        keep &= p0 >= power[nb]
    return tuple(c[keep] for c in cells)


def cube_threshold(cube: Cube, guard=RADAR_GUARD, train=RADAR_TRAIN, p_fa: float = 1e-6,
                   accuracy: float | None = None):
    """(threshold, noise) of CA-CFAR on every cell of the cube: training band in range ×
    Doppler of each angle bin, α designed for the noise correlation of those cells
    (``cube.correlation``; :func:`clradcom.radar.cfar.cfar_alpha`), noise estimates no
    lower than the numerical floor."""
    power = np.asarray(cube.power, dtype=float)
    if power.ndim != 4:
        raise ArgumentError("must be a (N, M, A_y, A_z) cube", argument="cube",
                            value=f"shape {power.shape}")
    fp = training_footprint(guard, train)
    if fp.shape[0] > power.shape[0] or fp.shape[1] > power.shape[1]:
        raise ArgumentError(f"is larger than the cube's {power.shape[0]} x {power.shape[1]} "
                            "range-Doppler cells", argument="guard + train",
                            value=f"CFAR window {fp.shape}")
    correlation = cube.correlation
    if correlation is not None and (np.size(correlation.range), np.size(correlation.doppler)) \
            != power.shape[:2]:
        raise ArgumentError(f"must give one lag per range and Doppler cell {power.shape[:2]}",
                            argument="cube.correlation",
                            value=f"lengths {np.size(correlation.range)}, "
                                  f"{np.size(correlation.doppler)}")
    alpha, _ = cfar_alpha(guard, train, p_fa, "ca", None, correlation)
    floor = numerical_floor(power, accuracy)
    noise = np.maximum(training_sums(power, guard, train) / int(fp.sum()), floor)
    return alpha * noise, noise


def detect_cube(cube: Cube, guard=RADAR_GUARD, train=RADAR_TRAIN, p_fa: float = 1e-6,
                accuracy: float | None = None, max_detections: int | None = None,
                sidelobe_db: float | None = 30.0):
    """CA-CFAR over the cube (training band in range × Doppler of each angle bin), local
    maxima over all axes, parabolic refinement per axis (module docstring). Returns
    :data:`CUBE_DETECTION_DTYPE` rows, strongest first.

    ``sidelobe_db``: a detection more than this below a stronger one within one range and
    one Doppler cell of it is taken for that one's angle sidelobe and dropped (the range–
    Doppler CFAR cannot tell: the training cells of an angle bin hold the target's
    range–Doppler sidelobes at that angle's own sidelobe level). 30 dB is below the peak
    sidelobe of the Hann window (−31.5 dB); None keeps every CFAR detection."""
    power = np.asarray(cube.power, dtype=float)
    threshold, noise = cube_threshold(cube, guard, train, p_fa, accuracy)
    cells = _local_maxima(power, np.nonzero(power > threshold))
    out = np.zeros(cells[0].size, CUBE_DETECTION_DTYPE)
    if out.size == 0:
        return out
    y0 = _db(power, cells)
    frac, peak = [], y0.copy()
    for axis in range(4):
        if power.shape[axis] > 2:
            off, h = _interp(power, cells, axis, power.shape[axis])
            peak += h - y0
        else:
            off = np.zeros(y0.shape)
        frac.append(cells[axis] + off)
    u_y = _axis_value(cube.u_y, frac[2])
    u_z = _axis_value(cube.u_z, frac[3])
    el = np.arcsin(np.clip(u_z, -1.0, 1.0))
    out["range_m"] = _axis_value(cube.range_m, frac[0])
    out["velocity_mps"] = _axis_value(cube.velocity_mps, frac[1])
    out["u_y"], out["u_z"] = u_y, u_z
    out["elevation_rad"] = el
    out["azimuth_rad"] = np.arcsin(np.clip(u_y / np.cos(el), -1.0, 1.0))
    out["power_db"] = peak
    out["snr_db"] = peak - 10.0 * np.log10(noise[cells])
    out["range_bin"], out["doppler_bin"] = frac[0], frac[1]
    out["azimuth_bin"], out["elevation_bin"] = frac[2], frac[3]
    out = out[np.argsort(-out["power_db"], kind="stable")]
    if sidelobe_db is not None and out.size > 1:
        dr = np.abs(out["range_bin"][:, None] - out["range_bin"][None, :])
        dd = np.abs(out["doppler_bin"][:, None] - out["doppler_bin"][None, :])
        dd = np.minimum(dd, power.shape[1] - dd)
        weaker = out["power_db"][:, None] < out["power_db"][None, :] - float(sidelobe_db)
        out = out[~np.any((dr <= 1.5) & (dd <= 1.5) & weaker, axis=1)]
    return out[:max_detections] if max_detections is not None else out


def tdm_channels(received, symbols, waveform: Waveform, n_tx: int):
    """(F, slow_time) of a TDM frame: the raw channel estimates F = D_r/D of every virtual
    channel v = i·E_rx + j on its transmitter's symbols μ = m·E_tx + i, (E_tx·E_rx, N, M_v)
    as :func:`clradcom.radar.mimo.tdm_range_doppler` orders them, and each channel's
    slow-time offset i/E_tx (in units of the channel's interval E_tx·T_sym)."""
    d = check_symbols(symbols, waveform)
    r = np.asarray(received)
    if r.ndim != 3 or r.shape[1:] != d.shape:
        raise ArgumentError(f"must be (E_rx, {d.shape[0]}, {d.shape[1]})", argument="received",
                            value=f"shape {r.shape}")
    if isinstance(n_tx, bool) or not isinstance(n_tx, int | np.integer) or n_tx < 1 \
            or d.shape[1] % n_tx:
        raise ArgumentError(f"must be a positive integer dividing the {d.shape[1]} symbols",
                            argument="n_tx", value=n_tx)
    er, n, m = r.shape
    mv = m // n_tx
    f = (r / d[None]).reshape(er, n, mv, n_tx).transpose(3, 0, 1, 2).reshape(n_tx * er, n, mv)
    return f, np.repeat(np.arange(n_tx) / n_tx, er)


def refine_detections(detections, cube: Cube, channels, slow_time, virtual_positions_local,
                      waveform: Waveform) -> np.ndarray:
    """The cube's detections with range, velocity and direction replaced by the joint
    maximum-likelihood estimate (module docstring); ``refined`` True where it converged
    (elsewhere the parabola's values stay). ``channels``/``slow_time`` from
    :func:`tdm_channels`; the cube's range and velocity cells are those of the waveform
    (Δr, and Δv of the whole frame: M_v·E_tx·T_sym = M·T_sym)."""
    det = np.array(detections, dtype=CUBE_DETECTION_DTYPE, copy=True)
    if det.size == 0:
        return det
    pos = np.asarray(virtual_positions_local, float)
    dr, dv = waveform.range_resolution, waveform.velocity_resolution
    u0 = np.stack([det["u_y"], det["u_z"]], axis=1)
    ref = refine_mimo_detections(channels, slow_time, pos[:, 1:3], waveform.wavelength,
                                 det["range_m"] / dr, det["velocity_mps"] / dv, u0)
    ok = ref.converged
    det["range_m"] = np.where(ok, ref.range_bin * dr, det["range_m"])
    det["velocity_mps"] = np.where(ok, ref.doppler_bin * dv, det["velocity_mps"])
    det["u_y"], det["u_z"] = ref.u[:, 0], ref.u[:, 1]
    el = np.arcsin(np.clip(det["u_z"], -1.0, 1.0))
    det["elevation_rad"] = el
    det["azimuth_rad"] = np.arcsin(np.clip(det["u_y"] / np.cos(el), -1.0, 1.0))
    det["refined"] = ok
    return det


def point_cloud(detections, position, orientation) -> np.ndarray:
    """:data:`POINT_DTYPE` points of cube detections: the radar's ``position`` plus
    range times the detection's direction (azimuth, elevation in the radar frame, its
    columns ``orientation``) in the world."""
    det = np.asarray(detections)
    r, az, el = det["range_m"], det["azimuth_rad"], det["elevation_rad"]
    local = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=1)
    world = np.asarray(position, float)[None, :] + (r[:, None] * local) @ \
        np.asarray(orientation, float).T
    out = np.zeros(det.size, POINT_DTYPE)
    out["x"], out["y"], out["z"] = world.T
    out["velocity_mps"] = det["velocity_mps"]
    out["power_db"], out["snr_db"] = det["power_db"], det["snr_db"]
    return out


# --- Capon (MVDR) super-resolution ------------------------------------------------------
def capon_spectrum(snapshots, positions_m, wavelength_m, u_grid, *, subarray: int | None = None,
                   forward_backward: bool = True, loading: float = 1e-3) -> np.ndarray:
    """Capon (MVDR) spatial spectrum P(u) = 1 / Re(aᴴ R⁻¹ a) along one array axis (Capon,
    Proc. IEEE 57(8), 1969; Van Trees, Optimum Array Processing, §6.2, §9.2).

    ``snapshots`` (V, K): the virtual channels at K cells; ``positions_m`` (V,) element
    positions along the axis (a filled uniform array when ``subarray`` is set: spatial
    smoothing over every run of ``subarray`` consecutive elements, Shan, Wax & Kailath,
    IEEE T-ASSP 33(4), 1985, which with ``forward_backward`` averaging (Pillai & Kwon
    1989) decorrelates coherent returns of one range–Doppler cell). ``loading``: diagonal
    loading relative to the mean eigenvalue. a(u) = exp(+j2π x u / λ)."""
    x = np.asarray(snapshots, dtype=complex)
    pos = np.asarray(positions_m, dtype=float).reshape(-1)
    if x.ndim != 2 or x.shape[0] != pos.size:
        raise ArgumentError(f"must be ({pos.size}, K) snapshots", argument="snapshots",
                            value=f"shape {x.shape}")
    v = pos.size
    length = v if subarray is None else int(subarray)
    if not 2 <= length <= v:
        raise ArgumentError(f"must lie in [2, {v}]", argument="subarray", value=subarray)
    order = np.argsort(pos)
    x, pos = x[order], pos[order]
    r = np.zeros((length, length), complex)
    shifts = v - length + 1
    for s in range(shifts):
        xs = x[s:s + length]
        r += xs @ xs.conj().T
    r /= shifts * x.shape[1]
    if forward_backward:
        j = np.eye(length)[::-1]
        r = 0.5 * (r + j @ r.conj() @ j)
    r += loading * np.real(np.trace(r)) / length * np.eye(length)
    sub = pos[:length] - pos[0]
    a = np.exp(2j * np.pi * np.outer(sub, np.asarray(u_grid, float)) / float(wavelength_m))
    ri_a = np.linalg.solve(r, a)
    return 1.0 / np.real(np.sum(a.conj() * ri_a, axis=0))


def capon_angles(rd: RangeDoppler, detections, virtual_positions_local, wavelength_m, *,
                 n_grid: int = 721, neighbourhood=(1, 1), subarray: int | None = None,
                 max_sources: int = 4, floor_db: float = 10.0) -> list[np.ndarray]:
    """Azimuths (rad, radar frame) found by Capon at each detection's range–Doppler cell,
    for a horizontal virtual array (along local y): snapshots are the virtual channels of
    the cells within ``neighbourhood`` (range, Doppler half-widths) of the detection,
    spatial smoothing with ``subarray`` elements (default ⌈2V/3⌉ for a filled uniform
    array, none otherwise) and forward–backward averaging. Returns, per detection, the
    azimuths of the spectrum's local maxima within ``floor_db`` of its highest, at most
    ``max_sources``, strongest first."""
    pos = np.asarray(virtual_positions_local, float)
    idx, spacing = angle_grid(pos, wavelength_m)
    if spacing[1] > 0 or spacing[0] == 0:
        raise ArgumentError("capon_angles takes a horizontal linear virtual array (along "
                            "local y)", argument="virtual_positions_local")
    order = np.argsort(idx[:, 0])
    filled = np.array_equal(idx[order, 0], np.arange(idx.shape[0]))
    if subarray is None:
        subarray = int(np.ceil(2 * idx.shape[0] / 3)) if filled else None
    elif not filled:
        raise ArgumentError("spatial smoothing needs a filled uniform array",
                            argument="subarray", value=subarray)
    s = np.asarray(rd.spectra)
    n, m, _ = s.shape
    lam = float(wavelength_m)
    u_max = min(1.0, lam / (2 * spacing[0]))
    u = np.linspace(-u_max, u_max, n_grid)
    hr, hd = neighbourhood
    out = []
    for det in np.atleast_1d(detections):
        r0, d0 = int(round(det["range_bin"])), int(round(det["doppler_bin"]))
        rows = (r0 + np.arange(-hr, hr + 1)) % n
        cols = (d0 + np.arange(-hd, hd + 1)) % m
        snaps = s[np.ix_(rows, cols)].reshape(-1, s.shape[2]).T
        p = capon_spectrum(snaps[order], pos[order, 1], lam, u, subarray=subarray)
        pdb = 10 * np.log10(p)
        peaks = np.nonzero((pdb[1:-1] > pdb[:-2]) & (pdb[1:-1] >= pdb[2:]))[0] + 1
        peaks = peaks[pdb[peaks] >= pdb.max() - floor_db]
        peaks = peaks[np.argsort(-pdb[peaks])][:max_sources]
        out.append(np.arcsin(u[peaks]))
    return out
