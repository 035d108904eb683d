"""Diffracting wedges of a scene mesh and the diffraction points on them (UTD, issue 5).

:func:`extract_wedges` turns the scene's triangle soup into flat arrays of straight
diffracting edges: creases shared by two triangles of one object whose faces turn by more
than a threshold (solid wedges, exterior angle ``n*pi``), and rim edges of open meshes
(half-planes, ``n = 2``). :func:`diffraction_point` is Keller's point on one edge in closed
form and :func:`multi_diffraction_points` the points of a chain of edges (convex
minimisation of the path length, Newton in float64). docs/wedges.md is the reference.

Face-0 convention (Kouyoumjian & Pathak): with ``e`` the unit edge direction, ``n0`` the
outward normal of face 0 and ``t0 = n0 x e`` the unit vector in face 0 pointing away from
the edge, ``phi`` is measured from face 0 (``phi = 0``) about ``e`` through the exterior to
face n (``phi = n*pi``). The edge direction is fixed by face 0 as ``e = t0 x n0``; for a
convex wedge this equals ``normalize(n0 x nn)``.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from clradcom.errors import ArgumentError
from clradcom.geometry.rows import unique_rows
from clradcom.geometry.triangles import triangle_normals_and_double_areas

__all__ = ["Wedges", "extract_wedges", "free_wedges", "weld_vertices", "DiffractionPoint",
           "diffraction_point", "MultiDiffraction", "multi_diffraction_points"]

#: Unit-vector tolerance (normals, directions) for joining collinear segments of one crease.
_MERGE_TOL = 1e-6
#: Radians added to the threshold so turns equal to it are excluded deterministically.
_ANGLE_MARGIN = 1e-9
#: A wedge face lies flush on another object's surface where that surface's plane is
#: within this distance (m) of the face next to the edge, and its triangles cover the face
#: there to this slack: 0.1 mm, lambda/125 at 24 GHz, above the float32 rounding of
#: meshes 100 m from the origin and far below the 1 mm a lifted object stands free.
FLUSH_TOL_M = 1e-4
#: ... whose normal is parallel or antiparallel to the face's within this angle (rad).
FLUSH_ANGLE_RAD = 1e-3
#: The face is probed for cover this far (m) from the edge, on a line parallel to it;
#: free pieces of an edge shorter than this are dropped with the covered parts.
FLUSH_PROBE_M = 1e-3


@dataclass(eq=False)
class Wedges:
    """Diffracting edges as flat arrays (one row per wedge, W rows).

    ``start``/``end`` are ordered so that ``end - start`` points along ``direction``
    (``e = t0 x n0``, the KP edge vector of face 0). ``n`` is the exterior wedge angle
    over pi: ``1 < n < 2`` convex crease, ``0 < n < 1`` concave (re-entrant) crease,
    ``n == 2`` half-plane (``half_plane`` True, ``tri1 == -1``, ``normal1 == -normal0``,
    ``material1 == material0``).
    """

    start: np.ndarray  #: (W,3) float64, m
    end: np.ndarray  #: (W,3) float64, m
    direction: np.ndarray  #: (W,3) float64 unit, = t0 x normal0
    length: np.ndarray  #: (W,) float64, m
    n: np.ndarray  #: (W,) float64, exterior angle / pi
    normal0: np.ndarray  #: (W,3) float64 unit outward normal of face 0
    normal1: np.ndarray  #: (W,3) float64 unit outward normal of face n
    tri0: np.ndarray  #: (W,) int32 a scene triangle of face 0
    tri1: np.ndarray  #: (W,) int32 a scene triangle of face n, -1 for half-planes
    object_id: np.ndarray  #: (W,) int32
    material0: np.ndarray  #: (W,) int32
    material1: np.ndarray  #: (W,) int32
    half_plane: np.ndarray  #: (W,) bool, a rim edge of an open mesh (thin screen)
    n_segments: np.ndarray  #: (W,) int32, mesh edges joined into this wedge
    #: counts of what was left out or repaired (see extract_wedges)
    stats: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.n)

    @property
    def tangent0(self) -> np.ndarray:
        """(W,3) t0 = normal0 x direction: unit vector in face 0, away from the edge."""
        return np.cross(self.normal0, self.direction)

    @property
    def concave(self) -> np.ndarray:
        return self.n < 1.0

    def select(self, mask) -> Wedges:
        """The wedges where ``mask`` (bool or index array) selects, stats kept."""
        m = np.asarray(mask)
        kw = {k: getattr(self, k)[m] for k in _ARRAY_FIELDS}
        return Wedges(**kw, stats=dict(self.stats))


_ARRAY_FIELDS = ("start", "end", "direction", "length", "n", "normal0", "normal1", "tri0",
                 "tri1", "object_id", "material0", "material1", "half_plane", "n_segments")


def weld_vertices(points, tol: float) -> np.ndarray:
    """Ids of (P,3) points such that points closer than ``tol`` (metres) share an id.

    Exact duplicates are folded first; points within ``tol`` are then joined through a
    k-d tree (transitively: a chain of close points becomes one vertex).
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(pts) == 0:
        return np.zeros(0, dtype=np.int64)
    uniq, inverse, _ = unique_rows(pts)  # np.unique(pts, axis=0)'s, by one lexsort
    if tol <= 0 or len(uniq) == 1:
        return inverse.astype(np.int64)
    pairs = cKDTree(uniq).query_pairs(tol, output_type="ndarray")
    if len(pairs) == 0:
        return inverse.astype(np.int64)
    U = len(uniq)
    graph = coo_matrix((np.ones(len(pairs), dtype=np.int8), (pairs[:, 0], pairs[:, 1])),
                       shape=(U, U))
    _, labels = connected_components(graph, directed=False)
    return labels[inverse].astype(np.int64)


