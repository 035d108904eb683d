"""Antenna arrays: element positions in the world and the channel of every element pair.

A snapshot holds each link's paths once, between the radars' reference points (their
``position``), with the full polyline; the directions of departure and arrival come from
that polyline (:func:`path_directions`), so a snapshot is the "per path, angles stored"
form of an array channel (docs/dsp.md §9). The channel of transmit element i and receive
element j is then computed here, in one of two ways:

* **synthetic array** (:func:`synthetic_channels`, the default): the plane-wave phase of
  each element's offset along the path's departure and arrival directions,

      a_k,ij = a_k · exp(+j k p_i·d_dep,k) · exp(+j k q_j·d_arr,k),

  p_i, q_j the elements' offsets from the reference points, d_dep the unit direction from
  the transmitter to the path's first point, d_arr the unit direction from the receiver to
  the path's last point (where the wave comes from), k = 2π/λ. With e^{+jωt} a path's
  phase is −kL; moving an element by p changes the path length by −p·d to first order,
  hence the + signs. Delay and Doppler stay those of the reference path (narrowband,
  rigid array).
* **exact path-length correction** (:func:`exact_channels`): the same paths with the
  interaction points held fixed and the first and last legs recomputed from the displaced
  elements in float64: L_ij = |x_1 − (x_0 + p_i)| + Σ middle legs + |(x_{n+1} + q_j) − x_n|,
  gain a_k · exp(−jk(L_ij − L_k)), delay τ_k + (L_ij − L_k)/c. It is exact for line of
  sight and for returns from a point (scattering tiles, PO facet centroids). For specular
  and diffracted points, which move with the element, it is exact to first order and
  errs at second order in the element offset, like the synthetic array but by another
  term (a mirror at distance h: −k(q + p)²/(4h) where the synthetic array has
  +k(q − p)²/(4h); tests/test_element_trace.py). It is not a re-trace: paths that appear
  or vanish between elements are not found. Amplitudes (spreading) are those of the
  reference path. The re-trace is :mod:`clradcom.radar.element_trace`.

The synthetic array is the exact one's first-order expansion: they agree when the array's
extent D satisfies D²/(λ R) ≪ 1 (R the distance to the first/last interaction), and the
exact form is needed in the near field (tests/test_arrays.py: a point 1 km away and 0.5 m
away). Each element's own pattern and polarisation enter through :func:`element_gains`.
"""

from __future__ import annotations

import numpy as np

from clradcom.errors import ArgumentError
from clradcom.radar.waveform import SPEED_OF_LIGHT

__all__ = ["element_gains", "element_positions", "exact_channels", "path_angles",
           "path_directions", "synthetic_channels"]


def element_positions(position, orientation, positions_local=None) -> np.ndarray:
    """(E, 3) world positions of an array's elements: ``position`` + R · local offset
    (R = ``orientation``, columns = the radar's local axes). ``positions_local`` None (a
    radar without array) gives its position alone, (1, 3)."""
    p = np.asarray(position, dtype=np.float64).reshape(3)
    r = np.asarray(orientation, dtype=np.float64).reshape(3, 3)
    if positions_local is None:
        return p[None, :].copy()
    loc = np.asarray(positions_local, dtype=np.float64)
    if loc.ndim != 2 or loc.shape[1] != 3 or not np.all(np.isfinite(loc)):
        raise ArgumentError("must be finite (E, 3) offsets", argument="positions_local",
                            value=f"shape {loc.shape}")
    return p + loc @ r.T


def _unit(v):
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    if np.any(n == 0):
        raise ArgumentError("a path has a leg of zero length", argument="paths")
    return v / n


def _ends(paths):
    """Per path: tx point, first point after it, last point before rx, rx point."""
    pts = np.asarray(paths.points, dtype=np.float64)
    n = np.asarray(paths.n_interactions, dtype=np.int64)
    idx = np.arange(n.size)
    return pts[:, 0], pts[:, 1], pts[idx, n], pts[idx, n + 1], n


def path_directions(paths) -> tuple[np.ndarray, np.ndarray]:
    """(d_dep, d_arr), each (P, 3) world unit vectors: from the transmitter towards the
    path's first point, and from the receiver towards its last point (the direction the
    wave arrives from)."""
    x0, x1, xn, xr, _ = _ends(paths)
    return _unit(x1 - x0), _unit(xn - xr)


def path_angles(paths, orientation_tx, orientation_rx) -> dict:
    """Azimuth and elevation (rad) of departure and arrival in the radars' own frames
    (azimuth from boresight +x towards +y, elevation above the local x-y plane)."""
    d_dep, d_arr = path_directions(paths)
    out = {}
    for name, d, r in (("departure", d_dep, orientation_tx), ("arrival", d_arr, orientation_rx)):
        loc = d @ np.asarray(r, dtype=np.float64)
        out[f"{name}_azimuth"] = np.arctan2(loc[:, 1], loc[:, 0])
        out[f"{name}_elevation"] = np.arcsin(np.clip(loc[:, 2], -1.0, 1.0))
    return out


def _offsets(name, value):
    a = np.asarray(value, dtype=np.float64)
    if a.ndim != 2 or a.shape[1] != 3 or not np.all(np.isfinite(a)):
        raise ArgumentError("must be finite (E, 3) world offsets from the reference point",
                            argument=name, value=f"shape {a.shape}")
    return a


def _wavenumber(wavelength_m):
    lam = float(wavelength_m)
    if not (np.isfinite(lam) and lam > 0):
        raise ArgumentError("must be a positive length (m)", argument="wavelength_m",
                            value=wavelength_m)
    return 2.0 * np.pi / lam


