"""Specular paths: candidate search on the device, exact geometry on the host.

Stages (each plain arrays in and out):

1. :func:`launch_directions` - a Fibonacci lattice over the transmit
   pattern's support (directions where its gain is non-zero).
2. :func:`reflection_sequences` - the OpenCL kernel ``trace_reflections``
   follows every ray through up to ``max_order`` specular bounces and
   returns the faces it reflects off, in order.
3. :func:`unique_candidates` - every prefix of every sequence is a
   candidate for a path to any receiver (the approach of Sionna RT's
   shooting-and-bouncing candidate stage); duplicates go.
4. :func:`image_points` - the image method in float64 gives the exact
   reflection points of a candidate for one tx/rx pair and rejects those
   whose line to an image misses the plane between its ends (wrong side).
5. :func:`confirm_paths` - one closest-hit query per segment: the segment
   toward a reflection point must first meet exactly that face there (so the
   point lies inside the face and nothing blocks it), and the last segment
   must reach the receiver unobstructed.

The ray density only decides which candidates are proposed; every kept path
is exact, and the set stops growing once the lattice is dense enough.
"""

from __future__ import annotations

import warnings

import numpy as np

from clradcom.device.raycast import RayCaster, make_rays, spawn_origins
from clradcom.errors import SurfaceContactWarning
from clradcom.geometry.triangles import triangle_cross_products, triangle_normals

#: A segment counts as reaching its reflection point when the first thing it
#: meets is that face within this many metres (plus float32 resolution).
CONFIRM_TOL_M = 1e-3
#: A reflection point counts as inside a triangle when it lies at most this far
#: outside an edge, relative to 1 + its largest coordinate (float64 rounding).
INSIDE_TOL_REL = 1e-9
#: An antenna this close to a face's plane (relative, as INSIDE_TOL_REL) is on it.
CONTACT_TOL_REL = 1e-9


def fibonacci_cap(n: int, half_angle: float = np.pi) -> np.ndarray:
    """n nearly uniform unit vectors (golden-angle spiral) within half_angle of +x.

    half_angle = pi covers the whole sphere. Uniform steps in x = cos(angle
    from +x) give equal areas, so the lattice density is the same everywhere.
    """
    if n < 1:
        raise ValueError(f"need at least one direction, got n={n}")
    k = np.arange(n, dtype=np.float64)
    x = 1.0 - (1.0 - np.cos(half_angle)) * (k + 0.5) / n
    r = np.sqrt(np.maximum(1.0 - x * x, 0.0))
    phi = k * np.pi * (3.0 - np.sqrt(5.0))
    return np.stack([x, r * np.cos(phi), r * np.sin(phi)], axis=1)


def fibonacci_sphere(n: int) -> np.ndarray:
    """n nearly uniform unit vectors over the whole sphere, float64 (n, 3)."""
    return fibonacci_cap(n, np.pi)


def launch_directions(n_rays: int, gain_fn=None, orientation=None) -> np.ndarray:
    """About n_rays world directions covering where the pattern radiates.

    gain_fn maps local unit directions (K,3) to gain; orientation (3,3) has
    the antenna's local axes as columns. The lattice is laid over the
    smallest cap around boresight (+x) that holds the pattern's support, at
    the density that puts about n_rays inside the support, so a narrow beam
    costs no more than a wide one.
    """
    if gain_fn is None:
        return fibonacci_sphere(n_rays)
    probe = fibonacci_sphere(1 << 16)
    inside = np.asarray(gain_fn(probe)) > 0
    if not inside.any():
        raise ValueError("the antenna pattern has zero gain everywhere (or in a region "
                         "narrower than 0.01 sr)")
    spacing = np.sqrt(4.0 * np.pi / len(probe))
    half_angle = min(np.pi, float(np.arccos(probe[inside, 0].min())) + 2.0 * spacing)
    in_cap = probe[:, 0] >= np.cos(half_angle)
    share = float(inside[in_cap].mean())
    local = fibonacci_cap(int(np.ceil(n_rays / share)), half_angle)
    local = local[np.asarray(gain_fn(local)) > 0]
    if orientation is None:
        return local
    return local @ np.asarray(orientation, dtype=np.float64).T


