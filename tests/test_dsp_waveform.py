"""Waveform parameters, derived radar figures (paper Table I), symbols and CP-OFDM."""

import numpy as np
import pytest
from dsp_helpers import brute_force_rx, small_waveform
from hypothesis import given, settings
from hypothesis import strategies as st

from clradcom.radar import Waveform, constellation, ofdm_demodulate, ofdm_modulate, random_symbols

C = 299_792_458.0


def test_table_one_figures_from_formulas():
    wf = Waveform()
    n, df, fc, m = 1024, 90.909e3, 24e9, 256
    fs = n * df
    t_sym = (n + round(1.375e-6 * fs)) / fs
    assert wf.n_cp == 128
    assert wf.symbol_duration == pytest.approx(t_sym, rel=1e-12)
    assert wf.bandwidth == pytest.approx(fs)
    assert wf.range_resolution == pytest.approx(C / (2 * n * df), rel=1e-12)
    assert wf.max_range == pytest.approx(C / (2 * df), rel=1e-12)
    assert wf.isi_free_range == pytest.approx(C * (128 / fs) / 2, rel=1e-12)
    assert wf.max_velocity == pytest.approx(C / (4 * fc * t_sym), rel=1e-12)
    assert wf.velocity_resolution == pytest.approx(C / (2 * fc * m * t_sym), rel=1e-12)
    # The paper's rounded Table I values (it used c = 3e8).
    assert wf.useful_duration == pytest.approx(11e-6, rel=1e-5)
    assert wf.symbol_duration == pytest.approx(12.375e-6, rel=1e-5)
    assert wf.bandwidth / 1e6 == pytest.approx(93.1, abs=0.05)
    assert wf.range_resolution == pytest.approx(1.61, abs=0.005)
    assert wf.max_range == pytest.approx(1650, rel=2e-3)
    assert wf.isi_free_range == pytest.approx(206, abs=0.5)
    assert wf.max_velocity == pytest.approx(252.5, rel=2e-3)
    assert wf.velocity_resolution == pytest.approx(1.97, abs=0.005)


def test_given_useful_duration_accepted_when_consistent():
    wf = Waveform(useful_duration_s=11e-6)
    assert wf.symbol_duration == pytest.approx(Waveform().symbol_duration)


@pytest.mark.parametrize(
    "kwargs, name",
    [
        ({"useful_duration_s": 10e-6}, "useful_duration_s"),
        ({"n_subcarriers": 0}, "n_subcarriers"),
        ({"n_subcarriers": -4}, "n_subcarriers"),
        ({"n_subcarriers": 64.0}, "n_subcarriers"),
        ({"n_symbols": 0}, "n_symbols"),
        ({"subcarrier_spacing_hz": float("nan")}, "subcarrier_spacing_hz"),
        ({"subcarrier_spacing_hz": -1.0}, "subcarrier_spacing_hz"),
        ({"cp_s": 1e-6}, "cp_s"),
        ({"cp_s": -1e-6}, "cp_s"),
        ({"carrier_hz": 0.0}, "carrier_hz"),
        ({"modulation": "ofdm"}, "modulation"),
    ],
)
def test_inconsistent_waveform_refused(kwargs, name):
    with pytest.raises(ValueError, match=name):
        Waveform(**kwargs)


@pytest.mark.parametrize("mod, size", [("bpsk", 2), ("qpsk", 4), ("8psk", 8), ("16qam", 16),
                                       ("64qam", 64), ("256qam", 256)])
def test_constellations_unit_power(mod, size):
    pts = constellation(mod)
    assert np.unique(np.round(pts, 12)).size == size
    assert np.mean(np.abs(pts) ** 2) == pytest.approx(1.0, rel=1e-12)


def test_random_symbols_reproducible_and_from_constellation():
    wf = small_waveform(modulation="16qam")
    a, b = random_symbols(wf, 7), random_symbols(wf, 7)
    assert a.shape == (64, 16)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, random_symbols(wf, 8))
    pts = constellation("16qam")
    assert np.min(np.abs(a.ravel()[:, None] - pts[None, :]), axis=1).max() < 1e-12


def test_modulated_frame_is_eq1_with_cyclic_prefix():
    wf = small_waveform()
    d = random_symbols(wf, 1)
    x = ofdm_modulate(d, wf)
    assert x.shape == (wf.n_symbols * (wf.n_subcarriers + wf.n_cp),)
    # Direct evaluation of eq. (1) at the sample instants, independent of the IFFT.
    np.testing.assert_allclose(x, brute_force_rx(d, [1.0], [0.0], [0.0], wf), atol=1e-12)
    frames = x.reshape(wf.n_symbols, -1)
    np.testing.assert_array_equal(frames[:, : wf.n_cp], frames[:, -wf.n_cp:])
    # Unitary scaling: the useful part of each symbol carries mean |D|² = 1 (Parseval).
    assert np.mean(np.abs(frames[:, wf.n_cp:]) ** 2) == pytest.approx(1.0, rel=1e-12)


@settings(deadline=None, max_examples=20)
@given(n=st.sampled_from([8, 16, 64]), m=st.integers(1, 6), seed=st.integers(0, 1000))
def test_demodulate_inverts_modulate(n, m, seed):
    wf = Waveform(n_subcarriers=n, n_symbols=m, subcarrier_spacing_hz=1e6, cp_s=n / 8 / (n * 1e6))
    d = random_symbols(wf, seed)
    np.testing.assert_allclose(ofdm_demodulate(ofdm_modulate(d, wf), wf), d, atol=1e-12)


def test_modulate_demodulate_refuse_bad_shapes():
    wf = small_waveform()
    with pytest.raises(ValueError, match="symbols"):
        ofdm_modulate(np.ones((wf.n_subcarriers + 1, wf.n_symbols)), wf)
    with pytest.raises(ValueError, match="rx: has"):
        ofdm_demodulate(np.ones(10), wf)
    with pytest.raises(ValueError, match="NaN"):
        ofdm_modulate(np.full((wf.n_subcarriers, wf.n_symbols), np.nan), wf)
