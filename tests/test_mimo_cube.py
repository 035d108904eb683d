"""MIMO (TDM with its Doppler phase compensated, DDM) and the radar cube: targets at known
range, velocity and azimuth found within one cell; Capon resolving two targets the FFT
cannot; the point cloud's files and picture."""

from __future__ import annotations

import csv

import numpy as np
import pytest
import trimesh

import clradcom.radar.cube as cube_module
from clradcom.errors import ArgumentError
from clradcom.radar import Waveform, add_noise, random_symbols
from clradcom.radar.cube import capon_angles, detect_cube, point_cloud, radar_cube
from clradcom.radar.mimo import (
    RangeDoppler,
    ddm_range_doppler,
    mimo_received,
    tdm_range_doppler,
    virtual_positions,
)
from clradcom.radar.pointcloud import (
    POINT_COLUMNS,
    bird_eye_figure,
    read_point_cloud_ply,
    save_bird_eye,
    write_point_cloud_csv,
    write_point_cloud_ply,
)


def mimo_array(et, er, lam):
    """A filled virtual ULA along local y: rx at λ/2, tx at er·λ/2."""
    tx = np.zeros((et, 3))
    tx[:, 1] = np.arange(et) * er * lam / 2
    rx = np.zeros((er, 3))
    rx[:, 1] = np.arange(er) * lam / 2
    return tx, rx


def plane_wave_gains(tx, rx, azimuth, lam, amplitude=1.0):
    """(E_tx, E_rx, P) channel of point targets in the radar's x-y plane, computed here
    from the element positions directly (independent of clradcom.radar.array)."""
    d = np.stack([np.cos(azimuth), np.sin(azimuth), np.zeros_like(azimuth)], axis=1)
    k = 2 * np.pi / lam
    return (np.exp(1j * k * tx @ d.T)[:, None, :] * np.exp(1j * k * rx @ d.T)[None]
            * amplitude)


def frame(wf, et, er, rng_m, vel, az, mode, seed=1, noise=1e-4, amplitude=1.0):
    lam = wf.wavelength
    tx, rx = mimo_array(et, er, lam)
    d = random_symbols(wf, seed)
    g = plane_wave_gains(tx, rx, np.asarray(az), lam, amplitude)
    dr = mimo_received(d, g, 2 * np.asarray(rng_m) / 2.99792458e8,
                       2 * np.asarray(vel) / lam, wf, mode=mode)
    return d, add_noise(dr, noise, np.random.default_rng(seed + 1)), virtual_positions(tx, rx)


def test_tdm_angle_of_a_fast_target_is_right_only_with_compensation():
    wf = Waveform(n_subcarriers=128, n_symbols=48)
    d, dr, vp = frame(wf, 3, 4, [20.0], [60.0], [np.radians(10.0)], "tdm")
    az = {}
    for comp in (True, False):
        rd = tdm_range_doppler(dr, d, wf, 3, compensate=comp)
        det = detect_cube(radar_cube(rd, vp, wf.wavelength, n_azimuth=64))
        az[comp] = np.degrees(det["azimuth_rad"][0])
        assert det["velocity_mps"][0] == pytest.approx(60.0, abs=rd.velocity_mps[1]
                                                       - rd.velocity_mps[0])
    # 2π f_D T_sym = 0.75 rad per transmitter slot: ~3.6° of azimuth uncompensated
    assert abs(az[True] - 10.0) < 0.5
    assert abs(az[False] - 10.0) > 2.5


