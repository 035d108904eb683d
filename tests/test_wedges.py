"""Wedge extraction and diffraction points (clradcom.geometry.wedges, docs/wedges.md)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from clradcom.geometry.wedges import (
    diffraction_point,
    extract_wedges,
    multi_diffraction_points,
    weld_vertices,
)
from clradcom.scene.models import car_mesh


def _soup(mesh: trimesh.Trimesh) -> np.ndarray:
    return np.asarray(mesh.vertices[mesh.faces], dtype=np.float64)


def _wedges(tri, threshold=20.0, obj=None, **kw):
    obj = np.zeros(len(tri), dtype=np.int32) if obj is None else obj
    return extract_wedges(tri, obj, np.zeros(len(tri), dtype=np.int32), threshold, **kw)


def _grid_plane(nx, ny, sx=3.0, sy=2.0):
    xs, ys = np.linspace(0, sx, nx + 1), np.linspace(0, sy, ny + 1)
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    p = np.stack([gx, gy, np.zeros_like(gx)], axis=-1)
    q = np.stack([p[:-1, :-1], p[1:, :-1], p[1:, 1:], p[:-1, 1:]], axis=2).reshape(-1, 4, 3)
    return np.concatenate([q[:, [0, 1, 2]], q[:, [0, 2, 3]]])


def _l_prism():
    """Closed L-shaped prism (outward winding): 18 creases, the inner vertical one concave."""
    poly = np.array([[0, 0], [2, 0], [2, 1], [1, 1], [1, 2], [0, 2]], dtype=float)
    bot = np.column_stack([poly, np.zeros(6)])
    top = np.column_stack([poly, np.ones(6)])
    fan = [(3, 4, 5), (3, 5, 0), (3, 0, 1), (3, 1, 2)]
    tris = [top[list(f)] for f in fan] + [bot[list(f[::-1])] for f in fan]
    for i in range(6):
        j = (i + 1) % 6
        tris += [np.array([bot[i], bot[j], top[j]]), np.array([bot[i], top[j], top[i]])]
    return np.array(tris)


def _check_kp_frame(w, tri):
    """KP frame: n0 = e x t0, t0 rotated by n*pi about e is face n's direction, n1 = tn x e."""
    e, t0 = w.direction, w.tangent0
    np.testing.assert_allclose(np.linalg.norm(e, axis=1), 1.0, atol=1e-14)
    np.testing.assert_allclose(np.cross(e, t0), w.normal0, atol=1e-12)
    np.testing.assert_allclose(np.einsum("ij,ij->i", w.end - w.start, e), w.length, atol=1e-12)
    ang = w.n * np.pi
    b = np.cross(e, t0)
    tn = np.cos(ang)[:, None] * t0 + np.sin(ang)[:, None] * b  # Rodrigues, t0 perp e
    np.testing.assert_allclose(np.cross(tn, e), w.normal1, atol=1e-12)
    # tn points from the edge into face n's triangle
    crease = w.tri1 >= 0
    c = tri[w.tri1[crease]].mean(axis=1) - w.start[crease]
    assert np.all(np.einsum("ij,ij->i", c, tn[crease]) > 0)
    c0 = tri[w.tri0].mean(axis=1) - w.start
    assert np.all(np.einsum("ij,ij->i", c0, t0) > 0)


def test_cube_has_12_right_angle_wedges():
    tri = _soup(trimesh.creation.box(extents=[1.0, 1.0, 1.0]))
    w = _wedges(tri)
    assert len(w) == 12
    np.testing.assert_allclose(w.n, 1.5, atol=1e-14)
    np.testing.assert_allclose(w.length, 1.0, atol=1e-14)
    assert not w.half_plane.any() and np.all(w.tri1 >= 0)
    # outward axis normals, orthogonal; the edge lies on both face planes
    for nrm in (w.normal0, w.normal1):
        assert np.allclose(np.sort(np.abs(nrm), axis=1), [0, 0, 1])
    np.testing.assert_allclose(np.einsum("ij,ij->i", w.normal0, w.normal1), 0.0, atol=1e-14)
    mid = 0.5 * (w.start + w.end)
    np.testing.assert_allclose(np.einsum("ij,ij->i", mid, w.normal0), 0.5, atol=1e-14)
    np.testing.assert_allclose(np.einsum("ij,ij->i", mid, w.normal1), 0.5, atol=1e-14)
    # convex: e = n0 x n1 (KP), and face 0 is the lower triangle
    np.testing.assert_allclose(np.cross(w.normal0, w.normal1), w.direction, atol=1e-14)
    assert np.all(w.tri0 < w.tri1)
    assert {w.stats[k] for k in ("degenerate", "inconsistent", "nonmanifold")} == {0}
    _check_kp_frame(w, tri)
    # every undirected cube edge exactly once
    keys = {tuple(sorted([tuple(np.round(a, 9)), tuple(np.round(b, 9))]))
            for a, b in zip(w.start, w.end, strict=True)}
    assert len(keys) == 12


