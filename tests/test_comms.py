"""The communication half of RadCom (clradcom.radar.comms, clradcom comms).

Each stage against an independent result: Gray mapping by exhaustive check, the AWGN
closed forms written out here (Proakis §5.2; Cho & Yoon 2002 for 16-QAM's Gray BER),
Monte Carlo error rates against them within binomial error (known channel) or within
1 dB (pilots), synchronisation against a known timing and frequency offset.  Small frames
(N = 256, M = 32) keep it fast.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from clradcom.errors import ArgumentError
from clradcom.radar import comms as c
from clradcom.radar.waveform import Waveform, constellation
from tests.dsp_helpers import los_paths

N, M = 256, 32
WF = Waveform(n_subcarriers=N, n_symbols=M)


def q(x):
    return 0.5 * math.erfc(x / math.sqrt(2.0))


def mean_power(gains, delays, dopplers):
    """mean over the frame's cells of |Σ a e^{−j2πnΔfτ} e^{j2πf μT_sym}|², summed directly."""
    n = np.arange(N)[:, None, None]
    mu = np.arange(M)[None, :, None]
    h = np.sum(np.asarray(gains) * np.exp(-2j * np.pi * n * WF.subcarrier_spacing_hz
                                          * np.asarray(delays))
               * np.exp(2j * np.pi * np.asarray(dopplers) * mu * WF.symbol_duration), axis=2)
    return float(np.mean(np.abs(h) ** 2))


def binomial_ok(errors, trials, p, sigmas=4.0):
    """|errors − trials·p| within ``sigmas`` binomial standard deviations (plus one)."""
    return abs(errors - trials * p) <= sigmas * math.sqrt(trials * p * (1 - p)) + 1


# ----------------------------------------------------------------------------------------
# mapping and theory
# ----------------------------------------------------------------------------------------
@pytest.mark.parametrize("mod", c.COMMS_MODULATIONS)
def test_gray_mapping_round_trips_and_neighbours_differ_in_one_bit(mod):
    k = c.bits_per_symbol(mod)
    bits = (np.arange(2 ** k)[:, None] >> np.arange(k - 1, -1, -1)) & 1
    pts = c.gray_map(bits, mod)
    assert np.mean(np.abs(pts) ** 2) == pytest.approx(1.0)
    ref = constellation(mod)
    assert np.allclose(np.sort_complex(np.round(pts, 12)), np.sort_complex(np.round(ref, 12)))
    back_pts, back_bits = c.gray_demap(pts + 0.01 * (1 + 1j) * (mod != "bpsk"), mod)
    assert np.array_equal(back_bits, bits) and np.allclose(back_pts, pts)
    d = np.abs(pts[:, None] - pts[None, :])
    dmin = d[d > 0].min()
    near = np.isclose(d, dmin)
    hamming = (bits[:, None, :] != bits[None, :, :]).sum(axis=2)
    assert np.all(hamming[near] == 1)


def test_awgn_closed_forms():
    for s_db in (0.0, 4.0, 8.0):
        g = 10 ** (s_db / 10)
        ser, ber = c.awgn_error_rates("qpsk", s_db)
        assert ber == pytest.approx(q(math.sqrt(g)), rel=1e-12)  # Q(√(2Eb/N0)), Eb = Es/2
        assert ser == pytest.approx(1 - (1 - q(math.sqrt(g))) ** 2, rel=1e-12)
        ser, ber = c.awgn_error_rates("bpsk", s_db)
        assert ber == pytest.approx(q(math.sqrt(2 * g)), rel=1e-12)
    for s_db in (6.0, 12.0, 18.0):
        g = 10 ** (s_db / 10)
        a = math.sqrt(g / 5)
        ser, ber = c.awgn_error_rates("16qam", s_db)
        p = 2 * (1 - 1 / 4) * q(math.sqrt(3 * g / 15))
        assert ser == pytest.approx(1 - (1 - p) ** 2, rel=1e-12)
        assert ber == pytest.approx((3 * q(a) + 2 * q(3 * a) - q(5 * a)) / 4, rel=1e-12)
    # a flat channel: the known-channel theory is the AWGN one
    ser, ber = c.channel_error_rates("16qam", [10.0], np.full((8, 4), 2.0 + 1j))
    assert ber[0] == pytest.approx(c.awgn_error_rates("16qam", 10.0)[1], rel=1e-3)


def test_pilot_pattern_overhead_and_refusals():
    block = c.PilotPattern.named("block", 8)
    assert block.overhead(N, M) == pytest.approx(5 / 32)  # symbols 0, 8, 16, 24, 31
    comb = c.PilotPattern.named("comb", 4)
    assert comb.overhead(N, M) == pytest.approx(65 / 256)
    with pytest.raises(ArgumentError, match="symbol_step"):
        c.PilotPattern(1, 0)
    with pytest.raises(ArgumentError, match="pilots"):
        c.PilotPattern.named("diamond", 4)
    with pytest.raises(ArgumentError, match="modulation"):
        c.bits_per_symbol("8psk")


