"""The maps a RadCom engineer asks of a street, from one-way radio maps (docs/maps.md).

Every map here is built from :func:`clradcom.maps.radio_map` (one transmitter's mean
incoherent path gain per cell) and the radar's link budget:

* :func:`received_power_map` - P_tx g(cell): the power a receiver with ``rx``'s antenna
  takes from ``tx``'s frame in each cell.
* :func:`sinr_map` - the data link: ``tx``'s frame received by a receiver with ``rx``'s
  antenna in each cell, another radar ``interferer`` transmitting at the same time;
  SINR = P_tx g_tx / (P_i g_i + k T B F_rx) with B = N Delta f, and the BER the comms
  model gives at that SINR (:func:`clradcom.radar.comms.awgn_error_rates`, the other
  radar's OFDM frame counted as Gaussian noise).
* :func:`radar_snr_map` - monostatic detection: a point target of RCS sigma in each cell,
  SNR after processing = P_tx g_1^2 (4 pi sigma / lambda^2) G_p / (k T B F), g_1 the
  radar's one-way map to a polarisation-matched isotropic point (the return path is the
  same by reciprocity; the incoherent sum of its K^2 two-way paths is (sum |a_k|^2)^2),
  G_p = N M / (ENBW_range ENBW_doppler) the OFDM processing gain (docs/dsp.md).
* :func:`inr_map` - the interference a second radar causes in the victim's receiver,
  per position of the second: by reciprocity (the bilinear receive projection of
  :func:`clradcom.physics.em.path_gains`), the gain from the interferer in a cell to the
  victim is the gain from the victim to a receiver in the cell with the interferer's
  antenna, so one map from the victim gives every position; INR = P_i g / (k T B F_victim)
  per received sample, before processing.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from clradcom.errors import ArgumentError
from clradcom.maps import MapGrid, MapSettings, RadioMap, find_radar, radio_map
from clradcom.physics.em import C0
from clradcom.radar.comms import COMMS_MODULATIONS, awgn_error_rates
from clradcom.radar.processing import get_window
from clradcom.radar.synthesis import thermal_noise_power
from clradcom.radar.waveform import Waveform
from clradcom.scene.records import Radar, Scene

__all__ = ["MAP_KINDS", "KindMap", "enbw", "inr_map", "processing_gain",
           "radar_snr_map", "received_power_map", "sinr_map"]

#: The kinds of :func:`clradcom.commands.map` (``clradcom map --kind``)
MAP_KINDS = ("gain", "sinr", "radar", "inr")


@dataclass
class KindMap:
    """One map of a kind: ``value_db`` (ny, nx) in dB (NaN where no ray reached), its
    ``quantity`` (a label with the unit), the one-way radio maps it came from, and
    extra per-cell arrays (``ber`` of a SINR map)."""

    kind: str
    quantity: str
    value_db: np.ndarray
    maps: tuple[RadioMap, ...]
    extra: dict

    @property
    def grid(self) -> MapGrid:
        return self.maps[0].grid

    @property
    def converged(self) -> np.ndarray:
        """Cells where every map it came from satisfies the convergence rule."""
        return np.logical_and.reduce([m.converged for m in self.maps])


def _db(x) -> np.ndarray:
    x = np.asarray(x, dtype=np.float64)
    with np.errstate(divide="ignore"):
        return np.where(x > 0, 10.0 * np.log10(np.where(x > 0, x, 1.0)), np.nan)


def _noise_w(radar: Radar, waveform: Waveform, key: str) -> float:
    if radar.noise_figure_db is None:
        raise ArgumentError(f"radar {radar.name!r} has no noise_figure_db: give it one in "
                            "the scene to compute its noise", argument=key, value=radar.name)
    return thermal_noise_power(waveform.bandwidth, radar.noise_figure_db)


def _radar_of(scene: Scene, which, key: str) -> Radar:
    radar = find_radar(scene, which, key)
    if radar is None:
        raise ArgumentError("names no radar", argument=key, value=which)
    return radar


def enbw(window, length: int) -> float:
    """Equivalent noise bandwidth in bins, N sum w^2 / (sum w)^2 (1 for rect, 1.5 Hann)."""
    w = get_window(window, length)
    return float(length * np.sum(w * w) / np.sum(w) ** 2)


def processing_gain(waveform: Waveform, window_range="rect", window_doppler="rect") -> float:
    """The OFDM radar's processing gain N M / (ENBW_n ENBW_mu) (docs/dsp.md, section 4):
    a target's SNR in its image cell over the SNR of one subcarrier and symbol."""
    n, m = waveform.n_subcarriers, waveform.n_symbols
    return n * m / (enbw(window_range, n) * enbw(window_doppler, m))