def _norm3(v):
    """np.linalg.norm(v, axis=-1) of (..., 3) vectors, bit for bit (the squares added in
    numpy's order, (x^2 + y^2) + z^2), without the reduction's overhead on so short an
    axis."""
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    return np.sqrt((x * x + y * y) + z * z)


def _max_abs3(v):
    """np.max(np.abs(v), axis=-1) of (..., 3) vectors (exact either way)."""
    a = np.abs(v)
    return np.maximum(np.maximum(a[..., 0], a[..., 1]), a[..., 2])


def _unit(v):
    norm = _norm3(v)[..., None]
    with np.errstate(invalid="ignore", divide="ignore"):
        return v / norm


def _edge_groups(obj, lo, hi):
    """(order, first, counts) of the edge rows (object, lesser vertex id, greater vertex
    id), all ids >= 0: the rows sorted by key with ties in row order, where each key's run
    starts in that order, and how many rows each key has, keys ascending as
    np.unique(keys, axis=0) orders them.  One int64 key per row where the ids fit
    (lexicographic order is the keys' order), else :func:`unique_rows`."""
    span = int(max(lo.max(), hi.max())) + 1
    if int(obj.min()) >= 0 and (int(obj.max()) + 1) * span * span < 2**62:
        key = (obj.astype(np.int64) * span + lo) * span + hi
        order = np.argsort(key, kind="stable")
        srt = key[order]
        new = np.ones(len(srt), dtype=bool)
        new[1:] = srt[1:] != srt[:-1]
        first = np.flatnonzero(new)
        counts = np.diff(np.append(first, len(srt)))
        return order, first, counts
    _, inverse, counts = unique_rows(np.column_stack([obj, lo, hi]))
    order = np.argsort(inverse, kind="stable")
    return order, np.searchsorted(inverse[order], np.arange(len(counts))), counts


def _empty_wedges(stats) -> Wedges:
    z3 = np.zeros((0, 3))
    zi = np.zeros(0, dtype=np.int32)
    return Wedges(start=z3, end=z3.copy(), direction=z3.copy(), length=np.zeros(0),
                  n=np.zeros(0), normal0=z3.copy(), normal1=z3.copy(), tri0=zi, tri1=zi.copy(),
                  object_id=zi.copy(), material0=zi.copy(), material1=zi.copy(),
                  half_plane=np.zeros(0, dtype=bool), n_segments=zi.copy(), stats=stats)