# ----------------------------------------------------------------------------------------
# synchronisation
# ----------------------------------------------------------------------------------------
def test_synchronisation_finds_known_timing_and_frequency_offset():
    rng = np.random.default_rng(3)
    pattern = c.PilotPattern()
    tx = c.transmit_frame(WF, "qpsk", pattern, rng)
    fs, df = WF.sample_rate, WF.subcarrier_spacing_hz
    for t_off, cfo in ((2.0e-6, 7000.0), (9.5e-6, -12000.0)):
        tau = 80e-9
        y = c.received_signal(tx.symbols, [1e-4], [tau], [1500.0], WF,
                              timing_offset_s=t_off, cfo_hz=cfo, phase_rad=1.0)
        nv = c.snr_noise_variance(1e-8, 10.0)
        y = y + math.sqrt(nv / 2) * (rng.standard_normal(y.size)
                                     + 1j * rng.standard_normal(y.size))
        sync, _ = c.synchronise(y, WF, c.pilot_values(N, M), tx.pilot_mask)
        start = (t_off + tau) * fs
        assert abs(sync.frame_start - start) <= 1.0
        assert sync.eps * df == pytest.approx(cfo + 1500.0, abs=0.003 * df)


# ----------------------------------------------------------------------------------------
# error rates
# ----------------------------------------------------------------------------------------
@pytest.mark.parametrize("mod, snrs", [("qpsk", (2.0, 6.0, 9.0)), ("16qam", (10.0, 14.0))])
def test_line_of_sight_matches_awgn_theory(mod, snrs):
    """One path, no Doppler: with the known channel BER/SER/EVM are the AWGN theory within
    Monte Carlo error; with the pilots' estimate within 1 dB of it."""
    rng = np.random.default_rng(5)
    a, tau, fd = [3e-5 * np.exp(0.4j)], [70e-9], [0.0]
    t_off = 2.5e-6
    for s in snrs:
        counts = np.zeros(6)
        for _ in range(2):
            tx = c.transmit_frame(WF, mod, c.PilotPattern(), rng)
            clean = c.received_signal(tx.symbols, a, tau, fd, WF, timing_offset_s=t_off)
            nv = c.snr_noise_variance(abs(a[0]) ** 2, s)
            y = clean + math.sqrt(nv / 2) * (rng.standard_normal(clean.size)
                                             + 1j * rng.standard_normal(clean.size))
            est = c.receive(y, tx, WF)
            h = c.known_channel(a, tau, fd, WF, est.sync, timing_offset_s=t_off)
            known = c.receive(y, tx, WF, channel=h)
            counts += (known.bit_errors, known.bits, known.symbol_errors, known.symbols,
                       est.bit_errors, known.evm ** 2)
        be, nb, se, ns, be_est, evm2 = counts
        ser_th, ber_th = c.awgn_error_rates(mod, s)
        assert binomial_ok(be, nb, ber_th), (s, be / nb, ber_th)
        assert binomial_ok(se, ns, ser_th), (s, se / ns, ser_th)
        # EVM² is the mean of ns/2 per frame exponential noise powers: relative sd 1/√n
        assert 10 * math.log10(evm2 / 2) == pytest.approx(-s, abs=4 * 4.343 / math.sqrt(ns))
        assert be_est / nb <= c.awgn_error_rates(mod, s - 1.0)[1]
        assert binomial_ok(be_est, nb, ber_th) or be_est > nb * ber_th


def test_two_path_channel_estimation_comes_within_one_db():
    """Two resolved paths (−3 dB, 0.45 µs apart) with different Dopplers and a carrier
    offset: pilots + Wiener estimate + ZF within 1 dB of the known-channel theory."""
    a = [2e-5, 1.4e-5 * np.exp(2.0j)]
    tau, fd = [60e-9, 510e-9], [2100.0, 2400.0]
    mc = c.monte_carlo(a, tau, fd, WF, [8.0, 12.0], modulation="qpsk", frames=3, seed=2,
                       timing_offset_s=4e-6, cfo_hz=1500.0)
    for row in mc.rows:
        s, ber = row[0], row[1]
        be, nb = row[4], row[5]
        kc_ser, kc_ber = c.channel_error_rates(
            "qpsk", [s, s - 1.0],
            c.known_channel(a, tau, fd, WF, c.Sync(0, 0.0, 0, 0)))
        assert row[13] == 0  # every frame found
        assert ber <= kc_ber[1], (s, ber, kc_ber)
        assert be >= nb * kc_ber[0] - 4 * math.sqrt(nb * kc_ber[0]) - 1  # no better than CSI
        assert row[14] < 0.01 * WF.subcarrier_spacing_hz


