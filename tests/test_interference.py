"""Two radars: D's interference in A's image and its cancellation (clradcom.radar.interference).

References: docs/interference.md; docs/reference/ofdm-radar-dsp.md §2 (peak-to-floor =
NM·SIR_in, coherent ghost when D sends A's symbols, residual P_I(NMSE + SER·E|d−d̂|²)).
Each stage is checked against a closed form or a brute-force sum; the whole chain on a
small frame (N = 256, M = 64) whose paths are resolved.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from clradcom.radar import (
    Waveform,
    detect,
    radar_image,
    random_symbols,
    spectral_estimate,
    synthesize_frequency_domain,
)
from clradcom.radar import interference as itf
from clradcom.radar.processing import get_window
from clradcom.radar.waveform import SPEED_OF_LIGHT
from tests.dsp_helpers import dirichlet, los_paths

N, M = 256, 64
WF = Waveform(n_subcarriers=N, n_symbols=M)
WF_STREAM = Waveform(n_subcarriers=N, n_symbols=itf.stream_symbols(WF))
NOISE = 10 ** (-104 / 10)

# A's own echoes: a strong zero-Doppler return right under the bumper (it is 20 dB above
# D at A and would wreck D's decisions if not removed first), a car that stays visible
# through the interference and a weak one that the interference floor hides.  Speeds are
# moderate so that the cars' own ICI floor stays > 15 dB under the noise, and the cars sit
# outside the ground return's CFAR training window (6.4 m range cells on this frame).
CARS = [(55.0, -30.0), (90.0, 35.0)]
OWN_G = np.array([10 ** (-57 / 20), 10 ** (-100 / 20) * np.exp(1j), 10 ** (-107 / 20) * 1j])
OWN_T = np.array([3.336e-9, 2 * CARS[0][0] / SPEED_OF_LIGHT, 2 * CARS[1][0] / SPEED_OF_LIGHT])
OWN_F = np.array([0.0, WF.velocity_to_doppler(CARS[0][1]),
                  WF.velocity_to_doppler(CARS[1][1])])
# D -> A: line of sight and a weaker reflection, resolved in delay (> 1/(NΔf) = 43 ns)
D_G = np.array([10 ** (-78 / 20), 10 ** (-88 / 20) * np.exp(2.1j)])
D_T = np.array([108.9e-9, 190.0e-9])
D_F = np.array([2180.0, 1620.0])
T_OFF = 5.0e-6   # D's symbols start 5 µs after A's: far beyond the 1.375 µs prefix
CFO = 3000.0


def brute_stream(symbols, gain, delay, freq, wf, n_samples):
    """a·e^{j2πft}·x(t − Δ) evaluated directly: x is the CP-OFDM stream of ``symbols``
    (symbol ν from ν·T_sym, prefix first), zero outside it; Δ may be negative."""
    n, ell, ncp = wf.n_subcarriers, wf.samples_per_symbol, wf.n_cp
    t = np.arange(n_samples) / wf.sample_rate
    s = (t - delay) * wf.sample_rate
    nu = np.floor(s / ell).astype(int)
    local = s - nu * ell - ncp
    ok = (nu >= 0) & (nu < symbols.shape[1])
    x = np.zeros(n_samples, complex)
    ph = np.exp(2j * np.pi * np.outer(local[ok], np.arange(n)) / n)
    x[ok] = np.einsum("sn,ns->s", ph, symbols[:, nu[ok]]) / math.sqrt(n)
    return gain * np.exp(2j * np.pi * freq * t) * x


@pytest.fixture(scope="module")
def symbols():
    rng = np.random.default_rng(7)
    return random_symbols(WF, rng), random_symbols(WF_STREAM, rng)


@pytest.fixture(scope="module")
def run(symbols):
    d_a, d_d = symbols
    own = itf.own_echo_signal(d_a, OWN_G, OWN_T, OWN_F, WF)
    return itf.run_interference(own, d_a, d_d, D_G, D_T, D_F, WF, timing_offset_s=T_OFF,
                                cfo_hz=CFO, phase_rad=0.7, noise_variance=NOISE, rng=11)


# ----------------------------------------------------------------------------------------
# stages
# ----------------------------------------------------------------------------------------
@pytest.mark.parametrize("delay_sym", [-1.3, -0.37, 0.0, 0.61])
def test_stream_signal_matches_brute_force(delay_sym):
    wf = Waveform(n_subcarriers=16, n_symbols=4)
    d = random_symbols(Waveform(n_subcarriers=16, n_symbols=6), 3)
    delay = delay_sym * wf.symbol_duration + 0.3 / wf.sample_rate
    n_out = 5 * wf.samples_per_symbol
    got = itf.stream_signal(d, [0.5 - 0.2j], [delay], [7000.0], wf, n_out)
    ref = brute_stream(d, 0.5 - 0.2j, delay, 7000.0, wf, n_out)
    assert np.max(np.abs(got - ref)) < 1e-9


def test_own_echo_fast_and_exact_agree_in_a_frame(symbols):
    """Inside A's FFT windows both own-echo models give D·H with the Doppler phase
    referred to A's frame start (as pipeline.radar_frame's fast model)."""
    d_a, _ = symbols
    df, t_sym = WF.subcarrier_spacing_hz, WF.symbol_duration
    g, t, f = np.array([1e-3, 5e-4j]), np.array([3.3e-9, 200e-9]), np.array([0.0, 900.0])
    ref = synthesize_frequency_domain(d_a, g, t, f, WF, time_origin_s=WF.fft_window_centre)
    # the strong still path exact, the moving one by the frequency-domain model
    split = itf.frame_symbols(itf.own_echo_signal(d_a, g, t, f, WF, method="fast",
                                                  exact_within_db=3.0), WF)
    assert np.max(np.abs(split - ref)) < 1e-9 * np.max(np.abs(ref))
    # all exact: the moving echo has ICI, but its fitted amplitude is a·e^{j2πf t_0}·|P_N|
    exact = itf.frame_symbols(itf.own_echo_signal(d_a, g, t, f, WF), WF)
    comp, _ = itf.fit_components(exact / d_a, df, t_sym, min_peak_to_floor_db=20.0)
    k = int(np.argmin(np.abs(comp.doppler_hz - 900.0)))
    expect = g[1] * np.exp(2j * np.pi * 900.0 * WF.fft_window_centre) \
        * abs(dirichlet(900.0 / df, N))
    assert abs(comp.amplitude[k] - expect) < 1e-3 * abs(expect)
    with pytest.raises(ValueError, match="method"):
        itf.own_echo_signal(d_a, g, t, f, WF, method="fastest")


def test_interference_signal_places_d_stream_by_the_documented_clock(symbols):
    """Stream symbol j leaves D at A-frame time t_off + (j − STREAM_LEAD)·T_sym; the
    capture starts one symbol before A's frame."""
    _, d_d = symbols
    got = itf.interference_signal(d_d, D_G[:1], D_T[:1], D_F[:1], WF, T_OFF, CFO,
                                  phase_rad=0.7, power_ratio=2.0)
    delay = T_OFF + D_T[0] - itf.STREAM_LEAD * WF.symbol_duration + WF.symbol_duration
    ref = brute_stream(d_d, D_G[0] * math.sqrt(2.0) * np.exp(0.7j), delay, D_F[0] + CFO,
                       WF, itf.capture_length(WF))
    assert np.max(np.abs(got - ref)) / np.max(np.abs(ref)) < 1e-8


