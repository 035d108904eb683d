"""Radar processing: bins, interpolation, resolution, ambiguities, windows, CRB."""

import numpy as np
import pytest
from dsp_helpers import small_waveform

from clradcom.radar import (
    Waveform,
    add_noise,
    detect,
    get_window,
    interpolate_peaks,
    ofdm_demodulate,
    radar_image,
    random_symbols,
    spectral_estimate,
    synthesize_frequency_domain,
    synthesize_time_domain,
)

# these tests place targets beyond the cyclic prefix, r_max and v_max on purpose (the
# synthesis models ISI and wrapping there); the PhysicsWarnings that say so are expected
pytestmark = pytest.mark.filterwarnings("ignore::clradcom.errors.PhysicsWarning")

C = 299_792_458.0


def _image(wf, a, r, v, seed=0, noise_var=0.0, **kw):
    d = random_symbols(wf, seed)
    dr = synthesize_frequency_domain(d, a, wf.range_to_delay(r), wf.velocity_to_doppler(v), wf)
    if noise_var:
        dr = add_noise(dr, noise_var, rng=seed + 1)
    return radar_image(spectral_estimate(dr, d), wf, **kw)


def _peak(img):
    i, j = np.unravel_index(np.argmax(img.power), img.power.shape)
    return i, j


