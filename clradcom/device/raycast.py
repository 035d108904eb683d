"""Host side of batch ray casting: closest hit and any hit over a flattened BVH.

Rays and hits cross to the kernels as the packed structs of ``kernels/types.h``;
the numpy dtypes below mirror them byte for byte (tests check the sizes).
"""

from __future__ import annotations

import threading

import numpy as np

from clradcom.device.runtime import Runtime, get_runtime
from clradcom.geometry.bvh import build_bvh

RAY_DTYPE = np.dtype(
    [("org", "<f4", (3,)), ("tmin", "<f4"), ("dir", "<f4", (3,)), ("tmax", "<f4")]
)
HIT_DTYPE = np.dtype(
    [("t", "<f4"), ("u", "<f4"), ("v", "<f4"), ("prim", "<i4"), ("ng", "<f4", (3,)),
     ("pad", "<i4")]
)

BVH8_NODE_DTYPE = np.dtype(
    [("minx", "<f4", (8,)), ("miny", "<f4", (8,)), ("minz", "<f4", (8,)),
     ("maxx", "<f4", (8,)), ("maxy", "<f4", (8,)), ("maxz", "<f4", (8,)),
     ("child", "<i4", (8,)), ("pad", "<i4", (8,))]
)
"""numpy mirror of ``Bvh8Node`` (kernels/types.h): 256 bytes, see :func:`bvh8_nodes`."""

# kernels/intersect.h: BVH_STACK_SIZE, TRI4_ROWS, and the leaf code's 5-bit group count
BVH_STACK_SIZE = 192
BVH_WIDTH = 8
TRI4_ROWS = 9
_MAX_LEAF_GROUPS = 31

# float32 unit roundoff; spawn offsets are a few multiples of it times |p|
_F32_EPS = float(np.finfo(np.float32).eps) * 0.5


def make_rays(origins, directions, tmin=0.0, tmax=np.inf) -> np.ndarray:
    """Pack origins (R,3), directions (R,3) and scalar or (R,) ranges into RAY_DTYPE.

    Directions need not be unit length; t is then measured in units of |dir|.
    """
    origins = np.asarray(origins, dtype=np.float64)
    directions = np.asarray(directions, dtype=np.float64)
    if origins.ndim != 2 or origins.shape[1] != 3:
        raise ValueError(f"origins must have shape (R, 3), got {origins.shape}")
    if directions.shape != origins.shape:
        raise ValueError(
            f"directions shape {directions.shape} differs from origins shape {origins.shape}"
        )
    for name, arr in (("origins", origins), ("directions", directions)):
        bad = ~np.isfinite(arr).all(axis=1)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise ValueError(f"{name}[{i}] is not finite: {arr[i].tolist()}")
    zero = ~np.any(directions != 0.0, axis=1)
    if zero.any():
        raise ValueError(f"directions[{int(np.flatnonzero(zero)[0])}] is the zero vector")
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
    bound = 8.0 * _F32_EPS * (np.abs(points).max(axis=1) + 1.0)
    side = np.sign(np.einsum("ij,ij->i", normals, directions))
    side[side == 0] = 1.0
    n_len = np.linalg.norm(normals, axis=1)
    n_len[n_len == 0] = 1.0
    return points + (side * bound / n_len)[:, None] * normals


