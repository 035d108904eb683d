"""Direction of arrival at the Cramér–Rao bound (clradcom.radar.angle_estimation).

The bound is checked against a Fisher information computed by brute force (central
differences of the signal model written in θ, with range, Doppler and the complex
amplitude unknown too); the estimator by Monte Carlo with a 12-element virtual ULA at λ/2.

Frame of the Monte Carlo: 64 × 32 cells instead of the paper's 1024 × 256, with the SNR
per cell raised by 10·log10(1024·256 / (64·32)) = 21.07 dB so that the integrated SNR
N·M·K·|b|²/σ² is the paper's at 0 and 10 dB per cell (the angle bound depends on N, M only
through N·M·SNR; the whole frame per trial would cost 128 times more).
"""

import numpy as np
import pytest

from clradcom.errors import ArgumentError
from clradcom.radar.angle_estimation import (
    angle_cramer_rao_bound,
    array_snapshots,
    refine_angles,
    refine_range_doppler_angle,
    spatial_periodogram,
)
from clradcom.radar.cube import detect_cube, radar_cube
from clradcom.radar.mimo import RangeDoppler

C = 299_792_458.0
LAM = C / 24e9
K = 12
POS = np.arange(K) * LAM / 2
PAPER_CELLS = 1024 * 256


def _frame(n, m, x, y, sin_theta, b, pos=POS):
    """F_k(n, μ) = b e^{−j2πnx/N} e^{+j2πμy/M} e^{+j2π p_k u/λ}, (K, N, M)."""
    ni = np.arange(n)[None, :, None]
    mi = np.arange(m)[None, None, :]
    pk = np.asarray(pos)[:, None, None]
    return b * np.exp(-2j * np.pi * ni * x / n) * np.exp(2j * np.pi * mi * y / m) \
        * np.exp(2j * np.pi * pk * sin_theta / LAM)


# ----------------------------------------------------------------------------------------
# the bound against a brute-force Fisher information
# ----------------------------------------------------------------------------------------
def _brute_force_sd(n, m, pos, theta, b, noise_var):
    """sqrt(diag(J⁻¹)) for θ (rad) and u = sin θ, J = (2/σ²)Re(∂sᴴ∂s) over the real
    parameters (x, y, angle, Re b, Im b), by central differences."""
    out = []
    for to_u in (np.sin, lambda t: t):  # angle parameter θ, then u itself
        def signal(q, to_u=to_u):
            return _frame(n, m, q[0], q[1], to_u(q[2]), q[3] + 1j * q[4], pos).ravel()

        p0 = np.array([3.3, -1.7, theta if to_u is np.sin else np.sin(theta), b.real,
                       b.imag])
        steps = [1e-5, 1e-5, 1e-7, 1e-6, 1e-6]
        jac = np.empty((signal(p0).size, 5), complex)
        for i, h in enumerate(steps):
            e = np.zeros(5)
            e[i] = h
            jac[:, i] = (signal(p0 + e) - signal(p0 - e)) / (2 * h)
        fisher = 2.0 / noise_var * np.real(jac.conj().T @ jac)
        out.append(np.sqrt(np.linalg.inv(fisher)[2, 2]))
    return out  # sd θ (rad), sd u


@pytest.mark.parametrize("pos, theta_deg, snr_db", [
    (POS, 17.0, 0.0),
    (POS, -48.0, 10.0),
    # a sparse, non-uniform line (the bound's general Σ(p − p̄)² form)
    (np.array([0.0, 0.5, 1.5, 4.0, 4.5, 7.0]) * LAM, 31.0, -3.0),
])
def test_bound_matches_brute_force_fisher_information(pos, theta_deg, snr_db):
    n, m = 16, 8
    b = 0.7 * np.exp(0.4j)
    snr = 10 ** (snr_db / 10)
    theta = np.radians(theta_deg)
    sd_theta, sd_u = _brute_force_sd(n, m, pos, theta, b, abs(b) ** 2 / snr)
    got = angle_cramer_rao_bound(snr, pos, LAM, n_cells=n * m, theta_rad=theta)
    assert got.sin_theta == pytest.approx(sd_u, rel=1e-4)
    assert got.theta_deg == pytest.approx(np.degrees(sd_theta), rel=1e-4)