def test_on_grid_target_lands_in_exact_bin():
    wf = Waveform()
    for p, q in [(10, -7), (300, 100), (0, 0), (1023, -128)]:
        r, v = p * wf.range_resolution, q * wf.velocity_resolution
        # Hann, not rect: rect's on-grid neighbours are exact nulls (numerical noise in dB).
        img = _image(wf, [1.0], [r], [v], window_range="hann", window_doppler="hann")
        i, j = _peak(img)
        assert (i, j) == (p, q + wf.n_symbols // 2)
        assert img.range_m[i] == pytest.approx(r, abs=1e-9)
        assert img.velocity_mps[j] == pytest.approx(v, abs=1e-9)
        rf, cf, _ = interpolate_peaks(img.power, [i], [j])
        assert abs(rf[0] - i) < 1e-6 and abs(cf[0] - j) < 1e-6


def test_off_grid_within_002_cell_exact_synthesis():
    """Paper frame, exact time-domain synthesis (with ICI), ×2 zero padding, Hann."""
    wf = Waveform()
    rng = np.random.default_rng(11)
    r = np.array([16.1, 25.2, 34.4, 61.7]) + rng.uniform(0, 1, 4) * wf.range_resolution
    v = np.array([25.7, 0.3, -27.4, 12.9]) + rng.uniform(0, 1, 4) * wf.velocity_resolution
    a = np.exp(2j * np.pi * rng.uniform(size=4)) * np.array([1.0, 0.8, 0.6, 0.5])
    d = random_symbols(wf, 5)
    y = synthesize_time_domain(d, a, wf.range_to_delay(r), wf.velocity_to_doppler(v), wf)
    img = radar_image(spectral_estimate(ofdm_demodulate(y, wf), d), wf,
                      zero_pad_range=2, zero_pad_doppler=2)
    det = detect(img, guard=(4, 4), train=(4, 4), p_fa=1e-6, max_detections=4)
    assert det.size == 4
    for rk, vk in zip(r, v, strict=True):
        k = np.argmin(np.abs(det["range_m"] - rk) + np.abs(det["velocity_mps"] - vk))
        assert abs(det["range_m"][k] - rk) < 0.02 * wf.range_resolution
        assert abs(det["velocity_mps"][k] - vk) < 0.02 * wf.velocity_resolution


@pytest.mark.parametrize("window, width", [("rect", 2), ("hann", 4), ("hamming", 4)])
@pytest.mark.parametrize("axis", ["range", "velocity"])
def test_two_targets_one_mainlobe_apart_resolved(window, width, axis):
    """Equal targets separated by the null-to-null mainlobe width, any relative phase."""
    wf = small_waveform(n=128, m=64)
    zp = 4
    for phase in (0.0, np.pi / 2, np.pi, 4.0):
        r0, v0 = 20.37 * wf.range_resolution, 5.41 * wf.velocity_resolution
        if axis == "range":
            r = [r0, r0 + width * wf.range_resolution]
            v = [v0, v0]
        else:
            r = [r0, r0]
            v = [v0, v0 + width * wf.velocity_resolution]
        img = _image(wf, [1.0, np.exp(1j * phase)], r, v, noise_var=1e-4,
                     window_range=window, window_doppler=window,
                     zero_pad_range=zp, zero_pad_doppler=zp)
        det = detect(img, guard=(3 * zp, 3 * zp), train=(4, 4), p_fa=1e-4)
        main = det[det["power_db"] > det["power_db"].max() - 10]
        assert main.size == 2, (phase, main)
        got = np.sort(main["range_m"] if axis == "range" else main["velocity_mps"])
        cell = wf.range_resolution if axis == "range" else wf.velocity_resolution
        np.testing.assert_allclose(got, np.sort(r if axis == "range" else v), atol=0.3 * cell)


def test_range_and_velocity_wrap_as_formulas_say():
    wf = small_waveform(n=128, m=32)
    rmax, vmax = wf.max_range, wf.max_velocity
    cases = [(rmax + 5 * wf.range_resolution, 3 * wf.velocity_resolution),
             (2 * rmax + 17 * wf.range_resolution, 2 * vmax + 4 * wf.velocity_resolution),
             (9 * wf.range_resolution, -(vmax + 6 * wf.velocity_resolution)),
             (30 * wf.range_resolution, vmax + 2 * wf.velocity_resolution)]
    for r, v in cases:
        img = _image(wf, [1.0], [r], [v], window_range="rect", window_doppler="rect")
        i, j = _peak(img)
        assert img.range_m[i] == pytest.approx(np.mod(r, rmax), abs=1e-6)
        assert img.velocity_mps[j] == pytest.approx(np.mod(v + vmax, 2 * vmax) - vmax, abs=1e-6)


def _window_loss_and_psl(name, n=1024, m=16, zp=16):
    wf = Waveform(n_subcarriers=n, n_symbols=m)
    rng = np.random.default_rng(3)
    floor = np.mean([
        np.mean(radar_image(add_noise(np.zeros((n, m), complex), 1.0, rng), wf,
                            window_range=name, window_doppler="rect").power)
        for _ in range(6)
    ])
    r = 100 * wf.range_resolution
    img = _image(wf, [1.0], [r], [0.0], window_range=name, window_doppler="rect")
    loss_db = 10 * np.log10(n * m) - 10 * np.log10(img.power.max() / floor)
    prof = _image(wf, [1.0], [r], [0.0], window_range=name, window_doppler="rect",
                  zero_pad_range=zp).power[:, m // 2]
    k = int(np.argmax(prof))
    lo = k
    while prof[lo - 1] < prof[lo]:
        lo -= 1
    hi = k
    while prof[hi + 1] < prof[hi]:
        hi += 1
    side = np.concatenate([prof[:lo], prof[hi + 1:]])
    return loss_db, 10 * np.log10(side.max() / prof[k])


@pytest.mark.parametrize("name, loss, psl", [("hann", 1.76, -31.5), ("hamming", 1.34, -42.7),
                                             ("rect", 0.0, -13.3),
                                             ("blackmanharris", 3.02, -92.0)])
def test_window_snr_loss_and_peak_sidelobe(name, loss, psl):
    """Reference §1 window table (Harris 1978; Richards Table 5.2)."""
    got_loss, got_psl = _window_loss_and_psl(name)
    assert got_loss == pytest.approx(loss, abs=0.06)
    assert got_psl == pytest.approx(psl, abs=0.25)


def test_windows_accept_parameters():
    assert get_window(("taylor", 5, 40), 64).shape == (64,)
    assert get_window(("chebwin", 80), 64).shape == (64,)
    with pytest.raises(ValueError, match="unknown window"):
        get_window("gauss-ish", 64)
    wf = small_waveform()
    with pytest.raises(ValueError, match="zero_pad_range"):
        radar_image(np.ones((64, 16)), wf, zero_pad_range=0)


def _crb(wf, snr):
    n, m = wf.n_subcarriers, wf.n_symbols
    var_r = 6 * C**2 / ((4 * np.pi * wf.subcarrier_spacing_hz) ** 2 * snr * n * m * (n**2 - 1))
    var_v = 6 * C**2 / ((4 * np.pi * wf.carrier_hz * wf.symbol_duration) ** 2 * snr * n * m
                        * (m**2 - 1))
    return var_r, var_v


def _mc_errors(wf, snr_db, trials, seed):
    rng = np.random.default_rng(seed)
    d = random_symbols(wf, seed)
    err = np.empty((trials, 2))
    for t in range(trials):
        r = (20 + rng.uniform()) * wf.range_resolution
        v = (3 + rng.uniform()) * wf.velocity_resolution
        a = np.exp(2j * np.pi * rng.uniform())
        dr = synthesize_frequency_domain(d, [a], wf.range_to_delay([r]),
                                         wf.velocity_to_doppler([v]), wf)
        dr = add_noise(dr, 10 ** (-snr_db / 10), rng)
        img = radar_image(spectral_estimate(dr, d), wf, window_range="rect",
                          window_doppler="rect", zero_pad_range=4, zero_pad_doppler=4)
        i, j = _peak(img)
        rf, cf, _ = interpolate_peaks(img.power, [i], [j])
        err[t] = (rf[0] * (img.range_m[1] - img.range_m[0]) - r,
                  img.velocity_mps[0] + cf[0] * (img.velocity_mps[1] - img.velocity_mps[0]) - v)
    return np.mean(err**2, axis=0)


@pytest.mark.parametrize("snr_db", [0.0, -6.0])
def test_rmse_reaches_cramer_rao_bound_above_threshold(snr_db):
    """Periodogram ML (rect, ×4 padding, parabolic on dB) vs Rife–Boorstyn 2-D CRB."""
    wf = small_waveform(n=64, m=16)
    mse_r, mse_v = _mc_errors(wf, snr_db, 250, seed=int(-snr_db) + 1)
    var_r, var_v = _crb(wf, 10 ** (snr_db / 10))
    assert -0.7 < 10 * np.log10(mse_r / var_r) < 1.0
    assert -0.7 < 10 * np.log10(mse_v / var_v) < 1.0


def test_rmse_breaks_away_from_bound_below_threshold():
    wf = small_waveform(n=64, m=16)
    mse_r, _ = _mc_errors(wf, -24.0, 60, seed=9)
    var_r, _ = _crb(wf, 10 ** (-2.4))
    assert 10 * np.log10(mse_r / var_r) > 3.0