def reflection_sequences(caster: RayCaster, tri_face, origin, directions, max_order: int,
                         batch: int = 1 << 20) -> np.ndarray:
    """(R, max_order) int32 face ids of each ray's specular bounces, -1 after it escapes."""
    import pyopencl as cl

    if max_order < 1:
        return np.zeros((len(directions), 0), dtype=np.int32)
    rt = caster.runtime
    kernel = rt.kernel("reflect.cl", "trace_reflections")
    face_buf = rt.to_device(np.asarray(tri_face, dtype=np.int32))
    o = np.asarray(origin, dtype=np.float64)
    out = np.empty((len(directions), max_order), dtype=np.int32)
    for start in range(0, len(directions), batch):
        d = np.zeros((min(batch, len(directions) - start), 4), dtype=np.float32)
        d[:, :3] = directions[start:start + len(d)]
        n = len(d)
        d_buf = rt.to_device(d)
        o_buf = rt.empty(n * max_order * 4)
        kernel(rt.queue, (n,), None, caster.device_nodes, caster.device_verts,
               caster.device_tri_index, face_buf, np.float32(o[0]), np.float32(o[1]),
               np.float32(o[2]), d_buf, np.int32(max_order), o_buf, np.int32(n))
        chunk = np.empty((n, max_order), dtype=np.int32)
        cl.enqueue_copy(rt.queue, chunk, o_buf)
        out[start:start + n] = chunk
    return out


def unique_candidates(face_seq: np.ndarray) -> dict[int, np.ndarray]:
    """Unique face sequences of each length 1..max_order from all prefixes.

    Sequences that reflect off one plane twice in a row are cut there: a
    planar face cannot do that, so the rest of such a ray is a float32
    artefact of re-hitting a neighbouring triangle of the face it left.
    Rays repeat each other massively, so whole rows are de-duplicated first
    (one sort) and prefixes are taken from the few unique rows.
    """
    seq = np.ascontiguousarray(face_seq, dtype=np.int32)
    k_max = seq.shape[1]
    if k_max > 1:
        repeat = np.zeros(seq.shape, dtype=bool)
        repeat[:, 1:] = (seq[:, 1:] == seq[:, :-1]) & (seq[:, 1:] >= 0)
        cut = np.cumsum(repeat, axis=1) > 0
        seq = np.where(cut, -1, seq)
    if len(seq):
        rows = seq.view(np.dtype((np.void, seq.dtype.itemsize * k_max))).ravel()
        seq = seq[np.unique(rows, return_index=True)[1]]
    out: dict[int, np.ndarray] = {}
    for k in range(1, k_max + 1):
        pref = seq[seq[:, k - 1] >= 0, :k]
        out[k] = np.unique(pref, axis=0) if len(pref) else np.zeros((0, k), np.int32)
    return out


def mirror(points, normal, offset):
    """Reflect points (C,3) across planes n.x = d (n unit), all float64."""
    dist = np.einsum("ij,ij->i", points, normal) - offset
    return points - 2.0 * dist[:, None] * normal


