"""Shooting and bouncing rays with physical optics (SBR-PO): multi-bounce target returns.

The single-bounce PO facet term (:mod:`clradcom.mechanisms.physical_optics`) gives each
lit facet its true strength, but a dihedral or trihedral corner returns through two or three
reflections.  SBR (Ling, Chou & Lee, IEEE TAP 37(2) 1989, "Shooting and bouncing
rays: calculating the RCS of an arbitrarily shaped cavity") shoots a dense grid of
ray tubes at the target and follows each tube with GO (the material reflection dyads
of :mod:`clradcom.physics.em`, spreading of the spherical wave of the image source).  At
every bounce it radiates the PO current of the tube's footprint toward the
receiver, rather than over one exit aperture, since an open target such as a car has
none.  docs/po.md gives the formulas and the measured accuracy.

**Launch.** Tubes leave the transmitter through *windows* (:class:`TubeWindows`): square
grids of pitch ``spacing`` on a plane perpendicular to the line of sight, one per SBR
object (its silhouette) and one per mirror image of the object in a large planar face
of the environment (the road, a facade: the tubes that reach the object through one
reflection there), each covering only the blocks of cells that the object's (image's)
projected triangles overlap (:func:`clradcom.geometry.silhouette.block_coverage`).  A
direction that several windows cover belongs to the first of them, so every direction
is shot once.  Tubes are enumerated by index and never held all at once: the device
engine generates them in the kernel, batch by batch, so there is no cap on their number
and the work grows with the lit area in square wavelengths.

Here the tubes radiate from their 2nd bounce on (``first_bounce=2``): the first
bounce is the exact facet integral of
:func:`clradcom.mechanisms.physical_optics.po_paths`, so a hybrid of the two counts every
bounce exactly once.

Tube contribution at bounce m, hit point p on a facet with lit-side normal n, incident
direction k_i, unfolded length L_in = |tx -> ... -> p|, transfer chain C of the m-1
earlier reflection dyads (C = I - k0 k0^T for m = 1), receiver at R_r along s::

    T = -(j k / 2 pi) L/(L_in R_r) (I - s s^T) [n x (k_i x .)] C  I_fp(q),  L = L_in + R_r
    I_fp = |e1' x e2'| sinc(q.e1'/2) sinc(q.e2'/2),  q = k (s - k_i)

with e1', e2' the tube's square cross-section (side sqrt(dOmega) L_in, edges carried
through the mirrors) projected along k_i onto the facet: the exact radiation integral
of a parallelogram footprint with a linear phase.  This is :func:`clradcom.physics.po.po_transfer`
with the facet replaced by the footprint and 1/R_t by the image source's 1/L_in.  A footprint
on a non-PEC facet radiates the currents of the incident plus reflected field instead,
(I - s s^T)[n x (k_i x .)] -> K/2 of :func:`clradcom.physics.po.penetrable_po_operator` with
the material's reflection dyad at the tube's incidence.  Every reflection in C is the
material's full specular dyad: Fresnel x roughness x sqrt(1 - S^2)
(:func:`clradcom.physics.em.material_reflection_dyad`).

**Two engines, one result.**  ``geom.engine == "device"`` follows and radiates the tubes in
``kernels/sbr.cl`` (:mod:`clradcom.device.sbr`, :func:`device_block_sums`); ``"host"`` does
the same in numpy over ray casts (:func:`shoot_tubes`, :func:`_radiate`,
:func:`host_block_sums`), the reference the device is tested against.  Both give
:class:`BlockSums` (the footprints' polarimetric matrices summed per launch block,
bounce, receiver and face sequence), which :func:`block_paths` turns into paths the same
way.
"""

from __future__ import annotations

import dataclasses
import functools
import warnings
import weakref
from dataclasses import dataclass

import numpy as np

from clradcom.device import engines
from clradcom.device import sbr as device_sbr
from clradcom.device import silhouette as device_silhouette
from clradcom.device.raycast import make_rays, spawn_origins
from clradcom.device.visibility import surface_sees
from clradcom.errors import ArgumentError
from clradcom.geometry.rows import unique_rows
from clradcom.geometry.silhouette import BLOCK, cover_xy_many
from clradcom.geometry.triangles import (
    triangle_double_areas,
    triangle_normals,
)
from clradcom.paths import InteractionType, Paths
from clradcom.physics import em
from clradcom.physics.po import penetrable_po_operator, sinc
from clradcom.physics.vectors import orthonormal_frame

__all__ = ["BlockSums", "SbrTubes", "TubeGrid", "TubeHits", "TubeWindows", "block_paths",
           "bounding_sphere", "device_block_sums", "host_block_sums", "launch_tubes",
           "launch_windows", "sbr_paths", "shoot_sbr", "shoot_tubes", "window_tubes"]

#: Planar faces of the environment at least this large (m^2) mirror an SBR object: tubes
#: aimed at the object's image there reach it after one reflection off the face.
MIRROR_MIN_AREA_M2 = 1.0
#: A window's triangles must lie at least this fraction of the window's distance in front
#: of the transmitter (a mirror image seen at grazing angles gets no window).
MIN_DEPTH_FRACTION = 0.2
#: A window covers triangles whose bounding sphere keeps tx this many radii from its
#: centre (so all of them lie at least MIN_DEPTH_FRACTION in front); larger groups split.
CHUNK_CLEARANCE = 1.25
#: Tubes per host batch of the reference engine (bounds its memory).
HOST_BATCH_TUBES = 1 << 20
#: The spacing rule (:func:`spacing_for_accuracy`): dB of corner error per unit of
#: pitch / feature size.  Tubes count whole where their centre ray lands, so along each
#: rim of a corner's aperture the count is off by less than one row of tubes in all: an
#: aperture of area A and perimeter P errs by < 20 log10(e) (P l / 2A) s / l dB at pitch
#: s, 14.8 s / l for the square dihedral (A = sqrt(2) l^2), 12.3 s / l for the square
#: trihedral (docs/po.md; tools/sbr_pitch.py measures up to 0.74 of the target); 18 keeps a
#: margin over both for less square faces...
ERROR_DB_PER_PITCH = 18.0
#: ... the share of an object's area in faces smaller than its feature size ...
FEATURE_AREA_SHARE = 0.1
#: the accuracy targets (dB) the rule holds for: below, the PO approximations' own
#: 0.2 dB (plate sidelobes beating against a corner) dominate; above, pitch / feature
#: passes 0.1, where the stair-stepping stops growing linearly
ACCURACY_DB_RANGE = (0.25, 2.0)
#: ... and the pitch's bounds in wavelengths: at least the rule's pitch for a corner of
#: one wavelength at the tightest target (a smaller corner is beyond PO's reach anyway;
#: the floor bounds the tubes of an object of tiny faces); coarser than the cap lets a
#: tube straddle too much of a curved surface
MIN_SPACING_WAVELENGTHS = ACCURACY_DB_RANGE[0] / ERROR_DB_PER_PITCH
MAX_SPACING_WAVELENGTHS = 4.0

@dataclass
class TubeGrid:
    """Ray tubes leaving one transmitter: unit directions (R,3), solid angle (R,) and
    two unit edge vectors (R,3) of each tube's square cross-section."""

    directions: np.ndarray
    solid_angle: np.ndarray
    edge1: np.ndarray
    edge2: np.ndarray

    def __len__(self) -> int:
        return len(self.directions)


def launch_tubes(tx_pos, spheres, spacing_m: float, max_rays: int = 4_000_000) -> TubeGrid:
    """Square grids of ray tubes from tx over bounding spheres (centre, radius).

    Each sphere gets a grid of pitch ``spacing_m`` on the plane through its centre
    perpendicular to the line of sight, covering the sphere's tangent cone; a ray
    whose direction already lies in an earlier sphere's cone belongs to that grid only,
    so every direction is shot once.  Tube solid angle: spacing^2 cos^3(alpha) / D^2
    (alpha off the grid's axis, D the centre's distance).  Spheres that hold tx are
    refused (a radar inside its own car's bounding sphere: use "both" for that object).
    """
    tx = np.asarray(tx_pos, dtype=np.float64)
    spacing = float(spacing_m)
    if not (np.isfinite(spacing) and spacing > 0):
        raise ArgumentError(f"spacing_m must be a positive number, got {spacing_m!r}")
    dirs, dom, e1s, e2s = [], [], [], []
    cones = []
    total = 0
    for centre, radius in spheres:
        c = np.asarray(centre, dtype=np.float64)
        r = float(radius)
        d_vec = c - tx
        D = float(np.linalg.norm(d_vec))
        if D <= r * 1.001:
            raise ArgumentError(f"the transmitter at {tx.tolist()} lies inside the bounding "
                             f"sphere (centre {c.tolist()}, radius {r:.3g} m) of an SBR "
                             f"object; give that object optics = \"both\"")
        w = d_vec / D
        a, b = orthonormal_frame(w)
        rho = r * D / np.sqrt(D * D - r * r) + spacing
        n = int(np.ceil(rho / spacing))
        total += (2 * n + 1) ** 2
        if total > max_rays:
            raise ArgumentError(f"SBR needs more than max_rays = {max_rays} ray tubes "
                             f"(spacing {spacing:.3g} m over a sphere of radius {r:.3g} m); "
                             f"use a coarser spacing")
        g = np.arange(-n, n + 1) * spacing
        x, y = np.meshgrid(g, g, indexing="ij")
        x, y = x.ravel(), y.ravel()
        inside = x * x + y * y <= rho * rho
        x, y = x[inside], y[inside]
        v = D * w + x[:, None] * a + y[:, None] * b
        dist = np.linalg.norm(v, axis=1)
        d = v / dist[:, None]
        cos_a = D / dist
        keep = np.ones(len(d), dtype=bool)
        for w_j, cos_j in cones:
            keep &= d @ w_j < cos_j
        d, cos_a = d[keep], cos_a[keep]
        cones.append((w, np.sqrt(1.0 - (r / D) ** 2)))
        e1 = a - (d @ a)[:, None] * d
        e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
        dirs.append(d)
        dom.append(spacing * spacing * cos_a**3 / (D * D))
        e1s.append(e1)
        e2s.append(np.cross(d, e1))
    if not dirs:
        z = np.zeros((0, 3))
        return TubeGrid(z, np.zeros(0), z, z)
    return TubeGrid(np.concatenate(dirs), np.concatenate(dom), np.concatenate(e1s),
                    np.concatenate(e2s))