def test_cp_sync_finds_d_timing_and_frequency(symbols):
    _, d_d = symbols
    y = itf.interference_signal(d_d, D_G, D_T, D_F, WF, T_OFF, CFO)
    rng = np.random.default_rng(1)
    y = y + 1e-5 * (rng.standard_normal(y.size) + 1j * rng.standard_normal(y.size))
    theta, eps, _ = itf.cp_sync(y, WF)
    # the CP of the line-of-sight copy starts (t_off + τ_LOS)·f_s after a capture symbol
    expect = ((T_OFF + D_T[0]) * WF.sample_rate) % WF.samples_per_symbol
    assert abs(theta - expect) <= 2
    # the estimate is the power-weighted mean frequency of the paths
    w = np.abs(D_G) ** 2
    f_mean = np.sum(w * (D_F + CFO)) / np.sum(w)
    assert abs(eps * WF.subcarrier_spacing_hz - f_mean) < 0.01 * WF.subcarrier_spacing_hz


def test_fit_components_recovers_resolved_tones():
    rng = np.random.default_rng(5)
    df, t_sym = WF.subcarrier_spacing_hz, WF.symbol_duration
    true = itf.Components(np.array([1.0, 0.3j, 0.1 * np.exp(2j)]),
                          np.array([12.3e-9, 160.7e-9, -55.1e-9]),
                          np.array([210.0, -3300.0, 1234.5]))
    g = true.grid(N, M, df, t_sym)
    g += 0.03 * (rng.standard_normal(g.shape) + 1j * rng.standard_normal(g.shape))
    comp, floor = itf.fit_components(g, df, t_sym, min_peak_to_floor_db=15.0)
    assert comp.amplitude.size == 3
    order = np.argsort(-np.abs(comp.amplitude))
    # single-tone CRB at these SNRs is ~1e-4 bin; allow 2e-3 bin
    assert np.allclose(comp.delay_s[order], true.delay_s, atol=2e-3 / (N * df))
    assert np.allclose(comp.doppler_hz[order], true.doppler_hz, atol=2e-3 / (M * t_sym))
    assert np.allclose(comp.amplitude[order], true.amplitude, atol=3e-3)
    assert floor == pytest.approx(2 * 0.03 ** 2, rel=0.1)


