"""The kernels' traversal layout of a binary BVH: 8-wide records and Tri4 leaf groups.

Plain numpy, no OpenCL: :mod:`clradcom.device.raycast` uploads what these
functions return. The numbers below are the kernels' only source: the device
layer passes them to every kernel build as ``-D NAME=value``, and
``kernels/layout.cl`` reports them back so a test can compare (docs/bvh.md).
"""

from __future__ import annotations

import numpy as np

from clradcom.errors import ArgumentError

#: Children per traversal record: the kernels test a record's boxes as one float8.
BVH_WIDTH = 8
#: The deepest traversal stack a kernel is built with; :func:`bvh8_nodes` refuses a tree
#: that needs more. Builds for a caster use the smallest of :data:`STACK_SIZES` that holds
#: its tree's need (:func:`stack_need`), so private memory stays small (registers on a GPU).
BVH_STACK_SIZE = 192
#: The stack sizes kernels are built with: tinybvh-class short stacks for every ordinary
#: tree (the street's need is 48), deeper builds only for trees that need them.
STACK_SIZES = (32, 64, 128, BVH_STACK_SIZE)
#: float4 rows of a Tri4 group: coordinate k of vertex j of its four triangles in row 3 j + k.
TRI4_ROWS = 9
#: A leaf child code packs its group count into this many low bits beside its first group.
LEAF_GROUP_BITS = 5
MAX_LEAF_GROUPS = (1 << LEAF_GROUP_BITS) - 1

BVH8_NODE_DTYPE = np.dtype(
    [("minx", "<f4", (BVH_WIDTH,)), ("miny", "<f4", (BVH_WIDTH,)), ("minz", "<f4", (BVH_WIDTH,)),
     ("maxx", "<f4", (BVH_WIDTH,)), ("maxy", "<f4", (BVH_WIDTH,)), ("maxz", "<f4", (BVH_WIDTH,)),
     ("child", "<i4", (BVH_WIDTH,)), ("pad", "<i4", (BVH_WIDTH,))]
)
"""numpy mirror of ``Bvh8Node`` (kernels/types.h): 256 bytes, see :func:`bvh8_nodes`."""


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


def stack_need(records: np.ndarray) -> int:
    """The most traversal stack entries any walk of the 8-wide ``records`` (every tree in
    them: a two-level buffer's top-level tree and each bottom-level tree) holds at once.

    A record with k children met pushes at most k - 1 of them before going on into one
    (the closest-hit walk pushes all k and pops the nearest at once, hence the kernels'
    one spare entry), so a record needs k - 1 plus the most any of its inner children
    needs; leaves need nothing. Evaluated by sweeping that recurrence over all records
    until it settles (as many sweeps as the trees are deep)."""
    child = np.asarray(records["child"]).astype(np.int64)
    used = child != 0
    k_minus_1 = np.maximum(used.sum(axis=1) - 1, 0)
    inner = child > 0
    target = np.where(inner, child, 0)
    need = k_minus_1.copy()
    for _ in range(len(records) + 1):
        below = np.where(inner, need[target], 0).max(axis=1, initial=0)
        new = k_minus_1 + below
        if np.array_equal(new, need):
            return int(need.max(initial=0))
        need = new
    raise ArgumentError("the BVH records hold a cycle")  # pragma: no cover


def stack_size_for(need: int) -> int:
    """The stack a kernel is built with for a tree needing ``need`` entries: the smallest
    of :data:`STACK_SIZES` that holds it."""
    for size in STACK_SIZES:
        if need <= size:
            return size
    raise ArgumentError(f"BVH needs a traversal stack of {int(need)} entries; the kernels "
                        f"hold at most {BVH_STACK_SIZE}", argument="bvh", value=int(need))


def bvh8_nodes(nodes: np.ndarray, leaf_first=None, leaf_count=None) -> np.ndarray:
    """8-wide traversal layout (BVH8_NODE_DTYPE) from a builder's BVH_NODE_DTYPE array.

    Each binary inner node that starts a record gets its two children, and
    then, while it has fewer than eight, the inner child with the largest
    surface area is replaced by its own two children (the usual greedy
    collapse). Records are numbered depth first (a record's first inner child
    follows it), record 0 is the root. Child codes are a record index (> 0), a
    leaf ``-(first << LEAF_GROUP_BITS | count) - 1`` with ``first``/``count`` from
    ``leaf_first``/``leaf_count`` (per binary node; default: the node's own
    ``left_first``/``count``), or 0 for an empty slot, whose bounds are
    +inf / -inf. A tree that is one leaf gets one record holding that leaf.
    Raises ValueError if a leaf count exceeds MAX_LEAF_GROUPS or the tree needs a deeper
    traversal stack than the kernels have.
    """
    nodes = np.asarray(nodes)
    counts = nodes["count"].astype(np.int64)
    left = nodes["left_first"].astype(np.int64)
    leaf_first = left if leaf_first is None else np.asarray(leaf_first, dtype=np.int64)
    leaf_count = counts if leaf_count is None else np.asarray(leaf_count, dtype=np.int64)
    if leaf_count[counts > 0].max(initial=0) > MAX_LEAF_GROUPS:
        raise ArgumentError(f"a BVH leaf holds {int(leaf_count.max())} triangle groups; at most "
                         f"{MAX_LEAF_GROUPS} are supported")
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
    leaf_code = -((leaf_first[slot] << LEAF_GROUP_BITS) + leaf_count[slot]) - 1
    if leaf_code.min(initial=0) < np.iinfo(np.int32).min:
        raise ArgumentError("too many leaf slots for the 8-wide leaf codes")
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
        raise ArgumentError(f"BVH needs a traversal stack of {int(need[0])} entries; the kernels "
                         f"hold {BVH_STACK_SIZE} (build it with a smaller max_depth)")
    return out
