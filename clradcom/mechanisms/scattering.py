"""Single diffuse (Lambertian) scattering from surface tiles (effective-roughness model).

Each triangle of a material with scattering coefficient S > 0 is cut into small
tiles; every tile lit from tx and seen from rx gives one path tx -> tile -> rx,
and with ``max_reflections`` >= 1 also tx -> mirror -> tile -> rx (specular
prefix), tx -> tile -> mirror -> rx (suffix) and, with 2, both (image method,
see :func:`scattering_paths`).  docs/scattering.md gives the model and sources
(Degli-Esposti, "A diffuse scattering model for urban propagation prediction",
IEEE TAP 49(7) 2001; Degli-Esposti, Fuschini, Vitucci, Falciasecca, "Measurement
and modelling of scattering from buildings", IEEE TAP 55(1) pp. 143-153, 2007;
Sionna RT's primer, "Scattering").

Field of a tile of area A at q (incident E_i(q) from tx, scattered towards s)::

    E_s = (S Gamma / r_s) sqrt(f_s cos(theta_i) A) X E_i(q),   f_s = cos(theta_s) / pi

with X the unitary polarisation map (cross-polarisation share K_x, see
:func:`tile_transfer`) carrying two random phases per tile, fixed for the whole
frame.  Since int_hemisphere f_s dOmega = 1, the power scattered into the
hemisphere is S^2 Gamma^2 |E_i|^2 A cos(theta_i), i.e. S^2 Gamma^2 times the
power incident on the tile; the monostatic RCS of a tile is
sigma = 4 S^2 Gamma^2 A cos^2(theta).  In the bookkeeping of :mod:`clradcom.physics.em`
(tx radiates e_tx e^{-jkd}/d, the field at rx is T e_tx e^{-jkL}/L) this is the
transfer dyad::

    T = (L / (r_i r_s)) S Gamma sqrt(A cos(theta_i) cos(theta_s) / pi) X_world

so that, for isotropic antennas,
|a|^2 = lambda^2 S^2 Gamma^2 A cos(theta_i) cos(theta_s) / (16 pi^3 r_i^2 r_s^2).
A planar reflection before (after) the tile replaces tx (rx) by its image, so
r_i (r_s) becomes the unfolded length of that leg, and multiplies T by the
reflection dyad (Fresnel x roughness x sqrt(1 - S_mirror^2)) on that side.
"""

from __future__ import annotations

import math
import warnings
import weakref
from dataclasses import dataclass

import numpy as np

from clradcom.device import engines
from clradcom.device import scatter as device_scatter
from clradcom.device.raycast import spawn_origins
from clradcom.device.visibility import (
    antenna_blocked,
    antenna_slack,
    confirm_margin_m,
    confirm_slack,
    reaches_face,
    surface_sees,
)
from clradcom.errors import ArgumentError, TileSizeWarning
from clradcom.geometry.triangles import (
    point_triangle_distance,
    triangle_areas,
    triangle_normals_and_double_areas,
)
from clradcom.mechanisms.common import Geometry, check_number
from clradcom.paths import InteractionType, Paths
from clradcom.physics import em
from clradcom.physics.vectors import unit
from clradcom.scene.antenna import pattern_peak_gain
from clradcom.scene.records import Radar

__all__ = ["make_tiles", "choose_tile_size", "tile_transfer", "mirror_faces", "reflection_legs",
           "scattering_paths"]

#: Default relative power error of the point-source (far-field) tile approximation.
DEFAULT_ACCURACY = 0.05


def _longest_edges(triangles):
    v = np.asarray(triangles, dtype=np.float64).reshape(-1, 3, 3)
    return np.linalg.norm(v[:, [1, 2, 0]] - v, axis=-1).max(axis=1)


def _subdivisions(triangles, tile_size_m, longest=None):
    """n per triangle: ceil(longest edge / tile size) (``longest``: the triangles'
    :func:`_longest_edges`, when known)."""
    longest = _longest_edges(triangles) if longest is None else longest
    return np.maximum(1, np.ceil(longest / float(tile_size_m) - 1e-9)).astype(np.int64)


def make_tiles(triangles, tile_size_m):
    """Cut triangles into tiles of edge <= ``tile_size_m``.

    Regular barycentric subdivision: a triangle whose longest edge is l is cut
    into n^2 congruent triangles (n = ceil(l / tile_size_m)), each similar to it
    with edges 1/n of its own, so every tile has area A/n^2 and the tile areas of
    a triangle add up to its area exactly.  Each tile is represented by its
    centroid.

    Parameters
    ----------
    triangles : (T,3,3) float  vertices (m); the winding normal (v1-v0)x(v2-v0)
        is the tile normal.
    tile_size_m : float > 0

    Returns
    -------
    centres (N,3), areas (N,), normals (N,3) unit, tri_ids (N,) int64 (index
    into ``triangles``).
    """
    v = np.asarray(triangles, dtype=np.float64).reshape(-1, 3, 3)
    if not (np.isfinite(tile_size_m) and tile_size_m > 0):
        raise ArgumentError(f"tile_size_m must be > 0, got {tile_size_m}")
    if len(v) == 0:
        z = np.zeros((0, 3))
        return z, np.zeros(0), z.copy(), np.zeros(0, np.int64)
    with np.errstate(invalid="ignore", divide="ignore"):  # such triangles are refused below
        nrm, two_a = triangle_normals_and_double_areas(v)
    if np.any(two_a == 0) or not np.all(np.isfinite(two_a)):
        raise ArgumentError("degenerate or non-finite triangle")
    ns = _subdivisions(v, tile_size_m)
    centres, local = _cut_tiles(v, ns)
    return (centres, np.repeat(0.5 * two_a / (ns * ns), ns * ns), np.repeat(nrm, ns * ns, axis=0),
            local)


def _cut_tiles(v, ns):
    """Tile centroids (N,3) of triangles v (K,3,3) cut into ns (K,) x ns tiles each, and
    each tile's triangle (N,): triangle by triangle, in :func:`make_tiles`' order (which
    ``kernels/scatter.cl: tile_centres`` follows: the up tiles row by row, then the down
    tiles)."""
    centres, ids = [], []
    for n in np.unique(ns):
        n = int(n)
        up = [((3 * i + 1) / (3 * n), (3 * j + 1) / (3 * n))
              for i in range(n) for j in range(n - i)]
        dn = [((3 * i + 2) / (3 * n), (3 * j + 2) / (3 * n))
              for i in range(n) for j in range(n - 1 - i)]
        uv = np.array(up + dn, dtype=np.float64).reshape(-1, 2)  # barycentric (u, v)
        sel = np.flatnonzero(ns == n)
        vs = v[sel]
        pts = (vs[:, None, 0] + uv[None, :, 0, None] * (vs[:, None, 1] - vs[:, None, 0])
               + uv[None, :, 1, None] * (vs[:, None, 2] - vs[:, None, 0]))
        centres.append(pts.reshape(-1, 3))
        ids.append(np.repeat(sel, len(uv)))
    if not centres:
        return np.zeros((0, 3)), np.zeros(0, np.int64)
    order = np.argsort(np.concatenate(ids), kind="stable")
    return np.concatenate(centres)[order], np.concatenate(ids)[order]


