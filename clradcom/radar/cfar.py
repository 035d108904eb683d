"""2-D CFAR detection on the square-law radar image, peak interpolation, detection table.

- CA-CFAR: T = α·mean(training cells), α = N_T(P_fa^{−1/N_T} − 1) (Richards, Fundamentals
  of Radar Signal Processing, ch. 6; exact for exponential (square-law Gaussian) noise in
  independent cells).
- OS-CFAR (Rohling, IEEE T-AES 19(4), 1983): T = α·x_(k), the k-th smallest training cell;
  P_fa = Π_{i=0}^{k−1} (N_T − i)/(N_T − i + α), solved for α.
- Correlated cells (a window, zero padding; the map's :class:`CellCorrelation`): those
  closed forms overstate the training cells' information (a Hann image's CA-CFAR gave
  2.3-5.3x its P_fa), so α is designed for the correlation (:func:`cfar_alpha`): CA by
  the exact P_fa of a Hermitian form in correlated Gaussian cells (Turin, Biometrika 47,
  1960), OS by importance-sampled conditional Monte Carlo (docs/dsp.md §5).
- Training cells: a rectangle of half-size guard+train around the cell under test, minus
  the guard rectangle; the map wraps around on both axes (range and Doppler are DFT axes,
  so the map is periodic).  Sizes are in image bins: with zero padding, scale them by the
  padding factor.
- Training sums are sums of non-negative cells (two separable correlations over disjoint
  bands), never a running sum or an outer-minus-inner difference: those cancel, and beside
  a strong peak their rounding error (~1e-16 of the peak) exceeds, or turns negative, the
  training mean of a noiseless image's empty cells.
- Numerical floor: an image computed from data of relative accuracy ε (L2 norm; the
  synthesis tolerance, or floating-point rounding) has an error of total energy at most
  ~ε² times its own, so no cell's noise estimate is taken below ε²·Σ power
  (:func:`numerical_floor`): a noiseless frame's rounding and NUFFT residue never counts
  as a detection, and any real noise (σ² ≫ ε²·NM·σ²) is never touched.
- Peaks: cells above threshold that are the maximum of their neighbourhood; their position
  is refined by a 3-point parabola on the dB values along each axis (docs/dsp.md §5), and
  to the periodogram maximum by ``clradcom.radar.estimation`` in ``pipeline.process``.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import ndimage, stats
from scipy.optimize import brentq

from clradcom.errors import ArgumentError
from clradcom.radar.processing import CellCorrelation, RadarImage

DETECTION_DTYPE = np.dtype([
    ("range_m", float), ("velocity_mps", float), ("power_db", float), ("snr_db", float),
    ("range_bin", float), ("doppler_bin", float),
])


#: guard and training half-sizes (range, Doppler bins) of the radar chain's CFAR
#: (``pipeline.process``, ``cube.detect_cube``) on the critically sampled Hann image
#: (docs/dsp.md §5: chosen so that, at its design P_fa, the detection probability is
#: within 0.3 dB of the former (2, 1)/(4, 2) detector, which had 3-5x its P_fa, and the
#: street keeps its cars and buildings)
RADAR_GUARD = (1, 1)
RADAR_TRAIN = (5, 4)


def _check_pfa(p_fa):
    if not (isinstance(p_fa, int | float | np.floating) and 0.0 < p_fa < 1.0):
        raise ArgumentError(f"p_fa must lie in (0, 1), got {p_fa!r}")
    return float(p_fa)


def ca_cfar_alpha(n_train: int, p_fa: float) -> float:
    """α = N_T (P_fa^{−1/N_T} − 1) for cell-averaging CFAR on square-law power."""
    if isinstance(n_train, bool) or not isinstance(n_train, int | np.integer) or n_train < 1:
        raise ArgumentError(f"n_train must be a positive integer, got {n_train!r}")
    p_fa = _check_pfa(p_fa)
    return float(n_train * (p_fa ** (-1.0 / n_train) - 1.0))


def os_cfar_pfa(n_train: int, k: int, alpha: float) -> float:
    """Rohling's P_fa = Π_{i=0}^{k−1} (N_T − i)/(N_T − i + α)."""
    i = np.arange(k)
    return float(np.exp(np.sum(np.log(n_train - i) - np.log(n_train - i + alpha))))


