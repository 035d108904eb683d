"""Plain float64 numpy geometry of triangle soups: normals, areas, distances, ray
crossings and inside tests. Every module that needs a triangle's normal or area takes
it from here."""

from __future__ import annotations

import numpy as np

__all__ = ["inside_closed_mesh", "point_triangle_distance", "ray_hit_distances",
           "triangle_areas", "triangle_cross_products", "triangle_double_areas",
           "triangle_normals", "triangle_normals_and_double_areas"]


# Every formula below is the one the tracer's results were fixed with: the cross product
# of the edges from vertex 0, (v1 - v0) x (v2 - v0); its Euclidean norm; unit normals by
# dividing by that norm; areas as 0.5 * norm.  Another edge pair, a multiplication by the
# reciprocal or norm / 2 round differently and would change traced numbers in the last bits.


def triangle_cross_products(triangles) -> np.ndarray:
    """(T, 3) unnormalised normals (v1 - v0) x (v2 - v0) of triangles (T, 3, 3): the
    right-hand normal of the vertex order, twice the triangle's area long."""
    tri = np.asarray(triangles, dtype=np.float64)
    return np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])


def triangle_double_areas(triangles) -> np.ndarray:
    """(T,) twice the areas of triangles (T, 3, 3): |(v1 - v0) x (v2 - v0)|."""
    return np.linalg.norm(triangle_cross_products(triangles), axis=-1)


def triangle_areas(triangles) -> np.ndarray:
    """(T,) areas (m^2) of triangles (T, 3, 3): 0.5 |(v1 - v0) x (v2 - v0)|."""
    return 0.5 * triangle_double_areas(triangles)


def triangle_normals_and_double_areas(triangles) -> tuple[np.ndarray, np.ndarray]:
    """Unit normals (T, 3) of the vertex order and twice the areas (T,) of triangles
    (T, 3, 3), from one cross product.  A zero-area triangle's normal is NaN; numpy warns
    about that division unless the caller silences it (``np.errstate``)."""
    cross = triangle_cross_products(triangles)
    double_areas = np.linalg.norm(cross, axis=-1)
    return cross / double_areas[:, None], double_areas


def triangle_normals(triangles) -> np.ndarray:
    """(T, 3) unit normals of triangles (T, 3, 3), right-handed with the vertex order:
    (v1 - v0) x (v2 - v0) divided by its norm (NaN for zero-area triangles)."""
    return triangle_normals_and_double_areas(triangles)[0]


def point_triangle_distance(point, triangles) -> np.ndarray:
    """Euclidean distance from one point (3,) to each triangle (T, 3, 3); numpy, exact.

    Closest point by Voronoi regions of the triangle (Ericson, Real-Time Collision
    Detection, 5.1.5), vectorised over triangles.
    """
    p = np.asarray(point, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.float64).reshape(-1, 3, 3)
    a, b, c = t[:, 0], t[:, 1], t[:, 2]
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = np.einsum("ij,ij->i", ab, ap), np.einsum("ij,ij->i", ac, ap)
    bp = p - b
    d3, d4 = np.einsum("ij,ij->i", ab, bp), np.einsum("ij,ij->i", ac, bp)
    cp = p - c
    d5, d6 = np.einsum("ij,ij->i", ab, cp), np.einsum("ij,ij->i", ac, cp)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = 1.0 / (va + vb + vc)
        q = a + ab * (vb * denom)[:, None] + ac * (vc * denom)[:, None]  # interior
        # edges
        v_ab = d1 / (d1 - d3)
        q = np.where(((vc <= 0) & (d1 >= 0) & (d3 <= 0))[:, None], a + ab * v_ab[:, None], q)
        w_ac = d2 / (d2 - d6)
        q = np.where(((vb <= 0) & (d2 >= 0) & (d6 <= 0))[:, None], a + ac * w_ac[:, None], q)
        w_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        q = np.where(((va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0))[:, None],
                     b + (c - b) * w_bc[:, None], q)
    # vertices
    q = np.where(((d1 <= 0) & (d2 <= 0))[:, None], a, q)
    q = np.where(((d3 >= 0) & (d4 <= d3))[:, None], b, q)
    q = np.where(((d6 >= 0) & (d5 <= d6))[:, None], c, q)
    return np.linalg.norm(p - q, axis=1)


def ray_hit_distances(origin, direction, triangles) -> np.ndarray:
    """Distances t > 0 along one ray to every triangle it crosses (float64, Moller-Trumbore).

    A plain numpy check for scene generation and tests, where trimesh's own ray
    queries would need optional packages (rtree or embreex).
    """
    o = np.asarray(origin, dtype=np.float64)
    d = np.asarray(direction, dtype=np.float64)
    tri = np.asarray(triangles, dtype=np.float64)
    e1 = tri[:, 1] - tri[:, 0]
    e2 = tri[:, 2] - tri[:, 0]
    p = np.cross(d, e2)
    det = np.einsum("ij,ij->i", e1, p)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / det
        s = o - tri[:, 0]
        u = np.einsum("ij,ij->i", s, p) * inv
        q = np.cross(s, e1)
        v = (q @ d) * inv
        t = np.einsum("ij,ij->i", e2, q) * inv
        hit = (det != 0) & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0)
    return np.sort(t[hit])


def inside_closed_mesh(point, triangles) -> bool:
    """Parity test: a point is inside a closed mesh when a ray from it crosses it oddly often.

    The ray direction is irrational-looking so it does not graze edges of
    axis-aligned or symmetric meshes.
    """
    d = np.array([0.5773502691896258, 0.5772502691896258, 0.5774502691896258])
    return len(ray_hit_distances(point, d, triangles)) % 2 == 1
