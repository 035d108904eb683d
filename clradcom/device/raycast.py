"""Host side of batch ray casting: closest hit and any hit over a flattened BVH.

Rays and hits cross to the kernels as the packed structs of ``kernels/types.h``;
the numpy dtypes below mirror them byte for byte (tests check the sizes).
"""

from __future__ import annotations

import threading
import time

import numpy as np

from clradcom.device.precision import kernel_float64, kernel_scalar64
from clradcom.device.runtime import Runtime, get_runtime
from clradcom.errors import ArgumentError
from clradcom.geometry import layout
from clradcom.geometry.bvh import build_bvh
from clradcom.geometry.instances import (
    build_blas,
    instance_boxes,
    refit,
    step_head,
    tlas_nodes,
    two_level,
    world_tri4,
)
from clradcom.geometry.layout import bvh8_nodes, tri4_groups
from clradcom.geometry.triangles import triangle_normals

RAY_DTYPE = np.dtype(
    [("org", "<f4", (3,)), ("tmin", "<f4"), ("dir", "<f4", (3,)), ("tmax", "<f4")]
)
HIT_DTYPE = np.dtype(
    [("t", "<f4"), ("u", "<f4"), ("v", "<f4"), ("prim", "<i4"), ("ng", "<f4", (3,)),
     ("pad", "<i4")]
)

# float32 unit roundoff; spawn offsets are a few multiples of it times |p|
_F32_EPS = float(np.finfo(np.float32).eps) * 0.5
#: Rays leave a surface this many float32 roundoffs times (1 + max |p|) off it, on the
#: host (spawn_origins) and on the device (kernels/reflect.cl) alike.
SPAWN_OFFSET_ROUNDOFFS = 8

#: Rays per packet at most (kernels/intersect.h: packet_closest; an SBR launch block's
#: tubes).
PACKET_MAX = 64

#: Every kernel build gets these as -D options: the host is the kernels' only source of
#: them, and kernels/layout.cl reports them back for a test.
KERNEL_DEFINES = {
    "BVH_WIDTH": layout.BVH_WIDTH,
    "BVH_STACK_SIZE": layout.BVH_STACK_SIZE,
    "TRI4_ROWS": layout.TRI4_ROWS,
    "LEAF_GROUP_BITS": layout.LEAF_GROUP_BITS,
    "SPAWN_OFFSET_ROUNDOFFS": SPAWN_OFFSET_ROUNDOFFS,
    "PACKET_MAX": PACKET_MAX,
}


def make_rays(origins, directions, tmin=0.0, tmax=np.inf) -> np.ndarray:
    """Pack origins (R,3), directions (R,3) and scalar or (R,) ranges into RAY_DTYPE.

    Directions need not be unit length; t is then measured in units of |dir|.
    """
    origins = np.asarray(origins, dtype=np.float64)
    directions = np.asarray(directions, dtype=np.float64)
    if origins.ndim != 2 or origins.shape[1] != 3:
        raise ArgumentError(f"origins must have shape (R, 3), got {origins.shape}")
    if directions.shape != origins.shape:
        raise ArgumentError(
            f"directions shape {directions.shape} differs from origins shape {origins.shape}"
        )
    for name, arr in (("origins", origins), ("directions", directions)):
        bad = ~np.isfinite(arr).all(axis=1)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise ArgumentError(f"{name}[{i}] is not finite: {arr[i].tolist()}")
    zero = ~np.any(directions != 0.0, axis=1)
    if zero.any():
        raise ArgumentError(f"directions[{int(np.flatnonzero(zero)[0])}] is the zero vector")
    return pack_rays(origins, directions, tmin, tmax)


def pack_rays(origins, directions, tmin=0.0, tmax=np.inf) -> np.ndarray:
    """:func:`make_rays` without its checks, for callers whose rays cannot fail them
    (finite origins, non-zero directions by construction): the checks cost four times
    the packing (15 of 19 ms for 2^18 rays, a radio map's batch)."""
    rays = np.empty(len(origins), dtype=RAY_DTYPE)
    rays["org"] = origins
    rays["dir"] = directions
    rays["tmin"] = tmin
    rays["tmax"] = tmax
    return rays


