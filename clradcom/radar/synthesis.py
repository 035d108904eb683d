"""Received OFDM radar signal from a snapshot's paths, and thermal noise.

Channel model (docs/architecture.md, "Contracts"):
y(t) = Σ_k a_k · x(t − τ_k) · e^{j2π f_D,k t}, with the
carrier phase −2π f_c τ_k already inside a_k, so nothing here adds a carrier phase.  t = 0
is the first sample of the frame (start of symbol 0's cyclic prefix); nothing is
transmitted before the frame.  τ_k is constant over the frame (no range migration:
|v|·M·T_sym ≤ 0.8 m < Δr for the paper's waveform, docs/dsp.md §1).

Two methods (docs/dsp.md §3):

- ``synthesize_frequency_domain``: the model of the paper's eq. (3) / Sturm & Wiesbeck (2011),
  D_r(n, μ) = D(n, μ) · Σ_k a_k e^{−j2π nΔf τ_k} e^{j2π f_D,k (μ T_sym + t_0)}.  No ICI, no
  ISI.  Computed as one 2-D type-1 non-uniform FFT (finufft), or a separable matrix product.
- ``synthesize_time_domain``: the rectangular-pulse CP-OFDM signal of the paper's eq. (1)
  evaluated *exactly* at the receiver's sample instants for every path: fractional delays,
  Doppler running inside each symbol (ICI), delays beyond the CP (ISI).
"""

from __future__ import annotations

import math
import warnings

import numpy as np

from clradcom.errors import AliasingWarning, ArgumentError, CyclicPrefixWarning
from clradcom.radar.waveform import Waveform, check_symbols

BOLTZMANN = 1.380649e-23
#: default relative accuracy of the synthesised frames (NUFFT ``eps``, Chebyshev ``tol``):
#: what a noiseless frame's empty cells hold instead of zero (cfar.numerical_floor)
SYNTHESIS_ACCURACY = 1e-10


# ----------------------------------------------------------------------------------------
# input checks
# ----------------------------------------------------------------------------------------
def check_paths(gains, delays_s, dopplers_hz):
    """Validate path arrays; returns (complex gains, float delays, float dopplers), 1-D."""
    a = np.atleast_1d(np.asarray(gains))
    tau = np.atleast_1d(np.asarray(delays_s))
    fd = np.atleast_1d(np.asarray(dopplers_hz))
    for name, arr in (("gains", a), ("delays_s", tau), ("dopplers_hz", fd)):
        if arr.ndim != 1:
            raise ArgumentError(f"must be 1-D (one value per path), got shape {arr.shape}",
                                argument=name)
        if not (np.issubdtype(arr.dtype, np.number) or arr.size == 0):
            raise ArgumentError(f"must be numeric, got dtype {arr.dtype}", argument=name)
    if not (a.size == tau.size == fd.size):
        raise ArgumentError(
            "gains, delays_s and dopplers_hz must have the same length, got "
            f"{a.size}, {tau.size}, {fd.size}", argument="gains")
    for name, arr in (("delays_s", tau), ("dopplers_hz", fd)):
        if np.iscomplexobj(arr):
            raise ArgumentError("must be real, got complex values", argument=name)
    a = a.astype(complex)
    tau = tau.astype(float)
    fd = fd.astype(float)
    for name, arr in (("gains", a), ("delays_s", tau), ("dopplers_hz", fd)):
        bad = ~np.isfinite(arr)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise ArgumentError(f"{name}[{i}] is {arr[i]!r}; every path value must be finite",
                                argument=name)
    if (tau < 0).any():
        i = int(np.flatnonzero(tau < 0)[0])
        raise ArgumentError(f"delays_s[{i}] = {tau[i]!r} is negative; delays must be >= 0",
                            argument="delays_s")
    return a, tau, fd