def image_points(tx, rx, normals, offsets, seqs: np.ndarray):
    """Exact reflection points for candidate face sequences, by the image method.

    tx, rx: (3,) positions; normals (F,3) unit and offsets (F,) of the
    faces' planes; seqs (C,k) face ids. Returns points (C, k+2, 3) - tx, the
    k reflection points, rx - and a mask of candidates whose every point lies
    strictly between its neighbours' image line ends (so each reflection
    happens on the side both segments are on).
    """
    seqs = np.asarray(seqs)
    C, k = seqs.shape
    tx = np.asarray(tx, dtype=np.float64)
    rx = np.asarray(rx, dtype=np.float64)
    points = np.empty((C, k + 2, 3))
    points[:, 0] = tx
    points[:, -1] = rx
    ok = np.ones(C, dtype=bool)
    if C == 0:
        return points, ok
    images = np.empty((C, k, 3))
    current = np.broadcast_to(tx, (C, 3))
    for i in range(k):
        n = normals[seqs[:, i]]
        d = offsets[seqs[:, i]]
        current = mirror(current, n, d)
        images[:, i] = current
    target = np.broadcast_to(rx, (C, 3)).copy()
    for i in range(k - 1, -1, -1):
        n = normals[seqs[:, i]]
        d = offsets[seqs[:, i]]
        line = images[:, i] - target
        denom = np.einsum("ij,ij->i", line, n)
        with np.errstate(divide="ignore", invalid="ignore"):
            s = (d - np.einsum("ij,ij->i", target, n)) / denom
        good = np.isfinite(s) & (s > 1e-12) & (s < 1.0 - 1e-12)
        ends = ([("receiver", rx)] if i == k - 1 else []) + (
            [("transmitter", tx)] if i == 0 else [])
        for what, point in ends if not good.all() else ():
            _warn_surface_contact(point, what, n, d, seqs[:, i], ok & ~good)
        ok &= good
        s = np.where(good, s, 0.5)
        target = target + s[:, None] * line
        points[:, i + 1] = target
    return points, ok


def _warn_surface_contact(point, what, normals, offsets, faces, dropped):
    """Warn when candidates were dropped because an antenna lies on their face's plane:
    the reflection point then coincides with the antenna, and the path with the line
    of sight (geometrical optics has no wave guided along the surface)."""
    dist = np.abs(normals @ point - offsets)
    on = dropped & (dist <= CONTACT_TOL_REL * (1.0 + np.abs(point).max()))
    if on.any():
        warnings.warn(f"the {what} at {point.tolist()} lies on the plane of face(s) "
                      f"{np.unique(faces[on]).tolist()}: the reflection off it coincides with "
                      "the line of sight and the image method cannot place it; the tracer "
                      "adds it as the limit of the merging rays where the line of sight "
                      "exists (tracer.surface_contact_paths)", SurfaceContactWarning,
                      stacklevel=5)


def _edge_distances(points, tri):
    """(C, 3) signed in-plane distances (m) of points inside the three edges of their
    triangles (C, 3, 3): all >= 0 inside, negative outside."""
    n = triangle_normals(tri)
    out = np.empty((len(points), 3))
    for j in range(3):
        a, b = tri[:, j], tri[:, (j + 1) % 3]
        e = b - a
        out[:, j] = np.einsum("ij,ij->i", np.cross(e, points - a), n) / np.linalg.norm(e, axis=1)
    return out


def containing_triangles(points, faces, prims, triangles, tri_face):
    """The triangle of face ``faces[c]`` that holds ``points[c]`` in float64, or -1.

    ``prims`` is a first guess per point (the float32 hit, -1 for none).  The float32
    cast alone lets a reflection point up to its rounding (tens of um at 1 km) outside a
    face's rim count as inside, and one inside count as outside; the UTD field of the
    rim assumes the exact side, so the total field jumps there.  Decided here in
    float64, the reflection appears and disappears where the edge diffraction
    expects it.
    """
    points = np.asarray(points, dtype=np.float64)
    faces = np.asarray(faces)
    out = np.full(len(points), -1, dtype=np.int32)
    if len(points) == 0:
        return out
    min_dist = -INSIDE_TOL_REL * (1.0 + np.abs(points).max(axis=1))
    prims = np.asarray(prims)
    guess = (prims >= 0) & (tri_face[np.maximum(prims, 0)] == faces)
    g = np.flatnonzero(guess)
    inside = np.all(_edge_distances(points[g], triangles[prims[g]]) >= min_dist[g, None], axis=1)
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
            dist = _edge_distances(p, t).reshape(len(sel), len(cand), 3)
            inside = np.all(dist >= min_dist[sel, None, None], axis=2)
            hit = inside.any(axis=1)
            out[sel[hit]] = cand[np.argmax(inside[hit], axis=1)]
    return out


