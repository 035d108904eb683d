"""Ray casting on the OpenCL device against a brute-force reference.

The reference tests every ray against every triangle in float64 (Moller-
Trumbore on the float32-rounded inputs the kernel sees) and classifies each
candidate hit by its distance (in metres) inside the triangle's outline: a
hit more than a few float32 ulps of the scene's coordinates inside must be
found, a miss by more than that must not be, and only the sliver in between
may go either way. A distance, not a barycentric margin, so needles are
judged fairly.
"""

import numpy as np
import pyopencl as cl
import pytest
import trimesh
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from clradcom.device.raycast import KERNEL_DEFINES, RayCaster, make_rays, spawn_origins
from clradcom.geometry import layout
from clradcom.geometry.bvh import BVH_NODE_DTYPE, Bvh, build_bvh, validate_bvh
from clradcom.geometry.layout import (
    BVH8_NODE_DTYPE,
    LEAF_GROUP_BITS,
    MAX_LEAF_GROUPS,
    bvh8_nodes,
    tri4_groups,
)
from clradcom.scene import load_scene

MARGIN_ULPS = 64  # float32 ulps of the coordinates where rounding may decide either way


def brute_force(origins, directions, triangles):
    """Every ray against every triangle: t and signed distance inside the outline, (R, T)."""
    o = np.asarray(origins, np.float32).astype(np.float64)
    d = np.asarray(directions, np.float32).astype(np.float64)
    tri = np.asarray(triangles, np.float32).astype(np.float64)
    v0, e1, e2 = tri[:, 0], tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    p = np.cross(d[:, None, :], e2[None])
    det = np.einsum("rtk,tk->rt", p, e1)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = o[:, None, :] - v0[None]
        u = np.einsum("rtk,rtk->rt", s, p) / det
        q = np.cross(s, e1[None])
        v = np.einsum("rk,rtk->rt", d, q) / det
        t = np.einsum("tk,rtk->rt", e2, q) / det
        # barycentric weight times the height over the opposite edge = distance to that edge
        area2 = np.linalg.norm(np.cross(e1, e2), axis=1)
        h0 = area2 / np.linalg.norm(tri[:, 2] - tri[:, 1], axis=1)
        h1 = area2 / np.linalg.norm(e2, axis=1)
        h2 = area2 / np.linalg.norm(e1, axis=1)
        inside = np.minimum(np.minimum(u * h1, v * h2), (1.0 - u - v) * h0)
    inside = np.where(np.isfinite(inside) & (det != 0), inside, -np.inf)
    t = np.where(np.isfinite(t), t, -np.inf)
    return t, inside


def point_triangle_distance(p, tri):
    """Euclidean distance from points (R,3) to triangles (R,3,3), in float64."""
    v0, v1, v2 = tri[:, 0], tri[:, 1], tri[:, 2]
    n = np.cross(v1 - v0, v2 - v0)
    nn = np.einsum("ij,ij->i", n, n)

    def segment(a, b):
        ab = b - a
        denom = np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-300)
        s = np.clip(np.einsum("ij,ij->i", p - a, ab) / denom, 0.0, 1.0)
        return np.linalg.norm(p - (a + s[:, None] * ab), axis=1)

    best = np.minimum(np.minimum(segment(v0, v1), segment(v1, v2)), segment(v2, v0))
    with np.errstate(divide="ignore", invalid="ignore"):
        h = np.einsum("ij,ij->i", p - v0, n) / nn
        q = p - h[:, None] * n
        w0 = np.einsum("ij,ij->i", np.cross(v1 - q, v2 - q), n)
        w1 = np.einsum("ij,ij->i", np.cross(v2 - q, v0 - q), n)
        w2 = np.einsum("ij,ij->i", np.cross(v0 - q, v1 - q), n)
    inside = (nn > 0) & (w0 >= 0) & (w1 >= 0) & (w2 >= 0)
    return np.where(inside, np.minimum(best, np.abs(h) * np.sqrt(nn)), best)


