"""Visibility for every mechanism: float32 casts on the device, re-decided in float64
where their rounding could flip a path on or off.

The caster answers in float32, whose resolution is tens of micrometres 1 km from the
origin. Where a segment ends on a face's rim or passes an edge closer than that, the
float32 answer may disagree with the float64 geometry the fields are computed from
(the UTD terms of that rim or edge): the total field would then jump. So:

* :func:`reaches_face` - a segment toward a reflection point must first meet that
  face there; whether the point lies inside the face is decided in float64
  (:func:`containing_triangles`);
* :func:`segments_clear` - nothing may block a segment; a float32 "blocked" is
  re-decided in float64 (:func:`blocked_in_float64`);
* :func:`antenna_blocked` - the last millimetre of a segment at an antenna, where the
  casts stop short (so an antenna on a wall is not blocked by that wall), decided
  wholly in float64: a face strictly between blocks, a face through the antenna does
  not;
* :func:`confirm_paths` - all three along a chain of reflection points;
* :func:`surface_sees` - a point on a surface (a facet, a tile, a ray-tube hit) sees
  a target, the surface's own triangle ignored.

Two engines give the same decisions.  ``engine="device"`` (the default) answers a whole
batch of segments in one launch of ``kernels/visibility.cl``: the float32 cast and the
float64 re-decision of every float32 "blocked" (or the float64 "is the end inside its
face") in the same work item, by the same rules and in the same operation order as the
numpy functions here -- in double where the device has fp64 (the host's decisions bit for
bit), else in double-float (``kernels/precise.h``; the host's decisions except within
~1e-13 (1 + |p|) m of a threshold, docs/precision.md).  ``engine="host"`` is that numpy
reference: float32 casts, then float64 rounds on the host (:func:`blocked_in_float64`,
:func:`containing_triangles`).  Each call notes which engine decided
(:func:`clradcom.device.engines.record`, stages "visibility.segments" and
"visibility.surface_sight").  The float64 millimetre at an antenna
(:func:`antenna_blocked`) is decided on the host for both: a few triangles within
millimetres of the antenna, by design not a fallback.
"""

from __future__ import annotations

import functools
import weakref

import numpy as np

from clradcom.device import engines
from clradcom.device.precision import kernel_float64, kernel_scalar64
from clradcom.device.raycast import RayCaster, make_rays, spawn_origins
from clradcom.errors import ArgumentError
from clradcom.geometry.rows import row_counts
from clradcom.geometry.triangles import triangle_cross_products, triangle_normals

#: Where the visibility decisions are made: "device" (kernels/visibility.cl, float64 on
#: the device) or "host" (numpy over float32 casts: the reference).  The same names as
#: clradcom.mechanisms.common.ENGINES, which passes its Geometry.engine here.
ENGINES = ("device", "host")

#: A segment counts as reaching its reflection point when the first thing it
#: meets is that face within this many metres (plus float32 resolution).
CONFIRM_TOL_M = 1e-3
#: A point counts as inside a triangle when it lies at most this far outside an edge that
#: the triangle shares with another triangle of its face (a seam), relative to 1 + its
#: largest coordinate (float64 rounding), so a seam has no gap.  Outside a rim edge of
#: the face (one no other triangle of the face shares) nothing counts as inside: the
#: rim is decided exactly, as UTD decides its edge's boundaries.
INSIDE_TOL_REL = 1e-9
#: A sight line from a surface point stops this fraction of its length short of its
#: target, so the target's own surface (an antenna on a wall) does not block it.
SIGHT_STOP = 1e-7
#: An antenna this close to a face's plane, relative to 1 + its largest coordinate, lies
#: on that face: the face never blocks the antenna's own segments (an antenna on a wall or
#: on the road sees both sides).  Any farther behind a face, the face blocks.  About 500
#: float64 roundoffs: what rounding leaves of the plane distance of a point that is on the
#: plane, not a length of the scene.
ON_FACE_TOL_REL = 1e-13
#: A float32 "blocked" whose blocker's face misses the float64 crossing is looked past
#: for at most this many blockers; still undecided, it stays blocked.
RESCUE_ROUNDS = 4
#: Looking past a blocker, the next cast starts at this fraction of the blocker's float32
#: distance (so a blocker just behind it is not skipped).
LOOK_PAST = 1.0 - 1e-6


def confirm_margin_m(end) -> np.ndarray:
    """(S,) metres within which a segment counts as reaching ``end`` (S,3):
    CONFIRM_TOL_M plus the float32 resolution at ``end``."""
    return CONFIRM_TOL_M + 1e-6 * np.abs(end).max(axis=1)


def confirm_slack(end, length) -> np.ndarray:
    """:func:`confirm_margin_m` as a fraction of segments of ``length`` (m)."""
    return confirm_margin_m(end) / np.maximum(length, 1e-12)


def antenna_slack(antenna, length) -> np.ndarray:
    """The fraction of segments of ``length`` (m) leaving ``antenna`` that their casts
    leave to :func:`antenna_blocked`: :func:`confirm_slack`, but at most half the segment,
    so a segment shorter than two margins still has its far half cast (where a
    reflection point's face must be met)."""
    return np.minimum(confirm_slack(antenna, length), 0.5)