def spawn_origins(points, normals, directions) -> np.ndarray:
    """Origins for rays leaving a surface, pushed off it by a float32 error bound.

    The offset (after pbrt-v4's OffsetRayOrigin) is along the geometric normal,
    toward the side the ray leaves into, and scales with |p| so it exceeds the
    rounding error of a float32 intersection point anywhere in the scene while
    staying far below a wavelength (|p| = 1 km gives 0.5 mm).
    """
    points = np.asarray(points, dtype=np.float64)
    normals = np.asarray(normals, dtype=np.float64)
    directions = np.asarray(directions, dtype=np.float64)
    bound = SPAWN_OFFSET_ROUNDOFFS * _F32_EPS * (np.abs(points).max(axis=1) + 1.0)
    side = np.sign(np.einsum("ij,ij->i", normals, directions))
    side[side == 0] = 1.0
    n_len = np.linalg.norm(normals, axis=1)
    n_len[n_len == 0] = 1.0
    return points + (side * bound / n_len)[:, None] * normals


class RayCaster:
    """Closest-hit, any-hit and specular-bounce queries for one triangle set on one
    OpenCL device: the only driver of the kernels.

    Device data: the 8-wide BVH (:func:`bvh8_nodes`), the leaf triangles in
    Tri4 groups and the scene id of every leaf slot (:func:`tri4_groups`). On a
    CPU device the kernels read the rays and write the results in the numpy
    arrays themselves (USE_HOST_PTR); elsewhere ray, ignore and result buffers
    are kept between calls and grown as needed. Calls are serialised by a lock, and
    each one's wall time (enqueue to finish) adds to ``runtime.kernel_seconds``.
    """

    # Preferred work-group size (Runtime.local_size rounds it to the device's multiple and
    # keeps it within the kernel's limit): PoCL's CPU device runs a work-group's items one
    # after the other in a loop, 16 to 256 measured the same, its own choice ~15% slower;
    # 64 is two warps on NVIDIA, one wavefront on AMD.
    LOCAL_SIZE = 64
    #: -D options beyond KERNEL_DEFINES that this caster's buffers need
    EXTRA_DEFINES: dict = {}

    def __init__(self, triangles, bvh=None, runtime: Runtime | None = None):
        triangles = np.asarray(triangles, dtype=np.float64)
        if triangles.ndim != 3 or triangles.shape[1:] != (3, 3):
            raise ArgumentError(f"triangles must have shape (T, 3, 3), got {triangles.shape}")
        self.runtime = runtime or get_runtime()
        self.triangles = triangles
        if bvh is None:
            # all three axes binned: ~10% faster casting for twice the (small) build time
            bvh = build_bvh(triangles, axes="all")
        self.bvh = bvh
        tri4, slot_prim, leaf_first, leaf_groups = tri4_groups(bvh, triangles)
        rt = self.runtime
        records = bvh8_nodes(bvh.nodes, leaf_first, leaf_groups)
        #: the traversal stack the kernels are built with: the short one that holds this
        #: tree's need (layout.stack_need), a deeper one only for a deeper tree
        self.stack_size = layout.stack_size_for(layout.stack_need(records))
        self._nodes = rt.to_device(records)
        self._tri4 = rt.to_device(tri4)
        self._slot_prim = rt.to_device(slot_prim)
        self._lock = threading.Lock()
        self._buffers: dict[str, tuple[int, object]] = {}
        #: counts the placements of the triangles (InstancedCaster.place): data derived
        #: from them elsewhere (clradcom.device.visibility's face tables) is redone when
        #: it changes
        self.generation = 0
        self._bounds: tuple[np.ndarray, np.ndarray] | None = None
        self._data64: dict | None = None
        self._normals: np.ndarray | None = None
        self._lattice: tuple | None = None   # (local lattice, its device buffer)
        # PoCL's CPU device uses USE_HOST_PTR memory in place (5% of the end-to-end
        # time saved on 500k rays); other devices get reused buffers and copies.
        self._zero_copy = rt.info.device_type == "CPU"

    def kernel_defines(self) -> dict:
        """The -D defines every kernel that walks this caster's BVH is built with:
        :data:`KERNEL_DEFINES` with this tree's stack size, and the caster's own."""
        return {**KERNEL_DEFINES, "BVH_STACK_SIZE": self.stack_size, **self.EXTRA_DEFINES}

    def bvh_buffers(self) -> tuple:
        """The device buffers (nodes, tri4, slot_prim) every BVH kernel takes first."""
        self._check_ready()
        return self._nodes, self._tri4, self._slot_prim

    def local_size(self, kernel, preferred: int | None = None) -> int:
        """The work-group size of ``kernel`` on this caster's device (Runtime.local_size
        of ``preferred``, default :attr:`LOCAL_SIZE`)."""
        return self.runtime.local_size(kernel, preferred or self.LOCAL_SIZE)

    def _buffer(self, name, nbytes):
        """A device buffer (Runtime.empty) of at least nbytes kept under name, grown by
        doubling."""
        size, buf = self._buffers.get(name, (0, None))
        if size < nbytes:
            size = max(nbytes, 2 * size, 4096)
            buf = self.runtime.empty(size)
            self._buffers[name] = (size, buf)
        return buf

    def _launch(self, kernel_name, rays, ignore_prim, out_dtype):
        import pyopencl as cl

        self._check_ready()
        rays = np.ascontiguousarray(rays, dtype=RAY_DTYPE)
        n = len(rays)
        out = np.empty(n, dtype=out_dtype)
        if n == 0:
            return out
        ignore = None
        if ignore_prim is not None:
            ignore = np.ascontiguousarray(np.broadcast_to(ignore_prim, (n,)), dtype=np.int32)
        rt = self.runtime
        mf = cl.mem_flags
        kernel = rt.kernel("raycast.cl", kernel_name, defines=self.kernel_defines())
        local = self.local_size(kernel)
        with self._lock, rt.kernel_clock(), rt.guard(f"ray casting ({kernel_name})"):
            if self._zero_copy:
                # A CPU device reads and writes the numpy arrays in place: no copies.
                if not rays.flags.writeable:
                    rays = rays.copy()
                ray_buf = cl.Buffer(rt.context, mf.READ_ONLY | mf.USE_HOST_PTR, hostbuf=rays)
                out_buf = cl.Buffer(rt.context, mf.WRITE_ONLY | mf.USE_HOST_PTR, hostbuf=out)
                ign_buf = None if ignore is None else cl.Buffer(
                    rt.context, mf.READ_ONLY | mf.USE_HOST_PTR, hostbuf=np.array(ignore))
            else:
                ray_buf = self._buffer("rays", rays.nbytes)
                out_buf = self._buffer(kernel_name, out.nbytes)
                cl.enqueue_copy(rt.queue, ray_buf, rays, is_blocking=False)
                ign_buf = None
                if ignore is not None:
                    ign_buf = self._buffer("ignore", ignore.nbytes)
                    cl.enqueue_copy(rt.queue, ign_buf, ignore, is_blocking=False)
            # ign_buf None is a NULL pointer: no ray ignores a triangle. The kernels
            # ignore the work items past n.
            rt.launch(kernel, n, local, self._nodes, self._tri4, self._slot_prim, ray_buf,
                      ign_buf, out_buf, np.int32(n), name=kernel_name)
            if self._zero_copy:
                mapped, _ = cl.enqueue_map_buffer(rt.queue, out_buf, cl.map_flags.READ, 0,
                                                  (n,), out_dtype, is_blocking=True)
                if mapped.ctypes.data != out.ctypes.data:   # the driver kept a copy
                    out[...] = mapped
                mapped.base.release(rt.queue)
                rt.queue.finish()
            else:
                cl.enqueue_copy(rt.queue, out, out_buf, is_blocking=True)
        return out

    def run_kernel(self, source: str, kernel_name: str, global_size: int, *args,
                   defines=None, local_size: int | None = None, options=()) -> None:
        """Launch ``kernel_name`` of ``kernels/<source>`` over ``global_size`` work items
        (rounded up to whole work-groups: the kernel ignores the items past its own
        count) with the BVH buffers first: ``(nodes, tri4, slot_prim, *args)``.

        The driver for every kernel family that traverses this caster's BVH (SBR tubes,
        scattering tiles, batched visibility): builds get :data:`KERNEL_DEFINES` plus
        ``defines`` (the caster's own BVH defines win over those); ``local_size`` is the
        preferred work-group size (default :attr:`LOCAL_SIZE`), kept within the device's
        limits by :meth:`Runtime.local_size`; calls are serialised by the caster's lock
        and finish before return, their wall time counted in ``runtime.kernel_seconds``.
        """
        self._check_ready()
        if global_size <= 0:
            return
        rt = self.runtime
        # the caster's BVH defines win: a stage's own copy of KERNEL_DEFINES must not
        # undo this tree's stack size
        kernel = rt.kernel(source, kernel_name, tuple(options),
                           defines={**(defines or {}), **self.kernel_defines()})
        local = self.local_size(kernel, local_size)
        with self._lock, rt.kernel_clock():
            rt.launch(kernel, global_size, local, self._nodes, self._tri4, self._slot_prim,
                      *args, name=f"{kernel_name} ({source})", wait=True)

    def scene_data64(self) -> dict:
        """Device buffers of the triangles in float64, uploaded once: ``vertices`` (T*9
        values, v0 v1 v2 per triangle) and ``normals`` (T*3, the host's
        :func:`clradcom.geometry.triangles.triangle_normals`, so a kernel's exact plane
        hits agree with the host's): doubles, or (hi, lo) float pairs where the device
        computes without fp64 (``kernels/precise.h``'s pr_elem,
        :func:`clradcom.device.precision.kernel_float64`)."""
        if self._data64 is None:
            rt = self.runtime
            self._data64 = {
                "vertices": rt.to_device(kernel_float64(rt, self.triangles)),
                "normals": rt.to_device(kernel_float64(rt, self.normals64())),
            }
        return self._data64

    def normals64(self) -> np.ndarray:
        """(T, 3) float64 unit normals of the triangles (the host's
        :func:`clradcom.geometry.triangles.triangle_normals`), computed once."""
        if self._normals is None:
            self._normals = triangle_normals(self.triangles)
        return self._normals

    def triangle_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(lo, hi): the (T, 3) float64 corners of every triangle's box, computed once."""
        if self._bounds is None:
            self._bounds = (self.triangles.min(axis=1), self.triangles.max(axis=1))
        return self._bounds

    def closest_hit(self, rays: np.ndarray, ignore_prim=None) -> np.ndarray:
        """HIT_DTYPE per ray: t (inf on a miss), u, v, prim (-1 on a miss), unit ng."""
        return self._launch("closest_hit", rays, ignore_prim, HIT_DTYPE)

    def closest_hit_packets(self, rays: np.ndarray, packet_first) -> np.ndarray:
        """:meth:`closest_hit`'s hits, ray for ray and bit for bit, with the rays cast in
        packets: packet p holds rays ``packet_first[p]`` .. ``packet_first[p + 1] - 1``
        (at most :data:`PACKET_MAX`; ``packet_first`` rises from 0 to ``len(rays)``) and
        walks the tree once for all of them (kernels/intersect.h: packet_closest). Faster
        where a packet's rays are coherent (neighbours of a launch grid, or rays that
        left one plane), slower where they are not."""
        import pyopencl as cl

        self._check_ready()
        rays = np.ascontiguousarray(rays, dtype=RAY_DTYPE)
        first = np.asarray(packet_first)
        if (first.ndim != 1 or len(first) < 1 or not np.issubdtype(first.dtype, np.integer)
                or first[0] != 0 or first[-1] != len(rays)):
            raise ArgumentError(f"must be integers rising from 0 to the number of rays "
                                f"({len(rays)})", argument="packet_first",
                                value=first.tolist() if first.size < 8 else first.shape)
        sizes = np.diff(first)
        if np.any(sizes < 0) or np.any(sizes > PACKET_MAX):
            raise ArgumentError(f"packets must hold 0 to {PACKET_MAX} rays",
                                argument="packet_first",
                                value=int(sizes[(sizes < 0) | (sizes > PACKET_MAX)][0]))
        out = np.empty(len(rays), dtype=HIT_DTYPE)
        if len(rays) == 0:
            return out
        rt = self.runtime
        kernel = rt.kernel("raycast.cl", "closest_hit_packets", defines=self.kernel_defines())
        n_packets = len(first) - 1
        with self._lock, rt.kernel_clock(), rt.guard("ray casting (closest_hit_packets)"):
            ray_buf = rt.to_device(rays)
            first_buf = rt.to_device(first.astype(np.int32))
            out_buf = self._buffer("closest_hit_packets", out.nbytes)
            # a packet is 64 rays' work: small groups keep both threads of a CPU busy
            rt.launch(kernel, n_packets, self.local_size(kernel, 8), self._nodes,
                      self._tri4, self._slot_prim, ray_buf, first_buf, out_buf,
                      np.int32(n_packets), name="closest_hit_packets")
            cl.enqueue_copy(rt.queue, out, out_buf, is_blocking=True)
        return out

    def occluded(self, rays: np.ndarray, ignore_prim=None) -> np.ndarray:
        """True where any triangle is hit in (tmin, tmax)."""
        return self._launch("any_hit", rays, ignore_prim, np.uint8).astype(bool)

    def specular_sequences(self, origin, directions, tri_face, max_order: int,
                           batch: int = 1 << 20) -> np.ndarray:
        """(R, max_order) int32: the ``tri_face`` ids that each ray from ``origin`` along
        ``directions`` (R,3) reflects off, in order, -1 after it escapes.

        Geometry is float32 (kernels/reflect.cl): the sequences only propose
        candidates, which the host confirms in float64.
        """
        import pyopencl as cl

        self._check_ready()
        directions = np.asarray(directions)
        if max_order < 1:
            return np.zeros((len(directions), 0), dtype=np.int32)
        rt = self.runtime
        kernel = rt.kernel("reflect.cl", "trace_reflections", defines=self.kernel_defines())
        o = np.asarray(origin, dtype=np.float64)
        out = np.empty((len(directions), max_order), dtype=np.int32)
        with self._lock, rt.kernel_clock(), rt.guard("specular face sequences"):
            face_buf = rt.to_device(np.asarray(tri_face, dtype=np.int32))
            for start in range(0, len(directions), batch):
                # float4 rows: the kernel loads each direction as one aligned vector
                d = np.zeros((min(batch, len(directions) - start), 4), dtype=np.float32)
                d[:, :3] = directions[start:start + len(d)]
                n = len(d)
                d_buf = rt.to_device(d)
                o_buf = rt.empty(n * max_order * 4)
                # whole work-groups (the kernel ignores items past n): left to itself PoCL
                # may pick groups of thousands, whose private traversal stacks overflow its
                # threads' stacks
                rt.launch(kernel, n, self.local_size(kernel), self._nodes, self._tri4,
                          self._slot_prim, face_buf, np.float32(o[0]), np.float32(o[1]),
                          np.float32(o[2]), d_buf, np.int32(max_order), o_buf, np.int32(n),
                          name="trace_reflections")
                chunk = np.empty((n, max_order), dtype=np.int32)
                cl.enqueue_copy(rt.queue, chunk, o_buf)
                out[start:start + n] = chunk
        return out


    def lattice_sequences(self, origin, local, rotation, tri_face, max_order: int,
                          batch: int = 1 << 20) -> np.ndarray:
        """:meth:`specular_sequences` of the rays ``local @ rotation.T`` (local (R, 3)
        float64 lattice, rotation (3, 3)), rotated on the device as numpy's column sums
        ``local[:, :1] * r[:, 0] + local[:, 1:2] * r[:, 1] + local[:, 2:] * r[:, 2]`` do
        (kernels/reflect.cl: trace_reflections_rotated): in double where the device has
        fp64, so the sequences are those of the host-rotated directions bit for bit; in
        double-float without, each direction the host's float32 one but for a component
        within ~1e-14 of a float rounding boundary (1 ulp off; about one in 10^6). The
        lattice is uploaded once and kept while ``local`` is the same array (a launch
        lattice shared by transmitters and traces)."""
        local, r = self._check_lattice(local, rotation)
        if max_order < 1:
            dirs = local[:, :1] * r[:, 0] + local[:, 1:2] * r[:, 1] + local[:, 2:] * r[:, 2]
            return self.specular_sequences(origin, dirs, tri_face, max_order, batch)
        out = np.empty((len(local), max_order), dtype=np.int32)
        self._rotated_launch("trace_reflections_rotated", origin, local, r, tri_face,
                             (np.int32(max_order),), out, batch)
        return out

    def lattice_keys(self, origin, local, rotation, tri_face, max_order: int, base: int,
                     batch: int = 1 << 20) -> np.ndarray:
        """(R,) int64: each of :meth:`lattice_sequences`' rows as one exact key, in one
        launch of ``trace_reflection_keys_rotated`` (kernels/reflect.cl): the digits are
        face + 1 in ``base``, first face most significant, and 0 from the first escape or
        the first face that repeats the one before it
        (:func:`clradcom.mechanisms.specular.sequence_keys`, the host's same keys).
        ``base`` must exceed every face id + 1 and base^max_order fit in an int64."""
        local, r = self._check_lattice(local, rotation)
        self._check_key_base(tri_face, max_order, base)
        out = np.empty(len(local), dtype=np.int64)
        self._rotated_launch("trace_reflection_keys_rotated", origin, local, r, tri_face,
                             (np.int32(max_order), np.int64(base)), out, batch)
        return out

    def key_set_refusal(self) -> str | None:
        """Why :meth:`lattice_key_set` cannot gather its set on this device (no 64-bit
        atomics), or None."""
        if not self.runtime.info.int64_atomics:
            return ("the device has no 64-bit atomics (cl_khr_int64_base_atomics): every "
                    "ray's key comes back and the host de-duplicates them")
        return None

    def lattice_key_set(self, origin, local, rotation, tri_face, max_order: int,
                        base: int, batch: int = 1 << 20, table_bits: int | None = None,
                        on_host=None) -> np.ndarray:
        """The distinct non-zero keys of :meth:`lattice_keys`, ascending: gathered into a
        hash set on the device (``collect_reflection_keys_rotated``) where it has 64-bit
        atomics, so only the set leaves the device; a set that fills up (or no such
        atomics: :meth:`key_set_refusal`) falls back to every ray's key and ``np.unique``
        on the host, and ``on_host`` (a callable) is told why. The set has
        2^``table_bits`` slots (default: a quarter of the rays' count, at least 2^12)."""
        local, r = self._check_lattice(local, rotation)
        self._check_key_base(tri_face, max_order, base)
        rt = self.runtime
        refusal = self.key_set_refusal()
        if refusal is None and len(local):
            import pyopencl as cl

            # 4 slots per expected distinct key at one distinct sequence in 16 rays
            bits = (max(12, int(np.ceil(np.log2(max(len(local), 1) / 4))))
                    if table_bits is None else int(table_bits))
            if not 1 <= bits <= 30:
                raise ArgumentError("must lie in [1, 30]", argument="table_bits", value=bits)
            table = np.full(1 << bits, -1, dtype=np.int64)
            table_buf = cl.Buffer(rt.context, cl.mem_flags.READ_WRITE
                                  | cl.mem_flags.COPY_HOST_PTR, hostbuf=table)
            overflow = np.zeros(1, dtype=np.int32)
            overflow_buf = cl.Buffer(rt.context, cl.mem_flags.READ_WRITE
                                     | cl.mem_flags.COPY_HOST_PTR, hostbuf=overflow)
            self._rotated_launch("collect_reflection_keys_rotated", origin, local, r,
                                 tri_face, (np.int32(max_order), np.int64(base),
                                            np.int32(bits), table_buf, overflow_buf),
                                 None, batch)
            with rt.kernel_clock():
                cl.enqueue_copy(rt.queue, table, table_buf)
                cl.enqueue_copy(rt.queue, overflow, overflow_buf, is_blocking=True)
            if not overflow[0]:
                return np.sort(table[table > 0])
            refusal = (f"the device's key set of 2^{bits} slots filled up: every ray's key "
                       "came back and the host de-duplicated them")
        if on_host is not None and refusal is not None and len(local):
            on_host(refusal)
        keys = self.lattice_keys(origin, local, rotation, tri_face, max_order, base, batch)
        keys = np.unique(keys)
        return keys[keys > 0]

    @staticmethod
    def _check_key_base(tri_face, max_order: int, base: int) -> None:
        n_faces = int(np.max(tri_face, initial=-1)) + 1
        if not (max_order >= 1 and base > n_faces and float(base) ** max_order < 2.0**63):
            raise ArgumentError(f"needs max_order >= 1, a base above every face id + 1 "
                                f"({n_faces}) and base^max_order < 2^63", argument="base",
                                value=(base, max_order))

    def _check_ready(self) -> None:
        """Raise where the caster cannot cast yet (InstancedCaster: before its first
        place()); every launch passes here."""

    @staticmethod
    def _check_lattice(local, rotation):
        local = np.asarray(local)
        r = np.asarray(rotation, dtype=np.float64)
        if local.ndim != 2 or local.shape[1] != 3 or local.dtype != np.float64:
            raise ArgumentError(f"local must be a float64 (R, 3) array, got {local.dtype} "
                                f"{local.shape}", argument="local", value=local.shape)
        if r.shape != (3, 3):
            raise ArgumentError(f"rotation must be 3 x 3, got {r.shape}", argument="rotation",
                                value=r.shape)
        return local, r

    def _rotated_launch(self, kernel_name, origin, local, r, tri_face, extra, out, batch):
        """Launch ``kernel_name`` of kernels/reflect.cl over the lattice ``local`` rotated
        by ``r`` in batches, each ray's row of ``out`` written by its work item (``out``
        None: the kernel writes its results into buffers among ``extra``, which it ends
        with, and nothing is read back here); the lattice buffer is kept while ``local``
        is the same array."""
        import pyopencl as cl

        self._check_ready()
        rt = self.runtime
        kernel = rt.kernel("reflect.cl", kernel_name, defines=self.kernel_defines())
        o = np.asarray(origin, dtype=np.float64)
        row_bytes = 0 if out is None else out[:1].nbytes
        local_size = self.local_size(kernel)
        with self._lock, rt.kernel_clock(), rt.guard(f"launch of kernel {kernel_name}"):
            cached = getattr(self, "_lattice", None)
            if cached is None or cached[0] is not local:
                self._lattice = cached = (local, rt.to_device(kernel_float64(rt, local)))
            face_buf = rt.to_device(np.asarray(tri_face, dtype=np.int32))
            for start in range(0, len(local), batch):
                n = min(batch, len(local) - start)
                o_buf = () if out is None else (rt.empty(n * row_bytes),)
                # whole work-groups, as in specular_sequences
                rt.launch(kernel, n, local_size, self._nodes, self._tri4, self._slot_prim,
                          face_buf, np.float32(o[0]), np.float32(o[1]), np.float32(o[2]),
                          cached[1], *(kernel_scalar64(rt, x) for x in r.ravel()),
                          np.int32(start),
                          *extra, *o_buf, np.int32(n), name=kernel_name)
                if out is not None:
                    cl.enqueue_copy(rt.queue, out[start:start + n], o_buf[0])
            if out is None:
                rt.queue.finish()


