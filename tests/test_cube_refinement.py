"""The cube's detections refined to the joint maximum-likelihood range, velocity and
direction (issue #17, item 3): a target off the grid in every axis, its point in the
cloud against the truth, with the ML step and with the 3-point dB parabola, and the ML
errors against the Cramér–Rao bounds the package computes."""

from __future__ import annotations

import numpy as np
import pytest

from clradcom.errors import ArgumentError
from clradcom.radar import Waveform, add_noise, random_symbols
from clradcom.radar.angle_estimation import angle_cramer_rao_bound, refine_mimo_detections
from clradcom.radar.cube import (
    detect_cube,
    point_cloud,
    radar_cube,
    refine_detections,
    tdm_channels,
)
from clradcom.radar.estimation import cramer_rao_bound
from clradcom.radar.mimo import mimo_received, tdm_range_doppler, virtual_positions

ET, ER = 2, 6
C = 2.99792458e8


def tdm_frame(wf, r, v, az, el, seed, snr_db):
    """One point target (range r, radial velocity v, azimuth/elevation in the radar's
    frame), a 2 x 6 TDM array whose virtual ULA is filled (here along local y), F's
    noise at ``snr_db`` per cell. The received symbols are written here in closed form
    (subcarrier n: e^{−j2πnΔf·2r/c}; symbol μ, sent by transmitter μ mod 2:
    e^{+j2π f_D μ T_sym}; element phases from the positions), independent of the package's
    synthesis and of clradcom.radar.array."""
    lam = wf.wavelength
    tx = np.zeros((ET, 3))
    tx[:, 1] = np.arange(ET) * ER * lam / 2
    rx = np.zeros((ER, 3))
    rx[:, 1] = np.arange(ER) * lam / 2
    u = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    k = 2 * np.pi / lam
    n, m = wf.n_subcarriers, wf.n_symbols
    rng_ph = np.exp(-2j * np.pi * np.arange(n) * wf.subcarrier_spacing_hz * 2 * r / C)
    mu = np.arange(m)
    dop = np.exp(2j * np.pi * (2 * v / lam) * mu * wf.symbol_duration)
    steer_tx = np.exp(1j * k * tx @ u)[mu % ET]  # (M,)
    h = np.stack([rng_ph[:, None] * (dop * steer_tx * np.exp(1j * k * rx[j] @ u))[None, :]
                  for j in range(ER)])
    d = random_symbols(wf, seed)
    rng = np.random.default_rng(seed + 100)
    dr = d * add_noise(h, 10 ** (-snr_db / 10), rng)
    return d, dr, virtual_positions(tx, rx), u