def check_against_reference(caster, origins, directions, tmin=1e-6):
    """Assert the kernel's closest hits agree with the brute force.

    A reported hit must lie on its triangle (point-to-triangle distance within
    float32 resolution) and no certain hit may lie closer; a miss is only
    allowed where the reference has no certain hit.
    """
    rays = make_rays(origins, directions, tmin=tmin)
    hits = caster.closest_hit(rays)
    t, inside = brute_force(origins, directions, caster.triangles)
    scale = 1.0 + np.abs(t)
    extent = 1.0 + np.abs(caster.triangles).max() + np.abs(origins).max()
    margin = MARGIN_ULPS * float(np.finfo(np.float32).eps) * extent
    sure = (inside > margin) & (t > tmin + 1e-5 * scale)
    maybe = (inside > -margin) & (t > tmin - 1e-5 * scale)
    t_sure = np.where(sure, t, np.inf).min(axis=1)
    hit = hits["prim"] >= 0
    missed = ~hit & np.isfinite(t_sure)
    assert not missed.any(), f"rays {np.flatnonzero(missed)[:5]} missed certain hits"
    idx = np.flatnonzero(hit)
    prim = hits["prim"][idx]
    assert maybe[idx, prim].all(), f"rays {idx[~maybe[idx, prim]][:5]} hit ruled-out triangles"
    o32 = np.asarray(origins, np.float32).astype(np.float64)[idx]
    d32 = np.asarray(directions, np.float32).astype(np.float64)[idx]
    points = o32 + hits["t"][idx, None].astype(np.float64) * d32
    tris32 = np.asarray(caster.triangles, np.float32).astype(np.float64)[prim]
    off = point_triangle_distance(points, tris32)
    # t from a float32 watertight test is ill-conditioned on needles (the edge
    # functions cancel to the needle's width), so their hit points may sit
    # further off; exact path geometry is recomputed in float64 on the host.
    longest = np.linalg.norm(tris32 - np.roll(tris32, 1, axis=1), axis=2).max(axis=1)
    area2 = np.linalg.norm(np.cross(tris32[:, 1] - tris32[:, 0], tris32[:, 2] - tris32[:, 0]),
                           axis=1)
    needle = longest**2 > 100.0 * area2
    allowed = np.where(needle, 1e-3, 1e-5) * extent
    assert (off < allowed).all(), f"hit points {off.max():.2e} m off their triangle"
    tol = 1e-4 * (1.0 + hits["t"][idx])
    assert (hits["t"][idx] <= t_sure[idx] + tol).all(), "a nearer certain hit was skipped"
    return hits


@pytest.fixture(scope="module")
def sphere():
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    return mesh


def test_random_soup_matches_brute_force(runtime):
    rng = np.random.default_rng(1)
    tris = rng.uniform(-1, 1, (1500, 3, 3)) * 0.15 + rng.uniform(-1, 1, (1500, 1, 3))
    caster = RayCaster(tris, runtime=runtime)
    origins = rng.uniform(-1.5, 1.5, (1200, 3))
    hits = check_against_reference(caster, origins, rng.normal(size=(1200, 3)))
    assert 0.1 < (hits["prim"] >= 0).mean() < 0.9  # the scene is neither empty nor solid


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    seed=st.integers(0, 2**31 - 1),
    n_tris=st.integers(1, 300),
    spread=st.floats(0.01, 2.0),
    offset=st.sampled_from([0.0, 100.0, 1000.0]),
)
def test_hypothesis_scenes_match_brute_force(runtime, seed, n_tris, spread, offset):
    rng = np.random.default_rng(seed)
    tris = rng.uniform(-1, 1, (n_tris, 3, 3)) * spread + rng.uniform(-1, 1, (n_tris, 1, 3))
    tris += offset
    caster = RayCaster(tris, runtime=runtime)
    origins = rng.uniform(-2, 2, (200, 3)) + offset
    targets = tris[rng.integers(0, n_tris, 200)].mean(axis=1) + rng.normal(0, 0.05, (200, 3))
    check_against_reference(caster, origins, targets - origins)


def test_rays_through_shared_edges_and_vertices_never_slip(runtime, sphere):
    """Rays from inside a closed mesh aimed exactly at its vertices and edges all hit."""
    verts = np.asarray(sphere.vertices, np.float32).astype(np.float64)
    tris = verts[sphere.faces]
    caster = RayCaster(tris, runtime=runtime)
    edges = sphere.edges_unique
    edge_points = 0.5 * (verts[edges[:, 0]] + verts[edges[:, 1]])
    for origin in ([0.0, 0.0, 0.0], [0.31, -0.2, 0.17], [-0.5, 0.4, -0.3]):
        for targets in (verts, edge_points):
            origins = np.broadcast_to(origin, targets.shape)
            hits = caster.closest_hit(make_rays(origins, targets - origins))
            assert (hits["prim"] >= 0).all(), f"{(hits['prim'] < 0).sum()} rays slipped through"
            np.testing.assert_allclose(hits["t"], 1.0, atol=1e-4)  # target is at t = 1


