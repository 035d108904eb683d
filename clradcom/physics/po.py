"""Physical-optics (PO) radiation integrals of flat triangles and their facet fields.

Each lit facet radiates the surface current the incident wave induces on it; the
integral over a flat triangle has a closed form (Gordon 1975), so a facet's return and
its sinc-like lobe cost one evaluation. PEC facets carry J = 2 n x H_inc; penetrable
ones the currents of the incident plus the Fresnel-reflected field. The mechanisms that
use this are :mod:`clradcom.mechanisms.physical_optics` (one path per facet) and
:mod:`clradcom.mechanisms.sbr` (ray-tube footprints); docs/po.md gives the derivation and
sources (Knott, Shaeffer & Tuley, *Radar Cross Section*; Balanis, *Advanced Engineering
Electromagnetics*).

Conventions are those of :mod:`clradcom.physics.em` (time factor e^{+jwt}, field
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

A penetrable (lossy dielectric) facet carries J = n x H_tot and M = -n x E_tot of the
incident plus the locally reflected plane wave E_r = D E_i (D the reflection dyad of
the facet's material at its own incidence angle: TE and TM Fresnel coefficients,
roughness, specular share), radiated with the same integral::

    T = -(j k / 4 pi) L/(R_t R_r) K I_c(q)
    K = (I - s s^T)[n x (k_i x .) + n x (k_r x D .)] + s x (n x (I + D) .)

(:func:`penetrable_po_operator`; a PEC's D gives M = 0 and K = 2 (I - s s^T)[n x (k_i x .)]).
"""

from __future__ import annotations

import math

import numpy as np

from clradcom.errors import ArgumentError
from clradcom.geometry.triangles import triangle_normals_and_double_areas
from clradcom.physics import em

__all__ = ["FAR_FIELD_FACTOR", "MAX_SUBDIVISION_LEVELS", "NEAR_SIZE_FACTOR", "SPLIT_RULES",
           "far_field_pieces", "fresnel_zone", "penetrable_po_operator", "po_facet_field",
           "po_transfer", "sinc", "triangle_po_integral"]

#: Below this spread max|q.(v_i - c)| (rad) the integral uses its Taylor series.
_SERIES_SPREAD = 2.0
_SERIES_TERMS = 40
#: A facet of longest edge D lies outside an antenna's near zone when the antenna's
#: distance R from its centroid is at least NEAR_SIZE_FACTOR D: the spread of directions
#: and of 1/R over the facet, which the centroid's stand for, stays small ...
NEAR_SIZE_FACTOR = 2.0
#: ... and in its Fraunhofer far field when also R >= FAR_FIELD_FACTOR D^2 / lambda: the
#: quadratic phase k rho^2 / 2R that its linear-phase integral drops stays below pi/6
FAR_FIELD_FACTOR = 2.0
#: how far facets are split: "near" until no piece lies in an antenna's near zone,
#: "fresnel" until every piece is in its far field (both criteria), "none" not at all
SPLIT_RULES = ("near", "fresnel", "none")
#: at most this many halvings (4^levels pieces) per facet; an antenna on the facet itself
#: would ask for infinitely many
MAX_SUBDIVISION_LEVELS = 12


def sinc(x):
    """sin(x)/x with the limit 1 at 0 (stable: series below |x| = 1e-4)."""
    x = np.asarray(x, dtype=np.float64)
    small = np.abs(x) < 1e-4
    xs = np.where(small, 1.0, x)
    return np.where(small, 1.0 - x * x / 6.0, np.sin(xs) / xs)


