"""Two-level BVH layout: bottom-level trees built once per rigid part, a top-level tree
over their placed instances rebuilt per time step (docs/bvh.md, "Two levels").

Plain numpy, no OpenCL: :class:`clradcom.device.raycast.InstancedCaster` uploads what
these functions return into the same three buffers a single-level caster has
(``nodes``, ``tri4``, ``slot_prim``), and builds its kernels with ``-D BVH_INSTANCED``
(``kernels/intersect.h``). The ``nodes`` buffer then holds, in records of 256 bytes:

* the *head*, rewritten every step: ``tlas_capacity(N)`` top-level records (record 0 the
  root; unused ones empty), then ``N`` :data:`INSTANCE_DTYPE` records. Record 0's
  ``pad[0]`` is the first instance record, ``pad[1]`` the number of instances; a
  top-level leaf is one instance, coded ``LEAF_CODE(instance, 1)``;
* the bottom-level trees, one after the other, built once: their record indices and
  Tri4 group indices shifted to where they lie in the concatenated buffers.

``slot_prim`` keeps scene triangle ids, so every kernel reports the same ``prim`` in
either layout. As in Embree's and OptiX's instancing, a transform is rigid here
(``world = R local + p``, R a rotation), so a hit's t is the same in both frames.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from clradcom.errors import ArgumentError
from clradcom.geometry.bvh import build_bvh
from clradcom.geometry.layout import (
    BVH8_NODE_DTYPE,
    BVH_WIDTH,
    LEAF_GROUP_BITS,
    bvh8_nodes,
    tri4_groups,
)

__all__ = ["INSTANCE_DTYPE", "Blas", "TwoLevel", "build_blas", "instance_boxes", "refit",
           "step_head", "tlas_capacity", "tlas_nodes", "two_level", "world_tri4"]

INSTANCE_DTYPE = np.dtype(
    [("world_to_local", "<f4", (9,)), ("origin", "<f4", (3,)), ("local_to_world", "<f4", (9,)),
     ("root", "<i4"), ("identity", "<i4"), ("first_group", "<i4"), ("end_group", "<i4"),
     ("pad", "<i4", (39,))]
)
"""numpy mirror of ``Bvh8Instance`` (kernels/types.h): 256 bytes, one record's room."""
assert INSTANCE_DTYPE.itemsize == BVH8_NODE_DTYPE.itemsize

#: Top-level boxes are widened by this many float32 roundoffs of the scene's extent: the
#: kernels take a ray into an instance's frame in float32, so a hit found there lies
#: within a few roundoffs (of |origin| and of t) of the world ray the box test sees.
BOX_PAD_ROUNDOFFS = 64


@dataclass(frozen=True)
class Blas:
    """One bottom-level BVH in its own frame: 8-wide records (root first), Tri4 groups,
    and the scene id of every leaf slot."""

    nodes: np.ndarray      # (R,) BVH8_NODE_DTYPE, record 0 the root
    tri4: np.ndarray       # (G, 9, 4) float32
    slot_prim: np.ndarray  # (4 G,) int32 scene triangle ids


def build_blas(triangles, ids) -> Blas:
    """The bottom-level tree of ``triangles`` ((T, 3, 3), in their own frame) whose scene
    ids are ``ids`` (T,): SAH over all three axes, as the single-level caster builds."""
    triangles = np.asarray(triangles, dtype=np.float64)
    ids = np.asarray(ids, dtype=np.int64)
    if triangles.ndim != 3 or triangles.shape[1:] != (3, 3) or len(triangles) == 0:
        raise ArgumentError("must have shape (T, 3, 3) with T > 0", argument="triangles",
                            value=triangles.shape)
    if ids.shape != (len(triangles),):
        raise ArgumentError(f"needs one id per triangle ({len(triangles)})", argument="ids",
                            value=ids.shape)
    bvh = build_bvh(triangles, axes="all")
    tri4, slot_local, leaf_first, leaf_groups = tri4_groups(bvh, triangles)
    nodes = bvh8_nodes(bvh.nodes, leaf_first, leaf_groups)
    return Blas(nodes=nodes, tri4=tri4,
                slot_prim=np.ascontiguousarray(ids[slot_local], dtype=np.int32))


def tlas_capacity(n_instances: int) -> int:
    """Records reserved for the top-level tree of ``n_instances`` leaves: a binary tree
    over N leaves has N - 1 inner nodes, and each 8-wide record starts at one of them."""
    return max(1, int(n_instances))


def _shift_codes(child: np.ndarray, record_base: int, group_base: int) -> np.ndarray:
    """Child codes of a tree moved to start at ``record_base`` with its Tri4 groups at
    ``group_base``: records > 0 shift, leaves re-pack their first group, 0 stays."""
    c = child.astype(np.int64)
    packed = -c - 1
    leaf = ((packed >> LEAF_GROUP_BITS) + group_base << LEAF_GROUP_BITS) + (
        packed & ((1 << LEAF_GROUP_BITS) - 1))
    out = np.where(c > 0, c + record_base, np.where(c < 0, -leaf - 1, 0))
    if out.min(initial=0) < np.iinfo(np.int32).min:
        raise ArgumentError("too many Tri4 groups for the 8-wide leaf codes",
                            argument="triangles", value=int(group_base))
    return out.astype(np.int32)