def test_rays_through_the_diagonal_of_a_quad_grid(runtime):
    """A flat grid of quads split on the diagonal: rays at the seams never pass."""
    n = 20
    xs = np.linspace(-1.0, 1.0, n + 1)
    gx, gy = np.meshgrid(xs, xs, indexing="ij")
    p = np.stack([gx, gy, np.zeros_like(gx)], axis=-1)
    quads = np.stack([p[:-1, :-1], p[1:, :-1], p[1:, 1:], p[:-1, 1:]], axis=2).reshape(-1, 4, 3)
    tris = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    caster = RayCaster(tris, runtime=runtime)
    rng = np.random.default_rng(7)
    f = rng.uniform(0, 1, (len(quads), 1))
    seam_points = quads[:, 0] + f * (quads[:, 2] - quads[:, 0])  # on the shared diagonal
    for origins in (np.array([[0.3, -0.2, 2.0]]), rng.uniform(-3, 3, (len(quads), 3))):
        origins = np.broadcast_to(origins, seam_points.shape).copy()
        origins[:, 2] = np.abs(origins[:, 2]) + 0.5
        hits = caster.closest_hit(make_rays(origins, seam_points - origins))
        assert (hits["prim"] >= 0).all()
        np.testing.assert_allclose(hits["t"], 1.0, atol=1e-5)


def test_grazing_rays_hit_on_the_surface(runtime):
    plane = np.array([[[-50, -50, 0], [50, -50, 0], [50, 50, 0]],
                      [[-50, -50, 0], [50, 50, 0], [-50, 50, 0]]], dtype=np.float64)
    caster = RayCaster(plane, runtime=runtime)
    angles = np.logspace(-6, -1, 40)
    origins = np.zeros((40, 3))
    origins[:, 2] = 1e-3
    dirs = np.stack([np.cos(angles), np.zeros(40), -np.sin(angles)], axis=1)
    hits = caster.closest_hit(make_rays(origins, dirs))
    expected = 1e-3 / np.sin(angles)
    inside = expected * np.cos(angles) < 49.0
    assert (hits["prim"][inside] >= 0).all()
    assert (hits["prim"][~inside] < 0).all()
    # the hit point lies on the plane to float32 precision along the ray
    z = origins[:, 2] + hits["t"] * dirs[:, 2]
    assert np.all(np.abs(z[inside]) < 1e-6 * (1 + hits["t"][inside]))
    # rays exactly in the plane of a triangle meet no area: a clean miss, no NaN
    flat = caster.closest_hit(make_rays([[-60.0, 0.0, 0.0]], [[1.0, 0.0, 0.0]]))
    assert flat["prim"][0] == -1 and np.isinf(flat["t"][0])
    assert not np.isnan(caster.closest_hit(make_rays(origins, dirs))["u"]).any()


def test_degenerate_and_needle_triangles(runtime):
    rng = np.random.default_rng(3)
    good = rng.uniform(-1, 1, (200, 3, 3)) * 0.2 + rng.uniform(-1, 1, (200, 1, 3))
    # on a 1/64 grid so midpoints are exact in float32 and collinear stays collinear
    a = rng.integers(-64, 65, (60, 3)) / 64.0
    b = rng.integers(-64, 65, (60, 3)) / 64.0
    collinear = np.stack([a, b, 0.5 * (a + b)], axis=1)
    repeated = np.stack([a, a, b], axis=1)
    point = np.stack([a, a, a], axis=1)
    needles = np.stack([a, b, b + rng.normal(0, 1e-5, (60, 3))], axis=1)
    tris = np.concatenate([good, collinear, repeated, point, needles])
    caster = RayCaster(tris, runtime=runtime)
    origins = rng.uniform(-1.5, 1.5, (1000, 3))
    hits = check_against_reference(caster, origins, rng.normal(size=(1000, 3)))
    zero_area = np.arange(200, 380)
    assert not np.isin(hits["prim"], zero_area).any()
    # rays aimed at needles: a hit must be a true one, at the reference's distance
    n_origins = rng.uniform(-1.5, 1.5, (60, 3))
    check_against_reference(caster, n_origins, needles.mean(axis=1) - n_origins)


@pytest.mark.parametrize("offset", [0.0, 1000.0])
def test_rays_leaving_a_surface_do_not_hit_it_again(runtime, offset):
    """Reflected rays from points on a closed box reach the far wall, not themselves."""
    box = trimesh.creation.box(extents=[4.0, 3.0, 2.0])
    box = box.subdivide().subdivide()
    tris = box.vertices[box.faces] + offset
    caster = RayCaster(tris, runtime=runtime)
    rng = np.random.default_rng(5)
    face = rng.integers(0, len(tris), 2000)
    bary = rng.dirichlet([1, 1, 1], 2000)
    points = np.einsum("rk,rkj->rj", bary, tris[face])
    normals = np.cross(tris[face, 1] - tris[face, 0], tris[face, 2] - tris[face, 0])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    inward = -normals  # trimesh boxes wind outward
    dirs = rng.normal(size=(2000, 3))
    dirs -= np.minimum(np.einsum("ij,ij->i", dirs, inward), 0)[:, None] * 2 * inward
    origins = spawn_origins(points, inward, dirs)
    assert np.all(np.linalg.norm(origins - points, axis=1) < 1e-3)  # well under a wavelength
    # exit distance from inside an axis-aligned box, in closed form
    lo, hi = box.bounds[0] + offset, box.bounds[1] + offset
    with np.errstate(divide="ignore"):
        exit_t = np.where(dirs > 0, (hi - origins) / dirs, (lo - origins) / dirs)
    exit_t = np.where(dirs == 0, np.inf, exit_t).min(axis=1)
    for ignore in (face, None):
        hits = caster.closest_hit(make_rays(origins, dirs), ignore_prim=ignore)
        assert (hits["prim"] >= 0).all()
        np.testing.assert_allclose(hits["t"], exit_t, rtol=1e-4, atol=2e-3,
                                   err_msg="a ray stopped short: it hit the surface it leaves")


