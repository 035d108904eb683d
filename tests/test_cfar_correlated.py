"""CFAR at its design false-alarm rate on windowed (correlated) images (issue #33 item 1):
the cells' correlation from the windows, the exact CA-CFAR P_fa for correlated Gaussian
cells against its own sampled estimate, the measured rate on noise-only frames of the
radar chain (1e-4 and 1e-5 counted, 1e-6 by importance sampling) for the image, the cube
and OS-CFAR, and the detection probability against the detector it replaces."""

import math

import numpy as np
import pytest
from dsp_helpers import small_waveform
from scipy.linalg import sqrtm

from clradcom.radar import Waveform, radar_image
from clradcom.radar.cfar import (
    RADAR_GUARD,
    RADAR_TRAIN,
    ca_cfar_alpha,
    ca_cfar_detection_probability,
    ca_cfar_pfa_correlated,
    cell_covariance,
    cfar_alpha,
    cfar_threshold,
    os_cfar_alpha,
    os_cfar_pfa,
    sampled_pfa,
    training_offsets,
)
from clradcom.radar.cube import cube_threshold, radar_cube
from clradcom.radar.mimo import tdm_range_doppler
from clradcom.radar.processing import CellCorrelation, cell_correlation, get_window
from clradcom.radar.waveform import random_symbols

#: the guard and training shape `pipeline.process` and `cube.detect_cube` ran before the
#: fix, with α for independent cells: the detection probability is held against it
OLD_GUARD, OLD_TRAIN = (2, 1), (4, 2)


def hann_covariance(guard, train, n=1024, m=256):
    offsets = np.vstack([[0, 0], training_offsets(guard, train)])
    return cell_covariance(offsets, cell_correlation("hann", "hann", n, m))


def white(rng, shape):
    return (rng.standard_normal(shape) + 1j * rng.standard_normal(shape)) / math.sqrt(2.0)


def test_hann_cell_correlation_is_its_closed_form_and_the_images():
    # periodic Hann w = ½ − ½cos: w² = 3/8 − ½cos + ⅛cos2, so ρ(±1) = −(1/4)/(3/8),
    # ρ(±2) = (1/16)/(3/8), 0 beyond
    c = cell_correlation("hann", "hann", 64, 32)
    for rho in (c.range, c.doppler):
        assert rho[:4] == pytest.approx([1.0, -2 / 3, 1 / 6, 0.0], abs=1e-14)
        assert rho[-2:] == pytest.approx([1 / 6, -2 / 3], abs=1e-14)
    assert np.abs(cell_correlation("rect", "rect", 64, 32).range[1:]).max() < 1e-15
    # the images' power correlates as |ρ|² (Gaussian cells): 4/9 at lag 1, 1/36 at lag 2
    wf = small_waveform(n=256, m=64)
    rng = np.random.default_rng(3)
    p = np.stack([radar_image(white(rng, (256, 64)), wf).power for _ in range(40)])
    p = (p - p.mean()) / p.std()
    for lag, want in ((1, 4 / 9), (2, 1 / 36), (3, 0.0)):
        for axis in (1, 2):
            got = np.mean(p * np.roll(p, lag, axis=axis))
            assert got == pytest.approx(want, abs=0.012), (lag, axis)


def test_exact_ca_pfa_is_richards_on_independent_cells():
    for n_t, p in ((16, 1e-6), (76, 1e-4)):
        alpha = ca_cfar_alpha(n_t, p)
        assert ca_cfar_pfa_correlated(alpha, np.eye(n_t + 1)) == pytest.approx(p, rel=1e-10)


def test_exact_ca_pfa_is_the_product_over_the_eigenvalues():
    """The secular-equation evaluation against the definition: eigenvalues of
    R^½ A R^½ by scipy (square root by sqrtm), P = Π 1/(1 + μ_k/λ₊)."""
    cov = hann_covariance(RADAR_GUARD, RADAR_TRAIN)
    n_t = cov.shape[0] - 1
    root = sqrtm(cov)
    for alpha in (5.0, 20.0, 60.0):
        ev = np.linalg.eigvalsh(root @ np.diag([1.0] + [-alpha / n_t] * n_t) @ root)
        assert (ev > 0).sum() == 1
        want = np.prod(1.0 / (1.0 - ev[:-1] / ev[-1]))
        assert ca_cfar_pfa_correlated(alpha, cov) == pytest.approx(want, rel=1e-9)