def test_ml_refinement_beats_the_parabola_and_reaches_the_bounds():
    wf = Waveform(n_subcarriers=128, n_symbols=64)
    rng = np.random.default_rng(7)
    snr_db, trials = 0.0, 24
    err = {"parabola": [], "ml": []}
    pos_err = {"parabola": [], "ml": []}
    for t in range(trials):
        # off the grid on every axis: range, velocity and sin(azimuth) fractional cells
        r = (5.0 + rng.uniform(0.2, 0.8)) * wf.range_resolution
        v = (7.0 + rng.uniform(0.2, 0.8)) * wf.velocity_resolution
        az = np.arcsin(rng.uniform(0.15, 0.35))
        d, dr, vp, u = tdm_frame(wf, r, v, az, 0.0, t, snr_db)
        rd = tdm_range_doppler(dr, d, wf, ET)
        cube = radar_cube(rd, vp, wf.wavelength)
        det = detect_cube(cube)[:1]
        f, s = tdm_channels(dr, d, wf, ET)
        ml = refine_detections(det, cube, f, s, vp, wf)
        assert ml["refined"][0] and not det["refined"][0]
        for name, x in (("parabola", det), ("ml", ml)):
            err[name].append([x["range_m"][0] - r, x["velocity_mps"][0] - v,
                              x["u_y"][0] - u[1]])
            p = point_cloud(x, np.zeros(3), np.eye(3))
            pos_err[name].append(np.linalg.norm([p["x"][0] - r * u[0], p["y"][0] - r * u[1],
                                                 p["z"][0]]))
    rmse = {k: np.sqrt(np.mean(np.square(v), axis=0)) for k, v in err.items()}
    # the bounds: every virtual channel sees N x M_v cells, E_rx x N x M cells in all
    # (range, velocity); the angle over the 12-element virtual ULA
    snr = 10 ** (snr_db / 10)
    crb = cramer_rao_bound(wf, snr * ER)
    crb_u = angle_cramer_rao_bound(snr, vp[:, 1], wf.wavelength,
                                   n_cells=wf.n_subcarriers * wf.n_symbols // ET).sin_theta
    bound = np.array([crb.range_m, crb.velocity_mps, crb_u])
    # the ML step: within 2 dB of the bound on every axis (24 trials: RMSE known to ~15 %)
    assert np.all(rmse["ml"] < 10 ** (2 / 20) * bound), (rmse["ml"] / bound)
    # the parabola on the Hann grid: several times worse on every axis
    assert np.all(rmse["parabola"] > 3 * rmse["ml"]), (rmse["parabola"] / rmse["ml"])
    # and so the point cloud's positions: the ML points several times closer to the truth
    pe = {k: float(np.sqrt(np.mean(np.square(v)))) for k, v in pos_err.items()}
    assert pe["ml"] < pe["parabola"] / 3, pe


def test_elevation_of_a_planar_virtual_array_is_refined_too():
    wf = Waveform(n_subcarriers=64, n_symbols=32)
    lam = wf.wavelength
    tx = np.array([[0, 0, 0], [0, 0, lam / 2]])  # vertical pair
    rx = np.zeros((4, 3))
    rx[:, 1] = np.arange(4) * lam / 2
    az, el = np.radians(13.7), np.radians(-21.3)
    u = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    k = 2 * np.pi / lam
    g = (np.exp(1j * k * tx @ u)[:, None] * np.exp(1j * k * rx @ u)[None, :])[:, :, None]
    d = random_symbols(wf, 3)
    r, v = 3.3 * wf.range_resolution, 2.6 * wf.velocity_resolution
    dr = mimo_received(d, g, [2 * r / 2.99792458e8], [2 * v / lam], wf)
    dr = d * add_noise(dr / d, 1e-6, np.random.default_rng(0))
    vp = virtual_positions(tx, rx)
    cube = radar_cube(tdm_range_doppler(dr, d, wf, 2), vp, lam, n_azimuth=32, n_elevation=32)
    det = detect_cube(cube)[:1]
    f, s = tdm_channels(dr, d, wf, 2)
    ml = refine_detections(det, cube, f, s, vp, wf)[0]
    assert ml["refined"]
    # noiseless (60 dB per cell): the ML estimate is the truth to numerical precision
    assert ml["range_m"] == pytest.approx(r, abs=1e-4 * wf.range_resolution)
    assert ml["velocity_mps"] == pytest.approx(v, abs=1e-4 * wf.velocity_resolution)
    assert ml["u_y"] == pytest.approx(u[1], abs=1e-5)
    assert np.degrees(ml["elevation_rad"]) == pytest.approx(-21.3, abs=1e-3)
    assert np.degrees(ml["azimuth_rad"]) == pytest.approx(13.7, abs=1e-3)
    assert abs(det["u_z"][0] - u[2]) > 1e-3  # the parabola is not


def test_refusals_name_the_argument():
    f = np.zeros((4, 8, 8), complex)
    with pytest.raises(ArgumentError, match="positions_m"):
        refine_mimo_detections(f, np.zeros(3), np.zeros((4, 2)), 0.0125, [1.0], [1.0],
                               [[0.0, 0.0]])
    with pytest.raises(ArgumentError, match="n_tx"):
        wf = Waveform(n_subcarriers=64, n_symbols=15)
        tdm_channels(np.zeros((2, 64, 15)), random_symbols(wf, 0), wf, 2)