def antenna_blocked(caster: RayCaster, tri_face, antennas, others, radius) -> np.ndarray:
    """(S,) bool: a face crosses the segment antennas[s] -> others[s] strictly between its
    ends, within ``radius`` (m, scalar or (S,)) of the antenna; all in float64.

    The casts that confirm a segment stop :func:`confirm_margin_m` short of an antenna
    (and start as far from one), so that an antenna on a wall is not blocked by that
    wall; this decides the part they leave out.  A face blocks when the antenna lies
    farther than ON_FACE_TOL_REL x (1 + |antenna|) from its plane, on the other side
    from ``others[s]`` (which must not lie on that plane either: the segment's own
    reflection point), and the crossing lies inside the face
    (:func:`containing_triangles`).  So an antenna behind a face is blocked however close
    it is, from either end of the link, and one exactly on a face is not.
    """
    triangles = caster.triangles
    antennas = np.asarray(antennas, dtype=np.float64)
    others = np.asarray(others, dtype=np.float64)
    S = len(others)
    antennas = np.broadcast_to(antennas, (S, 3))
    radius = np.broadcast_to(np.asarray(radius, dtype=np.float64), (S,))
    out = np.zeros(S, dtype=bool)
    if S == 0 or len(triangles) == 0:
        return out
    tri_face = np.asarray(tri_face)
    lo, hi = caster.triangle_bounds()
    if np.all(antennas == antennas[0]):  # the usual case: one antenna for all segments
        groups = [(antennas[0], np.arange(S))]
    else:
        ants, which = np.unique(antennas, axis=0, return_inverse=True)
        which = which.reshape(-1)
        groups = [(ant, np.flatnonzero(which == i)) for i, ant in enumerate(ants)]
    for ant, rows in groups:
        near = antenna_near_triangles(caster, ant, radius[rows].max())
        if len(near) == 0:
            continue
        tri = triangles[near]
        n = caster.normals64()[near]
        d_ant = np.einsum("ij,ij->i", n, ant - tri[:, 0])  # (N,)
        other = others[rows]
        d_other = (other @ n.T) - np.einsum("ij,ij->i", n, tri[:, 0])[None, :]  # (R, N)
        on_other = np.abs(d_other) <= ON_FACE_TOL_REL * (1.0 + np.abs(other).max(axis=1))[:, None]
        cross = (d_ant[None, :] * d_other < 0) & ~on_other
        with np.errstate(divide="ignore", invalid="ignore"):
            t = d_ant[None, :] / (d_ant[None, :] - d_other)
        seg = other - ant
        cross &= t * np.linalg.norm(seg, axis=1)[:, None] <= radius[rows][:, None]
        i, j = np.nonzero(cross)
        if len(i) == 0:
            continue
        points = ant + t[i, j][:, None] * seg[i]
        inside = containing_triangles(points, tri_face[near[j]], near[j], triangles,
                                      tri_face) >= 0
        out[rows[i[inside]]] = True
    return out


#: :func:`antenna_blocked` keeps, per antenna, the triangles whose boxes come within
#: twice this many metres of it, and tests only those for radii up to this (its radii are
#: millimetres: :func:`confirm_margin_m`)
NEAR_ANTENNA_M = 0.25
# per caster: (its generation, {antenna's bytes: triangle ids near it})
_NEAR_ANTENNA: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def _boxes_near(caster: RayCaster, ant, r) -> np.ndarray:
    """Ascending ids of the triangles whose boxes lie within ``r`` of the point ``ant``
    along every axis (lo - r <= ant <= hi + r). For r <= NEAR_ANTENNA_M the exact test
    runs only on the triangles found once per antenna within 2 NEAR_ANTENNA_M, a superset
    whatever the rounding: one scan of the scene per antenna instead of one per call."""
    lo, hi = caster.triangle_bounds()
    if r > NEAR_ANTENNA_M:
        return np.flatnonzero(np.all((ant >= lo - r) & (ant <= hi + r), axis=1))
    generation, known = _NEAR_ANTENNA.get(caster, (None, {}))
    if generation != caster.generation:
        known = {}
        _NEAR_ANTENNA[caster] = (caster.generation, known)
    key = ant.tobytes()
    cand = known.get(key)
    if cand is None:
        if len(known) >= 256:   # many antennas (surface points): keep the memory bounded
            known.clear()
        gap = np.maximum(lo - ant, ant - hi).max(axis=1)
        cand = np.flatnonzero(gap <= 2.0 * NEAR_ANTENNA_M)
        known[key] = cand
    return cand[np.all((ant >= lo[cand] - r) & (ant <= hi[cand] + r), axis=1)]