def test_tessellated_cube_merges_collinear_segments():
    mesh = trimesh.creation.box(extents=[2.0, 1.0, 1.0]).subdivide().subdivide()
    tri = _soup(mesh)
    w = _wedges(tri)
    assert len(w) == 12
    assert np.all(w.n_segments == 4)
    np.testing.assert_allclose(np.sort(w.length), [1.0] * 8 + [2.0] * 4, atol=1e-14)
    segs = _wedges(tri, merge_collinear=False)
    assert len(segs) == 48 and np.all(segs.n_segments == 1)
    np.testing.assert_allclose(segs.length.sum(), w.length.sum(), atol=1e-12)
    _check_kp_frame(w, tri)
    _check_kp_frame(segs, tri)


def test_tessellated_plane_has_only_its_rim():
    tri = _grid_plane(6, 4)
    w = _wedges(tri)
    assert w.stats["crease_segments"] == 0
    assert w.stats["boundary_edges"] == 2 * (6 + 4)
    assert len(w) == 4 and np.all(w.half_plane)
    np.testing.assert_allclose(w.n, 2.0)
    np.testing.assert_allclose(np.sort(w.length), [2.0, 2.0, 3.0, 3.0], atol=1e-14)
    np.testing.assert_array_equal(np.sort(w.n_segments), [4, 4, 6, 6])
    assert np.all(w.tri1 == -1)
    np.testing.assert_allclose(w.normal1, -w.normal0)
    np.testing.assert_allclose(np.abs(w.normal0[:, 2]), 1.0)
    _check_kp_frame(w, tri)
    segs = _wedges(tri, merge_collinear=False)
    assert len(segs) == 20 and np.all(segs.half_plane)
    assert len(_wedges(tri, include_half_planes=False)) == 0


def test_icosphere_smooth_at_20_all_edges_at_5():
    tri = _soup(trimesh.creation.icosphere(subdivisions=2))
    assert len(_wedges(tri, 20.0)) == 0
    all_edges = _wedges(tri, 5.0)
    assert len(all_edges) == 3 * len(tri) // 2
    assert np.all((all_edges.n > 1.0) & (all_edges.n < 1.2))
    assert not all_edges.half_plane.any()
    _check_kp_frame(all_edges, tri)


def test_car_counts_shrink_with_threshold():
    tri = _soup(car_mesh())
    counts = {}
    for thr in (0.0, 10.0, 20.0, 30.0, 60.0):
        w = _wedges(tri, thr)
        counts[thr] = len(w)
        assert w.stats["nonmanifold"] == 0 and w.stats["inconsistent"] == 0
        assert not w.half_plane.any()  # closed parts
        assert np.all((w.n > 1.0 + thr / 180.0) & (w.n <= 1.5 + 1e-12))
        # the four wheels' rims (2 x 12 right-angle edges each) survive every threshold
        assert np.count_nonzero(np.isclose(w.n, 1.5)) >= 96
    seq = [counts[t] for t in (0.0, 10.0, 20.0, 30.0, 60.0)]
    assert all(a > b for a, b in zip(seq, seq[1:], strict=False)), counts
    # docs/wedges.md quotes these (car_mesh() as of this commit)
    assert (counts[10.0], counts[20.0], counts[30.0]) == (412, 328, 200), counts


def test_l_prism_has_one_concave_edge():
    tri = _l_prism()
    mesh = trimesh.Trimesh(tri.reshape(-1, 3), np.arange(3 * len(tri)).reshape(-1, 3))
    assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume == pytest.approx(3)
    w = _wedges(tri)
    assert len(w) == 18
    concave = w.n < 1
    assert np.count_nonzero(concave) == 1
    np.testing.assert_allclose(w.n[concave], 0.5, atol=1e-14)
    np.testing.assert_allclose(w.n[~concave], 1.5, atol=1e-14)
    k = np.flatnonzero(concave)[0]
    np.testing.assert_allclose(w.start[k][:2], [1, 1])
    np.testing.assert_allclose(w.end[k][:2], [1, 1])
    _check_kp_frame(w, tri)


def test_duplicate_vertices_are_welded():
    tri = _soup(trimesh.creation.box(extents=[1.0, 1.0, 1.0]))
    rng = np.random.default_rng(3)
    jittered = tri + rng.uniform(-1e-8, 1e-8, size=tri.shape)  # every copy its own position
    w = _wedges(jittered)
    assert len(w) == 12 and not w.half_plane.any()
    np.testing.assert_allclose(w.n, 1.5, atol=1e-7)
    # without welding the jittered copies no edge is shared: 36 rims, no creases
    raw = _wedges(jittered, weld_tol=0.0)
    assert raw.stats["crease_segments"] == 0 and raw.stats["boundary_edges"] == 36
    ids = weld_vertices(jittered.reshape(-1, 3), 1e-6)
    assert len(np.unique(ids)) == 8