def extract_wedges(triangles, tri_object, tri_material, angle_threshold_deg: float = 20.0,
                   weld_tol: float = 1e-6, *, include_half_planes: bool = True,
                   merge_collinear: bool = True, two_sided=None) -> Wedges:
    """Diffracting edges of a triangle soup (a Scene's ``triangles``, ``tri_object``,
    ``tri_material``).

    Vertices are welded by position within ``weld_tol`` times the scene size (the largest
    extent of the bounding box), since the scene keeps every triangle's vertices as
    stored. An edge (welded vertex pair) of one object is

    * shared by exactly two triangles: a crease wedge if the faces turn by more than
      ``angle_threshold_deg`` (``|n - 1| > threshold / 180``); coplanar seams and smooth
      tessellation are not wedges. Face 0 is the lower-numbered triangle; the material
      side is taken from its winding (its normal is outward). If the two triangles run
      the edge in the same direction (inconsistent winding), face n's normal is flipped
      to agree with face 0 (``stats["inconsistent"]`` counts these).
    * used by one triangle: a rim edge, a half-plane (``n = 2``) when
      ``include_half_planes``.
    * used by three or more triangles: non-manifold, skipped (``stats["nonmanifold"]``).

    ``two_sided`` (T,) bool, optional: triangles of two-sided objects (open sheets,
    ``SceneObject.two_sided``). A crease between two of them has no material side to
    take from the winding: it gives two wedges, the one above and its twin with both
    normals reversed (exterior angle ``2 - n``), so the convex one exists whichever way
    the sheet is wound (``stats["two_sided_creases"]`` counts the twins). Rims are
    half-planes, the same from either side, either way.

    Triangles that collapse under welding or have zero area are ignored
    (``stats["degenerate"]``). With ``merge_collinear`` consecutive collinear segments of
    one crease (same object, materials, face normals and ``n``, meeting at a welded vertex)
    are joined into one edge; ``tri0``/``tri1`` are then those of its first segment and
    ``n_segments`` says how many were joined.
    """
    tri = np.asarray(triangles, dtype=np.float64)
    obj = np.asarray(tri_object, dtype=np.int64).reshape(-1)
    mat = np.asarray(tri_material, dtype=np.int64).reshape(-1)
    if tri.ndim != 3 or tri.shape[1:] != (3, 3):
        raise ArgumentError(f"triangles must have shape (T, 3, 3), got {tri.shape}")
    T = len(tri)
    if obj.shape != (T,) or mat.shape != (T,):
        raise ArgumentError("tri_object and tri_material need one entry per triangle")
    if not 0.0 <= angle_threshold_deg < 180.0:
        raise ArgumentError(f"angle_threshold_deg must be in [0, 180), got {angle_threshold_deg}")
    stats = {"triangles": T, "degenerate": 0, "inconsistent": 0, "nonmanifold": 0,
             "boundary_edges": 0, "crease_segments": 0, "weld_tol_m": 0.0}
    if T == 0:
        return _empty_wedges(stats)

    pts = tri.reshape(-1, 3)
    # np.max(np.ptp(pts, axis=0)) column by column: a reduction down a (P, 3) array's
    # short rows costs some 40x more than one down a column
    scale = float(max(pts[:, k].max() - pts[:, k].min() for k in range(3)))
    tol = weld_tol * (scale if scale > 0 else 1.0)
    stats["weld_tol_m"] = tol
    vid = weld_vertices(pts, tol).reshape(T, 3)

    with np.errstate(invalid="ignore", divide="ignore"):
        tri_normal, area2 = triangle_normals_and_double_areas(tri)
    side = _norm3(tri - tri[:, [2, 0, 1]])  # np.roll(tri, 1, axis=1)'s edges
    longest = np.maximum(np.maximum(side[:, 0], side[:, 1]), side[:, 2])
    good = (area2 > 1e-12 * longest**2) & (vid[:, 0] != vid[:, 1]) & (vid[:, 1] != vid[:, 2])
    good &= vid[:, 2] != vid[:, 0]
    stats["degenerate"] = int(T - np.count_nonzero(good))
    if two_sided is not None:
        two_sided = np.asarray(two_sided, dtype=bool).reshape(-1)
        if two_sided.shape != (T,):
            raise ArgumentError(f"two_sided needs one entry per triangle ({T}), got "
                                f"{two_sided.shape}")

    # one row per (good triangle, local edge), triangle-major so ties keep triangle order
    li, lj, lk = np.array([0, 1, 2]), np.array([1, 2, 0]), np.array([2, 0, 1])
    t_idx = np.repeat(np.flatnonzero(good), 3)
    loc = np.tile(np.arange(3), int(np.count_nonzero(good)))
    a = vid[t_idx, li[loc]]
    b = vid[t_idx, lj[loc]]
    if len(t_idx) == 0:
        return _empty_wedges(stats)
    order, first, counts = _edge_groups(obj[t_idx], np.minimum(a, b), np.maximum(a, b))
    stats["nonmanifold"] = int(np.count_nonzero(counts >= 3))

    # every row's edge p -> q and the unit in-plane direction u from it into its triangle
    flat = tri.reshape(-1, 3)
    p_all = flat[3 * t_idx + li[loc]]
    q_all = flat[3 * t_idx + lj[loc]]
    c_all = flat[3 * t_idx + lk[loc]]
    e_all = _unit(q_all - p_all)
    u_all = c_all - p_all
    u_all = _unit(u_all - np.einsum("ij,ij->i", u_all, e_all)[:, None] * e_all)

    def edge_geometry(rows):
        return t_idx[rows], p_all[rows], q_all[rows], u_all[rows]

    parts = []
    # -- creases: edges of exactly two triangles
    g2 = np.flatnonzero(counts == 2)
    ra, rb = order[first[g2]], order[first[g2] + 1]
    tA, pA, qA, uA = edge_geometry(ra)
    tB, _, _, uB = edge_geometry(rb)
    nA = tri_normal[tA]
    nB = tri_normal[tB].copy()
    # consistent winding runs the shared edge in opposite directions
    inconsistent = (a[ra] < b[ra]) == (a[rb] < b[rb])
    stats["inconsistent"] = int(np.count_nonzero(inconsistent))
    nB[inconsistent] *= -1.0
    opening = np.arctan2(_norm3(np.cross(uA, uB)),
                         np.einsum("ij,ij->i", uA, uB))  # [0, pi] between the face directions

    def crease(nA, nB, rows):
        convex = np.einsum("ij,ij->i", nA, uB) <= 0.0
        interior = np.where(convex, opening, 2.0 * np.pi - opening)
        n_val = (2.0 * np.pi - interior) / np.pi
        # a turn exactly at the threshold (a 12-sided cylinder at 30 deg) stays out whatever
        # the rounding: the margin is far above float64 noise and far below any real crease
        keep = np.abs(np.pi - interior) > np.deg2rad(angle_threshold_deg) + _ANGLE_MARGIN
        keep &= rows
        return dict(p=pA[keep], q=qA[keep], u0=uA[keep], n0=nA[keep], n1=nB[keep],
                    n=n_val[keep], tri0=tA[keep], tri1=tB[keep], half=np.zeros(
                        int(np.count_nonzero(keep)), dtype=bool),
                    va=a[ra][keep], vb=b[ra][keep])

    parts.append(crease(nA, nB, np.ones(len(tA), dtype=bool)))
    stats["crease_segments"] = len(parts[-1]["n"])
    if two_sided is not None:
        # a crease of a two-sided (thin) surface is a wedge seen from either side: its
        # twin has the material on the other side of both faces (exterior angle 2 - n)
        parts.append(crease(-nA, -nB, two_sided[tA] & two_sided[tB]))
        stats["two_sided_creases"] = len(parts[-1]["n"])
    # -- rims: edges of one triangle
    g1 = np.flatnonzero(counts == 1)
    stats["boundary_edges"] = int(len(g1))
    if include_half_planes and len(g1):
        r1 = order[first[g1]]
        t1, p1, q1, u1 = edge_geometry(r1)
        n1 = tri_normal[t1]
        parts.append(dict(p=p1, q=q1, u0=u1, n0=n1, n1=-n1, n=np.full(len(g1), 2.0), tri0=t1,
                          tri1=np.full(len(g1), -1), half=np.ones(len(g1), dtype=bool),
                          va=a[r1], vb=b[r1]))
    seg = {k: np.concatenate([pt[k] for pt in parts]) for k in parts[0]}
    if len(seg["n"]) == 0:
        return _empty_wedges(stats)
    # KP edge vector of face 0 and endpoints ordered along it
    d = np.cross(seg["u0"], seg["n0"])
    d = _unit(d)
    fwd = np.einsum("ij,ij->i", seg["q"] - seg["p"], d) >= 0.0
    start = np.where(fwd[:, None], seg["p"], seg["q"])
    end = np.where(fwd[:, None], seg["q"], seg["p"])
    vs = np.where(fwd, seg["va"], seg["vb"])
    ve = np.where(fwd, seg["vb"], seg["va"])
    # stable order: by face-0 triangle
    srt = np.lexsort((seg["half"], seg["tri0"]))
    t0 = seg["tri0"][srt]
    tri1 = seg["tri1"][srt]
    W = dict(start=start[srt], end=end[srt], direction=d[srt], n=seg["n"][srt],
             normal0=seg["n0"][srt], normal1=seg["n1"][srt], tri0=t0, tri1=tri1,
             object_id=obj[t0], material0=mat[t0],
             material1=np.where(tri1 >= 0, mat[np.maximum(tri1, 0)], mat[t0]),
             half_plane=seg["half"][srt], n_segments=np.ones(len(t0), dtype=np.int64))
    vs, ve = vs[srt], ve[srt]
    if merge_collinear:
        W = _merge_collinear(W, vs, ve)
    W["length"] = _norm3(W["end"] - W["start"])
    out = {k: W[k] for k in _ARRAY_FIELDS}
    for k in ("tri0", "tri1", "object_id", "material0", "material1", "n_segments"):
        out[k] = out[k].astype(np.int32)
    return Wedges(**out, stats=stats)