def triangle_po_integral(vertices, q):
    """Closed-form radiation integral of flat triangles (Gordon 1975)::

        I(q) = int_triangle e^{j q . r} dA

    Edge sum (divergence theorem in the facet's plane, n = unit normal of the
    vertex order v0 -> v1 -> v2, edges l_e = v_{e+1} - v_e, midpoints m_e)::

        I = (-j / |q_t|^2) sum_e [q . (l_e x n)] sinc(q . l_e / 2) e^{j q . m_e}

    with q_t = q - (q.n) n the tangential part and sinc(x) = sin(x)/x.  When the
    phase spread over the triangle is small (max_i |q.(v_i - c)| < 2 rad, c the
    centroid; this includes q_t -> 0) the edge sum cancels badly and the exact
    Taylor series is used instead::

        I = 2 A e^{j q.c} sum_n j^n / (n+2)! h_n(d_0, d_1, d_2),  d_i = q.(v_i - c)

    (h_n the complete homogeneous symmetric polynomial; from
    int_T lambda_0^a lambda_1^b lambda_2^c dA = 2A a! b! c! / (a+b+c+2)!), which
    gives A e^{j q.c} at q_t = 0.  Coordinates are used as given: pass vertices
    relative to a reference point to get the phase relative to it.

    Parameters
    ----------
    vertices : (F,3,3) float  triangle vertices (m).
    q : (F,3) float  (rad/m), broadcast against F.

    Returns
    -------
    I : (F,) complex128 (m^2).
    """
    v = np.asarray(vertices, dtype=np.float64)
    if v.ndim != 3 or v.shape[1:] != (3, 3):
        raise ArgumentError(f"vertices must have shape (F,3,3), got {v.shape}")
    q = np.broadcast_to(np.asarray(q, dtype=np.float64), (len(v), 3))
    with np.errstate(invalid="ignore", divide="ignore"):  # such triangles are refused below
        n, two_area = triangle_normals_and_double_areas(v)
    if np.any(two_area == 0) or not np.all(np.isfinite(two_area)):
        raise ArgumentError("degenerate or non-finite triangle")
    c = v.mean(axis=1)
    qc = np.einsum("fi,fi->f", q, c)
    d = np.einsum("fi,fvi->fv", q, v - c[:, None, :])  # (F,3) phase deviations
    spread = np.abs(d).max(axis=1)
    series = spread < _SERIES_SPREAD
    out = np.empty(len(v), dtype=np.complex128)

    if np.any(series):
        ds = d[series]
        # h_n by the recurrence on the number of variables: h_n(x..) built term-wise
        # h^{(1)}_n = x0^n; h^{(m)}_n = sum_i x_m^i h^{(m-1)}_{n-i}  -> O(N^2) per var
        N = _SERIES_TERMS
        pw = ds[:, :, None] ** np.arange(N + 1)[None, None, :]  # (S,3,N+1)
        h = pw[:, 0].copy()
        for m in (1, 2):
            new = np.zeros_like(h)
            for nn in range(N + 1):
                new[:, nn] = np.sum(pw[:, m, :nn + 1] * h[:, nn::-1], axis=1)
            h = new
        coef = np.array([(1j) ** nn / math.factorial(nn + 2) for nn in range(N + 1)])
        out[series] = two_area[series] * np.exp(1j * qc[series]) * (h @ coef)

    edge = ~series
    if np.any(edge):
        ve, qe, ne = v[edge], q[edge], n[edge]
        qn = np.einsum("fi,fi->f", qe, ne)
        qt2 = np.einsum("fi,fi->f", qe, qe) - qn * qn
        acc = np.zeros(len(ve), dtype=np.complex128)
        for e in range(3):
            a, b = ve[:, e], ve[:, (e + 1) % 3]
            ell = b - a
            mid = 0.5 * (a + b)
            w = np.einsum("fi,fi->f", qe, np.cross(ell, ne))
            acc += w * sinc(0.5 * np.einsum("fi,fi->f", qe, ell)) * np.exp(
                1j * np.einsum("fi,fi->f", qe, mid))
        out[edge] = -1j * acc / qt2
    return out


def _size_and_range(v, antennas):
    """(F,) longest edge D of facets (F,3,3) and (F,) distance R of their centroids from
    the nearest antenna position (A,3)."""
    D = np.sqrt(np.max(np.sum((v - v[:, [1, 2, 0]]) ** 2, axis=-1), axis=1))
    c = v.mean(axis=1)
    R = np.min(np.linalg.norm(c[:, None, :] - antennas[None, :, :], axis=-1), axis=1)
    return D, R


