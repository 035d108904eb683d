"""MIMO OFDM radar: time-division (TDM) and Doppler-division (DDM) multiplexing of the
transmit elements, the virtual array, and the range–Doppler spectrum of every virtual
channel with TDM's motion-induced phase compensated (docs/dsp.md §9).

Virtual channel v = i·E_rx + j pairs transmit element i with receive element j; its
virtual position is p_i + q_j (monostatic far field: the two plane-wave phases add).

* **TDM**: symbol μ is sent by transmit element μ mod E_tx only (the others are silent),
  so each virtual channel sees M_v = M / E_tx symbols at μ = m·E_tx + i, a slow-time
  interval E_tx·T_sym. A target with Doppler f_D adds exp(j2π f_D i T_sym) to every
  channel of transmitter i: an extra linear phase across the virtual array that shifts
  the angle. It is removed per Doppler bin by exp(−j2π f_D(q) i T_sym), with f_D(q) the
  bin's Doppler (Bechter, Roos & Waldschmidt, "Compensation of motion-induced phase
  errors in TDM MIMO radars", IEEE Microwave Wireless Compon. Lett. 27(12), 2017;
  their hypothesis test for Doppler beyond the ±1/(2E_tx T_sym) interval is not done
  here: a target outside it is compensated with its aliased Doppler).
* **DDM**: every transmitter sends every symbol, element i with the phase code
  exp(j2π i μ / N_c) (N_c ≥ E_tx codes; N_c > E_tx leaves empty Doppler bands). In the
  Doppler spectrum of a receive channel transmitter i's echoes are shifted by i·M/N_c bins;
  virtual channel (i, j) is the band of width M/N_c centred there (Sun, Brigui &
  Lesturgie, "Analysis and comparison of MIMO radar waveforms", Int. Radar Conf. 2014,
  "DDMA"). Unambiguous velocity shrinks by N_c, the
  Doppler resolution stays that of the whole frame.

All functions take and return plain arrays.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy import fft as sfft

from clradcom.errors import ArgumentError
from clradcom.radar.processing import CellCorrelation, dft_correlation, get_window, range_axis
from clradcom.radar.synthesis import channel_transfer_function
from clradcom.radar.waveform import SPEED_OF_LIGHT, Waveform, check_symbols

__all__ = ["MIMO_MODES", "RangeDoppler", "ddm_codes", "ddm_range_doppler", "mimo_received",
           "tdm_range_doppler", "virtual_positions"]

MIMO_MODES = ("tdm", "ddm")


class RangeDoppler(NamedTuple):
    """Range–Doppler spectra of the virtual channels: ``spectra`` (N', M', V) complex,
    windowed and normalised so that white noise of variance σ² per cell of F = D_r/D has
    power σ² per cell (docs/dsp.md §4); ``velocity_mps`` ascending (fftshifted);
    ``correlation``: how the windows correlate the noise of a channel's cells (the same in
    every channel and in any combination of channels; None: independent cells)."""

    spectra: np.ndarray
    range_m: np.ndarray
    velocity_mps: np.ndarray
    correlation: CellCorrelation | None = None


def virtual_positions(tx_positions, rx_positions) -> np.ndarray:
    """(E_tx·E_rx, 3) virtual element positions p_i + q_j, channel v = i·E_rx + j."""
    p = np.asarray(tx_positions, dtype=np.float64).reshape(-1, 3)
    q = np.asarray(rx_positions, dtype=np.float64).reshape(-1, 3)
    return (p[:, None, :] + q[None, :, :]).reshape(-1, 3)


def _n_tx(n_tx, n_symbols):
    if isinstance(n_tx, bool) or not isinstance(n_tx, int | np.integer) or n_tx < 1:
        raise ArgumentError("must be a positive integer", argument="n_tx", value=n_tx)
    if n_symbols % n_tx:
        raise ArgumentError(f"the {n_symbols} symbols must divide evenly among the "
                            f"transmitters", argument="n_tx", value=n_tx)
    return int(n_tx)


def ddm_codes(n_tx: int, n_symbols: int, n_codes: int | None = None) -> np.ndarray:
    """(E_tx, M) DDM phase codes exp(j2π i μ / N_c); N_c (default E_tx) must divide M."""
    nc = n_tx if n_codes is None else n_codes
    if isinstance(nc, bool) or not isinstance(nc, int | np.integer) or nc < n_tx:
        raise ArgumentError(f"must be an integer >= the {n_tx} transmitters",
                            argument="n_codes", value=n_codes)
    _n_tx(int(nc), n_symbols)
    return np.exp(2j * np.pi * np.outer(np.arange(n_tx), np.arange(n_symbols)) / nc)


def mimo_received(symbols, gains, delays_s, dopplers_hz, waveform: Waveform, mode="tdm",
                  n_codes: int | None = None, time_origin_s: float | None = None):
    """Received symbols (E_rx, N, M) of every receive element (fast model, no noise).

    ``gains`` (E_tx, E_rx, P) per element pair (e.g. from
    :func:`clradcom.radar.array.synthetic_channels`), ``delays_s`` (P,) or (E_tx, E_rx, P),
    ``dopplers_hz`` (P,). TDM: symbol μ from transmitter μ mod E_tx; DDM: all transmit,
    element i's symbols times :func:`ddm_codes`. ``time_origin_s`` defaults to the FFT
    window centre, as :func:`clradcom.radar.pipeline.radar_frame`."""
    if mode not in MIMO_MODES:
        raise ArgumentError(f"must be one of {MIMO_MODES}", argument="mode", value=mode)
    d = check_symbols(symbols, waveform)
    g = np.asarray(gains)
    if g.ndim != 3:
        raise ArgumentError("must be (E_tx, E_rx, P)", argument="gains", value=f"shape {g.shape}")
    et, er, p = g.shape
    tau = np.broadcast_to(np.asarray(delays_s, dtype=np.float64), (et, er, p))
    t0 = waveform.fft_window_centre if time_origin_s is None else time_origin_s
    m = waveform.n_symbols
    if mode == "tdm":
        _n_tx(et, m)
        owner = np.arange(m) % et
    else:
        codes = ddm_codes(et, m, n_codes)
    out = np.zeros((er, waveform.n_subcarriers, m), complex)
    for i in range(et):
        for j in range(er):
            h = channel_transfer_function(g[i, j], tau[i, j], dopplers_hz, waveform, t0)
            if mode == "tdm":
                out[j][:, owner == i] = d[:, owner == i] * h[:, owner == i]
            else:
                out[j] += d * h * codes[i][None, :]
    return out


def _windows(window, n, m):
    wn, wm = get_window(window[0], n), get_window(window[1], m)
    norm = np.sqrt(np.sum(wn**2) * np.sum(wm**2))
    if norm == 0:
        raise ArgumentError("window is all zeros", argument="window", value=window)
    return wn / norm, wm


def _pair(window):
    return (window, window) if isinstance(window, str) or window is None else tuple(window)


def _range_transform(f, wn, workers):
    """IDFT over subcarriers (axis 1 of (V, N, M')) with the range window."""
    return sfft.ifft(f * wn[None, :, None], axis=1, norm="forward", workers=workers)


def tdm_range_doppler(received, symbols, waveform: Waveform, n_tx: int, *, window="hann",
                      compensate: bool = True, workers: int | None = None) -> RangeDoppler:
    """Range–Doppler spectra (N, M_v, E_tx·E_rx) of a TDM frame.

    ``received`` (E_rx, N, M). Per virtual channel (i, j): F = D_r/D on transmitter i's
    symbols μ = m·E_tx + i, windows, IDFT over subcarriers, DFT over its M_v = M/E_tx
    symbols (slow-time interval E_tx·T_sym), and with ``compensate`` the motion-induced
    phase exp(+j2π f_D i T_sym) removed per Doppler bin (module docstring)."""
    d = check_symbols(symbols, waveform)
    r = np.asarray(received)
    if r.ndim != 3 or r.shape[1:] != d.shape:
        raise ArgumentError(f"must be (E_rx, {d.shape[0]}, {d.shape[1]})", argument="received",
                            value=f"shape {r.shape}")
    et = _n_tx(n_tx, waveform.n_symbols)
    er, n, m = r.shape
    mv = m // et
    wn, wm = _windows(_pair(window), n, mv)
    # (E_rx, N, M_v, E_tx) -> virtual channel v = i * E_rx + j
    f = (r / d[None]).reshape(er, n, mv, et).transpose(3, 0, 1, 2).reshape(et * er, n, mv)
    h = _range_transform(f * wm[None, None, :], wn, workers)
    h = sfft.fft(h, axis=2, workers=workers)
    t_slow = et * waveform.symbol_duration
    fd = sfft.fftfreq(mv, t_slow)  # Doppler of each unshifted bin
    if compensate:
        tx_index = np.repeat(np.arange(et), er)
        h *= np.exp(-2j * np.pi * np.outer(tx_index, fd) * waveform.symbol_duration)[:, None, :]
    h = np.fft.fftshift(h, axes=2).transpose(1, 2, 0)
    vel = np.fft.fftshift(fd) * SPEED_OF_LIGHT / (2.0 * waveform.carrier_hz)
    # the compensation is a phase per Doppler bin and transmitter: it leaves each
    # channel's power correlation as it is and turns the lag-k coefficient of a sum of
    # channels by at most 2π(E_tx − 1)k/M (docs/dsp.md §9)
    correlation = CellCorrelation(dft_correlation(wn, n, +1), dft_correlation(wm, mv, -1))
    return RangeDoppler(np.ascontiguousarray(h), range_axis(waveform, n), vel, correlation)


def ddm_range_doppler(received, symbols, waveform: Waveform, n_tx: int, *,
                      n_codes: int | None = None, window="hann",
                      workers: int | None = None) -> RangeDoppler:
    """Range–Doppler spectra (N, M/N_c, E_tx·E_rx) of a DDM frame: per receive channel
    F = D_r/D, windows, IDFT over subcarriers, DFT over all M symbols, then virtual
    channel (i, j) = the band of M/N_c Doppler bins centred on transmitter i's code
    shift i·M/N_c (module docstring)."""
    d = check_symbols(symbols, waveform)
    r = np.asarray(received)
    if r.ndim != 3 or r.shape[1:] != d.shape:
        raise ArgumentError(f"must be (E_rx, {d.shape[0]}, {d.shape[1]})", argument="received",
                            value=f"shape {r.shape}")
    nc = int(n_tx if n_codes is None else n_codes)
    ddm_codes(n_tx, waveform.n_symbols, nc)  # checks n_tx, n_codes
    er, n, m = r.shape
    band = m // nc
    wn, wm = _windows(_pair(window), n, m)
    # the window over all M symbols keeps its power normalisation per band: noise of
    # variance σ² per cell stays σ² per bin
    h = _range_transform((r / d[None]) * wm[None, None, :], wn, workers)
    h = sfft.fft(h, axis=2, workers=workers)  # (E_rx, N, M), unshifted bins
    q = np.arange(band) - band // 2  # signed Doppler bins of one band, ascending
    spectra = np.empty((n, band, n_tx * er), complex)
    for i in range(n_tx):
        cols = (q + i * band) % m
        spectra[:, :, i * er:(i + 1) * er] = h[:, :, cols].transpose(1, 2, 0)
    vel = q / (m * waveform.symbol_duration) * SPEED_OF_LIGHT / (2.0 * waveform.carrier_hz)
    # a band of M/N_c bins of the M-point transform, taken as periodic like the CFAR's map
    lag = np.arange(band)
    lag = np.where(lag <= band - lag, lag, lag - band)
    correlation = CellCorrelation(dft_correlation(wn, n, +1),
                                  dft_correlation(wm, m, -1)[lag % m])
    return RangeDoppler(spectra, range_axis(waveform, n), vel, correlation)