def os_cfar_alpha(n_train: int, k: int, p_fa: float) -> float:
    """Scale α that gives OS-CFAR with the k-th smallest of N_T cells the design P_fa."""
    if isinstance(n_train, bool) or not isinstance(n_train, int | np.integer) or n_train < 1:
        raise ArgumentError(f"n_train must be a positive integer, got {n_train!r}")
    if isinstance(k, bool) or not isinstance(k, int | np.integer) or not 1 <= k <= n_train:
        raise ArgumentError(f"rank k must be an integer in [1, {n_train}], got {k!r}")
    p_fa = _check_pfa(p_fa)
    target = math.log(p_fa)

    def f(log_alpha):
        return math.log(os_cfar_pfa(n_train, k, math.exp(log_alpha))) - target

    hi = 1.0
    while f(hi) > 0:  # P_fa falls monotonically with α
        hi += 2.0
    return float(math.exp(brentq(f, -30.0, hi, xtol=1e-13)))


def _pair(name, value):
    v = (value, value) if np.isscalar(value) else tuple(value)
    if len(v) != 2 or any(isinstance(x, bool) or not isinstance(x, int | np.integer) or x < 0
                          for x in v):
        raise ArgumentError(f"{name} must be a non-negative int or a pair of them, got {value!r}")
    return int(v[0]), int(v[1])


def training_footprint(guard=(2, 2), train=(4, 4)) -> np.ndarray:
    """Boolean mask of the training cells (outer rectangle minus guard rectangle)."""
    g, t = _pair("guard", guard), _pair("train", train)
    h = (g[0] + t[0], g[1] + t[1])
    fp = np.ones((2 * h[0] + 1, 2 * h[1] + 1), bool)
    fp[h[0] - g[0]:h[0] + g[0] + 1, h[1] - g[1]:h[1] + g[1] + 1] = False
    return fp


