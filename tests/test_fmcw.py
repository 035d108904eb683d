"""The FMCW chirp-sequence radar (clradcom.radar.fmcw) against closed forms: the beat
frequency S·2R/c − f_D, the phase across chirps 4πR(t)/λ, the fast synthesis against the
exact one (range migration included), the residual phase noise's range correlation
2(1 − cos 2πfτ)·S_φ(f), range and velocity at the Cramér-Rao bound through the OFDM
chain's CFAR and refinement, and the waveform's refusals."""

import warnings

import numpy as np
import pytest
from dsp_helpers import los_paths
from scipy.optimize import minimize_scalar

from clradcom.errors import AliasingWarning, ArgumentError
from clradcom.radar.angle_estimation import angle_cramer_rao_bound
from clradcom.radar.cube import detect_cube, radar_cube, refine_detections, tdm_channels
from clradcom.radar.fmcw import (
    FmcwWaveform,
    beat_frequencies,
    correct_coupling,
    fmcw_cramer_rao_bound,
    fmcw_frame,
    if_response,
    phase_noise_psd,
    residual_phase_noise,
    synthesize_beat,
    synthesize_beat_exact,
)
from clradcom.radar.mimo import tdm_range_doppler, virtual_positions
from clradcom.radar.pipeline import find_targets, fmcw_process, radar_chain

C = 299_792_458.0


def _small(**kw) -> FmcwWaveform:
    base = dict(samples_per_chirp=64, n_chirps=16, adc_rate_hz=5e6, chirp_s=20e-6,
                idle_s=5e-6, adc_start_s=3e-6, sweep_bandwidth_hz=1e9)
    base.update(kw)
    return FmcwWaveform(**base)


def _target(wf, r, v):
    """delay and Doppler of a monostatic point target at range r, closing speed v."""
    return 2 * r / C, 2 * v * wf.traced_carrier_hz / C


# ----------------------------------------------------------------------------------------
# waveform
# ----------------------------------------------------------------------------------------
def test_derived_figures_follow_from_the_parameters():
    wf = FmcwWaveform()
    assert wf.slope == pytest.approx(1e9 / 40e-6)
    assert wf.range_resolution == pytest.approx(C / (2 * wf.slope * 256 / 10e6))
    assert wf.max_range == pytest.approx(C * 10e6 / (2 * wf.slope))
    assert FmcwWaveform(if_type="real").max_range == pytest.approx(wf.max_range / 2)
    assert wf.velocity_resolution == pytest.approx(C / wf.carrier_hz / (2 * 128 * 50e-6))
    # the chain's range axis: c/(2NΔf) with Δf = S/f_s
    assert C / (2 * wf.n_subcarriers * wf.subcarrier_spacing_hz) == pytest.approx(
        wf.range_resolution)


@pytest.mark.parametrize("kw, argument", [
    (dict(samples_per_chirp=512), "samples_per_chirp"),          # window past the chirp end
    (dict(adc_start_s=20e-6), "samples_per_chirp"),
    (dict(if_bandwidth_hz=11e6), "if_bandwidth_hz"),             # beyond complex Nyquist
    (dict(if_type="real", if_bandwidth_hz=6e6), "if_bandwidth_hz"),
    (dict(start_hz=78e9), "start_hz"),                           # sweep misses the carrier
    (dict(traced_carrier_hz=24e9), "start_hz"),
    (dict(if_type="iq"), "if_type"),
    (dict(n_chirps=0), "n_chirps"),
    (dict(idle_s=-1e-6), "idle_s"),
    (dict(chirp_s=float("nan")), "chirp_s"),
])
def test_contradictory_waveforms_are_refused_by_name(kw, argument):
    with pytest.raises(ArgumentError) as err:
        FmcwWaveform(**kw)
    assert err.value.argument == argument


