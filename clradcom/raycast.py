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

PAIR_NODE_DTYPE = np.dtype(
    [("lmin", "<f4", (3,)), ("lref", "<i4"), ("lmax", "<f4", (3,)), ("lcount", "<i4"),
     ("rmin", "<f4", (3,)), ("rref", "<i4"), ("rmax", "<f4", (3,)), ("rcount", "<i4")]
)

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


def pair_nodes(nodes: np.ndarray) -> np.ndarray:
    """Traversal layout (PAIR_NODE_DTYPE) from a builder's BVH_NODE_DTYPE array.

    One record per inner node holding both children's boxes; record 0 is the
    root. A tree that is one leaf gets one record with the leaf on the left
    and no right child (count -1).
    """
    nodes = np.asarray(nodes)
    inner = np.flatnonzero(nodes["count"] == 0)
    if len(inner) == 0:
        out = np.zeros(1, dtype=PAIR_NODE_DTYPE)
        root = nodes[0]
        out["lmin"], out["lmax"] = root["bmin"], root["bmax"]
        out["lref"], out["lcount"] = root["left_first"], root["count"]
        out["rcount"] = -1
        return out
    if inner[0] != 0:
        raise ValueError("BVH root (node 0) must be an inner node when any node is")
    record = np.full(len(nodes), -1, dtype=np.int64)
    record[inner] = np.arange(len(inner))
    out = np.zeros(len(inner), dtype=PAIR_NODE_DTYPE)
    for side, offset in (("l", 0), ("r", 1)):
        child = nodes["left_first"][inner] + offset
        c = nodes[child]
        out[side + "min"] = c["bmin"]
        out[side + "max"] = c["bmax"]
        is_leaf = c["count"] > 0
        out[side + "count"] = c["count"]
        out[side + "ref"] = np.where(is_leaf, c["left_first"], record[child])
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
        self._nodes = rt.to_device(pair_nodes(self.bvh.nodes))
        self._verts = rt.to_device(verts)
        self._tri_index = rt.to_device(self.bvh.tri_index.astype(np.int32))

    @property
    def device_nodes(self):
        """Device buffer of the traversal layout (PairNode records)."""
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
        kernel(rt.queue, (-(-n // local) * local,), (local,), self._nodes, self._verts, self._tri_index, ray_buf,
               ign_buf, out_buf, np.int32(n))
        cl.enqueue_copy(rt.queue, out, out_buf)
        return out

    def closest_hit(self, rays: np.ndarray, ignore_prim=None) -> np.ndarray:
        """HIT_DTYPE per ray: t (inf on a miss), u, v, prim (-1 on a miss), unit ng."""
        return self._launch("closest_hit", rays, ignore_prim, HIT_DTYPE)

    def occluded(self, rays: np.ndarray, ignore_prim=None) -> np.ndarray:
        """True where any triangle is hit in (tmin, tmax)."""
        return self._launch("any_hit", rays, ignore_prim, np.uint8).astype(bool)