def blocked_in_float64(caster: RayCaster, tri_face, start, seg, tmax, max_rounds: int = 4):
    """Re-decide segments a float32 any-hit cast called blocked: (S,) bool.

    A segment that passes an edge closer than float32 resolution (tens of um at 1 km) may be
    "blocked" by a triangle it misses.  On a shadow boundary that flips the line of
    sight off while the UTD field of the edge, computed in float64, is still on its lit
    side: the total field jumps.  Each round takes the closest float32 hit, crosses the
    segment with that triangle's plane in float64 and keeps the segment blocked if the
    crossing lies inside the triangle's face (:func:`containing_triangles`, so a ray
    through a seam of a tessellated wall stays blocked); otherwise it looks past that
    triangle.  Segments still undecided after ``max_rounds`` stay blocked.
    """
    start = np.asarray(start, dtype=np.float64)
    seg = np.asarray(seg, dtype=np.float64)
    tmax = np.broadcast_to(np.asarray(tmax, dtype=np.float64), (len(start),))
    blocked = np.ones(len(start), dtype=bool)
    todo = np.arange(len(start))
    tmin = np.zeros(len(start))
    ignore = np.full(len(start), -1, dtype=np.int32)
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
        tmin[todo] = np.maximum(tmin[todo], t_hit.astype(np.float64) * (1.0 - 1e-6))
        ignore[todo] = prim
    return blocked


def confirm_paths(caster: RayCaster, tri_face, face_normals, points: np.ndarray,
                  seqs: np.ndarray, ok: np.ndarray | None = None):
    """Mask of candidate paths whose every segment is confirmed by a ray cast.

    Returns (keep (C,) bool, triangles (C, k) int32): the scene triangle each
    kept path's reflection points lie in (-1 where not confirmed).

    Segment i runs from points[:, i] to points[:, i+1]. Toward a reflection
    point it must first meet that point's face at the point (within
    CONFIRM_TOL_M), or, where the float32 cast slips past the face's rim,
    nothing at all: that proves nothing stands in between. That the point lies
    inside the face, not just in its plane, is decided in float64
    (:func:`containing_triangles`). The last segment must reach
    the receiver with nothing in between. Segments leave reflection points
    from just off the face, on the side they leave into.
    """
    tri_face = np.asarray(tri_face)
    C, k2, _ = points.shape
    k = k2 - 2
    keep = np.ones(C, dtype=bool) if ok is None else ok.copy()
    triangles = np.full((C, k), -1, dtype=np.int32)
    if C == 0:
        return keep, triangles
    idx = np.flatnonzero(keep)
    for i in range(k + 1):
        if len(idx) == 0:
            break
        start = points[idx, i]
        end = points[idx, i + 1]
        seg = end - start
        length = np.linalg.norm(seg, axis=1)
        if i > 0:
            start = spawn_origins(start, face_normals[seqs[idx, i - 1]], seg)
            seg = end - start
        slack = (CONFIRM_TOL_M + 1e-6 * np.abs(end).max(axis=1)) / np.maximum(length, 1e-12)
        if i < k:
            rays = make_rays(start, seg, tmin=0.0, tmax=1.0 + 2.0 * slack)
            hits = caster.closest_hit(rays)
            hit_face = np.where(hits["prim"] >= 0, tri_face[np.maximum(hits["prim"], 0)], -1)
            # reached: the face itself at the point, or (a float32 miss just past its rim)
            # nothing at all; whether the point is inside the face is decided in float64
            reached = ((hit_face == seqs[idx, i]) & (np.abs(hits["t"] - 1.0) <= slack)) | (
                hits["prim"] < 0)
            tri = np.full(len(idx), -1, dtype=np.int32)
            tri[reached] = containing_triangles(end[reached], seqs[idx[reached], i],
                                                hits["prim"][reached], caster.triangles,
                                                tri_face)
            good = tri >= 0
            triangles[idx, i] = tri
        else:
            rays = make_rays(start, seg, tmin=0.0, tmax=1.0 - slack)
            blocked = caster.occluded(rays)
            if blocked.any():
                blocked[blocked] = blocked_in_float64(caster, tri_face, start[blocked],
                                                      seg[blocked], 1.0 - slack[blocked])
            good = ~blocked & (length > 0)
        keep[idx[~good]] = False
        idx = idx[good]
    triangles[~keep] = -1
    return keep, triangles
