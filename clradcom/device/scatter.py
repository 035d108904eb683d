"""Diffuse-scattering tiles resolved on the device: tiles, their sight of tx and rx, their
Lambertian power and the fields of their direct paths, in the kernels of
``kernels/scatter.cl``.

:func:`tile_sight` cuts the traced scattering triangles into tiles (the host's
:func:`clradcom.mechanisms.scattering.make_tiles` rule and order), tests every tile centre's
front side and float32 sight line to tx and rx (the casts of
:func:`clradcom.device.visibility.surface_sees`, bit for bit) and lists the tiles both ends
see in tile order, each with its centre and Lambertian power, or, given
:class:`FieldInputs`, with the whole direct path tx -> tile -> rx (``tile_fields``: length,
Doppler, antenna directions, polarimetric matrix for Gamma = 1 and the pieces of Gamma).
Only those rows come back (and, when asked, the per-tile flags and centres that reflected
legs need); what stays with the caller: the antenna patterns (applied to the matrices as
the SBR engine applies them), Gamma for the polarisation they send, the threshold, and the
float64 antenna ends (:func:`clradcom.device.visibility.antenna_blocked`) of the rare rows
the kernel leaves undecided. Positions, lengths and the phase k L are double where the
device has fp64 (the host's numbers bit for bit) and double-float without
(``kernels/precise.h``: within ~1e-14 relative, float64 values crossing as (hi, lo)
pairs); the fields are double, or float without fp64 (docs/precision.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from clradcom.device.precision import host_float64, kernel_float64, kernel_scalar64
from clradcom.device.raycast import RayCaster
from clradcom.device.visibility import (
    LOOK_PAST,
    ON_FACE_TOL_REL,
    RESCUE_ROUNDS,
    SIGHT_STOP,
    antenna_near_triangles,
    confirm_margin_m,
    dot3_order,
    scene64_args,
)
from clradcom.errors import ArgumentError

__all__ = ["FIELD_COLUMNS", "FieldInputs", "TileSight", "tile_sight"]

SOURCE = "scatter.cl"
#: flag bits of :func:`tile_sight`'s per-tile flags
SEES_TX, SEES_RX = 1, 2
#: columns of a ``tile_fields`` row (passed to the kernels as -D TF_<NAME>): first column
#: and width
FIELD_COLUMNS = {"power": (0, 1), "centre": (1, 3), "length": (4, 1), "doppler": (5, 1),
                 "tx_dir": (6, 3), "rx_dir": (9, 3), "matrix": (12, 8), "proj": (20, 4),
                 "fresnel": (24, 4), "undecided": (28, 1)}
FIELD_WIDTH = 29
DEFINES = {**{f"TF_{k.upper()}": v[0] for k, v in FIELD_COLUMNS.items()},
           "TILE_FIELDS": FIELD_WIDTH}


def _defines() -> dict:
    """DEFINES and the dot-product order of the float64 sight rounds (scene64.h)."""
    return {**DEFINES, "DOT3_ORDER": int(dot3_order() or 0)}
#: per traced triangle: S, K_x, eps' and -eps'' (eps_r's real and imaginary parts), PEC
#: (0/1), the object's velocity (3), angular velocity (3, rad/s) and rotation centre (3)
TRI_PAR_WIDTH = 14


@dataclass
class FieldInputs:
    """What ``tile_fields`` needs beyond the tiles, K traced triangles.

    ``tri_par`` (K, 14) (:data:`TRI_PAR_WIDTH`); ``glob_first`` (K,) the index among all
    tiles (the phases' rows) of each traced triangle's first tile; ``phases`` (all tiles,
    2) chi1, chi2 (the rows' are gathered here); tx and rx velocities (3,) and antenna
    frames (3, 3) (columns the local axes in world)."""

    tri_par: np.ndarray
    glob_first: np.ndarray
    phases: np.ndarray
    tx_velocity: np.ndarray
    rx_velocity: np.ndarray
    tx_frame: np.ndarray
    rx_frame: np.ndarray


@dataclass
class TileSight:
    """What :func:`tile_sight` returns, tile indices counting the traced tiles in order.

    ``tile`` (R,) int64 ascending: the tiles both ends see (float32 casts);
    ``centre`` (R,3) and ``power`` (R,) theirs (power: |a|^2 for isotropic antennas and
    Gamma = 1). ``flags`` (N,) uint8 (bits SEES_TX, SEES_RX) and ``centres`` (N,3) of every
    tile when asked for, else None. ``fields`` (R, FIELD_WIDTH) the rows of
    ``tile_fields`` and ``triangle`` (R,) each row's triangle (0..K-1) when
    :class:`FieldInputs` were given (:meth:`column` reads the fields)."""

    tile: np.ndarray
    centre: np.ndarray
    power: np.ndarray
    flags: np.ndarray | None = None
    centres: np.ndarray | None = None
    fields: np.ndarray | None = None
    triangle: np.ndarray | None = None

    def column(self, name: str) -> np.ndarray:
        """A ``tile_fields`` column (R,) or columns (R, width) by name (a view)."""
        first, width = FIELD_COLUMNS[name]
        return self.fields[:, first] if width == 1 else self.fields[:, first:first + width]


def _xyz(name, value):
    a = np.asarray(value, dtype=np.float64).reshape(-1)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise ArgumentError("must be 3 finite coordinates", argument=name, value=value)
    return [np.float64(x) for x in a]


def tile_sight(caster: RayCaster, vertices, normals, tile_area, scattering, prim, subdivisions,
               tx_pos, rx_pos, wavelength, *, all_ends: bool, monostatic: bool,
               want_tiles: bool = False, fields: FieldInputs | None = None,
               tri_face=None) -> TileSight:
    """Tiles of K triangles, their sight of tx and rx and their Lambertian power.

    vertices (K,3,3), normals (K,3) unit, tile_area (K,) the area of one of the triangle's
    tiles, scattering (K,) S, prim (K,) scene triangle ids (ignored by the tile's own
    casts), subdivisions (K,) n >= 1 (n^2 tiles each). ``all_ends`` False: direct paths
    only (a tile needs both fronts; rx is cast only where tx sees); True: both ends on
    their own (flags and centres come back, ``want_tiles`` implied). ``monostatic``:
    tx == rx, rx's casts are tx's. ``fields``: the rows come with their direct paths'
    fields (``tile_fields``, :attr:`TileSight.fields`; power and centre from it too).
    ``tri_face``: the planar face of every scene triangle, against which a float32
    "blocked" sight line is re-decided in float64 (default: every triangle its own).
    """
    import pyopencl as cl

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
    if fields is not None:
        empty.fields, empty.triangle = np.zeros((0, FIELD_WIDTH)), np.zeros(0, np.int64)
    if N == 0:
        return empty
    tx = _xyz("tx_pos", tx_pos)
    rx = _xyz("rx_pos", rx_pos)
    rt = caster.runtime

    def f64(a, shape):
        """float64 values as the build reads them (doubles, or pairs without fp64)"""
        return rt.to_device(kernel_float64(rt, np.asarray(a, dtype=np.float64).reshape(shape)))

    def scalars(xs):
        return [kernel_scalar64(rt, x) for x in xs]

    d_vert = f64(v, (K, 9))
    d_first = rt.to_device(first.astype(np.int32))
    d_n = rt.to_device(n.astype(np.int32))
    d_nrm = f64(normals, (K, 3))
    d_prim = rt.to_device(np.asarray(prim, dtype=np.int32).reshape(K))
    d_area = f64(tile_area, (K,))
    d_S = f64(scattering, (K,))
    d_centres = rt.empty(N * 24)
    d_tri = rt.empty(N * 4)
    d_flags = rt.empty(N)
    run = caster.run_kernel
    run(SOURCE, "tile_centres", N, d_vert, d_first, d_n, np.int32(K), np.int32(N), d_centres,
        d_tri, defines=_defines())
    if tri_face is None:
        tri_face = np.arange(len(caster.triangles))
    run(SOURCE, "tile_sight", N, *scene64_args(caster, tri_face), np.int32(RESCUE_ROUNDS),
        *scalars([LOOK_PAST, 1.0 - SIGHT_STOP]), d_centres, d_tri, d_nrm, d_prim,
        *scalars(tx), *scalars(rx),
        np.float32(1.0 - SIGHT_STOP), np.int32(bool(all_ends)), np.int32(bool(monostatic)),
        np.int32(N), d_flags, defines=_defines())
    flags = np.empty(N, dtype=np.uint8)
    cl.enqueue_copy(rt.queue, flags, d_flags, is_blocking=True)
    rows = np.flatnonzero(flags == SEES_TX | SEES_RX)  # tile order
    R = len(rows)
    out = TileSight(rows.astype(np.int64), np.empty((R, 3)), np.empty(R),
                    fields=None if fields is None else np.zeros((0, FIELD_WIDTH)),
                    triangle=None if fields is None else np.zeros(0, np.int64))
    if want_tiles:
        out.flags = flags
        out.centres = np.empty((N, 3), dtype=np.float64)
        cl.enqueue_copy(rt.queue, out.centres, d_centres, is_blocking=False)
    if R:
        d_rows = rt.to_device(rows.astype(np.int32))
        if fields is None:
            d_centre = rt.empty(R * 24)
            d_power = rt.empty(R * 8)
            scale = float(wavelength) ** 2 / (16.0 * math.pi ** 3)
            run(SOURCE, "tile_lambert", R, d_centres, d_tri, d_nrm, d_area, d_S, d_rows,
                np.int32(R), *scalars(tx), *scalars(rx), *scalars([scale]), d_centre,
                d_power, defines=_defines())
            cl.enqueue_copy(rt.queue, out.centre, d_centre, is_blocking=False)
            cl.enqueue_copy(rt.queue, out.power, d_power, is_blocking=False)
        else:
            out.triangle = np.searchsorted(first, rows, side="right") - 1
            out.fields = _tile_fields(caster, fields, d_centres, d_tri, rows - first[
                out.triangle], out.triangle, K=K, d_nrm=d_nrm, d_area=d_area, tx=tx, rx=rx,
                wavelength=wavelength, d_rows=d_rows)
            out.centre = out.column("centre")
            out.power = out.column("power")
    rt.queue.finish()
    if fields is None:
        # the kernels' float64 values as float64 (pairs joined without fp64)
        out.centre, out.power = host_float64(rt, out.centre), host_float64(rt, out.power)
    if want_tiles:
        out.centres = host_float64(rt, out.centres)
    return out


def _tile_fields(caster, fields: FieldInputs, d_centres, d_tri, within, triangle, *, K, d_nrm,
                 d_area, tx, rx, wavelength, d_rows) -> np.ndarray:
    """Launch ``tile_fields`` on the R listed rows (the ``within``-th tile of traced triangle
    ``triangle``, each (R,)): (R, FIELD_WIDTH) float64."""
    import pyopencl as cl

    rt = caster.runtime
    tri_par = np.ascontiguousarray(fields.tri_par, dtype=np.float64)
    glob_first = np.ascontiguousarray(fields.glob_first, dtype=np.int64).reshape(-1)
    if tri_par.shape != (K, TRI_PAR_WIDTH) or glob_first.shape != (K,):
        raise ArgumentError(f"must hold one row per traced triangle ({K})",
                            argument="fields.tri_par", value=tri_par.shape)
    R = len(within)
    phases = np.asarray(fields.phases, dtype=np.float64).reshape(-1, 2)[
        glob_first[triangle] + within]
    ends = np.array([tx, rx], dtype=np.float64)
    lam = float(wavelength)
    radius = [2.0 * float(confirm_margin_m(e[None])[0]) for e in ends]
    link = np.concatenate([
        ends.reshape(6), np.asarray(fields.tx_velocity, np.float64).reshape(3),
        np.asarray(fields.rx_velocity, np.float64).reshape(3),
        [2.0 * np.pi / lam, lam / (4.0 * np.pi), lam, lam ** 2 / (16.0 * math.pi ** 3)],
        radius])
    # the antenna frames, read as the fields' `real` (double, or float without fp64)
    frames = np.concatenate([np.asarray(fields.tx_frame, np.float64).reshape(9),
                             np.asarray(fields.rx_frame, np.float64).reshape(9)])
    if not (np.all(np.isfinite(link)) and np.all(np.isfinite(frames))):
        raise ArgumentError("velocities and antenna frames must be finite",
                            argument="fields", value=link.tolist())
    near_first, near_tri = _near_lists(caster, ends, radius)
    # one antenna at both ends (position and frame): the kernel takes rx's basis from tx's
    mono = bool(np.array_equal(ends[0], ends[1])
                and np.array_equal(np.asarray(fields.tx_frame, np.float64),
                                   np.asarray(fields.rx_frame, np.float64)))
    data64 = caster.scene_data64()
    d_out = rt.empty(R * FIELD_WIDTH * 8)

    def dev(a, dtype):
        a = np.ascontiguousarray(a, dtype=dtype)
        if dtype == np.float64:
            a = kernel_float64(rt, a)
        return rt.to_device(a if a.size else np.zeros(1, a.dtype))

    real = np.float64 if rt.has_double else np.float32
    caster.run_kernel(SOURCE, "tile_fields", R, d_centres, d_tri, d_nrm, d_area,
                      dev(tri_par, np.float64),
                      dev(phases, np.float64), dev(link, np.float64), dev(frames, real),
                      dev(near_first, np.int32), dev(near_tri, np.int32),
                      data64["vertices"], data64["normals"], d_rows, np.int32(R),
                      np.int32(mono), d_out, defines=_defines())
    out = np.empty((R, FIELD_WIDTH), dtype=np.float64)
    cl.enqueue_copy(rt.queue, out, d_out, is_blocking=True)
    return host_float64(rt, out)


def _near_lists(caster: RayCaster, ends, radius):
    """CSR lists ``(first (3,), triangles)`` of the triangles that may block the last
    ``radius[e]`` metres at antenna ``ends[e]`` in :func:`clradcom.device.visibility.
    antenna_blocked`: a superset of that test's own choice (radius and tolerance widened
    by rounding), since a row the kernel finds near none of them is clear for good and
    the others go to that test."""
    lists = [antenna_near_triangles(caster, ant, float(rad) * (1.0 + 1e-9) + 1e-12,
                                    0.5 * ON_FACE_TOL_REL)
             for ant, rad in zip(ends, radius, strict=True)]
    first = np.array([0, len(lists[0]), len(lists[0]) + len(lists[1])], dtype=np.int32)
    return first, np.concatenate(lists).astype(np.int32)