def test_blind_channel_needs_no_pilots():
    """Two paths, the second at −10 dB (its cross terms in H⁴ outweigh the main path's
    own tone, so a one-path power law would be biased): Ĥ matches H up to one global
    rotation by 90°, and the decisions from it are right almost everywhere."""
    rng = np.random.default_rng(2)
    df, t_sym = WF.subcarrier_spacing_hz, WF.symbol_duration
    d = random_symbols(WF, rng)
    true = itf.Components(np.array([0.8 * np.exp(0.4j), 0.25j]), np.array([370e-9, 520e-9]),
                          np.array([140.0, -900.0]))
    h = true.grid(N, M, df, t_sym)
    r = h * d + 0.1 * (rng.standard_normal(d.shape) + 1j * rng.standard_normal(d.shape))
    h_hat = itf.blind_channel(r, "qpsk", df, t_sym)
    rot = np.exp(0.5j * np.pi * np.round(np.angle(np.mean(h_hat / h)) / (0.5 * np.pi)))
    err = np.abs(h_hat - rot * h) ** 2
    strong = np.abs(h) > 0.3 * np.abs(h).max()  # the root is ill-posed in deep fades
    assert np.mean(err[strong]) / np.mean(np.abs(h[strong]) ** 2) < 1e-3
    dh = itf.decide(r / h_hat, "qpsk")
    assert np.mean(np.abs(dh / d - np.conj(rot)) < 1e-9) > 0.99


# ----------------------------------------------------------------------------------------
# the whole chain
# ----------------------------------------------------------------------------------------
def test_interference_power_matches_the_channel(run):
    """The exact time-domain interferer has the power of the frequency-domain D->A
    channel: timing offset, ISI and CFO move power around but do not change it."""
    assert 10 * math.log10(run.interference_power / run.predicted_interference_power) \
        == pytest.approx(0.0, abs=0.3)


def test_floor_rises_by_the_interference_to_noise_ratio(run):
    # the clean floor is the thermal noise itself (image normalisation, docs/dsp.md §4)
    assert 10 * math.log10(run.floors["clean"] / NOISE) == pytest.approx(0.0, abs=0.3)
    expect = 10 * math.log10(1 + run.predicted_floor_power / NOISE)
    assert expect > 20  # the case is interference-limited
    assert run.measured_floor_rise_db == pytest.approx(expect, abs=0.5)
    assert run.predicted_floor_rise_db == pytest.approx(expect, abs=0.3)


