"""Physical-optics (PO) facet returns: one path per lit, visible triangle.

A pure GO / image-method tracer sees a faceted body only where some facet's
normal points exactly at the specular direction, so a monostatic radar misses
almost every car facet.  Physical optics integrates the lit-side surface current
of each facet instead, which gives every lit facet a (usually small) return with
the facet's own sinc-like lobe.  Two and more bounces (corners) are the job of
:mod:`clradcom.sbr` (shooting and bouncing ray tubes with the same PO radiation
integral).  docs/po.md gives the derivation and sources
(Gordon 1975; Knott, Shaeffer & Tuley, *Radar Cross Section*; Balanis,
*Advanced Engineering Electromagnetics*, ch. 11).

Conventions are those of :mod:`clradcom.em` (time factor e^{+jwt}, field
bookkeeping with a 3x3 transfer dyad T and the unfolded length L):

    a = (lambda / 4 pi) e^{-jkL} / L  *  E_rx . T . E_tx

For a PO facet with centroid c, tx at distance R_t = |c - t| (incident direction
k_i = (c - t)/R_t) and rx at R_r = |r - c| (scattered direction s = (r - c)/R_r)::

    T = -(j k / 2 pi) * L / (R_t R_r) * (I - s s^T) [n x (k_i x .)] * I_c(q)
    I_c(q) = int_facet e^{j q . (r' - c)} dA',   q = k (s - k_i),   L = R_t + R_r

(PEC, J = 2 n x H_inc on the lit side, far field of the facet but not of the
scene).  A flat plate at normal incidence in its far field gives
T = -j (2A / (lambda R)) (I - k k^T) monostatic, i.e. sigma = 4 pi A^2 / lambda^2,
and the polarimetric matrix is j (2A/(lambda R)) times the GO plate's (-I in the
backscatter-alignment basis).
"""

from __future__ import annotations

import numpy as np

from clradcom.device.visibility import surface_sees
from clradcom.paths import InteractionType, Paths
from clradcom.physics import em
from clradcom.physics.po import po_transfer

__all__ = ["po_paths"]

def _default_objects(scene):
    pec = scene.material_pec
    return [i for i, o in enumerate(scene.objects) if bool(pec[o.material])]