@dataclass(frozen=True)
class TwoLevel:
    """Bottom-level trees concatenated behind a head of ``head_records`` records."""

    nodes: np.ndarray        # (head_records + sum R,) BVH8_NODE_DTYPE; the head is zero
    tri4: np.ndarray         # (sum G, 9, 4) float32
    slot_prim: np.ndarray    # (4 sum G,) int32
    roots: np.ndarray        # (N,) int32 record of each instance's root
    group_range: np.ndarray  # (N, 2) int32 [first, end) Tri4 groups of each instance
    head_records: int        # top-level capacity + N instance records
    n_records: np.ndarray    # (N,) int64 records of each instance's tree

    @property
    def n_instances(self) -> int:
        return len(self.roots)


def two_level(blases: list[Blas]) -> TwoLevel:
    """One instance per bottom-level tree, in order: the buffers the kernels read."""
    if not blases:
        raise ArgumentError("needs at least one bottom-level tree", argument="blases",
                            value=0)
    n = len(blases)
    head = tlas_capacity(n) + n
    rec_base = head + np.cumsum([0] + [len(b.nodes) for b in blases])
    grp_base = np.cumsum([0] + [len(b.tri4) for b in blases])
    nodes = np.zeros(int(rec_base[-1]), dtype=BVH8_NODE_DTYPE)
    for b, r0, g0 in zip(blases, rec_base, grp_base, strict=False):
        part = b.nodes.copy()
        part["child"] = _shift_codes(b.nodes["child"], int(r0), int(g0))
        nodes[int(r0):int(r0) + len(part)] = part
    return TwoLevel(
        nodes=nodes,
        tri4=np.ascontiguousarray(np.concatenate([b.tri4 for b in blases])),
        slot_prim=np.ascontiguousarray(np.concatenate([b.slot_prim for b in blases])),
        roots=rec_base[:-1].astype(np.int32),
        group_range=np.column_stack([grp_base[:-1], grp_base[1:]]).astype(np.int32),
        head_records=head, n_records=np.diff(rec_base).astype(np.int64))


def instance_boxes(lo, hi, extent: float) -> tuple[np.ndarray, np.ndarray]:
    """float32 boxes holding the float64 world boxes ``lo``, ``hi`` (N, 3), widened by
    :data:`BOX_PAD_ROUNDOFFS` float32 roundoffs of ``extent`` (the largest |coordinate|
    a ray or triangle has) and rounded outward."""
    pad = BOX_PAD_ROUNDOFFS * 0.5 * float(np.finfo(np.float32).eps) * (float(extent) + 1.0)
    lo32 = np.nextafter((np.asarray(lo, np.float64) - pad).astype(np.float32),
                        np.float32(-np.inf))
    hi32 = np.nextafter((np.asarray(hi, np.float64) + pad).astype(np.float32),
                        np.float32(np.inf))
    return lo32, hi32


def tlas_nodes(lo32, hi32) -> np.ndarray:
    """8-wide top-level records over N instance boxes (float32 (N, 3) corners): a binary
    SAH tree with one instance per leaf, collapsed like any bottom-level tree; a leaf's
    code holds its instance as ``LEAF_CODE(instance, 1)``. Up to eight instances are
    one record, no tree built."""
    lo32 = np.asarray(lo32, np.float32)
    hi32 = np.asarray(hi32, np.float32)
    n = len(lo32)
    if n <= BVH_WIDTH:
        rec = np.zeros(1, dtype=BVH8_NODE_DTYPE)
        for k, name in enumerate(("minx", "miny", "minz")):
            rec[name][0] = np.inf
            rec[name][0, :n] = lo32[:, k]
        for k, name in enumerate(("maxx", "maxy", "maxz")):
            rec[name][0] = -np.inf
            rec[name][0, :n] = hi32[:, k]
        rec["child"][0, :n] = -((np.arange(n) << LEAF_GROUP_BITS) + 1) - 1
        return rec
    # a box as a triangle with that box: two corners and the centre (the SAH centroid)
    mid = (lo32.astype(np.float64) + hi32) * 0.5
    boxes = np.stack([lo32.astype(np.float64), hi32.astype(np.float64), mid], axis=1)
    bvh = build_bvh(boxes, max_leaf_size=1, max_leaf_cap=1, axes="all")
    leaf = bvh.nodes["count"] > 0
    leaf_first = np.where(leaf, np.asarray(bvh.tri_index)[
        np.where(leaf, bvh.nodes["left_first"], 0)], 0).astype(np.int64)
    records = bvh8_nodes(bvh.nodes, leaf_first, leaf.astype(np.int64))
    if len(records) > tlas_capacity(n):
        raise ArgumentError(f"the top-level tree needs {len(records)} records, more than "
                            f"the {tlas_capacity(n)} reserved", argument="instances", value=n)
    return records