def test_bad_input_is_refused_by_name():
    with pytest.raises(ArgumentError, match="timing_offset_s"):
        c.received_signal(np.ones((N, M)), [1.0], [1e-6], [0.0], WF, timing_offset_s=30e-6)
    with pytest.raises(ArgumentError, match="channel_power_gain"):
        c.snr_noise_variance(0.0, 10.0)
    with pytest.raises(ArgumentError, match="frames"):
        c.monte_carlo([1.0], [0.0], [0.0], WF, [5.0], frames=0)


# ----------------------------------------------------------------------------------------
# the command-line tool
# ----------------------------------------------------------------------------------------
def _tool():
    from tool_helpers import load_tool

    return load_tool("comms")


def test_tool_on_a_snapshot_writes_csv_and_picture(tmp_path, capsys):
    from clradcom.snapshot import Link, Snapshot, save_snapshot

    snap = Snapshot("two_radars", 24e9, "", links=(
        Link("A", "D", 0, 1, los_paths([10 ** (-78 / 20), 10 ** (-86 / 20) * 1j],
                                       [115e-9, 160e-9], [2200.0, 2150.0])),
    ))
    save_snapshot(tmp_path / "snapshot.npz", snap)
    out = tmp_path / "out"
    rc = _tool().main(["--snapshot", str(tmp_path / "snapshot.npz"), "--out", str(out),
                       "--subcarriers", str(N), "--symbols", str(M), "--snr-db", "4,12",
                       "--modulation", "16qam", "-q"])
    text = capsys.readouterr().out
    assert rc == 0, text
    assert (out / "comms.png").stat().st_size > 10_000 and (out / "comms.svg").exists()
    lines = (out / "comms.csv").read_text().splitlines()
    assert tuple(lines[0].split(",")) == c.CSV_COLUMNS
    rows = [dict(zip(c.CSV_COLUMNS, ln.split(","), strict=True)) for ln in lines[1:]]
    link = 10 * math.log10(0.01 * mean_power([10 ** (-78 / 20), 10 ** (-86 / 20) * 1j],
                                             [115e-9, 160e-9], [2200.0, 2150.0])
                           / (1.380649e-23 * 290 * WF.bandwidth * 10.0))
    assert [float(r["esn0_db"]) for r in rows] == pytest.approx(sorted([4.0, 12.0, link]),
                                                                 abs=0.01)
    low = rows[0]
    assert float(low["ber"]) > 0.05 and int(low["timing_errors"]) == 0
    assert "the link's own SNR" in text


def test_tool_refuses_unclear_input(tmp_path, capsys):
    tool = _tool()
    with pytest.raises(SystemExit):
        tool.main(["--out", str(tmp_path)])
    assert "exactly one" in capsys.readouterr().err
    rc = tool.main(["--snapshot", str(tmp_path / "missing.npz"), "--out", str(tmp_path)])
    assert rc == 2 and "missing.npz" in capsys.readouterr().err


def test_tool_traces_a_small_two_car_scene(tmp_path, capsys, runtime):
    """A and D over a road: the traced A->D link (line of sight and road bounce) decoded."""
    scene = tmp_path / "two.toml"
    scene.write_text("""
[scene]
name = "two_radars"
carrier_hz = 24e9

[[materials]]
name = "road"
base = "concrete_road"
roughness_m = 0.0

[[objects]]
name = "ground"
material = "road"
shape = "plane"
size = [100.0, 20.0]
position = [17.3, 0.0, 0.0]

[[radars]]
name = "A"
position = [0.0, -1.75, 0.5]
velocity = [12.9, 0.0, 0.0]
tx_power_w = 0.01
noise_figure_db = 10.0

[[radars]]
name = "D"
position = [34.6, 1.75, 0.5]
velocity = [-14.5, 0.0, 0.0]
orientation_deg = [0.0, 0.0, 180.0]
tx_power_w = 0.01
noise_figure_db = 10.0
""")
    out = tmp_path / "out"
    rc = _tool().main([str(scene), "--out", str(out), "--rays", "20000", "--preset", "go",
                       "--subcarriers", str(N), "--symbols", str(M), "--snr-db", "6", "-q"])
    text = capsys.readouterr().out
    assert rc == 0, text
    assert (out / "snapshot.npz").exists() and (out / "comms.csv").exists()
    from clradcom.snapshot import load_snapshot

    p = load_snapshot(out / "snapshot.npz").link("A", "D").paths
    link = 10 * math.log10(0.01 * mean_power(p.gain, p.delay_s, p.doppler_hz)
                           / (1.380649e-23 * 290 * WF.bandwidth * 10.0))
    rows = [ln.split(",") for ln in (out / "comms.csv").read_text().splitlines()[1:]]
    assert len(rows) == 2
    own = [r for r in rows if abs(float(r[0]) - link) < 0.01]
    assert len(own) == 1
    # the line of sight and the road bounce arrive 14 ps apart: a flat channel (their sum
    # is its power), so the link decodes as AWGN at its SNR does, within 1 dB
    s, be, nb = float(own[0][0]), int(own[0][4]), int(own[0][5])
    assert be <= nb * c.awgn_error_rates("qpsk", s - 1.0)[1] + 3
