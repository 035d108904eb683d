"""Physical-optics (PO) facet returns: one path per lit, visible triangle.

A pure GO / image-method tracer sees a faceted body only where some facet's
normal points exactly at the specular direction, so a monostatic radar misses
almost every car facet.  Physical optics integrates the lit-side surface current
of each facet instead, which gives every lit facet a (usually small) return with
the facet's own sinc-like lobe.  Two and more bounces (corners) are the job of
:mod:`clradcom.mechanisms.sbr` (shooting and bouncing ray tubes with the same PO radiation
integral).  docs/po.md gives the derivation and sources
(Gordon 1975; Knott, Shaeffer & Tuley, *Radar Cross Section*; Balanis,
*Advanced Engineering Electromagnetics*, ch. 11).

The facet's transfer dyad and its closed-form radiation integral are
:func:`clradcom.physics.po.po_transfer` (conventions and formulas in that module's
docstring); this module picks the lit, visible facets of a link and turns them into
paths tagged :attr:`~clradcom.paths.InteractionType.PHYSICAL_OPTICS`.
"""

from __future__ import annotations

import warnings

import numpy as np

from clradcom.device.visibility import surface_sees
from clradcom.errors import FresnelZoneWarning
from clradcom.geometry.triangles import triangle_normals
from clradcom.paths import InteractionType, Paths
from clradcom.physics import em
from clradcom.physics.po import far_field_pieces, fresnel_zone, po_transfer

__all__ = ["po_paths"]

def _default_objects(scene):
    pec = scene.material_pec
    return [i for i, o in enumerate(scene.objects) if bool(pec[o.material])]


def _mixed_transfer(scene, v, nrm, mat, pec, tx_pos, rx_pos):
    """po_transfer's outputs for facets of PEC and penetrable materials: the PEC rows
    with the PEC current, the others with the currents of the incident plus the
    specularly reflected field (:func:`clradcom.physics.em.material_reflection_dyad` at
    each facet's own incidence: Fresnel x roughness x sqrt(1 - S^2))."""
    P = len(v)
    T = np.empty((P, 3, 3), np.complex128)
    L, c, k_dep, k_arr = np.empty(P), np.empty((P, 3)), np.empty((P, 3)), np.empty((P, 3))
    metal, other = np.flatnonzero(pec), np.flatnonzero(~pec)

    def reflection(k_in, n):
        return em.material_reflection_dyad(scene, mat[other], k_in, n)

    for rows, refl in ((metal, None), (other, reflection)):
        if len(rows):
            T[rows], L[rows], c[rows], k_dep[rows], k_arr[rows] = po_transfer(
                v[rows], nrm[rows], tx_pos, rx_pos, scene.carrier_hz, refl)
    return T, L, c, k_dep, k_arr


def _warn_fresnel_zone(scene, pieces, owner, tx, rx, tx_pos, rx_pos) -> None:
    """One FresnelZoneWarning per link naming each object whose PO facets (after the
    near-zone split) lie inside their Fraunhofer distance of tx or rx, with the nearest
    such facet's distance and that facet's 2D^2/lambda."""
    inside, dist, far = fresnel_zone(pieces, [tx_pos, rx_pos], scene.wavelength_m)
    parts = []
    for o in np.unique(owner[inside]):
        rows = np.flatnonzero(inside & (owner == o))
        k = rows[np.argmin(dist[rows])]
        parts.append(f"{scene.objects[o].name!r} ({len(rows)}, the nearest {dist[k]:.3g} m "
                     f"away where its 2D^2/lambda is {far[k]:.3g} m)")
    if not parts:
        return
    who = repr(tx.name) if tx.name == rx.name else f"{tx.name!r} or {rx.name!r}"
    warnings.warn(f"PO facets in the Fresnel zone of {who}, closer than their "
                  f"2D^2/lambda: {', '.join(parts)}; their facet integrals drop "
                  "the quadratic phase across them (po_split='fresnel' splits them into "
                  "their far field, docs/po.md)", FresnelZoneWarning, stacklevel=4)


def _near_field_gains(scene, v, nrm, mat, pec, tx, rx, tx_pos, rx_pos, obj, rule):
    """Gains (F,) and matrices (F,2,2) of facets some antenna sees in its near field: the
    sums over their far-field pieces (:func:`clradcom.physics.po.far_field_pieces`), each
    with its own transfer, length and directions; None when every facet is in both
    antennas' far field (``rule``: :data:`clradcom.physics.po.SPLIT_RULES`).  Warns once
    per object whose pieces stay in a near field."""
    pieces, parent, settled = far_field_pieces(v, [tx_pos, rx_pos], scene.wavelength_m,
                                               rule)
    if rule == "near":
        _warn_fresnel_zone(scene, pieces, obj[parent], tx, rx, tx_pos, rx_pos)
    if len(pieces) == len(v):
        return None
    if not settled.all():
        for o in np.unique(obj[parent[~settled]]):
            rows = parent[~settled][obj[parent[~settled]] == o]
            c = v[rows].mean(axis=1)
            dist = min(np.linalg.norm(c - tx_pos, axis=1).min(),
                       np.linalg.norm(c - rx_pos, axis=1).min())
            warnings.warn(f"PO facets of object {scene.objects[o].name!r} lie "
                          f"{dist:.3g} m from antenna {tx.name!r} or {rx.name!r}, in their "
                          f"near field even after subdivision: their returns are "
                          f"approximate", stacklevel=3)
    T, L, _, k_dep, k_arr = _mixed_transfer(scene, pieces, nrm[parent], mat[parent],
                                            pec[parent], tx_pos, rx_pos)
    g, M = em.path_gains(T, L, k_dep, k_arr, tx, rx, scene.carrier_hz)
    gain = np.zeros(len(v), np.complex128)
    matrix = np.zeros((len(v), 2, 2), np.complex128)
    np.add.at(gain, parent, g)
    np.add.at(matrix, parent, M)
    return gain, matrix