def test_exact_ca_pfa_agrees_with_its_sampled_estimate_on_hann_cells():
    """Two computations that share nothing but the covariance: eigenvalues of R^½AR^½
    against conditional Monte Carlo (plain, and importance-sampled)."""
    cov = hann_covariance(RADAR_GUARD, RADAR_TRAIN)
    n_t = cov.shape[0] - 1
    for p in (1e-4, 1e-6):
        alpha, _ = cfar_alpha(RADAR_GUARD, RADAR_TRAIN, p, correlation=cell_correlation(
            "hann", "hann", 1024, 256))
        assert ca_cfar_pfa_correlated(alpha, cov) == pytest.approx(p, rel=1e-9)
        theta = 1.0 / (1.0 + alpha / n_t)
        log_pfa, rel_error, _ = sampled_pfa(cov, None, 160000, theta, seed=5)
        assert rel_error(alpha) < 0.05
        assert math.exp(log_pfa(alpha)) == pytest.approx(p, rel=4 * rel_error(alpha))
    log_pfa, rel_error, _ = sampled_pfa(cov, None, 60000, 1.0, seed=6)
    alpha, _ = cfar_alpha(RADAR_GUARD, RADAR_TRAIN, 1e-3,
                          correlation=cell_correlation("hann", "hann", 1024, 256))
    assert math.exp(log_pfa(alpha)) == pytest.approx(1e-3, rel=4 * rel_error(alpha))


def test_sampled_os_pfa_is_rohling_on_independent_cells():
    n_t, k = 76, 57
    for p in (1e-4, 1e-6):
        alpha = os_cfar_alpha(n_t, k, p)
        theta = 1.0 / (1.0 + ca_cfar_alpha(n_t, p) / n_t)
        log_pfa, rel_error, mean_stat = sampled_pfa(np.eye(n_t + 1), k, 40000, theta, seed=7)
        assert math.exp(log_pfa(alpha)) == pytest.approx(os_cfar_pfa(n_t, k, alpha),
                                                         rel=4 * rel_error(alpha))
        assert mean_stat == pytest.approx(np.sum(1.0 / np.arange(n_t - k + 1, n_t + 1)),
                                          rel=0.01)


def test_correlated_alpha_exceeds_the_independent_one_and_refuses_nonsense():
    corr = cell_correlation("hann", "hann", 1024, 256)
    n_t = training_offsets(RADAR_GUARD, RADAR_TRAIN).shape[0]
    alpha, ratio = cfar_alpha(RADAR_GUARD, RADAR_TRAIN, 1e-6, "ca", None, corr)
    assert alpha > 1.05 * ca_cfar_alpha(n_t, 1e-6) and ratio == 1.0
    # a rectangular window leaves the cells independent: the closed forms, exactly
    rect = cell_correlation("rect", "rect", 1024, 256)
    assert cfar_alpha((2, 1), (4, 2), 1e-6, "ca", None, rect)[0] == ca_cfar_alpha(76, 1e-6)
    with pytest.raises(ValueError, match="correlation"):
        cfar_threshold(np.ones((64, 32)), correlation=corr)  # lengths of another map
    with pytest.raises(ValueError, match="correlation"):
        cfar_alpha(correlation=CellCorrelation(np.full(64, 0.5), np.ones(32)))


def noise_images(rng, frames, wf):
    for _ in range(frames):
        yield radar_image(white(rng, (wf.n_subcarriers, wf.n_symbols)), wf)