def test_peak_to_floor_is_nm_times_input_sir(symbols):
    """Braun 2013: after A's division D's data is white, so a target's peak over the
    interference floor is NM·SIR_in times the windows' coherent gain.  One on-grid
    target (no straddle loss), its ICI loss |P_N(ε)|² included; no noise.  The target is
    30 dB over the floor in the image, so the interference in its own cell moves the peak
    by about ±0.3 dB (1σ)."""
    d_a, d_d = symbols
    df, t_sym = WF.subcarrier_spacing_hz, WF.symbol_duration
    a, tau, f = 10 ** (-85 / 20), 30 / (N * df), 3 / (M * t_sym)
    own = itf.own_echo_signal(d_a, [a], [tau], [f], WF)
    y = own + itf.interference_signal(d_d, D_G, D_T, D_F, WF, T_OFF, CFO)
    im = radar_image(spectral_estimate(itf.frame_symbols(y, WF), d_a), WF, "hann", "hann",
                     2, 2)
    p_i = itf.predicted_interference_power(D_G, D_T, D_F, WF, 1.0, "hann", "hann")
    wn, wm = get_window("hann", N), get_window("hann", M)
    gain = wn.sum() ** 2 / (N * np.sum(wn ** 2)) * wm.sum() ** 2 / (M * np.sum(wm ** 2))
    sir_in = a ** 2 * abs(dirichlet(f / df, N)) ** 2 / p_i
    assert 10 * math.log10(sir_in) < -7  # well below D at the input ...
    floor = itf.image_floor(im)
    assert 10 * math.log10(floor / p_i) == pytest.approx(0.0, abs=0.3)
    expect_db = 10 * math.log10(N * M * sir_in * gain)
    measured_db = 10 * math.log10(im.power.max() / floor)
    assert measured_db == pytest.approx(expect_db, abs=0.75)  # ... well above it in the image


def test_genie_cancellation_restores_the_floor(run):
    rel = 10 * math.log10(run.floors["genie"] / run.floors["clean"])
    assert abs(rel) < 0.1  # the issue asks for 3 dB; true data and channel remove D exactly


def test_realistic_cancellation_comes_within_one_db(run):
    """Stated margin: 1 dB over the interference-free floor, with INR ≈ 28 dB."""
    rel = 10 * math.log10(run.floors["realistic"] / run.floors["clean"])
    assert rel < 1.0
    assert run.symbol_error_rate == 0.0
    # the residual interference is the channel error (no wrong decisions here)
    assert run.residual_power == pytest.approx(run.interference_power * run.channel_nmse,
                                               rel=1e-6)
    assert 10 * math.log10(run.channel_nmse) < -35.0
    # what the receiver found: D's timing, its frequency, and A's strong echo removed
    est = run.estimate
    assert est.own.amplitude.size >= 1
    assert abs(est.own.delay_s[0] - OWN_T[0]) < 0.01 / WF.bandwidth
    assert abs(est.eps * WF.subcarrier_spacing_hz - (D_F[0] + CFO)) < 200.0


def test_every_interference_free_detection_is_found_again(run):
    kw = dict(guard=(3, 2), train=(8, 4))
    ref = detect(run.images["clean"], **kw)
    assert len(ref) >= 3
    for r, v in CARS:  # the two cars are among the interference-free detections
        assert np.any((np.abs(ref["range_m"] - r) < WF.range_resolution)
                      & (np.abs(ref["velocity_mps"] - v) < WF.velocity_resolution))
    with_d = detect(run.images["interfered"], **kw)
    assert len(with_d) < len(ref)  # the interference floor hides something
    for key in ("genie", "realistic"):
        found = detect(run.images[key], **kw)
        for d in ref:
            near = (np.abs(found["range_m"] - d["range_m"]) <= WF.range_resolution) & \
                   (np.abs(found["velocity_mps"] - d["velocity_mps"])
                    <= WF.velocity_resolution)
            assert near.any(), (key, d)