def test_bound_paper_frame_figures_and_scaling():
    got = angle_cramer_rao_bound(1.0, POS, LAM, n_cells=PAPER_CELLS)
    # closed form of the ULA: 6λ²/[(2πd)² SNR NM K(K²−1)] with d = λ/2
    ula = np.sqrt(6 / (np.pi**2 * PAPER_CELLS * K * (K**2 - 1)))
    assert got.sin_theta == pytest.approx(ula, rel=1e-12)
    assert got.sin_theta == pytest.approx(3.68e-5, abs=0.01e-5)
    ten = angle_cramer_rao_bound([1.0, 10.0], POS, LAM, n_cells=PAPER_CELLS,
                                 theta_rad=np.radians(60.0))
    assert ten.sin_theta[0] / ten.sin_theta[1] == pytest.approx(np.sqrt(10))
    assert ten.theta_deg[0] == pytest.approx(np.degrees(ula) / 0.5)


@pytest.mark.parametrize("kwargs, argument", [
    (dict(snr_per_cell=0.0), "snr_per_cell"),
    (dict(n_cells=0), "n_cells"),
    (dict(theta_rad=np.pi / 2), "theta_rad"),
    (dict(positions_m=[0.0]), "positions_m"),
    (dict(positions_m=[1.0, 1.0]), "positions_m"),
    (dict(wavelength_m=-1.0), "wavelength_m"),
])
def test_bound_rejects_bad_input(kwargs, argument):
    args = dict(snr_per_cell=1.0, positions_m=POS, wavelength_m=LAM, n_cells=10)
    args.update(kwargs)
    with pytest.raises(ArgumentError) as err:
        angle_cramer_rao_bound(**args)
    assert err.value.argument == argument


# ----------------------------------------------------------------------------------------
# the estimator
# ----------------------------------------------------------------------------------------
def test_noiseless_exact_and_amplitude():
    n, m = 32, 16
    b = 1.3 * np.exp(-0.8j)
    f = _frame(n, m, 7.31, -3.62, np.sin(np.radians(-23.0)), b)
    z = array_snapshots(f, [7.31], [-3.62])
    assert z.shape == (1, K)
    ref = refine_angles(f, 7.31, -3.62, POS, LAM)
    assert ref.converged[0]
    assert np.degrees(ref.theta_rad[0]) == pytest.approx(-23.0, abs=1e-9)
    assert ref.amplitude[0] == pytest.approx(b, rel=1e-9)
    # from integer start bins, jointly
    x, y, ang = refine_range_doppler_angle(f, 7.0, -4.0, POS, LAM)
    assert x[0] == pytest.approx(7.31, abs=1e-8)
    assert y[0] == pytest.approx(-3.62, abs=1e-8)
    assert np.degrees(ang.theta_rad[0]) == pytest.approx(-23.0, abs=1e-8)
    # the periodogram peaks there
    u = np.sin(np.radians(-23.0)) + np.array([-1e-3, 0.0, 1e-3])
    p = spatial_periodogram(z[0], POS, LAM, u)
    assert p[1] > p[0] and p[1] > p[2]


def test_refine_rejects_bad_input():
    f = np.zeros((K, 8, 8), complex)
    with pytest.raises(ArgumentError) as err:
        refine_angles(f[:, :, 0], 1.0, 1.0, POS, LAM)
    assert err.value.argument == "channels"
    with pytest.raises(ArgumentError) as err:
        refine_angles(f, [1.0, 2.0], [1.0], POS, LAM)
    assert err.value.argument == "range_bin"
    with pytest.raises(ArgumentError) as err:
        refine_range_doppler_angle(f, 1.0, 1.0, POS[:5], LAM)
    assert err.value.argument == "positions_m"


N_MC, M_MC = 64, 32
COMPENSATION_DB = 10 * np.log10(PAPER_CELLS / (N_MC * M_MC))  # 21.07 dB
#: trials per SNR: the MSE estimate's own spread is 4.34·sqrt(2/500) = 0.27 dB, so the
#: 1-dB band is 3.6 of its standard deviations
TRIALS = 500
TARGET = dict(x=20.37, y=5.61, theta_deg=17.0)


