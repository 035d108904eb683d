"""Single diffuse (Lambertian) scattering from surface tiles (effective-roughness model).

Each triangle of a material with scattering coefficient S > 0 is cut into small
tiles; every tile lit from tx and seen from rx gives one path tx -> tile -> rx.
docs/scattering.md gives the model and sources (Degli-Esposti, "A diffuse
scattering model for urban propagation prediction", IEEE TAP 49(7) 2001;
Degli-Esposti et al., "Measurement and modelling of scattering from buildings",
IEEE TAP 55(1) 2007; Sionna RT's primer, "Scattering").

Field of a tile of area A at q (incident E_i(q) from tx, scattered towards s)::

    E_s = (S Gamma / r_s) sqrt(f_s cos(theta_i) A) X E_i(q),   f_s = cos(theta_s) / pi

with X the unitary cross-polarisation map (share K_x, see :func:`tile_transfer`)
carrying two random phases per tile, fixed for the whole frame.  Since
int_hemisphere f_s dOmega = 1, the power scattered into the hemisphere is
S^2 Gamma^2 |E_i|^2 A cos(theta_i), i.e. S^2 Gamma^2 times the power incident
on the tile; the monostatic RCS of a tile is sigma = 4 S^2 Gamma^2 A cos^2(theta).
In the bookkeeping of :mod:`clradcom.em` (tx radiates e_tx e^{-jkd}/d, the field at rx is
T e_tx e^{-jkL}/L) this is the transfer dyad::

    T = (L / (r_i r_s)) S Gamma sqrt(A cos(theta_i) cos(theta_s) / pi) X_world

so that, for isotropic antennas,
|a|^2 = lambda^2 S^2 Gamma^2 A cos(theta_i) cos(theta_s) / (16 pi^3 r_i^2 r_s^2).
"""

from __future__ import annotations

import math

import numpy as np

from . import em
from .raycast import make_rays, spawn_origins
from .snapshot import InteractionType, Paths

__all__ = ["make_tiles", "choose_tile_size", "tile_transfer", "scattering_paths"]

#: Default relative power error of the point-source (far-field) tile approximation.
DEFAULT_ACCURACY = 0.05


def _subdivisions(triangles, tile_size_m):
    v = np.asarray(triangles, dtype=np.float64).reshape(-1, 3, 3)
    edges = np.linalg.norm(v[:, [1, 2, 0]] - v, axis=-1)
    return np.maximum(1, np.ceil(edges.max(axis=1) / float(tile_size_m) - 1e-9)).astype(np.int64)


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
        raise ValueError(f"tile_size_m must be > 0, got {tile_size_m}")
    if len(v) == 0:
        z = np.zeros((0, 3))
        return z, np.zeros(0), z.copy(), np.zeros(0, np.int64)
    cr = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    two_a = np.linalg.norm(cr, axis=-1)
    if np.any(two_a == 0) or not np.all(np.isfinite(two_a)):
        raise ValueError("degenerate or non-finite triangle")
    nrm = cr / two_a[:, None]
    ns = _subdivisions(v, tile_size_m)
    centres, areas, normals, ids = [], [], [], []
    cache = {}
    for n in np.unique(ns):
        n = int(n)
        if n not in cache:
            up = [((3 * i + 1) / (3 * n), (3 * j + 1) / (3 * n))
                  for i in range(n) for j in range(n - i)]
            dn = [((3 * i + 2) / (3 * n), (3 * j + 2) / (3 * n))
                  for i in range(n) for j in range(n - 1 - i)]
            cache[n] = np.array(up + dn, dtype=np.float64).reshape(-1, 2)
        uv = cache[n]  # (n^2, 2) barycentric (u, v) of the tile centroids
        sel = np.flatnonzero(ns == n)
        vs = v[sel]
        pts = (vs[:, None, 0] + uv[None, :, 0, None] * (vs[:, None, 1] - vs[:, None, 0])
               + uv[None, :, 1, None] * (vs[:, None, 2] - vs[:, None, 0]))
        m = len(uv)
        centres.append(pts.reshape(-1, 3))
        areas.append(np.repeat(0.5 * two_a[sel] / (n * n), m))
        normals.append(np.repeat(nrm[sel], m, axis=0))
        ids.append(np.repeat(sel, m))
    order = np.argsort(np.concatenate(ids), kind="stable")
    return (np.concatenate(centres)[order], np.concatenate(areas)[order],
            np.concatenate(normals)[order], np.concatenate(ids)[order])


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
        raise ValueError("wavelength, distance and accuracy must be > 0")
    dphi = math.sqrt(45.0 * acc / 4.0)
    return math.sqrt(2.0 * lam * R * dphi / math.pi)


