"""UTD edge-diffraction paths: up to three diffractions, mixed with reflections.

A candidate is an *interaction pattern* (a tuple of REFLECTION / DIFFRACTION codes,
e.g. ``(R, D)`` or ``(D, D)``) and, per candidate, the planar face or wedge of every
interaction. Stages (plain arrays in and out):

1. wedges come from :func:`clradcom.geometry.wedges.extract_wedges` (once per scene);
2. :func:`diffraction_candidates` proposes patterns and elements: single wedges, the
   tracer's own ray-found reflection sequences as prefixes (from the transmitter) and
   suffixes (from the receiver), and chains of 2-3 wedges that see each other;
3. :func:`unfold_points` places every point exactly in float64: each reflection
   mirrors everything after it (images), which straightens the path into a chain of
   diffractions between the transmitter and the receiver's image; the diffraction
   points on the mirrored edges follow from Keller's law (closed form for one edge,
   convex minimisation for several, :func:`clradcom.geometry.wedges.multi_diffraction_points`),
   and the reflection points are where the straight unfolded segments cross the
   mirrored face planes;
4. :func:`confirm_chains` checks every point with rays: a reflection point must be the
   first thing its incoming segment meets (inside its face, nothing in between), a
   segment to a diffraction point or the receiver must be unobstructed, and each
   diffraction must see both its neighbours from outside its wedge;
5. :func:`chain_fields` multiplies the reflection dyads (Fresnel x roughness x
   sqrt(1 - S^2), as for specular paths) and the UTD diffraction dyads
   (Kouyoumjian-Pathak / Luebbers, :mod:`clradcom.physics.utd`) in order, with the
   multi-edge spreading of :func:`clradcom.physics.utd.multi_edge_spreading` on the unfolded
   segment lengths -> gain, 2x2 matrix, delay, Doppler.

Concave creases (n < 1) are left out (UTD is not validated there and their faces'
reflections dominate). See docs/utd.md "Mixed paths" for the candidate budget.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from clradcom.device import edges as device_edges
from clradcom.device import engines
from clradcom.device.raycast import make_rays, spawn_origins
from clradcom.device.visibility import (
    antenna_slack,
    confirm_segments,
    confirm_slack,
    containing_triangles,
    edge_distances,
)
from clradcom.errors import ArgumentError, ArgumentTypeError, BoundaryWarning, CausticWarning
from clradcom.geometry.rows import row_counts
from clradcom.geometry.wedges import (
    Wedges,
    diffraction_point,
    extract_wedges,
    free_wedges,
    multi_diffraction_points,
)
from clradcom.mechanisms.common import Geometry, check_number, seen_by_antennas
from clradcom.paths import InteractionType, Paths, concat_paths
from clradcom.physics import em, utd
from clradcom.scene.records import Radar

#: Segments leave the edge point from this far along themselves (m), past the
#: float32 rounding of the faces that meet at the edge.
EDGE_CLEARANCE_M = 1e-3
#: A ray this close (rad) to a wedge face grazes it: phi is snapped onto the face.
GRAZING_RAD = 1e-6
#: A diffraction this close (rad) to a shadow or reflection boundary is "on" it.
ON_BOUNDARY_RAD = 1e-9
#: Within this many float32 roundoffs of a boundary, relative to 1 + |Q| over the shorter
#: leg at the edge point Q (and never less than ON_BOUNDARY_RAD), a UTD term takes the
#: side of the tracer's own GO decision of that boundary (the line of sight or the face's
#: reflection found or not), so GO and UTD are cut at one decision: the float32 casts
#: that confirm GO paths resolve about 1e-7 |p|, and float64 rounding the rest.
GO_MATCH_REL = 1e-6
#: Occlusion tests of segments that touch an edge run this far (m) off the wedge, so a
#: segment grazing along a face is not blocked by that face's own triangles.
EDGE_LIFT_M = 1e-4
#: wedges_seeing halves a piece of an edge that no single face is proven to hide at most
#: this many times (pieces down to 1/16 of an edge) before keeping the wedge anyway.
#: Halving only helps where blockers overlap; deeper cost more than it saved on the street.
SEEING_MAX_DEPTH = 2

#: The candidate pre-test (:func:`_keller_plausible_grid`, :func:`_angles_plausible`)
#: rejects only beyond these margins of the exact tests it anticipates: Keller points
#: this far (relative to 1 + the largest coordinate of the antennas' images) off the
#: usable edge, reflection crossings this far outside their segment, directions this far
#: (rad) inside the wedge; the exact float64 tests then decide, so a candidate they would
#: keep is never pre-rejected.
PLAUSIBLE_REL = 1e-6
PLAUSIBLE_RAD = 1e-5

REFLECTION = int(InteractionType.REFLECTION)
DIFFRACTION = int(InteractionType.DIFFRACTION)


@dataclass(eq=False)
class Chains:
    """Candidates of one interaction pattern: ``elements[:, i]`` is a planar face id
    where ``pattern[i]`` is REFLECTION and a wedge id where it is DIFFRACTION."""

    pattern: tuple[int, ...]
    elements: np.ndarray  # (C, K) int64

    def __len__(self) -> int:
        return len(self.elements)

    @property
    def n_diffractions(self) -> int:
        return sum(1 for p in self.pattern if p == DIFFRACTION)


def _apply(A, b, x):
    return np.einsum("cij,cj->ci", A, x) + b


def _apply_inverse(A, b, x):
    return np.einsum("cji,cj->ci", A, x - b)


def unfold_points(chains: Chains, tx, rx, face_normal, face_offset, wedges: Wedges):
    """Exact interaction points of every candidate: (points (C, K+2, 3), ok (C,)).

    ``points[:, 0]`` is tx, ``points[:, -1]`` rx. ``ok`` is false where a diffraction
    point falls off its finite edge (or within EDGE_CLEARANCE_M of its ends, which are
    corners, not wedges), the chain minimisation did not converge, or a reflection
    plane is not crossed between its neighbours in the right order.
    """
    pattern, elem = chains.pattern, np.asarray(chains.elements)
    C, K = elem.shape
    tx = np.asarray(tx, dtype=np.float64)
    rx = np.asarray(rx, dtype=np.float64)
    points = np.full((C, K + 2, 3), np.nan)
    points[:, 0] = tx
    points[:, -1] = rx
    ok = np.ones(C, dtype=bool)
    if C == 0:
        return points, ok
    # T(x) = A x + b maps the real position of everything after the reflections seen so
    # far into the unfolded (straightened) frame: T <- T o Mirror(face) per reflection
    A = np.broadcast_to(np.eye(3), (C, 3, 3)).copy()
    b = np.zeros((C, 3))
    frames, starts, ends, planes = [], [], [], []
    for i, kind in enumerate(pattern):
        frames.append((A, b))
        if kind == REFLECTION:
            n = face_normal[elem[:, i]]
            d = face_offset[elem[:, i]]
            n_unf = np.einsum("cij,cj->ci", A, n)
            planes.append((n_unf, d + np.einsum("ci,ci->c", n_unf, b)))
            mirror = np.eye(3)[None] - 2.0 * n[:, :, None] * n[:, None, :]
            b = b + np.einsum("cij,cj->ci", A, 2.0 * d[:, None] * n)
            A = A @ mirror
        elif kind == DIFFRACTION:
            w = elem[:, i]
            starts.append(_apply(A, b, wedges.start[w]))
            ends.append(_apply(A, b, wedges.end[w]))
        else:
            raise ArgumentError(f"pattern[{i}] = {kind!r} is neither REFLECTION nor DIFFRACTION")
    rx_unf = _apply(A, b, np.broadcast_to(rx, (C, 3)))
    nd = len(starts)
    if nd == 0:
        raise ArgumentError(f"pattern {pattern} has no diffraction: specular paths are "
                         "clradcom.specular's")
    if nd == 1:
        dp = diffraction_point(tx, rx_unf, starts[0], ends[0])
        q_unf, t = dp.point[:, None], dp.t[:, None]
    else:
        S_, E_ = np.stack(starts, 1), np.stack(ends, 1)
        ok &= _keller_plausible(tx, rx_unf, S_, E_)
        q_unf = np.full((C, nd, 3), np.nan)
        t = np.full((C, nd), -1.0)
        sel = np.flatnonzero(ok)
        if len(sel):
            md = multi_diffraction_points(tx, rx_unf[sel], S_[sel], E_[sel])
            q_unf[sel], t[sel] = md.points, md.t
            ok[sel] &= md.converged
    lengths = np.stack([wedges.length[elem[:, i]] for i, k in enumerate(pattern)
                        if k == DIFFRACTION], axis=1)
    ok &= np.all((t > EDGE_CLEARANCE_M) & (t < lengths - EDGE_CLEARANCE_M), axis=1)
    nodes = [np.broadcast_to(tx, (C, 3))] + [q_unf[:, j] for j in range(nd)] + [rx_unf]
    j = r = 0
    last_t = np.zeros(C)
    for i, kind in enumerate(pattern):
        A_i, b_i = frames[i]
        if kind == DIFFRACTION:
            points[:, i + 1] = _apply_inverse(A_i, b_i, q_unf[:, j])
            j += 1
            last_t = np.zeros(C)
            continue
        n_unf, d_unf = planes[r]
        r += 1
        prev, nxt = nodes[j], nodes[j + 1]
        line = nxt - prev
        with np.errstate(divide="ignore", invalid="ignore"):
            s = (d_unf - np.einsum("ci,ci->c", n_unf, prev)) / np.einsum("ci,ci->c", n_unf,
                                                                         line)
        good = np.isfinite(s) & (s > last_t + 1e-12) & (s < 1.0 - 1e-12)
        ok &= good
        s = np.where(good, s, 0.5)
        last_t = s
        points[:, i + 1] = _apply_inverse(A_i, b_i, prev + s[:, None] * line)
    ok &= np.all(np.isfinite(points), axis=(1, 2))
    return points, ok


def _keller_plausible(tx, rx, starts, ends) -> np.ndarray:
    """Cheap necessary-ish test before the chain minimisation: on every edge of a chain
    (unfolded frame, (C, N, 3)), the closed-form Keller points between its neighbours'
    end points (the source and target for the outer edges) must reach into the finite
    edge for at least one choice of neighbour points. The exact point lies between such
    extremes for all but strongly skewed edges."""
    C, N, _ = starts.shape
    ok = np.ones(C, bool)
    src = np.broadcast_to(np.asarray(tx, np.float64), (C, 3))
    dst = np.asarray(rx, np.float64)
    for j in range(N):
        before = [src] if j == 0 else [starts[:, j - 1], ends[:, j - 1]]
        after = [dst] if j == N - 1 else [starts[:, j + 1], ends[:, j + 1]]
        length = np.linalg.norm(ends[:, j] - starts[:, j], axis=1)
        lo = np.full(C, np.inf)
        hi = np.full(C, -np.inf)
        for p in before:
            for q in after:
                t = diffraction_point(p, q, starts[:, j], ends[:, j]).t
                lo, hi = np.minimum(lo, t), np.maximum(hi, t)
        ok &= (hi > 0.0) & (lo < length)
    return ok


def diffraction_angles(chains: Chains, points, wedges: Wedges, ok=None):
    """(phi', phi, beta0, grazing) (C, nd) at each diffraction, and a mask of candidates
    whose every diffraction sees both neighbours from outside its wedge (or along one of
    its faces: ``grazing`` marks incidence along a face from the previous edge, where KP's
    1/2 applies), not end-on."""
    C = len(chains)
    nd = chains.n_diffractions
    keep = np.ones(C, bool) if ok is None else np.asarray(ok, bool).copy()
    phi_p = np.zeros((C, nd))
    phi = np.zeros((C, nd))
    beta0 = np.full((C, nd), np.pi / 2)
    grazing = np.zeros((C, nd), bool)
    if C == 0:
        return phi_p, phi, beta0, grazing, keep
    j = 0
    for i, kind in enumerate(chains.pattern):
        if kind != DIFFRACTION:
            continue
        w = chains.elements[:, i]
        s_in = points[:, i + 1] - points[:, i]
        s_out = points[:, i + 2] - points[:, i + 1]
        len_in = np.linalg.norm(s_in, axis=1)
        len_out = np.linalg.norm(s_out, axis=1)
        good = keep & (len_in > EDGE_CLEARANCE_M) & (len_out > EDGE_CLEARANCE_M)
        good &= wedges.n[w] >= 1.0
        e = wedges.direction[w]
        safe_in = np.where(good[:, None], s_in, e + 1.0) / np.where(good, len_in, 1.0)[:, None]
        safe_out = np.where(good[:, None], s_out, e + 1.0) / np.where(good, len_out,
                                                                     1.0)[:, None]
        # an end on the edge line sees it end-on: no Keller cone
        end_on = good & ~((np.linalg.norm(np.cross(safe_in, e), axis=1) > 1e-9) & (
            np.linalg.norm(np.cross(safe_out, e), axis=1) > 1e-9))
        if end_on.any():
            warnings.warn(CausticWarning(
                f"{int(end_on.sum())} edge(s) seen end-on (within 1e-9 rad of the edge "
                f"line, e.g. wedge {int(w[end_on][0])}): the Keller cone collapses onto "
                "the edge, a caustic of the diffracted rays, and the path is left out; "
                "a hair off the line its field is finite (docs/stability.md)"),
                stacklevel=3)
        good &= ~end_on
        pp, p, b0 = utd.wedge_angles(safe_in, safe_out, e, wedges.normal0[w])
        limit = wedges.n[w] * np.pi
        pp, graze_in = _snap_to_faces(pp, limit)
        p, _ = _snap_to_faces(p, limit)
        good &= (pp <= limit) & (p <= limit) & ~(graze_in & (np.abs(p - pp) < GRAZING_RAD))
        phi_p[:, j], phi[:, j], beta0[:, j] = pp, p, b0
        # KP's grazing 1/2 is for a total (incident + face-reflected) field arriving along
        # the face: the hop from another edge.  The wave of an antenna (or of a mirror)
        # near the face's plane is the incident field alone, and the full D gives its
        # diffraction, as for the antenna receiving there (reciprocity).
        after_edge = i > 0 and chains.pattern[i - 1] == DIFFRACTION
        grazing[:, j] = graze_in & after_edge
        keep &= good
        j += 1
    return phi_p, phi, beta0, grazing, keep


def _snap_to_faces(angle, limit):
    """Angles within GRAZING_RAD of a face (0 or n pi, or 2 pi as 0) put on it, and a
    mask of those; the wedge's interior stays beyond ``limit``.  For a half-plane
    (n pi = 2 pi) an angle just below 2 pi lies at face n, its back, not at face 0."""
    a = np.where((angle > 2 * np.pi - GRAZING_RAD) & (limit < 2 * np.pi - GRAZING_RAD), 0.0,
                 angle)
    on0 = a < GRAZING_RAD
    on_n = np.abs(a - limit) < GRAZING_RAD
    a = np.where(on0, 0.0, np.where(on_n, limit, a))
    return a, on0 | on_n


def lift_direction(wedges: Wedges, w, away) -> np.ndarray:
    """Unit vectors off wedges w into their exterior: the bisector of the two outward
    normals, or for a half-plane its normal on the side of ``away``."""
    n0, n1 = wedges.normal0[w], wedges.normal1[w]
    bis = n0 + n1
    size = np.linalg.norm(bis, axis=1)
    side = np.where(np.einsum("ci,ci->c", n0, away) < 0, -1.0, 1.0)
    flat = size < 1e-6
    return np.where(flat[:, None], side[:, None] * n0,
                    bis / np.where(flat, 1.0, size)[:, None])


def confirm_chains(caster, tri_face, face_normal, chains: Chains, points, ok=None,
                   wedges: Wedges | None = None, engine: str = "device"):
    """Mask of candidates whose every segment is confirmed by a ray cast, and the scene
    triangle of each reflection point ((C, K) int32, -1 at diffractions).

    Toward a reflection point the segment must first meet that face at the point (which
    proves the point lies inside the face and nothing stands in between); toward a
    diffraction point or the receiver nothing may block it. Both are decided as for
    specular paths, in float64 where float32 rounding could flip them
    (:func:`clradcom.device.visibility.reaches_face`,
    :func:`clradcom.device.visibility.segments_clear`). Segments leave reflection points
    from just off the face and diffraction points from EDGE_CLEARANCE_M along themselves.
    The millimetre next to each antenna is decided in float64
    (:func:`clradcom.device.visibility.antenna_blocked`), as for specular paths.
    ``engine`` ("device" or "host") is where the float64 re-decisions are made.
    """
    pattern, elem = chains.pattern, chains.elements
    C, K = elem.shape
    keep = np.ones(C, bool) if ok is None else np.asarray(ok, bool).copy()
    triangles = np.full((C, K), -1, dtype=np.int32)
    idx = np.flatnonzero(keep)
    for i in range(K + 1):
        if len(idx) == 0:
            break
        start, end = points[idx, i], points[idx, i + 1]
        seg = end - start
        length = np.linalg.norm(seg, axis=1)
        if i == 0:  # leaving the transmitter: its first millimetre is antenna_blocked's
            tmin = antenna_slack(start, length)
        else:
            tmin = np.zeros(len(idx))
        if i > 0 and pattern[i - 1] == REFLECTION:
            start = spawn_origins(start, face_normal[elem[idx, i - 1]], seg)
        elif i > 0:
            start = start + EDGE_LIFT_M * lift_direction(wedges, elem[idx, i - 1], seg)
            tmin = EDGE_CLEARANCE_M / np.maximum(length, 1e-12)
        if i < K and pattern[i] == DIFFRACTION:
            end = end + EDGE_LIFT_M * lift_direction(wedges, elem[idx, i], -seg)
        to_face = i < K and pattern[i] == REFLECTION
        to_edge = i < K and pattern[i] == DIFFRACTION
        stop = (EDGE_CLEARANCE_M / np.maximum(length, 1e-12) if to_edge
                else confirm_slack(end, length))
        good, tri = confirm_segments(caster, tri_face, start, end, length,
                                     face=elem[idx, i] if to_face else None, tmin=tmin,
                                     stop=stop, at_tx=i == 0, at_rx=i == K, engine=engine)
        if to_face:
            triangles[idx, i] = tri
        keep[idx[~good]] = False
        idx = idx[good]
    triangles[~keep] = -1
    return keep, triangles


def go_face_sequences(paths: Paths, tri_face) -> set:
    """The planar-face sequences (tuples; () for the line of sight) of the GO paths
    (reflections only) among ``paths``."""
    out = set()
    n = np.asarray(paths.n_interactions)
    for k in np.unique(n):
        rows = np.flatnonzero(n == k)
        rows = rows[np.all(paths.interaction[rows, :k] == REFLECTION, axis=1)]
        out.update(map(tuple, np.asarray(tri_face)[paths.face_id[rows, :k]].tolist()))
    return out


def go_sides(chains: Chains, i: int, points, phi, phi_p, wedges: Wedges, tri_face,
             go_sequences: set):
    """Sides of the four UTD terms (D1-D4, utd.boundary_epsilons) of the diffraction at
    ``pattern[i]`` of single-diffraction candidates: within the GO_MATCH_REL band of a
    term's boundary, +1 where the tracer's GO path of that boundary was found, -1 where
    not; 0 (the term's own sign) elsewhere.  That GO path is the candidate's reflections
    without the edge (shadow boundary, D1 and D2) or with the edge replaced by a
    reflection off face n (D3) or face 0 (D4): the same face sequence,
    ``go_sequences`` (:func:`go_face_sequences`)."""
    C = len(chains)
    sides = [np.zeros(C, np.int8) for _ in range(4)]
    w = chains.elements[:, i]
    eps = utd.boundary_epsilons(phi, phi_p, wedges.n[w])
    q = points[:, i + 1]
    leg = np.minimum(np.linalg.norm(q - points[:, i], axis=1),
                     np.linalg.norm(points[:, i + 2] - q, axis=1))
    band = np.maximum(ON_BOUNDARY_RAD,
                      GO_MATCH_REL * (1.0 + np.abs(q).max(axis=1)) / np.maximum(leg, 1e-12))
    near = [np.abs(e) < band for e in eps]
    face0 = np.asarray(tri_face)[wedges.tri0[w]]
    face_n = np.where(wedges.tri1[w] >= 0, np.asarray(tri_face)[np.maximum(wedges.tri1[w], 0)],
                      face0)
    for c in np.flatnonzero(near[0] | near[1] | near[2] | near[3]):
        pre = tuple(int(f) for f in chains.elements[c, :i])
        post = tuple(int(f) for f in chains.elements[c, i + 1:])
        counterpart = (pre + post, pre + post, pre + (int(face_n[c]),) + post,
                       pre + (int(face0[c]),) + post)
        for k in range(4):
            if near[k][c]:
                sides[k][c] = 1 if counterpart[k] in go_sequences else -1
    return sides


def chain_fields(scene, faces, wedges: Wedges, chains: Chains, points, triangles, angles,
                 tx, rx, go_sequences: set | None = None) -> Paths:
    """UTD fields of confirmed mixed paths as :class:`Paths` (K = len(pattern)).

    With ``go_sequences`` (the face sequences of the link's GO paths) a single
    diffraction near one of its boundaries takes the side of the GO decision there
    (:func:`go_sides`), so the total is continuous through the boundary."""
    pattern, elem = chains.pattern, chains.elements
    C, K = elem.shape
    if C == 0:
        return Paths.empty(K)
    phi_p, phi, beta0, grazing = angles
    seg = np.diff(points, axis=1)
    s = np.linalg.norm(seg, axis=2)
    u = seg / s[..., None]
    total = s.sum(axis=1)
    k = 2.0 * np.pi / scene.wavelength_m
    # unfolded lengths between consecutive diffraction nodes (reflections are isometries)
    group = np.cumsum([0] + [1 if p == DIFFRACTION else 0 for p in pattern])
    s_unf = np.stack([s[:, group == g].sum(axis=1) for g in range(group[-1] + 1)], axis=1)
    spread, L = utd.multi_edge_spreading(s_unf, beta0)
    T = (np.eye(3)[None] - u[:, 0, :, None] * u[:, 0, None, :]).astype(np.complex128)
    obj = np.empty((C, K), np.int32)
    face_id = np.empty((C, K), np.int32)
    j = 0
    for i, kind in enumerate(pattern):
        el = elem[:, i]
        if kind == REFLECTION:
            dyad = em.material_reflection_dyad(scene, faces.material_id[el], u[:, i],
                                               faces.normal[el])
            obj[:, i] = faces.object_id[el]
            face_id[:, i] = triangles[:, i]
        else:
            sides = None
            if go_sequences is not None and chains.n_diffractions == 1:
                sides = go_sides(chains, i, points, phi[:, j], phi_p[:, j], wedges,
                                 faces.tri_face, go_sequences)
            _warn_on_boundaries(phi[:, j], phi_p[:, j], wedges.n[el], grazing[:, j], sides)
            m0, m1 = wedges.material0[el], wedges.material1[el]
            pec = scene.material_pec[m0] & scene.material_pec[m1]
            d_soft, d_hard = utd.diffraction_coefficients(
                phi[:, j], phi_p[:, j], beta0[:, j], wedges.n[el], k, L[:, j],
                eps_r_0=scene.material_eps_r[m0], eps_r_n=scene.material_eps_r[m1], pec=pec,
                go_sides=sides)
            # incidence along a face: the wave arriving there is already the total
            # (incident + face-reflected) field, so KP's grazing 1/2 applies [KP74]
            half = np.where(grazing[:, j], 0.5, 1.0)
            basis = utd.edge_fixed_basis(u[:, i], u[:, i + 1], wedges.direction[el])
            dyad = utd.diffraction_dyad(half * d_soft, half * d_hard, *basis)
            obj[:, i] = wedges.object_id[el]
            face_id[:, i] = wedges.tri0[el]
            j += 1
        T = dyad @ T
    # em.path_gains scales by exp(-jkL)/L with L the total length; the diffracted wave
    # carries (1/s_0) prod_i A_i instead, so T absorbs the ratio
    T = T * (total / s_unf[:, 0] * spread)[:, None, None]
    gain, M = em.path_gains(T, total, u[:, 0], u[:, -1], tx, rx, scene.carrier_hz)
    vel = np.empty_like(points)
    vel[:, 0] = tx.velocity
    vel[:, 1:K + 1] = scene.point_velocity(obj, points[:, 1:K + 1])
    vel[:, K + 1] = rx.velocity
    doppler = em.doppler_hz(points, vel, scene.wavelength_m)
    return Paths(gain=gain, matrix=M, delay_s=em.delay_s(total), doppler_hz=doppler,
                 n_interactions=np.full(C, K, np.int16),
                 interaction=np.broadcast_to(np.asarray(pattern, np.int8), (C, K)).copy(),
                 points=points, object_id=obj, face_id=face_id)


def _warn_on_boundaries(phi, phi_p, n, grazing, sides=None):
    """BoundaryWarning for diffractions exactly on a shadow boundary (phi - phi' = +-pi)
    or a reflection boundary (phi + phi' = pi or (2n - 1) pi) whose side no GO decision
    gave (``sides``, :func:`go_sides`: then the total is continuous there). Grazing
    incidence puts every boundary on a face by construction: KP's 1/2 handles it, no
    warning."""
    d_inc = np.abs(np.abs(phi - phi_p) - np.pi)
    d_ref = np.minimum(np.abs(phi + phi_p - np.pi), np.abs(phi + phi_p - (2 * n - 1) * np.pi))
    if sides is not None:
        d_inc = np.where((sides[0] != 0) | (sides[1] != 0), np.inf, d_inc)
        d_ref = np.where((sides[2] != 0) | (sides[3] != 0), np.inf, d_ref)
    on = ~grazing & ((d_inc < ON_BOUNDARY_RAD) | (d_ref < ON_BOUNDARY_RAD))
    if on.any():
        i = int(np.flatnonzero(on)[0])
        kind = "shadow" if d_inc[i] < ON_BOUNDARY_RAD else "reflection"
        warnings.warn(BoundaryWarning(
            f"{int(on.sum())} diffracted path(s) lie on a {kind} boundary of their edge "
            f"(phi = {phi[i]:.12f}, phi' = {phi_p[i]:.12f} rad): the total field there is "
            "off by half the GO field (docs/stability.md)"), stacklevel=4)


# ---------------------------------------------------------------------------
# candidates

def wedges_seeing(caster, wedges: Wedges, point, samples=(0.25, 0.5, 0.75), tri_face=None,
                  max_depth: int = SEEING_MAX_DEPTH, engine: str = "device") -> np.ndarray:
    """Mask of wedges of which some point (away from the ends by EDGE_CLEARANCE_M, where
    Keller points may lie) may see ``point`` unobstructed from outside the wedge: a
    candidate filter that only over-accepts (the exact diffraction point is confirmed
    later).

    Sight lines to three ``samples`` (fractions of the edge) come first; a wedge seen
    there is in.  A wedge hidden at all of them is dropped only when its whole usable
    edge is proven hidden: the edge is cut into pieces between sight lines whose first
    blocker is known, and a piece is hidden when one planar face (``tri_face``, default
    one per triangle) covers the whole triangle ``point`` - piece
    (:func:`_face_covers`).  Pieces not proven so are halved (a sight line from the
    midpoint: clear -> the wedge is in) down to ``max_depth`` halvings; a wedge with a
    piece still open then is kept.  (Three samples alone dropped edges whose samples a
    plate hid while their Keller points were in plain sight.)

    ``engine`` "device" decides every wedge in one launch of
    ``kernels/edges.cl`` (:func:`clradcom.device.edges.wedges_seen`), the same wedges as
    "host", this numpy reference over float32 casts."""
    return _seeing_many(caster, wedges, [point], samples, tri_face, max_depth,
                        engine=engine)[0][1]


def _seeing_many(caster, wedges: Wedges, points, samples=(0.25, 0.5, 0.75), tri_face=None,
                 max_depth: int = SEEING_MAX_DEPTH, outlines: dict | None = None,
                 engine: str = "device"):
    """[(seen at the samples, kept)] per point: :func:`_seeing` for several antenna
    positions, on the device in one launch (engine "device", unless
    :func:`clradcom.device.edges.device_refusal` gives a reason, which is recorded:
    :func:`clradcom.device.engines.record`), else point by point on the host."""
    refusal = device_edges.device_refusal(caster, len(samples), max_depth)
    if engine == "host":
        engines.record("diffraction.edge_sight", "host", fallback=False)
    elif refusal is not None:
        engines.record("diffraction.edge_sight", "host", refusal)
    if engine == "host" or refusal is not None or len(wedges) == 0:
        return [_seeing(caster, wedges, p, samples, tri_face, max_depth, outlines)
                for p in points]
    engines.record("diffraction.edge_sight", "device")
    W, S = len(wedges), len(samples)
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    P = len(points)
    # whether each point lies outside each wedge, seen from the sample points and from the
    # midpoint: the host's arctangents (_seeing's own expressions, row by row), one call
    span = wedges.end - wedges.start
    ends = np.stack([wedges.start + f * span for f in samples]
                    + [0.5 * (wedges.start + wedges.end)])  # (S + 1, W, 3)
    d = points[:, None, None, :] - ends[None]  # (P, S + 1, W, 3)
    outside = _outside_every(wedges, d)
    far = np.linalg.norm(d[:, :S].reshape(-1, 3), axis=1).reshape(P, S, W) > (
        2 * EDGE_CLEARANCE_M)
    outside[:, :S] &= far
    outside[:, S] &= wedges.length > 2 * EDGE_CLEARANCE_M
    gate = np.zeros((P, W), np.uint8)
    for k in range(S + 1):
        gate |= outside[:, k].astype(np.uint8) << k
    tri_face = np.arange(len(caster.triangles)) if tri_face is None else np.asarray(tri_face)
    bits = device_edges.wedges_seen(caster, tri_face, wedges.start, wedges.end,
                                    wedges.direction, wedges.length, wedges.normal0,
                                    wedges.normal1, points, samples, gate, max_depth,
                                    EDGE_CLEARANCE_M, EDGE_LIFT_M)
    return [((b & device_edges.SAMPLED) != 0, (b & device_edges.SEEN) != 0) for b in bits]


def _seeing(caster, wedges: Wedges, point, samples=(0.25, 0.5, 0.75), tri_face=None,
            max_depth: int = SEEING_MAX_DEPTH, outlines: dict | None = None):
    """(seen at the samples, kept): :func:`wedges_seeing`'s mask and the part of it the
    sample sight lines alone decided, the numpy reference.  ``outlines``:
    :func:`_face_outlines`' cache, which callers with one ``tri_face`` may share between
    points."""
    W = len(wedges)
    seen = np.zeros(W, dtype=bool)
    if W == 0:
        return seen, seen
    p = np.asarray(point, dtype=np.float64)
    for f in samples:
        q = wedges.start + f * (wedges.end - wedges.start)
        d = p - q
        length = np.linalg.norm(d, axis=1)
        outside = _outside(wedges, np.arange(W), d)
        idx = np.flatnonzero(outside & (length > 2 * EDGE_CLEARANCE_M) & ~seen)
        if len(idx) == 0:
            continue
        clear = EDGE_CLEARANCE_M / length[idx]
        origin = q[idx] + EDGE_LIFT_M * lift_direction(wedges, idx, d[idx])
        rays = make_rays(origin, p - origin, tmin=clear, tmax=1.0 - clear)
        seen[idx[~caster.occluded(rays)]] = True
    # the rest, piece by piece; whether the point lies outside the wedge is the same for
    # every point of a straight edge
    mid = 0.5 * (wedges.start + wedges.end)
    sampled = seen.copy()
    todo = np.flatnonzero(~seen & _outside(wedges, np.arange(W), p - mid)
                          & (wedges.length > 2 * EDGE_CLEARANCE_M))
    if len(todo) == 0:
        return sampled, seen
    tri_face = np.arange(len(caster.triangles)) if tri_face is None else np.asarray(tri_face)
    c = EDGE_CLEARANCE_M
    length = wedges.length[todo]
    knots = np.sort(np.clip(np.stack([np.full(len(todo), c), 0.25 * length, 0.5 * length,
                                      0.75 * length, length - c], axis=1),
                            c, (length - c)[:, None]), axis=1)
    prim_k = _first_blocker(caster, wedges, np.repeat(todo, 5), knots.ravel(), p)
    seen[todo[np.any(prim_k.reshape(-1, 5) < 0, axis=1)]] = True
    # pieces between consecutive knots: wedge, ends (m along it), first blocker at each end
    w_p = np.repeat(todo, 4)
    s0, s1 = knots[:, :-1].ravel(), knots[:, 1:].ravel()
    b0 = prim_k.reshape(-1, 5)[:, :-1].ravel()
    b1 = prim_k.reshape(-1, 5)[:, 1:].ravel()
    outlines = {} if outlines is None else outlines
    for depth in range(max_depth + 1):
        keep = ~seen[w_p] & (s1 > s0)
        # the face first met at either end may hide the whole piece (a car in front of a
        # wall at one end, the wall alone behind it)
        for b, at_end in ((b0, False), (b1, True)):
            sel = np.flatnonzero(keep)
            keep[sel[_face_covers(caster.triangles, tri_face, wedges, w_p[sel], s0[sel],
                                  s1[sel], b[sel], at_end, p, outlines)]] = False
        w_p, s0, s1, b0, b1 = w_p[keep], s0[keep], s1[keep], b0[keep], b1[keep]
        if len(w_p) == 0:
            return sampled, seen
        if depth == max_depth:
            break
        sm = 0.5 * (s0 + s1)
        bm = _first_blocker(caster, wedges, w_p, sm, p)
        seen[w_p[bm < 0]] = True
        w_p = np.concatenate([w_p, w_p])
        s0, s1 = np.concatenate([s0, sm]), np.concatenate([sm, s1])
        b0, b1 = np.concatenate([b0, bm]), np.concatenate([bm, b1])
    # pieces neither seen nor proven hidden: keep their wedges (over-accept)
    seen[w_p] = True
    return sampled, seen


def _edge_origins(wedges: Wedges, w, s, p):
    """(origins, lengths): the points s metres along wedges w, lifted off them by
    EDGE_LIFT_M as the sight lines to p leave them, and their distances to p."""
    q = wedges.start[w] + s[:, None] * wedges.direction[w]
    d = p - q
    return q + EDGE_LIFT_M * lift_direction(wedges, w, d), np.linalg.norm(d, axis=1)


def _first_blocker(caster, wedges: Wedges, w, s, p) -> np.ndarray:
    """(S,) the triangle first met on the sight line from s metres along wedges w to p
    (as wedges_seeing casts them), -1 where nothing blocks it."""
    origin, length = _edge_origins(wedges, w, s, p)
    clear = EDGE_CLEARANCE_M / np.maximum(length, 1e-12)
    return caster.closest_hit(make_rays(origin, p - origin, tmin=clear,
                                        tmax=1.0 - clear))["prim"]


def _face_outlines(triangles, tri_face, cache: dict):
    """(edges (E, 2, 3), first (F + 1,)): the edges of every planar face that no other of
    its triangles shares (vertex for vertex), i.e. the faces' outlines, grouped by face:
    those of face f are edges[first[f]:first[f + 1]].  Kept in ``cache``."""
    if "edges" not in cache:
        e = np.stack([triangles, np.roll(triangles, -1, axis=1)], axis=2).reshape(-1, 2, 3)
        face = np.repeat(tri_face, 3)
        a, b = e[:, 0], e[:, 1]
        first = _lex_less(a, b)
        rows = np.concatenate([face[:, None].astype(np.float64),
                               np.where(first[:, None], a, b), np.where(first[:, None], b, a)],
                              axis=1)
        rim = np.flatnonzero(row_counts(rows) == 1)
        rim = rim[np.argsort(face[rim], kind="stable")]
        n_faces = int(tri_face.max()) + 1 if len(tri_face) else 0
        cache["edges"] = e[rim]
        cache["first"] = np.searchsorted(face[rim], np.arange(n_faces + 1))
    return cache["edges"], cache["first"]


def _lex_less(a, b) -> np.ndarray:
    """(N,) rows of a lexicographically before rows of b ((N, 3) each)."""
    out = np.zeros(len(a), dtype=bool)
    decided = np.zeros(len(a), dtype=bool)
    for k in range(3):
        less, more = a[:, k] < b[:, k], a[:, k] > b[:, k]
        out |= ~decided & less
        decided |= less | more
    return out


def _face_covers(triangles, tri_face, wedges: Wedges, w, s0, s1, blocker, at_end: bool, p,
                 outlines: dict) -> np.ndarray:
    """(P,) bool: the planar face of triangle ``blocker`` (the first thing met on the
    sight line from the piece's start, or its end where ``at_end``) blocks every sight
    line from the piece [s0, s1] (metres along wedge w, lifted as wedges_seeing lifts it)
    to p; in float64, with margins, so it says True only where the confirming casts would
    block them too.

    The sight lines fill the triangle p - piece.  The face's plane must separate p from
    the whole piece (the plane distance is linear along it: its ends decide), at least
    2 EDGE_CLEARANCE_M from the edge (the casts ignore blockers next to it).  The lines
    then cross the plane along the segment x0 x1, the piece projected from p: it lies in
    the face when both ends lie in the blocker (a triangle is convex), or when the end
    whose line met the blocker lies in the face and x0 x1 comes no closer than the margin
    to the face's outline (its rim edges).  The margin, 1e-5 m (merge_coplanar joins
    planes that close) + 1e-6 (1 + |x|) (float32 resolution), keeps the proof on the safe
    side."""
    out = np.zeros(len(w), dtype=bool)
    idx = np.flatnonzero(blocker >= 0)  # a clear end has no blocker to test
    if len(idx) == 0:
        return out
    w, s0, s1, blocker = w[idx], s0[idx], s1[idx], blocker[idx]
    o0, _ = _edge_origins(wedges, w, s0, p)
    o1, _ = _edge_origins(wedges, w, s1, p)
    v = triangles[blocker]
    n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    dp = np.einsum("ij,ij->i", n, p - v[:, 0])
    d0 = np.einsum("ij,ij->i", n, o0 - v[:, 0])
    d1 = np.einsum("ij,ij->i", n, o1 - v[:, 0])
    margin = 1e-5 + 1e-6 * (1.0 + np.abs(p).max())
    ok = (d0 * dp < 0) & (d1 * dp < 0) & (np.abs(dp) > margin)
    ok &= (np.abs(d0) > 2 * EDGE_CLEARANCE_M) & (np.abs(d1) > 2 * EDGE_CLEARANCE_M)
    sel = np.flatnonzero(ok)
    if len(sel) == 0:
        return out
    idx, blocker = idx[sel], blocker[sel]
    x0 = o0[sel] + (d0[sel] / (d0[sel] - dp[sel]))[:, None] * (p - o0[sel])
    x1 = o1[sel] + (d1[sel] / (d1[sel] - dp[sel]))[:, None] * (p - o1[sel])
    tol = margin + 1e-6 * np.maximum(np.abs(x0).max(axis=1), np.abs(x1).max(axis=1))
    # both ends well inside the blocker: the segment is in it
    tri = triangles[blocker]
    one = np.all(edge_distances(x0, tri) > tol[:, None], axis=1) & np.all(
        edge_distances(x1, tri) > tol[:, None], axis=1)
    out[idx[one]] = True
    # otherwise across seams: the blocker's end in the face, the segment clear of its outline
    rest = np.flatnonzero(~one)
    if len(rest) == 0:
        return out
    faces = tri_face[blocker[rest]]
    anchor = (x1 if at_end else x0)[rest]
    inside = containing_triangles(anchor, faces, blocker[rest], triangles, tri_face) >= 0
    rest, faces = rest[inside], faces[inside]
    edges, first = _face_outlines(triangles, tri_face, outlines)
    count = first[faces + 1] - first[faces]
    pair = np.repeat(np.arange(len(rest)), count)
    e = first[faces][pair] + np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
    gap = np.full(len(rest), np.inf)
    np.minimum.at(gap, pair, _segment_distances(x0[rest][pair], x1[rest][pair], edges[e, 0],
                                                edges[e, 1]))
    out[idx[rest[gap > tol[rest]]]] = True
    return out


def _segment_distances(a, b, c, d) -> np.ndarray:
    """(N,) distances (m) between the segments a[i] b[i] and c[i] d[i] in 3-D (closest
    points by clamping, Ericson, Real-Time Collision Detection 5.1.9)."""
    u, v, w0 = b - a, d - c, a - c
    uu = np.einsum("ij,ij->i", u, u)
    vv = np.einsum("ij,ij->i", v, v)
    uv = np.einsum("ij,ij->i", u, v)
    uw = np.einsum("ij,ij->i", u, w0)
    vw = np.einsum("ij,ij->i", v, w0)
    den = uu * vv - uv * uv
    with np.errstate(divide="ignore", invalid="ignore"):
        sc = np.clip(np.where(den > 0, (uv * vw - vv * uw) / den, 0.0), 0.0, 1.0)
        tc = np.clip(np.where(vv > 0, (uv * sc + vw) / vv, 0.0), 0.0, 1.0)
        sc = np.clip(np.where(uu > 0, (uv * tc - uw) / uu, 0.0), 0.0, 1.0)
    return np.linalg.norm(w0 + sc[:, None] * u - tc[:, None] * v, axis=1)


def _outside(wedges: Wedges, w, direction) -> np.ndarray:
    """Direction (from the edge) points into the exterior of wedge w (0 < phi < n pi)."""
    e = wedges.direction[w]
    n0 = wedges.normal0[w]
    t0 = np.cross(n0, e)
    phi = np.mod(np.arctan2(np.einsum("ci,ci->c", direction, n0),
                            np.einsum("ci,ci->c", direction, t0)), 2 * np.pi)
    limit = wedges.n[w] * np.pi
    phi, _ = _snap_to_faces(phi, limit)
    perp = direction - np.einsum("ci,ci->c", direction, e)[:, None] * e
    return (phi <= limit) & (np.linalg.norm(perp, axis=1) > 0)


def _outside_every(wedges: Wedges, direction) -> np.ndarray:
    """:func:`_outside` of every wedge at once: ``direction`` (..., W, 3) -> (..., W) bool,
    the same decisions bit for bit (the same float64 operations row by row, the wedge
    arrays broadcast instead of gathered; np.mod(a, 2 pi) of an arctangent a in
    [-pi, pi] is a + 2 pi below 0, else a (-0.0 as 0.0, which compares alike); a
    perpendicular part's norm is > 0 exactly when one of its squares is)."""
    e = wedges.direction
    n0 = wedges.normal0
    t0 = np.cross(n0, e)
    y = np.einsum("...ci,ci->...c", direction, n0)
    x = np.einsum("...ci,ci->...c", direction, t0)
    a = np.arctan2(y, x)
    phi = np.where(a < 0, a + 2 * np.pi, a)
    limit = wedges.n * np.pi
    phi, _ = _snap_to_faces(phi, limit)
    perp = direction - np.einsum("...ci,ci->...c", direction, e)[..., None] * e
    return (phi <= limit) & np.any(perp * perp > 0, axis=-1)


def _reaches(point, other_start, other_end, start, end) -> np.ndarray:
    """Keller points on edges (start, end) between ``point`` and the ends of the other
    edges reach into the finite edge for at least one end."""
    length = np.linalg.norm(end - start, axis=1)
    t0 = diffraction_point(point, other_start, start, end).t
    t1 = diffraction_point(point, other_end, start, end).t
    return (np.maximum(t0, t1) > 0.0) & (np.minimum(t0, t1) < length)


def wedge_pairs(caster, wedges: Wedges, first, second, max_hop_m: float, source=None,
                target=None) -> np.ndarray:
    """(P, 2) wedge pairs (i from ``first``, j from ``second``, i != j) whose midpoints
    lie within ``max_hop_m`` of each other and see each other from outside both
    wedges; with ``source`` (``target``) given, the first (second) edge must also be
    able to hold a Keller point between that point and the other edge."""
    first = np.asarray(first, np.int64)
    second = np.asarray(second, np.int64)
    empty = np.zeros((0, 2), np.int64)
    if len(first) == 0 or len(second) == 0:
        return empty
    mid = 0.5 * (wedges.start + wedges.end)
    near = cKDTree(mid[first]).sparse_distance_matrix(cKDTree(mid[second]), max_hop_m,
                                                      output_type="ndarray")
    I, J = first[near["i"]], second[near["j"]]
    d = mid[J] - mid[I]
    length = np.linalg.norm(d, axis=1)
    keep = (I != J) & (length > 4 * EDGE_CLEARANCE_M)
    keep &= _outside(wedges, I, d) & _outside(wedges, J, -d)
    if source is not None:
        keep &= _reaches(np.asarray(source, np.float64), wedges.start[J], wedges.end[J],
                         wedges.start[I], wedges.end[I])
    if target is not None:
        keep &= _reaches(np.asarray(target, np.float64), wedges.start[I], wedges.end[I],
                         wedges.start[J], wedges.end[J])
    I, J, d, length = I[keep], J[keep], d[keep], length[keep]
    if len(I) == 0:
        return empty
    clear = EDGE_CLEARANCE_M / length
    a = mid[I] + EDGE_LIFT_M * lift_direction(wedges, I, d)
    b = mid[J] + EDGE_LIFT_M * lift_direction(wedges, J, -d)
    free = ~caster.occluded(make_rays(a, b - a, tmin=clear, tmax=1.0 - clear))
    return np.stack([I[free], J[free]], axis=1)


@dataclass(frozen=True)
class DiffractionSettings:
    """UTD edge diffraction: how many edges per path and how far the candidate search goes."""

    #: UTD edge diffractions per path, 0 (off) to 3
    max_diffractions: int = 1
    #: faces turning less than this meet in no wedge (deg)
    wedge_angle_deg: float = 20.0
    #: most reflections in a path that also diffracts (prefix + suffix + between), taken
    #: from the rays' own face sequences on one side of the edges; the tracer never lets it
    #: exceed the specular search's max_reflections
    max_reflections: int = 0
    #: most distance between consecutive edges of a multi-diffraction chain (m)
    max_hop_m: float = 20.0
    #: cap on chains of 2-3 edges per link; beyond it the nearest chains are kept
    max_chains: int = 20_000
    #: UTD at the edges of objects that physical optics handles too: their facet integrals
    #: already carry the edge field (a plate's PO lobe is its edges' doing), so UTD there
    #: counts it twice - a 10 m plate at broadside returns 13 dB too much (docs/po.md)
    po_object_edges: bool = False

    def __post_init__(self):
        if not isinstance(self.po_object_edges, bool):
            raise ArgumentTypeError("must be True or False",
                                    argument="DiffractionSettings.po_object_edges",
                                    value=self.po_object_edges)
        check_number("DiffractionSettings", "max_diffractions", self.max_diffractions,
                     low=0, high=3, integer=True)
        check_number("DiffractionSettings", "wedge_angle_deg", self.wedge_angle_deg, low=0.0,
                     high=180.0, low_open=True)
        if self.wedge_angle_deg >= 180.0:
            raise ArgumentError("must lie in (0, 180)",
                                argument="DiffractionSettings.wedge_angle_deg",
                                value=self.wedge_angle_deg)
        check_number("DiffractionSettings", "max_reflections", self.max_reflections, low=0,
                     high=16, integer=True)
        check_number("DiffractionSettings", "max_hop_m", self.max_hop_m, low=0.0,
                     low_open=True)
        check_number("DiffractionSettings", "max_chains", self.max_chains, low=1, integer=True)


def _prefixes(sequences: dict, n: int) -> np.ndarray:
    if n == 0:
        return np.zeros((1, 0), np.int64)
    return np.asarray(sequences.get(n, np.zeros((0, n))), np.int64)


def _product(parts, chunk: int):
    """Rows of the Cartesian product of row sets, concatenated column-wise, in chunks."""
    sizes = [len(p) for p in parts]
    total = int(np.prod(sizes))
    for lo in range(0, total, chunk):
        flat = np.arange(lo, min(total, lo + chunk))
        cols = []
        for p, idx in zip(parts, np.unravel_index(flat, sizes), strict=True):
            cols.append(p[idx])
        yield np.concatenate(cols, axis=1)


def diffraction_candidates(caster, wedges: Wedges, tx_pos, rx_pos, tx_sequences: dict,
                           rx_sequences: dict, budget: DiffractionSettings, stats=None,
                           chunk: int = 1 << 19, tri_face=None, seeing: dict | None = None,
                           engine: str = "device", face_normal=None, face_offset=None):
    """Candidate :class:`Chains` of one link, yielded in chunks of at most ``chunk``.

    * one diffraction: [tx's ray-found face sequence of a reflections] + wedge, or
      wedge + [rx's ray-found face sequence of b reflections, reversed], a, b <=
      budget.max_reflections (reflections on one side of the edge); a wedge must see the
      end it meets directly;
    * two or three diffractions: chains of wedges where the first sees tx, the last
      sees rx and neighbours see each other within budget.max_hop_m, with at most one
      reflection before the first or after the last edge when the budget allows.

    With ``face_normal`` and ``face_offset`` (the planar faces' planes, as
    :func:`unfold_points` takes them) single-diffraction candidates are pre-tested by the
    image method (:func:`_keller_plausible_grid`, :func:`_angles_plausible`) and only
    those that may pass :func:`unfold_points` and :func:`diffraction_angles` are yielded,
    in the same order;
    ``stats["pretested"]`` counts the candidates tested, ``stats["candidates"]`` (by the
    caller) those yielded.  Without them every candidate of the product is yielded.

    ``stats`` (a dict) receives ``chains_over_cap``: chains the cap left out.
    ``tri_face``: the planar face of every triangle, for :func:`wedges_seeing`;
    ``seeing`` (a dict) keeps its masks per antenna position, and the planar faces'
    outlines, for the next links of a trace.  ``engine``: where :func:`wedges_seeing`
    runs ("device": one launch for the link's new antenna positions; "host": numpy).
    """
    stats = {} if stats is None else stats
    stats.setdefault("chains_over_cap", 0)
    if len(wedges) == 0 or budget.max_diffractions < 1:
        return
    seeing = {} if seeing is None else seeing

    def key(pos):
        return tuple(float(x) for x in np.asarray(pos, dtype=np.float64))

    # the antenna positions not yet asked, in one batch
    new = list(dict.fromkeys(k for k in (key(tx_pos), key(rx_pos)) if k not in seeing))
    if new:
        for k, masks in zip(new, _seeing_many(caster, wedges, new, tri_face=tri_face,
                                              outlines=seeing.setdefault("face outlines", {}),
                                              engine=engine), strict=True):
            seeing[k] = masks
    (sampled_tx, seen_tx), (sampled_rx, seen_rx) = seeing[key(tx_pos)], seeing[key(rx_pos)]
    sides = [(0, 0)] + [(a, 0) for a in range(1, budget.max_reflections + 1)] + [
        (0, b) for b in range(1, budget.max_reflections + 1)]
    for a, b in sides:
        mask = np.ones(len(wedges), bool)
        if a == 0:
            mask &= seen_tx
        if b == 0:
            mask &= seen_rx
        pre = _prefixes(tx_sequences, a)
        suf = _prefixes(rx_sequences, b)[:, ::-1]
        ws = np.flatnonzero(mask)[:, None]
        pattern = (REFLECTION,) * a + (DIFFRACTION,) + (REFLECTION,) * b
        if not (len(pre) and len(suf) and len(ws)):
            continue
        if face_normal is None:
            for elem in _product([pre, ws, suf], chunk):
                yield Chains(pattern, elem)
            continue
        stats["pretested"] = stats.get("pretested", 0) + len(pre) * len(ws) * len(suf)
        for elem in _plausible_product(wedges, pre, ws[:, 0], suf, tx_pos, rx_pos,
                                       face_normal, face_offset, chunk):
            yield Chains(pattern, elem)
    if budget.max_diffractions < 2:
        return
    every = np.arange(len(wedges))
    near_rx = np.flatnonzero(seen_rx)
    # pairs of wedges seen at their sample points first, in the pair search's order, then
    # those with a wedge only the whole-edge test kept: where these add no path, the
    # paths keep the order they had when the samples alone decided
    old_tx, new_tx = np.flatnonzero(sampled_tx), np.flatnonzero(seen_tx & ~sampled_tx)
    old_rx, new_rx = np.flatnonzero(sampled_rx), np.flatnonzero(seen_rx & ~sampled_rx)
    hop = budget.max_hop_m
    for nd in range(2, budget.max_diffractions + 1):
        if nd == 2:
            chain = np.concatenate([
                wedge_pairs(caster, wedges, old_tx, old_rx, hop, tx_pos, rx_pos),
                wedge_pairs(caster, wedges, new_tx, near_rx, hop, tx_pos, rx_pos),
                wedge_pairs(caster, wedges, old_tx, new_rx, hop, tx_pos, rx_pos)])
        else:
            chain = _chains_of(
                np.concatenate([wedge_pairs(caster, wedges, ends, every, hop, source=tx_pos)
                                for ends in (old_tx, new_tx)]),
                np.concatenate([wedge_pairs(caster, wedges, every, ends, hop, target=rx_pos)
                                for ends in (old_rx, new_rx)]))
        for a, b in sides:
            if a + b > 1:
                continue
            ok = np.ones(len(chain), bool)
            if a == 0:
                ok &= seen_tx[chain[:, 0]]
            if b == 0:
                ok &= seen_rx[chain[:, -1]]
            c = chain[ok]
            pre = _prefixes(tx_sequences, a)
            suf = _prefixes(rx_sequences, b)[:, ::-1]
            n_ends = len(pre) * len(suf)
            if len(c) * n_ends > budget.max_chains:
                # keep the shortest chains: the amplitude falls with every hop
                keep = budget.max_chains // max(n_ends, 1)
                stats["chains_over_cap"] += (len(c) - keep) * n_ends
                c = c[np.argsort(_chain_hop(wedges, c), kind="stable")[:keep]]
            if len(c) == 0 or n_ends == 0:
                continue
            pattern = (REFLECTION,) * a + (DIFFRACTION,) * nd + (REFLECTION,) * b
            for elem in _product([pre, c, suf], chunk):
                yield Chains(pattern, elem)


def _images(point, normal, offset, seqs) -> np.ndarray:
    """(S, k + 1, 3): ``point`` and its mirror images through the first 1..k faces of each
    face sequence ``seqs`` (S, k)."""
    S, k = seqs.shape
    out = np.empty((S, k + 1, 3))
    out[:, 0] = np.asarray(point, dtype=np.float64)
    for i in range(k):
        n, d = normal[seqs[:, i]], offset[seqs[:, i]]
        cur = out[:, i]
        out[:, i + 1] = cur - 2.0 * (np.einsum("ij,ij->i", cur, n) - d)[:, None] * n
    return out


def _plausible_product(wedges: Wedges, pre, ws, suf, tx, rx, face_normal, face_offset,
                       chunk: int):
    """The rows (prefix, wedge, suffix) of the product of ``pre`` (P, a) face sequences,
    wedges ``ws`` (W,) and ``suf`` (S, b), in the product's order, that
    :func:`_keller_plausible_grid` and :func:`_angles_plausible` keep, yielded in chunks
    of about ``chunk`` rows.  Blocks of the many prefixes (or suffixes) are tested
    against every wedge at once."""
    tx_img = _images(tx, face_normal, face_offset, pre)  # through f1..fa
    rx_img = _images(rx, face_normal, face_offset, suf[:, ::-1])  # through gb..g1
    P, S = len(pre), len(suf)
    if P > 1 and S > 1:
        raise ArgumentError("reflections on both sides of one edge are not searched "
                            f"({P} prefixes, {S} suffixes)", argument="sequences",
                            value=(P, S))
    kept, n_kept = [], 0
    if S == 1:  # rows p-major: blocks of prefixes x every wedge
        blocks = [(np.arange(lo, min(P, lo + max(1, chunk // len(ws)))), slice(None))
                  for lo in range(0, P, max(1, chunk // len(ws)))]
    else:  # P == 1 here (a reflection on one side only): rows w-major, s-minor
        blocks = [(np.arange(lo, min(len(ws), lo + max(1, chunk // S))), None)
                  for lo in range(0, len(ws), max(1, chunk // S))]
    for rows, _ in blocks:
        if S == 1:
            good, t, sure = _keller_plausible_grid(wedges, ws[None, :],
                                                   tx_img[rows, -1][:, None],
                                                   rx_img[0, -1][None, None])
            i, j = np.nonzero(good)
            p, w, s = rows[i], ws[j], np.zeros(len(i), np.int64)
        else:
            good, t, sure = _keller_plausible_grid(wedges, ws[rows][:, None],
                                                   tx_img[0, -1][None, None],
                                                   rx_img[:, -1][None, :])
            i, j = np.nonzero(good)
            p, w, s = np.zeros(len(i), np.int64), ws[rows[i]], j
        sel = np.flatnonzero(_angles_plausible(wedges, w, p, s, t[i, j], sure[i, j], tx_img,
                                               pre, rx_img, suf, face_normal, face_offset))
        if len(sel):
            kept.append(np.concatenate([pre[p[sel]], w[sel, None], suf[s[sel]]], axis=1))
            n_kept += len(sel)
        if n_kept >= chunk:
            yield np.concatenate(kept)
            kept, n_kept = [], 0
    if n_kept:
        yield np.concatenate(kept)


def _keller_plausible_grid(wedges: Wedges, w, src, dst):
    """(good, t, sure): good is False only where :func:`unfold_points` must reject a
    single diffraction at wedge ``w`` between the images ``src`` and ``dst`` (arrays
    broadcast: w (...), src and dst (..., 3)) by more than the margin: a concave wedge,
    or Keller's point more than PLAUSIBLE_REL (1 + the images' largest coordinate) off
    the usable edge (an ill-conditioned point, ``sure`` False, is kept); t and sure are
    :func:`_keller_t`'s."""
    t, sure, margin = _keller_t(wedges, w, src, dst)
    length = wedges.length[w]
    off = (t < EDGE_CLEARANCE_M - margin) | (t > length - EDGE_CLEARANCE_M + margin)
    return (wedges.n[w] >= 1.0) & ~(off & sure), t, sure


def _keller_t(wedges: Wedges, w, src, dst):
    """(t, sure, margin): Keller's point (m along wedge w from its start) between src
    and dst, as :func:`clradcom.geometry.wedges.diffraction_point` places it; ``sure``
    where it is well conditioned (the images' distances from the edge line add up to
    more than ``margin``, PLAUSIBLE_REL (1 + their largest coordinate)).  Component by
    component: a (blocks x wedges) grid needs no (..., 3) temporaries."""
    a = [wedges.start[w, k] for k in range(3)]
    e = [wedges.direction[w, k] for k in range(3)]
    scale = 1.0 + np.maximum(np.abs(src).max(axis=-1), np.abs(dst).max(axis=-1))
    vs = [src[..., k] - a[k] for k in range(3)]
    vr = [dst[..., k] - a[k] for k in range(3)]
    ts = vs[0] * e[0] + vs[1] * e[1] + vs[2] * e[2]
    tr = vr[0] * e[0] + vr[1] * e[1] + vr[2] * e[2]
    ds = np.sqrt(sum((vs[k] - ts * e[k]) ** 2 for k in range(3)))
    dr = np.sqrt(sum((vr[k] - tr * e[k]) ** 2 for k in range(3)))
    den = ds + dr
    margin = PLAUSIBLE_REL * scale
    with np.errstate(invalid="ignore", divide="ignore"):
        t = (ts * dr + tr * ds) / den
    return t, np.isfinite(t) & (den > margin), margin


def _angles_plausible(wedges: Wedges, w, p, s, t, sure, tx_img, pre, rx_img, suf,
                      face_normal, face_offset) -> np.ndarray:
    """(C,) False only for single-diffraction candidates (wedge w, prefix p, suffix s,
    Keller point t metres along the edge where ``sure``) that :func:`unfold_points` or
    :func:`diffraction_angles` must reject (up to the PLAUSIBLE_* margins): a source or
    observer inside the wedge, or a reflection whose plane the image line does not cross
    between its neighbours.

    The image method in the real frame, equivalent to the unfolding: tx_img (P, a + 1,
    3) are tx and its images through the prefix faces ``pre`` (P, a) in order, rx_img
    (S, b + 1, 3) rx and its images through the suffix faces ``suf`` (S, b) from the last
    one back; the Keller point Q lies on the real edge between the two full images, the
    last reflection before Q on the line from Q to tx's full image, and so on back."""
    good = np.ones(len(w), bool)
    idx = np.flatnonzero(sure)  # an ill-conditioned point is kept
    w, p, s = w[idx], p[idx], s[idx]
    q = wedges.start[w] + t[idx, None] * wedges.direction[w]
    # a neighbour inside a convex wedge lies behind both faces (phi in (n pi, 2 pi)); the
    # margin, sin(PLAUSIBLE_RAD) |d|, is at least PLAUSIBLE_RAD of angle about the edge
    n0, n1 = wedges.normal0[w], wedges.normal1[w]
    inside = np.zeros(len(idx), bool)
    for end in (tx_img[p, -1], rx_img[s, -1]):
        d = end - q
        m = np.sin(PLAUSIBLE_RAD) * np.sqrt(np.einsum("ij,ij->i", d, d))
        inside |= (np.einsum("ij,ij->i", d, n0) < -m) & (np.einsum("ij,ij->i", d, n1) < -m)
    inside &= (wedges.n[w] > 1.0) & (wedges.n[w] < 2.0)
    good[idx[inside]] = False
    idx, q, p, s = idx[~inside], q[~inside], p[~inside], s[~inside]
    # the reflections, from Q back to each antenna
    for images, faces in ((tx_img[p], pre[p, ::-1]), (rx_img[s], suf[s])):
        cur = q
        k = faces.shape[1]
        for i in range(k):
            n, d = face_normal[faces[:, i]], face_offset[faces[:, i]]
            line = images[:, k - i] - cur
            with np.errstate(invalid="ignore", divide="ignore"):
                u = (d - np.einsum("ij,ij->i", n, cur)) / np.einsum("ij,ij->i", n, line)
            finite = np.isfinite(u)
            good[idx[finite & ((u < -PLAUSIBLE_REL) | (u > 1.0 + PLAUSIBLE_REL))]] = False
            cur = cur + np.where(finite, u, 0.5)[:, None] * line
    return good


def _chains_of(first_pairs: np.ndarray, last_pairs: np.ndarray) -> np.ndarray:
    """Three-wedge chains (i, j, k) with (i, j) in ``first_pairs`` and (j, k) in
    ``last_pairs``, i != k."""
    if len(first_pairs) == 0 or len(last_pairs) == 0:
        return np.zeros((0, 3), np.int64)
    by_first = last_pairs[np.argsort(last_pairs[:, 0], kind="stable")]
    starts = np.searchsorted(by_first[:, 0], first_pairs[:, 1], "left")
    stops = np.searchsorted(by_first[:, 0], first_pairs[:, 1], "right")
    counts = stops - starts
    rows = np.repeat(np.arange(len(first_pairs)), counts)
    offs = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    nxt = by_first[np.repeat(starts, counts) + offs, 1]
    chain = np.concatenate([first_pairs[rows], nxt[:, None]], axis=1)
    return chain[chain[:, 0] != chain[:, 2]]


def _chain_hop(wedges: Wedges, chain: np.ndarray) -> np.ndarray:
    mid = 0.5 * (wedges.start + wedges.end)
    hop = np.zeros(len(chain))
    for j in range(chain.shape[1] - 1):
        hop += np.linalg.norm(mid[chain[:, j + 1]] - mid[chain[:, j]], axis=1)
    return hop


def diffraction_link_paths(scene, faces, caster, wedges: Wedges, tx, rx, tx_sequences,
                           rx_sequences, budget: DiffractionSettings, keep_fn=None,
                           go_sequences: set | None = None, seeing: dict | None = None,
                           engine: str = "device", pretest: bool = True):
    """All confirmed diffraction paths of one link: (list of Paths per pattern, stats).

    ``pretest`` (default) lets only the single-diffraction candidates that the image
    method finds plausible reach the exact tests (:func:`diffraction_candidates`); False
    sends every candidate through them, the reference that gives the same paths
    (tests/test_flush_edges.py, tools/bench_paths.py).

    ``keep_fn(k_dep, k_arr)`` (optional) drops paths outside the antennas' patterns
    before their fields are computed.  ``go_sequences`` (optional) are the face
    sequences of the link's GO paths, whose decisions the UTD terms follow at their
    boundaries (:func:`chain_fields`).  ``seeing``: see :func:`diffraction_candidates`.
    """
    stats = {"candidates": 0, "paths": 0}
    out = []
    for ch in diffraction_candidates(caster, wedges, tx.position, rx.position, tx_sequences,
                                     rx_sequences, budget, stats, tri_face=faces.tri_face,
                                     seeing=seeing, engine=engine,
                                     face_normal=faces.normal if pretest else None,
                                     face_offset=faces.offset if pretest else None):
        stats["candidates"] += len(ch)
        pts, ok = unfold_points(ch, tx.position, rx.position, faces.normal, faces.offset,
                                wedges)
        sel = np.flatnonzero(ok)
        ch = Chains(ch.pattern, ch.elements[sel])
        pts = pts[sel]
        pp, p, b0, graze, ok = diffraction_angles(ch, pts, wedges)
        keep, tris = confirm_chains(caster, faces.tri_face, faces.normal, ch, pts, ok, wedges,
                                    engine=engine)
        if keep_fn is not None and keep.any():
            k_dep = pts[:, 1] - pts[:, 0]
            k_arr = pts[:, -1] - pts[:, -2]
            k_dep /= np.linalg.norm(k_dep, axis=1, keepdims=True)
            k_arr /= np.linalg.norm(k_arr, axis=1, keepdims=True)
            keep &= keep_fn(k_dep, k_arr)
        sel = np.flatnonzero(keep)
        if len(sel) == 0:
            continue
        ch = Chains(ch.pattern, ch.elements[sel])
        out.append(chain_fields(scene, faces, wedges, ch, pts[sel], tris[sel],
                                (pp[sel], p[sel], b0[sel], graze[sel]), tx, rx, go_sequences))
        stats["paths"] += len(sel)
    return out, stats


# ---------------------------------------------------------------------------
# the mechanism: wedges once per scene, paths of a link


def prepare(geom: Geometry, settings: DiffractionSettings,
            po_objects=()) -> Wedges | None:
    """The scene's wedges (edges between faces turning by more than wedge_angle_deg); one
    set serves every transmitter. None when diffraction is off or nothing can diffract.
    Creases of two-sided objects (open sheets) diffract seen from either side.
    Wedges of ``po_objects`` (those physical optics handles) are left out unless
    ``settings.po_object_edges``."""
    if not settings.max_diffractions or not len(geom.scene.triangles):
        return None
    scene = geom.scene
    # the geometry's triangles, objects and materials are the memo's (kept_geometry);
    # the rest the wedges depend on is the key
    key = ("wedges", float(settings.wedge_angle_deg), bool(settings.po_object_edges),
           tuple(sorted(int(i) for i in po_objects)), scene.tri_two_sided.tobytes())
    if key not in geom.memo:
        wedges = _scene_wedges(scene, settings, po_objects)
        for value in vars(wedges).values():
            if isinstance(value, np.ndarray):
                value.flags.writeable = False  # shared by the next traces
        geom.memo[key] = wedges
    return geom.memo[key]


def _scene_wedges(scene, settings: DiffractionSettings, po_objects) -> Wedges:
    """:func:`prepare`'s wedges, computed."""
    wedges = extract_wedges(scene.triangles, scene.tri_object, scene.tri_material,
                            settings.wedge_angle_deg, two_sided=scene.tri_two_sided)
    if len(po_objects) and not settings.po_object_edges:
        wedges = wedges.select(~np.isin(wedges.object_id, np.asarray(po_objects)))
    # an edge whose face lies on another object (a box's floor edge on the road) is no
    # wedge in free space: cut to where it stands free, for the host and device alike
    return free_wedges(wedges, scene.triangles, scene.tri_object)


def link_paths(geom: Geometry, wedges: Wedges, tx: Radar, rx: Radar,
               settings: DiffractionSettings, tx_sequences=None, rx_sequences=None,
               stats: dict | None = None, go_paths: Paths | None = None,
               seeing: dict | None = None) -> Paths:
    """UTD diffraction paths of one link, up to settings.max_diffractions edges mixed with
    reflections from the rays' face sequences of tx and rx (``stats`` adds up counts).

    ``go_paths``: the link's GO paths (line of sight and reflections, as the specular
    mechanism found them): at a shadow or reflection boundary the UTD term follows their
    decision, so the GO + UTD total is continuous (docs/stability.md).  ``seeing`` (a
    dict kept over the links of a trace) holds the wedges each antenna may see."""
    go = None if go_paths is None else go_face_sequences(go_paths, geom.faces.tri_face)
    parts, counts = diffraction_link_paths(
        geom.scene, geom.faces, geom.caster, wedges, tx, rx, tx_sequences or {},
        rx_sequences or {}, settings, keep_fn=lambda d, a: seen_by_antennas(tx, rx, d, a),
        go_sequences=go, seeing=seeing, engine=geom.engine)
    if stats is not None:
        for key, value in counts.items():
            stats[key] = stats.get(key, 0) + value
    if len(parts) == 1:
        return parts[0]
    return concat_paths(parts) if parts else Paths.empty(1)