def _base(paths, gains, et, er):
    """The gains the array phases multiply: the paths' own (P,), or each element pair's
    (E_tx, E_rx, P) (:func:`element_gains`)."""
    if gains is None:
        return np.asarray(paths.gain)[None, None, :]
    g = np.asarray(gains)
    if g.shape != (et, er, len(paths.gain)):
        raise ArgumentError(f"must be ({et}, {er}, {len(paths.gain)}) element-pair gains",
                            argument="gains", value=f"shape {g.shape}")
    return g


def synthetic_channels(paths, tx_offsets, rx_offsets, wavelength_m, gains=None) -> np.ndarray:
    """Gains (E_tx, E_rx, P) of every element pair, plane-wave phases on the reference
    paths' gains (module docstring), or on ``gains`` (E_tx, E_rx, P) when given (each
    pair's own patterns, :func:`element_gains`). ``tx_offsets``/``rx_offsets``: (E, 3)
    world offsets of the elements from the link's transmit/receive reference points."""
    k = _wavenumber(wavelength_m)
    p, q = _offsets("tx_offsets", tx_offsets), _offsets("rx_offsets", rx_offsets)
    base = _base(paths, gains, p.shape[0], q.shape[0])
    d_dep, d_arr = path_directions(paths)
    steer_tx = np.exp(1j * k * (p @ d_dep.T))  # (Et, P)
    steer_rx = np.exp(1j * k * (q @ d_arr.T))  # (Er, P)
    return steer_tx[:, None, :] * steer_rx[None, :, :] * base


def exact_channels(paths, tx_offsets, rx_offsets, wavelength_m, gains=None):
    """Gains and delays (E_tx, E_rx, P) of every element pair with the first and last legs
    of each path recomputed exactly from the displaced elements (module docstring);
    ``gains`` as :func:`synthetic_channels`."""
    k = _wavenumber(wavelength_m)
    p, q = _offsets("tx_offsets", tx_offsets), _offsets("rx_offsets", rx_offsets)
    base = _base(paths, gains, p.shape[0], q.shape[0])
    x0, x1, xn, xr, n = _ends(paths)
    pts = np.asarray(paths.points, dtype=np.float64)
    legs = np.linalg.norm(np.diff(pts, axis=1), axis=2)  # NaN past the rx row
    idx = np.arange(n.size)
    total = np.array([np.sum(legs[i, :n[i] + 1]) for i in idx])
    # first leg from each tx element, last leg to each rx element
    first = np.linalg.norm(x1[None, :, :] - (x0[None, :, :] + p[:, None, :]), axis=2)  # (Et,P)
    last = np.linalg.norm((xr[None, :, :] + q[:, None, :]) - xn[None, :, :], axis=2)  # (Er,P)
    direct = n == 0
    middle = total - legs[idx, 0] - np.where(direct, 0.0, legs[idx, n])
    length = first[:, None, :] + last[None, :, :] + middle[None, None, :]
    if np.any(direct):  # line of sight: one leg between the two displaced elements
        d = (x1[None, None, direct] + q[None, :, None, :]) - (x0[None, None, direct]
                                                              + p[:, None, None, :])
        length[:, :, direct] = np.linalg.norm(d, axis=3)
    dl = length - total[None, None, :]
    out = base * np.exp(-1j * k * dl)
    delays = np.asarray(paths.delay_s)[None, None, :] + dl / SPEED_OF_LIGHT
    return out, delays


def element_gains(paths, radar) -> np.ndarray:
    """Gains (E_tx, E_rx, P) of every element pair before the array's phases, with each
    element's own pattern and polarisation (``ArrayLayout.patterns``; the radar's where
    an array gives none): a_ij = c_rx,j(d_arr)ᵀ M c_tx,i(d_dep), M the path's 2 × 2
    polarimetric matrix (antenna patterns left out, its carrier phase and spreading in)
    and c = pattern.field(direction in the radar's frame) the element's (C_θ, C_φ) with
    its Jones vector (:func:`clradcom.physics.em.path_gains`, the tracer's own product).
    Monostatic only (the radar is both ends). Where no array gives its elements patterns
    this is the paths' own gain on every pair, unchanged (P,) broadcast."""
    et = 1 if radar.tx_array is None else radar.tx_array.n_elements
    er = 1 if radar.rx_array is None else radar.rx_array.n_elements
    p = len(paths.gain)
    tx_pat = None if radar.tx_array is None else radar.tx_array.patterns
    rx_pat = None if radar.rx_array is None else radar.rx_array.patterns
    if tx_pat is None and rx_pat is None:
        return np.broadcast_to(np.asarray(paths.gain), (et, er, p))
    r = np.asarray(radar.orientation, dtype=np.float64)
    d_dep, d_arr = path_directions(paths) if p else (np.zeros((0, 3)), np.zeros((0, 3)))
    loc_dep, loc_arr = d_dep @ r, d_arr @ r
    c_tx = np.stack([np.asarray(pt.field(loc_dep), complex)
                     for pt in (tx_pat or [radar.pattern] * et)])  # (Et, P, 2)
    c_rx = np.stack([np.asarray(pt.field(loc_arr), complex)
                     for pt in (rx_pat or [radar.pattern] * er)])  # (Er, P, 2)
    m = np.asarray(paths.matrix)
    return np.einsum("jpa,pab,ipb->ijp", c_rx, m, c_tx)