def _merge_collinear(W, vs, ve):
    """Join segments that continue each other at a shared welded vertex (see extract_wedges)."""
    S = len(W["n"])
    verts = np.concatenate([vs, ve])
    segs = np.concatenate([np.arange(S), np.arange(S)])
    o = np.argsort(verts, kind="stable")
    verts, segs = verts[o], segs[o]
    ia, ib = [], []
    k = 1
    while k < len(verts):
        same = verts[:-k] == verts[k:]
        if not same.any():
            break
        ia.append(segs[:-k][same])
        ib.append(segs[k:][same])
        k += 1
    if not ia:
        return W
    ia, ib = np.concatenate(ia), np.concatenate(ib)
    ok = ia != ib
    ia, ib = ia[ok], ib[ok]

    def close(x, y):
        return _max_abs3(x - y) < _MERGE_TOL

    da, db = W["direction"][ia], W["direction"][ib]
    same_dir = close(da, db)
    flip_dir = close(da, -db)
    n0a, n1a, n0b, n1b = W["normal0"][ia], W["normal1"][ia], W["normal0"][ib], W["normal1"][ib]
    m0a, m1a, m0b, m1b = (W["material0"][ia], W["material1"][ia], W["material0"][ib],
                          W["material1"][ib])
    straight = same_dir & close(n0a, n0b) & close(n1a, n1b) & (m0a == m0b) & (m1a == m1b)
    swapped = flip_dir & close(n0a, n1b) & close(n1a, n0b) & (m0a == m1b) & (m1a == m0b)
    ok = (straight | swapped) & (W["object_id"][ia] == W["object_id"][ib])
    ok &= np.abs(W["n"][ia] - W["n"][ib]) < _MERGE_TOL
    ok &= W["half_plane"][ia] == W["half_plane"][ib]
    # the two segments lie on opposite sides of the shared vertex (not overlapping)
    mid_a = 0.5 * (W["start"][ia] + W["end"][ia])
    mid_b = 0.5 * (W["start"][ib] + W["end"][ib])
    sep = np.einsum("ij,ij->i", mid_b - mid_a, da)
    ext = 0.5 * (_norm3(W["end"][ia] - W["start"][ia]) + _norm3(W["end"][ib] - W["start"][ib]))
    ok &= np.abs(np.abs(sep) - ext) <= 1e-6 * (1.0 + ext)
    ia, ib = ia[ok], ib[ok]
    if len(ia) == 0:
        return W
    graph = coo_matrix((np.ones(len(ia), dtype=np.int8), (ia, ib)), shape=(S, S))
    _, labels = connected_components(graph, directed=False)
    G = labels.max() + 1
    rep = np.full(G, S, dtype=np.int64)
    np.minimum.at(rep, labels, np.arange(S))
    # endpoints of every member projected on its representative's direction
    P = np.concatenate([W["start"], W["end"]])
    g = np.concatenate([labels, labels])
    r = rep[g]
    t = np.einsum("ij,ij->i", P - W["start"][r], W["direction"][r])
    o = np.lexsort((t, g))
    bounds = np.searchsorted(g[o], np.arange(G))
    lo = o[bounds]
    hi = o[np.append(bounds[1:], len(o)) - 1]
    keep_order = np.argsort(rep)  # groups numbered by their first segment
    out = {k: v[rep][keep_order] for k, v in W.items()}
    out["start"] = P[lo][keep_order]
    out["end"] = P[hi][keep_order]
    out["n_segments"] = np.bincount(labels, minlength=G)[keep_order]
    return out