def po_paths(geom, tx, rx, *, objects=None, min_relative_db=-80.0, two_sided=None,
             split="near"):
    """PO facet paths of one tx -> rx link as :class:`clradcom.snapshot.Paths`.

    One path per scene triangle of the chosen objects (default: every object
    whose material is PEC) that is lit from tx and seen from rx:

    * front side: n . (tx - c) > 0 and n . (rx - c) > 0 with n the triangle's
      winding normal (v1 - v0) x (v2 - v0), outward for a closed mesh;
      a triangle of a two-sided object (``SceneObject.two_sided``: an open sheet, or
      ``sides = "two_sided"``) is also accepted with both on its back side, using -n
      there; ``two_sided=True`` / ``False`` does so for every triangle / none;
    * visibility: no triangle (other than the facet itself) hit on the segments
      centroid -> tx and centroid -> rx
      (:func:`clradcom.device.visibility.surface_sees`, origins spawned off the
      facet).

    Each path: points [tx, centroid, rx], n_interactions 1, interaction
    REFLECTION (a PO facet term, not a specular point), object_id, face_id = the
    triangle id, delay L/c0, Doppler -(1/lambda) dL/dt with the centroid moving
    with its object, gain and matrix from :func:`po_transfer` through
    :func:`clradcom.physics.em.path_gains` (antenna patterns and polarisations of tx/rx).
    Facets of one flat face are coherent pieces of one plate: the sum of their
    gains is that plate's PO return.

    Non-PEC objects (when listed in ``objects``) carry the equivalent currents of a
    penetrable surface, J = n x H_tot and M = -n x E_tot of the incident plus the
    specularly reflected field, with the material's Fresnel coefficients (TE and TM at
    each facet's own incidence angle), roughness factor and sqrt(1 - S^2) specular share
    (:func:`clradcom.physics.po.penetrable_po_operator`; docs/po.md).  PEC facets keep
    the PEC current J = 2 n x H_inc.

    A facet with tx or rx in its near zone (closer than 2 D, D its longest edge) is split
    until no piece has (``split`` "near", the default); with "fresnel" also until every
    piece is in its Fraunhofer far field (2 D^2/lambda); "none" keeps facets whole
    (:func:`clradcom.physics.po.far_field_pieces`).  The path's gain and matrix are then
    the sums of its pieces', its delay, Doppler and point its centroid's.

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
    nrm = triangle_normals(v)
    c = v.mean(axis=1)
    st = np.einsum("fi,fi->f", nrm, tx_pos - c)
    sr = np.einsum("fi,fi->f", nrm, rx_pos - c)
    front = (st > 0) & (sr > 0)
    both = (scene.tri_two_sided[tri_ids] if two_sided is None
            else np.full(len(tri_ids), bool(two_sided)))
    if both.any():
        back = both & (st < 0) & (sr < 0)
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
                            tri_face=geom.faces.tri_face, engine=geom.engine)
    if not vis.any():
        return Paths.empty(1)
    tri_ids, v, nrm, c = tri_ids[vis], v[vis], nrm[vis], c[vis]

    mat = scene.tri_material[tri_ids]
    obj = scene.tri_object[tri_ids]
    pec = scene.material_pec[mat]
    if np.all(pec):
        T, L, c, k_dep, k_arr = po_transfer(v, nrm, tx_pos, rx_pos, scene.carrier_hz)
    else:
        T, L, c, k_dep, k_arr = _mixed_transfer(scene, v, nrm, mat, pec, tx_pos, rx_pos)
    gain, M = em.path_gains(T, L, k_dep, k_arr, tx, rx, scene.carrier_hz)
    if split != "none":
        near = _near_field_gains(scene, v, nrm, mat, pec, tx, rx, tx_pos, rx_pos, obj,
                                 split)
        if near is not None:
            gain, M = near

    P = len(tri_ids)
    pts = np.stack([np.broadcast_to(tx_pos, (P, 3)), c, np.broadcast_to(rx_pos, (P, 3))],
                   axis=1)
    vel = np.stack([np.broadcast_to(np.asarray(tx.velocity, float), (P, 3)),
                    scene.point_velocity(obj, c),
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