@pytest.mark.parametrize("mode", ["tdm", "ddm"])
def test_cube_finds_targets_within_one_cell(mode):
    wf = Waveform(n_subcarriers=128, n_symbols=64)
    truth = [(15.0, 4.0, 20.0), (40.0, -12.0, -35.0), (70.0, 20.0, 0.0)]
    r, v, a = (np.array(x) for x in zip(*truth, strict=True))
    d, dr, vp = frame(wf, 2, 6, r, v, np.radians(a), mode)
    rd = (tdm_range_doppler(dr, d, wf, 2) if mode == "tdm"
          else ddm_range_doppler(dr, d, wf, 2))
    cube = radar_cube(rd, vp, wf.wavelength)
    assert cube.power.shape == (128, 32, 16, 1)
    det = detect_cube(cube, p_fa=1e-9)  # no false alarm among the 65 k cells
    assert det.size == 3
    dr_, dv = cube.range_m[1], cube.velocity_mps[1] - cube.velocity_mps[0]
    du = cube.u_y[1] - cube.u_y[0]
    for rt, vt, at in truth:
        k = np.argmin(np.abs(det["range_m"] - rt))
        assert abs(det["range_m"][k] - rt) < dr_
        assert abs(det["velocity_mps"][k] - vt) < dv
        assert abs(det["u_y"][k] - np.sin(np.radians(at))) < du
        assert abs(np.degrees(det["azimuth_rad"][k]) - at) < 2.0


def test_cube_cfar_keeps_its_design_false_alarm_rate():
    rng = np.random.default_rng(0)
    vp = np.zeros((12, 3))
    vp[:, 1] = np.arange(12) * 0.00625
    hits = cells = 0
    for _ in range(10):
        s = (rng.standard_normal((128, 64, 12)) + 1j * rng.standard_normal((128, 64, 12)))
        cube = radar_cube(RangeDoppler(s / np.sqrt(2), np.arange(128.0), np.arange(64.0)),
                          vp, 0.0125)
        hits += detect_cube(cube, p_fa=1e-4, sidelobe_db=None).size
        cells += cube.power.size
    # local maxima only: fewer than the raw crossings (1e-4 per cell), but of that order
    assert 0.2e-4 < hits / cells < 1.3e-4


def test_planar_virtual_array_gives_elevation():
    wf = Waveform(n_subcarriers=64, n_symbols=16)
    lam = wf.wavelength
    tx = np.array([[0, 0, 0], [0, 0, lam / 2]])  # vertical pair
    rx = np.zeros((4, 3))
    rx[:, 1] = np.arange(4) * lam / 2
    az, el = np.radians(15.0), np.radians(-20.0)
    u = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    k = 2 * np.pi / lam
    g = (np.exp(1j * k * tx @ u)[:, None] * np.exp(1j * k * rx @ u)[None, :])[:, :, None]
    d = random_symbols(wf, 3)
    dr = add_noise(mimo_received(d, g, [2 * 10.0 / 2.99792458e8], [0.0], wf), 1e-4,
                   np.random.default_rng(0))
    cube = radar_cube(tdm_range_doppler(dr, d, wf, 2), virtual_positions(tx, rx), lam,
                      n_azimuth=32, n_elevation=32)
    det = detect_cube(cube, train=(4, 2))[0]  # 8 Doppler cells: the radar band's 11 don't fit
    assert np.degrees(det["elevation_rad"]) == pytest.approx(-20.0, abs=2.0)
    assert np.degrees(det["azimuth_rad"]) == pytest.approx(15.0, abs=2.0)


def test_capon_resolves_two_targets_in_one_cell_that_the_fft_merges():
    wf = Waveform(n_subcarriers=128, n_symbols=32)
    d, dr, vp = frame(wf, 2, 6, [20.0, 20.0], [5.0, 5.0], np.radians([0.0, 7.0]), "tdm",
                      seed=2, amplitude=np.array([1.0, np.exp(1j)]))
    rd = tdm_range_doppler(dr, d, wf, 2)
    det = detect_cube(radar_cube(rd, vp, wf.wavelength))
    fft_az = np.degrees(det["azimuth_rad"])
    # the FFT (Rayleigh width ~9.5°, Hann) does not place both
    assert not all(np.min(np.abs(fft_az - t)) < 1.5 for t in (0.0, 7.0))
    found = np.sort(np.degrees(capon_angles(rd, det[:1], vp, wf.wavelength)[0]))
    assert found.size == 2
    np.testing.assert_allclose(found, [0.0, 7.0], atol=0.5)


def test_refusals_name_the_argument():
    wf = Waveform(n_subcarriers=64, n_symbols=15)
    d = random_symbols(wf, 0)
    with pytest.raises(ArgumentError, match="n_tx"):
        tdm_range_doppler(np.zeros((2, 64, 15)), d, wf, 2)
    with pytest.raises(ArgumentError, match="virtual_positions"):
        radar_cube(None, [[0, 0, 0], [0, 0.004, 0], [0, 0.0101, 0]], 0.0125)