def test_residual_follows_the_error_budget_when_decisions_fail(symbols):
    """With D only a few dB above the noise A's decisions on D fail now and then; the
    residual is then P_I·(NMSE + SER·E|d − d̂|²) (docs/reference/ofdm-radar-dsp.md §2).  That budget
    spreads the errors evenly, so D's channel here is flat (one path); on a selective
    channel the errors fall in fades and the |Ĥ|²-weighted budget holds instead."""
    d_a, d_d = symbols
    own = itf.own_echo_signal(d_a, OWN_G[1:], OWN_T[1:], OWN_F[1:], WF)
    res = itf.run_interference(own, d_a, d_d, D_G[:1] * 10 ** (-17 / 20), D_T[:1], D_F[:1], WF,
                               timing_offset_s=2.0e-6, cfo_hz=-1500.0,
                               noise_variance=NOISE, rng=4)
    assert 1e-3 < res.symbol_error_rate < 0.05  # INR ≈ 9 dB
    assert res.estimate.cancel
    assert res.mean_error_energy == pytest.approx(2.0, rel=0.1)  # QPSK neighbours: |Δd|² = 2
    assert res.channel_nmse < 1e-4  # so the decisions make the residual
    ratio = res.residual_power / res.predicted_residual_power
    assert 10 * math.log10(ratio) == pytest.approx(0.0, abs=0.5)
    ratio_w = res.residual_power / res.predicted_residual_weighted
    assert 10 * math.log10(ratio_w) == pytest.approx(0.0, abs=0.5)


def test_unreliable_estimate_is_left_alone(symbols):
    """D at about the noise level: the blind receiver cannot decide D's symbols (its
    SER would be near 1/2 and the rebuild would add interference).  It sees that from
    its own fit, subtracts nothing, and the image stays as interfered, not worse."""
    d_a, d_d = symbols
    own = itf.own_echo_signal(d_a, OWN_G, OWN_T, OWN_F, WF)
    res = itf.run_interference(own, d_a, d_d, D_G * 10 ** (-27 / 20), D_T, D_F, WF,
                               timing_offset_s=T_OFF, cfo_hz=CFO, noise_variance=NOISE,
                               rng=5)
    assert res.symbol_error_rate > 0.2
    assert not res.estimate.cancel and res.estimate.sinr_db < 6.0
    assert res.floors["realistic"] == res.floors["interfered"]
    assert res.residual_power == pytest.approx(res.interference_power)


def test_d_sending_a_symbols_makes_a_coherent_ghost(symbols):
    """If D's data equals A's, D is a target at the one-way delay plus D's timing offset
    (range c(t_off + τ)/2) and the one-way Doppler plus D's carrier offset
    (velocity (f + cfo)·c/(2 f_c)), with the power NM·|a|²·|P_N(ε)|²·window gain."""
    d_a, _ = symbols
    d_d = np.array(random_symbols(WF_STREAM, 9))
    d_d[:, itf.STREAM_LEAD:itf.STREAM_LEAD + M] = d_a
    df, t_sym = WF.subcarrier_spacing_hz, WF.symbol_duration
    t_off = 0.4e-6                          # inside the prefix together with τ
    tau = 20 / (N * df) - t_off             # total delay on range bin 20
    f_tot = 5 / (M * t_sym)                 # on Doppler bin 5 ...
    cfo = 1200.0                            # ... of which D's oscillator makes 1200 Hz
    a = 10 ** (-80 / 20)
    y = itf.interference_signal(d_d, [a], [tau], [f_tot - cfo], WF, t_off, cfo)
    rng = np.random.default_rng(3)
    y = y + math.sqrt(NOISE / 2) * (rng.standard_normal(y.size)
                                    + 1j * rng.standard_normal(y.size))
    im = radar_image(spectral_estimate(itf.frame_symbols(y, WF), d_a), WF, "hann", "hann",
                     2, 2)
    det = detect(im, guard=(3, 2), train=(8, 4))
    top = det[0]
    assert top["range_m"] == pytest.approx(SPEED_OF_LIGHT * (t_off + tau) / 2,
                                           abs=0.05 * WF.range_resolution)
    assert top["velocity_mps"] == pytest.approx(f_tot * SPEED_OF_LIGHT / (2 * WF.carrier_hz),
                                                abs=0.05 * WF.velocity_resolution)
    wn, wm = get_window("hann", N), get_window("hann", M)
    gain = wn.sum() ** 2 / (N * np.sum(wn ** 2)) * wm.sum() ** 2 / (M * np.sum(wm ** 2))
    expect = N * M * a ** 2 * abs(dirichlet(f_tot / df, N)) ** 2 * gain
    assert 10 * math.log10(im.power.max() / expect) == pytest.approx(0.0, abs=0.2)
    # the same D with its own data: no ghost, only a floor
    y2 = itf.interference_signal(random_symbols(WF_STREAM, 9), [a], [tau], [f_tot - cfo],
                                 WF, t_off, cfo)
    im2 = radar_image(spectral_estimate(itf.frame_symbols(y2, WF), d_a), WF, "hann", "hann",
                      2, 2)
    assert im2.power.max() < 1e-2 * expect


