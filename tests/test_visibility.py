"""The visibility decisions every mechanism shares (clradcom.device.visibility), on a floor
and a wall floating above it: reaching a face, clear segments, surface points seeing a
target, and whole reflection paths."""

import numpy as np
import pytest

from clradcom.device.raycast import RayCaster
from clradcom.device.visibility import (
    confirm_paths,
    confirm_slack,
    containing_triangles,
    reaches_face,
    segments_clear,
    surface_sees,
)

# floor z = 0 over x in [-3, 3], y in [-1, 1] (face 0); wall x = 2 over z in [0.2, 2] (face 1)
TRIANGLES = np.array([
    [[-3, -1, 0], [3, -1, 0], [3, 1, 0]],
    [[-3, -1, 0], [3, 1, 0], [-3, 1, 0]],
    [[2, -1, 0.2], [2, 1, 0.2], [2, 1, 2]],
    [[2, -1, 0.2], [2, 1, 2], [2, -1, 2]],
], dtype=np.float64)
TRI_FACE = np.array([0, 0, 1, 1])
FACE_NORMAL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0]])


@pytest.fixture(scope="module")
def caster(runtime):
    return RayCaster(TRIANGLES, runtime=runtime)


def test_reaches_face_names_the_triangle_holding_the_end(caster):
    start = np.array([[0.0, 0.0, 1.0], [4.0, 0.0, 1.0], [3.0, 0.0, 1.0]])
    end = np.array([[0.5, 0.5, 0.0],     # on the floor, in triangle 1
                    [4.0, 0.0, 0.0],     # in the floor's plane, off the floor: the ray misses
                    [0.5, 0.0, 0.0]])    # on the floor, behind the wall
    slack = confirm_slack(end, np.linalg.norm(end - start, axis=1))
    assert reaches_face(caster, TRI_FACE, start, end, [0, 0, 0], slack).tolist() == [1, -1, -1]


def test_segments_clear_between_tmin_and_tmax(caster):
    start = np.tile([3.0, 0.0, 1.0], (3, 1))
    end = np.tile([0.0, 0.0, 1.0], (3, 1))    # crosses the wall a third of the way
    clear = segments_clear(caster, TRI_FACE, start, end, [0.0, 0.5, 0.0], [1.0, 1.0, 0.3])
    assert clear.tolist() == [False, True, True]


def test_surface_sees_past_its_own_triangle_but_not_through_the_wall(caster):
    points = np.tile([-1.0, 0.5, 0.0], (2, 1))
    normals = np.tile([0.0, 0.0, 1.0], (2, 1))
    assert surface_sees(caster, points[:1], normals[:1], [-1.0, 0.5, 5.0], [1]).tolist() == [True]
    assert surface_sees(caster, points[:1], normals[:1], [4.0, 0.5, 0.5], [1]).tolist() == [False]
    on_wall = np.array([[2.0, 0.5, 1.0], [2.0, 0.5, 1.0]])
    assert surface_sees(caster, points, normals, on_wall, [1, 1],
                        stop_short_m=np.full(2, 1e-3)).tolist() == [True, True]
    assert surface_sees(caster, points[:0], normals[:0], [0.0, 0.0, 1.0], []).shape == (0,)


def test_confirm_paths_checks_every_segment(caster):
    tx = np.array([-0.5, 0.0, 1.0])
    rx_open, rx_hidden = np.array([1.0, 0.0, 1.0]), np.array([2.5, 0.0, 0.5])
    # the floor reflections: (0.25, 0, 0) in the open; (1.5, 0, 0), whose way to rx_hidden
    # the wall blocks
    points = np.array([[tx, [0.25, 0.0, 0.0], rx_open], [tx, [1.5, 0.0, 0.0], rx_hidden]])
    keep, tris = confirm_paths(caster, TRI_FACE, FACE_NORMAL, points, np.zeros((2, 1), int))
    assert keep.tolist() == [True, False]
    assert tris[:, 0].tolist() == [0, -1]


def test_inside_is_exact_at_the_rim_and_forgiving_at_a_seam():
    """containing_triangles: a point on the floor's rim is inside, one 1e-12 m outside it is
    not (INSIDE_TOL_REL forgives rounding across seams only, so the rim is where UTD puts
    its edge's boundary); points on the diagonal seam between the floor's two triangles
    are inside whichever triangle is guessed first."""
    rim = np.array([[0.3, -1.0, 0.0], [0.3, -1.0 - 1e-12, 0.0], [3.0 + 1e-12, 0.2, 0.0],
                    [-3.0, 0.7, 0.0]])
    got = containing_triangles(rim, np.zeros(4, int), np.zeros(4, int), TRIANGLES, TRI_FACE)
    assert got.tolist() == [0, -1, -1, 1]
    t = np.linspace(0.01, 0.99, 97)
    seam = np.array([-3.0, -1.0, 0.0]) + t[:, None] * np.array([6.0, 2.0, 0.0])
    for guess in (0, 1):
        got = containing_triangles(seam, np.zeros(len(t), int), np.full(len(t), guess),
                                   TRIANGLES, TRI_FACE)
        assert np.all(got >= 0)
