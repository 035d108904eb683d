"""What a point sees of a set of triangles: their silhouette on a plane, in square blocks.

SBR-PO (:mod:`clradcom.mechanisms.sbr`) launches its ray tubes through a square grid on a
plane perpendicular to the line of sight, a *window*; only the grid cells that some
triangle of the target covers need a tube. This module projects triangles centrally from
the eye onto such a plane and marks the blocks of ``BLOCK`` x ``BLOCK`` cells that a
triangle overlaps, by the separating-axis test of a triangle against a square (Akenine-
Möller, "Fast 3D triangle-box overlap testing", J. Graphics Tools 6(1), 2001, in 2-D:
the two axes of the square and the three edge normals of the triangle). Conservative by
construction: a block that a triangle touches is never left out, so the tubes cover the
whole silhouette; a block is at most one block wide beyond it.
"""

from __future__ import annotations

import numpy as np

from clradcom.errors import ArgumentError

__all__ = ["BLOCK", "block_coverage", "cover_blocks", "cover_blocks_many", "cover_xy_many",
           "coverage_setup", "coverage_setup_many", "project_to_plane"]

#: Cells per block side: a block is the unit of launch (BLOCK**2 tubes, one work-group's
#: worth) and of the coverage masks.
BLOCK = 8

# (triangle, block) pairs tested at once: bounds the temporaries to some 100 MB
_PAIR_CHUNK = 1 << 21


