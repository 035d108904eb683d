"""OFDM RadCom waveform: parameters, derived radar figures, symbols, CP-OFDM (de)modulation.

Defaults are the paper's Table I (Sit et al., APWC 2011): f_c = 24 GHz, N = 1024,
Δf = 90.909 kHz, T = 1/Δf ≈ 11 µs, T_CP = 1.375 µs, M = 256.  Every derived figure
(bandwidth, Δr, r_max, v_max, Δv, ...) is computed from those parameters, never typed in
(formulas: Sturm & Wiesbeck, Proc. IEEE 99(7), 2011; docs/dsp.md §1).

Discrete-time conventions (docs/dsp.md §2):
- subcarrier n = 0..N-1 sits at baseband frequency nΔf (the paper's f_n = nΔf);
- sample rate f_s = NΔf; symbol μ occupies samples [μL, (μ+1)L), L = N + N_cp, the first
  N_cp of which are the cyclic prefix;
- the transforms are unitary: x = √N·IDFT(D), D_r = DFT(y)/√N, so white noise of variance
  σ² per time sample has variance σ² per subcarrier cell too.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from clradcom.errors import ArgumentError
from clradcom.scene.records import MODULATIONS

SPEED_OF_LIGHT = 299_792_458.0

#: |T·Δf − 1| above this is a contradiction, not rounding (90.909 kHz vs 11 µs is 1e-6).
ORTHOGONALITY_TOLERANCE = 1e-4
#: T_CP·f_s may miss an integer by this many samples (1.375 µs·93.0908 MHz = 127.99987).
CP_SAMPLE_TOLERANCE = 1e-3



def _positive_finite(name: str, value) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError, OverflowError):
        raise ArgumentError("must be a real number", argument=name, value=value) from None
    if not math.isfinite(v) or v <= 0.0:
        raise ArgumentError("must be positive and finite", argument=name, value=value)
    return v


def _positive_int(name: str, value) -> int:
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value <= 0:
        raise ArgumentError("must be a positive integer", argument=name, value=value)
    return int(value)


@dataclass(frozen=True)
class Waveform:
    """CP-OFDM RadCom waveform parameters (SI units).

    ``useful_duration_s`` (T) may be given; it is then checked against 1/Δf because the
    subcarriers are orthogonal only for T = 1/Δf (paper eq. after (1)).  Left as None it is
    derived as 1/Δf.  ``cp_s`` must be a whole number of samples at f_s = NΔf; the value
    actually used is ``n_cp / sample_rate`` (within ``CP_SAMPLE_TOLERANCE`` samples of the
    value given).
    """

    carrier_hz: float = 24e9
    n_subcarriers: int = 1024
    subcarrier_spacing_hz: float = 90.909e3
    cp_s: float = 1.375e-6
    n_symbols: int = 256
    modulation: str = "qpsk"
    useful_duration_s: float | None = None

    def __post_init__(self):
        fc = _positive_finite("carrier_hz", self.carrier_hz)
        n = _positive_int("n_subcarriers", self.n_subcarriers)
        df = _positive_finite("subcarrier_spacing_hz", self.subcarrier_spacing_hz)
        _positive_int("n_symbols", self.n_symbols)
        try:
            cp = float(self.cp_s)
        except (TypeError, ValueError):
            raise ArgumentError("must be a real number", argument="cp_s",
                                value=self.cp_s) from None
        if not math.isfinite(cp) or cp < 0.0:
            raise ArgumentError("must be non-negative and finite", argument="cp_s",
                                value=self.cp_s)
        if not isinstance(self.modulation, str) or self.modulation.lower() not in MODULATIONS:
            raise ArgumentError(f"must be one of {MODULATIONS}", argument="modulation",
                                value=self.modulation)
        if self.useful_duration_s is not None:
            t = _positive_finite("useful_duration_s", self.useful_duration_s)
            if abs(t * df - 1.0) > ORTHOGONALITY_TOLERANCE:
                raise ArgumentError(
                    f"contradicts subcarrier_spacing_hz={df!r}: "
                    f"orthogonal OFDM needs T = 1/Δf = {1.0 / df!r} s, but T·Δf = {t * df!r} "
                    f"(tolerance {ORTHOGONALITY_TOLERANCE})", argument="useful_duration_s",
                    value=self.useful_duration_s)
        if fc <= n * df / 2:
            raise ArgumentError(
                f"must exceed half the bandwidth N·Δf/2 = {n * df / 2!r} Hz (N = {n}, "
                f"Δf = {df!r} Hz)", argument="carrier_hz", value=self.carrier_hz)
        if cp * df >= 1.0:
            raise ArgumentError(
                f"the cyclic prefix must be shorter than the symbol it precedes, "
                f"T = 1/Δf = {1.0 / df!r} s", argument="cp_s", value=self.cp_s)
        n_cp_exact = cp * n * df
        if abs(n_cp_exact - round(n_cp_exact)) > CP_SAMPLE_TOLERANCE:
            step = cp_subcarrier_step(cp, df)
            raise ArgumentError(
                f"is {n_cp_exact!r} samples at the sample rate N·Δf = {n * df!r} Hz (N = {n});"
                f" it must be a whole number of samples (±{CP_SAMPLE_TOLERANCE})"
                + ("" if step is None else f": N a multiple of {step} makes it one"),
                argument="cp_s", value=self.cp_s)

    # --- sampling ------------------------------------------------------------------------
    @property
    def sample_rate(self) -> float:
        """f_s = NΔf (critically sampled complex baseband)."""
        return self.n_subcarriers * self.subcarrier_spacing_hz

    @property
    def n_cp(self) -> int:
        """Cyclic-prefix length in samples, round(T_CP·f_s)."""
        return int(round(self.cp_s * self.sample_rate))

    @property
    def samples_per_symbol(self) -> int:
        """L = N + N_cp."""
        return self.n_subcarriers + self.n_cp

    @property
    def n_samples(self) -> int:
        """Frame length M·L in samples."""
        return self.n_symbols * self.samples_per_symbol

    # --- durations -----------------------------------------------------------------------
    @property
    def useful_duration(self) -> float:
        """Elementary symbol duration T = N/f_s = 1/Δf."""
        return 1.0 / self.subcarrier_spacing_hz

    @property
    def cp_duration(self) -> float:
        """T_CP actually used: N_cp/f_s."""
        return self.n_cp / self.sample_rate

    @property
    def symbol_duration(self) -> float:
        """T_sym = T + T_CP (the paper's T_sym, Sturm's T_O)."""
        return self.samples_per_symbol / self.sample_rate

    @property
    def frame_duration(self) -> float:
        return self.n_symbols * self.symbol_duration

    @property
    def fft_window_centre(self) -> float:
        """Time of the centre of symbol 0's FFT window, T_CP + (N−1)/(2f_s).

        A Doppler f_D observed through the receiver FFT carries the phase
        2πf_D(μT_sym + this): the Dirichlet kernel's phase πε(N−1)/N (docs/dsp.md §3).
        """
        return self.cp_duration + (self.n_subcarriers - 1) / (2.0 * self.sample_rate)

    # --- radar figures -------------------------------------------------------------------
    @property
    def bandwidth(self) -> float:
        """B = NΔf."""
        return self.sample_rate

    @property
    def wavelength(self) -> float:
        return SPEED_OF_LIGHT / self.carrier_hz

    @property
    def range_resolution(self) -> float:
        """Δr = c/(2NΔf)."""
        return SPEED_OF_LIGHT / (2.0 * self.n_subcarriers * self.subcarrier_spacing_hz)

    @property
    def max_range(self) -> float:
        """Unambiguous range r_max = c/(2Δf)."""
        return SPEED_OF_LIGHT / (2.0 * self.subcarrier_spacing_hz)

    @property
    def isi_free_range(self) -> float:
        """Largest range whose echo stays inside the cyclic prefix, c·T_CP/2."""
        return SPEED_OF_LIGHT * self.cp_duration / 2.0

    @property
    def max_velocity(self) -> float:
        """Unambiguous velocity ±c/(4 f_c T_sym)."""
        return SPEED_OF_LIGHT / (4.0 * self.carrier_hz * self.symbol_duration)

    @property
    def velocity_resolution(self) -> float:
        """Δv = c/(2 f_c M T_sym)."""
        return SPEED_OF_LIGHT / (2.0 * self.carrier_hz * self.n_symbols * self.symbol_duration)

    # --- conversions (monostatic radar: τ = 2r/c, f_D = 2v f_c/c) -----------------------
    def range_to_delay(self, range_m):
        return 2.0 * np.asarray(range_m, dtype=float) / SPEED_OF_LIGHT

    def velocity_to_doppler(self, velocity_mps):
        """f_D = 2v/λ; positive v (approaching) gives positive Doppler."""
        return 2.0 * np.asarray(velocity_mps, dtype=float) / self.wavelength

    def summary(self) -> dict:
        """All derived figures, for tables and logs."""
        names = (
            "sample_rate", "n_cp", "useful_duration", "cp_duration", "symbol_duration",
            "frame_duration", "bandwidth", "wavelength", "range_resolution", "max_range",
            "isi_free_range", "max_velocity", "velocity_resolution",
        )
        return {k: getattr(self, k) for k in names}


def cp_subcarrier_step(cp_s: float, subcarrier_spacing_hz: float,
                       limit: int = 1 << 16) -> int | None:
    """Smallest N step such that a cyclic prefix ``cp_s`` is a whole number of samples at
    N·Δf for every multiple of it (8 for the paper's 1.375 µs at 90.909 kHz), or None
    where no N up to ``limit`` does."""
    for n in range(1, limit + 1):
        exact = cp_s * n * subcarrier_spacing_hz
        if abs(exact - round(exact)) <= CP_SAMPLE_TOLERANCE:
            return n
    return None


def round_cyclic_prefix(cp_s: float, sample_rate_hz: float) -> int:
    """A cyclic prefix of ``cp_s`` seconds as a whole number of samples at
    ``sample_rate_hz``: the nearest one, halves rounded up (floor(T_CP·f_s + 1/2))."""
    fs = _positive_finite("sample_rate_hz", sample_rate_hz)
    try:
        cp = float(cp_s)
    except (TypeError, ValueError):
        raise ArgumentError("must be a real number", argument="cp_s", value=cp_s) from None
    if not math.isfinite(cp) or cp < 0.0:
        raise ArgumentError("must be non-negative and finite", argument="cp_s", value=cp_s)
    return int(math.floor(cp * fs + 0.5))


def paper_waveform(**overrides) -> Waveform:
    """The paper's Table I waveform (the dataclass defaults), with optional overrides."""
    return Waveform(**overrides)


def constellation(modulation: str) -> np.ndarray:
    """Unit-average-power constellation points for ``modulation``."""
    mod = str(modulation).lower()
    if mod == "bpsk":
        return np.array([1.0 + 0j, -1.0 + 0j])
    psk = {"qpsk": 4, "8psk": 8, "16psk": 16}
    if mod in psk:
        m = psk[mod]
        # QPSK on the diagonals (π/4 offset), the usual convention.
        offset = np.pi / 4 if m == 4 else 0.0
        return np.exp(1j * (2 * np.pi * np.arange(m) / m + offset))
    qam = {"16qam": 4, "64qam": 8, "256qam": 16}
    if mod in qam:
        side = qam[mod]
        levels = np.arange(-(side - 1), side, 2, dtype=float)
        pts = (levels[:, None] + 1j * levels[None, :]).ravel()
        return pts / np.sqrt(np.mean(np.abs(pts) ** 2))
    raise ArgumentError(f"must be one of {MODULATIONS}", argument="modulation", value=modulation)


def random_symbols(waveform: Waveform, seed=None) -> np.ndarray:
    """Random modulation symbols D, shape (N, M) = (subcarrier, symbol), unit mean power.

    ``seed`` is anything ``numpy.random.default_rng`` accepts (an int or a Generator).
    """
    rng = np.random.default_rng(seed)
    pts = constellation(waveform.modulation)
    idx = rng.integers(0, pts.size, size=(waveform.n_subcarriers, waveform.n_symbols))
    return pts[idx]


def check_symbols(symbols, waveform: Waveform, name: str = "symbols") -> np.ndarray:
    d = np.asarray(symbols)
    shape = (waveform.n_subcarriers, waveform.n_symbols)
    if d.shape != shape:
        raise ArgumentError(f"must have shape (N, M) = {shape}, got {d.shape}", argument=name)
    if not np.all(np.isfinite(d)):
        raise ArgumentError("contains NaN or infinite values", argument=name)
    return d.astype(complex, copy=False)


def ofdm_modulate(symbols, waveform: Waveform) -> np.ndarray:
    """CP-OFDM transmit frame: 1-D, M·(N+N_cp) samples at f_s = NΔf.

    Sample μL + N_cp + m holds x = (1/√N) Σ_n D(n, μ) e^{j2πnm/N} (paper eq. (1) sampled,
    unitary scaling); the first N_cp samples of each symbol repeat its last N_cp.
    """
    d = check_symbols(symbols, waveform)
    n, ncp = waveform.n_subcarriers, waveform.n_cp
    body = np.fft.ifft(d, axis=0, norm="ortho")  # (N, M)
    frame = np.concatenate([body[n - ncp:, :], body], axis=0) if ncp else body
    return np.ascontiguousarray(frame.T).ravel()


def ofdm_demodulate(rx, waveform: Waveform) -> np.ndarray:
    """Received symbols D_r, shape (N, M): drop each cyclic prefix, unitary DFT.

    ``rx`` must hold at least M·L samples; extra trailing samples are ignored.
    """
    y = np.asarray(rx)
    if y.ndim != 1:
        raise ArgumentError(f"must be 1-D, got shape {y.shape}", argument="rx")
    need = waveform.n_samples
    if y.size < need:
        raise ArgumentError(f"has {y.size} samples, the waveform needs M·(N+N_cp) = {need}",
                            argument="rx")
    if not np.all(np.isfinite(y[:need])):
        raise ArgumentError("contains NaN or infinite values", argument="rx")
    frames = y[:need].reshape(waveform.n_symbols, waveform.samples_per_symbol)
    body = frames[:, waveform.n_cp:]
    return np.fft.fft(body, axis=1, norm="ortho").T.copy()