def _trial_frames(rng, snr_db, trials):
    snr = 10 ** ((snr_db + COMPENSATION_DB) / 10)
    clean = _frame(N_MC, M_MC, TARGET["x"], TARGET["y"],
                   np.sin(np.radians(TARGET["theta_deg"])), 1.0)
    sigma = np.sqrt(1.0 / snr / 2)
    for _ in range(trials):
        w = rng.standard_normal((2,) + clean.shape) * sigma
        yield clean + w[0] + 1j * w[1]


def _start_bins(f):
    """The detection a radar would have: the un-windowed FFT cell with the largest
    non-coherent sum over the channels (signed Doppler bin)."""
    img = np.sum(np.abs(np.fft.fft(np.fft.ifft(f, axis=1), axis=2)) ** 2, axis=0)
    r, d = np.unravel_index(np.argmax(img), img.shape)
    return float(r), float(d if d < M_MC // 2 else d - M_MC)


@pytest.mark.parametrize("snr_db", [0.0, 10.0])
def test_rmse_within_1db_of_bound(snr_db):
    rng = np.random.default_rng(1700 + int(snr_db))
    theta0 = TARGET["theta_deg"]
    err_ref, err_fft = [], []
    for f in _trial_frames(rng, snr_db, TRIALS):
        x0, y0 = _start_bins(f)
        _, _, ang = refine_range_doppler_angle(f, x0, y0, POS, LAM)
        assert ang.converged[0]
        err_ref.append(np.degrees(ang.theta_rad[0]) - theta0)
        # plain FFT bin: 16-point array FFT at the detection's cell
        z = array_snapshots(f, x0, y0)[0]
        spec = np.abs(np.fft.fft(z, 16)) ** 2
        kb = np.argmax(spec)
        u_bin = (kb if kb < 8 else kb - 16) * LAM / (16 * LAM / 2)
        err_fft.append(np.degrees(np.arcsin(u_bin)) - theta0)
    bound = angle_cramer_rao_bound(10 ** ((snr_db + COMPENSATION_DB) / 10), POS, LAM,
                                   n_cells=N_MC * M_MC,
                                   theta_rad=np.radians(theta0)).theta_deg
    paper = angle_cramer_rao_bound(10 ** (snr_db / 10), POS, LAM, n_cells=PAPER_CELLS,
                                   theta_rad=np.radians(theta0)).theta_deg
    assert bound == pytest.approx(paper, rel=1e-12)  # the compensation is exact
    over = 20 * np.log10(np.sqrt(np.mean(np.square(err_ref))) / bound)
    assert abs(over) < 1.0, over
    assert abs(np.mean(err_ref)) < 3 * bound / np.sqrt(TRIALS)  # unbiased
    fft_over = 20 * np.log10(np.sqrt(np.mean(np.square(err_fft))) / bound)
    assert fft_over > 10.0, fft_over


def test_cube_parabola_misses_bound():
    """The cube's own angle (Hann array taper, 16-point FFT, parabola on dB at the Hann
    range–Doppler cell) is biased and noisier: far above the bound at 10 dB per cell."""
    rng = np.random.default_rng(1717)
    snr_db = 10.0
    theta0 = TARGET["theta_deg"]
    errs = []
    wn, wm = np.hanning(N_MC + 1)[:-1], np.hanning(M_MC + 1)[:-1]
    for f in _trial_frames(rng, snr_db, 40):
        spec = np.fft.fft(np.fft.ifft(f * wn[None, :, None] * wm[None, None, :], axis=1),
                          axis=2)
        spec = np.fft.fftshift(spec, axes=2).transpose(1, 2, 0)
        rd = RangeDoppler(spec, np.arange(N_MC) * 1.0, np.arange(M_MC) - M_MC // 2.0)
        pos3 = np.stack([np.zeros(K), POS, np.zeros(K)], 1)
        det = detect_cube(radar_cube(rd, pos3, LAM), max_detections=1)
        errs.append(np.degrees(det["azimuth_rad"][0]) - theta0)
    bound = angle_cramer_rao_bound(10 ** (snr_db / 10), POS, LAM, n_cells=PAPER_CELLS,
                                   theta_rad=np.radians(theta0)).theta_deg
    over = 20 * np.log10(np.sqrt(np.mean(np.square(errs))) / bound)
    assert over > 10.0, over
