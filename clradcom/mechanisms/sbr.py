"""Shooting and bouncing rays with physical optics (SBR-PO): multi-bounce target returns.

The single-bounce PO facet term (:mod:`clradcom.mechanisms.physical_optics`) gives each
lit facet its true strength, but a dihedral or trihedral corner returns through two or three
reflections.  SBR (Ling, Chou & Lee, IEEE TAP 37(2) 1989, "Shooting and bouncing
rays: calculating the RCS of an arbitrarily shaped cavity") shoots a dense grid of
ray tubes at the target and follows each tube with GO (the Fresnel reflection dyads
of :mod:`clradcom.physics.em`, spreading of the spherical wave of the image source).  At
every bounce it radiates the PO current of the tube's footprint toward the
receiver, rather than over one exit aperture, since an open target such as a car has
none.  docs/po.md gives the formulas and the measured accuracy.

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
the material's reflection dyad at the tube's incidence.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from clradcom.device.raycast import make_rays, spawn_origins
from clradcom.device.visibility import surface_sees
from clradcom.errors import ArgumentError
from clradcom.geometry.triangles import triangle_normals
from clradcom.paths import InteractionType, Paths
from clradcom.physics import em
from clradcom.physics.po import penetrable_po_operator, sinc
from clradcom.physics.vectors import orthonormal_frame

__all__ = ["TubeGrid", "TubeHits", "bounding_sphere", "launch_tubes", "shoot_tubes",
           "sbr_paths", "shoot_sbr"]

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
class TubeHits:
    """Bounces of ray tubes (one row per tube and bounce at or after first_bounce).

    ``tube`` (H,) launch index; ``bounce`` (H,) 1-based; ``point`` (H,3) exact hit
    point (float64 plane intersection); ``k_in`` (H,3); ``normal`` (H,3) lit-side
    unit normal; ``length`` (H,) unfolded tx -> point; ``chain`` (H,3,3) complex
    transfer of the earlier reflections; ``edge1``/``edge2`` (H,3) unit cross-section
    edges; ``triangle`` (H,) scene triangle; ``history`` (H, max_bounces, 3) bounce
    points so far (NaN after), ``tri_history`` (H, max_bounces) their triangles (-1).
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
    C = D_{m-1} ... D_1 (I - k0 k0^T), replaying the mirrors of their triangles."""
    d = np.array(k0_dir, dtype=np.float64)
    chain = (np.eye(3)[None] - d[:, :, None] * d[:, None, :]).astype(np.complex128)
    if len(d) == 0:
        return chain
    k = 2.0 * np.pi * scene.carrier_hz / em.C0
    for j in range(m - 1):
        tri = tri_history[:, j]
        n = triangle_normals(scene.triangles[tri])
        mat = scene.tri_material[tri]
        dn = np.einsum("ij,ij->i", d, n)
        r_te, r_tm = em.fresnel_coefficients(scene.material_eps_r[mat], np.abs(dn),
                                             scene.material_pec[mat])
        rho = em.roughness_factor(scene.material_roughness_m[mat], np.abs(dn), k,
                                  scene.material_roughness_model[mat])
        chain = em.reflection_dyad(d, n, rho * r_te, rho * r_tm) @ chain
        d = d - 2.0 * dn[:, None] * n
    return chain


def shoot_tubes(geom, tx_pos, grid: TubeGrid, max_bounces: int, first_bounce: int = 2,
                record_triangles=None) -> TubeHits:
    """Follow every tube through up to ``max_bounces`` specular reflections.

    Closest hits come from the BVH caster (float32); each hit point is then the exact
    float64 intersection of the ray with the hit triangle's plane.  Bounces at or after
    ``first_bounce`` on triangles in ``record_triangles`` (bool mask over the scene's
    triangles; default all) are recorded for radiation, with the transfer chain of their
    earlier reflections: the material's Fresnel coefficients and roughness factor
    (:func:`clradcom.physics.em.reflection_dyad`), so tubes may pass over GO objects (the road)
    on the way.  Chains are built for the recorded tubes only, from their bounce points.
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