def test_ca_false_alarm_rate_on_noise_frames_of_the_radar_chain():
    """`pipeline.process`'s CFAR (critically sampled Hann image, its guard and training
    cells): raw threshold crossings on 40 noise-only paper frames (10.5 M cells) within a
    factor 1.5 of P_fa = 1e-4 and 1e-5; the α of independent cells gives several times
    as many."""
    wf = Waveform()
    rng = np.random.default_rng(11)
    p_fas = (1e-4, 1e-5)
    hits = dict.fromkeys(p_fas, 0)
    old_hits = 0
    cells = 0
    n_old = training_offsets(OLD_GUARD, OLD_TRAIN).shape[0]
    for img in noise_images(rng, 40, wf):
        for p in p_fas:
            thr, noise, _ = cfar_threshold(img.power, RADAR_GUARD, RADAR_TRAIN, p,
                                           correlation=img.correlation)
            hits[p] += np.count_nonzero(img.power > thr)
        _, noise_old, _ = cfar_threshold(img.power, OLD_GUARD, OLD_TRAIN, 1e-5)
        old_hits += np.count_nonzero(img.power > ca_cfar_alpha(n_old, 1e-5) * noise_old)
        cells += img.power.size
    for p in p_fas:
        assert 1 / 1.5 < hits[p] / cells / p < 1.5, (p, hits[p] / cells)
    assert old_hits / cells > 2.5e-5


