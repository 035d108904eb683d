"""Tests for the BVH builder: layout invariants, degenerate scenes, SAH quality, ray queries."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from clradcom.geometry.bvh import BVH_NODE_DTYPE, Bvh, BvhValidationError, build_bvh, validate_bvh


def soup(n: int, seed: int = 0, spread: float = 10.0, size: float = 0.5) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.uniform(0, spread, (n, 1, 3)) + rng.normal(0, size, (n, 3, 3))


def clustered(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    centers = rng.uniform(-100, 100, (8, 3))
    c = centers[rng.integers(0, 8, n)] + rng.normal(0, 2.0, (n, 3))
    return c[:, None, :] + rng.normal(0, 0.3, (n, 3, 3))


# --------------------------------------------------------------------------- layout / API


def test_dtype_matches_c_struct():
    assert BVH_NODE_DTYPE.itemsize == 32
    assert [BVH_NODE_DTYPE.fields[f][1] for f in ("bmin", "left_first", "bmax", "count")] == [
        0,
        12,
        16,
        28,
    ]


def test_single_triangle_is_leaf_root():
    tri = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]]], dtype=np.float64)
    bvh = build_bvh(tri)
    validate_bvh(bvh, tri)
    assert bvh.n_nodes == 1
    assert bvh.nodes[0]["count"] == 1 and bvh.nodes[0]["left_first"] == 0
    assert bvh.tri_index.tolist() == [0]
    assert bvh.depth() == 0
    np.testing.assert_array_equal(bvh.nodes[0]["bmin"], [0, 0, 0])
    np.testing.assert_array_equal(bvh.nodes[0]["bmax"], [1, 1, 0])


def test_outputs_are_contiguous_and_typed():
    tris = soup(500)
    bvh = build_bvh(tris)
    assert isinstance(bvh, Bvh)
    assert bvh.nodes.dtype == BVH_NODE_DTYPE and bvh.nodes.flags.c_contiguous
    assert bvh.tri_index.dtype == np.int32 and bvh.tri_index.flags.c_contiguous
    assert sorted(bvh.tri_index.tolist()) == list(range(500))
    assert bvh.leaf_sizes().sum() == 500
    assert bvh.leaf_sizes().max() <= 16
    with pytest.raises(AttributeError):
        bvh.nodes = bvh.nodes  # frozen


@pytest.mark.parametrize(
    "bad, msg",
    [
        (np.zeros((0, 3, 3)), "0 triangles"),
        (np.zeros((4, 3)), "shape"),
        (np.zeros((4, 4, 3)), "shape"),
        (np.zeros((4, 3, 2)), "shape"),
        (np.array([[[0, 0, 0], [1, 0, 0], [np.nan, 1, 0]]]), "NaN"),
        (np.array([[[0, 0, 0], [1, 0, 0], [np.inf, 1, 0]]]), "NaN or infinite"),
        (np.array([[[0, 0, 0], [1, 0, 0], [1e300, 1, 0]]]), "overflow float32"),
        (np.zeros((2, 3, 3), dtype=complex), "dtype"),
    ],
)
def test_invalid_input(bad, msg):
    with pytest.raises(ValueError, match=msg):
        build_bvh(bad)


def test_bounds_conservative_for_float32():
    # float64 vertices that are not representable in float32: boxes must contain the rounded
    # float32 triangles the kernel tests.
    rng = np.random.default_rng(3)
    tris = 1234.5678 + rng.normal(0, 1e-3, (300, 3, 3))
    bvh = build_bvh(tris)
    validate_bvh(bvh, tris)
    t32 = tris.astype(np.float32)
    assert (bvh.nodes[0]["bmin"] <= t32.min(axis=(0, 1))).all()
    assert (bvh.nodes[0]["bmax"] >= t32.max(axis=(0, 1))).all()


# --------------------------------------------------------------------------- invariants


@settings(deadline=None, max_examples=40)
@given(
    n=st.integers(1, 400),
    seed=st.integers(0, 2**32 - 1),
    leaf=st.integers(1, 8),
    bins=st.integers(2, 32),
    axes=st.sampled_from(["longest", "all"]),
)
def test_invariants_random_soup(n, seed, leaf, bins, axes):
    tris = soup(n, seed, spread=float(np.random.default_rng(seed).uniform(0.01, 1e3)))
    bvh = build_bvh(tris, max_leaf_size=leaf, n_bins=bins, axes=axes)
    validate_bvh(bvh, tris)
    assert bvh.leaf_sizes().max() <= max(leaf, 16)


@settings(deadline=None, max_examples=25)
@given(
    n=st.integers(1, 300),
    seed=st.integers(0, 2**32 - 1),
    coords=st.sampled_from([-1.0, 0.0, 1.0, 2.5]),
)
def test_invariants_quantised_coordinates(n, seed, coords):
    # Few distinct coordinate values: many identical centroids and zero-area triangles.
    rng = np.random.default_rng(seed)
    tris = rng.integers(0, 3, (n, 3, 3)) * 0.5 + coords
    bvh = build_bvh(tris)
    validate_bvh(bvh, tris)


@pytest.mark.parametrize(
    "name",
    ["identical", "zero_area", "points", "offset_1e4", "flat", "collinear_centroids", "median"],
)
def test_degenerate_scenes(name):
    rng = np.random.default_rng(7)
    if name == "identical":
        tris = np.repeat(rng.normal(size=(1, 3, 3)), 5000, axis=0)
    elif name == "zero_area":
        a = rng.uniform(0, 10, (2000, 1, 3))
        d = rng.normal(size=(2000, 1, 3))
        tris = a + d * np.array([0.0, 1.0, 2.0])[None, :, None]  # collinear vertices
    elif name == "points":
        tris = np.repeat(rng.uniform(0, 1, (3000, 1, 3)), 3, axis=1)  # every triangle a point
        tris[:1500] = tris[0]
    elif name == "offset_1e4":
        tris = soup(3000, 1, spread=50.0, size=0.2) + np.array([1.0e4, -3.0e3, 1.0e3])
    elif name == "flat":
        tris = soup(3000, 2, spread=100.0)
        tris[..., 2] = 0.0
    elif name == "collinear_centroids":
        t = rng.uniform(0, 100, 2000)
        tris = np.stack([t, np.zeros_like(t), np.zeros_like(t)], -1)[:, None, :] + np.array(
            [[0, 0, 0], [0, 1, 0], [0, 0, 1]]
        )
    else:
        tris = soup(3000, 4)
    bvh = build_bvh(tris, method="median" if name == "median" else "sah")
    validate_bvh(bvh, tris)
    assert bvh.leaf_sizes().max() <= 16
    assert bvh.depth() <= 64
    if name == "identical":
        # balanced fallback: depth ~ log2(5000 / 16)
        assert bvh.depth() <= 14


def test_max_depth_is_respected():
    # Exponentially spaced triangles make the SAH peel off one triangle per level.
    x = 2.0 ** np.arange(0, 60, 0.5)
    tris = np.stack([x, np.zeros_like(x), np.zeros_like(x)], -1)[:, None, :] + np.array(
        [[0, 0, 0], [1e-3, 0, 0], [0, 1e-3, 0]]
    )
    free = build_bvh(tris, max_leaf_size=1, max_depth=1000)
    validate_bvh(free, tris)
    capped = build_bvh(tris, max_leaf_size=1, max_depth=12)
    validate_bvh(capped, tris)
    assert capped.depth() <= 12 < free.depth()


def test_validate_detects_corruption():
    tris = soup(200, 5)
    bvh = build_bvh(tris)
    validate_bvh(bvh, tris)

    def broken(mutate):
        nodes = bvh.nodes.copy()
        ti = bvh.tri_index.copy()
        mutate(nodes, ti)
        return Bvh(nodes=nodes, tri_index=ti)

    inner = int(np.flatnonzero(bvh.nodes["count"] == 0)[1])
    leaf = int(np.flatnonzero(bvh.nodes["count"] > 0)[0])
    cases = {
        "permutation": lambda n, t: t.__setitem__(0, t[1]),
        "inside": lambda n, t: n["bmax"].__setitem__(leaf, n["bmin"][leaf]),
        "reached more than once": lambda n, t: n["left_first"].__setitem__(inner, 1),
        "out-of-range": lambda n, t: n["left_first"].__setitem__(0, len(n) - 1),
        "negative count": lambda n, t: n["count"].__setitem__(leaf, -1),
    }
    for msg, mutate in cases.items():
        with pytest.raises(BvhValidationError, match=msg):
            validate_bvh(broken(mutate), tris)


# --------------------------------------------------------------------------- quality


def test_sah_beats_median_on_clustered_scene():
    tris = clustered(20_000)
    sah = build_bvh(tris)
    med = build_bvh(tris, method="median")
    validate_bvh(med, tris)
    assert sah.sah_cost() < 0.95 * med.sah_cost()
    assert build_bvh(tris, axes="all").sah_cost() <= 1.02 * sah.sah_cost()


# --------------------------------------------------------------------------- ray queries


def _ray_tri_brute(org, dirs, tris):
    """Moller-Trumbore against all triangles (float64). Returns (t, prim) per ray."""
    v0, v1, v2 = tris[:, 0], tris[:, 1], tris[:, 2]
    e1, e2 = v1 - v0, v2 - v0
    p = np.cross(dirs[:, None, :], e2[None])
    det = np.einsum("tk,rtk->rt", e1, p)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / det
        s = org[:, None, :] - v0[None]
        u = np.einsum("rtk,rtk->rt", s, p) * inv
        q = np.cross(s, e1[None])
        v = np.einsum("rk,rtk->rt", dirs, q) * inv
        t = np.einsum("tk,rtk->rt", e2, q) * inv
        ok = (np.abs(det) > 1e-12) & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 1e-9)
    t = np.where(ok, t, np.inf)
    prim = np.argmin(t, axis=1)
    tmin = t[np.arange(len(org)), prim]
    return tmin, np.where(np.isfinite(tmin), prim, -1)


def _ray_box(o, inv_d, lo, hi, tmax):
    with np.errstate(invalid="ignore"):
        t0 = (lo - o) * inv_d
        t1 = (hi - o) * inv_d
    tn = np.nanmax(np.minimum(t0, t1))
    tf = np.nanmin(np.maximum(t0, t1))
    tn = max(tn, 0.0)
    return tn if tn <= tf * (1 + 1e-9) + 1e-12 and tn < tmax else np.inf


def _traverse(bvh, tris, o, d):
    """Closest hit by stack traversal of the flat layout (the kernel's semantics, in Python)."""
    nodes = bvh.nodes
    lo = nodes["bmin"].astype(np.float64)
    hi = nodes["bmax"].astype(np.float64)
    with np.errstate(divide="ignore"):
        inv_d = 1.0 / d
    best_t, best = np.inf, -1
    stack = [0]
    visited = 0
    while stack:
        i = stack.pop()
        if _ray_box(o, inv_d, lo[i], hi[i], best_t) == np.inf:
            continue
        visited += 1
        c = int(nodes["count"][i])
        f = int(nodes["left_first"][i])
        if c > 0:
            slots = bvh.tri_index[f : f + c]
            t, p = _ray_tri_brute(o[None], d[None], tris[slots])
            if t[0] < best_t:
                best_t, best = float(t[0]), int(slots[p[0]])
        else:
            stack.append(f + 1)
            stack.append(f)
    return best_t, best, visited


@pytest.mark.parametrize("scene", ["soup", "flat_offset"])
def test_traversal_matches_brute_force(scene):
    rng = np.random.default_rng(11)
    if scene == "soup":
        tris = soup(1500, 3, spread=20.0, size=0.8)
        base = np.zeros(3)
    else:
        base = np.array([3.0e3, 2.0e3, 0.0])
        tris = soup(1500, 4, spread=40.0, size=1.0) + base
        tris[:700, :, 2] = 0.0  # flat ground
    tris = tris.astype(np.float32).astype(np.float64)  # what the kernel sees
    bvh = build_bvh(tris)
    validate_bvh(bvh, tris)
    n_rays = 300
    org = base + rng.uniform(-5, 45, (n_rays, 3))
    # Most rays aim near a triangle (hits), some are random, some axis-aligned (inf in 1/d).
    target = tris[rng.integers(0, len(tris), n_rays)].mean(axis=1) + rng.normal(0, 0.3, (n_rays, 3))
    dirs = target - org
    dirs[::5] = rng.normal(size=dirs[::5].shape)
    dirs[::7, 1:] = 0.0
    dirs[3::7] = [0.0, 0.0, -1.0]
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    t_ref, p_ref = _ray_tri_brute(org, dirs, tris)
    total_visited = 0
    for r in range(n_rays):
        t, p, visited = _traverse(bvh, tris, org[r], dirs[r])
        total_visited += visited
        if np.isfinite(t_ref[r]):
            assert t == pytest.approx(t_ref[r], rel=1e-9, abs=1e-9), r
            # ties between coincident hits may pick either triangle
            assert p == p_ref[r] or abs(t - t_ref[r]) < 1e-9
        else:
            assert p == -1
    assert (p_ref >= 0).sum() > n_rays // 3  # the test is meaningful
    assert total_visited < 0.25 * n_rays * bvh.n_nodes  # and the tree actually culls


def test_ordered_triangles_helper():
    tris = soup(100, 8)
    bvh = build_bvh(tris)
    ordered = bvh.ordered_triangles(tris)
    np.testing.assert_array_equal(ordered, tris.astype(np.float32)[bvh.tri_index])
    assert ordered.dtype == np.float32 and ordered.flags.c_contiguous
