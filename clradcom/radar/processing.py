"""OFDM radar processing: spectral estimate, windows, periodogram → range–Doppler image.

Chain (Sturm & Wiesbeck, Proc. IEEE 99(7) 2011, eqs. (9)–(14); paper eqs. (4)–(8)):
F = D_r/D (or D_r·D*/E|D|²), window on both axes, IDFT over subcarriers (→ range), DFT
over symbols (→ Doppler), |·|².  Bin p of an N'-point range IDFT is r = p·c/(2N'Δf); bin q
of an M'-point Doppler DFT is v = q·c/(2 f_c M' T_sym), shown fftshifted so that approaching
targets (positive Doppler, e^{+j2π f_D μ T_sym}) have positive velocity (paper Table III).

Power normalisation: power = |Σ_n Σ_μ w_n w_μ F e^{..}|² / (Σw_n² · Σw_μ²), so white noise
of variance σ² per cell has expected power σ² in every image cell, whatever the window,
and a unit target on the grid peaks at (Σw_n)²(Σw_μ)²/(Σw_n² Σw_μ²) = NM / (ENBW_n ENBW_μ),
i.e. the window's SNR loss shows as a lower peak over an unchanged floor.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy import fft as sfft
from scipy.signal import windows as sw

from clradcom.errors import ArgumentError
from clradcom.radar.waveform import SPEED_OF_LIGHT, Waveform, check_symbols

WINDOW_ALIASES = {
    "rect": "boxcar", "rectangular": "boxcar", "boxcar": "boxcar", "none": "boxcar",
    "hann": "hann", "hanning": "hann", "hamming": "hamming",
    "blackman": "blackman", "blackmanharris": "blackmanharris",
    "blackman-harris": "blackmanharris", "taylor": "taylor", "chebwin": "chebwin",
    "chebyshev": "chebwin",
}


class CellCorrelation(NamedTuple):
    """Correlation coefficient of white noise between the cells of a range–Doppler map,
    separable over its axes: the noise in cells (p, q) and (p', q') has E[X X'*]/σ² =
    ``range[(p − p') mod N'] · doppler[(q − q') mod M']`` (docs/dsp.md §5). Both arrays are
    complex, 1 at lag 0; the independent cells of an unpadded rectangular-window map have
    0 at every other lag."""

    range: np.ndarray
    doppler: np.ndarray


class RadarImage(NamedTuple):
    """Range–Doppler power map and its axes. ``power`` has shape (N', M'): axis 0 range
    (bin p ↦ ``range_m[p]``), axis 1 velocity (fftshifted, ``velocity_mps``).
    ``correlation``: how the windows and zero padding correlate the noise of its cells
    (:func:`cell_correlation`; the CFAR threshold is computed for it); None for a map
    whose cells are independent."""

    power: np.ndarray
    power_db: np.ndarray
    range_m: np.ndarray
    velocity_mps: np.ndarray
    correlation: CellCorrelation | None = None


def spectral_estimate(rx_symbols, tx_symbols, method: str = "divide") -> np.ndarray:
    """Channel estimate F(n, μ) from received and transmitted symbols, both (N, M).

    'divide': F = D_r/D, the zero-forcing "reciprocal filter" (paper eq. (4)); exact channel
    for any constellation but it amplifies noise on small QAM symbols.  'conjugate':
    F = D_r·D*/mean|D|², the matched filter; for PSK the two are identical.
    """
    dr = np.asarray(rx_symbols)
    d = np.asarray(tx_symbols)
    if dr.shape != d.shape or dr.ndim != 2:
        raise ArgumentError(
            f"rx_symbols {dr.shape} and tx_symbols {d.shape} must be 2-D arrays of equal shape"
        )
    if not (np.all(np.isfinite(dr)) and np.all(np.isfinite(d))):
        raise ArgumentError("rx_symbols/tx_symbols contain NaN or infinite values")
    if method == "divide":
        if np.any(d == 0):
            raise ArgumentError("tx_symbols contains zeros; use method='conjugate' or fix the data")
        return dr / d
    if method == "conjugate":
        p = np.mean(np.abs(d) ** 2)
        if p == 0:
            raise ArgumentError("tx_symbols are all zero")
        return dr * np.conj(d) / p
    raise ArgumentError(f"method must be 'divide' or 'conjugate', got {method!r}")


def get_window(window, length: int) -> np.ndarray:
    """A real window of ``length`` points (DFT-even, as in Harris 1978).

    ``window`` is a name ('rect', 'hann', 'hamming', 'blackman', 'blackmanharris',
    'taylor', 'chebwin'), a tuple with parameters (('taylor', nbar, sll_db),
    ('chebwin', attenuation_db)), or an explicit array of ``length`` values.
    Defaults: Taylor n̄ = 4, −30 dB; Chebyshev −60 dB.
    """
    if isinstance(window, np.ndarray | list):
        w = np.asarray(window, dtype=float)
        if w.shape != (length,) or not np.all(np.isfinite(w)):
            raise ArgumentError(f"window array must be {length} finite values, got shape {w.shape}")
        return w
    name, params = (window[0], tuple(window[1:])) if isinstance(window, tuple) else (window, ())
    key = WINDOW_ALIASES.get(str(name).lower())
    if key is None:
        raise ArgumentError(f"unknown window {window!r}; known: {sorted(WINDOW_ALIASES)}")
    if key == "taylor":
        nbar = params[0] if len(params) > 0 else 4
        sll = params[1] if len(params) > 1 else 30.0
        return sw.taylor(length, nbar=int(nbar), sll=float(sll), norm=True, sym=False)
    if key == "chebwin":
        at = params[0] if params else 60.0
        return sw.chebwin(length, at=float(at), sym=False)
    return sw.get_window(key, length, fftbins=True)


def dft_correlation(taper, n_fft: int, sign: int) -> np.ndarray:
    """Correlation coefficient ρ(k), k = 0..n_fft−1, between bins p and p − k of the
    ``n_fft``-point transform Σ_n a_n G_n e^{sign·j2πnp/n_fft} of white noise G tapered by
    ``a``: ρ(k) = Σ_n a_n² e^{sign·j2πnk/n_fft} / Σ_n a_n² (docs/dsp.md §5)."""
    a2 = np.asarray(taper, dtype=float) ** 2
    total = float(np.sum(a2))
    if a2.ndim != 1 or a2.size > n_fft or not total > 0.0:
        raise ArgumentError("must be a non-zero 1-D taper no longer than the transform",
                            argument="taper", value=f"shape {a2.shape}, n_fft {n_fft}")
    spectrum = np.fft.ifft(a2, n=n_fft) * n_fft if sign > 0 else np.fft.fft(a2, n=n_fft)
    return spectrum / total


def cell_correlation(window_range, window_doppler, n: int, m: int, zero_pad_range: int = 1,
                     zero_pad_doppler: int = 1) -> CellCorrelation:
    """The noise correlation of the cells of :func:`radar_image`'s map of an N × M
    frame with these windows and zero padding: range by an IDFT (e^{+j}), Doppler by a
    DFT (e^{−j}); the fftshift of the Doppler axis keeps lags."""
    nz = n * _zero_pad("zero_pad_range", zero_pad_range)
    mz = m * _zero_pad("zero_pad_doppler", zero_pad_doppler)
    return CellCorrelation(dft_correlation(get_window(window_range, n), nz, +1),
                           dft_correlation(get_window(window_doppler, m), mz, -1))


def range_axis(waveform: Waveform, n_fft: int) -> np.ndarray:
    """Range of each IDFT bin: r_p = p·c/(2 N' Δf), p = 0..N'−1."""
    return np.arange(n_fft) * SPEED_OF_LIGHT / (2.0 * n_fft * waveform.subcarrier_spacing_hz)


def velocity_axis(waveform: Waveform, m_fft: int) -> np.ndarray:
    """Velocity of each fftshifted DFT bin: v = (q − ⌊M'/2⌋)·c/(2 f_c M' T_sym)."""
    step = SPEED_OF_LIGHT / (2.0 * waveform.carrier_hz * m_fft * waveform.symbol_duration)
    return (np.arange(m_fft) - m_fft // 2) * step


def _zero_pad(name, value):
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 1:
        raise ArgumentError(f"{name} must be an integer >= 1, got {value!r}")
    return int(value)


def radar_image(spectral, waveform: Waveform, window_range="hann", window_doppler="hann",
                zero_pad_range: int = 1, zero_pad_doppler: int = 1,
                workers: int | None = None) -> RadarImage:
    """Periodogram of the channel estimate F (N, M): the radar image (Sturm & Wiesbeck 2011,
    eq. (14); Braun 2014 §2.3).  Range via an N'·zero_pad_range-point IDFT over subcarriers,
    velocity via an M'·zero_pad_doppler-point DFT over symbols (fftshifted).  Power is
    normalised to the noise floor (module docstring); ``power_db`` = 10·log10(power)."""
    f = check_symbols(spectral, waveform, name="spectral")
    n, m = f.shape
    nz = n * _zero_pad("zero_pad_range", zero_pad_range)
    mz = m * _zero_pad("zero_pad_doppler", zero_pad_doppler)
    wn = get_window(window_range, n)
    wm = get_window(window_doppler, m)
    norm = np.sqrt(np.sum(wn**2) * np.sum(wm**2))
    if norm == 0:
        raise ArgumentError("window is all zeros")
    g = f * (wn[:, None] / norm) * wm[None, :]
    # IDFT over n as a forward DFT of the conjugate-free form: ifft·N' keeps e^{+j2πnp/N'}.
    h = sfft.ifft(g, n=nz, axis=0, norm="forward", workers=workers)
    h = sfft.fft(h, n=mz, axis=1, workers=workers)
    power = h.real**2 + h.imag**2
    power = np.fft.fftshift(power, axes=1)
    with np.errstate(divide="ignore"):
        power_db = 10.0 * np.log10(power)
    correlation = CellCorrelation(dft_correlation(wn, nz, +1), dft_correlation(wm, mz, -1))
    return RadarImage(power, power_db, range_axis(waveform, nz), velocity_axis(waveform, mz),
                      correlation)