# ----------------------------------------------------------------------------------------
# bad input
# ----------------------------------------------------------------------------------------
def test_bad_input_is_refused_by_name(symbols):
    d_a, d_d = symbols
    with pytest.raises(ValueError, match="timing_offset_s"):
        itf.interference_signal(d_d, D_G, D_T, D_F, WF, WF.symbol_duration, 0.0)
    with pytest.raises(ValueError, match="timing_offset_s"):
        itf.interference_signal(d_d, D_G, D_T, D_F, WF, -1e-9, 0.0)
    with pytest.raises(ValueError, match="cfo_hz"):
        itf.interference_signal(d_d, D_G, D_T, D_F, WF, 0.0, 0.45 * WF.subcarrier_spacing_hz)
    with pytest.raises(ValueError, match="d_stream"):
        itf.interference_signal(d_d[:, :M], D_G, D_T, D_F, WF, 0.0, 0.0)
    with pytest.raises(ValueError, match="power_ratio"):
        itf.interference_signal(d_d, D_G, D_T, D_F, WF, 0.0, 0.0, power_ratio=0.0)
    with pytest.raises(ValueError, match="own_signal"):
        itf.run_interference(np.zeros(10), d_a, d_d, D_G, D_T, D_F, WF, timing_offset_s=0.0,
                             cfo_hz=0.0, noise_variance=NOISE)
    with pytest.raises(ValueError, match="noise_variance"):
        itf.run_interference(np.zeros(itf.capture_length(WF)), d_a, d_d, D_G, D_T, D_F, WF,
                             timing_offset_s=0.0, cfo_hz=0.0, noise_variance=-1.0)
    with pytest.raises(ValueError, match="delays_s"):
        itf.stream_signal(d_d, [1.0], [np.nan], [0.0], WF, 100)


# ----------------------------------------------------------------------------------------
# the tracer gives every link of a two-radar scene
# ----------------------------------------------------------------------------------------
def test_two_radar_scene_traces_all_four_links(runtime):
    """A and D (the paper's cars' radars, 34.6 m apart in opposite lanes, closing) over a
    smooth road: one snapshot holds A->A, A->D, D->A and D->D; the one-way D->A line of
    sight has delay L/c and Doppler −(1/λ)dL/dt, equal both ways (reciprocity)."""
    from clradcom.scene.reader import scene_from_dict
    from clradcom.trace import DiffractionSettings, SpecularSettings, TraceSettings, trace_scene

    p_a, v_a = np.array([0.0, -1.75, 0.5]), np.array([12.9, 0.0, 0.0])
    p_d, v_d = np.array([34.6, 1.75, 0.5]), np.array([-14.5, 0.0, 0.0])
    data = {
        "scene": {"name": "two_radars", "carrier_hz": 24e9},
        "materials": [{"name": "road", "base": "concrete_road", "roughness_m": 0.0}],
        "objects": [{"name": "ground", "material": "road", "shape": "plane",
                     "size": [200.0, 40.0], "position": [17.3, 0.0, 0.0]}],
        "radars": [
            {"name": "A", "role": "txrx", "position": p_a.tolist(), "velocity": v_a.tolist()},
            {"name": "D", "role": "txrx", "position": p_d.tolist(), "velocity": v_d.tolist(),
             "orientation_deg": [0.0, 0.0, 180.0]},
        ],
    }
    snap = trace_scene(scene_from_dict(data, base_dir="."),
                       TraceSettings(specular=SpecularSettings(max_reflections=1, rays=20_000),
                                     diffraction=DiffractionSettings(max_diffractions=0)),
                       runtime=runtime)
    assert {lk.label for lk in snap.links} == {"A->A", "A->D", "D->A", "D->D"}
    lam = SPEED_OF_LIGHT / 24e9
    dist = float(np.linalg.norm(p_a - p_d))
    u = (p_a - p_d) / dist
    f_los = -float(u @ (v_a - v_d)) / lam  # closing: positive
    assert f_los > 0
    for tx, rx in (("D", "A"), ("A", "D")):
        paths = snap.link(tx, rx).paths
        los = np.flatnonzero(np.asarray(paths.n_interactions) == 0)
        assert los.size == 1
        k = int(los[0])
        assert paths.delay_s[k] == pytest.approx(dist / SPEED_OF_LIGHT, abs=1e-13)
        assert paths.doppler_hz[k] == pytest.approx(f_los, abs=1e-6 * abs(f_los))
        # the road bounce, one way: image of the transmitter 0.5 m under the road
        ref = np.flatnonzero(np.asarray(paths.n_interactions) == 1)
        l_ref = math.hypot(dist, 1.0)
        assert np.any(np.abs(paths.delay_s[ref] - l_ref / SPEED_OF_LIGHT) < 1e-13)
    ab, ba = snap.link("A", "D").paths, snap.link("D", "A").paths
    assert np.sort(ab.delay_s) == pytest.approx(np.sort(ba.delay_s), abs=1e-13)
    for name in ("A", "D"):  # monostatic: the road straight down and back, 2·0.5 m
        mono = snap.link(name, name).paths
        assert np.any(np.abs(mono.delay_s - 1.0 / SPEED_OF_LIGHT) < 1e-13)


