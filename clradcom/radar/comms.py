"""The communication half of RadCom: radar A's OFDM frame received as data by car D.

The frame that radar A sends carries Gray-mapped data (BPSK, QPSK or square QAM) and
known pilots; car D receives it through the traced A->D link (one-way delays, gains and
Dopplers that carry both cars' motion), with its own receiver timing and oscillator
offset, plus white noise.  D's receiver (docs/comms.md):

1. ``synchronise``: symbol timing and carrier frequency offset from the cyclic prefix
   (van de Beek, Sandell & Börjesson, IEEE T-SP 45(7), 1997, the ML estimator with its
   energy term), the offset removed, then the frame's first symbol found by correlating
   with the known pilots;
2. ``estimate_channel``: least squares on the pilots, a robust Wiener filter over
   frequency with a uniform power-delay profile over the cyclic prefix (Li, Cimini &
   Sollenberger, IEEE T-Comm 46(7), 1998; Edfors et al., IEEE T-Comm 46(7), 1998), linear
   interpolation over time between pilot symbols; optionally one decision-directed pass;
3. zero-forcing equalisation (the per-cell MMSE equaliser, scaled to be unbiased, is the
   same), hard decisions, Gray demapping;
4. error vector magnitude, symbol and bit error rates, beside the AWGN closed forms
   (Proakis, Digital Communications, 4th ed., §5.2; Cho & Yoon, IEEE T-Comm 50(7), 2002).

Every function takes and returns plain arrays (plus the ``Waveform`` and the small
``PilotPattern``), so every stage can be tested alone.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, replace

import numpy as np
from scipy.special import erfc

from clradcom.errors import AliasingWarning, ArgumentError, CyclicPrefixWarning
from clradcom.figures import new_figure
from clradcom.radar.interference import stream_signal
from clradcom.radar.synthesis import (
    channel_transfer_function,
    check_paths,
    thermal_noise_power,
)
from clradcom.radar.waveform import Waveform, check_symbols

#: the modulations the receiver decodes with Gray mapping (square QAM per axis)
COMMS_MODULATIONS = ("bpsk", "qpsk", "16qam", "64qam", "256qam")
#: points per axis of each square constellation (BPSK: one real axis of 2)
_SIDE = {"bpsk": 2, "qpsk": 2, "16qam": 4, "64qam": 8, "256qam": 16}


def check_modulation(modulation) -> str:
    mod = str(modulation).lower() if isinstance(modulation, str) else modulation
    if mod not in COMMS_MODULATIONS:
        raise ArgumentError(f"the receiver decodes {COMMS_MODULATIONS} (Gray mapped)",
                            argument="modulation", value=modulation)
    return mod


def bits_per_symbol(modulation: str) -> int:
    mod = check_modulation(modulation)
    side = _SIDE[mod]
    return int(math.log2(side)) * (1 if mod == "bpsk" else 2)


# ----------------------------------------------------------------------------------------
# Gray mapping
# ----------------------------------------------------------------------------------------
def _axis_scale(mod: str) -> float:
    """Distance from 0 to the innermost level: unit mean power for the whole constellation."""
    side = _SIDE[mod]
    mean_level2 = (side * side - 1) / 3.0  # mean of l² over l = ±1, ±3, ..., ±(side−1)
    return 1.0 / math.sqrt(mean_level2 * (1 if mod == "bpsk" else 2))


def _gray_to_index(bits):
    """Level index (0..side−1, lowest level first) of Gray-coded bit groups (..., k)."""
    b = np.asarray(bits, dtype=np.int64)
    binary = np.cumsum(b, axis=-1) % 2  # b_i = g_0 ⊕ ... ⊕ g_i
    weights = 1 << np.arange(b.shape[-1] - 1, -1, -1)
    return binary @ weights


def _index_to_gray(index, k):
    i = np.asarray(index, dtype=np.int64)
    g = i ^ (i >> 1)
    return (g[..., None] >> np.arange(k - 1, -1, -1)) & 1


def gray_map(bits, modulation: str) -> np.ndarray:
    """Constellation points of ``bits`` (..., bits_per_symbol): per axis a Gray-coded PAM
    (in-phase bits first), so neighbouring points differ in one bit; unit mean power, the
    same point set as ``waveform.constellation``."""
    mod = check_modulation(modulation)
    b = np.asarray(bits)
    k = bits_per_symbol(mod)
    if b.shape[-1:] != (k,):
        raise ArgumentError(f"last axis must hold {k} bits per {mod} symbol, got shape "
                            f"{b.shape}", argument="bits")
    side, scale = _SIDE[mod], _axis_scale(mod)
    if mod == "bpsk":
        return (2.0 * _gray_to_index(b) - (side - 1)) * scale + 0j
    half = k // 2
    i = 2.0 * _gray_to_index(b[..., :half]) - (side - 1)
    q = 2.0 * _gray_to_index(b[..., half:]) - (side - 1)
    return scale * (i + 1j * q)


def _slice_axis(x, side, scale):
    return np.clip(np.rint((x / scale + (side - 1)) / 2.0), 0, side - 1).astype(np.int64)


def gray_demap(z, modulation: str):
    """Hard decisions on ``z``: (nearest points, their bits (..., bits_per_symbol)).
    Nearest point per axis (the square constellation's decision regions)."""
    mod = check_modulation(modulation)
    z = np.asarray(z)
    side, scale = _SIDE[mod], _axis_scale(mod)
    k = bits_per_symbol(mod)
    ii = _slice_axis(z.real, side, scale)
    if mod == "bpsk":
        return (2.0 * ii - (side - 1)) * scale + 0j, _index_to_gray(ii, k)
    qq = _slice_axis(z.imag, side, scale)
    points = scale * ((2.0 * ii - (side - 1)) + 1j * (2.0 * qq - (side - 1)))
    bits = np.concatenate([_index_to_gray(ii, k // 2), _index_to_gray(qq, k // 2)], axis=-1)
    return points, bits


# ----------------------------------------------------------------------------------------
# AWGN theory
# ----------------------------------------------------------------------------------------
def q_function(x):
    """Gaussian tail Q(x) = ½ erfc(x/√2)."""
    return 0.5 * erfc(np.asarray(x, dtype=float) / math.sqrt(2.0))


def _pam_error_rates(side: int, a):
    """Per-axis symbol error and Gray bit error probabilities of a ``side``-level PAM with
    levels ±a, ±3a, ... and unit noise standard deviation: decision regions of width 2a,
    exact sums of Q-function differences (the M-QAM BER of Cho & Yoon 2002 per axis)."""
    a = np.asarray(a, dtype=float)
    levels = 2 * np.arange(side) - (side - 1)
    k = int(math.log2(side))
    gray = _index_to_gray(np.arange(side), k)  # (side, k)
    # decision region of index j: ((2j−side)a, (2j−side+2)a), outer ones open
    edges = np.concatenate([[-np.inf], (2 * np.arange(1, side) - side).astype(float), [np.inf]])
    ser = np.zeros_like(a)
    ber = np.zeros_like(a)
    for i, lvl in enumerate(levels):
        # P(decide j | sent i) = Q((lo − lvl)a) − Q((hi − lvl)a)
        lo = (edges[:-1] - lvl)[:, None] * a[None, ...] if a.ndim else (edges[:-1] - lvl) * a
        hi = (edges[1:] - lvl)[:, None] * a[None, ...] if a.ndim else (edges[1:] - lvl) * a
        p = q_function(lo) - q_function(hi)  # (side, ...)
        ser = ser + (1.0 - p[i]) / side
        wrong_bits = (gray != gray[i]).sum(axis=1).astype(float)  # (side,)
        ber = ber + np.tensordot(wrong_bits, p, axes=(0, 0)) / (side * k)
    return ser, ber


def awgn_error_rates(modulation: str, esn0_db):
    """(SER, BER) of coherent detection with Gray mapping in AWGN at Es/N0 = ``esn0_db``:
    BPSK Q(√(2Es/N0)), QPSK BER Q(√(2Eb/N0)) and SER 1 − (1 − Q(√(Es/N0)))², square M-QAM
    SER 1 − (1 − 2(1 − 1/√M)Q(√(3Es/((M−1)N0))))² (Proakis §5.2) and its exact Gray BER
    (Cho & Yoon 2002), all from the per-axis PAM error probabilities."""
    mod = check_modulation(modulation)
    g = 10.0 ** (np.asarray(esn0_db, dtype=float) / 10.0)
    side = _SIDE[mod]
    # half the distance between neighbours over the noise std per axis (N0/2)
    dims = 1 if mod == "bpsk" else 2
    a = _axis_scale(mod) * np.sqrt(2.0 * g)
    ser_axis, ber_axis = _pam_error_rates(side, a)
    if dims == 1:
        return ser_axis, ber_axis
    return 1.0 - (1.0 - ser_axis) ** 2, ber_axis


def awgn_evm(esn0_db):
    """Data-aided rms EVM of an unbiased receiver in AWGN: √(N0/Es)."""
    return 10.0 ** (-np.asarray(esn0_db, dtype=float) / 20.0)


def channel_error_rates(modulation: str, esn0_db, channel):
    """(SER, BER) of a receiver that knows the channel exactly, on a frequency-selective
    (and time-variant) channel ``channel`` H (cells of one frame): the AWGN rates at each
    cell's Es/N0·|H|²/mean|H|², averaged over the cells.  ``esn0_db`` is the mean Es/N0."""
    h2 = np.abs(np.asarray(channel)).ravel() ** 2
    if h2.size == 0 or not np.all(np.isfinite(h2)) or h2.mean() <= 0:
        raise ArgumentError("must hold finite values with some power", argument="channel")
    # a histogram of the cells' gains keeps this cheap for a whole frame
    rel_db = 10.0 * np.log10(np.maximum(h2 / h2.mean(), 1e-30))
    counts, edges = np.histogram(rel_db, bins=400)
    centres = 0.5 * (edges[:-1] + edges[1:])
    w = counts / counts.sum()
    sers, bers = [], []
    for s in np.atleast_1d(np.asarray(esn0_db, dtype=float)):
        ser, ber = awgn_error_rates(modulation, s + centres)
        sers.append(float(w @ ser))
        bers.append(float(w @ ber))
    shape = np.shape(esn0_db)
    return np.reshape(sers, shape), np.reshape(bers, shape)


# ----------------------------------------------------------------------------------------
# the transmitted frame
# ----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class PilotPattern:
    """A rectangular lattice of known pilots: every ``subcarrier_step``-th subcarrier of
    every ``symbol_step``-th symbol, the last subcarrier and last symbol always included
    (so that interpolation never extrapolates).  ``block`` (whole pilot symbols):
    subcarrier_step 1; ``comb`` (pilot subcarriers in every symbol): symbol_step 1."""

    subcarrier_step: int = 1
    symbol_step: int = 8

    def __post_init__(self):
        for name in ("subcarrier_step", "symbol_step"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int | np.integer) or v < 1:
                raise ArgumentError("must be a positive integer", argument=f"PilotPattern.{name}",
                                    value=v)

    @classmethod
    def named(cls, kind: str, step: int) -> PilotPattern:
        if kind == "block":
            return cls(1, step)
        if kind == "comb":
            return cls(step, 1)
        raise ArgumentError("must be 'block' or 'comb'", argument="pilots", value=kind)

    def subcarriers(self, n: int) -> np.ndarray:
        return _lattice(n, self.subcarrier_step)

    def symbols(self, m: int) -> np.ndarray:
        return _lattice(m, self.symbol_step)

    def mask(self, n: int, m: int) -> np.ndarray:
        """(N, M) booleans, True on pilot cells."""
        out = np.zeros((n, m), bool)
        out[np.ix_(self.subcarriers(n), self.symbols(m))] = True
        return out

    def overhead(self, n: int, m: int) -> float:
        """Fraction of the frame's cells that carry pilots."""
        return self.subcarriers(n).size * self.symbols(m).size / (n * m)


def _lattice(n, step):
    idx = np.arange(0, n, step)
    return idx if idx[-1] == n - 1 else np.append(idx, n - 1)


@dataclass(frozen=True)
class TxFrame:
    """What A sends: ``symbols`` (N, M) with pilots on ``pilot_mask`` cells and Gray-mapped
    ``bits`` (data cells in column-major order, bits_per_symbol each) on the others."""

    symbols: np.ndarray
    pilot_mask: np.ndarray
    bits: np.ndarray
    modulation: str
    pattern: PilotPattern


def pilot_values(n: int, m: int) -> np.ndarray:
    """The known pilot value of every cell, (N, M): QPSK from a fixed seed (both ends know
    it); the pattern decides which cells use it."""
    rng = np.random.default_rng(0x5EED)
    return np.exp(1j * (np.pi / 4 + np.pi / 2 * rng.integers(0, 4, size=(n, m))))


def transmit_frame(waveform: Waveform, modulation: str, pattern: PilotPattern,
                   rng=None) -> TxFrame:
    """A's frame: random data bits, Gray mapped to ``modulation``, pilots on ``pattern``."""
    mod = check_modulation(modulation)
    n, m = waveform.n_subcarriers, waveform.n_symbols
    mask = pattern.mask(n, m)
    rng = np.random.default_rng(rng)
    k = bits_per_symbol(mod)
    n_data = int((~mask).sum())
    bits = rng.integers(0, 2, size=(n_data, k), dtype=np.int8)
    d = pilot_values(n, m)
    data = np.zeros((n, m), complex)
    data.T[~mask.T] = gray_map(bits, mod)  # column-major: symbol by symbol
    d = np.where(mask, d, data)
    return TxFrame(d, mask, bits, mod, pattern)


def _data_cells(grid, mask):
    """Data cells of (N, M) in the order of ``TxFrame.bits``."""
    return np.asarray(grid).T[~np.asarray(mask).T]


# ----------------------------------------------------------------------------------------
# the received signal
# ----------------------------------------------------------------------------------------
def capture_length(waveform: Waveform) -> int:
    """Samples D records: the frame plus two symbols' room for the timing offset and delays."""
    return (waveform.n_symbols + 2) * waveform.samples_per_symbol


def received_signal(symbols, gains, delays_s, dopplers_hz, waveform: Waveform, *,
                    timing_offset_s: float = 0.0, cfo_hz: float = 0.0,
                    phase_rad: float = 0.0) -> np.ndarray:
    """D's noiseless capture (``capture_length`` samples at f_s = NΔf): A's CP-OFDM frame of
    ``symbols`` leaves A at capture time ``timing_offset_s`` and reaches D over every path
    (y = Σ a_k x(t − t_0 − τ_k) e^{j2π(f_D,k + Δf_c)t + jφ}), exact time-domain synthesis
    (fractional delays, Doppler inside each symbol (ICI), delays beyond the prefix (ISI);
    ``interference.stream_signal``).  ``cfo_hz`` is D's oscillator offset from A's."""
    d = check_symbols(symbols, waveform)
    a, tau, fd = check_paths(gains, delays_s, dopplers_hz)
    t0, cfo, ph = (_finite(k, v) for k, v in (("timing_offset_s", timing_offset_s),
                                                ("cfo_hz", cfo_hz), ("phase_rad", phase_rad)))
    if t0 < 0:
        raise ArgumentError("must be >= 0", argument="timing_offset_s", value=timing_offset_s)
    if a.size and t0 + float(tau.max()) >= 2 * waveform.symbol_duration:
        raise ArgumentError(
            f"the timing offset plus the longest delay ({t0 + float(tau.max())!r} s) must stay "
            f"under 2 T_sym = {2 * waveform.symbol_duration!r} s, the capture's spare room",
            argument="timing_offset_s", value=timing_offset_s)
    return stream_signal(d, a * np.exp(1j * ph), tau + t0, fd + cfo, waveform,
                         capture_length(waveform))


def _finite(name, value) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ArgumentError("must be a real number", argument=name, value=value) from None
    if not math.isfinite(v):
        raise ArgumentError("must be finite", argument=name, value=value)
    return v


def channel_power(gains, delays_s, dopplers_hz, waveform: Waveform) -> float:
    """Mean power gain of the link over the frame's cells, mean |H(n, μ)|² of the
    frequency-domain channel (docs/dsp.md §3): Σ|a_k|² when the paths are resolved, less
    when unresolved paths cancel (a line of sight and its road bounce)."""
    a, tau, fd = check_paths(gains, delays_s, dopplers_hz)
    with warnings.catch_warnings():  # only the power is used: aliasing does not change it
        warnings.simplefilter("ignore", AliasingWarning)
        warnings.simplefilter("ignore", CyclicPrefixWarning)
        h = channel_transfer_function(a, tau, fd, waveform,
                                      method="matmul" if a.size <= 64 else "nufft")
    return float(np.mean(np.abs(h) ** 2))


def snr_noise_variance(channel_power_gain: float, esn0_db: float) -> float:
    """Noise variance per sample for a mean Es/N0 of ``esn0_db`` at D: the symbols have unit
    power and the transforms are unitary, so Es/N0 = mean|H|²/σ² (``channel_power``)."""
    p = _finite("channel_power_gain", channel_power_gain)
    if not p > 0:
        raise ArgumentError("the link carries no power", argument="channel_power_gain",
                            value=p)
    return p * 10.0 ** (-_finite("esn0_db", esn0_db) / 10.0)


# ----------------------------------------------------------------------------------------
# synchronisation
# ----------------------------------------------------------------------------------------
def cp_timing(signal, waveform: Waveform, rho: float | None = None):
    """Van de Beek ML timing and frequency offset, the metric summed over every symbol.

    γ(θ) = Σ_{k∈CP(θ)} r(k) r*(k+N), Φ(θ) = ½ Σ (|r(k)|² + |r(k+N)|²),
    Λ(θ) = |γ(θ)| − ρΦ(θ), ρ = SNR/(SNR+1); θ̂ = argmax Λ (mod L), ε̂ = −∠γ(θ̂)/2π
    subcarrier spacings.  ``rho`` None estimates it as |γ|/Φ at the plain correlation's
    peak.  Returns (θ̂, ε̂, Λ)."""
    y = np.asarray(signal)
    n, ncp, ell = waveform.n_subcarriers, waveform.n_cp, waveform.samples_per_symbol
    if y.ndim != 1 or y.size < 2 * ell:
        raise ArgumentError(f"must be 1-D with at least 2L = {2 * ell} samples",
                            argument="signal", value=f"shape {y.shape}")
    if ncp == 0:
        raise ArgumentError("synchronisation needs a cyclic prefix", argument="waveform.n_cp",
                            value=0)
    z = y[:-n] * np.conj(y[n:])
    e = 0.5 * (np.abs(y[:-n]) ** 2 + np.abs(y[n:]) ** 2)

    def fold_window(v):
        folded = np.zeros(ell, v.dtype)
        full = v.size // ell
        folded += v[:full * ell].reshape(full, ell).sum(axis=0)
        folded[:v.size - full * ell] += v[full * ell:]
        ext = np.concatenate([folded, folded[:ncp]])
        cs = np.concatenate([[0], np.cumsum(ext)])
        return cs[ncp:ncp + ell] - cs[:ell]

    gamma, phi = fold_window(z), fold_window(e)
    if rho is None:
        k = int(np.argmax(np.abs(gamma)))
        rho = float(np.abs(gamma[k]) / phi[k]) if phi[k] > 0 else 0.0
    lam = np.abs(gamma) - rho * phi
    theta = int(np.argmax(lam))
    eps = float(-np.angle(gamma[theta]) / (2 * np.pi))
    return theta, eps, lam


@dataclass(frozen=True)
class Sync:
    """Where D found A's frame: ``theta`` (sample of a CP start, mod L), ``eps`` (carrier
    offset, subcarrier spacings), ``frame_start`` (capture sample of symbol 0's CP),
    ``window_start`` (capture sample of symbol 0's FFT window)."""

    theta: int
    eps: float
    frame_start: int
    window_start: int


def synchronise(capture, waveform: Waveform, pilots, pilot_mask, *,
                backoff: int | None = None, rho: float | None = None):
    """Timing, frequency offset and frame start; returns (Sync, received symbols R (N, M)
    after the offset's removal).  The FFT windows start ``backoff`` samples (default
    N_cp/8) into the cyclic prefix, so paths a little ahead of the timing estimate stay
    ISI-free.  The first symbol is the candidate window whose pilots correlate best with
    the known ones (energy of the correlation in the delays a prefix covers)."""
    y = np.asarray(capture)
    n, ncp, ell, m = (waveform.n_subcarriers, waveform.n_cp, waveform.samples_per_symbol,
                      waveform.n_symbols)
    b = max(1, ncp // 8) if backoff is None else int(backoff)
    if not 0 <= b <= ncp:
        raise ArgumentError(f"must lie in [0, N_cp = {ncp}]", argument="backoff", value=backoff)
    theta, eps, _ = cp_timing(y, waveform, rho)
    yc = y * np.exp(-2j * np.pi * eps * np.arange(y.size) / n)
    ref = np.where(pilot_mask[:, 0], pilots[:, 0], 0.0)
    best, start = -1.0, None
    for j in range(-1, 3):
        s = theta + j * ell
        w = s + ncp - b
        if w < 0 or w + (m - 1) * ell + n > y.size:
            continue
        r0 = np.fft.fft(yc[w:w + n], norm="ortho")
        taps = np.fft.ifft(r0 * np.conj(ref))
        score = float(np.sum(np.abs(taps[:ncp + 1]) ** 2))
        if score > best:
            best, start = score, s
    if start is None:
        raise ArgumentError("the capture is too short for a whole frame after the timing "
                            "estimate", argument="capture", value=f"{y.size} samples")
    w0 = start + ncp - b
    blocks = yc[w0 + ell * np.arange(m)[:, None] + np.arange(n)[None, :]]
    r = np.fft.fft(blocks, axis=1, norm="ortho").T.copy()
    return Sync(theta, eps, start, w0), r


# ----------------------------------------------------------------------------------------
# channel estimation and equalisation
# ----------------------------------------------------------------------------------------
def delay_correlation(n: int, support: int) -> np.ndarray:
    """Frequency correlation R(k, l) = E H(k)H*(l) of a channel whose power is spread
    uniformly over delays [0, support] samples (unit total power): the robust prior of
    Li, Cimini & Sollenberger (1998), sinc-like, exact for fractional delays."""
    d = np.subtract.outer(np.arange(n), np.arange(n)).astype(float)
    x = 2 * np.pi * d * support / n
    with np.errstate(invalid="ignore", divide="ignore"):
        r = np.where(d == 0, 1.0, (1.0 - np.exp(-1j * x)) / (1j * x))
    return r


def noise_from_pilots(h_ls, pilot_rows, n: int, support: int) -> float:
    """Noise variance of least-squares pilot estimates (unit-power pilots), from delay taps
    far outside the channel's support: the uniformly spaced pilot rows' IDFT, taps in the
    middle quarter (half a period away from the channel)."""
    rows = np.asarray(pilot_rows)
    step = rows[1] - rows[0] if rows.size > 1 else 1
    uniform = rows[:(n - 1) // step + 1] if rows.size > 1 else rows
    uniform = uniform[uniform == np.arange(uniform.size) * step]
    p = uniform.size
    taps = np.fft.ifft(h_ls[:p], axis=0, norm="ortho")
    lo, hi = p // 2 - p // 8, p // 2 + p // 8
    if hi <= lo or support * p / n >= lo:
        raise ArgumentError("too few pilot subcarriers to measure the noise beside the "
                            "channel's delay spread", argument="pilots", value=p)
    return float(np.mean(np.abs(taps[lo:hi]) ** 2))


def estimate_channel(r, pilots, pattern: PilotPattern, waveform: Waveform, *,
                     support: int | None = None, noise_variance: float | None = None):
    """Channel estimate Ĥ (N, M) from the received symbols ``r`` and known ``pilots``.

    Least squares on the pilot cells; per pilot symbol a Wiener filter over frequency,
    Ĥ = R_{:,p}(R_{p,p} + σ²I)^{-1} Ĥ_LS,p with the uniform delay prior over [0, ``support``]
    samples (default N_cp + N_cp/8: the prefix and the window's backoff); then linear
    interpolation over time between pilot symbols.  σ² from the pilots' delay taps far
    from the channel unless given.  Returns (Ĥ, σ̂²)."""
    n, m, ncp = waveform.n_subcarriers, waveform.n_symbols, waveform.n_cp
    rows, cols = pattern.subcarriers(n), pattern.symbols(m)
    sup = ncp + max(1, ncp // 8) if support is None else int(support)
    h_ls = r[np.ix_(rows, cols)] / pilots[np.ix_(rows, cols)]
    nv = noise_from_pilots(h_ls, rows, n, sup) if noise_variance is None \
        else float(noise_variance)
    corr = delay_correlation(n, sup)
    r_pp = corr[np.ix_(rows, rows)]
    # R_{:,p} A^{-1} = (A^{-T} R_{:,p}^T)^T
    a_mat = r_pp + _relative_noise(h_ls, nv) * np.eye(rows.size)
    filt = np.linalg.solve(a_mat.T, corr[:, rows].T).T
    h_cols = filt @ h_ls  # (N, pilot symbols)
    h = _interp_columns(h_cols, cols, m)
    return h, nv


def _relative_noise(h_ls, noise_variance):
    """σ² over the channel's mean power (the prior has unit power), floored at 1e-10 so
    that a noiseless estimate stays a well-posed regularised fit."""
    p_h = max(float(np.mean(np.abs(h_ls) ** 2)) - noise_variance, 1e-300)
    return max(noise_variance / p_h, 1e-10)


def _interp_columns(h_cols, cols, m):
    """Linear interpolation of (N, P) columns at symbols ``cols`` onto 0..m−1."""
    if cols.size == 1:
        return np.repeat(h_cols, m, axis=1)
    mu = np.arange(m)
    right = np.clip(np.searchsorted(cols, mu, side="right"), 1, cols.size - 1)
    left = right - 1
    t = (mu - cols[left]) / (cols[right] - cols[left])
    return h_cols[:, left] * (1 - t) + h_cols[:, right] * t


def decision_directed(r, h, frame_mask, pilots, modulation: str, waveform: Waveform,
                      noise_variance: float, support: int | None = None):
    """One decision-directed pass: every symbol's decided data (and its pilots) taken as
    known, Ĥ re-estimated per symbol with the same Wiener filter over all subcarriers."""
    n, ncp = waveform.n_subcarriers, waveform.n_cp
    sup = ncp + max(1, ncp // 8) if support is None else int(support)
    x_hat, _ = gray_demap(r / h, modulation)
    x_hat = np.where(frame_mask, pilots, x_hat)
    corr = delay_correlation(n, sup)
    lam, u = np.linalg.eigh(corr)
    h_dd = r / x_hat
    rel = _relative_noise(h_dd, noise_variance)
    w = (u * (lam / (lam + rel))) @ u.conj().T
    return w @ h_dd


def equalise(r, h) -> np.ndarray:
    """Zero-forcing equaliser R/Ĥ (one tap per cell; the unbiased per-cell MMSE is the same)."""
    return r / h


# ----------------------------------------------------------------------------------------
# figures of merit and the whole receiver
# ----------------------------------------------------------------------------------------
@dataclass
class CommsResult:
    """One received frame: sync, channel estimate, error counts on the data cells."""

    sync: Sync
    channel: np.ndarray          # Ĥ (N, M)
    noise_variance: float        # σ̂² the estimator used
    equalised: np.ndarray        # data cells after equalisation
    bit_errors: int
    bits: int
    symbol_errors: int
    symbols: int
    evm: float                   # rms |x̂ − x| over the data cells (unit-power symbols)

    @property
    def ber(self) -> float:
        return self.bit_errors / self.bits

    @property
    def ser(self) -> float:
        return self.symbol_errors / self.symbols


def receive(capture, tx: TxFrame, waveform: Waveform, *, dd_passes: int = 0,
            noise_variance: float | None = None, channel=None, backoff: int | None = None):
    """D's whole receiver on a capture: synchronise, estimate the channel from the pilots
    (or use ``channel``, a known Ĥ (N, M) in the receiver's timing), ``dd_passes``
    decision-directed passes, zero-forcing, hard Gray decisions; counts against ``tx``."""
    pil = pilot_values(waveform.n_subcarriers, waveform.n_symbols)
    sync, r = synchronise(capture, waveform, pil, tx.pilot_mask, backoff=backoff)
    if channel is None:
        h, nv = estimate_channel(r, pil, tx.pattern, waveform, noise_variance=noise_variance)
        for _ in range(int(dd_passes)):
            h = decision_directed(r, h, tx.pilot_mask, pil, tx.modulation, waveform, nv)
    else:
        h, nv = np.asarray(channel), float("nan") if noise_variance is None else noise_variance
    z = _data_cells(equalise(r, h), tx.pilot_mask)
    x = _data_cells(tx.symbols, tx.pilot_mask)
    points, bits = gray_demap(z, tx.modulation)
    bit_err = int(np.sum(bits != tx.bits))
    sym_err = int(np.sum(np.abs(points - x) > 1e-9))
    evm = float(np.sqrt(np.mean(np.abs(z - x) ** 2)))
    return CommsResult(sync, h, nv, z, bit_err, int(tx.bits.size), sym_err, int(z.size), evm)


def known_channel(gains, delays_s, dopplers_hz, waveform: Waveform, sync: Sync, *,
                  timing_offset_s: float = 0.0, cfo_hz: float = 0.0,
                  phase_rad: float = 0.0) -> np.ndarray:
    """The channel a perfectly informed receiver would use, in the receiver's timing
    (``sync``'s FFT windows and its frequency correction): H(n, μ) = Σ_k a_k e^{jφ}
    e^{−j2πn(t_0+τ_k − w_0/f_s + T_CP)Δf} e^{j2π(f_k+Δf_c−ε̂Δf)t_μ}, t_μ the centre of
    window μ.  ICI-free (the frequency-domain model, docs/dsp.md §3)."""
    a, tau, fd = check_paths(gains, delays_s, dopplers_hz)
    n, m = waveform.n_subcarriers, waveform.n_symbols
    fs, df = waveform.sample_rate, waveform.subcarrier_spacing_hz
    lag = timing_offset_s + tau + waveform.cp_duration - sync.window_start / fs  # (K,)
    f_res = fd + cfo_hz - sync.eps * df
    t_mu = (sync.window_start + waveform.samples_per_symbol * np.arange(m) + (n - 1) / 2) / fs
    # the frequency correction e^{−j2πε̂ i/N} starts at capture sample 0
    e_n = np.exp(-2j * np.pi * np.outer(np.arange(n), lag * df))  # (N, K)
    e_t = np.exp(2j * np.pi * np.outer(f_res, t_mu))  # (K, M)
    return e_n @ ((a * np.exp(1j * phase_rad))[:, None] * e_t)


# ----------------------------------------------------------------------------------------
# Monte Carlo over SNR
# ----------------------------------------------------------------------------------------
CSV_COLUMNS = ("esn0_db", "ber", "ser", "evm_db", "bit_errors", "bits", "symbol_errors",
               "symbols", "ber_awgn_theory", "ser_awgn_theory", "evm_awgn_theory_db",
               "ber_known_channel_theory", "ser_known_channel_theory", "timing_errors",
               "cfo_error_max_hz")


@dataclass
class MonteCarlo:
    """Error rates against Es/N0 for one link, with the theory beside them (one row per
    SNR, :data:`CSV_COLUMNS`)."""

    modulation: str
    pattern: PilotPattern
    overhead: float
    rows: list

    def column(self, name: str) -> np.ndarray:
        i = CSV_COLUMNS.index(name)
        return np.array([row[i] for row in self.rows], dtype=float)


def monte_carlo(gains, delays_s, dopplers_hz, waveform: Waveform, esn0_db, *,
                modulation: str = "qpsk", pattern: PilotPattern | None = None,
                frames: int = 1, seed: int = 0, timing_offset_s: float = 3e-6,
                cfo_hz: float = 0.0, phase_rad: float = 0.3, dd_passes: int = 0,
                progress=None) -> MonteCarlo:
    """BER, SER and EVM of D's receiver against Es/N0 (``esn0_db``: a list) on one link.

    Each of ``frames`` frames has its own data and is synthesised once; every SNR adds its
    own noise to it.  Es/N0 is the link's mean: mean|H|²/σ² (``channel_power``).  Beside
    each measurement: the AWGN theory and the known-channel theory (AWGN rates averaged
    over the cells' |H|² of the frequency-domain channel).  A timing error is a frame
    start off by more than the window's backoff."""
    mod = check_modulation(modulation)
    pattern = PilotPattern() if pattern is None else pattern
    a, tau, fd = check_paths(gains, delays_s, dopplers_hz)
    snrs = [_finite("esn0_db", s) for s in np.atleast_1d(esn0_db)]
    if isinstance(frames, bool) or not isinstance(frames, int) or frames < 1:
        raise ArgumentError("must be a positive integer", argument="frames", value=frames)
    wf = replace(waveform, modulation=mod)
    say = progress or (lambda msg: None)
    rng = np.random.default_rng(seed)
    acc = {s: np.zeros(7) for s in snrs}  # bit err, bits, sym err, syms, evm², timing, cfo
    h_known = None
    p_link = channel_power(a, tau, fd, wf)
    n, fs, df = wf.n_subcarriers, wf.sample_rate, wf.subcarrier_spacing_hz
    true_start = (timing_offset_s + float(tau[np.argmax(np.abs(a))])) * fs
    backoff = max(1, wf.n_cp // 8)
    for f in range(frames):
        say(f"frame {f + 1} of {frames}: synthesis")
        tx = transmit_frame(wf, mod, pattern, rng)
        clean = received_signal(tx.symbols, a, tau, fd, wf, timing_offset_s=timing_offset_s,
                                cfo_hz=cfo_hz, phase_rad=phase_rad)
        for s in snrs:
            nv = snr_noise_variance(p_link, s)
            noise = math.sqrt(nv / 2) * (rng.standard_normal(clean.size)
                                         + 1j * rng.standard_normal(clean.size))
            res = receive(clean + noise, tx, wf, dd_passes=dd_passes, backoff=backoff)
            cfo_true = cfo_hz + float(np.sum(np.abs(a) ** 2 * fd) / np.sum(np.abs(a) ** 2))
            acc[s][:6] += (res.bit_errors, res.bits, res.symbol_errors, res.symbols,
                           res.evm ** 2 * res.symbols,
                           abs(res.sync.frame_start - true_start) > backoff)
            acc[s][6] = max(acc[s][6], abs(res.sync.eps * df - cfo_true))
        if h_known is None:  # the channel's cells, for the known-channel theory
            h_known = known_channel(a, tau, fd, wf, res.sync, timing_offset_s=timing_offset_s,
                                    cfo_hz=cfo_hz, phase_rad=phase_rad)
    ser_th, ber_th = awgn_error_rates(mod, snrs)
    ser_kc, ber_kc = channel_error_rates(mod, snrs, h_known)
    rows = []
    for i, s in enumerate(snrs):
        be, nb, se, ns, e2, terr, cerr = acc[s]
        rows.append((s, be / nb, se / ns, 10 * math.log10(e2 / ns), int(be), int(nb), int(se),
                     int(ns), float(ber_th[i]), float(ser_th[i]),
                     float(20 * np.log10(awgn_evm(s))), float(ber_kc[i]), float(ser_kc[i]),
                     int(terr), float(cerr)))
    return MonteCarlo(mod, pattern, pattern.overhead(n, wf.n_symbols), rows)


def link_snr_db(gains, delays_s, dopplers_hz, waveform: Waveform, tx_power_w: float,
                noise_figure_db: float, temperature_k: float = 290.0) -> float:
    """Mean Es/N0 of the link in dB: P_tx mean|H|² over D's thermal noise kTBF, B = NΔf."""
    p = channel_power(gains, delays_s, dopplers_hz, waveform)
    if not p > 0:
        raise ArgumentError("the link carries no power", argument="gains", value=p)
    noise = thermal_noise_power(waveform.bandwidth, noise_figure_db, temperature_k)
    return 10.0 * math.log10(_finite("tx_power_w", tx_power_w) * p / noise)


# ----------------------------------------------------------------------------------------
# the picture
# ----------------------------------------------------------------------------------------
def comms_figure(mc: MonteCarlo, title: str = "A -> D data link", link_snr_db=None):
    """BER and SER against Es/N0 with the AWGN and known-channel theory (log scale), and
    EVM against Es/N0 with its AWGN line; ``link_snr_db`` marks the link's own SNR."""
    fig = new_figure(figsize=(10.0, 4.2))
    ax, bx = fig.subplots(1, 2)
    s = mc.column("esn0_db")
    order = np.argsort(s)
    s_fine = np.linspace(float(s.min()), float(s.max()), 200)
    ser_th, ber_th = awgn_error_rates(mc.modulation, s_fine)
    floor = 0.5 / max(mc.column("bits").max(), 1.0)
    for name, colour, theory, kc in (("ber", "C0", ber_th, "ber_known_channel_theory"),
                                     ("ser", "C3", ser_th, "ser_known_channel_theory")):
        ax.semilogy(s_fine, theory, "-", color=colour, lw=1.0,
                    label=f"{name.upper()} AWGN theory")
        ax.semilogy(s[order], np.maximum(mc.column(kc)[order], floor), ":", color=colour,
                    lw=1.0, label=f"{name.upper()} known channel (theory)")
        meas = mc.column(name)[order]
        ok = meas > 0
        ax.semilogy(s[order][ok], meas[ok], "o", color=colour, ms=4,
                    label=f"{name.upper()} measured")
    ax.set_ylim(max(floor, 1e-7), 1.0)
    ax.set_xlabel("Es/N0 [dB]")
    ax.set_ylabel("error rate")
    ax.grid(True, which="both", alpha=0.3)
    bx.plot(s_fine, 20 * np.log10(awgn_evm(s_fine)), "-", color="C2", lw=1.0,
            label="AWGN theory")
    bx.plot(s[order], mc.column("evm_db")[order], "o", color="C2", ms=4, label="measured")
    bx.set_xlabel("Es/N0 [dB]")
    bx.set_ylabel("EVM [dB]")
    bx.grid(True, alpha=0.3)
    for axis in (ax, bx):
        if link_snr_db is not None and s.min() <= link_snr_db <= s.max():
            axis.axvline(link_snr_db, color="k", lw=0.8, ls="--", label="link SNR")
        axis.legend(fontsize=7)
    ax.set_title(f"{title}: {mc.modulation.upper()}, pilots {mc.overhead:.1%}", fontsize=9)
    bx.set_title("error vector magnitude", fontsize=9)
    fig.tight_layout()
    return fig


def csv_rows(mc: MonteCarlo) -> list[tuple]:
    """The Monte Carlo's rows as text for a CSV with :data:`CSV_COLUMNS`."""
    out = []
    for row in mc.rows:
        out.append(tuple(f"{v:.6g}" if isinstance(v, float) else str(v) for v in row))
    return out