def antenna_near_triangles(caster: RayCaster, antenna, radius,
                           on_face_tol: float = ON_FACE_TOL_REL) -> np.ndarray:
    """Ascending ids of the triangles :func:`antenna_blocked` tests for the segments at
    ``antenna`` (3,) within ``radius`` (m): their boxes within the radius of it along
    every axis, and the antenna farther than ``on_face_tol`` x (1 + its largest
    coordinate) from their plane. Kernels that decide the antenna ends themselves take
    these lists (kernels/sbr.cl, kernels/scatter.cl)."""
    ant = np.asarray(antenna, dtype=np.float64)
    near = _boxes_near(caster, ant, float(radius))
    d_ant = np.einsum("ij,ij->i", caster.normals64()[near], ant - caster.triangles[near, 0])
    return near[np.abs(d_ant) > on_face_tol * (1.0 + np.abs(ant).max())]


def edge_distances(points, tri):
    """(C, 3) signed in-plane distances (m) of points inside the three edges of their
    triangles (C, 3, 3): all >= 0 inside, negative outside."""
    n = triangle_normals(tri)
    out = np.empty((len(points), 3))
    for j in range(3):
        a, b = tri[:, j], tri[:, (j + 1) % 3]
        e = b - a
        out[:, j] = np.einsum("ij,ij->i", np.cross(e, points - a), n) / np.linalg.norm(e, axis=1)
    return out


def _seam_edges(tri_ids, edges, triangles, tri_face) -> np.ndarray:
    """(M,) bool: edge ``edges[m]`` (vertex j to j + 1) of triangle ``tri_ids[m]`` is a
    seam: another triangle of the same face has both its end vertices (bit for bit, as
    neighbours in a mesh do)."""
    tri_ids = np.asarray(tri_ids)
    edges = np.asarray(edges)
    out = np.zeros(len(tri_ids), dtype=bool)
    a = triangles[tri_ids, edges]
    b = triangles[tri_ids, (edges + 1) % 3]
    face = tri_face[tri_ids]
    for f in np.unique(face):
        sel = np.flatnonzero(face == f)
        cand = np.flatnonzero(tri_face == f)
        verts = triangles[cand][None]  # (1, K, 3, 3)
        has_a = np.all(verts == a[sel, None, None], axis=3).any(axis=2)
        has_b = np.all(verts == b[sel, None, None], axis=3).any(axis=2)
        out[sel] = np.any(has_a & has_b & (cand[None] != tri_ids[sel, None]), axis=1)
    return out


def _inside(dist, min_dist, tri_ids, triangles, tri_face) -> np.ndarray:
    """(M,) bool: edge distances ``dist`` (M, 3) of points to triangles ``tri_ids`` say
    inside: none negative, or the negative ones (>= ``min_dist``, (M,)) across seams."""
    exact = np.all(dist >= 0.0, axis=1)
    near = ~exact & np.all(dist >= min_dist[:, None], axis=1)
    if near.any():
        m, j = np.nonzero((dist < 0.0) & near[:, None])
        seam = _seam_edges(np.asarray(tri_ids)[m], j, triangles, tri_face)
        rim = np.zeros(len(dist), dtype=bool)
        rim[m[~seam]] = True
        exact |= near & ~rim
    return exact