def free_wedges(wedges: Wedges, triangles, tri_object, tol: float = FLUSH_TOL_M,
                angle: float = FLUSH_ANGLE_RAD, probe: float = FLUSH_PROBE_M) -> Wedges:
    """The wedges clipped to the parts of their edges where both faces stand free.

    A face lies flush on another surface next to its edge where a triangle of *another*
    object lies in the face's plane (normals parallel or antiparallel within ``angle``,
    plane within ``tol`` of both the edge and the face ``probe`` metres from it) and
    covers the face there (to ``tol``): a box standing on a road, a box against a wall.
    Such an edge is no wedge in free space (the box's floor edge is the foot of a wall
    on the road, a concave corner), so the covered parts are cut away.  A wedge whose
    edge is free everywhere is returned as it is (the same row, bit for bit); one
    covered in parts gives a wedge per free piece (longer than ``probe``), in order along
    the edge; one covered everywhere is dropped.  Triangles of the wedge's own object
    never count (a mesh's own coincident sheets stay its business), nor do zero-area ones.
    ``stats`` gains ``flush_dropped`` and ``flush_clipped`` (wedges) and
    ``flush_tol_m``.  docs/wedges.md, "Edges flush on another surface"."""
    stats = dict(wedges.stats)
    stats.update(flush_dropped=0, flush_clipped=0, flush_tol_m=float(tol))
    W = len(wedges)
    tri = np.asarray(triangles, dtype=np.float64).reshape(-1, 3, 3)
    tri_obj = np.asarray(tri_object, dtype=np.int64).reshape(-1)
    if W == 0 or len(tri) == 0:
        return Wedges(**{k: getattr(wedges, k) for k in _ARRAY_FIELDS}, stats=stats)
    with np.errstate(invalid="ignore", divide="ignore"):
        tri_n, area2 = triangle_normals_and_double_areas(tri)
    usable = np.flatnonzero(np.isfinite(tri_n).all(axis=1) & (area2 > 0))
    if len(usable) == 0:
        return Wedges(**{k: getattr(wedges, k) for k in _ARRAY_FIELDS}, stats=stats)
    e = wedges.direction
    # each face of a wedge: its normal and its in-plane direction away from the edge
    # (t0 = n0 x e; face n: e x nn); a half-plane's two faces are one sheet
    faces_w = np.concatenate([np.arange(W), np.flatnonzero(~wedges.half_plane)])
    face_n = np.concatenate([wedges.normal0, wedges.normal1[~wedges.half_plane]])
    face_t = np.concatenate([np.cross(wedges.normal0, e),
                             np.cross(e[~wedges.half_plane],
                                      wedges.normal1[~wedges.half_plane])])
    f, t = _flush_pairs(wedges, faces_w, face_n, face_t, tri, tri_n, area2, usable, tol,
                        angle, probe)
    w = faces_w[f]
    keep = (tri_obj[t] != wedges.object_id[w]) & (
        np.abs(np.einsum("ij,ij->i", tri_n[t], face_n[f])) >= np.cos(angle))
    f, t, w = f[keep], t[keep], w[keep]
    lo, hi = _covered_spans(wedges.start[w], e[w], wedges.length[w], face_t[f], tri[t],
                            tri_n[t], tol, probe)
    hit = hi > lo
    if not hit.any():
        return Wedges(**{k: getattr(wedges, k) for k in _ARRAY_FIELDS}, stats=stats)
    w, lo, hi = w[hit], lo[hit], hi[hit]
    order = np.lexsort((lo, w))
    w, lo, hi = w[order], lo[order], hi[order]
    bounds = np.flatnonzero(np.diff(np.concatenate([[-1], w, [W]])))
    covered = dict.fromkeys(w.tolist())
    for a, b in zip(bounds[:-1], bounds[1:], strict=True):
        k = int(w[a])
        free, at = [], 0.0
        for s0, s1 in zip(lo[a:b].tolist(), hi[a:b].tolist(), strict=True):
            if s0 - at > probe:
                free.append((at, s0))
            at = max(at, s1)
        if wedges.length[k] - at > probe:
            free.append((at, float(wedges.length[k])))
        covered[k] = free
    # the free wedges' rows as they are; a covered wedge's free pieces in its place, in
    # order along its edge
    piece_rows, piece_lo, piece_hi = [], [], []
    for k, pieces in covered.items():
        if not pieces:
            stats["flush_dropped"] += 1
            continue
        stats["flush_clipped"] += 1
        for s0, s1 in pieces:
            piece_rows.append(k)
            piece_lo.append(s0)
            piece_hi.append(s1)
    whole = np.ones(W, dtype=bool)
    whole[np.fromiter(covered, dtype=np.int64, count=len(covered))] = False
    piece_rows = np.asarray(piece_rows, dtype=np.int64)
    rows = np.concatenate([np.flatnonzero(whole), piece_rows])
    # rows by wedge, a wedge's pieces in the order found (the stable sort keeps it)
    order = np.argsort(rows, kind="stable")
    rows = rows[order]
    out = {k: getattr(wedges, k)[rows] for k in _ARRAY_FIELDS}
    if len(rows):
        start_k = wedges.start[piece_rows]
        e_k = e[piece_rows]
        starts = np.concatenate([wedges.start[whole],
                                 start_k + np.asarray(piece_lo)[:, None] * e_k])[order]
        ends = np.concatenate([wedges.end[whole],
                               start_k + np.asarray(piece_hi)[:, None] * e_k])[order]
        out["start"], out["end"] = starts, ends
        length = _norm3(out["end"] - out["start"])
        out["length"] = np.where(whole[rows], out["length"], length)
    return Wedges(**out, stats=stats)


#: Planes shared by more triangles than this (a tessellated road) are searched by
#: position too (a k-d tree over their centroids), not triangle by triangle.
_FLUSH_GROUP_TREE = 64


