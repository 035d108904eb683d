"""A radio map's rays stage on the device (kernels/map_walk.cl): one launch per batch.

:func:`walk_rays` walks every ray of a batch of the transmitter's launch lattice through
all its bounces on the device (closest hits over the caster's BVH, each reflection the
material's Fresnel dyad with roughness and specular share as ``kernels/em.h`` applies
it, the mirror direction and spawn offset of
:func:`clradcom.device.raycast.spawn_origins`) and returns two compact lists: the
segments that may reach the map's slab (for the host's receive projection and
:func:`clradcom.device.maps.accumulate_rows`) and the hits on scattering faces (where
:mod:`clradcom.maps`' diffuse rays start). Both lists come back sorted by (order, ray),
the order the numpy walk of :mod:`clradcom.maps` (``MapSettings(engine="host")``, the
reference it is tested against) makes them in. Geometry and fields are float64 where the
device has fp64, float32 elsewhere.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from clradcom.device.raycast import RayCaster
from clradcom.device.sbr import material_tables
from clradcom.errors import ArgumentError
from clradcom.parallel import in_pieces

__all__ = ["LaunchLattice", "WalkHits", "WalkSegments", "WalkTables", "receive_weights",
           "walk_rays"]

SOURCE = "map_walk.cl"
#: a scattering hit's reals and ints, a segment's receive reals (kernels/map_walk.cl)
HIT_REALS = 13
HIT_INTS = 3
RX_REALS = 9
#: PO objects' triangles in ``tri_flags`` (kernels/map_walk.cl: FLAG_PO), and SBR
#: objects' (FLAG_SBR: a later bounce's exit segment is marked with its ray)
FLAG_PO = 1
FLAG_SBR = 2


def _real(runtime) -> type:
    return np.float64 if runtime.info.has_double else np.float32


@dataclass
class LaunchLattice:
    """A transmitter's launch lattice on the device: ``local`` (N, 3) float64 directions
    in the antenna's frame, ``launch`` (N, 2) complex the pattern's (C_theta, C_phi) at
    them, and their device copies in the kernel's real type (made once, kept between
    maps with the lattice)."""

    local: np.ndarray
    launch: np.ndarray
    runtime: object
    _buffers: tuple | None = None

    def buffers(self) -> tuple:
        if self._buffers is None:
            real = _real(self.runtime)
            c = np.empty((len(self.launch), 4), dtype=real)
            c[:, 0::2] = self.launch.real
            c[:, 1::2] = self.launch.imag
            self._buffers = (self.runtime.to_device(self.local.astype(real)),
                             self.runtime.to_device(c))
        return self._buffers


@dataclass
class WalkTables:
    """Per-triangle and per-material device tables of one map: unit normals (float64's,
    as the host reflects off them), material ids, flags (:data:`FLAG_PO`,
    :data:`FLAG_SBR`) and the
    material rows of ``kernels/em.h`` (eps re, eps im, roughness, sqrt(1 - S^2)) and
    (pec, roughness model) with whether the material scatters (S > 0)."""

    normals: object
    tri_material: object
    tri_flags: object
    mat_f: object
    mat_i: object

    @classmethod
    def of(cls, runtime, scene, normals, po_triangles, sbr_triangles=None) -> WalkTables:
        real = _real(runtime)
        em_f, em_i = material_tables(scene)
        # whether a material scatters as its own flag: sqrt(1 - S^2) rounds to 1 below
        # S ~ 1e-8, where the host's S > 0 still starts diffuse rays
        scatters = np.asarray(scene.material_scattering, dtype=np.float64) > 0
        mat_i = np.column_stack([em_i, scatters])
        flags = np.where(np.asarray(po_triangles, dtype=bool), FLAG_PO, 0)
        if sbr_triangles is not None:
            flags |= np.where(np.asarray(sbr_triangles, dtype=bool), FLAG_SBR, 0)
        dev = runtime.to_device
        return cls(normals=dev(np.asarray(normals, dtype=real)),
                   tri_material=dev(np.asarray(scene.tri_material, dtype=np.int32)),
                   tri_flags=dev(flags.astype(np.int32)), mat_f=dev(em_f.astype(real)),
                   mat_i=dev(mat_i.astype(np.int32)))


@dataclass
class WalkHits:
    """Hits on scattering faces (S rows) in (order, ray) order: ``origins``, unit
    ``directions`` (S, 3) float64 world of the rays that made them, ``lengths`` (S,) m
    to the hit, ``fields`` (S, 3) complex the ray's field vector, ``ray`` (S,) its index
    in the lattice, ``order`` (S,) its reflections so far, ``prim`` (S,) the triangle."""

    origins: np.ndarray
    directions: np.ndarray
    lengths: np.ndarray
    fields: np.ndarray
    ray: np.ndarray
    order: np.ndarray
    prim: np.ndarray

    @classmethod
    def from_rows(cls, rows, ints, n_rays) -> WalkHits:
        ints = ints.astype(np.int64)
        sort = np.argsort(ints[:, 1] * np.int64(n_rays) + ints[:, 0], kind="stable")
        rows, ints = rows[sort].astype(np.float64), ints[sort]
        return cls(origins=rows[:, 0:3], directions=rows[:, 3:6], lengths=rows[:, 6],
                   fields=rows[:, 7:10] + 1j * rows[:, 10:13], ray=ints[:, 0],
                   order=ints[:, 1], prim=ints[:, 2])


@dataclass
class WalkSegments:
    """A batch's segments that may reach the slab, left on the device: ``org``, ``dir``
    the float4 buffers of :func:`clradcom.device.maps.accumulate_rows` (origin relative to the
    slab's corner; unit direction and length), ``count`` of them, and ``receive``
    (count, 9) float64 on the host: the arrival direction in the receiver's frame and
    the field's theta and phi components there (re, im), or without a receiver |E|^2 in
    column 0 (:func:`receive_weights`); then the ray's index in two halves where the
    segment leaves a :data:`FLAG_SBR` triangle after the ray's second or later bounce
    (:attr:`exit_ray`)."""

    org: object
    dir: object
    count: int
    receive: np.ndarray

    @property
    def exit_ray(self) -> np.ndarray:
        """(count,) int64: the lattice ray of each segment that leaves an SBR object's
        triangle after its second or later bounce, -1 for the others."""
        lo, hi = self.receive[:, 7], self.receive[:, 8]
        return np.where(lo < 0, -1, hi.astype(np.int64) * 65536 + lo.astype(np.int64))


def receive_weights(segments: WalkSegments, rx_pattern) -> np.ndarray:
    """|p(E)|^2 (S,) of each segment: the receiver's pattern (C_theta, C_phi) at the
    arrival direction against the field's components (clradcom.maps._projection's
    bilinear form), or |E|^2 where ``rx_pattern`` is None."""
    r = segments.receive
    if rx_pattern is None:
        return r[:, 0].copy()
    if not len(r):
        return np.zeros(0)

    def projected(rows):
        c = np.asarray(rx_pattern.field(rows[:, 0:3]), dtype=np.complex128)
        p = c[:, 0] * (rows[:, 3] + 1j * rows[:, 4]) + c[:, 1] * (rows[:, 5] + 1j * rows[:, 6])
        return p.real ** 2 + p.imag ** 2

    return in_pieces(projected, r)


def walk_rays(caster: RayCaster, lattice: LaunchLattice, tables: WalkTables, frame,
              origin, slab, margin: float, wavenumber: float, first: int, count: int,
              max_reflections: int, line_of_sight: bool, scatter_orders: int,
              rx_frame=None, capacity: tuple[int, int] | None = None,
              workspace: dict | None = None) -> tuple[WalkSegments, WalkHits]:
    """(segments, scattering hits) of the lattice's rays
    ``first`` .. ``first + count`` from ``origin`` (3,) with the antenna's ``frame``
    (3, 3, columns its axes in the world), up to ``max_reflections`` reflections: the
    segments that may pass through the slab's box grown by ``margin`` m (line of sight
    where ``line_of_sight``; a first reflection off a :data:`FLAG_PO` triangle never),
    with the receive records in the frame ``rx_frame`` (None: no receiver), and the hits
    on faces with S > 0 after at most ``scatter_orders`` reflections (-1: none).
    ``capacity`` (segments, hits) is a first guess of the
    records' room; a batch that needs more runs again with room for all. ``workspace``
    (a dict the caller keeps) holds the device buffers between batches; the segments'
    rows returned live in it until the next call."""
    import pyopencl as cl

    rt = caster.runtime
    if not 0 <= first <= first + count <= len(lattice.local):
        raise ArgumentError("the batch must lie inside the lattice", argument="rays",
                            value=(first, count, len(lattice.local)))
    real = _real(rt)
    itemsize = np.dtype(real).itemsize
    corner = np.array([slab.x0, slab.y0, slab.z_lo])
    params = np.zeros(13)
    params[0:3] = origin
    params[3:6] = corner - margin
    params[6:9] = np.array([slab.x0 + slab.nx * slab.cell_x, slab.y0 + slab.ny * slab.cell_y,
                            slab.z_hi]) + margin
    params[9] = wavenumber
    params[10:13] = corner
    frame_buf = rt.to_device(np.asarray(frame, dtype=real).reshape(9))
    params_buf = rt.to_device(params.astype(real))
    rx_buf = None if rx_frame is None else rt.to_device(
        np.asarray(rx_frame, dtype=real).reshape(9))
    lattice_buf, launch_buf = lattice.buffers()
    seg_cap, hit_cap = capacity or (3 * count, count // 4 + 64)
    workspace = {} if workspace is None else workspace

    def buffer(name, nbytes):
        # kept between batches, grown by half again where a batch needs more
        held = workspace.get(name)
        if held is None or held[0] < nbytes:
            size = max(nbytes, 3 * (0 if held is None else held[0]) // 2)
            workspace[name] = held = (size, rt.empty(size))
        return held[1]

    while True:
        with rt.guard("radio map rays (map_walk)"):
            seg_cap, hit_cap = max(seg_cap, 1), max(hit_cap, 1)
            seg_org, seg_dir = buffer("org", 16 * seg_cap), buffer("dir", 16 * seg_cap)
            seg_rx = buffer("rx", RX_REALS * itemsize * seg_cap)
            hit_rows = buffer("hit rows", HIT_REALS * itemsize * hit_cap)
            hit_ints = buffer("hit ints", HIT_INTS * 4 * hit_cap)
            counters = buffer("counters", 8)
            rt.fill(counters, np.int32(0), 8)
        caster.run_kernel(SOURCE, "map_walk", count, lattice_buf, launch_buf, frame_buf,
                          params_buf, tables.normals, tables.tri_material,
                          tables.tri_flags, tables.mat_f, tables.mat_i, np.int32(first),
                          np.int32(count), np.int32(max_reflections),
                          np.int32(bool(line_of_sight)), np.int32(scatter_orders), rx_buf,
                          seg_org, seg_dir, seg_rx, np.int32(seg_cap), hit_rows, hit_ints,
                          np.int32(hit_cap), counters)
        with rt.kernel_clock(), rt.guard("radio map rays (read back)"):
            got = np.zeros(2, dtype=np.int32)
            cl.enqueue_copy(rt.queue, got, counters, is_blocking=True)
            n_segments, n_hits = int(got[0]), int(got[1])
            if n_segments > seg_cap or n_hits > hit_cap:
                seg_cap, hit_cap = max(seg_cap, n_segments), max(hit_cap, n_hits)
                continue
            receive = np.empty((n_segments, RX_REALS), dtype=real)
            rows = np.empty((n_hits, HIT_REALS), dtype=real)
            ints = np.empty((n_hits, HIT_INTS), dtype=np.int32)
            for host, buf in ((receive, seg_rx), (rows, hit_rows), (ints, hit_ints)):
                if len(host):
                    cl.enqueue_copy(rt.queue, host, buf, is_blocking=False)
            rt.queue.finish()
        return (WalkSegments(org=seg_org, dir=seg_dir, count=n_segments,
                             receive=receive.astype(np.float64, copy=False)),
                WalkHits.from_rows(rows, ints, len(lattice.local)))