def _in_far_field(v, antennas, wavelength, fresnel):
    """(F,) bool: facets (F,3,3) outside the near zone of every antenna position (A,3)
    and, with ``fresnel``, in their far field."""
    D, R = _size_and_range(v, antennas)
    ok = R >= NEAR_SIZE_FACTOR * D
    if fresnel:
        ok &= R >= FAR_FIELD_FACTOR * D * D / wavelength
    return ok


def fresnel_zone(vertices, antennas, wavelength):
    """(inside, R, far) per facet (F,3,3): outside every antenna's near zone but closer to
    one than its Fraunhofer distance ``far`` = :data:`FAR_FIELD_FACTOR` D^2/lambda, ``R``
    its centroid's distance from the nearest antenna."""
    v = np.asarray(vertices, dtype=np.float64).reshape(-1, 3, 3)
    D, R = _size_and_range(v, np.asarray(antennas, dtype=np.float64).reshape(-1, 3))
    far = FAR_FIELD_FACTOR * D * D / float(wavelength)
    return (R >= NEAR_SIZE_FACTOR * D) & (R < far), R, far


def _split4(v):
    """Each triangle (F,3,3) as its four midpoint triangles (4F,3,3), same winding,
    children of facet f at rows 4f .. 4f+3."""
    m01, m12, m20 = (0.5 * (v[:, 0] + v[:, 1]), 0.5 * (v[:, 1] + v[:, 2]),
                     0.5 * (v[:, 2] + v[:, 0]))
    kids = np.stack([np.stack([v[:, 0], m01, m20], axis=1),
                     np.stack([m01, v[:, 1], m12], axis=1),
                     np.stack([m20, m12, v[:, 2]], axis=1),
                     np.stack([m01, m12, m20], axis=1)], axis=1)
    return kids.reshape(-1, 3, 3)


def far_field_pieces(vertices, antennas, wavelength, rule="fresnel",
                     max_levels=MAX_SUBDIVISION_LEVELS):
    """Facets split by midpoints until no piece lies in the near zone of an antenna
    (:data:`NEAR_SIZE_FACTOR`) and, with ``rule`` "fresnel", every piece is in its far
    field (:data:`FAR_FIELD_FACTOR`); each only as far as it needs.

    A facet integral (:func:`triangle_po_integral` at one q, 1/R_t R_r and directions of
    its centroid) is the PO return of a facet in its antennas' far field; closer, it is
    not (an antenna 1 mm off a plate: the two directions of a link differed by 30 dB).
    Pieces in their far field sum to the Fresnel-zone PO integral of the facet.

    Returns ``(pieces (P,3,3), parent (P,) facet index, ascending, settled (P,) bool)``;
    ``settled`` is False for the pieces still in a near field after ``max_levels``
    halvings.  Facets already in the far field come back as they are."""
    if rule not in SPLIT_RULES:
        raise ArgumentError(f"must be one of {', '.join(map(repr, SPLIT_RULES))}",
                            argument="rule", value=rule)
    v = np.asarray(vertices, dtype=np.float64).reshape(-1, 3, 3)
    ant = np.asarray(antennas, dtype=np.float64).reshape(-1, 3)
    parent = np.arange(len(v))
    if rule == "none":
        return v, parent, np.ones(len(v), bool)
    out_v, out_p, out_ok = [], [], []
    for level in range(int(max_levels) + 1):
        ok = _in_far_field(v, ant, float(wavelength), rule == "fresnel")
        if level == max_levels or ok.all():
            out_v.append(v)
            out_p.append(parent)
            out_ok.append(ok)
            break
        out_v.append(v[ok])
        out_p.append(parent[ok])
        out_ok.append(ok[ok])
        v = _split4(v[~ok])
        parent = np.repeat(parent[~ok], 4)
    pieces, parent, settled = (np.concatenate(x) for x in (out_v, out_p, out_ok))
    order = np.argsort(parent, kind="stable")
    return pieces[order], parent[order], settled[order]


