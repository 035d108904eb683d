"""Independent references for the DSP tests: brute-force evaluation of the paper's eq. (1)."""

from __future__ import annotations

import numpy as np

from clradcom.paths import Paths
from clradcom.radar import Waveform


def small_waveform(n=64, m=16, **kw) -> Waveform:
    """The paper's Δf, T_CP and f_c with fewer subcarriers/symbols (N_cp = N/8)."""
    kw.setdefault("modulation", "qpsk")
    return Waveform(n_subcarriers=n, n_symbols=m, **kw)


def brute_force_rx(symbols, gains, delays_s, dopplers_hz, wf: Waveform) -> np.ndarray:
    """y_i = Σ_k a_k e^{j2π f_D t_i} x(t_i − τ_k), x evaluated as a direct sum over
    subcarriers for every sample and path (O(K·M·L·N); small waveforms only)."""
    n, m, ncp, ell = wf.n_subcarriers, wf.n_symbols, wf.n_cp, wf.samples_per_symbol
    fs = wf.sample_rate
    i = np.arange(m * ell)
    y = np.zeros(i.size, complex)
    sub = np.arange(n)
    for a, tau, fd in zip(np.atleast_1d(gains), np.atleast_1d(delays_s),
                          np.atleast_1d(dopplers_hz), strict=True):
        delay = tau * fs
        if abs(delay - round(delay)) < 1e-9:  # the synthesis's documented snap to a sample
            delay = float(round(delay))
        s = i - delay  # source position in samples, continuous
        nu = np.floor(s / ell).astype(int)
        local = s - nu * ell - ncp  # time since the useful part started, in samples
        valid = (nu >= 0) & (nu < m)
        x = np.zeros(i.size, complex)
        ph = np.exp(2j * np.pi * np.outer(local[valid], sub) / n)  # (samples, N)
        x[valid] = np.einsum("sn,ns->s", ph, symbols[:, nu[valid]]) / np.sqrt(n)
        y += a * np.exp(2j * np.pi * fd * i / fs) * x
    return y


def dirichlet(eps: float, n: int) -> complex:
    """(1/N) Σ_{m<N} e^{j2π ε m/N}: the FFT-window response to a frequency offset ε bins."""
    if eps == 0:
        return 1.0 + 0j
    return np.exp(1j * np.pi * eps * (n - 1) / n) * np.sin(np.pi * eps) / (
        n * np.sin(np.pi * eps / n))


def los_paths(gains, delays, dopplers) -> Paths:
    """Paths with given gains, delays and Doppler shifts and no interactions (direct
    paths), for feeding the radar chain without a tracer."""
    p = len(gains)
    return Paths(gain=np.asarray(gains, complex), matrix=np.zeros((p, 2, 2), complex),
                 delay_s=np.asarray(delays, float), doppler_hz=np.asarray(dopplers, float),
                 n_interactions=np.zeros(p, np.int16), interaction=np.zeros((p, 0), np.int8),
                 points=np.zeros((p, 2, 3)), object_id=np.zeros((p, 0), np.int32),
                 face_id=np.zeros((p, 0), np.int32))
