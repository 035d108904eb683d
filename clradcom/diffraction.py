"""First-order UTD edge diffraction paths: tx -> edge point -> rx.

Stages (plain arrays in and out):

1. wedges come from :func:`clradcom.wedges.extract_wedges` (once per scene);
2. :func:`keller_candidates` - the Keller point of every wedge for one tx/rx
   pair (closed form), kept where it lies on the finite edge and both ends
   see the wedge from outside (0 < phi, phi' < n pi);
3. :func:`confirm_diffraction` - both segments unobstructed (any-hit casts);
4. :func:`diffraction_fields` - Kouyoumjian-Pathak / Luebbers coefficients
   (:mod:`clradcom.utd`) as a 3x3 dyad in the edge-fixed bases, spherical
   spreading, antenna patterns -> gain, 2x2 matrix, delay, Doppler.

Only single diffraction without reflections before or after is modelled
here; concave creases (n < 1) are left out (UTD is not validated there and
their faces' reflections dominate).
"""

from __future__ import annotations

import numpy as np

from . import em, utd
from .raycast import make_rays
from .snapshot import InteractionType, Paths
from .wedges import Wedges, diffraction_point

#: Segments leave the edge point from this far along themselves (m), past the
#: float32 rounding of the faces that meet at the edge.
EDGE_CLEARANCE_M = 1e-3


def keller_candidates(wedges: Wedges, tx_pos, rx_pos):
    """(wedge indices, points (C,3), angles phi' phi beta0) of valid Keller points."""
    tx = np.asarray(tx_pos, dtype=np.float64)
    rx = np.asarray(rx_pos, dtype=np.float64)
    if len(wedges) == 0:
        empty = np.zeros(0)
        return np.zeros(0, np.int64), np.zeros((0, 3)), empty, empty, empty
    dp = diffraction_point(tx, rx, wedges.start, wedges.end)
    q = dp.point
    d_in = q - tx
    d_out = rx - q
    len_in = np.linalg.norm(d_in, axis=1)
    len_out = np.linalg.norm(d_out, axis=1)
    ok = dp.inside & (wedges.n >= 1.0) & (len_in > EDGE_CLEARANCE_M) & (
        len_out > EDGE_CLEARANCE_M)
    # strictly inside the edge: the end points are corners, not wedges
    ok &= (dp.t > EDGE_CLEARANCE_M) & (dp.t < wedges.length - EDGE_CLEARANCE_M)
    idx = np.flatnonzero(ok)
    s_in = d_in[idx] / len_in[idx, None]
    s_out = d_out[idx] / len_out[idx, None]
    e = wedges.direction[idx]
    # an end lying on the edge line sees it end-on: no Keller cone
    ok2 = (np.linalg.norm(np.cross(s_in, e), axis=1) > 1e-9) & (
        np.linalg.norm(np.cross(s_out, e), axis=1) > 1e-9)
    idx, s_in, s_out, e = idx[ok2], s_in[ok2], s_out[ok2], e[ok2]
    phi_p, phi, beta0 = utd.wedge_angles(s_in, s_out, e, wedges.normal0[idx])
    limit = wedges.n[idx] * np.pi
    outside = (phi_p > 0) & (phi_p < limit) & (phi > 0) & (phi < limit)
    idx = idx[outside]
    return idx, q[idx], phi_p[outside], phi[outside], beta0[outside]


def confirm_diffraction(caster, tx_pos, rx_pos, points) -> np.ndarray:
    """Mask of edge points that see both tx and rx with nothing in between."""
    keep = np.ones(len(points), dtype=bool)
    if len(points) == 0 or caster is None:
        return keep
    for end in (np.asarray(tx_pos, float), np.asarray(rx_pos, float)):
        seg = end - points
        length = np.linalg.norm(seg, axis=1)
        clear = EDGE_CLEARANCE_M / length
        rays = make_rays(points, seg, tmin=clear, tmax=1.0 - clear)
        keep &= ~caster.occluded(rays)
    return keep


def diffraction_fields(scene, wedges: Wedges, idx, points, phi_p, phi, beta0, tx, rx) -> Paths:
    """UTD fields of first-order diffraction paths as :class:`Paths` (K = 1)."""
    P = len(idx)
    if P == 0:
        return Paths.empty(1)
    tx_pos = np.asarray(tx.position, dtype=np.float64)
    rx_pos = np.asarray(rx.position, dtype=np.float64)
    s_in_vec = points - tx_pos
    s_out_vec = rx_pos - points
    sp = np.linalg.norm(s_in_vec, axis=1)
    s = np.linalg.norm(s_out_vec, axis=1)
    s_in = s_in_vec / sp[:, None]
    s_out = s_out_vec / s[:, None]
    k = 2.0 * np.pi / scene.wavelength_m
    L = utd.distance_parameter(s, sp, beta0)
    m0, m1 = wedges.material0[idx], wedges.material1[idx]
    pec = scene.material_pec[m0] & scene.material_pec[m1]
    d_soft, d_hard = utd.diffraction_coefficients(
        phi, phi_p, beta0, wedges.n[idx], k, L,
        eps_r_0=scene.material_eps_r[m0], eps_r_n=scene.material_eps_r[m1], pec=pec)
    basis = utd.edge_fixed_basis(s_in, s_out, wedges.direction[idx])
    dyad = utd.diffraction_dyad(d_soft, d_hard, *basis)
    transverse = np.eye(3)[None] - s_in[:, :, None] * s_in[:, None, :]
    total = s + sp
    # em.path_gains scales by exp(-jkL)/L; the diffracted wave instead carries
    # (1/s') A(s) = 1/sqrt(s' s (s + s')), so T absorbs the ratio
    ratio = total / np.sqrt(sp * s * total)
    T = dyad @ transverse * ratio[:, None, None]
    gain, M = em.path_gains(T, total, s_in, s_out, tx, rx, scene.carrier_hz)
    pts = np.stack([np.broadcast_to(tx_pos, (P, 3)), points, np.broadcast_to(rx_pos, (P, 3))],
                   axis=1)
    obj = wedges.object_id[idx]
    vel = np.stack([np.broadcast_to(tx.velocity, (P, 3)), scene.object_velocity[obj],
                    np.broadcast_to(rx.velocity, (P, 3))], axis=1)
    doppler = em.doppler_hz(pts, vel, scene.wavelength_m)
    return Paths(gain=gain, matrix=M, delay_s=em.delay_s(total), doppler_hz=doppler,
                 n_interactions=np.ones(P, np.int16),
                 interaction=np.full((P, 1), int(InteractionType.DIFFRACTION), np.int8),
                 points=pts, object_id=obj[:, None].astype(np.int32),
                 face_id=wedges.tri0[idx][:, None].astype(np.int32))