def containing_triangles(points, faces, prims, triangles, tri_face):
    """The triangle of face ``faces[c]`` that holds ``points[c]`` in float64, or -1.

    ``prims`` is a first guess per point (the float32 hit, -1 for none).  The float32
    cast alone lets a reflection point up to its rounding (tens of um at 1 km) outside a
    face's rim count as inside, and one inside count as outside; the UTD field of the
    rim assumes the exact side, so the total field jumps there.  Decided here in
    float64, the reflection appears and disappears where the edge diffraction
    expects it: a point on or inside the rim is inside, one outside it by any amount
    is not; across a seam between two triangles of the face INSIDE_TOL_REL of rounding
    is forgiven, so the seam has no gap.
    """
    points = np.asarray(points, dtype=np.float64)
    faces = np.asarray(faces)
    tri_face = np.asarray(tri_face)
    out = np.full(len(points), -1, dtype=np.int32)
    if len(points) == 0:
        return out
    min_dist = -INSIDE_TOL_REL * (1.0 + np.abs(points).max(axis=1))
    prims = np.asarray(prims)
    guess = (prims >= 0) & (tri_face[np.maximum(prims, 0)] == faces)
    g = np.flatnonzero(guess)
    inside = _inside(edge_distances(points[g], triangles[prims[g]]), min_dist[g], prims[g],
                     triangles, tri_face)
    out[g[inside]] = prims[g[inside]]
    rest = np.flatnonzero(out < 0)
    if len(rest) == 0:
        return out
    # points whose first guess failed: the other triangles of their face, face by face,
    # after a bounding-box cut (most such points lie well outside the face)
    order = np.argsort(tri_face, kind="stable")
    bounds = np.searchsorted(tri_face[order], [faces[rest], faces[rest] + 1])
    for f in np.unique(faces[rest]):
        pts_idx = rest[faces[rest] == f]
        a, b = bounds[:, np.flatnonzero(faces[rest] == f)[0]]
        cand = order[a:b]
        tri = triangles[cand]
        lo = tri.min(axis=(0, 1)) + min_dist[pts_idx, None]
        hi = tri.max(axis=(0, 1)) - min_dist[pts_idx, None]
        near = np.all((points[pts_idx] >= lo) & (points[pts_idx] <= hi), axis=1)
        step = max(1, (1 << 18) // max(len(cand), 1))
        for c0 in range(0, int(near.sum()), step):
            sel = pts_idx[near][c0:c0 + step]
            p = np.repeat(points[sel], len(cand), axis=0)
            t = np.tile(tri, (len(sel), 1, 1))
            inside = _inside(edge_distances(p, t), np.repeat(min_dist[sel], len(cand)),
                             np.tile(cand, len(sel)), triangles, tri_face)
            inside = inside.reshape(len(sel), len(cand))
            hit = inside.any(axis=1)
            out[sel[hit]] = cand[np.argmax(inside[hit], axis=1)]
    return out


def blocked_in_float64(caster: RayCaster, tri_face, start, seg, tmax,
                       max_rounds: int = RESCUE_ROUNDS, tmin=0.0, ignore_prim=None):
    """Re-decide segments a float32 any-hit cast called blocked: (S,) bool.

    A segment that passes an edge closer than float32 resolution (tens of um at 1 km) may be
    "blocked" by a triangle it misses.  On a shadow boundary that flips the line of
    sight off while the UTD field of the edge, computed in float64, is still on its lit
    side: the total field jumps.  Each round takes the closest float32 hit, crosses the
    segment with that triangle's plane in float64 and keeps the segment blocked if the
    crossing lies inside the triangle's face (:func:`containing_triangles`, so a ray
    through a seam of a tessellated wall stays blocked); otherwise it looks past that
    triangle.  Segments still undecided after ``max_rounds`` stay blocked.
    ``ignore_prim`` (S,): a triangle the first round skips (the surface a sight line
    leaves, as the any-hit cast skipped it).
    """
    start = np.asarray(start, dtype=np.float64)
    seg = np.asarray(seg, dtype=np.float64)
    tmax = np.broadcast_to(np.asarray(tmax, dtype=np.float64), (len(start),))
    blocked = np.ones(len(start), dtype=bool)
    todo = np.arange(len(start))
    tmin = np.broadcast_to(np.asarray(tmin, dtype=np.float64), (len(start),)).copy()
    ignore = (np.full(len(start), -1, dtype=np.int32) if ignore_prim is None else
              np.broadcast_to(np.asarray(ignore_prim), (len(start),)).astype(np.int32))
    for _ in range(max_rounds):
        if len(todo) == 0:
            break
        hits = caster.closest_hit(make_rays(start[todo], seg[todo], tmin[todo], tmax[todo]),
                                  ignore_prim=ignore[todo])
        prim = hits["prim"]
        blocked[todo[prim < 0]] = False
        todo, prim, t_hit = todo[prim >= 0], prim[prim >= 0], hits["t"][prim >= 0]
        tri = caster.triangles[prim]
        n = triangle_cross_products(tri)
        denom = np.einsum("ij,ij->i", n, seg[todo])
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.einsum("ij,ij->i", n, tri[:, 0] - start[todo]) / denom
        ok = np.isfinite(t) & (t >= tmin[todo]) & (t <= tmax[todo])
        point = start[todo] + np.where(ok, t, 0.0)[:, None] * seg[todo]
        inside = np.zeros(len(todo), dtype=bool)
        inside[ok] = containing_triangles(point[ok], tri_face[prim[ok]], prim[ok],
                                          caster.triangles, tri_face) >= 0
        # inside: really blocked, decided; outside: look past this triangle
        todo, prim, t_hit = todo[~inside], prim[~inside], t_hit[~inside]
        tmin[todo] = np.maximum(tmin[todo], t_hit.astype(np.float64) * LOOK_PAST)
        ignore[todo] = prim
    return blocked


# --------------------------------------------------------------------------------------
# the device engine: kernels/visibility.cl


def _check_engine(engine) -> None:
    if engine not in ENGINES:
        raise ArgumentError(f"must be one of {', '.join(ENGINES)}", argument="engine",
                            value=engine)


@functools.cache
def dot3_order() -> int | None:
    """The order in which numpy's ``einsum("ij,ij->i")`` adds three products here: 0 for
    (p0 + p1) + p2, 1 for (p0 + p2) + p1, 2 for (p1 + p2) + p0 (it depends on the CPU's
    vector width); None if none of them.  kernels/visibility.cl adds in that order, so its
    float64 distances are the host's bit for bit."""
    e = 2.0 ** -53
    probes = np.array([[1.0, e, -1.0], [e, 1.0, -1.0], [-1.0, 1.0, e]])
    got = np.einsum("ij,ij->i", probes, np.ones_like(probes)).tolist()
    for order, (i, j, k) in enumerate(((0, 1, 2), (0, 2, 1), (1, 2, 0))):
        if got == [(p[i] + p[j]) + p[k] for p in probes.tolist()]:
            return order
    return None


#: why the device engine leaves a float64 decision to the host on a device with fp64
DOT3_UNKNOWN = ("numpy's order of three-term dot products on this host is unknown, so a "
                "double kernel cannot repeat its float64 decisions bit for bit")


def device_refusal(caster: RayCaster) -> str | None:
    """Why the caster's device cannot take the float64 re-decisions, or None where it
    can: always without fp64 (double-float), and with fp64 where numpy's dot-product
    order is known (:func:`dot3_order`)."""
    if caster.runtime.info.has_double and dot3_order() is None:
        return DOT3_UNKNOWN
    return None


def uses_device(caster: RayCaster, engine: str = "device") -> bool:
    """True where ``engine`` is "device" and the caster's device can take the float64
    re-decision (:func:`device_refusal`); otherwise the host decides."""
    _check_engine(engine)
    return engine == "device" and device_refusal(caster) is None


def decide_on_device(caster: RayCaster, engine: str, stage: str) -> bool:
    """:func:`uses_device`, and the engine that decides noted for ``stage``
    (:func:`clradcom.device.engines.record`: the host reference engine as such, a device
    engine that cannot with its reason)."""
    _check_engine(engine)
    if engine == "host":
        engines.record(stage, "host", fallback=False)
        return False
    reason = device_refusal(caster)
    if reason is not None:
        engines.record(stage, "host", reason)
        return False
    engines.record(stage, "device")
    return True


def face_tables(triangles, tri_face) -> dict:
    """What :func:`containing_triangles` reads of the faces, as flat arrays for a kernel:

    * ``seam`` (T, 3) bool: edge j -> j+1 of each triangle is a seam (another triangle of
      its face has both end vertices, bit for bit: :func:`_seam_edges` for every edge);
    * ``face_first`` (F+1,), ``face_tris`` (T,): the triangles of face f in ascending id
      at ``face_tris[face_first[f]:face_first[f + 1]]``;
    * ``face_box`` (F, 6): each face's vertex minima and maxima (float64).
    """
    triangles = np.asarray(triangles, dtype=np.float64)
    tri_face = np.asarray(tri_face).astype(np.int64)
    T = len(triangles)
    F = int(tri_face.max()) + 1 if T else 0
    a = triangles + 0.0  # -0.0 -> 0.0: equal coordinates compare equal, as == does
    b = a[:, [1, 2, 0]]
    # an edge as (face, lesser end, greater end), the ends ordered lexicographically
    a_first = ((a[..., 0] < b[..., 0]) | ((a[..., 0] == b[..., 0]) & (
        (a[..., 1] < b[..., 1]) | ((a[..., 1] == b[..., 1]) & (a[..., 2] <= b[..., 2])))))
    lo = np.where(a_first[..., None], a, b)
    hi = np.where(a_first[..., None], b, a)
    rows = np.concatenate([np.repeat(tri_face[:, None], 3, axis=1)[..., None].astype(np.float64),
                           lo, hi], axis=2).reshape(-1, 7)
    if T:
        seam = (row_counts(rows) >= 2).reshape(T, 3)
    else:
        seam = np.zeros((0, 3), dtype=bool)
    order = np.argsort(tri_face, kind="stable")
    face_first = np.searchsorted(tri_face[order], np.arange(F + 1)).astype(np.int32)
    return {"seam": seam, "face_first": face_first, "face_tris": order.astype(np.int32),
            "face_box": face_boxes(triangles, tri_face, F)}


def face_boxes(triangles, tri_face, n_faces: int) -> np.ndarray:
    """(n_faces, 6) float64: each face's vertex minima and maxima (+-inf for none)."""
    box = np.empty((n_faces, 6))
    box[:, :3] = np.inf
    box[:, 3:] = -np.inf
    if len(triangles):
        np.minimum.at(box[:, :3], tri_face, triangles.min(axis=1))
        np.maximum.at(box[:, 3:], tri_face, triangles.max(axis=1))
    return box


# per caster, per tri_face (its bytes): the device buffers of face_tables and the
# caster's generation they were made at
_DEVICE_TABLES: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def scene64_args(caster: RayCaster, tri_face) -> tuple:
    """The SCENE64_ARGS of kernels/scene64.h for ``tri_face``, uploaded once per caster
    and faces; a caster placed since (a time step of InstancedCaster) gets the float64
    scene buffers it holds now and its faces' boxes redone (the faces' triangles and
    seams stay: a rigid motion moves the equal vertices of a seam alike). Float64 values
    as the device's mode reads them (:func:`clradcom.device.precision.kernel_float64`)."""
    tri_face = np.ascontiguousarray(tri_face, dtype=np.int32)
    key = tri_face.tobytes()
    cache = _DEVICE_TABLES.setdefault(caster, {})
    if key not in cache:
        if len(tri_face) != len(caster.triangles):
            raise ArgumentError(f"has {len(tri_face)} entries for "
                                f"{len(caster.triangles)} triangles", argument="tri_face",
                                value=tri_face.shape)
        tables = face_tables(caster.triangles, tri_face)
        rt = caster.runtime
        topology = (rt.to_device(tri_face), rt.to_device(tables["seam"].astype(np.uint8)),
                    rt.to_device(tables["face_first"]), rt.to_device(tables["face_tris"]))
        cache[key] = (None, topology, len(tables["face_box"]), None)
    generation, topology, n_faces, args = cache[key]
    if generation != caster.generation:
        data64 = caster.scene_data64()
        box = face_boxes(caster.triangles, tri_face, n_faces)
        rt = caster.runtime
        args = (data64["vertices"], data64["normals"], *topology,
                rt.to_device(kernel_float64(rt, box)), np.int32(n_faces),
                kernel_scalar64(rt, INSIDE_TOL_REL))
        cache[key] = (caster.generation, topology, n_faces, args)
    return args


def kernel_defines() -> dict:
    """The -D defines of the kernels that include kernels/scene64.h or dot3.h (an unknown
    order, which only a build without fp64 runs with, adds as numpy's most common)."""
    return {"DOT3_ORDER": int(dot3_order() or 0)}


def download(caster: RayCaster, buf, n: int, dtype) -> np.ndarray:
    """The first ``n`` elements of ``dtype`` of a device buffer, read back blocking."""
    import pyopencl as cl

    out = np.empty(n, dtype=dtype)
    cl.enqueue_copy(caster.runtime.queue, out, buf, is_blocking=True)
    return out


def _f64(rt, a, n: int, shape=()):
    """A device buffer of float64 values ``a`` broadcast to (n, *shape), as the build
    reads them (double or pairs)."""
    return rt.to_device(kernel_float64(rt, np.broadcast_to(np.asarray(a, dtype=np.float64),
                                                          (n, *shape))))


def segments_blocked_device(caster: RayCaster, tri_face, start, seg, tmin, tmax,
                            ignore_prim=None, max_rounds: int = RESCUE_ROUNDS) -> np.ndarray:
    """(S,) bool, in one launch of ``segments_blocked`` (kernels/visibility.cl): something
    blocks the segments start + t seg, t in (tmin, tmax) (scalars or (S,)).

    A float32 "blocked" is re-decided on the device in float64 as
    :func:`blocked_in_float64` does (up to ``max_rounds`` blockers; 0: the float32 answer
    stands).  ``ignore_prim`` (S,) skips the surface a segment leaves (the any-hit and
    the first float64 round)."""
    start = np.asarray(start, dtype=np.float64)
    seg = np.asarray(seg, dtype=np.float64)
    S = len(start)
    rays = make_rays(start, seg, tmin=tmin, tmax=tmax)
    if S == 0:
        return np.zeros(0, dtype=bool)
    rt = caster.runtime
    ignore = None if ignore_prim is None else rt.to_device(
        np.ascontiguousarray(np.broadcast_to(ignore_prim, (S,)), dtype=np.int32))
    out = rt.empty(S)
    caster.run_kernel("visibility.cl", "segments_blocked", S, *scene64_args(caster, tri_face),
                      rt.to_device(rays), _f64(rt, start, S, (3,)), _f64(rt, seg, S, (3,)),
                      _f64(rt, tmin, S), _f64(rt, tmax, S), ignore, np.int32(max_rounds),
                      kernel_scalar64(rt, LOOK_PAST), out, np.int32(S),
                      defines=kernel_defines())
    return download(caster, out, S, np.uint8).astype(bool)


def reaches_face_device(caster: RayCaster, tri_face, start, end, faces, slack,
                        tmin=0.0) -> np.ndarray:
    """:func:`reaches_face` in one launch of ``reach_faces`` (kernels/visibility.cl): the
    closest float32 hit and the float64 "which triangle of the face holds the end" in the
    same work item."""
    start = np.asarray(start, dtype=np.float64)
    end = np.asarray(end, dtype=np.float64)
    S = len(start)
    slack = np.ascontiguousarray(np.broadcast_to(np.asarray(slack, dtype=np.float64), (S,)))
    rays = make_rays(start, end - start, tmin=tmin, tmax=1.0 + 2.0 * slack)
    if S == 0:
        return np.zeros(0, dtype=np.int32)
    rt = caster.runtime
    out = rt.empty(4 * S)
    caster.run_kernel("visibility.cl", "reach_faces", S, *scene64_args(caster, tri_face),
                      rt.to_device(rays), _f64(rt, end, S, (3,)),
                      rt.to_device(np.ascontiguousarray(np.broadcast_to(faces, (S,)),
                                                        dtype=np.int32)),
                      _f64(rt, slack, S), out, np.int32(S), defines=kernel_defines())
    return download(caster, out, S, np.int32)


# --------------------------------------------------------------------------------------
# the decisions every mechanism calls


def reaches_face(caster: RayCaster, tri_face, start, end, faces, slack,
                 tmin=0.0, engine: str = "device") -> np.ndarray:
    """(S,) int32: the scene triangle of face ``faces[s]`` holding ``end[s]``, where the
    segment start -> end first meets that face at ``end`` (within ``slack``, a fraction
    of the segment, and past ``tmin``); -1 where it does not.

    A float32 cast that slips past the face's rim and meets nothing also counts (that
    proves nothing stands in between); whether ``end`` lies inside the face is then
    decided in float64 (:func:`containing_triangles`), never by the float32 hit.
    ``engine``: "device" (:func:`reaches_face_device`) or "host" (numpy).
    """
    tri_face = np.asarray(tri_face)
    start = np.asarray(start, dtype=np.float64)
    end = np.asarray(end, dtype=np.float64)
    faces = np.asarray(faces)
    if decide_on_device(caster, engine, "visibility.segments"):
        return reaches_face_device(caster, tri_face, start, end, faces, slack, tmin)
    hits = caster.closest_hit(make_rays(start, end - start, tmin=tmin, tmax=1.0 + 2.0 * slack))
    prim = hits["prim"]
    hit_face = np.where(prim >= 0, tri_face[np.maximum(prim, 0)], -1)
    reached = ((hit_face == faces) & (np.abs(hits["t"] - 1.0) <= slack)) | (prim < 0)
    tri = np.full(len(start), -1, dtype=np.int32)
    tri[reached] = containing_triangles(end[reached], faces[reached], prim[reached],
                                        caster.triangles, tri_face)
    return tri


def segments_clear(caster: RayCaster, tri_face, start, end, tmin, tmax,
                   engine: str = "device") -> np.ndarray:
    """(S,) bool: nothing blocks the segments start -> end between the fractions
    ``tmin`` and ``tmax`` of their length (scalars or (S,)).

    A float32 "blocked" stands only if the blocker's face holds the crossing in
    float64 (:func:`blocked_in_float64`; on the device :func:`segments_blocked_device`).
    """
    start = np.asarray(start, dtype=np.float64)
    seg = np.asarray(end, dtype=np.float64) - start
    if decide_on_device(caster, engine, "visibility.segments"):
        return ~segments_blocked_device(caster, tri_face, start, seg, tmin, tmax)
    blocked = caster.occluded(make_rays(start, seg, tmin=tmin, tmax=tmax))
    if blocked.any():
        tmin = np.broadcast_to(np.asarray(tmin, dtype=np.float64), (len(start),))
        tmax = np.broadcast_to(np.asarray(tmax, dtype=np.float64), (len(start),))
        blocked[blocked] = blocked_in_float64(caster, np.asarray(tri_face), start[blocked],
                                              seg[blocked], tmax[blocked],
                                              tmin=tmin[blocked])
    return ~blocked


def antenna_ends_blocked(caster: RayCaster, tri_face, start, end, *, at_tx: bool,
                         at_rx: bool) -> np.ndarray:
    """(S,) bool: the float64 millimetre next to the transmitter (``start``, when the
    segments leave it) or the receiver (``end``, when they reach it) is blocked
    (:func:`antenna_blocked` over twice :func:`confirm_margin_m`)."""
    blocked = np.zeros(len(end), dtype=bool)
    if at_rx:
        blocked |= antenna_blocked(caster, tri_face, end, start, 2.0 * confirm_margin_m(end))
    if at_tx:
        blocked |= antenna_blocked(caster, tri_face, start, end,
                                   2.0 * confirm_margin_m(start))
    return blocked


def confirm_segments(caster: RayCaster, tri_face, start, end, length, *, face, tmin, stop,
                     at_tx: bool, at_rx: bool, engine: str = "device"):
    """One step of a path's confirmation for segments start -> end (their unmoved
    ``length``): (good (S,) bool, triangle (S,) int32 or None).

    With ``face`` (S,) the segment must reach that face (:func:`reaches_face`, the
    triangle it meets there returned); without, nothing may block it between the
    fractions ``tmin`` and 1 - ``stop`` (:func:`segments_clear`). The antenna ends are
    decided in float64 (:func:`antenna_ends_blocked`). ``engine``: see
    :func:`segments_clear`."""
    if face is not None:
        tri = reaches_face(caster, tri_face, start, end, face, stop, tmin, engine=engine)
        good = tri >= 0
    else:
        tri = None
        good = segments_clear(caster, tri_face, start, end, tmin, 1.0 - stop,
                              engine=engine) & (length > 0)
    good &= ~antenna_ends_blocked(caster, tri_face, start, end, at_tx=at_tx, at_rx=at_rx)
    return good, tri


def confirm_paths(caster: RayCaster, tri_face, face_normals, points: np.ndarray,
                  seqs: np.ndarray, ok: np.ndarray | None = None, engine: str = "device",
                  n_interactions: np.ndarray | None = None):
    """Mask of candidate paths whose every segment is confirmed by a ray cast.

    Returns (keep (C,) bool, triangles (C, k) int32): the scene triangle each
    kept path's reflection points lie in (-1 where not confirmed).

    Segment i runs from points[:, i] to points[:, i+1]. Toward a reflection
    point it must reach that point's face there (:func:`reaches_face`); the
    last segment must reach the receiver with nothing in between
    (:func:`segments_clear`). Segments leave reflection points from just off
    the face, on the side they leave into. The casts leave out the
    :func:`confirm_margin_m` next to the transmitter (points[:, 0]) and the
    receiver (the path's last point); :func:`antenna_blocked` decides those in float64.
    ``n_interactions`` (C,): candidates of several orders at once, row c holding
    n_interactions[c] <= k reflections (its receiver at points[c, n + 1], seqs[c, :n]
    its faces; the rest padding): each segment index is confirmed for every row in one
    batch. Default: every row has k. ``engine``: see :func:`segments_clear`.
    """
    tri_face = np.asarray(tri_face)
    C, k2, _ = points.shape
    k = k2 - 2
    keep = np.ones(C, dtype=bool) if ok is None else ok.copy()
    triangles = np.full((C, k), -1, dtype=np.int32)
    if C == 0:
        return keep, triangles
    n_row = (np.full(C, k, dtype=np.int64) if n_interactions is None
             else np.asarray(n_interactions, dtype=np.int64))
    idx = np.flatnonzero(keep)
    for i in range(k + 1):
        idx = idx[n_row[idx] >= i]
        if len(idx) == 0:
            break
        start = points[idx, i]
        end = points[idx, i + 1]
        length = np.linalg.norm(end - start, axis=1)
        if i > 0:
            start = spawn_origins(start, face_normals[seqs[idx, i - 1]], end - start)
            tmin = 0.0
        else:  # leaving the transmitter
            tmin = antenna_slack(start, length)
        last = n_row[idx] == i
        tmin = np.broadcast_to(tmin, (len(idx),))
        good = np.zeros(len(idx), dtype=bool)
        for part, face in ((~last, seqs[idx, i] if i < k else None), (last, None)):
            if not part.any():
                continue
            rows = np.flatnonzero(part)
            g, tri = confirm_segments(caster, tri_face, start[rows], end[rows], length[rows],
                                      face=None if face is None else face[rows],
                                      tmin=tmin[rows], stop=confirm_slack(end[rows],
                                                                          length[rows]),
                                      at_tx=i == 0, at_rx=face is None, engine=engine)
            good[rows] = g
            if tri is not None:
                triangles[idx[rows], i] = tri
        keep[idx[~good]] = False
        idx = idx[good]
    triangles[~keep] = -1
    return keep, triangles


def surface_sees(caster: RayCaster, points, normals, targets, ignore_prim, *,
                 leave_direction=None, stop_short_m=None, tri_face=None,
                 engine: str = "device") -> np.ndarray:
    """(S,) bool: nothing but the surface's own triangle ``ignore_prim`` lies between
    the surface points (S,3) and their targets ((3,) or (S,3)).

    The sight line starts just off the surface (:func:`spawn_origins`) on the side of
    ``leave_direction`` (default: toward the target) and stops ``stop_short_m`` metres
    short of the target where given (a target on a face that is not to block it).
    Otherwise the target is an antenna: the cast stops SIGHT_STOP of its length short
    and :func:`antenna_blocked` decides the last :func:`confirm_margin_m` in float64
    against the planar faces ``tri_face`` (default: every triangle its own face).
    A float32 "blocked" is re-decided in float64 (:func:`blocked_in_float64`, the
    surface's triangle skipped in its first round; on the device in the same launch,
    :func:`segments_blocked_device`), against the faces ``tri_face``: a sight line that
    grazes a rim within float32 rounding is decided as the float64 geometry has it.
    """
    points = np.asarray(points, dtype=np.float64)
    targets = np.asarray(targets, dtype=np.float64)
    if len(points) == 0:
        return np.zeros(0, dtype=bool)
    leave = targets - points if leave_direction is None else leave_direction
    org = spawn_origins(points, normals, leave)
    sight = targets - org
    stop = SIGHT_STOP if stop_short_m is None else stop_short_m / np.linalg.norm(sight, axis=1)
    if tri_face is None:
        tri_face = np.arange(len(caster.triangles))
    ignore = np.asarray(ignore_prim).astype(np.int32)
    if decide_on_device(caster, engine, "visibility.surface_sight"):
        sees = ~segments_blocked_device(caster, tri_face, org, sight, 0.0, 1.0 - stop,
                                        ignore_prim=ignore)
    else:
        sees = ~caster.occluded(make_rays(org, sight, 0.0, 1.0 - stop), ignore_prim=ignore)
        if not sees.all():
            b = ~sees
            tmax = np.broadcast_to(1.0 - stop, (len(org),))
            sees[b] = ~blocked_in_float64(caster, np.asarray(tri_face), org[b], sight[b],
                                          tmax[b], ignore_prim=np.broadcast_to(
                                              ignore, (len(org),))[b])
    if stop_short_m is None and sees.any():
        # the target is an antenna: what lies just before it is decided in float64
        t = np.broadcast_to(targets, org.shape)
        sees[sees] = ~antenna_blocked(caster, tri_face, t[sees], org[sees],
                                      2.0 * confirm_margin_m(t[sees]))
    return sees