class InstancedCaster(RayCaster):
    """A :class:`RayCaster` over a two-level BVH (docs/bvh.md, "Two levels"): one
    bottom-level tree per *part* (the static scene, each rigid moving object), built once
    in the part's own frame, and a top-level tree over the parts placed in the world,
    rebuilt by :meth:`place` at every time step. Kernels are built with
    ``-D BVH_INSTANCED``; their arguments are the same three buffers.

    ``parts`` is a list of ``(local_triangles (T_i, 3, 3), ids (T_i,))``: the part's
    triangles in its frame and their scene ids (together every id of the scene once).
    ``refit`` (N,) bool marks parts whose tree is instead *refit* at every step: their
    Tri4 groups rewritten from the world triangles and their boxes recomputed bottom up
    (same topology), so the kernels test exactly the float32 triangles a single-level
    BVH holds (no transform; O(part) per step). Nothing can be cast before the first
    :meth:`place`.
    """

    EXTRA_DEFINES = {"BVH_INSTANCED": 1}

    def __init__(self, parts, runtime: Runtime | None = None, refit=None):
        self.runtime = runtime or get_runtime()
        if not parts:
            raise ArgumentError("needs at least one part", argument="parts", value=0)
        self.refit = np.zeros(len(parts), bool) if refit is None else np.asarray(refit, bool)
        if self.refit.shape != (len(parts),):
            raise ArgumentError(f"needs one flag per part ({len(parts)})", argument="refit",
                                value=self.refit.shape)
        self.part_ids = [np.asarray(ids, dtype=np.int64) for _, ids in parts]
        n_tri = sum(len(i) for i in self.part_ids)
        seen = np.zeros(n_tri, dtype=np.int64)
        for ids in self.part_ids:
            if ids.size and (ids.min() < 0 or ids.max() >= n_tri):
                raise ArgumentError(f"scene ids must lie in [0, {n_tri})", argument="parts",
                                    value=(int(ids.min()), int(ids.max())))
            np.add.at(seen, ids, 1)
        if not np.all(seen == 1):
            raise ArgumentError("every scene triangle must belong to exactly one part",
                                argument="parts", value=int(np.flatnonzero(seen != 1)[0]))
        self.layout = two_level([build_blas(tri, ids) for tri, ids in parts])
        # the bottom-level trees' need now; place() raises it where a top-level tree needs
        # more (it only ever grows, so kernels built for one step serve the next)
        self.stack_size = layout.stack_size_for(layout.stack_need(self.layout.nodes))
        rt = self.runtime
        self._nodes = rt.to_device(self.layout.nodes)
        self._tri4 = rt.to_device(self.layout.tri4)
        self._slot_prim = rt.to_device(self.layout.slot_prim)
        self.bvh = None
        self.triangles = np.zeros((n_tri, 3, 3))
        self._lock = threading.Lock()
        self._buffers = {}
        self.generation = 0
        self._bounds = None
        self._data64 = None
        self._normals = None
        self._zero_copy = rt.info.device_type == "CPU"
        self._placed = False
        self._head = None
        self._head_copy = None

    def place(self, triangles, rotations, origins, identity=None) -> None:
        """Place the parts for one time step: ``triangles`` (T, 3, 3) float64 are the
        scene's world triangles now (the float64 data every exact computation reads),
        ``rotations`` (N, 3, 3) and ``origins`` (N, 3) the parts' transforms
        (world = R local + p), ``identity`` (N,) bool the parts that are not moved (their
        frame is the world's; default: none). Rebuilds the top-level tree over the parts'
        world boxes and rewrites the head of the node buffer; refit parts (their
        transforms unused) get their groups and boxes from the world triangles; host data
        derived from the triangles (normals, boxes, the float64 device copy) is redone
        only for the parts that moved."""
        import pyopencl as cl

        triangles = np.asarray(triangles, dtype=np.float64)
        n = len(self.part_ids)
        if triangles.shape != self.triangles.shape:
            raise ArgumentError(f"must have the shape {self.triangles.shape} of the parts",
                                argument="triangles", value=triangles.shape)
        rotations = np.asarray(rotations, dtype=np.float64)
        origins = np.asarray(origins, dtype=np.float64)
        identity = np.zeros(n, bool) if identity is None else np.asarray(identity, bool)
        if rotations.shape != (n, 3, 3) or origins.shape != (n, 3) or identity.shape != (n,):
            raise ArgumentError(f"needs one rotation (3, 3), origin (3,) and identity flag "
                                f"per part ({n})", argument="rotations",
                                value=(rotations.shape, origins.shape, identity.shape))
        if not (np.all(np.isfinite(rotations)) and np.all(np.isfinite(origins))):
            raise ArgumentError("transforms must be finite", argument="rotations")
        moved = [k for k in range(n) if not (self._placed and identity[k])]
        t0 = time.perf_counter()
        lo = np.empty((n, 3))
        hi = np.empty((n, 3))
        extent = 0.0
        for k, ids in enumerate(self.part_ids):
            if k in moved:
                tri = triangles[ids]
                self.triangles[ids] = tri
                lo[k], hi[k] = tri.min(axis=(0, 1)), tri.max(axis=(0, 1))
            else:
                lo[k], hi[k] = self._lo[k], self._hi[k]
            extent = max(extent, float(np.abs(lo[k]).max()), float(np.abs(hi[k]).max()))
        self._lo, self._hi = lo, hi
        lo32, hi32 = instance_boxes(lo, hi, extent)
        t1 = time.perf_counter()
        rotations = np.where(self.refit[:, None, None], np.eye(3), rotations)
        origins = np.where(self.refit[:, None], 0.0, origins)
        tlas = tlas_nodes(lo32, hi32)
        self.stack_size = max(self.stack_size,
                              layout.stack_size_for(layout.stack_need(tlas)))
        head = step_head(tlas, n, rotations, origins, self.layout.roots,
                         self.layout.group_range, identity | self.refit)
        refits = []
        for k in moved:
            if self.refit[k]:
                (g0, g1), r0 = self.layout.group_range[k], int(self.layout.roots[k])
                r1 = r0 + self.layout.n_records[k]
                tri4 = world_tri4(triangles, self.layout.slot_prim[4 * g0:4 * g1])
                refits.append((int(g0), tri4, r0, refit(self.layout.nodes[r0:r1], tri4, r0,
                                                         int(g0))))
        t2 = time.perf_counter()
        rt = self.runtime
        with self._lock:
            for g0, tri4, r0, records in refits:
                cl.enqueue_copy(rt.queue, self._tri4, tri4, dst_offset=g0 * tri4[0].nbytes)
                cl.enqueue_copy(rt.queue, self._nodes, records,
                                dst_offset=r0 * records.dtype.itemsize)
            if self._head_copy is not None:   # the last step's head has reached the device
                self._head_copy.wait()
            # not blocking: the in-order queue runs every later kernel after the copy;
            # the array is kept alive until the copy is waited for
            self._head = head
            self._head_copy = cl.enqueue_copy(rt.queue, self._nodes, head, is_blocking=False)
            t3 = time.perf_counter()
            if self._normals is not None or self._bounds is not None:
                for k in moved:
                    ids = self.part_ids[k]
                    if self._normals is not None:
                        self._normals[ids] = triangle_normals(self.triangles[ids])
                    if self._bounds is not None:
                        self._bounds[0][ids] = self.triangles[ids].min(axis=1)
                        self._bounds[1][ids] = self.triangles[ids].max(axis=1)
            if self._data64 is not None:
                for k in moved:
                    ids = self.part_ids[k]
                    if ids.size and np.all(np.diff(ids) == 1):   # one contiguous run
                        start = int(ids[0])
                        # as scene_data64 wrote them: doubles, or (hi, lo) pairs
                        # without fp64 (the same 8 bytes a value)
                        cl.enqueue_copy(rt.queue, self._data64["vertices"],
                                        kernel_float64(rt, self.triangles[ids]),
                                        dst_offset=start * 72)
                        cl.enqueue_copy(rt.queue, self._data64["normals"],
                                        kernel_float64(rt, self.normals64()[ids]),
                                        dst_offset=start * 24)
                    else:
                        self._data64 = None
                        break
                rt.queue.finish()
        self._placed = True
        self.generation += 1
        #: seconds of the last place(): moved triangles and boxes, the top-level tree and
        #: head (and refits), their upload, the host and device data derived from the
        #: moved triangles
        self.last_times = {"boxes": t1 - t0, "tlas": t2 - t1, "upload": t3 - t2,
                           "derived": time.perf_counter() - t3}

    def _check_ready(self) -> None:
        if not self._placed:
            raise ArgumentError("place() the parts before casting", argument="caster",
                                value="unplaced")