def test_objects_are_separate_and_nonmanifold_edges_skipped():
    plate = np.array([[[0, 0, 0], [1, 0, 0], [1, 1, 0]], [[0, 0, 0], [1, 1, 0], [0, 1, 0]]],
                     dtype=float)
    two = np.concatenate([plate, plate + [1.0, 0, 0]])
    same = _wedges(two, obj=np.zeros(4, dtype=np.int32))
    assert len(same) == 4 and same.stats["boundary_edges"] == 6  # the seam x=1 is coplanar
    split = _wedges(two, obj=np.array([0, 0, 1, 1], dtype=np.int32))
    assert len(split) == 8 and set(split.object_id) == {0, 1}
    fin = np.concatenate([plate[:1], [[[0, 0, 0], [1, 1, 0], [0.5, 0.5, 1.0]]],
                          [[[0, 0, 0], [1, 1, 0], [0.5, 0.5, -1.0]]]])
    w = _wedges(fin)
    assert w.stats["nonmanifold"] == 1
    assert np.all(w.half_plane) and len(w) == 6  # only the rims; the shared diagonal skipped


def test_inconsistent_winding_is_counted_and_repaired():
    tri = _soup(trimesh.creation.box(extents=[1.0, 1.0, 1.0]))
    flipped = tri.copy()
    flipped[-1] = flipped[-1][::-1]  # the last triangle is never face 0 of an edge it shares
    w = _wedges(flipped)
    assert w.stats["inconsistent"] == 3
    assert len(w) == 12
    np.testing.assert_allclose(w.n, 1.5, atol=1e-14)
    # face 0's winding is trusted: flipping triangle 0 turns its two creases concave
    flipped = tri.copy()
    flipped[0] = flipped[0][::-1]
    w = _wedges(flipped)
    assert w.stats["inconsistent"] == 3 and len(w) == 12
    assert np.count_nonzero(np.isclose(w.n, 0.5)) == 2


# ---------------------------------------------------------------------------
# diffraction points


def _brute_t(S, R, A, B):
    """Minimise |S-Q|+|Q-T| on the line by nested grid refinement."""
    e = (B - A) / np.linalg.norm(B - A)
    lo, hi = -30.0, 30.0
    for _ in range(12):
        t = np.linspace(lo, hi, 201)
        Q = A + t[:, None] * e
        f = np.linalg.norm(Q - S, axis=1) + np.linalg.norm(R - Q, axis=1)
        i = int(np.argmin(f))
        step = t[1] - t[0]
        lo, hi = t[i] - 2 * step, t[i] + 2 * step
    return t[i], f[i]


def test_keller_point_equal_angles_and_minimum():
    rng = np.random.default_rng(7)
    S, R = rng.normal(size=(500, 3)) * 4, rng.normal(size=(500, 3)) * 4
    A = rng.normal(size=(500, 3))
    B = A + rng.normal(size=(500, 3))
    d = diffraction_point(S, R, A, B)
    e = (B - A) / np.linalg.norm(B - A, axis=1)[:, None]
    cos_in = np.einsum("ij,ij->i", d.point - S, e) / np.linalg.norm(d.point - S, axis=1)
    cos_out = np.einsum("ij,ij->i", R - d.point, e) / np.linalg.norm(R - d.point, axis=1)
    np.testing.assert_allclose(cos_in, cos_out, rtol=0, atol=1e-12)
    # the point lies on the line
    np.testing.assert_allclose(np.linalg.norm(np.cross(d.point - A, e), axis=1), 0, atol=1e-12)
    for k in range(20):
        tb, fb = _brute_t(S[k], R[k], A[k], B[k])
        assert abs(d.t[k] - tb) < 1e-7 * (1 + abs(tb))
        assert d.length[k] <= fb + 1e-12
        assert abs(d.length[k] - fb) < 1e-12 * fb
    L = np.linalg.norm(B - A, axis=1)
    np.testing.assert_array_equal(d.inside, (d.t >= 0) & (d.t <= L))
    assert 0 < np.count_nonzero(d.inside) < len(d.inside)


