"""Host-side BVH construction over triangle soups, in flat arrays for the OpenCL kernels.

Layout
------
The tree is an array of :data:`BVH_NODE_DTYPE` records (32 bytes each, mirroring the C struct
``BVHNode`` in ``kernels/types.h``)::

    typedef struct { float bmin[3]; int left_first; float bmax[3]; int count; } BVHNode;

* Node 0 is the root.
* Inner node: ``count == 0``; its children are ``nodes[left_first]`` and ``nodes[left_first + 1]``
  (siblings are always adjacent; the left child has the smaller centroid coordinates along the
  split axis).
* Leaf: ``count > 0``; its triangles are ``tri_index[left_first : left_first + count]``, where
  ``tri_index`` (int32) is a permutation of ``range(T)`` giving scene triangle ids. A kernel
  usually stores the vertices in leaf order, ``triangles[tri_index]``, so that leaf slot ``i``
  holds triangle ``tri_index[i]``.
* A one-triangle scene is a single leaf root. Nodes are numbered breadth first.
* Boxes are computed from the float32-rounded vertices with exact float32 min/max, so every box
  conservatively contains the float32 triangles the kernels intersect.

Build algorithm
---------------
Binned SAH construction after Wald, "On fast construction of SAH-based bounding volume
hierarchies", IEEE Symposium on Interactive Ray Tracing 2007: the centroid bounds of each node are
cut into ``n_bins`` equal bins along their longest axis (or along all three axes with
``axes="all"``), per-bin triangle counts and boxes are gathered, a prefix/suffix sweep evaluates
the surface area heuristic (MacDonald & Booth, "Heuristics for ray tracing using space
subdivision", The Visual Computer 6(3), 1990) at every bin boundary, and the cheapest plane wins
unless making a leaf is cheaper.

To be fast in numpy the tree is built breadth first: all nodes of one level are binned and split
at once (``np.bincount`` / ``np.minimum.at`` over (node, bin) keys, cumulative min/max over bins,
an O(n) stable partition of the triangle order per node by prefix sums, ``reduceat`` for the
children's boxes). Triangles that reach a leaf leave the working set.

Fallbacks: a node with no valid SAH plane (all centroids in one bin, e.g. thousands of copies of
one triangle) or one that would exceed ``max_depth`` is split at the object median along its
longest centroid axis (ties in the order they come, so identical centroids split by index). Nodes
with at most ``max_leaf_size`` triangles are always leaves; SAH-terminated leaves never exceed
``max_leaf_cap``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from clradcom.errors import ArgumentError

__all__ = [
    "BVH_NODE_DTYPE",
    "Bvh",
    "BvhValidationError",
    "build_bvh",
    "triangle_bounds",
    "validate_bvh",
]

BVH_NODE_DTYPE = np.dtype(
    [
        ("bmin", "<f4", (3,)),
        ("left_first", "<i4"),
        ("bmax", "<f4", (3,)),
        ("count", "<i4"),
    ]
)
"""numpy mirror of ``BVHNode`` (itemsize 32, no padding)."""

assert BVH_NODE_DTYPE.itemsize == 32


class BvhValidationError(ValueError):
    """A BVH breaks one of the layout invariants (raised by :func:`validate_bvh`)."""


@dataclass(frozen=True)
class Bvh:
    """A flattened BVH: ``nodes`` (:data:`BVH_NODE_DTYPE`, C-contiguous) and ``tri_index``.

    ``tri_index`` (int32, C-contiguous) is a permutation of ``range(n_triangles)``; leaf ``i``
    covers ``tri_index[nodes[i].left_first : nodes[i].left_first + nodes[i].count]``.
    """

    nodes: np.ndarray
    tri_index: np.ndarray

    @property
    def n_nodes(self) -> int:
        return int(self.nodes.shape[0])

    @property
    def n_triangles(self) -> int:
        return int(self.tri_index.shape[0])

    def is_leaf(self) -> np.ndarray:
        """Boolean mask of leaf nodes."""
        return self.nodes["count"] > 0

    def leaf_sizes(self) -> np.ndarray:
        """Triangle counts of the leaves, in node order."""
        c = self.nodes["count"]
        return c[c > 0].copy()

    def node_depths(self) -> np.ndarray:
        """Depth of every node (root 0), as edges from the root."""
        return _node_depths(self.nodes)

    def depth(self) -> int:
        """Longest root-to-leaf path in edges (0 for a single-leaf tree).

        A stack-based traversal that pushes one sibling per inner node needs at most this many
        stack slots.
        """
        return int(self.node_depths().max())

    def sah_cost(self, traversal_cost: float = 1.0, intersect_cost: float = 1.0) -> float:
        """SAH cost of the whole tree (MacDonald & Booth 1990), relative to the root's area.

        ``sum_inner C_t A(n)/A(root) + sum_leaf C_i count(n) A(n)/A(root)``.
        """
        return _tree_sah(self.nodes, traversal_cost, intersect_cost)

    def ordered_triangles(self, triangles: np.ndarray) -> np.ndarray:
        """``triangles`` reordered into leaf-slot order (float32, C-contiguous)."""
        t = np.asarray(triangles, dtype=np.float32)
        return np.ascontiguousarray(t[self.tri_index])


def _half_area(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Half surface area of boxes given as (..., 3) float arrays, computed in float64."""
    d = hi.astype(np.float64) - lo.astype(np.float64)
    return d[..., 0] * d[..., 1] + d[..., 1] * d[..., 2] + d[..., 2] * d[..., 0]