def _unit(x):
    return x / np.linalg.norm(x, axis=-1, keepdims=True)


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
    n = _unit(np.asarray(normals, dtype=np.float64).reshape(-1, 3))
    dt = c - np.asarray(tx_pos, dtype=np.float64).reshape(-1, 3)
    dr = np.asarray(rx_pos, dtype=np.float64).reshape(-1, 3) - c
    r_i = np.linalg.norm(dt, axis=-1)
    r_s = np.linalg.norm(dr, axis=-1)
    if np.any(r_i == 0) or np.any(r_s == 0):
        raise ValueError("tx or rx coincides with a tile centre")
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


def _estimate_count(triangles, size):
    return int(np.sum(_subdivisions(triangles, size) ** 2))


def scattering_paths(geom, tx, rx, *, tile_size_m=None, threshold_db=-60.0, seed=0,
                     reference_gain=None, accuracy=DEFAULT_ACCURACY, max_tiles=200_000):
    """Single diffuse-scattering paths of one tx -> rx link: ``(Paths, n_dropped)``.

    Tiles (:func:`make_tiles`) are cut from every scene triangle whose material
    has S > 0.  ``tile_size_m=None`` picks :func:`choose_tile_size` for the
    distance from the nearer antenna to the closest scattering triangle's
    centroid, then enlarges it if more than ``max_tiles`` tiles would result (an
    explicit size with too many tiles raises ValueError).

    One path per tile that is

    * on the front side for both ends: n . (tx - q) > 0 and n . (rx - q) > 0,
      n the source triangle's winding normal (outward for a closed mesh);
    * visible: nothing hit on q -> tx and q -> rx (``geom.caster.occluded``,
      origins spawned off the tile, the source triangle ignored);
    * inside both antenna patterns;
    * not more than |threshold_db| below the strongest tile of the link, or
      below ``reference_gain`` (a complex or |a|, e.g. the strongest specular
      path) when given.

    Gamma is the Fresnel reflection magnitude at the tile's angle of incidence
    for the actual incident polarisation of tx,
    Gamma^2 = (|r_te E_te|^2 + |r_tm E_tm|^2) / |E|^2
    (the unpolarised mean (|r_te|^2 + |r_tm|^2)/2 where tx radiates nothing).
    Each tile gets two random phases (chi1, chi2) from ``seed`` (the same for a
    given scene, seed and tile size, so fixed across the frame); delay L/c0;
    Doppler -(1/lambda) dL/dt with the tile moving with its object; interaction
    SCATTERING; object_id/face_id the source triangle's.

    ``n_dropped`` counts lit, visible tiles not emitted (threshold or antenna
    pattern).
    """
    scene = geom.scene
    if geom.caster is None or len(scene.triangles) == 0:
        return Paths.empty(1), 0
    S_mat = scene.material_scattering
    tri_sel = np.flatnonzero(S_mat[scene.tri_material] > 0)
    if len(tri_sel) == 0:
        return Paths.empty(1), 0
    tx_pos = np.asarray(tx.position, dtype=np.float64)
    rx_pos = np.asarray(rx.position, dtype=np.float64)
    tris = scene.triangles[tri_sel]
    lam = scene.wavelength_m
    if tile_size_m is None:
        cen = tris.mean(axis=1)
        d = min(np.linalg.norm(cen - tx_pos, axis=-1).min(),
                np.linalg.norm(cen - rx_pos, axis=-1).min())
        size = choose_tile_size(lam, max(d, lam), accuracy)
        cnt = _estimate_count(tris, size)
        while cnt > max_tiles:
            size *= 1.05 * math.sqrt(cnt / max_tiles)
            cnt = _estimate_count(tris, size)
    else:
        size = float(tile_size_m)
        cnt = _estimate_count(tris, size)
        if cnt > max_tiles:
            raise ValueError(f"tile_size_m={size} gives {cnt} tiles > max_tiles={max_tiles}")
    q, area, nrm, local = make_tiles(tris, size)
    tri_ids = tri_sel[local]
    # phases drawn for every tile before any selection: fixed per tile for a seed
    phases = np.random.default_rng(seed).uniform(0.0, 2.0 * np.pi, size=(len(q), 2))

    st = np.einsum("pi,pi->p", nrm, tx_pos - q)
    sr = np.einsum("pi,pi->p", nrm, rx_pos - q)
    keep = np.flatnonzero((st > 0) & (sr > 0))
    vis = np.ones(len(keep), dtype=bool)
    for end in (tx_pos, rx_pos):
        if not vis.any():
            break
        idx = keep[vis]
        org = spawn_origins(q[idx], nrm[idx], end[None, :] - q[idx])
        rays = make_rays(org, end[None, :] - org, 0.0, 1.0 - 1e-7)
        vis[vis] = ~geom.caster.occluded(rays, ignore_prim=tri_ids[idx].astype(np.int32))
    keep = keep[vis]
    if len(keep) == 0:
        return Paths.empty(1), 0
    q, area, nrm, tri_ids, phases = q[keep], area[keep], nrm[keep], tri_ids[keep], phases[keep]
    mat = scene.tri_material[tri_ids]
    obj = scene.tri_object[tri_ids]
    P = len(q)

    # Fresnel |Gamma| at the incidence angle for tx's polarisation
    ki = _unit(q - tx_pos)
    cos_i = np.abs(np.einsum("pi,pi->p", ki, nrm))
    r_te, r_tm = em.fresnel_coefficients(scene.material_eps_r[mat], cos_i,
                                         scene.material_pec[mat])
    d_loc, th_w, ph_w = em._antenna_basis_world(ki, tx.orientation)
    c_tx = np.asarray(tx.pattern.field(d_loc), dtype=np.complex128).reshape(P, 2)
    e_w = c_tx[:, :1] * th_w + c_tx[:, 1:] * ph_w
    te, tm = _te_basis(ki, nrm)
    e_te = np.einsum("pi,pi->p", e_w, te)
    e_tm = np.einsum("pi,pi->p", e_w, tm)
    p_in = np.abs(e_te) ** 2 + np.abs(e_tm) ** 2
    g2 = np.where(p_in > 0,
                  (np.abs(r_te * e_te) ** 2 + np.abs(r_tm * e_tm) ** 2) / np.where(p_in > 0,
                                                                               p_in, 1.0),
                  0.5 * (np.abs(r_te) ** 2 + np.abs(r_tm) ** 2))
    gamma = np.sqrt(g2)

    T, L, k_dep, k_arr = tile_transfer(q, area, nrm, tx_pos, rx_pos, S_mat[mat], gamma,
                                       scene.material_cross_pol_share[mat], phases)
    gain, M = em.path_gains(T, L, k_dep, k_arr, tx, rx, scene.carrier_hz)

    pts = np.stack([np.broadcast_to(tx_pos, (P, 3)), q, np.broadcast_to(rx_pos, (P, 3))],
                   axis=1)
    vel = np.stack([np.broadcast_to(np.asarray(tx.velocity, float), (P, 3)),
                    scene.object_velocity[obj],
                    np.broadcast_to(np.asarray(rx.velocity, float), (P, 3))], axis=1)
    doppler = em.doppler_hz(pts, vel, lam)

    mag = np.abs(gain)
    top = float(np.abs(reference_gain)) if reference_gain is not None else mag.max()
    sel = (mag > 0) & (mag >= top * 10.0 ** (-abs(float(threshold_db)) / 20.0))
    m = int(sel.sum())
    paths = Paths(gain=gain[sel], matrix=M[sel], delay_s=em.delay_s(L)[sel],
                  doppler_hz=doppler[sel], n_interactions=np.ones(m, np.int16),
                  interaction=np.full((m, 1), int(InteractionType.SCATTERING), np.int8),
                  points=pts[sel], object_id=obj[sel].astype(np.int32)[:, None],
                  face_id=tri_ids[sel].astype(np.int32)[:, None])
    return paths, int(P - m)