def _radiate(geom, hits: TubeHits, grid: TubeGrid, tx, rx):
    """Per recorded hit: T (H,3,3), L (H,), k_dep, k_arr and the hits kept (shadowing,
    side).  See the module docstring for T."""
    scene = geom.scene
    k0 = 2.0 * np.pi * scene.carrier_hz / em.C0
    rx_pos = np.asarray(rx.position, dtype=np.float64)
    p, n = hits.point, hits.normal
    dr = rx_pos - p
    R_r = np.linalg.norm(dr, axis=1)
    ok = R_r > 0
    s = dr / np.where(ok, R_r, 1.0)[:, None]
    ok &= np.einsum("ij,ij->i", s, n) > 0
    keep = np.flatnonzero(ok)
    if len(keep):
        keep = keep[surface_sees(geom.caster, p[keep], n[keep], rx_pos, hits.triangle[keep],
                                 leave_direction=s[keep], tri_face=geom.faces.tri_face)]
    p, n, s, R_r = p[keep], n[keep], s[keep], R_r[keep]
    k_in, L_in = hits.k_in[keep], hits.length[keep]
    dom = grid.solid_angle[hits.tube[keep]]
    w = np.sqrt(dom) * L_in
    kn = np.einsum("ij,ij->i", k_in, n)
    q = k0 * (s - k_in)
    edges = []
    for e in (hits.edge1[keep], hits.edge2[keep]):
        e = w[:, None] * e
        edges.append(e - k_in * (np.einsum("ij,ij->i", n, e) / kn)[:, None])
    area = w * w / np.abs(kn)
    i_fp = area * sinc(0.5 * np.einsum("ij,ij->i", q, edges[0])) * sinc(
        0.5 * np.einsum("ij,ij->i", q, edges[1]))
    mat = scene.tri_material[hits.triangle[keep]]
    pec = scene.material_pec[mat]
    eye = np.eye(3)
    cross2 = k_in[:, :, None] * n[:, None, :] - kn[:, None, None] * eye
    proj = eye - s[:, :, None] * s[:, None, :]
    op = proj @ cross2
    if not np.all(pec):
        # penetrable footprints: currents of the incident plus reflected field
        pen = np.flatnonzero(~pec)
        op = op.astype(np.complex128)
        D = em.material_reflection_dyad(scene, mat[pen], k_in[pen], n[pen])
        op[pen] = 0.5 * penetrable_po_operator(n[pen], k_in[pen], s[pen], D)
    L = L_in + R_r
    scale = -1j * k0 / (2.0 * np.pi) * L / (L_in * R_r) * i_fp
    T = scale[:, None, None] * (op @ hits.chain[keep])
    k_dep = grid.directions[hits.tube[keep]]
    return T, L, k_dep, s, keep


def shoot_sbr(geom, tx, objects, *, spacing_m: float | None = None,
              spacing_wavelengths: float = 0.5, max_bounces: int = 3, first_bounce: int = 2,
              grid: TubeGrid | None = None):
    """(grid, hits) of tx's tubes over ``objects``: what every receiver of tx shares, so a
    tracer computes it once per transmitter (see :func:`sbr_paths`)."""
    scene = geom.scene
    objects = np.asarray(list(objects), dtype=np.int64)
    on = np.isin(scene.tri_object, objects)
    if grid is None:
        spacing = (float(spacing_m) if spacing_m is not None
                   else float(spacing_wavelengths) * scene.wavelength_m)
        spheres = []
        for o in objects:
            if not np.any(scene.tri_object == o):
                continue
            c, r = bounding_sphere(scene.triangles[scene.tri_object == o])
            if np.linalg.norm(c - np.asarray(tx.position, dtype=np.float64)) <= r * 1.001:
                # a radar riding on the object: no tube grid can cover it from inside;
                # its own multi-bounce echoes are left out, its PO facets stay
                warnings.warn(f"SBR skips object {scene.objects[o].name!r}: transmitter "
                              f"{tx.name!r} lies inside its bounding sphere", stacklevel=3)
                continue
            spheres.append((c, r))
        grid = launch_tubes(tx.position, spheres, spacing)
    return grid, shoot_tubes(geom, tx.position, grid, max_bounces, first_bounce, on)