def test_keller_point_on_and_off_the_finite_edge():
    A, B = np.array([0.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0])
    # symmetric: Q is the foot of the common perpendicular height
    d = diffraction_point([1.0, 0.0, 0.3], [-2.0, 0.5, 0.3], A, B)
    np.testing.assert_allclose(d.point, [0, 0, 0.3], atol=1e-15)
    assert d.inside
    # source and target both far above the edge top: Q beyond `end`
    d = diffraction_point([1.0, 0.0, 3.0], [0.0, 2.0, 5.0], A, B)
    np.testing.assert_allclose(d.t, (3.0 * 2.0 + 5.0 * 1.0) / 3.0)
    assert not d.inside
    assert diffraction_point([1.0, 0.0, 3.0], [0.0, 2.0, 5.0], A, B, tol=3.0).inside
    # broadcasting: one source, many targets, one edge
    tg = np.column_stack([np.full(5, -1.0), np.zeros(5), np.linspace(-1, 2, 5)])
    d = diffraction_point(np.array([1.0, 0.0, 0.5]), tg, A, B)
    assert d.point.shape == (5, 3)
    np.testing.assert_array_equal(d.inside, [False, True, True, True, False])


def _brute_chain(S, R, A, B):
    """Grid minimisation of the chain length over the N edge parameters (N <= 3)."""
    N = len(A)
    E = (B - A) / np.linalg.norm(B - A, axis=1)[:, None]
    centre = np.zeros(N)
    half = np.full(N, 20.0)
    pts = 41 if N == 2 else 17
    for _ in range(40 if N == 2 else 60):
        axes = [np.linspace(c - h, c + h, pts) for c, h in zip(centre, half, strict=True)]
        grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, N)
        P = A[None] + grid[..., None] * E[None]
        nodes = np.concatenate([np.broadcast_to(S, (len(grid), 1, 3)), P,
                                np.broadcast_to(R, (len(grid), 1, 3))], axis=1)
        f = np.linalg.norm(np.diff(nodes, axis=1), axis=-1).sum(axis=1)
        i = int(np.argmin(f))
        centre = grid[i]
        half = half * 0.6
    return centre, f[i]


@pytest.mark.parametrize("N", [2, 3])
def test_multi_edge_points_against_brute_force(N):
    rng = np.random.default_rng(11 + N)
    n_cases = 6
    S, R = rng.normal(size=(n_cases, 3)) * 4, rng.normal(size=(n_cases, 3)) * 4
    A = rng.normal(size=(n_cases, N, 3)) * 2
    B = A + rng.normal(size=(n_cases, N, 3))
    m = multi_diffraction_points(S, R, A, B)
    assert m.points.shape == (n_cases, N, 3) and m.converged.all()
    E = (B - A) / np.linalg.norm(B - A, axis=-1)[..., None]
    nodes = np.concatenate([S[:, None], m.points, R[:, None]], axis=1)
    seg = np.diff(nodes, axis=1)
    u = seg / np.linalg.norm(seg, axis=-1)[..., None]
    # generalised Keller: equal angles with each edge on both sides
    np.testing.assert_allclose(np.einsum("bki,bki->bk", E, u[:, :-1]),
                               np.einsum("bki,bki->bk", E, u[:, 1:]), atol=1e-12)
    for k in range(n_cases):
        tb, fb = _brute_chain(S[k], R[k], A[k], B[k])
        assert m.length[k] <= fb + 1e-12
        assert abs(m.length[k] - fb) < 1e-9 * fb
        np.testing.assert_allclose(m.t[k], tb, atol=1e-4)
    L = np.linalg.norm(B - A, axis=-1)
    np.testing.assert_array_equal(m.inside, (m.t >= 0) & (m.t <= L))
    np.testing.assert_array_equal(m.all_inside, m.inside.all(axis=1))


def test_multi_edge_single_edge_and_flags():
    rng = np.random.default_rng(5)
    S, R = rng.normal(size=(50, 3)) * 3, rng.normal(size=(50, 3)) * 3
    A = rng.normal(size=(50, 3))
    B = A + rng.normal(size=(50, 3))
    m = multi_diffraction_points(S, R, A[:, None], B[:, None])
    d = diffraction_point(S, R, A, B)
    np.testing.assert_allclose(m.t[:, 0], d.t, atol=1e-12)
    np.testing.assert_array_equal(m.inside[:, 0], d.inside)
    # two parallel vertical edges between source and target at their heights: all inside;
    # the same edges shifted up leave the points below their starts
    edges_a = np.array([[1.0, 0.2, 0.0], [2.0, -0.2, 0.0]])
    edges_b = edges_a + [0.0, 0.0, 2.0]
    src, tgt = np.array([0.0, 0.0, 1.0]), np.array([3.0, 0.0, 1.0])
    m = multi_diffraction_points(src, tgt, edges_a, edges_b)
    assert m.points.shape == (2, 3) and bool(m.all_inside) and bool(m.converged)
    np.testing.assert_allclose(m.points[:, 2], 1.0, atol=1e-12)
    m = multi_diffraction_points(src, tgt, edges_a + [0, 0, 1.5], edges_b + [0, 0, 1.5])
    assert not m.inside.any() and not m.all_inside
    np.testing.assert_allclose(m.t, -0.5, atol=1e-12)