def training_offsets(guard=(2, 2), train=(4, 4)) -> np.ndarray:
    """(N_T, 2) offsets (range, Doppler bins) of the training cells from the cell under
    test, in the order of :func:`training_footprint`."""
    fp = training_footprint(guard, train)
    rows, cols = np.nonzero(fp)
    return np.stack([rows - fp.shape[0] // 2, cols - fp.shape[1] // 2], axis=1)


def cell_covariance(offsets, correlation: CellCorrelation) -> np.ndarray:
    """Unit-variance noise covariance of the cells at ``offsets`` (K, 2) of a map whose
    cells correlate as ``correlation``: R_ij = ρ_r(Δr)·ρ_d(Δd), Δ = offset_i − offset_j
    taken cyclically (the map wraps)."""
    o = np.asarray(offsets, dtype=int).reshape(-1, 2)
    rho_r, rho_d = np.asarray(correlation.range), np.asarray(correlation.doppler)
    lag_r = (o[:, None, 0] - o[None, :, 0]) % rho_r.size
    lag_d = (o[:, None, 1] - o[None, :, 1]) % rho_d.size
    return rho_r[lag_r] * rho_d[lag_d]


def _hermitian_sqrt(matrix) -> np.ndarray:
    w, v = np.linalg.eigh(matrix)
    return (v * np.sqrt(np.clip(w, 0.0, None))) @ v.conj().T


def _ca_log_pfa(covariance):
    """log P_fa(α) of CA-CFAR on circular Gaussian cells of unit variance and covariance
    R (cell under test first, then the N_T training cells), exactly (docs/dsp.md §5):
    the test |X₀|² − β Σ|X_t|² > 0 (β = α/N_T) is a Hermitian form X^H A X; with
    X = R^{1/2} Y, Y white, it is Σ λ_i |Y_i|², λ the eigenvalues of R^{1/2} A R^{1/2}:
    one positive (λ₊, the inertia of A) and N_T non-positive (−μ_k), so P_fa =
    P(λ₊E₀ > Σ μ_k E_k) = Π_k 1/(1 + μ_k/λ₊) for independent unit exponentials E.
    R^{1/2} A R^{1/2} = s s^H − β G (s the first column of R^{1/2}, G the Gram matrix of the
    others) is a rank-one change of −βG: with G = U diag(γ) U^H and c = U^H s, λ₊ is the
    positive root of Σ|c_i|²/(x + βγ_i) = 1 (secular equation, Golub 1973) and
    Π_k (λ₊ + μ_k) is the derivative of det(x − s s^H + βG) there, so
    log P_fa = N_T log λ₊ − Σ log(λ₊ + βγ_i) − log Σ|c_i|²/(λ₊ + βγ_i)²: one
    eigendecomposition for all α. Where R is singular (a heavily padded map) the roots
    are found by a full eigendecomposition per α instead."""
    root = _hermitian_sqrt(covariance)
    s0 = root[:, 0]
    gram = root[:, 1:] @ root[:, 1:].conj().T
    n_t = covariance.shape[0] - 1
    gamma, u = np.linalg.eigh(gram)
    gamma = np.clip(gamma, 0.0, None)
    c2 = np.abs(u.conj().T @ s0) ** 2

    def by_eigenvalues(beta):
        ev = np.linalg.eigvalsh(np.outer(s0, s0.conj()) - beta * gram)
        return -float(np.sum(np.log1p(np.clip(-ev[:-1], 0.0, None) / ev[-1])))

    def log_pfa(alpha):
        beta = alpha / n_t
        x_lo = 1e-13

        def secular(x):
            return float(np.sum(c2 / (x + beta * gamma))) - 1.0

        if secular(x_lo) <= 0.0:  # no root above x_lo: R (near) singular
            return by_eigenvalues(beta)
        # Σ|c_i|²/x ≥ the sum, so λ₊ ≤ Σ|c_i|² = R₀₀
        lam = brentq(secular, x_lo, float(np.sum(c2)) * (1.0 + 1e-9), xtol=1e-15,
                     rtol=1e-14)
        d = lam + beta * gamma
        return (n_t * math.log(lam) - float(np.sum(np.log(d)))
                - math.log(float(np.sum(c2 / d**2))))

    return log_pfa


def ca_cfar_pfa_correlated(alpha: float, covariance) -> float:
    """Exact P_fa of CA-CFAR with scale α on Gaussian cells of covariance ``covariance``
    (unit diagonal; cell under test first): :func:`_ca_log_pfa`."""
    return math.exp(_ca_log_pfa(np.asarray(covariance, dtype=complex))(float(alpha)))


def ca_cfar_detection_probability(alpha: float, covariance, snr: float) -> float:
    """Exact P_d of CA-CFAR with scale α for a Swerling-1 target of mean SNR ``snr`` in the
    cell under test alone (a target on the grid, whose window response stays inside the
    guard cells) on Gaussian noise cells of covariance ``covariance``: the P_fa form with
    the cell under test's variance 1 + snr."""
    cov = np.array(covariance, dtype=complex)
    if not (math.isfinite(snr) and snr >= 0.0):
        raise ArgumentError("must be finite and >= 0", argument="snr", value=snr)
    cov[0, 0] += snr
    return math.exp(_ca_log_pfa(cov)(float(alpha)))


#: importance-sampled conditional Monte Carlo (OS-CFAR on correlated cells): samples to
#: start with, the most it may take, drawn a chunk at a time, the relative standard error
#: of P_fa it stops at (5 %: α then within ~0.5 %, 0.02 dB, as P_fa ∝ α^{−10} there), its
#: seed
SAMPLES_START = 8192
SAMPLES_MAX = 1 << 17
SAMPLES_CHUNK = 8192
SAMPLED_PFA_REL_ERROR = 0.05
SAMPLING_SEED = 20261128


def sampled_pfa(covariance, rank: int | None, n_samples: int, theta: float = 1.0,
                seed: int = SAMPLING_SEED):
    """P_fa(α) of CFAR on Gaussian cells of covariance R (cell under test first), by
    importance-sampled conditional Monte Carlo (docs/dsp.md §5): training cells drawn
    with covariance θR (θ < 1 makes the small noise estimates that carry the false alarms
    common; likelihood ratio θ^{N_T} e^{(1−θ)|z|²} per draw z), and for each draw the cell
    under test's exact conditional tail P(|X₀|² > α·s | X_t): X₀ | X_t is circular Gaussian
    of mean R₀ₜR_t⁻¹X_t and variance 1 − R₀ₜR_t⁻¹Rₜ₀, a non-central χ² with 2 degrees of
    freedom. ``rank`` k: s = the k-th smallest training cell (OS); None: s = their mean
    (CA). Returns (log_pfa(α), relative_standard_error(α), E[s]) (E[s] under the true
    distribution, for the noise estimate)."""
    cov = np.asarray(covariance, dtype=complex)
    n_t = cov.shape[0] - 1
    r_t = cov[1:, 1:]
    w, v = np.linalg.eigh(r_t)
    keep = w > 1e-10 * w[-1]  # a pseudo-inverse: padded maps make R_t near singular
    coef = cov[0, 1:] @ ((v[:, keep] / w[keep]) @ v[:, keep].conj().T)
    var = float(np.real(1.0 - coef @ cov[1:, 0]))
    root_t = (v * np.sqrt(np.clip(w, 0.0, None))) @ v.conj().T
    rng = np.random.default_rng(seed)
    stat, mean2, log_w = (np.empty(n_samples) for _ in range(3))
    for start in range(0, n_samples, SAMPLES_CHUNK):  # a chunk at a time: little memory
        size = min(SAMPLES_CHUNK, n_samples - start)
        z = (rng.standard_normal((size, n_t))
             + 1j * rng.standard_normal((size, n_t))) / math.sqrt(2.0)
        x_t = z @ root_t.T
        power = x_t.real**2 + x_t.imag**2
        part = slice(start, start + size)
        stat[part] = (np.partition(power, rank - 1, axis=1)[:, rank - 1] if rank is not None
                      else power.mean(axis=1))
        mean2[part] = np.abs(x_t @ coef) ** 2
        log_w[part] = np.sum(z.real**2 + z.imag**2, axis=1)
    mean_stat = float(np.mean(stat))
    stat *= theta
    mean2 *= theta
    log_w = n_t * math.log(theta) + (1.0 - theta) * log_w
    correlated_cut = var > 0.0 and float(np.max(mean2)) > 1e-24 * var

    def log_terms(alpha):
        t = alpha * stat
        if var <= 1e-12:  # the cell under test is fixed by its training cells
            tail = np.where(mean2 > t, 0.0, -np.inf)
        elif correlated_cut:
            tail = stats.ncx2.logsf(2.0 * t / var, 2, 2.0 * mean2 / var)
        else:
            tail = -t / var
        return log_w + tail

    def log_pfa(alpha):
        lt = log_terms(alpha)
        top = float(np.max(lt))
        return top + math.log(float(np.mean(np.exp(lt - top))))

    def rel_error(alpha):
        v = np.exp(log_terms(alpha) - log_pfa(alpha))
        return float(np.std(v) / math.sqrt(n_samples))

    return log_pfa, rel_error, mean_stat


def _solve_alpha(log_pfa, p_fa: float, start: float) -> float:
    """α with log_pfa(α) = log p_fa (log_pfa falls monotonically with α)."""
    target = math.log(p_fa)

    def f(log_alpha):
        return log_pfa(math.exp(log_alpha)) - target

    lo = hi = math.log(start)
    while f(lo) < 0.0:
        lo -= 0.5
    while f(hi) > 0.0:
        hi += 0.5
    return float(math.exp(brentq(f, lo, hi, xtol=1e-12)))


_CORRELATED_DESIGNS: dict = {}


def _footprint_lags(guard, train, correlation: CellCorrelation):
    """The correlation at the lags a footprint spans, rounded (a cache key), and whether
    all of them but lag 0 vanish (independent cells)."""
    g, t = _pair("guard", guard), _pair("train", train)
    out = []
    for rho, half in ((correlation.range, g[0] + t[0]), (correlation.doppler, g[1] + t[1])):
        rho = np.asarray(rho, dtype=complex)
        if rho.ndim != 1 or rho.size == 0 or abs(rho[0] - 1.0) > 1e-9:
            raise ArgumentError("must be 1 at lag 0 (a correlation coefficient)",
                                argument="correlation", value=f"{rho[:1]!r}")
        out.append(np.round(rho[np.arange(-2 * half, 2 * half + 1) % rho.size], 12))
    independent = all(np.max(np.abs(np.delete(x, x.size // 2))) < 1e-12 for x in out)
    return out, independent


def cfar_alpha(guard=(2, 2), train=(4, 4), p_fa: float = 1e-6, method: str = "ca",
               rank: int | None = None, correlation: CellCorrelation | None = None):
    """(α, E[s]/σ²) of CFAR with this footprint on cells that correlate as
    ``correlation`` (None: independent), for the design ``p_fa``: the threshold is α·s,
    s the training mean (CA) or the ``rank``-th smallest training cell (OS, default
    round(¾N_T)); E[s]/σ² turns s into a noise estimate.

    Independent cells: Richards' and Rohling's closed forms. Correlated cells (a window,
    zero padding): CA exactly (:func:`_ca_log_pfa`); OS by importance-sampled conditional
    Monte Carlo (:func:`sampled_pfa`, fixed seed, samples added until the relative
    standard error of P_fa at the solution is under 5 %). Computed once per footprint,
    P_fa and correlation, then cached (docs/dsp.md §5)."""
    p_fa = _check_pfa(p_fa)
    if method not in ("ca", "os"):
        raise ArgumentError(f"method must be 'ca' or 'os', got {method!r}")
    offsets = training_offsets(guard, train)
    n_t = offsets.shape[0]
    if n_t == 0:
        raise ArgumentError(f"train={train!r} leaves no training cells")
    k = None
    if method == "os":
        k = int(round(0.75 * n_t)) if rank is None else rank
        if isinstance(k, bool) or not isinstance(k, int | np.integer) or not 1 <= k <= n_t:
            raise ArgumentError(f"rank k must be an integer in [1, {n_t}], got {k!r}")
        k = int(k)
    independent = correlation is None
    if not independent:
        lags, independent = _footprint_lags(guard, train, correlation)
    if independent:
        if k is None:
            return ca_cfar_alpha(n_t, p_fa), 1.0
        return os_cfar_alpha(n_t, k, p_fa), float(np.sum(1.0 / np.arange(n_t - k + 1, n_t + 1)))
    key = (method, _pair("guard", guard), _pair("train", train), k, p_fa,
           lags[0].tobytes(), lags[1].tobytes())
    if key not in _CORRELATED_DESIGNS:
        half = (lags[0].size // 2, lags[1].size // 2)
        cov = cell_covariance(np.vstack([[0, 0], offsets]),
                              CellCorrelation(np.roll(lags[0], -half[0]),
                                              np.roll(lags[1], -half[1])))
        if k is None:
            alpha = _solve_alpha(_ca_log_pfa(cov), p_fa, ca_cfar_alpha(n_t, p_fa))
            _CORRELATED_DESIGNS[key] = (alpha, 1.0)
        else:
            # half the tilt (in log θ) that makes CA on independent cells a zero-variance
            # estimate: the smallest standard error of a scan (Hann, N_T = 128, 1e-4 and
            # 1e-6: 0.034 and 0.077 at 8,192 draws against 0.038 and 0.104 with the full
            # tilt, 0.058 and 0.19 with twice it)
            theta = (1.0 + ca_cfar_alpha(n_t, p_fa) / n_t) ** -0.5
            n = SAMPLES_START
            while True:
                log_pfa, rel_error, mean_stat = sampled_pfa(cov, k, n, theta)
                alpha = _solve_alpha(log_pfa, p_fa, os_cfar_alpha(n_t, k, p_fa))
                if rel_error(alpha) <= SAMPLED_PFA_REL_ERROR or n >= SAMPLES_MAX:
                    break
                n *= 4
            _CORRELATED_DESIGNS[key] = (alpha, mean_stat)
    return _CORRELATED_DESIGNS[key]


def _ring(half: int, guard: int) -> np.ndarray:
    """1-D 0/1 kernel of length 2·half + 1 with the central 2·guard + 1 taps zero."""
    k = np.ones(2 * half + 1)
    k[half - guard:half + guard + 1] = 0.0
    return k


def training_sums(power, guard=(2, 2), train=(4, 4)) -> np.ndarray:
    """Sum of the training cells around every cell (wrapping), computed without
    cancellation: the rows outside the guard band over the full width, plus the guard
    rows outside the guard columns, each a separable correlation of non-negative cells
    with 0/1 kernels (relative error ~1e-15 of the sum itself, whatever lies in the
    guard)."""
    g, t = _pair("guard", guard), _pair("train", train)
    h = (g[0] + t[0], g[1] + t[1])
    pw = np.asarray(power, dtype=float)
    # A cube's (N, M, A...) cells: its range and Doppler axes moved last, so that the
    # correlations run along contiguous memory (a third less time on a 12-channel cube;
    # the same sums bit for bit). An image (N, M) is already in that order.
    pw = np.ascontiguousarray(np.moveaxis(pw, (0, 1), (-2, -1)))
    bands = ndimage.correlate1d(pw, _ring(h[0], g[0]), axis=-2, mode="wrap")
    bands = ndimage.correlate1d(bands, np.ones(2 * h[1] + 1), axis=-1, mode="wrap")
    sides = ndimage.correlate1d(pw, np.ones(2 * g[0] + 1), axis=-2, mode="wrap")
    sides = ndimage.correlate1d(sides, _ring(h[1], g[1]), axis=-1, mode="wrap")
    return np.moveaxis(bands + sides, (-2, -1), (0, 1))


def rounding_accuracy(cells: int) -> float:
    """Relative L2 accuracy of a float64 FFT image of ``cells`` cells: log2(cells)·u,
    u = 2⁻⁵³ (Higham, *Accuracy and Stability of Numerical Algorithms*, 2nd ed., §24.1,
    Theorem 24.2: ‖ŷ − y‖/‖y‖ ≲ log2(n)·u for the radix-2 Cooley–Tukey FFT)."""
    return float(max(math.log2(max(int(cells), 2)), 1.0) * np.finfo(float).eps / 2)


def numerical_floor(power, accuracy: float | None = None) -> float:
    """Lowest noise power a cell of ``power`` can be told apart from: ε²·Σ power, where ε
    is the relative L2 accuracy of the data (default :func:`rounding_accuracy`).  The
    image's error has total energy ≤ ~ε²·Σ power, so this bounds the error of any single
    cell, even if all of it fell there."""
    pw = np.asarray(power, dtype=float)
    eps = rounding_accuracy(pw.size) if accuracy is None else float(accuracy)
    if not (math.isfinite(eps) and 0.0 <= eps < 1.0):
        raise ArgumentError("must lie in [0, 1)", argument="accuracy", value=accuracy)
    eps = max(eps, rounding_accuracy(pw.size))
    return float(eps**2 * np.sum(pw))


def cfar_threshold(power, guard=(2, 2), train=(4, 4), p_fa: float = 1e-6,
                   method: str = "ca", rank: int | None = None,
                   accuracy: float | None = None,
                   correlation: CellCorrelation | None = None):
    """CFAR threshold and noise-power estimate for every cell of a square-law map.

    Returns (threshold, noise, alpha): arrays shaped like ``power`` and the scale α
    (:func:`cfar_alpha`: for the map's cell ``correlation``, None for independent cells).
    ``noise`` is the per-cell noise estimate (CA: training mean; OS: x_(k)/E[x_(k)/σ²],
    E[x_(k)/σ²] = Σ_{i=N_T−k+1}^{N_T} 1/i for independent exponential cells, sampled for
    correlated ones).  ``rank`` (OS only) is k, default round(0.75·N_T) (Rohling).
    ``accuracy`` is the relative accuracy of the data (:func:`numerical_floor`; default
    float64 rounding): no noise estimate is taken below the floor it sets.
    """
    pw = np.asarray(power, dtype=float)
    if pw.ndim != 2:
        raise ArgumentError(f"power must be a 2-D map, got shape {pw.shape}")
    if not np.all(np.isfinite(pw)) or (pw < 0).any():
        raise ArgumentError("power must be finite and non-negative (square-law, not dB)")
    if method not in ("ca", "os"):
        raise ArgumentError(f"method must be 'ca' or 'os', got {method!r}")
    fp = training_footprint(guard, train)
    n_t = int(fp.sum())
    if n_t == 0:
        raise ArgumentError(f"train={train!r} leaves no training cells")
    if fp.shape[0] > pw.shape[0] or fp.shape[1] > pw.shape[1]:
        raise ArgumentError(f"CFAR window {fp.shape} is larger than the map {pw.shape}")
    _check_correlation_shape(correlation, pw.shape)
    alpha, mean_ratio = cfar_alpha(guard, train, p_fa, method, rank, correlation)
    floor = numerical_floor(pw, accuracy)
    if method == "ca":
        noise = np.maximum(training_sums(pw, guard, train) / n_t, floor)
        return alpha * noise, noise, alpha
    k = int(round(0.75 * n_t)) if rank is None else rank
    xk = ndimage.rank_filter(pw, rank=k - 1, footprint=fp, mode="wrap")
    noise = np.maximum(xk / mean_ratio, floor)
    return alpha * mean_ratio * noise, noise, alpha


def _check_correlation_shape(correlation, shape):
    if correlation is None:
        return
    if not isinstance(correlation, CellCorrelation):
        raise ArgumentError("must be a CellCorrelation or None", argument="correlation",
                            value=type(correlation).__name__)
    sizes = (np.size(correlation.range), np.size(correlation.doppler))
    if sizes != tuple(shape[:2]):
        raise ArgumentError(f"must give one lag per cell of the {shape[0]} x {shape[1]} "
                            "map", argument="correlation", value=f"lengths {sizes}")


def parabolic_offset(y_minus, y0, y_plus):
    """Vertex offset (bins, in [−0.5, 0.5]) and height of the parabola through 3 points."""
    den = y_minus - 2.0 * y0 + y_plus
    with np.errstate(divide="ignore", invalid="ignore"):
        delta = np.where(den < 0, 0.5 * (y_minus - y_plus) / den, 0.0)
    delta = np.clip(delta, -0.5, 0.5)
    return delta, y0 - 0.25 * (y_minus - y_plus) * delta


def interpolate_peaks(power, rows, cols):
    """Parabolic (on dB) sub-bin refinement of peaks at integer (rows, cols), wrapping at
    the edges.  Returns (row_float, col_float, peak_db)."""
    pdb = 10.0 * np.log10(np.maximum(np.asarray(power, float), 1e-300))
    n, m = pdb.shape
    rows = np.asarray(rows, int)
    cols = np.asarray(cols, int)
    y0 = pdb[rows, cols]
    dr, hr = parabolic_offset(pdb[(rows - 1) % n, cols], y0, pdb[(rows + 1) % n, cols])
    dc, hc = parabolic_offset(pdb[rows, (cols - 1) % m], y0, pdb[rows, (cols + 1) % m])
    return rows + dr, cols + dc, hr + hc - y0


def detect(image: RadarImage, guard=(2, 2), train=(4, 4), p_fa: float = 1e-6,
           method: str = "ca", rank: int | None = None, neighbourhood=(3, 3),
           max_detections: int | None = None, accuracy: float | None = None) -> np.ndarray:
    """CFAR detections with local-maximum suppression and sub-bin interpolation.

    ``accuracy``: relative accuracy of the data behind the image (see
    :func:`numerical_floor`; default float64 rounding). The threshold is designed for
    the image's cell correlation (``image.correlation``, which :func:`radar_image`
    records from its windows and zero padding).

    Returns a structured array (``DETECTION_DTYPE``): range_m, velocity_mps, power_db
    (interpolated peak, image units), snr_db (peak over the CFAR noise estimate), range_bin,
    doppler_bin (fractional indices into ``image.power``), strongest first.
    """
    power, r_axis, v_axis = image.power, image.range_m, image.velocity_mps
    thr, noise, _ = cfar_threshold(power, guard, train, p_fa, method, rank, accuracy,
                                   image.correlation)
    nb = _pair("neighbourhood", neighbourhood)
    local_max = power >= ndimage.maximum_filter(power, size=nb, mode="wrap")
    rows, cols = np.nonzero((power > thr) & local_max)
    out = np.zeros(rows.size, DETECTION_DTYPE)
    if rows.size == 0:
        return out
    rf, cf, peak_db = interpolate_peaks(power, rows, cols)
    dr = r_axis[1] - r_axis[0] if r_axis.size > 1 else 0.0
    dv = v_axis[1] - v_axis[0] if v_axis.size > 1 else 0.0
    out["range_m"] = r_axis[0] + rf * dr
    out["velocity_mps"] = v_axis[0] + cf * dv
    out["power_db"] = peak_db
    out["snr_db"] = peak_db - 10.0 * np.log10(np.maximum(noise[rows, cols], 1e-300))
    out["range_bin"] = rf
    out["doppler_bin"] = cf
    out = out[np.argsort(-out["power_db"], kind="stable")]
    return out[:max_detections] if max_detections is not None else out


def cfar_false_alarms(power, guard=(2, 2), train=(4, 4), p_fa: float = 1e-6,
                      method: str = "ca", rank: int | None = None,
                      correlation: CellCorrelation | None = None) -> int:
    """Number of raw threshold crossings (no peak suppression): for noise-only maps this
    divided by the cell count estimates the realised P_fa."""
    thr, _, _ = cfar_threshold(power, guard, train, p_fa, method, rank,
                               correlation=correlation)
    return int(np.count_nonzero(np.asarray(power) > thr))