def choose_tile_size(wavelength, distance, accuracy=DEFAULT_ACCURACY):
    """Largest tile edge D for which a tile acts as a point scatterer.

    A tile is replaced by a point source at its centroid.  Across a tile of edge
    D seen from range R (tx and rx both at >= R) the quadratic (Fresnel) phase
    that the point approximation ignores reaches, over both legs,
    dphi = 2 * k (D/2)^2 / (2R) = pi D^2 / (2 lambda R).  For a phase
    phi = dphi u^2 over a uniform aperture (u in [-1, 1]) the power of the
    coherent tile sum changes by 1 - |<e^{j phi}>|^2 ~ Var(phi) = (4/45) dphi^2;
    requiring this below ``accuracy`` (relative power error) gives::

        dphi <= sqrt(45 accuracy / 4),   D <= sqrt(2 lambda R dphi / pi)
                                           = sqrt(lambda R / 2) * f(accuracy),
        f(accuracy) = 2 (45 accuracy / 4)^{1/4} / sqrt(pi)

    (accuracy 0.05: dphi = 0.75 rad, D = 0.69 sqrt(lambda R); e.g. 24 GHz, 10 m:
    0.24 m).  The 1/R^2 and cosine factors vary linearly across the tile, which
    the centroid integrates exactly, so their error is O((D/R)^2), far smaller.

    The *incoherent* sum sum|a|^2 over tiles does not depend on the tile size
    (the areas add up exactly); the size only sets how finely the delay/Doppler
    spread of a surface is sampled and the speckle of the coherent sum.  So a
    tile should also stay below the radar's range resolution c/(2B) where that
    is smaller (pass the min of both).
    """
    lam = float(wavelength)
    R = float(distance)
    acc = float(accuracy)
    if not (lam > 0 and R > 0 and acc > 0):
        raise ArgumentError("wavelength, distance and accuracy must be > 0")
    return float(_tile_bounds(lam, np.float64(R), acc))


def _tile_bounds(wavelength: float, distance, accuracy: float):
    """:func:`choose_tile_size` over an array of distances (checked by the caller)."""
    dphi = math.sqrt(45.0 * accuracy / 4.0)
    return np.sqrt(2.0 * wavelength * np.asarray(distance, dtype=np.float64) * dphi / math.pi)


def _power_weighted_gamma(e_te, e_tm, r_te, r_tm) -> np.ndarray:
    """|Gamma| of a tile for the incident field's TE/TM components e_te, e_tm and the
    Fresnel coefficients r_te, r_tm: the power-weighted sqrt((|r_te e_te|^2 +
    |r_tm e_tm|^2) / (|e_te|^2 + |e_tm|^2)), the mean of the two powers where no field
    arrives."""
    p_in = np.abs(e_te) ** 2 + np.abs(e_tm) ** 2
    some = p_in > 0
    g2 = np.where(some, (np.abs(r_te * e_te) ** 2 + np.abs(r_tm * e_tm) ** 2)
                  / np.where(some, p_in, 1.0), 0.5 * (np.abs(r_te) ** 2 + np.abs(r_tm) ** 2))
    return np.sqrt(g2)


