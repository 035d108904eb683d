"""Host side of batch ray casting: closest hit and any hit over a flattened BVH.

Rays and hits cross to the kernels as the packed structs of ``kernels/types.h``;
the numpy dtypes below mirror them byte for byte (tests check the sizes).
"""

from __future__ import annotations

import numpy as np

from .opencl import Runtime, get_runtime

RAY_DTYPE = np.dtype(
    [("org", "<f4", (3,)), ("tmin", "<f4"), ("dir", "<f4", (3,)), ("tmax", "<f4")]
)
HIT_DTYPE = np.dtype(
    [("t", "<f4"), ("u", "<f4"), ("v", "<f4"), ("prim", "<i4"), ("ng", "<f4", (3,)),
     ("pad", "<i4")]
)

BVH4_NODE_DTYPE = np.dtype(
    [("minx", "<f4", (4,)), ("miny", "<f4", (4,)), ("minz", "<f4", (4,)),
     ("maxx", "<f4", (4,)), ("maxy", "<f4", (4,)), ("maxz", "<f4", (4,)),
     ("child", "<i4", (4,)), ("pad", "<i4", (4,))]
)

# kernels/intersect.h: BVH4_STACK_SIZE, and the leaf code's 5-bit count
BVH4_STACK_SIZE = 192
_MAX_LEAF_COUNT = 31

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


def bvh4_nodes(nodes: np.ndarray) -> np.ndarray:
    """4-wide traversal layout (BVH4_NODE_DTYPE) from a builder's BVH_NODE_DTYPE array.

    Each binary inner node that starts a record gets its two children, and
    then, while it has fewer than four, the inner child with the largest
    surface area is replaced by its own two children (the usual greedy
    collapse). Record 0 is the root; child codes are a record index (> 0), a
    leaf ``-(first * 32 + count) - 1``, or 0 for an empty slot, whose bounds
    are +inf / -inf. A tree that is one leaf gets one record holding that leaf.
    Raises ValueError if a leaf holds more than 31 triangles or the tree needs
    a deeper traversal stack than the kernels have.
    """
    nodes = np.asarray(nodes)
    counts = nodes["count"].astype(np.int64)
    left = nodes["left_first"].astype(np.int64)
    if counts.max(initial=0) > _MAX_LEAF_COUNT:
        raise ValueError(f"a BVH leaf holds {int(counts.max())} triangles; at most "
                         f"{_MAX_LEAF_COUNT} are supported")
    ext = (nodes["bmax"].astype(np.float64) - nodes["bmin"].astype(np.float64))
    area = ext[:, 0] * ext[:, 1] + ext[:, 1] * ext[:, 2] + ext[:, 2] * ext[:, 0]
    counts_l, left_l, area_l = counts.tolist(), left.tolist(), area.tolist()

    if counts_l[0] > 0:
        groups = [[0]]
    else:
        groups = []          # per record: the binary nodes in its child slots
        queue = [0]          # binary nodes that start a record, in record order
        record_of = {0: 0}
        q = 0
        while q < len(queue):
            b = queue[q]
            q += 1
            kids = [left_l[b], left_l[b] + 1]
            while len(kids) < 4:
                best, best_area = -1, -1.0
                for j, k in enumerate(kids):
                    if counts_l[k] == 0 and area_l[k] > best_area:
                        best, best_area = j, area_l[k]
                if best < 0:
                    break
                k = kids.pop(best)
                kids[best:best] = [left_l[k], left_l[k] + 1]
            for k in kids:
                if counts_l[k] == 0:
                    record_of[k] = len(queue)
                    queue.append(k)
            groups.append(kids)
    n_rec = len(groups)
    slot = np.zeros((n_rec, 4), dtype=np.int64)
    used = np.zeros((n_rec, 4), dtype=bool)
    for r, kids in enumerate(groups):
        slot[r, :len(kids)] = kids
        used[r, :len(kids)] = True
    c = nodes[slot]
    out = np.zeros(n_rec, dtype=BVH4_NODE_DTYPE)
    for name, field, axis in (("minx", "bmin", 0), ("miny", "bmin", 1), ("minz", "bmin", 2),
                              ("maxx", "bmax", 0), ("maxy", "bmax", 1), ("maxz", "bmax", 2)):
        empty = np.float32(np.inf if field == "bmin" else -np.inf)
        out[name] = np.where(used, c[field][:, :, axis], empty)
    is_leaf = c["count"] > 0
    if counts_l[0] > 0:
        inner_code = np.zeros_like(slot)
    else:
        rec_index = np.zeros(len(nodes), dtype=np.int64)
        rec_index[list(record_of)] = list(record_of.values())
        inner_code = rec_index[slot]
    leaf_code = -(c["left_first"].astype(np.int64) * 32 + c["count"]) - 1
    if leaf_code.min(initial=0) < np.iinfo(np.int32).min:
        raise ValueError("too many leaf slots for the 4-wide leaf codes")
    out["child"] = np.where(used, np.where(is_leaf, leaf_code, inner_code), 0)

    # stack need: a record pushes up to (children - 1) entries before going on
    k_minus_1 = used.sum(axis=1) - 1
    need = np.zeros(n_rec, dtype=np.int64)
    child = out["child"]
    for r in range(n_rec - 1, -1, -1):   # children have larger record indices
        sub = child[r][child[r] > 0]
        need[r] = k_minus_1[r] + (need[sub].max() if len(sub) else 0)
    if need[0] > BVH4_STACK_SIZE:
        raise ValueError(f"BVH needs a traversal stack of {int(need[0])} entries; the kernels "
                         f"hold {BVH4_STACK_SIZE} (build it with a smaller max_depth)")
    return out