def sbr_paths(geom, tx, rx, *, objects, spacing_m: float | None = None,
              spacing_wavelengths: float = 0.5, max_bounces: int = 3, first_bounce: int = 2,
              min_relative_db: float = -80.0, grid: TubeGrid | None = None,
              shot=None) -> Paths:
    """SBR-PO multi-bounce returns of one tx -> rx link as :class:`Paths`.

    Tubes are shot from tx over the bounding sphere of each object in ``objects`` (pitch
    ``spacing_m``, default ``spacing_wavelengths`` wavelengths, at the sphere's centre),
    bounce off anything in the scene, and radiate (module docstring) from every bounce
    >= ``first_bounce`` that lands on one of ``objects`` and sees rx unblocked.

    Tube contributions with the same sequence of planar faces (``geom.faces``) add up
    coherently to one path: gain and matrix are the sums; points, delay, Doppler,
    object and triangle ids are those of the tube whose unfolded length is closest to
    the |gain|-weighted mean length of the group (so the delay is the group's and is
    consistent with the points).  Groups more than |min_relative_db| below the
    strongest of the link, and tubes outside either antenna's pattern, are dropped.
    ``shot`` is :func:`shoot_sbr`'s (grid, hits) for this tx and these settings, when
    the caller keeps it across receivers.
    """
    scene = geom.scene
    objects = np.asarray(list(objects), dtype=np.int64)
    if geom.caster is None or len(objects) == 0 or max_bounces < first_bounce:
        return Paths.empty(max(first_bounce, 1))
    if shot is None:
        shot = shoot_sbr(geom, tx, objects, spacing_m=spacing_m,
                         spacing_wavelengths=spacing_wavelengths, max_bounces=max_bounces,
                         first_bounce=first_bounce, grid=grid)
    grid, hits = shot
    if len(hits.tube) == 0:
        return Paths.empty(max_bounces)
    T, L, k_dep, k_arr, keep = _radiate(geom, hits, grid, tx, rx)
    if len(keep) == 0:
        return Paths.empty(max_bounces)
    gain, M = em.path_gains(T, L, k_dep, k_arr, tx, rx, scene.carrier_hz)
    seen = (np.asarray(tx.pattern.gain(k_dep @ np.asarray(tx.orientation))) > 0) & (
        np.asarray(rx.pattern.gain(-k_arr @ np.asarray(rx.orientation))) > 0)
    gain, M, L = gain[seen], M[seen], L[seen]
    keep = keep[seen]
    if len(keep) == 0:
        return Paths.empty(max_bounces)
    tri_hist = hits.tri_history[keep]
    nb = hits.bounce[keep].astype(np.int64)
    face_seq = np.where(tri_hist >= 0, geom.faces.tri_face[np.maximum(tri_hist, 0)], -1)
    _, group = np.unique(face_seq, axis=0, return_inverse=True)
    group = group.ravel()
    G = int(group.max()) + 1
    g_gain = np.zeros(G, np.complex128)
    np.add.at(g_gain, group, gain)
    g_M = np.zeros((G, 2, 2), np.complex128)
    np.add.at(g_M, group, M)
    w = np.abs(gain) + 1e-300
    mean_L = np.bincount(group, w * L, G) / np.bincount(group, w, G)
    # representative tube: unfolded length closest to the group's mean
    order = np.lexsort((np.abs(L - mean_L[group]), group))
    first = np.ones(len(order), dtype=bool)
    first[1:] = group[order[1:]] != group[order[:-1]]
    rep = order[first]  # one row per group, in group order
    mag = np.abs(g_gain)
    if not np.any(mag > 0):
        mag = np.linalg.norm(g_M.reshape(G, -1), axis=1)
    strong = mag >= mag.max() * 10.0 ** (-abs(float(min_relative_db)) / 20.0)
    strong &= mag > 0
    rep_s = rep[strong]
    P = len(rep_s)
    k_max = max_bounces
    nk = nb[rep_s]
    pts = np.full((P, k_max + 2, 3), np.nan)
    pts[:, 0] = tx.position
    pts[:, 1:k_max + 1] = hits.history[keep][rep_s]
    pts[np.arange(P), nk + 1] = rx.position
    tri_ids = np.where(np.arange(k_max)[None, :] < nk[:, None], tri_hist[rep_s], -1)
    obj = np.where(tri_ids >= 0, scene.tri_object[np.maximum(tri_ids, 0)], -1)
    vel = np.zeros_like(pts)
    vel[:, 0] = tx.velocity
    vel[:, 1:k_max + 1] = np.where((tri_ids >= 0)[..., None],
                                   scene.object_velocity[np.maximum(obj, 0)], 0.0)
    vel[np.arange(P), nk + 1] = rx.velocity
    doppler = em.doppler_hz(pts, vel, scene.wavelength_m, num_interactions=nk)
    active = tri_ids >= 0
    return Paths(gain=g_gain[strong], matrix=g_M[strong], delay_s=em.delay_s(L[rep_s]),
                 doppler_hz=doppler, n_interactions=nk.astype(np.int16),
                 interaction=np.where(active, int(InteractionType.SBR), 0
                                      ).astype(np.int8),
                 points=pts, object_id=obj.astype(np.int32), face_id=tri_ids.astype(np.int32))