@dataclass
class TubeWindows:
    """Where one transmitter's SBR tubes leave through: W windows, B covered blocks.

    Window w is the plane at ``distance[w]`` along the unit ``axis[w]`` from ``tx``, with
    in-plane unit vectors ``u[w]``, ``v[w]`` and cell pitch ``spacing[w]``; cell (i, j)
    is centred on x = (i + 1/2) spacing, y = (j + 1/2) spacing: the window's axis, aimed
    at the centre of what it covers, where a symmetric object's folds and apex lie,
    falls between tubes (a tube through a fold ends there and its area would be lost).
    Its blocks of BLOCK x BLOCK cells start at cell ``cell0[w]`` and span ``shape[w]``
    blocks; ``masks[mask_offset[w]:...]``
    (row-major over ``shape[w]``) marks the covered ones.  ``object_id[w]`` is the SBR
    object it aims at, ``mirror_face[w]`` the face it is mirrored in (-1: direct).
    Covered block b is (``block_window[b]``, ``block_i[b]``, ``block_j[b]``); tube
    ``b * BLOCK**2 + cy * BLOCK + cx`` is cell (cx, cy) of block b.
    """

    tx: np.ndarray
    axis: np.ndarray
    u: np.ndarray
    v: np.ndarray
    distance: np.ndarray
    spacing: np.ndarray
    cell0: np.ndarray
    shape: np.ndarray
    mask_offset: np.ndarray
    masks: np.ndarray
    object_id: np.ndarray
    mirror_face: np.ndarray
    block_window: np.ndarray
    block_i: np.ndarray
    block_j: np.ndarray

    @property
    def n_windows(self) -> int:
        return len(self.distance)

    @property
    def n_tubes(self) -> int:
        return len(self.block_window) * BLOCK * BLOCK

    @staticmethod
    def empty(tx) -> TubeWindows:
        z3, zi = np.zeros((0, 3)), np.zeros(0, np.int32)
        return TubeWindows(tx=np.asarray(tx, np.float64), axis=z3, u=z3, v=z3,
                           distance=np.zeros(0), spacing=np.zeros(0),
                           cell0=np.zeros((0, 2), np.int64), shape=np.zeros((0, 2), np.int64),
                           mask_offset=np.zeros(0, np.int64), masks=np.zeros(0, np.uint8),
                           object_id=zi, mirror_face=zi, block_window=zi, block_i=zi,
                           block_j=zi)


def _dot3(a, b):
    """a.b over the last axis as ((a0 b0 + a1 b1) + a2 b2): the order kernels/silhouette.cl
    uses, so the launch windows' tests are the device's bit for bit."""
    return (a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1]) + a[..., 2] * b[..., 2]


def _clip_near(tri, eye, axis, near, return_index: bool = False):
    """Triangles (T,3,3) clipped to the half-space (p - eye).axis >= near (0, 1 or 2
    triangles each): a face that reaches behind the eye still projects.  A straddling
    triangle becomes the polygon of its vertices in front and its edges' crossings, in
    edge order, fanned from its first vertex.  ``axis`` (3,) or one per triangle (T,3),
    ``near`` a number or (T,); ``return_index``: also the input triangle of each output."""
    tri = np.asarray(tri, dtype=np.float64)
    axis = np.asarray(axis, dtype=np.float64)
    near = np.broadcast_to(np.asarray(near, dtype=np.float64), (len(tri),))
    depth = _dot3(tri - eye, axis[:, None, :] if axis.ndim == 2 else axis)
    front = depth >= near[:, None]
    n_front = front.sum(axis=1)
    part = (n_front > 0) & (n_front < 3)
    idx = np.arange(len(tri))
    s, d, f, nr, ip = tri[part], depth[part], front[part], near[part], idx[part]
    whole = n_front == 3
    if len(s) == 0:
        return (tri[whole], idx[whole]) if return_index else tri[whole]
    nxt = [1, 2, 0]
    b, db, fb = s[:, nxt], d[:, nxt], f[:, nxt]
    with np.errstate(divide="ignore", invalid="ignore"):
        cut = s + ((nr[:, None] - d) / (db - d))[..., None] * (b - s)   # edge k's crossing
    # per edge k: vertex k if in front, then the crossing if the edge crosses
    cand = np.stack([s, cut], axis=2).reshape(len(s), 6, 3)
    valid = np.stack([f, f != fb], axis=2).reshape(len(s), 6)
    order = np.argsort(~valid, axis=1, kind="stable")
    poly = np.take_along_axis(cand, order[..., None], axis=1)   # valid ones first
    quad = valid.sum(axis=1) == 4
    first = poly[:, [0, 1, 2]]
    second = poly[quad][:, [0, 2, 3]]
    # the loop this replaces gave each straddler its fan triangles in turn; the order
    # of triangles does not matter to a coverage mask, the order of vertices is kept
    out = np.concatenate([tri[whole], first, second])
    if return_index:
        return out, np.concatenate([idx[whole], ip, ip[quad]])
    return out


def beside_pairs(triangles, tri_index, tri_start, pair_start, frame, rect, eye,
                 chunk: int = 1 << 18) -> np.ndarray:
    """(pairs,) bool: for window w's clip triangles ``triangles[tri_index[tri_start[w] +
    k]]``, k < ``pair_start[w+1] - pair_start[w]``, whether the triangle lies wholly
    beyond one side plane of the pyramid from ``eye`` through the rectangle ``rect[w]``
    (lo x, lo y, hi x, hi y) of the window plane (``frame[w]``: axis, u, v, distance), by
    more than rounding: its part in front of the eye projects outside the rectangle.
    kernels/silhouette.cl: beside_cull is the device's twin (the same expressions)."""
    pair_start = np.asarray(pair_start, dtype=np.int64)
    counts = np.diff(pair_start)
    n = int(pair_start[-1])
    out = np.zeros(n, dtype=bool)
    frame = np.asarray(frame, dtype=np.float64)
    rect = np.asarray(rect, dtype=np.float64)
    reach = (np.maximum(np.abs(rect[:, 0]), np.abs(rect[:, 1]))
             + np.maximum(np.abs(rect[:, 2]), np.abs(rect[:, 3]))) + frame[:, 9]
    w_all = np.repeat(np.arange(len(counts)), counts)
    for a in range(0, n, chunk):
        w = w_all[a:a + chunk]
        p = np.arange(a, a + len(w))
        rel = triangles[tri_index[np.asarray(tri_start)[w] + (p - pair_start[w])]] - eye
        f = frame[w][:, None, :]
        D = f[..., 9]
        depth = _dot3(rel, f[..., 0:3])
        x = D * _dot3(rel, f[..., 3:6])
        y = D * _dot3(rel, f[..., 6:9])
        margin = 1e-9 * ((np.abs(x) + np.abs(y)) + reach[w][:, None] * np.abs(depth))
        r = rect[w][:, None, :]
        out[a:a + len(w)] = (np.all(x - r[..., 2] * depth > margin, axis=1)
                             | np.all(r[..., 0] * depth - x > margin, axis=1)
                             | np.all(y - r[..., 3] * depth > margin, axis=1)
                             | np.all(r[..., 1] * depth - y > margin, axis=1))
    return out


def _beside(tri, eye, axis, u, v, distance, lo, hi):
    """(T,) bool: :func:`beside_pairs` of one window's triangles (T,3,3)."""
    tri = np.asarray(tri, dtype=np.float64)
    frame = np.concatenate([axis, u, v, [distance]])[None]
    return beside_pairs(tri, np.arange(len(tri)), np.zeros(1, np.int64),
                        np.array([0, len(tri)]), frame,
                        np.concatenate([lo, hi])[None], np.asarray(eye, np.float64))