def tilted_noise(rng, wf, rows, cols, theta, tilt):
    """The importance-sampling density: white noise F of variance θ, plus for every cell
    (rows, cols) of the critically sampled image an independent CN(0, tilt) component
    along the unit vector that cell reads (on a :func:`lattice` those vectors are
    orthogonal to each other and to those of every other cell's footprint, for Hann)."""
    n, m = wf.n_subcarriers, wf.n_symbols
    q = (cols - m // 2) % m  # DFT bin of the fftshifted column
    grid = np.zeros((n, m), complex)
    grid[rows, q] = math.sqrt(tilt) * white(rng, rows.size)
    # Σ_k Z_k e^{−j2πn p_k/N} e^{+j2πμ q_k/M}: the image reads Σ a_n b_μ F e^{+j2πnp/N}
    # e^{−j2πμq/M}/‖a‖‖b‖, so this times a_n b_μ/‖a‖‖b‖ puts Z_k in cell k
    s = np.fft.ifft(np.fft.fft(grid, axis=0), axis=1) * m
    return math.sqrt(theta) * white(rng, (n, m)) + hann_taper(n, m) * s


def hann_taper(n, m):
    wn, wm = get_window("hann", n), get_window("hann", m)
    return np.outer(wn, wm) / math.sqrt(np.sum(wn**2) * np.sum(wm**2))


def complex_image(f):
    """The complex cells whose squares are radar_image's Hann map (fftshifted)."""
    n, m = f.shape
    h = np.fft.fft(np.fft.ifft(f * hann_taper(n, m), axis=0) * n, axis=1)
    return np.fft.fftshift(h, axes=1)


def lattice(wf):
    """Cells of the critically sampled image far enough apart that none is within three
    bins (where Hann cells stop correlating) of another's CFAR footprint: spacing
    guard + train + 3 per axis, also across the wrap."""
    offsets = training_offsets(RADAR_GUARD, RADAR_TRAIN)
    step = np.abs(offsets).max(axis=0) + 3
    n, m = wf.n_subcarriers, wf.n_symbols
    r, c = np.meshgrid(np.arange(n // step[0]) * step[0], np.arange(m // step[1]) * step[1],
                       indexing="ij")
    return r.ravel(), c.ravel()


def importance_sampled_pfa(p_fa, frames, method="ca", wf=None, seed=13, theta=0.9):
    """P_fa of the radar chain's CFAR (radar_image, cfar_threshold) measured by importance
    sampling: the frames' noise has variance θ < 1 (small noise estimates, which carry
    the false alarms, become more common; 0.9 gave the smallest error of 1, 0.95, 0.9
    and 0.8, the log-likelihood ratio spreading with (1/θ − 1)·√K) and each
    :func:`lattice` cell gets extra variance c along its own direction (its variance
    θ + c about the threshold). The cell's test
    reads only the K = N_T + 1 complex cells Y of its footprint, of covariance R under
    the true density and Q = θR + c·r r^H (r = R's first column) under this one, so each
    crossing counts with the likelihood ratio (det Q/det R)·exp(Y^H Q⁻¹Y − Y^H R⁻¹Y)."""
    wf = wf or Waveform()
    n, m = wf.n_subcarriers, wf.n_symbols
    rng = np.random.default_rng(seed)
    rows, cols = lattice(wf)
    corr = cell_correlation("hann", "hann", n, m)
    offsets = np.vstack([[0, 0], training_offsets(RADAR_GUARD, RADAR_TRAIN)])
    cov = cell_covariance(offsets, corr)
    alpha, mean_ratio = cfar_alpha(RADAR_GUARD, RADAR_TRAIN, p_fa, method, correlation=corr)
    tilt = theta * (alpha * mean_ratio - 1.0)
    cov_q = theta * cov + tilt * np.outer(cov[:, 0], cov[:, 0].conj())
    log_det = np.linalg.slogdet(cov_q)[1] - np.linalg.slogdet(cov)[1]
    at_r = (rows[:, None] + offsets[None, :, 0]) % n
    at_c = (cols[:, None] + offsets[None, :, 1]) % m
    total = []
    for _ in range(frames):
        f = tilted_noise(rng, wf, rows, cols, theta, tilt)
        img = radar_image(f, wf)
        thr, _, _ = cfar_threshold(img.power, RADAR_GUARD, RADAR_TRAIN, p_fa, method,
                                   correlation=img.correlation)
        x = complex_image(f)
        np.testing.assert_allclose(np.abs(x) ** 2, img.power, rtol=1e-9, atol=1e-12)
        y = x[at_r, at_c].T  # (K, cells)
        quad_p = np.real(np.sum(y.conj() * np.linalg.solve(cov, y), axis=0))
        quad_q = np.real(np.sum(y.conj() * np.linalg.solve(cov_q, y), axis=0))
        weight = np.exp(log_det + quad_q - quad_p)
        total.append(np.where(img.power[rows, cols] > thr[rows, cols], weight, 0.0))
    total = np.concatenate(total)
    return total.mean(), total.std() / math.sqrt(total.size) / total.mean()


def test_ca_false_alarm_rate_1e6_by_importance_sampling():
    estimate, rel = importance_sampled_pfa(1e-6, 16)
    assert rel < 0.08
    assert 1 / 1.5 < estimate / 1e-6 < 1.5


def test_os_false_alarm_rate_on_noise_frames():
    """OS-CFAR with its sampled α: counted at 1e-4 (0.8 M cells of 512 × 128 frames) and
    importance-sampled at 1e-6, within a factor 1.5."""
    wf = small_waveform(n=512, m=128)
    rng = np.random.default_rng(17)
    hits = cells = 0
    for img in noise_images(rng, 12, wf):
        thr, _, _ = cfar_threshold(img.power, RADAR_GUARD, RADAR_TRAIN, 1e-4, "os",
                                   correlation=img.correlation)
        hits += np.count_nonzero(img.power > thr)
        cells += img.power.size
    assert 1 / 1.5 < hits / cells / 1e-4 < 1.5
    estimate, rel = importance_sampled_pfa(1e-6, 12, "os", wf)
    assert rel < 0.15
    assert 1 / 1.5 < estimate / 1e-6 < 1.5


def test_cube_false_alarm_rate_on_noise_frames():
    """The cube's CFAR (TDM 2 × 6, Hann range–Doppler spectra, 16 azimuth bins): raw
    crossings on noise-only cubes within a factor 1.5 of 1e-4 and 1e-5."""
    wf = small_waveform(n=256, m=128)
    d = random_symbols(wf, 0)
    vp = np.zeros((12, 3))
    vp[:, 1] = np.arange(12) * wf.wavelength / 2
    rng = np.random.default_rng(19)
    p_fas = (1e-4, 1e-5)
    hits = dict.fromkeys(p_fas, 0)
    cells = 0
    for _ in range(40):
        rd = tdm_range_doppler(white(rng, (6, 256, 128)) * d[None], d, wf, 2)
        cube = radar_cube(rd, vp, wf.wavelength)
        for p in p_fas:
            thr, _ = cube_threshold(cube, RADAR_GUARD, RADAR_TRAIN, p)
            hits[p] += np.count_nonzero(cube.power > thr)
        cells += cube.power.size
    for p in p_fas:
        assert 1 / 1.5 < hits[p] / cells / p < 1.5, (p, hits[p] / cells)


def snr_for(pd, alpha, cov):
    """SNR (dB) of a Swerling-1 target in the cell under test for detection probability
    ``pd`` (bisection on the closed form)."""
    lo, hi = -10.0, 40.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if ca_cfar_detection_probability(alpha, cov, 10 ** (mid / 10)) < pd:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


@pytest.mark.parametrize(("p_fa", "bound_db"), [(1e-4, 0.3), (1e-5, 0.3), (1e-6, 0.3)])
def test_detection_probability_near_the_old_detectors(p_fa, bound_db):
    """Swerling-1 target on a cell of the Hann image: the SNR for P_d = 0.5 and 0.9 with
    the radar shape and α for correlated cells against the old shape with α for
    independent cells (which bought its P_d with 2.3-5.3x the false alarms). Within
    0.3 dB at every P_fa (0.21, 0.24, 0.28 dB at P_d = 0.5 with the (1, 1)/(5, 4) band;
    the (2, 1)/(4, 4) band cost 0.34 dB at 1e-6, docs/dsp.md §5); the old shape with
    the corrected α costs 0.7 dB."""
    corr = cell_correlation("hann", "hann", 1024, 256)
    new_cov = hann_covariance(RADAR_GUARD, RADAR_TRAIN)
    old_cov = hann_covariance(OLD_GUARD, OLD_TRAIN)
    alpha_new, _ = cfar_alpha(RADAR_GUARD, RADAR_TRAIN, p_fa, correlation=corr)
    alpha_old = ca_cfar_alpha(old_cov.shape[0] - 1, p_fa)
    assert ca_cfar_pfa_correlated(alpha_old, old_cov) > 2 * p_fa
    alpha_same, _ = cfar_alpha(OLD_GUARD, OLD_TRAIN, p_fa, correlation=corr)
    for pd in (0.5, 0.9):
        old = snr_for(pd, alpha_old, old_cov)
        assert snr_for(pd, alpha_new, new_cov) - old < bound_db
        assert snr_for(pd, alpha_same, old_cov) - old > 0.45  # why the band grew


def targets(rng, wf, rows, cols, snr):
    """White unit noise F plus a Swerling-1 point target on the grid at every cell (rows,
    cols) of the critically sampled image, of mean SNR ``snr`` in its cell: amplitude
    CN(0, snr/G), G = (Σa Σb)²/(Σa² Σb²) the windows' coherent gain (Hann: NM·4/9); its
    response reaches one cell either side, inside the guard cells."""
    n, m = wf.n_subcarriers, wf.n_symbols
    q = (cols - m // 2) % m
    grid = np.zeros((n, m), complex)
    grid[rows, q] = math.sqrt(snr / (n * m * 4 / 9)) * white(rng, rows.size)
    return white(rng, (n, m)) + np.fft.ifft(np.fft.fft(grid, axis=0), axis=1) * m


def test_detection_probability_closed_form_against_simulation():
    """Swerling-1 targets on a lattice of cells of noise frames, through radar_image and
    the CFAR: the fraction detected matches the closed form (binomial 4σ)."""
    wf = small_waveform(n=512, m=128)
    corr = cell_correlation("hann", "hann", 512, 128)
    alpha, _ = cfar_alpha(RADAR_GUARD, RADAR_TRAIN, 1e-6, correlation=corr)
    snr = 10 ** (16.0 / 10)
    want = ca_cfar_detection_probability(alpha, hann_covariance(RADAR_GUARD, RADAR_TRAIN,
                                                                512, 128), snr)
    assert 0.2 < want < 0.8
    rng = np.random.default_rng(23)
    rows, cols = lattice(wf)
    found = trials = 0
    for _ in range(8):
        img = radar_image(targets(rng, wf, rows, cols, snr), wf)
        thr, _, _ = cfar_threshold(img.power, RADAR_GUARD, RADAR_TRAIN, 1e-6,
                                   correlation=img.correlation)
        found += np.count_nonzero(img.power[rows, cols] > thr[rows, cols])
        trials += rows.size
    assert abs(found / trials - want) < 4 * math.sqrt(want * (1 - want) / trials)
