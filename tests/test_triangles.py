"""The shared triangle normals and areas (clradcom.geometry.triangles): the right-hand
normal of the vertex order, and bit for bit the formulas the traced results were fixed
with ((v1 - v0) x (v2 - v0), its norm, division by it, 0.5 * norm)."""

import numpy as np

from clradcom.geometry.triangles import (
    triangle_areas,
    triangle_cross_products,
    triangle_double_areas,
    triangle_normals,
    triangle_normals_and_double_areas,
)


def _random_triangles(n=500, seed=3):
    rng = np.random.default_rng(seed)
    return rng.normal(size=(n, 3, 3)) * rng.uniform(1e-3, 1e3, size=(n, 1, 1)) + rng.normal(
        size=(n, 1, 3)) * 100.0


def test_right_hand_normal_and_area():
    tri = np.array([[[0.0, 0, 0], [2, 0, 0], [0, 3, 0]], [[0.0, 0, 1], [0, 0, 3], [0, 4, 1]]])
    np.testing.assert_array_equal(triangle_normals(tri), [[0, 0, 1], [-1, 0, 0]])
    np.testing.assert_array_equal(triangle_areas(tri), [3.0, 4.0])
    np.testing.assert_array_equal(triangle_double_areas(tri), [6.0, 8.0])
    np.testing.assert_array_equal(triangle_cross_products(tri), [[0, 0, 6], [-8, 0, 0]])


def test_bit_identical_to_the_reference_formulas():
    tri = _random_triangles()
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    norm = np.linalg.norm(cross, axis=1)
    assert triangle_cross_products(tri).tobytes() == cross.tobytes()
    assert triangle_double_areas(tri).tobytes() == norm.tobytes()
    assert triangle_areas(tri).tobytes() == (0.5 * norm).tobytes()
    normals, double_areas = triangle_normals_and_double_areas(tri)
    assert normals.tobytes() == (cross / norm[:, None]).tobytes()
    assert double_areas.tobytes() == norm.tobytes()
    assert triangle_normals(tri).tobytes() == normals.tobytes()


def test_zero_area_triangle_has_nan_normal():
    tri = np.array([[[0.0, 0, 0], [1, 0, 0], [2, 0, 0]]])
    with np.errstate(invalid="ignore", divide="ignore"):
        n, a2 = triangle_normals_and_double_areas(tri)
    assert a2[0] == 0.0 and np.all(np.isnan(n))