def penetrable_po_operator(normal, k_in, s, reflection):
    """Current operator K (F,3,3) of a penetrable facet: the scattered far field of its
    lit-side equivalent currents per incident field, for ``reflection`` the local
    reflection dyad D (F,3,3) (E_r = D E_i, :func:`clradcom.physics.em.reflection_dyad`
    at k_in on this facet, Fresnel coefficients x roughness x specular share)::

        K = (I - s s^T) [n x (k_i x .) + n x (k_r x D .)] + s x (n x (I + D) .)
        k_r = k_i - 2 (k_i . n) n

    from J = n x (H_i + H_r), M = -n x (E_i + E_r), H = k x E / eta (docs/po.md).  The
    facet's transfer dyad is T = -(j k / 4 pi) L/(R_t R_r) K I_c(q).  A PEC's D
    (r_te = -1, r_tm = +1) gives M = 0 and K = 2 (I - s s^T)[n x (k_i x .)], the PEC
    current of :func:`po_transfer`.  ``normal`` is the lit-side unit normal (k_in . n < 0),
    ``s`` the unit direction towards the receiver.
    """
    n = np.asarray(normal, dtype=np.float64).reshape(-1, 3)
    ki = np.asarray(k_in, dtype=np.float64).reshape(-1, 3)
    s = np.asarray(s, dtype=np.float64).reshape(-1, 3)
    D = np.asarray(reflection, dtype=np.complex128).reshape(-1, 3, 3)
    eye = np.eye(3)
    kin = np.einsum("fi,fi->f", n, ki)
    kr = ki - 2.0 * kin[:, None] * n
    # n x (b x e) = b (n . e) - e (n . b); n . k_r = -n . k_i
    a_i = ki[:, :, None] * n[:, None, :] - kin[:, None, None] * eye
    a_r = kr[:, :, None] * n[:, None, :] + kin[:, None, None] * eye
    proj = eye - s[:, :, None] * s[:, None, :]
    return proj @ (a_i + a_r @ D) + _cross_matrix(s) @ _cross_matrix(n) @ (eye + D)


def po_currents(normal, k_in, field, reflection=None):
    """The currents (a, b), each (F,3) complex, that an incident ``field`` (F,3) drives on
    facets of lit-side ``normal`` along ``k_in``, written so that the far field toward
    any s is K E = (I - s s^T) a + s x b (:func:`penetrable_po_operator`'s K applied to
    E, for evaluating one facet toward many s without a 3 x 3 product each): a = n x
    (k_i x E) + n x (k_r x D E), b = n x ((I + D) E); ``reflection`` None is a PEC's
    (a = 2 n x (k_i x E), b = 0)."""
    n = np.asarray(normal, dtype=np.float64).reshape(-1, 3)
    ki = np.asarray(k_in, dtype=np.float64).reshape(-1, 3)
    e = np.asarray(field, dtype=np.complex128).reshape(-1, 3)
    if reflection is None:
        return 2.0 * np.cross(n, np.cross(ki, e)), np.zeros_like(e)
    reflected = np.einsum("fij,fj->fi", np.asarray(reflection, dtype=np.complex128), e)
    kr = ki - 2.0 * np.einsum("fi,fi->f", ki, n)[:, None] * n
    return (np.cross(n, np.cross(ki, e)) + np.cross(n, np.cross(kr, reflected)),
            np.cross(n, e + reflected))


def _cross_matrix(v):
    """[v]_x (F,3,3): [v]_x e = v x e."""
    z = np.zeros(len(v))
    return np.stack([np.stack([z, -v[:, 2], v[:, 1]], axis=-1),
                     np.stack([v[:, 2], z, -v[:, 0]], axis=-1),
                     np.stack([-v[:, 1], v[:, 0], z], axis=-1)], axis=1)


