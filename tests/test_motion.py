"""Motion in the scene file (clradcom.scene.motion): rotation, trajectories, [time];
scene_at; the Doppler of points on a rotating body against the closed form.

Rotating disc (the closed form): a disc in the plane z = 0 turns at omega about the z
axis through its centre, the origin; a monostatic radar at s = (D, 0, H). A point
p = r (cos t, sin t, 0) moves at v = omega r (-sin t, cos t, 0), so with L = 2 |s - p|
    f_D = -(1/lambda) dL/dt = (2/lambda) v . (s - p) / |s - p|
        = -2 omega r D sin(t) / (lambda |s - p|).
"""

from __future__ import annotations

import copy

import numpy as np
import pytest

from clradcom.errors import ArgumentError, SceneError
from clradcom.mechanisms.common import build_geometry
from clradcom.mechanisms.physical_optics import po_paths
from clradcom.physics.em import C0
from clradcom.scene.motion import scene_at
from clradcom.scene.reader import load_scene, scene_from_dict

F_C = 24e9
LAM = C0 / F_C
CANON = __import__("pathlib").Path(__file__).parent.parent / "scenes" / "canonical"
#: the content hash of scenes/canonical/moving_car.toml before motion existed (6442f4b)
HASH_MOVING_CAR = "a34daf9134526b62eaf581175c51400a6da8860bf6a80ef458f63d7e615cc51b"


def disc(n=24, radius=0.5):
    """A triangle fan (normal +z) of n sectors around the origin."""
    ang = 2 * np.pi * np.arange(n) / n
    verts = [[0.0, 0.0, 0.0]] + [[radius * np.cos(a), radius * np.sin(a), 0.0] for a in ang]
    faces = [[0, 1 + i, 1 + (i + 1) % n] for i in range(n)]
    return verts, faces


def disc_doc(omega_deg_s=(0.0, 0.0, 900.0), **extra):
    verts, faces = disc()
    obj = {"name": "disc", "material": "metal", "shape": "triangles", "vertices": verts,
           "faces": faces, "angular_velocity_deg_s": list(omega_deg_s), **extra}
    return {"scene": {"name": "disc", "carrier_hz": F_C}, "objects": [obj],
            "radars": [{"name": "r", "position": [3.0, 0.0, 4.0], "pattern": "isotropic"}]}


def test_rotating_disc_doppler_closed_form(runtime):
    doc = disc_doc()
    scene = scene_from_dict(doc)
    geom = build_geometry(scene, runtime)
    radar = scene.radars[0]
    p = po_paths(geom, radar, radar, min_relative_db=-300)
    assert len(p.gain) == 24
    pts = p.points[:, 1]
    s = radar.position
    omega = np.radians(900.0)
    r = np.hypot(pts[:, 0], pts[:, 1])
    theta = np.arctan2(pts[:, 1], pts[:, 0])
    want = -2 * omega * r * s[0] * np.sin(theta) / (LAM * np.linalg.norm(s - pts, axis=1))
    np.testing.assert_allclose(p.doppler_hz, want, rtol=1e-12, atol=1e-9)
    assert np.abs(want).max() > 100  # it turns fast enough to matter: hundreds of Hz
    # the same disc without rotation: no Doppler at all
    still = scene_from_dict(disc_doc((0.0, 0.0, 0.0)))
    p0 = po_paths(build_geometry(still, runtime), still.radars[0], still.radars[0],
                  min_relative_db=-300)
    assert np.all(p0.doppler_hz == 0)
    # and against -(1/lambda) dL/dt by central differences of the facets' centroids as
    # scene_at turns the triangles (independent of point_velocity)
    dt = 1e-6
    cen = [scene_at(scene, t).triangles.mean(axis=1) for t in (-dt, dt)]
    lengths = [2 * np.linalg.norm(s - c, axis=1) for c in cen]
    fd = -(lengths[1] - lengths[0]) / (2 * dt) / LAM
    centroid = scene.triangles.mean(axis=1)
    order = [int(np.argmin(np.linalg.norm(centroid - q, axis=1))) for q in pts]
    np.testing.assert_allclose(p.doppler_hz, fd[order], rtol=1e-6, atol=1e-3)