def _project(tri, eye, axis, u, v, distance):
    """Central projection of triangles (T,3,3) from ``eye`` onto their windows' planes
    (one axis, u, v (T,3) and distance (T,) per triangle): xy (T,3,2) and depth (T,3),
    x = distance (p - eye).u / depth as :func:`clradcom.geometry.silhouette.project_to_plane`
    with the dot products of :func:`_dot3`."""
    rel = np.asarray(tri, dtype=np.float64) - eye
    depth = _dot3(rel, axis[:, None, :])
    D = distance[:, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        x = D * _dot3(rel, u[:, None, :]) / depth
        y = D * _dot3(rel, v[:, None, :]) / depth
    return np.stack([x, y], axis=-1), depth


def _mirror_faces(geom, objects, tx):
    """Planar faces of the environment (objects not in ``objects``) of at least
    MIRROR_MIN_AREA_M2 that tx lies in front of: (face ids, unit normals toward tx,
    offsets, boxes' lower and upper corners)."""
    faces = geom.faces
    data = _face_data(geom)
    ids = np.flatnonzero((data["area"] >= MIRROR_MIN_AREA_M2)
                         & ~np.isin(faces.object_id, objects))
    n, d = faces.normal[ids], faces.offset[ids]
    side = n @ tx - d
    keep = np.abs(side) > 1e-9 * (1.0 + np.abs(tx).max())
    ids, n, d, side = ids[keep], n[keep], d[keep], side[keep]
    sgn = np.sign(side)
    return ids, n * sgn[:, None], d * sgn, data["lo"][ids], data["hi"][ids]


#: per Geometry (by id, dropped when it is collected): :func:`_face_data`
_FACE_DATA: dict[int, dict] = {}


def _face_data(geom) -> dict:
    """What the launch needs of the planar faces, the same for every transmitter, computed
    once per :class:`~clradcom.mechanisms.common.Geometry` (a moved scene is a new one):
    ``order``, ``start`` (face f's triangles are ``order[start[f]:start[f+1]]``, in scene
    order), ``area`` (F,) and each face's box ``lo``, ``hi`` (F, 3)."""
    key = id(geom)
    got = _FACE_DATA.get(key)
    if got is not None and got["geom"]() is geom:
        return got
    scene, faces = geom.scene, geom.faces
    order = np.argsort(faces.tri_face, kind="stable")
    count = np.bincount(faces.tri_face, minlength=faces.n_faces)
    start = np.zeros(faces.n_faces + 1, np.int64)
    np.cumsum(count, out=start[1:])
    area2 = triangle_double_areas(scene.triangles)
    area = np.bincount(faces.tri_face, 0.5 * np.nan_to_num(area2), faces.n_faces)
    lo = np.full((faces.n_faces, 3), np.inf)
    hi = np.full((faces.n_faces, 3), -np.inf)
    some = count > 0
    if some.any():
        tris = scene.triangles[order]
        lo[some] = np.minimum.reduceat(tris.min(axis=1), start[:-1][some])
        hi[some] = np.maximum.reduceat(tris.max(axis=1), start[:-1][some])
    got = {"geom": weakref.ref(geom), "order": order, "start": start, "area": area,
           "lo": lo, "hi": hi}
    _FACE_DATA[key] = got
    weakref.finalize(geom, _FACE_DATA.pop, key, None)
    return got


def _chunks(tris, tx) -> tuple[list[np.ndarray], int]:
    """The triangles (T,3,3) in groups whose bounding spheres keep tx CHUNK_CLEARANCE radii
    away, so each projects onto one window plane well in front of tx: the whole set when
    it does, else halves split at the median centroid along the longest axis, and so on.
    A single triangle that still holds tx that close is dropped: (groups, dropped)."""
    groups, dropped = _chunk_spheres(tris, tx)
    return [g[0] for g in groups], dropped


def _chunk_spheres(tris, tx) -> tuple[list[tuple], int]:
    """:func:`_chunks` with each group's :func:`bounding_sphere`: ([(tris, centre,
    radius)], dropped); the centroids are computed once and split with the triangles."""
    out: list[tuple] = []
    if len(tris) == 0:
        return out, 0
    dropped = _split(tris, tris.mean(axis=1), np.asarray(tx, dtype=np.float64), out)
    return out, dropped


def _split(tris, cen, tx, out) -> int:
    c, r = bounding_sphere(tris)
    if np.linalg.norm(c - tx) >= CHUNK_CLEARANCE * r:
        out.append((tris, c, r))
        return 0
    if len(tris) == 1:
        return 1
    axis = int(np.argmax(np.ptp(cen, axis=0)))
    order = np.argsort(cen[:, axis], kind="stable")
    half = len(tris) // 2
    lo, hi = order[:half], order[half:]
    return _split(tris[lo], cen[lo], tx, out) + _split(tris[hi], cen[hi], tx, out)


def launch_windows(geom, tx_pos, objects, spacing_m, *, mirrors: bool = True,
                   tx_name: str = "tx") -> TubeWindows:
    """The windows of tx's SBR tubes over ``objects`` (scene object ids) with per-object
    pitch ``spacing_m`` (scalar or one per object): the silhouette of each object, then
    (``mirrors``) its image in every large environment face that both tx and the object's
    centre lie in front of, clipped to that face's own silhouette.  An object too close to
    tx for one window (a guard rail beside the radar, the radar's own car) is split into
    groups of triangles (:func:`_chunks`) with a window each; triangles within their own
    size of tx get none (a warning counts them), their PO facets stay.  All windows are
    made at once (:func:`_make_windows`); the device engine runs their block rasters and
    the mirror windows' clip cull in kernels (:mod:`clradcom.device.silhouette`, the same
    masks)."""
    scene = geom.scene
    runtime = geom.runtime if geom.engine == "device" else None
    engines.record("physical_optics.windows", geom.engine, fallback=False)
    tx = np.asarray(tx_pos, dtype=np.float64)
    objects = np.asarray(list(objects), dtype=np.int64)
    spacing = np.broadcast_to(np.asarray(spacing_m, dtype=np.float64), objects.shape)
    if np.any(~np.isfinite(spacing) | (spacing <= 0)):
        raise ArgumentError("must be positive numbers", argument="spacing_m",
                            value=spacing_m)
    direct, mirrored = [], []   # candidate windows: (object, face, spacing, centre, tris)
    face_ids, face_n, face_d, face_lo, face_hi = (
        _mirror_faces(geom, objects, tx) if mirrors
        else (np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros(0), np.zeros((0, 3)),
              np.zeros((0, 3))))
    for o, s in zip(objects, spacing, strict=True):
        chunks, dropped = _chunk_spheres(scene.triangles[scene.tri_object == o], tx)
        if dropped:
            warnings.warn(f"SBR launches no tubes at {dropped} triangle(s) of object "
                          f"{scene.objects[o].name!r}: transmitter {tx_name!r} lies within "
                          f"their own size of them (a radar mounted on it); their PO facet "
                          f"returns stay", stacklevel=3)
        for tris, c, r in chunks:
            direct.append((o, -1, s, c, tris))
            # mirrors in front of which the chunk lies, whose box (grown by the chunk's
            # radius) the line of sight to the chunk's image crosses
            h_c = face_n @ c - face_d
            c_img = c - 2.0 * h_c[:, None] * face_n
            h_tx = face_n @ tx - face_d
            with np.errstate(divide="ignore", invalid="ignore"):
                cross_at = tx + (h_tx / (h_tx + h_c))[:, None] * (c_img - tx)
            near = np.all((cross_at >= face_lo - r) & (cross_at <= face_hi + r), axis=1)
            near &= (h_c > 0) & (np.linalg.norm(c_img - tx, axis=1) > CHUNK_CLEARANCE * r)
            if not near.any():
                continue
            # the chunk's images in all those mirrors at once
            n = face_n[near][:, None, None, :]
            h = _dot3(tris[None], n) - face_d[near][:, None, None]
            images = tris[None] - 2.0 * h[..., None] * n
            for f, ci, image in zip(face_ids[near], c_img[near], images, strict=True):
                mirrored.append((o, int(f), s, ci, image))
    return _make_windows(geom, runtime, tx, direct + mirrored)


def _make_windows(geom, runtime, tx, cands) -> TubeWindows:
    """The candidate windows ``cands`` (object, mirror face or -1, pitch, centre,
    triangles (T,3,3) to cover) as :class:`TubeWindows`, all at once: a window is aimed at
    its centre, its grid spans its triangles' projection plus a cell, its mask marks the
    blocks they cover (and, for a mirror window, that the mirror face's own triangles,
    culled by the pyramid through the covered blocks' rectangle and clipped at the near
    plane, cover too).  A window whose triangles do not all lie MIN_DEPTH_FRACTION of its
    distance in front of tx, or whose mask is empty, is dropped.  ``runtime``: the
    device that rasters and culls (None: numpy), with the same results bit for bit."""
    if not cands:
        return TubeWindows.empty(tx)
    W = len(cands)
    spacing = np.array([c[2] for c in cands], dtype=np.float64)
    counts = np.array([len(c[4]) for c in cands], dtype=np.int64)
    tris = np.concatenate([c[4] for c in cands]).astype(np.float64, copy=False)
    win = np.repeat(np.arange(W), counts)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    rel = np.array([c[3] for c in cands], dtype=np.float64) - tx
    # a window's distance as one vector's norm gives it (a BLAS dot, not a row sum)
    D = np.array([float(np.linalg.norm(r)) for r in rel])
    ok = D != 0.0
    with np.errstate(divide="ignore", invalid="ignore"):
        axis = rel / np.where(ok, D, 1.0)[:, None]
        u, v = orthonormal_frame(axis)
    if runtime is not None:
        # projected on the device, kept there for the raster; the extents come back
        xy, ext = device_silhouette.project_windows(
            runtime, tris, win, np.column_stack([axis, u, v, D]), tx)
    else:
        xy, depth = _project(tris, tx, axis[win], u[win], v[win], D[win])
        ext = np.column_stack([depth.min(axis=1), xy[..., 0].min(axis=1),
                               xy[..., 0].max(axis=1), xy[..., 1].min(axis=1),
                               xy[..., 1].max(axis=1)])
    ok &= ~(np.minimum.reduceat(ext[:, 0], starts) < MIN_DEPTH_FRACTION * D)
    with np.errstate(invalid="ignore"):
        lo_xy = np.minimum.reduceat(ext[:, [1, 3]], starts, axis=0)
        hi_xy = np.maximum.reduceat(ext[:, [2, 4]], starts, axis=0)
        ok &= np.all(np.isfinite(lo_xy) & np.isfinite(hi_xy), axis=1)
        lo = np.floor(np.where(ok[:, None], lo_xy, 0.0) / spacing[:, None]
                      ).astype(np.int64) - 1
        hi = np.floor(np.where(ok[:, None], hi_xy, 0.0) / spacing[:, None]
                      ).astype(np.int64) + 1
    shape = np.where(ok[:, None], -(-(hi - lo + 1) // BLOCK), 0)
    origin = lo * spacing[:, None]
    block = BLOCK * spacing
    sizes = shape[:, 0] * shape[:, 1]
    offset = np.concatenate([[0], np.cumsum(sizes)[:-1]])
    total = int(sizes.sum())
    ny = shape[:, 1]
    if runtime is not None:
        cover = functools.partial(device_silhouette.cover_xy_many, runtime)
    else:
        cover = cover_xy_many
    if runtime is not None:
        mask = cover(xy, win, block, origin, shape, offset, total)
    else:
        sel = ok[win]
        mask = cover(xy[sel], win[sel], block, origin, shape, offset, total)
    cell_win = np.repeat(np.arange(W), sizes)
    mirror = ok & (np.array([c[1] for c in cands]) >= 0)
    mirror &= np.bincount(cell_win[mask], minlength=W) > 0
    m = np.flatnonzero(mirror)
    if len(m):
        mask &= _clip_masks(geom, runtime, tx, cands, m, cell_win, mask, axis, u, v, D,
                            origin, block, shape, offset, total, cover)
    per_window = np.bincount(cell_win[mask], minlength=W)
    keep = ok & (per_window > 0)
    if not keep.any():
        return TubeWindows.empty(tx)
    k = np.flatnonzero(keep)
    masks = mask[keep[cell_win]]
    kept_sizes = sizes[k]
    kept_offset = np.concatenate([[0], np.cumsum(kept_sizes)[:-1]])
    covered = np.flatnonzero(masks)
    bw = np.repeat(np.arange(len(k)), per_window[k])   # covered cells are window-ordered
    local = covered - kept_offset[bw]
    return TubeWindows(
        tx=tx, axis=axis[k], u=u[k], v=v[k], distance=D[k], spacing=spacing[k],
        cell0=lo[k], shape=shape[k].astype(np.int64), mask_offset=kept_offset.astype(np.int64),
        masks=masks.astype(np.uint8),
        object_id=np.array([cands[i][0] for i in k], dtype=np.int32),
        mirror_face=np.array([cands[i][1] for i in k], dtype=np.int32),
        block_window=bw.astype(np.int32), block_i=(local // ny[k][bw]).astype(np.int32),
        block_j=(local % ny[k][bw]).astype(np.int32))


def _clip_masks(geom, runtime, tx, cands, m, cell_win, mask, axis, u, v, D, origin, block,
                shape, offset, total, cover) -> np.ndarray:
    """(total,) bool: where the mirror windows ``m`` may keep their blocks - the blocks
    their mirror faces' own triangles cover (culled beside the covered blocks' rectangle
    by :func:`beside_pairs`, clipped at the near plane by :func:`_clip_near`); True in
    every other window's cells."""
    covered = np.flatnonzero(mask)
    cw = cell_win[covered]
    local = covered - offset[cw]
    bi, bj = local // shape[cw, 1], local % shape[cw, 1]
    # covered cells are window-ordered, the direct windows' first: from the first mirror
    # window's on, every covered cell is a mirror window's, so each reduceat group holds
    # exactly one window's cells
    first = np.searchsorted(cw, m)
    ij_lo = np.stack([np.minimum.reduceat(bi, first), np.minimum.reduceat(bj, first)], 1)
    ij_hi = np.stack([np.maximum.reduceat(bi, first), np.maximum.reduceat(bj, first)], 1)
    rect_lo = origin[m] + ij_lo * block[m][:, None]
    rect_hi = origin[m] + (ij_hi + 1) * block[m][:, None]
    data = _face_data(geom)
    order, fstart = data["order"], data["start"]
    face = np.array([cands[i][1] for i in m], dtype=np.int64)
    used, inv = np.unique(face, return_inverse=True)
    n_used = fstart[used + 1] - fstart[used]
    tri_index = np.concatenate([order[fstart[f]:fstart[f + 1]] for f in used])
    used_start = np.concatenate([[0], np.cumsum(n_used)[:-1]])
    tri_start = used_start[inv]
    pair_count = n_used[inv]
    pair_start = np.concatenate([[0], np.cumsum(pair_count)])
    triangles = geom.scene.triangles
    frame = np.column_stack([axis[m], u[m], v[m], D[m]])
    rect = np.column_stack([rect_lo, rect_hi])
    if runtime is not None:
        # the triangles of the used faces only travel to the device
        beside = device_silhouette.beside_cull(
            runtime, triangles[tri_index], np.arange(len(tri_index)), tri_start,
            pair_start, frame, rect, tx)
    else:
        beside = beside_pairs(triangles, tri_index, tri_start, pair_start, frame, rect, tx)
    p = np.flatnonzero(~beside)
    pw = np.searchsorted(pair_start, p, side="right") - 1
    clip = triangles[tri_index[tri_start[pw] + (p - pair_start[pw])]]
    clip, src = _clip_near(clip, tx, axis[m][pw], MIN_DEPTH_FRACTION * D[m][pw],
                           return_index=True)
    cwin = m[pw[src]]
    xy, _ = _project(clip, tx, axis[cwin], u[cwin], v[cwin], D[cwin])
    allowed = cover(xy, cwin, block, origin, shape, offset, total)
    in_mirror = np.zeros(len(D), dtype=bool)
    in_mirror[m] = True
    return allowed | ~in_mirror[cell_win]


def blocks_in_pattern(windows: TubeWindows, tx) -> TubeWindows:
    """``windows`` without the blocks that lie wholly outside tx's antenna pattern (zero
    gain at their four corners and centre): tubes there would radiate nothing.  The
    masks stay, so which window owns a direction does not change."""
    if len(windows.block_window) == 0:
        return windows
    w = windows.block_window.astype(np.int64)
    # each window's frame turned into tx's antenna frame once, the points' directions
    # summed there without a matrix product per point (numpy's BLAS takes threads for
    # large ones, slow on a loaded machine). Corners are shared by up to four blocks: each
    # corner of the windows' block lattices that a block needs is tested once (its
    # coordinates are the same half-integers, so the same numbers), then the centres of
    # the blocks with no corner inside.
    o = np.asarray(tx.orientation, dtype=np.float64)
    a_l, u_l, v_l = ((f[:, :, None] * o[None]).sum(axis=1)
                     for f in (windows.axis, windows.u, windows.v))
    a_l = windows.distance[:, None] * a_l

    def seen(g, i, j, f):
        x = (windows.cell0[g, 0] + i * BLOCK + f * BLOCK) * windows.spacing[g]
        y = (windows.cell0[g, 1] + j * BLOCK + f * BLOCK) * windows.spacing[g]
        d = a_l[g] + x[:, None] * u_l[g] + y[:, None] * v_l[g]
        d /= np.linalg.norm(d, axis=-1, keepdims=True)
        return np.asarray(tx.pattern.gain(d)) > 0

    bi = windows.block_i.astype(np.int64)
    bj = windows.block_j.astype(np.int64)
    row = windows.shape[:, 1] + 1
    size = (windows.shape[:, 0] + 1) * row
    off = np.cumsum(size) - size
    base = off[w] + bi * row[w] + bj
    corners = (base, base + 1, base + row[w], base + row[w] + 1)
    needed = np.zeros(int(size.sum()), dtype=bool)
    for c in corners:
        needed[c] = True
    at = np.flatnonzero(needed)
    g = np.searchsorted(off, at, side="right") - 1
    g_row = row[g]
    inside = np.zeros(len(needed), dtype=bool)
    inside[at] = seen(g, (at - off[g]) // g_row, (at - off[g]) % g_row, 0.0)
    keep = inside[corners[0]] | inside[corners[1]] | inside[corners[2]] | inside[corners[3]]
    rest = np.flatnonzero(~keep)
    if len(rest):
        keep[rest] = seen(w[rest], bi[rest], bj[rest], 0.5)
    if keep.all():
        return windows
    return dataclasses.replace(windows, block_window=windows.block_window[keep],
                               block_i=windows.block_i[keep], block_j=windows.block_j[keep])


def _tube_directions(windows: TubeWindows, tubes):
    """Tubes ``tubes``' windows (int64), unit directions (N,3) and cos of their angle off
    their window's axis, as :func:`window_tubes` computes them."""
    tubes = np.asarray(tubes, dtype=np.int64)
    blk, cell = np.divmod(tubes, BLOCK * BLOCK)
    w = windows.block_window[blk].astype(np.int64)
    i = windows.cell0[w, 0] + windows.block_i[blk] * BLOCK + cell % BLOCK
    j = windows.cell0[w, 1] + windows.block_j[blk] * BLOCK + cell // BLOCK
    s, D = windows.spacing[w], windows.distance[w]
    vec = (D[:, None] * windows.axis[w] + ((i + 0.5) * s)[:, None] * windows.u[w]
           + ((j + 0.5) * s)[:, None] * windows.v[w])
    dist = np.linalg.norm(vec, axis=1)
    return w, vec / dist[:, None], D / dist


def window_tubes(windows: TubeWindows, tubes) -> tuple[TubeGrid, np.ndarray]:
    """The tubes ``tubes`` (indices, see :class:`TubeWindows`) as a :class:`TubeGrid`
    (directions, solid angles spacing^2 cos^3(alpha)/D^2, edges), and which of them their
    window owns (False: an earlier window covers the direction, or its cell lies outside
    its own window's mask, never the case for enumerated tubes)."""
    w, d, cos_a = _tube_directions(windows, tubes)
    s, D = windows.spacing[w], windows.distance[w]
    a = windows.u[w]
    e1 = a - np.einsum("ij,ij->i", d, a)[:, None] * d
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    owned = np.ones(len(w), dtype=bool)
    overlaps = earlier_overlaps(windows)
    for k in range(windows.n_windows - 1):
        later = overlaps[w, k]
        if not later.any():
            continue
        owned[later] &= ~_covers(windows, k, d[later])
    grid = TubeGrid(directions=d, solid_angle=s * s * cos_a**3 / (D * D), edge1=e1,
                    edge2=np.cross(d, e1))
    return grid, owned


def earlier_overlaps(windows: TubeWindows) -> np.ndarray:
    """(W, W) bool: window k < w can cover a direction of window w - their cones of
    directions (axis, and the half-angle of the grid extent's farthest corner) meet.
    Only those need the ownership test; the others never hold each other's directions."""
    W = windows.n_windows
    half = _window_half_angles(windows)
    between = np.arccos(np.clip(windows.axis @ windows.axis.T, -1.0, 1.0))
    meet = between <= half[:, None] + half[None, :] + 1e-9
    return meet & np.tri(W, k=-1, dtype=bool)


def _covers(windows: TubeWindows, k: int, d) -> np.ndarray:
    """Whether window k launches a tube whose cell holds each direction d (N,3)."""
    return _covering_block(windows, k, d)[0]


def _covering_block(windows: TubeWindows, k: int, d) -> tuple[np.ndarray, np.ndarray]:
    """For each direction d (N,3): whether window k's mask covers it, and the index into
    ``windows.masks`` of the block that holds it (0 where not covered)."""
    depth = d @ windows.axis[k]
    ok = depth > 0
    with np.errstate(divide="ignore", invalid="ignore"):
        x = windows.distance[k] * (d @ windows.u[k]) / depth
        y = windows.distance[k] * (d @ windows.v[k]) / depth
    s = windows.spacing[k]
    ok &= np.isfinite(x) & np.isfinite(y)
    ci = np.floor(np.where(ok, x, 0.0) / s).astype(np.int64) - windows.cell0[k, 0]
    cj = np.floor(np.where(ok, y, 0.0) / s).astype(np.int64) - windows.cell0[k, 1]
    bi, bj = np.floor_divide(ci, BLOCK), np.floor_divide(cj, BLOCK)
    nx, ny = windows.shape[k]
    ok &= (bi >= 0) & (bi < nx) & (bj >= 0) & (bj < ny)
    flat = windows.mask_offset[k] + np.where(ok, bi * ny + bj, 0)
    ok &= windows.masks[flat] != 0
    return ok, np.where(ok, flat, 0)


def launched(windows: TubeWindows, directions) -> np.ndarray:
    """Whether the tubes of ``windows`` were shot along each direction (N,3) from tx: the
    first window whose mask covers it owns it (the kernels' ownership test), and its
    block there is one of those launched (not cut by :func:`blocks_in_pattern`).  A
    direction outside every launched tube's cell is one SBR-PO never follows."""
    d = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    out = np.zeros(len(d), dtype=bool)
    if len(windows.block_window) == 0 or len(d) == 0:
        return out
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    w = windows.block_window.astype(np.int64)
    kept = np.unique(windows.mask_offset[w] + windows.block_i.astype(np.int64)
                     * windows.shape[w, 1] + windows.block_j)
    # each window's cone of directions (earlier_overlaps' half-angle, widened a little)
    # first: most directions lie in none, and one product tests them against all
    cos_half = np.cos(np.minimum(_window_half_angles(windows) + 1e-6, np.pi))
    rows, cones = [], []
    for start in range(0, len(d), 1 << 16):
        r, k = np.nonzero(d[start:start + (1 << 16)] @ windows.axis.T >= cos_half)
        rows.append(r + start)
        cones.append(k)
    rows, cones = np.concatenate(rows), np.concatenate(cones)
    order = np.argsort(cones, kind="stable")
    rows, cones = rows[order], cones[order]
    bounds = np.searchsorted(cones, np.arange(windows.n_windows + 1))
    decided = np.zeros(len(d), dtype=bool)
    for k in range(windows.n_windows):
        mine = rows[bounds[k]:bounds[k + 1]]
        mine = mine[~decided[mine]]
        if not len(mine):
            continue
        ok, flat = _covering_block(windows, k, d[mine])
        out[mine[ok]] = np.isin(flat[ok], kept)
        decided[mine[ok]] = True
    return out


def _window_half_angles(windows: TubeWindows) -> np.ndarray:
    """(W,) the half-angle of each window's cone of directions: its axis to the
    farthest corner of its grid's extent."""
    lo = windows.cell0 * windows.spacing[:, None]
    hi = (windows.cell0 + windows.shape * BLOCK) * windows.spacing[:, None]
    reach = np.hypot(np.maximum(np.abs(lo[:, 0]), np.abs(hi[:, 0])),
                     np.maximum(np.abs(lo[:, 1]), np.abs(hi[:, 1])))
    return np.arctan2(reach, windows.distance)


@dataclass
class TubeHits:
    """Bounces of ray tubes (one row per tube and bounce at or after first_bounce).

    ``tube`` (H,) index into the grid shot; ``bounce`` (H,) 1-based; ``point`` (H,3)
    exact hit point (float64 plane intersection); ``k_in`` (H,3); ``normal`` (H,3) lit-side
    unit normal; ``length`` (H,) unfolded tx -> point; ``chain`` (H,3,3) complex transfer
    of the earlier reflections; ``edge1``/``edge2`` (H,3) unit cross-section edges;
    ``triangle`` (H,) scene triangle; ``history`` (H, max_bounces, 3) bounce points so far
    (NaN after), ``tri_history`` (H, max_bounces) their triangles (-1).
    """

    tube: np.ndarray
    bounce: np.ndarray
    point: np.ndarray
    k_in: np.ndarray
    normal: np.ndarray
    length: np.ndarray
    chain: np.ndarray
    edge1: np.ndarray
    edge2: np.ndarray
    triangle: np.ndarray
    history: np.ndarray
    tri_history: np.ndarray


def _chains(scene, tri_history, k0_dir, m):
    """Transfer chains (H,3,3) of the first m-1 reflections of H recorded tubes:
    C = D_{m-1} ... D_1 (I - k0 k0^T), replaying the mirrors of their triangles with
    each material's full specular dyad (Fresnel x roughness x sqrt(1 - S^2))."""
    d = np.array(k0_dir, dtype=np.float64)
    chain = (np.eye(3)[None] - d[:, :, None] * d[:, None, :]).astype(np.complex128)
    if len(d) == 0:
        return chain
    for j in range(m - 1):
        tri = tri_history[:, j]
        n = triangle_normals(scene.triangles[tri])
        chain = em.material_reflection_dyad(scene, scene.tri_material[tri], d, n) @ chain
        d = d - 2.0 * np.einsum("ij,ij->i", d, n)[:, None] * n
    return chain


def shoot_tubes(geom, tx_pos, grid: TubeGrid, max_bounces: int, first_bounce: int = 2,
                record_triangles=None) -> TubeHits:
    """Follow every tube through up to ``max_bounces`` specular reflections (the host
    reference engine).

    Closest hits come from the BVH caster (float32); each hit point is then the exact
    float64 intersection of the ray with the hit triangle's plane.  Bounces at or after
    ``first_bounce`` on triangles in ``record_triangles`` (bool mask over the scene's
    triangles; default all) are recorded for radiation, with the transfer chain of their
    earlier reflections (:func:`_chains`), so tubes may pass over GO objects (the road)
    on the way.
    """
    scene = geom.scene
    tx = np.asarray(tx_pos, dtype=np.float64)
    R = len(grid)
    tris_all = scene.triangles
    nrm_all = triangle_normals(tris_all)
    if record_triangles is None:
        record_triangles = np.ones(len(tris_all), dtype=bool)
    idx = np.arange(R)
    pos = np.broadcast_to(tx, (R, 3))
    org = pos
    d = grid.directions
    e1, e2 = grid.edge1, grid.edge2
    L = np.zeros(R)
    hist = np.full((R, max_bounces, 3), np.nan)
    thist = np.full((R, max_bounces), -1, dtype=np.int32)
    rec: dict[str, list] = {k: [] for k in TubeHits.__dataclass_fields__}
    for m in range(1, max_bounces + 1):
        if len(idx) == 0 or geom.caster is None:
            break
        hits = geom.caster.closest_hit(make_rays(org, d))
        tri = hits["prim"].astype(np.int64)
        n = nrm_all[np.maximum(tri, 0)]
        dn = np.einsum("ij,ij->i", d, n)
        good = (tri >= 0) & (np.abs(dn) > 1e-9)  # grazing hits carry no footprint
        idx, pos, d, e1, e2, L, tri, n, dn = (
            a[good] for a in (idx, pos, d, e1, e2, L, tri, n, dn))
        if len(idx) == 0:
            break
        t = np.einsum("ij,ij->i", tris_all[tri, 0] - pos, n) / dn
        # a hit on the plane the tube just left (a corner's edge) has no length to go:
        # the tube ends there, as at a grazing hit
        ahead = t > 0
        if not ahead.all():
            idx, pos, d, e1, e2, L, tri, n, dn, t = (
                a[ahead] for a in (idx, pos, d, e1, e2, L, tri, n, dn, t))
            if len(idx) == 0:
                break
        p = pos + t[:, None] * d
        L = L + np.linalg.norm(p - pos, axis=1)
        hist[idx, m - 1] = p
        thist[idx, m - 1] = tri
        if m >= first_bounce:
            sel = record_triangles[tri]
            ids = idx[sel]
            rec["chain"].append(_chains(scene, thist[ids], grid.directions[ids], m))
            for key, val in (("tube", ids), ("point", p[sel]), ("k_in", d[sel]),
                             ("normal", -np.sign(dn[sel])[:, None] * n[sel]),
                             ("length", L[sel]), ("edge1", e1[sel]), ("edge2", e2[sel]),
                             ("triangle", tri[sel]), ("history", hist[ids]),
                             ("tri_history", thist[ids])):
                rec[key].append(val)
            rec["bounce"].append(np.full(len(ids), m, dtype=np.int16))
        if m == max_bounces:
            break
        d = d - 2.0 * dn[:, None] * n
        e1 = e1 - 2.0 * np.einsum("ij,ij->i", e1, n)[:, None] * n
        e2 = e2 - 2.0 * np.einsum("ij,ij->i", e2, n)[:, None] * n
        pos = p
        org = spawn_origins(p, n, d)
    if not rec["tube"]:
        return TubeHits(tube=np.zeros(0, np.int64), bounce=np.zeros(0, np.int16),
                        point=np.zeros((0, 3)), k_in=np.zeros((0, 3)),
                        normal=np.zeros((0, 3)), length=np.zeros(0),
                        chain=np.zeros((0, 3, 3), np.complex128), edge1=np.zeros((0, 3)),
                        edge2=np.zeros((0, 3)), triangle=np.zeros(0, np.int64),
                        history=np.zeros((0, max_bounces, 3)),
                        tri_history=np.zeros((0, max_bounces), np.int32))
    return TubeHits(**{k: np.concatenate(v) for k, v in rec.items()})


def bounding_sphere(points):
    """(centre, radius) of the axis-aligned box around points: cheap and never too small."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    c = 0.5 * (lo + hi)
    return c, float(np.linalg.norm(pts - c, axis=1).max())


def footprint_shape(hits: TubeHits, grid: TubeGrid, rows=slice(None)):
    """(edge1, edge2, area) of recorded hits ``rows``: the tube's square cross-section,
    of side sqrt(dOmega) L_in, projected along k_in onto the hit's plane (two (H,3)
    edges), and the area |e1' x e2'| = side^2 / |k_in . n|."""
    k_in, n = hits.k_in[rows], hits.normal[rows]
    side = np.sqrt(grid.solid_angle[hits.tube[rows]]) * hits.length[rows]
    kn = np.einsum("ij,ij->i", k_in, n)
    edges = []
    for e in (hits.edge1[rows], hits.edge2[rows]):
        e = side[:, None] * e
        edges.append(e - k_in * (np.einsum("ij,ij->i", n, e) / kn)[:, None])
    return edges[0], edges[1], side * side / np.abs(kn)


def footprint_integral(q, edge1, edge2, area):
    """I_fp (H,): the radiation integral of parallelograms (``area``, edges ``edge1``,
    ``edge2``) with the linear phase q (H,3): area sinc(q.e1/2) sinc(q.e2/2)."""
    return area * sinc(0.5 * np.einsum("ij,ij->i", q, edge1)) * sinc(
        0.5 * np.einsum("ij,ij->i", q, edge2))


def _radiate(geom, hits: TubeHits, grid: TubeGrid, rx_pos):
    """Per recorded hit that sees rx: T (H,3,3), L (H,), k_arr and the hits kept
    (side, shadowing).  See the module docstring for T."""
    scene = geom.scene
    k0 = 2.0 * np.pi * scene.carrier_hz / em.C0
    rx_pos = np.asarray(rx_pos, dtype=np.float64)
    p, n = hits.point, hits.normal
    dr = rx_pos - p
    R_r = np.linalg.norm(dr, axis=1)
    ok = R_r > 0
    s = dr / np.where(ok, R_r, 1.0)[:, None]
    ok &= np.einsum("ij,ij->i", s, n) > 0
    keep = np.flatnonzero(ok)
    if len(keep):
        keep = keep[surface_sees(geom.caster, p[keep], n[keep], rx_pos, hits.triangle[keep],
                                 leave_direction=s[keep], tri_face=geom.faces.tri_face,
                                 engine=geom.engine)]
    p, n, s, R_r = p[keep], n[keep], s[keep], R_r[keep]
    k_in, L_in = hits.k_in[keep], hits.length[keep]
    kn = np.einsum("ij,ij->i", k_in, n)
    edge1, edge2, area = footprint_shape(hits, grid, keep)
    i_fp = footprint_integral(k0 * (s - k_in), edge1, edge2, area)
    mat = scene.tri_material[hits.triangle[keep]]
    pec = scene.material_pec[mat]
    eye = np.eye(3)
    cross2 = k_in[:, :, None] * n[:, None, :] - kn[:, None, None] * eye
    proj = eye - s[:, :, None] * s[:, None, :]
    op = (proj @ cross2).astype(np.complex128)
    if not np.all(pec):
        # penetrable footprints: currents of the incident plus reflected field
        pen = np.flatnonzero(~pec)
        D = em.material_reflection_dyad(scene, mat[pen], k_in[pen], n[pen])
        op[pen] = 0.5 * penetrable_po_operator(n[pen], k_in[pen], s[pen], D)
    L = L_in + R_r
    scale = -1j * k0 / (2.0 * np.pi) * L / (L_in * R_r) * i_fp
    T = scale[:, None, None] * (op @ hits.chain[keep])
    return T, L, s, keep


@dataclass
class BlockSums:
    """SBR-PO footprints of one transmitter summed per launch block, bounce, receiver
    and sequence of planar faces: what both engines produce.  Per row: ``receiver`` (C,)
    index into the receivers shot for; ``bounce`` (C,) int16; ``matrix`` (C,2,2) the sum
    of the footprints' polarimetric matrices (:func:`clradcom.physics.em.
    polarimetric_matrix`, in the antennas' bases of each tube's own directions);
    ``weight`` (C,) the sum of their Frobenius norms and ``weighted_length`` (C,) of norm
    x unfolded length; ``count`` (C,) footprints; ``face`` (C, max_bounces) the face
    sequence (-1 after); and the representative footprint (largest norm, the first of
    equals): ``tube`` (C,) int64, ``length`` (C,) unfolded tx -> footprint -> rx,
    ``point`` (C,3) and ``tri`` (C, max_bounces) its triangles."""

    receiver: np.ndarray
    bounce: np.ndarray
    matrix: np.ndarray
    weight: np.ndarray
    weighted_length: np.ndarray
    count: np.ndarray
    face: np.ndarray
    tube: np.ndarray
    length: np.ndarray
    point: np.ndarray
    tri: np.ndarray

    def __len__(self) -> int:
        return len(self.tube)

    def select(self, rows) -> BlockSums:
        return BlockSums(**{k: getattr(self, k)[rows] for k in self.__dataclass_fields__})

    @staticmethod
    def empty(max_bounces: int) -> BlockSums:
        z = np.zeros(0)
        k = np.zeros((0, max_bounces), np.int32)
        return BlockSums(receiver=np.zeros(0, np.int32), bounce=np.zeros(0, np.int16),
                         matrix=np.zeros((0, 2, 2), np.complex128), weight=z,
                         weighted_length=z, count=np.zeros(0, np.int32), face=k,
                         tube=np.zeros(0, np.int64), length=z, point=np.zeros((0, 3)), tri=k)


def _sum_blocks(tube, bounce, receiver, M, L, point, tri, tri_face, max_bounces) -> BlockSums:
    """Per-footprint rows (in tube, bounce, receiver order) summed as the device kernel
    sums them: per block, bounce, receiver and face sequence, in the order each group
    first appears, the representative the first footprint of the largest norm."""
    if len(tube) == 0:
        return BlockSums.empty(max_bounces)
    face = np.where(tri >= 0, tri_face[np.maximum(tri, 0)], -1).astype(np.int32)
    block = tube // (BLOCK * BLOCK)
    keys = np.column_stack([block, bounce, receiver, face])
    _, first, group = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    group = group.ravel()
    # number the groups by first appearance (the kernel's emission order)
    rank = np.empty(len(first), np.int64)
    rank[np.argsort(first, kind="stable")] = np.arange(len(first))
    group = rank[group]
    G = len(first)
    w = np.sqrt(np.sum(np.abs(M.reshape(len(M), 4)) ** 2, axis=1))
    g_M = np.zeros((G, 2, 2), np.complex128)
    np.add.at(g_M, group, M)
    g_w = np.zeros(G)
    np.add.at(g_w, group, w)
    g_wl = np.zeros(G)
    np.add.at(g_wl, group, w * L)
    count = np.bincount(group, minlength=G).astype(np.int32)
    order = np.lexsort((np.arange(len(group)), -w, group))
    head = np.ones(len(order), bool)
    head[1:] = group[order[1:]] != group[order[:-1]]
    rep = order[head]
    return BlockSums(receiver=receiver[rep].astype(np.int32), bounce=bounce[rep].astype(np.int16),
                     matrix=g_M, weight=g_w, weighted_length=g_wl, count=count,
                     face=face[rep], tube=tube[rep].astype(np.int64), length=L[rep],
                     point=point[rep], tri=tri[rep].astype(np.int32))


def host_block_sums(geom, windows: TubeWindows, tx, receivers, max_bounces: int,
                    first_bounce: int, record_triangles) -> BlockSums:
    """The reference engine: every owned tube of ``windows`` shot with :func:`shoot_tubes`
    and radiated toward each receiver (radars) with :func:`_radiate`, in batches of
    HOST_BATCH_TUBES tubes; each footprint's polarimetric matrix by
    :func:`clradcom.physics.em.polarimetric_matrix`, then summed by :func:`_sum_blocks`."""
    scene = geom.scene
    rows: dict[str, list] = {k: [] for k in ("tube", "bounce", "receiver", "M", "L", "point",
                                             "tri")}
    for start in range(0, windows.n_tubes, HOST_BATCH_TUBES):
        tubes = np.arange(start, min(start + HOST_BATCH_TUBES, windows.n_tubes))
        grid, owned = window_tubes(windows, tubes)
        tubes = tubes[owned]
        grid = TubeGrid(grid.directions[owned], grid.solid_angle[owned],
                        grid.edge1[owned], grid.edge2[owned])
        hits = shoot_tubes(geom, windows.tx, grid, max_bounces, first_bounce,
                           record_triangles)
        if len(hits.tube) == 0:
            continue
        for r, rx in enumerate(receivers):
            T, L, s, keep = _radiate(geom, hits, grid, rx.position)
            if len(keep) == 0:
                continue
            rows["M"].append(em.polarimetric_matrix(
                T, L, grid.directions[hits.tube[keep]], s, tx.orientation, rx.orientation,
                scene.carrier_hz))
            rows["tube"].append(tubes[hits.tube[keep]])
            rows["bounce"].append(hits.bounce[keep])
            rows["receiver"].append(np.full(len(keep), r, np.int32))
            rows["L"].append(L)
            rows["point"].append(hits.point[keep])
            rows["tri"].append(np.where(np.arange(max_bounces)[None, :]
                                        < hits.bounce[keep, None], hits.tri_history[keep], -1))
    if not rows["tube"]:
        return BlockSums.empty(max_bounces)
    cat = {k: np.concatenate(v) for k, v in rows.items()}
    order = np.lexsort((cat["receiver"], cat["bounce"], cat["tube"]))
    cat = {k: v[order] for k, v in cat.items()}
    return _sum_blocks(cat["tube"], cat["bounce"], cat["receiver"], cat["M"], cat["L"],
                       cat["point"], cat["tri"], geom.faces.tri_face, max_bounces)


def device_block_sums(geom, windows: TubeWindows, tx, receivers, max_bounces: int,
                      first_bounce: int, record_triangles, precision: str = "auto"
                      ) -> BlockSums:
    """The device engine: :func:`clradcom.device.sbr.shoot_and_radiate` (``precision``:
    fp64 where the device has it, else double-float positions with float fields)."""
    scene = geom.scene
    rec = device_sbr.shoot_and_radiate(
        geom.caster, scene, geom.faces.tri_face, windows, tx.orientation,
        [rx.position for rx in receivers], [rx.orientation for rx in receivers],
        wavenumber=2.0 * np.pi * scene.carrier_hz / em.C0,
        wavelength=em.C0 / scene.carrier_hz, max_bounces=max_bounces,
        first_bounce=first_bounce, record_triangles=record_triangles, precision=precision,
        earlier=earlier_overlaps(windows))
    M = rec["M"].reshape(-1, 2, 2, 2)
    return BlockSums(receiver=rec["receiver"].astype(np.int32),
                     bounce=rec["bounce"].astype(np.int16),
                     matrix=M[..., 0] + 1j * M[..., 1], weight=rec["weight"],
                     weighted_length=rec["weighted_length"],
                     count=rec["count"].astype(np.int32),
                     face=rec["face"][:, :max_bounces].astype(np.int32),
                     tube=rec["tube"].astype(np.int64), length=rec["length"],
                     point=rec["point"], tri=rec["tri"][:, :max_bounces].astype(np.int32))


def _bounce_points(geom, tx_pos, directions, max_bounces: int) -> np.ndarray:
    """(R, max_bounces, 3) the bounce points of rays from tx along ``directions`` (NaN
    past a ray's last bounce): :func:`shoot_tubes`' walk, its arithmetic for the points
    and directions unchanged, without the tubes' edges, lengths and transfer chains."""
    tris_all = geom.scene.triangles
    R = len(directions)
    tx = np.asarray(tx_pos, dtype=np.float64)
    idx = np.arange(R)
    pos = np.broadcast_to(tx, (R, 3))
    org = pos
    d = directions
    hist = np.full((R, max_bounces, 3), np.nan)
    for m in range(1, max_bounces + 1):
        if len(idx) == 0 or geom.caster is None:
            break
        tri = geom.caster.closest_hit(make_rays(org, d))["prim"].astype(np.int64)
        hit = tri >= 0
        idx, pos, d, tri = idx[hit], pos[hit], d[hit], tri[hit]
        # the normals of the hit triangles only: row for row triangle_normals' of all
        n = triangle_normals(tris_all[tri])
        dn = np.einsum("ij,ij->i", d, n)
        good = np.abs(dn) > 1e-9  # grazing hits carry no footprint
        idx, pos, d, tri, n, dn = (a[good] for a in (idx, pos, d, tri, n, dn))
        if len(idx) == 0:
            break
        t = np.einsum("ij,ij->i", tris_all[tri, 0] - pos, n) / dn
        ahead = t > 0
        if not ahead.all():
            idx, pos, d, tri, n, dn, t = (a[ahead] for a in (idx, pos, d, tri, n, dn, t))
            if len(idx) == 0:
                break
        p = pos + t[:, None] * d
        hist[idx, m - 1] = p
        if m == max_bounces:
            break
        d = d - 2.0 * dn[:, None] * n
        pos = p
        org = spawn_origins(p, n, d)
    return hist


def _replay(geom, windows: TubeWindows, tubes, bounces, max_bounces: int):
    """Bounce points (P, max_bounces, 3) of tubes ``tubes`` up to their bounce
    ``bounces``, re-shot on the host (the engines are deterministic, so a tube retraces
    its path; points past the bounce are NaN, and all of a tube's when it does not reach
    that bounce)."""
    tubes = np.asarray(tubes, dtype=np.int64)
    bounces = np.asarray(bounces, dtype=np.int64)
    uniq, inv = np.unique(tubes, return_inverse=True)
    hist = _bounce_points(geom, windows.tx, _tube_directions(windows, uniq)[1],
                          max_bounces)[inv.reshape(-1)]
    reached = ~np.isnan(hist[np.arange(len(tubes)), bounces - 1, 0])
    hist[np.arange(max_bounces)[None, :] >= bounces[:, None]] = np.nan
    hist[~reached] = np.nan
    return hist


def block_paths(geom, windows: TubeWindows, sums: BlockSums, tx, rx, *, max_bounces: int,
                min_relative_db: float = -80.0) -> Paths:
    """One receiver's :class:`BlockSums` as :class:`Paths`.

    Each row's gain applies the antenna patterns at its representative's directions (a
    block spans a few tube pitches, over which a pattern does not change) to its matrix;
    rows outside either pattern there are dropped.  Rows with the same face sequence add
    up coherently to one path (gains and matrices summed); its delay, points, Doppler,
    object and triangle ids are those of the representative whose unfolded length is
    closest to the group's norm-weighted mean length, so the delay is the group's and
    is consistent with the points.  Groups more than |min_relative_db| below the
    strongest of the link are dropped.
    """
    groups = _block_groups(windows, sums, tx, rx, min_relative_db)
    if groups is None:
        return Paths.empty(max_bounces)
    return _block_finish(geom, groups, tx, rx, max_bounces, _replay(
        geom, windows, groups["tube"], groups["nk"], max_bounces))


def face_groups(face) -> np.ndarray:
    """(N,) each row's group among the distinct rows of ``face`` (N, K) (face ids >= -1),
    numbered in lexicographic order: ``np.unique(face, axis=0, return_inverse=True)``'s
    inverse. Where the rows fit one int64 in base max + 2 (the street's 4,972 faces at
    K = 5 do), one sort of those keys; else :func:`clradcom.geometry.rows.unique_rows`."""
    face = np.asarray(face)
    K = face.shape[1]
    base = int(face.max(initial=-1)) + 2
    if base ** K >= 2**63:
        return unique_rows(face)[1]
    key = np.zeros(len(face), dtype=np.int64)
    for k in range(K):
        key = key * base + (face[:, k].astype(np.int64) + 1)
    return np.unique(key, return_inverse=True)[1].reshape(-1)


def _block_groups(windows: TubeWindows, sums: BlockSums, tx, rx, min_relative_db: float,
                  rows=None) -> dict | None:
    """:func:`block_paths` up to the replay: the rows in both patterns summed per face
    sequence, the strong groups' representatives (``tube``, bounce ``nk``) and what
    :func:`_block_finish` needs; None where no row is seen.  ``rows``: the rows of
    ``sums`` that are rx's (default all)."""
    rows = np.arange(len(sums)) if rows is None else np.asarray(rows)
    if len(rows) == 0:
        return None
    k_dep = _tube_directions(windows, sums.tube[rows])[1]
    k_arr = np.asarray(rx.position, np.float64) - sums.point[rows]
    k_arr /= np.linalg.norm(k_arr, axis=1, keepdims=True)
    d_tx = k_dep @ np.asarray(tx.orientation)
    d_rx = -k_arr @ np.asarray(rx.orientation)
    seen = (np.asarray(tx.pattern.gain(d_tx)) > 0) & (np.asarray(rx.pattern.gain(d_rx)) > 0)
    if not seen.any():
        return None
    c = sums.select(rows[seen])
    c_tx = np.asarray(tx.pattern.field(d_tx[seen]), dtype=np.complex128)
    c_rx = np.asarray(rx.pattern.field(d_rx[seen]), dtype=np.complex128)
    gain = np.einsum("pi,pij,pj->p", c_rx, c.matrix, c_tx)
    group = face_groups(c.face)
    G = int(group.max()) + 1
    # np.add.at's sums, row by row in order, as bincounts of the real and imaginary parts
    g_gain = np.empty(G, np.complex128)
    g_gain.real = np.bincount(group, gain.real, G)
    g_gain.imag = np.bincount(group, gain.imag, G)
    parts = np.ascontiguousarray(c.matrix).view(np.float64).reshape(len(group), 8)
    g_M = np.bincount((group[:, None] * 8 + np.arange(8)).ravel(), parts.ravel(), G * 8
                      ).view(np.complex128).reshape(G, 2, 2)
    w = np.bincount(group, c.weight, G)
    mean_L = np.bincount(group, c.weighted_length, G) / np.where(w > 0, w, 1.0)
    order = np.lexsort((np.arange(len(group)), np.abs(c.length - mean_L[group]), group))
    head = np.ones(len(order), dtype=bool)
    head[1:] = group[order[1:]] != group[order[:-1]]
    rep = order[head]  # one row per group, in group order
    mag = np.abs(g_gain)
    if not np.any(mag > 0):
        mag = np.linalg.norm(g_M.reshape(G, -1), axis=1)
    strong = mag >= mag.max() * 10.0 ** (-abs(float(min_relative_db)) / 20.0)
    strong &= mag > 0
    rep_s = rep[strong]
    return {"c": c, "g_gain": g_gain[strong], "g_M": g_M[strong], "rep_s": rep_s,
            "tube": c.tube[rep_s], "nk": c.bounce[rep_s].astype(np.int64)}


def _block_finish(geom, groups: dict, tx, rx, max_bounces: int, replayed) -> Paths:
    """:func:`block_paths` after the replay: the strong groups of :func:`_block_groups`
    as :class:`Paths`, their earlier bounce points ``replayed`` (:func:`_replay`)."""
    scene = geom.scene
    c, rep_s, nk = groups["c"], groups["rep_s"], groups["nk"]
    P = len(rep_s)
    pts = np.full((P, max_bounces + 2, 3), np.nan)
    pts[:, 0] = tx.position
    pts[:, 1:max_bounces + 1] = replayed
    # the footprint itself as the engine computed it (the replay agrees to rounding)
    pts[np.arange(P), nk] = c.point[rep_s]
    pts[np.arange(P), nk + 1] = rx.position
    tri_ids = c.tri[rep_s]
    obj = np.where(tri_ids >= 0, scene.tri_object[np.maximum(tri_ids, 0)], -1)
    vel = np.zeros_like(pts)
    vel[:, 0] = tx.velocity
    vel[:, 1:max_bounces + 1] = np.where((tri_ids >= 0)[..., None], scene.point_velocity(
        np.maximum(obj, 0), pts[:, 1:max_bounces + 1]), 0.0)
    vel[np.arange(P), nk + 1] = rx.velocity
    doppler = em.doppler_hz(pts, vel, scene.wavelength_m, num_interactions=nk)
    active = tri_ids >= 0
    return Paths(gain=groups["g_gain"], matrix=groups["g_M"],
                 delay_s=em.delay_s(c.length[rep_s]),
                 doppler_hz=doppler, n_interactions=nk.astype(np.int16),
                 interaction=np.where(active, int(InteractionType.SBR), 0
                                      ).astype(np.int8),
                 points=pts, object_id=obj.astype(np.int32), face_id=tri_ids.astype(np.int32))


@dataclass
class SbrTubes:
    """One transmitter's SBR tubes, radiated toward all its receivers: the windows they
    left through, the receivers' positions (R,3) and the :class:`BlockSums`."""

    windows: TubeWindows
    receivers: np.ndarray
    sums: BlockSums
    max_bounces: int
    #: the receivers as given to :func:`shoot_sbr` (None: positions only)
    radars: list | None = None
    #: :func:`sbr_paths`' paths of every receiver, made together on the first call
    _paths: dict = dataclasses.field(default_factory=dict, init=False, repr=False,
                                     compare=False)

    def __getstate__(self) -> dict:
        # the paths made ahead hold the geometry (device buffers): not pickled
        state = self.__dict__.copy()
        state["_paths"] = {}
        return state

    def receiver_index(self, rx_pos) -> int:
        hit = np.flatnonzero(np.all(self.receivers == np.asarray(rx_pos, np.float64),
                                    axis=1))
        if len(hit) == 0:
            raise ArgumentError("was not among the receivers the tubes were shot for",
                                argument="rx.position", value=list(map(float, rx_pos)))
        return int(hit[0])


def feature_size_m(geom, objects) -> np.ndarray:
    """Per object, the side sqrt(A) of its planar faces (``geom.faces``) below which lies
    FEATURE_AREA_SHARE of its area: the size of the small faces its corners are made of."""
    area = _face_data(geom)["area"]
    out = []
    for o in objects:
        a = area[(geom.faces.object_id == o) & (area > 0)]
        if len(a) == 0:
            out.append(np.inf)
            continue
        order = np.argsort(a)
        share = np.cumsum(a[order]) / a.sum()
        out.append(float(np.sqrt(a[order][np.searchsorted(share, FEATURE_AREA_SHARE)])))
    return np.array(out, dtype=np.float64)


def spacing_for_accuracy(geom, objects, accuracy_db: float) -> np.ndarray:
    """Tube pitch (m) per object for a corner error of at most ``accuracy_db``:
    ``accuracy_db * feature / ERROR_DB_PER_PITCH``, between MIN_SPACING_WAVELENGTHS and
    MAX_SPACING_WAVELENGTHS wavelengths.

    The rule (docs/po.md): a tube grid of pitch s stair-steps the rim of a corner whose
    faces are l across, and the corner's RCS errs by less than ERROR_DB_PER_PITCH * s / l
    dB - a bound derived from the count of tubes along the rims, which the 90 degree
    dihedral and the square trihedral keep against their closed forms from lambda to 100
    lambda (tools/sbr_pitch.py, tests/test_sbr_pitch.py).  l is the object's
    :func:`feature_size_m`; ``accuracy_db`` within ACCURACY_DB_RANGE.
    """
    lam = geom.scene.wavelength_m
    s = float(accuracy_db) * feature_size_m(geom, objects) / ERROR_DB_PER_PITCH
    return np.clip(s, MIN_SPACING_WAVELENGTHS * lam, MAX_SPACING_WAVELENGTHS * lam)


def object_spacing_m(geom, objects, spacing_wavelengths: float | None,
                     accuracy_db: float = 0.5) -> np.ndarray:
    """Tube pitch (m) per object: its own ``sbr_spacing_wavelengths`` scene key where it
    has one, else ``spacing_wavelengths`` (wavelengths of the scene's carrier) where given,
    else :func:`spacing_for_accuracy`."""
    scene = geom.scene
    objects = list(objects)
    if spacing_wavelengths is None:
        out = spacing_for_accuracy(geom, objects, accuracy_db)
    else:
        out = np.full(len(objects), float(spacing_wavelengths) * scene.wavelength_m)
    own = [getattr(scene.objects[o], "sbr_spacing_wavelengths", None) for o in objects]
    return np.array([s if w is None else float(w) * scene.wavelength_m
                     for s, w in zip(out, own, strict=True)], dtype=np.float64)


def shoot_sbr(geom, tx, objects, receivers, *, spacing_wavelengths: float | None = None,
              accuracy_db: float = 0.5, max_bounces: int = 3, first_bounce: int = 2,
              mirrors: bool = True, precision: str = "auto") -> SbrTubes:
    """Shoot tx's tubes over ``objects`` and radiate them toward every receiver (radars):
    what a tracer computes once per transmitter, with the engine ``geom.engine``
    (``precision`` of the device engine: :data:`clradcom.device.sbr.PRECISIONS`)."""
    scene = geom.scene
    objects = np.asarray(list(objects), dtype=np.int64)
    receivers = list(receivers)
    rx_pos = np.array([np.asarray(r.position, dtype=np.float64) for r in receivers]
                      ).reshape(-1, 3)
    windows = blocks_in_pattern(launch_windows(
        geom, tx.position, objects,
        object_spacing_m(geom, objects, spacing_wavelengths, accuracy_db), mirrors=mirrors,
        tx_name=tx.name), tx)
    record = np.isin(scene.tri_object, objects)
    if not (windows.n_tubes and receivers and max_bounces >= first_bounce):
        sums = BlockSums.empty(max_bounces)
    elif geom.engine == "device":
        engines.record("physical_optics.tubes", "device")
        sums = device_block_sums(geom, windows, tx, receivers, max_bounces, first_bounce,
                                 record, precision)
    else:
        engines.record("physical_optics.tubes", "host", fallback=False)
        sums = host_block_sums(geom, windows, tx, receivers, max_bounces, first_bounce,
                               record)
    return SbrTubes(windows=windows, receivers=rx_pos, sums=sums, max_bounces=max_bounces,
                    radars=receivers)


def sbr_paths(geom, tx, rx, *, objects, spacing_wavelengths: float | None = None,
              accuracy_db: float = 0.5, max_bounces: int = 3, first_bounce: int = 2,
              min_relative_db: float = -80.0, mirrors: bool = True,
              shot: SbrTubes | None = None) -> Paths:
    """SBR-PO multi-bounce returns of one tx -> rx link as :class:`Paths`.

    Tubes are shot from tx through the windows of :func:`launch_windows` (pitch
    :func:`object_spacing_m`: the object's own, else ``spacing_wavelengths`` wavelengths,
    else chosen for ``accuracy_db``), bounce off
    anything in the scene, and radiate (module docstring) from every bounce
    >= ``first_bounce`` that lands on one of ``objects`` and sees rx unblocked;
    :func:`block_paths` groups them into paths.  ``shot`` is :func:`shoot_sbr`'s result
    for tx when the caller keeps it across receivers (it must include rx).
    """
    objects = np.asarray(list(objects), dtype=np.int64)
    if geom.caster is None or len(objects) == 0 or max_bounces < first_bounce:
        return Paths.empty(max(first_bounce, 1))
    if shot is None:
        shot = shoot_sbr(geom, tx, objects, [rx], spacing_wavelengths=spacing_wavelengths,
                         accuracy_db=accuracy_db, max_bounces=max_bounces,
                         first_bounce=first_bounce, mirrors=mirrors)
    sums = shot.sums
    if len(sums) == 0:
        return Paths.empty(shot.max_bounces)
    r = shot.receiver_index(rx.position)
    if shot.radars is not None and shot.radars[r] is rx:
        # every receiver's paths at once, their replays in one walk; each handed out once
        key = (float(min_relative_db), r)
        cached = shot._paths.pop(key, None)
        if cached is not None and cached[0] is geom and cached[1] is tx:
            return cached[2]
        made = _shot_paths(geom, shot, tx, min_relative_db)
        for k, p in enumerate(made):
            if k != r:
                shot._paths[(float(min_relative_db), k)] = (geom, tx, p)
        return made[r]
    return block_paths(geom, shot.windows, sums.select(np.flatnonzero(sums.receiver == r)),
                       tx, rx, max_bounces=shot.max_bounces,
                       min_relative_db=min_relative_db)


def _shot_paths(geom, shot: SbrTubes, tx, min_relative_db: float) -> list[Paths]:
    """:func:`block_paths` of every receiver of ``shot`` (its ``radars``), the
    representatives' bounce points replayed in one :func:`_replay` for all."""
    sums, windows, mb = shot.sums, shot.windows, shot.max_bounces
    groups = [_block_groups(windows, sums, tx, rx, min_relative_db,
                            rows=np.flatnonzero(sums.receiver == r))
              for r, rx in enumerate(shot.radars)]
    live = [g for g in groups if g is not None]
    if not live:
        return [Paths.empty(mb) for _ in groups]
    replayed = _replay(geom, windows, np.concatenate([g["tube"] for g in live]),
                       np.concatenate([g["nk"] for g in live]), mb)
    cut = np.cumsum([len(g["tube"]) for g in live])[:-1]
    parts = iter(np.split(replayed, cut))
    return [Paths.empty(mb) if g is None else _block_finish(geom, g, tx, rx, mb, next(parts))
            for g, rx in zip(groups, shot.radars, strict=True)]