def warn_unmodelled(delays_s, dopplers_hz, waveform: Waveform, isi_modelled: bool,
                    stacklevel: int = 3) -> None:
    """Warn about paths the radar cannot show where they are (docs/stability.md).

    Range and velocity alias whatever the synthesis: a delay tau >= 1/Δf lands at
    r = (c tau / 2) mod r_max, a Doppler outside [-1/(2 T_sym), 1/(2 T_sym)) wraps by
    multiples of 1/T_sym (``AliasingWarning``).  Delays beyond the cyclic prefix also
    break the frequency-domain model, which has no ISI (``CyclicPrefixWarning``, only
    when ``isi_modelled`` is false).  The time-domain synthesis does model the ISI, so
    it warns about aliasing alone.
    """
    tau = np.asarray(delays_s, dtype=float)
    fd = np.asarray(dopplers_hz, dtype=float)
    if tau.size == 0:
        return
    t_max = 1.0 / waveform.subcarrier_spacing_hz
    far = tau >= t_max
    if far.any():
        i = int(np.argmax(tau))
        warnings.warn(
            f"{int(far.sum())} of {tau.size} paths have delays beyond the unambiguous range "
            f"(delays_s[{i}] = {float(tau[i])!r} s >= 1/Δf = {t_max!r} s, r_max = "
            f"{waveform.max_range:.2f} m): they appear at range (c·τ/2) mod r_max",
            AliasingWarning, stacklevel=stacklevel)
    f_lim = 0.5 / waveform.symbol_duration
    fast = (fd >= f_lim) | (fd < -f_lim)
    if fast.any():
        i = int(np.argmax(np.abs(fd)))
        warnings.warn(
            f"{int(fast.sum())} of {fd.size} paths have Doppler shifts beyond the unambiguous "
            f"±1/(2·T_sym) = ±{f_lim:.1f} Hz (dopplers_hz[{i}] = {float(fd[i])!r} Hz; v_max = "
            f"{waveform.max_velocity:.2f} m/s): they wrap into [-v_max, v_max)",
            AliasingWarning, stacklevel=stacklevel)
    if not isi_modelled:
        long = tau > waveform.cp_duration * (1.0 + 1e-12)
        if long.any():
            i = int(np.argmax(tau))
            warnings.warn(
                f"{int(long.sum())} of {tau.size} paths are delayed beyond the cyclic prefix "
                f"(delays_s[{i}] = {float(tau[i])!r} s > T_CP = {waveform.cp_duration!r} s, range "
                f"{waveform.isi_free_range:.2f} m): the frequency-domain model ignores "
                "their inter-symbol interference; the exact time-domain synthesis models it "
                "(--synthesis exact; in Python method=\"exact\", synthesize_time_domain)",
                CyclicPrefixWarning, stacklevel=stacklevel)


def _wrap_phase(cycles):
    """2π·(cycles mod 1) mapped into [−π, π): exact for the integer-mode NUFFT."""
    frac = cycles - np.floor(cycles + 0.5)
    return 2.0 * np.pi * frac