def _half_area_soa(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Half surface area of boxes stored as (3, ...) arrays (float32)."""
    dx = hi[0] - lo[0]
    dy = hi[1] - lo[1]
    dz = hi[2] - lo[2]
    return dx * dy + dy * dz + dz * dx


def _node_depths(nodes: np.ndarray) -> np.ndarray:
    depth = np.zeros(nodes.shape[0], dtype=np.int64)
    inner = np.flatnonzero(nodes["count"] == 0)
    lf = nodes["left_first"].astype(np.int64)
    # Children always have larger ids than their parent in a BFS layout, but do not rely on it:
    # propagate level by level from the root.
    frontier = np.array([0], dtype=np.int64)
    is_inner = np.zeros(nodes.shape[0], dtype=bool)
    is_inner[inner] = True
    d = 0
    while frontier.size:
        depth[frontier] = d
        fi = frontier[is_inner[frontier]]
        frontier = np.concatenate([lf[fi], lf[fi] + 1])
        d += 1
    return depth


def _tree_sah(nodes: np.ndarray, ct: float, ci: float) -> float:
    area = _half_area(nodes["bmin"], nodes["bmax"])
    root = area[0]
    cnt = nodes["count"].astype(np.float64)
    w = np.where(cnt > 0, ci * cnt, ct)
    if root <= 0.0:
        # Degenerate (point/segment) scene: count every node with unit area.
        return float(w.sum())
    return float((w * area).sum() / root)


def triangle_bounds(triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Check ``triangles`` and return ``(tris_f32, lo, hi)``: float32 (T,3,3) and (T,3) boxes.

    Raises ValueError for a wrong shape, zero triangles, a non-real dtype, or NaN/inf vertices
    (including finite float64 values that overflow float32).
    """
    arr = np.asarray(triangles)
    if arr.ndim != 3 or arr.shape[1:] != (3, 3):
        raise ArgumentError(
            f"triangles must have shape (T, 3, 3) (T triangles x 3 vertices x xyz), got {arr.shape}"
        )
    if arr.shape[0] == 0:
        raise ArgumentError("cannot build a BVH over 0 triangles")
    if not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)):
        raise ArgumentError(f"triangles must be a real numeric array, got dtype {arr.dtype}")
    with np.errstate(over="ignore", invalid="ignore"):
        tris = np.ascontiguousarray(arr, dtype=np.float32)
        lo = np.minimum(np.minimum(tris[:, 0], tris[:, 1]), tris[:, 2])
        hi = np.maximum(np.maximum(tris[:, 0], tris[:, 1]), tris[:, 2])
    # NaN propagates through min/max and inf reaches lo or hi, so checking the boxes suffices.
    if not (np.isfinite(lo).all() and np.isfinite(hi).all()):
        bad_in = ~np.isfinite(arr).reshape(arr.shape[0], -1).all(axis=1)
        if bad_in.any():
            bad = np.flatnonzero(bad_in)
            raise ArgumentError(
                f"triangles contain NaN or infinite vertex coordinates ({bad.size} triangles, "
                f"first index {int(bad[0])})"
            )
        bad = np.flatnonzero(~np.isfinite(tris).reshape(tris.shape[0], -1).all(axis=1))
        raise ArgumentError(
            f"vertex coordinates overflow float32 ({bad.size} triangles, first index {int(bad[0])})"
        )
    return tris, lo, hi