def _te_basis(k, n):
    """TE (perpendicular to the plane of incidence) and TM unit vectors for
    propagation directions k (P,3) at a surface with normal n (P,3)."""
    te = np.cross(k, n)
    nn = np.linalg.norm(te, axis=-1)
    bad = nn < 1e-9
    if np.any(bad):  # along the normal: any perpendicular
        a = np.where(np.abs(n[bad, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
        te[bad] = np.cross(n[bad], a)
        nn = np.linalg.norm(te, axis=-1)
    te = te / nn[:, None]
    tm = np.cross(te, k)
    return te, tm


def tile_transfer(centres, areas, normals, tx_pos, rx_pos, scattering, gamma,
                  cross_pol_share, phases, carrier_hz=None):
    """Transfer dyads T (N,3,3), L (N,), k_dep, k_arr of tiles (front sides).

    T = (L/(r_i r_s)) S Gamma sqrt(A cos(theta_i) cos(theta_s)/pi) X_world, with
    X_world = [e^{j chi1} sqrt(1-K) I + e^{j chi2} sqrt(K) (s x .)] R0,
    R0 = -te_s te_i^T + tm_s tm_i^T
    (te = k x n / |k x n|, tm = te x k; R0 maps the incident transverse plane onto
    the scattered one like a PEC reflection: -I at normal incidence).  The co-pol
    part keeps the polarisation, the cross-pol part is it turned by 90 degrees
    about s, each with its own random phase.  For any linearly polarised
    incident field the power splits exactly (1-K) co-pol / K cross-pol and the
    total is preserved; for elliptical fields on average over the phases.  (The
    reference's X applies the phases per (theta, phi) output component, which
    makes the split depend on that basis; this form does not.)
    ``phases`` (N,2) = (chi1, chi2).
    ``gamma`` (N,) is |Gamma| (see :func:`scattering_paths`).
    """
    c = np.asarray(centres, dtype=np.float64).reshape(-1, 3)
    n = unit(np.asarray(normals, dtype=np.float64).reshape(-1, 3))
    dt = c - np.asarray(tx_pos, dtype=np.float64).reshape(-1, 3)
    dr = np.asarray(rx_pos, dtype=np.float64).reshape(-1, 3) - c
    r_i = np.linalg.norm(dt, axis=-1)
    r_s = np.linalg.norm(dr, axis=-1)
    if np.any(r_i == 0) or np.any(r_s == 0):
        raise ArgumentError("tx or rx coincides with a tile centre")
    ki, s = dt / r_i[:, None], dr / r_s[:, None]
    cos_i = np.clip(-np.einsum("pi,pi->p", ki, n), 0.0, 1.0)
    cos_s = np.clip(np.einsum("pi,pi->p", s, n), 0.0, 1.0)
    L = r_i + r_s
    te_i, tm_i = _te_basis(ki, n)
    te_s, tm_s = _te_basis(s, n)
    K = np.broadcast_to(np.asarray(cross_pol_share, dtype=np.float64), L.shape)
    ph = np.asarray(phases, dtype=np.float64).reshape(-1, 2)
    e1, e2 = np.exp(1j * ph[:, 0]), np.exp(1j * ph[:, 1])
    co, cx = np.sqrt(1.0 - K), np.sqrt(K)

    def outer(a, b):
        return a[:, :, None] * b[:, None, :]

    # R0: the PEC-like reflection map of the transverse plane of k_i onto that of s
    # (-I at normal incidence, so backscatter keeps the polarisation); J = s x .
    R0 = -outer(te_s, te_i) + outer(tm_s, tm_i)
    J = np.zeros((len(L), 3, 3))
    J[:, 0, 1], J[:, 0, 2] = -s[:, 2], s[:, 1]
    J[:, 1, 0], J[:, 1, 2] = s[:, 2], -s[:, 0]
    J[:, 2, 0], J[:, 2, 1] = -s[:, 1], s[:, 0]
    X = (e1 * co)[:, None, None] * R0 + (e2 * cx)[:, None, None] * (J @ R0)
    amp = (L / (r_i * r_s) * np.asarray(scattering, dtype=np.float64) * np.asarray(gamma)
           * np.sqrt(np.asarray(areas, dtype=np.float64) * cos_i * cos_s / np.pi))
    return amp[:, None, None] * X, L, ki, s


#: Reflecting faces smaller than this (m^2) take no part in scattering paths (see
#: :func:`mirror_faces`).
DEFAULT_MIN_FACE_AREA_M2 = 1.0

# a tile closer than this to a mirror's plane lies in it: no reflection there
_PLANE_EPS_M = 1e-6


def mirror_faces(geom, min_area_m2=DEFAULT_MIN_FACE_AREA_M2):
    """Planar faces that may reflect before or after a tile: ``(ids, lo, hi)``.

    A face qualifies when its material keeps some specular field (S < 1, so
    sqrt(1 - S^2) > 0) and its area is at least ``min_area_m2``: a facet much
    smaller than the first Fresnel zone (sqrt(lambda d), 0.35 m at 24 GHz and
    10 m) is no mirror, and the cost grows with tiles x faces.  The choice is
    geometric, the same for every tx and rx, so a link and its reverse use the
    same mirrors (reciprocity) whatever rays the tracer launched.  ``lo``/``hi``
    (F,3) are the axis-aligned boxes of *all* faces, a cheap pre-test of the
    image method's reflection point before any ray is cast.
    """
    scene, faces = geom.scene, geom.faces
    tri = scene.triangles
    F = faces.n_faces
    lo = np.full((F, 3), np.inf)
    hi = np.full((F, 3), -np.inf)
    np.minimum.at(lo, faces.tri_face, tri.min(axis=1))
    np.maximum.at(hi, faces.tri_face, tri.max(axis=1))
    area = np.bincount(faces.tri_face, minlength=F, weights=triangle_areas(tri))
    S = scene.material_scattering[faces.material_id]
    ids = np.flatnonzero((S < 1.0) & (area >= float(min_area_m2)))
    return ids, lo, hi


def reflection_legs(geom, end, q, nrm, tri_ids, tiles, face_ids, lo, hi):
    """Confirmed one-reflection legs ``end -> p (on a face) -> tile`` by the image method.

    For every tile in ``tiles`` (indices into q/nrm/tri_ids) and face in
    ``face_ids``: ``end`` and the tile on the same side of the face's plane, the
    tile's front facing the image end' of ``end``, the reflection point p (where
    tile -> end' crosses the plane) inside the face's box; then two ray casts
    confirm the leg: ``end -> p`` must first meet that face at p (so p lies
    inside the face and nothing blocks it;
    :func:`clradcom.device.visibility.reaches_face`, as for specular paths), and
    nothing may lie between the tile (origin spawned off it, its own triangle
    ignored) and p.  The same
    function serves prefixes (end = tx) and suffixes (end = rx), so a path and
    its reverse are confirmed by identical rays.

    Returns ``(tile, face, p, image, tri)``: (M,) tile indices, (M,) face ids,
    (M,3) reflection points, (M,3) images of ``end``, (M,) scene triangle hit at p.
    """
    end = np.asarray(end, dtype=np.float64)
    fn, fd = geom.faces.normal, geom.faces.offset
    qq, nn = q[tiles], nrm[tiles]
    cols = ([], [], [], [])
    for f in face_ids:
        se = float(fn[f] @ end - fd[f])
        if abs(se) <= _PLANE_EPS_M:
            continue
        sq = qq @ fn[f] - fd[f]
        img = end - 2.0 * se * fn[f]
        ok = (sq * se > 0) & (np.abs(sq) > _PLANE_EPS_M)
        ok &= np.einsum("pi,pi->p", nn, img - qq) > 0
        t = sq / (sq + se)  # fraction of the way from the tile to the image
        p = qq + t[:, None] * (img - qq)
        tol = confirm_margin_m(p)[:, None]
        ok &= np.all((p >= lo[f] - tol) & (p <= hi[f] + tol), axis=1)
        sel = np.flatnonzero(ok)
        cols[0].append(sel)
        cols[1].append(np.full(len(sel), f, np.int64))
        cols[2].append(p[sel])
        cols[3].append(np.broadcast_to(img, (len(sel), 3)))
    if not cols[0] or sum(len(c) for c in cols[0]) == 0:
        z = np.zeros(0, np.int64)
        return z, z.copy(), np.zeros((0, 3)), np.zeros((0, 3)), z.copy()
    loc = np.concatenate(cols[0])
    face = np.concatenate(cols[1])
    p = np.concatenate(cols[2])
    img = np.concatenate(cols[3])
    tile = np.asarray(tiles)[loc]
    # end -> p: the first thing met must be this face, at p; the first millimetre from the
    # antenna is decided in float64, as for specular paths
    start = np.broadcast_to(end, p.shape)
    length = np.linalg.norm(p - start, axis=1)
    slack = confirm_slack(p, length)
    prim = reaches_face(geom.caster, geom.faces.tri_face, start, p, face, slack,
                        tmin=antenna_slack(start, length), engine=geom.engine)
    good = prim >= 0
    good[good] = ~antenna_blocked(geom.caster, geom.faces.tri_face, end, p[good],
                                  2.0 * confirm_margin_m(start[good]))
    # tile -> p: nothing in between (stop short of the mirror itself)
    idx = np.flatnonzero(good)
    if len(idx):
        good[idx] = surface_sees(geom.caster, q[tile[idx]], nrm[tile[idx]], p[idx],
                                 tri_ids[tile[idx]], stop_short_m=confirm_margin_m(p[idx]),
                                 tri_face=geom.faces.tri_face, engine=geom.engine)
    return tile[good], face[good], p[good], img[good], prim[good].astype(np.int64)


def _visible(geom, q, nrm, tri_ids, idx, end):
    """Mask over ``idx``: nothing between tile q and ``end`` (tile's triangle ignored)."""
    return surface_sees(geom.caster, q[idx], nrm[idx], end, tri_ids[idx],
                        tri_face=geom.faces.tri_face, engine=geom.engine)


def _antenna_clear(geom, q, nrm, end):
    """Mask over tiles q whose float32 sight line to the antenna ``end`` is clear: the
    float64 part of :func:`clradcom.device.visibility.surface_sees` (the last
    millimetres at the antenna, :func:`antenna_blocked`), from the same spawned origins."""
    if len(q) == 0:
        return np.zeros(0, dtype=bool)
    end = np.asarray(end, dtype=np.float64)
    org = spawn_origins(q, nrm, end - q)
    t = np.broadcast_to(end, org.shape)
    return ~antenna_blocked(geom.caster, geom.faces.tri_face, t, org, 2.0 * confirm_margin_m(t))


def _host_tiles(geom, plan, kb, phases, tx_pos, rx_pos, mr, monostatic):
    """The numpy reference (``engine="host"``): the tiles of plan pieces ``kb`` (one batch),
    their sight of tx and rx; ``phases`` theirs (:func:`_batch_phases`)."""
    q, local = _cut_tiles(plan.vertices[kb], plan.n[kb])
    area, nrm, tri_ids = plan.tile_area[kb][local], plan.normals[kb][local], plan.prim[kb][local]
    N = len(q)
    front_t = np.einsum("pi,pi->p", nrm, tx_pos - q) > 0
    front_r = np.einsum("pi,pi->p", nrm, rx_pos - q) > 0
    vis_t = np.zeros(N, dtype=bool)
    vis_r = np.zeros(N, dtype=bool)
    if mr == 0:  # only direct paths: test the second end only where the first is seen
        idx = np.flatnonzero(front_t & front_r)
        vis_t[idx] = _visible(geom, q, nrm, tri_ids, idx, tx_pos)
        idx = idx[vis_t[idx]]
        vis_r[idx] = _visible(geom, q, nrm, tri_ids, idx, rx_pos)
        vis_t &= vis_r
    else:
        idx = np.flatnonzero(front_t)
        vis_t[idx] = _visible(geom, q, nrm, tri_ids, idx, tx_pos)
        if monostatic:
            vis_r = vis_t.copy()
        else:
            idx = np.flatnonzero(front_r)
            vis_r[idx] = _visible(geom, q, nrm, tri_ids, idx, rx_pos)
    return q, area, nrm, tri_ids, phases, vis_t, vis_r, np.flatnonzero(vis_t & vis_r)


def _device_tiles(geom, plan, kb, phases, tx_pos, rx_pos, monostatic):
    """The same as :func:`_host_tiles` with reflections around the tiles (``max_reflections``
    >= 1) from the kernels of :mod:`clradcom.device.scatter`.

    Tiles, front sides and the float32 sight casts run on the device; every tile's centre
    and flags come back (the reflected legs start from any of them); the host keeps the
    per-piece numbers (subdivisions, normals, areas), the random phases and the float64
    antenna ends of the tiles the casts let through."""
    scene = geom.scene
    S = scene.material_scattering[scene.tri_material[plan.prim[kb]]]
    sight = device_scatter.tile_sight(geom.caster, plan.vertices[kb], plan.normals[kb],
                                      plan.tile_area[kb], S, plan.prim[kb], plan.n[kb],
                                      tx_pos, rx_pos, scene.wavelength_m,
                                      all_ends=True, monostatic=monostatic,
                                      tri_face=geom.faces.tri_face)
    counts = plan.n[kb] * plan.n[kb]
    j = np.repeat(np.arange(len(kb)), counts)  # each tile's piece within the batch
    q, nrm = sight.centres, plan.normals[kb][j]
    vis_t = (sight.flags & device_scatter.SEES_TX) != 0
    vis_t[vis_t] = _antenna_clear(geom, q[vis_t], nrm[vis_t], tx_pos)
    if monostatic:
        vis_r = vis_t.copy()
    else:
        vis_r = (sight.flags & device_scatter.SEES_RX) != 0
        vis_r[vis_r] = _antenna_clear(geom, q[vis_r], nrm[vis_r], rx_pos)
    return (q, plan.tile_area[kb][j], nrm, plan.prim[kb][j], phases, vis_t, vis_r,
            np.flatnonzero(vis_t & vis_r))


#: a piece of a scattering triangle is halved (cut into four by its edges' midpoints) while
#: its tiles at its own accuracy bound would be more than this many to an edge: the pieces
#: farther from the antennas then take larger tiles (the bound grows as sqrt(distance))
ADAPTIVE_PIECE_N = 8
#: with an explicit tile size, a triangle is cut into four while it holds more than this
#: many tiles to an edge (so that one piece fits a batch; smaller triangles keep the
#: regular n x n cut of make_tiles)
EXPLICIT_PIECE_N = 256
#: tiles handled at once: a surface of any size is streamed through in batches (a batch
#: holds ~300 bytes per tile at its peak, host and device together: on a 200 m road
#: square, 1.2 million tiles, the peak resident memory was 425 MB with batches of 2^14 to
#: 2^17 tiles, most of it the OpenCL runtime, and 754 MB with 2^20)
BATCH_TILES = 1 << 17


@dataclass(frozen=True)
class TilePlan:
    """How one link's scattering triangles are cut into tiles: K pieces, each a triangle
    (a scattering triangle or a part of it from repeated cuts into four) with n x n tiles.

    ``vertices`` (K,3,3), ``prim`` (K,) scene triangle ids, ``normals`` (K,3) unit (their
    triangle's), ``tile_area`` (K,), ``n`` (K,), ``first`` (K+1,) the index of each
    piece's first tile among all tiles (the random phases' rows), ``bound`` (K,) the
    accuracy bound (m) at each piece's nearest point to the nearer antenna, ``size`` the
    explicit tile size or None (adaptive)."""

    vertices: np.ndarray
    prim: np.ndarray
    normals: np.ndarray
    tile_area: np.ndarray
    n: np.ndarray
    first: np.ndarray
    bound: np.ndarray
    size: float | None

    @property
    def tile_edges(self) -> np.ndarray:
        """Each piece's longest tile edge (m)."""
        return _longest_edges(self.vertices) / self.n


def _split4(v):
    """Each triangle (K,3,3) cut into four by its edges' midpoints (K*4,3,3), the four
    of a triangle consecutive, each wound as it is."""
    a, b, c = v[:, 0], v[:, 1], v[:, 2]
    ab, bc, ca = 0.5 * (a + b), 0.5 * (b + c), 0.5 * (c + a)
    return np.stack([np.stack([a, ab, ca], 1), np.stack([ab, b, bc], 1),
                     np.stack([ca, bc, c], 1), np.stack([ab, bc, ca], 1)], 1).reshape(-1, 3, 3)


def _nearest_distance(v, tx_pos, rx_pos, wavelength):
    """Distance (K,) from each triangle's closest point to the nearer antenna, at least
    one wavelength (the tile rule's far-field floor)."""
    d = np.minimum(point_triangle_distance(tx_pos, v), point_triangle_distance(rx_pos, v))
    return np.maximum(d, wavelength)


def tile_plan(st, tx_pos, rx_pos, wavelength, *, tile_size_m=None,
              accuracy=DEFAULT_ACCURACY) -> TilePlan:
    """The tiles of one link (``st``: the scene's :class:`_ScatterTriangles`).

    ``tile_size_m=None`` (adaptive): every piece takes the tile size that
    :func:`choose_tile_size` allows at its own nearest point (closest point on the
    triangle, not its centroid) to the nearer antenna, and a piece that would hold more
    than :data:`ADAPTIVE_PIECE_N` tiles to an edge is cut into four first, again and
    again, so the tiles grow with the distance as the bound does and no tile anywhere is
    coarser than its bound. A road square of 200 m half-width seen from 0.55 m holds
    1.2 million tiles this way, where one size everywhere would need 2 x 10^8.

    An explicit ``tile_size_m``: the regular n x n cut of :func:`make_tiles` at that
    size for every triangle (a triangle with more than :data:`EXPLICIT_PIECE_N` tiles to
    an edge cut into four first); no cap.
    """
    if st.degenerate:
        raise ArgumentError("degenerate or non-finite triangle")
    lam = float(wavelength)
    acc = float(accuracy)
    if not (math.isfinite(acc) and acc > 0):
        raise ArgumentError("must be a finite number > 0", argument="accuracy", value=accuracy)
    size = None if tile_size_m is None else float(tile_size_m)
    if size is not None and not (math.isfinite(size) and size > 0):
        raise ArgumentError(f"tile_size_m must be > 0, got {tile_size_m}")
    limit = ADAPTIVE_PIECE_N if size is None else EXPLICIT_PIECE_N
    v, owner, level, longest = st.tris, np.arange(len(st.tris)), np.zeros(len(st.tris),
                                                                         np.int64), st.longest
    out = []
    while len(v):
        bound = _tile_bounds(lam, _nearest_distance(v, tx_pos, rx_pos, lam), acc)
        # make_tiles' n = ceil(l / D), with D the piece's own bound or the explicit size
        n = np.maximum(1, np.ceil(longest / (bound if size is None else size) - 1e-9)
                       ).astype(np.int64)
        split = n > limit
        keep = ~split
        out.append((v[keep], owner[keep], level[keep], n[keep], bound[keep]))
        v = _split4(v[split])
        owner = np.repeat(owner[split], 4)
        level = np.repeat(level[split] + 1, 4)
        longest = _longest_edges(v)
    v, owner, level, n, bound = (np.concatenate(c) for c in zip(*out, strict=True))
    order = np.argsort(owner, kind="stable")  # piece by piece within each triangle's order
    v, owner, level, n, bound = v[order], owner[order], level[order], n[order], bound[order]
    counts = n * n
    first = np.concatenate([[0], np.cumsum(counts)])
    return TilePlan(vertices=v, prim=st.sel[owner], normals=st.normals[owner],
                    tile_area=0.5 * st.two_a[owner] / (counts * 4 ** level), n=n, first=first,
                    bound=bound, size=size)


def _warn_coarse_tiles(scene, plan: TilePlan, traced, accuracy):
    """One :class:`~clradcom.errors.TileSizeWarning` when traced pieces' tiles are coarser
    than their accuracy bound (an explicit tile size), naming the surface whose bound is
    smallest, that bound and how many other surfaces share the fault."""
    edges = plan.tile_edges[traced]
    bound = plan.bound[traced]
    coarse = np.flatnonzero(edges > bound * (1.0 + 1e-9))
    if len(coarse) == 0:
        return
    worst = coarse[np.argmin(bound[coarse])]
    prim = plan.prim[traced]
    objects = np.unique(scene.tri_object[prim[coarse]])
    obj = int(scene.tri_object[prim[worst]])
    name = scene.objects[obj].name if obj < len(scene.objects) else str(obj)
    others = len(objects) - 1
    warnings.warn(TileSizeWarning(
        f"scattering tiles of {edges[worst]:.3g} m on surface '{name}' (triangle "
        f"{int(prim[worst])}) are coarser than their accuracy bound {bound[worst]:.3g} m "
        f"(the tile-size rule at accuracy {accuracy:g}, for its nearest point "
        f"{float(_bound_distance(bound[worst], scene.wavelength_m, accuracy)):.3g} m from "
        f"the nearer antenna)" + (f"; {others} other surface(s) too" if others else "")
        + ": a tile there is no point scatterer; set ScatteringSettings.tile_size_m = 0 "
        "(tiles chosen per surface) or a size within the bound"), stacklevel=3)


def _bound_distance(bound, wavelength, accuracy):
    """The distance at which :func:`_tile_bounds` gives ``bound`` (its inverse)."""
    dphi = math.sqrt(45.0 * accuracy / 4.0)
    return bound ** 2 * math.pi / (2.0 * wavelength * dphi)


def _batches(counts, batch_tiles):
    """Consecutive index ranges [a, b) of pieces with ``counts`` tiles, each range holding
    at most ``batch_tiles`` tiles (or one piece that alone holds more)."""
    cum = np.concatenate([[0], np.cumsum(counts)])
    out, a = [], 0
    while a < len(counts):
        b = int(np.searchsorted(cum, cum[a] + batch_tiles, side="right")) - 1
        b = max(b, a + 1)
        out.append((a, b))
        a = b
    return out


def _batch_phases(seed, first, kb):
    """The two random phases (chi1, chi2) of every tile of pieces ``kb`` (ascending), in
    tile order: the rows first[k] .. first[k+1] of ``default_rng(seed).uniform(0, 2 pi,
    (all tiles, 2))``, drawn by advancing the generator to each run of consecutive pieces
    (so a batch costs memory for its own tiles only, and the phases never depend on the
    batches or on which pieces are traced)."""
    kb = np.asarray(kb, dtype=np.int64)
    if len(kb) == 0:
        return np.zeros((0, 2))
    breaks = np.flatnonzero(np.diff(kb) != 1) + 1
    out = []
    for run in np.split(kb, breaks):
        a, b = int(first[run[0]]), int(first[run[-1] + 1])
        bitgen = np.random.PCG64(seed)
        bitgen.advance(2 * a)  # two doubles (one 64-bit draw each) per tile before it
        out.append(np.random.Generator(bitgen).uniform(0.0, 2.0 * np.pi, size=(b - a, 2)))
    return np.concatenate(out)


@dataclass(frozen=True, eq=False)
class _ScatterTriangles:
    """A scene's scattering triangles (material S > 0) and what every link needs of them."""

    triangles: np.ndarray  # the scene arrays they were taken from (identity checked)
    tri_material: np.ndarray
    material_scattering: np.ndarray  # the materials' S (values checked)
    sel: np.ndarray  # (T_s,) scene triangle ids
    tris: np.ndarray  # (T_s, 3, 3)
    longest: np.ndarray  # longest edges
    centroids: np.ndarray
    normals: np.ndarray  # unit
    two_a: np.ndarray  # twice the areas
    degenerate: bool


# per scene: its _ScatterTriangles (computed on the first link, kept while the scene lives)
_TRIANGLES: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def _scattering_triangles(scene) -> _ScatterTriangles:
    """The scene's :class:`_ScatterTriangles`, computed once per scene (again if its
    triangle or material arrays were replaced or its materials' S changed)."""
    st = _TRIANGLES.get(scene)
    S = scene.material_scattering
    if (st is not None and st.triangles is scene.triangles
            and st.tri_material is scene.tri_material
            and np.array_equal(st.material_scattering, S)):
        return st
    sel = np.flatnonzero(S[scene.tri_material] > 0)
    tris = scene.triangles[sel]
    with np.errstate(invalid="ignore", divide="ignore"):  # such triangles are refused later
        nrm, two_a = triangle_normals_and_double_areas(tris)
    st = _ScatterTriangles(scene.triangles, scene.tri_material, S, sel, tris,
                           _longest_edges(tris), tris.mean(axis=1), nrm, two_a,
                           bool(np.any(two_a == 0) or not np.all(np.isfinite(two_a))))
    _TRIANGLES[scene] = st
    return st


def _object_motion(scene):
    """(velocity, angular velocity, rotation centre), each (objects, 3), of the scene's
    objects: a material point p of object i moves with v_i + omega_i x (p - c_i)
    (:meth:`clradcom.scene.records.Scene.point_velocity`)."""
    n = len(scene.objects)
    omega = np.zeros((n, 3))
    centre = np.zeros((n, 3))
    for i, o in enumerate(scene.objects):
        if o.motion is not None and o.motion.angular_velocity_deg_s is not None:
            omega[i] = o.motion.angular_velocity
            centre[i] = o.motion.rotation_centre
    return np.asarray(scene.object_velocity, dtype=np.float64).reshape(n, 3), omega, centre


def _device_direct_rows(geom, tx, rx, plan, kb, phases, tx_pos, rx_pos, monostatic):
    """Direct paths tx -> tile -> rx (``max_reflections`` 0) of plan pieces ``kb`` (one
    batch) with their fields from the kernels (:func:`clradcom.device.scatter.tile_sight`
    with ``tile_fields``): the rows of :func:`_path_rows`, before the threshold.

    The kernel gives each row its length, Doppler, antenna directions, polarimetric
    matrix for Gamma = 1, Fresnel coefficients and the tx basis' TE/TM projections at the
    tile; here the antenna patterns are applied (as to the SBR kernel's matrices), Gamma
    for the polarisation tx sends (:func:`_path_rows`' rule). Rows whose float64 antenna
    end the kernel leaves open (a triangle within millimetres of an antenna) are decided
    by :func:`_antenna_clear`, the host's test."""
    scene = geom.scene
    tid_k = plan.prim[kb]
    mat = scene.tri_material[tid_k]
    obj = scene.tri_object[tid_k]
    eps = np.asarray(scene.material_eps_r, dtype=np.complex128)[mat]
    pec = (np.asarray(scene.material_pec, dtype=bool)[mat] | np.isinf(eps.real)
           | np.isinf(eps.imag))
    v_obj, omega, centre = _object_motion(scene)
    S = scene.material_scattering[mat]
    tri_par = np.column_stack([S, scene.material_cross_pol_share[mat], eps.real, eps.imag,
                               pec.astype(np.float64), v_obj[obj], omega[obj], centre[obj]])
    counts = plan.n[kb] * plan.n[kb]
    inputs = device_scatter.FieldInputs(
        tri_par=tri_par, glob_first=np.concatenate([[0], np.cumsum(counts)[:-1]]),
        phases=phases, tx_velocity=tx.velocity, rx_velocity=rx.velocity,
        tx_frame=tx.orientation, rx_frame=rx.orientation)
    sight = device_scatter.tile_sight(geom.caster, plan.vertices[kb], plan.normals[kb],
                                      plan.tile_area[kb], S, tid_k, plan.n[kb], tx_pos,
                                      rx_pos, scene.wavelength_m, all_ends=False,
                                      monostatic=monostatic, fields=inputs,
                                      tri_face=geom.faces.tri_face)
    F = sight.fields

    def col(name, rows=slice(None)):
        first, width = device_scatter.FIELD_COLUMNS[name]
        return F[rows, first] if width == 1 else F[rows, first:first + width]

    j = sight.triangle
    open_ = np.flatnonzero(sight.column("undecided") != 0)
    if len(open_):  # a triangle near an antenna: the host's float64 test decides
        q, nrm = col("centre", open_), plan.normals[kb][j[open_]]
        clear = _antenna_clear(geom, q, nrm, tx_pos)
        clear[clear] = _antenna_clear(geom, q[clear], nrm[clear], rx_pos)
        keep = np.ones(len(F), dtype=bool)
        keep[open_[~clear]] = False
        F, j = F[keep], j[keep]
    P = len(F)
    if P == 0:
        return None
    c_tx = np.asarray(tx.pattern.field(col("tx_dir")), dtype=np.complex128)
    if rx is tx:  # -k_arr = k_dep bit for bit (tile_fields negates exactly): the same field
        c_rx = c_tx
    else:
        c_rx = np.asarray(rx.pattern.field(col("rx_dir")), dtype=np.complex128)
    proj, fres = col("proj"), col("fresnel").view(np.complex128)
    e_te = c_tx[:, 0] * proj[:, 0] + c_tx[:, 1] * proj[:, 1]
    e_tm = c_tx[:, 0] * proj[:, 2] + c_tx[:, 1] * proj[:, 3]
    r_te, r_tm = fres[:, 0], fres[:, 1]
    gamma = _power_weighted_gamma(e_te, e_tm, r_te, r_tm)
    M0 = col("matrix").view(np.complex128)  # (P, 4): VV, VH, HV, HH for Gamma = 1
    gain = gamma * (c_rx[:, 0] * (M0[:, 0] * c_tx[:, 0] + M0[:, 1] * c_tx[:, 1])
                    + c_rx[:, 1] * (M0[:, 2] * c_tx[:, 0] + M0[:, 3] * c_tx[:, 1]))
    L = col("length")
    em.check_path_lengths(L, scene.wavelength_m, stacklevel=3)
    tid = tid_k[j]
    pts = np.empty((P, 3, 3))
    pts[:, 0] = tx_pos
    pts[:, 1] = col("centre")
    pts[:, 2] = rx_pos
    return (gain, (gamma[:, None] * M0).reshape(P, 2, 2), L, col("doppler"),
            np.ones(P, np.int16), np.full((P, 1), int(InteractionType.SCATTERING), np.int8),
            pts, scene.tri_object[tid][:, None], tid[:, None])


class _KeptRows:
    """Path rows gathered batch by batch under the link's threshold: rows below
    |threshold| x the strongest so far are dropped at once (they stay below it, since the
    strongest only grows), the rest when :meth:`paths` knows the final strongest. Memory:
    the rows that may still be emitted."""

    def __init__(self, threshold_db, reference_gain):
        self.thr = 10.0 ** (-abs(float(threshold_db)) / 20.0)
        self.top = float(np.abs(reference_gain)) if reference_gain is not None else 0.0
        self.fixed = reference_gain is not None
        self.rows = []
        self.block = []
        self.total = 0

    def add(self, rows, block=None):
        """rows: (gain, matrix, L, doppler, n_interactions, codes, points, object ids, face
        ids), as :func:`_path_rows` returns them; ``block`` (P,) the kind of each row
        (direct, prefix, suffix, both), the order of :meth:`paths`."""
        if rows is None or len(rows[0]) == 0:
            return
        mag = np.abs(rows[0])
        self.total += len(mag)
        if not self.fixed:
            self.top = max(self.top, float(mag.max()))
        sel = np.flatnonzero((mag > 0) & (mag >= self.top * self.thr))
        self.rows.append([c[sel] for c in rows])
        self.block.append(np.zeros(len(sel), np.int8) if block is None else block[sel])

    def paths(self):
        """(Paths, n_dropped): the rows at or above the final threshold, by block (stable:
        batch by batch and in each batch's order within a block)."""
        if not self.rows:
            return Paths.empty(1), self.total
        width = max(c[6].shape[1] for c in self.rows)
        cols = []
        for i in range(9):
            parts = [c[i] for c in self.rows]
            if i in (5, 7, 8):  # codes, object and face ids: (P, K) padded to the widest
                parts = [np.pad(c, ((0, 0), (0, width - 2 - c.shape[1])),
                                constant_values=0 if i == 5 else -1) for c in parts]
            elif i == 6:  # points (P, K + 2, 3), NaN padded
                parts = [np.pad(c, ((0, 0), (0, width - c.shape[1]), (0, 0)),
                                constant_values=np.nan) for c in parts]
            cols.append(np.concatenate(parts))
        gain, M, L, doppler, nk, code, pts, oid, fid = cols
        order = np.argsort(np.concatenate(self.block), kind="stable")
        mag = np.abs(gain[order])
        sel = order[(mag > 0) & (mag >= self.top * self.thr)]
        m = len(sel)
        K = max(1, int(nk[sel].max())) if m else 1
        paths = Paths(gain=gain[sel], matrix=M[sel], delay_s=em.delay_s(L)[sel],
                      doppler_hz=doppler[sel], n_interactions=nk[sel],
                      interaction=code[sel, :K], points=pts[sel, :K + 2],
                      object_id=oid[sel, :K], face_id=fid[sel, :K])
        return paths, int(self.total - m)


def _mirror_dyads(scene, faces, face, k_in):
    """Reflection dyads at mirror faces (identity where face < 0): Fresnel x roughness
    x sqrt(1 - S^2), as :func:`clradcom.mechanisms.specular.path_fields` weighs specular paths."""
    P = len(face)
    D = np.broadcast_to(np.eye(3, dtype=np.complex128), (P, 3, 3)).copy()
    act = np.flatnonzero(face >= 0)
    if len(act) == 0:
        return D
    f = face[act]
    D[act] = em.material_reflection_dyad(scene, faces.material_id[f], k_in[act],
                                         faces.normal[f])
    return D


def _join(a_tile, b_tile):
    """All index pairs (i, j) with a_tile[i] == b_tile[j], in the order of a."""
    order = np.argsort(b_tile, kind="stable")
    sb = b_tile[order]
    lo = np.searchsorted(sb, a_tile, side="left")
    hi = np.searchsorted(sb, a_tile, side="right")
    cnt = hi - lo
    i = np.repeat(np.arange(len(a_tile)), cnt)
    start = np.repeat(lo - np.cumsum(cnt) + cnt, cnt)
    j = order[start + np.arange(len(i))] if len(i) else np.zeros(0, np.int64)
    return i, j


def scattering_paths(geom, tx, rx, *, tile_size_m=None, threshold_db=-60.0, seed=0,
                     reference_gain=None, accuracy=DEFAULT_ACCURACY, max_reflections=0,
                     min_face_area_m2=DEFAULT_MIN_FACE_AREA_M2, triangle_mask=None,
                     batch_tiles=BATCH_TILES):
    """Single diffuse-scattering paths of one tx -> rx link: ``(Paths, n_dropped)``.

    Tiles are cut from every scene triangle whose material has S > 0 as
    :func:`tile_plan` says: ``tile_size_m=None`` gives every part of a surface the
    size :func:`choose_tile_size` allows at its nearest point to the nearer antenna
    (pieces cut into four until it does), an explicit size the regular cut of
    :func:`make_tiles` everywhere, with a :class:`~clradcom.errors.TileSizeWarning`
    naming the surface where that is coarser than the bound.  There is no cap on the
    number of tiles: they are streamed through in batches of about ``batch_tiles``
    (host and device memory bounded by the batch and the rows kept).

    Paths, in this order (each block by tile, then mirror face):

    * direct ``tx -> tile -> rx`` for every tile with its front towards both
      ends (n . (tx - q) > 0 and n . (rx - q) > 0, n the source triangle's
      winding normal, outward for a closed mesh) and nothing hit on q -> tx and
      q -> rx (:func:`clradcom.device.visibility.surface_sees`, origins spawned
      off the tile, the source triangle ignored);
    * ``max_reflections >= 1``: prefix ``tx -> p -> tile -> rx`` and suffix
      ``tx -> tile -> p -> rx`` with one specular reflection at p on a face of
      :func:`mirror_faces` (``min_face_area_m2``), found by the image method
      and confirmed by :func:`reflection_legs`; the other leg as for direct;
    * ``max_reflections >= 2``: ``tx -> p1 -> tile -> p2 -> rx`` (one reflection
      on each side; a monostatic radar sees a tile over the ground this way).

    A leg with a reflection is the direct leg with its end replaced by the image
    (the tile's incidence / scattering angle, r_i or r_s the unfolded length)
    and the reflection dyad (:func:`_mirror_dyads`) applied on that side.

    ``triangle_mask`` (bool per scene triangle, optional): tiles of triangles where it
    is false are never traced (e.g. those that cannot reach the radar's noise floor,
    :func:`scattering_triangle_bounds`); they are not counted as
    dropped. Tile sizes and phases do not depend on it.

    Emitted are the paths inside both antenna patterns and not more than
    |threshold_db| below the strongest scattering path of the link, or below
    ``reference_gain`` (a complex or |a|, e.g. the strongest specular path) when
    given.  ``n_dropped`` counts the lit, confirmed paths not emitted (threshold
    or antenna pattern).

    Gamma is the Fresnel reflection magnitude at the tile's angle of incidence
    for the polarisation actually arriving there (tx's, after the prefix's
    reflection dyad), Gamma^2 = (|r_te E_te|^2 + |r_tm E_tm|^2) / |E|^2 (the
    unpolarised mean (|r_te|^2 + |r_tm|^2)/2 where no field arrives).
    Each tile gets two random phases (chi1, chi2) from ``seed`` (the same for a
    given scene, seed and tile plan, so fixed across the frame, and shared by
    all paths through the tile); delay L/c0 (L unfolded); Doppler
    -(1/lambda) dL/dt with the tile and mirrors moving with their objects.
    Interactions SCATTERING, with REFLECTION before/after it; object_id/face_id
    the object and scene triangle at each interaction.

    ``geom.engine`` "device" cuts the tiles and tests their sight of tx and rx in the
    kernels of :mod:`clradcom.device.scatter` (the same numbers as the host's, bit for bit
    with fp64, to ~1e-14 without; docs/scattering.md "On the device"); "host" is the
    numpy reference.
    """
    mr = max_reflections
    if not (isinstance(mr, (int, np.integer)) and not isinstance(mr, bool) and 0 <= mr <= 2):
        raise ArgumentError(f"max_reflections must be 0, 1 or 2 (one reflection on each side "
                         f"of the tile at most), got {max_reflections!r}")
    if isinstance(batch_tiles, bool) or not isinstance(batch_tiles, (int, np.integer)) \
            or batch_tiles < 1:
        raise ArgumentError("must be a positive integer", argument="batch_tiles",
                            value=batch_tiles)
    scene = geom.scene
    if geom.caster is None or len(scene.triangles) == 0:
        return Paths.empty(1), 0
    st = _scattering_triangles(scene)
    if len(st.sel) == 0:
        return Paths.empty(1), 0
    tx_pos = np.asarray(tx.position, dtype=np.float64)
    rx_pos = np.asarray(rx.position, dtype=np.float64)
    plan = tile_plan(st, tx_pos, rx_pos, scene.wavelength_m, tile_size_m=tile_size_m,
                     accuracy=accuracy)
    traced = np.arange(len(plan.prim))
    if triangle_mask is not None:
        mask = np.asarray(triangle_mask, dtype=bool)
        if mask.shape != (len(scene.triangles),):
            raise ArgumentError(f"triangle_mask must have one entry per scene triangle "
                             f"({len(scene.triangles)}), got shape {mask.shape}")
        traced = np.flatnonzero(mask[plan.prim])
    if plan.size is not None:
        _warn_coarse_tiles(scene, plan, traced, accuracy)
    monostatic = bool(np.array_equal(tx_pos, rx_pos))
    on_device = geom.engine == "device"
    engines.record("scattering.tiles", geom.engine, fallback=False)
    kept = _KeptRows(threshold_db, reference_gain)
    if mr >= 1:
        mirrors, lo, hi = mirror_faces(geom, min_face_area_m2)
    for a, b in _batches(plan.n[traced] ** 2, int(batch_tiles)):
        kb = traced[a:b]
        phases = _batch_phases(seed, plan.first, kb)
        if on_device and mr == 0:
            kept.add(_device_direct_rows(geom, tx, rx, plan, kb, phases, tx_pos, rx_pos,
                                         monostatic))
            continue
        if on_device:
            tiles = _device_tiles(geom, plan, kb, phases, tx_pos, rx_pos, monostatic)
        else:
            tiles = _host_tiles(geom, plan, kb, phases, tx_pos, rx_pos, mr, monostatic)
        blocks = _tile_blocks(geom, tiles, tx_pos, rx_pos, mr, monostatic,
                              (mirrors, lo, hi) if mr >= 1 else None)
        cols = [np.concatenate(c) for c in zip(*blocks, strict=True)]
        if len(cols[0]) == 0:
            continue
        kind = np.repeat(np.arange(len(blocks), dtype=np.int8), [len(b[0]) for b in blocks])
        q, area, nrm, tri_ids, phases = tiles[:5]
        kept.add(_path_rows(geom, tx, rx, q, area, nrm, tri_ids, phases, cols), kind)
    return kept.paths()


def _tile_blocks(geom, tiles, tx_pos, rx_pos, mr, monostatic, mirrors):
    """The path rows through one batch's tiles, as blocks (direct, and with reflections
    prefix, suffix, both): each (tile, f1, p1, im1, tr1, f2, p2, im2, tr2), a missing leg
    being the direct one (no face, p = q, the end itself as image)."""
    q, area, nrm, tri_ids, phases, vis_t, vis_r, direct = tiles
    N = len(q)

    def block(t, pre=None, suf=None):
        n = len(t)
        none = np.full(n, -1, np.int64)
        a = pre if pre is not None else (none, q[t], np.broadcast_to(tx_pos, (n, 3)), none)
        b = suf if suf is not None else (none, q[t], np.broadcast_to(rx_pos, (n, 3)), none)
        return (t, *a, *b)

    blocks = [block(direct)]
    if mr >= 1:
        faces, lo, hi = mirrors
        everywhere = np.arange(N)
        # legs from tx matter only for tiles rx sees directly, unless a suffix may follow
        lt = reflection_legs(geom, tx_pos, q, nrm, tri_ids,
                             everywhere if mr >= 2 else np.flatnonzero(vis_r), faces, lo, hi)
        lr = lt if monostatic else reflection_legs(
            geom, rx_pos, q, nrm, tri_ids, everywhere if mr >= 2 else np.flatnonzero(vis_t),
            faces, lo, hi)
        pre = np.flatnonzero(vis_r[lt[0]])
        blocks.append(block(lt[0][pre], pre=[c[pre] for c in lt[1:]]))
        suf = np.flatnonzero(vis_t[lr[0]])
        blocks.append(block(lr[0][suf], suf=[c[suf] for c in lr[1:]]))
        if mr >= 2:
            i, j = _join(lt[0], lr[0])
            blocks.append(block(lt[0][i], pre=[c[i] for c in lt[1:]],
                                suf=[c[j] for c in lr[1:]]))
    return blocks


def _path_rows(geom, tx, rx, q, area, nrm, tri_ids, phases, cols):
    """Fields and records of path rows ``cols`` = (tile, f1, p1, im1, tr1, f2, p2, im2,
    tr2): (gain, matrix, L, doppler, n_interactions, codes, points, object ids, face ids)."""
    tile, f1, p1, im1, tr1, f2, p2, im2, tr2 = cols
    scene = geom.scene
    S_mat = scene.material_scattering
    lam = scene.wavelength_m
    tx_pos = np.asarray(tx.position, dtype=np.float64)
    rx_pos = np.asarray(rx.position, dtype=np.float64)
    P = len(tile)
    qt, nt, tid = q[tile], nrm[tile], tri_ids[tile]
    mat = scene.tri_material[tid]
    obj = scene.tri_object[tid]
    faces = geom.faces
    # first and last legs as travelled (p1 = q without a prefix, p2 = q without a suffix)
    k_dep = unit(p1 - tx_pos)
    D1 = _mirror_dyads(scene, faces, f1, k_dep)
    out2 = p2 - qt
    out2[f2 < 0] = 1.0  # no suffix: a placeholder direction, the dyad stays the identity
    D2 = _mirror_dyads(scene, faces, f2, unit(out2))

    # Fresnel |Gamma| at the tile for the polarisation arriving there
    ki = unit(qt - im1)
    cos_i = np.abs(np.einsum("pi,pi->p", ki, nt))
    r_te, r_tm = em.fresnel_coefficients(scene.material_eps_r[mat], cos_i,
                                         scene.material_pec[mat])
    d_loc, th_w, ph_w = em._antenna_basis_world(k_dep, tx.orientation)
    c_tx = np.asarray(tx.pattern.field(d_loc), dtype=np.complex128).reshape(P, 2)
    e_w = np.einsum("pij,pj->pi", D1, c_tx[:, :1] * th_w + c_tx[:, 1:] * ph_w)
    te, tm = _te_basis(ki, nt)
    e_te = np.einsum("pi,pi->p", e_w, te)
    e_tm = np.einsum("pi,pi->p", e_w, tm)
    gamma = _power_weighted_gamma(e_te, e_tm, r_te, r_tm)

    T, L, _, _ = tile_transfer(qt, area[tile], nt, im1, im2, S_mat[mat], gamma,
                               scene.material_cross_pol_share[mat], phases[tile])
    T = D2 @ T @ D1
    k_arr = unit(rx_pos - p2)
    gain, M = em.path_gains(T, L, k_dep, k_arr, tx, rx, scene.carrier_hz)

    # polylines [tx, (p1), q, (p2), rx] packed left, NaN padding
    has1, has2 = f1 >= 0, f2 >= 0
    nk = (1 + has1 + has2).astype(np.int16)
    rows = np.arange(P)
    pts = np.full((P, 5, 3), np.nan)
    vel = np.zeros((P, 5, 3))
    code = np.zeros((P, 3), np.int8)
    oid = np.full((P, 3), -1, np.int32)
    fid = np.full((P, 3), -1, np.int32)
    pts[:, 0] = tx_pos
    vel[:, 0] = tx.velocity
    refl = int(InteractionType.REFLECTION)
    j_q = 1 + has1.astype(np.int64)  # column of the tile among the points
    pts[has1, 1] = p1[has1]
    vel[has1, 1] = scene.point_velocity(faces.object_id[f1[has1]], p1[has1])
    code[has1, 0] = refl
    oid[has1, 0] = faces.object_id[f1[has1]]
    fid[has1, 0] = tr1[has1]
    pts[rows, j_q] = qt
    vel[rows, j_q] = scene.point_velocity(obj, qt)
    code[rows, j_q - 1] = int(InteractionType.SCATTERING)
    oid[rows, j_q - 1] = obj
    fid[rows, j_q - 1] = tid
    r2 = rows[has2]
    pts[r2, j_q[has2] + 1] = p2[has2]
    vel[r2, j_q[has2] + 1] = scene.point_velocity(faces.object_id[f2[has2]], p2[has2])
    code[r2, j_q[has2]] = refl
    oid[r2, j_q[has2]] = faces.object_id[f2[has2]]
    fid[r2, j_q[has2]] = tr2[has2]
    pts[rows, nk + 1] = rx_pos
    vel[rows, nk + 1] = rx.velocity
    doppler = em.doppler_hz(pts, vel, lam, num_interactions=nk)
    return gain, M, L, doppler, nk, code, pts, oid, fid


def scattering_triangle_bounds(scene, tx, rx, floor_power: float):
    """(triangle ids, best |a|², above-floor mask) of the scene's scattering triangles.

    All tiles of a triangle of area A together carry at most
    |a|² ≤ λ² S² A G_tx G_rx / (16 π³ r_i² r_s²) (:func:`scattering_paths` with Γ ≤ 1 and both
    cosines ≤ 1), r_i and r_s the distances from tx and rx to the triangle; a tile carries
    at most its share of A, so a triangle below the floor has no tile above it.
    """
    p = float(floor_power)
    if not (math.isfinite(p) and p > 0):
        raise ArgumentError(f"floor_power must be a finite number > 0, got {floor_power!r}")
    S_mat = np.asarray(scene.material_scattering)
    ids = np.flatnonzero(S_mat[scene.tri_material] > 0)
    if ids.size == 0:
        return ids, np.zeros(0), np.zeros(0, dtype=bool)
    tris = scene.triangles[ids]
    area = triangle_areas(tris)
    r_i = point_triangle_distance(np.asarray(tx.position, dtype=np.float64), tris)
    r_s = point_triangle_distance(np.asarray(rx.position, dtype=np.float64), tris)
    S = S_mat[scene.tri_material[ids]]
    g = pattern_peak_gain(tx.pattern) * pattern_peak_gain(rx.pattern)
    with np.errstate(divide="ignore"):
        best = (scene.wavelength_m ** 2 * S**2 * area * g
                / (16.0 * math.pi**3 * np.maximum(r_i, 1e-300) ** 2
                   * np.maximum(r_s, 1e-300) ** 2))
    return ids, best, best >= p


# ---------------------------------------------------------------------------
# the mechanism: settings and paths of a link


@dataclass(frozen=True)
class ScatteringSettings:
    """Single Lambertian scattering from tiles of materials with S > 0 (the trees)."""

    #: scatter at all; the specular reflections of such materials then carry sqrt(1 - S^2)
    #: of the field whether or not this is on (effective roughness)
    enabled: bool = False
    #: specular reflections around a tile: 0 tx-tile-rx only; 1 also one reflection before
    #: or after it; 2 also one on each side
    max_reflections: int = 0
    #: tiles more than this far (dB) below the link's strongest tile are dropped
    threshold_db: float = -60.0
    #: tile edge (m); 0 gives every part of a surface the largest edge the accuracy bound
    #: allows at its nearest point to the antennas (tile_plan); an explicit size coarser
    #: than that bound somewhere warns (TileSizeWarning) naming the surface
    tile_size_m: float = 0.0
    #: faces smaller than this (m^2) reflect into no scattering path
    min_face_area_m2: float = DEFAULT_MIN_FACE_AREA_M2
    #: |a|^2 below which a triangle's tiles are never traced, from an upper bound of all
    #: its tiles together (scattering_triangle_bounds; e.g. the radar's processed noise
    #: floor, clradcom.evaluation.budget.noise_floor); 0 traces every triangle
    floor: float = 0.0

    def __post_init__(self):
        if not isinstance(self.enabled, bool):
            raise ArgumentError("must be True or False", argument="ScatteringSettings.enabled",
                                value=self.enabled)
        if (isinstance(self.max_reflections, bool) or not isinstance(self.max_reflections, int)
                or self.max_reflections not in (0, 1, 2)):
            raise ArgumentError("must be 0, 1 or 2", argument="ScatteringSettings.max_reflections",
                                value=self.max_reflections)
        check_number("ScatteringSettings", "threshold_db", self.threshold_db, high=0.0)
        for name in ("tile_size_m", "min_face_area_m2", "floor"):
            check_number("ScatteringSettings", name, getattr(self, name), low=0.0)


def prepare(geom: Geometry, tx: Radar, settings: ScatteringSettings) -> None:
    """Nothing is shared between a transmitter's links: tiles are cut per link, their
    size set by the nearer antenna's distance."""
    return None


def link_paths(geom: Geometry, prepared: None, tx: Radar, rx: Radar,
               settings: ScatteringSettings, stats: dict | None = None) -> Paths:
    """Diffuse scattering paths of one link; ``stats`` adds up ``tiles_dropped`` and
    ``triangles_below_floor``."""
    if not settings.enabled or geom.caster is None:
        return Paths.empty(1)
    scene = geom.scene
    mask = None
    below = 0
    if settings.floor > 0:
        mask = np.ones(len(scene.triangles), dtype=bool)
        ids, _, above = scattering_triangle_bounds(scene, tx, rx, settings.floor)
        mask[ids[~above]] = False
        below = int(np.count_nonzero(~above))
    paths, dropped = scattering_paths(
        geom, tx, rx, tile_size_m=settings.tile_size_m or None,
        threshold_db=settings.threshold_db, max_reflections=settings.max_reflections,
        min_face_area_m2=settings.min_face_area_m2, triangle_mask=mask)
    if stats is not None:
        stats["tiles_dropped"] = stats.get("tiles_dropped", 0) + int(dropped)
        stats["triangles_below_floor"] = stats.get("triangles_below_floor", 0) + below
    return paths