def _flush_pairs(wedges, faces_w, face_n, face_t, tri, tri_n, area2, usable, tol, angle,
                 probe):
    """(face, triangle) candidate pairs of :func:`free_wedges`: triangles (of ``usable``)
    whose plane may lie within ``tol`` of the face's edge with its normal within
    ``angle`` (either orientation) and whose box, grown by what :func:`_covered_spans`
    allows (:func:`_grown_boxes`), meets the box of the face's probe line.

    Triangles are grouped by their exact plane (n, n.x / L), L the scene's largest
    coordinate; a k-d tree over those planes (and their reverses) finds each face's
    groups within the radius that a plane through the edge with its normal within
    ``angle`` can reach, and a group whose grown box misses the probe line's is left
    there.  A large group (a tessellated road) gives only its triangles whose centroid
    lies within reach of the edge (half its length, the group's largest centroid-vertex
    distance, the probe and tol, around its midpoint).  The boxes only drop pairs whose
    spans would be empty: the pairs that cover anything are those the planes and
    centroids find."""
    scale = max(float(np.abs(tri).max()), float(np.abs(wedges.start).max()),
                float(np.abs(wedges.end).max()), 1.0)
    tri_u = tri[usable]
    keys = np.column_stack([tri_n[usable], np.einsum("ij,ij->i", tri_n[usable],
                                                      tri_u[:, 0]) / scale])
    planes, group, counts = unique_rows(keys)
    G = len(planes)
    members = np.argsort(group, kind="stable")
    first = np.concatenate([[0], np.cumsum(counts)])
    face_key = np.column_stack([face_n, np.einsum("ij,ij->i", face_n,
                                                  wedges.start[faces_w]) / scale])
    # |n - m| <= 2 sin(angle/2); the offsets differ by that times |x| <= scale, plus the
    # tolerances, plus the tilt along the longest edge
    turn = 2.0 * np.sin(0.5 * angle)
    radius = 1.01 * (2.0 * turn + (tol + probe + np.sin(angle) * float(wedges.length.max()))
                     / scale)
    # |-k - p| = |k - (-p)|: the reversed planes are the faces' other orientation
    near = cKDTree(face_key).sparse_distance_matrix(cKDTree(np.concatenate([planes, -planes])),
                                                    radius, output_type="ndarray")
    f_g = near["i"].astype(np.int64)
    g_g = near["j"].astype(np.int64) % G
    # each usable triangle's box grown by its margin, each group's box around them
    grown_lo, grown_hi = _grown_boxes(tri_u, area2[usable], tol, scale)
    group_lo = np.minimum.reduceat(grown_lo[members], first[:-1], axis=0)
    group_hi = np.maximum.reduceat(grown_hi[members], first[:-1], axis=0)
    line_lo, line_hi = _probe_line_boxes(wedges, faces_w, face_t, probe)
    meets = ((group_lo[g_g] <= line_hi[f_g]) & (group_hi[g_g] >= line_lo[f_g])).all(axis=1)
    f_g, g_g = f_g[meets], g_g[meets]
    big = counts[g_g] > _FLUSH_GROUP_TREE
    # small groups: every member
    fs, gs = f_g[~big], g_g[~big]
    n = counts[gs]
    f_out = [np.repeat(fs, n)]
    t_out = [members[np.repeat(first[gs], n) + np.arange(n.sum())
                     - np.repeat(np.cumsum(n) - n, n)]]
    # large groups: members near the edge
    centroid = tri_u.mean(axis=1)
    reach = _norm3(tri_u - centroid[:, None]).max(axis=1)
    mid = 0.5 * (wedges.start + wedges.end)[faces_w]
    half = 0.5 * wedges.length[faces_w]
    for g in np.unique(g_g[big]):
        idx = members[first[g]:first[g + 1]]
        fg = f_g[big][g_g[big] == g]
        found = cKDTree(centroid[idx]).query_ball_point(
            mid[fg], half[fg] + float(reach[idx].max()) + probe + 2.0 * tol,
            return_sorted=False)
        sizes = np.fromiter((len(x) for x in found), dtype=np.int64, count=len(found))
        f_out.append(np.repeat(fg, sizes))
        t_out.append(idx[np.fromiter(itertools.chain.from_iterable(found), dtype=np.int64,
                                     count=int(sizes.sum()))])
    f, t = np.concatenate(f_out), np.concatenate(t_out)
    # the boxes meet where lo_t <= hi_f and -hi_t <= -lo_f on every axis: one gather each
    meets = (np.hstack([grown_lo, -grown_hi])[t]
             <= np.hstack([line_hi, -line_lo])[f]).all(axis=1)
    return f[meets], usable[t[meets]]


def _grown_boxes(tri, area2, tol, scale):
    """Boxes (lo, hi) (T,3) of triangles grown by the most that :func:`_covered_spans`
    lets a covered point lie outside them, plus a rounding slack of the scene's size.

    A point q it keeps is within ``tol`` of the triangle's plane and its projection
    within ``tol`` of each edge line (inside), so within tol / sin(theta/2) of the
    triangle at a vertex of angle theta; sin(theta) = 2A / (a b) for the sides a, b at
    it, so 1 / sin(theta/2) <= 2 / sin(theta) <= 2 l^2 / (2A), l the longest side. The
    margin is twice tol (1 + that)."""
    longest2 = np.max([_norm3(tri[:, (k + 1) % 3] - tri[:, k]) for k in range(3)],
                      axis=0) ** 2
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        margin = 2.0 * tol * (1.0 + 2.0 * longest2 / area2) + 1e-9 * scale
    margin = np.where(np.isfinite(margin), margin, np.inf)[:, None]
    v0, v1, v2 = tri[:, 0], tri[:, 1], tri[:, 2]
    return (np.minimum(np.minimum(v0, v1), v2) - margin,
            np.maximum(np.maximum(v0, v1), v2) + margin)


def _probe_line_boxes(wedges, faces_w, face_t, probe):
    """Boxes (lo, hi) (F,3) of the faces' probe lines (the edge moved ``probe`` into the
    face)."""
    start = wedges.start[faces_w] + probe * face_t
    end = start + wedges.length[faces_w][:, None] * wedges.direction[faces_w]
    return np.minimum(start, end), np.maximum(start, end)


def _covered_spans(start, direction, length, inward, tri, tri_n, tol, probe):
    """(lo, hi) (P,): the span of each edge (metres from its start) along which the
    triangle tri[i] covers the face: the probe line ``start + s direction + probe
    inward`` within the triangle (to ``tol``), and the triangle's plane within ``tol``
    of that line and of the edge itself.  Every condition is linear in s, so the span is
    one interval (empty where hi <= lo)."""
    lo = np.zeros(len(start))
    hi = np.asarray(length, dtype=np.float64).copy()
    line0 = start + probe * inward

    def at_least(alpha, beta, bound):
        # alpha + s beta >= -bound for s in [lo, hi]
        nonlocal lo, hi
        with np.errstate(invalid="ignore", divide="ignore"):
            s = -(alpha + bound) / beta
        lo = np.where(beta > 0, np.maximum(lo, s), lo)
        hi = np.where(beta < 0, np.minimum(hi, s), hi)
        hi = np.where((beta == 0) & (alpha + bound < 0), -np.inf, hi)

    slope = np.einsum("ij,ij->i", tri_n, direction)
    for origin in (start, line0):
        g = np.einsum("ij,ij->i", tri_n, origin - tri[:, 0])
        at_least(g, slope, tol)
        at_least(-g, -slope, tol)
    for k in range(3):
        v, nxt = tri[:, k], tri[:, (k + 1) % 3]
        inner = np.cross(tri_n, nxt - v)
        inner = inner / _norm3(inner)[:, None]
        at_least(np.einsum("ij,ij->i", inner, line0 - v),
                 np.einsum("ij,ij->i", inner, direction), tol)
    return lo, hi