def po_paths(geom, tx, rx, *, objects=None, min_relative_db=-80.0, two_sided=False):
    """PO facet paths of one tx -> rx link as :class:`clradcom.snapshot.Paths`.

    One path per scene triangle of the chosen objects (default: every object
    whose material is PEC) that is lit from tx and seen from rx:

    * front side: n . (tx - c) > 0 and n . (rx - c) > 0 with n the triangle's
      winding normal (v1 - v0) x (v2 - v0), outward for a closed mesh;
      ``two_sided=True`` also accepts both on the back side (open sheets with
      arbitrary winding), using -n there;
    * visibility: no triangle (other than the facet itself) hit on the segments
      centroid -> tx and centroid -> rx
      (:func:`clradcom.device.visibility.surface_sees`, origins spawned off the
      facet).

    Each path: points [tx, centroid, rx], n_interactions 1, interaction
    REFLECTION (a PO facet term, not a specular point), object_id, face_id = the
    triangle id, delay L/c0, Doppler -(1/lambda) dL/dt with the centroid moving
    with its object, gain and matrix from :func:`po_transfer` through
    :func:`clradcom.em.path_gains` (antenna patterns and polarisations of tx/rx).
    Facets of one flat face are coherent pieces of one plate: the sum of their
    gains is that plate's PO return.

    Non-PEC objects (when listed in ``objects``) are weighted by -r_te at normal
    incidence (the Fresnel coefficient for eps_r, with PEC's -1 as reference):
    an approximation that ignores the angle and polarisation dependence of the
    dielectric's currents.

    Paths whose |gain| lies more than |min_relative_db| below the link's strongest
    facet are dropped, as are facets outside either antenna's pattern.
    """
    scene = geom.scene
    if objects is None:
        objects = _default_objects(scene)
    objects = np.asarray(list(objects), dtype=np.int64)
    if geom.caster is None or len(objects) == 0:
        return Paths.empty(1)
    tri_ids = np.flatnonzero(np.isin(scene.tri_object, objects))
    if len(tri_ids) == 0:
        return Paths.empty(1)
    tx_pos = np.asarray(tx.position, dtype=np.float64)
    rx_pos = np.asarray(rx.position, dtype=np.float64)
    v = scene.triangles[tri_ids]
    nrm = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    nrm = nrm / np.linalg.norm(nrm, axis=-1, keepdims=True)
    c = v.mean(axis=1)
    st = np.einsum("fi,fi->f", nrm, tx_pos - c)
    sr = np.einsum("fi,fi->f", nrm, rx_pos - c)
    front = (st > 0) & (sr > 0)
    if two_sided:
        back = (st < 0) & (sr < 0)
        nrm = np.where(back[:, None], -nrm, nrm)
        front = front | back
    keep = np.flatnonzero(front)
    if len(keep) == 0:
        return Paths.empty(1)
    tri_ids, v, nrm, c = tri_ids[keep], v[keep], nrm[keep], c[keep]

    # visibility of the centroid from tx and rx
    vis = np.ones(len(tri_ids), dtype=bool)
    for end in (tx_pos, rx_pos):
        vis &= surface_sees(geom.caster, c, nrm, end, tri_ids,
                            tri_face=geom.faces.tri_face)
    if not vis.any():
        return Paths.empty(1)
    tri_ids, v, nrm, c = tri_ids[vis], v[vis], nrm[vis], c[vis]

    mat = scene.tri_material[tri_ids]
    obj = scene.tri_object[tri_ids]
    pec = scene.material_pec[mat]
    refl = np.ones(len(tri_ids), dtype=np.complex128)
    if not np.all(pec):
        r_te, _ = em.fresnel_coefficients(scene.material_eps_r[mat], 1.0, pec)
        refl = -r_te
    T, L, c, k_dep, k_arr = po_transfer(v, nrm, tx_pos, rx_pos, scene.carrier_hz, refl)
    gain, M = em.path_gains(T, L, k_dep, k_arr, tx, rx, scene.carrier_hz)

    P = len(tri_ids)
    pts = np.stack([np.broadcast_to(tx_pos, (P, 3)), c, np.broadcast_to(rx_pos, (P, 3))],
                   axis=1)
    vel = np.stack([np.broadcast_to(np.asarray(tx.velocity, float), (P, 3)),
                    scene.object_velocity[obj],
                    np.broadcast_to(np.asarray(rx.velocity, float), (P, 3))], axis=1)
    doppler = em.doppler_hz(pts, vel, scene.wavelength_m)

    seen = (np.asarray(tx.pattern.gain(k_dep @ np.asarray(tx.orientation))) > 0) & (
        np.asarray(rx.pattern.gain(-k_arr @ np.asarray(rx.orientation))) > 0)
    mag = np.abs(gain)
    if not np.any(mag > 0):
        mag = np.linalg.norm(M.reshape(P, -1), axis=-1)
    top = mag[seen].max() if seen.any() else 0.0
    strong = mag >= top * 10.0 ** (-abs(float(min_relative_db)) / 20.0)
    sel = seen & strong & (mag > 0)
    return Paths(gain=gain[sel], matrix=M[sel], delay_s=em.delay_s(L)[sel],
                 doppler_hz=doppler[sel], n_interactions=np.ones(int(sel.sum()), np.int16),
                 interaction=np.full((int(sel.sum()), 1), int(InteractionType.PHYSICAL_OPTICS),
                                     np.int8),
                 points=pts[sel], object_id=obj[sel].astype(np.int32)[:, None],
                 face_id=tri_ids[sel].astype(np.int32)[:, None])
