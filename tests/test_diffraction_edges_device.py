"""Edge visibility on the device (kernels/edges.cl, clradcom/device/edges.py) against the
numpy reference (diffraction._seeing): the same wedges, bit for bit, for every antenna
position, number of samples and halving depth."""

import numpy as np
import pytest

from clradcom.device import edges as device_edges
from clradcom.device import engines
from clradcom.errors import DeviceFallbackWarning
from clradcom.geometry.wedges import extract_wedges
from clradcom.mechanisms import diffraction
from clradcom.mechanisms.common import build_geometry
from clradcom.scene.reader import scene_from_dict


def grid_wall(x, y0, y1, z0, z1, ny, nz):
    """A planar wall x = const cut into ny x nz quads of two triangles (seams inside)."""
    ys, zs = np.linspace(y0, y1, ny + 1), np.linspace(z0, z1, nz + 1)
    verts = [[x, y, z] for z in zs for y in ys]
    faces = []
    for j in range(nz):
        for i in range(ny):
            a = j * (ny + 1) + i
            b, c, d = a + 1, a + ny + 1, a + ny + 2
            faces += [[a, b, d], [a, d, c]]
    return {"shape": "triangles", "vertices": verts, "faces": faces}


def edge_scene():
    """Boxes near and far, one hidden, one behind a tiled wall, a plain wall and two
    screens side by side, and one radar among them."""
    objects = [
        {"name": "near", "material": "metal", "shape": "box", "extents": [1.0, 1.0, 3.0],
         "position": [4.0, 0.5, 1.5]},
        {"name": "far", "material": "metal", "shape": "box", "extents": [2.0, 3.0, 6.0],
         "position": [12.0, -1.0, 3.0]},
        {"name": "hidden", "material": "metal", "shape": "box", "extents": [1.0, 1.0, 1.0],
         "position": [20.0, 8.0, 0.5]},
        {"name": "behind", "material": "metal", "shape": "box", "extents": [1.5, 1.0, 2.0],
         "position": [19.0, -6.0, 1.0]},
        {"name": "wall", "material": "concrete_building", "shape": "plane", "size": [6.0, 10.0],
         "position": [16.0, 8.0, 2.0], "rotation_deg": [0.0, -90.0, 0.0]},
        {"name": "tiled", "material": "concrete_building",
         **grid_wall(16.0, -9.0, -3.0, 0.0, 4.0, 6, 4)},
        {"name": "left", "material": "metal", "shape": "plane", "size": [8.0, 1.2],
         "position": [8.0, -1.9, 4.0], "rotation_deg": [0.0, -90.0, 0.0]},
        {"name": "right", "material": "metal", "shape": "plane", "size": [8.0, 1.2],
         "position": [8.0, -0.5, 4.0], "rotation_deg": [0.0, -90.0, 0.0]},
    ]
    return scene_from_dict({"scene": {"name": "edges", "carrier_hz": 24e9},
                            "objects": objects,
                            "radars": [{"name": "r", "position": [0.0, -1.0, 1.0]}]})


@pytest.fixture(scope="module")
def scene_and_geometry(runtime):
    scene = edge_scene()
    geom = build_geometry(scene, runtime)
    wedges = extract_wedges(scene.triangles, scene.tri_object, scene.tri_material)
    return scene, geom, wedges


POINTS = [[0.0, -1.0, 1.0], [6.0, -5.0, 2.0], [25.0, -6.0, 1.5], [10.0, 4.0, 0.4],
          [3.0, 0.5, 1.5], [14.0, -1.0, 7.0], [30.0, 8.0, 2.0], [8.0, -1.2, 4.0]] + (
    np.random.default_rng(3).uniform([-5.0, -12.0, 0.2], [32.0, 12.0, 8.0], (24, 3)).tolist())


def host_reference(geom, wedges, points, samples, depth):
    return [diffraction._seeing(geom.caster, wedges, p, samples, geom.faces.tri_face, depth,
                                outlines={}) for p in points]