# ---------------------------------------------------------------------------
# diffraction points


@dataclass(eq=False)
class DiffractionPoint:
    """Keller points of single diffractions (broadcast shape ``...``)."""

    point: np.ndarray  #: (...,3) float64 point Q on the edge line
    t: np.ndarray  #: (...,) float64 distance of Q from ``start`` along the edge, m
    inside: np.ndarray  #: (...,) bool, 0 <= t <= edge length (within ``tol``)
    length: np.ndarray  #: (...,) float64 |S - Q| + |Q - T|


def diffraction_point(source, target, start, end, tol: float = 0.0) -> DiffractionPoint:
    """Keller's diffraction point on straight edges, closed form, vectorised.

    All arguments broadcast against each other as ``(..., 3)`` arrays. With the edge
    line ``P(t) = start + t e`` (``e`` unit), the source at ``t_S`` along it and distance
    ``d_S`` from it (likewise ``t_T``, ``d_T``), unfolding the two half-planes through
    the line into one plane gives ``t* = (t_S d_T + t_T d_S) / (d_S + d_T)``, where the
    angles of the two segments with the edge are equal (``(Q-S).e/|Q-S| = (T-Q).e/|T-Q|``)
    and ``|S-Q| + |Q-T|`` is smallest. If both ends lie on the line, ``t*`` is their
    midpoint. ``inside`` flags ``-tol <= t* <= |end - start| + tol``; a point off the finite
    edge is still returned (on the line) so callers can reject or clamp.
    """
    S = np.asarray(source, dtype=np.float64)
    R = np.asarray(target, dtype=np.float64)
    A = np.asarray(start, dtype=np.float64)
    B = np.asarray(end, dtype=np.float64)
    edge = B - A
    L = np.linalg.norm(edge, axis=-1)
    e = edge / L[..., None]
    vs, vr = S - A, R - A
    ts = np.einsum("...i,...i->...", vs, e)
    tr = np.einsum("...i,...i->...", vr, e)
    ds = np.linalg.norm(vs - ts[..., None] * e, axis=-1)
    dr = np.linalg.norm(vr - tr[..., None] * e, axis=-1)
    den = ds + dr
    with np.errstate(invalid="ignore", divide="ignore"):
        t = np.where(den > 0, (ts * dr + tr * ds) / np.where(den > 0, den, 1.0),
                     0.5 * (ts + tr))
    Q = A + t[..., None] * e
    inside = (t >= -tol) & (t <= L + tol)
    length = np.linalg.norm(Q - S, axis=-1) + np.linalg.norm(R - Q, axis=-1)
    return DiffractionPoint(point=Q, t=t, inside=inside, length=length)


@dataclass(eq=False)
class MultiDiffraction:
    """Points of a chain of N diffractions (batch shape ``B``, possibly empty)."""

    points: np.ndarray  #: (...,N,3) float64
    t: np.ndarray  #: (...,N) float64, distances from each edge's start, m
    inside: np.ndarray  #: (...,N) bool, per edge
    all_inside: np.ndarray  #: (...,) bool
    length: np.ndarray  #: (...,) float64, total path length S -> Q1 -> ... -> QN -> T
    converged: np.ndarray  #: (...,) bool
    iterations: int


def _chain_length(S, R, O, E, t):
    P = O + t[..., None] * E
    nodes = np.concatenate([S[:, None], P, R[:, None]], axis=1)
    return np.linalg.norm(np.diff(nodes, axis=1), axis=-1).sum(axis=1)


def _chain_grad_hess(S, R, A, E, t, hessian=True):
    """Gradient (B,N) and Hessian (B,N,N) of the chain length in the edge parameters."""
    Bsz, N = t.shape
    P = A + t[..., None] * E
    nodes = np.concatenate([S[:, None], P, R[:, None]], axis=1)  # (B,N+2,3)
    d = np.diff(nodes, axis=1)  # (B,N+1,3): segment j from node j to node j+1
    rr = np.maximum(np.linalg.norm(d, axis=-1), 1e-300)
    u = d / rr[..., None]
    # dL/dt_k = e_k.u_k - e_k.u_{k+1}: edge k is node k+1, between segments k and k+1
    g = np.einsum("bki,bki->bk", E, u[:, :-1]) - np.einsum("bki,bki->bk", E, u[:, 1:])
    if not hessian:
        return g, None
    # d2|d_j| = (I - u_j u_j^T)/|d_j|, d_j = P_{j+1} - P_j: + e_j (edge j), - e_{j-1}
    H = np.zeros((Bsz, N, N))
    for j in range(N + 1):
        uj, rj = u[:, j], rr[:, j]
        ends = [(k, sgn) for k, sgn in ((j - 1, -1.0), (j, 1.0)) if 0 <= k < N]
        for k1, s1 in ends:
            for k2, s2 in ends:
                e1, e2 = E[:, k1], E[:, k2]
                m = (np.einsum("bi,bi->b", e1, e2)
                     - np.einsum("bi,bi->b", e1, uj) * np.einsum("bi,bi->b", e2, uj)) / rj
                H[:, k1, k2] += s1 * s2 * m
    return g, H