def test_rotation_centre_and_riding_radar_velocity():
    doc = disc_doc((0.0, 0.0, 90.0), rotation_centre=[1.0, 0.0, 0.0], velocity=[2.0, 0, 0])
    doc["radars"].append({"name": "on", "rides_on": "disc", "position": [0.0, 1.0, 0.0]})
    scene = scene_from_dict(doc)
    w = np.radians(90.0)
    # v + omega x (p - c): p - c = (-1, 1, 0), omega z x that = w (-1, -1, 0)
    np.testing.assert_allclose(scene.radars[1].velocity, [2.0 - w, -w, 0.0], atol=1e-15)
    v = scene.point_velocity(np.array([0]), np.array([[1.0, 0.0, 0.0]]))
    np.testing.assert_allclose(v, [[2.0, 0.0, 0.0]])
    # a quarter turn later (1 s): everything turned 90 deg about the moved centre
    later = scene_at(scene, 1.0)
    c = np.array([3.0, 0.0, 0.0])  # the centre moved with the velocity
    q = scene.triangles.reshape(-1, 3) - [1.0, 0.0, 0.0]
    want = c + np.stack([-q[:, 1], q[:, 0], q[:, 2]], axis=1)
    np.testing.assert_allclose(later.triangles.reshape(-1, 3), want, atol=1e-12)
    np.testing.assert_allclose(later.radars[1].position, c + [-1.0, -1.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(later.radars[1].orientation[:, 0], [0, 1, 0], atol=1e-12)
    np.testing.assert_allclose(later.objects[0].rotation_deg, [0, 0, 90], atol=1e-9)
    np.testing.assert_allclose(later.objects[0].motion.rotation_centre, c)
    assert later.time_s == 1.0 and scene.time_s == 0.0


def test_trajectory_pose_velocity_and_time_table():
    doc = disc_doc((0.0, 0.0, 0.0))
    del doc["objects"][0]["angular_velocity_deg_s"]
    doc["objects"][0]["trajectory"] = [[0.0, 0, 0, 0], [1.0, 10, 0, 0], [3.0, 10, 4, 0]]
    doc["radars"][0] = {"name": "r", "trajectory": [[0.5, 0, 0, 5], [2.5, 0, 20, 5]]}
    doc["time"] = {"start_s": 0.5, "step_s": 0.5, "count": 5}
    scene = scene_from_dict(doc)
    assert scene.time_s == 0.5
    np.testing.assert_allclose(scene.time_axis.times, [0.5, 1.0, 1.5, 2.0, 2.5])
    np.testing.assert_allclose(scene.objects[0].position, [5, 0, 0])
    np.testing.assert_allclose(scene.object_velocity[0], [10, 0, 0])
    np.testing.assert_allclose(scene.radars[0].velocity, [0, 10, 0])
    at = scene_at(scene, 2.0)
    np.testing.assert_allclose(at.objects[0].position, [10, 2, 0])
    np.testing.assert_allclose(at.object_velocity[0], [0, 2, 0])
    np.testing.assert_allclose(at.triangles - scene.triangles, np.broadcast_to(
        [5.0, 2.0, 0.0], scene.triangles.shape), atol=1e-14)
    np.testing.assert_allclose(at.radars[0].position, [0, 15, 5])
    with pytest.raises(ArgumentError, match="outside the trajectory") as exc:
        scene_at(scene, 2.75)
    assert exc.value.argument == "t"
    assert scene.content_hash() != at.content_hash()


def test_scenes_without_motion_keep_their_hash_and_arrays():
    scene = load_scene(CANON / "moving_car.toml")
    # the hash this scene had before motion existed (clradcom at 6442f4b)
    assert scene.content_hash() == HASH_MOVING_CAR
    assert scene.time_s == 0.0 and scene.time_axis is None and not scene.moving
    same = scene_at(scene, 0.0)
    assert np.array_equal(same.triangles, scene.triangles)
    assert same.content_hash() == scene.content_hash()
    later = scene_at(scene, 0.5)  # constant velocities: a plain translation
    b = scene.object_index("carB")
    sl = scene.objects[b].tri_slice
    np.testing.assert_allclose(later.triangles[sl] - scene.triangles[sl],
                               np.broadcast_to([-6.65, 0, 0], scene.triangles[sl].shape),
                               atol=1e-12)
    np.testing.assert_allclose(later.radars[0].position - scene.radars[0].position,
                               [6.45, 0, 0], atol=1e-12)
    ids = np.array([b, b])
    assert np.array_equal(scene.point_velocity(ids, np.full((2, 3), np.nan)),
                          scene.object_velocity[ids])




@pytest.mark.parametrize("change, key, text", [
    (lambda d: d["objects"][0].update(angular_velocity_deg_s=[0, 0]),
     "objects[0].angular_velocity_deg_s", "array of 3"),
    (lambda d: d["objects"][0].update(rotation_centre=[0, 0, 1]) or d["objects"][0].pop(
        "angular_velocity_deg_s"), "objects[0].rotation_centre", "needs angular"),
    (lambda d: d["objects"][0].update(trajectory=[[0, 0, 0, 0]]),
     "objects[0].trajectory", "at least 2 rows"),
    (lambda d: d["objects"][0].update(trajectory=[[0, 0, 0, 0], [0, 1, 0, 0]]),
     "objects[0].trajectory[1]", "increase strictly"),
    (lambda d: d["objects"][0].update(trajectory=[[0, 0, 0, 0], [1, 1, 0, float("nan")]]),
     "objects[0].trajectory[1]", "NaN"),
    (lambda d: d["objects"][0].update(trajectory=[[0, 0, 0, 0], [1e-9, 1, 0, 0]]),
     "objects[0].trajectory[1]", "speed of light"),
    (lambda d: d["objects"][0].update(trajectory=[[1, 0, 0, 0], [2, 1, 0, 0]]),
     "objects[0].trajectory", "extend it"),
    (lambda d: d["objects"][0].update(trajectory=[[0, 0, 0, 0], [1, 1, 0, 0]],
                                      velocity=[1, 0, 0]), "objects[0].velocity",
     "trajectory gives"),
    (lambda d: d["objects"][0].update(trajectory=[[0, 0, 0, 0], [1, 1, 0, 0]],
                                      position=[1, 0, 0]), "objects[0].position",
     "trajectory gives"),
    (lambda d: d["radars"].append({"name": "x", "rides_on": "disc", "position": [0, 0, 0],
                                   "angular_velocity_deg_s": [0, 0, 1]}),
     "radars[1].angular_velocity_deg_s", "rides_on"),
    (lambda d: d.update(time={"step_s": 0.0, "count": 2}), "time.step_s", "> 0"),
    (lambda d: d.update(time={"step_s": 0.1, "count": 0}), "time.count", "whole number"),
    (lambda d: d.update(time={"step_s": 0.1, "count": 2.5}), "time.count", "whole number"),
    (lambda d: d.update(time={"step_s": 0.1, "count": 2, "stop_s": 1}), "time.stop_s",
     "unknown key"),
    (lambda d: d.update(time=[1, 2]), "time", "expected a table"),
])
def test_motion_keys_are_checked(change, key, text):
    doc = copy.deepcopy(disc_doc())
    change(doc)
    with pytest.raises(SceneError, match=text) as exc:
        scene_from_dict(doc, file="motion.toml")
    assert exc.value.key == key
    assert "motion.toml" in str(exc.value)


def test_scene_at_refuses_bad_times():
    scene = scene_from_dict(disc_doc())
    for bad in (float("nan"), "1", None, True):
        with pytest.raises(ArgumentError) as exc:
            scene_at(scene, bad)
        assert exc.value.argument == "t"


def test_turning_radar_frame_and_velocity():
    doc = disc_doc((0.0, 0.0, 0.0))
    doc["radars"][0].update(velocity=[1.0, 0.0, 0.0], angular_velocity_deg_s=[0, 0, 180.0],
                            rotation_centre=[3.0, -1.0, 4.0])
    scene = scene_from_dict(doc)
    w = np.pi
    # v + omega x (p - c), p - c = (0, 1, 0): omega z x y = -w x
    np.testing.assert_allclose(scene.radars[0].velocity, [1.0 - w, 0.0, 0.0], atol=1e-15)
    half = scene_at(scene, 0.5)  # a quarter turn about the centre, which moved 0.5 m
    np.testing.assert_allclose(half.radars[0].position, [3.5 - 1.0, -1.0, 4.0], atol=1e-12)
    np.testing.assert_allclose(half.radars[0].orientation[:, 0], [0, 1, 0], atol=1e-12)
    # at (-1, 0, 0) from the centre omega z x (-x) = -w y
    np.testing.assert_allclose(half.radars[0].velocity, [1.0, -w, 0.0], atol=1e-12)
    again = scene_at(scene, 0.0)
    np.testing.assert_allclose(again.radars[0].velocity, scene.radars[0].velocity,
                               atol=1e-15)
