"""Diffuse-scattering tiles resolved on the device: tiles, their sight of tx and rx, and
their Lambertian power, in the kernels of ``kernels/scatter.cl``.

:func:`tile_sight` cuts the traced scattering triangles into tiles (the host's
:func:`clradcom.mechanisms.scattering.make_tiles` rule and order), tests every tile centre's
front side and float32 sight line to tx and rx (the casts of
:func:`clradcom.device.visibility.surface_sees`, bit for bit) and packs the tiles both ends
see with an atomic counter, each with its centre and Lambertian power. Only those rows come
back (and, when asked, the per-tile flags and centres that reflected legs need); what is
cheap and exact stays with the caller: the float64 antenna ends
(:func:`clradcom.device.visibility.antenna_blocked`), antenna patterns, polarisation and the
threshold. Needs a device with fp64 (:func:`has_fp64`); positions are double throughout.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from clradcom.device.raycast import RayCaster
from clradcom.device.visibility import SIGHT_STOP
from clradcom.errors import ArgumentError

__all__ = ["TileSight", "has_fp64", "tile_sight"]

SOURCE = "scatter.cl"
#: flag bits of :func:`tile_sight`'s per-tile flags
SEES_TX, SEES_RX = 1, 2


@dataclass
class TileSight:
    """What :func:`tile_sight` returns, tile indices counting the traced tiles in order.

    ``tile`` (R,) int64 ascending: the tiles both ends see (float32 casts);
    ``centre`` (R,3) and ``power`` (R,) theirs (power: |a|^2 for isotropic antennas and
    Gamma = 1). ``flags`` (N,) uint8 (bits SEES_TX, SEES_RX) and ``centres`` (N,3) of every
    tile when asked for, else None."""

    tile: np.ndarray
    centre: np.ndarray
    power: np.ndarray
    flags: np.ndarray | None = None
    centres: np.ndarray | None = None


def has_fp64(caster: RayCaster) -> bool:
    """True when the caster's device has double precision (the kernels need it)."""
    return bool(caster.runtime.info.has_double)


def _xyz(name, value):
    a = np.asarray(value, dtype=np.float64).reshape(-1)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise ArgumentError("must be 3 finite coordinates", argument=name, value=value)
    return [np.float64(x) for x in a]


def tile_sight(caster: RayCaster, vertices, normals, tile_area, scattering, prim, subdivisions,
               tx_pos, rx_pos, wavelength, *, all_ends: bool, monostatic: bool,
               want_tiles: bool = False) -> TileSight:
    """Tiles of K triangles, their sight of tx and rx and their Lambertian power.

    vertices (K,3,3), normals (K,3) unit, tile_area (K,) the area of one of the triangle's
    tiles, scattering (K,) S, prim (K,) scene triangle ids (ignored by the tile's own
    casts), subdivisions (K,) n >= 1 (n^2 tiles each). ``all_ends`` False: direct paths
    only (a tile needs both fronts; rx is cast only where tx sees); True: both ends on
    their own (flags and centres come back, ``want_tiles`` implied). ``monostatic``:
    tx == rx, rx's casts are tx's.
    """
    import pyopencl as cl

    if not has_fp64(caster):
        raise ArgumentError("the device has no fp64; scattering tiles on the device need it",
                            argument="device", value=caster.runtime.info.device_name.strip())
    v = np.ascontiguousarray(vertices, dtype=np.float64).reshape(-1, 9)
    K = len(v)
    n = np.asarray(subdivisions, dtype=np.int64).reshape(-1)
    if n.shape != (K,) or (K and n.min() < 1):
        raise ArgumentError("must hold one integer >= 1 per triangle", argument="subdivisions",
                            value=n.shape)
    first = np.zeros(K + 1, dtype=np.int64)
    np.cumsum(n * n, out=first[1:])
    N = int(first[-1])
    if N >= 2**31 - 1:
        raise ArgumentError("too many tiles for 32-bit tile indices", argument="subdivisions",
                            value=N)
    want_tiles = want_tiles or all_ends
    empty = TileSight(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros(0),
                      np.zeros(0, np.uint8) if want_tiles else None,
                      np.zeros((0, 3)) if want_tiles else None)
    if N == 0:
        return empty
    tx = _xyz("tx_pos", tx_pos)
    rx = _xyz("rx_pos", rx_pos)
    rt = caster.runtime
    mf = cl.mem_flags
    d_vert = rt.to_device(v)
    d_first = rt.to_device(first.astype(np.int32))
    d_n = rt.to_device(n.astype(np.int32))
    d_nrm = rt.to_device(np.ascontiguousarray(normals, dtype=np.float64).reshape(K, 3))
    d_prim = rt.to_device(np.asarray(prim, dtype=np.int32).reshape(K))
    d_area = rt.to_device(np.asarray(tile_area, dtype=np.float64).reshape(K))
    d_S = rt.to_device(np.asarray(scattering, dtype=np.float64).reshape(K))
    d_centres = rt.empty(N * 24)
    d_tri = rt.empty(N * 4)
    d_flags = rt.empty(N)
    counter = np.zeros(1, dtype=np.int32)
    d_counter = cl.Buffer(rt.context, mf.READ_WRITE | mf.COPY_HOST_PTR, hostbuf=counter)
    d_tile = rt.empty(N * 4)
    d_centre = rt.empty(N * 24)
    d_power = rt.empty(N * 8)

    caster.run_kernel(SOURCE, "tile_centres", N, d_vert, d_first, d_n, np.int32(K),
                      np.int32(N), d_centres, d_tri)
    caster.run_kernel(SOURCE, "tile_sight", N, d_centres, d_tri, d_nrm, d_prim, *tx, *rx,
                      np.float32(1.0 - SIGHT_STOP), np.int32(bool(all_ends)),
                      np.int32(bool(monostatic)), np.int32(N), d_flags)
    scale = np.float64(float(wavelength) ** 2 / (16.0 * math.pi ** 3))
    caster.run_kernel(SOURCE, "tile_lambert", N, d_centres, d_tri, d_nrm, d_area, d_S, d_flags,
                      *tx, *rx, scale, np.int32(N), d_counter, d_tile, d_centre, d_power)
    cl.enqueue_copy(rt.queue, counter, d_counter, is_blocking=True)
    R = int(counter[0])
    tile = np.empty(R, dtype=np.int32)
    centre = np.empty((R, 3), dtype=np.float64)
    power = np.empty(R, dtype=np.float64)
    if R:
        cl.enqueue_copy(rt.queue, tile, d_tile, is_blocking=False)
        cl.enqueue_copy(rt.queue, centre, d_centre, is_blocking=False)
        cl.enqueue_copy(rt.queue, power, d_power, is_blocking=True)
    # the atomic counter packs rows in any order: tile order makes the result deterministic
    order = np.argsort(tile, kind="stable")
    out = TileSight(tile[order].astype(np.int64), centre[order], power[order])
    if want_tiles:
        out.flags = np.empty(N, dtype=np.uint8)
        out.centres = np.empty((N, 3), dtype=np.float64)
        cl.enqueue_copy(rt.queue, out.flags, d_flags, is_blocking=False)
        cl.enqueue_copy(rt.queue, out.centres, d_centres, is_blocking=True)
    return out