def po_transfer(vertices, normal, tx_pos, rx_pos, carrier_hz, reflection=None):
    """PO transfer dyad T (F,3,3), length L (F,), centroid c (F,3) and the unit
    directions k_dep = (c - tx)/R_t, k_arr = (rx - c)/R_r of facets.

    PEC (``reflection`` None)::

        T = -(j k / 2 pi) L/(R_t R_r) (I - s s^T) [n x (k_i x .)] I_c(k (s - k_i))

    Penetrable: ``reflection`` is a callable ``(k_in (F,3), normal (F,3)) -> D (F,3,3)``
    giving each facet's local reflection dyad (e.g.
    :func:`clradcom.physics.em.material_reflection_dyad` of its material); then
    T = -(j k / 4 pi) L/(R_t R_r) K I_c with K of :func:`penetrable_po_operator`
    (J = n x H_tot, M = -n x E_tot of the incident plus reflected fields).

    ``normal`` (F,3) is the lit-side unit normal (the caller checks the sides).
    """
    v = np.asarray(vertices, dtype=np.float64).reshape(-1, 3, 3)
    n = np.asarray(normal, dtype=np.float64).reshape(-1, 3)
    n = n / np.linalg.norm(n, axis=-1, keepdims=True)
    t = np.asarray(tx_pos, dtype=np.float64).reshape(-1, 3)
    r = np.asarray(rx_pos, dtype=np.float64).reshape(-1, 3)
    k = 2.0 * np.pi * float(carrier_hz) / em.C0
    c = v.mean(axis=1)
    dt = c - t
    dr = r - c
    R_t = np.linalg.norm(dt, axis=-1)
    R_r = np.linalg.norm(dr, axis=-1)
    if np.any(R_t == 0) or np.any(R_r == 0):
        raise ArgumentError("tx or rx coincides with a facet centroid")
    ki = dt / R_t[:, None]
    s = dr / R_r[:, None]
    L = R_t + R_r
    I_c = triangle_po_integral(v - c[:, None, :], k * (s - ki))
    scale = -1j * k / (2.0 * np.pi) * L / (R_t * R_r) * I_c
    if reflection is None:
        eye = np.eye(3)
        # n x (k_i x e) = k_i (n . e) - e (n . k_i)
        cross2 = ki[:, :, None] * n[:, None, :] - np.einsum("fi,fi->f", n, ki)[:, None, None] * eye
        proj = eye - s[:, :, None] * s[:, None, :]
        op = proj @ cross2
    else:
        n = np.broadcast_to(n, ki.shape)
        D = np.asarray(reflection(ki, n), dtype=np.complex128)
        op = 0.5 * penetrable_po_operator(n, ki, s, D)
    T = scale[:, None, None] * op
    return T, L, c, ki, s


def po_facet_field(vertices, normal, tx_pos, rx_pos, e_tx, carrier_hz, reflection=None):
    """Bistatic PO scattered field of facets, normalised like :mod:`clradcom.physics.em`.

    The transmitter radiates ``e_tx e^{-jkd}/d`` (e_tx (F,3) complex, world,
    transverse to k_dep: C_theta theta_hat + C_phi phi_hat); the returned field at
    rx is ``E = T e_tx e^{-jkL}/L`` (F,3), so the gain for a receive vector e_rx is
    a = (lambda/4 pi) e_rx . E.  ``reflection`` as in :func:`po_transfer` (None: PEC).
    Returns (E, T, L, centroid).
    """
    T, L, c, _, _ = po_transfer(vertices, normal, tx_pos, rx_pos, carrier_hz, reflection)
    k = 2.0 * np.pi * float(carrier_hz) / em.C0
    e = np.broadcast_to(np.asarray(e_tx, dtype=np.complex128), (len(L), 3))
    E = np.einsum("fij,fj->fi", T, e) * (np.exp(-1j * k * L) / L)[:, None]
    return E, T, L, c