# ----------------------------------------------------------------------------------------
# the command-line tool
# ----------------------------------------------------------------------------------------
def _tool():
    from tool_helpers import load_tool

    return load_tool("interference")


def test_tool_on_a_snapshot_writes_the_picture_and_recovers_the_detections(tmp_path, capsys):
    from clradcom.snapshot import Link, Snapshot, save_snapshot

    snap = Snapshot("two_radars", 24e9, "", links=(
        Link("A", "A", 0, 0, los_paths(OWN_G, OWN_T, OWN_F)),
        Link("D", "A", 1, 0, los_paths(D_G, D_T, D_F)),
    ))
    save_snapshot(tmp_path / "snapshot.npz", snap)
    out = tmp_path / "out"
    rc = _tool().main(["--snapshot", str(tmp_path / "snapshot.npz"), "--out", str(out),
                       "--range-max", "100", "--subcarriers", str(N), "--symbols", str(M)])
    text = capsys.readouterr().out
    assert rc == 0
    # no silent stage: each printed as it starts, in order
    starts = [text.find(f"] {stage}") for stage in itf.INTERFERENCE_STAGES]
    assert -1 not in starts and starts == sorted(starts), starts
    assert (out / "interference.png").stat().st_size > 10_000
    rows = dict(line.rstrip("\n").rsplit(",", 1) for line in
                (out / "interference_summary.csv").read_text().splitlines()[1:])
    rise_p = float(rows["floor rise predicted (1 + INR) [dB]"])
    rise_m = float(rows["floor rise measured [dB]"])
    assert rise_p > 10 and abs(rise_m - rise_p) < 0.5
    assert abs(float(rows["floor after genie cancellation re without D [dB]"])) < 0.1
    assert float(rows["floor after realistic cancellation re without D [dB]"]) < 1.0
    line = [s for s in text.splitlines() if s.strip().startswith("realistic:")][0]
    found, total = (int(x) for x in line.split()[1:4:2])
    assert found == total >= 2


def test_tool_refuses_unclear_input(tmp_path, capsys):
    tool = _tool()
    with pytest.raises(SystemExit):
        tool.main(["--out", str(tmp_path)])  # neither a scene nor a snapshot
    assert "exactly one" in capsys.readouterr().err
    rc = tool.main(["--snapshot", str(tmp_path / "missing.npz"), "--out", str(tmp_path)])
    assert rc == 2
    assert "missing.npz" in capsys.readouterr().err