def test_any_hit_agrees_with_closest_hit(runtime):
    rng = np.random.default_rng(11)
    tris = rng.uniform(-1, 1, (800, 3, 3)) * 0.2 + rng.uniform(-1, 1, (800, 1, 3))
    caster = RayCaster(tris, runtime=runtime)
    origins = rng.uniform(-1.5, 1.5, (3000, 3))
    dirs = rng.normal(size=(3000, 3))
    tmax = rng.uniform(0.1, 3.0, 3000).astype(np.float32)
    closest = caster.closest_hit(make_rays(origins, dirs, tmin=1e-5))
    occluded = caster.occluded(make_rays(origins, dirs, tmin=1e-5, tmax=tmax))
    definite = np.abs(closest["t"] - tmax) > 1e-4 * (1 + tmax)
    np.testing.assert_array_equal(occluded[definite], (closest["t"] < tmax)[definite])
    assert 0.05 < occluded.mean() < 0.95


def test_hit_record_fields(runtime):
    tri = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]]], dtype=np.float64)
    caster = RayCaster(tri, runtime=runtime)
    hits = caster.closest_hit(make_rays([[0.2, 0.3, 2.0], [0.2, 0.3, -2.0]],
                                        [[0, 0, -1], [0, 0, 1]]))
    np.testing.assert_allclose(hits["t"], [2.0, 2.0], rtol=1e-6)
    np.testing.assert_allclose(hits["u"], [0.2, 0.2], atol=1e-6)
    np.testing.assert_allclose(hits["v"], [0.3, 0.3], atol=1e-6)
    np.testing.assert_allclose(hits["ng"], [[0, 0, 1], [0, 0, 1]], atol=1e-6)
    assert hits["prim"].tolist() == [0, 0]
    # tmax bounds the search
    short = caster.closest_hit(make_rays([[0.2, 0.3, 2.0]], [[0, 0, -1]], tmax=1.5))
    assert short["prim"][0] == -1