def _levels_needed(count: np.ndarray, leaf: int) -> np.ndarray:
    """Levels of halving needed to get ``count`` triangles into leaves of at most ``leaf``."""
    q = -(-count // leaf)  # ceil
    return np.ceil(np.log2(np.maximum(q, 1))).astype(np.int64)


def build_bvh(
    triangles: np.ndarray,
    *,
    max_leaf_size: int = 4,
    n_bins: int = 16,
    max_leaf_cap: int = 16,
    traversal_cost: float = 1.0,
    intersect_cost: float = 1.0,
    axes: str = "longest",
    max_depth: int = 64,
    method: str = "sah",
) -> Bvh:
    """Build a BVH over ``triangles`` ((T, 3, 3) vertex coordinates, any real dtype).

    Parameters
    ----------
    max_leaf_size:
        Nodes with at most this many triangles always become leaves.
    n_bins:
        SAH bins per node and axis (Wald 2007 uses 8-32; 16 is a good trade-off).
    max_leaf_cap:
        Hard cap on leaf size when the SAH prefers a leaf (``>= max_leaf_size``). Nodes
        above it are always split.
    traversal_cost, intersect_cost:
        SAH constants C_t and C_i: splitting costs ``C_t + C_i (A_L N_L + A_R N_R) / A``,
        a leaf costs ``C_i N``.
    axes:
        ``"longest"`` bins only along the longest centroid-bounds axis of each node (Wald 2007;
        fastest), ``"all"`` tries all three axes (about 2x slower build, slightly lower cost).
    max_depth:
        Upper bound on the tree depth in edges (the OpenCL traversal stack holds 64 entries).
        Nodes that would exceed it are split at the object median. It is raised to the minimum
        depth a balanced tree needs if set lower.
    method:
        ``"sah"`` (default) or ``"median"``: object-median split along the longest centroid
        axis at every node (a quality reference; leaves hold at most ``max_leaf_size``).

    Returns
    -------
    Bvh
        With ``nodes`` (:data:`BVH_NODE_DTYPE`) and ``tri_index`` (int32); see the module
        docstring for the layout.
    """
    if method not in ("sah", "median"):
        raise ArgumentError(f"method must be 'sah' or 'median', got {method!r}")
    if axes not in ("longest", "all"):
        raise ArgumentError(f"axes must be 'longest' or 'all', got {axes!r}")
    max_leaf_size = int(max_leaf_size)
    n_bins = int(n_bins)
    if max_leaf_size < 1:
        raise ArgumentError(f"max_leaf_size must be >= 1, got {max_leaf_size}")
    if n_bins < 2:
        raise ArgumentError(f"n_bins must be >= 2, got {n_bins}")
    max_leaf_cap = max(int(max_leaf_cap), max_leaf_size)
    ct = float(traversal_cost)
    ci = float(intersect_cost)
    if not (ct >= 0.0 and ci > 0.0):
        raise ArgumentError("traversal_cost must be >= 0 and intersect_cost > 0")

    _, tlo, thi = triangle_bounds(triangles)
    n_tri = tlo.shape[0]
    if n_tri > np.iinfo(np.int32).max // 2:
        raise ArgumentError(f"too many triangles for int32 node indices: {n_tri}")
    max_depth = max(int(max_depth), int(_levels_needed(np.array([n_tri]), max_leaf_size)[0]))

    # Working set, structure-of-arrays (3, n), in node order: each active node owns a
    # contiguous range [ws, ws + cnt).
    lo = np.ascontiguousarray(tlo.T)
    hi = np.ascontiguousarray(thi.T)
    cen = lo * np.float32(0.5)
    cen += hi * np.float32(0.5)
    ids = np.arange(n_tri, dtype=np.int32)

    max_nodes = 2 * n_tri - 1
    nb_lo = np.empty((max_nodes, 3), dtype=np.float32)
    nb_hi = np.empty((max_nodes, 3), dtype=np.float32)
    n_lf = np.empty(max_nodes, dtype=np.int32)
    n_cnt = np.empty(max_nodes, dtype=np.int32)
    tri_index = np.empty(n_tri, dtype=np.int32)

    nb_lo[0] = lo.min(axis=1)
    nb_hi[0] = hi.max(axis=1)
    next_id = 1
    if n_tri <= max_leaf_size:
        n_lf[0] = 0
        n_cnt[0] = n_tri
        tri_index[:] = ids
        return _finish(nb_lo, nb_hi, n_lf, n_cnt, 1, tri_index)

    # Active node table.
    a_id = np.zeros(1, dtype=np.int64)
    a_ws = np.zeros(1, dtype=np.int64)
    a_cnt = np.array([n_tri], dtype=np.int64)
    a_gs = np.zeros(1, dtype=np.int64)
    a_dep = np.zeros(1, dtype=np.int64)
    a_cmin = cen.min(axis=1)[None, :]
    a_cmax = cen.max(axis=1)[None, :]

    while a_id.size:
        k = a_id.size
        n = int(a_cnt.sum())
        seg = np.repeat(np.arange(k, dtype=np.int32), a_cnt)
        ext = (a_cmax - a_cmin).astype(np.float64)
        long_ax = np.argmax(ext, axis=1)
        node_area = _half_area(nb_lo[a_id], nb_hi[a_id])

        if method == "sah":
            # Fewer bins when the level's nodes are small: keeps the (node, bin) tables no
            # larger than the triangle arrays (a node with c triangles has at most c non-empty
            # bins anyway).
            nb = int(min(n_bins, max(4, n // k)))
            if axes == "all":
                candidates = [np.full(k, ax, dtype=np.int64) for ax in range(3)]
            else:
                candidates = [long_ax]
            best_cost = np.full(k, np.inf)
            best_bin = np.zeros(k, dtype=np.int64)
            best_box = None
            elem_bin = None
            for cand in candidates:
                b, cost, split, box = _bin_level(
                    lo, hi, cen, seg, a_cnt, a_cmin, ext, cand, node_area, nb, k, ct, ci
                )
                better = cost < best_cost
                if elem_bin is None:
                    elem_bin, best_box = b, box
                else:
                    elem_bin = np.where(np.repeat(better, a_cnt), b, elem_bin)
                    best_box = np.where(better, box, best_box)
                best_cost = np.where(better, cost, best_cost)
                best_bin = np.where(better, split, best_bin)
            leaf_cost = ci * a_cnt
            make_leaf = (best_cost >= leaf_cost) & (a_cnt <= max_leaf_cap)
            fallback = ~make_leaf & ~np.isfinite(best_cost)
        else:
            make_leaf = np.zeros(k, dtype=bool)
            fallback = np.ones(k, dtype=bool)
            best_bin = np.zeros(k, dtype=np.int64)
            best_box = None
            elem_bin = None

        # Depth guard: force balanced (object median) splits when close to max_depth.
        guard = ~make_leaf & (a_dep + _levels_needed(a_cnt, max_leaf_size) >= max_depth)
        fallback |= guard
        is_split = ~make_leaf

        # goes-left flag per element. Leaf nodes: everything "left" (keeps order).
        if elem_bin is not None:
            gl = elem_bin < np.repeat(best_bin.astype(np.int32), a_cnt)
            gl |= np.repeat(make_leaf, a_cnt)
        else:
            gl = np.ones(n, dtype=bool)
        if fallback.any():
            gl = _median_flags(cen, seg, a_ws, a_cnt, long_ax, fallback, gl)

        # Stable partition of every node range by gl (O(n) prefix sums).
        cs0 = np.zeros(n + 1, dtype=np.int32)
        np.cumsum(gl, out=cs0[1:])
        before = cs0[a_ws]
        nl = (cs0[a_ws + a_cnt] - before).astype(np.int64)
        # Left elements go to ws + (lefts before them in the node); right elements to
        # ws + nl + (rights before them) = ws + nl + local - lefts_before.
        lefts_incl = cs0[1:]
        lefts_incl -= np.repeat(before, a_cnt)  # lefts up to and including each element
        ws32 = a_ws.astype(np.int32)
        newpos = np.repeat(ws32 + nl.astype(np.int32), a_cnt)  # right: ws + nl + local - li
        newpos += np.arange(n, dtype=np.int32)
        newpos -= np.repeat(ws32, a_cnt)
        newpos -= lefts_incl
        left_pos = np.repeat(ws32 - 1, a_cnt)  # left: ws + li - 1
        left_pos += lefts_incl
        left_pos -= newpos
        left_pos *= gl
        newpos += left_pos  # branch-free select
        del left_pos, lefts_incl
        if not (nl[is_split] > 0).all() or not (nl[is_split] < a_cnt[is_split]).all():
            raise RuntimeError("internal error: empty child in BVH split")  # pragma: no cover

        # Groups: leaf nodes give one group (themselves), split nodes two (their children).
        ng = 1 + is_split.astype(np.int64)
        g_par = np.repeat(np.arange(k, dtype=np.int64), ng)
        gbase = np.cumsum(ng) - ng
        g_second = np.arange(g_par.size, dtype=np.int64) - gbase[g_par]
        p_split = is_split[g_par]
        g_cnt = np.where(
            g_second == 1, a_cnt[g_par] - nl[g_par], np.where(p_split, nl[g_par], a_cnt[g_par])
        )
        g_off = np.where(g_second == 1, nl[g_par], 0)
        g_ws = a_ws[g_par] + g_off
        g_gs = a_gs[g_par] + g_off

        # Leaf-terminated nodes.
        leaf_nodes = a_id[make_leaf]
        n_lf[leaf_nodes] = a_gs[make_leaf]
        n_cnt[leaf_nodes] = a_cnt[make_leaf]

        # Children of split nodes: adjacent ids, left then right.
        child_g = np.flatnonzero(p_split)
        n_child = child_g.size
        child_ids = np.full(g_par.size, -1, dtype=np.int64)
        child_ids[child_g] = next_id + np.arange(n_child, dtype=np.int64)
        sn = np.flatnonzero(is_split)
        n_lf[a_id[sn]] = next_id + 2 * np.arange(sn.size)
        n_cnt[a_id[sn]] = 0
        next_id += n_child

        # Child boxes: SAH splits take them exactly from the bin sweep; the (rare) median
        # splits gather them from their triangles.
        if sn.size:
            from_bins = ~fallback[sn] if best_box is not None else np.zeros(sn.size, bool)
            if from_bins.any():
                j = sn[from_bins]
                lid = child_ids[gbase[j]]
                nb_lo[lid] = best_box[0][:, j].T
                nb_hi[lid] = best_box[1][:, j].T
                nb_lo[lid + 1] = best_box[2][:, j].T
                nb_hi[lid + 1] = best_box[3][:, j].T
            if not from_bins.all():
                fb = sn[~from_bins]
                sel = _concat_ranges(a_ws[fb], a_cnt[fb])
                ckey = child_ids[gbase[seg[sel]]] + ~gl[sel]
                _box_at(nb_lo, nb_hi, ckey, lo[:, sel], hi[:, sel])

        # Groups that end here (leaf-terminated nodes and small children) leave the working
        # set; the rest are compacted in the same scatter that partitions them.
        g_drop = ~p_split | (g_cnt <= max_leaf_size)
        small_child = p_split & g_drop
        n_lf[child_ids[small_child]] = g_gs[small_child]
        n_cnt[child_ids[small_child]] = g_cnt[small_child]
        g_keep = np.where(g_drop, 0, g_cnt)
        g_new_ws = np.cumsum(g_keep) - g_keep
        n_keep = int(g_keep.sum())
        e_group = np.repeat(gbase.astype(np.int32), a_cnt)
        e_group += ~gl
        # Dropped elements land in a junk slot n_keep (overwritten, discarded).
        shift = np.where(g_drop, 0, g_new_ws - g_ws).astype(np.int32)
        dest = newpos + shift[e_group]
        e_drop = g_drop[e_group]
        np.copyto(dest, np.int32(n_keep), where=e_drop)
        di = np.flatnonzero(e_drop)
        if di.size:
            eg = e_group[di]
            tri_index[g_gs[eg] + (newpos[di] - g_ws[eg])] = ids[di]
        del newpos, e_drop, di, e_group
        if n_keep == 0:
            break

        ids2 = np.empty(n_keep + 1, dtype=np.int32)
        ids2[dest] = ids
        lo2 = np.empty((3, n_keep + 1), dtype=np.float32)
        hi2 = np.empty((3, n_keep + 1), dtype=np.float32)
        for d in range(3):  # row by row: faster than one 2-D fancy assignment
            lo2[d][dest] = lo[d]
            hi2[d][dest] = hi[d]
        del dest
        ids, lo, hi = ids2[:n_keep], lo2[:, :n_keep], hi2[:, :n_keep]
        cen = lo * np.float32(0.5)
        cen += hi * np.float32(0.5)

        act_g = np.flatnonzero(~g_drop)
        a_id = child_ids[act_g]
        a_cnt = g_cnt[act_g]
        a_ws = g_new_ws[act_g]
        a_gs = g_gs[act_g]
        a_dep = a_dep[g_par[act_g]] + 1
        a_cmin = np.minimum.reduceat(cen, a_ws, axis=1).T
        a_cmax = np.maximum.reduceat(cen, a_ws, axis=1).T

    return _finish(nb_lo, nb_hi, n_lf, n_cnt, next_id, tri_index)


def _bin_level(lo, hi, cen, seg, a_cnt, a_cmin, ext, ax, node_area, n_bins, k, ct, ci):
    """Bin every active node along axis ``ax`` (per node) and evaluate the SAH.

    Returns (per-element bin, per-node best cost, per-node best split bin s: left = bins < s,
    (4, 3, k) boxes of the left and right children at that split: lo_L, hi_L, lo_R, hi_R).
    """
    kk = np.arange(k)
    e = ext[kk, ax]
    with np.errstate(divide="ignore", over="ignore"):
        scale64 = np.where(e > 0, n_bins * (1.0 - 1e-6) / np.where(e > 0, e, 1.0), 0.0)
        scale = scale64.astype(np.float32)
    scale[~np.isfinite(scale)] = 0.0
    cmin_ax = a_cmin[kk, ax].astype(np.float32)
    if np.all(ax == ax[0]):
        c_t = cen[int(ax[0])]
    else:
        ax_t = np.repeat(ax, a_cnt)
        c_t = np.where(ax_t == 0, cen[0], np.where(ax_t == 1, cen[1], cen[2]))
    f = (c_t - np.repeat(cmin_ax, a_cnt)) * np.repeat(scale, a_cnt)
    b = f.astype(np.int32)
    np.minimum(b, n_bins - 1, out=b)
    np.maximum(b, 0, out=b)
    # Bin-major keys so the per-node sweeps below run along a leading axis of length n_bins
    # with contiguous rows of k nodes (fast cumulative min/max).
    key = b * np.int32(k)
    key += seg
    nk = k * n_bins
    cnt = np.bincount(key, minlength=nk).reshape(n_bins, k)
    blo = np.full((3, nk), np.inf, dtype=np.float32)
    bhi = np.full((3, nk), -np.inf, dtype=np.float32)
    for d in range(3):
        np.minimum.at(blo[d], key, lo[d])
        np.maximum.at(bhi[d], key, hi[d])
    blo = blo.reshape(3, n_bins, k)
    bhi = bhi.reshape(3, n_bins, k)
    # Prefix (left of boundary s = 1..n_bins-1) and suffix sweeps.
    l_lo = _sweep(np.minimum, blo[:, :-1])
    l_hi = _sweep(np.maximum, bhi[:, :-1])
    r_lo = _sweep(np.minimum, blo[:, :0:-1])[:, ::-1]
    r_hi = _sweep(np.maximum, bhi[:, :0:-1])[:, ::-1]
    n_l = _sweep(np.add, cnt[None, :-1])[0]
    n_r = a_cnt[None, :] - n_l
    with np.errstate(invalid="ignore", over="ignore"):
        a_l = _half_area_soa(l_lo, l_hi)
        a_r = _half_area_soa(r_lo, r_hi)
        valid = (n_l > 0) & (n_r > 0)
        inv_area = (ci / np.where(node_area > 0, node_area, 1.0)).astype(np.float32)
        cost = (a_l * n_l + a_r * n_r) * inv_area[None, :] + np.float32(ct)
    cost[~valid] = np.inf
    split = np.argmin(cost, axis=0)
    best = cost[split, kk].astype(np.float64)
    box = np.stack([l_lo[:, split, kk], l_hi[:, split, kk], r_lo[:, split, kk], r_hi[:, split, kk]])
    return b, best, split + 1, box


def _box_at(nb_lo, nb_hi, key, lo, hi) -> None:
    """Set nb_lo[key] / nb_hi[key] to the exact box of the elements (lo, hi: (3, m))."""
    u, inv = np.unique(key, return_inverse=True)
    m_lo = np.full((3, u.size), np.inf, dtype=np.float32)
    m_hi = np.full((3, u.size), -np.inf, dtype=np.float32)
    for d in range(3):
        np.minimum.at(m_lo[d], inv, lo[d])
        np.maximum.at(m_hi[d], inv, hi[d])
    nb_lo[u] = m_lo.T
    nb_hi[u] = m_hi.T


def _sweep(ufunc, a: np.ndarray) -> np.ndarray:
    """Cumulative ``ufunc`` along axis 1 of a (c, n_bins, k) array, one vector op per bin.

    (``ufunc.accumulate`` along a short middle axis runs a tiny inner loop per node and is
    several times slower here.)
    """
    out = np.empty(a.shape, dtype=a.dtype)
    out[:, 0] = a[:, 0]
    for j in range(1, a.shape[1]):
        ufunc(out[:, j - 1], a[:, j], out=out[:, j])
    return out


def _median_flags(cen, seg, a_ws, a_cnt, long_ax, fallback, gl):
    """Set gl for fallback nodes: first half (by centroid along the longest axis, stable) left."""
    fb_nodes = np.flatnonzero(fallback)
    sel = _concat_ranges(a_ws[fb_nodes], a_cnt[fb_nodes])
    sseg = seg[sel]
    ax = long_ax[sseg]
    c = cen[ax, sel]
    order = np.lexsort((c, sseg))  # stable; sel is already sorted by seg
    rank = np.empty(sel.size, dtype=np.int64)
    rank[order] = np.arange(sel.size, dtype=np.int64)
    sub_start = np.cumsum(a_cnt[fb_nodes]) - a_cnt[fb_nodes]
    node_pos = np.empty(a_cnt.size, dtype=np.int64)
    node_pos[fb_nodes] = np.arange(fb_nodes.size)
    local = rank - sub_start[node_pos[sseg]]
    gl = gl.copy()
    gl[sel] = local < (a_cnt[sseg] // 2)
    return gl


def _concat_ranges(starts: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Concatenation of ``arange(s, s + c)`` for each (s, c), vectorised."""
    total = int(counts.sum())
    offs = np.cumsum(counts) - counts
    return np.repeat(starts - offs, counts) + np.arange(total, dtype=np.int64)


def _finish(nb_lo, nb_hi, n_lf, n_cnt, m, tri_index) -> Bvh:
    nodes = np.empty(m, dtype=BVH_NODE_DTYPE)
    nodes["bmin"] = nb_lo[:m]
    nodes["bmax"] = nb_hi[:m]
    nodes["left_first"] = n_lf[:m]
    nodes["count"] = n_cnt[:m]
    return Bvh(nodes=nodes, tri_index=tri_index)


def validate_bvh(bvh: Bvh, triangles: np.ndarray) -> None:
    """Check every layout invariant of ``bvh`` against ``triangles``; raise on the first failure.

    Checks: dtypes and contiguity; ``tri_index`` is a permutation of ``range(T)``; every node is
    reached exactly once from the root (no cycles, no sharing, no orphans); inner nodes have
    ``count == 0`` and in-range adjacent children; leaves have ``count > 0`` and in-range
    triangle ranges which together cover every slot exactly once; boxes are finite with
    ``bmin <= bmax``; every inner box contains its children's boxes and every leaf box contains
    the float32 boxes of its triangles.

    Raises
    ------
    BvhValidationError
        (a ValueError) naming the broken invariant and an offending node.
    """
    _, tlo, thi = triangle_bounds(triangles)
    n_tri = tlo.shape[0]
    nodes = bvh.nodes
    ti = bvh.tri_index

    def fail(msg: str) -> None:
        raise BvhValidationError(msg)

    if not isinstance(nodes, np.ndarray) or nodes.dtype != BVH_NODE_DTYPE:
        fail(f"nodes must be a numpy array of BVH_NODE_DTYPE, got {getattr(nodes, 'dtype', None)}")
    if nodes.ndim != 1 or nodes.shape[0] < 1 or not nodes.flags.c_contiguous:
        fail("nodes must be a non-empty, 1-D, C-contiguous array")
    if not isinstance(ti, np.ndarray) or ti.dtype != np.int32 or ti.ndim != 1:
        fail("tri_index must be a 1-D int32 array")
    if not ti.flags.c_contiguous:
        fail("tri_index must be C-contiguous")
    if ti.shape[0] != n_tri:
        fail(f"tri_index has {ti.shape[0]} entries but there are {n_tri} triangles")
    if ti.size and (ti.min() < 0 or ti.max() >= n_tri):
        fail("tri_index has out-of-range triangle ids")
    if np.bincount(ti, minlength=n_tri).max(initial=0) != 1:
        fail("tri_index is not a permutation: some triangle appears more than once")

    m = nodes.shape[0]
    cnt = nodes["count"].astype(np.int64)
    lf = nodes["left_first"].astype(np.int64)
    blo = nodes["bmin"]
    bhi = nodes["bmax"]
    if (cnt < 0).any():
        fail(f"negative count at node {int(np.flatnonzero(cnt < 0)[0])}")
    if not (np.isfinite(blo).all() and np.isfinite(bhi).all()):
        fail("non-finite node bounds")
    if (blo > bhi).any():
        fail(f"bmin > bmax at node {int(np.flatnonzero((blo > bhi).any(axis=1))[0])}")
    inner = cnt == 0
    bad = inner & ((lf < 1) | (lf + 1 >= m))
    if bad.any():
        fail(f"inner node {int(np.flatnonzero(bad)[0])} has out-of-range children {lf[bad][0]}")
    leaf = ~inner
    bad = leaf & ((lf < 0) | (lf + cnt > n_tri))
    if bad.any():
        fail(f"leaf {int(np.flatnonzero(bad)[0])} has an out-of-range triangle range")

    # Reachability: every node exactly once (no cycles or sharing), none orphaned.
    seen = np.zeros(m, dtype=np.int64)
    frontier = np.array([0], dtype=np.int64)
    steps = 0
    while frontier.size:
        np.add.at(seen, frontier, 1)
        if seen[frontier].max() > 1:
            fail(
                f"node {int(frontier[seen[frontier] > 1][0])} is reached more than once (cycle "
                "or shared subtree)"
            )
        steps += 1
        if steps > m + 1:
            fail("cycle in the node graph")  # pragma: no cover
        fi = frontier[inner[frontier]]
        frontier = np.concatenate([lf[fi], lf[fi] + 1])
    if (seen == 0).any():
        fail(f"node {int(np.flatnonzero(seen == 0)[0])} is not reachable from the root")

    # Leaf ranges cover each slot exactly once.
    cover = np.zeros(n_tri + 1, dtype=np.int64)
    np.add.at(cover, lf[leaf], 1)
    np.add.at(cover, lf[leaf] + cnt[leaf], -1)
    cover = np.cumsum(cover)[:n_tri]
    if (cover != 1).any():
        fail(
            f"leaf ranges do not cover triangle slot {int(np.flatnonzero(cover != 1)[0])} "
            "exactly once"
        )

    # Containment.
    ii = np.flatnonzero(inner)
    for c in (lf[ii], lf[ii] + 1):
        ok = (blo[c] >= blo[ii]).all(axis=1) & (bhi[c] <= bhi[ii]).all(axis=1)
        if not ok.all():
            j = int(np.flatnonzero(~ok)[0])
            fail(f"child {int(c[j])} box is not inside its parent {int(ii[j])}")
    li = np.flatnonzero(leaf)
    owner = np.repeat(li, cnt[li])
    slots = _concat_ranges(lf[li], cnt[li])
    tri = ti[slots]
    ok = (tlo[tri] >= blo[owner]).all(axis=1) & (thi[tri] <= bhi[owner]).all(axis=1)
    if not ok.all():
        j = int(np.flatnonzero(~ok)[0])
        fail(f"triangle {int(tri[j])} is not inside its leaf {int(owner[j])}")
    # Node count sanity (a binary tree with L leaves has 2L - 1 nodes).
    if m != 2 * li.size - 1:
        fail(f"{m} nodes for {li.size} leaves; a binary tree needs {2 * li.size - 1}")