class RayCaster:
    """Closest-hit and any-hit queries for one triangle set on one OpenCL device."""

    def __init__(self, triangles, bvh=None, runtime: Runtime | None = None):


        triangles = np.asarray(triangles, dtype=np.float64)
        if triangles.ndim != 3 or triangles.shape[1:] != (3, 3):
            raise ValueError(f"triangles must have shape (T, 3, 3), got {triangles.shape}")
        self.runtime = runtime or get_runtime()
        self.triangles = triangles
        if bvh is None:
            from .bvh import build_bvh

            bvh = build_bvh(triangles)
        self.bvh = bvh
        verts = np.zeros((len(triangles), 3, 4), dtype=np.float32)
        verts[:, :, :3] = triangles[self.bvh.tri_index]
        rt = self.runtime
        self._nodes = rt.to_device(bvh4_nodes(self.bvh.nodes))
        self._verts = rt.to_device(verts)
        self._tri_index = rt.to_device(self.bvh.tri_index.astype(np.int32))

    @property
    def device_nodes(self):
        """Device buffer of the traversal layout (Bvh4Node records, see bvh4_nodes)."""
        return self._nodes

    @property
    def device_verts(self):
        """Device buffer of the float4 vertices in leaf-slot order."""
        return self._verts

    @property
    def device_tri_index(self):
        """Device buffer mapping leaf slots to scene triangle ids."""
        return self._tri_index

    def _launch(self, kernel_name, rays, ignore_prim, out_dtype):
        import pyopencl as cl

        rays = np.ascontiguousarray(rays, dtype=RAY_DTYPE)
        n = len(rays)
        out = np.empty(n, dtype=out_dtype)
        if n == 0:
            return out
        if ignore_prim is None:
            ignore = np.full(n, -1, dtype=np.int32)
        else:
            ignore = np.ascontiguousarray(np.broadcast_to(ignore_prim, (n,)), dtype=np.int32)
        rt = self.runtime
        ray_buf = rt.to_device(rays)
        ign_buf = rt.to_device(ignore)
        out_buf = rt.empty(out.nbytes)
        kernel = rt.kernel("raycast.cl", kernel_name)
        # A fixed work-group size: PoCL's own pick (hundreds to thousands of
        # work items) ran ~15% slower; 64 also suits GPUs. The kernels ignore
        # the work items past n.
        local = 64
        kernel(rt.queue, (-(-n // local) * local,), (local,), self._nodes, self._verts,
               self._tri_index, ray_buf, ign_buf, out_buf, np.int32(n))
        cl.enqueue_copy(rt.queue, out, out_buf)
        return out

    def closest_hit(self, rays: np.ndarray, ignore_prim=None) -> np.ndarray:
        """HIT_DTYPE per ray: t (inf on a miss), u, v, prim (-1 on a miss), unit ng."""
        return self._launch("closest_hit", rays, ignore_prim, HIT_DTYPE)

    def occluded(self, rays: np.ndarray, ignore_prim=None) -> np.ndarray:
        """True where any triangle is hit in (tmin, tmax)."""
        return self._launch("any_hit", rays, ignore_prim, np.uint8).astype(bool)