# ----------------------------------------------------------------------------------------
# frequency-domain model
# ----------------------------------------------------------------------------------------
def _channel_grid(weights, delays_s, dopplers_hz, n_sub, n_sym, df, t_sym, t0,
                  method, eps):
    """H_r(n, μ) = Σ_k w_{r,k} e^{−j2π nΔf τ_k} e^{j2π f_D,k (μ T_sym + t0)}, shape (R, N, M)."""
    w = np.atleast_2d(weights)
    n_tr = w.shape[0]
    if delays_s.size == 0:
        return np.zeros((n_tr, n_sub, n_sym), complex)
    if method == "nufft":
        import finufft

        # Phases in cycles per index step; the NUFFT folds them into [−π, π).
        x = _wrap_phase(-df * delays_s)
        y = _wrap_phase(dopplers_hz * t_sym)
        # finufft's modes run k = −⌊N/2⌋..; n = k + ⌊N/2⌋, so e^{inx} = e^{ikx}·e^{i⌊N/2⌋x}.
        shift = np.exp(1j * (n_sub // 2 * x + n_sym // 2 * y + 2 * np.pi * dopplers_hz * t0))
        c = np.ascontiguousarray(w * shift[None, :])
        out = finufft.nufft2d1(x, y, c if n_tr > 1 else c[0], n_modes=(n_sub, n_sym),
                               eps=eps, isign=1)
        return out.reshape(n_tr, n_sub, n_sym)
    if method == "matmul":
        n = np.arange(n_sub)
        mu = np.arange(n_sym)
        e_tau = np.exp(-2j * np.pi * np.outer(n, df * delays_s))  # (N, K)
        e_dop = np.exp(2j * np.pi * np.outer(dopplers_hz, mu * t_sym + t0))  # (K, M)
        return np.stack([e_tau @ (wr[:, None] * e_dop) for wr in w])
    if method == "direct":
        n = np.arange(n_sub)
        mu = np.arange(n_sym)
        out = np.zeros((n_tr, n_sub, n_sym), complex)
        for k in range(delays_s.size):
            e_tau = np.exp(-2j * np.pi * n * df * delays_s[k])
            e_dop = np.exp(2j * np.pi * dopplers_hz[k] * (mu * t_sym + t0))
            outer = np.outer(e_tau, e_dop)
            for r in range(n_tr):
                out[r] += w[r, k] * outer
        return out
    raise ArgumentError(f"method must be 'nufft', 'matmul' or 'direct', got {method!r}")


def channel_transfer_function(gains, delays_s, dopplers_hz, waveform: Waveform,
                              time_origin_s: float = 0.0, method: str = "nufft",
                              eps: float = SYNTHESIS_ACCURACY) -> np.ndarray:
    """Time-variant transfer function H(n, μ), shape (N, M), of the frequency-domain model.

    H(n, μ) = Σ_k a_k e^{−j2π nΔf τ_k} e^{j2π f_D,k (μ T_sym + t_0)}  (paper eq. (3),
    Sturm & Wiesbeck 2011 eq. (9)).  ``time_origin_s`` = t_0 is the time that symbol 0's
    Doppler phase refers to: 0 reproduces the paper's model; ``waveform.fft_window_centre``
    makes it agree with ``synthesize_time_domain`` (docs/dsp.md §3).

    ``method``: 'nufft' (2-D type-1 NUFFT, finufft, relative accuracy ≈ ``eps``), 'matmul'
    (separable (N×K)@(K×M) product), 'direct' (one outer product per path; reference).
    """
    return _transfer(gains, delays_s, dopplers_hz, waveform, time_origin_s, method, eps, 4)


def _transfer(gains, delays_s, dopplers_hz, waveform, time_origin_s, method, eps, stacklevel):
    a, tau, fd = check_paths(gains, delays_s, dopplers_hz)
    t0 = float(time_origin_s)
    if not math.isfinite(t0):
        raise ArgumentError(f"time_origin_s must be finite, got {time_origin_s!r}")
    if not (1e-15 < eps < 1e-1):
        raise ArgumentError(f"eps must lie in (1e-15, 0.1), got {eps!r}")
    # stacklevel: the warning names the line that called the public function
    warn_unmodelled(tau, fd, waveform, isi_modelled=False, stacklevel=stacklevel)
    return _channel_grid(a[None, :], tau, fd, waveform.n_subcarriers, waveform.n_symbols,
                         waveform.subcarrier_spacing_hz, waveform.symbol_duration, t0,
                         method, eps)[0]


def synthesize_frequency_domain(symbols, gains, delays_s, dopplers_hz, waveform: Waveform,
                                time_origin_s: float = 0.0, method: str = "nufft",
                                eps: float = SYNTHESIS_ACCURACY) -> np.ndarray:
    """Received symbols D_r = D ⊙ H (paper eq. (3)); shape (N, M).  See
    ``channel_transfer_function`` for the parameters."""
    d = check_symbols(symbols, waveform)
    return d * _transfer(gains, delays_s, dopplers_hz, waveform, time_origin_s, method, eps, 4)


# ----------------------------------------------------------------------------------------
# exact time-domain superposition
# ----------------------------------------------------------------------------------------
def chebyshev_order(theta_max: float, half_width: float, tol: float) -> int:
    """Fewest Chebyshev nodes R so that interpolating ε ↦ e^{jθε} on [c−h, c+h] errs ≤ tol
    for |θ| ≤ theta_max.  Bound: (θh)^R / (2^{R−1} R!) (Trefethen, ATAP, Thm 8.2 form for
    entire functions; the R-th derivative of e^{jθε} is θ^R in modulus)."""
    z = theta_max * half_width
    if z == 0.0:
        return 1
    r = 1
    while r < 400:
        log_bound = r * math.log(z) - (r - 1) * math.log(2.0) - math.lgamma(r + 1)
        if log_bound <= math.log(tol):
            return r
        r += 1
    raise ArgumentError(
        f"Doppler spread too large for the exact synthesis: ε spread ±{half_width!r} "
        "subcarrier spacings needs more than 400 interpolation nodes"
    )


def _lagrange_weights(x, nodes):
    """Barycentric Lagrange basis ℓ_r(x) at Chebyshev first-kind nodes, shape (len(x), R)."""
    r = nodes.size
    if r == 1:
        return np.ones((x.size, 1))
    j = np.arange(r)
    bw = (-1.0) ** j * np.sin((2 * j + 1) * np.pi / (2 * r))
    diff = x[:, None] - nodes[None, :]
    exact = diff == 0.0
    diff[exact] = 1.0
    t = bw[None, :] / diff
    ell = t / t.sum(axis=1, keepdims=True)
    rows = exact.any(axis=1)
    if rows.any():
        ell[rows] = exact[rows].astype(float)
    return ell


def synthesize_time_domain(symbols, gains, delays_s, dopplers_hz, waveform: Waveform,
                           tol: float = SYNTHESIS_ACCURACY,
                           eps: float | None = None) -> np.ndarray:
    """Exact received baseband frame, 1-D, M·(N+N_cp) samples at f_s = NΔf.

    Sample i (t_i = i/f_s) is y_i = Σ_k a_k e^{j2π f_D,k t_i} x(t_i − τ_k), with x(t) the
    rectangular-pulse CP-OFDM signal of the paper's eq. (1) built from ``symbols`` D (N, M):
    inside symbol ν, x(t) = (1/√N) Σ_n D(n, ν) e^{j2π nΔf (t − νT_sym − T_CP)}, zero before
    t = 0.  The delayed copy is evaluated from its trigonometric polynomial, so fractional
    delays are exact, the symbol boundary falls where t_i − τ_k crosses it (ISI beyond the
    CP) and the Doppler phase runs through every sample (ICI).  There is no receive filter.

    How (docs/dsp.md §3): with δ_k = τ_k f_s = q_k L + ρ_k, sample p of received symbol μ is
    Σ_k a_k e^{j2π f_D,k μ T_sym} e^{j2π ε_k p/N} (1/√N) Σ_n D(n, ν) e^{j2πn(p−N_cp−ρ_k)/N},
    ν = μ − q_k − [p < ρ_k], ε_k = f_D,k/Δf.  The in-symbol Doppler factor e^{j2π ε p/N} is
    interpolated in ε at R Chebyshev nodes (error ≤ ``tol`` per unit path amplitude; R = 1
    and exact when all Dopplers are equal); each node is one type-1 NUFFT of the paths plus
    one IFFT.  Samples with p < ρ_k (which come from the previous symbol) are corrected with
    a type-2 NUFFT at exactly those points.  ``eps`` is the NUFFT accuracy (default tol).
    """
    d = check_symbols(symbols, waveform)
    a, tau, fd = check_paths(gains, delays_s, dopplers_hz)
    if not (1e-15 < tol < 1e-1):
        raise ArgumentError(f"tol must lie in (1e-15, 0.1), got {tol!r}")
    eps = tol if eps is None else eps
    if not (1e-15 < eps < 1e-1):
        raise ArgumentError(f"eps must lie in (1e-15, 0.1), got {eps!r}")

    warn_unmodelled(tau, fd, waveform, isi_modelled=True)
    n, m, ncp = waveform.n_subcarriers, waveform.n_symbols, waveform.n_cp
    ell_len = waveform.samples_per_symbol
    fs, df, t_sym = waveform.sample_rate, waveform.subcarrier_spacing_hz, waveform.symbol_duration
    y = np.zeros((m, ell_len), complex)
    if a.size == 0:
        return y.ravel()

    delta = tau * fs
    q = np.floor(delta / ell_len).astype(np.int64)
    rho = delta - q * ell_len
    # A delay a hair off a whole sample must not flip the symbol of that boundary sample.
    near = np.abs(rho - np.round(rho)) < 1e-9
    rho[near] = np.round(rho[near])
    q[rho >= ell_len] += 1
    rho[rho >= ell_len] -= ell_len
    keep = q < m  # a path delayed by the whole frame or more contributes nothing
    a, fd, q, rho = a[keep], fd[keep], q[keep], rho[keep]
    if a.size == 0:
        return y.ravel()

    eps_d = fd / df
    lo, hi = float(eps_d.min()), float(eps_d.max())
    centre, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
    theta_max = 2.0 * np.pi * (ell_len - 1) / n
    try:
        n_nodes = chebyshev_order(theta_max, half, tol)
    except ValueError as exc:
        raise ArgumentError(f"{exc} (dopplers_hz span [{float(fd.min())!r}, {float(fd.max())!r}] "
                         f"Hz, Δf = {df!r} Hz); speeds that high are no radar target: check "
                         "the velocities, or use synthesize_frequency_domain") from None
    nodes = centre + half * np.cos((2 * np.arange(n_nodes) + 1) * np.pi / (2 * n_nodes))
    if n_nodes == 1:
        nodes = np.array([centre])
    ell = _lagrange_weights(eps_d, nodes)  # (K, R)

    p = np.arange(ell_len)
    cyc = (p - ncp) % n
    ramps = np.exp(2j * np.pi * np.outer(nodes, p) / n)  # (R, L)
    d_pad = np.concatenate([np.zeros((n, 1), complex), d], axis=1)  # column 0 = "before"

    for qq in np.unique(q):
        sel = q == qq
        d_q = _shifted_symbols(d_pad, qq, m)
        for r0 in range(0, n_nodes, 4):  # chunks of nodes bound the (R, N, M) temporaries
            r1 = min(r0 + 4, n_nodes)
            w = (a[sel, None] * ell[sel, r0:r1]).T
            s = _channel_grid(w, rho[sel] / fs, fd[sel], n, m, df, t_sym, 0.0, "nufft", eps)
            s *= d_q[None]
            z = np.fft.ifft(s, axis=1, norm="ortho")  # (r, N, M): time index m' on axis 1
            for r in range(r1 - r0):
                y += ramps[r0 + r][None, :] * z[r].T[:, cyc]
        _isi_correction(y, d_pad, a[sel], fd[sel], rho[sel], int(qq), waveform, eps)
    return y.ravel()


def _shifted_symbols(d_pad, shift, m):
    """Columns μ = 0..M−1 of D(·, μ − shift), zero where μ − shift < 0; d_pad[:, 0] is 0."""
    idx = np.arange(m) - shift + 1
    idx[idx < 0] = 0
    return d_pad[:, idx]


def _isi_correction(y, d_pad, a, fd, rho, shift, waveform, eps, chunk_elems=1 << 21):
    """Replace symbol μ−q by μ−q−1 on the samples p < ρ_k (added in place to y (M, L))."""
    import finufft

    n_pts = np.ceil(rho).astype(np.int64)
    total = int(n_pts.sum())
    if total == 0:
        return
    n, m, ncp = waveform.n_subcarriers, waveform.n_symbols, waveform.n_cp
    df, t_sym = waveform.subcarrier_spacing_hz, waveform.symbol_duration
    k_of = np.repeat(np.arange(a.size), n_pts)
    starts = np.repeat(np.cumsum(n_pts) - n_pts, n_pts)
    p_of = np.arange(total) - starts
    order = np.argsort(p_of, kind="stable")
    k_of, p_of = k_of[order], p_of[order]

    # Previous symbol ν−1 at sample p sits N + p − ρ samples into its useful part (≡ p − ρ),
    # the current one at p − ρ − N_cp: one polynomial in e^{j2πn(p−ρ)/N} carries both.
    cp_turn = np.exp(-2j * np.pi * np.arange(n) * ncp / n)[:, None]
    delta_d = _shifted_symbols(d_pad, shift + 1, m) - cp_turn * _shifted_symbols(d_pad, shift, m)
    f_modes = np.ascontiguousarray(delta_d.T)  # (M, N): one transform per symbol
    # (M, K) so that gathering one column per point yields a contiguous (M, P) block.
    e_mu_t = np.exp(2j * np.pi * np.outer(np.arange(m) * t_sym, fd))
    chunk = max(1, chunk_elems // m)
    for c0 in range(0, total, chunk):
        kk, pp = k_of[c0:c0 + chunk], p_of[c0:c0 + chunk]
        x = _wrap_phase((pp - rho[kk]) / n)
        vals = finufft.nufft1d2(x, f_modes, eps=eps, isign=1)  # (M, P)
        per_point = (a[kk] / math.sqrt(n)) * np.exp(1j * (n // 2 * x + 2 * np.pi * fd[kk] / df
                                                         * pp / n))
        vals *= per_point[None, :]
        vals *= e_mu_t[:, kk]
        # p is sorted: sum the points that land on the same sample, then add once.
        uniq, first = np.unique(pp, return_index=True)
        y[:, uniq] += np.add.reduceat(vals, first, axis=1)


# ----------------------------------------------------------------------------------------
# noise
# ----------------------------------------------------------------------------------------
def check_noise_figure(noise_figure_db, argument: str = "noise_figure_db") -> float:
    """A receiver noise figure in dB: finite and >= 0 (F = 10^{NF/10} >= 1 by definition:
    a receiver adds noise, it never removes any); ``argument`` names it in the error."""
    if not (isinstance(noise_figure_db, int | float | np.floating)
            and not isinstance(noise_figure_db, bool) and math.isfinite(noise_figure_db)):
        raise ArgumentError("must be a finite number of dB", argument=argument,
                            value=noise_figure_db)
    if noise_figure_db < 0:
        raise ArgumentError("a receiver's noise figure is >= 0 dB by definition (F = "
                            "10^(NF/10) >= 1: a receiver adds noise, it removes none)",
                            argument=argument, value=noise_figure_db)
    return float(noise_figure_db)


def check_tx_power(tx_power_w, argument: str = "tx_power_w") -> float:
    """A transmit power in W that a radar frame can be scaled to: positive and finite.
    (A radar transmitting nothing, 0 W, has no echo: there is no frame to make.)"""
    if not (isinstance(tx_power_w, int | float | np.floating) and not isinstance(tx_power_w, bool)
            and math.isfinite(tx_power_w) and tx_power_w > 0):
        raise ArgumentError("must be positive and finite (a radar transmitting nothing has "
                            "no echo)", argument=argument, value=tx_power_w)
    return float(tx_power_w)


def thermal_noise_power(bandwidth_hz: float, noise_figure_db: float,
                        temperature_k: float = 290.0) -> float:
    """Receiver noise power k·T·B·F in watts (F = 10^{NF/10}; NF >= 0 dB)."""
    for name, v in (("bandwidth_hz", bandwidth_hz), ("temperature_k", temperature_k)):
        if not (isinstance(v, int | float | np.floating) and math.isfinite(v) and v > 0):
            raise ArgumentError("must be positive and finite", argument=name, value=v)
    check_noise_figure(noise_figure_db)
    return BOLTZMANN * temperature_k * bandwidth_hz * 10.0 ** (noise_figure_db / 10.0)


def add_noise(signal, noise_variance: float, rng=None) -> np.ndarray:
    """signal + circular complex Gaussian noise of variance σ² = ``noise_variance`` per
    element (σ²/2 per real and imaginary part)."""
    s = np.asarray(signal)
    if not (math.isfinite(noise_variance) and noise_variance >= 0):
        raise ArgumentError("must be finite and >= 0", argument="noise_variance",
                            value=noise_variance)
    rng = np.random.default_rng(rng)
    scale = math.sqrt(noise_variance / 2.0)
    noise = rng.standard_normal(s.shape) + 1j * rng.standard_normal(s.shape)
    return s + scale * noise


def add_thermal_noise(signal, tx_power_w: float, noise_figure_db: float, bandwidth_hz: float,
                      temperature_k: float = 290.0, rng=None) -> np.ndarray:
    """Add receiver thermal noise to a signal expressed relative to the transmit amplitude.

    Scaling: path gains a_k are amplitude ratios, so the synthesised signal is in units of
    √P_tx (the transmit frame has unit mean power per sample).  Thermal noise kT·B·F watts
    is therefore σ² = kT·B·F / P_tx in these units, per time sample at f_s = B.  Because the
    OFDM transforms here are unitary the same σ² holds per subcarrier cell, so this works on
    a time-domain frame and on D_r (N, M) alike.  B is normally ``waveform.bandwidth``.
    """
    check_tx_power(tx_power_w)
    var = thermal_noise_power(bandwidth_hz, noise_figure_db, temperature_k) / tx_power_w
    return add_noise(signal, var, rng)