def tri4_groups(bvh, triangles) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Leaf triangles in the kernels' Tri4 layout (kernels/intersect.h).

    Every leaf of ``bvh`` gets ``ceil(count / 4)`` consecutive groups of four
    triangles, leaves in ``tri_index`` order; a group is 9 float4 rows, row
    ``3 * j + k`` holding coordinate k of vertex j of its four triangles (one per
    lane). Lanes past a leaf's last triangle repeat it. Leaf slot ``s`` is lane
    ``s % 4`` of group ``s // 4``.

    Returns ``(tri4, slot_prim, leaf_first, leaf_groups)``: float32 ``(G, 9, 4)``,
    int32 ``(4 G,)`` scene triangle id per slot, and per binary node of ``bvh``
    the first group and number of groups of its leaf (0 for inner nodes).
    """
    nodes = bvh.nodes
    count = nodes["count"].astype(np.int64)
    first = nodes["left_first"].astype(np.int64)
    leaves = np.flatnonzero(count > 0)
    leaves = leaves[np.argsort(first[leaves], kind="stable")]
    n_groups = (count[leaves] + 3) // 4
    g_first = np.cumsum(n_groups) - n_groups
    n_total = int(n_groups.sum())
    leaf = np.repeat(np.arange(len(leaves)), n_groups)
    local = np.arange(n_total) - g_first[leaf]
    lane = np.minimum(4 * local[:, None] + np.arange(4)[None, :],
                      (count[leaves] - 1)[leaf][:, None])
    prim = np.asarray(bvh.tri_index)[first[leaves][leaf][:, None] + lane]
    verts = np.asarray(triangles, dtype=np.float32)[prim]          # (G, lane, vertex, xyz)
    tri4 = np.ascontiguousarray(verts.transpose(0, 2, 3, 1).reshape(n_total, TRI4_ROWS, 4))
    leaf_first = np.zeros(len(nodes), dtype=np.int64)
    leaf_groups = np.zeros(len(nodes), dtype=np.int64)
    leaf_first[leaves] = g_first
    leaf_groups[leaves] = n_groups
    return tri4, np.ascontiguousarray(prim.reshape(-1), dtype=np.int32), leaf_first, leaf_groups


def _collapse(inner: np.ndarray, left: np.ndarray, area: np.ndarray):
    """Greedy 8-wide collapse of a binary tree (root inner), all records of a level at once.

    Returns (slot, used, rec_index, level): per record the binary nodes in its slots, which
    slots are used, the record index of every binary node that starts a record (depth-first
    record numbering: a record's first inner child follows it), and per record its level.
    """
    levels = []
    starts = np.zeros(1, dtype=np.int64)   # binary nodes starting this level's records
    while starts.size:
        n = starts.size
        rows = np.arange(n)
        slot = np.full((n, BVH_WIDTH), -1, dtype=np.int64)
        slot[:, 0] = left[starts]
        slot[:, 1] = left[starts] + 1
        filled = np.full(n, 2)
        for _ in range(BVH_WIDTH - 2):
            # open the inner child of largest area while there is room
            ok = slot >= 0
            cand = np.where(ok & inner[np.where(ok, slot, 0)], area[np.where(ok, slot, 0)], -1.0)
            j = np.argmax(cand, axis=1)
            grow = np.flatnonzero(cand[rows, j] >= 0.0)
            if not grow.size:
                break
            b = slot[grow, j[grow]]
            slot[grow, j[grow]] = left[b]
            slot[grow, filled[grow]] = left[b] + 1
            filled[grow] += 1
        levels.append(slot)
        ok = slot >= 0
        starts = slot[ok & inner[np.where(ok, slot, 0)]]   # row-major: breadth-first order
    depth = np.repeat(np.arange(len(levels)), [len(x) for x in levels])
    slot = np.concatenate(levels)
    used = slot >= 0
    slot = np.where(used, slot, 0)
    is_inner = used & inner[slot]
    # breadth-first record ids (the order the level loop made them) ...
    n_rec = len(slot)
    bfs = np.zeros(len(inner), dtype=np.int64)
    bfs[slot[is_inner]] = np.arange(1, n_rec)
    kid = np.where(is_inner, bfs[slot], 0)
    # ... renumbered depth first: subtree sizes bottom up, then preorder ids top down
    size = np.ones(n_rec, dtype=np.int64)
    first = np.cumsum([0] + [len(x) for x in levels])
    for d in range(len(levels) - 1, -1, -1):
        r = np.arange(first[d], first[d + 1])
        size[r] += np.where(kid[r] > 0, size[kid[r]], 0).sum(axis=1)
    pre = np.zeros(n_rec, dtype=np.int64)
    for d in range(len(levels) - 1):
        r = np.arange(first[d], first[d + 1])
        ks = np.where(kid[r] > 0, size[kid[r]], 0)
        before = np.cumsum(ks, axis=1) - ks
        m = kid[r] > 0
        pre[kid[r][m]] = (pre[r][:, None] + 1 + before)[m]
    order = np.empty(n_rec, dtype=np.int64)
    order[pre] = np.arange(n_rec)
    rec_index = np.zeros(len(inner), dtype=np.int64)
    rec_index[slot[is_inner]] = pre[bfs[slot[is_inner]]]
    return slot[order], used[order], rec_index, depth[order]


def bvh8_nodes(nodes: np.ndarray, leaf_first=None, leaf_count=None) -> np.ndarray:
    """8-wide traversal layout (BVH8_NODE_DTYPE) from a builder's BVH_NODE_DTYPE array.

    Each binary inner node that starts a record gets its two children, and
    then, while it has fewer than eight, the inner child with the largest
    surface area is replaced by its own two children (the usual greedy
    collapse). Records are numbered depth first (a record's first inner child
    follows it), record 0 is the root. Child codes are a record index (> 0), a
    leaf ``-(first * 32 + count) - 1`` with ``first``/``count`` from
    ``leaf_first``/``leaf_count`` (per binary node; default: the node's own
    ``left_first``/``count``), or 0 for an empty slot, whose bounds are
    +inf / -inf. A tree that is one leaf gets one record holding that leaf.
    Raises ValueError if a leaf count exceeds 31 or the tree needs a deeper
    traversal stack than the kernels have.
    """
    nodes = np.asarray(nodes)
    counts = nodes["count"].astype(np.int64)
    left = nodes["left_first"].astype(np.int64)
    leaf_first = left if leaf_first is None else np.asarray(leaf_first, dtype=np.int64)
    leaf_count = counts if leaf_count is None else np.asarray(leaf_count, dtype=np.int64)
    if leaf_count[counts > 0].max(initial=0) > _MAX_LEAF_GROUPS:
        raise ValueError(f"a BVH leaf holds {int(leaf_count.max())} triangle groups; at most "
                         f"{_MAX_LEAF_GROUPS} are supported")
    ext = (nodes["bmax"].astype(np.float64) - nodes["bmin"].astype(np.float64))
    area = ext[:, 0] * ext[:, 1] + ext[:, 1] * ext[:, 2] + ext[:, 2] * ext[:, 0]
    if counts[0] > 0:
        slot = np.zeros((1, BVH_WIDTH), dtype=np.int64)
        used = np.zeros((1, BVH_WIDTH), dtype=bool)
        used[0, 0] = True
        rec_index = np.zeros(len(nodes), dtype=np.int64)
        level = np.zeros(1, dtype=np.int64)
    else:
        slot, used, rec_index, level = _collapse(counts == 0, left, area)
    n_rec = len(slot)
    c = nodes[slot]
    out = np.zeros(n_rec, dtype=BVH8_NODE_DTYPE)
    for name, field, axis in (("minx", "bmin", 0), ("miny", "bmin", 1), ("minz", "bmin", 2),
                              ("maxx", "bmax", 0), ("maxy", "bmax", 1), ("maxz", "bmax", 2)):
        empty = np.float32(np.inf if field == "bmin" else -np.inf)
        out[name] = np.where(used, c[field][:, :, axis], empty)
    is_leaf = c["count"] > 0
    inner_code = rec_index[slot]
    leaf_code = -(leaf_first[slot] * 32 + leaf_count[slot]) - 1
    if leaf_code.min(initial=0) < np.iinfo(np.int32).min:
        raise ValueError("too many leaf slots for the 8-wide leaf codes")
    out["child"] = np.where(used, np.where(is_leaf, leaf_code, inner_code), 0)

    # stack need: a record pushes up to (children - 1) entries before going on, so a
    # record needs that plus the most any inner child needs; evaluated level by level
    # from the deepest records up
    k_minus_1 = used.sum(axis=1) - 1
    child = out["child"].astype(np.int64)
    inner = child > 0
    need = np.zeros(n_rec, dtype=np.int64)
    for d in range(int(level.max()), -1, -1):
        rows = np.flatnonzero(level == d)
        sub = np.where(inner[rows], need[np.where(inner[rows], child[rows], 0)], 0)
        need[rows] = k_minus_1[rows] + sub.max(axis=1)
    if need[0] > BVH_STACK_SIZE:
        raise ValueError(f"BVH needs a traversal stack of {int(need[0])} entries; the kernels "
                         f"hold {BVH_STACK_SIZE} (build it with a smaller max_depth)")
    return out


class RayCaster:
    """Closest-hit and any-hit queries for one triangle set on one OpenCL device.

    Device data: the 8-wide BVH (:func:`bvh8_nodes`), the leaf triangles in
    Tri4 groups and the scene id of every leaf slot (:func:`tri4_groups`). On a
    CPU device the kernels read the rays and write the results in the numpy
    arrays themselves (USE_HOST_PTR); elsewhere ray, ignore and result buffers
    are kept between calls and grown as needed. Calls are serialised by a lock.
    """

    # Work-group size: PoCL's CPU device runs a work-group's items one after the
    # other in a loop; 16 to 256 measured the same, its own choice ~15% slower.
    LOCAL_SIZE = 64

    def __init__(self, triangles, bvh=None, runtime: Runtime | None = None):
        triangles = np.asarray(triangles, dtype=np.float64)
        if triangles.ndim != 3 or triangles.shape[1:] != (3, 3):
            raise ValueError(f"triangles must have shape (T, 3, 3), got {triangles.shape}")
        self.runtime = runtime or get_runtime()
        self.triangles = triangles
        if bvh is None:
            # all three axes binned: ~10% faster casting for twice the (small) build time
            bvh = build_bvh(triangles, axes="all")
        self.bvh = bvh
        tri4, slot_prim, leaf_first, leaf_groups = tri4_groups(bvh, triangles)
        rt = self.runtime
        self._nodes = rt.to_device(bvh8_nodes(bvh.nodes, leaf_first, leaf_groups))
        self._tri4 = rt.to_device(tri4)
        self._slot_prim = rt.to_device(slot_prim)
        self._lock = threading.Lock()
        self._buffers: dict[str, tuple[int, object]] = {}
        # PoCL's CPU device uses USE_HOST_PTR memory in place (5% of the end-to-end
        # time saved on 500k rays); other devices get reused buffers and copies.
        self._zero_copy = rt.info.device_type == "CPU"

    @property
    def device_nodes(self):
        """Device buffer of the traversal layout (Bvh8Node records, see bvh8_nodes)."""
        return self._nodes

    @property
    def device_verts(self):
        """Device buffer of the leaf triangles as Tri4 groups (see tri4_groups)."""
        return self._tri4

    @property
    def device_tri_index(self):
        """Device buffer mapping leaf slots to scene triangle ids (int32)."""
        return self._slot_prim

    def _buffer(self, name, nbytes, flags):
        """A device buffer of at least nbytes kept under name, grown by doubling."""
        import pyopencl as cl

        size, buf = self._buffers.get(name, (0, None))
        if size < nbytes:
            size = max(nbytes, 2 * size, 4096)
            buf = cl.Buffer(self.runtime.context, flags, size=size)
            self._buffers[name] = (size, buf)
        return buf

    def _launch(self, kernel_name, rays, ignore_prim, out_dtype):
        import pyopencl as cl

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
        kernel = rt.kernel("raycast.cl", kernel_name)
        local = self.LOCAL_SIZE
        with self._lock:
            if self._zero_copy:
                # A CPU device reads and writes the numpy arrays in place: no copies.
                if not rays.flags.writeable:
                    rays = rays.copy()
                ray_buf = cl.Buffer(rt.context, mf.READ_ONLY | mf.USE_HOST_PTR, hostbuf=rays)
                out_buf = cl.Buffer(rt.context, mf.WRITE_ONLY | mf.USE_HOST_PTR, hostbuf=out)
                ign_buf = None if ignore is None else cl.Buffer(
                    rt.context, mf.READ_ONLY | mf.USE_HOST_PTR, hostbuf=np.array(ignore))
            else:
                ray_buf = self._buffer("rays", rays.nbytes, mf.READ_ONLY)
                out_buf = self._buffer(kernel_name, out.nbytes, mf.WRITE_ONLY)
                cl.enqueue_copy(rt.queue, ray_buf, rays, is_blocking=False)
                ign_buf = None
                if ignore is not None:
                    ign_buf = self._buffer("ignore", ignore.nbytes, mf.READ_ONLY)
                    cl.enqueue_copy(rt.queue, ign_buf, ignore, is_blocking=False)
            # ign_buf None is a NULL pointer: no ray ignores a triangle. The kernels
            # ignore the work items past n.
            kernel(rt.queue, (-(-n // local) * local,), (local,), self._nodes, self._tri4,
                   self._slot_prim, ray_buf, ign_buf, out_buf, np.int32(n))
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

    def closest_hit(self, rays: np.ndarray, ignore_prim=None) -> np.ndarray:
        """HIT_DTYPE per ray: t (inf on a miss), u, v, prim (-1 on a miss), unit ng."""
        return self._launch("closest_hit", rays, ignore_prim, HIT_DTYPE)

    def occluded(self, rays: np.ndarray, ignore_prim=None) -> np.ndarray:
        """True where any triangle is hit in (tmin, tmax)."""
        return self._launch("any_hit", rays, ignore_prim, np.uint8).astype(bool)