def step_head(tlas: np.ndarray, n_instances: int, rotations, origins, roots, group_range,
                 identity) -> np.ndarray:
    """The ``nodes`` buffer's head for one step: the top-level records (padded with empty
    ones to the capacity) and one :data:`INSTANCE_DTYPE` record per instance
    (``rotations`` (N, 3, 3) R, ``origins`` (N, 3) p: world = R local + p)."""
    cap = tlas_capacity(n_instances)
    head = np.zeros(cap + n_instances, dtype=BVH8_NODE_DTYPE)
    for name in ("minx", "miny", "minz"):
        head[name][:cap] = np.inf
    for name in ("maxx", "maxy", "maxz"):
        head[name][:cap] = -np.inf
    head[:len(tlas)] = tlas
    head["pad"][0, 0] = cap
    head["pad"][0, 1] = n_instances
    inst = np.zeros(n_instances, dtype=INSTANCE_DTYPE)
    rot = np.asarray(rotations, np.float64)
    inst["world_to_local"] = rot.transpose(0, 2, 1).reshape(-1, 9)
    inst["local_to_world"] = rot.reshape(-1, 9)
    inst["origin"] = origins
    inst["root"] = roots
    inst["identity"] = np.asarray(identity, bool)
    inst["first_group"] = np.asarray(group_range)[:, 0]
    inst["end_group"] = np.asarray(group_range)[:, 1]
    head[cap:] = inst.view(BVH8_NODE_DTYPE)
    return head


def world_tri4(triangles, slot_prim) -> np.ndarray:
    """Tri4 groups (G, 9, 4) float32 of the scene ``triangles`` (T, 3, 3) that the leaf
    slots ``slot_prim`` (4 G,) name: a tree's groups with its triangles moved, in the
    layout of :func:`~clradcom.geometry.layout.tri4_groups`."""
    prim = np.asarray(slot_prim, dtype=np.int64).reshape(-1, 4)
    verts = np.asarray(triangles)[prim].astype(np.float32)         # (G, lane, vertex, xyz)
    return np.ascontiguousarray(verts.transpose(0, 2, 3, 1).reshape(len(prim), 9, 4))


def refit(records: np.ndarray, tri4: np.ndarray, record_base: int,
          group_base: int) -> np.ndarray:
    """The 8-wide ``records`` of one tree (child codes as they lie in the concatenated
    buffers: records from ``record_base``, groups from ``group_base``) with every child
    box recomputed bottom up from its Tri4 groups ``tri4`` (the tree's own, moved): the
    same topology, boxes the exact float32 bounds of the moved triangles (Embree's
    refit; a rigid motion keeps the tree valid, its boxes grow by up to sqrt(3) where a
    part turns)."""
    out = records.copy()
    child = records["child"].astype(np.int64)
    lo_g = np.stack([tri4[:, [k, 3 + k, 6 + k], :].min(axis=(1, 2)) for k in range(3)], 1)
    hi_g = np.stack([tri4[:, [k, 3 + k, 6 + k], :].max(axis=(1, 2)) for k in range(3)], 1)
    leaf = child < 0
    packed = -child[leaf] - 1
    first = (packed >> LEAF_GROUP_BITS) - group_base
    count = packed & ((1 << LEAF_GROUP_BITS) - 1)
    # a leaf's groups are consecutive: reduce over [first, first + count)
    g = np.repeat(np.arange(len(first)), count)
    gi = np.repeat(first - np.cumsum(count) + count, count) + np.arange(int(count.sum()))
    lo_leaf = np.full((len(first), 3), np.inf, np.float32)
    hi_leaf = np.full((len(first), 3), -np.inf, np.float32)
    np.minimum.at(lo_leaf, g, lo_g[gi])
    np.maximum.at(hi_leaf, g, hi_g[gi])
    names_lo, names_hi = ("minx", "miny", "minz"), ("maxx", "maxy", "maxz")
    for k in range(3):
        out[names_lo[k]][leaf] = lo_leaf[:, k]
        out[names_hi[k]][leaf] = hi_leaf[:, k]
    inner = child > 0
    sub = np.where(inner, child - record_base, 0)
    for _ in range(len(records)):   # children follow their parent: depth passes settle it
        rec_lo = [out[n].min(axis=1) for n in names_lo]
        rec_hi = [out[n].max(axis=1) for n in names_hi]
        changed = False
        for k in range(3):
            new_lo = np.where(inner, rec_lo[k][sub], out[names_lo[k]])
            new_hi = np.where(inner, rec_hi[k][sub], out[names_hi[k]])
            changed |= not (np.array_equal(new_lo, out[names_lo[k]])
                            and np.array_equal(new_hi, out[names_hi[k]]))
            out[names_lo[k]], out[names_hi[k]] = new_lo, new_hi
        if not changed:
            break
    return out