def test_point_cloud_files_parse_and_the_picture_shows_them(tmp_path):
    wf = Waveform(n_subcarriers=128, n_symbols=64)
    d, dr, vp = frame(wf, 2, 6, [15.0, 40.0], [4.0, -12.0], np.radians([20.0, -35.0]), "tdm")
    det = detect_cube(radar_cube(tdm_range_doppler(dr, d, wf, 2), vp, wf.wavelength))
    yaw = np.radians(90.0)  # radar at (1, 2, 0.5) looking along world +y
    rot = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]])
    pts = point_cloud(det, [1.0, 2.0, 0.5], rot)
    # target 1: 15 m at 20° left of boresight -> world (1 - 15 sin 20°, 2 + 15 cos 20°)
    k = np.argmin(np.abs(det["range_m"] - 15.0))
    assert pts["x"][k] == pytest.approx(1 - 15 * np.sin(np.radians(20)), abs=0.4)
    assert pts["y"][k] == pytest.approx(2 + 15 * np.cos(np.radians(20)), abs=0.4)
    assert pts["z"][k] == pytest.approx(0.5, abs=1e-9)
    write_point_cloud_csv(tmp_path / "pc.csv", pts)
    write_point_cloud_ply(tmp_path / "pc.ply", pts)
    with open(tmp_path / "pc.csv", newline="") as fh:
        rows = list(csv.reader(fh))
    assert tuple(rows[0]) == POINT_COLUMNS and len(rows) == pts.size + 1
    np.testing.assert_array_equal([float(r[3]) for r in rows[1:]], pts["velocity_mps"])
    back = read_point_cloud_ply(tmp_path / "pc.ply")
    np.testing.assert_array_equal(back, pts)
    cloud = trimesh.load(tmp_path / "pc.ply")  # an independent PLY reader
    np.testing.assert_allclose(cloud.vertices, np.stack([pts["x"], pts["y"], pts["z"]], 1))
    truth = [{"name": "car", "centre_m": [-4.0, 16.0, 0.5]}]
    fig = bird_eye_figure(pts, np.array([[[0, 0, 0], [5, 0, 0], [0, 5, 0]]]), truth, (1, 2))
    ax = fig.axes[0]
    np.testing.assert_allclose(ax.collections[-1].get_offsets(),
                               np.stack([pts["x"], pts["y"]], 1))
    assert any(ln.get_xydata().tolist() == [[-4.0, 16.0]] for ln in ax.lines)
    out = save_bird_eye(tmp_path / "bev.png", pts, truth=truth)
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize("bins", [(16, 2), (7, 4), (8, 5)])
def test_direct_angle_dft_equals_the_gridded_fft(monkeypatch, bins):
    # a planar virtual array whose elements overlap (tx one rx spacing apart along y and a
    # vertical tx), even and odd angle bin counts: the small-array matrix DFT and the
    # gridded FFT give the same power
    wf = Waveform(n_subcarriers=32, n_symbols=12)
    lam = wf.wavelength
    tx = np.array([[0, 0, 0], [0, lam / 2, 0], [0, 0, lam / 2]])
    rx = np.zeros((4, 3))
    rx[:, 1] = np.arange(4) * lam / 2
    rng = np.random.default_rng(5)
    spectra = rng.standard_normal((32, 4, 12)) + 1j * rng.standard_normal((32, 4, 12))
    rd = RangeDoppler(spectra, np.arange(32.0), np.arange(4.0))
    vp = virtual_positions(tx, rx)
    direct = radar_cube(rd, vp, lam, n_azimuth=bins[0], n_elevation=bins[1]).power
    monkeypatch.setattr(cube_module, "DIRECT_DFT_MAX", 0)
    gridded = radar_cube(rd, vp, lam, n_azimuth=bins[0], n_elevation=bins[1]).power
    assert direct.shape == gridded.shape == (32, 4) + bins
    assert np.max(np.abs(direct - gridded)) <= 1e-12 * np.max(gridded)
