"""Received-signal synthesis: exact time domain vs brute force, fast model, ICI, ISI, noise."""

import numpy as np
import pytest
from dsp_helpers import brute_force_rx, dirichlet, small_waveform
from hypothesis import assume, example, given, settings
from hypothesis import strategies as st

from clradcom.radar import (
    Waveform,
    add_thermal_noise,
    channel_transfer_function,
    ofdm_demodulate,
    random_symbols,
    spectral_estimate,
    synthesize_frequency_domain,
    synthesize_time_domain,
    thermal_noise_power,
)

# these tests place targets beyond the cyclic prefix, r_max and v_max on purpose (the
# synthesis models ISI and wrapping there); the PhysicsWarnings that say so are expected
pytestmark = pytest.mark.filterwarnings("ignore::clradcom.errors.PhysicsWarning")


def _paths(rng, k, max_delay, max_eps, wf):
    a = rng.standard_normal(k) + 1j * rng.standard_normal(k)
    tau = rng.uniform(0, max_delay, k)
    fd = rng.uniform(-max_eps, max_eps, k) * wf.subcarrier_spacing_hz
    return a, tau, fd


def _rel_err_db(x, ref):
    return 10 * np.log10(np.sum(np.abs(x - ref) ** 2) / np.sum(np.abs(ref) ** 2))


def test_time_domain_matches_brute_force_with_isi_and_ici():
    wf = small_waveform()
    d = random_symbols(wf, 1)
    a, tau, fd = _paths(np.random.default_rng(0), 7, 2.5 * wf.symbol_duration, 0.45, wf)
    y = synthesize_time_domain(d, a, tau, fd, wf)
    ref = brute_force_rx(d, a, tau, fd, wf)
    assert np.max(np.abs(y - ref)) < 1e-8 * np.max(np.abs(ref))


@settings(deadline=None, max_examples=25)
@given(delay_samples=st.floats(0, 200), eps=st.floats(-0.6, 0.6), seed=st.integers(0, 99))
@example(delay_samples=13.0, eps=0.0, seed=0)  # 13 / f_s * f_s = 13.000000000000002
def test_time_domain_single_path_property(delay_samples, eps, seed):
    # Delays within 1e-9 samples of a sample instant are snapped onto it by design.
    assume(delay_samples == round(delay_samples)
           or abs(delay_samples - round(delay_samples)) > 1e-6)
    wf = small_waveform(n=32, m=6)
    d = random_symbols(wf, seed)
    tau, fd = delay_samples / wf.sample_rate, eps * wf.subcarrier_spacing_hz
    y = synthesize_time_domain(d, [0.5 - 0.3j], [tau], [fd], wf)
    ref = brute_force_rx(d, [0.5 - 0.3j], [tau], [fd], wf)
    assert np.max(np.abs(y - ref)) < 1e-8


def test_fast_methods_agree():
    wf = small_waveform(n=128, m=32)
    a, tau, fd = _paths(np.random.default_rng(1), 40, 3e-6, 0.2, wf)
    ref = channel_transfer_function(a, tau, fd, wf, method="direct", time_origin_s=1e-6)
    for method in ("nufft", "matmul"):
        h = channel_transfer_function(a, tau, fd, wf, method=method, time_origin_s=1e-6)
        assert _rel_err_db(h, ref) < -150


def test_fast_model_is_paper_eq3():
    wf = small_waveform()
    d = random_symbols(wf, 2)
    n, mu = np.arange(wf.n_subcarriers)[:, None], np.arange(wf.n_symbols)[None, :]
    r, v = 40.0, -11.0
    tau, fd = 2 * r / 299_792_458.0, 2 * v / wf.wavelength
    expect = d * np.exp(-2j * np.pi * n * wf.subcarrier_spacing_hz * tau) * np.exp(
        2j * np.pi * fd * mu * wf.symbol_duration)
    got = synthesize_frequency_domain(d, [1.0], [tau], [fd], wf)
    assert np.max(np.abs(got - expect)) < 1e-9


def test_methods_agree_without_ici_isi_paper_frame():
    """Zero Doppler, every delay inside the CP: exact synthesis == eq. (3) to −60 dB."""
    wf = Waveform()
    d = random_symbols(wf, 3)
    a, tau, _ = _paths(np.random.default_rng(2), 30, wf.cp_duration, 0, wf)
    dr_exact = ofdm_demodulate(synthesize_time_domain(d, a, tau, np.zeros(30), wf), wf)
    dr_fast = synthesize_frequency_domain(d, a, tau, np.zeros(30), wf)
    assert _rel_err_db(dr_fast, dr_exact) < -60


def test_methods_differ_by_closed_form_ici_with_doppler():
    """With Doppler and t0 at the FFT-window centre the methods differ only by the
    Dirichlet gain P_N(ε) and the ICI power 1 − |P_N(ε)|² (docs/dsp.md §3)."""
    wf = small_waveform(n=256, m=32)
    d = random_symbols(wf, 4)
    eps = 0.05
    fd = eps * wf.subcarrier_spacing_hz
    dr = ofdm_demodulate(synthesize_time_domain(d, [1.0], [1e-7], [fd], wf), wf)
    fast = synthesize_frequency_domain(d, [1.0], [1e-7], [fd], wf,
                                       time_origin_s=wf.fft_window_centre)
    g = abs(dirichlet(eps, wf.n_subcarriers))
    diff_db = _rel_err_db(dr, g * fast)
    assert diff_db == pytest.approx(10 * np.log10(1 - g**2), abs=0.3)
    assert diff_db > -30  # a real difference, far above the −60 dB agreement