def test_a_path_beyond_the_adc_band_is_announced():
    wf = _small()
    tau, fd = _target(wf, 1.2 * wf.max_range, 0.0)
    with pytest.warns(AliasingWarning, match="beat outside the ADC's band"):
        synthesize_beat([1.0], [tau], [fd], wf)
    tau, fd = _target(wf, 0.5 * wf.max_range, 0.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        synthesize_beat([1.0], [tau], [fd], wf)


def test_if_filter_is_3db_at_cutoff_and_rolls_off_with_its_order():
    wf = _small(if_bandwidth_hz=2e6, if_filter_order=4)
    h = if_response(wf, np.array([-2e6, -4e6, 0.0]))
    assert abs(h[0]) ** 2 == pytest.approx(0.5, rel=1e-9)
    assert 20 * np.log10(abs(h[1])) == pytest.approx(-10 * np.log10(1 + 2.0 ** 8), abs=1e-9)
    assert abs(h[2]) == pytest.approx(1.0)


# ----------------------------------------------------------------------------------------
# synthesis
# ----------------------------------------------------------------------------------------
def _random_paths(wf, k, v_max, seed=3):
    rng = np.random.default_rng(seed)
    r = rng.uniform(1.0, 0.4 * wf.max_range, k)
    v = rng.uniform(-v_max, v_max, k)
    a = (rng.standard_normal(k) + 1j * rng.standard_normal(k)) * 1e-3
    tau, fd = _target(wf, r, v)
    return a, tau, fd


@pytest.mark.parametrize("v_max", [0.0, 3.0, 19.0])
def test_fast_synthesis_matches_the_exact_one(v_max):
    """At 19 m/s the range migration over the frame (the t'·u term) is ~1 rad at the
    frame's corners: a separable (outer-product) model would miss it by that much."""
    wf = FmcwWaveform(n_chirps=64, samples_per_chirp=128, adc_start_s=1e-6)
    a, tau, fd = _random_paths(wf, 60, v_max)
    exact = synthesize_beat_exact(a, tau, fd, wf)
    fast = synthesize_beat(a, tau, fd, wf)
    assert np.abs(fast - exact).max() <= 1e-8 * np.abs(a).sum()


def test_range_migration_is_in_the_exact_frame():
    """A 19 m/s target's beat phase at the frame's corners departs from the separable
    (first-order) model by 2πSβ·x·y, the closed form of the range migration."""
    wf = FmcwWaveform(n_chirps=64, samples_per_chirp=128, adc_start_s=1e-6)
    tau, fd = _target(wf, 20.0, 19.0)
    s = synthesize_beat_exact([1.0], [tau], [fd], wf)
    ph = np.angle(s * np.conj(s[:1, :1]))
    # second differences of the phase over the corner samples: the cross term alone
    n, m = wf.samples_per_chirp - 1, wf.n_chirps - 1
    cross = ph[n, m] - ph[n, 0] - ph[0, m] + ph[0, 0]
    beta = fd / wf.traced_carrier_hz
    want = 2 * np.pi * wf.slope * beta * (1 + beta) * (n / wf.adc_rate_hz) * (
        m * wf.chirp_interval)
    assert np.angle(np.exp(1j * (cross - want))) == pytest.approx(0.0, abs=1e-6)
    assert abs(want) > 0.5


def test_echo_before_it_arrives_is_zero_in_the_exact_frame():
    wf = _small(adc_start_s=0.0, sweep_bandwidth_hz=1e8, traced_carrier_hz=77.05e9)
    tau, fd = _target(wf, 100.0, 0.0)
    s = synthesize_beat_exact([1.0], [tau], [fd], wf)
    first = int(np.ceil(tau * wf.adc_rate_hz))
    assert first == 4
    assert np.all(s[:first] == 0) and np.all(np.abs(s[first:]) > 0.5)
    with pytest.warns(AliasingWarning, match="arrive after the ADC window opens"):
        synthesize_beat([1.0], [tau], [fd], wf)


def _peak_frequency(x, fs):
    """Frequency (Hz) of the periodogram maximum of a 1-D tone, searched finely."""
    n = np.arange(x.size)
    spec = np.abs(np.fft.fft(x, 16 * x.size))
    f0 = np.fft.fftfreq(16 * x.size, 1 / fs)[np.argmax(spec)]

    def neg(f):
        return -abs(np.sum(x * np.exp(-2j * np.pi * f * n / fs)))

    return minimize_scalar(neg, bounds=(f0 - fs / x.size, f0 + fs / x.size),
                           method="bounded", options={"xatol": 1e-6 * fs / x.size}).x


@pytest.mark.parametrize("method", ["exact", "fast"])
@pytest.mark.parametrize("r, v", [(12.3, 0.0), (31.7, 14.0), (5.1, -9.0)])
def test_beat_frequency_is_slope_times_delay_minus_doppler(method, r, v):
    """Target: within 0.01 bin of S·2R/c − f_D (the echo's beat is negative: −S·2R/c + f_D
    with the receiver's rx·tx* mixing), R at the centre of the ADC window."""
    wf = FmcwWaveform()
    tau, fd = _target(wf, r, v)
    synth = synthesize_beat_exact if method == "exact" else synthesize_beat
    s = synth([1.0], [tau], [fd], wf)
    t_c = wf.window_centre_s
    r_c = r - v * t_c
    want = -wf.slope * 2 * r_c / C + fd
    got = _peak_frequency(s[:, 0], wf.adc_rate_hz)
    fs = wf.adc_rate_hz  # complex samples: frequencies modulo f_s
    miss = (got - want + fs / 2) % fs - fs / 2
    assert abs(miss) / (fs / wf.samples_per_chirp) < 0.01


@pytest.mark.parametrize("method", ["exact", "fast"])
def test_phase_across_chirps_is_four_pi_range_over_wavelength(method):
    """Target: the phase of each chirp's echo (the range DFT at its beat frequency) within
    1° of −4πR(t)/λ, R(t) the range at that chirp's window centre, λ at the frequency
    the echo sampled there was sent at, f(t_c − τ) (∂Φ/∂τ = −2π f(t' − τ))."""
    wf = FmcwWaveform()
    r, v = 23.4, 17.0
    tau, fd = _target(wf, r, v)
    synth = synthesize_beat_exact if method == "exact" else synthesize_beat
    s = synth([1.0], [tau], [fd], wf)
    f_b = _peak_frequency(s[:, 0], wf.adc_rate_hz)
    n = np.arange(wf.samples_per_chirp) - (wf.samples_per_chirp - 1) / 2
    per_chirp = np.exp(-2j * np.pi * f_b * n / wf.adc_rate_hz) @ s
    t = np.arange(wf.n_chirps) * wf.chirp_interval + wf.window_centre_s
    sent_at = wf.carrier_hz - wf.slope * tau
    want = -4 * np.pi * (r - v * t) / (C / sent_at)
    d = np.angle(per_chirp * np.exp(-1j * want))
    d = np.angle(np.exp(1j * (d - d[0])))
    assert np.degrees(np.abs(d)).max() < 1.0


# ----------------------------------------------------------------------------------------
# phase noise
# ----------------------------------------------------------------------------------------
def test_residual_phase_noise_follows_the_range_correlation_closed_form():
    """The residual φ(t − τ) − φ(t) has PSD 2(1 − cos 2πfτ)·S_φ(f) (Budge & Burt 1993):
    its periodogram, averaged over draws and over bands of bins, within 0.5 dB of it."""
    fs, n = 1e6, 4096
    period = n / fs
    t = np.arange(n) / fs
    cutoff = 0.4 * fs

    def psd(f):
        return 1e-10 * (np.abs(f) < cutoff) * (1e4 / np.maximum(np.abs(f), 1e4))

    tau = np.array([2e-7, 1.3e-6])
    acc = np.zeros((tau.size, n))
    draws = 10
    for k in range(draws):
        res = residual_phase_noise(psd, tau, t, period, rng=k)
        acc += np.abs(np.fft.fft(res, axis=1)) ** 2
    # one-sided PSD estimate: 2|X|²/(f_s n) on bins 1..n/2
    est = 2 * acc / draws / (fs * n)
    f = np.arange(n) / period
    for i, d in enumerate(tau):
        want = 2 * (1 - np.cos(2 * np.pi * f * d)) * psd(f)
        for lo, hi in [(20, 220), (500, 900), (1200, 1600)]:
            ratio = est[i, lo:hi].sum() / want[lo:hi].sum()
            assert abs(10 * np.log10(ratio)) < 0.5, (d, lo, ratio)
    # a close reflector's phase noise cancels: variance ratio as the closed form says
    var = [np.mean(residual_phase_noise(psd, tau, t, period, rng=99) ** 2, axis=1)]
    closed = [np.sum(2 * (1 - np.cos(2 * np.pi * f[1:n // 2] * d)) * psd(f[1:n // 2])) / period
              for d in tau]
    assert closed[0] < closed[1] / 10
    assert var[0][0] == pytest.approx(closed[0], rel=0.3)


def test_phase_noise_mask_is_two_times_ssb():
    psd = phase_noise_psd([1e3, 1e6], [-80.0, -110.0])
    assert psd(1e3) == pytest.approx(2e-8)
    assert psd(1e6) == pytest.approx(2e-11)
    assert psd(10 ** 4.5) == pytest.approx(2 * 10 ** -9.5)
    with pytest.raises(ArgumentError):
        phase_noise_psd([1e6, 1e3], [-80.0, -110.0])


def test_far_reflector_keeps_more_phase_noise_in_the_frame():
    """Through the whole frame: the phase noise left in a reflector's beat grows with its
    range as the closed form says, Σ 2(1 − cos 2πfτ)·S_φ(f) over the band the ADC sees
    (within 1 dB for a 2 m and a 14 m reflector, ~45x apart)."""
    wf = _small(adc_start_s=1e-6)
    psd = phase_noise_psd([1e3, 1e5, 1e6], [-60.0, -80.0, -100.0])
    f = np.linspace(1e3, wf.adc_rate_hz / 2, 20000)
    powers, closed = [], []
    for r in (2.0, 14.0):
        tau, fd = _target(wf, r, 0.0)
        paths = los_paths([1.0], [tau], [fd])
        clean = fmcw_frame(paths, wf)
        noisy = [fmcw_frame(paths, wf, phase_noise=psd, seed=k) for k in range(4)]
        # relative to the echo's own power (the IF filter passes the two differently)
        powers.append(np.mean([np.sum(np.abs(x - clean) ** 2) for x in noisy])
                      / np.sum(np.abs(clean) ** 2))
        closed.append(np.trapezoid(2 * (1 - np.cos(2 * np.pi * f * tau)) * psd(f), f))
    assert powers[1] > 20 * powers[0]
    assert abs(10 * np.log10((powers[1] / powers[0]) / (closed[1] / closed[0]))) < 1.0


# ----------------------------------------------------------------------------------------
# processing and estimation
# ----------------------------------------------------------------------------------------
def test_coupling_correction_inverts_the_beat_model():
    wf = FmcwWaveform()
    r, v = np.array([10.0, 42.0]), np.array([-12.0, 18.0])
    beta = 2 * v / C
    fw, s = wf.carrier_hz, wf.slope
    raw_r = r - v * fw / s
    raw_v = v * (1 - 2 * s * r / (C * fw))
    got_r, got_v = correct_coupling(raw_r, raw_v, wf)
    assert got_r == pytest.approx(r, abs=1e-9)
    assert got_v == pytest.approx(v, abs=1e-9)
    assert np.all(beta != 0)


def test_radar_chain_finds_two_targets_where_they_are():
    wf = FmcwWaveform(n_chirps=64, samples_per_chirp=128)
    targets = [(14.2, 6.0), (37.9, -11.5)]
    tau, fd = np.array([_target(wf, r, v) for r, v in targets]).T
    paths = los_paths([3e-5, 1e-5], tau, fd)
    res = radar_chain(paths, wf, tx_power_w=1.0, noise_figure_db=10.0)
    assert len(res.detections) >= 2
    frame_centre = 0.5 * (wf.n_chirps - 1) * wf.chirp_interval + wf.window_centre_s
    for r, v in targets:
        rc = r - v * frame_centre
        d = res.detections[np.argmin(np.abs(res.detections["range_m"] - rc))]
        assert abs(d["range_m"] - rc) < 0.05 * wf.range_resolution
        assert abs(d["velocity_mps"] - v) < 0.05 * wf.velocity_resolution


def test_real_if_images_half_the_range_and_finds_the_target():
    wf = FmcwWaveform(if_type="real")
    tau, fd = _target(wf, 20.0, 4.0)
    image, dets = fmcw_process(fmcw_frame(los_paths([1e-5], [tau], [fd]), wf,
                                          tx_power_w=1.0, noise_figure_db=10.0), wf)
    assert image.power.shape[0] == wf.samples_per_chirp  # zero padded x2, half kept
    assert image.range_m[-1] < wf.max_range
    assert abs(dets["range_m"][0] - 20.0) < 0.1 * wf.range_resolution


#: 12 frames x 16 targets = 192 errors per SNR: the mean-square error's own spread is
#: 4.34·sqrt(2/192) = 0.44 dB, a 1-dB band is 2.3 of its standard deviations
MC_FRAMES = 12


@pytest.mark.parametrize("snr_db", [0.0, 10.0])
def test_range_velocity_rmse_within_1db_of_the_bound(snr_db):
    """Monte Carlo: 16 targets per frame synthesised from their delays and Dopplers (fast
    synthesis, IF filter undone in their gains so that each has the SNR per sample
    given), through find_targets (CFAR + ML refinement) and the coupling correction:
    range and velocity MSE within 1 dB of fmcw_cramer_rao_bound (truth: R at the frame's
    centre time)."""
    wf = FmcwWaveform(n_chirps=64, samples_per_chirp=128)
    rng = np.random.default_rng(11 + int(snr_db))
    centre = 0.5 * (wf.n_chirps - 1) * wf.chirp_interval + wf.window_centre_s
    grid_r = np.linspace(4.0, 0.8 * wf.max_range, 4)
    grid_v = np.linspace(-0.7, 0.7, 4) * wf.max_velocity
    var = 10 ** (-snr_db / 10)
    err = []
    for _ in range(MC_FRAMES):
        r = (grid_r[:, None] + rng.uniform(0, 3, (4, 4)) * wf.range_resolution).ravel()
        v = (grid_v[None, :] + rng.uniform(0, 3, (4, 4)) * wf.velocity_resolution).ravel()
        tau, fd = _target(wf, r, v)
        f_b, _ = beat_frequencies(tau, fd, wf)
        gains = rng.uniform(-np.pi, np.pi, r.size)
        gains = np.exp(1j * gains) / np.abs(if_response(wf, f_b))
        x = synthesize_beat(gains, tau, fd, wf)
        x = x + np.sqrt(var / 2) * (rng.standard_normal(x.shape)
                                    + 1j * rng.standard_normal(x.shape))
        det = find_targets(x, wf)
        rr, vv = correct_coupling(det["range_m"], det["velocity_mps"], wf)
        for rt, vt in zip(r - v * centre, v, strict=True):
            near = (np.abs(rr - rt) < wf.range_resolution) & \
                (np.abs(vv - vt) < wf.velocity_resolution)
            assert near.sum() == 1, (rt, vt)
            err.append((rr[near][0] - rt, vv[near][0] - vt))
    err = np.array(err)
    bound = fmcw_cramer_rao_bound(wf, 10 ** (snr_db / 10))
    over = 10 * np.log10(np.mean(err ** 2, axis=0)
                         / np.array([bound.range_m ** 2, bound.velocity_mps ** 2]))
    assert np.all(np.abs(over) < 1.0), over
    assert np.all(np.abs(err.mean(axis=0)) < 4 * err.std(axis=0) / np.sqrt(len(err)))


def test_real_if_costs_three_db_of_snr():
    """The I channel alone: half the echo's power in its one-sided bin over half the
    noise (σ²/2 per real sample): the image's peak over its mean floor 3 dB below I/Q."""
    snr = {}
    for kind in ("complex", "real"):
        wf = _small(if_type=kind)
        # 3 m: a beat of 1 MHz, well inside both IF filters (2.5 and 5 MHz)
        tau, fd = _target(wf, 3.0, 2.0)
        paths = los_paths([2e-7], [tau], [fd])
        ratios = []
        for seed in range(6):
            img = fmcw_process(fmcw_frame(paths, wf, seed=seed, tx_power_w=1.0,
                                          noise_figure_db=10.0), wf, zero_pad=(1, 1))[0]
            p = img.power
            i, j = np.unravel_index(np.argmax(p), p.shape)
            floor = np.delete(p, np.s_[max(i - 3, 0):i + 4], axis=0).mean()
            ratios.append(p[i, j] / floor)
        snr[kind] = 10 * np.log10(np.mean(ratios))
    assert snr["complex"] - snr["real"] == pytest.approx(10 * np.log10(2), abs=0.6)


def test_the_waveforms_phase_noise_mask_is_used_by_default():
    mask = dict(phase_noise_offsets_hz=(1e3, 1e5, 1e6), phase_noise_dbc_per_hz=(-60, -80, -100))
    wf = _small(adc_start_s=1e-6, **mask)
    tau, fd = _target(wf, 14.0, 0.0)
    paths = los_paths([1.0], [tau], [fd])
    own = fmcw_frame(paths, wf, seed=3)
    given = fmcw_frame(paths, _small(adc_start_s=1e-6), seed=3,
                       phase_noise=phase_noise_psd(mask["phase_noise_offsets_hz"],
                                                   mask["phase_noise_dbc_per_hz"]))
    assert np.array_equal(own, given)
    assert not np.allclose(own, fmcw_frame(paths, _small(adc_start_s=1e-6), seed=3))
    with pytest.raises(ArgumentError) as err:
        _small(phase_noise_offsets_hz=(1e3, 1e5))
    assert err.value.argument == "phase_noise_dbc_per_hz"
    with pytest.raises(ArgumentError) as err:
        _small(phase_noise_offsets_hz=(1e5, 1e3), phase_noise_dbc_per_hz=(-60, -80))
    assert err.value.argument == "phase_noise_offsets_hz"


def test_tdm_mimo_fmcw_reaches_the_range_velocity_and_angle_bounds():
    """A 2 x 4 TDM array (8-element virtual ULA at λ/2): each element pair's beat frame
    synthesised from the target's delay and Doppler with its plane-wave phase in the gain,
    transmitter i on chirps μ ≡ i (mod 2), D = 1; the OFDM cube chain (TDM range-Doppler
    with motion compensation, cube, CFAR, joint ML refinement) and the coupling
    correction. 16 trials at 0 dB per cell: range, velocity and sin(azimuth) RMSE within
    2 dB of their bounds (the OFDM cube's test holds the same, its RMSE known to ~18 %)."""
    et, er = 2, 4
    wf = FmcwWaveform(n_chirps=64, samples_per_chirp=128)
    lam = wf.wavelength
    tx = np.zeros((et, 3))
    tx[:, 1] = np.arange(et) * er * lam / 2
    rx = np.zeros((er, 3))
    rx[:, 1] = np.arange(er) * lam / 2
    vp = virtual_positions(tx, rx)
    owner = np.arange(wf.n_chirps) % et
    centre = 0.5 * (wf.n_chirps - 1) * wf.chirp_interval + wf.window_centre_s
    rng = np.random.default_rng(21)
    err = []
    for _ in range(16):
        r = (40 + rng.uniform(0.2, 0.8)) * wf.range_resolution
        v = (7 + rng.uniform(0.2, 0.8)) * wf.velocity_resolution
        az = np.arcsin(rng.uniform(0.15, 0.35))
        u = np.array([np.cos(az), np.sin(az), 0.0])
        tau, fd = _target(wf, r, v)
        f_b, _ = beat_frequencies(tau, fd, wf)
        gain = 1.0 / abs(if_response(wf, f_b))
        received = np.zeros((er, wf.samples_per_chirp, wf.n_chirps), complex)
        for i in range(et):
            for j in range(er):
                g = gain * np.exp(2j * np.pi / lam * (tx[i] + rx[j]) @ u)
                received[j][:, owner == i] = synthesize_beat([g], [tau], [fd], wf)[:, owner == i]
        received += np.sqrt(0.5) * (rng.standard_normal(received.shape)
                                    + 1j * rng.standard_normal(received.shape))
        d = np.ones((wf.samples_per_chirp, wf.n_chirps), complex)
        cube = radar_cube(tdm_range_doppler(received, d, wf, et), vp, lam)
        det = detect_cube(cube)[:1]
        f, slow = tdm_channels(received, d, wf, et)
        ml = refine_detections(det, cube, f, slow, vp, wf)
        assert ml["refined"][0]
        rr, vv = correct_coupling(ml["range_m"], ml["velocity_mps"], wf)
        err.append([rr[0] - (r - v * centre), vv[0] - v, ml["u_y"][0] - u[1]])
    rmse = np.sqrt(np.mean(np.square(err), axis=0))
    crb = fmcw_cramer_rao_bound(wf, er)  # SNR 1 per cell, E_rx receivers per chirp
    crb_u = angle_cramer_rao_bound(1.0, vp[:, 1], lam,
                                   n_cells=wf.n_subcarriers * wf.n_symbols // et).sin_theta
    bound = np.array([crb.range_m, crb.velocity_mps, crb_u])
    assert np.all(np.abs(20 * np.log10(rmse / bound)) < 2.0), rmse / bound