def test_tri4_groups_hold_every_leaf_triangle():
    rng = np.random.default_rng(21)
    tris = rng.uniform(-1, 1, (700, 3, 3)) * 0.1 + rng.uniform(-1, 1, (700, 1, 3))
    bvh = build_bvh(tris, max_leaf_size=8, max_leaf_cap=16)
    tri4, slot_prim, first, groups = tri4_groups(bvh, tris)
    assert tri4.dtype == np.float32 and tri4.shape == (len(slot_prim) // 4, 9, 4)
    assert sorted(set(slot_prim.tolist())) == list(range(len(tris)))
    lanes = tri4.reshape(-1, 3, 3, 4).transpose(0, 3, 1, 2).reshape(-1, 3, 3)  # slot, vertex, xyz
    np.testing.assert_array_equal(lanes, tris.astype(np.float32)[slot_prim])
    count = bvh.nodes["count"]
    leaves = np.flatnonzero(count > 0)
    np.testing.assert_array_equal(groups[leaves], (count[leaves] + 3) // 4)
    assert groups.sum() == len(tri4) and (groups[count == 0] == 0).all()
    for leaf in leaves:   # a leaf's slots: its triangles in tri_index order, then repeats
        lf = bvh.nodes["left_first"][leaf]
        own = bvh.tri_index[lf:lf + count[leaf]]
        slots = slot_prim[4 * first[leaf]:4 * (first[leaf] + groups[leaf])]
        np.testing.assert_array_equal(slots[:count[leaf]], own)
        assert (slots[count[leaf]:] == own[-1]).all()


def test_bvh8_records_reach_every_group_once_inside_their_boxes():
    rng = np.random.default_rng(22)
    tris = rng.uniform(-1, 1, (2000, 3, 3)) * 0.05 + rng.uniform(-1, 1, (2000, 1, 3))
    bvh = build_bvh(tris)
    tri4, _, first, groups = tri4_groups(bvh, tris)
    rec = bvh8_nodes(bvh.nodes, first, groups)
    assert rec.dtype.itemsize == 256 and len(rec) < bvh.n_nodes / 3
    lo = np.stack([rec["minx"], rec["miny"], rec["minz"]], axis=-1)   # (R, 8, 3)
    hi = np.stack([rec["maxx"], rec["maxy"], rec["maxz"]], axis=-1)
    child = rec["child"]
    empty = child == 0
    assert np.isposinf(lo[empty]).all() and np.isneginf(hi[empty]).all()
    seen_groups = np.zeros(len(tri4), dtype=int)
    seen_records = np.zeros(len(rec), dtype=int)
    todo = [(0, np.full(3, -np.inf, np.float32), np.full(3, np.inf, np.float32))]
    while todo:
        r, box_lo, box_hi = todo.pop()
        seen_records[r] += 1
        for k in np.flatnonzero(~empty[r]):
            assert (lo[r, k] >= box_lo).all() and (hi[r, k] <= box_hi).all()
            c = int(child[r, k])
            if c > 0:
                todo.append((c, lo[r, k], hi[r, k]))
                continue
            packed = -c - 1
            g0, ng = packed >> LEAF_GROUP_BITS, packed & MAX_LEAF_GROUPS
            seen_groups[g0:g0 + ng] += 1
            v = tri4[g0:g0 + ng].reshape(ng, 3, 3, 4)   # group, vertex, xyz, lane
            assert (v.min(axis=(1, 3)) >= lo[r, k]).all() and (v.max(axis=(1, 3)) <= hi[r, k]).all()
    assert (seen_groups == 1).all() and (seen_records == 1).all()
    for r in range(len(rec)):   # depth-first numbering: a record's first inner child follows it
        kids = child[r][child[r] > 0]
        assert not len(kids) or kids[0] == r + 1


def test_bvh8_refuses_a_tree_deeper_than_the_kernel_stack(monkeypatch):
    rng = np.random.default_rng(23)
    tris = rng.uniform(-1, 1, (3000, 3, 3)) * 0.05 + rng.uniform(-1, 1, (3000, 1, 3))
    bvh = build_bvh(tris)
    bvh8_nodes(bvh.nodes)
    monkeypatch.setattr(layout, "BVH_STACK_SIZE", 8)
    with pytest.raises(ValueError, match="traversal stack"):
        bvh8_nodes(bvh.nodes)


def test_ignore_prim_also_skips_the_repeats_that_pad_a_group(runtime):
    """Five stacked triangles in one leaf: two Tri4 groups, the second padded with the fifth."""
    base = np.array([[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [0.0, 1.0, 0.0]])
    heights = np.array([3.0, 5.0, 1.0, 4.0, 2.0])
    tris = base[None] + heights[:, None, None] * np.array([0.0, 0.0, 1.0])
    caster = RayCaster(tris, bvh=build_bvh(tris, max_leaf_size=8), runtime=runtime)
    assert caster.bvh.n_nodes == 1
    order = np.argsort(heights)
    rays = make_rays(np.zeros((6, 3)), np.tile([0.0, 0.0, 1.0], (6, 1)))
    ignore = np.concatenate([[-1], order])   # each triangle, the nearest first
    hits = caster.closest_hit(rays, ignore_prim=ignore)
    expected = [order[0], order[1], order[0], order[0], order[0], order[0]]
    assert hits["prim"].tolist() == [int(p) for p in expected]
    np.testing.assert_allclose(hits["t"], heights[expected])
    # any hit: only the one triangle in range, ignored -> nothing
    for i in range(5):
        short = make_rays([[0.0, 0.0, heights[i] - 0.5]], [[0.0, 0.0, 1.0]], tmax=1.0)
        assert caster.occluded(short).tolist() == [True]
        assert caster.occluded(short, ignore_prim=i).tolist() == [False]
    np.testing.assert_array_equal(caster.closest_hit(rays),
                                  caster.closest_hit(rays, ignore_prim=-1))


def test_rays_in_a_coordinate_plane_hit_the_ridge_of_a_closed_mesh(runtime):
    """An octahedron's equator (z = 0) is a ridge of shared edges; rays from inside that
    lie in the plane (dir z exactly 0, so 1/dir = inf) must hit it. The boxes of the
    upper and lower faces end exactly in the plane: the robust slab test's NaN case."""
    octa = trimesh.Trimesh(
        vertices=[[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]],
        faces=[[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4],
               [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]])
    octa = octa.subdivide().subdivide()
    caster = RayCaster(np.asarray(octa.vertices)[octa.faces], runtime=runtime)
    rng = np.random.default_rng(24)
    phi = rng.uniform(0.0, 2.0 * np.pi, 400)
    plane_dirs = np.stack([np.cos(phi), np.sin(phi), np.zeros_like(phi)], axis=1)
    plane_dirs[:8] = [[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0],
                      [1, 1, 0], [-1, 1, 0], [1, -1, 0], [-1, -1, 0]]
    plane_origins = np.zeros((400, 3))
    plane_origins[:, :2] = rng.integers(-3, 4, (400, 2)) / 8.0
    for perm in ([0, 1, 2], [1, 2, 0], [2, 0, 1]):   # the planes z = 0, x = 0, y = 0
        origins, dirs = plane_origins[:, perm], plane_dirs[:, perm]
        hits = caster.closest_hit(make_rays(origins, dirs))
        assert (hits["prim"] >= 0).all(), f"{(hits['prim'] < 0).sum()} rays slipped through"
        points = origins + hits["t"][:, None] * dirs
        np.testing.assert_allclose(np.abs(points).sum(axis=1), 1.0, atol=1e-5)  # |x|+|y|+|z|=1
        assert caster.occluded(make_rays(origins, dirs)).all()


def test_bad_rays_are_refused():
    with pytest.raises(ValueError, match=r"origins\[1\] is not finite"):
        make_rays([[0, 0, 0], [np.nan, 0, 0]], [[1, 0, 0], [1, 0, 0]])
    with pytest.raises(ValueError, match=r"directions\[0\] is the zero vector"):
        make_rays([[0, 0, 0]], [[0, 0, 0]])
    with pytest.raises(ValueError, match="shape"):
        make_rays([[0, 0, 0]], [[1, 0, 0], [1, 0, 0]])


# ---------------------------------------------------------------------------
# traversal stack: short builds for ordinary trees, a deeper one where a tree needs it


def test_stack_need_is_the_pushes_of_the_deepest_walk():
    rec = np.zeros(3, dtype=BVH8_NODE_DTYPE)
    rec["child"][0] = [-1, -1, -1, -1, -1, -1, -1, 1]   # seven leaves and record 1
    rec["child"][1, :3] = [-1, 2, -1]                    # two leaves and record 2
    rec["child"][2, :2] = [-1, -1]
    assert layout.stack_need(rec) == 7 + 2 + 1
    rec["child"][1, :3] = [-1, -1, -1]                   # record 2 no longer reached
    assert layout.stack_need(rec) == 7 + 2
    assert [layout.stack_size_for(n) for n in (0, 32, 33, 64, 65, 192)] == [32, 32, 64, 64,
                                                                          128, 192]
    with pytest.raises(ValueError, match="traversal stack of 193"):
        layout.stack_size_for(193)


def test_the_street_is_traced_with_a_short_stack(runtime):
    scene = load_scene("scenes/street/street.toml")
    caster = RayCaster(scene.triangles, runtime=runtime)
    assert caster.stack_size == 64   # its tree needs 48 entries
    small = RayCaster(trimesh.creation.icosphere(subdivisions=2).triangles, runtime=runtime)
    assert small.stack_size == 32
    # the kernels are built with the caster's own number
    prog = runtime.program("layout.cl", defines=caster.kernel_defines())
    out = np.zeros(len(KERNEL_DEFINES), dtype=np.int32)
    buf = runtime.empty(out.nbytes)
    prog.build_constants(runtime.queue, (1,), None, buf)
    cl.enqueue_copy(runtime.queue, out, buf)
    assert dict(zip(KERNEL_DEFINES, out.tolist(), strict=True))["BVH_STACK_SIZE"] == 64


def chain_bvh(triangles) -> Bvh:
    """The worst tree for a stack: every inner node holds one triangle's leaf and the
    node of all the triangles after it."""
    n = len(triangles)
    nodes = np.zeros(2 * n - 1, dtype=BVH_NODE_DTYPE)
    lo, hi = triangles.min(axis=1), triangles.max(axis=1)
    for i in range(n - 1):
        nodes[2 * i]["left_first"], nodes[2 * i]["count"] = 2 * i + 1, 0
        nodes[2 * i]["bmin"], nodes[2 * i]["bmax"] = lo[i:].min(axis=0), hi[i:].max(axis=0)
        nodes[2 * i + 1]["left_first"], nodes[2 * i + 1]["count"] = i, 1
        nodes[2 * i + 1]["bmin"], nodes[2 * i + 1]["bmax"] = lo[i], hi[i]
    last = 2 * n - 2
    nodes[last]["left_first"], nodes[last]["count"] = n - 1, 1
    nodes[last]["bmin"], nodes[last]["bmax"] = lo[-1], hi[-1]
    bvh = Bvh(nodes=nodes, tri_index=np.arange(n, dtype=np.int32))
    validate_bvh(bvh, triangles)
    return bvh


def test_a_tree_deeper_than_the_short_stacks_gets_a_deeper_build(runtime):
    """120 parallel triangles in a row, chained: a ray down the row meets every box and
    keeps the far leaves of each record on the stack while it walks into the nearer
    rest, so the walk really holds the tree's whole need (over 64 entries)."""
    n = 120
    x = 0.1 * np.arange(n)
    tris = np.zeros((n, 3, 3))
    tris[:, :, 0] = x[:, None]
    tris[:, :, 1:] = [(-1.0, -1.0), (2.0, -1.0), (-1.0, 2.0)]
    caster = RayCaster(tris, bvh=chain_bvh(tris), runtime=runtime)
    need = layout.stack_need(bvh8_nodes(caster.bvh.nodes))
    assert 64 < need <= 128 and caster.stack_size == 128
    rng = np.random.default_rng(5)
    origins = np.column_stack([np.full(200, 20.0), rng.uniform(-0.3, 0.3, (200, 2))])
    directions = np.column_stack([-np.ones(200), rng.uniform(-0.01, 0.01, (200, 2))])
    hits = check_against_reference(caster, origins, directions)
    assert (hits["prim"] == n - 1).all()   # the nearest of the row, for every ray
    # from inside the row, every way: the brute force decides
    inside = np.column_stack([rng.uniform(0, x[-1], 300), rng.uniform(-0.5, 0.5, (300, 2))])
    check_against_reference(caster, inside, rng.normal(size=(300, 3)))
    # any hit: a segment between two triangles' planes sees nothing, one across them does
    free = make_rays(np.column_stack([x[:-1] + 0.05, np.zeros((n - 1, 2))]),
                     np.tile([0.0, 0.0, 1.0], (n - 1, 1)), tmax=0.5)
    assert not caster.occluded(free).any()
    across = make_rays(np.column_stack([np.full(n, -1.0), np.zeros((n, 2))]),
                       np.tile([1.0, 0.0, 0.0], (n, 1)), tmax=1.0 + x + 0.05)
    assert caster.occluded(across).all()


# ---------------------------------------------------------------------------
# ray packets (intersect.h: packet_closest): closest_hit's hits, ray for ray


def grid_packets(origin, centre, u, v, pitch, n_side, block=8):
    """Rays from ``origin`` through an n_side x n_side grid of points of ``pitch`` around
    ``centre`` in the plane of u, v, as packets of block x block neighbours (an SBR
    launch window's blocks): (rays, packet_first)."""
    k = (np.arange(n_side) - (n_side - 1) / 2.0) * pitch
    i, j = np.meshgrid(k, k, indexing="ij")
    # block-major order: the block x block cells of a block consecutive
    nb = n_side // block
    i = i.reshape(nb, block, nb, block).transpose(0, 2, 1, 3).reshape(-1)
    j = j.reshape(nb, block, nb, block).transpose(0, 2, 1, 3).reshape(-1)
    target = (np.asarray(centre, float) + i[:, None] * np.asarray(u, float)
              + j[:, None] * np.asarray(v, float))
    origins = np.broadcast_to(np.asarray(origin, float), target.shape)
    first = np.arange(0, len(target) + 1, block * block)
    return make_rays(origins, target - origins), first


def overlapping_planes():
    """The plane z = 0 twice over: a coarse grid of large triangles and, on top of it, a
    fine grid of small ones, so most rays hit two coplanar triangles (in different
    leaves) at the same t, to within rounding; plus a box of 12 triangles above it."""
    def grid(n, half):
        xs = np.linspace(-half, half, n + 1)
        gx, gy = np.meshgrid(xs, xs, indexing="ij")
        p = np.stack([gx, gy, np.zeros_like(gx)], axis=-1)
        q = np.stack([p[:-1, :-1], p[1:, :-1], p[1:, 1:], p[:-1, 1:]], axis=2).reshape(-1, 4, 3)
        return np.concatenate([q[:, [0, 1, 2]], q[:, [0, 2, 3]]])

    box = trimesh.creation.box(extents=(0.6, 0.4, 0.3))
    box.apply_translation((0.3, -0.2, 0.5))
    return np.concatenate([grid(4, 2.0), grid(40, 2.0),
                           np.asarray(box.triangles, np.float64)])


def test_packets_are_the_single_ray_hits_bit_for_bit(runtime):
    """closest_hit_packets returns closest_hit's records byte for byte: coherent 8 x 8
    packets over coplanar overlapping triangles (exact and near ties between leaves,
    which the packet resolves by casting those rays again on their own), over a grid's
    shared edges and vertices (rays aimed through them), with misses beside, and
    incoherent packets of every size (rays toward both sides of an axis: ray by ray)."""
    tris = overlapping_planes()
    caster = RayCaster(tris, runtime=runtime)
    # through the fine grid's vertices and edges (pitch 0.05: every other ray on a seam),
    # from a point above and to the side, part of the grid beyond the plane's rim
    rays, first = grid_packets([0.7, -0.4, 3.0], [0.9, 0.2, 0.0], [1, 0, 0], [0, 1, 0],
                               0.025, 96)
    single = caster.closest_hit(rays)
    packed = caster.closest_hit_packets(rays, first)
    assert packed.tobytes() == single.tobytes()
    hit = single["prim"] >= 0
    assert 0.5 < hit.mean() < 0.99          # hits, and misses past the rim
    on_box = hit & (single["prim"] >= len(tris) - 12)
    assert on_box.sum() > 100               # a nearer object in front of the planes
    # the premise: rays whose coarse and fine triangles lie at the same t within rounding
    rays_o = rays["org"].astype(np.float64)
    t_plane = -rays_o[:, 2] / rays["dir"][:, 2].astype(np.float64)
    on_plane = hit & ~on_box
    np.testing.assert_allclose(single["t"][on_plane], t_plane[on_plane], rtol=1e-6)
    coarse = on_plane & (single["prim"] < 32)
    fine = on_plane & (single["prim"] >= 32)
    assert coarse.sum() > 100 and fine.sum() > 100   # either of two ties wins, by walk

    # incoherent rays in packets of 1 to 64
    rng = np.random.default_rng(3)
    origins = rng.uniform(-2.5, 2.5, (3000, 3))
    targets = tris[rng.integers(0, len(tris), 3000)].mean(axis=1)
    rays = make_rays(origins, targets - origins + rng.normal(0, 0.3, (3000, 3)))
    sizes = rng.integers(1, 65, 200)
    first = np.concatenate([[0], np.cumsum(sizes)])
    first = first[first < len(rays)]
    first = np.append(first, len(rays))
    assert caster.closest_hit_packets(rays, first).tobytes() == \
        caster.closest_hit(rays).tobytes()


def test_packets_on_a_few_rays(runtime):
    """A small case for Oclgrind: 4 coherent packets of 64 over the overlapping planes,
    and one of a single ray; the same records as closest_hit."""
    caster = RayCaster(overlapping_planes(), runtime=runtime)
    rays, first = grid_packets([0.3, 0.2, 2.0], [0.1, 0.0, 0.0], [1, 0, 0], [0, 1, 0],
                               0.05, 16)
    first = np.append(first, len(rays) + 1)
    rays = np.concatenate([rays, make_rays([[0.0, 0.0, 1.0]], [[0.01, 0.02, -1.0]])])
    assert caster.closest_hit_packets(rays, first).tobytes() == \
        caster.closest_hit(rays).tobytes()


def test_packets_of_a_two_level_caster_are_its_hits(runtime):
    """A two-level tree casts a packet's rays one by one: still closest_hit's records."""
    from clradcom.device.raycast import InstancedCaster

    rng = np.random.default_rng(5)
    static = overlapping_planes()
    mover = rng.uniform(-0.2, 0.2, (60, 3, 3)) + np.array([0.0, 0.0, 0.8])
    caster = InstancedCaster([(static, np.arange(len(static))),
                              (mover, np.arange(len(static), len(static) + 60))],
                             runtime=runtime)
    # the mover turned a little about z and lifted: a frame of its own
    c, s_ = np.cos(0.3), np.sin(0.3)
    rot = np.array([np.eye(3), [[c, -s_, 0.0], [s_, c, 0.0], [0.0, 0.0, 1.0]]])
    org = np.array([[0.0, 0.0, 0.0], [0.05, -0.05, 0.1]])
    caster.place(np.concatenate([static, mover @ rot[1].T + org[1]]), rot, org,
                 [True, False])
    rays, first = grid_packets([0.1, 0.1, 3.0], [0.0, 0.0, 0.0], [1, 0, 0], [0, 1, 0],
                               0.02, 32)
    hits = caster.closest_hit_packets(rays, first)
    assert hits.tobytes() == caster.closest_hit(rays).tobytes()
    assert (hits["prim"] >= len(static)).sum() > 20


def test_bad_packets_are_refused(runtime):
    caster = RayCaster(overlapping_planes()[:8], runtime=runtime)
    rays = make_rays(np.zeros((70, 3)), np.tile([0.0, 0.0, -1.0], (70, 1)))
    with pytest.raises(ValueError, match="packet_first"):
        caster.closest_hit_packets(rays, [0, 10])          # does not end at len(rays)
    with pytest.raises(ValueError, match="0 to 64 rays"):
        caster.closest_hit_packets(rays, [0, 70])          # a packet too large
    with pytest.raises(ValueError, match="0 to 64 rays"):
        caster.closest_hit_packets(rays, [0, 40, 30, 70])  # falling
    with pytest.raises(ValueError, match="packet_first"):
        caster.closest_hit_packets(rays, [0.0, 70.0])      # not integers