def project_to_plane(points, eye, axis, u, v, distance):
    """Central projection of ``points`` (..., 3) from ``eye`` onto the plane at
    ``distance`` along the unit ``axis``, in the plane's orthonormal coordinates (u, v):
    (x, y, depth) with x = distance (p - eye).u / depth, depth = (p - eye).axis."""
    rel = np.asarray(points, dtype=np.float64) - np.asarray(eye, dtype=np.float64)
    depth = rel @ np.asarray(axis, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        x = distance * (rel @ np.asarray(u, dtype=np.float64)) / depth
        y = distance * (rel @ np.asarray(v, dtype=np.float64)) / depth
    return x, y, depth


def coverage_setup(tri_xy, block_size: float, shape, origin=(0.0, 0.0)) -> dict | None:
    """The separating-axis data of :func:`block_coverage` for the triangles that can
    cover a block: ``nrm`` (T, 3, 2) outward edge normals, ``off`` (T, 3) the triangle
    lies where n.p <= off, ``radius`` (T, 3) the half block's reach along each normal,
    ``lo`` (T, 2) first block and ``cnt`` (T, 2) blocks of each triangle's box in the
    grid, ``n_pairs`` (T,) their products, ``window`` (T,) zeros (one grid: see
    :func:`coverage_setup_many`). None: nothing to test (the mask stays empty). Checks
    the arguments."""
    tri = np.asarray(tri_xy, dtype=np.float64)
    if tri.ndim != 3 or tri.shape[1:] != (3, 2):
        raise ArgumentError(f"tri_xy must have shape (T, 3, 2), got {tri.shape}")
    if not (np.isfinite(block_size) and block_size > 0):
        raise ArgumentError("must be a positive number", argument="block_size",
                            value=block_size)
    nx, ny = (int(n) for n in shape)
    if len(tri) == 0 or nx == 0 or ny == 0:
        return None
    return coverage_setup_many(tri, np.zeros(len(tri), np.int64),
                               np.array([float(block_size)]),
                               np.array([[float(o) for o in origin]]),
                               np.array([[nx, ny]], dtype=np.int64))


def coverage_setup_many(tri_xy, window, block_size, origin, shape) -> dict | None:
    """:func:`coverage_setup` of triangles on many grids at once: triangle t lies on grid
    ``window[t]`` of ``block_size`` (W,), ``origin`` (W, 2) and ``shape`` (W, 2); the
    expressions per triangle are those of one grid, so the data are the same bit for bit.
    The result holds the triangles that can cover a block, with their ``window``."""
    tri = np.asarray(tri_xy, dtype=np.float64)
    window = np.asarray(window, dtype=np.int64)
    if len(tri) == 0:
        return None
    bs = np.asarray(block_size, dtype=np.float64)[window]
    o = np.asarray(origin, dtype=np.float64)[window]
    top = np.asarray(shape, dtype=np.int64)[window] - 1
    e = tri[:, [1, 2, 0]] - tri  # edges v_k -> v_{k+1}
    area2 = e[:, 0, 0] * e[:, 1, 1] - e[:, 0, 1] * e[:, 1, 0]
    scale = np.abs(e).max(axis=(1, 2))
    keep = np.abs(area2) > 1e-12 * scale * scale
    lo = np.floor((tri.min(axis=1) - o) / bs[:, None]).astype(np.int64)
    hi = np.floor((tri.max(axis=1) - o) / bs[:, None]).astype(np.int64)
    lo = np.maximum(lo, 0)
    hi = np.minimum(hi, top)
    cnt = np.maximum(hi - lo + 1, 0)
    n_pairs = cnt[:, 0] * cnt[:, 1]
    keep &= n_pairs > 0   # wholly outside the grid: no block to test
    tri, e, area2, lo, cnt, n_pairs, window, bs = (
        a[keep] for a in (tri, e, area2, lo, cnt, n_pairs, window, bs))
    if len(tri) == 0:
        return None
    # outward edge normals: for a counter-clockwise triangle (area2 > 0) (e_y, -e_x)
    sgn = np.sign(area2)[:, None]
    nrm = np.stack([e[..., 1] * sgn, -e[..., 0] * sgn], axis=-1)  # (T, 3, 2)
    off = nrm[..., 0] * tri[..., 0] + nrm[..., 1] * tri[..., 1]  # triangle: n.p <= off
    half = 0.5 * bs
    radius = half[:, None] * np.abs(nrm).sum(axis=-1)  # (T, 3): the square's reach
    return {"nrm": nrm, "off": off, "radius": radius, "lo": lo, "cnt": cnt,
            "n_pairs": n_pairs, "window": window}


def block_coverage(tri_xy, block_size: float, origin, shape) -> np.ndarray:
    """(shape) bool: the blocks of a grid that the 2-D triangles ``tri_xy`` (T, 3, 2) overlap.

    Block (i, j) is the square [origin + (i, j) * block_size, origin + (i+1, j+1) *
    block_size]. Triangles of (near) zero area, seen edge-on, cover nothing. Block
    centres are ``origin + (i + 1/2) * block_size``; a block is covered where, for all
    three edges k, ``(n_k,x c_x + n_k,y c_y) - r_k <= off_k`` (:func:`coverage_setup`):
    the device's kernels/silhouette.cl evaluates the same expressions.
    """
    return cover_blocks(coverage_setup(tri_xy, block_size, shape, origin), block_size,
                        origin, shape)


def cover_blocks(setup: dict | None, block_size: float, origin, shape) -> np.ndarray:
    """:func:`block_coverage`'s mask from its :func:`coverage_setup` (the pair tests)."""
    nx, ny = (int(n) for n in shape)
    return cover_blocks_many(setup, np.array([float(block_size)]),
                             np.array([[float(o) for o in origin]]),
                             np.array([ny], dtype=np.int64), np.zeros(1, np.int64),
                             nx * ny).reshape(nx, ny)


def cover_blocks_many(setup: dict | None, block_size, origin, ny, offset,
                      size: int) -> np.ndarray:
    """The masks of many grids from :func:`coverage_setup_many`'s ``setup``, concatenated
    (``size`` cells): grid w's (nx, ny[w]) row-major mask starts at ``offset[w]``."""
    mask = np.zeros(int(size), dtype=bool)
    if setup is None:
        return mask
    nrm, off, radius = setup["nrm"], setup["off"], setup["radius"]
    lo, cnt, n_pairs, win = setup["lo"], setup["cnt"], setup["n_pairs"], setup["window"]
    block_size = np.asarray(block_size, dtype=np.float64)
    origin = np.asarray(origin, dtype=np.float64)
    start = 0
    while start < len(nrm):
        # as many triangles as keep the pair count under the chunk size (at least one)
        cum = np.cumsum(n_pairs[start:])
        stop = start + max(1, int(np.searchsorted(cum, _PAIR_CHUNK, side="right")))
        counts = n_pairs[start:stop]
        t = np.repeat(np.arange(start, stop), counts)
        k = np.arange(len(t)) - np.repeat(np.cumsum(counts) - counts, counts)
        w = cnt[t, 1]
        bi = lo[t, 0] + k // w
        bj = lo[t, 1] + k % w
        g = win[t]
        bs = block_size[g]
        cx = origin[g, 0] + (bi + 0.5) * bs
        cy = origin[g, 1] + (bj + 0.5) * bs
        # the three edge normals as separating axes, one at a time on the pairs left
        for edge in range(3):
            ok = (nrm[t, edge, 0] * cx + nrm[t, edge, 1] * cy) - radius[t, edge] <= off[t, edge]
            t, bi, bj, g, cx, cy = t[ok], bi[ok], bj[ok], g[ok], cx[ok], cy[ok]
        mask[offset[g] + bi * ny[g] + bj] = True
        start = stop
    return mask


def cover_xy_many(tri_xy, window, block_size, origin, shape, offset, size: int) -> np.ndarray:
    """(size,) bool: the concatenated masks (grid w's row-major (nx, ny) mask at
    ``offset[w]``) of the projected triangles ``tri_xy`` (T, 3, 2), triangle t on grid
    ``window[t]`` (``block_size`` (W,), ``origin`` (W, 2), ``shape`` (W, 2)):
    :func:`coverage_setup_many` then :func:`cover_blocks_many`. The device's
    kernels/silhouette.cl: block_cover_xy evaluates the same expressions."""
    shape = np.asarray(shape, dtype=np.int64)
    return cover_blocks_many(coverage_setup_many(tri_xy, window, block_size, origin, shape),
                             block_size, origin, shape[:, 1], offset, size)
