"""CFAR: α formulas, false-alarm rate on noise, detection table on a Table III-like scene."""

import numpy as np
import pytest
from dsp_helpers import small_waveform

from clradcom.radar import (
    DETECTION_DTYPE,
    Waveform,
    add_noise,
    ca_cfar_alpha,
    cfar_false_alarms,
    cfar_threshold,
    detect,
    ofdm_demodulate,
    os_cfar_alpha,
    os_cfar_pfa,
    radar_image,
    random_symbols,
    spectral_estimate,
    synthesize_time_domain,
    training_footprint,
)


def test_ca_alpha_reference_example():
    # Reference §1: N_T = 16, P_fa = 1e-6 -> α ≈ 21.9 (13.4 dB).
    alpha = ca_cfar_alpha(16, 1e-6)
    assert alpha == pytest.approx(21.9, abs=0.05)
    assert 10 * np.log10(alpha) == pytest.approx(13.4, abs=0.05)


def test_ca_alpha_matches_exponential_tail_probability():
    # P_fa = E[exp(−αS/N_T)] with S ~ Gamma(N_T, 1): (1 + α/N_T)^(−N_T).
    for n_t, p in [(8, 1e-3), (144, 1e-6), (40, 0.05)]:
        alpha = ca_cfar_alpha(n_t, p)
        assert (1 + alpha / n_t) ** (-n_t) == pytest.approx(p, rel=1e-9)


def test_os_alpha_solves_rohling():
    for n_t, k, p in [(24, 18, 1e-6), (144, 108, 1e-3), (16, 12, 1e-4)]:
        alpha = os_cfar_alpha(n_t, k, p)
        # Independent evaluation of Rohling's product with the Gamma-function form:
        # P_fa = Γ(N+1)Γ(N−k+1+α) / (Γ(N−k+1)Γ(N+1+α)).
        from scipy.special import gammaln
        lp = (gammaln(n_t + 1) + gammaln(n_t - k + 1 + alpha) - gammaln(n_t - k + 1)
              - gammaln(n_t + 1 + alpha))
        assert np.exp(lp) == pytest.approx(p, rel=1e-8)
        assert os_cfar_pfa(n_t, k, alpha) == pytest.approx(p, rel=1e-8)


def test_footprint_counts():
    fp = training_footprint((2, 1), (4, 3))
    assert fp.shape == (13, 9)
    assert fp.sum() == 13 * 9 - 5 * 3


@pytest.mark.parametrize("method", ["ca", "os"])
@pytest.mark.parametrize("p_fa", [1e-2, 1e-3])
def test_false_alarm_rate_on_noise_within_factor_two(method, p_fa):
    """Noise-only image (rect windows, no padding: independent exponential cells)."""
    wf = small_waveform(n=256, m=64)
    d = random_symbols(wf, 0)
    rng = np.random.default_rng(42)
    alarms, cells = 0, 0
    for _ in range(4):
        f = spectral_estimate(add_noise(np.zeros(d.shape, complex), 1.0, rng), d)
        img = radar_image(f, wf, window_range="rect", window_doppler="rect")
        alarms += cfar_false_alarms(img.power, (2, 2), (4, 4), p_fa, method)
        cells += img.power.size
    rate = alarms / cells
    assert p_fa / 2 < rate < 2 * p_fa


def test_cfar_refuses_bad_input():
    with pytest.raises(ValueError, match="p_fa"):
        ca_cfar_alpha(16, 0.0)
    with pytest.raises(ValueError, match="rank"):
        os_cfar_alpha(16, 17, 1e-3)
    with pytest.raises(ValueError, match="square-law"):
        cfar_threshold(-np.ones((32, 32)))
    with pytest.raises(ValueError, match="method"):
        cfar_threshold(np.ones((32, 32)), method="go")
    with pytest.raises(ValueError, match="larger than the map"):
        cfar_threshold(np.ones((5, 5)))


def test_table_three_scene_detected():
    """The paper's Table III simulated values as point targets on the paper's frame:
    exact synthesis, thermal-level noise, Hann windows, OS-CFAR; the table rows come back
    within a tenth of a resolution cell, with SNR consistent with NM·SNR_cell − window loss."""
    wf = Waveform()
    rows = [(16.1, 25.7), (25.2, 0.0), (34.4, 27.4)]  # B, C, D: R [m], v_rel [m/s]
    r = np.array([x[0] for x in rows])
    v = np.array([x[1] for x in rows])
    amp = 1e-3
    a = amp * np.exp(1j * np.array([0.3, 2.0, -1.1]))
    d = random_symbols(wf, 8)
    y = synthesize_time_domain(d, a, wf.range_to_delay(r), wf.velocity_to_doppler(v), wf)
    snr_cell_db = -20.0
    y = add_noise(y, amp**2 * 10 ** (-snr_cell_db / 10), rng=8)
    img = radar_image(spectral_estimate(ofdm_demodulate(y, wf), d), wf)
    det = detect(img, guard=(2, 2), train=(4, 4), p_fa=1e-6, method="os")
    assert det.dtype == DETECTION_DTYPE
    top = det[:3]
    expect_snr = snr_cell_db + 10 * np.log10(wf.n_subcarriers * wf.n_symbols) - 2 * 1.76
    for rk, vk in rows:
        k = np.argmin(np.abs(top["range_m"] - rk) + np.abs(top["velocity_mps"] - vk))
        assert abs(top["range_m"][k] - rk) < 0.1 * wf.range_resolution
        assert abs(top["velocity_mps"][k] - vk) < 0.1 * wf.velocity_resolution
        # Straddle (≤ 1.4 dB/axis for Hann) lowers the peak; the OS noise estimate from
        # Hann-correlated cells scatters by about ±1.5 dB.
        assert expect_snr - 4.5 < top["snr_db"][k] < expect_snr + 2.5
    # Nothing else survives at this P_fa: no false targets.
    assert det.size <= 4