@pytest.mark.parametrize("eps", [0.02, 0.05, 0.1, 0.2, 0.44])
def test_ici_loss_and_floor_closed_form(eps):
    wf = small_waveform(n=256, m=64)
    d = random_symbols(wf, 5)
    fd = eps * wf.subcarrier_spacing_hz
    f = spectral_estimate(ofdm_demodulate(synthesize_time_domain(d, [1.0], [0.0], [fd], wf),
                                          wf), d)
    h = channel_transfer_function([1.0], [0.0], [fd], wf, time_origin_s=wf.fft_window_centre)
    coherent = np.mean(f / h)
    residual = np.mean(np.abs(f - coherent * h) ** 2)
    pn = dirichlet(eps, wf.n_subcarriers)
    # Random data makes the ICI a zero-mean disturbance of the estimate: allow 5 σ of it.
    sigma = np.sqrt(residual / f.size) / abs(coherent)
    # Peak loss sinc²(ε) (exactly |P_N(ε)|², N finite), in phase as the window centre says.
    assert 20 * np.log10(abs(coherent)) == pytest.approx(20 * np.log10(np.sinc(eps)),
                                                         abs=0.005 + 8.7 * 5 * sigma)
    assert abs(np.angle(coherent)) < 5 * sigma
    # ICI power 1 − |P_N|²: floor of the image NM·|P_N|²/(1 − |P_N|²), ≈ NM·3/(πε)².
    nm = wf.n_subcarriers * wf.n_symbols
    floor_db = 10 * np.log10(nm * abs(coherent) ** 2 / residual)
    assert floor_db == pytest.approx(10 * np.log10(nm * abs(pn) ** 2 / (1 - abs(pn) ** 2)),
                                     abs=0.2)
    if eps <= 0.1:  # the small-ε form drifts by ~0.4 dB at ε = 0.2 (reference §1)
        assert floor_db == pytest.approx(10 * np.log10(nm * 3 / (np.pi * eps) ** 2), abs=0.3)


@pytest.mark.parametrize("frac_beyond", [0.05, 0.2, 0.5])
def test_isi_loss_and_floor_closed_form(frac_beyond):
    """Delay T_CP + x·T: useful fraction f = 1 − x, peak loss 20log10 f, floor NM f²/(1−f²)."""
    wf = small_waveform(n=256, m=64)
    d = random_symbols(wf, 6)
    tau = wf.cp_duration + frac_beyond * wf.useful_duration
    f = spectral_estimate(ofdm_demodulate(synthesize_time_domain(d, [1.0], [tau], [0.0], wf),
                                          wf), d)
    h = channel_transfer_function([1.0], [tau], [0.0], wf)
    cells = slice(1, None)  # symbol 0 has no predecessor, so no ISI from it
    ratio = f[:, cells] / h[:, cells]
    coherent = np.mean(ratio)
    residual = np.mean(np.abs(f[:, cells] - coherent * h[:, cells]) ** 2)
    useful = 1 - frac_beyond
    assert 20 * np.log10(abs(coherent)) == pytest.approx(20 * np.log10(useful), abs=0.05)
    nm = wf.n_subcarriers * wf.n_symbols
    floor_db = 10 * np.log10(nm * abs(coherent) ** 2 / residual)
    assert floor_db == pytest.approx(10 * np.log10(nm * useful**2 / (1 - useful**2)), abs=0.3)


def test_isi_free_inside_cyclic_prefix():
    wf = small_waveform(n=128, m=8)
    d = random_symbols(wf, 7)
    tau = 0.999 * wf.cp_duration
    dr = ofdm_demodulate(synthesize_time_domain(d, [1.0], [tau], [0.0], wf), wf)
    assert _rel_err_db(dr, synthesize_frequency_domain(d, [1.0], [tau], [0.0], wf)) < -150


def test_thermal_noise_scaling():
    wf = small_waveform(n=256, m=64)
    p_tx, nf = 0.01, 8.0
    kt = 1.380649e-23 * 290.0
    expect = kt * wf.bandwidth * 10 ** 0.8 / p_tx
    assert thermal_noise_power(wf.bandwidth, nf) == pytest.approx(kt * wf.bandwidth * 10**0.8)
    z = add_thermal_noise(np.zeros((256, 64), complex), p_tx, nf, wf.bandwidth, rng=1)
    assert np.mean(np.abs(z) ** 2) == pytest.approx(expect, rel=0.03)
    assert np.mean(z.real**2) == pytest.approx(expect / 2, rel=0.04)  # circular


@pytest.mark.parametrize(
    "gains, delays, dopplers, match",
    [
        ([1, 1], [0.0], [0.0, 0.0], "same length"),
        ([1], [np.nan], [0.0], "delays_s"),
        ([1], [1e-7], [np.inf], "dopplers_hz"),
        ([np.nan], [1e-7], [0.0], "gains"),
        ([1], [-1e-9], [0.0], "negative"),
        ([[1]], [[1e-7]], [[0.0]], "1-D"),
    ],
)
def test_bad_paths_refused(gains, delays, dopplers, match):
    wf = small_waveform()
    d = random_symbols(wf, 0)
    for fn in (synthesize_time_domain, synthesize_frequency_domain):
        with pytest.raises(ValueError, match=match):
            fn(d, gains, delays, dopplers, wf)


def test_no_paths_gives_silence():
    wf = small_waveform()
    d = random_symbols(wf, 0)
    assert not synthesize_time_domain(d, [], [], [], wf).any()
    assert not synthesize_frequency_domain(d, [], [], [], wf).any()
