"""The launch windows' geometry helpers, as made faster, against plain references: the
near-plane clip against the per-triangle loop it replaced, the frustum cull against
projected sample points, block coverage against a brute-force separating-axis test of
every (triangle, block) pair."""

import numpy as np

from clradcom.geometry.silhouette import block_coverage
from clradcom.mechanisms import sbr


def clip_near_loop(tri, eye, axis, near):
    """The per-triangle clip the vectorised one replaced (commit 6ffe190), its depths
    summed in the launch kernels' order ((x + y) + z) as the vectorised clip now does."""
    rel = tri - eye
    depth = (rel[..., 0] * axis[0] + rel[..., 1] * axis[1]) + rel[..., 2] * axis[2]
    front = depth >= near
    out = [tri[front.all(axis=1)]]
    part = front.any(axis=1) & ~front.all(axis=1)
    for t, d in zip(tri[part], depth[part], strict=True):
        poly = []
        for k in range(3):
            a, b, da, db = t[k], t[(k + 1) % 3], d[k], d[(k + 1) % 3]
            if da >= near:
                poly.append(a)
            if (da >= near) != (db >= near):
                poly.append(a + (near - da) / (db - da) * (b - a))
        out.extend(np.array([[poly[0], poly[i], poly[i + 1]]])
                   for i in range(1, len(poly) - 1))
    return np.concatenate(out)


def test_clip_near_gives_the_loops_triangles_bit_for_bit():
    rng = np.random.default_rng(3)
    tri = rng.normal(size=(400, 3, 3)) * 3.0
    eye, axis = np.array([0.1, -0.2, 0.3]), np.array([0.0, 0.6, 0.8])
    got = sbr._clip_near(tri, eye, axis, 0.5)
    want = clip_near_loop(tri, eye, axis, 0.5)
    # both straddling cases occur, and triangles wholly behind are dropped
    depth = (tri - eye) @ axis
    n_front = (depth >= 0.5).sum(axis=1)
    assert {0, 1, 2, 3} <= set(n_front.tolist())
    assert len(got) == len(want) == (n_front == 3).sum() + (n_front == 1).sum() + 2 * (
        n_front == 2).sum()
    key = lambda a: a[np.lexsort(a.reshape(len(a), -1).T)]  # noqa: E731
    np.testing.assert_array_equal(key(got), key(want))
    assert np.all((got - eye) @ axis >= 0.5 - 1e-12)


def test_beside_culls_only_triangles_projecting_outside_the_rectangle():
    rng = np.random.default_rng(5)
    eye = np.zeros(3)
    axis, u, v = np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0]), np.array([0, 1.0, 0])
    D, lo, hi = 10.0, np.array([-1.0, -0.5]), np.array([2.0, 1.5])
    tri = rng.normal(size=(3000, 3, 3)) * [4.0, 4.0, 6.0] + [0.0, 0.0, 8.0]
    culled = sbr._beside(tri, eye, axis, u, v, D, lo, hi)
    assert 0.2 < culled.mean() < 0.95
    # dense points of each culled triangle in front of the eye project outside [lo, hi]
    w = rng.dirichlet(np.ones(3), size=200)
    pts = np.einsum("sk,tkc->tsc", w, tri[culled])
    front = pts[..., 2] > 1e-6
    x, y = D * pts[..., 0] / pts[..., 2], D * pts[..., 1] / pts[..., 2]
    inside = front & (x >= lo[0]) & (x <= hi[0]) & (y >= lo[1]) & (y <= hi[1])
    assert not inside.any()
    # and the kept ones include every triangle with a sample point inside
    pts = np.einsum("sk,tkc->tsc", w, tri[~culled])
    x, y = D * pts[..., 0] / pts[..., 2], D * pts[..., 1] / pts[..., 2]
    hit = ((pts[..., 2] > 0) & (x >= lo[0]) & (x <= hi[0]) & (y >= lo[1])
           & (y <= hi[1])).any(axis=1)
    assert hit.sum() > 100


def coverage_brute(tri, bs, origin, shape):
    """Every (triangle, block) pair: separated on a box axis or an edge normal."""
    mask = np.zeros(shape, bool)
    for t in tri:
        e = np.roll(t, -1, axis=0) - t
        a2 = e[0, 0] * e[1, 1] - e[0, 1] * e[1, 0]
        if abs(a2) <= 1e-12 * np.abs(e).max() ** 2:
            continue
        n = np.stack([e[:, 1], -e[:, 0]], axis=1) * np.sign(a2)
        for i in range(shape[0]):
            for j in range(shape[1]):
                c = np.array(origin) + (np.array([i, j]) + 0.5) * bs
                if np.any(t.min(axis=0) > c + bs / 2) or np.any(t.max(axis=0) < c - bs / 2):
                    continue
                if np.all(n @ c - 0.5 * bs * np.abs(n).sum(axis=1) <= np.sum(n * t, axis=1)):
                    mask[i, j] = True
    return mask


def test_block_coverage_matches_every_pair_tested():
    rng = np.random.default_rng(7)
    tri = rng.uniform(-3.0, 3.0, size=(60, 1, 2)) + rng.normal(size=(60, 3, 2)) * 0.8
    tri[:5] = tri[:5, :1] + 1e-3 * rng.normal(size=(5, 3, 2))   # tiny ones inside a block
    tri[5:8] += 20.0                                             # outside the grid
    got = block_coverage(tri, 0.4, (-3.0, -2.6), (15, 14))
    np.testing.assert_array_equal(got, coverage_brute(tri, 0.4, (-3.0, -2.6), (15, 14)))
    assert 0 < got.sum() < got.size


def test_device_block_coverage_is_the_hosts_bit_for_bit(runtime):
    from clradcom.device.silhouette import block_coverage as device_coverage

    rng = np.random.default_rng(11)
    tri = rng.uniform(-3.0, 3.0, size=(40, 1, 2)) + rng.normal(size=(40, 3, 2)) * 0.5
    tri[:5] = tri[:5, :1] + 1e-3 * rng.normal(size=(5, 3, 2))   # tiny ones inside a block
    tri[5:8] += 20.0                                             # outside the grid
    tri[8:10, 2] = tri[8:10, 0] + 0.5 * (tri[8:10, 1] - tri[8:10, 0])  # edge-on: no area
    for origin, shape in (((-3.0, -2.6), (15, 14)), ((-4.05, -3.3), (31, 29))):
        want = block_coverage(tri, 0.2, origin, shape)
        got = device_coverage(runtime, tri, 0.2, origin, shape, min_pairs=0)
        assert got.dtype == bool and got.shape == tuple(shape)
        np.testing.assert_array_equal(got, want)
        assert 0 < got.sum() < got.size
    # the host path below the pair threshold gives the same mask
    np.testing.assert_array_equal(
        device_coverage(runtime, tri, 0.2, (-3.0, -2.6), (15, 14), min_pairs=1 << 40),
        block_coverage(tri, 0.2, (-3.0, -2.6), (15, 14)))