@pytest.mark.parametrize("samples, depth", [((0.25, 0.5, 0.75), 2), ((0.5,), 0),
                                            ((0.25, 0.5, 0.75), 4), ((), 1)])
def test_device_keeps_the_host_references_wedges(scene_and_geometry, samples, depth):
    """Every antenna position (in the open, behind the tiled wall, between the screens,
    inside a box's corner region): the same (sampled, kept) masks from one launch as from
    the numpy reference; the filter keeps wedges only the pieces decided and drops some."""
    scene, geom, wedges = scene_and_geometry
    assert device_edges.usable(geom.caster, "device", len(samples), depth)
    device = diffraction._seeing_many(geom.caster, wedges, POINTS, samples,
                                      geom.faces.tri_face, depth, engine="device")
    host = host_reference(geom, wedges, POINTS, samples, depth)
    for p, (d_sampled, d_kept), (h_sampled, h_kept) in zip(POINTS, device, host, strict=True):
        assert np.array_equal(d_sampled, h_sampled), p
        assert np.array_equal(d_kept, h_kept), (p, np.flatnonzero(d_kept != h_kept))
    kept = np.array([k for _, k in host])
    sampled = np.array([s for s, _ in host])
    assert np.any(kept & ~sampled)           # pieces kept wedges the samples missed
    assert np.any(~kept)                     # and proved others hidden
    behind = wedges.object_id == [o.name for o in scene.objects].index("behind")
    assert not np.any(kept[0][behind])      # the box behind the tiled wall, seen from r


def test_wedges_seeing_engines_agree_and_fall_back(scene_and_geometry):
    """The public filter gives the same mask on both engines; more halvings than the
    kernel's stack holds go to the host."""
    _, geom, wedges = scene_and_geometry
    p = np.array(POINTS[1])
    dev = diffraction.wedges_seeing(geom.caster, wedges, p, tri_face=geom.faces.tri_face)
    host = diffraction.wedges_seeing(geom.caster, wedges, p, tri_face=geom.faces.tri_face,
                                     engine="host")
    assert np.array_equal(dev, host) and dev.any()
    assert not device_edges.usable(geom.caster, "device", 3, device_edges.MAX_DEPTH + 1)
    assert not device_edges.usable(geom.caster, "host", 3, 2)
    # a test beyond the kernel's stack runs on the host, recorded and said once
    deep = device_edges.MAX_DEPTH + 1
    with engines.engine_log() as log, pytest.warns(DeviceFallbackWarning,
                                                   match="diffraction.edge_sight.*halvings"):
        deep_mask = diffraction.wedges_seeing(geom.caster, wedges, p,
                                              tri_face=geom.faces.tri_face, max_depth=deep)
    assert log.engine_of("diffraction.edge_sight") == "host"
    assert "halvings" in log.metadata()["engine.diffraction.edge_sight"]
    assert np.array_equal(deep_mask, diffraction.wedges_seeing(
        geom.caster, wedges, p, tri_face=geom.faces.tri_face, max_depth=deep, engine="host"))


def test_outside_every_is_outside(scene_and_geometry):
    """The broadcast form of _outside decides every direction alike: random ones, along
    both faces of each wedge, along its edge (end-on: not outside) and the zero vector."""
    _, _, wedges = scene_and_geometry
    W = len(wedges)
    rng = np.random.default_rng(7)
    t0 = np.cross(wedges.normal0, wedges.direction)
    t1 = np.cross(wedges.direction, wedges.normal1)
    special = np.stack([wedges.normal0, -wedges.normal0, t0, -t0, t1, wedges.normal1,
                        wedges.direction, -wedges.direction, np.zeros((W, 3)),
                        t0 + 1e-7 * wedges.normal0, t0 - 1e-7 * wedges.normal0])
    for d in (rng.normal(size=(5, W, 3)), special):
        expected = diffraction._outside(wedges, np.tile(np.arange(W), len(d)),
                                        d.reshape(-1, 3)).reshape(len(d), W)
        assert np.array_equal(diffraction._outside_every(wedges, d), expected)