def received_power_map(scene: Scene, tx, grid: MapGrid, rx=None,
                       settings: MapSettings | None = None, **kw) -> KindMap:
    """(a) P_tx g in dBW per cell: ``tx``'s frame received with ``rx``'s antenna (None:
    gain 1, every polarisation)."""
    m = radio_map(scene, tx, grid, rx=rx, settings=settings, **kw)
    return KindMap("gain", "received power (dBW)", _db(m.received_power_w), (m,),
                   {"path_gain_db": _db(m.gain)})


def sinr_map(scene: Scene, tx, rx, interferer, grid: MapGrid, waveform: Waveform,
             settings: MapSettings | None = None, modulation: str | None = None,
             **kw) -> KindMap:
    """(b) SINR in dB of ``tx``'s frame at a receiver with ``rx``'s antenna and noise
    figure in each cell, ``interferer`` (a radar, or None for none) transmitting at the
    same time; ``extra["ber"]`` the comms model's BER at that SINR for ``modulation``
    (default: the waveform's)."""
    rx_radar = _radar_of(scene, rx, "rx")
    mod = (modulation or waveform.modulation).lower()
    if mod not in COMMS_MODULATIONS:
        raise ArgumentError(f"the comms model's BER covers {', '.join(COMMS_MODULATIONS)}",
                            argument="modulation", value=mod)
    noise = _noise_w(rx_radar, waveform, "rx")
    signal = radio_map(scene, tx, grid, rx=rx_radar, settings=settings, **kw)
    maps = [signal]
    interference = np.zeros_like(signal.gain)
    if interferer is not None:
        other = radio_map(scene, interferer, grid, rx=rx_radar, settings=settings, **kw)
        maps.append(other)
        interference = other.received_power_w
    sinr = signal.received_power_w / (interference + noise)
    sinr_db = _db(sinr)
    ber = np.full(sinr.shape, 0.5)
    reached = sinr > 0
    ber[reached] = awgn_error_rates(mod, sinr_db[reached])[1]
    return KindMap("sinr", "SINR (dB)", sinr_db, tuple(maps),
                   {"ber": ber, "noise_w": noise, "modulation": mod,
                    "inr_db": _db(interference / noise)})


def radar_snr_map(scene: Scene, radar, grid: MapGrid, waveform: Waveform,
                  rcs_m2: float = 1.0, settings: MapSettings | None = None,
                  window_range="rect", window_doppler="rect", **kw) -> KindMap:
    """(c) SNR in dB after processing of a point target of ``rcs_m2`` in each cell, seen
    by the monostatic ``radar``: P_tx g_1^2 (4 pi sigma / lambda^2) G_p / (k T B F)."""
    if not (isinstance(rcs_m2, int | float) and np.isfinite(rcs_m2) and rcs_m2 > 0):
        raise ArgumentError("must be a positive RCS in m^2", argument="rcs_m2", value=rcs_m2)
    me = _radar_of(scene, radar, "radar")
    noise = _noise_w(me, waveform, "radar")
    one_way = radio_map(scene, me, grid, rx=None, settings=settings, **kw)
    lam = C0 / float(scene.carrier_hz)
    gp = processing_gain(waveform, window_range, window_doppler)
    snr = me.tx_power_w * one_way.gain**2 * 4.0 * np.pi * rcs_m2 / lam**2 * gp / noise
    return KindMap("radar", f"SNR after processing, {rcs_m2:g} m² target (dB)", _db(snr),
                   (one_way,), {"processing_gain_db": float(10 * np.log10(gp)),
                                "noise_w": noise})


def inr_map(scene: Scene, victim, interferer, grid: MapGrid, waveform: Waveform,
            settings: MapSettings | None = None, **kw) -> KindMap:
    """(d) INR in dB that ``interferer`` (its antenna, orientation and power) causes in
    ``victim``'s receiver when placed in each cell, per received sample."""
    me = _radar_of(scene, victim, "victim")
    other = _radar_of(scene, interferer, "interferer")
    noise = _noise_w(me, waveform, "victim")
    m = radio_map(scene, me, grid, rx=other, settings=settings, **kw)
    return KindMap("inr", f"INR at {me.name} (dB)", _db(other.tx_power_w * m.gain / noise),
                   (m,), {"noise_w": noise})
