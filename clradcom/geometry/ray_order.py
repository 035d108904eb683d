"""Directions ordered so that neighbours in the array are neighbours on the sphere.

A launch lattice in Fibonacci order puts consecutive rays far apart (each step turns by
the golden angle), so the rays that one OpenCL work-group traces one after the other on a
CPU core walk different parts of the BVH and keep little of it in the core's caches.
Ordered along a space-filling curve, a work-group's rays leave in a narrow cone, walk the
same records and triangles, and after a reflection off the same plane stay together.
The order changes which rays run together, never what any ray hits
(docs/performance.md, "Coherent launch order").

The curve: the octahedral map of the unit sphere onto the square [-1, 1]^2 (Praun &
Hoppe, "Spherical parametrization and remeshing", SIGGRAPH 2003; Cigolle et al., "A
Survey of Efficient Representations for Independent Unit Vectors", JCGT 3(2), 2014),
cut into 2^bits x 2^bits cells visited in Morton (Z) order.
"""

from __future__ import annotations

import numpy as np

from clradcom.errors import ArgumentError

__all__ = ["MORTON_BITS", "coherent_order", "morton_codes", "octahedral_coordinates"]

#: cells per side of the octahedral square, as a power of two: 2^16 cells, so the codes
#: are uint16 and numpy's stable argsort is a radix sort (~0.02 s for 10^6 directions);
#: about 15 rays of a 10^6-ray launch per cell (measured as fast as 7 or 10 bits)
MORTON_BITS = 8


def octahedral_coordinates(directions) -> tuple[np.ndarray, np.ndarray]:
    """(u, v) in [-1, 1]^2 of non-zero directions (R, 3) on the octahedral map: the
    direction scaled to |x| + |y| + |z| = 1, the lower half (z < 0) folded out over the
    square's corners. Continuous except across the folded edges; equal areas of the
    sphere land on areas of the square within a factor of about 2."""
    d = np.asarray(directions, dtype=np.float64)
    if d.ndim != 2 or d.shape[1] != 3:
        raise ArgumentError(f"directions must have shape (R, 3), got {d.shape}",
                            argument="directions", value=d.shape)
    # |x| + |y| + |z| added left to right, as np.abs(d).sum(axis=1) adds a row's three
    # (bit for bit: tests/test_ray_order.py), without its slow reduction over 3 columns
    a = np.abs(d)
    norm1 = a[:, 0] + a[:, 1]
    norm1 += a[:, 2]
    if not np.all(np.isfinite(norm1)) or np.any(norm1 == 0.0):
        bad = int(np.flatnonzero(~np.isfinite(norm1) | (norm1 == 0.0))[0])
        raise ArgumentError("must be finite and non-zero", argument=f"directions[{bad}]",
                            value=d[bad].tolist())
    x, y, z = (d[:, k] / norm1 for k in range(3))
    lower = z < 0.0
    sx = np.where(x < 0.0, -1.0, 1.0)
    sy = np.where(y < 0.0, -1.0, 1.0)
    u = np.where(lower, (1.0 - np.abs(y)) * sx, x)
    v = np.where(lower, (1.0 - np.abs(x)) * sy, y)
    return u, v


def _spread_bits(w: np.ndarray) -> np.ndarray:
    """The bits of w (< 2^16) moved to the even positions of a uint32."""
    w = w.astype(np.uint32)
    w = (w | (w << 8)) & np.uint32(0x00FF00FF)
    w = (w | (w << 4)) & np.uint32(0x0F0F0F0F)
    w = (w | (w << 2)) & np.uint32(0x33333333)
    return (w | (w << 1)) & np.uint32(0x55555555)


def morton_codes(u, v, bits: int = MORTON_BITS) -> np.ndarray:
    """The Morton (Z-order) code of the cell of each point (u, v) of [-1, 1]^2 on a
    2^bits x 2^bits grid: u's cell index in the even bits, v's in the odd ones; uint16
    where 2 * bits <= 16, else uint32."""
    if isinstance(bits, bool) or not isinstance(bits, int | np.integer) or not 1 <= bits <= 16:
        raise ArgumentError("must be an integer in [1, 16]", argument="bits", value=bits)
    cells = 1 << int(bits)
    iu = np.clip(np.floor((np.asarray(u, np.float64) + 1.0) * (cells / 2.0)), 0, cells - 1)
    iv = np.clip(np.floor((np.asarray(v, np.float64) + 1.0) * (cells / 2.0)), 0, cells - 1)
    code = _spread_bits(iu) | (_spread_bits(iv) << np.uint32(1))
    return code.astype(np.uint16 if bits <= 8 else np.uint32)


def coherent_order(directions, bits: int = MORTON_BITS) -> np.ndarray:
    """The permutation (int64) that orders directions (R, 3) along the Morton curve over
    their octahedral map; directions in one cell keep their order (stable)."""
    u, v = octahedral_coordinates(directions)
    return np.argsort(morton_codes(u, v, bits), kind="stable")