def multi_diffraction_points(source, target, edges_start, edges_end, tol: float = 0.0,
                             max_iter: int = 100) -> MultiDiffraction:
    """Diffraction points on a chain of N straight edges (N >= 1, typically 2 or 3).

    ``source``/``target`` are ``(3,)`` or ``(B,3)``; ``edges_start``/``edges_end`` are
    ``(N,3)`` or ``(B,N,3)``. The path ``S -> P1(t1) -> ... -> PN(tN) -> T`` with
    ``Pk(t) = start_k + t e_k`` is a sum of norms of affine functions of ``t``, hence
    convex; its minimum (the generalised Keller condition: at every edge the incoming and
    outgoing segments make equal angles with it) is found by damped Newton in float64 on
    the analytic gradient and tridiagonal Hessian, from the single-edge Keller points (or
    edge midpoints) as start. The optimum is on the infinite lines; ``inside`` flags each
    point within its finite edge (``tol`` metres of slack).
    """
    S = np.asarray(source, dtype=np.float64)
    R = np.asarray(target, dtype=np.float64)
    A = np.asarray(edges_start, dtype=np.float64)
    Bn = np.asarray(edges_end, dtype=np.float64)
    batched = A.ndim == 3 or S.ndim == 2 or R.ndim == 2
    if A.ndim == 2:
        A, Bn = A[None], Bn[None]
    Bsz = max(len(A), S.reshape(-1, 3).shape[0], R.reshape(-1, 3).shape[0])
    S = np.broadcast_to(S.reshape(-1, 3), (Bsz, 3))
    R = np.broadcast_to(R.reshape(-1, 3), (Bsz, 3))
    A = np.broadcast_to(A, (Bsz,) + A.shape[1:])
    Bn = np.broadcast_to(Bn, (Bsz,) + Bn.shape[1:])
    N = A.shape[1]
    edge = Bn - A
    L = np.linalg.norm(edge, axis=-1)
    E = edge / L[..., None]
    scale = np.maximum(np.linalg.norm(R - S, axis=-1), L.max(axis=1)) + 1.0

    # start: Keller points of each edge between its neighbours' edge midpoints
    mid = 0.5 * (A + Bn)
    prev = np.concatenate([S[:, None], mid[:, :-1]], axis=1)
    nxt = np.concatenate([mid[:, 1:], R[:, None]], axis=1)
    t = diffraction_point(prev, nxt, A, Bn).t
    t = np.where(np.isfinite(t), t, 0.5 * L)

    f = _chain_length(S, R, A, E, t)
    active = np.ones(Bsz, dtype=bool)
    it = 0
    eye = np.eye(N)
    for it in range(1, max_iter + 1):  # noqa: B007
        idx = np.flatnonzero(active)
        if len(idx) == 0:
            break
        g, H = _chain_grad_hess(S[idx], R[idx], A[idx], E[idx], t[idx])
        gnorm = np.max(np.abs(g), axis=1)
        done = gnorm < 1e-15 * N
        lam = 1e-14 * (np.trace(H, axis1=1, axis2=2)[:, None, None] + 1e-300) / N
        try:
            step = -np.linalg.solve(H + lam * eye, g[..., None])[..., 0]
        except np.linalg.LinAlgError:
            step = -g * scale[idx, None]
        bad = ~np.all(np.isfinite(step), axis=1) | (np.einsum("bk,bk->b", step, g) >= 0)
        step[bad] = -g[bad] * scale[idx][bad, None]
        # backtracking line search (Armijo), vectorised
        alpha = np.ones(len(idx))
        accepted = np.zeros(len(idx), dtype=bool)
        f0 = f[idx]
        slope = np.einsum("bk,bk->b", step, g)
        t_new = t[idx].copy()
        f_new = f0.copy()
        first_try = True
        for _ in range(60):
            pend = ~accepted
            if not pend.any():
                break
            sel = idx[pend]
            cand = t[sel] + alpha[pend, None] * step[pend]
            fc = _chain_length(S[sel], R[sel], A[sel], E[sel], cand)
            good = fc <= f0[pend] + 1e-4 * alpha[pend] * slope[pend]
            if first_try:
                # near the optimum f stops resolving the decrease (it is quadratic in the
                # step): accept the full Newton step when it shrinks the gradient instead
                gc, _ = _chain_grad_hess(S[sel], R[sel], A[sel], E[sel], cand, hessian=False)
                flat = fc <= f0[pend] * (1.0 + 1e-14)
                good |= flat & (np.max(np.abs(gc), axis=1) < 0.5 * gnorm[pend])
                first_try = False
            pi = np.flatnonzero(pend)
            acc = pi[good]
            t_new[acc] = cand[good]
            f_new[acc] = fc[good]
            accepted[acc] = True
            alpha[pend] *= 0.5
        small = np.max(np.abs(t_new - t[idx]), axis=1) <= 4e-16 * (
            np.max(np.abs(t[idx]), axis=1) + scale[idx])
        t[idx] = t_new
        f[idx] = f_new
        fin = done | small | ~accepted
        active[idx[fin]] = False
    g, _ = _chain_grad_hess(S, R, A, E, t, hessian=False)
    # the Keller condition: the cosines of each edge with its two segments agree
    converged = np.all(np.abs(g) <= 1e-9, axis=1)
    P = A + t[..., None] * E
    inside = (t >= -tol) & (t <= L + tol)
    res = MultiDiffraction(points=P, t=t, inside=inside, all_inside=inside.all(axis=1),
                           length=f, converged=converged, iterations=it)
    if not batched:
        res = MultiDiffraction(points=P[0], t=t[0], inside=inside[0],
                               all_inside=res.all_inside[0], length=f[0],
                               converged=converged[0], iterations=it)
    return res
